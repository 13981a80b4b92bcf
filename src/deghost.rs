//! Deghosting: where a frame disagrees with the bracket's reference frame by more than
//! its noise allows, that frame is left out of the merge there.
//!
//! # The test
//!
//! Each frame `k` estimates radiance `x_k = g(B_k)·e_ref/e_k` per sample (see
//! [`crate::merge`]). Where two frames are both well exposed (brightness within
//! [`WELL_EXPOSED`]), they agree unless a moving subject or a misregistration separates
//! them; with `σ_k` the standard deviation of `ln x_k`, frame `k` disagrees with frame `a`
//! in a channel when
//!
//! ```text
//! |ln x_k − ln x_a|  >  Z · √(σ_k² + σ_a²) + δ,          Z = 4,  δ = 0.15 stop · ln 2
//! ```
//!
//! ([`NOISE_SIGMAS`], [`RESPONSE_TOLERANCE_STOPS`]: `δ` absorbs a fitted response's error
//! and the JPEG codec's). The noise of a sample of brightness `B` and linear value
//! `X = g(B)` (in units of the frame's clipping point) is read noise and quantisation,
//! constant in code values and carried through the response's slope, plus shot noise:
//!
//! ```text
//! σ_k² = ((g'(B) · σ_B)² + X / W) / X²,        σ_B = 1.5 codes of 255,  W = 2000 e⁻
//! ```
//!
//! ([`CODE_NOISE`], [`FULL_WELL_ELECTRONS`]: a conservative camera at base ISO; a noisier
//! one is less often left out, never more often).
//!
//! A frame disagrees at a pixel when any channel that both frames expose well
//! disagrees. Frames are tested in order of exposure distance from the reference; each
//! pixel is compared against its *anchor*: the reference where the reference exposes any
//! channel well, otherwise the nearest frame already accepted there (so a region the
//! reference clipped is still checked between the frames that see it).
//!
//! # The mask
//!
//! Disagreement is counted over blocks of [`BLOCK`]×[`BLOCK`] pixels. A block is left out
//! where the share of disagreeing pixels, averaged over its 3×3 neighbourhood, exceeds
//! [`GHOST_SHARE`] (isolated noise never reaches it; a subject does). The left-out blocks
//! grow by one block and are feathered by two box filters of one block, and the mask is
//! interpolated bilinearly back to pixels: a frame's weight falls smoothly to 0 over about
//! two blocks around a ghost, so the reference fills the region without a seam. A frame
//! with no block left out gets no mask, and the merge is then exactly the plain one.

use rayon::prelude::*;

use crate::frame::{Frame, Samples};
use crate::merge::BracketFrame;
use crate::response::InverseResponse;

/// Brightness range (normalised codes) in which a sample is compared.
pub const WELL_EXPOSED: (f64, f64) = (0.02, 0.95);

/// `Z`: standard deviations of the difference beyond which two samples disagree.
pub const NOISE_SIGMAS: f64 = 4.0;

/// `δ`: a disagreement this large (stops) is always allowed, for the response's error.
pub const RESPONSE_TOLERANCE_STOPS: f64 = 0.15;

/// `σ_B`: read noise and quantisation, in codes of an 8-bit scale.
pub const CODE_NOISE: f64 = 1.5;

/// `W`: electrons at the clipping point, for the shot noise.
pub const FULL_WELL_ELECTRONS: f64 = 2000.0;

/// Side of the blocks over which disagreement is counted, pixels.
pub const BLOCK: usize = 4;

/// Share of disagreeing pixels in a block's neighbourhood above which the block is left out.
pub const GHOST_SHARE: f32 = 0.2;

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

    /// The masks as the merge takes them, one per input frame.
    pub fn weights(&self) -> Vec<Option<&[u8]>> {
        self.masks.iter().map(|m| m.as_deref()).collect()
    }
}

/// The frame that exposes most of the scene well: the largest number of samples within
/// [`WELL_EXPOSED`] (every 4th pixel of every 4th row counted); ties go to the earlier.
pub fn choose_reference(frames: &[BracketFrame<'_>]) -> usize {
    let count = |f: &Frame| {
        let max = f64::from(f.bit_depth().max_code());
        let (lo, hi) = (WELL_EXPOSED.0 * max, WELL_EXPOSED.1 * max);
        let row = f.width() as usize * f.channels();
        let good = |c: f64| c >= lo && c <= hi;
        match f.samples() {
            Samples::Eight(v) => strided(v, row, f.channels(), |c| good(f64::from(c))),
            Samples::Sixteen(v) => strided(v, row, f.channels(), |c| good(f64::from(c))),
        }
    };
    let counts: Vec<usize> = frames.iter().map(|f| count(f.frame)).collect();
    let best = counts.iter().copied().max().unwrap_or(0);
    counts.iter().position(|&c| c == best).unwrap_or(0)
}

/// Samples of every 4th pixel of every 4th row for which `good` holds.
fn strided<T: Copy>(v: &[T], row: usize, channels: usize, good: impl Fn(T) -> bool) -> usize {
    v.chunks(row)
        .step_by(4)
        .flat_map(|r| r.chunks(channels).step_by(4).flatten())
        .filter(|&&c| good(c))
        .count()
}

/// Per code of one frame and channel: `ln x`, `σ` of it, and whether it is well exposed.
#[derive(Clone, Copy)]
struct Code {
    ln_x: f32,
    sigma: f32,
    good: bool,
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
        let sigma_b = CODE_NOISE / 255.0;
        let h = 1.0 / 256.0;
        let mut table = Vec::with_capacity(frames.len() * channels * levels);
        for f in frames {
            for c in 0..channels {
                for code in 0..levels {
                    let b = code as f64 / (levels - 1) as f64;
                    let x = response.eval(c, b).max(1e-9);
                    let (lo, hi) = ((b - h).max(0.0), (b + h).min(1.0));
                    let slope = (response.eval(c, hi) - response.eval(c, lo)) / (hi - lo);
                    let var = ((slope * sigma_b).powi(2) + x / FULL_WELL_ELECTRONS) / (x * x);
                    table.push(Code {
                        ln_x: (x * e_ref / f.exposure).ln() as f32,
                        sigma: var.sqrt() as f32,
                        good: b >= WELL_EXPOSED.0 && b <= WELL_EXPOSED.1 && x > 1e-6,
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
}

/// No anchor yet at a pixel.
const NO_ANCHOR: u8 = u8::MAX;

/// How two frames compare at one pixel.
#[derive(PartialEq)]
enum Verdict {
    /// No channel both expose well.
    Unknown,
    Agree,
    Disagree,
}

/// Decides, for every frame of `frames` but the reference, where it is left out of the
/// merge (module docs). Frames must share size, depth and channels (the merge checks it).
pub fn ghost_masks(frames: &[BracketFrame<'_>], response: &InverseResponse) -> GhostMasks {
    let reference = choose_reference(frames);
    let n = frames.len();
    assert!(
        n <= NO_ANCHOR as usize,
        "fewer than 255 frames in a bracket"
    );
    let codes = Codes::new(frames, response);
    let first = frames[0].frame;
    let (width, height) = (first.width() as usize, first.height() as usize);
    let mut anchor = vec![NO_ANCHOR; width * height];
    let mut masks = vec![None; n];
    let mut left_out = vec![0.0; n];
    for k in by_distance(frames, reference) {
        let disagree = match first.samples() {
            Samples::Eight(_) => compare(frames, &codes, k, &mut anchor, eight),
            Samples::Sixteen(_) => compare(frames, &codes, k, &mut anchor, sixteen),
        };
        if k == reference {
            continue;
        }
        if let Some(mask) = mask_of(&disagree, width, height) {
            left_out[k] = mask.iter().filter(|&&m| m < 128).count() as f64 / mask.len() as f64;
            masks[k] = Some(mask);
        }
    }
    GhostMasks {
        reference,
        masks,
        left_out,
    }
}

fn eight(f: &Frame) -> &[u8] {
    match f.samples() {
        Samples::Eight(v) => v,
        Samples::Sixteen(_) => &[],
    }
}

fn sixteen(f: &Frame) -> &[u16] {
    match f.samples() {
        Samples::Sixteen(v) => v,
        Samples::Eight(_) => &[],
    }
}

/// Input indices, the reference first, then by `|ln(e_k/e_ref)|` (stable).
fn by_distance(frames: &[BracketFrame<'_>], reference: usize) -> Vec<usize> {
    let e_ref = frames[reference].exposure;
    let mut order: Vec<usize> = (0..frames.len()).collect();
    order.sort_by(|&a, &b| {
        let d = |i: usize| (frames[i].exposure / e_ref).ln().abs();
        d(a).total_cmp(&d(b))
    });
    order
}

/// Blocks of frame `k` against each pixel's anchor: per block, the share of its compared
/// pixels that disagree (a grid of `⌈w/BLOCK⌉ × ⌈h/BLOCK⌉`). Pixels without an anchor
/// that `k` exposes well take `k` as their anchor.
fn compare<T: Copy + Into<usize> + Sync>(
    frames: &[BracketFrame<'_>],
    codes: &Codes,
    k: usize,
    anchor: &mut [u8],
    samples: fn(&Frame) -> &[T],
) -> Vec<f32> {
    let first = frames[0].frame;
    let (width, channels) = (first.width() as usize, first.channels());
    let blocks_x = width.div_ceil(BLOCK);
    let all: Vec<&[T]> = frames.iter().map(|f| samples(f.frame)).collect();
    let mut share = vec![0.0f32; blocks_x * (first.height() as usize).div_ceil(BLOCK)];
    anchor
        .par_chunks_mut(width * BLOCK)
        .zip(share.par_chunks_mut(blocks_x))
        .enumerate()
        .for_each(|(band, (anchors, shares))| {
            let mut counts = vec![(0u32, 0u32); blocks_x];
            for (i, a) in anchors.iter_mut().enumerate() {
                let p = band * BLOCK * width + i;
                let sample = |f: usize, c: usize| codes.get(f, c, all[f][p * channels + c].into());
                let verdict = if *a == NO_ANCHOR {
                    Verdict::Unknown
                } else {
                    verdict(channels, |c| (sample(k, c), sample(usize::from(*a), c)))
                };
                let count = &mut counts[(i % width) / BLOCK];
                match verdict {
                    Verdict::Disagree => *count = (count.0 + 1, count.1 + 1),
                    Verdict::Agree => count.1 += 1,
                    Verdict::Unknown if *a == NO_ANCHOR => {
                        if (0..channels).any(|c| sample(k, c).good) {
                            *a = k as u8;
                        }
                    }
                    Verdict::Unknown => {}
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

/// The verdict over `channels` of the code pairs `pair(c) = (frame, anchor)`.
#[inline]
fn verdict(channels: usize, pair: impl Fn(usize) -> (Code, Code)) -> Verdict {
    let tolerance = (RESPONSE_TOLERANCE_STOPS * std::f64::consts::LN_2) as f32;
    let mut seen = false;
    for c in 0..channels {
        let (x, a) = pair(c);
        if !(x.good && a.good) {
            continue;
        }
        seen = true;
        let allowed = NOISE_SIGMAS as f32 * x.sigma.hypot(a.sigma) + tolerance;
        if (x.ln_x - a.ln_x).abs() > allowed {
            return Verdict::Disagree;
        }
    }
    if seen {
        Verdict::Agree
    } else {
        Verdict::Unknown
    }
}

/// The pixel mask (255 kept … 0 left out) from the blocks' disagreeing shares, or `None`
/// when no block is left out.
fn mask_of(share: &[f32], width: usize, height: usize) -> Option<Vec<u8>> {
    let (bw, bh) = (width.div_ceil(BLOCK), height.div_ceil(BLOCK));
    let neighbourhood = box_mean(share, bw, bh, 1);
    let ghost: Vec<f32> = neighbourhood
        .iter()
        .map(|&s| if s > GHOST_SHARE { 1.0 } else { 0.0 })
        .collect();
    if ghost.iter().all(|&g| g == 0.0) {
        return None;
    }
    let grown: Vec<f32> = box_mean(&ghost, bw, bh, 1)
        .iter()
        .map(|&g| if g > 0.0 { 1.0 } else { 0.0 })
        .collect();
    let soft = box_mean(&box_mean(&grown, bw, bh, 1), bw, bh, 1);
    Some(upsample(&soft, bw, bh, width, height))
}

/// The mean over the `(2r+1)²` neighbourhood of each cell (clamped at the borders: only
/// the cells inside the grid count).
fn box_mean(grid: &[f32], w: usize, h: usize, r: usize) -> Vec<f32> {
    let pass = |src: &[f32], along_x: bool| -> Vec<f32> {
        let mut out = vec![0.0; src.len()];
        for y in 0..h {
            for x in 0..w {
                let (i, n) = if along_x { (x, w) } else { (y, h) };
                let (lo, hi) = (i.saturating_sub(r), (i + r).min(n - 1));
                let at = |j: usize| if along_x { y * w + j } else { j * w + x };
                let sum: f32 = (lo..=hi).map(|j| src[at(j)]).sum();
                out[y * w + x] = sum / (hi - lo + 1) as f32;
            }
        }
        out
    };
    pass(&pass(grid, true), false)
}

/// Pixel weights `255·(1 − s)` from the block grid `soft` (`s` the left-out share),
/// interpolated bilinearly between block centres.
fn upsample(soft: &[f32], bw: usize, bh: usize, width: usize, height: usize) -> Vec<u8> {
    let coordinate = |p: usize, n: usize| {
        let t = ((p as f32 + 0.5) / BLOCK as f32 - 0.5).clamp(0.0, (n - 1) as f32);
        let i = (t as usize).min(n.saturating_sub(2));
        (i, (i + 1).min(n - 1), t - i as f32)
    };
    let mut mask = vec![0u8; width * height];
    mask.par_chunks_mut(width).enumerate().for_each(|(y, row)| {
        let (y0, y1, fy) = coordinate(y, bh);
        for (x, m) in row.iter_mut().enumerate() {
            let (x0, x1, fx) = coordinate(x, bw);
            let at = |yy: usize, xx: usize| soft[yy * bw + xx];
            let top = at(y0, x0) * (1.0 - fx) + at(y0, x1) * fx;
            let bottom = at(y1, x0) * (1.0 - fx) + at(y1, x1) * fx;
            let s = top * (1.0 - fy) + bottom * fy;
            *m = (255.0 * (1.0 - s)).round().clamp(0.0, 255.0) as u8;
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
        let camera = Camera::default();
        let masks = ghost_masks(&bracket(&frames, &camera), &linear());
        assert!(masks.is_empty(), "{:?}", masks.left_out);
        assert_eq!(masks.share(), 0.0);
    }

    #[test]
    fn a_moved_square_is_left_out_where_it_differs() {
        let frames = [
            (shot(1.0, Some(8)), 1.0),
            (shot(2.0, Some(40)), 2.0),
            (shot(0.5, Some(24)), 0.5),
        ];
        let camera = Camera::default();
        let masks = ghost_masks(&bracket(&frames, &camera), &linear());
        assert_eq!(
            masks.reference, 0,
            "the frame that exposes most pixels well"
        );
        assert!(masks.masks[0].is_none(), "the reference is never left out");
        let mask = masks.masks[1].as_ref().expect("frame 1 disagrees");
        // Inside the square of frame 1 and inside the reference's square: left out.
        assert_eq!(mask[32 * 64 + 48], 0);
        assert_eq!(mask[32 * 64 + 16], 0);
        // Far from both: kept.
        assert_eq!(mask[4 * 64 + 4], 255);
        assert_eq!(mask[60 * 64 + 60], 255);
        assert!(masks.masks[2].is_some());
        assert!(
            masks.share() > 0.05 && masks.share() < 0.5,
            "{}",
            masks.share()
        );
    }

    #[test]
    fn masks_fall_smoothly() {
        let frames = [(shot(1.0, Some(8)), 1.0), (shot(2.0, Some(40)), 2.0)];
        let camera = Camera::default();
        let masks = ghost_masks(&bracket(&frames, &camera), &linear());
        let mask = masks.masks[1].as_ref().expect("frame 1 disagrees");
        let row = &mask[32 * 64..33 * 64];
        let steepest = row
            .windows(2)
            .map(|w| (i32::from(w[0]) - i32::from(w[1])).abs())
            .max()
            .unwrap();
        assert!(steepest < 128, "a step of {steepest} in {row:?}");
    }

    #[test]
    fn the_reference_exposes_most_of_the_scene_well() {
        let frames = [
            (shot(0.02, None), 0.02),
            (shot(1.0, None), 1.0),
            (shot(30.0, None), 30.0),
        ];
        let camera = Camera::default();
        assert_eq!(choose_reference(&bracket(&frames, &camera)), 1);
    }
}
