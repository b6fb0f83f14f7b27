//! The cli crate's integration tests in one binary (one module per concern), so the
//! shared helpers and their dependencies' generic code are compiled and linked once.

#[path = "../../../daemon/tests/common/mod.rs"]
mod common;

mod cli;
mod experiment;
mod interop;
mod scan_client;
