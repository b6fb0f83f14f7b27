//! Inspection outputs: `deviation.ply` (points in the CAD frame with a `deviation` property)
//! and `deviation.png` (colour map seen along the part's thinnest axis, a colour bar with ticks
//! at ±tolerance and 0, and a logarithmic histogram of the deviations in the same colours).

use std::path::Path;

use crate::decode::hue_to_rgb;
use crate::image::save_rgb_png;
use crate::io::write_atomic;
use crate::Result;

/// Binary little-endian PLY: x y z deviation (float32), atomically.
pub fn write_deviation_ply(path: &Path, points: &[[f64; 3]], deviations: &[f64]) -> Result<()> {
    let header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment RIS inspection: points in the CAD frame, signed deviation in mm\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nproperty float deviation\nend_header\n",
        points.len()
    );
    let mut buf = Vec::with_capacity(header.len() + points.len() * 16);
    buf.extend_from_slice(header.as_bytes());
    for (p, d) in points.iter().zip(deviations) {
        for v in [p[0] as f32, p[1] as f32, p[2] as f32, *d as f32] {
            buf.extend_from_slice(&v.to_le_bytes());
        }
    }
    write_atomic(path, &buf)
}

/// Colour of deviation `d` for tolerance `tol`: green within tolerance, cyan → blue below
/// (missing material), yellow → red above (excess), saturating at ±2 tolerances (SPEC §2).
pub fn deviation_colour(d: f64, tol: f64) -> [u8; 3] {
    if !d.is_finite() {
        return [40, 40, 40];
    }
    let t = (d / tol).clamp(-2.0, 2.0);
    if t.abs() <= 1.0 {
        // Within tolerance: green, lighter towards the limits.
        let g = 0.55 + 0.35 * t.abs();
        return [(40.0 + 60.0 * t.abs()) as u8, (255.0 * g) as u8, 60];
    }
    // Out of tolerance: hue from yellow (t = 1) to red (t = 2), or cyan (−1) to blue (−2).
    let s = (t.abs() - 1.0) as f32;
    if t > 0.0 {
        [255, (220.0 * (1.0 - s)) as u8, 0]
    } else {
        let c = hue_to_rgb(0.25 * (1.0 - s), 1.0);
        [c[0], c[1], c[2].max(200)]
    }
}

/// Render the deviation map with colour bar and histogram.
pub fn write_deviation_png(
    path: &Path,
    points: &[[f64; 3]],
    deviations: &[f64],
    tol: f64,
) -> Result<()> {
    // View along the thinnest principal axis of the points.
    let n = points.len().max(1) as f64;
    let mut c = [0.0; 3];
    for p in points {
        for k in 0..3 {
            c[k] += p[k] / n;
        }
    }
    let mut cov = nalgebra::Matrix3::<f64>::zeros();
    for p in points {
        let d = nalgebra::Vector3::new(p[0] - c[0], p[1] - c[1], p[2] - c[2]);
        cov += d * d.transpose();
    }
    let e = cov.symmetric_eigen();
    let mut idx = [0usize, 1, 2];
    idx.sort_by(|&i, &j| e.eigenvalues[j].total_cmp(&e.eigenvalues[i]));
    let (ax, ay) = (
        e.eigenvectors.column(idx[0]).into_owned(),
        e.eigenvectors.column(idx[1]).into_owned(),
    );
    let uv: Vec<(f64, f64)> = points
        .iter()
        .map(|p| {
            let d = nalgebra::Vector3::new(p[0] - c[0], p[1] - c[1], p[2] - c[2]);
            (d.dot(&ax), -d.dot(&ay))
        })
        .collect();
    let (mut u0, mut u1, mut v0, mut v1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for &(u, v) in &uv {
        u0 = u0.min(u);
        u1 = u1.max(u);
        v0 = v0.min(v);
        v1 = v1.max(v);
    }
    // Pixel size from the point density so the map has few holes; map at most 1200 px wide.
    let area = ((u1 - u0) * (v1 - v0)).max(1e-9);
    let px = ((area / n).sqrt() * 1.3).max((u1 - u0) / 1200.0).max(1e-9);
    let (mw, mh) = (
        (((u1 - u0) / px) as usize + 1).max(1),
        (((v1 - v0) / px) as usize + 1).max(1),
    );
    let (bar_w, hist_h, pad) = (60usize, 160usize, 20usize);
    let (w, h) = (mw + bar_w + 3 * pad, mh + hist_h + 3 * pad);
    let mut img = vec![255u8; w * h * 3];
    let put = |x: usize, y: usize, rgb: [u8; 3], img: &mut Vec<u8>| {
        if x < w && y < h {
            img[(y * w + x) * 3..(y * w + x) * 3 + 3].copy_from_slice(&rgb);
        }
    };
    for (&(u, v), &d) in uv.iter().zip(deviations) {
        let (x, y) = (
            pad + ((u - u0) / px) as usize,
            pad + ((v - v0) / px) as usize,
        );
        put(x, y, deviation_colour(d, tol), &mut img);
    }
    // Colour bar: +2 tol at the top, −2 tol at the bottom; black ticks at ±tol and 0.
    let (bx, by) = (mw + 2 * pad, pad);
    let bar_h = mh.max(100);
    for y in 0..bar_h {
        let d = (2.0 - 4.0 * y as f64 / (bar_h - 1).max(1) as f64) * tol;
        let tick = [-tol, 0.0, tol]
            .iter()
            .any(|t| ((d - t) / (4.0 * tol) * bar_h as f64).abs() < 0.5);
        for x in 0..bar_w {
            put(
                bx + x,
                by + y,
                if tick {
                    [0, 0, 0]
                } else {
                    deviation_colour(d, tol)
                },
                &mut img,
            );
        }
    }
    // Histogram over ±2 tol (80 bins), bars in the bin's colour, logarithmic so the tails show.
    let bins = 80usize;
    let mut counts = vec![0usize; bins];
    for d in deviations.iter().filter(|d| d.is_finite()) {
        let b = (((d / tol).clamp(-2.0, 2.0) + 2.0) / 4.0 * bins as f64) as usize;
        counts[b.min(bins - 1)] += 1;
    }
    let peak = (counts.iter().copied().max().unwrap_or(1).max(1) as f64).ln_1p();
    let (hx, hy) = (pad, mh + 2 * pad);
    let bin_w = (mw / bins).max(2);
    for (b, &cnt) in counts.iter().enumerate() {
        let bar = ((cnt as f64).ln_1p() / peak * hist_h as f64) as usize;
        let d = (-2.0 + 4.0 * (b as f64 + 0.5) / bins as f64) * tol;
        for y in 0..bar {
            for x in 0..bin_w - 1 {
                put(
                    hx + b * bin_w + x,
                    hy + hist_h - 1 - y,
                    deviation_colour(d, tol),
                    &mut img,
                );
            }
        }
    }
    for x in 0..bins * bin_w {
        put(hx + x, hy + hist_h, [0, 0, 0], &mut img);
    }
    save_rgb_png(path, w as u32, h as u32, &img)
}
