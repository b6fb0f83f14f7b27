//! The crossing's phase bias: a stripe edge between two camera pixels is located where the
//! pattern and its inverse cross (eq. 4.17), linearly interpolated between the pixels. The
//! signal is a blurred step integrated over each pixel, not a straight line, so the linear
//! crossing is off by a periodic function of where the edge falls between the pixels (its
//! phase): zero at a pixel's centre and half-way, up to 0.05 camera pixels between for a
//! projector blur of about half a camera pixel (the "peak locking" of particle image
//! velocimetry). Where the projector's pixels image at nearly a whole number of camera pixels,
//! neighbouring edges share a phase and the line fit across them cannot average it out: the
//! coordinates carry a moiré of the two pixel grids, 0.01–0.02 projector pixels correlated over
//! tens of camera pixels, which no smoothing removes.
//!
//! The bias depends on the blur and the pixel's footprint, which no setting states, so each
//! capture measures its own: on a sample of lines, every edge is compared with the straight
//! line through its neighbours (leave-one-out), and a few harmonics of its true phase are
//! fitted to those residuals by least squares, with the same harmonics of the neighbours'
//! phases subtracted through the line's weights (the line absorbs part of their bias; the
//! model accounts for it exactly). The phases are read off the line through the neighbours
//! once their bias is removed (the previous round's estimate), not off the edge itself: an
//! edge's own noise would move its phase and its residual together and bias the fit where
//! phases cluster, which is where the moiré is. The amplitudes are polynomials in the local
//! magnification (camera pixels per code cell), and edges are told apart by the bit that flips
//! at them: the finest stripes' signal is not an isolated step, and its shape changes with the
//! magnification. The surface's own shape and the noise do not follow the phase and average
//! out over the tens of thousands of edges of a sample.

use rayon::prelude::*;

use super::{widen_down, widen_up, Edge};
use crate::pattern::flipped_bit;

/// Kinds of edge: on the finest stripes, on the next, and on coarser ones (isolated steps).
const CLASSES: usize = 3;

/// Sine harmonics of the phase in the model (odd about the pixel's centre and half-way).
const HARMONICS: usize = 3;

/// Powers of the local magnification in each harmonic's amplitude.
const POWERS: usize = 3;

/// The magnification's variable: (camera pixels per code cell / the capture's median − 1) ×
/// this, about ±1 over a sensor's depth of field.
const SCALE: f64 = 5.0;

/// Edges whose variable lies beyond this are not on a usable surface (a magnification of
/// more than twice the median).
const LIMIT: f64 = 5.0;

const PARAMS: usize = CLASSES * HARMONICS * POWERS;

/// Samples of the harmonics over one phase period.
const TABLE: usize = 64;

/// Residuals beyond this (camera pixels) are a break the chain did not see, not a bias.
const OUTLIER: f64 = 0.5;

/// Edges whose reliability (see `Edge::weight`) is below this sit beside albedo edges.
const MIN_WEIGHT: f32 = 0.5;

/// Edges needed to trust the fit (an 800x600 capture's sample holds some 30 000).
const MIN_ROWS: usize = 2000;

/// A bias beyond this (camera pixels) is not a crossing's; the capture is left uncorrected.
const MAX_BIAS: f32 = 0.2;

/// Rounds of the fit: each reads the phases off lines corrected by the round before.
const ROUNDS: usize = 2;

/// Bins of the histogram of the magnification's variable over [−LIMIT, LIMIT].
const BINS: usize = 200;

/// Share of the sampled edges left out at either end of the magnifications the fit is used
/// over (the polynomial is not extrapolated to a few stray lines).
const TAIL: f64 = 0.005;

/// The kind of edge at `boundary` (by the bit that flips there).
#[inline]
pub(super) fn class(boundary: u32) -> usize {
    (flipped_bit(boundary) as usize).min(CLASSES - 1)
}

/// sin(2π m t) for m = 1..=[`HARMONICS`] (from one sine and cosine).
#[inline]
fn basis(t: f64) -> [f64; HARMONICS] {
    let (s, c) = (std::f64::consts::TAU * t).sin_cos();
    [s, 2.0 * s * c, s * (3.0 - 4.0 * s * s)]
}

/// The straight line x = a + b (u − ū) through `(u, x)` points by least squares.
#[derive(Clone, Copy, Debug)]
struct Line {
    mean_u: f64,
    a: f64,
    b: f64,
}

impl Line {
    fn fit(points: impl Iterator<Item = (f64, f64)> + Clone) -> Option<Line> {
        let (mut n, mut su, mut sx) = (0.0, 0.0, 0.0);
        for (u, x) in points.clone() {
            n += 1.0;
            su += u;
            sx += x;
        }
        if n < 2.0 {
            return None;
        }
        let (mean_u, mean_x) = (su / n, sx / n);
        let (mut suu, mut sux) = (0.0, 0.0);
        for (u, x) in points {
            suu += (u - mean_u) * (u - mean_u);
            sux += (u - mean_u) * (x - mean_x);
        }
        (suu > 0.0).then(|| Line {
            mean_u,
            a: mean_x,
            b: sux / suu,
        })
    }

    #[inline]
    fn at(&self, u: f64) -> f64 {
        self.a + self.b * (u - self.mean_u)
    }
}

/// A capture's measured crossing bias per kind of edge, as a function of the true phase and
/// of the local magnification.
#[derive(Clone, Debug)]
pub(super) struct PhaseBias {
    coefficients: [f64; PARAMS],
    /// The harmonics sampled over the phase.
    table: [[f32; HARMONICS]; TABLE + 1],
    /// Magnifications the fit saw (as its variable); the polynomial is not extrapolated beyond.
    range: (f64, f64),
    /// The capture's median magnification (the variable's origin).
    median: f64,
}

impl PhaseBias {
    fn new(coefficients: [f64; PARAMS], range: (f64, f64), median: f64) -> PhaseBias {
        let table = std::array::from_fn(|k| basis(k as f64 / TABLE as f64).map(|b| b as f32));
        PhaseBias {
            coefficients,
            table,
            range,
            median,
        }
    }

    /// The magnification's variable.
    #[inline]
    fn variable(median: f64, magnification: f64) -> f64 {
        (magnification.abs() / median - 1.0) * SCALE
    }

    /// The bias (camera pixels) of an edge of `class` whose true position is `x` (its
    /// fractional part is the phase) where the code advances one cell every `magnification`
    /// camera pixels.
    #[inline(always)]
    fn at(&self, class: usize, x: f64, magnification: f64) -> f64 {
        let p = (x - x.floor()) * TABLE as f64;
        let i = (p as usize).min(TABLE - 1);
        let f = (p - i as f64) as f32;
        let d = Self::variable(self.median, magnification).clamp(self.range.0, self.range.1);
        let c = &self.coefficients[class * HARMONICS * POWERS..(class + 1) * HARMONICS * POWERS];
        let mut bias = 0.0;
        for m in 0..HARMONICS {
            let a = c[m * POWERS..(m + 1) * POWERS]
                .iter()
                .rev()
                .fold(0.0, |acc, ck| acc * d + ck);
            let (lo, hi) = (self.table[i][m], self.table[i + 1][m]);
            bias += a * f64::from(lo + (hi - lo) * f);
        }
        bias
    }

    /// Largest bias of any kind of edge at any phase over the magnifications seen, camera
    /// pixels.
    pub(super) fn amplitude(&self) -> f32 {
        let mut worst = 0.0f64;
        for class in 0..CLASSES {
            for k in 0..=16 {
                let d = self.range.0 + (self.range.1 - self.range.0) * k as f64 / 16.0;
                let m = self.median * (1.0 + d / SCALE);
                for p in 0..=TABLE {
                    worst = worst.max(self.at(class, p as f64 / TABLE as f64, m).abs());
                }
            }
        }
        worst as f32
    }

    /// The fitted coefficients, by class, harmonic and power of the magnification.
    pub(super) fn coefficients(&self) -> &[f64; PARAMS] {
        &self.coefficients
    }

    /// Subtract the bias from one line's edges: each edge's true phase and magnification are
    /// read off the straight line through its window (up to `window` edges of its chain on
    /// either side) once the window's edges are corrected at their own phases, as in the fit.
    /// The lines come from running sums along each chain, so each costs the same whatever
    /// the window.
    pub(super) fn correct(&self, edges: &mut [Edge], window: usize, scratch: &mut Scratch) {
        self.first_guess(edges, window, &mut scratch.guess);
        let guess = &scratch.guess;
        let sums = &mut scratch.sums;
        let mut start = 0;
        while start < edges.len() {
            let end = widen_up(edges, start, edges.len()) + 1;
            // Σ du, Σ du², Σ dy, Σ du·dy from the run's first edge (small numbers, no
            // cancellation).
            let (u0, y0) = (f64::from(edges[start].boundary), guess[start]);
            sums.clear();
            sums.push([0.0; 4]);
            let mut s = [0.0; 4];
            for (e, g) in edges[start..end].iter().zip(&guess[start..end]) {
                let (du, dy) = (f64::from(e.boundary) - u0, g - y0);
                s = [s[0] + du, s[1] + du * du, s[2] + dy, s[3] + du * dy];
                sums.push(s);
            }
            for i in start..end {
                let (lo, hi) = (widen_down(edges, i, window), widen_up(edges, i, window));
                if hi - lo < 2 {
                    continue;
                }
                let (a, b) = (sums[lo - start], sums[hi + 1 - start]);
                let n = (hi - lo + 1) as f64;
                let (su, suu, sy, suy) = (b[0] - a[0], b[1] - a[1], b[2] - a[2], b[3] - a[3]);
                let var = suu - su * su / n;
                if var <= 0.0 {
                    continue;
                }
                let slope = (suy - su * sy / n) / var;
                let e = &mut edges[i];
                let du = f64::from(e.boundary) - u0 - su / n;
                let at = y0 + sy / n + slope * du;
                let bias = self.at(class(e.boundary), at, slope);
                e.x = (f64::from(e.x) - bias) as f32;
            }
            start = end;
        }
    }

    /// Each edge's position less its bias at its measured phase, with the magnification
    /// between the ends of its window (the first guess from which the true phases are read).
    fn first_guess(&self, edges: &[Edge], window: usize, out: &mut Vec<f64>) {
        out.clear();
        out.extend(edges.iter().map(|e| f64::from(e.x)));
        for (i, guess) in out.iter_mut().enumerate() {
            let (lo, hi) = (widen_down(edges, i, window), widen_up(edges, i, window));
            if hi != lo {
                let (first, last) = (&edges[lo], &edges[hi]);
                let span = f64::from(last.boundary.abs_diff(first.boundary));
                let magnification = f64::from(last.x - first.x) / span;
                *guess -= self.at(class(edges[i].boundary), *guess, magnification);
            }
        }
    }
}

/// Working memory of [`PhaseBias::correct`], kept across lines.
#[derive(Debug, Default)]
pub(super) struct Scratch {
    guess: Vec<f64>,
    sums: Vec<[f64; 4]>,
}

/// The crossing bias measured from sampled lines' edges (each line's edges in order), with
/// `window` edges on either side of each; `None` from too few edges or an implausible fit.
pub(super) fn measure(lines: &[Vec<Edge>], window: usize) -> Option<PhaseBias> {
    let median = median_magnification(lines, window)?;
    let mut bias: Option<PhaseBias> = None;
    for _ in 0..ROUNDS {
        let normal = lines
            .par_iter()
            .fold(
                || (Normal::new(median), Vec::new()),
                |(mut normal, mut guess), edges| {
                    normal.add(edges, window, bias.as_ref(), &mut guess);
                    (normal, guess)
                },
            )
            .map(|(normal, _)| normal)
            .reduce(|| Normal::new(median), Normal::merge);
        bias = Some(normal.solve()?);
    }
    bias
}

/// Bins of the histogram of log2 of the magnification over [−8, 8).
const LOG_BINS: usize = 1024;

/// The median of the magnification (camera pixels per code cell) over the sampled edges with
/// a whole window; `None` without any.
fn median_magnification(lines: &[Vec<Edge>], window: usize) -> Option<f64> {
    let histogram = lines
        .par_iter()
        .fold(
            || vec![0u64; LOG_BINS],
            |mut histogram, edges| {
                for around in edges.windows(2 * window + 1) {
                    let (first, last) = (&around[0], &around[2 * window]);
                    if around.iter().any(|e| e.chain != first.chain) {
                        continue;
                    }
                    let span = f64::from(last.boundary.abs_diff(first.boundary));
                    let m = f64::from((last.x - first.x).abs()) / span;
                    if m > 0.0 && m.is_finite() {
                        let bin = ((m.log2() + 8.0) / 16.0 * LOG_BINS as f64).floor();
                        if (0.0..LOG_BINS as f64).contains(&bin) {
                            histogram[bin as usize] += 1;
                        }
                    }
                }
                histogram
            },
        )
        .reduce(
            || vec![0u64; LOG_BINS],
            |mut a, b| {
                a.iter_mut().zip(&b).for_each(|(x, y)| *x += y);
                a
            },
        );
    let total: u64 = histogram.iter().sum();
    let mut seen = 0;
    let bin = histogram.iter().position(|c| {
        seen += c;
        total > 0 && 2 * seen >= total
    })?;
    Some(2f64.powf((bin as f64 + 0.5) / LOG_BINS as f64 * 16.0 - 8.0))
}

/// Normal equations of the bias fit, accumulated line by line.
#[derive(Clone, Debug)]
struct Normal {
    m: [[f64; PARAMS]; PARAMS],
    r: [f64; PARAMS],
    rows: usize,
    /// Histogram of the magnification's variable over the rows.
    spread: [u32; BINS],
    /// The capture's median magnification.
    median: f64,
}

impl Normal {
    fn new(median: f64) -> Normal {
        Normal {
            m: [[0.0; PARAMS]; PARAMS],
            r: [0.0; PARAMS],
            rows: 0,
            spread: [0; BINS],
            median,
        }
    }

    /// Add one line's edges: each edge with `window` reliable edges of its chain on either
    /// side is compared with the line through them; the phases are read off that line once
    /// `prior` (the previous round's bias) is removed from the neighbours.
    fn add(
        &mut self,
        edges: &[Edge],
        window: usize,
        prior: Option<&PhaseBias>,
        guess: &mut Vec<f64>,
    ) {
        let n = 2 * window;
        if edges.len() <= n {
            return;
        }
        match prior {
            Some(p) => p.first_guess(edges, window, guess),
            None => {
                guess.clear();
                guess.extend(edges.iter().map(|e| f64::from(e.x)));
            }
        }
        for i in window..edges.len() - window {
            let around = &edges[i - window..=i + window];
            let chain = edges[i].chain;
            if around
                .iter()
                .any(|e| e.chain != chain || e.weight < MIN_WEIGHT)
            {
                continue;
            }
            let others = || (i - window..=i + window).filter(|&k| k != i);
            let Some(line) = Line::fit(others().map(|k| (f64::from(edges[k].boundary), guess[k])))
            else {
                continue;
            };
            let neighbours = || others().map(|k| &edges[k]);
            let d = PhaseBias::variable(self.median, line.b);
            if d.abs() >= LIMIT {
                continue;
            }
            let powers: [f64; POWERS] = std::array::from_fn(|p| d.powi(p as i32));
            let ui = f64::from(edges[i].boundary);
            let suu: f64 = neighbours()
                .map(|e| (f64::from(e.boundary) - line.mean_u).powi(2))
                .sum();
            let mut predicted = 0.0;
            let mut row = [0.0; PARAMS];
            let mut add = |class: usize, t: f64, scale: f64| {
                for (m, b) in basis(t).iter().enumerate() {
                    for (p, dp) in powers.iter().enumerate() {
                        row[(class * HARMONICS + m) * POWERS + p] += scale * b * dp;
                    }
                }
            };
            add(class(edges[i].boundary), line.at(ui), 1.0);
            for e in neighbours() {
                let u = f64::from(e.boundary);
                let l = 1.0 / n as f64 + (ui - line.mean_u) * (u - line.mean_u) / suu;
                predicted += l * f64::from(e.x);
                add(class(e.boundary), line.at(u), -l);
            }
            let residual = f64::from(edges[i].x) - predicted;
            if residual.abs() > OUTLIER {
                continue;
            }
            for (j, rj) in row.iter().enumerate() {
                self.r[j] += rj * residual;
                for (k, rk) in row.iter().enumerate().skip(j) {
                    self.m[j][k] += rj * rk;
                }
            }
            self.rows += 1;
            let bin = ((d + LIMIT) / (2.0 * LIMIT) * BINS as f64) as usize;
            self.spread[bin.min(BINS - 1)] += 1;
        }
    }

    fn merge(mut self, other: Normal) -> Normal {
        for j in 0..PARAMS {
            self.r[j] += other.r[j];
            for k in j..PARAMS {
                self.m[j][k] += other.m[j][k];
            }
        }
        for (a, b) in self.spread.iter_mut().zip(&other.spread) {
            *a += b;
        }
        self.rows += other.rows;
        self
    }

    /// The magnifications (as the variable) between the tails of the rows' histogram.
    fn range(&self) -> (f64, f64) {
        let edge = |k: usize| -LIMIT + 2.0 * LIMIT * k as f64 / BINS as f64;
        let tail = (TAIL * self.rows as f64) as u64;
        let mut seen = 0u64;
        let mut lo = 0;
        for (k, c) in self.spread.iter().enumerate() {
            seen += u64::from(*c);
            if seen > tail {
                lo = k;
                break;
            }
        }
        seen = 0;
        let mut hi = BINS - 1;
        for (k, c) in self.spread.iter().enumerate().rev() {
            seen += u64::from(*c);
            if seen > tail {
                hi = k;
                break;
            }
        }
        (edge(lo), edge(hi + 1))
    }

    /// The least-squares bias; `None` from too few edges or an implausible fit. A kind of edge
    /// too rare to be measured keeps a bias near zero (a small ridge holds it there).
    fn solve(&self) -> Option<PhaseBias> {
        if self.rows < MIN_ROWS {
            return None;
        }
        let ridge = 1e-4 * self.rows as f64 / PARAMS as f64;
        let normal = nalgebra::SMatrix::<f64, PARAMS, PARAMS>::from_fn(|j, k| {
            let v = if j <= k { self.m[j][k] } else { self.m[k][j] };
            if j == k {
                v + ridge
            } else {
                v
            }
        });
        let r = nalgebra::SVector::<f64, PARAMS>::from_fn(|j, _| self.r[j]);
        let solved = normal.cholesky()?.solve(&r);
        let coefficients: [f64; PARAMS] = std::array::from_fn(|j| solved[j]);
        if coefficients.iter().any(|c| !c.is_finite()) {
            return None;
        }
        let bias = PhaseBias::new(coefficients, self.range(), self.median);
        (bias.amplitude() <= MAX_BIAS).then_some(bias)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Edges of one chain on the line x = 37.2 + `slope`·u (boundary u), each displaced by
    /// `bias` at its true phase, and split into chains of 40 edges.
    fn biased_line(bias: &PhaseBias, slope: f64, len: u32) -> Vec<Edge> {
        (1..len)
            .map(|b| {
                let x = 37.2 + slope * f64::from(b);
                let found = x + bias.at(class(b), x, slope);
                Edge {
                    gap: found.floor() as u32,
                    x: found as f32,
                    boundary: b,
                    chain: b / 40,
                    weight: 1.0,
                    slope: 1.0,
                }
            })
            .collect()
    }

    /// A bias whose first harmonic grows with the magnification on the finest stripes.
    fn planted() -> PhaseBias {
        let mut c = [0.0; PARAMS];
        let at = |class: usize, m: usize, p: usize| (class * HARMONICS + m) * POWERS + p;
        c[at(0, 0, 0)] = 0.04;
        c[at(0, 0, 1)] = 0.01;
        c[at(0, 1, 0)] = -0.01;
        c[at(1, 0, 0)] = 0.03;
        c[at(1, 2, 0)] = -0.004;
        c[at(2, 0, 0)] = -0.02;
        c[at(2, 1, 0)] = 0.006;
        PhaseBias::new(c, (-2.0, 2.0), 1.0)
    }

    fn slopes() -> [f64; 8] {
        [0.77, 0.86, 0.93, 1.02, 1.08, 1.17, 1.31, 1.22]
    }

    #[test]
    fn a_planted_bias_is_measured_back_from_the_edges_alone() {
        let planted = planted();
        // Magnifications that spread the phases, and some near a whole pixel per boundary
        // (the moiré), where the line absorbs the bias.
        let lines: Vec<Vec<Edge>> = slopes()
            .iter()
            .map(|s| biased_line(&planted, *s, 3000))
            .collect();
        let measured = measure(&lines, 3).expect("enough edges");
        for class in 0..CLASSES {
            for slope in [0.8, 1.0, 1.2] {
                for k in 0..=20 {
                    let t = f64::from(k) / 20.0;
                    let (m, p) = (measured.at(class, t, slope), planted.at(class, t, slope));
                    assert!(
                        (m - p).abs() < 2e-3,
                        "class {class}, magnification {slope}, phase {t}: {m} against {p}"
                    );
                }
            }
        }
        // Corrected, every edge is back on its line, to a tenth of the bias at a chain's
        // ends (where its window is one-sided) and a twentieth inside.
        let mut scratch = Scratch::default();
        for (mut line, slope) in lines.into_iter().zip(slopes()) {
            measured.correct(&mut line, 3, &mut scratch);
            for (i, e) in line.iter().enumerate() {
                let x = 37.2 + slope * f64::from(e.boundary);
                let inside = i >= 3
                    && i + 3 < line.len()
                    && line[i - 3].chain == e.chain
                    && line[i + 3].chain == e.chain;
                let tolerance = if inside { 2.5e-3 } else { 5e-3 };
                assert!((f64::from(e.x) - x).abs() < tolerance, "{e:?} against {x}");
            }
        }
    }

    #[test]
    fn a_camera_finer_than_the_projector_is_measured_too() {
        // 2.5 camera pixels per code cell around the median (a 2 k camera on a 1 k projector).
        let mut c = [0.0; PARAMS];
        c[0] = 0.01;
        c[HARMONICS * POWERS] = -0.008;
        c[2 * HARMONICS * POWERS] = 0.006;
        let planted = PhaseBias::new(c, (-2.0, 2.0), 2.5);
        let lines: Vec<Vec<Edge>> = slopes()
            .iter()
            .map(|s| biased_line(&planted, 2.5 * s, 3000))
            .collect();
        let measured = measure(&lines, 3).expect("enough edges");
        assert!((measured.median - 2.5).abs() < 0.1, "{}", measured.median);
        for class in 0..CLASSES {
            for k in 0..=20 {
                let t = f64::from(k) / 20.0;
                let (m, p) = (measured.at(class, t, 2.5), planted.at(class, t, 2.5));
                assert!(
                    (m - p).abs() < 1e-3,
                    "class {class}, phase {t}: {m} against {p}"
                );
            }
        }
    }

    #[test]
    fn unbiased_edges_measure_no_bias_and_too_few_measure_nothing() {
        let zero = PhaseBias::new([0.0; PARAMS], (0.0, 0.0), 1.0);
        let lines: Vec<Vec<Edge>> = slopes()
            .iter()
            .map(|s| biased_line(&zero, *s, 3000))
            .collect();
        let measured = measure(&lines, 3).expect("enough edges");
        // Edges stored in f32 at x up to 3 300 px are rounded by up to 1.2e-4 px.
        assert!(measured.amplitude() < 1e-3, "{measured:?}");
        assert!(measure(&[biased_line(&zero, 0.83, 200)], 3).is_none());
    }
}
