//! What a pair's devices are opened with: one description of a camera and one of a projector,
//! built from the cell configuration and the sensor file, that every backend takes. A backend
//! built without its cargo feature answers [`unavailable`] instead of a device.

use crate::{Camera, DriverError, ErrorKind, Result, TriggerMode};

/// How to open and set up a pair's camera.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraSettings {
    /// Device: IP address or id (GigE Vision), path (V4L2).
    pub device: String,
    /// Image size the sensor was calibrated at (a region of interest at the origin); the
    /// camera must deliver exactly this.
    pub size: (u32, u32),
    /// Exposure, µs.
    pub exposure_us: f64,
    /// Analogue gain, dB (`None` keeps the device's).
    pub gain_db: Option<f64>,
    /// How exposures start: software trigger after each present, or the projector's sync
    /// output wired to a camera line.
    pub trigger: TriggerMode,
}

/// How to open a pair's projector.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ProjectorSettings {
    /// Monitor index, in the display server's monitor list (`xrandr --listmonitors` order).
    pub monitor: u32,
    /// Native width, pixels.
    pub width: u32,
    /// Native height, pixels.
    pub height: u32,
}

/// The error of a backend left out of this build: it names the cargo feature that brings it.
pub fn unavailable(backend: &str, device: &str, feature: &str) -> DriverError {
    DriverError::new(
        ErrorKind::Unsupported,
        device,
        format!(
            "this build has no {backend} backend; rebuild with `--features {feature}` \
             (cargo build --release --features {feature})"
        ),
    )
}

/// Apply exposure, gain and trigger of `settings` to an opened camera and check its size.
pub fn configure(camera: &mut dyn Camera, settings: &CameraSettings) -> Result<()> {
    let info = camera.info().clone();
    if (info.width, info.height) != settings.size {
        return Err(DriverError::new(
            ErrorKind::InvalidArgument,
            &info.id,
            format!(
                "delivers {}x{} images, the sensor file is calibrated for {}x{}",
                info.width, info.height, settings.size.0, settings.size.1
            ),
        ));
    }
    camera.set_exposure_us(settings.exposure_us)?;
    if let Some(g) = settings.gain_db {
        camera.set_gain_db(g)?;
    }
    camera.set_trigger(settings.trigger.clone())?;
    Ok(())
}
