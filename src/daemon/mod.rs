//! The watch-folder daemon: files appear in the ingest folder, brackets come out.
//!
//! ```text
//! notify / poll ─► candidates ─settle─► probe (EXIF, header) ─► Grouper ─► queue
//!                                                                          │ ≤ jobs
//!             journal ◄─ cache update ◄─ outputs ◄─ Lab (blocking thread) ◄┘
//! ```
//!
//! One async task owns all state; pixel work runs on blocking threads through the
//! [`Lab`] boundary, at most `jobs` at a time. The state is made of owned parts, each
//! with its own file and tests: the state of every file noticed (`files`: settling,
//! waiting out a back-off, taken, held, set aside), the settling of one file
//! (`candidate`), back-off (`backoff`), the grouper ([`bracket`]), the memory budget,
//! the journal and the response cache. The event loop reads the clock and passes `now`
//! in; nothing below it reads the clock itself, except after listing or probing files,
//! which takes time. A file is taken once its size, mtime, change time and inode were unchanged for
//! `settle_ms` on the daemon's clock (never judged by its mtime, which tethering tools set
//! to the capture time). When the queue is full, files simply stay on disk as candidates,
//! and nothing is dropped. Memory is bounded twice: by `jobs` developing brackets, and by the
//! `memory_mb` budget their estimates ([`job_bytes`]) must fit in (`budget`).
//!
//! Errors split as in any service: [`DaemonError`] is fatal (folders cannot be created,
//! the journal cannot be written); a bad frame, a failed output or a bad reload is
//! reported and the loop goes on.

pub mod bracket;
pub mod cache;
pub mod config;
pub mod journal;

mod backoff;
mod budget;
mod candidate;
mod files;
mod hooks;
pub(crate) mod intake;
pub(crate) mod lab;
mod queue;
mod settle;
mod status;
mod viewer;

use std::collections::{HashSet, VecDeque};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use tokio::sync::mpsc;
use tokio::task::JoinSet;
use tracing::{info, warn};

pub use budget::{Footprint, job_bytes};
pub use lab::{
    Aligned, Cause, DarkroomLab, Facts, Job, JobError, Lab, Pictured, Pictures, PresetError,
    Processed,
};
pub use status::{Retry, Snapshot, lock_held, read_snapshot, state_writable};
pub use viewer::PREVIEW_FOLDER;

use crate::atomic;
use bracket::{Closed, Grouper};
use cache::ResponseCache;
use config::Config;
use files::Files;
use intake::Notice;
use journal::{Journal, JournalError};

/// How long in-flight brackets may finish after a stop request before they are
/// abandoned (the journal redoes them); systemd's default stop timeout is 90 s, ours
/// promises 10 s.
pub const STOP_GRACE: Duration = Duration::from_secs(8);

/// Folder in the state folder where `filmback redo STEM` leaves its requests.
pub const REDO_FOLDER: &str = "redo";

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
    /// The folders overlap once links are resolved: outputs would come back as frames.
    #[error("{0}")]
    Folders(String),
    /// The journal cannot be read or written: continuing could lose or repeat work.
    #[error("journal: {0}")]
    Journal(#[from] JournalError),
    /// Another daemon holds the state folder: two would develop every bracket twice.
    #[error(
        "{}: another filmback watch ({}) already uses this state folder (it holds {LOCK_FILE}); stop it first, or give this one its own state folder",
        .state.display(),
        .pid.map_or_else(|| "pid unknown".to_string(), |p| format!("pid {p}"))
    )]
    Running {
        /// The state folder.
        state: PathBuf,
        /// The process holding it, as its lock file says.
        pid: Option<u32>,
    },
    /// The state folder's lock file cannot be opened or locked.
    #[error("{path}: cannot lock the state folder: {source}")]
    Lock {
        /// The lock file.
        path: PathBuf,
        /// What the operating system said.
        source: std::io::Error,
    },
}

/// File in the state folder that a running daemon holds locked (`flock`, exclusive, for
/// as long as the process lives: the kernel releases it even after `kill -9`), holding
/// the daemon's pid: one daemon per state folder.
pub const LOCK_FILE: &str = "daemon.lock";

/// Takes the state folder's lock ([`LOCK_FILE`]) and writes this process's pid into it;
/// [`DaemonError::Running`] names the holder when another daemon has it.
fn lock_state(state: &Path) -> Result<std::fs::File, DaemonError> {
    use std::io::{Read, Seek, Write};
    let path = state.join(LOCK_FILE);
    let io = |source| DaemonError::Lock {
        path: path.clone(),
        source,
    };
    let mut file = match atomic::lock_file(&path).map_err(io)? {
        atomic::Lock::Taken(file) => file,
        atomic::Lock::Held(mut file) => {
            let mut text = String::new();
            let _ = file.read_to_string(&mut text);
            return Err(DaemonError::Running {
                state: state.to_path_buf(),
                pid: text.trim().parse().ok(),
            });
        }
    };
    file.set_len(0)
        .and_then(|()| file.rewind())
        .and_then(|()| writeln!(file, "{}", std::process::id()))
        .and_then(|()| file.sync_data())
        .map_err(io)?;
    Ok(file)
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
    /// The earlier bracket or single this one replaces (a re-shot frame, `redo`).
    supersedes: Option<Superseded>,
    /// Bytes of the memory budget counted for it while it develops (released exactly when
    /// it finishes, whatever changed meanwhile).
    reserved: u64,
}

impl Work {
    fn new(closed: Closed) -> Work {
        Work {
            closed,
            attempts: 0,
            supersedes: None,
            reserved: 0,
        }
    }
}

/// What a re-development replaces: its outputs are published under the same stem, and
/// those of the earlier outputs the new set lacks are removed.
#[derive(Debug, Clone)]
struct Superseded {
    stem: String,
    outputs: Vec<PathBuf>,
}

type Outcome = (Work, Result<Processed, JobError>, Duration);

/// What woke the daemon's loop.
enum Event {
    Notice(Notice),
    Done(Box<Outcome>),
    Reload(Box<Config>),
    Tick,
}

struct State {
    config: Config,
    /// The folders as configured (the running configuration holds the ingest folder
    /// resolved): a reload compares against these.
    configured: config::Folders,
    /// The resolved ingest folder, and the one name of each of its files.
    root: intake::IngestRoot,
    /// The state folder's lock, held while the daemon runs ([`LOCK_FILE`]).
    _lock: std::fs::File,
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
    last_redo: Instant,
    /// The stems of the files noticed in ingest (RAW+JPEG pairing).
    stems: intake::Stems,
    /// Bodies seen shooting RAW+JPEG in this run: their JPEGs wait for a raw.
    pairing_bodies: HashSet<bracket::CameraId>,
    /// Estimated bytes of the jobs in flight.
    in_use: budget::InUse,
    /// Every file noticed that the daemon has business with, and its state.
    files: Files,
    queue: VecDeque<Work>,
    /// Brackets whose outputs failed: when to try again, and why.
    retries: Vec<(Instant, Work, String)>,
    in_flight: JoinSet<Outcome>,
    summary: Summary,
    stopping: bool,
    last_snapshot: Option<Snapshot>,
    last_report: Instant,
    last_watchdog: Instant,
    watchdog: Option<Duration>,
    /// The tether station's server, when it is served.
    viewer: Option<viewer::Station>,
    /// The thread running `[hooks]` commands, once one was needed.
    hooks: Option<hooks::Hooks>,
}

/// Runs the daemon until [`Control::Stop`] (or the control sender is dropped).
pub async fn run(
    mut config: Config,
    lab: Arc<dyn Lab>,
    control: mpsc::Receiver<Control>,
) -> Result<Summary, DaemonError> {
    create_folders(&config.folders)?;
    // Before anything in the folders is touched: another daemon's work is its own.
    let lock = lock_state(&config.folders.state)?;
    let configured = config.folders.clone();
    let root = intake::IngestRoot::new(&configured.ingest);
    config.folders.ingest = root.real().to_path_buf();
    let folders = &config.folders;
    remove_leftovers(folders);
    refuse_overlap(&config)?;
    recover_outputs(&folders.out);
    let mut journal = Journal::open(&folders.state)?;
    journal.resolve_inputs(|p| root.identity(p));
    let viewer = open_viewer(&config, journal.entries()).await;
    let (notices, rx) = mpsc::unbounded_channel();
    let now = Instant::now();
    let mut st = State {
        cache: ResponseCache::new(&folders.state),
        grouper: Grouper::new(config.bracket),
        config,
        configured,
        root,
        _lock: lock,
        lab,
        journal,
        started: now,
        notices,
        watcher: None,
        watched: None,
        watch_retry_at: now,
        last_rescan: now,
        last_redo: now,
        stems: intake::Stems::default(),
        pairing_bodies: HashSet::new(),
        in_use: budget::InUse::default(),
        files: Files::default(),
        queue: VecDeque::new(),
        retries: Vec::new(),
        in_flight: JoinSet::new(),
        summary: Summary::default(),
        stopping: false,
        last_snapshot: None,
        last_report: now,
        last_watchdog: now,
        watchdog: sd_notify::watchdog_enabled(),
        viewer,
        hooks: None,
    };
    st.check_folder(now).await;
    st.log_watching();
    let _ = sd_notify::notify(&[sd_notify::NotifyState::Ready]);
    st.serve(rx, control).await?;
    st.stop().await
}

/// Creates the ingest, output and state folders when they are missing.
fn create_folders(folders: &config::Folders) -> Result<(), DaemonError> {
    for dir in [&folders.ingest, &folders.out, &folders.state] {
        std::fs::create_dir_all(dir).map_err(|source| DaemonError::Folder {
            path: dir.clone(),
            source,
        })?;
    }
    Ok(())
}

/// Removes the temporary files a killed daemon left in the output and state folders
/// (the response cache and the previews included), and those a killed hook left in
/// ingest.
fn remove_leftovers(folders: &config::Folders) {
    for dir in [
        folders.out.clone(),
        folders.state.clone(),
        ResponseCache::new(&folders.state).dir().to_path_buf(),
    ] {
        remove_temporaries(&dir, Duration::ZERO);
    }
    if let Ok(stems) = std::fs::read_dir(folders.state.join(PREVIEW_FOLDER)) {
        for stem in stems.filter_map(Result::ok) {
            remove_temporaries(&stem.path(), Duration::ZERO);
        }
    }
    // In ingest a `filmback hook` may be handing a frame over right now: only what a
    // killed hook left (its download is still where gphoto2 saved it).
    remove_temporaries(&folders.ingest, STALE_HAND_OVER);
}

/// Completes or rolls back the output sets in `out` whose publishing a crash
/// interrupted, logging each.
fn recover_outputs(out: &Path) {
    for r in atomic::recover_sets(out) {
        match r {
            atomic::Recovered::Completed(stage, files) => info!(
                stage = %stage.display(),
                files = files.len(),
                "finished publishing a bracket's outputs interrupted by a crash"
            ),
            atomic::Recovered::RolledBack(stage) => info!(
                stage = %stage.display(),
                "removed the unpublished outputs of an interrupted bracket"
            ),
        }
    }
}

impl State {
    /// Logs the folders and settings the daemon watches with.
    fn log_watching(&self) {
        info!(
            ingest = %self.config.folders.ingest.display(),
            out = %self.config.folders.out.display(),
            state = %self.config.folders.state.display(),
            mode = ?self.config.watch.mode,
            jobs = self.config.daemon.jobs,
            finished_before = self.journal.entries().len(),
            "watching"
        );
    }

    /// The event loop: file notices, finished jobs, control messages and a tick of a
    /// quarter of `settle` (10–250 ms), each followed by dispatching and reporting; it
    /// returns at [`Control::Stop`] or when the control sender is dropped.
    async fn serve(
        &mut self,
        mut notices: mpsc::UnboundedReceiver<Notice>,
        mut control: mpsc::Receiver<Control>,
    ) -> Result<(), DaemonError> {
        let period = (self.config.watch.settle / 4)
            .clamp(Duration::from_millis(10), Duration::from_millis(250));
        let mut tick = tokio::time::interval(period);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            let event = tokio::select! {
                Some(notice) = notices.recv() => Event::Notice(notice),
                Some(done) = self.in_flight.join_next(), if !self.in_flight.is_empty() => {
                    Event::Done(Box::new(done.expect("develop panics are caught inside the task")))
                }
                c = control.recv() => match c {
                    Some(Control::Reload(cfg)) => Event::Reload(cfg),
                    Some(Control::Stop) | None => return Ok(()),
                },
                _ = tick.tick() => Event::Tick,
            };
            let now = Instant::now();
            match event {
                Event::Notice(notice) => self.notice(notice, now).await,
                Event::Done(done) => self.finish(*done, now)?,
                Event::Reload(config) => self.reload(*config, now).await,
                Event::Tick => self.tick(now).await?,
            }
            // Listing and probing may have taken time.
            let now = Instant::now();
            self.dispatch(now)?;
            self.report(false, now);
        }
    }

    /// Stops taking work, lets the brackets in flight finish for up to [`STOP_GRACE`],
    /// abandons the rest and returns the run's summary.
    async fn stop(mut self) -> Result<Summary, DaemonError> {
        self.stopping = true;
        let _ = sd_notify::notify(&[
            sd_notify::NotifyState::Stopping,
            sd_notify::NotifyState::Status("stopping: finishing brackets in flight"),
        ]);
        info!(in_flight = self.in_flight.len(), "stopping");
        let deadline = tokio::time::Instant::now() + STOP_GRACE;
        while !self.in_flight.is_empty() {
            tokio::select! {
                Some(done) = self.in_flight.join_next() => {
                    let done = done.expect("develop panics are caught inside the task");
                    self.finish(done, Instant::now())?;
                }
                () = tokio::time::sleep_until(deadline) => break,
            }
        }
        self.summary.abandoned = self.in_flight.len();
        if self.summary.abandoned > 0 {
            warn!(
                abandoned = self.summary.abandoned,
                "brackets still developing were abandoned; the next start redoes them"
            );
        }
        // Blocking threads cannot be interrupted; the process exit ends them, and their
        // temporary files are removed at the next start.
        self.in_flight.detach_all();
        self.report(true, Instant::now());
        info!(
            finished = self.summary.finished,
            rejected = self.summary.rejected,
            "stopped"
        );
        Ok(self.summary)
    }
}

/// The viewer's server, when `[viewer] enabled`; one that cannot be served is logged and
/// the daemon runs without it (the darkroom never depends on it). The recent
/// developments of `journal` are shown again.
async fn open_viewer(config: &Config, journal: &[journal::Entry]) -> Option<viewer::Station> {
    if !config.viewer.enabled {
        return None;
    }
    match viewer::Station::open(&config.viewer, &config.folders.state, journal).await {
        Ok(station) => Some(station),
        Err(e) => {
            warn!(error = %e, "the viewer is not served; the daemon goes on without it");
            None
        }
    }
}

/// Refuses folders that overlap once links are resolved (the configuration's check is
/// lexical): out, state or archive equal to the ingest folder, or inside it when it is
/// watched recursively.
fn refuse_overlap(config: &Config) -> Result<(), DaemonError> {
    let f = &config.folders;
    let Ok(ingest) = std::fs::canonicalize(&f.ingest) else {
        return Ok(());
    };
    for (name, dir) in [("out", &f.out), ("state", &f.state)]
        .into_iter()
        .chain(f.archive.as_ref().map(|a| ("archive", a)))
    {
        let Ok(real) = std::fs::canonicalize(dir) else {
            continue;
        };
        if real == ingest || (config.watch.recursive && real.starts_with(&ingest)) {
            return Err(DaemonError::Folders(format!(
                "{name} folder {} (really {}) is inside the watched ingest folder {} (really {}); its files would be taken as frames",
                dir.display(),
                real.display(),
                f.ingest.display(),
                ingest.display()
            )));
        }
    }
    Ok(())
}

/// A filmback temporary file in ingest unchanged for this long (by its `ctime`, which a
/// link or a write sets; its mtime may be the capture time) was left by a killed hook.
const STALE_HAND_OVER: Duration = Duration::from_secs(3600);

/// Removes temporary files of [`atomic`] left by an earlier run that was killed: those in
/// `dir` whose status (`ctime`) has not changed for `min_age`.
fn remove_temporaries(dir: &Path, min_age: Duration) {
    use std::os::unix::fs::MetadataExt;
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    let now = journal::unix_now() as i64;
    let old_enough = |path: &Path| {
        min_age.is_zero()
            || std::fs::symlink_metadata(path)
                .is_ok_and(|m| now - m.ctime() >= min_age.as_secs() as i64)
    };
    for path in entries.filter_map(Result::ok).map(|e| e.path()) {
        if atomic::is_temporary(&path) && old_enough(&path) {
            match std::fs::remove_file(&path) {
                Ok(()) => {
                    info!(file = %path.display(), "removed temporary file of an interrupted run")
                }
                Err(e) => warn!(file = %path.display(), error = %e, "cannot remove temporary file"),
            }
        }
    }
}

/// The message of a caught panic (`panic!`'s text), or `""` when it carried none.
fn panic_text(panic: &(dyn std::any::Any + Send)) -> String {
    panic
        .downcast_ref::<&str>()
        .map(|s| (*s).to_string())
        .or_else(|| panic.downcast_ref::<String>().cloned())
        .unwrap_or_default()
}

/// The output stem a frame at `path` gives ([`crate::atomic::fitting_stem`] of its stem).
fn file_stem(path: &Path) -> String {
    let stem = path.file_stem().unwrap_or_default().to_string_lossy();
    crate::atomic::fitting_stem(&stem).into_owned()
}

fn folder_id(dir: &Path) -> Option<(u64, u64)> {
    use std::os::unix::fs::MetadataExt;
    std::fs::metadata(dir)
        .ok()
        .filter(std::fs::Metadata::is_dir)
        .map(|m| (m.dev(), m.ino()))
}

impl State {
    /// The memory budget, `[daemon] memory_mb` in bytes (MB = 10⁶ bytes).
    fn budget_bytes(&self) -> u64 {
        budget::budget_bytes(self.config.daemon.memory_mb)
    }

    /// Seconds from the start to `now`: the grouper's clock.
    fn since_start(&self, now: Instant) -> f64 {
        now.saturating_duration_since(self.started).as_secs_f64()
    }

    async fn reload(&mut self, mut config: Config, now: Instant) {
        if config.folders != self.configured {
            warn!("folders changed in the configuration; they take effect at the next start");
        }
        config.folders = self.config.folders.clone();
        let rewatch = config.watch.mode != self.config.watch.mode
            || config.watch.recursive != self.config.watch.recursive
            || config.watch.poll != self.config.watch.poll;
        self.grouper.set_rules(config.bracket);
        self.config = config;
        if rewatch {
            self.watcher = None;
            self.watched = None;
            self.check_folder(now).await;
        }
        info!(source = ?self.config.source, "configuration reloaded");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Out, state and cache lose every leftover; ingest only those a killed hook left,
    /// not one a running hook is renaming into place.
    #[test]
    fn leftover_temporaries_are_removed_and_a_fresh_hand_over_is_not() {
        let dir = tempfile::tempdir().unwrap();
        let tmp = atomic::temporary_name(&dir.path().join("IMG_1.jpg"));
        let frame = dir.path().join("IMG_2.jpg");
        std::fs::write(&tmp, b"half").unwrap();
        std::fs::write(&frame, b"frame").unwrap();
        remove_temporaries(dir.path(), STALE_HAND_OVER);
        assert!(tmp.exists(), "a hand-over in progress is left alone");
        remove_temporaries(dir.path(), Duration::ZERO);
        assert!(!tmp.exists());
        assert!(frame.exists(), "frames are never touched");
    }
}
