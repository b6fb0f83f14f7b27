//! The `risd` service (SPEC §12): a Zenoh session serving scan requests for the cell, publishing
//! every stage of each scan, its clouds as binary PLY and the stored results, with a liveliness
//! token and a status for health. Modelled on mini-redis: [`run`] takes its stop signal as an
//! argument; scans run one at a time on a worker thread fed by a bounded queue.

mod claim;
mod handlers;
mod refusals;
mod session;
mod worker;

pub use handlers::validate;
pub use session::{apply_access, client_config, login_config, open, plain, zenoh_config};

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc, Mutex};
use std::time::Duration;

use anyhow::{anyhow, Context, Result};
use tokio_util::sync::CancellationToken;
use zenoh::Session;

use crate::cell::Cell;
use crate::config::CellConfig;
use crate::notify;
use crate::protocol::{
    health_key, scan_key, scans_key, stream_key, stream_sensor_key, verifications_key, verify_key,
    Health,
};
use crate::store::{self, DataDirLock};
use crate::stream::StreamControl;
use crate::verification::{unix_now, Ledger};

use claim::Claim;
use handlers::{
    handle_point, handle_scan, handle_store, handle_stream, handle_verifications, handle_verify,
    reply_error, ScanDesk,
};
use refusals::Refusals;
use worker::{worker_loop, Heartbeat, Job, WorkerContext};

/// Open the cell's session ([`open`]) and [`run`] the service on a tokio multi-thread runtime
/// of its own (Zenoh needs one), blocking the calling thread until `shutdown` is cancelled or,
/// with `signals`, SIGTERM or SIGINT arrives. Preparation still running then is not waited for
/// beyond two seconds.
pub fn serve(config: CellConfig, shutdown: CancellationToken, signals: bool) -> Result<()> {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    let served = runtime.block_on(async move {
        if signals {
            let stop = shutdown.clone();
            tokio::spawn(async move {
                use tokio::signal::unix::{signal, SignalKind};
                let (Ok(mut term), Ok(mut int)) = (
                    signal(SignalKind::terminate()),
                    signal(SignalKind::interrupt()),
                ) else {
                    tracing::error!("cannot listen for SIGTERM/SIGINT");
                    return;
                };
                tokio::select! {
                    _ = term.recv() => tracing::info!("SIGTERM"),
                    _ = int.recv() => tracing::info!("SIGINT"),
                }
                stop.cancel();
            });
        }
        let session = open(&config).await?;
        run(config, session, shutdown).await
    });
    runtime.shutdown_timeout(Duration::from_secs(2));
    served
}

/// Serve the cell on `session` (from [`open`], or any session a test opens on loopback) until
/// `shutdown` is cancelled; then stop accepting, let the running scan end (finished, or failed at
/// the next exposure group), and close the session. The data directory is locked before anything
/// in it is touched; the health token and `READY=1` come only when every pair is prepared (a scan
/// request before that gets an error reply saying so).
pub async fn run(config: CellConfig, session: Session, shutdown: CancellationToken) -> Result<()> {
    let cell = config.name.clone();
    let data_dir = config.storage.data_dir.clone();
    let locked = DataDirLock::acquire(&data_dir).and_then(|lock| {
        let removed = store::housekeeping(
            &data_dir,
            config.storage.keep_scans,
            config.storage.max_age_days,
        )?;
        Ok((lock, removed))
    });
    let lock = match locked {
        Ok((lock, removed)) => {
            for name in removed {
                tracing::info!(scan = %name, "removed");
            }
            lock
        }
        Err(e) => {
            let _ = session.close().await;
            return Err(e);
        }
    };
    tracing::debug!(lock = %lock.path().display(), "data directory locked");
    // One daemon per cell name on the network, from the first instant: two would both scan
    // for one request.
    let claim = match Claim::stake(&session, &cell, config.zenoh.access.is_some()).await {
        Ok(c) => c,
        Err(e) => {
            let _ = session.close().await;
            return Err(e);
        }
    };
    let ledger = match config
        .verify
        .as_ref()
        .map(|v| Ledger::load(&cell, &data_dir, v))
        .transpose()
    {
        Ok(l) => l.map(|l| Arc::new(Mutex::new(l))),
        Err(e) => {
            let _ = session.close().await;
            return Err(e);
        }
    };
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
        verification: None,
        refused: 0,
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
    let verify_q = session
        .declare_queryable(verify_key(&cell))
        .await
        .map_err(|e| anyhow!("declaring {}: {e}", verify_key(&cell)))?;
    let verifications_q = session
        .declare_queryable(verifications_key(&cell))
        .await
        .map_err(|e| anyhow!("declaring {}: {e}", verifications_key(&cell)))?;

    let refusals = Refusals::default();
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
                let mut cell_ready = match done {
                    Ok(Ok(c)) => c,
                    Ok(Err(e)) => break Err(e.context("preparing the cell")),
                    Err(e) => break Err(anyhow!("preparing the cell: {e}")),
                };
                cell_ready.stop_with(stopping.clone());
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
                let w_ledger = ledger.clone();
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
                            ledger: w_ledger.as_deref(),
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
            // While preparing, a rival that claimed first wins; once ready, newcomers see the
            // health token and step aside.
            rival = claim.rival(), if !prepared => {
                break Err(rival);
            }
            _ = &mut worker_gone, if worker.is_some() => {
                break Err(anyhow!("the scan worker stopped unexpectedly"));
            }
            q = scan_q.recv_async() => {
                let Ok(q) = q else { break Ok(()) };
                if !prepared || token.is_none() {
                    reply_error(&q, &scan_key(&cell), "the cell is starting: its pairs are being prepared; try again when ris/<cell>/health is alive", &refusals).await;
                    continue;
                }
                counter += 1;
                let desk = ScanDesk {
                    config: &config,
                    status: &status,
                    ledger: ledger.as_deref(),
                    session: &session,
                    refusals: &refusals,
                };
                handle_scan(&q, &desk, &tx, counter).await;
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
                handle_stream(&q, &config, prepared && token.is_some(), &status, &streams, &refusals).await;
            }
            q = point_q.recv_async() => {
                let Ok(q) = q else { break Ok(()) };
                handle_point(&q, &streams).await;
            }
            q = verify_q.recv_async() => {
                let Ok(q) = q else { break Ok(()) };
                handle_verify(&q, &cell, ledger.as_deref(), &session, &refusals).await;
            }
            q = verifications_q.recv_async() => {
                let Ok(q) = q else { break Ok(()) };
                if let Some(l) = &ledger {
                    let (c, l) = (cell.clone(), l.clone());
                    tokio::spawn(async move { handle_verifications(&q, &c, &l).await });
                }
            }
            q = health.recv_async() => {
                let Ok(q) = q else { break Ok(()) };
                let verification = ledger
                    .as_ref()
                    .and_then(|l| l.lock().ok().map(|l| l.health(unix_now())));
                let health = status.lock().ok().map(|s| Health {
                    stream: streams.status(),
                    verification,
                    refused: refusals.total(),
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
    drop(verify_q);
    drop(stream_q);
    drop(point_q);
    streams.stop();
    stopping.store(true, Ordering::SeqCst);
    drop(tx);
    // The running stage stops at its next iteration; one that does not (stuck in a driver or
    // a loop without a check) is left behind: risd exits anyway, and its unfinished scan is
    // removed at the next start.
    if let Some(worker) = worker {
        // Joined on a thread of its own, not the runtime's blocking pool: the runtime's shutdown
        // would wait for a worker left behind.
        let (joined_tx, joined) = tokio::sync::oneshot::channel();
        std::thread::spawn(move || {
            let _ = joined_tx.send(worker.join());
        });
        match tokio::time::timeout(STOP_WAIT, joined).await {
            Ok(joined) => joined
                .context("joining the scan worker")?
                .map_err(|_| anyhow!("the scan worker panicked"))?,
            Err(_) => tracing::error!(
                wait_s = STOP_WAIT.as_secs_f64(),
                "the running scan did not stop in time: risd exits without it"
            ),
        }
    }
    if let Some(w) = watchdog {
        w.abort();
    }
    drop(store_q);
    drop(verifications_q);
    drop(health);
    drop(token);
    drop(claim);
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

/// How long stopping waits for the running scan to end (SIGTERM ends risd within about this
/// and the Zenoh session's close).
const STOP_WAIT: Duration = Duration::from_millis(1000);

fn set_state(status: &Mutex<Health>, state: &str) {
    if let Ok(mut s) = status.lock() {
        s.state = state.into();
    }
}
