//! Estimating one frame's transform onto the reference: the log-radiance pyramid, the
//! coarse search and the Gauss–Newton refinement (the method is in the parent module's
//! docs).

use nalgebra::{DMatrix, DVector, Matrix3, Vector3};
use rayon::prelude::*;

use super::{
    COARSEST_SIDE, ESTIMATION_PIXELS, FrameAlignment, IDENTITY_PX, MAX_UNCERTAINTY_BLOCKS,
    MIN_CORRELATION, MIN_OVERLAP, Motion, SEARCH_RANGE, WELL_EXPOSED_HIGH, WELL_EXPOSED_LOW,
};
use crate::frame::{BitDepth, Frame, Samples};
use crate::response::InverseResponse;

mod full;

#[cfg(feature = "raw")]
pub(super) use full::Picture;
pub(super) use full::{Codes, FullFrame};

/// Gauss–Newton iterations per level at most.
const MAX_ITERATIONS: usize = 60;

/// A level has converged when an update moves no corner by more than this many of its
/// pixels.
const CONVERGED_PX: f64 = 0.002;

/// A level a finer stage refines has converged when a proposed step would move no corner
/// by more than this many of its pixels: the finer stage starts well within its reach.
const ROUGH_PX: f64 = 0.05;

/// How far [`damped`] refines a level.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Convergence {
    /// To [`CONVERGED_PX`], or to where no step lowers the residual: the level's result
    /// is the registration's.
    Final,
    /// Until a proposed step would move no corner by more than this many of the level's
    /// pixels; the step is not taken. [`ROUGH_PX`] where a finer level, or the
    /// full-resolution refinement, follows.
    Within(f64),
}

/// Samples one Gauss–Newton iteration reads at least, where the level has more blocks (a
/// regular subsample: [`Sampling`]).
const SAMPLES_PER_ITERATION: usize = 120_000;

/// The damping `λ` a level's refinement starts from, and the least it falls to.
const INITIAL_DAMPING: f64 = 1e-4;

/// A refinement whose damping must rise above this has reached its minimum.
const MAX_DAMPING: f64 = 1e4;

/// The least number of samples a Gauss–Newton iteration needs.
const MIN_SAMPLES: usize = 200;

/// Why one frame could not be registered onto another (its text ends in the frame's
/// alignment note).
#[derive(Debug, Clone, thiserror::Error)]
enum Refusal {
    #[error("only {0} blocks overlap once moved")]
    FewBlocks(usize),
    #[error("the registration's equations are singular (too little texture)")]
    Singular,
    #[error("the registration diverged")]
    Diverged,
    #[error("the registration did not converge in {MAX_ITERATIONS} iterations")]
    NoConvergence,
    #[error("too little texture in common (correlation {0:.2} < {MIN_CORRELATION})")]
    LowCorrelation(f64),
    #[error(
        "moved more than the search range ({:.0} % of the frame's longer side)",
        SEARCH_RANGE * 100.0
    )]
    OutOfRange,
    #[error(
        "the registration moves a corner by {displacement:.0} px, beyond the {farthest:.0} px \
         that a shift within the search range and a small turn can"
    )]
    TooFar { displacement: f64, farthest: f64 },
    #[error("they measure less than {LEAST_COMMON_SPAN:.2} (ln) of radiance in common")]
    NoCommonRange,
    #[error(
        "the tones both measure put the frame {apart:.1} px (±{spread:.2}) from where its \
         clipped edges do"
    )]
    ClippedEdgesMoved { apart: f64, spread: f64 },
    #[error(
        "only {:.1} % of the frame is well exposed in both (< {:.0} %)",
        shared * 100.0,
        MIN_OVERLAP * 100.0
    )]
    LittleOverlap { shared: f64 },
    #[error(
        "the estimated move ({displacement:.2} px) does not reduce the residual ({moved:.4} \
         against {still:.4} unmoved)"
    )]
    NoBetter {
        displacement: f64,
        moved: f64,
        still: f64,
    },
    #[error("no level to refine")]
    NoLevel,
    #[error("too little texture to register the frame (±{0:.2} px)")]
    Undetermined(f64),
}

/// How [`register_or_chain`] compares two frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Way {
    /// On the blocks both measure well, every pyramid level.
    Measured,
    /// The same, passing over coarse levels that share too few blocks.
    FinerLevels,
    /// As [`Pyramid::clipped_alike`].
    ClippedAlike,
}

/// One way [`register_or_chain`] tried and why it failed.
#[derive(Debug, Clone)]
struct Failure {
    /// The frame registered onto.
    onto: usize,
    /// How the two were compared.
    way: Way,
    /// Why it failed.
    why: Refusal,
}

/// Every way [`register_or_chain`] tried, in order, and why each failed.
#[derive(Debug, Clone, thiserror::Error)]
struct Failures(Vec<Failure>);

impl std::fmt::Display for Failures {
    /// `onto frame N[ on its finer levels| clipped alike]: why`, joined by `; `.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        for (i, failure) in self.0.iter().enumerate() {
            let way = match failure.way {
                Way::Measured => "",
                Way::FinerLevels => " on its finer levels",
                Way::ClippedAlike => " clipped alike",
            };
            let sep = if i > 0 { "; " } else { "" };
            write!(f, "{sep}onto frame {}{way}: {}", failure.onto, failure.why)?;
        }
        Ok(())
    }
}

/// One level of a frame's log-radiance pyramid: a value per block of `step × step`
/// full-resolution pixels.
pub(super) struct Level {
    width: usize,
    height: usize,
    /// Full-resolution pixels per block side.
    step: f64,
    /// `ln(mean g(B)) − ln e`, row by row.
    log: Vec<f32>,
    /// Every sample of the block well exposed.
    usable: Vec<bool>,
    /// The block's mean [`log_weight`] (0 when not usable).
    weight: Vec<f32>,
    /// Usable, and so are its four neighbours (its gradient is clean).
    solid: Vec<bool>,
    /// Central differences of `log`, per block.
    grad_x: Vec<f32>,
    grad_y: Vec<f32>,
}

impl Level {
    fn new(width: usize, height: usize, step: f64, log: Vec<f32>, weight: Vec<f32>) -> Level {
        let log = smooth(width, height, &log);
        let usable = weight.iter().map(|&w| w > 0.0).collect();
        let mut level = Level {
            width,
            height,
            step,
            log,
            usable,
            weight,
            solid: Vec::new(),
            grad_x: Vec::new(),
            grad_y: Vec::new(),
        };
        level.gradients();
        level
    }

    /// The solid blocks (see [`erode`]) and the central differences of the smoothed
    /// values.
    fn gradients(&mut self) {
        let (w, h) = (self.width, self.height);
        let (mut gx, mut gy) = (vec![0f32; w * h], vec![0f32; w * h]);
        for y in 1..h.saturating_sub(1) {
            for x in 1..w.saturating_sub(1) {
                let i = y * w + x;
                gx[i] = 0.5 * (self.log[i + 1] - self.log[i - 1]);
                gy[i] = 0.5 * (self.log[i + w] - self.log[i - w]);
            }
        }
        self.solid = erode(w, h, &self.usable, SOLID_RADIUS);
        (self.grad_x, self.grad_y) = (gx, gy);
    }

    /// Half the size: 2 × 2 block means, usable when all four are.
    fn half(&self) -> Level {
        let (w, h) = (self.width / 2, self.height / 2);
        let mut log = vec![0f32; w * h];
        let mut weight = vec![0f32; w * h];
        for y in 0..h {
            for x in 0..w {
                let i = 2 * y * self.width + 2 * x;
                let quad = [i, i + 1, i + self.width, i + self.width + 1];
                log[y * w + x] = quad.iter().map(|&q| self.log[q]).sum::<f32>() / 4.0;
                if quad.iter().all(|&q| self.usable[q]) {
                    weight[y * w + x] = quad.iter().map(|&q| self.weight[q]).sum::<f32>() / 4.0;
                }
            }
        }
        Level::new(w, h, self.step * 2.0, log, weight)
    }

    /// The value, gradient and weight at level coordinates `(x, y)`, bilinear, when its
    /// four neighbours are solid.
    fn sample(&self, x: f64, y: f64) -> Option<(f64, f64, f64, f64)> {
        if !(x >= 0.0 && y >= 0.0) {
            return None;
        }
        let (x0, y0) = (x as usize, y as usize);
        if x0 + 1 >= self.width || y0 + 1 >= self.height {
            return None;
        }
        let i = y0 * self.width + x0;
        let quad = [i, i + 1, i + self.width, i + self.width + 1];
        if !quad.iter().all(|&q| self.solid[q]) {
            return None;
        }
        let (fx, fy) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
        let weights = [
            (1.0 - fx) * (1.0 - fy),
            fx * (1.0 - fy),
            (1.0 - fx) * fy,
            fx * fy,
        ];
        let mix = |v: &[f32]| -> f64 {
            f64::from(
                quad.iter()
                    .zip(&weights)
                    .map(|(&q, &w)| v[q] * w)
                    .sum::<f32>(),
            )
        };
        Some((
            mix(&self.log),
            mix(&self.grad_x),
            mix(&self.grad_y),
            mix(&self.weight),
        ))
    }
}

/// A block is solid when every block within this many of it (a square) is usable: its
/// smoothed value (radius 1) and that value's central differences (radius 1 more) then
/// read no unusable block, so two frames whose usable areas differ still compare alike.
const SOLID_RADIUS: usize = 2;

/// The blocks whose every neighbour within `radius` (a square) is `usable`; the blocks
/// within `radius` of the level's edge are not solid.
fn erode(width: usize, height: usize, usable: &[bool], radius: usize) -> Vec<bool> {
    let run = |line: &mut dyn Iterator<Item = bool>, n: usize| -> Vec<bool> {
        let values: Vec<bool> = line.collect();
        (0..n)
            .map(|i| {
                i >= radius && i + radius < n && values[i - radius..=i + radius].iter().all(|&v| v)
            })
            .collect()
    };
    let mut rows = vec![false; width * height];
    for y in 0..height {
        let eroded = run(
            &mut usable[y * width..(y + 1) * width].iter().copied(),
            width,
        );
        rows[y * width..(y + 1) * width].copy_from_slice(&eroded);
    }
    let mut out = vec![false; width * height];
    for x in 0..width {
        let eroded = run(&mut (0..height).map(|y| rows[y * width + x]), height);
        for (y, v) in eroded.into_iter().enumerate() {
            out[y * width + x] = v;
        }
    }
    out
}

/// `log` filtered by the binomial kernel `[1 2 1]/4` in both directions (renormalised at
/// the level's edge): the gradients then follow the image's shape, not its finest
/// texture, and Gauss–Newton's linearisation holds over a wider move.
fn smooth(width: usize, height: usize, log: &[f32]) -> Vec<f32> {
    const KERNEL: [f32; 3] = [0.25, 0.5, 0.25];
    let mut out = log.to_vec();
    let edge = |x: usize, y: usize| x == 0 || y == 0 || x + 1 == width || y + 1 == height;
    for y in 1..height.saturating_sub(1) {
        // Inside the level the kernel's weights sum to exactly 1: the same terms, in the
        // same order, without the edge's checks.
        let rows = [y - 1, y, y + 1].map(|yy| &log[yy * width..(yy + 1) * width]);
        for x in 1..width.saturating_sub(1) {
            let mut sum = 0.0f32;
            for (row, ky) in rows.iter().zip(KERNEL) {
                for (v, kx) in row[x - 1..=x + 1].iter().zip(KERNEL) {
                    sum += ky * kx * v;
                }
            }
            out[y * width + x] = sum;
        }
    }
    for y in 0..height {
        for x in (0..width).filter(|&x| edge(x, y)) {
            let (mut sum, mut weight) = (0.0f32, 0.0f32);
            for (dy, ky) in KERNEL.iter().enumerate() {
                let Some(yy) = (y + dy).checked_sub(1).filter(|&v| v < height) else {
                    continue;
                };
                for (dx, kx) in KERNEL.iter().enumerate() {
                    let Some(xx) = (x + dx).checked_sub(1).filter(|&v| v < width) else {
                        continue;
                    };
                    sum += ky * kx * log[yy * width + xx];
                    weight += ky * kx;
                }
            }
            if weight > 0.0 {
                out[y * width + x] = sum / weight;
            }
        }
    }
    out
}

/// The weight of a log-radiance sample of brightness `B` (a fraction of full scale): 0
/// outside [`WELL_EXPOSED_LOW`]..=[`WELL_EXPOSED_HIGH`], else `B²`, the inverse variance of
/// `ln g(B)` under code-value noise up to a constant factor (`σ_ln g ≈ γ·σ_B/B` for a
/// response `g ≈ B^γ`; for a raw's linear signal `σ_ln s = σ_s/s`).
pub(super) fn log_weight(b: f32) -> f32 {
    if (WELL_EXPOSED_LOW as f32..=WELL_EXPOSED_HIGH as f32).contains(&b) {
        b * b
    } else {
        0.0
    }
}

/// A frame's levels, finest first, its relative exposure and what its finest blocks
/// measured (for [`Pyramid::clipped_alike`]).
pub(super) struct Pyramid {
    levels: Vec<Level>,
    exposure: f64,
    blocks: Blocks,
}

/// What the pixels of a block of the finest level saw.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Tone {
    /// Every pixel well exposed.
    Measured,
    /// Some pixels above the well-exposed range (clipped), none below it.
    Bright,
    /// Some pixels below it (in the noise floor), none above it.
    Dark,
    /// Some of each.
    Mixed,
}

/// The finest level before smoothing: per block its log radiance `ln(mean g) − ln e`
/// (meaningful where [`Tone::Measured`]), weight and tone, and the log radiances
/// `[low, high]` the frame measures (the well-exposed range through the response, less
/// `ln e`).
struct Blocks {
    width: usize,
    height: usize,
    step: usize,
    log: Vec<f32>,
    weight: Vec<f32>,
    tone: Vec<Tone>,
    range: (f32, f32),
}

/// One row of blocks of the finest level as its pixel rows are read: per pixel column,
/// the sums over the rows read so far of the linear value and the weight, and how many
/// of its pixels were usable and how many bright (unusable, above the range's geometric
/// mean). Summing down the columns runs over whole rows, which the compiler vectorises;
/// the blocks then add up their `step` columns.
struct BlockRow {
    value: Vec<f32>,
    weight: Vec<f32>,
    usable: Vec<u32>,
    bright: Vec<u32>,
    /// Scratch: the row being read (values and weights, the image's full width).
    row: (Vec<f32>, Vec<f32>),
}

impl BlockRow {
    /// Sums for `columns` pixel columns (the blocks' width) of an image `width` wide.
    fn new(columns: usize, width: usize) -> BlockRow {
        BlockRow {
            value: vec![0.0; columns],
            weight: vec![0.0; columns],
            usable: vec![0; columns],
            bright: vec![0; columns],
            row: (vec![0.0; width], vec![0.0; width]),
        }
    }

    fn clear(&mut self) {
        self.value.fill(0.0);
        self.weight.fill(0.0);
        self.usable.fill(0);
        self.bright.fill(0);
    }

    /// Pixel row `y`, read by `row` (as [`Pyramid::from_rows`] takes it), added in; a
    /// pixel unusable at a value of `middle` or more counts as bright.
    fn add<F: Fn(usize, &mut [f32], &mut [f32])>(&mut self, y: usize, row: &F, middle: f32) {
        let (values, weights) = &mut self.row;
        row(y, values, weights);
        let sums = self.value.iter_mut().zip(self.weight.iter_mut());
        let counts = self.usable.iter_mut().zip(self.bright.iter_mut());
        for (((sum, wsum), (usable, bright)), (&v, &o)) in
            sums.zip(counts).zip(values.iter().zip(weights.iter()))
        {
            (*sum, *wsum) = (*sum + v, *wsum + o);
            *usable += u32::from(o > 0.0);
            *bright += u32::from((o <= 0.0) & (v >= middle));
        }
    }

    /// Each block of `step × step` pixels (its `step` rows added): its log radiance
    /// `ln(mean) − log_e`, its weight (the pixels' mean weight when it is
    /// [`Tone::Measured`], else 0) and its tone, into the three rows.
    fn finish(
        &self,
        step: usize,
        log_e: f32,
        (log, weight, tone): (&mut [f32], &mut [f32], &mut [Tone]),
    ) {
        let all = (step * step) as u32;
        let area = all as f32;
        let sums = self
            .value
            .chunks_exact(step)
            .zip(self.weight.chunks_exact(step));
        let counts = self
            .usable
            .chunks_exact(step)
            .zip(self.bright.chunks_exact(step));
        for (((l, wt), t), ((value, wsum), (usable, bright))) in log
            .iter_mut()
            .zip(weight.iter_mut())
            .zip(tone.iter_mut())
            .zip(sums.zip(counts))
        {
            let (sum, wsum) = (value.iter().sum::<f32>(), wsum.iter().sum::<f32>());
            let (usable, bright) = (usable.iter().sum::<u32>(), bright.iter().sum::<u32>());
            let mean = sum / area;
            *t = match (usable, bright, all - usable - bright) {
                (n, _, _) if n == all && mean > 0.0 => Tone::Measured,
                (_, 0, _) => Tone::Dark,
                (_, _, 0) => Tone::Bright,
                _ => Tone::Mixed,
            };
            *wt = if *t == Tone::Measured {
                wsum / area
            } else {
                0.0
            };
            *l = mean.max(1e-12).ln() - log_e;
        }
    }
}

/// The least span, in natural-log units (one stop), of log radiance two frames must both
/// measure for [`Pyramid::clipped_alike`] to compare them.
const LEAST_COMMON_SPAN: f32 = std::f32::consts::LN_2;

/// A value per code of any depth: an 8- or 16-bit code indexes it without a bounds check
/// (a shallower depth leaves the entries above its top code at 0).
type Table = [f32; 1 << 16];

/// The codes' entries `entry(k)` in a [`Table`].
fn table_of(levels: usize, entry: impl Fn(usize) -> f32) -> Box<Table> {
    let mut table: Box<Table> = vec![0.0; 1 << 16]
        .into_boxed_slice()
        .try_into()
        .expect("the length is the table's");
    for (k, slot) in table.iter_mut().take(levels).enumerate() {
        *slot = entry(k);
    }
    table
}

/// Codes to linear values and weights, per code and channel `g(B)/C` (`C` channels, so a
/// pixel's mean is the sum of its channels' entries) and per code its [`log_weight`]:
/// what [`Pyramid::from_rows`] and the full-resolution refinement read.
pub(super) struct Convert {
    tables: Vec<Box<Table>>,
    weight_of: Box<Table>,
    /// The codes whose weight is not 0, first and last: the weight rises between them.
    weighed: (usize, usize),
    /// The mean `g` over the channels at the lower and upper well-exposed codes.
    range: (f32, f32),
}

impl Convert {
    /// The tables of frames of `channels` channels at `depth` through `response`.
    pub(super) fn new(response: &InverseResponse, depth: BitDepth, channels: usize) -> Convert {
        let levels = depth.levels();
        let share = 1.0 / channels as f32;
        let tables: Vec<Box<Table>> = (0..channels)
            .map(|ch| {
                let table = response.table(ch.min(response.channels() - 1), levels);
                table_of(levels, |k| table[k] * share)
            })
            .collect();
        let max = depth.max_code() as f32;
        let (low, high) = super::well_exposed_codes(depth.max_code());
        let mean_at = |k: u32| tables.iter().map(|t| t[k as usize]).sum::<f32>();
        let range = (mean_at(low), mean_at(high));
        let weight_of = table_of(levels, |k| log_weight(k as f32 / max));
        let first = weight_of.iter().position(|&w| w > 0.0).unwrap_or(levels);
        let last = weight_of.iter().rposition(|&w| w > 0.0).unwrap_or(0);
        Convert {
            tables,
            weight_of,
            weighed: (first, last),
            range,
        }
    }

    /// One pixel's codes (one per channel): its mean `g(B)` over the channels and its
    /// worst channel's weight.
    fn pixel<T: Copy + Into<u16>>(&self, codes: &[T]) -> (f32, f32) {
        let (mut sum, mut worst) = (0.0f32, f32::INFINITY);
        for (&k, table) in codes.iter().zip(&self.tables) {
            let k = usize::from(k.into());
            sum += table[k];
            worst = worst.min(self.weight_of[k]);
        }
        (sum, worst)
    }

    /// A row of pixels (`codes`, channels interleaved) as [`Convert::pixel`] gives them.
    fn row<T: Copy + Into<u16>>(&self, codes: &[T], values: &mut [f32], weights: &mut [f32]) {
        match self.tables.len() {
            1 => self.row_of::<T, 1>(codes, values, weights),
            _ => self.row_of::<T, 3>(codes, values, weights),
        }
    }

    /// [`Convert::row`] for `C` channels. The worst channel's weight is that of the
    /// lowest code when every code is weighed ([`log_weight`] rises with the code), else 0.
    fn row_of<T: Copy + Into<u16>, const C: usize>(
        &self,
        codes: &[T],
        values: &mut [f32],
        weights: &mut [f32],
    ) {
        let tables: [&Table; C] = std::array::from_fn(|ch| &*self.tables[ch]);
        let (first, last) = self.weighed;
        for ((pixel, value), weight) in codes.chunks_exact(C).zip(values).zip(weights) {
            let (mut sum, mut low, mut high) = (0.0f32, u16::MAX, 0);
            for (&k, table) in pixel.iter().zip(tables) {
                let k: u16 = k.into();
                sum += table[usize::from(k)];
                (low, high) = (low.min(k), high.max(k));
            }
            *value = sum;
            *weight = if usize::from(low) >= first && usize::from(high) <= last {
                self.weight_of[usize::from(low)]
            } else {
                0.0
            };
        }
    }
}

/// The block size of the finest level for a `width × height` frame: the smallest
/// multiple of `tile` with at most [`ESTIMATION_PIXELS`] blocks.
pub(super) fn step_for(width: usize, height: usize, tile: usize) -> usize {
    let step = ((width * height) as f64 / ESTIMATION_PIXELS as f64)
        .sqrt()
        .ceil() as usize;
    step.max(1).div_ceil(tile) * tile
}

impl Pyramid {
    /// The pyramid of a frame of codes through `convert` at relative `exposure`.
    pub(super) fn of_frame(
        frame: &Frame,
        convert: &Convert,
        exposure: f64,
        step: usize,
    ) -> Pyramid {
        let (w, c) = (frame.width() as usize, frame.channels());
        let row = |y: usize, values: &mut [f32], weights: &mut [f32]| {
            let span = y * w * c..(y + 1) * w * c;
            match frame.samples() {
                Samples::Eight(v) => convert.row(&v[span], values, weights),
                Samples::Sixteen(v) => convert.row(&v[span], values, weights),
            }
        };
        let (h, range) = (frame.height() as usize, convert.range);
        Pyramid::from_rows(w, h, step, exposure, range, row)
    }

    /// The pyramid of a `width × height` image whose row `y` `row(y, values, weights)`
    /// fills with linear values (≥ 0) and their [`log_weight`]s (0: not usable), at
    /// relative `exposure`; `range` is the linear values that bound the usable ones (an
    /// unusable pixel is bright above their geometric mean, dark below it). A block's
    /// weight is its pixels' mean, 0 unless all are usable. Rows of blocks are summed in
    /// parallel ([`BlockRow`]).
    pub(super) fn from_rows<F>(
        width: usize,
        height: usize,
        step: usize,
        exposure: f64,
        range: (f32, f32),
        row: F,
    ) -> Pyramid
    where
        F: Fn(usize, &mut [f32], &mut [f32]) + Sync,
    {
        let (lw, lh) = (width / step, height / step);
        let log_e = exposure.ln() as f32;
        let middle = (range.0.max(f32::MIN_POSITIVE) * range.1).sqrt();
        let mut log = vec![0f32; lw * lh];
        let mut weight = vec![0f32; lw * lh];
        let mut tone = vec![Tone::Mixed; lw * lh];
        log.par_chunks_mut(lw.max(1))
            .zip(weight.par_chunks_mut(lw.max(1)))
            .zip(tone.par_chunks_mut(lw.max(1)))
            .enumerate()
            .for_each_init(
                || BlockRow::new(lw * step, width),
                |blocks, (j, ((log_row, weight_row), tone_row))| {
                    blocks.clear();
                    for y in j * step..(j + 1) * step {
                        blocks.add(y, &row, middle);
                    }
                    blocks.finish(step, log_e, (log_row, weight_row, tone_row));
                },
            );
        let log_range = (
            range.0.max(1e-12).ln() - log_e,
            range.1.max(1e-12).ln() - log_e,
        );
        let blocks = Blocks {
            width: lw,
            height: lh,
            step,
            log,
            weight,
            tone,
            range: log_range,
        };
        Pyramid {
            levels: levels(blocks.log.clone(), blocks.weight.clone(), lw, lh, step),
            exposure,
            blocks,
        }
    }

    /// This frame and `other` as the log radiance both could have measured, clamped to
    /// the range both measure (`[max of the lows, min of the highs]`): a block with no
    /// clipped pixel at its value (dark pixels' values are noisy but below the range), one
    /// with clipped pixels and none dark at the top when its value (a lower bound) is
    /// above it, else left out; a block not wholly well exposed weighs as one at the
    /// range's top (its clamped value carries no noise). Two frames several stops apart
    /// share few well-exposed blocks, but a window clipped in one and exposed in the
    /// other is at the top in both: its edges register. `None` when they share less than
    /// [`LEAST_COMMON_SPAN`].
    pub(super) fn clipped_alike(&self, other: &Pyramid) -> Option<(Vec<Level>, Vec<Level>)> {
        let low = self.blocks.range.0.max(other.blocks.range.0);
        let high = self.blocks.range.1.min(other.blocks.range.1);
        if high - low < LEAST_COMMON_SPAN {
            return None;
        }
        Some((self.clamped(low, high), other.clamped(low, high)))
    }

    /// The levels of [`Pyramid::clipped_alike`]'s image of this frame for the range
    /// `[low, high]`.
    fn clamped(&self, low: f32, high: f32) -> Vec<Level> {
        let b = &self.blocks;
        let top = log_weight(WELL_EXPOSED_HIGH as f32);
        let (log, weight): (Vec<f32>, Vec<f32>) = b
            .tone
            .iter()
            .zip(b.log.iter().zip(&b.weight))
            .map(|(tone, (&l, &w))| match tone {
                Tone::Measured => (l.clamp(low, high), w),
                Tone::Dark => (l.clamp(low, high), top),
                Tone::Bright if l >= high => (high, top),
                Tone::Bright | Tone::Mixed => (l, 0.0),
            })
            .unzip();
        levels(log, weight, b.width, b.height, b.step)
    }
}

/// The levels of a finest `width × height` level of `step`, halved while the shorter
/// side stays at least [`COARSEST_SIDE`].
fn levels(log: Vec<f32>, weight: Vec<f32>, width: usize, height: usize, step: usize) -> Vec<Level> {
    let mut levels = vec![Level::new(width, height, step as f64, log, weight)];
    while let Some(last) = levels.last()
        && last.width.min(last.height) / 2 >= COARSEST_SIDE
    {
        let half = last.half();
        levels.push(half);
    }
    levels
}

/// Full-resolution normalisation `ũ = (u − c)/s`: `c` the frame's centre, `s` half its
/// longer side.
pub(super) struct Geometry {
    cx: f64,
    cy: f64,
    s: f64,
    width: f64,
    height: f64,
}

impl Geometry {
    pub(super) fn new(width: u32, height: u32) -> Geometry {
        let (w, h) = (f64::from(width), f64::from(height));
        Geometry {
            cx: (w - 1.0) / 2.0,
            cy: (h - 1.0) / 2.0,
            s: w.max(h) / 2.0,
            width: w,
            height: h,
        }
    }

    /// Block `(x, y)` of a level of `step` (its centre is full-resolution pixel
    /// `step·x + (step − 1)/2`) in normalised coordinates.
    fn to_normalised(&self, step: f64, x: f64, y: f64) -> (f64, f64) {
        let o = (step - 1.0) / 2.0;
        (
            (step * x + o - self.cx) / self.s,
            (step * y + o - self.cy) / self.s,
        )
    }

    fn to_level(&self, step: f64, u: f64, v: f64) -> (f64, f64) {
        let o = (step - 1.0) / 2.0;
        (
            (self.s * u + self.cx - o) / step,
            (self.s * v + self.cy - o) / step,
        )
    }

    /// The full-resolution pixel transform `N⁻¹·H·N` of a normalised one, scaled so that
    /// its last entry is 1.
    fn pixel_matrix(&self, h: &Matrix3<f64>) -> [[f64; 3]; 3] {
        let n = Matrix3::new(
            1.0 / self.s,
            0.0,
            -self.cx / self.s,
            0.0,
            1.0 / self.s,
            -self.cy / self.s,
            0.0,
            0.0,
            1.0,
        );
        let n_inv = Matrix3::new(self.s, 0.0, self.cx, 0.0, self.s, self.cy, 0.0, 0.0, 1.0);
        let p = n_inv * h * n;
        let p = p / p[(2, 2)];
        [
            [p[(0, 0)], p[(0, 1)], p[(0, 2)]],
            [p[(1, 0)], p[(1, 1)], p[(1, 2)]],
            [p[(2, 0)], p[(2, 1)], p[(2, 2)]],
        ]
    }

    /// The largest distance, in full-resolution pixels, that `m` moves a corner of the
    /// frame.
    fn displacement(&self, m: &Matrix3<f64>) -> f64 {
        self.corner_shift(&Matrix3::identity(), m)
    }

    /// The largest distance, in full-resolution pixels, between where `a` and `b` take the
    /// frame's four corners.
    fn corner_shift(&self, a: &Matrix3<f64>, b: &Matrix3<f64>) -> f64 {
        let corners = [
            (0.0, 0.0),
            (self.width - 1.0, 0.0),
            (0.0, self.height - 1.0),
            (self.width - 1.0, self.height - 1.0),
        ];
        corners
            .iter()
            .map(|&(x, y)| {
                let u = Vector3::new((x - self.cx) / self.s, (y - self.cy) / self.s, 1.0);
                let (p, q) = (a * u, b * u);
                let (dx, dy) = (p.x / p.z - q.x / q.z, p.y / p.z - q.y / q.z);
                dx.hypot(dy) * self.s
            })
            .fold(0.0, f64::max)
    }
}

/// The motion and photometric parameters being estimated.
#[derive(Debug, Clone, Copy)]
struct State {
    motion: Motion,
    /// Translation `(tx, ty)`; rigid `(θ, tx, ty)`; homography `H − I` row by row, the
    /// last entry left out.
    p: [f64; 8],
    gain: f64,
    bias: f64,
}

impl State {
    fn params(&self) -> usize {
        match self.motion {
            Motion::Translation => 2,
            Motion::Rigid => 3,
            Motion::Homography => 8,
        }
    }

    fn matrix(&self) -> Matrix3<f64> {
        let p = &self.p;
        match self.motion {
            Motion::Translation => Matrix3::new(1.0, 0.0, p[0], 0.0, 1.0, p[1], 0.0, 0.0, 1.0),
            Motion::Rigid => {
                let (s, c) = p[0].sin_cos();
                Matrix3::new(c, -s, p[1], s, c, p[2], 0.0, 0.0, 1.0)
            }
            Motion::Homography => Matrix3::new(
                1.0 + p[0],
                p[1],
                p[2],
                p[3],
                1.0 + p[4],
                p[5],
                p[6],
                p[7],
                1.0,
            ),
        }
    }

    /// The same transform (as near as the model allows) as model `motion`.
    fn as_motion(&self, motion: Motion) -> State {
        let m = self.matrix();
        let m = m / m[(2, 2)];
        let p = match motion {
            Motion::Translation => [m[(0, 2)], m[(1, 2)], 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            Motion::Rigid => {
                let angle = (m[(1, 0)] - m[(0, 1)]).atan2(m[(0, 0)] + m[(1, 1)]);
                [angle, m[(0, 2)], m[(1, 2)], 0.0, 0.0, 0.0, 0.0, 0.0]
            }
            Motion::Homography => [
                m[(0, 0)] - 1.0,
                m[(0, 1)],
                m[(0, 2)],
                m[(1, 0)],
                m[(1, 1)] - 1.0,
                m[(1, 2)],
                m[(2, 0)],
                m[(2, 1)],
            ],
        };
        State { motion, p, ..*self }
    }

    /// `∂x′/∂p` and `∂y′/∂p` at the normalised point `(u, v)`, which the transform takes to
    /// `(x′, y′) = (X/W, Y/W)`; `(s, c)` the sine and cosine of a rigid model's angle.
    fn jacobian(
        &self,
        (s, c): (f64, f64),
        (u, v): (f64, f64),
        (xp, yp, w): (f64, f64, f64),
    ) -> ([f64; 8], [f64; 8]) {
        let mut dx = [0.0; 8];
        let mut dy = [0.0; 8];
        match self.motion {
            Motion::Translation => {
                dx[0] = 1.0;
                dy[1] = 1.0;
            }
            Motion::Rigid => {
                dx[..3].copy_from_slice(&[-s * u - c * v, 1.0, 0.0]);
                dy[..3].copy_from_slice(&[c * u - s * v, 0.0, 1.0]);
            }
            Motion::Homography => {
                let r = 1.0 / w;
                dx = [u * r, v * r, r, 0.0, 0.0, 0.0, -u * xp * r, -v * xp * r];
                dy = [0.0, 0.0, 0.0, u * r, v * r, r, -u * yp * r, -v * yp * r];
            }
        }
        (dx, dy)
    }
}

/// A state as a pass linearises it: the state, how many of its motion parameters the
/// pass estimates, and what every sample's row shares (the sine and cosine of a rigid
/// model's angle).
struct Linearised<'s> {
    state: &'s State,
    motion: usize,
    sin_cos: (f64, f64),
}

impl Linearised<'_> {
    fn new(state: &State, motion: usize) -> Linearised<'_> {
        Linearised {
            state,
            motion,
            sin_cos: state.p[0].sin_cos(),
        }
    }
}

/// Parameters at most: eight of motion, gain, offset.
const MAX_PARAMS: usize = 10;

/// The Gauss–Newton normal equations of one pass: `JᵀJ`, `Jᵀr`, `Σ r²` and the count.
#[derive(Clone)]
struct Normal {
    jtj: [[f64; MAX_PARAMS]; MAX_PARAMS],
    jtr: [f64; MAX_PARAMS],
    sse: f64,
    count: usize,
}

impl Normal {
    fn zero() -> Normal {
        Normal {
            jtj: [[0.0; MAX_PARAMS]; MAX_PARAMS],
            jtr: [0.0; MAX_PARAMS],
            sse: 0.0,
            count: 0,
        }
    }

    fn add(mut self, other: Normal) -> Normal {
        for (row, other) in self.jtj.iter_mut().zip(&other.jtj) {
            for (a, b) in row.iter_mut().zip(other) {
                *a += b;
            }
        }
        for (a, b) in self.jtr.iter_mut().zip(&other.jtr) {
            *a += b;
        }
        self.sse += other.sse;
        self.count += other.count;
        self
    }

    fn mean_square(&self) -> f64 {
        self.sse / self.count.max(1) as f64
    }

    fn rms(&self) -> f64 {
        self.mean_square().sqrt()
    }

    /// Adds one equation: the first `n` entries of its row `j` (the rest are 0), residual
    /// `r`, `weight`.
    fn include(&mut self, j: &[f64; MAX_PARAMS], r: f64, weight: f64, n: usize) {
        // The models' sizes as constants, so that the loops unroll.
        match n {
            2 => self.include_first::<2>(j, r, weight),
            4 => self.include_first::<4>(j, r, weight),
            5 => self.include_first::<5>(j, r, weight),
            _ => self.include_first::<MAX_PARAMS>(j, r, weight),
        }
    }

    /// [`Normal::include`] of the first `N` entries of `j`.
    fn include_first<const N: usize>(&mut self, j: &[f64; MAX_PARAMS], r: f64, weight: f64) {
        for a in 0..N {
            let wa = weight * j[a];
            for (sum, jb) in self.jtj[a][a..N].iter_mut().zip(&j[a..N]) {
                *sum += wa * jb;
            }
            self.jtr[a] += wa * r;
        }
        self.sse += weight * r * r;
        self.count += 1;
    }

    /// Adds the equation of one reference sample at normalised `(u, v)`, `reference` its
    /// log radiance and weight, whose image `p = T·(u, v, 1)ᵀ` the moving frame samples
    /// as `seen`: log radiance, its gradient per normalised unit and weight. The residual
    /// is `gain·L_k + bias − L_ref`, its row the first `motion` motion parameters of
    /// `state`, gain and offset; the weight `w_ref·w_k/(w_ref + w_k)`, the inverse
    /// variance of the difference of two log values.
    fn equation(
        &mut self,
        at: &Linearised<'_>,
        (u, v): (f64, f64),
        p: &Vector3<f64>,
        (reference, reference_weight): (f64, f64),
        (value, gu, gv, moving_weight): (f64, f64, f64, f64),
    ) {
        let (state, motion) = (at.state, at.motion);
        let weight = reference_weight * moving_weight / (reference_weight + moving_weight);
        let r = state.gain * value + state.bias - reference;
        let mut j = [0.0; MAX_PARAMS];
        let (dx, dy) = state.jacobian(at.sin_cos, (u, v), (p.x / p.z, p.y / p.z, p.z));
        for k in 0..motion {
            j[k] = state.gain * (gu * dx[k] + gv * dy[k]);
        }
        j[motion] = value;
        j[motion + 1] = 1.0;
        self.include(&j, r, weight, motion + 2);
    }

    /// The mean square residual after the least-squares step in the first `n`
    /// parameters: `(SSE − bᵀA⁻¹b)/count`, `A` and `b` their system; without the step
    /// when `A` is singular.
    fn fitted_mean_square(&self, n: usize) -> f64 {
        let (a, b) = self.system(n);
        let sse = a.try_inverse().map_or(self.sse, |inverse| {
            self.sse - (b.transpose() * inverse * &b)[0]
        });
        sse.max(0.0) / self.count.max(1) as f64
    }

    /// The equations of gain and offset alone, of a system whose first `motion`
    /// parameters are the motion's.
    fn photometric(&self, motion: usize) -> Normal {
        let (g, b) = (motion, motion + 1);
        let mut out = Normal {
            sse: self.sse,
            count: self.count,
            ..Normal::zero()
        };
        out.jtj[0][0] = self.jtj[g][g];
        out.jtj[0][1] = self.jtj[g][b];
        out.jtj[1][1] = self.jtj[b][b];
        out.jtr[0] = self.jtr[g];
        out.jtr[1] = self.jtr[b];
        out
    }

    /// These equations (first `motion` parameters the motion's, then gain and offset,
    /// taken at gain `gain`) after the gain and offset move by `δ = (δg, δb)`, in closed
    /// form: each residual gains `δg·L_k + δb = j_p·δ` (`j_p` its gain and offset
    /// columns) and each motion column scales by `ρ = (gain + δg)/gain`, so with
    /// `D = diag(ρ, …, ρ, 1, 1)`: `JᵀJ′ = D·JᵀJ·D`, `Jᵀr′ = D·(Jᵀr + JᵀJ_p·δ)` and
    /// `Σr′² = Σr² + 2δᵀ·(Jᵀr)_p + δᵀ·(JᵀJ)_pp·δ`, the count unchanged.
    fn with_photometric_step(&self, motion: usize, gain: f64, delta: [f64; 2]) -> Normal {
        let size = motion + 2;
        let (g, b) = (motion, motion + 1);
        let at = |i: usize, j: usize| self.jtj[i.min(j)][i.max(j)];
        let rho = (gain + delta[0]) / gain;
        let scale = |i: usize| if i < motion { rho } else { 1.0 };
        let mut out = Normal {
            count: self.count,
            ..Normal::zero()
        };
        for i in 0..size {
            for j in i..size {
                out.jtj[i][j] = scale(i) * scale(j) * at(i, j);
            }
            let moved = self.jtr[i] + at(i, g) * delta[0] + at(i, b) * delta[1];
            out.jtr[i] = scale(i) * moved;
        }
        let quadratic = delta[0] * delta[0] * at(g, g)
            + 2.0 * delta[0] * delta[1] * at(g, b)
            + delta[1] * delta[1] * at(b, b);
        out.sse = self.sse + 2.0 * (delta[0] * self.jtr[g] + delta[1] * self.jtr[b]) + quadratic;
        out
    }

    /// The `n × n` matrix and the vector of the first `n` parameters.
    fn system(&self, n: usize) -> (DMatrix<f64>, DVector<f64>) {
        let a = DMatrix::from_fn(n, n, |i, j| self.jtj[i.min(j)][i.max(j)]);
        (a, DVector::from_fn(n, |i, _| self.jtr[i]))
    }
}

/// One pass over the reference level: the normal equations of the residual
/// `gain·L_k(T·x) + bias − L_ref(x)` in the first `motion` motion parameters of `state`
/// (0: gain and offset only), gain and offset.
fn accumulate(
    reference: &Level,
    moving: &Level,
    geometry: &Geometry,
    state: &State,
    motion: usize,
) -> Normal {
    let sampling = Sampling::of(reference, geometry, Linearised::new(state, motion));
    // Rows in fixed groups, the groups' sums added in order: the same sums, to the last
    // bit, however the threads share the work.
    let rows: Vec<usize> = (0..reference.height).step_by(sampling.stride).collect();
    let groups: Vec<Normal> = rows
        .par_chunks(ROWS_PER_GROUP)
        .map(|group| {
            let mut acc = Normal::zero();
            for &y in group {
                for x in (0..reference.width).step_by(sampling.stride) {
                    sampling.add(reference, moving, (x, y), &mut acc);
                }
            }
            acc
        })
        .collect();
    groups.into_iter().fold(Normal::zero(), Normal::add)
}

/// The normal equations of [`accumulate`] split by cell of a [`CELLS`] × [`CELLS`] grid
/// over the level: what [`robust_uncertainty_px`] reads the residuals' spatial correlation
/// from.
fn accumulate_cells(
    reference: &Level,
    moving: &Level,
    geometry: &Geometry,
    state: &State,
    motion: usize,
) -> Vec<Normal> {
    let sampling = Sampling::of(reference, geometry, Linearised::new(state, motion));
    let (w, h) = (reference.width, reference.height);
    (0..CELLS)
        .into_par_iter()
        .flat_map_iter(|cy| {
            let rows = cy * h / CELLS..(cy + 1) * h / CELLS;
            let mut cells: Vec<Normal> = (0..CELLS).map(|_| Normal::zero()).collect();
            for y in rows.filter(|y| y.is_multiple_of(sampling.stride)) {
                for x in (0..w).step_by(sampling.stride) {
                    let cell = &mut cells[x * CELLS / w];
                    sampling.add(reference, moving, (x, y), cell);
                }
            }
            cells
        })
        .collect()
}

/// Cells per side of the grid [`accumulate_cells`] splits the samples by.
const CELLS: usize = 16;

/// How [`accumulate`] samples a reference level under a state: every `stride`-th block
/// of every `stride`-th row, `stride = ⌊√(n/S)⌋` (at least 1) for a level of `n` blocks and
/// `S` = [`SAMPLES_PER_ITERATION`]: every block of a level of fewer than `4S`, else
/// between `S` and `4S` of them. The blocks' normalised coordinates are computed once
/// per column and per row.
struct Sampling<'g, 's> {
    stride: usize,
    at: Linearised<'s>,
    matrix: Matrix3<f64>,
    geometry: &'g Geometry,
    /// `ũ` of each column of the level, `ṽ` of each row.
    columns: Vec<f64>,
    rows: Vec<f64>,
}

impl<'g, 's> Sampling<'g, 's> {
    fn of(reference: &Level, geometry: &'g Geometry, at: Linearised<'s>) -> Sampling<'g, 's> {
        let blocks = (reference.width * reference.height) as f64;
        let stride = ((blocks / SAMPLES_PER_ITERATION as f64).sqrt().floor() as usize).max(1);
        let step = reference.step;
        let normalised = |x: usize, y: usize| geometry.to_normalised(step, x as f64, y as f64);
        Sampling {
            stride,
            matrix: at.state.matrix(),
            at,
            geometry,
            columns: (0..reference.width).map(|x| normalised(x, 0).0).collect(),
            rows: (0..reference.height).map(|y| normalised(0, y).1).collect(),
        }
    }

    /// Adds the equation of reference block `(x, y)` to `acc`, when it is solid and its
    /// image lands on solid blocks of `moving`.
    fn add(&self, reference: &Level, moving: &Level, (x, y): (usize, usize), acc: &mut Normal) {
        let i = y * reference.width + x;
        if !reference.solid[i] {
            return;
        }
        let step = reference.step;
        let (u, v) = (self.columns[x], self.rows[y]);
        let p = self.matrix * Vector3::new(u, v, 1.0);
        let (xp, yp) = (p.x / p.z, p.y / p.z);
        let (lx, ly) = self.geometry.to_level(step, xp, yp);
        let Some((value, gx, gy, moving_weight)) = moving.sample(lx, ly) else {
            return;
        };
        let to_level = self.geometry.s / step;
        let fixed = (f64::from(reference.log[i]), f64::from(reference.weight[i]));
        let seen = (value, gx * to_level, gy * to_level, moving_weight);
        acc.equation(&self.at, (u, v), &p, fixed, seen);
    }
}

/// Rows of a level [`accumulate`] sums in one task.
const ROWS_PER_GROUP: usize = 8;

/// The damped Gauss–Newton step `δ = −(JᵀJ + λ·diag(JᵀJ))⁻¹Jᵀr`, `None` when the
/// system is singular.
fn solve(normal: &Normal, n: usize, damping: f64) -> Option<DVector<f64>> {
    let (mut a, b) = normal.system(n);
    for i in 0..n {
        a[(i, i)] *= 1.0 + damping;
    }
    a.cholesky().map(|c| -c.solve(&b))
}

/// Refines `state` on one level by [`damped`] Gauss–Newton to `convergence`: the state
/// and its normal equations, or why it failed.
fn refine(
    (reference, moving): (&Level, &Level),
    geometry: &Geometry,
    state: State,
    convergence: Convergence,
) -> Result<(State, Normal), Refusal> {
    let n = state.params();
    let normal = |s: &State| accumulate(reference, moving, geometry, s, n);
    let current = normal(&state);
    damped(
        geometry,
        reference.step,
        state,
        current,
        &normal,
        convergence,
    )
}

/// Refines `state`, whose normal equations are `current`, by damped Gauss–Newton on
/// those `normal` gives at a state (Levenberg–Marquardt: the diagonal of `JᵀJ` raised by
/// the factor `1 + λ`, `λ` divided by 10 after a step that lowers the mean squared
/// residual and multiplied by 10 after one that does not) until, in units of `step`
/// full-resolution pixels, an accepted step moves no corner by more than
/// [`CONVERGED_PX`], or (for [`Convergence::Within`]) a proposed step would move none by
/// more than its bound (it is not taken) or a refused step (one that does not lower the
/// residual) moves none by more than twice the bound, or no step short of `λ` =
/// [`MAX_DAMPING`] lowers the residual: the state and its normal equations, or why it
/// failed. A residual quadratic along a descent step of length `d` that rises over it
/// has its minimum on that line nearer than `d/2` to the state: a refused step under
/// twice the bound finds the state within the bound, where damping it further (which
/// shrinks it little while `λ` is small) would spend a pass over the samples per
/// tenfold `λ`.
fn damped(
    geometry: &Geometry,
    step: f64,
    mut state: State,
    mut current: Normal,
    normal: &dyn Fn(&State) -> Normal,
    convergence: Convergence,
) -> Result<(State, Normal), Refusal> {
    let n = state.params();
    let mut damping = INITIAL_DAMPING;
    for _ in 0..MAX_ITERATIONS {
        if current.count < MIN_SAMPLES {
            return Err(Refusal::FewBlocks(current.count));
        }
        let Some(delta) = solve(&current, n + 2, damping) else {
            return Err(Refusal::Singular);
        };
        let mut trial = state;
        for (p, d) in trial.p.iter_mut().zip(delta.iter().take(n)) {
            *p += d;
        }
        trial.gain += delta[n];
        trial.bias += delta[n + 1];
        let moved = geometry.corner_shift(&state.matrix(), &trial.matrix()) / step;
        if !moved.is_finite() {
            return Err(Refusal::Diverged);
        }
        if let Convergence::Within(bound) = convergence
            && moved < bound
        {
            return Ok((state, current));
        }
        let next = normal(&trial);
        let better = next.count >= MIN_SAMPLES && next.mean_square() <= current.mean_square();
        if better {
            (state, current) = (trial, next);
            damping = (damping / 10.0).max(INITIAL_DAMPING);
            if moved < CONVERGED_PX {
                return Ok((state, current));
            }
        } else {
            if let Convergence::Within(bound) = convergence
                && moved < 2.0 * bound
            {
                return Ok((state, current));
            }
            damping *= 10.0;
            if damping > MAX_DAMPING {
                return Ok((state, current));
            }
        }
    }
    Err(Refusal::NoConvergence)
}

/// The standard deviation, in full-resolution pixels, of the displacement the motion
/// parameters imply: `σ/√λ_min` of the motion block's Schur complement (gain and offset
/// eliminated), in units of displacement at the frame's edge (`s·p`).
fn uncertainty_px(normal: &Normal, motion: usize, geometry: &Geometry) -> f64 {
    let (a, _) = normal.system(motion + 2);
    let amm = a.view((0, 0), (motion, motion));
    let amp = a.view((0, motion), (motion, 2));
    let app = a.view((motion, motion), (2, 2)).into_owned();
    let Some(app_inv) = app.try_inverse() else {
        return f64::INFINITY;
    };
    let schur = amm - amp * app_inv * amp.transpose();
    let smallest = schur
        .symmetric_eigen()
        .eigenvalues
        .iter()
        .copied()
        .fold(f64::INFINITY, f64::min);
    let per_px = smallest / (geometry.s * geometry.s);
    if per_px <= 0.0 {
        return f64::INFINITY;
    }
    let sigma2 = normal.sse / normal.count.max(1) as f64;
    (sigma2 / per_px).sqrt()
}

/// The cluster-robust standard deviation, in full-resolution pixels, of the displacement
/// the motion parameters imply: with `A = Σ wJJᵀ` the normal matrix and `g_c = Σ_{i∈c}
/// w_i r_i J_i` each cell's score (centred on their mean), the parameters' covariance is
/// `A⁻¹ (Σ_c g_c g_cᵀ) A⁻¹`; the largest eigenvalue `λ` of its motion block gives
/// `s·√λ` (`s` the normalisation's half side). Residuals correlated within a cell (a flat
/// patch quantised alike, a response off in one tone) count once per cell, not per block.
fn robust_uncertainty_px(cells: &[Normal], motion: usize, geometry: &Geometry) -> f64 {
    let n = motion + 2;
    let total = cells.iter().cloned().fold(Normal::zero(), Normal::add);
    let (a, _) = total.system(n);
    let Some(a_inv) = a.try_inverse() else {
        return f64::INFINITY;
    };
    let scores: Vec<DVector<f64>> = cells
        .iter()
        .filter(|c| c.count > 0)
        .map(|c| DVector::from_fn(n, |i, _| c.jtr[i]))
        .collect();
    if scores.len() < 2 {
        return f64::INFINITY;
    }
    let mean = scores.iter().fold(DVector::zeros(n), |acc, g| acc + g) / scores.len() as f64;
    let meat = scores.iter().fold(DMatrix::zeros(n, n), |acc, g| {
        let d = g - &mean;
        acc + &d * d.transpose()
    }) * (scores.len() as f64 / (scores.len() - 1) as f64);
    let covariance = &a_inv * meat * &a_inv;
    let largest = covariance
        .view((0, 0), (motion, motion))
        .into_owned()
        .symmetric_eigen()
        .eigenvalues
        .iter()
        .copied()
        .fold(0.0, f64::max);
    geometry.s * largest.sqrt()
}

/// The best integer shift of the coarsest level within [`SEARCH_RANGE`], by normalised
/// cross-correlation over blocks usable in both: `(dx, dy)` in its blocks, or why none.
fn coarse_search(reference: &Level, moving: &Level) -> Result<(i64, i64), Refusal> {
    let (w, h) = (reference.width as i64, reference.height as i64);
    let range = (SEARCH_RANGE * w.max(h) as f64).ceil() as i64 + 1;
    let shifts: Vec<(i64, i64)> = (-range..=range)
        .flat_map(|dy| (-range..=range).map(move |dx| (dx, dy)))
        .collect();
    let scored: Vec<(f64, (i64, i64))> = shifts
        .par_iter()
        .map(|&(dx, dy)| (correlation(reference, moving, dx, dy), (dx, dy)))
        .collect();
    let (best, (dx, dy)) =
        scored.iter().copied().fold(
            (f64::NEG_INFINITY, (0, 0)),
            |a, b| if b.0 > a.0 { b } else { a },
        );
    if best.is_nan() || best < MIN_CORRELATION {
        return Err(Refusal::LowCorrelation(best));
    }
    if dx.abs() == range || dy.abs() == range {
        return Err(Refusal::OutOfRange);
    }
    Ok((dx, dy))
}

/// Zero-mean normalised cross-correlation of `reference(x)` and `moving(x + d)` over the
/// blocks usable in both (−1 when fewer than a quarter of the level's blocks are).
fn correlation(reference: &Level, moving: &Level, dx: i64, dy: i64) -> f64 {
    let (w, h) = (reference.width as i64, reference.height as i64);
    let (mut n, mut sa, mut sb, mut saa, mut sbb, mut sab) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    for y in 0.max(-dy)..h.min(h - dy) {
        for x in 0.max(-dx)..w.min(w - dx) {
            let i = (y * w + x) as usize;
            let k = ((y + dy) * w + x + dx) as usize;
            if reference.usable[i] && moving.usable[k] {
                let (a, b) = (f64::from(reference.log[i]), f64::from(moving.log[k]));
                n += 1.0;
                sa += a;
                sb += b;
                saa += a * a;
                sbb += b * b;
                sab += a * b;
            }
        }
    }
    if n < (w * h) as f64 * MIN_OVERLAP / 4.0 || n < 16.0 {
        return -1.0;
    }
    let cov = sab - sa * sb / n;
    let (va, vb) = (saa - sa * sa / n, sbb - sb * sb / n);
    if va <= 0.0 || vb <= 0.0 {
        return -1.0;
    }
    cov / (va * vb).sqrt()
}

/// The share of the finest level's blocks usable in both frames at the same place.
fn overlap(reference: &Level, moving: &Level) -> f64 {
    let both = reference
        .usable
        .iter()
        .zip(&moving.usable)
        .filter(|&(&a, &b)| a && b)
        .count();
    both as f64 / reference.usable.len().max(1) as f64
}

/// One frame registered onto another: the transform in normalised coordinates (see
/// [`Geometry`]), the model and a note when the model was simplified.
struct Registration {
    matrix: Matrix3<f64>,
    motion: Motion,
    note: Option<String>,
}

/// Every frame's alignment onto frame `reference` (input order), models capped at
/// `model`; with `full` (the frames at full resolution, when the pyramids' finest level
/// has blocks of more than one pixel), each registration on well-exposed blocks is then
/// refined on them ([`full::refine`]).
///
/// Frames are visited outward from the reference in exposure order, the shorter ones and
/// then the longer ones. Each is registered onto the reference; when that fails (most
/// often because the two share too few well-exposed blocks, several stops apart), onto
/// the nearest frame between them in exposure that was registered, and the transforms
/// composed: `T_k = T_{k←n}·T_n` (reference pixel → frame `n` → frame `k`).
pub(super) fn register_all(
    pyramids: &[Pyramid],
    full: Option<&[FullFrame<'_>]>,
    reference: usize,
    geometry: &Geometry,
    model: Motion,
) -> Vec<FrameAlignment> {
    let mut order: Vec<usize> = (0..pyramids.len()).collect();
    order.sort_by(|&a, &b| pyramids[a].exposure.total_cmp(&pyramids[b].exposure));
    let at = order.iter().position(|&k| k == reference).unwrap_or(0);
    let mut results: Vec<FrameAlignment> = (0..pyramids.len())
        .map(|_| FrameAlignment::unmoved(None))
        .collect();
    let shorter = order[..at].iter().rev();
    let longer = order[at + 1..].iter();
    for side in [
        shorter.copied().collect::<Vec<_>>(),
        longer.copied().collect(),
    ] {
        // The frame nearest in exposure that was registered, with its transform.
        let mut via: Option<(usize, Registration)> = None;
        for k in side {
            let pair = Pair {
                pyramids,
                full,
                geometry,
                model,
            };
            let found = register_or_chain(&pair, reference, via.as_ref(), k);
            results[k] = match found {
                Ok(registration) => {
                    let alignment = settle(&registration, geometry);
                    via = Some((k, registration));
                    alignment
                }
                Err(why) => FrameAlignment::unmoved(Some(format!("{why}: not aligned"))),
            };
        }
    }
    results
}

/// What [`register_or_chain`] registers frames with: their pyramids, the frames at full
/// resolution when refined there, the geometry and the most general model.
struct Pair<'p, 'f> {
    pyramids: &'p [Pyramid],
    full: Option<&'p [FullFrame<'f>]>,
    geometry: &'p Geometry,
    model: Motion,
}

/// Frame `k` registered, the first that works of: onto the reference; onto `via` (a
/// registered frame nearer the reference in exposure, with its transform), composed with
/// its transform; the same two on their finer levels only, where a coarse level shared
/// too few blocks, the one sharing more of the finest level's blocks with `k` first (a
/// registration on a small share fits the frame to structure the shared blocks happen to
/// have, extrapolated to the rest); the same two compared as [`Pyramid::clipped_alike`].
/// The registration, or why none worked.
fn register_or_chain(
    with: &Pair<'_, '_>,
    reference: usize,
    via: Option<&(usize, Registration)>,
    k: usize,
) -> Result<Registration, Failures> {
    let (geometry, model) = (with.geometry, with.model);
    let mut targets = vec![(reference, None)];
    if let Some((n, through)) = via {
        targets.push((*n, Some(through)));
    }
    let shared = |n: usize| overlap(&with.pyramids[n].levels[0], &with.pyramids[k].levels[0]);
    let mut failures: Vec<Failure> = Vec::new();
    for way in [Way::Measured, Way::FinerLevels, Way::ClippedAlike] {
        let mut order = targets.clone();
        if way == Way::FinerLevels {
            order.sort_by(|a, b| shared(b.0).total_cmp(&shared(a.0)));
        }
        for &(n, through) in &order {
            let sparse = |f: &Failure| f.onto == n && matches!(f.why, Refusal::FewBlocks(_));
            if way == Way::FinerLevels && !failures.iter().any(sparse) {
                // Only a coarse level that shared too few blocks makes this way differ.
                continue;
            }
            let (fixed, moving) = (&with.pyramids[n], &with.pyramids[k]);
            let full = with.full.map(|frames| (&frames[n], &frames[k]));
            let found = match way {
                Way::Measured => register(fixed, moving, full, geometry, model, false),
                Way::FinerLevels => register(fixed, moving, full, geometry, model, true),
                Way::ClippedAlike => register_clipped(fixed, moving, geometry, model),
            };
            match found {
                Ok(step) => return Ok(compose(step, through, n, reference, way)),
                Err(why) => failures.push(Failure { onto: n, way, why }),
            }
        }
    }
    Err(Failures(failures))
}

/// A registration onto frame `n` (`through` its own transform when `n` is not the
/// reference) as a registration onto the reference, its note saying how it was reached.
fn compose(
    step: Registration,
    through: Option<&Registration>,
    n: usize,
    reference: usize,
    way: Way,
) -> Registration {
    let mut how = Vec::new();
    if n != reference {
        how.push(format!("registered through frame {n}"));
    }
    match way {
        Way::Measured => {}
        Way::FinerLevels => how.push("registered on the finer levels only".to_string()),
        Way::ClippedAlike => how.push("compared where both clip alike".to_string()),
    }
    how.extend(step.note);
    let (matrix, motion) = match through {
        Some(t) => (step.matrix * t.matrix, step.motion.max(t.motion)),
        None => (step.matrix, step.motion),
    };
    Registration {
        matrix,
        motion,
        note: (!how.is_empty()).then(|| how.join("; ")),
    }
}

/// The alignment a registration gives a frame: the identity when it moves no pixel by
/// [`IDENTITY_PX`] or more.
fn settle(registration: &Registration, geometry: &Geometry) -> FrameAlignment {
    let displacement = geometry.displacement(&registration.matrix);
    let note = registration.note.clone();
    if displacement < IDENTITY_PX {
        FrameAlignment {
            displacement_px: displacement,
            ..FrameAlignment::unmoved(note)
        }
    } else {
        FrameAlignment {
            transform: geometry.pixel_matrix(&registration.matrix),
            motion: Some(registration.motion),
            displacement_px: displacement,
            note,
        }
    }
}

/// Frame `moving` registered onto frame `fixed` (see the parent module's docs for the
/// steps and the fallbacks), or why it cannot be; with `skip_sparse`, a level above the
/// finest whose shared blocks are too few to refine on is passed over; with `full` (the
/// two frames at full resolution), the pyramid's estimate is refined on them (and its
/// finest level converges [`Convergence::Within`] [`ROUGH_PX`]).
fn register(
    fixed: &Pyramid,
    moving: &Pyramid,
    full: Option<(&FullFrame<'_>, &FullFrame<'_>)>,
    geometry: &Geometry,
    model: Motion,
    skip_sparse: bool,
) -> Result<Registration, Refusal> {
    let finest = if full.is_some() {
        Convergence::Within(ROUGH_PX)
    } else {
        Convergence::Final
    };
    let schedule = Schedule {
        skip_sparse,
        finest,
    };
    let (mut state, normal, note) =
        estimate(&fixed.levels, &moving.levels, geometry, model, schedule)?;
    if let Some((f, m)) = full {
        let still = |s: &State| geometry.displacement(&s.matrix()) < IDENTITY_PX;
        if still(&state) {
            let (fine_fixed, fine_moving) = (&fixed.levels[0], &moving.levels[0]);
            let at = |s: &State| accumulate(fine_fixed, fine_moving, geometry, s, s.params());
            let step = fine_fixed.step;
            let finished = damped(geometry, step, state, normal, &at, Convergence::Final);
            state = finished.map_or(state, |(s, _)| s);
        }
        if !still(&state) {
            state = full::refine(f, m, geometry, state, fixed.levels[0].step);
        }
    }
    let finest = (&fixed.levels[0], &moving.levels[0]);
    let moved = geometry.displacement(&state.matrix());
    let still = (moved >= IDENTITY_PX).then(|| {
        no_better_locally(finest, geometry, &state, moved)
            .map(Ok)
            .or_else(|| insignificant(finest, geometry, &state, moved))
    });
    if let Some(why) = still.flatten() {
        let why = why?;
        return Ok(Registration {
            matrix: Matrix3::identity(),
            motion: Motion::Translation,
            note: Some(why),
        });
    }
    Ok(Registration {
        matrix: state.matrix(),
        motion: state.motion,
        note,
    })
}

/// Whether `state`, which moves some pixel by `moved` px, is within
/// [`SIGNIFICANT_SPREADS`] cluster-robust standard deviations of its displacement on the
/// finest levels ([`robust_uncertainty_px`]) of no move: `None` when it is not; why it
/// counts as no move when it is (a frame registered on blocks that crowd into part of it,
/// several stops from the other, fits its parameters to structure the residuals share,
/// and a still frame would be resampled); [`Refusal::Undetermined`] when that standard
/// deviation also exceeds [`STILL_SPREAD_PX`]: the registration then tells neither a move
/// nor stillness, and another way is tried (a frame registered through a neighbour would
/// otherwise keep the neighbour's transform, however far it moved from it).
fn insignificant(
    (fine_fixed, fine_moving): (&Level, &Level),
    geometry: &Geometry,
    state: &State,
    moved: f64,
) -> Option<Result<String, Refusal>> {
    let params = state.params();
    let cells = accumulate_cells(fine_fixed, fine_moving, geometry, state, params);
    let spread = robust_uncertainty_px(&cells, params, geometry);
    if moved > SIGNIFICANT_SPREADS * spread {
        return None;
    }
    if spread > STILL_SPREAD_PX {
        return Some(Err(Refusal::Undetermined(spread)));
    }
    Some(Ok(format!(
        "a move of {moved:.2} px is within {SIGNIFICANT_SPREADS} standard deviations \
         of none (σ {spread:.2} px): not moved"
    )))
}

/// The largest cluster-robust standard deviation, in pixels, of a registration's
/// displacement for [`insignificant`] to call the frame still.
const STILL_SPREAD_PX: f64 = 1.0;

/// Why `state`, which moves some pixel by `moved` px, counts as no move, when it fits the
/// finest levels better than the identity in too few cells of a [`CELLS`] ×
/// [`CELLS`] grid, each cell with its own gain and offset
/// ([`Normal::fitted_mean_square`]). A sign test: were the frame still, each cell would
/// be as likely to favour the state as not, so the state must win more than
/// `n/2 + k·√n/2` of the `n` cells both fits measure, `k` = [`SIGNIFICANT_SPREADS`]. A
/// camera's move lowers the residual in nearly every cell with texture; a brightness that
/// varies across the frame (flare, vignetting, a camera's local tone mapping), which one
/// gain and offset for the whole frame leave for the motion to fit, the cells match.
fn no_better_locally(
    (fine_fixed, fine_moving): (&Level, &Level),
    geometry: &Geometry,
    state: &State,
    moved: f64,
) -> Option<String> {
    let unmoved = State {
        p: [0.0; 8],
        ..*state
    };
    let at_state = accumulate_cells(fine_fixed, fine_moving, geometry, state, 0);
    let at_identity = accumulate_cells(fine_fixed, fine_moving, geometry, &unmoved, 0);
    let measured = |cell: &Normal| cell.count > 2;
    let (cells, better) = at_state
        .iter()
        .zip(&at_identity)
        .filter(|(a, b)| measured(a) && measured(b))
        .fold((0usize, 0usize), |(cells, better), (a, b)| {
            let wins = a.fitted_mean_square(2) < b.fitted_mean_square(2);
            (cells + 1, better + usize::from(wins))
        });
    let n = cells as f64;
    (better as f64 <= n / 2.0 + SIGNIFICANT_SPREADS * n.sqrt() / 2.0).then(|| {
        format!(
            "a move of {moved:.2} px fits better than none in {better} of {cells} parts of \
             the frame, each with its brightness matched: not moved"
        )
    })
}

/// [`register`] on the two frames compared as [`Pyramid::clipped_alike`], kept unless
/// the blocks both frames measure well, refined from it, move it by more than
/// [`CLIPPED_AGREEMENT_PX`] and by more than three standard deviations of the refined
/// displacement (`σ/√λ_min`, the parent module's uncertainty): a clipped edge that moved
/// between the frames, by flare or the camera's local tone mapping, must not pass for
/// the scene.
fn register_clipped(
    fixed: &Pyramid,
    moving: &Pyramid,
    geometry: &Geometry,
    model: Motion,
) -> Result<Registration, Refusal> {
    let Some((clamped_fixed, clamped_moving)) = fixed.clipped_alike(moving) else {
        return Err(Refusal::NoCommonRange);
    };
    let schedule = Schedule {
        skip_sparse: false,
        finest: Convergence::Final,
    };
    let (state, _, note) = estimate(&clamped_fixed, &clamped_moving, geometry, model, schedule)?;
    let fine = (&fixed.levels[0], &moving.levels[0]);
    // Too few well-exposed blocks in common to refine: nothing contradicts the edges.
    if let Ok((refined, normal)) = refine(fine, geometry, state, Convergence::Final) {
        let apart = geometry.corner_shift(&state.matrix(), &refined.matrix());
        let spread = uncertainty_px(&normal, refined.params(), geometry);
        if apart > CLIPPED_AGREEMENT_PX.max(3.0 * spread) {
            return Err(Refusal::ClippedEdgesMoved { apart, spread });
        }
    }
    Ok(Registration {
        matrix: state.matrix(),
        motion: state.motion,
        note,
    })
}

/// The largest distance, in pixels, between a registration on clipped edges and its
/// refinement on the tones both frames measure for the first to be kept.
const CLIPPED_AGREEMENT_PX: f64 = 1.0;

/// How [`descend`] goes down the levels.
#[derive(Debug, Clone, Copy)]
struct Schedule {
    /// A level above the finest whose shared blocks are too few to refine on is passed
    /// over.
    skip_sparse: bool,
    /// How far the finest level converges; the coarser ones, [`Convergence::Within`] [`ROUGH_PX`].
    finest: Convergence,
}

/// The state of [`register`], its normal equations on the finest level and a note when
/// the model was simplified.
fn estimate(
    fixed: &[Level],
    moving: &[Level],
    geometry: &Geometry,
    model: Motion,
    schedule: Schedule,
) -> Result<(State, Normal, Option<String>), Refusal> {
    let (fine_fixed, fine_moving) = (&fixed[0], &moving[0]);
    let shared = overlap(fine_fixed, fine_moving);
    if shared < MIN_OVERLAP {
        return Err(Refusal::LittleOverlap { shared });
    }
    let (state, normal, note) = descend(fixed, moving, geometry, model, schedule)?;
    let displacement = geometry.displacement(&state.matrix());
    let farthest = 2.0 * SEARCH_RANGE * geometry.width.max(geometry.height);
    if displacement > farthest {
        return Err(Refusal::TooFar {
            displacement,
            farthest,
        });
    }
    // Only a move (of some pixel by IDENTITY_PX) must fit better than none.
    if displacement >= IDENTITY_PX {
        let still = identity_rms(fine_fixed, fine_moving, geometry);
        if normal.rms() >= still {
            return Err(Refusal::NoBetter {
                displacement,
                moved: normal.rms(),
                still,
            });
        }
    }
    Ok((state, normal, note))
}

/// The coarse search, then Gauss–Newton from the coarsest level to the finest (the
/// model's schedule in the parent module's docs), then the model simplified while its
/// parameters are not determined: the state, the finest level's normal equations and a
/// note when the model was simplified.
fn descend(
    reference: &[Level],
    moving: &[Level],
    geometry: &Geometry,
    model: Motion,
    schedule: Schedule,
) -> Result<(State, Normal, Option<String>), Refusal> {
    let top = reference.len().min(moving.len()) - 1;
    let (dx, dy) = coarse_search(&reference[top], &moving[top])?;
    let scale = reference[top].step / geometry.s;
    let mut state = State {
        motion: Motion::Translation,
        p: [
            dx as f64 * scale,
            dy as f64 * scale,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
        ],
        gain: 1.0,
        bias: 0.0,
    };
    let mut finest = None;
    for level in (0..=top).rev() {
        let target = if level == top {
            Motion::Translation
        } else {
            model
        };
        if state.motion != target {
            state = state.as_motion(target);
        }
        let start = state;
        let convergence = if level == 0 {
            schedule.finest
        } else {
            Convergence::Within(ROUGH_PX)
        };
        let pair = (&reference[level], &moving[level]);
        match refine(pair, geometry, state, convergence) {
            Ok((refined, normal)) => {
                state = refined;
                if level == 0 {
                    finest = Some((start, normal));
                }
            }
            // A coarse level can hold too few shared blocks where the finer ones do not:
            // the finer level starts from where this one would have.
            Err(Refusal::FewBlocks(_)) if schedule.skip_sparse && level > 0 => {}
            Err(why) => return Err(why),
        }
    }
    let Some((start, normal)) = finest else {
        return Err(Refusal::NoLevel);
    };
    let fine = (&reference[0], &moving[0]);
    let kept = Kept {
        state,
        normal,
        start,
    };
    let (kept, note) = determined(fine, geometry, kept, schedule.finest)?;
    let kept = significant(fine, geometry, kept, schedule.finest);
    Ok((kept.state, kept.normal, note))
}

/// The finest level's result: the state, its normal equations and the state the level
/// started from (what [`significant`] refines the rigid model from).
struct Kept {
    state: State,
    normal: Normal,
    start: State,
}

/// `kept` simplified while its model's parameters are not determined
/// ([`MAX_UNCERTAINTY_BLOCKS`]), with a note when it was; why not, when even a
/// translation is not. Each simpler model is refined from the estimate it replaces, as
/// near as it can express it ([`State::as_motion`]): the level may have started far from
/// the move (from a coarse level that ran off), and only the model refined there came
/// back to it.
fn determined(
    fine: (&Level, &Level),
    geometry: &Geometry,
    mut kept: Kept,
    convergence: Convergence,
) -> Result<(Kept, Option<String>), Refusal> {
    let mut note = None;
    loop {
        let spread = uncertainty_px(&kept.normal, kept.state.params(), geometry);
        if spread <= MAX_UNCERTAINTY_BLOCKS * fine.0.step {
            return Ok((kept, note));
        }
        let Some(simpler) = kept.state.motion.simpler() else {
            return Err(Refusal::Undetermined(spread));
        };
        note = Some(format!(
            "the texture does not determine a {} model (±{spread:.2} px): {} used",
            kept.state.motion.as_str(),
            simpler.as_str()
        ));
        (kept.state, kept.normal) =
            refine(fine, geometry, kept.state.as_motion(simpler), convergence)?;
    }
}

/// `kept` as the rigid model, refined from the same start, when it is a homography that
/// moves no corner from that rigid fit by more than [`SIGNIFICANT_SPREADS`] cluster-robust
/// standard deviations ([`robust_uncertainty_px`]) or [`SIGNIFICANT_BLOCKS`]: its
/// perspective and scale then fit the residuals' correlated structure (a flat patch
/// quantised alike, a dark frame's noise where the shared blocks crowd into part of the
/// frame), extrapolated to corners no shared block reaches, and would resample a still
/// frame. A rotation is not tested so: the whole support determines it, and a nudged
/// tripod's tenth of a degree must be kept. A homography that moves no pixel by
/// [`IDENTITY_PX`] leaves the frame still under either model: it yields to the rigid
/// model refined from it, without the test.
fn significant(
    fine: (&Level, &Level),
    geometry: &Geometry,
    kept: Kept,
    convergence: Convergence,
) -> Kept {
    if kept.state.motion != Motion::Homography {
        return kept;
    }
    let still = geometry.displacement(&kept.state.matrix()) < IDENTITY_PX;
    let from = if still { kept.state } else { kept.start };
    let Ok((rigid, normal)) = refine(fine, geometry, from.as_motion(Motion::Rigid), convergence)
    else {
        return kept;
    };
    if !still {
        let params = kept.state.params();
        let cells = accumulate_cells(fine.0, fine.1, geometry, &kept.state, params);
        let spread = robust_uncertainty_px(&cells, params, geometry);
        let apart = geometry.corner_shift(&kept.state.matrix(), &rigid.matrix());
        if apart > (SIGNIFICANT_SPREADS * spread).max(SIGNIFICANT_BLOCKS * fine.0.step) {
            return kept;
        }
    }
    Kept {
        state: rigid,
        normal,
        ..kept
    }
}

/// How many cluster-robust standard deviations a homography must move a corner by, from
/// the rigid fit, to be kept, and a registration must move a pixel by to move the frame.
const SIGNIFICANT_SPREADS: f64 = 3.0;

/// The least a homography must move a corner by, from the rigid fit, to be kept, in
/// blocks of the finest level (1 px for a 24 MP raw): the blocks bound the estimate's
/// precision.
const SIGNIFICANT_BLOCKS: f64 = 0.1;

/// The residual's RMS without moving the frame, gain and offset fitted.
fn identity_rms(reference: &Level, moving: &Level, geometry: &Geometry) -> f64 {
    let mut state = State {
        motion: Motion::Translation,
        p: [0.0; 8],
        gain: 1.0,
        bias: 0.0,
    };
    let normal = accumulate(reference, moving, geometry, &state, 0);
    if let Some(delta) = solve(&normal, 2, 0.0) {
        state.gain += delta[0];
        state.bias += delta[1];
    }
    accumulate(reference, moving, geometry, &state, 0).rms()
}

#[cfg(test)]
mod tests;
