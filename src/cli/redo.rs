//! `filmback redo STEM... [--state DIR]`: develop finished brackets again.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use filmback::atomic::{self, Overwrite};
use filmback::daemon::journal;
use filmback::daemon::{self, REDO_FOLDER};

/// Arguments of `filmback redo`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Output stems of finished brackets or singles (`out/<STEM>.exr`, as `filmback
    /// status` and the log name them).
    #[arg(required = true, value_name = "STEM")]
    stems: Vec<String>,
    /// State folder of the daemon.
    #[arg(long, value_name = "DIR", default_value = ".filmback")]
    state: PathBuf,
}

/// Leaves one request per stem in `state/redo/`; the daemon develops each bracket again
/// from its inputs (which must still be in the ingest folder, unchanged) and replaces its
/// outputs.
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let entries = journal::read(&args.state)?;
    let dir = args.state.join(REDO_FOLDER);
    // All or nothing: every stem is checked before any request is left.
    let mut found = Vec::with_capacity(args.stems.len());
    for stem in &args.stems {
        if stem.is_empty() || stem.contains('/') || stem.starts_with('.') {
            anyhow::bail!("{stem:?}: not an output stem; nothing queued");
        }
        let Some(entry) = entries
            .iter()
            .rev()
            .find(|e| e.output_stem().as_deref() == Some(stem.as_str()))
        else {
            anyhow::bail!(
                "{stem}: no finished bracket or single of that name in {} (`filmback status` lists the state); nothing queued",
                args.state.join(journal::FILE_NAME).display()
            );
        };
        found.push((stem, entry));
    }
    std::fs::create_dir_all(&dir).with_context(|| format!("{}", dir.display()))?;
    let running = daemon::lock_held(&args.state)
        .unwrap_or_else(|| daemon::read_snapshot(&args.state).is_some_and(|s| s.running));
    for (stem, entry) in found {
        atomic::publish(&dir.join(stem), b"", Overwrite::Replace)?;
        println!(
            "{stem}: {} frame(s) queued to develop again {}",
            entry.inputs().len(),
            if running {
                "now"
            } else {
                "when the daemon next runs"
            }
        );
    }
    Ok(ExitCode::SUCCESS)
}
