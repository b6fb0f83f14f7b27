//! How the `ris` client commands reach a running risd: the command-line arguments, and the
//! client calls of [`ris_daemon::client`] they use.

use std::path::PathBuf;

pub use ris_daemon::client::{ask, fetch, open, replies};

/// How a client reaches a running risd.
#[derive(Clone, Debug, clap::Args)]
pub struct DaemonArgs {
    /// Zenoh endpoint of the daemon.
    #[arg(long, default_value = "tcp/127.0.0.1:7447")]
    pub connect: Vec<String>,
    /// Cell name.
    #[arg(long, default_value = "mock")]
    pub cell: String,
    /// Zenoh user, for a cell with [zenoh.access].
    #[arg(long, requires = "password_file")]
    pub user: Option<String>,
    /// File whose first line is the user's password.
    #[arg(long, requires = "user")]
    pub password_file: Option<PathBuf>,
}
