//! `risd` as a service on 127.0.0.1, driven by an independent Zenoh client (the eclipse-zenoh
//! Python package, installed by `.ci/run`), then stopped with SIGTERM; and a `risd --once`
//! killed with SIGKILL mid-scan, which must leave nothing that looks like a finished scan.

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use crate::common;
use common::{free_port, output_within, Risd};

fn repo() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn signal(pid: u32, sig: &str) {
    let ok = Command::new("kill")
        .args([sig, &pid.to_string()])
        .status()
        .is_ok_and(|s| s.success());
    assert!(ok, "kill {sig} {pid}");
}

#[test]
fn independent_zenoh_client_scans_twice_then_sigterm_stops_cleanly() {
    let have_client = Command::new("python3")
        .args(["-c", "import zenoh"])
        .status()
        .is_ok_and(|s| s.success());
    assert!(
        have_client,
        "the eclipse-zenoh Python package is missing: run .ci/run (it installs it), or pip install eclipse-zenoh"
    );
    let data = tempfile::tempdir().expect("tmp");
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let config = repo().join("config/mock-cell.toml");
    let mut risd = Risd::start(&[
        "--config".as_ref(),
        config.as_os_str(),
        "--listen".as_ref(),
        endpoint.as_ref(),
        "--data-dir".as_ref(),
        data.path().as_os_str(),
    ]);
    risd.wait_ready(Duration::from_secs(120));
    let client = output_within(
        Command::new("python3")
            .arg("-u")
            .arg(repo().join("tests/zenoh_client.py"))
            .args([&endpoint, "mock", "s1", "s2", "s3", "s4"]),
        Duration::from_secs(300),
    );
    let out = String::from_utf8_lossy(&client.stdout).into_owned();
    eprintln!("{out}{}", String::from_utf8_lossy(&client.stderr));
    // Our own client: `ris scan` writes what it receives; a refused request fails clearly.
    let received = tempfile::tempdir().expect("tmp");
    let ris_scan = |extra: &[&str]| {
        output_within(
            Command::new(common::binary("ris"))
                .args(["scan", "--connect", &endpoint, "--cell", "mock", "--out"])
                .arg(received.path())
                .args(extra),
            Duration::from_secs(180),
        )
    };
    let scan_out = ris_scan(&["--sensor", "s1", "--sensor", "s2", "--tag", "ris scan"]);
    let refused = ris_scan(&["--sensor", "s9"]);
    let t = Instant::now();
    let (status, lines) = risd.terminate();
    assert!(
        client.status.success(),
        "client failed; risd log: {lines:#?}"
    );
    assert!(out.contains("1 passed, 0 failed"), "{out}");
    assert!(status.success(), "risd exit {status:?}; log: {lines:#?}");
    let text = String::from_utf8_lossy(&scan_out.stdout).into_owned();
    assert!(
        scan_out.status.success(),
        "ris scan: {text}{}",
        String::from_utf8_lossy(&scan_out.stderr)
    );
    assert!(text.contains("inspection: PASS"), "{text}");
    let got: Vec<_> = std::fs::read_dir(received.path())
        .expect("received")
        .flatten()
        .map(|e| e.path())
        .collect();
    assert_eq!(got.len(), 1, "{got:?}");
    for f in ["s1.ply", "s2.ply", "merged.ply", "report.json", "scan.json"] {
        assert!(
            got[0].join(f).is_file(),
            "{f} missing in {}",
            got[0].display()
        );
    }
    assert!(
        !got[0].join("s3.ply").exists(),
        "only s1 and s2 were asked for"
    );
    let merged = ris_core::cloud::PointCloud::read_ply(&got[0].join("merged.ply")).expect("ply");
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(got[0].join("report.json")).expect("report"))
            .expect("json");
    assert_eq!(report["verdict"], "pass");
    assert!(
        merged.len() > 500_000
            && report["statistics"]["points"].as_u64() <= Some(merged.len() as u64),
        "{} merged points",
        merged.len()
    );
    let err = String::from_utf8_lossy(&refused.stderr);
    assert!(
        !refused.status.success() && err.contains("refused") && err.contains("s9"),
        "{err}"
    );
    eprintln!(
        "risd stopped {:.1} s after SIGTERM",
        t.elapsed().as_secs_f64()
    );
    // The three scans (two of the Python client, one of `ris scan`) are stored complete.
    let scans: Vec<_> = std::fs::read_dir(data.path().join("scans"))
        .expect("scans")
        .flatten()
        .collect();
    assert_eq!(scans.len(), 3);
    let inspected = scans
        .iter()
        .filter(|s| {
            s.path().join("report.json").is_file() && s.path().join("deviation.png").is_file()
        })
        .count();
    assert_eq!(
        inspected, 2,
        "the client's first scan and `ris scan` inspect the part, the client's second does not"
    );
    for s in scans {
        for f in ["s1.ply", "s2.ply", "merged.ply", "scan.json"] {
            assert!(
                s.path().join(f).is_file(),
                "{f} missing in {}",
                s.path().display()
            );
        }
    }
}

#[test]
fn sigkill_mid_scan_leaves_no_scan_that_looks_complete() {
    let data = tempfile::tempdir().expect("tmp");
    // The mock cell with each slide held 250 ms: the second group's acquisition lasts about
    // 10 s, so the kill lands mid-scan even when the test thread waits seconds for a core.
    let mock = repo().join("config/mock-cell.toml");
    let text = std::fs::read_to_string(&mock)
        .expect("mock cell")
        .replace(
            "\"mock-cell/",
            &format!("\"{}/", repo().join("config/mock-cell").display()),
        )
        .replace(
            "exposure_us = 10000.0",
            "exposure_us = 10000.0\nsettle_ms = 250.0",
        );
    assert_eq!(
        text.matches("settle_ms").count(),
        4,
        "the mock cell's four sensors"
    );
    let cell_dir = tempfile::tempdir().expect("tmp");
    let config = cell_dir.path().join("cell.toml");
    std::fs::write(&config, text).expect("cell file");
    let mut risd = Command::new(env!("CARGO_BIN_EXE_risd"))
        .args(["--once", "--config"])
        .arg(&config)
        .arg("--data-dir")
        .arg(data.path())
        .arg("--cache-dir")
        .arg(common::shared_cache())
        .env("RIS_LOG", "info")
        .env("NO_COLOR", "1")
        .stderr(Stdio::piped())
        .spawn()
        .expect("risd");
    let stderr = risd.stderr.take().expect("stderr");
    // Kill it while the first group is acquiring.
    for line in BufReader::new(stderr).lines().map_while(Result::ok) {
        if line.contains("sequence recorded") {
            break;
        }
    }
    signal(risd.id(), "-KILL");
    let _ = risd.wait();
    let scans = data.path().join("scans");
    let entries: Vec<String> = std::fs::read_dir(&scans)
        .expect("scans")
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    for name in &entries {
        assert!(
            name.ends_with(".partial"),
            "{name} looks finished after SIGKILL"
        );
    }
    let removed = ris_daemon::store::housekeeping(data.path(), 50, 30).expect("housekeeping");
    assert_eq!(removed.len(), entries.len());
    assert_eq!(std::fs::read_dir(&scans).expect("scans").count(), 0);
}
