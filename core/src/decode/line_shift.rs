//! Pass 2 of decoding: Gray-code line shifting to sub-pixel projector coordinates (Ch. 4.4.4).

use rayon::prelude::*;

use super::ScanDirection;

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
}

/// Columns handled together when scanning down columns, so frame reads stay row-major.
const BLOCK: usize = 64;

/// Continuous projector coordinate per pixel (NaN where invalid) and a quality factor (1 where
/// interpolated between edges, 0.5 where extrapolated from one side, 0 where invalid).
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
) -> (Vec<f32>, Vec<f32>) {
    let code = Code {
        bits,
        step: step as f32,
        max_jump: params.max_jump,
        window: params.edge_window.max(1),
        extrapolate: params.extrapolate,
        cell_tolerance: params.cell_tolerance,
        albedo_power: params.albedo_weight_power,
    };
    let mut coord = vec![f32::NAN; w * h];
    let mut quality = vec![0f32; w * h];
    match dir {
        ScanDirection::AlongRows => {
            coord
                .par_chunks_mut(w)
                .zip(quality.par_chunks_mut(w))
                .enumerate()
                .for_each_init(
                    || (Vec::new(), Vec::new()),
                    |(edges, prefix), (y, (out, q))| {
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
                        fit_runs(line, codes, &code, edges, prefix, out, q);
                    },
                );
        }
        ScanDirection::AlongColumns => {
            // Phase 2 reads each column's codes contiguously from a transposed copy.
            let codes_t = super::transpose(codes, w, h);
            coord
                .par_chunks_mut(BLOCK * h)
                .zip(quality.par_chunks_mut(BLOCK * h))
                .enumerate()
                .for_each_init(
                    || {
                        (
                            vec![Vec::new(); BLOCK],
                            vec![ChainState::default(); BLOCK],
                            Vec::new(),
                        )
                    },
                    |(edges, chains, prefix), (b, (out, q))| {
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
                                prefix,
                                &mut out[x * h..(x + 1) * h],
                                &mut q[x * h..(x + 1) * h],
                            );
                        }
                    },
                );
        }
    }
    (coord, quality)
}

/// Chain bookkeeping of one line while its gaps are visited in order.
#[derive(Clone, Copy, Debug, Default)]
struct ChainState {
    chain: u32,
    broken: bool,
    direction: i64,
    started: bool,
}

/// Weighted moments of the edges, for line fits over any window in O(1).
#[derive(Clone, Copy, Debug, Default)]
struct Moments {
    w: f64,
    p: f64,
    x: f64,
    pp: f64,
    px: f64,
}

impl Moments {
    /// Weighted least-squares line x = α + β P through the edges whose moments these are
    /// (P = step·boundary − 0.5; the noise is in x). `None` when degenerate.
    #[inline]
    fn line(&self, step: f32) -> Option<(f32, f32)> {
        let den = self.w * self.pp - self.p * self.p;
        if den.abs() < 1e-9 * self.w * self.w {
            return None;
        }
        let b = (self.w * self.px - self.p * self.x) / den; // camera pixels per code cell
        let a = (self.x - b * self.p) / self.w; // x at boundary 0
        if b.abs() < 1e-6 {
            return None;
        }
        // x = a + b B and P = step·B − 0.5  ⇒  x = α + β P.
        let beta = b / f64::from(step);
        Some(((a + 0.5 * beta) as f32, beta as f32))
    }
}

/// Assign sub-pixel values to every run of equal code along the line from its edges.
fn fit_runs(
    line: Line,
    codes: &[i32],
    code: &Code,
    edges: &[Edge],
    prefix: &mut Vec<Moments>,
    out: &mut [f32],
    quality: &mut [f32],
) {
    // Prefix sums of the edges' weighted moments (f64: absolute coordinates on long lines).
    prefix.clear();
    prefix.push(Moments::default());
    let mut acc = Moments::default();
    for ed in edges {
        let (w, p, x) = (
            f64::from(ed.weight),
            f64::from(ed.boundary),
            f64::from(ed.x),
        );
        acc.w += w;
        acc.p += w * p;
        acc.x += w * x;
        acc.pp += w * p * p;
        acc.px += w * p * x;
        prefix.push(acc);
    }
    let window = |first: usize, last: usize| {
        let (a, b) = (&prefix[first], &prefix[last + 1]);
        Moments {
            w: b.w - a.w,
            p: b.p - a.p,
            x: b.x - a.x,
            pp: b.pp - a.pp,
            px: b.px - a.px,
        }
    };
    let at = |n: usize| line.start + n * line.stride;
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
        let (first, last, q) = match (left, right) {
            (Some(l), Some(r))
                if edges[l].chain == edges[r].chain && edges[l].boundary != edges[r].boundary =>
            {
                (
                    widen_down(edges, l, code.window - 1),
                    widen_up(edges, r, code.window - 1),
                    1.0,
                )
            }
            (Some(l), _) => (widen_down(edges, l, code.window.max(2) - 1), l, 0.5),
            (None, Some(r)) => (r, widen_up(edges, r, code.window.max(2) - 1), 0.5),
            (None, None) => continue,
        };
        if last <= first || (q < 1.0 && !code.extrapolate) {
            continue;
        }
        let Some((alpha, beta)) = window(first, last).line(code.step) else {
            continue;
        };
        // A fitted value well outside the pixel's own code cell means the edges and the code
        // disagree (a mixed pixel): reject rather than clamp.
        let tol = code.cell_tolerance * code.step;
        let inv_beta = 1.0 / beta;
        for m in a..=e {
            let v = (m as f32 - alpha) * inv_beta;
            if v >= lo - tol && v <= hi + tol {
                out[m] = v.clamp(lo, hi);
                quality[m] = q;
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
