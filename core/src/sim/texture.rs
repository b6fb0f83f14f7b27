//! Procedural albedo textures (smooth value noise, checkers) so that decoding is tested on
//! surfaces whose reflectance changes from pixel to pixel.

use std::sync::Arc;

use crate::geometry::Vec3;
use crate::spatial::KdTree;

/// An albedo modulation `1 + amplitude × n(p)`, n in [−1, 1].
#[derive(Clone, Debug, PartialEq)]
pub enum Texture {
    /// Uniform albedo.
    None,
    /// Smooth 3D value noise with the given period (mm).
    Noise {
        /// Relative amplitude.
        amplitude: f64,
        /// Period, mm.
        period: f64,
    },
    /// 3D checkerboard with the given period (mm).
    Checker {
        /// Relative amplitude.
        amplitude: f64,
        /// Period, mm.
        period: f64,
    },
    /// A calibration chessboard in the x–y plane: `cols × rows` inner corners centred on the
    /// origin (SPEC §7 board frame), dark squares at `dark` times the albedo, light outside.
    Chessboard {
        /// Inner corners along x.
        cols: usize,
        /// Inner corners along y.
        rows: usize,
        /// Square size, mm.
        square: f64,
        /// Albedo factor of the dark squares.
        dark: f64,
    },
}

impl Texture {
    /// From the scene file's `texture`, `texture_amplitude`, `texture_period`.
    pub fn parse(kind: Option<&str>, amplitude: f64, period: f64) -> Result<Texture, String> {
        if !(period.is_finite() && period > 0.0) {
            return Err(format!("texture_period {period} must be positive"));
        }
        Ok(match kind {
            None | Some("none") => Texture::None,
            Some("noise") => Texture::Noise { amplitude, period },
            Some("checker") => Texture::Checker { amplitude, period },
            Some(other) => return Err(format!("unknown texture `{other}` (none, noise, checker)")),
        })
    }

    /// Albedo factor at `p`.
    pub fn factor(&self, p: &Vec3) -> f64 {
        match *self {
            Texture::None => 1.0,
            Texture::Noise { amplitude, period } => 1.0 + amplitude * value_noise(p / period),
            Texture::Checker { amplitude, period } => {
                let s = (p.x / period).floor() + (p.y / period).floor() + (p.z / period).floor();
                1.0 + amplitude * if s.rem_euclid(2.0) < 1.0 { 1.0 } else { -1.0 }
            }
            Texture::Chessboard {
                cols,
                rows,
                square,
                dark,
            } => {
                let a = (p.x / square + (cols as f64 + 1.0) / 2.0).floor();
                let b = (p.y / square + (rows as f64 + 1.0) / 2.0).floor();
                let inside = a >= 0.0 && b >= 0.0 && a <= cols as f64 && b <= rows as f64;
                if inside && (a + b).rem_euclid(2.0) < 1.0 {
                    dark
                } else {
                    1.0
                }
            }
        }
    }
}

fn hash(i: i64, j: i64, k: i64) -> f64 {
    let mut h = (i.wrapping_mul(73_856_093)
        ^ j.wrapping_mul(19_349_663)
        ^ k.wrapping_mul(83_492_791)) as u64;
    h ^= h >> 33;
    h = h.wrapping_mul(0xff51_afd7_ed55_8ccd);
    h ^= h >> 33;
    h = h.wrapping_mul(0xc4ce_b9fe_1a85_ec53);
    h ^= h >> 33;
    (h >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
}

/// Trilinear value noise with smoothstep weights, in [−1, 1].
fn value_noise(p: Vec3) -> f64 {
    let (fx, fy, fz) = (p.x.floor(), p.y.floor(), p.z.floor());
    let (i, j, k) = (fx as i64, fy as i64, fz as i64);
    let s = |t: f64| t * t * (3.0 - 2.0 * t);
    let (u, v, w) = (s(p.x - fx), s(p.y - fy), s(p.z - fz));
    let lerp = |a: f64, b: f64, t: f64| a + (b - a) * t;
    let c = |a, b, c| hash(i + a, j + b, k + c);
    lerp(
        lerp(
            lerp(c(0, 0, 0), c(1, 0, 0), u),
            lerp(c(0, 1, 0), c(1, 1, 0), u),
            v,
        ),
        lerp(
            lerp(c(0, 0, 1), c(1, 0, 1), u),
            lerp(c(0, 1, 1), c(1, 1, 1), u),
            v,
        ),
        w,
    )
}

/// Circular markers painted on an object (a marker gauge): points within `radius` of a centre
/// take the marker's albedo instead of the material's.
#[derive(Clone, Debug)]
pub struct MarkerPaint {
    centers: Arc<KdTree>,
    radius2: f64,
    /// Albedo of the markers.
    pub albedo: f64,
}

impl MarkerPaint {
    /// Markers of `radius` at `centers` (scene world frame).
    pub fn new(centers: &[Vec3], radius: f64, albedo: f64) -> MarkerPaint {
        let pts: Vec<[f64; 3]> = centers.iter().map(|c| [c.x, c.y, c.z]).collect();
        MarkerPaint {
            centers: Arc::new(KdTree::new(&pts)),
            radius2: radius * radius,
            albedo,
        }
    }

    /// Whether `p` lies on a marker.
    pub fn covers(&self, p: &Vec3) -> bool {
        self.centers
            .nearest(&[p.x, p.y, p.z])
            .is_some_and(|(_, d2)| d2 <= self.radius2)
    }
}
