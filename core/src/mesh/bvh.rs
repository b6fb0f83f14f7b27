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

/// A subtree: a leaf's triangles (`count > 0`, from `start` in the leaf order) or an inner
/// node (`count == 0`, `start` its index among the nodes).
#[derive(Clone, Copy, Debug)]
pub(super) struct Child {
    pub(super) start: u32,
    pub(super) count: u32,
}

/// An inner node: its two children and their boxes side by side, in `f32` rounded outward (a
/// box never shrinks, so what it prunes is exactly what the `f64` box would), one cache line a
/// node: a traversal step reads one line and tests both children at once.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(64))]
pub(super) struct Node {
    /// `min[axis][child]`.
    min: [[f32; 2]; 3],
    /// `max[axis][child]`.
    max: [[f32; 2]; 3],
    pub(super) child: [Child; 2],
}

impl Node {
    /// Squared distances from `p` to the two children's boxes (0 inside).
    #[inline]
    pub(super) fn distance2(&self, p: &Vec3) -> [f64; 2] {
        let mut d = [0.0; 2];
        for k in 0..3 {
            for (c, d) in d.iter_mut().enumerate() {
                let e = (f64::from(self.min[k][c]) - p[k])
                    .max(0.0)
                    .max(p[k] - f64::from(self.max[k][c]));
                *d += e * e;
            }
        }
        d
    }

    /// Whether the ray meets child `c`'s box within `(t_min, t_max)`.
    #[inline]
    fn slab(&self, c: usize, o: &Vec3, inv: &[f64; 3], t_min: f64, t_max: f64) -> bool {
        let lo = self.min.map(|m| f64::from(m[c]));
        let hi = self.max.map(|m| f64::from(m[c]));
        slab(&lo, &hi, o, inv, t_min, t_max)
    }
}

/// A BVH over the triangles of a mesh (median split on the longest axis).
#[derive(Clone, Debug)]
pub struct Bvh {
    mesh: TriangleMesh,
    /// Inner nodes, parents before children (a subtree's nodes are contiguous).
    nodes: Vec<Node>,
    root: Child,
    bounds: ([f64; 3], [f64; 3]),
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
            nodes: Vec::with_capacity(n / LEAF + 1),
            root: Child { start: 0, count: 0 },
            bounds: ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]),
            order: (0..n as u32).collect(),
            corners: Vec::new(),
        };
        let (root, lo, hi) = bvh.build(&centroids, 0, n);
        bvh.root = root;
        bvh.bounds = (lo, hi);
        bvh.corners = bvh
            .order
            .iter()
            .map(|&t| bvh.mesh.corners(t as usize))
            .collect();
        bvh
    }

    /// The subtree over `order[start..start + count]` and its box; inner nodes are appended
    /// parent first.
    fn build(
        &mut self,
        centroids: &[Vec3],
        start: usize,
        count: usize,
    ) -> (Child, [f64; 3], [f64; 3]) {
        let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        for &t in &self.order[start..start + count] {
            for v in self.mesh.corners(t as usize) {
                for k in 0..3 {
                    lo[k] = lo[k].min(v[k]);
                    hi[k] = hi[k].max(v[k]);
                }
            }
        }
        if count <= LEAF {
            let leaf = Child {
                start: start as u32,
                count: count as u32,
            };
            return (leaf, lo, hi);
        }
        let axis = (0..3)
            .max_by(|&a, &b| (hi[a] - lo[a]).total_cmp(&(hi[b] - lo[b])))
            .unwrap_or(0);
        let mid = count / 2;
        self.order[start..start + count].select_nth_unstable_by(mid, |&a, &b| {
            centroids[a as usize][axis].total_cmp(&centroids[b as usize][axis])
        });
        let index = self.nodes.len();
        let empty = Child { start: 0, count: 0 };
        self.nodes.push(Node {
            min: [[0.0; 2]; 3],
            max: [[0.0; 2]; 3],
            child: [empty, empty],
        });
        let (left, llo, lhi) = self.build(centroids, start, mid);
        let (right, rlo, rhi) = self.build(centroids, start + mid, count - mid);
        let node = &mut self.nodes[index];
        node.child = [left, right];
        for k in 0..3 {
            node.min[k] = [down(llo[k]), down(rlo[k])];
            node.max[k] = [up(lhi[k]), up(rhi[k])];
        }
        let node = Child {
            start: index as u32,
            count: 0,
        };
        (node, lo, hi)
    }

    /// The mesh this hierarchy was built over.
    pub fn mesh(&self) -> &TriangleMesh {
        &self.mesh
    }

    /// The whole tree (a leaf when the mesh has at most a leaf's triangles).
    pub(super) fn root(&self) -> Child {
        self.root
    }

    /// Inner node `i`.
    #[inline]
    pub(super) fn node(&self, i: u32) -> &Node {
        &self.nodes[i as usize]
    }

    /// Triangles of a leaf, and their corners.
    #[inline]
    pub(super) fn leaf(&self, leaf: Child) -> (&[u32], &[[Vec3; 3]]) {
        let range = leaf.start as usize..(leaf.start + leaf.count) as usize;
        (&self.order[range.clone()], &self.corners[range])
    }

    /// The triangles in leaf order, and their corners.
    pub(super) fn leaf_order(&self) -> (&[u32], &[[Vec3; 3]]) {
        (&self.order, &self.corners)
    }

    /// Axis-aligned bounds of the whole mesh.
    pub fn bounds(&self) -> ([f64; 3], [f64; 3]) {
        self.bounds
    }

    /// Nearest hit with `t` in `(t_min, t_max)`.
    pub fn intersect(&self, o: &Vec3, d: &Vec3, t_min: f64, t_max: f64) -> Option<RayHit> {
        if self.mesh.triangles.is_empty() {
            return None;
        }
        let inv = [1.0 / d.x, 1.0 / d.y, 1.0 / d.z];
        let (lo, hi) = self.bounds;
        if !slab(&lo, &hi, o, &inv, t_min, t_max) {
            return None;
        }
        let mut best: Option<RayHit> = None;
        let mut limit = t_max;
        let mut stack = [self.root; 64];
        let mut sp = 1usize;
        while sp > 0 {
            sp -= 1;
            let sub = stack[sp];
            if sub.count > 0 {
                let (tris, corners) = self.leaf(sub);
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
                continue;
            }
            let node = self.node(sub.start);
            // The right child is visited first, as it always was (equal hits keep the first).
            for c in 0..2 {
                if sp < stack.len() && node.slab(c, o, &inv, t_min, limit) {
                    stack[sp] = node.child[c];
                    sp += 1;
                }
            }
        }
        best
    }
}

/// The largest `f32` at or below `v`.
fn down(v: f64) -> f32 {
    let f = v as f32;
    if f64::from(f) > v {
        f.next_down()
    } else {
        f
    }
}

/// The smallest `f32` at or above `v`.
fn up(v: f64) -> f32 {
    let f = v as f32;
    if f64::from(f) < v {
        f.next_up()
    } else {
        f
    }
}

#[inline]
fn slab(lo: &[f64; 3], hi: &[f64; 3], o: &Vec3, inv: &[f64; 3], t_min: f64, t_max: f64) -> bool {
    let (mut t0, mut t1) = (t_min, t_max);
    for k in 0..3 {
        if inv[k].is_infinite() {
            // Ray parallel to this slab: inside it or never (avoids 0 · ∞ = NaN on a face).
            if o[k] < lo[k] || o[k] > hi[k] {
                return false;
            }
            continue;
        }
        let a = (lo[k] - o[k]) * inv[k];
        let b = (hi[k] - o[k]) * inv[k];
        t0 = t0.max(a.min(b));
        t1 = t1.min(a.max(b));
    }
    t0 <= t1
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

    /// The nearest hit ahead of `o` along `d` through the hierarchy and by testing every
    /// triangle (infinite for none).
    fn hit_and_brute_force(bvh: &Bvh, mesh: &TriangleMesh, o: &Vec3, d: &Vec3) -> (f64, f64) {
        let brute = (0..mesh.triangles.len())
            .filter_map(|i| {
                let [a, b, c] = mesh.corners(i);
                moller_trumbore(o, d, &a, &b, &c).filter(|&t| t > 0.0)
            })
            .fold(f64::INFINITY, f64::min);
        let got = bvh
            .intersect(o, d, 0.0, f64::INFINITY)
            .map_or(f64::INFINITY, |h| h.t);
        (got, brute)
    }

    #[test]
    fn boxes_round_outward_to_f32() {
        let mut rng = crate::testing::Rng(11);
        for _ in 0..10_000 {
            let v = rng.range(-1.0, 1.0) * 10f64.powf(rng.range(-3.0, 7.0));
            let (lo, hi) = (f64::from(down(v)), f64::from(up(v)));
            assert!(lo <= v && v <= hi, "{v}: [{lo}, {hi}]");
            // The nearest f32 on each side: no looser than one step.
            assert!(f64::from(down(v).next_up()) > v || lo == v, "{v}");
            assert!(f64::from(up(v).next_down()) < v || hi == v, "{v}");
        }
    }

    #[test]
    fn bvh_far_from_the_origin_matches_brute_force() {
        // At 1e6 mm an f32 step is 0.06 mm: boxes must still hold every hit.
        let mut mesh = grid(20);
        for v in &mut mesh.vertices {
            *v += Vec3::new(1.0e6 + 0.013, -2.0e6 + 0.029, 3.0e5);
        }
        let bvh = Bvh::new(mesh.clone());
        let mut rng = crate::testing::Rng(5);
        for k in 0..300 {
            let o = Vec3::new(
                1.0e6 + rng.range(0.0, 20.0),
                -2.0e6 + rng.range(0.0, 20.0),
                3.0e5 + 5.0,
            );
            let d = Vec3::new(rng.range(-0.2, 0.2), rng.range(-0.2, 0.2), -1.0);
            let (got, brute) = hit_and_brute_force(&bvh, &mesh, &o, &d);
            assert!(
                got == brute || (got.is_infinite() && brute.is_infinite()),
                "ray {k}: {got} vs {brute}"
            );
        }
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
            let (got, brute) = hit_and_brute_force(&bvh, &mesh, &o, &d);
            assert!(
                (got - brute).abs() < 1e-9 || (got.is_infinite() && brute.is_infinite()),
                "ray {k}: {got} vs {brute}"
            );
        }
    }
}
