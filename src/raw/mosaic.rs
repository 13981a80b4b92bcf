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
pub(crate) struct Codes<'a> {
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
        // The row's black levels and scales `1/(w − b)` for a run of whole tiles, at
        // least 16 columns, so that the loop over a run is long enough to vectorise.
        let period = self.black_width * 16usize.div_ceil(self.black_width);
        let level: Vec<f32> = black.iter().copied().cycle().take(period).collect();
        let scale: Vec<f32> = level.iter().map(|&b| 1.0 / (self.white - b)).collect();
        for (o, c) in out.chunks_mut(period).zip(codes.chunks(period)) {
            for (((o, &c), &b), &k) in o.iter_mut().zip(c).zip(&level).zip(&scale) {
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

/// Pixels of a row that [`merge_row`] sums over the frames at a time (its sums stay in
/// registers and the first-level cache).
const LANES: usize = 64;

/// One row of the merge (see the module docs); returns the samples clipped in every
/// frame. `frames` are darkest first: `(signal, r, a, σ²)`.
/// `rows` holds each frame's row of `width` signals, in the order of `frames`.
///
/// The row is taken [`LANES`] pixels at a time, each pass a loop over those pixels for one
/// frame, the clipped samples left out by selecting the sum without them, so that the
/// loops vectorise; each pixel's sums still add the frames in the order of `frames`.
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
    for (chunk, out) in out.chunks_mut(LANES).enumerate() {
        let (x0, n) = (chunk * LANES, out.len());
        // First pass: E₀ = Σ s_k / Σ r_k over the unclipped frames.
        let (mut sum_s, mut sum_r) = ([0.0f32; LANES], [0.0f32; LANES]);
        for ((row, f), &clip) in rows.iter().zip(frames).zip(&clips) {
            let r = f.1;
            for ((acc_s, acc_r), &s) in sum_s.iter_mut().zip(&mut sum_r).zip(&row[x0..x0 + n]) {
                let unclipped = s < clip;
                *acc_s = if unclipped { *acc_s + s } else { *acc_s };
                *acc_r = if unclipped { *acc_r + r } else { *acc_r };
            }
        }
        let mut e0 = [0.0f32; LANES];
        for (e, (&s, &r)) in e0.iter_mut().zip(sum_s.iter().zip(&sum_r)) {
            *e = (s / r).max(0.0);
        }
        // Second pass: Σ w_k x_k and Σ w_k with w = 1/Var x = r² / (a·E₀·r + σ²).
        let (mut num, mut den) = ([0.0f32; LANES], [0.0f32; LANES]);
        for (((row, &(_, r, shot, read2)), &clip), &inv) in
            rows.iter().zip(frames).zip(&clips).zip(&inverse)
        {
            let samples = &row[x0..x0 + n];
            for (((acc_n, acc_d), &e), &s) in num.iter_mut().zip(&mut den).zip(&e0).zip(samples) {
                let w = r * r / (shot * e * r + read2).max(f32::MIN_POSITIVE);
                let unclipped = s < clip;
                *acc_n = if unclipped {
                    *acc_n + w * s * inv
                } else {
                    *acc_n
                };
                *acc_d = if unclipped { *acc_d + w } else { *acc_d };
            }
        }
        // Clipped in every frame: the darkest frame's x₀, a lower bound.
        let darkest = &rows[0][x0..x0 + n];
        for ((o, ((&nu, &de), &r)), &s) in out
            .iter_mut()
            .zip(num.iter().zip(&den).zip(&sum_r))
            .zip(darkest)
        {
            let everywhere = r == 0.0;
            clipped += u64::from(everywhere);
            *o = if everywhere { s * inverse[0] } else { nu / de };
        }
    }
    clipped
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A xorshift stream of values in `[0, 1)`.
    fn stream(mut seed: u64) -> impl FnMut() -> f32 {
        move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 40) as f32 / (1u64 << 24) as f32
        }
    }

    /// The merge of one pixel as the module docs write it, frame after frame (darkest
    /// first): `None` when it is clipped in every frame.
    fn merged_pixel(frames: &[(f32, f32, f32, f32)], samples: &[f32]) -> Option<f32> {
        let (mut sum_s, mut sum_r) = (0.0f32, 0.0f32);
        for (&(r, ..), &s) in frames.iter().zip(samples) {
            if s < 1.0 {
                sum_s += s;
                sum_r += r;
            }
        }
        if sum_r == 0.0 {
            return None;
        }
        let e0 = (sum_s / sum_r).max(0.0);
        let (mut num, mut den) = (0.0f32, 0.0f32);
        for (&(r, shot, read2, inv), &s) in frames.iter().zip(samples) {
            if s < 1.0 {
                let w = r * r / (shot * e0 * r + read2).max(f32::MIN_POSITIVE);
                num += w * s * inv;
                den += w;
            }
        }
        Some(num / den)
    }

    /// The merge, `LANES` pixels at a time, gives the per-pixel formula bit for bit and
    /// counts the samples clipped in every frame, for one to four frames and rows that end
    /// part-way through a chunk.
    #[test]
    fn the_chunked_merge_equals_the_per_pixel_formula() {
        let mut random = stream(0x9e37_79b9_7f4a_7c15);
        for count in 1..=4 {
            let mut clipped_in_all = 0;
            for width in [1, 7, LANES, LANES + 1, 3 * LANES + 29] {
                let height = 3;
                let exposures: Vec<f64> = (0..count).map(|k| 4f64.powi(k)).collect();
                // Brighter frames clip more often; some samples are negative (noise below
                // the black level).
                let signals: Vec<Vec<f32>> = exposures
                    .iter()
                    .map(|&e| {
                        (0..width * height)
                            .map(|_| (random() * 1.3 - 0.05) * (e as f32).sqrt())
                            .collect()
                    })
                    .collect();
                let linear: Vec<Linear<'_>> = signals
                    .iter()
                    .map(|signal| Linear { signal, width })
                    .collect();
                let noise = Noise {
                    shot: 2e-4,
                    read: 2e-3,
                };
                let inputs: Vec<(&dyn Signal, f64, Noise)> = linear
                    .iter()
                    .zip(&exposures)
                    .map(|(l, &e)| (l as &dyn Signal, e, noise))
                    .collect();
                let merged = merge(&inputs, width, height);
                let e_ref = exposures[count as usize - 1];
                let frames: Vec<(f32, f32, f32, f32)> = exposures
                    .iter()
                    .map(|&e| {
                        let r = (e / e_ref) as f32;
                        (r, 2e-4f64 as f32, (2e-3f64 * 2e-3) as f32, 1.0 / r)
                    })
                    .collect();
                let mut clipped = 0;
                for i in 0..width * height {
                    let samples: Vec<f32> = signals.iter().map(|s| s[i]).collect();
                    let expected = merged_pixel(&frames, &samples).unwrap_or_else(|| {
                        clipped += 1;
                        samples[0] * frames[0].3
                    });
                    assert_eq!(
                        merged.values[i].to_bits(),
                        expected.to_bits(),
                        "{count} frames, {width} wide: pixel {i} reads {}, not {expected}",
                        merged.values[i]
                    );
                }
                assert_eq!(merged.clipped, clipped, "{count} frames, {width} wide");
                clipped_in_all += clipped;
            }
            assert!(
                clipped_in_all > 0,
                "{count} frames: the test needs pixels clipped"
            );
        }
    }

    /// Codes become `(k − b)/(w − b)` with the black level of each position of its tile,
    /// for tiles 1, 2 and 3 pixels wide and 1 or 2 high, and rows that end part-way
    /// through a tile and through a run.
    #[test]
    fn codes_take_the_black_level_of_their_tile_position() {
        let (width, height) = (53, 4);
        let codes: Vec<u16> = (0..width * height)
            .map(|i| (i * 7919 % 16_384) as u16)
            .collect();
        for (black_width, black_height) in [(1, 1), (2, 2), (3, 1), (2, 1)] {
            let black: Vec<f32> = (0..black_width * black_height)
                .map(|i| 500.0 + 37.0 * i as f32)
                .collect();
            let signal = Codes {
                codes: &codes,
                width,
                black: &black,
                black_width,
                black_height,
                white: 16_000.0,
            };
            let mut row = vec![0.0f32; width];
            for y in 0..height {
                signal.row(y, &mut row);
                for (x, &s) in row.iter().enumerate() {
                    let b = black[(y % black_height) * black_width + x % black_width];
                    let expected = (f32::from(codes[y * width + x]) - b) * (1.0 / (16_000.0 - b));
                    assert_eq!(
                        s.to_bits(),
                        expected.to_bits(),
                        "tile {black_width}×{black_height}: ({x}, {y}) reads {s}, not {expected}"
                    );
                }
            }
        }
    }
}
