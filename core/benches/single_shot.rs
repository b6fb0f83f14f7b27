//! Single-shot speed: generating the X-point code and primitives of a 1920x1080 projector at a
//! 14 px step, and rendering its 8-bit image; detecting and decoding the X-points of one
//! 1200x900 (1.08 MP) camera frame of the demo scene (pattern at 14 px), and the whole
//! measurement of it as risd makes it (detection, decoding with the Gray-code reference's
//! prediction, reconstruction through the parallax model); and each stage of one frame of a
//! stream at the demo's own 800x600 (the measurement, the fusion picture, its PNG, the PLY).
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

/// The demo scene: its own 800x600 camera, or (`large`) a 1200x900 one with a longer lens.
fn demo(large: bool) -> ris_core::sim::Scene {
    use ris_core::sim::{Scene, SceneFile};
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/scenes/demo.toml");
    let mut f: SceneFile =
        toml::from_str(&std::fs::read_to_string(path).expect("read")).expect("parse");
    if large {
        f.camera.width = 1200;
        f.camera.height = 900;
        f.camera.k = [[2667.0, 0.0, 599.5], [0.0, 2667.0, 449.5], [0.0, 0.0, 1.0]];
    }
    Scene::from_file(f, std::path::Path::new("."), "bench").expect("scene")
}

fn frame(c: &mut Criterion) {
    frame_of(c, false);
    frame_of(c, true);
}

/// The 1200x900 frame's detector, decoder and measurement; or (`stream`) each stage of one
/// frame of a stream at the demo's 800x600.
fn frame_of(c: &mut Criterion, stream: bool) {
    use ris_core::pattern::{Pattern, ProjectionMask};
    use ris_core::sensor::Reconstructor;
    use ris_core::sim::Simulator;
    use ris_core::single_shot::{
        decode, detect, fuse, measure, DetectParams, Detector, FusionRange, ReferencePrediction,
    };
    let scene = demo(!stream);
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
    // As risd measures: the prediction and the parallax model from the decoded reference.
    let board = Simulator::new(scene.sprayed().reference());
    let reference = ris_core::decode::decode(
        &board.capture(&board.layout(), 1000, &|_, _| {}),
        &ris_core::decode::DecodeParams::default(),
    )
    .expect("reference");
    let rec = Reconstructor::parallax(&scene.camera, scene.projector.center(), &reference)
        .expect("parallax");
    let prediction = ReferencePrediction::new(&reference).expect("row codes");
    let predict = |x: f64, y: f64| prediction.at(x, y);
    let mut g = c.benchmark_group("single_shot");
    g.sample_size(20);
    let mut detector = Detector::new(DetectParams::default());
    if stream {
        // What risd does with each frame of a stream, stage by stage.
        let size = format!("{w}x{h}");
        g.bench_function(format!("stream_measure_{size}"), |b| {
            b.iter(|| measure(&mut detector, &img, &p, Some(&predict), &rec))
        });
        let m = measure(&mut detector, &img, &p, Some(&predict), &rec);
        let c = rec.camera().center();
        let eye = [c.x, c.y, c.z];
        let range = FusionRange::covering(&m.cloud, eye);
        g.bench_function(format!("stream_fusion_picture_{size}"), |b| {
            b.iter(|| fuse(&img, &m.cloud, eye, range, None).expect("fuse"))
        });
        let picture = fuse(&img, &m.cloud, eye, range, None).expect("fuse");
        g.bench_function(format!("stream_picture_png_{size}"), |b| {
            b.iter(|| picture.png().expect("png"))
        });
        g.bench_function(format!("stream_cloud_ply_{size}"), |b| {
            b.iter(|| m.cloud.to_ply())
        });
        g.finish();
        return;
    }
    g.bench_function("detect_1200x900", |b| {
        b.iter(|| detector.detect(&levels, w, h))
    });
    let found = detect(&levels, w, h, &DetectParams::default());
    g.bench_function("decode_1200x900", |b| {
        b.iter(|| decode(&found, &p, Some(&predict)))
    });
    g.bench_function("measure_1200x900", |b| {
        b.iter(|| measure(&mut detector, &img, &p, Some(&predict), &rec))
    });
    g.finish();
}

criterion_group!(benches, pattern, frame);
criterion_main!(benches);
