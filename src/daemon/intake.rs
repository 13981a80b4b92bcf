//! Noticing files and taking only complete ones: the watcher (inotify or polling), the
//! folder scan, and the probe that reads a settled file's EXIF and checks its header.
//!
//! Symbolic links inside the ingest folder are never followed: a linked folder is not
//! descended into (nor watched), and a link with a frame's name is refused with the
//! reason (where it points, or that it dangles) instead of being opened. Files are
//! opened with `O_NOFOLLOW`, so a file swapped for a link after the check is refused too.
//! The ingest folder itself may be a link (the operator's choice in the configuration).

use std::collections::HashMap;
use std::io::Cursor;
use std::path::{Path, PathBuf};
use std::time::UNIX_EPOCH;

use notify::event::{AccessKind, AccessMode, ModifyKind, RenameMode};
use notify::{EventKind, RecursiveMode, Watcher};
use tokio::sync::mpsc::UnboundedSender;

use crate::atomic;
use crate::daemon::Footprint;
use crate::daemon::bracket::{CameraId, Capture, Input};
use crate::daemon::budget::{MB, megabytes};
use crate::daemon::config::{Watch, WatchMode};
use crate::daemon::journal;
use crate::frame;
use crate::metadata;

/// What the watcher reports to the daemon loop.
#[derive(Debug)]
pub(crate) enum Notice {
    /// Something happened to this file: what it says of the file's writer.
    File { path: PathBuf, arrival: Arrival },
    /// Events may have been lost (queue overflow): rescan the folder.
    Rescan,
}

/// What a notice says of its file's writer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Arrival {
    /// Created or written: the writer may not be done.
    Writing,
    /// Its writer closed it, or it was renamed into place: done unless the writer comes
    /// back at once (a tool that rewrites the EXIF just after the copy).
    Closed,
    /// Renamed into place from a filmback temporary name ([`atomic::is_temporary`]): handed
    /// over whole by `filmback hook` or another filmback process, never written again.
    Delivered,
}

/// Why the ingest folder cannot be watched (the daemon then goes on scanning it every
/// `poll` and tries again); each kernel limit comes with the knob that raises it.
#[derive(Debug, thiserror::Error)]
pub(crate) enum WatchError {
    /// The user's inotify watches are used up.
    #[error(
        "{}: too many inotify watches ({source}); raise fs.inotify.max_user_watches or set \
         [watch] mode = \"poll\"",
        folder.display()
    )]
    TooManyWatches {
        folder: PathBuf,
        source: notify::Error,
    },
    /// The process's file descriptors are used up.
    #[error(
        "{}: too many open files ({source}); raise the file-descriptor limit (LimitNOFILE=)",
        folder.display()
    )]
    TooManyFiles {
        folder: PathBuf,
        source: notify::Error,
    },
    /// Any other failure to watch.
    #[error("{}: cannot watch: {source}", folder.display())]
    Other {
        folder: PathBuf,
        source: notify::Error,
    },
}

impl WatchError {
    /// `source`, met while watching `folder`, sorted by what raises the limit.
    fn from_notify(folder: &Path, source: notify::Error) -> WatchError {
        let folder = folder.to_path_buf();
        match &source.kind {
            notify::ErrorKind::MaxFilesWatch => WatchError::TooManyWatches { folder, source },
            notify::ErrorKind::Io(io) if io.raw_os_error() == Some(libc::EMFILE) => {
                WatchError::TooManyFiles { folder, source }
            }
            _ => WatchError::Other { folder, source },
        }
    }
}

/// A running watcher; dropping it stops watching.
pub(crate) type ActiveWatcher = Box<dyn Watcher + Send>;

/// Starts watching `dir` (inotify, or notify's poller for network shares).
pub(crate) fn watch(
    cfg: &Watch,
    dir: &Path,
    tx: UnboundedSender<Notice>,
) -> Result<ActiveWatcher, WatchError> {
    let takes = cfg.clone();
    let root = dir.to_path_buf();
    let handler = move |res: notify::Result<notify::Event>| match res {
        Ok(event) => {
            if event.need_rescan() {
                let _ = tx.send(Notice::Rescan);
            }
            // Reads are no news; a writer closing the file is (its last size), and so is
            // a rename into place (the write-to-temporary-then-rename convention).
            let finished = matches!(
                event.kind,
                EventKind::Access(AccessKind::Close(AccessMode::Write))
                    | EventKind::Modify(ModifyKind::Name(RenameMode::To | RenameMode::Both))
            );
            if matches!(event.kind, EventKind::Access(_)) && !finished {
                return;
            }
            // notify pairs a rename's two halves into one event, source first.
            let delivered = matches!(
                event.kind,
                EventKind::Modify(ModifyKind::Name(RenameMode::Both))
            ) && event.paths.first().is_some_and(|p| atomic::is_temporary(p));
            let arrival = if delivered {
                Arrival::Delivered
            } else if finished {
                Arrival::Closed
            } else {
                Arrival::Writing
            };
            for path in event.paths {
                if takes.takes_path(&root, &path) {
                    let _ = tx.send(Notice::File { path, arrival });
                }
            }
        }
        // The kernel's queue overflowed or the watch broke: a rescan recovers.
        Err(_) => {
            let _ = tx.send(Notice::Rescan);
        }
    };
    let mode = if cfg.recursive {
        RecursiveMode::Recursive
    } else {
        RecursiveMode::NonRecursive
    };
    let explain = |source: notify::Error| WatchError::from_notify(dir, source);
    let mut watcher: ActiveWatcher = match cfg.mode {
        WatchMode::Notify => Box::new(
            notify::RecommendedWatcher::new(
                handler,
                notify::Config::default().with_follow_symlinks(false),
            )
            .map_err(explain)?,
        ),
        WatchMode::Poll => Box::new(
            notify::PollWatcher::new(
                handler,
                notify::Config::default()
                    .with_poll_interval(cfg.poll)
                    .with_follow_symlinks(false),
            )
            .map_err(explain)?,
        ),
    };
    watcher.watch(dir, mode).map_err(explain)?;
    Ok(watcher)
}

/// Every file (or link, to be refused) under `dir` whose name is taken (sorted;
/// sub-folders when `recursive`, except hidden and tools' folders ([`Watch::descends`]),
/// never through a link). A missing folder is an empty list.
pub(crate) fn scan(cfg: &Watch, dir: &Path) -> Vec<PathBuf> {
    let mut found = Vec::new();
    let mut folders = vec![dir.to_path_buf()];
    while let Some(folder) = folders.pop() {
        let Ok(entries) = std::fs::read_dir(&folder) else {
            continue;
        };
        for entry in entries.filter_map(Result::ok) {
            let path = entry.path();
            let Ok(kind) = entry.file_type() else {
                continue;
            };
            let name = entry.file_name();
            let name = name.to_string_lossy();
            if kind.is_dir() {
                if cfg.descends(&name) {
                    folders.push(path);
                }
            } else if cfg.takes(&name) {
                found.push(path);
            }
        }
    }
    found.sort();
    found
}

/// The one name by which the daemon knows a file of the ingest folder, whatever the
/// configuration, a watcher or an old journal called it: the ingest folder resolved once
/// at start (`canonicalize`: absolute, `.`, `..` and links of the folder itself and its
/// parents resolved) joined with the file's path below it. `./ingest/a.jpg`,
/// `ingest//a.jpg`, `/srv/ingest/a.jpg` and `/link-to-srv/ingest/a.jpg` are one file.
/// Links below the folder are never resolved (they are refused, not followed).
#[derive(Debug, Clone)]
pub(crate) struct IngestRoot {
    /// The folder resolved.
    real: PathBuf,
    /// The folder as configured, made absolute against the working directory.
    spelled: PathBuf,
}

impl IngestRoot {
    /// Resolves the configured ingest folder (as it is spelled when it cannot be, e.g.
    /// while it is missing).
    pub(crate) fn new(configured: &Path) -> IngestRoot {
        let spelled = std::path::absolute(configured).unwrap_or_else(|_| configured.to_path_buf());
        let real = std::fs::canonicalize(configured).unwrap_or_else(|_| spelled.clone());
        IngestRoot { real, spelled }
    }

    /// The ingest folder resolved.
    pub(crate) fn real(&self) -> &Path {
        &self.real
    }

    /// The name the daemon knows `path` by: below the resolved folder when `path` is
    /// below it as resolved, as configured, or through a parent folder that resolves
    /// into it; otherwise `path` made absolute.
    pub(crate) fn identity(&self, path: &Path) -> PathBuf {
        let path = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
        for root in [&self.real, &self.spelled] {
            if let Ok(rest) = path.strip_prefix(root) {
                return self.real.join(rest);
            }
        }
        if let (Some(parent), Some(name)) = (path.parent(), path.file_name())
            && let Ok(parent) = std::fs::canonicalize(parent)
            && let Ok(rest) = parent.strip_prefix(&self.real)
        {
            return self.real.join(rest).join(name);
        }
        path
    }
}

/// True when a folder between `root` and `path` (exclusive of `path` itself) is a
/// symbolic link: such a path is not inside the ingest folder, only reachable from it.
/// `path` may be given under `root` as configured or as resolved (watchers report either);
/// a path under neither is not in the ingest folder either.
pub(crate) fn through_link(root: &Path, path: &Path) -> bool {
    if let Ok(rest) = path.strip_prefix(root) {
        return linked_folder(root, rest);
    }
    match std::fs::canonicalize(root) {
        Ok(real) => path
            .strip_prefix(&real)
            .map_or(true, |rest| linked_folder(&real, rest)),
        Err(_) => true,
    }
}

fn linked_folder(root: &Path, rest: &Path) -> bool {
    let mut at = root.to_path_buf();
    let parts: Vec<_> = rest.components().collect();
    for part in parts.iter().take(parts.len().saturating_sub(1)) {
        at.push(part);
        match std::fs::symlink_metadata(&at) {
            Ok(m) if m.file_type().is_symlink() => return true,
            Ok(_) => {}
            Err(_) => return false,
        }
    }
    false
}

/// Size and modification time of a file, as the journal identifies it. A symbolic link
/// is identified as itself (not followed), so that it can be refused once.
pub(crate) fn identify(path: &Path) -> std::io::Result<Input> {
    let meta = std::fs::symlink_metadata(path)?;
    if !meta.is_file() && !meta.file_type().is_symlink() {
        return Err(std::io::Error::other("not a regular file"));
    }
    stamp(path, &meta)
}

/// What settling watches of a file: its journal identity, and what changes with any
/// write, `utime` or replacement even when the writer sets the mtime back (gphoto2 sets
/// it to the capture time): the inode's change time (`ctime`, set by the kernel's clock)
/// and the device and inode numbers.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct Observed {
    /// Path, size, mtime.
    pub input: Input,
    /// `ctime` in nanoseconds since the Unix epoch.
    changed_ns: i64,
    /// `(st_dev, st_ino)`.
    inode: (u64, u64),
}

/// [`identify`] with the change time and the inode (see [`Observed`]).
pub(crate) fn observe(path: &Path) -> std::io::Result<Observed> {
    use std::os::unix::fs::MetadataExt;
    let meta = std::fs::symlink_metadata(path)?;
    if !meta.is_file() && !meta.file_type().is_symlink() {
        return Err(std::io::Error::other("not a regular file"));
    }
    Ok(Observed {
        input: stamp(path, &meta)?,
        changed_ns: meta
            .ctime()
            .saturating_mul(1_000_000_000)
            .saturating_add(meta.ctime_nsec()),
        inode: (meta.dev(), meta.ino()),
    })
}

fn stamp(path: &Path, meta: &std::fs::Metadata) -> std::io::Result<Input> {
    let modified_ns = meta
        .modified()?
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| i64::try_from(d.as_nanos()).unwrap_or(i64::MAX));
    Ok(Input {
        path: path.to_path_buf(),
        size: meta.len(),
        modified_ns,
    })
}

/// True when a JPEG's last scan (`FF DA`) is followed by an end-of-image marker
/// (`FF D9`). Entropy-coded data never contains `FF DA` or `FF D9` (a data byte `FF` is
/// stuffed as `FF 00`), so a file cut short anywhere after its headers fails this test,
/// while an embedded thumbnail (inside APP1, before the main scan) cannot fake it. The
/// decoder alone is lenient and fills a truncated image with grey.
fn jpeg_complete(bytes: &[u8]) -> bool {
    let last_scan = bytes.windows(2).rposition(|w| w == [0xFF, 0xDA]);
    last_scan.is_some_and(|i| bytes[i..].windows(2).any(|w| w == [0xFF, 0xD9]))
}

/// What the daemon keeps of a frame it took, beside its capture: its decoded size (for
/// the memory budget), its content digest (journaled) and its `(device, inode)`, to see
/// the file replaced while its bracket develops.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Taken {
    /// Decoded size.
    pub footprint: Footprint,
    /// [`journal::content_digest`] of the bytes read.
    pub digest: u64,
    /// `(st_dev, st_ino)` when read.
    pub inode: (u64, u64),
}

impl Observed {
    /// `(st_dev, st_ino)`.
    pub(crate) fn inode(&self) -> (u64, u64) {
        self.inode
    }
}

/// What reading a settled file found.
#[derive(Debug)]
pub(crate) enum Probe {
    /// A frame with its EXIF, its decoded size, content digest and inode.
    Frame(Capture, Taken),
    /// Not a usable frame (its content, or a link); set aside with the reason.
    Rejected(Input, String),
    /// It could not be read now (permission denied, I/O error): try again later.
    Unreadable(String),
    /// It changed while being read: still being written, look again later.
    Changed,
    /// It disappeared.
    Gone,
}

/// True for read errors that are the file's (or the system's) state now, not its
/// content: permission denied, I/O error, stale or busy file, out of descriptors or
/// memory. These are retried; anything else about a file is final.
pub(crate) fn transient(e: &std::io::Error) -> bool {
    e.kind() == std::io::ErrorKind::PermissionDenied
        || e.raw_os_error().is_some_and(|code| {
            [
                libc::EIO,
                libc::EAGAIN,
                libc::EBUSY,
                libc::EINTR,
                libc::ETIMEDOUT,
                libc::ESTALE,
                libc::ENFILE,
                libc::EMFILE,
                libc::ENOMEM,
                libc::ENOLCK,
            ]
            .contains(&code)
        })
}

/// Why a link is refused: where it points, and whether that exists.
fn link_reason(path: &Path) -> String {
    let target = std::fs::read_link(path)
        .map(|t| t.display().to_string())
        .unwrap_or_else(|e| format!("? ({e})"));
    if std::fs::metadata(path).is_err() {
        format!("symbolic link to {target} (dangling): links in ingest are not followed")
    } else {
        format!("symbolic link to {target}: links in ingest are not followed")
    }
}

/// Opens a file for reading without following a final symbolic link, and without
/// waiting for a writer should it have been swapped for a FIFO (`O_NONBLOCK` changes
/// nothing for a regular file).
pub(crate) fn open_no_follow(path: &Path) -> std::io::Result<std::fs::File> {
    use std::os::unix::fs::OpenOptionsExt;
    std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NOFOLLOW | libc::O_NONBLOCK)
        .open(path)
}

/// Reads a settled file: EXIF (camera, exposure, capture time) and the image header
/// (format and dimensions; the pixels are decoded later, by the developer). A file of
/// more than `max_bytes` (the memory budget: a frame never holds less than its file) is
/// rejected without being read.
pub(crate) fn probe(path: &Path, max_bytes: u64) -> Probe {
    let observed = match observe(path) {
        Ok(o) => o,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Probe::Gone,
        Err(e) if transient(&e) => return Probe::Unreadable(format!("cannot read: {e}")),
        Err(e) => {
            return Probe::Rejected(
                Input {
                    path: path.to_path_buf(),
                    size: 0,
                    modified_ns: 0,
                },
                format!("cannot read: {e}"),
            );
        }
    };
    let before = observed.input.clone();
    if std::fs::symlink_metadata(path).is_ok_and(|m| m.file_type().is_symlink()) {
        return Probe::Rejected(before, link_reason(path));
    }
    if before.size > max_bytes {
        let reason = format!(
            "a {} MB file is larger than the memory budget ([daemon] memory_mb = {}): it could never be developed",
            megabytes(before.size),
            max_bytes / MB
        );
        return Probe::Rejected(before, reason);
    }
    // At most one byte more than allowed: a file still growing shows as changed below.
    let bytes = match read_at_most(path, max_bytes.saturating_add(1)) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Probe::Gone,
        // ELOOP: swapped for a link since `identify`.
        Err(e) if e.raw_os_error() == Some(libc::ELOOP) => {
            return Probe::Rejected(before, link_reason(path));
        }
        Err(e) if transient(&e) => return Probe::Unreadable(format!("cannot read: {e}")),
        Err(e) => return Probe::Rejected(before, format!("cannot read: {e}")),
    };
    match observe(path) {
        Ok(after) if after == observed => {}
        Ok(_) => return Probe::Changed,
        Err(_) => return Probe::Gone,
    }
    let inode = observed.inode;
    if bytes.is_empty() {
        return Probe::Rejected(before, "file is empty (0 bytes)".to_string());
    }
    match frame::probe_raw(path, &bytes) {
        Some(Ok((meta, (width, height)))) => {
            // The mosaic is decoded as one 16-bit sample per pixel.
            let footprint = Footprint {
                width,
                height,
                bytes_per_pixel: 2,
            };
            return capture(before, meta, footprint, inode, &bytes);
        }
        Some(Err(e)) => return Probe::Rejected(before, e.to_string()),
        None => {}
    }
    let header = image_footprint(&bytes);
    match header {
        Ok(footprint) => capture(before, metadata::read(&bytes), footprint, inode, &bytes),
        Err(reason) => Probe::Rejected(before, reason),
    }
}

/// The first `limit` bytes of `path`, opened without following a link.
fn read_at_most(path: &Path, limit: u64) -> std::io::Result<Vec<u8>> {
    use std::io::Read;
    let f = open_no_follow(path)?;
    let mut bytes = Vec::new();
    f.take(limit).read_to_end(&mut bytes)?;
    Ok(bytes)
}

/// The footprint of a JPEG, PNG or TIFF image from its header in `bytes` (a JPEG must
/// also be whole), or why it is not one.
fn image_footprint(bytes: &[u8]) -> Result<Footprint, String> {
    image::ImageReader::new(Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| e.to_string())
        .and_then(|r| match r.format() {
            Some(image::ImageFormat::Jpeg) if !jpeg_complete(bytes) => {
                Err("JPEG data ends before its end-of-image marker (truncated file)".to_string())
            }
            Some(image::ImageFormat::Jpeg | image::ImageFormat::Png | image::ImageFormat::Tiff) => {
                use image::ImageDecoder;
                r.into_decoder()
                    .map(|d| {
                        let (width, height) = d.dimensions();
                        Footprint {
                            width,
                            height,
                            bytes_per_pixel: u32::from(d.color_type().bytes_per_pixel()),
                        }
                    })
                    .map_err(|e| format!("unreadable image header: {e}"))
            }
            _ => Err("not a JPEG, PNG or TIFF image (unrecognised content)".to_string()),
        })
}

/// [`probe`], with a panic of a decoder or the EXIF reader on untrusted bytes turned into
/// the file's rejection with the panic's message: no file can take the service down.
pub(crate) fn probe_guarded(path: &Path, max_bytes: u64) -> Probe {
    std::panic::catch_unwind(|| probe(path, max_bytes)).unwrap_or_else(|panic| {
        let what = super::panic_text(&*panic);
        let input = identify(path).unwrap_or_else(|_| Input {
            path: path.to_path_buf(),
            size: 0,
            modified_ns: 0,
        });
        Probe::Rejected(input, format!("reading it made a decoder fail: {what}"))
    })
}

/// The index of the stems of the files in the ingest folder, kept as they are noticed:
/// the two files of one RAW+JPEG capture are found without listing any folder.
///
/// Two files are one capture when their stems are equal ignoring case (`IMG_1.CR2` and
/// `img_1.jpg`), one is a raw and the other not, and they are in the same folder or in
/// sibling folders (`RAW/IMG_1.CR2` and `JPG/IMG_1.JPG`, a common tool setting). Lookups
/// cost `O(k)` for the `k` files of one stem.
#[derive(Debug, Default)]
pub(crate) struct Stems {
    by_stem: HashMap<String, Vec<PathBuf>>,
}

impl Stems {
    fn key(path: &Path) -> Option<String> {
        path.file_stem().map(|s| s.to_string_lossy().to_lowercase())
    }

    /// Notes a file noticed in the ingest folder.
    pub(crate) fn insert(&mut self, path: &Path) {
        let Some(key) = Self::key(path) else {
            return;
        };
        let files = self.by_stem.entry(key).or_default();
        if !files.iter().any(|p| p == path) {
            files.push(path.to_path_buf());
        }
    }

    /// Forgets a file that is gone.
    pub(crate) fn remove(&mut self, path: &Path) {
        let Some(key) = Self::key(path) else {
            return;
        };
        if let Some(files) = self.by_stem.get_mut(&key) {
            files.retain(|p| p != path);
            if files.is_empty() {
                self.by_stem.remove(&key);
            }
        }
    }

    /// Forgets everything (before a full scan rebuilds it).
    pub(crate) fn clear(&mut self) {
        self.by_stem.clear();
    }

    /// The other files of `path`'s capture: same stem, same or sibling folder.
    fn partners<'a>(&'a self, path: &'a Path) -> impl Iterator<Item = &'a PathBuf> + 'a {
        let folder = path.parent();
        let above = folder.and_then(Path::parent);
        Self::key(path)
            .and_then(|k| self.by_stem.get(&k))
            .into_iter()
            .flatten()
            .filter(move |p| {
                p.as_path() != path
                    && (p.parent() == folder || p.parent().and_then(Path::parent) == above)
            })
    }

    /// The raw of the capture whose JPEG (PNG, TIFF) is `path`, when there is one.
    pub(crate) fn raw_of(&self, path: &Path) -> Option<PathBuf> {
        if is_raw(path) {
            return None;
        }
        self.partners(path).find(|p| is_raw(p)).cloned()
    }

    /// The JPEG (PNG, TIFF) of the capture whose raw is `path`, when there is one.
    pub(crate) fn companion_of(&self, path: &Path) -> Option<PathBuf> {
        if !is_raw(path) {
            return None;
        }
        self.partners(path).find(|p| !is_raw(p)).cloned()
    }
}

/// True for a camera raw's name, when filmback reads raws.
pub(crate) fn is_raw(path: &Path) -> bool {
    #[cfg(feature = "raw")]
    {
        crate::raw::is_raw_extension(path)
    }
    #[cfg(not(feature = "raw"))]
    {
        let _ = path;
        false
    }
}

/// A frame probed: its camera, exposure and capture time (the file's time when the EXIF
/// has none), its decoded size, the digest of its `bytes` and its inode.
fn capture(
    before: Input,
    meta: metadata::Metadata,
    footprint: Footprint,
    inode: (u64, u64),
    bytes: &[u8],
) -> Probe {
    let time_s = meta
        .captured_at
        .map_or(before.modified_ns as f64 * 1e-9, |t| t.local_seconds());
    Probe::Frame(
        Capture {
            camera: CameraId {
                make: meta.camera.make,
                model: meta.camera.model,
                serial: meta.camera.serial,
            },
            exposure: meta.exposure.relative(),
            time_s,
            input: before,
            companion: None,
        },
        Taken {
            footprint,
            digest: journal::content_digest(bytes),
            inode,
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic::demo;

    /// The watcher tells a file handed over by filmback (renamed from its temporary
    /// name) from one renamed into place by another writer, and both from a new file.
    #[test]
    fn a_hand_over_by_filmback_is_told_from_other_arrivals() {
        let dir = tempfile::tempdir().unwrap();
        let (ingest, elsewhere) = (dir.path().join("ingest"), dir.path().join("dl"));
        std::fs::create_dir_all(&ingest).unwrap();
        std::fs::create_dir_all(&elsewhere).unwrap();
        let watch = crate::daemon::config::Config::defaults().watch;
        let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel();
        let _watcher = super::watch(&watch, &ingest, tx).unwrap();
        std::fs::write(elsewhere.join("a.jpg"), b"a").unwrap();
        atomic::move_into(&elsewhere.join("a.jpg"), &ingest).unwrap();
        std::fs::write(ingest.join("b.jpg.part"), b"b").unwrap();
        std::fs::rename(ingest.join("b.jpg.part"), ingest.join("b.jpg")).unwrap();
        std::fs::write(ingest.join("c.jpg"), b"c").unwrap();
        // What each file's notices said last, writes aside (as settling keeps it: notify
        // sends a rename's `To` half, Closed, before the paired event, Delivered).
        let mut said: HashMap<String, Arrival> = HashMap::new();
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
        while said.len() < 3 || said.get("c.jpg") != Some(&Arrival::Closed) {
            assert!(
                std::time::Instant::now() < deadline,
                "notices so far: {said:?}"
            );
            let Ok(notice) = rx.try_recv() else {
                std::thread::sleep(std::time::Duration::from_millis(10));
                continue;
            };
            if let Notice::File { path, arrival } = notice {
                let name = path.file_name().unwrap().to_string_lossy().into_owned();
                let entry = said.entry(name).or_insert(arrival);
                if arrival != Arrival::Writing {
                    *entry = arrival;
                }
            }
        }
        assert_eq!(said["a.jpg"], Arrival::Delivered);
        assert_eq!(said["b.jpg"], Arrival::Closed);
        assert_eq!(said.len(), 3, "{said:?}");
    }

    #[cfg(feature = "raw")]
    #[test]
    fn the_stem_index_pairs_raw_and_jpeg_in_one_or_sibling_folders() {
        let mut stems = Stems::default();
        for p in [
            "/in/IMG_1.CR2",
            "/in/img_1.jpg",
            "/in/RAW/IMG_2.CR2",
            "/in/JPG/IMG_2.JPG",
            "/in/a/b/IMG_3.NEF",
            "/in/c/IMG_3.jpg",
            "/in/IMG_4.jpg",
        ] {
            stems.insert(Path::new(p));
        }
        let raw = |stems: &Stems, p: &str| stems.raw_of(Path::new(p));
        let jpeg = |stems: &Stems, p: &str| stems.companion_of(Path::new(p));
        assert_eq!(raw(&stems, "/in/img_1.jpg"), Some("/in/IMG_1.CR2".into()));
        assert_eq!(jpeg(&stems, "/in/IMG_1.CR2"), Some("/in/img_1.jpg".into()));
        assert_eq!(
            raw(&stems, "/in/JPG/IMG_2.JPG"),
            Some("/in/RAW/IMG_2.CR2".into())
        );
        assert_eq!(
            jpeg(&stems, "/in/RAW/IMG_2.CR2"),
            Some("/in/JPG/IMG_2.JPG".into())
        );
        // Not siblings (a deeper folder): two captures that share a counter.
        assert_eq!(raw(&stems, "/in/c/IMG_3.jpg"), None);
        assert_eq!(raw(&stems, "/in/IMG_4.jpg"), None);
        assert_eq!(
            raw(&stems, "/in/IMG_1.CR2"),
            None,
            "a raw has no raw partner"
        );
        stems.remove(Path::new("/in/IMG_1.CR2"));
        assert_eq!(raw(&stems, "/in/img_1.jpg"), None);
        stems.clear();
        assert_eq!(raw(&stems, "/in/JPG/IMG_2.JPG"), None);
    }

    /// Every spelling of a file in the ingest folder gives one identity.
    #[test]
    fn one_identity_for_every_spelling_of_an_ingest_file() {
        let dir = tempfile::tempdir().unwrap();
        let real = std::fs::canonicalize(dir.path()).unwrap();
        std::fs::create_dir_all(real.join("srv/ingest/sub")).unwrap();
        std::os::unix::fs::symlink(real.join("srv"), real.join("link")).unwrap();
        let root = IngestRoot::new(&real.join("link/./ingest/"));
        let want = real.join("srv/ingest/a.jpg");
        assert_eq!(root.real(), real.join("srv/ingest"));
        for spelled in [
            real.join("srv/ingest/a.jpg"),
            real.join("srv/./ingest//a.jpg"),
            real.join("link/ingest/a.jpg"),
            real.join("link/./ingest/a.jpg"),
        ] {
            assert_eq!(root.identity(&spelled), want, "{}", spelled.display());
        }
        assert_eq!(
            root.identity(&real.join("link/ingest/sub/b.jpg")),
            real.join("srv/ingest/sub/b.jpg")
        );
        // A relative spelling is taken from the working directory.
        let relative = root.identity(Path::new("x.jpg"));
        assert_eq!(relative, std::env::current_dir().unwrap().join("x.jpg"));
    }

    #[test]
    fn truncated_jpeg_is_incomplete() {
        let shots = demo::aeb("Body", None, 1);
        let jpeg = demo::jpegs(96, 64, &shots, 3).unwrap().remove(1);
        assert!(jpeg_complete(&jpeg));
        for cut in [jpeg.len() - 1, jpeg.len() / 2, jpeg.len() / 3, 100] {
            assert!(!jpeg_complete(&jpeg[..cut]), "cut at {cut}");
        }
        assert!(!jpeg_complete(b""));
    }

    #[test]
    fn probe_reads_exif_and_rejects_with_reasons() {
        let dir = tempfile::tempdir().unwrap();
        let shots = demo::aeb("Body", Some("9"), 1);
        let jpeg = demo::jpegs(96, 64, &shots, 3).unwrap().remove(2);
        let good = dir.path().join("a.jpg");
        std::fs::write(&good, &jpeg).unwrap();
        match probe(&good, u64::MAX) {
            Probe::Frame(c, Taken { footprint: fp, .. }) => {
                assert_eq!((fp.width, fp.height, fp.bytes_per_pixel), (96, 64, 3));
                assert_eq!(c.camera.serial.as_deref(), Some("9"));
                assert!((c.exposure.unwrap() - 100.0 / 15.0 / 64.0).abs() < 1e-9);
                assert_eq!(c.input.size, jpeg.len() as u64);
            }
            other => panic!("{other:?}"),
        }
        // Larger than the budget: refused before it is read.
        let small = jpeg.len() as u64 - 1;
        assert!(matches!(
            probe(&good, small),
            Probe::Rejected(_, r) if r.contains("larger than the memory budget")
        ));
        let cut = dir.path().join("b.jpg");
        std::fs::write(&cut, &jpeg[..jpeg.len() / 2]).unwrap();
        let p = probe(&cut, u64::MAX);
        assert!(
            matches!(&p, Probe::Rejected(_, r) if r.contains("truncated")),
            "{p:?}"
        );
        let empty = dir.path().join("c.jpg");
        std::fs::write(&empty, b"").unwrap();
        assert!(matches!(probe(&empty, u64::MAX), Probe::Rejected(_, r) if r.contains("empty")));
        assert!(matches!(
            probe(&dir.path().join("none.jpg"), u64::MAX),
            Probe::Gone
        ));
        let fifo = dir.path().join("e.jpg");
        assert!(
            std::process::Command::new("mkfifo")
                .arg(&fifo)
                .status()
                .unwrap()
                .success()
        );
        let p = probe(&fifo, u64::MAX);
        assert!(
            matches!(&p, Probe::Rejected(_, r) if r.contains("not a regular file")),
            "{p:?}"
        );
        let link = dir.path().join("d.jpg");
        std::os::unix::fs::symlink(&good, &link).unwrap();
        let p = probe(&link, u64::MAX);
        assert!(
            matches!(&p, Probe::Rejected(i, r) if r.contains("not followed") && i.path == link),
            "{p:?}"
        );
    }
}
