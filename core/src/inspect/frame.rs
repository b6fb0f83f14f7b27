//! The datum reference frame (3-2-1 / RPS): the primary level pins its strongest degrees of
//! freedom (3 by default: a surface's normal translation and two tilts), the secondary pins its
//! strongest of those left (2: a hole's in-plane position), the tertiary the rest (1: a slot or
//! edge fixing the rotation about the normal). Each Gauss–Newton step solves the levels in
//! order, each only in the subspace the levels before it left free, so a lower datum never
//! pulls what a higher one fixed, and the deformation elsewhere on the part is not fitted at
//! all (Ch. 5.3.3–5.3.5: datums weighted, deformation not absorbed). Directions no level pins
//! are fitted to all datums together and reported by their strength.

use nalgebra::{
    DMatrix, DVector, Matrix6, Point3, SymmetricEigen, Translation3, UnitQuaternion, Vector3,
    Vector6,
};
use rayon::prelude::*;
use serde::Serialize;

use super::conditioning::{Conditioning, Direction, UNPINNED_STRENGTH};
use super::datums::{level_dofs, Datum, Feature};
use super::features::{self, Measured};
use crate::mesh::SignedDistance;
use crate::register::Pose;

/// Points kept per datum neighbourhood (a uniform subsample beyond it).
const GATHER_CAP: usize = 60_000;

/// One datum as measured in the final pose.
#[derive(Clone, Debug, Serialize)]
pub struct DatumMeasurement {
    /// Datum name.
    pub name: String,
    /// Feature kind.
    pub feature: Feature,
    /// Level in the frame (1 primary, 2 secondary, 3 tertiary).
    pub order: Option<u8>,
    /// Measured position, CAD frame (a surface patch: the mean of its points).
    pub measured: Option<[f64; 3]>,
    /// Measured minus nominal along each direction the datum pins, mm (a surface patch: its
    /// mean deviation along the normal).
    pub offset_mm: Vec<f64>,
    /// Measured hole diameter or slot width, mm.
    pub size_mm: Option<f64>,
    /// Points or edge samples the measurement rests on.
    pub samples: usize,
    /// Why it was not measured.
    pub error: Option<String>,
}

/// The frame fit's result.
pub(super) struct FrameFit {
    pub pose: Pose,
    pub iterations: usize,
    pub measurements: Vec<DatumMeasurement>,
    pub conditioning: Conditioning,
    /// The last step moved the pose by less than 1e-6 mm.
    pub converged: bool,
}

/// The cloud points (cloud frame) within each datum's search reach of where `pose`
/// (cad_from_cloud) puts it; at most [`GATHER_CAP`] each (a uniform subsample beyond).
fn gather(cloud: &[[f64; 3]], datums: &[Datum], pose: &Pose) -> Vec<Vec<[f64; 3]>> {
    let cloud_from_cad = pose.inverse();
    datums
        .iter()
        .map(|d| {
            let c = cloud_from_cad * Point3::from(d.position);
            let r2 = (d.radius + features::SEARCH_MARGIN).powi(2);
            let near: Vec<[f64; 3]> = cloud
                .par_iter()
                .filter(|p| (Point3::from(**p) - c).norm_squared() <= r2)
                .copied()
                .collect();
            let step = (near.len() / GATHER_CAP).max(1);
            near.into_iter().step_by(step).collect()
        })
        .collect()
}

/// Rows (a, b, w) of one datum at the current pose, with its measurement.
struct DatumRows {
    rows: Vec<(Vector6<f64>, f64, f64)>,
    measurement: DatumMeasurement,
}

/// Fit `cloud` (all points, cloud frame) to the datum frame from `start` (cad_from_cloud).
pub(super) fn fit(
    cloud: &[[f64; 3]],
    cad: &SignedDistance,
    datums: &[Datum],
    start: Pose,
    tolerance: f64,
) -> FrameFit {
    let normals: Vec<Vector3<f64>> = datums
        .iter()
        .map(|d| {
            cad.query(&Vector3::from(d.position))
                .map(|c| c.normal)
                .unwrap_or_else(Vector3::z)
        })
        .collect();
    // Rotations about the datums' centroid, scaled by their spread, so that every direction of
    // the 6-space is in millimetres.
    let n = datums.len().max(1) as f64;
    let centre = datums
        .iter()
        .fold(Vector3::zeros(), |a, d| a + Vector3::from(d.position))
        / n;
    let spread = (datums
        .iter()
        .map(|d| (Vector3::from(d.position) - centre).norm_squared() + d.radius * d.radius)
        .sum::<f64>()
        / n)
        .sqrt()
        .max(1.0);
    let measure_all = |hoods: &[Vec<[f64; 3]>], pose: &Pose| -> Vec<DatumRows> {
        datums
            .iter()
            .zip(hoods)
            .zip(&normals)
            .map(|((d, hood), nrm)| datum_rows(d, hood, *nrm, cad, pose, &centre, spread))
            .collect()
    };
    let mut pose = start;
    let mut iterations = 0;
    let mut converged = false;
    let mut solved = Vec::new();
    // Each datum's neighbourhood is gathered in the cloud frame around where the pose puts it,
    // again once the pose has moved (a sliding start can be tens of mm off along the surface).
    let mut hoods = gather(cloud, datums, &pose);
    let mut gathered_at = pose;
    for it in 0..60 {
        iterations = it + 1;
        let moved = datums
            .iter()
            .map(|d| {
                let p = Point3::from(d.position);
                ((gathered_at.inverse() * p) - (pose.inverse() * p)).norm()
            })
            .fold(0.0, f64::max);
        if moved > 2.0 {
            hoods = gather(cloud, datums, &pose);
            gathered_at = pose;
        }
        let (x, dirs) = solve(datums, &measure_all(&hoods, &pose));
        solved = dirs;
        let omega = Vector3::new(x[0], x[1], x[2]) / spread;
        let t = Vector3::new(x[3], x[4], x[5]);
        let rot = UnitQuaternion::from_scaled_axis(omega);
        let delta = Pose::from_parts(Translation3::from(centre + t - rot * centre), rot);
        pose = delta * pose;
        if t.norm() < 1e-6 && omega.norm() * spread < 1e-6 {
            converged = true;
            break;
        }
    }
    // The final measurement, at the converged pose.
    let rows_now = measure_all(&hoods, &pose);
    let total_rows = rows_now.iter().map(|r| r.rows.len()).sum();
    let mut directions: Vec<Direction> = solved
        .into_iter()
        .map(|(v, strength)| Direction::new(&v, strength, tolerance))
        .collect();
    directions.sort_by(|a, b| a.strength.total_cmp(&b.strength));
    let pinned =
        directions.len() == 6 && directions.iter().all(|d| d.strength >= UNPINNED_STRENGTH);
    FrameFit {
        pose,
        iterations,
        measurements: rows_now.into_iter().map(|r| r.measurement).collect(),
        converged,
        conditioning: Conditioning {
            points: total_rows,
            centre: centre.into(),
            radius_mm: spread,
            directions,
            pinned,
        },
    }
}

/// The rows of datum `d` at `pose`: a surface patch gives one point-to-plane row per point
/// (weights summing to 1), a feature one row per pinned direction.
fn datum_rows(
    d: &Datum,
    hood: &[[f64; 3]],
    normal: Vector3<f64>,
    cad: &SignedDistance,
    pose: &Pose,
    centre: &Vector3<f64>,
    spread: f64,
) -> DatumRows {
    let pts: Vec<Vector3<f64>> = hood
        .iter()
        .map(|p| (pose * Point3::from(*p)).coords)
        .collect();
    let row = |p: &Vector3<f64>, dir: &Vector3<f64>| {
        let r = (p - centre).cross(dir) / spread;
        Vector6::new(r.x, r.y, r.z, dir.x, dir.y, dir.z)
    };
    let mut m = DatumMeasurement {
        name: d.name.clone(),
        feature: d.feature,
        order: d.order,
        measured: None,
        offset_mm: Vec::new(),
        size_mm: None,
        samples: 0,
        error: None,
    };
    let q = Vector3::from(d.position);
    if d.feature == Feature::Surface {
        let on: Vec<(Vector3<f64>, Vector3<f64>, f64)> = pts
            .par_iter()
            .filter(|p| (*p - q).norm() <= d.radius)
            .filter_map(|p| {
                let c = cad.query(p)?;
                (!c.beyond_boundary && c.distance.abs() < 5.0)
                    .then(|| (*p, c.normal, (p - c.point).dot(&c.normal)))
            })
            .collect();
        m.samples = on.len();
        if on.len() < 10 {
            m.error = Some(format!(
                "{} points within {} mm of it (10 needed)",
                on.len(),
                d.radius
            ));
            return DatumRows {
                rows: Vec::new(),
                measurement: m,
            };
        }
        let w = 1.0 / on.len() as f64;
        let mean = on.iter().map(|(_, _, e)| e).sum::<f64>() * w;
        m.measured = Some((on.iter().fold(Vector3::zeros(), |a, (p, _, _)| a + p) * w).into());
        m.offset_mm = vec![mean];
        let rows = on.iter().map(|(p, nrm, e)| (row(p, nrm), -e, w)).collect();
        return DatumRows {
            rows,
            measurement: m,
        };
    }
    match features::measure(d, &pts, normal) {
        Ok(Measured {
            position,
            directions,
            size,
            samples,
        }) => {
            m.measured = Some(position.into());
            m.size_mm = size;
            m.samples = samples;
            m.offset_mm = directions.iter().map(|e| e.dot(&(position - q))).collect();
            let rows = directions
                .iter()
                .map(|e| (row(&position, e), -e.dot(&(position - q)), 1.0))
                .collect();
            DatumRows {
                rows,
                measurement: m,
            }
        }
        Err(why) => {
            m.error = Some(why);
            DatumRows {
                rows: Vec::new(),
                measurement: m,
            }
        }
    }
}

/// One hierarchical Gauss–Newton step: the scaled motion (θ·spread, t) and the directions each
/// level pinned with their strengths (eigenvalue over the level's total weight).
fn solve(datums: &[Datum], rows: &[DatumRows]) -> (Vector6<f64>, Vec<(Vector6<f64>, f64)>) {
    let framed = datums.iter().any(|d| d.order.is_some());
    let levels: Vec<(Vec<usize>, usize)> = if framed {
        let mut l: Vec<(Vec<usize>, usize)> = (1..=3u8)
            .map(|o| {
                let members = (0..datums.len())
                    .filter(|&i| datums[i].order == Some(o))
                    .collect();
                (members, level_dofs(datums, o))
            })
            .filter(|(m, k): &(Vec<usize>, usize)| !m.is_empty() && *k > 0)
            .collect();
        // Whatever the levels leave free is fitted to every datum together.
        l.push(((0..datums.len()).collect(), 6));
        l
    } else {
        vec![((0..datums.len()).collect(), 6)]
    };
    let mut basis = DMatrix::<f64>::identity(6, 6);
    let mut x = Vector6::<f64>::zeros();
    let mut pinned = Vec::new();
    for (members, k) in levels {
        let free = basis.ncols();
        if free == 0 {
            break;
        }
        let (mut ata, mut atb, mut wsum) = (Matrix6::<f64>::zeros(), Vector6::<f64>::zeros(), 0.0);
        for &i in &members {
            for (a, b, w) in &rows[i].rows {
                ata += a * a.transpose() * *w;
                atb += a * (*b * *w);
                wsum += *w;
            }
        }
        if wsum <= 0.0 {
            continue;
        }
        let ata_d = DMatrix::from_column_slice(6, 6, ata.as_slice());
        let g_full = DVector::from_column_slice((atb - ata * x).as_slice());
        let a = basis.transpose() * &ata_d * &basis;
        let g = basis.transpose() * g_full;
        let eig = SymmetricEigen::new(a);
        let mut order: Vec<usize> = (0..free).collect();
        order.sort_by(|&i, &j| eig.eigenvalues[j].total_cmp(&eig.eigenvalues[i]));
        let k = k.min(free);
        let mut next = DMatrix::<f64>::zeros(6, free - k);
        for (slot, &i) in order.iter().enumerate() {
            let v = eig.eigenvectors.column(i);
            let dir = &basis * v;
            if slot < k {
                let lambda = eig.eigenvalues[i];
                // A direction the level does not pin stays where it started.
                if lambda >= UNPINNED_STRENGTH * wsum {
                    let y = v.dot(&g) / lambda;
                    for r in 0..6 {
                        x[r] += dir[r] * y;
                    }
                }
                pinned.push((
                    Vector6::from_column_slice(dir.as_slice()),
                    (lambda / wsum).max(0.0),
                ));
            } else {
                next.set_column(slot - k, &dir);
            }
        }
        basis = next;
    }
    (x, pinned)
}
