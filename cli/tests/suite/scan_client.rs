//! `ris scan` against the mock cell served in this process: an interrupted client says which
//! scan goes on and where its results are, and the scan does finish in risd.

use crate::common;

use std::io::BufRead;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::{cell_config, client, free_port, states, wait_end, InProcess};

#[test]
fn an_interrupted_scan_client_names_the_scan_that_goes_on() {
    let dir = tempfile::tempdir().expect("tmp");
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let mut config = cell_config(
        &root.join("config/mock-cell.toml"),
        &endpoint,
        &dir.path().join("data"),
    );
    // Each slide held 250 ms: the scan lasts about 20 s, so the interrupt reaches the client
    // while it runs even when the test thread waits seconds for a core (the mock cell's own
    // scan takes about 3 s, less than a loaded CI machine may take to deliver the signal).
    for sensor in &mut config.sensors {
        sensor.settle = Duration::from_millis(250);
    }
    let mut risd = InProcess::start(config);
    risd.wait_ready(Duration::from_secs(120));
    let watcher = client(&endpoint);
    let (_sub, seen) = states(&watcher, "mock");

    let mut scan = Command::new(env!("CARGO_BIN_EXE_ris"))
        .args(["scan", "--connect", &endpoint, "--cell", "mock", "--out"])
        .arg(dir.path().join("out"))
        .env("RIS_LOG", "info")
        .env("RUST_BACKTRACE", "0")
        .stderr(Stdio::piped())
        .spawn()
        .expect("ris scan");
    let mut lines = std::io::BufReader::new(scan.stderr.take().expect("stderr")).lines();
    // The id the client logs once risd accepted the scan.
    let t = Instant::now();
    let scan_id = loop {
        assert!(t.elapsed() < Duration::from_secs(60), "no scan accepted");
        let line = lines.next().expect("ris scan ended early").expect("utf8");
        if line.contains("scan accepted") {
            let id = line
                .split("scan_id=")
                .nth(1)
                .and_then(|r| r.split_whitespace().next())
                .expect("the scan id")
                .to_string();
            break id;
        }
    };
    let interrupted = Command::new("kill")
        .args(["-INT", &scan.id().to_string()])
        .status()
        .expect("kill");
    assert!(interrupted.success());
    let rest: Vec<String> = lines.map_while(Result::ok).collect();
    let status = scan.wait().expect("exit");
    assert!(!status.success(), "{rest:#?}");
    let said = rest.join("\n");
    assert!(
        said.contains(&format!("interrupted: scan {scan_id} goes on"))
            && said.contains(&format!("ris/mock/scans/{scan_id}/")),
        "{said}"
    );
    assert!(!dir.path().join("out").join(&scan_id).exists());
    // The scan the client left finishes in risd and is stored.
    let end = wait_end(&seen, &scan_id);
    assert_eq!(end["state"], "done", "{end}");
    assert!(dir
        .path()
        .join("data/scans")
        .join(&scan_id)
        .join("merged.ply")
        .is_file());
    risd.stop().expect("the service stops cleanly");
}
