//! Pixel formats of V4L2 cameras converted to the gray images RIS decodes. Rows may be padded
//! (`stride` bytes per row); short or malformed buffers are errors, never panics.

use ris_core::image::GrayImage;

/// The pixel formats RIS takes from a V4L2 camera, by FourCC.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PixelFormat {
    /// 8-bit gray (`GREY`).
    Grey,
    /// 16-bit little-endian gray (`Y16 `).
    Y16,
    /// 4:2:2 packed Y Cb Y Cr (`YUYV`): the luma is the gray image.
    Yuyv,
    /// Motion JPEG (`MJPG`): each frame a JPEG, decoded to luma.
    Mjpeg,
}

impl PixelFormat {
    /// The format of a FourCC, if RIS takes it.
    pub fn from_fourcc(code: &[u8; 4]) -> Option<PixelFormat> {
        match code {
            b"GREY" => Some(PixelFormat::Grey),
            b"Y16 " => Some(PixelFormat::Y16),
            b"YUYV" => Some(PixelFormat::Yuyv),
            b"MJPG" => Some(PixelFormat::Mjpeg),
            _ => None,
        }
    }

    /// The FourCC.
    pub fn fourcc(self) -> [u8; 4] {
        match self {
            PixelFormat::Grey => *b"GREY",
            PixelFormat::Y16 => *b"Y16 ",
            PixelFormat::Yuyv => *b"YUYV",
            PixelFormat::Mjpeg => *b"MJPG",
        }
    }

    /// Preference for measurement: more bits first, lossless before lossy.
    pub fn rank(self) -> u8 {
        match self {
            PixelFormat::Y16 => 0,
            PixelFormat::Grey => 1,
            PixelFormat::Yuyv => 2,
            PixelFormat::Mjpeg => 3,
        }
    }

    /// Significant bits of the converted image.
    pub fn bit_depth(self) -> u8 {
        match self {
            PixelFormat::Y16 => 16,
            _ => 8,
        }
    }

    /// Bytes per row without padding, for the uncompressed formats.
    pub fn min_stride(self, width: u32) -> Option<usize> {
        match self {
            PixelFormat::Grey => Some(width as usize),
            PixelFormat::Y16 | PixelFormat::Yuyv => Some(2 * width as usize),
            PixelFormat::Mjpeg => None,
        }
    }
}

/// Why a buffer could not be converted.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ConvertError(pub String);

impl std::fmt::Display for ConvertError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for ConvertError {}

/// Convert one buffer of `format` (`width` × `height`, rows `stride` bytes apart; 0 = packed)
/// to a gray image.
pub fn to_gray(
    format: PixelFormat,
    width: u32,
    height: u32,
    stride: usize,
    data: &[u8],
) -> Result<GrayImage, ConvertError> {
    if width == 0 || height == 0 {
        return Err(ConvertError(format!("frame size {width}x{height}")));
    }
    let (w, h) = (width as usize, height as usize);
    if format == PixelFormat::Mjpeg {
        return mjpeg(width, height, data);
    }
    let min = format.min_stride(width).unwrap_or(w);
    let stride = if stride == 0 { min } else { stride };
    if stride < min {
        return Err(ConvertError(format!(
            "{format:?}: stride {stride} < {min} bytes for width {width}"
        )));
    }
    let need = stride * (h - 1) + min;
    if data.len() < need {
        return Err(ConvertError(format!(
            "{format:?} {width}x{height}: buffer of {} bytes, need {need}",
            data.len()
        )));
    }
    let rows = (0..h).map(|y| &data[y * stride..y * stride + min]);
    Ok(match format {
        PixelFormat::Grey => {
            let mut px = Vec::with_capacity(w * h);
            rows.for_each(|r| px.extend_from_slice(r));
            GrayImage::from_u8(width, height, px)
        }
        PixelFormat::Yuyv => {
            let mut px = Vec::with_capacity(w * h);
            rows.for_each(|r| px.extend(r.iter().step_by(2)));
            GrayImage::from_u8(width, height, px)
        }
        PixelFormat::Y16 => {
            let mut px = Vec::with_capacity(w * h);
            rows.for_each(|r| {
                px.extend(r.chunks_exact(2).map(|b| u16::from_le_bytes([b[0], b[1]])))
            });
            GrayImage::from_u16(width, height, px)
        }
        PixelFormat::Mjpeg => unreachable!("handled above"),
    })
}

fn mjpeg(width: u32, height: u32, data: &[u8]) -> Result<GrayImage, ConvertError> {
    let img = image::load_from_memory_with_format(data, image::ImageFormat::Jpeg)
        .map_err(|e| ConvertError(format!("MJPEG frame: {e}")))?;
    if (img.width(), img.height()) != (width, height) {
        return Err(ConvertError(format!(
            "MJPEG frame is {}x{}, the stream {width}x{height}",
            img.width(),
            img.height()
        )));
    }
    Ok(GrayImage::from_u8(width, height, img.to_luma8().into_raw()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use ris_core::image::Pixels;

    fn u8s(img: &GrayImage) -> &[u8] {
        match &img.pixels {
            Pixels::U8(v) => v,
            Pixels::U16(_) => panic!("expected 8-bit"),
        }
    }

    #[test]
    fn grey_and_yuyv_keep_the_luma_and_skip_row_padding() {
        // 3×2 GREY with 5-byte rows.
        let data = [1, 2, 3, 0, 0, 4, 5, 6];
        let g = to_gray(PixelFormat::Grey, 3, 2, 5, &data).expect("grey");
        assert_eq!(u8s(&g), &[1, 2, 3, 4, 5, 6]);
        // 2×2 YUYV packed: Y0 U Y1 V.
        let data = [10, 128, 20, 128, 30, 99, 40, 77];
        let y = to_gray(PixelFormat::Yuyv, 2, 2, 0, &data).expect("yuyv");
        assert_eq!(u8s(&y), &[10, 20, 30, 40]);
    }

    #[test]
    fn y16_is_little_endian_sixteen_bit() {
        let data = [0x34, 0x12, 0xff, 0xff, 0x00, 0x01, 0x02, 0x00];
        let g = to_gray(PixelFormat::Y16, 2, 2, 4, &data).expect("y16");
        match &g.pixels {
            Pixels::U16(v) => assert_eq!(v, &[0x1234, 0xffff, 0x0100, 0x0002]),
            Pixels::U8(_) => panic!("expected 16-bit"),
        }
        assert_eq!(PixelFormat::Y16.bit_depth(), 16);
    }

    #[test]
    fn mjpeg_decodes_to_luma() {
        // A gray ramp, JPEG-encoded at high quality, comes back within JPEG's error.
        let (w, h) = (64u32, 48u32);
        let ramp: Vec<u8> = (0..w * h).map(|i| ((i % w) * 4) as u8).collect();
        let mut jpeg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 95)
            .encode(&ramp, w, h, image::ExtendedColorType::L8)
            .expect("encode");
        let g = to_gray(PixelFormat::Mjpeg, w, h, 0, &jpeg).expect("mjpeg");
        let worst = u8s(&g)
            .iter()
            .zip(&ramp)
            .map(|(a, b)| a.abs_diff(*b))
            .max()
            .expect("pixels");
        assert!(worst <= 4, "JPEG error {worst}");
        let e = to_gray(PixelFormat::Mjpeg, w + 1, h, 0, &jpeg).expect_err("size");
        assert!(e.0.contains("64x48"), "{e}");
    }

    #[test]
    fn short_or_malformed_buffers_are_errors() {
        let e = to_gray(PixelFormat::Yuyv, 4, 2, 0, &[0; 15]).expect_err("short");
        assert!(e.0.contains("need 16"), "{e}");
        assert!(
            to_gray(PixelFormat::Grey, 4, 2, 3, &[0; 64]).is_err(),
            "stride < width"
        );
        assert!(to_gray(PixelFormat::Grey, 0, 2, 0, &[]).is_err());
        assert!(to_gray(PixelFormat::Mjpeg, 4, 4, 0, b"not a jpeg").is_err());
    }

    #[test]
    fn fourccs_round_trip_and_rank_by_fidelity() {
        for f in [
            PixelFormat::Grey,
            PixelFormat::Y16,
            PixelFormat::Yuyv,
            PixelFormat::Mjpeg,
        ] {
            assert_eq!(PixelFormat::from_fourcc(&f.fourcc()), Some(f));
        }
        assert_eq!(PixelFormat::from_fourcc(b"RGB3"), None);
        assert!(PixelFormat::Y16.rank() < PixelFormat::Grey.rank());
        assert!(PixelFormat::Yuyv.rank() < PixelFormat::Mjpeg.rank());
    }
}
