//! The queue: closed brackets become jobs for the lab (at most `jobs` at a time), and a
//! job's outcome becomes a journal entry, a cache update, a rejection or a retry.

use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};

use tracing::{error, info, warn};

use super::bracket::{Alone, Bracket, CameraId, Closed};
use super::cache::{DISSENTS_TO_REPLACE, Dissent, PooledBracket};
use super::config::{Recalibrate, Singles};
use super::journal::{self, Entry};
use super::{
    DaemonError, Job, JobError, MAX_RETRY, Outcome, Processed, State, Work, file_stem, job_bytes,
};
use crate::darkroom::Pooling;

impl State {
    pub(super) fn dispatch(&mut self) -> Result<(), DaemonError> {
        while !self.stopping && self.in_flight.len() < self.config.daemon.jobs {
            let Some(mut work) = self.queue.pop_front() else {
                break;
            };
            // The memory budget: a job starts when its estimate fits beside those
            // developing; one that cannot fit even alone is recorded as failed.
            let need = self.job_bytes(&work.closed);
            let budget = self.config.daemon.memory_mb.saturating_mul(1_000_000);
            let single_reported = matches!(&work.closed, Closed::Single(..))
                && self.config.bracket.singles == Singles::Report;
            if !single_reported && self.in_use + need > budget {
                if self.in_flight.is_empty() {
                    let reason = format!(
                        "needs {} MB to develop, more than the memory budget ([daemon] memory_mb = {})",
                        need.div_ceil(1_000_000),
                        self.config.daemon.memory_mb
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
                info!(file = %capture.input.path.display(), camera = %capture.camera, reason = %alone, "single frame reported, not rendered");
                self.journal.record(Entry::Single {
                    id: work.closed.id(),
                    camera: capture.camera.clone(),
                    input: capture.input.clone(),
                    alone: *alone,
                    outputs: Vec::new(),
                    digests: self
                        .digests
                        .get(&capture.input.path)
                        .map(|d| vec![*d])
                        .unwrap_or_default(),
                    at: journal::unix_now(),
                })?;
                self.summary.finished += 1;
                self.release(&work.closed);
                continue;
            }
            // The JPEGs set aside beside raws, as they have settled by now.
            for frame in work.closed.frames_mut() {
                if frame.companion.is_none() {
                    frame.companion = self.companion_of_raw.get(&frame.input.path).cloned();
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
                stem: work
                    .supersedes
                    .as_ref()
                    .map_or_else(|| self.output_stem(&work.closed), |s| s.stem.clone()),
                stocks: self.config.folders.stocks.clone(),
            };
            let lab = Arc::clone(&self.lab);
            self.in_use += need;
            work.reserved = need;
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
            self.taken.remove(&f.input.path);
            self.footprints.remove(&f.input.path);
            self.digests.remove(&f.input.path);
        }
    }

    /// The memory estimate of a closed group ([`job_bytes`] of its frames' footprints;
    /// a frame without one, e.g. from a test, counts nothing).
    pub(super) fn job_bytes(&self, closed: &Closed) -> u64 {
        let frames: Vec<_> = closed
            .frames()
            .iter()
            .filter_map(|c| self.footprints.get(&c.input.path).copied())
            .collect();
        job_bytes(&frames)
    }

    /// Takes a job's outcome: journal and cache on success; on a bad frame, reject it and
    /// requeue the rest; retry output failures with back-off; record other failures.
    pub(super) fn finish(&mut self, (work, result, took): Outcome) -> Result<(), DaemonError> {
        self.in_use = self.in_use.saturating_sub(work.reserved);
        match result {
            Ok(processed) => self.developed(&work, &processed, took)?,
            Err(JobError::Frame { path, reason }) => self.frame_failed(&work, &path, reason)?,
            Err(e @ JobError::Output { .. }) => self.retry_later(work, &e),
            Err(JobError::Bracket(reason)) => self.failed(&work, reason)?,
        }
        Ok(())
    }

    /// A job that published its outputs: refine the cache, journal it, log it, archive.
    pub(super) fn developed(
        &mut self,
        work: &Work,
        dev: &Processed,
        took: Duration,
    ) -> Result<(), DaemonError> {
        let closed = &work.closed;
        let digests: Vec<u64> = closed
            .frames()
            .iter()
            .map(|c| self.digests.get(&c.input.path).copied())
            .collect::<Option<_>>()
            .unwrap_or_default();
        let camera = closed.camera().clone();
        let preset = self
            .config
            .preset_for(camera.model.as_deref(), camera.serial.as_deref());
        if let Some(pooling) = &dev.pooling
            && preset.recalibrate == Recalibrate::Auto
        {
            self.pool(&camera, &closed.stem(), dev, pooling);
        }
        if let Some(measured) = &dev.measured
            && let Err(e) = self
                .cache
                .put_measured(&camera, measured, journal::unix_now())
        {
            warn!(error = %e, "cannot store the measured JPEG curve in the response cache");
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
        };
        self.journal.record(entry)?;
        if let Some(old) = &work.supersedes {
            // Outputs of the earlier development the new one did not replace are stale.
            for stale in old.outputs.iter().filter(|o| !dev.outputs.contains(o)) {
                match std::fs::remove_file(stale) {
                    Ok(()) => info!(file = %stale.display(), "removed stale output"),
                    Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                    Err(e) => {
                        warn!(file = %stale.display(), error = %e, "cannot remove stale output")
                    }
                }
            }
        }
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
        Ok(())
    }

    /// A frame of the job could not be decoded: reject it, requeue the rest (a single if
    /// one frame is left).
    pub(super) fn frame_failed(
        &mut self,
        work: &Work,
        path: &Path,
        reason: String,
    ) -> Result<(), DaemonError> {
        let closed = &work.closed;
        let camera = closed.camera().clone();
        let frames: Vec<_> = closed.frames().into_iter().cloned().collect();
        let Some(bad) = frames.iter().find(|c| c.input.path == *path) else {
            return self.failed(
                work,
                format!("lab named a foreign frame {}: {reason}", path.display()),
            );
        };
        self.reject(bad.input.clone(), reason)?;
        let rest: Vec<_> = frames
            .into_iter()
            .filter(|c| c.input.path != *path)
            .collect();
        let closed = match rest.len() {
            0 => return Ok(()),
            1 => Closed::Single(rest.into_iter().next().expect("one"), Alone::NoPartner),
            _ => Closed::Bracket(Bracket {
                camera,
                frames: rest,
            }),
        };
        self.queue.push_front(Work::new(closed));
        Ok(())
    }

    /// Outputs could not be written: try again after `retry · 2^attempts` (at most
    /// [`MAX_RETRY`]).
    pub(super) fn retry_later(&mut self, work: Work, e: &JobError) {
        let delay =
            (self.config.daemon.retry * 2u32.saturating_pow(work.attempts.min(16))).min(MAX_RETRY);
        error!(
            bracket = %work.closed.stem(),
            error = %e,
            retry_in_s = delay.as_secs_f64(),
            "outputs not written; will retry"
        );
        self.retries.push((
            Instant::now() + delay,
            Work {
                attempts: work.attempts + 1,
                ..work
            },
            e.to_string(),
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
    /// aside beside their raws.
    pub(super) fn archive(&self, closed: &Closed) {
        let Some(dir) = &self.config.folders.archive else {
            return;
        };
        if let Err(e) = std::fs::create_dir_all(dir) {
            warn!(archive = %dir.display(), error = %e, "cannot create archive folder");
            return;
        }
        let files = closed
            .frames()
            .into_iter()
            .flat_map(|c| std::iter::once(&c.input).chain(c.companion.as_ref()));
        for input in files {
            let Some(name) = input.path.file_name() else {
                continue;
            };
            if let Err(e) = std::fs::rename(&input.path, dir.join(name)) {
                warn!(file = %input.path.display(), error = %e, "cannot archive input");
            }
        }
    }
}
