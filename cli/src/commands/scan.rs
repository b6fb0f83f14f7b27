//! `ris scan`: the client of a running `risd` (SPEC §12). It asks `ris/<cell>/scan` for a
//! scan, follows the scan's state publications with a progress bar, and writes what it
//! receives (sensor and merged clouds, the inspection report, the final state) into
//! `<out>/<scan id>/`, fetching from the daemon's store anything the live stream missed.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{anyhow, bail, Context, Result};
use serde_json::Value;

use ris_daemon::protocol::{scans_key, Artefact, ScanItem, ScanMode, ScanReply, ScanRequest};

/// What to ask for and where to write it.
pub struct ScanArgs {
    /// Zenoh endpoints of the daemon (e.g. `tcp/127.0.0.1:7447`).
    pub connect: Vec<String>,
    /// Cell name.
    pub cell: String,
    /// Request fields (SPEC §12); `None` leaves the daemon's default.
    pub mode: Option<ScanMode>,
    /// Sensors to scan (empty: all).
    pub sensors: Vec<String>,
    /// Inspect (`Some(false)`: do not).
    pub inspect: Option<bool>,
    /// Part id.
    pub part: Option<String>,
    /// Free text stored with the scan.
    pub tag: Option<String>,
    /// The part's serial number, stored with the scan.
    pub serial: Option<String>,
    /// What a `verify` scan measures: the artefact and its position.
    pub verify: Option<(Artefact, String)>,
    /// Output directory; the scan lands in `<out>/<scan id>/`.
    pub out: PathBuf,
    /// Give up after this long without the scan finishing.
    pub timeout: Duration,
    /// Zenoh user and the file whose first line is its password, for a cell with
    /// `[zenoh.access]`.
    pub credentials: Option<(String, PathBuf)>,
}

/// The finished scan as received.
pub struct Received {
    /// Scan id.
    pub scan_id: String,
    /// Where it was written.
    pub dir: PathBuf,
    /// The final `done` state (timings, points, inspection summary).
    pub done: Value,
    /// Inspection verdict, when the scan inspected a part.
    pub verdict: Option<String>,
}

/// `ris scan`: the daemon, the request and where the results go.
#[derive(Clone, Debug, clap::Args)]
pub struct ScanCommand {
    /// How to reach the daemon.
    #[command(flatten)]
    pub daemon: super::client::DaemonArgs,
    /// Scan mode (gray, adaptive, single-shot); the daemon's default when omitted.
    #[arg(long, value_parser = ["gray", "adaptive", "single-shot"])]
    pub mode: Option<String>,
    /// Sensors to scan (repeat; default all).
    #[arg(long = "sensor")]
    pub sensors: Vec<String>,
    /// Part to inspect (default: the cell's only part, if it has one).
    #[arg(long)]
    pub part: Option<String>,
    /// Do not inspect.
    #[arg(long, conflicts_with = "part")]
    pub no_inspect: bool,
    /// Free text stored with the scan.
    #[arg(long)]
    pub tag: Option<String>,
    /// The part's serial number, stored with the scan (the station's history searches it).
    #[arg(long)]
    pub serial: Option<String>,
    /// Give up when the scan has not finished after this many seconds.
    #[arg(long, default_value_t = 300)]
    pub timeout_s: u64,
    /// Output directory.
    #[arg(long)]
    pub out: PathBuf,
}

/// Run `ris scan`: ask, follow, write, say what arrived; the exit status of the verdict
/// (see [`super::verdict_exit_code`]).
pub fn command(c: &ScanCommand) -> Result<Option<i32>> {
    let r = run(&ScanArgs {
        connect: c.daemon.connect.clone(),
        cell: c.daemon.cell.clone(),
        mode: c.mode.as_deref().and_then(ScanMode::parse),
        sensors: c.sensors.clone(),
        inspect: c.no_inspect.then_some(false),
        part: c.part.clone(),
        tag: c.tag.clone(),
        serial: c.serial.clone(),
        verify: None,
        out: c.out.clone(),
        timeout: Duration::from_secs(c.timeout_s),
        credentials: c.daemon.user.clone().zip(c.daemon.password_file.clone()),
    })?;
    println!(
        "scan {}: {} merged points, {:.2} s of computation after the last frame",
        r.scan_id,
        r.done["merged_points"],
        r.done["compute_after_last_frame"]
            .as_f64()
            .unwrap_or(f64::NAN)
    );
    for w in r.done["warnings"].as_array().into_iter().flatten() {
        println!("warning: {}", w.as_str().unwrap_or_default());
    }
    if let Some(v) = &r.verdict {
        println!("inspection: {}", v.to_uppercase());
    }
    println!("wrote {}", r.dir.display());
    Ok(r.verdict.as_deref().and_then(super::verdict_exit_code))
}

/// The request of `args`.
fn request(args: &ScanArgs) -> ScanRequest {
    ScanRequest {
        mode: args.mode,
        sensors: (!args.sensors.is_empty()).then(|| args.sensors.clone()),
        inspect: args.inspect,
        part: args.part.clone(),
        tag: args.tag.clone(),
        serial: args.serial.clone(),
        operator: None,
        artefact: args.verify.as_ref().map(|v| v.0),
        position: args.verify.as_ref().map(|v| v.1.clone()),
    }
}

/// The progress bar's (length, position) in frames: every planned sensor counts with its own
/// sequence once it reported one, else with the longest reported so far, so the total is known
/// from the first frame and does not grow as sensors start.
fn progress(planned: &[String], frames: &BTreeMap<String, (u64, u64)>) -> (u64, u64) {
    let typical = frames.values().map(|f| f.1).max().unwrap_or(0);
    let mut names: Vec<&String> = planned.iter().collect();
    names.extend(frames.keys().filter(|k| !planned.contains(k)));
    let length = names
        .iter()
        .map(|n| frames.get(*n).map_or(typical, |f| f.1))
        .sum();
    let position = frames.values().map(|f| f.0.min(f.1)).sum();
    (length, position)
}

/// Run the scan on tokio's multi-thread runtime (Zenoh needs it).
pub fn run(args: &ScanArgs) -> Result<Received> {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    let got = runtime.block_on(scan(args))?;
    // Files are written off the async runtime, once the session is closed.
    let dir = args.out.join(&got.scan_id);
    write(
        &dir,
        &got.clouds,
        got.report.as_deref(),
        &got.pages,
        &got.done,
    )?;
    let verdict = got.done["inspection"]["verdict"]
        .as_str()
        .map(str::to_string);
    Ok(Received {
        scan_id: got.scan_id,
        dir,
        done: got.done,
        verdict,
    })
}

/// What arrived for one scan.
struct Arrived {
    scan_id: String,
    clouds: BTreeMap<String, Vec<u8>>,
    report: Option<Vec<u8>>,
    /// The inspection's labelled map and one-page report (`deviation.png`, `report.html`).
    pages: Vec<(&'static str, Vec<u8>)>,
    done: Value,
}

/// A result item of a scan: its key's last chunks after `scans/<id>/`.
enum Item {
    State(Value),
    Cloud(String, Vec<u8>),
    Report(Vec<u8>),
}

fn classify(key: &str, payload: Vec<u8>) -> Option<(String, Item)> {
    let (_, id, item) = ScanItem::parse(key)?;
    match item {
        ScanItem::State => Some((id, Item::State(serde_json::from_slice(&payload).ok()?))),
        ScanItem::Cloud(name) => Some((id, Item::Cloud(name, payload))),
        ScanItem::Report => Some((id, Item::Report(payload))),
        _ => None,
    }
}

async fn scan(args: &ScanArgs) -> Result<Arrived> {
    // Registered before the scan is asked for, and kept: an interrupt that arrives while a
    // message is handled (between two waits) is held for the next wait instead of lost.
    let mut interrupt = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::interrupt())
        .context("listening for Ctrl-C")?;
    let session = super::client::open(&args.connect, args.credentials.as_ref()).await?;
    let cell = &args.cell;
    // Subscribe before asking, so that no publication of the scan is missed.
    let sub = session
        .declare_subscriber(scans_key(cell))
        .await
        .map_err(|e| anyhow!("subscribing to {}: {e}", scans_key(cell)))?;
    let reply: ScanReply = super::client::ask(
        &session,
        &ris_daemon::protocol::scan_key(cell),
        &request(args),
    )
    .await
    .with_context(|| format!("asking cell {cell:?} at {:?} for a scan", args.connect))?;
    let scan_id = reply.scan_id;
    let planned = reply.sensors;
    tracing::info!(%scan_id, "scan accepted");
    let pb = crate::progress::bar(0, "queued");
    let mut frames: BTreeMap<String, (u64, u64)> = BTreeMap::new();
    let mut clouds: BTreeMap<String, Vec<u8>> = BTreeMap::new();
    let mut report: Option<Vec<u8>> = None;
    let deadline = tokio::time::Instant::now() + args.timeout;
    let done = loop {
        let next = tokio::select! {
            next = tokio::time::timeout_at(deadline, sub.recv_async()) => next,
            _ = interrupt.recv() => {
                pb.abandon_with_message("interrupted");
                bail!(
                    "interrupted: scan {scan_id} goes on in risd; its results stay under ris/{cell}/scans/{scan_id}/ (state, report, cloud/<sensor>)"
                );
            }
        };
        let sample = next
            .map_err(|_| {
                anyhow!(
                    "scan {scan_id} did not finish within {} s; its results, when it finishes, are under ris/{cell}/scans/{scan_id}/",
                    args.timeout.as_secs()
                )
            })?
            .map_err(|e| anyhow!("the subscription ended: {e}"))?;
        let key = sample.key_expr().as_str().to_string();
        let Some((id, item)) = classify(&key, sample.payload().to_bytes().into_owned()) else {
            continue;
        };
        if id != scan_id {
            continue;
        }
        match item {
            Item::Cloud(name, bytes) => {
                clouds.insert(name, bytes);
            }
            Item::Report(bytes) => report = Some(bytes),
            Item::State(state) => match state["state"].as_str().unwrap_or("") {
                "acquiring" => {
                    let sensor = state["sensor"].as_str().unwrap_or("?").to_string();
                    let f = (
                        state["frame"].as_u64().unwrap_or(0),
                        state["frames"].as_u64().unwrap_or(0),
                    );
                    pb.set_message(format!("acquiring {sensor}"));
                    frames.insert(sensor, f);
                    let (length, position) = progress(&planned, &frames);
                    pb.set_length(length);
                    pb.set_position(position);
                }
                "reconstructing" => pb.set_message(format!(
                    "reconstructing {}",
                    state["sensor"].as_str().unwrap_or("?")
                )),
                "inspecting" => pb.set_message(format!(
                    "inspecting {}",
                    state["part"].as_str().unwrap_or("?")
                )),
                "failed" => {
                    pb.abandon_with_message("failed");
                    bail!(
                        "scan {scan_id} failed: {}",
                        state["reason"].as_str().unwrap_or("no reason given")
                    );
                }
                "done" => break state,
                other => pb.set_message(other.to_string()),
            },
        }
    };
    pb.finish_with_message("done");
    // The clouds and report precede `done` on the stream; fetch from the store whatever did
    // not arrive (a subscriber that was slow, a dropped sample).
    let mut expected: Vec<String> = done["sensors"]
        .as_array()
        .map(|a| {
            a.iter()
                .filter_map(|s| s["sensor"].as_str().map(str::to_string))
                .collect()
        })
        .unwrap_or_default();
    expected.push("merged".into());
    let inspected = done["inspection"].is_object();
    for name in &expected {
        if clouds.contains_key(name) {
            continue;
        }
        let key = ScanItem::Cloud(name.clone()).key(cell, &scan_id);
        let bytes = super::client::fetch(&session, &key).await?;
        clouds.insert(name.clone(), bytes);
    }
    if inspected && report.is_none() {
        report = Some(super::client::fetch(&session, &ScanItem::Report.key(cell, &scan_id)).await?);
    }
    let mut pages = Vec::new();
    if inspected {
        for (item, name) in [
            (ScanItem::Map, "deviation.png"),
            (ScanItem::Page, "report.html"),
        ] {
            pages.push((
                name,
                super::client::fetch(&session, &item.key(cell, &scan_id)).await?,
            ));
        }
    }
    drop(sub);
    session
        .close()
        .await
        .map_err(|e| anyhow!("closing the Zenoh session: {e}"))?;
    Ok(Arrived {
        scan_id,
        clouds,
        report,
        pages,
        done,
    })
}

/// Write the received scan into `dir` all at once (nothing half-written on failure).
fn write(
    dir: &Path,
    clouds: &BTreeMap<String, Vec<u8>>,
    report: Option<&[u8]>,
    pages: &[(&str, Vec<u8>)],
    done: &Value,
) -> Result<()> {
    ris_core::io::write_dir_atomically(dir, |tmp| {
        ris_core::io::create_dir(tmp)?;
        for (name, bytes) in clouds {
            ris_core::io::write_atomic(&tmp.join(format!("{name}.ply")), bytes)?;
        }
        for (name, bytes) in pages {
            ris_core::io::write_atomic(&tmp.join(name), bytes)?;
        }
        if let Some(r) = report {
            ris_core::io::write_atomic(&tmp.join("report.json"), r)?;
        }
        let state = serde_json::to_string_pretty(done).unwrap_or_default();
        ris_core::io::write_atomic(&tmp.join("scan.json"), state.as_bytes())
    })
    .with_context(|| format!("writing {}", dir.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_of_a_scan_are_classified() {
        let state = classify("ris/mock/scans/a1/state", br#"{"state":"done"}"#.to_vec());
        assert!(matches!(state, Some((id, Item::State(v))) if id == "a1" && v["state"] == "done"));
        let cloud = classify("ris/mock/scans/a1/cloud/s2", b"ply".to_vec());
        assert!(matches!(cloud, Some((_, Item::Cloud(n, _))) if n == "s2"));
        assert!(matches!(
            classify("ris/mock/scans/a1/report", b"{}".to_vec()),
            Some((_, Item::Report(_)))
        ));
        assert!(classify("ris/mock/scans/a1/state", b"not json".to_vec()).is_none());
        assert!(classify("ris/mock/scans/a1/other", vec![]).is_none());
        assert!(classify("ris/mock/health", vec![]).is_none());
    }

    #[test]
    fn the_progress_total_is_known_from_the_first_frame() {
        let planned: Vec<String> = ["s1", "s2", "s3", "s4"].map(String::from).to_vec();
        let mut frames = BTreeMap::new();
        let mut lengths = Vec::new();
        for (sensor, frame) in [
            ("s1", 1),
            ("s3", 1),
            ("s1", 42),
            ("s3", 42),
            ("s2", 5),
            ("s4", 42),
            ("s2", 42),
        ] {
            frames.insert(sensor.to_string(), (frame, 42));
            let (length, position) = progress(&planned, &frames);
            assert!(position <= length);
            lengths.push(length);
        }
        assert!(lengths.iter().all(|&l| l == 168), "{lengths:?}");
        assert_eq!(progress(&planned, &frames), (168, 168));
    }

    #[test]
    fn the_request_carries_only_what_was_given() {
        let mut args = ScanArgs {
            connect: vec!["tcp/127.0.0.1:7447".into()],
            cell: "mock".into(),
            credentials: None,
            mode: None,
            sensors: vec![],
            inspect: None,
            part: None,
            tag: None,
            serial: None,
            verify: None,
            out: PathBuf::from("out"),
            timeout: Duration::from_secs(1),
        };
        let json = |a: &ScanArgs| serde_json::to_value(request(a)).expect("json");
        assert_eq!(json(&args).to_string(), "{}");
        args.sensors = vec!["s1".into(), "s3".into()];
        args.inspect = Some(false);
        args.tag = Some("shift 2".into());
        let r = json(&args);
        assert_eq!(r["sensors"], serde_json::json!(["s1", "s3"]));
        assert_eq!(r["inspect"], false);
        assert_eq!(r["tag"], "shift 2");
        assert!(r.get("mode").is_none() && r.get("part").is_none());
        // What the client sends is what the daemon parses.
        args.mode = Some(ScanMode::SingleShot);
        let body = serde_json::to_vec(&request(&args)).expect("body");
        assert_eq!(ScanRequest::parse(&body).expect("parsed"), request(&args));
        assert_eq!(json(&args)["mode"], "single-shot");
        args.mode = Some(ScanMode::Verify);
        args.verify = Some((Artefact::BallBar, "bar-1".into()));
        let body = serde_json::to_vec(&request(&args)).expect("body");
        assert_eq!(ScanRequest::parse(&body).expect("parsed"), request(&args));
        assert_eq!(json(&args)["artefact"], "ball_bar");
        assert_eq!(json(&args)["position"], "bar-1");
    }
}
