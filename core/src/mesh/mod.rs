//! Triangle meshes: STL input (binary and ASCII), a bounding-volume hierarchy for ray casts and
//! signed point-to-mesh distances.

mod bvh;
mod distance;
pub mod stl;

pub use bvh::{Bvh, RayHit};
pub use distance::{Closest, SignedDistance};

use crate::geometry::{Mat3, Vec3};

/// An indexed triangle mesh, mm.
#[derive(Clone, Debug, Default)]
pub struct TriangleMesh {
    /// Vertex positions.
    pub vertices: Vec<Vec3>,
    /// Triangles as vertex indices (counter-clockwise seen from outside).
    pub triangles: Vec<[u32; 3]>,
}

impl TriangleMesh {
    /// Read an STL file (binary or ASCII).
    pub fn load_stl(path: &std::path::Path) -> crate::Result<TriangleMesh> {
        stl::read(path)
    }

    /// Apply `p ↦ R (s p) + t` to every vertex.
    pub fn transform(&mut self, r: &Mat3, scale: f64, t: &Vec3) {
        for v in &mut self.vertices {
            *v = r * (*v * scale) + t;
        }
    }

    /// Corner positions of triangle `i`.
    #[inline]
    pub fn corners(&self, i: usize) -> [Vec3; 3] {
        let [a, b, c] = self.triangles[i];
        [
            self.vertices[a as usize],
            self.vertices[b as usize],
            self.vertices[c as usize],
        ]
    }
}
