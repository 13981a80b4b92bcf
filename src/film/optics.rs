//! What happens to the light inside the film before it forms density: the emulsion's
//! modulation transfer function (MTF) and halation. Both act on exposure `H` (linear
//! light), before the characteristic curve, as the data sheets measure the MTF.
//!
//! **MTF.** The sheet's curve `M_c(f)` (response against cycles/mm at film scale, layer
//! `c`) becomes a symmetric FIR kernel at the pixel pitch `p` (mm at film scale):
//!
//! `k[n] = 2 ∫₀^½ M_c(ν / p) · cos(2π ν n) dν` (ν in cycles/pixel),
//!
//! by the midpoint rule on 2048 steps, cut at the radius where the dropped taps sum to
//! under 0.002 in absolute value (at most [`MAX_RADIUS`] pixels), then normalised to
//! `Σ k = 1` so that a uniform area keeps its exposure (`M(0) = 1`). It is applied
//! separably (rows, then columns): the 2-D response is `M(f_x)·M(f_y)`, exact along the
//! axes, `M(f/√2)²` instead of `M(f)` on the diagonals. A sheet's response above 100 %
//! at low frequency (the development's adjacency effects) is kept: edges gain the
//! film's own acutance. Exposure that the kernel's negative lobes take below zero is
//! held at zero (no light).
//!
//! **Halation.** Light that passes the emulsion reflects off the back of the base and
//! re-exposes the layers nearest the base, red most, from a halo of radius about twice
//! the base thickness. Modelled as `H'_r = H_r + s·(G_σ ∗ H_r)`,
//! `H'_g = H_g + (s/4)·(G_σ ∗ H_g)`, blue untouched, with `G_σ` a Gaussian of
//! σ = [`HALATION_SIGMA_MM`] at film scale (three box passes per axis) and `s` the user's
//! strength. Only bright highlights make a visible halo, since `G_σ ∗ H` is a small
//! fraction of a mid-tone but a large one next to the sun. The built-in stocks all have an
//! anti-halation layer, so it is off unless asked for.

use rayon::prelude::*;

use super::stock::Mtf;

/// Largest MTF kernel radius, pixels.
pub const MAX_RADIUS: usize = 40;

/// Halo spread of halation at film scale, mm (a base ≈ 0.12 mm thick).
pub const HALATION_SIGMA_MM: f64 = 0.1;

/// The symmetric FIR kernel of layer `c` of `mtf` at `pitch_mm` per pixel, centre tap at
/// index `radius` (`len = 2·radius + 1`).
pub fn mtf_kernel(mtf: &Mtf, c: usize, pitch_mm: f64) -> Vec<f32> {
    const STEPS: usize = 2048;
    let response: Vec<f64> = (0..STEPS)
        .map(|i| {
            let nu = (i as f64 + 0.5) / STEPS as f64 * 0.5;
            mtf.response(c, nu / pitch_mm)
        })
        .collect();
    let tap = |n: usize| -> f64 {
        let sum: f64 = response
            .iter()
            .enumerate()
            .map(|(i, m)| {
                let nu = (i as f64 + 0.5) / STEPS as f64 * 0.5;
                m * (2.0 * std::f64::consts::PI * nu * n as f64).cos()
            })
            .sum();
        2.0 * sum * 0.5 / STEPS as f64
    };
    let taps: Vec<f64> = (0..=MAX_RADIUS + 64).map(tap).collect();
    // The smallest radius whose dropped taps (both sides) sum to under 0.002.
    let mut radius = MAX_RADIUS;
    for r in 0..MAX_RADIUS {
        let dropped: f64 = 2.0 * taps[r + 1..].iter().map(|t| t.abs()).sum::<f64>();
        if dropped < 0.002 {
            radius = r;
            break;
        }
    }
    let mut kernel: Vec<f64> = (0..=2 * radius).map(|i| taps[i.abs_diff(radius)]).collect();
    let total: f64 = kernel.iter().sum();
    for k in &mut kernel {
        *k /= total;
    }
    kernel.into_iter().map(|k| k as f32).collect()
}

/// Convolves channel `c` of an interleaved `ch`-channel image with `kernel` along rows
/// then columns (edges repeat the border pixel); results below zero are held at zero.
pub fn convolve_separable(
    pixels: &mut [f32],
    width: usize,
    height: usize,
    ch: usize,
    c: usize,
    kernel: &[f32],
) {
    let r = kernel.len() / 2;
    if r == 0 {
        return;
    }
    // Rows.
    pixels.par_chunks_mut(width * ch).for_each(|row| {
        let line: Vec<f32> = row.iter().skip(c).step_by(ch).copied().collect();
        let mut padded = Vec::with_capacity(width + 2 * r);
        padded.extend(std::iter::repeat_n(line[0], r));
        padded.extend_from_slice(&line);
        padded.extend(std::iter::repeat_n(line[width - 1], r));
        for x in 0..width {
            let window = &padded[x..x + 2 * r + 1];
            let v: f32 = window.iter().zip(kernel).map(|(a, k)| a * k).sum();
            row[x * ch + c] = v;
        }
    });
    // Columns: transpose through a plane, convolve its rows, write back.
    let mut plane = vec![0f32; width * height];
    plane
        .par_chunks_mut(height)
        .enumerate()
        .for_each(|(x, col)| {
            for (y, v) in col.iter_mut().enumerate() {
                *v = pixels[(y * width + x) * ch + c];
            }
        });
    let mut out = vec![0f32; width * height];
    out.par_chunks_mut(height)
        .zip(plane.par_chunks(height))
        .for_each(|(o, col)| {
            for (y, v) in o.iter_mut().enumerate() {
                let mut s = 0.0;
                for (i, k) in kernel.iter().enumerate() {
                    let yy = (y + i).saturating_sub(r).min(height - 1);
                    s += col[yy] * k;
                }
                *v = s;
            }
        });
    pixels
        .par_chunks_mut(width * ch)
        .enumerate()
        .for_each(|(y, row)| {
            for x in 0..width {
                row[x * ch + c] = out[x * height + y].max(0.0);
            }
        });
}

/// Adds the halo: channel `c` += `strength · (G_σ ∗ channel c)` with `σ = sigma_px`
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
    let half = (((4.0 * sigma_px * sigma_px + 1.0).sqrt() - 1.0) / 2.0).round() as usize;
    let mut plane: Vec<f32> = pixels.iter().skip(c).step_by(ch).copied().collect();
    for _ in 0..3 {
        box_rows(&mut plane, width, half);
        plane = transpose(&plane, width, height);
        box_rows(&mut plane, height, half);
        plane = transpose(&plane, height, width);
    }
    pixels
        .par_chunks_mut(ch)
        .zip(plane.par_iter())
        .for_each(|(p, g)| {
            if g.is_finite() {
                p[c] += strength * g;
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

fn transpose(plane: &[f32], width: usize, height: usize) -> Vec<f32> {
    let mut out = vec![0f32; plane.len()];
    out.par_chunks_mut(height).enumerate().for_each(|(x, col)| {
        for (y, v) in col.iter_mut().enumerate() {
            *v = plane[y * width + x];
        }
    });
    out
}
