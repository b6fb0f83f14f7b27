//! Inspection against CAD (Ch. 5.3, SPEC §9): object-oriented registration that does not absorb
//! the part's deformation, signed deviations, statistics, datum residuals, out-of-tolerance
//! regions and a pass/fail verdict.
//!
//! Registration fits the cloud to the CAD surface (point-to-plane against the true closest
//! points of the mesh) using only *trusted* points: the datum regions when the part has datums;
//! otherwise regions estimated from the curvature of the deviation field (flat where only a
//! rigid misalignment acts) and trimmed iteratively (fit, drop points whose deviation departs
//! from the trusted median by more than an annealed threshold, refit, until the set converges);
//! regions the trimming left out rejoin when a rigid motion puts them back on the CAD with the
//! rest (tile consensus), and the whole is repeated from the new pose until it stops moving.
//! How far leaving out any one region moves the fit is reported as its stability.

mod alignment;
pub(crate) mod canvas;
mod characteristics;
mod conditioning;
mod consensus;
mod coverage;
mod datums;
mod features;
mod frame;
mod output;
mod regions;
mod report;
mod rim;
mod stability;
mod surface;

pub use alignment::Alignment;
pub use canvas::Label;
pub use characteristics::{
    evaluate as evaluate_characteristics, load_characteristics, resolve as resolve_characteristics,
    Characteristic, CharacteristicResult, CharacteristicSpec, Kind as CharacteristicKind,
};
pub use conditioning::{analyse as conditioning, Conditioning, Direction, UNPINNED_STRENGTH};
pub use coverage::{coverage, Coverage};
pub use datums::{
    check_against as check_datums_against, level_dofs, load_datums, validate as validate_datums,
    Datum, Feature,
};
pub use frame::DatumMeasurement;
pub use output::{
    deviation_colour, render_deviation_map, verdict_colour, write_deviation_ply,
    write_deviation_png, DeviationMap, MapTitle,
};
pub use regions::{out_of_tolerance_regions, Region};
pub use report::{DatumResidual, Report, Statistics, NOT_MEASURED};
pub use rim::RimUse;
pub use stability::Stability;
pub use surface::{seen, InspectedSurface, Viewpoint, GRAZING_LIMIT_DEG};

use nalgebra::{Matrix6, Point3, UnitQuaternion, Vector3, Vector6};
use rayon::prelude::*;
use std::sync::atomic::{AtomicU32, Ordering};

use crate::mesh::SignedDistance;
use crate::register::Pose;
use crate::{Error, Result};
use datums::in_datums;

/// Inspection settings.
#[derive(Clone, Debug)]
pub struct InspectParams {
    /// Tolerance on |deviation|, mm.
    pub tolerance: f64,
    /// Datum regions (empty: trusted regions by iterative trimming).
    pub datums: Vec<Datum>,
    /// Initial cad_from_cloud; `None` = coarse alignment by principal axes.
    pub init: Option<Pose>,
    /// Register the cloud (from `init` or a coarse alignment); `false`: `init` is the pose as
    /// known (a calibrated cell, a measured transform) and nothing is fitted, so the
    /// deviations are those of the cloud where it lies.
    pub fit_pose: bool,
    /// Iteration limit of each fit.
    pub max_iterations: usize,
    /// Points used for fitting (a uniform subsample of the cloud; deviations use every point).
    pub fit_points: usize,
    /// Minimum fraction of the CAD surface that must have been measured for a verdict; below
    /// it the part is `not_measured`.
    pub min_coverage: f64,
    /// Minimum points in each datum region for a verdict.
    pub min_datum_points: usize,
    /// The part of the CAD that coverage and the verdict are about.
    pub surface: InspectedSurface,
    /// Toleranced characteristics on the CAD's faces (ISO 1101), each in the verdict.
    pub characteristics: Vec<Characteristic>,
}

impl Default for InspectParams {
    fn default() -> Self {
        InspectParams {
            tolerance: 0.5,
            datums: Vec::new(),
            init: None,
            fit_pose: true,
            max_iterations: 60,
            fit_points: 50_000,
            min_coverage: 0.5,
            min_datum_points: 10,
            surface: InspectedSurface::Whole,
            characteristics: Vec::new(),
        }
    }
}

/// The result: the cloud in the CAD frame with its deviations, and the report.
pub struct Inspection {
    /// Points in the CAD frame.
    pub points: Vec<[f64; 3]>,
    /// Signed deviation per point (SPEC §2 sign), mm.
    pub deviations: Vec<f64>,
    /// The report (verdict, transform, statistics, datums, regions).
    pub report: Report,
}

/// Register `cloud` to the CAD surface and measure its deviations.
pub fn inspect(
    cloud: &[[f64; 3]],
    cad: &SignedDistance,
    params: &InspectParams,
) -> Result<Inspection> {
    // A point with a NaN or infinite coordinate carries no measurement (and would stall the
    // rotation fits): left out, and counted in the report.
    let finite: Vec<[f64; 3]>;
    let mut non_finite = 0;
    let cloud = if cloud.iter().all(|p| p.iter().all(|c| c.is_finite())) {
        cloud
    } else {
        finite = cloud
            .iter()
            .filter(|p| p.iter().all(|c| c.is_finite()))
            .copied()
            .collect();
        non_finite = cloud.len() - finite.len();
        &finite
    };
    if let Some(bounds) = cad.mesh().bounds() {
        datums::check_against("datums", &params.datums, bounds)?;
    }
    if !(0.0..=1.0).contains(&params.min_coverage) {
        return Err(Error::invalid(
            "inspection",
            "min_coverage",
            format!("{} must be within 0 … 1", params.min_coverage),
        ));
    }
    if cloud.len() < 10 {
        return Err(Error::Insufficient(format!(
            "the cloud has {} points; inspection needs at least 10",
            cloud.len()
        )));
    }
    if !(params.tolerance.is_finite() && params.tolerance > 0.0) {
        return Err(Error::invalid(
            "inspection",
            "tolerance",
            format!("{} must be positive", params.tolerance),
        ));
    }
    params.surface.triangle_mask(cad.mesh())?;
    if !params.fit_pose {
        let pose = params.init.ok_or_else(|| {
            Error::invalid(
                "inspection",
                "init",
                "a known pose (fit_pose = false) needs the pose itself",
            )
        })?;
        return Ok(known_pose(cloud, cad, params, pose, non_finite));
    }
    let clock = std::time::Instant::now();
    let lap = |phase: &str| {
        tracing::debug!(
            seconds = clock.elapsed().as_secs_f64(),
            "inspection: {phase}"
        )
    };
    let step = (cloud.len() / params.fit_points.max(1)).max(1);
    let fit: Vec<[f64; 3]> = cloud.iter().step_by(step).copied().collect();
    let (start, mut alignment, contenders) = match params.init {
        Some(p) => (p, None, vec![p]),
        None => {
            let (p, a, c) = alignment::coarse_alignment(&fit, cad, params.tolerance);
            (p, Some(a), c)
        }
    };
    lap("coarse alignment");
    crate::budget::check()?;
    let framed = params.datums.iter().any(|d| d.order.is_some());
    let mut measurements = Vec::new();
    let mut frame_conditioning = None;
    let mut frame_warning = None;
    let mut stability = None;
    let mut rim_fit = None;
    let (pose, mode, trusted_fit, iterations) = if framed {
        let f = frame_from_contenders(cloud, &fit, cad, params, &contenders, alignment.as_mut());
        if !f.converged {
            frame_warning = Some(format!(
                "the datum frame fit had not converged after {} iterations: the datums' features may disagree with each other",
                f.iterations
            ));
        }
        measurements = f.measurements;
        frame_conditioning = Some(f.conditioning);
        (f.pose, "datum-frame", 0.0, f.iterations)
    } else if params.datums.is_empty() {
        let (pose, mode, frac, it, trusted, rim) =
            trusted_region_fit(&fit, cloud, cad, start, params, &contenders[1..]);
        // Where the part's pose was given (a cell's fixture) and neither the surface nor the
        // rim pins a motion, the report says the part lies along it where the fixture holds
        // it: so it does, whatever the noise and the deformation drew the fit to. (Judged on
        // the points the report's conditioning judges.)
        let pose = match params.init {
            Some(held) if rim.as_ref().is_none_or(|r| r.summary.ambiguous.is_some()) => {
                conditioning::held_along_unpinned(&fit, cad, &pose, &held, near_surface(params))
            }
            _ => pose,
        };
        // A fit cut short by its budget is not judged.
        crate::budget::check()?;
        // Contending coarse poses that fit the surface as well but not the rim: the rim
        // settles which one the part is in.
        if let (Some(a), Some(r)) = (
            alignment.as_mut().filter(|a| a.ambiguous || a.symmetric),
            rim.as_ref(),
        ) {
            if contenders.len() > 1 && !r.turned_rival && r.summary.ambiguous.is_none() {
                a.ambiguous = false;
                a.symmetric = false;
                a.settled_by = Some(format!(
                    "the CAD's rim: of {} contending poses only this one puts the scan's edges on it ({:.0} mm of it)",
                    contenders.len(),
                    r.summary.seen_mm
                ));
            }
        }
        lap("trusted-region fit");
        let edges = rim.as_ref().map_or(&[][..], |r| &r.edges[..]);
        stability = stability::analyse(&trusted, cad, &pose, edges);
        lap("stability");
        rim_fit = rim;
        (pose, mode, frac, it)
    } else {
        datum_fit(&fit, cad, start, params)
    };
    crate::budget::check()?;
    let points = to_cad(cloud, &pose);
    let (deviations, outside) = inspected_deviations(&points, cad, params);
    lap("deviations");
    crate::budget::check()?;
    let (coverage, near) = surface_coverage(&points, &deviations, cad, params, &pose);
    lap("coverage");
    // What the fit used: the datum regions when the part has datums, else the surface; a
    // datum frame states its own.
    let conditioning = match frame_conditioning {
        Some(c) => c,
        None => {
            let fit_cad: Vec<[f64; 3]> = to_cad(&fit, &pose)
                .into_iter()
                .filter(|p| params.datums.is_empty() || in_datums(p, &params.datums))
                .collect();
            let edges: Vec<(Vector3<f64>, Vector3<f64>, f64)> = rim_fit
                .as_ref()
                .filter(|r| r.summary.ambiguous.is_none())
                .map(|r| {
                    r.edges
                        .iter()
                        .map(|e| (e.plane, e.normal, e.weight))
                        .collect()
                })
                .unwrap_or_default();
            conditioning::analyse_with_edges(&fit_cad, cad, near, params.tolerance, &edges)
        }
    };
    lap("conditioning");
    let mut report = report::build(
        &points,
        &deviations,
        &pose,
        params,
        report::Fit {
            mode,
            iterations,
            trusted_fraction: trusted_fit,
            conditioning,
            alignment,
            measurements,
            stability,
            rim: rim_fit.map(|r| r.summary),
        },
        coverage,
        non_finite,
    );
    count_outside(&mut report, outside);
    report::add_characteristics(
        &mut report,
        characteristics::evaluate(&points, cad, &params.characteristics),
    );
    report.warnings.extend(frame_warning);
    tracing::info!(verdict = %report.verdict, rms = report.statistics.rms, mode, "inspected");
    Ok(Inspection {
        points,
        deviations,
        report,
    })
}

/// The distance from the CAD surface within which a point counts as on it: the deformation a
/// part may plausibly have, mm.
fn near_surface(params: &InspectParams) -> f64 {
    (20.0 * params.tolerance).max(10.0)
}

/// How much of the CAD the points on its nominal surface cover, and the distance that counts
/// as on it: within the deformation a part may plausibly have, so that a cloud registered next
/// to the CAD measures nothing.
fn surface_coverage(
    points: &[[f64; 3]],
    deviations: &[f64],
    cad: &SignedDistance,
    params: &InspectParams,
    pose: &Pose,
) -> (coverage::Coverage, f64) {
    let near = near_surface(params);
    let on_surface: Vec<[f64; 3]> = points
        .iter()
        .zip(deviations)
        .step_by((points.len() / params.fit_points.max(1)).max(1))
        .filter(|(_, d)| d.abs() <= near)
        .map(|(p, _)| *p)
        .collect();
    let (samples, area) = coverage::surface_samples(cad.mesh(), coverage::SAMPLES);
    let total = samples.len().max(1) as f64;
    let keep: Vec<bool> = match &params.surface {
        InspectedSurface::Whole => vec![true; samples.len()],
        InspectedSurface::Faces { triangles, .. } => samples
            .iter()
            .map(|(_, t)| triangles[*t as usize])
            .collect(),
        InspectedSurface::SeenFrom(views) => {
            // the sensors' centres move with the cloud into the CAD's frame
            let moved: Vec<Viewpoint> = views.iter().map(|v| v.moved(pose)).collect();
            surface::seen(cad.bvh(), &samples, &moved)
        }
    };
    let inspected: Vec<[f64; 3]> = samples
        .iter()
        .zip(&keep)
        .filter(|(_, k)| **k)
        .map(|((p, _), _)| *p)
        .collect();
    let share = inspected.len() as f64 / total;
    (
        coverage::coverage_of(
            &inspected,
            area * share,
            &on_surface,
            params.min_coverage,
            params.surface.describe(),
        ),
        near,
    )
}

/// The deviations of `points` (CAD frame), NaN beyond the CAD's open boundary and, with named
/// faces, where the closest CAD triangle is not one of theirs; and how many the faces left out.
fn inspected_deviations(
    points: &[[f64; 3]],
    cad: &SignedDistance,
    params: &InspectParams,
) -> (Vec<f64>, usize) {
    match &params.surface {
        InspectedSurface::Faces { triangles, .. } => {
            let d = cad.deviations_on(points, triangles);
            let all = cad.deviations(points);
            let outside = d
                .iter()
                .zip(&all)
                .filter(|(a, b)| a.is_nan() && !b.is_nan())
                .count();
            (d, outside)
        }
        _ => (cad.deviations(points), 0),
    }
}

/// Points left out as closest to a face that is not inspected are not "beyond the CAD".
fn count_outside(report: &mut Report, outside: usize) {
    report.statistics.beyond_cad -= outside.min(report.statistics.beyond_cad);
    report.statistics.outside_inspected = outside;
}

/// The inspection at a known pose: the deviations of every point where `pose` puts it, the
/// coverage and the verdict; nothing is fitted (the distance tool's work, and its time).
fn known_pose(
    cloud: &[[f64; 3]],
    cad: &SignedDistance,
    params: &InspectParams,
    pose: Pose,
    non_finite: usize,
) -> Inspection {
    let points = to_cad(cloud, &pose);
    let (deviations, outside) = inspected_deviations(&points, cad, params);
    let (coverage, _) = surface_coverage(&points, &deviations, cad, params, &pose);
    let mut report = report::build(
        &points,
        &deviations,
        &pose,
        params,
        report::Fit {
            mode: "known pose",
            iterations: 0,
            trusted_fraction: 0.0,
            conditioning: Conditioning::not_fitted(),
            alignment: None,
            measurements: Vec::new(),
            stability: None,
            rim: None,
        },
        coverage,
        non_finite,
    );
    count_outside(&mut report, outside);
    report::add_characteristics(
        &mut report,
        characteristics::evaluate(&points, cad, &params.characteristics),
    );
    tracing::debug!(verdict = %report.verdict, rms = report.statistics.rms, "inspected at a known pose");
    Inspection {
        points,
        deviations,
        report,
    }
}

/// The datum frame fitted from each coarse-alignment contender (a robust fit on everything first
/// brings the datums into reach); the one that measures the most datums wins, then the one that
/// puts the most points on the CAD. A symmetric part's ambiguity is settled when only that one
/// measures every datum.
fn frame_from_contenders(
    cloud: &[[f64; 3]],
    fit: &[[f64; 3]],
    cad: &SignedDistance,
    params: &InspectParams,
    contenders: &[Pose],
    alignment: Option<&mut Alignment>,
) -> frame::FrameFit {
    let band = (3.0 * params.tolerance).max(0.5);
    let sample: Vec<[f64; 3]> = fit
        .iter()
        .step_by((fit.len() / 5000).max(1))
        .copied()
        .collect();
    let mut tries: Vec<(usize, f64, frame::FrameFit)> = contenders
        .iter()
        .map(|start| {
            let (rough, it) = fit_to_surface(fit, cad, *start, 15, &|_, d| {
                if d.abs() < 5.0 {
                    1.0
                } else {
                    0.0
                }
            });
            let mut f = frame::fit(cloud, cad, &params.datums, rough, params.tolerance);
            f.iterations += it;
            let measured = f.measurements.iter().filter(|m| m.error.is_none()).count();
            let on = cad
                .query_all(&to_cad(&sample, &f.pose))
                .iter()
                .filter(|d| d.abs() <= band)
                .count();
            (measured, on as f64 / sample.len().max(1) as f64, f)
        })
        .collect();
    tries.sort_by(|a, b| b.0.cmp(&a.0).then(b.1.total_cmp(&a.1)));
    if let Some(a) = alignment.filter(|a| a.ambiguous) {
        let best = &tries[0];
        let rivals = tries[1..]
            .iter()
            .filter(|t| t.0 == best.0 && t.1 >= 0.9 * best.1)
            .filter(|t| {
                let rel = t.2.pose * best.2.pose.inverse();
                crate::register::rotation_angle_deg(&rel) > 2.0
                    || rel.translation.vector.norm() > 5.0
            })
            .count();
        if rivals == 0 && best.0 == params.datums.len() {
            a.ambiguous = false;
            a.settled_by = Some(format!(
                "datum frame: of {} contending poses only this one measures every datum",
                tries.len()
            ));
        }
    }
    tries.swap_remove(0).2
}

/// The points of `pts` whose entry in `mask` is set.
fn selected(pts: &[[f64; 3]], mask: &[bool]) -> Vec<[f64; 3]> {
    pts.iter()
        .zip(mask)
        .filter(|(_, m)| **m)
        .map(|(p, _)| *p)
        .collect()
}

/// `pts` mapped into the CAD frame by `pose`.
fn to_cad(pts: &[[f64; 3]], pose: &Pose) -> Vec<[f64; 3]> {
    pts.par_iter()
        .map(|p| (pose * Point3::from(*p)).coords.into())
        .collect()
}

fn median(v: &[f64]) -> f64 {
    let mut s: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    if s.is_empty() {
        return 0.0;
    }
    let m = s.len() / 2;
    *s.select_nth_unstable_by(m, f64::total_cmp).1
}

/// Trusted seeds: points whose neighbourhood shows a deviation field without significant
/// curvature. A rigid misalignment leaves the deviation field near-affine; a deformation bends it.
/// The quadratic terms of a local fit dev ≈ a + b u + c v + d u² + e uv + f v² (u, v in the
/// local tangent plane, 200 neighbours of a ~10 k subsample) are compared with what the
/// measurement noise alone would give; neighbourhoods bent beyond two sigmas are left out.
fn flat_seeds(pts: &[[f64; 3]], cad: &SignedDistance, pose: &Pose) -> Vec<bool> {
    const K: usize = 200;
    let cad_pts = to_cad(pts, pose);
    // Bending is estimated on a ~10 k-point subsample, so 200 neighbours span a wide patch
    // (its quadratic terms are then far above the noise).
    let sub: Vec<usize> = (0..pts.len())
        .step_by((pts.len() / 10_000).max(1))
        .collect();
    let sub_pts: Vec<[f64; 3]> = sub.iter().map(|&i| cad_pts[i]).collect();
    let sub_dev = cad.query_all(&sub_pts);
    let tree = crate::spatial::KdTree::new(&sub_pts);
    let sigma = local_noise(&sub_pts, &tree, &sub_dev).max(1e-6);
    let centres: Vec<usize> = (0..sub_pts.len()).step_by(3).collect();
    let bend: Vec<f64> = centres
        .par_iter()
        .map_init(Vec::new, |nn, &c| {
            tree.k_nearest(&sub_pts[c], K, nn);
            let o = Vector3::from(sub_pts[c]);
            let mut cov = nalgebra::Matrix3::<f64>::zeros();
            for &(i, _) in nn.iter() {
                let d = Vector3::from(sub_pts[i]) - o;
                cov += d * d.transpose();
            }
            let e = cov.symmetric_eigen();
            let mut idx = [0usize, 1, 2];
            idx.sort_by(|&i, &j| e.eigenvalues[j].total_cmp(&e.eigenvalues[i]));
            let (eu, ev) = (
                e.eigenvectors.column(idx[0]).into_owned(),
                e.eigenvectors.column(idx[1]).into_owned(),
            );
            let mut ata = Matrix6::<f64>::zeros();
            let mut atb = Vector6::<f64>::zeros();
            for &(i, _) in nn.iter() {
                if !sub_dev[i].is_finite() {
                    continue;
                }
                let d = Vector3::from(sub_pts[i]) - o;
                let (u, v) = (d.dot(&eu), d.dot(&ev));
                let row = Vector6::new(1.0, u, v, u * u, u * v, v * v);
                ata += row * row.transpose();
                atb += row * sub_dev[i];
            }
            // Bending and its expected value from noise alone (σ² (AᵀA)⁻¹ on the quadratic
            // terms): their ratio is a significance, independent of patch size and density.
            match ata.try_inverse() {
                Some(inv) => {
                    let x = inv * atb;
                    let bend2 = x[3] * x[3] + 0.5 * x[4] * x[4] + x[5] * x[5];
                    let noise2 = sigma * sigma * (inv[(3, 3)] + 0.5 * inv[(4, 4)] + inv[(5, 5)]);
                    (bend2 / noise2.max(1e-300)).sqrt()
                }
                None => f64::INFINITY,
            }
        })
        .collect();
    // Flat: bending within two noise sigmas (pure noise gives 1.5 at the 90th percentile).
    let limit = 2.0;
    let flat: Vec<bool> = bend.iter().map(|b| *b <= limit).collect();
    let centre_pts: Vec<[f64; 3]> = centres.iter().map(|&c| sub_pts[c]).collect();
    let centre_tree = crate::spatial::KdTree::new(&centre_pts);
    let seed: Vec<bool> = cad_pts
        .par_iter()
        .map(|p| centre_tree.nearest(p).is_some_and(|(c, _)| flat[c]))
        .collect();
    if seed.iter().filter(|s| **s).count() < pts.len() / 10 {
        return vec![true; pts.len()];
    }
    seed
}

/// Robust σ of the measurement noise: deviation minus the mean deviation of its 16 nearest
/// neighbours, scaled for the neighbour mean's own noise; at most 20 000 points, evenly spread,
/// are the centres (the median's own scatter is then under 1 %). `tree` indexes `points` (in
/// any frame: only the distances between them count).
fn local_noise(points: &[[f64; 3]], tree: &crate::spatial::KdTree, dev: &[f64]) -> f64 {
    const K: usize = 16;
    const CENTRES: usize = 20_000;
    let resid: Vec<f64> = points
        .par_iter()
        .zip(dev.par_iter())
        .step_by((points.len() / CENTRES).max(1))
        .map_init(Vec::new, |nn, (p, d)| {
            tree.k_nearest(p, K + 1, nn);
            let (sum, count) = nn
                .iter()
                .filter(|(i, d2)| *d2 > 0.0 && dev[*i].is_finite())
                .fold((0.0, 0usize), |(s, c), (i, _)| (s + dev[*i], c + 1));
            if count == 0 || !d.is_finite() {
                return f64::NAN;
            }
            d - sum / count as f64
        })
        .collect();
    let abs: Vec<f64> = resid
        .iter()
        .filter(|r| r.is_finite())
        .map(|r| r.abs())
        .collect();
    1.4826 * median(&abs) / (1.0 + 1.0 / K as f64).sqrt()
}

fn fit_to_surface(
    pts: &[[f64; 3]],
    cad: &SignedDistance,
    pose: Pose,
    max_iter: usize,
    weight: &(dyn Fn(&[f64; 3], f64) -> f64 + Sync),
) -> (Pose, usize) {
    fit_with_edges(pts, cad, pose, max_iter, weight, &[])
}

/// [`fit_to_surface`] with measured edges held on the CAD's rim (see [`rim`]): each a
/// point-to-plane row of its own weight beside the surface's.
fn fit_with_edges(
    pts: &[[f64; 3]],
    cad: &SignedDistance,
    pose: Pose,
    max_iter: usize,
    weight: &(dyn Fn(&[f64; 3], f64) -> f64 + Sync),
    edges: &[rim::Edge],
) -> (Pose, usize) {
    let hints = no_hints(pts.len());
    fit_with_edges_hinted(
        pts,
        cad,
        pose,
        (max_iter, CONVERGED_MM),
        weight,
        edges,
        &hints,
    )
}

/// One closest-triangle hint per point of a fit, none known yet.
fn no_hints(n: usize) -> Vec<AtomicU32> {
    (0..n).map(|_| AtomicU32::new(u32::MAX)).collect()
}

/// [`fit_with_edges`] whose closest-point queries start from `hints` (one per point: its
/// closest triangle in an earlier fit of the same points from a nearby pose) and leave their
/// answers there. The hints make the queries faster, never different. The fit stops after
/// `max_iter` steps or at a step that moves no point within two RMS radii of the centroid
/// farther than `converged` mm.
fn fit_with_edges_hinted(
    pts: &[[f64; 3]],
    cad: &SignedDistance,
    mut pose: Pose,
    (max_iter, converged): (usize, f64),
    weight: &(dyn Fn(&[f64; 3], f64) -> f64 + Sync),
    edges: &[rim::Edge],
    hints: &[AtomicU32],
) -> (Pose, usize) {
    if pts.is_empty() {
        return (pose, 0);
    }
    debug_assert_eq!(hints.len(), pts.len());
    // Rotations about the points' centroid, scaled by their RMS radius: every unknown in mm
    // and the strengths comparable with the conditioning report's.
    let n = pts.len() as f64;
    let centroid = pts
        .iter()
        .fold(Vector3::zeros(), |a, p| a + Vector3::from(*p))
        / n;
    let radius = (pts
        .iter()
        .map(|p| (Vector3::from(*p) - centroid).norm_squared())
        .sum::<f64>()
        / n)
        .sqrt()
        .max(1e-6);
    // Each point's closest triangle of the previous iteration starts its next query.
    let index: Vec<usize> = (0..pts.len()).collect();
    let mut it = 0;
    let mut trail: Vec<Pose> = Vec::new();
    while it < max_iter {
        it += 1;
        let centre = (pose * Point3::from(centroid)).coords;
        let mut eq = crate::register::accumulate(&index, |&i| {
            let p = (pose * Point3::from(pts[i])).coords;
            let c = cad.query_near(&p, hints[i].load(Ordering::Relaxed))?;
            hints[i].store(c.triangle, Ordering::Relaxed);
            let w = weight(&p.into(), c.distance);
            if w <= 0.0 {
                return None;
            }
            let nrm = c.normal;
            let r = (p - centre).cross(&nrm) / radius;
            Some((
                Vector6::new(r.x, r.y, r.z, nrm.x, nrm.y, nrm.z),
                -(p - c.point).dot(&nrm),
                w,
            ))
        });
        if !edges.is_empty() && eq.count > 0 {
            // The edges act only along the motions the surface barely pins: they pin what a
            // surface cannot, and do not argue with one that pins (a scan's edge a little
            // short of the rim must not pull a part its features hold).
            let eig = nalgebra::SymmetricEigen::new(eq.ata / eq.count as f64);
            let mut weak = Matrix6::<f64>::zeros();
            for k in 0..6 {
                if eig.eigenvalues[k] < rim::PINS_BELOW {
                    let v = eig.eigenvectors.column(k);
                    weak += v * v.transpose();
                }
            }
            let (mut ata, mut atb) = (Matrix6::<f64>::zeros(), Vector6::<f64>::zeros());
            for e in edges {
                let p = (pose * Point3::from(e.cloud)).coords;
                let nrm = e.normal;
                let r = (p - centre).cross(&nrm) / radius;
                let a = Vector6::new(r.x, r.y, r.z, nrm.x, nrm.y, nrm.z);
                ata += a * a.transpose() * e.weight;
                atb += a * (-(p - e.plane).dot(&nrm) * e.weight);
            }
            eq.ata += weak * ata * weak;
            eq.atb += weak * atb;
            eq.count += edges.len();
        }
        if eq.count < 6 {
            break;
        }
        let Some(x) = pinned_step(&eq.ata, &eq.atb, eq.count as f64) else {
            break;
        };
        let omega = Vector3::new(x[0], x[1], x[2]) / radius;
        let t = Vector3::new(x[3], x[4], x[5]);
        // p ↦ R (p − centre) + centre + t
        let rot = UnitQuaternion::from_scaled_axis(omega);
        let delta = Pose::from_parts((centre - rot * centre + t).into(), rot);
        pose = delta * pose;
        // Converged when no point within two radii moves by more than 10 nm.
        if t.norm() + 2.0 * radius * omega.norm() < converged {
            break;
        }
        trail.push(pose);
        if let Some(mean) = cycle_mean(&trail, &centroid, radius) {
            pose = mean;
            break;
        }
    }
    (pose, it)
}

/// A fit has converged when its step moves no point within two RMS radii of the centroid by
/// more than this, mm.
const CONVERGED_MM: f64 = 1e-5;

/// Longest cycle of poses [`cycle_mean`] looks for, in steps.
const LONGEST_CYCLE: usize = 8;

/// The mean pose of the cycle the fit's poses (`trail`, latest last) have settled into, when
/// they have: the latest pose is, to within [`CONVERGED_MM`] at two RMS radii of `centroid`, one
/// it held 2 to [`LONGEST_CYCLE`] steps before. On a faceted CAD, closest points that change
/// facets, or slide along the rim's edges, from one step to the next can send Gauss–Newton
/// round the same few poses for ever (micrometres apart, so each step is far above the
/// convergence threshold); the poses of the cycle straddle the optimum, and their mean is the
/// fit's answer.
fn cycle_mean(trail: &[Pose], centroid: &Vector3<f64>, radius: f64) -> Option<Pose> {
    let last = trail.last()?;
    let here = (last * Point3::from(*centroid)).coords;
    let period = (2..=LONGEST_CYCLE.min(trail.len() - 1)).find(|&p| {
        let past = &trail[trail.len() - 1 - p];
        let shift = (here - (past * Point3::from(*centroid)).coords).norm();
        let turn = (last.rotation * past.rotation.inverse()).angle();
        shift + 2.0 * radius * turn < CONVERGED_MM
    })?;
    let cycle = &trail[trail.len() - period..];
    let n = period as f64;
    let translation = cycle
        .iter()
        .fold(Vector3::zeros(), |a, p| a + p.translation.vector)
        / n;
    // The rotations differ by micro-radians: the normalised sum of their quaternions (taken in
    // one hemisphere) is their mean.
    let q0 = cycle[0].rotation.into_inner();
    let sum = cycle
        .iter()
        .fold(nalgebra::Quaternion::new(0.0, 0.0, 0.0, 0.0), |a, p| {
            let q = p.rotation.into_inner();
            if q.dot(&q0) < 0.0 {
                a - q
            } else {
                a + q
            }
        });
    let rotation = UnitQuaternion::from_quaternion(sum);
    Some(Pose::from_parts(translation.into(), rotation))
}

/// The Gauss–Newton step of normal equations (rotation columns in mm, `count` rows of weight
/// ≤ 1) restricted to the directions the data pin: a direction of strength below
/// [`UNPINNED_STRENGTH`] (a cylinder's axis, a plane's in-plane motions) does not move, so it
/// keeps the starting pose instead of drifting on noise; every pinned direction, however weak
/// (a gently curved panel's slide along itself), takes its full step. One step is capped at
/// 50 mm of motion at the RMS radius.
fn pinned_step(ata: &Matrix6<f64>, atb: &Vector6<f64>, count: f64) -> Option<Vector6<f64>> {
    if !(ata.iter().all(|v| v.is_finite()) && atb.iter().all(|v| v.is_finite())) {
        return None;
    }
    let eig = nalgebra::SymmetricEigen::new(ata / count);
    let g = atb / count;
    let mut x = Vector6::zeros();
    for k in 0..6 {
        let lambda = eig.eigenvalues[k];
        if lambda >= UNPINNED_STRENGTH {
            let v = eig.eigenvectors.column(k);
            x += v * (v.dot(&g) / lambda);
        }
    }
    const MAX_STEP_MM: f64 = 50.0;
    let motion = x.norm();
    if motion > MAX_STEP_MM {
        x *= MAX_STEP_MM / motion;
    }
    Some(x)
}

/// Fit on the datum regions only (membership evaluated in the CAD frame as the pose moves).
fn datum_fit(
    pts: &[[f64; 3]],
    cad: &SignedDistance,
    start: Pose,
    params: &InspectParams,
) -> (Pose, &'static str, f64, usize) {
    // First a robust fit on everything to bring the datums into reach, then datums only.
    let (rough, _) = fit_to_surface(pts, cad, start, 15, &|_, d| {
        if d.abs() < 5.0 {
            1.0
        } else {
            0.0
        }
    });
    let datums = params.datums.clone();
    let weight = move |p: &[f64; 3], _d: f64| if in_datums(p, &datums) { 1.0 } else { 0.0 };
    let (pose, it) = fit_to_surface(pts, cad, rough, params.max_iterations, &weight);
    let n_datum = pts
        .iter()
        .filter(|p| in_datums(&(pose * Point3::from(**p)).coords.into(), &params.datums))
        .count();
    (pose, "datums", n_datum as f64 / pts.len() as f64, it)
}

/// Whether the trusted-region fit's passes have settled: the motion still to come is under 2 %
/// of `tolerance` (mm). Passes contract onto their fixed point: with each moving the pose `rate`
/// times as far as the one before (`moved` after `last_moved`, mm at the points), the passes
/// still to come move it `rate / (1 - rate)` times this one's motion in all. A first pass
/// (`last_moved` infinite), or passes that do not contract by half, are judged by their own
/// motion.
fn passes_settled(moved: f64, last_moved: f64, tolerance: f64) -> bool {
    let rate = moved / last_moved;
    let to_come = if last_moved.is_finite() && rate < 0.5 {
        moved * rate / (1.0 - rate)
    } else {
        moved
    };
    to_come < 0.02 * tolerance
}

/// Grow the trusted set by iterative trimming until it stops changing; where the scan reaches
/// the CAD's open boundary, its edges hold the fit on the rim (see [`rim`]). Once this thread's
/// [`crate::budget`] is spent it stops between rounds and returns the pose it has; the caller's
/// check then fails the inspection.
///
/// Where the rim turns out not to pin the fit (another placement puts as much of the scan's
/// edge on it), its edges are no evidence of where the part lies, and the pose they drew the
/// fit to is not kept: the fit is made again from `start` as if the CAD had no rim, so that a
/// motion the surface does not pin stays where `start` (a cell's fixture pose) put it. The
/// rim's summary, with the ambiguity, is returned without its edges.
fn trusted_region_fit(
    pts: &[[f64; 3]],
    cloud: &[[f64; 3]],
    cad: &SignedDistance,
    start: Pose,
    params: &InspectParams,
    contenders: &[Pose],
) -> TrustedFit {
    let cad_rim = rim::CadRim::of(cad);
    let (fit, fork) = trusted_region_passes(
        pts,
        cloud,
        cad,
        start,
        params,
        contenders,
        Some(&cad_rim),
        None,
    );
    match (fit.5, fork) {
        (Some(r), Some(fork)) if r.summary.ambiguous.is_some() && !crate::budget::spent() => {
            tracing::debug!("trusted-region fit: the rim is ambiguous; fitted again without it");
            // (the passes without the rim are those with it up to where the rim first took
            // part: they go on from there)
            let shared = fork.total;
            let ((pose, mode, frac, total, set, _), _) =
                trusted_region_passes(pts, cloud, cad, start, params, contenders, None, Some(fork));
            let rim = rim::RimFit {
                edges: Vec::new(),
                search: None,
                ..r
            };
            (pose, mode, frac, fit.3 + total - shared, set, Some(rim))
        }
        (rim_fit, _) => (fit.0, fit.1, fit.2, fit.3, fit.4, rim_fit),
    }
}

/// A trusted-region fit: the pose, the registration mode, the share of the points trusted,
/// the iterations, the trusted points (cloud frame) and the rim fit.
type TrustedFit = (
    Pose,
    &'static str,
    f64,
    usize,
    Vec<[f64; 3]>,
    Option<rim::RimFit>,
);

/// Where a rim fit's rivals are searched for: the coarse alignment's runners-up, or, where the
/// pose was given (a cell's fixture), that pose as a placement reaching no rim.
fn rivals_from<'a>(contenders: &'a [Pose], params: &InspectParams) -> rim::Rivals<'a> {
    match params.init {
        Some(held) if contenders.is_empty() => rim::Rivals::Fixture(held),
        _ => rim::Rivals::Search(contenders),
    }
}

/// The state of [`trusted_region_passes`] where the rim first took part (after that pass's
/// consensus step, before its rim step): up to there the passes with and without the rim are
/// the same, so a fit without the rim goes on from here.
#[derive(Clone)]
struct Fork {
    /// The pass, and the pose it began from.
    pass: usize,
    before: Pose,
    /// After the pass's consensus step: the pose, the iterations so far, the trusted points.
    pose: Pose,
    total: usize,
    trusted: Vec<bool>,
    /// The measurement noise of the rough fit, and the motion of the pass before.
    noise: f64,
    last_moved: f64,
}

/// One pass of [`trusted_region_passes`] up to its rim step: seeds at the current pose, the
/// trusted set annealed onto them (with the rim's edges of `rim_fit`), and the tiles a rigid
/// motion puts back (`consensus`). Updates the pose, the iteration count and the trusted set.
fn pass_to_consensus(
    pts: &[[f64; 3]],
    cad: &SignedDistance,
    params: &InspectParams,
    (noise, floor): (f64, f64),
    rim_fit: Option<&rim::RimFit>,
    (pose, total, trusted): (&mut Pose, &mut usize, &mut Vec<bool>),
    lap: &dyn Fn(&str, usize),
) {
    let seeds = flat_seeds(pts, cad, pose);
    lap("seeds", *total);
    *trusted = seeds.clone();
    let mut thr = 0.5 * params.tolerance;
    for _round in 0..40 {
        if crate::budget::spent() {
            break;
        }
        let dev = cad.query_all(&to_cad(pts, pose));
        let current: Vec<f64> = dev
            .iter()
            .zip(trusted.iter())
            .filter(|(d, t)| **t && d.is_finite())
            .map(|(d, _)| *d)
            .collect();
        let med = median(&current);
        // Only seeds (flat neighbourhoods) may be trusted: growing into bent regions
        // would let the deformation's tails pull the fit.
        let next: Vec<bool> = dev
            .iter()
            .zip(&seeds)
            .map(|(d, s)| *s && d.is_finite() && (d - med).abs() <= thr)
            .collect();
        let changed = next
            .iter()
            .zip(trusted.iter())
            .filter(|(a, b)| a != b)
            .count();
        if next.iter().filter(|t| **t).count() < 10 {
            break;
        }
        *trusted = next;
        let set = selected(pts, trusted);
        let edges = rim_fit.map_or(&[][..], |r| &r.edges[..]);
        let (p, it) = fit_with_edges(&set, cad, *pose, params.max_iterations, &|_, _| 1.0, edges);
        *pose = p;
        *total += it;
        if thr <= floor && changed * 1000 < pts.len() {
            break;
        }
        thr = (thr * 0.7).max(floor);
    }
    lap("annealed", *total);
    if let Some((mask, p)) = consensus::admit(pts, trusted, cad, pose, noise) {
        *trusted = mask;
        *pose = p;
    }
    lap("consensus", *total);
}

/// [`trusted_region_fit`]'s passes, with the CAD's rim (`cad_rim`, sampled once for both
/// fits) taking part where it is given and not empty; from `resume` (a [`Fork`] of passes
/// with the rim) when given. Returns the fit and, where the rim took part, where it did.
#[allow(clippy::too_many_arguments)]
fn trusted_region_passes(
    pts: &[[f64; 3]],
    cloud: &[[f64; 3]],
    cad: &SignedDistance,
    start: Pose,
    params: &InspectParams,
    contenders: &[Pose],
    cad_rim: Option<&rim::CadRim>,
    resume: Option<Fork>,
) -> (TrustedFit, Option<Fork>) {
    let clock = std::time::Instant::now();
    let lap = |step: &str, iterations: usize| {
        tracing::debug!(
            seconds = clock.elapsed().as_secs_f64(),
            iterations,
            "trusted-region fit: {step}"
        )
    };
    let pts_tree = crate::spatial::KdTree::new(pts);
    // (the CAD's rim and the cloud whose edges are looked for on it)
    let edges_on_rim = cad_rim
        .filter(|r| !r.is_empty())
        .map(|r| (r, rim::RimCloud::new(cloud, pts, &pts_tree)));
    let mut rim_fit: Option<rim::RimFit> = None;
    let mut search: Option<rim::Search> = None;
    let mut fork: Option<Fork> = None;
    let (mut pose, mut total, noise) = match &resume {
        Some(f) => (f.pose, f.total, f.noise),
        None => {
            let (pose, total) = fit_to_surface(pts, cad, start, 15, &|_, d| {
                if d.abs() < 5.0 {
                    1.0
                } else {
                    0.0
                }
            });
            // Measurement noise from the local roughness of the deviation field (a point
            // against the mean of its neighbours): smooth deformation and misalignment cancel
            // there, noise does not.
            let noise = local_noise(pts, &pts_tree, &cad.query_all(&to_cad(pts, &pose)));
            (pose, total, noise)
        }
    };
    // The threshold anneals from half the tolerance down to three noise sigmas, so the trusted
    // set contracts onto the undeformed majority instead of settling on a compromise.
    let floor = (3.0 * noise).max(0.01);
    // Passes: seeds and trimming at the current pose, then the tiles the trimming left out
    // that a rigid motion puts back on the CAD (see `consensus`); again from the new pose
    // until it stops moving. Seeds taken once at a pose a deformation had pulled along the
    // surface would exclude the very features that pin the slide.
    let mut trusted = Vec::new();
    // The passes have converged when the motion still to come (of the points' centroid, and the
    // turn at their RMS radius) is less than 2 % of the tolerance: seeds and trimming then see
    // the same deviations to well within the noise, and the rim's edges are found again where
    // they were.
    let centroid = Point3::from(
        pts.iter()
            .fold(Vector3::zeros(), |a, p| a + Vector3::from(*p))
            / pts.len().max(1) as f64,
    );
    let radius = (pts
        .iter()
        .map(|p| (Point3::from(*p) - centroid).norm_squared())
        .sum::<f64>()
        / pts.len().max(1) as f64)
        .sqrt();
    // How far a change of pose moves the points: their centroid's shift and the turn at their
    // RMS radius, mm.
    let motion = |a: &Pose, b: &Pose| {
        (a * centroid - b * centroid).norm()
            + crate::register::rotation_angle_deg(&(a * b.inverse())).to_radians() * radius
    };
    lap("rough fit and noise", total);
    let mut last_moved = resume.as_ref().map_or(f64::INFINITY, |f| f.last_moved);
    let mut resume = resume;
    for pass in resume.as_ref().map_or(0, |f| f.pass)..4 {
        if crate::budget::spent() {
            break;
        }
        // (a resumed pass goes on after its consensus step, where the rim would take part)
        let before = match resume.take() {
            Some(f) => {
                trusted = f.trusted;
                f.before
            }
            None => {
                let before = pose;
                pass_to_consensus(
                    pts,
                    cad,
                    params,
                    (noise, floor),
                    rim_fit.as_ref(),
                    (&mut pose, &mut total, &mut trusted),
                    &lap,
                );
                before
            }
        };
        if rim_fit.is_none() && edges_on_rim.is_some() {
            fork = Some(Fork {
                pass,
                before,
                pose,
                total,
                trusted: trusted.clone(),
                noise,
                last_moved,
            });
        }
        if let Some(r) = edges_on_rim.as_ref().and_then(|(cad_rim, edge_cloud)| {
            rim::register(
                edge_cloud,
                &selected(pts, &trusted),
                cad,
                cad_rim,
                pose,
                params.tolerance,
                // where the rim is first found, other placements compete (the basin to refine in)
                if rim_fit.is_none() {
                    rivals_from(contenders, params)
                } else {
                    rim::Rivals::None
                },
            )
        }) {
            let mut r = r;
            pose = r.pose;
            search = r.search.take().or(search);
            rim_fit = Some(r);
        }
        lap("rim", total);
        let moved = motion(&pose, &before);
        tracing::debug!(moved, "trusted-region fit: the pass moved the pose");
        if passes_settled(moved, last_moved, params.tolerance) {
            break;
        }
        last_moved = moved;
    }
    tracing::debug!(noise, floor, "trusted-region fit");
    let set = selected(pts, &trusted);
    // Once converged: other placements that would put the scan's edges on the rim as well
    // (and the coarse alignment's runners-up) are looked for. Where the pose was given (no
    // runners-up) and the search made where the rim was first found started from nearly this
    // pose — the points since moved by less than a tenth of the tolerance (how far apart a
    // rival must place them) and of the millimetre to which its slides were bracketed — the
    // placements it found are fitted again instead. With runners-up the search is made again:
    // fitted again from where the early search left it, a symmetric dome's turned runner-up
    // was judged a rival that the fresh search did not find (the rim panels' family).
    if let (Some(_), Some((cad_rim, edge_cloud)), false) =
        (&rim_fit, &edges_on_rim, crate::budget::spent())
    {
        // The pose the fit began from (the coarse alignment's best) contends as its runners-up
        // do: the passes may have carried the fit from it to its symmetric twin, which the
        // search from here would not reach.
        let mut finals = contenders.to_vec();
        if params.init.is_none() && motion(&start, &pose) > params.tolerance {
            finals.push(start);
        }
        let rivals = match &search {
            Some(s)
                if finals.is_empty()
                    && motion(&pose, &s.from) < 0.1 * params.tolerance.min(1.0) =>
            {
                rim::Rivals::Reuse(s)
            }
            _ => rivals_from(&finals, params),
        };
        rim_fit = rim::register(
            edge_cloud,
            &set,
            cad,
            cad_rim,
            pose,
            params.tolerance,
            rivals,
        );
        if let Some(r) = &rim_fit {
            pose = r.pose;
        }
    }
    lap("rim rivals", total);
    let frac = set.len() as f64 / pts.len() as f64;
    let mode = if rim_fit.is_some() {
        "trusted-region and rim"
    } else {
        "trusted-region"
    };
    ((pose, mode, frac, total, set, rim_fit), fork)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::TriangleMesh;

    #[test]
    fn passes_settle_on_the_motion_still_to_come() {
        // the mock cell's passes at a 0.5 mm tolerance: 0.19 mm, then 0.018 mm (0.0018 to come)
        assert!(!passes_settled(0.19, f64::INFINITY, 0.5));
        assert!(passes_settled(0.0177, 0.19, 0.5));
        // a first pass is judged by its own motion
        assert!(passes_settled(0.009, f64::INFINITY, 0.5));
        assert!(!passes_settled(0.011, f64::INFINITY, 0.5));
        // slow contraction (rate 0.75, 0.045 mm to come) goes on
        assert!(!passes_settled(0.015, 0.02, 0.5));
        // growing motion goes on
        assert!(!passes_settled(0.03, 0.02, 0.5));
    }

    #[test]
    fn a_cycle_of_poses_ends_at_its_mean_and_a_drift_is_no_cycle() {
        let centroid = Vector3::new(0.0, 0.0, 0.0);
        let a = Pose::translation(0.0, 0.0, 0.0);
        let b = Pose::from_parts(
            nalgebra::Translation3::new(0.004, 0.0, 0.0),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.0, 2e-5)),
        );
        let mean = cycle_mean(&[b, a, b, a], &centroid, 100.0).expect("a two-cycle");
        assert!((mean.translation.vector.x - 0.002).abs() < 1e-12);
        assert!((mean.rotation.angle() - 1e-5).abs() < 1e-12);
        // three poses round and back
        let c = Pose::translation(0.0, 0.003, 0.0);
        assert!(cycle_mean(&[a, b, c, a], &centroid, 100.0).is_some());
        // steady progress, however slow, is not a cycle
        let drift: Vec<Pose> = (0..12)
            .map(|k| Pose::translation(1e-5 * k as f64, 0.0, 0.0))
            .collect();
        assert!(cycle_mean(&drift, &centroid, 100.0).is_none());
    }

    /// Strips of a cylinder of radius 400 mm tessellated into facets of 1–6 mm, measured on
    /// their true surface (with and without noise) 10–50 mm past their rim on either side: the
    /// points past the rim find their closest points on its edges, whose normals turn with each
    /// step, and Gauss–Newton goes round a cycle of poses micrometres apart (each of these ran
    /// to the limit of 60 iterations without the cycle test). Every fit must end on its cycle,
    /// well before the limit, with the points inside the rim on the surface.
    #[test]
    fn fits_to_faceted_cylinders_end_before_their_limit() {
        let r = 400.0;
        let arc = |x: f64| (r * r - x * x).sqrt() - r;
        // (facets across, half-width of the CAD, noise amplitude, seed of the noise)
        for (facets, half, noise, seed) in [
            (64usize, 200.0, 0.07, 12345u64),
            (180, 190.0, 0.07, 12345),
            (360, 150.0, 0.0, 0),
        ] {
            let mesh =
                TriangleMesh::height_field(facets, 30, (-half, half), (-150.0, 150.0), |x, _| {
                    arc(x)
                });
            let cad = SignedDistance::new(mesh);
            let mut pts = Vec::new();
            let mut h = seed;
            for i in 0..200 {
                for j in 0..100 {
                    h = h
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(1442695040888963407);
                    let u = ((h >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0;
                    let x = -200.0 + 400.0 * i as f64 / 199.0 + 0.37 * (j % 3) as f64;
                    let y = -150.0 + 300.0 * j as f64 / 99.0;
                    pts.push([x, y, arc(x) + noise * u]);
                }
            }
            let start = Pose::from_parts(
                nalgebra::Translation3::new(0.3, 0.0, 0.4),
                UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.002, 0.0)),
            );
            let (pose, it) = fit_to_surface(&pts, &cad, start, 60, &|_, _| 1.0);
            let case = format!("{facets} facets over ±{half} mm, noise {noise} mm");
            assert!(it < 40, "{case}: {it} iterations");
            if half < 190.0 {
                // A quarter of the points 50 mm past the rim, unweighted here (the inspection
                // trims them), pull the fit off the surface: only the ending is asserted.
                continue;
            }
            let worst = pts
                .iter()
                .filter(|p| p[0].abs() < half - 10.0)
                .filter_map(|p| cad.query(&(pose * Point3::from(*p)).coords))
                .map(|c| c.distance.abs())
                .fold(0.0, f64::max);
            // the noise, and a facet's sag (at most 0.012 mm for 6.25 mm facets)
            assert!(
                worst < noise + 0.03,
                "{case}: {worst} mm from the CAD after {it} iterations"
            );
        }
    }
}
