//! Adaptive-mask computation on a 2 MP camera (1600x1200, the challenge scene): the once-per-
//! scan setup (photo-response fits of two flat series, exposure, desired levels, the
//! reference-plane guess, the advanced mask) and one loop iteration (decoding the advanced
//! capture, refining the crosstalk, the mask, one feedback round).
#![allow(missing_docs)] // criterion_group! generates an undocumented public function

use std::path::Path;

use criterion::{criterion_group, criterion_main, Criterion};
use ris_core::decode::{decode, DecodeParams};
use ris_core::image::GrayImage;
use ris_core::mask::{feedback, CodeMap, MaskBuild, MaskParams, PhotoResponse, FLAT_LEVELS};
use ris_core::pattern::Pattern;
use ris_core::sim::{Scene, SceneFile, Simulator};

fn scene_2mp() -> Scene {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/scenes/challenge.toml");
    let text = std::fs::read_to_string(&path).expect("challenge scene");
    let mut file: SceneFile = toml::from_str(&text).expect("parse");
    let s = 2.0;
    file.camera.width = 1600;
    file.camera.height = 1200;
    file.camera.k = [
        [1778.0 * s, 0.0, 799.5],
        [0.0, 1778.0 * s, 599.5],
        [0.0, 0.0, 1.0],
    ];
    file.render.supersample = 1;
    Scene::from_file(file, path.parent().expect("dir"), "bench scene").expect("scene")
}

fn series(f: &[GrayImage]) -> Vec<(u8, &GrayImage)> {
    FLAT_LEVELS.iter().copied().zip(f).collect()
}

fn bench(c: &mut Criterion) {
    let scene = scene_2mp();
    let p = MaskParams::default();
    let sim = Simulator::new(scene.clone());
    let layout = sim.layout();
    let flats = |exposure: f64| -> Vec<GrayImage> {
        FLAT_LEVELS
            .iter()
            .enumerate()
            .map(|(i, &l)| sim.frame_with(&layout, Pattern::Flat(l), None, exposure, i as u64))
            .collect()
    };
    let (f0, f1) = (flats(1.0), flats(8.0));
    let reference = decode(
        &Simulator::new(scene.sprayed().reference()).capture(&layout, 7, &|_, _| {}),
        &DecodeParams::default(),
    )
    .expect("reference");
    // The advanced capture under a mask of the right magnitude.
    let r = PhotoResponse::fit(&series(&f0), 1.0, p.saturation)
        .at_exposure(8.0)
        .merged(&PhotoResponse::fit(&series(&f1), 8.0, p.saturation));
    let guess = CodeMap::reference_guess(&reference).expect("guess");
    let advanced_mask = MaskBuild::dilate(
        &MaskBuild::splat(&guess, &r.desired_mask(&p), 1024, 768),
        p.dilation,
    );
    let mut advanced = ris_core::capture::CaptureSet::new(layout, 1600, 1200);
    for (i, pat) in layout.sequence(true).into_iter().enumerate() {
        advanced.frames.insert(
            pat,
            sim.frame_with(&layout, pat, Some(&advanced_mask), 8.0, 100 + i as u64),
        );
    }
    let adv_params = DecodeParams {
        extrapolate: true,
        ..DecodeParams::default()
    };
    let (w, b) = (
        advanced.frame(Pattern::White).expect("white").clone(),
        advanced.frame(Pattern::Black).expect("black").clone(),
    );

    let mut g = c.benchmark_group("mask");
    g.sample_size(10);
    // Once per scan: responses, exposure, desired levels, the guess and the advanced mask.
    g.bench_function("setup_1600x1200", |bch| {
        bch.iter(|| {
            let r0 = PhotoResponse::fit(&series(&f0), 1.0, p.saturation);
            let factor = r0.choose_exposure(&p);
            let r1 = PhotoResponse::fit(&series(&f1), 8.0, p.saturation);
            let desired = r0.at_exposure(8.0).merged(&r1).desired_mask(&p);
            let guess = CodeMap::reference_guess(&reference).expect("guess");
            let dark =
                MaskBuild::dilate(&MaskBuild::splat(&guess, &desired, 1024, 768), p.dilation);
            let bright = MaskBuild::erode(
                &MaskBuild::splat_min(&guess, &desired, 1024, 768),
                p.dilation,
            );
            (factor, dark, bright)
        })
    });
    // Each iteration: decode the advanced capture, refine the crosstalk, build the mask, one
    // feedback round.
    let desired0 = r.desired_mask(&p);
    g.bench_function("iteration_1600x1200", |bch| {
        bch.iter(|| {
            let mut desired = desired0.clone();
            let dec = decode(&advanced, &adv_params).expect("decode");
            let measured = CodeMap::from_decoded(&dec).expect("map");
            let (map, _) = CodeMap::refined(&guess, &measured, &p);
            let mask = MaskBuild::splat(&map, &desired, 1024, 768);
            let fb = feedback(&mut desired, &w, &b, p.feedback_spread, &p);
            (mask, fb)
        })
    });
    g.bench_function("decode_advanced_1600x1200", |bch| {
        bch.iter(|| decode(&advanced, &adv_params).expect("decode"))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
