//! Verification speed: a full VDI/VDE 2634-2 acceptance set (7 ball-bar, 6 flat and 10 sphere
//! clouds, each with its table, post and clutter) found, fitted and evaluated.
#![allow(missing_docs)] // criterion_group! generates an undocumented public function

use criterion::{criterion_group, criterion_main, Criterion};
use ris_core::verify::synthetic::{acceptance_set, artefacts};
use ris_core::verify::{evaluate, VerifyParams};

fn bench(c: &mut Criterion) {
    let a = artefacts();
    let (bars, planes, spheres) = acceptance_set(2634, 0.008, 1.0);
    let points: usize = bars
        .iter()
        .chain(&planes)
        .chain(&spheres)
        .map(|c| c.points.len())
        .sum();
    eprintln!("acceptance set: 23 clouds, {points} points");
    let mut g = c.benchmark_group("verify");
    g.sample_size(10);
    g.bench_function("acceptance_set_23_clouds", |b| {
        b.iter(|| {
            evaluate(
                &a,
                &bars,
                &planes,
                &spheres,
                &VerifyParams::default(),
                String::new(),
            )
            .expect("evaluate")
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
