//! The station: `ris console`, a web console for one cell or a plant of cells. It joins the
//! Zenoh fabric the cells already use (as a client of a peer risd or of a router), finds every
//! cell by its health token, shows each cell's state and each scan's progress as it happens,
//! lets operators start scans, keeps every result's characteristics in its own history
//! (SQLite) so trends outlive the cells' retention, charts them with control limits and run
//! rules, raises alarms (on the page and on `ris/<cell>/alarms`) and exports CSV and AQDEF.
//! risd itself serves no HTTP.

pub mod auth;
pub mod characteristic;
pub mod export;
pub mod fabric;
pub mod history;
pub mod pages;
pub mod spc;
pub mod web;

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{anyhow, bail, Context, Result};
use tokio_util::sync::CancellationToken;

use crate::auth::Auth;
use crate::fabric::Fabric;
use crate::history::History;

/// How the console runs.
#[derive(Clone, Debug)]
pub struct Options {
    /// Zenoh endpoints to connect to (a risd, or a router of a line of cells).
    pub connect: Vec<String>,
    /// Where the web console listens.
    pub http: SocketAddr,
    /// The history database (created when missing).
    pub db: PathBuf,
    /// A cell configuration whose `[zenoh.access]` users and roles sign in (none: everyone is
    /// an operator, on loopback only).
    pub access: Option<PathBuf>,
    /// The console's own Zenoh login (user, file whose first line is the password) for cells
    /// with access control.
    pub zenoh_user: Option<(String, PathBuf)>,
    /// Scans of each part whose values set the control limits.
    pub baseline: usize,
}

/// A running console.
pub struct Console {
    /// The address it serves on (the port chosen when `http` asked for port 0).
    pub addr: SocketAddr,
    /// Its fabric and history.
    pub fabric: Arc<Fabric>,
    tasks: tokio::task::JoinSet<Result<()>>,
}

impl Console {
    /// Wait until the console stops (its shutdown token, or a failure).
    pub async fn wait(mut self) -> Result<()> {
        while let Some(r) = self.tasks.join_next().await {
            r.map_err(|e| anyhow!("a console task ended abnormally: {e}"))??;
        }
        Ok(())
    }
}

/// Start the console: open the history, join the fabric, serve HTTP; everything stops when
/// `shutdown` is cancelled.
pub async fn start(options: Options, shutdown: CancellationToken) -> Result<Console> {
    let auth = match &options.access {
        Some(path) => Auth::from_cell_config(path)?,
        None => {
            if !options.http.ip().is_loopback() {
                bail!(
                    "--http {}: without --access (users and roles) the console serves loopback only; give --access CELL.toml or --http 127.0.0.1:PORT",
                    options.http
                );
            }
            Auth::open()
        }
    };
    if let Some(dir) = options.db.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("--db: creating {}", dir.display()))?;
    }
    let history = Arc::new(History::open(&options.db)?);
    // A peer that listens nowhere: it opens whether or not the cells (or the router) answer
    // yet, and links up with them whenever they do.
    let config = ris_daemon::client::login("peer", &options.connect, options.zenoh_user.as_ref())?;
    let session = zenoh::open(config).await.map_err(|e| {
        anyhow!(
            "cannot join the fabric at {}: {}",
            options.connect.join(", "),
            ris_daemon::service::plain(&e.to_string())
        )
    })?;
    let fabric = Fabric::new(session, history, options.baseline);
    let listener = tokio::net::TcpListener::bind(options.http)
        .await
        .with_context(|| format!("--http {}: cannot listen (in use?)", options.http))?;
    let addr = listener.local_addr()?;
    let app = Arc::new(web::App {
        fabric: fabric.clone(),
        auth,
        shutdown: shutdown.clone(),
    });
    let mut tasks = tokio::task::JoinSet::new();
    let f = fabric.clone();
    let s = shutdown.clone();
    tasks.spawn(async move { f.run(s).await });
    let s = shutdown.clone();
    tasks.spawn(async move {
        axum::serve(listener, web::router(app))
            .with_graceful_shutdown(async move { s.cancelled().await })
            .await
            .context("serving HTTP")
    });
    tracing::info!(%addr, db = %options.db.display(), "console serving");
    Ok(Console {
        addr,
        fabric,
        tasks,
    })
}
