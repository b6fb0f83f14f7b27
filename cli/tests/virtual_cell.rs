//! The whole hardware stack without hardware: `ris virtual-cell` starts Xvfb cut into four
//! monitors and four `ris virtual-camera` processes (GigE Vision on 127.0.0.1–4, each frame
//! rendered under the light read back from its projector's monitor), and
//! `risd --config config/virtual-cell.toml` scans it through its projector windows and Aravis.
//! An independent Zenoh client (eclipse-zenoh in Python) scans; the clouds must lie on the
//! scenes' surfaces. Then a camera disappears mid-scan: that scan fails naming the sensor, risd
//! keeps serving, health shows the pair reconnecting, and once the camera is back the next
//! scan succeeds. A projector monitor that does not exist fails start-up naming it.
#![cfg(all(feature = "aravis", feature = "projector"))]

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use ris_cli::commands::virtual_cell::start_rig;
use ris_core::cloud::PointCloud;
use ris_core::geometry::Vec3;
use ris_core::sim::{Scene, Simulator};

#[path = "../../daemon/tests/common/mod.rs"]
mod common;
use common::{ask, client, free_port, output_within, states, wait_end, Risd, Watchdog};

fn repo() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// Mean |error| (mm) of a sensor cloud against the scene's truth at each point's pixel, and
/// the fraction of points that have truth there.
fn accuracy(cloud: &PointCloud, scene: &Scene) -> (f64, f64) {
    let truth = Simulator::new(scene.clone()).cache.truth.clone();
    let (w, h) = (scene.camera.width as i64, scene.camera.height as i64);
    let (mut sum, mut n) = (0.0, 0usize);
    for p in &cloud.points {
        let q = Vec3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
        let Some((u, v)) = scene.camera.project(&q) else {
            continue;
        };
        let (x, y) = (u.round() as i64, v.round() as i64);
        if x < 0 || y < 0 || x >= w || y >= h {
            continue;
        }
        let t = truth.xyz[(y * w + x) as usize];
        if !t[0].is_finite() {
            continue;
        }
        let t = Vec3::new(f64::from(t[0]), f64::from(t[1]), f64::from(t[2]));
        sum += (q - t).norm();
        n += 1;
    }
    (sum / n.max(1) as f64, n as f64 / cloud.len().max(1) as f64)
}

fn health(session: &zenoh::Session) -> serde_json::Value {
    let replies = ask(session, "ris/virtual/health", None);
    let text = replies
        .into_iter()
        .find_map(Result::ok)
        .expect("a health reply");
    serde_json::from_str(&text).expect("health json")
}

fn pair_state(h: &serde_json::Value, sensor: &str) -> String {
    h["pairs"]
        .as_array()
        .and_then(|a| a.iter().find(|p| p["sensor"] == sensor))
        .map(|p| p["state"].as_str().unwrap_or_default().to_string())
        .unwrap_or_default()
}

#[test]
fn risd_scans_the_virtual_cell_and_survives_a_lost_camera() {
    let dog = Watchdog::arm("virtual_cell", Duration::from_secs(480));
    let ris = Path::new(env!("CARGO_BIN_EXE_ris"));
    let rig_file = repo().join("config/virtual-cell/rig.toml");
    dog.stage("starting the virtual rig");
    let mut rig = start_rig(&rig_file, ris, None).expect("the virtual rig");
    for pid in rig.pids() {
        dog.watch(pid);
    }
    let data = tempfile::tempdir().expect("tmp");
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let config = repo().join("config/virtual-cell.toml");

    // A projector monitor that does not exist fails start-up, naming it.
    dog.stage("risd with a missing projector monitor");
    let bad_dir = tempfile::tempdir().expect("tmp");
    let cfg = repo().join("config").display().to_string();
    let text = std::fs::read_to_string(&config)
        .expect("config")
        .replace("projector_monitor = 3", "projector_monitor = 9")
        .replace("\"virtual-cell/", &format!("\"{}/virtual-cell/", cfg))
        .replace("\"mock-cell/", &format!("\"{}/mock-cell/", cfg));
    let bad = bad_dir.path().join("bad.toml");
    std::fs::write(&bad, text).expect("write");
    let o = output_within(
        Command::new(common::binary("risd"))
            .arg("--config")
            .arg(&bad)
            .args(["--once", "--data-dir"])
            .arg(bad_dir.path().join("data"))
            .env("DISPLAY", &rig.display)
            .env("NO_COLOR", "1"),
        Duration::from_secs(120),
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("monitor 9") && err.contains("sensor s4"),
        "the error names the sensor and the monitor: {err}"
    );

    dog.stage("starting risd");
    let mut risd = Risd::start_env(
        &[
            "--config".as_ref(),
            config.as_os_str(),
            "--listen".as_ref(),
            endpoint.as_ref(),
            "--data-dir".as_ref(),
            data.path().as_os_str(),
        ],
        &[("DISPLAY", &rig.display)],
    );
    dog.watch(risd.pid());
    risd.wait_ready(Duration::from_secs(120));

    // An independent client scans (twice, the first inspecting the part).
    dog.stage("the Python client scans");
    // (python3 with the eclipse-zenoh package; .ci/run installs it)
    let out = output_within(
        Command::new("python3")
            .arg("-u")
            .arg(repo().join("tests/zenoh_client.py"))
            .args([&endpoint, "virtual", "s1", "s2", "s3", "s4"]),
        Duration::from_secs(300),
    );
    let text = String::from_utf8_lossy(&out.stdout);
    eprintln!("{text}{}", String::from_utf8_lossy(&out.stderr));
    if !(out.status.success() && text.contains("1 passed, 0 failed")) {
        panic!(
            "the client failed: {text}\nrisd's log, last lines:\n{}",
            risd.kill_for_log(60)
        );
    }

    // The clouds lie on the scenes' surfaces.
    dog.stage("checking the clouds");
    let mut scans: Vec<_> = std::fs::read_dir(data.path().join("scans"))
        .expect("scans")
        .flatten()
        .map(|e| e.path())
        .collect();
    scans.sort();
    let scan = scans.first().expect("a scan");
    for s in ["s1", "s2", "s3", "s4"] {
        let scene = Scene::load(&repo().join(format!("config/mock-cell/{s}.toml"))).expect(s);
        let cloud = PointCloud::read_ply(&scan.join(format!("{s}.ply"))).expect("cloud");
        let (mean, with_truth) = accuracy(&cloud, &scene);
        eprintln!(
            "{s}: {} points, mean |error| {mean:.4} mm against the scene, {:.2} % with truth",
            cloud.len(),
            100.0 * with_truth
        );
        assert!(cloud.len() > 300_000, "{s}: {} points", cloud.len());
        assert!(mean <= 0.1, "{s}: mean |error| {mean} mm");
        assert!(with_truth > 0.99, "{s}: {with_truth}");
    }
    let merged = PointCloud::read_ply(&scan.join("merged.ply")).expect("merged");
    let off = merged
        .points
        .iter()
        .map(|p| {
            let (x, y, z) = (f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
            (z + x * x / 5000.0 + y * y / 8000.0).abs()
        })
        .sum::<f64>()
        / merged.len() as f64;
    eprintln!(
        "merged: {} points, mean |off the panel| {off:.4} mm",
        merged.len()
    );
    assert!(off <= 0.1, "merged cloud {off} mm off the panel");

    // A camera disappears mid-scan.
    dog.stage("opening a Zenoh session");
    let session = client(&endpoint);
    dog.stage("subscribing to the scan states");
    let (_sub, st) = states(&session, "virtual");
    // Let the subscription reach risd before the scan starts publishing.
    std::thread::sleep(Duration::from_secs(1));
    dog.stage("a scan that loses camera s2");
    let accepted = ask(&session, "ris/virtual/scan", Some(r#"{"inspect": false}"#));
    let reply: serde_json::Value =
        serde_json::from_str(accepted[0].as_ref().expect("accepted")).expect("json");
    let id = reply["scan_id"].as_str().expect("id").to_string();
    let t = Instant::now();
    let mut seen = Vec::new();
    loop {
        assert!(
            t.elapsed() < Duration::from_secs(60),
            "s2 never acquired in {id}: {seen:?}"
        );
        if let Ok((sid, v)) = st.recv_timeout(Duration::from_millis(100)) {
            seen.push((sid.clone(), v.clone()));
            if sid == id
                && v["state"] == "acquiring"
                && v["sensor"] == "s2"
                && v["frame"].as_u64() >= Some(5)
            {
                break;
            }
        }
    }
    rig.kill_camera(1);
    dog.stage("waiting for the failed scan");
    let end = wait_end(&st, &id);
    assert_eq!(end["state"], "failed", "{end}");
    let reason = end["reason"].as_str().unwrap_or_default();
    assert!(
        reason.contains("sensor s2"),
        "the reason names the sensor: {reason}"
    );
    let h = health(&session);
    assert_eq!(pair_state(&h, "s2"), "reconnecting", "{h}");
    assert_eq!(pair_state(&h, "s1"), "connected", "{h}");

    // It comes back: health shows it connected again, and the next scan succeeds.
    dog.stage("camera s2 back");
    rig.restart_camera(ris, &rig_file, 1).expect("camera back");
    for pid in rig.pids() {
        dog.watch(pid);
    }
    let t = Instant::now();
    while pair_state(&health(&session), "s2") != "connected" {
        assert!(
            t.elapsed() < Duration::from_secs(60),
            "s2 did not reconnect: {}",
            health(&session)
        );
        std::thread::sleep(Duration::from_millis(500));
    }
    let accepted = ask(&session, "ris/virtual/scan", Some(r#"{"inspect": false}"#));
    let reply: serde_json::Value =
        serde_json::from_str(accepted[0].as_ref().expect("accepted")).expect("json");
    let id = reply["scan_id"].as_str().expect("id").to_string();
    dog.stage("the scan after the reconnection");
    let end = wait_end(&st, &id);
    dog.stage("SIGTERM");
    let (status, log) = risd.terminate();
    // risd's own account of the scan says which device stalled. Twice on a fresh machine,
    // camera s4 (never restarted) kept answering but sent no frame after s2 came back, for
    // four triggers of 10 s; the sequencer now reopens a camera silent on two triggers.
    assert_eq!(
        end["state"],
        "done",
        "{end}\nrisd's log, last lines:\n{}",
        log[log.len().saturating_sub(60)..].join("\n")
    );
    assert!(status.success(), "{log:#?}");
}
