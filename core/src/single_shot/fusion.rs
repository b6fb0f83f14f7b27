//! The fusion display (Ch. 7.2.2): distance colour-coded over the camera's own picture, red
//! near to blue far, with a labelled colour bar, so an operator driving a robot reads distance
//! on the live image. Single-shot points are sparse; each colours the pixels nearer to it than
//! to any other point, up to a radius that makes the cells of a regular grid meet.

use rayon::prelude::*;

use crate::cloud::PointCloud;
use crate::decode::hue_to_rgb;
use crate::error::{Error, Result};
use crate::image::GrayImage;
use crate::inspect::canvas::Canvas;
use crate::inspect::Label;

/// Width of the colour-bar panel right of the picture, pixels.
const PANEL: usize = 120;

/// How distances are coloured.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FusionRange {
    /// Distance drawn red, mm (nearer is red too).
    pub near: f64,
    /// Distance drawn blue, mm (further is blue too).
    pub far: f64,
}

impl FusionRange {
    /// A range, refused unless `0 ≤ near < far` and both are finite (`context` names the
    /// argument in the error).
    pub fn new(near: f64, far: f64, context: &str) -> Result<FusionRange> {
        if !(near.is_finite() && far.is_finite() && near >= 0.0 && near < far) {
            return Err(Error::invalid(
                context,
                "range",
                format!("{near},{far}: need 0 <= NEAR < FAR (mm)"),
            ));
        }
        Ok(FusionRange { near, far })
    }

    /// The range from the 2nd to the 98th percentile of `cloud`'s distances from `eye`, widened
    /// to round values; 0 … 1000 mm for an empty cloud.
    pub fn covering(cloud: &PointCloud, eye: [f64; 3]) -> FusionRange {
        let mut d: Vec<f64> = cloud.points.iter().map(|p| distance(p, eye)).collect();
        if d.is_empty() {
            return FusionRange {
                near: 0.0,
                far: 1000.0,
            };
        }
        d.sort_by(f64::total_cmp);
        let (lo, hi) = (
            d[d.len() * 2 / 100],
            d[(d.len() * 98 / 100).min(d.len() - 1)],
        );
        let step = nice_step(((hi - lo) / 6.0).max(1.0));
        let near = ((lo / step).floor() * step).max(0.0);
        let far = ((hi / step).ceil() * step).max(near + step);
        FusionRange { near, far }
    }

    /// The colour of distance `d`, mm: red at `near` through yellow, green and cyan to blue at
    /// `far`, clamped outside.
    pub fn colour(&self, d: f64) -> [u8; 3] {
        let t = ((d - self.near) / (self.far - self.near)).clamp(0.0, 1.0);
        hue_to_rgb((1.0 - t) as f32, 1.0)
    }
}

/// A fusion picture: the camera image with distance colours, and a colour bar.
#[derive(Clone, Debug)]
pub struct Fused {
    /// Width, pixels (the camera image and the bar panel).
    pub width: usize,
    /// Height, pixels.
    pub height: usize,
    /// RGB, row-major.
    pub rgb: Vec<u8>,
    /// Text drawn on it (the bar's title and ticks).
    pub labels: Vec<Label>,
    /// Radius each point colours, camera pixels.
    pub radius: f64,
    /// Camera pixels that carry a distance colour.
    pub coloured: usize,
}

impl Fused {
    /// Encoded as PNG.
    pub fn png(&self) -> Result<Vec<u8>> {
        crate::image::encode_rgb_png(self.width as u32, self.height as u32, &self.rgb)
    }

    /// Written as PNG through a temporary file and a rename.
    pub fn save(&self, path: &std::path::Path) -> Result<()> {
        crate::image::save_rgb_png(path, self.width as u32, self.height as u32, &self.rgb)
    }
}

/// Fuse `cloud` (organised on `image`'s pixels) over `image`: each point's distance from `eye`
/// (the camera centre in the cloud's frame, mm) coloured by `range`. `radius` (camera pixels)
/// bounds the cell a point colours; `None` takes 0.75 × the median spacing of the points.
pub fn fuse(
    image: &GrayImage,
    cloud: &PointCloud,
    eye: [f64; 3],
    range: FusionRange,
    radius: Option<f64>,
) -> Result<Fused> {
    fuse_from(image, cloud, eye, range, radius, "mm from camera", &[])
}

/// [`fuse`] with the colour bar's caption naming where distance is measured from (the
/// omnidirectional panorama measures from the sensor's origin), and `keys`: colours off the
/// distance scale that the caller paints afterwards, each named with a swatch under the bar.
pub fn fuse_from(
    image: &GrayImage,
    cloud: &PointCloud,
    eye: [f64; 3],
    range: FusionRange,
    radius: Option<f64>,
    caption: &str,
    keys: &[([u8; 3], &str)],
) -> Result<Fused> {
    let (w, h) = (image.width as usize, image.height as usize);
    match cloud.image {
        Some([cw, ch]) if (cw as usize, ch as usize) == (w, h) => {}
        Some([cw, ch]) => {
            return Err(Error::invalid(
                "fusion",
                "cloud",
                format!("the cloud is organised on {cw}x{ch} pixels, the image is {w}x{h}"),
            ))
        }
        None => {
            return Err(Error::invalid(
                "fusion",
                "cloud",
                "the cloud has no camera pixels (not organised)",
            ))
        }
    }
    let at: Vec<(f64, f64)> = cloud
        .pixels
        .iter()
        .map(|&p| ((p as usize % w) as f64, (p as usize / w) as f64))
        .collect();
    let radius = radius
        .unwrap_or_else(|| 0.75 * median_spacing(&at, w, h))
        .max(0.5);
    // Each pixel takes the nearest point within the radius (of equally near ones, the first):
    // row by row in parallel, over the points whose disc reaches the row, each disc's row a
    // span whose half-width is tabled.
    let r = radius.floor() as usize;
    let span: Vec<usize> = (0..=r)
        .map(|dy| {
            let left = radius * radius - (dy * dy) as f64;
            let mut half = left.max(0.0).sqrt().floor() as usize;
            while ((half + 1) * (half + 1)) as f64 <= left {
                half += 1;
            }
            while half > 0 && (half * half) as f64 > left {
                half -= 1;
            }
            half
        })
        .collect();
    let row_of = |k: u32| cloud.pixels[k as usize] as usize / w;
    let mut by_row: Vec<u32> = (0..at.len() as u32).collect();
    by_row.sort_by_key(|&k| row_of(k));
    let mut owner = vec![u32::MAX; w * h];
    owner.par_chunks_mut(w).enumerate().for_each_init(
        || vec![usize::MAX; w],
        |best, (y, row)| {
            best.fill(usize::MAX);
            let first = by_row.partition_point(|&k| row_of(k) + r < y);
            for &k in by_row[first..].iter().take_while(|&&k| row_of(k) <= y + r) {
                let px = cloud.pixels[k as usize] as usize;
                let (cx, cy) = (px % w, px / w);
                let dy = cy.abs_diff(y);
                let half = span[dy];
                for x in cx.saturating_sub(half)..=(cx + half).min(w - 1) {
                    let d2 = x.abs_diff(cx).pow(2) + dy * dy;
                    if d2 < best[x] || (d2 == best[x] && k < row[x]) {
                        best[x] = d2;
                        row[x] = k;
                    }
                }
            }
        },
    );
    let colours: Vec<[u8; 3]> = cloud
        .points
        .iter()
        .map(|p| range.colour(distance(p, eye)))
        .collect();
    let levels = image.to_levels();
    let top = levels.iter().copied().fold(1.0f32, f32::max);
    let mut cv = Canvas::new(w + PANEL, h.max(220), [255, 255, 255]);
    // Row by row in parallel: the picture's pixels, coloured where a point owns them.
    let coloured: usize = cv
        .rgb
        .par_chunks_mut((w + PANEL) * 3)
        .take(h)
        .enumerate()
        .map(|(y, row)| {
            let mut n = 0;
            for x in 0..w {
                let i = y * w + x;
                let g = (levels[i] / top).clamp(0.0, 1.0);
                let c = if owner[i] == u32::MAX {
                    let v = (g * 255.0) as u8;
                    [v, v, v]
                } else {
                    n += 1;
                    // The picture's shading stays visible under the colour.
                    let c = colours[owner[i] as usize];
                    let s = 0.45 + 0.55 * g;
                    c.map(|v| (f32::from(v) * s) as u8)
                };
                row[3 * x..3 * x + 3].copy_from_slice(&c);
            }
            n
        })
        .sum();
    draw_bar(&mut cv, w as i64, h.max(220) as i64, range, caption, keys);
    Ok(Fused {
        width: cv.width,
        height: cv.height,
        rgb: cv.rgb,
        labels: cv.labels,
        radius,
        coloured,
    })
}

/// Distance of `p` from `eye`, mm.
fn distance(p: &[f32; 3], eye: [f64; 3]) -> f64 {
    ((f64::from(p[0]) - eye[0]).powi(2)
        + (f64::from(p[1]) - eye[1]).powi(2)
        + (f64::from(p[2]) - eye[2]).powi(2))
    .sqrt()
}

/// The median distance from a point to its nearest other point, pixels (a grid hash of cells
/// about the mean spacing); the image diagonal / 100 when there are fewer than two points.
fn median_spacing(at: &[(f64, f64)], w: usize, h: usize) -> f64 {
    if at.len() < 2 {
        return ((w * w + h * h) as f64).sqrt() / 100.0;
    }
    let cell = ((w * h) as f64 / at.len() as f64).sqrt().max(2.0);
    let (gw, gh) = (
        (w as f64 / cell).ceil() as usize + 1,
        (h as f64 / cell).ceil() as usize + 1,
    );
    let mut grid: Vec<Vec<u32>> = vec![Vec::new(); gw * gh];
    let key = |p: (f64, f64)| ((p.0 / cell) as usize, (p.1 / cell) as usize);
    for (k, &p) in at.iter().enumerate() {
        let (gx, gy) = key(p);
        grid[gy.min(gh - 1) * gw + gx.min(gw - 1)].push(k as u32);
    }
    let step = (at.len() / 2000).max(1);
    let mut nearest: Vec<f64> = Vec::new();
    for (k, &p) in at.iter().enumerate().step_by(step) {
        let (gx, gy) = key(p);
        let mut d = f64::INFINITY;
        for yy in gy.saturating_sub(2)..(gy + 3).min(gh) {
            for xx in gx.saturating_sub(2)..(gx + 3).min(gw) {
                for &o in &grid[yy * gw + xx] {
                    if o as usize != k {
                        let q = at[o as usize];
                        d = d.min(((p.0 - q.0).powi(2) + (p.1 - q.1).powi(2)).sqrt());
                    }
                }
            }
        }
        if d.is_finite() {
            nearest.push(d);
        }
    }
    if nearest.is_empty() {
        return 2.0 * cell;
    }
    nearest.sort_by(f64::total_cmp);
    nearest[nearest.len() / 2]
}

/// The colour bar right of the picture: red (near) at the top, blue (far) at the bottom,
/// ticked at round distances with their values in mm.
fn draw_bar(
    cv: &mut Canvas,
    x0: i64,
    height: i64,
    range: FusionRange,
    caption: &str,
    keys: &[([u8; 3], &str)],
) {
    const INK: [u8; 3] = [20, 20, 20];
    const KEY: i64 = 18;
    let (bx, by) = (x0 + 16, 34i64);
    let (bw, bh) = (22i64, (height - 60 - KEY * keys.len() as i64).max(100));
    cv.text((x0 + 8) as f64, 8.0, 14.0, "distance", INK);
    for y in 0..bh {
        let d = range.near + (range.far - range.near) * y as f64 / (bh - 1) as f64;
        cv.fill(bx, by + y, bw, 1, range.colour(d));
    }
    cv.frame(bx - 1, by - 1, bw + 2, bh + 2, INK);
    let span = range.far - range.near;
    let step = nice_step(span / 6.0);
    let mut v = (range.near / step).ceil() * step;
    while v <= range.far + 1e-9 {
        let y = by + ((v - range.near) / span * (bh - 1) as f64).round() as i64;
        cv.fill(bx + bw + 1, y, 5, 1, INK);
        cv.text(
            (bx + bw + 9) as f64,
            y as f64 - 6.0,
            12.0,
            &format_mm(v),
            INK,
        );
        v += step;
    }
    cv.text(x0 as f64 + 8.0, (by + bh + 8) as f64, 12.0, caption, INK);
    for (i, (colour, name)) in keys.iter().enumerate() {
        let y = by + bh + 8 + KEY * (i as i64 + 1);
        cv.fill(x0 + 8, y, 12, 12, *colour);
        cv.frame(x0 + 7, y - 1, 14, 14, INK);
        cv.text(x0 as f64 + 26.0, y as f64, 12.0, name, INK);
    }
}

/// 1, 2 or 5 × a power of ten, at least `raw`.
fn nice_step(raw: f64) -> f64 {
    let p = 10f64.powf(raw.max(1e-9).log10().floor());
    [1.0, 2.0, 5.0, 10.0]
        .into_iter()
        .map(|m| m * p)
        .find(|s| *s >= raw)
        .unwrap_or(10.0 * p)
}

fn format_mm(v: f64) -> String {
    if v.fract().abs() < 1e-9 {
        format!("{v:.0}")
    } else {
        format!("{v:.1}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn steps_are_round() {
        assert_eq!(nice_step(0.3), 0.5);
        assert_eq!(nice_step(166.0), 200.0);
        assert_eq!(nice_step(1000.0), 1000.0);
        assert_eq!(nice_step(1001.0), 2000.0);
    }

    #[test]
    fn near_is_red_and_far_is_blue() {
        let r = FusionRange::new(2000.0, 4000.0, "t").expect("range");
        assert_eq!(r.colour(1000.0), [255, 0, 0]);
        assert_eq!(r.colour(2000.0), [255, 0, 0]);
        assert_eq!(r.colour(4000.0), [0, 0, 255]);
        assert!(FusionRange::new(5.0, 5.0, "t").is_err());
        assert!(FusionRange::new(f64::NAN, 5.0, "t").is_err());
    }

    /// Seeded pictures, clouds and ranges: every pixel of the picture carries the colour of the
    /// distance of the point nearest to it (within the radius), shaded by the picture, and
    /// every other pixel the picture's own grey; the bar's ticks lie within the range, in order.
    #[test]
    fn each_pixel_shows_its_nearest_points_distance() {
        let mut rng = crate::testing::Rng(11);
        let mut rand = move || rng.uniform();
        for case in 0..5 {
            let (w, h) = (
                60 + (rand() * 140.0) as usize,
                40 + (rand() * 110.0) as usize,
            );
            let grey: Vec<u8> = (0..w * h).map(|_| (rand() * 255.0) as u8).collect();
            let image = GrayImage::from_u8(w as u32, h as u32, grey.clone());
            let near = 200.0 + rand() * 2000.0;
            let range = FusionRange::new(near, near + 50.0 + rand() * 1500.0, "t").expect("range");
            let eye = [rand() * 100.0, rand() * 100.0, -rand() * 100.0];
            let mut cloud = PointCloud {
                image: Some([w as u32, h as u32]),
                ..Default::default()
            };
            let mut taken = vec![false; w * h];
            for _ in 0..(w * h) / (20 + (rand() * 80.0) as usize) {
                let px = (rand() * (w * h) as f64) as usize;
                if std::mem::replace(&mut taken[px], true) {
                    continue;
                }
                let d = range.near - 100.0 + rand() * (range.far - range.near + 200.0);
                let (a, b) = (rand() * std::f64::consts::TAU, rand() * 1.5);
                let dir = [b.sin() * a.cos(), b.sin() * a.sin(), b.cos()];
                cloud
                    .points
                    .push([0, 1, 2].map(|k| (eye[k] + d * dir[k]) as f32));
                cloud.confidence.push(1.0);
                cloud.pixels.push(px as u32);
            }
            let radius = (case % 2 == 0).then(|| 1.0 + rand() * 6.0);
            let f = fuse(&image, &cloud, eye, range, radius).expect("fused");
            let r = f.radius;
            let top = f64::from(*grey.iter().max().expect("pixels")).max(1.0);
            let mut coloured = 0;
            for y in 0..h {
                for x in 0..w {
                    let got = &f.rgb[(y * f.width + x) * 3..][..3];
                    let g = f64::from(grey[y * w + x]) / top;
                    // The points nearest to the pixel (ties all count).
                    let d2 = |p: u32| {
                        let (px, py) = ((p as usize % w) as f64, (p as usize / w) as f64);
                        (px - x as f64).powi(2) + (py - y as f64).powi(2)
                    };
                    let least = cloud
                        .pixels
                        .iter()
                        .map(|&p| d2(p))
                        .fold(f64::INFINITY, f64::min);
                    if least > r * r {
                        let v = (g * 255.0) as u8;
                        assert_eq!(got, [v, v, v], "case {case} ({x}, {y})");
                        continue;
                    }
                    coloured += 1;
                    let s = 0.45 + 0.55 * g;
                    let fits = cloud.pixels.iter().zip(&cloud.points).any(|(&p, q)| {
                        d2(p) == least
                            && range
                                .colour(distance(q, eye))
                                .iter()
                                .zip(got)
                                .all(|(&c, &o)| (f64::from(c) * s - f64::from(o)).abs() <= 1.5)
                    });
                    assert!(fits, "case {case} ({x}, {y}): {got:?}");
                }
            }
            assert_eq!(f.coloured, coloured, "case {case}");
            let ticks: Vec<f64> = f
                .labels
                .iter()
                .filter_map(|l| l.text.parse::<f64>().ok())
                .collect();
            assert!(ticks.len() >= 2, "case {case}: {ticks:?}");
            assert!(
                ticks.windows(2).all(|t| t[0] < t[1])
                    && ticks
                        .iter()
                        .all(|&t| t >= range.near - 1e-6 && t <= range.far + 1e-6),
                "case {case}: ticks {ticks:?} for {range:?}"
            );
        }
    }
}
