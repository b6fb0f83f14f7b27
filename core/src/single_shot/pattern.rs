//! The X-point pattern (Ch. 4.2.1–4.2.2, SPEC §10): checkerboard-corner primitives on black, on
//! a grid of `step` projector pixels, each turned to one of four orientations that encode its
//! symbol. A primitive is the two opposite quadrants of a checkerboard corner, cut to a disc:
//! its corner (the X-point) is a saddle that locates it to a fraction of a pixel, and its long
//! (principal) axis, the bisector of the bright quadrants, is at `value · 45°` from the grid's
//! rows (measured from +u towards +v).
//!
//! Dense regions (the seed's critical regions, Ch. 4.2.1) take a finer step. The grid stays one
//! grid, so every primitive keeps its column and row and the code's windows are unchanged: the
//! columns over a region's projector columns take its `dx`, the rows over its projector rows
//! its `dy`. The region itself is dense both ways; the bands beside it, across the whole
//! image, are dense one way. Each primitive's radius is set by the least gap to its grid
//! neighbours, so the coarse parts keep the coarse pattern's primitives.

use std::path::Path;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::code;
use crate::{Error, Result};

/// Smallest grid step, projector pixels: below it a primitive is too small to tell its axis.
pub const MIN_STEP: u32 = 8;
/// Primitive radius as a fraction of the smaller step (the gap to a neighbour is the rest).
const RADIUS: f64 = 0.38;
/// Sub-samples per pixel side when rendering.
const SUPERSAMPLE: usize = 8;

/// `[pattern]` of `xpoint.toml`.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct PatternSection {
    /// Projector width, pixels.
    pub width: u32,
    /// Projector height, pixels.
    pub height: u32,
    /// Grid steps (dx, dy), projector pixels.
    pub step: [u32; 2],
    /// Hamming distance every two distinct 3×3 windows keep (Eq. 4.1).
    pub min_distance: u32,
    /// The seed of the code array.
    pub seed: u64,
    /// Primitive radius, projector pixels. With dense regions, that of the finest step: each
    /// primitive's is then 0.38 times the least gap to its grid neighbours
    /// ([`XPointPattern::radii`]).
    pub radius: f64,
    /// Grid columns and rows after which windows repeat: the decoder must know a
    /// correspondence to within fewer than these.
    pub period: [u32; 2],
    /// Regions of the projector with a finer step (`[[pattern.dense]]`); none by default.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub dense: Vec<DenseRegion>,
}

/// A region of the projector where the grid is finer (`[[pattern.dense]]` of `xpoint.toml`).
#[derive(Clone, Copy, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct DenseRegion {
    /// Projector columns it spans, from and to (pixels).
    pub x: [f64; 2],
    /// Projector rows it spans, from and to (pixels).
    pub y: [f64; 2],
    /// Its grid steps (dx, dy), projector pixels: at least [`MIN_STEP`], at most the pattern's.
    pub step: [u32; 2],
}

/// `[primitives]`: one entry per X-point, the same order in every array.
#[derive(Clone, Debug, Default, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Primitives {
    /// Projector column of the corner (SPEC §2 convention).
    pub u: Vec<f64>,
    /// Projector row of the corner.
    pub v: Vec<f64>,
    /// Symbol 0–3: long axis at 0/45/90/135°.
    pub value: Vec<u8>,
    /// Grid column.
    pub i: Vec<u32>,
    /// Grid row.
    pub j: Vec<u32>,
}

/// An X-point pattern as `xpoint.toml` states it: enough to redraw `xpoint.png` exactly.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct XPointPattern {
    /// The image and the code.
    pub pattern: PatternSection,
    /// The primitives, row by row.
    pub primitives: Primitives,
}

impl XPointPattern {
    /// The pattern for a `width × height` projector: a grid of `step` pixels centred on the
    /// image, every primitive whole inside it, symbols from the code array of `seed`.
    pub fn generate(
        width: u32,
        height: u32,
        step: [u32; 2],
        min_distance: u32,
        seed: u64,
    ) -> Result<XPointPattern> {
        Self::with_dense(width, height, step, &[], min_distance, seed)
    }

    /// As [`XPointPattern::generate`], with the grid finer over each of `dense`: the columns
    /// across a region's projector columns at its `dx`, the rows across its rows at its `dy`.
    pub fn with_dense(
        width: u32,
        height: u32,
        step: [u32; 2],
        dense: &[DenseRegion],
        min_distance: u32,
        seed: u64,
    ) -> Result<XPointPattern> {
        let bad = |field: &str, message: String| Error::invalid("X-point pattern", field, message);
        if !(1..=code::DISTANCE).contains(&min_distance) {
            return Err(bad(
                "min_distance",
                format!(
                    "{min_distance}: a 4-symbol array of 3×3 windows keeps at most {} over a projector's grid (RIS builds it with exactly that)",
                    code::DISTANCE
                ),
            ));
        }
        if step.iter().any(|&s| !(MIN_STEP..=512).contains(&s)) {
            return Err(bad(
                "step",
                format!(
                    "{}x{}: each step must be {MIN_STEP} … 512 projector pixels",
                    step[0], step[1]
                ),
            ));
        }
        for (k, r) in dense.iter().enumerate() {
            r.check(Some((width, height)), step)
                .map_err(|m| bad(&format!("dense[{k}]"), m))?;
        }
        let finest = finest_step(step, dense);
        let radius = RADIUS * f64::from(finest[0].min(finest[1]));
        // The coarse primitives' radius keeps every primitive whole inside the image.
        let margin = (RADIUS * f64::from(step[0].min(step[1]))).ceil() + 1.0;
        let bands = |axis: usize| -> Vec<([f64; 2], f64)> {
            dense
                .iter()
                .map(|r| (if axis == 0 { r.x } else { r.y }, f64::from(r.step[axis])))
                .collect()
        };
        let us = axis_positions(width, f64::from(step[0]), &bands(0), margin);
        let vs = axis_positions(height, f64::from(step[1]), &bands(1), margin);
        let (columns, rows) = (us.len(), vs.len());
        if columns < 3 || rows < 3 {
            return Err(bad(
                "step",
                format!(
                    "{}x{} on a {width}x{height} projector leaves a {columns}x{rows} grid; a code window needs 3x3",
                    step[0], step[1]
                ),
            ));
        }
        let values = code::array(columns, rows, seed);
        let mut p = Primitives::default();
        for (j, &v) in vs.iter().enumerate() {
            for (i, &u) in us.iter().enumerate() {
                p.u.push(u);
                p.v.push(v);
                p.value.push(values[j * columns + i]);
                p.i.push(i as u32);
                p.j.push(j as u32);
            }
        }
        Ok(XPointPattern {
            pattern: PatternSection {
                width,
                height,
                step,
                min_distance,
                seed,
                radius,
                period: code::PERIOD.map(|p| p as u32),
                dense: dense.to_vec(),
            },
            primitives: p,
        })
    }

    /// The finest grid steps anywhere in the pattern (the dense regions' or the pattern's):
    /// the spacing the detector must resolve.
    pub fn finest_step(&self) -> [u32; 2] {
        finest_step(self.pattern.step, &self.pattern.dense)
    }

    /// Each primitive's radius, projector pixels: [`PatternSection::radius`] without dense
    /// regions, else 0.38 times the least gap to its grid neighbours.
    pub fn radii(&self) -> Vec<f64> {
        let n = self.primitives.u.len();
        if self.pattern.dense.is_empty() {
            return vec![self.pattern.radius; n];
        }
        let lattice = self.lattice();
        let least_gap = |axis: &[f64], i: usize| {
            let before = i.checked_sub(1).map(|b| axis[i] - axis[b]);
            let after = axis.get(i + 1).map(|a| a - axis[i]);
            before
                .into_iter()
                .chain(after)
                .fold(f64::INFINITY, f64::min)
        };
        let cols = lattice.columns.len();
        (0..n)
            .map(|k| {
                let (i, j) = (k % cols, k / cols);
                RADIUS * least_gap(&lattice.columns, i).min(least_gap(&lattice.rows, j))
            })
            .collect()
    }

    /// The grid's columns and rows in the projector, to map projector positions to grid places.
    pub fn lattice(&self) -> Lattice {
        let [cols, rows] = self.grid();
        let q = &self.primitives;
        Lattice {
            columns: q.u[..cols.min(q.u.len())].to_vec(),
            rows: (0..rows)
                .filter_map(|j| q.v.get(j * cols).copied())
                .collect(),
        }
    }

    /// Read `xpoint.toml`, checking that its arrays agree.
    pub fn load(path: &Path) -> Result<XPointPattern> {
        let p: XPointPattern = crate::io::read_toml(path)?;
        let ctx = path.display().to_string();
        let n = p.primitives.u.len();
        let lens = [
            ("v", p.primitives.v.len()),
            ("value", p.primitives.value.len()),
            ("i", p.primitives.i.len()),
            ("j", p.primitives.j.len()),
        ];
        if let Some((name, len)) = lens.iter().find(|(_, l)| *l != n) {
            return Err(Error::invalid(
                &ctx,
                format!("primitives.{name}"),
                format!("{len} entries where primitives.u has {n}"),
            ));
        }
        if let Some(k) = p.primitives.value.iter().position(|&v| v > 3) {
            return Err(Error::invalid(
                &ctx,
                "primitives.value",
                format!("entry {k} is {}; symbols are 0 … 3", p.primitives.value[k]),
            ));
        }
        if !(p.pattern.radius.is_finite() && p.pattern.radius > 0.0) {
            return Err(Error::invalid(
                &ctx,
                "pattern.radius",
                format!("{} must be positive", p.pattern.radius),
            ));
        }
        if p.pattern.width == 0 || p.pattern.height == 0 || p.pattern.step.contains(&0) {
            return Err(Error::invalid(
                &ctx,
                "pattern",
                format!(
                    "a {}x{} image with steps {:?} holds no pattern",
                    p.pattern.width, p.pattern.height, p.pattern.step
                ),
            ));
        }
        // The decoder reads the primitives as a whole grid, row by row.
        let [cols, rows] = p.grid();
        if cols < 3 || rows < 3 || cols * rows != n {
            return Err(Error::invalid(
                &ctx,
                "primitives",
                format!("{n} primitives on a {cols}x{rows} grid; every cell of a grid of at least 3x3 needs one"),
            ));
        }
        let q = &p.primitives;
        if let Some(k) = (0..n).find(|&k| {
            q.i[k] as usize != k % cols
                || q.j[k] as usize != k / cols
                || !(q.u[k].is_finite() && q.v[k].is_finite())
        }) {
            return Err(Error::invalid(
                &ctx,
                "primitives",
                format!(
                    "entry {k} (i {}, j {}, u {}, v {}) is out of row-by-row grid order or not finite",
                    q.i[k], q.j[k], q.u[k], q.v[k]
                ),
            ));
        }
        // The decoder maps projector positions to grid places through the grid's columns and
        // rows: every column must lie at one projector column, every row at one row, in order.
        if let Some(k) = (0..n).find(|&k| {
            let (i, j) = (k % cols, k / cols);
            q.u[k] != q.u[i]
                || q.v[k] != q.v[j * cols]
                || (i > 0 && q.u[k] <= q.u[k - 1])
                || (j > 0 && q.v[k] <= q.v[k - cols])
        }) {
            return Err(Error::invalid(
                &ctx,
                "primitives",
                format!(
                    "entry {k} (i {}, j {}) at ({}, {}) is off its grid column's u or its row's v, or out of order",
                    q.i[k], q.j[k], q.u[k], q.v[k]
                ),
            ));
        }
        for (k, r) in p.pattern.dense.iter().enumerate() {
            r.check(Some((p.pattern.width, p.pattern.height)), p.pattern.step)
                .map_err(|m| Error::invalid(&ctx, format!("pattern.dense[{k}]"), m))?;
        }
        Ok(p)
    }

    /// Grid columns and rows.
    pub fn grid(&self) -> [usize; 2] {
        let c = self
            .primitives
            .i
            .iter()
            .max()
            .map_or(0, |&m| m as usize + 1);
        let r = self
            .primitives
            .j
            .iter()
            .max()
            .map_or(0, |&m| m as usize + 1);
        [c, r]
    }

    /// The 8-bit image: every primitive anti-aliased (`SUPERSAMPLE`² samples per pixel),
    /// black elsewhere. Primitives are drawn in parallel, then placed.
    pub fn render(&self) -> Vec<u8> {
        let (w, h) = (self.pattern.width as usize, self.pattern.height as usize);
        let radii = self.radii();
        let p = &self.primitives;
        let patches: Vec<(usize, usize, usize, Vec<u8>)> = (0..p.u.len())
            .into_par_iter()
            .map(|k| {
                let (cu, cv, r) = (p.u[k], p.v[k], radii[k]);
                let theta = f64::from(p.value[k]) * std::f64::consts::FRAC_PI_4;
                let (c, s) = (theta.cos(), theta.sin());
                let x0 = (cu - r).floor().max(0.0) as usize;
                let x1 = ((cu + r).ceil().max(0.0) as usize).min(w - 1);
                let y0 = (cv - r).floor().max(0.0) as usize;
                let y1 = ((cv + r).ceil().max(0.0) as usize).min(h - 1);
                let pw = x1 + 1 - x0.min(x1 + 1);
                let mut patch = Vec::with_capacity(pw * (y1 + 1 - y0.min(y1 + 1)));
                for y in y0..=y1 {
                    for x in x0..=x1 {
                        let mut inside = 0usize;
                        for sy in 0..SUPERSAMPLE {
                            let dy = y as f64 - 0.5 + (sy as f64 + 0.5) / SUPERSAMPLE as f64 - cv;
                            for sx in 0..SUPERSAMPLE {
                                let dx =
                                    x as f64 - 0.5 + (sx as f64 + 0.5) / SUPERSAMPLE as f64 - cu;
                                let along = dx * c + dy * s;
                                let across = -dx * s + dy * c;
                                if dx * dx + dy * dy <= r * r && along.abs() > across.abs() {
                                    inside += 1;
                                }
                            }
                        }
                        patch.push((255 * inside / (SUPERSAMPLE * SUPERSAMPLE)) as u8);
                    }
                }
                (x0, y0, pw, patch)
            })
            .collect();
        let mut img = vec![0u8; w * h];
        for (x0, y0, pw, patch) in patches {
            if pw == 0 {
                continue;
            }
            for (dy, row) in patch.chunks_exact(pw).enumerate() {
                let at = (y0 + dy) * w + x0;
                for (px, &v) in img[at..at + pw].iter_mut().zip(row) {
                    *px = (*px).max(v);
                }
            }
        }
        img
    }
}

impl DenseRegion {
    /// Why this region cannot refine a pattern of steps `step` (on a `size` projector, when
    /// known): its span must run from a lower to a higher pixel (inside the image), its steps
    /// from [`MIN_STEP`] to the pattern's.
    pub fn check(
        &self,
        size: Option<(u32, u32)>,
        step: [u32; 2],
    ) -> std::result::Result<(), String> {
        let (w, h) = size.map_or((f64::INFINITY, f64::INFINITY), |(w, h)| {
            (f64::from(w), f64::from(h))
        });
        let inside = |a: [f64; 2], size: f64| {
            a.iter().all(|v| v.is_finite()) && a[0] >= 0.0 && a[0] < a[1] && a[1] <= size
        };
        if !inside(self.x, w) || !inside(self.y, h) {
            let within = size.map_or(String::new(), |(w, h)| {
                format!(" inside the {w}x{h} projector")
            });
            return Err(format!(
                "x {:?}, y {:?}: a region runs from a lower to a higher pixel{within}",
                self.x, self.y
            ));
        }
        if (0..2).any(|a| !(MIN_STEP..=step[a]).contains(&self.step[a])) {
            return Err(format!(
                "step {}x{}: a dense region's steps are {MIN_STEP} … the pattern's ({}x{})",
                self.step[0], self.step[1], step[0], step[1]
            ));
        }
        Ok(())
    }
}

/// Where the grid's columns and rows lie in the projector (each column at one projector column,
/// each row at one row, as [`XPointPattern::load`] checks).
#[derive(Clone, Debug)]
pub struct Lattice {
    /// Projector column of each grid column, increasing.
    pub columns: Vec<f64>,
    /// Projector row of each grid row, increasing.
    pub rows: Vec<f64>,
}

impl Lattice {
    /// The grid place (column, row; fractional, extrapolated past the ends) of projector
    /// point (u, v).
    pub fn place(&self, u: f64, v: f64) -> (f64, f64) {
        (fractional(&self.columns, u), fractional(&self.rows, v))
    }

    /// The grid steps (dx, dy) about projector point (u, v), projector pixels.
    pub fn step_at(&self, u: f64, v: f64) -> [f64; 2] {
        [spacing(&self.columns, u), spacing(&self.rows, v)]
    }
}

/// The interval of increasing `axis` (at least two entries) that holds `x`, the nearest at
/// either end: its first index.
fn interval(axis: &[f64], x: f64) -> usize {
    axis.partition_point(|&a| a <= x)
        .saturating_sub(1)
        .min(axis.len().saturating_sub(2))
}

/// `x` as a fractional index into increasing `axis`.
fn fractional(axis: &[f64], x: f64) -> f64 {
    if axis.len() < 2 {
        return 0.0;
    }
    let k = interval(axis, x);
    k as f64 + (x - axis[k]) / (axis[k + 1] - axis[k])
}

/// The gap between the entries of increasing `axis` about `x`.
fn spacing(axis: &[f64], x: f64) -> f64 {
    if axis.len() < 2 {
        return 1.0;
    }
    let k = interval(axis, x);
    axis[k + 1] - axis[k]
}

/// The finest of `step` and the dense regions' steps, per axis.
fn finest_step(step: [u32; 2], dense: &[DenseRegion]) -> [u32; 2] {
    dense
        .iter()
        .fold(step, |f, r| [f[0].min(r.step[0]), f[1].min(r.step[1])])
}

/// Grid positions along one axis of `size` pixels, `margin` from either end: `coarse` apart,
/// but `fine` apart across each band `([from, to], fine)` (the first position in a band at its
/// start), the whole centred in the image (the walk is made again from half the slack the first
/// left). Without bands, `coarse` apart from the centred origin.
fn axis_positions(size: u32, coarse: f64, bands: &[([f64; 2], f64)], margin: f64) -> Vec<f64> {
    let end = f64::from(size) - 1.0 - margin;
    let walk = |start: f64| {
        let mut at = Vec::new();
        let mut p = start;
        while p <= end + 1e-9 {
            at.push(p);
            let mut next = p + coarse;
            for &([a, b], fine) in bands {
                if a < p + coarse && p < b {
                    next = next.min(if p >= a { p + fine } else { a.max(p + fine) });
                }
            }
            p = next;
        }
        at
    };
    let first = walk(margin);
    match first.last() {
        Some(&last) => walk(margin + (end - last) / 2.0),
        None => first,
    }
}
