//! Back-off: when to try again what failed for now (a file that could not be read, a
//! bracket whose outputs could not be written or whose frame is not on disk), on the
//! clock the caller passes in.

use std::time::{Duration, Instant};

/// Longest delay between two attempts.
pub(super) const MAX_RETRY: Duration = Duration::from_secs(300);

/// The wait before the next attempt after `attempts` failed ones, from `[daemon] retry_s`:
/// `retry · 2^attempts`, at most [`MAX_RETRY`].
pub(super) fn delay(retry: Duration, attempts: u32) -> Duration {
    (retry * 2u32.saturating_pow(attempts.min(16))).min(MAX_RETRY)
}

/// Takes out of `pending` the first `room` items that are `due`, in order; the others
/// stay, in order (retries that come due while the queue is full wait for room).
pub(super) fn take_due<T>(pending: &mut Vec<T>, due: impl Fn(&T) -> bool, room: usize) -> Vec<T> {
    let mut taken = Vec::new();
    let mut kept = Vec::with_capacity(pending.len());
    for item in pending.drain(..) {
        if taken.len() < room && due(&item) {
            taken.push(item);
        } else {
            kept.push(item);
        }
    }
    *pending = kept;
    taken
}

/// A file whose last read failed transiently (permission denied, I/O error): how often,
/// why, and when to look again.
#[derive(Debug, Clone)]
pub(super) struct Unreadable {
    first_seen: Instant,
    attempts: u32,
    next: Instant,
    reason: String,
}

impl Unreadable {
    /// A file whose first read failed at `now`, with no attempt counted yet.
    pub(super) fn new(now: Instant) -> Unreadable {
        Unreadable {
            first_seen: now,
            attempts: 0,
            next: now,
            reason: String::new(),
        }
    }

    /// Counts a failed read at `now` for `reason`; returns the wait before the next one
    /// ([`delay`] of the attempts before it).
    pub(super) fn failed(&mut self, now: Instant, retry: Duration, reason: String) -> Duration {
        let wait = delay(retry, self.attempts);
        self.attempts += 1;
        self.next = now + wait;
        self.reason = reason;
        wait
    }

    /// True once the file may be read again.
    pub(super) fn due(&self, now: Instant) -> bool {
        self.next <= now
    }

    /// When the file may be read again.
    pub(super) fn next(&self) -> Instant {
        self.next
    }

    /// Failed reads so far.
    pub(super) fn attempts(&self) -> u32 {
        self.attempts
    }

    /// Why the last read failed.
    pub(super) fn reason(&self) -> &str {
        &self.reason
    }

    /// True while open brackets wait for the file (first seen less than
    /// [`super::candidate::WRITER_PATIENCE`] before `now`).
    pub(super) fn writing(&self, now: Instant) -> bool {
        now.saturating_duration_since(self.first_seen) < super::candidate::WRITER_PATIENCE
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn take_due_takes_no_more_than_room_and_keeps_the_order() {
        let mut pending = vec![1, 8, 3, 5, 9, 7];
        let odd = |k: &i32| k % 2 == 1;
        assert_eq!(take_due(&mut pending, odd, 0), Vec::<i32>::new());
        assert_eq!(take_due(&mut pending, odd, 2), [1, 3]);
        assert_eq!(pending, [8, 5, 9, 7]);
        assert_eq!(take_due(&mut pending, odd, 9), [5, 9, 7]);
        assert_eq!(pending, [8]);
    }

    #[test]
    fn the_delay_doubles_from_retry_up_to_the_cap() {
        let retry = Duration::from_secs(5);
        let waits: Vec<u64> = (0..8).map(|n| delay(retry, n).as_secs()).collect();
        assert_eq!(waits, [5, 10, 20, 40, 80, 160, 300, 300]);
        assert_eq!(delay(retry, u32::MAX), MAX_RETRY);
    }

    #[test]
    fn an_unreadable_file_is_due_after_each_growing_wait() {
        let retry = Duration::from_secs(1);
        let t0 = Instant::now();
        let mut u = Unreadable::new(t0);
        assert!(u.due(t0));
        assert_eq!(u.failed(t0, retry, "EACCES".into()), Duration::from_secs(1));
        assert!(!u.due(t0 + Duration::from_millis(999)));
        assert!(u.due(t0 + Duration::from_secs(1)));
        let t1 = t0 + Duration::from_secs(1);
        assert_eq!(u.failed(t1, retry, "EIO".into()), Duration::from_secs(2));
        assert!(!u.due(t1 + Duration::from_millis(1999)));
        assert!(u.due(t1 + Duration::from_secs(2)));
        assert_eq!((u.attempts(), u.reason()), (2, "EIO"));
        assert!(u.writing(t0 + Duration::from_secs(59)));
        assert!(!u.writing(t0 + Duration::from_secs(60)));
    }
}
