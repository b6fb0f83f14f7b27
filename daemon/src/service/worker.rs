//! The scan worker: one thread taking jobs from the bounded queue, scanning through the cell,
//! publishing every state, cloud and report, and beating the heartbeat the watchdog reads.

use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{mpsc, Mutex};
use std::time::{Duration, Instant};

use zenoh::qos::CongestionControl;
use zenoh::{Session, Wait};

use crate::cell::{Cell, ScanJob};
use anyhow::Context;
use ris_core::cloud::PointCloud;

use crate::protocol::{state_key, Artefact, Health, ScanItem, ScanState, VerifyPosition};
use crate::scan::{self, ScanReport};
use crate::store::{self};
use crate::stream::{self, StreamControl};
use crate::verification::{self, Ledger};

pub(super) struct Job {
    pub(super) scan_id: String,
    pub(super) scan: ScanJob,
}

/// The scan worker's sign of life: milliseconds since `start` at its last beat. The systemd
/// watchdog is fed only while it is recent, so a stuck or dead worker gets risd restarted.
pub(super) struct Heartbeat {
    start: Instant,
    last_ms: AtomicU64,
}

impl Heartbeat {
    pub(super) fn new() -> Heartbeat {
        Heartbeat {
            start: Instant::now(),
            last_ms: AtomicU64::new(0),
        }
    }

    pub(super) fn beat(&self) {
        self.last_ms
            .store(self.start.elapsed().as_millis() as u64, Ordering::Relaxed);
    }

    pub(super) fn age(&self) -> Duration {
        self.start
            .elapsed()
            .saturating_sub(Duration::from_millis(self.last_ms.load(Ordering::Relaxed)))
    }
}

/// Publish a scan's state. States are small and a client follows a scan by them, so they are
/// never dropped: Zenoh's default for a put drops it when the link's queue stays full for a
/// millisecond, which is what it does right after a scan's clouds went out to a slow
/// subscriber, and a client that lost `done` waits for ever.
pub(super) fn publish(session: &Session, cell: &str, scan_id: &str, state: &ScanState) {
    publish_json(
        session,
        cell,
        scan_id,
        serde_json::to_string(state).unwrap_or_default(),
    );
}

/// [`publish`] of a state already written as JSON (`done`, with the scan's figures).
fn publish_json(session: &Session, cell: &str, scan_id: &str, json: String) {
    let key = state_key(cell, scan_id);
    if let Err(e) = session
        .put(&key, json)
        .congestion_control(CongestionControl::Block)
        .wait()
    {
        tracing::warn!(%key, error = %e, "state publication failed");
    }
}

/// [`publish`] from an async handler: the same never-dropped put, awaited instead of blocking
/// the runtime's thread while the link is congested.
pub(super) async fn publish_async(session: &Session, cell: &str, scan_id: &str, state: &ScanState) {
    let key = state_key(cell, scan_id);
    let json = serde_json::to_string(state).unwrap_or_default();
    if let Err(e) = session
        .put(&key, json)
        .congestion_control(CongestionControl::Block)
        .await
    {
        tracing::warn!(%key, error = %e, "state publication failed");
    }
}

/// What the scan worker shares with the service.
pub(super) struct WorkerContext<'a> {
    pub(super) session: &'a Session,
    pub(super) status: &'a Mutex<Health>,
    pub(super) stopping: &'a AtomicBool,
    pub(super) heartbeat: &'a Heartbeat,
    pub(super) cell: &'a str,
    pub(super) data_dir: &'a Path,
    pub(super) storage: &'a crate::config::StorageSection,
    pub(super) ros2: Option<&'a crate::ros2::Bridge>,
    pub(super) streams: &'a StreamControl,
    pub(super) ledger: Option<&'a Mutex<Ledger>>,
}

pub(super) fn worker_loop(rx: mpsc::Receiver<Job>, mut cell: Cell, ctx: &WorkerContext) {
    let report_pairs = |cell: &Cell| {
        if let Ok(mut s) = ctx.status.lock() {
            s.pairs = cell.status();
        }
    };
    report_pairs(&cell);
    loop {
        ctx.heartbeat.beat();
        let wanted = ctx.streams.wanted();
        if let (Some((spec, generation)), false) = (wanted, ctx.stopping.load(Ordering::SeqCst)) {
            let stopping = || ctx.stopping.load(Ordering::SeqCst);
            let beat = || ctx.heartbeat.beat();
            let out = stream::Publish {
                session: ctx.session,
                cell: ctx.cell,
                stopping: &stopping,
                beat: &beat,
            };
            // A panic while streaming ends the stream, not the worker.
            let ended = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                stream::run(&mut cell, &spec, generation, ctx.streams, &out, &rx)
            }));
            report_pairs(&cell);
            match ended {
                Ok(stream::StreamEnd::Stopped) => continue,
                Ok(stream::StreamEnd::Closed) => break,
                Ok(stream::StreamEnd::Job(job)) => {
                    run_one(job, &mut cell, ctx, &report_pairs);
                    continue;
                }
                Err(panic) => {
                    let reason = format!("internal error: {}", scan::panic_message(&*panic));
                    tracing::error!(%reason, "stream panicked");
                    ctx.streams.stop();
                    if let Ok(mut s) = ctx.status.lock() {
                        s.last_error = Some(format!("stream: {reason}"));
                    }
                    continue;
                }
            }
        }
        let job = match rx.recv_timeout(Duration::from_secs(1)) {
            Ok(job) => job,
            Err(mpsc::RecvTimeoutError::Timeout) => {
                // Lost cameras are reopened between scans, so health shows them back.
                if cell
                    .status()
                    .iter()
                    .any(|p| p.driver != crate::protocol::DriverState::Connected)
                {
                    cell.reconnect();
                    report_pairs(&cell);
                }
                continue;
            }
            Err(mpsc::RecvTimeoutError::Disconnected) => break,
        };
        run_one(job, &mut cell, ctx, &report_pairs);
    }
}

/// How a scan job ended: the terminal state goes out only after health says what the scan
/// left behind (a lost camera reconnecting, the last scan, the last error), so a client that
/// sees `failed` or `done` and asks for health reads the cell as the scan left it.
enum Ending {
    /// `done` with the scan's figures, as JSON.
    Done(String),
    Failed(String),
}

/// Run one scan job on the worker: a panic fails that job only.
fn run_one(job: Job, cell: &mut Cell, ctx: &WorkerContext, report_pairs: &dyn Fn(&Cell)) {
    if let Ok(mut s) = ctx.status.lock() {
        s.queue = s.queue.saturating_sub(1);
        s.state = "scanning".into();
    }
    let id = job.scan_id.clone();
    // A panic anywhere in a job fails that job; the worker goes on with the next.
    let ran = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| run_job(job, cell, ctx)));
    report_pairs(cell);
    let ending = ran.unwrap_or_else(|panic| {
        let reason = format!("internal error: {}", scan::panic_message(&*panic));
        tracing::error!(scan = %id, %reason, "scan panicked");
        let partial = ctx.data_dir.join("scans").join(format!("{id}.partial"));
        if partial.exists() {
            let _ = std::fs::remove_dir_all(&partial);
        }
        Ending::Failed(reason)
    });
    if let Ok(mut s) = ctx.status.lock() {
        match &ending {
            Ending::Done(_) => s.last_scan = Some(id.clone()),
            Ending::Failed(reason) => s.last_error = Some(format!("{id}: {reason}")),
        }
        if s.state == "scanning" {
            s.state = "ready".into();
        }
    }
    match ending {
        Ending::Done(json) => publish_json(ctx.session, ctx.cell, &id, json),
        Ending::Failed(reason) => {
            publish(ctx.session, ctx.cell, &id, &ScanState::Failed { reason })
        }
    }
}

fn run_job(mut job: Job, cell_: &mut Cell, ctx: &WorkerContext) -> Ending {
    // Every inspection report carries what the cell's verification says (never verified,
    // failed, stale, drifting).
    if let Some(ledger) = ctx.ledger {
        if let Ok(l) = ledger.lock() {
            job.scan.notes = l.warnings(verification::unix_now());
        }
    }
    let id = job.scan_id;
    let (session, cell) = (ctx.session, ctx.cell);
    if ctx.stopping.load(Ordering::SeqCst) {
        return Ending::Failed("risd is stopping".into());
    }
    let result = cell_.scan(
        &job.scan,
        ctx.data_dir,
        &id,
        &|| ctx.stopping.load(Ordering::SeqCst),
        &|s| {
            ctx.heartbeat.beat();
            // The ending goes out from `run_one`, after health.
            if !matches!(s, ScanState::Done | ScanState::Failed { .. }) {
                publish(session, cell, &id, s);
            }
        },
    );
    // Retention before the end state goes out: a client that sees `done` sees the store as
    // it stays.
    match store::retention(
        ctx.data_dir,
        ctx.storage.keep_scans,
        ctx.storage.max_age_days,
    ) {
        Ok(removed) => {
            for name in removed {
                tracing::info!(scan = %name, "removed (retention)");
            }
        }
        Err(e) => tracing::warn!(error = %format!("{e:#}"), "retention failed"),
    }
    // A verify scan's figures join the verification session before `done` goes out.
    let result = result.and_then(|(report, dir)| {
        let measured = match (&job.scan.verify, ctx.ledger) {
            (Some((artefact, position)), Some(ledger)) => Some(verify_position(
                &report, cell_, ledger, &id, *artefact, position,
            )),
            _ => None,
        };
        measured.transpose().map(|position| (report, dir, position))
    });
    match result {
        Ok((report, dir, position)) => {
            // The clouds as written, from memory.
            for (name, bytes) in &report.clouds {
                let key = ScanItem::Cloud(name.clone()).key(cell, &id);
                if let Err(e) = session
                    .put(&key, bytes.as_slice())
                    .congestion_control(CongestionControl::Block)
                    .wait()
                {
                    tracing::warn!(%key, error = %e, "publication failed");
                }
            }
            if let Some(bridge) = ctx.ros2 {
                bridge.publish(session, &report.clouds, std::time::SystemTime::now());
            }
            if report.inspection.is_some() {
                publish_file(
                    session,
                    &ScanItem::Report.key(cell, &id),
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
                "warnings": report.warnings,
                "total": report.total,
                "verification": position,
            });
            tracing::info!(scan = %id, points = report.merged_points, "scan done");
            Ending::Done(done.to_string())
        }
        Err(e) => {
            tracing::warn!(scan = %id, error = %format!("{e:#}"), "scan failed");
            Ending::Failed(format!("{e:#}"))
        }
    }
}

/// Evaluate a verify scan's artefact in every sensor's cloud and the merged one (each in
/// the cell frame, points outside their sensor's calibrated volume left out) and add the
/// position to the open verification session.
fn verify_position(
    report: &ScanReport,
    cell: &Cell,
    ledger: &Mutex<Ledger>,
    scan_id: &str,
    artefact: Artefact,
    position: &str,
) -> anyhow::Result<VerifyPosition> {
    let mut clouds = Vec::with_capacity(report.clouds.len());
    for (name, bytes) in &report.clouds {
        let mut cloud = PointCloud::from_ply(bytes, Path::new(&format!("{name}.ply")))
            .with_context(|| format!("reading back the cloud of {name}"))?;
        cloud.retain_finite();
        cloud.drop_outside();
        let to_cell = cell
            .pairs
            .iter()
            .find(|p| p.name == *name)
            .map(|p| p.to_common);
        let mut points = cloud.positions();
        if let Some(m) = to_cell {
            let (r, t) = (m.fixed_view::<3, 3>(0, 0), m.fixed_view::<3, 1>(0, 3));
            for p in &mut points {
                *p = r * *p + t;
            }
        }
        clouds.push((name.clone(), points));
    }
    let artefacts = ledger
        .lock()
        .map_err(|_| anyhow::anyhow!("the verification ledger is unavailable"))?
        .artefacts()
        .clone();
    let measured = verification::measure(&artefacts, scan_id, artefact, position, clouds)?;
    for (scope, figures) in &measured.position.scopes {
        for f in figures {
            tracing::info!(scope, position, error = ?f.error, status = ?f.status, "verification figure");
        }
    }
    ledger
        .lock()
        .map_err(|_| anyhow::anyhow!("the verification ledger is unavailable"))?
        .add(measured)
}

/// Publish a result file of a scan (large payloads block rather than drop).
pub(super) fn publish_file(session: &Session, key: &str, path: &Path) {
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
