//! The darkroom: decoded frames in, published files out. One bracket goes through the
//! report's three steps — response ([`crate::response`]), radiance merge
//! ([`crate::merge`]), display renderings ([`crate::rendering`]) — and the radiance map is
//! written as OpenEXR ([`crate::hdr_output`]). `filmback merge` and the daemon both
//! develop through here, so a bracket dropped in the ingest folder and the same bracket
//! given on the command line come out identical.
//!
//! # Which response
//!
//! [`ResponsePolicy::Fit`] calibrates from the bracket itself: with more than two
//! distinct exposures from every frame jointly ([`response::calibrate_bracket`]: the tone
//! pairs of every two frames adjacent in exposure, one curve per channel), with two from
//! that pair; about three million
//! pixels a frame (stride `⌊√(pixels/3·10⁶)⌋`), degree chosen by the data. The fit's
//! confidence is the smallest of its channels' (a channel that borrowed another's curve
//! has confidence 0, so a bracket with one saturated channel never counts as good). When
//! the fit fails or its confidence is below the policy's `min_confidence`, the fallback
//! (the camera's cached curve, else the sRGB inverse) is used instead and a note says
//! why — unless the bracket contradicts the fallback: if the fallback explains the tone
//! pairs worse than the weak fit by more than 0.05 stop RMS (`log₂(g(τ)/(γ·g(b)))`), the
//! fit is kept, with a note. [`ResponsePolicy::Use`] takes a curve as given (a response file, the cache, sRGB).
//!
//! # Memory
//!
//! Two 8-bit frames written only as EXR are merged while the file is encoded
//! ([`PairMerge`]): no radiance buffer exists. With renderings (or a confidence layer, or
//! more frames) the map is built once (`width × height × channels × 4` bytes) beside the
//! decoded frames the caller holds, and the EXR and every rendering read that one map.

use std::io::Cursor;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use crate::atomic::{self, Overwrite, PublishError};
use crate::frame::{LoadedFrame, Samples};
use crate::hdr_output::{
    self, ExrOptions, FrameRecord, OutputError, Provenance, RadianceSource, Written,
};
use crate::histogram::Histogram;
use crate::merge::{self, BracketFrame, MergeError, MergeOptions, PairMerge};
use crate::radiance::RadianceMap;
use crate::rendering::{self, Format, Look, Outputs, RenderingError, SourceExif};
use crate::response::{
    self, Calibration, CalibrationError, Degree, InverseResponse, Ratio, RatioSource,
};

/// Pixels per frame the calibration histograms look at (a speed knob measured in
/// `benches/calibrate_speed.rs`: beyond a few million pixels the histograms of a
/// 256-level frame no longer change the fit).
pub const CALIBRATION_PIXELS: f64 = 3e6;

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
    /// The OpenEXR or Radiance HDR file could not be encoded or published.
    #[error(transparent)]
    Output(#[from] OutputError),
    /// A rendering could not be made or published.
    #[error(transparent)]
    Rendering(#[from] RenderingError),
    /// A file could not be published.
    #[error(transparent)]
    Publish(#[from] PublishError),
}

impl DarkroomError {
    /// The output file a failure to write concerns, if it is one (full disk, permissions,
    /// an existing file): such failures are worth retrying; the others are not.
    pub fn output_path(&self) -> Option<&Path> {
        let publish = match self {
            DarkroomError::Publish(p)
            | DarkroomError::Output(OutputError::Publish(p))
            | DarkroomError::Rendering(RenderingError::Publish(p)) => p,
            DarkroomError::Rendering(RenderingError::Encode { path, .. }) => return Some(path),
            _ => return None,
        };
        Some(match publish {
            PublishError::Exists { path }
            | PublishError::Io { path, .. }
            | PublishError::Content { path, .. } => path,
        })
    }
}

/// Where a response came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Source {
    /// Fitted from this bracket's histograms.
    Fitted,
    /// The camera body's cached curve.
    Cached,
    /// A response file.
    File,
    /// The sRGB inverse (IEC 61966-2-1), for lack of anything better.
    Standard,
}

impl std::fmt::Display for Source {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Source::Fitted => "fitted",
            Source::Cached => "cached",
            Source::File => "file",
            Source::Standard => "standard (sRGB)",
        })
    }
}

/// A curve to use as it is, with where it came from.
#[derive(Debug, Clone)]
pub struct GivenResponse {
    /// The curve.
    pub response: InverseResponse,
    /// Its origin.
    pub source: Source,
    /// One line for logs and the EXR header, e.g. `cached (12 brackets)`.
    pub label: String,
}

impl GivenResponse {
    /// The sRGB inverse for `channels` channels.
    pub fn standard(channels: usize) -> GivenResponse {
        GivenResponse {
            response: InverseResponse::srgb(channels, 1024),
            source: Source::Standard,
            label: "sRGB inverse (IEC 61966-2-1), default".to_string(),
        }
    }
}

/// How the response is chosen (see the module docs).
#[derive(Debug, Clone)]
pub enum ResponsePolicy {
    /// Calibrate from the bracket; below `min_confidence`, or when the fit fails, use
    /// `fallback` (an error when there is none).
    Fit {
        /// Used when the fit is weak or impossible.
        fallback: Option<GivenResponse>,
        /// The confidence a fit needs to be used.
        min_confidence: f64,
    },
    /// Use this curve.
    Use(GivenResponse),
}

/// The response a bracket was merged with.
#[derive(Debug, Clone)]
pub struct ChosenResponse {
    /// The curve used.
    pub response: InverseResponse,
    /// Its origin.
    pub source: Source,
    /// One line for logs and the EXR header.
    pub summary: String,
    /// Machine-readable detail (model, degrees, covered ranges, confidences).
    pub report: serde_json::Value,
    /// This bracket's own fit and its confidence, when one was made, used or not (the
    /// daemon folds good ones into the camera's cache).
    pub fit: Option<(InverseResponse, f64)>,
    /// Why a fit was not used, etc.
    pub notes: Vec<String>,
}

/// Wall time per stage, in the order they ran.
pub type Stages = Vec<(&'static str, Duration)>;

fn file_name(path: &Path) -> String {
    path.file_name().map_or_else(
        || path.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    )
}

/// Chooses the response for `bracket` under `policy`; `ratio_source` says where the
/// exposures came from. Histogram and fit times are appended to `stages`.
pub fn choose_response(
    bracket: &[BracketFrame<'_>],
    ratio_source: RatioSource,
    policy: ResponsePolicy,
    stages: &mut Stages,
) -> Result<ChosenResponse, DarkroomError> {
    let (fallback, min_confidence) = match policy {
        ResponsePolicy::Use(given) => return Ok(use_given(given, Vec::new(), None)),
        ResponsePolicy::Fit {
            fallback,
            min_confidence,
        } => (fallback, min_confidence),
    };
    let mut order: Vec<usize> = (0..bracket.len()).collect();
    order.sort_by(|&a, &b| bracket[a].exposure.total_cmp(&bracket[b].exposure));
    // The adjacent pair nearest the middle whose exposures differ (duplicates, as in
    // 1/60, 1/60, 1/15, tell the fit nothing); if none differ, the middle pair, and the
    // fit says why it cannot work.
    let mid = (order.len() / 2).max(1);
    let distinct = |k: &usize| {
        let (a, b) = (&bracket[order[k - 1]], &bracket[order[*k]]);
        b.exposure > a.exposure * 1.01
    };
    let k = (1..order.len())
        .filter(distinct)
        .min_by_key(|k| k.abs_diff(mid))
        .unwrap_or(mid);
    let (dark, bright) = (&bracket[order[k - 1]], &bracket[order[k]]);
    let t = Instant::now();
    let stride = ((dark.frame.pixel_count() as f64 / CALIBRATION_PIXELS)
        .sqrt()
        .floor() as usize)
        .max(1);
    // More than two distinct exposures: every frame, every pair, one curve per channel.
    let distinct = (1..order.len()).filter(distinct).count() + 1;
    let joint = distinct > 2;
    let (fitted, ratio, pair, sources) = if joint {
        use rayon::prelude::*;
        let histograms: Vec<Histogram> = bracket
            .par_iter()
            .map(|f| Histogram::of_frame(f.frame, stride))
            .collect();
        stages.push(("histogram", t.elapsed()));
        let t = Instant::now();
        let frames: Vec<(&Histogram, f64)> = histograms
            .iter()
            .zip(bracket)
            .map(|(h, f)| (h, f.exposure))
            .collect();
        let fitted = response::calibrate_bracket(&frames, ratio_source, Degree::Auto);
        stages.push(("fit", t.elapsed()));
        let ratio = bracket[order[order.len() - 1]].exposure / bracket[order[0]].exposure;
        let sources: Vec<&Path> = order.iter().map(|&i| bracket[i].source).collect();
        let pair = format!("all {} frames", bracket.len());
        (fitted, ratio, pair, sources)
    } else {
        let (h_dark, h_bright) = rayon::join(
            || Histogram::of_frame(dark.frame, stride),
            || Histogram::of_frame(bright.frame, stride),
        );
        stages.push(("histogram", t.elapsed()));
        let t = Instant::now();
        let ratio = bright.exposure / dark.exposure;
        let fitted = response::calibrate(
            &h_dark,
            &h_bright,
            Ratio::Known(ratio, ratio_source),
            Degree::Auto,
        );
        stages.push(("fit", t.elapsed()));
        let pair = format!(
            "{} and {}",
            file_name(dark.source),
            file_name(bright.source)
        );
        (fitted, ratio, pair, vec![dark.source, bright.source])
    };
    let (calibration, fallback) = match (fitted, fallback) {
        (Ok(c), fallback) => (c, fallback),
        (Err(source), None) => {
            return Err(DarkroomError::Calibrate {
                dark: dark.source.to_path_buf(),
                bright: bright.source.to_path_buf(),
                source,
            });
        }
        (Err(e), Some(given)) => {
            let note = format!(
                "no response could be fitted from {pair} ({e}); used the {}",
                given.label
            );
            return Ok(use_given(given, vec![note], None));
        }
    };
    let confidence = calibration
        .channels
        .iter()
        .map(|c| c.fit.confidence)
        .fold(f64::INFINITY, f64::min)
        .clamp(0.0, 1.0);
    let fit = Some((calibration.response.clone(), confidence));
    let report = serde_json::json!({
        "source": "fitted",
        "frames": sources.iter().map(|p| p.display().to_string()).collect::<Vec<_>>(),
        "ratio": ratio,
        "ratio_source": ratio_source.as_str(),
        "confidence": confidence,
        "channels": calibration.channels.iter().map(|c| serde_json::json!({
            "name": c.name,
            "model": c.fit.model(),
            "degree": c.fit.degree,
            "effective_parameters": c.fit.effective_parameters,
            "covered": [c.fit.covered.0, c.fit.covered.1],
            "residual_rms_stops": c.fit.residual_rms,
            "confidence": c.fit.confidence,
            "borrowed_from": c.borrowed_from,
        })).collect::<Vec<_>>(),
    });
    let mut notes = Vec::new();
    if confidence < min_confidence
        && let Some(given) = fallback
    {
        // A fallback is only better than a weak fit if the bracket does not contradict it.
        let fit_misfit = misfit(&calibration, &calibration.response);
        let given_misfit = misfit(&calibration, &given.response);
        if given_misfit <= fit_misfit + CONTRADICTION_STOPS {
            let note = format!(
                "the fit from {pair} has confidence {confidence:.2} < {min_confidence:.2}; used the {}",
                given.label
            );
            let mut chosen = use_given(given, vec![note], fit);
            chosen.report["rejected_fit"] = report;
            return Ok(chosen);
        }
        notes.push(format!(
            "the fit from {pair} has confidence {confidence:.2} < {min_confidence:.2}, but the {} \
             contradicts this bracket ({given_misfit:.3} stops RMS against the fit's \
             {fit_misfit:.3}); used the fit",
            given.label
        ));
    }
    let sizes: Vec<String> = calibration
        .channels
        .iter()
        .map(|c| format!("{} {}", c.name, c.fit.size()))
        .collect();
    let family = calibration
        .channels
        .iter()
        .find(|c| c.borrowed_from.is_none())
        .map_or_else(String::new, |c| c.fit.family());
    if confidence < 0.5 {
        notes.push(format!(
            "low-confidence response fit ({confidence:.2}) from {pair}: check the result or give a response file"
        ));
    }
    Ok(ChosenResponse {
        response: calibration.response,
        source: Source::Fitted,
        summary: format!(
            "calibrated from {pair} (ratio {ratio:.4}, {}): {family}; {}; confidence {confidence:.2}",
            ratio_source.as_str(),
            sizes.join("; ")
        ),
        report,
        fit,
        notes,
    })
}

/// How much worse (RMS, stops) a fallback may explain the bracket's tone pairs than the
/// bracket's own fit before it counts as contradicted. A ripple the two exposures cannot
/// resolve costs a few hundredths of a stop; a wrong curve family (sRGB for a film
/// shoulder) costs tenths.
const CONTRADICTION_STOPS: f64 = 0.05;

/// RMS over the calibration's tone pairs of `log₂(g(τ(b)) / (γ·g(b)))`, stops, each pair
/// at its own ratio `γ`: how far `g` is from explaining the frames' histograms. Pairs
/// where `g` is 0 are skipped; no pairs gives 0.
fn misfit(calibration: &Calibration, g: &InverseResponse) -> f64 {
    let (mut sum, mut n) = (0.0, 0usize);
    for (c, channel) in calibration.channels.iter().enumerate() {
        let c = c.min(g.channels().saturating_sub(1));
        for (p, log_ratio) in channel.pairs.iter().zip(&channel.log_ratios) {
            let (lo, hi) = (g.eval(c, p.dark), g.eval(c, p.bright));
            if lo > 0.0 && hi > 0.0 {
                sum += ((hi / lo).ln() - log_ratio).powi(2) / std::f64::consts::LN_2.powi(2);
                n += 1;
            }
        }
    }
    if n == 0 { 0.0 } else { (sum / n as f64).sqrt() }
}

fn use_given(
    given: GivenResponse,
    notes: Vec<String>,
    fit: Option<(InverseResponse, f64)>,
) -> ChosenResponse {
    ChosenResponse {
        report: serde_json::json!({ "source": given.source, "model": given.label }),
        summary: given.label,
        response: given.response,
        source: given.source,
        fit,
        notes,
    }
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
    /// Renderings, one file each.
    pub looks: &'a [Look],
    /// Encoding of the renderings.
    pub format: Format,
    /// EXIF carried into the renderings.
    pub exif: &'a SourceExif,
    /// Replace existing files or refuse.
    pub overwrite: Overwrite,
}

impl Prints<'_> {
    /// `DIR/STEM.exr`.
    pub fn exr_path(&self) -> PathBuf {
        self.dir.join(format!("{}.exr", self.stem))
    }

    /// `DIR/STEM.hdr`.
    pub fn hdr_path(&self) -> PathBuf {
        self.dir.join(format!("{}.hdr", self.stem))
    }

    /// Every path this will write, in order (EXR, HDR, renderings).
    pub fn paths(&self) -> Vec<PathBuf> {
        let mut paths = Vec::new();
        if self.exr.is_some() {
            paths.push(self.exr_path());
        }
        if self.radiance_hdr {
            paths.push(self.hdr_path());
        }
        for look in self.looks {
            paths.push(rendering::look_path(self.dir, self.stem, look, self.format));
        }
        paths
    }
}

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
    /// True when the merge ran inside the EXR encoder (no radiance buffer).
    pub fused: bool,
    /// Warnings (frame metadata, half overflow, weak fits).
    pub warnings: Vec<String>,
    /// Wall time per stage.
    pub stages: Stages,
}

/// The merged bracket: evaluated during encoding, or held as a map.
enum Radiance<'a> {
    Fused(PairMerge<'a>),
    Buffered(merge::Merged),
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
    let mut stages = Stages::new();
    let bracket = bracket(frames, exposures);
    // One frame is not a bracket (sizes, depths and cameras are checked by the merge).
    if bracket.len() < 2 {
        return Err(MergeError::TooFewFrames(bracket.len()).into());
    }
    let chosen = choose_response(&bracket, ratio_source, policy, &mut stages)?;
    let t = Instant::now();
    let fused = if options.confidence || !prints.looks.is_empty() || prints.exr.is_none() {
        None
    } else {
        PairMerge::new(&bracket, &chosen.response, options.weighting)?
    };
    let merged = match fused {
        Some(pair) => Radiance::Fused(pair),
        None => Radiance::Buffered(merge::merge(&bracket, &chosen.response, options)?),
    };
    stages.push(("merge", t.elapsed()));
    let (order, ratio, clipped) = match &merged {
        Radiance::Fused(p) => (p.order.clone(), p.ratio(), (p.clipped_high, p.clipped_low)),
        Radiance::Buffered(m) => (m.order.clone(), m.ratio(), (m.clipped_high, m.clipped_low)),
    };
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
        weighting: format!("{:?}", options.weighting),
        clipped,
    };
    let mut warnings: Vec<String> = frames
        .iter()
        .flat_map(|f| {
            f.metadata
                .warnings
                .iter()
                .map(move |w| format!("{}: {w}", f.path.display()))
        })
        .chain(chosen.notes.iter().cloned())
        .collect();
    let (source, confidence): (&dyn RadianceSource, Option<&[f32]>) = match &merged {
        Radiance::Fused(pair) => (pair, None),
        Radiance::Buffered(m) => (&m.radiance, m.confidence.as_deref()),
    };
    let mut outputs = Vec::new();
    let mut exr_scale = 1.0;
    if let Some(exr) = prints.exr {
        let written = write_radiance(source, confidence, &provenance, exr, prints, &mut stages)?;
        exr_scale = written.scale;
        warnings.extend(written.warnings);
        outputs.push(prints.exr_path());
    }
    if prints.radiance_hdr {
        let t = Instant::now();
        let path = prints.hdr_path();
        let mut hdr = Vec::new();
        hdr_output::encode_radiance_hdr(&mut hdr, source)?;
        atomic::publish(&path, &hdr, prints.overwrite)?;
        outputs.push(path);
        stages.push(("hdr", t.elapsed()));
    }
    let fused = matches!(merged, Radiance::Fused(_));
    if let Radiance::Buffered(m) = merged {
        outputs.extend(print_looks(&m.radiance, prints, &mut stages)?);
    }
    Ok(Developed {
        outputs,
        response: chosen,
        order,
        ratio,
        clipped,
        exr_scale,
        fused,
        warnings,
        stages,
    })
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
    let mut exr = Cursor::new(Vec::new());
    let written = hdr_output::encode_exr(&mut exr, source, confidence, provenance, options)?;
    stages.push(("encode", t.elapsed()));
    let t = Instant::now();
    let path = prints.exr_path();
    atomic::publish(&path, exr.get_ref(), prints.overwrite)?;
    stages.push(("write", t.elapsed()));
    Ok(written)
}

/// Renders `map` in every look of `prints` (stage `render`).
fn print_looks(
    map: &RadianceMap,
    prints: &Prints<'_>,
    stages: &mut Stages,
) -> Result<Vec<PathBuf>, DarkroomError> {
    if prints.looks.is_empty() {
        return Ok(Vec::new());
    }
    let t = Instant::now();
    let written = rendering::render_all(
        map,
        prints.looks,
        &Outputs {
            dir: prints.dir,
            stem: prints.stem,
            format: prints.format,
            overwrite: prints.overwrite,
            exif: prints.exif,
        },
    )?;
    stages.push(("render", t.elapsed()));
    Ok(written)
}

/// One frame's radiance estimate, `E = g(B)` per sample: the frame's own range, no
/// extension (scale: a sample at the top code reads 1.0, as the longest frame of a
/// bracket does).
pub fn linearise(
    loaded: &LoadedFrame,
    response: &InverseResponse,
) -> Result<RadianceMap, MergeError> {
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
    let t = Instant::now();
    let map = linearise(frame, &response.response)?;
    stages.push(("linearise", t.elapsed()));
    let outputs = print_looks(&map, prints, &mut stages)?;
    Ok(Developed {
        outputs,
        response: use_given(response, Vec::new(), None),
        order: vec![0],
        ratio: 1.0,
        clipped: (0, 0),
        exr_scale: 1.0,
        fused: false,
        warnings: frame
            .metadata
            .warnings
            .iter()
            .map(|w| format!("{}: {w}", frame.path.display()))
            .collect(),
        stages,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::{BitDepth, Frame};
    use crate::metadata::{Camera, Exposure, Metadata};
    use crate::synthetic::{ResponseCurve, Sensor, expose, scene};

    fn loaded(name: &str, frame: Frame) -> LoadedFrame {
        LoadedFrame {
            path: PathBuf::from(name),
            frame,
            metadata: Metadata {
                camera: Camera::default(),
                exposure: Exposure::default(),
                captured_at: None,
                orientation: 1,
                warnings: Vec::new(),
            },
        }
    }

    /// 1/60, 1/60, 1/15: the middle pair is a duplicate; the fit must take the pair that
    /// differs, not fail on a ratio of 1.
    #[test]
    fn duplicate_exposures_in_the_middle_do_not_stop_the_fit() {
        let truth = scene(240, 160, 3);
        let sensor = Sensor::noiseless(ResponseCurve::Srgb, BitDepth::Eight);
        let exposures = [1.0 / 60.0, 1.0 / 60.0, 1.0 / 15.0];
        let frames: Vec<LoadedFrame> = exposures
            .iter()
            .enumerate()
            .map(|(i, &e)| loaded(&format!("f{i}.png"), expose(&truth, e * 15.0, &sensor)))
            .collect();
        let bracket = bracket(&frames, &exposures);
        let policy = ResponsePolicy::Fit {
            fallback: None,
            min_confidence: 0.0,
        };
        let chosen = choose_response(&bracket, RatioSource::Argument, policy, &mut Stages::new())
            .expect("the distinct pair is fitted");
        assert_eq!(chosen.source, Source::Fitted);
        assert!((chosen.report["ratio"].as_f64().unwrap() - 4.0).abs() < 1e-9);
        assert!(chosen.summary.contains("f2.png"), "{}", chosen.summary);
    }

    /// Three distinct exposures are calibrated jointly from all frames, and the
    /// contradiction check weighs each tone pair at its own ratio: frames through a film
    /// S curve still contradict sRGB.
    #[test]
    fn three_exposures_are_fitted_from_every_frame() {
        let truth = scene(240, 160, 5);
        let sensor = Sensor::noiseless(ResponseCurve::FilmS, BitDepth::Eight);
        let exposures = [0.25, 1.0, 4.0];
        let frames: Vec<LoadedFrame> = exposures
            .iter()
            .enumerate()
            .map(|(i, &e)| loaded(&format!("f{i}.png"), expose(&truth, e, &sensor)))
            .collect();
        let bracket = bracket(&frames, &exposures);
        let policy = ResponsePolicy::Fit {
            fallback: Some(GivenResponse::standard(3)),
            min_confidence: 1.01,
        };
        let chosen =
            choose_response(&bracket, RatioSource::Argument, policy, &mut Stages::new()).unwrap();
        assert_eq!(chosen.source, Source::Fitted, "{:?}", chosen.notes);
        assert!(
            chosen.summary.contains("all 3 frames"),
            "{}",
            chosen.summary
        );
        assert_eq!(chosen.report["frames"].as_array().unwrap().len(), 3);
        assert!((chosen.report["ratio"].as_f64().unwrap() - 16.0).abs() < 1e-9);
        assert!(
            chosen.notes[0].contains("contradicts"),
            "{:?}",
            chosen.notes
        );
    }

    /// A weak fit below `min_confidence` gives way to the fallback, and says so; the fit
    /// itself is still reported (the daemon decides whether the cache learns from it).
    #[test]
    fn a_fit_below_min_confidence_uses_the_fallback() {
        let truth = scene(240, 160, 4);
        let sensor = Sensor::noiseless(ResponseCurve::Srgb, BitDepth::Eight);
        let frames = [
            loaded("a.png", expose(&truth, 1.0, &sensor)),
            loaded("b.png", expose(&truth, 4.0, &sensor)),
        ];
        let bracket = bracket(&frames, &[1.0, 4.0]);
        let policy = ResponsePolicy::Fit {
            fallback: Some(GivenResponse::standard(3)),
            min_confidence: 1.01,
        };
        let chosen =
            choose_response(&bracket, RatioSource::Argument, policy, &mut Stages::new()).unwrap();
        assert_eq!(chosen.source, Source::Standard);
        assert!(chosen.fit.is_some());
        assert!(chosen.notes[0].contains("confidence"), "{:?}", chosen.notes);
        assert_eq!(chosen.report["rejected_fit"]["source"], "fitted");
    }

    /// A weak fit is kept when the fallback contradicts the bracket: frames through a film
    /// S curve are not explained by sRGB.
    #[test]
    fn a_fallback_the_bracket_contradicts_is_not_used() {
        let truth = scene(240, 160, 4);
        let sensor = Sensor::noiseless(ResponseCurve::FilmS, BitDepth::Eight);
        let frames = [
            loaded("a.png", expose(&truth, 1.0, &sensor)),
            loaded("b.png", expose(&truth, 4.0, &sensor)),
        ];
        let bracket = bracket(&frames, &[1.0, 4.0]);
        let policy = ResponsePolicy::Fit {
            fallback: Some(GivenResponse::standard(3)),
            min_confidence: 1.01,
        };
        let chosen =
            choose_response(&bracket, RatioSource::Argument, policy, &mut Stages::new()).unwrap();
        assert_eq!(chosen.source, Source::Fitted, "{:?}", chosen.notes);
        assert!(
            chosen.notes[0].contains("contradicts"),
            "{:?}",
            chosen.notes
        );
    }
}
