//! Marker gauges (Ch. 5.2.3): a part painted black with white circular markers whose centres
//! were measured by a CMM. The gauge file lists them in the cell (common) frame.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::geometry::Vec3;
use crate::io::{read_toml, write_toml};
use crate::{Error, Result};

/// `[[marker]]` of a gauge file.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MarkerSection {
    /// Centre on the surface, mm, cell frame.
    pub center: [f64; 3],
}

/// A gauge file: `radius` (mm) and the `[[marker]]` centres.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GaugeFile {
    /// Marker radius, mm (5 in the text).
    pub radius: f64,
    /// The markers.
    pub marker: Vec<MarkerSection>,
}

/// A validated marker gauge.
#[derive(Clone, Debug, PartialEq)]
pub struct Gauge {
    /// Marker radius, mm.
    pub radius: f64,
    /// Marker centres, cell frame.
    pub centers: Vec<Vec3>,
}

impl Gauge {
    /// Read and validate a gauge file (finite centres, positive radius, at least 3 markers that
    /// do not overlap).
    pub fn load(path: &Path) -> Result<Gauge> {
        let f: GaugeFile = read_toml(path)?;
        Gauge::from_file(&f, &path.display().to_string())
    }

    /// Validate a parsed gauge file; `ctx` names its source in errors.
    pub fn from_file(f: &GaugeFile, ctx: &str) -> Result<Gauge> {
        if !(f.radius.is_finite() && f.radius > 0.0) {
            return Err(Error::invalid(
                ctx,
                "radius",
                format!("{} must be positive", f.radius),
            ));
        }
        if f.marker.len() < 3 {
            return Err(Error::invalid(
                ctx,
                "marker",
                format!("{} markers; a gauge needs at least 3", f.marker.len()),
            ));
        }
        let mut centers = Vec::with_capacity(f.marker.len());
        for (i, m) in f.marker.iter().enumerate() {
            if m.center.iter().any(|v| !v.is_finite()) {
                return Err(Error::invalid(
                    ctx,
                    format!("marker[{i}].center"),
                    "must be finite",
                ));
            }
            let c = Vec3::from(m.center);
            if let Some(j) = centers
                .iter()
                .position(|o: &Vec3| (o - c).norm() < 2.0 * f.radius)
            {
                return Err(Error::invalid(
                    ctx,
                    format!("marker[{i}].center"),
                    format!("overlaps marker[{j}] (centres closer than two radii)"),
                ));
            }
            centers.push(c);
        }
        Ok(Gauge {
            radius: f.radius,
            centers,
        })
    }

    /// Write the gauge file.
    pub fn save(&self, path: &Path) -> Result<()> {
        write_toml(
            path,
            &GaugeFile {
                radius: self.radius,
                marker: self
                    .centers
                    .iter()
                    .map(|c| MarkerSection {
                        center: [c.x, c.y, c.z],
                    })
                    .collect(),
            },
        )
    }

    /// Markers on a jittered grid over the surface z = f(x, y), [x0, x1] × [y0, y1], `pitch`
    /// apart: the irregular spacing makes every marker triangle distinguishable, which the
    /// correspondence-free coarse alignment relies on. `seed` makes the jitter reproducible.
    pub fn jittered_grid(
        (x0, x1): (f64, f64),
        (y0, y1): (f64, f64),
        pitch: f64,
        radius: f64,
        seed: u64,
        z: impl Fn(f64, f64) -> f64,
    ) -> Gauge {
        let mut state = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        let mut jitter = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            ((state >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 0.5 * pitch
        };
        let (nx, ny) = (
            ((x1 - x0) / pitch).floor() as usize,
            ((y1 - y0) / pitch).floor() as usize,
        );
        let mut centers = Vec::new();
        for j in 0..ny {
            for i in 0..nx {
                let x = x0 + (i as f64 + 0.5) * pitch + jitter();
                let y = y0 + (j as f64 + 0.5) * pitch + jitter();
                centers.push(Vec3::new(x, y, z(x, y)));
            }
        }
        Gauge { radius, centers }
    }
}
