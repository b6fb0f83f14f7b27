//! Camera frames.

use ris_core::image::GrayImage;

/// One frame delivered by a camera.
#[derive(Clone, Debug)]
pub struct Frame {
    /// The pixels (8 or 16 bit; see `bit_depth` for the significant bits).
    pub image: GrayImage,
    /// Significant bits per sample (8, 10, 12, 16).
    pub bit_depth: u8,
    /// The camera's frame counter; consecutive exposures have consecutive ids.
    pub frame_id: u64,
    /// When the host received the frame, [`crate::clock::now_ns`].
    pub host_ns: u64,
    /// The device's own timestamp, ns (its clock, not comparable to the host's).
    pub device_ns: u64,
    /// Exposure time, µs.
    pub exposure_us: f64,
    /// Analogue gain, dB.
    pub gain_db: f64,
}

impl Frame {
    /// Width, pixels.
    pub fn width(&self) -> u32 {
        self.image.width
    }

    /// Height, pixels.
    pub fn height(&self) -> u32 {
        self.image.height
    }
}
