//! Resampling frames onto the reference grid (bilinear, rows in parallel), and the raw
//! mosaics' alignment, which estimates on whole CFA tiles and warps each CFA position's
//! sub-lattice.

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
        h,
    };
    out.par_chunks_mut(w * c).enumerate().for_each_init(
        || Positions::new(w, c),
        |at, (y, row)| {
            if c == 1 {
                at.locate::<T, 1>(&grid, y, t);
                grid.row::<1>(y, row, at);
            } else {
                at.locate::<T, 3>(&grid, y, t);
                grid.row::<3>(y, row, at);
            }
        },
    );
    out
}

/// The frame being resampled and the reference it is resampled onto.
struct Grid<'a, T> {
    codes: &'a [T],
    reference: &'a [T],
    w: usize,
    h: usize,
}

/// Where one output row reads the frame: per pixel whether it is covered and the upper
/// left `(x0, y0)` of its four neighbours, and per sample (channels interleaved) the
/// bilinear weights `(fx, fy)`.
struct Positions {
    covered: Vec<bool>,
    x0: Vec<u32>,
    y0: Vec<u32>,
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
            pixel_fx: vec![0.0; width],
            pixel_fy: vec![0.0; width],
            fx: vec![0.0; width * channels],
            fy: vec![0.0; width * channels],
        }
    }

    /// Output row `y`'s positions in `grid`'s frame, `C` channels: `T·(x, y, 1)ᵀ` over
    /// its third coordinate (in `f64`, linear in `x` before the division), then as `f32`
    /// (off by under 0.001 px on frames under 16 384 px): `x0` its floor (the integer
    /// nearest `sx − ½`, one up where that tie went down) and at most `w − 2`,
    /// `fx = sx − x0` in `[0, 1]` where covered; the same in `y`. Written so that it
    /// vectorises.
    fn locate<T: Code, const C: usize>(&mut self, grid: &Grid<'_, T>, y: usize, t: &[[f64; 3]; 3]) {
        let (w, h) = (grid.w, grid.h);
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
        for ((fx, fy), (&px, &py)) in self
            .fx
            .chunks_exact_mut(C)
            .zip(self.fy.chunks_exact_mut(C))
            .zip(self.pixel_fx.iter().zip(&self.pixel_fy))
        {
            fx.fill(px);
            fy.fill(py);
        }
    }
}

impl<T: Code> Grid<'_, T> {
    /// Output row `y` of `C` interleaved channels at the positions `at`: in runs of
    /// covered pixels whose neighbours lie on the same two frame rows at the same offset
    /// from the output pixel (a near-identity transform keeps runs long), so each run
    /// reads two contiguous spans of the frame.
    fn row<const C: usize>(&self, y: usize, row: &mut [T], at: &Positions) {
        let w = self.w;
        let mut x = 0;
        while x < w {
            if !at.covered[x] {
                self.uncovered(&mut row[x * C..(x + 1) * C], (y * w + x) * C);
                x += 1;
                continue;
            }
            let (x0, y0) = (at.x0[x] as usize, at.y0[x]);
            let mut end = x + 1;
            while end < w
                && at.covered[end]
                && (at.x0[end] as usize, at.y0[end]) == (x0 + end - x, y0)
            {
                end += 1;
            }
            let samples = x * C..end * C;
            self.run::<C>(
                &mut row[samples.clone()],
                (y0 as usize * w + x0) * C,
                &at.fx[samples.clone()],
                &at.fy[samples],
            );
            x = end;
        }
    }

    /// One run: output sample `i` mixes the frame's samples `base + i` and `base + i + C`
    /// on the upper row and the same on the lower, with weights `fx[i]`, `fy[i]`: the
    /// top code if one of the four is clipped there, else 0 if one is 0, else the
    /// bilinear mix of their codes [`rounded`].
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
    use rayon::prelude::*;

    use super::super::estimate::{self, Geometry, Pyramid};
    use super::super::{AlignMode, Alignment, SMALLEST_SIDE, exposure_weight};
    use crate::raw::{CLIPPED, RawInfo};

    /// `T·(x, y, 1)ᵀ` divided by its third coordinate.
    fn project(t: &[[f64; 3]; 3], x: f64, y: f64) -> (f64, f64) {
        let w = t[2][0] * x + t[2][1] * y + t[2][2];
        (
            (t[0][0] * x + t[0][1] * y + t[0][2]) / w,
            (t[1][0] * x + t[1][1] * y + t[1][2]) / w,
        )
    }

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

    impl MosaicFrame<'_> {
        /// The normalised signal `(k − b)/(w − b)` of pixel `(x, y)`.
        fn signal(&self, x: usize, y: usize) -> f32 {
            let b = self.info.black_at(x, y);
            (f32::from(self.codes[y * self.width + x]) - b) / (self.info.white - b)
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
        let pyramids: Vec<Pyramid> = frames.iter().map(|f| pyramid(f, step)).collect();
        let geometry = Geometry::new(first.width as u32, first.height as u32);
        Alignment {
            mode,
            reference,
            frames: estimate::register_all(&pyramids, None, reference, &geometry, model),
        }
    }

    fn pyramid(f: &MosaicFrame<'_>, step: usize) -> Pyramid {
        let range = (RAW_FLOOR, CLIPPED);
        Pyramid::from_rows(
            f.width,
            f.height,
            step,
            f.exposure,
            range,
            |y, values, weights| {
                for (x, (v, w)) in values.iter_mut().zip(weights.iter_mut()).enumerate() {
                    let s = f.signal(x, y);
                    *v = s.max(0.0);
                    *w = raw_log_weight(s);
                }
            },
        )
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

    fn warp_mosaic(f: &MosaicFrame<'_>, t: &[[f64; 3]; 3]) -> Vec<u16> {
        let (w, h) = (f.width, f.height);
        let white = f.info.white.ceil().clamp(0.0, 65535.0) as u16;
        let mut out = vec![white; w * h];
        out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            let oy = y % 2;
            let rows = (h - oy).div_ceil(2);
            for (x, o) in row.iter_mut().enumerate() {
                let ox = x % 2;
                let cols = (w - ox).div_ceil(2);
                let (sx, sy) = project(t, x as f64, y as f64);
                let (i, j) = ((sx - ox as f64) / 2.0, (sy - oy as f64) / 2.0);
                if !(i >= 0.0 && j >= 0.0 && i <= (cols - 1) as f64 && j <= (rows - 1) as f64) {
                    continue;
                }
                let (i0, j0) = ((i as usize).min(cols - 2), (j as usize).min(rows - 2));
                let (fi, fj) = ((i - i0 as f64) as f32, (j - j0 as f64) as f32);
                let at = |a: usize, b: usize| (ox + 2 * a, oy + 2 * b);
                let quad = [
                    at(i0, j0),
                    at(i0 + 1, j0),
                    at(i0, j0 + 1),
                    at(i0 + 1, j0 + 1),
                ];
                if quad.iter().any(|&(px, py)| f.signal(px, py) >= CLIPPED) {
                    continue;
                }
                let [a, b, c, d] = quad.map(|(px, py)| f32::from(f.codes[py * w + px]));
                let top = a + (b - a) * fi;
                let bottom = c + (d - c) * fi;
                *o = (top + (bottom - top) * fj).round().clamp(0.0, 65535.0) as u16;
            }
        });
        out
    }
}
