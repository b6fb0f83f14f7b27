//! `ris verify --cell …`: a running cell's verification session over Zenoh — open it, scan
//! each artefact position (`mode: verify`), finish it into the certificates risd stores and
//! publishes; a quick check in one command; the session's status and the cell's history.

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{anyhow, bail, Context, Result};
use serde::de::DeserializeOwned;
use serde::Serialize;

use ris_core::verify::Status;
use ris_daemon::protocol::{
    verify_key, Artefact, HistoryEntry, ScanMode, VerificationHealth, VerificationItem,
    VerificationSummary, VerifyAction, VerifyKind, VerifyPosition, VerifyRequest,
};

use super::client::DaemonArgs;
use super::verify::{exit_code, word};

/// How `ris verify` drives a running cell's verification.
#[derive(Clone, Debug, clap::Args)]
pub struct SessionArgs {
    /// How to reach the daemon.
    #[command(flatten)]
    pub daemon: DaemonArgs,
    /// Open an acceptance test on the cell.
    #[arg(long)]
    pub start: bool,
    /// Scan one artefact position into the open session (opening an acceptance test when
    /// none is open): `ball_bar:bar-1`, `sphere:sphere-3`, `plane:flat-2`.
    #[arg(long, value_name = "ARTEFACT:POSITION")]
    pub measure: Option<String>,
    /// A quick check between tests: open a check, scan this one position, finish it.
    #[arg(long, value_name = "ARTEFACT:POSITION")]
    pub check: Option<String>,
    /// Finish the open session: its certificates, verdict and drift warnings.
    #[arg(long)]
    pub finish: bool,
    /// Drop the open session.
    #[arg(long)]
    pub abort: bool,
    /// The open session, the last verification and what health warns about.
    #[arg(long)]
    pub status: bool,
    /// Every stored verification's worst figures per scope, oldest first.
    #[arg(long)]
    pub history: bool,
    /// With --history: only this scope (a sensor, or `merged`).
    #[arg(long, requires = "history")]
    pub scope: Option<String>,
    /// Give up on a scan that has not finished after this many seconds.
    #[arg(long, default_value_t = 300)]
    pub timeout_s: u64,
}

/// What the command line asks of the cell.
#[derive(Clone, Debug, PartialEq)]
pub enum Action {
    /// Open an acceptance test.
    Start,
    /// Scan one position.
    Measure(Artefact, String),
    /// Open a check, scan one position, finish.
    Check(Artefact, String),
    /// Finish the open session.
    Finish,
    /// Drop the open session.
    Abort,
    /// Report.
    Status,
    /// The history.
    History,
}

impl SessionArgs {
    /// The one action asked (`None`: none, the clouds are evaluated here).
    pub fn action(&self) -> Result<Option<Action>> {
        let mut asked = Vec::new();
        if self.start {
            asked.push(Action::Start);
        }
        if let Some(m) = &self.measure {
            let (a, p) = artefact_position("--measure", m)?;
            asked.push(Action::Measure(a, p));
        }
        if let Some(m) = &self.check {
            let (a, p) = artefact_position("--check", m)?;
            asked.push(Action::Check(a, p));
        }
        if self.finish {
            asked.push(Action::Finish);
        }
        if self.abort {
            asked.push(Action::Abort);
        }
        if self.status {
            asked.push(Action::Status);
        }
        if self.history {
            asked.push(Action::History);
        }
        if asked.len() > 1 {
            bail!("give one of --start, --measure, --check, --finish, --abort, --status and --history at a time");
        }
        Ok(asked.pop())
    }
}

/// `ball_bar:bar-1` → (artefact, position).
fn artefact_position(flag: &str, text: &str) -> Result<(Artefact, String)> {
    let (a, p) = text.split_once(':').ok_or_else(|| {
        anyhow!("{flag} {text:?}: give ARTEFACT:POSITION, such as ball_bar:bar-1")
    })?;
    let artefact = match a {
        "ball_bar" | "ball-bar" => Artefact::BallBar,
        "sphere" => Artefact::Sphere,
        "plane" => Artefact::Plane,
        _ => bail!("{flag} {text:?}: the artefact is ball_bar, sphere or plane"),
    };
    Ok((artefact, p.to_string()))
}

/// Run `action` on the cell; the exit status of a finished session's (or a measured
/// position's) verdict.
pub fn run(args: &SessionArgs, action: &Action, out: Option<&Path>) -> Result<Option<i32>> {
    let cell = &args.daemon.cell;
    match action {
        Action::Start => {
            let s: VerificationSummary = ask(args, VerifyAction::Start, VerifyKind::Acceptance)?;
            println!(
                "verification {} opened on cell {cell} (acceptance test): scan each position with --measure ARTEFACT:POSITION, then --finish",
                s.id
            );
            Ok(None)
        }
        Action::Measure(a, p) => {
            let position = measure(args, *a, p, out)?;
            print_position(&position);
            let statuses = position.scopes.values().flatten().map(|f| f.status);
            Ok(exit_code(ris_core::verify::verdict(statuses)).filter(|&c| c == 3))
        }
        Action::Check(a, p) => {
            let s: VerificationSummary = ask(args, VerifyAction::Start, VerifyKind::Check)?;
            println!("quick check {} opened on cell {cell}", s.id);
            let measured = measure(args, *a, p, None);
            let position = match measured {
                Ok(p) => p,
                Err(e) => {
                    // A check that could not scan is not left open.
                    let _ =
                        ask::<VerificationSummary>(args, VerifyAction::Abort, VerifyKind::Check);
                    return Err(e);
                }
            };
            print_position(&position);
            finish(args, out)
        }
        Action::Finish => finish(args, out),
        Action::Abort => {
            let s: VerificationSummary = ask(args, VerifyAction::Abort, VerifyKind::Acceptance)?;
            println!(
                "verification {} aborted ({} positions dropped)",
                s.id, s.positions
            );
            Ok(None)
        }
        Action::Status => {
            let h: VerificationHealth = ask(args, VerifyAction::Status, VerifyKind::Acceptance)?;
            match &h.last {
                Some(l) => println!(
                    "last verification: {} ({:?}, {}): {}{}",
                    l.id,
                    l.kind,
                    l.finished.as_deref().unwrap_or("?"),
                    l.verdict.map_or("?", word),
                    h.age_days
                        .map(|d| format!(", {d:.1} days ago"))
                        .unwrap_or_default()
                ),
                None => println!("no verification on record"),
            }
            if let Some(o) = &h.open {
                println!(
                    "open: {} ({:?}, since {}), {} positions",
                    o.id, o.kind, o.started, o.positions
                );
            }
            for w in &h.warnings {
                println!("warning: {w}");
            }
            Ok(None)
        }
        Action::History => {
            let entries: Vec<HistoryEntry> =
                ask(args, VerifyAction::History, VerifyKind::Acceptance)?;
            let mut shown = 0;
            println!(
                "{:<26} {:<10} {:<8} {:<12} {:>17} {:>17} {:>17} {:>17}",
                "verification", "kind", "scope", "verdict", "SD mm (%MPE)", "PF", "PS", "F"
            );
            for e in entries
                .iter()
                .filter(|e| args.scope.as_ref().is_none_or(|s| *s == e.scope))
            {
                let cell = |k: &str| {
                    e.worst
                        .get(k)
                        .map(|w| format!("{:+.3} ({:>3.0} %)", w.error, 100.0 * w.share))
                        .unwrap_or_else(|| "—".into())
                };
                println!(
                    "{:<26} {:<10} {:<8} {:<12} {:>17} {:>17} {:>17} {:>17}",
                    e.id,
                    format!("{:?}", e.kind).to_lowercase(),
                    e.scope,
                    word(e.verdict),
                    cell("SD"),
                    cell("PF"),
                    cell("PS"),
                    cell("F")
                );
                shown += 1;
            }
            if shown == 0 {
                println!(
                    "no stored verification{}",
                    args.scope
                        .as_ref()
                        .map(|s| format!(" of scope {s}"))
                        .unwrap_or_default()
                );
            }
            Ok(None)
        }
    }
}

/// Scan one position (`mode: verify`) and return its figures; the clouds go to `out` when
/// given.
fn measure(
    args: &SessionArgs,
    artefact: Artefact,
    position: &str,
    out: Option<&Path>,
) -> Result<VerifyPosition> {
    // Without --out the clouds are only passed through (risd keeps them in its store).
    let scratch = std::env::temp_dir().join(format!("ris-verify-{}", std::process::id()));
    let dir = out.map_or_else(|| scratch.clone(), Path::to_path_buf);
    let got = super::scan::run(&super::scan::ScanArgs {
        connect: args.daemon.connect.clone(),
        cell: args.daemon.cell.clone(),
        mode: Some(ScanMode::Verify),
        sensors: Vec::new(),
        inspect: None,
        part: None,
        tag: None,
        serial: None,
        verify: Some((artefact, position.to_string())),
        out: dir,
        timeout: Duration::from_secs(args.timeout_s),
        credentials: credentials(args),
    });
    if out.is_none() {
        let _ = std::fs::remove_dir_all(&scratch);
    }
    let got = got?;
    serde_json::from_value(got.done["verification"].clone()).with_context(|| {
        format!(
            "scan {} ended without the position's figures (a risd of another version?)",
            got.scan_id
        )
    })
}

/// Finish the open session, print it and fetch its certificate and page into `out`.
fn finish(args: &SessionArgs, out: Option<&Path>) -> Result<Option<i32>> {
    let s: VerificationSummary = ask(args, VerifyAction::Finish, VerifyKind::Acceptance)?;
    println!(
        "verification {} ({:?}, {} position{}) finished {}",
        s.id,
        s.kind,
        s.positions,
        if s.positions == 1 { "" } else { "s" },
        s.finished.as_deref().unwrap_or("")
    );
    for (scope, v) in &s.scopes {
        println!("  {scope:<8} {}", word(*v));
    }
    for w in &s.warnings {
        println!("warning: {w}");
    }
    let verdict = s.verdict.unwrap_or(Status::NotMeasured);
    println!("verification: {}", word(verdict));
    if let Some(out) = out {
        let cell = &args.daemon.cell;
        let creds = credentials(args);
        let (certificate, page) = runtime()?.block_on(async {
            let session = super::client::open(&args.daemon.connect, creds.as_ref()).await?;
            let got = async {
                let c = VerificationItem::Certificate.key(cell, &s.id);
                let p = VerificationItem::Page.key(cell, &s.id);
                Ok::<_, anyhow::Error>((
                    super::client::fetch(&session, &c).await?,
                    super::client::fetch(&session, &p).await?,
                ))
            }
            .await;
            let _ = session.close().await;
            got
        })?;
        ris_core::io::write_dir_atomically(out, |dir| {
            ris_core::io::create_dir(dir)?;
            ris_core::io::write_atomic(&dir.join("certificate.json"), &certificate)?;
            ris_core::io::write_atomic(&dir.join("verify.html"), &page)
        })
        .with_context(|| format!("writing {}", out.display()))?;
        println!("wrote {}", out.display());
    }
    Ok(exit_code(verdict))
}

fn credentials(args: &SessionArgs) -> Option<(String, PathBuf)> {
    args.daemon
        .user
        .clone()
        .zip(args.daemon.password_file.clone())
}

fn runtime() -> Result<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("starting the async runtime")
}

/// Ask `ris/<cell>/verify` for `action`.
fn ask<Rep: DeserializeOwned>(
    args: &SessionArgs,
    action: VerifyAction,
    kind: VerifyKind,
) -> Result<Rep> {
    let request = VerifyRequest { action, kind };
    query(args, &verify_key(&args.daemon.cell), &request)
}

fn query<Req: Serialize, Rep: DeserializeOwned>(
    args: &SessionArgs,
    key: &str,
    body: &Req,
) -> Result<Rep> {
    let creds = credentials(args);
    runtime()?.block_on(async {
        let session = super::client::open(&args.daemon.connect, creds.as_ref()).await?;
        let reply = super::client::ask(&session, key, body).await;
        let _ = session.close().await;
        reply
    })
}

fn print_position(p: &VerifyPosition) {
    for (scope, figures) in &p.scopes {
        for (k, f) in figures.iter().enumerate() {
            let symbol = match (p.artefact, k) {
                (Artefact::BallBar, _) => "SD",
                (Artefact::Plane, _) => "F ",
                (Artefact::Sphere, 0) => "PF",
                (Artefact::Sphere, _) => "PS",
            };
            match (f.error, &f.reason) {
                (Some(e), _) => println!(
                    "{scope:<8} {symbol} {:<12} {e:>+9.4} mm  MPE {:.4} mm  {}",
                    p.position,
                    f.mpe,
                    word(f.status)
                ),
                (None, r) => println!(
                    "{scope:<8} {symbol} {:<12} NOT MEASURED: {}",
                    p.position,
                    r.as_deref().unwrap_or("")
                ),
            }
        }
    }
}
