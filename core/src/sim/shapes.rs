//! Analytic primitives and meshes with exact ray intersection.

use super::texture::MarkerPaint;
use crate::geometry::Vec3;
use crate::mesh::Bvh;

/// A scene object: a shape and its material index.
#[derive(Clone, Debug)]
pub struct Object {
    /// Geometry.
    pub shape: Shape,
    /// Index into the scene's materials.
    pub material: usize,
    /// Markers painted over the material (gauges).
    pub markers: Option<MarkerPaint>,
    /// Velocity, mm/s (a part moving on a line); zero for a still object.
    pub velocity: Vec3,
    /// Displacement from the pose the scene file gives, at the time the scene is rendered
    /// ([`super::Scene::at`]).
    pub offset: Vec3,
    /// A panel that wears scan by scan ([`super::Scene::worn`]).
    pub wear: Option<super::PanelWear>,
}

impl Object {
    /// A still object.
    pub fn still(shape: Shape, material: usize, markers: Option<MarkerPaint>) -> Object {
        Object {
            shape,
            material,
            markers,
            velocity: Vec3::zeros(),
            offset: Vec3::zeros(),
            wear: None,
        }
    }
}

/// Geometry of a scene object.
#[derive(Clone, Debug)]
pub enum Shape {
    /// The reference plane z = 0.
    Plane,
    /// Axis-aligned box.
    Box {
        /// Centroid.
        center: Vec3,
        /// Half extents.
        half: Vec3,
    },
    /// Sphere.
    Sphere {
        /// Centre.
        center: Vec3,
        /// Radius.
        radius: f64,
    },
    /// Spherical cap standing on z = `base`, with its flat base disk.
    Dome {
        /// Centre of the sphere the cap is cut from.
        sphere_center: Vec3,
        /// Sphere radius.
        sphere_radius: f64,
        /// Base height.
        base: f64,
        /// Base disk radius.
        base_radius: f64,
    },
    /// Cylinder closed by two disks.
    Cylinder {
        /// Centroid.
        center: Vec3,
        /// Unit direction of the axis.
        axis: Vec3,
        /// Radius.
        radius: f64,
        /// Half height.
        half_height: f64,
    },
    /// Triangle mesh.
    Mesh(Box<Bvh>),
}

impl Shape {
    /// A dome of base radius `r` and height `h` standing on `center`.
    pub fn dome(center: Vec3, r: f64, h: f64) -> Shape {
        let rs = (r * r + h * h) / (2.0 * h);
        Shape::Dome {
            sphere_center: Vec3::new(center.x, center.y, center.z + h - rs),
            sphere_radius: rs,
            base: center.z,
            base_radius: r,
        }
    }

    /// Nearest hit with `t` in `(t_min, t_max)`, with the outward unit normal.
    pub fn intersect(&self, o: &Vec3, d: &Vec3, t_min: f64, t_max: f64) -> Option<(f64, Vec3)> {
        let ok = |t: f64| t > t_min && t < t_max;
        match self {
            Shape::Plane => {
                if d.z.abs() < 1e-15 {
                    return None;
                }
                let t = -o.z / d.z;
                ok(t).then(|| (t, Vec3::z()))
            }
            Shape::Box { center, half } => {
                let (mut lo, mut hi) = (f64::NEG_INFINITY, f64::INFINITY);
                let (mut axis_lo, mut axis_hi) = (0usize, 0usize);
                for k in 0..3 {
                    let inv = 1.0 / d[k];
                    let t1 = (center[k] - half[k] - o[k]) * inv;
                    let t2 = (center[k] + half[k] - o[k]) * inv;
                    let (a, b) = if t1 < t2 { (t1, t2) } else { (t2, t1) };
                    if a > lo {
                        lo = a;
                        axis_lo = k;
                    }
                    if b < hi {
                        hi = b;
                        axis_hi = k;
                    }
                }
                if lo > hi {
                    return None;
                }
                let (t, k) = if ok(lo) {
                    (lo, axis_lo)
                } else if ok(hi) {
                    (hi, axis_hi)
                } else {
                    return None;
                };
                let p = o + d * t;
                let mut n = Vec3::zeros();
                n[k] = (p[k] - center[k]).signum();
                Some((t, n))
            }
            Shape::Sphere { center, radius } => sphere_hits(o, d, center, *radius)
                .into_iter()
                .flatten()
                .find(|&t| ok(t))
                .map(|t| (t, (o + d * t - center) / *radius)),
            Shape::Dome {
                sphere_center,
                sphere_radius,
                base,
                base_radius,
            } => {
                let mut best: Option<(f64, Vec3)> = None;
                for t in sphere_hits(o, d, sphere_center, *sphere_radius)
                    .into_iter()
                    .flatten()
                {
                    if ok(t) && (o.z + d.z * t) >= *base {
                        best = Some((t, (o + d * t - sphere_center) / *sphere_radius));
                        break;
                    }
                }
                if let Some(t) = disk(o, d, *base, sphere_center.x, sphere_center.y, *base_radius) {
                    if ok(t) && best.is_none_or(|b| t < b.0) {
                        best = Some((t, -Vec3::z()));
                    }
                }
                best
            }
            Shape::Cylinder {
                center,
                axis,
                radius,
                half_height,
            } => {
                let mut best: Option<(f64, Vec3)> = None;
                // Components across the axis: |oc⊥ + t d⊥|² = r² on the side.
                let oc = o - center;
                let (oa, da) = (oc.dot(axis), d.dot(axis));
                let (oc_n, d_n) = (oc - axis * oa, d - axis * da);
                let a = d_n.dot(&d_n);
                if a > 1e-18 {
                    let b = oc_n.dot(&d_n);
                    let c = oc_n.dot(&oc_n) - radius * radius;
                    let disc = b * b - a * c;
                    if disc >= 0.0 {
                        let s = disc.sqrt();
                        for t in [(-b - s) / a, (-b + s) / a] {
                            if ok(t) && (oa + da * t).abs() <= *half_height {
                                best = Some((t, (oc_n + d_n * t) / *radius));
                                break;
                            }
                        }
                    }
                }
                if da.abs() > 1e-15 {
                    for side in [1.0, -1.0] {
                        let t = (side * half_height - oa) / da;
                        let across = oc_n + d_n * t;
                        if ok(t)
                            && across.dot(&across) <= radius * radius
                            && best.is_none_or(|b| t < b.0)
                        {
                            best = Some((t, axis * side));
                        }
                    }
                }
                best
            }
            Shape::Mesh(bvh) => bvh.intersect(o, d, t_min, t_max).map(|h| (h.t, h.normal)),
        }
    }
}

fn sphere_hits(o: &Vec3, d: &Vec3, c: &Vec3, r: f64) -> [Option<f64>; 2] {
    let oc = o - c;
    let a = d.dot(d);
    let b = oc.dot(d);
    let cc = oc.dot(&oc) - r * r;
    let disc = b * b - a * cc;
    if disc < 0.0 {
        return [None, None];
    }
    let s = disc.sqrt();
    [Some((-b - s) / a), Some((-b + s) / a)]
}

fn disk(o: &Vec3, d: &Vec3, z: f64, cx: f64, cy: f64, r: f64) -> Option<f64> {
    if d.z.abs() < 1e-15 {
        return None;
    }
    let t = (z - o.z) / d.z;
    let (x, y) = (o.x + d.x * t - cx, o.y + d.y * t - cy);
    (x * x + y * y <= r * r).then_some(t)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn primitives_report_entry_points_and_normals() {
        let o = Vec3::new(0.0, 0.0, 100.0);
        let d = -Vec3::z();
        let cases: [(Shape, f64); 5] = [
            (Shape::Plane, 100.0),
            (
                Shape::Box {
                    center: Vec3::new(0.0, 0.0, 20.0),
                    half: Vec3::new(10.0, 10.0, 20.0),
                },
                60.0,
            ),
            (
                Shape::Sphere {
                    center: Vec3::new(0.0, 0.0, 30.0),
                    radius: 30.0,
                },
                40.0,
            ),
            (Shape::dome(Vec3::zeros(), 50.0, 20.0), 80.0),
            (
                Shape::Cylinder {
                    center: Vec3::new(0.0, 0.0, 25.0),
                    axis: Vec3::z(),
                    radius: 10.0,
                    half_height: 25.0,
                },
                50.0,
            ),
        ];
        for (shape, want) in cases {
            let (t, n) = shape.intersect(&o, &d, 1e-9, f64::INFINITY).expect("hit");
            assert!((t - want).abs() < 1e-9, "{shape:?}: t = {t}");
            assert!((n - Vec3::z()).norm() < 1e-9, "{shape:?}: n = {n}");
        }
        // Side of the cylinder, seen horizontally.
        let cyl = Shape::Cylinder {
            center: Vec3::new(0.0, 0.0, 25.0),
            axis: Vec3::z(),
            radius: 10.0,
            half_height: 25.0,
        };
        let (t, n) = cyl
            .intersect(&Vec3::new(-50.0, 0.0, 10.0), &Vec3::x(), 0.0, f64::INFINITY)
            .expect("side");
        assert!((t - 40.0).abs() < 1e-9 && (n + Vec3::x()).norm() < 1e-9);
    }
}
