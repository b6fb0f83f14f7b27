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

/// Render an omnidirectional room scene (a file with `[room]`) into `out`: the camera's view
/// of the ring pattern (`image.png`, with `rings.png` and `rings.toml`) or of `show`
/// (`shown.png`), the sensor file (`sensor.toml`) and the truth (`truth/`).
pub fn omni(scene: &Path, out: &Path, show: Option<&Path>) -> Result<()> {
    use ris_core::omni::scene::{write_truth, OmniScene};
    let s = OmniScene::load(scene).with_context(|| format!("reading scene {}", scene.display()))?;
    let lens = &s.sensor.projector.lens;
    let (pw, ph) = (lens.width, lens.height);
    let (picture, name) = match show {
        Some(path) => {
            let img =
                GrayImage::load(path).with_context(|| format!("reading {}", path.display()))?;
            let Pixels::U8(px) = &img.pixels else {
                anyhow::bail!("{}: a projector picture is 8-bit grey", path.display());
            };
            if (img.width, img.height) != (pw, ph) {
                anyhow::bail!(
                    "{}: the picture is {}x{}, the sensor's projector {pw}x{ph}",
                    path.display(),
                    img.width,
                    img.height
                );
            }
            (px.clone(), "shown.png")
        }
        None => (s.rings()?.render(), "image.png"),
    };
    let sensor_text = std::fs::read(&s.sensor_path)
        .with_context(|| format!("reading {}", s.sensor_path.display()))?;
    let pb = progress::spinner("rendering through the mirrors");
    let (image, truth) = s.render(&picture)?;
    pb.finish_and_clear();
    ris_core::io::write_dir_atomically(out, |dir| {
        ris_core::io::create_dir(dir)?;
        if show.is_none() {
            let rings = s.rings()?;
            GrayImage::from_u8(pw, ph, rings.render()).save_png(&dir.join("rings.png"))?;
            ris_core::io::write_toml(&dir.join("rings.toml"), &rings)?;
        }
        image.save_png(&dir.join(name))?;
        ris_core::io::write_atomic(&dir.join("sensor.toml"), &sensor_text)?;
        write_truth(&truth, image.width, image.height, &dir.join("truth"))
    })
    .with_context(|| format!("writing {}", out.display()))?;
    let seen = truth.xyz.iter().filter(|p| p[0].is_finite()).count();
    let lit = truth.lit.iter().filter(|l| **l).count();
    println!(
        "simulated room {}: {} ({} pixels see the room, {} lit by the projector), sensor and truth in {}",
        scene.display(),
        out.join(name).display(),
        seen,
        lit,
        out.display()
    );
    Ok(())
}

/// Render `scene` into `out` with a progress bar; with `show` (a projector picture, checked
/// before anything is rendered) also the camera's view of it, `out/shown.png`.
pub fn run(scene: &Path, out: &Path, show: Option<&Path>) -> Result<Simulated> {
    let s = Scene::load(scene).with_context(|| format!("reading scene {}", scene.display()))?;
    let shown = show
        .map(|picture| Ok::<_, anyhow::Error>((picture, projector_picture(&s, picture)?)))
        .transpose()?;
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
        if let Some((picture, mask)) = &shown {
            let sim = Simulator::new(s);
            let frame = sim.frame_with(&sim.layout(), Pattern::White, Some(mask), 1.0, 1);
            let path = out.join("shown.png");
            frame
                .save_png(&path)
                .with_context(|| format!("writing {}", path.display()))?;
            println!("camera view of {}: {}", picture.display(), path.display());
        }
        return Ok(Simulated::Session(o));
    }
    let frames = frames_per_capture(&s);
    // The scene is ray-cast before the first frame (tens of seconds for a large one).
    let pb = progress::bar(2 * frames, "ray-casting");
    let stage = Mutex::new(String::new());
    let mask = shown.as_ref().map(|(_, m)| m);
    let result = simulate(&s, out, mask, &|what, _, _| {
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
    if let (Some((picture, _)), Some(path)) = (&shown, &o.shown) {
        println!("camera view of {}: {}", picture.display(), path.display());
    }
    Ok(Simulated::Scene(o))
}

/// The projector picture at `picture` as a mask for `s`'s projector: an 8-bit grey image of
/// the projector's size.
fn projector_picture(s: &Scene, picture: &Path) -> Result<ProjectionMask> {
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
    Ok(ProjectionMask::picture(pw, ph, pixels))
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
