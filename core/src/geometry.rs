//! The small math vocabulary of RIS: vectors, the pinhole camera with Brown distortion, and
//! line–line geometry. Millimetres; `X_c = R X_w + t` (SPEC §2).

pub use nalgebra::{Matrix3, Matrix4, Point3, Vector2, Vector3};

/// 3-vector of f64.
pub type Vec3 = Vector3<f64>;
/// 3×3 matrix of f64.
pub type Mat3 = Matrix3<f64>;

/// OpenCV's Brown distortion (k1, k2, p1, p2, k3) on normalized image coordinates.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Distortion {
    /// Radial r².
    pub k1: f64,
    /// Radial r⁴.
    pub k2: f64,
    /// Tangential.
    pub p1: f64,
    /// Tangential.
    pub p2: f64,
    /// Radial r⁶.
    pub k3: f64,
}

impl Distortion {
    /// From OpenCV order `[k1, k2, p1, p2, k3]`.
    pub fn from_array(d: [f64; 5]) -> Self {
        Distortion {
            k1: d[0],
            k2: d[1],
            p1: d[2],
            p2: d[3],
            k3: d[4],
        }
    }

    /// As OpenCV order `[k1, k2, p1, p2, k3]`.
    pub fn to_array(&self) -> [f64; 5] {
        [self.k1, self.k2, self.p1, self.p2, self.k3]
    }

    /// Whether all coefficients are zero.
    pub fn is_zero(&self) -> bool {
        self.to_array().iter().all(|&c| c == 0.0)
    }

    /// Distort normalized coordinates.
    #[inline]
    pub fn distort(&self, x: f64, y: f64) -> (f64, f64) {
        let (d, _, _) = self.distort_with_radial(x, y);
        d
    }

    /// [`Distortion::distort`] with the r² and radial factor it used (for the Jacobian).
    #[inline]
    fn distort_with_radial(&self, x: f64, y: f64) -> ((f64, f64), f64, f64) {
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        (
            (
                x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x),
                y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y,
            ),
            r2,
            radial,
        )
    }

    /// Invert [`Distortion::distort`] by Newton's method with the model's analytic Jacobian
    /// (converges to ~1e-12 in a few steps for realistic lenses).
    pub fn undistort(&self, xd: f64, yd: f64) -> (f64, f64) {
        self.undistort_from(xd, yd, (xd, yd))
    }

    /// [`Distortion::undistort`] with Newton's method started at `start`: a nearby point's
    /// solution, moved by the difference of the distorted points, is within about a
    /// millionth of this one's, and one step settles it instead of two or three.
    pub fn undistort_from(&self, xd: f64, yd: f64, start: (f64, f64)) -> (f64, f64) {
        if self.is_zero() {
            return (xd, yd);
        }
        let (mut x, mut y) = start;
        for _ in 0..20 {
            let ((fx, fy), r2, radial) = self.distort_with_radial(x, y);
            let (ex, ey) = (fx - xd, fy - yd);
            if ex * ex + ey * ey < 1e-24 {
                break;
            }
            let [j00, j01, j11] = self.jacobian(x, y, r2, radial);
            let det = j00 * j11 - j01 * j01;
            if det.abs() < 1e-12 {
                break;
            }
            x -= (j11 * ex - j01 * ey) / det;
            y -= (-j01 * ex + j00 * ey) / det;
        }
        (x, y)
    }

    /// The Jacobian of [`Distortion::distort`] at (x, y) given r² and the radial factor there:
    /// [∂x'/∂x, ∂x'/∂y (= ∂y'/∂x), ∂y'/∂y].
    fn jacobian(&self, x: f64, y: f64, r2: f64, radial: f64) -> [f64; 3] {
        // d radial / d r²
        let dr = self.k1 + r2 * (2.0 * self.k2 + 3.0 * self.k3 * r2);
        [
            radial + 2.0 * x * x * dr + 2.0 * self.p1 * y + 6.0 * self.p2 * x,
            2.0 * x * y * dr + 2.0 * self.p1 * x + 2.0 * self.p2 * y,
            radial + 2.0 * y * y * dr + 6.0 * self.p1 * y + 2.0 * self.p2 * x,
        ]
    }
}

/// A pinhole device (camera or projector) with pose `X_dev = R X_w + t`.
#[derive(Clone, Debug, PartialEq)]
pub struct Pinhole {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Intrinsics K.
    pub k: Mat3,
    /// Lens distortion.
    pub dist: Distortion,
    /// Rotation world → device.
    pub r: Mat3,
    /// Translation world → device.
    pub t: Vec3,
}

impl Pinhole {
    /// Optical centre in the world frame, `C = −Rᵀ t`.
    pub fn center(&self) -> Vec3 {
        -(self.r.transpose() * self.t)
    }

    /// Project a world point to (distorted) pixel coordinates; `None` behind the device.
    pub fn project(&self, p: &Vec3) -> Option<(f64, f64)> {
        let c = self.r * p + self.t;
        if c.z <= 1e-9 {
            return None;
        }
        let (x, y) = self.dist.distort(c.x / c.z, c.y / c.z);
        Some((
            self.k[(0, 0)] * x + self.k[(0, 1)] * y + self.k[(0, 2)],
            self.k[(1, 1)] * y + self.k[(1, 2)],
        ))
    }

    /// Undistorted normalized coordinates of pixel (u, v).
    pub fn normalized(&self, u: f64, v: f64) -> (f64, f64) {
        let (xd, yd) = self.distorted(u, v);
        self.dist.undistort(xd, yd)
    }

    /// Distorted normalized coordinates of pixel (u, v): K undone, the lens not.
    fn distorted(&self, u: f64, v: f64) -> (f64, f64) {
        let yd = (v - self.k[(1, 2)]) / self.k[(1, 1)];
        (
            (u - self.k[(0, 2)] - self.k[(0, 1)] * yd) / self.k[(0, 0)],
            yd,
        )
    }

    /// Unit direction (world frame) of the ray through pixel (u, v).
    pub fn ray(&self, u: f64, v: f64) -> Vec3 {
        let (x, y) = self.normalized(u, v);
        self.direction(x, y)
    }

    /// [`Pinhole::ray`] with the lens undone from a nearby pixel's solution: `near` holds the
    /// last pixel's distorted and undistorted normalized coordinates (`None` at first) and
    /// is updated to this pixel's. For pixels visited in order (a ray cast's sub-samples).
    pub fn ray_near(&self, u: f64, v: f64, near: &mut Option<[f64; 4]>) -> Vec3 {
        let (xd, yd) = self.distorted(u, v);
        let start = near.map_or((xd, yd), |[xd0, yd0, x0, y0]| {
            (x0 + xd - xd0, y0 + yd - yd0)
        });
        let (x, y) = self.dist.undistort_from(xd, yd, start);
        *near = Some([xd, yd, x, y]);
        self.direction(x, y)
    }

    /// Unit world direction for undistorted normalized coordinates (x, y).
    #[inline]
    pub fn direction(&self, x: f64, y: f64) -> Vec3 {
        (self.r.transpose() * Vec3::new(x, y, 1.0)).normalize()
    }
}

/// Parameter α of the point on line `o1 + α d1` closest to line `o2 + β d2`, with the distance
/// between the lines; `None` for parallel lines.
#[inline]
pub fn closest_on_first(o1: &Vec3, d1: &Vec3, o2: &Vec3, d2: &Vec3) -> Option<(f64, f64)> {
    let w0 = o1 - o2;
    let (a, b, c) = (d1.dot(d1), d1.dot(d2), d2.dot(d2));
    let (d, e) = (d1.dot(&w0), d2.dot(&w0));
    let den = a * c - b * b;
    if den.abs() < 1e-12 * a * c {
        return None;
    }
    let alpha = (b * e - c * d) / den;
    let beta = (a * e - b * d) / den;
    let gap = ((o1 + d1 * alpha) - (o2 + d2 * beta)).norm();
    Some((alpha, gap))
}

/// The rows of a 3×3 matrix, as files store it (`k`, `r`).
pub fn rows_of(m: &Mat3) -> [[f64; 3]; 3] {
    [0, 1, 2].map(|i| [m[(i, 0)], m[(i, 1)], m[(i, 2)]])
}

/// Whether (x, y) lies in the rectangle `[x_min, x_max, y_min, y_max]` (edges included).
#[inline]
pub fn in_rect(r: &[f64; 4], x: f64, y: f64) -> bool {
    x >= r[0] && x <= r[1] && y >= r[2] && y <= r[3]
}

/// The rotation of a row-major 4×4 rigid transform as a unit quaternion.
pub fn rotation_of(m: &[[f64; 4]; 4]) -> nalgebra::UnitQuaternion<f64> {
    nalgebra::UnitQuaternion::from_matrix(&Mat3::from_fn(|i, j| m[i][j]))
}

/// Rotation matrix from XYZ Euler angles in degrees (applied x, then y, then z).
pub fn rotation_xyz_deg(angles: [f64; 3]) -> Mat3 {
    let [a, b, c] = angles.map(f64::to_radians);
    let rx = Mat3::new(1.0, 0.0, 0.0, 0.0, a.cos(), -a.sin(), 0.0, a.sin(), a.cos());
    let ry = Mat3::new(b.cos(), 0.0, b.sin(), 0.0, 1.0, 0.0, -b.sin(), 0.0, b.cos());
    let rz = Mat3::new(c.cos(), -c.sin(), 0.0, c.sin(), c.cos(), 0.0, 0.0, 0.0, 1.0);
    rz * ry * rx
}

/// World → camera rotation and translation of a device at `eye` looking at `target`, with the
/// image's v axis pointing along −`up` (so `up` appears at the top of the image).
pub fn look_at(eye: Vec3, target: Vec3, up: Vec3) -> (Mat3, Vec3) {
    let z = (target - eye).normalize();
    let x = z.cross(&up).normalize();
    let y = z.cross(&x);
    let r = Mat3::from_rows(&[x.transpose(), y.transpose(), z.transpose()]);
    (r, -(r * eye))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn undistort_inverts_distort() {
        let d = Distortion::from_array([-0.266, -0.0386, 0.0018, -0.0003, 0.2384]);
        for &(x, y) in &[(0.0, 0.0), (0.3, -0.2), (-0.5, 0.4), (0.1, 0.6)] {
            let (xd, yd) = d.distort(x, y);
            let (xu, yu) = d.undistort(xd, yd);
            assert!(
                (xu - x).abs() < 1e-10 && (yu - y).abs() < 1e-10,
                "({x},{y}) -> ({xu},{yu})"
            );
        }
    }

    /// Rays solved from the previous pixel's lens solution, visited in raster order with
    /// sub-sample steps and jumps to a new row, are the rays solved afresh (to Newton's
    /// tolerance), for a strong lens with tangential terms.
    #[test]
    fn rays_solved_from_a_neighbour_are_the_rays_solved_afresh() {
        let cam = Pinhole {
            width: 640,
            height: 480,
            k: Mat3::new(600.0, 0.5, 320.0, 0.0, 610.0, 240.0, 0.0, 0.0, 1.0),
            dist: Distortion::from_array([-0.266, -0.0386, 0.0018, -0.0003, 0.2384]),
            r: Mat3::identity(),
            t: Vec3::zeros(),
        };
        let mut near = None;
        for v in (0..480).step_by(37) {
            for u in 0..640 {
                for sub in [0.125, 0.375, 0.625, 0.875] {
                    let (uu, vv) = (u as f64 + sub - 0.5, v as f64 + sub - 0.5);
                    let a = cam.ray_near(uu, vv, &mut near);
                    let b = cam.ray(uu, vv);
                    assert!((a - b).norm() < 1e-11, "({uu}, {vv}): {a:?} against {b:?}");
                }
            }
        }
    }

    #[test]
    fn the_distortion_jacobian_matches_central_differences() {
        let d = Distortion::from_array([-0.266, -0.0386, 0.0018, -0.0003, 0.2384]);
        for &(x, y) in &[(0.0, 0.0), (0.3, -0.2), (-0.5, 0.4), (0.1, 0.6)] {
            let (_, r2, radial) = d.distort_with_radial(x, y);
            let j = d.jacobian(x, y, r2, radial);
            let h = 1e-6;
            let (ax, ay) = d.distort(x + h, y);
            let (bx, by) = d.distort(x - h, y);
            let (cx, cy) = d.distort(x, y + h);
            let (dx, dy) = d.distort(x, y - h);
            let numeric = [
                (ax - bx) / (2.0 * h),
                (cx - dx) / (2.0 * h),
                (cy - dy) / (2.0 * h),
            ];
            let across = (ay - by) / (2.0 * h);
            for (a, n) in j.iter().zip(numeric) {
                assert!((a - n).abs() < 1e-8, "({x},{y}): {j:?} vs {numeric:?}");
            }
            assert!((j[1] - across).abs() < 1e-8, "∂y'/∂x {across} vs {}", j[1]);
        }
    }

    #[test]
    fn project_and_ray_agree() {
        let (r, t) = look_at(Vec3::new(300.0, -50.0, 1600.0), Vec3::zeros(), Vec3::y());
        let cam = Pinhole {
            width: 800,
            height: 600,
            k: Mat3::new(1800.0, 0.0, 400.0, 0.0, 1800.0, 300.0, 0.0, 0.0, 1.0),
            dist: Distortion::from_array([-0.1, 0.05, 0.001, -0.001, 0.0]),
            r,
            t,
        };
        let p = Vec3::new(40.0, -25.0, 30.0);
        let (u, v) = cam.project(&p).expect("in front");
        let dir = cam.ray(u, v);
        let to_p = (p - cam.center()).normalize();
        assert!((dir - to_p).norm() < 1e-9);
        let (cu, cv) = cam.project(&Vec3::zeros()).expect("target");
        assert!((cu - 400.0).abs() < 1e-6 && (cv - 300.0).abs() < 1e-6);
    }

    #[test]
    fn closest_point_of_skew_lines() {
        let (alpha, gap) = closest_on_first(
            &Vec3::zeros(),
            &Vec3::x(),
            &Vec3::new(2.0, 0.0, 1.0),
            &Vec3::y(),
        )
        .expect("skew");
        assert!((alpha - 2.0).abs() < 1e-12 && (gap - 1.0).abs() < 1e-12);
    }
}
