//! `ris omni`: decode a ring-pattern image into the 360° cloud and panorama, or (`--analyse`)
//! the omnidirectional sensor's resolution and depth error (Sec. 6.3) for wall points at given
//! ranges and heights.

use std::path::Path;

use anyhow::{Context, Result};
use ris_core::image::GrayImage;
use ris_core::omni::{
    analyse, panorama, ErrorPoint, OmniSensor, RingDecoder, RingParams, RingPattern,
};
use ris_core::single_shot::FusionRange;
use serde::Serialize;

/// What `ris omni IMAGE` did.
#[derive(Clone, Debug, Serialize)]
pub struct DecodeSummary {
    /// Points written.
    pub points: usize,
    /// Ring crossings found on the radial lines.
    pub crossings: usize,
    /// Arcs of linked crossings, and how many were named a ring.
    pub arcs: usize,
    /// Arcs named.
    pub arcs_named: usize,
    /// Crossings left out because their ring could not be told from others.
    pub ambiguous: usize,
    /// Seconds to decode and to triangulate.
    pub decode_s: f64,
    /// Seconds to triangulate.
    pub reconstruct_s: f64,
    /// Elevation of the panorama's top and bottom rows, degrees (when written).
    pub panorama_elevation_deg: Option<[f64; 2]>,
    /// Width of the panorama's unrolled image, pixels: column x looks along azimuth
    /// 360° · (x + 0.5) / width (the colour bar is right of it).
    pub panorama_width: Option<u32>,
    /// The cloud's path.
    pub cloud: String,
}

impl DecodeSummary {
    /// One line for people.
    pub fn line(&self) -> String {
        format!(
            "{} points from {} ring crossings ({} of {} arcs named, {} crossings left out as ambiguous) in {:.0} ms + {:.0} ms -> {}{}",
            self.points,
            self.crossings,
            self.arcs_named,
            self.arcs,
            self.ambiguous,
            1e3 * self.decode_s,
            1e3 * self.reconstruct_s,
            self.cloud,
            self.panorama_elevation_deg
                .map_or(String::new(), |[a, b]| format!(
                    "; panorama rows from {a:.1}° (top) to {b:.1}° (bottom) elevation"
                )),
        )
    }
}

/// Decode the ring pattern in `image` seen by `sensor`; write the cloud to `out` and, if asked,
/// the panorama coloured by `range`. `depth` bounds the kept points' distance from the camera.
pub fn decode_file(
    sensor: &Path,
    pattern: Option<&Path>,
    image: &Path,
    out: &Path,
    panorama_path: Option<&Path>,
    range: FusionRange,
    depth: [f64; 2],
) -> Result<DecodeSummary> {
    let s = OmniSensor::load(sensor)
        .with_context(|| format!("reading sensor file {}", sensor.display()))?;
    let rings = match pattern {
        Some(p) => ris_core::io::read_toml::<RingPattern>(p)
            .with_context(|| format!("reading ring pattern {}", p.display()))?,
        None => s
            .rings()
            .with_context(|| format!("designing rings for {}", sensor.display()))?,
    };
    let img =
        GrayImage::load(image).with_context(|| format!("reading image {}", image.display()))?;
    let params = RingParams {
        range_mm: depth,
        ..RingParams::default()
    };
    let decoder = RingDecoder::new(&s, &rings, params)
        .with_context(|| format!("preparing the ring decoder for {}", sensor.display()))?;
    let decoded = decoder
        .decode(&img)
        .with_context(|| format!("decoding {}", image.display()))?;
    let cloud = decoded.cloud();
    cloud
        .write_ply(out)
        .with_context(|| format!("writing {}", out.display()))?;
    let (mut elevation, mut width) = (None, None);
    if let Some(p) = panorama_path {
        let pano = panorama(&s, &decoder, &img, &decoded, range)
            .with_context(|| format!("unrolling {}", image.display()))?;
        pano.fused
            .save(p)
            .with_context(|| format!("writing {}", p.display()))?;
        elevation = Some(pano.elevation_deg);
        width = Some(pano.width);
    }
    Ok(DecodeSummary {
        points: decoded.points.len(),
        crossings: decoded.peaks,
        arcs: decoded.arcs,
        arcs_named: decoded.arcs_named,
        ambiguous: decoded.ambiguous.len(),
        decode_s: decoded.decode_s,
        reconstruct_s: decoded.reconstruct_s,
        panorama_elevation_deg: elevation,
        panorama_width: width,
        cloud: out.display().to_string(),
    })
}

/// Analyse the sensor file at `sensor` for `ranges` × `heights` (mm).
pub fn analyse_file(sensor: &Path, ranges: &[f64], heights: &[f64]) -> Result<Vec<ErrorPoint>> {
    anyhow::ensure!(
        !ranges.is_empty() && ranges.iter().all(|r| r.is_finite() && *r > 0.0),
        "--ranges: positive distances in mm"
    );
    anyhow::ensure!(
        !heights.is_empty() && heights.iter().all(|h| h.is_finite()),
        "--heights: heights in mm"
    );
    let s = OmniSensor::load(sensor)
        .with_context(|| format!("reading sensor file {}", sensor.display()))?;
    analyse(&s, ranges, heights).with_context(|| format!("analysing {}", sensor.display()))
}

/// Heights FROM,TO,STEP (mm) as a list.
pub fn heights(spec: &str) -> Result<Vec<f64>> {
    let v: Vec<f64> = spec
        .split(',')
        .map(|t| t.trim().parse::<f64>())
        .collect::<std::result::Result<_, _>>()
        .with_context(|| format!("--heights {spec:?}: expected FROM,TO,STEP in mm"))?;
    let [from, to, step] = v[..] else {
        anyhow::bail!("--heights {spec:?}: expected FROM,TO,STEP in mm");
    };
    anyhow::ensure!(
        from.is_finite()
            && to.is_finite()
            && step.is_finite()
            && step > 0.0
            && (to - from) / step <= 10_000.0,
        "--heights {spec:?}: a positive STEP and at most 10000 heights"
    );
    let n = ((to - from) / step).floor().max(0.0) as usize;
    Ok((0..=n).map(|k| from + k as f64 * step).collect())
}

/// The analysis as a table.
pub fn print(points: &[ErrorPoint]) {
    println!(
        "{:>8} {:>8} {:>9} {:>9} | {:>10} {:>10} | {:>10} {:>10} {:>10}",
        "range", "height", "elev.", "radius", "camera", "projector", "Δd cam", "Δd proj", "Δd"
    );
    println!(
        "{:>8} {:>8} {:>9} {:>9} | {:>10} {:>10} | {:>10} {:>10} {:>10}",
        "mm", "mm", "deg", "px", "mm/px", "mm/px", "mm", "mm", "mm"
    );
    for p in points {
        println!(
            "{:>8.0} {:>8.0} {:>9.1} {:>9.1} | {:>10.1} {:>10.1} | {:>10.1} {:>10.1} {:>10.1}",
            p.range_mm,
            p.height_mm,
            p.elevation_deg,
            p.camera_radius_px,
            p.camera_mm_per_px,
            p.projector_mm_per_px,
            p.depth_error_camera_mm,
            p.depth_error_projector_mm,
            p.depth_error_mm
        );
    }
}
