//! The characteristics of one inspection report: every figure a quality engineer charts over a
//! part's scans, each with the specification limits the part's tolerance gives it.

use serde::Serialize;
use serde_json::Value;

/// One measured characteristic of one scan.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Characteristic {
    /// Stable name (`mean`, `datum A p99`, ...): the key a trend follows across scans.
    pub name: String,
    /// Measured value (mm, or % for shares).
    pub value: f64,
    /// Lower specification limit, when the tolerance gives one.
    pub lower: Option<f64>,
    /// Upper specification limit, when the tolerance gives one.
    pub upper: Option<f64>,
    /// `mm` or `%`.
    pub unit: &'static str,
}

/// The characteristics `report` (a `report.json`) carries: the deviation statistics (mean,
/// RMS, 5th and 95th percentiles, the robust minimum and maximum — 0.01 % and 99.99 %
/// quantiles) against ± tolerance, the share of points in
/// tolerance, the coverage against its minimum, each datum's mean and 99th percentile, and the
/// out-of-tolerance regions (count, points, largest |peak|), and the part's ISO 1101
/// characteristics (`flatness top`, `position bore A`, ...) with their limits. Figures the
/// report lacks or gives as not finite (no point measured) are left out.
pub fn from_report(report: &Value) -> Vec<Characteristic> {
    let tol = report["tolerance_mm"].as_f64().filter(|t| t.is_finite());
    let mut out = Vec::new();
    let mut push = |name: String, value: Option<f64>, lower, upper, unit| {
        if let Some(value) = value.filter(|v| v.is_finite()) {
            out.push(Characteristic {
                name,
                value,
                lower,
                upper,
                unit,
            });
        }
    };
    let s = &report["statistics"];
    let band = (tol.map(|t| -t), tol);
    // The extremes are charted without the noise's last points: a single stray point of a
    // million would move `min` or `max` from scan to scan and fire rules on nothing.
    for (name, key) in [
        ("mean", "mean"),
        ("p05", "p05"),
        ("p95", "p95"),
        ("robust min", "robust_min"),
        ("robust max", "robust_max"),
    ] {
        push(name.into(), s[key].as_f64(), band.0, band.1, "mm");
    }
    push("rms".into(), s["rms"].as_f64(), None, tol, "mm");
    push(
        "within tolerance".into(),
        s["within_tolerance"].as_f64().map(|f| 100.0 * f),
        None,
        None,
        "%",
    );
    let c = &report["coverage"];
    push(
        "coverage".into(),
        c["fraction"].as_f64().map(|f| 100.0 * f),
        c["minimum"].as_f64().map(|f| 100.0 * f),
        None,
        "%",
    );
    for d in report["datums"].as_array().into_iter().flatten() {
        let Some(name) = d["name"].as_str() else {
            continue;
        };
        push(
            format!("datum {name} mean"),
            d["mean"].as_f64(),
            band.0,
            band.1,
            "mm",
        );
        push(
            format!("datum {name} p99"),
            d["p99_abs"].as_f64(),
            None,
            tol,
            "mm",
        );
    }
    let regions = report["regions_out_of_tolerance"].as_array();
    if let Some(regions) = regions {
        push(
            "regions out of tolerance".into(),
            Some(regions.len() as f64),
            None,
            Some(0.0),
            "",
        );
        push(
            "points out of tolerance".into(),
            Some(
                regions
                    .iter()
                    .filter_map(|r| r["points"].as_f64())
                    .sum::<f64>(),
            ),
            None,
            None,
            "",
        );
        let peak = regions
            .iter()
            .filter_map(|r| r["peak_deviation_mm"].as_f64())
            .map(f64::abs)
            .fold(0.0, f64::max);
        push("largest region peak".into(), Some(peak), None, tol, "mm");
    }
    // The part's ISO 1101 characteristics, each with its own limits (form, profile and
    // position zones from 0; a diameter between its limit deviations); one not measured on a
    // scan leaves a gap in its trend.
    for c in report["characteristics"].as_array().into_iter().flatten() {
        let (Some(name), Some(kind)) = (c["name"].as_str(), c["characteristic"].as_str()) else {
            continue;
        };
        push(
            format!("{kind} {name}"),
            c["measured"].as_f64(),
            c["lower_limit"].as_f64(),
            c["upper_limit"].as_f64(),
            "mm",
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn iso_1101_characteristics_are_charted_with_their_limits() {
        let report = serde_json::json!({
            "tolerance_mm": 0.5,
            "characteristics": [
                {"name": "bore A", "characteristic": "diameter", "measured": 12.04,
                 "lower_limit": 11.95, "upper_limit": 12.05},
                {"name": "bore A", "characteristic": "position", "measured": 0.31,
                 "lower_limit": 0.0, "upper_limit": 0.2},
                {"name": "top", "characteristic": "flatness", "measured": null,
                 "lower_limit": 0.0, "upper_limit": 0.05, "not_measured": "too little"}
            ]
        });
        let c = from_report(&report);
        let get = |n: &str| c.iter().find(|x| x.name == n);
        let d = get("diameter bore A").expect("diameter");
        assert_eq!(
            (d.value, d.lower, d.upper),
            (12.04, Some(11.95), Some(12.05))
        );
        assert_eq!(get("position bore A").expect("position").upper, Some(0.2));
        assert!(
            get("flatness top").is_none(),
            "a figure not measured is a gap"
        );
    }

    #[test]
    fn a_report_gives_its_figures_with_their_limits() {
        let report = serde_json::json!({
            "tolerance_mm": 0.5,
            "coverage": {"fraction": 0.8, "minimum": 0.6},
            "statistics": {"mean": 0.01, "rms": 0.1, "p05": -0.2, "p95": 0.2, "min": -0.6,
                           "max": 0.3, "robust_min": -0.4, "robust_max": 0.25,
                           "within_tolerance": 0.99},
            "datums": [{"name": "A", "mean": 0.02, "p99_abs": 0.3}],
            "regions_out_of_tolerance": [{"points": 40, "peak_deviation_mm": -0.6}]
        });
        let c = from_report(&report);
        let get = |n: &str| c.iter().find(|c| c.name == n).expect(n);
        assert_eq!(get("mean").value, 0.01);
        assert_eq!(
            (get("mean").lower, get("mean").upper),
            (Some(-0.5), Some(0.5))
        );
        assert_eq!((get("rms").lower, get("rms").upper), (None, Some(0.5)));
        assert_eq!(get("robust min").value, -0.4);
        assert_eq!(get("robust max").upper, Some(0.5));
        assert!(
            !c.iter().any(|c| c.name == "min" || c.name == "max"),
            "single points are not charted"
        );
        assert!((get("coverage").value - 80.0).abs() < 1e-12);
        assert_eq!(get("coverage").lower, Some(60.0));
        assert_eq!(get("datum A p99").value, 0.3);
        assert_eq!(get("largest region peak").value, 0.6);
        assert_eq!(get("regions out of tolerance").value, 1.0);
    }

    #[test]
    fn figures_of_an_unmeasured_scan_are_left_out() {
        let report = serde_json::json!({
            "tolerance_mm": 0.5,
            "statistics": {"mean": null, "rms": null},
        });
        assert!(from_report(&report).is_empty());
    }
}
