//! Publishing output files atomically: nothing half-written is ever visible under its
//! final name.
//!
//! The bytes go to a hidden temporary file in the destination folder, are flushed to disk
//! (`fsync`), and only then appear under the final name: by `rename` when overwriting is
//! allowed, by a rename that refuses to replace (`renameat2` with `RENAME_NOREPLACE`;
//! where the file system cannot, a `link`, which fails if the name exists, then the
//! temporary name removed) when it is not: two writers can never clobber each other. A
//! watcher of the folder sees the file arrive whole under its name, by a rename from a
//! name [`is_temporary`] tells as ours. The folder is synced afterwards so the new name survives a
//! power cut. On any error the temporary file is removed.
//!
//! A set of files that belongs together (a bracket's EXR and its renderings) is published
//! as a unit by [`publish_set`]: all are written into a hidden staging folder beside
//! the destination, synced, marked complete, and only then renamed into place one by
//! one; a rename that fails moves the ones already renamed back, so either all names
//! appear or none. A crash between the renames is finished at the next start by
//! [`recover_sets`] (a complete set is moved into place, an incomplete one removed).

use std::fs::{self, File};
use std::io::{self, Write};
use std::os::unix::ffi::OsStrExt;
use std::path::{Path, PathBuf};

/// Whether an existing file under the final name may be replaced.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Overwrite {
    /// Replace it.
    Replace,
    /// Refuse with [`PublishError::Exists`].
    Refuse,
}

/// Why a file could not be published.
#[derive(Debug, thiserror::Error)]
pub enum PublishError {
    /// The final name is taken and overwriting was refused.
    #[error("{path}: already exists (not overwritten)")]
    Exists {
        /// The final name.
        path: PathBuf,
    },
    /// Writing, syncing or renaming failed (full disk, permissions, …).
    #[error("{path}: cannot write: {source}")]
    Io {
        /// The final name.
        path: PathBuf,
        /// What the operating system said.
        source: io::Error,
    },
    /// What was to be moved is not a regular file (a folder, a link, a device).
    #[error("{path}: not a regular file")]
    NotAFile {
        /// The file given.
        path: PathBuf,
    },
    /// Another process holds the lock of the staging folder ([`StageLock`]).
    #[error(
        "{path}: held by another filmback developing the same set (a daemon or a farm task); retry later"
    )]
    Busy {
        /// The lock file.
        path: PathBuf,
    },
}

impl PublishError {
    /// The file this failure concerns.
    pub fn path(&self) -> &Path {
        match self {
            PublishError::Exists { path }
            | PublishError::Io { path, .. }
            | PublishError::NotAFile { path }
            | PublishError::Busy { path } => path,
        }
    }
}

/// The temporary name used for `path` while it is written: `.<name>.filmback-tmp-<pid>`
/// in the same folder. Watchers and cleanup recognise it by [`is_temporary`].
pub fn temporary_name(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    path.with_file_name(format!(".{name}.filmback-tmp-{}", std::process::id()))
}

/// True for names made by [`temporary_name`].
pub fn is_temporary(path: &Path) -> bool {
    path.file_name()
        .and_then(|n| n.to_str())
        .is_some_and(|n| n.starts_with('.') && n.contains(".filmback-tmp-"))
}

/// Longest file name, in bytes, that Linux file systems take (`NAME_MAX` of ext4, XFS,
/// Btrfs, tmpfs).
pub const NAME_MAX: usize = 255;

/// Bytes [`temporary_name`] adds to a name: a leading `.`, `.filmback-tmp-` and a process
/// id of up to 10 digits.
pub const TEMPORARY_EXTRA: usize = 1 + ".filmback-tmp-".len() + 10;

/// Bytes kept for what follows an output stem: the longest look and extension
/// (`.provia400-t0.5+grain+mtf.jpg` is 29) with room for stock names of one's own.
pub const SUFFIX_ROOM: usize = 64;

/// Longest output stem, in bytes: a stem, [`SUFFIX_ROOM`] and [`TEMPORARY_EXTRA`] fit in
/// [`NAME_MAX`].
pub const MAX_STEM: usize = NAME_MAX - SUFFIX_ROOM - TEMPORARY_EXTRA;

/// The output stem for `stem`: `stem` itself when it has at most [`MAX_STEM`] bytes, else
/// its first bytes (cut at a character boundary), `~` and the 16 hex digits of
/// [`name_digest`] of the whole stem, [`MAX_STEM`] bytes at most in all: two long names
/// that differ only in their tails keep different stems.
pub fn fitting_stem(stem: &str) -> std::borrow::Cow<'_, str> {
    if stem.len() <= MAX_STEM {
        return stem.into();
    }
    let digest = name_digest(stem.as_bytes());
    let mut end = MAX_STEM - 1 - digest.len();
    while !stem.is_char_boundary(end) {
        end -= 1;
    }
    format!("{}~{digest}", &stem[..end]).into()
}

/// 64-bit FNV-1a of `bytes` as 16 lower-case hex digits: a short name for them, the same on
/// every platform and in every version (unlike the standard library's hasher).
pub fn name_digest(bytes: &[u8]) -> String {
    format!("{:016x}", fnv1a(FNV_OFFSET, bytes))
}

/// The offset basis of 64-bit FNV-1a: the hash of no bytes.
pub(crate) const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;

/// 64-bit FNV-1a of `bytes` continued from the hash `h`: for each byte `b`,
/// `h ← (h ⊕ b) · 0x100000001b3 (mod 2⁶⁴)`. Written here rather than taken from a crate:
/// five lines, and the digests in journals, output names and caches must not change.
pub(crate) fn fnv1a(h: u64, bytes: &[u8]) -> u64 {
    bytes.iter().fold(h, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

/// Writes the bytes that `produce` streams into the file, then publishes it at `path` and
/// returns what `produce` returned. A failure of `produce` is returned as it is (nothing is
/// published); a failure to write, sync or rename as a [`PublishError`] converted into
/// the producer's error type `E`.
pub fn publish_with<T, E, F>(path: &Path, overwrite: Overwrite, produce: F) -> Result<T, E>
where
    F: FnOnce(&mut io::BufWriter<&mut File>) -> Result<T, E>,
    E: From<PublishError>,
{
    if overwrite == Overwrite::Refuse && path.exists() {
        return Err(PublishError::Exists {
            path: path.to_path_buf(),
        }
        .into());
    }
    let tmp = temporary_name(path);
    let io_err = |source: io::Error| PublishError::Io {
        path: path.to_path_buf(),
        source,
    };
    let result = (|| {
        // A leftover of a process that had this one's id goes first; the new file is
        // created, never opened through whatever (a link) might stand under its name.
        let _ = fs::remove_file(&tmp);
        let mut file = File::create_new(&tmp).map_err(io_err)?;
        let produced = {
            let mut writer = io::BufWriter::with_capacity(1 << 20, &mut file);
            let produced = produce(&mut writer)?;
            writer.flush().map_err(io_err)?;
            produced
        };
        file.sync_all().map_err(io_err)?;
        drop(file);
        match overwrite {
            Overwrite::Replace => fs::rename(&tmp, path).map_err(io_err)?,
            Overwrite::Refuse => rename_no_replace(&tmp, path).map_err(|source| {
                if source.kind() == io::ErrorKind::AlreadyExists {
                    PublishError::Exists {
                        path: path.to_path_buf(),
                    }
                } else {
                    io_err(source)
                }
            })?,
        }
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            // Persist the directory entry; not every file system supports syncing a folder.
            if let Ok(d) = File::open(dir) {
                let _ = d.sync_all();
            }
        }
        Ok(produced)
    })();
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    result
}

/// Publishes `bytes` at `path` (see [`publish_with`]).
pub fn publish(path: &Path, bytes: &[u8], overwrite: Overwrite) -> Result<(), PublishError> {
    publish_with(path, overwrite, |w| {
        w.write_all(bytes).map_err(|source| PublishError::Io {
            path: path.to_path_buf(),
            source,
        })
    })
}

/// Prefix of the hidden staging folders of [`publish_set`] (`.filmback-stage-<key>`).
const STAGE_PREFIX: &str = ".filmback-stage-";

/// Renames `from` to `to` unless `to` exists ([`io::ErrorKind::AlreadyExists`]), in one
/// step: `renameat2(…, RENAME_NOREPLACE)`. Where the kernel or the file system has no such
/// rename (`EINVAL`, `ENOSYS`), or off Linux, a hard link under `to` and then `from`
/// removed (a failure to remove it is not an error: `to` is in place): the same
/// guarantee, but a watcher sees a new link rather than a rename.
pub fn rename_no_replace(from: &Path, to: &Path) -> io::Result<()> {
    #[cfg(target_os = "linux")]
    {
        use rustix::fs::{CWD, RenameFlags, renameat_with};
        use rustix::io::Errno;
        match renameat_with(CWD, from, CWD, to, RenameFlags::NOREPLACE) {
            Ok(()) => return Ok(()),
            Err(e) if e == Errno::INVAL || e == Errno::NOSYS => {}
            Err(e) => return Err(e.into()),
        }
    }
    fs::hard_link(from, to)?;
    let _ = fs::remove_file(from);
    Ok(())
}

/// Moves the finished file `source` into `dir` under its own name, whole or not at all,
/// never replacing a file there ([`PublishError::Exists`], `source` left in place). On
/// one file system it is a hard link under a temporary name in `dir`, renamed into place
/// by [`rename_no_replace`], and then the old name removed; across file systems (or where
/// links are refused) it is a copy published as by [`publish_with`] with
/// [`Overwrite::Refuse`], keeping `source`'s mtime, and then `source` removed. Where the
/// file system has `RENAME_NOREPLACE`, an inotify watcher of `dir` sees the file renamed
/// into place from a name [`is_temporary`] tells as ours (the daemon takes such a frame
/// at once); elsewhere, and to a polling watcher, it is a new file. Returns the new path.
pub fn move_into(source: &Path, dir: &Path) -> Result<PathBuf, PublishError> {
    let io_err = |path: &Path| {
        let path = path.to_path_buf();
        move |source| PublishError::Io { path, source }
    };
    let meta = fs::symlink_metadata(source).map_err(io_err(source))?;
    let not_a_file = || PublishError::NotAFile {
        path: source.to_path_buf(),
    };
    if !meta.is_file() {
        return Err(not_a_file());
    }
    let name = source.file_name().ok_or_else(not_a_file)?;
    let target = dir.join(name);
    if fs::symlink_metadata(&target).is_ok() {
        return Err(PublishError::Exists { path: target });
    }
    let tmp = temporary_name(&target);
    // A leftover of a process that had this one's id, never a frame.
    let _ = fs::remove_file(&tmp);
    match fs::hard_link(source, &tmp) {
        Ok(()) => {
            if let Err(e) = rename_no_replace(&tmp, &target) {
                let _ = fs::remove_file(&tmp);
                return Err(if e.kind() == io::ErrorKind::AlreadyExists {
                    PublishError::Exists { path: target }
                } else {
                    io_err(&target)(e)
                });
            }
            sync_folder(dir);
        }
        Err(e) if cannot_link(&e) => {
            let mut from = File::open(source).map_err(io_err(source))?;
            publish_with(&target, Overwrite::Refuse, |w| {
                io::copy(&mut from, w).map_err(io_err(source))?;
                w.flush().map_err(io_err(&target))?;
                if let Ok(mtime) = meta.modified() {
                    w.get_ref().set_modified(mtime).map_err(io_err(&target))?;
                }
                Ok::<(), PublishError>(())
            })?;
        }
        Err(e) => return Err(io_err(&target)(e)),
    }
    fs::remove_file(source).map_err(io_err(source))?;
    Ok(target)
}

/// Why a hard link cannot be made: another file system, or one without hard links (FAT,
/// exFAT, some network shares).
fn cannot_link(e: &io::Error) -> bool {
    e.kind() == io::ErrorKind::CrossesDevices
        || e.kind() == io::ErrorKind::Unsupported
        || e.raw_os_error().is_some_and(|c| {
            [libc::EXDEV, libc::EPERM, libc::EOPNOTSUPP, libc::EMLINK].contains(&c)
        })
}

/// Name of the marker written into a staging folder once every file in it is complete.
const COMPLETE: &str = ".complete";

/// Sub-folder of a staging folder holding hard links to the files a set replaces, so a
/// failed publication can put them back.
const PREVIOUS: &str = ".previous";

/// The staging folder of a set `key` (e.g. a bracket id) in `dir`.
pub fn stage_folder(dir: &Path, key: &str) -> PathBuf {
    dir.join(format!("{STAGE_PREFIX}{key}"))
}

/// A lock file opened by [`lock_file`].
#[derive(Debug)]
pub(crate) enum Lock {
    /// Locked by us, for as long as the file stays open.
    Taken(File),
    /// Another open file (in any process) holds the lock.
    Held(File),
}

/// Opens the file at `path` for reading and writing, creating it, and tries to lock it
/// (`flock`, exclusive, without waiting); the kernel releases the lock when the file is
/// closed or its process ends, even by `kill -9`.
pub(crate) fn lock_file(path: &Path) -> io::Result<Lock> {
    let file = fs::OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .open(path)?;
    match file.try_lock() {
        Ok(()) => Ok(Lock::Taken(file)),
        Err(fs::TryLockError::WouldBlock) => Ok(Lock::Held(file)),
        Err(fs::TryLockError::Error(e)) => Err(e),
    }
}

/// The lock of a staging folder, `<stage>.lock` beside it, held (`flock`, exclusive) by
/// whoever develops into the folder and publishes it: the daemon or a farm task, in any
/// process on this host. Two developments of one set never share its folder, and
/// [`recover_sets`] leaves a folder alone while it is held. The file is removed, still
/// held, when the lock is dropped; one a killed process left is taken over (the kernel
/// released its lock).
#[derive(Debug)]
pub struct StageLock {
    path: PathBuf,
    _file: File,
}

impl StageLock {
    /// Takes the lock of `stage` ([`stage_folder`]); [`PublishError::Busy`] while another
    /// holder has it (or has just removed its file), [`PublishError::Io`] when the file
    /// cannot be created.
    pub fn take(stage: &Path) -> Result<StageLock, PublishError> {
        use std::os::unix::fs::MetadataExt;
        let mut name = stage.as_os_str().to_owned();
        name.push(".lock");
        let path = PathBuf::from(name);
        let io = |source| PublishError::Io {
            path: path.clone(),
            source,
        };
        let file = match lock_file(&path).map_err(io)? {
            Lock::Taken(file) => file,
            Lock::Held(_) => return Err(PublishError::Busy { path }),
        };
        // Locked after the holder removed it: this inode guards nothing.
        let inode = |m: fs::Metadata| (m.dev(), m.ino());
        let held = file.metadata().map(inode).map_err(io)?;
        if fs::metadata(&path).map(inode).ok() != Some(held) {
            return Err(PublishError::Busy { path });
        }
        Ok(StageLock { path, _file: file })
    }

    /// The lock file.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

impl Drop for StageLock {
    fn drop(&mut self) {
        let _ = fs::remove_file(&self.path);
    }
}

fn sync_folder(dir: &Path) {
    // Not every file system supports syncing a folder.
    if let Ok(d) = File::open(dir) {
        let _ = d.sync_all();
    }
}

/// The files of a staging folder (not the marker, not temporaries), sorted.
fn staged(stage: &Path) -> io::Result<Vec<PathBuf>> {
    let mut files: Vec<PathBuf> = fs::read_dir(stage)?
        .filter_map(Result::ok)
        .filter(|e| e.file_type().is_ok_and(|t| t.is_file()))
        .map(|e| e.path())
        .filter(|p| !is_temporary(p) && p.file_name().is_some_and(|n| n != COMPLETE))
        .collect();
    files.sort();
    Ok(files)
}

/// Publishes every file of the staging folder `stage` into `dir` (its parent) as one
/// set, replacing files of the same names, and removes the folder. Returns the published
/// paths, sorted. On error nothing of the set is visible in `dir`: the files it had
/// replaced are put back (from hard links taken before the renames; on a file system
/// without hard links they are gone) and the staging folder is removed.
pub fn publish_set(stage: &Path, dir: &Path) -> Result<Vec<PathBuf>, PublishError> {
    let result = publish_staged(stage, dir);
    let _ = fs::remove_dir_all(stage);
    result
}

/// Seals the set in the staging folder `stage`: syncs its files, then writes the marker
/// that says the set is complete, listing their names one per line (what
/// [`interrupted_sets`] compares with what is left to move). Returns the files, sorted.
/// From here on the set belongs in the destination: [`recover_sets`] finishes it.
pub fn seal_set(stage: &Path) -> Result<Vec<PathBuf>, PublishError> {
    let io_err = |path: &Path| {
        let path = path.to_path_buf();
        move |source| PublishError::Io { path, source }
    };
    let files = staged(stage).map_err(io_err(stage))?;
    for f in &files {
        File::open(f)
            .and_then(|h| h.sync_all())
            .map_err(io_err(f))?;
    }
    let mut manifest = Vec::new();
    for f in &files {
        if let Some(name) = f.file_name() {
            manifest.extend_from_slice(name.as_bytes());
            manifest.push(b'\n');
        }
    }
    File::create(stage.join(COMPLETE))
        .and_then(|mut h| {
            h.write_all(&manifest)?;
            h.sync_all()
        })
        .map_err(io_err(stage))?;
    sync_folder(stage);
    Ok(files)
}

fn publish_staged(stage: &Path, dir: &Path) -> Result<Vec<PathBuf>, PublishError> {
    let files = seal_set(stage)?;
    // Hard links to the files the set replaces (best effort: without them an undo
    // removes the new files but cannot restore the old ones).
    let previous = stage.join(PREVIOUS);
    let name = |f: &Path| f.file_name().expect("read_dir names files").to_owned();
    if fs::create_dir(&previous).is_ok() {
        for from in &files {
            let to = dir.join(name(from));
            if fs::symlink_metadata(&to).is_ok_and(|m| m.is_file()) {
                let _ = fs::hard_link(&to, previous.join(name(from)));
            }
        }
    }
    let mut moved: Vec<(PathBuf, PathBuf)> = Vec::with_capacity(files.len());
    for from in &files {
        let to = dir.join(name(from));
        if let Err(source) = fs::rename(from, &to) {
            // Undo: the set is not visible at all, and what it replaced is back.
            for (back_from, back_to) in moved.iter().rev() {
                let _ = fs::rename(back_to, back_from);
                let _ = fs::rename(previous.join(name(back_from)), back_to);
            }
            let _ = fs::remove_file(stage.join(COMPLETE));
            sync_folder(dir);
            return Err(PublishError::Io { path: to, source });
        }
        moved.push((from.clone(), to));
    }
    sync_folder(dir);
    Ok(moved.into_iter().map(|(_, to)| to).collect())
}

/// What [`recover_sets`] did with one staging folder.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Recovered {
    /// A complete set interrupted between renames: the rest was moved into place.
    Completed(PathBuf, Vec<PathBuf>),
    /// An incomplete set: removed, nothing of it was visible.
    RolledBack(PathBuf),
}

/// A set whose publication was interrupted between its renames (the process killed):
/// part of it is visible in the destination, the rest waits in its staging folder until
/// [`recover_sets`] moves it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct InterruptedSet {
    /// The staging folder.
    pub stage: PathBuf,
    /// Files of the set already under their final names.
    pub published: Vec<PathBuf>,
    /// Files still in the staging folder, by their final names.
    pub pending: Vec<PathBuf>,
}

/// The sets in `dir` whose publication was interrupted between renames, read without
/// changing anything (for `filmback status`): sealed staging folders ([`seal_set`]) with
/// the names their marker lists split into those already in `dir` and those still
/// staged. A folder sealed by an earlier version (an empty marker) lists no published
/// files.
pub fn interrupted_sets(dir: &Path) -> Vec<InterruptedSet> {
    let mut sets = Vec::new();
    for stage in stage_folders(dir) {
        let Ok(manifest) = fs::read(stage.join(COMPLETE)) else {
            continue;
        };
        let pending: Vec<PathBuf> = staged(&stage)
            .unwrap_or_default()
            .iter()
            .filter_map(|f| f.file_name().map(|n| dir.join(n)))
            .collect();
        let published: Vec<PathBuf> = manifest
            .split(|&b| b == b'\n')
            .filter(|n| !n.is_empty())
            .map(|n| dir.join(std::ffi::OsStr::from_bytes(n)))
            .filter(|p| !pending.contains(p) && p.is_file())
            .collect();
        sets.push(InterruptedSet {
            stage,
            published,
            pending,
        });
    }
    sets.sort_by(|a, b| a.stage.cmp(&b.stage));
    sets
}

/// The staging folders of [`publish_set`] in `dir` (folders, not links).
fn stage_folders(dir: &Path) -> Vec<PathBuf> {
    let Ok(entries) = fs::read_dir(dir) else {
        return Vec::new();
    };
    entries
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.starts_with(STAGE_PREFIX))
                && fs::symlink_metadata(p).is_ok_and(|m| m.is_dir())
        })
        .collect()
}

/// Finishes or removes the staging folders an interrupted [`publish_set`] left in `dir`;
/// one whose [`StageLock`] another process holds is in use and left alone.
pub fn recover_sets(dir: &Path) -> Vec<Recovered> {
    stage_folders(dir)
        .into_iter()
        .filter_map(|stage| {
            let _lock = StageLock::take(&stage).ok()?;
            Some(recover_set(&stage, dir))
        })
        .collect()
}

/// Finishes or removes one staging folder `stage` of `dir` that an interrupted
/// [`publish_set`] left: a sealed set ([`seal_set`]) has the rest of its files moved into
/// place, an unsealed one is removed (nothing of it was visible).
pub(crate) fn recover_set(stage: &Path, dir: &Path) -> Recovered {
    let done = if stage.join(COMPLETE).is_file() {
        let mut moved = Vec::new();
        for from in staged(stage).unwrap_or_default() {
            let Some(name) = from.file_name() else {
                continue;
            };
            let to = dir.join(name);
            if fs::rename(&from, &to).is_ok() {
                moved.push(to);
            }
        }
        sync_folder(dir);
        Recovered::Completed(stage.to_path_buf(), moved)
    } else {
        Recovered::RolledBack(stage.to_path_buf())
    };
    let _ = fs::remove_dir_all(stage);
    done
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn long_stems_are_shortened_to_fit_a_file_name() {
        let short = "IMG_0001";
        assert_eq!(fitting_stem(short), short);
        let at_limit = "a".repeat(MAX_STEM);
        assert_eq!(fitting_stem(&at_limit), at_limit);
        let long = format!("{}-1", "é".repeat(120));
        let other = format!("{}-2", "é".repeat(120));
        let (a, b) = (fitting_stem(&long), fitting_stem(&other));
        assert!(a.len() <= MAX_STEM && b.len() <= MAX_STEM, "{a}");
        assert_ne!(a, b, "the digest tells the names apart");
        assert!(a.starts_with("éé") && a.contains('~'), "{a}");
        let dir = tempfile::tempdir().unwrap();
        let path = dir
            .path()
            .join(format!("{a}.{}", "x".repeat(SUFFIX_ROOM - 1)));
        publish(&path, b"fits", Overwrite::Refuse).unwrap();
        assert_eq!(fs::read(&path).unwrap(), b"fits");
    }

    #[test]
    fn a_rename_that_cannot_replace_leaves_both_files() {
        let dir = tempfile::tempdir().unwrap();
        let (from, to) = (dir.path().join("a"), dir.path().join("b"));
        fs::write(&from, b"new").unwrap();
        fs::write(&to, b"old").unwrap();
        let err = rename_no_replace(&from, &to).unwrap_err();
        assert_eq!(err.kind(), io::ErrorKind::AlreadyExists, "{err}");
        assert_eq!(fs::read(&from).unwrap(), b"new");
        assert_eq!(fs::read(&to).unwrap(), b"old");
        fs::remove_file(&to).unwrap();
        rename_no_replace(&from, &to).unwrap();
        assert_eq!(fs::read(&to).unwrap(), b"new");
        assert!(!from.exists());
    }

    /// A producer's own error type, as a caller of [`publish_with`] would have.
    #[derive(Debug, thiserror::Error)]
    enum ProducerError {
        #[error(transparent)]
        Publish(#[from] PublishError),
        #[error(transparent)]
        Io(#[from] io::Error),
        #[error("encoder failed")]
        Encoder,
    }

    #[test]
    fn a_staging_folder_whose_lock_is_held_is_left_to_its_holder() {
        let dir = tempfile::tempdir().unwrap();
        let stage = stage_folder(dir.path(), "bracket");
        fs::create_dir(&stage).unwrap();
        fs::write(stage.join("a.exr"), b"half an EXR").unwrap();
        let held = StageLock::take(&stage).unwrap();
        assert!(matches!(
            StageLock::take(&stage),
            Err(PublishError::Busy { path }) if path == held.path()
        ));
        assert!(recover_sets(dir.path()).is_empty());
        assert!(
            stage.join("a.exr").is_file(),
            "a folder in use is not touched"
        );
        let lock_file = held.path().to_path_buf();
        drop(held);
        assert!(!lock_file.exists(), "the lock file goes with its holder");
        let recovered = recover_sets(dir.path());
        assert!(matches!(&recovered[..], [Recovered::RolledBack(s)] if *s == stage));
        assert!(!stage.exists());
        assert!(!lock_file.exists());
    }

    #[test]
    fn a_file_that_appears_while_publishing_is_not_replaced() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.bin");
        let err = publish_with(&path, Overwrite::Refuse, |w| {
            // Another writer takes the name after the check, before the rename.
            fs::write(&path, b"other")?;
            Ok::<(), ProducerError>(w.write_all(b"ours")?)
        })
        .unwrap_err();
        assert!(
            matches!(err, ProducerError::Publish(PublishError::Exists { .. })),
            "{err}"
        );
        assert_eq!(fs::read(&path).unwrap(), b"other");
        let names: Vec<_> = fs::read_dir(dir.path()).unwrap().collect();
        assert_eq!(names.len(), 1, "no temporary file left behind");
    }

    #[test]
    fn publishes_and_refuses_to_clobber() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.bin");
        publish(&path, b"one", Overwrite::Refuse).unwrap();
        assert_eq!(fs::read(&path).unwrap(), b"one");
        let err = publish(&path, b"two", Overwrite::Refuse).unwrap_err();
        assert!(matches!(err, PublishError::Exists { .. }), "{err}");
        assert_eq!(fs::read(&path).unwrap(), b"one");
        publish(&path, b"three", Overwrite::Replace).unwrap();
        assert_eq!(fs::read(&path).unwrap(), b"three");
        let names: Vec<_> = fs::read_dir(dir.path()).unwrap().collect();
        assert_eq!(names.len(), 1, "no temporary file left behind");
    }

    #[test]
    fn failed_producer_leaves_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("b.bin");
        let err = publish_with(&path, Overwrite::Replace, |w| {
            w.write_all(b"partial")?;
            Err::<(), _>(ProducerError::Encoder)
        })
        .unwrap_err();
        assert!(matches!(err, ProducerError::Encoder), "{err}");
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 0);
    }

    #[test]
    fn a_set_appears_whole_or_not_at_all() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path();
        let stage = stage_folder(out, "b1");
        fs::create_dir(&stage).unwrap();
        publish(&stage.join("x.exr"), b"e", Overwrite::Replace).unwrap();
        publish(&stage.join("x.look.jpg"), b"j", Overwrite::Replace).unwrap();
        // The second name is taken by a folder: the rename fails, the first is undone.
        fs::create_dir(out.join("x.look.jpg")).unwrap();
        let err = publish_set(&stage, out).unwrap_err();
        assert!(err.to_string().contains("x.look.jpg"), "{err}");
        let mut names: Vec<_> = fs::read_dir(out)
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        names.sort();
        assert_eq!(names, ["x.look.jpg"], "only the blocking folder");
        fs::remove_dir(out.join("x.look.jpg")).unwrap();
        fs::create_dir(&stage).unwrap();
        publish(&stage.join("x.exr"), b"e", Overwrite::Replace).unwrap();
        publish(&stage.join("x.look.jpg"), b"j", Overwrite::Replace).unwrap();
        let published = publish_set(&stage, out).unwrap();
        assert_eq!(published, [out.join("x.exr"), out.join("x.look.jpg")]);
        assert!(!stage.exists());
    }

    #[test]
    fn a_failed_set_puts_back_the_files_it_replaced() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path();
        fs::write(out.join("a.exr"), b"old exr").unwrap();
        fs::write(out.join("a.velvia50.jpg"), b"old jpeg").unwrap();
        let stage = stage_folder(out, "b2");
        fs::create_dir(&stage).unwrap();
        publish(&stage.join("a.exr"), b"new exr", Overwrite::Replace).unwrap();
        publish(
            &stage.join("a.velvia50.jpg"),
            b"new jpeg",
            Overwrite::Replace,
        )
        .unwrap();
        publish(&stage.join("a.zz.jpg"), b"new", Overwrite::Replace).unwrap();
        // The last name is taken by a folder: its rename fails after two replaced files.
        fs::create_dir(out.join("a.zz.jpg")).unwrap();
        assert!(publish_set(&stage, out).is_err());
        assert_eq!(fs::read(out.join("a.exr")).unwrap(), b"old exr");
        assert_eq!(fs::read(out.join("a.velvia50.jpg")).unwrap(), b"old jpeg");
        assert!(!stage.exists());
    }

    #[test]
    fn a_stage_reached_through_a_link_is_not_published() {
        let dir = tempfile::tempdir().unwrap();
        let (out, elsewhere) = (dir.path().join("out"), dir.path().join("elsewhere"));
        fs::create_dir_all(&out).unwrap();
        fs::create_dir_all(&elsewhere).unwrap();
        fs::write(elsewhere.join("secret.txt"), b"x").unwrap();
        fs::write(elsewhere.join(COMPLETE), b"").unwrap();
        std::os::unix::fs::symlink(&elsewhere, stage_folder(&out, "evil")).unwrap();
        assert!(recover_sets(&out).is_empty());
        assert!(!out.join("secret.txt").exists());
        assert!(elsewhere.join("secret.txt").exists());
    }

    #[test]
    fn a_crash_between_renames_is_completed_and_a_partial_set_rolled_back() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path();
        // Crashed after the marker and the first rename.
        let done = stage_folder(out, "a");
        fs::create_dir(&done).unwrap();
        fs::write(out.join("a.exr"), b"e").unwrap();
        fs::write(done.join("a.look.jpg"), b"j").unwrap();
        fs::write(done.join(COMPLETE), b"").unwrap();
        // Crashed while writing.
        let partial = stage_folder(out, "b");
        fs::create_dir(&partial).unwrap();
        fs::write(partial.join("b.exr"), b"half").unwrap();
        let mut r = recover_sets(out);
        r.sort_by_key(|x| format!("{x:?}"));
        assert_eq!(
            r,
            [
                Recovered::Completed(done.clone(), vec![out.join("a.look.jpg")]),
                Recovered::RolledBack(partial.clone()),
            ]
        );
        let mut names: Vec<_> = fs::read_dir(out)
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        names.sort();
        assert_eq!(names, ["a.exr", "a.look.jpg"]);
    }

    #[test]
    fn unwritable_folder_is_an_error_naming_the_file() {
        let path = Path::new("/nonexistent-folder-filmback/c.bin");
        let err = publish(path, b"x", Overwrite::Replace).unwrap_err();
        assert!(err.to_string().contains("c.bin"), "{err}");
    }
}
