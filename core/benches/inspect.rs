//! Inspection of the mock cell's part: 1.2 M points on the 4 400-triangle panel CAD, registered
//! from the cell frame (a small misalignment to remove) with trusted regions, as risd does after
//! every scan (issue 14's target: ≤ 1.0 s); and `ris inspect`'s case, a 200 k-point cloud in an
//! unknown pose against a 483 k-triangle CAD.
#![allow(missing_docs)] // criterion_group! generates an undocumented public function

use std::path::Path;

use criterion::{criterion_group, criterion_main, Criterion};
use nalgebra::{Point3, UnitQuaternion, Vector3};
use ris_core::inspect::{inspect, InspectParams};
use ris_core::mesh::{SignedDistance, TriangleMesh};
use ris_core::register::Pose;

#[path = "../tests/common/mod.rs"]
mod common;
use common::Rng;

/// `n` points in rows on the mock cell's panel (z = −(x²/5000 + y²/8000)) over the CAD's extent, with
/// 0.05 mm of noise, moved off the nominal pose by 0.3 mm and 0.02°.
fn panel_cloud(mesh: &TriangleMesh, n: usize) -> Vec<[f64; 3]> {
    let (mut lo, mut hi) = ([f64::MAX; 2], [f64::MIN; 2]);
    for v in &mesh.vertices {
        for k in 0..2 {
            lo[k] = lo[k].min(v[k]);
            hi[k] = hi[k].max(v[k]);
        }
    }
    let mut rng = Rng(11u64);
    let mut u = move || rng.uniform();
    let off = Pose::from_parts(
        Vector3::new(0.3, -0.2, 0.1).into(),
        UnitQuaternion::from_scaled_axis(Vector3::new(0.0002, -0.0003, 0.0001)),
    );
    // A raster like a camera's rows (merged clouds keep each sensor's scan order), jittered.
    let (w, h) = (hi[0] - lo[0] - 4.0, hi[1] - lo[1] - 4.0);
    let cols = ((n as f64 * w / h).sqrt().ceil() as usize).max(1);
    (0..n)
        .map(|k| {
            let (i, j) = (k % cols, k / cols);
            let rows = n.div_ceil(cols);
            let x = lo[0] + 2.0 + w * (i as f64 + u()) / cols as f64;
            let y = lo[1] + 2.0 + h * (j as f64 + u()) / rows as f64;
            // Sum of 4 uniforms: near-Gaussian, σ ≈ 0.05 mm.
            let noise = 0.05 * 1.732 * (u() + u() + u() + u() - 2.0);
            let z = -(x * x / 5000.0 + y * y / 8000.0) + noise;
            (off * Point3::new(x, y, z)).coords.into()
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let stl = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/mock-cell/panel.stl");
    let mesh = TriangleMesh::load(&stl).expect("panel.stl");
    let cloud = panel_cloud(&mesh, 1_200_000);
    let cad = SignedDistance::new(mesh);
    let params = InspectParams {
        tolerance: 0.5,
        init: Some(Pose::identity()),
        ..InspectParams::default()
    };
    let mut g = c.benchmark_group("inspect");
    g.sample_size(10);
    g.bench_function("mock_cell_1.2M_points", |b| {
        b.iter(|| inspect(&cloud, &cad, &params).expect("inspection"))
    });
    // `ris inspect`'s case: no initial pose (coarse alignment first), 200 k points against a
    // finely triangulated CAD (483 k triangles over 1000 × 800 mm).
    let fine = TriangleMesh::height_field(491, 491, (-500.0, 500.0), (-400.0, 400.0), |x, y| {
        -(x * x / 5000.0 + y * y / 8000.0)
    });
    let cloud = panel_cloud(&fine, 200_000);
    let cad = SignedDistance::new(fine);
    let params = InspectParams {
        tolerance: 0.5,
        ..InspectParams::default()
    };
    g.bench_function("200k_points_483k_triangles_unknown_pose", |b| {
        b.iter(|| inspect(&cloud, &cad, &params).expect("inspection"))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
