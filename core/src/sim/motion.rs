//! Moving parts (Ch. 7.1.2): every frame rendered at its own time, integrated over its
//! exposure, so a multi-shot scan of a moving part smears across its patterns while a single
//! frame does not; and the error of a cloud against the surface at a given time.

use rayon::prelude::*;

use super::{Scene, Simulator};
use crate::capture::CaptureSet;
use crate::cloud::PointCloud;
use crate::image::GrayImage;
use crate::pattern::{CodeLayout, Pattern, ProjectionMask};

/// When frames are taken.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Timing {
    /// Frames per second of the projector–camera sequence.
    pub fps: f64,
    /// Exposure of each frame, s.
    pub exposure_s: f64,
}

/// Most sub-frames one exposure is integrated from.
const MAX_SUBFRAMES: usize = 6;
/// Displacement within one exposure above which it is split into sub-frames, mm.
const SUBFRAME_TRAVEL: f64 = 0.25;

/// Sub-frames an exposure of `scene` needs: one per 0.25 mm that its fastest object travels.
fn subframes(scene: &Scene, exposure_s: f64) -> usize {
    let fastest = scene
        .objects
        .iter()
        .map(|o| o.velocity.norm())
        .fold(0.0, f64::max);
    ((fastest * exposure_s / SUBFRAME_TRAVEL).ceil() as usize).clamp(1, MAX_SUBFRAMES)
}

/// The camera frame of `pattern` (under `mask`) exposed around time `t` (s): the mean of
/// frames rendered at evenly spaced times across the exposure (their noise averages down by
/// the square root of their number). `seed` varies the noise.
pub fn frame_at(
    scene: &Scene,
    layout: &CodeLayout,
    pattern: Pattern,
    mask: Option<&ProjectionMask>,
    t: f64,
    exposure_s: f64,
    seed: u64,
) -> GrayImage {
    let n = subframes(scene, exposure_s);
    let frames: Vec<GrayImage> = (0..n)
        .map(|i| {
            let ti = t + exposure_s * ((i as f64 + 0.5) / n as f64 - 0.5);
            Simulator::new(scene.at(ti)).frame_with(
                layout,
                pattern,
                mask,
                1.0,
                seed.wrapping_mul(31).wrapping_add(i as u64),
            )
        })
        .collect();
    if n == 1 {
        return frames
            .into_iter()
            .next()
            .unwrap_or_else(|| GrayImage::from_u8(0, 0, Vec::new()));
    }
    let (w, h) = (frames[0].width, frames[0].height);
    let mut sum = vec![0f32; (w * h) as usize];
    for f in &frames {
        for (s, v) in sum.iter_mut().zip(f.to_levels()) {
            *s += v;
        }
    }
    GrayImage::from_u8(
        w,
        h,
        sum.iter()
            .map(|s| (s / n as f32).round().clamp(0.0, 255.0) as u8)
            .collect(),
    )
}

/// The Gray-code sequence of `layout` (SPEC §3 order, rows as the scene says) with frame `k`
/// exposed at `k / fps`; `progress(done, total)` per frame.
pub fn capture_at_frame_times(
    scene: &Scene,
    layout: &CodeLayout,
    timing: Timing,
    seed: u64,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> CaptureSet {
    let patterns = layout.sequence(scene.render.rows);
    let mut set = CaptureSet::new(*layout, scene.camera.width, scene.camera.height);
    // Nothing moves: one ray cast serves every frame (the frames are those of `frame_at`).
    let still = (!scene.moving()).then(|| Simulator::new(scene.at(0.0)));
    for (k, p) in patterns.iter().enumerate() {
        let t = k as f64 / timing.fps;
        let frame = match &still {
            Some(sim) => sim.frame_with(layout, *p, None, 1.0, (seed + k as u64).wrapping_mul(31)),
            None => frame_at(
                scene,
                layout,
                *p,
                None,
                t,
                timing.exposure_s,
                seed + k as u64,
            ),
        };
        set.frames.insert(*p, frame);
        progress(k + 1, patterns.len());
    }
    set.meta.insert(
        "source".into(),
        toml::Value::String("ris simulate (moving)".into()),
    );
    set
}

/// Seconds from the first to the last frame of `layout`'s sequence for `scene`.
pub fn sequence_span(scene: &Scene, layout: &CodeLayout, timing: Timing) -> f64 {
    (layout.sequence(scene.render.rows).len().saturating_sub(1)) as f64 / timing.fps
}

/// For each point of `cloud` (the scene's world frame), its distance along the camera's ray
/// to the surface `scene` has there (positive: behind it); NaN where the ray meets nothing.
pub fn depth_errors(scene: &Scene, cloud: &PointCloud) -> Vec<f64> {
    let oc = scene.camera.center();
    cloud
        .points
        .par_iter()
        .map(|p| {
            let p = nalgebra::Vector3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
            let along = p - oc;
            let range = along.norm();
            if range < 1e-9 {
                return f64::NAN;
            }
            let d = along / range;
            scene
                .intersect(&oc, &d, 1e-6, f64::INFINITY)
                .map_or(f64::NAN, |(t, _, _)| range - t)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scene(velocity: [f64; 3]) -> Scene {
        let text = format!(
            r#"
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
[[object]]
shape = "plane"
material = "m"
[[object]]
shape = "box"
center = [0.0, 0.0, 50.0]
size = [200.0, 200.0, 100.0]
material = "m"
velocity = [{}, {}, {}]
"#,
            velocity[0], velocity[1], velocity[2]
        );
        let file: super::super::SceneFile = toml::from_str(&text).expect("toml");
        Scene::from_file(file, std::path::Path::new("."), "test").expect("scene")
    }

    #[test]
    fn a_moving_box_is_where_its_velocity_puts_it() {
        let s = scene([0.0, 0.0, 20.0]);
        assert!(s.moving());
        let cloud = PointCloud {
            points: vec![[0.0, 0.0, 100.0], [0.0, 0.0, 120.0]],
            ..Default::default()
        };
        // At t = 0 the top is at z = 100; one second later at z = 120.
        let e0 = depth_errors(&s.at(0.0), &cloud);
        let e1 = depth_errors(&s.at(1.0), &cloud);
        assert!(e0[0].abs() < 1e-6 && (e0[1] + 20.0).abs() < 1e-6, "{e0:?}");
        assert!((e1[0] - 20.0).abs() < 1e-6 && e1[1].abs() < 1e-6, "{e1:?}");
        assert_eq!(subframes(&s, 0.005), 1);
        assert_eq!(subframes(&scene([0.0, 200.0, 0.0]), 0.005), 4);
        assert_eq!(subframes(&scene([0.0, 1e5, 0.0]), 0.005), MAX_SUBFRAMES);
    }

    /// A still scene's sequence is rendered from one ray cast; its frames are those that
    /// `frame_at` renders one by one.
    #[test]
    fn a_still_scene_renders_the_frames_of_frame_at() {
        let s = scene([0.0; 3]);
        assert!(!s.moving());
        let layout = CodeLayout::new(s.projector.width, s.projector.height);
        let timing = Timing {
            fps: 60.0,
            exposure_s: 0.005,
        };
        let set = capture_at_frame_times(&s, &layout, timing, 7, &|_, _| {});
        let patterns = layout.sequence(s.render.rows);
        assert_eq!(set.frames.len(), patterns.len());
        for (k, p) in patterns.iter().enumerate() {
            let one = frame_at(&s, &layout, *p, None, k as f64 / 60.0, 0.005, 7 + k as u64);
            assert!(set.frames[p] == one, "frame {k} ({p:?}) differs");
        }
    }

    #[test]
    fn a_plane_cannot_move() {
        let text = "[camera]\nwidth = 8\nheight = 6\nk = [[17.0, 0.0, 3.5], [0.0, 17.0, 2.5], [0.0, 0.0, 1.0]]\nr = [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]\nt = [0.0, 0.0, 1600.0]\n[projector]\nwidth = 8\nheight = 6\nk = [[17.0, 0.0, 3.5], [0.0, 17.0, 2.5], [0.0, 0.0, 1.0]]\nr = [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]\nt = [100.0, 0.0, 1600.0]\n[material.m]\nalbedo = 0.6\n[[object]]\nshape = \"plane\"\nmaterial = \"m\"\nvelocity = [1.0, 0.0, 0.0]\n";
        let file: super::super::SceneFile = toml::from_str(text).expect("toml");
        let e = Scene::from_file(file, std::path::Path::new("."), "test").expect_err("refused");
        assert!(e.to_string().contains("velocity"), "{e}");
    }
}
