//! Gray-code decoding (SPEC §5): camera pixel → continuous projector column (and row).
//!
//! Two passes, both data-parallel over image lines:
//! 1. `binarize`: dual-projection binarization (or a mid-level threshold when the capture has
//!    no inverses), Gray → binary, validity by contrast. Gives an integer code cell per pixel.
//! 2. `line_shift`: along each camera line crossing the stripes, every boundary between code
//!    cells is located to sub-pixel precision where pattern and inverse cross (Eq. 4.17), and each
//!    valid pixel's projector coordinate is interpolated between the edges around it.
//!
//! Sub-pixel convention: code cell `i` covers projector pixels `[step*i, step*i + step - 1]`; the
//! boundary between cells `i-1` and `i` lies at projector coordinate `step*i - 0.5`. A decoded
//! value is therefore in the same pixel-centre convention as the camera (SPEC §2).

mod binarize;
mod line_shift;

pub use line_shift::edge_position;

use std::path::Path;

use rayon::prelude::*;

use crate::capture::CaptureSet;
use crate::image::{Pixels, Sample};
use crate::io::npy;
use crate::pattern::{CodeAxis, CodeLayout, Pattern};
use crate::{Error, Result};

/// Thresholds of the decoder, in 8-bit grey levels (scaled by 257 for 16-bit captures).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DecodeParams {
    /// A pixel is valid only where white − black exceeds this.
    pub contrast_threshold: f32,
    /// A bit is undecidable where |pattern − inverse| ≤ this. 0 decides by sign alone: a pixel
    /// that straddles an edge then takes the code of one side, and line shifting places it.
    pub bit_threshold: f32,
    /// Largest code jump between neighbouring pixels still bridged by sub-pixel edges; larger
    /// jumps are depth discontinuities.
    pub max_jump: u32,
    /// Edges used on each side of a pixel for its local line fit (1 = interpolate between the
    /// two nearest edges; more averages decoding noise and the crossing bias on smooth surfaces).
    pub edge_window: usize,
    /// A pixel whose coordinate differs by more than this many code cells from both neighbours
    /// across the scan direction is a mixed pixel at a depth edge and is rejected.
    pub consistency_cells: f32,
    /// Whether a pixel with a sub-pixel edge on one side only (next to a shadow, an invalid
    /// pixel or a discontinuity) is extrapolated; such pixels are often mixed, so off by default.
    pub extrapolate: bool,
    /// How far (in code cells) a fitted coordinate may fall outside the pixel's own code cell
    /// before the pixel is rejected as inconsistent.
    pub cell_tolerance: f32,
    /// Valid pixels within this many pixels of an invalid one, across the scan direction, are
    /// dropped: the footprints of pixels on a depth edge or shadow border mix two surfaces.
    pub edge_erosion: u32,
    /// Average each coordinate with its two neighbours across the scan direction ([1, 2, 1]),
    /// where both are valid and consistent: line shifting on neighbouring camera lines gives
    /// independent estimates, and a symmetric kernel leaves linear trends (slopes) untouched.
    pub cross_smoothing: bool,
    /// Power of the contrast ratio of an edge's two pixels used as its weight in the line fit
    /// (0 = all edges equal). Crossings beside albedo edges are biased; this discounts them.
    pub albedo_weight_power: u32,
    /// Remove the line fit's curvature bias on curved regions (a quartic through the edges
    /// beyond the line's window; see `line_shift::add_bend`). Off, a sphere's surface reads
    /// about 0.1 mm inside at the default window.
    pub bend_correction: bool,
    /// Remove the crossing's phase bias: each edge solved through a model of the blurred,
    /// pixel-integrated step whose blur each capture measures (`line_shift::crossing_model`;
    /// the phase's harmonics, `line_shift::phase_bias`, where it cannot). Off, the coordinates
    /// carry a moiré of the camera's and the projector's pixel grids of 0.01–0.02 projector
    /// pixels on flats and ±0.05 on small spheres.
    pub phase_correction: bool,
}

impl Default for DecodeParams {
    fn default() -> Self {
        DecodeParams {
            contrast_threshold: 12.0,
            bit_threshold: 0.0,
            max_jump: 2,
            edge_window: 3,
            consistency_cells: 3.0,
            extrapolate: false,
            cell_tolerance: 0.25,
            edge_erosion: 1,
            cross_smoothing: true,
            albedo_weight_power: 4,
            bend_correction: true,
            phase_correction: true,
        }
    }
}

/// How bits were decided.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Binarization {
    /// Pattern against its inverse (robust).
    Dual,
    /// Pattern against the mid level of white and black (no inverses; lower quality).
    Threshold,
}

/// The direction along which a code's stripes are crossed in the camera image.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ScanDirection {
    /// Along camera rows (stripes roughly vertical in the image).
    AlongRows,
    /// Along camera columns (stripes roughly horizontal in the image).
    AlongColumns,
}

/// Decoded correspondence maps of one capture.
#[derive(Clone, Debug)]
pub struct Decoded {
    /// Camera width.
    pub width: u32,
    /// Camera height.
    pub height: u32,
    /// Projector code layout.
    pub layout: CodeLayout,
    /// Continuous projector column per camera pixel, NaN where invalid.
    pub col: Vec<f32>,
    /// Continuous projector row per camera pixel, when the capture has row codes.
    pub row: Option<Vec<f32>>,
    /// Per-pixel confidence in [0, 1]: (white − black) relative to full scale, halved without
    /// inverses, halved again where the coordinate was extrapolated from one edge. 0 = invalid.
    pub confidence: Vec<f32>,
    /// How the column bits were decided.
    pub binarization: Binarization,
}

impl Decoded {
    /// Number of pixels with a valid column.
    pub fn valid_count(&self) -> usize {
        self.col.iter().filter(|v| v.is_finite()).count()
    }

    /// The map along `axis`.
    pub fn map(&self, axis: CodeAxis) -> Option<&[f32]> {
        match axis {
            CodeAxis::Column => Some(&self.col),
            CodeAxis::Row => self.row.as_deref(),
        }
    }

    /// Write `col.npy`, `row.npy` (if any), `confidence.npy` and `decoded.png` (false colour:
    /// hue from column, brightness from row stripes, black where invalid) into `dir`.
    pub fn save(&self, dir: &Path) -> Result<()> {
        crate::io::create_dir(dir)?;
        let shape = [self.height as usize, self.width as usize];
        npy::write(&dir.join("col.npy"), &shape, &self.col)?;
        if let Some(row) = &self.row {
            npy::write(&dir.join("row.npy"), &shape, row)?;
        }
        npy::write(&dir.join("confidence.npy"), &shape, &self.confidence)?;
        let rgb = self.false_colour();
        crate::image::save_rgb_png(&dir.join("decoded.png"), self.width, self.height, &rgb)
    }

    /// False-colour rendering of the maps (RGB8): hue encodes the column, a gentle modulation
    /// encodes the row, invalid pixels are black.
    pub fn false_colour(&self) -> Vec<u8> {
        let w = self.layout.width.max(1) as f32;
        let h = self.layout.height.max(1) as f32;
        let mut rgb = vec![0u8; self.col.len() * 3];
        rgb.par_chunks_mut(3).enumerate().for_each(|(i, px)| {
            let c = self.col[i];
            if !c.is_finite() {
                return;
            }
            let value = match &self.row {
                Some(r) if r[i].is_finite() => {
                    0.75 + 0.25 * ((r[i] / h) * 16.0 * std::f32::consts::TAU).cos()
                }
                _ => 1.0,
            };
            px.copy_from_slice(&hue_to_rgb(c / w, value));
        });
        rgb
    }
}

/// Map t in [0, 1] to a rainbow colour (blue → red) with brightness `value`.
pub fn hue_to_rgb(t: f32, value: f32) -> [u8; 3] {
    let h = (1.0 - t.clamp(0.0, 1.0)) * 240.0 / 60.0;
    let x = 1.0 - ((h % 2.0) - 1.0).abs();
    let (r, g, b) = match h as u32 {
        0 => (1.0, x, 0.0),
        1 => (x, 1.0, 0.0),
        2 => (0.0, 1.0, x),
        3 => (0.0, x, 1.0),
        _ => (x, 0.0, 1.0),
    };
    let v = value.clamp(0.0, 1.0) * 255.0;
    [(r * v) as u8, (g * v) as u8, (b * v) as u8]
}

/// The frames of one code axis: patterns and inverses (if any), most significant bit first.
struct AxisFrames<'a, T> {
    pat: Vec<&'a [T]>,
    inv: Option<Vec<&'a [T]>>,
}

/// The frames of one capture as borrowed sample planes of one type.
struct Planes<'a, T> {
    white: &'a [T],
    black: &'a [T],
    col: AxisFrames<'a, T>,
    row: Option<AxisFrames<'a, T>>,
}

/// Decode a capture set into continuous projector coordinates.
pub fn decode(capture: &CaptureSet, params: &DecodeParams) -> Result<Decoded> {
    let need = |p: Pattern| {
        capture
            .frame(p)
            .ok_or_else(|| Error::Insufficient(format!("capture has no `{}` frame", p.name())))
    };
    need(Pattern::White)?;
    need(Pattern::Black)?;
    if !capture.has_code(CodeAxis::Column) {
        return Err(Error::Insufficient(
            "capture has no complete column code".into(),
        ));
    }
    let all_u8 = capture
        .frames
        .values()
        .all(|f| matches!(f.pixels, Pixels::U8(_)));
    if all_u8 {
        let planes = borrow_planes(capture, |p| match capture.frame(p).map(|f| &f.pixels) {
            Some(Pixels::U8(v)) => Some(v.as_slice()),
            _ => None,
        })?;
        Ok(decode_planes(capture, &planes, params, 1.0))
    } else {
        // Mixed or 16-bit: widen everything to 16 bit once.
        let widened: std::collections::BTreeMap<Pattern, Vec<u16>> = capture
            .frames
            .par_iter()
            .map(|(p, img)| (*p, img.to_u16()))
            .collect();
        let planes = borrow_planes(capture, |p| widened.get(&p).map(|v| v.as_slice()))?;
        Ok(decode_planes(capture, &planes, params, 257.0))
    }
}

fn borrow_planes<'a, T>(
    capture: &'a CaptureSet,
    get: impl Fn(Pattern) -> Option<&'a [T]>,
) -> Result<Planes<'a, T>> {
    let plane = |p: Pattern| -> Result<&'a [T]> {
        get(p).ok_or_else(|| {
            Error::Insufficient(format!("capture has no usable `{}` frame", p.name()))
        })
    };
    let axis_planes = |axis: CodeAxis| -> Result<AxisFrames<'a, T>> {
        let n = capture.layout.bits(axis);
        let pat = (0..n)
            .map(|bit| {
                plane(Pattern::Gray {
                    axis,
                    bit,
                    inverse: false,
                })
            })
            .collect::<Result<Vec<_>>>()?;
        let inv = if capture.has_inverses(axis) {
            Some(
                (0..n)
                    .map(|bit| {
                        plane(Pattern::Gray {
                            axis,
                            bit,
                            inverse: true,
                        })
                    })
                    .collect::<Result<Vec<_>>>()?,
            )
        } else {
            None
        };
        Ok(AxisFrames { pat, inv })
    };
    Ok(Planes {
        white: plane(Pattern::White)?,
        black: plane(Pattern::Black)?,
        col: axis_planes(CodeAxis::Column)?,
        row: if capture.has_code(CodeAxis::Row) {
            Some(axis_planes(CodeAxis::Row)?)
        } else {
            None
        },
    })
}

fn decode_planes<T: Sample>(
    capture: &CaptureSet,
    planes: &Planes<'_, T>,
    params: &DecodeParams,
    scale: f32,
) -> Decoded {
    let (w, h) = (capture.width as usize, capture.height as usize);
    let full_scale = 255.0 * scale;
    let thresholds = binarize::Thresholds {
        contrast: (params.contrast_threshold * scale).round() as i32,
        bit: (params.bit_threshold * scale).round() as i32,
    };
    let layout = capture.layout;
    let run_axis =
        |axis: CodeAxis, frames: &AxisFrames<'_, T>| -> (Vec<f32>, Vec<f32>, Binarization) {
            let t0 = std::time::Instant::now();
            let codes = binarize::codes(
                w,
                h,
                planes.white,
                planes.black,
                &frames.pat,
                frames.inv.as_deref(),
                layout.cells(axis),
                thresholds,
            );
            let t_bin = t0.elapsed();
            let dir = scan_direction(w, h, &codes);
            let tolerance = params.consistency_cells * layout.step(axis) as f32;
            let bin = if frames.inv.is_some() {
                Binarization::Dual
            } else {
                Binarization::Threshold
            };
            let signal = line_shift::Signal {
                white: planes.white,
                black: planes.black,
                pat: &frames.pat,
                inv: frames.inv.as_deref(),
            };
            let (mut coord, quality, bend) = line_shift::subpixel(
                w,
                h,
                &codes,
                &signal,
                dir,
                layout.bits(axis),
                layout.step(axis),
                params,
            );
            let t_sub = t0.elapsed();
            // The filters look across the scan as rows; a column scan comes back transposed.
            let (lw, lh) = if dir == ScanDirection::AlongRows {
                (w, h)
            } else {
                (h, w)
            };
            if params.bend_correction {
                line_shift::add_bend(lw, lh, &mut coord, &bend);
            }
            let coord = filter_across(lw, lh, &coord, tolerance, params);
            let t_filter = t0.elapsed();
            let need_quality = axis == CodeAxis::Column;
            let (coord, quality) = match dir {
                ScanDirection::AlongRows => (coord, quality),
                ScanDirection::AlongColumns => (
                    transpose(&coord, h, w),
                    if need_quality {
                        transpose(&quality, h, w)
                    } else {
                        Vec::new()
                    },
                ),
            };
            let ms = |d: std::time::Duration| d.as_secs_f64() * 1e3;
            tracing::debug!(
                ?axis,
                ?dir,
                binarize_ms = ms(t_bin),
                line_shift_ms = ms(t_sub - t_bin),
                filters_ms = ms(t_filter - t_sub),
                total_ms = ms(t0.elapsed()),
                "axis decoded"
            );
            (coord, quality, bin)
        };
    // The two axes are independent: run them side by side so neither leaves a core idle.
    let ((col, quality, binarization), row) = rayon::join(
        || run_axis(CodeAxis::Column, &planes.col),
        || planes.row.as_ref().map(|f| run_axis(CodeAxis::Row, f).0),
    );
    let mode_factor = if binarization == Binarization::Dual {
        1.0
    } else {
        0.5
    };
    let mut confidence = vec![0f32; w * h];
    confidence.par_iter_mut().enumerate().for_each(|(i, c)| {
        if col[i].is_finite() {
            let contrast = planes.white[i].to_i32() - planes.black[i].to_i32();
            *c = (contrast as f32 / full_scale).clamp(0.0, 1.0) * mode_factor * quality[i];
        }
    });
    tracing::debug!(
        valid = col.iter().filter(|v| v.is_finite()).count(),
        total = w * h,
        "decoded"
    );
    Decoded {
        width: capture.width,
        height: capture.height,
        layout,
        col,
        row,
        confidence,
        binarization,
    }
}

/// Blocked parallel transpose of a row-major (w × h) image into a row-major (h × w) one.
pub(crate) fn transpose<T: Copy + Send + Sync + Default>(src: &[T], w: usize, h: usize) -> Vec<T> {
    const B: usize = 32;
    let mut out = vec![T::default(); w * h];
    out.par_chunks_mut(B * h)
        .enumerate()
        .for_each(|(bx, block)| {
            let x0 = bx * B;
            let bw = block.len() / h;
            for y0 in (0..h).step_by(B) {
                for y in y0..(y0 + B).min(h) {
                    let row = &src[y * w + x0..y * w + x0 + bw];
                    for (dx, &v) in row.iter().enumerate() {
                        block[dx * h + y] = v;
                    }
                }
            }
        });
    out
}

/// Rows per task of the fused filter pass.
const BAND: usize = 32;

/// The depth-edge filters across the scan (which runs along rows), fused into one banded pass:
///
/// 1. *reject*: a pixel whose coordinate jumps by more than `tolerance` to a valid neighbour
///    across the scan, or that has no valid neighbour there to agree with, mixes two surfaces
///    (a depth edge running along the scan; jumps along it already break line shifting's chains);
/// 2. *erode* (`edge_erosion` times): pixels next to an invalid one across the scan are dropped,
///    since footprints on depth edges and shadow borders mix two surfaces;
/// 3. *smooth* (`cross_smoothing`): [1, 2, 1] across the scan where both neighbours are valid
///    and within `tolerance`; line shifting on neighbouring lines gives independent estimates and
///    the symmetric kernel leaves slopes untouched. No one-sided averaging (it would bias).
///
/// Output row y depends on input rows y ± (2 + erosion), so each band reads a few extra rows
/// and nothing is copied whole.
fn filter_across(
    w: usize,
    h: usize,
    coord: &[f32],
    tolerance: f32,
    params: &DecodeParams,
) -> Vec<f32> {
    let erosion = params.edge_erosion as usize;
    // Rows beyond a band read for validity: the smoothing's reach plus the erosion's.
    let halo = 1 + SMOOTH_REACH + erosion;
    let nan_row = vec![f32::NAN; w];
    // Rows beyond the image read as invalid (NaN), which neither agree nor jump.
    let row = |y: isize| -> &[f32] {
        if y < 0 || y as usize >= h {
            &nan_row
        } else {
            &coord[y as usize * w..(y as usize + 1) * w]
        }
    };
    let mut out = vec![0f32; w * h];
    out.par_chunks_mut(BAND * w).enumerate().for_each_init(
        || (Vec::<bool>::new(), Vec::<bool>::new()),
        |(keep, next), (band, dst)| {
            dst.fill(f32::NAN);
            let y0 = band * BAND;
            let y1 = (y0 + dst.len() / w).min(h);
            // Rows lo..hi of validity after `reject` (branch-free, vectorisable).
            let lo = y0.saturating_sub(halo - 1);
            let hi = (y1 + halo - 1).min(h);
            keep.clear();
            keep.resize((hi - lo) * w, false);
            for y in lo..hi {
                let (above, cur, below) =
                    (row(y as isize - 1), row(y as isize), row(y as isize + 1));
                let k = &mut keep[(y - lo) * w..(y - lo + 1) * w];
                for (k, ((&v, &a), &b)) in k.iter_mut().zip(cur.iter().zip(above).zip(below)) {
                    // NaN compares false: a missing neighbour is neither close nor a jump.
                    let (close_a, close_b) =
                        ((a - v).abs() <= tolerance, (b - v).abs() <= tolerance);
                    let (jump_a, jump_b) = (a.is_finite() & !close_a, b.is_finite() & !close_b);
                    *k = (close_a | close_b) & !jump_a & !jump_b;
                }
            }
            // Erosion shrinks the range of correct rows by one per step; neighbours outside
            // the image (or outside the rows computed here, which this band does not write)
            // do not erode.
            let (mut vlo, mut vhi) = (lo, hi);
            for _ in 0..erosion {
                next.clear();
                next.extend_from_slice(keep);
                for y in vlo..vhi {
                    let r = (y - lo) * w;
                    let cur = &mut next[r..r + w];
                    if y > vlo {
                        for (c, &u) in cur.iter_mut().zip(&keep[r - w..r]) {
                            *c &= u;
                        }
                    }
                    if y + 1 < vhi {
                        for (c, &d) in cur.iter_mut().zip(&keep[r + w..r + 2 * w]) {
                            *c &= d;
                        }
                    }
                }
                std::mem::swap(keep, next);
                if vlo > 0 {
                    vlo += 1;
                }
                if vhi < h {
                    vhi -= 1;
                }
            }
            let kept = |y: usize| &keep[(y - lo) * w..(y - lo + 1) * w];
            for y in y0..y1 {
                let d = &mut dst[(y - y0) * w..(y - y0 + 1) * w];
                let cur = row(y as isize);
                for ((d, &v), &k) in d.iter_mut().zip(cur).zip(kept(y)) {
                    if k {
                        *d = v;
                    }
                }
                if params.cross_smoothing {
                    smooth_across(d, y, h, tolerance, coord, keep, lo);
                }
            }
        },
    );
    out
}

/// Rows on either side that [`smooth_across`] reads.
const SMOOTH_REACH: usize = 3;

/// Average each kept coordinate of row `y` (in `d`) with its neighbours across the scan by a
/// quadratic least-squares (Savitzky–Golay) fit over 7 lines, or 5 where the outer lines are
/// missing or do not fit; left alone otherwise. Every line used must be kept, within
/// `tolerance` of the pixel's own coordinate, and within a twelfth of it (a quarter of a code
/// cell at the default) of the fitted parabola: lines from across a depth edge are not.
///
/// Line shifting on neighbouring camera lines gives independent estimates, but across a
/// curved surface the coordinate curves too: the [1, 2, 1] average moves it by a quarter of
/// its second difference (0.01 mm inwards on a 40 mm sphere at 1.6 m). A quadratic fit leaves
/// curvature untouched and, over 7 lines, still divides the noise by 1.7.
fn smooth_across(
    d: &mut [f32],
    y: usize,
    h: usize,
    tolerance: f32,
    coord: &[f32],
    keep: &[bool],
    keep_first_row: usize,
) {
    let w = d.len();
    let reach = |k: usize| y >= k && y + k < h;
    if !reach(2) {
        return;
    }
    let row = |y: usize| &coord[y * w..(y + 1) * w];
    let kept = |y: usize| &keep[(y - keep_first_row) * w..(y - keep_first_row + 1) * w];
    let lines = |k: usize| (row(y - k), row(y + k), kept(y - k), kept(y + k));
    let (cur, k0) = (row(y), kept(y));
    let (a1, b1, ka1, kb1) = lines(1);
    let (a2, b2, ka2, kb2) = lines(2);
    let l3 = reach(3).then(|| lines(3));
    let misfit = tolerance / 12.0;
    for x in 0..w {
        let v = cur[x];
        if !k0[x] {
            continue;
        }
        let ok = |a: &[f32], b: &[f32], ka: &[bool], kb: &[bool]| {
            ka[x] && kb[x] && (a[x] - v).abs() <= tolerance && (b[x] - v).abs() <= tolerance
        };
        if !(ok(a1, b1, ka1, kb1) && ok(a2, b2, ka2, kb2)) {
            continue;
        }
        let five = [a2[x], a1[x], v, b1[x], b2[x]];
        let seven = l3
            .filter(|(a3, b3, ka3, kb3)| ok(a3, b3, ka3, kb3))
            .map(|(a3, b3, _, _)| [a3[x], a2[x], a1[x], v, b1[x], b2[x], b3[x]]);
        if let Some(c) = seven.as_ref().and_then(|t| parabola_centre(t, misfit)) {
            d[x] = c;
        } else if let Some(c) = parabola_centre(&five, misfit) {
            d[x] = c;
        }
    }
}

/// The centre value of the least-squares parabola through `taps` (an odd count at offsets
/// −n..=n, n = 2 or 3), or `None` when a tap lies farther than `misfit` from it.
fn parabola_centre(taps: &[f32], misfit: f32) -> Option<f32> {
    let n = (taps.len() / 2) as f32;
    let (mut s0, mut s1, mut s2) = (0f32, 0f32, 0f32);
    for (i, &t) in taps.iter().enumerate() {
        let k = i as f32 - n;
        s0 += t;
        s1 += k * t;
        s2 += k * k * t;
    }
    // Normal equations of c0 + c1 k + c2 k² over symmetric offsets: Σk, Σk³ vanish.
    let m = taps.len() as f32;
    let (k2, k4) = if taps.len() == 7 {
        (28.0, 196.0)
    } else {
        (10.0, 34.0)
    };
    let det = m * k4 - k2 * k2;
    let c0 = (k4 * s0 - k2 * s2) / det;
    let c2 = (m * s2 - k2 * s0) / det;
    let c1 = s1 / k2;
    taps.iter()
        .enumerate()
        .all(|(i, &t)| {
            let k = i as f32 - n;
            (t - (c0 + c1 * k + c2 * k * k)).abs() <= misfit
        })
        .then_some(c0)
}

/// Choose the camera direction that crosses the stripes of a code: the one along which the code
/// changes more often (sampled on every 8th line).
fn scan_direction(w: usize, h: usize, codes: &[i32]) -> ScanDirection {
    let mut along_rows = 0usize;
    let mut along_cols = 0usize;
    for y in (0..h.saturating_sub(1)).step_by(8) {
        for x in 0..w - 1 {
            let a = codes[y * w + x];
            if a >= 0 {
                let r = codes[y * w + x + 1];
                let d = codes[(y + 1) * w + x];
                along_rows += usize::from(r >= 0 && r != a);
                along_cols += usize::from(d >= 0 && d != a);
            }
        }
    }
    if along_cols > along_rows {
        ScanDirection::AlongColumns
    } else {
        ScanDirection::AlongRows
    }
}
