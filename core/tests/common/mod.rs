//! Helpers shared by the core tests: a seeded generator for families of cases.
#![allow(dead_code)] // each test binary uses part of it

/// A small seeded generator (64-bit LCG): the same seed gives the same case on every machine.
pub struct Rng(pub u64);

impl Rng {
    /// Uniform in (0, 1).
    pub fn uniform(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((self.0 >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    /// Uniform in (a, b).
    pub fn range(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * self.uniform()
    }
    /// Standard normal (Box–Muller).
    pub fn gauss(&mut self) -> f64 {
        (-2.0 * self.uniform().ln()).sqrt() * (std::f64::consts::TAU * self.uniform()).cos()
    }
}

/// Whether this run is the long tier (`.ci/run --long`, which sets `RIS_TIER=long`): whole
/// seeded families and surveys. The default tier runs the first cases of each family, so every
/// family is still exercised by `.ci/run`.
pub fn long_tier() -> bool {
    std::env::var("RIS_TIER").is_ok_and(|v| v == "long")
}

/// The demo scene's file up to its first object: the demo sensor's camera and projector (1600 mm
/// standoff, 500 mm baseline, 800x600 camera at about 0.9 mm/px) and its materials (`table`
/// textured), for scenes that place their own objects.
pub fn demo_optics() -> String {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/scenes/demo.toml");
    let demo = std::fs::read_to_string(&path).expect("demo scene");
    demo[..demo.find("[[object]]").expect("objects")].to_string()
}

/// `optics` (from [`demo_optics`]) without read or shot noise.
pub fn noiseless(optics: &str) -> String {
    assert!(optics.contains("noise = 1.5") && optics.contains("shot_noise = 0.05"));
    optics
        .replace("shot_noise = 0.05", "shot_noise = 0.0")
        .replace("noise = 1.5", "noise = 0.0")
}

/// Seeds `0..default` of a family, or `0..long` in the long tier.
pub fn seeds(default: u64, long: u64) -> std::ops::Range<u64> {
    0..if long_tier() { long } else { default }
}

/// `n` points in rows on the mock cell's panel (z = −(x²/5000 + y²/8000)) over the CAD's extent, with
/// 0.05 mm of noise, moved off the nominal pose by 0.3 mm and 0.02°.
pub fn panel_cloud(mesh: &ris_core::mesh::TriangleMesh, n: usize) -> Vec<[f64; 3]> {
    let (mut lo, mut hi) = ([f64::MAX; 2], [f64::MIN; 2]);
    for v in &mesh.vertices {
        for k in 0..2 {
            lo[k] = lo[k].min(v[k]);
            hi[k] = hi[k].max(v[k]);
        }
    }
    let mut rng = Rng(11u64);
    let mut u = move || rng.uniform();
    let off = ris_core::register::Pose::from_parts(
        nalgebra::Vector3::new(0.3, -0.2, 0.1).into(),
        nalgebra::UnitQuaternion::from_scaled_axis(nalgebra::Vector3::new(0.0002, -0.0003, 0.0001)),
    );
    // A raster like a camera's rows (merged clouds keep each sensor's scan order), jittered.
    let (w, h) = (hi[0] - lo[0] - 4.0, hi[1] - lo[1] - 4.0);
    let cols = ((n as f64 * w / h).sqrt().ceil() as usize).max(1);
    (0..n)
        .map(|k| {
            let (i, j) = (k % cols, k / cols);
            let rows = n.div_ceil(cols);
            let x = lo[0] + 2.0 + w * (i as f64 + u()) / cols as f64;
            let y = lo[1] + 2.0 + h * (j as f64 + u()) / rows as f64;
            // Sum of 4 uniforms: near-Gaussian, σ ≈ 0.05 mm.
            let noise = 0.05 * 1.732 * (u() + u() + u() + u() - 2.0);
            let z = -(x * x / 5000.0 + y * y / 8000.0) + noise;
            (off * nalgebra::Point3::new(x, y, z)).coords.into()
        })
        .collect()
}

/// RMS of `measured` − `truth` over the finite measured values (a deviation map against the
/// deviations planted), mm.
pub fn rms_against(measured: &[f64], truth: &[f64]) -> f64 {
    let (mut s, mut n) = (0.0, 0usize);
    for (d, t) in measured.iter().zip(truth) {
        if d.is_finite() {
            s += (d - t).powi(2);
            n += 1;
        }
    }
    (s / n.max(1) as f64).sqrt()
}
