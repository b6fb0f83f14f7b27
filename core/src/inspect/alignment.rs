//! Coarse alignment of a cloud to its CAD when no initial pose is given: several hypotheses
//! (principal axes of cloud and CAD surface with every proper sign flip, the two largest axes
//! also swapped for near-square parts, and the pose as given), each refined briefly and scored
//! by the fraction of points that land on the CAD surface. The best wins; the best *different*
//! pose's score is kept so that an ambiguous case (a symmetric or deformed part) is visible.

use nalgebra::{Matrix3, Point3, UnitQuaternion, Vector3};
use rayon::prelude::*;
use serde::Serialize;

use super::fit_to_surface;
use crate::mesh::SignedDistance;
use crate::register::{rotation_angle_deg, Pose};

/// How the coarse alignment chose the starting pose.
#[derive(Clone, Debug, Serialize)]
pub struct Alignment {
    /// Hypotheses refined and scored.
    pub hypotheses: usize,
    /// Distance band a point must land within to count, mm.
    pub band_mm: f64,
    /// Fraction of the points within the band at the chosen pose.
    pub best_score: f64,
    /// The same for the best pose that differs from the chosen one (by more than 2° or
    /// 5 mm), when any.
    pub runner_up_score: Option<f64>,
    /// How far the runner-up lies from the chosen pose: rotation, degrees.
    pub runner_up_rotation_deg: Option<f64>,
    /// And translation of the cloud's centre, mm.
    pub runner_up_shift_mm: Option<f64>,
    /// RMS of the change in the points' deviations between the two poses, mm: near zero when
    /// the runner-up is the chosen pose's image under a symmetry of the part.
    pub runner_up_map_change_mm: Option<f64>,
    /// A different pose fits nearly as well (score at least 90 % of the best) and would draw a
    /// different map (deviations changing by more than half the tolerance RMS): the report is
    /// then `not_measured`.
    pub ambiguous: bool,
    /// Change of the deviation *map*, mm (98th percentile): each point's deviation at the
    /// runner-up's placement against the mean deviation the chosen pose shows at the same place
    /// on the CAD (its 8 nearest points).
    /// Large while the points' own deviations do not change: the runner-up is the chosen
    /// pose's image under a symmetry of the CAD, and the deviations are the same either way
    /// but lie on the part in one of two places.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub runner_up_placement_change_mm: Option<f64>,
    /// The CAD looks the same at the runner-up's pose, which fits as well, but the deviations
    /// would lie elsewhere on the part (see `runner_up_placement_change_mm`): the verdict
    /// stands, where on the part is one of two.
    pub symmetric: bool,
    /// How an ambiguity was settled: a datum reference frame measured every datum from one
    /// contender only.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub settled_by: Option<String>,
}

impl Alignment {
    /// Whether the data cannot tell the pose (see [`Alignment::ambiguous`], the field).
    pub fn ambiguous(&self) -> bool {
        self.ambiguous
    }
}

/// Principal axes (columns, largest first) of a covariance, as a proper rotation.
fn axes(m: Matrix3<f64>) -> Matrix3<f64> {
    let e = m.symmetric_eigen();
    let mut idx = [0usize, 1, 2];
    idx.sort_by(|&i, &j| e.eigenvalues[j].total_cmp(&e.eigenvalues[i]));
    let mut r = Matrix3::from_columns(&[
        e.eigenvectors.column(idx[0]).into_owned(),
        e.eigenvectors.column(idx[1]).into_owned(),
        e.eigenvectors.column(idx[2]).into_owned(),
    ]);
    if r.determinant() < 0.0 {
        r.set_column(2, &(-r.column(2)));
    }
    r
}

/// Area-weighted centroid and covariance of the CAD surface.
fn cad_moments(cad: &SignedDistance) -> (Vector3<f64>, Matrix3<f64>) {
    let mesh = cad.mesh();
    let (mut area_sum, mut c) = (0.0, Vector3::zeros());
    let mut samples = Vec::with_capacity(mesh.triangles.len());
    for t in 0..mesh.triangles.len() {
        let [a, b, cc] = mesh.corners(t);
        let area = 0.5 * (b - a).cross(&(cc - a)).norm();
        let centroid = (a + b + cc) / 3.0;
        samples.push((centroid, area));
        area_sum += area;
        c += centroid * area;
    }
    let w = area_sum.max(1e-300);
    c /= w;
    let cov = samples.iter().fold(Matrix3::zeros(), |m, (p, a)| {
        m + (p - c) * (p - c).transpose() * *a
    }) / w;
    (c, cov)
}

/// Cubes across the CAD's bounding diagonal in which [`proxy`] merges its vertices: a 1 m
/// part's stand-in (8 mm cubes) keeps a smooth surface to within the sagitta over a cube, far
/// inside the scoring band, with a few per cent of a fine mesh's triangles.
const PROXY_CELLS: f64 = 128.0;

/// The CAD clustered at [`PROXY_CELLS`] across its diagonal, where that leaves fewer than half
/// its triangles (a coarse CAD is its own stand-in).
fn proxy(cad: &SignedDistance) -> Option<SignedDistance> {
    let (lo, hi) = cad.mesh().bounds()?;
    let diagonal = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt();
    let coarse = cad.mesh().clustered(diagonal / PROXY_CELLS);
    (coarse.triangles.len() * 2 < cad.mesh().triangles.len()).then(|| SignedDistance::new(coarse))
}

/// The best starting pose for `pts` on `cad` and how it was chosen; `tolerance` (mm) sets the
/// scoring band. Also the contenders: the distinct poses scoring at least 90 % of the best
/// (best first, at most 4), for a datum frame to decide between.
pub(super) fn coarse_alignment(
    pts: &[[f64; 3]],
    cad: &SignedDistance,
    tolerance: f64,
) -> (Pose, Alignment, Vec<Pose>) {
    let (c_cad, cov_cad) = cad_moments(cad);
    let n = pts.len().max(1) as f64;
    let c_cloud = pts
        .iter()
        .fold(Vector3::zeros(), |s, p| s + Vector3::from(*p))
        / n;
    let cov_cloud = pts.iter().fold(Matrix3::zeros(), |m, p| {
        let d = Vector3::from(*p) - c_cloud;
        m + d * d.transpose()
    }) / n;
    let (a_cad, a_cloud) = (axes(cov_cad), axes(cov_cloud));
    let sub: Vec<[f64; 3]> = pts
        .iter()
        .step_by((pts.len() / 5000).max(1))
        .copied()
        .collect();
    let mut candidates = vec![Pose::identity()];
    let swap = Matrix3::new(0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0);
    // A partly seen part's centroid is not the CAD's: its centre is also tried a quarter of
    // the CAD's extent away along each of the two largest axes.
    let mut sd: Vec<f64> = cov_cad
        .symmetric_eigen()
        .eigenvalues
        .iter()
        .map(|e| 2.0 * e.max(0.0).sqrt())
        .collect();
    sd.sort_by(|a, b| b.total_cmp(a));
    let shifts = [
        Vector3::zeros(),
        a_cad.column(0) * 0.5 * sd[0],
        a_cad.column(0) * -0.5 * sd[0],
        a_cad.column(1) * 0.5 * sd[1],
        a_cad.column(1) * -0.5 * sd[1],
    ];
    for order in [Matrix3::identity(), swap] {
        for flips in [
            [1.0, 1.0, 1.0],
            [-1.0, -1.0, 1.0],
            [-1.0, 1.0, -1.0],
            [1.0, -1.0, -1.0],
        ] {
            let f = Matrix3::from_diagonal(&Vector3::from(flips));
            let r = a_cad * order * f * a_cloud.transpose();
            let rot = UnitQuaternion::from_rotation_matrix(
                &nalgebra::Rotation3::from_matrix_unchecked(r),
            );
            for shift in &shifts {
                candidates.push(Pose::from_parts(
                    (c_cad + shift - rot * c_cloud).into(),
                    rot,
                ));
            }
        }
    }
    let band = (3.0 * tolerance).max(0.5);
    // A point this far past the CAD's open rim lies where the part has no surface: a pose that
    // puts more points there than the best does is not a rival (a dome's apex off the panel's
    // centre: turned about the apex, the surface fits but the outline does not).
    let overhang = band.max(3.0);
    type Scored = (f64, f64, Pose, usize);
    let refine = |surface: &SignedDistance, pts: &[[f64; 3]], start: &Pose, iterations: usize| {
        let (p, _) = fit_to_surface(pts, surface, *start, iterations, &|_, d| {
            if d.abs() < 50.0 {
                1.0
            } else {
                0.1
            }
        });
        let (mut within, mut sq, mut past) = (0usize, 0.0, 0usize);
        for x in pts {
            if let Some(c) = surface.query(&(p * Point3::from(*x)).coords) {
                within += usize::from(c.distance.abs() <= band);
                past += usize::from(c.beyond_boundary && c.distance.abs() > overhang);
                sq += c.distance.min(50.0).powi(2);
            }
        }
        let m = pts.len().max(1) as f64;
        (within as f64 / m, (sq / m).sqrt(), p, past)
    };
    // Best: most points on the surface, then the smaller truncated RMS.
    let order = |a: &Scored, b: &Scored| b.0.total_cmp(&a.0).then(a.1.total_cmp(&b.1));
    // Every hypothesis briefly on a small sample, the most promising ones at length.
    let few: Vec<[f64; 3]> = sub
        .iter()
        .step_by((sub.len() / 800).max(1))
        .copied()
        .collect();
    // The short fits start far off, where a closest-point query searches a large share of a
    // fine mesh: they run on its clustered stand-in where that is much smaller (a coarse mesh
    // only ranks the hypotheses; the most promising are refined on the CAD itself). Each fit
    // is too small to spread over the threads, so the hypotheses run side by side.
    let stand_in = proxy(cad);
    let mut first: Vec<Scored> = candidates
        .par_iter()
        .map(|c| refine(stand_in.as_ref().unwrap_or(cad), &few, c, 8))
        .collect();
    first.sort_by(order);
    let scored: Vec<Scored> = first[..first.len().min(6)]
        .par_iter()
        .map(|(_, _, p, _)| refine(cad, &sub, p, 20))
        .collect();
    let mut sorted: Vec<&Scored> = scored.iter().collect();
    sorted.sort_by(|a, b| order(a, b));
    let best = sorted[0];
    let slack = 3 + sub.len() / 500;
    sorted.retain(|s| s.3 <= best.3 + slack);
    let centre = Point3::from(c_cloud);
    let differs = |p: &Pose| {
        let rel = p * best.2.inverse();
        let shift = ((p * centre) - (best.2 * centre)).norm();
        (rotation_angle_deg(&rel), shift)
    };
    let deviations = |p: &Pose| -> Vec<f64> {
        sub.iter()
            .map(|x| {
                cad.query(&(p * Point3::from(*x)).coords)
                    .map_or(f64::NAN, |c| c.distance)
            })
            .collect()
    };
    let at_best = deviations(&best.2);
    // RMS change of the points' own deviations between the chosen pose and `p`.
    let change = |b: &[f64]| {
        let (mut s, mut n) = (0.0, 0usize);
        for (x, y) in at_best.iter().zip(b) {
            if x.is_finite() && y.is_finite() {
                s += (x - y).powi(2);
                n += 1;
            }
        }
        if n == 0 {
            f64::INFINITY
        } else {
            (s / n as f64).sqrt()
        }
    };
    // The map at `p`'s placement against the chosen one's, place by place.
    let placed: Vec<[f64; 3]> = sub
        .iter()
        .map(|x| (best.2 * Point3::from(*x)).coords.into())
        .collect();
    let tree = crate::spatial::KdTree::new(&placed);
    let placement_change = |p: &Pose, b: &[f64]| {
        let reach = 4.0 * band.max(1.0);
        let mut nn = Vec::new();
        let mut change: Vec<f64> = Vec::new();
        for (x, db) in sub.iter().zip(b) {
            let q: [f64; 3] = (p * Point3::from(*x)).coords.into();
            tree.k_nearest(&q, 8, &mut nn);
            let near: Vec<f64> = nn
                .iter()
                .filter(|(i, d2)| *d2 <= reach * reach && at_best[*i].is_finite())
                .map(|(i, _)| at_best[*i])
                .collect();
            if db.is_finite() && !near.is_empty() {
                change.push((db - near.iter().sum::<f64>() / near.len() as f64).abs());
            }
        }
        // A defect covers a few per cent of a part: the 98th percentile, not the RMS.
        if change.is_empty() {
            0.0
        } else {
            let k = (0.98 * (change.len() - 1) as f64) as usize;
            *change.select_nth_unstable_by(k, f64::total_cmp).1
        }
    };
    // The first pose that differs from the chosen one (by more than 2° or 5 mm); when it
    // neither contends nor shows a symmetry, the first of the others fitting nearly as well
    // (at least 90 % of the best score) that puts the same deviations elsewhere on the part:
    // a surface symmetric where the scan sees it can hide its turned placement behind a near
    // duplicate of the chosen one.
    type Runner = (f64, f64, f64, Pose, f64, f64);
    let mut runners: Vec<Runner> = Vec::new();
    for s in sorted.iter().skip(1) {
        let (deg, mm) = differs(&s.2);
        if !(deg > 2.0 || mm > 5.0) {
            continue;
        }
        if !runners.is_empty() && (s.0 < 0.9 * best.0 || runners.len() >= 4) {
            break;
        }
        let b = deviations(&s.2);
        runners.push((s.0, deg, mm, s.2, change(&b), placement_change(&s.2, &b)));
    }
    let contends = |r: &&Runner| r.0 >= 0.9 * best.0;
    let is_ambiguous = |r: &&Runner| contends(r) && r.4 > 0.5 * tolerance;
    let is_symmetric =
        |r: &&Runner| contends(r) && r.4 <= 0.5 * tolerance && r.5 > 0.75 * tolerance;
    let runner = runners
        .first()
        .filter(|r| is_ambiguous(r) || is_symmetric(r))
        .or_else(|| runners.iter().find(is_symmetric))
        .or(runners.first());
    let alignment = Alignment {
        hypotheses: candidates.len(),
        band_mm: band,
        best_score: best.0,
        runner_up_score: runner.map(|r| r.0),
        runner_up_rotation_deg: runner.map(|r| r.1),
        runner_up_shift_mm: runner.map(|r| r.2),
        runner_up_map_change_mm: runner.map(|r| r.4),
        ambiguous: runner.as_ref().is_some_and(is_ambiguous),
        runner_up_placement_change_mm: runner.map(|r| r.5),
        symmetric: runner.as_ref().is_some_and(is_symmetric),
        settled_by: None,
    };
    let mut contenders = vec![best.2];
    for s in sorted.iter().skip(1) {
        if contenders.len() < 4
            && s.0 >= 0.9 * best.0
            && contenders.iter().all(|c| {
                let rel = s.2 * c.inverse();
                rotation_angle_deg(&rel) > 2.0 || ((s.2 * centre) - (c * centre)).norm() > 5.0
            })
        {
            contenders.push(s.2);
        }
    }
    tracing::debug!(?alignment, "coarse alignment");
    (best.2, alignment, contenders)
}
