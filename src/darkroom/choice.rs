//! Which response a bracket is merged with: its own fit, the camera's cached curve,
//! a response file or sRGB.
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
//! **A body's pool.** A good fit (confidence at least `min_confidence`) that the cached
//! curve does not contradict agrees with the body: when that curve is the body's pool
//! ([`BodyPool`]: one fit over the evidence of its earlier good brackets) and is trusted
//! (confidence at least `min_confidence` and 0.5) or at least as confident as the
//! bracket's own fit, the bracket is merged with it ([`Source::Pooled`]): one curve for
//! the body's brackets, steadier from scene to scene than each one's own. Either way its
//! evidence is returned ([`Pooling`]) for the daemon to pool and refit after the outputs
//! are published, off the bracket's critical path. A
//! bracket that contradicts the cached curve is merged with its own fit and its evidence
//! returned as a dissent.

use std::path::Path;
use std::time::Instant;

use rayon::prelude::*;

use super::{DarkroomError, Stages, file_name};
use crate::histogram::FrameCounts;
use crate::merge::BracketFrame;
use crate::response::fit::LOW_CONFIDENCE;
use crate::response::pool::{self, Evidence};
use crate::response::{self, Calibration, CalibrationError, Degree, InverseResponse, RatioSource};

/// Pixels per frame the calibration histograms look at (a speed knob measured in
/// `benches/calibrate_speed.rs`: beyond a few million pixels the histograms of a
/// 256-level frame no longer change the fit).
pub const CALIBRATION_PIXELS: f64 = 3e6;

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
    /// A camera raw: linear after the black level, clipped at the white level.
    Raw,
    /// The body's curve, one fit over its earlier good brackets, which this bracket
    /// agrees with (see the module docs).
    Pooled,
}

impl std::fmt::Display for Source {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Source::Fitted => "fitted",
            Source::Cached => "cached",
            Source::File => "file",
            Source::Standard => "standard (sRGB)",
            Source::Raw => "linear (raw)",
            Source::Pooled => "pooled (this body's brackets)",
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
        /// Set when `fallback` is the body's pooled curve.
        pool: Option<BodyPool>,
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
    /// True when this bracket's own fit was good but the camera's cached curve explains
    /// its frames worse by more than [`CONTRADICTION_STOPS`] (a picture style or setting
    /// changed): the daemon reports it and keeps the cache as it was.
    pub contradicts_cache: bool,
    /// A good fit's evidence for the body's pool (the daemon pools it and refits).
    pub pooling: Option<Pooling>,
}

/// The body's pooled curve behind a cached fallback (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BodyPool {
    /// Brackets the curve was fitted over.
    pub brackets: usize,
    /// Its lowest channel confidence.
    pub confidence: f64,
}

/// What a good fit gives the body's pool (see the module docs).
#[derive(Debug, Clone)]
pub struct Pooling {
    /// This bracket's tone pairs, thinned ([`Evidence::of`]).
    pub evidence: Evidence,
    /// How far the bracket's own fit is from explaining that evidence, RMS stops
    /// ([`pool::agreement`]).
    pub own_misfit: f64,
    /// The bracket's own fit's confidence per channel.
    pub own_confidence: Vec<f64>,
    /// The body's pool refitted with this bracket, with its channels' confidences (set
    /// by the daemon after publishing; `None` from the darkroom).
    pub pooled: Option<(InverseResponse, Vec<f64>)>,
}

/// Chooses the response for `bracket` under `policy`; `ratio_source` says where the
/// exposures came from. Histogram and fit times are appended to `stages`. The steps: fit
/// (`fit_bracket`); on failure the fallback; a fit the cached curve contradicts keeps
/// its own curve (`contradicts_cached`); a weak fit yields to a fallback that the
/// bracket does not contradict (`weak_fit_fallback`); a good fit yields to a trusted
/// body pool; else the fit (`use_fitted`).
pub fn choose_response(
    bracket: &[BracketFrame<'_>],
    ratio_source: RatioSource,
    policy: ResponsePolicy,
    stages: &mut Stages,
) -> Result<ChosenResponse, DarkroomError> {
    let (fallback, min_confidence, body_pool) = match policy {
        ResponsePolicy::Use(given) => return Ok(use_given(given, Vec::new(), None)),
        ResponsePolicy::Fit {
            fallback,
            min_confidence,
            pool,
        } => (fallback, min_confidence, pool),
    };
    let Fitting {
        chosen,
        dark,
        bright,
        pair,
        fitted,
    } = fit_bracket(bracket, ratio_source, stages);
    let (calibration, mut fallback) = match (fitted, fallback) {
        (Ok(c), fallback) => (c, fallback),
        (Err(source), None) => {
            return Err(DarkroomError::Calibrate {
                dark: dark.to_path_buf(),
                bright: bright.to_path_buf(),
                source,
            });
        }
        (Err(e), Some(given)) => {
            let note = format!(
                "no response could be fitted from {} ({e}); used the {}",
                pair, given.label
            );
            return Ok(use_given(given, vec![note], None));
        }
    };
    let fitted = Fitted::of(calibration, &chosen, ratio_source);
    let mut notes = Vec::new();
    let contradicts_cache = fitted.confidence >= min_confidence
        && contradicts_cached(&fitted, fallback.as_ref(), &mut notes);
    if fitted.confidence < min_confidence
        && let Some(given) = fallback.take()
    {
        match weak_fit_fallback(&fitted, given, min_confidence, &pair) {
            WeakFit::Yields(chosen) => return Ok(*chosen),
            WeakFit::Kept(note) => notes.push(note),
        }
    }
    notes.extend(wide_pair_note(&chosen, &pair));
    let pooling = (fitted.confidence >= min_confidence)
        .then(|| pooling_of(&fitted.calibration, chosen.len()));
    // The pool is steadier from scene to scene than one bracket's fit (docs/accuracy.md,
    // "A body's pool"): used when it is trusted itself, or at least as sure as this fit.
    let trusted = min_confidence.max(LOW_CONFIDENCE);
    if !contradicts_cache
        && let Some(body) =
            body_pool.filter(|b| b.confidence >= trusted || b.confidence >= fitted.confidence)
        && let Some(cached) = fallback.take().filter(|g| g.source == Source::Cached)
        && pooling.is_some()
    {
        let fit = Some(fitted.own_fit());
        return Ok(use_pooled(cached, body, fit, fitted.report, notes, pooling));
    }
    Ok(use_fitted(
        fitted,
        &pair,
        ratio_source,
        notes,
        contradicts_cache,
        pooling,
    ))
}

/// A note when frames of `chosen` (named `pair`) are further apart than the fit's
/// confidence is calibrated on (four stops).
fn wide_pair_note(chosen: &[&BracketFrame<'_>], pair: &str) -> Option<String> {
    let exposures: Vec<f64> = chosen.iter().map(|f| f.exposure).collect();
    response::beyond_calibrated_ratios(&exposures).map(|widest| {
        format!(
            "frames {:.1} stops apart in {}: the fit's confidence is calibrated on frames \
             up to four stops apart",
            widest.log2(),
            pair
        )
    })
}

/// The frames a bracket's response is fitted from, and the fit.
struct Fitting<'b, 'f> {
    /// The frames fitted, darkest first: every frame when more than two exposures are
    /// distinct, else the adjacent pair nearest the middle whose exposures differ.
    chosen: Vec<&'b BracketFrame<'f>>,
    /// The darker and brighter frame of that pair (the ends of the bracket otherwise).
    dark: &'f Path,
    /// See `dark`.
    bright: &'f Path,
    /// How notes name the frames: `all N frames` or `A and B`.
    pair: String,
    /// The calibration, or why there is none.
    fitted: Result<Calibration, CalibrationError>,
}

/// Fits the response of `bracket` ([`Fitting`]): histograms of about
/// [`CALIBRATION_PIXELS`] pixels a frame (stage `histogram`), then
/// [`response::calibrate_frames`] (stage `fit`).
fn fit_bracket<'b, 'f>(
    bracket: &'b [BracketFrame<'f>],
    ratio_source: RatioSource,
    stages: &mut Stages,
) -> Fitting<'b, 'f> {
    let mut order: Vec<usize> = (0..bracket.len()).collect();
    order.sort_by(|&a, &b| bracket[a].exposure.total_cmp(&bracket[b].exposure));
    // The adjacent pair nearest the middle whose exposures differ (duplicates, as in
    // 1/60, 1/60, 1/15, tell the fit nothing); if none differ, the middle pair, and the
    // fit says why it cannot work.
    let mid = (order.len() / 2).max(1);
    let distinct = |k: &usize| {
        let (a, b) = (&bracket[order[k - 1]], &bracket[order[*k]]);
        !response::same_exposure(a.exposure, b.exposure)
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
    let joint = (1..order.len()).filter(distinct).count() + 1 > 2;
    let chosen: Vec<&BracketFrame<'_>> = if joint {
        order.iter().map(|&i| &bracket[i]).collect()
    } else {
        vec![dark, bright]
    };
    let counts: Vec<FrameCounts> = chosen
        .par_iter()
        .map(|f| FrameCounts::of_frame(f.frame, stride))
        .collect();
    stages.push(("histogram", t.elapsed()));
    let t = Instant::now();
    let frames: Vec<(&FrameCounts, f64)> = counts
        .iter()
        .zip(&chosen)
        .map(|(c, f)| (c, f.exposure))
        .collect();
    let fitted = response::calibrate_frames(&frames, ratio_source, Degree::Auto);
    stages.push(("fit", t.elapsed()));
    let pair = if joint {
        format!("all {} frames", bracket.len())
    } else {
        format!(
            "{} and {}",
            file_name(dark.source),
            file_name(bright.source)
        )
    };
    Fitting {
        chosen,
        dark: dark.source,
        bright: bright.source,
        pair,
        fitted,
    }
}

/// A bracket's own calibration, its confidence and its `--json` report.
struct Fitted {
    /// The calibration.
    calibration: Calibration,
    /// The smallest of its channels' confidences, in `[0, 1]`.
    confidence: f64,
    /// What `--json` reports of it.
    report: serde_json::Value,
    /// The exposure ratio between the ends of the frames fitted.
    ratio: f64,
}

impl Fitted {
    /// `calibration` of the frames `chosen` (darkest first), with its confidence and report.
    fn of(
        calibration: Calibration,
        chosen: &[&BracketFrame<'_>],
        ratio_source: RatioSource,
    ) -> Self {
        let confidence = calibration
            .channels
            .iter()
            .map(|c| c.fit.confidence)
            .fold(f64::INFINITY, f64::min)
            .clamp(0.0, 1.0);
        let ratio = chosen[chosen.len() - 1].exposure / chosen[0].exposure;
        let report = serde_json::json!({
            "source": "fitted",
            "frames": chosen.iter().map(|f| f.source.display().to_string()).collect::<Vec<_>>(),
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
        Fitted {
            calibration,
            confidence,
            report,
            ratio,
        }
    }

    /// The fitted curve and its confidence, as [`ChosenResponse::fit`] records it.
    fn own_fit(&self) -> (InverseResponse, f64) {
        (self.calibration.response.clone(), self.confidence)
    }
}

/// True (with a note) when the fallback is the camera's cached curve and it explains the
/// bracket's tone pairs worse than its own fit by more than [`CONTRADICTION_STOPS`]: a
/// picture style or setting has changed, and the bracket keeps its own fit.
fn contradicts_cached(
    fitted: &Fitted,
    fallback: Option<&GivenResponse>,
    notes: &mut Vec<String>,
) -> bool {
    let Some(cached) = fallback.filter(|g| g.source == Source::Cached) else {
        return false;
    };
    let calibration = &fitted.calibration;
    let fit_misfit = pool::misfit(calibration, &calibration.response);
    let cached_misfit = pool::misfit(calibration, &cached.response);
    if cached_misfit <= fit_misfit + CONTRADICTION_STOPS {
        return false;
    }
    notes.push(format!(
        "this bracket contradicts the {} ({cached_misfit:.3} stops RMS against its own \
         fit's {fit_misfit:.3}: has a picture style or setting changed?); used its own \
         fit and left the cache as it was",
        cached.label
    ));
    true
}

/// What becomes of a fit below the policy's confidence.
enum WeakFit {
    /// It yields to the fallback (boxed: a choice is large beside a note).
    Yields(Box<ChosenResponse>),
    /// It is kept, because the bracket contradicts the fallback; the note says so.
    Kept(String),
}

/// A fit of confidence below `min_confidence`: the fallback `given` unless the bracket
/// contradicts it (explains its tone pairs worse than the weak fit by more than
/// [`CONTRADICTION_STOPS`]), in which case the fit is kept.
fn weak_fit_fallback(
    fitted: &Fitted,
    given: GivenResponse,
    min_confidence: f64,
    pair: &str,
) -> WeakFit {
    let (calibration, confidence) = (&fitted.calibration, fitted.confidence);
    let fit_misfit = pool::misfit(calibration, &calibration.response);
    let given_misfit = pool::misfit(calibration, &given.response);
    if given_misfit > fit_misfit + CONTRADICTION_STOPS {
        return WeakFit::Kept(format!(
            "the fit from {pair} has confidence {confidence:.2} < {min_confidence:.2}, but the {} \
             contradicts this bracket ({given_misfit:.3} stops RMS against the fit's \
             {fit_misfit:.3}); used the fit",
            given.label
        ));
    }
    let note = format!(
        "the fit from {pair} has confidence {confidence:.2} < {min_confidence:.2}; used the {}",
        given.label
    );
    let mut chosen = use_given(given, vec![note], Some(fitted.own_fit()));
    chosen.report["rejected_fit"] = fitted.report.clone();
    WeakFit::Yields(Box::new(chosen))
}

/// A good fit's evidence for the body's pool, from `frames` frames.
fn pooling_of(calibration: &Calibration, frames: usize) -> Pooling {
    let evidence = Evidence::of(calibration, frames);
    let own_misfit = pool::agreement(&evidence, &calibration.response);
    Pooling {
        evidence,
        own_misfit,
        own_confidence: calibration
            .channels
            .iter()
            .map(|c| c.fit.confidence)
            .collect(),
        pooled: None,
    }
}

/// The bracket merged with its own fit, summarised for the log.
fn use_fitted(
    fitted: Fitted,
    pair: &str,
    ratio_source: RatioSource,
    mut notes: Vec<String>,
    contradicts_cache: bool,
    pooling: Option<Pooling>,
) -> ChosenResponse {
    let Fitted {
        calibration,
        confidence,
        report,
        ratio,
    } = fitted;
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
    if confidence < LOW_CONFIDENCE {
        notes.push(format!(
            "low-confidence response fit ({confidence:.2}) from {pair}: check the result or give a response file"
        ));
    }
    let fit = Some((calibration.response.clone(), confidence));
    ChosenResponse {
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
        contradicts_cache,
        pooling,
    }
}

/// The bracket merged with the body's pooled curve `cached`, which it agrees with.
fn use_pooled(
    cached: GivenResponse,
    body: BodyPool,
    own_fit: Option<(InverseResponse, f64)>,
    own_report: serde_json::Value,
    notes: Vec<String>,
    pooling: Option<Pooling>,
) -> ChosenResponse {
    let own_confidence = own_fit.as_ref().map_or(0.0, |f| f.1);
    ChosenResponse {
        summary: format!(
            "{}; this bracket agrees with it (its own fit: confidence {own_confidence:.2})",
            cached.label
        ),
        report: serde_json::json!({
            "source": Source::Pooled,
            "model": cached.label,
            "brackets": body.brackets,
            "confidence": body.confidence,
            "own_fit": own_report,
        }),
        response: cached.response,
        source: Source::Pooled,
        fit: own_fit,
        notes,
        contradicts_cache: false,
        pooling,
    }
}

/// How much worse (weighted RMS, stops: [`pool::misfit`]) a fallback may explain the
/// bracket's tone pairs than the bracket's own fit before it counts as contradicted. A
/// ripple the two exposures cannot resolve costs a few hundredths of a stop; a wrong curve
/// family (sRGB for a film shoulder) costs tenths.
pub const CONTRADICTION_STOPS: f64 = 0.05;

pub(super) fn use_given(
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
        contradicts_cache: false,
        pooling: None,
    }
}
