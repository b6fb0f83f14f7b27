//! V4L2 cameras (USB/UVC and other Linux capture devices) for RIS: pixel formats GREY, Y16,
//! YUYV and MJPEG converted to gray ([`convert`]), exposure and gain mapped onto the device's
//! controls ([`controls`]), and with the cargo feature `v4l2` the [`Camera`](ris_drivers::Camera)
//! over mmap streaming.

pub mod controls;
pub mod convert;

#[cfg(feature = "v4l2")]
mod camera;

#[cfg(feature = "v4l2")]
pub use camera::{devices, V4l2Camera};

/// Whether this build can open V4L2 devices.
pub const AVAILABLE: bool = cfg!(feature = "v4l2");
