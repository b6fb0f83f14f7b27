//! Datum features measured from the cloud (CAD frame, near the nominal): an RPS surface point,
//! a hole's centre, a slot's centre line and an outer edge. Each gives a measured position and
//! the directions it pins. An edge in a uniformly sampled surface is best located by its
//! extreme points (the largest empty circle for a hole; the innermost or outermost points of a
//! straight edge): the gap between the true edge and the k-th point in from it, over a length
//! L at areal density ρ, is k/(ρ L) on average, which sizes and edge positions correct for
//! (centres need no correction: opposite sides' gaps cancel).

use nalgebra::{Matrix3, Vector3};

use super::datums::{Datum, Feature};

/// A feature measured in the cloud.
#[derive(Clone, Debug)]
pub(super) struct Measured {
    /// Measured position, CAD frame (for a hole or slot, on the nominal's tangent plane).
    pub position: Vector3<f64>,
    /// The unit directions the feature pins.
    pub directions: Vec<Vector3<f64>>,
    /// A hole's diameter or a slot's width, mm.
    pub size: Option<f64>,
    /// Edge samples (or patch points) the measurement rests on.
    pub samples: usize,
}

/// Local frame at a datum: origin and two tangent directions (e1 × e2 the axis); `first` is
/// the datum's in-surface direction when it has one.
struct Frame {
    origin: Vector3<f64>,
    e1: Vector3<f64>,
    e2: Vector3<f64>,
}

impl Frame {
    fn new(origin: Vector3<f64>, axis: Vector3<f64>, first: Option<Vector3<f64>>) -> Option<Frame> {
        let axis = axis.try_normalize(1e-12)?;
        let seed = first.unwrap_or_else(|| {
            if axis.x.abs() < 0.9 {
                Vector3::x()
            } else {
                Vector3::y()
            }
        });
        let e1 = (seed - axis * seed.dot(&axis)).try_normalize(1e-9)?;
        Some(Frame {
            origin,
            e1,
            e2: axis.cross(&e1),
        })
    }

    fn uv(&self, p: &Vector3<f64>) -> (f64, f64) {
        let d = p - self.origin;
        (d.dot(&self.e1), d.dot(&self.e2))
    }

    /// In-plane coordinates of the points on the surface around the datum: those within
    /// 1 mm + a fifth of `radius` of the median height above the tangent plane (what a hole or
    /// an edge shows beyond it, a floor or a wall, is not the surface whose edge is measured).
    fn surface_uv(&self, points: &[Vector3<f64>], radius: f64) -> Vec<(f64, f64)> {
        let axis = self.e1.cross(&self.e2);
        let h: Vec<f64> = points
            .iter()
            .map(|p| (p - self.origin).dot(&axis))
            .collect();
        let level = median(&mut h.clone());
        let band = 1.0 + 0.2 * radius;
        points
            .iter()
            .zip(&h)
            .filter(|(_, z)| (*z - level).abs() <= band)
            .map(|(p, _)| self.uv(p))
            .collect()
    }

    fn at(&self, u: f64, v: f64) -> Vector3<f64> {
        self.origin + self.e1 * u + self.e2 * v
    }
}

/// Measure `datum` from `points` (CAD frame, its neighbourhood); `normal` is the CAD's normal at
/// the nominal position. `Err` says why it could not be measured.
pub(super) fn measure(
    datum: &Datum,
    points: &[Vector3<f64>],
    normal: Vector3<f64>,
) -> Result<Measured, String> {
    let q = Vector3::from(datum.position);
    let dir = datum.direction.map(Vector3::from);
    let m = measure_feature(datum, points, normal, q, dir)?;
    // A size far from the nominal is another feature (a slot taken for a hole, a hole for a
    // slot) or a wrong place, not this datum.
    let nominal = datum.diameter.or(datum.width);
    if let (Some(size), Some(nominal)) = (m.size, nominal) {
        if (size - nominal).abs() > (0.15 * nominal).max(1.0) {
            return Err(format!(
                "the feature found measures {size:.2} mm against a nominal {nominal} mm"
            ));
        }
    }
    Ok(m)
}

fn measure_feature(
    datum: &Datum,
    points: &[Vector3<f64>],
    normal: Vector3<f64>,
    q: Vector3<f64>,
    dir: Option<Vector3<f64>>,
) -> Result<Measured, String> {
    match datum.feature {
        Feature::Surface => Err("a surface datum is fitted point by point".into()),
        Feature::Point => point(q, dir.unwrap_or(normal), points, datum.radius),
        Feature::Hole => {
            let f = Frame::new(q, dir.unwrap_or(normal), None).ok_or("degenerate axis")?;
            hole(
                &f,
                points,
                0.5 * datum.diameter.unwrap_or(0.0),
                datum.radius,
            )
        }
        Feature::Slot => {
            let f = Frame::new(q, normal, dir)
                .ok_or("the slot's direction is along the surface normal")?;
            slot(
                &f,
                points,
                datum.width.unwrap_or(0.0),
                datum.length.unwrap_or(0.0),
                datum.radius,
            )
        }
        Feature::Edge => {
            let f = Frame::new(q, normal, dir)
                .ok_or("the edge's direction is along the surface normal")?;
            edge(&f, points, datum.radius)
        }
    }
}

/// Where the surface fitted to the patch within `radius` of `q` crosses the line q + s·d.
fn point(
    q: Vector3<f64>,
    d: Vector3<f64>,
    points: &[Vector3<f64>],
    radius: f64,
) -> Result<Measured, String> {
    let d = d.try_normalize(1e-12).ok_or("degenerate direction")?;
    let near: Vec<&Vector3<f64>> = points
        .iter()
        .filter(|p| (*p - q).norm() <= radius)
        .collect();
    if near.len() < 10 {
        return Err(format!(
            "{} points within {radius} mm (10 needed)",
            near.len()
        ));
    }
    let g = near.iter().fold(Vector3::zeros(), |a, p| a + *p) / near.len() as f64;
    let cov = near
        .iter()
        .fold(Matrix3::zeros(), |a, p| a + (*p - g) * (*p - g).transpose());
    let e = cov.symmetric_eigen();
    let n = e.eigenvectors.column(e.eigenvalues.imin()).into_owned();
    let dn = d.dot(&n);
    if dn.abs() < 0.2 {
        return Err("the pinned direction runs along the measured surface".into());
    }
    let s = (g - q).dot(&n) / dn;
    Ok(Measured {
        position: q + d * s,
        directions: vec![d],
        size: None,
        samples: near.len(),
    })
}

/// Circle fit (algebraic, Kåsa) to `(u, v)` samples: centre and radius.
fn circle(samples: &[(f64, f64)]) -> Option<(f64, f64, f64)> {
    let mut a = Matrix3::<f64>::zeros();
    let mut b = Vector3::<f64>::zeros();
    for &(u, v) in samples {
        let r = Vector3::new(u, v, 1.0);
        a += r * r.transpose();
        b -= r * (u * u + v * v);
    }
    let x = a.cholesky()?.solve(&b);
    let (cu, cv) = (-0.5 * x[0], -0.5 * x[1]);
    let r2 = cu * cu + cv * cv - x[2];
    (r2 > 0.0).then(|| (cu, cv, r2.sqrt()))
}

/// Median of `v` (NaN when empty); reorders it.
fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let m = v.len() / 2;
    *v.select_nth_unstable_by(m, f64::total_cmp).1
}

/// How far beyond a datum's `radius` its feature is searched, mm: the starting pose of a part
/// that slides along its own surface (a near-quadric sheet) may be off by this much.
pub(super) const SEARCH_MARGIN: f64 = 25.0;

/// The centre of the empty region nearest the origin whose clearance (distance to the nearest
/// point) lies within `clear` and that the surface encloses: points in each of 12 directions
/// within `enclose` of it (an unseen area is not a hole). Candidates on a grid of `step` within
/// `reach`.
fn locate(
    uv: &[(f64, f64)],
    clear: std::ops::Range<f64>,
    enclose: f64,
    reach: f64,
    step: f64,
) -> Option<(f64, f64)> {
    let flat: Vec<[f64; 3]> = uv.iter().map(|(u, v)| [*u, *v, 0.0]).collect();
    let tree = crate::spatial::KdTree::new(&flat);
    // At most 201 × 201 grid nodes and 200 enclosure checks, whatever the datum's sizes.
    let step = step.max(reach / 100.0);
    let n = (reach / step).ceil() as i64;
    let mut cand: Vec<(f64, f64, f64)> = Vec::new();
    for i in -n..=n {
        for j in -n..=n {
            let (u, v) = (i as f64 * step, j as f64 * step);
            let d = u.hypot(v);
            if d > reach {
                continue;
            }
            if let Some((_, d2)) = tree.nearest(&[u, v, 0.0]) {
                if clear.contains(&d2.sqrt()) {
                    cand.push((d, u, v));
                }
            }
        }
    }
    cand.sort_by(|a, b| a.0.total_cmp(&b.0));
    cand.into_iter()
        .take(200)
        .map(|(_, u, v)| (u, v))
        .find(|&(u, v)| {
            let mut sectors = [false; 12];
            for (pu, pv) in uv {
                let (du, dv) = (pu - u, pv - v);
                if du.hypot(dv) <= enclose {
                    let turn = dv.atan2(du) / std::f64::consts::TAU + 1.0;
                    sectors[(turn * 12.0) as usize % 12] = true;
                }
            }
            sectors.iter().all(|s| *s)
        })
}

/// Angular bins of the first, coarse circle through a hole's edge.
const HOLE_BINS: usize = 36;
/// Sectors of 30° that must each hold an edge sample: a hole seen only partly is not measured
/// (its empty side would pull the centre).
const HOLE_SECTORS: usize = 12;

/// The `k`-th smallest of `v` (k from 1), reordering it.
fn kth_smallest(v: &mut [f64], k: usize) -> f64 {
    let k = k.clamp(1, v.len()) - 1;
    *v.select_nth_unstable_by(k, f64::total_cmp).1
}

/// The centre `c` within `reach` of `c0` that maximises the distance to the nearest of `pts`
/// (the largest empty circle, linearised about c0): the maximum-likelihood edge of a hole in a
/// uniformly sampled surface, accurate to about 1/(ρ·circumference) rather than to the point
/// spacing. Nested ternary searches on the convex max of affine functions.
fn largest_empty_circle(pts: &[(f64, f64)], c0: (f64, f64), reach: f64) -> (f64, f64, f64) {
    let lin: Vec<(f64, f64, f64)> = pts
        .iter()
        .map(|(u, v)| {
            let (du, dv) = (u - c0.0, v - c0.1);
            let d = du.hypot(dv).max(1e-12);
            (du / d, dv / d, d)
        })
        .collect();
    // -(radius) of the empty circle centred at c0 + (x, y), to first order.
    let f = |x: f64, y: f64| {
        lin.iter()
            .map(|(a, b, d)| a * x + b * y - d)
            .fold(f64::NEG_INFINITY, f64::max)
    };
    let ternary = |lo: f64, hi: f64, g: &dyn Fn(f64) -> f64| {
        let (mut lo, mut hi) = (lo, hi);
        for _ in 0..48 {
            let (m1, m2) = (lo + (hi - lo) / 3.0, hi - (hi - lo) / 3.0);
            if g(m1) <= g(m2) {
                hi = m2;
            } else {
                lo = m1;
            }
        }
        0.5 * (lo + hi)
    };
    let best_y = |x: f64| ternary(-reach, reach, &|y| f(x, y));
    let x = ternary(-reach, reach, &|x| f(x, best_y(x)));
    let y = best_y(x);
    (c0.0 + x, c0.1 + y, -f(x, y))
}

/// A hole's centre: a first circle through the innermost point in each of 36 directions (its
/// outliers beyond 3 robust sigmas dropped), then the largest circle empty of points near it,
/// re-linearised twice. The edge must be seen in every 30° sector.
fn hole(f: &Frame, points: &[Vector3<f64>], r0: f64, radius: f64) -> Result<Measured, String> {
    let uv = f.surface_uv(points, radius);
    let reach = radius + SEARCH_MARGIN;
    let (mut cu, mut cv) = locate(
        &uv,
        0.6 * r0..1.3 * r0,
        r0 + 3.0,
        reach,
        (0.25 * r0).min(1.0),
    )
    .ok_or_else(|| {
        format!(
            "no hole of about {:.1} mm diameter within {reach:.0} mm of the nominal",
            2.0 * r0
        )
    })?;
    let mut samples: Vec<(f64, f64)> = Vec::new();
    let mut r = r0;
    for _ in 0..3 {
        let mut inner = [f64::INFINITY; HOLE_BINS];
        let mut at = [(0.0, 0.0); HOLE_BINS];
        for &(u, v) in &uv {
            let (du, dv) = (u - cu, v - cv);
            let rho = du.hypot(dv);
            if rho > radius {
                continue;
            }
            let turn = dv.atan2(du) / std::f64::consts::TAU + 1.0;
            let bin = (turn * HOLE_BINS as f64) as usize % HOLE_BINS;
            if rho < inner[bin] {
                inner[bin] = rho;
                at[bin] = (u, v);
            }
        }
        // An edge sample lies beyond half the hole's radius and well inside the searched
        // neighbourhood (a direction with no surface seen gives none).
        samples = (0..HOLE_BINS)
            .filter(|&b| inner[b] > 0.5 * r0 && inner[b] < r0 + 0.6 * (radius - r0))
            .map(|b| at[b])
            .collect();
        for _ in 0..2 {
            let (u0, v0, rr) = circle(&samples)
                .ok_or_else(|| format!("no circle through {} edge samples", samples.len()))?;
            let mut res: Vec<f64> = samples
                .iter()
                .map(|(u, v)| ((u - u0).hypot(v - v0) - rr).abs())
                .collect();
            let limit = (3.0 * 1.4826 * median(&mut res)).max(1e-3);
            samples.retain(|(u, v)| ((u - u0).hypot(v - v0) - rr).abs() <= limit);
        }
        let (u0, v0, rr) = circle(&samples).ok_or("no circle through the edge samples")?;
        (cu, cv, r) = (u0, v0, rr);
    }
    let mut sectors = [false; HOLE_SECTORS];
    for (u, v) in &samples {
        let turn = (v - cv).atan2(u - cu) / std::f64::consts::TAU + 1.0;
        sectors[(turn * HOLE_SECTORS as f64) as usize % HOLE_SECTORS] = true;
    }
    let seen = sectors.iter().filter(|s| **s).count();
    if seen < HOLE_SECTORS {
        return Err(format!(
            "its edge was seen in {seen} of {HOLE_SECTORS} directions (30° sectors; all needed)"
        ));
    }
    if cu.hypot(cv) > reach {
        return Err(format!(
            "the edge found is {:.1} mm from the nominal centre, beyond the searched neighbourhood",
            cu.hypot(cv)
        ));
    }
    // The coarse circle runs through the innermost samples, a mean gap outside the edge; points
    // further in than a few gaps (and the noise) are strays, not surface.
    let mut spread: Vec<f64> = samples
        .iter()
        .map(|(u, v)| ((u - cu).hypot(v - cv) - r).abs())
        .collect();
    let inner_limit = r - 4.0 * 1.4826 * median(&mut spread) - 0.1;
    for _ in 0..2 {
        let ring: Vec<(f64, f64)> = uv
            .iter()
            .copied()
            .filter(|(u, v)| (inner_limit..r + 2.0).contains(&(u - cu).hypot(v - cv)))
            .collect();
        let reach = (0.25 * r).min(2.0);
        (cu, cv, r) = largest_empty_circle(&ring, (cu, cv), reach);
    }
    // The diameter is the empty circle's: an upper bound of the hole's, by a fraction of the
    // point spacing (it grows into the gaps between the edge points).
    let size = 2.0 * r;
    Ok(Measured {
        position: f.at(cu, cv),
        directions: vec![f.e1, f.e2],
        size: Some(size),
        samples: samples.len(),
    })
}

/// Order statistic used for straight edges: the second point in from the edge, so one stray
/// point does not move it; its expected gap from a uniformly sampled edge of length L is
/// 2/(ρ·L).
const EDGE_RANK: usize = 2;

/// A slot's centre line. First over the central half of its straight part (a pose off by a
/// quarter of that still finds no rounded end), then over the whole straight part between its
/// ends as found: the innermost points on either side; the midpoint of the two order
/// statistics is unbiased, the width is corrected by their expected gaps.
fn slot(
    f: &Frame,
    points: &[Vector3<f64>],
    width: f64,
    length: f64,
    radius: f64,
) -> Result<Measured, String> {
    let uv = f.surface_uv(points, radius);
    let quarter = 0.25 * (length - width);
    let reach = radius + SEARCH_MARGIN;
    let (u0, mut cv) = locate(
        &uv,
        0.3 * width..0.65 * width,
        length + 3.0,
        reach,
        (0.2 * width).min(1.0),
    )
    .ok_or_else(|| format!("no slot {width} mm wide within {reach:.0} mm of the nominal"))?;
    let (mut lo, mut hi) = (u0 - quarter, u0 + quarter);
    let mut result = Err("no edge samples".to_string());
    for _ in 0..3 {
        let mut window: Vec<(f64, f64)> = uv
            .iter()
            .filter(|(u, v)| (lo..=hi).contains(u) && (v - cv).abs() <= radius)
            .map(|(u, v)| (*u, v - cv))
            .collect();
        // Centre on the widest empty band near the current centre line (the pose may be off
        // by more than half the width).
        let mut vs: Vec<f64> = window.iter().map(|(_, v)| *v).collect();
        vs.sort_by(f64::total_cmp);
        if let Some(mid) = vs
            .windows(2)
            .filter(|w| w[1] - w[0] > 0.5 * width && w[1] > -width && w[0] < width)
            .max_by(|a, b| (a[1] - a[0]).total_cmp(&(b[1] - b[0])))
            .map(|w| 0.5 * (w[0] + w[1]))
        {
            cv += mid;
            window.iter_mut().for_each(|(_, v)| *v -= mid);
        }
        // Both sides must be seen along the whole window.
        let span = hi - lo;
        let mut seen = [[false; 2]; 8];
        for (u, v) in &window {
            seen[(((u - lo) / span) * 8.0).min(7.0) as usize][usize::from(*v >= 0.0)] = true;
        }
        if !seen.iter().all(|s| s[0] && s[1]) {
            return Err(format!(
                "both its sides were seen in {} of 8 places along it (all needed)",
                seen.iter().filter(|s| s[0] && s[1]).count()
            ));
        }
        let mut top: Vec<f64> = window
            .iter()
            .map(|(_, v)| *v)
            .filter(|v| *v >= 0.0)
            .collect();
        let mut bottom: Vec<f64> = window
            .iter()
            .map(|(_, v)| -v)
            .filter(|v| *v > 0.0)
            .collect();
        let t = kth_smallest(&mut top, EDGE_RANK);
        let b = kth_smallest(&mut bottom, EDGE_RANK);
        if !(0.5 * width..2.0 * width).contains(&(t + b)) {
            return Err(format!(
                "the gap found is {:.2} mm wide against a nominal {width} mm",
                t + b
            ));
        }
        let depth = radius - 0.5 * width;
        let gap = |side: &[f64]| {
            let n = side.iter().filter(|v| **v <= 0.5 * width + depth).count() as f64;
            EDGE_RANK as f64 / (n / depth.max(1e-9)).max(1e-9)
        };
        let w = t + b - gap(&top) - gap(&bottom);
        cv += 0.5 * (t - b);
        result = Ok(Measured {
            position: f.at(0.0, cv),
            directions: vec![f.e2],
            size: Some(w),
            samples: top.len() + bottom.len(),
        });
        // The ends: the innermost points along the centre line; the straight part lies half a
        // width inside them (less a margin for the caps' sampling).
        let along: Vec<f64> = uv
            .iter()
            .filter(|(_, v)| (v - cv).abs() < 0.25 * w.max(0.5 * width))
            .map(|(u, _)| *u)
            .collect();
        let end = |sign: f64| {
            along
                .iter()
                .map(|u| sign * u)
                .filter(|u| *u > 0.0)
                .fold(f64::INFINITY, f64::min)
        };
        let (e_hi, e_lo) = (end(1.0), -end(-1.0));
        let found = e_hi - e_lo;
        if found.is_finite() && (0.8 * length..1.2 * length).contains(&found) {
            let margin = 0.5 * width + 1.0;
            if e_hi - e_lo > 2.0 * margin + quarter {
                (lo, hi) = (e_lo + margin, e_hi - margin);
            }
        }
    }
    result
}

/// An outer straight edge: the outermost points within `radius` along it; the order statistic
/// corrected by its expected gap. The outward direction is pinned.
fn edge(f: &Frame, points: &[Vector3<f64>], radius: f64) -> Result<Measured, String> {
    const BINS: usize = 8;
    // e1 is the outward direction (u); the edge runs along e2 (v).
    let reach = radius + SEARCH_MARGIN;
    let uv: Vec<(f64, f64)> = f
        .surface_uv(points, radius)
        .into_iter()
        .filter(|(u, v)| u.abs() <= reach && v.abs() <= radius)
        .collect();
    let mut seen = [false; BINS];
    for (_, v) in &uv {
        seen[(((v + radius) / (2.0 * radius)) * BINS as f64).min(BINS as f64 - 1.0) as usize] =
            true;
    }
    if uv.len() < 20 || !seen.iter().all(|s| *s) {
        return Err(format!(
            "the surface along it was seen in {} of {BINS} places (all needed)",
            seen.iter().filter(|s| **s).count()
        ));
    }
    let mut out: Vec<f64> = uv.iter().map(|(u, _)| -u).collect();
    let e = -kth_smallest(&mut out, EDGE_RANK);
    if e >= reach - 1.0 {
        return Err("the surface runs on past the searched neighbourhood: no edge there".into());
    }
    let depth = (0.5 * (e + reach)).min(radius);
    let n = uv
        .iter()
        .filter(|(u, _)| *u >= e - depth && *u <= e)
        .count();
    let rho = n as f64 / (depth * 2.0 * radius).max(1e-9);
    let gap = EDGE_RANK as f64 / (rho * 2.0 * radius).max(1e-9);
    Ok(Measured {
        position: f.at(e + gap, 0.0),
        directions: vec![f.e1],
        size: None,
        samples: uv.len(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A flat sheet z = 0 sampled at `density` points/mm² over [-r, r]², with `keep`.
    fn sheet(
        seed: u64,
        r: f64,
        density: f64,
        keep: impl Fn(f64, f64) -> bool,
    ) -> Vec<Vector3<f64>> {
        let mut rng = crate::testing::Rng(seed);
        let mut uni = || rng.uniform();
        let n = (density * 4.0 * r * r) as usize;
        (0..n)
            .filter_map(|_| {
                let (x, y) = (-r + 2.0 * r * uni(), -r + 2.0 * r * uni());
                keep(x, y).then(|| Vector3::new(x, y, 0.0))
            })
            .collect()
    }

    fn datum(feature: Feature, position: [f64; 3], radius: f64) -> Datum {
        Datum {
            feature,
            order: Some(2),
            ..Datum::region("X", position, radius)
        }
    }

    #[test]
    fn hole_centre_and_diameter_from_its_edge() {
        for seed in 0..5 {
            let (cx, cy) = (1.3 - 0.4 * seed as f64, -0.7 + 0.3 * seed as f64);
            let pts = sheet(seed, 30.0, 2.0, |x, y| (x - cx).hypot(y - cy) > 6.0);
            let d = Datum {
                diameter: Some(12.0),
                ..datum(Feature::Hole, [0.0; 3], 15.0)
            };
            let m = measure(&d, &pts, Vector3::z()).expect("measured");
            assert!(
                (m.position.x - cx).abs() < 0.06 && (m.position.y - cy).abs() < 0.06,
                "{:?}",
                m.position
            );
            assert!(
                (m.size.expect("size") - 12.0).abs() < 0.15,
                "diameter {:?}",
                m.size
            );
        }
    }

    #[test]
    fn hole_half_seen_is_not_measured() {
        let pts = sheet(3, 30.0, 2.0, |x, y| x.hypot(y) > 6.0 && x < 0.0);
        let d = Datum {
            diameter: Some(12.0),
            ..datum(Feature::Hole, [0.0; 3], 15.0)
        };
        let e = measure(&d, &pts, Vector3::z()).expect_err("not measured");
        assert!(e.contains("directions") || e.contains("no hole"), "{e}");
    }

    #[test]
    fn slot_centre_line_and_width() {
        for seed in 0..5u64 {
            let cy = 0.8 - 1.7 * seed as f64;
            let pts = sheet(7 + seed, 40.0, 2.0, |x, y| {
                !(x.abs() < 10.0 && (y - cy).abs() < 4.0 || (x.abs() - 10.0).hypot(y - cy) < 4.0)
            });
            let d = Datum {
                width: Some(8.0),
                length: Some(28.0),
                direction: Some([1.0, 0.0, 0.0]),
                ..datum(Feature::Slot, [1.5, 0.0, 0.0], 15.0)
            };
            let m = measure(&d, &pts, Vector3::z()).expect("measured");
            eprintln!("slot {cy}: {:?} {:?}", m.position, m.size);
            assert!((m.position.y - cy).abs() < 0.12, "{:?}", m.position);
            assert!(
                (m.size.expect("size") - 8.0).abs() < 0.3,
                "width {:?}",
                m.size
            );
            assert!((m.directions[0] - Vector3::y()).norm() < 1e-9);
        }
    }

    #[test]
    fn edge_position_corrected_for_the_point_spacing() {
        for (seed, ex) in [(1u64, 2.0), (2, -1.5), (3, 0.3)] {
            let pts = sheet(seed, 20.0, 1.0, |x, _| x < ex);
            let d = Datum {
                direction: Some([1.0, 0.0, 0.0]),
                ..datum(Feature::Edge, [0.0; 3], 10.0)
            };
            let m = measure(&d, &pts, Vector3::z()).expect("measured");
            assert!(
                (m.position.x - ex).abs() < 0.12,
                "edge at {ex}: {:?}",
                m.position
            );
        }
    }

    #[test]
    fn absurd_sizes_cost_bounded_work() {
        // A 0.01 mm hole searched over 5 km: the grid and the enclosure checks are capped,
        // so this answers at once (found or not) instead of walking 10^12 nodes.
        let pts = sheet(4, 30.0, 2.0, |x, y| x.hypot(y) > 6.0);
        let d = Datum {
            diameter: Some(0.01),
            ..datum(Feature::Hole, [0.0; 3], 5000.0)
        };
        let _ = measure(&d, &pts, Vector3::z());
        let s = Datum {
            width: Some(0.01),
            length: Some(1e6),
            direction: Some([1.0, 0.0, 0.0]),
            ..datum(Feature::Slot, [0.0; 3], 5000.0)
        };
        let _ = measure(&s, &pts, Vector3::z());
    }

    #[test]
    fn rps_point_on_a_tilted_patch() {
        let pts: Vec<Vector3<f64>> = sheet(9, 10.0, 4.0, |_, _| true)
            .into_iter()
            .map(|p| Vector3::new(p.x, p.y, 0.7 + 0.1 * p.x))
            .collect();
        let d = datum(Feature::Point, [0.0; 3], 5.0);
        let m = measure(&d, &pts, Vector3::z()).expect("measured");
        assert!((m.position.z - 0.7).abs() < 1e-9, "{:?}", m.position);
    }
}
