//! Where the light of a camera pixel comes from in the projector (the crosstalk f_cr, Eq. 4.8):
//! first guessed through the reference plane (Eq. 4.16), then measured by an advanced masked
//! projection; and the mask built by carrying each camera pixel's desired level there.

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
        let (w, h) = (map.width as usize, map.height as usize);
        let mut out = vec![f32::INFINITY; (pw * ph) as usize];
        let at = |x: usize, y: usize| (map.u[y * w + x], map.v[y * w + x]);
        for y in 0..h {
            for x in 0..w {
                let (u, v) = at(x, y);
                let m = level[y * w + x];
                if !(u.is_finite() && v.is_finite() && m.is_finite()) {
                    continue;
                }
                let mut hu = 0.5f32;
                let mut hv = 0.5f32;
                for (nx, ny) in [(x + 1, y), (x, y + 1)] {
                    if nx < w && ny < h {
                        let (nu, nv) = at(nx, ny);
                        if nu.is_finite() && nv.is_finite() {
                            hu = hu.max(0.5 * (nu - u).abs() + 0.5);
                            hv = hv.max(0.5 * (nv - v).abs() + 0.5);
                        }
                    }
                }
                let (hu, hv) = (hu.min(3.0), hv.min(3.0));
                let u0 = (u - hu).round().max(0.0) as i64;
                let u1 = ((u + hu).round() as i64).min(i64::from(pw) - 1);
                let v0 = (v - hv).round().max(0.0) as i64;
                let v1 = ((v + hv).round() as i64).min(i64::from(ph) - 1);
                for pv in v0..=v1 {
                    for pu in u0..=u1 {
                        let c = &mut out[pv as usize * pw as usize + pu as usize];
                        *c = c.min(m);
                    }
                }
            }
        }
        for c in &mut out {
            if !c.is_finite() {
                *c = 0.0;
            }
        }
        ProjectionMask {
            width: pw,
            height: ph,
            values: out,
        }
    }

    /// Like [`MaskBuild::splat`], but projector pixels no camera pixel maps to stay 1, so that
    /// a following erosion spreads only the levels that were placed.
    pub fn splat_min(map: &CodeMap, level: &[f32], pw: u32, ph: u32) -> ProjectionMask {
        let any: Vec<f32> = level
            .iter()
            .map(|l| if l.is_finite() { 1.0 } else { f32::NAN })
            .collect();
        let placed = MaskBuild::splat(map, &any, pw, ph);
        let mut m = MaskBuild::splat(map, level, pw, ph);
        for (v, p) in m.values.iter_mut().zip(&placed.values) {
            if *p == 0.0 {
                *v = 1.0;
            }
        }
        m
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
