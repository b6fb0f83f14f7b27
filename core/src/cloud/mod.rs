//! Point clouds and PLY files (SPEC §2): written as binary little-endian `x y z confidence`
//! float32; read from ASCII or binary PLY with float or double coordinates. E57 in `e57`.
//!
//! A cloud from one camera is *organised*: each point keeps the camera pixel it was measured
//! at. PLY carries it as `row` and `column` (uint) with the image size in the PCL-style header
//! lines `obj_info num_cols W` and `obj_info num_rows H`; E57 as `rowIndex`/`columnIndex` with
//! the image's extent as the cloud's index bounds.

mod e57;
mod merge;
pub mod pointcloud2;

pub use merge::{merge, MergeStats, Merger};

use std::path::Path;

use crate::io::write_atomic;
use crate::{Error, Result};

/// A point cloud with a per-point confidence and, when it came from a camera, the pixel index.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PointCloud {
    /// Positions, mm.
    pub points: Vec<[f32; 3]>,
    /// Confidence per point (1 when unknown).
    pub confidence: Vec<f32>,
    /// Row-major camera pixel index per point (empty when not organised).
    pub pixels: Vec<u32>,
    /// The camera image (width, height) that `pixels` index; `None` when not organised.
    pub image: Option<[u32; 2]>,
    /// Per point, whether it lies outside its sensor's calibrated volume (empty when the
    /// sensor states no volume); written to PLY as `outside_volume`.
    pub outside: Vec<bool>,
    /// Further per-point values a file brought (a deviation, an intensity), carried through
    /// PLY and E57 under their names.
    pub scalars: Vec<Scalar>,
}

/// A named per-point value (one per point of its cloud).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Scalar {
    /// The property's name (`deviation`, `intensity`, …).
    pub name: String,
    /// One value per point.
    pub values: Vec<f32>,
}

/// The vertex properties RIS gives a meaning of its own; others are kept as [`Scalar`]s.
const KNOWN: [&str; 8] = [
    "x",
    "y",
    "z",
    "confidence",
    "outside_volume",
    "nx",
    "ny",
    "nz",
];

impl PointCloud {
    /// Compact a dense row-major per-pixel buffer of an image `width` pixels wide (NaN = no
    /// point) with its confidence map; the cloud is organised.
    pub fn from_dense(dense: &[[f32; 3]], confidence: &[f32], width: u32) -> PointCloud {
        let n = dense.iter().filter(|p| p[0].is_finite()).count();
        let height = (dense.len() as u64).div_ceil(u64::from(width.max(1))) as u32;
        let mut cloud = PointCloud {
            points: Vec::with_capacity(n),
            confidence: Vec::with_capacity(n),
            pixels: Vec::with_capacity(n),
            image: Some([width, height]),
            outside: Vec::new(),
            scalars: Vec::new(),
        };
        for (i, p) in dense.iter().enumerate() {
            if p[0].is_finite() {
                cloud.points.push(*p);
                cloud
                    .confidence
                    .push(confidence.get(i).copied().unwrap_or(1.0));
                cloud.pixels.push(i as u32);
            }
        }
        cloud
    }

    /// Drop points with a NaN or infinite coordinate (and their confidence and pixel);
    /// returns how many were dropped.
    pub fn retain_finite(&mut self) -> usize {
        let keep: Vec<bool> = self
            .points
            .iter()
            .map(|p| p.iter().all(|c| c.is_finite()))
            .collect();
        self.retain(&keep)
    }

    /// Keep the points whose entry in `keep` is true, with their per-point attributes;
    /// returns how many were dropped.
    fn retain(&mut self, keep: &[bool]) -> usize {
        fn by<T>(v: &mut Vec<T>, keep: &[bool]) {
            if v.len() == keep.len() {
                let mut k = 0;
                v.retain(|_| {
                    k += 1;
                    keep[k - 1]
                });
            }
        }
        let before = self.points.len();
        by(&mut self.points, keep);
        by(&mut self.confidence, keep);
        by(&mut self.pixels, keep);
        by(&mut self.outside, keep);
        for s in &mut self.scalars {
            by(&mut s.values, keep);
        }
        before - self.points.len()
    }

    /// The image size (width, height) when every point carries its camera pixel.
    pub fn organised(&self) -> Option<[u32; 2]> {
        self.image
            .filter(|&[w, _]| w > 0 && self.pixels.len() == self.points.len())
    }

    /// The camera (row, column) of point `i` of an organised cloud.
    pub fn row_column(&self, i: usize) -> Option<(u32, u32)> {
        let [w, _] = self.organised()?;
        self.pixels.get(i).map(|&p| (p / w, p % w))
    }

    /// The scalars that hold one value per point (the ones written).
    pub fn full_scalars(&self) -> impl Iterator<Item = &Scalar> {
        self.scalars
            .iter()
            .filter(|s| s.values.len() == self.points.len())
    }

    /// Points flagged outside the calibrated volume.
    pub fn outside_count(&self) -> usize {
        self.outside.iter().filter(|o| **o).count()
    }

    /// Leave out the points flagged outside the calibrated volume; returns how many.
    pub fn drop_outside(&mut self) -> usize {
        if self.outside.len() != self.points.len() {
            return 0;
        }
        let keep: Vec<bool> = self.outside.iter().map(|o| !o).collect();
        self.retain(&keep)
    }

    /// The points as double-precision vectors (what fits and measurements take), mm.
    pub fn positions(&self) -> Vec<crate::geometry::Vec3> {
        self.points
            .iter()
            .map(|p| crate::geometry::Vec3::new(p[0].into(), p[1].into(), p[2].into()))
            .collect()
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Whether the cloud has no points.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Write a binary little-endian PLY (x y z confidence, float32; `outside_volume` uchar
    /// when the cloud is flagged), atomically.
    pub fn write_ply(&self, path: &Path) -> Result<()> {
        write_atomic(path, &self.to_ply())
    }

    /// The binary little-endian PLY of [`PointCloud::write_ply`], in memory (what risd
    /// publishes).
    pub fn to_ply(&self) -> Vec<u8> {
        let flagged = self.outside.len() == self.points.len() && !self.points.is_empty();
        let grid = self.organised();
        let mut header = format!(
            "ply\nformat binary_little_endian 1.0\ncomment written by RIS {}\n",
            env!("CARGO_PKG_VERSION")
        );
        if let Some([w, h]) = grid {
            header += &format!("obj_info num_cols {w}\nobj_info num_rows {h}\n");
        }
        header += &format!(
            "element vertex {}\nproperty float x\nproperty float y\nproperty float z\nproperty float confidence\n",
            self.points.len()
        );
        if flagged {
            header += "property uchar outside_volume\n";
        }
        if grid.is_some() {
            header += "property uint row\nproperty uint column\n";
        }
        let scalars: Vec<&Scalar> = self.full_scalars().collect();
        for s in &scalars {
            header += &format!("property float {}\n", s.name);
        }
        header += "end_header\n";
        let stride =
            16 + usize::from(flagged) + if grid.is_some() { 8 } else { 0 } + 4 * scalars.len();
        let mut buf = Vec::with_capacity(header.len() + self.points.len() * stride);
        buf.extend_from_slice(header.as_bytes());
        for (i, (p, c)) in self.points.iter().zip(&self.confidence).enumerate() {
            for v in [p[0], p[1], p[2], *c] {
                buf.extend_from_slice(&v.to_le_bytes());
            }
            if flagged {
                buf.push(u8::from(self.outside[i]));
            }
            if let Some((r, col)) = self.row_column(i) {
                buf.extend_from_slice(&r.to_le_bytes());
                buf.extend_from_slice(&col.to_le_bytes());
            }
            for s in &scalars {
                buf.extend_from_slice(&s.values[i].to_le_bytes());
            }
        }
        buf
    }

    /// Read a PLY file (ASCII, binary little- or big-endian); `confidence` defaults to 1.
    pub fn read_ply(path: &Path) -> Result<PointCloud> {
        let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
        Self::from_ply(&bytes, path)
    }

    /// Parse PLY bytes (as [`PointCloud::read_ply`]); `origin` names them in errors.
    pub fn from_ply(bytes: &[u8], origin: &Path) -> Result<PointCloud> {
        parse_ply(bytes).map_err(|message| Error::Format {
            path: origin.to_path_buf(),
            message,
        })
    }
}

#[derive(Clone, Copy, PartialEq)]
pub(crate) enum Encoding {
    Ascii,
    Le,
    Be,
}

pub(crate) fn type_size(t: &str) -> Option<usize> {
    Some(match t {
        "char" | "uchar" | "int8" | "uint8" => 1,
        "short" | "ushort" | "int16" | "uint16" => 2,
        "int" | "uint" | "float" | "int32" | "uint32" | "float32" => 4,
        "double" | "float64" => 8,
        _ => return None,
    })
}

pub(crate) fn read_scalar(t: &str, b: &[u8], enc: Encoding) -> f64 {
    macro_rules! num {
        ($ty:ty, $n:expr) => {{
            let mut a = [0u8; $n];
            a.copy_from_slice(&b[..$n]);
            (if enc == Encoding::Be {
                <$ty>::from_be_bytes(a)
            } else {
                <$ty>::from_le_bytes(a)
            }) as f64
        }};
    }
    match t {
        "char" | "int8" => f64::from(b[0] as i8),
        "uchar" | "uint8" => f64::from(b[0]),
        "short" | "int16" => num!(i16, 2),
        "ushort" | "uint16" => num!(u16, 2),
        "int" | "int32" => num!(i32, 4),
        "uint" | "uint32" => num!(u32, 4),
        "float" | "float32" => num!(f32, 4),
        _ => num!(f64, 8),
    }
}

fn parse_ply(bytes: &[u8]) -> std::result::Result<PointCloud, String> {
    let end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .ok_or("no end_header line")?
        + 11;
    let header = std::str::from_utf8(&bytes[..end]).map_err(|_| "header is not text")?;
    let mut lines = header.lines();
    if lines.next() != Some("ply") {
        return Err("missing `ply` magic".into());
    }
    let mut enc = Encoding::Ascii;
    let mut count = 0usize;
    let mut props: Vec<(String, String)> = Vec::new();
    let mut in_vertex = false;
    let mut before_vertex_bytes = false;
    let (mut num_cols, mut num_rows) = (None::<u32>, None::<u32>);
    for line in lines {
        let f: Vec<&str> = line.split_whitespace().collect();
        match f.as_slice() {
            ["obj_info", "num_cols", n] => num_cols = n.parse().ok(),
            ["obj_info", "num_rows", n] => num_rows = n.parse().ok(),
            ["format", "ascii", _] => enc = Encoding::Ascii,
            ["format", "binary_little_endian", _] => enc = Encoding::Le,
            ["format", "binary_big_endian", _] => enc = Encoding::Be,
            ["element", "vertex", n] => {
                count = n.parse().map_err(|_| format!("bad vertex count `{n}`"))?;
                in_vertex = true;
            }
            ["element", name, n] => {
                if !in_vertex && n.parse::<usize>().map_err(|_| "bad element count")? > 0 {
                    before_vertex_bytes = true;
                    tracing::warn!(element = name, "PLY element before vertices");
                }
                in_vertex = false;
            }
            ["property", "list", ..] if in_vertex => {
                return Err("list properties on vertices are not supported".into())
            }
            ["property", t, name] if in_vertex => {
                type_size(t).ok_or_else(|| format!("unknown property type `{t}`"))?;
                props.push((t.to_string(), name.to_string()));
            }
            _ => {}
        }
    }
    if before_vertex_bytes {
        return Err("elements before `vertex` are not supported".into());
    }
    let idx = |n: &str| props.iter().position(|(_, p)| p == n);
    let (ix, iy, iz) = match (idx("x"), idx("y"), idx("z")) {
        (Some(a), Some(b), Some(c)) => (a, b, c),
        _ => return Err("vertex has no x, y, z properties".into()),
    };
    let ic = idx("confidence");
    let io = idx("outside_volume");
    let grid = idx("row").zip(idx("column"));
    let extra: Vec<usize> = (0..props.len())
        .filter(|&k| !KNOWN.contains(&props[k].1.as_str()))
        .filter(|&k| grid.is_none() || !matches!(props[k].1.as_str(), "row" | "column"))
        .collect();
    let body = &bytes[end..];
    // The header's count is checked against the bytes that follow before anything is
    // allocated: an ASCII vertex takes at least one character and one separator per property.
    let sizes: Vec<usize> = props.iter().filter_map(|(t, _)| type_size(t)).collect();
    let stride: usize = sizes.iter().sum();
    let per_vertex = match enc {
        Encoding::Ascii => 2 * props.len(),
        _ => stride,
    };
    let needed = count.saturating_mul(per_vertex);
    if needed > body.len() + 1 {
        return Err(format!(
            "truncated: the header claims {count} vertices, which need at least {needed} bytes; the file has {} after the header",
            body.len()
        ));
    }
    let mut cloud = PointCloud {
        points: Vec::with_capacity(count),
        confidence: Vec::with_capacity(count),
        pixels: Vec::new(),
        image: None,
        outside: Vec::new(),
        scalars: extra
            .iter()
            .map(|&k| Scalar {
                name: props[k].1.clone(),
                values: Vec::with_capacity(count),
            })
            .collect(),
    };
    let mut rows_cols: Vec<(f64, f64)> = Vec::new();
    let mut vals = vec![0f64; props.len()];
    match enc {
        Encoding::Ascii => {
            let text = std::str::from_utf8(body).map_err(|_| "ASCII body is not text")?;
            let mut tokens = text.split_whitespace();
            for k in 0..count {
                for v in vals.iter_mut() {
                    *v = tokens
                        .next()
                        .ok_or(format!("truncated at vertex {k}"))?
                        .parse()
                        .map_err(|_| format!("bad number at vertex {k}"))?;
                }
                cloud
                    .points
                    .push([vals[ix] as f32, vals[iy] as f32, vals[iz] as f32]);
                cloud.confidence.push(ic.map_or(1.0, |c| vals[c] as f32));
                if let Some(o) = io {
                    cloud.outside.push(vals[o] != 0.0);
                }
                if let Some((r, c)) = grid {
                    rows_cols.push((vals[r], vals[c]));
                }
                for (s, &k) in cloud.scalars.iter_mut().zip(&extra) {
                    s.values.push(vals[k] as f32);
                }
            }
        }
        _ => {
            if body.len() < stride * count {
                return Err(format!(
                    "truncated: {count} vertices need {} bytes, file has {}",
                    stride * count,
                    body.len()
                ));
            }
            for rec in body.chunks_exact(stride).take(count) {
                let mut off = 0;
                for (j, (t, _)) in props.iter().enumerate() {
                    vals[j] = read_scalar(t, &rec[off..], enc);
                    off += sizes[j];
                }
                cloud
                    .points
                    .push([vals[ix] as f32, vals[iy] as f32, vals[iz] as f32]);
                cloud.confidence.push(ic.map_or(1.0, |c| vals[c] as f32));
                if let Some(o) = io {
                    cloud.outside.push(vals[o] != 0.0);
                }
                if let Some((r, c)) = grid {
                    rows_cols.push((vals[r], vals[c]));
                }
                for (s, &k) in cloud.scalars.iter_mut().zip(&extra) {
                    s.values.push(vals[k] as f32);
                }
            }
        }
    }
    if grid.is_some() {
        organise(&mut cloud, &rows_cols, num_cols.zip(num_rows))?;
    }
    let dropped = cloud.retain_finite();
    if dropped > 0 {
        tracing::warn!(
            dropped,
            "PLY points with a NaN or infinite coordinate left out"
        );
    }
    Ok(cloud)
}

/// Give a cloud its camera pixels from per-point (row, column): the image is `size` when the
/// file states it (every index must lie inside), else the smallest that holds them.
pub(crate) fn organise(
    cloud: &mut PointCloud,
    rows_cols: &[(f64, f64)],
    size: Option<(u32, u32)>,
) -> std::result::Result<(), String> {
    let mut extent = (0u32, 0u32);
    for (k, &(r, c)) in rows_cols.iter().enumerate() {
        let valid = |v: f64| v >= 0.0 && v.fract() == 0.0 && v < f64::from(u32::MAX);
        if !valid(r) || !valid(c) {
            return Err(format!(
                "point {k}: row {r} / column {c} is not a pixel index"
            ));
        }
        extent = (extent.0.max(c as u32 + 1), extent.1.max(r as u32 + 1));
    }
    let (w, h) = match size {
        Some((w, h)) if extent.0 <= w && extent.1 <= h => (w, h),
        Some((w, h)) => {
            return Err(format!(
                "a point's row/column lies outside the stated {w} x {h} image"
            ))
        }
        None => extent,
    };
    if u64::from(w) * u64::from(h) > u64::from(u32::MAX) {
        return Err(format!("a {w} x {h} image is too large to index"));
    }
    cloud.pixels = rows_cols
        .iter()
        .map(|&(r, c)| r as u32 * w + c as u32)
        .collect();
    cloud.image = Some([w, h]);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn binary_round_trip_and_ascii_double_input() {
        let dir = tempfile::tempdir().expect("tempdir");
        let cloud = PointCloud {
            points: vec![[1.0, 2.0, 3.0], [-4.5, 0.25, 1e3]],
            confidence: vec![0.5, 1.0],
            pixels: vec![],
            image: None,
            outside: vec![false, true],
            scalars: vec![],
        };
        let p = dir.path().join("a.ply");
        cloud.write_ply(&p).expect("write");
        assert_eq!(PointCloud::read_ply(&p).expect("read"), cloud);
        let q = dir.path().join("b.ply");
        std::fs::write(&q, "ply\nformat ascii 1.0\nelement vertex 2\nproperty double x\nproperty double y\nproperty double z\nproperty uchar intensity\nend_header\n1 2 3 9\n4 5 6 7\n").expect("write");
        let back = PointCloud::read_ply(&q).expect("ascii");
        assert_eq!(back.points, vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]);
        std::fs::write(&q, "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n").expect("write");
        assert!(PointCloud::read_ply(&q)
            .expect_err("truncated")
            .to_string()
            .contains("b.ply"));
    }
}
