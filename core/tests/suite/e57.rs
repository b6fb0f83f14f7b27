//! Clouds as E57: written and read back with the same points, confidences and volume flags;
//! what another reader (the `e57` crate's own simple reader) sees is in metres, as the
//! standard says; a file that is not E57 is refused with its name.

use ris_core::cloud::PointCloud;

use crate::common;
use common::Rng;

#[test]
fn clouds_round_trip_through_e57_in_metres() {
    let dir = tempfile::tempdir().expect("tmp");
    for (seed, flagged) in [(1u64, false), (2, true)] {
        let mut r = Rng(seed);
        let n = 5_000 + (r.range(0.0, 5_000.0) as usize);
        let mut cloud = PointCloud::default();
        for _ in 0..n {
            cloud.points.push([
                r.range(-900.0, 900.0) as f32,
                r.range(-700.0, 700.0) as f32,
                r.range(-50.0, 1600.0) as f32,
            ]);
            cloud.confidence.push(r.range(0.0, 1.0) as f32);
            if flagged {
                cloud.outside.push(r.range(0.0, 1.0) < 0.1);
            }
        }
        let path = dir.path().join(format!("cloud{seed}.e57"));
        cloud.write_e57(&path).expect("write");
        let back = PointCloud::read_e57(&path).expect("read");
        assert_eq!(back.len(), n);
        for (a, b) in cloud.points.iter().zip(&back.points) {
            for k in 0..3 {
                assert!(
                    (a[k] - b[k]).abs() <= 1e-4 * a[k].abs().max(1.0),
                    "{a:?} {b:?}"
                );
            }
        }
        assert_eq!(back.confidence, cloud.confidence);
        assert_eq!(back.outside, cloud.outside);

        // Another reader: the crate's simple iterator, which knows nothing of RIS.
        let mut e = e57::E57Reader::from_file(&path).expect("e57 reader");
        let pcs = e.pointclouds();
        assert_eq!(pcs.len(), 1);
        assert_eq!(pcs[0].records, n as u64);
        let first = e
            .pointcloud_simple(&pcs[0])
            .expect("simple")
            .next()
            .expect("a point")
            .expect("valid");
        let e57::CartesianCoordinate::Valid { x, y, z } = first.cartesian else {
            panic!("{:?}", first.cartesian);
        };
        let p = cloud.points[0];
        for (m, mm) in [(x, p[0]), (y, p[1]), (z, p[2])] {
            assert!(
                (m * 1000.0 - f64::from(mm)).abs() < 1e-3,
                "{m} m vs {mm} mm"
            );
        }
    }
    let ply = dir.path().join("not.e57");
    std::fs::write(&ply, b"ply\nformat ascii 1.0\nend_header\n").expect("w");
    let err = PointCloud::read_e57(&ply).expect_err("refused").to_string();
    assert!(err.contains("not.e57") && err.contains("E57"), "{err}");
}

#[test]
fn deviations_and_intensities_go_through_ply_and_e57() {
    let dir = tempfile::tempdir().expect("tmp");
    let mut r = Rng(21);
    let n = 3_000;
    let points: Vec<[f64; 3]> = (0..n)
        .map(|_| {
            [
                r.range(-500.0, 500.0),
                r.range(-400.0, 400.0),
                r.range(0.0, 60.0),
            ]
        })
        .collect();
    let devs: Vec<f64> = (0..n).map(|_| r.range(-0.8, 0.8)).collect();
    // The inspection's own deviation cloud keeps its deviations through E57 and back.
    let ply = dir.path().join("deviation.ply");
    ris_core::inspect::write_deviation_ply(&ply, &points, &devs).expect("deviation.ply");
    let cloud = PointCloud::read_ply(&ply).expect("read");
    assert_eq!(cloud.scalars.len(), 1);
    assert_eq!(cloud.scalars[0].name, "deviation");
    for (a, b) in cloud.scalars[0].values.iter().zip(&devs) {
        assert_eq!(*a, *b as f32);
    }
    let e57 = dir.path().join("deviation.e57");
    cloud.write_e57(&e57).expect("e57");
    let back = PointCloud::read_e57(&e57).expect("read e57");
    assert_eq!(back.scalars, cloud.scalars);
    let again = dir.path().join("again.ply");
    back.write_ply(&again).expect("ply");
    assert_eq!(
        PointCloud::read_ply(&again).expect("read").scalars,
        cloud.scalars
    );

    // An intensity (uchar in a PLY made elsewhere) becomes the standard's intensity, which a
    // reader that knows nothing of RIS sees.
    let mut text = format!(
        "ply\nformat ascii 1.0\nelement vertex {n}\nproperty double x\nproperty double y\nproperty double z\nproperty uchar intensity\nend_header\n"
    );
    for (i, p) in points.iter().enumerate() {
        text += &format!("{} {} {} {}\n", p[0], p[1], p[2], i % 256);
    }
    let ply = dir.path().join("grey.ply");
    std::fs::write(&ply, text).expect("w");
    let cloud = PointCloud::read_ply(&ply).expect("read");
    let e57 = dir.path().join("grey.e57");
    cloud.write_e57(&e57).expect("e57");
    let mut e = e57::E57Reader::from_file(&e57).expect("e57 reader");
    let pcs = e.pointclouds();
    let seen: Vec<f32> = e
        .pointcloud_simple(&pcs[0])
        .expect("simple")
        .map(|p| p.expect("point").intensity.expect("an intensity"))
        .collect();
    assert_eq!(seen.len(), n);
    // The simple reader normalises intensity to 0 … 1 over the cloud's intensity limits.
    for (i, v) in seen.iter().enumerate() {
        let want = (i % 256) as f32 / 255.0;
        assert!((v - want).abs() < 1e-5, "point {i}: {v} vs {want}");
    }
    let back = PointCloud::read_e57(&e57).expect("read");
    assert_eq!(back.scalars, cloud.scalars);

    // A name E57 cannot hold is refused with the file's name.
    let mut odd = cloud.clone();
    odd.scalars[0].name = "9 lives".into();
    let err = odd
        .write_e57(&dir.path().join("odd.e57"))
        .expect_err("refused")
        .to_string();
    assert!(err.contains("odd.e57") && err.contains("9 lives"), "{err}");
}
