//! The daemon crate's integration tests in one binary (one module per concern), so the
//! shared helpers and their dependencies' generic code are compiled and linked once.

#[path = "../common/mod.rs"]
mod common;

mod access;
mod adaptive;
mod hardening;
mod inspected_surface;
mod omni;
mod replay;
mod report_page;
mod risd;
mod ros2;
mod service;
mod stream;
mod stream_faults;
mod verification;
