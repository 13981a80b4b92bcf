//! The radiance map: linear, relative scene radiance per pixel and channel.
//!
//! Values are `f32`, interleaved like the frames they came from (1 or 3 channels).
//! Radiance is relative: the merge's convention (see `merge`) fixes the scale.

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

/// Anything radiance can be read from: a [`RadianceMap`], or a merge evaluated on demand
/// (`merge::PairMerge`, `merge::BracketMerge`) while the EXR is encoded or a look is
/// developed, a block of lines at a time on each thread, with no radiance buffer at all.
pub trait RadianceSource: Sync {
    /// Width in pixels.
    fn width(&self) -> u32;
    /// Height in pixels.
    fn height(&self) -> u32;
    /// 1 (grey) or 3 (RGB).
    fn channels(&self) -> usize;
    /// Linear relative radiance of `channel` of `pixel` (row-major index).
    fn sample(&self, pixel: usize, channel: usize) -> f32;
    /// Channel `channel` of the `out.len()` pixels from `pixel` on (one line or part of one).
    #[inline]
    fn line(&self, pixel: usize, channel: usize, out: &mut [f32]) {
        for (k, v) in out.iter_mut().enumerate() {
            *v = self.sample(pixel + k, channel);
        }
    }
    /// An upper bound of the finite values, cheap (from a merge's tables where it can).
    fn max_value(&self) -> f32;
    /// The largest finite value, for when the bound is not enough (half overflow): the
    /// bound itself unless the source can do better with one more pass.
    fn exact_max(&self) -> f32 {
        self.max_value()
    }
    /// The `out.len()/channels` whole pixels from `pixel` on, channels interleaved.
    #[inline]
    fn pixels_into(&self, pixel: usize, out: &mut [f32]) {
        let channels = self.channels();
        for (k, p) in out.chunks_exact_mut(channels).enumerate() {
            for (c, v) in p.iter_mut().enumerate() {
                *v = self.sample(pixel + k, c);
            }
        }
    }
    /// Every sample, interleaved, when the source holds them (a map): read in place
    /// rather than evaluated. `None` for a merge evaluated on demand.
    fn held(&self) -> Option<&[f32]> {
        None
    }
    /// The codes and table, when every sample is a function of two 8-bit codes (a merged
    /// pair), so that a per-channel function of the radiance can be tabulated by code
    /// pair instead of evaluated per sample.
    fn code_pairs(&self) -> Option<CodePairs<'_>> {
        None
    }
}

/// A source whose samples are each a function of two 8-bit codes: sample `i` (interleaved
/// index, channel `c = i mod channels`) is `values[(c << 16) | (dark[i] << 8) | bright[i]]`.
#[derive(Debug, Clone, Copy)]
pub struct CodePairs<'a> {
    /// The darker frame's codes, interleaved as the samples.
    pub dark: &'a [u8],
    /// The brighter frame's codes.
    pub bright: &'a [u8],
    /// 1 or 3.
    pub channels: usize,
    /// `channels · 2¹⁶` values, by channel, then dark code, then bright code.
    pub values: &'a [f32],
}

thread_local! {
    /// Pixels evaluated by [`with_pixels`], per thread (kept between calls).
    static EVALUATED: std::cell::RefCell<Vec<f32>> = std::cell::RefCell::default();
}

/// Calls `f` with pixels `first .. first + count` of `source`, channels interleaved: in
/// place for a source that holds them, else evaluated into a buffer of this thread.
pub(crate) fn with_pixels<R>(
    source: &(impl RadianceSource + ?Sized),
    first: usize,
    count: usize,
    f: impl FnOnce(&[f32]) -> R,
) -> R {
    let channels = source.channels();
    let range = first * channels..(first + count) * channels;
    if let Some(held) = source.held() {
        return f(&held[range]);
    }
    EVALUATED.with(|cell| {
        // Taken out of the cell so that `f` may itself evaluate pixels on this thread.
        let mut buffer = cell.take();
        buffer.resize(range.len(), 0.0);
        source.pixels_into(first, &mut buffer);
        let result = f(&buffer);
        cell.replace(buffer);
        result
    })
}

impl RadianceSource for RadianceMap {
    fn width(&self) -> u32 {
        RadianceMap::width(self)
    }
    fn height(&self) -> u32 {
        RadianceMap::height(self)
    }
    fn channels(&self) -> usize {
        RadianceMap::channels(self)
    }
    #[inline]
    fn sample(&self, pixel: usize, channel: usize) -> f32 {
        self.pixels()[pixel * RadianceMap::channels(self) + channel]
    }
    #[inline]
    fn line(&self, pixel: usize, channel: usize, out: &mut [f32]) {
        let channels = RadianceMap::channels(self);
        let from = &self.pixels()[pixel * channels..];
        if channels == 3 {
            // Whole pixels of a constant size, so that the gather is vectorised.
            for (v, rgb) in out.iter_mut().zip(from.chunks_exact(3)) {
                *v = rgb[channel];
            }
        } else {
            for (v, &s) in out.iter_mut().zip(from[channel..].iter().step_by(channels)) {
                *v = s;
            }
        }
    }
    fn held(&self) -> Option<&[f32]> {
        Some(self.pixels())
    }
    fn pixels_into(&self, pixel: usize, out: &mut [f32]) {
        let start = pixel * RadianceMap::channels(self);
        out.copy_from_slice(&self.pixels()[start..start + out.len()]);
    }
    fn max_value(&self) -> f32 {
        // Sixteen running maxima per stretch of samples, each updated by a compare and a
        // select, which vectorises (a fold with `f32::max` does not); the maximum of
        // finite values does not depend on the order.
        const LANES: usize = 16;
        self.pixels()
            .par_chunks(1 << 16)
            .map(|stretch| {
                let mut lanes = [0f32; LANES];
                let blocks = stretch.chunks_exact(LANES);
                let rest = blocks.remainder();
                for block in blocks {
                    for (m, &v) in lanes.iter_mut().zip(block) {
                        *m = if v.is_finite() && v > *m { v } else { *m };
                    }
                }
                for (m, &v) in lanes.iter_mut().zip(rest) {
                    *m = if v.is_finite() && v > *m { v } else { *m };
                }
                lanes.into_iter().fold(0.0, f32::max)
            })
            .reduce(|| 0.0, f32::max)
    }
}

/// A high-dynamic-range image of linear relative radiance.
#[derive(Debug, Clone, PartialEq)]
pub struct RadianceMap {
    width: u32,
    height: u32,
    channels: usize,
    pixels: Vec<f32>,
}

/// A radiance buffer whose length does not match its dimensions.
#[derive(Debug, thiserror::Error)]
#[error("radiance buffer of {got} values does not match {width}×{height}×{channels}")]
pub struct ShapeError {
    /// Width.
    pub width: u32,
    /// Height.
    pub height: u32,
    /// Channels.
    pub channels: usize,
    /// Values supplied.
    pub got: usize,
}

impl RadianceMap {
    /// Wraps interleaved linear values; `channels` is 1 or 3.
    pub fn new(
        width: u32,
        height: u32,
        channels: usize,
        pixels: Vec<f32>,
    ) -> Result<RadianceMap, ShapeError> {
        let expected = width as usize * height as usize * channels;
        if !(channels == 1 || channels == 3) || pixels.len() != expected {
            return Err(ShapeError {
                width,
                height,
                channels,
                got: pixels.len(),
            });
        }
        Ok(RadianceMap {
            width,
            height,
            channels,
            pixels,
        })
    }

    /// Width in pixels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// 1 (grey) or 3 (RGB).
    pub fn channels(&self) -> usize {
        self.channels
    }

    /// Interleaved values.
    pub fn pixels(&self) -> &[f32] {
        &self.pixels
    }

    /// Interleaved values, mutable.
    pub fn pixels_mut(&mut self) -> &mut [f32] {
        &mut self.pixels
    }

    /// Gives up the buffer.
    pub fn into_pixels(self) -> Vec<f32> {
        self.pixels
    }
}

/// The primaries of linear RGB: red, green, blue and white chromaticities `(x, y)` (CIE 1931).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Gamut(pub [(f64, f64); 4]);

/// D65 white.
const D65: (f64, f64) = (0.3127, 0.3290);

impl Gamut {
    /// ITU-R BT.709 / sRGB (filmback's working primaries), D65.
    pub const REC709: Gamut = Gamut([(0.64, 0.33), (0.30, 0.60), (0.15, 0.06), D65]);
    /// ACES AP1 (ACEScg, ACEScct), ACES white; Academy S-2014-004.
    pub const AP1: Gamut = Gamut([
        (0.713, 0.293),
        (0.165, 0.830),
        (0.128, 0.044),
        (0.32168, 0.33767),
    ]);
    /// ARRI Wide Gamut 4, D65; ARRI "LogC4 Logarithmic Color Space" specification (2022).
    pub(crate) const AWG4: Gamut =
        Gamut([(0.7347, 0.2653), (0.1424, 0.8576), (0.0991, -0.0308), D65]);
    /// Sony S-Gamut3.Cine, D65; Sony "Technical Summary for S-Gamut3.Cine/S-Log3 and
    /// S-Gamut3/S-Log3".
    pub(crate) const SGAMUT3_CINE: Gamut =
        Gamut([(0.766, 0.275), (0.225, 0.800), (0.089, -0.087), D65]);
    /// ACES AP0 (ACES2065-1), ACES white; SMPTE ST 2065-1.
    pub const AP0: Gamut = Gamut([
        (0.7347, 0.2653),
        (0.0, 1.0),
        (0.0001, -0.0770),
        (0.32168, 0.33767),
    ]);
    /// Display P3: the DCI-P3 primaries with a D65 white (SMPTE EG 432-1).
    pub(crate) const DISPLAY_P3: Gamut =
        Gamut([(0.680, 0.320), (0.265, 0.690), (0.150, 0.060), D65]);
    /// ITU-R BT.2020, D65.
    pub(crate) const REC2020: Gamut = Gamut([(0.708, 0.292), (0.170, 0.797), (0.131, 0.046), D65]);

    /// RGB → XYZ (`Y_white = 1`) and the white's XYZ.
    fn to_xyz(self) -> (Matrix3<f64>, Vector3<f64>) {
        let xyz = |(x, y): (f64, f64)| Vector3::new(x / y, 1.0, (1.0 - x - y) / y);
        let c = self.0;
        let m = Matrix3::from_columns(&[xyz(c[0]), xyz(c[1]), xyz(c[2])]);
        let white = xyz(c[3]);
        // Distinct primaries span XYZ, so `m` is invertible for every gamut above.
        let s = m.try_inverse().unwrap_or_else(Matrix3::zeros) * white;
        (m * Matrix3::from_diagonal(&s), white)
    }

    /// The matrix taking linear RGB in `self` to linear RGB in `to`:
    /// `M_to⁻¹ · CAT(W_self → W_to) · M_self` with the Bradford adaptation, so that a
    /// neutral stays neutral; exactly the identity from a gamut to itself.
    pub fn matrix_to(self, to: Gamut) -> [[f64; 3]; 3] {
        if self == to {
            return [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        }
        let bradford = Matrix3::new(
            0.8951, 0.2664, -0.1614, -0.7502, 1.7135, 0.0367, 0.0389, -0.0685, 1.0296,
        );
        let (m_from, w_from) = self.to_xyz();
        let (m_to, w_to) = to.to_xyz();
        let gain = (bradford * w_to).component_div(&(bradford * w_from));
        let inverse = |m: Matrix3<f64>| m.try_inverse().unwrap_or_else(Matrix3::zeros);
        let cat = inverse(bradford) * Matrix3::from_diagonal(&gain) * bradford;
        let t = inverse(m_to) * cat * m_from;
        [0, 1, 2].map(|r| [0, 1, 2].map(|c| t[(r, c)]))
    }
}

/// `m · v` for a row-major 3×3 matrix.
pub(crate) fn apply_matrix(m: &[[f64; 3]; 3], v: [f64; 3]) -> [f64; 3] {
    m.map(|row| row[0] * v[0] + row[1] * v[1] + row[2] * v[2])
}
