//! The reference recording as a smooth function on the reference plane.
//!
//! The decoded bare plane gives, for each plane point (X, Y), the projector code that lights it.
//! A projective (rational) map plus a low-order polynomial correction is fitted to every valid
//! pixel: the rational part is exact for a pinhole projector, the polynomial absorbs projector
//! lens distortion, and the fit removes the decoding noise of the single reference capture.

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

use crate::{Error, Result};

/// Polynomial degree of the correction term.
pub const DEFAULT_DEGREE: usize = 5;

/// Projector code φ(X, Y) on the reference plane.
#[derive(Clone, Debug)]
pub struct PlaneCodeMap {
    cx: f64,
    cy: f64,
    scale: f64,
    /// (h1 X + h2 Y + h3) / (h4 X + h5 Y + 1) in normalized plane coordinates.
    h: [f64; 5],
    degree: usize,
    poly: Vec<f64>,
    /// Bounding box of the samples in normalized coordinates, `[x_lo, x_hi, y_lo, y_hi]`: the
    /// polynomial correction is only known there and is held at its edge beyond it.
    domain: [f64; 4],
    /// RMS of the fit residual, projector pixels.
    pub rms: f64,
    /// Samples kept after outlier rejection.
    pub inliers: usize,
}

/// One sample: plane point and the decoded code there.
#[derive(Clone, Copy, Debug)]
pub struct PlaneSample {
    /// Plane X, mm.
    pub x: f64,
    /// Plane Y, mm.
    pub y: f64,
    /// Decoded projector coordinate.
    pub code: f64,
}

fn n_terms(degree: usize) -> usize {
    (degree + 1) * (degree + 2) / 2
}

impl PlaneCodeMap {
    /// Fit to samples with two rounds of outlier rejection (4 robust sigmas).
    pub fn fit(samples: &[PlaneSample], degree: usize) -> Result<PlaneCodeMap> {
        let nt = n_terms(degree);
        if samples.len() < 5 + nt + 10 {
            return Err(Error::Insufficient(format!(
                "reference has only {} valid samples; the fit needs at least {}",
                samples.len(),
                5 + nt + 10
            )));
        }
        let n = samples.len() as f64;
        let (sx, sy) = samples
            .iter()
            .fold((0.0, 0.0), |a, s| (a.0 + s.x, a.1 + s.y));
        let (cx, cy) = (sx / n, sy / n);
        let scale = samples
            .iter()
            .map(|s| (s.x - cx).abs().max((s.y - cy).abs()))
            .fold(0.0, f64::max)
            .max(1e-9);
        let domain = samples.iter().fold(
            [
                f64::INFINITY,
                f64::NEG_INFINITY,
                f64::INFINITY,
                f64::NEG_INFINITY,
            ],
            |d, s| {
                let (x, y) = ((s.x - cx) / scale, (s.y - cy) / scale);
                [d[0].min(x), d[1].max(x), d[2].min(y), d[3].max(y)]
            },
        );
        let mut map = PlaneCodeMap {
            cx,
            cy,
            scale,
            domain,
            h: [0.0; 5],
            degree,
            poly: vec![0.0; nt],
            rms: 0.0,
            inliers: samples.len(),
        };
        let mut keep: Vec<bool> = vec![true; samples.len()];
        for round in 0..3 {
            map.poly.iter_mut().for_each(|c| *c = 0.0);
            map.h = fit_rational(samples, &keep, cx, cy, scale)?;
            map.poly = fit_poly(samples, &keep, &map, degree)?;
            let resid: Vec<f64> = samples
                .par_iter()
                .map(|s| s.code - map.eval(s.x, s.y).0)
                .collect();
            let mut abs: Vec<f64> = resid
                .iter()
                .zip(&keep)
                .filter(|(_, k)| **k)
                .map(|(r, _)| r.abs())
                .collect();
            let mid = abs.len() / 2;
            abs.select_nth_unstable_by(mid, f64::total_cmp);
            let sigma = 1.4826 * abs[mid];
            let limit = (4.0 * sigma).max(0.05);
            let inl: Vec<f64> = resid
                .iter()
                .zip(&keep)
                .filter(|(r, k)| **k && r.abs() <= limit)
                .map(|(r, _)| *r)
                .collect();
            map.rms = (inl.iter().map(|r| r * r).sum::<f64>() / inl.len().max(1) as f64).sqrt();
            map.inliers = inl.len();
            tracing::debug!(round, rms = map.rms, inliers = map.inliers, "reference fit");
            if round < 2 {
                keep = resid.iter().map(|r| r.abs() <= limit).collect();
            }
        }
        Ok(map)
    }

    /// φ(X, Y) with its gradient (∂φ/∂X, ∂φ/∂Y). Beyond the sampled area the projective part
    /// (exact for a pinhole projector) extrapolates and the polynomial correction is held at
    /// its value on the area's edge, so that a degree-5 fit cannot swing outside its data.
    #[inline]
    pub fn eval(&self, x: f64, y: f64) -> (f64, f64, f64) {
        let (xn, yn) = ((x - self.cx) / self.scale, (y - self.cy) / self.scale);
        let h = &self.h;
        let num = h[0] * xn + h[1] * yn + h[2];
        let den = h[3] * xn + h[4] * yn + 1.0;
        let rat = num / den;
        let drx = (h[0] - rat * h[3]) / den;
        let dry = (h[1] - rat * h[4]) / den;
        let d = &self.domain;
        let (xc, yc) = (xn.clamp(d[0], d[1]), yn.clamp(d[2], d[3]));
        let (p, mut px, mut py) = self.poly_eval(xc, yc);
        if xc != xn {
            px = 0.0;
        }
        if yc != yn {
            py = 0.0;
        }
        (rat + p, (drx + px) / self.scale, (dry + py) / self.scale)
    }

    /// Whether the plane point (X, Y) lies in the area the map was fitted on.
    pub fn covers(&self, x: f64, y: f64) -> bool {
        let (xn, yn) = ((x - self.cx) / self.scale, (y - self.cy) / self.scale);
        let d = &self.domain;
        (d[0]..=d[1]).contains(&xn) && (d[2]..=d[3]).contains(&yn)
    }

    #[inline]
    fn poly_eval(&self, x: f64, y: f64) -> (f64, f64, f64) {
        let mut xp = [1.0f64; 8];
        let mut yp = [1.0f64; 8];
        for i in 1..=self.degree {
            xp[i] = xp[i - 1] * x;
            yp[i] = yp[i - 1] * y;
        }
        let (mut v, mut dx, mut dy) = (0.0, 0.0, 0.0);
        let mut t = 0;
        for d in 0..=self.degree {
            for i in 0..=d {
                let j = d - i;
                let c = self.poly[t];
                t += 1;
                v += c * xp[i] * yp[j];
                if i > 0 {
                    dx += c * i as f64 * xp[i - 1] * yp[j];
                }
                if j > 0 {
                    dy += c * j as f64 * xp[i] * yp[j - 1];
                }
            }
        }
        (v, dx, dy)
    }
}

fn monomials(degree: usize, x: f64, y: f64, out: &mut [f64]) {
    let mut xp = [1.0f64; 8];
    let mut yp = [1.0f64; 8];
    for i in 1..=degree {
        xp[i] = xp[i - 1] * x;
        yp[i] = yp[i - 1] * y;
    }
    let mut t = 0;
    for d in 0..=degree {
        for i in 0..=d {
            out[t] = xp[i] * yp[d - i];
            t += 1;
        }
    }
}

/// Least squares by accumulated normal equations (parallel, deterministic), solved by SVD for
/// robustness.
fn solve_normal(
    n: usize,
    rows: impl Fn(usize, &mut [f64]) -> Option<f64> + Sync,
    count: usize,
) -> Result<Vec<f64>> {
    // Fixed chunks summed in order: the same coefficients to the last bit whatever the thread
    // count or the load (a replayed scan must reproduce the recorded one exactly).
    const CHUNK: usize = 4096;
    let parts: Vec<(DMatrix<f64>, DVector<f64>)> = (0..count.div_ceil(CHUNK))
        .into_par_iter()
        .map(|chunk| {
            let (mut ata, mut atb) = (DMatrix::<f64>::zeros(n, n), DVector::<f64>::zeros(n));
            let mut row = vec![0.0; n];
            for i in chunk * CHUNK..((chunk + 1) * CHUNK).min(count) {
                if let Some(b) = rows(i, &mut row) {
                    for a in 0..n {
                        atb[a] += row[a] * b;
                        for c in a..n {
                            ata[(a, c)] += row[a] * row[c];
                        }
                    }
                }
            }
            (ata, atb)
        })
        .collect();
    let (ata, atb) = parts.into_iter().fold(
        (DMatrix::<f64>::zeros(n, n), DVector::<f64>::zeros(n)),
        |(a1, b1), (a2, b2)| (a1 + a2, b1 + b2),
    );
    let mut full = ata.clone();
    for a in 0..n {
        for c in 0..a {
            full[(a, c)] = ata[(c, a)];
        }
    }
    let svd = full.svd(true, true);
    let x = svd
        .solve(&atb, 1e-12)
        .map_err(|e| Error::Insufficient(format!("reference fit is singular: {e}")))?;
    Ok(x.iter().copied().collect())
}

fn fit_rational(
    s: &[PlaneSample],
    keep: &[bool],
    cx: f64,
    cy: f64,
    scale: f64,
) -> Result<[f64; 5]> {
    let x = solve_normal(
        5,
        |i, row| {
            if !keep[i] {
                return None;
            }
            let (xn, yn, c) = ((s[i].x - cx) / scale, (s[i].y - cy) / scale, s[i].code);
            row.copy_from_slice(&[xn, yn, 1.0, -c * xn, -c * yn]);
            Some(c)
        },
        s.len(),
    )?;
    Ok([x[0], x[1], x[2], x[3], x[4]])
}

fn fit_poly(
    s: &[PlaneSample],
    keep: &[bool],
    map: &PlaneCodeMap,
    degree: usize,
) -> Result<Vec<f64>> {
    solve_normal(
        n_terms(degree),
        |i, row| {
            if !keep[i] {
                return None;
            }
            let resid = s[i].code - map.eval(s[i].x, s[i].y).0;
            monomials(
                degree,
                (s[i].x - map.cx) / map.scale,
                (s[i].y - map.cy) / map.scale,
                row,
            );
            Some(resid)
        },
        s.len(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_least_squares_fit_does_not_depend_on_the_threads() {
        // 50 000 rows of a cubic in two variables: every thread count gives the same bits.
        let rows = |i: usize, row: &mut [f64]| {
            let (x, y) = (
                (i % 250) as f64 / 125.0 - 1.0,
                (i / 250) as f64 / 100.0 - 1.0,
            );
            monomials(3, x, y, row);
            Some((3.0 * x).sin() + y * y * 0.7 + (i as f64 * 0.37).sin() * 1e-3)
        };
        let fit = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("pool")
                .install(|| solve_normal(10, rows, 50_000).expect("fit"))
        };
        let one = fit(1);
        for threads in [2, 3, 8] {
            assert_eq!(fit(threads), one, "{threads} threads");
        }
    }

    #[test]
    fn recovers_a_distorted_projective_map_and_its_gradient() {
        let truth = |x: f64, y: f64| {
            let r = (3.0 * x + 0.2 * y + 500.0) / (0.0004 * x - 0.0001 * y + 1.0);
            r + 2e-7 * (x * x + y * y) * (x / 100.0)
        };
        let mut samples = Vec::new();
        for i in 0..200 {
            for j in 0..150 {
                let (x, y) = (-400.0 + 4.0 * i as f64, -300.0 + 4.0 * j as f64);
                let noise = ((i * 7919 + j * 104729) % 1000) as f64 / 1000.0 - 0.5;
                samples.push(PlaneSample {
                    x,
                    y,
                    code: truth(x, y) + 0.02 * noise,
                });
            }
        }
        samples[100].code += 40.0; // a gross outlier must not bend the fit
        let map = PlaneCodeMap::fit(&samples, DEFAULT_DEGREE).expect("fit");
        for &(x, y) in &[
            (0.0, 0.0),
            (350.0, 250.0),
            (-380.0, -280.0),
            (120.0, -200.0),
        ] {
            let (v, gx, gy) = map.eval(x, y);
            assert!(
                (v - truth(x, y)).abs() < 0.01,
                "value at ({x},{y}): {v} vs {}",
                truth(x, y)
            );
            let h = 1e-3;
            let ngx = (truth(x + h, y) - truth(x - h, y)) / (2.0 * h);
            let ngy = (truth(x, y + h) - truth(x, y - h)) / (2.0 * h);
            assert!(
                (gx - ngx).abs() < 1e-3 && (gy - ngy).abs() < 1e-3,
                "gradient"
            );
        }
        assert!(map.rms < 0.01, "rms {}", map.rms);
    }
}
