//! Wavefront OBJ meshes: `v` and `f` statements (faces as `i`, `i/t`, `i//n` or `i/t/n`,
//! negative indices counted back from the last vertex), polygons split into fans; every other
//! statement (normals, texture coordinates, groups, materials) is ignored.

use super::stl;
use crate::geometry::Vec3;

/// Whether `bytes` look like an OBJ file: not a binary STL, text with a `v` statement near the
/// start, and no ASCII STL keyword.
pub(super) fn looks_like(bytes: &[u8]) -> bool {
    if stl::is_binary(bytes) {
        return false;
    }
    let head = &bytes[..bytes.len().min(1 << 16)];
    let text = String::from_utf8_lossy(head);
    let mut lines = text.lines().map(str::trim_start);
    let first = lines.clone().find(|l| !l.is_empty() && !l.starts_with('#'));
    if first.is_some_and(|l| l.starts_with("solid")) {
        return false;
    }
    lines.any(|l| l.starts_with("v ") || l.starts_with("v\t"))
}

/// The triangles of an OBJ file's bytes, or why there are none (naming the line).
pub(super) fn parse(bytes: &[u8]) -> Result<Vec<[Vec3; 3]>, String> {
    let text = std::str::from_utf8(bytes).map_err(|e| {
        format!(
            "OBJ: not UTF-8 text (byte {})",
            e.valid_up_to().saturating_add(1)
        )
    })?;
    let mut vertices: Vec<Vec3> = Vec::new();
    let mut tris = Vec::new();
    let mut face: Vec<usize> = Vec::new();
    for (ln, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or_default();
        let mut it = line.split_whitespace();
        match it.next() {
            Some("v") => {
                let mut xyz = [0.0; 3];
                for c in &mut xyz {
                    *c = it
                        .next()
                        .and_then(|s| s.parse::<f64>().ok())
                        .ok_or_else(|| format!("line {}: `v` needs three numbers", ln + 1))?;
                }
                vertices.push(Vec3::new(xyz[0], xyz[1], xyz[2]));
            }
            Some("f") => {
                face.clear();
                for token in it {
                    let first = token.split('/').next().unwrap_or_default();
                    let i: i64 = first.parse().map_err(|_| {
                        format!("line {}: `{token}` is not a vertex reference", ln + 1)
                    })?;
                    let n = vertices.len() as i64;
                    let index = if i > 0 { i - 1 } else { n + i };
                    if i == 0 || index < 0 || index >= n {
                        return Err(format!(
                            "line {}: vertex {i} does not exist ({n} vertices so far)",
                            ln + 1
                        ));
                    }
                    face.push(index as usize);
                }
                if face.len() < 3 {
                    return Err(format!(
                        "line {}: a face needs at least three vertices",
                        ln + 1
                    ));
                }
                for k in 1..face.len() - 1 {
                    tris.push([vertices[face[0]], vertices[face[k]], vertices[face[k + 1]]]);
                }
            }
            _ => {}
        }
    }
    if tris.is_empty() {
        return Err(format!(
            "OBJ: no faces ({} vertices, no `f` statement)",
            vertices.len()
        ));
    }
    Ok(tris)
}
