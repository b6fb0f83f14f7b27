//! A grid of cubic cells over a mesh, each listing the triangles whose boxes reach into it, so
//! that the nearest triangle to a point lying close to the surface is found among a cell's few
//! triangles instead of by a walk down the hierarchy.
//!
//! A cell answers only when its answer is certain: every triangle within the found distance
//! of the point lies in the ball of that radius, and when the ball is inside the cell every
//! such triangle is on the cell's list. Otherwise (the ball crosses the cell's faces, the cell
//! is empty or crowded, the point is outside the grid, or the query's hint lies a quarter of a
//! cell away or more, so the ball would seldom fit) the hierarchy answers, started from the
//! cell's best triangle where there is one. Both give the same triangle, point and distance,
//! ties included (the lowest index), so results do not depend on which answered.

use super::Bvh;
use crate::geometry::Vec3;

/// Most cells the grid may have (dense offsets, 4 bytes each).
const MAX_CELLS: usize = 1 << 22;
/// A cell with more triangles than this is left to the hierarchy.
const CROWDED: usize = 48;
/// A hint this far from the point, in cell edges, sends the query to the hierarchy.
const FAR_HINT: f64 = 0.25;
/// Cell edge over the median triangle's longest box side.
const CELL_OVER_TRIANGLE: f64 = 1.4;

/// Triangle lists per cell (compressed rows), by the triangles' positions in the hierarchy's
/// leaf order, where neighbouring triangles lie near each other in memory.
pub(super) struct Cells {
    origin: [f64; 3],
    size: f64,
    dims: [usize; 3],
    /// `start[c]..start[c + 1]` indexes `refs` for cell `c`.
    start: Vec<u32>,
    refs: Vec<u32>,
}

/// What a cell says about a point: the certain nearest triangle, or only the best of its own
/// triangles (a good starting bound for the hierarchy).
pub(super) enum Near<F> {
    Certain((u32, Vec3, F, f64)),
    Bound(u32),
    Nothing,
}

impl Cells {
    /// The grid over `bvh`'s triangles; `None` for a mesh whose triangles' sizes give no
    /// useful cell (empty, degenerate, or so uneven that the lists would grow past a few
    /// references per triangle).
    pub(super) fn new(bvh: &Bvh) -> Option<Cells> {
        let (_, corners) = bvh.leaf_order();
        let n = corners.len();
        if n == 0 {
            return None;
        }
        let boxes: Vec<([f64; 3], [f64; 3])> = corners
            .iter()
            .map(|c| {
                let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
                for v in c {
                    for k in 0..3 {
                        lo[k] = lo[k].min(v[k]);
                        hi[k] = hi[k].max(v[k]);
                    }
                }
                (lo, hi)
            })
            .collect();
        let mut sides: Vec<f64> = boxes
            .iter()
            .map(|(lo, hi)| (0..3).map(|k| hi[k] - lo[k]).fold(0.0, f64::max))
            .collect();
        let mid = n / 2;
        sides.select_nth_unstable_by(mid, f64::total_cmp);
        let (lo, hi) = bvh.bounds();
        let extent: Vec<f64> = (0..3).map(|k| hi[k] - lo[k]).collect();
        let mut size = CELL_OVER_TRIANGLE * sides[mid];
        if !(size.is_finite() && size > 0.0) {
            return None;
        }
        let dims_for = |size: f64| -> [usize; 3] {
            [0, 1, 2].map(|k| (extent[k] / size).floor() as usize + 1)
        };
        let count = |d: [usize; 3]| d.iter().map(|&x| x as f64).product::<f64>();
        if count(dims_for(size)) > MAX_CELLS as f64 {
            size *= (count(dims_for(size)) / MAX_CELLS as f64).cbrt() * 1.01;
        }
        let dims = dims_for(size);
        if count(dims) > MAX_CELLS as f64 {
            return None;
        }
        // Boxes grown by a millionth of a cell, so that rounding in the cell of a point near a
        // face never leaves out a triangle that touches the cell.
        let grow = 1e-6 * size;
        let inv = 1.0 / size;
        let range = |(lo_b, hi_b): &([f64; 3], [f64; 3])| -> [[usize; 2]; 3] {
            [0, 1, 2].map(|k| {
                let a =
                    (((lo_b[k] - grow - lo[k]) * inv).floor().max(0.0) as usize).min(dims[k] - 1);
                let b =
                    (((hi_b[k] + grow - lo[k]) * inv).floor().max(0.0) as usize).min(dims[k] - 1);
                [a, b]
            })
        };
        let total: f64 = boxes
            .iter()
            .map(|b| {
                let r = range(b);
                (0..3)
                    .map(|k| (r[k][1] - r[k][0] + 1) as f64)
                    .product::<f64>()
            })
            .sum();
        if total > (16 * n + (1 << 20)) as f64 {
            return None;
        }
        let cells = dims[0] * dims[1] * dims[2];
        let index = |x: usize, y: usize, z: usize| (z * dims[1] + y) * dims[0] + x;
        let each = |f: &mut dyn FnMut(usize, usize)| {
            for (pos, b) in boxes.iter().enumerate() {
                let r = range(b);
                for z in r[2][0]..=r[2][1] {
                    for y in r[1][0]..=r[1][1] {
                        for x in r[0][0]..=r[0][1] {
                            f(index(x, y, z), pos);
                        }
                    }
                }
            }
        };
        let mut counts = vec![0u32; cells];
        each(&mut |c, _| counts[c] += 1);
        // Crowded cells keep no list: the hierarchy answers there.
        let mut start = Vec::with_capacity(cells + 1);
        let mut at = 0u32;
        for c in &mut counts {
            start.push(at);
            if (*c as usize) > CROWDED {
                *c = 0;
            }
            at += *c;
        }
        start.push(at);
        let mut refs = vec![0u32; at as usize];
        let mut fill: Vec<u32> = start[..cells].to_vec();
        each(&mut |c, pos| {
            if counts[c] > 0 {
                refs[fill[c] as usize] = pos as u32;
                fill[c] += 1;
            }
        });
        Some(Cells {
            origin: lo,
            size,
            dims,
            start,
            refs,
        })
    }

    /// The nearest triangle to `p` among its cell's, certain when the ball through it lies
    /// inside the cell; `closest` as in [`Bvh::closest`].
    #[inline]
    pub(super) fn near<F: Copy>(
        &self,
        bvh: &Bvh,
        p: &Vec3,
        hint: u32,
        closest: impl Fn(&Vec3, &Vec3, &Vec3, &Vec3) -> (Vec3, F),
    ) -> Near<F> {
        let mut cell = [0usize; 3];
        let mut low = [0.0; 3];
        for k in 0..3 {
            let u = (p[k] - self.origin[k]) / self.size;
            if !(u >= 0.0 && u < self.dims[k] as f64) {
                return Near::Nothing;
            }
            cell[k] = u as usize;
            low[k] = self.origin[k] + cell[k] as f64 * self.size;
        }
        // The hint first: its distance lets most of the list be passed over by their boxes.
        // A hint farther than a quarter of a cell (a point off the surface, or the hint of an
        // unrelated point) says the ball will seldom fit in the cell: the hierarchy answers.
        let mut best = bvh.at_triangle(p, hint, &closest);
        let mut best_d2 = best.as_ref().map_or(f64::INFINITY, |b| b.3);
        if best_d2.is_finite() && best_d2 > (FAR_HINT * self.size).powi(2) {
            return Near::Nothing;
        }
        let c = (cell[2] * self.dims[1] + cell[1]) * self.dims[0] + cell[0];
        let list = &self.refs[self.start[c] as usize..self.start[c + 1] as usize];
        if list.is_empty() {
            return Near::Nothing;
        }
        let (order, corners) = bvh.leaf_order();
        for &pos in list {
            let tri = order[pos as usize];
            let [a, b, c] = &corners[pos as usize];
            // (the triangle's box, as near as it may be; a tie may still have a lower index)
            let mut box_d2 = 0.0;
            for k in 0..3 {
                let lo = a[k].min(b[k]).min(c[k]);
                let hi = a[k].max(b[k]).max(c[k]);
                let e = (lo - p[k]).max(0.0).max(p[k] - hi);
                box_d2 += e * e;
            }
            if box_d2 > best_d2 * (1.0 + 1e-12) {
                continue;
            }
            let (q, f) = closest(p, a, b, c);
            let d2 = (p - q).norm_squared();
            if d2 < best_d2 || (d2 == best_d2 && best.as_ref().is_some_and(|b| tri < b.0)) {
                best_d2 = d2;
                best = Some((tri, q, f, d2));
            }
        }
        let Some(found) = best else {
            return Near::Nothing;
        };
        // The closed ball through the nearest point, with room for rounding, inside the cell.
        let r = best_d2.sqrt() * (1.0 + 1e-9) + 1e-9 * self.size;
        let inside = (0..3).all(|k| p[k] - r > low[k] && p[k] + r < low[k] + self.size);
        if inside {
            Near::Certain(found)
        } else {
            Near::Bound(found.0)
        }
    }
}
