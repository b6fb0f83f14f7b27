//! Reconstruction throughput (points per second) of the parallax and classical models on a
#![allow(missing_docs)] // criterion_group! generates an undocumented public function
//! decoded 2048x2048 capture.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use ris_core::decode::{decode, DecodeParams};
use ris_core::sensor::Reconstructor;

mod common;

fn bench(c: &mut Criterion) {
    let (scene, capture, reference) = common::captures_2k();
    let params = DecodeParams::default();
    let decoded = decode(&capture, &params).expect("decode");
    let dec_ref = decode(&reference, &params).expect("decode reference");
    let parallax =
        Reconstructor::parallax(&scene.camera, scene.projector.center(), &dec_ref).expect("model");
    let classical = Reconstructor::classical(&scene.camera, &scene.projector);
    let points = parallax.reconstruct(&decoded).expect("points").len() as u64;
    let mut g = c.benchmark_group("reconstruct");
    g.sample_size(20);
    g.throughput(Throughput::Elements(points));
    g.bench_function("parallax_2048x2048", |b| {
        b.iter(|| parallax.reconstruct(&decoded).expect("reconstruct"))
    });
    g.bench_function("classical_2048x2048", |b| {
        b.iter(|| classical.reconstruct(&decoded).expect("reconstruct"))
    });
    g.finish();
    let mut g = c.benchmark_group("prepare");
    g.sample_size(10);
    g.bench_function("parallax_reference_fit_2048x2048", |b| {
        b.iter(|| {
            Reconstructor::parallax(&scene.camera, scene.projector.center(), &dec_ref)
                .expect("model")
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
