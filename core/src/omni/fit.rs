//! A mirror unit's model fitted to what a calibration session saw (Ch. 6.2): the mirror's
//! pose (rotation and translation in the sensor frame), the pinhole's focal lengths and
//! principal point and the mirror's semi-axis `a`, adjusted by Levenberg–Marquardt so that the
//! unit projects every observed target point onto the pixel it was seen at. Rays from the
//! fitted model carry the whole session's evidence at every pixel, where a ray through a
//! pixel's two target points carries only the noise of those two.

use nalgebra::{SMatrix, SVector};
use rayon::prelude::*;
use serde::Serialize;

use super::MirrorUnit;
use crate::geometry::{Mat3, Vec3};

/// Parameters adjusted: rotation increment (3), translation (3), fx, fy, cx, cy, a.
const P: usize = 11;

/// Residual (px, each axis) given to an observation the model cannot project.
const MISS_PX: f64 = 50.0;

/// How a unit's fit went.
#[derive(Clone, Debug, Default, Serialize)]
pub struct UnitFit {
    /// Observations (pixel, target point) used, of those given (the rest were outliers).
    pub observations: [usize; 2],
    /// RMS reprojection error of the nominal model, pixels.
    pub nominal_rms_px: f64,
    /// RMS and 95th percentile reprojection error of the fitted model, pixels.
    pub rms_px: f64,
    /// 95th percentile, pixels.
    pub p95_px: f64,
    /// Whether the fitted model was kept (its errors are those of the measurements: RMS below
    /// [`MAX_RMS_PX`]); when not, the unit's rays come from its pixels' target points alone.
    pub used: bool,
    /// Largest change of a parameter from the nominal model: mirror translation, mm, and
    /// rotation, degrees.
    pub moved_mm: f64,
    /// Mirror rotation change, degrees.
    pub turned_deg: f64,
    /// Worst standard deviation of a fitted ray's direction over the unit's image, degrees,
    /// from the fit's covariance: what the observations leave loose (too few, all at one
    /// distance, one side of the mirror). Above [`MAX_RAY_SD_DEG`] the fit is not used.
    pub ray_sd_deg: f64,
}

/// Largest [`UnitFit::ray_sd_deg`] for which the fitted model is trusted, degrees (0.5 mm at
/// 3 m).
pub const MAX_RAY_SD_DEG: f64 = 0.01;

/// Largest RMS reprojection error for which the fitted model is trusted, pixels: above it the
/// unit is not the model (a warped mirror, a lens the model lacks) and per-pixel rays are kept.
pub const MAX_RMS_PX: f64 = 0.5;

fn apply(unit: &MirrorUnit, p: &SVector<f64, P>) -> MirrorUnit {
    let mut u = unit.clone();
    let w = Vec3::new(p[0], p[1], p[2]);
    let turn: Mat3 = *nalgebra::Rotation3::new(w).matrix();
    u.r = unit.r * turn;
    u.t = unit.t + Vec3::new(p[3], p[4], p[5]);
    u.lens.k[(0, 0)] = unit.lens.k[(0, 0)] + p[6];
    u.lens.k[(1, 1)] = unit.lens.k[(1, 1)] + p[7];
    u.lens.k[(0, 2)] = unit.lens.k[(0, 2)] + p[8];
    u.lens.k[(1, 2)] = unit.lens.k[(1, 2)] + p[9];
    u.mirror.a = unit.mirror.a + p[10];
    u
}

fn residual(unit: &MirrorUnit, obs: &([f64; 2], Vec3)) -> [f64; 2] {
    match unit.project(&obs.1) {
        Some(((u, v), _)) => [u - obs.0[0], v - obs.0[1]],
        None => [MISS_PX, MISS_PX],
    }
}

/// Cauchy cost of the residuals with scale `c` px (`None`: least squares): an observation
/// many scales off (a dot taken for its neighbour) weighs little.
fn cost(unit: &MirrorUnit, obs: &[([f64; 2], Vec3)], c: Option<f64>) -> f64 {
    obs.par_iter()
        .map(|o| {
            let r = residual(unit, o);
            let s = r[0] * r[0] + r[1] * r[1];
            c.map_or(s, |c| c * c * (s / (c * c)).ln_1p())
        })
        .sum()
}

/// Finite-difference steps of the parameters.
const STEPS: [f64; P] = [
    1e-6, 1e-6, 1e-6, 1e-4, 1e-4, 1e-4, 1e-3, 1e-3, 1e-3, 1e-3, 1e-5,
];

/// The unit with each parameter in turn moved by its finite-difference step.
fn shifted(nominal: &MirrorUnit, p: &SVector<f64, P>) -> Vec<MirrorUnit> {
    (0..P)
        .map(|k| {
            let mut q = *p;
            q[k] += STEPS[k];
            apply(nominal, &q)
        })
        .collect()
}

/// JᵀWJ and JᵀWr of the residuals at `p` (W: Cauchy weights with scale `c`, or 1).
fn normal_equations(
    nominal: &MirrorUnit,
    p: &SVector<f64, P>,
    obs: &[([f64; 2], Vec3)],
    c: Option<f64>,
) -> (SMatrix<f64, P, P>, SVector<f64, P>) {
    let unit = apply(nominal, p);
    let shifted = shifted(nominal, p);
    obs.par_iter()
        .map(|o| {
            let r0 = residual(&unit, o);
            let mut j = SMatrix::<f64, 2, P>::zeros();
            for k in 0..P {
                let r = residual(&shifted[k], o);
                j[(0, k)] = (r[0] - r0[0]) / STEPS[k];
                j[(1, k)] = (r[1] - r0[1]) / STEPS[k];
            }
            let r = nalgebra::Vector2::new(r0[0], r0[1]);
            let w = c.map_or(1.0, |c| {
                1.0 / (1.0 + (r0[0] * r0[0] + r0[1] * r0[1]) / (c * c))
            });
            (j.transpose() * j * w, j.transpose() * r * w)
        })
        .reduce(
            || (SMatrix::<f64, P, P>::zeros(), SVector::<f64, P>::zeros()),
            |a, b| (a.0 + b.0, a.1 + b.1),
        )
}

/// The worst standard deviation, degrees, of a ray's direction over the unit's image (a
/// 24 × 18 grid of pixels) that the fit's covariance gives: small where the observations pin
/// every parameter, large where some combination of them (or the rays through pixels far
/// from any observation) they leave loose. Infinite when the normal equations are singular.
fn ray_sd_deg(nominal: &MirrorUnit, p: &SVector<f64, P>, obs: &[([f64; 2], Vec3)]) -> f64 {
    let (jtj, _) = normal_equations(nominal, p, obs, None);
    let unit = apply(nominal, p);
    let dof = (2 * obs.len()).saturating_sub(P).max(1) as f64;
    let s2 = obs
        .iter()
        .map(|o| {
            let r = residual(&unit, o);
            r[0] * r[0] + r[1] * r[1]
        })
        .sum::<f64>()
        / dof;
    let Some(inverse) = jtj.cholesky().map(|c| c.inverse()) else {
        return f64::INFINITY;
    };
    let cov = inverse * s2;
    let shifted = shifted(nominal, p);
    let (w, h) = (f64::from(unit.lens.width), f64::from(unit.lens.height));
    let mut worst: f64 = 0.0;
    for gy in 0..18 {
        for gx in 0..24 {
            let (u, v) = (
                (f64::from(gx) + 0.5) * w / 24.0,
                (f64::from(gy) + 0.5) * h / 18.0,
            );
            let Some(ray) = unit.back_project(u, v) else {
                continue;
            };
            let mut d = SMatrix::<f64, 3, P>::zeros();
            let mut whole = true;
            for k in 0..P {
                let Some(rk) = shifted[k].back_project(u, v) else {
                    whole = false;
                    break;
                };
                let dd = (rk.direction - ray.direction) / STEPS[k];
                d[(0, k)] = dd.x;
                d[(1, k)] = dd.y;
                d[(2, k)] = dd.z;
            }
            if whole {
                let var = (d * cov * d.transpose()).trace();
                worst = worst.max(var.max(0.0).sqrt().to_degrees());
            }
        }
    }
    worst
}

/// One Levenberg–Marquardt solve from `nominal` over `obs` (robust with Cauchy scale `c`, by
/// reweighting each iteration); the parameter increments.
fn solve(nominal: &MirrorUnit, obs: &[([f64; 2], Vec3)], c: Option<f64>) -> SVector<f64, P> {
    let mut p = SVector::<f64, P>::zeros();
    let mut current = cost(&apply(nominal, &p), obs, c);
    let mut lambda = 1e-3;
    for _ in 0..40 {
        let (jtj, jtr) = normal_equations(nominal, &p, obs, c);
        let mut improved = false;
        for _ in 0..8 {
            let mut a = jtj;
            for k in 0..P {
                a[(k, k)] += lambda * jtj[(k, k)].max(1e-12);
            }
            let Some(step) = a.cholesky().map(|c| c.solve(&(-jtr))) else {
                lambda *= 10.0;
                continue;
            };
            let q = p + step;
            let next = cost(&apply(nominal, &q), obs, c);
            if next < current {
                let gain = (current - next) / current.max(1e-300);
                p = q;
                current = next;
                lambda = (lambda * 0.3).max(1e-9);
                improved = gain > 1e-10;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    p
}

fn rms(unit: &MirrorUnit, obs: &[([f64; 2], Vec3)]) -> (f64, Vec<f64>) {
    let mut e: Vec<f64> = obs
        .par_iter()
        .map(|o| {
            let r = residual(unit, o);
            r[0].hypot(r[1])
        })
        .collect();
    let rms = (e.iter().map(|x| x * x).sum::<f64>() / e.len().max(1) as f64).sqrt();
    e.sort_by(f64::total_cmp);
    (rms, e)
}

/// Fit `nominal` to `obs` (pixel seen, sensor-frame target point): the fitted unit and how the
/// fit went. Observations far from the fit (a dot taken for its neighbour, a blurred code) are
/// left out in later passes.
pub fn fit_unit(nominal: &MirrorUnit, obs: &[([f64; 2], Vec3)]) -> (MirrorUnit, UnitFit) {
    let (nominal_rms, _) = rms(nominal, obs);
    if obs.len() < 4 * P {
        return (
            nominal.clone(),
            UnitFit {
                observations: [0, obs.len()],
                nominal_rms_px: nominal_rms,
                ray_sd_deg: f64::INFINITY,
                ..UnitFit::default()
            },
        );
    }
    // A robust (Cauchy) fit first, then least-squares passes, each on the observations within
    // three times the previous fit's median error (at least 0.3 px) of it, so a region of dots
    // taken for their neighbours is left out once the rest has placed the model.
    let mut p = solve(nominal, obs, Some(1.0));
    let mut kept: Vec<([f64; 2], Vec3)> = obs.to_vec();
    for _ in 0..3 {
        let model = apply(nominal, &p);
        let (_, e) = rms(&model, obs);
        let limit = (3.0 * e[e.len() / 2]).max(0.3);
        kept = obs
            .iter()
            .filter(|o| {
                let r = residual(&model, o);
                r[0].hypot(r[1]) <= limit
            })
            .copied()
            .collect();
        if kept.len() < 4 * P {
            break;
        }
        p = solve(nominal, &kept, None);
    }
    let fitted = apply(nominal, &p);
    let (rms_px, e) = rms(&fitted, &kept);
    let p95 = e.get(e.len() * 95 / 100).copied().unwrap_or(f64::NAN);
    let ray_sd = ray_sd_deg(nominal, &p, &kept);
    let fit = UnitFit {
        observations: [kept.len(), obs.len()],
        nominal_rms_px: nominal_rms,
        rms_px,
        p95_px: p95,
        used: rms_px <= MAX_RMS_PX && ray_sd <= MAX_RAY_SD_DEG,
        ray_sd_deg: ray_sd,
        moved_mm: Vec3::new(p[3], p[4], p[5]).norm(),
        turned_deg: Vec3::new(p[0], p[1], p[2]).norm().to_degrees(),
    };
    (fitted, fit)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::omni::OmniSensor;
    use crate::testing::Rng;

    /// The largest angle between the two units' rays over a 16 px grid of a 640×480 image,
    /// degrees.
    fn worst_ray_deg(a: &MirrorUnit, b: &MirrorUnit) -> f64 {
        let mut worst: f64 = 0.0;
        for v in (0..480).step_by(16) {
            for u in (0..640).step_by(16) {
                let (Some(ra), Some(rb)) = (
                    a.back_project(f64::from(u), f64::from(v)),
                    b.back_project(f64::from(u), f64::from(v)),
                ) else {
                    continue;
                };
                let angle = ra.direction.dot(&rb.direction).clamp(-1.0, 1.0).acos();
                worst = worst.max(angle.to_degrees());
            }
        }
        worst
    }

    /// Points on two cylinders about the sensor (radius, half height, mm), seen through
    /// `truth` with uniform noise of ±0.175 px.
    fn observe(truth: &MirrorUnit, rng: &mut Rng) -> Vec<([f64; 2], Vec3)> {
        let mut obs = Vec::new();
        for (radius, half) in [(900.0, 1400.0), (3500.0, 2200.0)] {
            for i in 0..90 {
                let phi = f64::from(i) * 4f64.to_radians();
                for j in -20..=20 {
                    let x = Vec3::new(
                        radius * phi.cos(),
                        radius * phi.sin(),
                        half * f64::from(j) / 20.0,
                    );
                    if let Some(((u, v), _)) = truth.project(&x) {
                        obs.push((
                            [u + rng.range(-0.175, 0.175), v + rng.range(-0.175, 0.175)],
                            x,
                        ));
                    }
                }
            }
        }
        obs
    }

    /// Seeded units, each perturbed from the seed's nominal one (turn, shift, mirror and lens
    /// terms of either sign), fitted from a whole session, then from one sector of the view at
    /// one distance (a session that saw a target on one side only: the fit still meets every
    /// observation but leaves the rest of the mirror loose, and must say so), then from
    /// observations no parameter explains.
    #[test]
    fn a_perturbed_unit_is_recovered_from_its_projections() {
        let seed =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/omni/seed.toml");
        let nominal = OmniSensor::load(&seed).expect("seed").camera;
        let scale = [0.005, 0.005, 0.012, 0.8, 0.8, 1.0, 3.5, 3.0, 2.0, 3.0, 0.3];
        for case in 0..4u64 {
            let mut rng = Rng(7 + 1000 * case);
            let p: Vec<f64> = scale
                .iter()
                .map(|&s| {
                    let sign = if rng.range(0.0, 1.0) < 0.5 { -1.0 } else { 1.0 };
                    sign * s * rng.range(0.5, 1.0)
                })
                .collect();
            let truth = apply(&nominal, &SVector::<f64, P>::from_column_slice(&p));
            let obs = observe(&truth, &mut rng);
            let (fitted, fit) = fit_unit(&nominal, &obs);
            let worst = worst_ray_deg(&truth, &fitted);
            eprintln!("case {case}: {fit:?}, rays up to {worst:.4}° off");
            assert!(
                fit.used && fit.rms_px < 0.15 && fit.nominal_rms_px > 2.0,
                "case {case}: {fit:?}"
            );
            assert!(worst < 0.02, "case {case}: rays up to {worst:.4}° off");
            assert!(
                fit.ray_sd_deg < MAX_RAY_SD_DEG / 2.0,
                "case {case}: {fit:?}"
            );

            let centre = rng.range(-180.0, 180.0).to_radians();
            let half_width = rng.range(15.0, 30.0).to_radians();
            let near = rng.range(0.0, 1.0) < 0.5;
            let sector: Vec<([f64; 2], Vec3)> = obs
                .iter()
                .filter(|(_, x)| {
                    let off = (x.y.atan2(x.x) - centre + std::f64::consts::PI)
                        .rem_euclid(std::f64::consts::TAU)
                        - std::f64::consts::PI;
                    (x.norm() < 2000.0) == near && off.abs() < half_width
                })
                .copied()
                .collect();
            let (loose, fit) = fit_unit(&nominal, &sector);
            let far = worst_ray_deg(&truth, &loose);
            eprintln!(
                "case {case}: sector at {:.0}° ± {:.0}°, {} observations: {fit:?}, rays up to {far:.4}° off",
                centre.to_degrees(),
                half_width.to_degrees(),
                sector.len()
            );
            assert!(
                fit.rms_px < MAX_RMS_PX && !fit.used && fit.ray_sd_deg > MAX_RAY_SD_DEG,
                "case {case}: {fit:?}"
            );
            // What it reports as loose is no understatement of how far its rays are off.
            assert!(
                far < 3.0 * fit.ray_sd_deg,
                "case {case}: rays {far:.4}° off, σ {:.4}°",
                fit.ray_sd_deg
            );

            // A warped mirror: every point off by up to 3 px in a pattern no parameter follows.
            let warped: Vec<([f64; 2], Vec3)> = obs
                .iter()
                .map(|(p, x)| ([p[0] + 3.0 * (p[1] / 7.0).sin(), p[1]], *x))
                .collect();
            let (_, fit) = fit_unit(&nominal, &warped);
            assert!(!fit.used && fit.rms_px > MAX_RMS_PX, "case {case}: {fit:?}");
        }
    }
}
