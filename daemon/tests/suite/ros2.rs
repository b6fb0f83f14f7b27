//! ROS 2 clouds: the mock cell with `[ros2] enable = true` on 127.0.0.1, read by an independent
//! ROS 2 subscriber (`tests/ros2_client.py`: eclipse-zenoh and the `rosbags` CDR
//! deserialiser, installed by `.ci/run`). It finds the node and publishers in rmw_zenoh's
//! liveliness tokens, scans once, and checks every PointCloud2 against the PLY risd wrote.

use std::path::Path;
use std::process::Command;
use std::time::Duration;

use crate::common;
use common::{cell_config, free_port, output_within, InProcess};

fn repo() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

#[test]
fn an_independent_ros2_subscriber_decodes_every_cloud() {
    let have = Command::new("python3")
        .args(["-c", "import zenoh, rosbags, numpy"])
        .status()
        .is_ok_and(|s| s.success());
    assert!(
        have,
        "python3 with eclipse-zenoh, rosbags and numpy is missing: run .ci/run (it installs them)"
    );
    let dir = tempfile::tempdir().expect("tmp");
    let config_dir = repo().join("config");
    let mock = std::fs::read_to_string(config_dir.join("mock-cell.toml")).expect("mock cell");
    let config = mock.replace(
        "\"mock-cell/",
        &format!("\"{}/mock-cell/", config_dir.display()),
    ) + "\n[ros2]\nenable = true\nframe_id = \"cell\"\n\n[ros2.sensor_frames]\ns2 = \"s2_optical\"\n";
    let config_path = dir.path().join("cell.toml");
    std::fs::write(&config_path, config).expect("config");
    let data = dir.path().join("data");
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    // The service in this process: what it publishes is under test, not the process.
    let mut risd = InProcess::start(cell_config(&config_path, &endpoint, &data));
    risd.wait_ready(Duration::from_secs(120));
    let sensors = ["s1", "s2", "s3", "s4"];
    let client = output_within(
        Command::new("python3")
            .arg("-u")
            .arg(repo().join("tests/ros2_client.py"))
            .arg(&endpoint)
            .arg("mock")
            .arg(&data)
            .args(sensors),
        Duration::from_secs(300),
    );
    let stopped = risd.stop();
    let out = String::from_utf8_lossy(&client.stdout).into_owned();
    assert!(
        client.status.success(),
        "the ROS 2 client failed: {out}{}",
        String::from_utf8_lossy(&client.stderr)
    );
    stopped.expect("the service stops cleanly");
    eprintln!("{out}");
    let summary: serde_json::Value =
        serde_json::from_str(out.lines().last().expect("a summary")).expect("json");
    assert_eq!(
        summary["type_hash"],
        ris_core::cloud::pointcloud2::TYPE_HASH,
        "rosbags computes the same type hash"
    );
    let clouds = &summary["clouds"];
    for s in sensors {
        let c = &clouds[s];
        assert_eq!(
            (c["width"].as_u64(), c["height"].as_u64()),
            (Some(800), Some(600)),
            "{s}: organised at its camera's size"
        );
        assert!(c["points"].as_u64() > Some(200_000), "{s}: {c}");
        assert!(c["max_error_mm"].as_f64() < Some(1e-3), "{s}: {c}");
        let frame = if s == "s2" { "s2_optical" } else { "" };
        if !frame.is_empty() {
            assert_eq!(c["frame_id"], frame);
        } else {
            assert_eq!(c["frame_id"], format!("mock_{s}"));
        }
        assert_eq!(c["sequence"], 1);
    }
    assert_eq!(clouds["merged"]["frame_id"], "cell");
    assert_eq!(clouds["merged"]["height"], 1);
    let gids: std::collections::BTreeSet<&str> = clouds
        .as_object()
        .expect("clouds")
        .values()
        .map(|c| c["gid"].as_str().expect("gid"))
        .collect();
    assert_eq!(gids.len(), 5, "one gid per publisher");
}
