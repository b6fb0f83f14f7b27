//! Signed distance from points to a triangle mesh (SPEC §2 sign: positive outside the surface,
//! i.e. excess material). The nearest triangle comes from the BVH; the sign from angle-weighted
//! pseudo-normals (Bærentzen & Aanæs), which stay correct when the nearest point is an edge or
//! a vertex.

use crate::spatial::IntMap;

use rayon::prelude::*;

use super::cells::{Cells, Near};
use super::{Bvh, TriangleMesh};
use crate::geometry::Vec3;

/// Which feature of a triangle a closest point lies on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Feature {
    Face,
    Edge(u8),
    Vertex(u8),
}

/// A mesh prepared for signed-distance queries.
pub struct SignedDistance {
    bvh: Bvh,
    /// Cells answering queries near the surface (`None` where the triangles' sizes give none).
    cells: Option<Cells>,
    face_normals: Vec<Vec3>,
    vertex_normals: Vec<Vec3>,
    /// Summed face normals of each edge and how many triangles share it (1: open boundary).
    edge_normals: Vec<(Vec3, u32)>,
    /// Each triangle's edges (from corner k to k + 1) in `edge_normals`.
    triangle_edges: Vec<[u32; 3]>,
    /// Vertices on an open boundary edge.
    boundary_vertex: Vec<bool>,
}

/// The result of one query.
#[derive(Clone, Copy, Debug)]
pub struct Closest {
    /// Signed distance, mm (positive outside).
    pub distance: f64,
    /// Closest point on the mesh.
    pub point: Vec3,
    /// Triangle index.
    pub triangle: u32,
    /// Unit outward normal of that triangle.
    pub normal: Vec3,
    /// The closest point is on an open boundary of the surface (a sheet's rim): the point
    /// lies beyond the modelled surface rather than on or off it.
    pub beyond_boundary: bool,
}

impl SignedDistance {
    /// Prepare `mesh` (consistently oriented, counter-clockwise seen from outside).
    pub fn new(mesh: TriangleMesh) -> SignedDistance {
        let n = mesh.triangles.len();
        let mut face_normals = Vec::with_capacity(n);
        let mut vertex_normals = vec![Vec3::zeros(); mesh.vertices.len()];
        let mut edge_ids: IntMap<(u32, u32), u32> =
            IntMap::with_capacity_and_hasher(n * 3 / 2, Default::default());
        let mut edge_normals: Vec<(Vec3, u32)> = Vec::with_capacity(n * 3 / 2);
        let mut triangle_edges = Vec::with_capacity(n);
        for (t, tri) in mesh.triangles.iter().enumerate() {
            let c = mesh.corners(t);
            let nrm = (c[1] - c[0]).cross(&(c[2] - c[0]));
            let len = nrm.norm();
            let nrm = if len > 0.0 { nrm / len } else { Vec3::zeros() };
            face_normals.push(nrm);
            let mut ids = [0; 3];
            for k in 0..3 {
                let (a, b, o) = (c[k], c[(k + 1) % 3], c[(k + 2) % 3]);
                let (u, v) = ((b - a).normalize(), (o - a).normalize());
                let angle = u.dot(&v).clamp(-1.0, 1.0).acos();
                if angle.is_finite() {
                    vertex_normals[tri[k] as usize] += nrm * angle;
                }
                let key = edge_key(tri[k], tri[(k + 1) % 3]);
                let id = *edge_ids.entry(key).or_insert_with(|| {
                    edge_normals.push((Vec3::zeros(), 0));
                    (edge_normals.len() - 1) as u32
                });
                let e = &mut edge_normals[id as usize];
                e.0 += nrm;
                e.1 += 1;
                ids[k] = id;
            }
            triangle_edges.push(ids);
        }
        let mut boundary_vertex = vec![false; mesh.vertices.len()];
        for (&(a, b), &id) in &edge_ids {
            if edge_normals[id as usize].1 == 1 {
                boundary_vertex[a as usize] = true;
                boundary_vertex[b as usize] = true;
            }
        }
        let bvh = Bvh::new(mesh);
        SignedDistance {
            cells: Cells::new(&bvh),
            bvh,
            face_normals,
            vertex_normals,
            edge_normals,
            triangle_edges,
            boundary_vertex,
        }
    }

    /// The prepared mesh.
    pub fn mesh(&self) -> &TriangleMesh {
        self.bvh.mesh()
    }

    /// Whether edge `k` of triangle `t` (from its corner `k` to the next) is used by that
    /// triangle only: the surface's open boundary (a sheet's rim, a hole cut through it).
    pub fn is_open_edge(&self, t: usize, k: usize) -> bool {
        self.triangle_edges
            .get(t)
            .and_then(|ids| ids.get(k))
            .is_some_and(|&id| self.edge_normals[id as usize].1 == 1)
    }

    /// Signed distance of `p` to the mesh.
    pub fn query(&self, p: &Vec3) -> Option<Closest> {
        self.query_near(p, u32::MAX)
    }

    /// [`SignedDistance::query`] starting from triangle `hint` (e.g. the previous answer for
    /// a point that moved a little, or a neighbouring point's): the same result, found faster
    /// when the hint is close. `u32::MAX` or an index out of range is no hint.
    pub fn query_near(&self, p: &Vec3, hint: u32) -> Option<Closest> {
        let near = match &self.cells {
            Some(cells) => cells.near(&self.bvh, p, hint, closest_on_triangle),
            None => Near::Nothing,
        };
        let (tri, point, feature, d2) = match near {
            Near::Certain(found) => found,
            Near::Bound(tri) => self.bvh.closest(p, tri, closest_on_triangle)?,
            Near::Nothing => self.bvh.closest(p, hint, closest_on_triangle)?,
        };
        let mesh = self.bvh.mesh();
        let ids = mesh.triangles[tri as usize];
        let (normal, beyond_boundary) = match feature {
            Feature::Face => (self.face_normals[tri as usize], false),
            Feature::Edge(k) => {
                let (n, count) =
                    self.edge_normals[self.triangle_edges[tri as usize][k as usize] as usize];
                (n, count == 1)
            }
            Feature::Vertex(k) => {
                let v = ids[k as usize] as usize;
                (self.vertex_normals[v], self.boundary_vertex[v])
            }
        };
        let sign = if (p - point).dot(&normal) >= 0.0 {
            1.0
        } else {
            -1.0
        };
        Some(Closest {
            distance: sign * d2.sqrt(),
            point,
            triangle: tri,
            normal: self.face_normals[tri as usize],
            beyond_boundary,
        })
    }

    /// Signed distances of many points (parallel); NaN for an empty mesh.
    pub fn query_all(&self, points: &[[f64; 3]]) -> Vec<f64> {
        self.map_closest(points, |c| c.map_or(f64::NAN, |c| c.distance))
    }

    /// Deviations for inspection: signed distances, NaN where a point lies beyond the
    /// surface's open boundary (the CAD does not model it there, e.g. past a panel's rim).
    pub fn deviations(&self, points: &[[f64; 3]]) -> Vec<f64> {
        self.map_closest(points, |c| {
            c.filter(|c| !c.beyond_boundary)
                .map_or(f64::NAN, |c| c.distance)
        })
    }

    /// [`SignedDistance::deviations`], and NaN where the closest triangle is not in `mask`
    /// (per triangle: the inspected faces).
    pub fn deviations_on(&self, points: &[[f64; 3]], mask: &[bool]) -> Vec<f64> {
        self.map_closest(points, |c| {
            c.filter(|c| !c.beyond_boundary && mask.get(c.triangle as usize) == Some(&true))
                .map_or(f64::NAN, |c| c.distance)
        })
    }

    /// The bounding-volume hierarchy over the mesh (ray casts).
    pub fn bvh(&self) -> &Bvh {
        &self.bvh
    }

    /// `f` of every point's closest point, in parallel over runs of consecutive points, each
    /// query starting from the previous point's triangle (clouds are stored in scan order, so
    /// neighbours in the list are neighbours on the surface).
    fn map_closest(
        &self,
        points: &[[f64; 3]],
        f: impl Fn(Option<Closest>) -> f64 + Sync,
    ) -> Vec<f64> {
        let mut out = vec![0.0; points.len()];
        out.par_chunks_mut(1024)
            .zip(points.par_chunks(1024))
            .for_each(|(o, pts)| {
                let mut hint = u32::MAX;
                for (o, p) in o.iter_mut().zip(pts) {
                    let c = self.query_near(&Vec3::from(*p), hint);
                    if let Some(c) = &c {
                        hint = c.triangle;
                    }
                    *o = f(c);
                }
            });
        out
    }
}

fn edge_key(a: u32, b: u32) -> (u32, u32) {
    (a.min(b), a.max(b))
}

/// Closest point on triangle (a, b, c) to p (Ericson, Real-Time Collision Detection 5.1.5),
/// with the feature it lies on.
fn closest_on_triangle(p: &Vec3, a: &Vec3, b: &Vec3, c: &Vec3) -> (Vec3, Feature) {
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(&ap), ac.dot(&ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return (*a, Feature::Vertex(0));
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(&bp), ac.dot(&bp));
    if d3 >= 0.0 && d4 <= d3 {
        return (*b, Feature::Vertex(1));
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return (a + ab * (d1 / (d1 - d3)), Feature::Edge(0));
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(&cp), ac.dot(&cp));
    if d6 >= 0.0 && d5 <= d6 {
        return (*c, Feature::Vertex(2));
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return (a + ac * (d2 / (d2 - d6)), Feature::Edge(2));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return (
            b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6))),
            Feature::Edge(1),
        );
    }
    let denom = 1.0 / (va + vb + vc);
    (a + ab * (vb * denom) + ac * (vc * denom), Feature::Face)
}

impl Bvh {
    /// `p`'s closest point on triangle `tri` (`None` for an index out of range) as
    /// [`Bvh::closest`] gives it: (triangle, point, feature, squared distance).
    pub(super) fn at_triangle<F: Copy>(
        &self,
        p: &Vec3,
        tri: u32,
        closest: &impl Fn(&Vec3, &Vec3, &Vec3, &Vec3) -> (Vec3, F),
    ) -> Option<(u32, Vec3, F, f64)> {
        self.mesh().triangles.get(tri as usize)?;
        let [a, b, c] = self.mesh().corners(tri as usize);
        let (q, f) = closest(p, &a, &b, &c);
        Some((tri, q, f, (p - q).norm_squared()))
    }

    /// Nearest triangle to `p` by best-first traversal with box-distance pruning, using
    /// `closest` for the point on a triangle: (triangle, point, feature, squared distance).
    /// `hint` (a triangle index, or out of range for none) is tried first: its distance
    /// bounds the search. Of triangles equally near (a vertex or an edge they share), the
    /// lowest index is the answer, so the result does not depend on the hint or on the
    /// order of the traversal.
    fn closest<F: Copy>(
        &self,
        p: &Vec3,
        hint: u32,
        closest: impl Fn(&Vec3, &Vec3, &Vec3, &Vec3) -> (Vec3, F),
    ) -> Option<(u32, Vec3, F, f64)> {
        if self.mesh().triangles.is_empty() || !p.iter().all(|c| c.is_finite()) {
            return None;
        }
        let mut best = self.at_triangle(p, hint, &closest);
        let mut best_d2 = best.as_ref().map_or(f64::INFINITY, |b| b.3);
        let mut stack = [(self.root(), 0.0f64); 64];
        let mut sp = 1usize;
        while sp > 0 {
            sp -= 1;
            let (sub, box_d2) = stack[sp];
            // A box as near as the best so far may still hold a tie with a lower index.
            if box_d2 > best_d2 * (1.0 + 1e-12) {
                continue;
            }
            if sub.count > 0 {
                let (tris, corners) = self.leaf(sub);
                for (&tri, [a, b, c]) in tris.iter().zip(corners) {
                    let (q, f) = closest(p, a, b, c);
                    let d2 = (p - q).norm_squared();
                    if d2 < best_d2 || (d2 == best_d2 && best.as_ref().is_some_and(|b| tri < b.0)) {
                        best_d2 = d2;
                        best = Some((tri, q, f, d2));
                    }
                }
            } else if sp + 2 <= stack.len() {
                let node = self.node(sub.start);
                let [dl, dr] = node.distance2(p);
                let [l, r] = node.child;
                // Push the farther child first so the nearer is visited next.
                let (first, second) = if dl <= dr {
                    ((r, dr), (l, dl))
                } else {
                    ((l, dl), (r, dr))
                };
                stack[sp] = first;
                stack[sp + 1] = second;
                sp += 2;
            }
        }
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An icosphere-like UV sphere of radius r, outward triangles.
    fn sphere(r: f64, n: usize) -> TriangleMesh {
        let mut m = TriangleMesh::default();
        m.vertices.push(Vec3::new(0.0, 0.0, r));
        for i in 1..n {
            let th = std::f64::consts::PI * i as f64 / n as f64;
            for j in 0..2 * n {
                let ph = std::f64::consts::PI * j as f64 / n as f64;
                m.vertices.push(Vec3::new(
                    r * th.sin() * ph.cos(),
                    r * th.sin() * ph.sin(),
                    r * th.cos(),
                ));
            }
        }
        m.vertices.push(Vec3::new(0.0, 0.0, -r));
        let ring = |i: usize, j: usize| (1 + (i - 1) * 2 * n + j % (2 * n)) as u32;
        let last = (m.vertices.len() - 1) as u32;
        for j in 0..2 * n {
            m.triangles.push([0, ring(1, j), ring(1, j + 1)]);
            m.triangles.push([last, ring(n - 1, j + 1), ring(n - 1, j)]);
        }
        for i in 1..n - 1 {
            for j in 0..2 * n {
                m.triangles
                    .push([ring(i, j), ring(i + 1, j), ring(i + 1, j + 1)]);
                m.triangles
                    .push([ring(i, j), ring(i + 1, j + 1), ring(i, j + 1)]);
            }
        }
        m
    }

    #[test]
    fn signed_distances_match_brute_force_and_the_sign_convention() {
        let mesh = sphere(50.0, 12);
        let sd = SignedDistance::new(mesh.clone());
        let mut rng = crate::testing::Rng(3);
        let mut u = move || rng.range(-1.0, 1.0);
        let n = mesh.triangles.len() as f64;
        for _ in 0..500 {
            let p = Vec3::new(u(), u(), u()) * 80.0;
            let got = sd.query(&p).expect("non-empty");
            // Any hint (near, far, none, out of range) gives the same distance and sign.
            for hint in [
                (0.5 * (u() + 1.0) * n) as u32,
                got.triangle,
                u32::MAX,
                n as u32 + 7,
            ] {
                let h = sd.query_near(&p, hint).expect("non-empty");
                assert!((h.distance - got.distance).abs() < 1e-12, "hint {hint}");
            }
            let brute = (0..mesh.triangles.len())
                .map(|t| {
                    let [a, b, c] = mesh.corners(t);
                    (p - closest_on_triangle(&p, &a, &b, &c).0).norm()
                })
                .fold(f64::INFINITY, f64::min);
            assert!(
                (got.distance.abs() - brute).abs() < 1e-9,
                "{} vs {brute}",
                got.distance
            );
            // Outside the (convex) polyhedron is positive, inside negative.
            let inside = mesh.triangles.iter().all(|t| {
                let (a, b, c) = (
                    mesh.vertices[t[0] as usize],
                    mesh.vertices[t[1] as usize],
                    mesh.vertices[t[2] as usize],
                );
                (b - a).cross(&(c - a)).dot(&(p - a)) <= 0.0
            });
            assert_eq!(
                got.distance < 0.0,
                inside,
                "sign at {p:?}: {}",
                got.distance
            );
        }
        // Exactly above a vertex and an edge: the sign holds there too.
        let v = mesh.vertices[5];
        assert!(sd.query(&(v * 1.1)).expect("q").distance > 0.0);
        assert!(sd.query(&(v * 0.9)).expect("q").distance < 0.0);
    }

    /// Far from the origin an `f32` box is coarser than the distances searched (0.06 mm at
    /// 10⁶ mm): the pruning on boxes rounded outward to `f32` still finds brute force's triangle (the
    /// lowest index of the nearest) and its exact distance, for points on a facet, near it and
    /// off the sphere.
    #[test]
    fn far_from_the_origin_the_nearest_triangle_is_brute_forces() {
        let mut mesh = sphere(5.0, 16);
        let offset = Vec3::new(1.0e6 + 0.013, -2.0e6 + 0.029, 3.0e5);
        for v in &mut mesh.vertices {
            *v += offset;
        }
        let sd = SignedDistance::new(mesh.clone());
        let mut rng = crate::testing::Rng(17);
        for k in 0..3000 {
            let p = if k % 2 == 0 {
                // On a facet, or 0.1 µm off it: nearer than the f32 grid's step.
                let t = (rng.range(0.0, 1.0) * mesh.triangles.len() as f64) as usize;
                let [a, b, c] = mesh.corners(t.min(mesh.triangles.len() - 1));
                let (u, v) = (rng.range(0.0, 1.0), rng.range(0.0, 1.0));
                let (u, v) = if u + v > 1.0 {
                    (1.0 - u, 1.0 - v)
                } else {
                    (u, v)
                };
                let n = (b - a).cross(&(c - a)).normalize();
                a + (b - a) * u + (c - a) * v + n * [0.0, 1e-4, -1e-4][k / 2 % 3]
            } else {
                let dir = Vec3::new(rng.gauss(), rng.gauss(), rng.gauss()).normalize();
                offset + dir * (5.0 + [0.0, -0.02, 0.3, 4.0][k / 2 % 4] * rng.range(0.5, 1.0))
            };
            let (mut best, mut best_d2) = (u32::MAX, f64::INFINITY);
            for t in 0..mesh.triangles.len() {
                let [a, b, c] = mesh.corners(t);
                let d2 = (p - closest_on_triangle(&p, &a, &b, &c).0).norm_squared();
                if d2 < best_d2 {
                    (best, best_d2) = (t as u32, d2);
                }
            }
            let got = sd.query(&p).expect("non-empty");
            assert_eq!(got.triangle, best, "point {k}");
            assert_eq!(got.distance.abs(), best_d2.sqrt(), "point {k}");
        }
    }

    #[test]
    fn a_point_equally_near_several_triangles_gets_the_same_one_whatever_the_hint() {
        let mesh = sphere(50.0, 12);
        let sd = SignedDistance::new(mesh.clone());
        let mut ties = 0;
        for (v, &x) in mesh.vertices.iter().enumerate() {
            // Above a vertex: every triangle around it is nearest at that vertex.
            let p = x * 1.05;
            let around: Vec<u32> = (0..mesh.triangles.len() as u32)
                .filter(|&t| mesh.triangles[t as usize].contains(&(v as u32)))
                .collect();
            let got = sd.query(&p).expect("non-empty");
            assert_eq!(got.point, x, "vertex {v}");
            assert_eq!(got.triangle, around[0], "vertex {v}: the lowest index");
            for &hint in around.iter().chain(&[u32::MAX]) {
                let h = sd.query_near(&p, hint).expect("non-empty");
                assert_eq!(
                    (h.triangle, h.normal),
                    (got.triangle, got.normal),
                    "vertex {v}, hint {hint}"
                );
            }
            ties += around.len() - 1;
        }
        assert!(ties > 500, "{ties} ties");
    }

    /// A mesh of two sheets 0.3 mm apart (a thin plate's faces, the lower one facing down),
    /// beside a fine bumpy grid and two large triangles: crowded, empty and certain cells.
    fn uneven_mesh() -> TriangleMesh {
        let mut m = TriangleMesh::height_field(60, 40, (-60.0, 60.0), (-40.0, 40.0), |x, y| {
            3.0 * (x / 9.0).sin() * (y / 7.0).cos()
        });
        let mut add = |other: TriangleMesh, flip: bool| {
            let base = m.vertices.len() as u32;
            m.vertices.extend(other.vertices);
            m.triangles.extend(other.triangles.iter().map(|t| {
                let t = t.map(|i| i + base);
                if flip {
                    [t[0], t[2], t[1]]
                } else {
                    t
                }
            }));
        };
        add(
            TriangleMesh::height_field(30, 30, (100.0, 160.0), (-30.0, 30.0), |_, _| 0.0),
            false,
        );
        add(
            TriangleMesh::height_field(30, 30, (100.0, 160.0), (-30.0, 30.0), |_, _| -0.3),
            true,
        );
        add(
            TriangleMesh::height_field(2, 2, (-200.0, 200.0), (60.0, 300.0), |x, _| 0.1 * x),
            false,
        );
        m
    }

    #[test]
    fn cells_answer_near_the_surface_exactly_as_the_hierarchy_does() {
        let fine = TriangleMesh::height_field(120, 90, (-300.0, 300.0), (-200.0, 200.0), |x, y| {
            -(x * x / 5000.0 + y * y / 8000.0)
        });
        for (name, mesh) in [
            ("panel", fine),
            ("sphere", sphere(50.0, 24)),
            ("uneven", uneven_mesh()),
        ] {
            let sd = SignedDistance::new(mesh.clone());
            let cells = sd.cells.as_ref().expect("cells");
            let mut rng = crate::testing::Rng(11);
            let (mut certain, mut near_surface) = (0, 0);
            for i in 0..20_000 {
                // a point on a random triangle, moved along its normal by up to 0.01–30 mm
                let t = (rng.range(0.0, 1.0) * mesh.triangles.len() as f64) as usize;
                let t = t.min(mesh.triangles.len() - 1);
                let [a, b, c] = mesh.corners(t);
                let (u, v) = (rng.range(0.0, 1.0), rng.range(0.0, 1.0));
                let (u, v) = if u + v > 1.0 {
                    (1.0 - u, 1.0 - v)
                } else {
                    (u, v)
                };
                let scale = [0.01, 0.1, 1.0, 30.0][i % 4];
                let off = sd.face_normals[t] * rng.range(-1.0, 1.0) * scale;
                let p = a + (b - a) * u + (c - a) * v + off;
                let hint = [u32::MAX, t as u32, (t as u32) ^ 1][i % 3];
                let truth = sd
                    .bvh
                    .closest(&p, u32::MAX, closest_on_triangle)
                    .expect("mesh");
                if scale <= 0.1 {
                    near_surface += 1;
                }
                match cells.near(&sd.bvh, &p, hint, closest_on_triangle) {
                    Near::Certain(got) => {
                        certain += usize::from(scale <= 0.1);
                        assert_eq!(
                            (got.0, got.1, got.2, got.3.to_bits()),
                            (truth.0, truth.1, truth.2, truth.3.to_bits()),
                            "{name}: {p:?}"
                        );
                    }
                    Near::Bound(_) | Near::Nothing => {}
                }
                let q = sd.query_near(&p, hint).expect("mesh");
                assert_eq!((q.triangle, q.point), (truth.0, truth.1), "{name}: {p:?}");
            }
            // Most points within 0.1 mm of the surface are answered by their cell.
            assert!(
                certain * 10 >= near_surface * 6,
                "{name}: {certain} of {near_surface} near the surface"
            );
        }
    }

    #[test]
    fn points_past_a_sheets_rim_are_beyond_its_boundary() {
        let sheet = TriangleMesh::height_field(10, 10, (-50.0, 50.0), (-50.0, 50.0), |_, _| 0.0);
        let sd = SignedDistance::new(sheet);
        let at = |x: f64, y: f64, z: f64| sd.query(&Vec3::new(x, y, z)).expect("closest");
        // Above and below the interior, including over interior edges and vertices.
        for (x, y, z) in [
            (3.0, 7.0, 2.0),
            (0.0, 0.0, -1.5),
            (10.0, 10.0, 0.3),
            (49.0, 0.0, 1.0),
        ] {
            let c = at(x, y, z);
            assert!(!c.beyond_boundary, "({x}, {y}, {z})");
            assert!(
                (c.distance - z).abs() < 1e-9,
                "({x}, {y}, {z}): {}",
                c.distance
            );
        }
        // Past the rim (an edge) and past a corner (a vertex).
        assert!(at(51.0, 0.0, -2.0).beyond_boundary);
        assert!(at(55.0, -60.0, 0.5).beyond_boundary);
        let dev = sd.deviations(&[[0.0, 0.0, 0.2], [52.0, 3.0, -1.0]]);
        assert!((dev[0] - 0.2).abs() < 1e-9 && dev[1].is_nan(), "{dev:?}");
        // A closed surface has no boundary.
        let ball = SignedDistance::new(sphere(50.0, 12));
        let c = ball.query(&Vec3::new(0.0, 80.0, 0.0)).expect("closest");
        assert!(!c.beyond_boundary);
    }
}
