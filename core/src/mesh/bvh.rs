//! Bounding-volume hierarchy over a triangle mesh for nearest ray hits.

use super::TriangleMesh;
use crate::geometry::Vec3;

/// A ray hit: distance along the ray (in units of the ray direction), triangle and its unit
/// geometric normal (outward for counter-clockwise triangles).
#[derive(Clone, Copy, Debug)]
pub struct RayHit {
    /// Ray parameter.
    pub t: f64,
    /// Triangle index.
    pub triangle: u32,
    /// Unit normal.
    pub normal: Vec3,
}

#[derive(Clone, Copy, Debug)]
pub(super) struct Node {
    min: [f64; 3],
    max: [f64; 3],
    /// Leaf: first triangle in `order`; inner: index of the left child (right = left + 1).
    pub(super) start: u32,
    /// Leaf: triangle count; inner: 0.
    pub(super) count: u32,
}

/// A BVH over the triangles of a mesh (median split on the longest axis).
#[derive(Clone, Debug)]
pub struct Bvh {
    mesh: TriangleMesh,
    nodes: Vec<Node>,
    order: Vec<u32>,
    /// The corners of `order`'s triangles, in its order: a leaf's triangles are read in one
    /// run of memory rather than through the triangle and vertex tables.
    corners: Vec<[Vec3; 3]>,
}

const LEAF: usize = 4;

impl Bvh {
    /// Build over `mesh` (takes ownership).
    pub fn new(mesh: TriangleMesh) -> Bvh {
        let n = mesh.triangles.len();
        let centroids: Vec<Vec3> = (0..n)
            .map(|i| {
                let [a, b, c] = mesh.corners(i);
                (a + b + c) / 3.0
            })
            .collect();
        let mut bvh = Bvh {
            mesh,
            nodes: Vec::with_capacity(2 * n / LEAF + 1),
            order: (0..n as u32).collect(),
            corners: Vec::new(),
        };
        bvh.nodes.push(Node {
            min: [0.0; 3],
            max: [0.0; 3],
            start: 0,
            count: n as u32,
        });
        let mut stack = vec![0usize];
        while let Some(ni) = stack.pop() {
            let Node { start, count, .. } = bvh.nodes[ni];
            let (s, c) = (start as usize, count as usize);
            let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
            for &t in &bvh.order[s..s + c] {
                for v in bvh.mesh.corners(t as usize) {
                    for k in 0..3 {
                        lo[k] = lo[k].min(v[k]);
                        hi[k] = hi[k].max(v[k]);
                    }
                }
            }
            bvh.nodes[ni].min = lo;
            bvh.nodes[ni].max = hi;
            if c <= LEAF {
                continue;
            }
            let axis = (0..3)
                .max_by(|&a, &b| (hi[a] - lo[a]).total_cmp(&(hi[b] - lo[b])))
                .unwrap_or(0);
            let mid = c / 2;
            bvh.order[s..s + c].select_nth_unstable_by(mid, |&a, &b| {
                centroids[a as usize][axis].total_cmp(&centroids[b as usize][axis])
            });
            let left = bvh.nodes.len();
            bvh.nodes.push(Node {
                min: lo,
                max: hi,
                start,
                count: mid as u32,
            });
            bvh.nodes.push(Node {
                min: lo,
                max: hi,
                start: start + mid as u32,
                count: (c - mid) as u32,
            });
            bvh.nodes[ni].start = left as u32;
            bvh.nodes[ni].count = 0;
            stack.push(left);
            stack.push(left + 1);
        }
        bvh.corners = bvh
            .order
            .iter()
            .map(|&t| bvh.mesh.corners(t as usize))
            .collect();
        bvh
    }

    /// The mesh this hierarchy was built over.
    pub fn mesh(&self) -> &TriangleMesh {
        &self.mesh
    }

    /// Node `i`.
    pub(super) fn node(&self, i: usize) -> &Node {
        &self.nodes[i]
    }

    /// Triangles of a leaf node, and their corners.
    pub(super) fn leaf(&self, node: &Node) -> (&[u32], &[[Vec3; 3]]) {
        let range = node.start as usize..(node.start + node.count) as usize;
        (&self.order[range.clone()], &self.corners[range])
    }

    /// Squared distance from `p` to the box of node `i` (0 inside).
    pub(super) fn box_distance2(&self, i: usize, p: &Vec3) -> f64 {
        let n = &self.nodes[i];
        (0..3)
            .map(|k| (n.min[k] - p[k]).max(0.0).max(p[k] - n.max[k]))
            .map(|d| d * d)
            .sum()
    }

    /// Axis-aligned bounds of the whole mesh.
    pub fn bounds(&self) -> ([f64; 3], [f64; 3]) {
        (self.nodes[0].min, self.nodes[0].max)
    }

    /// Nearest hit with `t` in `(t_min, t_max)`.
    pub fn intersect(&self, o: &Vec3, d: &Vec3, t_min: f64, t_max: f64) -> Option<RayHit> {
        if self.mesh.triangles.is_empty() {
            return None;
        }
        let inv = [1.0 / d.x, 1.0 / d.y, 1.0 / d.z];
        let mut best: Option<RayHit> = None;
        let mut limit = t_max;
        let mut stack = [0u32; 64];
        let mut sp = 1usize;
        while sp > 0 {
            sp -= 1;
            let node = &self.nodes[stack[sp] as usize];
            if !slab(node, o, &inv, t_min, limit) {
                continue;
            }
            if node.count > 0 {
                let (tris, corners) = self.leaf(node);
                for (&tri, [a, b, c]) in tris.iter().zip(corners) {
                    if let Some(t) = moller_trumbore(o, d, a, b, c) {
                        if t > t_min && t < limit {
                            limit = t;
                            best = Some(RayHit {
                                t,
                                triangle: tri,
                                normal: (b - a).cross(&(c - a)).normalize(),
                            });
                        }
                    }
                }
            } else if sp + 2 <= stack.len() {
                stack[sp] = node.start;
                stack[sp + 1] = node.start + 1;
                sp += 2;
            }
        }
        best
    }
}

#[inline]
fn slab(n: &Node, o: &Vec3, inv: &[f64; 3], t_min: f64, t_max: f64) -> bool {
    let (mut lo, mut hi) = (t_min, t_max);
    for k in 0..3 {
        if inv[k].is_infinite() {
            // Ray parallel to this slab: inside it or never (avoids 0 · ∞ = NaN on a face).
            if o[k] < n.min[k] || o[k] > n.max[k] {
                return false;
            }
            continue;
        }
        let t1 = (n.min[k] - o[k]) * inv[k];
        let t2 = (n.max[k] - o[k]) * inv[k];
        lo = lo.max(t1.min(t2));
        hi = hi.min(t1.max(t2));
    }
    lo <= hi
}

#[inline]
fn moller_trumbore(o: &Vec3, d: &Vec3, a: &Vec3, b: &Vec3, c: &Vec3) -> Option<f64> {
    let e1 = b - a;
    let e2 = c - a;
    let p = d.cross(&e2);
    let det = e1.dot(&p);
    if det.abs() < 1e-14 {
        return None;
    }
    let inv = 1.0 / det;
    let s = o - a;
    let u = s.dot(&p) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(&e1);
    let v = d.dot(&q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    Some(e2.dot(&q) * inv)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(n: usize) -> TriangleMesh {
        let mut m = TriangleMesh::default();
        for j in 0..=n {
            for i in 0..=n {
                m.vertices
                    .push(Vec3::new(i as f64, j as f64, 0.1 * (i as f64 * 0.3).sin()));
            }
        }
        let id = |i: usize, j: usize| (j * (n + 1) + i) as u32;
        for j in 0..n {
            for i in 0..n {
                m.triangles.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
                m.triangles.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
            }
        }
        m
    }

    #[test]
    fn bvh_matches_brute_force() {
        let mesh = grid(30);
        let bvh = Bvh::new(mesh.clone());
        for k in 0..200 {
            let o = Vec3::new(
                (k % 17) as f64 * 1.7 + 0.3,
                (k % 13) as f64 * 2.1 + 0.2,
                10.0,
            );
            let d = Vec3::new(
                0.05 * ((k % 5) as f64 - 2.0),
                0.03 * ((k % 7) as f64 - 3.0),
                -1.0,
            );
            let brute = (0..mesh.triangles.len())
                .filter_map(|i| {
                    let [a, b, c] = mesh.corners(i);
                    moller_trumbore(&o, &d, &a, &b, &c).filter(|&t| t > 0.0)
                })
                .fold(f64::INFINITY, f64::min);
            let got = bvh
                .intersect(&o, &d, 0.0, f64::INFINITY)
                .map_or(f64::INFINITY, |h| h.t);
            assert!(
                (got - brute).abs() < 1e-9 || (got.is_infinite() && brute.is_infinite()),
                "ray {k}: {got} vs {brute}"
            );
        }
    }
}
