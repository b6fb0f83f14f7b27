//! A static, balanced 3D kd-tree stored implicitly in one array (median-split ranges), with
//! nearest and k-nearest queries. Built in O(n log n), queried without allocation.

/// Points per leaf range scanned by brute force.
const LEAF: usize = 8;

/// A kd-tree over 3D points; queries return indices into the original point slice.
#[derive(Clone, Debug)]
pub struct KdTree {
    points: Vec<[f64; 3]>,
    index: Vec<u32>,
    dims: Vec<u8>,
}

impl KdTree {
    /// Build over `points` (parallel for large inputs).
    pub fn new(points: &[[f64; 3]]) -> KdTree {
        let mut items: Vec<([f64; 3], u32)> = points
            .iter()
            .enumerate()
            .map(|(i, p)| (*p, i as u32))
            .collect();
        let mut dims = vec![0u8; points.len()];
        build(&mut items, &mut dims);
        let (points, index) = items.into_iter().unzip();
        KdTree {
            points,
            index,
            dims,
        }
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Whether the tree is empty.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Nearest point to `q`: (original index, squared distance).
    pub fn nearest(&self, q: &[f64; 3]) -> Option<(usize, f64)> {
        if self.points.is_empty() {
            return None;
        }
        let mut best = (usize::MAX, f64::INFINITY);
        self.nearest_in(q, 0, self.points.len(), &mut best);
        // A NaN query compares false with everything and finds nothing.
        (best.0 != usize::MAX).then(|| (self.index[best.0] as usize, best.1))
    }

    /// Nearest point to `q` closer than `sqrt(max_d2)`, pruning everything farther: cheap for
    /// queries far from the points, which [`KdTree::nearest`] must search widely.
    pub fn nearest_within(&self, q: &[f64; 3], max_d2: f64) -> Option<(usize, f64)> {
        let mut best = (usize::MAX, max_d2);
        if !self.points.is_empty() {
            self.nearest_in(q, 0, self.points.len(), &mut best);
        }
        (best.0 != usize::MAX).then(|| (self.index[best.0] as usize, best.1))
    }

    fn nearest_in(&self, q: &[f64; 3], lo: usize, hi: usize, best: &mut (usize, f64)) {
        if hi - lo <= LEAF {
            for i in lo..hi {
                let d = dist2(q, &self.points[i]);
                if d < best.1 {
                    *best = (i, d);
                }
            }
            return;
        }
        let m = (lo + hi) / 2;
        let d = dist2(q, &self.points[m]);
        if d < best.1 {
            *best = (m, d);
        }
        let axis = self.dims[m] as usize;
        let diff = q[axis] - self.points[m][axis];
        let (near, far) = if diff < 0.0 {
            ((lo, m), (m + 1, hi))
        } else {
            ((m + 1, hi), (lo, m))
        };
        self.nearest_in(q, near.0, near.1, best);
        if diff * diff < best.1 {
            self.nearest_in(q, far.0, far.1, best);
        }
    }

    /// The `k` nearest points to `q`, written into `out` as (original index, squared distance),
    /// nearest first. `out` is cleared first; its capacity is reused.
    pub fn k_nearest(&self, q: &[f64; 3], k: usize, out: &mut Vec<(usize, f64)>) {
        out.clear();
        if k == 0 || self.points.is_empty() {
            return;
        }
        self.knn_in(q, k, 0, self.points.len(), out);
        for item in out.iter_mut() {
            item.0 = self.index[item.0] as usize;
        }
    }

    /// Every point within distance `r` of `q`, written into `out` as (original index, squared
    /// distance) in no particular order. `out` is cleared first; its capacity is reused.
    pub fn within(&self, q: &[f64; 3], r: f64, out: &mut Vec<(usize, f64)>) {
        out.clear();
        if !self.points.is_empty() && r >= 0.0 {
            self.within_in(q, r * r, 0, self.points.len(), out);
        }
    }

    fn within_in(&self, q: &[f64; 3], r2: f64, lo: usize, hi: usize, out: &mut Vec<(usize, f64)>) {
        if hi - lo <= LEAF {
            for i in lo..hi {
                let d = dist2(q, &self.points[i]);
                if d <= r2 {
                    out.push((self.index[i] as usize, d));
                }
            }
            return;
        }
        let m = (lo + hi) / 2;
        let d = dist2(q, &self.points[m]);
        if d <= r2 {
            out.push((self.index[m] as usize, d));
        }
        let axis = self.dims[m] as usize;
        let diff = q[axis] - self.points[m][axis];
        if diff <= 0.0 || diff * diff <= r2 {
            self.within_in(q, r2, lo, m, out);
        }
        if diff >= 0.0 || diff * diff <= r2 {
            self.within_in(q, r2, m + 1, hi, out);
        }
    }

    fn knn_in(&self, q: &[f64; 3], k: usize, lo: usize, hi: usize, out: &mut Vec<(usize, f64)>) {
        let consider = |i: usize, out: &mut Vec<(usize, f64)>| {
            let d = dist2(q, &self.points[i]);
            if out.len() < k || d < out[out.len() - 1].1 {
                let pos = out.partition_point(|e| e.1 <= d);
                if out.len() == k {
                    out.pop();
                }
                out.insert(pos, (i, d));
            }
        };
        if hi - lo <= LEAF {
            for i in lo..hi {
                consider(i, out);
            }
            return;
        }
        let m = (lo + hi) / 2;
        consider(m, out);
        let axis = self.dims[m] as usize;
        let diff = q[axis] - self.points[m][axis];
        let (near, far) = if diff < 0.0 {
            ((lo, m), (m + 1, hi))
        } else {
            ((m + 1, hi), (lo, m))
        };
        self.knn_in(q, k, near.0, near.1, out);
        if out.len() < k || diff * diff < out[out.len() - 1].1 {
            self.knn_in(q, k, far.0, far.1, out);
        }
    }
}

#[inline]
fn dist2(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    let (x, y, z) = (a[0] - b[0], a[1] - b[1], a[2] - b[2]);
    x * x + y * y + z * z
}

/// Recursive median split on the axis of largest spread; `dims[m]` records the axis of the
/// node at the median position `m` of each range.
fn build(items: &mut [([f64; 3], u32)], dims: &mut [u8]) {
    let n = items.len();
    if n <= LEAF {
        return;
    }
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for (p, _) in items.iter() {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let axis = (0..3)
        .max_by(|&a, &b| (hi[a] - lo[a]).total_cmp(&(hi[b] - lo[b])))
        .unwrap_or(0);
    let m = n / 2;
    items.select_nth_unstable_by(m, |a, b| a.0[axis].total_cmp(&b.0[axis]));
    dims[m] = axis as u8;
    let (left, rest) = items.split_at_mut(m);
    let right = &mut rest[1..];
    let (dl, drest) = dims.split_at_mut(m);
    let dr = &mut drest[1..];
    if n > 20_000 {
        rayon::join(|| build(left, dl), || build(right, dr));
    } else {
        build(left, dl);
        build(right, dr);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cloud(n: usize, seed: u64) -> Vec<[f64; 3]> {
        let mut rng = crate::testing::Rng(seed);
        let mut r = || rng.range(0.0, 100.0);
        (0..n).map(|_| [r(), r(), r() * 0.1]).collect()
    }

    #[test]
    fn within_finds_exactly_the_points_in_the_ball() {
        let pts = cloud(5000, 3);
        let tree = KdTree::new(&pts);
        let mut out = Vec::new();
        for (k, q) in cloud(100, 4).iter().enumerate() {
            let r = 2.0 + k as f64 * 0.1;
            tree.within(q, r, &mut out);
            let mut got: Vec<usize> = out.iter().map(|e| e.0).collect();
            got.sort_unstable();
            let want: Vec<usize> = (0..pts.len())
                .filter(|&i| dist2(q, &pts[i]) <= r * r)
                .collect();
            assert_eq!(got, want);
        }
    }

    #[test]
    fn nearest_and_knn_match_brute_force() {
        let pts = cloud(5000, 1);
        let tree = KdTree::new(&pts);
        let mut out = Vec::new();
        for q in cloud(300, 2) {
            let mut brute: Vec<(usize, f64)> = pts
                .iter()
                .enumerate()
                .map(|(i, p)| (i, dist2(&q, p)))
                .collect();
            brute.sort_by(|a, b| a.1.total_cmp(&b.1));
            let (i, d) = tree.nearest(&q).expect("non-empty");
            assert_eq!(d, brute[0].1);
            assert_eq!(dist2(&q, &pts[i]), d);
            tree.k_nearest(&q, 7, &mut out);
            let got: Vec<f64> = out.iter().map(|e| e.1).collect();
            let want: Vec<f64> = brute[..7].iter().map(|e| e.1).collect();
            assert_eq!(got, want);
            for r2 in [brute[0].1 * 0.5, brute[0].1 * 2.0] {
                let within = tree.nearest_within(&q, r2);
                if brute[0].1 < r2 {
                    assert_eq!(within.map(|w| w.1), Some(brute[0].1));
                } else {
                    assert!(within.is_none());
                }
            }
        }
        assert!(KdTree::new(&[]).nearest(&[0.0; 3]).is_none());
    }
}
