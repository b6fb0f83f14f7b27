//! Seeded artefact clouds with known truth, made as a sensor above the volume sees them (front
//! faces towards the camera, a shadowed side away from the projector, the post, the table and
//! clutter): the unit tests' families, the CLI test's acceptance set and the benchmark.

use rand::rngs::SmallRng;
use rand::{Rng as _, SeedableRng};
use rand_distr::{Distribution, StandardNormal};

use super::{
    fit, Artefacts, BallBar, MeasuredCloud, Mpe, PlaneArtefact, SpacingMpe, SphereArtefact, System,
    Volume,
};
use crate::geometry::Vec3;

/// A seeded source of the clouds' randomness.
pub struct Noise(SmallRng);

impl Noise {
    /// The generator of `seed`.
    pub fn new(seed: u64) -> Noise {
        Noise(SmallRng::seed_from_u64(seed))
    }
    /// Uniform in [a, b).
    pub fn range(&mut self, a: f64, b: f64) -> f64 {
        self.0.random_range(a..b)
    }
    /// Standard normal.
    pub fn gauss(&mut self) -> f64 {
        StandardNormal.sample(&mut self.0)
    }
}

/// Where the sensor's camera is, mm.
pub const CAMERA: [f64; 3] = [0.0, 0.0, 1600.0];
/// Where the sensor's projector is, mm.
pub const PROJECTOR: [f64; 3] = [350.0, 0.0, 1600.0];

/// The calibrated volume of the examples: 600 x 500 x 300 mm about the origin.
pub fn volume() -> Volume {
    Volume {
        min: [-300.0, -250.0, -150.0],
        max: [300.0, 250.0, 150.0],
    }
}

/// The example artefacts: a 400 mm bar of 30 mm spheres, a 40 mm sphere, a 300 x 60 mm flat.
pub fn artefacts() -> Artefacts {
    Artefacts {
        system: System {
            name: "test cell".into(),
            calibration: "seeded truth".into(),
        },
        ball_bar: Some(BallBar {
            diameter_a: 30.0,
            diameter_b: 30.0,
            spacing: 400.0,
        }),
        sphere: Some(SphereArtefact {
            diameter: 40.0,
            form: 0.0,
        }),
        plane: Some(PlaneArtefact {
            length: 300.0,
            width: 60.0,
            flatness: 0.0,
        }),
        mpe: Mpe {
            probing_form: 0.1,
            probing_size: 0.05,
            sphere_spacing: SpacingMpe::LengthDependent { a: 0.05, b: 5000.0 },
            flatness: 0.1,
        },
        volume: Some(volume()),
    }
}

/// Whether the camera and the projector both see surface point `p` with outward normal `n`.
pub fn lit_and_seen(p: &Vec3, n: &Vec3) -> bool {
    (Vec3::from(CAMERA) - p).dot(n) > 0.05 * (Vec3::from(CAMERA) - p).norm()
        && (Vec3::from(PROJECTOR) - p).dot(n) > 0.05 * (Vec3::from(PROJECTOR) - p).norm()
}

/// Points of a sphere as the sensor sees it (its lower part hidden by the post), about
/// `spacing` mm apart, each off the surface along its normal by Gaussian noise `sigma`.
/// Returns the points and each one's true radial offset.
pub fn sphere_points(
    rng: &mut Noise,
    c: Vec3,
    r: f64,
    spacing: f64,
    sigma: f64,
    keep: impl Fn(&Vec3) -> bool,
) -> (Vec<Vec3>, Vec<f64>) {
    let n = (4.0 * std::f64::consts::PI * r * r / (spacing * spacing)) as usize;
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let (mut pts, mut off) = (Vec::new(), Vec::new());
    for i in 0..n {
        let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
        let s = (1.0 - z * z).sqrt();
        let phi = golden * i as f64;
        let u = Vec3::new(s * phi.cos(), s * phi.sin(), z);
        let p = c + u * r;
        if z < -0.3 || !lit_and_seen(&p, &u) || !keep(&u) {
            continue;
        }
        let e = sigma * rng.gauss();
        pts.push(c + u * (r + e));
        off.push(e);
    }
    (pts, off)
}

/// The table under an artefact: z = `z`, a square of half side `half` about (x, y).
pub fn table(
    rng: &mut Noise,
    x: f64,
    y: f64,
    z: f64,
    half: f64,
    spacing: f64,
    sigma: f64,
) -> Vec<Vec3> {
    let n = (2.0 * half / spacing) as i64;
    let mut out = Vec::new();
    for i in 0..n {
        for j in 0..n {
            let p = Vec3::new(
                x - half + (i as f64 + 0.5) * spacing,
                y - half + (j as f64 + 0.5) * spacing,
                z + sigma * rng.gauss(),
            );
            out.push(p);
        }
    }
    out
}

/// A sphere on a post over the table, with a box of clutter beside it.
pub fn sphere_on_post(rng: &mut Noise, c: Vec3, r: f64, sigma: f64) -> (Vec<Vec3>, Vec<f64>) {
    let spacing = 0.5;
    let (mut pts, off) = sphere_points(rng, c, r, spacing, sigma, |_| true);
    let table_z = c.z - r - 60.0;
    // The post: a vertical cylinder of radius 0.3 r from the table to the sphere.
    let rp = 0.3 * r;
    let top = c.z - (r * r - rp * rp).sqrt();
    let mut h = table_z;
    while h < top {
        let mut a = 0.0;
        while a < std::f64::consts::TAU {
            let n = Vec3::new(a.cos(), a.sin(), 0.0);
            let p = Vec3::new(c.x, c.y, h) + n * rp;
            if lit_and_seen(&p, &n) {
                pts.push(p + n * sigma * rng.gauss());
            }
            a += spacing / rp;
        }
        h += spacing;
    }
    for p in table(rng, c.x, c.y, table_z, 2.5 * r, 1.0, sigma) {
        // The sphere's shadow and its post's footprint are missing from the table.
        if ((p.x - c.x).powi(2) + (p.y - c.y).powi(2)).sqrt() > 1.1 * r {
            pts.push(p);
        }
    }
    // Clutter: the top of a block beside the sphere.
    for p in table(rng, c.x + 1.8 * r, c.y, table_z + 25.0, 0.4 * r, 0.7, sigma) {
        pts.push(p);
    }
    (pts, off)
}

/// Range of the true offsets after the guideline's left-out share (the largest |offset|).
pub fn truth_range(off: &[f64]) -> f64 {
    let mut v: Vec<f64> = off.to_vec();
    v.sort_by(|a, b| a.abs().total_cmp(&b.abs()));
    v.truncate(v.len() - fit::allowed_left_out(v.len()));
    fit::range(v.into_iter())
}

/// A ball bar between two spheres (no rod modelled) with tables under each sphere.
pub fn bar_cloud(rng: &mut Noise, a: Vec3, b: Vec3, r: f64, sigma: f64, scale: f64) -> Vec<Vec3> {
    let (mut pts, _) = sphere_on_post(rng, a, r, sigma);
    pts.extend(sphere_on_post(rng, b, r, sigma).0);
    let mid = 0.5 * (a + b);
    pts.iter().map(|p| mid + (p - mid) * scale).collect()
}

/// Seven bar positions: the four space diagonals and three face diagonals, 400 mm long,
/// centred at `centre`.
pub fn bar_positions(centre: Vec3) -> Vec<(Vec3, Vec3)> {
    let e = Vec3::new(600.0, 500.0, 300.0);
    let mut dirs: Vec<Vec3> = [(1.0, 1.0), (-1.0, 1.0), (-1.0, -1.0), (1.0, -1.0)]
        .iter()
        .map(|(sx, sy)| Vec3::new(sx * e.x, sy * e.y, e.z).normalize())
        .collect();
    dirs.push(Vec3::new(e.x, e.y, 0.0).normalize());
    dirs.push(Vec3::new(e.x, 0.0, e.z).normalize());
    dirs.push(Vec3::new(0.0, e.y, e.z).normalize());
    dirs.iter()
        .map(|d| (centre - d * 200.0, centre + d * 200.0))
        .collect()
}

/// A flat of `length` x `width` on a table, tilted by `tilt` about x, with a bowl-shaped warp
/// of `sag` mm at its centre; `keep` selects the seen part of its face (u, v in 0 … 1).
#[allow(clippy::too_many_arguments)]
pub fn flat_cloud(
    rng: &mut Noise,
    centre: Vec3,
    yaw: f64,
    tilt: f64,
    sag: f64,
    sigma: f64,
    keep: impl Fn(f64, f64) -> bool,
) -> (Vec<Vec3>, Vec<f64>) {
    let (l, w) = (300.0, 60.0);
    let rot = crate::geometry::rotation_xyz_deg([tilt, 0.0, yaw]);
    let (u, v, n) = (rot * Vec3::x(), rot * Vec3::y(), rot * Vec3::z());
    let (mut pts, mut off) = (Vec::new(), Vec::new());
    let s = 0.7;
    let (nu, nv) = ((l / s) as i64, (w / s) as i64);
    for i in 0..nu {
        for j in 0..nv {
            let (a, b) = ((i as f64 + 0.5) / nu as f64, (j as f64 + 0.5) / nv as f64);
            if !keep(a, b) {
                continue;
            }
            let (x, y) = ((a - 0.5) * l, (b - 0.5) * w);
            let warp = sag * (1.0 - (2.0 * x / l).powi(2)) * (1.0 - (2.0 * y / w).powi(2));
            let e = sigma * rng.gauss();
            pts.push(centre + u * x + v * y + n * (warp + e));
            off.push(warp + e);
        }
    }
    // The table 40 mm under the flat's centre, wider than the flat.
    for p in table(rng, centre.x, centre.y, centre.z - 40.0, 220.0, 2.0, sigma) {
        pts.push(p);
    }
    (pts, off)
}

/// The flat's six positions (yaw, tilt in degrees) of the acceptance set.
pub const FLAT_POSES: [(f64, f64); 6] = [
    (0.0, 0.0),
    (30.0, 0.0),
    (90.0, 20.0),
    (-40.0, 35.0),
    (140.0, -25.0),
    (60.0, 45.0),
];

/// A whole acceptance set in `volume()`: the bar in 7 positions (the four space diagonals and
/// three face diagonals), the flat in 6 positions and orientations, the sphere in 10 positions
/// spread over the volume; `scale` multiplies every cloud about its artefact (1 = the truth).
pub fn acceptance_set(
    seed: u64,
    sigma: f64,
    scale: f64,
) -> (Vec<MeasuredCloud>, Vec<MeasuredCloud>, Vec<MeasuredCloud>) {
    let mut rng = Noise::new(seed);
    let named = |kind: &str, i: usize, points: Vec<Vec3>| MeasuredCloud {
        name: format!("{kind}-{}.ply", i + 1),
        points,
    };
    let bars = bar_positions(Vec3::new(0.0, 0.0, 0.0))
        .into_iter()
        .enumerate()
        .map(|(i, (a, b))| named("bar", i, bar_cloud(&mut rng, a, b, 15.0, sigma, scale)))
        .collect();
    let planes = FLAT_POSES
        .iter()
        .enumerate()
        .map(|(i, (yaw, tilt))| {
            let c = Vec3::new(
                rng.range(-100.0, 100.0),
                rng.range(-80.0, 80.0),
                rng.range(-60.0, 60.0),
            );
            let (pts, _) = flat_cloud(&mut rng, c, *yaw, *tilt, 0.0, sigma, |_, _| true);
            named("flat", i, pts.iter().map(|p| c + (p - c) * scale).collect())
        })
        .collect();
    let v = volume();
    let spheres = (0..10)
        .map(|i| {
            // Alternate halves of the volume along every axis.
            let mut side = |k: usize, bit: usize| {
                let t = if (i >> bit) & 1 == 0 {
                    rng.range(0.15, 0.45)
                } else {
                    rng.range(0.55, 0.85)
                };
                v.min[k] + t * (v.max[k] - v.min[k])
            };
            let c = Vec3::new(side(0, 0), side(1, 1), side(2, 2));
            let (pts, _) = sphere_on_post(&mut rng, c, 20.0, sigma);
            named(
                "sphere",
                i,
                pts.iter().map(|p| c + (p - c) * scale).collect(),
            )
        })
        .collect();
    (bars, planes, spheres)
}
