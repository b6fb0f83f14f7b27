//! How much of the CAD surface the registered cloud measured: the fraction of the surface area
//! with a measured point nearby. A verdict on a part needs the part to have been measured; an
//! inspection below the minimum coverage is `not_measured`, never `pass`.

use rand::{Rng, SeedableRng};
use rayon::prelude::*;
use serde::Serialize;

use crate::mesh::TriangleMesh;
use crate::spatial::KdTree;

/// Samples of the CAD surface used to estimate the coverage.
pub(crate) const SAMPLES: usize = 20_000;

/// Measured coverage of the CAD surface.
#[derive(Clone, Debug, Serialize)]
pub struct Coverage {
    /// Fraction of the CAD surface area with a measured point within `radius_mm`.
    pub fraction: f64,
    /// The minimum fraction for a verdict.
    pub minimum: f64,
    /// Neighbourhood radius, mm: a few point spacings of the cloud.
    pub radius_mm: f64,
    /// Area of the inspected surface, mm².
    pub cad_area_mm2: f64,
    /// The surface the fraction is of, in words (the whole CAD, named faces, what the sensors
    /// can see).
    pub surface: String,
}

/// Area-uniform samples of the mesh surface with their triangles (fixed seed, so a report is
/// reproducible), and the area.
pub(crate) fn surface_samples(mesh: &TriangleMesh, n: usize) -> (Vec<([f64; 3], u32)>, f64) {
    let mut cumulative = Vec::with_capacity(mesh.triangles.len());
    let mut total = 0.0;
    for t in 0..mesh.triangles.len() {
        let [a, b, c] = mesh.corners(t);
        let area = 0.5 * (b - a).cross(&(c - a)).norm();
        if area.is_finite() {
            total += area;
        }
        cumulative.push(total);
    }
    if total <= 0.0 {
        return (Vec::new(), 0.0);
    }
    let mut rng = rand::rngs::SmallRng::seed_from_u64(0x5eed);
    let samples = (0..n)
        .map(|_| {
            let x = rng.random::<f64>() * total;
            let t = cumulative
                .partition_point(|c| *c < x)
                .min(cumulative.len() - 1);
            let [a, b, c] = mesh.corners(t);
            let (mut u, mut v) = (rng.random::<f64>(), rng.random::<f64>());
            if u + v > 1.0 {
                (u, v) = (1.0 - u, 1.0 - v);
            }
            ((a + (b - a) * u + (c - a) * v).into(), t as u32)
        })
        .collect();
    (samples, total)
}

/// Coverage of `mesh` by `points` (CAD frame; only points on the surface, |deviation| small,
/// should be passed): the radius is four times the median nearest-neighbour spacing of the
/// points (at least 1 mm).
pub fn coverage(mesh: &TriangleMesh, points: &[[f64; 3]], minimum: f64) -> Coverage {
    let (samples, area) = surface_samples(mesh, SAMPLES);
    let samples: Vec<[f64; 3]> = samples.into_iter().map(|(p, _)| p).collect();
    coverage_of(
        &samples,
        area,
        points,
        minimum,
        "the whole CAD surface".into(),
    )
}

/// Coverage of the surface that `samples` (area-uniform over it) stand for, of `area` mm².
pub(crate) fn coverage_of(
    samples: &[[f64; 3]],
    area: f64,
    points: &[[f64; 3]],
    minimum: f64,
    surface: String,
) -> Coverage {
    if points.len() < 2 || samples.is_empty() {
        return Coverage {
            fraction: 0.0,
            minimum,
            radius_mm: 0.0,
            cad_area_mm2: area,
            surface,
        };
    }
    let tree = KdTree::new(points);
    let probe: Vec<usize> = (0..points.len())
        .step_by((points.len() / 2000).max(1))
        .collect();
    let mut spacing: Vec<f64> = probe
        .par_iter()
        .map_init(Vec::new, |nn, &i| {
            tree.k_nearest(&points[i], 2, nn);
            nn.iter()
                .map(|(_, d2)| *d2)
                .filter(|d2| *d2 > 0.0)
                .fold(f64::INFINITY, f64::min)
                .sqrt()
        })
        .filter(|d| d.is_finite())
        .collect();
    spacing.sort_by(f64::total_cmp);
    let median = spacing.get(spacing.len() / 2).copied().unwrap_or(1.0);
    let radius = (4.0 * median).max(1.0);
    let hit = samples
        .par_iter()
        .filter(|s| tree.nearest_within(s, radius * radius).is_some())
        .count();
    Coverage {
        fraction: hit as f64 / samples.len() as f64,
        minimum,
        radius_mm: radius,
        cad_area_mm2: area,
        surface,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn coverage_is_the_measured_share_of_the_surface() {
        let mesh = TriangleMesh::height_field(20, 10, (0.0, 200.0), (0.0, 100.0), |_, _| 0.0);
        // A 2 mm grid over the left 60 % of the sheet.
        let mut pts = Vec::new();
        for j in 0..=50 {
            for i in 0..=60 {
                pts.push([2.0 * i as f64, 2.0 * j as f64, 0.0]);
            }
        }
        let c = coverage(&mesh, &pts, 0.5);
        // The neighbourhood radius (4 spacings, 8 mm) counts a band past the measured edge.
        let expected = (120.0 + c.radius_mm) / 200.0;
        assert!((c.radius_mm - 8.0).abs() < 1e-9, "{c:?}");
        assert!((c.fraction - expected).abs() < 0.02, "{c:?}");
        assert!((c.cad_area_mm2 - 20_000.0).abs() < 1e-6);
        let none = coverage(&mesh, &[[1e5, 0.0, 0.0], [1e5, 1.0, 0.0]], 0.5);
        assert_eq!(none.fraction, 0.0);
    }
}
