//! Where the adaptive loop's final crosstalk map disagrees with the simulator's truth, per
//! material, and how much of each material the final masked white frame saturates.
//! `cargo run --release -p ris-drivers --example adaptive_diag -- SCENE.toml`

use std::sync::Arc;

use ris_core::decode::{decode, DecodeParams};
use ris_core::geometry::Vec3;
use ris_core::pattern::Pattern;
use ris_core::sim::{Scene, Simulator};
use ris_drivers::adaptive::{adaptive_scan, AdaptiveParams};
use ris_drivers::mock::simulated_pair;

fn main() {
    let Some(path) = std::env::args().nth(1) else {
        eprintln!("usage: adaptive_diag SCENE.toml");
        std::process::exit(2);
    };
    let scene = match Scene::load(std::path::Path::new(&path)) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("{e}");
            std::process::exit(1);
        }
    };
    let params = DecodeParams::default();
    let board = Simulator::new(scene.sprayed().reference());
    let layout = board.layout();
    let reference =
        decode(&board.capture(&layout, 1000, &|_, _| {}), &params).expect("reference decodes");
    let sim = Arc::new(Simulator::new(scene.clone()));
    let truth = sim.cache.truth.clone();
    let (mut cam, mut proj, _) = simulated_pair(sim, "diag", 2);
    let scan = adaptive_scan(
        &mut cam,
        &mut proj,
        &layout,
        &reference,
        &AdaptiveParams::default(),
        &mut |_, _| {},
    )
    .expect("adaptive scan");
    for s in &scan.steps {
        println!("{:<28} {:>4} frames  {}", s.step, s.frames, s.detail);
    }
    let white = scan
        .capture
        .frame(Pattern::White)
        .expect("white")
        .to_levels();
    for (m, mat) in scene.materials.iter().enumerate() {
        let (mut n, mut wrong, mut saturated) = (0, 0, 0);
        for (i, p) in truth.xyz.iter().enumerate() {
            if truth.material[i] as usize != m || truth.lit[i] < 0.999 {
                continue;
            }
            let Some((u, v)) =
                scene
                    .projector
                    .project(&Vec3::new(p[0].into(), p[1].into(), p[2].into()))
            else {
                continue;
            };
            n += 1;
            let e = (f64::from(scan.map.u[i]) - u).hypot(f64::from(scan.map.v[i]) - v);
            wrong += usize::from(e.is_nan() || e > 3.0);
            saturated += usize::from(white[i] >= 250.0);
        }
        println!(
            "{:<12} lit {n:>7}: crosstalk off by > 3 px on {wrong:>6}, saturated {saturated:>6}",
            mat.name
        );
    }
}
