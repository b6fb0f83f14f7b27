//! Rim-aware registration. A smooth panel (a dome, a saddle, a cylinder-like sheet) barely pins
//! its position along itself: a slide is nearly a motion of the surface onto itself, and a
//! bulge can pull the fit that way. Its trim edges do not slide. Where the scan reaches the
//! CAD's open boundary, the place where the measured surface ends is a measurement of the
//! rim's position across it, in the surface's own plane.
//!
//! The CAD's open boundary is sampled every [`SAMPLE_SPACING`] mm. At each sample a strip
//! across the rim ([`HALF_WIDTH`] either side, within [`LEVEL`] of the surface) is searched for
//! the scan's points; where they form one continuous run from well inside up to an end within
//! the window, that end is the measured edge: the outermost point moved out by the expected gap
//! between the last point and the true edge (the mean spacing of the run's sorted offsets, less
//! for a camera lattice, as in the characteristics' rim fit). A run that goes on past the
//! window (the scan continues beyond the CAD: a slid cloud, a fixture) or that starts too close
//! to the rim (the surface inside was not seen) says nothing. Each edge found is a point-to-
//! plane pair — the measured edge against the plane through the rim sample normal to the rim
//! in the surface — that joins the surface fit; the window narrows from a search width to a
//! few point spacings, and Tukey weights on the offsets leave out coverage limits that happen
//! to lie near the rim. A coverage limit further inside than the last window is never taken for
//! an edge, so a scan that stops short of the rim is still reported as not pinned.

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;
use serde::Serialize;

use super::{fit_with_edges, fit_with_edges_hinted, median, no_hints};
use crate::mesh::SignedDistance;
use crate::register::Pose;
use crate::spatial::KdTree;

/// Distance between samples along the CAD's open boundary, mm.
pub(super) const SAMPLE_SPACING: f64 = 2.0;
/// Half the width of the strip across the rim that each sample searches, mm.
const HALF_WIDTH: f64 = 2.0;
/// Largest distance of a strip's point from the CAD surface's tangent plane at the rim, mm.
const LEVEL: f64 = 5.0;
/// Search windows across the rim, mm, widest first (the last is raised to a few point
/// spacings for sparse clouds).
const WINDOWS: [f64; 3] = [24.0, 10.0, 4.0];
/// Edges a fit needs before the rim takes part.
const MIN_EDGES: usize = 8;
/// Share of the edges found when the finest window's rounds begin that must still be found
/// where they end, where the rounds moved the points farther than the band.
const KEPT_WHILE_SETTLING: f64 = 0.7;
/// Surface strength (see [`super::Conditioning`]) below which a motion is the rim's to pin:
/// a tolerance-sized systematic deviation could slide the fit more than 100 tolerances along
/// it (a dome's, a saddle's or a sheet's slide along itself). A surface that pins a motion
/// better keeps it: a scan's edge that stops a few millimetres short of the rim (edge dropout)
/// would otherwise pull the part that far.
pub(super) const PINS_BELOW: f64 = 1e-4;
/// Samples at most (the spacing grows for very long boundaries).
const MAX_SAMPLES: usize = 20_000;
/// Points of the cloud in which edges are looked for: a larger cloud is thinned to every
/// `len / EDGE_POINTS`-th point (up to twice as many).
const EDGE_POINTS: usize = 200_000;
/// Trusted points (about; up to twice as many) in the surface part of every windowed fit: the
/// surface holds only the motions it pins strongly, which a few thousand points fix to a
/// micrometre, while a fit's cost grows with their number and a rival search converges tens
/// of fits of up to sixteen rounds each.
const SURFACE_POINTS: usize = 2_000;

/// One sample of the CAD's open boundary.
#[derive(Clone, Copy, Debug)]
struct RimSample {
    point: Vector3<f64>,
    /// In the surface, normal to the rim, away from the material.
    outward: Vector3<f64>,
    /// Along the rim.
    along: Vector3<f64>,
    /// The surface's normal at the rim.
    normal: Vector3<f64>,
}

/// The CAD's open boundary (its rim, and the rims of holes and slots cut through it), sampled.
pub(super) struct CadRim {
    samples: Vec<RimSample>,
    spacing: f64,
    /// Each sample's neighbours along the rim (within [`BESIDE`] spacings), as ranges of
    /// `beside` given by `beside_at` (one more entry than samples).
    beside_at: Vec<u32>,
    beside: Vec<u32>,
}

/// Share of the edges the finest window shows near the rim that must lie on it for the rim to
/// take part: where nearly all of them lie elsewhere (a scan ending short of the rim, or
/// reaching past it in mixed pixels, all round), the few on it are that limit's stragglers.
const MIN_SHARE: f64 = 0.2;

/// Samples this many spacings apart or less are beside each other along the rim.
const BESIDE: f64 = 2.5;

/// A rim sample's edge counts only where at least this many of the samples beside it show an
/// edge as well and the median offset of those edges and its own lies within the band:
/// a trim line is seen along runs of samples whose edges lie on it, while a coverage limit a
/// few millimetres inside the rim brushes the band only where its edge estimate's noise
/// reaches it, among neighbours that lie as far inside as the limit.
const IN_A_RUN: usize = 2;

impl CadRim {
    /// The open boundary of the CAD: edges used by one triangle. A closed part has none.
    pub(super) fn of(cad: &SignedDistance) -> CadRim {
        let mesh = cad.mesh();
        let mut edges = Vec::new();
        let mut length = 0.0;
        for (t, tri) in mesh.triangles.iter().enumerate() {
            for k in 0..3 {
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                if cad.is_open_edge(t, k) {
                    let [pa, pb, po] = [a, b, tri[(k + 2) % 3]].map(|i| mesh.vertices[i as usize]);
                    length += (pb - pa).norm();
                    edges.push((t, pa, pb, po));
                }
            }
        }
        let spacing = SAMPLE_SPACING.max(length / MAX_SAMPLES as f64);
        // Samples every `spacing` of accumulated length, in the triangles' order.
        let mut samples = Vec::new();
        let mut carry = 0.5 * spacing;
        for (t, pa, pb, po) in edges {
            let c = mesh.corners(t);
            let normal = (c[1] - c[0]).cross(&(c[2] - c[0]));
            let len = (pb - pa).norm();
            if normal.norm() == 0.0 || len == 0.0 {
                continue;
            }
            let normal = normal.normalize();
            let along = (pb - pa) / len;
            let mut outward = along.cross(&normal);
            if (po - pa).dot(&outward) > 0.0 {
                outward = -outward;
            }
            let mut at = carry;
            while at < len {
                samples.push(RimSample {
                    point: pa + along * at,
                    outward,
                    along,
                    normal,
                });
                at += spacing;
            }
            carry = at - len;
        }
        let points: Vec<[f64; 3]> = samples.iter().map(|s| s.point.into()).collect();
        let tree = KdTree::new(&points);
        let (mut beside_at, mut beside) = (vec![0u32], Vec::new());
        let mut near = Vec::new();
        for (k, p) in points.iter().enumerate() {
            tree.within(p, BESIDE * spacing, &mut near);
            beside.extend(near.iter().filter(|(j, _)| *j != k).map(|(j, _)| *j as u32));
            beside_at.push(beside.len() as u32);
        }
        CadRim {
            samples,
            spacing,
            beside_at,
            beside,
        }
    }

    /// Whether the CAD has an open boundary.
    pub(super) fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// The samples beside sample `k` along the rim.
    fn beside(&self, k: usize) -> &[u32] {
        &self.beside[self.beside_at[k] as usize..self.beside_at[k + 1] as usize]
    }

    /// `weights` (of `obs`, in the samples' order) with the edges that the edges beside them
    /// on the rim do not support set to 0 (see [`IN_A_RUN`]; `band`: how far from the rim an
    /// edge lies on it, mm).
    fn in_runs(&self, obs: &[(usize, f64, usize)], weights: &mut [f64], band: f64) {
        let mut near = Vec::new();
        for (o, w) in obs.iter().zip(weights.iter_mut()) {
            if *w > 0.0 {
                near.clear();
                near.push(o.1);
                near.extend(self.beside(o.0).iter().filter_map(|j| {
                    obs.binary_search_by_key(&(*j as usize), |e| e.0)
                        .ok()
                        .map(|i| obs[i].1)
                }));
                // (the median, selected in the scratch list: no allocation per edge)
                let m = near.len() / 2;
                if near.len() <= IN_A_RUN
                    || near.select_nth_unstable_by(m, f64::total_cmp).1.abs() > band
                {
                    *w = 0.0;
                }
            }
        }
    }
}

/// A measured edge paired with the CAD's rim: the fit moves `cloud` (cloud frame) onto the
/// plane through `plane` normal to `normal` (CAD frame).
#[derive(Clone, Copy, Debug)]
pub(super) struct Edge {
    pub cloud: [f64; 3],
    pub plane: Vector3<f64>,
    pub normal: Vector3<f64>,
    /// The points that measured it.
    pub weight: f64,
}

/// How the rim took part in a registration (the report's `registration.rim`).
#[derive(Clone, Debug, Serialize)]
pub struct RimUse {
    /// Length of the CAD's open boundary, mm.
    pub cad_rim_mm: f64,
    /// Length of it where the scan's own edge was found and used, mm.
    pub seen_mm: f64,
    /// RMS distance of those edges from the CAD's rim after the fit, mm.
    pub rms_mm: f64,
    /// Edges found but left out (their offset disagreed with the rest: a coverage limit near
    /// the rim, a cut edge that moved).
    pub left_out: usize,
    /// Why the rim does not pin the fit although edges were found on it: another placement
    /// puts as much of the scan's edge on the rim elsewhere. The edges then take no part in
    /// the verdict's conditioning.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ambiguous: Option<String>,
    /// How far apart another placement puts the points that rests on nearly as much rim,
    /// where that is within two tolerances (at least 1 mm): the rim pins the fit, to within
    /// this (mm). A deviation may be shown up to this far from where it is.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub spread_mm: Option<f64>,
}

/// The result of [`register`]: the pose, the edge pairs it rests on and the summary.
pub(super) struct RimFit {
    pub pose: Pose,
    pub edges: Vec<Edge>,
    pub summary: RimUse,
    /// A placement turned against this one puts as much of the scan's edge on the rim (a
    /// symmetric outline): the rim cannot settle which way round the part lies.
    pub turned_rival: bool,
    /// The placements its rival search found, for a later judgement from nearly this pose;
    /// `None` where no search was made.
    pub search: Option<Search>,
}

/// The placements a rival search converged to besides its winner, and the contenders that
/// reach no rim (fitted to the surface alone).
pub(super) struct Search {
    /// The winner's pose: where the slides that found the others started.
    pub from: Pose,
    others: Vec<Converged>,
    short: Vec<Pose>,
}

/// Where [`register`]'s rival placements come from.
pub(super) enum Rivals<'a> {
    /// None are looked for (a later pass from a pose already judged).
    None,
    /// The scan slid along each motion the surface barely pins, and these other starting
    /// poses (the coarse alignment's runners-up) with their own slides.
    Search(&'a [Pose]),
    /// As [`Rivals::Search`] without runners-up, and with the pose a cell's fixture holds the
    /// part in as a placement that reaches no rim: a scan whose edges the rim fit carried far
    /// from it may simply end short of the rim where the fixture holds the part.
    Fixture(Pose),
    /// Those an earlier search found, each fitted again from where it ended. The slides that
    /// found them were bracketed to a millimetre, so a fit that has since moved by a small
    /// share of the tolerance would start them where they started.
    Reuse(&'a Search),
}

/// Why a rim seen along `seen` mm does not pin the fit, given the rival placement (how far
/// apart it puts the points; the length of rim it rests on, 0 where it reaches none; mm).
fn ambiguity(seen: f64, (apart, theirs): (f64, f64)) -> String {
    if theirs == 0.0 {
        format!(
            "the scan's edges fit the CAD's rim along {seen:.0} mm, but the surface fits as well with the points placed up to {apart:.1} mm elsewhere, where they reach no rim: where the scan ends short of the rim cannot be told from where the part ends"
        )
    } else {
        format!(
            "the scan's edges fit the CAD's rim along {seen:.0} mm, but also along {theirs:.0} mm with the points placed up to {apart:.1} mm elsewhere: where the scan ends short of the rim cannot be told from where the part ends"
        )
    }
}

/// One observation: the edge's offset beyond the rim sample (along `outward`) and the run's
/// point count; `None` where the strip shows no edge within `depth`.
fn observe(
    s: &RimSample,
    tree: &KdTree,
    pts: &[[f64; 3]],
    cloud_from_cad: &Pose,
    depth: f64,
    nn: &mut Vec<(usize, f64)>,
    u: &mut Vec<f64>,
) -> Option<(f64, usize)> {
    let inv = cloud_from_cad;
    let c = inv * Point3::from(s.point);
    let (m, a, n) = (
        inv.rotation * s.outward,
        inv.rotation * s.along,
        inv.rotation * s.normal,
    );
    let reach = (HALF_WIDTH * HALF_WIDTH + depth * depth + LEVEL * LEVEL).sqrt();
    tree.within(&c.coords.into(), reach, nn);
    u.clear();
    for &(i, _) in nn.iter() {
        let d = Vector3::from(pts[i]) - c.coords;
        let x = d.dot(&m);
        if d.dot(&a).abs() <= HALF_WIDTH && d.dot(&n).abs() <= LEVEL && x.abs() <= depth {
            u.push(x);
        }
    }
    if u.len() < 6 {
        return None;
    }
    u.sort_by(f64::total_cmp);
    // The surface must be seen from well inside.
    if u[0] > -0.5 * depth {
        return None;
    }
    let spread = u[u.len() - 1] - u[0];
    let spacing = (2.0 * HALF_WIDTH * spread / (u.len() - 1) as f64).sqrt();
    let gap = (4.0 * spacing).max(0.5);
    let mut end = 0;
    while end + 1 < u.len() && u[end + 1] - u[end] <= gap {
        end += 1;
    }
    let run = end + 1;
    let (first, last) = (u[0], u[end]);
    if run < 6 || last >= depth - gap || last - first < 0.4 * depth {
        return None;
    }
    // The expected gap between the outermost point and the edge: the mean spacing g of the
    // sorted offsets (a uniform distribution's end), c/(c + 1) g for a lattice of c columns
    // across the strip.
    let g = (last - first) / (run - 1) as f64;
    let columns = (2.0 * HALF_WIDTH / g.max(1e-9)).sqrt().max(1.0);
    Some((last + columns / (columns + 1.0) * g, run))
}

/// Observe every rim sample at `pose` (CAD from cloud): (sample, offset, run), in the
/// samples' order.
fn observe_all(
    rim: &CadRim,
    tree: &KdTree,
    pts: &[[f64; 3]],
    pose: &Pose,
    depth: f64,
) -> Vec<(usize, f64, usize)> {
    let inv = pose.inverse();
    rim.samples
        .par_iter()
        .enumerate()
        .map_init(
            || (Vec::new(), Vec::new()),
            |(nn, u), (k, s)| observe(s, tree, pts, &inv, depth, nn, u).map(|(e, n)| (k, e, n)),
        )
        .flatten()
        .collect()
}

/// Tukey biweights of the offsets about zero, scaled by their MAD (within `floor` … `cap`).
fn tukey(offsets: &[f64], floor: f64, cap: f64) -> Vec<f64> {
    let abs: Vec<f64> = offsets.iter().map(|e| e.abs()).collect();
    let scale = (1.4826 * median(&abs)).clamp(floor, cap.max(floor));
    let c = 4.685 * scale;
    offsets
        .iter()
        .map(|e| {
            let r = e / c;
            if r.abs() >= 1.0 {
                0.0
            } else {
                (1.0 - r * r).powi(2)
            }
        })
        .collect()
}

/// The pairs of the observations with a positive weight.
fn pairs(rim: &CadRim, pose: &Pose, obs: &[(usize, f64, usize)], weights: &[f64]) -> Vec<Edge> {
    let inv = pose.inverse();
    obs.iter()
        .zip(weights)
        .filter(|(_, w)| **w > 0.0)
        .map(|(&(k, e, n), w)| {
            let s = &rim.samples[k];
            let at = s.point + s.outward * e;
            Edge {
                cloud: (inv * Point3::from(at)).coords.into(),
                plane: s.point,
                normal: s.outward,
                weight: w * n as f64,
            }
        })
        .collect()
}

/// One converged rim-aware fit: the pose, the observations at the finest window and their
/// weights.
struct Converged {
    pose: Pose,
    obs: Vec<(usize, f64, usize)>,
    weights: Vec<f64>,
}

impl Converged {
    /// The rim samples whose edge the fit used, in order.
    fn matched(&self) -> Vec<usize> {
        self.obs
            .iter()
            .zip(&self.weights)
            .filter(|(_, w)| **w > 0.0)
            .map(|(o, _)| o.0)
            .collect()
    }
}

/// The cloud whose edges are looked for on the rim (an even sample of about [`EDGE_POINTS`]
/// of its points), indexed once for all the rim fits of an inspection.
pub(super) struct RimCloud<'a> {
    pts: std::borrow::Cow<'a, [[f64; 3]]>,
    tree: KdTree,
    /// Median distance from a point to its nearest neighbour, mm.
    spacing: f64,
    /// The narrowest search window, mm.
    finest: f64,
}

impl<'a> RimCloud<'a> {
    /// Index an even sample of `cloud` (the cloud frame; denser than the surface fit's, so that
    /// a strip across the rim holds several columns of points and where the scan ends is
    /// measured to a fraction of their spacing). The narrowest window is sized by the spacing
    /// of `sparse`, the surface fit's sample (a subset of the cloud where it is large), and by
    /// the area each point of the sample covers (see [`FINEST_OVER_AREA`]): a strip
    /// across the rim then holds enough of `pts` for a run even where the scan ends a few
    /// millimetres short of the rim. Sized by the spacing of `pts` alone, a strip of a sparse
    /// random cloud held about as few points as a run needs, and which strips showed an edge
    /// changed from one round to the next. `sparse_tree` indexes `sparse`.
    pub(super) fn new(cloud: &'a [[f64; 3]], sparse: &[[f64; 3]], sparse_tree: &KdTree) -> Self {
        let step = cloud.len() / EDGE_POINTS;
        let pts: std::borrow::Cow<'a, [[f64; 3]]> = if step > 1 {
            cloud.iter().step_by(step).copied().collect()
        } else {
            std::borrow::Cow::Borrowed(cloud)
        };
        let tree = KdTree::new(&pts);
        let spacing = point_spacing(&pts, &tree);
        let sparse_spacing = if sparse.len() < pts.len() {
            point_spacing(sparse, sparse_tree)
        } else {
            spacing
        };
        let areal = areal_spacing(&pts, &tree);
        RimCloud {
            pts,
            tree,
            spacing,
            finest: WINDOWS[WINDOWS.len() - 1]
                .max(6.0 * spacing.max(sparse_spacing))
                .max(FINEST_OVER_AREA * areal),
        }
    }
}

/// The narrowest window in areal point spacings: [`observe`] takes a strip's edge only where
/// the strip reaches four of its point spacings past the edge (a run's largest gap), which a
/// window of fewer than about five never does for an edge on the rim: a random cloud's
/// strips then showed edges only where their points happened to lie dense, biased inwards,
/// and the finest rounds walked millimetres off the rim they had found.
const FINEST_OVER_AREA: f64 = 6.0;

/// What [`register`] works with.
struct Scene<'a> {
    pts: &'a [[f64; 3]],
    tree: &'a KdTree,
    fit_set: Vec<[f64; 3]>,
    cad: &'a SignedDistance,
    rim: &'a CadRim,
    spacing: f64,
    finest: f64,
    /// How far from the rim a measured edge may lie and count as on it, mm.
    band: f64,
}

impl Scene<'_> {
    /// The windowed fit from `pose`; `None` when too few edges are found.
    fn converge(&self, pose: Pose) -> Option<Converged> {
        self.converge_in(pose, &WINDOWS)
    }

    /// The windowed fit from `pose`, narrowing through `windows` (mm, widest first; each
    /// raised to the finest).
    fn converge_in(&self, mut pose: Pose, windows: &[f64]) -> Option<Converged> {
        let centroid = Point3::from(
            self.fit_set
                .iter()
                .fold(Vector3::zeros(), |a, p| a + Vector3::from(*p))
                / self.fit_set.len() as f64,
        );
        // How far a change of pose moves the points: their centroid's shift and the turn at
        // a metre, mm.
        let motion = |a: &Pose, b: &Pose| {
            (a * centroid - b * centroid).norm()
                + crate::register::rotation_angle_deg(&(a * b.inverse())).to_radians() * 1000.0
        };
        let all = |_: &[f64; 3], _: f64| 1.0;
        // Every round refits the same points from a pose near the last.
        let hints = no_hints(self.fit_set.len());
        let mut windows: Vec<f64> = windows.iter().map(|d| d.max(self.finest)).collect();
        windows.dedup();
        // (the pose and the edges found when the finest window's rounds began)
        let mut finest_start = (pose, 0);
        for (w, &depth) in windows.iter().enumerate() {
            let finest = w + 1 == windows.len();
            // A wider window only brings the edges within the next one's reach; the last
            // settles to a hundredth of the point spacing.
            let settled = if finest {
                (0.01 * self.spacing).max(1e-3)
            } else {
                0.05 * depth
            };
            // A round's fit need go no further than a tenth of what ends the rounds: the next
            // round starts from its edges again. The finest window's rounds converge fully.
            let converged = if finest {
                super::CONVERGED_MM
            } else {
                0.1 * settled
            };
            for round in 0..8 {
                let obs = observe_all(self.rim, self.tree, self.pts, &pose, depth);
                if finest && round == 0 {
                    finest_start = (pose, obs.len());
                }
                if obs.len() < MIN_EDGES {
                    break;
                }
                let offsets: Vec<f64> = obs.iter().map(|o| o.1).collect();
                // The widest window weighs every edge it finds (a least-squares compromise
                // that a subset of coverage limits cannot drag); narrower ones trim to the
                // consensus.
                let weights = tukey(
                    &offsets,
                    (0.25 * depth).max(0.5 * self.spacing),
                    f64::INFINITY,
                );
                let edges = pairs(self.rim, &pose, &obs, &weights);
                if edges.len() < MIN_EDGES {
                    break;
                }
                let before = pose;
                (pose, _) = fit_with_edges_hinted(
                    &self.fit_set,
                    self.cad,
                    pose,
                    (20, converged),
                    &all,
                    &edges,
                    &hints,
                );
                if motion(&pose, &before) < settled {
                    break;
                }
            }
        }
        let obs = observe_all(self.rim, self.tree, self.pts, &pose, self.finest);
        // The finest window only refines: the wider ones brought every edge it uses within its
        // reach. Rounds that carry the points farther than the band while the edges they
        // started from fall away are not settling on those edges but following whichever are
        // left — a scan ending a few millimetres short of the rim all round, pulled onto it
        // one side at a time as the other side's edges leave the window: its edges are not
        // on the rim.
        if motion(&pose, &finest_start.0) > self.band
            && (obs.len() as f64) < KEPT_WHILE_SETTLING * finest_start.1 as f64
        {
            tracing::debug!(
                started = finest_start.1,
                ended = obs.len(),
                "rim-aware fit: the finest window's rounds walked off their edges"
            );
            return None;
        }
        let offsets: Vec<f64> = obs.iter().map(|o| o.1).collect();
        // At the finest window an edge within a few point spacings of the rim counts, however
        // widely the rest scatter (a wavering coverage limit near the rim).
        // and an edge is on the rim only within `band` of it.
        let mut weights: Vec<f64> = tukey(&offsets, 0.5 * self.spacing, self.spacing)
            .into_iter()
            .zip(&offsets)
            .map(|(w, e)| if e.abs() <= self.band { w } else { 0.0 })
            .collect();
        self.rim.in_runs(&obs, &mut weights, self.band);
        let c = Converged { pose, obs, weights };
        let on = c.matched().len();
        (on >= MIN_EDGES && on as f64 >= MIN_SHARE * c.obs.len() as f64).then_some(c)
    }

    /// About 3 000 of the cloud's points, for [`Scene::overhang`].
    fn overhang_sample(&self) -> Vec<[f64; 3]> {
        self.pts
            .iter()
            .step_by((self.pts.len() / 3000).max(1))
            .copied()
            .collect()
    }

    /// The fit of the surface alone from `start` (a placement where the scan shows no edge
    /// on the rim).
    fn surface_fit(&self, start: Pose) -> Pose {
        let all = |_: &[f64; 3], _: f64| 1.0;
        fit_with_edges(&self.fit_set, self.cad, start, 20, &all, &[]).0
    }

    /// RMS distance of the fitted points from the CAD surface at `pose` (each capped at
    /// 5 mm), mm.
    fn surface_rms(&self, pose: &Pose) -> f64 {
        let sq: f64 = self
            .fit_set
            .par_iter()
            .map(|p| {
                self.cad
                    .query(&(pose * Point3::from(*p)).coords)
                    .map_or(25.0, |c| c.distance.abs().min(5.0).powi(2))
            })
            .sum();
        (sq / self.fit_set.len().max(1) as f64).sqrt()
    }

    /// Points of a sample of the cloud that `pose` puts beyond the CAD's rim by more than two
    /// point spacings (where the part has no surface).
    fn overhang(&self, pose: &Pose, sample: &[[f64; 3]]) -> usize {
        let margin = (2.0 * self.spacing).max(1.0);
        sample
            .par_iter()
            .filter(|p| {
                self.cad
                    .query(&(pose * Point3::from(**p)).coords)
                    .is_some_and(|c| c.beyond_boundary && c.distance.abs() > margin)
            })
            .count()
    }

    /// Other places the scan's edges could sit on the rim: along each motion the surface
    /// barely pins, the scan slid as far as it goes without overhanging the rim (in either
    /// sense), and the windowed fit from there.
    fn rivals(&self, best: &Converged) -> Vec<Converged> {
        let fit_cad: Vec<[f64; 3]> = self
            .fit_set
            .iter()
            .map(|p| (best.pose * Point3::from(*p)).coords.into())
            .collect();
        let (centre, radius, weak) =
            super::conditioning::weak_motions(&fit_cad, self.cad, 5.0, PINS_BELOW);
        let sample = self.overhang_sample();
        let base = self.overhang(&best.pose, &sample);
        let allowed = base + 3 + sample.len() / 1000;
        let slid = |v: &nalgebra::Vector6<f64>, t: f64| {
            let omega = Vector3::new(v[0], v[1], v[2]) * (t / radius);
            let rot = nalgebra::UnitQuaternion::from_scaled_axis(omega);
            let shift = centre - rot * centre + Vector3::new(v[3], v[4], v[5]) * t;
            Pose::from_parts(shift.into(), rot) * best.pose
        };
        let extent = 2.0 * radius;
        let mut starts = Vec::new();
        for v in &weak {
            for sign in [1.0, -1.0] {
                // Double the slide until the scan overhangs the rim, then halve the bracket
                // down to a millimetre.
                let (mut ok, mut bad) = (0.0, None);
                let mut t = 1.0;
                while t <= extent {
                    if self.overhang(&slid(v, sign * t), &sample) > allowed {
                        bad = Some(t);
                        break;
                    }
                    ok = t;
                    t *= 2.0;
                }
                if let Some(mut hi) = bad {
                    while hi - ok > 1.0 {
                        let mid = 0.5 * (ok + hi);
                        if self.overhang(&slid(v, sign * mid), &sample) > allowed {
                            hi = mid;
                        } else {
                            ok = mid;
                        }
                    }
                }
                if ok >= 2.0 {
                    starts.push(slid(v, sign * ok));
                }
            }
        }
        starts
            .into_par_iter()
            .filter_map(|start| self.converge(start))
            .collect()
    }
}

/// A placement that matches at least this share of the winner's rim samples matches as much
/// rim as the winner, within the scatter of a coverage limit near the rim.
const FLAT_EVIDENCE: f64 = 0.9;
/// A surface RMS below this share of another placement's fits the surface clearly better (the
/// noise moves the RMS of placements along a slide by a few per cent).
const CLEARLY_BETTER: f64 = 0.8;

/// Rival placements resting on the rim at most this many tolerances (and at least 0.5 mm)
/// apart from the winner do not leave the rim unable to pin the fit: two fits of one trim
/// line's noisy edges settle that close, and a systematic deviation of two tolerances moves a
/// fit that far along a weakly pinned motion, which the report states as a warning, not as a
/// part not measured.
pub(super) const NEAR_RIVAL: f64 = 2.0;

/// Register `surface` (cloud frame: the trusted points) to `cad` from `pose` together with the
/// edges `cloud` shows on the CAD's rim; `None` when too few edges are found (the scan
/// does not reach the rim, or the CAD has none). `tolerance` (mm): poses that place the points
/// less than this apart are one. `rivals`: the other placements whose rim fits compete with
/// this one.
pub(super) fn register(
    cloud: &RimCloud,
    surface: &[[f64; 3]],
    cad: &SignedDistance,
    rim: &CadRim,
    pose: Pose,
    tolerance: f64,
    rivals: Rivals,
) -> Option<RimFit> {
    if rim.is_empty() || surface.len() < 10 {
        return None;
    }
    // The cloud's point spacing sets the narrowest window and the offsets' noise floor.
    let spacing = cloud.spacing;
    let scene = Scene {
        pts: &cloud.pts,
        tree: &cloud.tree,
        fit_set: surface
            .iter()
            .step_by((surface.len() / SURFACE_POINTS).max(1))
            .copied()
            .collect(),
        cad,
        rim,
        spacing,
        finest: cloud.finest,
        // a point spacing and a half, or a trim line's own tolerance
        band: (1.5 * spacing).max(2.0 * tolerance),
    };
    // A surface that pins every motion needs no rim.
    let fit_cad: Vec<[f64; 3]> = scene
        .fit_set
        .iter()
        .map(|p| (pose * Point3::from(*p)).coords.into())
        .collect();
    if super::conditioning::weak_motions(&fit_cad, cad, 5.0, PINS_BELOW)
        .2
        .is_empty()
    {
        return None;
    }
    let first = scene.converge(pose)?;
    let probe: Vec<Point3<f64>> = scene
        .fit_set
        .iter()
        .step_by(7)
        .map(|p| Point3::from(*p))
        .collect();
    // How far apart two placements put the points, mm.
    let apart = |a: &Pose, b: &Pose| {
        probe
            .iter()
            .map(|p| (a * p - b * p).norm())
            .fold(0.0, f64::max)
    };
    // The fit with the most rim wins; another that rests on rim samples the winner does not
    // use (a scan stopping short of the rim all round matches it at either side; a symmetric
    // outline matches it turned) is a rival.
    let (mut all, short) = match rivals {
        Rivals::None => return Some(finish(rim, &scene, first, None, false, None)),
        // Each placement an earlier search found is fitted again from where it ended, to the
        // trusted points as they are now: its edges are within the finest window's reach.
        Rivals::Reuse(search) => (
            search
                .others
                .par_iter()
                .filter_map(|c| scene.converge_in(c.pose, &[scene.finest]))
                .collect(),
            search.short.iter().map(|p| scene.surface_fit(*p)).collect(),
        ),
        Rivals::Fixture(held) => {
            let all = scene.rivals(&first);
            (all, vec![scene.surface_fit(held)])
        }
        Rivals::Search(contenders) => {
            let mut all = scene.rivals(&first);
            // A contender's placement is searched along its own slides as well: it starts
            // where the coarse alignment left it, perhaps as far off along the surface as the
            // first was. One whose scan reaches no rim at all is kept apart: placed there, the
            // scan may simply end short of the rim.
            let mut short = Vec::new();
            for p in contenders {
                match scene.converge(*p) {
                    Some(c) => {
                        all.extend(scene.rivals(&c));
                        all.push(c);
                    }
                    None => short.push(scene.surface_fit(*p)),
                }
            }
            (all, short)
        }
    };
    all.push(first);
    all.sort_by_key(|c| std::cmp::Reverse(c.matched().len()));
    // Among the placements resting on about as much rim as the most (where the rim cannot
    // choose), one that fits the surface clearly better wins: a nearly symmetric panel turned
    // the other way fits the rim as well but not the surface.
    let most = all[0].matched().len() as f64;
    let rms: Vec<(usize, f64)> = all
        .par_iter()
        .enumerate()
        .filter(|(_, c)| c.matched().len() as f64 >= FLAT_EVIDENCE * most)
        .map(|(i, c)| (i, scene.surface_rms(&c.pose)))
        .collect();
    if let (Some(&(i, r)), Some(&(_, first))) =
        (rms.iter().min_by(|a, b| a.1.total_cmp(&b.1)), rms.first())
    {
        if r < CLEARLY_BETTER * first {
            all.swap(0, i);
        }
    }
    let best = all.swap_remove(0);
    let matched = best.matched();
    let best_rms = scene.surface_rms(&best.pose);
    // (how far apart the points are placed, the rival's rim, turned by more than 10°)
    let rivals: Vec<(f64, usize, bool)> = all
        .iter()
        .filter_map(|c| {
            let apart = apart(&c.pose, &best.pose);
            // Each placement's own evidence: the rim it matches that the other does not. A
            // rival matches at least about half as much of its own as the winner does (a
            // wavering shadow line brushing the rim at its crests is not a trim line). Only a
            // sample across the motion between the two tells them apart (one along it fits
            // both), so each counts by how squarely it faces that motion.
            let theirs = c.matched();
            let rel = c.pose * best.pose.inverse();
            let facing = |k: &usize| {
                let s = &rim.samples[*k];
                let d = (rel * Point3::from(s.point)).coords - s.point;
                let n = d.norm();
                if n > 1e-9 {
                    (s.outward.dot(&d) / n).abs()
                } else {
                    0.0
                }
            };
            // and by how closely it sits on the rim (a trim line's edge scatters by the
            // edge estimate's noise; a coverage limit brushing the rim, across the band).
            let sigma = 0.5 * scene.spacing;
            let closeness = |c: &Converged, k: usize| {
                c.obs
                    .binary_search_by_key(&k, |o| o.0)
                    .map_or(0.0, |i| (-0.5 * (c.obs[i].1 / sigma).powi(2)).exp())
            };
            let exclusive = |x: &Converged, a: &[usize], b: &[usize]| -> f64 {
                a.iter()
                    .filter(|k| b.binary_search(k).is_err())
                    .map(|k| facing(k) * closeness(x, *k))
                    .sum()
            };
            let (new, own) = (
                exclusive(c, &theirs, &matched),
                exclusive(&best, &matched, &theirs),
            );

            // A placement far off that matches nearly as much rim as the winner is a rival
            // by that alone: along the motion between them the rim's evidence is flat (a
            // slide along a saddle's valley whose rim samples all face across it).
            let flat = theirs.len() as f64 >= FLAT_EVIDENCE * matched.len() as f64;
            // A placement turned against the winner that fits the surface clearly worse is
            // told apart by the surface (an outline symmetric where the surface is not).
            let turned = crate::register::rotation_angle_deg(&rel) > 10.0;
            (apart > tolerance.max(0.5)
                && 2 * theirs.len() >= matched.len()
                && (flat || new + MIN_EDGES as f64 >= 0.5 * own)
                && !(turned && best_rms < CLEARLY_BETTER * scene.surface_rms(&c.pose)))
            .then_some((apart, theirs.len(), turned))
        })
        .collect();
    // A contender that fits the surface as well, puts no more of the scan past the rim and
    // reaches no rim is not contradicted by the rim: the winner's edges may be where its
    // coverage ends, laid on the rim by the weak motions the fit had.
    let sample = scene.overhang_sample();
    let (own_rms, own_past) = (best_rms, scene.overhang(&best.pose, &sample));
    let allowed = own_past + 3 + sample.len() / 1000;
    let mut rivals = rivals;
    for &pose in &short {
        let rel = pose * best.pose.inverse();
        let apart = apart(&pose, &best.pose);
        if apart > tolerance.max(0.5)
            && scene.surface_rms(&pose) <= 1.25 * own_rms + 0.005
            && scene.overhang(&pose, &sample) <= allowed
        {
            rivals.push((apart, 0, crate::register::rotation_angle_deg(&rel) > 10.0));
        }
    }
    // A slide, or any placement that reaches no rim, leaves the rim unable to pin the weak
    // motions; a turned placement resting on the rim as well marks a symmetric outline. One
    // that places the points only a little apart is how closely the rim pins them.
    // A placement reaching no rim is a rival however near: placed there, the scan may end short
    // of the rim all round, and the rim's edges none of its own.
    let near = NEAR_RIVAL * tolerance.max(0.5);
    let untold = |r: &&(f64, usize, bool)| !r.2 || r.1 == 0;
    let is_near = |r: &&(f64, usize, bool)| r.0 <= near && r.1 > 0;
    let rival = rivals
        .iter()
        .filter(untold)
        .filter(|r| !is_near(r))
        .max_by(|a, b| a.0.total_cmp(&b.0));
    let spread = rivals
        .iter()
        .filter(untold)
        .filter(is_near)
        .map(|r| r.0)
        .max_by(f64::total_cmp);
    let turned_rival = rivals.iter().any(|r| r.2);
    let search = Search {
        from: best.pose,
        others: all,
        short,
    };
    let mut fit = finish(
        rim,
        &scene,
        best,
        rival.map(|r| (r.0, r.1)),
        turned_rival,
        Some(search),
    );
    fit.summary.spread_mm = spread.filter(|_| fit.summary.ambiguous.is_none());
    Some(fit)
}

/// The result of the winning fit `best`, with the farthest untold-apart placement (how far
/// the points move, its rim samples) when one was found.
fn finish(
    rim: &CadRim,
    scene: &Scene,
    best: Converged,
    rival: Option<(f64, usize)>,
    turned_rival: bool,
    search: Option<Search>,
) -> RimFit {
    let edges = pairs(rim, &best.pose, &best.obs, &best.weights);
    let used: Vec<f64> = best
        .obs
        .iter()
        .zip(&best.weights)
        .filter(|(_, w)| **w > 0.0)
        .map(|(o, _)| o.1)
        .collect();
    let rival = rival.map(|(apart, n)| (apart, n as f64 * rim.spacing));
    let summary = RimUse {
        cad_rim_mm: rim.samples.len() as f64 * rim.spacing,
        seen_mm: used.len() as f64 * rim.spacing,
        rms_mm: (used.iter().map(|e| e * e).sum::<f64>() / used.len() as f64).sqrt(),
        left_out: best.obs.len() - used.len(),
        ambiguous: rival.map(|r| ambiguity(used.len() as f64 * rim.spacing, r)),
        spread_mm: None,
    };
    tracing::debug!(?summary, spacing = scene.spacing, "rim-aware fit");
    RimFit {
        pose: best.pose,
        edges,
        summary,
        turned_rival,
        search,
    }
}

/// The side of the area each point of `pts` covers (the square root of the area per point
/// from the disk holding each sampled point's 12 nearest neighbours), mm: a lattice's
/// spacing, and for a random cloud about twice its median nearest-neighbour distance.
fn areal_spacing(pts: &[[f64; 3]], tree: &KdTree) -> f64 {
    const K: usize = 12;
    let d: Vec<f64> = pts
        .par_iter()
        .step_by((pts.len() / 2000).max(1))
        .map_init(Vec::new, |nn, p| {
            tree.k_nearest(p, K + 1, nn);
            nn.get(K)
                .map_or(f64::NAN, |e| (std::f64::consts::PI * e.1 / K as f64).sqrt())
        })
        .collect();
    median(&d)
}

/// Median distance from a point to its nearest neighbour (a sample of the cloud), mm.
fn point_spacing(pts: &[[f64; 3]], tree: &KdTree) -> f64 {
    let d: Vec<f64> = pts
        .par_iter()
        .step_by((pts.len() / 2000).max(1))
        .map_init(Vec::new, |nn, p| {
            tree.k_nearest(p, 2, nn);
            nn.get(1).map_or(f64::NAN, |e| e.1.sqrt())
        })
        .collect();
    median(&d)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::TriangleMesh;

    #[test]
    fn a_sheets_rim_is_sampled_with_outward_normals_in_its_plane() {
        let mesh = TriangleMesh::height_field(20, 10, (-50.0, 50.0), (-25.0, 25.0), |_, _| 0.0);
        let rim = CadRim::of(&SignedDistance::new(mesh));
        let perimeter = 2.0 * (100.0 + 50.0);
        let count = rim.samples.len() as f64;
        assert!(
            (count * rim.spacing - perimeter).abs() <= 2.0 * rim.spacing,
            "{count}"
        );
        for s in &rim.samples {
            assert!(s.outward.z.abs() < 1e-9 && s.normal.z.abs() > 0.999);
            // outward points away from the sheet's centre
            assert!(s.point.dot(&s.outward) > 0.0, "{:?}", s.point);
        }
        // a closed part (a tetrahedron) has none
        let tetra = TriangleMesh {
            vertices: vec![
                Vector3::new(0.0, 0.0, 0.0),
                Vector3::new(10.0, 0.0, 0.0),
                Vector3::new(0.0, 10.0, 0.0),
                Vector3::new(0.0, 0.0, 10.0),
            ],
            triangles: vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
        };
        assert!(CadRim::of(&SignedDistance::new(tetra)).is_empty());
    }

    #[test]
    fn an_edge_is_found_where_the_points_end() {
        // A lattice of 0.8 mm ending at x = 10.3 (the rim sample at x = 10).
        let mut pts = Vec::new();
        let mut x = -30.0;
        while x <= 10.3 {
            let mut y = -10.0;
            while y <= 10.0 {
                pts.push([x, y, 0.0]);
                y += 0.8;
            }
            x += 0.8;
        }
        let last = pts.iter().map(|p| p[0]).fold(f64::MIN, f64::max);
        let tree = KdTree::new(&pts);
        let s = RimSample {
            point: Vector3::new(10.0, 0.0, 0.0),
            outward: Vector3::x(),
            along: Vector3::y(),
            normal: Vector3::z(),
        };
        let (mut nn, mut u) = (Vec::new(), Vec::new());
        let (e, n) =
            observe(&s, &tree, &pts, &Pose::identity(), 10.0, &mut nn, &mut u).expect("edge");
        assert!(n > 20);
        // beyond the last column by less than one spacing
        assert!(e > last - 10.0 && e < last - 10.0 + 0.8, "{e} vs {last}");
        // a scan that runs on past the window shows no edge
        let far = RimSample {
            point: Vector3::new(-15.0, 0.0, 0.0),
            ..s
        };
        assert!(observe(&far, &tree, &pts, &Pose::identity(), 10.0, &mut nn, &mut u).is_none());
        // nor one that stops short of it
        let short = RimSample {
            point: Vector3::new(25.0, 0.0, 0.0),
            ..s
        };
        assert!(observe(
            &short,
            &tree,
            &pts,
            &Pose::identity(),
            10.0,
            &mut nn,
            &mut u
        )
        .is_none());
    }

    /// Domed sheets (spheres' caps, which slide along themselves; seeded radii, lattice
    /// spacings, strips and starting poses) scanned as a strip across their whole width:
    /// ending short of the rim at both ends of its length, the strip may sit anywhere along it
    /// (a rival placement rests on as much rim); reaching the rim at one end, it is pinned. The
    /// judgement made again from the search's placements, fitted again where they ended, must
    /// be the fresh search's.
    #[test]
    fn rivals_found_once_are_judged_again_from_where_they_ended() {
        let mut rng = crate::testing::Rng(48);
        for seed in 0..3 {
            let r = rng.range(3000.0, 8000.0);
            let h = rng.range(1.2, 1.8);
            let mesh =
                TriangleMesh::height_field(80, 60, (-200.0, 200.0), (-150.0, 150.0), |x, y| {
                    -(x * x + y * y) / (2.0 * r)
                });
            let cad = SignedDistance::new(mesh);
            let rim = CadRim::of(&cad);
            let (inner, reach) = (rng.range(60.0, 110.0), rng.range(150.0, 250.0));
            for (x0, x1, slides) in [(-inner, inner, true), (-200.0, reach - 200.0, false)] {
                // a lattice whose outermost points lie half a spacing inside the strip's ends
                let mut pts = Vec::new();
                let mut x = x0 + 0.5 * h;
                while x <= x1 {
                    let mut y = -150.0 + 0.5 * h;
                    while y <= 150.0 {
                        pts.push([x, y, -(x * x + y * y) / (2.0 * r)]);
                        y += h;
                    }
                    x += h;
                }
                let cloud = RimCloud::new(&pts, &pts, &KdTree::new(&pts));
                let surface: Vec<[f64; 3]> = pts.iter().step_by(3).copied().collect();
                let start = Pose::new(
                    Vector3::new(rng.range(-0.4, 0.4), rng.range(-0.4, 0.4), 0.1),
                    Vector3::new(0.0, 0.0, rng.range(-3e-4, 3e-4)),
                );
                let case =
                    format!("seed {seed}: r {r:.0} mm, lattice {h:.2} mm, strip x {x0:.0}…{x1:.0}");
                let fresh = register(
                    &cloud,
                    &surface,
                    &cad,
                    &rim,
                    start,
                    0.3,
                    Rivals::Search(&[]),
                )
                .expect("the rim is seen");
                let search = fresh.search.as_ref().expect("a search was made");
                let again = register(
                    &cloud,
                    &surface,
                    &cad,
                    &rim,
                    fresh.pose,
                    0.3,
                    Rivals::Reuse(search),
                )
                .expect("the rim is seen");
                assert_eq!(
                    fresh.summary.ambiguous.is_some(),
                    slides,
                    "{case}: {:?}",
                    fresh.summary
                );
                assert_eq!(
                    again.summary.ambiguous.is_some(),
                    slides,
                    "{case}: {:?}",
                    again.summary
                );
                assert!(!fresh.turned_rival && !again.turned_rival, "{case}");
                if !slides {
                    // Where it is pinned it is placed where it is, to within half the points'
                    // spacing (a lattice's last column says where the surface ends only that
                    // well), and stays there (where it slides, the placements along the slide
                    // are all as good: any may win).
                    let off = |pose: &Pose| {
                        pts.iter()
                            .map(|p| (pose * Point3::from(*p) - Point3::from(*p)).norm())
                            .fold(0.0, f64::max)
                    };
                    let (a, b) = (off(&fresh.pose), off(&again.pose));
                    eprintln!("{case}: {a:.3}, {b:.3} mm from the truth");
                    assert!(
                        a < 0.5 * h && (a - b).abs() < 0.01,
                        "{case}: {a}, {b} mm from the truth"
                    );
                }
            }
        }
    }
}
