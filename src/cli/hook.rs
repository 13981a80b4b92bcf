//! `filmback hook`: gphoto2's `--hook-script`, handing each finished download to the
//! ingest folder.
//!
//! gphoto2 runs the hook script with the environment variable `ACTION` set to `init`,
//! `start`, `download` or `stop`, and for `download` with `ARGUMENT` set to the file it
//! has just finished saving (renamed from its `tmpfileXXXXXX` and given the capture time
//! as mtime). Only `download` does anything here: the file moves into the ingest folder
//! under its own name, whole or not at all, so the daemon never sees it partly written:
//!
//! - same file system: a hard link under the final name, then the source is unlinked (a
//!   rename that cannot replace an existing file);
//! - another file system: a copy to a hidden staging name in the ingest folder (which the
//!   daemon never takes), `fsync`, then the link under the final name, and the source is
//!   removed.
//!
//! An existing file of that name in the ingest folder is never replaced: the hook fails
//! naming both files and leaves the download where it is.

use std::fs;
use std::io;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, bail};
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

/// Moves `source` into `ingest` under its own name without ever replacing a file there.
fn hand_over(source: &Path, ingest: &Path) -> anyhow::Result<PathBuf> {
    let meta = fs::symlink_metadata(source)
        .with_context(|| format!("{}: cannot read the download", source.display()))?;
    if !meta.is_file() {
        bail!("{}: not a regular file", source.display());
    }
    let name = source
        .file_name()
        .with_context(|| format!("{}: no file name", source.display()))?;
    if !fs::metadata(ingest).is_ok_and(|m| m.is_dir()) {
        bail!("{}: the ingest folder does not exist", ingest.display());
    }
    let target = ingest.join(name);
    let collision = || {
        anyhow::anyhow!(
            "{} already exists: not replacing it with {} (left in place); rename one of them",
            target.display(),
            source.display()
        )
    };
    if fs::symlink_metadata(&target).is_ok() {
        return Err(collision());
    }
    match fs::hard_link(source, &target) {
        Ok(()) => {}
        Err(e) if e.kind() == io::ErrorKind::AlreadyExists => return Err(collision()),
        Err(e) if cannot_link(&e) => {
            copy_in(source, &target, &meta).map_err(|e| match e {
                Handover::Exists => collision(),
                Handover::Io(e) => anyhow::Error::new(e).context(format!(
                    "copying {} into {}",
                    source.display(),
                    ingest.display()
                )),
            })?;
        }
        Err(e) => {
            return Err(anyhow::Error::new(e).context(format!(
                "moving {} into {}",
                source.display(),
                ingest.display()
            )));
        }
    }
    sync_folder(ingest);
    fs::remove_file(source).with_context(|| {
        format!(
            "{} is in the ingest folder as {}, but the download could not be removed",
            source.display(),
            target.display()
        )
    })?;
    Ok(target)
}

/// Why a link cannot be made: another file system, or one without hard links (FAT,
/// exFAT, some network shares).
fn cannot_link(e: &io::Error) -> bool {
    e.kind() == io::ErrorKind::CrossesDevices
        || e.kind() == io::ErrorKind::Unsupported
        || e.raw_os_error().is_some_and(|c| {
            [libc::EXDEV, libc::EPERM, libc::EOPNOTSUPP, libc::EMLINK].contains(&c)
        })
}

enum Handover {
    Exists,
    Io(io::Error),
}

impl From<io::Error> for Handover {
    fn from(e: io::Error) -> Handover {
        Handover::Io(e)
    }
}

/// Copies `source` to a hidden staging name beside `target`, syncs it, keeps the
/// download's mtime (the capture time gphoto2 set) and publishes it under `target`: by a
/// hard link where the ingest file system has them (never replacing), else by a rename
/// after checking that `target` is still free.
fn copy_in(source: &Path, target: &Path, meta: &fs::Metadata) -> Result<(), Handover> {
    let name = target
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let staging = target.with_file_name(format!(".{name}.filmback-hook-{}", std::process::id()));
    let result = (|| {
        let mut from = fs::File::open(source)?;
        let mut to = fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&staging)?;
        io::copy(&mut from, &mut to)?;
        if let Ok(mtime) = meta.modified() {
            to.set_modified(mtime)?;
        }
        to.sync_all()?;
        drop(to);
        match fs::hard_link(&staging, target) {
            Ok(()) => {
                fs::remove_file(&staging)?;
                Ok(())
            }
            Err(e) if e.kind() == io::ErrorKind::AlreadyExists => Err(Handover::Exists),
            Err(e) if cannot_link(&e) => {
                if fs::symlink_metadata(target).is_ok() {
                    return Err(Handover::Exists);
                }
                fs::rename(&staging, target)?;
                Ok(())
            }
            Err(e) => Err(e.into()),
        }
    })();
    if result.is_err() {
        let _ = fs::remove_file(&staging);
    }
    result
}

/// Persists the folder's entries; not every file system can sync a folder.
fn sync_folder(dir: &Path) {
    if let Ok(d) = fs::File::open(dir) {
        let _ = d.sync_all();
    }
}
