//! What the daemon knows of each file it noticed in the ingest folder: one map from the
//! file's one name ([`super::intake::IngestRoot::identity`]) to its state, and every
//! change of state here, so that no part of the daemon can forget a file halfway.
//!
//! ```text
//!            notice                 settled             read
//! (unknown) ───────► Settling ─────────────► (probe) ───────► Taken ──► (released)
//!                      ▲  │ gone                │ │            │ ▲
//!        back-off ran  │  ▼                     │ │ not now    ▼ │ no raw within the gap
//!        out, noticed  Unreadable ◄─────────────┘ │          Held
//!                                                 │ the JPEG of a noticed raw
//!                                                 ▼
//!                                              Companion (changed: Settling again)
//! ```
//!
//! What was developed or rejected is the journal's to remember, across restarts; a file
//! this map does not hold is one the daemon has no business with now.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use super::backoff::Unreadable;
use super::bracket::{Capture, Input};
use super::candidate::Candidate;
use super::intake::{Arrival, Taken};

/// The state of one file.
#[derive(Debug, Clone)]
pub(super) enum FileState {
    /// Noticed, not yet complete.
    Settling(Settling),
    /// Its last read failed for now; it waits out its back-off.
    Unreadable(Unreadable),
    /// Read and accepted as a frame: in the grouper, queued, waiting to retry or
    /// developing.
    Taken(Taken),
    /// A JPEG of a body that shoots RAW+JPEG, read, waiting for its raw (up to the gap).
    Held(Taken, Held),
    /// The JPEG of a RAW+JPEG capture set aside beside its raw: not a frame.
    Companion(Companion),
}

/// A file settling, with what it was before it was noticed again.
#[derive(Debug, Clone)]
pub(super) struct Settling {
    /// When it is complete.
    pub candidate: Candidate,
    /// The back-off of an earlier read that failed.
    pub retry: Option<Unreadable>,
    /// The JPEG set aside beside its raw, as it was before it changed.
    pub aside: Option<Companion>,
}

/// A held JPEG: its capture, and since when it waits.
#[derive(Debug, Clone)]
pub(super) struct Held {
    pub capture: Capture,
    pub since: Instant,
}

/// A JPEG set aside: the file as it was then, and its raw.
#[derive(Debug, Clone)]
pub(super) struct Companion {
    pub input: Input,
    pub raw: PathBuf,
}

/// How many files are in each state, for `status`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(super) struct Counts {
    /// Settling.
    pub settling: usize,
    /// Held JPEGs.
    pub held: usize,
    /// Waiting out a back-off (settling again or not).
    pub retrying: usize,
}

/// The state of every file the daemon has business with.
#[derive(Debug, Default)]
pub(super) struct Files {
    map: HashMap<PathBuf, FileState>,
}

impl Files {
    /// The state of `path`, if it has one.
    pub(super) fn state(&self, path: &Path) -> Option<&FileState> {
        self.map.get(path)
    }

    /// The frame read from `path`, while it is taken (or held).
    pub(super) fn taken(&self, path: &Path) -> Option<&Taken> {
        match self.map.get(path)? {
            FileState::Taken(t) | FileState::Held(t, _) => Some(t),
            _ => None,
        }
    }

    /// True while `path` is settling.
    pub(super) fn is_settling(&self, path: &Path) -> bool {
        matches!(self.map.get(path), Some(FileState::Settling(_)))
    }

    /// A notice of `path` at `now`: it settles (again), unless it is taken, a companion
    /// that `unchanged` says is as it was set aside, or waiting out its back-off.
    pub(super) fn notice(
        &mut self,
        path: PathBuf,
        arrival: Arrival,
        now: Instant,
        unchanged: impl FnOnce(&Input) -> bool,
    ) {
        let new = |retry, aside| {
            FileState::Settling(Settling {
                candidate: Candidate::new(arrival, now),
                retry,
                aside,
            })
        };
        let state = match self.map.remove(&path) {
            None => new(None, None),
            Some(FileState::Settling(mut s)) => {
                s.candidate.notice(arrival, now);
                FileState::Settling(s)
            }
            Some(FileState::Unreadable(u)) if u.due(now) => new(Some(u), None),
            Some(FileState::Companion(c)) if !unchanged(&c.input) => new(None, Some(c)),
            Some(kept) => kept,
        };
        self.map.insert(path, state);
    }

    /// The settling files, by name.
    pub(super) fn settling(&self) -> impl Iterator<Item = (&PathBuf, &Settling)> {
        self.map.iter().filter_map(|(p, s)| match s {
            FileState::Settling(s) => Some((p, s)),
            _ => None,
        })
    }

    /// The settling files' names, sorted.
    pub(super) fn settling_paths(&self) -> Vec<PathBuf> {
        let mut paths: Vec<PathBuf> = self.settling().map(|(p, _)| p.clone()).collect();
        paths.sort();
        paths
    }

    /// The candidate of a settling file.
    pub(super) fn candidate_mut(&mut self, path: &Path) -> Option<&mut Candidate> {
        match self.map.get_mut(path)? {
            FileState::Settling(s) => Some(&mut s.candidate),
            _ => None,
        }
    }

    /// Settling of `path` ends (complete, or gone): it is again what it was before it
    /// was noticed (waiting out a back-off, set aside) or nothing.
    pub(super) fn end_settling(&mut self, path: &Path) {
        let Some(FileState::Settling(s)) = self.map.get(path) else {
            return;
        };
        match (s.aside.clone(), s.retry.clone()) {
            (Some(c), _) => self.map.insert(path.to_path_buf(), FileState::Companion(c)),
            (None, Some(u)) => self
                .map
                .insert(path.to_path_buf(), FileState::Unreadable(u)),
            (None, None) => self.map.remove(path),
        };
    }

    /// A read of `path` that did not fail for now: its back-off is over.
    pub(super) fn read(&mut self, path: &Path) {
        if matches!(self.map.get(path), Some(FileState::Unreadable(_))) {
            self.map.remove(path);
        }
    }

    /// A read of `path` failed for now at `now`: returns the wait before the next one and
    /// the attempts so far.
    pub(super) fn unreadable(
        &mut self,
        path: &Path,
        now: Instant,
        retry: Duration,
        reason: String,
    ) -> (Duration, u32) {
        let mut u = match self.map.remove(path) {
            Some(FileState::Unreadable(u)) => u,
            _ => Unreadable::new(now),
        };
        let wait = u.failed(now, retry, reason);
        let attempts = u.attempts();
        self.map
            .insert(path.to_path_buf(), FileState::Unreadable(u));
        (wait, attempts)
    }

    /// The files waiting out a back-off (settling again or not).
    pub(super) fn retrying(&self) -> impl Iterator<Item = (&PathBuf, &Unreadable)> {
        self.map.iter().filter_map(|(p, s)| match s {
            FileState::Unreadable(u) | FileState::Settling(Settling { retry: Some(u), .. }) => {
                Some((p, u))
            }
            _ => None,
        })
    }

    /// The files whose back-off ran out at `now` and that are not settling yet.
    pub(super) fn due(&self, now: Instant) -> Vec<PathBuf> {
        self.map
            .iter()
            .filter(|(_, s)| matches!(s, FileState::Unreadable(u) if u.due(now)))
            .map(|(p, _)| p.clone())
            .collect()
    }

    /// `path` read as a frame.
    pub(super) fn take(&mut self, path: PathBuf, taken: Taken) {
        self.map.insert(path, FileState::Taken(taken));
    }

    /// A taken JPEG waits for its raw from `held.since`.
    pub(super) fn hold(&mut self, path: &Path, held: Held) {
        if let Some(FileState::Taken(t)) = self.map.get(path) {
            let t = *t;
            self.map
                .insert(path.to_path_buf(), FileState::Held(t, held));
        }
    }

    /// The held JPEGs' names, sorted.
    pub(super) fn held_paths(&self) -> Vec<PathBuf> {
        let mut paths: Vec<PathBuf> = self
            .map
            .iter()
            .filter(|(_, s)| matches!(s, FileState::Held(..)))
            .map(|(p, _)| p.clone())
            .collect();
        paths.sort();
        paths
    }

    /// Since when the JPEG at `path` is held.
    pub(super) fn held_since(&self, path: &Path) -> Option<Instant> {
        match self.map.get(path)? {
            FileState::Held(_, h) => Some(h.since),
            _ => None,
        }
    }

    /// A held JPEG becomes a frame: taken, its capture handed back for the grouper.
    pub(super) fn unhold(&mut self, path: &Path) -> Option<Capture> {
        let Some(FileState::Held(t, h)) = self.map.remove(path) else {
            return None;
        };
        self.map.insert(path.to_path_buf(), FileState::Taken(t));
        Some(h.capture)
    }

    /// The JPEG `input` set aside beside `raw`, whatever it was before.
    pub(super) fn set_aside(&mut self, input: Input, raw: PathBuf) {
        self.map.insert(
            input.path.clone(),
            FileState::Companion(Companion { input, raw }),
        );
    }

    /// The JPEG set aside beside `raw`, as it was then (also while it settles again).
    pub(super) fn companion_of(&self, raw: &Path) -> Option<&Input> {
        self.map.values().find_map(|s| match s {
            FileState::Companion(c) | FileState::Settling(Settling { aside: Some(c), .. })
                if c.raw == raw =>
            {
                Some(&c.input)
            }
            _ => None,
        })
    }

    /// `raw` cannot be a frame: its JPEG is no longer set aside; returns it.
    pub(super) fn unpair(&mut self, raw: &Path) -> Option<Input> {
        let jpeg = self.companion_of(raw)?.path.clone();
        match self.map.remove(&jpeg)? {
            FileState::Companion(c) => Some(c.input),
            FileState::Settling(mut s) => {
                let c = s.aside.take()?;
                self.map.insert(jpeg, FileState::Settling(s));
                Some(c.input)
            }
            other => {
                self.map.insert(jpeg, other);
                None
            }
        }
    }

    /// A taken (or held) frame's work is over: developed, rejected, failed, or left out
    /// of its bracket. A file in another state keeps it.
    pub(super) fn release(&mut self, path: &Path) {
        if self.taken(path).is_some() {
            self.map.remove(path);
        }
    }

    /// True while a file may still join an open bracket at `now`: a held JPEG, or a file
    /// settling or waiting out a back-off that was noticed less than the writer's
    /// patience ago.
    pub(super) fn writing(&self, now: Instant) -> bool {
        self.map.values().any(|s| match s {
            FileState::Held(..) => true,
            FileState::Settling(s) => {
                s.candidate.writing(now) || s.retry.as_ref().is_some_and(|u| u.writing(now))
            }
            FileState::Unreadable(u) => u.writing(now),
            FileState::Taken(_) | FileState::Companion(_) => false,
        })
    }

    /// How many files are in each state.
    pub(super) fn counts(&self) -> Counts {
        let mut n = Counts::default();
        for s in self.map.values() {
            match s {
                FileState::Settling(s) => {
                    n.settling += 1;
                    n.retrying += usize::from(s.retry.is_some());
                }
                FileState::Held(..) => n.held += 1,
                FileState::Unreadable(_) => n.retrying += 1,
                FileState::Taken(_) | FileState::Companion(_) => {}
            }
        }
        n
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::daemon::Footprint;
    use crate::daemon::bracket::CameraId;

    fn input(name: &str) -> Input {
        Input {
            path: PathBuf::from(name),
            size: 1,
            modified_ns: 0,
        }
    }

    fn taken() -> Taken {
        Taken {
            footprint: Footprint {
                width: 4,
                height: 3,
                bytes_per_pixel: 3,
            },
            digest: 7,
            inode: (1, 2),
        }
    }

    fn capture(name: &str) -> Capture {
        Capture {
            camera: CameraId::default(),
            exposure: Some(1.0),
            time_s: 0.0,
            input: input(name),
            companion: None,
        }
    }

    const RETRY: Duration = Duration::from_secs(1);

    #[test]
    fn a_noticed_file_settles_and_is_forgotten_when_gone() {
        let (t0, a) = (Instant::now(), PathBuf::from("/in/a.jpg"));
        let mut files = Files::default();
        files.notice(a.clone(), Arrival::Writing, t0, |_| false);
        assert!(files.is_settling(&a));
        assert_eq!(files.counts().settling, 1);
        assert!(files.writing(t0));
        files.end_settling(&a);
        assert!(files.state(&a).is_none());
        assert!(!files.writing(t0));
    }

    /// A read failing for now, again noticed during its back-off (nothing), after it
    /// (settling, back-off kept), read at last (forgotten).
    #[test]
    fn an_unreadable_file_waits_out_its_back_off_then_settles_again() {
        let (t0, a) = (Instant::now(), PathBuf::from("/in/a.jpg"));
        let mut files = Files::default();
        files.notice(a.clone(), Arrival::Closed, t0, |_| false);
        files.end_settling(&a);
        assert_eq!(files.unreadable(&a, t0, RETRY, "EACCES".into()), (RETRY, 1));
        let half = t0 + RETRY / 2;
        files.notice(a.clone(), Arrival::Writing, half, |_| false);
        assert!(!files.is_settling(&a), "waits out its back-off");
        assert!(files.due(half).is_empty());
        let later = t0 + RETRY;
        assert_eq!(files.due(later), std::slice::from_ref(&a));
        files.notice(a.clone(), Arrival::Writing, later, |_| false);
        assert!(files.is_settling(&a));
        assert_eq!(files.counts().retrying, 1, "still shown as retried");
        files.end_settling(&a);
        assert_eq!(
            files.unreadable(&a, later, RETRY, "EIO".into()),
            (2 * RETRY, 2),
            "the back-off grows"
        );
        files.read(&a);
        assert!(files.state(&a).is_none());
    }

    /// Taken, a notice changes nothing; released, a rejection or the end of its work
    /// forgets everything read of it at once (its footprint, digest and inode are one
    /// value), and a later notice makes it settle again.
    #[test]
    fn a_released_frame_forgets_all_that_was_read_of_it() {
        let (t0, a) = (Instant::now(), PathBuf::from("/in/a.jpg"));
        let mut files = Files::default();
        files.take(a.clone(), taken());
        files.notice(a.clone(), Arrival::Closed, t0, |_| false);
        assert_eq!(files.taken(&a), Some(&taken()));
        files.release(&a);
        assert!(files.taken(&a).is_none());
        assert!(files.state(&a).is_none());
        files.notice(a.clone(), Arrival::Closed, t0, |_| false);
        assert!(files.is_settling(&a));
        // Releasing a file that is not taken (settling again) keeps its state.
        files.release(&a);
        assert!(files.is_settling(&a));
    }

    #[test]
    fn a_held_jpeg_is_taken_and_becomes_a_frame_or_a_companion() {
        let t0 = Instant::now();
        let (a, b) = (PathBuf::from("/in/a.jpg"), PathBuf::from("/in/b.jpg"));
        let mut files = Files::default();
        for p in [&a, &b] {
            files.take(p.clone(), taken());
            let held = Held {
                capture: capture(&p.to_string_lossy()),
                since: t0,
            };
            files.hold(p, held);
        }
        assert_eq!(files.held_paths(), [a.clone(), b.clone()]);
        assert_eq!(files.held_since(&a), Some(t0));
        assert!(files.writing(t0 + Duration::from_secs(3600)), "held JPEGs");
        assert_eq!(files.counts().held, 2);
        assert_eq!(files.unhold(&a).map(|c| c.input.path), Some(a.clone()));
        assert!(files.taken(&a).is_some());
        files.set_aside(input("/in/b.jpg"), "/in/b.cr2".into());
        assert!(files.taken(&b).is_none());
        assert!(files.held_paths().is_empty());
    }

    /// A JPEG whose read failed, settled again and set aside beside its raw without
    /// being read: no longer retried.
    #[test]
    fn a_jpeg_set_aside_is_no_longer_retried() {
        let (t0, a) = (Instant::now(), PathBuf::from("/in/a.jpg"));
        let mut files = Files::default();
        files.unreadable(&a, t0, RETRY, "EACCES".into());
        files.notice(a.clone(), Arrival::Writing, t0 + RETRY, |_| false);
        files.end_settling(&a);
        assert_eq!(files.counts().retrying, 1);
        files.set_aside(input("/in/a.jpg"), "/in/a.cr2".into());
        assert_eq!(files.counts(), Counts::default());
        assert!(files.due(t0 + 100 * RETRY).is_empty());
        assert!(!files.writing(t0));
    }

    /// A companion stays set aside while unchanged; changed, it settles again and is
    /// still its raw's companion until it is set aside again or its raw is rejected.
    #[test]
    fn a_companion_changed_settles_again_and_a_rejected_raw_gives_it_back() {
        let t0 = Instant::now();
        let (jpeg, raw) = (PathBuf::from("/in/a.jpg"), PathBuf::from("/in/a.cr2"));
        let mut files = Files::default();
        files.set_aside(input("/in/a.jpg"), raw.clone());
        files.notice(jpeg.clone(), Arrival::Closed, t0, |_| true);
        assert!(matches!(files.state(&jpeg), Some(FileState::Companion(_))));
        files.notice(jpeg.clone(), Arrival::Closed, t0, |_| false);
        assert!(files.is_settling(&jpeg));
        assert_eq!(files.companion_of(&raw).map(|i| &i.path), Some(&jpeg));
        files.end_settling(&jpeg);
        assert!(matches!(files.state(&jpeg), Some(FileState::Companion(_))));
        assert_eq!(files.unpair(&raw).map(|i| i.path), Some(jpeg.clone()));
        assert!(files.companion_of(&raw).is_none());
        assert!(files.state(&jpeg).is_none());
        assert!(files.unpair(&raw).is_none());
    }
}
