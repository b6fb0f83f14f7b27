//! `ris console`: the station, a web console over the Zenoh fabric of one cell or a plant of
//! cells (its own service beside each risd; see `systemd/ris-console.service`).

use std::net::SocketAddr;
use std::path::PathBuf;

use anyhow::{Context, Result};

/// `ris console`.
#[derive(Clone, Debug, clap::Args)]
pub struct ConsoleCommand {
    /// Zenoh endpoint of a risd or of the line's router (repeat for several).
    #[arg(long, default_value = "tcp/127.0.0.1:7447")]
    pub connect: Vec<String>,
    /// Address the web console listens on (loopback unless --access is given).
    #[arg(long, default_value = "127.0.0.1:8080")]
    pub http: SocketAddr,
    /// The history database (SQLite; created when missing).
    #[arg(long, default_value = "/var/lib/ris-console/history.sqlite")]
    pub db: PathBuf,
    /// A cell configuration whose [zenoh.access] users and roles sign in to the console
    /// (operators start scans, readers look).
    #[arg(long)]
    pub access: Option<PathBuf>,
    /// The console's own Zenoh user, for cells with [zenoh.access].
    #[arg(long, requires = "password_file")]
    pub user: Option<String>,
    /// File whose first line is that user's password.
    #[arg(long, requires = "user")]
    pub password_file: Option<PathBuf>,
    /// Scans of each part whose values set the control limits of its trends.
    #[arg(long, default_value_t = 20)]
    pub baseline: usize,
}

/// Run the console until SIGINT or SIGTERM.
pub fn command(c: &ConsoleCommand) -> Result<()> {
    let options = ris_console::Options {
        connect: c.connect.clone(),
        http: c.http,
        db: c.db.clone(),
        access: c.access.clone(),
        zenoh_user: c.user.clone().zip(c.password_file.clone()),
        baseline: c.baseline,
    };
    let runtime = tokio::runtime::Runtime::new().context("starting the async runtime")?;
    runtime.block_on(async move {
        let shutdown = tokio_util::sync::CancellationToken::new();
        let console = ris_console::start(options, shutdown.clone()).await?;
        eprintln!("ris console: http://{}/", console.addr);
        let stop = shutdown.clone();
        tokio::spawn(async move {
            let mut term =
                match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
                    Ok(t) => t,
                    Err(_) => return,
                };
            tokio::select! {
                _ = tokio::signal::ctrl_c() => {}
                _ = term.recv() => {}
            }
            stop.cancel();
        });
        console.wait().await
    })
}
