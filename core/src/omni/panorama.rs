//! The unwarped panorama (Fig. 6.7) with distance colours fused (Ch. 7.3): the camera's conic
//! image unrolled about its centre, azimuth 0 … 360° left to right (counter-clockwise seen from
//! above, from the sensor's +x), and each decoded point coloured by its distance from the
//! sensor origin, red near to blue far, over the picture; black where the mirror shows nothing.
//! Crossings whose ring could not be told from others are marked in magenta where no point is
//! drawn, so an operator sees that a surface was left out rather than a phantom wall.

use std::f64::consts::TAU;

use super::decode::{RingDecode, RingDecoder};
use super::OmniSensor;
use crate::cloud::PointCloud;
use crate::image::GrayImage;
use crate::single_shot::{fuse_from, Fused, FusionRange};
use crate::Result;

/// Colour of the crossings left out as ambiguous (magenta: not on the distance scale).
pub const AMBIGUOUS: [u8; 3] = [255, 0, 255];

/// A panorama and how its pixels map to directions.
#[derive(Clone, Debug)]
pub struct Panorama {
    /// The picture with its colour bar.
    pub fused: Fused,
    /// Width of the unrolled image (the colour bar is right of it), pixels: column x looks
    /// along azimuth 360° · (x + 0.5) / width.
    pub width: u32,
    /// Camera image radius of row 0 (pixels from the conic centre); each row is one pixel out.
    pub rho0: f64,
    /// Elevation (degrees above the horizontal through the camera's viewpoint) of the top and
    /// the bottom row.
    pub elevation_deg: [f64; 2],
}

/// Unroll `image` and fuse `decoded`'s points over it, coloured by `range`.
pub fn panorama(
    sensor: &OmniSensor,
    decoder: &RingDecoder,
    image: &GrayImage,
    decoded: &RingDecode,
    range: FusionRange,
) -> Result<Panorama> {
    let [cx, cy] = decoder.center();
    let [rho0, outer] = decoder.radial_span();
    let width = decoder.columns();
    let height = (outer - rho0).floor() as usize + 1;
    // Image angle → sensor azimuth is ± the image angle plus an offset for a stacked unit.
    let azimuth_at = |t: f64| {
        let rho = 0.5 * (rho0 + outer);
        let (u, v) = (cx + rho * t.cos(), cy + rho * t.sin());
        // The model where a ray table leaves the pixel out: only the turn's sense is needed.
        sensor
            .camera_ray(u, v)
            .or_else(|| sensor.camera.back_project(u, v))
            .map(|r| r.direction.y.atan2(r.direction.x))
    };
    let (a0, a1) = (azimuth_at(0.0), azimuth_at(0.01));
    let (offset, sign) = match (a0, a1) {
        (Some(a0), Some(a1)) => (a0, if (a1 - a0).sin() >= 0.0 { 1.0 } else { -1.0 }),
        _ => (0.0, 1.0),
    };
    // Image angle of azimuth phi.
    let angle = |phi: f64| sign * (phi - offset);
    let levels = image.to_levels();
    let (w, h) = (image.width as usize, image.height as usize);
    let mut pixels = vec![0u8; width * height];
    for x in 0..width {
        let t = angle(TAU * (x as f64 + 0.5) / width as f64);
        for y in 0..height {
            let rho = rho0 + y as f64;
            let (u, v) = (cx + rho * t.cos(), cy + rho * t.sin());
            if u >= 0.0 && v >= 0.0 && u <= (w - 1) as f64 && v <= (h - 1) as f64 {
                let i = v.round() as usize * w + u.round() as usize;
                pixels[y * width + x] = levels[i].round().clamp(0.0, 255.0) as u8;
            }
        }
    }
    let unrolled = GrayImage::from_u8(width as u32, height as u32, pixels);
    let mut cloud = PointCloud {
        image: Some([width as u32, height as u32]),
        ..PointCloud::default()
    };
    // The panorama pixel (column, row) of a crossing at `pixel` and sensor `azimuth`.
    let cell = |pixel: [f32; 2], azimuth: f32| {
        let x = (f64::from(azimuth).rem_euclid(TAU) / TAU * width as f64).floor() as usize;
        let rho = (f64::from(pixel[0]) - cx).hypot(f64::from(pixel[1]) - cy);
        let y = (rho - rho0).round();
        (y >= 0.0 && (y as usize) < height && x < width).then_some((x, y as usize))
    };
    for p in &decoded.points {
        let Some((x, y)) = cell(p.pixel, p.azimuth) else {
            continue;
        };
        cloud.points.push(p.point);
        cloud.confidence.push(1.0);
        cloud.pixels.push((y * width + x) as u32);
    }
    let mut fused = fuse_from(
        &unrolled,
        &cloud,
        [0.0, 0.0, 0.0],
        range,
        None,
        "mm from sensor",
        if decoded.ambiguous.is_empty() {
            &[]
        } else {
            &[(AMBIGUOUS, "ambiguous")]
        },
    )?;
    // The ambiguous crossings, where no decoded point coloured the pixel (a grey pixel).
    for a in &decoded.ambiguous {
        let Some((x, y)) = cell(a.pixel, a.azimuth) else {
            continue;
        };
        let i = 3 * (y * fused.width + x);
        if let Some(px) = fused.rgb.get_mut(i..i + 3) {
            if px[0] == px[1] && px[1] == px[2] {
                px.copy_from_slice(&AMBIGUOUS);
            }
        }
    }
    let elevation = |rho: f64| {
        sensor
            .camera_ray(cx + rho, cy)
            .or_else(|| sensor.camera.back_project(cx + rho, cy))
            .map_or(f64::NAN, |r| {
                r.direction
                    .z
                    .atan2(r.direction.x.hypot(r.direction.y))
                    .to_degrees()
            })
    };
    Ok(Panorama {
        fused,
        width: width as u32,
        rho0,
        elevation_deg: [elevation(rho0), elevation(outer)],
    })
}
