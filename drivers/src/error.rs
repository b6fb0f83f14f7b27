//! Driver errors with backend-independent kinds.

use std::fmt;

/// What went wrong, in terms a caller can act on.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ErrorKind {
    /// No frame (or no acknowledgement) within the allowed time; retrying may help.
    Timeout,
    /// The device went away; reconnect before retrying.
    Disconnected,
    /// The device or backend cannot do this (format, trigger mode, feature).
    Unsupported,
    /// The device is in use or not ready (streaming state, another client); retry later.
    Busy,
    /// An argument is out of the device's range.
    InvalidArgument,
    /// Any other failure of the device or backend.
    Failed,
}

impl ErrorKind {
    /// Whether the same request may succeed if simply retried.
    pub fn is_transient(self) -> bool {
        matches!(self, ErrorKind::Timeout | ErrorKind::Busy)
    }
}

impl fmt::Display for ErrorKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            ErrorKind::Timeout => "timeout",
            ErrorKind::Disconnected => "disconnected",
            ErrorKind::Unsupported => "unsupported",
            ErrorKind::Busy => "busy",
            ErrorKind::InvalidArgument => "invalid argument",
            ErrorKind::Failed => "failed",
        })
    }
}

/// An error of a camera or projector, naming the device.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{device}: {kind}: {message}")]
pub struct DriverError {
    /// The generic kind.
    pub kind: ErrorKind,
    /// Device id (camera id, projector monitor, ...).
    pub device: String,
    /// What the backend said.
    pub message: String,
}

impl DriverError {
    /// An error of `kind` on `device`.
    pub fn new(kind: ErrorKind, device: impl Into<String>, message: impl Into<String>) -> Self {
        DriverError {
            kind,
            device: device.into(),
            message: message.into(),
        }
    }
}

/// Result alias of the drivers.
pub type Result<T, E = DriverError> = std::result::Result<T, E>;
