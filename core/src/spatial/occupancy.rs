//! A coarse dense occupancy grid: which cells of space a point set touches (with their
//! neighbours), to cull a large point set to the region near another before finer searches.

use rayon::prelude::*;

/// Cells of a regular grid holding at least one point of a set, dilated by one cell.
#[derive(Clone, Debug)]
pub struct Occupancy {
    /// Lower corner of the points' bounding box (the grid has one margin cell below it).
    origin: [f64; 3],
    cell: f64,
    inv_cell: f64,
    dims: [usize; 3],
    occupied: Vec<u8>,
}

impl Occupancy {
    /// The cells (edge `cell`, grown if the bounding box would need more than `max_cells`)
    /// holding any finite point of `points`, plus their 26 neighbours: every point within
    /// `cell` of the set lies in one.
    pub fn around(points: &[[f64; 3]], cell: f64, max_cells: usize) -> Occupancy {
        let (lo, hi) = points
            .par_iter()
            .filter(|p| p.iter().all(|v| v.is_finite()))
            .fold(
                || ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]),
                |(mut lo, mut hi), p| {
                    for k in 0..3 {
                        lo[k] = lo[k].min(p[k]);
                        hi[k] = hi[k].max(p[k]);
                    }
                    (lo, hi)
                },
            )
            .reduce(
                || ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]),
                |a, b| {
                    (
                        std::array::from_fn(|k| a.0[k].min(b.0[k])),
                        std::array::from_fn(|k| a.1[k].max(b.1[k])),
                    )
                },
            );
        if lo[0] > hi[0] {
            return Occupancy {
                origin: [0.0; 3],
                cell: 1.0,
                inv_cell: 1.0,
                dims: [0; 3],
                occupied: Vec::new(),
            };
        }
        let mut cell = if cell.is_finite() && cell > 0.0 {
            cell
        } else {
            1.0
        };
        // A cell of margin below and two above (rounding) for the neighbourhoods.
        let dims_for = |cell: f64| -> [usize; 3] {
            std::array::from_fn(|k| ((hi[k] - lo[k]) / cell) as usize + 4)
        };
        let mut dims = dims_for(cell);
        while dims.iter().map(|&d| d as f64).product::<f64>() > max_cells.max(27) as f64 {
            cell *= 2.0;
            dims = dims_for(cell);
        }
        let mut grid = Occupancy {
            origin: lo,
            cell,
            inv_cell: 1.0 / cell,
            dims,
            occupied: vec![0; dims[0] * dims[1] * dims[2]],
        };
        // Bit 1: the cell holds a point; bit 0: it or a neighbour does. Each cell's
        // neighbourhood is marked once, when its first point arrives (the margin keeps the
        // neighbours inside the grid).
        let (sx, sy) = (1isize, dims[0] as isize);
        let sz = sy * dims[1] as isize;
        for p in points {
            let Some(i) = grid.index(p) else { continue };
            if grid.occupied[i] & 2 != 0 {
                continue;
            }
            grid.occupied[i] |= 2;
            for dz in -1..=1 {
                for dy in -1..=1 {
                    for dx in -1..=1 {
                        let j = i as isize + dx * sx + dy * sy + dz * sz;
                        grid.occupied[j as usize] |= 1;
                    }
                }
            }
        }
        grid
    }

    /// Whether `p` lies in an occupied (or neighbouring) cell.
    #[inline]
    pub fn contains(&self, p: &[f64; 3]) -> bool {
        self.index(p).is_some_and(|i| self.occupied[i] != 0)
    }

    /// Edge length of a cell.
    pub fn cell(&self) -> f64 {
        self.cell
    }

    #[inline]
    fn index(&self, p: &[f64; 3]) -> Option<usize> {
        let mut c = [0usize; 3];
        for k in 0..3 {
            // Cell 0 is the margin below the box: its points have f ≥ 1 exactly.
            let f = (p[k] - self.origin[k]) * self.inv_cell + 1.0;
            if !(f >= 0.0 && f < self.dims[k] as f64) {
                return None;
            }
            // Truncation is the floor here (f ≥ 0) and avoids a libm call.
            c[k] = f as usize;
        }
        Some((c[2] * self.dims[1] + c[1]) * self.dims[0] + c[0])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn occupancy_covers_every_point_within_a_cell_and_little_else() {
        let pts: Vec<[f64; 3]> = (0..100)
            .map(|i| [f64::from(i), 0.5 * f64::from(i), 10.0])
            .collect();
        let g = Occupancy::around(&pts, 4.0, 1 << 20);
        assert_eq!(g.cell(), 4.0);
        for p in &pts {
            for d in [
                [3.9, 0.0, 0.0],
                [0.0, -3.9, 0.0],
                [0.0, 0.0, 3.9],
                [-2.0, 2.0, -2.0],
            ] {
                assert!(
                    g.contains(&[p[0] + d[0], p[1] + d[1], p[2] + d[2]]),
                    "{p:?} + {d:?}"
                );
            }
        }
        assert!(!g.contains(&[50.0, 25.0, 30.0]), "20 mm off the line");
        assert!(!g.contains(&[0.0, 49.5, 10.0]), "across from the line");
        assert!(!g.contains(&[f64::NAN, 0.0, 0.0]));
        // A box too large for the cell budget coarsens the cells instead.
        let wide = [[0.0, 0.0, 0.0], [1.0e5, 1.0e5, 1.0e5]];
        let g = Occupancy::around(&wide, 1.0, 1000);
        assert!(g.cell() > 1.0e4 && g.contains(&[1.0e5, 1.0e5, 1.0e5]));
        assert!(!Occupancy::around(&[], 1.0, 10).contains(&[0.0; 3]));
    }
}
