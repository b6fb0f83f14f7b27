//! The error type of `ris-core`: every variant names the file or field at fault.

use std::path::PathBuf;

/// Errors of the core library. Messages name the file, field or value so a user can fix input.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file at fault.
        path: PathBuf,
        /// The underlying I/O error.
        #[source]
        source: std::io::Error,
    },
    /// A TOML file did not parse or did not match its schema.
    #[error("{path}: {message}")]
    Toml {
        /// The file at fault.
        path: PathBuf,
        /// What the parser said, including line and field.
        message: String,
    },
    /// An image could not be decoded or encoded.
    #[error("{path}: image error: {message}")]
    Image {
        /// The file at fault.
        path: PathBuf,
        /// What the codec said.
        message: String,
    },
    /// A value in a file or argument is out of range or inconsistent.
    #[error("{context}: invalid value for `{field}`: {message}")]
    Invalid {
        /// The file (or command-line argument) holding the value.
        context: String,
        /// The field name.
        field: String,
        /// Why the value is wrong.
        message: String,
    },
    /// A file has a format this crate cannot read (wrong magic, unsupported variant).
    #[error("{path}: {message}")]
    Format {
        /// The file at fault.
        path: PathBuf,
        /// What is wrong with it.
        message: String,
    },
    /// A computation had too little usable data (e.g. no valid pixels in a reference).
    #[error("{0}")]
    Insufficient(String),
    /// A stage was stopped by its [`crate::budget::Budget`]: cancelled or past its deadline.
    #[error("{stage}: {why}")]
    Interrupted {
        /// The stage, as its budget names it.
        stage: String,
        /// Cancelled, or the deadline it passed.
        why: crate::budget::Interruption,
    },
}

/// Result alias of the core library.
pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    /// An I/O error on `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            source,
        }
    }

    /// An invalid value in `context` (a file or argument) for `field`.
    pub fn invalid(
        context: impl std::fmt::Display,
        field: impl Into<String>,
        message: impl Into<String>,
    ) -> Self {
        Error::Invalid {
            context: context.to_string(),
            field: field.into(),
            message: message.into(),
        }
    }
}
