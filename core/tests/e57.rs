//! Clouds as E57: written and read back with the same points, confidences and volume flags;
//! what another reader (the `e57` crate's own simple reader) sees is in metres, as the
//! standard says; a file that is not E57 is refused with its name.

use ris_core::cloud::PointCloud;

mod common;
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
