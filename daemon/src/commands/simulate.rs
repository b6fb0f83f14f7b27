//! `ris simulate`: render a scene's capture, reference, sensor file and ground truth, or, for a
//! scene with `[calibration]`, a multi-layer calibration session.

use std::path::Path;
use std::sync::Mutex;

use anyhow::{Context, Result};
use ris_core::image::{GrayImage, Pixels};
use ris_core::pattern::{Pattern, ProjectionMask};
use ris_core::sim::{simulate, simulate_session, Scene, SimOutput, Simulator};

use crate::progress;

/// What `ris simulate` wrote.
pub enum Simulated {
    /// A capture of the scene's objects.
    Scene(SimOutput),
    /// A calibration session.
    Session(ris_core::sim::SessionOutput),
}

/// Render `scene` into `out` with a progress bar.
pub fn run(scene: &Path, out: &Path) -> Result<Simulated> {
    let s = Scene::load(scene).with_context(|| format!("reading scene {}", scene.display()))?;
    if let Some(c) = &s.file.calibration {
        let layers = c.heights.len() as u64;
        let pb = progress::bar(layers * frames_per_capture(&s), "rendering");
        let result = simulate_session(&s, out, &|what, _, _| {
            pb.set_message(what.to_string());
            pb.inc(1);
        });
        pb.finish_and_clear();
        let o = result.with_context(|| {
            format!(
                "simulating the session of {} into {}",
                scene.display(),
                out.display()
            )
        })?;
        println!(
            "simulated a {layers}-layer calibration session: {}, true sensor {}",
            o.session.display(),
            o.truth.display()
        );
        return Ok(Simulated::Session(o));
    }
    let frames = frames_per_capture(&s);
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
    Ok(Simulated::Scene(o))
}

/// Render the camera's view of `picture` projected on `scene` to `<out>/shown.png`.
pub fn show(scene: &Path, picture: &Path, out: &Path) -> Result<()> {
    let s = Scene::load(scene).with_context(|| format!("reading scene {}", scene.display()))?;
    let img = GrayImage::load(picture).with_context(|| format!("reading {}", picture.display()))?;
    let (pw, ph) = (s.projector.width, s.projector.height);
    if (img.width, img.height) != (pw, ph) {
        anyhow::bail!(
            "{}: the picture is {}x{}, the scene's projector {pw}x{ph}",
            picture.display(),
            img.width,
            img.height
        );
    }
    let Pixels::U8(pixels) = &img.pixels else {
        anyhow::bail!(
            "{}: a projector picture is 8-bit grey; this one is 16-bit",
            picture.display()
        );
    };
    let sim = Simulator::new(s);
    let mask = ProjectionMask::picture(pw, ph, pixels);
    let frame = sim.frame_with(&sim.layout(), Pattern::White, Some(&mask), 1.0, 1);
    let path = out.join("shown.png");
    frame
        .save_png(&path)
        .with_context(|| format!("writing {}", path.display()))?;
    println!("camera view of {}: {}", picture.display(), path.display());
    Ok(())
}

/// Frames in one full capture of the scene's projector.
fn frames_per_capture(s: &Scene) -> u64 {
    (if s.render.rows {
        2 + 2
            * (s.projector.width.next_power_of_two().trailing_zeros()
                + s.projector.height.next_power_of_two().trailing_zeros())
    } else {
        2 + 2 * s.projector.width.next_power_of_two().trailing_zeros()
    }) as u64
}
