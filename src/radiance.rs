//! The radiance map: linear, relative scene radiance per pixel and channel.
//!
//! Values are `f32`, interleaved like the frames they came from (1 or 3 channels).
//! Radiance is relative: the merge's convention (see `merge`) fixes the scale.

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
