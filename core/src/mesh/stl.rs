//! STL reading, binary and ASCII, and the welding every mesh reader ends with.

use std::collections::HashMap;
use std::path::Path;

use super::TriangleMesh;
use crate::geometry::Vec3;
use crate::{Error, Result};

/// The triangles of an STL file's bytes (binary or ASCII), or why there are none.
pub(super) fn parse(bytes: &[u8]) -> std::result::Result<Vec<[Vec3; 3]>, String> {
    if is_binary(bytes) {
        let n = u32::from_le_bytes([bytes[80], bytes[81], bytes[82], bytes[83]]) as usize;
        let f = |o: usize| {
            f64::from(f32::from_le_bytes([
                bytes[o],
                bytes[o + 1],
                bytes[o + 2],
                bytes[o + 3],
            ]))
        };
        return Ok((0..n)
            .map(|i| {
                let base = 84 + i * 50 + 12;
                [0, 1, 2].map(|k| {
                    let o = base + k * 12;
                    Vec3::new(f(o), f(o + 4), f(o + 8))
                })
            })
            .collect());
    }
    let text = std::str::from_utf8(bytes).map_err(|_| {
        "neither a binary STL (its size does not match its triangle count) nor text".to_string()
    })?;
    let mut verts = Vec::new();
    for (ln, line) in text.lines().enumerate() {
        let mut it = line.split_whitespace();
        if it.next() == Some("vertex") {
            let xyz: Vec<f64> = it
                .map(|s| s.parse::<f64>())
                .collect::<std::result::Result<_, _>>()
                .map_err(|_| format!("line {}: bad vertex", ln + 1))?;
            if xyz.len() != 3 {
                return Err(format!("line {}: vertex needs 3 numbers", ln + 1));
            }
            verts.push(Vec3::new(xyz[0], xyz[1], xyz[2]));
        }
    }
    if verts.len() % 3 != 0 {
        return Err(format!(
            "{} vertices is not a whole number of triangles",
            verts.len()
        ));
    }
    Ok(verts.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
}

/// A mesh from a triangle soup read from `path`: non-finite vertices refused, vertices welded,
/// zero-area triangles left out with a warning, a mesh with none left refused.
pub(super) fn finish(path: &Path, tris: Vec<[Vec3; 3]>) -> Result<TriangleMesh> {
    let bad = |m: String| Error::Format {
        path: path.to_path_buf(),
        message: m,
    };
    if tris.is_empty() {
        return Err(bad("mesh has no triangles".into()));
    }
    if tris
        .iter()
        .flatten()
        .any(|v| !v.iter().all(|c| c.is_finite()))
    {
        return Err(bad("mesh has a non-finite vertex".into()));
    }
    let (mesh, degenerate) = weld(tris);
    if mesh.triangles.is_empty() {
        return Err(bad(format!(
            "mesh has no usable triangle: all {degenerate} have zero area (repeated or collinear corners)"
        )));
    }
    if degenerate > 0 {
        tracing::warn!(path = %path.display(), degenerate, "zero-area triangles left out of the mesh");
    }
    Ok(mesh)
}

/// Weld vertices by exact position and drop zero-area triangles (repeated or collinear
/// corners: they have no normal and no surface); returns the mesh and how many were dropped.
pub(crate) fn weld(tris: Vec<[Vec3; 3]>) -> (TriangleMesh, usize) {
    let n = tris.len();
    let (mesh, kept) = weld_tagged(tris);
    (mesh, n - kept.len())
}

/// [`weld`], returning for each triangle of the mesh the index of the input triangle it came
/// from (so per-triangle data such as a CAD face id follows the triangles that were kept).
pub(crate) fn weld_tagged(tris: Vec<[Vec3; 3]>) -> (TriangleMesh, Vec<usize>) {
    let mut mesh = TriangleMesh::default();
    let mut kept = Vec::with_capacity(tris.len());
    let mut index: HashMap<[u64; 3], u32> = HashMap::new();
    for (i, t) in tris.into_iter().enumerate() {
        let scale = (t[1] - t[0]).norm().max((t[2] - t[0]).norm());
        let area2 = (t[1] - t[0]).cross(&(t[2] - t[0])).norm();
        if area2.is_nan() || area2 <= 1e-12 * scale * scale {
            continue;
        }
        let ids = t.map(|v| {
            *index
                .entry([v.x.to_bits(), v.y.to_bits(), v.z.to_bits()])
                .or_insert_with(|| {
                    mesh.vertices.push(v);
                    (mesh.vertices.len() - 1) as u32
                })
        });
        if ids[0] != ids[1] && ids[1] != ids[2] && ids[0] != ids[2] {
            mesh.triangles.push(ids);
            kept.push(i);
        }
    }
    (mesh, kept)
}

pub(super) fn is_binary(bytes: &[u8]) -> bool {
    if bytes.len() < 84 {
        return false;
    }
    let n = u32::from_le_bytes([bytes[80], bytes[81], bytes[82], bytes[83]]) as usize;
    n.checked_mul(50).and_then(|b| b.checked_add(84)) == Some(bytes.len())
}

/// Write a binary STL (used by tests and the simulator's fixtures).
pub fn write_binary(path: &Path, mesh: &TriangleMesh) -> Result<()> {
    let mut buf = vec![0u8; 80];
    buf.extend_from_slice(&(mesh.triangles.len() as u32).to_le_bytes());
    for i in 0..mesh.triangles.len() {
        let [a, b, c] = mesh.corners(i);
        let n = (b - a).cross(&(c - a)).normalize();
        for v in [n, a, b, c] {
            for k in 0..3 {
                buf.extend_from_slice(&(v[k] as f32).to_le_bytes());
            }
        }
        buf.extend_from_slice(&[0, 0]);
    }
    crate::io::write_atomic(path, &buf)
}
