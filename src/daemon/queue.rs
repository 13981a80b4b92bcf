//! The queue: closed brackets become jobs for the lab (at most `jobs` at a time), and a
//! job's outcome becomes a journal entry, a cache update, a rejection or a retry.

use std::ffi::{OsStr, OsString};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use tracing::{error, info, warn};

use super::bracket::{Alone, Bracket, CameraId, Capture, Closed};
use super::cache::{DISSENTS_TO_REPLACE, Dissent, PooledBracket};
use super::config::{Recalibrate, Singles};
use super::intake::{self, Arrival};
use super::journal::{self, Entry};
use super::{
    DaemonError, Job, JobError, Outcome, Processed, State, Superseded, Work, backoff, budget,
    file_stem, job_bytes,
};
use crate::atomic;
use crate::darkroom::{self, Pooling};

/// How many times a bracket waits (with back-off) for a frame that is not on disk before
/// it is developed without it: `retry_s · (1 + 2 + 4 + 8)`, 75 s at the default 5 s.
const MISSING_RETRIES: u32 = 4;

/// Most numbered names tried for one file in the archive (`IMG_0001-1.JPG` …).
const ARCHIVE_NUMBERS: u32 = 10_000;

impl State {
    /// Starts queued jobs while there is room (`jobs`, the memory budget) at `now`.
    pub(super) fn dispatch(&mut self, now: Instant) -> Result<(), DaemonError> {
        while !self.stopping && self.in_flight.len() < self.config.daemon.jobs {
            let Some(mut work) = self.queue.pop_front() else {
                break;
            };
            if let Some(missing) = missing_frame(&work.closed) {
                self.frame_missing(work, &missing, now);
                continue;
            }
            // The memory budget: a job starts when its estimate fits beside those
            // developing; one that cannot fit even alone is recorded as failed.
            let need = self.job_bytes(&work.closed);
            let budget = self.budget_bytes();
            let single_reported = matches!(&work.closed, Closed::Single(..))
                && self.config.bracket.singles == Singles::Report;
            if !single_reported && !self.in_use.fits(need, budget) {
                if self.in_flight.is_empty() {
                    let reason = format!(
                        "needs {}",
                        budget::over_budget(need, self.config.daemon.memory_mb)
                    );
                    self.failed(&work, reason)?;
                    continue;
                }
                self.queue.push_front(work);
                break;
            }
            if let Closed::Single(capture, alone) = &work.closed
                && self.config.bracket.singles == Singles::Report
            {
                self.report_single(&work.closed, capture, *alone)?;
                continue;
            }
            let job = self.job(&mut work);
            self.start(work, job, need);
        }
        Ok(())
    }

    /// Journals the single `capture` of `closed` as reported, not rendered, because it
    /// was `alone`, and releases its file.
    fn report_single(
        &mut self,
        closed: &Closed,
        capture: &Capture,
        alone: Alone,
    ) -> Result<(), DaemonError> {
        info!(file = %capture.input.path.display(), camera = %capture.camera, reason = %alone, "single frame reported, not rendered");
        self.journal.record(Entry::Single {
            id: closed.id(),
            camera: capture.camera.clone(),
            input: capture.input.clone(),
            alone,
            outputs: Vec::new(),
            digests: self
                .files
                .taken(&capture.input.path)
                .map(|t| vec![t.digest])
                .unwrap_or_default(),
            at: journal::unix_now(),
        })?;
        self.summary.finished += 1;
        self.release(closed);
        Ok(())
    }

    /// The lab's job for `work`: its frames (with the JPEGs set aside beside raws, as
    /// they have settled by now), its camera's preset, the cached response unless the
    /// preset always recalibrates, and where and under which stem to publish.
    fn job(&mut self, work: &mut Work) -> Job {
        for frame in work.closed.frames_mut() {
            if frame.companion.is_none() {
                frame.companion = self.files.companion_of(&frame.input.path).cloned();
            }
        }
        let camera = work.closed.camera().clone();
        let preset = self
            .config
            .preset_for(camera.model.as_deref(), camera.serial.as_deref())
            .clone();
        let cached = match self.cache.get(&camera) {
            Ok(c) => c,
            Err(e) => {
                warn!(error = %e, "response cache entry unusable; developing without it");
                None
            }
        };
        Job {
            id: work.closed.id(),
            camera,
            frames: work.closed.frames().into_iter().cloned().collect(),
            cached: if preset.recalibrate == Recalibrate::Always {
                None
            } else {
                cached
            },
            preset,
            out: self.config.folders.out.clone(),
            stem: work
                .supersedes
                .as_ref()
                .map_or_else(|| self.output_stem(&work.closed), |s| s.stem.clone()),
            stocks: self.config.folders.stocks.clone(),
            previews: self.viewer.is_some(),
        }
    }

    /// Reserves `need` bytes of the budget for `work` and develops its `job` on a
    /// blocking thread; a panic of the lab is the bracket's failure.
    fn start(&mut self, mut work: Work, job: Job, need: u64) {
        let lab = Arc::clone(&self.lab);
        self.in_use.reserve(need);
        work.reserved = need;
        self.in_flight.spawn_blocking(move || {
            let t = Instant::now();
            let result =
                std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| lab.process(&job)))
                    .unwrap_or_else(|panic| {
                        let what = super::panic_text(&*panic);
                        Err(JobError::Bracket(format!("lab panicked: {what}").into()))
                    });
            (work, result, t.elapsed())
        });
    }

    /// The first frame's stem, unless an earlier, different bracket already published
    /// under it (a camera's file counter wrapped, or inputs were replaced): then
    /// `<stem>-<first 8 hex digits of the id>`, so no finished output is ever replaced.
    pub(super) fn output_stem(&self, closed: &Closed) -> String {
        let (stem, id) = (closed.stem(), closed.id());
        let taken = self.journal.entries().iter().any(|e| match e {
            Entry::Bracket {
                id: other, inputs, ..
            } => *other != id && inputs.first().is_some_and(|i| file_stem(&i.path) == stem),
            Entry::Single {
                id: other,
                input,
                outputs,
                ..
            } => *other != id && !outputs.is_empty() && file_stem(&input.path) == stem,
            _ => false,
        });
        if taken {
            format!("{stem}-{}", &id[..8])
        } else {
            stem
        }
    }

    /// A good bracket's evidence into the body's pool, or aside as a dissent when it
    /// contradicted the cached curve (see [`crate::daemon::cache`]); failures are
    /// warnings, the outputs stand.
    fn pool(&self, camera: &CameraId, name: &str, dev: &Processed, pooling: &Pooling) {
        let now = journal::unix_now();
        let bracket = PooledBracket {
            name: name.to_string(),
            at: now,
            own_confidence: pooling.own_confidence.iter().copied().fold(1.0, f64::min),
            own_misfit: pooling.own_misfit,
            evidence: pooling.evidence.clone(),
        };
        let result = if dev.contradicts_cache {
            self.cache.dissent(camera, bracket, now).map(|(entry, d)| match d {
                Dissent::Kept(n) => info!(
                    camera = %camera,
                    "bracket {name} contradicts the body's curve; kept aside ({n} of {DISSENTS_TO_REPLACE} in a row replace it)"
                ),
                Dissent::Replaced => warn!(
                    camera = %camera,
                    "the body's curve changed: {DISSENTS_TO_REPLACE} brackets in a row agree with each other and not with the old pool; they replace it (confidence {:.2})",
                    entry.min_confidence().unwrap_or(0.0)
                ),
            })
        } else {
            let (curve, confidence) = match (&pooling.pooled, &dev.fit) {
                (Some((curve, confidence)), _) => (curve, confidence.clone()),
                (None, Some((own, _))) => (own, pooling.own_confidence.clone()),
                (None, None) => return,
            };
            self.cache
                .pool(camera, bracket, curve, confidence, now)
                .map(|_| ())
        };
        if let Err(e) = result {
            warn!(error = %e, "cannot update the response cache");
        }
    }

    pub(super) fn release(&mut self, closed: &Closed) {
        for f in closed.frames() {
            self.files.release(&f.input.path);
        }
    }

    /// The memory estimate of a closed group ([`job_bytes`] of its frames' footprints;
    /// a frame without one, e.g. from a test, counts nothing), and
    /// [`darkroom::DNG_BYTES_PER_PIXEL`] of its largest frame when its preset writes a
    /// raw bracket's DNG.
    pub(super) fn job_bytes(&self, closed: &Closed) -> u64 {
        let frames: Vec<_> = closed
            .frames()
            .iter()
            .filter_map(|c| self.files.taken(&c.input.path).map(|t| t.footprint))
            .collect();
        let camera = closed.camera();
        let dng = matches!(closed, Closed::Bracket(_))
            && self
                .config
                .preset_for(camera.model.as_deref(), camera.serial.as_deref())
                .dng
            && closed
                .frames()
                .iter()
                .all(|c| intake::is_raw(&c.input.path));
        let largest = frames
            .iter()
            .map(|f| u64::from(f.width) * u64::from(f.height))
            .max()
            .unwrap_or(0);
        job_bytes(&frames)
            + if dng {
                darkroom::DNG_BYTES_PER_PIXEL * largest
            } else {
                0
            }
    }

    /// Takes a job's outcome: journal and cache on success; on a bad frame, reject it and
    /// requeue the rest; retry output failures with back-off; record other failures.
    pub(super) fn finish(
        &mut self,
        (work, result, took): Outcome,
        now: Instant,
    ) -> Result<(), DaemonError> {
        self.in_use.release(work.reserved);
        match result {
            Ok(processed) => self.developed(&work, &processed, took, now)?,
            // A frame not on disk now (moved away, being replaced): not a verdict on it.
            Err(JobError::Frame { path, .. })
                if is_missing(&path)
                    && work.closed.frames().iter().any(|c| c.input.path == path) =>
            {
                self.frame_missing(work, &path, now);
            }
            Err(JobError::Frame { path, reason }) => {
                self.frame_failed(&work, &path, reason.to_string(), now)?;
            }
            Err(e @ JobError::Output { .. }) => {
                error!(bracket = %work.closed.stem(), error = %e, "outputs not written");
                self.retry_later(work, e.to_string(), now);
            }
            Err(JobError::Bracket(reason)) => self.failed(&work, reason.to_string())?,
        }
        Ok(())
    }

    /// A job that published its outputs: refine the cache, journal it, log it, archive.
    pub(super) fn developed(
        &mut self,
        work: &Work,
        dev: &Processed,
        took: Duration,
        now: Instant,
    ) -> Result<(), DaemonError> {
        let closed = &work.closed;
        let digests: Vec<u64> = closed
            .frames()
            .iter()
            .map(|c| self.files.taken(&c.input.path).map(|t| t.digest))
            .collect::<Option<_>>()
            .unwrap_or_default();
        let camera = closed.camera().clone();
        self.learn(&camera, closed, dev);
        for note in &dev.notes {
            warn!(bracket = %closed.stem(), "{note}");
        }
        let stem = work
            .supersedes
            .as_ref()
            .map_or_else(|| self.output_stem(closed), |s| s.stem.clone());
        self.journal
            .record(developed_entry(closed, &camera, dev, digests))?;
        if let Some(old) = &work.supersedes {
            remove_stale(old, &dev.outputs);
        }
        self.summary.finished += 1;
        log_developed(closed, &camera, dev, took);
        let replaced = self.replaced_since_read(closed);
        let archived = if replaced.is_empty() {
            self.archive(closed)
        } else {
            Vec::new()
        };
        self.announce(closed, dev, stem, took, &archived);
        self.release(closed);
        for path in replaced {
            info!(file = %path.display(), "replaced while its bracket developed: developing it again");
            self.consider(path, Arrival::Writing, now);
        }
        Ok(())
    }

    /// Refines `camera`'s cached response with what developing `closed` measured: its
    /// pooled pairs when the preset recalibrates automatically, a JPEG curve measured.
    fn learn(&mut self, camera: &CameraId, closed: &Closed, dev: &Processed) {
        let preset = self
            .config
            .preset_for(camera.model.as_deref(), camera.serial.as_deref());
        if let Some(pooling) = &dev.pooling
            && preset.recalibrate == Recalibrate::Auto
        {
            self.pool(camera, &closed.stem(), dev, pooling);
        }
        if let Some(measured) = &dev.measured
            && let Err(e) = self
                .cache
                .put_measured(camera, measured, journal::unix_now())
        {
            warn!(error = %e, "cannot store the measured JPEG curve in the response cache");
        }
    }

    /// Tells the viewer and the `on_developed` hook that `closed` was published under
    /// `stem`; `archived` lists the inputs moved to the archive and where.
    fn announce(
        &mut self,
        closed: &Closed,
        dev: &Processed,
        stem: String,
        took: Duration,
        archived: &[(PathBuf, PathBuf)],
    ) {
        if let Some(viewer) = &self.viewer {
            let frame_paths = closed
                .frames()
                .iter()
                .map(|c| {
                    archived
                        .iter()
                        .find(|(from, _)| *from == c.input.path)
                        .map_or_else(|| c.input.path.clone(), |(_, to)| to.clone())
                })
                .collect();
            viewer.developed(super::viewer::Published {
                record: super::viewer::record_of(closed, dev, &stem, took),
                frame_paths,
                pictures: dev.pictures.clone(),
            });
        }
        if let Some(command) = self.config.hooks.on_developed.clone() {
            let run = super::hooks::Developed {
                command,
                stem,
                camera: closed.camera().to_string(),
                outputs: dev.outputs.clone(),
            };
            self.hooks
                .get_or_insert_with(super::hooks::Hooks::start)
                .developed(run);
        }
    }

    /// The frames of `closed` whose file is no longer the one read (another size, mtime
    /// or inode): written again while their bracket developed.
    fn replaced_since_read(&self, closed: &Closed) -> Vec<PathBuf> {
        closed
            .frames()
            .into_iter()
            .filter(|c| {
                intake::observe(&c.input.path).is_ok_and(|seen| {
                    seen.input != c.input
                        || self
                            .files
                            .taken(&c.input.path)
                            .is_some_and(|t| t.inode != seen.inode())
                })
            })
            .map(|c| c.input.path.clone())
            .collect()
    }

    /// A frame of `work` is not on disk: moved away for a moment, or being replaced. The
    /// bracket waits for it with back-off ([`State::retry_later`]), nothing journaled;
    /// after [`MISSING_RETRIES`] it is developed without it (a file that comes back
    /// later is new work).
    fn frame_missing(&mut self, work: Work, path: &Path, now: Instant) {
        if work.attempts < MISSING_RETRIES {
            let reason = format!(
                "{}: not on disk now; its bracket waits for it",
                path.display()
            );
            warn!(bracket = %work.closed.stem(), file = %path.display(), "a frame is missing; its bracket waits for it");
            self.retry_later(work, reason, now);
            return;
        }
        warn!(bracket = %work.closed.stem(), file = %path.display(), "a frame stayed missing; its bracket is developed without it");
        self.files.release(path);
        self.requeue_without(&work.closed, path);
    }

    /// Queues the frames of `closed` but the one at `path` (a single when one is left).
    fn requeue_without(&mut self, closed: &Closed, path: &Path) {
        let camera = closed.camera().clone();
        let rest: Vec<_> = closed
            .frames()
            .into_iter()
            .filter(|c| c.input.path != *path)
            .cloned()
            .collect();
        let closed = match rest.len() {
            0 => return,
            1 => Closed::Single(rest.into_iter().next().expect("one"), Alone::NoPartner),
            _ => Closed::Bracket(Bracket {
                camera,
                frames: rest,
            }),
        };
        self.queue.push_front(Work::new(closed));
    }

    /// A frame of the job could not be decoded: reject it, requeue the rest (a single if
    /// one frame is left).
    pub(super) fn frame_failed(
        &mut self,
        work: &Work,
        path: &Path,
        reason: String,
        now: Instant,
    ) -> Result<(), DaemonError> {
        let closed = &work.closed;
        let frames: Vec<_> = closed.frames().into_iter().cloned().collect();
        let Some(bad) = frames.iter().find(|c| c.input.path == *path) else {
            return self.failed(
                work,
                format!("lab named a foreign frame {}: {reason}", path.display()),
            );
        };
        self.reject(bad.input.clone(), reason, now)?;
        self.requeue_without(closed, path);
        Ok(())
    }

    /// Outputs could not be written, or a frame is missing, at `now`: try again after
    /// [`backoff::delay`]; `status` shows the `reason`.
    pub(super) fn retry_later(&mut self, work: Work, reason: String, now: Instant) {
        let delay = backoff::delay(self.config.daemon.retry, work.attempts);
        info!(
            bracket = %work.closed.stem(),
            retry_in_s = delay.as_secs_f64(),
            "will retry"
        );
        if let Some(viewer) = &self.viewer {
            viewer.retry(super::Retry {
                what: work.closed.stem(),
                reason: reason.clone(),
                attempts: work.attempts + 1,
                next: journal::unix_now() + delay.as_secs(),
            });
        }
        self.retries.push((
            now + delay,
            Work {
                attempts: work.attempts + 1,
                ..work
            },
            reason,
        ));
    }

    pub(super) fn failed(&mut self, work: &Work, reason: String) -> Result<(), DaemonError> {
        warn!(bracket = %work.closed.stem(), reason = %reason, "bracket cannot be developed");
        self.journal.record(Entry::Failed {
            id: work.closed.id(),
            inputs: work
                .closed
                .frames()
                .iter()
                .map(|c| c.input.clone())
                .collect(),
            reason,
            at: journal::unix_now(),
        })?;
        self.release(&work.closed);
        Ok(())
    }

    /// Moves finished inputs to the archive folder, when configured, with the JPEGs set
    /// aside beside their raws ([`archive_file`]: never replacing an archived file).
    /// Returns each file moved and where it went.
    pub(super) fn archive(&self, closed: &Closed) -> Vec<(PathBuf, PathBuf)> {
        let Some(dir) = &self.config.folders.archive else {
            return Vec::new();
        };
        let mut moved = Vec::new();
        let files = closed
            .frames()
            .into_iter()
            .flat_map(|c| std::iter::once(&c.input).chain(c.companion.as_ref()));
        for input in files {
            match archive_file(&input.path, &self.config.folders.ingest, dir) {
                Ok(to) => {
                    tracing::debug!(file = %input.path.display(), to = %to.display(), "archived");
                    moved.push((input.path.clone(), to));
                }
                Err(e) => {
                    warn!(file = %input.path.display(), archive = %dir.display(), error = %e, "cannot archive input");
                }
            }
        }
        moved
    }
}

/// The first frame of `closed` that is not on disk.
fn missing_frame(closed: &Closed) -> Option<PathBuf> {
    closed
        .frames()
        .into_iter()
        .map(|c| &c.input.path)
        .find(|p| is_missing(p))
        .cloned()
}

/// True when nothing is at `path` (`ENOENT`; a link counts as something).
fn is_missing(path: &Path) -> bool {
    std::fs::symlink_metadata(path).is_err_and(|e| e.kind() == std::io::ErrorKind::NotFound)
}

/// Moves `file`, found below `ingest`, into `archive` at the same path below it (the
/// sub-folders of a `recursive` watch are kept), never replacing a file there: when the
/// name is taken (a camera's counter wrapped, two sub-folders with one name) it becomes
/// `<stem>-1.<ext>`, `<stem>-2.<ext>`, … (`IMG_0001.JPG` → `IMG_0001-1.JPG`), each tried
/// with a rename that refuses to replace ([`atomic::rename_no_replace`]). Returns where
/// the file went.
fn archive_file(file: &Path, ingest: &Path, archive: &Path) -> std::io::Result<PathBuf> {
    let below = file.strip_prefix(ingest).unwrap_or(file);
    let name = below
        .file_name()
        .ok_or_else(|| std::io::Error::other("no file name"))?;
    let folder = match below.parent() {
        Some(sub) if file.starts_with(ingest) => archive.join(sub),
        _ => archive.to_path_buf(),
    };
    std::fs::create_dir_all(&folder)?;
    for n in 0..ARCHIVE_NUMBERS {
        let target = folder.join(numbered(name, n));
        match atomic::rename_no_replace(file, &target) {
            Ok(()) => return Ok(target),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {}
            Err(e) => return Err(e),
        }
    }
    Err(std::io::Error::new(
        std::io::ErrorKind::AlreadyExists,
        format!("{ARCHIVE_NUMBERS} files of this name are archived already"),
    ))
}

/// `name` with `-n` before its extension (`IMG_0001.JPG`, 2 → `IMG_0001-2.JPG`); `name`
/// itself for 0. Names that are not UTF-8 keep their bytes.
fn numbered(name: &OsStr, n: u32) -> OsString {
    if n == 0 {
        return name.to_os_string();
    }
    let path = Path::new(name);
    let mut out = path.file_stem().unwrap_or(name).to_os_string();
    out.push(format!("-{n}"));
    if let Some(ext) = path.extension() {
        out.push(".");
        out.push(ext);
    }
    out
}

/// The journal entry of `closed`, developed by `camera` into `dev`'s outputs; `digests`
/// are its inputs' contents as read.
fn developed_entry(
    closed: &Closed,
    camera: &CameraId,
    dev: &Processed,
    digests: Vec<u64>,
) -> Entry {
    let at = journal::unix_now();
    match closed {
        Closed::Bracket(b) => Entry::Bracket {
            id: closed.id(),
            camera: camera.clone(),
            inputs: b.frames.iter().map(|c| c.input.clone()).collect(),
            outputs: dev.outputs.clone(),
            digests,
            ratio: b.ratio(),
            response: dev.source,
            at,
        },
        Closed::Single(c, alone) => Entry::Single {
            id: closed.id(),
            camera: camera.clone(),
            input: c.input.clone(),
            alone: *alone,
            outputs: dev.outputs.clone(),
            digests,
            at,
        },
    }
}

/// Removes the outputs of the earlier development `old` that the new `outputs` did not
/// replace: they are stale.
fn remove_stale(old: &Superseded, outputs: &[PathBuf]) {
    for stale in old.outputs.iter().filter(|o| !outputs.contains(o)) {
        match std::fs::remove_file(stale) {
            Ok(()) => info!(file = %stale.display(), "removed stale output"),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => {
                warn!(file = %stale.display(), error = %e, "cannot remove stale output")
            }
        }
    }
}

/// Logs `closed` as developed by `camera` in `took`: its stages' times and outputs.
fn log_developed(closed: &Closed, camera: &CameraId, dev: &Processed, took: Duration) {
    let stages: Vec<String> = dev
        .stages
        .iter()
        .map(|(s, d)| format!("{s}={:.0}ms", d.as_secs_f64() * 1e3))
        .collect();
    let outputs: Vec<String> = dev
        .outputs
        .iter()
        .map(|p| p.display().to_string())
        .collect();
    match closed {
        Closed::Bracket(b) => info!(
            camera = %camera,
            frames = b.frames.len(),
            ratio = format!("{:.2}", b.ratio()),
            response = %dev.source,
            stages = stages.join(" "),
            total_ms = took.as_millis() as u64,
            outputs = outputs.join(" "),
            "bracket developed"
        ),
        Closed::Single(c, alone) => info!(
            camera = %camera,
            file = %c.input.path.display(),
            reason = %alone,
            response = %dev.source,
            total_ms = took.as_millis() as u64,
            outputs = outputs.join(" "),
            "single frame rendered"
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A second file of an archived name (a camera's counter wrapped) and a same-named
    /// file of a sub-folder never replace the archived ones.
    #[test]
    fn the_archive_never_replaces_an_archived_file() {
        let dir = tempfile::tempdir().unwrap();
        let (ingest, archive) = (dir.path().join("ingest"), dir.path().join("archive"));
        std::fs::create_dir_all(ingest.join("session")).unwrap();
        for (k, content) in ["first", "second", "third"].iter().enumerate() {
            let file = ingest.join("IMG_0001.JPG");
            std::fs::write(&file, content).unwrap();
            let to = archive_file(&file, &ingest, &archive).unwrap();
            let want = if k == 0 {
                "IMG_0001.JPG".to_string()
            } else {
                format!("IMG_0001-{k}.JPG")
            };
            assert_eq!(to, archive.join(want));
            assert!(!file.exists());
        }
        let deeper = ingest.join("session/IMG_0001.JPG");
        std::fs::write(&deeper, "fourth").unwrap();
        let to = archive_file(&deeper, &ingest, &archive).unwrap();
        assert_eq!(to, archive.join("session/IMG_0001.JPG"));
        for (name, content) in [
            ("IMG_0001.JPG", "first"),
            ("IMG_0001-1.JPG", "second"),
            ("IMG_0001-2.JPG", "third"),
            ("session/IMG_0001.JPG", "fourth"),
        ] {
            assert_eq!(
                std::fs::read_to_string(archive.join(name)).unwrap(),
                content
            );
        }
        assert_eq!(numbered(OsStr::new("README"), 3), "README-3");
    }
}
