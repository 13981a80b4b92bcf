//! What happens to the light inside the film before it forms density: the emulsion's
//! modulation transfer function (MTF) and halation. Both act on exposure `H` (linear
//! light), before the characteristic curve, as the data sheets measure the MTF.
//!
//! **MTF.** The sheet's curve `M_c(f)` (response against cycles/mm at film scale, layer
//! `c`) is fitted by a sum of Gaussians, a form that is both radially symmetric and
//! separable:
//!
//! `M_c(f) ≈ Σᵢ wᵢ · exp(−2π² σᵢ² f²)`, `Σᵢ wᵢ = 1` (a uniform area keeps its exposure),
//!
//! with fixed spreads σᵢ = 1.5, 3, 6, 12, 24, 48, 96 µm and weights by least squares on
//! the sheet's points (ridge 10⁻⁴; [`MtfFit::worst_error`] states the fit's worst
//! deviation from the sheet's points). The filtered exposure is `Σᵢ wᵢ·(Gᵢ ∗ H)`, each
//! `Gᵢ` a Gaussian of σᵢ / p pixels (p the pixel's size at film scale): a sampled kernel
//! of radius ⌈3σ⌉ up to [`MAX_KERNEL_SIGMA`] px σ, three box passes per axis above. A sheet's response above
//! 100 % at low frequency (the development's adjacency effects) becomes a negative weight
//! on a wide Gaussian: edges gain the film's own acutance. Exposure taken below zero by
//! that is held at zero (no light).
//!
//! **Halation.** Light that passes the emulsion reflects off the back of the base and
//! re-exposes the layers nearest the base, red most, from a halo of radius about twice
//! the base thickness. Modelled as `H'_r = (H_r + s·(G_σ ∗ H_r)) / (1 + s)`,
//! `H'_g = (H_g + (s/4)·(G_σ ∗ H_g)) / (1 + s/4)`, blue untouched (dividing keeps a
//! uniform area's exposure, as the film's rated speed includes its own flare), with `G_σ` a Gaussian of
//! σ = [`HALATION_SIGMA_MM`] at film scale (three box passes per axis) and `s` the user's
//! strength. Only bright highlights make a visible halo, since `G_σ ∗ H` is a small
//! fraction of a mid-tone but a large one next to the sun. The built-in stocks all have an
//! anti-halation layer, so it is off unless asked for.

use rayon::prelude::*;

use super::stock::Mtf;

/// Spreads of the Gaussians the MTF is fitted with, µm at film scale.
pub const SPREADS_UM: [f64; 7] = [1.5, 3.0, 6.0, 12.0, 24.0, 48.0, 96.0];

/// Halo spread of halation at film scale, mm (a base ≈ 0.12 mm thick).
pub const HALATION_SIGMA_MM: f64 = 0.1;

/// One layer's MTF as a weighted sum of Gaussians.
#[derive(Debug, Clone, PartialEq)]
pub struct MtfFit {
    /// `(σ in mm, weight)`.
    pub terms: Vec<(f64, f64)>,
    /// The largest `|fit − sheet|` over the sheet's points (response, 1 = 100 %).
    pub worst_error: f64,
}

impl MtfFit {
    /// Fits layer `c` of `mtf`.
    pub fn new(mtf: &Mtf, c: usize) -> MtfFit {
        let n = SPREADS_UM.len();
        let sigma: Vec<f64> = SPREADS_UM.iter().map(|s| s / 1000.0).collect();
        let basis = |f: f64| -> Vec<f64> {
            sigma
                .iter()
                .map(|s| (-2.0 * std::f64::consts::PI.powi(2) * s * s * f * f).exp())
                .collect()
        };
        // Rows: the sheet's points, and M(0) = 1 weighted 100×.
        let mut rows: Vec<(Vec<f64>, f64, f64)> = mtf
            .cycles_per_mm
            .iter()
            .zip(&mtf.layers[c])
            .map(|(&f, &m)| (basis(f), m, 1.0))
            .collect();
        rows.push((basis(0.0), 1.0, 100.0));
        let mut a = vec![vec![0.0; n + 1]; n];
        for (b, m, weight) in &rows {
            let w2 = weight * weight;
            for i in 0..n {
                for j in 0..n {
                    a[i][j] += w2 * b[i] * b[j];
                }
                a[i][n] += w2 * b[i] * m;
            }
        }
        for (i, row) in a.iter_mut().enumerate() {
            row[i] += 1e-4;
        }
        let w = solve(a);
        let total: f64 = w.iter().sum();
        let terms: Vec<(f64, f64)> = sigma
            .iter()
            .zip(&w)
            .map(|(&s, &w)| (s, w / total))
            .collect();
        let mut fit = MtfFit {
            terms,
            worst_error: 0.0,
        };
        fit.worst_error = mtf
            .cycles_per_mm
            .iter()
            .zip(&mtf.layers[c])
            .map(|(&f, &m)| (fit.response(f) - m).abs())
            .fold(0.0, f64::max);
        fit
    }

    /// The fitted response at `f` cycles/mm.
    pub fn response(&self, f: f64) -> f64 {
        self.terms
            .iter()
            .map(|(s, w)| w * (-2.0 * std::f64::consts::PI.powi(2) * s * s * f * f).exp())
            .sum()
    }
}

/// Gauss–Jordan elimination with partial pivoting on an augmented `n × (n+1)` matrix.
fn solve(mut a: Vec<Vec<f64>>) -> Vec<f64> {
    let n = a.len();
    for col in 0..n {
        let pivot = (col..n)
            .max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs()))
            .unwrap_or(col);
        a.swap(col, pivot);
        let p = a[col][col];
        for v in a[col].iter_mut() {
            *v /= p;
        }
        let pivot_row = a[col].clone();
        for (i, row) in a.iter_mut().enumerate() {
            if i != col {
                let factor = row[col];
                for (v, p) in row.iter_mut().zip(&pivot_row) {
                    *v -= factor * p;
                }
            }
        }
    }
    a.iter().map(|row| row[n]).collect()
}

/// Filters channel `c` of an interleaved `ch`-channel image through `fit` at `pitch_mm`
/// per pixel: `Σ wᵢ·(Gᵢ ∗ H)`, held at zero from below.
pub fn apply_mtf(
    pixels: &mut [f32],
    width: usize,
    height: usize,
    ch: usize,
    c: usize,
    fit: &MtfFit,
    pitch_mm: f64,
) {
    let plane: Vec<f32> = pixels.iter().skip(c).step_by(ch).copied().collect();
    let mut acc = vec![0f32; plane.len()];
    for &(sigma, weight) in &fit.terms {
        let blurred = gaussian(&plane, width, height, sigma / pitch_mm);
        acc.par_iter_mut()
            .zip(blurred.par_iter())
            .for_each(|(a, b)| *a += weight as f32 * b);
    }
    pixels
        .par_chunks_mut(ch)
        .zip(acc.par_iter())
        .for_each(|(p, v)| p[c] = v.max(0.0));
}

/// Largest σ (pixels) blurred by a sampled kernel; above it, three box passes per axis.
pub const MAX_KERNEL_SIGMA: f64 = 4.0;

/// A Gaussian blur of σ `sigma_px` pixels: a sampled, normalised kernel of radius ⌈3σ⌉
/// for σ ≤ [`MAX_KERNEL_SIGMA`], three box passes per axis above (edges repeat the
/// border pixel). Both passes run along rows (columns as whole rows scaled and added), so
/// the inner loops are over contiguous memory and vectorise.
pub fn gaussian(plane: &[f32], width: usize, height: usize, sigma_px: f64) -> Vec<f32> {
    if sigma_px > MAX_KERNEL_SIGMA {
        let half = box_half_width(sigma_px);
        let mut out = plane.to_vec();
        for _ in 0..3 {
            box_rows(&mut out, width, half);
        }
        for _ in 0..3 {
            out = box_columns(&out, width, height, half);
        }
        return out;
    }
    let r = (3.0 * sigma_px).ceil().max(1.0) as usize;
    let mut kernel: Vec<f32> = (0..=2 * r)
        .map(|i| {
            let x = i as f64 - r as f64;
            (-x * x / (2.0 * sigma_px * sigma_px)).exp() as f32
        })
        .collect();
    let total: f32 = kernel.iter().sum();
    for k in &mut kernel {
        *k /= total;
    }
    let rows = fir_rows(plane, width, &kernel);
    fir_columns(&rows, width, height, &kernel)
}

fn fir_rows(plane: &[f32], width: usize, kernel: &[f32]) -> Vec<f32> {
    let r = kernel.len() / 2;
    let mut out = vec![0f32; plane.len()];
    out.par_chunks_mut(width)
        .zip(plane.par_chunks(width))
        .for_each(|(o, row)| {
            let mut padded = Vec::with_capacity(width + 2 * r);
            padded.extend(std::iter::repeat_n(row[0], r));
            padded.extend_from_slice(row);
            padded.extend(std::iter::repeat_n(row[width - 1], r));
            for (j, &k) in kernel.iter().enumerate() {
                for (v, &a) in o.iter_mut().zip(&padded[j..j + width]) {
                    *v += k * a;
                }
            }
        });
    out
}

fn fir_columns(plane: &[f32], width: usize, height: usize, kernel: &[f32]) -> Vec<f32> {
    let r = kernel.len() / 2;
    let mut out = vec![0f32; plane.len()];
    out.par_chunks_mut(width).enumerate().for_each(|(y, o)| {
        for (j, &k) in kernel.iter().enumerate() {
            let yy = (y + j).saturating_sub(r).min(height - 1);
            for (v, &a) in o.iter_mut().zip(&plane[yy * width..yy * width + width]) {
                *v += k * a;
            }
        }
    });
    out
}

/// One box pass down the columns: each output row the mean of rows `y−h ..= y+h`
/// (clamped), kept as a running sum of whole rows in `f64`.
fn box_columns(plane: &[f32], width: usize, height: usize, half: usize) -> Vec<f32> {
    if half == 0 {
        return plane.to_vec();
    }
    let n = (2 * half + 1) as f64;
    let row = |y: isize| {
        let y = y.clamp(0, height as isize - 1) as usize;
        &plane[y * width..y * width + width]
    };
    let mut out = vec![0f32; plane.len()];
    // Columns in strips of 256, strips in parallel.
    const STRIP: usize = 256;
    let strips: Vec<(usize, usize)> = (0..width)
        .step_by(STRIP)
        .map(|x| (x, STRIP.min(width - x)))
        .collect();
    let results: Vec<Vec<f32>> = strips
        .par_iter()
        .map(|&(x0, w)| {
            let mut sum = vec![0f64; w];
            for y in -(half as isize)..=half as isize {
                for (s, &v) in sum.iter_mut().zip(&row(y)[x0..x0 + w]) {
                    *s += f64::from(v);
                }
            }
            let mut strip = vec![0f32; w * height];
            for y in 0..height {
                for (o, s) in strip[y * w..y * w + w].iter_mut().zip(&sum) {
                    *o = (s / n) as f32;
                }
                let add = &row(y as isize + half as isize + 1)[x0..x0 + w];
                let sub = &row(y as isize - half as isize)[x0..x0 + w];
                for ((s, &a), &b) in sum.iter_mut().zip(add).zip(sub) {
                    *s += f64::from(a) - f64::from(b);
                }
            }
            strip
        })
        .collect();
    for ((x0, w), strip) in strips.iter().zip(results) {
        for y in 0..height {
            out[y * width + x0..y * width + x0 + w].copy_from_slice(&strip[y * w..y * w + w]);
        }
    }
    out
}

/// Half-width of a box whose three passes have variance σ²: `3·((2h+1)² − 1)/12 = σ²`.
fn box_half_width(sigma_px: f64) -> usize {
    (((4.0 * sigma_px * sigma_px + 1.0).sqrt() - 1.0) / 2.0).round() as usize
}

/// Adds the halo: channel `c` = `(c + strength·(G_σ ∗ c)) / (1 + strength)` with `σ = sigma_px`
/// pixels (three box blurs per axis, each of width `w` with `3·(w² − 1)/12 ≈ σ²`).
pub fn add_halo(
    pixels: &mut [f32],
    width: usize,
    height: usize,
    ch: usize,
    c: usize,
    strength: f32,
    sigma_px: f64,
) {
    let plane: Vec<f32> = pixels.iter().skip(c).step_by(ch).copied().collect();
    let plane = gaussian(&plane, width, height, sigma_px);
    pixels
        .par_chunks_mut(ch)
        .zip(plane.par_iter())
        .for_each(|(p, g)| {
            if g.is_finite() {
                p[c] = (p[c] + strength * g) / (1.0 + strength);
            }
        });
}

fn box_rows(plane: &mut [f32], width: usize, half: usize) {
    if half == 0 {
        return;
    }
    let n = (2 * half + 1) as f64;
    plane.par_chunks_mut(width).for_each(|row| {
        let src: Vec<f64> = row
            .iter()
            .map(|v| if v.is_finite() { f64::from(*v) } else { 0.0 })
            .collect();
        let at = |i: isize| src[i.clamp(0, width as isize - 1) as usize];
        let mut sum: f64 = (-(half as isize)..=half as isize).map(at).sum();
        for (x, out) in row.iter_mut().enumerate() {
            *out = (sum / n) as f32;
            sum += at(x as isize + half as isize + 1) - at(x as isize - half as isize);
        }
    });
}
