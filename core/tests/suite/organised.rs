//! Organised clouds: a cloud from one camera keeps each point's camera pixel through PLY and
//! E57 (row, column and the image size), for seeded image sizes, fills and volume flags;
//! another E57 reader sees the standard row/column indices; a PLY whose row/column leave the
//! stated image is refused with its name.

use ris_core::cloud::PointCloud;

use crate::common;
use common::Rng;

/// A dense per-pixel buffer of `w` x `h` with about `fill` of the pixels measured.
fn organised(r: &mut Rng, w: u32, h: u32, fill: f64) -> PointCloud {
    let n = (w * h) as usize;
    let mut dense = vec![[f32::NAN; 3]; n];
    let mut conf = vec![0f32; n];
    for (i, (p, c)) in dense.iter_mut().zip(conf.iter_mut()).enumerate() {
        if r.range(0.0, 1.0) < fill {
            let (u, v) = ((i as u32 % w) as f32, (i as u32 / w) as f32);
            *p = [u * 0.5 - 300.0, v * 0.5 - 200.0, r.range(0.0, 80.0) as f32];
            *c = r.range(0.0, 1.0) as f32;
        }
    }
    PointCloud::from_dense(&dense, &conf, w)
}

#[test]
fn organised_clouds_keep_their_pixels_through_ply_and_e57() {
    let dir = tempfile::tempdir().expect("tmp");
    for seed in 1..=6u64 {
        let mut r = Rng(seed);
        let w = r.range(17.0, 400.0) as u32;
        let h = r.range(9.0, 300.0) as u32;
        let fill = r.range(0.05, 0.95);
        let mut cloud = organised(&mut r, w, h, fill);
        if seed % 2 == 0 {
            cloud.outside = (0..cloud.len()).map(|_| r.range(0.0, 1.0) < 0.2).collect();
        }
        assert_eq!(cloud.organised(), Some([w, h]), "seed {seed}");
        for i in [0, cloud.len() / 2, cloud.len() - 1] {
            let (row, col) = cloud.row_column(i).expect("organised");
            let p = cloud.points[i];
            // The synthetic point encodes its own pixel.
            assert_eq!(
                (p[0] + 300.0) * 2.0,
                col as f32,
                "seed {seed}: column of point {i}"
            );
            assert_eq!((p[1] + 200.0) * 2.0, row as f32, "seed {seed}: row");
        }

        let ply = dir.path().join(format!("s{seed}.ply"));
        cloud.write_ply(&ply).expect("ply");
        let back = PointCloud::read_ply(&ply).expect("read ply");
        assert_eq!(back, cloud, "seed {seed}: PLY round trip");

        let e57 = dir.path().join(format!("s{seed}.e57"));
        cloud.write_e57(&e57).expect("e57");
        let back = PointCloud::read_e57(&e57).expect("read e57");
        assert_eq!(back.image, Some([w, h]), "seed {seed}: E57 image size");
        assert_eq!(back.pixels, cloud.pixels, "seed {seed}: E57 pixels");
        assert_eq!(back.outside, cloud.outside);

        // Another reader sees the standard row and column indices and their bounds.
        let mut e = e57::E57Reader::from_file(&e57).expect("e57 reader");
        let pcs = e.pointclouds();
        let bounds = pcs[0].index_bounds.clone().expect("index bounds");
        assert_eq!(
            (bounds.row_max, bounds.column_max),
            (Some(i64::from(h) - 1), Some(i64::from(w) - 1))
        );
        let last = e
            .pointcloud_simple(&pcs[0])
            .expect("simple")
            .last()
            .expect("a point")
            .expect("valid");
        let (row, col) = cloud.row_column(cloud.len() - 1).expect("pixel");
        assert_eq!(
            (last.row, last.column),
            (i64::from(row), i64::from(col)),
            "seed {seed}"
        );
    }
}

#[test]
fn merged_clouds_are_not_organised_and_bad_indices_are_refused() {
    let mut r = Rng(9);
    let cloud = organised(&mut r, 40, 30, 0.5);
    let (merged, _) = ris_core::cloud::merge(&[(cloud, nalgebra::Matrix4::identity())], 0.1);
    assert_eq!(merged.organised(), None);
    assert!(merged.pixels.is_empty());

    let dir = tempfile::tempdir().expect("tmp");
    let head = "ply\nformat ascii 1.0\nobj_info num_cols 4\nobj_info num_rows 3\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nproperty uint row\nproperty uint column\nend_header\n";
    let good = dir.path().join("good.ply");
    std::fs::write(&good, format!("{head}1 2 3 0 1\n4 5 6 2 3\n")).expect("w");
    let c = PointCloud::read_ply(&good).expect("read");
    assert_eq!((c.image, c.pixels.clone()), (Some([4, 3]), vec![1, 11]));
    assert_eq!(c.row_column(1), Some((2, 3)));

    let bad = dir.path().join("outside.ply");
    std::fs::write(&bad, format!("{head}1 2 3 0 1\n4 5 6 3 0\n")).expect("w");
    let err = PointCloud::read_ply(&bad).expect_err("refused").to_string();
    assert!(
        err.contains("outside.ply") && err.contains("4 x 3"),
        "{err}"
    );

    // Without the stated size, the smallest image that holds the indices.
    let bare = dir.path().join("bare.ply");
    std::fs::write(
        &bare,
        "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nproperty int row\nproperty int column\nend_header\n1 2 3 0 1\n4 5 6 5 2\n",
    )
    .expect("w");
    let c = PointCloud::read_ply(&bare).expect("read");
    assert_eq!(c.image, Some([3, 6]));
    assert_eq!(c.row_column(1), Some((5, 2)));
    std::fs::write(
        &bare,
        "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nproperty int row\nproperty int column\nend_header\n1 2 3 -1 2\n",
    )
    .expect("w");
    let err = PointCloud::read_ply(&bare)
        .expect_err("negative")
        .to_string();
    assert!(err.contains("bare.ply") && err.contains("row -1"), "{err}");
}
