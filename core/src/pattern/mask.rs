//! Projection masks (SPEC §8): a per-projector-pixel factor M in [0, 1] that every pattern is
//! multiplied by, stored in capture sets as 16-bit M × 4096.

use crate::image::{GrayImage, Pixels};
use crate::{Error, Result};

/// Scale of the 16-bit on-disk representation (M = 1 ↔ 4096).
pub const MASK_SCALE: f32 = 4096.0;

/// A projection mask over the projector's pixels, row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct ProjectionMask {
    /// Projector width.
    pub width: u32,
    /// Projector height.
    pub height: u32,
    /// Factors in [0, 1].
    pub values: Vec<f32>,
}

impl ProjectionMask {
    /// A mask of constant `level`.
    pub fn uniform(width: u32, height: u32, level: f32) -> ProjectionMask {
        ProjectionMask {
            width,
            height,
            values: vec![level.clamp(0.0, 1.0); (width * height) as usize],
        }
    }

    /// An 8-bit projector picture (row-major, `width` × `height`) as a mask over white: a
    /// white slide under it shows exactly the picture, so any backend projects any image
    /// (the single-shot pattern) through the slides it already knows.
    pub fn picture(width: u32, height: u32, pixels: &[u8]) -> ProjectionMask {
        ProjectionMask {
            width,
            height,
            values: pixels.iter().map(|&v| f32::from(v) / 255.0).collect(),
        }
    }

    /// The 16-bit image stored beside a capture set.
    pub fn to_image(&self) -> GrayImage {
        GrayImage::from_u16(
            self.width,
            self.height,
            self.values
                .iter()
                .map(|m| (m.clamp(0.0, 1.0) * MASK_SCALE).round() as u16)
                .collect(),
        )
    }

    /// From the 16-bit image of a capture set; values above 4096 are an error.
    pub fn from_image(img: &GrayImage) -> Result<ProjectionMask> {
        let Pixels::U16(v) = &img.pixels else {
            return Err(Error::Insufficient(
                "a projection mask must be a 16-bit image (M × 4096)".into(),
            ));
        };
        if let Some(bad) = v.iter().find(|&&m| f32::from(m) > MASK_SCALE) {
            return Err(Error::Insufficient(format!(
                "projection mask value {bad} exceeds 4096 (M = 1)"
            )));
        }
        Ok(ProjectionMask {
            width: img.width,
            height: img.height,
            values: v.iter().map(|&m| f32::from(m) / MASK_SCALE).collect(),
        })
    }

    /// Multiply a rendered 8-bit pattern by the mask in place.
    pub fn apply(&self, pixels: &mut [u8]) {
        for (p, m) in pixels.iter_mut().zip(&self.values) {
            *p = (f32::from(*p) * m).round() as u8;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn image_round_trip_and_apply() {
        let mut m = ProjectionMask::uniform(4, 2, 1.0);
        m.values[1] = 0.5;
        m.values[2] = 0.0;
        let back = ProjectionMask::from_image(&m.to_image()).expect("mask");
        assert_eq!(back, m);
        let mut px = vec![255u8; 8];
        m.apply(&mut px);
        assert_eq!(&px[..3], &[255, 128, 0]);
        assert!(ProjectionMask::from_image(&GrayImage::from_u16(1, 1, vec![5000])).is_err());
        assert!(ProjectionMask::from_image(&GrayImage::from_u8(1, 1, vec![5])).is_err());
    }
}
