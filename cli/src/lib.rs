//! The `ris` command. `src/main.rs` only parses arguments and sets up logging; every command's
//! logic is a function in [`commands`] so tests can call it directly. The commands that talk to
//! a running risd use its protocol (`ris_daemon::protocol`) and nothing else of it.

pub mod commands;
pub mod progress;
