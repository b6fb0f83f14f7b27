//! Decoding error against the simulator's truth on the demo sensor's flat table (uniform
//! albedo, or the demo's texture with TEXTURE=1), by image column band: shows the moiré of
//! the camera's and projector's pixel grids in the sub-pixel crossing.
use std::path::Path;

use ris_core::decode::{decode, DecodeParams};
use ris_core::geometry::Vec3;
use ris_core::sim::{Scene, SceneFile, Simulator};

fn main() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/scenes/demo.toml");
    let demo = std::fs::read_to_string(&path).expect("demo scene");
    let mut optics = demo[..demo.find("[[object]]").expect("objects")].to_string();
    if std::env::var("NOISELESS").is_ok() {
        optics = optics
            .replace("noise = 1.5", "noise = 0.0")
            .replace("shot_noise = 0.05", "shot_noise = 0.0");
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
        if phase {
            // Where the largest errors lie (the image's border, one-sided windows).
            let mut worst: Vec<(f64, usize, usize)> = Vec::new();
            for y in 0..h {
                for x in 0..w {
                    let i = y * w + x;
                    let p = truth.xyz[i];
                    if !p[0].is_finite() || !d.col[i].is_finite() || truth.lit[i] < 0.999 {
                        continue;
                    }
                    let p = Vec3::new(p[0] as f64, p[1] as f64, p[2] as f64);
                    let Some((u, v)) = scene.projector.project(&p) else {
                        continue;
                    };
                    let e = (d.col[i] as f64 - u).abs().max((rows[i] as f64 - v).abs());
                    worst.push((e, x, y));
                }
            }
            worst.sort_by(|a, b| b.0.total_cmp(&a.0));
            for (e, x, y) in worst.iter().take(12) {
                println!("  outlier {e:.4} px at ({x}, {y})");
            }
        }
        let (mut bands_c, mut bands_r) =
            (vec![(0.0, 0.0, 0usize); 16], vec![(0.0, 0.0, 0usize); 16]);
        let (mut all_c, mut all_r) = (Vec::new(), Vec::new());
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                let p = truth.xyz[i];
                if !p[0].is_finite() || !d.col[i].is_finite() || truth.lit[i] < 0.999 {
                    continue;
                }
                let p = Vec3::new(p[0] as f64, p[1] as f64, p[2] as f64);
                let Some((u, v)) = scene.projector.project(&p) else {
                    continue;
                };
                let ec = d.col[i] as f64 - u;
                let b = &mut bands_c[x * 16 / w];
                b.0 += ec;
                b.1 += ec * ec;
                b.2 += 1;
                all_c.push(ec);
                if rows[i].is_finite() {
                    let er = rows[i] as f64 - v;
                    let b = &mut bands_r[y * 16 / h];
                    b.0 += er;
                    b.1 += er * er;
                    b.2 += 1;
                    all_r.push(er);
                }
            }
        }
        // Correlated error: SD of the mean over 8x8 blocks (white noise: the pixel SD / 8).
        let mut blocks = std::collections::HashMap::<(usize, usize), (f64, usize)>::new();
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                let p = truth.xyz[i];
                if !p[0].is_finite() || !d.col[i].is_finite() || truth.lit[i] < 0.999 {
                    continue;
                }
                let p = Vec3::new(p[0] as f64, p[1] as f64, p[2] as f64);
                let Some((u, _)) = scene.projector.project(&p) else {
                    continue;
                };
                let e = blocks.entry((x / 8, y / 8)).or_default();
                e.0 += d.col[i] as f64 - u;
                e.1 += 1;
            }
        }
        let means: Vec<f64> = blocks
            .values()
            .filter(|(_, n)| *n == 64)
            .map(|(s, n)| s / *n as f64)
            .collect();
        let bm = means.iter().sum::<f64>() / means.len() as f64;
        let bsd = (means.iter().map(|m| (m - bm).powi(2)).sum::<f64>() / means.len() as f64).sqrt();
        println!(
            "  8x8 block means of the column error: SD {bsd:.4} px over {} blocks",
            means.len()
        );
        let stats = |v: &[f64]| {
            let m = v.iter().sum::<f64>() / v.len() as f64;
            let sd = (v.iter().map(|e| (e - m) * (e - m)).sum::<f64>() / v.len() as f64).sqrt();
            (m, sd)
        };
        let tail = |v: &[f64]| {
            let worst = v.iter().fold(0.0f64, |a, b| a.max(b.abs()));
            let beyond = v.iter().filter(|e| e.abs() > 0.03).count();
            format!("worst {worst:.4} px, {beyond} beyond 0.03 px")
        };
        println!("  tails: columns {}; rows {}", tail(&all_c), tail(&all_r));
        let (mc, sc) = stats(&all_c);
        let (mr, sr) = stats(&all_r);
        println!(
            "phase correction {phase}: columns mean {mc:+.4} SD {sc:.4} px ({} px); rows mean {mr:+.4} SD {sr:.4}",
            all_c.len()
        );
        let line = |b: &[(f64, f64, usize)]| {
            b.iter()
                .map(|(s, _, n)| format!("{:+.4}", s / (*n).max(1) as f64))
                .collect::<Vec<_>>()
                .join(" ")
        };
        println!("  column error by column band: {}", line(&bands_c));
        println!("  row error by row band:       {}", line(&bands_r));
    }
}
