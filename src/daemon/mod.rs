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
mod queue;
mod settle;
mod status;

use std::collections::{HashMap, HashSet, VecDeque};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime};

use tokio::sync::mpsc;
use tokio::task::JoinSet;
use tracing::{info, warn};

pub use lab::{DarkroomLab, Job, JobError, Lab, Processed};
pub use status::{STATUS_FILE, Snapshot, read_snapshot};

use crate::atomic;
use bracket::{Closed, Grouper, Input};
use cache::ResponseCache;
use config::Config;
use intake::Notice;
use journal::{Journal, JournalError};

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
}
