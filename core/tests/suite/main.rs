//! The core crate's integration tests in one binary (one module per concern), so the
//! shared helpers and their dependencies' generic code are compiled and linked once.

#[path = "../common/mod.rs"]
mod common;

mod acceptance_scenes;
mod bad_input;
mod calibrated_volume;
mod camera_calibration;
mod cell_calibration;
mod coarse_alignment;
mod conditioning;
mod crossing_bias;
mod curved_surfaces;
mod datum_frame;
mod decode_exact;
mod e57;
mod inspection;
mod mesh_formats;
mod organised;
mod real_data;
mod registration;
mod rim_panels;
mod sensor_calibration;
mod sim_reconstruct;
mod sim_variations;
mod single_shot;
mod step_cad;
mod xpoint_pattern;
