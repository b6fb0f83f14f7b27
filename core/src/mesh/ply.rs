//! PLY meshes (ASCII, binary little- or big-endian): the `vertex` element's x, y, z and the
//! `face` element's `vertex_indices` (or `vertex_index`) list, polygons split into fans; other
//! elements and properties are read past.

use crate::cloud::{read_scalar, type_size, Encoding};
use crate::geometry::Vec3;

enum Property {
    Scalar {
        kind: String,
        name: String,
    },
    List {
        count: String,
        item: String,
        name: String,
    },
}

struct Element {
    name: String,
    count: usize,
    properties: Vec<Property>,
}

/// Reads the body one value at a time, in either encoding.
struct Body<'a> {
    bytes: &'a [u8],
    at: usize,
    encoding: Encoding,
}

impl Body<'_> {
    fn value(&mut self, kind: &str) -> Result<f64, String> {
        if self.encoding == Encoding::Ascii {
            let rest = &self.bytes[self.at..];
            let start = rest
                .iter()
                .position(|b| !b.is_ascii_whitespace())
                .ok_or("truncated: the body ends early")?;
            let len = rest[start..]
                .iter()
                .position(u8::is_ascii_whitespace)
                .unwrap_or(rest.len() - start);
            self.at += start + len;
            let token = std::str::from_utf8(&rest[start..start + len]).unwrap_or("");
            return token
                .parse::<f64>()
                .map_err(|_| format!("`{token}` is not a number"));
        }
        let size = type_size(kind).ok_or_else(|| format!("unknown property type `{kind}`"))?;
        let b = self
            .bytes
            .get(self.at..self.at + size)
            .ok_or("truncated: the body ends early")?;
        self.at += size;
        Ok(read_scalar(kind, b, self.encoding))
    }
}

/// The triangles of a PLY mesh's bytes, or why there are none.
pub(super) fn parse(bytes: &[u8]) -> Result<Vec<[Vec3; 3]>, String> {
    let end = bytes
        .windows(10)
        .position(|w| w == b"end_header")
        .ok_or("PLY: no end_header line")?;
    let body_start = bytes[end..]
        .iter()
        .position(|&b| b == b'\n')
        .map(|p| end + p + 1)
        .ok_or("PLY: nothing after end_header")?;
    let header = std::str::from_utf8(&bytes[..end]).map_err(|_| "PLY: header is not text")?;
    let mut encoding = None;
    let mut elements: Vec<Element> = Vec::new();
    for line in header.lines().skip(1) {
        let f: Vec<&str> = line.split_whitespace().collect();
        match f.as_slice() {
            ["format", "ascii", _] => encoding = Some(Encoding::Ascii),
            ["format", "binary_little_endian", _] => encoding = Some(Encoding::Le),
            ["format", "binary_big_endian", _] => encoding = Some(Encoding::Be),
            ["format", other, ..] => return Err(format!("PLY: unknown format `{other}`")),
            ["element", name, n] => elements.push(Element {
                name: name.to_string(),
                count: n
                    .parse()
                    .map_err(|_| format!("PLY: element {name}: bad count `{n}`"))?,
                properties: Vec::new(),
            }),
            ["property", "list", count, item, name] => {
                for t in [count, item] {
                    type_size(t).ok_or_else(|| format!("PLY: unknown property type `{t}`"))?;
                }
                elements
                    .last_mut()
                    .ok_or("PLY: a property before any element")?
                    .properties
                    .push(Property::List {
                        count: count.to_string(),
                        item: item.to_string(),
                        name: name.to_string(),
                    });
            }
            ["property", kind, name] => {
                type_size(kind).ok_or_else(|| format!("PLY: unknown property type `{kind}`"))?;
                elements
                    .last_mut()
                    .ok_or("PLY: a property before any element")?
                    .properties
                    .push(Property::Scalar {
                        kind: kind.to_string(),
                        name: name.to_string(),
                    });
            }
            _ => {}
        }
    }
    let encoding = encoding.ok_or("PLY: no format line")?;
    let vertex = elements
        .iter()
        .find(|e| e.name == "vertex")
        .ok_or("PLY: no vertex element")?;
    let face = elements
        .iter()
        .find(|e| e.name == "face")
        .ok_or("PLY: no face element (a point cloud, not a mesh)")?;
    let scalar = |e: &Element, n: &str| {
        e.properties
            .iter()
            .any(|p| matches!(p, Property::Scalar { name, .. } if name == n))
    };
    if !(scalar(vertex, "x") && scalar(vertex, "y") && scalar(vertex, "z")) {
        return Err("PLY: vertex has no x, y, z properties".into());
    }
    if !face.properties.iter().any(|p| {
        matches!(p, Property::List { name, .. } if name == "vertex_indices" || name == "vertex_index")
    }) {
        return Err("PLY: face has no vertex_indices list".into());
    }
    // A count beyond what the bytes present can hold is refused before anything is allocated:
    // a record takes at least its scalars and list counts in binary, and a character and a
    // separator per property in ASCII.
    let available = bytes.len() - body_start;
    let mut needed = 0usize;
    for e in &elements {
        let least: usize = e
            .properties
            .iter()
            .map(|p| match (encoding, p) {
                (Encoding::Ascii, _) => 2,
                (_, Property::Scalar { kind, .. }) => type_size(kind).unwrap_or(1),
                (_, Property::List { count, .. }) => type_size(count).unwrap_or(1),
            })
            .sum::<usize>()
            .max(1);
        needed = needed.saturating_add(e.count.saturating_mul(least));
        if needed > available + 1 {
            return Err(format!(
                "PLY: truncated: the header claims {} {} records, which need at least {needed} bytes with those before them; the file has {available} after the header",
                e.count, e.name
            ));
        }
    }
    let mut body = Body {
        bytes,
        at: body_start,
        encoding,
    };
    let mut vertices: Vec<Vec3> = Vec::new();
    let mut tris: Vec<[Vec3; 3]> = Vec::new();
    let mut list: Vec<f64> = Vec::new();
    for e in &elements {
        let is_vertex = e.name == "vertex";
        let is_face = e.name == "face";
        if is_vertex {
            vertices.reserve(e.count);
        }
        for r in 0..e.count {
            let mut xyz = [0.0; 3];
            for p in &e.properties {
                match p {
                    Property::Scalar { kind, name } => {
                        let v = body
                            .value(kind)
                            .map_err(|m| format!("PLY: {} {r}: {m}", e.name))?;
                        if is_vertex {
                            match name.as_str() {
                                "x" => xyz[0] = v,
                                "y" => xyz[1] = v,
                                "z" => xyz[2] = v,
                                _ => {}
                            }
                        }
                    }
                    Property::List { count, item, name } => {
                        let n = body
                            .value(count)
                            .map_err(|m| format!("PLY: {} {r}: {m}", e.name))?;
                        if !(0.0..=1e6).contains(&n) || n.fract() != 0.0 {
                            return Err(format!("PLY: {} {r}: list length {n}", e.name));
                        }
                        list.clear();
                        for _ in 0..n as usize {
                            list.push(
                                body.value(item)
                                    .map_err(|m| format!("PLY: {} {r}: {m}", e.name))?,
                            );
                        }
                        if is_face && (name == "vertex_indices" || name == "vertex_index") {
                            fan(&list, &vertices, r, &mut tris)?;
                        }
                    }
                }
            }
            if is_vertex {
                vertices.push(Vec3::new(xyz[0], xyz[1], xyz[2]));
            }
        }
    }
    Ok(tris)
}

/// The triangles of polygon `r` (indices into `vertices`) as a fan.
fn fan(
    indices: &[f64],
    vertices: &[Vec3],
    r: usize,
    tris: &mut Vec<[Vec3; 3]>,
) -> Result<(), String> {
    if indices.len() < 3 {
        return Err(format!("PLY: face {r} has {} vertices", indices.len()));
    }
    let vertex = |i: f64| {
        if i >= 0.0 && i.fract() == 0.0 && (i as usize) < vertices.len() {
            Ok(vertices[i as usize])
        } else {
            Err(format!(
                "PLY: face {r} refers to vertex {i}; there are {} (the vertex element must come first)",
                vertices.len()
            ))
        }
    };
    let first = vertex(indices[0])?;
    for k in 1..indices.len() - 1 {
        tris.push([first, vertex(indices[k])?, vertex(indices[k + 1])?]);
    }
    Ok(())
}
