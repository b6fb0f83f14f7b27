//! GigE Vision and USB3 Vision cameras through Aravis 0.8 (feature `aravis`, Debian
//! `libaravis-dev`). `AravisCamera` implements [`ris_drivers::Camera`]: open by IP address
//! (direct, no discovery broadcast), by device id, or Aravis's in-process fake camera; Mono8 and
//! Mono16, region of interest, exposure, gain, software or hardware-line trigger, a stream with a
//! buffer pool, frame ids and timestamps, packet size and inter-packet delay, timeouts and
//! disconnects as typed errors, reconnect.

#[cfg(feature = "aravis")]
mod camera;

#[cfg(feature = "aravis")]
mod loopback;

#[cfg(feature = "aravis")]
pub use camera::{discover, AravisCamera, DeviceSpec, OpenOptions, PixelDepth};
#[cfg(feature = "aravis")]
pub use loopback::{Fill, LoopbackCamera};

/// Serialises the unit tests that create Aravis fake cameras: two at once in one process
/// (the in-process fake and the loopback GigE Vision one) fail at random, a feature or the
/// stream channel missing, since the fake's shared state is not guarded.
#[cfg(all(test, feature = "aravis"))]
pub(crate) static FAKE_CAMERAS: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// Whether this build includes the Aravis backend.
pub const AVAILABLE: bool = cfg!(feature = "aravis");

/// Open the camera of a pair from its settings (an IP address opens it directly, `fake` the
/// in-process fake, anything else is a device id), set to the calibrated size as a region of
/// interest at the origin, with exposure, gain and trigger applied.
pub fn open_camera(
    settings: &ris_drivers::CameraSettings,
) -> ris_drivers::Result<Box<dyn ris_drivers::Camera>> {
    #[cfg(feature = "aravis")]
    {
        let (w, h) = settings.size;
        let mut camera = AravisCamera::open(
            DeviceSpec::parse(&settings.device),
            OpenOptions {
                roi: Some((0, 0, w as i32, h as i32)),
                ..OpenOptions::default()
            },
        )?;
        ris_drivers::device::configure(&mut camera, settings)?;
        Ok(Box::new(camera))
    }
    #[cfg(not(feature = "aravis"))]
    {
        Err(ris_drivers::device::unavailable(
            "GigE Vision (Aravis)",
            &settings.device,
            "aravis",
        ))
    }
}
