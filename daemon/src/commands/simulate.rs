//! `ris simulate`: render a scene's capture, reference, sensor file and ground truth.

use std::path::Path;
use std::sync::Mutex;

use anyhow::{Context, Result};
use ris_core::sim::{simulate, Scene, SimOutput};

use crate::progress;

/// Render `scene` into `out` with a progress bar.
pub fn run(scene: &Path, out: &Path) -> Result<SimOutput> {
    let s = Scene::load(scene).with_context(|| format!("reading scene {}", scene.display()))?;
    let frames = (if s.render.rows {
        2 + 2
            * (s.projector.width.next_power_of_two().trailing_zeros()
                + s.projector.height.next_power_of_two().trailing_zeros())
    } else {
        2 + 2 * s.projector.width.next_power_of_two().trailing_zeros()
    }) as u64;
    let pb = progress::bar(2 * frames, "rendering");
    let stage = Mutex::new(String::new());
    let result = simulate(&s, out, &|what, _, _| {
        if let Ok(mut st) = stage.lock() {
            if *st != what {
                pb.set_message(what.to_string());
                *st = what.to_string();
            }
        }
        pb.inc(1);
    });
    pb.finish_and_clear();
    let o =
        result.with_context(|| format!("simulating {} into {}", scene.display(), out.display()))?;
    println!(
        "simulated {}: capture {}, reference {}, sensor {}, truth {}",
        scene.display(),
        o.capture.display(),
        o.reference.display(),
        o.sensor.display(),
        o.truth.display()
    );
    Ok(o)
}
