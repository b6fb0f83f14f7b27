//! What the projector emits, as seen through its defocus: each projector pixel is a square of
//! constant light blurred by a Gaussian of σ = `blur`, integrated exactly per pixel.

use rayon::prelude::*;

use crate::pattern::ProjectionMask;

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
            .into_par_iter()
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
                // Pixel i's upper edge is pixel i + 1's lower edge (i + 0.5 and (i + 1) − 0.5
                // are the same float): one CDF evaluation per edge, not two.
                let mut lower = phi((lo as f32 - 0.5 - u) / sigma);
                let mut sum = 0.0;
                for (i, v) in vals.iter().enumerate().take(hi).skip(lo) {
                    let upper = phi((i as f32 + 0.5 - u) / sigma);
                    sum += v * (upper - lower);
                    lower = upper;
                }
                sum
            })
            .collect();
        Profile { start, values }
    }

    #[inline(always)]
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

/// Projector output of one pattern (values 0..1 relative to full white): a separable stripe
/// profile, optionally multiplied by a slowly varying projection mask (blurred, then sampled
/// bilinearly; the product of the blurs stands for the blur of the product, which holds where
/// the mask is smooth at the scale of the defocus).
#[derive(Clone, Debug)]
pub struct Light {
    u: Profile,
    v: Profile,
    mask: Option<std::sync::Arc<BlurredMask>>,
}

/// A projection mask blurred by the projector's defocus (σ in projector pixels): computed once
/// per mask and blur, then shared by every frame that shows the mask.
#[derive(Clone, Debug)]
pub struct BlurredMask {
    width: usize,
    height: usize,
    values: Vec<f32>,
}

impl BlurredMask {
    /// `mask` blurred by a Gaussian of σ = `sigma`, integrated per pixel; 0 beyond the edges.
    /// Separable, parallel over rows in both passes.
    pub fn new(mask: &ProjectionMask, sigma: f32) -> BlurredMask {
        let (w, h) = (mask.width as usize, mask.height as usize);
        let radius = (3.0 * sigma).ceil() as isize;
        let kernel: Vec<f32> = if sigma <= 1e-6 {
            vec![1.0]
        } else {
            (-radius..=radius)
                .map(|k| phi((k as f32 + 0.5) / sigma) - phi((k as f32 - 0.5) / sigma))
                .collect()
        };
        let r = (kernel.len() / 2) as isize;
        let mut tmp = vec![0.0; w * h];
        let mut out = vec![0.0; w * h];
        if w == 0 || h == 0 {
            return BlurredMask {
                width: w,
                height: h,
                values: out,
            };
        }
        // Along each row.
        tmp.par_chunks_mut(w)
            .zip(mask.values.par_chunks(w))
            .for_each(|(dst, src)| {
                for (i, d) in dst.iter_mut().enumerate() {
                    let mut acc = 0.0;
                    for (k, kv) in kernel.iter().enumerate() {
                        let j = i as isize + k as isize - r;
                        if j >= 0 && (j as usize) < w {
                            acc += kv * src[j as usize];
                        }
                    }
                    *d = acc;
                }
            });
        // Along each column, a whole output row at a time (the taps in the same order).
        out.par_chunks_mut(w).enumerate().for_each(|(y, dst)| {
            for (k, kv) in kernel.iter().enumerate() {
                let j = y as isize + k as isize - r;
                if j >= 0 && (j as usize) < h {
                    let src = &tmp[j as usize * w..(j as usize + 1) * w];
                    for (d, s) in dst.iter_mut().zip(src) {
                        *d += kv * s;
                    }
                }
            }
        });
        BlurredMask {
            width: w,
            height: h,
            values: out,
        }
    }

    #[inline]
    fn sample(&self, u: f32, v: f32) -> f32 {
        let x = u.clamp(0.0, (self.width - 1) as f32);
        let y = v.clamp(0.0, (self.height - 1) as f32);
        let (x0, y0) = (x as usize, y as usize);
        let (x1, y1) = ((x0 + 1).min(self.width - 1), (y0 + 1).min(self.height - 1));
        let (fx, fy) = (x - x0 as f32, y - y0 as f32);
        let at = |xx: usize, yy: usize| self.values[yy * self.width + xx];
        (at(x0, y0) * (1.0 - fx) + at(x1, y0) * fx) * (1.0 - fy)
            + (at(x0, y1) * (1.0 - fx) + at(x1, y1) * fx) * fy
    }
}

impl Light {
    /// A uniform level over the whole projector.
    pub fn uniform(width: u32, height: u32, level: f32, blur: f32) -> Light {
        Light {
            u: Profile::new(&vec![level; width as usize], blur),
            v: Profile::new(&vec![1.0; height as usize], blur),
            mask: None,
        }
    }

    /// Vertical stripes: one value per projector column.
    pub fn columns(cols: &[f32], height: u32, blur: f32) -> Light {
        Light {
            u: Profile::new(cols, blur),
            v: Profile::new(&vec![1.0; height as usize], blur),
            mask: None,
        }
    }

    /// Horizontal stripes: one value per projector row.
    pub fn rows(width: u32, rows: &[f32], blur: f32) -> Light {
        Light {
            u: Profile::new(&vec![1.0; width as usize], blur),
            v: Profile::new(rows, blur),
            mask: None,
        }
    }

    /// This light multiplied by a projection mask, blurred by `blur` pixels.
    pub fn masked(self, mask: &ProjectionMask, blur: f32) -> Light {
        self.with_mask(std::sync::Arc::new(BlurredMask::new(mask, blur)))
    }

    /// This light multiplied by an already blurred projection mask.
    pub fn with_mask(mut self, mask: std::sync::Arc<BlurredMask>) -> Light {
        self.mask = Some(mask);
        self
    }

    /// Light at projector coordinate (u, v).
    #[inline(always)]
    pub fn sample(&self, u: f32, v: f32) -> f32 {
        let stripes = self.u.sample(u) * self.v.sample(v);
        match &self.mask {
            None => stripes,
            Some(m) => stripes * m.sample(u, v),
        }
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

    #[test]
    fn mask_scales_the_light_where_it_is_smooth() {
        let mut cols = vec![0.0f32; 40];
        cols[20..].fill(1.0);
        let plain = Light::columns(&cols, 30, 0.6);
        let mut mask = ProjectionMask::uniform(40, 30, 1.0);
        for v in &mut mask.values[15 * 40..] {
            *v = 0.25;
        }
        let masked = Light::columns(&cols, 30, 0.6).masked(&mask, 0.6);
        for u in [5.0, 19.2, 19.5, 25.0] {
            assert!((masked.sample(u, 5.0) - plain.sample(u, 5.0)).abs() < 1e-4);
            assert!((masked.sample(u, 25.0) - 0.25 * plain.sample(u, 25.0)).abs() < 1e-4);
        }
        let edge = masked.sample(30.0, 14.5);
        assert!(edge > 0.25 && edge < 1.0, "blurred mask edge {edge}");
    }
}
