//! Calibration speed: camera calibration of OpenCV's 13 VGA views and of 12 of them upscaled to
//! 1600x1200 (board detection included),
//! and a 9-layer 2 MP sensor session (1600x1200, the `session.toml` scene scaled; captures in
//! memory, so decoding, detection and every fit are measured but not PNG reading).
#![allow(missing_docs)] // criterion_group! generates an undocumented public function

use std::path::Path;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion};
use rayon::prelude::*;
use ris_core::calibrate::chessboard::{detect, BoardSize, DetectParams};
use ris_core::calibrate::{
    calibrate_camera, calibrate_sensor_with, BoardView, CameraParams, SensorParams, Session,
};
use ris_core::capture::CaptureSet;
use ris_core::image::GrayImage;
use ris_core::sim::{simulate_session, Scene, SceneFile};

fn camera(c: &mut Criterion) {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/opencv_chessboard_9x6");
    let images: Vec<(String, GrayImage)> = [1, 2, 3, 4, 5, 6, 7, 8, 9, 11, 12, 13, 14]
        .iter()
        .map(|n| {
            let p = dir.join(format!("left{n:02}.jpg"));
            (p.display().to_string(), GrayImage::load(&p).expect("image"))
        })
        .collect();
    let board = BoardSize { cols: 9, rows: 6 };
    let mut g = c.benchmark_group("calibrate");
    g.sample_size(20);
    g.bench_function("camera_13_vga_views", |b| {
        b.iter(|| {
            let views: Vec<BoardView> = images
                .par_iter()
                .map(|(name, img)| BoardView {
                    name: name.clone(),
                    corners: detect(&img.to_levels(), 640, 480, board, &DetectParams::default())
                        .expect("board"),
                })
                .collect();
            calibrate_camera(&views, 25.0, 640, 480, &CameraParams::default()).expect("calibration")
        })
    });
    // The comparison: 12 views of 1600x1200 (the first twelve, upscaled 2.5x
    // bilinearly), board detection and calibration.
    let big: Vec<(String, Vec<f32>)> = images[..12]
        .iter()
        .map(|(name, img)| {
            (
                name.clone(),
                upscale(&img.to_levels(), 640, 480, 1600, 1200),
            )
        })
        .collect();
    g.bench_function("camera_12_views_1600x1200", |b| {
        b.iter(|| {
            let views: Vec<BoardView> = big
                .par_iter()
                .map(|(name, levels)| BoardView {
                    name: name.clone(),
                    corners: detect(levels, 1600, 1200, board, &DetectParams::default())
                        .expect("board"),
                })
                .collect();
            calibrate_camera(&views, 25.0, 1600, 1200, &CameraParams::default())
                .expect("calibration")
        })
    });
    g.finish();
}

/// Bilinear resampling of a `w × h` image to `nw × nh` (pixel centres aligned, as OpenCV's
/// `INTER_LINEAR`).
fn upscale(levels: &[f32], w: usize, h: usize, nw: usize, nh: usize) -> Vec<f32> {
    let (sx, sy) = (w as f64 / nw as f64, h as f64 / nh as f64);
    let mut out = vec![0.0f32; nw * nh];
    for y in 0..nh {
        let fy = ((y as f64 + 0.5) * sy - 0.5).clamp(0.0, (h - 1) as f64);
        let (y0, ty) = (fy.floor() as usize, (fy - fy.floor()) as f32);
        let y1 = (y0 + 1).min(h - 1);
        for x in 0..nw {
            let fx = ((x as f64 + 0.5) * sx - 0.5).clamp(0.0, (w - 1) as f64);
            let (x0, tx) = (fx.floor() as usize, (fx - fx.floor()) as f32);
            let x1 = (x0 + 1).min(w - 1);
            let top = levels[y0 * w + x0] * (1.0 - tx) + levels[y0 * w + x1] * tx;
            let bottom = levels[y1 * w + x0] * (1.0 - tx) + levels[y1 * w + x1] * tx;
            out[y * nw + x] = top * (1.0 - ty) + bottom * ty;
        }
    }
    out
}

fn sensor(c: &mut Criterion) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/scenes/session.toml");
    let text = std::fs::read_to_string(&path).expect("session scene");
    let mut file: SceneFile = toml::from_str(&text).expect("parse");
    file.camera.width = 1600;
    file.camera.height = 1200;
    file.camera.k = [[2000.0, 0.0, 799.5], [0.0, 2000.0, 599.5], [0.0, 0.0, 1.0]];
    file.render.supersample = 2;
    let scene = Scene::from_file(file, path.parent().expect("dir"), "bench").expect("scene");
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("session");
    simulate_session(&scene, &out, &|_, _, _| {}).expect("render");
    let session = Session::load(&out).expect("session");
    let captures: Vec<CaptureSet> = session
        .layers
        .iter()
        .map(|l| CaptureSet::load(&l.dir).expect("layer"))
        .collect();
    let params = SensorParams::default();
    let mut g = c.benchmark_group("calibrate");
    g.sample_size(10);
    g.measurement_time(Duration::from_secs(40));
    g.bench_function("sensor_9_layers_2mp", |b| {
        b.iter(|| {
            let cal = calibrate_sensor_with(
                &session,
                &params,
                &|i| Ok(captures[i].clone()),
                &|_, _, _| {},
            )
            .expect("calibration");
            assert!(cal.passed(), "{:?}", cal.report.gates);
            cal
        })
    });
    g.finish();
}

criterion_group!(benches, camera, sensor);
criterion_main!(benches);
