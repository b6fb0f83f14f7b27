//! The calibrated volume: where a calibration session measured the sensor. Outside it the
//! camera's distortion, the reference map and the residual field are extrapolated, so points
//! there are flagged rather than trusted silently.

use serde::{Deserialize, Serialize};

use crate::{Error, Result};

/// `[volume]` of a sensor file, written by `ris calibrate sensor`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VolumeSection {
    /// Area of the board's squares on the reference plane, `[x_min, x_max, y_min, y_max]` mm.
    pub extent: [f64; 4],
    /// Lowest and highest layer, mm above the reference plane.
    pub heights: [f64; 2],
}

/// The box of the sensor frame a calibration covered, with the tolerance a point may lie
/// beyond it (noise at the reference plane, a surface a few millimetres above the top layer).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CalibratedVolume {
    /// `[x_min, x_max, y_min, y_max]`, mm.
    pub extent: [f64; 4],
    /// `[z_min, z_max]`, mm.
    pub heights: [f64; 2],
}

impl CalibratedVolume {
    /// Validate a `[volume]` section; errors name `ctx` and the field.
    pub fn from_section(s: &VolumeSection, ctx: &str) -> Result<CalibratedVolume> {
        let e = s.extent;
        if e.iter().chain(&s.heights).any(|v| !v.is_finite()) {
            return Err(Error::invalid(
                ctx,
                "volume",
                format!("{s:?} has a value that is not finite"),
            ));
        }
        if e[0] >= e[1] || e[2] >= e[3] {
            return Err(Error::invalid(
                ctx,
                "volume.extent",
                format!("{e:?} is not [x_min, x_max, y_min, y_max] with min < max"),
            ));
        }
        if s.heights[0] > s.heights[1] {
            return Err(Error::invalid(
                ctx,
                "volume.heights",
                format!("{:?} is not [lowest, highest]", s.heights),
            ));
        }
        Ok(CalibratedVolume {
            extent: e,
            heights: s.heights,
        })
    }

    /// The section to write.
    pub fn section(&self) -> VolumeSection {
        VolumeSection {
            extent: self.extent,
            heights: self.heights,
        }
    }

    /// How far beyond the layers a height still counts as calibrated, mm: 5 % of the layers'
    /// span, at least 2 mm.
    pub fn height_margin(&self) -> f64 {
        (0.05 * (self.heights[1] - self.heights[0])).max(2.0)
    }

    /// Whether a sensor-frame point lies in the volume.
    #[inline]
    pub fn contains(&self, p: &[f32; 3]) -> bool {
        let (x, y, z) = (f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
        let m = self.height_margin();
        let e = &self.extent;
        (e[0]..=e[1]).contains(&x)
            && (e[2]..=e[3]).contains(&y)
            && (self.heights[0] - m..=self.heights[1] + m).contains(&z)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_box_has_a_height_margin_and_bad_sections_are_named() {
        let v = CalibratedVolume::from_section(
            &VolumeSection {
                extent: [-100.0, 100.0, -50.0, 50.0],
                heights: [0.0, 160.0],
            },
            "s.toml",
        )
        .expect("volume");
        assert!(v.contains(&[0.0, 0.0, -7.9]));
        assert!(!v.contains(&[0.0, 0.0, -8.1]));
        assert!(v.contains(&[99.0, -49.0, 167.9]));
        assert!(!v.contains(&[101.0, 0.0, 10.0]));
        assert!(!v.contains(&[0.0, 51.0, 10.0]));
        let e = CalibratedVolume::from_section(
            &VolumeSection {
                extent: [1.0, 0.0, 0.0, 1.0],
                heights: [0.0, 1.0],
            },
            "s.toml",
        )
        .expect_err("bad extent");
        assert!(e.to_string().contains("volume.extent"), "{e}");
    }
}
