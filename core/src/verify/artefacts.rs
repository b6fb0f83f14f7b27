//! The artefacts file of an acceptance test (`ARTEFACTS.toml`): the calibrated artefacts, the
//! maximum permissible errors the system claims, and the calibrated measuring volume.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::io::read_toml;
use crate::{Error, Result};

/// `[ball_bar]`: two spheres on a bar, diameters and centre distance as calibrated, mm.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BallBar {
    /// Calibrated diameter of sphere A, mm.
    pub diameter_a: f64,
    /// Calibrated diameter of sphere B, mm.
    pub diameter_b: f64,
    /// Calibrated distance of the two centres, mm.
    pub spacing: f64,
}

/// `[sphere]`: the probing sphere, mm.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SphereArtefact {
    /// Calibrated diameter, mm.
    pub diameter: f64,
    /// Calibrated form deviation (range of radial deviations), mm; 0 when not stated.
    #[serde(default)]
    pub form: f64,
}

/// `[plane]`: the flat, mm.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlaneArtefact {
    /// Length of the flat's measured face, mm.
    pub length: f64,
    /// Width of the flat's measured face, mm.
    pub width: f64,
    /// Calibrated flatness of the face, mm; 0 when not stated.
    #[serde(default)]
    pub flatness: f64,
}

/// The MPE of the sphere-spacing error: a constant, or `a + L / b` with L the spacing in mm.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum SpacingMpe {
    /// The same limit for every length, mm.
    Constant(f64),
    /// `a + L / b` (a in mm, b dimensionless), as ISO 10360 states length errors.
    LengthDependent {
        /// Constant part, mm.
        a: f64,
        /// Length divisor: L / b is added.
        b: f64,
    },
}

impl SpacingMpe {
    /// The limit for a spacing of `length` mm.
    pub fn at(&self, length: f64) -> f64 {
        match *self {
            SpacingMpe::Constant(v) => v,
            SpacingMpe::LengthDependent { a, b } => a + length.abs() / b,
        }
    }
}

/// `[mpe]`: the maximum permissible errors the system claims, mm.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Mpe {
    /// Probing error form PF.
    pub probing_form: f64,
    /// Probing error size PS (limit on |PS|).
    pub probing_size: f64,
    /// Sphere-spacing error SD (limit on |SD|).
    pub sphere_spacing: SpacingMpe,
    /// Flatness measurement error F.
    pub flatness: f64,
}

/// `[volume]`: the calibrated measuring volume as a box in the clouds' frame, mm.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Volume {
    /// Lowest corner.
    pub min: [f64; 3],
    /// Highest corner.
    pub max: [f64; 3],
}

impl Volume {
    /// The volume's diagonal L0, mm (the guideline sizes artefacts against it).
    pub fn diagonal(&self) -> f64 {
        (0..3)
            .map(|k| (self.max[k] - self.min[k]).powi(2))
            .sum::<f64>()
            .sqrt()
    }

    /// Position of `p` in the volume, 0 … 1 per axis (outside that range when outside).
    pub fn normalised(&self, p: [f64; 3]) -> [f64; 3] {
        std::array::from_fn(|k| (p[k] - self.min[k]) / (self.max[k] - self.min[k]))
    }
}

/// `[system]`: what is being tested, for the certificate.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct System {
    /// The measuring system (cell or sensor name).
    #[serde(default)]
    pub name: String,
    /// Who or what calibrated the artefacts (certificate number, laboratory).
    #[serde(default)]
    pub calibration: String,
}

/// A validated artefacts file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Artefacts {
    /// What is tested.
    #[serde(default)]
    pub system: System,
    /// The ball bar, when the test has one.
    pub ball_bar: Option<BallBar>,
    /// The probing sphere, when the test has one.
    pub sphere: Option<SphereArtefact>,
    /// The flat, when the test has one.
    pub plane: Option<PlaneArtefact>,
    /// The limits.
    pub mpe: Mpe,
    /// The calibrated volume; without it positions cannot be judged against the volume.
    pub volume: Option<Volume>,
}

impl Artefacts {
    /// Read and validate an artefacts file.
    pub fn load(path: &Path) -> Result<Artefacts> {
        let a: Artefacts = read_toml(path)?;
        a.validate(&path.display().to_string())?;
        Ok(a)
    }

    /// Check every size and limit: positive and finite, spheres smaller than the bar's
    /// spacing, a volume with positive extent. `ctx` names the source in errors.
    pub fn validate(&self, ctx: &str) -> Result<()> {
        let positive = |field: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(Error::invalid(
                    ctx,
                    field,
                    format!("{v} must be a positive number of mm"),
                ))
            }
        };
        let not_negative = |field: &str, v: f64| {
            if v.is_finite() && v >= 0.0 {
                Ok(())
            } else {
                Err(Error::invalid(
                    ctx,
                    field,
                    format!("{v} must be zero or a positive number of mm"),
                ))
            }
        };
        if let Some(b) = &self.ball_bar {
            positive("ball_bar.diameter_a", b.diameter_a)?;
            positive("ball_bar.diameter_b", b.diameter_b)?;
            positive("ball_bar.spacing", b.spacing)?;
            if b.spacing <= 0.5 * (b.diameter_a + b.diameter_b) {
                return Err(Error::invalid(
                    ctx,
                    "ball_bar.spacing",
                    format!(
                        "{} mm is not more than the spheres' radii together ({} mm): the spheres would overlap",
                        b.spacing,
                        0.5 * (b.diameter_a + b.diameter_b)
                    ),
                ));
            }
        }
        if let Some(s) = &self.sphere {
            positive("sphere.diameter", s.diameter)?;
            not_negative("sphere.form", s.form)?;
        }
        if let Some(p) = &self.plane {
            positive("plane.length", p.length)?;
            positive("plane.width", p.width)?;
            not_negative("plane.flatness", p.flatness)?;
            if p.width > p.length {
                return Err(Error::invalid(
                    ctx,
                    "plane.width",
                    format!(
                        "{} mm is more than the length {} mm; give the longer side as length",
                        p.width, p.length
                    ),
                ));
            }
        }
        positive("mpe.probing_form", self.mpe.probing_form)?;
        positive("mpe.probing_size", self.mpe.probing_size)?;
        positive("mpe.flatness", self.mpe.flatness)?;
        match self.mpe.sphere_spacing {
            SpacingMpe::Constant(v) => positive("mpe.sphere_spacing", v)?,
            SpacingMpe::LengthDependent { a, b } => {
                not_negative("mpe.sphere_spacing.a", a)?;
                positive("mpe.sphere_spacing.b", b)?;
            }
        }
        if let Some(v) = &self.volume {
            for k in 0..3 {
                let axis = ["x", "y", "z"][k];
                if !(v.min[k].is_finite() && v.max[k].is_finite() && v.max[k] > v.min[k]) {
                    return Err(Error::invalid(
                        ctx,
                        format!("volume.max[{k}]"),
                        format!(
                            "the volume's {axis} extent {} … {} is empty or not finite",
                            v.min[k], v.max[k]
                        ),
                    ));
                }
            }
        }
        if self.ball_bar.is_none() && self.sphere.is_none() && self.plane.is_none() {
            return Err(Error::invalid(
                ctx,
                "ball_bar",
                "no artefact: give at least one of [ball_bar], [sphere], [plane]",
            ));
        }
        Ok(())
    }
}
