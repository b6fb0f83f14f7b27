//! `ris stream`: start a running risd's single-shot stream, show it live (frames per second,
//! points, latency per sensor), stop it, and keep each sensor's last cloud and fusion picture.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::{Duration, Instant, SystemTime};

use anyhow::{anyhow, bail, Context, Result};

use super::client::ask;
use ris_daemon::protocol::{stream_sensor_key, StreamRequest};
use serde_json::Value;

/// What to stream and for how long.
pub struct StreamArgs {
    /// Zenoh endpoints of the daemon.
    pub connect: Vec<String>,
    /// Cell name.
    pub cell: String,
    /// Sensors (empty: all).
    pub sensors: Vec<String>,
    /// Frames per second asked (`None`: the cell's default).
    pub rate: Option<f64>,
    /// Stop once every sensor delivered this many frames.
    pub frames: Option<u64>,
    /// Stop after this long.
    pub seconds: Option<f64>,
    /// Leave the stream running when done.
    pub keep_running: bool,
    /// Write each sensor's last cloud and fusion picture here.
    pub out: Option<PathBuf>,
    /// Zenoh user and password file, for a cell with `[zenoh.access]`.
    pub credentials: Option<(String, PathBuf)>,
}

/// One sensor's stream as received.
#[derive(Clone, Debug, Default)]
pub struct Received {
    /// Clouds received.
    pub clouds: u64,
    /// Fusion pictures received.
    pub pictures: u64,
    /// Frame numbers the daemon skipped between received clouds (dropped or lost).
    pub skipped: u64,
    /// Timestamps (ns since the epoch) of the clouds, in arrival order.
    pub timestamps: Vec<u64>,
    /// Frame numbers of the clouds, in arrival order.
    pub frames: Vec<u64>,
    /// Points per cloud.
    pub points: Vec<usize>,
    /// Daemon latency (frame arrival to publication), ms, per cloud.
    pub daemon_ms: Vec<f64>,
    /// Frame arrival at the daemon to arrival here, ms, per cloud.
    pub end_to_end_ms: Vec<f64>,
    /// The last cloud (PLY) and picture (PNG).
    pub last_cloud: Vec<u8>,
    /// The last fusion picture (PNG).
    pub last_picture: Vec<u8>,
}

/// Stream as `args` says; per sensor what arrived.
pub fn run(args: &StreamArgs) -> Result<BTreeMap<String, Received>> {
    if args.connect.is_empty() {
        bail!("--connect: give the daemon's endpoint, e.g. tcp/127.0.0.1:7447");
    }
    if args.frames.is_none() && args.seconds.is_none() {
        bail!("say when to stop: --frames N or --seconds S");
    }
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    let got = runtime.block_on(stream(args))?;
    if let Some(dir) = &args.out {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        for (sensor, r) in &got {
            for (name, bytes) in [("ply", &r.last_cloud), ("png", &r.last_picture)] {
                if !bytes.is_empty() {
                    let path = dir.join(format!("{sensor}.{name}"));
                    ris_core::io::write_atomic(&path, bytes)
                        .with_context(|| format!("writing {}", path.display()))?;
                }
            }
        }
    }
    for (sensor, r) in &got {
        let median = |v: &[f64]| {
            let mut v = v.to_vec();
            v.sort_by(f64::total_cmp);
            v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
        };
        let span = match (r.timestamps.first(), r.timestamps.last()) {
            (Some(a), Some(b)) if b > a => (b - a) as f64 * 1e-9,
            _ => 0.0,
        };
        let fps = if span > 0.0 {
            (r.clouds.saturating_sub(1)) as f64 / span
        } else {
            0.0
        };
        let mean_points = r.points.iter().sum::<usize>() as f64 / (r.points.len().max(1)) as f64;
        println!(
            "{sensor}: {} clouds, {} pictures, {fps:.1} frames/s, {mean_points:.0} points, latency {:.0} ms in risd / {:.0} ms to here (median), {} frames skipped",
            r.clouds,
            r.pictures,
            median(&r.daemon_ms),
            median(&r.end_to_end_ms),
            r.skipped
        );
    }
    Ok(got)
}

async fn stream(args: &StreamArgs) -> Result<BTreeMap<String, Received>> {
    let session = super::client::open(&args.connect, args.credentials.as_ref()).await?;
    let cell = &args.cell;
    let sub = session
        .declare_subscriber(stream_sensor_key(cell, "*", "*"))
        .await
        .map_err(|e| anyhow!("subscribing to {}: {e}", stream_sensor_key(cell, "*", "*")))?;
    let request = StreamRequest {
        action: Some("start".into()),
        rate: args.rate,
        sensors: (!args.sensors.is_empty()).then(|| args.sensors.clone()),
    };
    let key = ris_daemon::protocol::stream_key(cell);
    let started: Value = ask(&session, &key, &request).await?;
    let sensors: Vec<String> = started["sensors"]
        .as_array()
        .map(|a| {
            a.iter()
                .filter_map(|s| s.as_str().map(str::to_string))
                .collect()
        })
        .unwrap_or_default();
    tracing::info!(?sensors, rate_hz = %started["rate_hz"], "streaming");
    let mut got: BTreeMap<String, Received> = sensors
        .iter()
        .map(|s| (s.clone(), Received::default()))
        .collect();
    let pb = crate::progress::spinner("waiting for the first frame");
    let t0 = Instant::now();
    let limit = args.seconds.map(Duration::from_secs_f64);
    let mut shown = Instant::now();
    let mut last_frame = Instant::now();
    let result = loop {
        if limit.is_some_and(|l| t0.elapsed() >= l) {
            break Ok(());
        }
        if let Some(n) = args.frames {
            if got.values().all(|r| r.clouds >= n) {
                break Ok(());
            }
        }
        let wait = limit.map_or(Duration::from_secs(2), |l| {
            l.saturating_sub(t0.elapsed()).min(Duration::from_secs(2))
        });
        let sample = match tokio::time::timeout(wait, sub.recv_async()).await {
            Ok(Ok(s)) => {
                last_frame = Instant::now();
                s
            }
            Ok(Err(e)) => break Err(anyhow!("the subscription ended: {e}")),
            Err(_) => {
                // No frame for a while: ask the daemon how the stream is.
                let status = StreamRequest {
                    action: Some("status".into()),
                    ..StreamRequest::default()
                };
                if let Ok(st) = ask::<_, Value>(&session, &key, &status).await {
                    match st["state"].as_str() {
                        Some("failed") => {
                            break Err(anyhow!(
                                "the stream failed: {}",
                                st["error"].as_str().unwrap_or("no reason given")
                            ))
                        }
                        Some("stopped") => {
                            break Err(anyhow!("the stream was stopped (by another client?)"))
                        }
                        _ => {}
                    }
                }
                if last_frame.elapsed() > Duration::from_secs(30) {
                    break Err(anyhow!("no stream frame for 30 s"));
                }
                continue;
            }
        };
        let parts: Vec<&str> = sample.key_expr().as_str().split('/').collect();
        let (Some(sensor), Some(what)) = (parts.get(3), parts.get(4)) else {
            continue;
        };
        let Some(r) = got.get_mut(*sensor) else {
            continue;
        };
        let meta: Value = sample
            .attachment()
            .and_then(|a| serde_json::from_slice(&a.to_bytes()).ok())
            .unwrap_or_default();
        let bytes = sample.payload().to_bytes().into_owned();
        match *what {
            "cloud" => {
                let frame = meta["frame"].as_u64().unwrap_or(0);
                let ts = meta["timestamp_ns"].as_u64().unwrap_or(0);
                if let Some(prev) = r.frames.last() {
                    r.skipped += frame.saturating_sub(prev + 1);
                }
                r.clouds += 1;
                r.frames.push(frame);
                r.timestamps.push(ts);
                r.points.push(meta["points"].as_u64().unwrap_or(0) as usize);
                r.daemon_ms
                    .push(meta["latency_ms"].as_f64().unwrap_or(f64::NAN));
                let now = SystemTime::now()
                    .duration_since(SystemTime::UNIX_EPOCH)
                    .map_or(0, |d| d.as_nanos() as u64);
                r.end_to_end_ms.push(now.saturating_sub(ts) as f64 * 1e-6);
                r.last_cloud = bytes;
            }
            "fused" => {
                r.pictures += 1;
                r.last_picture = bytes;
            }
            _ => continue,
        }
        if shown.elapsed() >= Duration::from_millis(250) {
            shown = Instant::now();
            let line: Vec<String> = got
                .iter()
                .map(|(s, r)| {
                    let n = r.timestamps.len();
                    let fps = if n >= 2 {
                        let span =
                            r.timestamps[n - 1].saturating_sub(r.timestamps[n.saturating_sub(10)]);
                        (n.min(10) - 1) as f64 / (span as f64 * 1e-9).max(1e-9)
                    } else {
                        0.0
                    };
                    format!(
                        "{s} {fps:.1}/s {} pts {:.0} ms",
                        r.points.last().copied().unwrap_or(0),
                        r.end_to_end_ms.last().copied().unwrap_or(f64::NAN)
                    )
                })
                .collect();
            pb.set_message(line.join(" | "));
        }
    };
    pb.finish_and_clear();
    if !args.keep_running {
        let stop = StreamRequest {
            action: Some("stop".into()),
            ..StreamRequest::default()
        };
        if let Err(e) = ask::<_, Value>(&session, &key, &stop).await {
            tracing::warn!(error = %format!("{e:#}"), "stopping the stream");
        }
    }
    let _ = session.close().await;
    result.map(|()| got)
}
