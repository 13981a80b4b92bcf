//! Clamped B-spline bases on an interval, and the monotone *ramps* built from them.
//!
//! A clamped knot vector on `[lo, hi]` repeats each end `p + 1` times around the interior
//! knots; its `n` B-splines `N_{i,p}` of degree `p` are non-negative and sum to one. With no
//! interior knots they are the Bernstein polynomials of degree `p` on `[lo, hi]`.
//!
//! The **tail sums** `T_j = Σ_{m ≥ j} N_{m,p}` (`j = 1..n−1`) rise from 0 at `lo` to 1 at
//! `hi`, and are non-decreasing: `T_j' = p·N_{j,p−1} / (t_{j+p} − t_j) ≥ 0` (de Boor). So a
//! spline `u = Σ_j d_j·(T_j − 1)` with every `d_j ≥ 0` is non-decreasing and `u(hi) = 0`:
//! [`Basis::ramps`] returns the `R_j = T_j − 1`, the columns in which monotonicity is a sign
//! constraint. Its B-spline coefficients are `c_m = −Σ_{j > m} d_j` (non-decreasing,
//! `c_{n−1} = 0`), see [`Basis::coefficients`].

/// A clamped B-spline basis of degree `p` on `[lo, hi]` (see module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct Basis {
    degree: usize,
    /// The full knot vector: `p + 1` copies of `lo`, the interior knots, `p + 1` of `hi`.
    knots: Vec<f64>,
}

impl Basis {
    /// Degree `p ≥ 1` on `[lo, hi]` (`lo < hi`) with the given interior knots; knots
    /// outside `(lo, hi)`, non-finite or repeated are dropped.
    pub fn new(degree: usize, lo: f64, hi: f64, interior: &[f64]) -> Basis {
        let degree = degree.max(1);
        let mut inner: Vec<f64> = interior
            .iter()
            .copied()
            .filter(|k| k.is_finite() && *k > lo && *k < hi)
            .collect();
        inner.sort_by(f64::total_cmp);
        inner.dedup();
        let mut knots = vec![lo; degree + 1];
        knots.extend(inner);
        knots.extend(std::iter::repeat_n(hi, degree + 1));
        Basis { degree, knots }
    }

    /// Degree `p` of the pieces.
    pub fn degree(&self) -> usize {
        self.degree
    }

    /// Number of B-splines `n` (the spline's coefficients).
    pub fn len(&self) -> usize {
        self.knots.len() - self.degree - 1
    }

    /// Always false: a basis has at least `p + 1 ≥ 2` functions.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// The interval `[lo, hi]`.
    pub fn domain(&self) -> (f64, f64) {
        (self.knots[0], self.knots[self.knots.len() - 1])
    }

    /// The interior knots.
    pub(crate) fn interior(&self) -> &[f64] {
        &self.knots[self.degree + 1..self.knots.len() - self.degree - 1]
    }

    /// The distinct knots `lo, interior…, hi`: the breakpoints between polynomial pieces.
    fn breakpoints(&self) -> Vec<f64> {
        let (lo, hi) = self.domain();
        let mut b = vec![lo];
        b.extend_from_slice(self.interior());
        b.push(hi);
        b
    }

    /// `N_{i,q}(x)` for every order `q = 0..=p` (Cox–de Boor, `0/0 = 0`); `x` is clamped to
    /// the domain, and `x = hi` belongs to the last piece.
    fn orders(&self, x: f64) -> Vec<Vec<f64>> {
        let t = &self.knots;
        let (lo, hi) = self.domain();
        let x = x.clamp(lo, hi);
        let last = t.len() - 1;
        // The piece holding x: t[s] ≤ x < t[s+1], or the last non-empty one at x = hi.
        let s = if x >= hi {
            (0..last).rev().find(|&i| t[i] < t[i + 1]).unwrap_or(0)
        } else {
            t.partition_point(|&k| k <= x)
                .saturating_sub(1)
                .min(last - 1)
        };
        let mut out: Vec<Vec<f64>> = Vec::with_capacity(self.degree + 1);
        out.push((0..last).map(|i| if i == s { 1.0 } else { 0.0 }).collect());
        for q in 1..=self.degree {
            let prev = &out[q - 1];
            let row = (0..last - q)
                .map(|i| {
                    ratio(x - t[i], t[i + q] - t[i]) * prev[i]
                        + ratio(t[i + q + 1] - x, t[i + q + 1] - t[i + 1]) * prev[i + 1]
                })
                .collect();
            out.push(row);
        }
        out
    }

    /// The `n` B-splines `N_{i,p}(x)`.
    pub fn values(&self, x: f64) -> Vec<f64> {
        self.orders(x).pop().unwrap_or_default()
    }

    /// The ramps `R_j(x) = T_j(x) − 1`, `j = 1..n−1` (see module docs).
    pub fn ramps(&self, x: f64) -> Vec<f64> {
        let n = self.values(x);
        let mut out = vec![0.0; n.len() - 1];
        let mut tail = 0.0;
        for j in (1..n.len()).rev() {
            tail += n[j];
            out[j - 1] = tail - 1.0;
        }
        out
    }

    /// `dR_j/dx = p·N_{j,p−1} / (t_{j+p} − t_j)`, `j = 1..n−1`.
    fn ramp_slopes(&self, x: f64) -> Vec<f64> {
        let p = self.degree;
        let orders = self.orders(x);
        let below = &orders[p - 1];
        let t = &self.knots;
        (1..self.len())
            .map(|j| ratio(p as f64 * below[j], t[j + p] - t[j]))
            .collect()
    }

    /// `d²R_j/dx² = p(p−1)/(t_{j+p} − t_j) · (N_{j,p−2}/(t_{j+p−1} − t_j) −
    /// N_{j+1,p−2}/(t_{j+p} − t_{j+1}))`, `j = 1..n−1` (zero for `p = 1`).
    pub(crate) fn ramp_curvatures(&self, x: f64) -> Vec<f64> {
        let p = self.degree;
        if p < 2 {
            return vec![0.0; self.len() - 1];
        }
        let orders = self.orders(x);
        let two_below = &orders[p - 2];
        let t = &self.knots;
        (1..self.len())
            .map(|j| {
                let inner = ratio(two_below[j], t[j + p - 1] - t[j])
                    - ratio(two_below[j + 1], t[j + p] - t[j + 1]);
                ratio((p * (p - 1)) as f64 * inner, t[j + p] - t[j])
            })
            .collect()
    }

    /// B-spline coefficients `c_m = −Σ_{j>m} d_j` of `u = Σ_j d_j R_j` (`n` values, the last 0).
    pub fn coefficients(&self, increments: &[f64]) -> Vec<f64> {
        let n = increments.len() + 1;
        let mut c = vec![0.0; n];
        for m in (0..n - 1).rev() {
            c[m] = c[m + 1] - increments[m];
        }
        c
    }

    /// `u(x) = Σ_m c_m N_m(x)`.
    pub fn eval(&self, coefficients: &[f64], x: f64) -> f64 {
        self.values(x)
            .iter()
            .zip(coefficients)
            .map(|(n, c)| n * c)
            .sum()
    }

    /// `u'(x) = Σ_m c_m N_m'(x)`, from the ramps' slopes (`c_m − c_{m−1}` are the increments).
    pub fn slope(&self, coefficients: &[f64], x: f64) -> f64 {
        self.ramp_slopes(x)
            .iter()
            .zip(coefficients.windows(2))
            .map(|(s, w)| s * (w[1] - w[0]))
            .sum()
    }

    /// Nodes and weights of a quadrature that integrates `(u'')²` exactly over the domain:
    /// Gauss–Legendre with `max(1, p − 1)` points on every piece (`u''` has degree `p − 2`).
    pub fn curvature_quadrature(&self) -> Vec<(f64, f64)> {
        let rule = gauss_legendre(self.degree.saturating_sub(1).max(1));
        self.breakpoints()
            .windows(2)
            .flat_map(|w| {
                let (mid, half) = ((w[0] + w[1]) / 2.0, (w[1] - w[0]) / 2.0);
                rule.iter()
                    .map(move |&(z, wt)| (mid + half * z, half * wt))
                    .collect::<Vec<_>>()
            })
            .collect()
    }
}

/// `num / den`, and 0 where a repeated knot makes `den` zero (the B-spline convention
/// `0/0 = 0`: the term belongs to an empty piece).
fn ratio(num: f64, den: f64) -> f64 {
    if den > 0.0 { num / den } else { 0.0 }
}

/// Gauss–Legendre nodes and weights on `[−1, 1]` with `k ≥ 1` points (Newton's method on
/// `P_k`, started at the Chebyshev-like guesses `cos(π(i − ¼)/(k + ½))`).
fn gauss_legendre(k: usize) -> Vec<(f64, f64)> {
    (1..=k)
        .map(|i| {
            let mut z = (std::f64::consts::PI * (i as f64 - 0.25) / (k as f64 + 0.5)).cos();
            let mut derivative = 1.0;
            for _ in 0..100 {
                // P_k(z) and P_k'(z) by the three-term recurrence.
                let (mut p0, mut p1) = (1.0, z);
                for m in 2..=k {
                    let p2 = ((2 * m - 1) as f64 * z * p1 - (m - 1) as f64 * p0) / m as f64;
                    p0 = p1;
                    p1 = p2;
                }
                let (pk, pk_1) = if k == 1 { (z, 1.0) } else { (p1, p0) };
                derivative = k as f64 * (z * pk - pk_1) / (z * z - 1.0);
                let step = pk / derivative;
                z -= step;
                if step.abs() < 1e-15 {
                    break;
                }
            }
            (z, 2.0 / ((1.0 - z * z) * derivative * derivative))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cubic() -> Basis {
        Basis::new(3, -4.0, 0.0, &[-3.0, -1.5, -0.4, -0.1, -0.03])
    }

    #[test]
    fn partition_of_unity_and_ramp_ends() {
        for basis in [cubic(), Basis::new(7, -4.0, 0.0, &[])] {
            for x in [-4.0, -3.2, -1.0, -0.05, 0.0] {
                assert!((basis.values(x).iter().sum::<f64>() - 1.0).abs() < 1e-14);
            }
            assert!(basis.ramps(0.0).iter().all(|v| v.abs() < 1e-14));
            assert!(basis.ramps(-4.0).iter().all(|v| (v + 1.0).abs() < 1e-14));
        }
    }

    #[test]
    fn no_interior_knots_is_bernstein() {
        let basis = Basis::new(5, -2.0, 0.0, &[]);
        let t: f64 = 0.3; // x = -2 + 0.3·2
        let binomial = [1.0, 5.0, 10.0, 10.0, 5.0, 1.0];
        for (k, v) in basis.values(-1.4).iter().enumerate() {
            let bernstein = binomial[k] * t.powi(k as i32) * (1.0 - t).powi(5 - k as i32);
            assert!((v - bernstein).abs() < 1e-14, "{k}: {v} vs {bernstein}");
        }
    }

    #[test]
    fn slopes_and_curvatures_match_finite_differences() {
        let basis = cubic();
        let h = 1e-5;
        for x in [-3.7, -2.2, -1.0, -0.2, -0.07, -0.01] {
            let (lo, mid, hi) = (basis.ramps(x - h), basis.ramps(x), basis.ramps(x + h));
            let slopes = basis.ramp_slopes(x);
            let curvatures = basis.ramp_curvatures(x);
            for j in 0..slopes.len() {
                let s = (hi[j] - lo[j]) / (2.0 * h);
                let c = (hi[j] - 2.0 * mid[j] + lo[j]) / (h * h);
                assert!(
                    (s - slopes[j]).abs() < 1e-6 * (1.0 + s.abs()),
                    "x {x} j {j}: {s} vs {}",
                    slopes[j]
                );
                assert!(
                    (c - curvatures[j]).abs() < 1e-3 * (1.0 + c.abs()),
                    "x {x} j {j}: {c} vs {}",
                    curvatures[j]
                );
                assert!(slopes[j] >= 0.0);
            }
        }
    }

    #[test]
    fn increments_and_coefficients_describe_one_curve() {
        let basis = cubic();
        let d: Vec<f64> = (0..basis.len() - 1)
            .map(|j| 0.1 + 0.05 * j as f64)
            .collect();
        let c = basis.coefficients(&d);
        assert_eq!(c[c.len() - 1], 0.0);
        assert!(c.windows(2).all(|w| w[0] <= w[1]));
        for x in [-3.9, -2.0, -0.3, -0.02] {
            let from_ramps: f64 = basis.ramps(x).iter().zip(&d).map(|(r, d)| r * d).sum();
            assert!((basis.eval(&c, x) - from_ramps).abs() < 1e-13);
            let from_slopes: f64 = basis
                .ramp_slopes(x)
                .iter()
                .zip(&d)
                .map(|(r, d)| r * d)
                .sum();
            assert!((basis.slope(&c, x) - from_slopes).abs() < 1e-12);
        }
    }

    #[test]
    fn quadrature_integrates_squared_curvature_exactly() {
        let basis = cubic();
        let d: Vec<f64> = (0..basis.len() - 1)
            .map(|j| ((j * 7) % 5) as f64 * 0.3)
            .collect();
        let second = |x: f64| -> f64 {
            basis
                .ramp_curvatures(x)
                .iter()
                .zip(&d)
                .map(|(r, d)| r * d)
                .sum()
        };
        let by_rule: f64 = basis
            .curvature_quadrature()
            .iter()
            .map(|&(x, w)| w * second(x).powi(2))
            .sum();
        // Simpson on a fine grid inside each piece (u'' is linear there).
        let mut fine = 0.0;
        for w in basis.breakpoints().windows(2) {
            let steps = 200;
            let h = (w[1] - w[0]) / steps as f64;
            for k in 0..steps {
                let a = w[0] + k as f64 * h;
                let (f0, f1, f2) = (
                    second(a + 1e-12),
                    second(a + h / 2.0),
                    second(a + h - 1e-12),
                );
                fine += h / 6.0 * (f0 * f0 + 4.0 * f1 * f1 + f2 * f2);
            }
        }
        assert!((by_rule - fine).abs() < 1e-6 * fine, "{by_rule} vs {fine}");
    }

    #[test]
    fn gauss_legendre_integrates_polynomials() {
        for k in 1..=15 {
            let rule = gauss_legendre(k);
            assert!((rule.iter().map(|r| r.1).sum::<f64>() - 2.0).abs() < 1e-12);
            // ∫ z^(2k−2) over [−1, 1] = 2/(2k−1).
            let e = 2 * k - 2;
            let sum: f64 = rule.iter().map(|&(z, w)| w * z.powi(e as i32)).sum();
            assert!((sum - 2.0 / (e + 1) as f64).abs() < 1e-12, "k {k}");
        }
    }
}
