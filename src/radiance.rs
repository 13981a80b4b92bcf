//! The radiance map: linear, relative scene radiance per pixel and channel.
//!
//! Values are `f32`, interleaved like the frames they came from (1 or 3 channels).
//! Radiance is relative: the merge's convention (see `merge`) fixes the scale.

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
pub fn with_pixels<R>(
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
