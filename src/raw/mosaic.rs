//! Merging a bracket of raw mosaics in CFA space, with the weight that minimises the
//! noise of a linear sensor.
//!
//! # The estimate
//!
//! Frame `k` has relative exposure `e_k` and ratio `r_k = e_k / e_ref` to the longest
//! frame. Its normalised signal `s_k = (code − b)/(w − b)` estimates `x_k = s_k / r_k`,
//! the radiance in units of the longest frame's clipping point (so a sample just below
//! clipping in the longest frame reads 1.0). A sensor's noise in `s` is shot noise plus
//! read noise, `Var s = a·s̄ + σ²` (`a` the inverse full well in electrons, `σ` the read
//! noise, both in units of `w − b`), so
//!
//! ```text
//! Var x_k = (a·E·r_k + σ²) / r_k²,     w_k = 1 / Var x_k,     E = Σ w_k x_k / Σ w_k
//! ```
//!
//! over the frames whose sample is not clipped (clipped: `s_k ≥` [`CLIPPED`]),
//! channel by channel as the CFA lays them out. `E` in the variance is not known before
//! the merge: a first pass takes `E₀ = Σ s_k / Σ r_k` over the unclipped frames (the
//! estimate under shot noise alone), the second pass weighs with `E₀` (Granados et al.,
//! "Optimal HDR reconstruction with linear digital cameras", CVPR 2010). Weighing with
//! each frame's own noisy `s_k` instead would bias the result low.
//!
//! A sample clipped in every frame takes the darkest frame's `x₀` (a lower bound) and is
//! counted in [`MergedMosaic::clipped`].

use rayon::prelude::*;

use super::CLIPPED;

/// A sensor's noise in normalised signal units: `Var s = shot · s + read²`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Noise {
    /// Shot-noise factor `a`: the inverse of the electrons at the clipping point.
    pub shot: f64,
    /// Read-noise standard deviation `σ`, as a fraction of `w − b`.
    pub read: f64,
}

impl Noise {
    /// The noise assumed when nothing better is known: a full well of
    /// `40 000 · 100/ISO` electrons at the clipping point and 3 codes of read noise, for a
    /// sensor with `white − black` codes of range. Only the ratio of the two terms shapes
    /// the weights, and the merge's error depends on it weakly (see `tests/raw.rs`).
    pub fn typical(iso: Option<f64>, range_codes: f64) -> Noise {
        let iso = iso.filter(|i| i.is_finite() && *i > 0.0).unwrap_or(100.0);
        Noise {
            shot: iso / 100.0 / 40_000.0,
            read: 3.0 / range_codes.max(1.0),
        }
    }
}

/// One frame of a bracket in normalised signal `s`, as [`merge`] reads it.
pub trait Signal: Sync {
    /// `s` of every sample of row `y` into `out` (one value per pixel of the row).
    fn row(&self, y: usize, out: &mut [f32]);
    /// The signal at and above which a sample is clipped.
    fn clip(&self) -> f32;
}

/// Raw codes with their levels.
pub struct Codes<'a> {
    /// Codes, row by row.
    pub codes: &'a [u16],
    /// Width of a row.
    pub width: usize,
    /// Black level per position of its tile (`black_width × black_height`).
    pub black: &'a [f32],
    /// Width of the black-level tile.
    pub black_width: usize,
    /// Height of the black-level tile.
    pub black_height: usize,
    /// White level.
    pub white: f32,
}

impl Signal for Codes<'_> {
    fn row(&self, y: usize, out: &mut [f32]) {
        let codes = &self.codes[y * self.width..(y + 1) * self.width];
        let tile = (y % self.black_height) * self.black_width;
        let black = &self.black[tile..tile + self.black_width];
        let scale: Vec<f32> = black.iter().map(|&b| 1.0 / (self.white - b)).collect();
        for (o, c) in out
            .chunks_mut(self.black_width)
            .zip(codes.chunks(self.black_width))
        {
            for (((o, &c), &b), &k) in o.iter_mut().zip(c).zip(black).zip(&scale) {
                *o = (f32::from(c) - b) * k;
            }
        }
    }

    fn clip(&self) -> f32 {
        CLIPPED
    }
}

/// A frame already in normalised signal, row by row (the float reference of the tests):
/// `s ≥ 1` is clipped.
pub struct Linear<'a> {
    /// The signal, row by row.
    pub signal: &'a [f32],
    /// Width of a row.
    pub width: usize,
}

impl Signal for Linear<'_> {
    fn row(&self, y: usize, out: &mut [f32]) {
        out.copy_from_slice(&self.signal[y * self.width..(y + 1) * self.width]);
    }

    fn clip(&self) -> f32 {
        1.0
    }
}

/// A merged mosaic: one radiance value per pixel, of the colour the CFA puts there.
#[derive(Debug, Clone, PartialEq)]
pub struct MergedMosaic {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Radiance in units of the longest frame's clipping point, row by row.
    pub values: Vec<f32>,
    /// Samples clipped in every frame (their value is a lower bound).
    pub clipped: u64,
}

/// A mosaic that can be read row by row: a merged mosaic held in memory, or a bracket
/// merged on demand ([`Merge`]), so that the demosaicking pulls the rows it needs
/// without a full-size merged buffer.
pub trait MosaicRows: Sync {
    /// Width in pixels.
    fn width(&self) -> usize;
    /// Height in pixels.
    fn height(&self) -> usize;
    /// Row `y` into `out` (`width` values, radiance in units of the longest frame's
    /// clipping point); returns the samples of the row clipped in every frame. `scratch`
    /// is working memory the caller keeps between calls.
    fn row(&self, y: usize, out: &mut [f32], scratch: &mut Vec<f32>) -> u64;
}

impl MosaicRows for MergedMosaic {
    fn width(&self) -> usize {
        self.width
    }

    fn height(&self) -> usize {
        self.height
    }

    fn row(&self, y: usize, out: &mut [f32], _scratch: &mut Vec<f32>) -> u64 {
        out.copy_from_slice(&self.values[y * self.width..(y + 1) * self.width]);
        0
    }
}

/// A bracket of frames merged row by row on demand (see the module docs for the
/// estimate).
pub struct Merge<'a> {
    /// Darkest first: `(signal, r, a, σ²)`.
    frames: Vec<(&'a dyn Signal, f32, f32, f32)>,
    width: usize,
    height: usize,
}

impl<'a> Merge<'a> {
    /// The merge of `frames` (each with its relative exposure and noise, any order) of
    /// one `width × height` mosaic.
    pub fn new(frames: &[(&'a dyn Signal, f64, Noise)], width: usize, height: usize) -> Merge<'a> {
        let mut order: Vec<usize> = (0..frames.len()).collect();
        order.sort_by(|&a, &b| frames[a].1.total_cmp(&frames[b].1));
        let e_ref = order.last().map_or(1.0, |&k| frames[k].1);
        let frames = order
            .iter()
            .map(|&k| {
                let (signal, e, noise) = frames[k];
                let r = (e / e_ref) as f32;
                (
                    signal,
                    r,
                    noise.shot as f32,
                    (noise.read * noise.read) as f32,
                )
            })
            .collect();
        Merge {
            frames,
            width,
            height,
        }
    }
}

impl MosaicRows for Merge<'_> {
    fn width(&self) -> usize {
        self.width
    }

    fn height(&self) -> usize {
        self.height
    }

    fn row(&self, y: usize, out: &mut [f32], scratch: &mut Vec<f32>) -> u64 {
        let width = self.width;
        scratch.resize(width * self.frames.len(), 0.0);
        for (row, &(signal, ..)) in scratch.chunks_exact_mut(width.max(1)).zip(&self.frames) {
            signal.row(y, row);
        }
        merge_row(&self.frames, scratch, width, out)
    }
}

/// Merges `frames` (each with its relative exposure and noise, any order) of one
/// `width × height` mosaic into memory; see the module docs for the estimate.
pub fn merge(frames: &[(&dyn Signal, f64, Noise)], width: usize, height: usize) -> MergedMosaic {
    let merge = Merge::new(frames, width, height);
    let mut values = vec![0.0f32; width * height];
    let clipped: u64 = values
        .par_chunks_mut(width.max(1))
        .enumerate()
        .map_init(Vec::new, |scratch, (y, out)| merge.row(y, out, scratch))
        .sum();
    MergedMosaic {
        width,
        height,
        values,
        clipped,
    }
}

/// One row of the merge (see the module docs); returns the samples clipped in every
/// frame. `frames` are darkest first: `(signal, r, a, σ²)`.
/// `rows` holds each frame's row of `width` signals, in the order of `frames`.
fn merge_row(
    frames: &[(&dyn Signal, f32, f32, f32)],
    rows: &[f32],
    width: usize,
    out: &mut [f32],
) -> u64 {
    let rows: Vec<&[f32]> = rows.chunks_exact(width.max(1)).collect();
    let clips: Vec<f32> = frames.iter().map(|f| f.0.clip()).collect();
    let inverse: Vec<f32> = frames.iter().map(|f| 1.0 / f.1).collect();
    let mut clipped = 0;
    for (x, out) in out.iter_mut().enumerate() {
        let (mut sum_s, mut sum_r) = (0.0f32, 0.0f32);
        for ((row, f), &clip) in rows.iter().zip(frames).zip(&clips) {
            let s = row[x];
            if s < clip {
                sum_s += s;
                sum_r += f.1;
            }
        }
        if sum_r == 0.0 {
            clipped += 1;
            *out = rows[0][x] * inverse[0];
            continue;
        }
        let e0 = (sum_s / sum_r).max(0.0);
        let (mut num, mut den) = (0.0f32, 0.0f32);
        for (((row, &(_, r, shot, read2)), &clip), &inv) in
            rows.iter().zip(frames).zip(&clips).zip(&inverse)
        {
            let s = row[x];
            if s < clip {
                // w = 1/Var x = r² / (a·E₀·r + σ²)
                let w = r * r / (shot * e0 * r + read2).max(f32::MIN_POSITIVE);
                num += w * s * inv;
                den += w;
            }
        }
        *out = num / den;
    }
    clipped
}
