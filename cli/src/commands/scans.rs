//! `ris scans`: a running cell's stored scans from a terminal, as the station shows them:
//! `list` (id, time, part, serial, verdict), `get ID` (its summary and report), `fetch ID --out
//! DIR` (every stored item: clouds, report, summary, deviation cloud, map, page).

use std::path::PathBuf;

use anyhow::{anyhow, bail, Context, Result};
use ris_daemon::protocol::{ScanItem, ScanState};
use serde_json::Value;

/// `ris scans`.
#[derive(Clone, Debug, clap::Args)]
pub struct ScansCommand {
    /// How to reach the daemon.
    #[command(flatten)]
    pub daemon: super::client::DaemonArgs,
    /// What to do.
    #[command(subcommand)]
    pub action: ScansAction,
}

/// What `ris scans` does.
#[derive(Clone, Debug, clap::Subcommand)]
pub enum ScansAction {
    /// Every stored scan, oldest first: id, time, part, serial, tag, verdict.
    List {
        /// JSON lines (each scan's summary) instead of a table.
        #[arg(long)]
        json: bool,
    },
    /// One scan's summary and (when inspected) its report, as JSON.
    Get {
        /// Scan id.
        id: String,
    },
    /// Every stored item of one scan into OUT/ID/ (clouds, report.json, scan.json,
    /// deviation.ply, deviation.png, report.html).
    Fetch {
        /// Scan id.
        id: String,
        /// Output directory.
        #[arg(long)]
        out: PathBuf,
    },
}

/// A summary's fields as the table shows them.
fn row(id: &str, s: &Value) -> String {
    let text = |v: &Value| v.as_str().unwrap_or("").to_string();
    let verdict = match s["inspection"]["verdict"].as_str() {
        Some("pass") => "PASS",
        Some("fail") => "FAIL",
        Some("not_measured") => "NOT MEASURED",
        _ => "-",
    };
    format!(
        "{id:<26} {:<12} {:<14} {:<20} {verdict}",
        text(&s["inspection"]["part"]),
        text(&s["serial"]),
        text(&s["tag"]).chars().take(20).collect::<String>(),
    )
}

/// Run `ris scans`.
pub fn command(c: &ScansCommand) -> Result<()> {
    let runtime = tokio::runtime::Runtime::new().context("starting the async runtime")?;
    runtime.block_on(run(c))
}

async fn run(c: &ScansCommand) -> Result<()> {
    let credentials = c.daemon.user.clone().zip(c.daemon.password_file.clone());
    let session = super::client::open(&c.daemon.connect, credentials.as_ref()).await?;
    let cell = &c.daemon.cell;
    match &c.action {
        ScansAction::List { json } => {
            let mut ids: Vec<String> =
                super::client::replies(&session, &ris_daemon::protocol::scan_states_key(cell))
                    .await?
                    .into_iter()
                    .filter_map(|(k, v)| {
                        let (_, id, _) = ScanItem::parse(&k)?;
                        (serde_json::from_slice::<ScanState>(&v).ok()? == ScanState::Done)
                            .then_some(id)
                    })
                    .collect();
            ids.sort();
            ids.dedup();
            let summaries =
                super::client::replies(&session, &format!("ris/{cell}/scans/*/summary")).await?;
            if !json {
                println!(
                    "{:<26} {:<12} {:<14} {:<20} verdict",
                    "scan", "part", "serial", "tag"
                );
            }
            for id in &ids {
                let s: Value = summaries
                    .iter()
                    .find(|(k, _)| ScanItem::parse(k).is_some_and(|(_, i, _)| i == *id))
                    .and_then(|(_, v)| serde_json::from_slice(v).ok())
                    .unwrap_or(Value::Null);
                if *json {
                    println!("{}", serde_json::to_string(&s)?);
                } else {
                    println!("{}", row(id, &s));
                }
            }
            if !json {
                println!("{} scans stored by cell {cell}", ids.len());
            }
        }
        ScansAction::Get { id } => {
            let summary = super::client::fetch(&session, &ScanItem::Summary.key(cell, id))
                .await
                .with_context(|| format!("scan {id} of cell {cell}"))?;
            let summary: Value =
                serde_json::from_slice(&summary).context("the summary is not JSON")?;
            let report = if summary["inspection"].is_object() {
                let r = super::client::fetch(&session, &ScanItem::Report.key(cell, id)).await?;
                serde_json::from_slice(&r).context("the report is not JSON")?
            } else {
                Value::Null
            };
            println!(
                "{}",
                serde_json::to_string_pretty(
                    &serde_json::json!({"summary": summary, "report": report})
                )?
            );
        }
        ScansAction::Fetch { id, out } => {
            let items =
                super::client::replies(&session, &format!("ris/{cell}/scans/{id}/**")).await?;
            let mut files: Vec<(String, Vec<u8>)> = Vec::new();
            for (key, bytes) in items {
                let Some((_, got, item)) = ScanItem::parse(&key) else {
                    continue;
                };
                if got != *id {
                    continue;
                }
                let name = match item {
                    ScanItem::Summary => "scan.json".to_string(),
                    ScanItem::Report => "report.json".to_string(),
                    ScanItem::Deviation => "deviation.ply".to_string(),
                    ScanItem::Map => "deviation.png".to_string(),
                    ScanItem::Page => "report.html".to_string(),
                    ScanItem::Cloud(n) if !n.contains(['/', '\\']) && !n.starts_with('.') => {
                        format!("{n}.ply")
                    }
                    _ => continue,
                };
                if !files.iter().any(|(n, _)| *n == name) {
                    files.push((name, bytes));
                }
            }
            let Some(summary) = files.iter().find(|(n, _)| n == "scan.json") else {
                bail!("cell {cell} stores no scan {id} (ris scans list shows the stored ones)");
            };
            // A scan without inspection answers its summary as the report too: no report.json.
            let inspected = serde_json::from_slice::<Value>(&summary.1)
                .is_ok_and(|s| s["inspection"].is_object());
            if !inspected {
                files.retain(|(n, _)| n != "report.json");
            }
            let dir = out.join(id);
            ris_core::io::write_dir_atomically(&dir, |tmp| {
                ris_core::io::create_dir(tmp)?;
                for (name, bytes) in &files {
                    ris_core::io::write_atomic(&tmp.join(name), bytes)?;
                }
                Ok(())
            })
            .with_context(|| format!("writing {}", dir.display()))?;
            println!("wrote {} files into {}", files.len(), dir.display());
        }
    }
    session
        .close()
        .await
        .map_err(|e| anyhow!("closing the Zenoh session: {e}"))?;
    Ok(())
}
