//! Single-shot speed: generating the X-point code and primitives of a 1920x1080 projector at a
//! 14 px step, and rendering its 8-bit image; detecting and decoding the X-points of one
//! 1200x900 (1.08 MP) camera frame of the demo scene (pattern at 14 px, reference prediction).
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

fn frame(c: &mut Criterion) {
    use ris_core::pattern::{Pattern, ProjectionMask};
    use ris_core::sim::{Scene, SceneFile, Simulator};
    use ris_core::single_shot::{decode, detect, DetectParams};
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/scenes/demo.toml");
    let mut f: SceneFile =
        toml::from_str(&std::fs::read_to_string(path).expect("read")).expect("parse");
    f.camera.width = 1200;
    f.camera.height = 900;
    f.camera.k = [[2667.0, 0.0, 599.5], [0.0, 2667.0, 449.5], [0.0, 0.0, 1.0]];
    let scene = Scene::from_file(f, std::path::Path::new("."), "bench").expect("scene");
    let sim = Simulator::new(scene.clone());
    let (pw, ph) = (scene.projector.width, scene.projector.height);
    let p = XPointPattern::generate(pw, ph, [14, 14], 3, 7).expect("pattern");
    let mask = ProjectionMask {
        width: pw,
        height: ph,
        values: p
            .render()
            .into_iter()
            .map(|v| f32::from(v) / 255.0)
            .collect(),
    };
    let img = sim.frame_with(&sim.layout(), Pattern::White, Some(&mask), 1.0, 3);
    let levels = img.to_levels();
    let (w, h) = (img.width as usize, img.height as usize);
    let (cam, proj) = (scene.camera.clone(), scene.projector.clone());
    let predict = move |x: f64, y: f64| {
        let (d, o) = (cam.ray(x, y), cam.center());
        proj.project(&(o + (-o.z / d.z) * d))
    };
    let mut g = c.benchmark_group("single_shot");
    g.sample_size(20);
    g.bench_function("detect_1200x900", |b| {
        b.iter(|| detect(&levels, w, h, &DetectParams::default()))
    });
    let found = detect(&levels, w, h, &DetectParams::default());
    g.bench_function("decode_1200x900", |b| {
        b.iter(|| decode(&found, &p, Some(&predict)))
    });
    g.bench_function("detect_decode_1200x900", |b| {
        b.iter(|| {
            let found = detect(&levels, w, h, &DetectParams::default());
            decode(&found, &p, Some(&predict))
        })
    });
    g.finish();
}

criterion_group!(benches, pattern, frame);
criterion_main!(benches);
