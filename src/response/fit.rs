//! Fitting one channel's inverse response to the tone pairs `g(τ(b)) = γ·g(b)`.
//!
//! **Model: a monotone Bernstein polynomial for `log g` on a log-brightness axis.**
//! With `x = ln b` on the fit domain `[x₀, 0]` (`x₀ = ln` of the darkest usable tone) and
//! `t = 1 − x/x₀ ∈ [0, 1]`,
//!
//! `u(t) = ln g = Σ_{k=0..n} c_k·B_{k,n}(t)`, `c_k = −Σ_{j>k} d_j`, `d_j ≥ 0`,
//!
//! so the Bernstein coefficients rise (`u`, hence `g`, is non-decreasing by construction)
//! and `c_n = 0` gives `g(1) = 1` exactly. Written with the increments,
//! `u(t) = Σ_{j=1..n} d_j·(S_j(t) − 1)` where `S_j = Σ_{k≥j} B_{k,n}` rises from 0 to 1.
//! Each tone pair becomes one equation that is *linear* in `d`:
//!
//! `u(t_τ) − u(t_b) = Σ_j d_j·(S_j(t_τ) − S_j(t_b)) = ln γ`.
//!
//! Why this family: a power law `g = b^k` (gamma curves, most of sRGB) is a straight line
//! in `(ln b, ln g)`, so low degrees already fit real cameras; errors are measured
//! relative to `g` (stops), which is what a radiance merge needs, so dark tones are not
//! swamped by bright ones; every equation is a difference, so the normalisation `g(1)=1`
//! never enters the fit and cannot pull on it; and at a large ratio the same difference
//! equation links the dark and bright ends through the overlap (chaining `g(τ(τ(b))) =
//! γ²g(b)` happens implicitly). Below the darkest usable tone `b₀`, `g` continues as the
//! power law `g(b₀)·(b/b₀)^s` with the end slope `s` (≥ 0.5), which gives `g(0) = 0`.
//!
//! **Solve.** Weighted non-negative least squares `min ‖W(A d − ln γ)‖`, `d ≥ 0`: the
//! weighted design is reduced by a Householder QR to its `n × n` triangle, and the
//! Lawson–Hanson active-set method runs on that triangle with SVD solves of the free
//! columns. No normal equations are formed.
//!
//! **Weights** are inverse variances: an error `σ_b` in a tone moves `ln g` by
//! `s(b)·σ_b/b` (`s = d ln g / d ln b`), so `σ² = (s_b σ_b/b)² + (s_τ σ_τ/τ)²`, with the
//! slopes from a pilot fit and `σ_b, σ_τ` from the histogram (bin width and pixel support,
//! see [`crate::histogram::tone_pairs`]).
//!
//! **Smoothness.** Two exposures determine `g` only up to functions that repeat along the
//! chain `b → τ(b) → τ(τ(b))` (Grossberg & Nayar's ambiguity): a flexible model can add
//! such ripples without changing any residual, which is how a plain polynomial goes
//! confidently wrong at large ratios. A penalty on the log–log curvature,
//! `λ·∫ (d² ln g / d(ln b)²)² d ln b` over the fit domain (midpoint rule on
//! [`CURVATURE_NODES`] nodes, added as rows of the least-squares system), removes them;
//! a power law (`g = b^k`) costs nothing.
//!
//! **Model size.** `auto` uses degree [`AUTO_DEGREE`] and lets the data choose `λ` by
//! blocked 5-fold cross-validation: the tone pairs, in tone order, are cut into 5
//! contiguous blocks and each is predicted from the other four. Neighbouring tone pairs
//! share pixels, so random folds leak and always prefer the most flexible model (as a
//! prototype found); contiguous blocks test what matters, the curve between and beyond the
//! data. From the grid [`SMOOTHING_GRID`] the *largest* `λ` whose score is within one
//! standard error of the best is taken (the one-standard-error rule): ripples the data
//! cannot see do not change the score, so the smoothest adequate curve wins. For the same
//! reason `λ/Σw` never goes below `3·10⁻⁷·(ln γ)⁴`: the ambiguity's ripples repeat every
//! `ln γ` along `ln g`, a ripple of amplitude `A` and period `P` costs `∝ A²/P⁴` of
//! curvature, so a larger ratio needs a larger `λ` to keep them down. A fixed degree
//! (`Degree::Fixed`) keeps the same penalty choice.

use nalgebra::{DMatrix, DVector};

use crate::histogram::TonePair;

/// Largest degree `auto` considers and a fixed degree may ask for.
pub const MAX_DEGREE: usize = 16;

/// How the model size is chosen.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Degree {
    /// Degree [`AUTO_DEGREE`], smoothness by blocked cross-validation (see module docs).
    Auto,
    /// A fixed degree `1..=MAX_DEGREE` (the report used 6).
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
        "the brighter frame is darker than the darker one in most tones: frames or ratio swapped"
    )]
    Swapped,
}

/// One channel's fitted inverse response and how well the data determined it.
#[derive(Debug, Clone, PartialEq)]
pub struct ChannelFit {
    /// Polynomial degree `n`.
    pub degree: usize,
    /// Smoothness weight `λ / Σw` chosen for the log–log curvature penalty.
    pub smoothing: f64,
    /// Bernstein coefficients `c_0 ≤ … ≤ c_n = 0` of `ln g` on the fit domain.
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
    /// Condition number of the weighted design matrix (ratio of extreme singular values).
    pub condition: f64,
    /// Predicted standard error of `log₂ g` over codes 16..239 (stops), from the fit's
    /// covariance scaled by the residual misfit.
    pub predicted_error: f64,
    /// Fraction of the tones 16/255..239/255 inside [`ChannelFit::covered`].
    pub coverage: f64,
    /// `coverage / (1 + (predicted_error / 0.05)²)`, in `[0, 1]`; below 0.5 is "low".
    pub confidence: f64,
}

impl ChannelFit {
    /// `ln g(b)` for `b > 0`.
    pub fn log_g(&self, b: f64) -> f64 {
        let x = b.min(1.0).ln();
        if x < self.log_floor {
            let s = self.end_slope();
            return self.u(0.0) + s * (x - self.log_floor);
        }
        self.u(1.0 - x / self.log_floor)
    }

    /// `g(b)`, with `g(0) = 0` and `g(1) = 1`.
    pub fn eval(&self, b: f64) -> f64 {
        if b.is_nan() || b <= 0.0 {
            return 0.0;
        }
        self.log_g(b).exp().min(1.0)
    }

    /// Log–log slope used below the fit domain: the fitted slope at `b₀`, at least 0.5.
    fn end_slope(&self) -> f64 {
        (self.slope_t(0.0) / -self.log_floor).max(0.5)
    }

    fn u(&self, t: f64) -> f64 {
        bernstein(self.degree, t)
            .iter()
            .zip(&self.coefficients)
            .map(|(b, c)| b * c)
            .sum()
    }

    /// `du/dt`.
    fn slope_t(&self, t: f64) -> f64 {
        let n = self.degree;
        let b = bernstein(n - 1, t);
        (0..n)
            .map(|k| n as f64 * (self.coefficients[k + 1] - self.coefficients[k]) * b[k])
            .sum()
    }

    /// `d ln g / d ln b` at brightness `b` (within the fit domain; clamped to it).
    pub fn log_slope(&self, b: f64) -> f64 {
        let x = b.clamp(self.log_floor.exp(), 1.0).ln();
        self.slope_t(1.0 - x / self.log_floor) / -self.log_floor
    }
}

/// `B_{k,n}(t)` for `k = 0..=n`.
fn bernstein(n: usize, t: f64) -> Vec<f64> {
    let t = t.clamp(0.0, 1.0);
    // de Casteljau-style build-up: stable for every t in [0, 1].
    let mut b = vec![0.0; n + 1];
    b[0] = 1.0;
    for m in 1..=n {
        for k in (0..=m).rev() {
            let left = if k > 0 { b[k - 1] * t } else { 0.0 };
            b[k] = left + b[k] * (1.0 - t);
        }
    }
    b
}

/// `S_j(t) − 1` for `j = 1..=n`: the increments' basis functions, `u = Σ d_j (S_j − 1)`.
fn ramps(n: usize, t: f64) -> Vec<f64> {
    let b = bernstein(n, t);
    let mut out = vec![0.0; n];
    let mut tail = 0.0;
    for j in (1..=n).rev() {
        tail += b[j];
        out[j - 1] = tail - 1.0;
    }
    out
}

/// The equations in `t` coordinates: `(t_b, t_τ)` per pair.
fn positions(pairs: &[TonePair], log_floor: f64) -> Vec<(f64, f64)> {
    pairs
        .iter()
        .map(|p| {
            (
                1.0 - p.dark.ln() / log_floor,
                1.0 - p.bright.min(1.0).ln() / log_floor,
            )
        })
        .collect()
}

/// Unweighted design for degree `n`: row `i` is `ramps(t_τ) − ramps(t_b)` of pair `i`.
fn design(n: usize, at: &[(f64, f64)]) -> DMatrix<f64> {
    let mut a = DMatrix::zeros(at.len(), n);
    for (i, &(tb, tt)) in at.iter().enumerate() {
        let (lo, hi) = (ramps(n, tb), ramps(n, tt));
        for j in 0..n {
            a[(i, j)] = hi[j] - lo[j];
        }
    }
    a
}

/// Rows of the curvature penalty `∫ (d²u/dx²)² dx` over the fit domain `x = ln b ∈ [x₀, 0]`
/// by the midpoint rule: row `q` is `√Δx · d²R_j/dx²(x_q)` with `R_j = S_j − 1`, so that
/// `‖P d‖² ≈ ∫ u''(x)² dx` (units: nats² per nat of log brightness). With `t = 1 − x/x₀`,
/// `d²S_j/dx² = n(n−1)·(B_{j−2,n−2}(t) − B_{j−1,n−2}(t)) / x₀²` (terms outside `0..=n−2`
/// absent).
fn curvature(n: usize, log_floor: f64) -> DMatrix<f64> {
    let dx = -log_floor / CURVATURE_NODES as f64;
    let mut p = DMatrix::zeros(CURVATURE_NODES, n);
    if n < 2 {
        return p;
    }
    let scale = dx.sqrt() * (n * (n - 1)) as f64 / (log_floor * log_floor);
    for q in 0..CURVATURE_NODES {
        let b = bernstein(n - 2, (q as f64 + 0.5) / CURVATURE_NODES as f64);
        let at = |k: Option<usize>| k.and_then(|k| b.get(k)).copied().unwrap_or(0.0);
        for j in 1..=n {
            p[(q, j - 1)] = scale * (at(j.checked_sub(2)) - at(Some(j - 1)));
        }
    }
    p
}

/// Quadrature nodes of the curvature penalty (equally spaced in `ln b`).
pub const CURVATURE_NODES: usize = 48;

/// `min ‖A x − y‖` subject to `x ≥ 0` (Lawson–Hanson), after a QR reduction of `A`.
fn nnls(a: &DMatrix<f64>, y: &DVector<f64>) -> DVector<f64> {
    let n = a.ncols();
    let qr = a.clone().qr();
    let r = qr.r();
    let z = qr.q().transpose() * y;
    let tol = 1e-12 * (1.0 + r.norm() * z.norm());
    let mut x = DVector::zeros(n);
    let mut free = vec![false; n];
    for _ in 0..3 * n + 3 {
        let grad = r.transpose() * (&z - &r * &x);
        let pick = (0..n)
            .filter(|&j| !free[j] && grad[j] > tol)
            .max_by(|&i, &j| grad[i].total_cmp(&grad[j]));
        let Some(j) = pick else { break };
        free[j] = true;
        loop {
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
        }
    }
    x
}

/// Smoothness strengths `λ` tried, as multiples of the total data weight `Σ w`.
/// The penalty's scale relative to the data's varies by orders of magnitude between
/// curves, so the grid spans ten decades: over the synthetic and DoRF curves at ratio 4
/// (three encodings, 1 889 cross-validated choices) the smallest value was taken 5 times.
pub const SMOOTHING_GRID: [f64; 11] = [
    1.0, 1e-1, 1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10,
];

/// The least smoothness `λ/Σw` cross-validation may choose at exposure ratio `γ`:
/// [`RIPPLE_FLOOR`]`·(ln γ)⁴` (see the module docs: the ambiguity's ripples lengthen with
/// the ratio, cost less curvature, and change no residual, so cross-validation cannot see
/// them).
fn ripple_floor(log_ratio: f64) -> f64 {
    RIPPLE_FLOOR * log_ratio.powi(4)
}

/// The constant of [`ripple_floor`]. Chosen on the DoRF curves (8-bit lossless): at ratio
/// 64 the 90th-percentile shape error fell from 0.61 to 0.29 stops (1e-7: 0.34, 1e-6:
/// 0.24 but seven confident wrong curves at ratio 16), at ratio 4 it changed nothing.
const RIPPLE_FLOOR: f64 = 3e-7;

/// The weighted equations of one channel at one degree.
struct Problem {
    /// Unweighted design, one row per equation (see [`design`]).
    design: DMatrix<f64>,
    /// Curvature penalty rows (see [`curvature`]).
    penalty: DMatrix<f64>,
    /// `1/σ` per equation.
    sqrt_w: Vec<f64>,
    /// `ln γ`.
    log_ratio: f64,
}

impl Problem {
    fn equations(&self) -> usize {
        self.design.nrows()
    }

    fn degree(&self) -> usize {
        self.design.ncols()
    }

    fn total_weight(&self) -> f64 {
        self.sqrt_w.iter().map(|w| w * w).sum()
    }

    /// The weighted data rows `rows` and their right-hand sides `√w·ln γ`.
    fn weighted(&self, rows: &[usize]) -> (DMatrix<f64>, DVector<f64>) {
        let n = self.degree();
        let a = DMatrix::from_fn(rows.len(), n, |r, j| {
            self.sqrt_w[rows[r]] * self.design[(rows[r], j)]
        });
        let y = DVector::from_iterator(
            rows.len(),
            rows.iter().map(|&i| self.sqrt_w[i] * self.log_ratio),
        );
        (a, y)
    }

    /// Data rows plus the penalty rows times `√λ`.
    fn system(&self, lambda: f64, rows: &[usize]) -> (DMatrix<f64>, DVector<f64>) {
        let n = self.degree();
        let (a, y) = self.weighted(rows);
        let extra = self.penalty.nrows();
        let mut full = DMatrix::zeros(rows.len() + extra, n);
        full.rows_mut(0, rows.len()).copy_from(&a);
        full.rows_mut(rows.len(), extra)
            .copy_from(&(&self.penalty * lambda.sqrt()));
        let mut full_y = DVector::zeros(rows.len() + extra);
        full_y.rows_mut(0, rows.len()).copy_from(&y);
        (full, full_y)
    }

    fn solve(&self, lambda: f64, rows: &[usize]) -> DVector<f64> {
        let (a, y) = self.system(lambda, rows);
        nnls(&a, &y)
    }

    /// Sum of squared weighted data residuals of `d` on `rows`.
    fn misfit(&self, d: &DVector<f64>, rows: &[usize]) -> f64 {
        let (a, y) = self.weighted(rows);
        (a * d - y).norm_squared()
    }

    /// Chooses the smoothness `λ` by blocked 5-fold cross-validation, then the largest
    /// `λ` whose score is within one standard error of the best.
    fn choose_smoothing(&self) -> Smoothing {
        const FOLDS: usize = 5;
        let (m, n) = (self.equations(), self.degree());
        let scale = self.total_weight();
        if m < 2 * FOLDS || n <= 1 {
            let only = scale * SMOOTHING_GRID[0];
            return Smoothing {
                chosen: only,
                best: only,
            };
        }
        let fold_of = |i: usize| i * FOLDS / m;
        let floor = ripple_floor(self.log_ratio);
        let grid: Vec<f64> = SMOOTHING_GRID
            .iter()
            .copied()
            .chain((floor < SMOOTHING_GRID[0]).then_some(floor))
            .collect();
        // (λ, mean score, standard error, allowed by the floor)
        let scores: Vec<(f64, f64, f64, bool)> = grid
            .iter()
            .map(|&k| {
                let per_fold: Vec<f64> = (0..FOLDS)
                    .map(|f| {
                        let train: Vec<usize> = (0..m).filter(|&i| fold_of(i) != f).collect();
                        let test: Vec<usize> = (0..m).filter(|&i| fold_of(i) == f).collect();
                        let d = self.solve(scale * k, &train);
                        self.misfit(&d, &test) / test.len() as f64
                    })
                    .collect();
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
        // Allowed values are in descending order: the first within one standard error
        // of the best is the largest.
        let chosen = scores
            .iter()
            .filter(|s| s.3)
            .find(|s| s.1 <= best.1 + best.2)
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

/// The smoothness cross-validation chose, and the one it scored best with no floor.
#[derive(Debug, Clone, Copy)]
struct Smoothing {
    chosen: f64,
    best: f64,
}

fn coefficients(d: &DVector<f64>) -> Vec<f64> {
    let n = d.len();
    let mut c = vec![0.0; n + 1];
    for k in (0..n).rev() {
        c[k] = c[k + 1] - d[k];
    }
    c
}

/// Nominal sensor noise, brightness units (1 DN of an 8-bit frame), added to each side's
/// variance: without it the darkest tones, where noise bends the histograms most, would
/// carry as much weight as mid-tones.
const NOISE: f64 = 1.0 / 255.0;

/// Fits `ln g` to the tone pairs of one channel for a known `ln γ > 0` (see module docs).
pub fn fit(pairs: &[TonePair], log_ratio: f64, degree: Degree) -> Result<ChannelFit, FitError> {
    if let Degree::Fixed(n) = degree
        && !(1..=MAX_DEGREE).contains(&n)
    {
        return Err(FitError::Degree(n));
    }
    let backwards = pairs.iter().filter(|p| p.bright < p.dark).count();
    if backwards * 2 > pairs.len() {
        return Err(FitError::Swapped);
    }
    let pairs: Vec<TonePair> = pairs
        .iter()
        .filter(|p| p.dark > 0.0 && p.bright > p.dark && p.bright.is_finite())
        .copied()
        .collect();
    let m = pairs.len();
    if m < 2 {
        return Err(FitError::TooFewTones(m));
    }
    let darkest = pairs.iter().map(|p| p.dark).fold(f64::INFINITY, f64::min);
    let brightest = pairs.iter().map(|p| p.bright).fold(0.0, f64::max);
    let log_floor = darkest.ln().min(-1e-3);
    let sigma2 = |p: &TonePair, s_b: f64, s_t: f64| {
        let v_b = p.sigma_dark.powi(2) + NOISE * NOISE;
        let v_t = p.sigma_bright.powi(2) + NOISE * NOISE;
        s_b * s_b * v_b / (p.dark * p.dark) + s_t * s_t * v_t / (p.bright * p.bright)
    };
    let n = match degree {
        Degree::Fixed(n) => n,
        Degree::Auto => AUTO_DEGREE.min(m / 4).max(1),
    };
    let mut problem = Problem {
        design: design(n, &positions(&pairs, log_floor)),
        penalty: curvature(n, log_floor),
        sqrt_w: pairs
            .iter()
            .map(|p| 1.0 / sigma2(p, 1.0, 1.0).sqrt())
            .collect(),
        log_ratio,
    };
    // Pilot at unit slopes; then the weights use its slopes.
    let pilot_lambda = problem.choose_smoothing().chosen;
    let pilot = finish(&problem, pilot_lambda, log_floor, (darkest, brightest));
    problem.sqrt_w = pairs
        .iter()
        .map(|p| {
            let s_b = pilot.log_slope(p.dark).max(0.3);
            let s_t = pilot.log_slope(p.bright).max(0.3);
            1.0 / sigma2(p, s_b, s_t).sqrt()
        })
        .collect();
    let smoothing = problem.choose_smoothing();
    let mut fit = finish(&problem, smoothing.chosen, log_floor, (darkest, brightest));
    if smoothing.best != smoothing.chosen {
        // The data cannot choose between the two curves: their difference is part of
        // the error to expect.
        let other = finish(&problem, smoothing.best, log_floor, (darkest, brightest));
        let codes = 16..=239;
        let count = codes.clone().count() as f64;
        let spread = (codes
            .map(|k| {
                let b = f64::from(k) / 255.0;
                ((fit.log_g(b) - other.log_g(b)) / std::f64::consts::LN_2).powi(2)
            })
            .sum::<f64>()
            / count)
            .sqrt();
        fit.predicted_error = fit.predicted_error.hypot(spread);
        fit.confidence = confidence(fit.coverage, fit.predicted_error);
    }
    Ok(fit)
}

/// Degree used by `auto` (fewer with fewer than `4n` equations): high enough for S-shaped
/// film curves; the smoothness penalty, chosen by the data, decides how much of it is used.
pub const AUTO_DEGREE: usize = 12;

/// Final solve at degree `n` and smoothness `λ`, and its report.
fn finish(problem: &Problem, lambda: f64, log_floor: f64, covered: (f64, f64)) -> ChannelFit {
    let (m, n) = (problem.equations(), problem.degree());
    let rows: Vec<usize> = (0..m).collect();
    let (a, y) = problem.system(lambda, &rows);
    let d = nnls(&a, &y);
    let data_a = a.rows(0, m).into_owned();
    let resid = &data_a * &d - y.rows(0, m);
    let chi2 = resid.norm_squared();
    let residual_rms =
        (chi2 / problem.total_weight().max(f64::MIN_POSITIVE)).sqrt() / std::f64::consts::LN_2;
    let sv = data_a.clone().svd(false, false).singular_values;
    let (smax, smin) = sv.iter().fold((0.0f64, f64::INFINITY), |(hi, lo), &s| {
        (hi.max(s), lo.min(s))
    });
    let condition = if smin > 0.0 {
        smax / smin
    } else {
        f64::INFINITY
    };
    // Covariance of the free increments under the penalised model: s²·(R⁻¹R⁻ᵀ) from the
    // SVD of the free columns of the full (data + smoothness) system, with
    // s² = 2·max(1, χ²/(m − p)): the misfit inflates it, and each pixel bin feeds two
    // neighbouring equations, so the equations are not independent.
    let free: Vec<usize> = (0..n).filter(|&j| d[j] > 0.0).collect();
    let p = free.len().max(1);
    let scale2 = 2.0 * (chi2 / (m.saturating_sub(p).max(1)) as f64).max(1.0);
    let predicted_error = if free.is_empty() {
        f64::INFINITY
    } else {
        let svd = a.select_columns(&free).svd(false, true);
        let vt = svd.v_t.unwrap_or_else(|| DMatrix::identity(p, p));
        let codes = 16..=239;
        let count = codes.clone().count() as f64;
        let var_sum: f64 = codes
            .map(|k| {
                let x = (f64::from(k) / 255.0).ln().max(log_floor);
                let r = ramps(n, 1.0 - x / log_floor);
                let phi = DVector::from_iterator(p, free.iter().map(|&j| r[j]));
                (&vt * phi)
                    .iter()
                    .zip(svd.singular_values.iter())
                    .map(|(v, s)| {
                        if *s > 0.0 {
                            (v / s).powi(2)
                        } else {
                            f64::INFINITY
                        }
                    })
                    .sum::<f64>()
            })
            .sum();
        (scale2 * var_sum / count).sqrt() / std::f64::consts::LN_2
    };
    let (lo, hi) = (covered.0, covered.1.min(1.0));
    let coverage =
        ((hi.min(239.0 / 255.0) - lo.max(16.0 / 255.0)) / (223.0 / 255.0)).clamp(0.0, 1.0);
    ChannelFit {
        degree: n,
        smoothing: lambda / problem.total_weight().max(f64::MIN_POSITIVE),
        coefficients: coefficients(&d),
        log_floor,
        covered: (lo, hi),
        residual_rms,
        equations: m,
        condition,
        predicted_error,
        coverage,
        confidence: confidence(coverage, predicted_error),
    }
}

/// `coverage / (1 + (predicted_error / 0.05 stop)²)`; 0 for an undetermined curve.
fn confidence(coverage: f64, predicted_error: f64) -> f64 {
    if predicted_error.is_finite() {
        coverage / (1.0 + (predicted_error / 0.05).powi(2))
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
    fn bernstein_partition_of_unity_and_ramps() {
        for t in [0.0, 0.2, 0.7, 1.0] {
            assert!((bernstein(7, t).iter().sum::<f64>() - 1.0).abs() < 1e-14);
        }
        assert!(ramps(5, 1.0).iter().all(|v| v.abs() < 1e-14));
        assert!(ramps(5, 0.0).iter().all(|v| (v + 1.0).abs() < 1e-14));
    }

    #[test]
    fn curvature_rows_integrate_the_squared_second_derivative() {
        let (n, x0) = (9, -4.5);
        let p = curvature(n, x0);
        // A power law (all increments equal: u linear in ln b) costs nothing.
        let flat = &p * DVector::from_element(n, 0.7);
        assert!(flat.norm() < 1e-9, "{}", flat.norm());
        // Any other curve: ‖P d‖² against ∫ u''(x)² dx by finite differences.
        let d = DVector::from_iterator(n, (0..n).map(|j| 0.1 + ((j * 7) % 5) as f64 * 0.3));
        let u = |x: f64| -> f64 {
            ramps(n, 1.0 - x / x0)
                .iter()
                .zip(d.iter())
                .map(|(r, d)| r * d)
                .sum()
        };
        let steps = 4000;
        let dx = -x0 / steps as f64;
        // Inside the domain: the ramps are clamped at its ends.
        let h = dx / 4.0;
        let integral: f64 = (0..steps)
            .map(|k| {
                let x = x0 + (k as f64 + 0.5) * dx;
                let second = (u(x + h) - 2.0 * u(x) + u(x - h)) / (h * h);
                second * second * dx
            })
            .sum();
        let rows = (&p * &d).norm_squared();
        assert!(
            (rows - integral).abs() < 0.02 * integral,
            "{rows} vs {integral}"
        );
    }

    #[test]
    fn nnls_matches_unconstrained_when_interior_and_clamps_otherwise() {
        let a = DMatrix::from_row_slice(3, 2, &[1.0, 0.0, 0.0, 1.0, 1.0, 1.0]);
        let y = DVector::from_vec(vec![1.0, 2.0, 3.0]);
        let x = nnls(&a, &y);
        assert!((x[0] - 1.0).abs() < 1e-12 && (x[1] - 2.0).abs() < 1e-12);
        let y = DVector::from_vec(vec![-1.0, 2.0, 1.0]);
        let x = nnls(&a, &y);
        assert_eq!(x[0], 0.0);
        assert!((x[1] - 1.5).abs() < 1e-12);
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
        // A power law is a straight line in log–log: the data let the smoothest model win.
        assert_eq!(auto.smoothing, SMOOTHING_GRID[0], "{auto:?}");
        assert!(auto.confidence > 0.8, "{auto:?}");
    }

    #[test]
    fn rejects_too_few_tones_and_bad_degrees() {
        assert_eq!(fit(&[], 1.0, Degree::Auto), Err(FitError::TooFewTones(0)));
        assert_eq!(
            fit(&power_pairs(2.2, 4.0), 1.0, Degree::Fixed(0)),
            Err(FitError::Degree(0))
        );
    }
}
