//! RIS core: the pure algorithms of a structured-light measurement cell.
//!
//! Nothing here talks to hardware. The modules follow the data flow of a scan:
//! [`pattern`] (what the projector shows) → [`capture`] (what the camera saw, on disk) →
//! [`decode`] (camera pixel → sub-pixel projector coordinate) → [`sensor`] (coordinates → 3D
//! points, plane-induced parallax or classical triangulation) → [`cloud`] (PLY). [`sim`] renders
//! captures of known scenes so that every stage can be checked against ground truth.
//! Conventions (frames, units, pixel centres) are those of the project's SPEC §2.

pub mod budget;
pub mod calibrate;
pub mod capture;
pub mod cloud;
pub mod decode;
mod disjoint_sets;
pub mod error;
pub mod geometry;
pub mod image;
pub mod inspect;
pub mod io;
pub mod mask;
pub mod mesh;
pub mod omni;
pub mod pattern;
pub mod register;
pub mod sensor;
pub mod sim;
pub mod single_shot;
pub mod spatial;
pub mod verify;

// The shared test helpers name this crate as the integration tests do.
#[cfg(test)]
extern crate self as ris_core;

/// The seeded generator the integration tests use, for the unit tests' families of cases.
#[cfg(test)]
#[path = "../tests/common/mod.rs"]
mod testing;

pub use error::{Error, Result};
