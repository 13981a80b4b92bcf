//! A body's response from the evidence of many brackets: pooled tone pairs, one joint fit.
//!
//! Every bracket of one camera body constrains the same curve: its tone pairs say
//! `g(τ(b)) = γ·g(b)` whatever the scene. One bracket covers the tones its scene holds; a
//! body that has shot a dozen scenes has seen nearly every tone in several frame pairs,
//! and above all the highlights close to white whose extrapolation sets a channel's scale
//! ([`ChannelFit::top_span`](super::ChannelFit::top_span)). So the evidence is kept, not
//! the curves: [`Evidence::of`] takes a calibration's tone pairs, frame pair by frame
//! pair, thinned to at most [`PAIRS_PER_SET`] each; [`refit`] fits one curve per channel
//! to the pairs of every bracket at once with [`fit::fit_joint`] (each frame pair a set,
//! so a bracket that scatters more than the others is down-weighted, not followed).
//!
//! [`agreement`] says how well a curve explains one bracket's evidence, [`misfit`] a
//! calibration's own tone pairs: the same weighted RMS of `log₂(g(τ)/(γ·g(b)))` in stops,
//! the measure of the darkroom's and the cache's contradiction tests.

use rayon::prelude::*;

use super::fit::{self, ChannelFit, Degree, FitError};
use super::{
    Calibration, CalibrationError, ChannelSets, RatioSource, assemble, channel_names, finish,
};
use crate::histogram::TonePair;

/// Most tone pairs kept per frame pair and channel. A frame pair of 8-bit frames gives up
/// to ~500, one per bin edge of either frame, and neighbouring pairs rest on the same
/// pixels; an even selection by tone keeps what the set says about the curve's shape
/// (a spline of ten pieces) at a quarter of the storage.
pub const PAIRS_PER_SET: usize = 128;

/// The tone pairs of one frame pair of one channel and their `ln γ`.
#[derive(Debug, Clone, PartialEq)]
pub struct PairSet {
    /// `ln(e_bright / e_dark)` of the frame pair.
    pub log_ratio: f64,
    /// The pairs, in order of the dark tone.
    pub pairs: Vec<TonePair>,
}

/// What one bracket says about its body's response (see the module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct Evidence {
    /// Distinct exposures of the bracket.
    pub frames: usize,
    /// Per channel, the frame pairs' tone pairs (empty for a channel that borrowed
    /// another's curve).
    pub channels: Vec<Vec<PairSet>>,
}

impl Evidence {
    /// The evidence of `calibration` (a pair or a bracket of `frames` distinct
    /// exposures), each frame pair's tone pairs thinned evenly by tone to at most
    /// [`PAIRS_PER_SET`].
    pub fn of(calibration: &Calibration, frames: usize) -> Evidence {
        let channels = calibration
            .channels
            .iter()
            .map(|ch| {
                let mut start = 0;
                ch.set_lengths
                    .iter()
                    .map(|&len| {
                        let end = (start + len).min(ch.pairs.len());
                        let mut pairs = ch.pairs[start..end].to_vec();
                        let log_ratio = ch.log_ratios.get(start).copied().unwrap_or(0.0);
                        start = end;
                        pairs.sort_by(|a, b| a.dark.total_cmp(&b.dark));
                        PairSet {
                            log_ratio,
                            pairs: thin(&pairs, PAIRS_PER_SET),
                        }
                    })
                    .filter(|s| !s.pairs.is_empty())
                    .collect()
            })
            .collect();
        Evidence {
            frames: frames.max(2),
            channels,
        }
    }

    /// Frame pairs over all channels.
    pub fn sets(&self) -> usize {
        self.channels.iter().map(Vec::len).sum()
    }
}

/// At most `n` of `pairs`, evenly spaced by index (both ends kept).
fn thin(pairs: &[TonePair], n: usize) -> Vec<TonePair> {
    if pairs.len() <= n {
        return pairs.to_vec();
    }
    (0..n)
        .map(|k| pairs[(k * (pairs.len() - 1) + (n - 1) / 2) / (n - 1)])
        .collect()
}

/// One curve per channel fitted to the evidence of every bracket in `pool` at once (see
/// the module docs). The sets rest on `1 + Σ (frames − 1)` independent exposures' worth
/// of histograms. A channel without evidence borrows the most confident channel's curve
/// at confidence 0, as in [`super::calibrate`]. The result's `ratio` is the widest
/// bracket's span.
pub fn refit(pool: &[&Evidence], degree: Degree) -> Result<Calibration, CalibrationError> {
    let Some(first) = pool.first() else {
        return Err(CalibrationError::NoChannel("no brackets pooled".into()));
    };
    let channels = first.channels.len();
    if let Some(e) = pool.iter().find(|e| e.channels.len() != channels) {
        return Err(CalibrationError::Mismatch(format!(
            "pooled brackets of {channels} and {} channels",
            e.channels.len()
        )));
    }
    let exposures = 1 + pool.iter().map(|e| e.frames - 1).sum::<usize>();
    let fitted: Vec<(Result<ChannelFit, FitError>, Vec<&PairSet>)> = (0..channels)
        .into_par_iter()
        .map(|c| {
            let sets: Vec<&PairSet> = pool.iter().flat_map(|e| &e.channels[c]).collect();
            let borrowed: Vec<(&[TonePair], f64)> = sets
                .iter()
                .map(|s| (s.pairs.as_slice(), s.log_ratio))
                .collect();
            let result = if borrowed.is_empty() {
                Err(FitError::TooFewTones(0))
            } else {
                fit::fit_joint(&borrowed, exposures, degree)
            };
            (result, sets)
        })
        .collect();
    let calibrated = assemble(
        channel_names(channels),
        fitted
            .into_iter()
            .map(|(f, sets)| {
                let tones = ChannelSets {
                    pairs: sets.iter().flat_map(|s| s.pairs.iter().copied()).collect(),
                    log_ratios: sets
                        .iter()
                        .flat_map(|s| std::iter::repeat_n(s.log_ratio, s.pairs.len()))
                        .collect(),
                    set_lengths: sets.iter().map(|s| s.pairs.len()).collect(),
                };
                (f, tones)
            })
            .collect(),
    )?;
    let span = pool
        .iter()
        .flat_map(|e| e.channels.iter().flatten())
        .map(|s| s.log_ratio)
        .fold(0.0, f64::max);
    finish(span.exp().max(1.0), RatioSource::Exif, calibrated)
}

/// How far `g` is from explaining `evidence`: the [`misfit`] measure over its tone pairs.
pub fn agreement(evidence: &Evidence, g: &super::InverseResponse) -> f64 {
    weighted_misfit(
        evidence.channels.iter().enumerate().flat_map(|(c, sets)| {
            sets.iter()
                .flat_map(move |set| set.pairs.iter().map(move |p| (c, p, set.log_ratio)))
        }),
        g,
    )
}

/// How far `g` is from explaining `calibration`'s own tone pairs `(channel, b ↦ τ, ln γ)`,
/// each at its own ratio: the weighted RMS, stops, of `r = log₂(g(τ)/(γ·g(b)))`,
/// `√(Σ w·r² / Σ w)` with `w = 1/(v_b/b² + v_τ/τ²)`, the inverse variance of
/// `ln τ − ln b` from each side's standard deviation and 1 DN (`v = σ² + (1/255)²`,
/// brightness units). The weights do not depend on `g`, so two curves are judged on the
/// same terms; a sparse or dark tone, whose match the histograms' noise moves most,
/// counts least (on a thumbnail most of all). Pairs where `g` is 0 are skipped; no pairs
/// gives 0.
pub fn misfit(calibration: &Calibration, g: &super::InverseResponse) -> f64 {
    weighted_misfit(
        calibration.channels.iter().enumerate().flat_map(|(c, ch)| {
            ch.pairs
                .iter()
                .zip(&ch.log_ratios)
                .map(move |(p, &log_ratio)| (c, p, log_ratio))
        }),
        g,
    )
}

/// The weighted RMS of [`misfit`] over any tone pairs `(channel, pair, ln γ)`.
fn weighted_misfit<'a>(
    pairs: impl Iterator<Item = (usize, &'a TonePair, f64)>,
    g: &super::InverseResponse,
) -> f64 {
    const DN: f64 = 1.0 / 255.0;
    let (mut sum, mut total) = (0.0, 0.0);
    for (c, p, log_ratio) in pairs {
        let c = c.min(g.channels().saturating_sub(1));
        let (lo, hi) = (g.eval(c, p.dark), g.eval(c, p.bright));
        if lo > 0.0 && hi > 0.0 && p.dark > 0.0 && p.bright > 0.0 {
            let v_b = p.sigma_dark.powi(2) + DN * DN;
            let v_t = p.sigma_bright.powi(2) + DN * DN;
            let w = 1.0 / (v_b / (p.dark * p.dark) + v_t / (p.bright * p.bright));
            sum += w * ((hi / lo).ln() - log_ratio).powi(2);
            total += w;
        }
    }
    if total > 0.0 {
        (sum / total).sqrt() / std::f64::consts::LN_2
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thinning_keeps_both_ends_and_spreads_evenly() {
        let pairs: Vec<TonePair> = (0..500)
            .map(|i| TonePair {
                dark: f64::from(i) / 1000.0,
                bright: f64::from(i) / 500.0,
                sigma_dark: 0.001,
                sigma_bright: 0.001,
                quantile: f64::from(i) / 500.0,
            })
            .collect();
        let kept = thin(&pairs, 128);
        assert_eq!(kept.len(), 128);
        assert_eq!(kept[0], pairs[0]);
        assert_eq!(kept[127], pairs[499]);
        let gaps: Vec<f64> = kept.windows(2).map(|w| w[1].dark - w[0].dark).collect();
        let (lo, hi) = gaps
            .iter()
            .fold((f64::INFINITY, 0.0f64), |(l, h), &g| (l.min(g), h.max(g)));
        assert!(hi - lo <= 0.0011, "{lo} {hi}");
        assert_eq!(thin(&pairs[..10], 128).len(), 10);
    }
}
