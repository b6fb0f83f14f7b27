//! Tile consensus for the trusted-region fit. Trimming by deviation has a blind spot on a
//! gently curved part: once a deformation has pulled the fit along the surface, the part's
//! features (where the slide is pinned) show large deviations at that pose and are trimmed,
//! and the remaining, weakly pinning surface keeps the fit where it is. A rigid misfit and a
//! deformation differ in one way that does not depend on the pose: a rigid motion explains
//! the misfit of an undeformed region *and* keeps the trusted set on the CAD, while nothing
//! rigid explains a bump. So each region the trimming left out is tried jointly with the
//! trusted set; one that then sits on the CAD within the noise, without lifting the trusted
//! set off it, is undeformed and rejoins.

use nalgebra::{Point3, SymmetricEigen, Vector3};
use rayon::prelude::*;

use super::{fit_to_surface, median, selected, to_cad};
use crate::mesh::SignedDistance;
use crate::register::Pose;

/// Tiles along the part's longer principal axis.
const TILES_LONG: usize = 8;
/// Trusted points a joint fit uses at most.
const MAX_TRUSTED: usize = 8_000;
/// Points of a tile a joint fit uses at most.
const MAX_TILE: usize = 600;

/// Points of `pts` (cloud frame) in left-out tiles that a rigid motion puts on the CAD
/// together with the `trusted` ones (noise σ `noise`), with the joint pose; `None` when no
/// tile is admitted.
pub(super) fn admit(
    pts: &[[f64; 3]],
    trusted: &[bool],
    cad: &SignedDistance,
    pose: &Pose,
    noise: f64,
) -> Option<(Vec<bool>, Pose)> {
    let cad_pts = to_cad(pts, pose);
    let tile = tiles(&cad_pts);
    let count = tile.iter().copied().max().map_or(0, |m| m + 1);
    let trusted_idx: Vec<usize> = (0..pts.len()).filter(|&i| trusted[i]).collect();
    let base: Vec<[f64; 3]> = trusted_idx
        .iter()
        .step_by((trusted_idx.len() / MAX_TRUSTED).max(1))
        .map(|&i| pts[i])
        .collect();
    if base.len() < 100 {
        return None;
    }
    let sigma = noise.max(1e-4);
    let rms_about_median = |set: &[[f64; 3]], p: &Pose, centre: Option<f64>| {
        let d: Vec<f64> = cad
            .query_all(&to_cad(set, p))
            .into_iter()
            .filter(|d| d.is_finite())
            .collect();
        let m = centre.unwrap_or_else(|| median(&d));
        let rms = (d.iter().map(|x| (x - m).powi(2)).sum::<f64>() / d.len().max(1) as f64).sqrt();
        (rms, m)
    };
    let (base_rms, _) = rms_about_median(&base, pose, None);
    let all = |_: &[f64; 3], _: f64| 1.0;
    let admitted: Vec<(usize, Pose)> = (0..count)
        .into_par_iter()
        .filter_map(|t| {
            let members: Vec<usize> = (0..pts.len()).filter(|&i| tile[i] == t).collect();
            let inside = members.iter().filter(|&&i| trusted[i]).count();
            if members.len() < 30 || 2 * inside >= members.len() {
                return None;
            }
            let sample: Vec<[f64; 3]> = members
                .iter()
                .step_by((members.len() / MAX_TILE).max(1))
                .map(|&i| pts[i])
                .collect();
            // Weight the tile like the trusted points of an equal area, so a rigid motion
            // must serve both.
            let mut joint = base.clone();
            joint.extend_from_slice(&sample);
            let (p, _) = fit_to_surface(&joint, cad, *pose, 30, &all);
            let (rms_base, m) = rms_about_median(&base, &p, None);
            let (rms_tile, _) = rms_about_median(&sample, &p, Some(m));
            (rms_tile <= 2.0 * sigma && rms_base <= base_rms + 0.25 * sigma).then_some((t, p))
        })
        .collect();
    tracing::debug!(tiles = count, admitted = admitted.len(), "tile consensus");
    if admitted.is_empty() {
        return None;
    }
    let chosen: Vec<bool> = (0..count)
        .map(|t| admitted.iter().any(|(a, _)| *a == t))
        .collect();
    let mask: Vec<bool> = (0..pts.len())
        .map(|i| trusted[i] || chosen[tile[i]])
        .collect();
    let set = selected(pts, &mask);
    let (joint, _) = fit_to_surface(&set, cad, *pose, 60, &all);
    Some((mask, joint))
}

/// Tile index of each point: a grid on the points' principal plane, square cells,
/// [`TILES_LONG`] along the longer axis.
fn tiles(cad_pts: &[[f64; 3]]) -> Vec<usize> {
    let n = cad_pts.len().max(1) as f64;
    let c = cad_pts
        .iter()
        .fold(Vector3::zeros(), |a, p| a + Vector3::from(*p))
        / n;
    let cov = cad_pts.iter().fold(nalgebra::Matrix3::zeros(), |a, p| {
        let d = Vector3::from(*p) - c;
        a + d * d.transpose()
    }) / n;
    let eig = SymmetricEigen::new(cov);
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    let axes = [
        eig.eigenvectors.column(order[0]).into_owned(),
        eig.eigenvectors.column(order[1]).into_owned(),
    ];
    let uv: Vec<[f64; 2]> = cad_pts
        .iter()
        .map(|p| {
            let d = Point3::from(*p) - Point3::from(c);
            [d.dot(&axes[0]), d.dot(&axes[1])]
        })
        .collect();
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for q in &uv {
        for k in 0..2 {
            lo[k] = lo[k].min(q[k]);
            hi[k] = hi[k].max(q[k]);
        }
    }
    let size = ((hi[0] - lo[0]) / TILES_LONG as f64).max(1e-6);
    let cols = ((hi[1] - lo[1]) / size).ceil().max(1.0) as usize;
    uv.iter()
        .map(|q| {
            let i = (((q[0] - lo[0]) / size) as usize).min(TILES_LONG - 1);
            let j = (((q[1] - lo[1]) / size) as usize).min(cols - 1);
            i * cols + j
        })
        .collect()
}
