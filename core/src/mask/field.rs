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
    let mut tmp = vec![0.0; values.len()];
    let mut line = Vec::new();
    let mut out_line = Vec::new();
    for y in 0..height {
        line.clear();
        line.extend_from_slice(&values[y * width..(y + 1) * width]);
        running(&line, radius, op, identity, &mut out_line);
        tmp[y * width..(y + 1) * width].copy_from_slice(&out_line);
    }
    let mut out = vec![0.0; values.len()];
    for x in 0..width {
        line.clear();
        line.extend((0..height).map(|y| tmp[y * width + x]));
        running(&line, radius, op, identity, &mut out_line);
        for (y, v) in out_line.iter().enumerate() {
            out[y * width + x] = *v;
        }
    }
    out
}

/// 1-D running `op` over windows of 2r+1 (van Herk / Gil–Werman: block prefix and suffix).
fn running(line: &[f32], r: usize, op: fn(f32, f32) -> f32, identity: f32, out: &mut Vec<f32>) {
    let n = line.len();
    let k = 2 * r + 1;
    let padded = n + 2 * r;
    let at = |i: usize| -> f32 {
        if i < r || i >= r + n {
            identity
        } else {
            line[i - r]
        }
    };
    let mut g = vec![identity; padded];
    let mut h = vec![identity; padded];
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
    out.clear();
    out.extend((0..n).map(|x| op(h[x], g[x + 2 * r])));
}

/// For every invalid cell of a `width`-wide grid, the index of a valid cell at most `radius`
/// cells away (8-connected chamfer propagation, two raster passes), or `None`.
pub(crate) fn nearest_valid(valid: &[bool], width: usize, radius: u32) -> Vec<Option<u32>> {
    let height = valid.len() / width;
    let mut src: Vec<Option<u32>> = valid
        .iter()
        .enumerate()
        .map(|(i, &v)| v.then_some(i as u32))
        .collect();
    let d2 = |i: usize, s: u32| {
        let (x, y) = ((i % width) as i64, (i / width) as i64);
        let (sx, sy) = ((s as usize % width) as i64, (s as usize / width) as i64);
        (x - sx).pow(2) + (y - sy).pow(2)
    };
    let relax = |i: usize, j: usize, src: &mut [Option<u32>]| {
        if let Some(s) = src[j] {
            if src[i].is_none_or(|c| d2(i, s) < d2(i, c)) {
                src[i] = Some(s);
            }
        }
    };
    for y in 0..height {
        for x in 0..width {
            let i = y * width + x;
            if x > 0 {
                relax(i, i - 1, &mut src);
            }
            if y > 0 {
                relax(i, i - width, &mut src);
                if x > 0 {
                    relax(i, i - width - 1, &mut src);
                }
                if x + 1 < width {
                    relax(i, i - width + 1, &mut src);
                }
            }
        }
    }
    for y in (0..height).rev() {
        for x in (0..width).rev() {
            let i = y * width + x;
            if x + 1 < width {
                relax(i, i + 1, &mut src);
            }
            if y + 1 < height {
                relax(i, i + width, &mut src);
                if x + 1 < width {
                    relax(i, i + width + 1, &mut src);
                }
                if x > 0 {
                    relax(i, i + width - 1, &mut src);
                }
            }
        }
    }
    let r2 = i64::from(radius) * i64::from(radius);
    src.iter()
        .enumerate()
        .map(|(i, s)| s.filter(|&s| d2(i, s) <= r2))
        .collect()
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
