//! The first pass of a `pooled` plan: one curve per body, frozen before any task runs.
//!
//! Of each body's JPEG/PNG/TIFF brackets, at most [`POOL_BRACKETS`] spread evenly over
//! its captures (the `k`-th of `m` picked is bracket `⌊k·n/m⌋` of `n`) are fitted as the
//! daemon fits a bracket ([`crate::darkroom::choose_response`] with the preset's
//! `min_confidence`); the good fits' evidence is pooled into one joint fit
//! ([`crate::response::pool::refit`]) and written in the response-cache format
//! ([`crate::daemon::cache`]), so the body's every task reads the same curve.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use rayon::prelude::*;

use super::PlanError;
use super::plan::preset_of;
use crate::daemon::bracket::{Bracket, CameraId, Closed};
use crate::daemon::cache::{CachedResponse, POOL_BRACKETS, PooledBracket, ResponseCache};
use crate::daemon::config::Config;
use crate::daemon::{intake, journal};
use crate::darkroom::{self, ResponsePolicy};
use crate::frame::{self, Limits, LoadedFrame};
use crate::response::pool::{self, Evidence};
use crate::response::{Degree, RatioSource};

/// Fits and writes each body's frozen curve into the response cache under `state`;
/// returns each body's file. A body without a good fit has none.
pub(super) fn freeze(
    groups: &[Closed],
    config: &Config,
    state: &Path,
) -> Result<HashMap<CameraId, PathBuf>, PlanError> {
    let mut by_body: BTreeMap<&CameraId, Vec<&Bracket>> = BTreeMap::new();
    for group in groups {
        if let Closed::Bracket(b) = group
            && !b.frames.iter().any(|c| intake::is_raw(&c.input.path))
        {
            by_body.entry(&b.camera).or_default().push(b);
        }
    }
    let cache = ResponseCache::new(state);
    let mut files = HashMap::new();
    for (camera, brackets) in by_body {
        let min_confidence = preset_of(config, camera).min_confidence;
        let pooled: Vec<PooledBracket> = spread(&brackets, POOL_BRACKETS)
            .par_iter()
            .filter_map(|b| evidence(b, min_confidence))
            .collect();
        let Some(entry) = frozen_entry(camera, pooled) else {
            continue;
        };
        cache.put(&entry).map_err(|source| PlanError::Response {
            camera: camera.to_string(),
            source: Box::new(source),
        })?;
        files.insert(camera.clone(), cache.path_for(camera));
    }
    Ok(files)
}

/// At most `n` of `items`, spread evenly: item `⌊k·len/n⌋` for `k < n`.
fn spread<T>(items: &[T], n: usize) -> Vec<&T> {
    if items.len() <= n {
        return items.iter().collect();
    }
    (0..n).map(|k| &items[k * items.len() / n]).collect()
}

/// A bracket's own fit, as the daemon makes it, when it is good: its evidence for the
/// body's pool. `None` when a frame does not decode or the fit is weak.
fn evidence(bracket: &Bracket, min_confidence: f64) -> Option<PooledBracket> {
    let frames: Vec<LoadedFrame> = bracket
        .frames
        .iter()
        .map(|c| frame::load(&c.input.path, Limits::default()).ok())
        .collect::<Option<_>>()?;
    let exposures: Vec<f64> = bracket
        .frames
        .iter()
        .map(|c| c.exposure)
        .collect::<Option<_>>()?;
    let policy = ResponsePolicy::Fit {
        fallback: None,
        min_confidence,
        pool: None,
    };
    let mut stages = Vec::new();
    let chosen = darkroom::choose_response(
        &darkroom::bracket(&frames, &exposures),
        RatioSource::Exif,
        policy,
        &mut stages,
    )
    .ok()?;
    let pooling = chosen.pooling?;
    let name = Closed::Bracket(bracket.clone()).stem();
    Some(PooledBracket {
        name,
        at: journal::unix_now(),
        own_confidence: pooling.own_confidence.iter().copied().fold(1.0, f64::min),
        own_misfit: pooling.own_misfit,
        evidence: pooling.evidence,
    })
}

/// One joint fit over `pooled` as the body's cache entry; `None` without evidence or
/// when the joint fit fails.
fn frozen_entry(camera: &CameraId, pooled: Vec<PooledBracket>) -> Option<CachedResponse> {
    let all: Vec<&Evidence> = pooled.iter().map(|b| &b.evidence).collect();
    let calibration = pool::refit(&all, Degree::Auto).ok()?;
    Some(CachedResponse {
        camera: camera.clone(),
        confidence: calibration
            .channels
            .iter()
            .map(|c| c.fit.confidence)
            .collect(),
        response: calibration.response,
        brackets: pooled.len() as u64,
        updated: journal::unix_now(),
        pool: pooled,
        dissent: Vec::new(),
        measured: None,
    })
}
