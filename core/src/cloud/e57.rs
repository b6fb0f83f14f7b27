//! Point clouds as E57 (ASTM E2807), what laser-scanning and metrology tools open: one
//! Data3D cloud with Cartesian coordinates in metres (the standard's unit; RIS works in mm),
//! double precision, and the per-point confidence and calibrated-volume flag as attributes of
//! the `ris` extension. Reading takes the first cloud of any E57 file: Cartesian coordinates
//! of any storage type, the RIS attributes when present (confidence 1 otherwise). An organised
//! cloud carries the standard `rowIndex`/`columnIndex` per point and the camera image's
//! extent as the cloud's index bounds, which read back as the image size. Further per-point
//! values ([`super::Scalar`]) go out as the standard's `intensity` when so named, else as
//! `ris:<name>` attributes, and come back under the same names.

use std::io::Cursor;
use std::path::Path;

use e57::{
    E57Reader, E57Writer, Extension, IndexBounds, IntensityLimits, Record, RecordDataType,
    RecordName, RecordValue,
};

use super::{PointCloud, Scalar};
use crate::io::write_atomic;
use crate::{Error, Result};

/// Namespace of the RIS point attributes.
const NAMESPACE: &str = "ris";
/// The extension's identifier (a URN: the attributes are described in docs/commands.md, `ris convert`).
const URL: &str = "urn:ris:e57:point-attributes:1";
const CONFIDENCE: &str = "confidence";
const OUTSIDE: &str = "outsideVolume";

fn named(name: &str) -> RecordName {
    RecordName::Unknown {
        namespace: NAMESPACE.into(),
        name: name.into(),
    }
}

/// Whether `name` can name an E57 attribute (an XML name without a namespace).
fn attribute_name(name: &str) -> bool {
    name.chars()
        .next()
        .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.'))
}

/// The E57 record of a per-point value called `name`.
fn scalar_record(name: &str) -> RecordName {
    if name == "intensity" {
        RecordName::Intensity
    } else {
        named(name)
    }
}

fn format_error(path: &Path, e: impl std::fmt::Display) -> Error {
    Error::Format {
        path: path.to_path_buf(),
        message: format!("E57: {e}"),
    }
}

impl PointCloud {
    /// The E57 file of this cloud, in memory.
    pub fn to_e57(&self, name: &str) -> std::result::Result<Vec<u8>, e57::Error> {
        let flagged = self.outside.len() == self.points.len() && !self.points.is_empty();
        let guid = format!("ris-{name}-{}", self.points.len());
        let mut buffer = Cursor::new(Vec::new());
        let mut w = E57Writer::new(&mut buffer, &guid)?;
        w.register_extension(Extension {
            namespace: NAMESPACE.into(),
            url: URL.into(),
        })?;
        let mut prototype = vec![
            Record::CARTESIAN_X_F64,
            Record::CARTESIAN_Y_F64,
            Record::CARTESIAN_Z_F64,
            Record {
                name: named(CONFIDENCE),
                data_type: RecordDataType::F32,
            },
        ];
        if flagged {
            prototype.push(Record {
                name: named(OUTSIDE),
                data_type: RecordDataType::Integer { min: 0, max: 1 },
            });
        }
        let grid = self.organised();
        if let Some([w, h]) = grid {
            for (name, n) in [(RecordName::RowIndex, h), (RecordName::ColumnIndex, w)] {
                prototype.push(Record {
                    name,
                    data_type: RecordDataType::Integer {
                        min: 0,
                        max: i64::from(n.max(1)) - 1,
                    },
                });
            }
        }
        let scalars: Vec<&Scalar> = self.full_scalars().collect();
        for sc in &scalars {
            if !attribute_name(&sc.name) || [CONFIDENCE, OUTSIDE].contains(&sc.name.as_str()) {
                return e57::Error::invalid(format!(
                    "the per-point value {:?} cannot be named in E57",
                    sc.name
                ));
            }
            prototype.push(Record {
                name: scalar_record(&sc.name),
                data_type: RecordDataType::F32,
            });
        }
        let mut pc = w.add_pointcloud(&format!("{guid}-cloud"), prototype)?;
        if let Some(sc) = scalars.iter().find(|sc| sc.name == "intensity") {
            let (lo, hi) = sc
                .values
                .iter()
                .filter(|v| v.is_finite())
                .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &v| {
                    (a.min(v), b.max(v))
                });
            if lo <= hi {
                pc.set_intensity_limits(Some(IntensityLimits {
                    intensity_min: Some(RecordValue::Single(lo)),
                    intensity_max: Some(RecordValue::Single(hi)),
                }));
            }
        }
        if let Some([w, h]) = grid {
            pc.set_index_bounds(Some(IndexBounds {
                row_min: Some(0),
                row_max: Some(i64::from(h.max(1)) - 1),
                column_min: Some(0),
                column_max: Some(i64::from(w.max(1)) - 1),
                return_min: None,
                return_max: None,
            }));
        }
        pc.set_name(Some(name.to_string()));
        pc.set_description(Some("RIS point cloud (coordinates in metres)".into()));
        for (i, p) in self.points.iter().enumerate() {
            let mut values = vec![
                RecordValue::Double(f64::from(p[0]) / 1000.0),
                RecordValue::Double(f64::from(p[1]) / 1000.0),
                RecordValue::Double(f64::from(p[2]) / 1000.0),
                RecordValue::Single(self.confidence.get(i).copied().unwrap_or(1.0)),
            ];
            if flagged {
                values.push(RecordValue::Integer(i64::from(self.outside[i])));
            }
            if let Some((r, c)) = self.row_column(i) {
                values.push(RecordValue::Integer(i64::from(r)));
                values.push(RecordValue::Integer(i64::from(c)));
            }
            for sc in &scalars {
                values.push(RecordValue::Single(sc.values[i]));
            }
            pc.add_point(values)?;
        }
        pc.finalize()?;
        w.finalize()?;
        drop(w);
        Ok(buffer.into_inner())
    }

    /// Write an E57 file (see the module), atomically.
    pub fn write_e57(&self, path: &Path) -> Result<()> {
        let name = path
            .file_stem()
            .map_or_else(|| "cloud".to_string(), |s| s.to_string_lossy().into_owned());
        let bytes = self.to_e57(&name).map_err(|e| format_error(path, e))?;
        write_atomic(path, &bytes)
    }

    /// Read the first point cloud of an E57 file (coordinates converted to mm).
    pub fn read_e57(path: &Path) -> Result<PointCloud> {
        let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
        let mut r = E57Reader::new(Cursor::new(bytes)).map_err(|e| format_error(path, e))?;
        let clouds = r.pointclouds();
        let pc = clouds
            .first()
            .ok_or_else(|| format_error(path, "the file holds no point cloud"))?;
        let find = |n: &RecordName| pc.prototype.iter().position(|rec| &rec.name == n);
        let (Some(ix), Some(iy), Some(iz)) = (
            find(&RecordName::CartesianX),
            find(&RecordName::CartesianY),
            find(&RecordName::CartesianZ),
        ) else {
            return Err(format_error(
                path,
                "the first point cloud has no Cartesian coordinates (spherical-only clouds are not read)",
            ));
        };
        let ic = find(&named(CONFIDENCE));
        let io = find(&named(OUTSIDE));
        let invalid = find(&RecordName::CartesianInvalidState);
        let grid = find(&RecordName::RowIndex).zip(find(&RecordName::ColumnIndex));
        let mut rows_cols = Vec::new();
        let extra: Vec<(usize, String)> = pc
            .prototype
            .iter()
            .enumerate()
            .filter_map(|(k, rec)| match &rec.name {
                RecordName::Intensity => Some((k, "intensity".to_string())),
                RecordName::Unknown { namespace, name }
                    if namespace == NAMESPACE && name != CONFIDENCE && name != OUTSIDE =>
                {
                    Some((k, name.clone()))
                }
                _ => None,
            })
            .collect();
        let types: Vec<RecordDataType> = pc.prototype.iter().map(|p| p.data_type.clone()).collect();
        let mut cloud = PointCloud {
            scalars: extra
                .iter()
                .map(|(_, name)| Scalar {
                    name: name.clone(),
                    values: Vec::new(),
                })
                .collect(),
            ..Default::default()
        };
        let reader = r.pointcloud_raw(pc).map_err(|e| format_error(path, e))?;
        for values in reader {
            let values = values.map_err(|e| format_error(path, e))?;
            let get = |k: usize| -> Result<f64> {
                values
                    .get(k)
                    .ok_or_else(|| {
                        format_error(path, "a point has fewer values than its prototype")
                    })?
                    .to_f64(&types[k])
                    .map_err(|e| format_error(path, e))
            };
            if let Some(k) = invalid {
                if get(k)? != 0.0 {
                    continue;
                }
            }
            cloud.points.push([
                (get(ix)? * 1000.0) as f32,
                (get(iy)? * 1000.0) as f32,
                (get(iz)? * 1000.0) as f32,
            ]);
            cloud
                .confidence
                .push(ic.map(get).transpose()?.unwrap_or(1.0) as f32);
            if let Some(k) = io {
                cloud.outside.push(get(k)? != 0.0);
            }
            if let Some((r, c)) = grid {
                rows_cols.push((get(r)?, get(c)?));
            }
            for (sc, (k, _)) in cloud.scalars.iter_mut().zip(&extra) {
                sc.values.push(get(*k)? as f32);
            }
        }
        if grid.is_some() {
            let b = &pc.index_bounds;
            let size = match b.as_ref().map(|b| (b.column_max, b.row_max)) {
                Some((Some(c), Some(r))) if c >= 0 && r >= 0 => Some((
                    (c + 1).min(i64::from(u32::MAX)) as u32,
                    (r + 1).min(i64::from(u32::MAX)) as u32,
                )),
                _ => None,
            };
            super::organise(&mut cloud, &rows_cols, size).map_err(|e| format_error(path, e))?;
        }
        Ok(cloud)
    }
}
