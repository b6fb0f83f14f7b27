//! The omnidirectional sensor file (SPEC §13): a camera unit and a projector unit, each a pinhole
//! behind a hyperbolic mirror, with optional per-pixel ray tables.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use std::sync::Arc;

use super::lut::RayTable;
use super::{Mirror, MirrorUnit, Ray};
use crate::geometry::{Distortion, Mat3, Pinhole, Vec3};
use crate::io::read_toml;
use crate::{Error, Result};

/// The file as written.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct OmniFile {
    /// Always `omni`.
    pub kind: String,
    /// The camera unit.
    pub camera: UnitSection,
    /// The projector unit.
    pub projector: UnitSection,
    /// Per-pixel ray tables that replace the analytic model.
    #[serde(default)]
    pub lut: Option<LutSection>,
}

/// One unit: its pinhole and its mirror.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct UnitSection {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Intrinsics (SPEC §2).
    pub k: [[f64; 3]; 3],
    /// Brown distortion k1, k2, p1, p2, k3 (zeros: an ideal lens).
    #[serde(default)]
    pub dist: [f64; 5],
    /// The mirror.
    pub mirror: MirrorSection,
}

/// A mirror and its pose.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct MirrorSection {
    /// Semi-axis along the axis of revolution, mm.
    pub a: f64,
    /// Transverse semi-axis, mm.
    pub b: f64,
    /// Radius of the mirror's edge, mm.
    pub rim: f64,
    /// Pinhole displacement from the outer focus F2, mm.
    #[serde(default)]
    pub offset: [f64; 3],
    /// Mirror → sensor rotation.
    pub r: [[f64; 3]; 3],
    /// Mirror frame origin in the sensor frame, mm.
    pub t: [f64; 3],
}

/// Ray tables (`.npy`, float32 H × W × 6), relative to the sensor file.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct LutSection {
    /// The camera's table.
    pub camera: PathBuf,
    /// The projector's table.
    pub projector: PathBuf,
}

/// A validated omnidirectional sensor.
#[derive(Clone, Debug)]
pub struct OmniSensor {
    /// The camera unit.
    pub camera: MirrorUnit,
    /// The projector unit.
    pub projector: MirrorUnit,
    /// Ray tables, resolved against the file's directory.
    pub lut: Option<(PathBuf, PathBuf)>,
    /// The camera's and the projector's ray tables, when the file names them (loaded).
    pub tables: Option<Arc<(RayTable, RayTable)>>,
}

impl OmniSensor {
    /// Read and validate `path`; errors name the file and the field.
    pub fn load(path: &Path) -> Result<OmniSensor> {
        let file: OmniFile = read_toml(path)?;
        let base = path.parent().unwrap_or(Path::new("."));
        OmniSensor::from_file(&file, base, &path.display().to_string())
    }

    /// Validate `file` (`context` names it in errors); tables are resolved against `base`.
    pub fn from_file(file: &OmniFile, base: &Path, context: &str) -> Result<OmniSensor> {
        if file.kind != "omni" {
            return Err(Error::invalid(
                context,
                "kind",
                format!(
                    "`{}`: an omnidirectional sensor file says `omni`",
                    file.kind
                ),
            ));
        }
        let camera = unit(&file.camera, context, "camera")?;
        let projector = unit(&file.projector, context, "projector")?;
        let lut = file
            .lut
            .as_ref()
            .map(|l| (base.join(&l.camera), base.join(&l.projector)));
        let tables = match &lut {
            Some((c, p)) => Some(Arc::new((
                RayTable::load(c, camera.lens.width, camera.lens.height)?,
                RayTable::load(p, projector.lens.width, projector.lens.height)?,
            ))),
            None => None,
        };
        Ok(OmniSensor {
            camera,
            projector,
            lut,
            tables,
        })
    }

    /// The default ring pattern for this sensor's projector, about its principal point.
    pub fn rings(&self) -> Result<super::RingPattern> {
        let l = &self.projector.lens;
        super::RingPattern::design(l.width, l.height, [l.k[(0, 2)], l.k[(1, 2)]])
    }

    /// The ray camera pixel (u, v) sees: from the ray table when the file has one (NaN there:
    /// `None`, the calibration did not see it), else from the mirror model.
    pub fn camera_ray(&self, u: f64, v: f64) -> Option<Ray> {
        match &self.tables {
            Some(t) => t.0.ray(u, v),
            None => self.camera.back_project(u, v),
        }
    }

    /// The ray projector pixel (u, v) casts, as [`OmniSensor::camera_ray`].
    pub fn projector_ray(&self, u: f64, v: f64) -> Option<Ray> {
        match &self.tables {
            Some(t) => t.1.ray(u, v),
            None => self.projector.back_project(u, v),
        }
    }
}

fn unit(s: &UnitSection, context: &str, name: &str) -> Result<MirrorUnit> {
    let bad =
        |field: &str, message: String| Error::invalid(context, format!("{name}.{field}"), message);
    if s.width == 0 || s.height == 0 || s.width > 32768 || s.height > 32768 {
        return Err(bad(
            "width",
            format!("{}x{} must be 1 … 32768 per side", s.width, s.height),
        ));
    }
    let k = Mat3::from_fn(|i, j| s.k[i][j]);
    if !(k.iter().all(|v| v.is_finite()) && k[(0, 0)] > 0.0 && k[(1, 1)] > 0.0) {
        return Err(bad("k", "needs finite entries and positive fx, fy".into()));
    }
    if !s.dist.iter().all(|v| v.is_finite()) {
        return Err(bad("dist", "has a non-finite coefficient".into()));
    }
    let m = &s.mirror;
    for (field, v) in [("a", m.a), ("b", m.b), ("rim", m.rim)] {
        if !(v.is_finite() && v > 0.0) {
            return Err(bad(
                &format!("mirror.{field}"),
                format!("{v} must be positive"),
            ));
        }
    }
    let r = Mat3::from_fn(|i, j| m.r[i][j]);
    if !r.iter().all(|v| v.is_finite())
        || (r.transpose() * r - Mat3::identity()).norm() > 1e-6
        || (r.determinant() - 1.0).abs() > 1e-6
    {
        return Err(bad(
            "mirror.r",
            "is not a rotation (orthonormal, determinant +1)".into(),
        ));
    }
    for (field, v) in [("mirror.t", m.t), ("mirror.offset", m.offset)] {
        if !v.iter().all(|c| c.is_finite()) {
            return Err(bad(field, "has a non-finite entry".into()));
        }
    }
    Ok(MirrorUnit {
        mirror: Mirror {
            a: m.a,
            b: m.b,
            rim: m.rim,
        },
        lens: Pinhole {
            width: s.width,
            height: s.height,
            k,
            dist: Distortion::from_array(s.dist),
            r: Mat3::identity(),
            t: Vec3::zeros(),
        },
        offset: Vec3::from(m.offset),
        r,
        t: Vec3::from(m.t),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const SEED: &str = r#"
kind = "omni"
[camera]
width = 640
height = 480
k = [[400.0, 0.0, 319.5], [0.0, 400.0, 239.5], [0.0, 0.0, 1.0]]
[camera.mirror]
a = 35.32996
b = 18.75617
rim = 30.0
r = [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]
t = [0.0, 0.0, 190.0]
[projector]
width = 1024
height = 768
k = [[600.0, 0.0, 511.5], [0.0, 600.0, 383.5], [0.0, 0.0, 1.0]]
dist = [0.0, 0.0, 0.0, 0.0, 0.0]
[projector.mirror]
a = 35.32996
b = 18.75617
rim = 30.0
offset = [0.0, 0.0, 0.5]
r = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
t = [0.0, 0.0, -190.0]
"#;

    fn parse(text: &str) -> Result<OmniSensor> {
        let file: OmniFile =
            toml::from_str(text).map_err(|e| Error::invalid("omni.toml", "toml", e.to_string()))?;
        OmniSensor::from_file(&file, Path::new("/cell"), "omni.toml")
    }

    #[test]
    fn the_stacked_seed_layout_reads_with_a_300_mm_baseline() {
        let s = parse(SEED).expect("sensor");
        let baseline = (s.camera.viewpoint() - s.projector.viewpoint()).norm();
        assert!((baseline - 300.0).abs() < 1e-3, "{baseline}");
        assert!(s.camera.is_central() && !s.projector.is_central());
        assert!(s.lut.is_none());
    }

    #[test]
    fn bad_values_name_the_unit_and_field() {
        for (from, to, field) in [
            ("kind = \"omni\"", "kind = \"pair\"", "kind"),
            ("a = 35.32996\nb", "a = -1.0\nb", "camera.mirror.a"),
            (
                "rim = 30.0\noffset",
                "rim = 0.0\noffset",
                "projector.mirror.rim",
            ),
            ("width = 1024", "width = 0", "projector.width"),
            ("[0.0, -1.0, 0.0]", "[0.0, -2.0, 0.0]", "camera.mirror.r"),
            ("[[400.0, 0.0, 319.5]", "[[-400.0, 0.0, 319.5]", "camera.k"),
        ] {
            let text = SEED.replacen(from, to, 1);
            assert_ne!(text, SEED, "{from}");
            let err = parse(&text).expect_err(field).to_string();
            assert!(
                err.contains(field) && err.contains("omni.toml"),
                "{field}: {err}"
            );
        }
    }
}
