//! Classical triangulation with a fully calibrated projector: camera ray against the projector
//! ray (column and row known) or the projector column plane (column only).

use crate::geometry::{closest_on_first, Mat3, Pinhole, Vec3};

/// Camera + projector triangulation geometry.
#[derive(Clone, Debug)]
pub struct Classical {
    oc: Vec3,
    r_t: Mat3,
    projector: Pinhole,
    op: Vec3,
    rp_t: Mat3,
}

impl Classical {
    /// The projector's optical centre in the sensor frame, mm.
    pub fn projector_centre(&self) -> Vec3 {
        self.op
    }

    /// Geometry from both devices' calibrations.
    pub fn new(camera: &Pinhole, projector: &Pinhole) -> Self {
        Classical {
            oc: camera.center(),
            r_t: camera.r.transpose(),
            projector: projector.clone(),
            op: projector.center(),
            rp_t: projector.r.transpose(),
        }
    }

    /// Camera-frame direction (x, y, 1) → world point on the camera ray closest to the projector
    /// ray through (col, row), or on the column plane of `col` when `row` is `None`.
    pub fn point(&self, x: f64, y: f64, col: f64, row: Option<f64>) -> Option<Vec3> {
        let d = self.r_t * Vec3::new(x, y, 1.0);
        let alpha = match row {
            Some(row) => {
                let (xp, yp) = self.projector.normalized(col, row);
                let e = self.rp_t * Vec3::new(xp, yp, 1.0);
                closest_on_first(&self.oc, &d, &self.op, &e)?.0
            }
            None => self.column_plane(&d, col)?,
        };
        (alpha > 0.0).then(|| self.oc + d * alpha)
    }

    /// Intersect the camera ray with the (distortion-aware) light sheet of projector column
    /// `col`: iterate plane intersection and re-projection to find the row the point lies on.
    fn column_plane(&self, d: &Vec3, col: f64) -> Option<f64> {
        let p = &self.projector;
        let mut row = p.k[(1, 2)];
        let mut alpha = None;
        let iterations = if p.dist.is_zero() { 1 } else { 6 };
        for _ in 0..iterations {
            let (xn, _) = p.normalized(col, row);
            // Plane x − xn z = 0 in the projector frame, i.e. nᵀ(R X + t) = 0.
            let nl = Vec3::new(1.0, 0.0, -xn);
            let nw = self.rp_t * nl;
            let c0 = nl.dot(&p.t);
            let den = nw.dot(d);
            if den.abs() < 1e-12 {
                return None;
            }
            let a = -(nw.dot(&self.oc) + c0) / den;
            alpha = Some(a);
            match p.project(&(self.oc + d * a)) {
                Some((_, v)) => row = v,
                None => return None,
            }
        }
        alpha
    }
}
