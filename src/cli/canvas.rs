//! The one raster canvas behind the CLI's PNG figures (`films --plot`, `films
//! --contact-sheet`, `calibrate --plot`, `cache show --plot`): an RGB image with clipped
//! pixels, filled rectangles, 1-pixel lines, thick dashed polylines (none anti-aliased),
//! text in one 5×7 bitmap font, and atomic PNG output through the `image` crate.
//!
//! Not `plotters`: its bitmap backend draws text only through font-kit (system fonts via
//! fontconfig/freetype) or a TTF file we would have to embed, adds a dozen crates to the
//! build, and would redraw every figure differently, while all these figures need fits here.

use std::path::Path;

use filmback::atomic::{self, Overwrite, PublishError};

/// Why a canvas could not be written.
#[derive(Debug, thiserror::Error)]
pub enum CanvasError {
    /// The file could not be published.
    #[error(transparent)]
    Publish(#[from] PublishError),
    /// The PNG encoder refused.
    #[error("{path}: cannot encode the PNG: {source}")]
    Encode {
        /// The PNG file.
        path: std::path::PathBuf,
        /// What the encoder said.
        source: image::ImageError,
    },
}
use image::{ImageEncoder, Rgb, RgbImage};

/// An RGB raster; every drawing call clips to its bounds.
pub struct Canvas {
    image: RgbImage,
}

impl Canvas {
    /// A `width × height` canvas filled with `background`.
    pub fn new(width: u32, height: u32, background: Rgb<u8>) -> Canvas {
        Canvas {
            image: RgbImage::from_pixel(width, height, background),
        }
    }

    pub fn width(&self) -> u32 {
        self.image.width()
    }

    pub fn height(&self) -> u32 {
        self.image.height()
    }

    /// Sets one pixel; outside the canvas, nothing.
    pub fn put(&mut self, x: i64, y: i64, colour: Rgb<u8>) {
        if x >= 0 && y >= 0 && (x as u32) < self.width() && (y as u32) < self.height() {
            self.image.put_pixel(x as u32, y as u32, colour);
        }
    }

    /// Fills the `w × h` rectangle whose top-left corner is `(x, y)`.
    pub fn fill(&mut self, x: i64, y: i64, w: i64, h: i64, colour: Rgb<u8>) {
        for yy in y.max(0)..(y + h).min(i64::from(self.height())) {
            for xx in x.max(0)..(x + w).min(i64::from(self.width())) {
                self.image.put_pixel(xx as u32, yy as u32, colour);
            }
        }
    }

    /// Copies a `w × h` block of packed RGB8 pixels (`rgb`, row by row) with its top-left
    /// corner at `(x, y)`.
    pub fn paste(&mut self, x: u32, y: u32, w: u32, h: u32, rgb: &[u8]) {
        for (dy, row) in rgb
            .chunks_exact(3 * w as usize)
            .take(h as usize)
            .enumerate()
        {
            for (dx, p) in row.chunks_exact(3).enumerate() {
                self.put(
                    i64::from(x) + dx as i64,
                    i64::from(y) + dy as i64,
                    Rgb([p[0], p[1], p[2]]),
                );
            }
        }
    }

    /// A 1-pixel line: one pixel per step along the longer axis, at rounded positions.
    pub fn line(&mut self, (x0, y0): (f64, f64), (x1, y1): (f64, f64), colour: Rgb<u8>) {
        let steps = (x1 - x0).abs().max((y1 - y0).abs()).ceil().max(1.0) as i64;
        for i in 0..=steps {
            let t = i as f64 / steps as f64;
            let (x, y) = (x0 + t * (x1 - x0), y0 + t * (y1 - y0));
            self.put(x.round() as i64, y.round() as i64, colour);
        }
    }

    /// A polyline `width` pixels thick (a square brush stamped every half pixel) with the
    /// dash pattern `(on, off)` in pixels of path length; `off = 0` draws it solid.
    pub fn stroke(&mut self, points: &[(f64, f64)], width: i64, dash: (f64, f64), colour: Rgb<u8>) {
        let mut travelled = 0.0;
        for w in points.windows(2) {
            let ((x0, y0), (x1, y1)) = (w[0], w[1]);
            let len = ((x1 - x0).powi(2) + (y1 - y0).powi(2)).sqrt();
            let steps = (len * 2.0).ceil().max(1.0) as usize;
            for s in 0..steps {
                let f = s as f64 / steps as f64;
                let along = travelled + f * len;
                if dash.1 > 0.0 && along % (dash.0 + dash.1) >= dash.0 {
                    continue;
                }
                let (x, y) = (x0 + f * (x1 - x0), y0 + f * (y1 - y0));
                self.fill(
                    x.round() as i64 - width / 2,
                    y.round() as i64 - width / 2,
                    width,
                    width,
                    colour,
                );
            }
            travelled += len;
        }
    }

    /// Draws `text` with its top-left corner at `(x, y)`, each font pixel `scale × scale`,
    /// glyphs `6 × scale` apart. Characters without a glyph leave a blank.
    pub fn text(&mut self, x: i64, y: i64, scale: i64, colour: Rgb<u8>, text: &str) {
        for (i, c) in text.chars().enumerate() {
            let gx = x + i as i64 * 6 * scale;
            for (r, bits) in glyph(c).iter().enumerate() {
                for col in 0..5 {
                    if bits & (0x10 >> col) != 0 {
                        self.fill(gx + col * scale, y + r as i64 * scale, scale, scale, colour);
                    }
                }
            }
        }
    }

    /// Width in pixels of `text` drawn by [`Canvas::text`] at `scale`.
    pub fn text_width(text: &str, scale: i64) -> i64 {
        text.chars().count() as i64 * 6 * scale - scale
    }

    /// Encodes the canvas as PNG straight into the file published atomically at `path`.
    pub fn publish_png(&self, path: &Path, overwrite: Overwrite) -> Result<(), CanvasError> {
        atomic::publish_with(path, overwrite, |w| {
            image::codecs::png::PngEncoder::new(w)
                .write_image(
                    self.image.as_raw(),
                    self.width(),
                    self.height(),
                    image::ExtendedColorType::Rgb8,
                )
                .map_err(|source| CanvasError::Encode {
                    path: path.to_path_buf(),
                    source,
                })
        })
    }
}

/// 5×7 glyphs (upper case), one byte per row, bit 4 = leftmost column.
fn glyph(c: char) -> [u8; 7] {
    match c.to_ascii_uppercase() {
        '0' => [0x0E, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0E],
        '1' => [0x04, 0x0C, 0x04, 0x04, 0x04, 0x04, 0x0E],
        '2' => [0x0E, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1F],
        '3' => [0x1F, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0E],
        '4' => [0x02, 0x06, 0x0A, 0x12, 0x1F, 0x02, 0x02],
        '5' => [0x1F, 0x10, 0x1E, 0x01, 0x01, 0x11, 0x0E],
        '6' => [0x06, 0x08, 0x10, 0x1E, 0x11, 0x11, 0x0E],
        '7' => [0x1F, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08],
        '8' => [0x0E, 0x11, 0x11, 0x0E, 0x11, 0x11, 0x0E],
        '9' => [0x0E, 0x11, 0x11, 0x0F, 0x01, 0x02, 0x0C],
        'A' => [0x0E, 0x11, 0x11, 0x11, 0x1F, 0x11, 0x11],
        'B' => [0x1E, 0x11, 0x11, 0x1E, 0x11, 0x11, 0x1E],
        'C' => [0x0E, 0x11, 0x10, 0x10, 0x10, 0x11, 0x0E],
        'D' => [0x1C, 0x12, 0x11, 0x11, 0x11, 0x12, 0x1C],
        'E' => [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x1F],
        'F' => [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x10],
        'G' => [0x0E, 0x11, 0x10, 0x17, 0x11, 0x11, 0x0F],
        'H' => [0x11, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11],
        'I' => [0x0E, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E],
        'J' => [0x07, 0x02, 0x02, 0x02, 0x02, 0x12, 0x0C],
        'K' => [0x11, 0x12, 0x14, 0x18, 0x14, 0x12, 0x11],
        'L' => [0x10, 0x10, 0x10, 0x10, 0x10, 0x10, 0x1F],
        'M' => [0x11, 0x1B, 0x15, 0x15, 0x11, 0x11, 0x11],
        'N' => [0x11, 0x11, 0x19, 0x15, 0x13, 0x11, 0x11],
        'O' => [0x0E, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E],
        'P' => [0x1E, 0x11, 0x11, 0x1E, 0x10, 0x10, 0x10],
        'Q' => [0x0E, 0x11, 0x11, 0x11, 0x15, 0x12, 0x0D],
        'R' => [0x1E, 0x11, 0x11, 0x1E, 0x14, 0x12, 0x11],
        'S' => [0x0F, 0x10, 0x10, 0x0E, 0x01, 0x01, 0x1E],
        'T' => [0x1F, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04],
        'U' => [0x11, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E],
        'V' => [0x11, 0x11, 0x11, 0x11, 0x11, 0x0A, 0x04],
        'W' => [0x11, 0x11, 0x11, 0x15, 0x15, 0x15, 0x0A],
        'X' => [0x11, 0x11, 0x0A, 0x04, 0x0A, 0x11, 0x11],
        'Y' => [0x11, 0x11, 0x11, 0x0A, 0x04, 0x04, 0x04],
        'Z' => [0x1F, 0x01, 0x02, 0x04, 0x08, 0x10, 0x1F],
        '-' => [0x00, 0x00, 0x00, 0x1F, 0x00, 0x00, 0x00],
        '+' => [0x00, 0x04, 0x04, 0x1F, 0x04, 0x04, 0x00],
        '.' => [0x00, 0x00, 0x00, 0x00, 0x00, 0x0C, 0x0C],
        ',' => [0x00, 0x00, 0x00, 0x00, 0x0C, 0x04, 0x08],
        ':' => [0x00, 0x0C, 0x0C, 0x00, 0x0C, 0x0C, 0x00],
        '/' => [0x00, 0x01, 0x02, 0x04, 0x08, 0x10, 0x00],
        '(' => [0x02, 0x04, 0x08, 0x08, 0x08, 0x04, 0x02],
        ')' => [0x08, 0x04, 0x02, 0x02, 0x02, 0x04, 0x08],
        '=' => [0x00, 0x00, 0x1F, 0x00, 0x1F, 0x00, 0x00],
        '#' => [0x0A, 0x0A, 0x1F, 0x0A, 0x1F, 0x0A, 0x0A],
        '_' => [0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x1F],
        '@' => [0x0E, 0x11, 0x01, 0x0D, 0x15, 0x15, 0x0E],
        '·' => [0x00, 0x00, 0x00, 0x0C, 0x0C, 0x00, 0x00],
        _ => [0; 7],
    }
}
