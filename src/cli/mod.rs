//! Command-line parsing and dispatch. Each subcommand lives in its own file and turns the
//! library's typed errors into messages at this edge (`anyhow`).

use std::process::ExitCode;

use clap::{Parser, Subcommand};

mod calibrate;
mod inspect;
mod merge;

/// filmback: brackets from a tethered camera to HDR radiance maps and film renderings.
#[derive(Debug, Parser)]
#[command(name = "filmback", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Recover the camera's inverse response from two exposures' histograms.
    Calibrate(calibrate::Args),
    /// Show each frame's size, depth, camera, exposure and capture time.
    Inspect(inspect::Args),
    /// Merge a bracket into one OpenEXR radiance map.
    Merge(merge::Args),
}

/// Parses the command line, runs the subcommand, and reports errors on stderr.
pub fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Calibrate(args) => calibrate::run(args),
        Command::Inspect(args) => inspect::run(args),
        Command::Merge(args) => merge::run(args),
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("filmback: {e:#}");
            ExitCode::FAILURE
        }
    }
}
