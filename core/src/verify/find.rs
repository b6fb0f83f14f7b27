//! Finding a calibrated artefact of known size in a cloud that also holds the table, posts and
//! clutter: spheres by one-point hypotheses (a point and its normal put the centre one radius
//! inwards), flats by region growing on planar seeds, each kept only when its size matches.

use nalgebra::SymmetricEigen;
use rayon::prelude::*;

use super::fit::{fit_plane, fit_sphere, PlaneFit, SphereFit};
use crate::geometry::{Mat3, Vec3};
use crate::spatial::KdTree;

use crate::spatial::{IntMap as CellMap, IntSet as CellSet};

/// A uniform hash grid over a cloud, for the points within a distance of a place.
pub(crate) struct Grid {
    cell: f64,
    cells: CellMap<[i32; 3], Vec<u32>>,
}

impl Grid {
    pub fn new(points: &[Vec3], cell: f64) -> Grid {
        let mut cells: CellMap<[i32; 3], Vec<u32>> = CellMap::default();
        for (i, p) in points.iter().enumerate() {
            cells.entry(key(p, cell)).or_default().push(i as u32);
        }
        Grid { cell, cells }
    }

    /// Call `f` with every point index in the cells that a ball of `radius` about `c` touches
    /// (a superset of the points within `radius`).
    pub fn around(&self, c: &Vec3, radius: f64, mut f: impl FnMut(usize)) {
        let lo = key(&(c - Vec3::repeat(radius)), self.cell);
        let hi = key(&(c + Vec3::repeat(radius)), self.cell);
        for x in lo[0]..=hi[0] {
            for y in lo[1]..=hi[1] {
                for z in lo[2]..=hi[2] {
                    if let Some(v) = self.cells.get(&[x, y, z]) {
                        v.iter().for_each(|&i| f(i as usize));
                    }
                }
            }
        }
    }
}

fn key(p: &Vec3, cell: f64) -> [i32; 3] {
    std::array::from_fn(|k| (p[k] / cell).floor().clamp(-1e9, 1e9) as i32)
}

/// A cloud prepared for searching.
pub(crate) struct Searchable<'a> {
    pub points: &'a [Vec3],
    tree: KdTree,
    /// Median distance between neighbouring points, mm.
    pub spacing: f64,
}

const NORMAL_NEIGHBOURS: usize = 16;

/// Largest angle between a point's local normal and its artefact's normal there, degrees.
const NORMAL_AGREEMENT_DEG: f64 = 30.0;

impl<'a> Searchable<'a> {
    pub fn new(points: &'a [Vec3]) -> Searchable<'a> {
        let raw: Vec<[f64; 3]> = points.iter().map(|p| [p.x, p.y, p.z]).collect();
        let tree = KdTree::new(&raw);
        let mut nn = Vec::new();
        let step = (points.len() / 200).max(1);
        let mut d: Vec<f64> = Vec::new();
        for p in points.iter().step_by(step) {
            tree.k_nearest(&[p.x, p.y, p.z], 2, &mut nn);
            if let Some(&(_, d2)) = nn.get(1) {
                d.push(d2.sqrt());
            }
        }
        d.sort_by(f64::total_cmp);
        let spacing = d.get(d.len() / 2).copied().unwrap_or(1.0).max(1e-3);
        Searchable {
            points,
            tree,
            spacing,
        }
    }

    /// Unit normal and RMS off the local plane of the neighbours of point `i`.
    fn normal(&self, i: usize, nn: &mut Vec<(usize, f64)>) -> Option<(Vec3, f64)> {
        let p = self.points[i];
        self.tree.k_nearest(&[p.x, p.y, p.z], NORMAL_NEIGHBOURS, nn);
        if nn.len() < 8 {
            return None;
        }
        let n = nn.len() as f64;
        let mean = nn
            .iter()
            .fold(Vec3::zeros(), |a, &(j, _)| a + self.points[j])
            / n;
        let mut cov = Mat3::zeros();
        for &(j, _) in nn.iter() {
            let d = self.points[j] - mean;
            cov += d * d.transpose();
        }
        let eig = SymmetricEigen::new(cov / n);
        let k = (0..3).min_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]))?;
        Some((
            eig.eigenvectors.column(k).into_owned().normalize(),
            eig.eigenvalues[k].max(0.0).sqrt(),
        ))
    }

    /// The points of `indices` whose local surface normal lies within `max_angle` of the
    /// normal `expected` gives for them: a band about a fitted form also catches the rim of
    /// whatever touches it (a sphere's post, a flat's side faces), whose normals turn away.
    pub fn with_normals_like(
        &self,
        indices: &[usize],
        expected: impl Fn(&Vec3) -> Vec3 + Sync,
        max_angle_deg: f64,
    ) -> Vec<usize> {
        let min_cos = max_angle_deg.to_radians().cos();
        indices
            .par_iter()
            .map_init(Vec::new, |nn, &j| {
                let ok = self
                    .normal(j, nn)
                    .is_some_and(|(n, _)| n.dot(&expected(&self.points[j])).abs() >= min_cos);
                ok.then_some(j)
            })
            .flatten()
            .collect()
    }

    /// About `count` seed indices spread evenly through the cloud's order.
    fn seeds(&self, count: usize) -> impl Iterator<Item = usize> {
        let n = self.points.len();
        let step = (n / count.max(1)).max(1);
        (step / 2..n).step_by(step)
    }
}

/// A sphere found in a cloud: its fit and the points on it.
#[derive(Clone, Debug)]
pub(crate) struct FoundSphere {
    pub fit: SphereFit,
    pub inliers: Vec<usize>,
}

/// Spheres of nominal `radius` in the cloud, most supported first, at most `max` of them.
/// A candidate's radius must come out within `radius_tolerance` (relative) of the nominal.
pub(crate) fn spheres(
    s: &Searchable<'_>,
    radius: f64,
    radius_tolerance: f64,
    min_points: usize,
    max: usize,
) -> Vec<FoundSphere> {
    let grid = Grid::new(s.points, radius);
    let band = (0.08 * radius).max(3.0 * s.spacing).min(0.5 * radius);
    let score = |c: &Vec3| {
        let mut count = 0usize;
        grid.around(c, radius + band, |j| {
            let d = (s.points[j] - c).norm();
            if (d - radius).abs() < band {
                count += 1;
            }
        });
        count
    };
    // At least one seed per hundred points: in a sensor's whole cloud the table holds most
    // points, and a sphere of a few hundred must still get several.
    let seeds: Vec<usize> = s.seeds((s.points.len() / 100).clamp(600, 10_000)).collect();
    let mut hyps: Vec<(usize, Vec3)> = seeds
        .par_iter()
        .map_init(Vec::new, |nn, &i| {
            let Some((n, _)) = s.normal(i, nn) else {
                return Vec::new();
            };
            [1.0, -1.0]
                .iter()
                .map(|sign| {
                    let c = s.points[i] + n * (sign * radius);
                    (score(&c), c)
                })
                .collect::<Vec<_>>()
        })
        .flatten()
        .collect();
    hyps.sort_by_key(|h| std::cmp::Reverse(h.0));
    let mut found: Vec<FoundSphere> = Vec::new();
    // Hypotheses near one already refined (kept or not) would refine to the same place.
    let mut tried: Vec<Vec3> = Vec::new();
    for (count, c) in hyps {
        if found.len() >= max || count < min_points / 2 {
            break;
        }
        if tried.iter().any(|t| (t - c).norm() < 0.5 * radius) {
            continue;
        }
        tried.push(c);
        if let Some(f) = refine_sphere(s, &grid, c, radius, radius_tolerance, band) {
            tried.push(f.fit.centre);
            if (f.fit.radius - radius).abs() <= radius_tolerance * radius
                && !found
                    .iter()
                    .any(|g| (g.fit.centre - f.fit.centre).norm() < radius)
            {
                found.push(f);
            }
        }
    }
    found.sort_by_key(|f| std::cmp::Reverse(f.inliers.len()));
    found
}

/// Fit a sphere about a hypothesis: the points within `band` of it, fitted with free radius,
/// then again with the band narrowed to the fit's own scatter (never below what a real form
/// error of the sphere needs: the band stays at least 0.3 mm); `None` when it wanders off or
/// its radius is beyond twice `radius_tolerance` of `radius`.
fn refine_sphere(
    s: &Searchable<'_>,
    grid: &Grid,
    centre: Vec3,
    radius: f64,
    radius_tolerance: f64,
    band: f64,
) -> Option<FoundSphere> {
    let (mut c, mut r, mut b) = (centre, radius, band);
    let mut inliers = Vec::new();
    let mut fit = None;
    for _ in 0..5 {
        inliers.clear();
        grid.around(&c, r + b, |j| {
            if ((s.points[j] - c).norm() - r).abs() < b {
                inliers.push(j);
            }
        });
        let pts: Vec<Vec3> = inliers.iter().map(|&j| s.points[j]).collect();
        let f = fit_sphere(&pts)?;
        if (f.centre - c).norm() > radius {
            return None;
        }
        c = f.centre;
        r = f.radius;
        b = (6.0 * f.rms).max(0.3).min(band.max(0.3));
        fit = Some(f);
    }
    // A fit far from the nominal size is no artefact whatever its rim holds: the normals
    // (the costly part) are checked only on candidates near it.
    if (r - radius).abs() > 2.0 * radius_tolerance * radius {
        return None;
    }
    let inliers = s.with_normals_like(&inliers, |p| (p - c).normalize(), NORMAL_AGREEMENT_DEG);
    let pts: Vec<Vec3> = inliers.iter().map(|&j| s.points[j]).collect();
    let fit = fit_sphere(&pts).or(fit)?;
    Some(FoundSphere { fit, inliers })
}

/// A planar region found in a cloud.
#[derive(Clone, Debug)]
pub(crate) struct FoundPlane {
    pub fit: PlaneFit,
    pub inliers: Vec<usize>,
    /// Extent along the region's long and short in-plane axes, mm.
    pub extent: [f64; 2],
    /// Area the region's points cover, mm².
    pub area: f64,
}

/// Planar regions of the cloud, largest first: grown from planar seeds through neighbouring
/// points near the plane (refitted as the region grows, so a warped face is followed), then
/// every point over the region's footprint within a loose band of the final plane, so that
/// the flatness figure sees the face's whole form, not only what a tight band let in.
pub(crate) fn planes(s: &Searchable<'_>, max: usize) -> Vec<FoundPlane> {
    let link = (3.0 * s.spacing).max(0.05);
    let grid = Grid::new(s.points, link);
    let mut taken = vec![false; s.points.len()];
    let mut out = Vec::new();
    let mut nn = Vec::new();
    let seeds: Vec<usize> = s.seeds(300).collect();
    for i in seeds {
        if taken[i] || out.len() >= 4 * max {
            continue;
        }
        let Some((n, local_rms)) = s.normal(i, &mut nn) else {
            continue;
        };
        let local_extent = nn.last().map(|&(_, d2)| d2.sqrt()).unwrap_or(link);
        if local_rms > 0.1 * local_extent {
            continue; // not a planar neighbourhood
        }
        let band = (6.0 * local_rms).max(0.3);
        let region = grow(s, &grid, &mut taken, i, n, band, link);
        if region.len() < 50 {
            continue;
        }
        if let Some(p) = describe_plane(s, &grid, region, link) {
            out.push(p);
        }
    }
    out.sort_by(|a, b| b.area.total_cmp(&a.area));
    out.truncate(max);
    out
}

fn grow(
    s: &Searchable<'_>,
    grid: &Grid,
    taken: &mut [bool],
    seed: usize,
    normal: Vec3,
    band: f64,
    link: f64,
) -> Vec<usize> {
    let mut plane = PlaneFit {
        point: s.points[seed],
        normal,
        rms: 0.0,
    };
    let mut region = vec![seed];
    taken[seed] = true;
    let mut next_refit = 64usize;
    let mut k = 0;
    while k < region.len() {
        let p = s.points[region[k]];
        k += 1;
        grid.around(&p, link, |j| {
            if !taken[j]
                && (s.points[j] - p).norm() <= link
                && plane.residual(&s.points[j]).abs() < band
            {
                taken[j] = true;
                region.push(j);
            }
        });
        if region.len() >= next_refit {
            let pts: Vec<Vec3> = region.iter().map(|&j| s.points[j]).collect();
            if let Some(f) = fit_plane(&pts) {
                plane = f;
            }
            next_refit = region.len() * 2;
        }
    }
    region
}

fn describe_plane(
    s: &Searchable<'_>,
    grid: &Grid,
    region: Vec<usize>,
    link: f64,
) -> Option<FoundPlane> {
    let pts: Vec<Vec3> = region.iter().map(|&j| s.points[j]).collect();
    let fit = fit_plane(&pts)?;
    let (u, v) = in_plane_axes(&pts, &fit);
    // The footprint: occupied cells of a 2D grid in the plane.
    let cell = 2.0 * link;
    let uv = |p: &Vec3| {
        let d = p - fit.point;
        (
            (d.dot(&u) / cell).floor() as i64,
            (d.dot(&v) / cell).floor() as i64,
        )
    };
    let footprint: CellSet<(i64, i64)> = pts.iter().map(uv).collect();
    // Every point over the footprint within a loose band: the 3D cells about the region.
    let mut cells: CellSet<[i32; 3]> = CellSet::default();
    for p in &pts {
        let k = key(p, grid.cell);
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    cells.insert([k[0] + dx, k[1] + dy, k[2] + dz]);
                }
            }
        }
    }
    let loose = (8.0 * fit.rms).max(1.0);
    let mut inliers = Vec::with_capacity(region.len());
    for k in &cells {
        for &m in grid.cells.get(k).map(Vec::as_slice).unwrap_or(&[]) {
            let q = &s.points[m as usize];
            if fit.residual(q).abs() < loose && footprint.contains(&uv(q)) {
                inliers.push(m as usize);
            }
        }
    }
    inliers.sort_unstable();
    // Side faces can only come in at the footprint's border: check the normals there alone.
    let interior = |q: &Vec3| {
        let (a, b) = uv(q);
        (-1..=1).all(|da| (-1..=1).all(|db| footprint.contains(&(a + da, b + db))))
    };
    let (inner, border): (Vec<usize>, Vec<usize>) =
        inliers.iter().partition(|&&j| interior(&s.points[j]));
    let mut inliers = inner;
    inliers.extend(s.with_normals_like(&border, |_| fit.normal, NORMAL_AGREEMENT_DEG));
    inliers.sort_unstable();
    let pts: Vec<Vec3> = inliers.iter().map(|&j| s.points[j]).collect();
    let fit = fit_plane(&pts)?;
    let (u, v) = in_plane_axes(&pts, &fit);
    let extent = [spread(&pts, &fit.point, &u), spread(&pts, &fit.point, &v)];
    Some(FoundPlane {
        fit,
        inliers,
        extent,
        area: footprint.len() as f64 * cell * cell,
    })
}

/// The long and short principal axes of points in their plane.
pub(crate) fn in_plane_axes(pts: &[Vec3], fit: &PlaneFit) -> (Vec3, Vec3) {
    let mut cov = Mat3::zeros();
    for p in pts {
        let d = p - fit.point;
        cov += d * d.transpose();
    }
    let eig = SymmetricEigen::new(cov);
    let k = (0..3)
        .max_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]))
        .unwrap_or(0);
    let mut u = eig.eigenvectors.column(k).into_owned();
    u -= fit.normal * u.dot(&fit.normal);
    let u = if u.norm() > 1e-9 {
        u.normalize()
    } else {
        fit.normal.cross(&Vec3::x()).normalize()
    };
    (u, fit.normal.cross(&u))
}

/// Robust extent along `axis` (0.1st to 99.9th percentile of the projections).
fn spread(pts: &[Vec3], origin: &Vec3, axis: &Vec3) -> f64 {
    let mut t: Vec<f64> = pts.iter().map(|p| (p - origin).dot(axis)).collect();
    if t.is_empty() {
        return 0.0;
    }
    t.sort_by(f64::total_cmp);
    let at = |q: f64| t[((t.len() - 1) as f64 * q).round() as usize];
    at(0.999) - at(0.001)
}
