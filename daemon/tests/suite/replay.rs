//! Replay: a scan of the built-in mock cell kept with its captures is re-run through
//! `config/replay-cell.toml` (every pair a `replay` backend serving the recorded capture set
//! through the same sequencer, decoder and merge) and gives the recorded scan's clouds exactly.

use crate::common;

use std::path::Path;
use std::process::Command;

use ris_core::cloud::PointCloud;

#[test]
fn a_replayed_scan_equals_the_recorded_scan() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    // Where config/replay-cell.toml expects the recording.
    let recording = root.join("target/mock-recording");
    let _ = std::fs::remove_dir_all(&recording);
    let recorded = common::record(&recording, "mock", &[]);
    for s in ["s1", "s2", "s3", "s4"] {
        assert!(
            recorded
                .join("captures")
                .join(s)
                .join("capture.toml")
                .is_file(),
            "{s}'s capture was not kept"
        );
    }
    let replayed_dir = tempfile::tempdir().expect("tmp");
    let o = Command::new(env!("CARGO_BIN_EXE_risd"))
        .arg("--config")
        .arg(root.join("config/replay-cell.toml"))
        .args(["--once", "--scan-id", "replayed", "--data-dir"])
        .arg(replayed_dir.path())
        .output()
        .expect("risd");
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "replay: {out}{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let replayed = replayed_dir.path().join("scans/replayed");
    for name in ["s1", "s2", "s3", "s4", "merged"] {
        let a = PointCloud::read_ply(&recorded.join(format!("{name}.ply"))).expect("recorded");
        let b = PointCloud::read_ply(&replayed.join(format!("{name}.ply"))).expect("replayed");
        assert!(a.len() > 100_000, "{name}: {} points", a.len());
        assert_eq!(a.points, b.points, "{name}: the replayed cloud differs");
        assert_eq!(a.confidence, b.confidence, "{name}: confidences differ");
    }
    let report = |dir: &Path| -> serde_json::Value {
        serde_json::from_slice(&std::fs::read(dir.join("report.json")).expect("report.json"))
            .expect("json")
    };
    assert_eq!(
        report(&recorded)["statistics"],
        report(&replayed)["statistics"],
        "the inspection of the replay differs"
    );
    assert!(out.contains("part panel: PASS"), "{out}");
}
