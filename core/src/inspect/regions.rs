//! Out-of-tolerance regions: points whose |deviation| exceeds the tolerance, grouped by voxel
//! connectivity (26-neighbourhood) so a report names "a dent here" instead of listing points.

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
    let key = |p: &[f64; 3]| {
        [
            (p[0] / cell).floor() as i64,
            (p[1] / cell).floor() as i64,
            (p[2] / cell).floor() as i64,
        ]
    };
    let mut voxels: HashMap<[i64; 3], usize> = HashMap::new();
    let mut members: Vec<Vec<usize>> = Vec::new();
    for (i, (p, d)) in points.iter().zip(deviations).enumerate() {
        if d.abs() > tolerance {
            let v = *voxels.entry(key(p)).or_insert_with(|| {
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
                    if let Some(&u) = voxels.get(&[k[0] + dx, k[1] + dy, k[2] + dz]) {
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
