//! The one boundary between the daemon and the pixel pipeline: [`Develop`].
//!
//! The daemon hands a developer a [`Job`] (the frames of one bracket or one single frame,
//! the camera's preset, its cached response, where to write) and gets back the published
//! outputs and the response it used. Everything about files appearing, queues, retries
//! and restarts stays on the daemon's side; everything about pixels on this side.
//!
//! [`PlainMerge`] is a complete, small developer built only on the crate's shared stages
//! (frame loading, [`InverseResponse`], [`atomic`]): it merges with the cached (else sRGB)
//! response and writes the EXR and the `linear` tone map. It is what `filmback watch`
//! runs until the fitted-response / film pipeline is connected behind this same trait.

use std::io::{Cursor, Write};
use std::path::PathBuf;
use std::time::{Duration, Instant};

use crate::atomic::{self, Overwrite};
use crate::bracket::{CameraId, Capture};
use crate::cache::CachedResponse;
use crate::config::Preset;
use crate::frame::{self, Limits, Samples};
use crate::journal::ResponseSource;
use crate::response::InverseResponse;

/// One unit of work: a bracket (two or more frames) or a single frame.
#[derive(Debug, Clone)]
pub struct Job {
    /// Deterministic id ([`crate::bracket::fingerprint`] of the inputs).
    pub id: String,
    /// The body.
    pub camera: CameraId,
    /// Frames in capture-time order, each with its EXIF exposure.
    pub frames: Vec<Capture>,
    /// The camera's preset (defaults merged with its `[camera.*]` table).
    pub preset: Preset,
    /// The camera's cached response, if any.
    pub cached: Option<CachedResponse>,
    /// Output folder.
    pub out: PathBuf,
    /// Output name stem (the first frame's file stem).
    pub stem: String,
}

impl Job {
    /// `out/<stem>.exr`.
    pub fn exr_path(&self) -> PathBuf {
        self.out.join(format!("{}.exr", self.stem))
    }

    /// `out/<stem>.<look>.jpg` for a film stock or tone map.
    pub fn look_path(&self, look: &str) -> PathBuf {
        self.out.join(format!("{}.{look}.jpg", self.stem))
    }

    /// True for a single frame (renderings only, no extended range).
    pub fn is_single(&self) -> bool {
        self.frames.len() == 1
    }
}

/// What a developer did.
#[derive(Debug, Clone)]
pub struct Developed {
    /// Every file published, in a stable order.
    pub outputs: Vec<PathBuf>,
    /// Where the response came from.
    pub source: ResponseSource,
    /// The bracket's own fit and its confidence in `(0, 1]`, to refine the cache.
    pub fit: Option<(InverseResponse, f64)>,
    /// Wall time per stage, in order (`decode`, `merge`, `exr`, …).
    pub stages: Vec<(&'static str, Duration)>,
    /// Things worth a warning (e.g. a requested look this developer does not render).
    pub notes: Vec<String>,
}

/// Why a job failed; the variant decides what the daemon does next.
#[derive(Debug, thiserror::Error)]
pub enum DevelopError {
    /// One input is not a usable frame: it is set aside as rejected and the rest of the
    /// bracket is developed without it.
    #[error("{path}: {reason}")]
    Frame {
        /// The frame.
        path: PathBuf,
        /// Why.
        reason: String,
    },
    /// An output could not be written (full disk, permissions): retried later.
    #[error("{path}: cannot write output: {reason}")]
    Output {
        /// The output.
        path: PathBuf,
        /// Why.
        reason: String,
    },
    /// The frames are fine one by one but cannot be developed together (different
    /// sizes, …): recorded as failed, retried only if an input changes.
    #[error("{0}")]
    Bracket(String),
}

impl From<atomic::PublishError> for DevelopError {
    fn from(e: atomic::PublishError) -> Self {
        let path = match &e {
            atomic::PublishError::Exists { path }
            | atomic::PublishError::Io { path, .. }
            | atomic::PublishError::Content { path, .. } => path.clone(),
        };
        DevelopError::Output {
            path,
            reason: e.to_string(),
        }
    }
}

/// Develops one job: reads the frames, publishes every output atomically under the job's
/// names (replacing a complete file left by an interrupted earlier attempt).
pub trait Develop: Send + Sync + 'static {
    /// Runs on a blocking thread; may take seconds.
    fn develop(&self, job: &Job) -> Result<Developed, DevelopError>;
}

impl<F> Develop for F
where
    F: Fn(&Job) -> Result<Developed, DevelopError> + Send + Sync + 'static,
{
    fn develop(&self, job: &Job) -> Result<Developed, DevelopError> {
        self(job)
    }
}

/// Merge with the cached (else sRGB) response; write the EXR and the `linear` tone map
/// (see the module docs).
#[derive(Debug, Clone, Copy, Default)]
pub struct PlainMerge;

/// Hat weight `w(B) = min(B, 1 − B)`, floored at `1e-3` so a pixel clipped in every frame
/// still takes a value (the mean of the frames' estimates) instead of `0/0`.
fn hat(b: f32) -> f32 {
    b.min(1.0 - b).max(1e-3)
}

impl Develop for PlainMerge {
    fn develop(&self, job: &Job) -> Result<Developed, DevelopError> {
        let mut stages = Vec::new();
        let mut notes = Vec::new();
        let t0 = Instant::now();
        let mut frames = Vec::with_capacity(job.frames.len());
        for capture in &job.frames {
            let loaded = frame::load(&capture.input.path, Limits::default()).map_err(|e| {
                DevelopError::Frame {
                    path: capture.input.path.clone(),
                    reason: e.to_string(),
                }
            })?;
            frames.push(loaded.frame);
        }
        stages.push(("decode", t0.elapsed()));
        let (w, h, ch) = (frames[0].width(), frames[0].height(), frames[0].channels());
        if let Some((c, f)) = job
            .frames
            .iter()
            .zip(&frames)
            .find(|(_, f)| (f.width(), f.height(), f.channels()) != (w, h, ch))
        {
            return Err(DevelopError::Bracket(format!(
                "{}: {}×{}×{} differs from the first frame's {w}×{h}×{ch}",
                c.input.path.display(),
                f.width(),
                f.height(),
                f.channels()
            )));
        }
        let (response, source) = match &job.cached {
            Some(c) if c.response.channels() == ch => (c.response.clone(), ResponseSource::Cached),
            _ => (InverseResponse::srgb(ch, 1024), ResponseSource::Standard),
        };
        // E = Σ w(B_k)·g(B_k)/e_k / Σ w(B_k), per channel; e_k normalised to the first
        // frame so the map's scale does not depend on ISO units.
        let t1 = Instant::now();
        let e0 = job.frames[0].exposure.unwrap_or(1.0);
        let n = w as usize * h as usize * ch;
        let mut num = vec![0f32; n];
        let mut den = vec![0f32; n];
        for (capture, f) in job.frames.iter().zip(&frames) {
            let e = (capture.exposure.unwrap_or(e0) / e0) as f32;
            let levels = f.bit_depth().levels();
            let scale = 1.0 / f.bit_depth().max_code() as f32;
            let tables: Vec<Vec<f32>> = (0..ch).map(|c| response.table(c, levels)).collect();
            let mut add = |i: usize, code: usize| {
                let b = code as f32 * scale;
                let wt = hat(b);
                num[i] += wt * tables[i % ch][code] / e;
                den[i] += wt;
            };
            match f.samples() {
                Samples::Eight(v) => v.iter().enumerate().for_each(|(i, &k)| add(i, k.into())),
                Samples::Sixteen(v) => v.iter().enumerate().for_each(|(i, &k)| add(i, k.into())),
            }
        }
        drop(frames);
        let mut radiance = num;
        radiance.iter_mut().zip(&den).for_each(|(e, w)| *e /= w);
        drop(den);
        stages.push(("merge", t1.elapsed()));
        let mut outputs = Vec::new();
        let rgb = |i: usize| -> (f32, f32, f32) {
            if ch == 3 {
                (radiance[3 * i], radiance[3 * i + 1], radiance[3 * i + 2])
            } else {
                (radiance[i], radiance[i], radiance[i])
            }
        };
        if job.preset.exr && !job.is_single() {
            let t2 = Instant::now();
            let path = job.exr_path();
            use exr::prelude::WritableImage;
            let mut bytes = Cursor::new(Vec::new());
            exr::prelude::Image::from_channels(
                (w as usize, h as usize),
                exr::prelude::SpecificChannels::rgb(|p: exr::prelude::Vec2<usize>| {
                    rgb(p.y() * w as usize + p.x())
                }),
            )
            .write()
            .to_buffered(&mut bytes)
            .map_err(|e| DevelopError::Output {
                path: path.clone(),
                reason: e.to_string(),
            })?;
            atomic::publish(&path, bytes.get_ref(), Overwrite::Replace)?;
            outputs.push(path);
            stages.push(("exr", t2.elapsed()));
        }
        for look in job.preset.tonemaps.iter().chain(&job.preset.films) {
            if look != "linear" {
                notes.push(format!("look {look:?} is not rendered by this developer"));
                continue;
            }
            let t3 = Instant::now();
            let path = job.look_path(look);
            let jpeg = linear_jpeg(&radiance, w, h, ch, job.preset.jpeg_quality, job.preset.t)
                .map_err(|reason| DevelopError::Output {
                    path: path.clone(),
                    reason,
                })?;
            atomic::publish(&path, &jpeg, Overwrite::Replace)?;
            outputs.push(path);
            stages.push(("linear", t3.elapsed()));
        }
        Ok(Developed {
            outputs,
            source,
            fit: None,
            stages,
            notes,
        })
    }
}

/// The `linear` tone map: radiance scaled so its 99th percentile times `2^t` is white,
/// clipped, sRGB-encoded, JPEG at `quality`.
fn linear_jpeg(
    radiance: &[f32],
    w: u32,
    h: u32,
    ch: usize,
    quality: u8,
    t: f64,
) -> Result<Vec<u8>, String> {
    let mut sorted: Vec<f32> = radiance.iter().copied().filter(|v| v.is_finite()).collect();
    let k = (sorted.len().saturating_sub(1) * 99) / 100;
    let p99 = if sorted.is_empty() {
        1.0
    } else {
        *sorted.select_nth_unstable_by(k, f32::total_cmp).1
    };
    let scale = 2f32.powf(t as f32) / p99.max(f32::MIN_POSITIVE);
    let encode = |v: f32| -> u8 {
        let x = (v * scale).clamp(0.0, 1.0);
        let s = if x <= 0.003_130_8 {
            12.92 * x
        } else {
            1.055 * x.powf(1.0 / 2.4) - 0.055
        };
        (s * 255.0 + 0.5) as u8
    };
    let pixels: Vec<u8> = radiance.iter().map(|&v| encode(v)).collect();
    let mut out = Vec::new();
    let color = if ch == 3 {
        jpeg_encoder::ColorType::Rgb
    } else {
        jpeg_encoder::ColorType::Luma
    };
    let (w16, h16) = (
        u16::try_from(w).map_err(|_| format!("width {w} exceeds JPEG's 65535"))?,
        u16::try_from(h).map_err(|_| format!("height {h} exceeds JPEG's 65535"))?,
    );
    jpeg_encoder::Encoder::new(&mut out, quality)
        .encode(&pixels, w16, h16, color)
        .map_err(|e| e.to_string())?;
    out.flush().map_err(|e| e.to_string())?;
    Ok(out)
}
