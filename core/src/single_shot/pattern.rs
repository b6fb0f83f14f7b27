//! The X-point pattern (Ch. 4.2.1–4.2.2, SPEC §10): checkerboard-corner primitives on black, on
//! a grid of `step` projector pixels, each turned to one of four orientations that encode its
//! symbol. A primitive is the two opposite quadrants of a checkerboard corner, cut to a disc:
//! its corner (the X-point) is a saddle that locates it to a fraction of a pixel, and its long
//! (principal) axis, the bisector of the bright quadrants, is at `value · 45°` from the grid's
//! rows (measured from +u towards +v).

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
    /// Primitive radius, projector pixels.
    pub radius: f64,
    /// Grid columns and rows after which windows repeat: the decoder must know a
    /// correspondence to within fewer than these.
    pub period: [u32; 2],
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
        let radius = RADIUS * f64::from(step[0].min(step[1]));
        let margin = radius.ceil() + 1.0;
        let fit = |size: u32, s: u32| -> usize {
            let span = f64::from(size) - 1.0 - 2.0 * margin;
            if span < 0.0 {
                0
            } else {
                (span / f64::from(s)).floor() as usize + 1
            }
        };
        let (columns, rows) = (fit(width, step[0]), fit(height, step[1]));
        if columns < 3 || rows < 3 {
            return Err(bad(
                "step",
                format!(
                    "{}x{} on a {width}x{height} projector leaves a {columns}x{rows} grid; a code window needs 3x3",
                    step[0], step[1]
                ),
            ));
        }
        let origin = |size: u32, n: usize, s: u32| {
            ((f64::from(size) - 1.0) - (n as f64 - 1.0) * f64::from(s)) / 2.0
        };
        let (u0, v0) = (
            origin(width, columns, step[0]),
            origin(height, rows, step[1]),
        );
        let values = code::array(columns, rows, seed);
        let mut p = Primitives::default();
        for j in 0..rows {
            for i in 0..columns {
                p.u.push(u0 + (i as f64) * f64::from(step[0]));
                p.v.push(v0 + (j as f64) * f64::from(step[1]));
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
            },
            primitives: p,
        })
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
        let r = self.pattern.radius;
        let p = &self.primitives;
        let patches: Vec<(usize, usize, usize, Vec<u8>)> = (0..p.u.len())
            .into_par_iter()
            .map(|k| {
                let (cu, cv) = (p.u[k], p.v[k]);
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
