//! The camera trait.

use std::time::Duration;

use crate::{Frame, Result};

/// How exposures are started.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum TriggerMode {
    /// The camera runs at its own frame rate.
    FreeRun,
    /// Each [`Camera::trigger`] call starts one exposure.
    Software,
    /// A hardware line starts each exposure (e.g. the projector's vsync on `Line0`).
    Hardware {
        /// Trigger source as the device names it.
        source: String,
    },
}

/// What a camera is.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CameraInfo {
    /// Stable id (serial, IP address, device path).
    pub id: String,
    /// Vendor and model.
    pub model: String,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Significant bits per sample.
    pub bit_depth: u8,
}

/// A camera: configure, stream, trigger, receive frames. Implementations are `Send` so a pair
/// can run on its own thread.
pub trait Camera: Send {
    /// Identity and image format.
    fn info(&self) -> &CameraInfo;
    /// Set the exposure time, µs.
    fn set_exposure_us(&mut self, us: f64) -> Result<()>;
    /// The exposure time in effect, µs.
    fn exposure_us(&self) -> f64;
    /// Set the analogue gain, dB.
    fn set_gain_db(&mut self, db: f64) -> Result<()>;
    /// Select the trigger mode (only while not streaming).
    fn set_trigger(&mut self, mode: TriggerMode) -> Result<()>;
    /// Start streaming (allocate buffers, arm the trigger).
    fn start(&mut self) -> Result<()>;
    /// Stop streaming; queued frames are discarded.
    fn stop(&mut self) -> Result<()>;
    /// Start one exposure (software trigger mode).
    fn trigger(&mut self) -> Result<()>;
    /// The next frame, waiting at most `timeout`; `Duration::ZERO` only takes a queued one.
    fn next_frame(&mut self, timeout: Duration) -> Result<Frame>;
    /// Re-open the device after a disconnect, restoring its settings.
    fn reconnect(&mut self) -> Result<()>;
}
