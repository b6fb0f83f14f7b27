//! How much the registration depends on any one part of the surface it was fitted to. The
//! trusted points are cut into tiles on their principal plane; the fit is repeated leaving out
//! each tile in turn, and the largest motion this causes at the points is the registration's
//! *location stability*. Noise moves a well-pinned fit by microns; a deformation that
//! trimming could not separate (a broad bulge's shoulders on a weakly pinned, gently curved
//! panel) pulls the fit along the surface, and leaving out its tile shows by how much. The
//! conditioning report says how far a fit *could* slide; this says how far the data *do* pull
//! it, so a map whose deviations may sit up to that far from where they are is said so.

use std::sync::atomic::{AtomicU32, Ordering};

use nalgebra::{Point3, SymmetricEigen, Vector3};
use rayon::prelude::*;
use serde::Serialize;

use super::{fit_with_edges_hinted, no_hints, rim::Edge};
use crate::mesh::SignedDistance;
use crate::register::Pose;

/// Tiles per side of the grid on the principal plane.
const GRID: usize = 4;
/// Points the refits use at most (a uniform subsample of the trusted set).
const MAX_POINTS: usize = 6_000;
/// Iteration limit of each refit (they start at the fitted pose).
const MAX_ITERATIONS: usize = 30;
/// A refit has converged when its step moves no point within two RMS radii by more than this,
/// mm: the stability is reported to a micrometre, and the refits' last steps to the fits' own
/// 10 nm moved it by less.
const CONVERGED_MM: f64 = 1e-4;

/// The location stability of a registration.
#[derive(Clone, Debug, Serialize)]
pub struct Stability {
    /// Tiles left out in turn.
    pub tiles: usize,
    /// The largest motion of any fitted point when one tile is left out, mm.
    pub shift_mm: f64,
    /// Centre (CAD frame) of the tile whose removal moves the fit most.
    pub worst_tile: [f64; 3],
}

/// Refit `trusted` (cloud frame) to `cad` from `pose` leaving out each tile in turn; the
/// `edges` held on the CAD's rim (none without a rim-aware fit) stay in every refit.
pub(super) fn analyse(
    trusted: &[[f64; 3]],
    cad: &SignedDistance,
    pose: &Pose,
    edges: &[Edge],
) -> Option<Stability> {
    let step = (trusted.len() / MAX_POINTS).max(1);
    let pts: Vec<[f64; 3]> = trusted.iter().step_by(step).copied().collect();
    if pts.len() < 20 * GRID * GRID {
        return None;
    }
    let cad_pts: Vec<Vector3<f64>> = pts
        .iter()
        .map(|p| (pose * Point3::from(*p)).coords)
        .collect();
    let n = cad_pts.len() as f64;
    let centre = cad_pts.iter().sum::<Vector3<f64>>() / n;
    let cov = cad_pts.iter().fold(nalgebra::Matrix3::zeros(), |a, p| {
        a + (p - centre) * (p - centre).transpose()
    }) / n;
    let eig = SymmetricEigen::new(cov);
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    let (eu, ev) = (
        eig.eigenvectors.column(order[0]).into_owned(),
        eig.eigenvectors.column(order[1]).into_owned(),
    );
    let uv: Vec<(f64, f64)> = cad_pts
        .iter()
        .map(|p| ((p - centre).dot(&eu), (p - centre).dot(&ev)))
        .collect();
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for &(u, v) in &uv {
        lo = [lo[0].min(u), lo[1].min(v)];
        hi = [hi[0].max(u), hi[1].max(v)];
    }
    let cell = |x: f64, k: usize| {
        let f = (x - lo[k]) / (hi[k] - lo[k]).max(1e-9);
        ((f * GRID as f64) as usize).min(GRID - 1)
    };
    let tile: Vec<usize> = uv
        .iter()
        .map(|&(u, v)| cell(u, 0) * GRID + cell(v, 1))
        .collect();
    let all = |_: &[f64; 3], _: f64| 1.0;
    // Each refit's queries start from the triangles the reference ended on (a hint changes no
    // answer, only where the search begins).
    let hints = no_hints(pts.len());
    let (reference, _) = fit_with_edges_hinted(
        &pts,
        cad,
        *pose,
        (MAX_ITERATIONS, super::CONVERGED_MM),
        &all,
        edges,
        &hints,
    );
    let probe: Vec<Point3<f64>> = pts.iter().step_by(7).map(|p| Point3::from(*p)).collect();
    let tiles: Vec<usize> = (0..GRID * GRID)
        .filter(|t| tile.iter().filter(|x| *x == t).count() * GRID * GRID * 4 >= pts.len())
        .collect();
    let shifts: Vec<(f64, usize)> = tiles
        .par_iter()
        .map(|&t| {
            let (kept, hints): (Vec<[f64; 3]>, Vec<AtomicU32>) = pts
                .iter()
                .zip(&tile)
                .zip(&hints)
                .filter(|((_, x), _)| **x != t)
                .map(|((p, _), h)| (*p, AtomicU32::new(h.load(Ordering::Relaxed))))
                .unzip();
            let (refit, _) = fit_with_edges_hinted(
                &kept,
                cad,
                reference,
                (MAX_ITERATIONS, CONVERGED_MM),
                &all,
                edges,
                &hints,
            );
            let shift = probe
                .iter()
                .map(|p| (refit * p - reference * p).norm())
                .fold(0.0, f64::max);
            (shift, t)
        })
        .collect();
    let (shift, worst) = shifts.iter().copied().max_by(|a, b| a.0.total_cmp(&b.0))?;
    let members: Vec<&Vector3<f64>> = cad_pts
        .iter()
        .zip(&tile)
        .filter(|(_, x)| **x == worst)
        .map(|(p, _)| p)
        .collect();
    let worst_tile = members.iter().copied().sum::<Vector3<f64>>() / members.len().max(1) as f64;
    Some(Stability {
        tiles: tiles.len(),
        shift_mm: shift,
        worst_tile: worst_tile.into(),
    })
}
