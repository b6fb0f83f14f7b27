//! Sensor → cell calibration with a marker gauge (Ch. 5.2.3, SPEC §9): segment the measured
//! markers, fit each one's centre, find the gauge markers they are without an initial pose
//! (distance-consistent triangles), refine by ICP on the centres, and gate the result.

use std::collections::HashMap;

use nalgebra::{Matrix3, SymmetricEigen};
use serde::Serialize;

use super::gauge::Gauge;
use crate::cloud::PointCloud;
use crate::geometry::Vec3;
use crate::register::{fit_rigid, Pose};
use crate::spatial::KdTree;
use crate::{Error, Result};

/// Thresholds of the gauge fit.
#[derive(Clone, Debug)]
pub struct GaugeParams {
    /// Points closer than this (mm) belong to the same marker.
    pub link: f64,
    /// Fewest points a marker must have.
    pub min_points: usize,
    /// Largest ratio of the in-plane spreads (a full disc is 1; a cut marker is elongated).
    pub max_elongation: f64,
    /// Allowed relative error of the radius estimated from the spread (a cut or merged marker
    /// is too small or too large).
    pub radius_tolerance: f64,
    /// Distance (mm) within which a measured centre and a gauge centre are the same marker.
    pub match_tolerance: f64,
    /// Fewest matched markers for a calibration.
    pub min_markers: usize,
    /// Largest accepted RMS of the matched centres, mm.
    pub max_rms: f64,
}

impl Default for GaugeParams {
    fn default() -> Self {
        GaugeParams {
            link: 2.5,
            min_points: 20,
            max_elongation: 1.35,
            radius_tolerance: 0.3,
            match_tolerance: 1.0,
            min_markers: 4,
            max_rms: 0.3,
        }
    }
}

/// One marker found in a sensor's cloud.
#[derive(Clone, Debug, Serialize)]
pub struct MeasuredMarker {
    /// Fitted centre, sensor frame.
    pub center: [f64; 3],
    /// Points in the marker.
    pub points: usize,
    /// Radius implied by the points' spread, mm.
    pub radius: f64,
    /// Index of the gauge marker it was matched to.
    pub gauge_index: Option<usize>,
    /// Distance to that gauge marker after the fit, mm.
    pub residual: Option<f64>,
}

/// A point cluster that was not used as a marker, and why.
#[derive(Clone, Debug, Serialize)]
pub struct RejectedCluster {
    /// Cluster centroid, sensor frame.
    pub centroid: [f64; 3],
    /// Points in the cluster.
    pub points: usize,
    /// Why it was rejected.
    pub reason: String,
}

/// The calibration of one sensor against the gauge.
#[derive(Clone, Debug)]
pub struct GaugeFit {
    /// Sensor world → cell transform.
    pub to_common: Pose,
    /// Markers accepted as full discs.
    pub markers: Vec<MeasuredMarker>,
    /// Clusters rejected (cut at the image border, shadowed, noise).
    pub rejected: Vec<RejectedCluster>,
    /// Matched markers.
    pub matched: usize,
    /// RMS of the matched centres, mm.
    pub rms: f64,
    /// Largest matched residual, mm.
    pub max: f64,
}

/// Calibrate one sensor: `cloud` is its measurement of the gauge in the sensor world frame.
pub fn fit_gauge(cloud: &PointCloud, gauge: &Gauge, params: &GaugeParams) -> Result<GaugeFit> {
    let (mut markers, rejected) = find_markers(cloud, gauge.radius, params);
    let found = markers.len();
    if found < params.min_markers.max(3) {
        return Err(Error::Insufficient(format!(
            "{found} complete markers found ({} clusters rejected); need {}",
            rejected.len(),
            params.min_markers.max(3)
        )));
    }
    let measured: Vec<Vec3> = markers.iter().map(|m| Vec3::from(m.center)).collect();
    let tree = KdTree::new(
        &gauge
            .centers
            .iter()
            .map(|c| [c.x, c.y, c.z])
            .collect::<Vec<_>>(),
    );
    let coarse = coarse_alignment(&measured, gauge, &tree, params).ok_or_else(|| {
        Error::Insufficient(format!(
            "none of the {found} measured markers forms a triangle that matches the gauge \
             within {} mm",
            params.match_tolerance
        ))
    })?;
    let (pose, pairs) = refine(&measured, gauge, &tree, coarse, params);
    if pairs.len() < params.min_markers || 2 * pairs.len() < found {
        return Err(Error::Insufficient(format!(
            "only {} of {found} markers match the gauge within {} mm; need {} and at least \
             half: is this the right gauge file?",
            pairs.len(),
            params.match_tolerance,
            params.min_markers
        )));
    }
    let mut sq = 0.0;
    let mut max = 0.0f64;
    for &(i, g) in &pairs {
        let r = (pose * nalgebra::Point3::from(measured[i])
            - nalgebra::Point3::from(gauge.centers[g]))
        .norm();
        markers[i].gauge_index = Some(g);
        markers[i].residual = Some(r);
        sq += r * r;
        max = max.max(r);
    }
    let rms = (sq / pairs.len() as f64).sqrt();
    if rms > params.max_rms {
        return Err(Error::Insufficient(format!(
            "matched marker RMS {rms:.3} mm exceeds {} mm: the gauge file does not describe \
             what the sensor measured, or the sensor is not calibrated",
            params.max_rms
        )));
    }
    tracing::info!(
        found,
        matched = pairs.len(),
        rejected = rejected.len(),
        rms_mm = rms,
        max_mm = max,
        "gauge fit"
    );
    Ok(GaugeFit {
        to_common: pose,
        markers,
        rejected,
        matched: pairs.len(),
        rms,
        max,
    })
}

/// Cluster the cloud (voxel connectivity at `link`) and keep the clusters that are complete
/// discs of the gauge's radius, with their centres.
fn find_markers(
    cloud: &PointCloud,
    radius: f64,
    params: &GaugeParams,
) -> (Vec<MeasuredMarker>, Vec<RejectedCluster>) {
    let cell = params.link;
    let key = |p: &[f32; 3]| {
        (
            (f64::from(p[0]) / cell).floor() as i64,
            (f64::from(p[1]) / cell).floor() as i64,
            (f64::from(p[2]) / cell).floor() as i64,
        )
    };
    let mut cells: HashMap<(i64, i64, i64), Vec<u32>> = HashMap::new();
    for (i, p) in cloud.points.iter().enumerate() {
        if p.iter().all(|v| v.is_finite()) {
            cells.entry(key(p)).or_default().push(i as u32);
        }
    }
    let mut label: HashMap<(i64, i64, i64), usize> = HashMap::with_capacity(cells.len());
    let mut clusters: Vec<Vec<u32>> = Vec::new();
    let mut keys: Vec<_> = cells.keys().copied().collect();
    keys.sort_unstable();
    let mut stack = Vec::new();
    for k in keys {
        if label.contains_key(&k) {
            continue;
        }
        let id = clusters.len();
        let mut members = Vec::new();
        label.insert(k, id);
        stack.push(k);
        while let Some(c) = stack.pop() {
            members.extend_from_slice(&cells[&c]);
            for dz in -1..=1 {
                for dy in -1..=1 {
                    for dx in -1..=1 {
                        let n = (c.0 + dx, c.1 + dy, c.2 + dz);
                        if cells.contains_key(&n) && !label.contains_key(&n) {
                            label.insert(n, id);
                            stack.push(n);
                        }
                    }
                }
            }
        }
        clusters.push(members);
    }
    let mut markers = Vec::new();
    let mut rejected = Vec::new();
    for members in clusters {
        let pts: Vec<Vec3> = members
            .iter()
            .map(|&i| {
                let p = cloud.points[i as usize];
                Vec3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]))
            })
            .collect();
        let centroid = pts.iter().sum::<Vec3>() / pts.len() as f64;
        let reject = |reason: String| RejectedCluster {
            centroid: [centroid.x, centroid.y, centroid.z],
            points: pts.len(),
            reason,
        };
        if pts.len() < params.min_points {
            rejected.push(reject(format!(
                "{} points (fewer than {})",
                pts.len(),
                params.min_points
            )));
            continue;
        }
        match disc_center(&pts, radius, params) {
            Ok((center, r)) => markers.push(MeasuredMarker {
                center: [center.x, center.y, center.z],
                points: pts.len(),
                radius: r,
                gauge_index: None,
                residual: None,
            }),
            Err(reason) => rejected.push(reject(reason)),
        }
    }
    (markers, rejected)
}

/// Centre and effective radius of a disc of points: the centroid after dropping points far
/// from the disc (flying pixels), checked for roundness and size. A uniformly sampled disc has
/// in-plane variance r²/4 along every direction.
fn disc_center(pts: &[Vec3], radius: f64, params: &GaugeParams) -> Result<(Vec3, f64), String> {
    let mut center = pts.iter().sum::<Vec3>() / pts.len() as f64;
    let mut normal = Vec3::z();
    let mut spread = (0.0, 0.0);
    for pass in 0..2 {
        let keep = |p: &Vec3| {
            pass == 0 || {
                let d = p - center;
                let h = d.dot(&normal);
                h.abs() < 0.5 * radius && (d - normal * h).norm() < 1.3 * radius
            }
        };
        let kept: Vec<&Vec3> = pts.iter().filter(|p| keep(p)).collect();
        if kept.len() < params.min_points {
            return Err(format!("{} points after removing outliers", kept.len()));
        }
        center = kept.iter().copied().sum::<Vec3>() / kept.len() as f64;
        let mut cov = Matrix3::zeros();
        for p in &kept {
            let d = *p - center;
            cov += d * d.transpose();
        }
        cov /= kept.len() as f64;
        let eig = SymmetricEigen::new(cov);
        let mut order = [0usize, 1, 2];
        order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
        normal = eig.eigenvectors.column(order[2]).into_owned();
        spread = (
            eig.eigenvalues[order[0]],
            eig.eigenvalues[order[1]].max(1e-12),
        );
    }
    let elongation = (spread.0 / spread.1).sqrt();
    let r = (2.0 * (spread.0 + spread.1)).sqrt();
    if elongation > params.max_elongation {
        return Err(format!(
            "elongated (spread ratio {elongation:.2} > {}): cut by a border, a shadow or an occlusion",
            params.max_elongation
        ));
    }
    if (r - radius).abs() > params.radius_tolerance * radius {
        return Err(format!(
            "radius {r:.2} mm, the gauge's is {radius} mm (± {:.0} %)",
            params.radius_tolerance * 100.0
        ));
    }
    Ok((center, r))
}

/// A pose from measured (sensor) to gauge (cell) centres without an initial guess: for large
/// measured triangles, every gauge triangle with the same side lengths is a hypothesis; the one
/// under which most measured markers land on a gauge marker wins.
fn coarse_alignment(
    measured: &[Vec3],
    gauge: &Gauge,
    tree: &KdTree,
    params: &GaugeParams,
) -> Option<Pose> {
    let tol = params.match_tolerance;
    let g = &gauge.centers;
    let mut pairs: Vec<(f64, u32, u32)> = Vec::with_capacity(g.len() * (g.len() - 1) / 2);
    for i in 0..g.len() {
        for j in i + 1..g.len() {
            pairs.push(((g[i] - g[j]).norm(), i as u32, j as u32));
        }
    }
    pairs.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
    let score = |pose: &Pose| -> (usize, f64) {
        let mut n = 0;
        let mut sq = 0.0;
        for m in measured {
            let p = pose * nalgebra::Point3::from(*m);
            if let Some((_, d2)) = tree.nearest(&[p.x, p.y, p.z]) {
                if d2 <= tol * tol {
                    n += 1;
                    sq += d2;
                }
            }
        }
        (n, sq)
    };
    let mut best: Option<(usize, f64, Pose)> = None;
    let anchors = measured.len().min(12);
    for a in 0..anchors {
        let b = (0..measured.len())
            .max_by(|&x, &y| {
                (measured[x] - measured[a])
                    .norm()
                    .total_cmp(&(measured[y] - measured[a]).norm())
            })
            .filter(|&b| b != a)?;
        let c = (0..measured.len())
            .max_by(|&x, &y| {
                let area = |k: usize| {
                    (measured[b] - measured[a])
                        .cross(&(measured[k] - measured[a]))
                        .norm()
                };
                area(x).total_cmp(&area(y))
            })
            .filter(|&c| c != a && c != b)?;
        let (dab, dac, dbc) = (
            (measured[a] - measured[b]).norm(),
            (measured[a] - measured[c]).norm(),
            (measured[b] - measured[c]).norm(),
        );
        let lo = pairs.partition_point(|p| p.0 < dab - tol);
        for &(d, i, j) in &pairs[lo..] {
            if d > dab + tol {
                break;
            }
            for (gi, gj) in [(i as usize, j as usize), (j as usize, i as usize)] {
                for (gk, gc) in g.iter().enumerate() {
                    if ((g[gi] - gc).norm() - dac).abs() > tol
                        || ((g[gj] - gc).norm() - dbc).abs() > tol
                    {
                        continue;
                    }
                    let from = [measured[a], measured[b], measured[c]].map(|v| [v.x, v.y, v.z]);
                    let to = [g[gi], g[gj], g[gk]].map(|v| [v.x, v.y, v.z]);
                    let Some(pose) = fit_rigid(&from, &to, None) else {
                        continue;
                    };
                    let (n, sq) = score(&pose);
                    if best
                        .as_ref()
                        .is_none_or(|b| n > b.0 || (n == b.0 && sq < b.1))
                    {
                        best = Some((n, sq, pose));
                    }
                }
            }
        }
        if best.as_ref().is_some_and(|b| b.0 == measured.len()) {
            break;
        }
    }
    best.filter(|b| b.0 >= 3).map(|b| b.2)
}

/// ICP on the centres: nearest gauge marker within the tolerance (one measured marker per gauge
/// marker), closed-form refit, until the pairs stop changing.
fn refine(
    measured: &[Vec3],
    gauge: &Gauge,
    tree: &KdTree,
    mut pose: Pose,
    params: &GaugeParams,
) -> (Pose, Vec<(usize, usize)>) {
    let tol2 = params.match_tolerance * params.match_tolerance;
    let mut pairs: Vec<(usize, usize)> = Vec::new();
    for _ in 0..20 {
        let mut owner: HashMap<usize, (usize, f64)> = HashMap::new();
        for (i, m) in measured.iter().enumerate() {
            let p = pose * nalgebra::Point3::from(*m);
            if let Some((g, d2)) = tree.nearest(&[p.x, p.y, p.z]) {
                if d2 <= tol2 && owner.get(&g).is_none_or(|o| d2 < o.1) {
                    owner.insert(g, (i, d2));
                }
            }
        }
        let mut next: Vec<(usize, usize)> = owner.into_iter().map(|(g, (i, _))| (i, g)).collect();
        next.sort_unstable();
        if next.len() < 3 {
            break;
        }
        let from: Vec<[f64; 3]> = next.iter().map(|&(i, _)| measured[i].into()).collect();
        let to: Vec<[f64; 3]> = next.iter().map(|&(_, g)| gauge.centers[g].into()).collect();
        if let Some(p) = fit_rigid(&from, &to, None) {
            pose = p;
        }
        let done = next == pairs;
        pairs = next;
        if done {
            break;
        }
    }
    (pose, pairs)
}

/// Agreement of the sensors where they overlap: for every pair of sensors, the markers both
/// matched and the RMS distance between their two cell-frame estimates.
pub fn overlap_consistency(fits: &[GaugeFit]) -> Vec<OverlapCheck> {
    let mut out = Vec::new();
    let in_cell = |f: &GaugeFit| -> HashMap<usize, Vec3> {
        f.markers
            .iter()
            .filter_map(|m| {
                m.gauge_index.map(|g| {
                    (
                        g,
                        (f.to_common * nalgebra::Point3::from(Vec3::from(m.center))).coords,
                    )
                })
            })
            .collect()
    };
    let maps: Vec<_> = fits.iter().map(in_cell).collect();
    for a in 0..maps.len() {
        for b in a + 1..maps.len() {
            let d: Vec<f64> = maps[a]
                .iter()
                .filter_map(|(g, p)| maps[b].get(g).map(|q| (p - q).norm()))
                .collect();
            if !d.is_empty() {
                out.push(OverlapCheck {
                    sensors: (a, b),
                    shared: d.len(),
                    rms: (d.iter().map(|x| x * x).sum::<f64>() / d.len() as f64).sqrt(),
                });
            }
        }
    }
    out
}

/// Two sensors' agreement on the markers they both see.
#[derive(Clone, Debug, Serialize)]
pub struct OverlapCheck {
    /// Indices of the two sensors.
    pub sensors: (usize, usize),
    /// Markers both matched.
    pub shared: usize,
    /// RMS distance between their cell-frame centres, mm.
    pub rms: f64,
}
