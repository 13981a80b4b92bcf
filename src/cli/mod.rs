//! Command-line parsing and dispatch. Each subcommand lives in its own file and turns the
//! library's typed errors into messages at this edge (`anyhow`).

use std::process::ExitCode;

use clap::{Parser, Subcommand};

mod cache;
mod calibrate;
mod canvas;
mod check_config;
mod films;
mod hook;
mod inspect;
mod looks;
mod merge;
mod plan;
mod redo;
mod render;
mod run;
mod status;
mod watch;

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
    /// List film stocks, plot their curves (--plot), or make the contact sheet.
    Films(films::Args),
    /// Render an OpenEXR radiance map through film stocks and tone maps.
    Render(render::Args),
    /// Watch the ingest folder and develop every bracket that lands in it (the daemon).
    Watch(watch::Args),
    /// What the daemon has done and is doing: brackets, pending work, rejected files.
    Status(status::Args),
    /// Have the daemon develop finished brackets again (e.g. after deleting outputs).
    Redo(redo::Args),
    /// Validate a configuration file without starting.
    CheckConfig(check_config::Args),
    /// The per-camera response cache: list, show, reset.
    Cache(cache::Args),
    /// gphoto2 hook script: hand each finished download to the ingest folder atomically.
    Hook(hook::Args),
    /// Group a folder tree into a render-farm plan: one JSON line per bracket or single.
    Plan(plan::Args),
    /// Develop one task of a plan (a farm's array task); exit 0 done, 75 retry, 65 bad input.
    Run(run::Args),
}

/// Exit status when the reader of standard output went away (`filmback … | head -1`):
/// 128 + SIGPIPE, what the shell reports for a program the signal ended.
const BROKEN_PIPE: u8 = 141;

/// True for the panic `print!` raises when standard output is a closed pipe (Rust
/// ignores SIGPIPE, so the write fails with EPIPE and the macro panics).
fn is_broken_pipe_panic(info: &std::panic::PanicHookInfo<'_>) -> bool {
    let text = info
        .payload()
        .downcast_ref::<String>()
        .map(String::as_str)
        .or_else(|| info.payload().downcast_ref::<&str>().copied())
        .unwrap_or("");
    text.starts_with("failed printing to stdout") && text.contains("Broken pipe")
}

/// True when an error comes from writing to a closed pipe.
fn is_broken_pipe(e: &anyhow::Error) -> bool {
    e.chain().any(|c| {
        c.downcast_ref::<std::io::Error>()
            .is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe)
    })
}

/// Parses the command line, runs the subcommand, and reports errors on stderr. A closed
/// standard output ends any command quietly with status 141, as SIGPIPE would.
pub fn main() -> ExitCode {
    let default_hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        if is_broken_pipe_panic(info) {
            std::process::exit(i32::from(BROKEN_PIPE));
        }
        default_hook(info);
    }));
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => {
            // `--help`, `--version` and usage errors: clap prints them; a closed pipe
            // is not worth a message.
            let _ = e.print();
            return ExitCode::from(if e.use_stderr() { 2 } else { 0 });
        }
    };
    let result = match cli.command {
        Command::Calibrate(args) => calibrate::run(args),
        Command::Inspect(args) => inspect::run(args),
        Command::Merge(args) => merge::run(args),
        Command::Films(args) => films::run(args),
        Command::Render(args) => render::run(args),
        Command::Watch(args) => watch::run(args),
        Command::Status(args) => status::run(args),
        Command::Redo(args) => redo::run(args),
        Command::CheckConfig(args) => check_config::run(args),
        Command::Cache(args) => cache::run(args),
        Command::Hook(args) => hook::run(args),
        Command::Plan(args) => plan::run(args),
        Command::Run(args) => run::run(args),
    };
    match result {
        Ok(code) => code,
        Err(e) if is_broken_pipe(&e) => ExitCode::from(BROKEN_PIPE),
        Err(e) => {
            eprintln!("filmback: {}", chain_text(&e));
            ExitCode::FAILURE
        }
    }
}

/// An error and its causes joined by `": "`, each cause said once: the library's errors
/// already name their cause in their own message, so a cause that the text so far ends
/// with is not repeated.
fn chain_text(e: &anyhow::Error) -> String {
    let mut text = String::new();
    for cause in e.chain() {
        let part = cause.to_string();
        if text.ends_with(&part) {
            continue;
        }
        if !text.is_empty() {
            text.push_str(": ");
        }
        text.push_str(&part);
    }
    text
}

#[cfg(test)]
mod tests {
    use super::chain_text;

    #[derive(Debug, thiserror::Error)]
    #[error("channel R: {source}")]
    struct Channel {
        source: std::io::Error,
    }

    #[test]
    fn a_cause_already_in_the_message_is_said_once() {
        let inner = std::io::Error::other("frames swapped");
        let e = anyhow::Error::new(Channel { source: inner }).context("calibrating a.png");
        assert_eq!(
            chain_text(&e),
            "calibrating a.png: channel R: frames swapped"
        );
        let plain = anyhow::Error::new(std::io::Error::other("disk full")).context("writing x");
        assert_eq!(chain_text(&plain), "writing x: disk full");
    }
}
