//! Camera response curves `f`: normalised exposure `X ∈ [0, 1]` to brightness `B ∈ [0, 1]`.

use super::{CurveError, SyntheticError};

/// Exponent `k` of the film-like S-curve (slope of its logistic in `ln X`).
const FILM_S_POWER: f64 = 1.6;
/// Half-saturation constant `m` of the film-like S-curve, chosen so that `f(0.18) = 0.46`:
/// `m = 0.18^k·(1 − 0.46)/(0.46 − 0.18^k)`.
const FILM_S_HALF: f64 = 0.087_801_168_603_203_57;
/// Toe width `t` of the strong-toe curve (in normalised exposure).
const TOE_WIDTH: f64 = 0.1;
/// Display gamma applied after the strong toe.
const TOE_GAMMA: f64 = 2.2;

/// A camera response `f: X ↦ B`, normalised exposure to brightness, both in `[0, 1]`.
///
/// Every curve satisfies `f(0) = 0`, `f(1) = 1` and is strictly increasing, so its inverse
/// `g = f⁻¹` (what response recovery estimates) exists and `g(1) = 1`.
#[derive(Debug, Clone, PartialEq)]
pub enum ResponseCurve {
    /// `B = X`.
    Linear,
    /// `B = X^(1/γ)`, inverse `X = B^γ` (γ = 2.2 is the classic display gamma). γ > 0.
    Gamma(f64),
    /// The sRGB transfer function (IEC 61966-2-1): `B = 12.92·X` for `X ≤ 0.0031308`,
    /// else `B = 1.055·X^(1/2.4) − 0.055`.
    Srgb,
    /// A film-like S-curve: a logistic in log exposure, i.e. the Hill function
    /// `B = (1 + m)·X^k / (X^k + m)` with `k = 1.6`, `m ≈ 0.0878` (`f(0.18) = 0.46`): a toe
    /// with zero slope at black and a shoulder with slope ≈ 0.13 at white.
    /// Inverse `X = (m·B / (1 + m − B))^(1/k)`.
    FilmS,
    /// A strong toe under a display gamma: `B = (h(X)/h(1))^(1/2.2)` with
    /// `h(X) = X³ / (X² + t²)`, `t = 0.1`. Above `X ≈ t` it behaves like gamma 2.2; below,
    /// the shadows fall off as `X^(3/2.2)` (e.g. `f(0.01) = 0.015` where gamma 2.2 gives
    /// 0.12). The inverse has no convenient closed form and is found by bisection.
    StrongToe,
    /// `B_i = f(i/(n−1))` sampled on `n ≥ 2` evenly spaced exposures, linearly interpolated
    /// (build it with [`ResponseCurve::sampled`], which checks the samples). The inverse is
    /// the exact inverse of the interpolant (table search).
    Sampled(Vec<f64>),
}

impl ResponseCurve {
    /// The built-in curves with short names: linear, gamma-2.2, srgb, film-s, strong-toe.
    pub fn builtin() -> Vec<(String, ResponseCurve)> {
        [
            ("linear", ResponseCurve::Linear),
            ("gamma-2.2", ResponseCurve::Gamma(2.2)),
            ("srgb", ResponseCurve::Srgb),
            ("film-s", ResponseCurve::FilmS),
            ("strong-toe", ResponseCurve::StrongToe),
        ]
        .into_iter()
        .map(|(name, curve)| (name.to_string(), curve))
        .collect()
    }

    /// A sampled curve, checked: at least two finite samples, `B_0 = 0`, `B_{n−1} = 1`,
    /// strictly increasing.
    pub fn sampled(samples: Vec<f64>) -> Result<ResponseCurve, SyntheticError> {
        let curve = ResponseCurve::Sampled(samples);
        curve.check()?;
        Ok(curve)
    }

    /// Checks the invariants a curve's parameters must meet (γ finite and positive; a
    /// sampled table as in [`ResponseCurve::sampled`]). The other variants are always valid.
    pub fn check(&self) -> Result<(), SyntheticError> {
        Ok(self.broken()?)
    }

    /// The first invariant [`ResponseCurve::check`] finds broken.
    pub(super) fn broken(&self) -> Result<(), CurveError> {
        match self {
            ResponseCurve::Gamma(gamma) if !(gamma.is_finite() && *gamma > 0.0) => {
                Err(CurveError::Gamma(*gamma))
            }
            ResponseCurve::Sampled(b) => {
                if b.len() < 2 {
                    return Err(CurveError::TooFewSamples(b.len()));
                }
                if let Some(i) = b.iter().position(|v| !v.is_finite()) {
                    return Err(CurveError::NotFinite(i));
                }
                if b[0] != 0.0 || b[b.len() - 1] != 1.0 {
                    return Err(CurveError::Ends {
                        first: b[0],
                        last: b[b.len() - 1],
                    });
                }
                if let Some(at) = b.windows(2).position(|w| w[1] <= w[0]) {
                    return Err(CurveError::NotIncreasing { at });
                }
                Ok(())
            }
            _ => Ok(()),
        }
    }

    /// Brightness `B = f(X)` for normalised exposure `X` (clamped to `[0, 1]`; NaN reads as 0).
    pub fn brightness(&self, x: f64) -> f64 {
        if x.is_nan() || x <= 0.0 {
            return 0.0;
        }
        if x >= 1.0 {
            return 1.0;
        }
        match self {
            ResponseCurve::Linear => x,
            ResponseCurve::Gamma(gamma) => x.powf(gamma.recip()),
            ResponseCurve::Srgb => {
                if x <= 0.003_130_8 {
                    12.92 * x
                } else {
                    1.055 * x.powf(1.0 / 2.4) - 0.055
                }
            }
            ResponseCurve::FilmS => {
                let p = x.powf(FILM_S_POWER);
                (1.0 + FILM_S_HALF) * p / (p + FILM_S_HALF)
            }
            ResponseCurve::StrongToe => (toe(x) / toe(1.0)).powf(TOE_GAMMA.recip()),
            ResponseCurve::Sampled(b) => interpolate_even(b, x),
        }
    }

    /// Normalised exposure `X = g(B) = f⁻¹(B)` for brightness `B` (clamped to `[0, 1]`;
    /// NaN reads as 0). `g(0) = 0`, `g(1) = 1`. Exact for the closed-form curves; the
    /// strong toe is inverted by bisection to full `f64` precision.
    pub fn inverse(&self, b: f64) -> f64 {
        if b.is_nan() || b <= 0.0 {
            return 0.0;
        }
        if b >= 1.0 {
            return 1.0;
        }
        match self {
            ResponseCurve::Linear => b,
            ResponseCurve::Gamma(gamma) => b.powf(*gamma),
            ResponseCurve::Srgb => {
                if b <= 0.040_45 {
                    b / 12.92
                } else {
                    ((b + 0.055) / 1.055).powf(2.4)
                }
            }
            ResponseCurve::FilmS => {
                (FILM_S_HALF * b / (1.0 + FILM_S_HALF - b)).powf(FILM_S_POWER.recip())
            }
            ResponseCurve::StrongToe => bisect(|x| self.brightness(x), b),
            ResponseCurve::Sampled(table) => invert_even(table, b),
        }
    }
}

/// The toe `h(X) = X³ / (X² + t²)`: strictly increasing, `≈ X³/t²` below `t`, `≈ X` above.
fn toe(x: f64) -> f64 {
    x * x * x / (x * x + TOE_WIDTH * TOE_WIDTH)
}

/// Solves `f(x) = b` for a strictly increasing `f` on `[0, 1]` by bisection.
fn bisect(f: impl Fn(f64) -> f64, b: f64) -> f64 {
    let (mut lo, mut hi) = (0.0_f64, 1.0_f64);
    // 64 halvings take the bracket below the spacing of f64 near any x in (0, 1].
    for _ in 0..64 {
        let mid = 0.5 * (lo + hi);
        if mid <= lo || mid >= hi {
            break;
        }
        if f(mid) < b {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// Linear interpolation of samples on the even grid `X_i = i/(n−1)`, at `x ∈ (0, 1)`.
fn interpolate_even(b: &[f64], x: f64) -> f64 {
    match b.len() {
        0 => x,
        1 => b[0],
        n => {
            let p = x * (n - 1) as f64;
            let i = (p as usize).min(n - 2);
            let t = p - i as f64;
            b[i] + t * (b[i + 1] - b[i])
        }
    }
}

/// Exact inverse of [`interpolate_even`] for increasing samples, at `v ∈ (0, 1)`.
fn invert_even(b: &[f64], v: f64) -> f64 {
    let n = b.len();
    if n < 2 {
        return v;
    }
    // First sample above v; the segment [i, i+1] contains v.
    let j = b.partition_point(|&s| s <= v).clamp(1, n - 1);
    let i = j - 1;
    let rise = b[j] - b[i];
    let t = if rise > 0.0 {
        ((v - b[i]) / rise).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (i as f64 + t) / (n - 1) as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    fn all_curves() -> Vec<(String, ResponseCurve)> {
        let mut curves = ResponseCurve::builtin();
        curves.push(("gamma-1.8".into(), ResponseCurve::Gamma(1.8)));
        curves.push((
            "sampled".into(),
            ResponseCurve::sampled(vec![0.0, 0.5, 0.6, 0.9, 1.0]).unwrap(),
        ));
        curves
    }

    #[test]
    fn every_curve_is_normalised_strictly_increasing_and_inverted() {
        for (name, curve) in all_curves() {
            assert_eq!(curve.brightness(0.0), 0.0, "{name}");
            assert_eq!(curve.brightness(1.0), 1.0, "{name}");
            assert_eq!(curve.inverse(0.0), 0.0, "{name}");
            assert_eq!(curve.inverse(1.0), 1.0, "{name}");
            let mut previous = 0.0;
            for i in 1..=1000 {
                let x = f64::from(i) / 1000.0;
                let b = curve.brightness(x);
                assert!(b > previous, "{name}: f({x}) = {b} not above {previous}");
                previous = b;
                let back = curve.inverse(b);
                assert!((back - x).abs() < 1e-9, "{name}: g(f({x})) = {back}");
            }
        }
    }

    #[test]
    fn curves_have_their_documented_values() {
        let srgb = ResponseCurve::Srgb;
        assert!((srgb.brightness(0.18) - 0.461_356).abs() < 1e-5);
        assert!((srgb.brightness(0.002) - 0.025_84).abs() < 1e-6);
        assert!(
            (ResponseCurve::Gamma(2.2).brightness(0.5) - 0.5_f64.powf(1.0 / 2.2)).abs() < 1e-15
        );
        assert!((ResponseCurve::FilmS.brightness(0.18) - 0.46).abs() < 1e-12);
        // A film-like S: toe (slope below 1 near black), shoulder (slope below 1 near white).
        let film = ResponseCurve::FilmS;
        assert!(film.brightness(0.01) < 0.01);
        assert!((film.brightness(1.0) - film.brightness(0.9)) / 0.1 < 0.2);
        let toe = ResponseCurve::StrongToe;
        assert!((toe.brightness(0.01) - 0.0152).abs() < 1e-3);
        assert!(toe.brightness(0.01) < 0.2 * ResponseCurve::Gamma(2.2).brightness(0.01));
        let sampled = ResponseCurve::sampled(vec![0.0, 0.5, 1.0]).unwrap();
        assert_eq!(sampled.brightness(0.25), 0.25);
        let sampled = ResponseCurve::sampled(vec![0.0, 0.8, 1.0]).unwrap();
        assert!((sampled.brightness(0.25) - 0.4).abs() < 1e-15);
        assert!((sampled.inverse(0.9) - 0.75).abs() < 1e-15);
    }

    #[test]
    fn invalid_curves_are_refused() {
        assert!(ResponseCurve::Gamma(0.0).check().is_err());
        assert!(ResponseCurve::Gamma(f64::NAN).check().is_err());
        assert!(ResponseCurve::sampled(vec![0.0]).is_err());
        assert!(ResponseCurve::sampled(vec![0.0, 0.5, 0.5, 1.0]).is_err());
        assert!(ResponseCurve::sampled(vec![0.0, 0.6, 0.5, 1.0]).is_err());
        assert!(ResponseCurve::sampled(vec![0.1, 1.0]).is_err());
        assert!(ResponseCurve::sampled(vec![0.0, f64::NAN, 1.0]).is_err());
    }
}
