//! What a wrong response costs: errors of a recovered curve and of a merged radiance map
//! against the ground truth, shared by the tests and the accuracy bench.

use super::ResponseCurve;
use crate::frame::{Frame, Samples};
use crate::radiance::RadianceMap;
use crate::response::InverseResponse;

/// Codes (of 255) over which curve errors are taken: the tones a merge relies on.
pub const ERROR_CODES: std::ops::RangeInclusive<u32> = 16..=239;

/// Per channel, the **scale error** of `g` in stops: the mean over [`ERROR_CODES`] of
/// `log₂ g(k/255) − log₂ g_true(k/255)`. It is how far the channel's level sits from the
/// truth under `g`'s own normalisation `g(1) = 1`; the differences between channels are
/// the colour cast a merge with `g` shows.
pub fn scale_errors(g: &InverseResponse, truth: &ResponseCurve) -> Vec<f64> {
    (0..g.channels())
        .map(|c| {
            let n = ERROR_CODES.count() as f64;
            ERROR_CODES
                .map(|k| {
                    let b = f64::from(k) / 255.0;
                    g.eval(c, b).max(1e-300).log2() - truth.inverse(b).log2()
                })
                .sum::<f64>()
                / n
        })
        .collect()
}

/// Per channel, the **shape error** of `g` in stops: the RMS over [`ERROR_CODES`] of
/// `log₂ g − log₂ g_true` after removing the channel's scale error (what two histograms
/// can determine at all).
pub fn shape_errors(g: &InverseResponse, truth: &ResponseCurve) -> Vec<f64> {
    let scales = scale_errors(g, truth);
    (0..g.channels())
        .map(|c| {
            let n = ERROR_CODES.count() as f64;
            (ERROR_CODES
                .map(|k| {
                    let b = f64::from(k) / 255.0;
                    (g.eval(c, b).max(1e-300).log2() - truth.inverse(b).log2() - scales[c]).powi(2)
                })
                .sum::<f64>()
                / n)
                .sqrt()
        })
        .collect()
}

/// The merged radiance error: the median over samples of `|s·E/e_ref − E_true| / E_true`,
/// taken over the samples well exposed (code within 5–95 % of full scale) in at least one
/// of `frames`; `E` is `merged` (relative to the exposure `e_ref` of its reference frame,
/// so `E/e_ref` is in the scene's units) and `s` the one global factor, the median of
/// `E_true·e_ref/E` over those samples, for all channels at once: a radiance map is
/// relative, but its channels' balance is not. `None` when no sample qualifies.
pub fn radiance_error(
    merged: &RadianceMap,
    truth: &RadianceMap,
    e_ref: f64,
    frames: &[&Frame],
) -> Option<f64> {
    let code = |f: &Frame, i: usize| match f.samples() {
        Samples::Eight(v) => f64::from(v[i]) / 255.0,
        Samples::Sixteen(v) => f64::from(v[i]) / 65535.0,
    };
    let region: Vec<usize> = (0..truth.pixels().len())
        .filter(|&i| frames.iter().any(|f| (0.05..=0.95).contains(&code(f, i))))
        .collect();
    if region.is_empty() {
        return None;
    }
    let value = |i: usize| f64::from(merged.pixels()[i]) / e_ref;
    let mut ratios: Vec<f64> = region
        .iter()
        .map(|&i| f64::from(truth.pixels()[i]) / value(i))
        .filter(|r| r.is_finite())
        .collect();
    if ratios.is_empty() {
        return None;
    }
    ratios.sort_by(f64::total_cmp);
    let s = ratios[ratios.len() / 2];
    let mut errors: Vec<f64> = region
        .iter()
        .map(|&i| {
            let t = f64::from(truth.pixels()[i]);
            (s * value(i) - t).abs() / t
        })
        .collect();
    errors.sort_by(f64::total_cmp);
    Some(errors[errors.len() / 2])
}

/// The true inverse response of `curve` sampled at `samples` evenly spaced brightness
/// values, 3 channels: what a merge "given the true response" uses.
pub fn true_response(curve: &ResponseCurve, samples: usize) -> InverseResponse {
    let g: Vec<f64> = (0..samples)
        .map(|k| curve.inverse(k as f64 / (samples - 1) as f64))
        .collect();
    InverseResponse::from_samples(vec![g; 3]).expect("a response curve's inverse is valid")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::BitDepth;
    use crate::synthetic::{Sensor, expose, scene};

    #[test]
    fn scale_error_is_the_log_offset_and_shape_ignores_it() {
        let truth = ResponseCurve::Gamma(2.2);
        // g = 1.1·b^2.2 clipped at 1 is 0.1375 stop high below b ≈ 0.957.
        let g: Vec<f64> = (0..1024)
            .map(|k| {
                let b = k as f64 / 1023.0;
                if k == 1023 {
                    1.0
                } else {
                    (1.1 * b.powf(2.2)).min(1.0)
                }
            })
            .collect();
        let g = InverseResponse::from_samples(vec![g.clone(), g.clone(), g]).unwrap();
        let scale = scale_errors(&g, &truth);
        assert!((scale[0] - 1.1f64.log2()).abs() < 2e-3, "{scale:?}");
        assert!(shape_errors(&g, &truth)[1] < 2e-3);
        let exact = true_response(&truth, 1024);
        assert!(scale_errors(&exact, &truth)[2].abs() < 1e-3);
    }

    #[test]
    fn merge_with_the_true_response_has_a_small_error_and_a_wrong_one_a_larger() {
        let truth = scene(128, 96, 2);
        let curve = ResponseCurve::Srgb;
        let s = Sensor {
            read_noise_dn: 1.0,
            ..Sensor::noiseless(curve.clone(), BitDepth::Eight)
        };
        let (dark, bright) = (expose(&truth, 0.5, &s), expose(&truth, 2.0, &s));
        let merge = |g: &InverseResponse| {
            let camera = crate::metadata::Camera::default();
            let frames = [(&dark, 0.5), (&bright, 2.0)].map(|(frame, exposure)| {
                crate::merge::BracketFrame {
                    source: std::path::Path::new("synthetic"),
                    frame,
                    exposure,
                    camera: &camera,
                }
            });
            let merged =
                crate::merge::merge(&frames, g, crate::merge::MergeOptions::default()).unwrap();
            radiance_error(&merged.radiance, &truth, 2.0, &[&dark, &bright]).unwrap()
        };
        let right = merge(&true_response(&curve, 256));
        let wrong = merge(&true_response(&ResponseCurve::Gamma(1.6), 256));
        assert!(right < 0.03, "{right}");
        assert!(wrong > 2.0 * right, "{wrong} vs {right}");
    }
}
