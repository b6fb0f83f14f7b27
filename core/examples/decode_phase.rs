//! Decoding error against the simulator's truth on the demo sensor's flat table (uniform
//! albedo, or the demo's texture with TEXTURE=1; at height Z mm; NOISELESS=1 without read and
//! shot noise), with and without the crossing's phase bias removed: the error's SD, its
//! correlated part (8x8-pixel block means), its mean by image band (the moiré of the camera's
//! and projector's pixel grids shows where their pitches beat), its tail and where the largest
//! errors lie.
#[path = "../tests/common/mod.rs"]
mod common;

use std::path::Path;

use ris_core::decode::{decode, DecodeParams};
use ris_core::geometry::Vec3;
use ris_core::sim::{Scene, SceneFile, Simulator};

/// One decoded pixel: its position and its column and row errors (projector px; the row's NaN
/// where it has none).
struct Pixel {
    x: usize,
    y: usize,
    col: f64,
    row: f64,
}

fn moments(v: impl Iterator<Item = f64> + Clone) -> (f64, f64) {
    let n = v.clone().count().max(1) as f64;
    let mean = v.clone().sum::<f64>() / n;
    (
        mean,
        (v.map(|e| (e - mean).powi(2)).sum::<f64>() / n).sqrt(),
    )
}

fn main() {
    let mut optics = common::demo_optics();
    if std::env::var("NOISELESS").is_ok() {
        optics = common::noiseless(&optics);
    }
    let material = if std::env::var("TEXTURE").is_ok() {
        "table"
    } else {
        "flat"
    };
    let height: f64 = std::env::var("Z")
        .ok()
        .and_then(|z| z.parse().ok())
        .unwrap_or(0.0);
    let text = format!(
        "{optics}\n[material.flat]\nalbedo = 0.6\n\n[[object]]\nshape = \"box\"\nmaterial = \"{material}\"\n\
         center = [0, 0, {}]\nsize = [3000, 3000, 20]\n", height - 10.0
    );
    let file: SceneFile = toml::from_str(&text).expect("scene");
    let scene = Scene::from_file(file, Path::new("."), "phase scene").expect("scene");
    let sim = Simulator::new(scene.clone());
    let capture = sim.capture(&sim.layout(), 7, &|_, _| {});
    let truth = &sim.cache.truth;
    let (w, h) = (truth.width as usize, truth.height as usize);
    for phase in [false, true] {
        let params = DecodeParams {
            phase_correction: phase,
            ..DecodeParams::default()
        };
        let d = decode(&capture, &params).expect("decode");
        let rows = d.row.as_ref().expect("rows");
        let pixels: Vec<Pixel> = (0..w * h)
            .filter_map(|i| {
                let p = truth.xyz[i];
                if !p[0].is_finite() || !d.col[i].is_finite() || truth.lit[i] < 0.999 {
                    return None;
                }
                let p = Vec3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
                let (u, v) = scene.projector.project(&p)?;
                Some(Pixel {
                    x: i % w,
                    y: i / w,
                    col: f64::from(d.col[i]) - u,
                    row: f64::from(rows[i]) - v,
                })
            })
            .collect();
        let cols = pixels.iter().map(|p| p.col);
        let rws = pixels.iter().map(|p| p.row).filter(|e| e.is_finite());
        let ((mc, sc), (mr, sr)) = (moments(cols.clone()), moments(rws.clone()));
        println!(
            "phase correction {phase}: columns mean {mc:+.4} SD {sc:.4} px ({} px); rows mean {mr:+.4} SD {sr:.4}",
            pixels.len()
        );
        // Correlated error: SD of the mean over whole 8x8 blocks (white noise: the pixel SD / 8).
        let bw = w.div_ceil(8);
        let mut blocks = vec![(0.0, 0usize); bw * h.div_ceil(8)];
        let (mut bands_c, mut bands_r) = (vec![(0.0, 0usize); 16], vec![(0.0, 0usize); 16]);
        for p in &pixels {
            let b = &mut blocks[(p.y / 8) * bw + p.x / 8];
            b.0 += p.col;
            b.1 += 1;
            let b = &mut bands_c[p.x * 16 / w];
            b.0 += p.col;
            b.1 += 1;
            if p.row.is_finite() {
                let b = &mut bands_r[p.y * 16 / h];
                b.0 += p.row;
                b.1 += 1;
            }
        }
        let means = blocks
            .iter()
            .filter(|(_, n)| *n == 64)
            .map(|(s, n)| s / *n as f64);
        println!(
            "  8x8 block means of the column error: SD {:.4} px over {} blocks",
            moments(means.clone()).1,
            means.count()
        );
        let line = |b: &[(f64, usize)]| {
            b.iter()
                .map(|(s, n)| format!("{:+.4}", s / (*n).max(1) as f64))
                .collect::<Vec<_>>()
                .join(" ")
        };
        println!("  column error by column band: {}", line(&bands_c));
        println!("  row error by row band:       {}", line(&bands_r));
        let tail = |v: &mut dyn Iterator<Item = f64>| {
            let (mut worst, mut beyond) = (0.0f64, 0usize);
            for e in v {
                worst = worst.max(e.abs());
                beyond += usize::from(e.abs() > 0.03);
            }
            format!("worst {worst:.4} px, {beyond} beyond 0.03 px")
        };
        println!(
            "  tails: columns {}; rows {}",
            tail(&mut cols.clone()),
            tail(&mut rws.clone())
        );
        if phase {
            // Where the largest errors lie (the image's border, one-sided windows).
            let mut worst: Vec<(f64, usize, usize)> = pixels
                .iter()
                .map(|p| (p.col.abs().max(p.row.abs()), p.x, p.y))
                .filter(|(e, _, _)| e.is_finite())
                .collect();
            worst.sort_by(|a, b| b.0.total_cmp(&a.0));
            for (e, x, y) in worst.iter().take(12) {
                println!("  outlier {e:.4} px at ({x}, {y})");
            }
        }
    }
}
