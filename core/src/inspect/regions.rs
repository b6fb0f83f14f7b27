//! Out-of-tolerance regions: points whose |deviation| exceeds the tolerance, grouped by voxel
//! connectivity (26-neighbourhood) so a report names "a dent here" instead of listing points.
//! Points above and below the tolerance band are grouped apart: a dent inside a bulge's
//! margin is its own finding, not part of the bulge.

use std::collections::HashMap;

use serde::Serialize;

use crate::disjoint_sets::DisjointSets;

/// One connected region out of tolerance.
#[derive(Clone, Debug, Serialize)]
pub struct Region {
    /// Points in the region.
    pub points: usize,
    /// Centroid, CAD frame, mm.
    pub centroid: [f64; 3],
    /// Deviation of largest magnitude, mm (signed).
    pub peak_deviation_mm: f64,
    /// Mean deviation, mm.
    pub mean_deviation_mm: f64,
}

/// Regions of at least `min_points` points with |deviation| > `tolerance`, clustered on a grid
/// of `cell` mm; largest |peak| first.
pub fn out_of_tolerance_regions(
    points: &[[f64; 3]],
    deviations: &[f64],
    tolerance: f64,
    cell: f64,
    min_points: usize,
) -> Vec<Region> {
    // Voxel and side of the band (1 above, -1 below).
    let key = |p: &[f64; 3], d: f64| {
        [
            (p[0] / cell).floor() as i64,
            (p[1] / cell).floor() as i64,
            (p[2] / cell).floor() as i64,
            if d > 0.0 { 1 } else { -1 },
        ]
    };
    let mut voxels: HashMap<[i64; 4], usize> = HashMap::new();
    let mut members: Vec<Vec<usize>> = Vec::new();
    for (i, (p, d)) in points.iter().zip(deviations).enumerate() {
        if d.abs() > tolerance {
            let v = *voxels.entry(key(p, *d)).or_insert_with(|| {
                members.push(Vec::new());
                members.len() - 1
            });
            members[v].push(i);
        }
    }
    // Union-find over occupied voxels.
    let mut sets = DisjointSets::new(members.len());
    for (k, &v) in &voxels {
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    if let Some(&u) = voxels.get(&[k[0] + dx, k[1] + dy, k[2] + dz, k[3]]) {
                        sets.union(u, v);
                    }
                }
            }
        }
    }
    let mut groups: HashMap<usize, Vec<usize>> = HashMap::new();
    for (v, m) in members.iter().enumerate() {
        groups.entry(sets.find(v)).or_default().extend(m);
    }
    let mut regions: Vec<Region> = groups
        .into_values()
        .filter(|g| g.len() >= min_points)
        .map(|g| {
            let n = g.len() as f64;
            let mut c = [0.0; 3];
            let (mut peak, mut sum) = (0.0f64, 0.0);
            for &i in &g {
                for k in 0..3 {
                    c[k] += points[i][k] / n;
                }
                sum += deviations[i];
                if deviations[i].abs() > peak.abs() {
                    peak = deviations[i];
                }
            }
            Region {
                points: g.len(),
                centroid: c,
                peak_deviation_mm: peak,
                mean_deviation_mm: sum / n,
            }
        })
        .collect();
    regions.sort_by(|a, b| {
        b.peak_deviation_mm
            .abs()
            .total_cmp(&a.peak_deviation_mm.abs())
    });
    regions
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A broad bulge whose out-of-tolerance margin reaches a small dent, over a 1 mm grid, for
    /// several sizes and places, grouped on cells of three spacings as reports group them:
    /// the dent is a region of its own, below the band, where it
    /// was planted, and the bulge one above it; together they hold every point out of
    /// tolerance.
    #[test]
    fn a_dent_inside_a_bulge_s_margin_is_a_region_of_its_own() {
        let tolerance = 0.3;
        for (k, (bulge_r, height)) in [(30.0, 0.6), (45.0, 0.5), (60.0, 0.8)].iter().enumerate() {
            let (bx, by) = (10.0 * k as f64, -5.0 * k as f64);
            // The dent where the bulge alone stands `height` mm, above the tolerance, so the
            // points between the two pass through the band only on the dent's own slope.
            let (dx, dy) = (bx + bulge_r * (1.3f64 / height).ln().sqrt(), by);
            let bump = |x: f64, y: f64, cx: f64, cy: f64, r: f64, a: f64| {
                a * (-((x - cx).powi(2) + (y - cy).powi(2)) / (r * r)).exp()
            };
            let (mut points, mut dev) = (Vec::new(), Vec::new());
            for i in -120..=120 {
                for j in -120..=120 {
                    let (x, y) = (i as f64, j as f64);
                    points.push([x, y, 0.0]);
                    dev.push(bump(x, y, bx, by, *bulge_r, 1.3) + bump(x, y, dx, dy, 8.0, -1.5));
                }
            }
            let regions = out_of_tolerance_regions(&points, &dev, tolerance, 3.0, 20);
            let below: Vec<&Region> = regions
                .iter()
                .filter(|r| r.peak_deviation_mm < 0.0)
                .collect();
            let above: Vec<&Region> = regions
                .iter()
                .filter(|r| r.peak_deviation_mm > 0.0)
                .collect();
            assert_eq!((below.len(), above.len()), (1, 1), "case {k}: {regions:?}");
            let near = |r: &Region, x: f64, y: f64| (r.centroid[0] - x).hypot(r.centroid[1] - y);
            assert!(
                near(below[0], dx, dy) < 2.0,
                "case {k}: dent {:?}",
                below[0]
            );
            assert!(below[0].mean_deviation_mm < -tolerance, "case {k}");
            assert!(above[0].mean_deviation_mm > tolerance, "case {k}");
            let out = dev.iter().filter(|d| d.abs() > tolerance).count();
            assert_eq!(below[0].points + above[0].points, out, "case {k}");
        }
    }
}
