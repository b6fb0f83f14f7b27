//! Single-shot speed: generating the X-point code and primitives of a 1920x1080 projector at a
//! 14 px step, and rendering its 8-bit image.
#![allow(missing_docs)] // criterion_group! generates an undocumented public function

use criterion::{criterion_group, criterion_main, Criterion};
use ris_core::single_shot::XPointPattern;

fn pattern(c: &mut Criterion) {
    let mut g = c.benchmark_group("single_shot");
    g.sample_size(20);
    g.bench_function("xpoint_generate_1920x1080", |b| {
        b.iter(|| XPointPattern::generate(1920, 1080, [14, 14], 3, 7).expect("pattern"))
    });
    let p = XPointPattern::generate(1920, 1080, [14, 14], 3, 7).expect("pattern");
    g.bench_function("xpoint_render_1920x1080", |b| b.iter(|| p.render()));
    g.finish();
}

criterion_group!(benches, pattern);
criterion_main!(benches);
