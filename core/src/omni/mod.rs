//! The omnidirectional sensor (Ch. 6, SPEC §13): a camera and a projector, each a pinhole behind
//! a hyperbolic mirror, seeing a whole room around a robot in one shot.

pub mod analysis;
pub mod calibrate;
pub mod decode;
pub mod file;
pub mod fit;
pub mod lut;
pub mod mirror;
pub mod panorama;
pub mod render;
pub mod rings;
pub mod scene;

pub use analysis::{analyse, ErrorPoint};
pub use decode::{Ambiguous, RingDecode, RingDecoder, RingParams, RingPoint};
pub use file::{OmniFile, OmniSensor};
pub use lut::RayTable;
pub use mirror::{Mirror, MirrorUnit, Ray};
pub use panorama::{panorama, Panorama};
pub use render::{render, Exposure, OmniTruth, Room};
pub use rings::RingPattern;
