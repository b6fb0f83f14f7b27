//! `risd`: configuration errors name the file and field, the reference configuration documents
//! every key, and `--once` scans the built-in mock cell into a complete scan directory.

use std::path::Path;
use std::process::Command;

use ris_daemon::config::CellConfig;
use ris_daemon::scan::ScanOptions;

use crate::common;

fn config_dir() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../config")
}

#[test]
fn reference_and_mock_cell_configs_parse() {
    let r = CellConfig::load(&config_dir().join("reference.toml")).expect("reference.toml");
    assert_eq!(r.sensors.len(), 1);
    assert_eq!(r.parts.len(), 1);
    let m = CellConfig::load(&config_dir().join("mock-cell.toml")).expect("mock-cell.toml");
    assert_eq!(m.name, "mock");
    assert_eq!(m.sensors.len(), 4);
    assert_eq!(m.exposure_groups().len(), 2);
    m.check_files().expect("mock cell files");
    let v = CellConfig::load(&config_dir().join("virtual-cell.toml")).expect("virtual-cell.toml");
    assert_eq!(v.sensors.len(), 4);
    assert!(v
        .sensors
        .iter()
        .all(|s| s.backend == ris_daemon::config::Backend::Aravis));
    v.check_files().expect("virtual cell files");
    let o = CellConfig::load(&config_dir().join("omni-cell.toml")).expect("omni-cell.toml");
    assert_eq!(o.sensors[0].kind, ris_daemon::config::SensorKind::Omni);
    o.check_files().expect("omni cell files");
    let r = CellConfig::load(&config_dir().join("replay-cell.toml")).expect("replay-cell.toml");
    assert!(r
        .sensors
        .iter()
        .all(|s| matches!(s.backend, ris_daemon::config::Backend::Replay { .. })));
}

#[test]
fn config_errors_name_the_field() {
    let base = config_dir();
    let bare =
        "[cell]\nname = \"c\"\n[[sensor]]\nname = \"s1\"\nbackend = \"mock\"\nscene = \"x.toml\"\n";
    let identity =
        "to_common = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]\n";
    let ok = &format!("{bare}{identity}");
    assert!(CellConfig::parse(ok, &base, "t.toml").is_ok());
    let aravis = "[cell]\nname = \"c\"\n[[sensor]]\nname = \"s1\"\nbackend = \"aravis\"\ndevice = \"127.0.0.1\"\nsensor_file = \"s.toml\"\n";
    for (text, needle) in [
        ("[cell]\nname = \"bad name\"\n", "cell.name"),
        ("[cell]\nname = \"c\"\ncolour = 1\n", "unknown field"),
        ("[cell]\nname = \"c\"\n", "no [[sensor]]"),
        (
            "[cell]\nname = \"c\"\n[[sensor]]\nname = \"s1\"\nbackend = \"gige\"\n",
            "sensor[0].backend",
        ),
        (
            "[cell]\nname = \"c\"\n[[sensor]]\nname = \"s1\"\nbackend = \"aravis\"\ndevice = \"1.2.3.4\"\n",
            "sensor[0].sensor_file",
        ),
        (
            "[cell]\nname = \"c\"\n[[sensor]]\nname = \"s1\"\nbackend = \"mock\"\n",
            "sensor[0].scene",
        ),
        (
            &format!("{ok}[[sensor]]\nname = \"s1\"\nbackend = \"mock\"\nscene = \"y.toml\"\n"),
            "sensor[1].name",
        ),
        (
            &format!("{ok}exposure_us = -5.0\n"),
            "sensor[0].exposure_us",
        ),
        (
            &format!("{bare}to_common = [[2.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]\n"),
            "sensor[0].to_common",
        ),
        (bare, "sensor[0].to_common"),
        (aravis, "sensor[0].projector_monitor"),
        (
            &format!("{aravis}projector_monitor = 1\nscene = \"x.toml\"\n"),
            "sensor[0].scene",
        ),
        (
            &format!("{aravis}projector_monitor = 1\ntrigger = \"sometimes\"\n"),
            "sensor[0].trigger",
        ),
        (&format!("{ok}trigger = \"hardware\"\n"), "sensor[0].trigger"),
        (&format!("{ok}kind = \"lidar\"\n"), "sensor[0].kind"),
        (
            "[cell]\nname = \"c\"\n[[sensor]]\nname = \"o\"\nkind = \"omni\"\nbackend = \"replay\"\nrecording = \"r\"\n",
            "sensor[0].backend",
        ),
        (
            &format!("{aravis}projector_monitor = 1\nkind = \"omni\"\n"),
            "sensor[0].to_common",
        ),
        (&format!("{ok}trigger_line = \"Line1\"\n"), "sensor[0].trigger_line"),
        (
            &format!("{aravis}projector_monitor = 1\ntrigger = \"hardware\"\ntrigger_line = \"\"\n"),
            "sensor[0].trigger_line",
        ),
        (&format!("{ok}device = \"/dev/video0\"\n"), "sensor[0].device"),
        (&format!("{ok}gain_db = -3.0\n"), "sensor[0].gain_db"),
        (&format!("{ok}settle_ms = 1e9\n"), "sensor[0].settle_ms"),
        (&format!("{ok}frame_timeout_ms = 0\n"), "sensor[0].frame_timeout_ms"),
        (&format!("{ok}range_mm = [1800.0, 1400.0]\n"), "sensor[0].range_mm"),
        (&format!("{ok}range_mm = [-1.0, 5.0]\n"), "sensor[0].range_mm"),
        (
            "[cell]\nname = \"c\"\n[[sensor]]\nname = \"s1\"\nbackend = \"replay\"\nscene = \"x.toml\"\n",
            "sensor[0].recording",
        ),
        (
            "[cell]\nname = \"c\"\n[[sensor]]\nname = \"s1\"\nbackend = \"replay\"\nrecording = \"r\"\n",
            "sensor[0].scene",
        ),
        ("[cell]\nname = \"c\"\n[zenoh]\nmode = \"router\"\n", "zenoh.mode"),
        (&format!("{ok}[workers]\nqueue = 1000000000000000\n"), "workers.queue"),
        (&format!("{ok}exposure_us = 1e300\n"), "sensor[0].exposure_us"),
        (&format!("[zenoh]\nlisten = [\"tcp/127.0.0.1:99999\"]\n{ok}"), "zenoh.listen"),
        (&format!("[zenoh]\nlisten = [\"foo/bar\"]\n{ok}"), "zenoh.listen"),
        (&format!("[zenoh]\nconnect = [\"tcp/127.0.0.1\"]\n{ok}"), "zenoh.connect"),
        (
            &format!("{ok}[[part]]\nid = \"p\"\ncad = \"p.stl\"\ntolerance = 0.0\n"),
            "part[0].tolerance",
        ),
        (&format!("{ok}[ros2]\ndomain_id = 300\n"), "ros2.domain_id"),
        (
            &format!("{ok}[[single_shot.dense]]\nx = [500.0, 100.0]\ny = [0.0, 100.0]\nstep = [10, 10]\n"),
            "single_shot.dense[0]",
        ),
        (
            &format!("{ok}[[single_shot.dense]]\nx = [0.0, 100.0]\ny = [0.0, 100.0]\nstep = [20, 10]\n"),
            "single_shot.dense[0]",
        ),
        (&format!("{ok}[ros2]\nenable = true\nnamespace = \"ris\"\n"), "ros2.namespace"),
        (&format!("{ok}[ros2]\nenable = true\nnode = \"r-d\"\n"), "ros2.node"),
        (&format!("{ok}[ros2]\nframe_id = \"a b\"\n"), "ros2.frame_id"),
        (&format!("{ok}[ros2.sensor_frames]\ns9 = \"f\"\n"), "ros2.sensor_frames.s9"),
        (
            &format!("{}[ros2]\nenable = true\n", ok.replace("name = \"s1\"", "name = \"1s\"")),
            "sensor.name",
        ),
    ] {
        let err = CellConfig::parse(text, &base, "t.toml").expect_err(text);
        let msg = format!("{err:#}");
        assert!(msg.contains("t.toml") && msg.contains(needle), "{needle}: {msg}");
    }
}

/// The shipped examples validate as they ship in a build with every backend (the test build);
/// the reference with a sensor file that is not there is refused naming the sensor and the
/// file; a build without a backend refuses it naming the feature.
#[test]
fn check_config_passes_the_shipped_examples_and_reports_missing_files() {
    let check = |path: &Path| {
        Command::new(env!("CARGO_BIN_EXE_risd"))
            .arg("--check-config")
            .arg(path)
            .env("RIS_LOG", "warn")
            .env("RUST_BACKTRACE", "0")
            .output()
            .expect("risd")
    };
    for name in [
        "mock-cell",
        "omni-cell",
        "reference",
        "virtual-cell",
        "verify-cell",
    ] {
        let o = check(&config_dir().join(format!("{name}.toml")));
        let out = String::from_utf8_lossy(&o.stdout);
        let built = cfg!(all(feature = "aravis", feature = "projector"));
        if built || matches!(name, "mock-cell" | "omni-cell" | "verify-cell") {
            assert!(
                o.status.success() && out.contains(": ok"),
                "{name}: {out}{}",
                String::from_utf8_lossy(&o.stderr)
            );
        } else {
            let err = String::from_utf8_lossy(&o.stderr);
            assert!(
                !o.status.success() && err.contains("--features aravis"),
                "{name}: {err}"
            );
        }
    }
    let copy = tempfile::tempdir().expect("tmp");
    let text = std::fs::read_to_string(config_dir().join("reference.toml"))
        .expect("reference")
        .replace("\"virtual-cell/s1.toml\"", "\"sensors/s1.toml\"")
        .replace(
            "\"mock-cell/",
            &format!("\"{}/mock-cell/", config_dir().display()),
        );
    let missing = copy.path().join("reference.toml");
    std::fs::write(&missing, text).expect("write");
    let o = check(&missing);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    if cfg!(all(feature = "aravis", feature = "projector")) {
        assert!(
            err.contains("sensor s1") && err.contains("sensors/s1.toml"),
            "{err}"
        );
    }
    // A part whose CAD has no usable triangle (three equal corners) is refused by the check,
    // not found by the first scan.
    let dir = tempfile::tempdir().expect("tmp");
    let mut stl = vec![0u8; 80];
    stl.extend_from_slice(&1u32.to_le_bytes());
    stl.extend_from_slice(&[0u8; 12]);
    for _ in 0..3 {
        for c in [1.0f32, 2.0, 3.0] {
            stl.extend_from_slice(&c.to_le_bytes());
        }
    }
    stl.extend_from_slice(&[0, 0]);
    std::fs::write(dir.path().join("bad.stl"), stl).expect("stl");
    let cell = dir.path().join("cell.toml");
    std::fs::write(
        &cell,
        format!(
            "[cell]\nname = \"c\"\n[[sensor]]\nname = \"s1\"\nbackend = \"mock\"\nscene = \"{}\"\nto_common = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]\n[[part]]\nid = \"p\"\ncad = \"bad.stl\"\ntolerance = 0.5\n",
            config_dir().join("scenes/tiny.toml").display()
        ),
    )
    .expect("cell");
    let o = Command::new(env!("CARGO_BIN_EXE_risd"))
        .arg("--check-config")
        .arg(&cell)
        .env("RIS_LOG", "warn")
        .output()
        .expect("risd");
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("part p") && err.contains("bad.stl") && err.contains("no usable triangle"),
        "{err}"
    );
    // What start-up would refuse, the check refuses first: a data directory that is no
    // writable directory, a transport this build does not speak.
    for (extra, says) in [
        ("[storage]\ndata_dir = \"/dev/null\"\n", "not a directory"),
        (
            "[storage]\ndata_dir = \"/proc/self/risd\"\n",
            "not writable",
        ),
        ("[zenoh]\nlisten = [\"udp/127.0.0.1:7447\"]\n", "tcp only"),
    ] {
        let cell = dir.path().join("cell2.toml");
        std::fs::write(
            &cell,
            format!(
                "[cell]\nname = \"c\"\n{extra}[[sensor]]\nname = \"s1\"\nbackend = \"mock\"\nscene = \"{}\"\nto_common = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]\n",
                config_dir().join("scenes/tiny.toml").display()
            ),
        )
        .expect("cell");
        let o = check(&cell);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && err.contains(says), "{extra}: {err}");
    }
    // A datum larger than its part would size the inspection's work by its radius: refused.
    std::fs::write(
        dir.path().join("huge.toml"),
        "[[datum]]\nname = \"A\"\nposition = [0.0, 0.0, 0.0]\nradius = 1e9\n",
    )
    .expect("datums");
    let cell = dir.path().join("cell3.toml");
    std::fs::write(
        &cell,
        format!(
            "[cell]\nname = \"c\"\n[[sensor]]\nname = \"s1\"\nbackend = \"mock\"\nscene = \"{}\"\nto_common = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]\n[[part]]\nid = \"p\"\ncad = \"{}\"\ndatums = \"huge.toml\"\ntolerance = 0.5\n",
            config_dir().join("scenes/tiny.toml").display(),
            config_dir().join("mock-cell/panel.stl").display()
        ),
    )
    .expect("cell");
    let o = check(&cell);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("huge.toml") && err.contains("datum[0].radius"),
        "{err}"
    );
}

#[test]
fn once_scans_the_builtin_mock_cell() {
    let dir = tempfile::tempdir().expect("tmp");
    // A crashed scan left behind must be cleaned up, never taken for a finished one.
    let stale = dir.path().join("scans").join("123.partial");
    std::fs::create_dir_all(&stale).expect("stale");
    let o = Command::new(env!("CARGO_BIN_EXE_risd"))
        .arg("--once")
        .arg("--data-dir")
        .arg(dir.path())
        .env("RIS_LOG", "warn")
        .output()
        .expect("risd");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(!stale.exists(), "unfinished scan not removed");
    let scans: Vec<_> = std::fs::read_dir(dir.path().join("scans"))
        .expect("scans")
        .flatten()
        .map(|e| e.path())
        .collect();
    assert_eq!(scans.len(), 1, "{scans:?}");
    let scan = &scans[0];
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(scan.join("scan.json")).expect("scan.json"))
            .expect("json");
    let mut total = 0;
    for s in ["s1", "s2", "s3", "s4"] {
        let c = ris_core::cloud::PointCloud::read_ply(&scan.join(format!("{s}.ply"))).expect(s);
        assert!(c.len() > 200_000, "{s}: {} points", c.len());
        // Each sensor's cloud is organised: every point keeps the camera pixel it was measured
        // at, which the scene's true camera projects it back to.
        let scene = ris_core::sim::Scene::load(&config_dir().join(format!("mock-cell/{s}.toml")))
            .expect("scene");
        assert_eq!(
            c.organised(),
            Some([scene.camera.width, scene.camera.height]),
            "{s}"
        );
        let mut worst = 0f64;
        for i in (0..c.len()).step_by(97) {
            let p = c.points[i];
            let (row, col) = c.row_column(i).expect("pixel");
            let (u, v) = scene
                .camera
                .project(&nalgebra::Vector3::new(
                    f64::from(p[0]),
                    f64::from(p[1]),
                    f64::from(p[2]),
                ))
                .expect("in front of the camera");
            worst = worst.max((u - f64::from(col)).hypot(v - f64::from(row)));
        }
        assert!(
            worst < 0.5,
            "{s}: a point reprojects {worst} px from its pixel"
        );
        total += c.len();
    }
    let merged = ris_core::cloud::PointCloud::read_ply(&scan.join("merged.ply")).expect("merged");
    assert_eq!(report["merged_points"].as_u64(), Some(merged.len() as u64));
    // The overlaps are de-duplicated, and the merged cloud lies on the panel in the cell frame:
    // z = −x²/5000 − y²/8000 (the scenes' panel), within a fraction of a millimetre.
    assert!(
        merged.len() < total && merged.len() > total * 2 / 3,
        "{} of {total}",
        merged.len()
    );
    let off: Vec<f64> = merged
        .points
        .iter()
        .map(|p| {
            let (x, y, z) = (f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
            (z + x * x / 5000.0 + y * y / 8000.0).abs()
        })
        .collect();
    let mean = off.iter().sum::<f64>() / off.len() as f64;
    let far = off.iter().filter(|d| **d > 1.0).count() as f64 / off.len() as f64;
    assert!(
        mean < 0.1 && far < 0.002,
        "mean {mean} mm, {far} beyond 1 mm"
    );
    // Exposure groups {s1, s3} and {s2, s4} take turns; compute overlaps the second group.
    let t = |s: usize, k: &str, i: usize| report["sensors"][s][k][i].as_f64().expect("time");
    assert!(
        t(1, "acquire", 0) >= t(0, "acquire", 1) - 0.05,
        "groups overlapped"
    );
    assert!(
        t(0, "compute", 0) < t(1, "acquire", 1),
        "no overlap of compute and acquisition"
    );
    // The cell's part is that panel (its CAD vertices lie on the surface), so the inspection
    // passes with the sensors' noise and reports it.
    let cad =
        ris_core::mesh::TriangleMesh::load(&config_dir().join("mock-cell/panel.stl")).expect("cad");
    assert!(cad
        .vertices
        .iter()
        .all(|v| (v.z + v.x * v.x / 5000.0 + v.y * v.y / 8000.0).abs() < 1e-3));
    let inspection = &report["inspection"];
    assert_eq!(inspection["verdict"], "pass", "{inspection}");
    let rms = inspection["rms"].as_f64().expect("rms");
    assert!(rms > 0.0 && rms < 0.15, "deviation RMS {rms} mm");
    let full: serde_json::Value =
        serde_json::from_slice(&std::fs::read(scan.join("report.json")).expect("report.json"))
            .expect("json");
    assert_eq!(full["verdict"], "pass");
    assert!(scan.join("deviation.png").is_file() && scan.join("deviation.ply").is_file());

    // A second start reuses the prepared pairs (a decoded reference and a render cache per
    // pair under <data dir>/cache) and measures bit for bit what the cold start measured.
    let mut cached: Vec<String> = std::fs::read_dir(dir.path().join("cache"))
        .expect("cache")
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    cached.sort();
    assert_eq!(cached.len(), 8, "{cached:?}");
    for s in ["s1", "s2", "s3", "s4"] {
        for kind in [".reference", ".render"] {
            let n = cached
                .iter()
                .filter(|c| c.starts_with(&format!("{s}-")) && c.ends_with(kind))
                .count();
            assert_eq!(n, 1, "{s}{kind}: {cached:?}");
        }
    }
    let o = Command::new(env!("CARGO_BIN_EXE_risd"))
        .args(["--once", "--scan-id", "warm", "--data-dir"])
        .arg(dir.path())
        .env("RIS_LOG", "risd=debug,ris_daemon=debug,warn")
        .output()
        .expect("risd");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let log = String::from_utf8_lossy(&o.stderr);
    assert_eq!(log.matches("cached=true").count(), 8, "{log}");
    let warm = dir.path().join("scans/warm");
    for f in ["s1.ply", "s4.ply", "merged.ply", "deviation.ply"] {
        assert!(
            std::fs::read(scan.join(f)).expect("cold")
                == std::fs::read(warm.join(f)).expect("warm"),
            "{f} differs between a cold and a warm start"
        );
    }
}

/// The prepared pairs' cache the suite's risd processes share: only the first preparation of
/// a pair prepares it from scratch.
fn shared_cache() -> ris_daemon::prepared::Cache {
    ris_daemon::prepared::Cache::new(Some(common::shared_cache()))
}

/// One single-shot scan of `config`'s pairs into `data` (inspecting `part` when given).
fn single_shot_scan(
    config: &CellConfig,
    part: Option<&ris_daemon::scan::Part>,
    data: &Path,
    id: &str,
) -> anyhow::Result<(ris_daemon::scan::ScanReport, std::path::PathBuf)> {
    let mut pairs =
        ris_daemon::pair::open_all(config, 5, &shared_cache(), &|_, _, _| {}).expect("pairs");
    ris_daemon::scan::run(
        "mock",
        &mut pairs,
        ScanOptions {
            mode: ris_daemon::protocol::ScanMode::SingleShot,
            part,
            ..ScanOptions::default()
        },
        data,
        id,
        &|| false,
        &|_| {},
    )
}

/// An X-point pattern finer than the cameras resolve is refused per pair at open, with the
/// spacing and the least step that works (a step of 8 gives X-points 7.8 camera pixels apart on
/// the mock cell, and the detector finds a quarter of them); a single-shot scan then fails
/// naming it. A step of 9 (8.7 px), which the detector set for the spacing resolves, scans whole.
#[test]
fn a_pattern_finer_than_the_camera_resolves_is_refused_with_the_step_that_works() {
    let mut config = CellConfig::load(&config_dir().join("mock-cell.toml")).expect("config");
    config.sensors.retain(|s| s.name == "s1");
    let scan = |config: &CellConfig| {
        let data = tempfile::tempdir().expect("tmp");
        single_shot_scan(config, None, data.path(), "a")
    };
    config.single_shot.step = [8, 8];
    let msg = format!("{:#}", scan(&config).expect_err("refused"));
    assert!(
        msg.contains("sensor s1") && msg.contains("step [8, 8]") && msg.contains("[9, 9]"),
        "{msg}"
    );
    // At [9, 9] the primitives on the parts and the table in view: about 4 100 of them were
    // decoded when this was written; [12, 12] gives 2 300.
    config.single_shot.step = [9, 9];
    let (report, _) = scan(&config).expect("a step of 9 scans");
    let points = report.sensors.iter().map(|s| s.points).sum::<usize>();
    assert!(points > 3500, "{points} points at step [9, 9]");

    // A dense region is refused the same way when its step is the one the camera cannot
    // resolve, and scans with more points than the coarse pattern alone when it can.
    config.single_shot.step = [14, 14];
    let (report, _) = scan(&config).expect("a step of 14 scans");
    let coarse = report.sensors.iter().map(|s| s.points).sum::<usize>();
    let region = |step: u32| ris_core::single_shot::DenseRegion {
        x: [300.0, 700.0],
        y: [200.0, 550.0],
        step: [step, step],
    };
    config.single_shot.dense = vec![region(8)];
    let msg = format!("{:#}", scan(&config).expect_err("refused"));
    assert!(
        msg.contains("sensor s1") && msg.contains("finest step") && msg.contains("[8, 8]"),
        "{msg}"
    );
    config.single_shot.dense = vec![region(10)];
    let (report, _) = scan(&config).expect("a dense region of step 10 scans");
    let dense = report.sensors.iter().map(|s| s.points).sum::<usize>();
    assert!(
        dense as f64 > 1.3 * coarse as f64,
        "{dense} points with the dense region, {coarse} without"
    );
}

/// A scan whose sensors measure nothing has nothing to inspect: it fails, naming each sensor
/// that saw nothing and why it may have, and leaves no scan (and no verdict) behind. The
/// lenses are "covered" by an exposure of 1 µs, 10 000 times shorter than the cell's.
#[test]
fn a_scan_with_nothing_to_inspect_fails_naming_the_blind_sensors() {
    use ris_daemon::scan::Part;
    let mut config = CellConfig::load(&config_dir().join("mock-cell.toml")).expect("config");
    config.sensors.retain(|s| s.name == "s1" || s.name == "s2");
    for s in &mut config.sensors {
        s.exposure_us = 1.0;
    }
    let part = Part::prepare(&config.parts[0]).expect("part");
    let data = tempfile::tempdir().expect("tmp");
    let err = single_shot_scan(&config, Some(&part), data.path(), "blind")
        .expect_err("nothing to inspect");
    let msg = format!("{err:#}");
    for s in ["s1", "s2"] {
        assert!(
            msg.contains(&format!("sensor {s} reconstructed no points")),
            "{s} not named: {msg}"
        );
    }
    assert!(
        msg.contains("inspecting part panel") && msg.contains("the cloud has 0 points"),
        "{msg}"
    );
    let scans = data.path().join("scans");
    let left: Vec<_> = std::fs::read_dir(&scans)
        .map(|d| d.flatten().map(|e| e.path()).collect())
        .unwrap_or_default();
    assert!(left.is_empty(), "a failed scan left {left:?}");

    // One lens uncovered: the scan inspects what s1 measured, and its report names s2 alone.
    config.sensors[0].exposure_us = 10_000.0;
    let (report, dir) =
        single_shot_scan(&config, Some(&part), data.path(), "half").expect("s1 measures");
    assert!(report.sensors[0].points > 1000, "{:?}", report.sensors[0]);
    assert_eq!(report.sensors[1].points, 0);
    let named = |w: &[String], s: &str| w.iter().any(|w| w.starts_with(&format!("sensor {s} ")));
    assert!(named(&report.warnings, "s2") && !named(&report.warnings, "s1"));
    let inspected: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("report.json")).expect("report.json"))
            .expect("json");
    let warnings: Vec<String> =
        serde_json::from_value(inspected["warnings"].clone()).expect("warnings");
    assert!(named(&warnings, "s2"), "{warnings:?}");
}

/// Each scanned sensor without a point is named in the scan's warnings.
#[test]
fn sensors_without_points_are_named() {
    use ris_daemon::scan::{empty_views, SensorTiming};
    let timing = |name: &str, points| SensorTiming {
        sensor: name.to_string(),
        points,
        ..Default::default()
    };
    let sensors = [timing("s1", 1000), timing("s2", 0), timing("s3", 0)];
    let w = empty_views(&sensors);
    assert_eq!(w.len(), 2, "{w:?}");
    assert!(w[0].starts_with("sensor s2 reconstructed no points"));
    assert!(w[1].starts_with("sensor s3 reconstructed no points"));
    assert!(empty_views(&sensors[..1]).is_empty());
}

#[test]
fn a_fault_in_one_pair_fails_that_scan_and_the_next_succeeds() {
    use ris_drivers::mock::Fault;
    let config = CellConfig::load(&config_dir().join("mock-cell.toml")).expect("config");
    let mut pairs =
        ris_daemon::pair::open_all(&config, 3, &shared_cache(), &|_, _, _| {}).expect("pairs");
    let data = tempfile::tempdir().expect("tmp");
    // s2's camera ignores four triggers in a row: one slide exhausts its retries.
    let s2 = pairs.iter().position(|p| p.name == "s2").expect("s2");
    let faults = pairs[s2]
        .faults
        .clone()
        .expect("a mock pair injects faults");
    let at = faults.exposures() + 5;
    for k in 0..4 {
        faults.at(at + k, Fault::MissedTrigger);
    }
    let states = std::sync::Mutex::new(Vec::new());
    let record = |s: &ris_daemon::protocol::ScanState| {
        if let Ok(mut v) = states.lock() {
            v.push(serde_json::to_value(s).expect("json"));
        }
    };
    let err = ris_daemon::scan::run(
        "mock",
        &mut pairs,
        ScanOptions::default(),
        data.path(),
        "a",
        &|| false,
        &record,
    )
    .expect_err("the scan must fail");
    let msg = format!("{err:#}");
    assert!(
        msg.contains("sensor s2") && msg.contains("timeout"),
        "{msg}"
    );
    let last = states
        .lock()
        .expect("states")
        .last()
        .cloned()
        .expect("a state");
    assert_eq!(last["state"], "failed");
    assert!(
        last["reason"].as_str().expect("reason").contains("s2"),
        "{last}"
    );
    assert!(!data.path().join("scans/a").exists() && !data.path().join("scans/a.partial").exists());
    let (report, dir) = ris_daemon::scan::run(
        "mock",
        &mut pairs,
        ScanOptions::default(),
        data.path(),
        "b",
        &|| false,
        &|_| {},
    )
    .expect("the next scan succeeds");
    assert_eq!(report.sensors.len(), 4);
    assert!(dir.join("merged.ply").is_file());
    // A scan of a subset scans only those sensors.
    let only = vec!["s3".to_string()];
    let (report, _) = ris_daemon::scan::run(
        "mock",
        &mut pairs,
        ScanOptions {
            only: Some(&only),
            e57: true,
            ..ScanOptions::default()
        },
        data.path(),
        "c",
        &|| false,
        &|_| {},
    )
    .expect("subset scan");
    assert_eq!(report.sensors.len(), 1);
    // With E57 asked for, each cloud is also E57, the same points (mm after the metres
    // round trip) and, for the sensor's cloud, the same camera pixels.
    for name in ["s3", "merged"] {
        let c = data.path().join("scans/c");
        let ply =
            ris_core::cloud::PointCloud::read_ply(&c.join(format!("{name}.ply"))).expect("ply");
        let e57 =
            ris_core::cloud::PointCloud::read_e57(&c.join(format!("{name}.e57"))).expect("e57");
        assert_eq!(e57.len(), ply.len(), "{name}");
        assert_eq!((e57.image, &e57.pixels), (ply.image, &ply.pixels), "{name}");
        assert_eq!(ply.organised().is_some(), name == "s3", "{name}");
        for (a, b) in ply.points.iter().zip(&e57.points) {
            assert!(
                (0..3).all(|k| (a[k] - b[k]).abs() < 1e-3),
                "{name}: {a:?} vs {b:?}"
            );
        }
    }
    assert_eq!(report.sensors[0].sensor, "s3");

    // A panic inside a scan (here in the merge stage's state report) fails that scan with a
    // reason, publishes `failed`, leaves no `.partial`, and the pairs scan again afterwards.
    let failed = std::sync::Mutex::new(None);
    let err = ris_daemon::scan::run(
        "mock",
        &mut pairs,
        ScanOptions {
            only: Some(&only),
            ..ScanOptions::default()
        },
        data.path(),
        "d",
        &|| false,
        &|s| match s {
            ris_daemon::protocol::ScanState::Merging => panic!("injected fault in the merge"),
            ris_daemon::protocol::ScanState::Failed { reason } => {
                *failed.lock().expect("lock") = Some(reason.clone())
            }
            _ => {}
        },
    )
    .expect_err("the panicking scan fails");
    assert!(format!("{err:#}").contains("injected fault"), "{err:#}");
    let reason = failed
        .lock()
        .expect("lock")
        .clone()
        .expect("failed published");
    assert!(reason.contains("injected fault"), "{reason}");
    assert!(!data.path().join("scans/d").exists() && !data.path().join("scans/d.partial").exists());
    // Every early exit publishes `failed` too: a scan id that exists already.
    let failed = std::sync::Mutex::new(None);
    ris_daemon::scan::run(
        "mock",
        &mut pairs,
        ScanOptions::default(),
        data.path(),
        "b",
        &|| false,
        &|s| {
            if let ris_daemon::protocol::ScanState::Failed { reason } = s {
                *failed.lock().expect("lock") = Some(reason.clone())
            }
        },
    )
    .expect_err("scan b exists");
    assert!(failed
        .lock()
        .expect("lock")
        .as_deref()
        .is_some_and(|r| r.contains("exists already")));
    assert!(
        data.path().join("scans/b/merged.ply").is_file(),
        "the finished scan b is kept"
    );
    let (report, _) = ris_daemon::scan::run(
        "mock",
        &mut pairs,
        ScanOptions {
            only: Some(&only),
            tag: Some("after the panic"),
            ..ScanOptions::default()
        },
        data.path(),
        "e",
        &|| false,
        &|_| {},
    )
    .expect("the scan after the panic succeeds");
    assert_eq!(report.tag.as_deref(), Some("after the panic"));
    let stored: serde_json::Value = serde_json::from_slice(
        &std::fs::read(data.path().join("scans/e/scan.json")).expect("scan.json"),
    )
    .expect("json");
    assert_eq!(stored["tag"], "after the panic");
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig { failure_persistence: None, ..Default::default() })]

    /// The mock cell's configuration with a few printable bytes changed: a config or an error
    /// naming the file, never a panic.
    #[test]
    fn mutated_cell_files_parse_or_fail_cleanly(flips in proptest::collection::vec((0usize..4000, 32u8..127), 1..6)) {
        let mut text = ris_daemon::config::MOCK_CELL.as_bytes().to_vec();
        for (at, b) in flips {
            let i = at % text.len();
            text[i] = b;
        }
        let text = String::from_utf8_lossy(&text).into_owned();
        if let Err(e) = CellConfig::parse(&text, &config_dir(), "mutated.toml") {
            proptest::prop_assert!(format!("{e:#}").contains("mutated.toml"), "{:#}", e);
        }
    }
}

/// A listen endpoint another program holds: risd exits at once naming the endpoint and what to
/// change, without library source paths.
#[test]
fn a_listen_endpoint_in_use_is_named() {
    let holder = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
    let endpoint = format!(
        "tcp/127.0.0.1:{}",
        holder.local_addr().expect("addr").port()
    );
    let data = tempfile::tempdir().expect("tmp");
    let o = Command::new(env!("CARGO_BIN_EXE_risd"))
        .args(["--listen", &endpoint, "--data-dir"])
        .arg(data.path())
        .env_remove("RIS_LOG")
        .env("RUST_BACKTRACE", "0")
        .output()
        .expect("risd");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(err.contains(&endpoint) && err.contains("--listen"), "{err}");
    assert!(
        !err.contains("registry/src") && !err.contains(".rs:"),
        "{err}"
    );
    drop(holder);
}
