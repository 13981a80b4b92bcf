//! What the integration tests share.

use std::process::Command;

/// The `filmback` binary Cargo built for these tests.
pub fn filmback() -> Command {
    Command::new(env!("CARGO_BIN_EXE_filmback"))
}
