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
//! `Gᵢ` a Gaussian of σᵢ / p pixels (p the pixel's size at film scale), computed by
//! [`filter`]: narrow terms as sampled kernels at full resolution, wide ones on a
//! decimated plane. A sheet's response above
//! 100 % at low frequency (the development's adjacency effects) becomes a negative weight
//! on a wide Gaussian: edges gain the film's own acutance. Exposure taken below zero by
//! that is held at zero (no light).
//!
//! **Halation.** Light that passes the emulsion reflects off the back of the base and
//! re-exposes the layers nearest the base, red most, from a halo of radius about twice
//! the base thickness. Modelled as `H'_r = (H_r + s·(G_σ ∗ H_r)) / (1 + s)`,
//! `H'_g = (H_g + (s/4)·(G_σ ∗ H_g)) / (1 + s/4)`, blue untouched (dividing keeps a
//! uniform area's exposure, as the film's rated speed includes its own flare), with `G_σ` a Gaussian of
//! σ = [`HALATION_SIGMA_MM`] at film scale (through [`filter`]) and `s` the user's
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

impl MtfFit {
    /// The fit as filter terms `(σ in pixels, weight)` for pixels of `pitch_mm` at film
    /// scale.
    pub fn terms_px(&self, pitch_mm: f64) -> Vec<(f64, f64)> {
        self.terms.iter().map(|&(s, w)| (s / pitch_mm, w)).collect()
    }
}

/// The halation filter of one layer as terms `(σ in pixels, weight)`:
/// `(H + s·(G_σ ∗ H)) / (1 + s)`.
pub fn halation_terms(strength: f64, sigma_px: f64) -> Vec<(f64, f64)> {
    vec![
        (0.0, 1.0 / (1.0 + strength)),
        (sigma_px, strength / (1.0 + strength)),
    ]
}

/// Two filters one after the other, as one: `G(a) ∗ G(b) = G(√(a² + b²))`, so the terms
/// are every pair's `(√(σᵢ² + σⱼ²), wᵢ·wⱼ)`.
pub fn compose(first: &[(f64, f64)], then: &[(f64, f64)]) -> Vec<(f64, f64)> {
    first
        .iter()
        .flat_map(|&(a, v)| then.iter().map(move |&(b, w)| (a.hypot(b), v * w)))
        .collect()
}

/// The smallest spread, in pixels of the decimated plane, a wide term is blurred with
/// there: [`LEVEL_ONE_MIN_SIGMA`] at half resolution, this at coarser levels, so that the
/// decimated result is smooth on its grid and a point's halo comes back round, not
/// pyramid-shaped (see [`Filter`]).
pub const COARSE_MIN_SIGMA: f64 = 1.5;

/// The smallest spread at half resolution (level 1), in half-resolution pixels.
pub const LEVEL_ONE_MIN_SIGMA: f64 = 0.8;

/// Rows per band of [`filter`]'s full-resolution pass.
pub const BAND: usize = 16;

/// Variance (px², per axis) a term at decimation level `L` (`F = 2^L`) gains besides
/// its own blur: the `F × F` block mean, `(F² − 1)/12`, and bilinear upsampling by 2 at
/// every level back to full resolution, `Σₖ₌₁..L 4ᵏ/6 = (4^(L+1) − 4)/18`.
fn level_variance(l: u32) -> f64 {
    let f2 = 4f64.powi(l as i32);
    (f2 - 1.0) / 12.0 + (4.0 * f2 - 4.0) / 18.0
}

/// The decimation level `L` (factor `F = 2^L`) of a Gaussian of σ `s` pixels: the
/// largest with `s² − level_variance(L) ≥ F²·r_min²`, `r_min` [`LEVEL_ONE_MIN_SIGMA`]
/// at level 1 and [`COARSE_MIN_SIGMA`] above (0: full resolution).
fn level(s: f64) -> u32 {
    (1..24)
        .take_while(|&l| {
            let r_min = if l == 1 {
                LEVEL_ONE_MIN_SIGMA
            } else {
                COARSE_MIN_SIGMA
            };
            s * s - level_variance(l) >= 4f64.powi(l as i32) * r_min * r_min
        })
        .last()
        .unwrap_or(0)
}

/// A sampled, normalised Gaussian of σ `sigma` pixels and radius `⌈reach·σ⌉` (at least 1).
fn kernel(sigma: f64, reach: f64) -> Vec<f32> {
    let r = (reach * sigma).ceil().max(1.0) as usize;
    let k: Vec<f64> = (0..=2 * r)
        .map(|i| {
            let x = i as f64 - r as f64;
            (-x * x / (2.0 * sigma * sigma)).exp()
        })
        .collect();
    let total: f64 = k.iter().sum();
    k.iter().map(|v| (v / total) as f32).collect()
}

/// One channel of an interleaved image, read row by row as light: NaN and values ≤ 0
/// are 0, values above 10³⁰ (and +∞) are 10³⁰.
struct Source<'a> {
    pixels: &'a [f32],
    channels: usize,
    channel: usize,
    width: usize,
    height: usize,
}

impl Source<'_> {
    /// Row `y` (clamped to the image) into `out`.
    fn row(&self, y: isize, out: &mut [f32]) {
        let y = y.clamp(0, self.height as isize - 1) as usize;
        let row =
            &self.pixels[y * self.width * self.channels..(y + 1) * self.width * self.channels];
        for (o, p) in out.iter_mut().zip(row.chunks_exact(self.channels)) {
            let v = p[self.channel];
            *o = if v > 0.0 { v.min(1e30) } else { 0.0 };
        }
    }
}

/// One channel's filter, prepared: the identity's weight, the full-resolution kernels
/// and the wide terms summed on the half-resolution plane.
struct Plan {
    identity: f32,
    fine: Vec<(f32, Vec<f32>)>,
    /// Width, height and values of the half-resolution sum of the wide terms.
    coarse: Option<(usize, usize, Vec<f32>)>,
}

impl Plan {
    fn new(source: &Source<'_>, terms: &[(f64, f64)]) -> Plan {
        let mut plan = Plan {
            identity: 0.0,
            fine: Vec::new(),
            coarse: None,
        };
        let mut pyramid: Vec<(usize, usize, Vec<f32>)> = Vec::new();
        let mut sums: Vec<Option<Vec<f32>>> = Vec::new();
        for &(s, w) in terms {
            if s < 1e-3 {
                plan.identity += w as f32;
                continue;
            }
            let l = level(s) as usize;
            if l == 0 {
                plan.fine.push((w as f32, kernel(s, 3.0)));
                continue;
            }
            while pyramid.len() < l {
                let next = match pyramid.last() {
                    None => halve_source(source),
                    Some((lw, lh, p)) => halve(p, *lw, *lh),
                };
                pyramid.push(next);
                sums.push(None);
            }
            let (lw, lh, low) = &pyramid[l - 1];
            let f2 = 4f64.powi(l as i32);
            let r = ((s * s - level_variance(l as u32)) / f2).max(0.0).sqrt();
            let k = kernel(r, 3.0);
            let blurred = fir_columns(&fir_rows(low, *lw, &k), *lw, *lh, &k);
            let sum = sums[l - 1].get_or_insert_with(|| vec![0f32; lw * lh]);
            for (a, b) in sum.iter_mut().zip(&blurred) {
                *a += w as f32 * b;
            }
        }
        // Collapse the levels: each upsampled by 2 into the one below, down to level 1.
        for l in (1..sums.len()).rev() {
            if let Some(upper) = sums[l].take() {
                let (uw, uh, _) = pyramid[l];
                let (lw, lh, _) = pyramid[l - 1];
                let lower = sums[l - 1].get_or_insert_with(|| vec![0f32; lw * lh]);
                let mut mixed = vec![0f32; uw];
                for (y, row) in lower.chunks_exact_mut(lw).enumerate() {
                    mix_rows(&upper, uw, uh, y, &mut mixed);
                    upsample_row_add(&mixed, row);
                }
            }
        }
        if let Some(Some(sum)) = sums.into_iter().next() {
            let (lw, lh, _) = pyramid[0];
            plan.coarse = Some((lw, lh, sum));
        }
        plan
    }

    /// Rows `y0 .. y0 + acc.len()/width` of the filtered channel into `acc`.
    fn band(&self, source: &Source<'_>, y0: usize, acc: &mut [f32], scratch: &mut Scratch) {
        let width = source.width;
        let rows = acc.len() / width;
        let reach = self
            .fine
            .iter()
            .map(|(_, k)| k.len() / 2)
            .max()
            .unwrap_or(0);
        let lines = &mut scratch.lines;
        lines.resize((rows + 2 * reach) * width, 0.0);
        for (i, line) in lines.chunks_exact_mut(width).enumerate() {
            source.row(y0 as isize + i as isize - reach as isize, line);
        }
        for (a, &p) in acc
            .iter_mut()
            .zip(&lines[reach * width..(reach + rows) * width])
        {
            *a = self.identity * p;
        }
        for (w, k) in &self.fine {
            let r = k.len() / 2;
            let tmp = &mut scratch.tmp;
            tmp.resize((rows + 2 * r) * width, 0.0);
            let first = (reach - r) * width;
            for (t, line) in tmp
                .chunks_exact_mut(width)
                .zip(lines[first..].chunks_exact(width))
            {
                row_fir(line, k, &mut scratch.padded, t);
            }
            for (i, a) in acc.chunks_exact_mut(width).enumerate() {
                for (j, &kj) in k.iter().enumerate() {
                    let kw = w * kj;
                    for (v, &t) in a.iter_mut().zip(&tmp[(i + j) * width..(i + j + 1) * width]) {
                        *v += kw * t;
                    }
                }
            }
        }
        if let Some((lw, lh, plane)) = &self.coarse {
            let mixed = &mut scratch.low_row;
            mixed.resize(*lw, 0.0);
            for (i, a) in acc.chunks_exact_mut(width).enumerate() {
                mix_rows(plane, *lw, *lh, y0 + i, mixed);
                upsample_row_add(mixed, a);
            }
        }
    }
}

/// Row `y` of a plane upsampled by 2 vertically (bilinear, sample `j` centred on row
/// `2j + ½`): `¼·row(j−1) + ¾·row(j)` for even `y = 2j`, `¾·row(j) + ¼·row(j+1)` for odd,
/// rows clamped to the plane.
fn mix_rows(plane: &[f32], width: usize, height: usize, y: usize, out: &mut [f32]) {
    let j = y / 2;
    let (a, b) = if y.is_multiple_of(2) {
        (j.saturating_sub(1), j)
    } else {
        ((j + 1).min(height - 1), j)
    };
    let (ra, rb) = (
        &plane[a * width..(a + 1) * width],
        &plane[b * width..(b + 1) * width],
    );
    for ((o, &p), &q) in out.iter_mut().zip(ra).zip(rb) {
        *o = 0.25 * p + 0.75 * q;
    }
}

/// Adds a row upsampled by 2 (bilinear, as [`mix_rows`] across) to `out`, whose length is
/// `2·low.len()` or one less.
fn upsample_row_add(low: &[f32], out: &mut [f32]) {
    let n = low.len();
    let at = |i: usize| low[i.min(n - 1)];
    for (i, pair) in out.chunks_mut(2).enumerate() {
        let centre = 0.75 * low[i];
        pair[0] += centre + 0.25 * low[i.saturating_sub(1)];
        if let Some(odd) = pair.get_mut(1) {
            *odd += centre + 0.25 * at(i + 1);
        }
    }
}

/// Per-thread buffers of the band pass.
#[derive(Default)]
struct Scratch {
    lines: Vec<f32>,
    tmp: Vec<f32>,
    padded: Vec<f32>,
    low_row: Vec<f32>,
    acc: Vec<f32>,
}

/// A radially symmetric filter `Σᵢ wᵢ·(G(σᵢ) ∗ P)` of a `width × height` plane `P`, each
/// `G(σ)` a Gaussian of σ pixels (σ = 0: `P` itself), as [`Filter`] computes it.
pub fn filter(plane: &[f32], width: usize, height: usize, terms: &[(f64, f64)]) -> Vec<f32> {
    let filter = Filter::new(plane, 1, width, height, &[terms.to_vec()]);
    let mut out = vec![0f32; plane.len()];
    out.par_chunks_mut(width * BAND)
        .enumerate()
        .for_each(|(band, rows)| filter.rows(band * BAND, rows));
    out
}

/// The layers of an interleaved `channels`-channel image (1 or 3), layer `c` through its
/// own filter `Σᵢ wᵢ·(G(σᵢ) ∗ P)` (σ in pixels, σ = 0 the layer itself), computed a band
/// of rows at a time ([`Filter::rows`]) into an interleaved image of as many channels as
/// filters (a grey image feeds every layer). Values are read as light (NaN and negative:
/// 0; above 10³⁰: 10³⁰) and the result is held at zero from below. Edges repeat the
/// border pixel.
///
/// A term whose σ is below about 1.9 px (level 0, see `level`) is a sampled separable
/// kernel of radius ⌈3σ⌉ at full resolution. A wider term is computed on the plane
/// decimated by `F = 2^L` (means of 2 × 2 blocks, `L` times: the mean of `F × F`
/// blocks, variance `(F² − 1)/12` px² per axis) and blurred there by a sampled Gaussian
/// of `r` decimated pixels; the levels are summed from the top down, each upsampled by 2
/// (bilinear: a triangle of variance `4ᵏ/6` px² from level `k`) into the one below, and
/// level 1 is upsampled into the full-resolution band. `r` makes the variances add to
/// σ² (`level_variance`) and is at least [`COARSE_MIN_SIGMA`] ([`LEVEL_ONE_MIN_SIGMA`] at
/// level 1). Setting up reads the image
/// once per layer that has wide terms (half-resolution and smaller planes stay); a band
/// reads its rows and the kernels' reach around them. The error against the direct sum
/// of sampled Gaussians ([`filter_direct`]) is measured by `cargo bench --bench
/// film_speed` as the PSNR of the rendering (see `docs/film.md`).
pub struct Filter<'a> {
    sources: Vec<Source<'a>>,
    plans: Vec<Plan>,
}

thread_local! {
    static SCRATCH: std::cell::RefCell<Scratch> = std::cell::RefCell::default();
}

impl<'a> Filter<'a> {
    /// Prepares `terms[c]` for layer `c` of `pixels` (`channels` interleaved, `width ×
    /// height`); the wide terms are computed here, in parallel.
    pub fn new(
        pixels: &'a [f32],
        channels: usize,
        width: usize,
        height: usize,
        terms: &[Vec<(f64, f64)>],
    ) -> Filter<'a> {
        let sources: Vec<Source<'a>> = (0..terms.len())
            .map(|c| Source {
                pixels,
                channels,
                channel: if channels == 1 { 0 } else { c },
                width,
                height,
            })
            .collect();
        let plans = sources
            .par_iter()
            .zip(terms)
            .map(|(s, t)| Plan::new(s, t))
            .collect();
        Filter { sources, plans }
    }

    /// Filtered rows `first ..` into `out` (whole interleaved rows, as many channels as
    /// filters).
    pub fn rows(&self, first: usize, out: &mut [f32]) {
        let layers = self.plans.len();
        let width = self.sources[0].width;
        let rows = out.len() / (width * layers);
        SCRATCH.with_borrow_mut(|scratch| {
            for (c, (plan, source)) in self.plans.iter().zip(&self.sources).enumerate() {
                let mut acc = std::mem::take(&mut scratch.acc);
                acc.resize(rows * width, 0.0);
                plan.band(source, first, &mut acc, scratch);
                for (o, v) in out.chunks_exact_mut(layers).zip(&acc) {
                    o[c] = v.max(0.0);
                }
                scratch.acc = acc;
            }
        });
    }
}

/// The direct computation [`filter`] approximates: `Σᵢ wᵢ·(Gᵢ ∗ P)` with every Gaussian
/// a sampled separable kernel of radius ⌈4σ⌉ at full resolution (edges repeat the
/// border pixel). Slow for wide terms; the reference for measuring [`filter`].
pub fn filter_direct(plane: &[f32], width: usize, height: usize, terms: &[(f64, f64)]) -> Vec<f32> {
    let mut acc = vec![0f32; plane.len()];
    for &(s, w) in terms {
        let blurred;
        let b = if s < 1e-3 {
            plane
        } else {
            let k = kernel(s, 4.0);
            blurred = fir_columns(&fir_rows(plane, width, &k), width, height, &k);
            &blurred
        };
        acc.par_iter_mut()
            .zip(b.par_iter())
            .for_each(|(a, b)| *a += w as f32 * b);
    }
    acc
}

/// The first level of the pyramid: means of 2 × 2 blocks of the source (an odd last
/// row or column averages what it has).
fn halve_source(source: &Source<'_>) -> (usize, usize, Vec<f32>) {
    let (width, height) = (source.width, source.height);
    let (lw, lh) = (width.div_ceil(2), height.div_ceil(2));
    let mut low = vec![0f32; lw * lh];
    low.par_chunks_mut(lw).enumerate().for_each_init(
        || (vec![0f32; width], vec![0f32; width]),
        |(a, b), (j, out)| {
            source.row(2 * j as isize, a);
            let n = if 2 * j + 1 < height { 2 } else { 1 };
            if n == 2 {
                source.row(2 * j as isize + 1, b);
                for (x, y) in a.iter_mut().zip(b.iter()) {
                    *x += y;
                }
            }
            for (o, pair) in out.iter_mut().zip(a.chunks(2)) {
                *o = pair.iter().sum::<f32>() / (pair.len() * n) as f32;
            }
        },
    );
    (lw, lh, low)
}

/// The next level of the pyramid: means of 2 × 2 blocks of a plane.
fn halve(plane: &[f32], width: usize, height: usize) -> (usize, usize, Vec<f32>) {
    let source = Source {
        pixels: plane,
        channels: 1,
        channel: 0,
        width,
        height,
    };
    halve_source(&source)
}

/// One row through a symmetric kernel, edges repeating the border pixel.
fn row_fir(row: &[f32], kernel: &[f32], padded: &mut Vec<f32>, out: &mut [f32]) {
    let r = kernel.len() / 2;
    let width = row.len();
    padded.clear();
    padded.extend(std::iter::repeat_n(row[0], r));
    padded.extend_from_slice(row);
    padded.extend(std::iter::repeat_n(row[width - 1], r));
    out.fill(0.0);
    for (j, &k) in kernel.iter().enumerate() {
        for (v, &a) in out.iter_mut().zip(&padded[j..j + width]) {
            *v += k * a;
        }
    }
}

fn fir_rows(plane: &[f32], width: usize, kernel: &[f32]) -> Vec<f32> {
    let mut out = vec![0f32; plane.len()];
    out.par_chunks_mut(width)
        .zip(plane.par_chunks(width))
        .for_each_init(Vec::new, |padded, (o, row)| row_fir(row, kernel, padded, o));
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A plane with hard edges, a bright spot and fine detail, values 0.05..=50.
    fn scene(width: usize, height: usize) -> Vec<f32> {
        (0..width * height)
            .map(|i| {
                let (x, y) = (i % width, i / width);
                let edge = if x * 3 + y > width * 2 { 1.0 } else { 0.1 };
                let spot = if x.abs_diff(width / 3) < 3 && y.abs_diff(height / 2) < 3 {
                    50.0
                } else {
                    0.0
                };
                let detail = if (x / 2 + y / 3) % 2 == 0 { 0.05 } else { 0.0 };
                edge + spot + detail
            })
            .collect()
    }

    /// Root-mean-square difference over the peak value, in dB.
    fn psnr(reference: &[f32], other: &[f32]) -> f64 {
        let peak = reference.iter().fold(0f32, |a, &b| a.max(b)) as f64;
        let se: f64 = reference
            .iter()
            .zip(other)
            .map(|(&a, &b)| (f64::from(a) - f64::from(b)).powi(2))
            .sum();
        10.0 * (peak * peak / (se / reference.len() as f64)).log10()
    }

    #[test]
    fn fast_filter_matches_the_direct_sum_of_gaussians() {
        let (w, h) = (301, 203);
        let plane = scene(w, h);
        let wide = [(0.0, 0.5), (3.0, 0.3), (9.0, 0.5), (24.0, -0.3)];
        let narrow = [(0.25, 0.3), (0.5, 0.2), (1.0, 0.5)];
        // A bright spot through one wide Gaussian alone is the hardest case: the
        // decimated grid shows in the halo's peak (about 7 % of it, 45 dB of the spot).
        for (terms, floor) in [
            (&wide[..], 70.0),
            (&narrow[..], 100.0),
            (&[(16.7, 1.0)][..], 42.0),
        ] {
            let fast = filter(&plane, w, h, terms);
            let direct: Vec<f32> = filter_direct(&plane, w, h, terms)
                .into_iter()
                .map(|v| v.max(0.0))
                .collect();
            let db = psnr(&direct, &fast);
            println!("{terms:?}: {db:.1} dB");
            assert!(db > floor, "{terms:?}: {db:.1} dB");
        }
        // Only full-resolution kernels: the same sums as the direct computation's, up to
        // the ⌈3σ⌉ against ⌈4σ⌉ truncation.
        let fast = filter(&plane, w, h, &narrow);
        let direct = filter_direct(&plane, w, h, &narrow);
        assert!(psnr(&direct, &fast) > 80.0);
    }

    #[test]
    fn a_uniform_plane_keeps_its_value_and_composition_adds_variances() {
        let (w, h) = (64, 48);
        let plane = vec![2.5f32; w * h];
        for v in filter(&plane, w, h, &[(0.0, 0.4), (5.0, 0.9), (20.0, -0.3)]) {
            assert!((v - 2.5).abs() < 1e-4, "{v}");
        }
        let both = compose(&[(0.0, 0.5), (3.0, 0.5)], &[(4.0, 1.0)]);
        assert_eq!(both, vec![(4.0, 0.5), (5.0, 0.5)]);
    }
}
