//! The `risd` service (SPEC §12): a Zenoh session serving scan requests for the cell, publishing
//! every stage of each scan, its clouds as binary PLY and the stored results, with a liveliness
//! token and a status for health. Modelled on mini-redis: [`run`] takes its stop signal as an
//! argument; scans run one at a time on a worker thread fed by a bounded queue.

use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{mpsc, Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{anyhow, Context, Result};
use tokio_util::sync::CancellationToken;
use zenoh::qos::CongestionControl;
use zenoh::query::Query;
use zenoh::{Session, Wait};

use crate::cell::{Cell, ScanJob};
use crate::config::CellConfig;
use crate::notify;
use crate::protocol::{
    cell_key, echo, health_key, scan_key, scans_key, state_key, stream_key, stream_sensor_key,
    ErrorReply, Health, ScanItem, ScanMode, ScanReply, ScanRequest, ScanState, StreamRequest,
};
use crate::scan;
use crate::store::{self, DataDirLock};
use crate::stream::{self, StreamControl};

struct Job {
    scan_id: String,
    scan: ScanJob,
}

/// The scan worker's sign of life: milliseconds since `start` at its last beat. The systemd
/// watchdog is fed only while it is recent, so a stuck or dead worker gets risd restarted.
struct Heartbeat {
    start: Instant,
    last_ms: AtomicU64,
}

impl Heartbeat {
    fn new() -> Heartbeat {
        Heartbeat {
            start: Instant::now(),
            last_ms: AtomicU64::new(0),
        }
    }

    fn beat(&self) {
        self.last_ms
            .store(self.start.elapsed().as_millis() as u64, Ordering::Relaxed);
    }

    fn age(&self) -> Duration {
        self.start
            .elapsed()
            .saturating_sub(Duration::from_millis(self.last_ms.load(Ordering::Relaxed)))
    }
}

/// Validate a request against the cell and choose the part to inspect (an index into the
/// cell's parts); the error is the reply's reason.
pub fn validate(req: &ScanRequest, config: &CellConfig) -> Result<Option<usize>, String> {
    if let Some(list) = &req.sensors {
        if list.is_empty() {
            return Err("`sensors` is empty".into());
        }
        for s in list {
            if !config.sensors.iter().any(|c| c.name == *s) {
                return Err(format!("no sensor {} in cell {:?}", echo(s), config.name));
            }
        }
    }
    let named = match &req.part {
        Some(p) => Some(
            config
                .parts
                .iter()
                .position(|c| c.id == *p)
                .ok_or_else(|| format!("no part {} in cell {:?}", echo(p), config.name))?,
        ),
        None => None,
    };
    // A single-shot cloud is sparse and noisier than a Gray-code one: it is inspected only
    // when the request asks for it, never by default.
    let single = req.mode == Some(ScanMode::SingleShot);
    match (req.inspect, named, config.parts.len()) {
        (Some(false), Some(_), _) => Err("`part` is named but `inspect` is false".into()),
        (Some(false), None, _) => Ok(None),
        (None, _, _) if single => Ok(None),
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

/// Zenoh authentication and access control for `cell` (SPEC §12 keys): operators may query
/// `scan` and `stream`; users may ask streamed points; operators and readers may query health and stored scans, subscribe to the cell's
/// publications and see its liveliness; everything else, publishing under `ris/<cell>/**`
/// included, is denied. `ros2` adds the cell's ROS 2 topics and liveliness tokens (see
/// [`crate::ros2::acl_keys`]) to what users may follow.
pub fn apply_access(
    config: &mut zenoh::Config,
    cell: &str,
    access: &crate::config::AccessSection,
    ros2: (Vec<String>, Vec<String>),
) -> Result<()> {
    let (ros_data, ros_alive) = ros2;
    let follow: Vec<String> = std::iter::once(cell_key(cell)).chain(ros_data).collect();
    let alive: Vec<String> = std::iter::once(health_key(cell)).chain(ros_alive).collect();
    let both: Vec<&String> = access.operators.iter().chain(&access.readers).collect();
    let mut subjects = Vec::new();
    let mut policies = Vec::new();
    if !access.operators.is_empty() {
        subjects.push(serde_json::json!({"id": "operators", "usernames": access.operators}));
        policies.push(serde_json::json!({"rules": ["scan"], "subjects": ["operators"]}));
    }
    if !both.is_empty() {
        subjects.push(serde_json::json!({"id": "users", "usernames": both}));
        policies
            .push(serde_json::json!({"rules": ["read", "follow", "follow-out", "alive"], "subjects": ["users"]}));
    }
    let acl = serde_json::json!({
        "enabled": true,
        "default_permission": "deny",
        "rules": [
            {"id": "scan", "permission": "allow", "flows": ["ingress", "egress"],
             "messages": ["query", "reply"], "key_exprs": [scan_key(cell), stream_key(cell)]},
            {"id": "read", "permission": "allow", "flows": ["ingress", "egress"],
             "messages": ["query", "reply"],
             "key_exprs": [health_key(cell), scans_key(cell), stream_sensor_key(cell, "*", "point")]},
            {"id": "follow", "permission": "allow", "flows": ["ingress"],
             "messages": ["declare_subscriber"], "key_exprs": follow},
            {"id": "follow-out", "permission": "allow", "flows": ["egress"],
             "messages": ["put"], "key_exprs": follow},
            {"id": "alive", "permission": "allow", "flows": ["ingress", "egress"],
             "messages": ["liveliness_query", "declare_liveliness_subscriber", "liveliness_token", "reply"],
             "key_exprs": alive},
        ],
        "subjects": subjects,
        "policies": policies,
    });
    let users = access.users.display().to_string();
    for (key, value) in [
        (
            "transport/auth/usrpwd/dictionary_file",
            serde_json::to_string(&users)?,
        ),
        ("access_control", acl.to_string()),
    ] {
        config
            .insert_json5(key, &value)
            .map_err(|e| anyhow!("zenoh.access: {key}: {e}"))?;
    }
    Ok(())
}

/// A client configuration with `user`'s credentials (password from `password_file`, first
/// line), for `ris scan` and tests against a cell with `[zenoh.access]`.
pub fn client_config(connect: &[String], user: Option<(&str, &str)>) -> Result<zenoh::Config> {
    let mut c = zenoh_config("client", &[], connect)?;
    if let Some((user, password)) = user {
        for (key, value) in [
            ("transport/auth/usrpwd/user", serde_json::to_string(user)?),
            (
                "transport/auth/usrpwd/password",
                serde_json::to_string(password)?,
            ),
        ] {
            c.insert_json5(key, &value)
                .map_err(|e| anyhow!("zenoh credentials {key}: {e}"))?;
        }
    }
    Ok(c)
}

/// How long risd asks the network whether another daemon serves the same cell.
const PEER_CHECK: Duration = Duration::from_millis(1500);

/// Whether an endpoint listens on loopback only.
fn is_loopback(endpoint: &str) -> bool {
    let address = endpoint.split_once('/').map_or("", |(_, a)| a);
    address.starts_with("127.") || address.starts_with("[::1]") || address.starts_with("localhost:")
}

/// Serve the cell until `shutdown` is cancelled; then stop accepting, let the running scan
/// end (finished, or failed at the next exposure group), and close. The data directory is
/// locked before anything in it is touched; the health token and `READY=1` come only when
/// every pair is prepared (a scan request before that gets an error reply saying so).
pub async fn run(config: CellConfig, shutdown: CancellationToken) -> Result<()> {
    let cell = config.name.clone();
    let data_dir = config.storage.data_dir.clone();
    let lock = DataDirLock::acquire(&data_dir)?;
    tracing::debug!(lock = %lock.path().display(), "data directory locked");
    for name in store::housekeeping(
        &data_dir,
        config.storage.keep_scans,
        config.storage.max_age_days,
    )? {
        tracing::info!(scan = %name, "removed");
    }
    let z = &config.zenoh;
    let mut zc = zenoh_config(&z.mode, &z.listen, &z.connect)?;
    if let Some(access) = &z.access {
        apply_access(&mut zc, &cell, access, crate::ros2::acl_keys(&config))?;
    } else if z.listen.iter().any(|e| !is_loopback(e)) {
        tracing::warn!(listen = ?z.listen, "the cell listens beyond loopback without [zenoh.access]: anyone who reaches it may scan and read");
    }
    let session = zenoh::open(zc)
        .await
        .map_err(|e| anyhow!("opening the Zenoh session: {e}"))?;
    // One daemon per cell name on the network: two would both scan for one request.
    let others = session
        .liveliness()
        .get(health_key(&cell))
        .timeout(PEER_CHECK)
        .await
        .map_err(|e| anyhow!("asking for other daemons of cell {cell}: {e}"))?;
    let mut rivals = Vec::new();
    while let Ok(reply) = others.recv_async().await {
        if let Ok(sample) = reply.result() {
            rivals.push(sample.key_expr().to_string());
        }
    }
    if !rivals.is_empty() {
        let _ = session.close().await;
        return Err(anyhow!(
            "another risd already serves cell {cell:?} on this Zenoh network ({}); give each cell its own [cell] name",
            rivals.join(", ")
        ));
    }
    let ros2 = match crate::ros2::Bridge::declare(&session, &config).await {
        Ok(b) => b.map(Arc::new),
        Err(e) => {
            let _ = session.close().await;
            return Err(e);
        }
    };
    let status = Arc::new(Mutex::new(Health {
        state: "preparing".into(),
        sensors: config.sensors.iter().map(|s| s.name.clone()).collect(),
        queue: 0,
        last_scan: None,
        last_error: None,
        pairs: Vec::new(),
        prepared: Vec::new(),
        stream: Default::default(),
    }));
    let health = session
        .declare_queryable(health_key(&cell))
        .await
        .map_err(|e| anyhow!("declaring {}: {e}", health_key(&cell)))?;
    let scan_q = session
        .declare_queryable(scan_key(&cell))
        .await
        .map_err(|e| anyhow!("declaring {}: {e}", scan_key(&cell)))?;
    let store_q = session
        .declare_queryable(scans_key(&cell))
        .await
        .map_err(|e| anyhow!("declaring {}: {e}", scans_key(&cell)))?;
    let streams = Arc::new(StreamControl::default());
    let stream_q = session
        .declare_queryable(stream_key(&cell))
        .await
        .map_err(|e| anyhow!("declaring {}: {e}", stream_key(&cell)))?;
    let point_q = session
        .declare_queryable(stream_sensor_key(&cell, "*", "point"))
        .await
        .map_err(|e| anyhow!("declaring the stream's point queries: {e}"))?;

    let heartbeat = Arc::new(Heartbeat::new());
    heartbeat.beat();
    let watchdog = notify::watchdog_interval().map(|every| {
        let (stop, beat) = (shutdown.clone(), heartbeat.clone());
        tokio::spawn(async move {
            let mut tick = tokio::time::interval(every);
            loop {
                tokio::select! {
                    _ = stop.cancelled() => break,
                    _ = tick.tick() => {
                        // WATCHDOG_USEC is twice `every`: a worker silent that long is stuck.
                        if beat.age() < 2 * every {
                            notify::notify("WATCHDOG=1");
                        } else {
                            tracing::error!(silent_s = beat.age().as_secs_f64(), "the scan worker is not responding; leaving the watchdog unfed");
                        }
                    }
                }
            }
        })
    });

    // Preparation (reference recordings, CAD indexing) off the runtime; SIGTERM does not wait
    // for it.
    let (prep_config, prep_status) = (config.clone(), status.clone());
    let mut preparation = tokio::task::spawn_blocking(move || -> Result<_> {
        Cell::prepare(&prep_config, 1, &|pair, done, total| {
            tracing::info!(pair, "pair prepared ({done} of {total})");
            if let Ok(mut s) = prep_status.lock() {
                s.prepared.push(pair.to_string());
            }
        })
    });
    let mut prepared = false;
    let mut token = None;
    let (tx, rx) = mpsc::sync_channel::<Job>(config.workers.queue);
    let mut rx = Some(rx);
    let stopping = Arc::new(AtomicBool::new(false));
    let (worker_gone_tx, mut worker_gone) = tokio::sync::oneshot::channel::<()>();
    let mut worker_gone_tx = Some(worker_gone_tx);
    let mut worker = None;
    let mut counter = 0u64;
    let outcome: Result<()> = loop {
        tokio::select! {
            _ = shutdown.cancelled() => break Ok(()),
            done = &mut preparation, if !prepared => {
                prepared = true;
                let cell_ready = match done {
                    Ok(Ok(c)) => c,
                    Ok(Err(e)) => break Err(e.context("preparing the cell")),
                    Err(e) => break Err(anyhow!("preparing the cell: {e}")),
                };
                let (w_session, w_status, w_stopping, beat, w_cell, w_data_dir, storage) = (
                    session.clone(),
                    status.clone(),
                    stopping.clone(),
                    heartbeat.clone(),
                    cell.clone(),
                    data_dir.clone(),
                    config.storage.clone(),
                );
                let w_ros2 = ros2.clone();
                let w_streams = streams.clone();
                let (Some(rx), Some(gone)) = (rx.take(), worker_gone_tx.take()) else {
                    break Err(anyhow!("the scan worker was started twice"));
                };
                let spawned = std::thread::Builder::new()
                    .name("risd-scan".into())
                    .spawn(move || {
                        let ctx = WorkerContext {
                            session: &w_session,
                            status: &w_status,
                            stopping: &w_stopping,
                            heartbeat: &beat,
                            cell: &w_cell,
                            data_dir: &w_data_dir,
                            storage: &storage,
                            ros2: w_ros2.as_deref(),
                            streams: &w_streams,
                        };
                        worker_loop(rx, cell_ready, &ctx);
                        drop(gone);
                    });
                match spawned {
                    Ok(h) => worker = Some(h),
                    Err(e) => break Err(anyhow!("starting the scan worker: {e}")),
                }
                match session.liveliness().declare_token(health_key(&cell)).await {
                    Ok(t) => token = Some(t),
                    Err(e) => break Err(anyhow!("declaring the liveliness token: {e}")),
                }
                set_state(&status, "ready");
                notify::notify("READY=1");
                tracing::info!(%cell, zid = %session.zid(), "risd ready");
            }
            _ = &mut worker_gone, if worker.is_some() => {
                break Err(anyhow!("the scan worker stopped unexpectedly"));
            }
            q = scan_q.recv_async() => {
                let Ok(q) = q else { break Ok(()) };
                if !prepared || token.is_none() {
                    reply_error(&q, &scan_key(&cell), "the cell is starting: its pairs are being prepared; try again when ris/<cell>/health is alive").await;
                    continue;
                }
                counter += 1;
                handle_scan(&q, &config, &tx, &status, &session, counter).await;
            }
            q = store_q.recv_async() => {
                let Ok(q) = q else { break Ok(()) };
                // Stored scans can be large: served on their own task so health and scan
                // requests are not held up.
                let (c, d) = (cell.clone(), data_dir.clone());
                tokio::spawn(async move { handle_store(&q, &c, &d).await });
            }
            q = stream_q.recv_async() => {
                let Ok(q) = q else { break Ok(()) };
                handle_stream(&q, &config, prepared && token.is_some(), &status, &streams).await;
            }
            q = point_q.recv_async() => {
                let Ok(q) = q else { break Ok(()) };
                handle_point(&q, &streams).await;
            }
            q = health.recv_async() => {
                let Ok(q) = q else { break Ok(()) };
                let health = status.lock().ok().map(|s| Health {
                    stream: streams.status(),
                    ..s.clone()
                });
                let json = health
                    .and_then(|h| serde_json::to_string(&h).ok())
                    .unwrap_or_default();
                if let Err(e) = q.reply(health_key(&cell), json).await {
                    tracing::warn!(error = %e, "health reply failed");
                }
            }
        }
    };
    notify::notify("STOPPING=1");
    tracing::info!("stopping: no new scans; ending the running one");
    set_state(&status, "stopping");
    drop(scan_q);
    drop(stream_q);
    drop(point_q);
    streams.stop();
    stopping.store(true, Ordering::SeqCst);
    drop(tx);
    if let Some(worker) = worker {
        tokio::task::spawn_blocking(move || worker.join())
            .await
            .context("joining the scan worker")?
            .map_err(|_| anyhow!("the scan worker panicked"))?;
    }
    if let Some(w) = watchdog {
        w.abort();
    }
    drop(store_q);
    drop(health);
    drop(token);
    drop(ros2);
    session
        .close()
        .await
        .map_err(|e| anyhow!("closing the Zenoh session: {e}"))?;
    drop(lock);
    outcome?;
    tracing::info!("risd stopped");
    Ok(())
}

fn set_state(status: &Mutex<Health>, state: &str) {
    if let Ok(mut s) = status.lock() {
        s.state = state.into();
    }
}

async fn reply_error(q: &Query, key: &str, reason: &str) {
    tracing::warn!(reason, "scan refused");
    let reply = ErrorReply {
        error: reason.to_string(),
    };
    if let Err(e) = q
        .reply_err(serde_json::to_string(&reply).unwrap_or_default())
        .await
    {
        tracing::warn!(%key, error = %e, "error reply failed");
    }
}

async fn handle_scan(
    q: &Query,
    config: &CellConfig,
    tx: &mpsc::SyncSender<Job>,
    status: &Mutex<Health>,
    session: &Session,
    counter: u64,
) {
    let key = scan_key(&config.name);
    // Only the exact key starts a scan: a wildcard query (`ris/*/scan`, `**`) is not a request.
    if q.key_expr().as_str() != key {
        tracing::debug!(asked = %q.key_expr(), "wildcard query on the scan key ignored");
        return;
    }
    let body = q
        .payload()
        .map(|p| p.to_bytes().into_owned())
        .unwrap_or_default();
    let outcome = ScanRequest::parse(&body)
        .and_then(|r| validate(&r, config).map(|part| (r, part)))
        .and_then(|(r, part)| {
            let scan_id = scan::new_scan_id(counter);
            // Counted before the worker can take it, so the count never goes stale.
            if let Ok(mut s) = status.lock() {
                s.queue += 1;
            }
            let job = Job {
                scan_id: scan_id.clone(),
                scan: ScanJob {
                    sensors: r.sensors.clone(),
                    part,
                    tag: r.tag.clone(),
                    mode: r.mode.unwrap_or_default(),
                },
            };
            let sent = tx.try_send(job);
            if sent.is_err() {
                if let Ok(mut s) = status.lock() {
                    s.queue = s.queue.saturating_sub(1);
                }
            }
            match sent {
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
            tracing::info!(%scan_id, tag = ?r.tag.as_deref().map(echo), "scan accepted");
            publish(session, &config.name, &scan_id, &ScanState::Queued);
            let reply = ScanReply {
                scan_id,
                state: "accepted".into(),
                sensors: r
                    .sensors
                    .clone()
                    .unwrap_or_else(|| config.sensors.iter().map(|s| s.name.clone()).collect()),
            };
            if let Err(e) = q
                .reply(&key, serde_json::to_string(&reply).unwrap_or_default())
                .await
            {
                tracing::warn!(error = %e, "scan reply failed");
            }
        }
        Err(reason) => reply_error(q, &key, &reason).await,
    }
}

/// `ris/<cell>/stream`: start, stop or report the single-shot stream.
async fn handle_stream(
    q: &Query,
    config: &CellConfig,
    ready: bool,
    status: &Mutex<Health>,
    streams: &StreamControl,
) {
    let key = stream_key(&config.name);
    if q.key_expr().as_str() != key {
        return;
    }
    let body = q
        .payload()
        .map(|p| p.to_bytes().into_owned())
        .unwrap_or_default();
    let names: Vec<String> = config.sensors.iter().map(|s| s.name.clone()).collect();
    let outcome = StreamRequest::parse(&body).and_then(|r| match r.action.as_deref() {
        None | Some("status") => Ok(serde_json::to_value(streams.status()).unwrap_or_default()),
        Some("stop") => {
            let st = streams.stop();
            tracing::info!("stream stopped by request");
            Ok(serde_json::to_value(st).unwrap_or_default())
        }
        Some("start") => {
            if !ready {
                return Err("the cell is starting: its pairs are being prepared; try again when ris/<cell>/health is alive".into());
            }
            let spec = r.spec(&names, config.single_shot.rate_hz)?;
            let pairs = status.lock().map(|s| s.pairs.clone()).unwrap_or_default();
            for p in pairs.iter().filter(|p| spec.sensors.contains(&p.sensor)) {
                if let Some(why) = &p.single_shot {
                    return Err(why.clone());
                }
            }
            tracing::info!(sensors = ?spec.sensors, rate_hz = spec.rate_hz, "stream requested");
            let keys: serde_json::Map<String, serde_json::Value> = spec
                .sensors
                .iter()
                .map(|s| {
                    (
                        s.clone(),
                        serde_json::json!({
                            "cloud": stream_sensor_key(&config.name, s, "cloud"),
                            "fused": stream_sensor_key(&config.name, s, "fused"),
                            "point": stream_sensor_key(&config.name, s, "point"),
                        }),
                    )
                })
                .collect();
            let reply = serde_json::json!({
                "state": "streaming",
                "sensors": spec.sensors,
                "rate_hz": spec.rate_hz,
                "keys": keys,
            });
            streams.start(spec);
            Ok(reply)
        }
        Some(other) => Err(format!(
            "unknown action {} (start, stop, status)",
            echo(other)
        )),
    });
    match outcome {
        Ok(v) => {
            if let Err(e) = q.reply(&key, v.to_string()).await {
                tracing::warn!(error = %e, "stream reply failed");
            }
        }
        Err(reason) => reply_error(q, &key, &reason).await,
    }
}

/// `ris/<cell>/stream/<sensor>/point?u=..&v=..`: the streamed point nearest a camera pixel.
async fn handle_point(q: &Query, streams: &StreamControl) {
    let key = q.key_expr().clone();
    let sensor = key
        .as_str()
        .split('/')
        .nth(3)
        .unwrap_or_default()
        .to_string();
    if sensor.contains('*') {
        return;
    }
    // `u=..&v=..` as well as Zenoh's own `u=..;v=..`.
    let text = q.parameters().as_str().to_string();
    let params: Vec<(&str, &str)> = text
        .split(['&', ';'])
        .filter_map(|kv| kv.split_once('='))
        .collect();
    let num = |name: &str| {
        params
            .iter()
            .find(|(k, _)| *k == name)
            .map(|(_, v)| *v)
            .ok_or_else(|| format!("`{name}` is missing: ask ...point?u=<column>&v=<row>"))
            .and_then(|v| {
                v.parse::<f64>()
                    .map_err(|_| format!("`{name}` = {} is not a number", echo(v)))
            })
    };
    let answer = num("u")
        .and_then(|u| num("v").map(|v| (u, v)))
        .and_then(|(u, v)| stream::point_query(streams, &sensor, u, v));
    match answer {
        Ok(json) => {
            if let Err(e) = q.reply(key, json).await {
                tracing::warn!(error = %e, "point reply failed");
            }
        }
        Err(reason) => {
            let reply = serde_json::json!({ "error": reason }).to_string();
            if let Err(e) = q.reply_err(reply).await {
                tracing::warn!(error = %e, "point error reply failed");
            }
        }
    }
}

fn publish(session: &Session, cell: &str, scan_id: &str, state: &ScanState) {
    let key = state_key(cell, scan_id);
    let json = serde_json::to_string(state).unwrap_or_default();
    if let Err(e) = session.put(&key, json).wait() {
        tracing::warn!(%key, error = %e, "state publication failed");
    }
}

/// What the scan worker shares with the service.
struct WorkerContext<'a> {
    session: &'a Session,
    status: &'a Mutex<Health>,
    stopping: &'a AtomicBool,
    heartbeat: &'a Heartbeat,
    cell: &'a str,
    data_dir: &'a Path,
    storage: &'a crate::config::StorageSection,
    ros2: Option<&'a crate::ros2::Bridge>,
    streams: &'a StreamControl,
}

fn worker_loop(rx: mpsc::Receiver<Job>, mut cell: Cell, ctx: &WorkerContext) {
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
    if let Err(panic) = ran {
        let reason = format!("internal error: {}", scan::panic_message(&*panic));
        tracing::error!(scan = %id, %reason, "scan panicked");
        publish(
            ctx.session,
            ctx.cell,
            &id,
            &ScanState::Failed {
                reason: reason.clone(),
            },
        );
        if let Ok(mut s) = ctx.status.lock() {
            s.last_error = Some(format!("{id}: {reason}"));
        }
        let partial = ctx.data_dir.join("scans").join(format!("{id}.partial"));
        if partial.exists() {
            let _ = std::fs::remove_dir_all(&partial);
        }
    }
    if let Ok(mut s) = ctx.status.lock() {
        if s.state == "scanning" {
            s.state = "ready".into();
        }
    }
}

fn run_job(job: Job, cell_: &mut Cell, ctx: &WorkerContext) {
    let id = job.scan_id;
    let (session, cell) = (ctx.session, ctx.cell);
    if ctx.stopping.load(Ordering::SeqCst) {
        publish(
            session,
            cell,
            &id,
            &ScanState::Failed {
                reason: "risd is stopping".into(),
            },
        );
        return;
    }
    let result = cell_.scan(
        &job.scan,
        ctx.data_dir,
        &id,
        &|| ctx.stopping.load(Ordering::SeqCst),
        &|s| {
            ctx.heartbeat.beat();
            if !matches!(s, ScanState::Done) {
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
    match result {
        Ok((report, dir)) => {
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
            });
            let key = state_key(cell, &id);
            if let Err(e) = session.put(&key, done.to_string()).wait() {
                tracing::warn!(%key, error = %e, "state publication failed");
            }
            if let Ok(mut s) = ctx.status.lock() {
                s.last_scan = Some(id.clone());
            }
            tracing::info!(scan = %id, points = report.merged_points, "scan done");
        }
        Err(e) => {
            // scan::run has published `failed` with the reason.
            tracing::warn!(scan = %id, error = %format!("{e:#}"), "scan failed");
            if let Ok(mut s) = ctx.status.lock() {
                s.last_error = Some(format!("{id}: {e:#}"));
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

/// Answer `ris/<cell>/scans/**` from the finished scans on disk: `<id>/state`, `<id>/report`,
/// `<id>/cloud/<sensor>` and `<id>/deviation`, for every key the query matches.
async fn handle_store(q: &Query, cell: &str, data_dir: &Path) {
    let (c, d) = (cell.to_string(), data_dir.to_path_buf());
    let Ok((ids, items)) = tokio::task::spawn_blocking(move || store::stored_items(&c, &d)).await
    else {
        return;
    };
    let asked = q.key_expr().clone();
    let matching = |key: &str| {
        zenoh::key_expr::KeyExpr::try_from(key.to_string())
            .ok()
            .filter(|k| asked.intersects(k))
    };
    for id in ids {
        if let Some(k) = matching(&state_key(cell, &id)) {
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
            "[cell]\nname = \"t\"\n[[sensor]]\nname = \"s1\"\nbackend = \"mock\"\nscene = \"s.toml\"\nto_common = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]\n",
        );
        for p in parts {
            text += &format!("[[part]]\nid = \"{p}\"\ncad = \"{p}.stl\"\ntolerance = 0.5\n");
        }
        CellConfig::parse(&text, Path::new("."), "test").expect("config")
    }

    fn req(json: &str) -> ScanRequest {
        ScanRequest::parse(json.as_bytes()).expect("request")
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
        // An unknown mode is refused by the parser (the protocol's `ScanMode`).
        assert!(ScanRequest::parse(br#"{"mode": "fast"}"#).is_err());
        assert_eq!(validate(&req(r#"{"mode": "single-shot"}"#), &one), Ok(None));
        assert_eq!(
            validate(
                &req(r#"{"mode": "single-shot", "inspect": true, "part": "hood"}"#),
                &two
            ),
            Ok(Some(1))
        );
    }
}
