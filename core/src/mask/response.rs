//! The per-pixel photo response I_c = k7 I_p + k8 (Eq. 4.15), fitted to flat projections.

use rayon::prelude::*;

use super::MaskParams;
use crate::image::GrayImage;

/// Photo response of every camera pixel at one exposure.
#[derive(Clone, Debug)]
pub struct PhotoResponse {
    /// Width.
    pub width: u32,
    /// Height.
    pub height: u32,
    /// Exposure factor the coefficients refer to.
    pub exposure: f64,
    /// k7: camera DN per projector level; NaN where unknown (saturated by ambient light alone).
    pub gain: Vec<f32>,
    /// k8: camera DN at projector level 0 (ambient).
    pub offset: Vec<f32>,
    /// Unsaturated samples behind each fit (1 means `gain` is only a lower bound).
    pub samples: Vec<u8>,
}

impl PhotoResponse {
    /// Least-squares fit per pixel over the unsaturated samples of `flats` (level, frame)
    /// taken at `exposure`. A pixel with one unsaturated sample gets the smallest gain that
    /// saturates it at the next level (a lower bound).
    pub fn fit(flats: &[(u8, &GrayImage)], exposure: f64, saturation: f32) -> PhotoResponse {
        let (w, h) = flats
            .first()
            .map(|(_, f)| (f.width, f.height))
            .unwrap_or((0, 0));
        let mut levels: Vec<(f32, Vec<f32>)> = flats
            .iter()
            .map(|(l, f)| (f32::from(*l), f.to_levels()))
            .collect();
        levels.sort_by(|a, b| a.0.total_cmp(&b.0));
        let n = (w * h) as usize;
        let mut gain = vec![0.0f32; n];
        let mut offset = vec![0.0f32; n];
        let mut samples = vec![0u8; n];
        gain.par_iter_mut()
            .zip(offset.par_iter_mut())
            .zip(samples.par_iter_mut())
            .enumerate()
            .for_each(|(i, ((g, o), c))| {
                let (mut sx, mut sy, mut sxx, mut sxy, mut k) = (0.0f64, 0.0, 0.0, 0.0, 0u8);
                let mut first_saturated = None;
                for (l, v) in &levels {
                    let y = v[i];
                    if y >= saturation {
                        first_saturated.get_or_insert(*l);
                        continue;
                    }
                    let (x, y) = (f64::from(*l), f64::from(y));
                    sx += x;
                    sy += y;
                    sxx += x * x;
                    sxy += x * y;
                    k += 1;
                }
                *c = k;
                let kf = f64::from(k);
                if k >= 2 {
                    let den = kf * sxx - sx * sx;
                    let slope = if den > 0.0 {
                        (kf * sxy - sx * sy) / den
                    } else {
                        0.0
                    };
                    *g = slope.max(0.0) as f32;
                    *o = ((sy - slope * sx) / kf) as f32;
                } else if k == 1 {
                    *o = sy as f32;
                    let l = first_saturated.unwrap_or(255.0).max(1.0);
                    *g = ((f64::from(saturation) - sy) / f64::from(l)).max(0.0) as f32;
                } else {
                    *g = f32::NAN;
                    *o = saturation;
                }
            });
        PhotoResponse {
            width: w,
            height: h,
            exposure,
            gain,
            offset,
            samples,
        }
    }

    /// The same response at exposure factor `exposure` (a linear camera).
    pub fn at_exposure(&self, exposure: f64) -> PhotoResponse {
        let s = (exposure / self.exposure) as f32;
        PhotoResponse {
            exposure,
            gain: self.gain.iter().map(|g| g * s).collect(),
            offset: self.offset.iter().map(|o| o * s).collect(),
            ..self.clone()
        }
    }

    /// Per pixel, the better of two fits brought to `self`'s exposure: the one with more
    /// unsaturated samples, `other` on ties (a higher exposure resolves dark pixels better).
    pub fn merged(&self, other: &PhotoResponse) -> PhotoResponse {
        let o = other.at_exposure(self.exposure);
        let mut out = self.clone();
        for i in 0..out.gain.len() {
            if o.samples[i] >= out.samples[i] && o.samples[i] >= 2 {
                out.gain[i] = o.gain[i];
                out.offset[i] = o.offset[i];
                out.samples[i] = o.samples[i];
            }
        }
        out
    }

    /// The exposure factor (relative to this response's) at which the dark parts of the scene
    /// reach the target at full projector light, bounded by the ambient light the brightest
    /// pixels would then saturate with.
    pub fn choose_exposure(&self, params: &MaskParams) -> f64 {
        let mut responses: Vec<f32> = Vec::new();
        let mut ambient: Vec<f32> = Vec::new();
        for (g, o) in self.gain.iter().zip(&self.offset) {
            if g.is_finite() && g * 255.0 >= params.min_response {
                responses.push(g * 255.0);
                ambient.push(*o);
            }
        }
        if responses.is_empty() {
            return 1.0;
        }
        let pick = |v: &mut Vec<f32>, q: f32| {
            let k = ((v.len() - 1) as f32 * q).round() as usize;
            *v.select_nth_unstable_by(k, |a, b| a.total_cmp(b)).1
        };
        let dark = pick(&mut responses, params.exposure_percentile);
        let bright_ambient = pick(&mut ambient, 0.99).max(1e-3);
        let want = f64::from(params.target / dark);
        let limit = f64::from(params.ambient_limit * params.target / bright_ambient);
        want.min(limit)
            .clamp(params.min_exposure, params.max_exposure)
    }

    /// Per camera pixel, the mask value M = I_p* / 255 that makes it read the target:
    /// I_p* = (target − k8) / k7 clamped to [0, 255] (Eq. 4.9–4.10). Pixels that do not see
    /// the projector (shadows, or saturated by ambient light alone) get NaN: they have no say
    /// in the mask, since their crosstalk points at projector pixels that light something else.
    pub fn desired_mask(&self, params: &MaskParams) -> Vec<f32> {
        self.gain
            .par_iter()
            .zip(&self.offset)
            .map(|(&g, &o)| {
                if !g.is_finite() || g * 255.0 < params.min_response {
                    f32::NAN
                } else {
                    ((params.target - o) / g / 255.0).clamp(0.0, 1.0)
                }
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fits_gain_and_offset_from_unsaturated_flats() {
        // Pixel 0: gain 0.5, offset 10; pixel 1: gain 2, offset 5 (saturates from level 150).
        let levels = super::super::FLAT_LEVELS;
        let frames: Vec<GrayImage> = levels
            .iter()
            .map(|&l| {
                let l = f32::from(l);
                GrayImage::from_u8(
                    2,
                    1,
                    vec![
                        (0.5 * l + 10.0).round() as u8,
                        (2.0 * l + 5.0).min(255.0).round() as u8,
                    ],
                )
            })
            .collect();
        let flats: Vec<(u8, &GrayImage)> = levels.iter().copied().zip(frames.iter()).collect();
        let r = PhotoResponse::fit(&flats, 1.0, 250.0);
        assert!((r.gain[0] - 0.5).abs() < 0.01 && (r.offset[0] - 10.0).abs() < 0.5);
        assert!((r.gain[1] - 2.0).abs() < 0.01 && (r.offset[1] - 5.0).abs() < 0.5);
        assert_eq!(r.samples[1], 4);
        let p = MaskParams::default();
        let m = r.desired_mask(&p);
        assert!((m[0] - 1.0).abs() < 1e-6, "cannot reach 200: full light");
        assert!((m[1] * 255.0 - 97.5).abs() < 0.5, "{}", m[1] * 255.0);
        let r4 = r.at_exposure(4.0);
        assert!((r4.gain[0] - 2.0).abs() < 0.05);
    }
}

/// Figures of one feedback round.
#[derive(Clone, Copy, Debug, Default)]
pub struct Feedback {
    /// Pixels that saturated under the mask (their level was halved).
    pub saturated: usize,
    /// Pixels off the target by more than 10 % (their level was scaled).
    pub corrected: usize,
    /// Pixels that have a say in the mask.
    pub considered: usize,
}

/// Correct per-camera-pixel mask levels from what the camera saw under the mask (white and
/// black frames, `width` wide): pixels off the target are scaled towards it (at most ×2 up,
/// ×4 down, never above 1); every pixel within `spread` pixels of a saturated one has its level
/// halved, because saturation there may come from its neighbours' light (inter-reflection) as
/// much as from its own. This closes the loop around what the linear photo response misses.
pub fn feedback(
    levels: &mut [f32],
    white: &GrayImage,
    black: &GrayImage,
    spread: u32,
    params: &MaskParams,
) -> Feedback {
    let (w, b) = (white.to_levels(), black.to_levels());
    let mut f = Feedback::default();
    let mut factor = vec![1.0f32; levels.len()];
    for (i, m) in levels.iter_mut().enumerate() {
        if !m.is_finite() {
            continue;
        }
        f.considered += 1;
        let (wi, bi) = (w[i], b[i]);
        if wi >= params.saturation {
            factor[i] = 0.5;
            f.saturated += 1;
            continue;
        }
        let s = wi - bi;
        let want = params.target - bi;
        if s < params.min_response || want <= 0.0 {
            continue;
        }
        let ratio = want / s;
        if (ratio - 1.0).abs() > 0.1 {
            let next = (*m * ratio).clamp(*m / 4.0, (*m * 2.0).min(1.0));
            if next != *m {
                f.corrected += 1;
            }
            *m = next;
        }
    }
    if f.saturated > 0 {
        let factor = super::field::min_filter(&factor, white.width as usize, spread as usize);
        for (m, k) in levels.iter_mut().zip(factor) {
            *m *= k;
        }
    }
    f
}
