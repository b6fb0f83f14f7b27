//! The inspection report (`report.json`): verdict with reasons, registration, transform,
//! deviation statistics, datum residuals and out-of-tolerance regions.

use serde::Serialize;

use super::{out_of_tolerance_regions, Coverage, DatumMeasurement, Feature, InspectParams, Region};
use crate::register::Pose;

/// Deviation statistics over all points, mm.
#[derive(Clone, Debug, Serialize)]
pub struct Statistics {
    /// Points.
    pub points: usize,
    /// Mean.
    pub mean: f64,
    /// Root mean square.
    pub rms: f64,
    /// Standard deviation.
    pub std: f64,
    /// Minimum.
    pub min: f64,
    /// Maximum.
    pub max: f64,
    /// 0.01 % quantile: the low extreme without the noise's last points (the 120th lowest of
    /// 1.2 M), which a trend can chart where one stray point would move `min`.
    pub robust_min: f64,
    /// 99.99 % quantile: the high extreme as [`Statistics::robust_min`] is the low.
    pub robust_max: f64,
    /// 5th percentile.
    pub p05: f64,
    /// Median.
    pub p50: f64,
    /// 95th percentile.
    pub p95: f64,
    /// Fraction of points within ± tolerance.
    pub within_tolerance: f64,
    /// Points beyond the CAD surface's open boundary (no nominal there), left out of the
    /// statistics and the verdict.
    pub beyond_cad: usize,
    /// Input points with a NaN or infinite coordinate, left out.
    pub non_finite: usize,
    /// Points closest to a CAD face outside the inspected surface, left out of the statistics
    /// and the verdict.
    pub outside_inspected: usize,
}

/// How well a datum region sits on its nominal surface.
#[derive(Clone, Debug, Serialize)]
pub struct DatumResidual {
    /// Datum name.
    pub name: String,
    /// Points in the region.
    pub points: usize,
    /// Mean deviation, mm.
    pub mean: f64,
    /// RMS deviation, mm.
    pub rms: f64,
    /// 99th percentile of |deviation|, mm.
    pub p99_abs: f64,
    /// Whether p99_abs ≤ tolerance (and the datum was measured at all).
    pub in_tolerance: bool,
    /// In a datum reference frame: the feature as measured (position, offsets along the
    /// directions it pins, size).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub frame: Option<super::DatumMeasurement>,
}

/// Registration summary.
#[derive(Clone, Debug, Serialize)]
pub struct Registration {
    /// "trusted-region" (with " and rim" where the CAD's rim held the fit), "datums",
    /// "datum-frame", or "known pose" (nothing fitted).
    pub mode: String,
    /// Fit iterations in total.
    pub iterations: usize,
    /// Fraction of the fit points trusted at the end.
    pub trusted_fraction: f64,
    /// How the starting pose was chosen (absent when an initial pose was given).
    pub alignment: Option<super::Alignment>,
    /// How far leaving out any one part of the fitted surface moves the fit (trusted-region
    /// fits).
    pub stability: Option<super::Stability>,
    /// How the CAD's rim held the fit where the scan reached it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rim: Option<super::RimUse>,
}

/// The verdict that means the data cannot decide: too little of the part (or of a datum)
/// was measured.
pub const NOT_MEASURED: &str = "not_measured";

/// How the registration went, for the report.
pub(super) struct Fit<'a> {
    pub mode: &'a str,
    pub iterations: usize,
    pub trusted_fraction: f64,
    pub conditioning: super::Conditioning,
    pub alignment: Option<super::Alignment>,
    pub measurements: Vec<super::DatumMeasurement>,
    pub stability: Option<super::Stability>,
    pub rim: Option<super::RimUse>,
}

/// The report.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    /// "pass", "fail", or "not_measured" (too little of the part or of a datum measured for
    /// a verdict).
    pub verdict: String,
    /// Why it failed or was not measured (empty on pass).
    pub reasons: Vec<String>,
    /// How much of the CAD surface was measured.
    pub coverage: Coverage,
    /// Tolerance, mm.
    pub tolerance_mm: f64,
    /// Registration summary.
    pub registration: Registration,
    /// How well the registration pins each rigid degree of freedom.
    pub conditioning: super::Conditioning,
    /// What the verdict does not show but a reader should know (weakly pinned directions).
    pub warnings: Vec<String>,
    /// cad_from_cloud, row-major 4×4.
    pub transform: [[f64; 4]; 4],
    /// Deviation statistics.
    pub statistics: Statistics,
    /// Datum residuals.
    pub datums: Vec<DatumResidual>,
    /// Connected regions out of tolerance (at least 20 points), largest |peak| first.
    pub regions_out_of_tolerance: Vec<Region>,
    /// The part's toleranced characteristics (ISO 1101), in the file's order; left out when the
    /// part has none.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub characteristics: Vec<super::CharacteristicResult>,
}

/// Share of the points left out at either end for [`Statistics::robust_min`] and
/// [`Statistics::robust_max`].
const ROBUST_TAIL: f64 = 1e-4;

/// The `q` quantile of `v` (reordering it): the value that `v` sorted holds at index
/// `round((len − 1) q)`, found in linear time; NaN when `v` is empty.
fn percentile_of(v: &mut [f64], q: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let k = ((v.len() - 1) as f64 * q).round() as usize;
    *v.select_nth_unstable_by(k, f64::total_cmp).1
}

pub(super) fn build(
    points: &[[f64; 3]],
    dev: &[f64],
    pose: &Pose,
    params: &InspectParams,
    fit: Fit,
    coverage: Coverage,
    non_finite: usize,
) -> Report {
    let tol = params.tolerance;
    let mut finite: Vec<f64> = dev.iter().copied().filter(|d| d.is_finite()).collect();
    let beyond_cad = dev.len() - finite.len();
    let n = finite.len().max(1) as f64;
    let mean = finite.iter().sum::<f64>() / n;
    let rms = (finite.iter().map(|d| d * d).sum::<f64>() / n).sqrt();
    let statistics = Statistics {
        points: finite.len(),
        mean,
        rms,
        std: (rms * rms - mean * mean).max(0.0).sqrt(),
        min: percentile_of(&mut finite, 0.0),
        max: percentile_of(&mut finite, 1.0),
        robust_min: percentile_of(&mut finite, ROBUST_TAIL),
        robust_max: percentile_of(&mut finite, 1.0 - ROBUST_TAIL),
        p05: percentile_of(&mut finite, 0.05),
        p50: percentile_of(&mut finite, 0.5),
        p95: percentile_of(&mut finite, 0.95),
        within_tolerance: finite.iter().filter(|d| d.abs() <= tol).count() as f64 / n,
        beyond_cad,
        non_finite,
        outside_inspected: 0,
    };
    let mut reasons = Vec::new();
    let mut unmeasured = Vec::new();
    if statistics.points == 0 {
        unmeasured.push("no measured point lies on the CAD surface".to_string());
    }
    if coverage.fraction < coverage.minimum {
        unmeasured.push(format!(
            "only {:.1} % of {} was measured (minimum {:.1} %){}",
            100.0 * coverage.fraction,
            coverage.surface,
            100.0 * coverage.minimum,
            if matches!(params.surface, super::InspectedSurface::Whole) {
                ": if the cell cannot see the whole part, name the inspected faces or the sensors' viewpoints"
            } else {
                ""
            }
        ));
    }
    let (unpinned, mut warnings) = fit
        .conditioning
        .findings(params.tolerance, params.init.is_some());
    if let Some(s) = fit.stability.as_ref().filter(|s| s.shift_mm > tol) {
        warnings.push(format!(
            "the registration leans on the surface around ({:.1}, {:.1}, {:.1}) mm: leaving it out moves the map up to {:.2} mm, so deviations may be placed that far from where they are",
            s.worst_tile[0], s.worst_tile[1], s.worst_tile[2], s.shift_mm
        ));
    }
    if let Some(a) = fit.alignment.as_ref().filter(|a| a.ambiguous()) {
        unmeasured.push(format!(
            "ambiguous coarse alignment: a pose {:.1}° and {:.1} mm away puts {:.1} % of the points on the CAD against {:.1} % for the one used; give an initial pose or datums",
            a.runner_up_rotation_deg.unwrap_or(0.0),
            a.runner_up_shift_mm.unwrap_or(0.0),
            100.0 * a.runner_up_score.unwrap_or(0.0),
            100.0 * a.best_score
        ));
    }
    if let Some(a) = fit.alignment.as_ref().filter(|a| a.symmetric) {
        warnings.push(format!(
            "the CAD looks the same with the part turned {:.0}°, and the scan fits both ways: every deviation is as reported either way, but where it lies on the part is one of two places (the map shows one); give the part's pose or a datum that tells the two apart",
            a.runner_up_rotation_deg.unwrap_or(0.0)
        ));
    }
    if !unpinned.is_empty() {
        unmeasured.extend(fit.rim.as_ref().and_then(|r| r.ambiguous.clone()));
    }
    if let Some(spread) = fit.rim.as_ref().and_then(|r| r.spread_mm) {
        warnings.push(format!(
            "the part's edges pin its position on the CAD to within {spread:.1} mm: another fit of them places the points that far apart, so a deviation may be shown up to {spread:.1} mm from where it is"
        ));
    }
    unmeasured.extend(unpinned);
    let datums: Vec<DatumResidual> = params
        .datums
        .iter()
        .enumerate()
        .map(|(i, d)| {
            let r = datum_residual(points, dev, d, fit.measurements.get(i), params);
            let what = if d.feature == Feature::Surface {
                "datum".to_string()
            } else {
                format!("datum ({:?})", d.feature).to_lowercase()
            };
            match (&r.frame, r.in_tolerance) {
                (Some(DatumMeasurement { error: Some(why), .. }), _) => {
                    unmeasured.push(format!("{what} {} was not measured: {why}", d.name))
                }
                (Some(m), false) if d.feature != Feature::Surface => reasons.push(format!(
                    "{what} {} is {:.3} mm from its nominal position (offsets {:?} mm) > {tol} mm",
                    d.name,
                    m.offset_mm.iter().map(|o| o * o).sum::<f64>().sqrt(),
                    m.offset_mm.iter().map(|o| (o * 1000.0).round() / 1000.0).collect::<Vec<_>>()
                )),
                _ if r.points < params.min_datum_points.max(1) && d.feature == Feature::Surface => {
                    unmeasured.push(format!(
                        "datum {} was not measured ({} points within {} mm of it, {} needed)",
                        d.name,
                        r.points,
                        d.radius,
                        params.min_datum_points.max(1)
                    ))
                }
                (_, false) => reasons.push(format!(
                    "datum {} is out of tolerance: 99 % of its deviations within {:.3} mm > {tol} mm",
                    d.name, r.p99_abs
                )),
                _ => {}
            }
            r
        })
        .collect();
    let spacing = cell_size(points);
    let regions = out_of_tolerance_regions(points, dev, tol, spacing, 20);
    for (i, r) in regions.iter().enumerate() {
        reasons.push(format!(
            "region {}: {} points out of tolerance around ({:.1}, {:.1}, {:.1}) mm, peak {:+.3} mm",
            i + 1,
            r.points,
            r.centroid[0],
            r.centroid[1],
            r.centroid[2],
            r.peak_deviation_mm
        ));
    }
    let m = pose.to_homogeneous();
    let verdict = if !unmeasured.is_empty() {
        NOT_MEASURED
    } else if reasons.is_empty() {
        "pass"
    } else {
        "fail"
    };
    unmeasured.extend(reasons);
    Report {
        verdict: verdict.into(),
        reasons: unmeasured,
        coverage,
        tolerance_mm: tol,
        registration: Registration {
            mode: fit.mode.into(),
            iterations: fit.iterations,
            trusted_fraction: fit.trusted_fraction,
            alignment: fit.alignment,
            stability: fit.stability,
            rim: fit.rim,
        },
        conditioning: fit.conditioning,
        warnings,
        transform: std::array::from_fn(|i| std::array::from_fn(|j| m[(i, j)])),
        statistics,
        datums,
        regions_out_of_tolerance: regions,
        characteristics: Vec::new(),
    }
}

/// How datum `d` sits: deviations of the points in its neighbourhood and, in a datum frame,
/// its measurement. A surface datum is in tolerance when 99 % of its deviations are; a
/// feature when its offset from the nominal is within the tolerance.
fn datum_residual(
    points: &[[f64; 3]],
    dev: &[f64],
    d: &super::Datum,
    frame: Option<&DatumMeasurement>,
    params: &InspectParams,
) -> DatumResidual {
    let mut v: Vec<f64> = points
        .iter()
        .zip(dev)
        .filter(|(p, e)| e.is_finite() && d.contains(p))
        .map(|(_, e)| *e)
        .collect();
    let k = v.len().max(1) as f64;
    let mean = v.iter().sum::<f64>() / k;
    let rms = (v.iter().map(|e| e * e).sum::<f64>() / k).sqrt();
    v.iter_mut().for_each(|e| *e = e.abs());
    let p99 = percentile_of(&mut v, 0.99);
    let in_tolerance = match frame {
        Some(m) if m.error.is_some() => false,
        Some(m) if d.feature != Feature::Surface => {
            m.offset_mm.iter().map(|o| o * o).sum::<f64>().sqrt() <= params.tolerance
        }
        _ => v.len() >= params.min_datum_points.max(1) && p99 <= params.tolerance,
    };
    DatumResidual {
        name: d.name.clone(),
        points: v.len(),
        mean,
        rms,
        p99_abs: p99,
        in_tolerance,
        frame: frame.cloned(),
    }
}

/// Clustering cell: three times the typical point spacing (estimated from the bounding box
/// area and the point count), at least 1 mm.
fn cell_size(points: &[[f64; 3]]) -> f64 {
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for p in points {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let mut ext: Vec<f64> = (0..3).map(|k| (hi[k] - lo[k]).max(0.0)).collect();
    ext.sort_by(|a, b| b.total_cmp(a));
    let area = ext[0] * ext[1];
    (3.0 * (area / points.len().max(1) as f64).sqrt()).max(1.0)
}

/// Put the characteristics into the report and its verdict: one not measured makes the part
/// not measured (its figure is missing), one out of tolerance fails it.
pub(super) fn add_characteristics(report: &mut Report, results: Vec<super::CharacteristicResult>) {
    let mut unmeasured = 0;
    for r in &results {
        let what = format!("{} {} of {}", r.symbol, r.characteristic, r.name);
        match (r.measured, &r.not_measured) {
            (_, Some(why)) => {
                report
                    .reasons
                    .insert(unmeasured, format!("{what} was not measured: {why}"));
                unmeasured += 1;
                report.verdict = NOT_MEASURED.into();
            }
            (Some(v), None) if r.in_tolerance == Some(false) => {
                report.reasons.push(format!(
                    "{what} is {v:.3} mm, outside {:.3} … {:.3} mm",
                    r.lower_limit, r.upper_limit
                ));
                if report.verdict == "pass" {
                    report.verdict = "fail".into();
                }
            }
            _ => {}
        }
    }
    let fitted = report.registration.mode != "known pose" && report.datums.is_empty();
    if fitted && results.iter().any(|r| r.characteristic == "position") {
        report.warnings.push(
            "positions are measured in the best fit of the whole surface, not in a datum reference frame: a moved feature draws the fit a little towards itself; name datums or give the cell's pose".into(),
        );
    }
    report.characteristics = results;
}
