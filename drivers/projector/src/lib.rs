//! The projector of a sensor pair as a full-screen window (SPEC §3): a borderless window on the
//! chosen monitor showing each slide with exact 1:1 pixels (an R8 texture read with
//! `textureLoad`, no sampling, a non-sRGB surface), every slide of a scan uploaded before the
//! scan, [`Projector::show`](ris_drivers::Projector::show) returning once the frame is
//! presented. Behind the cargo feature `window` (winit + wgpu).

#[cfg(feature = "window")]
mod window;

#[cfg(feature = "window")]
pub use window::{WindowOptions, WindowProjector};

/// Whether this build can open projector windows.
pub const AVAILABLE: bool = cfg!(feature = "window");
