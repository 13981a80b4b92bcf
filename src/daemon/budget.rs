//! The memory budget, `[daemon] memory_mb`: what a job is estimated to need, and the
//! bytes held by the jobs developing. A job starts when its estimate fits beside theirs;
//! a frame or job that could never fit is refused with both numbers in its reason.

/// Bytes in one MB of `[daemon] memory_mb`, and of the sizes reasons give (10⁶).
pub(crate) const MB: u64 = 1_000_000;

/// The budget in bytes for `[daemon] memory_mb`.
pub(crate) fn budget_bytes(memory_mb: u64) -> u64 {
    memory_mb.saturating_mul(MB)
}

/// `bytes` in whole MB, rounded up.
pub(crate) fn megabytes(bytes: u64) -> u64 {
    bytes.div_ceil(MB)
}

/// The end of the reason a job of `need` bytes is refused under `memory_mb`:
/// `"N MB to develop, more than the memory budget ([daemon] memory_mb = M)"`.
pub(super) fn over_budget(need: u64, memory_mb: u64) -> String {
    format!(
        "{} MB to develop, more than the memory budget ([daemon] memory_mb = {memory_mb})",
        megabytes(need)
    )
}

/// The decoded size of one frame, read from its header at intake.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Footprint {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Bytes per decoded pixel (3 for 8-bit RGB, 6 for 16-bit RGB, 1 for 8-bit grey).
    pub bytes_per_pixel: u32,
}

/// The memory a job needs, in bytes, for frames `f_i` of `w_i × h_i = P_i` pixels and
/// `b_i` bytes per decoded pixel (`D_i = P_i·b_i`): each frame decoded; each frame but the
/// reference resampled onto the reference grid and its deghosting mask, `D_i + P_i`
/// ([`crate::darkroom::job_memory_bytes`]; the reference is chosen later, so the smallest
/// such term is left out); and the darkroom's working set for an RGB map of the largest
/// frame with looks ([`crate::darkroom::working_memory_bytes`]):
///
/// `Σ_i D_i + Σ_i (D_i + P_i) − min_i (D_i + P_i) + (4·3 + 2·3 + 8)·P + 18·64·w`,
/// `P = max_i P_i`
///
/// A decoder's buffer (at most the largest `D_i`) is freed before alignment and the
/// working set exist, and is smaller than they are; a raw bracket is not deghosted, and
/// its alignment's transient images (about 2.25 bytes a pixel a frame) are freed before
/// the working set exists. It does not depend on the configured looks (one or more are
/// assumed), so a reload cannot change what a running job was counted as. A three-frame
/// bracket of 45 MP 8-bit JPEGs: `45e6·(3·3 + 2·(3 + 1) + 26) ≈ 1.9e9` bytes.
pub fn job_bytes(frames: &[Footprint]) -> u64 {
    let pixels = |f: &Footprint| u64::from(f.width) * u64::from(f.height);
    let decoded = |f: &Footprint| pixels(f) * u64::from(f.bytes_per_pixel);
    let Some(largest) = frames.iter().max_by_key(|f| pixels(f)) else {
        return 0;
    };
    let aligned = |f: &Footprint| decoded(f) + pixels(f);
    let reference = frames.iter().map(aligned).min().unwrap_or(0);
    frames.iter().map(decoded).sum::<u64>() + frames.iter().map(aligned).sum::<u64>() - reference
        + crate::darkroom::working_memory_bytes(largest.width, largest.height, 3, 1)
}

/// The bytes of the budget held by the jobs developing.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(super) struct InUse(u64);

impl InUse {
    /// Bytes held.
    pub(super) fn bytes(self) -> u64 {
        self.0
    }

    /// True when a job of `need` bytes fits beside those developing in `budget` bytes.
    pub(super) fn fits(self, need: u64, budget: u64) -> bool {
        self.0.saturating_add(need) <= budget
    }

    /// A job of `need` bytes starts.
    pub(super) fn reserve(&mut self, need: u64) {
        self.0 = self.0.saturating_add(need);
    }

    /// A job that reserved `reserved` bytes finished.
    pub(super) fn release(&mut self, reserved: u64) {
        self.0 = self.0.saturating_sub(reserved);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn jobs_fit_beside_each_other_within_the_budget() {
        let budget = budget_bytes(64);
        assert_eq!(budget, 64_000_000);
        let mut in_use = InUse::default();
        let job = 46_000_000;
        assert!(in_use.fits(job, budget));
        in_use.reserve(job);
        assert!(!in_use.fits(job, budget), "two do not fit at once");
        assert!(in_use.fits(budget - job, budget));
        in_use.release(job);
        assert_eq!(in_use.bytes(), 0);
        in_use.release(job);
        assert_eq!(in_use.bytes(), 0, "never below zero");
        assert_eq!(budget_bytes(u64::MAX), u64::MAX);
    }

    #[test]
    fn reasons_round_up_to_whole_megabytes() {
        assert_eq!(megabytes(1), 1);
        assert_eq!(megabytes(MB), 1);
        assert_eq!(megabytes(MB + 1), 2);
        assert_eq!(
            over_budget(100_000_001, 64),
            "101 MB to develop, more than the memory budget ([daemon] memory_mb = 64)"
        );
    }

    /// A bracket of three 1400 × 1000 8-bit JPEGs (as the budget's test in
    /// `tests/daemon.rs` uses): the frames, two of them resampled with their masks, and
    /// the darkroom's working set; a single frame needs no alignment.
    #[test]
    fn a_jobs_estimate_counts_frames_their_alignment_and_the_working_set() {
        let jpeg = Footprint {
            width: 1400,
            height: 1000,
            bytes_per_pixel: 3,
        };
        let (pixels, frames) = (1400 * 1000, 1400 * 1000 * 3);
        let work = crate::darkroom::working_memory_bytes(1400, 1000, 3, 1);
        assert_eq!(job_bytes(&[jpeg]), frames + work);
        assert_eq!(
            job_bytes(&[jpeg; 3]),
            3 * frames + 2 * (frames + pixels) + work
        );
        assert_eq!(
            job_bytes(&[jpeg; 3]),
            crate::darkroom::job_memory_bytes(1400, 1000, 3, 3, 1, 1),
            "the darkroom's own bound for the same bracket"
        );
        let small = Footprint {
            width: 700,
            height: 500,
            ..jpeg
        };
        assert_eq!(
            job_bytes(&[jpeg, small]),
            frames + 700 * 500 * 3 + (frames + pixels) + work,
            "the smaller frame taken as the reference: the larger is resampled"
        );
        assert_eq!(job_bytes(&[]), 0);
    }
}
