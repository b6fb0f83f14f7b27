//! The RIS cell daemon `risd`: the cell's configuration, its pairs prepared and scanned, the
//! Zenoh protocol and service, the scan store. `src/bin/risd.rs` only parses arguments; the `ris`
//! command-line tool (`cli/`) is a client of this crate's [`protocol`].

pub mod cell;
pub mod client;
pub mod config;
pub mod logging;
pub mod notify;
pub mod page;
pub mod pair;
pub mod prepared;
pub mod protocol;
pub mod ros2;
pub mod scan;
pub mod service;
pub mod single_shot;
pub mod store;
pub mod stream;
pub mod verification;
