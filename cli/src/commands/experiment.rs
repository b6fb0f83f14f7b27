//! `ris experiment completeness`: Table 7.1 of the text on a simulated scene — points per
//! material of a powder-sprayed reference, a naive fixed-exposure unmasked scan and the
//! adaptive-mask scan, all through the mock pair and the sequencer.

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;

use anyhow::{Context, Result};
use ris_core::cloud::PointCloud;
use ris_core::decode::{decode, DecodeParams};
use ris_core::pattern::CodeLayout;
use ris_core::sensor::Reconstructor;
use ris_core::sim::accuracy::evaluate_where;
use ris_core::sim::{Scene, Simulator};
use ris_drivers::adaptive::{adaptive_scan, AdaptiveParams};
use ris_drivers::mock::simulated_pair;
use ris_drivers::sequence::{acquire, SequenceParams};
use ris_drivers::Slide;
use serde::Serialize;

use crate::progress;

/// Figures of one material.
#[derive(Clone, Debug, Serialize)]
pub struct MaterialFigures {
    /// Points on the material's pixels, sprayed reference.
    pub sprayed: usize,
    /// Points of the naive scan.
    pub naive: usize,
    /// Points of the adaptive scan.
    pub adaptive: usize,
    /// naive / sprayed.
    pub naive_relative: f64,
    /// adaptive / sprayed.
    pub adaptive_relative: f64,
    /// Mean 3D error of the adaptive points against truth, mm.
    pub adaptive_mean_abs_error_mm: f64,
    /// The same for the sprayed reference (what the geometry alone costs).
    pub sprayed_mean_abs_error_mm: f64,
    /// Fraction of adaptive points off by more than 1 mm.
    pub adaptive_outliers: f64,
}

/// The experiment's result.
#[derive(Clone, Debug, Serialize)]
pub struct Completeness {
    /// Per material name.
    pub materials: BTreeMap<String, MaterialFigures>,
    /// Frames projected by the naive scan.
    pub naive_frames: u64,
    /// Frames projected by the adaptive scan (acquisition time at 60 Hz: frames / 60 s).
    pub adaptive_frames: u64,
    /// Exposure of the adaptive scan relative to the naive one.
    pub adaptive_exposure_factor: f64,
    /// Camera pixels whose crosstalk the advanced projection measured.
    pub adaptive_measured_fraction: f32,
}

/// Run the three scans of `scene_path` and compare them per material; with `out`, write the
/// three clouds, the adaptive capture set (with its mask) and the result there.
pub fn completeness(scene_path: &Path, out: Option<&Path>) -> Result<Completeness> {
    let scene = Scene::load(scene_path)
        .with_context(|| format!("reading scene {}", scene_path.display()))?;
    let params = DecodeParams::default();
    // The projector's layout (what `Simulator::layout` gives, without rendering a scene for it).
    let layout = CodeLayout::new(scene.projector.width, scene.projector.height);
    // The reference recording is made on a white board, whatever the table is.
    let board = Simulator::new(scene.sprayed().reference());
    let reference = decode(&board.capture(&layout, 1000, &|_, _| {}), &params)
        .context("decoding the reference recording")?;
    let rec = Reconstructor::parallax(&scene.camera, scene.projector.center(), &reference)
        .context("fitting the parallax model to the reference")?;
    let slides: Vec<Slide> = layout
        .sequence(true)
        .into_iter()
        .map(Slide::plain)
        .collect();
    let seq = SequenceParams::default();

    let mut clouds: Vec<PointCloud> = Vec::new();
    let mut naive_frames = 0;
    // The naive and the adaptive scans see the same scene: one renderer serves both.
    let naive = Arc::new(Simulator::new(scene.clone()));
    for (name, sim) in [
        ("sprayed", Arc::new(Simulator::new(scene.sprayed()))),
        ("naive", Arc::clone(&naive)),
    ] {
        let (mut cam, mut proj, _) = simulated_pair(sim, name, 1);
        let pb = progress::bar(slides.len() as u64, name);
        let acq = acquire(&mut cam, &mut proj, &layout, &slides, &seq, &mut |p| {
            pb.set_position(p.done as u64)
        })
        .with_context(|| format!("{name} scan"))?;
        pb.finish_and_clear();
        naive_frames = acq.report.shows;
        let dec =
            decode(&acq.capture, &params).with_context(|| format!("decoding the {name} scan"))?;
        clouds.push(rec.reconstruct(&dec)?);
        tracing::info!(
            run = name,
            points = clouds.last().map_or(0, |c| c.len()),
            "scan reconstructed"
        );
    }
    let truth = naive.cache.truth.clone();
    let (mut cam, mut proj, _) = simulated_pair(naive, "adaptive", 2);
    let pb = progress::bar(0, "adaptive");
    let scan = adaptive_scan(
        &mut cam,
        &mut proj,
        &layout,
        &reference,
        &AdaptiveParams::default(),
        &mut |step, p| {
            pb.set_message(step);
            pb.set_length(p.total as u64);
            pb.set_position(p.done as u64);
        },
    )
    .context("adaptive scan")?;
    pb.finish_and_clear();
    for s in &scan.steps {
        tracing::info!(step = s.step, frames = s.frames, "{}", s.detail);
    }
    let dec = decode(&scan.capture, &params).context("decoding the adaptive scan")?;
    let adaptive = rec.reconstruct(&dec)?;
    if let Some(dir) = out {
        ris_core::io::create_dir(dir)?;
        for (name, cloud) in [
            ("sprayed", &clouds[0]),
            ("naive", &clouds[1]),
            ("adaptive", &adaptive),
        ] {
            let path = dir.join(format!("{name}.ply"));
            cloud
                .write_ply(&path)
                .with_context(|| format!("writing {}", path.display()))?;
        }
        scan.capture
            .save(&dir.join("adaptive-capture"))
            .context("writing the adaptive capture")?;
    }

    let count = |cloud: &PointCloud, m: usize| {
        cloud
            .pixels
            .iter()
            .filter(|&&p| truth.material[p as usize] as usize == m)
            .count()
    };
    let mut materials = BTreeMap::new();
    for (m, mat) in scene.materials.iter().enumerate() {
        let sprayed = count(&clouds[0], m);
        let naive = count(&clouds[1], m);
        let ad = count(&adaptive, m);
        let on = |i: usize| truth.material[i] as usize == m;
        let acc = evaluate_where(&adaptive, &truth, 0.999, on);
        let acc_sprayed = evaluate_where(&clouds[0], &truth, 0.999, on);
        let rel = |n: usize| n as f64 / sprayed.max(1) as f64;
        materials.insert(
            mat.name.clone(),
            MaterialFigures {
                sprayed,
                naive,
                adaptive: ad,
                naive_relative: rel(naive),
                adaptive_relative: rel(ad),
                adaptive_mean_abs_error_mm: acc.mean_abs_error_mm,
                sprayed_mean_abs_error_mm: acc_sprayed.mean_abs_error_mm,
                adaptive_outliers: acc.outlier_fraction,
            },
        );
    }
    let result = Completeness {
        materials,
        naive_frames,
        adaptive_frames: scan.frames,
        adaptive_exposure_factor: scan.exposure_factor,
        adaptive_measured_fraction: scan.measured_fraction,
    };
    if let Some(dir) = out {
        let path = dir.join("completeness.json");
        ris_core::io::write_atomic(&path, serde_json::to_string_pretty(&result)?.as_bytes())
            .with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(result)
}

/// Print the result as a table.
pub fn print_table(c: &Completeness) {
    println!(
        "{:<14} {:>9} {:>9} {:>9} {:>9} {:>9} {:>12} {:>12}",
        "material", "sprayed", "naive", "adaptive", "naive %", "adapt. %", "|err| mm", "sprayed mm"
    );
    for (name, f) in &c.materials {
        println!(
            "{:<14} {:>9} {:>9} {:>9} {:>8.1}% {:>8.1}% {:>12.4} {:>12.4}",
            name,
            f.sprayed,
            f.naive,
            f.adaptive,
            100.0 * f.naive_relative,
            100.0 * f.adaptive_relative,
            f.adaptive_mean_abs_error_mm,
            f.sprayed_mean_abs_error_mm
        );
    }
    println!(
        "frames: naive {}, adaptive {} ({:.2} s at 60 Hz); adaptive exposure ×{:.2}, crosstalk measured on {:.1} % of the camera",
        c.naive_frames,
        c.adaptive_frames,
        c.adaptive_frames as f64 / 60.0,
        c.adaptive_exposure_factor,
        100.0 * c.adaptive_measured_fraction
    );
}

/// One speed of the motion experiment.
#[derive(Clone, Debug, Serialize)]
pub struct MotionRow {
    /// Part speed, mm/s.
    pub speed_mm_s: f64,
    /// How far the part travels during the Gray-code sequence, mm.
    pub gray_travel_mm: f64,
    /// Gray-code scan: points.
    pub gray_points: usize,
    /// Gray-code scan: mean |error| against the part at the sequence's middle, mm.
    pub gray_mean_abs_mm: f64,
    /// Gray-code scan: points within 1 mm of the part at the sequence's middle.
    pub gray_within_1mm: usize,
    /// Single-shot frame: points.
    pub single_points: usize,
    /// Single-shot frame: mean |error| against the part at the frame's time, mm.
    pub single_mean_abs_mm: f64,
    /// Single-shot frame: points within 1 mm.
    pub single_within_1mm: usize,
}

/// The motion experiment's set-up and result.
#[derive(Clone, Debug, Serialize)]
pub struct Motion {
    /// Frames per second of the Gray-code sequence.
    pub fps: f64,
    /// Exposure per frame, ms.
    pub exposure_ms: f64,
    /// Frames of the Gray-code sequence.
    pub gray_frames: usize,
    /// Direction of motion (unit).
    pub direction: [f64; 3],
    /// One row per speed.
    pub rows: Vec<MotionRow>,
}

/// Ch. 7.1.2's argument, measured: the objects of `scene_path` (all but the reference plane)
/// move at each of `speeds` (mm/s) along `direction`; a Gray-code scan (frame k exposed at
/// k / fps) and one single-shot frame are reconstructed through the parallax model of the
/// still reference, and compared with where the part is.
pub fn motion(
    scene_path: &Path,
    speeds: &[f64],
    direction: [f64; 3],
    fps: f64,
    exposure_ms: f64,
) -> Result<Motion> {
    use ris_core::pattern::{Pattern, ProjectionMask};
    use ris_core::sim::motion::{
        capture_at_frame_times, depth_errors, frame_at, sequence_span, Timing,
    };
    use ris_core::single_shot::{self, ReferencePrediction, XPointPattern};

    anyhow::ensure!(
        fps.is_finite() && fps > 0.0,
        "--fps {fps}: a positive number of frames per second"
    );
    anyhow::ensure!(
        exposure_ms.is_finite() && exposure_ms > 0.0 && exposure_ms * fps <= 1000.0,
        "--exposure-ms {exposure_ms}: positive and at most one frame period ({:.1} ms)",
        1000.0 / fps
    );
    anyhow::ensure!(
        !speeds.is_empty() && speeds.iter().all(|s| s.is_finite() && *s >= 0.0),
        "--speeds: non-negative speeds in mm/s"
    );
    let norm = direction.iter().map(|d| d * d).sum::<f64>().sqrt();
    anyhow::ensure!(
        norm > 0.0 && norm.is_finite(),
        "--direction: a non-zero vector"
    );
    let dir = nalgebra::Vector3::new(direction[0], direction[1], direction[2]) / norm;
    let scene = Scene::load(scene_path)
        .with_context(|| format!("reading scene {}", scene_path.display()))?;
    let params = DecodeParams::default();
    let board = Simulator::new(scene.sprayed().reference());
    let layout = board.layout();
    let reference = decode(&board.capture(&layout, 1000, &|_, _| {}), &params)
        .context("decoding the reference recording")?;
    let rec = Reconstructor::parallax(&scene.camera, scene.projector.center(), &reference)
        .context("fitting the parallax model to the reference")?;
    let predict = ReferencePrediction::new(&reference)
        .context("the reference has no row codes (the scene needs rows = true)")?;
    let at = |x: f64, y: f64| predict.at(x, y);
    let xpoint = XPointPattern::generate(layout.width, layout.height, [14, 14], 3, 1)?;
    let picture = ProjectionMask::picture(layout.width, layout.height, &xpoint.render());
    let timing = Timing {
        fps,
        exposure_s: exposure_ms / 1000.0,
    };
    let span = sequence_span(&scene, &layout, timing);
    let frames = layout.sequence(scene.render.rows).len();
    let pb = progress::bar((speeds.len() * (frames + 1)) as u64, "motion");
    let summary = |e: &[f64]| {
        let finite: Vec<f64> = e.iter().copied().filter(|v| v.is_finite()).collect();
        let mean = finite.iter().map(|v| v.abs()).sum::<f64>() / finite.len().max(1) as f64;
        (mean, finite.iter().filter(|v| v.abs() <= 1.0).count())
    };
    let mut rows = Vec::new();
    let mut detector = single_shot::Detector::new(
        single_shot::camera_spacing(&reference, xpoint.finest_step()).map_or_else(
            single_shot::DetectParams::default,
            single_shot::DetectParams::for_spacing,
        ),
    );
    for &speed in speeds {
        let mut moving = scene.clone();
        for o in &mut moving.objects {
            if !matches!(o.shape, ris_core::sim::Shape::Plane) {
                o.velocity = dir * speed;
            }
        }
        pb.set_message(format!("{speed} mm/s"));
        let capture = capture_at_frame_times(&moving, &layout, timing, 7, &|_, _| pb.inc(1));
        let gray = rec
            .reconstruct(&decode(&capture, &params).context("decoding the moving scan")?)
            .context("reconstructing the moving scan")?;
        let (gray_mean, gray_good) = summary(&depth_errors(&moving.at(span / 2.0), &gray));
        let image = frame_at(
            &moving,
            &layout,
            Pattern::White,
            Some(&picture),
            0.0,
            timing.exposure_s,
            9,
        );
        pb.inc(1);
        let single = single_shot::measure(&mut detector, &image, &xpoint, Some(&at), &rec).cloud;
        let (single_mean, single_good) = summary(&depth_errors(&moving.at(0.0), &single));
        tracing::info!(speed, gray_mean, single_mean, "motion");
        rows.push(MotionRow {
            speed_mm_s: speed,
            gray_travel_mm: speed * span,
            gray_points: gray.len(),
            gray_mean_abs_mm: gray_mean,
            gray_within_1mm: gray_good,
            single_points: single.len(),
            single_mean_abs_mm: single_mean,
            single_within_1mm: single_good,
        });
    }
    pb.finish_and_clear();
    Ok(Motion {
        fps,
        exposure_ms,
        gray_frames: frames,
        direction: [dir.x, dir.y, dir.z],
        rows,
    })
}

/// Print the motion experiment as a table.
pub fn print_motion(m: &Motion) {
    println!(
        "{} Gray-code frames at {} fps ({} ms exposure) against one single-shot frame; motion along ({:.2}, {:.2}, {:.2})",
        m.gray_frames, m.fps, m.exposure_ms, m.direction[0], m.direction[1], m.direction[2]
    );
    println!(
        "{:>8} {:>9} | {:>8} {:>10} {:>9} | {:>8} {:>10} {:>9}",
        "mm/s", "travel", "gray pts", "mean |e|", "<= 1 mm", "ss pts", "mean |e|", "<= 1 mm"
    );
    for r in &m.rows {
        println!(
            "{:>8.1} {:>7.1}mm | {:>8} {:>8.3}mm {:>9} | {:>8} {:>8.3}mm {:>9}",
            r.speed_mm_s,
            r.gray_travel_mm,
            r.gray_points,
            r.gray_mean_abs_mm,
            r.gray_within_1mm,
            r.single_points,
            r.single_mean_abs_mm,
            r.single_within_1mm
        );
    }
}
