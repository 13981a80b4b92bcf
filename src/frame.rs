//! Frames: decoded pixels of one exposure, at their native bit depth.
//!
//! A [`Frame`] holds interleaved samples (grey or RGB) exactly as the camera wrote them:
//! 8-bit frames stay `u8`, 16-bit frames stay `u16` and are never squeezed to 8 bits.
//! Brightness of a sample `k` is `B = k / (2^bits − 1)` in `[0, 1]`.
//!
//! Loading applies the EXIF orientation so that every frame of a bracket shares one pixel
//! grid, refuses images larger than [`Limits`] before allocating their pixels (and files
//! larger than any such image before reading them), refuses a truncated file rather than
//! returning a frame padded with grey, and names the file in every error.

use std::io::Cursor;
use std::path::{Path, PathBuf};

use image::{DynamicImage, ImageReader};

use crate::metadata::{self, Metadata};

/// Bits per sample of a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub enum BitDepth {
    /// 8 bits per sample, 256 levels.
    Eight,
    /// 16 bits per sample, 65 536 levels.
    Sixteen,
}

impl BitDepth {
    /// Number of bits per sample (8 or 16).
    pub fn bits(self) -> u32 {
        match self {
            BitDepth::Eight => 8,
            BitDepth::Sixteen => 16,
        }
    }

    /// Number of distinct levels, `2^bits` (256 or 65 536).
    pub fn levels(self) -> usize {
        1usize << self.bits()
    }

    /// The largest code, `2^bits − 1` (255 or 65 535); brightness is `code / max_code`.
    pub fn max_code(self) -> u32 {
        (1u32 << self.bits()) - 1
    }
}

/// How the file stored the samples, which decides how close to clipping a tone can be
/// trusted ([`crate::histogram::UsableTones`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Compression {
    /// Every sample as the camera wrote it (PNG, TIFF, or a frame built in memory).
    Lossless,
    /// Lossy JPEG: the 8×8 blocks that hold clipped highlights ring, spreading the codes
    /// just below full scale over a few levels.
    Lossy,
}

/// Interleaved samples at the frame's native depth.
#[derive(Debug, Clone, PartialEq)]
pub enum Samples {
    /// 8-bit codes.
    Eight(Vec<u8>),
    /// 16-bit codes.
    Sixteen(Vec<u16>),
}

/// One decoded exposure: `width × height` pixels of `channels` interleaved samples.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    width: u32,
    height: u32,
    channels: usize,
    samples: Samples,
    compression: Compression,
}

/// Why a frame could not be built or loaded. Every variant names the file when there is one.
#[derive(Debug, thiserror::Error)]
pub enum FrameError {
    /// The file could not be read at all.
    #[error("{path}: cannot read: {source}")]
    Read {
        /// The file.
        path: PathBuf,
        /// What the operating system said.
        source: std::io::Error,
    },
    /// The path names a directory, not an image.
    #[error("{path}: is a directory, not an image file")]
    Directory {
        /// The path.
        path: PathBuf,
    },
    /// The path names something that is neither a regular file nor a directory (a FIFO,
    /// a device): reading it could block forever.
    #[error("{path}: not a regular file")]
    NotAFile {
        /// The path.
        path: PathBuf,
    },
    /// The file is larger than any image within the limits could be.
    #[error("{path}: file of {bytes} bytes exceeds the limit of {max_bytes} bytes; not read")]
    FileTooLarge {
        /// The file.
        path: PathBuf,
        /// Its size.
        bytes: u64,
        /// The limit, [`Limits::max_file_bytes`].
        max_bytes: u64,
    },
    /// The file is empty.
    #[error("{path}: file is empty (0 bytes)")]
    Empty {
        /// The file.
        path: PathBuf,
    },
    /// The bytes are not a JPEG, PNG or TIFF.
    #[error("{path}: not a JPEG, PNG or TIFF image (unrecognised content)")]
    UnknownFormat {
        /// The file.
        path: PathBuf,
    },
    /// The header declares more pixels than the limits allow.
    #[error(
        "{path}: image of {width}×{height} pixels exceeds the limit of {max_pixels} pixels; refused before decoding"
    )]
    TooLarge {
        /// The file.
        path: PathBuf,
        /// Declared width.
        width: u32,
        /// Declared height.
        height: u32,
        /// The limit in pixels.
        max_pixels: u64,
    },
    /// A camera raw that could not be decoded (unsupported camera, damaged file).
    #[cfg(feature = "raw")]
    #[error(transparent)]
    Raw(#[from] crate::raw::RawError),
    /// The decoder failed (truncated or corrupt data).
    #[error("{path}: cannot decode {format}: {source}")]
    Decode {
        /// The file.
        path: PathBuf,
        /// The detected container format.
        format: &'static str,
        /// Why.
        source: DecodeFailure,
    },
    /// The decoded pixel layout is not one filmback handles (e.g. floating point).
    #[error("{path}: unsupported pixel layout {layout}: filmback takes 8- or 16-bit grey or RGB")]
    UnsupportedLayout {
        /// The file.
        path: PathBuf,
        /// The decoder's colour type.
        layout: String,
    },
    /// Samples do not match the declared dimensions (in-memory construction).
    #[error("sample count {got} does not match {width}×{height}×{channels}")]
    Shape {
        /// Width.
        width: u32,
        /// Height.
        height: u32,
        /// Channels.
        channels: usize,
        /// Number of samples supplied.
        got: usize,
    },
}

/// Size limits applied before any pixel buffer is allocated.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Limits {
    /// Largest accepted `width × height`.
    pub max_pixels: u64,
}

impl Default for Limits {
    /// 200 megapixels: above every current camera (the largest medium-format backs are
    /// ~150 MP), small enough that a forged header cannot exhaust memory.
    fn default() -> Self {
        Limits {
            max_pixels: 200_000_000,
        }
    }
}

impl Limits {
    /// Largest file read, in bytes: `8 · max_pixels + 64 MiB`, room for uncompressed
    /// 16-bit RGBA at the pixel limit plus metadata and thumbnails.
    pub fn max_file_bytes(&self) -> u64 {
        self.max_pixels.saturating_mul(8).saturating_add(64 << 20)
    }
}

/// A frame together with what its file said about how it was taken.
#[derive(Debug, Clone)]
pub struct LoadedFrame {
    /// The file it came from.
    pub path: PathBuf,
    /// Pixels, oriented upright.
    pub frame: Frame,
    /// EXIF metadata (with warnings for anything missing or absurd).
    pub metadata: Metadata,
    /// For a camera raw: its levels, CFA and colour. The frame then holds the raw mosaic
    /// itself, one 16-bit code per pixel (1 channel), which is not an image to merge
    /// through a response: raw brackets go through [`crate::raw::develop`].
    #[cfg(feature = "raw")]
    pub raw: Option<Box<crate::raw::RawInfo>>,
}

impl LoadedFrame {
    /// True for a camera raw's mosaic (never without the `raw` feature).
    pub fn is_raw(&self) -> bool {
        #[cfg(feature = "raw")]
        return self.raw.is_some();
        #[cfg(not(feature = "raw"))]
        false
    }
}

impl Frame {
    /// Builds a frame from interleaved samples; `channels` is 1 (grey) or 3 (RGB). The
    /// samples count as [`Compression::Lossless`] (see [`Frame::with_compression`]).
    pub fn new(
        width: u32,
        height: u32,
        channels: usize,
        samples: Samples,
    ) -> Result<Frame, FrameError> {
        let got = match &samples {
            Samples::Eight(v) => v.len(),
            Samples::Sixteen(v) => v.len(),
        };
        let expected = width as usize * height as usize * channels;
        if !(channels == 1 || channels == 3) || got != expected {
            return Err(FrameError::Shape {
                width,
                height,
                channels,
                got,
            });
        }
        Ok(Frame {
            width,
            height,
            channels,
            samples,
            compression: Compression::Lossless,
        })
    }

    /// The same frame, marked as stored with `compression`.
    pub(crate) fn with_compression(self, compression: Compression) -> Frame {
        Frame {
            compression,
            ..self
        }
    }

    /// How the file stored the samples.
    pub fn compression(&self) -> Compression {
        self.compression
    }

    /// Width in pixels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Samples per pixel: 1 (grey) or 3 (RGB).
    pub fn channels(&self) -> usize {
        self.channels
    }

    /// Number of pixels, `width × height`.
    pub fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// Bit depth of the samples.
    pub fn bit_depth(&self) -> BitDepth {
        match self.samples {
            Samples::Eight(_) => BitDepth::Eight,
            Samples::Sixteen(_) => BitDepth::Sixteen,
        }
    }

    /// The interleaved samples.
    pub fn samples(&self) -> &Samples {
        &self.samples
    }

    /// Code of channel `c` of pixel `(x, y)`, widened to `u32`.
    pub fn code(&self, x: u32, y: u32, c: usize) -> u32 {
        let i = (y as usize * self.width as usize + x as usize) * self.channels + c;
        match &self.samples {
            Samples::Eight(v) => u32::from(v[i]),
            Samples::Sixteen(v) => u32::from(v[i]),
        }
    }

    /// Brightness `B = code / max_code ∈ [0, 1]` of channel `c` of pixel `(x, y)`.
    pub fn brightness(&self, x: u32, y: u32, c: usize) -> f64 {
        f64::from(self.code(x, y, c)) / f64::from(self.bit_depth().max_code())
    }

    fn from_dynamic(image: DynamicImage, path: &Path) -> Result<Frame, FrameError> {
        let (width, height) = (image.width(), image.height());
        let (channels, samples) = match image {
            DynamicImage::ImageLuma8(b) => (1, Samples::Eight(b.into_raw())),
            DynamicImage::ImageRgb8(b) => (3, Samples::Eight(b.into_raw())),
            DynamicImage::ImageLuma16(b) => (1, Samples::Sixteen(b.into_raw())),
            DynamicImage::ImageRgb16(b) => (3, Samples::Sixteen(b.into_raw())),
            // Alpha carries no exposure information: drop it, keep the depth.
            img @ DynamicImage::ImageLumaA8(_) => (1, Samples::Eight(img.into_luma8().into_raw())),
            img @ DynamicImage::ImageRgba8(_) => (3, Samples::Eight(img.into_rgb8().into_raw())),
            img @ DynamicImage::ImageLumaA16(_) => {
                (1, Samples::Sixteen(img.into_luma16().into_raw()))
            }
            img @ DynamicImage::ImageRgba16(_) => {
                (3, Samples::Sixteen(img.into_rgb16().into_raw()))
            }
            other => {
                return Err(FrameError::UnsupportedLayout {
                    path: path.to_path_buf(),
                    layout: format!("{:?}", other.color()),
                });
            }
        };
        Frame::new(width, height, channels, samples)
    }
}

/// Reads `path`, its EXIF metadata and its pixels, oriented upright, within [`Limits`].
///
/// The container is recognised by content, not by name: a PNG renamed `.jpg` loads as a
/// PNG, with a warning in its metadata that the extension disagrees.
pub fn load(path: &Path, limits: Limits) -> Result<LoadedFrame, FrameError> {
    use std::io::Read;
    let read_error = |source| FrameError::Read {
        path: path.to_path_buf(),
        source,
    };
    let info = std::fs::metadata(path).map_err(read_error)?;
    if info.is_dir() {
        return Err(FrameError::Directory {
            path: path.to_path_buf(),
        });
    }
    if !info.is_file() {
        // A FIFO or a device would block or never end.
        return Err(FrameError::NotAFile {
            path: path.to_path_buf(),
        });
    }
    let max_bytes = limits.max_file_bytes();
    if info.len() > max_bytes {
        return Err(FrameError::FileTooLarge {
            path: path.to_path_buf(),
            bytes: info.len(),
            max_bytes,
        });
    }
    // Sized for the file as it stands (no regrowing while a 20-80 MB raw is read);
    // `take` also bounds a file that grows while it is read.
    let mut bytes = Vec::with_capacity(info.len().min(max_bytes) as usize + 1);
    std::fs::File::open(path)
        .and_then(|file| file.take(max_bytes).read_to_end(&mut bytes))
        .map_err(read_error)?;
    decode(path, &bytes, limits)
}

/// Decodes an image already in memory; `path` is used for messages and the extension check.
pub fn decode(path: &Path, bytes: &[u8], limits: Limits) -> Result<LoadedFrame, FrameError> {
    if bytes.is_empty() {
        return Err(FrameError::Empty {
            path: path.to_path_buf(),
        });
    }
    let format = match image::guess_format(bytes) {
        #[cfg(feature = "raw")]
        _ if crate::raw::is_raw_extension(path) => return decode_raw(path, bytes, limits),
        Ok(f @ (image::ImageFormat::Jpeg | image::ImageFormat::Png | image::ImageFormat::Tiff)) => {
            f
        }
        // A raw under another name: rawler recognises it by content, or it is unknown.
        #[cfg(feature = "raw")]
        _ => {
            return decode_raw(path, bytes, limits).map_err(|_| FrameError::UnknownFormat {
                path: path.to_path_buf(),
            });
        }
        #[cfg(not(feature = "raw"))]
        _ => {
            return Err(FrameError::UnknownFormat {
                path: path.to_path_buf(),
            });
        }
    };
    let mut metadata = metadata::read(bytes);
    if let Some(warning) = extension_mismatch(path, format) {
        metadata.warnings.push(warning);
    }
    let mut image = decode_image(path, bytes, format, limits)?;
    if let Some(orientation) = image::metadata::Orientation::from_exif(metadata.orientation) {
        image.apply_orientation(orientation);
    }
    let compression = if format == image::ImageFormat::Jpeg {
        Compression::Lossy
    } else {
        Compression::Lossless
    };
    let frame = Frame::from_dynamic(image, path)?.with_compression(compression);
    Ok(LoadedFrame {
        path: path.to_path_buf(),
        frame,
        metadata,
        #[cfg(feature = "raw")]
        raw: None,
    })
}

/// Decodes a JPEG, PNG or TIFF image of `format` in `bytes` within `limits`: its size
/// is checked before its pixels are decoded, and a JPEG must be whole.
fn decode_image(
    path: &Path,
    bytes: &[u8],
    format: image::ImageFormat,
    limits: Limits,
) -> Result<image::DynamicImage, FrameError> {
    let decode_error = |source: DecodeFailure| FrameError::Decode {
        path: path.to_path_buf(),
        format: format_name(format),
        source,
    };
    let mut reader = ImageReader::with_format(Cursor::new(bytes), format);
    let mut image_limits = image::Limits::default();
    // Dimensions are checked against our own pixel limit below; the allocation limit
    // covers the decoded buffer (16-bit RGBA at the pixel limit) so no forged header can
    // make the decoder allocate more.
    image_limits.max_alloc = Some(limits.max_pixels.saturating_mul(8));
    reader.limits(image_limits.clone());
    let (width, height) = reader
        .into_dimensions()
        .map_err(|e| decode_error(e.into()))?;
    if width == 0 || height == 0 {
        return Err(decode_error(DecodeFailure::NoPixels { width, height }));
    }
    if u64::from(width) * u64::from(height) > limits.max_pixels {
        return Err(FrameError::TooLarge {
            path: path.to_path_buf(),
            width,
            height,
            max_pixels: limits.max_pixels,
        });
    }
    if format == image::ImageFormat::Jpeg {
        // The JPEG decoder fills a missing tail with grey rather than failing; a truncated
        // frame would poison a merge, so refuse it here.
        jpeg_end_of_image(bytes).map_err(decode_error)?;
    }
    let mut reader = ImageReader::with_format(Cursor::new(bytes), format);
    reader.limits(image_limits);
    reader.decode().map_err(|e| decode_error(e.into()))
}

/// Decodes a camera raw: the frame is its visible mosaic (1 channel, 16-bit codes, not
/// rotated), the metadata its EXIF, completed from what the raw decoder read (formats
/// whose EXIF is not in a TIFF structure, such as CR3 and RAF, have it only there).
#[cfg(feature = "raw")]
fn decode_raw(path: &Path, bytes: &[u8], limits: Limits) -> Result<LoadedFrame, FrameError> {
    let mosaic = crate::raw::decode(path, bytes, limits.max_pixels)?;
    let info = mosaic.info;
    let metadata = raw_metadata(
        bytes,
        &crate::raw::RawExif {
            make: info.make.clone(),
            model: info.model.clone(),
            exposure_time_s: info.exposure_time_s,
            f_number: info.f_number,
            iso: info.iso,
            captured: info.captured.clone(),
        },
    );
    let frame = Frame::new(
        mosaic.width,
        mosaic.height,
        1,
        Samples::Sixteen(mosaic.codes),
    )?;
    Ok(LoadedFrame {
        path: path.to_path_buf(),
        frame,
        metadata,
        raw: Some(Box::new(info)),
    })
}

/// A raw's metadata and sensor size `(width, height)`, or why it cannot be taken.
type RawProbe = Result<(Metadata, (u32, u32)), FrameError>;

/// For a file named as a camera raw (see [`crate::raw::RAW_EXTENSIONS`]): its metadata and
/// sensor size, read without decoding the pixels, or why the raw cannot be taken
/// (unsupported camera, damaged file). `None` for every other file, and always without
/// the `raw` feature.
pub(crate) fn probe_raw(path: &Path, bytes: &[u8]) -> Option<RawProbe> {
    #[cfg(feature = "raw")]
    if crate::raw::is_raw_extension(path) {
        return Some(
            crate::raw::probe(path, bytes)
                .map(|(exif, size)| (raw_metadata(bytes, &exif), size))
                .map_err(FrameError::from),
        );
    }
    #[cfg(not(feature = "raw"))]
    let _ = (path, bytes);
    None
}

/// The EXIF of a raw in `bytes` (read as for any TIFF-structured file), completed from
/// what the raw decoder read: formats whose EXIF is not in a TIFF structure (CR3, RAF)
/// have it only there. The orientation is not applied to a mosaic: a warning says so.
#[cfg(feature = "raw")]
fn raw_metadata(bytes: &[u8], exif: &crate::raw::RawExif) -> Metadata {
    let mut metadata = metadata::read(bytes);
    let mut filled: Vec<&str> = Vec::new();
    let exposure = &mut metadata.exposure;
    if exposure.time_s.is_none() && exif.exposure_time_s.is_some() {
        exposure.time_s = exif.exposure_time_s;
        filled.push("ExposureTime");
    }
    if exposure.f_number.is_none() && exif.f_number.is_some() {
        exposure.f_number = exif.f_number;
        filled.push("FNumber");
    }
    if exposure.iso.is_none() && exif.iso.is_some() {
        exposure.iso = exif.iso;
        filled.extend(["PhotographicSensitivity", "ISO"]);
    }
    if metadata.captured_at.is_none()
        && let Some(t) = exif.captured.as_deref().and_then(capture_time)
    {
        metadata.captured_at = Some(t);
        filled.push("DateTimeOriginal");
    }
    if metadata.camera.make.is_none() && !exif.make.is_empty() {
        metadata.camera.make = Some(exif.make.clone());
        filled.push("Make");
    }
    if metadata.camera.model.is_none() && !exif.model.is_empty() {
        metadata.camera.model = Some(exif.model.clone());
        filled.push("Model");
    }
    metadata
        .warnings
        .retain(|w| !filled.iter().any(|tag| w.contains(tag)));
    if metadata.orientation != 1 {
        metadata.warnings.push(format!(
            "EXIF orientation {} not applied: raw frames keep the sensor's orientation",
            metadata.orientation
        ));
        metadata.orientation = 1;
    }
    metadata
}

/// `YYYY:MM:DD HH:MM:SS` (EXIF's date format) as a capture time without offset.
#[cfg(feature = "raw")]
fn capture_time(text: &str) -> Option<metadata::CaptureTime> {
    let digits: Vec<u32> = text
        .split([':', ' ', '-', 'T'])
        .map(|p| p.trim().parse().ok())
        .collect::<Option<Vec<u32>>>()?;
    let [year, month, day, hour, minute, second] = digits[..] else {
        return None;
    };
    let small = |v: u32| u8::try_from(v).ok();
    let (year, month, day) = (u16::try_from(year).ok()?, small(month)?, small(day)?);
    let (hour, minute, second) = (small(hour)?, small(minute)?, small(second)?);
    metadata::is_real_date(year, month, day, hour, minute, second).then_some(
        metadata::CaptureTime {
            year,
            month,
            day,
            hour,
            minute,
            second,
            nanos: None,
            offset_minutes: None,
        },
    )
}

/// Why a JPEG, PNG or TIFF frame could not be decoded.
#[derive(Debug, thiserror::Error)]
pub enum DecodeFailure {
    /// The decoder refused the data.
    #[error(transparent)]
    Image(#[from] image::ImageError),
    /// The header declares no pixels.
    #[error("no pixels ({width}×{height})")]
    NoPixels {
        /// Declared width.
        width: u32,
        /// Declared height.
        height: u32,
    },
    /// A JPEG's data ends before its end-of-image marker.
    #[error("truncated: data ends at byte {at} before the end-of-image marker")]
    Truncated {
        /// Where the data ends, in bytes.
        at: usize,
    },
}

/// Walks the JPEG marker structure (segment lengths, then entropy-coded scans) and
/// checks that the end-of-image marker `FF D9` is reached before the data ends. Stray
/// bytes between segments are skipped, as libjpeg does; only a missing end is an error.
fn jpeg_end_of_image(bytes: &[u8]) -> Result<(), DecodeFailure> {
    let truncated = |at: usize| Err(DecodeFailure::Truncated { at });
    let mut i = 2; // after SOI
    loop {
        // Next marker: 0xFF (any fill bytes), then a code that is neither 0x00 nor 0xFF.
        while i < bytes.len() && bytes[i] != 0xFF {
            i += 1;
        }
        while i < bytes.len() && bytes[i] == 0xFF {
            i += 1;
        }
        let Some(&code) = bytes.get(i) else {
            return truncated(bytes.len());
        };
        i += 1;
        match code {
            0xD9 => return Ok(()),
            0x00 | 0x01 | 0xD0..=0xD7 => continue, // stuffed byte, TEM, restart markers
            _ => {}
        }
        let Some(len) = bytes.get(i..i + 2) else {
            return truncated(bytes.len());
        };
        let len = usize::from(u16::from_be_bytes([len[0], len[1]]));
        if i + len > bytes.len() {
            return truncated(bytes.len());
        }
        i += len;
        if code == 0xDA {
            // Entropy-coded data: runs until a marker other than FF00 or a restart.
            loop {
                match bytes.get(i..i + 2) {
                    None => return truncated(bytes.len()),
                    Some([0xFF, 0x00 | 0xD0..=0xD7 | 0xFF]) => i += 1,
                    Some([0xFF, _]) => break,
                    Some(_) => i += 1,
                }
            }
        }
    }
}

fn format_name(format: image::ImageFormat) -> &'static str {
    match format {
        image::ImageFormat::Jpeg => "JPEG",
        image::ImageFormat::Png => "PNG",
        image::ImageFormat::Tiff => "TIFF",
        _ => "image",
    }
}

fn extension_mismatch(path: &Path, format: image::ImageFormat) -> Option<String> {
    let ext = path.extension()?.to_str()?.to_ascii_lowercase();
    let expected = match ext.as_str() {
        "jpg" | "jpeg" | "jpe" => image::ImageFormat::Jpeg,
        "png" => image::ImageFormat::Png,
        "tif" | "tiff" => image::ImageFormat::Tiff,
        _ => return None,
    };
    (expected != format).then(|| {
        format!(
            "file extension .{ext} does not match its content ({}); read as {}",
            format_name(format),
            format_name(format)
        )
    })
}

#[cfg(all(test, feature = "raw"))]
mod tests {
    use super::*;

    #[test]
    fn a_raw_capture_time_is_a_real_date_or_none() {
        let t = capture_time("2026:03:14 09:26:53").unwrap();
        assert_eq!((t.year, t.month, t.day, t.second), (2026, 3, 14, 53));
        for placeholder in [
            "0000:00:00 00:00:00",
            "9999:12:31 23:59:59",
            "2026:02:30 12:00:00",
            "2026:04:31 12:00:00",
            "2026:01:01 24:00:00",
            "99999:01:01 00:00:00",
        ] {
            assert_eq!(capture_time(placeholder), None, "{placeholder}");
        }
    }
}
