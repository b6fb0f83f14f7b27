//! Grid operations of the mask: square min/max filters (van Herk / Gil–Werman, O(1) per pixel
//! whatever the radius) and nearest-valid filling of sparse fields.

/// Square grey dilation (maximum over a (2r+1)² window) of a `width`-wide grid.
pub fn max_filter(values: &[f32], width: usize, radius: usize) -> Vec<f32> {
    separable(values, width, radius, f32::max, f32::NEG_INFINITY)
}

/// Square grey erosion (minimum over a (2r+1)² window) of a `width`-wide grid.
pub fn min_filter(values: &[f32], width: usize, radius: usize) -> Vec<f32> {
    separable(values, width, radius, f32::min, f32::INFINITY)
}

fn separable(
    values: &[f32],
    width: usize,
    radius: usize,
    op: fn(f32, f32) -> f32,
    identity: f32,
) -> Vec<f32> {
    if radius == 0 || width == 0 {
        return values.to_vec();
    }
    let height = values.len() / width;
    let mut scratch = Running::new(width.max(height), radius, identity);
    let mut tmp = vec![0.0; values.len()];
    for (src, dst) in values.chunks_exact(width).zip(tmp.chunks_exact_mut(width)) {
        scratch.run(src, op, dst);
    }
    let mut out = vec![0.0; values.len()];
    let mut column = vec![0.0; height];
    let mut result = vec![0.0; height];
    for x in 0..width {
        for (y, c) in column.iter_mut().enumerate() {
            *c = tmp[y * width + x];
        }
        scratch.run(&column, op, &mut result);
        for (y, v) in result.iter().enumerate() {
            out[y * width + x] = *v;
        }
    }
    out
}

/// Buffers of the 1-D running filter (van Herk / Gil–Werman: block prefix and suffix), reused
/// across lines.
struct Running {
    r: usize,
    identity: f32,
    g: Vec<f32>,
    h: Vec<f32>,
}

impl Running {
    fn new(max_len: usize, r: usize, identity: f32) -> Running {
        Running {
            r,
            identity,
            g: vec![identity; max_len + 2 * r],
            h: vec![identity; max_len + 2 * r],
        }
    }

    /// `out[x] = op` over `line[x − r ..= x + r]`.
    fn run(&mut self, line: &[f32], op: fn(f32, f32) -> f32, out: &mut [f32]) {
        let (n, r, id) = (line.len(), self.r, self.identity);
        let k = 2 * r + 1;
        let padded = n + 2 * r;
        let at = |i: usize| -> f32 {
            if i < r || i >= r + n {
                id
            } else {
                line[i - r]
            }
        };
        let (g, h) = (&mut self.g[..padded], &mut self.h[..padded]);
        for i in 0..padded {
            g[i] = if i % k == 0 {
                at(i)
            } else {
                op(g[i - 1], at(i))
            };
        }
        for i in (0..padded).rev() {
            h[i] = if i % k == k - 1 || i == padded - 1 {
                at(i)
            } else {
                op(h[i + 1], at(i))
            };
        }
        for (x, o) in out.iter_mut().enumerate().take(n) {
            *o = op(h[x], g[x + 2 * r]);
        }
    }
}

/// For every invalid cell of a `width`-wide grid, the index of a valid cell at most `radius`
/// cells away (8-connected chamfer propagation of source coordinates, two raster passes), or
/// `None`.
pub(crate) fn nearest_valid(valid: &[bool], width: usize, radius: u32) -> Vec<Option<u32>> {
    const NONE: (i32, i32) = (i32::MIN / 4, i32::MIN / 4);
    let height = valid.len() / width;
    let mut src: Vec<(i32, i32)> = Vec::with_capacity(valid.len());
    for y in 0..height {
        for x in 0..width {
            src.push(if valid[y * width + x] {
                (x as i32, y as i32)
            } else {
                NONE
            });
        }
    }
    let d2 = |x: i32, y: i32, s: (i32, i32)| -> i64 {
        let (dx, dy) = (i64::from(x - s.0), i64::from(y - s.1));
        dx * dx + dy * dy
    };
    let mut pass = |ys: &mut dyn Iterator<Item = usize>, forward: bool| {
        let offsets: [(i32, i32); 4] = if forward {
            [(-1, 0), (-1, -1), (0, -1), (1, -1)]
        } else {
            [(1, 0), (1, 1), (0, 1), (-1, 1)]
        };
        for y in ys {
            for k in 0..width {
                let x = if forward { k } else { width - 1 - k };
                let i = y * width + x;
                let (xi, yi) = (x as i32, y as i32);
                let mut best = src[i];
                let mut best_d = if best == NONE {
                    i64::MAX
                } else {
                    d2(xi, yi, best)
                };
                for (dx, dy) in offsets {
                    let (nx, ny) = (xi + dx, yi + dy);
                    if nx < 0 || ny < 0 || nx as usize >= width || ny as usize >= height {
                        continue;
                    }
                    let s = src[ny as usize * width + nx as usize];
                    if s != NONE {
                        let d = d2(xi, yi, s);
                        if d < best_d {
                            best = s;
                            best_d = d;
                        }
                    }
                }
                src[i] = best;
            }
        }
    };
    pass(&mut (0..height), true);
    pass(&mut (0..height).rev(), false);
    let r2 = i64::from(radius) * i64::from(radius);
    let mut out = Vec::with_capacity(src.len());
    for y in 0..height {
        for x in 0..width {
            let s = src[y * width + x];
            out.push(
                (s != NONE && d2(x as i32, y as i32, s) <= r2)
                    .then(|| (s.1 as usize * width + s.0 as usize) as u32),
            );
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn filters_match_brute_force() {
        let (w, h) = (23usize, 17usize);
        let v: Vec<f32> = (0..w * h).map(|i| ((i * 7919) % 101) as f32).collect();
        for r in [1usize, 2, 5] {
            let mx = max_filter(&v, w, r);
            let mn = min_filter(&v, w, r);
            for y in 0..h {
                for x in 0..w {
                    let (mut a, mut b) = (f32::NEG_INFINITY, f32::INFINITY);
                    for yy in y.saturating_sub(r)..(y + r + 1).min(h) {
                        for xx in x.saturating_sub(r)..(x + r + 1).min(w) {
                            a = a.max(v[yy * w + xx]);
                            b = b.min(v[yy * w + xx]);
                        }
                    }
                    assert_eq!(mx[y * w + x], a, "max r={r} at {x},{y}");
                    assert_eq!(mn[y * w + x], b, "min r={r} at {x},{y}");
                }
            }
        }
    }

    #[test]
    fn nearest_valid_within_radius() {
        let w = 10;
        let mut valid = vec![false; 100];
        valid[0] = true;
        valid[99] = true;
        let n = nearest_valid(&valid, w, 5);
        assert_eq!(n[1], Some(0));
        assert_eq!(n[98], Some(99));
        assert_eq!(n[55], None, "farther than 5 from both");
        assert_eq!(n[33], Some(0));
    }
}
