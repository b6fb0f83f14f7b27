//! Per-pixel ray tables (SPEC §13, Eq. 6.1–6.6): for every camera or projector pixel a ray
//! (point and unit direction, sensor frame), NaN where the calibration did not see the pixel;
//! rays between pixels are interpolated bilinearly. They replace the analytic mirror model
//! when the sensor file names them.

use std::path::Path;

use super::{MirrorUnit, Ray};
use crate::geometry::Vec3;
use crate::io::npy;
use crate::{Error, Result};

/// A ray per pixel, row-major (`[x, y, z, dx, dy, dz]`, f32, NaN where unknown).
#[derive(Clone, Debug)]
pub struct RayTable {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// The rays.
    pub rays: Vec<[f32; 6]>,
}

impl RayTable {
    /// Read `path` (`.npy`, float32 H × W × 6) and check it is `width × height`.
    pub fn load(path: &Path, width: u32, height: u32) -> Result<RayTable> {
        let (shape, data) = npy::read::<f32>(path)?;
        if shape != [height as usize, width as usize, 6] {
            return Err(Error::invalid(
                path.display().to_string(),
                "shape",
                format!("{shape:?}: a {width}x{height} unit needs [{height}, {width}, 6]"),
            ));
        }
        Ok(RayTable {
            width,
            height,
            rays: data
                .chunks_exact(6)
                .map(|c| [c[0], c[1], c[2], c[3], c[4], c[5]])
                .collect(),
        })
    }

    /// Write the table to `path` (`.npy`, float32 H × W × 6; atomically).
    pub fn save(&self, path: &Path) -> Result<()> {
        let flat: Vec<f32> = self.rays.iter().flatten().copied().collect();
        npy::write(path, &[self.height as usize, self.width as usize, 6], &flat)
    }

    /// The analytic unit's rays at every pixel (for comparison and tests).
    pub fn from_unit(unit: &MirrorUnit) -> RayTable {
        let (w, h) = (unit.lens.width, unit.lens.height);
        let rays = (0..w * h)
            .map(|i| {
                unit.back_project(f64::from(i % w), f64::from(i / w))
                    .map_or([f32::NAN; 6], |r| pack(&r))
            })
            .collect();
        RayTable {
            width: w,
            height: h,
            rays,
        }
    }

    /// Pixels with a ray.
    pub fn known(&self) -> usize {
        self.rays.iter().filter(|r| r[0].is_finite()).count()
    }

    /// The ray at sub-pixel (u, v): bilinear between the four pixels around it, all of which
    /// must be known.
    pub fn ray(&self, u: f64, v: f64) -> Option<Ray> {
        let (w, h) = (self.width as usize, self.height as usize);
        if !(u >= 0.0 && v >= 0.0 && u <= (w - 1) as f64 && v <= (h - 1) as f64) {
            return None;
        }
        let (x0, y0) = (
            (u as usize).min(w.saturating_sub(2)),
            (v as usize).min(h.saturating_sub(2)),
        );
        let (ax, ay) = (u - x0 as f64, v - y0 as f64);
        let mut sum = [0.0f64; 6];
        for (dx, dy, wgt) in [
            (0, 0, (1.0 - ax) * (1.0 - ay)),
            (1, 0, ax * (1.0 - ay)),
            (0, 1, (1.0 - ax) * ay),
            (1, 1, ax * ay),
        ] {
            let r = &self.rays[(y0 + dy) * w + x0 + dx];
            if !r[0].is_finite() {
                return None;
            }
            for (s, x) in sum.iter_mut().zip(r) {
                *s += wgt * f64::from(*x);
            }
        }
        let direction = Vec3::new(sum[3], sum[4], sum[5]);
        let n = direction.norm();
        (n > 1e-9).then(|| Ray {
            origin: Vec3::new(sum[0], sum[1], sum[2]),
            direction: direction / n,
        })
    }
}

/// A ray as stored.
pub fn pack(r: &Ray) -> [f32; 6] {
    [
        r.origin.x as f32,
        r.origin.y as f32,
        r.origin.z as f32,
        r.direction.x as f32,
        r.direction.y as f32,
        r.direction.z as f32,
    ]
}
