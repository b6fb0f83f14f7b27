//! The simulator (SPEC §11): a pinhole camera and projector viewing primitives and STL meshes,
//! with anti-aliased pixel footprints, exact shadows and occlusions, ambient light, projector
//! defocus, read and shot noise and 8-bit saturation. It writes capture sets, the reference
//! recording of the bare plane, a sensor file and per-pixel ground truth.

pub mod accuracy;
mod light;
pub mod motion;
mod render;
mod scene;
mod session;
mod shapes;
mod texture;

pub use light::Light;
pub use render::{RenderCache, Truth};
pub use scene::{
    CalibrationSection, MaterialSection, ObjectSection, RenderSection, Scene, SceneFile, SimCamera,
    SimProjector,
};
pub use session::{simulate_session, SessionOutput};
pub use shapes::{Object, Shape};
pub use texture::Texture;

use std::path::{Path, PathBuf};

use crate::capture::CaptureSet;
use crate::image::GrayImage;
use crate::io::{create_dir, npy, write_dir_atomically, write_toml};
use crate::pattern::{CodeAxis, CodeLayout, Pattern, ProjectionMask};
use crate::sensor::{ProjectorSection, ReferenceSection, SensorFile};
use crate::Result;

/// A scene with its light transport computed, ready to render frames.
pub struct Simulator {
    /// The scene.
    pub scene: Scene,
    /// Its render cache (and ground truth).
    pub cache: RenderCache,
}

impl Simulator {
    /// Ray-cast `scene` once.
    pub fn new(scene: Scene) -> Simulator {
        let cache = RenderCache::build(&scene);
        Simulator { scene, cache }
    }

    /// The projector's output for `pattern` under `layout`, through the scene's defocus.
    pub fn light(&self, layout: &CodeLayout, pattern: Pattern) -> Light {
        self.light_blurred(layout, pattern, self.scene.blur as f32)
    }

    /// The projector's output for `pattern` blurred by `blur` pixels.
    fn light_blurred(&self, layout: &CodeLayout, pattern: Pattern, blur: f32) -> Light {
        let (w, h) = (layout.width, layout.height);
        match pattern {
            Pattern::White => Light::uniform(w, h, 1.0, blur),
            Pattern::Black => Light::uniform(w, h, 0.0, blur),
            Pattern::Flat(l) => Light::uniform(w, h, f32::from(l) / 255.0, blur),
            Pattern::Gray { axis, .. } => {
                let img = layout.render(pattern);
                match axis {
                    CodeAxis::Column => Light::columns(
                        &img[..w as usize]
                            .iter()
                            .map(|&p| f32::from(p) / 255.0)
                            .collect::<Vec<_>>(),
                        h,
                        blur,
                    ),
                    CodeAxis::Row => Light::rows(
                        w,
                        &img.chunks_exact(w as usize)
                            .map(|r| f32::from(r[0]) / 255.0)
                            .collect::<Vec<_>>(),
                        blur,
                    ),
                }
            }
        }
    }

    /// Render the camera frame of `pattern`; `frame` seeds the noise.
    pub fn frame(&self, layout: &CodeLayout, pattern: Pattern, frame: u64) -> GrayImage {
        self.frame_with(layout, pattern, None, 1.0, frame)
    }

    /// Render the camera frame of `pattern` multiplied by `mask`, at `exposure` times the
    /// scene's exposure; `frame` seeds the noise.
    pub fn frame_with(
        &self,
        layout: &CodeLayout,
        pattern: Pattern,
        mask: Option<&ProjectionMask>,
        exposure: f64,
        frame: u64,
    ) -> GrayImage {
        let s = &self.scene;
        let seed = s.render.seed.wrapping_mul(0x2545_F491_4F6C_DD1D)
            ^ frame.wrapping_mul(0x9E37_79B9_7F4A_7C15);
        let blur = s.blur as f32;
        let with_mask = |light: Light, sigma: f32| match mask {
            Some(m) => light.masked(m, sigma),
            None => light,
        };
        let light = with_mask(self.light_blurred(layout, pattern, blur), blur);
        let bounce: Vec<Light> = self
            .cache
            .bounce_sigmas
            .iter()
            .map(|&sigma| {
                let total = (blur * blur + sigma * sigma).sqrt();
                with_mask(self.light_blurred(layout, pattern, total), total)
            })
            .collect();
        let data = self.cache.render(
            &light,
            &bounce,
            s.exposure * exposure,
            s.noise,
            s.shot_noise,
            seed,
        );
        GrayImage::from_u8(s.camera.width, s.camera.height, data)
    }

    /// Render the full multi-shot capture (SPEC §3 order); `progress(done, total)` per frame.
    pub fn capture(
        &self,
        layout: &CodeLayout,
        seed_offset: u64,
        progress: &(dyn Fn(usize, usize) + Sync),
    ) -> CaptureSet {
        let patterns = layout.sequence(self.scene.render.rows);
        let mut set = CaptureSet::new(*layout, self.scene.camera.width, self.scene.camera.height);
        for (i, p) in patterns.iter().enumerate() {
            set.frames
                .insert(*p, self.frame(layout, *p, seed_offset + i as u64));
            progress(i + 1, patterns.len());
        }
        set.meta
            .insert("source".into(), toml::Value::String("ris simulate".into()));
        set
    }

    /// The projector's code layout (one cell per pixel).
    pub fn layout(&self) -> CodeLayout {
        CodeLayout::new(self.scene.projector.width, self.scene.projector.height)
    }
}

/// Paths written by [`simulate`].
#[derive(Clone, Debug)]
pub struct SimOutput {
    /// Capture set of the scene.
    pub capture: PathBuf,
    /// Capture set of the bare reference plane.
    pub reference: PathBuf,
    /// Sensor file (parallax model with reference; the full projector calibration as well).
    pub sensor: PathBuf,
    /// Ground-truth directory.
    pub truth: PathBuf,
}

/// Render `scene` into `out`: `capture/`, `reference/`, `sensor.toml` and `truth/`. Everything
/// is written into a temporary sibling directory first and renamed into place at the end.
pub fn simulate(
    scene: &Scene,
    out: &Path,
    progress: &(dyn Fn(&str, usize, usize) + Sync),
) -> Result<SimOutput> {
    write_dir_atomically(out, |tmp| write_simulation(scene, tmp, progress))?;
    Ok(SimOutput {
        capture: out.join("capture"),
        reference: out.join("reference"),
        sensor: out.join("sensor.toml"),
        truth: out.join("truth"),
    })
}

fn write_simulation(
    scene: &Scene,
    dir: &Path,
    progress: &(dyn Fn(&str, usize, usize) + Sync),
) -> Result<()> {
    create_dir(dir)?;
    let sim = Simulator::new(scene.clone());
    let layout = sim.layout();
    sim.capture(&layout, 0, &|i, n| progress("capture", i, n))
        .save(&dir.join("capture"))?;
    write_truth(&sim.cache.truth, scene, &dir.join("truth"))?;
    let reference = Simulator::new(scene.reference());
    reference
        .capture(&layout, 1000, &|i, n| progress("reference", i, n))
        .save(&dir.join("reference"))?;
    sensor_file(scene).save(&dir.join("sensor.toml"))
}

/// The sensor file of a simulated scene: camera, projector centre and full calibration, and the
/// reference capture at `reference/`.
pub fn sensor_file(scene: &Scene) -> SensorFile {
    let p = &scene.file.projector;
    let c = scene.projector.center();
    SensorFile {
        camera: SensorFile::camera_section(&scene.camera),
        projector: ProjectorSection {
            width: p.width,
            height: p.height,
            center: Some([c.x, c.y, c.z]),
            k: Some(p.k),
            dist: Some(p.dist),
            r: Some(p.r),
            t: Some(p.t),
        },
        reference: Some(ReferenceSection {
            capture: "reference".into(),
            extent: None,
        }),
        residual: None,
        to_common: None,
        volume: None,
    }
}

/// Write ground truth: `xyz.npy` (H×W×3 float32, NaN = no surface), `material.npy` (uint8,
/// 255 = none), `lit.npy` (float32 lit fraction) and `materials.toml` (index → name).
pub fn write_truth(truth: &Truth, scene: &Scene, dir: &Path) -> Result<()> {
    create_dir(dir)?;
    let (h, w) = (truth.height as usize, truth.width as usize);
    let flat: Vec<f32> = truth.xyz.iter().flatten().copied().collect();
    npy::write(&dir.join("xyz.npy"), &[h, w, 3], &flat)?;
    npy::write(&dir.join("material.npy"), &[h, w], &truth.material)?;
    npy::write(&dir.join("lit.npy"), &[h, w], &truth.lit)?;
    #[derive(serde::Serialize)]
    struct Names {
        materials: Vec<String>,
    }
    write_toml(
        &dir.join("materials.toml"),
        &Names {
            materials: scene.materials.iter().map(|m| m.name.clone()).collect(),
        },
    )
}
