//! The watch-folder daemon: files appear in the ingest folder, brackets come out.
//!
//! ```text
//! notify / poll ─► candidates ─settle─► probe (EXIF, header) ─► Grouper ─► queue
//!                                                                          │ ≤ jobs
//!             journal ◄─ cache update ◄─ outputs ◄─ Lab (blocking thread) ◄┘
//! ```
//!
//! One async task owns all state (candidates, grouper, queue, journal, cache); pixel
//! work runs on blocking threads through the [`Lab`] boundary, at most `jobs` at a
//! time. A file is taken once its writer closed it or its size and mtime were stable for
//! `settle_ms`. When the queue is full, files simply stay on disk as candidates: memory
//! is bounded by `jobs` developing brackets, and nothing is dropped.
//!
//! Errors split as in any service: [`DaemonError`] is fatal (folders cannot be created,
//! the journal cannot be written); a bad frame, a failed output or a bad reload is
//! reported and the loop goes on.

pub mod bracket;
pub mod cache;
pub mod config;
pub mod journal;

mod intake;
mod lab;

use std::collections::{HashMap, HashSet, VecDeque};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime};

use serde::{Deserialize, Serialize};
use tokio::sync::mpsc;
use tokio::task::JoinSet;
use tracing::{error, info, warn};

pub use lab::{DarkroomLab, Job, JobError, Lab, Processed};

use crate::atomic::{self, Overwrite};
use bracket::{Alone, Bracket, Closed, Grouper, Input};
use cache::ResponseCache;
use config::{Config, Recalibrate, Singles};
use intake::{Notice, Probe};
use journal::{Entry, Journal, JournalError};

/// File name of the status snapshot in the state folder.
pub const STATUS_FILE: &str = "status.json";

/// How long in-flight brackets may finish after a stop request before they are
/// abandoned (the journal redoes them); systemd's default stop timeout is 90 s, ours
/// promises 10 s.
pub const STOP_GRACE: Duration = Duration::from_secs(8);

/// How long a file still being written keeps open brackets from closing by the gap.
const WRITER_PATIENCE: Duration = Duration::from_secs(60);

/// Longest delay between retries of a bracket whose outputs could not be written.
const MAX_RETRY: Duration = Duration::from_secs(300);

/// What the daemon can be told while it runs (signals in the binary, channels in tests).
#[derive(Debug)]
pub enum Control {
    /// Stop taking work, let in-flight brackets finish (up to [`STOP_GRACE`]), return.
    Stop,
    /// Apply a new, already checked configuration. Folder changes need a restart.
    Reload(Box<Config>),
}

/// Why the daemon cannot run at all.
#[derive(Debug, thiserror::Error)]
pub enum DaemonError {
    /// A folder could not be created.
    #[error("{path}: cannot create folder: {source}")]
    Folder {
        /// The folder.
        path: PathBuf,
        /// What the operating system said.
        source: std::io::Error,
    },
    /// The journal cannot be read or written: continuing could lose or repeat work.
    #[error("journal: {0}")]
    Journal(#[from] JournalError),
}

/// Counters of one run, returned when the daemon stops.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Summary {
    /// Brackets and singles finished (journaled).
    pub finished: usize,
    /// Files set aside as rejected.
    pub rejected: usize,
    /// Brackets still developing when the grace period ran out (redone next start).
    pub abandoned: usize,
}

/// The daemon's state as `filmback status` shows it: `state/status.json`, rewritten
/// (atomically) whenever a count changes.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Snapshot {
    /// Process id.
    pub pid: u32,
    /// False once the daemon has stopped.
    pub running: bool,
    /// Unix seconds of this snapshot.
    pub updated: u64,
    /// Watched folder.
    pub ingest: PathBuf,
    /// Output folder.
    pub out: PathBuf,
    /// True while the ingest folder exists and is watched.
    pub watching: bool,
    /// Files seen, not yet complete.
    pub settling: usize,
    /// Frames in open (not yet closed) brackets.
    pub grouping: usize,
    /// Closed brackets waiting for a job.
    pub queued: usize,
    /// Brackets developing now.
    pub in_flight: usize,
    /// Brackets waiting to retry after an output failure.
    pub retrying: usize,
    /// Finished in this run.
    pub finished: usize,
    /// Rejected in this run.
    pub rejected: usize,
}

/// Reads `state/status.json`, if the daemon ever wrote one.
pub fn read_snapshot(state: &Path) -> Option<Snapshot> {
    let text = std::fs::read_to_string(state.join(STATUS_FILE)).ok()?;
    serde_json::from_str(&text).ok()
}

/// A closed group on its way through the queue.
#[derive(Debug, Clone)]
struct Work {
    closed: Closed,
    attempts: u32,
}

/// A file seen but not yet complete.
#[derive(Debug)]
struct Candidate {
    first_seen: Instant,
    seen: Option<Input>,
    stable_since: Instant,
    closed: bool,
}

type Outcome = (Work, Result<Processed, JobError>, Duration);

struct State {
    config: Config,
    lab: Arc<dyn Lab>,
    journal: Journal,
    cache: ResponseCache,
    grouper: Grouper,
    started: Instant,
    notices: mpsc::UnboundedSender<Notice>,
    watcher: Option<intake::ActiveWatcher>,
    /// `(device, inode)` of the watched ingest folder; `None` while it is missing.
    watched: Option<(u64, u64)>,
    /// After a failed attempt to watch, the next one waits until then.
    watch_retry_at: Instant,
    last_rescan: Instant,
    candidates: HashMap<PathBuf, Candidate>,
    /// Paths in the grouper, queue, retry list or in flight.
    taken: HashSet<PathBuf>,
    queue: VecDeque<Work>,
    retries: Vec<(Instant, Work)>,
    in_flight: JoinSet<Outcome>,
    summary: Summary,
    stopping: bool,
    last_snapshot: Option<Snapshot>,
    last_report: Instant,
    last_watchdog: Instant,
    watchdog: Option<Duration>,
}

/// Runs the daemon until [`Control::Stop`] (or the control sender is dropped).
pub async fn run(
    config: Config,
    lab: Arc<dyn Lab>,
    mut control: mpsc::Receiver<Control>,
) -> Result<Summary, DaemonError> {
    let folders = &config.folders;
    for dir in [&folders.ingest, &folders.out, &folders.state] {
        std::fs::create_dir_all(dir).map_err(|source| DaemonError::Folder {
            path: dir.clone(),
            source,
        })?;
    }
    for dir in [
        folders.out.clone(),
        folders.state.clone(),
        ResponseCache::new(&folders.state).dir().to_path_buf(),
    ] {
        remove_temporaries(&dir);
    }
    let journal = Journal::open(&folders.state)?;
    let (notices, mut rx) = mpsc::unbounded_channel();
    let now = Instant::now();
    let mut st = State {
        cache: ResponseCache::new(&folders.state),
        grouper: Grouper::new(config.bracket),
        config,
        lab,
        journal,
        started: now,
        notices,
        watcher: None,
        watched: None,
        watch_retry_at: now,
        last_rescan: now,
        candidates: HashMap::new(),
        taken: HashSet::new(),
        queue: VecDeque::new(),
        retries: Vec::new(),
        in_flight: JoinSet::new(),
        summary: Summary::default(),
        stopping: false,
        last_snapshot: None,
        last_report: now,
        last_watchdog: now,
        watchdog: sd_notify::watchdog_enabled(),
    };
    st.check_folder();
    info!(
        ingest = %st.config.folders.ingest.display(),
        out = %st.config.folders.out.display(),
        state = %st.config.folders.state.display(),
        mode = ?st.config.watch.mode,
        jobs = st.config.daemon.jobs,
        finished_before = st.journal.entries().len(),
        "watching"
    );
    let _ = sd_notify::notify(&[sd_notify::NotifyState::Ready]);
    let period =
        (st.config.watch.settle / 4).clamp(Duration::from_millis(10), Duration::from_millis(250));
    let mut tick = tokio::time::interval(period);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tokio::select! {
            Some(notice) = rx.recv() => st.notice(notice),
            Some(done) = st.in_flight.join_next(), if !st.in_flight.is_empty() => {
                st.finish(done.expect("develop panics are caught inside the task"))?;
            }
            c = control.recv() => match c {
                Some(Control::Reload(cfg)) => st.reload(*cfg),
                Some(Control::Stop) | None => break,
            },
            _ = tick.tick() => st.tick().await?,
        }
        st.dispatch()?;
        st.report(false);
    }
    st.stopping = true;
    let _ = sd_notify::notify(&[
        sd_notify::NotifyState::Stopping,
        sd_notify::NotifyState::Status("stopping: finishing brackets in flight"),
    ]);
    info!(in_flight = st.in_flight.len(), "stopping");
    let deadline = tokio::time::Instant::now() + STOP_GRACE;
    while !st.in_flight.is_empty() {
        tokio::select! {
            Some(done) = st.in_flight.join_next() => {
                st.finish(done.expect("develop panics are caught inside the task"))?;
            }
            () = tokio::time::sleep_until(deadline) => break,
        }
    }
    st.summary.abandoned = st.in_flight.len();
    if st.summary.abandoned > 0 {
        warn!(
            abandoned = st.summary.abandoned,
            "brackets still developing were abandoned; the next start redoes them"
        );
    }
    // Blocking threads cannot be interrupted; the process exit ends them, and their
    // temporary files are removed at the next start.
    st.in_flight.detach_all();
    st.report(true);
    info!(
        finished = st.summary.finished,
        rejected = st.summary.rejected,
        "stopped"
    );
    Ok(st.summary)
}

/// Removes temporary files of [`atomic`] left by an earlier run that was killed.
fn remove_temporaries(dir: &Path) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for path in entries.filter_map(Result::ok).map(|e| e.path()) {
        if atomic::is_temporary(&path) {
            match std::fs::remove_file(&path) {
                Ok(()) => {
                    info!(file = %path.display(), "removed temporary file of an interrupted run")
                }
                Err(e) => warn!(file = %path.display(), error = %e, "cannot remove temporary file"),
            }
        }
    }
}

fn file_stem(path: &Path) -> String {
    path.file_stem()
        .map_or_else(String::new, |s| s.to_string_lossy().into_owned())
}

fn folder_id(dir: &Path) -> Option<(u64, u64)> {
    use std::os::unix::fs::MetadataExt;
    std::fs::metadata(dir)
        .ok()
        .filter(std::fs::Metadata::is_dir)
        .map(|m| (m.dev(), m.ino()))
}

fn wall_seconds() -> f64 {
    SystemTime::now()
        .duration_since(SystemTime::UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

impl State {
    fn now_s(&self) -> f64 {
        self.started.elapsed().as_secs_f64()
    }

    /// Notices the ingest folder appearing, disappearing or being replaced, and
    /// (re)starts the watcher with a full scan when it (re)appears.
    fn check_folder(&mut self) {
        let dir = self.config.folders.ingest.clone();
        let id = folder_id(&dir);
        if id == self.watched && (id.is_none() || self.watcher.is_some()) {
            return;
        }
        if id == self.watched && Instant::now() < self.watch_retry_at {
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
                self.watch_retry_at = Instant::now() + Duration::from_secs(10);
            }
        }
        self.rescan();
    }

    fn rescan(&mut self) {
        self.last_rescan = Instant::now();
        for path in intake::scan(&self.config.watch, &self.config.folders.ingest) {
            self.consider(path, false);
        }
    }

    fn consider(&mut self, path: PathBuf, closed: bool) {
        if self.taken.contains(&path) {
            return;
        }
        let cand = self.candidates.entry(path).or_insert(Candidate {
            first_seen: Instant::now(),
            seen: None,
            stable_since: Instant::now(),
            closed: false,
        });
        cand.closed |= closed;
    }

    fn notice(&mut self, notice: Notice) {
        match notice {
            Notice::File { path, closed } => self.consider(path, closed),
            Notice::Rescan => {
                warn!("file events may have been lost; rescanning the ingest folder");
                self.rescan();
            }
        }
    }

    async fn tick(&mut self) -> Result<(), DaemonError> {
        self.check_folder();
        let rescan_due = match self.config.watch.rescan {
            Some(every) => self.last_rescan.elapsed() >= every,
            // Without a watcher, scans are all there is.
            None => false,
        } || (self.watcher.is_none()
            && self.last_rescan.elapsed() >= self.config.watch.poll);
        if rescan_due {
            self.rescan();
        }
        if !self.stopping {
            let ready = self.settle();
            if !ready.is_empty() {
                self.take(ready).await?;
            }
        }
        let now = self.now_s();
        // A frame still being written (or waiting on disk behind a full queue) may belong
        // to an open bracket: its gap clock starts when intake has caught up. A writer
        // stuck for over a minute no longer holds brackets open.
        let writing = self
            .candidates
            .values()
            .any(|c| c.first_seen.elapsed() < WRITER_PATIENCE);
        if writing || self.queue.len() >= self.config.daemon.queue {
            self.grouper.postpone(now);
        }
        for closed in self.grouper.expire(now) {
            self.queue.push_back(Work {
                closed,
                attempts: 0,
            });
        }
        let due = Instant::now();
        let (ready, later): (Vec<_>, Vec<_>) =
            self.retries.drain(..).partition(|(at, _)| *at <= due);
        self.retries = later;
        for (_, work) in ready {
            self.queue.push_back(work);
        }
        if let Some(interval) = self.watchdog
            && self.last_watchdog.elapsed() >= interval / 2
        {
            let _ = sd_notify::notify(&[sd_notify::NotifyState::Watchdog]);
            self.last_watchdog = Instant::now();
        }
        Ok(())
    }

    /// Candidates whose writer closed them or whose size and mtime were stable for
    /// `settle`. Nothing is taken while the queue is full (back-pressure).
    fn settle(&mut self) -> Vec<PathBuf> {
        let room = self.config.daemon.queue.saturating_sub(self.queue.len());
        if room == 0 {
            return Vec::new();
        }
        let settle = self.config.watch.settle;
        let wall_ns = (wall_seconds() * 1e9) as i64;
        let mut ready = Vec::new();
        let mut gone = Vec::new();
        let mut paths: Vec<&PathBuf> = self.candidates.keys().collect();
        paths.sort();
        let paths: Vec<PathBuf> = paths.into_iter().cloned().collect();
        let mut full = false;
        for path in paths {
            if ready.len() >= room {
                full = true;
                break;
            }
            let cand = self.candidates.get_mut(&path).expect("listed above");
            let id = match intake::identify(&path) {
                Ok(id) => id,
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                    gone.push(path);
                    continue;
                }
                // The probe reports it (e.g. permission denied) as a rejection.
                Err(_) => {
                    ready.push(path);
                    continue;
                }
            };
            if self.journal.is_settled(&id) {
                gone.push(path);
                continue;
            }
            if cand.seen.as_ref() != Some(&id) {
                cand.seen = Some(id.clone());
                cand.stable_since = Instant::now();
            }
            let untouched_for =
                Duration::from_nanos(wall_ns.saturating_sub(id.modified_ns).max(0) as u64);
            if cand.closed || cand.stable_since.elapsed() >= settle || untouched_for >= settle {
                ready.push(path);
            }
        }
        for p in &gone {
            self.candidates.remove(p);
        }
        // Complete frames wait while another is still settling (for at most
        // WRITER_PATIENCE): it may be an earlier frame of the same bracket (a copy racing
        // the start-up scan, a slow writer), and frames enter the grouper in capture-time
        // order only within one batch. When the queue limits the batch, take what is ready.
        let settling = self
            .candidates
            .iter()
            .any(|(p, c)| !ready.contains(p) && c.first_seen.elapsed() < WRITER_PATIENCE);
        if settling && !full {
            return Vec::new();
        }
        for p in &ready {
            self.candidates.remove(p);
        }
        ready
    }

    /// Probes settled files (off the async threads) and feeds the grouper.
    async fn take(&mut self, ready: Vec<PathBuf>) -> Result<(), DaemonError> {
        let probed = tokio::task::spawn_blocking(move || {
            ready
                .into_iter()
                .map(|p| {
                    let r = intake::probe(&p);
                    (p, r)
                })
                .collect::<Vec<_>>()
        })
        .await
        .expect("probing does not panic");
        let mut frames = Vec::new();
        for (path, probe) in probed {
            match probe {
                Probe::Frame(c) if self.journal.is_settled(&c.input) => {}
                Probe::Frame(c) => frames.push(c),
                Probe::Rejected(input, reason) => {
                    if !self.journal.is_settled(&input) {
                        self.reject(input, reason)?;
                    }
                }
                Probe::Changed => self.consider(path, false),
                Probe::Gone => {}
            }
        }
        // A batch (start-up scan, burst) enters in capture-time order.
        frames.sort_by(|a, b| {
            a.time_s
                .total_cmp(&b.time_s)
                .then_with(|| a.input.path.cmp(&b.input.path))
        });
        let now = self.now_s();
        for c in frames {
            tracing::debug!(file = %c.input.path.display(), time_s = c.time_s, "frame taken");
            self.taken.insert(c.input.path.clone());
            for closed in self.grouper.push(c, now) {
                self.queue.push_back(Work {
                    closed,
                    attempts: 0,
                });
            }
        }
        Ok(())
    }

    fn reject(&mut self, input: Input, reason: String) -> Result<(), DaemonError> {
        warn!(file = %input.path.display(), reason = %reason, "rejected");
        self.taken.remove(&input.path);
        self.summary.rejected += 1;
        self.journal.record(Entry::Rejected {
            input,
            reason,
            at: journal::unix_now(),
        })?;
        Ok(())
    }

    fn dispatch(&mut self) -> Result<(), DaemonError> {
        while !self.stopping && self.in_flight.len() < self.config.daemon.jobs {
            let Some(work) = self.queue.pop_front() else {
                break;
            };
            if let Closed::Single(capture, alone) = &work.closed
                && self.config.bracket.singles == Singles::Report
            {
                info!(file = %capture.input.path.display(), camera = %capture.camera, reason = %alone, "single frame reported, not rendered");
                self.journal.record(Entry::Single {
                    id: work.closed.id(),
                    camera: capture.camera.clone(),
                    input: capture.input.clone(),
                    alone: *alone,
                    outputs: Vec::new(),
                    at: journal::unix_now(),
                })?;
                self.summary.finished += 1;
                self.release(&work.closed);
                continue;
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
            let job = Job {
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
                stem: self.output_stem(&work.closed),
                stocks: self.config.folders.stocks.clone(),
            };
            let lab = Arc::clone(&self.lab);
            self.in_flight.spawn_blocking(move || {
                let t = Instant::now();
                let result =
                    std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| lab.process(&job)))
                        .unwrap_or_else(|panic| {
                            let what = panic
                                .downcast_ref::<&str>()
                                .map(|s| (*s).to_string())
                                .or_else(|| panic.downcast_ref::<String>().cloned())
                                .unwrap_or_default();
                            Err(JobError::Bracket(format!("lab panicked: {what}")))
                        });
                (work, result, t.elapsed())
            });
        }
        Ok(())
    }

    /// The first frame's stem, unless an earlier, different bracket already published
    /// under it (a camera's file counter wrapped, or inputs were replaced): then
    /// `<stem>-<first 8 hex digits of the id>`, so no finished output is ever replaced.
    fn output_stem(&self, closed: &Closed) -> String {
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

    fn release(&mut self, closed: &Closed) {
        for f in closed.frames() {
            self.taken.remove(&f.input.path);
        }
    }

    fn finish(&mut self, (work, result, took): Outcome) -> Result<(), DaemonError> {
        let closed = &work.closed;
        let camera = closed.camera().clone();
        match result {
            Ok(dev) => {
                let preset = self
                    .config
                    .preset_for(camera.model.as_deref(), camera.serial.as_deref());
                if let Some((fit, confidence)) = &dev.fit
                    && *confidence >= preset.min_confidence
                    && preset.recalibrate != Recalibrate::Never
                    && let Err(e) =
                        self.cache
                            .update(&camera, fit, *confidence, journal::unix_now())
                {
                    warn!(error = %e, "cannot update the response cache");
                }
                for note in &dev.notes {
                    warn!(bracket = %closed.stem(), "{note}");
                }
                let at = journal::unix_now();
                let entry = match closed {
                    Closed::Bracket(b) => Entry::Bracket {
                        id: closed.id(),
                        camera: camera.clone(),
                        inputs: b.frames.iter().map(|c| c.input.clone()).collect(),
                        outputs: dev.outputs.clone(),
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
                        at,
                    },
                };
                self.journal.record(entry)?;
                self.summary.finished += 1;
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
                self.archive(closed);
                self.release(closed);
            }
            Err(JobError::Frame { path, reason }) => {
                let frames: Vec<_> = closed.frames().into_iter().cloned().collect();
                let Some(bad) = frames.iter().find(|c| c.input.path == path) else {
                    return self.failed(
                        &work,
                        format!("lab named a foreign frame {}: {reason}", path.display()),
                    );
                };
                self.reject(bad.input.clone(), reason)?;
                let rest: Vec<_> = frames
                    .into_iter()
                    .filter(|c| c.input.path != path)
                    .collect();
                let closed = match rest.len() {
                    0 => return Ok(()),
                    1 => Closed::Single(rest.into_iter().next().expect("one"), Alone::NoPartner),
                    _ => Closed::Bracket(Bracket {
                        camera,
                        frames: rest,
                    }),
                };
                self.queue.push_front(Work {
                    closed,
                    attempts: 0,
                });
            }
            Err(e @ JobError::Output { .. }) => {
                let delay = (self.config.daemon.retry * 2u32.saturating_pow(work.attempts.min(16)))
                    .min(MAX_RETRY);
                error!(
                    bracket = %closed.stem(),
                    error = %e,
                    retry_in_s = delay.as_secs_f64(),
                    "outputs not written; will retry"
                );
                self.retries.push((
                    Instant::now() + delay,
                    Work {
                        closed: work.closed.clone(),
                        attempts: work.attempts + 1,
                    },
                ));
            }
            Err(JobError::Bracket(reason)) => self.failed(&work, reason)?,
        }
        Ok(())
    }

    fn failed(&mut self, work: &Work, reason: String) -> Result<(), DaemonError> {
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

    /// Moves finished inputs to the archive folder, when configured.
    fn archive(&self, closed: &Closed) {
        let Some(dir) = &self.config.folders.archive else {
            return;
        };
        if let Err(e) = std::fs::create_dir_all(dir) {
            warn!(archive = %dir.display(), error = %e, "cannot create archive folder");
            return;
        }
        for c in closed.frames() {
            let Some(name) = c.input.path.file_name() else {
                continue;
            };
            if let Err(e) = std::fs::rename(&c.input.path, dir.join(name)) {
                warn!(file = %c.input.path.display(), error = %e, "cannot archive input");
            }
        }
    }

    fn reload(&mut self, mut config: Config) {
        if config.folders != self.config.folders {
            warn!("folders changed in the configuration; they take effect at the next start");
            config.folders = self.config.folders.clone();
        }
        let rewatch = config.watch.mode != self.config.watch.mode
            || config.watch.recursive != self.config.watch.recursive
            || config.watch.poll != self.config.watch.poll;
        self.grouper.set_rules(config.bracket);
        self.config = config;
        if rewatch {
            self.watcher = None;
            self.watched = None;
            self.check_folder();
        }
        info!(source = ?self.config.source, "configuration reloaded");
    }

    fn snapshot(&self, running: bool) -> Snapshot {
        Snapshot {
            pid: std::process::id(),
            running,
            updated: journal::unix_now(),
            ingest: self.config.folders.ingest.clone(),
            out: self.config.folders.out.clone(),
            watching: self.watcher.is_some(),
            settling: self.candidates.len(),
            grouping: self.grouper.waiting(),
            queued: self.queue.len(),
            in_flight: self.in_flight.len(),
            retrying: self.retries.len(),
            finished: self.summary.finished,
            rejected: self.summary.rejected,
        }
    }

    /// Publishes the status snapshot and the systemd STATUS line when a count changed
    /// (at most every 200 ms), or unconditionally when `last`.
    fn report(&mut self, last: bool) {
        if !last && self.last_report.elapsed() < Duration::from_millis(200) {
            return;
        }
        let snap = self.snapshot(!last);
        let same = self.last_snapshot.as_ref().is_some_and(|s| {
            Snapshot {
                updated: snap.updated,
                ..s.clone()
            } == snap
        });
        if same && !last {
            return;
        }
        self.last_report = Instant::now();
        let status = format!(
            "{} finished, {} rejected, {} developing, {} queued, {} waiting",
            snap.finished,
            snap.rejected,
            snap.in_flight,
            snap.queued,
            snap.settling + snap.grouping
        );
        let _ = sd_notify::notify(&[sd_notify::NotifyState::Status(&status)]);
        let path = self.config.folders.state.join(STATUS_FILE);
        let json = serde_json::to_vec_pretty(&snap).expect("snapshot serialises");
        if let Err(e) = atomic::publish(&path, &json, Overwrite::Replace) {
            warn!(error = %e, "cannot write status snapshot");
        }
        self.last_snapshot = Some(snap);
    }
}
