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

pub use light::{BlurredMask, Light};
pub use render::{RenderCache, Truth};
pub use scene::{
    CalibrationSection, Material, MaterialSection, ObjectSection, PanelWear, RenderSection, Scene,
    SceneFile, SimCamera, SimProjector, WearSection,
};
pub use session::{simulate_session, SessionOutput};
pub use shapes::{Object, Shape};
pub use texture::Texture;

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, PoisonError};

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
    /// The last projection mask shown, blurred at each σ a frame asked for: a scan shows one
    /// mask under every pattern, and its blur costs more than the frame.
    masks: Mutex<Option<MaskBlurs>>,
}

/// A projection mask and its blurred versions, by σ.
struct MaskBlurs {
    mask: ProjectionMask,
    blurred: Vec<(f32, Arc<BlurredMask>)>,
}

impl Simulator {
    /// Ray-cast `scene` once.
    pub fn new(scene: Scene) -> Simulator {
        let cache = RenderCache::build(&scene);
        Simulator::with_cache(scene, cache)
    }

    /// `scene` with its render cache built earlier ([`RenderCache::build`] of the same scene,
    /// e.g. kept on disk with [`RenderCache::to_bytes`]).
    pub fn with_cache(scene: Scene, cache: RenderCache) -> Simulator {
        Simulator {
            scene,
            cache,
            masks: Mutex::new(None),
        }
    }

    /// `mask` blurred by `sigma`, from the cache when the last mask shown was the same.
    fn blurred_mask(&self, mask: &ProjectionMask, sigma: f32) -> Arc<BlurredMask> {
        let lock = || self.masks.lock().unwrap_or_else(PoisonError::into_inner);
        if let Some(c) = lock().as_ref().filter(|c| c.mask == *mask) {
            if let Some((_, b)) = c.blurred.iter().find(|(s, _)| *s == sigma) {
                return Arc::clone(b);
            }
        }
        // Blurred (in parallel) outside the lock: a thread outside the rayon pool waiting
        // there on workers that wait on the lock would never finish.
        let b = Arc::new(BlurredMask::new(mask, sigma));
        let mut cached = lock();
        if cached.as_ref().is_some_and(|c| c.mask != *mask) {
            *cached = None;
        }
        let c = cached.get_or_insert_with(|| MaskBlurs {
            mask: mask.clone(),
            blurred: Vec::new(),
        });
        if !c.blurred.iter().any(|(s, _)| *s == sigma) {
            c.blurred.push((sigma, Arc::clone(&b)));
        }
        b
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
            Some(m) => light.with_mask(self.blurred_mask(m, sigma)),
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
    /// The camera's view of the picture asked for (`shown.png`), when one was.
    pub shown: Option<PathBuf>,
}

/// Render `scene` into `out`: `capture/`, `reference/`, `sensor.toml`, `truth/` and, with
/// `show` (a projector picture as a mask under full white), the camera's view of it,
/// `shown.png`, from the same ray cast. Everything is written into a temporary sibling
/// directory first and renamed into place at the end.
pub fn simulate(
    scene: &Scene,
    out: &Path,
    show: Option<&ProjectionMask>,
    progress: &(dyn Fn(&str, usize, usize) + Sync),
) -> Result<SimOutput> {
    write_dir_atomically(out, |tmp| write_simulation(scene, tmp, show, progress))?;
    Ok(SimOutput {
        capture: out.join("capture"),
        reference: out.join("reference"),
        sensor: out.join("sensor.toml"),
        truth: out.join("truth"),
        shown: show.map(|_| out.join("shown.png")),
    })
}

fn write_simulation(
    scene: &Scene,
    dir: &Path,
    show: Option<&ProjectionMask>,
    progress: &(dyn Fn(&str, usize, usize) + Sync),
) -> Result<()> {
    create_dir(dir)?;
    let sim = Simulator::new(scene.clone());
    let layout = sim.layout();
    sim.capture(&layout, 0, &|i, n| progress("capture", i, n))
        .save(&dir.join("capture"))?;
    if let Some(mask) = show {
        sim.frame_with(&layout, Pattern::White, Some(mask), 1.0, 1)
            .save_png(&dir.join("shown.png"))?;
    }
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A frame under a mask is the same whether its blur came from the cache or not, and a
    /// changed mask is blurred anew.
    /// A small scene with inter-reflection (so every table of the cache is filled).
    pub(super) fn small_scene() -> Scene {
        let text = r#"
[camera]
width = 80
height = 60
k = [[178.0, 0.0, 39.5], [0.0, 178.0, 29.5], [0.0, 0.0, 1.0]]
r = [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]
t = [0.0, 0.0, 1600.0]
[projector]
width = 128
height = 96
k = [[225.0, 0.0, 63.5], [0.0, 225.0, 47.5], [0.0, 0.0, 1.0]]
r = [[0.954479978035, 0.0, -0.298274993136], [0.0, -1.0, 0.0], [-0.298274993136, 0.0, -0.954479978035]]
t = [0.0, 0.0, 1676.305461424]
[material.m]
albedo = 0.6
interreflection = 0.3
interreflection_radius = 20.0
[[object]]
shape = "plane"
material = "m"
"#;
        let file: SceneFile = toml::from_str(text).expect("toml");
        Scene::from_file(file, Path::new("."), "test").expect("scene")
    }

    /// A render cache kept as bytes renders the same frames and truth as the one built; damaged
    /// bytes are refused.
    #[test]
    fn render_caches_survive_their_bytes() {
        let scene = small_scene();
        let built = Simulator::new(scene.clone());
        let bytes = built.cache.to_bytes();
        let back = RenderCache::from_bytes(&bytes).expect("read back");
        assert!(!back.bounce_sigmas.is_empty() && bytes.len() > 80 * 60 * 40);
        let kept = Simulator::with_cache(scene, back);
        let layout = built.layout();
        for (i, p) in layout.sequence(true).into_iter().enumerate().take(6) {
            assert!(built.frame(&layout, p, i as u64) == kept.frame(&layout, p, i as u64));
        }
        let bits = |t: &Truth| {
            t.xyz
                .iter()
                .flatten()
                .map(|x| x.to_bits())
                .collect::<Vec<_>>()
        };
        assert_eq!(bits(&built.cache.truth), bits(&kept.cache.truth));
        for cut in [0, 5, bytes.len() / 2, bytes.len() - 1] {
            assert!(
                RenderCache::from_bytes(&bytes[..cut]).is_none(),
                "cut {cut}"
            );
        }
        let mut longer = bytes.clone();
        longer.push(0);
        assert!(RenderCache::from_bytes(&longer).is_none());
    }

    #[test]
    fn masked_frames_do_not_depend_on_the_masks_shown_before() {
        let scene = small_scene();
        let layout = CodeLayout::new(128, 96);
        let mask = |k: usize| ProjectionMask {
            width: 128,
            height: 96,
            values: (0..128 * 96)
                .map(|i| {
                    if (i % 128) / 16 % 2 == k % 2 {
                        1.0
                    } else {
                        0.25
                    }
                })
                .collect(),
        };
        let (a, b) = (mask(0), mask(1));
        let shown = Simulator::new(scene.clone());
        let fresh = |m: &ProjectionMask, f: u64| {
            Simulator::new(scene.clone()).frame_with(&layout, Pattern::White, Some(m), 1.0, f)
        };
        for (f, m) in [(1, &a), (2, &a), (3, &b), (4, &a)] {
            let frame = shown.frame_with(&layout, Pattern::White, Some(m), 1.0, f);
            assert!(frame == fresh(m, f), "frame {f}");
        }
        let one = shown.frame_with(&layout, Pattern::White, Some(&a), 1.0, 5);
        let other = shown.frame_with(&layout, Pattern::White, Some(&b), 1.0, 5);
        assert!(one != other, "the two masks light the plane alike");
    }
}
