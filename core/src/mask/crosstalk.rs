//! Where the light of a camera pixel comes from in the projector (the crosstalk f_cr, Eq. 4.8):
//! first guessed through the reference plane (Eq. 4.16), then measured by an advanced masked
//! projection; and the mask built by carrying each camera pixel's desired level there.

use rayon::prelude::*;

use super::field::{max_filter, min_filter, nearest_valid};
use super::MaskParams;
use crate::decode::Decoded;
use crate::pattern::ProjectionMask;
use crate::{Error, Result};

/// Camera pixel → projector coordinates (column u, row v), NaN where unknown.
#[derive(Clone, Debug)]
pub struct CodeMap {
    /// Camera width.
    pub width: u32,
    /// Camera height.
    pub height: u32,
    /// Projector column per camera pixel.
    pub u: Vec<f32>,
    /// Projector row per camera pixel.
    pub v: Vec<f32>,
}

impl CodeMap {
    /// The decoded columns and rows of a capture (both needed).
    pub fn from_decoded(d: &Decoded) -> Result<CodeMap> {
        let row = d.row.as_ref().ok_or_else(|| {
            Error::Insufficient("the crosstalk needs row codes; the capture has none".into())
        })?;
        let (u, v) = d
            .col
            .iter()
            .zip(row)
            .map(|(&c, &r)| {
                if c.is_finite() && r.is_finite() {
                    (c, r)
                } else {
                    (f32::NAN, f32::NAN)
                }
            })
            .unzip();
        Ok(CodeMap {
            width: d.width,
            height: d.height,
            u,
            v,
        })
    }

    /// This map where it is known, `other` elsewhere.
    pub fn or(&self, other: &CodeMap) -> CodeMap {
        let mut out = self.clone();
        for i in 0..out.u.len() {
            if !(out.u[i].is_finite() && out.v[i].is_finite()) {
                out.u[i] = other.u[i];
                out.v[i] = other.v[i];
            }
        }
        out
    }

    /// The first guess (flat scene): the decoded reference plane, holes filled from the
    /// nearest decoded pixel.
    pub fn reference_guess(reference: &Decoded) -> Result<CodeMap> {
        let mut map = CodeMap::from_decoded(reference)?;
        let valid: Vec<bool> = map.u.iter().map(|u| u.is_finite()).collect();
        if valid.iter().filter(|v| **v).count() < valid.len() / 10 {
            return Err(Error::Insufficient(
                "the reference recording decodes on under 10 % of the camera".into(),
            ));
        }
        let near = nearest_valid(&valid, map.width as usize, u32::MAX / 2);
        for (i, n) in near.iter().enumerate() {
            if !valid[i] {
                if let Some(s) = n {
                    map.u[i] = map.u[*s as usize];
                    map.v[i] = map.v[*s as usize];
                }
            }
        }
        Ok(map)
    }

    /// `guess` corrected by a measured map: measured where decoded (and within `max_shift`
    /// of the guess), elsewhere the guess moved by the shift measured at the nearest decoded
    /// pixel within `fill_radius`; the guess itself beyond. Returns the map and the fraction
    /// of pixels measured.
    pub fn refined(guess: &CodeMap, measured: &CodeMap, params: &MaskParams) -> (CodeMap, f32) {
        let max_shift = params.dilation as f32 * 1.5;
        let n = guess.u.len();
        let mut du = vec![0.0f32; n];
        let mut dv = vec![0.0f32; n];
        let valid: Vec<bool> = (0..n)
            .map(|i| {
                let (a, b) = (measured.u[i] - guess.u[i], measured.v[i] - guess.v[i]);
                let ok = a.is_finite() && b.is_finite() && a.hypot(b) <= max_shift;
                if ok {
                    du[i] = a;
                    dv[i] = b;
                }
                ok
            })
            .collect();
        let near = nearest_valid(&valid, guess.width as usize, params.fill_radius);
        let mut out = guess.clone();
        for (i, s) in near.iter().enumerate() {
            if let Some(s) = *s {
                out.u[i] += du[s as usize];
                out.v[i] += dv[s as usize];
            }
        }
        let fraction = valid.iter().filter(|v| **v).count() as f32 / n.max(1) as f32;
        (out, fraction)
    }
}

/// Building projector masks from per-camera-pixel levels.
pub struct MaskBuild;

impl MaskBuild {
    /// Carry each camera pixel's `level` (0..1) to its projector position under `map`,
    /// covering the pixel's footprint there (from the map's local derivatives, at most 3 px
    /// each way); where footprints overlap the smaller level wins (no pixel over-exposed).
    /// Projector pixels no camera pixel maps to stay 0.
    pub fn splat(map: &CodeMap, level: &[f32], pw: u32, ph: u32) -> ProjectionMask {
        Self::splat_into(map, level, pw, ph, 0.0)
    }

    /// Like [`MaskBuild::splat`], but projector pixels no camera pixel maps to stay 1, so that
    /// a following erosion spreads only the levels that were placed.
    pub fn splat_min(map: &CodeMap, level: &[f32], pw: u32, ph: u32) -> ProjectionMask {
        Self::splat_into(map, level, pw, ph, 1.0)
    }

    fn splat_into(map: &CodeMap, level: &[f32], pw: u32, ph: u32, empty: f32) -> ProjectionMask {
        let (w, h) = (map.width as usize, map.height as usize);
        let (pwu, phu) = (pw as usize, ph as usize);
        // Camera rows in bands, each splatted into its own projector buffer, then combined.
        let bands = rayon::current_num_threads().max(1);
        let band = h.div_ceil(bands).max(1);
        let partial: Vec<Vec<f32>> = (0..h.div_ceil(band))
            .into_par_iter()
            .map(|k| {
                let mut out = vec![f32::INFINITY; pwu * phu];
                for y in k * band..((k + 1) * band).min(h) {
                    for x in 0..w {
                        let i = y * w + x;
                        let (u, v, m) = (map.u[i], map.v[i], level[i]);
                        if !(u.is_finite() && v.is_finite() && m.is_finite()) {
                            continue;
                        }
                        let (mut hu, mut hv) = (0.5f32, 0.5f32);
                        for j in [i + 1, i + w] {
                            if (j == i + 1 && x + 1 < w) || (j == i + w && y + 1 < h) {
                                let (nu, nv) = (map.u[j], map.v[j]);
                                if nu.is_finite() && nv.is_finite() {
                                    hu = hu.max(0.5 * (nu - u).abs());
                                    hv = hv.max(0.5 * (nv - v).abs());
                                }
                            }
                        }
                        let (hu, hv) = (hu.min(3.0), hv.min(3.0));
                        // Projector pixels whose centres fall in the footprint (the nearest one
                        // at least).
                        let span = |c: f32, half: f32, n: usize| -> (usize, usize) {
                            let lo = (c - half).ceil().max(0.0) as usize;
                            let hi = ((c + half).floor().max(0.0) as usize).min(n - 1);
                            if lo > hi {
                                let r = (c.round().max(0.0) as usize).min(n - 1);
                                (r, r)
                            } else {
                                (lo, hi)
                            }
                        };
                        if u < -0.5 || v < -0.5 || u > pw as f32 - 0.5 || v > ph as f32 - 0.5 {
                            continue;
                        }
                        let (u0, u1) = span(u, hu, pwu);
                        let (v0, v1) = span(v, hv, phu);
                        for pv in v0..=v1 {
                            for c in &mut out[pv * pwu + u0..=pv * pwu + u1] {
                                *c = c.min(m);
                            }
                        }
                    }
                }
                out
            })
            .collect();
        let mut values = vec![f32::INFINITY; pwu * phu];
        for p in partial {
            for (a, b) in values.iter_mut().zip(p) {
                *a = a.min(b);
            }
        }
        for c in &mut values {
            if !c.is_finite() {
                *c = empty;
            }
        }
        ProjectionMask {
            width: pw,
            height: ph,
            values,
        }
    }

    /// Grow the bright parts of `mask` by `radius` (the first guess is uncertain: give every
    /// possible true position the light it may need).
    pub fn dilate(mask: &ProjectionMask, radius: u32) -> ProjectionMask {
        ProjectionMask {
            values: max_filter(&mask.values, mask.width as usize, radius as usize),
            ..mask.clone()
        }
    }

    /// Shrink the bright parts of `mask` by `radius` (guard band against defocus).
    pub fn erode(mask: &ProjectionMask, radius: u32) -> ProjectionMask {
        ProjectionMask {
            values: min_filter(&mask.values, mask.width as usize, radius as usize),
            ..mask.clone()
        }
    }
}
