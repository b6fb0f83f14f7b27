//! Iterative closest point (Ch. 5.2, SPEC §9): kd-tree pairing, trimmed rejection of far
//! pairs, the multi-resolution schedule Res = max(1, 2^(4−n)) of Eq. 5.16, point-to-point
//! (closed form) or point-to-plane (linearised) updates, and convergence on error decrease.

use nalgebra::{Point3, UnitQuaternion, Vector3, Vector6};
use rayon::prelude::*;

use super::{estimate_normals, fit_rigid, Pose};
use crate::spatial::KdTree;

/// The error ICP minimises.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum IcpMetric {
    /// Σ |T p − q|², solved in closed form each iteration.
    PointToPoint,
    /// Σ ((T p − q) · n_q)², linearised; converges faster on smooth surfaces and is not biased
    /// by different sampling of the two clouds.
    PointToPlane,
}

/// ICP settings.
#[derive(Clone, Copy, Debug)]
pub struct IcpParams {
    /// Error metric.
    pub metric: IcpMetric,
    /// Iteration limit.
    pub max_iterations: usize,
    /// Iterations always run (the text: at least 4).
    pub min_iterations: usize,
    /// Fraction of pairs kept, the closest (trimmed ICP; 1 = keep all). Pairs beyond three
    /// robust sigmas of the pair distances are rejected as well.
    pub trim: f64,
    /// Pairs farther apart than this are never used, mm.
    pub max_distance: f64,
    /// Stop when the RMS decreases by less than this fraction at full resolution.
    pub tolerance: f64,
    /// Use the multi-resolution schedule of Eq. 5.16.
    pub multiresolution: bool,
    /// Neighbours for normal estimation (point-to-plane).
    pub normal_neighbours: usize,
}

impl Default for IcpParams {
    fn default() -> Self {
        IcpParams {
            metric: IcpMetric::PointToPlane,
            max_iterations: 50,
            min_iterations: 4,
            trim: 0.9,
            max_distance: f64::INFINITY,
            tolerance: 1e-5,
            multiresolution: true,
            normal_neighbours: 12,
        }
    }
}

/// Outcome of an alignment.
#[derive(Clone, Copy, Debug)]
pub struct IcpResult {
    /// Maps moving points into the fixed cloud's frame.
    pub fixed_from_moving: Pose,
    /// RMS point distance of the kept pairs at the end, mm.
    pub rms: f64,
    /// Fraction of moving points with a fixed partner within the final rejection distance.
    pub overlap: f64,
    /// Iterations run.
    pub iterations: usize,
    /// Whether the error stopped decreasing before the iteration limit.
    pub converged: bool,
}

/// A fixed cloud prepared for alignment (kd-tree, and normals for point-to-plane).
pub struct Icp {
    points: Vec<[f64; 3]>,
    tree: KdTree,
    normals: Option<Vec<[f64; 3]>>,
}

impl Icp {
    /// Prepare `fixed`; normals are estimated when `metric` needs them.
    pub fn new(fixed: &[[f64; 3]], metric: IcpMetric, normal_neighbours: usize) -> Icp {
        let tree = KdTree::new(fixed);
        let normals = (metric == IcpMetric::PointToPlane)
            .then(|| estimate_normals(fixed, &tree, normal_neighbours, None));
        Icp {
            points: fixed.to_vec(),
            tree,
            normals,
        }
    }

    /// Align `moving` to the fixed cloud starting from `init` (fixed_from_moving).
    pub fn align(&self, moving: &[[f64; 3]], init: Pose, params: &IcpParams) -> IcpResult {
        let mut pose = init;
        let mut last_rms = f64::INFINITY;
        let mut result = IcpResult {
            fixed_from_moving: pose,
            rms: f64::INFINITY,
            overlap: 0.0,
            iterations: 0,
            converged: false,
        };
        if moving.len() < 3 || self.points.len() < 3 {
            return result;
        }
        let metric = if self.normals.is_some() {
            params.metric
        } else {
            IcpMetric::PointToPoint
        };
        for n in 0..params.max_iterations {
            // A stage out of budget stops here, unconverged; its caller's check says why.
            if crate::budget::spent() {
                break;
            }
            let res = if params.multiresolution {
                1usize << 4usize.saturating_sub(n)
            } else {
                1
            };
            // Pair every res-th moving point with its nearest fixed point.
            let pairs: Vec<(usize, usize, f64)> = (0..moving.len())
                .into_par_iter()
                .step_by(res)
                .filter_map(|i| {
                    let p = pose * Point3::from(moving[i]);
                    self.tree
                        .nearest(&p.coords.into())
                        .map(|(j, d2)| (i, j, d2))
                })
                .collect();
            if pairs.len() < 6 {
                break;
            }
            // Trimmed rejection: keep the closest `trim` fraction, never beyond max_distance.
            let mut d2: Vec<f64> = pairs.iter().map(|p| p.2).collect();
            let keep_n = ((pairs.len() as f64 * params.trim).ceil() as usize).clamp(6, pairs.len());
            let (_, kth, _) = d2.select_nth_unstable_by(keep_n - 1, f64::total_cmp);
            let kth = *kth;
            // Adaptive rejection as well: pairs beyond 3 robust sigmas (1.4826 × median
            // distance) are outliers, e.g. moving points beyond the fixed cloud's border.
            let mid = d2.len() / 2;
            let (_, median2, _) = d2.select_nth_unstable_by(mid, f64::total_cmp);
            let robust = (3.0 * 1.4826) * (3.0 * 1.4826) * *median2;
            let limit = kth
                .min(robust.max(1e-12))
                .min(params.max_distance * params.max_distance);
            let kept: Vec<&(usize, usize, f64)> = pairs.iter().filter(|p| p.2 <= limit).collect();
            if kept.len() < 6 {
                break;
            }
            let rms = (kept.iter().map(|p| p.2).sum::<f64>() / kept.len() as f64).sqrt();
            let delta = match metric {
                IcpMetric::PointToPoint => {
                    let p: Vec<[f64; 3]> = kept
                        .iter()
                        .map(|k| (pose * Point3::from(moving[k.0])).coords.into())
                        .collect();
                    let q: Vec<[f64; 3]> = kept.iter().map(|k| self.points[k.1]).collect();
                    fit_rigid(&p, &q, None)
                }
                IcpMetric::PointToPlane => self.plane_step(moving, &pose, &kept),
            };
            result = IcpResult {
                fixed_from_moving: pose,
                rms,
                // Overlap: moving points whose partner lies within 3 × the RMS of the kept pairs
                // (points beyond the fixed cloud's extent have far partners).
                overlap: pairs.iter().filter(|p| p.2 <= 9.0 * rms * rms).count() as f64
                    / pairs.len() as f64,
                iterations: n + 1,
                converged: false,
            };
            let Some(delta) = delta else { break };
            pose = delta * pose;
            result.fixed_from_moving = pose;
            let small_step =
                delta.translation.vector.norm() < 1e-7 && delta.rotation.angle() < 1e-9;
            let settled = last_rms.is_finite()
                && (last_rms - rms).abs() <= params.tolerance * last_rms.max(1e-12);
            if res == 1 && n + 1 >= params.min_iterations && (small_step || settled) {
                result.converged = true;
                break;
            }
            if res == 1 {
                last_rms = rms;
            }
        }
        tracing::debug!(
            rms = result.rms,
            overlap = result.overlap,
            iterations = result.iterations,
            converged = result.converged,
            "icp"
        );
        result
    }

    /// One linearised point-to-plane step: minimise Σ ((ω × p + t + p − q) · n)².
    fn plane_step(
        &self,
        moving: &[[f64; 3]],
        pose: &Pose,
        kept: &[&(usize, usize, f64)],
    ) -> Option<Pose> {
        let normals = self.normals.as_ref()?;
        let eq = super::accumulate(kept, |k| {
            let n = Vector3::from(normals[k.1]);
            if n.norm_squared() <= 0.5 {
                return None;
            }
            let p = (pose * Point3::from(moving[k.0])).coords;
            let q = Vector3::from(self.points[k.1]);
            let c = p.cross(&n);
            Some((
                Vector6::new(c.x, c.y, c.z, n.x, n.y, n.z),
                (q - p).dot(&n),
                1.0,
            ))
        });
        let (ata, atb) = (eq.ata, eq.atb);
        let x = ata.cholesky()?.solve(&atb);
        let omega = Vector3::new(x[0], x[1], x[2]);
        let rot = UnitQuaternion::from_scaled_axis(omega);
        Some(Pose::from_parts(Vector3::new(x[3], x[4], x[5]).into(), rot))
    }
}
