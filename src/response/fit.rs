//! Fitting one channel's inverse response to the tone pairs `g(τ(b)) = γ·g(b)`.
//!
//! **Model: `ln g` as a monotone spline of `x = ln b`.** On the fit domain `[x₀, 0]`
//! (`x₀ = ln` of the darkest usable tone) `u(x) = ln g = Σ_m c_m·N_m(x)` in a clamped
//! B-spline basis (see [`super::spline`]) with `c_m = −Σ_{j>m} d_j` and every increment
//! `d_j ≥ 0`, so the coefficients rise (`u`, hence `g`, is non-decreasing by construction)
//! and the last is 0, so `g(1) = 1` exactly. Written with the increments,
//! `u(x) = Σ_j d_j·R_j(x)` (the ramps `R_j = Σ_{m≥j} N_m − 1` rise from −1 to 0), each tone
//! pair becomes one equation that is *linear* in `d`:
//!
//! `u(ln τ) − u(ln b) = Σ_j d_j·(R_j(ln τ) − R_j(ln b)) = ln γ`.
//!
//! `auto` (the default) is a cubic spline of [`AUTO_PIECES`] pieces with knots evenly
//! spaced in brightness between the darkest and the brightest tone of the equations: the
//! tone pairs are spread evenly over the codes, so every piece gets its share of the data,
//! and the top codes — where a shoulder bends `g` steeply and a polynomial in `ln b`
//! (whose domain they occupy one percent of) cannot follow — get a piece of their own.
//! A fixed degree `n` (`Degree::Fixed`, the report's 6) is one polynomial with no interior
//! knots: the Bernstein polynomial of degree `n` in `ln b`.
//!
//! Why this family: a power law `g = b^k` (gamma curves, most of sRGB) is a straight line
//! in `(ln b, ln g)`; errors are measured relative to `g` (stops), which is what a radiance
//! merge needs, so dark tones are not swamped by bright ones; every equation is a
//! difference, so the normalisation `g(1)=1` never enters the fit and cannot pull on it;
//! and at a large ratio the same difference equation links the dark and bright ends
//! through the overlap. Below the darkest usable tone `b₀`, `g` continues as the power law
//! `g(b₀)·(b/b₀)^s` with the end slope `s` (≥ 0.5), which gives `g(0) = 0`.
//!
//! **Solve.** Weighted non-negative least squares `min ‖W(A d − ln γ)‖`, `d ≥ 0`: the
//! weighted design is reduced by a Householder QR to its triangle, and the Lawson–Hanson
//! active-set method runs on that triangle with SVD solves of the free columns. No normal
//! equations are formed. Down the cross-validation grid each fold's solve starts from
//! the previous smoothness's solution, whose free set is usually the answer's (the
//! minimum is the same from any feasible start).
//!
//! **Weights** are inverse variances: an error `σ_b` in a tone moves `ln g` by
//! `s(b)·σ_b/b` (`s = d ln g / d ln b`), so `σ² = (s_b σ_b/b)² + (s_τ σ_τ/τ)²`, with `σ_b,
//! σ_τ` from the histogram (bin width and pixel support, see
//! [`crate::histogram::tone_pairs`]) and the slopes from the previous fit (a pilot takes
//! `s = 1`).
//!
//! **Smoothness.** Two exposures determine `g` only up to functions that repeat along the
//! chain `b → τ(b) → τ(τ(b))`, i.e. with period `ln γ` in `ln g` (Grossberg & Nayar's
//! ambiguity): a flexible model can add such ripples without changing any residual. A
//! penalty on curvature removes them. It is the curvature of the log–log *response*
//! `ln b` as a function of the log exposure `ln g` — film curves and camera tone curves
//! are smooth functions of log exposure, and the ambiguity's ripples are evenly spaced
//! along it:
//!
//! `λ·∫ (d² ln b / d(ln g)²)² d ln g = λ·∫ u''(x)² / u'(x)⁵ dx`,
//!
//! made linear by taking `u'` from the previous fit: `λ·∫ (S/s(x))⁵·u''(x)² dx` with
//! [`SLOPE_SCALE`] `S = 2` (a gamma-2 curve is penalised as the plain log–log curvature;
//! units nats² per nat of log brightness). Where the curve is steep — a shoulder near
//! white, where the last few codes span a stop or more of exposure — the plain curvature
//! `∫ u''² dx` would make the bend prohibitively dear and flatten the top of `g`, and
//! through `g(1) = 1` shift the whole curve. The integral is taken by Gauss–Legendre nodes on every piece
//! ([`Basis::curvature_quadrature`], exact for the plain curvature), added as rows of the
//! least-squares system. A power law costs nothing.
//!
//! **Model size.** The data choose how much of the spline's freedom is used: `λ` by
//! blocked 5-fold cross-validation over [`SMOOTHING_GRID`]. The tone pairs, in tone order,
//! are cut into 5 contiguous blocks and each is predicted from the other four; neighbouring
//! tone pairs share pixels, so random folds leak and always prefer the most flexible model;
//! contiguous blocks test what matters, the curve between and beyond the data. The
//! largest `λ` whose score is within half a standard error of the lowest is taken
//! ([`STANDARD_ERRORS`]), but never below `3·10⁻⁷·(ln γ)⁴` of the data weight:
//! the ripples cross-validation cannot see repeat every `ln γ` along `ln g`, a ripple of
//! amplitude `A` and period `P` costs `∝ A²/P⁴` of curvature, so a larger ratio needs a
//! larger `λ` to keep them down. The result reports the *effective number of parameters*
//! (the trace of the penalised fit's hat matrix) as the size the data chose.
//!
//! The fit runs three times: a pilot (unit slopes, plain log–log curvature), then twice
//! with the weights and the penalty taken from the previous fit's slopes.
//!
//! **Robust weights.** Then each equation's weighted residual `r_i` (in units of the noise
//! model's standard deviation) is compared with the robust spread `ŝ = 1.4826·median|r|`
//! (at least 10⁻³: exact equations leave only rounding) and, beyond `c·ŝ` (Huber's
//! `c = 3`), its weight is multiplied by `c·ŝ/|r_i|` (one step of Huber's M-estimator)
//! before the smoothness is chosen again. Without it a few equations no smooth curve
//! explains — a JPEG's highlights ringing next to white when the file is not known as a
//! JPEG, a sparse bin — set the cross-validated smoothness of the whole curve and bend its
//! toe.

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

use super::spline::Basis;
use crate::histogram::TonePair;

/// Largest degree a fixed-degree polynomial (`Degree::Fixed`) may ask for.
pub const MAX_DEGREE: usize = 16;

/// How the model size is chosen.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Degree {
    /// A cubic spline of [`AUTO_PIECES`] pieces, smoothness by blocked cross-validation
    /// (see module docs).
    Auto,
    /// One polynomial of fixed degree `1..=MAX_DEGREE` (the report used 6).
    Fixed(usize),
}

/// Why a channel could not be fitted.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FitError {
    /// Too few tones are usable in both frames (unclipped and above the noise floor).
    #[error(
        "only {0} tone pairs are usable in both frames (need at least 2): the frames share too little tonal range"
    )]
    TooFewTones(usize),
    /// The degree is outside `1..=MAX_DEGREE`.
    #[error("degree {0} is outside 1..={MAX_DEGREE}")]
    Degree(usize),
    /// The tone mapping runs the wrong way (the "bright" frame is darker).
    #[error(
        "its tones run backwards: the brighter frame is darker than the darker one in most of them"
    )]
    Swapped,
    /// The fitted curve falls deeper below white than any camera records
    /// ([`DEEPEST_STOPS`]) within the tones its equations covered: contradictory
    /// equations, not a response.
    #[error(
        "the fitted curve is degenerate: {stops:.0} stops below white at brightness {at:.3}, inside the tones the frames cover"
    )]
    Degenerate {
        /// How far below white, in stops (infinite for `g = 0`).
        stops: f64,
        /// The brightness where it is that deep.
        at: f64,
    },
}

/// The deepest a fitted curve may fall below white over the tones its equations covered,
/// in stops: twice the 16 stops of 16-bit linear data. A curve beyond it (or one that is
/// not finite there) is refused as [`FitError::Degenerate`].
pub const DEEPEST_STOPS: f64 = 32.0;

/// Refuses a fit whose `log₂ g` at the darkest covered tone, or anywhere on a grid of 64
/// brightnesses across the covered range, is below `−DEEPEST_STOPS` or not finite.
fn check_degenerate(fit: &ChannelFit) -> Result<(), FitError> {
    let (lo, hi) = fit.covered;
    let curve = fit.curve();
    for i in 0..=64 {
        let b = lo + (hi - lo) * f64::from(i) / 64.0;
        let stops = -curve.log_g(b) / std::f64::consts::LN_2;
        if stops.is_nan() || stops > DEEPEST_STOPS {
            return Err(FitError::Degenerate { stops, at: b });
        }
    }
    Ok(())
}

/// One channel's fitted inverse response and how well the data determined it.
#[derive(Debug, Clone, PartialEq)]
pub struct ChannelFit {
    /// Degree `p` of the polynomial pieces of `ln g`.
    pub degree: usize,
    /// Interior knots of the spline, in `ln b` (empty: one polynomial over the domain).
    pub knots: Vec<f64>,
    /// Smoothness weight `λ / Σw` chosen for the log–log curvature penalty.
    pub smoothing: f64,
    /// B-spline coefficients `c_0 ≤ … ≤ c_{n−1} = 0` of `ln g` on the fit domain (for a
    /// polynomial, its Bernstein coefficients).
    pub coefficients: Vec<f64>,
    /// `x₀ = ln b₀`: the fit domain is `ln b ∈ [x₀, 0]`.
    pub log_floor: f64,
    /// Brightness range the equations covered: darkest dark tone, brightest bright tone.
    /// Outside it the curve is extrapolated.
    pub covered: (f64, f64),
    /// Root-mean-square equation residual `ln(g(τ)/(γ g(b)))`, weighted, in stops.
    pub residual_rms: f64,
    /// Number of equations (tone pairs) used.
    pub equations: usize,
    /// Effective number of parameters: the trace of the penalised fit's hat matrix
    /// (at most `coefficients.len() − 1`; fewer the more the smoothness constrains it).
    pub effective_parameters: f64,
    /// Condition number of the weighted design matrix (ratio of extreme singular values).
    pub condition: f64,
    /// Predicted standard error of `log₂ g` over [`ASSESSED_CODES`] (stops), from the fit's
    /// covariance scaled by the residual misfit: the curve's level (its anchor `g(1) = 1`
    /// extrapolated down to the codes) and its shape together.
    pub predicted_error: f64,
    /// The part of [`ChannelFit::predicted_error`] that is shape: the standard error of
    /// `log₂ g(b) − mean_b log₂ g(b)` over the same codes (stops), what is left after the
    /// level that the channels' balance and the map's own scale take out.
    pub predicted_shape_error: f64,
    /// Fraction of the tones of [`ASSESSED_CODES`] inside [`ChannelFit::covered`].
    pub coverage: f64,
    /// Weighted misfit per degree of freedom, `χ² / (m − p_eff)` (dimensionless): about
    /// 1 when the equations scatter as the histograms' noise model says (bin width, pixel
    /// count, 1 DN), larger when the frames disagree beyond it (a codec, a wrong ratio).
    pub misfit: f64,
    /// `ln γ` of the equations (the smallest of a bracket's pairs).
    pub log_ratio: f64,
    /// How much of the curve is extrapolated above the brightest tone the equations
    /// reached, `−log₂ g(b_hi)` in stops: `g(1) = 1` anchors the whole channel through
    /// this span, so its error is the channel's scale error.
    pub top_span: f64,
    /// The probability that the channel is good in what a relative radiance map shows:
    /// shape error ≤ 0.1 stop and scale within 0.05 stop of the map's level (the mean of
    /// the channels' scales; see [`CONFIDENCE_MODEL`]): the logistic model of
    /// [`ChannelFit::features`], capped where the predicted shape error reaches 0.2 stop
    /// and times [`ChannelFit::coverage`]; in `[0, 1]`, below [`LOW_CONFIDENCE`] is "low".
    pub confidence: f64,
}

/// The 8-bit codes (of 255) over which a response's error is judged and its coverage
/// counted: the tones a merge relies on, past the toe's noise and the shoulder's clipping.
pub const ASSESSED_CODES: std::ops::RangeInclusive<u32> = 16..=239;

/// A fit's confidence below this is low: the odds are against its being good (the
/// confidence is a probability), so it is reported and a response of the body's own is
/// preferred to it.
pub const LOW_CONFIDENCE: f64 = 0.5;

impl ChannelFit {
    /// The spline basis of `ln g` on `[x₀, 0]`.
    pub(crate) fn basis(&self) -> Basis {
        Basis::new(self.degree, self.log_floor, 0.0, &self.knots)
    }

    /// The model family in words: a monotone spline (or, without interior knots, a
    /// Bernstein polynomial) of `ln g` over `ln b`.
    pub fn family(&self) -> String {
        if self.knots.is_empty() {
            "monotone Bernstein polynomial of ln g over ln b".to_string()
        } else if self.degree == 3 {
            "monotone cubic spline of ln g over ln b".to_string()
        } else {
            format!("monotone degree-{} spline of ln g over ln b", self.degree)
        }
    }

    /// The model's size: its pieces (or degree) and the effective number of parameters
    /// the data chose, e.g. `10 pieces, 5.2 effective parameters`.
    pub fn size(&self) -> String {
        let shape = if self.knots.is_empty() {
            format!("degree {}", self.degree)
        } else {
            format!("{} pieces", self.knots.len() + 1)
        };
        format!(
            "{shape}, {:.1} effective parameters",
            self.effective_parameters
        )
    }

    /// [`ChannelFit::family`] with [`ChannelFit::size`] in brackets.
    pub fn model(&self) -> String {
        format!("{} ({})", self.family(), self.size())
    }

    /// `ln g(b)` for `b > 0`.
    pub(crate) fn log_g(&self, b: f64) -> f64 {
        self.curve().log_g(b)
    }

    /// `g(b)`, with `g(0) = 0` and `g(1) = 1`.
    pub fn eval(&self, b: f64) -> f64 {
        if b.is_nan() || b <= 0.0 {
            return 0.0;
        }
        self.log_g(b).exp().min(1.0)
    }

    /// The curve with its basis built once, to evaluate at many tones.
    pub fn curve(&self) -> LogResponse {
        LogResponse {
            basis: self.basis(),
            coefficients: self.coefficients.clone(),
            log_floor: self.log_floor,
        }
    }

    /// What the fit knows about its own error, the inputs of [`CONFIDENCE_MODEL`]:
    ///
    /// 1. `ln(predicted_shape_error + 0.001)`: the covariance's standard error of the
    ///    curve's shape (`log₂ g` less its mean over the codes);
    /// 2. `ln(max(misfit, 0.1))`: the misfit relative to the noise model;
    /// 3. `ln ln γ`, `γ` clamped to [`CALIBRATED_RATIOS`], the ratios the model was fitted
    ///    on (small ratios leave the chain ambiguity loose, large ones few shared tones).
    ///
    /// The extrapolated span above the brightest tone ([`ChannelFit::top_span`]) is not
    /// one: it sets the level, which the confidence does not speak of, and with it the
    /// model predicted held-out channels worse.
    pub fn features(&self) -> [f64; FEATURES] {
        [
            (self.predicted_shape_error.min(1e6) + 0.001).ln(),
            self.misfit.max(0.1).ln(),
            self.log_ratio
                .clamp(CALIBRATED_RATIOS[0].ln(), CALIBRATED_RATIOS[1].ln())
                .ln(),
        ]
    }
}

/// A fitted `ln g` with its spline basis built once, to evaluate at many tones
/// ([`ChannelFit::curve`]).
#[derive(Debug, Clone)]
pub struct LogResponse {
    basis: Basis,
    coefficients: Vec<f64>,
    log_floor: f64,
}

impl LogResponse {
    /// `ln g(b)` for `b > 0`: the spline of `x = ln b` on `[x₀, 0]`, and below `b₀` the
    /// power law `g(b₀)·(b/b₀)^s` with the end slope `s = max(0.5, u'(x₀))`.
    pub(crate) fn log_g(&self, b: f64) -> f64 {
        let x = b.min(1.0).ln();
        if x < self.log_floor {
            let s = self
                .basis
                .slope(&self.coefficients, self.log_floor)
                .max(0.5);
            return self.basis.eval(&self.coefficients, self.log_floor) + s * (x - self.log_floor);
        }
        self.basis.eval(&self.coefficients, x)
    }

    /// `d ln g / d ln b` at brightness `b` (within the fit domain; clamped to it).
    pub(crate) fn log_slope(&self, b: f64) -> f64 {
        let x = b.clamp(self.log_floor.exp(), 1.0).ln();
        self.basis.slope(&self.coefficients, x)
    }
}

/// Number of [`ChannelFit::features`].
pub const FEATURES: usize = 3;

/// The logistic model of the confidence: `p = 1 / (1 + exp(−(β₀ + Σ_k β_k·x_k)))` with
/// `x` the [`ChannelFit::features`] and `β = CONFIDENCE_MODEL`, the probability that
/// the channel is good in what a relative radiance map shows: shape error ≤ 0.1 stop and
/// its scale error within 0.05 stop of the mean of the calibration's channels' (after the
/// channels' balance, the part of its scale that is a colour cast). The map's common
/// level, set by `g(1) = 1` above the brightest tone any equation reaches, is not part of
/// it: no feature of the histograms predicts it (docs/accuracy.md states its spread, "How
/// accurate is a response from a pair?"). Fitted by maximum likelihood on the tuning split
/// of `benches/accuracy/response_accuracy.rs` (DoRF records ≡ 0 mod 4, every fourth of them, scenes
/// at seed 7, every scene kind, 512×384, 8-bit lossless, JPEG q95 and 16-bit at ratios
/// 2–16 and 3-frame brackets at ratio 4, lossless and JPEG q90); `--fit-confidence FILES
/// --target colour` refits it, and docs/accuracy.md ("When can I trust the confidence?")
/// gives its reliability on the report split. A larger predicted shape error, a larger
/// misfit and a larger ratio make a bad channel likelier: on the tuning split the channels
/// that are bad this way are almost all shape errors of pairs 8–16 apart, whose few shared
/// tones leave the curve between them loose. The confidence is `p·coverage`: the tuning scenes almost always cover the
/// codes 16..239, so the model has not seen what an uncovered curve does.
pub const CONFIDENCE_MODEL: [f64; FEATURES + 1] = [17.058, -1.240, -2.147, -19.467];

/// The exposure ratios [`CONFIDENCE_MODEL`] was fitted on (pairs 2× to 16× apart). Beyond
/// 16× it trusts up to one 8-bit channel in six that is off in shape or colour
/// (docs/accuracy.md, "When can I trust the confidence?"); callers say so
/// ([`super::beyond_calibrated_ratios`]).
pub const CALIBRATED_RATIOS: [f64; 2] = [2.0, 16.0];

/// The confidence of features `x` under the logistic model `beta` (see
/// [`CONFIDENCE_MODEL`]).
pub fn logistic_confidence(beta: &[f64; FEATURES + 1], x: &[f64; FEATURES]) -> f64 {
    let z = beta[0] + beta[1..].iter().zip(x).map(|(b, x)| b * x).sum::<f64>();
    1.0 / (1.0 + (-z).exp())
}

/// Unweighted design: row `i` is `R(ln τ_i) − R(ln b_i)` of pair `i` (see [`Basis::ramps`]).
fn design(basis: &Basis, pairs: &[TonePair]) -> DMatrix<f64> {
    let n = basis.len() - 1;
    let mut a = DMatrix::zeros(pairs.len(), n);
    for (i, p) in pairs.iter().enumerate() {
        let (lo, hi) = (
            basis.ramps(p.dark.ln()),
            basis.ramps(p.bright.min(1.0).ln()),
        );
        for j in 0..n {
            a[(i, j)] = hi[j] - lo[j];
        }
    }
    a
}

/// Rows of the curvature penalty `∫ (S/s(x))⁵·u''(x)² dx` over the fit domain
/// `x = ln b ∈ [x₀, 0]` (see the module docs; `s(x)` the log–log slope of the previous fit,
/// clamped to `[0.3, 100]`; `None`: plain `∫ u''² dx`): row `q` is `√(w_q·(S/s)⁵)·R_j''(x_q)`
/// at the nodes and weights of [`Basis::curvature_quadrature`], so that `‖P d‖²` is the
/// integral (exactly without the slope weight; units: nats² per nat of log brightness).
fn curvature(basis: &Basis, slope: Option<&dyn Fn(f64) -> f64>) -> DMatrix<f64> {
    let rule = basis.curvature_quadrature();
    let n = basis.len() - 1;
    let mut p = DMatrix::zeros(rule.len(), n);
    for (q, &(x, w)) in rule.iter().enumerate() {
        let stiffness = slope.map_or(1.0, |s| (SLOPE_SCALE / s(x).clamp(0.3, 100.0)).powi(5));
        let scale = (w * stiffness).sqrt();
        for (j, r) in basis.ramp_curvatures(x).into_iter().enumerate() {
            p[(q, j)] = scale * r;
        }
    }
    p
}

/// The log–log slope `S` at which the penalty is the plain curvature `∫ u''² dx`: a
/// gamma-2 curve (see the module docs).
pub const SLOPE_SCALE: f64 = 2.0;

/// `min ‖A x − y‖` subject to `x ≥ 0` (Lawson–Hanson), after a QR reduction of `A`,
/// from the feasible point `start` (non-negative; `None`: the origin).
///
/// The active-set iterations move between feasible points, so any feasible start reaches
/// the same minimum (unique where `A` has full column rank, as with the curvature rows):
/// started from the solution of a neighbouring problem (the next smoothness of a
/// cross-validation grid), whose free set is usually already the answer's, it takes one
/// or two subproblem solves instead of one per free variable.
fn nnls(a: &DMatrix<f64>, y: &DVector<f64>, start: Option<&DVector<f64>>) -> DVector<f64> {
    let n = a.ncols();
    let qr = a.clone().qr();
    let r = qr.r();
    let z = qr.q().transpose() * y;
    let tol = 1e-12 * (1.0 + r.norm() * z.norm());
    let mut x = match start {
        Some(s) if s.len() == n && s.iter().all(|&v| v >= 0.0) => s.clone(),
        _ => DVector::zeros(n),
    };
    let mut free: Vec<bool> = x.iter().map(|&v| v > 0.0).collect();
    // Solves on the free set, stepping back towards the feasible `x` (and freeing what
    // reaches zero) until the free set's solution is positive.
    let settle = |x: &mut DVector<f64>, free: &mut Vec<bool>| loop {
        let cols: Vec<usize> = (0..n).filter(|&j| free[j]).collect();
        let sub = r.select_columns(&cols);
        let sol = sub
            .svd(true, true)
            .solve(&z, 1e-13)
            .unwrap_or_else(|_| DVector::zeros(cols.len()));
        if sol.iter().all(|&v| v > 0.0) {
            x.fill(0.0);
            for (k, &c) in cols.iter().enumerate() {
                x[c] = sol[k];
            }
            break;
        }
        let mut alpha = 1.0f64;
        for (k, &c) in cols.iter().enumerate() {
            if sol[k] <= 0.0 {
                alpha = alpha.min(x[c] / (x[c] - sol[k]));
            }
        }
        for (k, &c) in cols.iter().enumerate() {
            x[c] += alpha * (sol[k] - x[c]);
            if x[c] <= 1e-15 {
                x[c] = 0.0;
                free[c] = false;
            }
        }
        if !free.iter().any(|&f| f) {
            break;
        }
    };
    if free.iter().any(|&f| f) {
        settle(&mut x, &mut free);
    }
    for _ in 0..3 * n + 3 {
        let grad = r.transpose() * (&z - &r * &x);
        let pick = (0..n)
            .filter(|&j| !free[j] && grad[j] > tol)
            .max_by(|&i, &j| grad[i].total_cmp(&grad[j]));
        let Some(j) = pick else { break };
        free[j] = true;
        settle(&mut x, &mut free);
    }
    x
}

/// Smoothness strengths `λ` tried, as multiples of the total data weight `Σ w`: ten
/// decades in half-decade steps. The penalty's scale relative to the data's varies by
/// orders of magnitude between curves, hence the span; half decades let the standard-error
/// margin ([`STANDARD_ERRORS`]) stop short of a whole decade more smoothing than the data
/// allow.
pub const SMOOTHING_GRID: [f64; 21] = [
    1.0, 3.162e-1, 1e-1, 3.162e-2, 1e-2, 3.162e-3, 1e-3, 3.162e-4, 1e-4, 3.162e-5, 1e-5, 3.162e-6,
    1e-6, 3.162e-7, 1e-7, 3.162e-8, 1e-8, 3.162e-9, 1e-9, 3.162e-10, 1e-10,
];

/// The least smoothness `λ/Σw` cross-validation may choose at exposure ratio `γ`:
/// [`RIPPLE_FLOOR`]`·(ln γ)⁴` (see the module docs: the ambiguity's ripples lengthen with
/// the ratio, cost less curvature, and change no residual, so cross-validation cannot see
/// them).
fn ripple_floor(log_ratio: f64) -> f64 {
    RIPPLE_FLOOR * log_ratio.powi(4)
}

/// The constant of [`ripple_floor`]. Chosen on the DoRF curves (8-bit lossless) with the
/// earlier degree-12 polynomial: at ratio 64 the 90th-percentile shape error fell from
/// 0.61 to 0.29 stops (1e-7: 0.34, 1e-6: 0.24 but seven confident wrong curves at ratio
/// 16). Kept for the spline and its slope-weighted penalty, where ratio 64 gives 0.12.
const RIPPLE_FLOOR: f64 = 3e-7;

/// The weighted equations of one channel in one basis.
struct Problem {
    /// The basis of `ln g`.
    basis: Basis,
    /// Unweighted design, one row per equation (see [`design`]).
    design: DMatrix<f64>,
    /// Curvature penalty rows (see [`curvature`]).
    penalty: DMatrix<f64>,
    /// `1/σ` per equation.
    sqrt_w: Vec<f64>,
    /// `ln γ` per equation (one value for a pair of frames; a bracket's pairs differ).
    log_ratios: Vec<f64>,
    /// The `ln γ` whose ripples the smoothness floor must hold down: the smallest of the
    /// equations' (see [`ripple_floor`]).
    ripple_log_ratio: f64,
    /// Factor on the covariance for equations that share histograms beyond one pair
    /// (see [`fit_joint`]); 1 for one pair.
    dependence: f64,
}

impl Problem {
    fn equations(&self) -> usize {
        self.design.nrows()
    }

    /// Number of unknown increments `d_j` (one fewer than the spline's coefficients).
    fn unknowns(&self) -> usize {
        self.design.ncols()
    }

    fn total_weight(&self) -> f64 {
        self.sqrt_w.iter().map(|w| w * w).sum()
    }

    /// The weighted data rows `rows` and their right-hand sides `√w·ln γ`.
    fn weighted(&self, rows: &[usize]) -> (DMatrix<f64>, DVector<f64>) {
        let n = self.unknowns();
        let a = DMatrix::from_fn(rows.len(), n, |r, j| {
            self.sqrt_w[rows[r]] * self.design[(rows[r], j)]
        });
        let y = DVector::from_iterator(
            rows.len(),
            rows.iter().map(|&i| self.sqrt_w[i] * self.log_ratios[i]),
        );
        (a, y)
    }

    /// Data rows plus the penalty rows times `√λ`.
    fn system(&self, lambda: f64, rows: &[usize]) -> (DMatrix<f64>, DVector<f64>) {
        let (a, y) = self.weighted(rows);
        self.with_penalty(lambda, &a, &y)
    }

    /// `[a; √λ·P]` and `[y; 0]`.
    fn with_penalty(
        &self,
        lambda: f64,
        a: &DMatrix<f64>,
        y: &DVector<f64>,
    ) -> (DMatrix<f64>, DVector<f64>) {
        let (k, extra) = (a.nrows(), self.penalty.nrows());
        let mut full = DMatrix::zeros(k + extra, self.unknowns());
        full.rows_mut(0, k).copy_from(a);
        full.rows_mut(k, extra)
            .copy_from(&(&self.penalty * lambda.sqrt()));
        let mut full_y = DVector::zeros(k + extra);
        full_y.rows_mut(0, k).copy_from(y);
        (full, full_y)
    }

    /// The data rows `rows` reduced to their `n × n` QR triangle `R` and `z = Qᵀ√w·ln γ`:
    /// `‖A d − y‖² = ‖R d − z‖² + const`, so every `λ` of a cross-validation fold solves the
    /// small system `[R; √λ·P] d ≈ [z; 0]` instead of all the fold's rows again.
    fn reduce(&self, rows: &[usize]) -> (DMatrix<f64>, DVector<f64>) {
        let (a, y) = self.weighted(rows);
        let n = self.unknowns();
        if a.nrows() < n {
            return (a, y);
        }
        let qr = a.qr();
        let z = qr.q().transpose() * y;
        (qr.r(), z)
    }

    /// The non-negative solution of the reduced data rows `(r, z)` (see
    /// [`Problem::reduce`]) with the penalty rows times `√λ`.
    /// `start` is a feasible point to begin from (see [`nnls`]).
    fn solve_reduced(
        &self,
        lambda: f64,
        r: &DMatrix<f64>,
        z: &DVector<f64>,
        start: Option<&DVector<f64>>,
    ) -> DVector<f64> {
        let (a, y) = self.with_penalty(lambda, r, z);
        nnls(&a, &y, start)
    }

    /// The curve of the penalised solution at smoothness `λ` on all equations (what
    /// [`finish`] reports on, without the report).
    fn curve(&self, lambda: f64, log_floor: f64) -> LogResponse {
        let rows: Vec<usize> = (0..self.equations()).collect();
        let (a, y) = self.system(lambda, &rows);
        let d = nnls(&a, &y, None);
        LogResponse {
            basis: self.basis.clone(),
            coefficients: self.basis.coefficients(d.as_slice()),
            log_floor,
        }
    }

    /// Sum of squared weighted data residuals of `d` on `rows`.
    fn misfit(&self, d: &DVector<f64>, rows: &[usize]) -> f64 {
        let (a, y) = self.weighted(rows);
        (a * d - y).norm_squared()
    }

    /// Chooses the smoothness `λ` by blocked 5-fold cross-validation: among the values
    /// the ripple floor allows, the largest whose score is within [`STANDARD_ERRORS`]
    /// standard errors of the lowest.
    fn choose_smoothing(&self) -> Smoothing {
        const FOLDS: usize = 5;
        let (m, n) = (self.equations(), self.unknowns());
        let scale = self.total_weight();
        if m < 2 * FOLDS || n <= 1 {
            let only = scale * SMOOTHING_GRID[0];
            return Smoothing {
                chosen: only,
                best: only,
            };
        }
        let fold_of = |i: usize| i * FOLDS / m;
        let floor = ripple_floor(self.ripple_log_ratio);
        let grid: Vec<f64> = SMOOTHING_GRID
            .iter()
            .copied()
            .chain((floor < SMOOTHING_GRID[0]).then_some(floor))
            .collect();
        // Held-out misfit per equation of every fold at every λ: the folds in parallel,
        // each running down the grid from one solution to the next (see [`nnls`]).
        let held_out: Vec<Vec<f64>> = (0..FOLDS)
            .into_par_iter()
            .map(|f| {
                let train: Vec<usize> = (0..m).filter(|&i| fold_of(i) != f).collect();
                let test: Vec<usize> = (0..m).filter(|&i| fold_of(i) == f).collect();
                let (r, z) = self.reduce(&train);
                let mut previous: Option<DVector<f64>> = None;
                grid.iter()
                    .map(|&k| {
                        let d = self.solve_reduced(scale * k, &r, &z, previous.as_ref());
                        let score = self.misfit(&d, &test) / test.len() as f64;
                        previous = Some(d);
                        score
                    })
                    .collect()
            })
            .collect();
        // (λ, mean held-out misfit per equation, its standard error, allowed by the
        // floor); λ descending, except for the floor itself, appended last.
        let scores: Vec<(f64, f64, f64, bool)> = grid
            .iter()
            .enumerate()
            .map(|(g, &k)| {
                let per_fold: Vec<f64> = held_out.iter().map(|fold| fold[g]).collect();
                let mean = per_fold.iter().sum::<f64>() / FOLDS as f64;
                let var =
                    per_fold.iter().map(|s| (s - mean).powi(2)).sum::<f64>() / (FOLDS - 1) as f64;
                (scale * k, mean, (var / FOLDS as f64).sqrt(), k >= floor)
            })
            .collect();
        let lowest = |allowed_only: bool| {
            scores
                .iter()
                .filter(|s| s.3 || !allowed_only)
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .copied()
                .unwrap_or((scale, 0.0, 0.0, true))
        };
        let best = lowest(true);
        // The largest allowed λ within the margin: the grid is descending and the floor,
        // appended last, is the smallest allowed value.
        let chosen = scores
            .iter()
            .filter(|s| s.3)
            .find(|s| s.1 <= best.1 + STANDARD_ERRORS * best.2)
            .map_or(best.0, |s| s.0);
        // The unconstrained best matters only where the floor overrode it.
        let unconstrained = lowest(false);
        Smoothing {
            chosen,
            best: if unconstrained.3 {
                chosen
            } else {
                unconstrained.0
            },
        }
    }
}

/// How many standard errors of the cross-validation score a smoother `λ` may lose to the
/// best and still be chosen (the one-standard-error rule, at half a standard error).
/// Scores of neighbouring `λ` often differ by noise alone; the smoother of two
/// indistinguishable curves has fewer ripples and a smaller predicted error. How the
/// choice trades accuracy against confidence is measured in `docs/accuracy.md`.
pub const STANDARD_ERRORS: f64 = 0.5;

/// The smoothness cross-validation chose, and the one it scored best with no floor.
#[derive(Debug, Clone, Copy)]
struct Smoothing {
    chosen: f64,
    best: f64,
}

/// Nominal sensor noise, brightness units (1 DN of an 8-bit frame), added to each side's
/// variance: without it the darkest tones, where noise bends the histograms most, would
/// carry as much weight as mid-tones.
const NOISE: f64 = 1.0 / 255.0;

/// Fits `ln g` to the tone pairs of one channel for a known `ln γ > 0` (see module docs).
pub fn fit(pairs: &[TonePair], log_ratio: f64, degree: Degree) -> Result<ChannelFit, FitError> {
    fit_joint(&[(pairs, log_ratio)], 2, degree)
}

/// Fits one `ln g` to the tone pairs of several frame pairs of one bracket of `frames`
/// frames at once, each set with its own `ln γ > 0`: every equation
/// `u(ln τ) − u(ln b) = ln γ_pair` constrains the same curve, so the frames' tonal
/// ranges add up. Ratios that are not whole multiples of one another also break the
/// chain ambiguity of each; an exposure bracket's (powers of one step) keep the ripples
/// of period `ln γ_step`, which the smoothness floor holds down.
///
/// The sets rest on only `frames` histograms: `k` sets from `N` frames carry at most the
/// information of `N − 1` independent (adjacent) pairs, so the covariance behind the
/// predicted error is scaled by `k/(N − 1)` when `k` is larger (1 for adjacent pairs).
/// The smoothness floor follows the smallest ratio, whose ripples are the shortest.
/// After the first fits, each set's weights are divided by `√max(1, χ̄²_set / χ̄²_best)`
/// (`χ̄²` the mean squared weighted residual of a set's equations against the joint
/// curve, `best` the smallest over sets): a pair that disagrees with the others counts
/// as noisier, not as evidence against them.
pub fn fit_joint(
    sets: &[(&[TonePair], f64)],
    frames: usize,
    degree: Degree,
) -> Result<ChannelFit, FitError> {
    check_request(sets, degree)?;
    let Equations {
        pairs,
        log_ratios,
        set_of,
    } = usable_equations(sets);
    let ripple_log_ratio = log_ratios.iter().copied().fold(f64::INFINITY, f64::min);
    let dependence = sets.len() as f64 / frames.saturating_sub(1).max(1) as f64;
    let m = pairs.len();
    if m < 2 {
        return Err(FitError::TooFewTones(m));
    }
    let darkest = pairs.iter().map(|p| p.dark).fold(f64::INFINITY, f64::min);
    let brightest = pairs.iter().map(|p| p.bright).fold(0.0, f64::max);
    let log_floor = darkest.ln().min(-1e-3);
    let basis = basis_for(degree, log_floor, (darkest, brightest), m);
    let mut problem = Problem {
        design: design(&basis, &pairs),
        penalty: curvature(&basis, None),
        basis,
        sqrt_w: noise_weights(&pairs, &|_| 1.0),
        log_ratios,
        ripple_log_ratio,
        dependence: dependence.max(1.0),
    };
    let mut smoothing = follow_the_slope(&mut problem, &pairs, log_floor);
    let fitted = problem.curve(smoothing.chosen, log_floor);
    let robust = match robust_factors(&mut problem, &pairs, &fitted) {
        Some(factors) => {
            smoothing = problem.choose_smoothing();
            factors
        }
        None => vec![1.0; pairs.len()],
    };
    if sets.len() > 1 {
        let joint = problem.curve(smoothing.chosen, log_floor);
        scale_by_set_scatter(&mut problem, &pairs, &set_of, sets.len(), &joint);
        smoothing = problem.choose_smoothing();
    }
    let mut fit = finish(&problem, smoothing.chosen, log_floor, (darkest, brightest));
    // The misfit the confidence reads is against the noise model, as the model was fitted:
    // without the robust factors.
    let chi2 = noise_chi2(&problem, &pairs, &robust, &fit.curve());
    fit.misfit = chi2 / (pairs.len() as f64 - fit.effective_parameters).max(1.0);
    fit.confidence = confidence(&fit);
    if smoothing.best != smoothing.chosen {
        let other = problem.curve(smoothing.best, log_floor);
        add_the_ambiguity(&mut fit, &other);
    }
    check_degenerate(&fit)?;
    Ok(fit)
}

/// Refuses a fixed degree outside `1..=MAX_DEGREE`, and sets whose tones run backwards
/// (the bright tone below the dark one) in more than half of all pairs.
fn check_request(sets: &[(&[TonePair], f64)], degree: Degree) -> Result<(), FitError> {
    if let Degree::Fixed(n) = degree
        && !(1..=MAX_DEGREE).contains(&n)
    {
        return Err(FitError::Degree(n));
    }
    let total: usize = sets.iter().map(|(p, _)| p.len()).sum();
    let backwards: usize = sets
        .iter()
        .map(|(p, _)| p.iter().filter(|p| p.bright < p.dark).count())
        .sum();
    if backwards * 2 > total {
        return Err(FitError::Swapped);
    }
    Ok(())
}

/// One equation `u(ln τ) − u(ln b) = ln γ` of [`fit_joint`].
struct Equation {
    /// Its tones `b` (dark) and `τ` (bright).
    pair: TonePair,
    /// `ln γ` of its set.
    log_ratio: f64,
    /// The index of its set.
    set: usize,
}

/// [`fit_joint`]'s equations in tone order, one field per part, equation `i` at index `i`
/// of each.
struct Equations {
    pairs: Vec<TonePair>,
    log_ratios: Vec<f64>,
    set_of: Vec<usize>,
}

/// The equations of the usable tone pairs of all `sets` (`0 < b < τ`, `τ` finite), in
/// order of their dark tone `b` when there are several sets (cross-validation blocks are
/// contiguous in tone; one set is already in tone order).
fn usable_equations(sets: &[(&[TonePair], f64)]) -> Equations {
    let mut equations: Vec<Equation> = sets
        .iter()
        .enumerate()
        .flat_map(|(set, (pairs, log_ratio))| {
            pairs
                .iter()
                .filter(|p| p.dark > 0.0 && p.bright > p.dark && p.bright.is_finite())
                .map(move |p| Equation {
                    pair: *p,
                    log_ratio: *log_ratio,
                    set,
                })
        })
        .collect();
    if sets.len() > 1 {
        equations.sort_by(|a, b| a.pair.dark.total_cmp(&b.pair.dark));
    }
    Equations {
        pairs: equations.iter().map(|e| e.pair).collect(),
        log_ratios: equations.iter().map(|e| e.log_ratio).collect(),
        set_of: equations.iter().map(|e| e.set).collect(),
    }
}

/// The basis of `ln g` on `[log_floor, 0]` for `degree`: one polynomial of a fixed
/// degree, or for `auto` a cubic spline of [`auto_pieces`]`(m)` pieces of equal width in
/// brightness over the `covered` tones `(darkest, brightest)` of `m` equations.
fn basis_for(degree: Degree, log_floor: f64, covered: (f64, f64), m: usize) -> Basis {
    let (darkest, brightest) = covered;
    match degree {
        Degree::Fixed(n) => Basis::new(n, log_floor, 0.0, &[]),
        Degree::Auto => Basis::new(
            SPLINE_DEGREE,
            log_floor,
            0.0,
            &even_knots(darkest, brightest, auto_pieces(m)),
        ),
    }
}

/// Variance of one equation's `ln τ − ln b` under the noise model, with the curve's
/// slopes `s_b`, `s_t` (`d ln g / d ln b`) at its two tones:
/// `s_b²·(σ_b² + N²)/b² + s_t²·(σ_τ² + N²)/τ²`, `N` the nominal [`NOISE`].
fn log_variance(p: &TonePair, s_b: f64, s_t: f64) -> f64 {
    let v_b = p.sigma_dark.powi(2) + NOISE * NOISE;
    let v_t = p.sigma_bright.powi(2) + NOISE * NOISE;
    s_b * s_b * v_b / (p.dark * p.dark) + s_t * s_t * v_t / (p.bright * p.bright)
}

/// `1/σ` of each equation ([`log_variance`]) with the slopes `slope(b)` of a curve, each
/// at least 0.3.
fn noise_weights(pairs: &[TonePair], slope: &dyn Fn(f64) -> f64) -> Vec<f64> {
    pairs
        .iter()
        .map(|p| {
            let s_b = slope(p.dark).max(0.3);
            let s_t = slope(p.bright).max(0.3);
            1.0 / log_variance(p, s_b, s_t).sqrt()
        })
        .collect()
}

/// Chooses the smoothness, then twice takes the slopes of the curve it gives into the
/// weights ([`noise_weights`]) and the curvature penalty and chooses again.
fn follow_the_slope(problem: &mut Problem, pairs: &[TonePair], log_floor: f64) -> Smoothing {
    let mut smoothing = problem.choose_smoothing();
    for _ in 0..2 {
        let previous = problem.curve(smoothing.chosen, log_floor);
        problem.sqrt_w = noise_weights(pairs, &|b| previous.log_slope(b));
        problem.penalty = curvature(&problem.basis, Some(&|x| previous.log_slope(x.exp())));
        smoothing = problem.choose_smoothing();
    }
    smoothing
}

/// Equation `i`'s weighted residual against `curve`:
/// `√w_i·(ln g(τ) − ln g(b) − ln γ_i)`, `w` the weight `sqrt_w` takes.
fn residual(sqrt_w: f64, curve: &LogResponse, p: &TonePair, log_ratio: f64) -> f64 {
    sqrt_w * (curve.log_g(p.bright) - curve.log_g(p.dark) - log_ratio)
}

/// Robust weights, one Huber step: an equation whose weighted residual against `fitted`
/// exceeds [`HUBER`] robust standard deviations counts as that much noisier, so that a few
/// equations no smooth curve explains (a codec's ringing next to white, a sparse bin)
/// cannot choose the smoothness of the whole curve. Multiplies the weights by the factors
/// `√min(1, limit/|r|)` and returns them; `None` (weights untouched) when no residual
/// exceeds the limit.
fn robust_factors(
    problem: &mut Problem,
    pairs: &[TonePair],
    fitted: &LogResponse,
) -> Option<Vec<f64>> {
    let residuals: Vec<f64> = pairs
        .iter()
        .enumerate()
        .map(|(i, p)| residual(problem.sqrt_w[i], fitted, p, problem.log_ratios[i]))
        .collect();
    let mut sizes: Vec<f64> = residuals.iter().map(|r| r.abs()).collect();
    sizes.sort_by(f64::total_cmp);
    // Equations a curve meets exactly (noise-free data) leave only rounding, which is
    // not an outlier: the spread is at least EXACT (in units of the noise model's σ).
    let spread = (MAD_TO_SIGMA * sizes[sizes.len() / 2]).max(EXACT);
    let limit = HUBER * spread;
    if !residuals.iter().any(|r| r.abs() > limit) {
        return None;
    }
    let mut robust = vec![1.0; pairs.len()];
    for ((w, r), f) in problem.sqrt_w.iter_mut().zip(&residuals).zip(&mut robust) {
        *f = (limit / r.abs()).min(1.0).sqrt();
        *w *= *f;
    }
    Some(robust)
}

/// Each frame pair's own scatter: a set whose equations misfit the `joint` curve more than
/// the best-fitting set's (a codec's ringing in one frame, a frame that does not follow
/// its listed time) has its weights divided by `√max(1, χ̄²_set / χ̄²_best)` (its variance
/// scaled by the ratio of the two mean squared weighted residuals), so it cannot pull the
/// curve of the others. `set_of[i]` is equation `i`'s set of `sets`.
fn scale_by_set_scatter(
    problem: &mut Problem,
    pairs: &[TonePair],
    set_of: &[usize],
    sets: usize,
    joint: &LogResponse,
) {
    let mut scatter = vec![(0.0, 0usize); sets];
    for (i, p) in pairs.iter().enumerate() {
        let r = residual(problem.sqrt_w[i], joint, p, problem.log_ratios[i]);
        scatter[set_of[i]].0 += r * r;
        scatter[set_of[i]].1 += 1;
    }
    let mean = |s: &(f64, usize)| s.0 / s.1.max(1) as f64;
    let best = scatter
        .iter()
        .filter(|s| s.1 > 0)
        .map(mean)
        .fold(f64::INFINITY, f64::min)
        .max(f64::MIN_POSITIVE);
    for (w, &set) in problem.sqrt_w.iter_mut().zip(set_of) {
        *w /= (mean(&scatter[set]) / best).max(1.0).sqrt();
    }
}

/// Sum of the squared weighted residuals against `curve` under the noise model: each
/// weight without its `robust` factor.
fn noise_chi2(problem: &Problem, pairs: &[TonePair], robust: &[f64], curve: &LogResponse) -> f64 {
    pairs
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let w = problem.sqrt_w[i] / robust[i];
            residual(w, curve, p, problem.log_ratios[i]).powi(2)
        })
        .sum()
}

/// When the data cannot choose between `fit`'s curve and the `other` the best
/// cross-validation score gave, their difference is part of the error to expect: its RMS
/// over [`ASSESSED_CODES`] in stops is added in quadrature to the predicted error, and
/// its RMS about its mean to the predicted shape error; the confidence follows.
fn add_the_ambiguity(fit: &mut ChannelFit, other: &LogResponse) {
    let fitted = fit.curve();
    let differences: Vec<f64> = ASSESSED_CODES
        .map(|k| {
            let b = f64::from(k) / 255.0;
            (fitted.log_g(b) - other.log_g(b)) / std::f64::consts::LN_2
        })
        .collect();
    let count = differences.len() as f64;
    let mean = differences.iter().sum::<f64>() / count;
    let rms = |offset: f64| {
        (differences
            .iter()
            .map(|d| (d - offset).powi(2))
            .sum::<f64>()
            / count)
            .sqrt()
    };
    fit.predicted_error = fit.predicted_error.hypot(rms(0.0));
    fit.predicted_shape_error = fit.predicted_shape_error.hypot(rms(mean));
    fit.confidence = confidence(fit);
}

/// Huber's threshold for [`robust_factors`], in robust standard deviations of
/// the weighted residuals: the conventional value, not tuned.
const HUBER: f64 = 3.0;

/// Least robust spread of the weighted residuals for [`robust_factors`], in
/// units of the noise model's standard deviation: below it the equations are met exactly
/// but for rounding.
const EXACT: f64 = 1e-3;

/// The median absolute deviation of a normal distribution times this is its standard
/// deviation.
const MAD_TO_SIGMA: f64 = 1.4826;

/// Degree of the pieces of the `auto` spline: cubic, so `ln g` has a continuous curvature.
const SPLINE_DEGREE: usize = 3;

/// Pieces of the `auto` spline (fewer with fewer than 8 equations a piece). Measured on
/// the DoRF curves at ratio 4 (8-bit lossless, `benches/accuracy/response_accuracy.rs`): 6, 8, 10,
/// 12 and 14 pieces differ by less than the spread between halves of the curve set; 10
/// had the lowest tail.
pub const AUTO_PIECES: usize = 10;

/// Number of pieces of the `auto` spline for `m` equations.
fn auto_pieces(m: usize) -> usize {
    AUTO_PIECES.min(m / 8).max(1)
}

/// Interior knots (in `ln b`) splitting `[darkest, brightest]` into `pieces` pieces of
/// equal width in brightness (see the module docs).
fn even_knots(darkest: f64, brightest: f64, pieces: usize) -> Vec<f64> {
    let (lo, hi) = (darkest, brightest.min(1.0));
    (1..pieces)
        .map(|i| (lo + (hi - lo) * i as f64 / pieces as f64).ln())
        .collect()
}

/// Final solve at smoothness `λ`, and its report.
fn finish(problem: &Problem, lambda: f64, log_floor: f64, covered: (f64, f64)) -> ChannelFit {
    let (m, n) = (problem.equations(), problem.unknowns());
    let rows: Vec<usize> = (0..m).collect();
    let (a, y) = problem.system(lambda, &rows);
    let d = nnls(&a, &y, None);
    let data_a = a.rows(0, m).into_owned();
    let resid = &data_a * &d - y.rows(0, m);
    let chi2 = resid.norm_squared();
    let residual_rms =
        (chi2 / problem.total_weight().max(f64::MIN_POSITIVE)).sqrt() / std::f64::consts::LN_2;
    let condition = condition_number(&data_a);
    // Covariance of the free increments under the penalised model: s²·(R⁻¹R⁻ᵀ) from the
    // SVD of the free columns of the full (data + smoothness) system, with
    // s² = 2·max(1, χ²/(m − p)): the misfit inflates it, and each pixel bin feeds two
    // neighbouring equations, so the equations are not independent.
    let free: Vec<usize> = (0..n).filter(|&j| d[j] > 0.0).collect();
    let p = free.len().max(1);
    let scale2 = 2.0 * problem.dependence * (chi2 / (m.saturating_sub(p).max(1)) as f64).max(1.0);
    let predicted = predict(problem, &a, &data_a, &free, scale2, log_floor);
    let (lo, hi) = (covered.0, covered.1.min(1.0));
    let dof = (m as f64 - predicted.effective_parameters).max(1.0);
    let mut fit = ChannelFit {
        degree: problem.basis.degree(),
        knots: problem.basis.interior().to_vec(),
        smoothing: lambda / problem.total_weight().max(f64::MIN_POSITIVE),
        coefficients: problem.basis.coefficients(d.as_slice()),
        log_floor,
        covered: (lo, hi),
        residual_rms,
        equations: m,
        effective_parameters: predicted.effective_parameters,
        condition,
        predicted_error: predicted.error,
        predicted_shape_error: predicted.shape_error,
        coverage: coverage(lo, hi),
        misfit: chi2 / dof,
        log_ratio: problem.ripple_log_ratio,
        top_span: 0.0,
        confidence: 0.0,
    };
    fit.top_span = (-fit.log_g(hi) / std::f64::consts::LN_2).max(0.0);
    fit.confidence = confidence(&fit);
    fit
}

/// The ratio of the largest to the smallest singular value of `data_a` (infinite when
/// it is singular).
fn condition_number(data_a: &DMatrix<f64>) -> f64 {
    let sv = data_a.clone().svd(false, false).singular_values;
    let (smax, smin) = sv.iter().fold((0.0f64, f64::INFINITY), |(hi, lo), &s| {
        (hi.max(s), lo.min(s))
    });
    if smin > 0.0 {
        smax / smin
    } else {
        f64::INFINITY
    }
}

/// What the covariance of a fit predicts of it.
struct Prediction {
    /// RMS over the assessed codes of the standard error of `log₂ g`, in stops.
    error: f64,
    /// The same of the curve's shape (its deviation from its mean over the codes).
    shape_error: f64,
    /// `tr(A (SᵀS)⁻¹ Aᵀ)`: the parameters the data effectively determine.
    effective_parameters: f64,
}

/// The errors predicted from the SVD of the `free` columns of the full (data +
/// smoothness) system `a`, whose first rows are `data_a`, at variance factor `scale2`
/// (s²); without a free increment they are infinite, with no effective parameter.
fn predict(
    problem: &Problem,
    a: &DMatrix<f64>,
    data_a: &DMatrix<f64>,
    free: &[usize],
    scale2: f64,
    log_floor: f64,
) -> Prediction {
    if free.is_empty() {
        return Prediction {
            error: f64::INFINITY,
            shape_error: f64::INFINITY,
            effective_parameters: 0.0,
        };
    }
    let p = free.len();
    let svd = a.select_columns(free).svd(false, true);
    let vt = svd.v_t.unwrap_or_else(|| DMatrix::identity(p, p));
    // Per code, `Σ⁻¹Vᵀφ(b)`: its squared norm is the variance of `ln g(b)` (over s²),
    // and that of its deviation from the codes' mean the variance of the shape.
    let codes = ASSESSED_CODES;
    let count = codes.clone().count() as f64;
    let whitened: Vec<DVector<f64>> = codes
        .map(|k| {
            let x = (f64::from(k) / 255.0).ln().max(log_floor);
            let r = problem.basis.ramps(x);
            let phi = DVector::from_iterator(p, free.iter().map(|&j| r[j]));
            let mut w = &vt * phi;
            for (v, s) in w.iter_mut().zip(svd.singular_values.iter()) {
                *v = if *s > 0.0 { *v / s } else { f64::INFINITY };
            }
            w
        })
        .collect();
    let var_sum: f64 = whitened.iter().map(|w| w.norm_squared()).sum();
    let mean = whitened.iter().fold(DVector::zeros(p), |acc, w| acc + w) / count;
    let shape_sum: f64 = if var_sum.is_finite() {
        whitened.iter().map(|w| (w - &mean).norm_squared()).sum()
    } else {
        f64::INFINITY
    };
    // tr(A (SᵀS)⁻¹ Aᵀ) = ‖A V Σ⁻¹‖²_F for the stacked system S = U Σ Vᵀ.
    let mut projected = data_a.select_columns(free) * vt.transpose();
    for (mut column, s) in projected.column_iter_mut().zip(svd.singular_values.iter()) {
        // A direction the stacked system does not see (σ = 0) is one `A` does not
        // see either: it adds nothing to the trace.
        column *= if *s > 0.0 { 1.0 / s } else { 0.0 };
    }
    Prediction {
        error: (scale2 * var_sum / count).sqrt() / std::f64::consts::LN_2,
        shape_error: (scale2 * shape_sum / count).sqrt() / std::f64::consts::LN_2,
        effective_parameters: projected.norm_squared(),
    }
}

/// Share of the assessed codes ([`ASSESSED_CODES`]) inside the brightness range
/// `[lo, hi]` the pairs covered.
fn coverage(lo: f64, hi: f64) -> f64 {
    let (first, last) = (
        f64::from(*ASSESSED_CODES.start()) / 255.0,
        f64::from(*ASSESSED_CODES.end()) / 255.0,
    );
    let span = f64::from(ASSESSED_CODES.end() - ASSESSED_CODES.start()) / 255.0;
    ((hi.min(last) - lo.max(first)) / span).clamp(0.0, 1.0)
}

/// `coverage · min(p, 1 / (1 + (predicted_shape_error / 0.2 stop)²))` with `p` the
/// [`logistic_confidence`] of the fit's features under [`CONFIDENCE_MODEL`]: the second
/// term caps it where the covariance alone puts the shape's standard error at twice the
/// 0.1-stop tolerance or beyond, outside the errors the model was fitted on (it is 0.5
/// at 0.2 stop and above 0.9 below 0.06, so it rarely binds inside them). 0 for an
/// undetermined curve (no free increment, or a non-finite feature).
fn confidence(fit: &ChannelFit) -> f64 {
    let x = fit.features();
    if fit.predicted_shape_error.is_finite() && x.iter().all(|v| v.is_finite()) {
        let precision = 1.0 / (1.0 + (fit.predicted_shape_error / 0.2).powi(2));
        fit.coverage * logistic_confidence(&CONFIDENCE_MODEL, &x).min(precision)
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Exact tone pairs of `g = b^k` at ratio γ: τ(b) = b·γ^(1/k).
    fn power_pairs(k: f64, gamma: f64) -> Vec<TonePair> {
        (3..=252)
            .map(|c| f64::from(c) / 255.0)
            .map(|b| (b, b * gamma.powf(1.0 / k)))
            .filter(|&(_, t)| t <= 252.0 / 255.0)
            .enumerate()
            .map(|(i, (b, t))| TonePair {
                dark: b,
                bright: t,
                sigma_dark: 0.001,
                sigma_bright: 0.001,
                quantile: i as f64,
            })
            .collect()
    }

    #[test]
    fn curvature_rows_integrate_the_weighted_squared_second_derivative() {
        let basis = Basis::new(3, -4.5, 0.0, &even_knots(0.011, 0.99, 10));
        let n = basis.len() - 1;
        let d = DVector::from_iterator(n, (0..n).map(|j| 0.1 + ((j * 7) % 5) as f64 * 0.3));
        let slope = |x: f64| 1.2 + 0.4 * x * x;
        let u = |x: f64| -> f64 {
            basis
                .ramps(x)
                .iter()
                .zip(d.iter())
                .map(|(r, d)| r * d)
                .sum()
        };
        // ‖P d‖² against ∫ (S/s)⁵ u''² dx by finite differences on a fine grid.
        let integral = |weight: &dyn Fn(f64) -> f64| -> f64 {
            let steps = 20_000;
            let dx = 4.5 / steps as f64;
            let h = dx / 4.0;
            (0..steps)
                .map(|k| {
                    let x = -4.5 + (k as f64 + 0.5) * dx;
                    let second = (u(x + h) - 2.0 * u(x) + u(x - h)) / (h * h);
                    weight(x) * second * second * dx
                })
                .sum()
        };
        let plain = (curvature(&basis, None) * &d).norm_squared();
        let expected = integral(&|_| 1.0);
        assert!(
            (plain - expected).abs() < 1e-3 * expected,
            "{plain} vs {expected}"
        );
        let weighted = (curvature(&basis, Some(&slope)) * &d).norm_squared();
        let expected = integral(&|x| (SLOPE_SCALE / slope(x)).powi(5));
        assert!(
            (weighted - expected).abs() < 0.02 * expected,
            "{weighted} vs {expected}"
        );
    }

    #[test]
    fn nnls_matches_unconstrained_when_interior_and_clamps_otherwise() {
        let a = DMatrix::from_row_slice(3, 2, &[1.0, 0.0, 0.0, 1.0, 1.0, 1.0]);
        let y = DVector::from_vec(vec![1.0, 2.0, 3.0]);
        let x = nnls(&a, &y, None);
        assert!((x[0] - 1.0).abs() < 1e-12 && (x[1] - 2.0).abs() < 1e-12);
        let y = DVector::from_vec(vec![-1.0, 2.0, 1.0]);
        let x = nnls(&a, &y, None);
        assert_eq!(x[0], 0.0);
        assert!((x[1] - 1.5).abs() < 1e-12);
    }

    #[test]
    fn nnls_reaches_the_same_minimum_from_any_feasible_start() {
        // 40 equations in 10 unknowns whose unconstrained optimum has entries of both
        // signs, so that some bounds are active at the answer.
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let a = DMatrix::from_fn(40, 10, |_, _| next());
        let truth = DVector::from_fn(10, |j, _| if j % 3 == 0 { -1.0 } else { 1.0 + j as f64 });
        let y = &a * &truth + DVector::from_fn(40, |_, _| 0.01 * next());
        let cold = nnls(&a, &y, None);
        let active = cold.iter().filter(|&&v| v == 0.0).count();
        assert!((1..10).contains(&active), "{cold}");
        // From a neighbouring problem's answer (as down a smoothness grid), from every
        // variable free, and from an infeasible point (ignored: the origin).
        let neighbour = nnls(&a, &(&y * 1.1), None);
        let starts = [neighbour, DVector::from_element(10, 1.0), -cold.clone()];
        for start in starts {
            let warm = nnls(&a, &y, Some(&start));
            assert!((&warm - &cold).amax() < 1e-10, "{warm} against {cold}");
        }
    }

    #[test]
    fn recovers_a_power_law_at_every_degree() {
        let pairs = power_pairs(2.2, 4.0);
        for degree in [
            Degree::Fixed(1),
            Degree::Fixed(6),
            Degree::Fixed(12),
            Degree::Auto,
        ] {
            let f = fit(&pairs, 4f64.ln(), degree).unwrap();
            for c in 16..240 {
                let b = f64::from(c) / 255.0;
                let err = (f.eval(b).log2() - 2.2 * b.log2()).abs();
                assert!(err < 1e-3, "{degree:?} code {c}: {err}");
            }
            assert!(f.coefficients.windows(2).all(|w| w[0] <= w[1]));
            assert_eq!(f.eval(1.0), 1.0);
            assert_eq!(f.eval(0.0), 0.0);
        }
        let auto = fit(&pairs, 4f64.ln(), Degree::Auto).unwrap();
        assert!(auto.confidence > 0.8, "{auto:?}");
        assert_eq!(auto.knots.len() + 1, AUTO_PIECES);
        // A power law is a straight line in log–log and costs no curvature: the data let
        // a stiff model win, about two effective parameters of the spline's twelve (the
        // slope, and what a finite λ still leaves of the curvature).
        assert!(
            auto.effective_parameters > 1.0 && auto.effective_parameters < 2.5,
            "{}",
            auto.effective_parameters
        );
    }

    /// The shape's predicted error is the curve's less the variance of its level: never
    /// more, and clearly less when the equations stop well below white, so that `g(1) = 1`
    /// is reached only by extrapolation.
    #[test]
    fn the_shape_is_surer_than_the_level_above_the_brightest_tone() {
        let full = fit(&power_pairs(2.2, 4.0), 4f64.ln(), Degree::Auto).unwrap();
        let short: Vec<TonePair> = power_pairs(2.2, 4.0)
            .into_iter()
            .filter(|p| p.bright <= 0.6)
            .map(|p| TonePair {
                sigma_dark: 0.004,
                sigma_bright: 0.004,
                ..p
            })
            .collect();
        let short = fit(&short, 4f64.ln(), Degree::Auto).unwrap();
        for f in [&full, &short] {
            assert!(f.predicted_shape_error.is_finite() && f.predicted_shape_error > 0.0);
            assert!(f.predicted_shape_error <= f.predicted_error, "{f:?}");
        }
        eprintln!(
            "full: {:.5} / {:.5}; short: {:.5} / {:.5}",
            full.predicted_shape_error,
            full.predicted_error,
            short.predicted_shape_error,
            short.predicted_error
        );
        assert!(short.predicted_shape_error < 0.5 * short.predicted_error);
    }

    #[test]
    fn confidence_is_the_logistic_model_of_the_features_times_the_coverage() {
        let good = fit(&power_pairs(2.2, 4.0), 4f64.ln(), Degree::Auto).unwrap();
        let p = logistic_confidence(&CONFIDENCE_MODEL, &good.features());
        let cap = 1.0 / (1.0 + (good.predicted_shape_error / 0.2).powi(2));
        assert!((good.confidence - good.coverage * p.min(cap)).abs() < 1e-12);
        assert!(good.confidence > 0.8, "{good:?}");
        // A larger predicted shape error, equations scattering further beyond their
        // noise, a wider ratio: each lowers the model's probability.
        let worse = |fit: ChannelFit| {
            assert!(
                logistic_confidence(&CONFIDENCE_MODEL, &fit.features()) < p,
                "{fit:?}"
            );
        };
        worse(ChannelFit {
            predicted_shape_error: 0.05,
            ..good.clone()
        });
        worse(ChannelFit {
            misfit: 10.0,
            ..good.clone()
        });
        worse(ChannelFit {
            log_ratio: 16f64.ln(),
            ..good.clone()
        });
        // A pair 16× apart whose equations scatter ten times beyond their noise, with a
        // predicted shape error of 0.05 stop: a channel to distrust.
        let bad = ChannelFit {
            predicted_shape_error: 0.05,
            misfit: 10.0,
            log_ratio: 16f64.ln(),
            ..good.clone()
        };
        assert!(confidence(&bad) < 0.1, "{}", confidence(&bad));
        let uncovered = ChannelFit {
            coverage: 0.4,
            ..good.clone()
        };
        assert!(confidence(&uncovered) < 0.5);
    }

    #[test]
    fn rejects_too_few_tones_and_bad_degrees() {
        assert_eq!(fit(&[], 1.0, Degree::Auto), Err(FitError::TooFewTones(0)));
        assert_eq!(
            fit(&power_pairs(2.2, 4.0), 1.0, Degree::Fixed(0)),
            Err(FitError::Degree(0))
        );
    }

    #[test]
    fn a_curve_deeper_than_any_camera_is_refused_as_degenerate() {
        let good = fit(&power_pairs(2.2, 4.0), 4f64.ln(), Degree::Auto).unwrap();
        assert!(check_degenerate(&good).is_ok());
        // The same fit pushed 40 stops down below its top coefficient: g ≈ 2⁻⁴⁰ up to
        // near white, as a contradictory set of equations can leave it.
        let mut deep = good.clone();
        let last = deep.coefficients.len() - 1;
        for c in &mut deep.coefficients[..last] {
            *c -= 40.0 * std::f64::consts::LN_2;
        }
        match check_degenerate(&deep) {
            Err(FitError::Degenerate { stops, .. }) => assert!(stops > DEEPEST_STOPS, "{stops}"),
            other => panic!("{other:?}"),
        }
        deep.coefficients[0] = f64::NEG_INFINITY;
        assert!(check_degenerate(&deep).is_err());
    }
}
