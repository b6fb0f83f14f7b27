//! Corners whose light an edge cut across one lobe (a table's end, a shadow): what is left is
//! still point-symmetric, about a centre up to a pixel inside the corner, so the symmetric fit
//! cannot see it. Two signs that do not share their noise agree there: the corner lies inside
//! the straight line through its two grid neighbours on the whole side, and the half of a whole
//! neighbour's light that faces away from the edge (a primitive of the same value, so the same
//! shape) matches this corner's best a little outward. Where both say so, the corner is moved
//! to that match: the half the edge did not reach places it.

use rayon::prelude::*;

use super::detect::Shifted;
use super::{Correspondence, Detector, XPointPattern};

/// How far (camera pixels) inside the line through its two neighbours on the whole side a
/// corner beside a missing neighbour must lie to be matched by halves. On the seeded
/// independent scenes 90 % of the boundary corners that are not cut lie less than 0.3 px inside
/// it (surfaces bend the grid, texture moves corners); cut ones 0.5–1.2 px inside.
pub const CUT_INSIDE: f64 = 0.3;

/// How far inside (camera pixels) a corner may lie and still be taken for one an edge cut:
/// cutting a pixel off one lobe moves the centre of symmetry by about half that, while a step
/// in the surface or one turning away puts the grid further off its line.
pub const CUT_INSIDE_MAX: f64 = 1.3;

/// How far outward (camera pixels) the half match must place a corner for it to be moved. On
/// whole boundary corners 90 % of half matches land within 0.28 px outward, and the two
/// signs together rarely agree by chance; cut corners match 0.3–1.2 px outward (0.4 px was
/// the bound before the symmetric fit took the albedo's slope, which leaves cut corners
/// nearer: on the 84 independent scenes 103 points beyond 2 mm at 0.3 px, 109 at 0.4 px).
pub const CUT_SHIFT: f64 = 0.3;

/// How far (camera pixels) inside the line through its two neighbours on the whole side a
/// corner beside a missing neighbour may lie when that line runs straight on (see
/// [`KINK_STRAIGHT`]) and no half match moved it back. Uncut boundary corners lie within
/// 0.3 px of it (90 %). On 36 seeded scenes of the independent renderer, 52 of 12 000
/// boundary corners lay more than 0.8 px inside a straight line, 12 of them beyond 2 mm (of 56
/// boundary corners there); on 24 more drawn afterwards, 17 more of 7 800, 10 beyond 2 mm.
pub const KINK_INSIDE: f64 = 0.8;

/// How far (camera pixels) the next neighbour may lie inside the line through the two before it
/// for that line to count as straight in [`drop_kinked`]: a surface that bends bends the grid
/// over several steps, an edge that cuts a corner moves that corner alone.
pub const KINK_STRAIGHT: f64 = 0.3;

/// The grid offsets of the four sides in `Correspondence::sides` bit order.
const SIDES: [(i64, i64); 4] = [(-1, 0), (1, 0), (0, -1), (0, 1)];

/// Most samples in half of the matching disc (a disc of radius 8 holds 197 points); a detector
/// set for a larger disc moves no corner rather than match a truncated half.
const MAX_SAMPLES: usize = 128;

impl Detector {
    /// Move each corner of `matches` (decoded from the frame this detector saw last) that an
    /// edge cut to where the half of a whole same-valued neighbour away from the edge matches
    /// its light; the count moved. Corners with all four grid neighbours are left as they are.
    pub fn recentre_cut(&self, matches: &mut [Correspondence], pattern: &XPointPattern) -> usize {
        let [cols, rows] = pattern.grid();
        let (s, width, height) = self.smoothed();
        if cols == 0 || rows == 0 || s.len() != width * height || s.is_empty() {
            return 0;
        }
        let grid = Placed::new(matches, cols, rows);
        let at = |i: i64, j: i64| grid.at(i, j);
        let values = &pattern.primitives.value;
        let radius = self.params().radius + 1.0;
        let inside = |k: usize, side: (i64, i64)| grid.inside(matches, k, side);
        // Each cut side's template: the nearest neighbour of the same value, not on the edge's
        // side, whose half away from the edge is whole and whose corner is not cut (one with
        // all four neighbours, or one missing only this side and lying on its neighbours' line).
        let mut sought = Vec::new();
        for (k, m) in matches.iter().enumerate() {
            if m.sides == 0b1111 {
                continue;
            }
            let (i, j) = ((m.primitive % cols) as i64, (m.primitive / cols) as i64);
            for (bit, &side) in SIDES.iter().enumerate() {
                if m.sides & (1 << bit) != 0 {
                    continue;
                }
                let Some((depth, n, _)) = inside(k, side) else {
                    continue;
                };
                if depth <= CUT_INSIDE || depth > CUT_INSIDE_MAX {
                    continue;
                }
                let mut same: Option<(i64, usize)> = None;
                for dj in -2..=2i64 {
                    for di in -2..=2i64 {
                        if (di, dj) == (0, 0) || di * side.0 + dj * side.1 > 0 {
                            continue;
                        }
                        let d2 = di * di + dj * dj;
                        let Some(q) = at(i + di, j + dj)
                            .filter(|&q| {
                                values.get(matches[q].primitive) == values.get(m.primitive)
                            })
                            .filter(|_| same.is_none_or(|(b, _)| d2 < b))
                        else {
                            continue;
                        };
                        let whole = matches[q].sides == 0b1111
                            || (matches[q].sides | (1 << bit) == 0b1111
                                && inside(q, side).is_some_and(|d| d.0.abs() <= CUT_INSIDE));
                        if whole {
                            same = Some((d2, q));
                        }
                    }
                }
                if let Some((_, q)) = same {
                    sought.push((k, n, (matches[q].x, matches[q].y)));
                }
            }
        }
        let mut found: Vec<(usize, f64, (f64, f64))> = sought
            .par_iter()
            .filter_map(|&(k, n, whole)| {
                let m = &matches[k];
                let o = half_match(s, width, height, (m.x, m.y), whole, n, radius)?;
                let shift = o.0 * n.0 + o.1 * n.1;
                (shift > CUT_SHIFT).then_some((k, shift, o))
            })
            .collect();
        // Where two sides were cut, the match that moves the corner furthest.
        found.sort_by(|a, b| a.0.cmp(&b.0).then(b.1.total_cmp(&a.1)));
        found.dedup_by_key(|f| f.0);
        for &(k, _, (ox, oy)) in &found {
            matches[k].x += ox;
            matches[k].y += oy;
        }
        found.len()
    }
}

/// Drop the corners beside a missing grid neighbour that lie more than [`KINK_INSIDE`] inside
/// the line through their two neighbours on the whole side, where that line runs straight on
/// (the next neighbour within [`KINK_STRAIGHT`] of it); the count dropped. Run after
/// [`Detector::recentre_cut`]: what it did not move back is an edge that cut more than a lobe's
/// edge, or a crease at the corner, and either leaves no trustworthy centre.
pub fn drop_kinked(matches: &mut Vec<Correspondence>, pattern: &XPointPattern) -> usize {
    let [cols, rows] = pattern.grid();
    let grid = Placed::new(matches, cols, rows);
    let kinked: Vec<bool> = (0..matches.len())
        .map(|k| {
            matches[k].sides != 0b1111
                && SIDES.iter().enumerate().any(|(bit, &side)| {
                    matches[k].sides & (1 << bit) == 0
                        && grid.inside(matches, k, side).is_some_and(|(depth, _, on)| {
                            depth > KINK_INSIDE && on.is_some_and(|o| o.abs() <= KINK_STRAIGHT)
                        })
                })
        })
        .collect();
    let before = matches.len();
    let mut kinked = kinked.into_iter();
    matches.retain(|_| !kinked.next().unwrap_or(false));
    before - matches.len()
}

/// Which correspondence holds each grid place.
struct Placed {
    grid: Vec<usize>,
    cols: usize,
    rows: usize,
}

impl Placed {
    fn new(matches: &[Correspondence], cols: usize, rows: usize) -> Placed {
        let mut grid = vec![usize::MAX; cols * rows];
        for (k, m) in matches.iter().enumerate() {
            if let Some(g) = grid.get_mut(m.primitive) {
                *g = k;
            }
        }
        Placed { grid, cols, rows }
    }

    /// The correspondence at grid place (i, j).
    fn at(&self, i: i64, j: i64) -> Option<usize> {
        (i >= 0 && j >= 0 && (i as usize) < self.cols && (j as usize) < self.rows)
            .then(|| self.grid[j as usize * self.cols + i as usize])
            .filter(|&k| k != usize::MAX)
    }

    /// How far corner k lies inside the line through its two grid neighbours opposite side
    /// (a, b), with the unit direction towards that side, and how far the next neighbour on
    /// that line lies inside the line through the two before it (where there is one).
    fn inside(
        &self,
        matches: &[Correspondence],
        k: usize,
        (a, b): (i64, i64),
    ) -> Option<(f64, (f64, f64), Option<f64>)> {
        let m = &matches[k];
        let (i, j) = (
            (m.primitive % self.cols) as i64,
            (m.primitive / self.cols) as i64,
        );
        let (p1, p2) = (
            &matches[self.at(i - a, j - b)?],
            &matches[self.at(i - 2 * a, j - 2 * b)?],
        );
        let (nx, ny) = (m.x - p1.x, m.y - p1.y);
        let l = nx.hypot(ny);
        if l < 1.0 {
            return None;
        }
        let n = (nx / l, ny / l);
        let off = |a: &Correspondence, b: &Correspondence, c: &Correspondence| {
            (a.x - 2.0 * b.x + c.x) * n.0 + (a.y - 2.0 * b.y + c.y) * n.1
        };
        let next = self
            .at(i - 3 * a, j - 3 * b)
            .map(|q| -off(p1, p2, &matches[q]));
        Some((-off(m, p1, p2), n, next))
    }
}

/// The offset from `at` where the light best matches, up to a gain and an offset, the half of
/// the light about `whole` within `radius` that lies away from the unit direction `n`: a search
/// along `n` every 0.2 px from 0.6 px inward to 2 px outward, refined twice in both directions
/// to 0.025 px. `None` where a disc leaves the image.
fn half_match(
    s: &[f32],
    width: usize,
    height: usize,
    at: (f64, f64),
    whole: (f64, f64),
    n: (f64, f64),
    radius: f64,
) -> Option<(f64, f64)> {
    const BACK: f64 = -0.6;
    const REACH: f64 = 2.0;
    const COARSE: f64 = 0.2;
    let r = radius.ceil() as i32;
    let mut offsets = [(0i32, 0i32); MAX_SAMPLES];
    let mut template = [0f64; MAX_SAMPLES];
    let source = Shifted::new(s, width, height, whole.0, whole.1, r)?;
    let mut len = 0;
    for dy in -r..=r {
        for dx in -r..=r {
            let (fx, fy) = (f64::from(dx), f64::from(dy));
            if fx * fx + fy * fy <= radius * radius && fx * n.0 + fy * n.1 < -0.5 {
                if len == MAX_SAMPLES {
                    return None;
                }
                offsets[len] = (dx, dy);
                template[len] = source.value(dx, dy);
                len += 1;
            }
        }
    }
    if len < 8 {
        return None;
    }
    let (offsets, template) = (&offsets[..len], &mut template[..len]);
    let mean = template.iter().sum::<f64>() / len as f64;
    template.iter_mut().for_each(|t| *t -= mean);
    let tt = template.iter().map(|t| t * t).sum::<f64>();
    if tt <= 0.0 {
        return None;
    }
    // The share of the light's variance left when it is regressed on the template (gain and
    // offset free): one less the squared correlation.
    let cost = |ox: f64, oy: f64| -> Option<f64> {
        let seen = Shifted::new(s, width, height, at.0 + ox, at.1 + oy, r)?;
        let (mut sum, mut sq, mut cross) = (0f64, 0f64, 0f64);
        for (&(dx, dy), &t) in offsets.iter().zip(template.iter()) {
            let v = seen.value(dx, dy);
            sum += v;
            sq += v * v;
            cross += v * t;
        }
        let var = sq - sum * sum / len as f64;
        Some(if var > 0.0 {
            1.0 - cross * cross / (tt * var)
        } else {
            1.0
        })
    };
    // Along `n` first (an edge moves the corner across itself), then about the best there.
    let mut best = (f64::INFINITY, 0.0, 0.0);
    for k in 0..=((REACH - BACK) / COARSE).round() as i32 {
        let t = BACK + f64::from(k) * COARSE;
        let e = cost(t * n.0, t * n.1)?;
        if e < best.0 {
            best = (e, t * n.0, t * n.1);
        }
    }
    let mut centre = (best.1, best.2);
    for step in [0.1, 0.025] {
        let c = centre;
        for iy in -2..=2 {
            for ix in -2..=2 {
                let (ox, oy) = (c.0 + f64::from(ix) * step, c.1 + f64::from(iy) * step);
                let e = cost(ox, oy)?;
                if e < best.0 {
                    best = (e, ox, oy);
                }
            }
        }
        centre = (best.1, best.2);
    }
    Some(centre)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::gaussian_blur_into;
    use crate::single_shot::{decode, DetectParams};
    use crate::testing::Rng;

    /// On a seeded family of grids that end at a column, a corner of that column pushed more
    /// than [`KINK_INSIDE`] inside its row's straight line is dropped; one pushed less stays,
    /// as does one at the end of a grid that bends over several steps; whole corners stay.
    #[test]
    fn corners_well_inside_a_straight_grid_line_are_dropped() {
        let mut rng = Rng(31);
        let mut bent = 0;
        for seed in 1..=8u64 {
            let step = [rng.range(12.0, 16.99) as u32, rng.range(12.0, 16.99) as u32];
            let pattern = XPointPattern::generate(480, 360, step, 3, seed).expect("pattern");
            let [cols, rows] = pattern.grid();
            let q = &pattern.primitives;
            let last = 10 + (rng.range(0.0, 10.0) as usize);
            // Camera = projector scaled, a grid that ends at column `last`; a bend (the
            // surface turning away) compresses the last columns quadratically.
            let bend = rng.range(0.0, 1.0) < 0.5;
            bent += usize::from(bend);
            let scale = rng.range(0.6, 0.9);
            let mut matches: Vec<Correspondence> = (0..rows * cols)
                .filter(|&k| k % cols <= last)
                .map(|k| {
                    let (i, j) = (k % cols, k / cols);
                    let sides = u8::from(i > 0)
                        | u8::from(i < last) << 1
                        | u8::from(j > 0) << 2
                        | u8::from(j + 1 < rows) << 3;
                    let x = if bend {
                        scale * q.u[k] - 0.4 * (i as f64 - last as f64 + 4.0).max(0.0).powi(2)
                    } else {
                        scale * q.u[k]
                    };
                    Correspondence {
                        x,
                        y: scale * q.v[k],
                        primitive: k,
                        u: q.u[k],
                        v: q.v[k],
                        from_codeword: true,
                        asymmetry: 0.01,
                        sides,
                    }
                })
                .collect();
            // Two rows pushed well inside, two a little.
            let row = |j: usize| j * cols + last;
            let pushes = [(row(4), 1.6), (row(6), 1.0), (row(8), 0.6), (row(10), 0.3)];
            for &(k, by) in &pushes {
                let m = matches
                    .iter_mut()
                    .find(|m| m.primitive == k)
                    .expect("corner");
                m.x -= by;
            }
            let before = matches.len();
            let dropped = drop_kinked(&mut matches, &pattern);
            let kept = |k: usize| matches.iter().any(|m| m.primitive == k);
            if bend {
                // The end of a bending grid lies 0.8 px a step inside already: its line is not
                // straight, nothing is dropped.
                assert_eq!(dropped, 0, "seed {seed}: a bending grid lost corners");
            } else {
                assert_eq!(dropped, 2, "seed {seed}");
                assert!(!kept(row(4)) && !kept(row(6)), "seed {seed}");
                assert!(kept(row(8)) && kept(row(10)), "seed {seed}");
            }
            assert_eq!(before - matches.len(), dropped);
        }
        assert!(
            (1..8).contains(&bent),
            "both kinds of grid: {bent} of 8 bent"
        );
    }

    /// Seeded patterns seen head-on with an edge 1.0–2.6 px right of one column of corners,
    /// beyond which nothing is lit: it cuts the lobes that reach right. Most corners of that
    /// column the symmetric fit placed more than 0.3 px inside are moved to within a quarter
    /// pixel of their primitives (19 of 29 when this was written; the others lack a second
    /// neighbour on the whole side or a template, or the edge cut them deeper than a half
    /// match reaches), none of that column ends further off, no corner off it moves, and a
    /// detector whose disc is too large for the template moves none.
    #[test]
    fn corners_an_edge_cut_are_moved_back_to_their_primitives() {
        let mut rng = Rng(5);
        let (mut moved_far, mut cut_far) = (0, 0);
        for seed in 1..=8u64 {
            let step = [rng.range(13.0, 16.99) as u32, rng.range(13.0, 16.99) as u32];
            let (w, h) = (480usize, 360usize);
            let pattern =
                XPointPattern::generate(w as u32, h as u32, step, 3, seed).expect("pattern");
            let u = &pattern.primitives.u;
            let column = u[0] + f64::from(step[0]) * (rng.range(18.0, 22.0) as u32) as f64;
            let edge = column + rng.range(1.0, 2.6);
            // The projector's lens blurs the pattern, the edge ends the lit surface, the
            // camera's lens blurs what is left and the sensor adds noise.
            let shown: Vec<f32> = pattern.render().into_iter().map(f32::from).collect();
            let (mut tmp, mut lit, mut levels) = (Vec::new(), Vec::new(), Vec::new());
            gaussian_blur_into(&shown, w, h, 0.6, &mut tmp, &mut lit);
            for row in lit.chunks_mut(w) {
                for (x, v) in row.iter_mut().enumerate() {
                    if x as f64 > edge {
                        *v = 0.0;
                    }
                }
            }
            gaussian_blur_into(&lit, w, h, 1.0, &mut tmp, &mut levels);
            for v in &mut levels {
                *v = 0.8 * *v + 10.0 + rng.range(-3.0, 3.0) as f32;
            }
            // A disc of 5 px: the default's 3.7 px is cut by these edges far less (7 corners
            // more than 0.3 px off in all eight patterns), too few to test the move on.
            let mut detector = Detector::new(DetectParams {
                radius: 5.0,
                sigma: 1.2,
                ..Default::default()
            });
            let found = detector.detect(&levels, w, h);
            let identity = |x: f64, y: f64| Some((x, y));
            let (before, _) = decode(&found, &pattern, Some(&identity));
            let mut after = before.clone();
            let moved = detector.recentre_cut(&mut after, &pattern);
            // A disc too large for the template's samples moves nothing rather than match a
            // truncated half.
            let mut wide = Detector::new(DetectParams {
                radius: 9.5,
                ..Default::default()
            });
            wide.detect(&levels, w, h);
            let mut unmoved = before.clone();
            assert_eq!(wide.recentre_cut(&mut unmoved, &pattern), 0);
            assert_eq!(unmoved, before);
            let off = |m: &Correspondence| (m.x - m.u).hypot(m.y - m.v);
            for (b, a) in before.iter().zip(&after) {
                if (b.u - column).abs() < 0.5 {
                    cut_far += usize::from(off(b) > 0.3);
                    moved_far += usize::from(off(b) > 0.3 && off(a) < 0.25);
                    assert!(
                        off(a) <= off(b) + 0.05,
                        "seed {seed}: corner at ({:.1}, {:.1}) {:.2} px off, {:.2} before",
                        b.u,
                        b.v,
                        off(a),
                        off(b)
                    );
                } else {
                    assert_eq!((a.x, a.y), (b.x, b.y), "seed {seed}: an uncut corner moved");
                }
            }
            eprintln!("seed {seed} step {step:?} edge {edge:.1}: {moved} moved");
        }
        eprintln!("{moved_far} of {cut_far} corners more than 0.3 px off moved to within 0.25 px");
        assert!(
            cut_far >= 12,
            "the edges cut too few corners to test: {cut_far}"
        );
        assert!(
            moved_far * 5 >= cut_far * 3,
            "{moved_far} of {cut_far} moved back"
        );
    }
}
