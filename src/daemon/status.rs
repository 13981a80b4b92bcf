//! What `filmback status` reads: a snapshot of the daemon's counts in
//! `state/status.json`, rewritten atomically when a count changes, and the systemd
//! `STATUS=` line.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};
use tracing::warn;

use super::State;
use super::journal;
use crate::atomic::{self, Overwrite};

/// File name of the status snapshot in the state folder.
pub(crate) const STATUS_FILE: &str = "status.json";

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
    /// True while the daemon runs and the ingest folder exists and is watched.
    pub watching: bool,
    /// Files seen, not yet complete.
    pub settling: usize,
    /// Frames in open (not yet closed) brackets.
    pub grouping: usize,
    /// Closed brackets waiting for a job.
    pub queued: usize,
    /// Brackets developing now.
    pub in_flight: usize,
    /// Brackets waiting to retry after an output failure, and files after a read error.
    pub retrying: usize,
    /// What is retried, why, and when next (absent in snapshots of older versions).
    #[serde(default)]
    pub retries: Vec<Retry>,
    /// Finished in this run.
    pub finished: usize,
    /// Rejected in this run.
    pub rejected: usize,
    /// Bytes of the memory budget held by the brackets developing (absent in snapshots
    /// of older versions).
    #[serde(default)]
    pub memory_in_use: u64,
    /// The memory budget, bytes (`[daemon] memory_mb` · 10⁶).
    #[serde(default)]
    pub memory_budget: u64,
    /// The viewer's address (`http://HOST:PORT/`) while it is served.
    #[serde(default)]
    pub viewer: Option<String>,
}

/// One thing the daemon will try again.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Retry {
    /// A bracket (its output stem) or a file (its path).
    pub what: String,
    /// Why the last attempt failed.
    pub reason: String,
    /// Attempts so far.
    pub attempts: u32,
    /// Unix seconds of the next attempt.
    pub next: u64,
}

/// Reads `state/status.json`, if the daemon ever wrote one.
pub fn read_snapshot(state: &Path) -> Option<Snapshot> {
    let text = std::fs::read_to_string(state.join(STATUS_FILE)).ok()?;
    serde_json::from_str(&text).ok()
}

/// Whether a daemon holds the state folder's lock ([`super::LOCK_FILE`]) now: `None` when
/// there is no lock file to ask (no daemon of this version ran there). The kernel
/// releases the lock when its process ends, even by `kill -9`, so a stale snapshot that
/// still says `running` is told from a live daemon.
pub fn lock_held(state: &Path) -> Option<bool> {
    let file = std::fs::File::open(state.join(super::LOCK_FILE)).ok()?;
    match file.try_lock_shared() {
        Ok(()) => {
            let _ = file.unlock();
            Some(false)
        }
        Err(std::fs::TryLockError::WouldBlock) => Some(true),
        Err(std::fs::TryLockError::Error(_)) => None,
    }
}

/// True when this process may create and replace files in the state folder: the daemon
/// publishes `status.json` by renaming a new file into it, so where that is refused the
/// snapshot may be stale (`access(2)` with write and search permission).
pub fn state_writable(state: &Path) -> bool {
    #[cfg(target_os = "linux")]
    {
        use rustix::fs::{Access, access};
        access(state, Access::WRITE_OK | Access::EXEC_OK).is_ok()
    }
    #[cfg(not(target_os = "linux"))]
    {
        std::fs::metadata(state).is_ok_and(|m| !m.permissions().readonly())
    }
}

impl State {
    /// The snapshot at `now`.
    pub(super) fn snapshot(&self, running: bool, now: Instant) -> Snapshot {
        let files = self.files.counts();
        Snapshot {
            pid: std::process::id(),
            running,
            updated: journal::unix_now(),
            ingest: self.config.folders.ingest.clone(),
            out: self.config.folders.out.clone(),
            watching: running && self.watcher.is_some(),
            settling: files.settling,
            grouping: self.grouper.waiting() + files.held,
            queued: self.queue.len(),
            in_flight: self.in_flight.len(),
            retrying: self.retries.len() + files.retrying,
            retries: self.retry_list(now),
            finished: self.summary.finished,
            rejected: self.summary.rejected,
            memory_in_use: self.in_use.bytes(),
            memory_budget: self.budget_bytes(),
            viewer: self
                .viewer
                .as_ref()
                .filter(|_| running)
                .map(|v| format!("http://{}/", v.address)),
        }
    }

    /// Output retries and unreadable files, soonest first, with their next attempt in
    /// Unix seconds as seen at `now`.
    fn retry_list(&self, now: Instant) -> Vec<Retry> {
        let unix = journal::unix_now();
        let at =
            |when: Instant| unix + when.saturating_duration_since(now).as_secs_f64().ceil() as u64;
        let mut list: Vec<Retry> = self
            .retries
            .iter()
            .map(|(when, work, reason)| Retry {
                what: work.closed.stem(),
                reason: reason.clone(),
                attempts: work.attempts,
                next: at(*when),
            })
            .chain(self.files.retrying().map(|(path, u)| Retry {
                what: path.display().to_string(),
                reason: u.reason().to_string(),
                attempts: u.attempts(),
                next: at(u.next()),
            }))
            .collect();
        list.sort_by(|a, b| a.next.cmp(&b.next).then_with(|| a.what.cmp(&b.what)));
        list
    }

    /// Publishes the status snapshot and the systemd STATUS line when a count changed
    /// (at most every 200 ms), or unconditionally when `last`.
    pub(super) fn report(&mut self, last: bool, now: Instant) {
        if !last && now.saturating_duration_since(self.last_report) < Duration::from_millis(200) {
            return;
        }
        let snap = self.snapshot(!last, now);
        let same = self.last_snapshot.as_ref().is_some_and(|s| {
            Snapshot {
                updated: snap.updated,
                ..s.clone()
            } == snap
        });
        if same && !last {
            return;
        }
        self.last_report = now;
        let status = format!(
            "{} finished, {} rejected, {} developing, {} queued, {} waiting, {} retrying",
            snap.finished,
            snap.rejected,
            snap.in_flight,
            snap.queued,
            snap.settling + snap.grouping,
            snap.retrying
        );
        let _ = sd_notify::notify(&[sd_notify::NotifyState::Status(&status)]);
        let path = self.config.folders.state.join(STATUS_FILE);
        let json = serde_json::to_vec_pretty(&snap).expect("snapshot serialises");
        if let Err(e) = atomic::publish(&path, &json, Overwrite::Replace) {
            warn!(error = %e, "cannot write status snapshot");
        }
        if let Some(viewer) = &self.viewer {
            viewer.status(&snap, self.in_use.bytes(), self.budget_bytes());
        }
        self.last_snapshot = Some(snap);
    }
}
