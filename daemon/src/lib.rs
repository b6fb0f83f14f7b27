//! The RIS daemon crate: the `risd` cell daemon and the `ris` command-line tool.
//!
//! Binaries under `src/bin/` only parse arguments and set up logging; every command's logic is a
//! function in [`commands`] so tests can call it directly.

pub mod cell;
pub mod commands;
pub mod config;
pub mod logging;
pub mod notify;
pub mod page;
pub mod pair;
pub mod prepared;
pub mod progress;
pub mod protocol;
pub mod ros2;
pub mod scan;
pub mod service;
pub mod single_shot;
pub mod store;
pub mod stream;
