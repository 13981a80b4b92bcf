//! Resampling frames onto the reference grid (bilinear, rows in parallel), and the raw
//! mosaics' alignment, which estimates on whole CFA tiles and warps each CFA position's
//! sub-lattice.

use rayon::prelude::*;

use super::{AlignFrame, Alignment};
use crate::frame::{Frame, Samples};

/// Integer codes a frame holds.
trait Code: Copy + Send + Sync + PartialEq + Into<u32> {
    const ZERO: Self;
    fn from_rounded(v: f32) -> Self;
}

impl Code for u8 {
    const ZERO: u8 = 0;
    fn from_rounded(v: f32) -> u8 {
        // `v` is a bilinear mix of codes (≥ 0): adding a half and truncating rounds it.
        (v + 0.5).min(255.0) as u8
    }
}

impl Code for u16 {
    const ZERO: u16 = 0;
    fn from_rounded(v: f32) -> u16 {
        (v + 0.5).min(65535.0) as u16
    }
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
        (Samples::Eight(v), Samples::Eight(r)) => Samples::Eight(warp_codes(v, r, shape, 255, t)),
        (Samples::Sixteen(v), Samples::Sixteen(r)) => {
            Samples::Sixteen(warp_codes(v, r, shape, 65535, t))
        }
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
    top: u32,
    t: &[[f64; 3]; 3],
) -> Vec<T> {
    let mut out = vec![T::ZERO; codes.len()];
    let top_code = T::from_rounded(top as f32);
    let (last_x, last_y) = ((w - 1) as f64, (h - 1) as f64);
    out.par_chunks_mut(w * c).enumerate().for_each(|(y, row)| {
        // `T·(x, y, 1)ᵀ` is linear in `x` along the row: its three rows at `x = 0` and
        // their increments per pixel.
        let y = y as f64;
        let start = [0, 1, 2].map(|r| t[r][1] * y + t[r][2]);
        let along = [0, 1, 2].map(|r| t[r][0]);
        for (x, o) in row.chunks_exact_mut(c).enumerate() {
            let p = [0, 1, 2].map(|r| start[r] + along[r] * x as f64);
            let (sx, sy) = (p[0] / p[2], p[1] / p[2]);
            let i = (y as usize * w + x) * c;
            if !(sx >= 0.0 && sy >= 0.0 && sx <= last_x && sy <= last_y) {
                for (o, &r) in o.iter_mut().zip(&reference[i..i + c]) {
                    *o = if r.into() * 2 > top {
                        top_code
                    } else {
                        T::ZERO
                    };
                }
                continue;
            }
            let (x0, y0) = ((sx as usize).min(w - 2), (sy as usize).min(h - 2));
            let (fx, fy) = ((sx - x0 as f64) as f32, (sy - y0 as f64) as f32);
            let base = (y0 * w + x0) * c;
            let (upper, lower) = (
                &codes[base..base + 2 * c],
                &codes[base + w * c..base + w * c + 2 * c],
            );
            for (ch, o) in o.iter_mut().enumerate() {
                let quad = [upper[ch], upper[c + ch], lower[ch], lower[c + ch]];
                *o = if quad.contains(&top_code) {
                    top_code
                } else if quad.contains(&T::ZERO) {
                    T::ZERO
                } else {
                    let [a, b, d, e] = quad.map(|q| q.into() as f32);
                    let upper = a + (b - a) * fx;
                    let lower = d + (e - d) * fx;
                    T::from_rounded(upper + (lower - upper) * fy)
                };
            }
        }
    });
    out
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
