//! Radiance merge: a bracket of frames and the camera's inverse response become one
//! high-dynamic-range [`RadianceMap`].
//!
//! # The estimate
//!
//! Frames are sorted by relative exposure `e_k = t·S/N²` (darkest first). Per pixel and
//! channel, with `B_k` the frame's brightness and `g` the inverse response,
//!
//! ```text
//! E = Σ_k w_k(B_k) · x_k(B_k)  /  Σ_k w_k(B_k),      x_k(B) = g(B) · e_ref / e_k
//! ```
//!
//! # Scale convention
//!
//! `e_ref` is the exposure of the *longest* frame, so radiance is relative and
//! dimensionless: a pixel at brightness `g⁻¹(1)` (that is `B = 1`, since `g(1) = 1`) in the
//! longest exposure reads exactly 1.0. Mid-grey lands wherever the longest frame put it
//! (about 0.18 for a normally exposed long frame with an sRGB-like response), and the
//! brightest representable value is `e_ref / e_min`, the bracket's total ratio.
//!
//! # Absolute scale
//!
//! The merge itself returns the relative scale above. [`exposure_scale`] turns it into a
//! scale anchored to the frames' EXIF exposure, so that equal scene luminance gives equal
//! values across brackets, settings and bodies. A frame of f-number `N`, exposure time `t`
//! (s) and ISO speed `S` receives the focal-plane exposure `H = q·L·t/N²` (lux·s) from a
//! scene luminance `L` (cd/m²), with `q = 0.65` ([`LENS_Q`], ISO 12232 and ISO 2720: lens
//! transmittance, vignetting and the cos⁴ falloff at a typical field angle). ISO 12232's
//! saturation-based speed `S = 78/H_sat` places saturation, `g(B) = 1`, at
//! `H_sat = 78/S`, so the luminance of a sample is
//!
//! ```text
//! L = g(B) · (78/q) · N²/(t·S) = 120 · g(B) · N²/(t·S)  cd/m²          (nominal)
//! ```
//!
//! the value written (times an optional calibration factor `c`, [`Scale::Luminance`]).
//! A reflected-light meter with `K = 12.5 cd·s/m²` (ISO 2720) calls the luminance
//! `L_m = K·N²/(t·S)` average, so a correctly metered average area reads
//! `g = 12.5/120 = 0.104` of saturation, while ISO 12232 derives its 78 from an 18 % grey
//! with √2 of headroom, `g = 0.18/√2 = 0.127`: the two conventions differ by 0.3 stop,
//! and the saturation one is used because `g(B) = 1` is saturation by construction of
//! `g` (JPEG white, or the raw's clipping point). Bodies do not all rate their ISO
//! against the same saturation point (a camera JPEG's white is not its raw's clipping
//! point), so the nominal value may be off by a constant per body, up to about half a
//! stop: that constant is what the calibration `c` corrects (shoot a grey card, read its
//! luminance `L_card` on a spot meter, and set `c = L_card / value read`).
//!
//! # Weights
//!
//! Both weights are exactly zero at the codes that mean "clipped" (0 and the largest
//! code) and positive everywhere in between.
//!
//! * [`Weighting::Hat`] (default), Debevec & Malik's triangle `w(B) = min(B, 1 − B)/0.5`:
//!   trusts mid-tones and fades towards both ends, the same for every frame. Better when
//!   the response is uncertain near its ends (the sRGB default for an unknown camera, a
//!   fit whose data did not reach the extremes), with JPEG highlight roll-off, and when
//!   the subject moved: every frame contributes, so nothing depends on one frame alone.
//! * [`Weighting::NoiseAware`]: inverse variance of each frame's estimate under noise
//!   that is constant in code values (read noise and quantisation, the regime of 8-bit
//!   JPEGs and low-ISO captures): `Var x_k = (g'(B)·e_ref/e_k)²·σ²`, so
//!   `w_k(B) = t(B) · (e_k / (e_ref · g'(B)))²`, with `t` a trust window that is 1 except
//!   within 5 % of either end, where it falls linearly to 0 (codes there are distorted
//!   by clipping of the noise). It prefers the longer exposure wherever that one is not
//!   clipped, and gives a lower error than the hat when the response is known well (see
//!   `tests/merge.rs`, which measures both).
//!
//! # Clipped everywhere
//!
//! A sample whose weight is zero in every frame has no estimate. The rule: if it is
//! clipped high (the darkest frame's code is in the upper half) it takes the darkest
//! frame's value `x_0(B_0)` — a lower bound of its true radiance; otherwise (clipped low)
//! it takes the brightest frame's value `x_{N−1}(B_{N−1})` — an upper bound. Either way it
//! is finite, never 0/0, and radiance stays monotone across the clip boundary, because
//! just inside it the estimate is the same frame's `x(B)` at a smaller code. Such samples
//! are counted ([`BracketOrder::clipped_high`], [`BracketOrder::clipped_low`]) and have
//! confidence 0.
//!
//! # Speed
//!
//! Per frame and channel, `w_k(code)` and `w_k(code)·x_k(code)` are tabulated once
//! (256 entries for 8-bit frames, 65 536 for 16-bit), so the per-sample work is two table
//! lookups and two additions per frame; rows are merged in parallel straight into the
//! output buffer, without per-frame floating-point copies of the frames. For the usual
//! bracket, two 8-bit frames, every outcome is tabulated once per channel by code pair
//! (65 536 entries), so a sample costs one lookup; [`PairMerge`] goes further and is
//! evaluated while the file is encoded, so no radiance buffer exists at all.
//! [`BracketMerge`] does the same for any other bracket (three frames or more, or 16-bit
//! frames) through the per-frame tables: an encoder pulls one line of one channel at a
//! time, so what a merge written only as a file holds is the frames' codes, the tables
//! and the lines in flight, whatever the number of frames. Both give exactly the values
//! of [`merge`] (the same tables, summed in the same order).
//!
//! # Equal exposures
//!
//! Frames of equal exposure (within 1 %) are merged as duplicates: the weighted mean
//! averages their noise. A set with only one distinct exposure is refused: it is not a
//! bracket.

use std::path::{Path, PathBuf};

use rayon::prelude::*;

use crate::align::AlignMode;
use crate::frame::{BitDepth, Frame, Samples};
use crate::metadata::Camera;
use crate::radiance::{CodePairs, RadianceMap, RadianceSource};
use crate::response::{InverseResponse, same_exposure};

/// How much each frame's sample is trusted (see the module docs for when to use which).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum Weighting {
    /// `w(B) = min(B, 1 − B)/0.5`, the same for all frames.
    #[default]
    Hat,
    /// Inverse variance under constant code-value noise: `t(B)·(e_k/(e_ref·g'(B)))²`.
    NoiseAware,
}

impl Weighting {
    /// The name as the command line and `--json` spell it (`hat`, `noise-aware`).
    pub fn name(self) -> &'static str {
        match self {
            Weighting::Hat => "hat",
            Weighting::NoiseAware => "noise-aware",
        }
    }
}

/// One frame of a bracket, as the merge needs it.
#[derive(Debug, Clone, Copy)]
pub struct BracketFrame<'a> {
    /// Where the frame came from; used only to name it in errors.
    pub source: &'a Path,
    /// The pixels.
    pub frame: &'a Frame,
    /// Relative exposure `e = t·S/N²` (any unit, the same for all frames), > 0.
    pub exposure: f64,
    /// The body that took it (compared field by field where both frames know it).
    pub camera: &'a Camera,
}

/// Options of [`merge`].
#[derive(Debug, Clone, Copy, Default)]
pub struct MergeOptions {
    /// The weight function.
    pub weighting: Weighting,
    /// Also return the per-pixel confidence (see [`Merged::confidence`]).
    pub confidence: bool,
    /// Whether the darkroom leaves frames out where they disagree with the reference
    /// ([`crate::deghost`] makes the masks that [`merge_masked`] applies; [`merge`]
    /// itself blends every frame).
    pub deghost: Deghost,
    /// How the darkroom aligns the frames before merging them ([`crate::align`]); the
    /// merge itself takes the frames as given.
    pub align: AlignMode,
}

/// Whether frames that disagree with the bracket's reference frame are left out there.
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    Default,
    serde::Serialize,
    serde::Deserialize,
    clap::ValueEnum,
)]
#[serde(rename_all = "lowercase")]
pub enum Deghost {
    /// Leave a frame out where it disagrees with the reference beyond its noise.
    #[default]
    On,
    /// Blend every frame everywhere: a moving subject appears translucent, "an effect
    /// similar to motion blur" (the method's report).
    Off,
}

/// Why a bracket cannot be merged. Every variant names the files concerned.
#[derive(Debug, thiserror::Error)]
pub enum MergeError {
    /// Fewer than two frames.
    #[error("a merge needs at least 2 frames, got {0}")]
    TooFewFrames(usize),
    /// Two frames of different pixel dimensions.
    #[error(
        "{first} is {first_size} but {other} is {other_size}: frames of one bracket must share one size"
    )]
    SizeMismatch {
        /// The first frame.
        first: PathBuf,
        /// Its size, `W×H×C`.
        first_size: String,
        /// The frame that differs.
        other: PathBuf,
        /// Its size.
        other_size: String,
    },
    /// Two frames of different bit depth.
    #[error(
        "{first} is {first_bits}-bit but {other} is {other_bits}-bit: frames of one bracket must share one depth"
    )]
    DepthMismatch {
        /// The first frame.
        first: PathBuf,
        /// Its bits per sample.
        first_bits: u32,
        /// The frame that differs.
        other: PathBuf,
        /// Its bits per sample.
        other_bits: u32,
    },
    /// Two frames from different camera bodies.
    #[error(
        "{first} was taken by {first_camera} but {other} by {other_camera}: a bracket comes from one camera"
    )]
    CameraMismatch {
        /// The first frame.
        first: PathBuf,
        /// Its camera.
        first_camera: String,
        /// The frame that differs.
        other: PathBuf,
        /// Its camera.
        other_camera: String,
    },
    /// An exposure that is not a positive finite number.
    #[error("{path}: exposure {exposure} is not a positive number")]
    BadExposure {
        /// The frame.
        path: PathBuf,
        /// The value given.
        exposure: f64,
    },
    /// Every frame has the same exposure: nothing to extend the range with.
    #[error(
        "{first} and {other} have the same exposure ({exposure}) and there is no other: not a bracket"
    )]
    SingleExposure {
        /// One frame.
        first: PathBuf,
        /// Another.
        other: PathBuf,
        /// The common exposure.
        exposure: f64,
    },
    /// A frame's weight mask does not have one weight per pixel.
    #[error("{path}: its weight mask has {mask} values for {pixels} pixels")]
    MaskSize {
        /// The frame.
        path: PathBuf,
        /// Values in the mask.
        mask: usize,
        /// Pixels in the frame.
        pixels: usize,
    },
    /// The response has 1 channel for RGB frames or 3 for grey ones.
    #[error("the response has {response} channel(s) but {path} has {frame}")]
    ChannelMismatch {
        /// A frame.
        path: PathBuf,
        /// Its channels.
        frame: usize,
        /// The response's channels.
        response: usize,
    },
}

/// What every merge reports of its bracket besides the radiance: the frames in exposure
/// order and the samples clipped in all of them.
#[derive(Debug, Clone, PartialEq)]
pub struct BracketOrder {
    /// Input indices sorted by exposure, darkest first.
    pub order: Vec<usize>,
    /// The exposures in that order.
    pub exposures: Vec<f64>,
    /// Samples clipped high in every frame (value is a lower bound).
    pub clipped_high: u64,
    /// Samples clipped low in every frame (value is an upper bound).
    pub clipped_low: u64,
}

impl BracketOrder {
    /// Ratio of the longest to the shortest exposure, `e_max/e_min`.
    pub fn ratio(&self) -> f64 {
        self.exposures[self.exposures.len() - 1] / self.exposures[0]
    }
}

/// The input indices of `frames` sorted by exposure, darkest first (stable), and the
/// exposures in that order.
fn exposure_order(frames: &[BracketFrame<'_>]) -> (Vec<usize>, Vec<f64>) {
    let mut order: Vec<usize> = (0..frames.len()).collect();
    order.sort_by(|&a, &b| frames[a].exposure.total_cmp(&frames[b].exposure));
    let exposures = order.iter().map(|&i| frames[i].exposure).collect();
    (order, exposures)
}

/// The result of [`merge`].
#[derive(Debug, Clone)]
pub struct Merged {
    /// Linear relative radiance (scale: see the module docs).
    pub radiance: RadianceMap,
    /// Per pixel, the smallest over channels of `Σ_k w_k` (weights peak at 1, so the
    /// range is `0..=N`); 0 where some channel was clipped in every frame. Present when
    /// asked for in [`MergeOptions::confidence`].
    pub confidence: Option<Vec<f32>>,
    /// The frames' order and what was clipped in all of them.
    pub bracket: BracketOrder,
}

/// Lens transmittance and vignetting factor `q` of `H = q·L·t/N²` (ISO 12232).
pub const LENS_Q: f64 = 0.65;

/// ISO 12232's saturation-based speed constant: `S = 78/H_sat` (lux·s).
const SATURATION_SPEED: f64 = 78.0;

/// Which scale a radiance map carries (see the module docs).
#[derive(Debug, Clone, PartialEq)]
pub enum Scale {
    /// Luminance: `value = c · (78/q) · g(B) · N²/(t·S)` cd/m², anchored to the EXIF
    /// exposure; `calibration` is `c` (1: nominal, uncalibrated).
    Luminance {
        /// The calibration factor `c`.
        calibration: f64,
    },
    /// Relative: 1.0 = `B = 1` in the longest exposure; `reason` says why no EXIF anchor.
    Relative {
        /// Why the frames could not be anchored.
        reason: String,
    },
}

impl Default for Scale {
    fn default() -> Scale {
        Scale::Relative {
            reason: "no exposure given".to_string(),
        }
    }
}

impl Scale {
    /// cd/m² of the value 1.0 (OpenEXR's `whiteLuminance`), when the scale is luminance.
    pub fn white_luminance(&self) -> Option<f64> {
        match self {
            Scale::Luminance { .. } => Some(1.0),
            Scale::Relative { .. } => None,
        }
    }

    /// The convention in one line, for the EXR header and reports.
    pub fn describe(&self) -> String {
        match self {
            Scale::Luminance { calibration } if *calibration == 1.0 => {
                "luminance in cd/m2, nominal (uncalibrated): value = 120 * g(B) * N^2/(t*S) \
                 (ISO 12232 saturation speed, q = 0.65)"
                    .to_string()
            }
            Scale::Luminance { calibration } => format!(
                "luminance in cd/m2, calibrated: value = {calibration} * 120 * g(B) * N^2/(t*S) \
                 (ISO 12232 saturation speed, q = 0.65, calibration factor {calibration})"
            ),
            Scale::Relative { reason } => format!(
                "relative: value = g(B_k) * e_longest / e_k, weighted over frames; \
                 1.0 = B=1 in the longest exposure (not anchored to the exposure: {reason})"
            ),
        }
    }

    /// `"luminance"`, `"luminance-calibrated"` or `"relative"`.
    pub fn kind(&self) -> &'static str {
        match self {
            Scale::Luminance { calibration } if *calibration == 1.0 => "luminance",
            Scale::Luminance { .. } => "luminance-calibrated",
            Scale::Relative { .. } => "relative",
        }
    }
}

/// The scale of a merge of frames with EXIF `exif` (per frame, any order) merged with
/// relative exposures `relative` (same order; the merge's 1.0 is `B = 1` at the largest),
/// and the factor that takes the merge's values to it: `c · 120 / a_ref` with
/// `a_ref = t·S/N²` of the longest frame (see the module docs).
///
/// The frames are anchored when every one's EXIF has time, f-number and ISO and the
/// relative exposures are proportional to `t·S/N²` within 1 % (they are when they came
/// from EXIF; exposures given another way must agree with it). Otherwise the scale stays
/// relative (factor 1) and says why. `calibration` must be positive and finite.
pub fn exposure_scale(
    exif: &[crate::metadata::Exposure],
    relative: &[f64],
    calibration: f64,
) -> (Scale, f64) {
    let relative_scale = |reason: String| (Scale::Relative { reason }, 1.0);
    if exif.len() != relative.len() || exif.is_empty() {
        return relative_scale("no frames".to_string());
    }
    let mut absolute = Vec::with_capacity(exif.len());
    for (k, e) in exif.iter().enumerate() {
        match e.relative() {
            Some(a) if a.is_finite() && a > 0.0 => absolute.push(a),
            _ => {
                return relative_scale(format!(
                    "frame {} lacks the EXIF exposure time, f-number or ISO",
                    k + 1
                ));
            }
        }
    }
    let longest = (0..relative.len())
        .max_by(|&a, &b| relative[a].total_cmp(&relative[b]))
        .expect("not empty");
    let lambda = relative[longest] / absolute[longest];
    if let Some(k) =
        (0..relative.len()).find(|&k| !same_exposure(relative[k], lambda * absolute[k]))
    {
        return relative_scale(format!(
            "the exposure used for frame {} is not in proportion to its EXIF t*S/N^2",
            k + 1
        ));
    }
    if !(calibration.is_finite() && calibration > 0.0) {
        return relative_scale(format!("calibration {calibration} is not positive"));
    }
    let factor = calibration * SATURATION_SPEED / LENS_Q / absolute[longest];
    (Scale::Luminance { calibration }, factor)
}

/// Frames of equal exposure (within 1 %) are merged as duplicates: the weighted mean
/// averages their noise. A set with only one distinct exposure is refused.
pub fn merge(
    frames: &[BracketFrame<'_>],
    response: &InverseResponse,
    options: MergeOptions,
) -> Result<Merged, MergeError> {
    merge_masked(frames, response, options, &Masks::default())
}

/// Deghosting's weight masks as [`merge_masked`] applies them.
#[derive(Debug, Clone, Default)]
pub struct Masks<'a> {
    /// Per input frame, its weight per pixel (`0..=255`, 255 kept) or `None` where it is
    /// kept everywhere; empty for no masks.
    pub weights: Vec<Option<&'a [u8]>>,
    /// Input index of the reference frame, which the others were compared with.
    pub reference: usize,
    /// The first and the last code at which the reference's sample measures the
    /// radiance; beyond them it is a bound (see [`merge_masked`]).
    pub measured: (usize, usize),
}

/// [`merge`] with a weight mask per frame (input order; `None` or an empty `masks`: the
/// frame is kept everywhere): frame `k`'s weight at pixel `p` is multiplied by
/// `m_k(p)/255`, so a frame masked to 0 does not contribute there
/// ([`crate::deghost`]). A sample every kept frame clipped takes the clipped-everywhere
/// rule over the kept frames (every frame when all are masked out there), except that a
/// sample black in every kept frame but seen by a masked-out one takes the latter's
/// weighted mean rather than black. Where any frame's weight is below 1, each value is
/// held within what the reference's sample allows ([`Masks::reference`]): at least the
/// reference's value at the last measured code ([`Masks::measured`]) where its code lies
/// above it, at most its value at the first where below. With no mask the values are
/// exactly those of [`merge`].
pub fn merge_masked(
    frames: &[BracketFrame<'_>],
    response: &InverseResponse,
    options: MergeOptions,
    masks: &Masks<'_>,
) -> Result<Merged, MergeError> {
    check(frames, response)?;
    let (order, exposures) = exposure_order(frames);
    let bound = Bound::of(&order, masks);
    let masks = sorted_masks(frames, &order, &masks.weights)?;
    let masked = masks.iter().any(Option::is_some);
    let first = frames[0].frame;
    let (width, height, channels) = (first.width(), first.height(), first.channels());
    let depth = first.bit_depth();
    let tables = Tables::new(&exposures, response, channels, depth, options.weighting);
    let masks = Masked {
        weights: &masks,
        bound,
    };

    let mut pixels = vec![0.0f32; first.pixel_count() * channels];
    let mut confidence = options
        .confidence
        .then(|| vec![0.0f32; first.pixel_count()]);
    let clipped = match Codes::of(frames, &order) {
        Codes::Eight(codes) => {
            match confidence.as_deref_mut() {
                // The common case, an 8-bit pair, takes one lookup per sample.
                None if codes.len() == 2 && !masked => {
                    let table = PairTable::new(&tables);
                    fill_pair(codes[0], codes[1], &table, width as usize, &mut pixels);
                    count_clipped(codes[0], codes[1], &table)
                }
                conf => merge_codes(&codes, &tables, masks, width as usize, &mut pixels, conf),
            }
        }
        Codes::Sixteen(codes) => merge_codes(
            &codes,
            &tables,
            masks,
            width as usize,
            &mut pixels,
            confidence.as_deref_mut(),
        ),
    };
    let radiance = RadianceMap::new(width, height, channels, pixels)
        .expect("buffer sized from the frame's dimensions");
    Ok(Merged {
        radiance,
        confidence,
        bracket: BracketOrder {
            order,
            exposures,
            clipped_high: clipped.high,
            clipped_low: clipped.low,
        },
    })
}

/// `masks` (input order, or empty for none) in the exposure `order`, each checked to hold
/// one weight per pixel.
fn sorted_masks<'m>(
    frames: &[BracketFrame<'_>],
    order: &[usize],
    masks: &[Option<&'m [u8]>],
) -> Result<Vec<Option<&'m [u8]>>, MergeError> {
    let pixels = frames[0].frame.pixel_count();
    for (frame, mask) in frames.iter().zip(masks) {
        if let Some(mask) = mask
            && mask.len() != pixels
        {
            return Err(MergeError::MaskSize {
                path: frame.source.to_path_buf(),
                mask: mask.len(),
                pixels,
            });
        }
    }
    Ok(order
        .iter()
        .map(|&i| masks.get(i).copied().flatten())
        .collect())
}

/// Sorted masks and the reference's [`Bound`] (`None` without masks).
#[derive(Clone, Copy)]
struct Masked<'m> {
    weights: &'m [Option<&'m [u8]>],
    bound: Option<Bound>,
}

impl Masked<'_> {
    /// Whether some frame's weight at pixel `p` is below 1.
    #[inline(always)]
    fn any_left_out(&self, p: usize) -> bool {
        self.weights.iter().flatten().any(|m| m[p] < u8::MAX)
    }

    /// The bound that holds at pixel `p`: the reference's where a frame is left out.
    #[inline(always)]
    fn at(&self, p: usize) -> Option<Bound> {
        self.bound.filter(|_| self.any_left_out(p))
    }

    /// `v`, merged for channel `c` of pixel `p`, held within [`Masked::at`]'s bound;
    /// `code(k)` is sorted frame `k`'s code of that sample.
    #[inline(always)]
    fn hold(
        &self,
        tables: &Tables,
        (p, c): (usize, usize),
        code: impl Fn(usize) -> usize,
        v: f32,
    ) -> f32 {
        self.at(p)
            .map_or(v, |b| b.hold(tables, c, code(b.frame), v))
    }
}

/// Where deghosting left a frame out, the reference's sample still bounds the radiance:
/// above its measured codes ([`Masks::measured`]) it is at least the reference's value at
/// the last of them, below them at most its value at the first. A frame kept there that
/// agreed with the bound only within its noise (a dark frame's view of what moved) would
/// otherwise set the value alone, the reference's own weight being 0 or nearly; the
/// merged value is held within the bound instead.
#[derive(Debug, Clone, Copy)]
struct Bound {
    /// The reference's index in exposure order.
    frame: usize,
    /// The first and the last measured code.
    codes: (usize, usize),
}

impl Bound {
    /// The bound of the frame `masks.reference` (input order) among frames in `order`;
    /// `None` without masks.
    fn of(order: &[usize], masks: &Masks<'_>) -> Option<Bound> {
        if masks.weights.iter().all(Option::is_none) {
            return None;
        }
        let frame = order.iter().position(|&i| i == masks.reference)?;
        Some(Bound {
            frame,
            codes: masks.measured,
        })
    }

    /// `v` held within the bound the reference's `code` in channel `c` sets.
    #[inline(always)]
    fn hold(&self, tables: &Tables, c: usize, code: usize, v: f32) -> f32 {
        let (first, last) = self.codes;
        if code > last {
            v.max(tables.value[tables.index(self.frame, c, last)])
        } else if code < first {
            v.min(tables.value[tables.index(self.frame, c, first)])
        } else {
            v
        }
    }
}

/// Whether a mask keeps every pixel of `weights` whole (each factor exactly 1).
fn all_kept(weights: &[u8]) -> bool {
    weights.iter().all(|&m| m == u8::MAX)
}

/// The weight factor `m_k(p)/255` of sorted frame `k` at pixel `p` (1 without a mask).
#[inline(always)]
fn kept(masks: &[Option<&[u8]>], k: usize, p: usize) -> f32 {
    masks[k].map_or(1.0, |m| f32::from(m[p]) / 255.0)
}

fn check(frames: &[BracketFrame<'_>], response: &InverseResponse) -> Result<(), MergeError> {
    if frames.len() < 2 {
        return Err(MergeError::TooFewFrames(frames.len()));
    }
    let first = &frames[0];
    let size = |f: &Frame| format!("{}×{}×{}", f.width(), f.height(), f.channels());
    for f in frames {
        if !(f.exposure.is_finite() && f.exposure > 0.0) {
            return Err(MergeError::BadExposure {
                path: f.source.to_path_buf(),
                exposure: f.exposure,
            });
        }
    }
    for other in &frames[1..] {
        let (a, b) = (first.frame, other.frame);
        if (a.width(), a.height(), a.channels()) != (b.width(), b.height(), b.channels()) {
            return Err(MergeError::SizeMismatch {
                first: first.source.to_path_buf(),
                first_size: size(a),
                other: other.source.to_path_buf(),
                other_size: size(b),
            });
        }
        if a.bit_depth() != b.bit_depth() {
            return Err(MergeError::DepthMismatch {
                first: first.source.to_path_buf(),
                first_bits: a.bit_depth().bits(),
                other: other.source.to_path_buf(),
                other_bits: b.bit_depth().bits(),
            });
        }
        if !same_camera(first.camera, other.camera) {
            return Err(MergeError::CameraMismatch {
                first: first.source.to_path_buf(),
                first_camera: describe(first.camera),
                other: other.source.to_path_buf(),
                other_camera: describe(other.camera),
            });
        }
    }
    if response.channels() != first.frame.channels() {
        return Err(MergeError::ChannelMismatch {
            path: first.source.to_path_buf(),
            frame: first.frame.channels(),
            response: response.channels(),
        });
    }
    let distinct = frames[1..]
        .iter()
        .any(|f| !same_exposure(f.exposure, first.exposure));
    if !distinct {
        return Err(MergeError::SingleExposure {
            first: first.source.to_path_buf(),
            other: frames[1].source.to_path_buf(),
            exposure: first.exposure,
        });
    }
    Ok(())
}

/// Same body unless make, model or serial are known for both and differ.
fn same_camera(a: &Camera, b: &Camera) -> bool {
    let agree = |x: &Option<String>, y: &Option<String>| match (x, y) {
        (Some(x), Some(y)) => x == y,
        _ => true,
    };
    agree(&a.make, &b.make) && agree(&a.model, &b.model) && agree(&a.serial, &b.serial)
}

fn describe(c: &Camera) -> String {
    let part = |x: &Option<String>| x.clone().unwrap_or_else(|| "?".to_string());
    format!(
        "{} {} (serial {})",
        part(&c.make),
        part(&c.model),
        part(&c.serial)
    )
}

/// Per frame `k` and channel `c`, indexed by code: `[w_k(code), w_k(code)·x_k(code)]`,
/// and `x_k(code)` for the clipped-everywhere rule.
struct Tables {
    levels: usize,
    channels: usize,
    frames: usize,
    weighted: Vec<[f32; 2]>,
    value: Vec<f32>,
}

impl Tables {
    fn new(
        exposures: &[f64],
        response: &InverseResponse,
        channels: usize,
        depth: BitDepth,
        weighting: Weighting,
    ) -> Tables {
        let levels = depth.levels();
        let e_ref = exposures[exposures.len() - 1];
        let mut value = Vec::with_capacity(exposures.len() * channels * levels);
        let mut weight = Vec::with_capacity(value.capacity());
        for &e in exposures {
            for c in 0..channels {
                let g = response.table(c, levels);
                let slope = match weighting {
                    Weighting::Hat => Vec::new(),
                    Weighting::NoiseAware => slope(response, c, levels),
                };
                for (code, &gv) in g.iter().enumerate() {
                    let b = code as f64 / (levels - 1) as f64;
                    value.push((f64::from(gv) * e_ref / e) as f32);
                    weight.push(match weighting {
                        Weighting::Hat => hat(b),
                        Weighting::NoiseAware => trust(b) * (e / (e_ref * slope[code])).powi(2),
                    });
                }
            }
        }
        // Normalise so the largest weight anywhere is 1 (confidence is then comparable
        // between weightings and f32 never underflows).
        let peak = weight.iter().copied().fold(0.0f64, f64::max);
        let weighted = weight
            .iter()
            .zip(&value)
            .map(|(&w, &x)| {
                let w = (w / peak) as f32;
                [w, w * x]
            })
            .collect();
        Tables {
            levels,
            channels,
            frames: exposures.len(),
            weighted,
            value,
        }
    }

    fn index(&self, frame: usize, channel: usize, code: usize) -> usize {
        (frame * self.channels + channel) * self.levels + code
    }

    /// True when sorted frame `frame` gives `code` of `channel` no weight: the code is
    /// clipped in that frame.
    #[inline(always)]
    fn clipped(&self, frame: usize, channel: usize, code: usize) -> bool {
        self.weighted[self.index(frame, channel, code)][0] == 0.0
    }

    /// The clipped-everywhere rule: a sample no frame weighs is clipped high when the
    /// darkest frame's code `dark_code` is in the upper half of the codes (its value then
    /// a lower bound of the radiance), else clipped low (an upper bound).
    #[inline(always)]
    fn clipped_high(&self, dark_code: usize) -> bool {
        dark_code >= self.levels / 2
    }
}

/// Samples clipped high and low in every frame (the clipped-everywhere rule's two
/// outcomes), counted.
#[derive(Debug, Clone, Copy, Default)]
struct ClipCount {
    high: u64,
    low: u64,
}

impl ClipCount {
    /// Counts one sample's [`Clip`].
    #[inline(always)]
    fn add(&mut self, clip: Clip) {
        match clip {
            Clip::High => self.high += 1,
            Clip::Low => self.low += 1,
            Clip::Measured => {}
        }
    }

    /// The counts of two parts together.
    fn plus(self, other: ClipCount) -> ClipCount {
        ClipCount {
            high: self.high + other.high,
            low: self.low + other.low,
        }
    }
}

/// Debevec & Malik's hat, peaking at 1: `min(B, 1 − B)/0.5`.
fn hat(b: f64) -> f64 {
    b.min(1.0 - b) / 0.5
}

/// 1 in the middle, falling linearly to 0 over the last 5 % at either end.
fn trust(b: f64) -> f64 {
    (b.min(1.0 - b) / 0.05).min(1.0)
}

/// `g'(B)` per code, a secant over ±1/256 of the range (so 16-bit codes do not see the
/// response's sampling steps), floored at 0.01 so a flat stretch cannot get infinite
/// weight (the mean slope of `g` is 1).
fn slope(response: &InverseResponse, c: usize, levels: usize) -> Vec<f64> {
    let h = 1.0 / 256.0;
    (0..levels)
        .map(|code| {
            let b = code as f64 / (levels - 1) as f64;
            let (lo, hi) = ((b - h).max(0.0), (b + h).min(1.0));
            ((response.eval(c, hi) - response.eval(c, lo)) / (hi - lo)).max(0.01)
        })
        .collect()
}

/// Merges sorted frames' codes into `out`; returns the samples clipped in every frame.
fn merge_codes<T: Copy + Into<usize> + Sync>(
    frames: &[&[T]],
    tables: &Tables,
    masks: Masked<'_>,
    width: usize,
    out: &mut [f32],
    confidence: Option<&mut [f32]>,
) -> ClipCount {
    let channels = tables.channels;
    let row_len = width * channels;
    let row = |y: usize, row: &mut [f32], conf: Option<&mut [f32]>| {
        let start = y * row_len;
        if masks
            .weights
            .iter()
            .flatten()
            .all(|m| all_kept(&m[y * width..(y + 1) * width]))
        {
            // Weight factors of 1 everywhere: the unmasked arithmetic, exactly.
            merge_row(frames, tables, start, row, conf, (|_, _| 1.0, |_, _| ()))
        } else {
            let kept = |k, p| kept(masks.weights, k, y * width + p);
            let hold = |p: usize, pixel: &mut [f32]| {
                if let Some(bound) = masks.at(y * width + p) {
                    let codes = &frames[bound.frame][start + p * channels..];
                    for ((c, v), &code) in pixel.iter_mut().enumerate().zip(codes) {
                        *v = bound.hold(tables, c, code.into(), *v);
                    }
                }
            };
            merge_row(frames, tables, start, row, conf, (kept, hold))
        }
    };
    match confidence {
        Some(conf) => out
            .par_chunks_mut(row_len)
            .zip(conf.par_chunks_mut(width))
            .enumerate()
            .map(|(y, (r, conf))| row(y, r, Some(conf)))
            .reduce(ClipCount::default, ClipCount::plus),
        None => out
            .par_chunks_mut(row_len)
            .enumerate()
            .map(|(y, r)| row(y, r, None))
            .reduce(ClipCount::default, ClipCount::plus),
    }
}

/// What one sample merges to.
enum Estimate {
    /// The weighted mean and the weight sum.
    Weighted(f32, f32),
    /// Clipped high in every frame: the darkest frame's value (a lower bound).
    High(f32),
    /// Clipped low in every frame: the brightest frame's value (an upper bound).
    Low(f32),
}

impl Estimate {
    /// Whether the sample was clipped in every (kept) frame, and how.
    #[inline(always)]
    fn clip(&self) -> Clip {
        match self {
            Estimate::Weighted(..) => Clip::Measured,
            Estimate::High(_) => Clip::High,
            Estimate::Low(_) => Clip::Low,
        }
    }
}

/// The estimate of channel `c` from the sorted frames' codes (`code(k)`), frame `k`'s
/// weight multiplied by `kept(k)` (1, or its mask's factor).
#[inline(always)]
fn estimate(
    tables: &Tables,
    c: usize,
    code: impl Fn(usize) -> usize,
    kept: impl Fn(usize) -> f32,
) -> Estimate {
    let (mut num, mut den) = (0.0f32, 0.0f32);
    let (mut lost_num, mut lost_den) = (0.0f32, 0.0f32);
    for k in 0..tables.frames {
        let m = kept(k);
        let [w, wx] = tables.weighted[tables.index(k, c, code(k))];
        num += m * wx;
        den += m * w;
        lost_num += (1.0 - m) * wx;
        lost_den += (1.0 - m) * w;
    }
    if den > 0.0 {
        return Estimate::Weighted(num / den, den);
    }
    let (darkest, brightest) = kept_ends(tables.frames, kept);
    let dark_code = code(darkest);
    if tables.clipped_high(dark_code) {
        Estimate::High(tables.value[tables.index(darkest, c, dark_code)])
    } else if lost_den > 0.0 {
        // Black in every kept frame but seen by a masked one: its value, not 0.
        Estimate::Weighted(lost_num / lost_den, 0.0)
    } else {
        Estimate::Low(tables.value[tables.index(brightest, c, code(brightest))])
    }
}

/// The darkest and the brightest sorted frame with `kept(k) > 0` (the first and the
/// last frame when none is kept).
#[inline(always)]
fn kept_ends(frames: usize, kept: impl Fn(usize) -> f32) -> (usize, usize) {
    let darkest = (0..frames).find(|&k| kept(k) > 0.0).unwrap_or(0);
    let brightest = (0..frames).rev().find(|&k| kept(k) > 0.0);
    (darkest, brightest.unwrap_or(frames - 1))
}

/// One row of [`merge_codes`]; `kept(k, p)` is sorted frame `k`'s weight factor at
/// pixel `p` of the row, and `hold(p, pixel)` holds that pixel's merged values within
/// the reference's bound ([`Masked::at`], [`Bound::hold`]).
fn merge_row<T: Copy + Into<usize>>(
    frames: &[&[T]],
    tables: &Tables,
    start: usize,
    row: &mut [f32],
    mut confidence: Option<&mut [f32]>,
    (kept, hold): (impl Fn(usize, usize) -> f32, impl Fn(usize, &mut [f32])),
) -> ClipCount {
    let channels = tables.channels;
    let rows: Vec<&[T]> = frames
        .iter()
        .map(|f| &f[start..start + row.len()])
        .collect();
    let mut clipped = ClipCount::default();
    for (p, pixel) in row.chunks_exact_mut(channels).enumerate() {
        let mut least = f32::INFINITY;
        for (c, out) in pixel.iter_mut().enumerate() {
            let i = p * channels + c;
            let (value, den) = match estimate(tables, c, |k| rows[k][i].into(), |k| kept(k, p)) {
                Estimate::Weighted(v, den) => (v, den),
                Estimate::High(v) => {
                    clipped.high += 1;
                    (v, 0.0)
                }
                Estimate::Low(v) => {
                    clipped.low += 1;
                    (v, 0.0)
                }
            };
            *out = value;
            least = least.min(den);
        }
        hold(p, pixel);
        if let Some(conf) = confidence.as_deref_mut() {
            conf[p] = least;
        }
    }
    clipped
}

/// For a pair of 8-bit frames, every outcome tabulated per channel by
/// `(dark code << 8) | bright code`: 65 536 values per channel (256 KB), so a sample
/// costs one lookup; `clipped` marks the clipped-everywhere entries.
struct PairTable {
    channels: usize,
    value: Vec<f32>,
    clipped: Vec<Clip>,
}

impl PairTable {
    #[inline(always)]
    fn index(&self, channel: usize, dark: u8, bright: u8) -> usize {
        (channel << 16) | (usize::from(dark) << 8) | usize::from(bright)
    }

    fn new(tables: &Tables) -> PairTable {
        let n = tables.channels << 16;
        let mut value = Vec::with_capacity(n);
        let mut clipped = Vec::with_capacity(n);
        for c in 0..tables.channels {
            for pair in 0..1usize << 16 {
                let codes = [pair >> 8, pair & 0xff];
                let estimate = estimate(tables, c, |k| codes[k], |_| 1.0);
                clipped.push(estimate.clip());
                value.push(match estimate {
                    Estimate::Weighted(v, _) | Estimate::High(v) | Estimate::Low(v) => v,
                });
            }
        }
        PairTable {
            channels: tables.channels,
            value,
            clipped,
        }
    }
}

/// Fills `out` from two 8-bit frames through a [`PairTable`], rows in parallel.
fn fill_pair(dark: &[u8], bright: &[u8], table: &PairTable, width: usize, out: &mut [f32]) {
    let row_len = width * table.channels;
    out.par_chunks_mut(row_len)
        .enumerate()
        .for_each(|(y, row)| {
            let start = y * row_len;
            let codes = start..start + row_len;
            gather_pair(&dark[codes.clone()], &bright[codes], table, row);
        });
}

/// Each sample of `out` (whole pixels, channels interleaved) from its codes `dark`,
/// `bright` (the same samples) through a [`PairTable`]: one lookup a sample.
#[inline]
fn gather_pair(dark: &[u8], bright: &[u8], table: &PairTable, out: &mut [f32]) {
    let value = &table.value;
    if table.channels == 3 {
        // Whole pixels of a constant size: each channel's index without a modulo.
        let pixels = out
            .chunks_exact_mut(3)
            .zip(dark.chunks_exact(3).zip(bright.chunks_exact(3)));
        for (o, (d, b)) in pixels {
            for c in 0..3 {
                o[c] = value[table.index(c, d[c], b[c])];
            }
        }
    } else {
        for ((o, &d), &b) in out.iter_mut().zip(dark).zip(bright) {
            *o = value[table.index(0, d, b)];
        }
    }
}

/// Samples clipped high and low in both frames, from the [`PairTable`]'s clipped marks.
/// Weights vanish only at codes 0 and 255, so only samples whose dark code is one of
/// those are looked up.
fn count_clipped(dark: &[u8], bright: &[u8], table: &PairTable) -> ClipCount {
    let chunk = table.channels << 14;
    dark.par_chunks(chunk)
        .zip(bright.par_chunks(chunk))
        .map(|(d, b)| {
            let mut clipped = ClipCount::default();
            for (i, (&dc, &bc)) in d.iter().zip(b).enumerate() {
                if matches!(dc, 0 | 255) {
                    clipped.add(table.clipped[table.index(i % table.channels, dc, bc)]);
                }
            }
            clipped
        })
        .reduce(ClipCount::default, ClipCount::plus)
}

/// A merge of two 8-bit frames evaluated sample by sample on demand, never held as a
/// whole image: an encoder can pull [`PairMerge::sample`] while it writes, which saves
/// the `f32` radiance buffer (12 bytes per RGB pixel) and the time to fill it. The values
/// are exactly those of [`merge`] (same tables).
pub struct PairMerge<'a> {
    dark: &'a [u8],
    bright: &'a [u8],
    table: PairTable,
    width: u32,
    height: u32,
    /// The frames' order and what was clipped in both.
    pub bracket: BracketOrder,
}

impl<'a> PairMerge<'a> {
    /// Prepares the merge of `frames` when they are two 8-bit frames (`Ok(None)` otherwise;
    /// use [`merge`] then). Checks the bracket exactly as [`merge`] does.
    pub fn new(
        frames: &[BracketFrame<'a>],
        response: &InverseResponse,
        weighting: Weighting,
    ) -> Result<Option<PairMerge<'a>>, MergeError> {
        check(frames, response)?;
        if frames.len() != 2 {
            return Ok(None);
        }
        let (order, exposures) = exposure_order(frames);
        let Codes::Eight(codes) = Codes::of(frames, &order) else {
            return Ok(None);
        };
        let (d, b) = (codes[0], codes[1]);
        let first = frames[0].frame;
        let tables = Tables::new(
            &exposures,
            response,
            first.channels(),
            BitDepth::Eight,
            weighting,
        );
        let table = PairTable::new(&tables);
        let clipped = count_clipped(d, b, &table);
        Ok(Some(PairMerge {
            dark: d,
            bright: b,
            table,
            width: first.width(),
            height: first.height(),
            bracket: BracketOrder {
                order,
                exposures,
                clipped_high: clipped.high,
                clipped_low: clipped.low,
            },
        }))
    }

    /// Width in pixels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// 1 (grey) or 3 (RGB).
    pub fn channels(&self) -> usize {
        self.table.channels
    }

    /// Radiance of channel `channel` of pixel `pixel` (row-major index).
    #[inline]
    pub fn sample(&self, pixel: usize, channel: usize) -> f32 {
        let i = pixel * self.table.channels + channel;
        self.table.value[self.table.index(channel, self.dark[i], self.bright[i])]
    }

    /// The `out.len()/channels` whole pixels from `pixel` on, channels interleaved: one
    /// table lookup per sample.
    #[inline]
    pub(crate) fn pixels_into(&self, pixel: usize, out: &mut [f32]) {
        let codes = pixel * self.table.channels..pixel * self.table.channels + out.len();
        gather_pair(
            &self.dark[codes.clone()],
            &self.bright[codes],
            &self.table,
            out,
        );
    }

    /// The frames' codes and the table by code pair ([`CodePairs`]).
    pub(crate) fn code_pairs(&self) -> CodePairs<'_> {
        CodePairs {
            dark: self.dark,
            bright: self.bright,
            channels: self.table.channels,
            values: &self.table.value,
        }
    }

    /// The largest value any sample can take (over all code pairs), an upper bound of the
    /// image's maximum: `e_max/e_min` for the sRGB-like responses (clipped high).
    pub(crate) fn max_value(&self) -> f32 {
        self.table.value.iter().copied().fold(0.0, f32::max)
    }

    /// Multiplies every value by `factor` (a change of scale, see [`exposure_scale`]).
    pub(crate) fn scale_by(&mut self, factor: f32) {
        for v in &mut self.table.value {
            *v *= factor;
        }
    }

    /// Evaluates every sample into a [`RadianceMap`] (rows in parallel).
    #[cfg(test)]
    fn to_map(&self) -> RadianceMap {
        let mut pixels = vec![0.0f32; self.dark.len()];
        fill_pair(
            self.dark,
            self.bright,
            &self.table,
            self.width as usize,
            &mut pixels,
        );
        RadianceMap::new(self.width, self.height, self.table.channels, pixels)
            .expect("buffer sized from the frames")
    }
}

impl RadianceSource for PairMerge<'_> {
    fn width(&self) -> u32 {
        PairMerge::width(self)
    }
    fn height(&self) -> u32 {
        PairMerge::height(self)
    }
    fn channels(&self) -> usize {
        PairMerge::channels(self)
    }
    #[inline]
    fn sample(&self, pixel: usize, channel: usize) -> f32 {
        PairMerge::sample(self, pixel, channel)
    }
    fn max_value(&self) -> f32 {
        PairMerge::max_value(self)
    }
    #[inline]
    fn pixels_into(&self, pixel: usize, out: &mut [f32]) {
        PairMerge::pixels_into(self, pixel, out)
    }
    fn code_pairs(&self) -> Option<CodePairs<'_>> {
        Some(PairMerge::code_pairs(self))
    }
}

impl RadianceSource for BracketMerge<'_> {
    fn width(&self) -> u32 {
        BracketMerge::width(self)
    }
    fn height(&self) -> u32 {
        BracketMerge::height(self)
    }
    fn channels(&self) -> usize {
        BracketMerge::channels(self)
    }
    #[inline]
    fn sample(&self, pixel: usize, channel: usize) -> f32 {
        BracketMerge::sample(self, pixel, channel)
    }
    #[inline]
    fn line(&self, pixel: usize, channel: usize, out: &mut [f32]) {
        BracketMerge::line(self, pixel, channel, out)
    }
    /// The tables' bound ([`BracketMerge::max_bound`]).
    fn max_value(&self) -> f32 {
        self.max_bound()
    }
    /// One more pass over the frames' codes ([`BracketMerge::max_value`]), so that half
    /// overflow is handled exactly as for the merged map.
    fn exact_max(&self) -> f32 {
        BracketMerge::max_value(self)
    }
}

/// The sorted frames' codes, borrowed from the frames.
enum Codes<'a> {
    Eight(Vec<&'a [u8]>),
    Sixteen(Vec<&'a [u16]>),
}

impl<'a> Codes<'a> {
    /// The codes of `frames` in `order`, at the first frame's depth (the bracket is
    /// checked to share one before).
    fn of(frames: &[BracketFrame<'a>], order: &[usize]) -> Codes<'a> {
        let sample = |i: usize| frames[i].frame.samples();
        match frames[0].frame.bit_depth() {
            BitDepth::Eight => Codes::Eight(
                order
                    .iter()
                    .map(|&i| match sample(i) {
                        Samples::Eight(v) => v.as_slice(),
                        Samples::Sixteen(_) => unreachable!("depth checked"),
                    })
                    .collect(),
            ),
            BitDepth::Sixteen => Codes::Sixteen(
                order
                    .iter()
                    .map(|&i| match sample(i) {
                        Samples::Sixteen(v) => v.as_slice(),
                        Samples::Eight(_) => unreachable!("depth checked"),
                    })
                    .collect(),
            ),
        }
    }
}

/// Pixels of one line merged at a time by [`BracketMerge::line`]: the weighted sums live
/// on the stack (2 KB).
const RUN: usize = 256;

/// A merge of any bracket evaluated a line at a time on demand, never held as a whole
/// image: an encoder pulls [`BracketMerge::line`] while it writes (a PIZ block of 32
/// lines at a time on each thread), which saves the `f32` radiance buffer (12 bytes per
/// RGB pixel). Per sample it sums `w_k(code_k)` and `w_k(code_k)·x_k(code_k)` over the
/// frames from the per-frame, per-channel tables of [`merge`], darkest first, and divides
/// (or applies the clipped-everywhere rule), so the values are exactly those of
/// [`merge`]. For two 8-bit frames [`PairMerge`] is faster (one lookup a sample).
pub struct BracketMerge<'a> {
    codes: Codes<'a>,
    masks: Vec<Option<&'a [u8]>>,
    bound: Option<Bound>,
    tables: Tables,
    factor: f32,
    width: u32,
    height: u32,
    /// The frames' order and what was clipped in all of them.
    pub bracket: BracketOrder,
}

impl<'a> BracketMerge<'a> {
    /// Prepares the merge of `frames` (any number ≥ 2, 8- or 16-bit): checks the bracket
    /// exactly as [`merge`] does, builds the tables and counts the clipped samples (one
    /// pass over the darkest frame's codes, and the others' only where it is clipped).
    #[cfg(test)]
    pub fn new(
        frames: &[BracketFrame<'a>],
        response: &InverseResponse,
        weighting: Weighting,
    ) -> Result<BracketMerge<'a>, MergeError> {
        BracketMerge::masked(frames, response, weighting, &Masks::default())
    }

    /// [`BracketMerge::new`] with a weight mask per frame, as [`merge_masked`] takes them:
    /// the values are exactly those of [`merge_masked`].
    pub(crate) fn masked(
        frames: &[BracketFrame<'a>],
        response: &InverseResponse,
        weighting: Weighting,
        masks: &Masks<'a>,
    ) -> Result<BracketMerge<'a>, MergeError> {
        check(frames, response)?;
        let (order, exposures) = exposure_order(frames);
        let bound = Bound::of(&order, masks);
        let masks = sorted_masks(frames, &order, &masks.weights)?;
        let first = frames[0].frame;
        let depth = first.bit_depth();
        let tables = Tables::new(&exposures, response, first.channels(), depth, weighting);
        let codes = Codes::of(frames, &order);
        let clipped = match &codes {
            _ if masks.iter().any(Option::is_some) => count_clipped_masked(&codes, &tables, &masks),
            Codes::Eight(c) => count_clipped_everywhere(c, &tables),
            Codes::Sixteen(c) => count_clipped_everywhere(c, &tables),
        };
        Ok(BracketMerge {
            codes,
            masks,
            bound,
            tables,
            factor: 1.0,
            width: first.width(),
            height: first.height(),
            bracket: BracketOrder {
                order,
                exposures,
                clipped_high: clipped.high,
                clipped_low: clipped.low,
            },
        })
    }

    /// Width in pixels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// 1 (grey) or 3 (RGB).
    pub fn channels(&self) -> usize {
        self.tables.channels
    }

    /// Multiplies every value by `factor` (a change of scale, see [`exposure_scale`]),
    /// applied to each merged value as [`merge`]'s caller applies it to the map.
    pub(crate) fn scale_by(&mut self, factor: f32) {
        self.factor *= factor;
    }

    /// Radiance of channel `channel` of pixel `pixel` (row-major index).
    pub fn sample(&self, pixel: usize, channel: usize) -> f32 {
        let i = pixel * self.tables.channels + channel;
        let kept = |k| kept(&self.masks, k, pixel);
        let code = |k: usize| match &self.codes {
            Codes::Eight(f) => f[k][i].into(),
            Codes::Sixteen(f) => f[k][i].into(),
        };
        let (Estimate::Weighted(v, _) | Estimate::High(v) | Estimate::Low(v)) =
            estimate(&self.tables, channel, code, kept);
        self.left_out()
            .hold(&self.tables, (pixel, channel), code, v)
            * self.factor
    }

    /// The sorted masks and the reference's bound.
    fn left_out(&self) -> Masked<'_> {
        Masked {
            weights: &self.masks,
            bound: self.bound,
        }
    }

    /// Channel `channel` of the `out.len()` pixels from `pixel` on (one line or part of
    /// one), frame by frame over runs of 256 pixels.
    pub fn line(&self, pixel: usize, channel: usize, out: &mut [f32]) {
        match &self.codes {
            Codes::Eight(f) => self.line_of(f, pixel, channel, out),
            Codes::Sixteen(f) => self.line_of(f, pixel, channel, out),
        }
    }

    fn line_of<T: Copy + Into<usize>>(
        &self,
        frames: &[&[T]],
        pixel: usize,
        channel: usize,
        out: &mut [f32],
    ) {
        let t = &self.tables;
        let channels = t.channels;
        for (run, out) in out.chunks_mut(RUN).enumerate() {
            let first = pixel + run * RUN;
            let start = first * channels + channel;
            let (mut num, mut den) = ([0f32; RUN], [0f32; RUN]);
            let (mut lost_num, mut lost_den) = ([0f32; RUN], [0f32; RUN]);
            for (k, codes) in frames.iter().enumerate() {
                let table = &t.weighted[t.index(k, channel, 0)..t.index(k, channel, t.levels)];
                let codes = codes[start..].iter().step_by(channels).take(out.len());
                let sums = num.iter_mut().zip(&mut den).zip(codes);
                let mask = self.masks[k].map(|m| &m[first..first + out.len()]);
                match mask.filter(|m| !all_kept(m)) {
                    None => {
                        for ((n, d), &code) in sums {
                            let [w, wx] = table[code.into()];
                            *n += wx;
                            *d += w;
                        }
                    }
                    Some(mask) => {
                        let lost = lost_num.iter_mut().zip(&mut lost_den);
                        for ((((n, d), &code), &m), (ln, ld)) in sums.zip(mask).zip(lost) {
                            let [w, wx] = table[code.into()];
                            let m = f32::from(m) / 255.0;
                            *n += m * wx;
                            *d += m * w;
                            *ln += (1.0 - m) * wx;
                            *ld += (1.0 - m) * w;
                        }
                    }
                }
            }
            for (j, v) in out.iter_mut().enumerate() {
                let value = if den[j] > 0.0 {
                    num[j] / den[j]
                } else {
                    // Clipped in every kept frame: the rule of `estimate`.
                    let i = start + j * channels;
                    let (dark, bright) = kept_ends(t.frames, |k| kept(&self.masks, k, first + j));
                    let dark_code: usize = frames[dark][i].into();
                    if t.clipped_high(dark_code) {
                        t.value[t.index(dark, channel, dark_code)]
                    } else if lost_den[j] > 0.0 {
                        // Black in every kept frame but seen by a masked one (`estimate`).
                        lost_num[j] / lost_den[j]
                    } else {
                        t.value[t.index(bright, channel, frames[bright][i].into())]
                    }
                };
                let code = |k: usize| frames[k][start + j * channels].into();
                *v = self.left_out().hold(t, (first + j, channel), code, value) * self.factor;
            }
        }
    }

    /// An upper bound of every value, from the tables alone: the largest `x_k(code)`
    /// (a weighted mean never exceeds its largest term; the clipped rules take a term),
    /// raised by 10⁻⁵ for the rounding of the `f32` sums.
    pub(crate) fn max_bound(&self) -> f32 {
        let largest = self.tables.value.iter().copied().fold(0.0, f32::max);
        largest * self.factor * (1.0 + 1e-5)
    }

    /// The largest finite value of the image: one pass over the whole merge, rows in
    /// parallel, nothing held.
    pub(crate) fn max_value(&self) -> f32 {
        let width = self.width as usize;
        (0..self.height as usize)
            .into_par_iter()
            .map(|y| {
                let mut line = vec![0f32; width];
                let mut max = 0f32;
                for c in 0..self.channels() {
                    self.line(y * width, c, &mut line);
                    max = line
                        .iter()
                        .copied()
                        .filter(|v| v.is_finite())
                        .fold(max, f32::max);
                }
                max
            })
            .reduce(|| 0.0, f32::max)
    }

    /// Evaluates every sample into a [`RadianceMap`] (rows in parallel).
    #[cfg(test)]
    fn to_map(&self) -> RadianceMap {
        let (width, channels) = (self.width as usize, self.channels());
        let mut pixels = vec![0.0f32; width * self.height as usize * channels];
        pixels
            .par_chunks_mut(width * channels)
            .enumerate()
            .for_each(|(y, row)| {
                let mut line = vec![0f32; width];
                for c in 0..channels {
                    self.line(y * width, c, &mut line);
                    for (o, &v) in row[c..].iter_mut().step_by(channels).zip(&line) {
                        *o = v;
                    }
                }
            });
        RadianceMap::new(self.width, self.height, channels, pixels)
            .expect("buffer sized from the frames")
    }
}

/// Samples clipped high and low in every kept frame under weight `masks` (sorted): every
/// sample's estimate, rows in parallel.
fn count_clipped_masked(codes: &Codes<'_>, tables: &Tables, masks: &[Option<&[u8]>]) -> ClipCount {
    fn count<T: Copy + Into<usize> + Sync>(
        frames: &[&[T]],
        tables: &Tables,
        masks: &[Option<&[u8]>],
    ) -> ClipCount {
        let channels = tables.channels;
        (0..frames[0].len() / channels)
            .into_par_iter()
            .map(|p| {
                let mut clipped = ClipCount::default();
                for c in 0..channels {
                    let code = |k: usize| frames[k][p * channels + c].into();
                    clipped.add(estimate(tables, c, code, |k| kept(masks, k, p)).clip());
                }
                clipped
            })
            .reduce(ClipCount::default, ClipCount::plus)
    }
    match codes {
        Codes::Eight(c) => count(c, tables, masks),
        Codes::Sixteen(c) => count(c, tables, masks),
    }
}

/// Whether a pixel of a [`ClipMap`] was exposed well by some frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Clip {
    /// Some frame exposed it well.
    Measured,
    /// Clipped high in every frame (a lower bound of its radiance).
    High,
    /// Clipped low in every frame, and not high (an upper bound).
    Low,
}

/// Where no frame of a bracket exposed the scene well, at a reduced size.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ClipMap {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Per pixel, rows top down.
    pub clips: Vec<Clip>,
}

impl ClipMap {
    /// True when some pixel is clipped in every frame.
    pub fn any(&self) -> bool {
        self.clips.iter().any(|&c| c != Clip::Measured)
    }
}

/// Where the merge of `frames` through `response` under `weighting` had no well-exposed
/// frame (the "clipped everywhere" rule of the module docs, without deghosting's masks),
/// within `edge` pixels: the frame reduced by `f = ⌈long edge / edge⌉`, each map pixel
/// covering `f × f` frame pixels of which every `⌈f/4⌉`-th of each row and column is read.
/// A frame pixel is [`Clip::High`] when one of its samples is clipped high in every frame,
/// else [`Clip::Low`] when one is clipped low in every frame; a map pixel takes the class
/// of at least half of the pixels it read (high first), else [`Clip::Measured`].
pub fn clip_map(
    frames: &[BracketFrame<'_>],
    response: &InverseResponse,
    weighting: Weighting,
    edge: u32,
) -> Result<ClipMap, MergeError> {
    check(frames, response)?;
    let (order, exposures) = exposure_order(frames);
    let first = frames[0].frame;
    let tables = Tables::new(
        &exposures,
        response,
        first.channels(),
        first.bit_depth(),
        weighting,
    );
    let (width, height) = (first.width() as usize, first.height() as usize);
    let f = width.max(height).div_ceil(edge.max(1) as usize).max(1);
    Ok(match Codes::of(frames, &order) {
        Codes::Eight(c) => reduce_clips(&c, &tables, width, height, f),
        Codes::Sixteen(c) => reduce_clips(&c, &tables, width, height, f),
    })
}

/// [`clip_map`] on the codes, darkest frame first, reduced by `f`.
fn reduce_clips<T: Copy + Into<usize> + Sync>(
    frames: &[&[T]],
    tables: &Tables,
    width: usize,
    height: usize,
    f: usize,
) -> ClipMap {
    let channels = tables.channels;
    let clip_of = |pixel: usize| {
        let mut low = false;
        for c in 0..channels {
            let i = pixel * channels + c;
            if (0..tables.frames).all(|k| tables.clipped(k, c, frames[k][i].into())) {
                if tables.clipped_high(frames[0][i].into()) {
                    return Clip::High;
                }
                low = true;
            }
        }
        if low { Clip::Low } else { Clip::Measured }
    };
    let (map_w, map_h) = (width.div_ceil(f), height.div_ceil(f));
    let stride = f.div_ceil(4);
    let clips = (0..map_h)
        .into_par_iter()
        .flat_map_iter(|my| {
            (0..map_w).map(move |mx| {
                let (mut high, mut low, mut read) = (0usize, 0usize, 0usize);
                for y in (my * f..((my + 1) * f).min(height)).step_by(stride) {
                    for x in (mx * f..((mx + 1) * f).min(width)).step_by(stride) {
                        read += 1;
                        match clip_of(y * width + x) {
                            Clip::High => high += 1,
                            Clip::Low => low += 1,
                            Clip::Measured => {}
                        }
                    }
                }
                if high > 0 && 2 * high >= read {
                    Clip::High
                } else if low > 0 && 2 * low >= read {
                    Clip::Low
                } else {
                    Clip::Measured
                }
            })
        })
        .collect();
    ClipMap {
        width: map_w as u32,
        height: map_h as u32,
        clips,
    }
}

/// Samples clipped high and low in every frame ([`Tables::clipped`],
/// [`Tables::clipped_high`]): the darkest frame's code decides most samples, the
/// brightest's most of the rest, the others are read only where both are clipped.
fn count_clipped_everywhere<T: Copy + Into<usize> + Sync>(
    frames: &[&[T]],
    tables: &Tables,
) -> ClipCount {
    let (channels, last) = (tables.channels, tables.frames - 1);
    let chunk = channels << 14;
    frames[0]
        .par_chunks(chunk)
        .enumerate()
        .map(|(n, dark)| {
            let mut clipped = ClipCount::default();
            for (p, pixel) in dark.chunks_exact(channels).enumerate() {
                for (c, &code) in pixel.iter().enumerate() {
                    if !tables.clipped(0, c, code.into()) {
                        continue;
                    }
                    let i = n * chunk + p * channels + c;
                    if !tables.clipped(last, c, frames[last][i].into())
                        || (1..last).any(|k| !tables.clipped(k, c, frames[k][i].into()))
                    {
                        continue;
                    }
                    if tables.clipped_high(code.into()) {
                        clipped.high += 1;
                    } else {
                        clipped.low += 1;
                    }
                }
            }
            clipped
        })
        .reduce(ClipCount::default, ClipCount::plus)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The EXR header's `filmbackWeighting` and `--json` spell a weighting alike.
    #[test]
    fn a_weighting_has_one_name() {
        for w in [Weighting::Hat, Weighting::NoiseAware] {
            assert_eq!(serde_json::to_value(w).unwrap(), w.name());
        }
    }

    fn grey(width: u32, codes: Vec<u8>) -> Frame {
        let h = codes.len() as u32 / width;
        Frame::new(width, h, 1, Samples::Eight(codes)).unwrap()
    }

    fn linear() -> InverseResponse {
        InverseResponse::from_samples(vec![vec![0.0, 1.0]]).unwrap()
    }

    fn bracket<'a>(frames: &'a [(Frame, f64)], camera: &'a Camera) -> Vec<BracketFrame<'a>> {
        frames
            .iter()
            .map(|(frame, exposure)| BracketFrame {
                source: Path::new("frame"),
                frame,
                exposure: *exposure,
                camera,
            })
            .collect()
    }

    #[test]
    fn consistent_frames_give_the_common_radiance_in_any_order() {
        // Linear response, ratio 4: code 40 at e=1 and code 160 at e=4 both mean
        // radiance 160/255 relative to the longest frame.
        let cam = Camera::default();
        let frames = [(grey(2, vec![160, 160]), 4.0), (grey(2, vec![40, 40]), 1.0)];
        let merged = merge(&bracket(&frames, &cam), &linear(), MergeOptions::default()).unwrap();
        assert_eq!(merged.bracket.order, vec![1, 0]);
        for &v in merged.radiance.pixels() {
            assert!((v - 160.0 / 255.0).abs() < 1e-6, "{v}");
        }
        assert_eq!(merged.bracket.ratio(), 4.0);
    }

    #[test]
    fn clipped_everywhere_takes_the_bounding_frame() {
        let cam = Camera::default();
        let frames = [(grey(2, vec![255, 0]), 1.0), (grey(2, vec![255, 0]), 4.0)];
        let options = MergeOptions {
            confidence: true,
            ..MergeOptions::default()
        };
        let merged = merge(&bracket(&frames, &cam), &linear(), options).unwrap();
        // Clipped high: darkest frame's g(1)·e_ref/e_0 = 4. Clipped low: brightest's g(0) = 0.
        assert_eq!(merged.radiance.pixels(), &[4.0, 0.0]);
        assert_eq!(
            (merged.bracket.clipped_high, merged.bracket.clipped_low),
            (1, 1)
        );
        assert_eq!(merged.confidence.unwrap(), vec![0.0, 0.0]);
    }

    /// An 8 × 4 bracket whose left half is clipped high in both frames, top right
    /// quarter clipped low in both and bottom right exposed well in one: reduced to 4 × 2
    /// (each map pixel two by two frame pixels), and to 1 × 1 (more high than not).
    #[test]
    fn the_clip_map_shows_where_no_frame_exposed_well() {
        let cam = Camera::default();
        let codes = |right_bottom: u8| -> Vec<u8> {
            (0..4)
                .flat_map(|y| (0..8).map(move |x| (x, y)))
                .map(|(x, y)| match (x < 4, y < 2) {
                    (true, _) => 255,
                    (false, true) => 0,
                    (false, false) => right_bottom,
                })
                .collect()
        };
        let frames = [(grey(8, codes(0)), 1.0), (grey(8, codes(128)), 4.0)];
        let b = bracket(&frames, &cam);
        let map = clip_map(&b, &linear(), Weighting::Hat, 4).unwrap();
        assert_eq!((map.width, map.height), (4, 2));
        use Clip::{High, Low, Measured};
        assert_eq!(
            map.clips,
            vec![High, High, Low, Low, High, High, Measured, Measured]
        );
        assert!(map.any());
        let one = clip_map(&b, &linear(), Weighting::Hat, 1).unwrap();
        assert_eq!(one.clips, vec![High]);
        let measured = [(grey(8, vec![128; 32]), 1.0), (grey(8, vec![200; 32]), 4.0)];
        let none = clip_map(&bracket(&measured, &cam), &linear(), Weighting::Hat, 4).unwrap();
        assert!(!none.any());
    }

    #[test]
    fn noise_aware_prefers_the_longer_exposure() {
        let cam = Camera::default();
        // The frames disagree (as noise would make them): the longer one should win.
        let frames = [(grey(1, vec![64]), 1.0), (grey(1, vec![200]), 4.0)];
        let b = bracket(&frames, &cam);
        let long = 200.0 / 255.0;
        let hat = merge(&b, &linear(), MergeOptions::default()).unwrap();
        let noise = merge(
            &b,
            &linear(),
            MergeOptions {
                weighting: Weighting::NoiseAware,
                ..MergeOptions::default()
            },
        )
        .unwrap();
        let (h, n) = (hat.radiance.pixels()[0], noise.radiance.pixels()[0]);
        assert!((n - long).abs() < (h - long).abs(), "hat {h} noise {n}");
    }

    #[test]
    fn refuses_bad_brackets_naming_files() {
        let cam = Camera::default();
        let a = grey(2, vec![1, 2]);
        let b = grey(1, vec![1, 2]);
        let frames = [
            BracketFrame {
                source: Path::new("a.jpg"),
                frame: &a,
                exposure: 1.0,
                camera: &cam,
            },
            BracketFrame {
                source: Path::new("b.jpg"),
                frame: &b,
                exposure: 2.0,
                camera: &cam,
            },
        ];
        let err = merge(&frames, &linear(), MergeOptions::default()).unwrap_err();
        let text = err.to_string();
        assert!(text.contains("a.jpg") && text.contains("b.jpg"), "{text}");
        assert!(matches!(
            merge(&frames[..1], &linear(), MergeOptions::default()),
            Err(MergeError::TooFewFrames(1))
        ));
        let same = [
            frames[0],
            BracketFrame {
                frame: &a,
                ..frames[0]
            },
        ];
        assert!(matches!(
            merge(&same, &linear(), MergeOptions::default()),
            Err(MergeError::SingleExposure { .. })
        ));
        let other_cam = Camera {
            model: Some("X".into()),
            ..Camera::default()
        };
        let cam_a = Camera {
            model: Some("Y".into()),
            ..Camera::default()
        };
        let two = [
            BracketFrame {
                camera: &cam_a,
                ..frames[0]
            },
            BracketFrame {
                frame: &a,
                camera: &other_cam,
                ..frames[1]
            },
        ];
        let err = merge(&two, &linear(), MergeOptions::default()).unwrap_err();
        assert!(matches!(err, MergeError::CameraMismatch { .. }), "{err}");
        let bad = [
            frames[0],
            BracketFrame {
                frame: &a,
                exposure: f64::NAN,
                ..frames[1]
            },
        ];
        assert!(matches!(
            merge(&bad, &linear(), MergeOptions::default()),
            Err(MergeError::BadExposure { .. })
        ));
    }

    #[test]
    fn sixteen_bit_frames_use_all_levels() {
        let cam = Camera::default();
        let f = |v: u16| Frame::new(1, 1, 1, Samples::Sixteen(vec![v])).unwrap();
        let frames = [(f(1000), 1.0), (f(4000), 4.0)];
        let merged = merge(&bracket(&frames, &cam), &linear(), MergeOptions::default()).unwrap();
        let v = merged.radiance.pixels()[0];
        assert!((v - 4000.0 / 65535.0).abs() < 1e-6, "{v}");
    }

    /// `n` RGB frames of an odd `width × height` (17 × 45: not a whole number of PIZ
    /// blocks or merge runs) one stop apart, of a scene spanning 34 stops with a gamma
    /// 2.2 response and a little pseudo-random noise, so that some samples are clipped
    /// high or low in every frame; 8-bit, or 16-bit when `sixteen`.
    fn exposed(n: usize, sixteen: bool) -> Vec<(Frame, f64)> {
        let (width, height) = (17u32, 45u32);
        let samples = (width * height * 3) as usize;
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut noise = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let scene: Vec<f64> = (0..samples)
            .map(|i| 2f64.powf(34.0 * i as f64 / samples as f64 - 28.0))
            .collect();
        (0..n)
            .map(|k| {
                let e = 2f64.powi(k as i32);
                let level = |r: f64, max: f64| (max * (r * e).min(1.0).powf(1.0 / 2.2)).round();
                let samples = if sixteen {
                    Samples::Sixteen(
                        scene
                            .iter()
                            .map(|&r| {
                                (level(r, 65535.0) + 40.0 * noise()).clamp(0.0, 65535.0) as u16
                            })
                            .collect(),
                    )
                } else {
                    Samples::Eight(
                        scene
                            .iter()
                            .map(|&r| (level(r, 255.0) + 2.0 * noise()).clamp(0.0, 255.0) as u8)
                            .collect(),
                    )
                };
                (Frame::new(width, height, 3, samples).unwrap(), e)
            })
            .collect()
    }

    #[test]
    fn bracket_merge_equals_the_merged_map_bit_for_bit() {
        let cam = Camera::default();
        let g = InverseResponse::srgb(3, 1024);
        for (n, sixteen) in [(3, false), (5, false), (3, true)] {
            let mut frames = exposed(n, sixteen);
            // Out of order, as a bracket may arrive.
            frames.swap(0, n - 1);
            for weighting in [Weighting::Hat, Weighting::NoiseAware] {
                let b = bracket(&frames, &cam);
                let options = MergeOptions {
                    weighting,
                    ..MergeOptions::default()
                };
                let map = merge(&b, &g, options).unwrap();
                let mut lazy = BracketMerge::new(&b, &g, weighting).unwrap();
                let case = format!("{n} frames, 16-bit {sixteen}, {weighting:?}");
                assert_eq!(lazy.to_map(), map.radiance, "{case}");
                assert_eq!(lazy.bracket.order, map.bracket.order, "{case}");
                assert_eq!(
                    (lazy.bracket.clipped_high, lazy.bracket.clipped_low),
                    (map.bracket.clipped_high, map.bracket.clipped_low),
                    "{case}"
                );
                assert!(
                    lazy.bracket.clipped_high > 0 && (sixteen || lazy.bracket.clipped_low > 0),
                    "{case}"
                );
                assert_eq!(lazy.sample(700, 2), map.radiance.pixels()[700 * 3 + 2]);
                let max = map.radiance.pixels().iter().copied().fold(0.0, f32::max);
                assert_eq!(lazy.max_value(), max, "{case}");
                assert!(lazy.max_bound() >= max, "{case}");
                // A change of scale multiplies each merged value, as on the map.
                lazy.scale_by(3.7);
                let scaled: Vec<f32> = map.radiance.pixels().iter().map(|v| v * 3.7).collect();
                assert_eq!(lazy.to_map().pixels(), &scaled[..], "{case}");
            }
        }
    }

    #[test]
    fn pair_table_matches_the_general_path() {
        let cam = Camera::default();
        // Every code pair once, so every table entry is compared.
        let (dark, bright): (Vec<u8>, Vec<u8>) = (0..65536u32)
            .map(|i| ((i >> 8) as u8, (i & 0xff) as u8))
            .unzip();
        let frame = |v: Vec<u8>| Frame::new(256, 256, 1, Samples::Eight(v)).unwrap();
        let frames = [(frame(dark), 0.5), (frame(bright), 2.0)];
        let g = InverseResponse::srgb(1, 1024);
        for weighting in [Weighting::Hat, Weighting::NoiseAware] {
            let run = |confidence| {
                let options = MergeOptions {
                    weighting,
                    confidence,
                    ..MergeOptions::default()
                };
                merge(&bracket(&frames, &cam), &g, options).unwrap()
            };
            let (fast, general) = (run(false), run(true));
            assert_eq!(fast.radiance, general.radiance, "{weighting:?}");
            assert_eq!(
                (fast.bracket.clipped_high, fast.bracket.clipped_low),
                (general.bracket.clipped_high, general.bracket.clipped_low)
            );
            assert_eq!(
                (fast.bracket.clipped_high, fast.bracket.clipped_low),
                (2, 2),
                "high: (255, 255), (255, 0); low: (0, 0), (0, 255)"
            );
            assert!(fast.radiance.pixels().iter().all(|v| v.is_finite()));
            let lazy = PairMerge::new(&bracket(&frames, &cam), &g, weighting)
                .unwrap()
                .unwrap();
            assert_eq!(lazy.to_map(), fast.radiance);
            assert_eq!(
                (lazy.bracket.clipped_high, lazy.bracket.clipped_low),
                (2, 2)
            );
            assert_eq!(lazy.sample(300, 0), fast.radiance.pixels()[300]);
            assert!(lazy.max_value() >= fast.radiance.pixels().iter().copied().fold(0.0, f32::max));
        }
    }

    /// Grey `frames` (exposed as given) merged with `mask` on frame 1, frame 2 the
    /// reference (8-bit codes 6 to 242 measured): the buffered merge's values, the banded
    /// merge's line by line and sample by sample, and the plain merge's.
    fn merged_with_mask(frames: &[(Frame, f64)], mask: &[u8]) -> [Vec<f32>; 4] {
        let cam = Camera::default();
        let w = frames[0].0.width() as usize;
        let masks = Masks {
            weights: vec![None, Some(mask), None],
            reference: 2,
            measured: (6, 242),
        };
        let b = bracket(frames, &cam);
        let options = MergeOptions::default();
        let masked = merge_masked(&b, &linear(), options, &masks).unwrap();
        let plain = merge(&b, &linear(), options).unwrap();
        let banded = BracketMerge::masked(&b, &linear(), options.weighting, &masks).unwrap();
        let mut lines = vec![0.0f32; mask.len()];
        for (y, line) in lines.chunks_mut(w).enumerate() {
            banded.line(y * w, 0, line);
        }
        let samples = (0..mask.len()).map(|p| banded.sample(p, 0)).collect();
        let [masked, plain] = [masked, plain].map(|m| m.radiance.pixels().to_vec());
        [masked, lines, samples, plain]
    }

    /// Where a frame is left out, the reference's sample bounds the merge: a kept frame
    /// reading beyond that bound (a dark frame's view of what moved) is held to it, in
    /// the buffered and the banded merge; where no frame is left out, the same codes
    /// merge as without masks.
    #[test]
    fn where_a_frame_is_left_out_the_references_bound_holds() {
        // Frames exposed 1, 4 and 16 (the reference), linear, one pixel per column.
        // Pixels 0 and 1: the reference clipped high, the dark frame reading 10/255 × 16
        // = 0.63 at the reference's scale, below its bound 242/255 = 0.95; the middle
        // frame is left out of pixel 0 only. Pixel 2: the reference dark (code 2, bound
        // 6/255 from above), the dark frame reading 200/255 × 16 = 12.5, the middle
        // frame left out.
        let frames: Vec<(Frame, f64)> = [[10u8, 10, 200], [250, 250, 250], [255, 255, 2]]
            .iter()
            .zip([1.0, 4.0, 16.0])
            .map(|(codes, e)| (grey(3, codes.to_vec()), e))
            .collect();
        let [masked, lines, samples, plain] = merged_with_mask(&frames, &[0, 255, 0]);
        assert_eq!(lines, masked, "banded and buffered");
        assert_eq!(samples, masked, "sample by sample");
        let close = |a: f32, b: f32| (a - b).abs() <= 1e-6 * b;
        let [held, free, capped] = [masked[0], masked[1], masked[2]];
        assert!(close(held, 242.0 / 255.0), "pixel 0: {held}");
        assert_eq!(free, plain[1], "no frame left out at pixel 1");
        assert!(close(capped, 6.0 / 255.0), "pixel 2: {capped}");
    }

    /// Three frames 600 × 3 of unrelated codes (0 and 255 among them); frame 1's mask
    /// keeps row 0 whole, ramps over row 1 and leaves row 2 out; frame 2 is the reference.
    /// The buffered and the banded merge agree exactly, sample by sample too, and equal
    /// the plain merge on row 0 only.
    #[test]
    fn a_mask_weighs_its_rows_alike_in_every_merge() {
        let (w, h) = (600usize, 3usize);
        let codes = |k: usize| {
            (0..w * h)
                .map(|p| ((p * 37 + k * 53) % 256) as u8)
                .collect()
        };
        let frames: Vec<(Frame, f64)> = (0..3)
            .map(|k| (grey(w as u32, codes(k)), 4f64.powi(k as i32)))
            .collect();
        let mask: Vec<u8> = (0..w * h)
            .map(|p| match p / w {
                0 => 255,
                1 => (p % 256) as u8,
                _ => 0,
            })
            .collect();
        let [masked, lines, samples, plain] = merged_with_mask(&frames, &mask);
        for y in 0..h {
            let row = |v: &[f32]| v[y * w..(y + 1) * w].to_vec();
            assert_eq!(row(&lines), row(&masked), "row {y}: banded and buffered");
            assert_eq!(row(&samples), row(&masked), "row {y}: sample by sample");
            assert_eq!(row(&masked) == row(&plain), y == 0, "row {y}");
        }
    }
}
