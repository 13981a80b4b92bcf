//! Per-channel brightness histograms, their cumulative form, and the intensity mapping
//! `τ(b) = H_B⁻¹(H_A(b))` between two exposures of one scene (Grossberg & Nayar 2003).
//!
//! **Bins.** An 8-bit frame has one bin per code (256 bins). A 16-bit frame is binned to
//! 4096 bins of 16 codes each (`bin = code >> 4`): real 16-bit files carry at most 12–14
//! bits of signal, so finer bins would only hold noise, and 4096 bins keep thousands of
//! pixels per bin and the fit small. Bin `k` of width `w` codes holds codes
//! `k·w ..= k·w + w − 1`; as brightness (`B = code / max_code`) it spans the interval
//! between the edges `e_k = (k·w − ½) / max_code` and `e_{k+1}`, clamped to `[0, 1]`
//! (a code stands for everything that rounds to it).
//!
//! **Cumulative histogram.** Each bin is treated as a uniform spread of its pixels over its
//! interval, so `H(b)` (fraction of pixels darker than `b`) is continuous, piecewise
//! linear, and invertible on its rising parts.
//!
//! **One pass.** [`Histogram::of_frame`] visits every `stride`-th pixel of every
//! `stride`-th row once; frames above about a megapixel are split into row bands counted
//! on all cores (rayon) and summed.

use std::borrow::Cow;

use rayon::prelude::*;

use crate::frame::{BitDepth, Compression, Frame, Samples};

/// Number of bins used for a bit depth: 256 for 8-bit, 4096 for 16-bit (see module docs).
fn bins_for(depth: BitDepth) -> usize {
    match depth {
        BitDepth::Eight => 256,
        BitDepth::Sixteen => 4096,
    }
}

/// Pixel counts per channel and bin of one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Histogram {
    depth: BitDepth,
    compression: Compression,
    counts: Vec<Vec<u64>>,
}

/// Pixels per parallel work unit; below this a frame is counted on one core.
const BAND_PIXELS: usize = 1 << 20;

impl Histogram {
    /// Counts every `stride`-th pixel of every `stride`-th row (`stride` 0 reads as 1),
    /// per channel, in one pass. Stride `s` reads about `1/s²` of the pixels.
    pub fn of_frame(frame: &Frame, stride: usize) -> Histogram {
        let stride = stride.max(1);
        let depth = frame.bit_depth();
        let channels = frame.channels();
        let bins = bins_for(depth);
        let shift = depth.bits() - bins.trailing_zeros();
        let row_len = frame.width() as usize * channels;
        let rows: Vec<usize> = (0..frame.height() as usize).step_by(stride).collect();
        let sampled_row = frame.width() as usize / stride + 1;
        let band_rows = (BAND_PIXELS / sampled_row.max(1)).max(1);
        // Counts are gathered channel-interleaved (`bin·channels + c`) for a tight inner loop.
        let count_rows = |rows: &[usize]| -> Vec<u64> {
            let mut counts = vec![0u64; bins * channels];
            for &y in rows {
                let start = y * row_len;
                match frame.samples() {
                    Samples::Eight(v) => {
                        for px in v[start..start + row_len]
                            .chunks_exact(channels)
                            .step_by(stride)
                        {
                            for (c, &code) in px.iter().enumerate() {
                                counts[usize::from(code) * channels + c] += 1;
                            }
                        }
                    }
                    Samples::Sixteen(v) => {
                        for px in v[start..start + row_len]
                            .chunks_exact(channels)
                            .step_by(stride)
                        {
                            for (c, &code) in px.iter().enumerate() {
                                counts[(usize::from(code) >> shift) * channels + c] += 1;
                            }
                        }
                    }
                }
            }
            counts
        };
        let interleaved = if rows.len() <= band_rows {
            count_rows(&rows)
        } else {
            rows.par_chunks(band_rows).map(count_rows).reduce(
                || vec![0u64; bins * channels],
                |mut a, b| {
                    a.iter_mut().zip(&b).for_each(|(x, y)| *x += y);
                    a
                },
            )
        };
        let counts = (0..channels)
            .map(|c| {
                interleaved
                    .iter()
                    .skip(c)
                    .step_by(channels)
                    .copied()
                    .collect()
            })
            .collect();
        Histogram {
            depth,
            compression: frame.compression(),
            counts,
        }
    }

    /// Bit depth of the frame that was counted.
    pub fn depth(&self) -> BitDepth {
        self.depth
    }

    /// How the counted frame's file stored its samples.
    pub fn compression(&self) -> Compression {
        self.compression
    }

    /// Number of channels.
    pub fn channels(&self) -> usize {
        self.counts.len()
    }

    /// Number of bins per channel.
    pub fn bins(&self) -> usize {
        bins_for(self.depth)
    }

    /// Counts of channel `c`, one per bin.
    pub fn counts(&self, c: usize) -> &[u64] {
        &self.counts[c]
    }

    /// Number of pixels counted (per channel).
    pub fn total(&self) -> u64 {
        self.counts[0].iter().sum()
    }

    /// The cumulative histogram of channel `c`.
    pub fn cumulative(&self, c: usize) -> Cumulative {
        Cumulative::new(self.depth, &self.counts[c])
    }
}

/// Side in pixels of the blocks a lossy frame is judged by: a JPEG's largest coding unit
/// (16×16 at 4:2:0 chroma subsampling, four 8×8 blocks at 4:4:4), on the grid that starts
/// at the image's top-left corner. The DCT's ringing around a clipped sample stays inside
/// its coding unit.
pub const CODING_BLOCK: usize = 16;

/// Side in pixels of the cells that share one chroma sample at 4:2:0, the unit by which a
/// block's pixels are left out ([`shared_counts`]).
const CHROMA_CELL: usize = 2;

/// Cells per row of a coding block.
const CELLS_PER_ROW: usize = CODING_BLOCK / CHROMA_CELL;

/// How far below full scale, as a fraction of it, a block's darkest sample must lie for a
/// clipped sample in it to make a hard edge (96/255: a sample at code 159 or darker of an
/// 8-bit frame). The ringing of a block grows with the step the codec must encode; a
/// highlight that clips softly, over a smooth gradient, leaves its block's near-white
/// tones where they were, and those tones are what shows the top of the curve.
pub const HARD_EDGE: f64 = 96.0 / 255.0;

/// What one coding block of a lossy frame holds: how many of its cells hold a clipped
/// sample (saturating at 2) and, when that is one, which (row-major within the block);
/// whether it holds a sample [`HARD_EDGE`] below full scale.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct BlockClip {
    clipped_cells: u8,
    clipped_cell: u8,
    dark: bool,
}

impl BlockClip {
    /// True if the block clips over a hard edge.
    fn hard(self) -> bool {
        self.dark && self.clipped_cells > 0
    }

    /// True if cell `k` of the block is left out: the block clips over a hard edge and a
    /// cell other than `k` holds a clipped sample.
    fn leaves_out(self, k: usize) -> bool {
        self.dark
            && (self.clipped_cells >= 2
                || (self.clipped_cells == 1 && usize::from(self.clipped_cell) != k))
    }

    /// Records that cell `k` holds a clipped sample.
    fn clip(&mut self, k: usize) {
        match self.clipped_cells {
            0 => {
                self.clipped_cells = 1;
                self.clipped_cell = k as u8;
            }
            1 if usize::from(self.clipped_cell) != k => self.clipped_cells = 2,
            _ => {}
        }
    }
}

/// A frame's histogram together with what pairing it with another frame needs: for a
/// lossy frame, its coding blocks that clip over a hard edge ([`shared_counts`]).
#[derive(Debug, Clone)]
pub struct FrameCounts<'a> {
    frame: &'a Frame,
    stride: usize,
    histogram: Histogram,
    /// Per block, row-major; empty when no block clips over a hard edge (always for a
    /// lossless frame).
    blocks: Vec<BlockClip>,
}

impl<'a> FrameCounts<'a> {
    /// Counts `frame` as [`Histogram::of_frame`] does and, if it is lossy, finds its
    /// blocks that clip over a hard edge (every pixel is looked at, whatever the stride).
    pub fn of_frame(frame: &'a Frame, stride: usize) -> FrameCounts<'a> {
        let stride = stride.max(1);
        let histogram = Histogram::of_frame(frame, stride);
        let blocks = match frame.compression() {
            Compression::Lossless => Vec::new(),
            Compression::Lossy => hard_clipped_blocks(frame),
        };
        FrameCounts {
            frame,
            stride,
            histogram,
            blocks,
        }
    }

    /// The whole frame's histogram.
    pub fn histogram(&self) -> &Histogram {
        &self.histogram
    }

    /// Number of coding blocks that clip over a hard edge (0 for a lossless frame).
    pub fn hard_clipped_blocks(&self) -> usize {
        self.blocks.iter().filter(|b| b.hard()).count()
    }

    /// The histogram of the sampled pixels that neither `self`'s blocks nor `other`'s
    /// (a frame of the same size) leave out.
    fn without(&self, other: &FrameCounts<'_>) -> Histogram {
        let frame = self.frame;
        let (w, h) = (frame.width() as usize, frame.height() as usize);
        let blocks_x = w.div_ceil(CODING_BLOCK);
        let channels = frame.channels();
        let shift = frame.bit_depth().bits() - self.histogram.bins().trailing_zeros();
        let mut counts = self.histogram.counts.clone();
        let s = self.stride;
        let block = |blocks: &[BlockClip], i: usize| blocks.get(i).copied().unwrap_or_default();
        for i in 0..blocks_x * h.div_ceil(CODING_BLOCK) {
            let (a, b) = (block(&self.blocks, i), block(&other.blocks, i));
            if !a.hard() && !b.hard() {
                continue;
            }
            let (x0, y0) = ((i % blocks_x) * CODING_BLOCK, (i / blocks_x) * CODING_BLOCK);
            // The sampled rows and columns are the multiples of the stride.
            let first = |v0: usize| v0.div_ceil(s) * s;
            for y in (first(y0)..(y0 + CODING_BLOCK).min(h)).step_by(s) {
                for x in (first(x0)..(x0 + CODING_BLOCK).min(w)).step_by(s) {
                    let k = (y - y0) / CHROMA_CELL * CELLS_PER_ROW + (x - x0) / CHROMA_CELL;
                    if !a.leaves_out(k) && !b.leaves_out(k) {
                        continue;
                    }
                    let at = (y * w + x) * channels;
                    for (c, bins) in counts.iter_mut().enumerate() {
                        let bin = match frame.samples() {
                            Samples::Eight(v) => usize::from(v[at + c]),
                            Samples::Sixteen(v) => usize::from(v[at + c]) >> shift,
                        };
                        bins[bin] -= 1;
                    }
                }
            }
        }
        Histogram {
            depth: self.histogram.depth,
            compression: self.histogram.compression,
            counts,
        }
    }
}

/// `frame`'s coding blocks ([`BlockClip`], row-major); empty if none clips over a hard
/// edge. A pixel is clipped if any of its samples is at full scale, dark if any is at
/// least [`HARD_EDGE`] below it.
fn hard_clipped_blocks(frame: &Frame) -> Vec<BlockClip> {
    let (w, h) = (frame.width() as usize, frame.height() as usize);
    let blocks_x = w.div_ceil(CODING_BLOCK);
    let mut blocks = vec![BlockClip::default(); blocks_x * h.div_ceil(CODING_BLOCK)];
    blocks
        .par_chunks_mut(blocks_x)
        .enumerate()
        .for_each(|(by, row_of_blocks)| match frame.samples() {
            Samples::Eight(v) => mark_blocks(frame, v, by, row_of_blocks),
            Samples::Sixteen(v) => mark_blocks(frame, v, by, row_of_blocks),
        });
    if blocks.iter().any(|b| b.hard()) {
        blocks
    } else {
        Vec::new()
    }
}

/// Marks the blocks of block row `by` of `frame` (samples `v`): each 16-pixel run of a
/// row is scanned for its darkest and brightest sample at once (a vectorised pass), and
/// only a run that reaches full scale is looked at pixel by pixel for its clipped cells.
fn mark_blocks<T: Copy + Ord + Into<u32>>(
    frame: &Frame,
    v: &[T],
    by: usize,
    row_of_blocks: &mut [BlockClip],
) {
    let (w, h) = (frame.width() as usize, frame.height() as usize);
    let channels = frame.channels();
    let max = frame.bit_depth().max_code();
    let dark_below = max - (f64::from(max) * HARD_EDGE).round() as u32;
    let row_len = w * channels;
    for y in by * CODING_BLOCK..((by + 1) * CODING_BLOCK).min(h) {
        let row = &v[y * row_len..(y + 1) * row_len];
        for (block, run) in row_of_blocks
            .iter_mut()
            .zip(row.chunks(CODING_BLOCK * channels))
        {
            if block.dark && block.clipped_cells >= 2 {
                continue;
            }
            let first = run[0];
            let lo = run.iter().copied().fold(first, Ord::min);
            let hi = run.iter().copied().fold(first, Ord::max);
            block.dark |= lo.into() <= dark_below;
            if hi.into() < max || block.clipped_cells >= 2 {
                continue;
            }
            for (x, pixel) in run.chunks_exact(channels).enumerate() {
                if pixel.iter().any(|&c| c.into() == max) {
                    let k = y % CODING_BLOCK / CHROMA_CELL * CELLS_PER_ROW + x / CHROMA_CELL;
                    block.clip(k);
                }
            }
        }
    }
}

/// The histograms of two frames of one scene counted over the same pixels. Where either
/// frame is lossy, a pixel is left out of both when its [`CODING_BLOCK`], in either frame,
/// clips over a hard edge (holds a clipped sample and one [`HARD_EDGE`] below full scale)
/// outside the pixel's own chroma cell (the 2×2 pixels that share a chroma sample at
/// 4:2:0). The codec's ringing next to clipped highlights then enters neither frame,
/// `τ = H_B⁻¹ ∘ H_A` still matches the same scene points, and whether a pixel is counted
/// does not depend on its own noise: a rule that looked at the pixel itself would keep,
/// next to white, only the pixels whose noise held them below it, and bias the top of `τ`
/// low. The frames must be aligned (a tripod bracket); frames of different sizes, or
/// without such blocks, give their whole histograms.
pub fn shared_counts<'h>(
    a: &'h FrameCounts<'_>,
    b: &'h FrameCounts<'_>,
) -> (Cow<'h, Histogram>, Cow<'h, Histogram>) {
    let same_size = a.frame.width() == b.frame.width() && a.frame.height() == b.frame.height();
    if !same_size || (a.blocks.is_empty() && b.blocks.is_empty()) {
        return (Cow::Borrowed(&a.histogram), Cow::Borrowed(&b.histogram));
    }
    (Cow::Owned(a.without(b)), Cow::Owned(b.without(a)))
}

/// A normalised cumulative histogram `H(b)`, piecewise linear between bin edges.
#[derive(Debug, Clone, PartialEq)]
pub struct Cumulative {
    /// Bin edges in brightness, `L + 1` values from 0 to 1, increasing.
    edges: Vec<f64>,
    /// `H` at each edge: fraction of pixels in the bins below it; `0 … 1`.
    at_edges: Vec<f64>,
    /// Pixels in each bin.
    counts: Vec<u64>,
}

impl Cumulative {
    fn new(depth: BitDepth, counts: &[u64]) -> Cumulative {
        let bins = counts.len();
        let max_code = f64::from(depth.max_code());
        let width = (depth.levels() / bins) as f64;
        let edges = (0..=bins)
            .map(|k| ((k as f64 * width - 0.5) / max_code).clamp(0.0, 1.0))
            .collect();
        let total = counts.iter().sum::<u64>().max(1) as f64;
        let mut running = 0u64;
        let mut at_edges = Vec::with_capacity(bins + 1);
        at_edges.push(0.0);
        for &n in counts {
            running += n;
            at_edges.push(running as f64 / total);
        }
        Cumulative {
            edges,
            at_edges,
            counts: counts.to_vec(),
        }
    }

    /// Bin edges in brightness (`bins + 1` values).
    pub fn edges(&self) -> &[f64] {
        &self.edges
    }

    /// `H` at each bin edge.
    pub fn at_edges(&self) -> &[f64] {
        &self.at_edges
    }

    /// Pixels in each bin.
    pub fn counts(&self) -> &[u64] {
        &self.counts
    }

    /// The bin holding brightness `b` (clamped to the valid range).
    fn bin_of(&self, b: f64) -> usize {
        let k = self.edges.partition_point(|&e| e <= b);
        k.clamp(1, self.counts.len()) - 1
    }

    /// `H(b)`: fraction of pixels darker than brightness `b`, linear within a bin.
    pub fn at(&self, b: f64) -> f64 {
        let k = self.bin_of(b);
        let (e0, e1) = (self.edges[k], self.edges[k + 1]);
        let f = if e1 > e0 {
            ((b - e0) / (e1 - e0)).clamp(0.0, 1.0)
        } else {
            0.0
        };
        self.at_edges[k] + f * (self.at_edges[k + 1] - self.at_edges[k])
    }

    /// `H⁻¹(q)`: the brightness below which a fraction `q` of the pixels lies, linear
    /// within the bin that holds the `q`-quantile; also returns that bin.
    pub fn inverse(&self, q: f64) -> (f64, usize) {
        let q = q.clamp(0.0, 1.0);
        // First edge whose H reaches q: the quantile lies in the bin just below it.
        let j = self.at_edges.partition_point(|&h| h < q);
        let k = j.clamp(1, self.counts.len()) - 1;
        let (h0, h1) = (self.at_edges[k], self.at_edges[k + 1]);
        let f = if h1 > h0 {
            ((q - h0) / (h1 - h0)).clamp(0.0, 1.0)
        } else {
            0.0
        };
        (self.edges[k] + f * (self.edges[k + 1] - self.edges[k]), k)
    }
}

/// One tone correspondence `b ↦ τ(b)` between the darker frame A and the brighter frame B,
/// with the standard deviations (brightness units) of each side.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TonePair {
    /// Brightness in the darker frame.
    pub dark: f64,
    /// The corresponding brightness in the brighter frame, `τ(dark)`.
    pub bright: f64,
    /// Standard deviation of `dark` (brightness units).
    pub sigma_dark: f64,
    /// Standard deviation of `bright` (brightness units).
    pub sigma_bright: f64,
    /// The fraction of pixels darker than this tone, `H_A(dark) = H_B(bright)`.
    pub quantile: f64,
}

/// The tone range of one frame-channel that carries information: above the noise floor and
/// below clipping, in brightness.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UsableTones {
    /// Lowest usable brightness.
    pub floor: f64,
    /// Highest usable brightness.
    pub ceiling: f64,
}

impl UsableTones {
    /// Default limits, tightened where the histogram shows a clipping spike.
    ///
    /// Noise spreads the darkest tones over the codes next to black and bends the
    /// histogram there; with a nominal noise of 1 DN of an 8-bit frame (`1/255`) the floor
    /// is kept 2.5 of it inside: `2.5/255` at either depth. At the top it depends on the
    /// file ([`Compression`]). A lossless frame is trusted to half a code (`0.5/255`) from
    /// full scale: a camera clips after its noise, so a clipped pixel reads exactly full
    /// scale, noise only blurs the histogram below as it does at every tone, and the edge
    /// of the clipped bin is exact. A JPEG keeps the 2.5/255 margin: the DCT blocks that
    /// hold clipped areas ring and move their unclipped neighbours by a few codes.
    /// Measured on the DoRF curves at ratio 4 (`benches/accuracy/response_accuracy.rs`, 8-bit
    /// lossless, own-normalisation median): 2.5 → 0.022 stops, 1.5 → 0.021, 0.5 → 0.020
    /// (shape error unchanged); JPEG q95 with 0.5 at ratio 16: shape p90 0.19 → 0.47.
    ///
    /// A spike — an end bin (or the last bin holding pixels) with more than 0.2 % of the
    /// pixels and more than four times its neighbours' mean — marks clipping below full
    /// scale: the limit moves the same margin inside the spike's edge.
    pub(crate) fn detect(cumulative: &Cumulative, compression: Compression) -> UsableTones {
        const FLOOR_MARGIN: f64 = 2.5 / 255.0;
        let top_margin: f64 = match compression {
            Compression::Lossless => 0.5 / 255.0,
            Compression::Lossy => 2.5 / 255.0,
        };
        let (mut floor, mut ceiling) = (FLOOR_MARGIN, 1.0 - top_margin);
        let counts = cumulative.counts();
        let edges = cumulative.edges();
        let total = counts.iter().sum::<u64>().max(1) as f64;
        let spike = |k: usize, inward: &[usize]| {
            let n = counts[k] as f64;
            let around = inward.iter().map(|&j| counts[j] as f64).sum::<f64>() / 4.0;
            n > 0.002 * total && n > 4.0 * around
        };
        let bins = counts.len();
        if let Some(top) = counts.iter().rposition(|&n| n > 0)
            && top >= 4
            && spike(top, &[top - 1, top - 2, top - 3, top - 4])
        {
            ceiling = ceiling.min(edges[top] - top_margin);
        }
        if let Some(bottom) = counts.iter().position(|&n| n > 0)
            && bottom + 4 < bins
            && spike(bottom, &[bottom + 1, bottom + 2, bottom + 3, bottom + 4])
        {
            floor = floor.max(edges[bottom + 1] + FLOOR_MARGIN);
        }
        UsableTones { floor, ceiling }
    }

    /// True if `b` lies within the limits.
    pub fn contains(&self, b: f64) -> bool {
        b >= self.floor && b <= self.ceiling
    }
}

/// The intensity mapping `τ(b) = H_B⁻¹(H_A(b))` sampled at every bin edge of both frames,
/// keeping only tones usable in both (see [`UsableTones`]).
///
/// At an edge of A the value `H_A(e)` is exact (the fraction of codes below the edge) and
/// only `H_B⁻¹` interpolates inside a bin; edges of B give the mirror set. The standard
/// deviation of an interpolated side is `w·√(1/12 + 1/n)` (`w` bin width in brightness, `n`
/// pixels in the bin): the uniform-bin assumption is off by about a bin's spread, and a
/// sparsely filled bin says little. An exact edge has `w·√(1/n̄)` with `n̄` the pixels of
/// the two bins around it. Tones in empty bins carry no information and are dropped.
pub fn tone_pairs(
    dark: &Cumulative,
    bright: &Cumulative,
    dark_ok: UsableTones,
    bright_ok: UsableTones,
) -> Vec<TonePair> {
    let sigma = |c: &Cumulative, k: usize, exact: bool| -> Option<f64> {
        let w = c.edges()[k + 1] - c.edges()[k];
        let n = c.counts()[k] as f64;
        if n == 0.0 {
            return None;
        }
        let v = if exact { 1.0 / n } else { 1.0 / 12.0 + 1.0 / n };
        Some(w * v.sqrt())
    };
    let edge_sigma = |c: &Cumulative, j: usize| -> Option<f64> {
        let below = if j > 0 { c.counts()[j - 1] } else { 0 };
        let above = c.counts().get(j).copied().unwrap_or(0);
        let n = (below + above) as f64 / 2.0;
        if below == 0 || above == 0 {
            return None;
        }
        let w = c.edges()[j.min(c.counts().len() - 1) + 1] - c.edges()[j.min(c.counts().len() - 1)];
        Some(w / n.sqrt())
    };
    let mut pairs = Vec::new();
    let inner = |h: f64| h > 0.0 && h < 1.0;
    for j in 1..dark.edges().len() - 1 {
        let (b, q) = (dark.edges()[j], dark.at_edges()[j]);
        if !inner(q) || !dark_ok.contains(b) {
            continue;
        }
        let (t, k) = bright.inverse(q);
        if !bright_ok.contains(t) {
            continue;
        }
        if let (Some(sd), Some(st)) = (edge_sigma(dark, j), sigma(bright, k, false)) {
            pairs.push(TonePair {
                dark: b,
                bright: t,
                sigma_dark: sd,
                sigma_bright: st,
                quantile: q,
            });
        }
    }
    for j in 1..bright.edges().len() - 1 {
        let (t, q) = (bright.edges()[j], bright.at_edges()[j]);
        if !inner(q) || !bright_ok.contains(t) {
            continue;
        }
        let (b, k) = dark.inverse(q);
        if !dark_ok.contains(b) {
            continue;
        }
        if let (Some(sd), Some(st)) = (sigma(dark, k, false), edge_sigma(bright, j)) {
            pairs.push(TonePair {
                dark: b,
                bright: t,
                sigma_dark: sd,
                sigma_bright: st,
                quantile: q,
            });
        }
    }
    pairs.sort_by(|a, b| a.quantile.total_cmp(&b.quantile));
    pairs
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame8(codes: Vec<u8>, channels: usize) -> Frame {
        let n = codes.len() / channels;
        Frame::new(n as u32, 1, channels, Samples::Eight(codes)).unwrap()
    }

    #[test]
    fn counts_every_pixel_per_channel() {
        let codes: Vec<u8> = (0..300u32)
            .flat_map(|i| [(i % 256) as u8, 7, 255])
            .collect();
        let h = Histogram::of_frame(&frame8(codes, 3), 1);
        assert_eq!(h.total(), 300);
        assert_eq!(h.counts(1)[7], 300);
        assert_eq!(h.counts(2)[255], 300);
        assert_eq!(h.counts(0)[10], 2);
        assert_eq!(h.counts(0)[200], 1);
    }

    #[test]
    fn parallel_bands_match_serial_count_and_stride_subsamples() {
        let (w, hgt) = (1500u32, 1000u32);
        let codes: Vec<u16> = (0..w * hgt)
            .map(|i| (i.wrapping_mul(2654435761) >> 16) as u16)
            .collect();
        let f = Frame::new(w, hgt, 1, Samples::Sixteen(codes.clone())).unwrap();
        let h = Histogram::of_frame(&f, 1);
        assert_eq!(h.bins(), 4096);
        let mut expect = vec![0u64; 4096];
        codes.iter().for_each(|&c| expect[usize::from(c >> 4)] += 1);
        assert_eq!(h.counts(0), expect.as_slice());
        let s = Histogram::of_frame(&f, 4);
        assert_eq!(s.total(), u64::from(w.div_ceil(4) * hgt.div_ceil(4)));
    }

    #[test]
    fn cumulative_is_continuous_and_inverts() {
        let codes: Vec<u8> = (0..1000u32).map(|i| (i % 100 + 50) as u8).collect();
        let c = Histogram::of_frame(&frame8(codes, 1), 1).cumulative(0);
        assert_eq!(c.at(0.0), 0.0);
        assert_eq!(c.at(1.0), 1.0);
        for q in [0.01, 0.3, 0.5, 0.77, 0.99] {
            let (b, _) = c.inverse(q);
            assert!((c.at(b) - q).abs() < 1e-12, "{q} {b}");
        }
        // Uniform over codes 50..149: the median sits at the edge between 99 and 100.
        assert!((c.inverse(0.5).0 - 99.5 / 255.0).abs() < 1e-12);
    }

    #[test]
    fn tau_of_a_shifted_histogram_is_the_shift() {
        let dark: Vec<u8> = (0..5000u32).map(|i| (i % 100 + 20) as u8).collect();
        let bright: Vec<u8> = dark.iter().map(|&c| c + 40).collect();
        let a = Histogram::of_frame(&frame8(dark, 1), 1).cumulative(0);
        let b = Histogram::of_frame(&frame8(bright, 1), 1).cumulative(0);
        let ok = UsableTones::detect(&a, Compression::Lossless);
        let pairs = tone_pairs(&a, &b, ok, UsableTones::detect(&b, Compression::Lossless));
        assert!(pairs.len() > 150);
        for p in pairs {
            assert!((p.bright - p.dark - 40.0 / 255.0).abs() < 1e-9, "{p:?}");
        }
    }

    /// A 32×16 lossy RGB frame (two coding blocks) at code `base`, with `set` codes.
    fn lossy_blocks(base: u8, set: &[(usize, usize, u8)]) -> Frame {
        let mut codes = vec![base; 32 * 16 * 3];
        for &(x, y, code) in set {
            codes[(y * 32 + x) * 3..(y * 32 + x + 1) * 3].fill(code);
        }
        Frame::new(32, 16, 3, Samples::Eight(codes))
            .unwrap()
            .with_compression(Compression::Lossy)
    }

    #[test]
    fn a_hard_clipped_block_of_either_frame_is_left_out_of_both() {
        // The bright frame's first block clips next to a dark sample; its second block
        // clips softly (nothing below 159). The dark frame clips nowhere.
        let bright = lossy_blocks(200, &[(3, 3, 255), (9, 12, 255), (5, 5, 40), (20, 4, 255)]);
        let dark = lossy_blocks(100, &[]);
        let (b, d) = (
            FrameCounts::of_frame(&bright, 1),
            FrameCounts::of_frame(&dark, 1),
        );
        assert_eq!((b.hard_clipped_blocks(), d.hard_clipped_blocks()), (1, 0));
        let (hd, hb) = shared_counts(&d, &b);
        assert_eq!((hd.total(), hb.total()), (256, 256));
        // The soft block keeps its clipped pixel; the hard one is gone from both frames.
        assert_eq!(hb.counts(0)[255], 1);
        assert_eq!(hb.counts(0)[40], 0);
        assert_eq!(hd.counts(0)[100], 256);
        // The same frames stored losslessly are counted whole.
        let (bright, dark) = (
            bright.clone().with_compression(Compression::Lossless),
            dark.clone().with_compression(Compression::Lossless),
        );
        let (b, d) = (
            FrameCounts::of_frame(&bright, 1),
            FrameCounts::of_frame(&dark, 1),
        );
        let (hd, hb) = shared_counts(&d, &b);
        assert!(matches!((&hd, &hb), (Cow::Borrowed(_), Cow::Borrowed(_))));
        assert_eq!(hb.total(), 512);
    }

    #[test]
    fn a_pixel_is_not_left_out_for_its_own_clipping() {
        // One clipped pixel in the block (its 2×2 chroma cell at x 6–7, y 2–3) and a dark
        // sample: the block's other cells go, the clipped pixel's cell stays — whether a
        // pixel is counted must not depend on its own noise.
        let f = lossy_blocks(230, &[(7, 2, 255), (12, 12, 10)]);
        let c = FrameCounts::of_frame(&f, 1);
        let (h, _) = shared_counts(&c, &c);
        assert_eq!(h.total(), 256 + 4);
        assert_eq!(h.counts(1)[255], 1);
        assert_eq!(h.counts(1)[230], 256 + 3);
        // A second clipped cell in the block leaves out every cell, both clipped ones too.
        let f = lossy_blocks(230, &[(7, 2, 255), (0, 0, 255), (12, 12, 10)]);
        let c = FrameCounts::of_frame(&f, 1);
        assert_eq!(shared_counts(&c, &c).0.total(), 256);
        // With a stride the same pixels are left out among those sampled.
        let c = FrameCounts::of_frame(&f, 2);
        let (h, _) = shared_counts(&c, &c);
        assert_eq!((c.histogram().total(), h.total()), (128, 64));
    }

    #[test]
    fn frames_off_the_block_grid_and_of_one_channel_are_counted_without_panic() {
        // 19×5 grey frames: one partial block column and row. The bright one clips next
        // to black in its first block and in its partial last column.
        let grey = |codes: Vec<u8>| {
            Frame::new(19, 5, 1, Samples::Eight(codes))
                .unwrap()
                .with_compression(Compression::Lossy)
        };
        let mut bright = vec![120u8; 19 * 5];
        bright[0] = 255;
        bright[2] = 0;
        bright[17] = 255;
        bright[19 + 18] = 255;
        bright[4 * 19 + 16] = 3;
        let (bright, dark) = (grey(bright), grey(vec![60u8; 19 * 5]));
        for stride in [1, 2, 3] {
            let (b, d) = (
                FrameCounts::of_frame(&bright, stride),
                FrameCounts::of_frame(&dark, stride),
            );
            assert_eq!(b.hard_clipped_blocks(), 2);
            let (hd, hb) = shared_counts(&d, &b);
            assert_eq!(hd.total(), hb.total());
            assert!(hb.total() < b.histogram().total());
        }
        // Frames of different sizes are counted whole.
        let wide = grey(vec![60u8; 19 * 4].into_iter().chain([0; 19]).collect());
        let tall = Frame::new(5, 19, 1, Samples::Eight(vec![60u8; 95]))
            .unwrap()
            .with_compression(Compression::Lossy);
        let (a, b) = (
            FrameCounts::of_frame(&wide, 1),
            FrameCounts::of_frame(&tall, 1),
        );
        assert!(matches!(
            shared_counts(&a, &b),
            (Cow::Borrowed(_), Cow::Borrowed(_))
        ));
    }

    #[test]
    fn clipping_spike_moves_the_ceiling() {
        let mut codes: Vec<u8> = (0..10000u32).map(|i| (i % 200) as u8).collect();
        codes.extend(std::iter::repeat_n(230u8, 3000));
        let c = Histogram::of_frame(&frame8(codes, 1), 1).cumulative(0);
        // The spike's lower edge is 229.5/255; a JPEG's ringing costs two more codes.
        for (compression, ceiling) in [(Compression::Lossless, 229.0), (Compression::Lossy, 227.0)]
        {
            let ok = UsableTones::detect(&c, compression);
            assert!((ok.ceiling - ceiling / 255.0).abs() < 1e-12, "{ok:?}");
            assert!((ok.floor - 2.5 / 255.0).abs() < 1e-12);
        }
    }
}
