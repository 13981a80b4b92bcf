//! The camera's inverse response `g = f⁻¹`: brightness `B ∈ [0, 1]` to relative exposure.
//!
//! [`InverseResponse`] is what every later stage consumes (merge, cache, daemon): per
//! channel, `g` sampled at `n` evenly spaced brightness values `B_i = i/(n−1)`, normalised
//! `g(0) = 0`, `g(1) = 1`, non-decreasing, evaluated between samples by linear
//! interpolation. How `g` was obtained (a fit, a cache, a default) is recorded beside it.
//!
//! [`calibrate`] recovers `g` from the histograms of two exposures of one scene
//! (`docs/design.md` §2): the tone pairs `b ↦ τ(b)` of [`crate::histogram::tone_pairs`] each
//! give `g(τ(b)) = γ·g(b)`, fitted per channel by [`mod@fit`]. [`save`] and [`load`] keep the
//! result in a versioned TOML file (see [`mod@file`]).

use std::borrow::Cow;

use rayon::prelude::*;

use crate::histogram::{FrameCounts, Histogram, TonePair, UsableTones, shared_counts, tone_pairs};

pub mod file;
pub mod fit;
pub mod measured;
pub mod pool;
pub mod spline;

pub use file::{ChannelSummary, ResponseFileError, ResponseRecord, load, save};
pub use fit::{ChannelFit, Degree, FitError};
pub use measured::{JpegMeter, MeasureError, MeasuredResponse, stops_apart};

/// Why an inverse response is not acceptable.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ResponseError {
    /// Not 1 or 3 channels, or fewer than two samples.
    #[error("inverse response needs 1 or 3 channels of at least 2 samples, got {0}")]
    Shape(String),
    /// A sample is NaN/∞, outside [0, 1], decreasing, or the ends are not 0 and 1.
    #[error("inverse response channel {channel}: {reason}")]
    Invalid {
        /// Channel index.
        channel: usize,
        /// What is wrong.
        reason: String,
    },
}

/// Per-channel sampled inverse response (see module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct InverseResponse {
    channels: Vec<Vec<f64>>,
}

impl InverseResponse {
    /// Validates per-channel samples `g(i/(n−1))`: finite, non-decreasing, `g(0)=0`, `g(1)=1`.
    pub fn from_samples(channels: Vec<Vec<f64>>) -> Result<InverseResponse, ResponseError> {
        if !(channels.len() == 1 || channels.len() == 3) || channels.iter().any(|c| c.len() < 2) {
            return Err(ResponseError::Shape(format!(
                "{} channels of lengths {:?}",
                channels.len(),
                channels.iter().map(Vec::len).collect::<Vec<_>>()
            )));
        }
        for (channel, g) in channels.iter().enumerate() {
            let bad = |reason: String| ResponseError::Invalid { channel, reason };
            if let Some(i) = g.iter().position(|v| !v.is_finite()) {
                return Err(bad(format!("sample {i} is not finite")));
            }
            if g[0] != 0.0 || g[g.len() - 1] != 1.0 {
                return Err(bad(format!(
                    "ends are {} and {}, must be 0 and 1",
                    g[0],
                    g[g.len() - 1]
                )));
            }
            if let Some(i) = g.windows(2).position(|w| w[1] < w[0]) {
                return Err(bad(format!("decreases between samples {i} and {}", i + 1)));
            }
        }
        Ok(InverseResponse { channels })
    }

    /// The inverse of the sRGB transfer function (IEC 61966-2-1), the usual response of a
    /// camera JPEG when nothing better is known:
    /// `g(B) = B/12.92` for `B ≤ 0.04045`, else `((B+0.055)/1.055)^2.4`.
    pub fn srgb(channels: usize, samples: usize) -> InverseResponse {
        let g = (0..samples)
            .map(|i| {
                let b = i as f64 / (samples - 1) as f64;
                if b <= 0.04045 {
                    b / 12.92
                } else {
                    ((b + 0.055) / 1.055).powf(2.4)
                }
            })
            .collect::<Vec<_>>();
        InverseResponse {
            channels: vec![g; channels],
        }
    }

    /// Number of channels (1 or 3).
    pub fn channels(&self) -> usize {
        self.channels.len()
    }

    /// The samples of channel `c`, `g(i/(n−1))`.
    pub fn samples(&self, c: usize) -> &[f64] {
        &self.channels[c]
    }

    /// `g(B)` for channel `c`, linear between samples; `B` is clamped to `[0, 1]`
    /// (NaN reads as 0).
    pub fn eval(&self, c: usize, b: f64) -> f64 {
        let g = &self.channels[c];
        let b = if b.is_nan() { 0.0 } else { b.clamp(0.0, 1.0) };
        let x = b * (g.len() - 1) as f64;
        let i = (x.floor() as usize).min(g.len() - 2);
        let f = x - i as f64;
        g[i] + (g[i + 1] - g[i]) * f
    }

    /// Lookup table for integer codes: `g(k/(levels−1))` for `k = 0..levels`.
    pub fn table(&self, c: usize, levels: usize) -> Vec<f32> {
        (0..levels)
            .map(|k| self.eval(c, k as f64 / (levels - 1) as f64) as f32)
            .collect()
    }
}

/// Number of samples per channel in a calibrated [`InverseResponse`] (`g(i/1023)`).
pub const CALIBRATED_SAMPLES: usize = 1024;

/// The prior used when the ratio must be estimated: `g(0.5)`, the relative radiance at
/// code 128 of a real camera's JPEG, 0.138 (mid grey 2.86 stops below white; the sRGB
/// curve's is 0.214, 2.22 stops). It is the value that makes the median estimate exact,
/// `exp(ln 0.214 / median κ_sRGB)`, over the tuning half of the real brackets
/// (`docs/accuracy.md`, "How good is the exposure ratio without EXIF?": 46 adjacent
/// pairs of seven sets from phones, a tablet, a compact and one unnamed body; the other
/// half is kept for reporting).
pub const PRIOR_MID_GREY: f64 = 0.1379;

/// How far the prior can be off: the 10th and 90th percentiles of
/// `κ = ln PRIOR_MID_GREY / ln g(0.5)` over the same tuning pairs. A curve with exponent
/// `κ` gives an estimate `γ̂ = γ^κ`, so for four pairs in five the true ratio lies in
/// `γ̂^(1/κ₉₀) ..= γ̂^(1/κ₁₀)` ([`Calibration::ratio_range`]).
pub(crate) const PRIOR_EXPONENTS: [f64; 2] = [0.800, 1.297];

/// Where the exposure ratio `γ = e_bright / e_dark` came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RatioSource {
    /// From the frames' EXIF exposures, `γ = (t·S/N²)_bright / (t·S/N²)_dark`.
    Exif,
    /// Given by the user.
    Argument,
    /// Estimated from the histograms with the prior [`PRIOR_MID_GREY`].
    Estimated,
}

impl RatioSource {
    /// `"exif"`, `"argument"` or `"estimated"`.
    pub fn as_str(self) -> &'static str {
        match self {
            RatioSource::Exif => "exif",
            RatioSource::Argument => "argument",
            RatioSource::Estimated => "estimated",
        }
    }
}

/// The exposure ratio to calibrate with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Ratio {
    /// A known `γ > 1` and where it came from.
    Known(f64, RatioSource),
    /// Estimate `γ`. `g` and `γ` trade off as `g^k, γ^k` (any power of a solution is a
    /// solution), so an estimate needs a prior: the one used here is that mid brightness
    /// `B = 0.5` is `g =` [`PRIOR_MID_GREY`] (0.1379) of white, a real camera's mid grey
    /// (the median over channels; the sRGB curve's is 0.214).
    Estimate,
}

/// Why two frames could not be calibrated.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CalibrationError {
    /// The exposure ratio is not a finite number above 1.
    #[error(
        "exposure ratio {0} is not usable: it must be a finite number above 1 (bright over dark)"
    )]
    Ratio(f64),
    /// The two histograms differ in channels or depth.
    #[error("the frames differ: {0}")]
    Mismatch(String),
    /// No channel could be fitted.
    #[error("no channel could be calibrated: {0}")]
    NoChannel(String),
    /// Every channel's fit failed: each channel's name and reason, in channel order.
    #[error("no channel could be calibrated: {}", fit_failures(.0))]
    Unfitted(Vec<(&'static str, FitError)>),
    /// The fitted curves do not make a valid inverse response.
    #[error("no channel could be calibrated: the fitted curve is not a valid response: {0}")]
    Curve(#[source] ResponseError),
    /// Every channel's tones run backwards: the frames or the ratio are swapped.
    #[error(
        "the brighter frame is darker than the darker one in most tones of every channel: frames or ratio swapped"
    )]
    Swapped,
    /// A channel's fit was refused (a degree out of range).
    #[error("channel {channel}: {source}")]
    Channel {
        /// Channel name.
        channel: &'static str,
        /// The fit's reason.
        source: FitError,
    },
}

/// `name: reason` for each channel, joined by "; ".
fn fit_failures(failures: &[(&'static str, FitError)]) -> String {
    failures
        .iter()
        .map(|(name, e)| format!("{name}: {e}"))
        .collect::<Vec<_>>()
        .join("; ")
}

/// One channel's calibration.
#[derive(Debug, Clone, PartialEq)]
pub struct ChannelCalibration {
    /// `"R"`, `"G"`, `"B"`, or `"Y"` for grey frames.
    pub name: &'static str,
    /// The fitted curve and its diagnostics.
    pub fit: ChannelFit,
    /// Set when this channel could not be fitted (no usable tones, e.g. saturated, or
    /// tones running backwards while other channels fit) and took the curve of another
    /// channel; its confidence is then 0.
    pub borrowed_from: Option<&'static str>,
    /// The tone pairs the fit used (empty when borrowed).
    pub pairs: Vec<TonePair>,
    /// `ln γ` of each entry of [`ChannelCalibration::pairs`]: one value for a pair of
    /// frames, the ratio of each frame pair for a bracket ([`calibrate_bracket`]).
    pub log_ratios: Vec<f64>,
    /// How many of [`ChannelCalibration::pairs`] each frame pair gave, in order (they
    /// partition the pairs; one entry for a pair of frames).
    pub set_lengths: Vec<usize>,
}

/// The result of [`calibrate`].
#[derive(Debug, Clone, PartialEq)]
pub struct Calibration {
    /// Exposure ratio `γ` used.
    pub ratio: f64,
    /// Where `γ` came from.
    pub ratio_source: RatioSource,
    /// Per channel.
    pub channels: Vec<ChannelCalibration>,
    /// The curves, sampled at [`CALIBRATED_SAMPLES`] points per channel.
    pub response: InverseResponse,
}

impl Calibration {
    /// For an estimated ratio, the range `γ̂^(1/κ₉₀) ..= γ̂^(1/κ₁₀)` that holds the true
    /// ratio for four camera curves in five ([`PRIOR_EXPONENTS`]); `None` when the ratio
    /// was known.
    pub fn ratio_range(&self) -> Option<(f64, f64)> {
        (self.ratio_source == RatioSource::Estimated).then(|| {
            let [lo, hi] = PRIOR_EXPONENTS;
            (self.ratio.powf(1.0 / hi), self.ratio.powf(1.0 / lo))
        })
    }
}

fn channel_names(channels: usize) -> &'static [&'static str] {
    if channels == 1 {
        &["Y"]
    } else {
        &["R", "G", "B"]
    }
}

/// Recovers the inverse response from the histograms of a darker and a brighter exposure
/// of one scene (`γ = e_bright/e_dark > 1`), per channel; see [`fit`] for the model.
///
/// A channel without usable tones (saturated, or a flat frame) borrows the most confident
/// other channel's curve with confidence 0; if no channel has usable tones it is an error.
pub fn calibrate(
    dark: &Histogram,
    bright: &Histogram,
    ratio: Ratio,
    degree: Degree,
) -> Result<Calibration, CalibrationError> {
    if dark.channels() != bright.channels() || dark.depth() != bright.depth() {
        return Err(CalibrationError::Mismatch(format!(
            "{} channels at {} bits against {} channels at {} bits",
            dark.channels(),
            dark.depth().bits(),
            bright.channels(),
            bright.depth().bits()
        )));
    }
    let log_ratio = match ratio {
        Ratio::Known(r, _) if r.is_finite() && r > 1.0 => r.ln(),
        Ratio::Known(r, _) => return Err(CalibrationError::Ratio(r)),
        Ratio::Estimate => 1.0,
    };
    let names = channel_names(dark.channels());
    // Channels are independent: fitted on all cores, errors reported in channel order.
    let mut fitted: Vec<(Result<ChannelFit, FitError>, Vec<TonePair>)> = (0..names.len())
        .into_par_iter()
        .map(|c| {
            let (a, b) = (dark.cumulative(c), bright.cumulative(c));
            let pairs = tone_pairs(
                &a,
                &b,
                UsableTones::detect(&a, dark.compression()),
                UsableTones::detect(&b, bright.compression()),
            );
            (fit::fit(&pairs, log_ratio, degree), pairs)
        })
        .collect();
    if let Some(e) = refusal(names.iter().copied().zip(fitted.iter().map(|(f, _)| f))) {
        return Err(e);
    }
    let (ratio, ratio_source) = match ratio {
        Ratio::Known(r, source) => (r, source),
        Ratio::Estimate => (estimate_ratio(&mut fitted, degree)?, RatioSource::Estimated),
    };
    let log_ratio = ratio.ln();
    let channels = assemble(
        names,
        fitted
            .into_iter()
            .map(|(f, pairs)| {
                let sets = ChannelSets {
                    log_ratios: vec![log_ratio; pairs.len()],
                    set_lengths: vec![pairs.len()],
                    pairs,
                };
                (f, sets)
            })
            .collect(),
    )?;
    finish(ratio, ratio_source, channels)
}

/// The ratio `γ = e^k` of a pair whose channels were `fitted` at `ln γ = 1`, with `k`
/// the median over the fitted channels of `ln PRIOR_MID_GREY / ln g(0.5)`; each fitted
/// channel is then fitted again at `ln γ = k`. Without a fitted channel it cannot be
/// estimated.
fn estimate_ratio(
    fitted: &mut [(Result<ChannelFit, FitError>, Vec<TonePair>)],
    degree: Degree,
) -> Result<f64, CalibrationError> {
    let mut per_channel: Vec<f64> = fitted
        .iter()
        .filter_map(|(f, _)| f.as_ref().ok())
        .map(|f| PRIOR_MID_GREY.ln() / f.log_g(0.5))
        .filter(|k| k.is_finite() && *k > 0.0)
        .collect();
    per_channel.sort_by(f64::total_cmp);
    let Some(&k) = per_channel.get(per_channel.len().saturating_sub(1) / 2) else {
        return Err(CalibrationError::NoChannel(
            "the ratio cannot be estimated: no channel has usable tones".into(),
        ));
    };
    // Refitted at the estimated ratio rather than scaled by `k`: the smoothness
    // floor depends on the ratio (see `fit`), so a fit at ratio e is not a fit
    // at e^k raised to the k-th power.
    fitted.par_iter_mut().for_each(|(f, pairs)| {
        if f.is_ok() {
            *f = fit::fit(pairs, k, degree);
        }
    });
    Ok(k.exp())
}

/// A channel's tone pairs as [`ChannelCalibration`] keeps them.
struct ChannelSets {
    pairs: Vec<TonePair>,
    log_ratios: Vec<f64>,
    set_lengths: Vec<usize>,
}

/// The channels' calibrations, in channel order, from their fits and tone pairs: a
/// fitted channel as it is; one that failed borrows the most confident fitted channel's
/// curve at confidence 0, without pairs. No fitted channel is an error giving each
/// channel's reason.
fn assemble(
    names: &[&'static str],
    fitted: Vec<(Result<ChannelFit, FitError>, ChannelSets)>,
) -> Result<Vec<ChannelCalibration>, CalibrationError> {
    let donor = fitted
        .iter()
        .enumerate()
        .filter_map(|(c, (f, _))| f.as_ref().ok().map(|f| (c, f.clone())))
        .max_by(|a, b| a.1.confidence.total_cmp(&b.1.confidence));
    let Some((donor_c, donor_fit)) = donor else {
        let failures = fitted
            .into_iter()
            .enumerate()
            .filter_map(|(c, (f, _))| f.err().map(|e| (names[c], e)))
            .collect();
        return Err(CalibrationError::Unfitted(failures));
    };
    Ok(fitted
        .into_iter()
        .enumerate()
        .map(|(c, (f, sets))| match f {
            Ok(fit) => ChannelCalibration {
                name: names[c],
                fit,
                borrowed_from: None,
                pairs: sets.pairs,
                log_ratios: sets.log_ratios,
                set_lengths: sets.set_lengths,
            },
            Err(_) => ChannelCalibration {
                name: names[c],
                fit: ChannelFit {
                    equations: 0,
                    coverage: 0.0,
                    confidence: 0.0,
                    ..donor_fit.clone()
                },
                borrowed_from: Some(names[donor_c]),
                pairs: Vec::new(),
                log_ratios: Vec::new(),
                set_lengths: Vec::new(),
            },
        })
        .collect())
}

/// Why a calibration is refused as a whole, from its channels' fits: a degree out of
/// range, or tones running backwards in **every** channel (the frames or the ratio are
/// swapped). A channel that runs backwards while others fit is a channel that cannot be
/// fitted (a scan's offset in one dye, say): it borrows a fitted channel's curve at
/// confidence 0, like a channel without usable tones.
fn refusal<'a>(
    mut fits: impl Iterator<Item = (&'static str, &'a Result<ChannelFit, FitError>)> + Clone,
) -> Option<CalibrationError> {
    if let Some((channel, Err(source))) = fits
        .clone()
        .find(|(_, f)| matches!(f, Err(FitError::Degree(_))))
    {
        return Some(CalibrationError::Channel {
            channel,
            source: source.clone(),
        });
    }
    fits.all(|(_, f)| matches!(f, Err(FitError::Swapped)))
        .then_some(CalibrationError::Swapped)
}

/// Brightness above which a channel's level is left alone: its fade to `g(1) = 1` starts
/// at its brightest tone or here, whichever is lower (the last code but one of 8 bits).
const BALANCE_TOP: f64 = 254.0 / 255.0;

/// Points, evenly spaced in brightness, at which the channels' levels are compared.
const BALANCE_POINTS: usize = 64;

/// The channels' balance where their equations are, not at white: per channel the
/// offset `o_c` (nats of `ln g`) subtracted from `ln g_c` up to its brightest tone.
///
/// Two frames fix each channel's curve only up to its level, which `g(1) = 1` sets by
/// extrapolating above the brightest tone the channel's equations reach (a few codes,
/// often tenths of a stop of exposure); the channels extrapolate differently, and their
/// difference is a colour cast over the whole map. Setting `g(1) = 1` in every channel
/// means "white that clips all channels at once is neutral"; the same convention is
/// applied here where it is measured: over the tones `[b_lo, b_hi]` that every fitted
/// channel's equations cover, `L_c = Σ_b w(b)·ln g_c(b) / Σ_b w(b)` at [`BALANCE_POINTS`]
/// points, weighted as the merge weighs a code (`w(b) = 1 − |2b − 1|`, the hat), and
/// `o_c = L_c − L` (a borrowed channel has its donor's curve and so its offset), so a
/// tone that is neutral in codes is neutral in radiance there, most of all at the codes
/// the merge takes its radiance from. The common level is the fitted channels' mean,
/// `L = mean_c L_c`, unless a channel cannot rise to it: `o_c ≥ ln g_c(b_c)` keeps
/// `g_c(b_c) ≤ 1`, so `L = min(mean_c L_c, min_c (L_c − ln g_c(b_c)))`, the highest level
/// every channel reaches (a channel extrapolated far above its brightest tone lowers the
/// common level rather than leaving a cast).
/// Above its brightest tone `b_c` the offset fades linearly in `b` to 0 at `b = 1`, so
/// `g(1) = 1` still holds. One channel, a single fitted channel, or no common tones: no
/// offsets.
fn balance(channels: &[ChannelCalibration]) -> Vec<f64> {
    let none = vec![0.0; channels.len()];
    let fitted: Vec<&ChannelCalibration> = channels
        .iter()
        .filter(|c| c.borrowed_from.is_none())
        .collect();
    if fitted.len() < 2 {
        return none;
    }
    let lo = fitted.iter().map(|c| c.fit.covered.0).fold(0.0, f64::max);
    let hi = fitted
        .iter()
        .map(|c| c.fit.covered.1)
        .fold(BALANCE_TOP, f64::min);
    if !(hi > lo && lo > 0.0) {
        return none;
    }
    let level = |c: &ChannelCalibration| {
        let curve = c.fit.curve();
        let (mut sum, mut total) = (0.0, 0.0);
        for k in 0..BALANCE_POINTS {
            let b = lo + (hi - lo) * (k as f64 + 0.5) / BALANCE_POINTS as f64;
            let w = 1.0 - (2.0 * b - 1.0).abs();
            sum += w * curve.log_g(b);
            total += w;
        }
        sum / total
    };
    let levels: Vec<f64> = channels.iter().map(level).collect();
    let top = |c: &ChannelCalibration| c.fit.log_g(c.fit.covered.1.min(BALANCE_TOP));
    let mean = channels
        .iter()
        .zip(&levels)
        .filter(|(c, _)| c.borrowed_from.is_none())
        .map(|(_, l)| l)
        .sum::<f64>()
        / fitted.len() as f64;
    // The highest common level every channel can reach without rising above 1 at its
    // brightest tone: `o_c ≥ ln g_c(b_c)` for all `c`.
    let reachable = channels
        .iter()
        .zip(&levels)
        .map(|(c, l)| l - top(c))
        .fold(f64::INFINITY, f64::min);
    let reference = mean.min(reachable);
    if !reference.is_finite() {
        return none;
    }
    channels
        .iter()
        .zip(&levels)
        .map(|(c, l)| (l - reference).max(top(c)))
        .collect()
}

/// The sampled curves of `channels`, balanced ([`balance`]) and checked.
fn finish(
    ratio: f64,
    ratio_source: RatioSource,
    channels: Vec<ChannelCalibration>,
) -> Result<Calibration, CalibrationError> {
    let offsets = balance(&channels);
    let samples = channels
        .iter()
        .zip(&offsets)
        .map(|(ch, &offset)| {
            let top = ch.fit.covered.1.min(BALANCE_TOP);
            let curve = ch.fit.curve();
            sample_curve(
                |b| {
                    // The offset in full up to the channel's brightest tone, fading
                    // linearly in `b` to nothing at `b = 1`, which stays `g(1) = 1`.
                    let fade = ((1.0 - b) / (1.0 - top)).clamp(0.0, 1.0);
                    (curve.log_g(b) - offset * fade).exp()
                },
                CALIBRATED_SAMPLES,
            )
        })
        .collect();
    let response = InverseResponse::from_samples(samples).map_err(CalibrationError::Curve)?;
    Ok(Calibration {
        ratio,
        ratio_source,
        channels,
        response,
    })
}

/// Exposures within this factor of each other are one exposure (EXIF's rounded shutter
/// times differ from the true ones by about 1 %; a third of a stop is 26 %): their pair
/// tells the fit nothing, and a bracket of them has one exposure.
pub const SAME_EXPOSURE: f64 = 1.01;

/// Whether exposures `a` and `b` are one exposure: `max(a, b) ≤` [`SAME_EXPOSURE`]` ·
/// min(a, b)`.
pub fn same_exposure(a: f64, b: f64) -> bool {
    a.max(b) <= SAME_EXPOSURE * a.min(b)
}

/// The largest ratio between exposures neighbouring in value when it is beyond the ratios
/// the confidence was fitted on ([`fit::CALIBRATED_RATIOS`], with the 1 % that EXIF's
/// rounded times allow), else `None`.
pub fn beyond_calibrated_ratios(exposures: &[f64]) -> Option<f64> {
    let mut sorted = exposures.to_vec();
    sorted.sort_by(f64::total_cmp);
    let widest = sorted
        .windows(2)
        .map(|w| w[1] / w[0])
        .fold(f64::NAN, f64::max);
    (widest > fit::CALIBRATED_RATIOS[1] * SAME_EXPOSURE).then_some(widest)
}

/// Frames at most this factor (four stops) apart are fitted as a pair even when others lie
/// between them.
pub const WIDEST_PAIR: f64 = 16.0;

/// Recovers one inverse response per channel from **every** frame of a bracket at once:
/// `frames` are the histograms with their relative exposures `e = t·S/N²` (any order,
/// all known). Every two frames of distinct exposures (`e_j > 1.01·e_i`) that are adjacent
/// or at most [`WIDEST_PAIR`] apart (`e_j ≤ 16·1.01·e_i`, four stops) give their tone pairs
/// `g(τ_ij(b)) = (e_j/e_i)·g(b)`, and all of them are fitted as one curve per channel
/// ([`fit::fit_joint`], each pair weighted by its own misfit): the frames' tonal ranges add
/// up, and a tone seen in several pairs is constrained several times and over longer
/// lever arms — a dark frame's toe meets the bright frames' mid tones directly rather than
/// through a chain of small ratios. Pairs wider than four stops share few tones that both
/// frames expose well. Two frames give exactly [`calibrate`] at the known ratio.
///
/// The result's `ratio` is the bracket's span, brightest over darkest exposure; each
/// channel's [`ChannelCalibration::log_ratios`] gives the ratio of each tone pair. A
/// channel without usable tones borrows the most confident other channel's curve with
/// confidence 0, as in [`calibrate`].
pub fn calibrate_bracket(
    frames: &[(&Histogram, f64)],
    ratio_source: RatioSource,
    degree: Degree,
) -> Result<Calibration, CalibrationError> {
    calibrate_pairs(frames, ratio_source, degree, |i, j| {
        (Cow::Borrowed(frames[i].0), Cow::Borrowed(frames[j].0))
    })
}

/// [`calibrate_bracket`] from frames counted with their hard-clipped JPEG blocks
/// ([`FrameCounts`]): each pair of frames is matched over the pixels both share
/// ([`shared_counts`]), so that the codec's ringing next to clipped highlights enters no
/// pair. Lossless frames give exactly [`calibrate_bracket`]. The frames must be aligned.
pub fn calibrate_frames(
    frames: &[(&FrameCounts<'_>, f64)],
    ratio_source: RatioSource,
    degree: Degree,
) -> Result<Calibration, CalibrationError> {
    let histograms: Vec<(&Histogram, f64)> =
        frames.iter().map(|(f, e)| (f.histogram(), *e)).collect();
    calibrate_pairs(&histograms, ratio_source, degree, |i, j| {
        shared_counts(frames[i].0, frames[j].0)
    })
}

/// [`calibrate_bracket`] with each pair's histograms from `pair(dark, bright)`.
fn calibrate_pairs<'h>(
    frames: &[(&'h Histogram, f64)],
    ratio_source: RatioSource,
    degree: Degree,
    pair: impl Fn(usize, usize) -> (Cow<'h, Histogram>, Cow<'h, Histogram>) + Sync,
) -> Result<Calibration, CalibrationError> {
    let first = check_frames(frames)?;
    let pairing = pair_frames(frames)?;
    let names = channel_names(first.channels());
    let counted: Vec<(Cow<Histogram>, Cow<Histogram>)> =
        pairing.pairs.par_iter().map(|&(i, j)| pair(i, j)).collect();
    let fitted: Vec<(Result<ChannelFit, FitError>, ChannelSets)> = (0..names.len())
        .into_par_iter()
        .map(|c| fit_channel(c, frames, &pairing, &counted, degree))
        .collect();
    if let Some(e) = refusal(names.iter().copied().zip(fitted.iter().map(|(f, _)| f))) {
        return Err(e);
    }
    let channels = assemble(names, fitted)?;
    finish(pairing.ratio, ratio_source, channels)
}

/// The first frame's histogram, once every frame has its channels and depth and a
/// finite, positive relative exposure.
fn check_frames<'h>(frames: &[(&'h Histogram, f64)]) -> Result<&'h Histogram, CalibrationError> {
    let Some(&(first, _)) = frames.first() else {
        return Err(CalibrationError::Mismatch("no frames".into()));
    };
    if let Some((h, _)) = frames
        .iter()
        .find(|(h, _)| h.channels() != first.channels() || h.depth() != first.depth())
    {
        return Err(CalibrationError::Mismatch(format!(
            "{} channels at {} bits against {} channels at {} bits",
            first.channels(),
            first.depth().bits(),
            h.channels(),
            h.depth().bits()
        )));
    }
    if let Some(&(_, e)) = frames.iter().find(|(_, e)| !(e.is_finite() && *e > 0.0)) {
        return Err(CalibrationError::Ratio(e));
    }
    Ok(first)
}

/// The pairs of frames a bracket is calibrated from.
struct Pairing {
    /// `(dark, bright)` frame indices of each pair.
    pairs: Vec<(usize, usize)>,
    /// The bracket's ratio: brightest over darkest exposure.
    ratio: f64,
    /// How many distinct exposures the bracket has.
    distinct: usize,
}

/// Pairs each frame with the brighter ones of adjacent distinct exposures (no frame
/// strictly between them) or close enough (within [`WIDEST_PAIR`]); a bracket without
/// two distinct exposures is an error giving its ratio.
fn pair_frames(frames: &[(&Histogram, f64)]) -> Result<Pairing, CalibrationError> {
    let mut order: Vec<usize> = (0..frames.len()).collect();
    order.sort_by(|&a, &b| frames[a].1.total_cmp(&frames[b].1));
    let pairs: Vec<(usize, usize)> = order
        .iter()
        .enumerate()
        .flat_map(|(k, &i)| order[k + 1..].iter().map(move |&j| (i, j)))
        .filter(|&(i, j)| frames[j].1 > SAME_EXPOSURE * frames[i].1)
        .filter(|&(i, j)| {
            frames[j].1 <= WIDEST_PAIR * SAME_EXPOSURE * frames[i].1
                || !frames.iter().any(|(_, e)| {
                    *e > SAME_EXPOSURE * frames[i].1 && *e * SAME_EXPOSURE < frames[j].1
                })
        })
        .collect();
    let (darkest, brightest) = (frames[order[0]].1, frames[order[order.len() - 1]].1);
    if pairs.is_empty() {
        return Err(CalibrationError::Ratio(brightest / darkest));
    }
    let distinct = 1 + order
        .windows(2)
        .filter(|w| frames[w[1]].1 > SAME_EXPOSURE * frames[w[0]].1)
        .count();
    Ok(Pairing {
        pairs,
        ratio: brightest / darkest,
        distinct,
    })
}

/// Fits channel `c` jointly over the tone pairs of every pair of `pairing`, with the
/// `counted` histograms of each pair and `ln(bright/dark)` as its log ratio.
fn fit_channel(
    c: usize,
    frames: &[(&Histogram, f64)],
    pairing: &Pairing,
    counted: &[(Cow<Histogram>, Cow<Histogram>)],
    degree: Degree,
) -> (Result<ChannelFit, FitError>, ChannelSets) {
    let sets: Vec<(Vec<TonePair>, f64)> = pairing
        .pairs
        .iter()
        .zip(counted)
        .map(|(&(i, j), (dark, bright))| {
            let (a, b) = (dark.cumulative(c), bright.cumulative(c));
            let usable_a = UsableTones::detect(&a, dark.compression());
            let usable_b = UsableTones::detect(&b, bright.compression());
            (
                tone_pairs(&a, &b, usable_a, usable_b),
                (frames[j].1 / frames[i].1).ln(),
            )
        })
        .collect();
    let borrowed: Vec<(&[TonePair], f64)> = sets.iter().map(|(p, r)| (p.as_slice(), *r)).collect();
    let result = fit::fit_joint(&borrowed, pairing.distinct, degree);
    let (pairs, log_ratios) = sets
        .iter()
        .flat_map(|(p, r)| p.iter().map(move |p| (*p, *r)))
        .unzip();
    let set_lengths = sets.iter().map(|(p, _)| p.len()).collect();
    let sets = ChannelSets {
        pairs,
        log_ratios,
        set_lengths,
    };
    (result, sets)
}

/// Samples `g` at `i/(n−1)`, pinning `g(0) = 0`, `g(1) = 1` and non-decreasing order.
fn sample_curve(g: impl Fn(f64) -> f64, n: usize) -> Vec<f64> {
    let mut out: Vec<f64> = (0..n)
        .map(|i| g(i as f64 / (n - 1) as f64).clamp(0.0, 1.0))
        .collect();
    out[0] = 0.0;
    out[n - 1] = 1.0;
    for i in 1..n {
        out[i] = out[i].max(out[i - 1]);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn neighbours_beyond_sixteen_times_are_beyond_the_calibrated_ratios() {
        assert_eq!(beyond_calibrated_ratios(&[1.0, 4.0, 16.0]), None);
        assert_eq!(
            beyond_calibrated_ratios(&[1.0, 16.1]),
            None,
            "EXIF rounding"
        );
        assert_eq!(
            beyond_calibrated_ratios(&[32.0, 1.0, 2.0]),
            None,
            "in order: 2×, 16×"
        );
        assert_eq!(beyond_calibrated_ratios(&[4.0, 1.0, 128.0]), Some(32.0));
        assert_eq!(beyond_calibrated_ratios(&[1.0]), None);
    }

    #[test]
    fn srgb_is_valid_and_interpolates() {
        let g = InverseResponse::srgb(3, 1024);
        let again = InverseResponse::from_samples((0..3).map(|c| g.samples(c).to_vec()).collect());
        assert!(again.is_ok());
        assert_eq!(g.eval(0, 0.0), 0.0);
        assert_eq!(g.eval(2, 1.0), 1.0);
        let mid = g.eval(1, 0.5);
        assert!((mid - 0.214).abs() < 1e-3, "{mid}");
        assert_eq!(g.eval(0, f64::NAN), 0.0);
    }

    #[test]
    fn a_channel_without_headroom_lowers_the_common_level_rather_than_casting() {
        // R and G: the exact tone pairs of g = b^2.2 at ratio 4. B: the same curve six
        // stops lower below its top piece (every coefficient but the last), so that it sits
        // far below the others and yet rises to within a fraction of a stop of white at its
        // brightest tone: it cannot be raised to the channels' mean level.
        let pairs: Vec<TonePair> = (3..=250)
            .map(|c| f64::from(c) / 255.0)
            .map(|b| (b, b * 4f64.powf(1.0 / 2.2)))
            .filter(|&(_, t)| t <= 250.0 / 255.0)
            .enumerate()
            .map(|(i, (dark, bright))| TonePair {
                dark,
                bright,
                sigma_dark: 0.001,
                sigma_bright: 0.001,
                quantile: i as f64,
            })
            .collect();
        let r = fit::fit(&pairs, 4f64.ln(), Degree::Auto).unwrap();
        let mut b = r.clone();
        let last = b.coefficients.len() - 1;
        for c in &mut b.coefficients[..last] {
            *c -= 6.0 * std::f64::consts::LN_2;
        }
        let channel = |name, fit| ChannelCalibration {
            name,
            fit,
            borrowed_from: None,
            pairs: Vec::new(),
            log_ratios: Vec::new(),
            set_lengths: Vec::new(),
        };
        let b_knot = b.knots.last().unwrap().exp();
        let top = b.covered.1.min(BALANCE_TOP);
        let headroom = -b.log_g(top);
        let mid = |f: &ChannelFit| f.log_g(0.5);
        // The mean level is four stops above B's; B may rise only by its headroom.
        assert!(
            (mid(&r) - mid(&b)) * 2.0 / 3.0 > headroom + 0.5,
            "headroom {headroom}"
        );
        let cal = finish(
            4.0,
            RatioSource::Argument,
            vec![channel("R", r.clone()), channel("G", r), channel("B", b)],
        )
        .unwrap();
        // Below B's top piece (its last interior knot), where the two curves differ by
        // their level alone.
        let knee = (b_knot * 255.0).floor() as i32;
        for k in [16, 64, 128, 192, knee] {
            let x = f64::from(k) / 255.0;
            let (gr, gb) = (cal.response.eval(0, x), cal.response.eval(2, x));
            assert!((gr / gb).log2().abs() < 0.05, "code {k}: R {gr}, B {gb}");
        }
        assert!(cal.response.samples(2).iter().all(|&g| g <= 1.0));
    }

    #[test]
    fn rejects_decreasing_and_unnormalised() {
        assert!(InverseResponse::from_samples(vec![vec![0.0, 0.6, 0.5, 1.0]]).is_err());
        assert!(InverseResponse::from_samples(vec![vec![0.0, 0.5, 0.9]]).is_err());
        assert!(InverseResponse::from_samples(vec![vec![0.0, f64::NAN, 1.0]]).is_err());
        assert!(InverseResponse::from_samples(vec![vec![0.0, 1.0]; 2]).is_err());
    }
}
