//! `filmback hook`: gphoto2's `--hook-script`, handing each finished download to the
//! ingest folder.
//!
//! gphoto2 runs the hook script with the environment variable `ACTION` set to `init`,
//! `start`, `download` or `stop`, and for `download` with `ARGUMENT` set to the file it
//! has just finished saving (renamed from its `tmpfileXXXXXX` and given the capture time
//! as mtime). Only `download` does anything here: the file moves into the ingest folder
//! under its own name, whole or not at all, so the daemon never sees it partly written:
//! a link (on one file system) or a synced copy (across file systems) under a hidden
//! temporary name in the ingest folder (which the daemon never takes), renamed into place
//! by a rename that cannot replace anything, and then the old name removed
//! ([`atomic::move_into`]). An existing file
//! of that name in the ingest folder is never replaced: the hook fails naming both files
//! and leaves the download where it is.

use std::fs;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, bail};
use filmback::atomic::{self, PublishError};
use filmback::daemon::config::Config;

/// Arguments of `filmback hook`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The ingest folder the download is handed to.
    #[arg(long, value_name = "DIR", required_unless_present = "config")]
    ingest: Option<PathBuf>,
    /// A configuration file: its `[folders] ingest` receives the download.
    #[arg(long, value_name = "FILE", conflicts_with = "ingest")]
    config: Option<PathBuf>,
}

/// Runs one call of the hook, as gphoto2 makes it (`ACTION`, `ARGUMENT`).
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let Some(action) = std::env::var_os("ACTION") else {
        bail!(
            "ACTION is not set: `filmback hook` is run by `gphoto2 --capture-tethered --hook-script=SCRIPT` (see docs/service.md)"
        );
    };
    if action != "download" {
        return Ok(ExitCode::SUCCESS);
    }
    let source = std::env::var_os("ARGUMENT")
        .map(PathBuf::from)
        .filter(|p| !p.as_os_str().is_empty())
        .context("ACTION=download without ARGUMENT (the downloaded file)")?;
    let ingest = match (args.ingest, args.config) {
        (Some(dir), _) => dir,
        (None, Some(file)) => Config::load(&file)?.folders.ingest,
        (None, None) => unreachable!("clap requires --ingest or --config"),
    };
    let target = hand_over(&source, &ingest)?;
    println!("{} -> {}", source.display(), target.display());
    Ok(ExitCode::SUCCESS)
}

/// Moves `source` into `ingest` under its own name without ever replacing a file there
/// ([`atomic::move_into`]).
fn hand_over(source: &Path, ingest: &Path) -> anyhow::Result<PathBuf> {
    if !fs::metadata(ingest).is_ok_and(|m| m.is_dir()) {
        bail!("{}: the ingest folder does not exist", ingest.display());
    }
    if let Err(e) = fs::symlink_metadata(source)
        && e.kind() == std::io::ErrorKind::NotFound
    {
        bail!(
            "{}: the downloaded file is missing (gone since gphoto2 named it); nothing handed over",
            source.display()
        );
    }
    atomic::move_into(source, ingest).map_err(|e| match e {
        PublishError::Exists { path } => anyhow::anyhow!(
            "{} already exists: not replacing it with {} (left in place); rename one of them",
            path.display(),
            source.display()
        ),
        e => anyhow::Error::new(e).context(format!(
            "moving the download {} into {}",
            source.display(),
            ingest.display()
        )),
    })
}
