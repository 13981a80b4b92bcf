//! The one boundary between the daemon and the pixel pipeline: [`Lab`].
//!
//! The daemon hands a lab a [`Job`] (the frames of one bracket or one single frame,
//! the camera's preset, its cached response, where to write) and gets back the published
//! outputs and the response it used. Everything about files appearing, queues, retries
//! and restarts stays on the daemon's side; everything about pixels on this side.
//!
//! [`DarkroomLab`] is the lab `filmback watch` runs: the pipeline of
//! [`crate::darkroom`] under the camera's preset. The response follows the preset's
//! `recalibrate`: `auto` fits the bracket and falls back to the cached curve (else sRGB)
//! when the fit is weaker than `min_confidence`; `always` uses the bracket's own fit (sRGB
//! only if no fit is possible); `never` uses the cached curve (else sRGB). A single frame
//! is rendered through the cached curve (else sRGB), without an EXR.
//!
//! A body whose cache entry holds a curve measured from RAW+JPEG uses that curve for its
//! JPEG brackets and single frames under `auto` and `never` (it is exact where a fit is
//! an estimate); `always` still fits every bracket. When a raw frame is developed and its
//! camera JPEG lies beside it (same folder, same stem, `.jpg`/`.jpeg` in any case), the
//! pair measures the body's JPEG curve ([`crate::response::measured`]): the merged raw
//! radiance, scaled to each frame's exposure, against that frame's JPEG.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use rayon::prelude::*;

use crate::atomic::{self, Overwrite};
use crate::daemon::bracket::{CameraId, Capture};
use crate::daemon::cache::CachedResponse;
use crate::daemon::config::{Preset, Recalibrate};
use crate::daemon::viewer::{PREVIEW_EDGE, THUMB_EDGE};
use crate::darkroom::{
    self, BodyPool, DarkroomError, GivenResponse, Pooling, Prints, ResponsePolicy, Source,
};
use crate::deghost::KeptMap;
use crate::film::{Catalogue, ColourMode, Key};
use crate::frame::{self, Limits, LoadedFrame, Samples};
use crate::hdr_output::ExrOptions;
use crate::merge::{ClipMap, MergeOptions};
use crate::radiance::RadianceMap;
use crate::rendering::{self, Format, Look, Preview, Shrink, SourceExif};
use crate::response::pool::{self, Evidence};
use crate::response::{Degree, InverseResponse, JpegMeter, MeasuredResponse, RatioSource};

/// One unit of work: a bracket (two or more frames) or a single frame.
#[derive(Debug, Clone)]
pub struct Job {
    /// Deterministic id ([`crate::daemon::bracket::fingerprint`] of the inputs).
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
    /// Folder of extra film stocks beside the built-in ones, if configured.
    pub stocks: Option<PathBuf>,
    /// Keep small copies of the renderings and frames for the viewer
    /// ([`Processed::pictures`]).
    pub previews: bool,
}

impl Job {
    /// True for a single frame (renderings only, no extended range).
    fn is_single(&self) -> bool {
        self.frames.len() == 1
    }
}

/// What a lab did.
#[derive(Debug, Clone)]
pub struct Processed {
    /// Every file published, in a stable order.
    pub outputs: Vec<PathBuf>,
    /// Where the response came from.
    pub source: Source,
    /// The bracket's own fit and its confidence in `(0, 1]`.
    pub fit: Option<(InverseResponse, f64)>,
    /// A good fit's evidence for the body's pool, and the pool's refit (see
    /// [`crate::darkroom::Pooling`]).
    pub pooling: Option<Pooling>,
    /// True when the good fit contradicted the cached curve: its evidence is a dissent.
    pub contradicts_cache: bool,
    /// Wall time per stage, in order (`decode`, `merge`, `exr`, …).
    pub stages: Vec<(&'static str, Duration)>,
    /// Things worth a warning (e.g. a requested look this lab does not render).
    pub notes: Vec<String>,
    /// The body's JPEG curve measured from the raw frames' companion JPEGs, if any.
    pub measured: Option<MeasuredResponse>,
    /// What the development measured beyond its outputs (shown by the viewer).
    pub facts: Facts,
    /// Small copies of the renderings and frames, when the job asked for them.
    pub pictures: Option<Arc<Pictures>>,
}

/// Small sRGB copies of a development's renderings and frames, made from what the lab
/// held in memory, from which the viewer makes its previews without decoding a file.
#[derive(Debug, Clone, Default)]
pub struct Pictures {
    /// Per rendering, its copy of long edge at most the viewer's preview edge (1600 px).
    pub renderings: Vec<Pictured>,
    /// Per frame of the job, in its order, its copy of long edge at most the viewer's
    /// thumbnail edge (256 px) (`None` for a camera raw); empty when the frames developed
    /// are not the job's.
    pub frames: Vec<Option<Preview>>,
    /// Where no frame exposed the scene well, for a bracket of JPEG, PNG or TIFF frames
    /// ([`darkroom::Developed::clip_map`]).
    pub clipped: Option<ClipMap>,
    /// Where deghosting left frames out, when it did
    /// ([`darkroom::Developed::left_out_map`]).
    pub left_out: Option<KeptMap>,
}

/// A rendering's small copy.
#[derive(Debug, Clone)]
pub struct Pictured {
    /// The rendering's file name.
    pub name: String,
    /// Its copy.
    pub preview: Preview,
}

/// What a development measured beyond its outputs, for the viewer and its events.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Facts {
    /// Share of samples clipped high or low in every frame (no frame exposed them
    /// well; the merge could only bound them), `0..=1`.
    pub clipped_everywhere: f64,
    /// How the frames were aligned, for a bracket.
    pub alignment: Option<Aligned>,
    /// Share of pixels at least one frame was left out of by deghosting (`0..=1`), when
    /// deghosting ran.
    pub deghosted: Option<f64>,
    /// The response used, in one line (as the log and the EXR header give it).
    pub response: String,
}

/// The alignment of a bracket in brief.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Aligned {
    /// The mode asked for (`auto`, `translation`, `rigid`, `homography`, `off`).
    pub mode: String,
    /// The largest displacement of any frame's corners, pixels.
    pub largest_shift_px: f64,
}

impl Facts {
    /// The facts of `d`, developed from frames of `samples` samples each
    /// (`width · height · channels` of the first frame).
    fn of(d: &darkroom::Developed, samples: u64) -> Facts {
        let clipped = d.clipped.0 + d.clipped.1;
        Facts {
            clipped_everywhere: if samples == 0 {
                0.0
            } else {
                (clipped as f64 / samples as f64).min(1.0)
            },
            alignment: d.alignment.as_ref().map(|a| Aligned {
                mode: a.mode.as_str().to_string(),
                largest_shift_px: a
                    .frames
                    .iter()
                    .map(|f| f.displacement_px)
                    .fold(0.0, f64::max),
            }),
            deghosted: d.deghost.as_ref().map(|g| g.share),
            response: d.response.summary.clone(),
        }
    }
}

/// The reason a [`JobError`] gives: the error a lab met, kept whole with its sources (a
/// decoder's, the file system's, the darkroom's), or plain text (`"…".into()`).
pub type Cause = Box<dyn std::error::Error + Send + Sync + 'static>;

/// Why a job failed; the variant decides what the daemon does next.
#[derive(Debug, thiserror::Error)]
pub enum JobError {
    /// One input is not a usable frame: it is set aside as rejected and the rest of the
    /// bracket is developed without it.
    #[error("{path}: {reason}")]
    Frame {
        /// The frame.
        path: PathBuf,
        /// Why.
        #[source]
        reason: Cause,
    },
    /// An output could not be written (full disk, permissions): retried later.
    #[error("{path}: cannot write output: {reason}")]
    Output {
        /// The output.
        path: PathBuf,
        /// Why.
        #[source]
        reason: Cause,
    },
    /// The frames are fine one by one but cannot be developed together (different
    /// sizes, …): recorded as failed, retried only if an input changes.
    #[error("{0}")]
    Bracket(#[source] Cause),
}

/// A preset whose looks do not resolve (an unknown film or tone map, a bad option).
#[derive(Debug, thiserror::Error)]
#[error("preset: {0}")]
pub struct PresetError(#[source] pub rendering::RenderingError);

/// Develops one job: reads the frames, publishes every output atomically under the job's
/// names (replacing a complete file left by an interrupted earlier attempt).
pub trait Lab: Send + Sync + 'static {
    /// Runs on a blocking thread; may take seconds.
    fn process(&self, job: &Job) -> Result<Processed, JobError>;
}

impl<F> Lab for F
where
    F: Fn(&Job) -> Result<Processed, JobError> + Send + Sync + 'static,
{
    fn process(&self, job: &Job) -> Result<Processed, JobError> {
        self(job)
    }
}

/// A staging folder, removed when this is dropped: a development that fails, or panics
/// (the queue catches the panic), leaves no hidden folder of partial outputs in `out/`.
/// After [`atomic::publish_set`] the folder is already gone.
struct Staging(PathBuf);

impl Drop for Staging {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// The real lab (see the module docs).
#[derive(Debug, Clone, Copy, Default)]
pub struct DarkroomLab;

impl From<DarkroomError> for JobError {
    fn from(e: DarkroomError) -> Self {
        if let Some(path) = e.output_path() {
            return JobError::Output {
                path: path.to_path_buf(),
                reason: Box::new(e),
            };
        }
        JobError::Bracket(Box::new(e))
    }
}

impl DarkroomLab {
    /// The measured curve if the cache has one that fits the frames, else the cached
    /// curve if it fits, else the sRGB inverse.
    fn fallback(job: &Job, channels: usize) -> GivenResponse {
        if let Some(m) = job.cached.as_ref().and_then(|c| c.measured.as_ref())
            && m.response.channels() == channels
        {
            return GivenResponse {
                response: m.response.clone(),
                source: Source::Cached,
                label: format!(
                    "measured curve of {} (raw+JPEG, {} capture(s))",
                    job.camera, m.captures
                ),
            };
        }
        match &job.cached {
            Some(c) if c.response.channels() == channels => GivenResponse {
                response: c.response.clone(),
                source: Source::Cached,
                label: match c.min_confidence() {
                    Some(conf) => format!(
                        "cached curve of {} (pooled from {} bracket(s), confidence {conf:.2})",
                        c.camera,
                        c.pool.len()
                    ),
                    None => format!("cached curve of {} ({} bracket(s))", c.camera, c.brackets),
                },
            },
            _ => GivenResponse::standard(channels),
        }
    }
}

impl Lab for DarkroomLab {
    fn process(&self, job: &Job) -> Result<Processed, JobError> {
        let start = std::time::Instant::now();
        let unmixed = unmix(job, load_frames(job)?)?;
        let same_frames = unmixed.job.is_none();
        let job = unmixed.job.as_ref().unwrap_or(job);
        let frames = unmixed.frames;
        let decode = start.elapsed();
        let looks = looks_of(&job.preset, job.stocks.as_deref())?;
        let exif = first_frame_exif(job);
        // The outputs are written into a staging folder and published as one set.
        let (_lock, stage) = open_stage(job)?;
        let _staging = Staging(stage.clone());
        let developed = Self::develop(job, &frames, &looks, &exif, &stage);
        let (measured, measure_notes) = match &developed {
            Ok(d) => match &d.raw_radiance {
                Some(map) => measure_companions(&frames, job, map),
                None => (None, Vec::new()),
            },
            Err(_) => (None, Vec::new()),
        };
        let mut developed = developed.map_err(|e| in_output_folder(e, &job.out))?;
        let outputs = atomic::publish_set(&stage, &job.out).map_err(|e| JobError::Output {
            path: e.path().to_path_buf(),
            reason: Box::new(e),
        })?;
        let pictures = job
            .previews
            .then(|| Arc::new(pictures(&mut developed, &frames, same_frames)));
        let first = &frames[0].frame;
        let samples =
            u64::from(first.width()) * u64::from(first.height()) * first.channels() as u64;
        let facts = Facts::of(&developed, samples);
        let mut stages = vec![("decode", decode)];
        stages.extend(developed.stages);
        let mut notes: Vec<String> = unmixed.note.into_iter().collect();
        notes.extend(developed.warnings);
        if let Some(d) = developed.deghost.as_ref().filter(|d| d.share > 0.0) {
            notes.push(format!(
                "deghosted: {:.1} % of pixels merged without some frame (a moving subject)",
                100.0 * d.share
            ));
        }
        notes.extend(measure_notes);
        let mut pooling = developed.response.pooling;
        if let Some(p) = pooling.as_mut()
            && !developed.response.contradicts_cache
        {
            // After publishing: the refit is for the body's next brackets.
            let t = std::time::Instant::now();
            p.pooled = refit_pool(job.cached.as_ref(), p, &mut notes);
            if p.pooled.is_some() {
                stages.push(("pool", t.elapsed()));
            }
        }
        Ok(Processed {
            outputs,
            source: developed.response.source,
            fit: developed.response.fit,
            pooling,
            contradicts_cache: developed.response.contradicts_cache,
            stages,
            notes,
            measured,
            facts,
            pictures,
        })
    }
}

/// Decodes the frames of `job`, in parallel; a frame that became a link since the
/// intake is refused (links in ingest are never followed).
fn load_frames(job: &Job) -> Result<Vec<LoadedFrame>, JobError> {
    job.frames
        .par_iter()
        .map(|c| {
            if std::fs::symlink_metadata(&c.input.path).is_ok_and(|m| m.is_symlink()) {
                return Err(JobError::Frame {
                    path: c.input.path.clone(),
                    reason: "became a symbolic link: links in ingest are not followed".into(),
                });
            }
            frame::load(&c.input.path, Limits::default()).map_err(|e| JobError::Frame {
                path: c.input.path.clone(),
                reason: Box::new(e),
            })
        })
        .collect()
}

/// The first frame's EXIF, which the renderings carry (camera, lens, exposure, date,
/// artist, copyright); a frame whose file vanished since decoding carries none. Opened
/// without following a link, as the intake does.
fn first_frame_exif(job: &Job) -> SourceExif {
    crate::daemon::intake::open_no_follow(&job.frames[0].input.path)
        .and_then(|mut f| {
            let mut bytes = Vec::new();
            std::io::Read::read_to_end(&mut f, &mut bytes).map(|_| bytes)
        })
        .map(|bytes| SourceExif::from_frame_bytes(&bytes))
        .unwrap_or_default()
}

/// The job's staging folder in its output folder, locked ([`atomic::StageLock`]: a farm
/// task or another daemon developing the same bracket into the same folder gets it
/// after us, or we retry) and emptied of what an earlier attempt left.
fn open_stage(job: &Job) -> Result<(atomic::StageLock, PathBuf), JobError> {
    let stage = atomic::stage_folder(&job.out, &job.id);
    let output = |path: PathBuf, reason: Cause| JobError::Output { path, reason };
    std::fs::create_dir_all(&job.out).map_err(|e| output(job.out.clone(), Box::new(e)))?;
    let lock = atomic::StageLock::take(&stage).map_err(|e| output(e.path().into(), Box::new(e)))?;
    let _ = std::fs::remove_dir_all(&stage);
    std::fs::create_dir_all(&stage).map_err(|e| output(stage.clone(), Box::new(e)))?;
    Ok((lock, stage))
}

/// `e`, with an output it names in the staging folder named where it would have been
/// published, in `out`.
fn in_output_folder(e: JobError, out: &Path) -> JobError {
    match e {
        JobError::Output { path, reason } => JobError::Output {
            path: path
                .file_name()
                .map_or_else(|| out.to_path_buf(), |n| out.join(n)),
            reason,
        },
        other => other,
    }
}

/// The small copies of `developed`'s renderings (taken from it) and, when `same_frames`
/// (the frames are the job's), of `frames`.
fn pictures(
    developed: &mut darkroom::Developed,
    frames: &[LoadedFrame],
    same_frames: bool,
) -> Pictures {
    let copies = std::mem::take(&mut developed.previews);
    // The renderings are the last outputs, in the order of the looks.
    let first = developed.outputs.len().saturating_sub(copies.len());
    let renderings = developed.outputs[first..]
        .iter()
        .zip(copies)
        .filter_map(|(path, preview)| {
            Some(Pictured {
                name: path.file_name()?.to_string_lossy().into_owned(),
                preview,
            })
        })
        .collect();
    let frames = if same_frames {
        frames
            .par_iter()
            .map(|f| frame_copy(f, THUMB_EDGE))
            .collect()
    } else {
        Vec::new()
    };
    Pictures {
        renderings,
        frames,
        clipped: developed.clip_map.take(),
        left_out: developed.left_out_map.take(),
    }
}

/// A frame's copy of long edge at most `edge`, for any frame but a camera raw (its
/// mosaic is no picture).
fn frame_copy(loaded: &LoadedFrame, edge: u32) -> Option<Preview> {
    #[cfg(feature = "raw")]
    if loaded.raw.is_some() {
        return None;
    }
    Some(frame_picture(&loaded.frame, edge))
}

/// Samples averaged per block side in a frame's copy (a thumbnail needs no more).
const FRAME_SAMPLES: u32 = 4;

/// `frame`'s copy of long edge at most `edge`, its codes reduced to their top 8 bits
/// (grey repeated in R, G and B): every `s`-th pixel of every `s`-th row, `s =
/// max(1, ⌊f / FRAME_SAMPLES⌋)` for the copy's block size `f`, averaged by [`Shrink`].
fn frame_picture(frame: &crate::frame::Frame, edge: u32) -> Preview {
    let (w, h) = (frame.width(), frame.height());
    let step = (w.max(h).div_ceil(edge.max(1)) / FRAME_SAMPLES).max(1);
    let shrink = Shrink::new(w.div_ceil(step), h.div_ceil(step), edge);
    let shift = frame.bit_depth().bits().saturating_sub(8);
    let last = frame.channels().saturating_sub(1);
    let mut row = vec![0u8; w.div_ceil(step) as usize * 3];
    for (k, y) in (0..h).step_by(step as usize).enumerate() {
        match frame.samples() {
            Samples::Eight(codes) if last == 2 => {
                let line = &codes[y as usize * w as usize * 3..][..w as usize * 3];
                for (px, src) in row.chunks_exact_mut(3).zip(line.chunks(3 * step as usize)) {
                    px.copy_from_slice(&src[..3]);
                }
            }
            _ => {
                for (x, px) in (0..w).step_by(step as usize).zip(row.chunks_exact_mut(3)) {
                    for (c, v) in px.iter_mut().enumerate() {
                        *v =
                            u8::try_from(frame.code(x, y, c.min(last)) >> shift).unwrap_or(u8::MAX);
                    }
                }
            }
        }
        shrink.add_rows(k, &row);
    }
    shrink.finish()
}

impl DarkroomLab {
    /// Develops the decoded frames into `dir` (the staging folder).
    fn develop(
        job: &Job,
        frames: &[LoadedFrame],
        looks: &[Look],
        exif: &SourceExif,
        dir: &Path,
    ) -> Result<darkroom::Developed, JobError> {
        let preset = &job.preset;
        let prints = prints(job, looks, exif, dir);
        let channels = frames[0].frame.channels();
        if job.is_single() {
            Ok(darkroom::develop_single(
                &frames[0],
                Self::fallback(job, channels),
                &prints,
            )?)
        } else {
            let exposures: Vec<f64> = job
                .frames
                .iter()
                .map(|c| {
                    c.exposure.ok_or_else(|| {
                        JobError::Bracket(
                            format!(
                                "{}: exposure unknown (EXIF lacks the exposure time, f-number or ISO)",
                                c.input.path.display()
                            )
                            .into(),
                        )
                    })
                })
                .collect::<Result<_, _>>()?;
            let fallback = Self::fallback(job, channels);
            let measured = job.cached.as_ref().is_some_and(|c| c.measured.is_some());
            let policy = match preset.recalibrate {
                Recalibrate::Never => ResponsePolicy::Use(fallback),
                Recalibrate::Auto if measured && fallback.label.starts_with("measured") => {
                    ResponsePolicy::Use(fallback)
                }
                Recalibrate::Always => ResponsePolicy::Fit {
                    fallback: Some(GivenResponse::standard(channels)),
                    min_confidence: 0.0,
                    pool: None,
                },
                Recalibrate::Auto => ResponsePolicy::Fit {
                    fallback: Some(fallback),
                    min_confidence: preset.min_confidence,
                    pool: job
                        .cached
                        .as_ref()
                        .filter(|c| c.response.channels() == channels && !c.pool.is_empty())
                        .and_then(|c| {
                            Some(BodyPool {
                                brackets: c.pool.len(),
                                confidence: c.min_confidence()?,
                            })
                        }),
                },
            };
            Ok(darkroom::develop(
                frames,
                &exposures,
                RatioSource::Exif,
                policy,
                MergeOptions {
                    align: preset.align,
                    deghost: preset.deghost,
                    ..MergeOptions::default()
                },
                &prints,
            )?)
        }
    }
}

/// The looks of a preset (its films, then its tone maps), with the stocks of `stocks`
/// beside the built-in ones.
pub(crate) fn looks_of(preset: &Preset, stocks: Option<&Path>) -> Result<Vec<Look>, JobError> {
    let mut catalogue = Catalogue::builtin().map_err(|e| JobError::Bracket(Box::new(e)))?;
    if let Some(dir) = stocks {
        catalogue = catalogue
            .with_folder(dir)
            .map_err(|e| JobError::Bracket(Box::new(e)))?;
    }
    rendering::looks(
        &catalogue,
        &preset.films,
        &preset.tonemaps,
        preset.t,
        ColourMode::PerLayer,
        Key::LogAverage,
    )
    .map_err(|e| JobError::Bracket(Box::new(PresetError(e))))
}

/// What a job writes into `dir`: `STEM.exr` for a bracket when its preset asks for it,
/// `STEM.dng` for a bracket of camera raws and `STEM.ghosts.png` for a bracket when it
/// asks for them, and one JPEG per look at the preset's quality ([`Prints::paths`] names
/// them).
pub(crate) fn prints<'a>(
    job: &'a Job,
    looks: &'a [Look],
    exif: &'a SourceExif,
    dir: &'a Path,
) -> Prints<'a> {
    let preset = &job.preset;
    Prints {
        dir,
        stem: &job.stem,
        exr: (preset.exr && !job.is_single()).then(|| ExrOptions {
            primaries: preset.primaries,
            ..ExrOptions::default()
        }),
        radiance_hdr: false,
        dng: preset.dng
            && !job.is_single()
            && job
                .frames
                .iter()
                .all(|c| crate::daemon::intake::is_raw(&c.input.path)),
        looks,
        format: if preset.hdr_still {
            Format::UltraHdr {
                quality: preset.jpeg_quality,
            }
        } else {
            Format::Jpeg {
                quality: preset.jpeg_quality,
            }
        },
        space: preset.colour_space,
        exif,
        // A complete file under a job's name is a leftover of an interrupted earlier
        // attempt at this same job (names are unique per bracket): replace it.
        overwrite: Overwrite::Replace,
        luminance_calibration: preset.luminance_calibration,
        preview_edge: job.previews.then_some(PREVIEW_EDGE),
        ghost_map: preset.ghost_map && !job.is_single(),
    }
}

/// What a bracket is developed from once [`unmix`] has looked at its frames.
struct Unmixed {
    /// The job with the frames developed, when they differ from the job's own.
    job: Option<Job>,
    /// The decoded frames, in the job's order.
    frames: Vec<LoadedFrame>,
    /// What was left out and why, when anything was.
    note: Option<String>,
}

impl Unmixed {
    /// `job` developed from `captures` alone (decoded as `frames`), `note` saying what was
    /// left out and why.
    fn left_out(
        job: &Job,
        captures: Vec<Capture>,
        frames: Vec<LoadedFrame>,
        note: String,
    ) -> Unmixed {
        Unmixed {
            job: Some(Job {
                frames: captures,
                ..job.clone()
            }),
            frames,
            note: Some(note),
        }
    }
}

/// The frames a bracket is developed from. A bracket is either all raw or all
/// JPEG/PNG/TIFF; one that mixes them (a RAW+JPEG capture whose raw was rejected stands
/// in it as its JPEG) is developed, in this order of preference:
/// 1. from every capture's JPEG, when each raw frame has its companion JPEG;
/// 2. from the raws alone, when there are two or more;
/// 3. from the other frames alone, when there are two or more.
///
/// Otherwise it cannot be developed ([`JobError::Bracket`]).
fn unmix(job: &Job, frames: Vec<LoadedFrame>) -> Result<Unmixed, JobError> {
    let raws = frames.iter().filter(|f| is_raw(f)).count();
    if raws == 0 || raws == frames.len() {
        return Ok(Unmixed {
            job: None,
            frames,
            note: None,
        });
    }
    let stand_ins = file_list(frames.iter().filter(|f| !is_raw(f)).map(|f| &*f.path));
    if let Some(jpegs) = companions_of(job, &frames, is_raw) {
        return Ok(from_jpegs(job, frames, jpegs, &stand_ins));
    }
    let keep_raws = raws >= 2;
    if !keep_raws && frames.len() - raws < 2 {
        return Err(JobError::Bracket(
            format!(
                "a bracket is either all raw or all JPEG/PNG/TIFF; this one mixes them ({stand_ins} among raws) with fewer than two of either kind"
            )
            .into(),
        ));
    }
    Ok(of_one_kind(job, frames, keep_raws))
}

/// Whether `f` was decoded from a raw.
fn is_raw(f: &LoadedFrame) -> bool {
    #[cfg(feature = "raw")]
    return f.raw.is_some();
    #[cfg(not(feature = "raw"))]
    return {
        let _ = f;
        false
    };
}

/// The `paths`, displayed and joined by commas.
fn file_list<'a>(paths: impl Iterator<Item = &'a Path>) -> String {
    let names: Vec<String> = paths.map(|p| p.display().to_string()).collect();
    names.join(", ")
}

/// The bracket of `job` developed from every capture's JPEG: each raw of `frames` is
/// replaced by its decoded companion of `jpegs` (by index); `stand_ins` names the
/// frames that stand for captures without a usable raw.
fn from_jpegs(
    job: &Job,
    mut frames: Vec<LoadedFrame>,
    jpegs: Vec<(usize, LoadedFrame)>,
    stand_ins: &str,
) -> Unmixed {
    let raws_out = file_list(jpegs.iter().map(|(k, _)| &*frames[*k].path));
    let note = format!(
        "{raws_out} left out: {stand_ins} stands for a capture without a usable raw, so the bracket is developed from every capture's JPEG"
    );
    let mut captures = job.frames.clone();
    for (k, jpeg) in jpegs {
        if let Some(companion) = captures[k].companion.take() {
            captures[k].input = companion;
        }
        frames[k] = jpeg;
    }
    Unmixed::left_out(job, captures, frames, note)
}

/// The bracket of `job` developed from its raws alone (`keep_raws`) or from its other
/// frames alone, the rest of `frames` left out.
fn of_one_kind(job: &Job, frames: Vec<LoadedFrame>, keep_raws: bool) -> Unmixed {
    let (kept, left): (Vec<_>, Vec<_>) = frames
        .into_iter()
        .zip(&job.frames)
        .partition(|(f, _)| is_raw(f) == keep_raws);
    let note = format!(
        "{} left out: a bracket is either all raw or all JPEG/PNG/TIFF, and its other {} frames are {}",
        file_list(left.iter().map(|(f, _)| &*f.path)),
        kept.len(),
        if keep_raws { "raws" } else { "not raws" }
    );
    let (frames, captures): (Vec<LoadedFrame>, Vec<Capture>) =
        kept.into_iter().map(|(f, c)| (f, c.clone())).unzip();
    Unmixed::left_out(job, captures, frames, note)
}

/// The companion JPEG ([`Capture::companion`]) of each raw of `frames`, decoded, with
/// its index; `None` when a raw has no companion, or one that does not decode as a
/// JPEG/PNG/TIFF frame.
fn companions_of(
    job: &Job,
    frames: &[LoadedFrame],
    is_raw: impl Fn(&LoadedFrame) -> bool,
) -> Option<Vec<(usize, LoadedFrame)>> {
    let mut jpegs = Vec::new();
    for (k, (f, capture)) in frames.iter().zip(&job.frames).enumerate() {
        if is_raw(f) {
            let companion = capture.companion.as_ref()?;
            let jpeg = frame::load(&companion.path, Limits::default()).ok()?;
            if is_raw(&jpeg) {
                return None;
            }
            jpegs.push((k, jpeg));
        }
    }
    Some(jpegs)
}

/// The body's pool refitted with a good bracket's evidence (its curve and channel
/// confidences); `None` when the body has no pool yet (its curve becomes the bracket's
/// own fit). A pool that cannot be refitted keeps its curve, with a note.
fn refit_pool(
    cached: Option<&CachedResponse>,
    own: &Pooling,
    notes: &mut Vec<String>,
) -> Option<(InverseResponse, Vec<f64>)> {
    let cached = cached
        .filter(|c| !c.pool.is_empty() && c.response.channels() == own.evidence.channels.len())?;
    let all: Vec<&Evidence> = cached
        .pool
        .iter()
        .map(|b| &b.evidence)
        .chain(std::iter::once(&own.evidence))
        .collect();
    match pool::refit(&all, Degree::Auto) {
        Ok(c) => {
            let confidence = c.channels.iter().map(|ch| ch.fit.confidence).collect();
            Some((c.response, confidence))
        }
        Err(e) => {
            notes.push(format!(
                "the body's {} pooled bracket(s) could not be refitted with this one ({e}); its curve stays as it was",
                cached.pool.len()
            ));
            Some((cached.response.clone(), cached.confidence.clone()))
        }
    }
}

/// Measures the body's JPEG curve from the raw frames of `frames` whose capture has a
/// companion JPEG ([`Capture::companion`]): `map` (the developed raw radiance) times `e_k/e_max` against frame `k`'s JPEG.
/// Returns the curve (none if no frame has a JPEG or they do not cover the codes) and
/// notes on what could not be measured.
fn measure_companions(
    frames: &[LoadedFrame],
    job: &Job,
    map: &RadianceMap,
) -> (Option<MeasuredResponse>, Vec<String>) {
    let exposures: Vec<f64> = job
        .frames
        .iter()
        .map(|c| c.exposure.unwrap_or(1.0))
        .collect();
    let longest = exposures.iter().copied().fold(0.0, f64::max);
    let mut meter = JpegMeter::new();
    let mut notes = Vec::new();
    let mut pairs = 0;
    for ((f, capture), &e) in frames.iter().zip(&job.frames).zip(&exposures) {
        if !f.is_raw() {
            continue;
        }
        // The JPEG of the same capture, paired by the intake (same stem, same or sibling
        // folder) and settled.
        let Some(jpeg) = capture.companion.as_ref().map(|c| &c.path) else {
            continue;
        };
        let unit = if longest > 0.0 && frames.len() > 1 {
            (e / longest) as f32
        } else {
            1.0
        };
        let added = frame::load(jpeg, Limits::default())
            .map_err(|e| e.to_string())
            .and_then(|j| {
                meter
                    .add(map, unit, &j.frame, jpeg)
                    .map_err(|e| e.to_string())
            });
        match added {
            Ok(()) => pairs += 1,
            Err(e) => notes.push(format!(
                "JPEG curve not measured from {}: {e}",
                jpeg.display()
            )),
        }
    }
    if pairs == 0 {
        return (None, notes);
    }
    match meter.finish() {
        Ok(m) => (Some(m), notes),
        Err(e) => {
            notes.push(format!(
                "JPEG curve not measured ({pairs} RAW+JPEG capture(s)): {e}"
            ));
            (None, notes)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::Frame;

    #[test]
    fn large_frames_are_sampled_sparsely() {
        // 64 × 8 to an edge of 2: f = 32, every 8th pixel of every 8th row.
        let codes: Vec<u8> = (0..64 * 8)
            .flat_map(|i| {
                let v = if i % 8 == 0 { 200 } else { 0 };
                [v, v, v]
            })
            .collect();
        let frame = Frame::new(64, 8, 3, Samples::Eight(codes)).unwrap();
        let copy = frame_picture(&frame, 2);
        assert_eq!((copy.width, copy.height), (2, 1));
        assert_eq!(copy.rgb, vec![200; 6]);
    }

    #[test]
    fn frames_are_copied_by_their_top_eight_bits() {
        // 4 × 2 grey at 16 bits, shrunk by 2: each block averages 0x1200 and 0x3400.
        let codes = vec![0x1200, 0x3400, 0xff00, 0xff00, 0x1200, 0x3400, 0, 0];
        let grey = Frame::new(4, 2, 1, Samples::Sixteen(codes)).unwrap();
        let copy = frame_picture(&grey, 2);
        assert_eq!((copy.width, copy.height), (2, 1));
        assert_eq!(copy.rgb, vec![0x23, 0x23, 0x23, 0x80, 0x80, 0x80]);
        let rgb: Vec<u8> = (0..2 * 2 * 3).map(|v| v * 10).collect();
        let colour = Frame::new(2, 2, 3, Samples::Eight(rgb.clone())).unwrap();
        assert_eq!(frame_picture(&colour, 8).rgb, rgb);
    }
}
