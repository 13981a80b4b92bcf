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

use std::borrow::Cow;

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

use super::stock::Mtf;

/// Spreads of the Gaussians the MTF is fitted with, µm at film scale.
const SPREADS_UM: [f64; 7] = [1.5, 3.0, 6.0, 12.0, 24.0, 48.0, 96.0];

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
        // Normal equations `(BᵀW²B + 10⁻⁴·I) w = BᵀW²m`, symmetric positive definite.
        let mut normal = DMatrix::<f64>::identity(n, n) * 1e-4;
        let mut rhs = DVector::<f64>::zeros(n);
        for (b, m, weight) in &rows {
            let b = DVector::from_column_slice(b);
            let w2 = weight * weight;
            normal += &b * b.transpose() * w2;
            rhs += &b * (w2 * m);
        }
        let w = normal
            .clone()
            .cholesky()
            .map(|c| c.solve(&rhs))
            .or_else(|| normal.lu().solve(&rhs))
            // Only a non-finite sheet (refused when the stock is read) gets here.
            .unwrap_or_else(|| DVector::from_element(n, f64::NAN));
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
pub(crate) fn compose(first: &[(f64, f64)], then: &[(f64, f64)]) -> Vec<(f64, f64)> {
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
pub(crate) const BAND: usize = 16;

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

/// The largest mass of a full-resolution kernel's outer taps that is dropped, both sides
/// together: a kernel loses its outermost pairs of taps while their summed mass stays
/// within this, and is renormalised.
const TRIM: f32 = 1e-3;

/// A sampled kernel without its outermost pairs of taps while their mass (both sides,
/// summed from the outside in) is at most [`TRIM`], renormalised: a term of σ = 0.25 px
/// (1.5 µm at 6 µm pixels, outer taps 3.4·10⁻⁴ each) becomes the identity, one of
/// σ = 0.5 px loses its taps at ±2 (2.6·10⁻⁴ each). The filtered value moves by at most
/// `|w|·2·TRIM` of the local light (both axes), 0.05 % for a weight of 0.25.
fn trimmed(mut k: Vec<f32>) -> Vec<f32> {
    let mut dropped = 0.0;
    while k.len() > 1 {
        let outer = k[0] + k[k.len() - 1];
        if dropped + outer > TRIM {
            break;
        }
        dropped += outer;
        k.pop();
        k.remove(0);
    }
    let total: f32 = k.iter().sum();
    k.iter().map(|v| v / total).collect()
}

/// A sample read as light: NaN and values ≤ 0 are 0, values above 10³⁰ (and +∞) 10³⁰.
#[inline]
fn light(v: f32) -> f32 {
    // `max` takes the number of a NaN pair, so NaN is 0 (`clamp` would keep the NaN).
    let lit = v.max(0.0);
    lit.min(1e30)
}

/// A plane and its size; rows outside it read as the nearest border row.
#[derive(Debug)]
struct Plane {
    width: usize,
    height: usize,
    values: Vec<f32>,
}

impl Plane {
    fn row(&self, y: isize) -> &[f32] {
        let y = y.clamp(0, self.height as isize - 1) as usize;
        &self.values[y * self.width..(y + 1) * self.width]
    }
}

/// Samples per block of the separable passes: a block's sums stay in registers while the
/// taps run over it, so each input row is read once per block and the output written
/// once (8 SSE vectors; the fixed length lets the compiler vectorise the taps' loops).
const BLOCK: usize = 32;

/// Adds `Σₜ wₜ·(kₜ ∗ P)` at one row to `out`, each `kₜ` a symmetric kernel applied down
/// then across (edges repeat the border pixel); `line(d)` is the row `d` rows from the
/// output's, `column` a row of scratch. Each kernel's weight is folded into its down pass,
/// and both passes add the symmetric taps' samples before multiplying:
/// `Σⱼ kⱼ·(v₋ⱼ + v₊ⱼ)`.
fn add_separable<'p>(
    line: impl Fn(isize) -> &'p [f32],
    terms: &[(f32, Vec<f32>)],
    column: &mut Vec<f32>,
    out: &mut [f32],
) {
    let n = out.len();
    column.resize(n, 0.0);
    for (w, k) in terms {
        let r = k.len() / 2;
        let centre = line(0);
        let mut x0 = 0;
        while x0 + BLOCK <= n {
            let mut acc = [0f32; BLOCK];
            let kc = w * k[r];
            for (a, &v) in acc.iter_mut().zip(block(centre, x0)) {
                *a = kc * v;
            }
            for j in 1..=r {
                let kj = w * k[r + j];
                let (above, below) = (block(line(-(j as isize)), x0), block(line(j as isize), x0));
                for ((a, &u), &v) in acc.iter_mut().zip(above).zip(below) {
                    *a += kj * (u + v);
                }
            }
            column[x0..x0 + BLOCK].copy_from_slice(&acc);
            x0 += BLOCK;
        }
        for x in x0..n {
            let mut a = w * k[r] * centre[x];
            for j in 1..=r {
                a += w * k[r + j] * (line(-(j as isize))[x] + line(j as isize)[x]);
            }
            column[x] = a;
        }
        add_across(column, k, out);
    }
}

/// The [`BLOCK`] samples of `row` from `x`.
#[inline]
fn block(row: &[f32], x: usize) -> &[f32; BLOCK] {
    row[x..x + BLOCK].try_into().expect("a whole block")
}

/// Adds `row` through the symmetric kernel `k` across to `out`, edges repeating the
/// border pixel: the interior a block at a time (taps folded as in [`add_separable`]),
/// the `r` pixels at each end clamped.
fn add_across(row: &[f32], k: &[f32], out: &mut [f32]) {
    let n = row.len();
    let r = k.len() / 2;
    let edge = |x: usize| -> f32 {
        k.iter()
            .enumerate()
            .map(|(j, &kj)| kj * row[(x + j).saturating_sub(r).min(n - 1)])
            .sum()
    };
    if n <= 2 * r {
        for (x, o) in out.iter_mut().enumerate() {
            *o += edge(x);
        }
        return;
    }
    let end = n - r;
    let mut x0 = r;
    while x0 + BLOCK <= end {
        let mut acc = [0f32; BLOCK];
        for (a, &v) in acc.iter_mut().zip(block(row, x0)) {
            *a = k[r] * v;
        }
        for j in 1..=r {
            let kj = k[r + j];
            for ((a, &u), &v) in acc
                .iter_mut()
                .zip(block(row, x0 - j))
                .zip(block(row, x0 + j))
            {
                *a += kj * (u + v);
            }
        }
        for (o, a) in out[x0..x0 + BLOCK].iter_mut().zip(acc) {
            *o += a;
        }
        x0 += BLOCK;
    }
    for x in x0..end {
        let mut a = k[r] * row[x];
        for j in 1..=r {
            a += k[r + j] * (row[x - j] + row[x + j]);
        }
        out[x] += a;
    }
    for x in (0..r).chain(end..n) {
        out[x] += edge(x);
    }
}

/// One layer's filter, prepared: the identity's weight, the full-resolution kernels and
/// the wide terms summed on the half-resolution plane.
struct Plan {
    identity: f32,
    fine: Vec<(f32, Vec<f32>)>,
    /// The half-resolution sum of the wide terms.
    coarse: Option<Plane>,
}

impl Plan {
    /// `level_one` is the layer's plane of 2 × 2 means, given when a term is wide.
    fn new(level_one: Option<Plane>, terms: &[(f64, f64)]) -> Plan {
        let mut plan = Plan {
            identity: 0.0,
            fine: Vec::new(),
            coarse: None,
        };
        // Per level: the kernels blurred there.
        let mut wide: Vec<Vec<(f32, Vec<f32>)>> = Vec::new();
        for &(s, w) in terms {
            if s < 1e-3 {
                plan.identity += w as f32;
                continue;
            }
            let l = level(s) as usize;
            if l == 0 {
                let k = trimmed(kernel(s, 3.0));
                if k.len() == 1 {
                    plan.identity += w as f32;
                } else {
                    plan.fine.push((w as f32, k));
                }
                continue;
            }
            if wide.len() < l {
                wide.resize_with(l, Vec::new);
            }
            let f2 = 4f64.powi(l as i32);
            let r = ((s * s - level_variance(l as u32)) / f2).max(0.0).sqrt();
            wide[l - 1].push((w as f32, kernel(r, 3.0)));
        }
        let Some(level_one) = level_one.filter(|_| !wide.is_empty()) else {
            return plan;
        };
        let mut pyramid = vec![level_one];
        while pyramid.len() < wide.len() {
            let next = halve(pyramid.last().expect("level one"));
            pyramid.push(next);
        }
        // Each level's terms in one pass of rows, over the level itself (a level without
        // terms becomes zero), then the levels collapsed from the top down, each upsampled
        // by 2 into the one below, down to level 1: no plane beyond the pyramid's.
        for (plane, terms) in pyramid.iter_mut().zip(&wide) {
            if terms.is_empty() {
                plane.values.fill(0.0);
            } else {
                blur_in_place(plane, terms);
            }
        }
        while pyramid.len() > 1 {
            let upper = pyramid.pop().expect("two levels");
            let lower = pyramid.last_mut().expect("one level");
            lower
                .values
                .par_chunks_mut(lower.width)
                .enumerate()
                .for_each_init(
                    || vec![0f32; upper.width],
                    |mixed, (y, row)| {
                        mix_rows(&upper, y, mixed);
                        upsample_row_add(mixed, row);
                    },
                );
        }
        plan.coarse = pyramid.pop();
        plan
    }

    /// Reach of the full-resolution kernels, rows.
    fn reach(&self) -> usize {
        self.fine
            .iter()
            .map(|(_, k)| k.len() / 2)
            .max()
            .unwrap_or(0)
    }

    /// Rows `y0 .. y0 + acc.len()/width` of the filtered layer into `acc`; `lines`
    /// holds the layer's rows from `y0 − reach` (clamped to the image), `reach` rows
    /// beyond the band on each side.
    fn band(
        &self,
        lines: &[f32],
        width: usize,
        reach: usize,
        y0: usize,
        acc: &mut [f32],
        scratch: &mut Rows,
    ) {
        for (i, a) in acc.chunks_exact_mut(width).enumerate() {
            let centre = reach + i;
            for (a, &p) in a
                .iter_mut()
                .zip(&lines[centre * width..(centre + 1) * width])
            {
                *a = self.identity * p;
            }
            let line = |d: isize| {
                let l = (centre as isize + d) as usize;
                &lines[l * width..(l + 1) * width]
            };
            add_separable(line, &self.fine, &mut scratch.column, a);
            if let Some(plane) = &self.coarse {
                scratch.low_row.resize(plane.width, 0.0);
                mix_rows(plane, y0 + i, &mut scratch.low_row);
                upsample_row_add(&scratch.low_row, a);
            }
        }
    }
}

/// The sum `Σₜ wₜ·(kₜ ∗ P)` of a plane's terms (each applied down then across, edges
/// repeating the border row), written over the plane: no second plane is allocated
/// (each would be fresh memory, page-faulted in at every rendering). The rows are split
/// into a few chunks per thread; before any is written, the `r` rows (the kernels'
/// reach) beyond each end of each chunk are copied; a chunk then runs down its rows,
/// keeping each original row in a ring of `r + 1` rows before overwriting it, so that
/// an output row reads the originals of the rows above from the ring, of the rows below
/// from the chunk itself or the copy beyond its end.
fn blur_in_place(plane: &mut Plane, terms: &[(f32, Vec<f32>)]) {
    let width = plane.width;
    let r = terms.iter().map(|(_, k)| k.len() / 2).max().unwrap_or(0);
    let rows = plane
        .height
        .div_ceil(4 * rayon::current_num_threads())
        .max(r)
        .max(1);
    let chunks = plane.height.div_ceil(rows);
    let source = &*plane;
    let beyond: Vec<(Vec<f32>, Vec<f32>)> = (0..chunks)
        .into_par_iter()
        .map(|i| {
            let (top, end) = ((i * rows) as isize, ((i + 1) * rows) as isize);
            let above: Vec<f32> = (1..=r as isize)
                .flat_map(|d| source.row(top - d))
                .copied()
                .collect();
            let below: Vec<f32> = (0..r as isize)
                .flat_map(|d| source.row(end + d))
                .copied()
                .collect();
            (above, below)
        })
        .collect();
    // Row `i` of a chunk (from −r) is kept in slot `i mod (r + 1)` of the ring; `slot`
    // reduces a value within −r..=r, a slot's offset from the current row's.
    let ring_rows = r as isize + 1;
    let slot = |i: isize| (if i < 0 { i + ring_rows } else { i }) as usize;
    plane
        .values
        .par_chunks_mut(rows * width)
        .zip(beyond)
        .for_each_init(
            || (vec![0f32; (r + 1) * width], Vec::new()),
            |(ring, column), (chunk, (above, below))| {
                let n = chunk.len() / width;
                for d in 1..=r {
                    let s = slot(-(d as isize));
                    ring[s * width..(s + 1) * width]
                        .copy_from_slice(&above[(d - 1) * width..d * width]);
                }
                // `now` is row `i`'s slot, advanced without a division.
                let mut now = 0;
                for i in 0..n {
                    let s = now;
                    now = if now == r { 0 } else { now + 1 };
                    ring[s * width..(s + 1) * width]
                        .copy_from_slice(&chunk[i * width..(i + 1) * width]);
                    let (head, tail) = chunk.split_at_mut((i + 1) * width);
                    let out = &mut head[i * width..];
                    out.fill(0.0);
                    let (ring, tail, below) = (&*ring, &*tail, &below);
                    let line = |d: isize| -> &[f32] {
                        if d <= 0 {
                            let s = slot(s as isize + d);
                            &ring[s * width..(s + 1) * width]
                        } else if i + (d as usize) < n {
                            let t = (d as usize - 1) * width;
                            &tail[t..t + width]
                        } else {
                            let b = i + d as usize - n;
                            &below[b * width..(b + 1) * width]
                        }
                    };
                    add_separable(line, terms, column, out);
                }
            },
        );
}

/// Row `y` of a plane upsampled by 2 vertically (bilinear, sample `j` centred on row
/// `2j + ½`): `¼·row(j−1) + ¾·row(j)` for even `y = 2j`, `¾·row(j) + ¼·row(j+1)` for odd,
/// rows clamped to the plane.
fn mix_rows(plane: &Plane, y: usize, out: &mut [f32]) {
    let j = (y / 2) as isize;
    let other = if y.is_multiple_of(2) { j - 1 } else { j + 1 };
    for ((o, &p), &q) in out.iter_mut().zip(plane.row(other)).zip(plane.row(j)) {
        *o = 0.25 * p + 0.75 * q;
    }
}

/// Adds a row upsampled by 2 (bilinear, as [`mix_rows`] across) to `out`, whose length is
/// `2·low.len()` or one less.
fn upsample_row_add(low: &[f32], out: &mut [f32]) {
    let n = low.len();
    let at = |i: usize| low[i.min(n - 1)];
    let edge = |i: usize, pair: &mut [f32]| {
        let centre = 0.75 * low[i];
        pair[0] += centre + 0.25 * low[i.saturating_sub(1)];
        if let Some(odd) = pair.get_mut(1) {
            *odd += centre + 0.25 * at(i + 1);
        }
    };
    if n < 3 {
        for (i, pair) in out.chunks_mut(2).enumerate() {
            edge(i, pair);
        }
        return;
    }
    // The interior (i = 1 .. n − 2) without clamping, then the two ends.
    for (pair, w) in out[2..2 * n - 2].chunks_exact_mut(2).zip(low.windows(3)) {
        let centre = 0.75 * w[1];
        pair[0] += centre + 0.25 * w[0];
        pair[1] += centre + 0.25 * w[2];
    }
    edge(0, &mut out[0..2]);
    edge(n - 1, &mut out[2 * n - 2..]);
}

/// Per-thread buffers of the band pass.
#[derive(Default)]
struct Rows {
    /// Per layer, the band's rows and the kernels' reach around them, as light.
    lines: Vec<Vec<f32>>,
    column: Vec<f32>,
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
/// kernel of radius ⌈3σ⌉ at full resolution, applied down then across, one output row at
/// a time. A wider term is computed on the plane
/// decimated by `F = 2^L` (means of 2 × 2 blocks, `L` times: the mean of `F × F`
/// blocks, variance `(F² − 1)/12` px² per axis) and blurred there by a sampled Gaussian
/// of `r` decimated pixels; the levels are summed from the top down, each upsampled by 2
/// (bilinear: a triangle of variance `4ᵏ/6` px² from level `k`) into the one below, and
/// level 1 is upsampled into the full-resolution band. `r` makes the variances add to
/// σ² (`level_variance`) and is at least [`COARSE_MIN_SIGMA`] ([`LEVEL_ONE_MIN_SIGMA`] at
/// level 1). Setting up reads the image once (all layers' half-resolution planes in one
/// pass; they and the smaller planes stay); a band reads its rows and the kernels' reach
/// around them, once for all layers. The error against the direct sum
/// of sampled Gaussians ([`filter_direct`]) is measured by `cargo bench --bench
/// film_speed` as the PSNR of the rendering (see `docs/film.md`).
pub struct Filter<'a> {
    pixels: Cow<'a, [f32]>,
    channels: usize,
    width: usize,
    height: usize,
    plans: Vec<Plan>,
    /// The widest full-resolution kernel's reach, rows.
    reach: usize,
}

thread_local! {
    static SCRATCH: std::cell::RefCell<Rows> = std::cell::RefCell::default();
}

impl<'a> Filter<'a> {
    /// Prepares `terms[c]` for layer `c` of `pixels` (`channels` interleaved, `width ×
    /// height`, borrowed or owned); the wide terms are computed here, in parallel.
    pub fn new(
        pixels: impl Into<Cow<'a, [f32]>>,
        channels: usize,
        width: usize,
        height: usize,
        terms: &[Vec<(f64, f64)>],
    ) -> Filter<'a> {
        let pixels = pixels.into();
        let wide = terms
            .iter()
            .flatten()
            .any(|&(s, _)| s >= 1e-3 && level(s) > 0);
        let level_one: Vec<Option<Plane>> = if wide {
            halve_layers(&pixels, channels, width, height, terms.len())
                .into_iter()
                .map(Some)
                .collect()
        } else {
            terms.iter().map(|_| None).collect()
        };
        let plans: Vec<Plan> = level_one
            .into_par_iter()
            .zip(terms)
            .map(|(l, t)| Plan::new(l, t))
            .collect();
        let reach = plans.iter().map(Plan::reach).max().unwrap_or(0);
        Filter {
            pixels,
            channels,
            width,
            height,
            plans,
            reach,
        }
    }

    /// Filtered rows `first ..` into `out` (whole interleaved rows, as many channels as
    /// filters).
    pub fn rows(&self, first: usize, out: &mut [f32]) {
        let layers = self.plans.len();
        let (width, channels, reach) = (self.width, self.channels, self.reach);
        let rows = out.len() / (width * layers);
        let count = rows + 2 * reach;
        let planes = if channels == 1 { 1 } else { layers };
        SCRATCH.with_borrow_mut(|scratch| {
            scratch.lines.resize_with(planes, Vec::new);
            for line in &mut scratch.lines {
                line.resize(count * width, 0.0);
            }
            for i in 0..count {
                let y = (first as isize + i as isize - reach as isize)
                    .clamp(0, self.height as isize - 1) as usize;
                let source = &self.pixels[y * width * channels..(y + 1) * width * channels];
                let row = i * width..(i + 1) * width;
                if let [r, g, b] = &mut scratch.lines[..]
                    && channels == 3
                {
                    // One pass over the interleaved row for the three layers.
                    for (((r, g), b), p) in r[row.clone()]
                        .iter_mut()
                        .zip(&mut g[row.clone()])
                        .zip(&mut b[row])
                        .zip(source.chunks_exact(3))
                    {
                        *r = light(p[0]);
                        *g = light(p[1]);
                        *b = light(p[2]);
                    }
                    continue;
                }
                for (c, line) in scratch.lines.iter_mut().enumerate() {
                    for (o, p) in line[row.clone()]
                        .iter_mut()
                        .zip(source.chunks_exact(channels))
                    {
                        *o = light(p[c]);
                    }
                }
            }
            let mut acc = std::mem::take(&mut scratch.acc);
            let lines = std::mem::take(&mut scratch.lines);
            acc.resize(rows * width, 0.0);
            for (c, plan) in self.plans.iter().enumerate() {
                let layer = &lines[c.min(planes - 1)];
                plan.band(layer, width, reach, first, &mut acc, scratch);
                for (o, v) in out.chunks_exact_mut(layers).zip(&acc) {
                    o[c] = v.max(0.0);
                }
            }
            scratch.acc = acc;
            scratch.lines = lines;
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

/// The first level of the pyramid of each of `layers` layers of an interleaved image
/// (a grey image feeds every layer): means of 2 × 2 blocks of the samples read as light
/// (an odd last row or column averages what it has), in one pass over the image.
fn halve_layers(
    pixels: &[f32],
    channels: usize,
    width: usize,
    height: usize,
    layers: usize,
) -> Vec<Plane> {
    let (lw, lh) = (width.div_ceil(2), height.div_ceil(2));
    let stride = width * channels;
    // A grey image is halved once and shared by every layer.
    let computed = if channels == 1 { 1 } else { layers };
    let mut planes: Vec<Vec<f32>> = (0..computed).map(|_| vec![0f32; lw * lh]).collect();
    let mut rows: Vec<Vec<&mut [f32]>> = (0..lh).map(|_| Vec::with_capacity(computed)).collect();
    for plane in &mut planes {
        for (row, chunk) in rows.iter_mut().zip(plane.chunks_exact_mut(lw)) {
            row.push(chunk);
        }
    }
    rows.into_par_iter().enumerate().for_each_init(
        || vec![0f32; stride],
        |sum, (j, mut outs)| {
            let top = 2 * j * stride;
            for (s, &v) in sum.iter_mut().zip(&pixels[top..top + stride]) {
                *s = light(v);
            }
            let rows = if 2 * j + 1 < height { 2 } else { 1 };
            if rows == 2 {
                for (s, &v) in sum.iter_mut().zip(&pixels[top + stride..top + 2 * stride]) {
                    *s += light(v);
                }
            }
            for (c, out) in outs.iter_mut().enumerate() {
                for (i, o) in out.iter_mut().enumerate() {
                    let left = 2 * i * channels + c;
                    *o = if 2 * i + 1 < width {
                        (sum[left] + sum[left + channels]) / (2 * rows) as f32
                    } else {
                        sum[left] / rows as f32
                    };
                }
            }
        },
    );
    while planes.len() < layers {
        planes.push(planes[0].clone());
    }
    planes
        .into_iter()
        .map(|values| Plane {
            width: lw,
            height: lh,
            values,
        })
        .collect()
}

/// The next level of the pyramid: means of 2 × 2 blocks of a plane.
fn halve(plane: &Plane) -> Plane {
    let mut planes = halve_layers(&plane.values, 1, plane.width, plane.height, 1);
    planes.pop().expect("one layer")
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
