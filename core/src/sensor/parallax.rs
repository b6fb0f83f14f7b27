//! Plane-induced parallax model (Ch. 2.2): reconstruction from the camera model, the projector
//! centre and a reference recording of the bare plane, without projector intrinsics or rotation.
//!
//! For camera pixel p_s with code c: the camera ray meets the plane at Q. The epipolar plane
//! through O_c, O_p and the ray cuts the reference plane in a line through Q; along it the point
//! P_r whose reference code equals c is found (Newton on the fitted reference). The projector ray
//! O_p → P_r and the camera ray meet at the surface point P_s (Eq. 2.34 in world terms).

use crate::geometry::{closest_on_first, Mat3, Pinhole, Vec3};
use crate::sensor::rays::RayTable;
use crate::sensor::reference::PlaneCodeMap;

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
    /// Per camera pixel: φ along its epipolar line as a quadratic in the plane shift t around
    /// the ray's own plane point, [φ(0), φ'(0), φ''(0)]; built by [`Parallax::with_table`].
    table: Vec<[f32; 3]>,
}

/// The plane point of the ray `d` from `oc` and the unit direction of its epipolar line on the
/// plane, or `None` for rays that miss the plane or point at the projector.
#[inline]
fn epipolar_line(oc: &Vec3, op: &Vec3, d: &Vec3) -> Option<(Vec3, f64, f64)> {
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
    Some((q, n.y / len, -n.x / len))
}

impl Parallax {
    /// The projector's optical centre in the sensor frame, mm.
    pub fn projector_centre(&self) -> Vec3 {
        self.op
    }

    /// Geometry from the camera, the projector centre and the fitted reference.
    pub fn new(camera: &Pinhole, projector_center: Vec3, map: PlaneCodeMap) -> Self {
        Parallax {
            oc: camera.center(),
            op: projector_center,
            r_t: camera.r.transpose(),
            map,
            table: Vec::new(),
        }
    }

    /// Precompute the per-pixel quadratic of φ along each pixel's epipolar line, which lets
    /// [`Parallax::point_fast`] reconstruct with one evaluation of the reference map.
    pub fn with_table(mut self, rays: &RayTable, len: usize) -> Self {
        use rayon::prelude::*;
        let h = 1.0; // mm; φ is smooth on this scale
        self.table = (0..len)
            .into_par_iter()
            .map(|i| {
                let (x, y) = rays.get(i);
                let d = self.r_t * Vec3::new(x, y, 1.0);
                match epipolar_line(&self.oc, &self.op, &d) {
                    Some((q, lx, ly)) => {
                        let f = |t: f64| self.map.eval(q.x + t * lx, q.y + t * ly).0;
                        let (fm, f0, fp) = (f(-h), f(0.0), f(h));
                        [
                            f0 as f32,
                            ((fp - fm) / (2.0 * h)) as f32,
                            ((fp - 2.0 * f0 + fm) / (h * h)) as f32,
                        ]
                    }
                    None => [f32::NAN; 3],
                }
            })
            .collect();
        self
    }

    /// Reconstruct pixel `i` from the quadratic table (see [`Parallax::with_table`]) and one
    /// Newton step on the true reference map; falls back to the iterative search when the
    /// table has no entry.
    #[inline]
    pub fn point_fast(&self, rays: &RayTable, i: usize, code: f64) -> Option<ParallaxPoint> {
        let (x, y) = rays.get(i);
        let d = self.r_t * Vec3::new(x, y, 1.0);
        let Some(&[f0, g, c2]) = self.table.get(i) else {
            return self.point_for_direction(&d, code, 0.0).map(|(p, _)| p);
        };
        let (q, lx, ly) = epipolar_line(&self.oc, &self.op, &d)?;
        let (f0, g, c2) = (f64::from(f0), f64::from(g), f64::from(c2));
        if g.is_nan() || g.abs() <= 1e-9 {
            return None;
        }
        // Solve f0 + g t + c2 t²/2 = code (root nearest 0), then one Newton step on φ itself.
        let r = code - f0;
        let disc = g * g + 2.0 * c2 * r;
        let mut t = if c2.abs() > 1e-12 && disc >= 0.0 {
            2.0 * r / (g + g.signum() * disc.sqrt())
        } else {
            r / g
        };
        let (phi, gx, gy) = self.map.eval(q.x + t * lx, q.y + t * ly);
        let gl = gx * lx + gy * ly;
        if gl.abs() < 1e-9 {
            return None;
        }
        t -= (phi - code) / gl;
        let pr = Vec3::new(q.x + t * lx, q.y + t * ly, 0.0);
        let (alpha, gap) = closest_on_first(&self.oc, &d, &self.op, &(pr - self.op))?;
        (alpha > 0.0).then(|| ParallaxPoint {
            point: self.oc + d * alpha,
            shift: t.abs(),
            gap,
        })
    }

    /// Reconstruct the point seen at pixel `i` of `rays` carrying projector code `code`.
    #[inline]
    pub fn point(&self, rays: &RayTable, i: usize, code: f64) -> Option<ParallaxPoint> {
        let (x, y) = rays.get(i);
        self.point_for_direction(&(self.r_t * Vec3::new(x, y, 1.0)), code, 0.0)
            .map(|(p, _)| p)
    }

    /// As [`Parallax::point`], with the search along the epipolar line started at signed shift
    /// `guess` (e.g. the neighbouring pixel's); returns the point and its signed shift.
    #[inline]
    pub fn point_near(
        &self,
        rays: &RayTable,
        i: usize,
        code: f64,
        guess: f64,
    ) -> Option<(ParallaxPoint, f64)> {
        let (x, y) = rays.get(i);
        self.point_for_direction(&(self.r_t * Vec3::new(x, y, 1.0)), code, guess)
    }

    /// Reconstruct along a world ray direction `d` from the camera centre, starting the Newton
    /// search at signed plane shift `t0`.
    pub fn point_for_direction(
        &self,
        d: &Vec3,
        code: f64,
        t0: f64,
    ) -> Option<(ParallaxPoint, f64)> {
        let (oc, op) = (&self.oc, &self.op);
        let (q, lx, ly) = epipolar_line(oc, op, d)?;
        let mut t = t0;
        let mut converged = false;
        for _ in 0..12 {
            let (phi, gx, gy) = self.map.eval(q.x + t * lx, q.y + t * ly);
            let g = gx * lx + gy * ly;
            if g.abs() < 1e-9 {
                return None;
            }
            let step = (phi - code) / g;
            t -= step;
            if step.abs() < 1e-5 {
                converged = true;
                break;
            }
        }
        if !converged {
            return None;
        }
        let pr = Vec3::new(q.x + t * lx, q.y + t * ly, 0.0);
        let (alpha, gap) = closest_on_first(oc, d, op, &(pr - op))?;
        (alpha > 0.0).then(|| {
            (
                ParallaxPoint {
                    point: oc + d * alpha,
                    shift: t.abs(),
                    gap,
                },
                t,
            )
        })
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
