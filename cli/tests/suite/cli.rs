//! End-to-end tests of the `ris` binary: the commands a user runs, and their errors on bad input.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn ris(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_ris"))
        .args(args)
        .env("RIS_LOG", "warn")
        .output()
        .expect("run ris")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// A tiny scene (160x120 camera) so the CLI tests stay fast.
const SCENE: &str = include_str!("../../../config/scenes/tiny.toml");

fn simulated(dir: &Path) -> PathBuf {
    let scene = dir.join("scene.toml");
    std::fs::write(&scene, SCENE).expect("write scene");
    let out = dir.join("sim");
    let o = ris(&[
        "simulate",
        "--scene",
        scene.to_str().expect("utf8"),
        "--out",
        out.to_str().expect("utf8"),
    ]);
    assert!(o.status.success(), "simulate failed: {}", stderr(&o));
    out
}

fn s(p: &Path) -> &str {
    p.to_str().expect("utf8 path")
}

#[test]
fn patterns_writes_the_full_sequence() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("p");
    let o = ris(&[
        "patterns",
        "--projector",
        "64x32",
        "--flats",
        "--out",
        s(&out),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let n = std::fs::read_dir(&out).expect("dir").count();
    assert_eq!(
        n,
        2 + 2 * (6 + 5) + 6,
        "white, black, 6 column and 5 row bits with inverses, 6 flats"
    );
    let img = ris_core::image::GrayImage::load(&out.join("gray_col_05.png")).expect("png");
    assert_eq!((img.width, img.height), (64, 32));
    let o = ris(&["patterns", "--projector", "64by32", "--out", s(&out)]);
    assert!(!o.status.success() && stderr(&o).contains("64by32"));
}

#[test]
fn simulate_decode_reconstruct_round_trip() {
    let dir = tempfile::tempdir().expect("tempdir");
    let sim = simulated(dir.path());
    let dec = dir.path().join("dec");
    let o = ris(&["decode", s(&sim.join("capture")), "--out", s(&dec)]);
    assert!(o.status.success(), "{}", stderr(&o));
    for f in ["col.npy", "row.npy", "confidence.npy", "decoded.png"] {
        assert!(dec.join(f).is_file(), "{f} missing");
    }
    let cloud = dir.path().join("cloud.ply");
    let o = ris(&[
        "reconstruct",
        "--sensor",
        s(&sim.join("sensor.toml")),
        s(&sim.join("capture")),
        "--out",
        s(&cloud),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let pc = ris_core::cloud::PointCloud::read_ply(&cloud).expect("ply");
    assert!(pc.len() > 10_000, "{} points", pc.len());
    // The box top (z = 100) and the plane (z = 0) are both there, nothing else.
    let top = pc
        .points
        .iter()
        .filter(|p| (p[2] - 100.0).abs() < 1.0)
        .count();
    let floor = pc.points.iter().filter(|p| p[2].abs() < 1.0).count();
    assert!(top > 1000 && floor > 10_000, "top {top}, floor {floor}");
    assert!(top + floor >= pc.len() * 99 / 100, "stray points");
    // Both models from the same sensor file agree.
    let cloud2 = dir.path().join("classical.ply");
    let o = ris(&[
        "reconstruct",
        "--model",
        "classical",
        "--sensor",
        s(&sim.join("sensor.toml")),
        s(&sim.join("capture")),
        "--out",
        s(&cloud2),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let pc2 = ris_core::cloud::PointCloud::read_ply(&cloud2).expect("ply");
    let on_surfaces = pc2
        .points
        .iter()
        .filter(|p| (p[2] - 100.0).abs() < 1.0 || p[2].abs() < 1.0)
        .count();
    assert!(
        pc2.len() > pc.len() * 9 / 10,
        "classical {} vs parallax {} points",
        pc2.len(),
        pc.len()
    );
    assert!(
        on_surfaces >= pc2.len() * 99 / 100,
        "classical stray points"
    );
}

/// Run `args`, expect failure with every `needles` in stderr and `out` not created.
fn fails(args: &[&str], needles: &[&str], out: &Path) {
    let o = ris(args);
    let err = stderr(&o);
    assert!(!o.status.success(), "expected failure for {args:?}");
    for n in needles {
        assert!(err.contains(n), "stderr should mention `{n}`: {err}");
    }
    assert!(!err.contains("panicked"), "panic: {err}");
    assert!(
        !out.exists(),
        "{} was written despite the error",
        out.display()
    );
}

#[test]
fn bad_input_gives_clear_errors_and_no_output() {
    let dir = tempfile::tempdir().expect("tempdir");
    let sim = simulated(dir.path());
    let cap = sim.join("capture");
    let sensor = sim.join("sensor.toml");
    let out = dir.path().join("never.ply");
    let dec_out = dir.path().join("never_dir");

    // Missing frame.
    let bad = dir.path().join("missing");
    copy_dir(&cap, &bad);
    std::fs::remove_file(bad.join("gray_col_03.png")).expect("rm");
    fails(
        &["decode", s(&bad), "--out", s(&dec_out)],
        &["gray_col_03.png", "frames.gray_col_03"],
        &dec_out,
    );
    fails(
        &[
            "reconstruct",
            "--sensor",
            s(&sensor),
            s(&bad),
            "--out",
            s(&out),
        ],
        &["gray_col_03.png"],
        &out,
    );

    // A picture to show that is not the projector's size: refused by name, nothing written.
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/scenes/demo.toml");
    let sim_out = dir.path().join("never_sim");
    fails(
        &[
            "simulate",
            "--scene",
            s(&scene),
            "--out",
            s(&sim_out),
            "--show",
            s(&cap.join("black.png")),
        ],
        &["black.png", "160x120", "1024x768"],
        &sim_out,
    );

    // Nothing in view (every frame black): no points, an error, no file.
    let bad = dir.path().join("all-black");
    copy_dir(&cap, &bad);
    let black = std::fs::read(bad.join("black.png")).expect("black.png");
    for e in std::fs::read_dir(&bad).expect("dir").flatten() {
        if e.path().extension().is_some_and(|x| x == "png") {
            std::fs::write(e.path(), &black).expect("write");
        }
    }
    fails(
        &[
            "reconstruct",
            "--sensor",
            s(&sensor),
            s(&bad),
            "--out",
            s(&out),
        ],
        &["all-black"],
        &out,
    );

    // Unreadable frame.
    let bad = dir.path().join("unreadable");
    copy_dir(&cap, &bad);
    std::fs::write(bad.join("white.png"), b"garbage").expect("write");
    fails(
        &["decode", s(&bad), "--out", s(&dec_out)],
        &["white.png"],
        &dec_out,
    );

    // Size mismatch.
    let bad = dir.path().join("size");
    copy_dir(&cap, &bad);
    ris_core::image::GrayImage::from_u8(10, 10, vec![0; 100])
        .save_png(&bad.join("black.png"))
        .expect("png");
    fails(
        &["decode", s(&bad), "--out", s(&dec_out)],
        &["black.png", "10x10", "160x120"],
        &dec_out,
    );

    // Unknown pattern in [frames].
    let bad = dir.path().join("unknown");
    copy_dir(&cap, &bad);
    append(
        &bad.join("capture.toml"),
        "\n[frames]\nstripes_07 = \"white.png\"\n",
    );
    fails(
        &["decode", s(&bad), "--out", s(&dec_out)],
        &["frames.stripes_07", "capture.toml"],
        &dec_out,
    );

    // Malformed TOML.
    let bad = dir.path().join("malformed");
    copy_dir(&cap, &bad);
    append(&bad.join("capture.toml"), "\n[camera\n");
    fails(
        &["decode", s(&bad), "--out", s(&dec_out)],
        &["capture.toml"],
        &dec_out,
    );

    // NaN in a matrix of the sensor file.
    let text = std::fs::read_to_string(&sensor).expect("sensor");
    let nan_sensor = sim.join("nan_sensor.toml");
    assert!(
        text.contains("k = [[190.0,"),
        "sensor file layout changed: {text}"
    );
    std::fs::write(&nan_sensor, text.replacen("k = [[190.0,", "k = [[nan,", 1)).expect("write");
    let o = ris(&[
        "reconstruct",
        "--sensor",
        s(&nan_sensor),
        s(&cap),
        "--out",
        s(&out),
    ]);
    assert!(!o.status.success());
    let err = stderr(&o);
    assert!(
        err.contains("nan_sensor.toml") && err.contains("camera.k[0]") && err.contains("NaN"),
        "{err}"
    );
    assert!(!out.exists());

    // A missing sensor file.
    fails(
        &[
            "reconstruct",
            "--sensor",
            s(&dir.path().join("nope.toml")),
            s(&cap),
            "--out",
            s(&out),
        ],
        &["nope.toml"],
        &out,
    );
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).expect("mkdir");
    for e in std::fs::read_dir(from).expect("read_dir") {
        let e = e.expect("entry");
        std::fs::copy(e.path(), to.join(e.file_name())).expect("copy");
    }
}

fn append(path: &Path, text: &str) {
    let mut s = std::fs::read_to_string(path).expect("read");
    s.push_str(text);
    std::fs::write(path, s).expect("write");
}

#[test]
fn register_recovers_a_known_motion_and_refuses_bad_transforms() {
    use ris_core::cloud::PointCloud;
    use ris_core::register::{Pose, TransformFile};
    let dir = tempfile::tempdir().expect("tempdir");
    let surface = |x: f32, y: f32| 20.0 * (x / 40.0).sin() * (y / 30.0).cos() + 0.002 * x * x;
    let mut fixed = PointCloud::default();
    let mut moving = PointCloud::default();
    let truth = Pose::new(
        ris_core::geometry::Vector3::new(2.0, -1.0, 0.5),
        ris_core::geometry::Vector3::new(0.01, 0.02, -0.03),
    );
    for i in 0..200 {
        for j in 0..150 {
            let (x, y) = (i as f32 * 0.7 - 70.0, j as f32 * 0.7 - 52.0);
            if x < 40.0 {
                fixed.points.push([x, y, surface(x, y)]);
                fixed.confidence.push(1.0);
            }
            if x > -40.0 {
                let (xm, ym) = (x + 0.35, y + 0.35);
                let p = truth.inverse()
                    * ris_core::geometry::Point3::new(
                        f64::from(xm),
                        f64::from(ym),
                        f64::from(surface(xm, ym)),
                    );
                moving.points.push([p.x as f32, p.y as f32, p.z as f32]);
                moving.confidence.push(1.0);
            }
        }
    }
    let (fp, mp, out) = (
        dir.path().join("fixed.ply"),
        dir.path().join("moving.ply"),
        dir.path().join("t.toml"),
    );
    fixed.write_ply(&fp).expect("ply");
    moving.write_ply(&mp).expect("ply");
    let o = ris(&[
        "register",
        "--fixed",
        s(&fp),
        "--moving",
        s(&mp),
        "--out",
        s(&out),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let got = TransformFile::load(&out).expect("transform");
    let d = got.inverse() * truth;
    assert!(
        d.rotation.angle().to_degrees() < 0.01 && d.translation.vector.norm() < 0.02,
        "error {d:?}"
    );
    // Out of iterations: not converged, an error, no transform written.
    let unconverged = dir.path().join("unconverged.toml");
    fails(
        &[
            "register",
            "--fixed",
            s(&fp),
            "--moving",
            s(&mp),
            "--max-iterations",
            "1",
            "--out",
            s(&unconverged),
        ],
        &["did not converge", "--max-iterations", "nothing written"],
        &unconverged,
    );
    // A non-rigid initial transform is refused with the file and field named.
    let bad = dir.path().join("bad.toml");
    std::fs::write(&bad, "matrix = [[2.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]\n").expect("write");
    let out2 = dir.path().join("never.toml");
    fails(
        &[
            "register",
            "--fixed",
            s(&fp),
            "--moving",
            s(&mp),
            "--init",
            s(&bad),
            "--out",
            s(&out2),
        ],
        &["bad.toml", "matrix", "rotation"],
        &out2,
    );
    fails(
        &[
            "register",
            "--fixed",
            s(&dir.path().join("nope.ply")),
            "--moving",
            s(&mp),
            "--out",
            s(&out2),
        ],
        &["nope.ply"],
        &out2,
    );
}

#[test]
fn merge_needs_to_common_and_deduplicates() {
    use ris_core::cloud::PointCloud;
    let dir = tempfile::tempdir().expect("tempdir");
    let sim = simulated(dir.path());
    let sensor = sim.join("sensor.toml");
    let cloud = dir.path().join("c.ply");
    let o = ris(&[
        "reconstruct",
        "--sensor",
        s(&sensor),
        s(&sim.join("capture")),
        "--out",
        s(&cloud),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let out = dir.path().join("merged.ply");
    let arg = format!("{}:{}", s(&sensor), s(&cloud));
    fails(
        &["merge", &arg, "--out", s(&out)],
        &["sensor.toml", "to_common"],
        &out,
    );
    // Two "sensors": the same cloud through the identity and through a 5 m shift (disjoint).
    let text = std::fs::read_to_string(&sensor).expect("read");
    let a = dir.path().join("a.toml");
    let b = dir.path().join("b.toml");
    let reference = format!("capture = {:?}", s(&sim.join("reference")));
    let base = text.replace("capture = \"reference\"", &reference);
    std::fs::write(&a, format!("{base}\n[to_common]\nmatrix = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]\n")).expect("a");
    std::fs::write(&b, format!("{base}\n[to_common]\nmatrix = [[1.0, 0.0, 0.0, 5000.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]\n")).expect("b");
    let (arg_a, arg_b) = (
        format!("{}:{}", s(&a), s(&cloud)),
        format!("{}:{}", s(&b), s(&cloud)),
    );
    let o = ris(&["merge", &arg_a, &arg_a, &arg_b, "--out", s(&out)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let single = PointCloud::read_ply(&cloud).expect("ply");
    let merged = PointCloud::read_ply(&out).expect("ply");
    // The repeated sensor is a pure duplicate; the shifted one is disjoint.
    assert_eq!(merged.len(), 2 * single.len());
    assert_eq!(
        merged.points.iter().filter(|p| p[0] > 2500.0).count(),
        single.len()
    );
}

#[test]
fn inspect_writes_deviation_map_report_and_exit_status() {
    use ris_core::cloud::PointCloud;
    use ris_core::mesh::{stl, TriangleMesh};
    let dir = tempfile::tempdir().expect("tempdir");
    let surface = |x: f64, y: f64| 20.0 * (x / 90.0).sin() * (y / 70.0).cos();
    let mesh = TriangleMesh::height_field(120, 80, (-120.0, 120.0), (-80.0, 80.0), surface);
    let cad = dir.path().join("part.stl");
    stl::write_binary(&cad, &mesh).expect("stl");
    // Measured: a 0.8 mm dent near (50, 20), shifted 1 mm in z overall (the pose is unknown).
    let mut cloud = PointCloud::default();
    for j in 0..300 {
        for i in 0..450 {
            let (x, y) = (
                -118.0 + 236.0 * i as f64 / 449.0,
                -78.0 + 156.0 * j as f64 / 299.0,
            );
            let dent = -0.8 * (-((x - 50.0).powi(2) + (y - 20.0).powi(2)) / 72.0).exp();
            cloud
                .points
                .push([x as f32, y as f32, (surface(x, y) + dent + 1.0) as f32]);
            cloud.confidence.push(1.0);
        }
    }
    let cp = dir.path().join("scan.ply");
    cloud.write_ply(&cp).expect("ply");
    let datums = dir.path().join("datums.toml");
    let mut text = String::new();
    for (n, (x, y)) in [
        (-100.0, -60.0),
        (100.0, -60.0),
        (100.0, 60.0),
        (-100.0, 60.0),
    ]
    .iter()
    .enumerate()
    {
        text.push_str(&format!(
            "[[datum]]\nname = \"D{}\"\nposition = [{x}, {y}, {}]\nradius = 15.0\n",
            n + 1,
            surface(*x, *y)
        ));
    }
    std::fs::write(&datums, text).expect("datums");
    let out = dir.path().join("report");
    let o = ris(&[
        "inspect",
        "--cloud",
        s(&cp),
        "--cad",
        s(&cad),
        "--datums",
        s(&datums),
        "--tolerance",
        "0.5",
        "--out",
        s(&out),
    ]);
    assert_eq!(
        o.status.code(),
        Some(3),
        "a failing part exits with 3: {}",
        stderr(&o)
    );
    // Its progress bar is drawn on a terminal only, never into a pipe.
    assert!(!stderr(&o).contains("registering"), "{}", stderr(&o));
    // The page beside the report: the verdict, the embedded map, the datums, the files.
    let page = std::fs::read_to_string(out.join("report.html")).expect("report.html");
    assert!(page.contains("class=\"verdict fail\">FAIL<"));
    assert!(page.contains("data:image/png;base64,") && page.contains("id=\"datums\""));
    assert!(page.contains("href=\"deviation.ply\"") && page.contains("href=\"report.json\""));
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).expect("report"))
            .expect("json");
    assert_eq!(report["verdict"], "fail");
    let region = &report["regions_out_of_tolerance"][0];
    assert!(
        (region["centroid"][0].as_f64().expect("x") - 50.0).abs() < 3.0
            && (region["peak_deviation_mm"].as_f64().expect("peak") + 0.8).abs() < 0.05,
        "{region}"
    );
    assert_eq!(report["datums"].as_array().expect("datums").len(), 4);
    let dev = PointCloud::read_ply(&out.join("deviation.ply")).expect("deviation.ply");
    assert_eq!(dev.len(), cloud.len());
    let png = ris_core::image::GrayImage::load(&out.join("deviation.png")).expect("png");
    assert!(png.width > 400 && png.height > 300);
    if let Ok(keep) = std::env::var("RIS_KEEP_PNG") {
        std::fs::copy(out.join("deviation.png"), keep).expect("keep");
    }
    // The same part within a 1 mm tolerance passes.
    let out2 = dir.path().join("report2");
    let o = ris(&[
        "inspect",
        "--cloud",
        s(&cp),
        "--cad",
        s(&cad),
        "--datums",
        s(&datums),
        "--tolerance",
        "1.0",
        "--deadline",
        "600",
        "--out",
        s(&out2),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    // An inspection past its deadline fails naming it and writes nothing; a deadline that is
    // not a positive number of seconds, a pose file that is not there or a datums file with a
    // negative radius is refused by name.
    let never = dir.path().join("never");
    let nope = dir.path().join("nope.toml");
    let bad_datums = dir.path().join("bad-datums.toml");
    std::fs::write(
        &bad_datums,
        "[[datum]]\nname = \"D1\"\nposition = [0.0, 0.0, 0.0]\nradius = -1.0\n",
    )
    .expect("write");
    for (option, value, needles) in [
        (
            "--deadline",
            "0.001",
            ["the inspection", "past its deadline of 1 ms"],
        ),
        ("--deadline", "0", ["--deadline", "got 0"]),
        ("--deadline", "NaN", ["--deadline", "got NaN"]),
        ("--pose", s(&nope), ["--pose", "nope.toml"]),
        (
            "--datums",
            s(&bad_datums),
            ["bad-datums.toml", "datum[0].radius"],
        ),
    ] {
        fails(
            &[
                "inspect",
                "--cloud",
                s(&cp),
                "--cad",
                s(&cad),
                "--tolerance",
                "1.0",
                option,
                value,
                "--out",
                s(&never),
            ],
            &needles,
            &never,
        );
    }
    // A known pose: nothing is fitted. Where the scan lies (1 mm above the CAD) every point
    // is out of a 0.5 mm tolerance; with the transform that puts it back, only the dent is.
    let known = |pose: &str, name: &str| -> serde_json::Value {
        let dir_out = dir.path().join(name);
        let o = ris(&[
            "inspect",
            "--cloud",
            s(&cp),
            "--cad",
            s(&cad),
            "--tolerance",
            "0.5",
            "--pose",
            pose,
            "--out",
            s(&dir_out),
        ]);
        assert_eq!(o.status.code(), Some(3), "{}", stderr(&o));
        serde_json::from_str(&std::fs::read_to_string(dir_out.join("report.json")).expect("report"))
            .expect("json")
    };
    let lifted = known("known", "known");
    assert_eq!(
        lifted["registration"]["mode"], "known pose",
        "{}",
        lifted["registration"]
    );
    assert!(
        (lifted["statistics"]["mean"].as_f64().expect("mean").abs() - 1.0).abs() < 0.02,
        "{}",
        lifted["statistics"]
    );
    assert!(
        lifted["statistics"]["within_tolerance"]
            .as_f64()
            .expect("share")
            < 0.01
    );
    let back = dir.path().join("down.toml");
    std::fs::write(
        &back,
        "matrix = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, -1.0], [0.0, 0.0, 0.0, 1.0]]\n",
    )
    .expect("transform");
    let placed = known(s(&back), "placed");
    let region = &placed["regions_out_of_tolerance"][0];
    assert!(
        (region["centroid"][0].as_f64().expect("x") - 50.0).abs() < 3.0
            && (region["peak_deviation_mm"].as_f64().expect("peak") + 0.8).abs() < 0.05,
        "{region}"
    );
    assert!(
        placed["statistics"]["within_tolerance"]
            .as_f64()
            .expect("share")
            > 0.97
    );
    // A cloud of one corner of the part measures too little of it for a verdict: not
    // measured, exit status 4, never a pass.
    let mut corner = cloud.clone();
    corner.points.retain(|p| p[0] < -70.0);
    corner.confidence.truncate(corner.points.len());
    let corner_path = dir.path().join("corner.ply");
    corner.write_ply(&corner_path).expect("ply");
    let out4 = dir.path().join("report4");
    let o = ris(&[
        "inspect",
        "--cloud",
        s(&corner_path),
        "--cad",
        s(&cad),
        "--tolerance",
        "1.0",
        "--out",
        s(&out4),
    ]);
    assert_eq!(o.status.code(), Some(4), "{}", stderr(&o));
    assert!(String::from_utf8_lossy(&o.stdout).contains("NOT MEASURED"));
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out4.join("report.json")).expect("report"))
            .expect("json");
    assert_eq!(report["verdict"], "not_measured");
    assert!(
        report["coverage"]["fraction"].as_f64().expect("coverage") < 0.3,
        "{report}"
    );
}

#[test]
fn inspect_with_a_3_2_1_datum_frame_reports_each_datum() {
    use ris_core::cloud::PointCloud;
    use ris_core::geometry::{Point3, Vector3};
    use ris_core::mesh::{stl, TriangleMesh};
    use ris_core::register::Pose;
    let dir = tempfile::tempdir().expect("tempdir");
    // A shallow dome with a 12 mm hole; its rim at y = 80 is the tertiary datum.
    let surface = |x: f64, y: f64| -(x * x + y * y) / 8000.0;
    let in_hole = |x: f64, y: f64| (x + 70.0).hypot(y - 5.0) < 6.0;
    let mut mesh = TriangleMesh::height_field(120, 80, (-120.0, 120.0), (-80.0, 80.0), surface);
    let verts = mesh.vertices.clone();
    mesh.triangles.retain(|t| {
        let c = t
            .iter()
            .fold(Vector3::zeros(), |a, i| a + verts[*i as usize])
            / 3.0;
        !in_hole(c.x, c.y)
    });
    let cad = dir.path().join("part.stl");
    stl::write_binary(&cad, &mesh).expect("stl");
    // Measured on a 0.5 mm grid, in a sensor frame 2° and a few mm away from the CAD's.
    let sensor_from_cad = Pose::new(
        Vector3::new(4.0, -3.0, 2.0),
        Vector3::new(0.01, -0.02, 0.035),
    );
    let mut cloud = PointCloud::default();
    for j in 0..=320 {
        for i in 0..=480 {
            let (x, y) = (-120.0 + 0.5 * i as f64, -80.0 + 0.5 * j as f64);
            if in_hole(x, y) {
                continue;
            }
            let p = sensor_from_cad * Point3::new(x, y, surface(x, y));
            cloud.points.push([p.x as f32, p.y as f32, p.z as f32]);
            cloud.confidence.push(1.0);
        }
    }
    let cp = dir.path().join("scan.ply");
    cloud.write_ply(&cp).expect("ply");
    let mut text = String::new();
    for (n, (x, y)) in [(-100.0, -60.0), (100.0, -60.0), (100.0, 60.0)]
        .iter()
        .enumerate()
    {
        text.push_str(&format!(
            "[[datum]]\nname = \"A{}\"\nposition = [{x}, {y}, {}]\nradius = 15.0\norder = 1\n",
            n + 1,
            surface(*x, *y)
        ));
    }
    text.push_str(&format!(
        "[[datum]]\nname = \"B\"\nfeature = \"hole\"\nposition = [-70.0, 5.0, {}]\nradius = 16.0\ndiameter = 12.0\norder = 2\n",
        surface(-70.0, 5.0)
    ));
    text.push_str(&format!(
        "[[datum]]\nname = \"C\"\nfeature = \"edge\"\nposition = [60.0, 80.0, {}]\nradius = 12.0\ndirection = [0.0, 1.0, 0.0]\norder = 3\n",
        surface(60.0, 80.0)
    ));
    let datums = dir.path().join("frame.toml");
    std::fs::write(&datums, text).expect("datums");
    let out = dir.path().join("report");
    let o = ris(&[
        "inspect",
        "--cloud",
        s(&cp),
        "--cad",
        s(&cad),
        "--datums",
        s(&datums),
        "--tolerance",
        "0.2",
        "--out",
        s(&out),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let said = String::from_utf8_lossy(&o.stdout);
    assert!(
        said.contains("datum B (Hole, order 2): at (-70.0"),
        "{said}"
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).expect("report"))
            .expect("json");
    assert_eq!(report["verdict"], "pass", "{}", report["reasons"]);
    assert_eq!(report["registration"]["mode"], "datum-frame");
    assert_eq!(report["conditioning"]["pinned"], true);
    let hole = &report["datums"][3]["frame"];
    assert_eq!(hole["feature"], "hole");
    let measured: Vec<f64> = hole["measured"]
        .as_array()
        .expect("measured")
        .iter()
        .map(|v| v.as_f64().expect("f64"))
        .collect();
    assert!(
        (measured[0] + 70.0).abs() < 0.15 && (measured[1] - 5.0).abs() < 0.15,
        "{hole}"
    );
    assert!(
        (hole["size_mm"].as_f64().expect("size") - 12.0).abs() < 0.3,
        "{hole}"
    );
    assert!(
        report["datums"][4]["frame"]["error"].is_null(),
        "{}",
        report["datums"][4]
    );
    // The map puts every point where it is on the part: the reported transform inverts the
    // sensor pose within 0.15 mm over the part.
    let t = &report["transform"];
    let m = |i: usize, j: usize| t[i][j].as_f64().expect("transform");
    for (x, y) in [
        (-120.0, -80.0),
        (120.0, -80.0),
        (120.0, 80.0),
        (-120.0, 80.0),
    ] {
        let p = sensor_from_cad * Point3::new(x, y, surface(x, y));
        let q: Vec<f64> = (0..3)
            .map(|i| m(i, 0) * p.x + m(i, 1) * p.y + m(i, 2) * p.z + m(i, 3))
            .collect();
        let err = (q[0] - x).hypot(q[1] - y).hypot(q[2] - surface(x, y));
        assert!(err < 0.15, "corner ({x}, {y}) mapped {err} mm off");
    }
}

#[test]
fn calibrate_cell_writes_to_common_from_a_simulated_gauge() {
    use ris_core::calibrate::Gauge;
    use ris_core::geometry::rotation_xyz_deg;
    use ris_core::mesh::{stl, TriangleMesh};
    use ris_core::sensor::Sensor;
    let dir = tempfile::tempdir().expect("tempdir");
    let surface = |x: f64, y: f64| -(x * x + y * y) / 6000.0;
    let mesh = TriangleMesh::height_field(80, 64, (-200.0, 200.0), (-160.0, 160.0), surface);
    stl::write_binary(&dir.path().join("gauge.stl"), &mesh).expect("stl");
    let gauge = Gauge::jittered_grid((-200.0, 200.0), (-160.0, 160.0), 40.0, 5.0, 3, surface);
    gauge.save(&dir.path().join("gauge.toml")).expect("gauge");
    // A 320x240 camera at 0.9 mm/px; the gauge rotated 30° and lifted in the sensor frame.
    let (rot, pos) = ([1.5, -1.0, 30.0], [12.0, -8.0, 80.0]);
    let scene = format!(
        r#"
[camera]
width = 320
height = 240
k = [[1778.0, 0.0, 159.5], [0.0, 1778.0, 119.5], [0.0, 0.0, 1.0]]
r = [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]
t = [0.0, 0.0, 1600.0]
noise = 1.0
[projector]
width = 1024
height = 768
k = [[1800.0, 0.0, 511.5], [0.0, 1800.0, 383.5], [0.0, 0.0, 1.0]]
r = [[0.954479978035, 0.0, -0.298274993136], [0.0, -1.0, 0.0], [-0.298274993136, 0.0, -0.954479978035]]
t = [0.0, 0.0, 1676.305461424]
ambient = 0.03
blur = 0.6
[material.paint]
albedo = 0.03
[[object]]
shape = "mesh"
file = "gauge.stl"
markers = "gauge.toml"
position = {pos:?}
rotation_deg = {rot:?}
material = "paint"
[render]
supersample = 3
rows = false
"#
    );
    std::fs::write(dir.path().join("scene.toml"), scene).expect("scene");
    let sim = dir.path().join("sim");
    let o = ris(&[
        "simulate",
        "--scene",
        s(&dir.path().join("scene.toml")),
        "--out",
        s(&sim),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let cloud = dir.path().join("gauge.ply");
    let sensor = sim.join("sensor.toml");
    let o = ris(&[
        "reconstruct",
        "--sensor",
        s(&sensor),
        s(&sim.join("capture")),
        "--out",
        s(&cloud),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let input = format!("{}:{}", s(&sensor), s(&cloud));

    // A gauge file that does not describe this part is refused and the sensor file is untouched.
    let other = dir.path().join("other.toml");
    Gauge::jittered_grid((-200.0, 200.0), (-160.0, 160.0), 40.0, 5.0, 11, surface)
        .save(&other)
        .expect("other");
    let before = std::fs::read(&sensor).expect("sensor");
    let o = ris(&["calibrate", "cell", "--gauge", s(&other), &input]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("gauge fit failed"), "{}", stderr(&o));
    assert_eq!(std::fs::read(&sensor).expect("sensor"), before);

    let report = dir.path().join("cell.json");
    let o = ris(&[
        "calibrate",
        "cell",
        "--gauge",
        s(&dir.path().join("gauge.toml")),
        &input,
        "--report",
        s(&report),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    eprintln!("{}", String::from_utf8_lossy(&o.stdout));
    let m = Sensor::load(&sensor)
        .expect("sensor")
        .to_common
        .expect("to_common");
    // Truth: sensor world = R · cell + pos, so cell = Rᵀ (world − pos).
    let r = rotation_xyz_deg(rot);
    let p = ris_core::geometry::Vec3::from(pos);
    for q in [[0.0, 0.0, 80.0], [100.0, 80.0, 60.0], [-120.0, -60.0, 70.0]] {
        let w = ris_core::geometry::Vec3::from(q);
        let truth = r.transpose() * (w - p);
        let got = (m * w.push(1.0)).xyz();
        assert!((got - truth).norm() < 0.1, "{q:?}: {got} vs {truth}");
    }
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&report).expect("report")).expect("json");
    assert!(
        json["sensors"][0]["matched"].as_u64().expect("matched") >= 15,
        "{json}"
    );
}

#[test]
fn calibrate_camera_on_the_opencv_images_writes_intrinsics_and_names_bad_views() {
    let data =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/opencv_chessboard_9x6");
    let mut images: Vec<String> = (1..=14)
        .filter(|n| *n != 10)
        .map(|n| data.join(format!("left{n:02}.jpg")).display().to_string())
        .collect();
    let dir = tempfile::tempdir().expect("tempdir");
    // A view without the board (the right camera sees it too, but a white frame does not).
    let blank = dir.path().join("blank.png");
    ris_core::image::GrayImage::from_u8(640, 480, vec![200; 640 * 480])
        .save_png(&blank)
        .expect("blank");
    images.push(s(&blank).to_string());
    let out = dir.path().join("camera.toml");
    let mut args = vec![
        "calibrate",
        "camera",
        "--board",
        "9x6",
        "--square",
        "25",
        "--out",
        s(&out),
    ];
    args.extend(images.iter().map(String::as_str));
    let o = ris(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        stdout.contains("RMS") && stdout.contains("blank.png"),
        "{stdout}"
    );
    let cal = ris_core::calibrate::CameraCalibration::load(&out).expect("camera file");
    assert!(
        (cal.k[0][0] / 535.9157 - 1.0).abs() < 0.005,
        "fx {}",
        cal.k[0][0]
    );
    assert!(cal.rms > 0.0 && cal.rms <= 0.45, "rms {}", cal.rms);
    assert_eq!(cal.views.len(), 13);
    assert_eq!(cal.dropped.len(), 1);
    assert!(
        cal.dropped[0].image.ends_with("blank.png"),
        "{:?}",
        cal.dropped
    );

    // Wrong board size: nothing found, nothing written.
    let bad = dir.path().join("bad.toml");
    let mut args = vec![
        "calibrate",
        "camera",
        "--board",
        "9x7",
        "--square",
        "25",
        "--out",
        s(&bad),
    ];
    args.extend(images.iter().take(3).map(String::as_str));
    fails(&args, &["9x7", "--board"], &bad);
    fails(
        &[
            "calibrate",
            "camera",
            "--board",
            "9",
            "--square",
            "25",
            "--out",
            s(&bad),
            &images[0],
        ],
        &["--board", "COLSxROWS"],
        &bad,
    );
    fails(
        &[
            "calibrate",
            "camera",
            "--board",
            "9x6",
            "--square=-1",
            "--out",
            s(&bad),
            &images[0],
        ],
        &["--square", "positive"],
        &bad,
    );
}

/// A small calibration session: 400x300 camera, 9x6 board of 40 mm squares, five layers.
const SMALL_SESSION: &str = r#"
[camera]
width = 400
height = 300
k = [[560.0, 0.0, 199.5], [0.0, 560.0, 149.5], [0.0, 0.0, 1.0]]
r = [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]
t = [0.0, 0.0, 1200.0]
noise = 1.0
[projector]
width = 512
height = 384
k = [[750.0, 0.0, 255.5], [0.0, 750.0, 191.5], [0.0, 0.0, 1.0]]
r = [[0.954479978035, 0.0, -0.298274993136], [0.0, -1.0, 0.0], [-0.298274993136, 0.0, -0.954479978035]]
t = [0.0, 0.0, 1300.0]
ambient = 0.02
blur = 0.5
[material.board]
albedo = 0.8
[material.table]
albedo = 0.4
[calibration]
inner_corners = [9, 6]
square = 40.0
heights = [0.0, 30.0, 60.0, 90.0, 120.0]
board_material = "board"
table_material = "table"
"#;

#[test]
fn calibrate_sensor_from_a_rendered_session_and_refuse_a_thin_one() {
    let dir = tempfile::tempdir().expect("tempdir");
    let scene = dir.path().join("session.toml");
    std::fs::write(&scene, SMALL_SESSION).expect("scene");
    let session = dir.path().join("session");
    let o = ris(&["simulate", "--scene", s(&scene), "--out", s(&session)]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(session.join("layer4/white.png").is_file());

    let out = dir.path().join("cal/sensor.toml");
    let o = ris(&["calibrate", "sensor", s(&session), "--out", s(&out)]);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{stdout}\n{}", stderr(&o));
    for needle in [
        "layer 4",
        "reprojection",
        "projector centre",
        "0.1 px",
        "verdict: pass",
        "standard error",
        "--camera",
    ] {
        assert!(stdout.contains(needle), "missing `{needle}`: {stdout}");
    }
    let sensor = ris_core::sensor::Sensor::load(&out).expect("sensor file");
    let truth = ris_core::sensor::Sensor::load(&session.join("truth.toml")).expect("truth");
    let centre_error = |s: &ris_core::sensor::Sensor| {
        (s.projector_center.expect("centre") - truth.projector_center.expect("centre")).norm()
    };
    // From corners alone a 400x300 camera confuses focal length with distance; with intrinsics
    // from a camera calibration only the pose is left to the layers.
    let alone = centre_error(&sensor);
    let camera = dir.path().join("camera.toml");
    let c = &truth.camera;
    ris_core::calibrate::CameraCalibration {
        width: 400,
        height: 300,
        k: ris_core::geometry::rows_of(&c.k),
        dist: c.dist.to_array(),
        rms: 0.0,
        square: 40.0,
        views: Vec::new(),
        dropped: Vec::new(),
    }
    .save(&camera)
    .expect("camera file");
    let out2 = dir.path().join("cal2/sensor.toml");
    let o = ris(&[
        "calibrate",
        "sensor",
        s(&session),
        "--camera",
        s(&camera),
        "--out",
        s(&out2),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let with_camera = centre_error(&ris_core::sensor::Sensor::load(&out2).expect("sensor"));
    eprintln!("projector centre error: {alone:.2} mm from the session alone, {with_camera:.2} mm with the camera file");
    assert!(with_camera < 2.0, "{with_camera}");
    assert!(sensor
        .reference
        .as_ref()
        .is_some_and(|r| r.join("capture.toml").is_file()));
    assert!(sensor.residual.as_ref().is_some_and(|r| r.is_file()));
    // The file states its calibrated volume; the table around the board lies outside it, and
    // `ris reconstruct` says how many points that is, flags them, or leaves them out.
    let volume = sensor.volume.expect("[volume]");
    assert_eq!(volume.heights[0], 0.0);
    let cloud_path = dir.path().join("layer0.ply");
    let o = ris(&[
        "reconstruct",
        "--sensor",
        s(&out),
        s(&session.join("layer0")),
        "--out",
        s(&cloud_path),
    ]);
    let line = String::from_utf8_lossy(&o.stdout).to_string();
    assert!(o.status.success(), "{line}{}", stderr(&o));
    let cloud = ris_core::cloud::PointCloud::read_ply(&cloud_path).expect("cloud");
    let outside = cloud.outside_count();
    assert!(
        line.contains(&format!("{outside} outside the calibrated volume")),
        "{line}"
    );
    assert!(
        outside > 1000 && outside + 10_000 < cloud.len(),
        "{outside} of {}",
        cloud.len()
    );
    for (p, o) in cloud.points.iter().zip(&cloud.outside) {
        assert_eq!(*o, !volume.contains(p), "{p:?}");
    }
    let o = ris(&[
        "reconstruct",
        "--sensor",
        s(&out),
        s(&session.join("layer0")),
        "--drop-outside",
        "--out",
        s(&cloud_path),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let kept = ris_core::cloud::PointCloud::read_ply(&cloud_path).expect("cloud");
    assert_eq!(kept.len(), cloud.len() - outside);
    assert_eq!(kept.outside_count(), 0);
    let report: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.path().join("cal/sensor.report.json")).expect("report"),
    )
    .expect("json");
    assert_eq!(report["verdict"], "pass");
    assert_eq!(report["layers"].as_array().map(Vec::len), Some(5));

    // Two layers without a board leave three: refused, nothing written.
    let blank = ris_core::image::GrayImage::from_u8(400, 300, vec![80; 400 * 300]);
    for l in ["layer1", "layer3"] {
        blank
            .save_png(&session.join(l).join("white.png"))
            .expect("blank");
    }
    let bad = dir.path().join("bad/sensor.toml");
    fails(
        &["calibrate", "sensor", s(&session), "--out", s(&bad)],
        &["3 usable layers", "layer 1", "layer 3", "no board"],
        &bad,
    );
}

#[test]
fn precision_grows_with_camera_noise() {
    let dir = tempfile::tempdir().expect("tempdir");
    let figure = |noise: f64| -> f64 {
        let mut captures = Vec::new();
        for seed in 1..=3 {
            let text = SCENE.replace("noise = 1.0", &format!("noise = {noise}"))
                + &format!("\n[render]\nseed = {seed}\n");
            let scene = dir.path().join(format!("n{noise}-{seed}.toml"));
            std::fs::write(&scene, text).expect("scene");
            let out = dir.path().join(format!("n{noise}-{seed}"));
            let o = ris(&["simulate", "--scene", s(&scene), "--out", s(&out)]);
            assert!(o.status.success(), "{}", stderr(&o));
            captures.push(out);
        }
        let heat = dir.path().join(format!("heat{noise}.png"));
        let sensor = captures[0].join("sensor.toml");
        let mut args = vec!["precision", "--sensor", s(&sensor), "--out", s(&heat)];
        let caps: Vec<String> = captures
            .iter()
            .map(|c| c.join("capture").display().to_string())
            .collect();
        args.extend(caps.iter().map(String::as_str));
        let o = ris(&args);
        let stdout = String::from_utf8_lossy(&o.stdout).into_owned();
        assert!(o.status.success(), "{}", stderr(&o));
        let img = ris_core::image::GrayImage::load(&heat).expect("heat map");
        assert_eq!((img.width, img.height), (160, 120));
        let fig: f64 = stdout
            .split("sensor figure ")
            .nth(1)
            .and_then(|t| t.split_whitespace().next())
            .and_then(|t| t.parse().ok())
            .unwrap_or_else(|| panic!("no figure in {stdout}"));
        fig
    };
    let (quiet, noisy) = (figure(0.5), figure(6.0));
    eprintln!("precision figure: noise 0.5 DN {quiet:.4} mm, noise 6 DN {noisy:.4} mm");
    assert!(quiet > 0.0 && quiet < 0.3, "{quiet}");
    assert!(noisy > 1.5 * quiet, "{quiet} -> {noisy}");
    let one = dir.path().join("one.png");
    fails(
        &[
            "precision",
            "--sensor",
            s(&dir.path().join("n0.5-1/sensor.toml")),
            "--out",
            s(&one),
            s(&dir.path().join("n0.5-1/capture")),
        ],
        &["at least two captures"],
        &one,
    );
}

#[cfg(feature = "aravis")]
#[test]
fn camera_grab_from_the_aravis_fake_gige_camera_on_loopback() {
    struct Fake(std::process::Child);
    impl Drop for Fake {
        fn drop(&mut self) {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }
    let _fake = Fake(
        Command::new("arv-fake-gv-camera-0.8")
            .args(["-i", "127.0.0.1"])
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .expect("arv-fake-gv-camera-0.8 (apt-get install aravis-tools)"),
    );
    std::thread::sleep(std::time::Duration::from_millis(700));
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("grab");
    let o = ris(&[
        "camera",
        "grab",
        "--backend",
        "aravis",
        "--device",
        "127.0.0.1",
        "--trigger",
        "software",
        "--count",
        "3",
        "--out",
        s(&out),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    for i in 0..3 {
        let img =
            ris_core::image::GrayImage::load(&out.join(format!("frame_{i:03}.png"))).expect("png");
        assert_eq!((img.width, img.height, img.bit_depth()), (512, 512, 8));
        // The fake's ramp: values rise along a row until they wrap.
        let row: Vec<f32> = (0..40).map(|x| img.get(x, 100)).collect();
        let rising = row.windows(2).filter(|w| w[1] >= w[0]).count();
        assert!(rising >= 35, "not a ramp: {row:?}");
    }
    let meta = std::fs::read_to_string(out.join("frames.toml")).expect("frames.toml");
    assert!(
        meta.contains("Aravis Fake") && meta.matches("[[frame]]").count() == 3,
        "{meta}"
    );
}

#[test]
fn camera_grab_from_the_mock_writes_frames_once_and_refuses_to_overwrite() {
    let dir = tempfile::tempdir().expect("tempdir");
    let scene = dir.path().join("scene.toml");
    std::fs::write(&scene, SCENE).expect("scene");
    let out = dir.path().join("grab");
    let args = [
        "camera",
        "grab",
        "--backend",
        "mock",
        "--device",
        s(&scene),
        "--count",
        "2",
        "--out",
        s(&out),
    ];
    let o = ris(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    for i in 0..2 {
        let img =
            ris_core::image::GrayImage::load(&out.join(format!("frame_{i:03}.png"))).expect("png");
        assert_eq!((img.width, img.height), (160, 120));
        // The plane and box (albedo 0.7) under the projector's full white are well lit.
        let mean: f32 = img.to_levels().iter().sum::<f32>() / (160.0 * 120.0);
        assert!(mean > 60.0, "mean level {mean}");
    }
    let meta = std::fs::read_to_string(out.join("frames.toml")).expect("frames.toml");
    assert_eq!(meta.matches("[[frame]]").count(), 2, "{meta}");
    let o = ris(&args);
    assert!(
        !o.status.success() && stderr(&o).contains("not empty"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn ring_pattern_is_written_with_a_file_that_rebuilds_it() {
    let dir = tempfile::tempdir().expect("tmp");
    let out = dir.path().join("rings");
    let o = ris(&[
        "patterns",
        "--rings",
        "--projector",
        "640x480",
        "--center",
        "320.5,236.0",
        "--out",
        out.to_str().expect("utf8"),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let img = ris_core::image::GrayImage::load(&out.join("rings.png")).expect("rings.png");
    assert_eq!((img.width, img.height), (640, 480));
    let levels = img.to_levels();
    // SPEC §13's formula, evaluated here from rings.toml alone.
    let text = std::fs::read_to_string(out.join("rings.toml")).expect("rings.toml");
    let t: toml::Value = toml::from_str(&text).expect("toml");
    let c = t["pattern"]["center"].as_array().expect("center");
    let (cx, cy) = (c[0].as_float().expect("cx"), c[1].as_float().expect("cy"));
    assert_eq!((cx, cy), (320.5, 236.0));
    assert_eq!(t["pattern"]["profile"].as_str(), Some("gaussian"));
    let rings = t["ring"].as_array().expect("rings");
    assert!(rings.len() > 10, "{} rings", rings.len());
    let f = |r: &toml::Value, k: &str| {
        r[k].as_float()
            .or_else(|| r[k].as_integer().map(|i| i as f64))
            .expect(k)
    };
    let mut checked = 0;
    for y in (0..480).step_by(7) {
        for x in (0..640).step_by(5) {
            let (dx, dy) = (x as f64 - cx, y as f64 - cy);
            let (rho, theta) = ((dx * dx + dy * dy).sqrt(), dy.atan2(dx));
            let v: f64 = rings
                .iter()
                .map(|r| {
                    let g = (-0.5 * ((rho - f(r, "radius")) / f(r, "width")).powi(2)).exp();
                    f(r, "intensity")
                        * g
                        * 0.5
                        * (1.0 + (f(r, "frequency") * theta + f(r, "phase")).cos())
                })
                .sum();
            let want = (255.0 * v.clamp(0.0, 1.0)).round();
            let got = f64::from(levels[y * 640 + x]);
            assert!((got - want).abs() <= 1.0, "({x}, {y}): {got} vs {want}");
            checked += 1;
        }
    }
    assert!(checked > 8000);
    let bad = ris(&[
        "patterns",
        "--rings",
        "--projector",
        "640x480",
        "--center",
        "1,2,3",
        "--out",
        out.to_str().expect("utf8"),
    ]);
    assert!(!bad.status.success() && stderr(&bad).contains("--center"));
}

#[test]
fn xpoint_pattern_is_written_with_a_file_that_states_every_primitive() {
    let dir = tempfile::tempdir().expect("tmp");
    let out = dir.path().join("xp");
    let o = ris(&[
        "patterns",
        "--xpoint",
        "--projector",
        "1024x768",
        "--step",
        "14,12",
        "--seed",
        "9",
        "--out",
        out.to_str().expect("utf8"),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let img = ris_core::image::GrayImage::load(&out.join("xpoint.png")).expect("xpoint.png");
    assert_eq!((img.width, img.height), (1024, 768));
    let p = ris_core::single_shot::XPointPattern::load(&out.join("xpoint.toml")).expect("toml");
    assert_eq!(
        (p.pattern.step, p.pattern.seed, p.pattern.min_distance),
        ([14, 12], 9, 3)
    );
    // The file rebuilds the image exactly, and it is what the library draws for that request.
    let drawn: Vec<f32> = p.render().into_iter().map(f32::from).collect();
    assert_eq!(img.to_levels(), drawn);
    assert_eq!(
        p,
        ris_core::single_shot::XPointPattern::generate(1024, 768, [14, 12], 3, 9).expect("again")
    );
    let [c, r] = p.grid();
    assert!(
        String::from_utf8_lossy(&o.stdout).contains(&format!("{c}x{r} grid")),
        "{}",
        String::from_utf8_lossy(&o.stdout)
    );
    for (args, needle) in [
        (vec!["--min-distance", "5"], "min_distance"),
        (vec!["--step", "14"], "--step"),
        (vec!["--rings"], "--rings and --xpoint"),
        (vec!["--dense", "100,400,100"], "--dense"),
        (vec!["--dense", "100,400,100,300,9.5,9"], "--dense"),
        (vec!["--dense", "400,100,100,300,9,9"], "dense[0]"),
        (vec!["--dense", "100,400,100,300,20,9"], "dense[0]"),
    ] {
        let mut a = vec!["patterns", "--xpoint", "--projector", "1024x768", "--out"];
        a.push(out.to_str().expect("utf8"));
        a.extend(args);
        let bad = ris(&a);
        assert!(
            !bad.status.success() && stderr(&bad).contains(needle),
            "{needle}: {}",
            stderr(&bad)
        );
    }
}

/// `--dense` regions: the file states them, the image is what the file redraws, and the grid
/// is finer there (more primitives than without); `--dense` without `--xpoint` is refused.
#[test]
fn xpoint_pattern_takes_dense_regions() {
    let dir = tempfile::tempdir().expect("tmp");
    let out = dir.path().join("xp");
    let o = ris(&[
        "patterns",
        "--xpoint",
        "--projector",
        "1024x768",
        "--step",
        "16,16",
        "--dense",
        "300,600,200,400,10,10",
        "--dense",
        "700,900,500,700,12,9",
        "--out",
        out.to_str().expect("utf8"),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let p = ris_core::single_shot::XPointPattern::load(&out.join("xpoint.toml")).expect("toml");
    assert_eq!(p.pattern.dense.len(), 2);
    assert_eq!(p.pattern.dense[1].step, [12, 9]);
    assert_eq!(p.finest_step(), [10, 9]);
    let img = ris_core::image::GrayImage::load(&out.join("xpoint.png")).expect("xpoint.png");
    let drawn: Vec<f32> = p.render().into_iter().map(f32::from).collect();
    assert_eq!(img.to_levels(), drawn);
    let plain =
        ris_core::single_shot::XPointPattern::generate(1024, 768, [16, 16], 3, 1).expect("plain");
    let lattice = p.lattice();
    let inside = lattice
        .columns
        .iter()
        .filter(|&&u| (300.0..600.0).contains(&u))
        .count();
    assert!(
        inside >= 29,
        "{inside} columns across the 300 px of the first region"
    );
    assert!(p.primitives.u.len() > plain.primitives.u.len());
    let bad = ris(&[
        "patterns",
        "--projector",
        "1024x768",
        "--dense",
        "300,600,200,400,10,10",
        "--out",
        out.to_str().expect("utf8"),
    ]);
    assert!(!bad.status.success() && stderr(&bad).contains("--xpoint"));
}

/// The median and 98th percentile of each point's distance (mm) from the surface the camera
/// sees at its pixel (the corner is within half a pixel of it, so on slopes the two differ by a
/// little).
fn error_quantiles(
    cloud: &ris_core::cloud::PointCloud,
    sim: &ris_core::sim::Simulator,
) -> (f64, f64) {
    let truth = &sim.cache.truth;
    let mut err: Vec<f64> = cloud
        .points
        .iter()
        .zip(&cloud.pixels)
        .filter_map(|(p, &px)| {
            let t = truth.xyz[px as usize];
            t[0].is_finite().then(|| {
                ((p[0] - t[0]).powi(2) + (p[1] - t[1]).powi(2) + (p[2] - t[2]).powi(2)).sqrt()
                    as f64
            })
        })
        .collect();
    assert!(!err.is_empty(), "no point on the surface");
    err.sort_by(f64::total_cmp);
    let q = |f: f64| err[((err.len() - 1) as f64 * f) as usize];
    (q(0.5), q(0.98))
}

/// `ris simulate` of `scene` into `out` with the camera's view of `picture` (`out/shown.png`).
fn simulate_showing(scene: &Path, out: &Path, picture: &Path) {
    let o = ris(&[
        "simulate",
        "--scene",
        s(scene),
        "--out",
        s(out),
        "--show",
        s(picture),
    ]);
    assert!(o.status.success(), "simulate: {}", stderr(&o));
}

/// `ris single-shot` on a pattern with a dense region: the camera's view of it (the
/// simulator), decoded with the detector set for the finest step, gives more points than the
/// same pattern without the region, as accurate.
#[test]
fn single_shot_reads_a_pattern_with_a_dense_region() {
    let dir = tempfile::tempdir().expect("tmp");
    let scene_path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/scenes/demo.toml");
    let scene = ris_core::sim::Scene::load(&scene_path).expect("scene");
    let sim = ris_core::sim::Simulator::new(scene);
    let mut points = Vec::new();
    for (name, dense) in [("plain", None), ("dense", Some("300,700,200,550,10,10"))] {
        let xp = dir.path().join(format!("{name}-xp"));
        let mut args = vec![
            "patterns",
            "--xpoint",
            "--projector",
            "1024x768",
            "--out",
            s(&xp),
        ];
        if let Some(d) = dense {
            args.extend(["--dense", d]);
        }
        let o = ris(&args);
        assert!(o.status.success(), "{}", stderr(&o));
        // The scene's sensor and reference come from `ris simulate` once; the dense pattern's
        // view is rendered by the simulator that `--show` runs (the plain view checks that
        // it is the same).
        let sim_dir = dir.path().join("plain-sim");
        let shown = dir.path().join(format!("{name}-shown.png"));
        let view = || {
            let picture = ris_core::image::GrayImage::load(&xp.join("xpoint.png")).expect("png");
            let ris_core::image::Pixels::U8(pixels) = &picture.pixels else {
                panic!("xpoint.png is 8-bit")
            };
            let mask =
                ris_core::pattern::ProjectionMask::picture(picture.width, picture.height, pixels);
            let white = ris_core::pattern::Pattern::White;
            sim.frame_with(&sim.layout(), white, Some(&mask), 1.0, 1)
        };
        if dense.is_none() {
            simulate_showing(&scene_path, &sim_dir, &xp.join("xpoint.png"));
            std::fs::rename(sim_dir.join("shown.png"), &shown).expect("rename");
            let cli = ris_core::image::GrayImage::load(&shown).expect("shown.png");
            assert!(
                cli.pixels == view().pixels,
                "ris simulate --show renders another view"
            );
        } else {
            view().save_png(&shown).expect("shown.png");
        }
        let cloud_path = dir.path().join(format!("{name}.ply"));
        let o = ris(&[
            "single-shot",
            "--sensor",
            s(&sim_dir.join("sensor.toml")),
            "--pattern",
            s(&xp.join("xpoint.toml")),
            s(&shown),
            "--out",
            s(&cloud_path),
        ]);
        assert!(o.status.success(), "single-shot {name}: {}", stderr(&o));
        let cloud = ris_core::cloud::PointCloud::read_ply(&cloud_path).expect("cloud");
        let (median, q98) = error_quantiles(&cloud, &sim);
        eprintln!(
            "{name}: {} points, median {median:.2} mm, 98 % {q98:.2} mm",
            cloud.len()
        );
        assert!(
            median < 0.8 && q98 < 3.0,
            "{name}: median {median:.2} mm, 98 % {q98:.2} mm"
        );
        points.push(cloud.len());
    }
    assert!(
        points[1] as f64 > 1.3 * points[0] as f64,
        "{} points with the dense region, {} without",
        points[1],
        points[0]
    );
}

#[test]
fn single_shot_reconstructs_one_image_of_the_x_point_pattern() {
    let dir = tempfile::tempdir().expect("tmp");
    let scene_path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/scenes/demo.toml");
    let xp = dir.path().join("xp");
    let o = ris(&[
        "patterns",
        "--xpoint",
        "--projector",
        "1024x768",
        "--step",
        "14,14",
        "--out",
        s(&xp),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    // The sensor file, and the camera's view of the pattern as projected.
    let sim_dir = dir.path().join("sim");
    simulate_showing(&scene_path, &sim_dir, &xp.join("xpoint.png"));
    let image = sim_dir.join("shown.png");
    let scene = ris_core::sim::Scene::load(&scene_path).expect("scene");
    let sim = ris_core::sim::Simulator::new(scene);
    let cloud_path = dir.path().join("single.ply");
    let o = ris(&[
        "single-shot",
        "--sensor",
        s(&sim_dir.join("sensor.toml")),
        "--pattern",
        s(&xp.join("xpoint.toml")),
        s(&image),
        "--out",
        s(&cloud_path),
        "--fused",
        s(&dir.path().join("fused.png")),
        "--range",
        "1450,1650",
    ]);
    assert!(o.status.success(), "single-shot: {}", stderr(&o));
    let cloud = ris_core::cloud::PointCloud::read_ply(&cloud_path).expect("cloud");
    assert!(cloud.len() > 1500, "{} points", cloud.len());
    assert_eq!(cloud.organised(), Some([800, 600]));
    // The fusion picture: at every point's own pixel, the colour of its distance from the
    // camera (red 1450 mm to blue 1650 mm), shaded by the picture by a factor in [0.45, 1].
    let fused = image::open(dir.path().join("fused.png"))
        .expect("fused.png")
        .into_rgb8();
    assert_eq!((fused.width(), fused.height()), (800 + 120, 600));
    let range = ris_core::single_shot::FusionRange::new(1450.0, 1650.0, "t").expect("range");
    let eye = sim.scene.camera.center();
    let mut off = 0;
    for (p, &px) in cloud.points.iter().zip(&cloud.pixels) {
        let d = ((f64::from(p[0]) - eye.x).powi(2)
            + (f64::from(p[1]) - eye.y).powi(2)
            + (f64::from(p[2]) - eye.z).powi(2))
        .sqrt();
        let want = range.colour(d);
        let got = fused.get_pixel(px % 800, px / 800).0;
        let top = want.iter().copied().max().unwrap_or(1).max(1);
        let shade = f64::from(got.iter().copied().max().unwrap_or(0)) / f64::from(top);
        let fits = (0.44..=1.01).contains(&shade)
            && want
                .iter()
                .zip(got)
                .all(|(w, g)| (f64::from(*w) * shade - f64::from(g)).abs() <= 3.0);
        if !fits {
            off += 1;
        }
    }
    assert_eq!(off, 0, "{off} of {} points coloured wrongly", cloud.len());
    // Near red and far blue both appear: the boxes stand out from the floor.
    let (mut reddish, mut bluish) = (0, 0);
    for px in fused.pixels() {
        let [r, _, b] = px.0;
        reddish += usize::from(r > 150 && b < 40);
        bluish += usize::from(b > 150 && r < 40);
    }
    assert!(
        reddish > 1000 && bluish > 1000,
        "{reddish} red, {bluish} blue pixels"
    );
    let (median, q98) = error_quantiles(&cloud, &sim);
    assert!(
        median < 0.8 && q98 < 3.0,
        "median {median:.2} mm, 98 % {q98:.2} mm"
    );
    // A pattern for another projector is refused by name.
    let other = dir.path().join("other");
    let o = ris(&[
        "patterns",
        "--xpoint",
        "--projector",
        "800x600",
        "--out",
        s(&other),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = ris(&[
        "single-shot",
        "--sensor",
        s(&sim_dir.join("sensor.toml")),
        "--pattern",
        s(&other.join("xpoint.toml")),
        s(&image),
        "--out",
        s(&cloud_path),
    ]);
    assert!(
        !o.status.success() && stderr(&o).contains("800x600"),
        "{}",
        stderr(&o)
    );
    for bad in ["1650,1450", "near,far", "1450"] {
        let o = ris(&[
            "single-shot",
            "--sensor",
            s(&sim_dir.join("sensor.toml")),
            "--pattern",
            s(&xp.join("xpoint.toml")),
            s(&image),
            "--out",
            s(&cloud_path),
            "--fused",
            s(&dir.path().join("bad.png")),
            "--range",
            bad,
        ]);
        assert!(
            !o.status.success() && stderr(&o).contains("--range"),
            "{bad}: {}",
            stderr(&o)
        );
    }
}

#[test]
fn convert_takes_a_cloud_through_e57_and_back() {
    let dir = tempfile::tempdir().expect("tmp");
    let mut cloud = ris_core::cloud::PointCloud::default();
    for i in 0..3000 {
        let t = f64::from(i) * 0.01;
        cloud.points.push([
            (300.0 * t.cos()) as f32,
            (200.0 * t.sin()) as f32,
            (850.0 + 10.0 * t) as f32,
        ]);
        cloud.confidence.push((i % 7) as f32 / 7.0);
        cloud.outside.push(i % 11 == 0);
    }
    let a = dir.path().join("a.ply");
    cloud.write_ply(&a).expect("ply");
    let (e, b) = (dir.path().join("a.e57"), dir.path().join("b.ply"));
    let o = ris(&["convert", s(&a), s(&e)]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(String::from_utf8_lossy(&o.stdout).contains("3000 points, 273 flagged"));
    let o = ris(&["convert", s(&e), s(&b)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let back = ris_core::cloud::PointCloud::read_ply(&b).expect("back");
    assert_eq!(back.outside, cloud.outside);
    assert_eq!(back.confidence, cloud.confidence);
    for (p, q) in cloud.points.iter().zip(&back.points) {
        for k in 0..3 {
            assert!((p[k] - q[k]).abs() < 1e-3, "{p:?} {q:?}");
        }
    }
    let o = ris(&["convert", s(&a), s(&dir.path().join("a.xyz"))]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("a.xyz") && stderr(&o).contains(".xyz"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn omni_analyse_prints_the_error_of_the_seeds_prototype() {
    let seed = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/omni/seed.toml");
    let o = ris(&[
        "omni",
        "--sensor",
        s(&seed),
        "--analyse",
        "--ranges",
        "2500,4000",
        "--heights=-1500,300,300",
        "--json",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
    let rows = v.as_array().expect("rows");
    assert_eq!(rows.len(), 14, "two ranges of seven heights");
    let level = rows
        .iter()
        .find(|r| r["range_mm"] == 2500.0 && r["height_mm"] == 0.0)
        .expect("the level point at 2.5 m");
    // The seed's 160 mm for a one-pixel error at 2.5 m with 640x480.
    let e = level["depth_error_camera_mm"].as_f64().expect("error");
    assert!((120.0..220.0).contains(&e), "{level}");
    let table = ris(&["omni", "--sensor", s(&seed), "--analyse"]);
    assert!(table.status.success(), "{}", stderr(&table));
    assert!(String::from_utf8_lossy(&table.stdout).contains("mm/px"));
    // A file of another kind and a bad height range are refused by name.
    let demo = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/scenes/demo.toml");
    let bad = ris(&["omni", "--sensor", s(&demo), "--analyse"]);
    assert!(
        !bad.status.success() && stderr(&bad).contains("demo.toml"),
        "{}",
        stderr(&bad)
    );
    let bad = ris(&[
        "omni",
        "--sensor",
        s(&seed),
        "--analyse",
        "--heights=0,100,-5",
    ]);
    assert!(
        !bad.status.success() && stderr(&bad).contains("--heights"),
        "{}",
        stderr(&bad)
    );
}

#[test]
fn simulate_renders_an_omni_room_through_the_mirrors_with_its_truth() {
    use ris_core::io::npy;
    let dir = tempfile::tempdir().expect("tmp");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/scenes/room.toml");
    let out = dir.path().join("room");
    let o = ris(&["simulate", "--scene", s(&scene), "--out", s(&out)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let image = ris_core::image::GrayImage::load(&out.join("image.png")).expect("image.png");
    assert_eq!((image.width, image.height), (640, 480));
    let (shape, xyz) = npy::read::<f32>(&out.join("truth/xyz.npy")).expect("xyz");
    assert_eq!(shape, [480, 640, 3]);
    let (_, lit) = npy::read::<u8>(&out.join("truth/lit.npy")).expect("lit");
    let (_, proj) = npy::read::<f32>(&out.join("truth/projector.npy")).expect("projector");
    let sensor = ris_core::omni::OmniSensor::load(&out.join("sensor.toml")).expect("sensor");
    let rings: ris_core::omni::RingPattern =
        ris_core::io::read_toml(&out.join("rings.toml")).expect("rings.toml");
    // The truth holds: each lit pixel's point projects back to the pixel through the camera
    // and to its projector pixel through the projector; and the image carries the rings there.
    let (mut pairs, mut checked) = (Vec::new(), 0);
    for i in (0..640 * 480).step_by(13) {
        if lit[i] == 0 {
            continue;
        }
        let p = ris_core::geometry::Vec3::new(
            f64::from(xyz[3 * i]),
            f64::from(xyz[3 * i + 1]),
            f64::from(xyz[3 * i + 2]),
        );
        let ((u, v), _) = sensor.camera.project(&p).expect("seen by the camera");
        assert!((u - (i % 640) as f64).hypot(v - (i / 640) as f64) < 0.01);
        let ((pu, pv), _) = sensor.projector.project(&p).expect("lit by the projector");
        assert!((pu - f64::from(proj[2 * i])).hypot(pv - f64::from(proj[2 * i + 1])) < 0.01);
        pairs.push((
            rings.value(pu, pv),
            image.get((i % 640) as u32, (i / 640) as u32) as f64,
        ));
        checked += 1;
    }
    assert!(checked > 2000, "{checked} lit pixels checked");
    let n = pairs.len() as f64;
    let (ma, mb) = (
        pairs.iter().map(|p| p.0).sum::<f64>() / n,
        pairs.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let cov: f64 = pairs.iter().map(|p| (p.0 - ma) * (p.1 - mb)).sum();
    let (va, vb): (f64, f64) = (
        pairs.iter().map(|p| (p.0 - ma).powi(2)).sum(),
        pairs.iter().map(|p| (p.1 - mb).powi(2)).sum(),
    );
    let corr = cov / (va * vb).sqrt();
    assert!(
        corr > 0.6,
        "image against the ring pattern: correlation {corr:.2}"
    );
    // A room whose floor is above its ceiling is refused by field.
    let bad = dir.path().join("bad.toml");
    let text = std::fs::read_to_string(&scene)
        .expect("scene")
        .replace(
            "sensor = \"../omni/seed.toml\"",
            &format!(
                "sensor = {:?}",
                Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/omni/seed.toml")
            ),
        )
        .replace("floor = -1200.0", "floor = 2000.0");
    std::fs::write(&bad, text).expect("bad scene");
    let o = ris(&[
        "simulate",
        "--scene",
        s(&bad),
        "--out",
        s(&dir.path().join("bad")),
    ]);
    assert!(
        !o.status.success() && stderr(&o).contains("room.floor"),
        "{}",
        stderr(&o)
    );
}

/// The distance a fused colour stands for under `near..far`, or `None` for a grey pixel (the
/// hue runs red 0° at `near` to blue 240° at `far`; shading scales the colour, not its hue).
fn distance_of_colour(c: [u8; 3], near: f64, far: f64) -> Option<f64> {
    let [r, g, b] = c.map(f64::from);
    let (max, min) = (r.max(g).max(b), r.min(g).min(b));
    if max < 30.0 || (max - min) / max < 0.5 {
        return None;
    }
    let d = max - min;
    let hue = if max == r {
        (60.0 * (g - b) / d).rem_euclid(360.0)
    } else if max == g {
        60.0 * ((b - r) / d + 2.0)
    } else {
        60.0 * ((r - g) / d + 4.0)
    };
    (hue <= 245.0).then(|| near + (far - near) * hue.min(240.0) / 240.0)
}

#[test]
fn omni_decodes_a_rendered_room_into_its_cloud_and_a_panorama_with_corners_at_their_bearing() {
    let dir = tempfile::tempdir().expect("tmp");
    let scene_path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/scenes/room.toml");
    let out = dir.path().join("room");
    let o = ris(&["simulate", "--scene", s(&scene_path), "--out", s(&out)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let (cloud, pano) = (dir.path().join("room.ply"), dir.path().join("pano.png"));
    let o = ris(&[
        "omni",
        "--sensor",
        s(&out.join("sensor.toml")),
        s(&out.join("image.png")),
        "--pattern",
        s(&out.join("rings.toml")),
        "--out",
        s(&cloud),
        "--panorama",
        s(&pano),
        "--range",
        "2000,4500",
        "--json",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let summary: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json summary");
    let n = summary["points"].as_u64().expect("points");
    assert!(n > 12_000, "{n} points");
    // Every point against the surface its camera ray meets in the room (the scene's truth).
    let scene = ris_core::omni::scene::OmniScene::load(&scene_path).expect("scene");
    let c = ris_core::cloud::PointCloud::read_ply(&cloud).expect("cloud");
    assert_eq!(c.len() as u64, n);
    let col = |name: &str| {
        c.scalars
            .iter()
            .find(|x| x.name == name)
            .unwrap_or_else(|| panic!("{name} per point"))
            .values
            .clone()
    };
    let (u, v) = (col("u"), col("v"));
    let mut errors: Vec<f64> = c
        .points
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let ray = scene
                .sensor
                .camera
                .back_project(f64::from(u[i]), f64::from(v[i]))
                .expect("a pixel on the mirror");
            let (t, _, _) = scene
                .room
                .intersect(&ray.origin, &ray.direction)
                .expect("room");
            let truth = ray.origin + ray.direction * t;
            ((f64::from(p[0]) - truth.x).powi(2)
                + (f64::from(p[1]) - truth.y).powi(2)
                + (f64::from(p[2]) - truth.z).powi(2))
            .sqrt()
        })
        .collect();
    errors.sort_by(f64::total_cmp);
    let median = errors[errors.len() / 2];
    let far = errors.iter().filter(|e| **e > 300.0).count() as f64 / errors.len() as f64;
    assert!(median < 30.0, "median |error| {median:.1} mm");
    assert!(far < 0.07, "{:.1} % of points > 300 mm off", 100.0 * far);
    // The panorama: columns are azimuth; the walls are furthest at the room's corners. The
    // room (6 x 5 m about (200, -300)) has corners at bearings 141.8° and 318.8° clear of the
    // box and the cylinder.
    let img = image::open(&pano).expect("panorama").to_rgb8();
    let width = summary["panorama_width"].as_u64().expect("panorama_width") as u32;
    assert_eq!(
        img.width(),
        width + 120,
        "the unrolled image and the colour bar"
    );
    let distance: Vec<Option<f64>> = (0..width)
        .map(|x| {
            let mut d: Vec<f64> = (0..img.height())
                .filter_map(|y| distance_of_colour(img.get_pixel(x, y).0, 2000.0, 4500.0))
                .collect();
            d.sort_by(f64::total_cmp);
            (d.len() >= 5).then(|| d[d.len() / 2])
        })
        .collect();
    for (cx, cy) in [(-2800.0f64, 2200.0f64), (3200.0, -2800.0)] {
        let bearing = cy.atan2(cx).to_degrees().rem_euclid(360.0);
        // The column of greatest distance within 20° of it, smoothed over 1°.
        let per_degree = f64::from(width) / 360.0;
        let smooth = |x: i64| {
            let k = (per_degree / 2.0).ceil() as i64;
            let vals: Vec<f64> = (x - k..=x + k)
                .filter_map(|i| distance[i.rem_euclid(i64::from(width)) as usize])
                .collect();
            (!vals.is_empty()).then(|| vals.iter().sum::<f64>() / vals.len() as f64)
        };
        let centre = (bearing * per_degree) as i64;
        let span = (20.0 * per_degree) as i64;
        let best = (centre - span..=centre + span)
            .filter_map(|x| Some((x, smooth(x)?)))
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .expect("coloured columns near the corner");
        let found = (best.0 as f64 + 0.5) / per_degree;
        let off = ((found - bearing + 180.0).rem_euclid(360.0) - 180.0).abs();
        eprintln!("corner at {bearing:.1}°: panorama {found:.1}°");
        assert!(
            off < 2.0,
            "corner at {bearing:.1}° shows at {found:.1}° in the panorama ({off:.1}° off)"
        );
    }
}

#[test]
fn calibrate_omni_turns_a_two_position_session_into_ray_tables_that_decode_a_room() {
    let dir = tempfile::tempdir().expect("tmp");
    let spec =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/omni/calibration-session.toml");
    let session = dir.path().join("session");
    let o = ris(&["simulate", "--scene", s(&spec), "--out", s(&session)]);
    assert!(o.status.success(), "{}", stderr(&o));
    // A second session into the same directory is refused; the first is left as it was.
    let before = std::fs::read(session.join("session.toml")).expect("session.toml");
    let o = ris(&["simulate", "--scene", s(&spec), "--out", s(&session)]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("not empty"), "{}", stderr(&o));
    assert_eq!(
        std::fs::read(session.join("session.toml")).expect("session.toml"),
        before
    );
    let out = dir.path().join("cal").join("omni.toml");
    let o = ris(&["calibrate", "omni", s(&session), "--out", s(&out)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let said = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(
        said.contains("camera: model fitted") && said.contains("projector: model fitted"),
        "{said}"
    );
    assert!(
        out.with_file_name("cam_rays.npy").exists() && out.with_file_name("proj_rays.npy").exists()
    );
    let sensor = ris_core::omni::OmniSensor::load(&out).expect("the calibrated file loads");
    let tables = sensor.tables.as_ref().expect("it names its tables");
    // Camera rays against the mirror model the session was rendered with.
    let mut angles: Vec<f64> = tables
        .0
        .rays
        .iter()
        .enumerate()
        .filter(|(_, r)| r[0].is_finite())
        .map(|(i, r)| {
            let m = sensor
                .camera
                .back_project((i % 640) as f64, (i / 640) as f64)
                .expect("on the mirror");
            let d =
                ris_core::geometry::Vec3::new(f64::from(r[3]), f64::from(r[4]), f64::from(r[5]));
            d.dot(&m.direction).clamp(-1.0, 1.0).acos().to_degrees()
        })
        .collect();
    angles.sort_by(f64::total_cmp);
    assert!(angles.len() > 80_000, "{} camera rays", angles.len());
    assert!(
        angles[angles.len() / 2] < 0.01,
        "median {:.4}°",
        angles[angles.len() / 2]
    );
    // The calibrated file decodes the room.
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/scenes/room.toml");
    let room = dir.path().join("room");
    let o = ris(&["simulate", "--scene", s(&scene), "--out", s(&room)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let cloud = dir.path().join("room.ply");
    let o = ris(&[
        "omni",
        "--sensor",
        s(&out),
        s(&room.join("image.png")),
        "--pattern",
        s(&room.join("rings.toml")),
        "--out",
        s(&cloud),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let c = ris_core::cloud::PointCloud::read_ply(&cloud).expect("cloud");
    assert!(c.len() > 5000, "{} points", c.len());
    // A session with one position is refused by field, and nothing is written.
    let bad = dir.path().join("bad");
    std::fs::create_dir_all(&bad).expect("mkdir");
    std::fs::copy(session.join("sensor.toml"), bad.join("sensor.toml")).expect("copy");
    std::fs::copy(session.join("session.toml"), bad.join("session.toml")).expect("copy");
    let text = std::fs::read_to_string(bad.join("session.toml")).expect("session.toml");
    let cut = text.rfind("[[position]]").expect("two positions");
    std::fs::write(bad.join("session.toml"), &text[..cut]).expect("write");
    let bad_out = dir.path().join("bad-cal").join("omni.toml");
    let o = ris(&["calibrate", "omni", s(&bad), "--out", s(&bad_out)]);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(e.contains("position") && e.contains("two"), "{e}");
    assert!(!bad_out.exists());
}

/// Rooms rendered by an independent renderer (`tests/omni_room_render.py`, numpy: 2 × 2 rays
/// per pixel, rings evaluated from rings.toml's formula, its own mirror and room code, 1.5
/// levels of noise) decode with `ris omni`: share of the ring pixels reconstructed, and the
/// points' error against the room.
#[test]
fn omni_decodes_rooms_rendered_by_an_independent_renderer() {
    use ris_core::geometry::Vec3;
    let dir = tempfile::tempdir().expect("tmp");
    let config = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/omni/seed.toml");
    let renderer = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/omni_room_render.py");
    let (rings_toml, rings) = ring_pattern(dir.path(), "640x480", "319.5,239.5");
    let sensor = ris_core::omni::OmniSensor::load(&config).expect("sensor");
    // (half, centre, floor, ceiling, box centre, box half, noise seed)
    let rooms = [
        (
            [2900.0, 2400.0],
            [150.0, -250.0],
            -1250.0,
            1350.0,
            [-1400.0, 900.0, -850.0],
            [350.0, 300.0, 400.0],
            11,
        ),
        (
            [3400.0, 2100.0],
            [-300.0, 200.0],
            -1100.0,
            1200.0,
            [1200.0, -1100.0, -700.0],
            [300.0, 400.0, 400.0],
            12,
        ),
    ];
    for (n, (half, centre, floor, ceiling, bc, bh, seed)) in rooms.into_iter().enumerate() {
        let out = dir.path().join(format!("room{n}"));
        std::fs::create_dir_all(&out).expect("mkdir");
        let room_json = out.join("room.json");
        let spec = serde_json::json!({
            "half": half, "center": centre, "floor": floor, "ceiling": ceiling,
            "albedo": [0.55, 0.35, 0.65],
            "boxes": [{"center": bc, "half": bh, "albedo": 0.5}],
            "gain": 230.0, "ambient": 0.03, "noise": 1.5, "seed": seed
        });
        std::fs::write(&room_json, spec.to_string()).expect("room.json");
        let py = Command::new("python3")
            .arg(&renderer)
            .args([&config, &rings_toml, &room_json, &out])
            .output()
            .expect("python3");
        assert!(
            py.status.success(),
            "{}",
            String::from_utf8_lossy(&py.stderr)
        );
        let c = decode_rendered_room(&config, &rings_toml, &out);
        let (u, v) = (column(&c, "u"), column(&c, "v"));
        // The room as the renderer was given it, for the truth along each point's camera ray.
        let room = ris_core::omni::Room {
            half,
            center: centre,
            floor,
            ceiling,
            albedo: [0.55, 0.35, 0.65],
            objects: vec![(
                ris_core::sim::Shape::Box {
                    center: Vec3::from(bc),
                    half: Vec3::from(bh),
                },
                0.5,
            )],
        };
        let mut errors: Vec<f64> = (0..c.len())
            .map(|i| {
                let ray = sensor
                    .camera
                    .back_project(f64::from(u[i]), f64::from(v[i]))
                    .expect("on the mirror");
                let (t, _, _) = room.intersect(&ray.origin, &ray.direction).expect("room");
                let p = c.points[i];
                (Vec3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]))
                    - (ray.origin + ray.direction * t))
                    .norm()
            })
            .collect();
        errors.sort_by(f64::total_cmp);
        let median = errors[errors.len() / 2];
        let far = errors.iter().filter(|e| **e > 300.0).count() as f64 / errors.len() as f64;
        let (ring_pixels, reconstructed) =
            ring_pixels_reconstructed(&c, &rings, &out.join("projector.npy"), [640, 480]);
        let coverage = reconstructed as f64 / ring_pixels as f64;
        eprintln!(
            "independent room {n}: {} points, {reconstructed} of {ring_pixels} ring pixels ({:.1} %), median {median:.1} mm, {:.2} % beyond 300 mm",
            c.len(),
            100.0 * coverage,
            100.0 * far
        );
        assert!(
            coverage > 0.85,
            "room {n}: ring pixels reconstructed {:.3}",
            coverage
        );
        assert!(median < 25.0, "room {n}: median {median:.1} mm");
        assert!(far < 0.03, "room {n}: {:.3} beyond 300 mm", far);
    }
}

/// The seeded room family at 2048 × 2048 (`tests/omni_room_family.py` seeds 1–6: half-sizes
/// 1.8–4 m, off the axis by up to 30 %, 1–3 boxes), rendered by the independent renderer and
/// decoded by `ris omni`: the share of points more than 200 mm from the renderer's truth in
/// each band of distance from the axis, and the ring pixels reconstructed. Issue 45 asks for
/// at most 1 % in every band with 95 % coverage; the bounds below are what the decoder holds
/// today (0.32 % pooled, bands up to 3.6 % on box faces 1.5–2.5 m away, coverage 94.4–96.6 %).
#[test]
#[ignore = "long tier (`.ci/run --long`): renders six 2048x2048 rooms, about 15 minutes"]
fn omni_room_family_at_2048_keeps_wrong_rings_rare() {
    use ris_core::io::npy;
    let dir = tempfile::tempdir().expect("tmp");
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let config = root.join("config/omni/seed-2k.toml");
    let (rings_toml, rings) = ring_pattern(dir.path(), "2048x2048", "1023.5,1023.5");
    let seeds = [1, 2, 3, 4, 5, 6];
    // Render two rooms at a time (the renderer is single-threaded numpy).
    for pair in seeds.chunks(2) {
        let children: Vec<_> = pair
            .iter()
            .map(|seed| {
                let out = dir.path().join(format!("room{seed}"));
                std::fs::create_dir_all(&out).expect("mkdir");
                let spec = Command::new("python3")
                    .arg(root.join("tests/omni_room_family.py"))
                    .arg(seed.to_string())
                    .output()
                    .expect("python3");
                assert!(spec.status.success(), "{}", stderr(&spec));
                std::fs::write(out.join("room.json"), &spec.stdout).expect("room.json");
                Command::new("python3")
                    .arg(root.join("tests/omni_room_render.py"))
                    .args([&config, &rings_toml, &out.join("room.json"), &out])
                    .stdout(std::process::Stdio::null())
                    .spawn()
                    .expect("python3")
            })
            .collect();
        for mut c in children {
            assert!(c.wait().expect("renderer").success());
        }
    }
    let bands = [
        0.0,
        1500.0,
        2000.0,
        2500.0,
        3000.0,
        3500.0,
        4000.0,
        f64::INFINITY,
    ];
    let (mut far_all, mut all) = (0usize, 0usize);
    for seed in seeds {
        let out = dir.path().join(format!("room{seed}"));
        let c = decode_rendered_room(&config, &rings_toml, &out);
        let (u, v) = (column(&c, "u"), column(&c, "v"));
        let (shape, xyz) = npy::read::<f32>(&out.join("xyz.npy")).expect("xyz.npy");
        let (h, w) = (shape[0], shape[1]);
        // (points, beyond 200 mm) per band of the truth's distance from the axis.
        let mut per = vec![(0usize, 0usize); bands.len() - 1];
        for i in 0..c.len() {
            let x = (u[i].round().max(0.0) as usize).min(w - 1);
            let y = (v[i].round().max(0.0) as usize).min(h - 1);
            let t = &xyz[3 * (y * w + x)..3 * (y * w + x) + 3];
            if !t[0].is_finite() {
                continue;
            }
            let p = c.points[i];
            let e = ((p[0] - t[0]).powi(2) + (p[1] - t[1]).powi(2) + (p[2] - t[2]).powi(2)).sqrt();
            let r = f64::from(t[0].hypot(t[1]));
            let b = bands.iter().rposition(|lo| r >= *lo).expect("band");
            per[b].0 += 1;
            per[b].1 += usize::from(e > 200.0);
        }
        let (ring_pixels, reconstructed) =
            ring_pixels_reconstructed(&c, &rings, &out.join("projector.npy"), [w, h]);
        let coverage = reconstructed as f64 / ring_pixels as f64;
        let shares: Vec<String> = per
            .iter()
            .map(|(n, f)| {
                if *n >= 1000 {
                    format!("{:.1}", 100.0 * *f as f64 / *n as f64)
                } else {
                    "-".into()
                }
            })
            .collect();
        let (n, f) = per.iter().fold((0, 0), |(a, b), (n, f)| (a + n, b + f));
        eprintln!(
            "room {seed}: {n} points, {:.2} % beyond 200 mm; by distance from the axis (<1.5, 1.5-2, 2-2.5, 2.5-3, 3-3.5, 3.5-4, >4 m): {} %; coverage {:.1} %",
            100.0 * f as f64 / n as f64,
            shares.join(" / "),
            100.0 * coverage
        );
        far_all += f;
        all += n;
        assert!(coverage > 0.94, "room {seed}: coverage {coverage:.3}");
        for (b, (n, f)) in per.iter().enumerate() {
            if *n >= 1000 {
                let share = *f as f64 / *n as f64;
                assert!(
                    share < 0.05,
                    "room {seed}: {:.3} beyond 200 mm at {} m from the axis",
                    share,
                    bands[b] / 1e3
                );
            }
        }
    }
    let pooled = far_all as f64 / all as f64;
    eprintln!("the family: {:.2} % beyond 200 mm", 100.0 * pooled);
    assert!(pooled < 0.005, "{pooled:.4} beyond 200 mm");
}

/// `ris patterns --rings` for a projector of `size` ("WxH") centred at `centre` ("u,v"),
/// written under `dir/rings`: the pattern file and the pattern read back.
fn ring_pattern(dir: &Path, size: &str, centre: &str) -> (PathBuf, ris_core::omni::RingPattern) {
    let rings_dir = dir.join("rings");
    let o = ris(&[
        "patterns",
        "--rings",
        "--projector",
        size,
        "--center",
        centre,
        "--out",
        s(&rings_dir),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let rings_toml = rings_dir.join("rings.toml");
    let rings = ris_core::io::read_toml(&rings_toml).expect("rings");
    (rings_toml, rings)
}

/// `ris omni` on the image a renderer wrote to `out` (`image.png`), its cloud read back.
fn decode_rendered_room(
    config: &Path,
    rings_toml: &Path,
    out: &Path,
) -> ris_core::cloud::PointCloud {
    let cloud = out.join("cloud.ply");
    let o = ris(&[
        "omni",
        "--sensor",
        s(config),
        s(&out.join("image.png")),
        "--pattern",
        s(rings_toml),
        "--out",
        s(&cloud),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    ris_core::cloud::PointCloud::read_ply(&cloud).expect("cloud")
}

/// A per-point scalar column of `c`.
fn column(c: &ris_core::cloud::PointCloud, name: &str) -> Vec<f32> {
    c.scalars
        .iter()
        .find(|x| x.name == name)
        .expect(name)
        .values
        .clone()
}

/// Ring pixels of a rendered image (`size`: width, height) — lit pixels whose projector pixel
/// (the renderer's `projector.npy`) lies within 0.5 px of a ring's centre where that ring is at
/// least a quarter bright — and how many of them have a point of that ring of `c` within 2 px.
fn ring_pixels_reconstructed(
    c: &ris_core::cloud::PointCloud,
    rings: &ris_core::omni::RingPattern,
    projector_npy: &Path,
    [w, h]: [usize; 2],
) -> (usize, usize) {
    let (u, v, ring) = (column(c, "u"), column(c, "v"), column(c, "ring"));
    let (_, proj) = ris_core::io::npy::read::<f32>(projector_npy).expect("projector.npy");
    let [pcx, pcy] = rings.pattern.center;
    let mut decoded: std::collections::HashMap<(i64, i64), Vec<u32>> = Default::default();
    for i in 0..c.len() {
        decoded
            .entry((u[i].round() as i64, v[i].round() as i64))
            .or_default()
            .push(ring[i] as u32);
    }
    let (mut ring_pixels, mut reconstructed) = (0usize, 0usize);
    for i in 0..w * h {
        let (pu, pv) = (f64::from(proj[2 * i]), f64::from(proj[2 * i + 1]));
        if !pu.is_finite() {
            continue;
        }
        let (rho, theta) = ((pu - pcx).hypot(pv - pcy), (pv - pcy).atan2(pu - pcx));
        let Some(k) = rings.ring.iter().position(|r| {
            (rho - r.radius).abs() <= 0.5
                && 0.5 * (1.0 + (f64::from(r.frequency) * theta + r.phase).cos()) >= 0.25
        }) else {
            continue;
        };
        ring_pixels += 1;
        let (x, y) = ((i % w) as i64, (i / w) as i64);
        reconstructed += usize::from((-2..=2).any(|dy| {
            (-2..=2).any(|dx| {
                decoded
                    .get(&(x + dx, y + dy))
                    .is_some_and(|rs| rs.contains(&(k as u32)))
            })
        }));
    }
    (ring_pixels, reconstructed)
}

/// Write the artefact clouds of `set` as PLY (and the first sphere as E57) under `dir`.
fn write_clouds(dir: &Path, set: &[ris_core::verify::MeasuredCloud]) -> Vec<String> {
    set.iter()
        .enumerate()
        .map(|(i, c)| {
            let mut name = c.name.clone();
            if i == 0 && name.starts_with("sphere") {
                name = name.replace(".ply", ".e57");
            }
            let path = dir.join(&name);
            let cloud = ris_core::cloud::PointCloud {
                points: c
                    .points
                    .iter()
                    .map(|p| [p.x as f32, p.y as f32, p.z as f32])
                    .collect(),
                confidence: vec![1.0; c.points.len()],
                ..Default::default()
            };
            if name.ends_with(".e57") {
                cloud.write_e57(&path).expect("write e57");
            } else {
                cloud.write_ply(&path).expect("write ply");
            }
            s(&path).to_string()
        })
        .collect()
}

#[test]
fn verify_certifies_an_acceptance_set_and_refuses_bad_input() {
    use ris_core::verify::synthetic::acceptance_set;
    let dir = tempfile::tempdir().expect("tempdir");
    let artefacts = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../config/verify/artefacts.toml"
    );
    let verify = |bars: &[String], planes: &[String], spheres: &[String], out: &Path| {
        let mut args: Vec<&str> = vec!["verify", "--artefacts", artefacts, "--out", s(out)];
        args.push("--ball-bar");
        args.extend(bars.iter().map(String::as_str));
        args.push("--plane");
        args.extend(planes.iter().map(String::as_str));
        args.push("--sphere");
        args.extend(spheres.iter().map(String::as_str));
        ris(&args)
    };
    let (bars, planes, spheres) = acceptance_set(41, 0.008, 1.0);
    let (b, p, sp) = (
        write_clouds(dir.path(), &bars),
        write_clouds(dir.path(), &planes),
        write_clouds(dir.path(), &spheres),
    );
    let out = dir.path().join("verify");
    let o = verify(&b, &p, &sp, &out);
    let stdout = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(o.status.success(), "{}\n{}", stdout, stderr(&o));
    assert!(stdout.contains("verification: PASS") && stdout.contains("acceptance test"));
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("verify.json")).expect("json"))
            .expect("parse");
    assert_eq!(json["verdict"], "pass");
    assert_eq!(json["sphere_spacing"].as_array().map(Vec::len), Some(7));
    assert_eq!(json["flatness"].as_array().map(Vec::len), Some(6));
    assert_eq!(json["probing_size"].as_array().map(Vec::len), Some(10));
    assert_eq!(json["probing_size"][0]["cloud"], "sphere-1.e57", "E57 read");
    for f in json["probing_size"].as_array().expect("array") {
        // The clouds are stored as float32: a 40 mm sphere keeps its size within 5 µm.
        let e = f["error"].as_f64().expect("PS");
        assert!(e.abs() < 0.005, "PS {e} of {}", f["cloud"]);
    }
    let html = std::fs::read_to_string(out.join("verify.html")).expect("html");
    assert!(html.contains("PASS") && html.contains("bar-7-a.png"));
    let map = image::open(out.join("flat-1.png")).expect("residual map decodes");
    assert!(map.width() > 100);
    // An existing output is not overwritten.
    let o = verify(&b, &p, &sp, &out);
    assert!(
        !o.status.success() && stderr(&o).contains("not empty"),
        "{}",
        stderr(&o)
    );
    // The same set measured 0.05 % large fails SD: exit status 3.
    let scaled = tempfile::tempdir().expect("tempdir");
    let (bars, _, _) = acceptance_set(41, 0.008, 1.0005);
    let b2 = write_clouds(scaled.path(), &bars);
    let o = verify(&b2, &p, &sp, &scaled.path().join("out"));
    assert_eq!(o.status.code(), Some(3), "{}", stderr(&o));
    // A bad artefacts file names the file and field, and writes nothing.
    let bad = dir.path().join("bad.toml");
    std::fs::write(
        &bad,
        std::fs::read_to_string(artefacts)
            .expect("read")
            .replace("diameter = 40.0", "diameter = -40.0"),
    )
    .expect("write");
    let bad_out = dir.path().join("bad-out");
    let o = ris(&[
        "verify",
        "--artefacts",
        s(&bad),
        "--out",
        s(&bad_out),
        "--sphere",
        &sp[1],
    ]);
    let e = stderr(&o);
    assert!(
        !o.status.success() && e.contains("bad.toml") && e.contains("sphere.diameter"),
        "{e}"
    );
    assert!(!bad_out.exists());
    // A cloud that is not a cloud.
    let junk = dir.path().join("junk.ply");
    std::fs::write(&junk, b"ply\nformat nonsense\n").expect("write");
    let o = ris(&[
        "verify",
        "--artefacts",
        artefacts,
        "--out",
        s(&bad_out),
        "--sphere",
        s(&junk),
    ]);
    let e = stderr(&o);
    assert!(!o.status.success() && e.contains("junk.ply"), "{e}");
    assert!(!bad_out.exists());
}

/// A client pointed at the wrong place is told what to change in its own words: an endpoint
/// without its protocol names `--connect` and the form; a port where no risd listens says so.
/// No library's source path, backtrace or log line reaches the user.
#[test]
fn client_commands_say_what_to_change_when_the_daemon_cannot_be_reached() {
    let dir = tempfile::tempdir().expect("tmp");
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("port");
    let nobody = format!("tcp/127.0.0.1:{port}");
    let out = dir.path().join("out");
    for (connect, needles) in [
        (
            "127.0.0.1:7447",
            vec!["--connect", "tcp/127.0.0.1:7447", "no protocol"],
        ),
        ("tcp/127.0.0.1", vec!["--connect", "no port"]),
        (
            nobody.as_str(),
            vec!["no risd answers", nobody.as_str(), "--connect"],
        ),
    ] {
        for command in ["scan", "stream"] {
            let o = Command::new(env!("CARGO_BIN_EXE_ris"))
                .args([command, "--connect", connect, "--out", s(&out)])
                .args(if command == "stream" {
                    &["--frames", "1"][..]
                } else {
                    &[]
                })
                .env_remove("RIS_LOG")
                .env("RUST_BACKTRACE", "0")
                .output()
                .expect("run ris");
            let err = stderr(&o);
            assert!(!o.status.success(), "{command} {connect}: {err}");
            for n in &needles {
                assert!(
                    err.contains(n),
                    "{command} {connect}: {n:?} missing in {err}"
                );
            }
            for noise in ["registry/src", ".rs:", "Json5Err", "WARN", "INFO"] {
                assert!(
                    !err.contains(noise),
                    "{command} {connect}: {noise:?} in {err}"
                );
            }
            assert!(!out.exists(), "{command} {connect} wrote output");
        }
    }
}

/// `ris verify --simulate` refuses what it cannot place or render, by name, writing nothing.
/// (The whole simulated set, 23 renders, runs in the core's acceptance_scenes test.)
#[test]
fn verify_simulate_refuses_a_file_without_a_volume_and_a_bad_scene() {
    let dir = tempfile::tempdir().expect("tmp");
    let root = concat!(env!("CARGO_MANIFEST_DIR"), "/../config/verify/");
    let text = std::fs::read_to_string(format!("{root}demo-artefacts.toml")).expect("artefacts");
    let no_volume = dir.path().join("no-volume.toml");
    std::fs::write(&no_volume, &text[..text.find("[volume]").expect("volume")]).expect("write");
    let out = dir.path().join("out");
    let scene = format!("{root}demo-sensor.toml");
    fails(
        &[
            "verify",
            "--artefacts",
            s(&no_volume),
            "--simulate",
            &scene,
            "--out",
            s(&out),
        ],
        &["no-volume.toml", "[volume]"],
        &out,
    );
    let bad_scene = dir.path().join("scene.toml");
    std::fs::write(&bad_scene, "[camera]\nwidth = 0\n").expect("write");
    let artefacts = format!("{root}demo-artefacts.toml");
    fails(
        &[
            "verify",
            "--artefacts",
            &artefacts,
            "--simulate",
            s(&bad_scene),
            "--out",
            s(&out),
        ],
        &["scene.toml"],
        &out,
    );
    // Measured clouds and a simulated set do not mix.
    fails(
        &[
            "verify",
            "--artefacts",
            &artefacts,
            "--simulate",
            &scene,
            "--sphere",
            "a.ply",
            "--out",
            s(&out),
        ],
        &["--simulate"],
        &out,
    );
}

/// `ris inspect --characteristics` (issue 42 item 3): a seeded STEP block built with its first
/// hole moved 0.3 mm and grown 0.1 mm, scanned from above (rays on a 0.3 mm lattice), inspected
/// at the known pose against the nominal STEP with ISO 1101 characteristics on its faces: the
/// hole's position and diameter read the planted values and fail, the top face's flatness
/// passes; the report, the text and the page carry them. A characteristics file with a mesh CAD
/// is refused.
#[cfg(feature = "step")]
#[test]
fn inspect_measures_characteristics_on_step_faces() {
    use ris_core::geometry::Vec3;
    use ris_core::mesh::step::{self, FaceSurface, StepOptions};
    let dir = tempfile::tempdir().expect("tmp");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/step_parts.py");
    let o = Command::new("python3")
        .arg(&script)
        .arg(dir.path())
        .args(["41", "1", "0.3", "0", "0.1"])
        .output()
        .expect("python3 runs tests/step_parts.py (cadquery-ocp, installed by .ci/run)");
    assert!(o.status.success(), "{}", stderr(&o));
    let truth: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.path().join("part_0.json")).expect("truth"),
    )
    .expect("json");
    let nominal = dir.path().join("part_0.step");
    let model = step::read(&nominal, &StepOptions::default()).expect("nominal");
    let built = step::read(
        &dir.path().join("part_0_actual.step"),
        &StepOptions::default(),
    )
    .expect("as built");
    let v = |j: &serde_json::Value| {
        Vec3::new(
            j[0].as_f64().expect("x"),
            j[1].as_f64().expect("y"),
            j[2].as_f64().expect("z"),
        )
    };
    let hole = &truth["holes"][0];
    let (centre, axis, radius) = (
        v(&hole["centre"]),
        v(&hole["axis"]).normalize(),
        hole["radius"].as_f64().expect("r"),
    );
    let face_of = |want: &dyn Fn(&FaceSurface) -> bool| {
        model
            .faces
            .iter()
            .filter(|f| want(&f.surface))
            .max_by_key(|f| f.triangles)
            .expect("face")
            .entity
    };
    let bore = face_of(&|s| match s {
        FaceSurface::Cylinder {
            origin, radius: r, ..
        } => {
            let off = origin - centre;
            (r - radius).abs() < 1e-6 && (off - axis * off.dot(&axis)).norm() < 1e-6
        }
        _ => false,
    });
    // the face seen from above: the plane facing along the countersunk side of the axis
    let top =
        face_of(&|s| matches!(s, FaceSurface::Plane { normal, .. } if normal.dot(&axis) > 0.99));
    // rays straight down the axis on a 0.3 mm lattice over the part
    let bvh = ris_core::mesh::Bvh::new(built.mesh.clone());
    let e1 = axis.cross(&Vec3::new(0.3, 0.5, 0.8)).normalize();
    let e2 = axis.cross(&e1);
    let mut points = Vec::new();
    for j in -800..800 {
        for i in -800..800 {
            let from = centre + axis * 200.0 + e1 * (0.3 * i as f64) + e2 * (0.3 * j as f64);
            if let Some(hit) = bvh.intersect(&from, &-axis, 0.0, 1e4) {
                if hit.normal.dot(&axis) > 0.17 {
                    let p = from - axis * hit.t;
                    points.push([p.x as f32, p.y as f32, p.z as f32]);
                }
            }
        }
    }
    let cloud = dir.path().join("scan.ply");
    ris_core::cloud::PointCloud {
        confidence: vec![1.0; points.len()],
        points,
        ..Default::default()
    }
    .write_ply(&cloud)
    .expect("ply");
    let spec = dir.path().join("gdt.toml");
    std::fs::write(
        &spec,
        format!(
            "[[characteristic]]\nname = \"top\"\nkind = \"flatness\"\nfaces = [{top}]\ntolerance = 0.05\n\n\
             [[characteristic]]\nname = \"bore\"\nkind = \"diameter\"\nfaces = [{bore}]\nlower = -0.05\nupper = 0.05\n\n\
             [[characteristic]]\nname = \"bore\"\nkind = \"position\"\nfaces = [{bore}]\ntolerance = 0.2\n"
        ),
    )
    .expect("write");
    let out = dir.path().join("out");
    let o = ris(&[
        "inspect",
        "--cloud",
        cloud.to_str().expect("utf8"),
        "--cad",
        nominal.to_str().expect("utf8"),
        "--characteristics",
        spec.to_str().expect("utf8"),
        "--tolerance",
        "0.5",
        "--min-coverage",
        "0",
        "--pose",
        "known",
        "--out",
        out.to_str().expect("utf8"),
    ]);
    let text = String::from_utf8_lossy(&o.stdout);
    assert_eq!(o.status.code(), Some(3), "{text}\n{}", stderr(&o));
    assert!(
        text.contains("⌖ position of bore") && text.contains("OUT"),
        "{text}"
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).expect("report"))
            .expect("json");
    let c = report["characteristics"]
        .as_array()
        .expect("characteristics");
    let get = |kind: &str| c.iter().find(|x| x["characteristic"] == kind).expect(kind);
    let flat = get("flatness");
    assert!(
        flat["measured"].as_f64().expect("flatness") < 0.02,
        "{flat}"
    );
    assert_eq!(flat["in_tolerance"], true, "{flat}");
    let d = get("diameter")["measured"].as_f64().expect("diameter");
    assert!(
        (d - 2.0 * (radius + 0.1)).abs() < 0.05,
        "diameter {d} against {}",
        2.0 * (radius + 0.1)
    );
    assert_eq!(get("diameter")["in_tolerance"], false);
    let p = get("position")["measured"].as_f64().expect("position");
    assert!((p - 0.6).abs() < 0.08, "position {p} against 0.6");
    assert_eq!(get("position")["in_tolerance"], false);
    let page = std::fs::read_to_string(out.join("report.html")).expect("page");
    assert!(
        page.contains("id=\"characteristics\""),
        "the page has no characteristics table"
    );
    // a mesh CAD has no faces to name
    let stl = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/mock-cell/panel.stl");
    let o = ris(&[
        "inspect",
        "--cloud",
        cloud.to_str().expect("utf8"),
        "--cad",
        stl.to_str().expect("utf8"),
        "--characteristics",
        spec.to_str().expect("utf8"),
        "--tolerance",
        "0.5",
        "--out",
        out.to_str().expect("utf8"),
    ]);
    assert!(
        !o.status.success() && stderr(&o).contains("--characteristics needs a STEP model"),
        "{}",
        stderr(&o)
    );
}
