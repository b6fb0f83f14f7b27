//! `ris single-shot`: one camera image of the X-point pattern + the sensor file → a cloud in
//! the sensor world frame (the same frame as the sensor's multi-shot clouds).

use std::path::Path;
use std::time::Instant;

use anyhow::{Context, Result};
use ris_core::capture::CaptureSet;
use ris_core::cloud::PointCloud;
use ris_core::decode::{decode, DecodeParams};
use ris_core::image::GrayImage;
use ris_core::sensor::{ModelChoice, Reconstructor, Sensor};
use ris_core::single_shot::{self, DetectParams, FusionRange, ReferencePrediction, XPointPattern};

/// Decode `image` (the X-point pattern of `pattern` seen by `sensor`'s camera) and write the
/// cloud to `out`; returns it. The sensor's Gray-code reference recording predicts where each
/// X-point lies in the projector, which picks the code's repeat. `fused` also writes the
/// fusion picture there, coloured over the given range (or one covering the points).
pub fn run(
    sensor: &Path,
    pattern: &Path,
    image: &Path,
    out: &Path,
    fused: Option<(&Path, Option<FusionRange>)>,
) -> Result<PointCloud> {
    let s = Sensor::load(sensor)
        .with_context(|| format!("reading sensor file {}", sensor.display()))?;
    let pattern = XPointPattern::load(pattern)
        .with_context(|| format!("reading pattern file {}", pattern.display()))?;
    if (pattern.pattern.width, pattern.pattern.height) != s.projector_size {
        anyhow::bail!(
            "{}: the pattern is for a {}x{} projector, the sensor's is {}x{}",
            image.display(),
            pattern.pattern.width,
            pattern.pattern.height,
            s.projector_size.0,
            s.projector_size.1
        );
    }
    let reference_dir = s.reference.as_ref().with_context(|| {
        format!(
            "{}: single-shot decoding needs the sensor's [reference] recording (it predicts each X-point's place in the projector)",
            sensor.display()
        )
    })?;
    let params = DecodeParams::default();
    let t = Instant::now();
    let rec = Reconstructor::new(&s, ModelChoice::Auto, &params)
        .with_context(|| format!("preparing sensor {}", sensor.display()))?;
    let reference = decode(
        &CaptureSet::load(reference_dir)
            .with_context(|| format!("reading {}", reference_dir.display()))?,
        &params,
    )
    .with_context(|| format!("decoding {}", reference_dir.display()))?;
    let predict = ReferencePrediction::new(&reference).with_context(|| {
        format!(
            "{}: the reference recording has no row codes, which single-shot decoding needs",
            reference_dir.display()
        )
    })?;
    let spacing = single_shot::camera_spacing(&reference, pattern.finest_step());
    if let Some(spacing) = spacing {
        if spacing[0].min(spacing[1]) < single_shot::MIN_CAMERA_SPACING {
            eprintln!(
                "warning: the X-points lie {:.1} × {:.1} camera pixels apart; the detector needs {} or more, and finds few or none",
                spacing[0],
                spacing[1],
                single_shot::MIN_CAMERA_SPACING
            );
        }
    }
    let prepare = t.elapsed();
    let img = GrayImage::load(image).with_context(|| format!("reading {}", image.display()))?;
    if (img.width, img.height) != (s.camera.width, s.camera.height) {
        anyhow::bail!(
            "{}: the image is {}x{}, the sensor's camera {}x{}",
            image.display(),
            img.width,
            img.height,
            s.camera.width,
            s.camera.height
        );
    }
    let at = |x: f64, y: f64| predict.at(x, y);
    let m = single_shot::measure(
        &mut single_shot::Detector::new(
            spacing.map_or_else(DetectParams::default, DetectParams::for_spacing),
        ),
        &img,
        &pattern,
        Some(&at),
        &rec,
    );
    let cloud = &m.cloud;
    tracing::info!(stats = ?m.stats, "single-shot decoding");
    cloud
        .write_ply(out)
        .with_context(|| format!("writing {}", out.display()))?;
    if let Some((path, range)) = fused {
        let c = rec.camera().center();
        let eye = [c.x, c.y, c.z];
        let range = range.unwrap_or_else(|| FusionRange::covering(cloud, eye));
        let picture = single_shot::fuse(&img, cloud, eye, range, None)
            .with_context(|| format!("fusing {}", image.display()))?;
        picture
            .save(path)
            .with_context(|| format!("writing {}", path.display()))?;
        println!(
            "fusion picture {}: {:.0}-{:.0} mm red to blue, {} pixels coloured (radius {:.1} px)",
            path.display(),
            range.near,
            range.far,
            picture.coloured,
            picture.radius
        );
    }
    println!(
        "{} points from {} X-points ({} gaps between primitives set aside; {} by their codeword, {} from a neighbour; {} codewords read, {} matched; {} dropped as cut by an edge, {} moved back from a cut, {} refused off the grid, {} confirmed by one neighbour only, {} disturbed inner corners, {} read across a depth edge, {} one step over that the code cannot tell across an edge, {} cut well inside their neighbours' line; {} beside an edge or a shadow at half confidence, where a cut primitive can be 2-3 mm off); prepare {:.0} ms, decode + reconstruct {:.0} ms; wrote {}",
        cloud.len(),
        m.detected,
        m.stats.gaps,
        m.from_codeword,
        m.stats.propagated,
        m.stats.windows,
        m.stats.matched,
        m.stats.cut,
        m.stats.recentred,
        m.stats.off_grid,
        m.stats.lone,
        m.stats.disturbed,
        m.stats.spliced,
        m.stats.undecided,
        m.stats.kinked,
        m.at_boundary,
        prepare.as_secs_f64() * 1e3,
        (m.decode_s + m.reconstruct_s) * 1e3,
        out.display()
    );
    Ok(m.cloud)
}
