//! Per-pixel undistorted camera rays, computed once per sensor so reconstruction is a table
//! look-up instead of an iterative undistortion per point.

use rayon::prelude::*;

use crate::geometry::{Mat3, Pinhole, Vec3};

/// Undistorted normalized coordinates (x, y) of every camera pixel, row-major.
#[derive(Clone, Debug)]
pub struct RayTable {
    width: u32,
    xy: Vec<[f32; 2]>,
}

impl RayTable {
    /// Build the table for `camera` (parallel over rows).
    pub fn new(camera: &Pinhole) -> Self {
        let (w, h) = (camera.width as usize, camera.height as usize);
        let mut xy = vec![[0f32; 2]; w * h];
        xy.par_chunks_mut(w).enumerate().for_each(|(v, row)| {
            for (u, out) in row.iter_mut().enumerate() {
                let (x, y) = camera.normalized(u as f64, v as f64);
                *out = [x as f32, y as f32];
            }
        });
        RayTable {
            width: camera.width,
            xy,
        }
    }

    /// Normalized coordinates of pixel index `i` (row-major).
    #[inline]
    pub fn get(&self, i: usize) -> (f64, f64) {
        let [x, y] = self.xy[i];
        (f64::from(x), f64::from(y))
    }

    /// World point where the ray of pixel `i` meets the plane z = `h`, for a camera centred at
    /// `oc` with camera → world rotation `r_t`; `None` behind the camera.
    #[inline]
    pub fn on_plane(&self, i: usize, oc: &Vec3, r_t: &Mat3, h: f64) -> Option<Vec3> {
        let (x, y) = self.get(i);
        let d = r_t * Vec3::new(x, y, 1.0);
        let lam = (h - oc.z) / d.z;
        (lam > 0.0 && lam.is_finite()).then(|| oc + d * lam)
    }

    /// Camera-frame direction (not normalized) of pixel (u, v).
    #[inline]
    pub fn camera_dir(&self, u: u32, v: u32) -> Vec3 {
        let (x, y) = self.get((v * self.width + u) as usize);
        Vec3::new(x, y, 1.0)
    }
}
