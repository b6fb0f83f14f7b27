//! RIS acquisition layer: what a sensor pair is to the rest of the system.
//!
//! [`Camera`] and [`Projector`] are the traits every backend implements (the simulated and
//! replay [`mock`] here; GigE Vision, V4L2 and the projector window in their own crates).
//! Errors carry a generic [`ErrorKind`] so callers decide to retry without knowing the backend.
//! The [`sequence`] module drives one pair through a pattern sequence and proves that every
//! frame it records belongs to the pattern it is filed under.

pub mod adaptive;
pub mod camera;
pub mod clock;
pub mod conformance;
pub mod device;
pub mod error;
pub mod frame;
pub mod mock;
pub mod projector;
pub mod sequence;

pub use camera::{Camera, CameraInfo, TriggerMode};
pub use device::{CameraSettings, ProjectorSettings};
pub use error::{DriverError, ErrorKind, Result};
pub use frame::Frame;
pub use projector::{Projector, ProjectorInfo, Shown, Slide};
