//! The crossing solved through a model of its signal. Each pixel's normalised difference
//! (pattern − inverse) / (white − black) is the mean over its footprint of the projected bit,
//! a step blurred by the projector's defocus (a Gaussian of σ projector pixels) with the bit's
//! neighbouring transitions `2^(k+1)` code cells to either side. Along a line whose pixels
//! cover `m` projector pixels each, the two samples around a transition at phase φ (from the
//! first pixel's centre) are that mean at −φ·m and (1 − φ)·m, and the linear crossing of eq.
//! 4.17 reads t = s₀ / (s₀ − s₁), a known function of φ, m and σ. Inverting it gives the
//! transition: the "peak locking" of the linear crossing, which on a small sphere (where m
//! runs from 0.4 to 1.5 across 25 pixels) leaves a ring-shaped moiré of ±0.05 projector pixels
//! that no fit over the whole capture can follow, is taken out edge by edge.
//!
//! σ is not a setting: each capture measures it from the same sample of lines as its phase
//! bias, as the σ whose model slope s₁ − s₀ (at each edge's phase and magnification) fits the
//! measured slopes best. A camera's own blur widens the step like a larger σ. Where the
//! model cannot be measured (too few edges, a best σ at the searched range's end), the
//! harmonics of [`super::phase_bias`] stand in.

use super::{widen_down, widen_up, Edge};
use crate::pattern::flipped_bit;
use rayon::prelude::*;

/// Kinds of edge: on the finest stripes, on the next, and on coarser ones (as in
/// [`super::phase_bias`]).
const CLASSES: usize = 3;

/// Magnifications (projector pixels per camera pixel) the table covers; beyond them an edge
/// keeps its linear crossing (far apart edges are sampled finely, the bias vanishes; denser
/// ones than five a pixel do not resolve).
const M_RANGE: (f64, f64) = (0.2, 5.0);

/// Table nodes over log m.
const M_NODES: usize = 33;

/// Table nodes over the crossing t in [0, ½] (the other half by symmetry).
const T_NODES: usize = 33;

/// Blurs searched, projector pixels.
const SIGMA_RANGE: (f64, f64) = (0.1, 4.0);

/// Sampled edges used to measure σ (evenly picked).
const SIGMA_EDGES: usize = 1500;

/// Edges beside an albedo edge (see `Edge::weight`) do not measure the blur.
const MIN_WEIGHT: f32 = 0.5;

/// Edges to either side over which an edge's magnification is read: the linear crossings
/// are off by up to a tenth of a pixel, which over one neighbour's 1.5 px is 7 %.
const REACH: usize = 3;

/// Rounds of the blur's fit: the first reads each slope at its linear crossing, the next at
/// the phase the model before gave it.
const ROUNDS: usize = 3;

/// Edges needed to measure σ.
const MIN_EDGES: usize = 200;

/// The error function, |error| < 1.2e-7 (Numerical Recipes' erfc by Chebyshev fit).
fn erf(x: f64) -> f64 {
    let z = x.abs();
    let t = 1.0 / (1.0 + 0.5 * z);
    let erfc = t
        * (-z * z - 1.265_512_23
            + t * (1.000_023_68
                + t * (0.374_091_96
                    + t * (0.096_784_18
                        + t * (-0.186_288_06
                            + t * (0.278_868_07
                                + t * (-1.135_203_98
                                    + t * (1.488_515_87
                                        + t * (-0.822_152_23 + t * 0.170_872_77)))))))))
            .exp();
    if x >= 0.0 {
        1.0 - erfc
    } else {
        erfc - 1.0
    }
}

/// ∫ erf(a v) dv.
#[inline]
fn erf_integral(a: f64, v: f64) -> f64 {
    v * erf(a * v) + (-(a * v) * (a * v)).exp() / (a * std::f64::consts::PI.sqrt())
}

/// The signal of one bit around one of its transitions, in projector pixels from it: the
/// blurred step and its two neighbouring transitions `d` away, averaged over a footprint `m`
/// wide centred at `u`.
#[derive(Clone, Copy, Debug)]
struct Signal {
    /// 1 / (σ √2).
    a: f64,
    /// Distance to the neighbouring transitions, projector pixels.
    d: f64,
}

impl Signal {
    fn new(sigma: f64, d: f64) -> Signal {
        Signal {
            a: 1.0 / (sigma * std::f64::consts::SQRT_2),
            d,
        }
    }

    /// The footprint's mean at `u`.
    fn sample(&self, u: f64, m: f64) -> f64 {
        // Beyond 6σ of a transition (4.24 / a) the blurred step is ±1 to 2e-9: a footprint
        // wholly there needs no integral (the neighbouring transitions mostly are).
        let far = 4.25 / self.a;
        let mean = |c: f64| {
            let (lo, hi) = (u - c - 0.5 * m, u - c + 0.5 * m);
            if hi < -far {
                -1.0
            } else if lo > far {
                1.0
            } else {
                (erf_integral(self.a, hi) - erf_integral(self.a, lo)) / m
            }
        };
        mean(0.0) - mean(self.d) - mean(-self.d)
    }

    /// The linear crossing t of the samples around a transition at phase `phi`.
    fn crossing(&self, phi: f64, m: f64) -> f64 {
        let (s0, s1) = (self.sample(-phi * m, m), self.sample((1.0 - phi) * m, m));
        s0 / (s0 - s1)
    }

    /// s₁ − s₀ at phase `phi`.
    fn slope(&self, phi: f64, m: f64) -> f64 {
        self.sample((1.0 - phi) * m, m) - self.sample(-phi * m, m)
    }
}

/// The transition's distance to its bit's neighbouring transitions, projector pixels.
fn neighbours(class: usize, step: f64) -> f64 {
    f64::from(1u32 << (class + 1)) * step
}

/// A capture's crossing model along one code axis: the blur and, per kind of edge, the phase
/// as a function of the linear crossing and the magnification.
#[derive(Clone, Debug)]
pub(super) struct CrossingModel {
    sigma: f64,
    /// Per class, φ − t at (m node, t node), t node over [0, ½].
    tables: Vec<Vec<f32>>,
}

impl CrossingModel {
    /// The model for blur `sigma` (projector pixels) and code cells `step` projector pixels
    /// wide.
    fn new(sigma: f64, step: f64) -> CrossingModel {
        let signals = signals(sigma, step);
        let tables = signals
            .iter()
            .map(|signal| {
                (0..M_NODES)
                    .into_par_iter()
                    .flat_map_iter(|j| {
                        let m = m_at(j);
                        (0..T_NODES).map(move |i| {
                            let t = 0.5 * i as f64 / (T_NODES - 1) as f64;
                            (phase_of(signal, m, t) - t) as f32
                        })
                    })
                    .collect()
            })
            .collect();
        CrossingModel { sigma, tables }
    }

    /// The blur, projector pixels.
    pub(super) fn sigma(&self) -> f64 {
        self.sigma
    }

    /// Measure the model from a sample of lines' edges (linear crossings, code cells `step`
    /// projector pixels wide); `None` where too few edges tell the blur.
    pub(super) fn measure(lines: &[Vec<Edge>], step: f64) -> Option<CrossingModel> {
        let mut samples = Vec::new();
        for edges in lines {
            for i in 0..edges.len() {
                let e = &edges[i];
                if e.weight < MIN_WEIGHT || !e.slope.is_finite() || e.slope <= 0.0 {
                    continue;
                }
                let Some(m) = magnification(edges, i, step, |j| edges[j].x) else {
                    continue;
                };
                let t = f64::from(e.x) - f64::from(e.gap);
                samples.push((m, t, class(e.boundary), f64::from(e.slope)));
            }
        }
        if samples.len() < MIN_EDGES {
            return None;
        }
        let every = samples.len().div_ceil(SIGMA_EDGES);
        let crossings: Vec<_> = samples.into_iter().step_by(every).collect();
        // The slopes are read at the linear crossings first, then at the phases the blur
        // before gives them (solved edge by edge; the table only for the final blur).
        let mut phased = crossings.clone();
        for _ in 1..ROUNDS {
            let sigma = fit_sigma(&phased, step)?;
            let signals = signals(sigma, step);
            phased
                .par_iter_mut()
                .zip(&crossings)
                .for_each(|(p, &(mag, t, c, _))| {
                    p.1 = t + folded(mag, t).map_or(0.0, |(tt, sign)| {
                        sign * (phase_of(&signals[c], mag, tt) - tt)
                    });
                });
        }
        Some(CrossingModel::new(fit_sigma(&phased, step)?, step))
    }

    /// Move each edge of one line from its linear crossing to the model's transition.
    pub(super) fn correct(&self, edges: &mut [Edge], step: f64) {
        // Magnifications from the linear crossings: the edges before this one have moved
        // already, so their linear crossings are kept aside (nearest first).
        let mut before = [f32::NAN; REACH];
        for i in 0..edges.len() {
            let raw = edges[i].x;
            let m = magnification(edges, i, step, |j| {
                if j < i {
                    before[i - j - 1]
                } else {
                    edges[j].x
                }
            });
            before.rotate_right(1);
            before[0] = raw;
            let Some(m) = m else {
                continue;
            };
            let e = &mut edges[i];
            let t = f64::from(e.x) - f64::from(e.gap);
            let shift = self.shift(class(e.boundary), m, t);
            e.x = (f64::from(e.x) + shift) as f32;
        }
    }

    /// φ − t for an edge of `class` at magnification `m` and linear crossing `t`.
    fn shift(&self, class: usize, m: f64, t: f64) -> f64 {
        let Some((tt, sign)) = folded(m, t) else {
            return 0.0;
        };
        let fm = (m / M_RANGE.0).ln() / (M_RANGE.1 / M_RANGE.0).ln() * (M_NODES - 1) as f64;
        let ft = tt / 0.5 * (T_NODES - 1) as f64;
        let (j, i) = (
            (fm as usize).min(M_NODES - 2),
            (ft as usize).min(T_NODES - 2),
        );
        let (wm, wt) = (fm - j as f64, ft - i as f64);
        let table = &self.tables[class];
        let at = |j: usize, i: usize| f64::from(table[j * T_NODES + i]);
        let v = (1.0 - wm) * ((1.0 - wt) * at(j, i) + wt * at(j, i + 1))
            + wm * ((1.0 - wt) * at(j + 1, i) + wt * at(j + 1, i + 1));
        sign * v
    }
}

/// Where the model applies (`m` within [`M_RANGE`], `t` between the two pixels): `t` folded
/// onto [0, ½] by φ(1 − t) = 1 − φ(t), and the sign that unfolds the shift.
fn folded(m: f64, t: f64) -> Option<(f64, f64)> {
    if !(M_RANGE.0..=M_RANGE.1).contains(&m) || !(0.0..=1.0).contains(&t) {
        return None;
    }
    Some(if t <= 0.5 { (t, 1.0) } else { (1.0 - t, -1.0) })
}

/// Each class's signal for blur `sigma` and code cells `step` projector pixels wide.
fn signals(sigma: f64, step: f64) -> [Signal; CLASSES] {
    std::array::from_fn(|c| Signal::new(sigma, neighbours(c, step)))
}

/// The blur whose model slopes fit the measured ones best: `(m, phase, class, slope)` per edge.
/// `None` where the best lies at the searched range's end (the signal is not this model's).
fn fit_sigma(picked: &[(f64, f64, usize, f64)], step: f64) -> Option<f64> {
    let misfit = |sigma: f64| -> f64 {
        let signals = signals(sigma, step);
        picked
            .iter()
            .map(|&(m, t, c, slope)| {
                let r = slope - signals[c].slope(t, m);
                r * r
            })
            .sum()
    };
    // Golden-section search over log σ.
    let (mut lo, mut hi) = (SIGMA_RANGE.0.ln(), SIGMA_RANGE.1.ln());
    let g = 0.5 * (5f64.sqrt() - 1.0);
    let (mut x1, mut x2) = (hi - g * (hi - lo), lo + g * (hi - lo));
    let (mut f1, mut f2) = (misfit(x1.exp()), misfit(x2.exp()));
    while hi - lo > 1e-3 {
        if f1 < f2 {
            hi = x2;
            x2 = x1;
            f2 = f1;
            x1 = hi - g * (hi - lo);
            f1 = misfit(x1.exp());
        } else {
            lo = x1;
            x1 = x2;
            f1 = f2;
            x2 = lo + g * (hi - lo);
            f2 = misfit(x2.exp());
        }
    }
    let sigma = (0.5 * (lo + hi)).exp();
    let ends = (SIGMA_RANGE.0 * 1.01, SIGMA_RANGE.1 / 1.01);
    (sigma > ends.0 && sigma < ends.1).then_some(sigma)
}

/// The kind of edge at `boundary` (by the bit that flips there).
#[inline]
fn class(boundary: u32) -> usize {
    (flipped_bit(boundary) as usize).min(CLASSES - 1)
}

/// The magnification at node `j`, log-spaced over [`M_RANGE`].
fn m_at(j: usize) -> f64 {
    M_RANGE.0 * (M_RANGE.1 / M_RANGE.0).powf(j as f64 / (M_NODES - 1) as f64)
}

/// The phase φ in [0, ½] whose linear crossing is `t` (the crossing rises with φ from 0 to ½;
/// regula falsi with the Illinois step, to 1e-9 of a pixel).
fn phase_of(signal: &Signal, m: f64, t: f64) -> f64 {
    let (mut lo, mut hi) = (0.0f64, 0.5f64);
    let (mut f_lo, mut f_hi) = (signal.crossing(lo, m) - t, signal.crossing(hi, m) - t);
    if f_lo >= 0.0 {
        return lo;
    }
    if f_hi <= 0.0 {
        return hi;
    }
    // Which end was kept last: an end kept twice has its value halved.
    let mut kept = 0i8;
    for _ in 0..60 {
        let x = (lo * f_hi - hi * f_lo) / (f_hi - f_lo);
        let f = signal.crossing(x, m) - t;
        if f < 0.0 {
            (lo, f_lo) = (x, f);
            if kept == 1 {
                f_hi *= 0.5;
            }
            kept = 1;
        } else {
            (hi, f_hi) = (x, f);
            if kept == -1 {
                f_lo *= 0.5;
            }
            kept = -1;
        }
        if hi - lo < 1e-9 || f == 0.0 {
            return x;
        }
    }
    0.5 * (lo + hi)
}

/// Projector pixels per camera pixel at edge `i`, from its neighbours in the chain (one to
/// either side, or the one there is) placed at `x(j)`.
fn magnification(edges: &[Edge], i: usize, step: f64, x: impl Fn(usize) -> f32) -> Option<f64> {
    let (lo, hi) = (widen_down(edges, i, REACH), widen_up(edges, i, REACH));
    if lo == hi {
        return None;
    }
    let du = (f64::from(edges[hi].boundary) - f64::from(edges[lo].boundary)).abs() * step;
    let dx = (f64::from(x(hi)) - f64::from(x(lo))).abs();
    (dx > 0.0).then(|| du / dx)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The edges of one line crossing a plane tilted so that each camera pixel covers `m`
    /// projector pixels, rendered through the model with blur `sigma`: linear crossings and
    /// slopes as the decoder measures them, and the true positions.
    fn line(sigma: f64, m: f64, offset: f64) -> (Vec<Edge>, Vec<f64>) {
        let step = 1.0;
        let mut edges = Vec::new();
        let mut truth = Vec::new();
        for b in 1u32..400 {
            // Boundary b at projector coordinate b − 0.5, camera position (b − 0.5 + offset) / m.
            let x = (f64::from(b) - 0.5 + offset) / m;
            let gap = x.floor();
            let phi = x - gap;
            let signal = Signal::new(sigma, neighbours(class(b), step));
            let t = signal.crossing(phi, m);
            // The decoder keeps a crossing only between its two pixels.
            if !(0.0..=1.0).contains(&t) {
                continue;
            }
            edges.push(Edge {
                gap: gap as u32,
                x: (gap + t) as f32,
                boundary: b,
                chain: 1,
                weight: 1.0,
                slope: signal.slope(phi, m) as f32,
            });
            truth.push(x);
        }
        (edges, truth)
    }

    #[test]
    fn the_blur_is_measured_and_the_crossings_come_back_to_their_transitions() {
        for &sigma in &[0.3, 0.45, 0.6, 0.9, 1.5] {
            for &m in &[0.4, 0.7, 1.0, 1.37] {
                if sigma * m > 1.5 {
                    // The finest stripes (1.5 camera px) under a blur of a pixel: not resolved.
                    continue;
                }
                let (mut edges, truth) = line(sigma, m, 0.123);
                let before = edges
                    .iter()
                    .zip(&truth)
                    .map(|(e, t)| (f64::from(e.x) - t).abs())
                    .fold(0.0, f64::max);
                let model = CrossingModel::measure(&[edges.clone()], 1.0).expect("measured");
                assert!(
                    // Worst at the densest edges (m 1.37, σ 0.3: 3.0 %), where the
                    // magnifications read over three neighbours are least exact.
                    (model.sigma() / sigma - 1.0).abs() < 0.035,
                    "σ {sigma} at m {m}: measured {}",
                    model.sigma()
                );
                model.correct(&mut edges, 1.0);
                let after = edges[1..edges.len() - 1]
                    .iter()
                    .zip(&truth[1..])
                    .map(|(e, t)| (f64::from(e.x) - t).abs())
                    .fold(0.0, f64::max);
                assert!(
                    after < 5e-3 && after < 0.2 * before,
                    "σ {sigma}, m {m}: worst crossing error {before:.4} → {after:.4} px"
                );
            }
        }
    }

    #[test]
    fn the_phase_is_the_inverse_of_the_crossing() {
        for &sigma in &[0.12, 0.3, 0.6, 1.5, 3.5] {
            for class in 0..CLASSES {
                let d = neighbours(class, 1.0);
                let signal = Signal::new(sigma, d);
                // Footprints narrower than the stripes (wider ones mix two transitions and
                // have no crossing between the pixels).
                for m in [0.2, 0.5, 1.0, 2.3, 5.0]
                    .into_iter()
                    .filter(|&m| 1.5 * m <= d)
                {
                    for k in 0..=20 {
                        let phi = 0.025 * f64::from(k);
                        let back = phase_of(&signal, m, signal.crossing(phi, m));
                        assert!(
                            (back - phi).abs() < 1e-7,
                            "σ {sigma}, class {class}, m {m}: φ {phi} → {back}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn a_signal_the_model_does_not_describe_is_left_alone() {
        // Slopes of a hard step (no blur at all, every sample ±1) lie at the range's end.
        let (mut edges, _) = line(0.6, 1.0, 0.3);
        for e in &mut edges {
            e.slope = 2.0;
        }
        assert!(CrossingModel::measure(&[edges], 1.0).is_none());
        assert!(CrossingModel::measure(&[Vec::new()], 1.0).is_none());
    }
}
