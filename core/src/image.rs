//! Grayscale images (8 or 16 bit), read from PNG, BMP (also 8-bit palette), TIFF or JPEG and
//! written as PNG. Colour input is converted to luma.

use std::path::Path;

use crate::io::write_atomic;
use crate::{Error, Result};

/// Pixel storage of a grayscale image.
#[derive(Clone, Debug, PartialEq)]
pub enum Pixels {
    /// 8-bit samples.
    U8(Vec<u8>),
    /// 16-bit samples.
    U16(Vec<u16>),
}

/// A row-major grayscale image.
#[derive(Clone, Debug, PartialEq)]
pub struct GrayImage {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// The samples, row-major.
    pub pixels: Pixels,
}

/// Sample types the decoder works on directly (u8 and u16).
pub trait Sample: Copy + Default + Send + Sync + 'static {
    /// The value widened to i32.
    fn to_i32(self) -> i32;
}

impl Sample for u8 {
    #[inline(always)]
    fn to_i32(self) -> i32 {
        i32::from(self)
    }
}

impl Sample for u16 {
    #[inline(always)]
    fn to_i32(self) -> i32 {
        i32::from(self)
    }
}

impl GrayImage {
    /// An 8-bit image from row-major samples.
    pub fn from_u8(width: u32, height: u32, data: Vec<u8>) -> Self {
        debug_assert_eq!(data.len(), (width * height) as usize);
        GrayImage {
            width,
            height,
            pixels: Pixels::U8(data),
        }
    }

    /// A 16-bit image from row-major samples.
    pub fn from_u16(width: u32, height: u32, data: Vec<u16>) -> Self {
        debug_assert_eq!(data.len(), (width * height) as usize);
        GrayImage {
            width,
            height,
            pixels: Pixels::U16(data),
        }
    }

    /// Bits per sample (8 or 16).
    pub fn bit_depth(&self) -> u8 {
        match self.pixels {
            Pixels::U8(_) => 8,
            Pixels::U16(_) => 16,
        }
    }

    /// The samples widened to 16 bit (8-bit values scaled by 257 so that 255 → 65535).
    pub fn to_u16(&self) -> Vec<u16> {
        match &self.pixels {
            Pixels::U8(v) => v.iter().map(|&p| u16::from(p) * 257).collect(),
            Pixels::U16(v) => v.clone(),
        }
    }

    /// The samples on the 8-bit scale (0..255, fractional for 16-bit images), so thresholds in
    /// DN apply to either depth.
    pub fn to_levels(&self) -> Vec<f32> {
        let mut out = Vec::new();
        self.levels_into(&mut out);
        out
    }

    /// [`GrayImage::to_levels`] into `out`, reusing its memory (a stream's frames are all
    /// one size).
    pub fn levels_into(&self, out: &mut Vec<f32>) {
        out.clear();
        match &self.pixels {
            Pixels::U8(v) => out.extend(v.iter().map(|&p| f32::from(p))),
            Pixels::U16(v) => out.extend(v.iter().map(|&p| f32::from(p) / 257.0)),
        }
    }

    /// Sample at (x, y) as f32 (no bounds check beyond the slice's).
    pub fn get(&self, x: u32, y: u32) -> f32 {
        let i = (y * self.width + x) as usize;
        match &self.pixels {
            Pixels::U8(v) => f32::from(v[i]),
            Pixels::U16(v) => f32::from(v[i]),
        }
    }

    /// Read an image file; colour images are converted to luma, palette BMPs are expanded.
    pub fn load(path: &Path) -> Result<GrayImage> {
        let reader = image::ImageReader::open(path)
            .map_err(|e| Error::io(path, e))?
            .with_guessed_format()
            .map_err(|e| Error::io(path, e))?;
        let img = reader.decode().map_err(|e| Error::Image {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        let (w, h) = (img.width(), img.height());
        use image::DynamicImage as D;
        Ok(match img {
            D::ImageLuma8(b) => GrayImage::from_u8(w, h, b.into_raw()),
            D::ImageLuma16(b) => GrayImage::from_u16(w, h, b.into_raw()),
            D::ImageLumaA16(_) | D::ImageRgb16(_) | D::ImageRgba16(_) => {
                GrayImage::from_u16(w, h, img.into_luma16().into_raw())
            }
            other => GrayImage::from_u8(w, h, other.into_luma8().into_raw()),
        })
    }

    /// Write as PNG (8 or 16 bit, as stored) through a temporary file and a rename.
    pub fn save_png(&self, path: &Path) -> Result<()> {
        let mut buf = Vec::new();
        let enc = image::codecs::png::PngEncoder::new(&mut buf);
        use image::ImageEncoder;
        let res = match &self.pixels {
            Pixels::U8(v) => {
                enc.write_image(v, self.width, self.height, image::ExtendedColorType::L8)
            }
            Pixels::U16(v) => {
                let bytes: Vec<u8> = v.iter().flat_map(|p| p.to_ne_bytes()).collect();
                enc.write_image(
                    &bytes,
                    self.width,
                    self.height,
                    image::ExtendedColorType::L16,
                )
            }
        };
        res.map_err(|e| Error::Image {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        write_atomic(path, &buf)
    }
}

/// An 8-bit RGB image encoded as PNG in memory.
pub fn encode_rgb_png(width: u32, height: u32, rgb: &[u8]) -> Result<Vec<u8>> {
    let mut buf = Vec::new();
    use image::codecs::png::{CompressionType, FilterType, PngEncoder};
    use image::ImageEncoder;
    // Fast deflate over the `Sub` filter: pictures drawn live (a stream's every frame) cost a
    // few milliseconds instead of tens; they are somewhat larger than the tightest encoding.
    PngEncoder::new_with_quality(&mut buf, CompressionType::Fast, FilterType::Sub)
        .write_image(rgb, width, height, image::ExtendedColorType::Rgb8)
        .map_err(|e| Error::Image {
            path: std::path::PathBuf::from("(in memory)"),
            message: e.to_string(),
        })?;
    Ok(buf)
}

/// Write an 8-bit RGB image as PNG through a temporary file and a rename.
pub fn save_rgb_png(path: &Path, width: u32, height: u32, rgb: &[u8]) -> Result<()> {
    let buf = encode_rgb_png(width, height, rgb).map_err(|e| match e {
        Error::Image { message, .. } => Error::Image {
            path: path.to_path_buf(),
            message,
        },
        other => other,
    })?;
    write_atomic(path, &buf)
}

/// Separable Gaussian blur of a row-major f32 image (σ in pixels, kernel ±3σ, edges clamped);
/// rows run in parallel.
pub fn gaussian_blur(data: &[f32], width: usize, height: usize, sigma: f32) -> Vec<f32> {
    let (mut tmp, mut out) = (Vec::new(), Vec::new());
    gaussian_blur_into(data, width, height, sigma, &mut tmp, &mut out);
    out
}

/// [`gaussian_blur`] into `out`, with `tmp` for the horizontal pass: both keep their memory
/// between calls, which spares a frame-sized allocation (and its page faults) per frame.
pub fn gaussian_blur_into(
    data: &[f32],
    width: usize,
    height: usize,
    sigma: f32,
    tmp: &mut Vec<f32>,
    out: &mut Vec<f32>,
) {
    use rayon::prelude::*;
    debug_assert_eq!(data.len(), width * height);
    out.clear();
    if sigma <= 0.0 || width == 0 || height == 0 {
        out.extend_from_slice(data);
        return;
    }
    let r = (3.0 * sigma).ceil() as isize;
    let mut kernel: Vec<f32> = (-r..=r)
        .map(|i| (-(i * i) as f32 / (2.0 * sigma * sigma)).exp())
        .collect();
    let sum: f32 = kernel.iter().sum();
    kernel.iter_mut().for_each(|k| *k /= sum);
    let clamp = |i: isize, n: usize| i.clamp(0, n as isize - 1) as usize;
    let pad = r as usize;
    tmp.resize(data.len(), 0.0);
    // Each row padded with its edge values, then one multiply-add sweep per kernel tap (the
    // same sums, in the same order, as a per-pixel dot product, but vectorised).
    tmp.par_chunks_mut(width)
        .zip(data.par_chunks(width))
        .for_each_init(Vec::new, |padded, (out, row)| {
            padded.clear();
            padded.extend(std::iter::repeat_n(row[0], pad));
            padded.extend_from_slice(row);
            padded.extend(std::iter::repeat_n(row[width - 1], pad));
            out.fill(0.0);
            for (k, w) in kernel.iter().enumerate() {
                for (o, s) in out.iter_mut().zip(&padded[k..k + width]) {
                    *o += w * s;
                }
            }
        });
    let tmp = &tmp[..];
    out.resize(data.len(), 0.0);
    out.par_chunks_mut(width).enumerate().for_each(|(y, row)| {
        row.fill(0.0);
        for (k, w) in kernel.iter().enumerate() {
            let src = &tmp[clamp(y as isize + k as isize - r, height) * width..][..width];
            for (o, s) in row.iter_mut().zip(src) {
                *o += w * s;
            }
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn png_round_trip_8_and_16_bit() {
        let dir = tempfile::tempdir().expect("tempdir");
        let a = GrayImage::from_u8(3, 2, vec![0, 1, 2, 253, 254, 255]);
        let b = GrayImage::from_u16(2, 2, vec![0, 1, 40000, 65535]);
        for (name, img) in [("a.png", &a), ("b.png", &b)] {
            let p = dir.path().join(name);
            img.save_png(&p).expect("save");
            assert_eq!(&GrayImage::load(&p).expect("load"), img);
        }
    }

    #[test]
    fn tiff_and_jpeg_and_colour_input_become_luma() {
        let dir = tempfile::tempdir().expect("tempdir");
        let (w, h) = (16u32, 8u32);
        let gray: Vec<u8> = (0..w * h).map(|i| (i * 2) as u8).collect();
        let img = image::GrayImage::from_raw(w, h, gray.clone()).expect("buffer");
        let tiff = dir.path().join("a.tiff");
        img.save(&tiff).expect("tiff");
        assert_eq!(
            GrayImage::load(&tiff).expect("load tiff"),
            GrayImage::from_u8(w, h, gray.clone())
        );
        let wide = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_fn(w, h, |x, y| {
            image::Luma([(x * 1000 + y) as u16])
        });
        let tiff16 = dir.path().join("b.tif");
        wide.save(&tiff16).expect("tiff16");
        let back = GrayImage::load(&tiff16).expect("load 16-bit tiff");
        assert_eq!(back.bit_depth(), 16);
        assert_eq!(back.get(3, 2), 3002.0);
        // JPEG is lossy: smooth content comes back within a few grey levels.
        let jpg = dir.path().join("c.jpg");
        img.save(&jpg).expect("jpeg");
        let back = GrayImage::load(&jpg).expect("load jpeg");
        assert!((0..w).all(|x| (back.get(x, 4) - gray[(4 * w + x) as usize] as f32).abs() <= 6.0));
        // Colour PNG → luma.
        let rgb = image::RgbImage::from_pixel(4, 4, image::Rgb([100, 100, 100]));
        let p = dir.path().join("rgb.png");
        rgb.save(&p).expect("rgb");
        assert_eq!(GrayImage::load(&p).expect("load rgb").get(1, 1), 100.0);
    }

    #[test]
    fn unreadable_file_names_the_path() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("broken.png");
        std::fs::write(&p, b"not a png").expect("write");
        let msg = GrayImage::load(&p).expect_err("must fail").to_string();
        assert!(msg.contains("broken.png"), "{msg}");
    }

    #[test]
    fn gaussian_blur_preserves_mass_and_spreads_an_impulse() {
        let (w, h) = (31, 21);
        let mut img = vec![0.0f32; w * h];
        img[10 * w + 15] = 100.0;
        let out = gaussian_blur(&img, w, h, 2.0);
        let total: f32 = out.iter().sum();
        assert!((total - 100.0).abs() < 1e-3, "{total}");
        // The centre keeps 1/(2πσ²) of the mass; the profile is symmetric.
        let c = out[10 * w + 15];
        assert!(
            (c - 100.0 / (2.0 * std::f32::consts::PI * 4.0)).abs() < 0.05,
            "{c}"
        );
        assert!((out[10 * w + 13] - out[10 * w + 17]).abs() < 1e-5);
        assert!((out[8 * w + 15] - out[12 * w + 15]).abs() < 1e-5);
    }
}
