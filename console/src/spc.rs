//! Statistical process control of one characteristic over a part's scans: the individuals
//! chart (centre line and 3-sigma limits from a baseline, sigma from the mean moving range),
//! the common run rules (Western Electric / Nelson) and the process capability Cp/Cpk against
//! the specification limits.

use serde::Serialize;

/// d2 for moving ranges of two: sigma = mean moving range / 1.128.
const D2: f64 = 1.128;
/// Fewest baseline values from which limits are set.
pub const MIN_BASELINE: usize = 8;

/// A run rule, as the common SPC literature numbers them (Nelson).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Rule {
    /// One point beyond the 3-sigma limits.
    BeyondLimits,
    /// Nine points in a row on one side of the centre line.
    RunOneSide,
    /// Six points in a row steadily increasing or decreasing.
    Trend,
    /// Two of three points in a row beyond 2 sigma on the same side.
    TwoOfThree,
}

impl Rule {
    /// The rule in words.
    pub fn describe(self) -> &'static str {
        match self {
            Rule::BeyondLimits => "a point beyond the control limits",
            Rule::RunOneSide => "nine points in a row on one side of the centre line",
            Rule::Trend => "six points in a row steadily increasing or decreasing",
            Rule::TwoOfThree => "two of three points beyond 2 sigma on one side",
        }
    }
}

/// A rule fired at one point.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Signal {
    /// Index of the point that completes the pattern.
    pub index: usize,
    /// The rule.
    pub rule: Rule,
}

/// An individuals chart.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Chart {
    /// Centre line (baseline mean).
    pub centre: f64,
    /// Sigma estimated from the baseline's mean moving range.
    pub sigma: f64,
    /// Upper control limit.
    pub ucl: f64,
    /// Lower control limit.
    pub lcl: f64,
    /// Values the limits were computed from (the first ones).
    pub baseline: usize,
    /// Every rule that fired, in order of the points.
    pub signals: Vec<Signal>,
}

/// The chart of `values` (oldest first) with limits from the first `baseline` of them; `None`
/// while fewer than [`MIN_BASELINE`] values exist.
pub fn chart(values: &[f64], baseline: usize) -> Option<Chart> {
    let b = baseline.max(MIN_BASELINE).min(values.len());
    if b < MIN_BASELINE {
        return None;
    }
    let base = &values[..b];
    let centre = base.iter().sum::<f64>() / b as f64;
    let mr = base.windows(2).map(|w| (w[1] - w[0]).abs()).sum::<f64>() / (b - 1) as f64;
    // A constant baseline (a figure that never moved) still gets limits: any change signals.
    let sigma = (mr / D2).max(1e-9 * centre.abs().max(1e-3));
    Some(Chart {
        centre,
        sigma,
        ucl: centre + 3.0 * sigma,
        lcl: centre - 3.0 * sigma,
        baseline: b,
        signals: signals(values, centre, sigma),
    })
}

fn signals(values: &[f64], centre: f64, sigma: f64) -> Vec<Signal> {
    let mut out = Vec::new();
    let side = |v: f64| (v - centre).signum() as i32;
    for i in 0..values.len() {
        let v = values[i];
        if (v - centre).abs() > 3.0 * sigma {
            out.push(Signal {
                index: i,
                rule: Rule::BeyondLimits,
            });
        }
        if i >= 8 {
            let s = side(v);
            if s != 0 && values[i - 8..=i].iter().all(|x| side(*x) == s) {
                out.push(Signal {
                    index: i,
                    rule: Rule::RunOneSide,
                });
            }
        }
        if i >= 5 {
            let w = &values[i - 5..=i];
            let up = w.windows(2).all(|p| p[1] > p[0]);
            let down = w.windows(2).all(|p| p[1] < p[0]);
            if up || down {
                out.push(Signal {
                    index: i,
                    rule: Rule::Trend,
                });
            }
        }
        if i >= 2 {
            for s in [1.0, -1.0] {
                let beyond = values[i - 2..=i]
                    .iter()
                    .filter(|x| s * (**x - centre) > 2.0 * sigma)
                    .count();
                if beyond >= 2 && s * (v - centre) > 2.0 * sigma {
                    out.push(Signal {
                        index: i,
                        rule: Rule::TwoOfThree,
                    });
                }
            }
        }
    }
    out
}

/// Process capability against the specification limits.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Capability {
    /// Cp = (USL − LSL) / 6σ (absent with a one-sided specification).
    pub cp: Option<f64>,
    /// Cpk = min(USL − mean, mean − LSL) / 3σ over the limits given.
    pub cpk: f64,
    /// Mean of the values.
    pub mean: f64,
    /// Standard deviation of the values (sample).
    pub sigma: f64,
}

/// Cp/Cpk of `values` against `lower`/`upper`; `None` without a limit, with fewer than two
/// values, or with no spread.
pub fn capability(values: &[f64], lower: Option<f64>, upper: Option<f64>) -> Option<Capability> {
    if values.len() < 2 || (lower.is_none() && upper.is_none()) {
        return None;
    }
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let sigma = (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    if sigma <= 0.0 || !sigma.is_finite() {
        return None;
    }
    let cp = lower.zip(upper).map(|(l, u)| (u - l) / (6.0 * sigma));
    let cpk = [
        upper.map(|u| (u - mean) / (3.0 * sigma)),
        lower.map(|l| (mean - l) / (3.0 * sigma)),
    ]
    .into_iter()
    .flatten()
    .fold(f64::INFINITY, f64::min);
    Some(Capability {
        cp,
        cpk,
        mean,
        sigma,
    })
}

/// `bins` equal bins over the range of `values`: (lower edge, upper edge, count).
pub fn histogram(values: &[f64], bins: usize) -> Vec<(f64, f64, usize)> {
    let (lo, hi) = values
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(*v), b.max(*v))
        });
    if values.is_empty() || bins == 0 {
        return Vec::new();
    }
    let width = ((hi - lo) / bins as f64).max(f64::EPSILON * hi.abs().max(1.0));
    let mut counts = vec![0usize; bins];
    for v in values {
        let i = (((v - lo) / width) as usize).min(bins - 1);
        counts[i] += 1;
    }
    counts
        .into_iter()
        .enumerate()
        .map(|(i, c)| (lo + i as f64 * width, lo + (i + 1) as f64 * width, c))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A deterministic noise in −1..1 (a fixed-seed linear congruential generator).
    fn noise(seed: u64, n: usize) -> Vec<f64> {
        let mut s = seed.wrapping_mul(6364136223846793005).wrapping_add(1);
        (0..n)
            .map(|_| {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                ((s >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
            })
            .collect()
    }

    #[test]
    fn a_stable_process_rarely_signals_and_its_limits_match_its_spread() {
        // Uniform noise of half-width 0.01: sigma 0.01/√3 ≈ 0.0058.
        for seed in 0..20 {
            let v: Vec<f64> = noise(seed, 60).iter().map(|x| 0.05 + 0.01 * x).collect();
            let c = chart(&v, 20).expect("chart");
            assert!((c.centre - 0.05).abs() < 0.006, "{c:?}");
            assert!(
                c.sigma > 0.003 && c.sigma < 0.010,
                "seed {seed}: {}",
                c.sigma
            );
            assert!(
                c.signals.iter().all(|s| s.rule != Rule::BeyondLimits),
                "seed {seed}: {:?}",
                c.signals
            );
        }
    }

    #[test]
    fn a_drift_signals_before_it_leaves_the_tolerance() {
        // A wear adding 0.004 mm per scan after 20 stable ones, noise ±0.005, tolerance 0.3.
        for seed in 0..20 {
            let v: Vec<f64> = noise(seed, 120)
                .iter()
                .enumerate()
                .map(|(i, x)| -0.1 - 0.004 * (i.saturating_sub(20)) as f64 + 0.005 * x)
                .collect();
            let c = chart(&v, 20).expect("chart");
            let first = c
                .signals
                .iter()
                .find(|s| s.index >= 20)
                .expect("the drift signals");
            let fails = v.iter().position(|x| *x < -0.3).expect("the drift fails");
            assert!(
                first.index < fails,
                "seed {seed}: {first:?} at or after {fails}"
            );
        }
    }

    #[test]
    fn each_rule_fires_on_its_pattern() {
        let base: Vec<f64> = noise(7, 20).iter().map(|x| 0.01 * x).collect();
        let c = chart(&base, 20).expect("chart");
        let with = |tail: &[f64]| {
            let mut v = base.clone();
            v.extend_from_slice(tail);
            chart(&v, 20).expect("chart").signals
        };
        let s = 5.0 * c.sigma;
        assert!(with(&[c.centre + s])
            .iter()
            .any(|x| x.index == 20 && x.rule == Rule::BeyondLimits));
        let side = [c.centre + 0.5 * c.sigma; 9];
        assert!(with(&side)
            .iter()
            .any(|x| x.index == 28 && x.rule == Rule::RunOneSide));
        let trend: Vec<f64> = (0..6)
            .map(|i| c.centre - c.sigma + 0.3 * c.sigma * i as f64)
            .collect();
        assert!(with(&trend)
            .iter()
            .any(|x| x.index == 25 && x.rule == Rule::Trend));
        let two = [c.centre + 2.5 * c.sigma, c.centre, c.centre + 2.5 * c.sigma];
        assert!(with(&two)
            .iter()
            .any(|x| x.index == 22 && x.rule == Rule::TwoOfThree));
        assert!(chart(&base[..MIN_BASELINE - 1], 20).is_none());
    }

    #[test]
    fn capability_matches_its_definition() {
        let v: Vec<f64> = noise(3, 200).iter().map(|x| 0.1 + 0.05 * x).collect();
        let c = capability(&v, Some(-0.5), Some(0.5)).expect("capability");
        let cp = 1.0 / (6.0 * c.sigma);
        assert!((c.cp.expect("two-sided") - cp).abs() < 1e-12);
        assert!((c.cpk - (0.5 - c.mean) / (3.0 * c.sigma)).abs() < 1e-12);
        let one = capability(&v, None, Some(0.5)).expect("one-sided");
        assert!(one.cp.is_none() && (one.cpk - c.cpk).abs() < 1e-12);
        assert!(capability(&v, None, None).is_none());
        let h = histogram(&v, 10);
        assert_eq!(h.iter().map(|b| b.2).sum::<usize>(), 200);
    }
}
