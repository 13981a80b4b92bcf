//! The darkroom: decoded frames in, published files out. One bracket goes through the
//! report's three steps — response ([`crate::response`]), radiance merge
//! ([`crate::merge`]), display renderings ([`crate::rendering`]) — and the radiance map is
//! written as OpenEXR ([`crate::hdr_output`]). `filmback merge` and the daemon both
//! develop through here, so a bracket dropped in the ingest folder and the same bracket
//! given on the command line come out identical.
//!
//! # Memory
//!
//! Unless a confidence layer is asked for or a look has optics (MTF, halation: it reads
//! the whole map), the merge is evaluated where it is read, with no radiance buffer: two
//! 8-bit frames through one table per code pair ([`PairMerge`], a lookup a sample),
//! while the EXR is encoded (a PIZ block of lines at a time on each thread) and while
//! each look is developed (a band of rows at a time); any other bracket through the
//! per-frame tables ([`BracketMerge`]) when it is written as EXR without looks (each look
//! would merge all its frames again). The peak is then the decoded frames the caller
//! holds plus the EXR and the looks' working sets. Otherwise the map is built once
//! (`width × height × channels × 4` bytes) beside the decoded frames and every output
//! reads it. The renderings are made on a second thread while the EXR is encoded.
//! [`job_memory_bytes`] bounds the peak.

use std::io::Cursor;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use crate::align::{self, AlignFrame, AlignMode, Alignment};
use crate::atomic::{self, Overwrite, PublishError};
use crate::deghost::{self, GhostMasks};
use crate::display::ColourSpace;
use crate::frame::{Frame, LoadedFrame, Samples};
use crate::hdr_output::{self, ExrOptions, FrameRecord, OutputError, Provenance, Written};
use crate::merge::{
    self, BracketFrame, BracketMerge, BracketOrder, Deghost, MergeError, MergeOptions, PairMerge,
};
use crate::radiance::{RadianceMap, RadianceSource};
use crate::rendering::{self, Format, Look, Outputs, Preview, RenderingError, SourceExif};
use crate::response::{CalibrationError, InverseResponse, RatioSource};

mod choice;
#[cfg(feature = "raw")]
mod raw;

use choice::use_given;

pub use choice::CALIBRATION_PIXELS;
pub use choice::{
    BodyPool, CONTRADICTION_STOPS, ChosenResponse, GivenResponse, Pooling, ResponsePolicy, Source,
    choose_response,
};

/// Why a bracket could not be developed. Each variant names the file concerned.
#[derive(Debug, thiserror::Error)]
pub enum DarkroomError {
    /// The frames do not form a bracket (sizes, depths, cameras, exposures).
    #[error(transparent)]
    Merge(#[from] MergeError),
    /// The response could not be recovered and there was no fallback.
    #[error("cannot calibrate the response from {dark} and {bright}: {source}")]
    Calibrate {
        /// The darker frame of the pair.
        dark: PathBuf,
        /// The brighter frame.
        bright: PathBuf,
        /// Why.
        source: CalibrationError,
    },
    /// The OpenEXR or Radiance HDR file could not be encoded or published (an encoder's
    /// refusal is not a failure to write: developing again would fail again).
    #[error(transparent)]
    Output(#[from] OutputError),
    /// A rendering could not be made or published.
    #[error(transparent)]
    Rendering(#[from] RenderingError),
    /// A raw bracket could not be merged (mixed with other frames, unlike frames).
    #[cfg(feature = "raw")]
    #[error(transparent)]
    Raw(#[from] crate::raw::RawError),
    /// The deghosting map could not be encoded (nothing was written).
    #[error("{path}: cannot encode the deghosting map as PNG: {source}")]
    GhostMap {
        /// The PNG it was encoding.
        path: PathBuf,
        /// What the encoder said.
        source: png::EncodingError,
    },
    /// A file could not be published.
    #[error(transparent)]
    Publish(#[from] PublishError),
    /// A DNG was asked for a bracket that is not camera raw: a DNG holds the sensor's
    /// mosaic, which only raw frames have.
    #[error(
        "{}: a DNG is made only of a camera raw bracket ({reason}); leave out the DNG for this bracket",
        path.display()
    )]
    DngNeedsRaw {
        /// The frame that is not raw.
        path: PathBuf,
        /// Why it is not raw.
        reason: NotRaw,
    },
    /// The DNG encoder refused the merged mosaic.
    #[cfg(feature = "raw")]
    #[error("{}: {source}", path.display())]
    Dng {
        /// The file it was encoding.
        path: PathBuf,
        /// Why.
        #[source]
        source: crate::raw::dng::DngError,
    },
}

/// Why a frame is not camera raw ([`DarkroomError::DngNeedsRaw`]).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum NotRaw {
    /// The frame is of another format: its extension in capitals ("JPG"), or "no file
    /// extension".
    #[error("this frame is {0}, not camera raw")]
    Format(String),
    /// This build reads no camera raw (feature `raw` off).
    #[error("filmback was built without camera raw support (feature `raw`)")]
    NoRawSupport,
}

impl DarkroomError {
    /// The output file a failure to write concerns, if it is one (full disk, permissions,
    /// an existing file): such failures are worth retrying; the others are not.
    pub(crate) fn output_path(&self) -> Option<&Path> {
        let publish = match self {
            DarkroomError::Publish(p)
            | DarkroomError::Output(OutputError::Publish(p))
            | DarkroomError::Rendering(RenderingError::Publish(p)) => p,
            DarkroomError::Rendering(RenderingError::Encode { path, .. }) => return Some(path),
            _ => return None,
        };
        Some(publish.path())
    }
}

/// Wall time per stage, in the order they ran.
pub type Stages = Vec<(&'static str, Duration)>;

/// A merged raw bracket's DNG (never made without raw support).
#[cfg(feature = "raw")]
type DngOf = raw::DngSource;
#[cfg(not(feature = "raw"))]
type DngOf = NoRaw;

/// Without raw support, the shape of a merged raw bracket, never made.
#[cfg(not(feature = "raw"))]
struct NoRaw {
    chosen: ChosenResponse,
    merged: merge::Merged,
    alignment: Alignment,
}

fn file_name(path: &Path) -> String {
    path.file_name().map_or_else(
        || path.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    )
}

/// What to make of a radiance map, and where.
#[derive(Debug, Clone)]
pub struct Prints<'a> {
    /// Output folder (must exist).
    pub dir: &'a Path,
    /// Stem of every output name: `DIR/STEM.exr`, `DIR/STEM.LOOK.jpg`.
    pub stem: &'a str,
    /// Write the OpenEXR map, with these options.
    pub exr: Option<ExrOptions>,
    /// Also write a Radiance RGBE file `DIR/STEM.hdr`.
    pub radiance_hdr: bool,
    /// Also write the merged mosaic as a linear DNG `DIR/STEM.dng` (camera raw brackets
    /// only; [`crate::raw::dng`]). It holds [`DNG_BYTES_PER_PIXEL`] more at its peak,
    /// beyond [`job_memory_bytes`].
    pub dng: bool,
    /// Renderings, one file each.
    pub looks: &'a [Look],
    /// Encoding of the renderings.
    pub format: Format,
    /// The display the renderings are encoded for.
    pub space: ColourSpace,
    /// EXIF carried into the renderings.
    pub exif: &'a SourceExif,
    /// Replace existing files or refuse.
    pub overwrite: Overwrite,
    /// The luminance calibration factor `c` of [`merge::exposure_scale`] (1: nominal).
    pub luminance_calibration: f64,
    /// Long edge, pixels, of a small sRGB copy of each rendering kept in memory
    /// ([`Developed::previews`]); `None` for none.
    pub preview_edge: Option<u32>,
    /// Also write `DIR/STEM.ghosts.png`, where deghosting left frames out
    /// ([`GhostMasks::least_kept`] as 8-bit grey; white everywhere when no frame was
    /// left out, or the bracket was not deghosted). Written after the other outputs, once
    /// their encoding buffers are freed; the map and its PNG take at most two bytes a
    /// pixel, which [`job_memory_bytes`] does not count.
    pub ghost_map: bool,
}

impl Prints<'_> {
    /// `DIR/STEM.exr`.
    pub fn exr_path(&self) -> PathBuf {
        self.dir.join(format!("{}.exr", self.stem))
    }

    /// `DIR/STEM.hdr`.
    fn hdr_path(&self) -> PathBuf {
        self.dir.join(format!("{}.hdr", self.stem))
    }

    /// `DIR/STEM.dng`.
    pub fn dng_path(&self) -> PathBuf {
        self.dir.join(format!("{}.dng", self.stem))
    }

    /// `DIR/STEM.ghosts.png`.
    pub fn ghost_map_path(&self) -> PathBuf {
        self.dir.join(format!("{}.ghosts.png", self.stem))
    }

    /// Every path this will write, in order (EXR, HDR, DNG, renderings).
    pub fn paths(&self) -> Vec<PathBuf> {
        let mut paths = Vec::new();
        if self.exr.is_some() {
            paths.push(self.exr_path());
        }
        if self.radiance_hdr {
            paths.push(self.hdr_path());
        }
        if self.dng {
            paths.push(self.dng_path());
        }
        for look in self.looks {
            paths.push(rendering::look_path(self.dir, self.stem, look, self.format));
        }
        if self.ghost_map {
            paths.push(self.ghost_map_path());
        }
        paths
    }
}

/// How the EXR header names a raw bracket's weighting (see `raw::mosaic`).
const RAW_WEIGHTING: &str = "noise-optimal (linear sensor: shot + read noise)";

/// What developing a bracket did.
#[derive(Debug)]
pub struct Developed {
    /// Files published, in the order of [`Prints::paths`].
    pub outputs: Vec<PathBuf>,
    /// The response used.
    pub response: ChosenResponse,
    /// Input indices sorted by exposure, darkest first.
    pub order: Vec<usize>,
    /// Longest over shortest exposure.
    pub ratio: f64,
    /// Samples clipped high and low in every frame.
    pub clipped: (u64, u64),
    /// Factor applied to the EXR's values (1 unless half overflow was scaled).
    pub exr_scale: f32,
    /// The scale of the radiance written (luminance anchored to EXIF, or relative).
    pub scale: merge::Scale,
    /// True when the merge was evaluated while the EXR was encoded and the looks were
    /// developed (no radiance buffer).
    pub fused: bool,
    /// Warnings (frame metadata, half overflow, weak fits).
    pub warnings: Vec<String>,
    /// Wall time per stage.
    pub stages: Stages,
    /// How the frames were aligned before the merge (`None` for a single frame).
    pub alignment: Option<Alignment>,
    /// The merged radiance of a raw bracket or frame (linear Rec. 709, on [`Self::scale`]),
    /// kept for measuring the body's JPEG curve against its companion JPEGs
    /// ([`crate::response::measured`]); `None` for other frames.
    pub raw_radiance: Option<RadianceMap>,
    /// What deghosting did, when it was asked for (see [`crate::deghost`]).
    pub deghost: Option<Deghosted>,
    /// Per look of [`Prints::looks`], in order, its small sRGB copy when
    /// [`Prints::preview_edge`] asked for them (empty otherwise).
    pub previews: Vec<rendering::Preview>,
    /// Where no frame exposed the scene well ([`merge::clip_map`], long edge
    /// [`CLIP_MAP_EDGE`]), when [`Prints::preview_edge`] asked for previews; `None` for a
    /// single frame and a camera raw bracket.
    pub clip_map: Option<merge::ClipMap>,
    /// Where deghosting left frames out ([`GhostMasks::least_kept_map`], long edge
    /// [`CLIP_MAP_EDGE`]), when [`Prints::preview_edge`] asked for previews and some frame
    /// was left out.
    pub left_out_map: Option<deghost::KeptMap>,
}

/// Long edge, pixels, of [`Developed::clip_map`]: an overlay on a preview, read at about
/// 16 frame pixels per map pixel.
pub const CLIP_MAP_EDGE: u32 = 400;

/// What deghosting did to a bracket.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Deghosted {
    /// Input index of the reference frame (the one that exposes most of the scene well).
    pub reference: usize,
    /// Per input frame, the share of pixels it was left out of (0 for the reference).
    pub left_out: Vec<f64>,
    /// The share of pixels at least one frame was left out of.
    pub share: f64,
}

impl Deghosted {
    fn of(ghosts: &GhostMasks) -> Deghosted {
        Deghosted {
            reference: ghosts.reference,
            left_out: ghosts.left_out.clone(),
            share: ghosts.share(),
        }
    }
}

/// The EXR header's account of deghosting: the reference frame and the shares left out.
fn describe_ghosts(ghosts: &Deghosted, frames: &[LoadedFrame]) -> String {
    let name = |i: usize| file_name(&frames[i].path);
    let frames: Vec<String> = ghosts
        .left_out
        .iter()
        .enumerate()
        .filter(|&(i, _)| i != ghosts.reference)
        .map(|(i, share)| format!("{} left out of {:.2} %", name(i), 100.0 * share))
        .collect();
    format!(
        "reference {}; {:.2} % of pixels merged without some frame ({})",
        name(ghosts.reference),
        100.0 * ghosts.share,
        frames.join(", ")
    )
}

/// The merged bracket: evaluated during encoding (an 8-bit pair, or any other bracket),
/// or held as a map.
enum Radiance<'a> {
    Pair(PairMerge<'a>),
    Banded(BracketMerge<'a>),
    Buffered(merge::Merged),
}

impl Radiance<'_> {
    /// Multiplies every value by `factor` (the absolute scale): the lazy merges fold it
    /// into their tables; a held map is multiplied unless it already is (`scaled`, a raw
    /// bracket's demosaicking applied it).
    fn scale_by(&mut self, factor: f64, scaled: bool) {
        match self {
            Radiance::Pair(p) => p.scale_by(factor as f32),
            Radiance::Banded(b) => b.scale_by(factor as f32),
            Radiance::Buffered(m) if factor != 1.0 && !scaled => {
                use rayon::prelude::*;
                let f = factor as f32;
                m.radiance.pixels_mut().par_iter_mut().for_each(|v| *v *= f);
            }
            Radiance::Buffered(_) => {}
        }
    }

    /// The frames' order and what was clipped in all of them.
    fn bracket(&self) -> &BracketOrder {
        match self {
            Radiance::Pair(p) => &p.bracket,
            Radiance::Banded(b) => &b.bracket,
            Radiance::Buffered(m) => &m.bracket,
        }
    }

    /// The map to encode, and its per-pixel confidence when it has one.
    fn source(&self) -> (&dyn RadianceSource, Option<&[f32]>) {
        match self {
            Radiance::Pair(pair) => (pair, None),
            Radiance::Banded(banded) => (banded, None),
            Radiance::Buffered(m) => (&m.radiance, m.confidence.as_deref()),
        }
    }
}

/// The merge's view of decoded `frames` with relative `exposures` (same order).
pub fn bracket<'a>(frames: &'a [LoadedFrame], exposures: &[f64]) -> Vec<BracketFrame<'a>> {
    frames
        .iter()
        .zip(exposures)
        .map(|(f, &exposure)| BracketFrame {
            source: &f.path,
            frame: &f.frame,
            exposure,
            camera: &f.metadata.camera,
        })
        .collect()
}

/// Merges `bracket` through `chosen`'s response, with `ghosts`' masks when any frame was
/// left out. Merges while the outputs are encoded and developed, unless a confidence
/// layer is asked for or a look spreads light between pixels (MTF, halation; it reads the
/// whole map). An unmasked 8-bit pair costs one table lookup a sample, so the EXR and
/// every look evaluate it again; any other bracket is evaluated so only for the EXR
/// alone, since each look would evaluate all its frames again.
fn merge_bracket<'a>(
    bracket: &[BracketFrame<'a>],
    chosen: &ChosenResponse,
    options: MergeOptions,
    prints: &Prints<'_>,
    ghosts: Option<&'a GhostMasks>,
) -> Result<Radiance<'a>, MergeError> {
    let masks = ghosts.filter(|g| !g.is_empty()).map(GhostMasks::masks);
    let masks = masks.unwrap_or_default();
    let lazy = !options.confidence && !prints.looks.iter().any(Look::has_optics);
    if lazy
        && masks.weights.is_empty()
        && let Some(pair) = PairMerge::new(bracket, &chosen.response, options.weighting)?
    {
        return Ok(Radiance::Pair(pair));
    }
    let response = &chosen.response;
    Ok(if lazy && prints.looks.is_empty() && prints.exr.is_some() {
        Radiance::Banded(BracketMerge::masked(
            bracket,
            response,
            options.weighting,
            &masks,
        )?)
    } else {
        Radiance::Buffered(merge::merge_masked(bracket, response, options, &masks)?)
    })
}

/// Develops a bracket of decoded `frames` with relative `exposures` (same order):
/// response under `policy`, merge, then the EXR and renderings of `prints`.
pub fn develop(
    frames: &[LoadedFrame],
    exposures: &[f64],
    ratio_source: RatioSource,
    policy: ResponsePolicy,
    options: MergeOptions,
    prints: &Prints<'_>,
) -> Result<Developed, DarkroomError> {
    // Longer than a step should be: the lazy merges borrow the aligned frames and the
    // ghost masks, which must live in this frame until the outputs are written, so the
    // merge and what follows it stay here (each step below it is a function of its own).
    let mut stages = Stages::new();
    let bracket = bracket(frames, exposures);
    // One frame is not a bracket (sizes, depths and cameras are checked by the merge).
    if bracket.len() < 2 {
        return Err(MergeError::TooFewFrames(bracket.len()).into());
    }
    if prints.dng {
        dng_needs_raw(frames)?;
    }
    // Anchor the values to the EXIF exposure (see `merge`'s "Absolute scale"); a raw
    // bracket's demosaicking applies the factor in its one pass.
    let exif: Vec<_> = frames.iter().map(|f| f.metadata.exposure).collect();
    let (scale, factor) = merge::exposure_scale(&exif, exposures, prints.luminance_calibration);
    #[cfg(feature = "raw")]
    let raw_merged = raw::merge(
        frames,
        exposures,
        factor,
        options.align,
        prints.dng,
        &mut stages,
    )?;
    #[cfg(not(feature = "raw"))]
    let raw_merged: Option<NoRaw> = None;
    let scaled = raw_merged.is_some();
    #[cfg(feature = "raw")]
    let mut dng = None;
    let mut weighting = options.weighting.name().to_string();
    let mut ghosts = None;
    // The moved frames resampled onto the reference grid; they outlive the merge.
    let warped: Vec<Option<Frame>>;
    let mut clip_map = None;
    let (chosen, merged, alignment) = match raw_merged {
        Some(raw) => {
            weighting = RAW_WEIGHTING.to_string();
            #[cfg(feature = "raw")]
            {
                dng = raw.dng;
            }
            (raw.chosen, Radiance::Buffered(raw.merged), raw.alignment)
        }
        None => {
            let chosen = choose_response(&bracket, ratio_source, policy, &mut stages)?;
            let alignment;
            (alignment, warped) =
                align_bracket(&bracket, &chosen.response, options.align, &mut stages);
            let bracket = aligned(&bracket, &warped);
            if options.deghost == Deghost::On {
                let t = Instant::now();
                let reference = alignment.reference;
                ghosts = Some(deghost::ghost_masks(&bracket, &chosen.response, reference));
                stages.push(("deghost", t.elapsed()));
            }
            let t = Instant::now();
            let merged = merge_bracket(&bracket, &chosen, options, prints, ghosts.as_ref())?;
            if prints.preview_edge.is_some() {
                clip_map =
                    merge::clip_map(&bracket, &chosen.response, options.weighting, CLIP_MAP_EDGE)
                        .ok();
            }
            stages.push(("merge", t.elapsed()));
            (chosen, merged, alignment)
        }
    };
    let mut merged = merged;
    merged.scale_by(factor, scaled);
    let deghosted = ghosts.as_ref().map(Deghosted::of);
    let (width, height) = (frames[0].frame.width(), frames[0].frame.height());
    let left_out_map = ghosts
        .as_ref()
        .filter(|_| prints.preview_edge.is_some())
        .and_then(|g| g.least_kept_map(width, height, CLIP_MAP_EDGE));
    let sorted = merged.bracket();
    let (order, ratio, clipped) = (
        sorted.order.clone(),
        sorted.ratio(),
        (sorted.clipped_high, sorted.clipped_low),
    );
    let provenance = Provenance {
        camera: frames[0].metadata.camera.clone(),
        captured_at: frames[order[0]].metadata.captured_at,
        frames: order
            .iter()
            .map(|&i| FrameRecord {
                name: file_name(&frames[i].path),
                exposure: frames[i].metadata.exposure,
                relative: exposures[i],
            })
            .collect(),
        response: chosen.summary.clone(),
        weighting,
        clipped,
        scale: scale.clone(),
        deghost: deghosted
            .as_ref()
            .filter(|g| g.share > 0.0)
            .map(|g| describe_ghosts(g, frames)),
        alignment: Some(alignment.describe(
            &frame_names(frames),
            frames[0].frame.width(),
            frames[0].frame.height(),
        )),
    };
    let mut warnings = bracket_warnings(frames, &chosen, &alignment, &scale);
    let (source, confidence) = merged.source();
    let fused = !matches!(merged, Radiance::Buffered(_));
    // Outputs are written concurrently below; a name already taken that may not be
    // replaced stops the bracket before any file is written, as it did in sequence.
    if prints.overwrite == Overwrite::Refuse
        && let Some(path) = prints.paths().into_iter().find(|p| p.exists())
    {
        return Err(PublishError::Exists { path }.into());
    }
    #[cfg(not(feature = "raw"))]
    let dng: Option<NoRaw> = None;
    let printed = print_all(source, confidence, &provenance, dng.as_ref(), prints)?;
    let raw_radiance = match merged {
        Radiance::Buffered(m) if chosen.source == Source::Raw => Some(m.radiance),
        _ => None,
    };
    warnings.extend(printed.warnings);
    stages.extend(printed.stages);
    let mut outputs = printed.outputs;
    if prints.ghost_map {
        let t = Instant::now();
        outputs.push(write_ghost_map(ghosts.as_ref(), &frames[0].frame, prints)?);
        stages.push(("ghosts", t.elapsed()));
    }
    Ok(Developed {
        outputs,
        response: chosen,
        order,
        ratio,
        clipped,
        exr_scale: printed.exr_scale,
        scale,
        fused,
        warnings,
        stages,
        alignment: Some(alignment),
        raw_radiance,
        deghost: deghosted,
        previews: printed.previews,
        clip_map,
        left_out_map,
    })
}

/// Each frame's file name.
fn frame_names(frames: &[LoadedFrame]) -> Vec<String> {
    frames.iter().map(|f| file_name(&f.path)).collect()
}

/// What the developing of `frames` warns of: each frame's EXIF warnings (naming the
/// file), the response's and the alignment's notes, and a relative `scale`.
fn bracket_warnings(
    frames: &[LoadedFrame],
    chosen: &ChosenResponse,
    alignment: &Alignment,
    scale: &merge::Scale,
) -> Vec<String> {
    let names = frame_names(frames);
    let mut warnings: Vec<String> = frames
        .iter()
        .flat_map(|f| {
            f.metadata
                .warnings
                .iter()
                .map(move |w| format!("{}: {w}", f.path.display()))
        })
        .chain(chosen.notes.iter().cloned())
        .chain(alignment_notes(alignment, &names, &frames[0].frame))
        .collect();
    if let merge::Scale::Relative { reason } = scale {
        warnings.push(format!(
            "radiance on the relative scale (1.0 = B=1 in the longest frame), not luminance: {reason}"
        ));
    }
    warnings
}

/// The files [`print_all`] published, in the order of [`Prints::paths`], and what it
/// measured.
struct Printed {
    /// Files published.
    outputs: Vec<PathBuf>,
    /// The EXR's overflow factor (1 unless half overflow was scaled).
    exr_scale: f32,
    /// The EXR writer's warnings.
    warnings: Vec<String>,
    /// Per look, its small sRGB copy (when `prints.preview_edge` asks for them).
    previews: Vec<Preview>,
    /// Wall time per output stage.
    stages: Stages,
}

/// Writes the radiance files (EXR, `.hdr`, and the DNG when there is one) and, on a
/// thread of their own beside them, the renderings: the PIZ encoder and each JPEG
/// encoder are partly single-threaded, so together they keep both cores busy. Their
/// stage times overlap.
fn print_all(
    source: &dyn RadianceSource,
    confidence: Option<&[f32]>,
    provenance: &Provenance,
    dng: Option<&DngOf>,
    prints: &Prints<'_>,
) -> Result<Printed, DarkroomError> {
    let (radiance, looks) = std::thread::scope(|scope| {
        let looks = (!prints.looks.is_empty()).then(|| {
            scope.spawn(move || {
                let mut stages = Stages::new();
                print_looks(source, prints, &mut stages).map(|rendered| (rendered, stages))
            })
        });
        let radiance = write_radiance_files(source, confidence, provenance, prints);
        #[cfg(feature = "raw")]
        let radiance = radiance.and_then(|mut written| {
            if let Some(dng) = dng {
                let t = Instant::now();
                written.outputs.push(write_dng(dng, prints)?);
                written.stages.push(("dng", t.elapsed()));
            }
            Ok(written)
        });
        #[cfg(not(feature = "raw"))]
        let _ = dng;
        let looks = looks.map(|handle| {
            handle
                .join()
                .unwrap_or_else(|panic| std::panic::resume_unwind(panic))
        });
        (radiance, looks)
    });
    let mut printed = radiance?;
    if let Some(looks) = looks {
        let (rendered, look_stages) = looks?;
        printed.outputs.extend(rendered.paths);
        printed.previews = rendered.previews;
        printed.stages.extend(look_stages);
    }
    Ok(printed)
}

/// Aligns the bracket's frames onto its reference frame (stage `align`): the alignment
/// and each frame resampled onto the reference grid (`None` for a frame merged as it
/// is). The response only makes the frames comparable; the calibration that chose it
/// read the frames unaligned (histograms need no registration).
fn align_bracket(
    bracket: &[BracketFrame<'_>],
    response: &InverseResponse,
    mode: AlignMode,
    stages: &mut Stages,
) -> (Alignment, Vec<Option<Frame>>) {
    let t = Instant::now();
    let frames: Vec<AlignFrame<'_>> = bracket
        .iter()
        .map(|f| AlignFrame {
            frame: f.frame,
            exposure: f.exposure,
        })
        .collect();
    let alignment = align::align(&frames, response, mode);
    let warped = align::warp_frames(&frames, &alignment);
    if mode != AlignMode::Off {
        stages.push(("align", t.elapsed()));
    }
    (alignment, warped)
}

/// The bracket with each moved frame replaced by its resampled copy.
fn aligned<'a>(bracket: &[BracketFrame<'a>], warped: &'a [Option<Frame>]) -> Vec<BracketFrame<'a>> {
    bracket
        .iter()
        .zip(warped)
        .map(|(f, w)| BracketFrame {
            frame: w.as_ref().unwrap_or(f.frame),
            ..*f
        })
        .collect()
}

/// What the report says of an alignment: each fallback, and the frames moved.
fn alignment_notes(alignment: &Alignment, names: &[String], frame: &Frame) -> Vec<String> {
    let mut notes = alignment.notes(names);
    let moved: Vec<String> = alignment
        .frames
        .iter()
        .zip(names)
        .filter(|(f, _)| f.motion.is_some())
        .map(|(f, name)| {
            let ((dx, dy), angle) = f.shift_and_rotation(frame.width(), frame.height());
            format!("{name} by ({dx:.2}, {dy:.2}) px and {angle:.2} deg")
        })
        .collect();
    if !moved.is_empty() {
        notes.push(format!(
            "frames moved between exposures, aligned onto {}: {}",
            names.get(alignment.reference).map_or("?", String::as_str),
            moved.join(", ")
        ));
    }
    notes
}

/// The EXR and Radiance HDR files of `prints`: paths written, the EXR's scale, its
/// warnings and the stages (`encode`, `write`, `hdr`).
fn write_radiance_files(
    source: &dyn RadianceSource,
    confidence: Option<&[f32]>,
    provenance: &Provenance,
    prints: &Prints<'_>,
) -> Result<Printed, DarkroomError> {
    let mut stages = Stages::new();
    let mut outputs = Vec::new();
    let mut exr_scale = 1.0;
    let mut warnings = Vec::new();
    if let Some(exr) = prints.exr {
        let written = write_radiance(source, confidence, provenance, exr, prints, &mut stages)?;
        exr_scale = written.scale;
        warnings.extend(written.warnings);
        outputs.push(prints.exr_path());
    }
    if prints.radiance_hdr {
        let t = Instant::now();
        let path = prints.hdr_path();
        let mut hdr = Vec::new();
        hdr_output::encode_radiance_hdr(&mut hdr, source).map_err(|source| {
            OutputError::Encode {
                path: path.clone(),
                source,
            }
        })?;
        atomic::publish(&path, &hdr, prints.overwrite)?;
        outputs.push(path);
        stages.push(("hdr", t.elapsed()));
    }
    Ok(Printed {
        outputs,
        exr_scale,
        warnings,
        previews: Vec::new(),
        stages,
    })
}

/// Publishes [`Prints::ghost_map_path`]: `ghosts`' least kept weight per pixel of a
/// frame the size of `frame` (white without masks), as an 8-bit grey PNG.
fn write_ghost_map(
    ghosts: Option<&GhostMasks>,
    frame: &Frame,
    prints: &Prints<'_>,
) -> Result<PathBuf, DarkroomError> {
    let path = prints.ghost_map_path();
    let (width, height) = (frame.width(), frame.height());
    let pixels = width as usize * height as usize;
    let least = ghosts.map_or_else(|| vec![u8::MAX; pixels], |g| g.least_kept(pixels));
    let mut bytes = Vec::new();
    grey_png(&mut bytes, width, height, &least).map_err(|source| DarkroomError::GhostMap {
        path: path.clone(),
        source,
    })?;
    atomic::publish(&path, &bytes, prints.overwrite)?;
    Ok(path)
}

/// An 8-bit greyscale PNG of `samples`, row by row.
fn grey_png(
    out: &mut Vec<u8>,
    width: u32,
    height: u32,
    samples: &[u8],
) -> Result<(), png::EncodingError> {
    let mut encoder = png::Encoder::new(out, width, height);
    encoder.set_color(png::ColorType::Grayscale);
    encoder.set_depth(png::BitDepth::Eight);
    let mut writer = encoder.write_header()?;
    writer.write_image_data(samples)?;
    writer.finish()
}

/// Refuses a DNG for `frames` unless every one is camera raw.
fn dng_needs_raw(frames: &[LoadedFrame]) -> Result<(), DarkroomError> {
    #[cfg(feature = "raw")]
    let not_raw = frames.iter().find(|f| f.raw.is_none()).map(|f| {
        let kind = f.path.extension().map_or_else(
            || "no file extension".to_string(),
            |e| e.to_string_lossy().to_uppercase(),
        );
        (f, NotRaw::Format(kind))
    });
    #[cfg(not(feature = "raw"))]
    let not_raw = frames.first().map(|f| (f, NotRaw::NoRawSupport));
    match not_raw {
        Some((f, reason)) => Err(DarkroomError::DngNeedsRaw {
            path: f.path.clone(),
            reason,
        }),
        None => Ok(()),
    }
}

/// Encodes the merged mosaic as DNG and publishes it as `DIR/STEM.dng`.
#[cfg(feature = "raw")]
fn write_dng(dng: &raw::DngSource, prints: &Prints<'_>) -> Result<PathBuf, DarkroomError> {
    let path = prints.dng_path();
    let bytes = dng.encode().map_err(|source| DarkroomError::Dng {
        path: path.clone(),
        source,
    })?;
    atomic::publish(&path, &bytes, prints.overwrite)?;
    Ok(path)
}

/// Encodes the EXR in memory (stage `encode`), then publishes it (stage `write`), so the
/// two costs are told apart.
fn write_radiance(
    source: &dyn RadianceSource,
    confidence: Option<&[f32]>,
    provenance: &Provenance,
    options: ExrOptions,
    prints: &Prints<'_>,
    stages: &mut Stages,
) -> Result<Written, DarkroomError> {
    let t = Instant::now();
    // Room for the samples uncompressed (an upper bound for a compressed file, which
    // stores a block raw when compression does not shrink it, and what the job's memory
    // budget already counts), so the buffer is not regrown and copied while it fills;
    // pages are only taken as they are written.
    let planes = source.channels() + usize::from(confidence.is_some());
    let bytes = match options.sample {
        hdr_output::SampleFormat::Half => 2,
        hdr_output::SampleFormat::Float => 4,
    };
    let samples = source.width() as usize * source.height() as usize * planes;
    let mut exr = Cursor::new(Vec::with_capacity(samples * bytes + (1 << 16)));
    let path = prints.exr_path();
    let written = hdr_output::encode_exr(&mut exr, source, confidence, provenance, options)
        .map_err(|source| OutputError::Encode {
            path: path.clone(),
            source,
        })?;
    stages.push(("encode", t.elapsed()));
    let t = Instant::now();
    atomic::publish(&path, exr.get_ref(), prints.overwrite)?;
    stages.push(("write", t.elapsed()));
    Ok(written)
}

/// Renders `map` in every look of `prints` (stage `render`), with their small copies
/// when `prints` asks for them.
fn print_looks(
    map: &dyn RadianceSource,
    prints: &Prints<'_>,
    stages: &mut Stages,
) -> Result<rendering::Rendered, DarkroomError> {
    if prints.looks.is_empty() {
        return Ok(rendering::Rendered::default());
    }
    let t = Instant::now();
    let rendered = rendering::render_previewed(
        map,
        prints.looks,
        &Outputs {
            dir: prints.dir,
            stem: prints.stem,
            format: prints.format,
            space: prints.space,
            overwrite: prints.overwrite,
            exif: prints.exif,
        },
        prints.preview_edge,
    )?;
    stages.push(("render", t.elapsed()));
    Ok(rendered)
}

/// An upper bound on the memory one bracket's development holds at its peak, in bytes,
/// for `frames` decoded frames of `width × height × channels` samples of
/// `bytes_per_sample` bytes (1 for 8-bit, 2 for 16-bit) and `looks` renderings. With
/// `P = width·height` and `S = P·channels`:
///
/// `frames·S·bytes_per_sample` (the decoded frames, held as codes; the merge makes no
/// per-frame float buffer) `+ (frames − 1)·S·bytes_per_sample` (each frame but the
/// reference resampled onto the reference grid when alignment moves it,
/// [`crate::align`]; its estimation pyramids, about 10 MB a frame by count (at most 300 000
/// finest blocks of 18 bytes over the levels, and 9 bytes a block kept for comparing where
/// both clip), and the two more of such a pair, and a raw frame's filtered tile image and
/// CFA lattices (about 2.25 bytes a pixel), are freed before the resampled frames exist)
/// `+ (frames −
/// 1)·P` (the deghosting masks, one byte per pixel of each frame but the reference, held
/// through the merge, [`crate::deghost`]; the comparison's own grids, under `P` bytes,
/// are freed before the merge's buffers exist) `+` [`working_memory_bytes`]: with looks, `4·S` (the
/// radiance map, `f32`; an 8-bit pair whose looks have no optics needs none, so its
/// peak stays `4·S` under the bound) `+ 2·S` (the EXR encoded in memory before it is
/// published, at most its uncompressed half-float size) `+ 8·P` (the largest working set of one look:
/// a tone map's luminances and percentile bucket, or the optics' half-resolution pyramid
/// of three layers; looks render one after another, beside the EXR, and stream to their
/// encoder) `+ 18·64·width` (the JPEG bands in flight); without looks (the EXR alone, no
/// confidence layer) the merge runs inside the encoder and only the `2·S` of the EXR is
/// added.
///
/// So each frame adds twice its own decoded size and a byte per pixel: a 24 MP 8-bit RGB
/// pair with two looks is bounded by 871 MB, a 5-frame 24 MP bracket written only as EXR
/// by 888 MB, a 7-frame 45 MP (8256 × 5504) bracket by 3.24 GB with looks and 2.32 GB
/// without.
pub fn job_memory_bytes(
    width: u32,
    height: u32,
    frames: usize,
    channels: usize,
    bytes_per_sample: usize,
    looks: usize,
) -> u64 {
    let samples = u64::from(width) * u64::from(height) * channels as u64;
    let frame = samples * bytes_per_sample as u64;
    let pixels = u64::from(width) * u64::from(height);
    let others = frames.saturating_sub(1) as u64;
    frames as u64 * frame
        + others * (frame + pixels)
        + working_memory_bytes(width, height, channels, looks)
}

/// Bytes a pixel that writing a DNG ([`Prints::dng`]) holds beyond [`job_memory_bytes`]:
/// the merged mosaic, its copy scaled for the file and the file encoded in memory, 4
/// bytes a pixel each.
pub const DNG_BYTES_PER_PIXEL: u64 = 12;

/// The part of [`job_memory_bytes`] that does not grow with the frames, for a
/// `width × height × channels` map: with looks, the radiance map, the EXR in memory, one
/// look's working set and the JPEG bands, `4·S + 2·S + 8·P + 18·64·width`; without looks
/// (the EXR alone, merged while it is encoded, no confidence layer), the EXR only, `2·S`.
/// The PIZ blocks in flight (at most `5·T` blocks of 32 lines, `320·T·width·channels`
/// bytes on `T` threads, 12 MB for a 24 MP map on 2 threads) are within the EXR's `2·S`:
/// PIZ files of photographs are about `0.6·S`.
pub fn working_memory_bytes(width: u32, height: u32, channels: usize, looks: usize) -> u64 {
    let pixels = u64::from(width) * u64::from(height);
    let samples = pixels * channels as u64;
    let exr = 2 * samples;
    if looks == 0 {
        return exr;
    }
    let map = 4 * samples;
    let look = 8 * pixels;
    let bands = 18 * 64 * u64::from(width);
    map + exr + look + bands
}

/// One frame's radiance estimate, `E = g(B)` per sample: the frame's own range, no
/// extension (scale: a sample at the top code reads 1.0, as the longest frame of a
/// bracket does).
fn linearise(loaded: &LoadedFrame, response: &InverseResponse) -> Result<RadianceMap, MergeError> {
    let frame = &loaded.frame;
    let channels = frame.channels();
    if response.channels() != channels {
        return Err(MergeError::ChannelMismatch {
            path: loaded.path.clone(),
            frame: channels,
            response: response.channels(),
        });
    }
    let levels = frame.bit_depth().levels();
    let tables: Vec<Vec<f32>> = (0..channels).map(|c| response.table(c, levels)).collect();
    let pixels = match frame.samples() {
        Samples::Eight(v) => v
            .iter()
            .enumerate()
            .map(|(i, &k)| tables[i % channels][usize::from(k)])
            .collect(),
        Samples::Sixteen(v) => v
            .iter()
            .enumerate()
            .map(|(i, &k)| tables[i % channels][usize::from(k)])
            .collect(),
    };
    Ok(
        RadianceMap::new(frame.width(), frame.height(), channels, pixels)
            .expect("one value per sample of a valid frame"),
    )
}

/// Renders a single frame (no bracket) through `response` in every look of `prints`;
/// the EXR is not written (it would hold no more range than the frame).
pub fn develop_single(
    frame: &LoadedFrame,
    response: GivenResponse,
    prints: &Prints<'_>,
) -> Result<Developed, DarkroomError> {
    let mut stages = Stages::new();
    #[cfg(feature = "raw")]
    let raw_map = raw::merge(
        std::slice::from_ref(frame),
        &[1.0],
        1.0,
        AlignMode::Off,
        false,
        &mut stages,
    )?;
    #[cfg(not(feature = "raw"))]
    let raw_map: Option<NoRaw> = None;
    let is_raw = raw_map.is_some();
    let (map, response) = match raw_map {
        Some(raw) => (raw.merged.radiance, raw.chosen),
        None => {
            let t = Instant::now();
            let map = linearise(frame, &response.response)?;
            stages.push(("linearise", t.elapsed()));
            (map, use_given(response, Vec::new(), None))
        }
    };
    let rendered = print_looks(&map, prints, &mut stages)?;
    let raw_radiance = is_raw.then_some(map);
    Ok(Developed {
        outputs: rendered.paths,
        response,
        order: vec![0],
        ratio: 1.0,
        clipped: (0, 0),
        exr_scale: 1.0,
        scale: merge::Scale::Relative {
            reason: "a single frame is rendered, not written as radiance".to_string(),
        },
        fused: false,
        warnings: frame
            .metadata
            .warnings
            .iter()
            .map(|w| format!("{}: {w}", frame.path.display()))
            .collect(),
        stages,
        alignment: None,
        raw_radiance,
        deghost: None,
        previews: rendered.previews,
        clip_map: None,
        left_out_map: None,
    })
}

#[cfg(test)]
mod tests;
