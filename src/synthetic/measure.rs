//! What a wrong response or alignment costs: errors of a recovered curve, of a merged
//! radiance map and of a found transform against the ground truth, shared by the tests
//! and the accuracy benches.

use super::ResponseCurve;
use crate::frame::{Frame, Samples};
use crate::radiance::RadianceMap;
use crate::response::InverseResponse;
use crate::response::fit::ASSESSED_CODES;

/// One channel's error in stops against the truth, over the response's [`ASSESSED_CODES`], from the
/// differences `d(k) = log₂ g(k/255) − log₂ g_true(k/255)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CurveError {
    /// The **scale error**: the mean of `d`. How far the channel's level sits from the
    /// truth under the curve's own normalisation `g(1) = 1`; the differences between
    /// channels are the colour cast a merge with the curve shows.
    pub scale: f64,
    /// The **shape error**: the RMS of `d` after removing the scale error (what two
    /// histograms can determine at all).
    pub shape: f64,
    /// The RMS of `d` itself: `√(scale² + shape²)`.
    pub own: f64,
}

/// Per channel (`0..channels`), the error of a curve given as `g(channel, b)` (`b` in
/// 0..=1) against `truth`. Values of `g` at or below zero count as `1e-300`.
pub fn curve_errors(
    channels: usize,
    g: impl Fn(usize, f64) -> f64,
    truth: &ResponseCurve,
) -> Vec<CurveError> {
    (0..channels)
        .map(|c| {
            let d: Vec<f64> = ASSESSED_CODES
                .map(|k| {
                    let b = f64::from(k) / 255.0;
                    g(c, b).max(1e-300).log2() - truth.inverse(b).log2()
                })
                .collect();
            let n = d.len() as f64;
            let scale = d.iter().sum::<f64>() / n;
            let shape = (d.iter().map(|x| (x - scale).powi(2)).sum::<f64>() / n).sqrt();
            let own = (d.iter().map(|x| x * x).sum::<f64>() / n).sqrt();
            CurveError { scale, shape, own }
        })
        .collect()
}

/// [`curve_errors`] of an inverse response, every channel.
pub fn response_errors(g: &InverseResponse, truth: &ResponseCurve) -> Vec<CurveError> {
    curve_errors(g.channels(), |c, b| g.eval(c, b), truth)
}

/// Per channel, the scale error of `g` in stops ([`CurveError::scale`]).
pub fn scale_errors(g: &InverseResponse, truth: &ResponseCurve) -> Vec<f64> {
    response_errors(g, truth).iter().map(|e| e.scale).collect()
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

/// The largest distance, in pixels, between where the pixel transforms `a` and `b`
/// (row-major, `x′ = (m₀·x)/(m₂·x)` for `x = (x, y, 1)`) send a corner of a `w × h`
/// frame: `(0, 0)`, `(w − 1, 0)`, `(0, h − 1)`, `(w − 1, h − 1)`.
pub fn corner_error(w: u32, h: u32, a: &[[f64; 3]; 3], b: &[[f64; 3]; 3]) -> f64 {
    let apply = |m: &[[f64; 3]; 3], x: f64, y: f64| {
        let z = m[2][0] * x + m[2][1] * y + m[2][2];
        (
            (m[0][0] * x + m[0][1] * y + m[0][2]) / z,
            (m[1][0] * x + m[1][1] * y + m[1][2]) / z,
        )
    };
    let (xs, ys) = (f64::from(w - 1), f64::from(h - 1));
    [(0.0, 0.0), (xs, 0.0), (0.0, ys), (xs, ys)]
        .iter()
        .map(|&(x, y)| {
            let ((ax, ay), (bx, by)) = (apply(a, x, y), apply(b, x, y));
            (ax - bx).hypot(ay - by)
        })
        .fold(0.0, f64::max)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::BitDepth;
    use crate::synthetic::{Sensor, expose, scene};

    #[test]
    fn corner_error_is_the_farthest_corner() {
        let still = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let shift = [[1.0, 0.0, 3.0], [0.0, 1.0, 4.0], [0.0, 0.0, 1.0]];
        assert_eq!(corner_error(100, 50, &still, &shift), 5.0);
        // Scaled by 1 % about the origin: the far corner (99, 49) moves most.
        let scale = [[1.01, 0.0, 0.0], [0.0, 1.01, 0.0], [0.0, 0.0, 1.0]];
        let far = 0.01 * 99f64.hypot(49.0);
        assert!((corner_error(100, 50, &still, &scale) - far).abs() < 1e-12);
        // A perspective row divides: x′ = x/(1 + 0.001·x).
        let tilt = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.001, 0.0, 1.0]];
        let (x, y) = (99.0, 49.0);
        let z: f64 = 1.0 + 0.001 * x;
        let far = (x - x / z).hypot(y - y / z);
        assert!((corner_error(100, 50, &tilt, &still) - far).abs() < 1e-12);
    }

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
        let errors = response_errors(&g, &truth);
        assert!(errors[1].shape < 2e-3, "{errors:?}");
        assert!((errors[1].own - errors[1].scale.hypot(errors[1].shape)).abs() < 1e-12);
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
