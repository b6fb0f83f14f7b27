//! GigE Vision and USB3 Vision cameras through Aravis 0.8 (feature `aravis`, Debian
//! `libaravis-dev`). [`AravisCamera`] implements [`ris_drivers::Camera`]: open by IP address
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

/// Whether this build includes the Aravis backend.
pub const AVAILABLE: bool = cfg!(feature = "aravis");
