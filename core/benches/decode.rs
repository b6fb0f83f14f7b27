//! Decoding speed: a 2048x2048 capture of a 1024x768 projector (42 frames) to sub-pixel maps.
#![allow(missing_docs)] // criterion_group! generates an undocumented public function

use criterion::{criterion_group, criterion_main, Criterion};
use ris_core::decode::{decode, DecodeParams};

mod common;

fn bench(c: &mut Criterion) {
    let (_, capture, _) = common::captures_2k();
    assert_eq!(capture.frames.len(), 42);
    let params = DecodeParams::default();
    let mut g = c.benchmark_group("decode");
    g.sample_size(20);
    g.bench_function("2048x2048_42_frames", |b| {
        b.iter(|| decode(&capture, &params).expect("decode"))
    });
    // The same without the curvature correction of the line fit, for its cost.
    let straight = DecodeParams {
        bend_correction: false,
        ..params
    };
    g.bench_function("2048x2048_42_frames_without_bend_correction", |b| {
        b.iter(|| decode(&capture, &straight).expect("decode"))
    });
    // The same without the crossing's phase bias measured and removed, for its cost.
    let locked = DecodeParams {
        phase_correction: false,
        ..params
    };
    g.bench_function("2048x2048_42_frames_without_phase_correction", |b| {
        b.iter(|| decode(&capture, &locked).expect("decode"))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
