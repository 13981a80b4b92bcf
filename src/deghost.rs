//! Deghosting: where a frame disagrees with the bracket's reference frame by more than
//! its noise allows, that frame is left out of the merge there.
//!
//! # The test
//!
//! Each frame `k` estimates radiance `x_k = g(B_k)·e_ref/e_k` per sample (see
//! [`crate::merge`]). Frame `k` is compared with an *anchor* frame `a` in every channel it
//! exposes well (brightness within [`WELL_EXPOSED`]) through the residual
//! `r = ln x_k − ln x_a`. In a still bracket `r` is noise plus what the single response
//! does not model (its fitting error, the camera's tone processing, the codec), which
//! depends on the tone; a moving subject is an outlier. So the residuals of the pair are
//! first gathered over the whole frame (every `s`-th pixel of every `s`-th row, `s` up to
//! [`STATS_STRIDE`] as [`STATS_PIXELS`] allows) by channel and by the anchor's tone ([`TONE_BINS`] bins of its
//! code), giving per bin a centre `m` and a spread `s = 1.4826·MAD` around it; a bin with
//! fewer than [`MIN_SAMPLES`] takes the channel's pooled figures.
//!
//! What the response does not model is scene-wide and smooth in tone; a subject is
//! compact. So the frame is cut into [`TILES`] × [`TILES`] tiles, and every tile holding at
//! least [`MIN_TILE_SAMPLES`] of a bin's residuals votes with its own median. A bin with at
//! least [`SCENE_WIDE_TILES`] votes (a quarter of the tiles) is scene-wide: `m` is the
//! median of the votes (a subject would have to fill half of the bin's tiles to move it)
//! and `m`, `s` are taken as they are. A bin with fewer votes is local, and may be a
//! subject's own tones: `m` is the median of its residuals, held within 0.3 stop, and `s`
//! within 0.5 stop ([`MAX_CENTRE_STOPS`], [`MAX_SPREAD_STOPS`]), so a bin that only a
//! subject fills cannot make it look still. The frame disagrees in a channel when
//!
//! ```text
//! |r − m|  >  Z · max(√(σ_k² + σ_a²), s) + δ,           Z = 4,  δ = 0.1 stop · ln 2
//! ```
//!
//! ([`NOISE_SIGMAS`], [`TOLERANCE_STOPS`]). `σ` is the noise of `ln x` the sensor model
//! predicts: for a sample of brightness `B` and linear value `X = g(B)` (units of the
//! frame's clipping point), read noise and quantisation constant in code values carried
//! through the response's slope, plus shot noise,
//!
//! ```text
//! σ² = ((g'(B) · σ_B)² + X / W) / X²,        σ_B = 1.5 codes of 255,  W = 2000 e⁻
//! ```
//!
//! ([`CODE_NOISE`], [`FULL_WELL_ELECTRONS`]). An anchor sample outside the well-exposed
//! range still bounds the radiance: clipped high, from below by its value at the range's
//! top (the frame disagrees only when `r − m < −allowance`); dark, from above by its
//! value at the range's bottom (only when `r − m > allowance`).
//!
//! The comparison reads every [`COMPARE_STRIDE`]-th pixel of every [`COMPARE_STRIDE`]-th
//! row (four points per block: the mask is decided per block, and a subject covers many).
//! A frame disagrees at a point when any channel disagrees. Frames are tested in order of
//! exposure distance from the reference, the anchor of every point being the reference
//! until a frame that exposes the point well where the anchor does not (a region the
//! reference clipped or left dark) agrees with it and takes its place.
//!
//! # The mask
//!
//! Disagreement is counted over blocks of [`BLOCK`]×[`BLOCK`] pixels. A block is left out
//! where the share of disagreeing points, averaged over its 3×3 neighbourhood, exceeds
//! [`GHOST_SHARE`] (isolated noise never reaches it; a subject does). The left-out blocks
//! grow by one block and are feathered by two box filters of one block, and the mask is
//! interpolated bilinearly back to pixels: a frame's weight falls smoothly to 0 over about
//! two blocks around a ghost, so the reference fills the region without a seam. A frame
//! with no block left out gets no mask, and the merge is then exactly the plain one.
//! Where a frame is left out, the merge holds each value within the bound the
//! reference's sample sets ([`GhostMasks::measured`], [`crate::merge::merge_masked`]): a
//! frame kept there may agree with a clipped or dark reference only within its own noise.

use rayon::prelude::*;

use crate::frame::{Frame, Samples};
use crate::merge::{BracketFrame, Masks};
use crate::response::InverseResponse;

/// Brightness range (normalised codes) in which a sample is compared.
pub const WELL_EXPOSED: (f64, f64) = (0.02, 0.95);

/// `Z`: spreads of the residual beyond which two samples disagree.
pub const NOISE_SIGMAS: f64 = 4.0;

/// `δ`: a disagreement this large (stops) is always allowed.
pub const TOLERANCE_STOPS: f64 = 0.1;

/// `σ_B`: read noise and quantisation, in codes of an 8-bit scale.
pub const CODE_NOISE: f64 = 1.5;

/// `W`: electrons at the clipping point, for the shot noise.
pub const FULL_WELL_ELECTRONS: f64 = 2000.0;

/// Side of the blocks over which disagreement is counted, pixels.
pub const BLOCK: usize = 4;

/// Share of disagreeing pixels in a block's neighbourhood above which the block is left out.
pub const GHOST_SHARE: f32 = 0.3;

/// Bins of the anchor's code over which a pair's residuals are gathered.
pub const TONE_BINS: usize = 32;

/// The most pixels and rows between the samples of a pair's residual statistics.
pub const STATS_STRIDE: usize = 4;

/// The statistics read every `s`-th pixel of every `s`-th row, `s` the largest stride up
/// to [`STATS_STRIDE`] that leaves at least this many pixels (1 for a frame under 4 MP).
pub const STATS_PIXELS: usize = 1_000_000;

/// Pixels and rows between the points the comparison reads (a half-resolution grid: four
/// points per block).
pub const COMPARE_STRIDE: usize = 2;

/// Fewest residuals for a tone bin's own statistics.
pub const MIN_SAMPLES: u32 = 64;

/// The largest centre `|m|` (stops) a still scene is granted: a bin whose residuals all
/// come from a subject (its tones the reference shows nowhere else) cannot pass the
/// subject off as the scene's own.
pub const MAX_CENTRE_STOPS: f64 = 0.3;

/// The largest spread `s` (stops) a still scene is granted, for the same reason.
pub const MAX_SPREAD_STOPS: f64 = 0.5;

/// Tiles per side of the grid over which a bin's centre is voted.
pub const TILES: usize = 8;

/// Fewest residuals of a tone bin in a tile for the tile to vote on the bin's centre.
pub const MIN_TILE_SAMPLES: u32 = 8;

/// Fewest voting tiles (a quarter of them) for a tone bin to count as scene-wide: its
/// centre is then the median of the tiles' medians and neither figure is capped.
pub const SCENE_WIDE_TILES: usize = 16;

/// Bins of the residual's histogram, over `±RESIDUAL_RANGE`.
const RESIDUAL_BINS: usize = 256;

/// Half the range of the residual's histogram, `ln` units (±4.3 stops).
const RESIDUAL_RANGE: f32 = 3.0;

/// What deghosting decided for a bracket.
#[derive(Debug, Clone, PartialEq)]
pub struct GhostMasks {
    /// Input index of the reference frame (never left out).
    pub reference: usize,
    /// Per input frame, its weight per pixel (0..=255, 255 = kept) or `None` where the
    /// frame was kept everywhere.
    pub masks: Vec<Option<Vec<u8>>>,
    /// Per input frame, the share of pixels it was left out of (weight below one half).
    pub left_out: Vec<f64>,
    /// The first and the last code within [`WELL_EXPOSED`] at the frames' depth: beyond
    /// them the reference's sample only bounds the radiance.
    pub measured: (usize, usize),
}

impl GhostMasks {
    /// True when no frame was left out anywhere.
    pub fn is_empty(&self) -> bool {
        self.masks.iter().all(Option::is_none)
    }

    /// The share of pixels at least one frame was left out of.
    pub fn share(&self) -> f64 {
        let Some(n) = self.masks.iter().flatten().map(Vec::len).next() else {
            return 0.0;
        };
        let out = (0..n)
            .into_par_iter()
            .filter(|&p| self.masks.iter().flatten().any(|m| m[p] < 128))
            .count();
        out as f64 / n as f64
    }

    /// The masks as the merge takes them, one per input frame, with the reference.
    pub fn masks(&self) -> Masks<'_> {
        Masks {
            weights: self.masks.iter().map(|m| m.as_deref()).collect(),
            reference: self.reference,
            measured: self.measured,
        }
    }

    /// [`GhostMasks::least_kept`] of a `width × height` bracket within `edge` pixels, for
    /// an overlay: reduced by `f = ⌈long edge / edge⌉`, each map pixel the least over its
    /// `f × f` frame pixels. `None` when no frame was left out anywhere.
    pub fn least_kept_map(&self, width: u32, height: u32, edge: u32) -> Option<KeptMap> {
        let masks: Vec<&[u8]> = self.masks.iter().flatten().map(Vec::as_slice).collect();
        let (w, h) = (width as usize, height as usize);
        if masks.is_empty() || masks.iter().any(|m| m.len() != w * h) {
            return None;
        }
        let f = w.max(h).div_ceil(edge.max(1) as usize).max(1);
        let (mw, mh) = (w.div_ceil(f), h.div_ceil(f));
        let mut least = vec![u8::MAX; mw * mh];
        least
            .par_chunks_mut(mw)
            .enumerate()
            .for_each(|(my, cells)| {
                for y in my * f..((my + 1) * f).min(h) {
                    for mask in &masks {
                        let row = &mask[y * w..(y + 1) * w];
                        for (cell, pixels) in cells.iter_mut().zip(row.chunks(f)) {
                            *cell = pixels.iter().fold(*cell, |a, &m| a.min(m));
                        }
                    }
                }
            });
        Some(KeptMap {
            width: mw as u32,
            height: mh as u32,
            least,
        })
    }

    /// Per pixel of a frame of `pixels`, the least weight the merge kept of any frame
    /// (0..=255): 255 where every frame was merged, 0 where some frame was left out.
    pub fn least_kept(&self, pixels: usize) -> Vec<u8> {
        let mut least = vec![u8::MAX; pixels];
        for mask in self.masks.iter().flatten() {
            for (l, &m) in least.iter_mut().zip(mask) {
                *l = (*l).min(m);
            }
        }
        least
    }
}

/// Where deghosting left frames out, reduced for an overlay
/// ([`GhostMasks::least_kept_map`]).
#[derive(Debug, Clone, PartialEq)]
pub struct KeptMap {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Per pixel, rows top down, the least weight kept of any frame (255 every frame
    /// merged, 0 some frame left out).
    pub least: Vec<u8>,
}

/// Where a code lies: well exposed, or a bound on the radiance.
#[derive(Clone, Copy, PartialEq)]
enum Tone {
    /// Below the well-exposed range: the radiance is at most `value`.
    Dark,
    /// Within it: the radiance is `value`.
    Good,
    /// Above it: the radiance is at least `value`.
    Bright,
}

/// Per code of one frame and channel: its `ln x` (or the bound at the range's edge), the
/// noise term `Z²σ²` of it, where it lies, and its tone bin.
#[derive(Clone, Copy)]
struct Code {
    value: f32,
    noise: f32,
    tone: Tone,
    bin: u8,
}

/// The [`Code`] table of every frame (input order), channel and code.
struct Codes {
    levels: usize,
    channels: usize,
    table: Vec<Code>,
}

impl Codes {
    fn new(frames: &[BracketFrame<'_>], response: &InverseResponse) -> Codes {
        let first = frames[0].frame;
        let (levels, channels) = (first.bit_depth().levels(), first.channels());
        let e_ref = frames.iter().map(|f| f.exposure).fold(0.0, f64::max);
        let mut table = Vec::with_capacity(frames.len() * channels * levels);
        for f in frames {
            for c in 0..channels {
                // `ln x` and `Z²σ²` at brightness `b` of this frame and channel.
                let at = |b: f64| {
                    let x = response.eval(c, b).max(1e-9);
                    let (lo, hi) = ((b - 1.0 / 256.0).max(0.0), (b + 1.0 / 256.0).min(1.0));
                    let slope = (response.eval(c, hi) - response.eval(c, lo)) / (hi - lo);
                    let var =
                        ((slope * CODE_NOISE / 255.0).powi(2) + x / FULL_WELL_ELECTRONS) / (x * x);
                    (
                        (x * e_ref / f.exposure).ln() as f32,
                        (NOISE_SIGMAS * NOISE_SIGMAS * var) as f32,
                    )
                };
                let (bottom, top) = (at(WELL_EXPOSED.0), at(WELL_EXPOSED.1));
                let (first, last) = well_exposed_codes(levels);
                for code in 0..levels {
                    let ((value, noise), tone) = if code < first {
                        (bottom, Tone::Dark)
                    } else if code > last {
                        (top, Tone::Bright)
                    } else {
                        (at(code as f64 / (levels - 1) as f64), Tone::Good)
                    };
                    let bin = (code * TONE_BINS / levels) as u8;
                    table.push(Code {
                        value,
                        noise,
                        tone,
                        bin,
                    });
                }
            }
        }
        Codes {
            levels,
            channels,
            table,
        }
    }

    #[inline]
    fn get(&self, frame: usize, channel: usize, code: usize) -> Code {
        self.table[(frame * self.channels + channel) * self.levels + code]
    }

    /// Where the residual of frame `k` (code `xk`) against frame `a` (code `xa`) in
    /// channel `c` falls among that channel's histograms: `bin(xa)·RESIDUAL_BINS + slot`;
    /// `None` where `k` does not expose the sample well.
    fn residual_index(
        &self,
        (k, a): (usize, usize),
        c: usize,
        xa: usize,
        xk: usize,
    ) -> Option<u16> {
        let (xk, xa) = (self.get(k, c, xk), self.get(a, c, xa));
        let slot = residual_bin(xk.value - xa.value);
        // At most TONE_BINS · RESIDUAL_BINS = 8192.
        (xk.tone == Tone::Good).then_some((usize::from(xa.bin) * RESIDUAL_BINS + slot) as u16)
    }
}

/// The first and the last code of a depth of `levels` codes within [`WELL_EXPOSED`]
/// (brightness `code/(levels − 1)`).
fn well_exposed_codes(levels: usize) -> (usize, usize) {
    let top = (levels - 1) as f64;
    (
        (WELL_EXPOSED.0 * top).ceil() as usize,
        (WELL_EXPOSED.1 * top).floor() as usize,
    )
}

/// `f` at every pair of codes `(a, x)` below `levels`, rows by `a`.
fn pair_table<V: Send>(levels: usize, f: impl Fn(usize, usize) -> V + Sync) -> Vec<V> {
    (0..levels * levels)
        .into_par_iter()
        .map(|i| f(i / levels, i % levels))
        .collect()
}

/// A frame's code type, 8 or 16 bits.
trait Sample: Copy + Send + Sync {
    fn index(self) -> usize;
}

impl Sample for u8 {
    #[inline]
    fn index(self) -> usize {
        usize::from(self)
    }
}

impl Sample for u16 {
    #[inline]
    fn index(self) -> usize {
        usize::from(self)
    }
}

/// The bracket's codes as read by the test: the frames' sample slices (input order), the
/// code table and the frame's width.
struct Bracket<'a, T> {
    planes: Vec<&'a [T]>,
    codes: Codes,
    width: usize,
    height: usize,
    /// Whether the tests go through tables of every pair of codes (anchor, frame) per
    /// channel, built once per pair of frames: when the comparison reads at least as many
    /// points as such a table has entries (`levels²`; 8-bit frames over about 0.26 MP,
    /// never 16-bit ones). Otherwise each test is computed where it is read.
    tabled: bool,
}

impl<T: Sample> Bracket<'_, T> {
    /// The stride of the residual statistics: `min(STATS_STRIDE, ⌊√(P/STATS_PIXELS)⌋)`,
    /// at least 1, for `P` pixels.
    fn stats_stride(&self) -> usize {
        let ratio = (self.width * self.height / STATS_PIXELS) as f64;
        (ratio.sqrt() as usize).clamp(1, STATS_STRIDE)
    }
}

/// A pair's residual statistics in one tone bin: the centre `m` and `Z²s²`.
#[derive(Clone, Copy)]
struct Bin {
    centre: f32,
    spread: f32,
}

/// What a pair's residuals `ln x_k − ln x_a` are in a still scene, per channel and tone bin
/// of the anchor: their median and `1.4826·MAD`.
struct Residuals {
    bins: Vec<Bin>,
}

impl Residuals {
    /// Gathers the pair `(k, a)`'s residuals over every [`Bracket::stats_stride`]-th pixel,
    /// tile by tile of a [`TILES`] × [`TILES`] grid, and decides each bin's figures (module docs).
    fn of<T: Sample>(bracket: &Bracket<'_, T>, k: usize, a: usize) -> Residuals {
        let (codes, channels) = (&bracket.codes, bracket.codes.channels);
        let index = |c: usize, xa: usize, xk: usize| codes.residual_index((k, a), c, xa, xk);
        let tiles = if bracket.tabled {
            let levels = codes.levels;
            let tables: Vec<Vec<u16>> = (0..channels)
                .map(|c| pair_table(levels, |xa, xk| index(c, xa, xk).unwrap_or(u16::MAX)))
                .collect();
            bracket.tile_histograms((k, a), &|c: usize, xa: usize, xk: usize| {
                let i = tables[c][xa * levels + xk];
                (i != u16::MAX).then_some(i)
            })
        } else {
            bracket.tile_histograms((k, a), &index)
        };
        let z2 = (NOISE_SIGMAS * NOISE_SIGMAS) as f32;
        let mut bins = Vec::with_capacity(channels * TONE_BINS);
        for c in 0..channels {
            let slot = |b: usize| (c * TONE_BINS + b) * RESIDUAL_BINS;
            let pooled: Vec<Vec<u32>> = (0..TONE_BINS)
                .map(|b| {
                    let mut h = vec![0u32; RESIDUAL_BINS];
                    for tile in &tiles {
                        let part = &tile[slot(b)..slot(b) + RESIDUAL_BINS];
                        h.iter_mut().zip(part).for_each(|(x, &y)| *x += y);
                    }
                    h
                })
                .collect();
            let mut channel = vec![0u32; RESIDUAL_BINS];
            for h in &pooled {
                channel.iter_mut().zip(h).for_each(|(x, &y)| *x += y);
            }
            let fallback = centre_and_spread(&channel, &[]).unwrap_or((0.0, 0.0));
            for (b, histogram) in pooled.iter().enumerate() {
                let votes: Vec<usize> = tiles
                    .iter()
                    .map(|tile| &tile[slot(b)..slot(b) + RESIDUAL_BINS])
                    .filter(|h| h.iter().sum::<u32>() >= MIN_TILE_SAMPLES)
                    .map(median_slot)
                    .collect();
                let (centre, s) = centre_and_spread(histogram, &votes).unwrap_or(fallback);
                bins.push(Bin {
                    centre,
                    spread: z2 * s * s,
                });
            }
        }
        Residuals { bins }
    }

    #[inline]
    fn get(&self, channel: usize, bin: u8) -> Bin {
        self.bins[channel * TONE_BINS + usize::from(bin)]
    }
}

impl<T: Sample> Bracket<'_, T> {
    /// Per tile of the [`TILES`] × [`TILES`] grid (row by row), the residual histogram of
    /// the pair `(k, a)`, per channel and tone bin of the anchor, from every
    /// [`Bracket::stats_stride`]-th pixel of every such row; `index` places a sample's
    /// residual ([`Codes::residual_index`]).
    fn tile_histograms<F>(&self, (k, a): (usize, usize), index: &F) -> Vec<Vec<u32>>
    where
        F: Fn(usize, usize, usize) -> Option<u16> + Sync,
    {
        (0..TILES * TILES)
            .into_par_iter()
            .map(|t| self.tile_histogram(t, (k, a), index))
            .collect()
    }

    /// Tile `t` of [`Bracket::tile_histograms`].
    fn tile_histogram<F>(&self, t: usize, (k, a): (usize, usize), index: &F) -> Vec<u32>
    where
        F: Fn(usize, usize, usize) -> Option<u16>,
    {
        let channels = self.codes.channels;
        let bins = TONE_BINS * RESIDUAL_BINS;
        let mut h = vec![0u32; channels * bins];
        let stride = self.stats_stride();
        let span =
            |i: usize, n: usize| (i * n / TILES).next_multiple_of(stride)..(i + 1) * n / TILES;
        let (ys, xs) = (span(t / TILES, self.height), span(t % TILES, self.width));
        let (planes_k, planes_a) = (self.planes[k], self.planes[a]);
        for y in ys.step_by(stride) {
            for x in xs.clone().step_by(stride) {
                for c in 0..channels {
                    let i = (y * self.width + x) * channels + c;
                    if let Some(slot) = index(c, planes_a[i].index(), planes_k[i].index()) {
                        h[c * bins + usize::from(slot)] += 1;
                    }
                }
            }
        }
        h
    }
}

/// The histogram slot of residual `r`.
#[inline]
fn residual_bin(r: f32) -> usize {
    let t = (r + RESIDUAL_RANGE) / (2.0 * RESIDUAL_RANGE) * RESIDUAL_BINS as f32;
    (t.max(0.0) as usize).min(RESIDUAL_BINS - 1)
}

/// The residual at the centre of histogram slot `slot`, `ln` units.
fn slot_value(slot: usize) -> f32 {
    -RESIDUAL_RANGE + (slot as f32 + 0.5) * 2.0 * RESIDUAL_RANGE / RESIDUAL_BINS as f32
}

/// The slot holding the median of a (non-empty) residual histogram.
fn median_slot(histogram: &[u32]) -> usize {
    let total: u32 = histogram.iter().sum();
    let mut seen = 0;
    histogram
        .iter()
        .position(|&n| {
            seen += n;
            2 * seen >= total
        })
        .unwrap_or(0)
}

/// A bin's centre and spread from its residual histogram and its tiles' `votes` (each
/// voting tile's median slot); `None` below [`MIN_SAMPLES`]. With at least
/// [`SCENE_WIDE_TILES`] votes the centre is the median of the votes and the spread
/// `1.4826·MAD` around it; with fewer the centre is the histogram's median and the two
/// are held within [`MAX_CENTRE_STOPS`] and [`MAX_SPREAD_STOPS`].
fn centre_and_spread(histogram: &[u32], votes: &[usize]) -> Option<(f32, f32)> {
    let total: u32 = histogram.iter().sum();
    if total < MIN_SAMPLES {
        return None;
    }
    let scene_wide = votes.len() >= SCENE_WIDE_TILES;
    let median = if scene_wide {
        let mut votes = votes.to_vec();
        votes.sort_unstable();
        votes[(votes.len() - 1) / 2]
    } else {
        median_slot(histogram)
    };
    // The median absolute deviation, in whole slots around the centre's slot.
    let mut within = histogram[median];
    let mut d = 0;
    while 2 * within < total && d < RESIDUAL_BINS {
        d += 1;
        within += median.checked_sub(d).map_or(0, |i| histogram[i]);
        within += histogram.get(median + d).copied().unwrap_or(0);
    }
    let (centre, spread) = (
        slot_value(median),
        1.4826 * d as f32 * 2.0 * RESIDUAL_RANGE / RESIDUAL_BINS as f32,
    );
    if scene_wide {
        return Some((centre, spread));
    }
    let (max_centre, max_spread) = (
        (MAX_CENTRE_STOPS * std::f64::consts::LN_2) as f32,
        (MAX_SPREAD_STOPS * std::f64::consts::LN_2) as f32,
    );
    Some((
        centre.clamp(-max_centre, max_centre),
        spread.min(max_spread),
    ))
}

/// How a frame compares with its anchor at one pixel.
#[derive(PartialEq)]
enum Verdict {
    /// No channel the frame exposes well.
    Unknown,
    /// Every channel the frame exposes well agrees; `anchored` when the anchor exposes
    /// some channel well.
    Agree {
        anchored: bool,
    },
    Disagree,
}

/// Decides, for every frame of `frames` but `reference` (the input index of the frame
/// alignment registered the others onto, [`crate::align::Alignment::reference`]; for a
/// bracket not aligned, [`crate::align::choose_reference`]'s), where it is left out of
/// the merge (module docs). An index past the frames is chosen again as the latter.
/// Frames that do not share size, depth and channels get no masks (the merge refuses
/// them).
pub fn ghost_masks(
    frames: &[BracketFrame<'_>],
    response: &InverseResponse,
    reference: usize,
) -> GhostMasks {
    let views: Vec<&Frame> = frames.iter().map(|f| f.frame).collect();
    let n = frames.len();
    let reference = if reference < n {
        reference
    } else {
        crate::align::choose_reference(&views)
    };
    let measured = well_exposed_codes(views[0].bit_depth().levels());
    let unmasked = GhostMasks {
        reference,
        masks: vec![None; n],
        left_out: vec![0.0; n],
        measured,
    };
    let shape = |f: &Frame| (f.width(), f.height(), f.channels(), f.bit_depth());
    if views.iter().any(|f| shape(f) != shape(views[0])) {
        // Not one bracket: nothing to compare; the merge refuses it, naming the files.
        return unmasked;
    }
    let eight: Option<Vec<&[u8]>> = views
        .iter()
        .map(|f| match f.samples() {
            Samples::Eight(v) => Some(v.as_slice()),
            Samples::Sixteen(_) => None,
        })
        .collect();
    let sixteen: Option<Vec<&[u16]>> = views
        .iter()
        .map(|f| match f.samples() {
            Samples::Sixteen(v) => Some(v.as_slice()),
            Samples::Eight(_) => None,
        })
        .collect();
    let (width, height) = (views[0].width() as usize, views[0].height() as usize);
    let codes = Codes::new(frames, response);
    let points = width.div_ceil(COMPARE_STRIDE) * height.div_ceil(COMPARE_STRIDE);
    let tabled = points >= codes.levels * codes.levels;
    let (masks, left_out) = match (eight, sixteen) {
        (Some(planes), _) => decide(
            frames,
            reference,
            &Bracket {
                planes,
                codes,
                width,
                height,
                tabled,
            },
        ),
        (_, Some(planes)) => decide(
            frames,
            reference,
            &Bracket {
                planes,
                codes,
                width,
                height,
                tabled,
            },
        ),
        _ => return unmasked,
    };
    GhostMasks {
        reference,
        masks,
        left_out,
        measured,
    }
}

/// Per input frame, its mask (or `None`) and the share of pixels left out.
fn decide<T: Sample>(
    frames: &[BracketFrame<'_>],
    reference: usize,
    bracket: &Bracket<'_, T>,
) -> (Vec<Option<Vec<u8>>>, Vec<f64>) {
    let n = frames.len();
    let (width, height) = (bracket.width, bracket.height);
    // The anchor of every point of the comparison grid. A bracket of more than 256 frames
    // compares each with the reference alone.
    let grid = width.div_ceil(COMPARE_STRIDE) * height.div_ceil(COMPARE_STRIDE);
    let mut anchor = vec![u8::try_from(reference).unwrap_or(0); grid];
    let mut masks = vec![None; n];
    let mut left_out = vec![0.0; n];
    let order = by_distance(frames, reference);
    for (rank, &k) in order.iter().enumerate().skip(1) {
        let mut residuals: Vec<Option<Residuals>> = (0..n).map(|_| None).collect();
        for &a in &order[..rank] {
            residuals[a] = Some(Residuals::of(bracket, k, a));
        }
        let pair = Pair {
            bracket,
            residuals: &residuals,
            k,
        };
        let disagree = pair.compare(&mut anchor);
        if let Some(mask) = mask_of(&disagree, width, height) {
            left_out[k] = mask.iter().filter(|&&m| m < 128).count() as f64 / mask.len() as f64;
            masks[k] = Some(mask);
        }
    }
    (masks, left_out)
}

/// Input indices, the reference first, then by `|ln(e_k/e_ref)|` (stable).
fn by_distance(frames: &[BracketFrame<'_>], reference: usize) -> Vec<usize> {
    let e_ref = frames[reference].exposure;
    let mut order: Vec<usize> = (0..frames.len()).collect();
    order.sort_by(|&a, &b| {
        let d = |i: usize| {
            let d = (frames[i].exposure / e_ref).ln().abs();
            if i == reference { -1.0 } else { d }
        };
        d(a).total_cmp(&d(b))
    });
    order
}

/// Frame `k` against the anchors of the frames before it.
struct Pair<'a, T> {
    bracket: &'a Bracket<'a, T>,
    /// Per anchor frame, the residual statistics of `(k, anchor)`.
    residuals: &'a [Option<Residuals>],
    k: usize,
}

/// [`Pair::judge`]'s flags: the anchor exposes the channel well.
const ANCHORED: u8 = 1;
/// Frame `k` exposes the channel well and agrees with the anchor.
const AGREES: u8 = 2;
/// Frame `k` exposes the channel well and disagrees with the anchor.
const DISAGREES: u8 = 4;

impl<T: Sample> Pair<'_, T> {
    /// Per block, the share of the grid points it compared that disagree (a grid of
    /// `⌈w/BLOCK⌉ × ⌈h/BLOCK⌉`). The points are every [`COMPARE_STRIDE`]-th pixel of every
    /// [`COMPARE_STRIDE`]-th row; `anchor` holds one anchor per point. Where the anchor
    /// exposes no channel well and `k` does and agrees with it, `k` becomes the anchor.
    fn compare(&self, anchor: &mut [u8]) -> Vec<f32> {
        if !self.bracket.tabled {
            return self.compare_by(&|a, c, xa, xk| self.judge(a, c, xa, xk), anchor);
        }
        let levels = self.bracket.codes.levels;
        let tables: Vec<Option<Vec<u8>>> = (0..self.residuals.len())
            .map(|a| {
                self.residuals[a].as_ref()?;
                let channels = 0..self.bracket.codes.channels;
                Some(
                    channels
                        .flat_map(|c| pair_table(levels, |xa, xk| self.judge(a, c, xa, xk)))
                        .collect(),
                )
            })
            .collect();
        let judge = |a: usize, c: usize, xa: usize, xk: usize| {
            tables[a]
                .as_ref()
                .map_or(0, |t| t[(c * levels + xa) * levels + xk])
        };
        self.compare_by(&judge, anchor)
    }

    /// [`Pair::compare`] with `judge` testing one channel ([`Pair::judge`]).
    fn compare_by<J>(&self, judge: &J, anchor: &mut [u8]) -> Vec<f32>
    where
        J: Fn(usize, usize, usize, usize) -> u8 + Sync,
    {
        let (width, height) = (self.bracket.width, self.bracket.height);
        let blocks_x = width.div_ceil(BLOCK);
        let grid_x = width.div_ceil(COMPARE_STRIDE);
        let per_block = BLOCK / COMPARE_STRIDE;
        let mut share = vec![0.0f32; blocks_x * height.div_ceil(BLOCK)];
        anchor
            .par_chunks_mut(grid_x * per_block)
            .zip(share.par_chunks_mut(blocks_x))
            .enumerate()
            .for_each(|(band, (anchors, shares))| {
                let mut counts = vec![(0u32, 0u32); blocks_x];
                for (row, anchors) in anchors.chunks_mut(grid_x).enumerate() {
                    let y = (band * per_block + row) * COMPARE_STRIDE;
                    for (gx, a) in anchors.iter_mut().enumerate() {
                        let p = y * width + gx * COMPARE_STRIDE;
                        let count = &mut counts[gx / per_block];
                        match self.verdict(judge, p, usize::from(*a)) {
                            Verdict::Disagree => *count = (count.0 + 1, count.1 + 1),
                            Verdict::Agree { anchored } => {
                                count.1 += 1;
                                if !anchored {
                                    *a = self.k as u8;
                                }
                            }
                            Verdict::Unknown => {}
                        }
                    }
                }
                for (s, (bad, seen)) in shares.iter_mut().zip(counts) {
                    *s = if seen == 0 {
                        0.0
                    } else {
                        bad as f32 / seen as f32
                    };
                }
            });
        share
    }

    /// Frame `k` against `anchor` at pixel `p`: it disagrees when any channel does
    /// ([`Pair::judge`] through `judge`); unknown without the pair's statistics (no
    /// channel has flags).
    #[inline]
    fn verdict<J>(&self, judge: &J, p: usize, anchor: usize) -> Verdict
    where
        J: Fn(usize, usize, usize, usize) -> u8,
    {
        let channels = self.bracket.codes.channels;
        let (anchors, ks) = (self.bracket.planes[anchor], self.bracket.planes[self.k]);
        let mut flags = 0;
        for c in 0..channels {
            let i = p * channels + c;
            flags |= judge(anchor, c, anchors[i].index(), ks[i].index());
        }
        if flags & DISAGREES != 0 {
            Verdict::Disagree
        } else if flags & AGREES != 0 {
            Verdict::Agree {
                anchored: flags & ANCHORED != 0,
            }
        } else {
            Verdict::Unknown
        }
    }

    /// One channel `c` of frame `k` (code `xk`) against `anchor` (code `xa`), as flags
    /// (module docs): with `e = |r − m| − δ` (one-sided where the anchor is a bound), it
    /// disagrees when `e > 0` and `e² > max(Z²(σ_k² + σ_a²), Z²s²)`. No flags without the
    /// pair's residual statistics.
    fn judge(&self, anchor: usize, c: usize, xa: usize, xk: usize) -> u8 {
        let Some(residuals) = self.residuals[anchor].as_ref() else {
            return 0;
        };
        let codes = &self.bracket.codes;
        let (a, x) = (codes.get(anchor, c, xa), codes.get(self.k, c, xk));
        let anchored = if a.tone == Tone::Good { ANCHORED } else { 0 };
        if x.tone != Tone::Good {
            return anchored;
        }
        let tolerance = (TOLERANCE_STOPS * std::f64::consts::LN_2) as f32;
        let bin = residuals.get(c, a.bin);
        let r = x.value - a.value - bin.centre;
        let excess = match a.tone {
            Tone::Good => r.abs(),
            Tone::Bright => -r,
            Tone::Dark => r,
        } - tolerance;
        if excess > 0.0 && excess * excess > (x.noise + a.noise).max(bin.spread) {
            anchored | DISAGREES
        } else {
            anchored | AGREES
        }
    }
}

/// The pixel mask (255 kept … 0 left out) from the blocks' disagreeing shares, or `None`
/// when no block is left out.
fn mask_of(share: &[f32], width: usize, height: usize) -> Option<Vec<u8>> {
    let (bw, bh) = (width.div_ceil(BLOCK), height.div_ceil(BLOCK));
    // A neighbourhood's mean exceeds the threshold only if one of its blocks does.
    if share.iter().all(|&s| s <= GHOST_SHARE) {
        return None;
    }
    // Two grids and the box filter's scratch, each filter writing one from the other.
    let mut across = vec![0.0f32; share.len()];
    let (mut a, mut b) = (vec![0.0f32; share.len()], vec![0.0f32; share.len()]);
    let mut filter = |from: &[f32], to: &mut [f32]| box_mean(from, (bw, bh), &mut across, to);
    filter(share, &mut a);
    let ghost = |s: &mut f32| *s = if *s > GHOST_SHARE { 1.0 } else { 0.0 };
    a.par_iter_mut().for_each(ghost);
    if a.iter().all(|&g| g == 0.0) {
        return None;
    }
    // Grown by one block, then feathered by two box filters.
    filter(&a, &mut b);
    b.par_iter_mut()
        .for_each(|g| *g = if *g > 0.0 { 1.0 } else { 0.0 });
    filter(&b, &mut a);
    filter(&a, &mut b);
    Some(upsample(&b, bw, bh, width, height))
}

/// Into `out`, the mean over the 3×3 neighbourhood of each cell of the `w × h` `grid`
/// (clamped at the borders: only the cells inside the grid count), along rows into
/// `across` then along columns, rows in parallel.
fn box_mean(grid: &[f32], (w, h): (usize, usize), across: &mut [f32], out: &mut [f32]) {
    across
        .par_chunks_mut(w)
        .zip(grid.par_chunks(w))
        .for_each(|(out, row)| mean_of_three(row, out));
    let across = &*across;
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        let (lo, hi) = (y.saturating_sub(1), (y + 1).min(h - 1));
        row.fill(0.0);
        for above in across[lo * w..(hi + 1) * w].chunks(w) {
            row.iter_mut().zip(above).for_each(|(o, &v)| *o += v);
        }
        let n = (hi - lo + 1) as f32;
        row.iter_mut().for_each(|o| *o /= n);
    });
}

/// Each cell of `row` into `out` as the mean of it and its neighbours in the row (one
/// neighbour at the ends), summed left to right.
fn mean_of_three(row: &[f32], out: &mut [f32]) {
    let w = row.len();
    if w < 2 {
        out.copy_from_slice(row);
        return;
    }
    out[0] = (row[0] + row[1]) / 2.0;
    out[w - 1] = (row[w - 2] + row[w - 1]) / 2.0;
    let (left, middle, right) = (&row[..w - 2], &row[1..w - 1], &row[2..]);
    for (((o, &a), &b), &c) in out[1..w - 1].iter_mut().zip(left).zip(middle).zip(right) {
        *o = (a + b + c) / 3.0;
    }
}

/// Pixel weights `255·(1 − s)` from the block grid `soft` (`s` the left-out share),
/// interpolated bilinearly between block centres (rounded to the nearest code).
fn upsample(soft: &[f32], bw: usize, bh: usize, width: usize, height: usize) -> Vec<u8> {
    let coordinate = |p: usize, n: usize| {
        let t = ((p as f32 + 0.5) / BLOCK as f32 - 0.5).clamp(0.0, (n - 1) as f32);
        let i = (t as usize).min(n.saturating_sub(2));
        (i, (i + 1).min(n - 1), t - i as f32)
    };
    let columns: Vec<(usize, usize, f32)> = (0..width).map(|x| coordinate(x, bw)).collect();
    // Block rows with nothing left out: their pixels are kept.
    let clear: Vec<bool> = soft
        .chunks(bw)
        .map(|r| r.iter().all(|&s| s == 0.0))
        .collect();
    let mut mask = vec![255u8; width * height];
    mask.par_chunks_mut(width).enumerate().for_each(|(y, row)| {
        let (y0, y1, fy) = coordinate(y, bh);
        if clear[y0] && clear[y1] {
            return;
        }
        // The block row interpolated to this pixel row, then along it.
        let (top, bottom) = (&soft[y0 * bw..(y0 + 1) * bw], &soft[y1 * bw..(y1 + 1) * bw]);
        let line: Vec<f32> = top
            .iter()
            .zip(bottom)
            .map(|(&t, &b)| t + (b - t) * fy)
            .collect();
        for (m, &(x0, x1, fx)) in row.iter_mut().zip(&columns) {
            let (a, b) = (line[x0], line[x1]);
            if a != 0.0 || b != 0.0 {
                let s = a + (b - a) * fx;
                *m = (255.0 * (1.0 - s) + 0.5).clamp(0.0, 255.0) as u8;
            }
        }
    });
    mask
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metadata::Camera;
    use std::path::Path;

    fn grey(width: u32, codes: Vec<u8>) -> Frame {
        let h = codes.len() as u32 / width;
        Frame::new(width, h, 1, Samples::Eight(codes)).unwrap()
    }

    fn linear() -> InverseResponse {
        InverseResponse::from_samples(vec![vec![0.0, 1.0]]).unwrap()
    }

    fn bracket<'a>(frames: &'a [(Frame, f64)], camera: &'a Camera) -> Vec<BracketFrame<'a>> {
        frames
            .iter()
            .map(|(frame, exposure)| BracketFrame {
                source: Path::new("frame"),
                frame,
                exposure: *exposure,
                camera,
            })
            .collect()
    }

    /// The masks of `frames` (linear codes) onto the frame alignment would choose.
    fn masks_of(frames: &[(Frame, f64)]) -> GhostMasks {
        let views: Vec<&Frame> = frames.iter().map(|(f, _)| f).collect();
        let reference = crate::align::choose_reference(&views);
        ghost_masks(&bracket(frames, &Camera::default()), &linear(), reference)
    }

    /// A 64×64 linear scene of smooth tones, exposed at `e`, with a square of side 16 at
    /// `(x0, 24)` four times brighter.
    fn shot(e: f64, x0: Option<usize>) -> Frame {
        let codes = (0..64 * 64)
            .map(|p| {
                let (x, y) = (p % 64, p / 64);
                let mut radiance = 0.05 + 0.1 * (x + y) as f64 / 128.0;
                if x0.is_some_and(|x0| (x0..x0 + 16).contains(&x) && (24..40).contains(&y)) {
                    radiance *= 4.0;
                }
                (radiance * e * 255.0).round().min(255.0) as u8
            })
            .collect();
        grey(64, codes)
    }

    #[test]
    fn a_static_bracket_has_no_mask() {
        let frames = [(shot(1.0, Some(8)), 1.0), (shot(2.0, Some(8)), 2.0)];
        let masks = masks_of(&frames);
        assert!(masks.is_empty(), "{:?}", masks.left_out);
        assert_eq!(masks.share(), 0.0);
    }

    /// The masks of three shots whose squares stand at x = 8, 40 and 24.
    fn moved_squares() -> GhostMasks {
        let frames = [
            (shot(1.0, Some(8)), 1.0),
            (shot(2.0, Some(40)), 2.0),
            (shot(0.5, Some(24)), 0.5),
        ];
        masks_of(&frames)
    }

    #[test]
    fn a_moved_square_is_left_out_where_it_differs() {
        let masks = moved_squares();
        let r = masks.reference;
        assert!(masks.masks[r].is_none(), "the reference is never left out");
        // 8-bit: codes 6 (0.0235) to 242 (0.949) lie within WELL_EXPOSED.
        assert_eq!(masks.masks().measured, (6, 242));
        // The squares' centres: x = 16, 48 and 32 in frames 0, 1 and 2; row 32.
        let centre = [32 * 64 + 16, 32 * 64 + 48, 32 * 64 + 32];
        for k in (0..3).filter(|&k| k != r) {
            let mask = masks.masks[k]
                .as_ref()
                .expect("every other frame disagrees");
            // Inside its own square and inside the reference's: left out.
            assert_eq!(mask[centre[k]], 0, "frame {k} in its square");
            assert_eq!(mask[centre[r]], 0, "frame {k} in the reference's square");
            // Far from both: kept.
            assert_eq!(mask[4 * 64 + 4], 255);
            assert_eq!(mask[60 * 64 + 60], 255);
        }
        assert!(
            masks.share() > 0.05 && masks.share() < 0.5,
            "{}",
            masks.share()
        );
    }

    #[test]
    fn the_given_reference_is_the_one_trusted() {
        let shots = [(shot(1.0, Some(8)), 1.0), (shot(2.0, Some(40)), 2.0)];
        let camera = Camera::default();
        let frames = bracket(&shots, &camera);
        for reference in [0, 1] {
            let masks = ghost_masks(&frames, &linear(), reference);
            assert_eq!(masks.reference, reference);
            assert!(
                masks.masks[reference].is_none(),
                "the reference is kept whole"
            );
            assert!(
                masks.masks[1 - reference].is_some(),
                "the other is left out"
            );
        }
        let chosen = ghost_masks(&frames, &linear(), 2).reference;
        let views: Vec<&Frame> = frames.iter().map(|f| f.frame).collect();
        assert_eq!(chosen, crate::align::choose_reference(&views));
    }

    /// Frames `k` of a noisy 160×120 sRGB bracket of the procedural scene, a flat square
    /// of code 230 at `(20 + 50k, 40)` standing in for a subject that moves.
    fn noisy_bracket_with_a_subject() -> Vec<(Frame, f64)> {
        use crate::frame::BitDepth;
        use crate::synthetic::{ResponseCurve, SceneKind, Sensor, expose};
        let radiance = SceneKind::Procedural.render(160, 120, 3);
        let sensor = Sensor {
            read_noise_dn: 1.0,
            seed: 3,
            ..Sensor::noiseless(ResponseCurve::Srgb, BitDepth::Eight)
        };
        [0.25, 1.0, 4.0]
            .into_iter()
            .enumerate()
            .map(|(k, e)| {
                let frame = expose(&radiance, e, &sensor);
                let Samples::Eight(mut codes) = frame.samples().clone() else {
                    unreachable!("the sensor is 8-bit")
                };
                for y in 40..72 {
                    let x0 = 20 + 50 * k;
                    codes[(y * 160 + x0) * 3..(y * 160 + x0 + 32) * 3].fill(230);
                }
                (Frame::new(160, 120, 3, Samples::Eight(codes)).unwrap(), e)
            })
            .collect()
    }

    #[test]
    fn the_tables_decide_as_the_arithmetic_does() {
        let frames = noisy_bracket_with_a_subject();
        let camera = Camera::default();
        let bracket = bracket(&frames, &camera);
        let response = InverseResponse::srgb(3, 1024);
        let views: Vec<&Frame> = frames.iter().map(|(f, _)| f).collect();
        let reference = crate::align::choose_reference(&views);
        let decided = |tabled: bool| {
            let planes = views
                .iter()
                .map(|f| match f.samples() {
                    Samples::Eight(v) => v.as_slice(),
                    Samples::Sixteen(_) => unreachable!("the sensor is 8-bit"),
                })
                .collect();
            let codes = Codes::new(&bracket, &response);
            decide(
                &bracket,
                reference,
                &Bracket {
                    planes,
                    codes,
                    width: 160,
                    height: 120,
                    tabled,
                },
            )
        };
        let (tabled, computed) = (decided(true), decided(false));
        assert!(
            tabled.0.iter().filter(|m| m.is_some()).count() == 2,
            "both frames but the reference are left out somewhere: {:?}",
            tabled.1
        );
        assert_eq!(tabled, computed);
    }

    #[test]
    fn the_reduced_map_keeps_the_least_of_each_cell() {
        let masks = moved_squares();
        let least = masks.least_kept(64 * 64);
        // 64 px within 10: cells of 7 × 7 pixels, the last row and column of one pixel.
        let map = masks
            .least_kept_map(64, 64, 10)
            .expect("frames were left out");
        assert_eq!((map.width, map.height), (10, 10));
        for (cell, &value) in map.least.iter().enumerate() {
            let (cx, cy) = (cell % 10, cell / 10);
            let inside = (cy * 7..(cy * 7 + 7).min(64))
                .flat_map(|y| (cx * 7..(cx * 7 + 7).min(64)).map(move |x| y * 64 + x));
            assert_eq!(
                value,
                inside.map(|p| least[p]).min().unwrap(),
                "cell {cell}"
            );
        }
        assert!(map.least.contains(&0) && map.least.contains(&255));
        let still = [(shot(1.0, Some(8)), 1.0), (shot(2.0, Some(8)), 2.0)];
        let none = masks_of(&still);
        assert_eq!(none.least_kept_map(64, 64, 10), None);
    }

    #[test]
    fn masks_fall_smoothly() {
        let frames = [(shot(1.0, Some(8)), 1.0), (shot(2.0, Some(40)), 2.0)];
        let masks = masks_of(&frames);
        let other = 1 - masks.reference;
        let mask = masks.masks[other]
            .as_ref()
            .expect("the other frame disagrees");
        let row = &mask[32 * 64..33 * 64];
        let steepest = row
            .windows(2)
            .map(|w| (i32::from(w[0]) - i32::from(w[1])).abs())
            .max()
            .unwrap();
        assert!(steepest < 128, "a step of {steepest} in {row:?}");
    }
}
