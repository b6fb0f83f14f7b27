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

/// Open the camera of a pair from its settings (a device path such as `/dev/video0`) at the
/// calibrated size, with exposure, gain and trigger applied.
pub fn open_camera(
    settings: &ris_drivers::CameraSettings,
) -> ris_drivers::Result<Box<dyn ris_drivers::Camera>> {
    #[cfg(feature = "v4l2")]
    {
        let mut camera = V4l2Camera::open(
            std::path::Path::new(&settings.device),
            Some(settings.size),
            None,
        )?;
        ris_drivers::device::configure(&mut camera, settings)?;
        Ok(Box::new(camera))
    }
    #[cfg(not(feature = "v4l2"))]
    {
        Err(ris_drivers::device::unavailable(
            "V4L2",
            &settings.device,
            "v4l2",
        ))
    }
}
