//! Hyperbolic mirror optics (Eq. 6.7, SPEC §13): the mirror is the sheet z > 0 of
//! z²/a² − (x² + y²)/b² = 1 in its mirror frame, with foci F1 = (0, 0, +e) and F2 = (0, 0, −e),
//! e = √(a² + b²). A ray heading for F1 reflects at the mirror into F2, where the pinhole sits:
//! the unit then sees from the single viewpoint F1. A pinhole displaced from F2 by `offset`
//! makes the unit non-central: each pixel's ray has its own origin on the mirror.

use crate::geometry::{Mat3, Pinhole, Vec3};

/// A hyperboloid-of-revolution mirror (mm).
#[derive(Clone, Debug, PartialEq)]
pub struct Mirror {
    /// Semi-axis along the axis of revolution.
    pub a: f64,
    /// Transverse semi-axis.
    pub b: f64,
    /// Radius of the mirror's edge: rays meeting the sheet further out miss the mirror.
    pub rim: f64,
}

/// A ray in the sensor frame: origin and unit direction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    /// Origin, mm.
    pub origin: Vec3,
    /// Unit direction.
    pub direction: Vec3,
}

impl Mirror {
    /// Focal distance e = √(a² + b²).
    pub fn e(&self) -> f64 {
        (self.a * self.a + self.b * self.b).sqrt()
    }

    /// Where the ray `o + s d` (s > 0) first meets the mirror sheet within its rim (mirror frame).
    pub fn intersect(&self, o: &Vec3, d: &Vec3) -> Option<Vec3> {
        let (a2, b2) = (self.a * self.a, self.b * self.b);
        let qa = d.z * d.z / a2 - (d.x * d.x + d.y * d.y) / b2;
        let qb = 2.0 * (o.z * d.z / a2 - (o.x * d.x + o.y * d.y) / b2);
        let qc = o.z * o.z / a2 - (o.x * o.x + o.y * o.y) / b2 - 1.0;
        let mut roots = [f64::NAN; 2];
        if qa.abs() < 1e-15 {
            roots[0] = -qc / qb;
        } else {
            let disc = qb * qb - 4.0 * qa * qc;
            if disc < 0.0 {
                return None;
            }
            // The numerically stable pair of roots.
            let q = -0.5 * (qb + qb.signum() * disc.sqrt());
            roots = [q / qa, qc / q];
        }
        roots.sort_by(f64::total_cmp);
        roots
            .iter()
            .filter(|s| s.is_finite() && **s > 1e-9)
            .map(|s| o + d * *s)
            .find(|p| p.z > 0.0 && (p.x * p.x + p.y * p.y).sqrt() <= self.rim)
    }

    /// Unit normal of the sheet at `p` (pointing out of the convex side that holds F1).
    pub fn normal(&self, p: &Vec3) -> Vec3 {
        Vec3::new(
            -p.x / (self.b * self.b),
            -p.y / (self.b * self.b),
            p.z / (self.a * self.a),
        )
        .normalize()
    }

    /// Direction `d` reflected at point `p` of the sheet.
    pub fn reflect(&self, p: &Vec3, d: &Vec3) -> Vec3 {
        let n = self.normal(p);
        (d - n * (2.0 * d.dot(&n))).normalize()
    }
}

/// A camera or projector behind its mirror: a pinhole at F2 + `offset` looking along the
/// mirror frame's +z, and the mirror frame's pose in the sensor frame.
#[derive(Clone, Debug)]
pub struct MirrorUnit {
    /// The mirror.
    pub mirror: Mirror,
    /// Intrinsics and size of the pinhole (its `r`, `t` are ignored: the unit places it).
    pub lens: Pinhole,
    /// Pinhole displacement from F2, mm (zero: a single-viewpoint unit).
    pub offset: Vec3,
    /// Mirror → sensor rotation: X_sensor = r X_mirror + t.
    pub r: Mat3,
    /// Mirror frame origin in the sensor frame, mm.
    pub t: Vec3,
}

impl MirrorUnit {
    /// The pinhole of the lens, placed at F2 + offset of the mirror frame.
    fn pinhole(&self) -> Pinhole {
        let centre = Vec3::new(0.0, 0.0, -self.mirror.e()) + self.offset;
        Pinhole {
            r: Mat3::identity(),
            t: -centre,
            ..self.lens.clone()
        }
    }

    /// Whether the pinhole sits at F2, so that every ray passes through F1.
    pub fn is_central(&self) -> bool {
        self.offset.norm() < 1e-12
    }

    /// The pixel that images the mirror's vertex: the centre of the conic image, about which
    /// the rings and the epipolar lines of a stacked sensor turn.
    pub fn axis_pixel(&self) -> Option<(f64, f64)> {
        self.pinhole().project(&Vec3::new(0.0, 0.0, self.mirror.a))
    }

    /// The single viewpoint F1 in the sensor frame.
    pub fn viewpoint(&self) -> Vec3 {
        self.r * Vec3::new(0.0, 0.0, self.mirror.e()) + self.t
    }

    /// The ray (sensor frame) that pixel (u, v) sees: from the mirror point it images, along
    /// the reflection. `None` when the pixel's ray misses the mirror.
    pub fn back_project(&self, u: f64, v: f64) -> Option<Ray> {
        let pin = self.pinhole();
        let o = pin.center();
        let d = pin.ray(u, v);
        let p = self.mirror.intersect(&o, &d)?;
        let out = self.mirror.reflect(&p, &d);
        Some(Ray {
            origin: self.r * p + self.t,
            direction: self.r * out,
        })
    }

    /// The pixel that sees sensor-frame point `x`, and the mirror point it is seen at; `None`
    /// when no mirror point reflects it into the pinhole (or `x` lies behind the mirror).
    pub fn project(&self, x: &Vec3) -> Option<((f64, f64), Vec3)> {
        let xm = self.r.transpose() * (x - self.t);
        let pin = self.pinhole();
        let f1 = Vec3::new(0.0, 0.0, self.mirror.e());
        // Central: the mirror point lies on the line from the point to F1.
        let mut p = self.mirror.intersect(&xm, &(f1 - xm).normalize())?;
        if !self.is_central() {
            p = self.reflection_point(&xm, p, &pin.center())?;
        }
        // Only the mirror's outer (convex) face reflects: a point on the side of F1 would be
        // seen through the mirror's back.
        if (xm - p).dot(&self.mirror.normal(&p)) > 0.0 {
            return None;
        }
        let px = pin.project(&p)?;
        let (w, h) = (f64::from(self.lens.width), f64::from(self.lens.height));
        if !(px.0 >= -0.5 && px.1 >= -0.5 && px.0 <= w - 0.5 && px.1 <= h - 0.5) {
            return None;
        }
        Some((px, self.r * p + self.t))
    }

    /// The mirror point at which `x` reflects into `c` (mirror frame), by Newton's method from
    /// `start`, over the point's (polar radius, azimuth) on the sheet: the bisector of the
    /// directions to `x` and to `c` must be the surface normal.
    fn reflection_point(&self, x: &Vec3, start: Vec3, c: &Vec3) -> Option<Vec3> {
        let (a, b) = (self.mirror.a, self.mirror.b);
        let on_sheet = |rho: f64, phi: f64| {
            let z = a * (1.0 + rho * rho / (b * b)).sqrt();
            Vec3::new(rho * phi.cos(), rho * phi.sin(), z)
        };
        // Residual: tangential components of (unit to x + unit to c), zero at the reflection.
        let residual = |rho: f64, phi: f64| {
            let p = on_sheet(rho, phi);
            let s = (x - p).normalize() + (c - p).normalize();
            let n = self.mirror.normal(&p);
            // Two tangents: the azimuthal direction (tangent to any surface of revolution)
            // and the one across it.
            let t1 = Vec3::new(-phi.sin(), phi.cos(), 0.0);
            let t2 = n.cross(&t1);
            (s.dot(&t1), s.dot(&t2))
        };
        let (mut rho, mut phi) = (
            (start.x * start.x + start.y * start.y).sqrt(),
            start.y.atan2(start.x),
        );
        for _ in 0..50 {
            let (f1, f2) = residual(rho, phi);
            if f1.abs() + f2.abs() < 1e-13 {
                break;
            }
            let h = 1e-6;
            let (a1, a2) = residual(rho + h, phi);
            let (b1, b2) = residual(rho, phi + h);
            let j =
                nalgebra::Matrix2::new((a1 - f1) / h, (b1 - f1) / h, (a2 - f2) / h, (b2 - f2) / h);
            let step = j.try_inverse()? * nalgebra::Vector2::new(-f1, -f2);
            rho = (rho + step.x).max(0.0);
            phi += step.y;
        }
        let (f1, f2) = residual(rho, phi);
        let p = on_sheet(rho, phi);
        (f1.abs() + f2.abs() < 1e-9 && rho <= self.mirror.rim).then_some(p)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Distortion;

    /// The seed's prototype mirror (a² = 1248.2060, b² = 351.7940: e = 40 mm) and 640×480 camera,
    /// mirror facing down with F1 at sensor z = +150 mm (SPEC §13's camera unit).
    fn unit(offset: Vec3) -> MirrorUnit {
        MirrorUnit {
            mirror: Mirror {
                a: 1248.2060f64.sqrt(),
                b: 351.7940f64.sqrt(),
                rim: 30.0,
            },
            lens: Pinhole {
                width: 640,
                height: 480,
                k: Mat3::new(400.0, 0.0, 319.5, 0.0, 400.0, 239.5, 0.0, 0.0, 1.0),
                dist: Distortion::default(),
                r: Mat3::identity(),
                t: Vec3::zeros(),
            },
            offset,
            r: Mat3::new(1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0),
            t: Vec3::new(0.0, 0.0, 190.0),
        }
    }

    fn room_points() -> Vec<Vec3> {
        let mut rng = crate::testing::Rng(17);
        let mut u = move || rng.uniform();
        (0..400)
            .map(|_| {
                let (az, range) = (u() * std::f64::consts::TAU, 2000.0 + 2000.0 * u());
                Vec3::new(range * az.cos(), range * az.sin(), -1200.0 + 2400.0 * u())
            })
            .collect()
    }

    #[test]
    fn focal_property_a_ray_for_f1_reflects_into_f2() {
        let m = unit(Vec3::zeros()).mirror;
        assert!((m.e() - 40.0).abs() < 1e-9);
        let (f1, f2) = (Vec3::new(0.0, 0.0, m.e()), Vec3::new(0.0, 0.0, -m.e()));
        for (x, y) in [(10.0, 0.0), (-7.0, 15.0), (20.0, -20.0)] {
            let p = Vec3::new(x, y, m.a * (1.0 + (x * x + y * y) / (m.b * m.b)).sqrt());
            // A ray from far outside heading for F1 hits the sheet at p and leaves towards F2.
            let d = (f1 - p).normalize();
            let hit = m.intersect(&(p - d * 500.0), &d).expect("hit");
            assert!((hit - p).norm() < 1e-8, "{hit} vs {p}");
            let out = m.reflect(&p, &d);
            assert!((out - (f2 - p).normalize()).norm() < 1e-12);
        }
    }

    #[test]
    fn central_unit_projects_and_back_projects_through_its_single_viewpoint() {
        let unit = unit(Vec3::zeros());
        let f1 = unit.viewpoint();
        assert!((f1 - Vec3::new(0.0, 0.0, 150.0)).norm() < 1e-9);
        let mut seen = 0;
        for x in room_points() {
            let Some(((u, v), on_mirror)) = unit.project(&x) else {
                continue;
            };
            seen += 1;
            let ray = unit.back_project(u, v).expect("pixel sees the mirror");
            assert!((ray.origin - on_mirror).norm() < 1e-6);
            // The ray passes through the point and, extended back, through F1.
            let to_x = x - ray.origin;
            assert!(
                to_x.cross(&ray.direction).norm() < 1e-6 * to_x.norm(),
                "{x}"
            );
            assert!(to_x.dot(&ray.direction) > 0.0);
            let back = f1 - ray.origin;
            assert!(back.cross(&ray.direction).norm() < 1e-9 * back.norm().max(1.0));
        }
        assert!(seen > 200, "{seen} of 400 room points seen");
    }

    #[test]
    fn displaced_pinhole_gives_rays_with_their_own_origins() {
        let unit = unit(Vec3::new(1.5, -0.8, 2.0));
        assert!(!unit.is_central());
        let f1 = unit.viewpoint();
        let (mut seen, mut worst_miss) = (0, 0.0f64);
        for x in room_points() {
            let Some(((u, v), on_mirror)) = unit.project(&x) else {
                continue;
            };
            seen += 1;
            let ray = unit.back_project(u, v).expect("pixel sees the mirror");
            assert!(
                (ray.origin - on_mirror).norm() < 1e-5,
                "{} vs {on_mirror}",
                ray.origin
            );
            let to_x = x - ray.origin;
            assert!(
                to_x.cross(&ray.direction).norm() < 1e-5 * to_x.norm(),
                "{x}"
            );
            // F1 is no longer on every ray: the unit is non-central.
            let back = f1 - ray.origin;
            worst_miss = worst_miss.max(back.cross(&ray.direction).norm());
        }
        assert!(seen > 200, "{seen} of 400 room points seen");
        assert!(worst_miss > 0.05, "rays still meet at F1 ({worst_miss} mm)");
    }

    #[test]
    fn rays_outside_the_rim_miss_the_mirror() {
        let unit = unit(Vec3::zeros());
        // The image corner looks past a 30 mm rim; the principal point sees the mirror's apex.
        assert!(unit.back_project(0.0, 0.0).is_none());
        let apex = unit.back_project(319.5, 239.5).expect("apex");
        assert!((apex.origin - unit.r * Vec3::new(0.0, 0.0, unit.mirror.a) - unit.t).norm() < 1e-9);
    }
}
