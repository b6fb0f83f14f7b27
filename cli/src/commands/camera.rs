//! `ris camera`: list the cameras this build can open and grab frames from one (PNG per frame
//! and a metadata TOML).

use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use anyhow::{Context, Result};
use ris_core::io::{create_dir, write_dir_atomically, write_toml};
use ris_core::pattern::Pattern;
use ris_core::sim::{Scene, Simulator};
use ris_drivers::{Camera, Frame, Projector, Slide, TriggerMode};
use serde::Serialize;

/// Camera backends of `ris camera grab`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Backend {
    /// GigE Vision / USB3 Vision through Aravis (feature `aravis`).
    Aravis,
    /// V4L2 / UVC (feature `v4l2`).
    V4l2,
    /// The simulator's camera looking at a scene under full white.
    Mock,
}

/// `ris camera list`: the in-process fake and, with `discover`, every device Aravis finds (a
/// broadcast on every network interface).
pub fn list(discover: bool) -> Result<()> {
    println!("mock\tsimulated camera (device: a scene file, or `demo`)");
    if ris_aravis::AVAILABLE {
        println!("aravis\tFake_1\tAravis in-process fake camera (512x512 Mono8)");
        #[cfg(feature = "aravis")]
        if discover {
            for (id, model, address) in ris_aravis::discover() {
                println!("aravis\t{id}\t{model}\t{address}");
            }
        }
    } else {
        println!("aravis\t(not built: rebuild with --features aravis; needs libaravis-dev)");
    }
    #[cfg(feature = "v4l2")]
    for (path, name) in ris_v4l2::devices() {
        println!("v4l2\t{}\t{name}", path.display());
    }
    if !ris_v4l2::AVAILABLE {
        println!("v4l2\t(not built: rebuild with --features v4l2; needs libclang-dev)");
    }
    if discover && !ris_aravis::AVAILABLE {
        anyhow::bail!("--discover needs the aravis backend (build with --features aravis)");
    }
    Ok(())
}

#[derive(Serialize)]
struct FrameMeta {
    file: String,
    frame_id: u64,
    host_ns: u64,
    device_ns: u64,
    exposure_us: f64,
    gain_db: f64,
    bit_depth: u8,
}

#[derive(Serialize)]
struct GrabMeta {
    backend: String,
    device: String,
    model: String,
    width: u32,
    height: u32,
    trigger: String,
    frame: Vec<FrameMeta>,
}

/// An opened camera, with the mock projector that lights its scene (kept alive with it).
struct Opened {
    camera: Box<dyn Camera>,
    _projector: Option<ris_drivers::mock::MockProjector>,
}

fn open(backend: Backend, device: &str) -> Result<Opened> {
    match backend {
        Backend::Mock => {
            let scene = if device == "demo" {
                let file =
                    toml::from_str(super::demo::DEMO_SCENE).context("built-in demo scene")?;
                Scene::from_file(file, Path::new("."), "demo scene")?
            } else {
                Scene::load(Path::new(device)).with_context(|| format!("reading scene {device}"))?
            };
            let (cam, mut projector, _) =
                ris_drivers::mock::simulated_pair(Arc::new(Simulator::new(scene)), "mock", 0);
            projector.load(&[Slide::plain(Pattern::White)])?;
            projector.show(0)?;
            Ok(Opened {
                camera: Box::new(cam),
                _projector: Some(projector),
            })
        }
        Backend::Aravis => {
            #[cfg(feature = "aravis")]
            {
                let cam = ris_aravis::AravisCamera::open(
                    ris_aravis::DeviceSpec::parse(device),
                    ris_aravis::OpenOptions::default(),
                )?;
                Ok(Opened {
                    camera: Box::new(cam),
                    _projector: None,
                })
            }
            #[cfg(not(feature = "aravis"))]
            anyhow::bail!(
                "this ris was built without the aravis backend; rebuild with --features aravis \
                 (needs libaravis-dev)"
            )
        }
        Backend::V4l2 => {
            #[cfg(feature = "v4l2")]
            {
                let cam = ris_v4l2::V4l2Camera::open(Path::new(device), None, None)?;
                Ok(Opened {
                    camera: Box::new(cam),
                    _projector: None,
                })
            }
            #[cfg(not(feature = "v4l2"))]
            anyhow::bail!(
                "this ris was built without the v4l2 backend; rebuild with --features v4l2 \
                 (needs libclang-dev)"
            )
        }
    }
}

/// `ris camera grab`: `count` frames (software-triggered or free-running) as 8/16-bit PNGs plus
/// `frames.toml`, written into `out` (absent or empty) only once every frame has arrived.
pub fn grab(
    backend: Backend,
    device: &str,
    software_trigger: bool,
    count: usize,
    exposure_us: Option<f64>,
    timeout: Duration,
    out: &Path,
) -> Result<Vec<Frame>> {
    anyhow::ensure!(count > 0, "--count must be at least 1");
    let mut opened = open(backend, device).with_context(|| format!("opening {device}"))?;
    let cam = &mut opened.camera;
    if let Some(us) = exposure_us {
        cam.set_exposure_us(us)?;
    }
    let trigger = if software_trigger {
        TriggerMode::Software
    } else {
        TriggerMode::FreeRun
    };
    cam.set_trigger(trigger.clone())?;
    cam.start()?;
    let bar = crate::progress::bar(count as u64, "frames");
    let mut frames = Vec::with_capacity(count);
    for i in 0..count {
        if software_trigger {
            cam.trigger()?;
        }
        let f = cam
            .next_frame(timeout)
            .with_context(|| format!("frame {} of {count}", i + 1))?;
        frames.push(f);
        bar.inc(1);
    }
    bar.finish_and_clear();
    cam.stop()?;
    let info = cam.info().clone();
    // Every frame first, then the directory at once: an interrupted grab leaves nothing.
    let meta = GrabMeta {
        backend: format!("{backend:?}").to_lowercase(),
        device: info.id.clone(),
        model: info.model.clone(),
        width: info.width,
        height: info.height,
        trigger: format!("{trigger:?}"),
        frame: frames
            .iter()
            .enumerate()
            .map(|(i, f)| FrameMeta {
                file: format!("frame_{i:03}.png"),
                frame_id: f.frame_id,
                host_ns: f.host_ns,
                device_ns: f.device_ns,
                exposure_us: f.exposure_us,
                gain_db: f.gain_db,
                bit_depth: f.bit_depth,
            })
            .collect(),
    };
    write_dir_atomically(out, |dir| {
        create_dir(dir)?;
        for (f, m) in frames.iter().zip(&meta.frame) {
            f.image.save_png(&dir.join(&m.file))?;
        }
        write_toml(&dir.join("frames.toml"), &meta)
    })
    .with_context(|| format!("writing {}", out.display()))?;
    println!(
        "{count} frames of {}x{} from {} ({}) in {}",
        info.width,
        info.height,
        info.id,
        info.model,
        out.display()
    );
    Ok(frames)
}
