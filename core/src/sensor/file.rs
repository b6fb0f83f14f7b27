//! The sensor file (SPEC §6): camera, projector, reference recording, residual, cell transform.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::geometry::{rows_of, Distortion, Mat3, Matrix4, Pinhole, Vec3};
use crate::io::{read_toml, write_toml};
use crate::sensor::volume::{CalibratedVolume, VolumeSection};
use crate::{Error, Result};

/// `[camera]` of a sensor file.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraSection {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Intrinsics.
    pub k: [[f64; 3]; 3],
    /// Brown distortion k1 k2 p1 p2 k3.
    #[serde(default)]
    pub dist: [f64; 5],
    /// World → camera rotation.
    pub r: [[f64; 3]; 3],
    /// World → camera translation, mm.
    pub t: [f64; 3],
}

/// `[projector]` of a sensor file: the optical centre (parallax model) and/or a full calibration
/// (classical model).
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProjectorSection {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Optical centre O_p in the sensor world frame, mm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub center: Option<[f64; 3]>,
    /// Intrinsics (classical model).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub k: Option<[[f64; 3]; 3]>,
    /// Distortion (classical model).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dist: Option<[f64; 5]>,
    /// World → projector rotation (classical model).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub r: Option<[[f64; 3]; 3]>,
    /// World → projector translation (classical model).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub t: Option<[f64; 3]>,
}

/// `[reference]`: the capture set of the bare reference plane, relative to the sensor file.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReferenceSection {
    /// Capture directory.
    pub capture: String,
    /// Area of the reference plane the recording is valid on, `[x_min, x_max, y_min, y_max]`
    /// mm (a calibration board's squares); pixels outside are not used. Absent: all of it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub extent: Option<[f64; 4]>,
}

/// `[residual]`: per-pixel quadratic height residual from calibration (Eq. 3.28).
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ResidualSection {
    /// `.npy` file, float32 H × W × 3 (A, B, C).
    pub file: String,
}

/// `[to_common]`: 4×4 sensor → cell transform.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ToCommonSection {
    /// Row-major homogeneous matrix.
    pub matrix: [[f64; 4]; 4],
}

/// A sensor file as written on disk.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorFile {
    /// The camera.
    pub camera: CameraSection,
    /// The projector.
    pub projector: ProjectorSection,
    /// The reference recording (parallax model).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reference: Option<ReferenceSection>,
    /// Residual compensation.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub residual: Option<ResidualSection>,
    /// Sensor → cell transform.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub to_common: Option<ToCommonSection>,
    /// Where the calibration session measured (points outside are flagged).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub volume: Option<VolumeSection>,
}

/// A validated sensor description with paths resolved against the file's directory.
#[derive(Clone, Debug)]
pub struct Sensor {
    /// The camera model.
    pub camera: Pinhole,
    /// Projector size (width, height).
    pub projector_size: (u32, u32),
    /// Projector optical centre, if given (or derived from a full calibration).
    pub projector_center: Option<Vec3>,
    /// Full projector model, if given.
    pub projector: Option<Pinhole>,
    /// Reference capture directory.
    pub reference: Option<PathBuf>,
    /// Valid area of the reference plane, `[x_min, x_max, y_min, y_max]` mm.
    pub reference_extent: Option<[f64; 4]>,
    /// Residual field file.
    pub residual: Option<PathBuf>,
    /// Sensor → cell transform.
    pub to_common: Option<Matrix4<f64>>,
    /// The calibrated volume, when the file states it.
    pub volume: Option<CalibratedVolume>,
}

impl Sensor {
    /// Read and validate a sensor file; errors name the file and the field.
    pub fn load(path: &Path) -> Result<Sensor> {
        let file: SensorFile = read_toml(path)?;
        let base = path.parent().unwrap_or(Path::new("."));
        Sensor::from_file(&file, base, &path.display().to_string())
    }

    /// Validate a parsed sensor file; `base` resolves relative paths, `ctx` names the source.
    pub fn from_file(f: &SensorFile, base: &Path, ctx: &str) -> Result<Sensor> {
        let camera = pinhole(
            ctx,
            "camera",
            f.camera.width,
            f.camera.height,
            &f.camera.k,
            &f.camera.dist,
            &f.camera.r,
            &f.camera.t,
        )?;
        let p = &f.projector;
        if p.width == 0 || p.height == 0 || p.width > MAX_SIDE || p.height > MAX_SIDE {
            return Err(Error::invalid(
                ctx,
                "projector.width/height",
                format!("{} x {} must be within 1 … {MAX_SIDE}", p.width, p.height),
            ));
        }
        let projector = match (&p.k, &p.r, &p.t) {
            (Some(k), Some(r), Some(t)) => Some(pinhole(
                ctx,
                "projector",
                p.width,
                p.height,
                k,
                &p.dist.unwrap_or_default(),
                r,
                t,
            )?),
            (None, None, None) => None,
            _ => {
                return Err(Error::invalid(
                    ctx,
                    "projector",
                    "a full projector calibration needs all of k, r and t",
                ))
            }
        };
        let center = match p.center {
            Some(c) => {
                finite(ctx, "projector.center", &c)?;
                Some(Vec3::from(c))
            }
            None => projector.as_ref().map(Pinhole::center),
        };
        if f.reference.is_some() && center.is_none() {
            return Err(Error::invalid(
                ctx,
                "projector.center",
                "the parallax model (a [reference]) needs the projector centre",
            ));
        }
        if f.reference.is_none() && projector.is_none() {
            return Err(Error::invalid(ctx, "reference", "give a [reference] capture (parallax model) or a full projector calibration k, r, t (classical model)"));
        }
        let reference_extent = match f.reference.as_ref().and_then(|r| r.extent) {
            Some(e) => {
                finite(ctx, "reference.extent", &e)?;
                if e[0] >= e[1] || e[2] >= e[3] {
                    return Err(Error::invalid(
                        ctx,
                        "reference.extent",
                        format!("{e:?} is not [x_min, x_max, y_min, y_max] with min < max"),
                    ));
                }
                Some(e)
            }
            None => None,
        };
        let to_common = match &f.to_common {
            Some(m) => {
                for (i, row) in m.matrix.iter().enumerate() {
                    finite(ctx, &format!("to_common.matrix[{i}]"), row)?;
                }
                let mm = Matrix4::from_fn(|i, j| m.matrix[i][j]);
                let rot = mm.fixed_view::<3, 3>(0, 0).into_owned();
                check_rotation(ctx, "to_common.matrix", &rot)?;
                Some(mm)
            }
            None => None,
        };
        Ok(Sensor {
            camera,
            projector_size: (p.width, p.height),
            projector_center: center,
            projector,
            reference: f.reference.as_ref().map(|r| base.join(&r.capture)),
            reference_extent,
            residual: f.residual.as_ref().map(|r| base.join(&r.file)),
            to_common,
            volume: f
                .volume
                .as_ref()
                .map(|v| CalibratedVolume::from_section(v, ctx))
                .transpose()?,
        })
    }
}

impl SensorFile {
    /// Write atomically as TOML.
    pub fn save(&self, path: &Path) -> Result<()> {
        write_toml(path, self)
    }

    /// The `[camera]` section of a pinhole model.
    pub fn camera_section(c: &Pinhole) -> CameraSection {
        CameraSection {
            width: c.width,
            height: c.height,
            k: rows_of(&c.k),
            dist: c.dist.to_array(),
            r: rows_of(&c.r),
            t: [c.t.x, c.t.y, c.t.z],
        }
    }
}

fn finite(ctx: &str, field: &str, values: &[f64]) -> Result<()> {
    match values.iter().position(|v| !v.is_finite()) {
        Some(i) => Err(Error::invalid(
            ctx,
            format!("{field}[{i}]"),
            format!("{} is not a finite number", values[i]),
        )),
        None => Ok(()),
    }
}

fn check_rotation(ctx: &str, field: &str, r: &Mat3) -> Result<()> {
    let err = (r.transpose() * r - Mat3::identity()).abs().max();
    if err > 1e-5 || r.determinant() < 0.0 {
        return Err(Error::invalid(
            ctx,
            field,
            format!(
                "is not a rotation (|RᵀR − I| = {err:.2e}, det = {:.4})",
                r.determinant()
            ),
        ));
    }
    Ok(())
}

/// Largest image side, pixels.
pub const MAX_SIDE: u32 = 32_768;
/// Largest image, pixels.
pub const MAX_PIXELS: u64 = 1 << 28;

#[allow(clippy::too_many_arguments)]
fn pinhole(
    ctx: &str,
    name: &str,
    width: u32,
    height: u32,
    k: &[[f64; 3]; 3],
    dist: &[f64; 5],
    r: &[[f64; 3]; 3],
    t: &[f64; 3],
) -> Result<Pinhole> {
    if width == 0 || height == 0 {
        return Err(Error::invalid(
            ctx,
            format!("{name}.width/height"),
            "must be positive",
        ));
    }
    if width > MAX_SIDE || height > MAX_SIDE || u64::from(width) * u64::from(height) > MAX_PIXELS {
        return Err(Error::invalid(
            ctx,
            format!("{name}.width/height"),
            format!("{width} x {height} is beyond the largest image RIS handles ({MAX_SIDE} per side, {MAX_PIXELS} pixels)"),
        ));
    }
    for (i, row) in k.iter().enumerate() {
        finite(ctx, &format!("{name}.k[{i}]"), row)?;
    }
    for (i, row) in r.iter().enumerate() {
        finite(ctx, &format!("{name}.r[{i}]"), row)?;
    }
    finite(ctx, &format!("{name}.t"), t)?;
    finite(ctx, &format!("{name}.dist"), dist)?;
    let km = Mat3::from_fn(|i, j| k[i][j]);
    if km[(0, 0)] <= 0.0
        || km[(1, 1)] <= 0.0
        || km[(1, 0)] != 0.0
        || km[(2, 0)] != 0.0
        || km[(2, 1)] != 0.0
        || km[(2, 2)] != 1.0
    {
        return Err(Error::invalid(
            ctx,
            format!("{name}.k"),
            "expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0",
        ));
    }
    let rm = Mat3::from_fn(|i, j| r[i][j]);
    check_rotation(ctx, &format!("{name}.r"), &rm)?;
    Ok(Pinhole {
        width,
        height,
        k: km,
        dist: Distortion::from_array(*dist),
        r: rm,
        t: Vec3::from(*t),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = r#"
[camera]
width = 800
height = 600
k = [[1800.0, 0.0, 400.0], [0.0, 1800.0, 300.0], [0.0, 0.0, 1.0]]
r = [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]
t = [0.0, 0.0, 1600.0]
[projector]
width = 1024
height = 768
center = [500.0, 0.0, 1600.0]
[reference]
capture = "reference"
"#;

    fn parse(text: &str) -> Result<Sensor> {
        let f: SensorFile = toml::from_str(text).map_err(|e| Error::Toml {
            path: "sensor.toml".into(),
            message: e.to_string(),
        })?;
        Sensor::from_file(&f, Path::new("/data"), "sensor.toml")
    }

    #[test]
    fn valid_file_parses_and_resolves_paths() {
        let s = parse(GOOD).expect("valid");
        assert_eq!(s.reference.as_deref(), Some(Path::new("/data/reference")));
        assert!((s.camera.center() - Vec3::new(0.0, 0.0, 1600.0)).norm() < 1e-12);
    }

    #[test]
    fn nan_and_bad_rotation_name_the_field() {
        let msg = parse(&GOOD.replace("400.0]", "nan]"))
            .expect_err("nan")
            .to_string();
        assert!(
            msg.contains("camera.k[0]") && msg.contains("sensor.toml"),
            "{msg}"
        );
        let msg = parse(&GOOD.replace("[0.0, -1.0, 0.0]", "[0.0, -2.0, 0.0]"))
            .expect_err("rot")
            .to_string();
        assert!(msg.contains("camera.r"), "{msg}");
        let msg = parse(&GOOD.replace("center = [500.0, 0.0, 1600.0]", ""))
            .expect_err("center")
            .to_string();
        assert!(msg.contains("projector.center"), "{msg}");
        let msg = parse(&GOOD.replace("height = 600", "height = 600\nfoo = 1"))
            .expect_err("unknown")
            .to_string();
        assert!(msg.contains("foo"), "{msg}");
    }
}
