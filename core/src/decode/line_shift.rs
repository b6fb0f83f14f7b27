//! Pass 2 of decoding: Gray-code line shifting to sub-pixel projector coordinates (Ch. 4.4.4).

use rayon::prelude::*;

use super::ScanDirection;

mod crossing_model;
mod phase_bias;

use crossing_model::CrossingModel;

use crate::image::Sample;
use crate::pattern::{binary_to_gray, flipped_bit};

/// Eq. 4.17: the sub-pixel position where a pattern and its inverse cross between camera pixels
/// `n` (pattern `a`, inverse `b`) and `n + 1` (pattern `d`, inverse `c`):
/// `X = n + (A − B) / ((C − B) − (D − A))`. `None` when the curves do not cross in `[n, n+1]`.
///
/// ```
/// use ris_core::decode::edge_position;
/// let x = edge_position(899.0, 61.0, 34.0, 64.0, 29.0).unwrap();
/// assert!((x - 899.4).abs() < 0.05);
/// ```
pub fn edge_position(n: f32, a: f32, b: f32, c: f32, d: f32) -> Option<f32> {
    let den = (c - b) - (d - a);
    let t = (a - b) / den;
    (den != 0.0 && (0.0..=1.0).contains(&t)).then_some(n + t)
}

/// Frames needed to evaluate the pattern-minus-inverse signal of any bit at any pixel.
pub(super) struct Signal<'a, T> {
    pub white: &'a [T],
    pub black: &'a [T],
    pub pat: &'a [&'a [T]],
    pub inv: Option<&'a [&'a [T]]>,
}

impl<T: Sample> Signal<'_, T> {
    /// White − black at pixel `i` (at least 1).
    #[inline(always)]
    fn contrast(&self, i: usize) -> f32 {
        (self.white[i].to_i32() - self.black[i].to_i32()).max(1) as f32
    }

    /// Pattern minus inverse (or 2P − W − K) of bit `j` at pixel `i`, times `inv_contrast`
    /// (1 / the pixel's contrast) so that albedo differences between neighbouring pixels do not
    /// move the edge.
    #[inline(always)]
    fn normalized(&self, j: usize, i: usize, inv_contrast: f32) -> f32 {
        let p = self.pat[j][i].to_i32();
        let s = match self.inv {
            Some(inv) => p - inv[j][i].to_i32(),
            None => 2 * p - self.white[i].to_i32() - self.black[i].to_i32(),
        };
        s as f32 * inv_contrast
    }
}

/// One located boundary on a line: between pixels `gap` and `gap + 1`, at position `x`, for the
/// boundary before code cell `boundary`. Consecutive edges of one `chain` step through adjacent
/// boundaries in one direction with no break (invalid pixel, discontinuity) between them.
#[derive(Clone, Copy, Debug)]
struct Edge {
    gap: u32,
    x: f32,
    boundary: u32,
    chain: u32,
    /// Reliability in (0, 1]: (smaller / larger contrast of the two pixels)^power. A crossing
    /// next to an albedo edge is biased, so it counts less in the line fit.
    weight: f32,
    /// The normalised signal's rise across the gap, |s₀ − s₁| (2 for a hard step between two
    /// wide stripes): how sharp the blurred step is (see [`CrossingModel`]).
    slope: f32,
}

/// Geometry of one camera line through the row-major image.
#[derive(Clone, Copy)]
struct Line {
    start: usize,
    stride: usize,
    len: usize,
}

struct Code {
    bits: u32,
    step: f32,
    max_jump: u32,
    window: usize,
    extrapolate: bool,
    cell_tolerance: f32,
    albedo_power: u32,
    /// The bend's filter for a whole symmetric window, when the bend is corrected.
    bend: Option<BendFilter>,
    /// The capture's crossing model, applied to every edge, when the bias is corrected.
    model: Option<CrossingModel>,
    /// The capture's crossing bias as harmonics of the phase, where the model was not measured.
    phase: Option<phase_bias::PhaseBias>,
}

/// Columns handled together when scanning down columns, so frame reads stay row-major.
const BLOCK: usize = 64;

/// Continuous projector coordinate per pixel (NaN where invalid), a quality factor (1 where
/// interpolated between edges, 0.5 where extrapolated from one side, 0 where invalid) and the
/// bend correction of each pixel's cell (0 where none; see [`add_bend`]).
///
/// Along rows the result is row-major (h × w). Along columns it is *transposed* (w × h: one
/// row per camera column), so that the filters that follow can always look across the scan
/// as "the previous and next row".
#[allow(clippy::too_many_arguments)]
pub(super) fn subpixel<T: Sample>(
    w: usize,
    h: usize,
    codes: &[i32],
    signal: &Signal<'_, T>,
    dir: ScanDirection,
    bits: u32,
    step: u32,
    params: &super::DecodeParams,
) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    let mut code = Code {
        bits,
        step: step as f32,
        max_jump: params.max_jump,
        window: params.edge_window.max(1),
        extrapolate: params.extrapolate,
        cell_tolerance: params.cell_tolerance,
        albedo_power: params.albedo_weight_power,
        bend: params
            .bend_correction
            .then(|| BendFilter::new(wide_window(params.edge_window.max(1)))),
        model: None,
        phase: None,
    };
    if params.phase_correction {
        (code.model, code.phase) = crossing_bias(w, h, codes, signal, dir, &code);
    }
    let mut coord = vec![f32::NAN; w * h];
    let mut quality = vec![0f32; w * h];
    let mut bend = vec![0f32; w * h];
    match dir {
        ScanDirection::AlongRows => {
            coord
                .par_chunks_mut(w)
                .zip(quality.par_chunks_mut(w))
                .zip(bend.par_chunks_mut(w))
                .enumerate()
                .for_each_init(
                    || (Vec::new(), phase_bias::Scratch::default()),
                    |(edges, scratch), (y, ((out, q), bent))| {
                        let line = Line {
                            start: y * w,
                            stride: 1,
                            len: w,
                        };
                        edges.clear();
                        let mut chain = ChainState::default();
                        for n in 0..w.saturating_sub(1) {
                            gap_edges(
                                y * w + n,
                                y * w + n + 1,
                                n,
                                codes,
                                signal,
                                &code,
                                &mut chain,
                                edges,
                            );
                        }
                        correct_phase(edges, &code, scratch);
                        fit_runs(line, codes, &code, edges, out, q, bent);
                    },
                );
        }
        ScanDirection::AlongColumns => {
            // Phase 2 reads each column's codes contiguously from a transposed copy.
            let codes_t = super::transpose(codes, w, h);
            coord
                .par_chunks_mut(BLOCK * h)
                .zip(quality.par_chunks_mut(BLOCK * h))
                .zip(bend.par_chunks_mut(BLOCK * h))
                .enumerate()
                .for_each_init(
                    || {
                        (
                            vec![Vec::new(); BLOCK],
                            vec![ChainState::default(); BLOCK],
                            phase_bias::Scratch::default(),
                        )
                    },
                    |(edges, chains, scratch), (b, ((out, q), bent))| {
                        let x0 = b * BLOCK;
                        let bw = out.len() / h;
                        for x in 0..bw {
                            edges[x].clear();
                            chains[x] = ChainState::default();
                        }
                        // Phase 1, row-major inside the block: every vertical gap of every column.
                        for y in 0..h.saturating_sub(1) {
                            for x in 0..bw {
                                let i0 = y * w + x0 + x;
                                gap_edges(
                                    i0,
                                    i0 + w,
                                    y,
                                    codes,
                                    signal,
                                    &code,
                                    &mut chains[x],
                                    &mut edges[x],
                                );
                            }
                        }
                        // Phase 2, per column: runs and line fits into this column's output row.
                        for x in 0..bw {
                            correct_phase(&mut edges[x], &code, scratch);
                            let line = Line {
                                start: (x0 + x) * h,
                                stride: 1,
                                len: h,
                            };
                            fit_runs(
                                line,
                                &codes_t,
                                &code,
                                &edges[x],
                                &mut out[x * h..(x + 1) * h],
                                &mut q[x * h..(x + 1) * h],
                                &mut bent[x * h..(x + 1) * h],
                            );
                        }
                    },
                );
        }
    }
    (coord, quality, bend)
}

/// Lines of the capture sampled to measure its crossing bias: about this many, evenly spread
/// (an 800x600 capture's every fifteenth row; some 30 000 edges).
const PHASE_LINES: usize = 40;

/// The crossing bias of this capture along `dir`, measured on [`PHASE_LINES`] lines: the
/// model of the blurred step (see [`CrossingModel`]) or, where the model cannot be measured,
/// the phase bias's harmonics (see [`phase_bias`]); both `None` where too few edges tell either.
fn crossing_bias<T: Sample>(
    w: usize,
    h: usize,
    codes: &[i32],
    signal: &Signal<'_, T>,
    dir: ScanDirection,
    code: &Code,
) -> (Option<CrossingModel>, Option<phase_bias::PhaseBias>) {
    let (lines, len, along, across) = match dir {
        ScanDirection::AlongRows => (h, w, 1, w),
        ScanDirection::AlongColumns => (w, h, w, 1),
    };
    let every = (lines / PHASE_LINES).max(1);
    let sample: Vec<Vec<Edge>> = (every / 2..lines)
        .into_par_iter()
        .step_by(every)
        .map(|line| {
            let mut edges = Vec::new();
            let mut chain = ChainState::default();
            let start = line * across;
            for n in 0..len.saturating_sub(1) {
                let i0 = start + n * along;
                gap_edges(
                    i0,
                    i0 + along,
                    n,
                    codes,
                    signal,
                    code,
                    &mut chain,
                    &mut edges,
                );
            }
            edges
        })
        .collect();
    let model = CrossingModel::measure(&sample, f64::from(code.step));
    // The harmonics stand in where the model could not be measured. After the model they
    // would fit what it leaves on phases that cluster (a flat at a constant magnification
    // shows a handful), where their fit is degenerate (see BENCHMARKS.md, session 55).
    let bias = match &model {
        Some(m) => {
            tracing::debug!(direction = ?dir, sigma = m.sigma(), "crossing model measured");
            None
        }
        None => phase_bias::measure(&sample, code.window),
    };
    match &bias {
        Some(b) => tracing::debug!(
            direction = ?dir,
            amplitude = b.amplitude(),
            coefficients = ?b.coefficients(),
            "crossing bias measured"
        ),
        None => tracing::debug!(direction = ?dir, "crossing bias not measured"),
    }
    (model, bias)
}

/// Remove the capture's crossing bias (as far as measured) from one line's edges.
fn correct_phase(edges: &mut [Edge], code: &Code, scratch: &mut phase_bias::Scratch) {
    if let Some(model) = &code.model {
        model.correct(edges, f64::from(code.step));
    }
    if let Some(bias) = &code.phase {
        bias.correct(edges, code.window, scratch);
    }
}

/// Chain bookkeeping of one line while its gaps are visited in order.
#[derive(Clone, Copy, Debug, Default)]
struct ChainState {
    chain: u32,
    broken: bool,
    direction: i64,
    started: bool,
}

/// Highest power of the polynomial that describes the edges' bend around a cell.
const DEGREE: usize = 4;

/// The bend of the edges' positions around one code cell: the terms of power 2..=[`DEGREE`]
/// of x(u), with u = boundary − origin (code cells from the cell's centre) and x in camera
/// pixels.
///
/// A straight line fitted across several edges on either side of a cell is biased wherever
/// the surface curves: by the mean of u² over the window times the curvature, 0.06–0.1 mm
/// inwards on a 40 mm sphere at 1.6 m with three edges a side. The bend is therefore taken
/// from a polynomial over a wider window, removed from the edges before the line is fitted
/// over the narrow window, and put back when each pixel's coordinate is solved; the
/// difference it makes is [`add_bend`]'s correction. A quadratic alone is not enough near a
/// sphere's rim, where the quartic term of a wide window shifts its curvature.
#[derive(Clone, Copy, Debug, Default)]
struct Bend {
    c: [f64; DEGREE - 1],
}

impl Bend {
    /// x − bend at `u`.
    #[inline]
    fn value(&self, u: f64) -> f64 {
        let mut uk = u * u;
        let mut v = 0.0;
        for c in self.c {
            v += c * uk;
            uk *= u;
        }
        v
    }

    /// d(bend)/du at `u`.
    #[inline]
    fn slope(&self, u: f64) -> f64 {
        let mut uk = u;
        let mut v = 0.0;
        for (k, c) in self.c.iter().enumerate() {
            v += (k + 2) as f64 * c * uk;
            uk *= u;
        }
        v
    }

    /// The bend of the weighted least-squares polynomial through `wide`.
    fn fit(wide: &[Edge], origin: f64) -> Bend {
        // Polynomial degree the window supports with three spare edges.
        let n = wide.len();
        let degree = match n {
            0..=5 => return Bend::default(),
            6..=7 => 2,
            _ => DEGREE,
        };
        let mut m = [0.0f64; 2 * DEGREE + 1]; // Σ w u^k
        let mut r = [0.0f64; DEGREE + 1]; // Σ w u^k x
        for ed in wide {
            let (w, u, x) = (
                f64::from(ed.weight),
                f64::from(ed.boundary) - origin,
                f64::from(ed.x),
            );
            let mut uk = w;
            for (k, mk) in m.iter_mut().enumerate().take(2 * degree + 1) {
                *mk += uk;
                if k <= degree {
                    r[k] += uk * x;
                }
                uk *= u;
            }
        }
        let mut c = [0.0; DEGREE - 1];
        let solved = if degree == DEGREE {
            solve::<{ DEGREE + 1 }>(&m, &r, &mut c)
        } else {
            solve::<3>(&m, &r, &mut c)
        };
        if solved {
            Bend { c }
        } else {
            Bend::default()
        }
    }
}

/// Solve the normal equations of a polynomial of N coefficients (Hankel matrix of the moments
/// `m`, right side `r`) and put the coefficients of power 2 and up into `bend`; false when
/// singular or not finite.
fn solve<const N: usize>(m: &[f64], r: &[f64], bend: &mut [f64]) -> bool {
    let normal = nalgebra::SMatrix::<f64, N, N>::from_fn(|i, j| m[i + j]);
    let Some(chol) = normal.cholesky() else {
        return false;
    };
    let coef = chol.solve(&nalgebra::SVector::<f64, N>::from_fn(|i, _| r[i]));
    if coef.iter().any(|v| !v.is_finite()) {
        return false;
    }
    for (k, b) in bend.iter_mut().enumerate().take(N - 2) {
        *b = coef[k + 2];
    }
    true
}

/// Pixels along and lines across the window that tells a curved region from a flat one.
const REGION: (usize, usize) = (12, 5);

/// Pixels along and lines across the window over which a curved region's bend correction is
/// averaged.
const SMOOTHING: (usize, usize) = (1, 1);

/// Mean bend correction over [`REGION`], projector pixels, above which a region counts as
/// curved (about 0.02 mm of depth at the demo sensor's 17° triangulation angle).
const CURVED: f32 = 0.006;

/// Add the bend correction of [`subpixel`] to the coordinates where the surface is curved
/// (line-major `w` × `h` layout, as [`subpixel`] returns it).
///
/// Each cell's bend comes from a quartic over many edges and is noisier than the straight
/// line it corrects; on flat surfaces its errors are not independent either (the moiré of
/// the projector's and the camera's pixel grids bends several neighbouring lines alike). A
/// surface's curvature, though, keeps its sign over a wide region, where the moiré averages
/// out: the correction (averaged over [`SMOOTHING`]) is applied only where its mean over
/// [`REGION`] exceeds [`CURVED`]. Flats keep the straight line's noise; spheres of 20–60 mm
/// lose their bias (see `core/tests/suite/curved_surfaces.rs`).
pub(super) fn add_bend(w: usize, h: usize, coord: &mut [f32], bend: &[f32]) {
    let region = box_mean(w, h, coord, bend, REGION);
    let local = box_mean(w, h, coord, bend, SMOOTHING);
    coord
        .par_iter_mut()
        .zip(region.par_iter().zip(&local))
        .for_each(|(c, (r, l))| {
            if c.is_finite() && r.abs() > CURVED {
                *c += l;
            }
        });
}

/// Mean of `values` over the valid pixels (finite `coord`) within `reach` pixels along and
/// `radius` lines across; 0 where none is valid.
fn box_mean(
    w: usize,
    h: usize,
    coord: &[f32],
    values: &[f32],
    (reach, radius): (usize, usize),
) -> Vec<f32> {
    // Along the lines: windowed sums of the valid pixels' values and their counts.
    let mut along = vec![(0f32, 0f32); w * h];
    along
        .par_chunks_mut(w)
        .zip(coord.par_chunks(w).zip(values.par_chunks(w)))
        .for_each(|(dst, (c, b))| {
            let term = |x: usize| {
                if c[x].is_finite() {
                    (b[x], 1.0)
                } else {
                    (0.0, 0.0)
                }
            };
            let (mut s, mut n) = (0f32, 0f32);
            for x in 0..reach.min(w) {
                let (v, k) = term(x);
                s += v;
                n += k;
            }
            for (x, d) in dst.iter_mut().enumerate() {
                if x + reach < w {
                    let (v, k) = term(x + reach);
                    s += v;
                    n += k;
                }
                if x > reach {
                    let (v, k) = term(x - reach - 1);
                    s -= v;
                    n -= k;
                }
                *d = (s, n);
            }
        });
    let mut out = vec![0f32; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, o)| {
        let (y0, y1) = (y.saturating_sub(radius), (y + radius + 1).min(h));
        for (x, v) in o.iter_mut().enumerate() {
            let (mut s, mut n) = (0f32, 0f32);
            for yy in y0..y1 {
                let (a, k) = along[yy * w + x];
                s += a;
                n += k;
            }
            if n > 0.0 {
                *v = s / n;
            }
        }
    });
    out
}

/// The edges' positions near one code cell: x = a + b·u + bend(u).
#[derive(Clone, Copy, Debug)]
struct LocalFit {
    a: f64,
    b: f64,
    bend: Bend,
}

impl LocalFit {
    /// The weighted least-squares line through `edges` after removing `bend` (the weights
    /// are the edges' reliabilities). `None` when degenerate or flat in x.
    fn line(edges: &[Edge], origin: f64, bend: Bend) -> Option<LocalFit> {
        let (mut s0, mut su, mut suu, mut sx, mut sux) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for ed in edges {
            let w = f64::from(ed.weight);
            let u = f64::from(ed.boundary) - origin;
            let x = f64::from(ed.x) - bend.value(u);
            s0 += w;
            su += w * u;
            suu += w * u * u;
            sx += w * x;
            sux += w * u * x;
        }
        let den = s0 * suu - su * su;
        if den.abs() < 1e-9 * s0 * s0 {
            return None;
        }
        let b = (s0 * sux - su * sx) / den;
        if b.abs() < 1e-6 {
            return None;
        }
        Some(LocalFit {
            a: (sx - b * su) / s0,
            b,
            bend,
        })
    }

    /// The continuous boundary coordinate u at camera position `x`: the root of
    /// a + b·u + bend(u) = x next to the line's, by two Newton steps.
    #[inline]
    fn at(&self, x: f64) -> f64 {
        let mut u = (x - self.a) / self.b;
        if self.bend.c.iter().any(|c| *c != 0.0) {
            for _ in 0..2 {
                let slope = self.b + self.bend.slope(u);
                if slope.abs() < 1e-6 {
                    break;
                }
                u -= (self.a + self.b * u + self.bend.value(u) - x) / slope;
            }
        }
        u
    }
}

/// Largest bend correction of one cell, projector pixels per code step (a 20 mm sphere needs
/// up to about a third of it near its rim).
const MAX_BEND: f32 = 0.15;

/// Edges on either side of a cell for its bend: enough for a quartic beyond the line's window.
fn wide_window(window: usize) -> usize {
    (2 * window + 2).max(4)
}

/// The bend's coefficients as fixed linear combinations of the edges' positions, for the usual
/// case of a whole window: `wide` consecutive boundaries on either side of the cell, equal
/// weights (a quartic least-squares fit is linear in the data). Saves building and solving the
/// normal equations for almost every cell.
#[derive(Clone, Debug)]
struct BendFilter {
    wide: usize,
    /// Per edge, in order of boundary from the lowest: its weight in each coefficient.
    weights: Vec<[f64; DEGREE - 1]>,
}

impl BendFilter {
    fn new(wide: usize) -> BendFilter {
        let n = 2 * wide;
        let u = |j: usize| j as f64 - wide as f64 + 0.5;
        let normal = nalgebra::SMatrix::<f64, { DEGREE + 1 }, { DEGREE + 1 }>::from_fn(|i, k| {
            (0..n).map(|j| u(j).powi((i + k) as i32)).sum()
        });
        let inverse = normal
            .try_inverse()
            .expect("the moments of distinct positions are invertible");
        let weights = (0..n)
            .map(|j| {
                let mut w = [0.0; DEGREE - 1];
                for (k, wk) in w.iter_mut().enumerate() {
                    *wk = (0..=DEGREE)
                        .map(|i| inverse[(k + 2, i)] * u(j).powi(i as i32))
                        .sum();
                }
                w
            })
            .collect();
        BendFilter { wide, weights }
    }

    /// The bend of `edges` around the cell whose centre is boundary `origin` − 0.5 … when they
    /// are its whole window (`None` otherwise).
    fn apply(&self, edges: &[Edge], origin: f64) -> Option<Bend> {
        if edges.len() != 2 * self.wide {
            return None;
        }
        let lowest = origin + 0.5 - self.wide as f64;
        let mut c = [0.0; DEGREE - 1];
        for ed in edges {
            let j = f64::from(ed.boundary) - lowest;
            let w = self.weights.get(j as usize).filter(|_| j >= 0.0)?;
            for (ck, wk) in c.iter_mut().zip(w) {
                *ck += wk * f64::from(ed.x);
            }
        }
        Some(Bend { c })
    }
}

/// Assign sub-pixel values to every run of equal code along the line from its edges.
fn fit_runs(
    line: Line,
    codes: &[i32],
    code: &Code,
    edges: &[Edge],
    out: &mut [f32],
    quality: &mut [f32],
    bend: &mut [f32],
) {
    let at = |n: usize| line.start + n * line.stride;
    // Edges on either side for the bend: enough for a quartic beyond the line's window.
    let wide = wide_window(code.window);
    let mut n = 0usize;
    let mut e_idx = 0usize;
    while n < line.len {
        let c = codes[at(n)];
        if c < 0 {
            n += 1;
            continue;
        }
        let a = n;
        while n + 1 < line.len && codes[at(n + 1)] == c {
            n += 1;
        }
        let e = n;
        n += 1;
        while e_idx < edges.len() && (edges[e_idx].gap as usize) + 1 < a {
            e_idx += 1;
        }
        let c = c as u32;
        let bounds = |edge: &Edge| edge.boundary == c || edge.boundary == c + 1;
        // The edge of the gap before `a` that bounds cell c (the last such), and the one after `e`.
        let left = if a > 0 {
            let k = edges[e_idx..]
                .iter()
                .take_while(|ed| ed.gap as usize == a - 1)
                .count();
            (e_idx..e_idx + k).rev().find(|&j| bounds(&edges[j]))
        } else {
            None
        };
        let mut r_idx = e_idx;
        while r_idx < edges.len() && (edges[r_idx].gap as usize) < e {
            r_idx += 1;
        }
        let right = edges[r_idx..]
            .iter()
            .take_while(|ed| ed.gap as usize == e)
            .position(bounds)
            .map(|k| r_idx + k);
        let (lo, hi) = (code.step * c as f32 - 0.5, code.step * (c + 1) as f32 - 0.5);
        // Narrow window (the line) and wide window (the curvature), as edge index ranges.
        let (first, last, wide_first, wide_last, q) = match (left, right) {
            (Some(l), Some(r))
                if edges[l].chain == edges[r].chain && edges[l].boundary != edges[r].boundary =>
            {
                (
                    widen_down(edges, l, code.window - 1),
                    widen_up(edges, r, code.window - 1),
                    widen_down(edges, l, wide - 1),
                    widen_up(edges, r, wide - 1),
                    1.0,
                )
            }
            (Some(l), _) => (
                widen_down(edges, l, code.window.max(2) - 1),
                l,
                widen_down(edges, l, 2 * wide - 1),
                l,
                0.5,
            ),
            (None, Some(r)) => (
                r,
                widen_up(edges, r, code.window.max(2) - 1),
                r,
                widen_up(edges, r, 2 * wide - 1),
                0.5,
            ),
            (None, None) => continue,
        };
        if last <= first || (q < 1.0 && !code.extrapolate) {
            continue;
        }
        let origin = f64::from(c) + 0.5;
        let narrow = &edges[first..=last];
        let Some(fit) = LocalFit::line(narrow, origin, Bend::default()) else {
            continue;
        };
        let bent_fit = code
            .bend
            .as_ref()
            .map(|filter| {
                let wide = &edges[wide_first..=wide_last];
                filter
                    .apply(wide, origin)
                    .unwrap_or_else(|| Bend::fit(wide, origin))
            })
            .filter(|b| b.c.iter().any(|c| *c != 0.0))
            .and_then(|b| LocalFit::line(narrow, origin, b));
        let value = |fit: &LocalFit, x: f64| code.step as f64 * (origin + fit.at(x)) - 0.5;
        // The bend's correction changes little across one run: taken at its middle.
        let middle = 0.5 * (a + e) as f64;
        let correction = bent_fit.map_or(0.0, |bent| {
            (value(&bent, middle) - value(&fit, middle)) as f32
        });
        // A larger bend is a kink or a step the chain did not break, not a curve.
        let correction = if correction.abs() <= MAX_BEND * code.step {
            correction
        } else {
            0.0
        };
        // A fitted value well outside the pixel's own code cell means the edges and the code
        // disagree (a mixed pixel): reject rather than clamp.
        let tol = code.cell_tolerance * code.step;
        for m in a..=e {
            let v = value(&fit, m as f64) as f32;
            if v >= lo - tol && v <= hi + tol {
                out[m] = v.clamp(lo, hi);
                quality[m] = q;
                bend[m] = correction;
            }
        }
    }
}

/// Index of the edge up to `k` edges before `i` in the same chain.
fn widen_down(edges: &[Edge], i: usize, k: usize) -> usize {
    let mut j = i;
    while j > 0 && i - j < k && edges[j - 1].chain == edges[i].chain {
        j -= 1;
    }
    j
}

/// Index of the edge up to `k` edges after `i` in the same chain.
fn widen_up(edges: &[Edge], i: usize, k: usize) -> usize {
    let mut j = i;
    while j + 1 < edges.len() && j - i < k && edges[j + 1].chain == edges[i].chain {
        j += 1;
    }
    j
}

/// Locate the sub-pixel boundaries in the gap between pixel `i0` (position `n` on its line)
/// and the next pixel `i1`, and continue or break the line's chain.
#[allow(clippy::too_many_arguments)]
#[inline]
fn gap_edges<T: Sample>(
    i0: usize,
    i1: usize,
    n: usize,
    codes: &[i32],
    signal: &Signal<'_, T>,
    code: &Code,
    state: &mut ChainState,
    edges: &mut Vec<Edge>,
) {
    let (c0, c1) = (codes[i0], codes[i1]);
    if c0 < 0 || c1 < 0 {
        state.broken = true;
        return;
    }
    if c0 == c1 {
        return;
    }
    let (lo, hi) = (c0.min(c1) as u32, c0.max(c1) as u32);
    if hi - lo > code.max_jump {
        state.broken = true;
        return;
    }
    let differs = binary_to_gray(c0 as u32) ^ binary_to_gray(c1 as u32);
    let increasing = c1 > c0;
    let (k0, k1) = (signal.contrast(i0), signal.contrast(i1));
    let (r0, r1) = (1.0 / k0, 1.0 / k1);
    let ratio = k0.min(k1) * r0.min(r1);
    let mut weight = 1.0f32;
    for _ in 0..code.albedo_power {
        weight *= ratio;
    }
    let weight = weight.max(1e-4);
    let first = edges.len();
    for b in lo + 1..=hi {
        let k = flipped_bit(b);
        if (differs >> k) & 1 == 0 || k >= code.bits {
            continue;
        }
        let j = (code.bits - 1 - k) as usize;
        let (s0, s1) = (signal.normalized(j, i0, r0), signal.normalized(j, i1, r1));
        let den = s0 - s1;
        if den == 0.0 {
            continue;
        }
        let t = s0 / den;
        if (0.0..=1.0).contains(&t) {
            edges.push(Edge {
                slope: den.abs(),
                gap: n as u32,
                x: n as f32 + t,
                boundary: b,
                chain: 0,
                weight,
            });
        }
    }
    if edges.len() == first {
        state.broken = true;
        return;
    }
    let run = &mut edges[first..];
    if run.len() > 1 {
        // Several boundaries in one gap come out in the order of their codes, monotonic in x.
        run.sort_by(|p, q| {
            if increasing {
                p.boundary.cmp(&q.boundary)
            } else {
                q.boundary.cmp(&p.boundary)
            }
        });
        for i in 1..run.len() {
            if run[i].x < run[i - 1].x {
                let mid = 0.5 * (run[i].x + run[i - 1].x);
                run[i].x = mid;
                run[i - 1].x = mid;
            }
        }
    }
    let dir = if increasing { 1 } else { -1 };
    let continues = state.started && !state.broken && first > 0 && dir == state.direction && {
        let prev = i64::from(edges[first - 1].boundary);
        i64::from(edges[first].boundary) - prev == dir
    };
    if !continues {
        state.chain += 1;
    }
    state.direction = dir;
    state.broken = false;
    state.started = true;
    for ed in &mut edges[first..] {
        ed.chain = state.chain;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Edges of a cell's whole window (boundaries c+1−wide ..= c+wide) on the curve
    /// x = 100 + 1.3 u + 0.02 u² − 0.004 u³ + 0.0007 u⁴, in the order a decreasing chain gives.
    fn curved_window(c: u32, wide: usize) -> Vec<Edge> {
        let origin = f64::from(c) + 0.5;
        (c + 1 - wide as u32..=c + wide as u32)
            .rev()
            .map(|b| {
                let u = f64::from(b) - origin;
                let x = 100.0 + 1.3 * u + 0.02 * u * u - 0.004 * u.powi(3) + 0.0007 * u.powi(4);
                Edge {
                    gap: 0,
                    x: x as f32,
                    boundary: b,
                    chain: 1,
                    weight: 1.0,
                    slope: 1.0,
                }
            })
            .collect()
    }

    #[test]
    fn the_bend_filter_is_the_quartic_fit_of_a_whole_window() {
        let wide = wide_window(3);
        let edges = curved_window(40, wide);
        let origin = 40.5;
        let fitted = Bend::fit(&edges, origin);
        let filtered = BendFilter::new(wide).apply(&edges, origin).expect("whole");
        for (f, g) in fitted.c.iter().zip(&filtered.c) {
            assert!((f - g).abs() < 1e-6, "{fitted:?} vs {filtered:?}");
        }
        assert!((fitted.c[0] - 0.02).abs() < 1e-4 && (fitted.c[2] - 0.0007).abs() < 1e-5);
        // A window short of an edge is not whole.
        assert!(BendFilter::new(wide).apply(&edges[1..], origin).is_none());
    }

    #[test]
    fn a_pixel_on_a_bent_run_gets_the_curve_s_coordinate() {
        let wide = wide_window(3);
        let edges = curved_window(40, wide);
        let origin = 40.5;
        let narrow: Vec<Edge> = edges
            .iter()
            .copied()
            .filter(|e| (f64::from(e.boundary) - origin).abs() < 3.0)
            .collect();
        let straight = LocalFit::line(&narrow, origin, Bend::default()).expect("line");
        let bent = LocalFit::line(&narrow, origin, Bend::fit(&edges, origin)).expect("line");
        // The camera position of u = 0.2 on the curve.
        let u = 0.2f64;
        let x = 100.0 + 1.3 * u + 0.02 * u * u - 0.004 * u.powi(3) + 0.0007 * u.powi(4);
        assert!((bent.at(x) - u).abs() < 1e-4, "bent {}", bent.at(x));
        assert!(
            (straight.at(x) - u).abs() > 0.03,
            "the straight line is biased"
        );
    }

    #[test]
    fn worked_examples_of_eq_4_17() {
        // (pattern, inverse) at n and (pattern, inverse) at n+1, from Ch. 4.5.
        let cases = [
            (899.0, 61.0, 34.0, 29.0, 64.0, 899.4),
            (899.0, 80.0, 28.0, 25.0, 62.0, 899.6),
            (1293.0, 133.0, 80.0, 83.0, 141.0, 1293.5),
        ];
        for (n, a, b, d, c, want) in cases {
            let x = edge_position(n, a, b, c, d).expect("crossing");
            assert!((x - want).abs() < 0.05, "got {x}, text says {want}");
        }
        assert_eq!(
            edge_position(10.0, 50.0, 20.0, 20.0, 50.0),
            None,
            "no crossing"
        );
    }
}
