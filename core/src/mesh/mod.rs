//! Triangle meshes: STL (binary and ASCII), PLY, OBJ and STEP (feature `step`) input, a
//! bounding-volume hierarchy for ray casts and signed point-to-mesh distances.

mod bvh;
mod cells;
mod clustering;
mod distance;
mod obj;
mod ply;
pub mod step;
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
    /// Axis-aligned bounds of the vertices (`None` without vertices).
    pub fn bounds(&self) -> Option<([f64; 3], [f64; 3])> {
        let first = self.vertices.first()?;
        let mut lo = [first.x, first.y, first.z];
        let mut hi = lo;
        for v in &self.vertices {
            for k in 0..3 {
                lo[k] = lo[k].min(v[k]);
                hi[k] = hi[k].max(v[k]);
            }
        }
        Some((lo, hi))
    }

    /// Read a mesh in any supported format: STL (binary or ASCII), PLY (ASCII or binary, a
    /// `vertex` and a `face` element; polygons split into fans), Wavefront OBJ (`v` and `f`
    /// lines; polygons split into fans) or STEP (tessellated by [`step::read`] with its default
    /// options; its faces are dropped here). The format is recognised by content (`ply` magic,
    /// STL size or `solid`, OBJ statements, the ISO 10303-21 header), whatever the extension.
    pub fn load(path: &std::path::Path) -> crate::Result<TriangleMesh> {
        let bytes = std::fs::read(path).map_err(|e| crate::Error::io(path, e))?;
        if step::looks_like(&bytes) {
            drop(bytes);
            return step::read(path, &step::StepOptions::default()).map(|m| m.mesh);
        }
        let tris = if stl::is_binary(&bytes) {
            stl::parse(&bytes)
        } else if bytes.starts_with(b"ply") {
            ply::parse(&bytes)
        } else if obj::looks_like(&bytes) {
            obj::parse(&bytes)
        } else {
            stl::parse(&bytes).map_err(|e| {
                format!("{e}; the CAD formats read are STL (binary or ASCII), PLY and OBJ meshes and STEP")
            })
        }
        .map_err(|message| crate::Error::Format {
            path: path.to_path_buf(),
            message,
        })?;
        stl::finish(path, tris)
    }

    /// Apply `p ↦ R (s p) + t` to every vertex.
    pub fn transform(&mut self, r: &Mat3, scale: f64, t: &Vec3) {
        for v in &mut self.vertices {
            *v = r * (*v * scale) + t;
        }
    }

    /// A height field z = f(x, y) over [x0, x1] × [y0, y1] with nx × ny cells (two triangles
    /// each, counter-clockwise seen from +z): CAD stand-ins for tests, benchmarks and demos.
    pub fn height_field(
        nx: usize,
        ny: usize,
        (x0, x1): (f64, f64),
        (y0, y1): (f64, f64),
        z: impl Fn(f64, f64) -> f64,
    ) -> TriangleMesh {
        let mut m = TriangleMesh::default();
        for j in 0..=ny {
            for i in 0..=nx {
                let (x, y) = (
                    x0 + (x1 - x0) * i as f64 / nx as f64,
                    y0 + (y1 - y0) * j as f64 / ny as f64,
                );
                m.vertices.push(Vec3::new(x, y, z(x, y)));
            }
        }
        let id = |i: usize, j: usize| (j * (nx + 1) + i) as u32;
        for j in 0..ny {
            for i in 0..nx {
                m.triangles.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
                m.triangles.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
            }
        }
        m
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
