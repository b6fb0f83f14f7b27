//! Finding X-points in a camera image (Ch. 4.2.3): each primitive's corner is a saddle of the
//! intensity (bright along its long axis, dark across it), found where the Hessian's
//! determinant is strongly negative relative to the local contrast, and refined to a fraction
//! of a pixel by fitting a quadratic to the smoothed image about it. Its long axis comes from
//! the second moments of the light around the corner (Eq. 4.4–4.5). Nothing depends on colour
//! or on a global threshold: a near-infrared camera, dark or bright parts and uneven light are
//! the same case.

use rayon::prelude::*;

use crate::image::gaussian_blur;

/// One X-point seen by the camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Detection {
    /// Sub-pixel corner, camera pixels (SPEC §2 convention).
    pub x: f64,
    /// Sub-pixel corner row.
    pub y: f64,
    /// Long axis in the camera image, radians in [0, π), from +x towards +y.
    pub axis: f64,
    /// How elongated the light about the corner is: (λ1 − λ2)/(λ1 + λ2) of its second moments.
    pub elongation: f64,
    /// Local contrast (brightest level near the corner minus the darkest), grey levels.
    pub contrast: f32,
    /// What is left of the light's variance after turning it half a turn about the corner (0
    /// for a whole primitive; texture, cuts by shadows and edges raise it).
    pub asymmetry: f64,
}

/// Settings of [`detect`].
#[derive(Clone, Copy, Debug)]
pub struct DetectParams {
    /// Smoothing before the Hessian, pixels.
    pub sigma: f32,
    /// Least local contrast, grey levels.
    pub min_contrast: f32,
    /// Least saddle strength: −det(H)·σ⁴ over the squared local contrast.
    pub min_saddle: f32,
    /// Radius of the moments about a corner, pixels.
    pub radius: f64,
    /// Least elongation for the axis to be read.
    pub min_elongation: f64,
    /// Most asymmetry left at the corner: Σ(I(c+d) − I(c−d))² over the light's variance.
    pub max_asymmetry: f64,
}

impl Default for DetectParams {
    fn default() -> Self {
        DetectParams {
            sigma: 1.2,
            min_contrast: 24.0,
            min_saddle: 0.004,
            radius: 5.0,
            min_elongation: 0.25,
            max_asymmetry: 1.0,
        }
    }
}

/// Grey levels added before the logarithm on which corners are placed: keeps read noise in the
/// dark sectors from dominating.
const LOG_OFFSET: f32 = 8.0;

/// The X-points of a `width × height` image of grey levels.
pub fn detect(levels: &[f32], width: usize, height: usize, p: &DetectParams) -> Vec<Detection> {
    if width < 8 || height < 8 || levels.len() != width * height {
        return Vec::new();
    }
    let s = gaussian_blur(levels, width, height, p.sigma);
    let reach = (p.radius.ceil() as usize).max(2);
    // Saddle strength per pixel: −det(H)·σ⁴ (scale-normalised), zero where no saddle.
    let s4 = p.sigma.powi(4);
    let mut strength = vec![0f32; width * height];
    strength
        .par_chunks_mut(width)
        .enumerate()
        .skip(1)
        .take(height.saturating_sub(2))
        .for_each(|(y, row)| {
            for (x, out) in row.iter_mut().enumerate().take(width - 1).skip(1) {
                let i = y * width + x;
                let fxx = s[i - 1] - 2.0 * s[i] + s[i + 1];
                let fyy = s[i - width] - 2.0 * s[i] + s[i + width];
                let fxy = 0.25
                    * (s[i - width - 1] + s[i + width + 1] - s[i - width + 1] - s[i + width - 1]);
                *out = (-(fxx * fyy - fxy * fxy) * s4).max(0.0);
            }
        });
    // Local maxima (over the moments' reach) strong enough relative to the local contrast
    // (the brightest and darkest smoothed levels within the reach): any saddle of a textured
    // dark surface is weak against it.
    let floor = p.min_saddle * p.min_contrast * p.min_contrast;
    let border = reach + 2;
    let nms = reach.max(3) - 1;
    let candidates: Vec<(usize, usize, f32, f32)> = (border..height.saturating_sub(border))
        .into_par_iter()
        .flat_map_iter(|y| {
            let strength = &strength;
            let s = &s;
            (border..width.saturating_sub(border)).filter_map(move |x| {
                let i = y * width + x;
                let v = strength[i];
                if v < floor {
                    return None;
                }
                for yy in y.saturating_sub(nms)..=(y + nms).min(height - 1) {
                    let row = &strength[yy * width..(yy + 1) * width];
                    let (x0, x1) = (x.saturating_sub(nms), (x + nms).min(width - 1));
                    if row[x0..=x1].iter().any(|&o| o > v) {
                        return None;
                    }
                }
                let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
                for yy in y - reach..=y + reach {
                    for &o in &s[yy * width + x - reach..=yy * width + x + reach] {
                        lo = lo.min(o);
                        hi = hi.max(o);
                    }
                }
                let c = hi - lo;
                (c >= p.min_contrast && v >= p.min_saddle * c * c).then_some((x, y, lo, hi))
            })
        })
        .collect();
    // The corner is placed on the logarithm of the light: a surface's texture multiplies the
    // pattern, and its log adds, weighing as much in the dark sectors as in the bright.
    let log: Vec<f32> = s
        .par_iter()
        .map(|&v| fast_ln(v.max(0.0) + LOG_OFFSET))
        .collect();
    let mut found: Vec<Detection> = candidates
        .par_iter()
        .filter_map(|&(x, y, lo, hi)| refine(&s, &log, levels, width, height, x, y, (lo, hi), p))
        .collect();
    // Plateaus give neighbouring maxima of one corner: keep the first of any two closer than
    // the moments' radius.
    found.sort_by(|a, b| {
        (a.y, a.x)
            .partial_cmp(&(b.y, b.x))
            .unwrap_or(std::cmp::Ordering::Equal)
    });
    let mut kept: Vec<Detection> = Vec::with_capacity(found.len());
    let r2 = (0.5 * p.radius).powi(2);
    for d in found {
        let near = kept
            .iter()
            .rev()
            .take_while(|k| d.y - k.y < p.radius)
            .any(|k| (k.x - d.x).powi(2) + (k.y - d.y).powi(2) < r2);
        if !near {
            kept.push(d);
        }
    }
    kept
}

/// ln x for normal positive x, within 1e-3: the exponent plus a cubic in the mantissa that is
/// exact at both ends of the octave, so it is continuous and increasing, and vectorises.
fn fast_ln(x: f32) -> f32 {
    let bits = x.to_bits();
    let exponent = ((bits >> 23) & 0xff) as i32 - 127;
    let t = f32::from_bits((bits & 0x007f_ffff) | 0x3f80_0000) - 1.0;
    let log2 = exponent as f32 + t * (1.420_864_5 + t * (-0.577_250_6 + t * 0.156_386_1));
    log2 * std::f32::consts::LN_2
}

/// The corner near candidate (x, y): a start from the saddle of a quadratic fit, the centre
/// of point symmetry of the log light `log`, then the axis from the moments of the raw image.
#[allow(clippy::too_many_arguments)]
fn refine(
    s: &[f32],
    log: &[f32],
    raw: &[f32],
    width: usize,
    height: usize,
    x: usize,
    y: usize,
    range: (f32, f32),
    p: &DetectParams,
) -> Option<Detection> {
    let (lo, hi) = (f64::from(range.0), f64::from(range.1));
    let contrast = range.1 - range.0;
    let (cx, cy) = saddle_of_quadratic(s, width, height, x, y).unwrap_or((x as f64, y as f64));
    let (cx, cy, _) = symmetric_centre(log, width, height, cx, cy, p.radius, 6)?;
    let (_, _, asymmetry) = symmetric_centre(s, width, height, cx, cy, p.radius, 1)?;
    // A primitive cut by a shadow, an occluding edge or the end of the surface is not
    // point-symmetric, and its centre of symmetry is not its corner.
    if asymmetry > p.max_asymmetry {
        return None;
    }
    // A primitive's bright quadrants reach into a small ring about its corner; the dark gaps
    // between primitives have saddles too, with only dark close about them.
    let ring = 0.45 * p.radius;
    let (mut rmin, mut rmax) = (f64::INFINITY, f64::NEG_INFINITY);
    for k in 0..16 {
        let a = f64::from(k) * std::f64::consts::PI / 8.0;
        let (v, _, _) = sample(s, width, height, cx + ring * a.cos(), cy + ring * a.sin())?;
        rmin = rmin.min(v);
        rmax = rmax.max(v);
    }
    let half = lo + 0.5 * (hi - lo);
    if rmax < half || rmin > half {
        return None;
    }
    // … and its corner lies half-way between them.
    let (centre, _, _) = sample(s, width, height, cx, cy)?;
    let level = (centre - rmin) / (rmax - rmin).max(1e-9);
    if !(0.25..=0.75).contains(&level) {
        return None;
    }
    // Second moments of the light about the corner, over a disc.
    let r = p.radius;
    let (x0, x1) = (
        (cx - r).floor().max(0.0) as usize,
        ((cx + r).ceil() as usize).min(width - 1),
    );
    let (y0, y1) = (
        (cy - r).floor().max(0.0) as usize,
        ((cy + r).ceil() as usize).min(height - 1),
    );
    let mut floor = f32::INFINITY;
    for yy in y0..=y1 {
        for xx in x0..=x1 {
            floor = floor.min(raw[yy * width + xx]);
        }
    }
    let (mut m20, mut m02, mut m11) = (0f64, 0f64, 0f64);
    for yy in y0..=y1 {
        for xx in x0..=x1 {
            let (u, v) = (xx as f64 - cx, yy as f64 - cy);
            let d2 = u * u + v * v;
            if d2 > r * r {
                continue;
            }
            let f = f64::from(raw[yy * width + xx] - floor);
            m20 += f * u * u;
            m02 += f * v * v;
            m11 += f * u * v;
        }
    }
    let tr = m20 + m02;
    if tr <= 0.0 {
        return None;
    }
    let elongation = ((m20 - m02).powi(2) + 4.0 * m11 * m11).sqrt() / tr;
    if elongation < p.min_elongation {
        return None;
    }
    let axis = (0.5 * (2.0 * m11).atan2(m20 - m02)).rem_euclid(std::f64::consts::PI);
    Some(Detection {
        x: cx,
        y: cy,
        axis,
        elongation,
        contrast,
        asymmetry,
    })
}

/// Saddle point of the quadratic fitted to the smoothed image on a 5×5 patch about (x, y),
/// moved to and refitted up to three times; `None` where the patch is no saddle.
fn saddle_of_quadratic(
    s: &[f32],
    width: usize,
    height: usize,
    x: usize,
    y: usize,
) -> Option<(f64, f64)> {
    let (mut cx, mut cy) = (x as f64, y as f64);
    for _ in 0..3 {
        let (ix, iy) = (cx.round() as isize, cy.round() as isize);
        if ix < 3 || iy < 3 || ix >= width as isize - 3 || iy >= height as isize - 3 {
            return None;
        }
        // Least squares of f = a x² + b xy + c y² + d x + e y + g on the 5×5 patch.
        let mut ata = [[0f64; 6]; 6];
        let mut atb = [0f64; 6];
        for dy in -2isize..=2 {
            for dx in -2isize..=2 {
                let (u, v) = (dx as f64, dy as f64);
                let row = [u * u, u * v, v * v, u, v, 1.0];
                let f = f64::from(s[(iy + dy) as usize * width + (ix + dx) as usize]);
                for a in 0..6 {
                    atb[a] += row[a] * f;
                    for b in 0..6 {
                        ata[a][b] += row[a] * row[b];
                    }
                }
            }
        }
        let c = nalgebra::Matrix6::from_fn(|r, k| ata[r][k])
            .lu()
            .solve(&nalgebra::Vector6::from_column_slice(&atb))?;
        let (a, b, cc, d, e) = (c[0], c[1], c[2], c[3], c[4]);
        let det = 4.0 * a * cc - b * b;
        if det >= 0.0 {
            return None;
        }
        let ox = (b * e - 2.0 * cc * d) / det;
        let oy = (b * d - 2.0 * a * e) / det;
        if ox.abs() > 2.0 || oy.abs() > 2.0 {
            return None;
        }
        cx = ix as f64 + ox;
        cy = iy as f64 + oy;
        if ox.abs() <= 0.5 && oy.abs() <= 0.5 {
            return Some((cx, cy));
        }
    }
    None
}

/// Bilinear sample and its gradient at (x, y); `None` outside the image.
fn sample(s: &[f32], width: usize, height: usize, x: f64, y: f64) -> Option<(f64, f64, f64)> {
    if x < 0.0 || y < 0.0 || x >= (width - 1) as f64 || y >= (height - 1) as f64 {
        return None;
    }
    let (x0, y0) = (x.floor() as usize, y.floor() as usize);
    let (ax, ay) = (x - x0 as f64, y - y0 as f64);
    let i = y0 * width + x0;
    let (a, b, c, d) = (
        f64::from(s[i]),
        f64::from(s[i + 1]),
        f64::from(s[i + width]),
        f64::from(s[i + width + 1]),
    );
    let v = a * (1.0 - ax) * (1.0 - ay) + b * ax * (1.0 - ay) + c * (1.0 - ax) * ay + d * ax * ay;
    let gx = (b - a) * (1.0 - ay) + (d - c) * ay;
    let gy = (c - a) * (1.0 - ax) + (d - b) * ax;
    Some((v, gx, gy))
}

/// The centre of point symmetry of the light about (x, y), with the asymmetry at the start (of
/// the light's variance): an X-point primitive is the same turned half a turn about its corner,
/// and stays so under the affine part of the camera's view. Up to `steps` of Gauss–Newton on
/// Σ (I(c + d) − I(c − d))² over a disc of `radius`, which uses every pixel of the primitive
/// rather than the few at its corner.
fn symmetric_centre(
    s: &[f32],
    width: usize,
    height: usize,
    x: f64,
    y: f64,
    radius: f64,
    steps: usize,
) -> Option<(f64, f64, f64)> {
    let (mut cx, mut cy) = (x, y);
    let r = radius.ceil() as i32;
    let mut asymmetry = None;
    for _ in 0..steps {
        let (mut ee, mut energy, mut sum, mut count) = (0f64, 0f64, 0f64, 0f64);
        let (mut h11, mut h12, mut h22, mut g1, mut g2) = (0f64, 0f64, 0f64, 0f64, 0f64);
        for dy in 0..=r {
            for dx in -r..=r {
                // Half the disc: each pair once.
                if dy == 0 && dx <= 0 {
                    continue;
                }
                let (fx, fy) = (f64::from(dx), f64::from(dy));
                if fx * fx + fy * fy > radius * radius {
                    continue;
                }
                let (Some((p, px, py)), Some((q, qx, qy))) = (
                    sample(s, width, height, cx + fx, cy + fy),
                    sample(s, width, height, cx - fx, cy - fy),
                ) else {
                    return None;
                };
                let e = p - q;
                ee += e * e;
                energy += p * p + q * q;
                sum += p + q;
                count += 2.0;
                let (jx, jy) = (px - qx, py - qy);
                h11 += jx * jx;
                h12 += jx * jy;
                h22 += jy * jy;
                g1 += jx * e;
                g2 += jy * e;
            }
        }
        let mean = sum / count.max(1.0);
        let spread = energy - count * mean * mean;
        asymmetry.get_or_insert(if spread > 0.0 { ee / spread } else { 1.0 });
        let det = h11 * h22 - h12 * h12;
        if det.abs() < 1e-12 {
            return None;
        }
        let sx = -(h22 * g1 - h12 * g2) / det;
        let sy = -(-h12 * g1 + h11 * g2) / det;
        cx += sx.clamp(-1.0, 1.0);
        cy += sy.clamp(-1.0, 1.0);
        if (cx - x).abs() > 2.0 || (cy - y).abs() > 2.0 {
            return None;
        }
        if sx.abs() < 1e-3 && sy.abs() < 1e-3 {
            break;
        }
    }
    Some((cx, cy, asymmetry.unwrap_or(1.0)))
}

#[cfg(test)]
mod tests {
    use super::fast_ln;

    #[test]
    fn fast_ln_follows_ln_and_increases() {
        let mut last = f32::NEG_INFINITY;
        for k in 0..20_000 {
            let x = 1.0 + k as f32 * 0.037;
            let y = fast_ln(x);
            assert!((y - x.ln()).abs() < 1e-3, "{x}: {y} against {}", x.ln());
            assert!(y > last, "{x}");
            last = y;
        }
    }
}
