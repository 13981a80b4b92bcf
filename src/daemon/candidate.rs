//! Settling one file: when a file noticed in the ingest folder is complete, judged from
//! what [`intake::observe`] reads of it and from what the watcher said of its writer, on
//! the clock the caller passes in (the daemon's monotonic clock; tests drive it).
//!
//! A candidate is complete once what is observed of it (size, mtime, `ctime`, device and
//! inode) has not changed for `settle`; or for [`FINISHED_QUIET`] (at most `settle`) after
//! its writer closed it or it was renamed into place; or as soon as it is observed when
//! it was handed over by filmback ([`Arrival::Delivered`]). A change after a close takes
//! the fast way back until the writer closes it again; a write notice after a hand-over
//! makes it wait as a closed file does.

use std::time::{Duration, Instant};

use super::intake::{Arrival, Observed};

/// How long a file must stay unchanged after its writer closed it or it was renamed into
/// place (at most `settle`): a rewrite just after the close (digiCamControl's EXIF)
/// restarts the wait; one later than this is a new version, developed again by content.
pub(super) const FINISHED_QUIET: Duration = Duration::from_millis(250);

/// How long a file still being written keeps open brackets from closing by the gap.
pub(super) const WRITER_PATIENCE: Duration = Duration::from_secs(60);

/// A file seen but not yet complete.
#[derive(Debug, Clone)]
pub(super) struct Candidate {
    first_seen: Instant,
    /// What was observed last, and since when it has not changed.
    seen: Option<Observed>,
    stable_since: Instant,
    /// Its writer closed it or it was renamed into place.
    finished: Option<Finished>,
}

/// A close or rename notice: the state first observed after it (`None` until settling
/// has looked), since when it has held, and how long it must hold ([`FINISHED_QUIET`],
/// or zero when delivered by filmback).
#[derive(Debug, Clone)]
struct Finished {
    first: Option<Observed>,
    since: Instant,
    quiet: Duration,
}

impl Candidate {
    /// A file first noticed at `now`, with what its notice said of its writer.
    pub(super) fn new(arrival: Arrival, now: Instant) -> Candidate {
        let mut c = Candidate {
            first_seen: now,
            seen: None,
            stable_since: now,
            finished: None,
        };
        c.notice(arrival, now);
        c
    }

    /// Another notice of the file at `now`.
    pub(super) fn notice(&mut self, arrival: Arrival, now: Instant) {
        let finished = |quiet| Finished {
            first: None,
            since: now,
            quiet,
        };
        match arrival {
            // Written after a hand-over: another writer's work, which waits as a closed
            // file does.
            Arrival::Writing => {
                if let Some(f) = &mut self.finished
                    && f.quiet.is_zero()
                {
                    *f = finished(FINISHED_QUIET);
                }
            }
            Arrival::Closed => self.finished = Some(finished(FINISHED_QUIET)),
            Arrival::Delivered => self.finished = Some(finished(Duration::ZERO)),
        }
    }

    /// Takes what was observed of the file at `now`; true when it is complete (see the
    /// module docs).
    pub(super) fn settled(&mut self, seen: Observed, now: Instant, settle: Duration) -> bool {
        let finished = match &mut self.finished {
            Some(f @ Finished { first: None, .. }) => {
                f.first = Some(seen.clone());
                f.since = now;
                f.quiet.is_zero()
            }
            // A hand-over once seen stays ready (only a write notice takes that back):
            // the hook's unlink of the download changes the file's ctime.
            Some(f) if f.quiet.is_zero() => true,
            Some(f) if f.first.as_ref() == Some(&seen) => {
                now.saturating_duration_since(f.since) >= settle.min(f.quiet)
            }
            Some(_) => {
                self.finished = None;
                false
            }
            None => false,
        };
        if finished {
            self.seen = Some(seen);
            true
        } else if self.seen.as_ref() != Some(&seen) {
            self.seen = Some(seen);
            self.stable_since = now;
            false
        } else {
            now.saturating_duration_since(self.stable_since) >= settle
        }
    }

    /// True while the file may still be being written (first noticed less than
    /// [`WRITER_PATIENCE`] before `now`): open brackets wait for it.
    pub(super) fn writing(&self, now: Instant) -> bool {
        now.saturating_duration_since(self.first_seen) < WRITER_PATIENCE
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::daemon::intake;

    const SETTLE: Duration = Duration::from_secs(2);

    /// A file's observed state, then the same file rewritten (another size and ctime).
    fn two_versions() -> (tempfile::TempDir, Observed, Observed) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.jpg");
        std::fs::write(&path, b"first").unwrap();
        let one = intake::observe(&path).unwrap();
        std::fs::write(&path, b"second version").unwrap();
        let two = intake::observe(&path).unwrap();
        assert_ne!(one, two);
        (dir, one, two)
    }

    fn at(t0: Instant, ms: u64) -> Instant {
        t0 + Duration::from_millis(ms)
    }

    #[test]
    fn an_unchanged_file_is_complete_after_the_settle_window() {
        let (_dir, one, two) = two_versions();
        let t0 = Instant::now();
        let mut c = Candidate::new(Arrival::Writing, t0);
        assert!(!c.settled(one.clone(), t0, SETTLE));
        assert!(!c.settled(one.clone(), at(t0, 1000), SETTLE));
        // A change restarts the window.
        assert!(!c.settled(two.clone(), at(t0, 1500), SETTLE));
        assert!(!c.settled(two.clone(), at(t0, 3499), SETTLE));
        assert!(c.settled(two, at(t0, 3500), SETTLE));
    }

    #[test]
    fn a_closed_file_is_complete_after_the_quiet_window_unless_rewritten() {
        let (_dir, one, two) = two_versions();
        let t0 = Instant::now();
        let mut c = Candidate::new(Arrival::Closed, t0);
        assert!(!c.settled(one.clone(), at(t0, 10), SETTLE));
        assert!(!c.settled(one.clone(), at(t0, 259), SETTLE));
        assert!(c.settled(one.clone(), at(t0, 260), SETTLE));
        // Rewritten after the close (the EXIF rewrite): the whole window again, until
        // the writer closes it again.
        let mut c = Candidate::new(Arrival::Closed, t0);
        assert!(!c.settled(one, at(t0, 10), SETTLE));
        assert!(!c.settled(two.clone(), at(t0, 100), SETTLE));
        assert!(!c.settled(two.clone(), at(t0, 1000), SETTLE));
        c.notice(Arrival::Closed, at(t0, 1100));
        assert!(!c.settled(two.clone(), at(t0, 1200), SETTLE));
        assert!(c.settled(two, at(t0, 1450), SETTLE));
    }

    #[test]
    fn the_quiet_window_is_at_most_the_settle_window() {
        let (_dir, one, _) = two_versions();
        let t0 = Instant::now();
        let settle = Duration::from_millis(100);
        let mut c = Candidate::new(Arrival::Closed, t0);
        assert!(!c.settled(one.clone(), t0, settle));
        assert!(c.settled(one, at(t0, 100), settle));
    }

    #[test]
    fn a_hand_over_is_complete_at_once_and_stays_so_until_written_again() {
        let (_dir, one, two) = two_versions();
        let t0 = Instant::now();
        let mut c = Candidate::new(Arrival::Delivered, t0);
        assert!(c.settled(one, t0, SETTLE));
        // The hook's unlink of the download changes the ctime: still complete.
        assert!(c.settled(two.clone(), at(t0, 5), SETTLE));
        // Written after the hand-over: it waits as a closed file does.
        c.notice(Arrival::Writing, at(t0, 10));
        assert!(!c.settled(two.clone(), at(t0, 20), SETTLE));
        assert!(c.settled(two, at(t0, 270), SETTLE));
    }

    #[test]
    fn a_candidate_holds_brackets_open_for_the_writers_patience() {
        let t0 = Instant::now();
        let c = Candidate::new(Arrival::Writing, t0);
        assert!(c.writing(t0 + WRITER_PATIENCE - Duration::from_millis(1)));
        assert!(!c.writing(t0 + WRITER_PATIENCE));
    }
}
