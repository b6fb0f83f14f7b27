//! What the projector emits, as seen through its defocus: each projector pixel is a square of
//! constant light blurred by a Gaussian of σ = `blur`, integrated exactly per pixel.

/// Samples of a 1-D blurred profile per projector pixel.
const RES: f32 = 16.0;

/// A blurred 1-D profile over projector coordinate, 0 outside the projector.
#[derive(Clone, Debug)]
struct Profile {
    start: f32,
    values: Vec<f32>,
}

impl Profile {
    /// Profile of pixel values `vals` (0..1) blurred by `sigma` pixels.
    fn new(vals: &[f32], sigma: f32) -> Profile {
        let margin = 4.0 * sigma + 2.0;
        let start = -0.5 - margin;
        let end = vals.len() as f32 - 0.5 + margin;
        let n = ((end - start) * RES).ceil() as usize + 1;
        let values = (0..n)
            .map(|k| {
                let u = start + k as f32 / RES;
                if sigma <= 1e-6 {
                    let i = (u + 0.5).floor();
                    return if i >= 0.0 && (i as usize) < vals.len() {
                        vals[i as usize]
                    } else {
                        0.0
                    };
                }
                let lo = ((u - 4.0 * sigma - 1.0).floor().max(0.0)) as usize;
                let hi = ((u + 4.0 * sigma + 1.0).ceil().max(0.0) as usize).min(vals.len());
                (lo..hi)
                    .map(|i| {
                        vals[i]
                            * (phi((i as f32 + 0.5 - u) / sigma)
                                - phi((i as f32 - 0.5 - u) / sigma))
                    })
                    .sum()
            })
            .collect();
        Profile { start, values }
    }

    #[inline]
    fn sample(&self, u: f32) -> f32 {
        let x = (u - self.start) * RES;
        if x < 0.0 {
            return 0.0;
        }
        let i = x as usize;
        if i + 1 >= self.values.len() {
            return 0.0;
        }
        let f = x - i as f32;
        self.values[i] * (1.0 - f) + self.values[i + 1] * f
    }
}

/// Standard normal CDF via erf (Abramowitz–Stegun 7.1.26, |error| < 1.5e-7).
fn phi(x: f32) -> f32 {
    let z = f64::from(x) / std::f64::consts::SQRT_2;
    let t = 1.0 / (1.0 + 0.327_591_1 * z.abs());
    let y = 1.0
        - (((((1.061_405_429 * t - 1.453_152_027) * t) + 1.421_413_741) * t - 0.284_496_736) * t
            + 0.254_829_592)
            * t
            * (-z * z).exp();
    let erf = if z >= 0.0 { y } else { -y };
    (0.5 * (1.0 + erf)) as f32
}

/// Projector output of one pattern (values 0..1 relative to full white).
#[derive(Clone, Debug)]
pub struct Light {
    u: Profile,
    v: Profile,
}

impl Light {
    /// A uniform level over the whole projector.
    pub fn uniform(width: u32, height: u32, level: f32, blur: f32) -> Light {
        Light {
            u: Profile::new(&vec![level; width as usize], blur),
            v: Profile::new(&vec![1.0; height as usize], blur),
        }
    }

    /// Vertical stripes: one value per projector column.
    pub fn columns(cols: &[f32], height: u32, blur: f32) -> Light {
        Light {
            u: Profile::new(cols, blur),
            v: Profile::new(&vec![1.0; height as usize], blur),
        }
    }

    /// Horizontal stripes: one value per projector row.
    pub fn rows(width: u32, rows: &[f32], blur: f32) -> Light {
        Light {
            u: Profile::new(&vec![1.0; width as usize], blur),
            v: Profile::new(rows, blur),
        }
    }

    /// Light at projector coordinate (u, v).
    #[inline]
    pub fn sample(&self, u: f32, v: f32) -> f32 {
        self.u.sample(u) * self.v.sample(v)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blurred_edge_is_half_at_the_boundary_and_area_preserving() {
        let mut cols = vec![0.0f32; 20];
        cols[10..].fill(1.0);
        let l = Light::columns(&cols, 10, 0.6);
        assert!((l.sample(9.5, 5.0) - 0.5).abs() < 1e-3);
        assert!(l.sample(7.0, 5.0) < 1e-3 && (l.sample(13.0, 5.0) - 1.0).abs() < 1e-3);
        assert!(
            (l.sample(9.0, 5.0) + l.sample(10.0, 5.0) - 1.0).abs() < 1e-3,
            "antisymmetric about the edge"
        );
        assert_eq!(l.sample(25.0, 5.0), 0.0, "dark outside the projector");
    }
}
