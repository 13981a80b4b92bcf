//! Resampling frames onto the reference grid (bilinear, rows in parallel), and the raw
//! mosaics' alignment, which estimates on whole CFA tiles and warps each CFA position's
//! sub-lattice.

use std::ops::Range;

use multiversion::multiversion;
use rayon::prelude::*;

use super::{AlignFrame, Alignment};
use crate::frame::{Frame, Samples};

/// Integer codes a frame holds.
trait Code: Copy + Send + Sync + Ord + Into<f32> + Into<u32> {
    const ZERO: Self;
    const TOP: Self;
    /// The low bits of `k` (which fits).
    fn from_low_bits(k: u32) -> Self;
}

impl Code for u8 {
    const ZERO: u8 = 0;
    const TOP: u8 = u8::MAX;
    fn from_low_bits(k: u32) -> u8 {
        k as u8
    }
}

impl Code for u16 {
    const ZERO: u16 = 0;
    const TOP: u16 = u16::MAX;
    fn from_low_bits(k: u32) -> u16 {
        k as u16
    }
}

/// `2²³`: adding it to an `f32` in `[0, 2²²)` leaves that value rounded to the nearest
/// integer (ties to even) in the low bits of the sum's mantissa. Unlike `as`, which
/// saturates, this compiles to vector instructions.
const ROUNDING: f32 = 8_388_608.0;

/// `v` in `[0, 2²²)` rounded to the nearest integer (ties to even).
fn rounded(v: f32) -> u32 {
    (v + ROUNDING).to_bits() - ROUNDING.to_bits()
}

/// Every moved frame resampled onto the reference grid (`None` for a frame merged as it
/// is), by [`warp_frame`].
pub fn warp_frames(frames: &[AlignFrame<'_>], alignment: &Alignment) -> Vec<Option<Frame>> {
    let reference = frames[alignment.reference].frame;
    frames
        .iter()
        .zip(&alignment.frames)
        .map(|(f, a)| {
            a.motion
                .and_then(|_| warp_frame(f.frame, reference, &a.transform))
        })
        .collect()
}

/// `frame` resampled at `T·x` for every pixel `x` of the reference grid, bilinear in code
/// values. A sample whose four neighbours include a clipped code (0 or the top code) takes
/// that code (the top code first); a pixel outside the frame takes the top code where the
/// reference's sample is in the upper half of its range and 0 otherwise (see the parent
/// module's "Coverage"). `None` when the frames' shapes differ (the merge refuses them).
pub fn warp_frame(frame: &Frame, reference: &Frame, t: &[[f64; 3]; 3]) -> Option<Frame> {
    let (w, h, c) = (frame.width(), frame.height(), frame.channels());
    if (w, h, c) != (reference.width(), reference.height(), reference.channels()) || w < 2 || h < 2
    {
        return None;
    }
    let shape = (w as usize, h as usize, c);
    let samples = match (frame.samples(), reference.samples()) {
        (Samples::Eight(v), Samples::Eight(r)) => Samples::Eight(warp_codes(v, r, shape, t)),
        (Samples::Sixteen(v), Samples::Sixteen(r)) => Samples::Sixteen(warp_codes(v, r, shape, t)),
        _ => return None,
    };
    Frame::new(w, h, c, samples)
        .ok()
        .map(|f| f.with_compression(frame.compression()))
}

fn warp_codes<T: Code>(
    codes: &[T],
    reference: &[T],
    (w, h, c): (usize, usize, usize),
    t: &[[f64; 3]; 3],
) -> Vec<T> {
    let mut out = vec![T::ZERO; codes.len()];
    let grid = Grid {
        codes,
        reference,
        w,
    };
    out.par_chunks_mut(w * c).enumerate().for_each_init(
        || Positions::new(w, c),
        |at, (y, row)| {
            if c == 1 {
                warp_row::<T, 1>(&grid, at, (w, h, y), t, row);
            } else {
                warp_row::<T, 3>(&grid, at, (w, h, y), t, row);
            }
        },
    );
    out
}

/// Output row `y` of a `w × h` frame of `C` channels, resampled from `grid` at `T·x`
/// (`at` is scratch). Compiled also for AVX2, taken at run time where the processor has
/// it: the same operations in wider vectors, so the same codes.
#[multiversion(targets("x86_64+avx2"))]
fn warp_row<T: Code, const C: usize>(
    grid: &Grid<'_, T>,
    at: &mut Positions,
    (w, h, y): (usize, usize, usize),
    t: &[[f64; 3]; 3],
    row: &mut [T],
) {
    at.locate::<C>((w, h), y, t);
    grid.row::<C>(y, row, at);
}

/// The frame being resampled and the reference it is resampled onto.
struct Grid<'a, T> {
    codes: &'a [T],
    reference: &'a [T],
    w: usize,
}

/// Where one output row reads the frame: per pixel whether it is covered and the upper
/// left `(x0, y0)` of its four neighbours, and per sample (channels interleaved) the
/// bilinear weights `(fx, fy)`.
struct Positions {
    covered: Vec<bool>,
    x0: Vec<u32>,
    y0: Vec<u32>,
    /// Per pixel 1 where it does not continue the [`Segment::Run`] of the pixel before it
    /// (the first pixel, one not covered or after one not covered, one whose neighbours
    /// are not those of the pixel before moved one to the right), else 0.
    breaks: Vec<u8>,
    /// The weights per pixel.
    pixel_fx: Vec<f32>,
    pixel_fy: Vec<f32>,
    /// The same per sample.
    fx: Vec<f32>,
    fy: Vec<f32>,
}

impl Positions {
    fn new(width: usize, channels: usize) -> Positions {
        Positions {
            covered: vec![false; width],
            x0: vec![0; width],
            y0: vec![0; width],
            breaks: vec![1; width],
            pixel_fx: vec![0.0; width],
            pixel_fy: vec![0.0; width],
            fx: vec![0.0; width * channels],
            fy: vec![0.0; width * channels],
        }
    }

    /// Output row `y`'s positions in a `w × h` frame, `C` channels: `T·(x, y, 1)ᵀ` over
    /// its third coordinate (in `f64`, linear in `x` before the division), then as `f32`
    /// (off by under 0.001 px on frames under 16 384 px): `x0` its floor (the integer
    /// nearest `sx − ½`, one up where that tie went down) and at most `w − 2`,
    /// `fx = sx − x0` in `[0, 1]` where covered; the same in `y`. Written so that it
    /// vectorises.
    #[inline(always)]
    fn locate<const C: usize>(&mut self, (w, h): (usize, usize), y: usize, t: &[[f64; 3]; 3]) {
        let (last_x, last_y) = ((w - 1) as f32, (h - 1) as f32);
        let (most_x0, most_y0) = ((w - 2) as f32, (h - 2) as f32);
        let yf = y as f64;
        let start = [0, 1, 2].map(|r| t[r][1] * yf + t[r][2]);
        let along = [0, 1, 2].map(|r| t[r][0]);
        let corner = |s: f32, most: f32| {
            let nearest = s - 0.5 + ROUNDING - ROUNDING;
            let floor = if s - nearest >= 1.0 {
                nearest + 1.0
            } else {
                nearest
            };
            floor.max(0.0).min(most)
        };
        let pixels = self
            .covered
            .iter_mut()
            .zip(self.x0.iter_mut().zip(&mut self.y0))
            .zip(self.pixel_fx.iter_mut().zip(&mut self.pixel_fy));
        for (x, ((covered, (x0, y0)), (fx, fy))) in (0..w as u32).zip(pixels) {
            let xf = f64::from(x);
            let inverse = 1.0 / (start[2] + along[2] * xf);
            let sx = ((start[0] + along[0] * xf) * inverse) as f32;
            let sy = ((start[1] + along[1] * xf) * inverse) as f32;
            *covered = sx >= 0.0 && sy >= 0.0 && sx <= last_x && sy <= last_y;
            let (cx, cy) = (corner(sx, most_x0), corner(sy, most_y0));
            (*x0, *y0) = (rounded(cx), rounded(cy));
            (*fx, *fy) = (sx - cx, sy - cy);
        }
        spread::<C>(&self.pixel_fx, &mut self.fx);
        spread::<C>(&self.pixel_fy, &mut self.fy);
        self.mark_breaks();
    }

    /// [`Positions::breaks`] from the pixels' positions, in a loop that vectorises.
    #[inline(always)]
    fn mark_breaks(&mut self) {
        let n = self.breaks.len().saturating_sub(1);
        if n == 0 {
            return;
        }
        let (covered, x0, y0) = (&self.covered, &self.x0, &self.y0);
        let (c, x, y) = (&covered[..n], &x0[..n], &y0[..n]);
        let (c1, x1, y1) = (&covered[1..], &x0[1..], &y0[1..]);
        for (i, b) in self.breaks[1..].iter_mut().enumerate() {
            let continues = c[i] & c1[i] & (x1[i] == x[i].wrapping_add(1)) & (y1[i] == y[i]);
            *b = u8::from(!continues);
        }
    }
}

/// The first index at or after `from` whose byte in `breaks` is not 0, or the length:
/// eight bytes at a time.
#[inline(always)]
fn next_break(breaks: &[u8], from: usize) -> usize {
    let mut words = breaks[from..].chunks_exact(8);
    let mut at = from;
    for word in &mut words {
        let bits = u64::from_le_bytes(word.try_into().expect("eight bytes"));
        if bits != 0 {
            return at + bits.trailing_zeros() as usize / 8;
        }
        at += 8;
    }
    let rest = words.remainder().iter().position(|&b| b != 0);
    rest.map_or(breaks.len(), |i| at + i)
}

/// Each of `per_pixel`'s values `C` times over into `per_sample`, four pixels at a time;
/// three channels as an explicit pattern of the four values, which compiles to vector
/// shuffles (the general loop's moves are scalar).
#[inline(always)]
fn spread<const C: usize>(per_pixel: &[f32], per_sample: &mut [f32]) {
    let mut samples = per_sample.chunks_exact_mut(4 * C);
    let mut pixels = per_pixel.chunks_exact(4);
    for (s, p) in (&mut samples).zip(&mut pixels) {
        if C == 3 {
            let [a, b, c, d] = [p[0], p[1], p[2], p[3]];
            s.copy_from_slice(&[a, a, a, b, b, b, c, c, c, d, d, d]);
        } else {
            for (k, s) in s.iter_mut().enumerate() {
                *s = p[k / C];
            }
        }
    }
    let rest = samples.into_remainder().chunks_exact_mut(C);
    for (s, &p) in rest.zip(pixels.remainder()) {
        s.fill(p);
    }
}

/// A stretch of an output row (see [`Positions::segments`]).
enum Segment {
    /// A pixel the frame does not cover.
    Uncovered(usize),
    /// Covered pixels whose four neighbours lie on the same two frame rows at the same
    /// offset from the output pixel; the first one's upper left neighbour `(x0, y0)`.
    Run(Range<usize>, (usize, usize)),
}

impl Positions {
    /// The row's pixels in order, each not covered alone and the covered ones in
    /// [`Segment::Run`]s: a near-identity transform keeps runs long.
    fn segments(&self) -> impl Iterator<Item = Segment> + '_ {
        let w = self.covered.len();
        let mut x = 0;
        std::iter::from_fn(move || {
            if x >= w {
                return None;
            }
            let start = x;
            if !self.covered[x] {
                x += 1;
                return Some(Segment::Uncovered(start));
            }
            x = next_break(&self.breaks, x + 1);
            let corner = (self.x0[start] as usize, self.y0[start] as usize);
            Some(Segment::Run(start..x, corner))
        })
    }
}

impl<T: Code> Grid<'_, T> {
    /// Output row `y` of `C` interleaved channels at the positions `at`, in the
    /// [`Positions::segments`] (a run reads two contiguous spans of the frame).
    #[inline(always)]
    fn row<const C: usize>(&self, y: usize, row: &mut [T], at: &Positions) {
        let w = self.w;
        for segment in at.segments() {
            match segment {
                Segment::Uncovered(x) => {
                    self.uncovered(&mut row[x * C..(x + 1) * C], (y * w + x) * C);
                }
                Segment::Run(pixels, (x0, y0)) => {
                    let samples = pixels.start * C..pixels.end * C;
                    self.run::<C>(
                        &mut row[samples.clone()],
                        (y0 * w + x0) * C,
                        &at.fx[samples.clone()],
                        &at.fy[samples],
                    );
                }
            }
        }
    }

    /// One run: output sample `i` mixes the frame's samples `base + i` and `base + i + C`
    /// on the upper row and the same on the lower, with weights `fx[i]`, `fy[i]`: the
    /// top code if one of the four is clipped there, else 0 if one is 0, else the
    /// bilinear mix of their codes [`rounded`].
    #[inline(always)]
    fn run<const C: usize>(&self, out: &mut [T], base: usize, fx: &[f32], fy: &[f32]) {
        let n = out.len();
        let lower = base + self.w * C;
        let (a, b) = (
            &self.codes[base..base + n],
            &self.codes[base + C..base + C + n],
        );
        let (d, e) = (
            &self.codes[lower..lower + n],
            &self.codes[lower + C..lower + C + n],
        );
        let (fx, fy) = (&fx[..n], &fy[..n]);
        for i in 0..n {
            let high = a[i].max(b[i]).max(d[i].max(e[i]));
            let low = a[i].min(b[i]).min(d[i].min(e[i]));
            let [p, q, r, s] = [a[i], b[i], d[i], e[i]].map(Into::<f32>::into);
            let upper = p + (q - p) * fx[i];
            let under = r + (s - r) * fx[i];
            let mix = T::from_low_bits(rounded(upper + (under - upper) * fy[i]));
            let unclipped = if low == T::ZERO { T::ZERO } else { mix };
            out[i] = if high == T::TOP { T::TOP } else { unclipped };
        }
    }

    /// A pixel the frame does not cover: the top code where the reference's sample at
    /// `i` is in the upper half of its range, 0 otherwise.
    fn uncovered(&self, o: &mut [T], i: usize) {
        let top: u32 = T::TOP.into();
        let n = o.len();
        for (o, &r) in o.iter_mut().zip(&self.reference[i..i + n]) {
            *o = if Into::<u32>::into(r) * 2 > top {
                T::TOP
            } else {
                T::ZERO
            };
        }
    }
}

#[cfg(feature = "raw")]
pub use raw::{MosaicFrame, align_mosaics, warp_mosaics};

#[cfg(feature = "raw")]
mod raw {
    use std::sync::OnceLock;

    use multiversion::multiversion;
    use nalgebra::Matrix3;
    use rayon::prelude::*;

    use super::{Code, Positions, Segment, rounded};

    use super::super::estimate::{self, FullFrame, Geometry, Picture, Pyramid};
    use super::super::{AlignMode, Alignment, SMALLEST_SIDE, exposure_weight};
    use crate::raw::{CLIPPED, RawInfo};

    /// One raw mosaic as alignment needs it.
    #[derive(Debug, Clone, Copy)]
    pub struct MosaicFrame<'a> {
        /// Codes, row by row.
        pub codes: &'a [u16],
        /// Width in pixels.
        pub width: usize,
        /// Height in pixels.
        pub height: usize,
        /// Levels and CFA.
        pub info: &'a RawInfo,
        /// Relative exposure `e = t·S/N²`, > 0.
        pub exposure: f64,
    }

    /// Code `k` as a normalised signal `(k − b)/d`, `b` its black level and `d = w − b`.
    fn normalised(k: u16, b: f32, d: f32) -> f32 {
        (f32::from(k) - b) / d
    }

    impl MosaicFrame<'_> {
        /// The normalised signal `(k − b)/(w − b)` of pixel `(x, y)`.
        fn signal(&self, x: usize, y: usize) -> f32 {
            let b = self.info.black_at(x, y);
            normalised(self.codes[y * self.width + x], b, self.info.white - b)
        }

        /// Per row of the black-level tile, every column's black level `b` and `w − b`:
        /// what [`MosaicFrame::signal_row`] and [`least_clipped_codes`] read.
        fn levels(&self) -> Vec<(Vec<f32>, Vec<f32>)> {
            (0..self.info.black_height.max(1))
                .map(|y| {
                    let black: Vec<f32> =
                        (0..self.width).map(|x| self.info.black_at(x, y)).collect();
                    let span = black.iter().map(|b| self.info.white - b).collect();
                    (black, span)
                })
                .collect()
        }

        /// Row `y`'s signal as [`MosaicFrame::signal`] gives it, into `out`, with the
        /// frame's [`MosaicFrame::levels`] (a loop the compiler vectorises).
        fn signal_row(&self, levels: &[(Vec<f32>, Vec<f32>)], y: usize, out: &mut [f32]) {
            let (black, span) = &levels[y % levels.len()];
            let codes = &self.codes[y * self.width..(y + 1) * self.width];
            for (((o, &k), &b), &d) in out.iter_mut().zip(codes).zip(black).zip(span) {
                *o = normalised(k, b, d);
            }
        }

        /// The score of `choose_reference` on the signal: the hat weight of every
        /// fourth row and column's well-exposed samples, summed.
        fn exposure_score(&self) -> f64 {
            let mut sum = 0.0;
            for y in (0..self.height).step_by(4) {
                for x in (0..self.width).step_by(4) {
                    sum += exposure_weight(f64::from(self.signal(x, y)));
                }
            }
            sum
        }
    }

    /// Aligns raw `frames` onto the one with the most well-exposed samples, under `mode`,
    /// on luminance images of whole CFA tiles (see the parent module's "Camera raw").
    pub fn align_mosaics(frames: &[MosaicFrame<'_>], mode: AlignMode) -> Alignment {
        let mut reference = 0;
        let mut best = f64::NEG_INFINITY;
        for (k, f) in frames.iter().enumerate() {
            let score = f.exposure_score();
            if score > best {
                (reference, best) = (k, score);
            }
        }
        let Some(model) = mode.model() else {
            return Alignment::unmoved(mode, reference, frames.len(), None);
        };
        let first = &frames[reference];
        let cfa = &first.info.cfa;
        let why = if cfa.width != 2 || cfa.height != 2 {
            Some(format!(
                "a {}×{} CFA (X-Trans) is not aligned",
                cfa.width, cfa.height
            ))
        } else if frames
            .iter()
            .any(|f| (f.width, f.height, &f.info.cfa) != (first.width, first.height, cfa))
        {
            Some("the mosaics differ in size or CFA: not aligned".to_string())
        } else if first.width.min(first.height) < SMALLEST_SIDE as usize {
            Some(format!(
                "the frames are under {SMALLEST_SIDE} pixels on a side: not aligned"
            ))
        } else {
            None
        };
        if why.is_some() {
            return Alignment::unmoved(mode, reference, frames.len(), why);
        }
        let step = estimate::step_for(first.width, first.height, 2);
        let tiles: Vec<Tiles<'_>> = frames.iter().map(Tiles::of).collect();
        let pyramids: Vec<Pyramid> = tiles.par_iter().map(|t| t.pyramid(step)).collect();
        let full: Vec<FullFrame<'_>> = tiles
            .iter()
            .map(|t| FullFrame::new(t, t.frame.exposure))
            .collect();
        let full = (step > 2).then_some(full.as_slice());
        let geometry = Geometry::new(first.width as u32, first.height as u32);
        Alignment {
            mode,
            reference,
            frames: estimate::register_all(&pyramids, full, reference, &geometry, model),
        }
    }

    /// A raw frame with its [`MosaicFrame::levels`]: the pyramid's rows, and the
    /// [`Picture`] the full-resolution refinement reads, one value per 2 × 2 CFA tile:
    /// the mean of its four normalised signals, filtered by the binomial kernel
    /// `[1 2 1]/4` in both directions (as the pyramid's levels are) and weighed as
    /// [`raw_log_weight`] of the result, usable when all nine tiles it reads are wholly
    /// within [`RAW_FLOOR`] and [`CLIPPED`] (the parent module's "Camera raw" says why
    /// filtered). The picture is made on first use: 4 bytes a tile, a byte a pixel.
    struct Tiles<'a> {
        frame: &'a MosaicFrame<'a>,
        levels: Vec<(Vec<f32>, Vec<f32>)>,
        /// Per tile its filtered value, -1 where not usable.
        filtered: OnceLock<Vec<f32>>,
    }

    impl<'a> Tiles<'a> {
        fn of(frame: &'a MosaicFrame<'a>) -> Tiles<'a> {
            Tiles {
                frame,
                levels: frame.levels(),
                filtered: OnceLock::new(),
            }
        }

        /// Row `y`'s signals (clamped at 0) and their [`raw_log_weight`]s.
        fn signal_row(&self, y: usize, values: &mut [f32], weights: &mut [f32]) {
            self.frame.signal_row(&self.levels, y, values);
            for (v, w) in values.iter_mut().zip(weights.iter_mut()) {
                *w = raw_log_weight(*v);
                *v = v.max(0.0);
            }
        }

        fn pyramid(&self, step: usize) -> Pyramid {
            let (f, range) = (self.frame, (RAW_FLOOR, CLIPPED));
            Pyramid::from_rows(f.width, f.height, step, f.exposure, range, |y, v, w| {
                self.signal_row(y, v, w)
            })
        }

        /// The filtered tile image: each tile row's means filtered along the row, then
        /// the rows filtered down the columns.
        fn filtered(&self) -> &[f32] {
            self.filtered.get_or_init(|| {
                let (w, h) = self.size();
                let mut along = vec![-1f32; w * h];
                along.par_chunks_mut(w).enumerate().for_each_init(
                    || (vec![0f32; 2 * w], vec![0f32; 2 * w], vec![0f32; w]),
                    |(top, bottom, means), (y, out)| {
                        self.frame.signal_row(&self.levels, 2 * y, top);
                        self.frame.signal_row(&self.levels, 2 * y + 1, bottom);
                        let pairs = top.chunks_exact(2).zip(bottom.chunks_exact(2));
                        for (m, (t, b)) in means.iter_mut().zip(pairs) {
                            *m = tile([t[0], t[1], b[0], b[1]]);
                        }
                        along_row(means, out);
                    },
                );
                let mut out = vec![-1f32; w * h];
                out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
                    if y > 0 && y + 1 < h {
                        for (x, o) in row.iter_mut().enumerate() {
                            let column = [
                                along[x + (y - 1) * w],
                                along[x + y * w],
                                along[x + (y + 1) * w],
                            ];
                            *o = filter(column);
                        }
                    }
                });
                out
            })
        }
    }

    impl Picture for Tiles<'_> {
        fn size(&self) -> (usize, usize) {
            (self.frame.width / 2, self.frame.height / 2)
        }

        fn step(&self) -> usize {
            2
        }

        fn pixel(&self, x: usize, y: usize) -> (f32, f32) {
            let v = self.filtered()[y * self.size().0 + x];
            weighed(v)
        }

        fn row(&self, y: usize, values: &mut [f32], weights: &mut [f32]) {
            let w = self.size().0;
            let row = &self.filtered()[y * w..(y + 1) * w];
            for ((value, weight), &v) in values.iter_mut().zip(weights.iter_mut()).zip(row) {
                (*value, *weight) = weighed(v);
            }
        }

        /// Yes: the parent module's "Camera raw" says why.
        fn tests_perspective(&self) -> bool {
            true
        }
    }

    /// A tile of four normalised signals: their mean when all four are within
    /// [`RAW_FLOOR`] and [`CLIPPED`], else -1.
    fn tile(s: [f32; 4]) -> f32 {
        if s.iter().all(|&v| raw_log_weight(v) > 0.0) {
            s.iter().sum::<f32>() / 4.0
        } else {
            -1.0
        }
    }

    /// The `[1 2 1]/4` filter of three values, -1 when one of them is (not usable).
    fn filter([a, b, c]: [f32; 3]) -> f32 {
        if a < 0.0 || b < 0.0 || c < 0.0 {
            -1.0
        } else {
            0.25 * a + 0.5 * b + 0.25 * c
        }
    }

    /// `values` filtered along their row into `out` ([`filter`]), -1 at the row's ends.
    fn along_row(values: &[f32], out: &mut [f32]) {
        let n = values.len();
        for (x, o) in out.iter_mut().enumerate() {
            *o = if x > 0 && x + 1 < n {
                filter([values[x - 1], values[x], values[x + 1]])
            } else {
                -1.0
            };
        }
    }

    /// A filtered tile value as a [`Picture`] pixel: the value and [`raw_log_weight`] of
    /// it, or `(0, 0)` where not usable.
    fn weighed(v: f32) -> (f32, f32) {
        if v < 0.0 {
            (0.0, 0.0)
        } else {
            (v, raw_log_weight(v))
        }
    }

    /// The least normalised raw signal a block is estimated from: ten times the read noise of
    /// a 14-bit sensor (3 codes of 14 500), far below a JPEG's floor.
    const RAW_FLOOR: f32 = 0.002;

    /// The weight of a raw sample's log signal: `s`, the inverse variance of `ln s` under
    /// shot noise (`Var s ∝ s`), between [`RAW_FLOOR`] and [`CLIPPED`]; 0 outside.
    fn raw_log_weight(s: f32) -> f32 {
        if (RAW_FLOOR..CLIPPED).contains(&s) {
            s
        } else {
            0.0
        }
    }

    /// Every moved mosaic resampled onto the reference grid (`None` for one merged as it
    /// is): each sample interpolates bilinearly the sub-lattice of the frame's pixels at
    /// the same position of the 2 × 2 tile; a sample outside the frame, or one whose
    /// neighbours include a clipped sample (signal ≥ [`CLIPPED`]), takes the white level
    /// (clipped: the raw merge gives it weight 0).
    pub fn warp_mosaics(
        frames: &[MosaicFrame<'_>],
        alignment: &Alignment,
    ) -> Vec<Option<Vec<u16>>> {
        frames
            .iter()
            .zip(&alignment.frames)
            .map(|(f, a)| a.motion.map(|_| warp_mosaic(f, &a.transform)))
            .collect()
    }

    /// `f` resampled at `T·x` for every pixel `x` of the reference grid, one CFA
    /// position's sub-lattice at a time ([`Lattice::warp`]).
    fn warp_mosaic(f: &MosaicFrame<'_>, t: &[[f64; 3]; 3]) -> Vec<u16> {
        let w = f.width;
        let white = f.info.white.ceil().clamp(0.0, 65535.0) as u16;
        let least_clipped = least_clipped_codes(&f.levels());
        let mut out = vec![white; w * f.height];
        for (ox, oy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
            let lattice = Lattice::of(f, &least_clipped, (ox, oy));
            let warped = lattice.warp(&on_lattice(t, (ox, oy)), white);
            out.par_chunks_mut(w)
                .skip(oy)
                .step_by(2)
                .zip(warped.par_chunks(lattice.cols))
                .for_each(|(row, samples)| {
                    for (o, &v) in row[ox..].chunks_mut(2).zip(samples) {
                        o[0] = v;
                    }
                });
        }
        out
    }

    /// `T` between sub-lattices of the CFA position `(ox, oy)`: `S⁻¹·T·S`, where `S` takes
    /// lattice `(i, j)` to pixel `(2i + ox, 2j + oy)`.
    fn on_lattice(t: &[[f64; 3]; 3], (ox, oy): (usize, usize)) -> [[f64; 3]; 3] {
        let (ox, oy) = (ox as f64, oy as f64);
        let s = Matrix3::new(2.0, 0.0, ox, 0.0, 2.0, oy, 0.0, 0.0, 1.0);
        let s_inv = Matrix3::new(0.5, 0.0, -ox / 2.0, 0.0, 0.5, -oy / 2.0, 0.0, 0.0, 1.0);
        let m = s_inv * Matrix3::from_fn(|r, c| t[r][c]) * s;
        std::array::from_fn(|r| std::array::from_fn(|c| m[(r, c)]))
    }

    /// Per row of the black-level tile (as [`MosaicFrame::levels`] gives its levels), per
    /// column the least code whose signal `(k − b)/d` is at least [`CLIPPED`] (`2¹⁶` when
    /// none is). The signal rises with the code (`d = w − b > 0`, which decoding
    /// ensures), so a code is clipped exactly when it is at least this one.
    fn least_clipped_codes(levels: &[(Vec<f32>, Vec<f32>)]) -> Vec<Vec<u32>> {
        let least = |b: f32, d: f32| {
            let (mut low, mut high) = (0u32, 1u32 << 16);
            while low < high {
                let mid = (low + high) / 2;
                if normalised(mid as u16, b, d) >= CLIPPED {
                    high = mid;
                } else {
                    low = mid + 1;
                }
            }
            low
        };
        let row = |(black, span): &(Vec<f32>, Vec<f32>)| {
            black.iter().zip(span).map(|(&b, &d)| least(b, d)).collect()
        };
        levels.iter().map(row).collect()
    }

    /// The pixels of one CFA position of a mosaic, `cols × rows`: codes, and whether each
    /// is clipped (signal ≥ [`CLIPPED`]).
    struct Lattice {
        codes: Vec<u16>,
        clipped: Vec<bool>,
        cols: usize,
        rows: usize,
    }

    impl Lattice {
        /// The pixels `(ox + 2i, oy + 2j)` of `f`, whose [`least_clipped_codes`] are
        /// `least_clipped`.
        fn of(f: &MosaicFrame<'_>, least_clipped: &[Vec<u32>], (ox, oy): (usize, usize)) -> Self {
            let (cols, rows) = ((f.width - ox).div_ceil(2), (f.height - oy).div_ceil(2));
            let mut codes = vec![0u16; cols * rows];
            let mut clipped = vec![false; cols * rows];
            codes
                .par_chunks_mut(cols)
                .zip(clipped.par_chunks_mut(cols))
                .enumerate()
                .for_each(|(j, (codes, clipped))| {
                    let y = oy + 2 * j;
                    let least = &least_clipped[y % least_clipped.len()][ox..];
                    let row = &f.codes[y * f.width + ox..(y + 1) * f.width];
                    let pairs = row.chunks(2).zip(least.chunks(2));
                    for ((c, k), (code, least)) in codes.iter_mut().zip(clipped).zip(pairs) {
                        (*c, *k) = (code[0], u32::from(code[0]) >= least[0]);
                    }
                });
            Lattice {
                codes,
                clipped,
                cols,
                rows,
            }
        }

        /// The lattice resampled at `T·x` for every lattice point `x`, bilinear in codes;
        /// `white` where `T·x` falls outside the lattice or one of its four neighbours
        /// is clipped (the raw merge gives it weight 0).
        fn warp(&self, t: &[[f64; 3]; 3], white: u16) -> Vec<u16> {
            let mut out = vec![white; self.codes.len()];
            out.par_chunks_mut(self.cols).enumerate().for_each_init(
                || Positions::new(self.cols, 1),
                |at, (y, row)| lattice_row(self, at, (y, t), white, row),
            );
            out
        }

        /// One [`Segment::Run`]: output `i` mixes lattice samples `base + i`,
        /// `base + i + 1` and the two below them with weights `fx[i]`, `fy[i]`
        /// ([`rounded`]), or is `white` where one of the four is clipped.
        #[inline(always)]
        fn run(&self, out: &mut [u16], base: usize, (fx, fy): (&[f32], &[f32]), white: u16) {
            let n = out.len();
            let lower = base + self.cols;
            let spans = [base, base + 1, lower, lower + 1];
            let [a, b, d, e] = spans.map(|i| &self.codes[i..i + n]);
            let [ka, kb, kd, ke] = spans.map(|i| &self.clipped[i..i + n]);
            let (fx, fy) = (&fx[..n], &fy[..n]);
            for i in 0..n {
                let [p, q, r, s] = [a[i], b[i], d[i], e[i]].map(f32::from);
                let upper = p + (q - p) * fx[i];
                let under = r + (s - r) * fx[i];
                let mix = u16::from_low_bits(rounded(upper + (under - upper) * fy[i]));
                out[i] = if ka[i] | kb[i] | kd[i] | ke[i] {
                    white
                } else {
                    mix
                };
            }
        }
    }

    /// Output row `y` of `lattice` resampled at `T·x` ([`Lattice::warp`]; `at` is
    /// scratch). Compiled also for AVX2, as [`super::warp_row`] is.
    #[multiversion(targets("x86_64+avx2"))]
    fn lattice_row(
        lattice: &Lattice,
        at: &mut Positions,
        (y, t): (usize, &[[f64; 3]; 3]),
        white: u16,
        row: &mut [u16],
    ) {
        at.locate::<1>((lattice.cols, lattice.rows), y, t);
        for segment in at.segments() {
            if let Segment::Run(pixels, (x0, y0)) = segment {
                let (fx, fy) = (&at.fx[pixels.clone()], &at.fy[pixels.clone()]);
                lattice.run(&mut row[pixels], y0 * lattice.cols + x0, (fx, fy), white);
            }
        }
    }

    #[cfg(test)]
    mod tests {
        use super::*;
        use crate::raw::{Cfa, RawInfo};

        /// A 2 × 2 RGGB mosaic's description, black level `black` per CFA position.
        fn info(black: [f32; 4], white: f32) -> RawInfo {
            RawInfo {
                make: "filmback".into(),
                model: "Raw Body".into(),
                bits: 14,
                cfa: Cfa {
                    width: 2,
                    height: 2,
                    colours: vec![0, 1, 1, 2],
                },
                black: black.to_vec(),
                black_width: 2,
                black_height: 2,
                white,
                neutral: [0.5, 1.0, 0.7],
                xyz_to_camera: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
                matrix_illuminant: "D65".into(),
                colour_matrices: Vec::new(),
                exposure_time_s: None,
                f_number: None,
                iso: None,
                captured: None,
            }
        }

        /// Pixel `(x, y)` of `f` resampled at `T·(x, y, 1)ᵀ` pixel by pixel, in `f64`:
        /// what [`warp_mosaic`] computes a lattice and a run at a time (`None` outside
        /// the frame's lattice, the white level where a neighbour is clipped).
        fn warped_at(
            f: &MosaicFrame<'_>,
            t: &[[f64; 3]; 3],
            (x, y): (usize, usize),
        ) -> Option<u16> {
            let (ox, oy) = (x % 2, y % 2);
            let (cols, rows) = ((f.width - ox).div_ceil(2), (f.height - oy).div_ceil(2));
            let (x, y) = (x as f64, y as f64);
            let w = t[2][0] * x + t[2][1] * y + t[2][2];
            let sx = (t[0][0] * x + t[0][1] * y + t[0][2]) / w;
            let sy = (t[1][0] * x + t[1][1] * y + t[1][2]) / w;
            let (i, j) = ((sx - ox as f64) / 2.0, (sy - oy as f64) / 2.0);
            if !(i >= 0.0 && j >= 0.0 && i <= (cols - 1) as f64 && j <= (rows - 1) as f64) {
                return None;
            }
            let (i0, j0) = ((i as usize).min(cols - 2), (j as usize).min(rows - 2));
            let (fi, fj) = (i - i0 as f64, j - j0 as f64);
            let quad = [(i0, j0), (i0 + 1, j0), (i0, j0 + 1), (i0 + 1, j0 + 1)]
                .map(|(a, b)| (ox + 2 * a, oy + 2 * b));
            if quad.iter().any(|&(px, py)| f.signal(px, py) >= CLIPPED) {
                return Some(f.info.white as u16);
            }
            let [a, b, c, d] = quad.map(|(px, py)| f64::from(f.codes[py * f.width + px]));
            let top = a + (b - a) * fi;
            let bottom = c + (d - c) * fi;
            Some((top + (bottom - top) * fj).round() as u16)
        }

        #[test]
        fn a_warped_mosaic_mixes_each_pixels_own_cfa_colour() {
            let (w, h) = (97usize, 61usize);
            let info = info([500.0, 510.0, 505.0, 515.0], 15_000.0);
            let mut state = 12345u32;
            let mut next = || {
                state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                state >> 16
            };
            // Ramps of a different slope per CFA colour, with clipped pixels scattered.
            let codes: Vec<u16> = (0..w * h)
                .map(|i| {
                    let (x, y) = (i % w, i / w);
                    match next() % 40 {
                        0 => 15_000,
                        k => {
                            (600 + x * (40 + 30 * (x % 2)) + y * (70 + 50 * (y % 2)) + k as usize)
                                as u16
                        }
                    }
                })
                .collect();
            let frame = MosaicFrame {
                codes: &codes,
                width: w,
                height: h,
                info: &info,
                exposure: 1.0,
            };
            let (a, c) = (0.6f64.to_radians().sin(), 0.6f64.to_radians().cos());
            let moves = [
                [[1.0, 0.0, 3.3], [0.0, 1.0, -2.7], [0.0, 0.0, 1.0]],
                [[c, -a, 1.4], [a, c, -0.6], [0.0002, -0.0001, 1.0]],
                [[1.0, 0.0, 2.0], [0.0, 1.0, 1.0], [0.0, 0.0, 1.0]],
            ];
            for t in moves {
                let out = warp_mosaic(&frame, &t);
                for y in 0..h {
                    for x in 0..w {
                        let got = out[y * w + x];
                        let expected = warped_at(&frame, &t, (x, y)).unwrap_or(15_000);
                        assert!(
                            got.abs_diff(expected) <= 1,
                            "({x}, {y}) under {t:?}: {got}, expected {expected}"
                        );
                    }
                }
            }
        }
    }
}
