//! Watching and settling: files noticed in the ingest folder become candidates, settled
//! candidates are probed (EXIF, header) and fed to the grouper in capture-time order.
//!
//! **Settling** trusts no single signal of the writer: a candidate is taken once what
//! [`intake::observe`] reads of it (size, mtime, `ctime`, device and inode) has not changed
//! for `settle` on the daemon's monotonic clock, or for [`FINISHED_QUIET`] (250 ms, at most
//! `settle`) after its writer closed it or it was renamed into place, or as soon as it is
//! seen when it was renamed into place from a filmback temporary name (`filmback hook`'s
//! hand-over, [`atomic::move_into`], with inotify on a file system that has
//! `RENAME_NOREPLACE`: whole; a write notice after it makes it wait as a closed file).
//! Never by its mtime
//! (gphoto2 sets it to the capture time, in the past, and across file systems copies
//! under the final name); a rewrite just after the close (digiCamControl copies
//! non-atomically and may rewrite the EXIF), a `utime` or a replacement changes `ctime` or
//! the inode and restarts the wait; a later rewrite is a new version of the frame, and
//! its bracket is developed again (the journal compares contents). The probe then checks the content (a JPEG ends with its end-of-image marker,
//! a raw's header decodes; a raw whose pixels do not decode is rejected by the lab and
//! taken again if it changes).
//!
//! **RAW+JPEG**: the two files of one capture (same stem, one a raw, same or sibling
//! folder; [`intake::Stems`], an index kept as files are noticed) are one frame, the raw.
//! A JPEG whose raw has been noticed (even while it is still being written) is set aside
//! unread; the raw's [`Capture::companion`] names it. A JPEG that settles first:
//! - of a body already seen shooting RAW+JPEG in this run, it waits for its raw up to the
//!   bracket gap `max_gap_s` (the raw of the same capture comes well within the gap to
//!   the next frame), holding its body's open bracket meanwhile; then it is a frame.
//! - of any other body, it is a frame at once; should its raw arrive while its bracket is
//!   still open, the raw takes its place (and the body is learnt).
//!
//! A raw rejected (unsupported camera, bad data) gives its JPEG back: the JPEG is then
//! the frame.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use tracing::{error, info, warn};

use super::bracket::{Alone, Bracket, CameraId, Capture, Closed, Input};
use super::intake::{self, Arrival, Notice, Probe};
use super::journal::{self, Entry};
use super::{
    DaemonError, REDO_FOLDER, State, Superseded, Work, files::FileState, files::Held, folder_id,
    job_bytes,
};
use crate::atomic;

impl State {
    /// Notices the ingest folder appearing, disappearing or being replaced, and
    /// (re)starts the watcher with a full scan when it (re)appears.
    pub(super) async fn check_folder(&mut self, now: Instant) {
        let dir = self.config.folders.ingest.clone();
        let id = folder_id(&dir);
        if id == self.watched && (id.is_none() || self.watcher.is_some()) {
            return;
        }
        if id == self.watched && now < self.watch_retry_at {
            return;
        }
        self.watcher = None;
        self.watched = id;
        if id.is_none() {
            warn!(ingest = %dir.display(), "ingest folder is missing; waiting for it to reappear");
            return;
        }
        match intake::watch(&self.config.watch, &dir, self.notices.clone()) {
            Ok(w) => {
                self.watcher = Some(w);
                info!(ingest = %dir.display(), "watching ingest folder");
            }
            // Keep going on scans alone (every `poll`); try again in 10 s.
            Err(e) => {
                error!(error = %e, "cannot watch; falling back to periodic scans");
                self.watch_retry_at = now + Duration::from_secs(10);
            }
        }
        self.rescan(now).await;
    }

    /// Lists the ingest folder ([`intake::scan`]) on a blocking thread, off the loop: a
    /// slow or huge folder (a network share) does not stall the service.
    async fn listing(&self) -> Vec<PathBuf> {
        let (watch, dir) = (
            self.config.watch.clone(),
            self.config.folders.ingest.clone(),
        );
        tokio::task::spawn_blocking(move || intake::scan(&watch, &dir))
            .await
            .unwrap_or_else(|e| {
                warn!(error = %e, "listing the ingest folder did not finish");
                Vec::new()
            })
    }

    /// Lists the ingest folder again (started at `now`); the stem index is rebuilt from
    /// the listing (files gone since are forgotten).
    pub(super) async fn rescan(&mut self, now: Instant) {
        self.last_rescan = now;
        let listing = self.listing().await;
        // The listing took time: its files are noticed when it ends.
        let now = Instant::now();
        self.stems.clear();
        for path in listing {
            self.consider(path, Arrival::Writing, now);
        }
    }

    /// Lists the ingest folder for files that are on disk but not yet reported by the
    /// watcher (its events queued behind a busy loop, or a polling interval longer than
    /// the bracket gap), makes each a candidate and returns true when there was one.
    /// Called before the gap clock closes a bracket: such a file arrived in time and may
    /// be its next frame. One listing and one `lstat` per unknown file, once per bracket.
    async fn unnoticed_arrivals(&mut self) -> bool {
        let mut found = false;
        let listing = self.listing().await;
        let now = Instant::now();
        for path in listing {
            if self.files.state(&path).is_some()
                || intake::observe(&path).map_or(true, |seen| self.journal.is_settled(&seen.input))
            {
                continue;
            }
            info!(file = %path.display(), "on disk but not yet reported: its bracket waits for it");
            self.consider(path.clone(), Arrival::Writing, now);
            found |= self.files.is_settling(&path);
        }
        found
    }

    /// Makes `path` a candidate (again) at `now`, as its notice's `arrival` says.
    pub(super) fn consider(&mut self, path: PathBuf, arrival: Arrival, now: Instant) {
        // One name per file, whatever spelling the notice or listing used.
        let path = self.root.identity(&path);
        // Reached through a linked folder (a watcher that followed it): not in ingest.
        if intake::through_link(&self.config.folders.ingest, &path) {
            tracing::debug!(file = %path.display(), "reached through a link; not followed");
            return;
        }
        self.stems.insert(&path);
        // Unless taken, waiting out its back-off, or a JPEG set aside beside its raw and
        // unchanged since.
        let unchanged = |aside: &Input| intake::identify(&aside.path).is_ok_and(|i| i == *aside);
        self.files.notice(path, arrival, now, unchanged);
    }

    /// The raw of the capture whose JPEG (PNG, TIFF) is `path`, when it is one the daemon
    /// takes: on disk, under a name and in a folder the watch takes, and not rejected.
    fn pairing_raw(&self, path: &Path) -> Option<PathBuf> {
        let raw = self.stems.raw_of(path)?;
        if !self
            .config
            .watch
            .takes_path(&self.config.folders.ingest, &raw)
        {
            return None;
        }
        let id = intake::identify(&raw).ok()?;
        let rejected = self.journal.is_settled(&id) && self.journal.developed(&raw).is_none();
        (!rejected).then_some(raw)
    }

    /// Sets the JPEG at `jpeg` aside as the companion of `raw`: not a frame, never read
    /// again while it stays as it is.
    fn set_aside(&mut self, jpeg: PathBuf, raw: PathBuf) {
        let Ok(input) = intake::identify(&jpeg) else {
            return;
        };
        info!(file = %jpeg.display(), raw = %raw.display(), "the JPEG of a RAW+JPEG capture: set aside beside its raw");
        self.files.set_aside(input, raw);
    }

    /// A raw that cannot be a frame gives its JPEG back: that is considered as a frame.
    pub(super) fn unpair(&mut self, raw: &Path, now: Instant) {
        if let Some(input) = self.files.unpair(raw) {
            info!(file = %input.path.display(), raw = %raw.display(), "its raw was rejected: the JPEG is the frame");
            self.consider(input.path, Arrival::Writing, now);
        }
    }

    /// Held JPEGs: set aside once their raw is noticed, frames once they waited the
    /// bracket gap without one.
    fn release_held(&mut self, now: Instant) {
        let hold = Duration::from_secs_f64(self.config.bracket.max_gap_s.max(0.0));
        let now_s = self.since_start(now);
        for path in self.files.held_paths() {
            if let Some(raw) = self.pairing_raw(&path) {
                self.set_aside(path, raw);
                continue;
            }
            if self
                .files
                .held_since(&path)
                .is_some_and(|since| now.saturating_duration_since(since) < hold)
            {
                continue;
            }
            let Some(capture) = self.files.unhold(&path) else {
                continue;
            };
            info!(file = %path.display(), "no raw came for this JPEG: it is the frame");
            self.grouper.push(capture, now_s);
            self.queue_closed(now_s);
        }
    }

    pub(super) async fn notice(&mut self, notice: Notice, now: Instant) {
        match notice {
            Notice::File { path, arrival } => self.consider(path, arrival, now),
            Notice::Rescan => {
                warn!("file events may have been lost; rescanning the ingest folder");
                self.rescan(now).await;
            }
        }
    }

    /// The periodic work at `now`: the folder, redo requests, rescans, settling and
    /// taking files, closing brackets, retries. The clock is read again after the steps
    /// that list or probe files, which take time.
    pub(super) async fn tick(&mut self, now: Instant) -> Result<(), DaemonError> {
        self.check_folder(now).await;
        if !self.stopping {
            self.redo_requests(now).await?;
        }
        if self.rescan_due(now) {
            self.rescan(now).await;
        }
        let now = Instant::now();
        if !self.stopping {
            let ready = self.settle(now);
            if !ready.is_empty() {
                self.take(ready).await?;
            }
        }
        let now = Instant::now();
        if !self.stopping {
            self.release_held(now);
        }
        self.close_brackets(now).await;
        self.retry_due(now);
        if let Some(interval) = self.watchdog
            && now.saturating_duration_since(self.last_watchdog) >= interval / 2
        {
            let _ = sd_notify::notify(&[sd_notify::NotifyState::Watchdog]);
            self.last_watchdog = now;
        }
        Ok(())
    }

    /// True when the folder is to be listed again at `now`: every `[watch] rescan_s`, and
    /// every `poll` while there is no watcher (scans are all there is then).
    fn rescan_due(&self, now: Instant) -> bool {
        let since = now.saturating_duration_since(self.last_rescan);
        self.config.watch.rescan.is_some_and(|every| since >= every)
            || (self.watcher.is_none() && since >= self.config.watch.poll)
    }

    /// Closes the brackets whose gap clock ran out at `now`, unless a frame that may
    /// belong to one is still on its way.
    async fn close_brackets(&mut self, now: Instant) {
        let now_s = self.since_start(now);
        // A frame still being written (or waiting on disk behind a full queue) may belong
        // to an open bracket: its gap clock starts when intake has caught up. A writer
        // stuck for over a minute no longer holds brackets open.
        if self.files.writing(now)
            || self.queue.len() >= self.config.daemon.queue
            || (self.grouper.due(now_s) && self.unnoticed_arrivals().await)
        {
            self.grouper.postpone(now_s);
        }
        self.queue_closed(now_s);
    }

    /// Queues the groups that closed at `now_s`, as many as the queue has room for.
    fn queue_closed(&mut self, now_s: f64) {
        let room = self.config.daemon.queue.saturating_sub(self.queue.len());
        for closed in self.grouper.close(now_s, room) {
            self.queue.push_back(Work::new(closed));
        }
    }

    /// Queues the brackets whose retry is due at `now`, as many as the queue has room
    /// for (the others wait), and looks again at the files whose back-off ran out.
    fn retry_due(&mut self, now: Instant) {
        let room = self.config.daemon.queue.saturating_sub(self.queue.len());
        let due = |(at, _, _): &(Instant, Work, String)| *at <= now;
        for (_, work, _) in super::backoff::take_due(&mut self.retries, due, room) {
            self.queue.push_back(work);
        }
        for path in self.files.due(now) {
            self.consider(path, Arrival::Writing, now);
        }
    }

    /// Candidates whose size, mtime, change time and inode were unchanged for `settle`, or
    /// for [`FINISHED_QUIET`] since their writer closed them, or handed over by filmback
    /// and seen once (see the module docs).
    /// Nothing is taken while the queue is full (back-pressure).
    pub(super) fn settle(&mut self, now: Instant) -> Vec<PathBuf> {
        let room = self.config.daemon.queue.saturating_sub(self.queue.len());
        if room == 0 {
            return Vec::new();
        }
        let settle = self.config.watch.settle;
        let mut ready = Vec::new();
        let mut gone = Vec::new();
        let paths = self.files.settling_paths();
        let mut full = false;
        for path in paths {
            if ready.len() >= room {
                full = true;
                break;
            }
            let seen = match intake::observe(&path) {
                Ok(seen) => seen,
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                    gone.push(path);
                    continue;
                }
                // The probe tells a transient error (retried) from a final one.
                Err(_) => {
                    ready.push(path);
                    continue;
                }
            };
            if self.journal.is_settled(&seen.input) {
                gone.push(path);
                continue;
            }
            let Some(cand) = self.files.candidate_mut(&path) else {
                continue;
            };
            if cand.settled(seen, now, settle) {
                ready.push(path);
            }
        }
        for p in &gone {
            self.files.end_settling(p);
            if std::fs::symlink_metadata(p).is_err() {
                self.stems.remove(p);
            }
        }
        // Complete frames wait while another is still settling (for at most the writer's
        // patience): it may be an earlier frame of the same bracket (a copy racing
        // the start-up scan, a slow writer), and frames enter the grouper in capture-time
        // order only within one batch. When the queue limits the batch, take what is ready.
        let settling = self
            .files
            .settling()
            .any(|(p, s)| !ready.contains(p) && s.candidate.writing(now));
        if settling && !full {
            return Vec::new();
        }
        for p in &ready {
            self.files.end_settling(p);
        }
        ready
    }

    /// Probes files off the async threads, under the memory budget; a decoder's panic is
    /// the file's rejection ([`intake::probe_guarded`]), never the service's end.
    async fn probe_all(&self, paths: Vec<PathBuf>) -> Vec<(PathBuf, Probe)> {
        let max_bytes = self.budget_bytes();
        let listed = paths.clone();
        tokio::task::spawn_blocking(move || {
            paths
                .into_iter()
                .map(|p| {
                    let r = intake::probe_guarded(&p, max_bytes);
                    (p, r)
                })
                .collect()
        })
        .await
        .unwrap_or_else(|e| {
            // Only a cancelled task gets here (panics are caught inside): read them later.
            let reason = format!("cannot read: probing did not finish: {e}");
            listed
                .into_iter()
                .map(|p| (p, Probe::Unreadable(reason.clone())))
                .collect()
        })
    }

    /// Probes settled files (off the async threads) and feeds the grouper.
    pub(super) async fn take(&mut self, ready: Vec<PathBuf>) -> Result<(), DaemonError> {
        let read = self.set_aside_paired_jpegs(ready);
        let probed = self.probe_all(read).await;
        let now = Instant::now();
        let frames = self.sift(probed, now)?;
        let admitted = self.admit(frames, now)?;
        let mut frames = self.redevelop_reshot(admitted).await;
        // A batch (start-up scan, burst) enters in capture-time order, as it is now (the
        // re-shot frames' probing took time).
        frames.sort_by(super::bracket::capture_order);
        self.hand_to_grouper(frames, Instant::now());
        Ok(())
    }

    /// Sets aside the JPEG of a RAW+JPEG capture whose raw is known (it is not even
    /// read); the other files of `ready` are returned, to be probed.
    fn set_aside_paired_jpegs(&mut self, ready: Vec<PathBuf>) -> Vec<PathBuf> {
        let mut read = Vec::with_capacity(ready.len());
        for path in ready {
            match self.pairing_raw(&path) {
                Some(raw) => self.set_aside(path, raw),
                None => read.push(path),
            }
        }
        read
    }

    /// Acts on what probing found at `now`: rejects, retries later or looks again at
    /// what is not a frame, journals a touched frame whose content is unchanged, and
    /// returns the new frames.
    fn sift(
        &mut self,
        probed: Vec<(PathBuf, Probe)>,
        now: Instant,
    ) -> Result<Vec<(Capture, intake::Taken)>, DaemonError> {
        let mut frames = Vec::new();
        for (path, probe) in probed {
            if !matches!(probe, Probe::Unreadable(_)) {
                self.files.read(&path);
            }
            match probe {
                Probe::Frame(c, ..) if self.journal.is_settled(&c.input) => {}
                Probe::Frame(c, taken) => {
                    let before = self.journal.developed(&c.input.path);
                    if let Some(e) =
                        before.filter(|e| e.digest_of(&c.input.path) == Some(taken.digest))
                    {
                        let of = match e {
                            Entry::Bracket { id, .. } | Entry::Single { id, .. } => id.clone(),
                            _ => String::new(),
                        };
                        info!(file = %c.input.path.display(), "touched, content unchanged: nothing redone");
                        self.journal.record(Entry::Unchanged {
                            input: c.input,
                            of,
                            at: journal::unix_now(),
                        })?;
                        continue;
                    }
                    frames.push((c, taken));
                }
                Probe::Rejected(input, reason) => {
                    if !self.journal.is_settled(&input) {
                        self.reject(input, reason, now)?;
                    }
                }
                Probe::Unreadable(reason) => self.unreadable_for_now(path, reason, now),
                Probe::Changed => self.consider(path, Arrival::Writing, now),
                Probe::Gone => {}
            }
        }
        Ok(frames)
    }

    /// Takes the `frames` whose development fits the memory budget alone; the others
    /// are rejected at `now`, naming their size.
    fn admit(
        &mut self,
        frames: Vec<(Capture, intake::Taken)>,
        now: Instant,
    ) -> Result<Vec<Capture>, DaemonError> {
        let mut admitted = Vec::new();
        for (c, taken) in frames {
            let footprint = taken.footprint;
            let need = job_bytes(&[footprint]);
            let budget = self.budget_bytes();
            if need > budget {
                let reason = format!(
                    "{}×{} pixels need {}",
                    footprint.width,
                    footprint.height,
                    super::budget::over_budget(need, self.config.daemon.memory_mb)
                );
                self.reject(c.input, reason, now)?;
            } else {
                self.files.take(c.input.path.clone(), taken);
                admitted.push(c);
            }
        }
        Ok(admitted)
    }

    /// A new version of a frame of a developed bracket (re-shot under the same name)
    /// re-develops that bracket with it, in place of the old outputs; the frames of
    /// `admitted` that are new work are returned.
    async fn redevelop_reshot(&mut self, admitted: Vec<Capture>) -> Vec<Capture> {
        let mut reshot: Vec<(Entry, Vec<Capture>)> = Vec::new();
        let mut frames = Vec::new();
        for c in admitted {
            match self.journal.developed(&c.input.path) {
                Some(e @ Entry::Bracket { .. }) => {
                    match reshot.iter_mut().find(|(old, _)| old == e) {
                        Some((_, new)) => new.push(c),
                        None => reshot.push((e.clone(), vec![c])),
                    }
                }
                _ => frames.push(c),
            }
        }
        for (old, new) in reshot {
            if let Err((new, why)) = self.redevelop(&old, new).await {
                tracing::debug!(reason = %why, "not a re-shot frame; new work");
                frames.extend(new);
            }
        }
        frames
    }

    /// Pushes `frames` to the grouper at `now`, queueing the brackets they close; a raw
    /// sets its JPEG aside, and a JPEG of a body shooting RAW+JPEG is held for its raw.
    fn hand_to_grouper(&mut self, frames: Vec<Capture>, now: Instant) {
        let now_s = self.since_start(now);
        for c in frames {
            let path = c.input.path.clone();
            if let Some(jpeg) = self.stems.companion_of(&path) {
                // A raw with a JPEG beside it: its body shoots RAW+JPEG, and a JPEG of
                // this capture that went ahead of its raw gives way.
                self.pairing_bodies.insert(c.camera.clone());
                let held = matches!(self.files.state(&jpeg), Some(FileState::Held(..)));
                if held || self.grouper.withdraw(&jpeg).is_some() {
                    self.set_aside(jpeg, path.clone());
                }
            } else if !intake::is_raw(&path) && self.pairing_bodies.contains(&c.camera) {
                tracing::debug!(file = %path.display(), "a JPEG of a RAW+JPEG body: waiting for its raw");
                self.files.hold(
                    &path,
                    Held {
                        capture: c,
                        since: now,
                    },
                );
                continue;
            }
            tracing::debug!(file = %path.display(), time_s = c.time_s, "frame taken");
            self.grouper.push(c, now_s);
            self.queue_closed(now_s);
        }
    }

    /// Develops again the frames of an earlier bracket or single `old`, with `new`
    /// versions of some of its files, publishing under its output stem and removing its
    /// outputs the new set lacks. Every other input of `old` must still be there,
    /// unchanged, and of the same camera; otherwise `new` is handed back with the reason.
    pub(super) async fn redevelop(
        &mut self,
        old: &Entry,
        new: Vec<Capture>,
    ) -> Result<(), (Vec<Capture>, String)> {
        let (Some(stem), Entry::Bracket { outputs, .. } | Entry::Single { outputs, .. }) =
            (old.output_stem(), old)
        else {
            return Err((new, "not a developed bracket".to_string()));
        };
        let replaced: Vec<&Path> = new.iter().map(|c| c.input.path.as_path()).collect();
        let others: Vec<PathBuf> = old
            .inputs()
            .into_iter()
            .filter(|i| !replaced.contains(&i.path.as_path()))
            .map(|i| i.path.clone())
            .collect();
        if !new.is_empty() && others.is_empty() {
            return Err((
                new,
                "no unchanged frame of the earlier bracket left".to_string(),
            ));
        }
        if others.iter().any(|p| self.files.taken(p).is_some()) {
            return Err((new, "its other frames are being developed".to_string()));
        }
        let mut frames = new;
        let found = match self.probe_unchanged(old, others).await {
            Ok(found) => found,
            Err(why) => return Err((frames, why)),
        };
        let Some(camera) = frames
            .first()
            .or(found.first().map(|(c, _)| c))
            .map(|c| c.camera.clone())
        else {
            return Err((frames, "no frame left".to_string()));
        };
        if frames
            .iter()
            .chain(found.iter().map(|(c, _)| c))
            .any(|c| c.camera != camera)
        {
            return Err((frames, "frames of another camera".to_string()));
        }
        for (c, taken) in found {
            self.files.take(c.input.path.clone(), taken);
            frames.push(c);
        }
        let closed = match reassemble(camera, frames) {
            Ok(closed) => closed,
            Err(frames) => return Err((frames, "no frame left".to_string())),
        };
        info!(bracket = %stem, frames = closed.frames().len(), "developing again");
        self.queue.push_back(Work {
            closed,
            attempts: 0,
            reserved: 0,
            supersedes: Some(Superseded {
                stem,
                outputs: outputs.clone(),
            }),
        });
        Ok(())
    }

    /// Probes the `others` inputs of the earlier development `old`; each must be
    /// unchanged: the very file journaled, or (touched since) the same content. The first
    /// that changed or is gone is named in the error.
    async fn probe_unchanged(
        &self,
        old: &Entry,
        others: Vec<PathBuf>,
    ) -> Result<Vec<(Capture, intake::Taken)>, String> {
        let journaled: Vec<Input> = old.inputs().into_iter().cloned().collect();
        let digests: Vec<(PathBuf, Option<u64>)> = journaled
            .iter()
            .map(|i| (i.path.clone(), old.digest_of(&i.path)))
            .collect();
        let unchanged = |c: &Capture, digest: u64| {
            journaled.contains(&c.input)
                || digests
                    .iter()
                    .any(|(p, d)| *p == c.input.path && *d == Some(digest))
        };
        let probed = self.probe_all(others).await;
        let mut found = Vec::new();
        for (path, probe) in probed {
            match probe {
                Probe::Frame(c, taken) if unchanged(&c, taken.digest) => {
                    found.push((c, taken));
                }
                _ => return Err(format!("{} changed or is gone", path.display())),
            }
        }
        Ok(found)
    }

    /// Requests of `filmback redo STEM`: files in `state/redo/`, each named by the output
    /// stem of a finished bracket or single, checked every half second.
    pub(super) async fn redo_requests(&mut self, now: Instant) -> Result<(), DaemonError> {
        if now.saturating_duration_since(self.last_redo) < Duration::from_millis(500) {
            return Ok(());
        }
        self.last_redo = now;
        let dir = self.config.folders.state.join(REDO_FOLDER);
        for request in redo_listing(dir).await {
            let stem = request
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default();
            match self.journal.by_stem(&stem).cloned() {
                Some(old) => {
                    if let Err((_, why)) = self.redevelop(&old, Vec::new()).await {
                        warn!(bracket = %stem, reason = %why, "cannot develop again");
                    }
                }
                None => warn!(bracket = %stem, "redo: no finished bracket or single of that name"),
            }
            if let Err(e) = std::fs::remove_file(&request) {
                warn!(file = %request.display(), error = %e, "cannot remove redo request");
            }
        }
        Ok(())
    }

    /// A file that cannot be read at `now`: look again after `retry · 2^attempts` (at most
    /// [`super::backoff::MAX_RETRY`]); meanwhile open brackets wait for it (up to
    /// [`super::candidate::WRITER_PATIENCE`]),
    /// and `status` shows it with the reason. Nothing is journaled.
    pub(super) fn unreadable_for_now(&mut self, path: PathBuf, reason: String, now: Instant) {
        let (delay, attempts) =
            self.files
                .unreadable(&path, now, self.config.daemon.retry, reason.clone());
        if let Some(viewer) = &self.viewer {
            viewer.retry(super::Retry {
                what: path.display().to_string(),
                reason: reason.clone(),
                attempts,
                next: super::journal::unix_now() + delay.as_secs(),
            });
        }
        warn!(
            file = %path.display(),
            reason = %reason,
            attempt = attempts,
            retry_in_s = delay.as_secs_f64(),
            "cannot read; will retry"
        );
    }

    pub(super) fn reject(
        &mut self,
        input: Input,
        reason: String,
        now: Instant,
    ) -> Result<(), DaemonError> {
        warn!(file = %input.path.display(), reason = %reason, "rejected");
        self.files.release(&input.path);
        self.summary.rejected += 1;
        if let Some(viewer) = &self.viewer {
            viewer.rejected(&input.path, &reason);
        }
        let path = input.path.clone();
        self.journal.record(Entry::Rejected {
            input,
            reason,
            at: journal::unix_now(),
        })?;
        self.unpair(&path, now);
        Ok(())
    }
}

/// The requests in the redo folder `dir` (none when it is missing), listed on a blocking
/// thread, off the loop.
async fn redo_listing(dir: PathBuf) -> Vec<PathBuf> {
    tokio::task::spawn_blocking(move || {
        let Ok(entries) = std::fs::read_dir(&dir) else {
            return Vec::new();
        };
        entries
            .filter_map(Result::ok)
            .map(|e| e.path())
            .filter(|p| !atomic::is_temporary(p))
            .collect()
    })
    .await
    .unwrap_or_else(|e| {
        warn!(error = %e, "listing the redo requests did not finish");
        Vec::new()
    })
}

/// The `frames` of `camera` in capture-time order as one closed set: a bracket, or a
/// single with no partner when one frame is left; no frame is handed back.
fn reassemble(camera: CameraId, mut frames: Vec<Capture>) -> Result<Closed, Vec<Capture>> {
    frames.sort_by(|a, b| a.time_s.total_cmp(&b.time_s));
    match frames.pop() {
        Some(only) if frames.is_empty() => Ok(Closed::Single(only, Alone::NoPartner)),
        Some(last) => {
            frames.push(last);
            Ok(Closed::Bracket(Bracket { camera, frames }))
        }
        None => Err(frames),
    }
}
