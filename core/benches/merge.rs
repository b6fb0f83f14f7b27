//! Merging four 2 MP sensor clouds (1.6 M points each, overlapping quarters of a 1100 × 800 mm
//! curved panel, 0.4 mm pitch) into the cell frame with duplicate removal.
#![allow(missing_docs)] // criterion_group! generates an undocumented public function

use criterion::{criterion_group, criterion_main, Criterion};
use ris_core::cloud::{Merger, PointCloud};
use ris_core::geometry::Matrix4;

#[path = "../tests/common/mod.rs"]
mod common;
use common::Rng;

/// One sensor's quarter: a 1600 × 1000 grid over [x0, x0 + 640) × [y0, y0 + 400) mm in the
/// cell frame, stored in a sensor frame shifted by `shift` (mm) and jittered a little.
fn quarter(x0: f64, y0: f64, shift: [f64; 3], seed: u64) -> (PointCloud, Matrix4<f64>) {
    let mut rng = Rng(seed);
    let mut u = move || rng.uniform();
    let mut c = PointCloud::default();
    for j in 0..1000 {
        for i in 0..1600 {
            let (x, y) = (x0 + 0.4 * f64::from(i), y0 + 0.4 * f64::from(j));
            let z = -(0.0004 * x * x + 0.00025 * y * y) / 2.0 + 0.05 * (u() - 0.5);
            c.points.push([
                (x - shift[0]) as f32,
                (y - shift[1]) as f32,
                (z - shift[2]) as f32,
            ]);
            c.confidence.push(u() as f32);
        }
    }
    let mut m = Matrix4::identity();
    for k in 0..3 {
        m[(k, 3)] = shift[k];
    }
    (c, m)
}

fn bench(c: &mut Criterion) {
    let clouds = [
        quarter(-560.0, -410.0, [-260.0, -180.0, -110.0], 1),
        quarter(-80.0, -410.0, [260.0, -180.0, -120.0], 2),
        quarter(-560.0, 10.0, [-260.0, 180.0, -130.0], 3),
        quarter(-80.0, 10.0, [260.0, 180.0, -140.0], 4),
    ];
    let mut g = c.benchmark_group("merge");
    g.sample_size(10);
    g.bench_function("four_2mp_sensor_clouds", |b| {
        b.iter(|| {
            let mut merger = Merger::new(0.5);
            for (cloud, m) in &clouds {
                merger.add(cloud, m);
            }
            merger.finish().0.len()
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
