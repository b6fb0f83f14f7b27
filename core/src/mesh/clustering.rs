//! Vertex clustering: a coarse stand-in for a fine mesh, for searches that need the part's
//! shape but not its detail (the coarse alignment's hypotheses start hundreds of millimetres
//! off, where a closest-point query visits a large share of a fine mesh's hierarchy).

use super::TriangleMesh;
use crate::geometry::Vec3;
use crate::spatial::{IntMap, IntSet};

impl TriangleMesh {
    /// The mesh with the vertices in each cube of side `cell` (mm, from the lowest corner of
    /// the bounds) merged into their mean, and the triangles that collapse or repeat dropped.
    /// Every vertex moves by less than a cube's diagonal; a smooth surface keeps its shape to
    /// within the sagitta over a cell, while features thinner than a cell (a sheet's two
    /// sides, a fillet) merge. Vertices and triangles keep the order in which they are first
    /// met, so the result does not depend on hashing.
    pub fn clustered(&self, cell: f64) -> TriangleMesh {
        let Some((lo, _)) = self.bounds() else {
            return TriangleMesh::default();
        };
        if !(cell.is_finite() && cell > 0.0) {
            return self.clone();
        }
        let mut ids: IntMap<[i64; 3], u32> = IntMap::default();
        let mut sums: Vec<(Vec3, f64)> = Vec::new();
        let remap: Vec<u32> = self
            .vertices
            .iter()
            .map(|v| {
                let key = [0, 1, 2].map(|k| ((v[k] - lo[k]) / cell).floor() as i64);
                let id = *ids.entry(key).or_insert_with(|| {
                    sums.push((Vec3::zeros(), 0.0));
                    (sums.len() - 1) as u32
                });
                let s = &mut sums[id as usize];
                s.0 += v;
                s.1 += 1.0;
                id
            })
            .collect();
        let mut seen: IntSet<[u32; 3]> = IntSet::default();
        let triangles = self
            .triangles
            .iter()
            .filter_map(|t| {
                let [a, b, c] = t.map(|i| remap[i as usize]);
                if a == b || b == c || a == c {
                    return None;
                }
                let mut key = [a, b, c];
                key.sort_unstable();
                seen.insert(key).then_some([a, b, c])
            })
            .collect();
        TriangleMesh {
            vertices: sums.into_iter().map(|(s, n)| s / n).collect(),
            triangles,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::SignedDistance;

    #[test]
    fn a_clustered_dome_keeps_its_shape_with_fewer_triangles() {
        let dome = |x: f64, y: f64| -(x * x / 4000.0 + y * y / 6000.0);
        let fine = TriangleMesh::height_field(300, 200, (-300.0, 300.0), (-200.0, 200.0), dome);
        let coarse = fine.clustered(10.0);
        assert!(
            coarse.triangles.len() * 10 < fine.triangles.len(),
            "{} of {} triangles",
            coarse.triangles.len(),
            fine.triangles.len()
        );
        // No collapsed or repeated triangle, every index in range.
        let mut keys = std::collections::HashSet::new();
        for t in &coarse.triangles {
            assert!(t[0] != t[1] && t[1] != t[2] && t[0] != t[2], "{t:?}");
            assert!(t.iter().all(|&i| (i as usize) < coarse.vertices.len()));
            let mut k = *t;
            k.sort_unstable();
            assert!(keys.insert(k), "repeated {t:?}");
        }
        // Points on the true surface lie within the sagitta over a few cells of the stand-in
        // (the vertices are cell means of the surface, inside the dome by about h²κ/8), and its
        // normals face the same way (+z, the height field's orientation).
        let sd = SignedDistance::new(coarse);
        for i in 0..50 {
            let (x, y) = (-280.0 + 11.3 * i as f64, -180.0 + 7.1 * i as f64);
            let c = sd.query(&Vec3::new(x, y, dome(x, y))).expect("closest");
            assert!(c.distance.abs() < 0.2, "({x}, {y}): {} mm", c.distance);
            assert!(c.normal.z > 0.9, "({x}, {y}): normal {:?}", c.normal);
        }
    }

    #[test]
    fn no_cell_or_no_vertices_leave_the_mesh_as_it_is() {
        let m = TriangleMesh::height_field(4, 3, (0.0, 4.0), (0.0, 3.0), |_, _| 0.0);
        assert_eq!(m.clustered(0.0).triangles, m.triangles);
        assert_eq!(m.clustered(f64::NAN).triangles, m.triangles);
        assert!(TriangleMesh::default().clustered(1.0).triangles.is_empty());
        // A cell smaller than the spacing merges nothing.
        assert_eq!(m.clustered(0.25).triangles, m.triangles);
    }
}
