//! Single-shot points in the sensor's frame: each decoded X-point through the sensor model
//! (parallax with the Gray-code reference, or classical), so single-shot and multi-shot clouds
//! of one sensor land in the same frame; and the prediction the decoder needs, from the decoded
//! reference recording.

use rayon::prelude::*;

use super::Correspondence;
use crate::cloud::PointCloud;
use crate::decode::Decoded;
use crate::sensor::Reconstructor;

/// The projector point the reference plane gives camera point (x, y): the decoded reference's
/// column and row maps, bilinear over the valid ones of the four pixels about it.
pub struct ReferencePrediction<'a> {
    reference: &'a Decoded,
    rows: &'a [f32],
}

impl<'a> ReferencePrediction<'a> {
    /// `None` when the reference has no row codes (the code's repeat along rows could not be
    /// chosen).
    pub fn new(reference: &'a Decoded) -> Option<ReferencePrediction<'a>> {
        Some(ReferencePrediction {
            rows: reference.row.as_deref()?,
            reference,
        })
    }

    /// The predicted projector point at camera (x, y).
    pub fn at(&self, x: f64, y: f64) -> Option<(f64, f64)> {
        let (w, h) = (
            self.reference.width as usize,
            self.reference.height as usize,
        );
        if !(x >= 0.0 && y >= 0.0 && x < (w - 1) as f64 && y < (h - 1) as f64) {
            return None;
        }
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        let (ax, ay) = (x - x0 as f64, y - y0 as f64);
        let (mut su, mut sv, mut sw) = (0.0, 0.0, 0.0);
        for (dx, dy, wt) in [
            (0, 0, (1.0 - ax) * (1.0 - ay)),
            (1, 0, ax * (1.0 - ay)),
            (0, 1, (1.0 - ax) * ay),
            (1, 1, ax * ay),
        ] {
            let i = (y0 + dy) * w + x0 + dx;
            let (c, r) = (self.reference.col[i], self.rows[i]);
            if c.is_finite() && r.is_finite() {
                su += wt * f64::from(c);
                sv += wt * f64::from(r);
                sw += wt;
            }
        }
        (sw > 1e-6).then(|| (su / sw, sv / sw))
    }
}

/// Fewest camera pixels between neighbouring X-points (as [`camera_spacing`] measures them) at
/// which [`super::detect`], set for the spacing ([`super::DetectParams::for_spacing`]), finds
/// them. On the mock cell (camera and projector pixels nearly 1:1) a step of 9 projector pixels
/// (8.7 camera pixels) decodes whole and a step of 8 (7.8) a quarter; on seeded scenes of the
/// demo at 8.7–10.7 px, 93–96 % of the primitives in view are decoded.
pub const MIN_CAMERA_SPACING: f64 = 8.5;

/// The camera distance, pixels, between neighbouring X-points of a pattern with grid `step`
/// (projector pixels) along the projector's rows and columns: the 10th percentile over the view
/// (the closest they come, but for a tenth of it), from the decoded reference's local Jacobian
/// (its column and row maps, every 4th pixel); `None` without row codes or enough valid pixels.
/// Perspective and tilt make the spacing vary across the view, and the detector must resolve
/// the closest.
pub fn camera_spacing(reference: &Decoded, step: [u32; 2]) -> Option<[f64; 2]> {
    let rows = reference.row.as_deref()?;
    let (w, h) = (reference.width as usize, reference.height as usize);
    let col = &reference.col;
    let (mut along_x, mut along_y) = (Vec::new(), Vec::new());
    for y in (0..h.saturating_sub(1)).step_by(4) {
        for x in (0..w.saturating_sub(1)).step_by(4) {
            let i = y * w + x;
            let (c, r) = (col[i], rows[i]);
            let (cx, rx, cy, ry) = (col[i + 1], rows[i + 1], col[i + w], rows[i + w]);
            if ![c, r, cx, rx, cy, ry].iter().all(|v| v.is_finite()) {
                continue;
            }
            // d(projector)/d(camera), inverted: camera pixels per projector pixel.
            let (a, b, cc, d) = (
                f64::from(cx - c),
                f64::from(cy - c),
                f64::from(rx - r),
                f64::from(ry - r),
            );
            let det = a * d - b * cc;
            if det.abs() < 1e-9 {
                continue;
            }
            // Camera vectors of one projector pixel along its columns (x) and rows (y).
            let (ux, uy) = (d / det, -cc / det);
            let (vx, vy) = (-b / det, a / det);
            along_x.push(f64::from(step[0]) * ux.hypot(uy));
            along_y.push(f64::from(step[1]) * vx.hypot(vy));
        }
    }
    if along_x.len() < 16 {
        return None;
    }
    let tenth = |v: &mut Vec<f64>| {
        let k = (v.len() - 1) / 10;
        *v.select_nth_unstable_by(k, f64::total_cmp).1
    };
    Some([tenth(&mut along_x), tenth(&mut along_y)])
}

/// The cloud of `matches` through `rec`: one point per X-point, organised by the camera pixel
/// nearest its corner, its confidence 1 − the corner's asymmetry (halved where a grid
/// neighbour is missing), flagged outside the sensor's calibrated volume where it states one.
pub fn reconstruct(matches: &[Correspondence], rec: &Reconstructor) -> PointCloud {
    let cam = rec.camera();
    let (w, h) = (cam.width, cam.height);
    let found: Vec<([f32; 3], u32, f32)> = matches
        .par_iter()
        .filter_map(|m| {
            let p = rec.point_at(m.x, m.y, m.u, m.v)?;
            let px = (m.x.round().clamp(0.0, f64::from(w) - 1.0) as u32)
                + (m.y.round().clamp(0.0, f64::from(h) - 1.0) as u32) * w;
            // A corner beside a shadow or an edge (a grid neighbour missing) may be cut by it:
            // on the demo scenes such points are 22 % of all and 17 of 22 of those beyond 2 mm.
            let boundary = if m.sides == 0b1111 { 1.0 } else { 0.5 };
            let confidence = ((1.0 - m.asymmetry).clamp(0.0, 1.0) * boundary) as f32;
            Some(([p.x as f32, p.y as f32, p.z as f32], px, confidence))
        })
        .collect();
    let mut cloud = PointCloud {
        points: found.iter().map(|f| f.0).collect(),
        confidence: found.iter().map(|f| f.2).collect(),
        pixels: found.iter().map(|f| f.1).collect(),
        image: Some([w, h]),
        ..Default::default()
    };
    if let Some(volume) = &rec.volume {
        cloud.outside = cloud.points.iter().map(|p| !volume.contains(p)).collect();
    }
    cloud
}

/// One camera frame of the pattern, measured: its cloud and how it went.
#[derive(Clone, Debug)]
pub struct Measured {
    /// The cloud (see [`reconstruct`]).
    pub cloud: PointCloud,
    /// X-points detected.
    pub detected: usize,
    /// Correspondences placed by their own codeword (the rest by a neighbour).
    pub from_codeword: usize,
    /// Correspondences beside a missing grid neighbour (an edge, a shadow): their points carry
    /// half confidence, since an edge that cuts a primitive's lobe moves its corner (by up to
    /// about a pixel, 2–3 mm at 1.6 m on the test scenes) where nothing in the light shows it.
    pub at_boundary: usize,
    /// How decoding went.
    pub stats: super::DecodeStats,
    /// Seconds detecting and decoding.
    pub decode_s: f64,
    /// Seconds reconstructing.
    pub reconstruct_s: f64,
}

/// The X-points of one camera `image` of `pattern` (found by `detector`, which keeps its working
/// images for the next frame), and those decoded (the repeat chosen by `predict`), with the
/// corners an edge cut moved to where the half it did not reach places them, and those it cut
/// further dropped.
pub fn decode_frame(
    detector: &mut super::Detector,
    image: &crate::image::GrayImage,
    pattern: &super::XPointPattern,
    predict: Option<super::Predict>,
) -> (
    Vec<super::Detection>,
    Vec<super::Correspondence>,
    super::DecodeStats,
) {
    let found = detector.detect_image(image);
    let (mut matches, mut stats) = super::decode(&found, pattern, predict);
    stats.recentred = detector.recentre_cut(&mut matches, pattern);
    stats.kinked = super::cut::drop_kinked(&mut matches, pattern);
    (found, matches, stats)
}

/// Detect (with `detector`, which keeps its working images for the next frame), decode (the
/// repeat chosen by `predict`) and reconstruct one camera `image` of `pattern` through `rec`.
pub fn measure(
    detector: &mut super::Detector,
    image: &crate::image::GrayImage,
    pattern: &super::XPointPattern,
    predict: Option<super::Predict>,
    rec: &Reconstructor,
) -> Measured {
    let t = std::time::Instant::now();
    let (found, matches, stats) = decode_frame(detector, image, pattern, predict);
    let decode_s = t.elapsed().as_secs_f64();
    let cloud = reconstruct(&matches, rec);
    Measured {
        cloud,
        detected: found.len(),
        from_codeword: matches.iter().filter(|m| m.from_codeword).count(),
        at_boundary: matches.iter().filter(|m| m.sides != 0b1111).count(),
        stats,
        decode_s,
        reconstruct_s: t.elapsed().as_secs_f64() - decode_s,
    }
}
