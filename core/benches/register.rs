//! Registration speed: point-to-plane ICP of 200 k vs 200 k points, normals included.
#![allow(missing_docs)] // criterion_group! generates an undocumented public function

use criterion::{criterion_group, criterion_main, Criterion};
use nalgebra::{Point3, Vector3};
use ris_core::register::{Icp, IcpMetric, IcpParams, Pose};

#[path = "../tests/common/mod.rs"]
mod common;
use common::Rng;

fn panel(n: usize, x0: f64, x1: f64, seed: u64) -> Vec<[f64; 3]> {
    let mut rng = Rng(seed);
    let mut u = move || rng.uniform();
    (0..n)
        .map(|_| {
            let (x, y) = (x0 + (x1 - x0) * u(), -200.0 + 400.0 * u());
            [
                x,
                y,
                40.0 * (x / 150.0).sin() * (y / 120.0).cos() + 0.0003 * x * x + 0.03 * (u() - 0.5),
            ]
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let fixed = panel(200_000, -250.0, 150.0, 1);
    let truth = Pose::new(
        Vector3::new(3.0, -2.0, 1.0),
        Vector3::new(0.01, -0.015, 0.02),
    );
    let moving: Vec<[f64; 3]> = panel(200_000, -150.0, 250.0, 2)
        .iter()
        .map(|p| (truth.inverse() * Point3::from(*p)).coords.into())
        .collect();
    let params = IcpParams {
        trim: 0.7,
        ..IcpParams::default()
    };
    let mut g = c.benchmark_group("icp");
    g.sample_size(10);
    g.bench_function("point_to_plane_200k_vs_200k_with_normals", |b| {
        b.iter(|| {
            let icp = Icp::new(&fixed, IcpMetric::PointToPlane, 12);
            icp.align(&moving, Pose::identity(), &params)
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
