//! The `risd` service (SPEC §12): a Zenoh session serving scan requests for the cell, publishing
//! every stage of each scan, its clouds as binary PLY and the stored results, with a liveliness
//! token and a status for health. Modelled on mini-redis: [`run`] takes its stop signal as an
//! argument; scans run one at a time on a worker thread fed by a bounded queue.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc, Mutex};

use anyhow::{anyhow, Context, Result};
use serde::{Deserialize, Serialize};
use tokio_util::sync::CancellationToken;
use zenoh::qos::CongestionControl;
use zenoh::query::Query;
use zenoh::{Session, Wait};

use crate::config::CellConfig;
use crate::notify;
use crate::scan::{self, Pair, Part, ScanOptions, ScanState};

/// A scan request (`ris/<cell>/scan` payload; every field optional).
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScanRequest {
    /// `gray` (default); `adaptive` and `single-shot` are refused by this build.
    #[serde(default)]
    pub mode: Option<String>,
    /// Sensors to scan (default all).
    #[serde(default)]
    pub sensors: Option<Vec<String>>,
    /// Inspect the merged cloud (default: when the cell defines exactly one part, or `part`
    /// names one).
    #[serde(default)]
    pub inspect: Option<bool>,
    /// Part id (required to inspect when the cell defines several).
    #[serde(default)]
    pub part: Option<String>,
    /// Free text stored with the scan.
    #[serde(default)]
    pub tag: Option<String>,
}

/// What `ris/<cell>/health` answers.
#[derive(Clone, Debug, Serialize)]
pub struct Status {
    /// `preparing`, `ready`, `scanning` or `stopping`.
    pub state: String,
    /// Sensors of the cell.
    pub sensors: Vec<String>,
    /// Scans waiting.
    pub queue: usize,
    /// Last finished scan id.
    pub last_scan: Option<String>,
    /// Last failure.
    pub last_error: Option<String>,
}

struct Job {
    scan_id: String,
    sensors: Option<Vec<String>>,
    /// Index of the part to inspect.
    part: Option<usize>,
}

/// Validate a request against the cell and choose the part to inspect (an index into the
/// cell's parts); the error is the reply's reason.
pub fn validate(req: &ScanRequest, config: &CellConfig) -> Result<Option<usize>, String> {
    match req.mode.as_deref() {
        None | Some("gray") => {}
        Some(m @ ("adaptive" | "single-shot")) => {
            return Err(format!(
                "mode {m:?} is not available in this risd build; use \"gray\""
            ))
        }
        Some(m) => return Err(format!("unknown mode {m:?} (gray, adaptive, single-shot)")),
    }
    if let Some(list) = &req.sensors {
        if list.is_empty() {
            return Err("`sensors` is empty".into());
        }
        for s in list {
            if !config.sensors.iter().any(|c| c.name == *s) {
                return Err(format!("no sensor {s:?} in cell {:?}", config.name));
            }
        }
    }
    let named = match &req.part {
        Some(p) => Some(
            config
                .parts
                .iter()
                .position(|c| c.id == *p)
                .ok_or_else(|| format!("no part {p:?} in cell {:?}", config.name))?,
        ),
        None => None,
    };
    match (req.inspect, named, config.parts.len()) {
        (Some(false), Some(_), _) => Err("`part` is named but `inspect` is false".into()),
        (Some(false), None, _) => Ok(None),
        (_, Some(i), _) => Ok(Some(i)),
        (_, None, 1) => Ok(Some(0)),
        (Some(true), None, 0) => Err(format!("cell {:?} defines no part to inspect", config.name)),
        (Some(true), None, n) => Err(format!(
            "cell {:?} defines {n} parts; name one in `part`",
            config.name
        )),
        (None, None, _) => Ok(None),
    }
}

/// A Zenoh configuration of `mode` (`peer` or `client`) with these endpoints and no multicast
/// scouting: RIS talks to the endpoints it is given, nothing else.
pub fn zenoh_config(mode: &str, listen: &[String], connect: &[String]) -> Result<zenoh::Config> {
    let mut c = zenoh::Config::default();
    for (key, value) in [
        ("mode", serde_json::to_string(mode)?),
        ("listen/endpoints", serde_json::to_string(listen)?),
        ("connect/endpoints", serde_json::to_string(connect)?),
        ("scouting/multicast/enabled", "false".to_string()),
    ] {
        c.insert_json5(key, &value)
            .map_err(|e| anyhow!("zenoh config {key} = {value}: {e}"))?;
    }
    Ok(c)
}

/// Serve the cell until `shutdown` is cancelled; then stop accepting, let the running scan
/// end (finished, or failed at the next exposure group), and close.
pub async fn run(config: CellConfig, shutdown: CancellationToken) -> Result<()> {
    let cell = config.name.clone();
    let data_dir = config.storage.data_dir.clone();
    std::fs::create_dir_all(&data_dir)
        .with_context(|| format!("creating the data directory {}", data_dir.display()))?;
    for name in scan::housekeeping(
        &data_dir,
        config.storage.keep_scans,
        config.storage.max_age_days,
    )? {
        tracing::info!(scan = %name, "removed");
    }
    let z = &config.zenoh;
    let session = zenoh::open(zenoh_config(&z.mode, &z.listen, &z.connect)?)
        .await
        .map_err(|e| anyhow!("opening the Zenoh session: {e}"))?;
    let status = Arc::new(Mutex::new(Status {
        state: "preparing".into(),
        sensors: config.sensors.iter().map(|s| s.name.clone()).collect(),
        queue: 0,
        last_scan: None,
        last_error: None,
    }));
    let token = session
        .liveliness()
        .declare_token(format!("ris/{cell}/health"))
        .await
        .map_err(|e| anyhow!("declaring the liveliness token: {e}"))?;
    let health = session
        .declare_queryable(format!("ris/{cell}/health"))
        .await
        .map_err(|e| anyhow!("declaring ris/{cell}/health: {e}"))?;

    let prep_config = config.clone();
    let (pairs, parts) = tokio::task::spawn_blocking(move || -> Result<_> {
        let parts = prep_config
            .parts
            .iter()
            .map(Part::prepare)
            .collect::<Result<Vec<_>>>()?;
        Ok((scan::prepare(&prep_config, 1)?, parts))
    })
    .await
    .context("preparing the pairs")??;
    set_state(&status, "ready");

    let (tx, rx) = mpsc::sync_channel::<Job>(config.workers.queue);
    let stopping = Arc::new(AtomicBool::new(false));
    let worker = {
        let (session, status, stopping, cell, data_dir) = (
            session.clone(),
            status.clone(),
            stopping.clone(),
            cell.clone(),
            data_dir.clone(),
        );
        let keep = config.storage.keep_captures;
        std::thread::spawn(move || {
            worker_loop(
                rx, pairs, &parts, &session, &status, &stopping, &cell, &data_dir, keep,
            )
        })
    };
    let scan_q = session
        .declare_queryable(format!("ris/{cell}/scan"))
        .await
        .map_err(|e| anyhow!("declaring ris/{cell}/scan: {e}"))?;
    let store_q = session
        .declare_queryable(format!("ris/{cell}/scans/**"))
        .await
        .map_err(|e| anyhow!("declaring ris/{cell}/scans/**: {e}"))?;
    notify::notify("READY=1");
    tracing::info!(%cell, zid = %session.zid(), "risd ready");
    let watchdog = notify::watchdog_interval().map(|every| {
        let stop = shutdown.clone();
        tokio::spawn(async move {
            let mut tick = tokio::time::interval(every);
            loop {
                tokio::select! {
                    _ = stop.cancelled() => break,
                    _ = tick.tick() => notify::notify("WATCHDOG=1"),
                }
            }
        })
    });
    let mut counter = 0u64;
    loop {
        tokio::select! {
            _ = shutdown.cancelled() => break,
            q = scan_q.recv_async() => {
                let Ok(q) = q else { break };
                counter += 1;
                handle_scan(&q, &config, &tx, &status, &session, counter).await;
            }
            q = store_q.recv_async() => {
                let Ok(q) = q else { break };
                handle_store(&q, &cell, &data_dir).await;
            }
            q = health.recv_async() => {
                let Ok(q) = q else { break };
                let json = status.lock().map(|s| serde_json::to_string(&*s).unwrap_or_default()).unwrap_or_default();
                if let Err(e) = q.reply(q.key_expr().clone(), json).await {
                    tracing::warn!(error = %e, "health reply failed");
                }
            }
        }
    }
    notify::notify("STOPPING=1");
    tracing::info!("stopping: no new scans; ending the running one");
    set_state(&status, "stopping");
    drop(scan_q);
    stopping.store(true, Ordering::SeqCst);
    drop(tx);
    tokio::task::spawn_blocking(move || worker.join())
        .await
        .context("joining the scan worker")?
        .map_err(|_| anyhow!("the scan worker panicked"))?;
    if let Some(w) = watchdog {
        w.abort();
    }
    drop(store_q);
    drop(health);
    drop(token);
    session
        .close()
        .await
        .map_err(|e| anyhow!("closing the Zenoh session: {e}"))?;
    tracing::info!("risd stopped");
    Ok(())
}

fn set_state(status: &Mutex<Status>, state: &str) {
    if let Ok(mut s) = status.lock() {
        s.state = state.into();
    }
}

async fn handle_scan(
    q: &Query,
    config: &CellConfig,
    tx: &mpsc::SyncSender<Job>,
    status: &Mutex<Status>,
    session: &Session,
    counter: u64,
) {
    let req: Result<ScanRequest, String> = match q.payload() {
        None => Ok(ScanRequest::default()),
        Some(p) if p.is_empty() => Ok(ScanRequest::default()),
        Some(p) => {
            serde_json::from_slice(&p.to_bytes()).map_err(|e| format!("malformed request: {e}"))
        }
    };
    let outcome = req
        .and_then(|r| validate(&r, config).map(|part| (r, part)))
        .and_then(|(r, part)| {
            let scan_id = scan::new_scan_id(counter);
            match tx.try_send(Job {
                scan_id: scan_id.clone(),
                sensors: r.sensors.clone(),
                part,
            }) {
                Ok(()) => Ok((scan_id, r)),
                Err(mpsc::TrySendError::Full(_)) => Err(format!(
                    "the scan queue is full ({} waiting); try again later",
                    config.workers.queue
                )),
                Err(mpsc::TrySendError::Disconnected(_)) => Err("risd is stopping".into()),
            }
        });
    match outcome {
        Ok((scan_id, r)) => {
            if let Ok(mut s) = status.lock() {
                s.queue += 1;
            }
            tracing::info!(%scan_id, tag = ?r.tag, "scan accepted");
            publish(session, &config.name, &scan_id, &ScanState::Queued);
            let reply = serde_json::json!({"scan_id": scan_id, "state": "accepted"}).to_string();
            if let Err(e) = q.reply(q.key_expr().clone(), reply).await {
                tracing::warn!(error = %e, "scan reply failed");
            }
        }
        Err(reason) => {
            tracing::warn!(%reason, "scan refused");
            let reply = serde_json::json!({"error": reason}).to_string();
            if let Err(e) = q.reply_err(reply).await {
                tracing::warn!(error = %e, "scan error reply failed");
            }
        }
    }
}

fn publish(session: &Session, cell: &str, scan_id: &str, state: &ScanState) {
    let key = format!("ris/{cell}/scans/{scan_id}/state");
    let json = serde_json::to_string(state).unwrap_or_default();
    if let Err(e) = session.put(&key, json).wait() {
        tracing::warn!(%key, error = %e, "state publication failed");
    }
}

#[allow(clippy::too_many_arguments)]
fn worker_loop(
    rx: mpsc::Receiver<Job>,
    mut pairs: Vec<Pair>,
    parts: &[Part],
    session: &Session,
    status: &Mutex<Status>,
    stopping: &AtomicBool,
    cell: &str,
    data_dir: &Path,
    keep_captures: bool,
) {
    for job in rx {
        if let Ok(mut s) = status.lock() {
            s.queue = s.queue.saturating_sub(1);
            s.state = "scanning".into();
        }
        let id = job.scan_id;
        if stopping.load(Ordering::SeqCst) {
            publish(
                session,
                cell,
                &id,
                &ScanState::Failed {
                    reason: "risd is stopping".into(),
                },
            );
            continue;
        }
        let options = ScanOptions {
            only: job.sensors.as_deref(),
            keep_captures,
            part: job.part.and_then(|i| parts.get(i)),
        };
        let result = scan::run(
            cell,
            &mut pairs,
            options,
            data_dir,
            &id,
            &|| stopping.load(Ordering::SeqCst),
            &|s| {
                if !matches!(s, ScanState::Done) {
                    publish(session, cell, &id, s);
                }
            },
        );
        match result {
            Ok((report, dir)) => {
                let mut names: Vec<String> =
                    report.sensors.iter().map(|s| s.sensor.clone()).collect();
                names.push("merged".into());
                for name in names {
                    publish_file(
                        session,
                        &format!("ris/{cell}/scans/{id}/cloud/{name}"),
                        &dir.join(format!("{name}.ply")),
                    );
                }
                if report.inspection.is_some() {
                    publish_file(
                        session,
                        &format!("ris/{cell}/scans/{id}/report"),
                        &dir.join("report.json"),
                    );
                }
                let done = serde_json::json!({
                    "state": "done",
                    "merged_points": report.merged_points,
                    "compute_after_last_frame": report.compute_after_last_frame,
                    "sensors": report.sensors,
                    "merge": report.merge,
                    "inspection": report.inspection,
                    "total": report.total,
                });
                let key = format!("ris/{cell}/scans/{id}/state");
                if let Err(e) = session.put(&key, done.to_string()).wait() {
                    tracing::warn!(%key, error = %e, "state publication failed");
                }
                if let Ok(mut s) = status.lock() {
                    s.last_scan = Some(id.clone());
                }
                tracing::info!(scan = %id, points = report.merged_points, "scan done");
            }
            Err(e) => {
                tracing::warn!(scan = %id, error = %format!("{e:#}"), "scan failed");
                if let Ok(mut s) = status.lock() {
                    s.last_error = Some(format!("{id}: {e:#}"));
                }
            }
        }
        if let Ok(mut s) = status.lock() {
            if s.state == "scanning" {
                s.state = "ready".into();
            }
        }
    }
}

/// Publish a result file of a scan (large payloads block rather than drop).
fn publish_file(session: &Session, key: &str, path: &Path) {
    match std::fs::read(path) {
        Ok(bytes) => {
            if let Err(e) = session
                .put(key, bytes)
                .congestion_control(CongestionControl::Block)
                .wait()
            {
                tracing::warn!(%key, error = %e, "publication failed");
            }
        }
        Err(e) => tracing::warn!(path = %path.display(), error = %e, "result file unreadable"),
    }
}

/// The stored results of finished scans: (key, file) for `<id>/report` (the scan's JSON) and
/// `<id>/cloud/<sensor>`, and the ids. Blocking directory walk: run off the async runtime.
fn stored_items(cell: &str, data_dir: &Path) -> (Vec<String>, Vec<(String, PathBuf)>) {
    let mut ids = Vec::new();
    let mut items = Vec::new();
    let Ok(entries) = std::fs::read_dir(data_dir.join("scans")) else {
        return (ids, items);
    };
    for e in entries.flatten() {
        let id = e.file_name().to_string_lossy().into_owned();
        let dir: PathBuf = e.path();
        if id.ends_with(".partial") || !dir.join("scan.json").is_file() {
            continue;
        }
        // The inspection report when the scan inspected a part, else the scan's summary.
        let report = Some(dir.join("report.json"))
            .filter(|p| p.is_file())
            .unwrap_or_else(|| dir.join("scan.json"));
        items.push((format!("ris/{cell}/scans/{id}/report"), report));
        if let Ok(files) = std::fs::read_dir(&dir) {
            for f in files.flatten() {
                let name = f.file_name().to_string_lossy().into_owned();
                if let Some(sensor) = name.strip_suffix(".ply") {
                    items.push((format!("ris/{cell}/scans/{id}/cloud/{sensor}"), f.path()));
                }
            }
        }
        ids.push(id);
    }
    (ids, items)
}

/// Answer `ris/<cell>/scans/**` from the finished scans on disk: `<id>/state`, `<id>/report`
/// and `<id>/cloud/<sensor>`, for every key the query matches.
async fn handle_store(q: &Query, cell: &str, data_dir: &Path) {
    let (c, d) = (cell.to_string(), data_dir.to_path_buf());
    let Ok((ids, items)) = tokio::task::spawn_blocking(move || stored_items(&c, &d)).await else {
        return;
    };
    let asked = q.key_expr().clone();
    let matching = |key: &str| {
        zenoh::key_expr::KeyExpr::try_from(key.to_string())
            .ok()
            .filter(|k| asked.intersects(k))
    };
    for id in ids {
        if let Some(k) = matching(&format!("ris/{cell}/scans/{id}/state")) {
            let _ = q.reply(k, r#"{"state":"done"}"#).await;
        }
    }
    for (key, path) in items {
        let Some(k) = matching(&key) else {
            continue;
        };
        match tokio::fs::read(&path).await {
            // Replies follow the query's congestion control.
            Ok(bytes) => {
                if let Err(err) = q.reply(k, bytes).await {
                    tracing::warn!(%key, error = %err, "stored reply failed");
                }
            }
            Err(err) => {
                tracing::warn!(path = %path.display(), error = %err, "stored file unreadable")
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cell(parts: &[&str]) -> CellConfig {
        let mut text = String::from(
            "[cell]\nname = \"t\"\n[[sensor]]\nname = \"s1\"\nbackend = \"mock\"\nscene = \"s.toml\"\n",
        );
        for p in parts {
            text += &format!("[[part]]\nid = \"{p}\"\ncad = \"{p}.stl\"\ntolerance = 0.5\n");
        }
        CellConfig::parse(&text, Path::new("."), "test").expect("config")
    }

    fn req(json: &str) -> ScanRequest {
        serde_json::from_str(json).expect("request")
    }

    #[test]
    fn the_part_to_inspect_follows_the_request_and_the_cell() {
        let none = cell(&[]);
        let one = cell(&["door"]);
        let two = cell(&["door", "hood"]);
        assert_eq!(validate(&req("{}"), &none), Ok(None));
        assert_eq!(validate(&req("{}"), &one), Ok(Some(0)));
        assert_eq!(validate(&req("{}"), &two), Ok(None));
        assert_eq!(validate(&req(r#"{"inspect": false}"#), &one), Ok(None));
        assert_eq!(validate(&req(r#"{"part": "hood"}"#), &two), Ok(Some(1)));
        let err = |r: &str, c: &CellConfig| validate(&req(r), c).expect_err(r);
        assert!(err(r#"{"inspect": true}"#, &none).contains("no part"));
        assert!(err(r#"{"inspect": true}"#, &two).contains("name one"));
        assert!(err(r#"{"part": "roof"}"#, &two).contains("\"roof\""));
        assert!(err(r#"{"part": "door", "inspect": false}"#, &two).contains("inspect"));
        assert!(err(r#"{"mode": "fast"}"#, &one).contains("fast"));
    }
}
