//! Inspection of the mock cell's part: 1.2 M points on the 4 400-triangle panel CAD, registered
//! from the cell frame (a small misalignment to remove) with trusted regions, as risd does after
//! every scan (issue 14's target: ≤ 1.0 s); and `ris inspect`'s case, a 200 k-point cloud in an
//! unknown pose against a 483 k-triangle CAD.
#![allow(missing_docs)] // criterion_group! generates an undocumented public function

use std::path::Path;

use criterion::{criterion_group, criterion_main, Criterion};
use ris_core::inspect::{inspect, InspectParams};
use ris_core::mesh::{SignedDistance, TriangleMesh};
use ris_core::register::Pose;

#[path = "../tests/common/mod.rs"]
mod common;
use common::panel_cloud;

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
