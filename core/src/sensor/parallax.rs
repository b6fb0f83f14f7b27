//! Plane-induced parallax model (Ch. 2.2): reconstruction from the camera model, the projector
//! centre and a reference recording of the bare plane, without projector intrinsics or rotation.
//!
//! For camera pixel p_s with code c: the camera ray meets the plane at Q. The epipolar plane
//! through O_c, O_p and the ray cuts the reference plane in a line through Q; along it the point
//! P_r whose reference code equals c is found (Newton on the fitted reference). The projector ray
//! O_p → P_r and the camera ray meet at the surface point P_s (Eq. 2.34 in world terms).

use crate::geometry::{closest_on_first, Mat3, Pinhole, Vec3};
use crate::sensor::reference::PlaneCodeMap;
use crate::sensor::rays::RayTable;

/// Eq. 2.37, the parallel configuration: height from the plane distance m = |H p_sr| between the
/// camera ray's plane point and the reference point with the same code, for standoff S and
/// baseline d.
///
/// ```
/// let h = ris_core::sensor::parallel_height(1600.0, 500.0, 15.625);
/// assert!((h - 48.48).abs() < 0.01);
/// ```
pub fn parallel_height(standoff: f64, baseline: f64, m: f64) -> f64 {
    standoff * m / (baseline + m)
}

/// A surface point with the quantities the parallax model produced it from.
#[derive(Clone, Copy, Debug)]
pub struct ParallaxPoint {
    /// The surface point P_s, sensor world frame.
    pub point: Vec3,
    /// m = |P_r − Q| on the reference plane (|H p_sr| of Eq. 2.36), mm.
    pub shift: f64,
    /// Distance between camera ray and projector ray, mm (a quality measure).
    pub gap: f64,
}

/// The parallax geometry of one sensor with the fitted reference along one code axis.
#[derive(Clone, Debug)]
pub struct Parallax {
    oc: Vec3,
    op: Vec3,
    r_t: Mat3,
    /// The reference code map φ(X, Y).
    pub map: PlaneCodeMap,
}

impl Parallax {
    /// Geometry from the camera, the projector centre and the fitted reference.
    pub fn new(camera: &Pinhole, projector_center: Vec3, map: PlaneCodeMap) -> Self {
        Parallax { oc: camera.center(), op: projector_center, r_t: camera.r.transpose(), map }
    }

    /// Reconstruct the point seen at pixel `i` of `rays` carrying projector code `code`.
    #[inline]
    pub fn point(&self, rays: &RayTable, i: usize, code: f64) -> Option<ParallaxPoint> {
        let (x, y) = rays.get(i);
        self.point_for_direction(&(self.r_t * Vec3::new(x, y, 1.0)), code)
    }

    /// Reconstruct along a world ray direction `d` from the camera centre.
    pub fn point_for_direction(&self, d: &Vec3, code: f64) -> Option<ParallaxPoint> {
        let (oc, op) = (&self.oc, &self.op);
        if d.z.abs() < 1e-12 {
            return None;
        }
        let lam = -oc.z / d.z;
        if lam <= 0.0 {
            return None;
        }
        let q = oc + d * lam;
        let n = (op - oc).cross(d);
        let len = n.x.hypot(n.y);
        if len < 1e-12 {
            return None;
        }
        let (lx, ly) = (n.y / len, -n.x / len);
        let mut t = 0.0;
        let mut converged = false;
        for _ in 0..10 {
            let (phi, gx, gy) = self.map.eval(q.x + t * lx, q.y + t * ly);
            let g = gx * lx + gy * ly;
            if g.abs() < 1e-9 {
                return None;
            }
            let step = (phi - code) / g;
            t -= step;
            if step.abs() < 1e-7 {
                converged = true;
                break;
            }
        }
        if !converged {
            return None;
        }
        let pr = Vec3::new(q.x + t * lx, q.y + t * ly, 0.0);
        let (alpha, gap) = closest_on_first(oc, d, op, &(pr - op))?;
        (alpha > 0.0).then(|| ParallaxPoint { point: oc + d * alpha, shift: t.abs(), gap })
    }

    /// Camera centre.
    pub fn camera_center(&self) -> Vec3 {
        self.oc
    }

    /// Camera → world rotation.
    pub fn world_from_camera(&self) -> &Mat3 {
        &self.r_t
    }
}
