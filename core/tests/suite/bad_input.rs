//! Bad files and degenerate data: every reader answers with an error in bounded time and
//! memory (header counts checked against the bytes present), NaN points are dropped with a
//! count rather than looped on, and an inspection that measured nothing of the part is
//! `not_measured`, never `pass`. Property tests feed the readers random and mutated bytes
//! (cases per reader: `PROPTEST_CASES`, 256 by default).

use std::path::Path;

use proptest::prelude::*;
use ris_core::cloud::PointCloud;
use ris_core::inspect::{inspect, InspectParams, NOT_MEASURED};
use ris_core::mesh::{SignedDistance, TriangleMesh};
use ris_core::sensor::Sensor;
use ris_core::spatial::KdTree;

fn write(dir: &Path, name: &str, bytes: &[u8]) -> std::path::PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).expect("write");
    p
}

fn ply_header(n: &str) -> String {
    format!("ply\nformat binary_little_endian 1.0\nelement vertex {n}\nproperty float x\nproperty float y\nproperty float z\nend_header\n")
}

#[test]
fn ply_counts_beyond_the_file_are_refused_before_allocating() {
    let dir = tempfile::tempdir().expect("tmp");
    for n in [
        "1000000000000",
        "1000000000000000000",
        "18446744073709551615",
    ] {
        let mut bytes = ply_header(n).into_bytes();
        bytes.extend_from_slice(&[0u8; 24]);
        let p = write(dir.path(), "big.ply", &bytes);
        let err = PointCloud::read_ply(&p).expect_err(n).to_string();
        assert!(
            err.contains("big.ply") && err.contains("truncated"),
            "{err}"
        );
    }
    let ascii = "ply\nformat ascii 1.0\nelement vertex 1000000000000\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n";
    let p = write(dir.path(), "big_ascii.ply", ascii.as_bytes());
    assert!(PointCloud::read_ply(&p).is_err());
}

#[test]
fn non_finite_points_are_dropped_and_counted() {
    let dir = tempfile::tempdir().expect("tmp");
    let text = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\nnan 0 0\n4 inf 6\n7 8 9\n";
    let p = write(dir.path(), "nan.ply", text.as_bytes());
    let c = PointCloud::read_ply(&p).expect("read");
    assert_eq!(c.points, vec![[1.0, 2.0, 3.0], [7.0, 8.0, 9.0]]);
    assert_eq!(c.confidence.len(), 2);
    let mut c = PointCloud {
        points: vec![[1.0, 0.0, 0.0], [f32::NAN, 0.0, 0.0]],
        confidence: vec![0.5, 0.7],
        pixels: vec![3, 4],
        image: Some([4, 2]),
        outside: vec![],
        scalars: vec![],
    };
    assert_eq!(c.retain_finite(), 1);
    assert_eq!(
        (c.confidence.as_slice(), c.pixels.as_slice()),
        (&[0.5f32][..], &[3u32][..])
    );
}

fn binary_stl(tris: &[[[f32; 3]; 3]]) -> Vec<u8> {
    let mut b = vec![0u8; 80];
    b.extend_from_slice(&(tris.len() as u32).to_le_bytes());
    for t in tris {
        b.extend_from_slice(&[0u8; 12]);
        for v in t {
            for c in v {
                b.extend_from_slice(&c.to_le_bytes());
            }
        }
        b.extend_from_slice(&[0, 0]);
    }
    b
}

#[test]
fn degenerate_cad_is_refused_and_degenerate_triangles_dropped() {
    let dir = tempfile::tempdir().expect("tmp");
    let same = [[1.0, 2.0, 3.0]; 3];
    let collinear = [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [2.0, 2.0, 2.0]];
    let good = [[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [0.0, 10.0, 0.0]];
    for (name, tris) in [
        ("same.stl", vec![same]),
        ("line.stl", vec![collinear, same]),
    ] {
        let p = write(dir.path(), name, &binary_stl(&tris));
        let err = TriangleMesh::load(&p).expect_err(name).to_string();
        assert!(
            err.contains(name) && err.contains("no usable triangle"),
            "{err}"
        );
    }
    let p = write(
        dir.path(),
        "mixed.stl",
        &binary_stl(&[good, same, collinear]),
    );
    let mesh = TriangleMesh::load(&p).expect("mixed");
    assert_eq!(mesh.triangles.len(), 1);
    // An empty mesh (built in code) answers no closest point instead of panicking.
    let empty = SignedDistance::new(TriangleMesh::default());
    assert!(empty.query(&[0.0, 0.0, 0.0].into()).is_none());
    assert!(SignedDistance::new(mesh)
        .query(&[f64::NAN, 0.0, 0.0].into())
        .is_none());
}

#[test]
fn kd_tree_answers_nan_queries_with_nothing() {
    let tree = KdTree::new(&[[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]);
    assert!(tree.nearest(&[f64::NAN, 0.0, 0.0]).is_none());
    assert!(tree.nearest(&[0.9, 0.9, 0.9]).is_some_and(|(i, _)| i == 1));
}

#[test]
fn huge_sensor_images_are_refused() {
    let dir = tempfile::tempdir().expect("tmp");
    for (w, h) in [(4_000_000_000u64, 4_000_000_000u64), (100_000, 100_000)] {
        let text = format!(
            "[camera]\nwidth = {w}\nheight = {h}\nk = [[1000.0, 0.0, 400.0], [0.0, 1000.0, 300.0], [0.0, 0.0, 1.0]]\ndist = [0.0, 0.0, 0.0, 0.0, 0.0]\nr = [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]\nt = [0.0, 0.0, 1000.0]\n[projector]\nwidth = 1024\nheight = 768\ncenter = [200.0, 0.0, 1000.0]\n"
        );
        let p = write(dir.path(), "s.toml", text.as_bytes());
        let Err(err) = Sensor::load(&p) else {
            panic!("a {w} x {h} camera must be refused")
        };
        let err = err.to_string();
        assert!(err.contains("s.toml") && err.contains("camera"), "{err}");
    }
}

fn sheet() -> SignedDistance {
    SignedDistance::new(TriangleMesh::height_field(
        20,
        20,
        (-100.0, 100.0),
        (-100.0, 100.0),
        |x, y| 0.001 * (x * x - y * y),
    ))
}

fn grid(step: f64, dx: f64, z: f64) -> Vec<[f64; 3]> {
    let mut v = Vec::new();
    let mut y = -95.0;
    while y <= 95.0 {
        let mut x = -95.0;
        while x <= 95.0 {
            v.push([x + dx, y, 0.001 * (x * x - y * y) + z]);
            x += step;
        }
        y += step;
    }
    v
}

#[test]
fn a_cad_that_the_cloud_does_not_overlap_is_not_measured() {
    let cad = sheet();
    let params = InspectParams {
        init: Some(ris_core::register::Pose::identity()),
        ..InspectParams::default()
    };
    // The part is measured: pass with full coverage.
    let on = inspect(&grid(2.0, 0.0, 0.0), &cad, &params).expect("inspect");
    assert_eq!(on.report.verdict, "pass", "{:?}", on.report.reasons);
    assert!(
        on.report.coverage.fraction > 0.95,
        "{:?}",
        on.report.coverage
    );
    // The CAD 100 m away: nothing of it was measured.
    let far: Vec<[f64; 3]> = grid(2.0, 0.0, 0.0)
        .into_iter()
        .map(|p| [p[0] + 100_000.0, p[1], p[2]])
        .collect();
    let r = inspect(&far, &cad, &params).expect("inspect");
    assert_eq!(r.report.verdict, NOT_MEASURED, "{:?}", r.report.reasons);
    assert!(
        r.report.reasons[0].contains("measured"),
        "{:?}",
        r.report.reasons
    );
    // A third of the part seen: below the 50 % minimum, not measured; with a lower minimum,
    // a verdict.
    let third: Vec<[f64; 3]> = grid(2.0, 0.0, 0.0)
        .into_iter()
        .filter(|p| p[0] < -35.0)
        .collect();
    let r = inspect(&third, &cad, &params).expect("inspect");
    assert_eq!(r.report.verdict, NOT_MEASURED);
    assert!(
        (r.report.coverage.fraction - 0.32).abs() < 0.06,
        "{:?}",
        r.report.coverage
    );
    let r = inspect(
        &third,
        &cad,
        &InspectParams {
            min_coverage: 0.2,
            ..params.clone()
        },
    )
    .expect("inspect");
    assert_eq!(r.report.verdict, "pass");
    // NaN points are left out and counted; the rest is inspected.
    let mut with_nan = grid(2.0, 0.0, 0.0);
    with_nan[5] = [f64::NAN, 0.0, 0.0];
    with_nan[9] = [0.0, f64::INFINITY, 0.0];
    let r = inspect(
        &with_nan,
        &cad,
        &InspectParams {
            init: None,
            ..params
        },
    )
    .expect("inspect");
    assert_eq!(r.report.statistics.non_finite, 2);
    assert_eq!(r.report.verdict, "pass", "{:?}", r.report.reasons);
    // A shallow saddle pins its in-plane position only weakly (a shift is a tilt to first
    // order), and the report says so.
    assert!(
        r.report
            .warnings
            .iter()
            .any(|w| w.contains("weakly pinned")),
        "{:?}",
        r.report.warnings
    );
}

proptest! {
    #![proptest_config(ProptestConfig { failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn ply_reader_never_panics(header_n in 0u64..u64::MAX, body in proptest::collection::vec(any::<u8>(), 0..256), ascii in any::<bool>()) {
        let dir = tempfile::tempdir().expect("tmp");
        let mut bytes = if ascii {
            format!("ply\nformat ascii 1.0\nelement vertex {header_n}\nproperty double x\nproperty double y\nproperty double z\nproperty float confidence\nend_header\n").into_bytes()
        } else {
            ply_header(&header_n.to_string()).into_bytes()
        };
        bytes.extend_from_slice(&body);
        let p = write(dir.path(), "f.ply", &bytes);
        if let Ok(c) = PointCloud::read_ply(&p) {
            prop_assert!(c.points.iter().all(|p| p.iter().all(|v| v.is_finite())));
            prop_assert!(c.len() as u64 <= header_n);
        }
    }

    #[test]
    fn ply_reader_survives_mutated_files(flips in proptest::collection::vec((0usize..200, any::<u8>()), 1..8)) {
        let dir = tempfile::tempdir().expect("tmp");
        let mut bytes = ply_header("4").into_bytes();
        for k in 0..12u32 {
            bytes.extend_from_slice(&(k as f32).to_le_bytes());
        }
        for (at, b) in flips {
            let i = at % bytes.len();
            bytes[i] = b;
        }
        let p = write(dir.path(), "m.ply", &bytes);
        let _ = PointCloud::read_ply(&p);
    }

    #[test]
    fn stl_reader_never_panics(count in 0u32..u32::MAX, body in proptest::collection::vec(any::<u8>(), 0..400)) {
        let dir = tempfile::tempdir().expect("tmp");
        let mut bytes = vec![0u8; 80];
        bytes.extend_from_slice(&count.to_le_bytes());
        bytes.extend_from_slice(&body);
        let p = write(dir.path(), "f.stl", &bytes);
        if let Ok(m) = TriangleMesh::load(&p) {
            prop_assert!(!m.triangles.is_empty());
            let sd = SignedDistance::new(m);
            let _ = sd.query(&[0.0, 0.0, 0.0].into());
        }
    }

    #[test]
    fn ascii_stl_reader_never_panics(words in proptest::collection::vec(prop_oneof![Just("vertex".to_string()), Just("facet".to_string()), Just("nan".to_string()), Just("1e400".to_string()), any::<f32>().prop_map(|f| f.to_string())], 0..60)) {
        let dir = tempfile::tempdir().expect("tmp");
        let text = format!("solid x\n{}\nendsolid x\n", words.join(" "));
        let p = write(dir.path(), "a.stl", text.as_bytes());
        let _ = TriangleMesh::load(&p);
    }

    #[test]
    fn npy_reader_never_panics(shape in proptest::collection::vec(0usize..usize::MAX, 0..4), body in proptest::collection::vec(any::<u8>(), 0..128)) {
        let dir = tempfile::tempdir().expect("tmp");
        let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
        let header = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': ({},), }}", dims.join(", "));
        let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
        bytes.extend_from_slice(&(header.len() as u16).to_le_bytes());
        bytes.extend_from_slice(header.as_bytes());
        bytes.extend_from_slice(&body);
        let p = write(dir.path(), "f.npy", &bytes);
        if let Ok((shape, data)) = ris_core::io::npy::read::<f32>(&p) {
            prop_assert_eq!(shape.iter().product::<usize>(), data.len());
        }
    }

    #[test]
    fn image_reader_never_panics(body in proptest::collection::vec(any::<u8>(), 0..300), png in any::<bool>()) {
        let dir = tempfile::tempdir().expect("tmp");
        let mut bytes = if png { b"\x89PNG\r\n\x1a\n".to_vec() } else { Vec::new() };
        bytes.extend_from_slice(&body);
        let p = write(dir.path(), "f.png", &bytes);
        let _ = ris_core::image::GrayImage::load(&p);
    }

    #[test]
    fn capture_manifest_never_panics(pw in any::<u32>(), ph in any::<u32>(), cw in any::<u32>(), ch in any::<u32>(), step in any::<u32>()) {
        let dir = tempfile::tempdir().expect("tmp");
        let manifest = format!("[projector]\nwidth = {pw}\nheight = {ph}\ncolumn_step = {step}\nrow_step = 1\n[camera]\nwidth = {cw}\nheight = {ch}\n");
        write(dir.path(), "capture.toml", manifest.as_bytes());
        let img = ris_core::image::GrayImage::from_u8(4, 3, vec![200; 12]);
        for name in ["white", "black", "gray_col_00"] {
            img.save_png(&dir.path().join(format!("{name}.png"))).expect("png");
        }
        let _ = ris_core::capture::CaptureSet::load(dir.path());
    }

    #[test]
    fn sensor_file_reader_never_panics(flips in proptest::collection::vec((0usize..400, 32u8..127), 1..6)) {
        let dir = tempfile::tempdir().expect("tmp");
        let mut text = "[camera]\nwidth = 800\nheight = 600\nk = [[1000.0, 0.0, 400.0], [0.0, 1000.0, 300.0], [0.0, 0.0, 1.0]]\ndist = [0.0, 0.0, 0.0, 0.0, 0.0]\nr = [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]\nt = [0.0, 0.0, 1000.0]\n[projector]\nwidth = 1024\nheight = 768\ncenter = [200.0, 0.0, 1000.0]\n".as_bytes().to_vec();
        for (at, b) in flips {
            let i = at % text.len();
            text[i] = b;
        }
        let p = write(dir.path(), "s.toml", &text);
        let _ = Sensor::load(&p);
    }
}
