//! Camera raw frames: the sensor's mosaic as it was read out, decoded by `rawler` (the
//! dnglab library, LGPL-2.1; Canon CR2/CR3, Nikon NEF, Sony ARW, Fuji RAF, Olympus ORF,
//! Panasonic RW2, Pentax PEF, DNG and more).
//!
//! # Response
//!
//! A raw sample's response is known and needs no calibration: with code `k`, black level
//! `b` (per CFA position) and white level `w`, the normalised signal
//! `s = (k − b)/(w − b)` is proportional to the light collected, up to the clipping point
//! `s = 1`. A sample within [`CLIPPED`] of the white level counts as clipped in its own
//! channel (the other channels of the same pixel are unaffected).
//!
//! # Stages
//!
//! `decode` reads a file into a [`RawMosaic`] (the visible area of the mosaic, 16-bit
//! codes, and a [`RawInfo`] with levels, CFA and colour); [`mosaic::Merge`] merges a
//! bracket of mosaics in CFA space with the noise-optimal weight of a linear sensor, row
//! by row as [`demosaic`] asks for them; [`demosaic`] interpolates the merged mosaic once
//! (PPG for Bayer sensors, bilinear for X-Trans) in one pass over bands of rows with the
//! white balance, the camera → Rec. 709 matrix of [`colour`] and the exposure scale, so
//! no full-size merged mosaic is held.
//!
//! # Hostile input
//!
//! rawler catches panics inside its decoders itself; the rest of its calls (choosing a
//! decoder, reading metadata) are wrapped here in `catch_unwind`, so a malformed file is
//! an error naming the file, never a crash. Before rawler sees a TIFF-based raw, its IFDs
//! are walked here ([`StructureError`] lists what is refused): a chain of IFDs that loops,
//! on which rawler 0.8 allocates without bound, is refused with that reason.

pub mod colour;
pub mod demosaic;
pub mod dng;
pub mod mosaic;

mod decode;
mod structure;

pub(crate) use decode::is_raw_extension;
pub use decode::{RawExif, decode, probe};
pub use structure::StructureError;

use std::path::PathBuf;

/// Samples whose signal `s = (k − b)/(w − b)` is at least this are clipped: converters
/// clip a little below the white level they declare, and a sample there is no longer
/// proportional to the light.
pub const CLIPPED: f32 = 0.995;

/// The colour filter array: which colour (0 red, 1 green, 2 blue) sits at each position of
/// its repeating tile.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Cfa {
    /// Tile width (2 for Bayer, 6 for X-Trans).
    pub width: usize,
    /// Tile height.
    pub height: usize,
    /// `width × height` colours, row by row, of the tile whose top-left corner is pixel
    /// (0, 0) of the visible image.
    pub colours: Vec<u8>,
}

impl Cfa {
    /// The colour at pixel `(x, y)`: 0 red, 1 green, 2 blue.
    pub fn colour_at(&self, x: usize, y: usize) -> usize {
        usize::from(self.colours[(y % self.height) * self.width + x % self.width])
    }

    /// The 2 × 2 Bayer tile named by its colours row by row, as [`Cfa::name`] writes it
    /// (`RGGB`, `BGGR`, `GRBG`, `GBRG`); `None` for another name.
    pub fn bayer(name: &str) -> Option<Cfa> {
        let colours: Vec<u8> = name
            .bytes()
            .map(|b| match b {
                b'R' => Some(0),
                b'G' => Some(1),
                b'B' => Some(2),
                _ => None,
            })
            .collect::<Option<_>>()?;
        (colours.len() == 4).then_some(Cfa {
            width: 2,
            height: 2,
            colours,
        })
    }

    /// The pattern's name, its tile's colours as letters row by row (`RGGB`).
    pub fn name(&self) -> String {
        self.colours
            .iter()
            .map(|&c| match c {
                0 => 'R',
                1 => 'G',
                2 => 'B',
                _ => '?',
            })
            .collect()
    }
}

/// What a raw file says about its mosaic, colour and capture.
#[derive(Debug, Clone, PartialEq)]
pub struct RawInfo {
    /// Maker, as rawler names it (e.g. `Canon`).
    pub make: String,
    /// Model (e.g. `EOS 5D Mark IV`).
    pub model: String,
    /// Bits per sample the sensor's converter delivers (12, 14, 16).
    pub bits: u32,
    /// The colour filter array of the visible area.
    pub cfa: Cfa,
    /// Black level per position of the black-level tile (`black_width × black_height`,
    /// row by row, aligned on pixel (0, 0) of the visible area), in codes.
    pub black: Vec<f32>,
    /// Width of the black-level tile.
    pub black_width: usize,
    /// Height of the black-level tile.
    pub black_height: usize,
    /// White level (the clipping code), in codes.
    pub white: f32,
    /// As-shot neutral: camera RGB of a white surface under the scene's light, normalised
    /// to green = 1.
    pub neutral: [f64; 3],
    /// XYZ → camera RGB matrix (the file's colour matrix), row-major.
    pub xyz_to_camera: [[f64; 3]; 3],
    /// The illuminant of that matrix as the file names it.
    pub matrix_illuminant: String,
    /// Every colour matrix the file has (the one above among them): the EXIF
    /// `LightSource` code of its calibration illuminant (21 D65, 17 A, …) and its XYZ →
    /// camera RGB matrix, row-major; carried into a merged DNG ([`dng`]).
    pub colour_matrices: Vec<(u16, [[f64; 3]; 3])>,
    /// Exposure time in seconds, when the file records it.
    pub exposure_time_s: Option<f64>,
    /// F-number.
    pub f_number: Option<f64>,
    /// ISO speed.
    pub iso: Option<f64>,
    /// Capture time as the file wrote it (`YYYY:MM:DD HH:MM:SS`).
    pub captured: Option<String>,
}

impl RawInfo {
    /// Black level at pixel `(x, y)` of the visible area, in codes.
    pub(crate) fn black_at(&self, x: usize, y: usize) -> f32 {
        self.black[(y % self.black_height) * self.black_width + x % self.black_width]
    }

    /// `make model`, the camera as messages name it.
    pub fn camera(&self) -> String {
        format!("{} {}", self.make, self.model).trim().to_string()
    }
}

/// A decoded raw: the visible mosaic (one 16-bit code per pixel) and what the file said.
#[derive(Debug, Clone, PartialEq)]
pub struct RawMosaic {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Codes, row by row.
    pub codes: Vec<u16>,
    /// Levels, CFA, colour and capture.
    pub info: RawInfo,
}

/// Why a raw could not be decoded or developed. Every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum RawError {
    /// rawler does not support this camera or mode.
    #[error("{path}: raw from {camera} is not supported: {reason}")]
    Unsupported {
        /// The file.
        path: PathBuf,
        /// Make and model as the file names them ("an unknown camera" when it names
        /// none).
        camera: String,
        /// What rawler said.
        reason: String,
    },
    /// The file's TIFF structure would make the decoder loop or allocate beyond the
    /// file's size; refused before decoding.
    #[error("{path}: damaged raw, refused before decoding: {source}")]
    Structure {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        #[source]
        source: StructureError,
    },
    /// The file is damaged or not a raw rawler recognises.
    #[error("{path}: cannot decode raw: {reason}")]
    Decode {
        /// The file.
        path: PathBuf,
        /// Why.
        reason: String,
    },
    /// The frames of a raw bracket do not belong together (size, CFA, camera).
    #[error("{first} and {other} cannot be merged: {reason}")]
    Mismatch {
        /// One frame.
        first: PathBuf,
        /// The frame that differs.
        other: PathBuf,
        /// How.
        reason: String,
    },
    /// The sensor declares more pixels than allowed; refused before decoding.
    #[error(
        "{path}: raw of {width}×{height} pixels exceeds the limit of {max_pixels} pixels; refused before decoding"
    )]
    TooLarge {
        /// The file.
        path: PathBuf,
        /// Declared width.
        width: usize,
        /// Declared height.
        height: usize,
        /// The limit.
        max_pixels: u64,
    },
    /// The colour matrix cannot be inverted.
    #[error("{path}: the colour matrix is singular")]
    SingularMatrix {
        /// The file.
        path: PathBuf,
    },
}

/// One raw frame of a bracket, as [`develop`] needs it.
#[derive(Debug, Clone, Copy)]
pub struct RawExposure<'a> {
    /// The file, for messages.
    pub path: &'a std::path::Path,
    /// The visible mosaic's codes, row by row.
    pub codes: &'a [u16],
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Levels, CFA and colour.
    pub info: &'a RawInfo,
    /// Relative exposure `t·S/N²`, > 0.
    pub exposure: f64,
}

/// A developed raw bracket: linear Rec. 709 radiance.
#[derive(Debug, Clone)]
pub struct DevelopedRaw {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Interleaved linear Rec. 709 RGB; 1.0 is a neutral at the longest frame's clipping
    /// point in green.
    pub rgb: Vec<f32>,
    /// Samples clipped in every frame (lower bounds).
    pub clipped: u64,
    /// Input indices sorted by exposure, darkest first.
    pub order: Vec<usize>,
    /// The demosaicking method used.
    pub demosaic: &'static str,
    /// Wall time of each step: `merge+demosaic` (the CFA merge, white balance,
    /// interpolation, the camera → output matrix and the scale, one pass over bands).
    pub timings: Vec<(&'static str, std::time::Duration)>,
    /// The merged mosaic the radiance was demosaicked from, when [`develop_keeping`] was
    /// asked to keep it (for a DNG, [`dng`]); `None` otherwise.
    pub mosaic: Option<mosaic::MergedMosaic>,
}

/// Merges a bracket of raw frames of one camera ([`mosaic::merge`], noise from
/// [`mosaic::Noise::typical`] at each frame's ISO), then white-balances, demosaicks,
/// converts to Rec. 709 and multiplies by `scale` ([`finish`]). One frame is developed
/// alone (no merge to make).
pub fn develop(frames: &[RawExposure<'_>], scale: f64) -> Result<DevelopedRaw, RawError> {
    develop_keeping(frames, scale, false)
}

/// [`develop`], and with `keep_mosaic` the merged mosaic kept in
/// [`DevelopedRaw::mosaic`]: the bracket is then merged into memory first
/// (`width × height × 4` bytes more) and demosaicked from there, with the same values.
pub fn develop_keeping(
    frames: &[RawExposure<'_>],
    scale: f64,
    keep_mosaic: bool,
) -> Result<DevelopedRaw, RawError> {
    let first = check_frames(frames)?;
    let codes: Vec<mosaic::Codes<'_>> = frames
        .iter()
        .map(|f| mosaic::Codes {
            codes: f.codes,
            width: f.width as usize,
            black: &f.info.black,
            black_width: f.info.black_width,
            black_height: f.info.black_height,
            white: f.info.white,
        })
        .collect();
    let inputs: Vec<(&dyn mosaic::Signal, f64, mosaic::Noise)> = frames
        .iter()
        .zip(&codes)
        .map(|(f, c)| {
            let mean_black =
                f.info.black.iter().map(|&b| f64::from(b)).sum::<f64>() / f.info.black.len() as f64;
            let noise = mosaic::Noise::typical(f.info.iso, f64::from(f.info.white) - mean_black);
            (c as &dyn mosaic::Signal, f.exposure, noise)
        })
        .collect();
    let merge = mosaic::Merge::new(&inputs, first.width as usize, first.height as usize);
    let to_709 = colour::camera_to_709(first.info, first.path)?;
    let t = std::time::Instant::now();
    let (gains, to_output) = (colour::white_balance(first.info), scaled(&to_709, scale));
    let (rgb, clipped, mosaic) = if keep_mosaic {
        let merged = mosaic::merge(&inputs, first.width as usize, first.height as usize);
        let (rgb, _) = demosaic::demosaic(&merged, &first.info.cfa, gains, &to_output);
        (rgb, merged.clipped, Some(merged))
    } else {
        let (rgb, clipped) = demosaic::demosaic(&merge, &first.info.cfa, gains, &to_output);
        (rgb, clipped, None)
    };
    let timings = vec![("merge+demosaic", t.elapsed())];
    let mut order: Vec<usize> = (0..frames.len()).collect();
    order.sort_by(|&a, &b| frames[a].exposure.total_cmp(&frames[b].exposure));
    Ok(DevelopedRaw {
        width: first.width,
        height: first.height,
        rgb,
        clipped,
        order,
        demosaic: demosaic::method(&first.info.cfa),
        timings,
        mosaic,
    })
}

/// The first of `frames`, once all have its size, colour filter array and camera, and
/// each has a code per pixel and a finite, positive exposure.
fn check_frames<'f, 'a>(frames: &'f [RawExposure<'a>]) -> Result<&'f RawExposure<'a>, RawError> {
    let Some(first) = frames.first() else {
        return Err(RawError::Decode {
            path: PathBuf::new(),
            reason: "no frames".to_string(),
        });
    };
    for other in &frames[1..] {
        check_alike(first, other)?;
    }
    for f in frames {
        let pixels = f.width as usize * f.height as usize;
        if f.codes.len() != pixels || !(f.exposure.is_finite() && f.exposure > 0.0) {
            return Err(RawError::Decode {
                path: f.path.to_path_buf(),
                reason: format!(
                    "{} codes for {}×{} pixels, exposure {}",
                    f.codes.len(),
                    f.width,
                    f.height,
                    f.exposure
                ),
            });
        }
    }
    Ok(first)
}

/// `other` against `first`: the same size, colour filter array and camera.
fn check_alike(first: &RawExposure<'_>, other: &RawExposure<'_>) -> Result<(), RawError> {
    let mismatch = |reason: String| RawError::Mismatch {
        first: first.path.to_path_buf(),
        other: other.path.to_path_buf(),
        reason,
    };
    if (other.width, other.height) != (first.width, first.height) {
        return Err(mismatch(format!(
            "{}×{} against {}×{} pixels",
            first.width, first.height, other.width, other.height
        )));
    }
    if other.info.cfa != first.info.cfa {
        return Err(mismatch(format!(
            "colour filter arrays {} and {}",
            first.info.cfa.name(),
            other.info.cfa.name()
        )));
    }
    if other.info.camera() != first.info.camera() {
        return Err(mismatch(format!(
            "taken by {} and {}",
            first.info.camera(),
            other.info.camera()
        )));
    }
    Ok(())
}

/// White balance, demosaicking, camera → Rec. 709 and `scale` in one pass: interleaved
/// linear RGB of `merged`, `scale · M · c'` with `M` of [`colour::camera_to_709`] and `c'`
/// the white-balanced camera RGB.
pub fn finish(
    merged: &mosaic::MergedMosaic,
    info: &RawInfo,
    path: &std::path::Path,
    scale: f64,
) -> Result<Vec<f32>, RawError> {
    let to_709 = colour::camera_to_709(info, path)?;
    let (rgb, _) = demosaic::demosaic(
        merged,
        &info.cfa,
        colour::white_balance(info),
        &scaled(&to_709, scale),
    );
    Ok(rgb)
}

/// `m · scale`.
fn scaled(m: &[[f32; 3]; 3], scale: f64) -> [[f32; 3]; 3] {
    m.map(|row| row.map(|v| (f64::from(v) * scale) as f32))
}
