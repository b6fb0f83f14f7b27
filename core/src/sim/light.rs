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
    ///
    /// The pixels are a staircase: a step of `vals[j] − vals[j − 1]` at each edge `j − 0.5`
    /// (0 outside the projector), so the blurred value at `u` is the value just left of the
    /// window of ±(4σ + 1) plus each step inside it times Φ((u − edge) / σ). Only edges where
    /// the value changes cost a Gaussian CDF: two for a uniform level, one per stripe edge
    /// for a pattern, however wide the blur.
    fn new(vals: &[f32], sigma: f32) -> Profile {
        let margin = 4.0 * sigma + 2.0;
        let start = -0.5 - margin;
        let end = vals.len() as f32 - 0.5 + margin;
        let n = ((end - start) * RES).ceil() as usize + 1;
        let at = |j: usize| if j < vals.len() { vals[j] } else { 0.0 };
        // (edge index j, step) where pixel j − 1 and pixel j differ.
        let steps: Vec<(usize, f32)> = (0..=vals.len())
            .filter_map(|j| {
                let below = if j == 0 { 0.0 } else { vals[j - 1] };
                (at(j) != below).then(|| (j, at(j) - below))
            })
            .collect();
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
                let hi = ((u + 4.0 * sigma + 1.0).ceil().max(0.0) as usize).min(vals.len() + 1);
                let mut sum = if lo == 0 { 0.0 } else { at(lo - 1) };
                let first = steps.partition_point(|&(j, _)| j < lo);
                for &(j, step) in steps[first..].iter().take_while(|&&(j, _)| j < hi) {
                    sum += step * phi((u - (j as f32 - 0.5)) / sigma);
                }
                sum
            })
            .collect();
        Profile { start, values }
    }

    /// Where `u` falls on the profile's grid: the grid point below it and the fraction towards
    /// the next; `None` outside the profile (where the light is 0).
    #[inline(always)]
    fn locate(&self, u: f32) -> Option<(u32, f32)> {
        let x = (u - self.start) * RES;
        if x < 0.0 {
            return None;
        }
        let i = x as usize;
        if i + 1 >= self.values.len() {
            return None;
        }
        Some((i as u32, x - i as f32))
    }

    /// The profile between grid points `i` and `i + 1`, a fraction `f` of the way.
    #[inline(always)]
    fn at(&self, i: u32, f: f32) -> f32 {
        let i = i as usize;
        self.values[i] * (1.0 - f) + self.values[i + 1] * f
    }

    #[inline(always)]
    fn sample(&self, u: f32) -> f32 {
        self.locate(u).map_or(0.0, |(i, f)| self.at(i, f))
    }
}

/// The sampling grid of a light's two profiles (start and length of each). It depends on the
/// blur and the projector's size only, so every pattern of a scan shares it and a point's
/// place on it ([`Tap`]) can be found once and reused for every frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Grid {
    u: (f32, usize),
    v: (f32, usize),
}

/// A projector point's place on a [`Grid`]: grid points and fractions along u and v.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Tap {
    iu: u32,
    fu: f32,
    iv: u32,
    fv: f32,
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

    /// The blurred mask at projector coordinate (u, v), bilinear, clamped to the edges.
    #[inline]
    pub(crate) fn sample(&self, u: f32, v: f32) -> f32 {
        self.at(&self.locate(u, v))
    }

    /// The mask's size (every blur of one mask has it, so a point located on one is located
    /// on all).
    pub(crate) fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    /// Where (u, v) falls on the mask's pixels.
    #[inline(always)]
    pub(crate) fn locate(&self, u: f32, v: f32) -> MaskTap {
        MaskTap::locate(self.size(), u, v)
    }

    /// The mask, bilinear, at a located point (of a mask of the same size).
    #[inline(always)]
    pub(crate) fn at(&self, t: &MaskTap) -> f32 {
        let i = t.index as usize;
        let (r, d) = (t.right as usize, t.down as usize);
        let v = &self.values;
        (v[i] * (1.0 - t.fx) + v[i + r] * t.fx) * (1.0 - t.fy)
            + (v[i + d] * (1.0 - t.fx) + v[i + d + r] * t.fx) * t.fy
    }
}

/// A projector point's place on a mask's pixels: the pixel at or below it, the steps to the
/// next pixel right and down (0 on the last column or row), and the fractions.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct MaskTap {
    index: u32,
    right: u32,
    down: u32,
    fx: f32,
    fy: f32,
}

impl MaskTap {
    /// Where (u, v) falls on the pixels of a mask of `(width, height)`, clamped to the edges.
    #[inline(always)]
    pub(crate) fn locate((width, height): (usize, usize), u: f32, v: f32) -> MaskTap {
        let x = u.clamp(0.0, (width - 1) as f32);
        let y = v.clamp(0.0, (height - 1) as f32);
        let (x0, y0) = (x as usize, y as usize);
        let (x1, y1) = ((x0 + 1).min(width - 1), (y0 + 1).min(height - 1));
        MaskTap {
            index: (y0 * width + x0) as u32,
            right: (x1 - x0) as u32,
            down: ((y1 - y0) * width) as u32,
            fx: x - x0 as f32,
            fy: y - y0 as f32,
        }
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

    /// The grid of this light's profiles.
    pub(crate) fn grid(&self) -> Grid {
        Grid {
            u: (self.u.start, self.u.values.len()),
            v: (self.v.start, self.v.values.len()),
        }
    }

    /// Where (u, v) falls on this light's grid; `None` where the light is 0 (outside it).
    #[inline(always)]
    pub(crate) fn locate(&self, u: f32, v: f32) -> Option<Tap> {
        let (iu, fu) = self.u.locate(u)?;
        let (iv, fv) = self.v.locate(v)?;
        Some(Tap { iu, fu, iv, fv })
    }

    /// The stripes' light at a located point (any light on the same grid), the same value as
    /// [`Light::sample`] gives there without a mask.
    #[inline(always)]
    pub(crate) fn stripes_at(&self, t: &Tap) -> f32 {
        self.u.at(t.iu, t.fu) * self.v.at(t.iv, t.fv)
    }

    /// The blurred projection mask this light shows, if any.
    pub(crate) fn mask(&self) -> Option<&BlurredMask> {
        self.mask.as_deref()
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

    /// The blurred profile against the integral of each pixel's square under the Gaussian,
    /// in f64 over every pixel, at the profile's grid points: stripes of 1 to 64 pixels, random levels and a uniform level,
    /// blurs from a tenth of a pixel to tens of pixels (the inter-reflection channels').
    #[test]
    fn profiles_match_the_exact_integral_for_any_pattern_and_blur() {
        use rand::{Rng, SeedableRng};
        let exact = |vals: &[f32], sigma: f64, u: f64| -> f64 {
            let cdf = |x: f64| 0.5 * (1.0 + erf_series(x / (sigma * std::f64::consts::SQRT_2)));
            vals.iter()
                .enumerate()
                .map(|(i, &v)| f64::from(v) * (cdf(i as f64 + 0.5 - u) - cdf(i as f64 - 0.5 - u)))
                .sum()
        };
        let mut rng = rand::rngs::SmallRng::seed_from_u64(7);
        let n = 300;
        let mut patterns: Vec<Vec<f32>> = [1, 2, 5, 64]
            .iter()
            .map(|&w| (0..n).map(|i| ((i / w) % 2) as f32).collect())
            .collect();
        patterns.push((0..n).map(|_| rng.random_range(0.0..1.0)).collect());
        patterns.push(vec![0.7; n]);
        for vals in &patterns {
            for sigma in [0.1f32, 0.6, 3.0, 25.0] {
                let p = Profile::new(vals, sigma);
                // At the profile's own grid points (between them it interpolates linearly).
                for k in (0..p.values.len()).step_by(7) {
                    let u = p.start + k as f32 / RES;
                    let want = exact(vals, f64::from(sigma), f64::from(u));
                    // the window of ±(4σ + 1) leaves out at most Φ(−4) of each side
                    assert!(
                        (f64::from(p.values[k]) - want).abs() < 1e-4,
                        "sigma {sigma} at {u}: {} against {want}",
                        p.values[k]
                    );
                }
            }
        }
    }

    /// erf by its series and continued fraction (f64), independent of [`phi`].
    fn erf_series(x: f64) -> f64 {
        let a = x.abs();
        let e = if a < 2.5 {
            let mut term = a;
            let mut sum = a;
            for k in 1..60 {
                term *= -a * a / k as f64;
                sum += term / (2 * k + 1) as f64;
            }
            sum * 2.0 / std::f64::consts::PI.sqrt()
        } else {
            // erfc by Lentz's continued fraction.
            let mut f = a;
            for k in (1..60).rev() {
                f = a + (k as f64 / 2.0) / f;
            }
            1.0 - (-a * a).exp() / (f * std::f64::consts::PI.sqrt())
        };
        e.copysign(x)
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
