//! Rendering through the mirrors (Ch. 6): a room (walls, floor, ceiling, and boxes and
//! cylinders standing in it) seen by the omnidirectional camera and lit by its projector
//! showing any picture, with per-pixel ground truth. Each camera pixel's ray is reflected at
//! the camera's mirror, meets the room, and the point is lit by the projector pixel that
//! reaches it through the projector's mirror, unless something stands in between.

use rayon::prelude::*;

use super::OmniSensor;
use crate::geometry::Vec3;
use crate::image::GrayImage;
use crate::sim::Shape;
use crate::{Error, Result};

/// A rectangular room around the sensor (sensor frame, mm, z up) and what stands in it.
#[derive(Clone, Debug)]
pub struct Room {
    /// Half the room's size along x and y: walls at x = ±`half[0]` and y = ±`half[1]` about
    /// `center`.
    pub half: [f64; 2],
    /// The room's centre (x, y) in the sensor frame.
    pub center: [f64; 2],
    /// Floor height.
    pub floor: f64,
    /// Ceiling height.
    pub ceiling: f64,
    /// Albedo of the walls, the floor and the ceiling.
    pub albedo: [f64; 3],
    /// Boxes and cylinders (and any other shape), each with its albedo.
    pub objects: Vec<(Shape, f64)>,
}

/// How frames are exposed.
#[derive(Clone, Copy, Debug)]
pub struct Exposure {
    /// Grey level of a white surface fully lit by the projector, head on.
    pub gain: f64,
    /// Ambient light, as a fraction of the projector's white.
    pub ambient: f64,
    /// Read noise σ, grey levels.
    pub noise: f64,
    /// Seed of the noise.
    pub seed: u64,
}

impl Default for Exposure {
    fn default() -> Self {
        Exposure {
            gain: 230.0,
            ambient: 0.03,
            noise: 1.0,
            seed: 1,
        }
    }
}

/// Per camera pixel: the point it sees (NaN where its ray misses the mirror or the room) and
/// whether the projector reaches that point.
#[derive(Clone, Debug)]
pub struct OmniTruth {
    /// Points, sensor frame, mm.
    pub xyz: Vec<[f32; 3]>,
    /// Whether the projector lights it (not shadowed, inside the projector's mirror).
    pub lit: Vec<bool>,
    /// The projector pixel that lights it (NaN where unlit).
    pub projector: Vec<[f32; 2]>,
}

impl Room {
    /// Nearest surface along `o + t d` (t > 1e-6): distance, unit normal facing the ray,
    /// albedo. The room's own box is seen from inside.
    pub fn intersect(&self, o: &Vec3, d: &Vec3) -> Option<(f64, Vec3, f64)> {
        let mut best: Option<(f64, Vec3, f64)> = None;
        // Leaving the room's box: the nearest positive exit across the six planes.
        let bounds = [
            (
                0,
                self.center[0] - self.half[0],
                self.center[0] + self.half[0],
                self.albedo[0],
            ),
            (
                1,
                self.center[1] - self.half[1],
                self.center[1] + self.half[1],
                self.albedo[0],
            ),
        ];
        let mut consider = |t: f64, n: Vec3, albedo: f64| {
            if t > 1e-6 && best.is_none_or(|b| t < b.0) {
                best = Some((t, n, albedo));
            }
        };
        for (axis, lo, hi, albedo) in bounds {
            let (oa, da) = (o[axis], d[axis]);
            if da.abs() > 1e-15 {
                let mut n = Vec3::zeros();
                if da > 0.0 {
                    n[axis] = -1.0;
                    consider((hi - oa) / da, n, albedo);
                } else {
                    n[axis] = 1.0;
                    consider((lo - oa) / da, n, albedo);
                }
            }
        }
        if d.z > 1e-15 {
            consider((self.ceiling - o.z) / d.z, -Vec3::z(), self.albedo[2]);
        } else if d.z < -1e-15 {
            consider((self.floor - o.z) / d.z, Vec3::z(), self.albedo[1]);
        }
        let limit = best.map_or(f64::INFINITY, |b| b.0);
        let mut nearest = limit;
        for (shape, albedo) in &self.objects {
            if let Some((t, n)) = shape.intersect(o, d, 1e-6, nearest) {
                nearest = t;
                let n = if n.dot(d) > 0.0 { -n } else { n };
                best = Some((t, n, *albedo));
            }
        }
        best
    }

    /// Whether something stands between `a` and `b`.
    fn blocked(&self, a: &Vec3, b: &Vec3) -> bool {
        let d = b - a;
        let len = d.norm();
        if len < 1e-9 {
            return false;
        }
        let d = d / len;
        self.objects
            .iter()
            .any(|(s, _)| s.intersect(a, &d, 1e-3, len - 1e-3).is_some())
    }
}

/// The camera image of `room` lit by the projector showing `picture` (8-bit, the projector's
/// size, row-major), and its truth. Pixels whose ray misses the camera's mirror are black.
pub fn render(
    sensor: &OmniSensor,
    room: &Room,
    picture: &[u8],
    exposure: &Exposure,
) -> Result<(GrayImage, OmniTruth)> {
    let (pw, ph) = (sensor.projector.lens.width, sensor.projector.lens.height);
    if picture.len() != (pw * ph) as usize {
        return Err(Error::invalid(
            "omni render",
            "picture",
            format!("{} pixels for a {pw}x{ph} projector", picture.len()),
        ));
    }
    let (w, h) = (sensor.camera.lens.width, sensor.camera.lens.height);
    let sample = |u: f64, v: f64| -> f64 {
        let (x0, y0) = (u.floor(), v.floor());
        let (ax, ay) = (u - x0, v - y0);
        let at = |x: f64, y: f64| {
            let (x, y) = (
                x.clamp(0.0, f64::from(pw - 1)),
                y.clamp(0.0, f64::from(ph - 1)),
            );
            f64::from(picture[y as usize * pw as usize + x as usize]) / 255.0
        };
        at(x0, y0) * (1.0 - ax) * (1.0 - ay)
            + at(x0 + 1.0, y0) * ax * (1.0 - ay)
            + at(x0, y0 + 1.0) * (1.0 - ax) * ay
            + at(x0 + 1.0, y0 + 1.0) * ax * ay
    };
    let rows: Vec<RowOut> = (0..h)
        .into_par_iter()
        .map(|v| {
            let mut row = (
                vec![0u8; w as usize],
                vec![[f32::NAN; 3]; w as usize],
                vec![false; w as usize],
                vec![[f32::NAN; 2]; w as usize],
            );
            for u in 0..w {
                let i = u as usize;
                let Some(ray) = sensor.camera.back_project(f64::from(u), f64::from(v)) else {
                    continue;
                };
                let Some((t, n, albedo)) = room.intersect(&ray.origin, &ray.direction) else {
                    continue;
                };
                let p = ray.origin + ray.direction * t;
                row.1[i] = [p.x as f32, p.y as f32, p.z as f32];
                let mut light = exposure.ambient;
                if let Some(((pu, pv), mirror)) = sensor.projector.project(&p) {
                    if !room.blocked(&p, &mirror) {
                        let to = (mirror - p).normalize();
                        light += sample(pu, pv) * n.dot(&to).max(0.0);
                        row.2[i] = true;
                        row.3[i] = [pu as f32, pv as f32];
                    }
                }
                let noise = exposure.noise
                    * gaussian(exposure.seed, u64::from(v) * u64::from(w) + u64::from(u));
                row.0[i] = (exposure.gain * albedo * light + noise)
                    .round()
                    .clamp(0.0, 255.0) as u8;
            }
            row
        })
        .collect();
    let mut image = Vec::with_capacity((w * h) as usize);
    let mut truth = OmniTruth {
        xyz: Vec::with_capacity((w * h) as usize),
        lit: Vec::with_capacity((w * h) as usize),
        projector: Vec::with_capacity((w * h) as usize),
    };
    for (px, xyz, lit, proj) in rows {
        image.extend(px);
        truth.xyz.extend(xyz);
        truth.lit.extend(lit);
        truth.projector.extend(proj);
    }
    Ok((GrayImage::from_u8(w, h, image), truth))
}

/// One rendered row: levels, points, lit flags, projector pixels.
type RowOut = (Vec<u8>, Vec<[f32; 3]>, Vec<bool>, Vec<[f32; 2]>);

/// A standard normal deviate from `seed` and `index` (two rounds of SplitMix64, Box–Muller).
pub(crate) fn gaussian(seed: u64, index: u64) -> f64 {
    let mix = |mut z: u64| {
        z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    };
    let a = mix(seed ^ index.wrapping_mul(0xD1B5_4A32_D192_ED03));
    let b = mix(a);
    let u1 = ((a >> 11) as f64 + 0.5) / (1u64 << 53) as f64;
    let u2 = (b >> 11) as f64 / (1u64 << 53) as f64;
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sensor() -> OmniSensor {
        OmniSensor::load(
            &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/omni/seed.toml"),
        )
        .expect("the seed's sensor")
    }

    fn room() -> Room {
        Room {
            half: [3000.0, 2500.0],
            center: [200.0, -300.0],
            floor: -1200.0,
            ceiling: 1300.0,
            albedo: [0.6, 0.4, 0.7],
            objects: vec![
                (
                    Shape::Box {
                        center: Vec3::new(1500.0, 800.0, -900.0),
                        half: Vec3::new(300.0, 300.0, 300.0),
                    },
                    0.5,
                ),
                (
                    Shape::Cylinder {
                        center: Vec3::new(-1200.0, -900.0, -300.0),
                        axis: Vec3::z(),
                        radius: 250.0,
                        half_height: 900.0,
                    },
                    0.5,
                ),
            ],
        }
    }

    #[test]
    fn each_pixel_sees_a_room_point_that_projects_back_to_it() {
        let s = sensor();
        let (pw, ph) = (s.projector.lens.width, s.projector.lens.height);
        let white = vec![255u8; (pw * ph) as usize];
        let (img, truth) = render(&s, &room(), &white, &Exposure::default()).expect("render");
        let (w, h) = (img.width as usize, img.height as usize);
        let mut seen = 0;
        let mut lit = 0;
        let (mut lit_sum, mut dark_sum) = (0.0, 0.0);
        for v in (0..h).step_by(7) {
            for u in (0..w).step_by(7) {
                let p = truth.xyz[v * w + u];
                if !p[0].is_finite() {
                    continue;
                }
                seen += 1;
                let x = Vec3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
                let ((pu, pv), _) = s.camera.project(&x).expect("seen");
                assert!(
                    (pu - u as f64).hypot(pv - v as f64) < 0.01,
                    "pixel ({u}, {v}) sees {x:?}, which projects to ({pu:.3}, {pv:.3})"
                );
                let level = f64::from(img.get(u as u32, v as u32));
                if truth.lit[v * w + u] {
                    lit += 1;
                    lit_sum += level;
                } else {
                    dark_sum += level;
                }
            }
        }
        // The mirror fills a disc: about π/4 · 480² / (640 · 480) of the image, less its centre.
        assert!(seen > 2000 && lit > seen / 2, "{seen} seen, {lit} lit");
        // Lit under white is far brighter than the ambient light of the shadows.
        let (lit_mean, dark_mean) = (lit_sum / lit as f64, dark_sum / (seen - lit).max(1) as f64);
        assert!(
            lit_mean > 4.0 * dark_mean,
            "lit {lit_mean:.1}, shadowed {dark_mean:.1}"
        );
    }

    #[test]
    fn what_stands_in_the_room_casts_shadows_and_the_picture_is_what_lights_it() {
        let s = sensor();
        let (pw, ph) = (s.projector.lens.width, s.projector.lens.height);
        let white = vec![255u8; (pw * ph) as usize];
        let black = vec![0u8; (pw * ph) as usize];
        let quiet = Exposure {
            noise: 0.0,
            ..Exposure::default()
        };
        let r = room();
        let (on, truth) = render(&s, &r, &white, &quiet).expect("white");
        let (off, _) = render(&s, &r, &black, &quiet).expect("black");
        let mut shadowed = 0;
        for (i, p) in truth.xyz.iter().enumerate() {
            if !p[0].is_finite() {
                continue;
            }
            let (x, y) = (
                (i % on.width as usize) as u32,
                (i / on.width as usize) as u32,
            );
            if truth.lit[i] {
                // Each lit pixel's light is the projector's: black leaves the ambient only.
                assert!(on.get(x, y) > off.get(x, y), "({x}, {y})");
            } else {
                // Shadowed (or beyond the projector's mirror): the same under both pictures.
                assert_eq!(on.get(x, y), off.get(x, y), "({x}, {y})");
                shadowed += 1;
            }
        }
        // The box and the cylinder shadow the walls behind them.
        assert!(shadowed > 100, "{shadowed} shadowed pixels");
        // A wrong-sized picture is refused.
        assert!(render(&s, &r, &white[1..], &quiet).is_err());
    }
}
