//! How well a registration pins each rigid degree of freedom. The point-to-plane normal
//! equations at the final pose (rotations about the points' centroid, scaled by their RMS
//! radius so that every direction is in millimetres) have six eigen-directions; the mean
//! squared normal component along each, the *strength* (1 for a translation along every
//! normal, 0 for a motion the surface does not see), says how far a systematic deviation of
//! one tolerance could move the fit along it: `tolerance / √strength`. A plane cannot pin its
//! in-plane translations and the rotation about its normal, a cylinder its axis; a gently
//! curved panel pins them weakly (a bulge can shift the fit along the surface). The report
//! states each direction; one the data do not pin makes the part `not_measured` rather than a
//! map at an arbitrary position.

use nalgebra::{Matrix6, Point3, SymmetricEigen, UnitQuaternion, Vector3, Vector6};
use rayon::prelude::*;
use serde::Serialize;

use crate::mesh::SignedDistance;
use crate::register::accumulate;
use crate::register::Pose;

/// Strength below which a direction is not pinned (a tolerance-sized systematic deviation
/// could move the fit more than 300 tolerances along it: a plane's in-plane motions, a
/// cylinder's axis, a gentle quadric's slide along itself).
pub const UNPINNED_STRENGTH: f64 = 1e-5;
/// Slide, in tolerances, above which a pinned direction is reported as weak.
pub const WEAK_SLIDE_TOLERANCES: f64 = 10.0;

/// One eigen-direction of the fit.
#[derive(Clone, Debug, Serialize)]
pub struct Direction {
    /// `translation` or `rotation` (its dominant part).
    pub kind: String,
    /// Unit axis in the CAD frame: the translation's direction, or the rotation's axis (through
    /// `centre` of [`Conditioning`]).
    pub axis: [f64; 3],
    /// Mean squared normal component of the motion, 0 … 1 (rotations at the RMS radius).
    pub strength: f64,
    /// How far a systematic deviation of one tolerance could move the fit along it, mm (at
    /// the RMS radius for a rotation); capped at 1e6.
    pub slide_mm: f64,
}

/// The conditioning of a registration.
#[derive(Clone, Debug, Serialize)]
pub struct Conditioning {
    /// Points the analysis used (on the CAD surface at the final pose).
    pub points: usize,
    /// Centroid of those points (CAD frame), the centre of the rotations.
    pub centre: [f64; 3],
    /// Their RMS distance from the centre, mm (the lever arm of the rotations).
    pub radius_mm: f64,
    /// The six directions, weakest first.
    pub directions: Vec<Direction>,
    /// Every direction has at least [`UNPINNED_STRENGTH`].
    pub pinned: bool,
}

impl Conditioning {
    /// Nothing was fitted (a known pose): no direction to pin, nothing to report.
    pub fn not_fitted() -> Conditioning {
        Conditioning {
            points: 0,
            centre: [0.0; 3],
            radius_mm: 0.0,
            directions: Vec::new(),
            pinned: true,
        }
    }
}

impl Direction {
    /// The direction of a motion `v` (scaled rotation, then translation) of the given
    /// `strength`: named by its dominant part, with the slide a `tolerance`-sized systematic
    /// deviation could cause along it.
    pub(super) fn new(v: &Vector6<f64>, strength: f64, tolerance: f64) -> Direction {
        let rot = Vector3::new(v[0], v[1], v[2]);
        let tra = Vector3::new(v[3], v[4], v[5]);
        let (kind, axis) = if rot.norm_squared() > tra.norm_squared() {
            ("rotation", rot.normalize())
        } else {
            ("translation", tra.normalize())
        };
        let strength = strength.max(0.0);
        Direction {
            kind: kind.into(),
            axis: axis.into(),
            strength,
            slide_mm: if strength > 0.0 {
                (tolerance / strength.sqrt()).min(1e6)
            } else {
                1e6
            },
        }
    }
}

impl Conditioning {
    /// Sentences for the directions the surface does not pin (first: reasons the part is not
    /// measured) and those it pins weakly (second: warnings). With `prior` (the registration
    /// started from a calibrated nominal pose, as in a cell) an unpinned direction is a
    /// warning: its position along it is the prior's, not the data's.
    pub fn findings(&self, tolerance: f64, prior: bool) -> (Vec<String>, Vec<String>) {
        let mut unpinned = Vec::new();
        let mut weak = Vec::new();
        for d in &self.directions {
            let axis = axis_in_words(d.axis);
            let rotation = d.kind == "rotation";
            let what = if rotation {
                format!("the part's turn about {axis}")
            } else {
                format!("the part's position along {axis}")
            };
            if d.strength < UNPINNED_STRENGTH && prior {
                weak.push(format!(
                    "the measured surface does not pin {what}: it is the cell calibration's (where the fixture holds the part), not measured, so the deviations are right only if the part sat as fixtured"
                ));
            } else if d.strength < UNPINNED_STRENGTH {
                unpinned.push(format!(
                    "the registration cannot pin {what}: the measured surface could {} without changing its fit, so where deviations lie is not known; add datums that fix it (an edge, a hole, a slot) or give the part's pose",
                    if rotation { "turn" } else { "slide" }
                ));
            } else if d.slide_mm > WEAK_SLIDE_TOLERANCES * tolerance {
                weak.push(format!(
                    "{what} is weakly pinned: a systematic deviation of {tolerance} mm could move the fit {:.1} mm{} along it, so a deviation may be shown that far from where it is",
                    d.slide_mm,
                    if rotation { " (at the part's RMS radius)" } else { "" }
                ));
            }
        }
        (unpinned, weak)
    }
}

/// A direction in words: the CAD's x, y or z axis when it lies within 8° of one, else its
/// components in the CAD frame.
fn axis_in_words(a: [f64; 3]) -> String {
    let n = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt().max(1e-12);
    let (k, c) = (0..3)
        .map(|k| (k, a[k].abs() / n))
        .max_by(|x, y| x.1.total_cmp(&y.1))
        .unwrap_or((0, 0.0));
    if c >= 8f64.to_radians().cos() {
        format!("the CAD's {} axis", ["x", "y", "z"][k])
    } else {
        format!(
            "the direction ({:.2}, {:.2}, {:.2}) of the CAD frame",
            a[0] / n,
            a[1] / n,
            a[2] / n
        )
    }
}

/// Analyse the fit of `points` (CAD frame, after registration); only points within `near` mm
/// of the surface take part.
pub fn analyse(
    points: &[[f64; 3]],
    cad: &SignedDistance,
    near: f64,
    tolerance: f64,
) -> Conditioning {
    analyse_with_edges(points, cad, near, tolerance, &[])
}

/// [`analyse`] with the measured edges the fit held on the CAD's rim (CAD-frame point on the
/// rim, the rim's outward direction in the surface, and the points that measured it, which
/// count as that many rows).
pub(super) fn analyse_with_edges(
    points: &[[f64; 3]],
    cad: &SignedDistance,
    near: f64,
    tolerance: f64,
    edges: &[(Vector3<f64>, Vector3<f64>, f64)],
) -> Conditioning {
    let (on, centre, radius, m) = normal_matrix(points, cad, near, edges);
    let eig = SymmetricEigen::new(m);
    let mut order: Vec<usize> = (0..6).collect();
    order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    let directions: Vec<Direction> = order
        .iter()
        .map(|&i| {
            Direction::new(
                &Vector6::from_column_slice(eig.eigenvectors.column(i).as_slice()),
                eig.eigenvalues[i],
                tolerance,
            )
        })
        .collect();
    let pinned = on >= 6 && directions.iter().all(|d| d.strength >= UNPINNED_STRENGTH);
    Conditioning {
        points: on,
        centre: centre.into(),
        radius_mm: radius,
        directions,
        pinned,
    }
}

/// The motions (scaled rotation about the centre, then translation; unit 6-vectors) whose
/// strength on the surface points of `points` (CAD frame) is below `below`, with the centre and
/// the RMS radius that scales the rotations.
pub(super) fn weak_motions(
    points: &[[f64; 3]],
    cad: &SignedDistance,
    near: f64,
    below: f64,
) -> (Vector3<f64>, f64, Vec<Vector6<f64>>) {
    let (_, centre, radius, m) = normal_matrix(points, cad, near, &[]);
    let eig = SymmetricEigen::new(m);
    let weak = (0..6)
        .filter(|&i| eig.eigenvalues[i] < below)
        .map(|i| Vector6::from_column_slice(eig.eigenvectors.column(i).as_slice()))
        .collect();
    (centre, radius, weak)
}

/// `pose` (CAD from cloud) with its motion from `held` taken out along every motion that
/// `points` (cloud frame), placed by `pose`, do not pin (strength below
/// [`UNPINNED_STRENGTH`] within `near` of the surface): along those the part stays where
/// `held` puts it.
pub(super) fn held_along_unpinned(
    points: &[[f64; 3]],
    cad: &SignedDistance,
    pose: &Pose,
    held: &Pose,
    near: f64,
) -> Pose {
    let placed: Vec<[f64; 3]> = points
        .iter()
        .map(|p| (pose * Point3::from(*p)).coords.into())
        .collect();
    let (centre, radius, free) = weak_motions(&placed, cad, near, UNPINNED_STRENGTH);
    if free.is_empty() || radius <= 0.0 {
        return *pose;
    }
    // The motion from `held` to `pose` as a turn about the centre (at the RMS radius) and
    // the centre's shift, in the coordinates the directions are unit vectors of.
    let delta = pose * held.inverse();
    let turn = delta.rotation.scaled_axis() * radius;
    let shift = (delta * Point3::from(centre)).coords - centre;
    let mut x = Vector6::new(turn.x, turn.y, turn.z, shift.x, shift.y, shift.z);
    for v in &free {
        x -= *v * v.dot(&x);
    }
    let rotation = UnitQuaternion::from_scaled_axis(Vector3::new(x[0], x[1], x[2]) / radius);
    let moved = centre + Vector3::new(x[3], x[4], x[5]);
    let kept = Pose::from_parts((moved - rotation * centre).into(), rotation);
    kept * held
}

/// The point-to-plane normal matrix per row of the points of `points` within `near` of the
/// surface and of `edges`: (surface points used, centre, RMS radius, matrix).
fn normal_matrix(
    points: &[[f64; 3]],
    cad: &SignedDistance,
    near: f64,
    edges: &[(Vector3<f64>, Vector3<f64>, f64)],
) -> (usize, Vector3<f64>, f64, Matrix6<f64>) {
    let on: Vec<(Vector3<f64>, Vector3<f64>)> = points
        .par_iter()
        .filter_map(|p| {
            let v = Vector3::from(*p);
            let c = cad.query(&v)?;
            (c.distance.abs() <= near && !c.beyond_boundary).then_some((v, c.normal))
        })
        .collect();
    let n = on.len().max(1) as f64;
    let centre = on.iter().fold(Vector3::zeros(), |a, (p, _)| a + p) / n;
    let radius = (on
        .iter()
        .map(|(p, _)| (p - centre).norm_squared())
        .sum::<f64>()
        / n)
        .sqrt()
        .max(1e-9);
    let eq = accumulate(&on, |(p, nrm)| {
        let r = (p - centre).cross(nrm) / radius;
        Some((Vector6::new(r.x, r.y, r.z, nrm.x, nrm.y, nrm.z), 0.0, 1.0))
    });
    let mut ata = eq.ata;
    let mut rows = n;
    if !edges.is_empty() {
        // As in the fit: the edges count only along the motions the surface barely pins.
        let eig = SymmetricEigen::new(eq.ata / n);
        let mut weak = Matrix6::<f64>::zeros();
        for k in 0..6 {
            if eig.eigenvalues[k] < super::rim::PINS_BELOW {
                let v = eig.eigenvectors.column(k);
                weak += v * v.transpose();
            }
        }
        let mut rim = Matrix6::<f64>::zeros();
        for (p, m, w) in edges {
            let r = (p - centre).cross(m) / radius;
            let a = Vector6::new(r.x, r.y, r.z, m.x, m.y, m.z);
            rim += a * a.transpose() * *w;
            rows += w;
        }
        ata += weak * rim * weak;
    }
    (on.len(), centre, radius, ata / rows)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::TriangleMesh;

    /// A flat plate pins its height and its tilts, not its slide in its plane nor its turn
    /// about its normal: held, a fit moved along those three goes back to where the fixture
    /// holds the part; what the plate pins is kept as fitted.
    #[test]
    fn a_plate_stays_where_held_along_what_it_does_not_pin() {
        let cad = SignedDistance::new(TriangleMesh::height_field(
            20,
            20,
            (-100.0, 100.0),
            (-80.0, 80.0),
            |_, _| 0.0,
        ));
        let points: Vec<[f64; 3]> = (0..400)
            .map(|k| {
                let (i, j) = ((k % 20) as f64, (k / 20) as f64);
                [-95.0 + 10.0 * i, -75.0 + 7.9 * j, 0.0]
            })
            .collect();
        let held = Pose::new(Vector3::new(1.0, -2.0, 0.5), Vector3::new(0.0, 0.0, 0.01));
        // fitted: slid 5 and 3 mm, turned 0.5° about the normal, raised 0.2 mm, tilted 0.1°
        let drift = Pose::new(
            Vector3::new(5.0, 3.0, 0.2),
            Vector3::new(0.1f64.to_radians(), 0.0, 0.5f64.to_radians()),
        );
        let fitted = drift * held;
        let kept = held_along_unpinned(&points, &cad, &fitted, &held, 10.0);
        // (points' positions under the kept pose, the held one and the fitted one)
        for p in &points {
            let p = Point3::from(*p);
            let (k, h, f) = (kept * p, held * p, fitted * p);
            // in the plane as held
            assert!(
                (k.x - h.x).abs() < 0.02 && (k.y - h.y).abs() < 0.02,
                "{k} vs {h}"
            );
            // across it as fitted
            assert!((k.z - f.z).abs() < 1e-3, "{k} vs {f}");
        }
        // a fit the plate pins entirely is kept whole
        let lifted = Pose::new(Vector3::new(0.0, 0.0, 0.3), Vector3::zeros()) * held;
        let same = held_along_unpinned(&points, &cad, &lifted, &held, 10.0);
        assert!((same.translation.vector - lifted.translation.vector).norm() < 1e-9);
    }
}
