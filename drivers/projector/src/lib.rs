//! The projector of a sensor pair as a full-screen window (SPEC §3): a borderless window on the
//! chosen monitor showing each slide with exact 1:1 pixels (an R8 texture read with
//! `textureLoad`, no sampling, a non-sRGB surface), every slide of a scan uploaded before the
//! scan, [`Projector::show`](ris_drivers::Projector::show) returning once the frame is
//! presented. Behind the cargo feature `window` (winit + wgpu).

#[cfg(feature = "window")]
mod connection;
#[cfg(feature = "window")]
pub mod screen;
#[cfg(feature = "window")]
mod window;
pub mod xvfb;

#[cfg(feature = "window")]
pub use window::{WindowOptions, WindowProjector};

/// Whether this build can open projector windows.
pub const AVAILABLE: bool = cfg!(feature = "window");

/// Open the projector of a pair from its settings: a full-screen window on monitor
/// `settings.monitor`, which must have the projector's native size.
pub fn open_projector(
    settings: &ris_drivers::ProjectorSettings,
) -> ris_drivers::Result<Box<dyn ris_drivers::Projector>> {
    #[cfg(feature = "window")]
    {
        Ok(Box::new(WindowProjector::open(&WindowOptions {
            width: settings.width,
            height: settings.height,
            monitor: settings.monitor as usize,
        })?))
    }
    #[cfg(not(feature = "window"))]
    {
        Err(ris_drivers::device::unavailable(
            "projector window",
            &format!("monitor {}", settings.monitor),
            "projector",
        ))
    }
}
