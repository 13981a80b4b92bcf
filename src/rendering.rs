//! Display renderings: the looks a radiance map can be shown with (film stocks, tone
//! maps), and encoding them as files — JPEG, PNG 8/16-bit or TIFF 16-bit, each with an
//! embedded sRGB ICC profile and the source frame's EXIF (with `Software = filmback`),
//! published atomically.
//!
//! JPEG goes through the `jpeg-encoder` crate with its `simd` feature (AVX2 DCT chosen at
//! run time): about 2.3 times faster than the `image` crate's encoder on the same 24 MP
//! image (see `docs/film.md`), and it pulls rows from an `ImageBuffer`, so a film look is
//! developed band by band on one core while the other encodes ([`encode_film_jpeg`]).
//! PNG goes through `image`'s encoder, TIFF through `kamadak-exif`'s TIFF writer so that
//! the EXIF sub-IFD (exposure, date) sits in the same file as the pixels.

use std::borrow::Cow;
use std::io::Cursor;
use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::sync::OnceLock;

use exif::{Field, In, Tag, Value};
use rayon::prelude::*;

use crate::atomic::{self, Overwrite, PublishError};
use crate::film::{self, Catalogue, ColourMode, FilmError, Key, Stock};
use crate::metadata::Metadata;
use crate::radiance::RadianceMap;
use crate::tonemap;

/// Why a rendering could not be made or written.
#[derive(Debug, thiserror::Error)]
pub enum RenderingError {
    /// A stock could not be found or rendered.
    #[error(transparent)]
    Film(#[from] FilmError),
    /// The encoder failed (reported with the file it was writing).
    #[error("{path}: cannot encode {format}: {reason}")]
    Encode {
        /// The output file.
        path: PathBuf,
        /// The format.
        format: String,
        /// The encoder's message.
        reason: String,
    },
    /// The file could not be published.
    #[error(transparent)]
    Publish(#[from] PublishError),
    /// An OpenEXR input could not be read.
    #[error("{path}: cannot read OpenEXR: {reason}")]
    Exr {
        /// The EXR file.
        path: PathBuf,
        /// The reader's message.
        reason: String,
    },
    /// A look or format name that does not parse.
    #[error("{text:?}: {reason}")]
    Parse {
        /// As typed.
        text: String,
        /// What was expected.
        reason: String,
    },
}

/// Bits per sample of a display image.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Depth {
    /// 8 bits (JPEG, PNG 8).
    Eight,
    /// 16 bits (PNG 16, TIFF 16).
    Sixteen,
}

/// A display image: RGB, sRGB-encoded, 8 or 16 bits per sample.
#[derive(Debug, Clone, PartialEq)]
pub struct DisplayImage {
    width: u32,
    height: u32,
    samples: Samples,
}

#[derive(Debug, Clone, PartialEq)]
enum Samples {
    Eight(Vec<u8>),
    Sixteen(Vec<u16>),
}

/// `round(v · 255 / 65535)`: a 16-bit sample at 8 bits.
#[inline]
pub fn to_8bit(v: u16) -> u8 {
    ((u32::from(v) * 255 + 32767) / 65535) as u8
}

impl DisplayImage {
    /// Wraps interleaved 16-bit RGB samples (`width·height·3` of them).
    ///
    /// # Panics
    /// If the length does not match: callers build the buffer from the same dimensions.
    pub fn new(width: u32, height: u32, samples: Vec<u16>) -> DisplayImage {
        assert_eq!(samples.len(), width as usize * height as usize * 3);
        DisplayImage {
            width,
            height,
            samples: Samples::Sixteen(samples),
        }
    }

    /// Wraps interleaved 8-bit RGB samples.
    ///
    /// # Panics
    /// If the length does not match.
    pub fn new_8bit(width: u32, height: u32, samples: Vec<u8>) -> DisplayImage {
        assert_eq!(samples.len(), width as usize * height as usize * 3);
        DisplayImage {
            width,
            height,
            samples: Samples::Eight(samples),
        }
    }

    /// Width in pixels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Bits per sample.
    pub fn depth(&self) -> Depth {
        match self.samples {
            Samples::Eight(_) => Depth::Eight,
            Samples::Sixteen(_) => Depth::Sixteen,
        }
    }

    /// Interleaved sRGB-encoded RGB at 16 bits (8-bit images scaled by 257).
    pub fn samples(&self) -> Cow<'_, [u16]> {
        match &self.samples {
            Samples::Sixteen(s) => Cow::Borrowed(s),
            Samples::Eight(s) => Cow::Owned(s.iter().map(|&v| u16::from(v) * 257).collect()),
        }
    }

    /// Interleaved sRGB-encoded RGB at 8 bits ([`to_8bit`] of 16-bit images).
    pub fn to_u8(&self) -> Cow<'_, [u8]> {
        match &self.samples {
            Samples::Eight(s) => Cow::Borrowed(s),
            Samples::Sixteen(s) => {
                let mut out = vec![0u8; s.len()];
                out.par_chunks_mut(1 << 16)
                    .zip(s.par_chunks(1 << 16))
                    .for_each(|(o, s)| {
                        for (o, &s) in o.iter_mut().zip(s) {
                            *o = to_8bit(s);
                        }
                    });
                Cow::Owned(out)
            }
        }
    }

    /// The image at `depth` (a copy only when it differs).
    pub fn at_depth(self, depth: Depth) -> DisplayImage {
        match (depth, &self.samples) {
            (Depth::Eight, Samples::Sixteen(_)) => {
                let s = self.to_u8().into_owned();
                DisplayImage::new_8bit(self.width, self.height, s)
            }
            (Depth::Sixteen, Samples::Eight(_)) => {
                let s = self.samples().into_owned();
                DisplayImage::new(self.width, self.height, s)
            }
            _ => self,
        }
    }
}

/// The sRGB transfer function (IEC 61966-2.1): linear `x ∈ [0,1]` to encoded value;
/// `12.92·x` below 0.0031308, `1.055·x^(1/2.4) − 0.055` above. Out-of-range and NaN
/// inputs clamp to `[0, 1]` (NaN to 0).
pub fn srgb_encode(x: f32) -> f32 {
    if x.is_nan() || x <= 0.0 {
        0.0
    } else if x >= 1.0 {
        1.0
    } else if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    }
}

/// `round(65535 · srgb_encode(x))` through a table: below 2⁻¹² (on the linear segment) it
/// is computed, above it looked up by the float's exponent and 11 mantissa bits at the
/// bucket centre — at most 1.1·10⁻⁴ relative error, under 7 of 65535 (0.03 of an 8-bit
/// step). Any `f32` is valid: NaN and negatives give 0, 1 and above 65535.
#[inline]
pub fn srgb_encode_u16(x: f32) -> u16 {
    const SHIFT: u32 = 12;
    static TABLE: OnceLock<(u32, Vec<u16>)> = OnceLock::new();
    let low = 2f32.powi(-12);
    if x.is_nan() || x <= 0.0 {
        return 0;
    }
    if x >= 1.0 {
        return 65535;
    }
    if x < low {
        return (12.92 * x * 65535.0).round() as u16;
    }
    let (base, table) = TABLE.get_or_init(|| {
        let base = low.to_bits() >> SHIFT;
        let top = 1f32.to_bits() >> SHIFT;
        let table = (base..top)
            .map(|i| {
                let centre = f32::from_bits((i << SHIFT) | (1 << (SHIFT - 1)));
                (srgb_encode(centre) * 65535.0).round() as u16
            })
            .collect();
        (base, table)
    });
    table[((x.to_bits() >> SHIFT) - base) as usize]
}

/// The sRGB ICC profile embedded in every output: built by the `moxcms` crate (already in
/// the build through `image`) from the IEC 61966-2.1 colorants (primaries x,y = 0.64,0.33 /
/// 0.30,0.60 / 0.15,0.06, D65 white, adapted to the D50 PCS) and the sRGB parametric
/// tone curve (γ 2.4, linear toe below 0.04045). About 0.5 kB.
pub fn srgb_icc_profile() -> &'static [u8] {
    static PROFILE: OnceLock<Vec<u8>> = OnceLock::new();
    PROFILE.get_or_init(|| {
        moxcms::ColorProfile::new_srgb()
            .encode()
            .unwrap_or_else(|e| panic!("moxcms cannot encode its own sRGB profile: {e:?}"))
    })
}

/// The EXIF fields carried from the source frame into every rendering.
#[derive(Debug, Clone, Default)]
pub struct SourceExif {
    fields: Vec<Field>,
}

/// Primary-image tags carried over: who and what made the shot, and how it was exposed.
/// Not `Orientation`: frames are turned upright when loaded, so renderings are upright.
const CARRIED: [Tag; 19] = [
    Tag::Make,
    Tag::Model,
    Tag::BodySerialNumber,
    Tag::LensMake,
    Tag::LensModel,
    Tag::LensSpecification,
    Tag::ExposureTime,
    Tag::FNumber,
    Tag::PhotographicSensitivity,
    Tag::ExposureProgram,
    Tag::ExposureBiasValue,
    Tag::FocalLength,
    Tag::FocalLengthIn35mmFilm,
    Tag::DateTimeOriginal,
    Tag::OffsetTimeOriginal,
    Tag::SubSecTimeOriginal,
    Tag::DateTime,
    Tag::Artist,
    Tag::Copyright,
];

fn ascii(tag: Tag, s: &str) -> Field {
    Field {
        tag,
        ifd_num: In::PRIMARY,
        value: Value::Ascii(vec![s.as_bytes().to_vec()]),
    }
}

fn rational(tag: Tag, x: f64) -> Field {
    // Exposure times as 1/n when shorter than a second, otherwise to 1/1000.
    let r = if x > 0.0 && x < 1.0 && ((1.0 / x) - (1.0 / x).round()).abs() < 1e-6 {
        exif::Rational::from((1, (1.0 / x).round() as u32))
    } else {
        exif::Rational::from(((x * 1000.0).round() as u32, 1000))
    };
    Field {
        tag,
        ifd_num: In::PRIMARY,
        value: Value::Rational(vec![r]),
    }
}

impl SourceExif {
    /// The carried fields of a source frame's file bytes (JPEG, TIFF, PNG, HEIF…);
    /// nothing when it has no readable EXIF.
    pub fn from_frame_bytes(bytes: &[u8]) -> SourceExif {
        let Ok(exif) = exif::Reader::new().read_from_container(&mut Cursor::new(bytes)) else {
            return SourceExif::default();
        };
        let fields = exif
            .fields()
            .filter(|f| f.ifd_num == In::PRIMARY && CARRIED.contains(&f.tag))
            .cloned()
            .collect();
        SourceExif { fields }
    }

    /// Fields rebuilt from parsed metadata (camera, lens, exposure, capture time) when the
    /// source bytes are not at hand, e.g. rendering from an EXR.
    pub fn from_metadata(metadata: &Metadata) -> SourceExif {
        let mut fields = Vec::new();
        let cam = &metadata.camera;
        for (tag, value) in [
            (Tag::Make, &cam.make),
            (Tag::Model, &cam.model),
            (Tag::BodySerialNumber, &cam.serial),
            (Tag::LensModel, &cam.lens),
        ] {
            if let Some(v) = value {
                fields.push(ascii(tag, v));
            }
        }
        let exposure = &metadata.exposure;
        if let Some(t) = exposure.time_s {
            fields.push(rational(Tag::ExposureTime, t));
        }
        if let Some(n) = exposure.f_number {
            fields.push(rational(Tag::FNumber, n));
        }
        if let Some(iso) = exposure.iso {
            fields.push(Field {
                tag: Tag::PhotographicSensitivity,
                ifd_num: In::PRIMARY,
                value: Value::Short(vec![iso.round().clamp(0.0, 65535.0) as u16]),
            });
        }
        if let Some(at) = &metadata.captured_at {
            let stamp = format!(
                "{:04}:{:02}:{:02} {:02}:{:02}:{:02}",
                at.year, at.month, at.day, at.hour, at.minute, at.second
            );
            fields.push(ascii(Tag::DateTimeOriginal, &stamp));
        }
        SourceExif { fields }
    }

    /// The carried fields.
    pub fn fields(&self) -> &[Field] {
        &self.fields
    }

    /// Carried fields plus `Software = filmback <version>`.
    fn with_software(&self) -> Vec<Field> {
        let mut fields: Vec<Field> = self
            .fields
            .iter()
            .filter(|f| f.tag != Tag::Software)
            .cloned()
            .collect();
        fields.push(ascii(
            Tag::Software,
            concat!("filmback ", env!("CARGO_PKG_VERSION")),
        ));
        fields
    }

    /// A TIFF-structured EXIF block (as embedded in JPEG APP1 after `Exif\0\0`, or in a
    /// PNG `eXIf` chunk).
    pub fn tiff_block(&self) -> Result<Vec<u8>, String> {
        let fields = self.with_software();
        let mut writer = exif::experimental::Writer::new();
        for f in &fields {
            writer.push_field(f);
        }
        let mut out = Cursor::new(Vec::new());
        writer.write(&mut out, false).map_err(|e| e.to_string())?;
        Ok(out.into_inner())
    }
}

/// Output encodings.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// Baseline JPEG, 4:2:0, at this quality (1–100).
    Jpeg {
        /// Quality.
        quality: u8,
    },
    /// PNG, 8 bits per sample.
    Png8,
    /// PNG, 16 bits per sample.
    Png16,
    /// Uncompressed TIFF, 16 bits per sample.
    Tiff16,
}

impl Format {
    /// Bits per sample the format stores.
    pub fn depth(self) -> Depth {
        match self {
            Format::Jpeg { .. } | Format::Png8 => Depth::Eight,
            Format::Png16 | Format::Tiff16 => Depth::Sixteen,
        }
    }

    /// File extension.
    pub fn extension(self) -> &'static str {
        match self {
            Format::Jpeg { .. } => "jpg",
            Format::Png8 | Format::Png16 => "png",
            Format::Tiff16 => "tif",
        }
    }
}

impl FromStr for Format {
    type Err = RenderingError;

    /// `jpeg`, `jpeg:95`, `png`, `png16`, `tiff`.
    fn from_str(s: &str) -> Result<Format, RenderingError> {
        let bad = || RenderingError::Parse {
            text: s.to_string(),
            reason: "expected jpeg, jpeg:QUALITY (1-100), png, png16 or tiff".into(),
        };
        match s {
            "jpeg" | "jpg" => Ok(Format::Jpeg { quality: 92 }),
            "png" | "png8" => Ok(Format::Png8),
            "png16" => Ok(Format::Png16),
            "tiff" | "tif" | "tiff16" => Ok(Format::Tiff16),
            _ => {
                let q = s
                    .strip_prefix("jpeg:")
                    .or_else(|| s.strip_prefix("jpg:"))
                    .and_then(|q| q.parse::<u8>().ok())
                    .filter(|q| (1..=100).contains(q))
                    .ok_or_else(bad)?;
                Ok(Format::Jpeg { quality: q })
            }
        }
    }
}

/// Encodes `image` in `format` with the sRGB profile and the EXIF block, into `out`.
pub fn encode(
    image: &DisplayImage,
    format: Format,
    exif: &SourceExif,
    out: &mut impl std::io::Write,
) -> Result<(), String> {
    let block = exif.tiff_block()?;
    let (w, h) = (image.width, image.height);
    match format {
        Format::Jpeg { quality } => {
            let rgb = image.to_u8();
            let mut encoder = jpeg_encoder::Encoder::new(out, quality);
            encoder
                .add_icc_profile(srgb_icc_profile())
                .map_err(|e| e.to_string())?;
            let mut app1 = b"Exif\0\0".to_vec();
            app1.extend_from_slice(&block);
            encoder
                .add_app_segment(1, app1)
                .map_err(|e| e.to_string())?;
            let (w16, h16) = (
                u16::try_from(w).map_err(|_| "JPEG is limited to 65535 pixels wide")?,
                u16::try_from(h).map_err(|_| "JPEG is limited to 65535 pixels high")?,
            );
            encoder
                .encode(&rgb, w16, h16, jpeg_encoder::ColorType::Rgb)
                .map_err(|e| e.to_string())
        }
        Format::Png8 | Format::Png16 => {
            use image::ImageEncoder;
            let mut encoder = image::codecs::png::PngEncoder::new(out);
            encoder
                .set_icc_profile(srgb_icc_profile().to_vec())
                .map_err(|e| e.to_string())?;
            encoder
                .set_exif_metadata(block)
                .map_err(|e| e.to_string())?;
            if format == Format::Png8 {
                encoder.write_image(&image.to_u8(), w, h, image::ExtendedColorType::Rgb8)
            } else {
                let bytes: Vec<u8> = image
                    .samples()
                    .iter()
                    .flat_map(|s| s.to_ne_bytes())
                    .collect();
                encoder.write_image(&bytes, w, h, image::ExtendedColorType::Rgb16)
            }
            .map_err(|e| e.to_string())
        }
        Format::Tiff16 => {
            let bytes = tiff16(image, exif)?;
            out.write_all(&bytes).map_err(|e| e.to_string())
        }
    }
}

/// A baseline uncompressed 16-bit RGB TIFF (little-endian) with the ICC profile (tag
/// 34675) and the EXIF fields, one strip per 64 rows.
fn tiff16(image: &DisplayImage, exif: &SourceExif) -> Result<Vec<u8>, String> {
    let (w, h) = (image.width, image.height);
    let rows_per_strip = 64u32;
    let row_bytes = w as usize * 6;
    let bytes: Vec<u8> = image
        .samples()
        .iter()
        .flat_map(|s| s.to_le_bytes())
        .collect();
    let strips: Vec<&[u8]> = bytes.chunks(row_bytes * rows_per_strip as usize).collect();
    let tiff = |tag: u16, value: Value| Field {
        tag: Tag(exif::Context::Tiff, tag),
        ifd_num: In::PRIMARY,
        value,
    };
    let mut fields = vec![
        tiff(256, Value::Long(vec![w])),
        tiff(257, Value::Long(vec![h])),
        tiff(258, Value::Short(vec![16, 16, 16])),
        tiff(259, Value::Short(vec![1])),
        tiff(262, Value::Short(vec![2])),
        tiff(277, Value::Short(vec![3])),
        tiff(278, Value::Long(vec![rows_per_strip])),
        tiff(284, Value::Short(vec![1])),
        tiff(34675, Value::Undefined(srgb_icc_profile().to_vec(), 0)),
    ];
    fields.extend(exif.with_software());
    let mut writer = exif::experimental::Writer::new();
    for f in &fields {
        writer.push_field(f);
    }
    writer.set_strips(&strips, In::PRIMARY);
    let mut out = Cursor::new(Vec::with_capacity(bytes.len() + 4096));
    writer.write(&mut out, true).map_err(|e| e.to_string())?;
    Ok(out.into_inner())
}

/// Rows per band handed from the developing thread to the JPEG encoder (a multiple of the
/// 16-row MCU of 4:2:0 JPEG).
const BAND_ROWS: usize = 64;

/// Row bands arriving from the developing thread, already in planar Y, Cb, Cr rows
/// (`jpeg_encoder::rgb_to_ycbcr`, the encoder's own conversion), copied out row by row.
struct Bands {
    width: u16,
    height: u16,
    receiver: std::sync::mpsc::Receiver<Vec<u8>>,
    /// (first row of the band, its rows of Y, Cb, Cr planes).
    current: std::cell::RefCell<(usize, Vec<u8>)>,
}

impl jpeg_encoder::ImageBuffer for Bands {
    fn get_jpeg_color_type(&self) -> jpeg_encoder::JpegColorType {
        jpeg_encoder::JpegColorType::Ycbcr
    }

    fn width(&self) -> u16 {
        self.width
    }

    fn height(&self) -> u16 {
        self.height
    }

    fn fill_buffers(&self, y: u16, buffers: &mut [Vec<u8>; 4]) {
        let w = usize::from(self.width);
        let row_bytes = w * 3;
        let mut current = self.current.borrow_mut();
        let y = usize::from(y);
        while y >= current.0 + current.1.len() / row_bytes {
            let start = current.0 + current.1.len() / row_bytes;
            // The developer never stops early; if it died, its panic surfaces when the
            // scope joins it, and these rows are black meanwhile.
            let band = self
                .receiver
                .recv()
                .unwrap_or_else(|_| vec![0; row_bytes * BAND_ROWS]);
            *current = (start, band);
        }
        let row = &current.1[(y - current.0) * row_bytes..][..row_bytes];
        for (plane, buffer) in row.chunks_exact(w).zip(buffers.iter_mut()) {
            buffer.extend_from_slice(plane);
        }
    }
}

/// Develops `map` through a stock and encodes it as JPEG at once: one thread develops
/// bands of 64 rows (in parallel within the band, colour conversion included) while the
/// single-threaded encoder consumes them, so developing hides behind encoding on a
/// 2-core machine. Decodes to the 8-bit [`film::Development::render`] within JPEG error.
pub fn encode_film_jpeg(
    map: &RadianceMap,
    development: &film::Development,
    quality: u8,
    exif: &SourceExif,
    out: &mut impl std::io::Write,
) -> Result<(), String> {
    let (w, h) = (map.width(), map.height());
    let width = u16::try_from(w).map_err(|_| "JPEG is limited to 65535 pixels wide")?;
    let height = u16::try_from(h).map_err(|_| "JPEG is limited to 65535 pixels high")?;
    let mut encoder = jpeg_encoder::Encoder::new(out, quality);
    encoder
        .add_icc_profile(srgb_icc_profile())
        .map_err(|e| e.to_string())?;
    let mut app1 = b"Exif\0\0".to_vec();
    app1.extend_from_slice(&exif.tiff_block()?);
    encoder
        .add_app_segment(1, app1)
        .map_err(|e| e.to_string())?;
    let (sender, receiver) = std::sync::mpsc::sync_channel::<Vec<u8>>(4);
    let w = w as usize;
    std::thread::scope(|scope| {
        scope.spawn(move || {
            for first in (0..h as usize).step_by(BAND_ROWS) {
                let rows = BAND_ROWS.min(h as usize - first);
                let mut rgb = vec![0u8; rows * w * 3];
                development.render_rows_8bit(map, first, &mut rgb);
                let mut planar = vec![0u8; rows * w * 3];
                planar
                    .par_chunks_mut(w * 3)
                    .zip(rgb.par_chunks(w * 3))
                    .for_each(|(out, rgb)| {
                        let (luma, chroma) = out.split_at_mut(w);
                        let (cb, cr) = chroma.split_at_mut(w);
                        for (i, p) in rgb.chunks_exact(3).enumerate() {
                            let (y, b, r) = jpeg_encoder::rgb_to_ycbcr(p[0], p[1], p[2]);
                            luma[i] = y;
                            cb[i] = b;
                            cr[i] = r;
                        }
                    });
                if sender.send(planar).is_err() {
                    break;
                }
            }
        });
        let bands = Bands {
            width,
            height,
            receiver,
            current: std::cell::RefCell::new((0, Vec::new())),
        };
        encoder.encode_image(bands).map_err(|e| e.to_string())
    })
}

/// Renders `look` and encodes it in `format`; film looks to JPEG take the streaming path
/// ([`encode_film_jpeg`]).
pub fn encode_look(
    map: &RadianceMap,
    look: &Look,
    format: Format,
    exif: &SourceExif,
    out: &mut impl std::io::Write,
) -> Result<(), RenderingError> {
    let encode_error = |reason: String| RenderingError::Encode {
        path: PathBuf::new(),
        format: format!("{format:?}"),
        reason,
    };
    if let (
        Look::Film {
            stock,
            exposure,
            colour,
            key,
        },
        Format::Jpeg { quality },
    ) = (look, format)
    {
        let development =
            film::Development::new(stock, *exposure, film::scene_key(map, *key), *colour)?;
        return encode_film_jpeg(map, &development, quality, exif, out).map_err(encode_error);
    }
    let image = look.render(map, format.depth())?;
    encode(&image, format, exif, out).map_err(encode_error)
}

/// Encodes and publishes `image` at `path` atomically.
pub fn write(
    path: &Path,
    image: &DisplayImage,
    format: Format,
    exif: &SourceExif,
    overwrite: Overwrite,
) -> Result<(), RenderingError> {
    atomic::publish_with(path, overwrite, |w| encode(image, format, exif, w)).map_err(|e| match e {
        PublishError::Content { path, reason } => RenderingError::Encode {
            path,
            format: format!("{format:?}"),
            reason,
        },
        other => RenderingError::Publish(other),
    })
}

/// Reads the first RGB(A) layer of an OpenEXR file as a radiance map (alpha dropped).
pub fn read_exr(path: &Path) -> Result<RadianceMap, RenderingError> {
    let image = exr::prelude::read_first_rgba_layer_from_file(
        path,
        |size, _| (size.width(), vec![0f32; size.width() * size.height() * 3]),
        |(width, pixels): &mut (usize, Vec<f32>), pos, (r, g, b, _a): (f32, f32, f32, f32)| {
            let i = (pos.y() * *width + pos.x()) * 3;
            pixels[i..i + 3].copy_from_slice(&[r, g, b]);
        },
    )
    .map_err(|e| RenderingError::Exr {
        path: path.to_path_buf(),
        reason: e.to_string(),
    })?;
    let size = image.layer_data.size;
    let (_, pixels) = image.layer_data.channel_data.pixels;
    RadianceMap::new(size.width() as u32, size.height() as u32, 3, pixels).map_err(|e| {
        RenderingError::Exr {
            path: path.to_path_buf(),
            reason: e.to_string(),
        }
    })
}

/// One way to show a radiance map.
#[derive(Debug, Clone)]
pub enum Look {
    /// Through a reversal stock.
    Film {
        /// The stock (boxed: a stock is large next to a tone-map operator).
        stock: Box<Stock>,
        /// Relative exposure `t`.
        exposure: f64,
        /// How the layers share the light.
        colour: ColourMode,
        /// What is metered.
        key: Key,
    },
    /// A tone-mapping operator.
    Tonemap(tonemap::Operator),
}

impl Look {
    /// A film look from a request such as `provia400@1/2`.
    pub fn film(
        catalogue: &Catalogue,
        request: &str,
        colour: ColourMode,
        key: Key,
    ) -> Result<Look, RenderingError> {
        let request: film::Request = request.parse()?;
        let stock = Box::new(catalogue.get(&request.stock)?.clone());
        if stock.kind == film::Kind::Negative {
            return Err(FilmError::Negative {
                id: stock.id.clone(),
            }
            .into());
        }
        Ok(Look::Film {
            stock,
            exposure: request.exposure,
            colour,
            key,
        })
    }

    /// The look's part of an output file name: `velvia50-t0.5`, `linear`, `histogram`.
    pub fn name(&self) -> String {
        match self {
            Look::Film {
                stock, exposure, ..
            } => format!("{}-t{}", stock.id, exposure_label(*exposure)),
            Look::Tonemap(op) => op.name().to_string(),
        }
    }

    /// Renders `map` in this look at `depth` bits per sample.
    pub fn render(&self, map: &RadianceMap, depth: Depth) -> Result<DisplayImage, RenderingError> {
        match self {
            Look::Film {
                stock,
                exposure,
                colour,
                key,
            } => {
                let development =
                    film::Development::new(stock, *exposure, film::scene_key(map, *key), *colour)?;
                Ok(development.render(map, depth))
            }
            Look::Tonemap(op) => Ok(op.apply(map).at_depth(depth)),
        }
    }
}

/// `1`, `0.5`, `0.125`, `8`: the shortest decimal that round-trips (at most 4 places).
fn exposure_label(t: f64) -> String {
    let s = format!("{t:.4}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

/// `DIR/STEM.LOOK.EXT`, the file a rendering of `look` is written to.
pub fn look_path(dir: &Path, stem: &str, look: &Look, format: Format) -> PathBuf {
    dir.join(format!("{stem}.{}.{}", look.name(), format.extension()))
}

/// The looks of film requests (`velvia50`, `provia400@1/2`, …) and tone-map names
/// (`linear`, `histogram`, `histogram-naive`), in that order. Every film's relative
/// exposure is multiplied by `2^stops` (a preset's exposure offset; 0 for none).
pub fn looks(
    catalogue: &Catalogue,
    films: &[String],
    tonemaps: &[String],
    stops: f64,
    colour: ColourMode,
    key: Key,
) -> Result<Vec<Look>, RenderingError> {
    let mut looks = Vec::with_capacity(films.len() + tonemaps.len());
    for request in films {
        let mut look = Look::film(catalogue, request, colour, key)?;
        if let Look::Film { exposure, .. } = &mut look {
            *exposure *= stops.exp2();
        }
        looks.push(look);
    }
    for name in tonemaps {
        let op = tonemap::Operator::parse(name).ok_or_else(|| RenderingError::Parse {
            text: name.clone(),
            reason: "unknown tone map: expected linear, histogram or histogram-naive".into(),
        })?;
        looks.push(Look::Tonemap(op));
    }
    Ok(looks)
}

/// Where and how renderings are written.
#[derive(Debug, Clone)]
pub struct Outputs<'a> {
    /// Output folder.
    pub dir: &'a Path,
    /// File stem shared by all renderings of one map (e.g. the EXR's stem).
    pub stem: &'a str,
    /// Encoding.
    pub format: Format,
    /// Replace existing files or refuse.
    pub overwrite: Overwrite,
    /// EXIF carried into every file.
    pub exif: &'a SourceExif,
}

/// Renders `map` in every look and writes `DIR/STEM.LOOK.EXT` for each, atomically.
/// Returns the paths written, in the order of `looks`. Stops at the first error; files
/// already written stay (each is complete).
pub fn render_all(
    map: &RadianceMap,
    looks: &[Look],
    outputs: &Outputs<'_>,
) -> Result<Vec<PathBuf>, RenderingError> {
    let mut written = Vec::with_capacity(looks.len());
    for look in looks {
        let path = look_path(outputs.dir, outputs.stem, look, outputs.format);
        // A look that cannot be rendered (a negative stock) fails before any file exists.
        if let Look::Film { stock, .. } = look
            && stock.kind == film::Kind::Negative
        {
            return Err(FilmError::Negative {
                id: stock.id.clone(),
            }
            .into());
        }
        let mut failure = None;
        let published = atomic::publish_with(&path, outputs.overwrite, |w| {
            encode_look(map, look, outputs.format, outputs.exif, w).map_err(|e| {
                let reason = e.to_string();
                failure = Some(e);
                reason
            })
        });
        match (published, failure) {
            (Ok(()), _) => written.push(path),
            (Err(_), Some(RenderingError::Encode { format, reason, .. })) => {
                return Err(RenderingError::Encode {
                    path,
                    format,
                    reason,
                });
            }
            (Err(_), Some(other)) => return Err(other),
            (Err(e), None) => return Err(e.into()),
        }
    }
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp() -> DisplayImage {
        let (w, h) = (32u32, 8u32);
        let samples = (0..w * h * 3).map(|i| (i * 97 % 65536) as u16).collect();
        DisplayImage::new(w, h, samples)
    }

    fn exif() -> SourceExif {
        let m = Metadata {
            camera: crate::metadata::Camera {
                make: Some("Testmaker".into()),
                model: Some("T-1".into()),
                ..Default::default()
            },
            exposure: crate::metadata::Exposure {
                time_s: Some(1.0 / 125.0),
                f_number: Some(8.0),
                iso: Some(100.0),
            },
            captured_at: None,
            orientation: 1,
            warnings: Vec::new(),
        };
        SourceExif::from_metadata(&m)
    }

    fn read_back(bytes: &[u8]) -> exif::Exif {
        exif::Reader::new()
            .read_from_container(&mut Cursor::new(bytes))
            .expect("EXIF readable")
    }

    #[test]
    fn icc_profile_is_a_valid_srgb_profile() {
        let p = srgb_icc_profile();
        let size = u32::from_be_bytes([p[0], p[1], p[2], p[3]]) as usize;
        assert_eq!(size, p.len());
        assert_eq!(&p[36..40], b"acsp");
        assert_eq!(&p[12..16], b"mntr");
        assert_eq!(&p[16..20], b"RGB ");
        assert_eq!(&p[20..24], b"XYZ ");
        let profile = moxcms::ColorProfile::new_from_slice(p).expect("parses back");
        // Published D50-adapted colorants of IEC 61966-2.1 (red X,Y,Z).
        let r = profile.red_colorant;
        assert!(
            (r.x - 0.4361).abs() < 1e-3 && (r.y - 0.2225).abs() < 1e-3,
            "{r:?}"
        );
    }

    #[test]
    fn every_format_carries_profile_and_exif() {
        let img = ramp();
        for format in [
            Format::Jpeg { quality: 90 },
            Format::Png8,
            Format::Png16,
            Format::Tiff16,
        ] {
            let mut bytes = Vec::new();
            encode(&img, format, &exif(), &mut bytes).unwrap();
            let decoded =
                image::load_from_memory(&bytes).unwrap_or_else(|e| panic!("{format:?}: {e}"));
            assert_eq!((decoded.width(), decoded.height()), (32, 8));
            if format == Format::Png16 || format == Format::Tiff16 {
                let rgb = decoded.to_rgb16();
                assert_eq!(rgb.as_raw().as_slice(), &*img.samples(), "{format:?}");
            }
            let e = read_back(&bytes);
            let get = |t: Tag| {
                e.get_field(t, In::PRIMARY)
                    .map(|f| f.display_value().to_string())
            };
            assert_eq!(
                get(Tag::Make).as_deref(),
                Some("\"Testmaker\""),
                "{format:?}"
            );
            assert!(
                get(Tag::Software).unwrap().contains("filmback"),
                "{format:?}"
            );
            assert_eq!(
                get(Tag::ExposureTime).as_deref(),
                Some("1/125"),
                "{format:?}"
            );
            let icc_tag = b"ICC_PROFILE";
            let has_icc = match format {
                Format::Jpeg { .. } => bytes.windows(icc_tag.len()).any(|w| w == icc_tag),
                Format::Png8 | Format::Png16 => bytes.windows(4).any(|w| w == b"iCCP"),
                Format::Tiff16 => e
                    .get_field(Tag(exif::Context::Tiff, 34675), In::PRIMARY)
                    .is_some(),
            };
            assert!(has_icc, "{format:?} lacks the ICC profile");
        }
    }

    #[test]
    fn streaming_jpeg_decodes_to_the_developed_image() {
        let catalogue = film::Catalogue::builtin().unwrap();
        let stock = catalogue.get("velvia50").unwrap();
        let map = crate::synthetic::scene(200, 150, 3);
        let development = film::Development::new(
            stock,
            1.0,
            film::scene_key(&map, Key::LogAverage),
            ColourMode::PerLayer,
        )
        .unwrap();
        let reference = development.render(&map, Depth::Eight);
        let mut streamed = Vec::new();
        encode_film_jpeg(&map, &development, 95, &exif(), &mut streamed).unwrap();
        let mut whole = Vec::new();
        encode(
            &reference,
            Format::Jpeg { quality: 95 },
            &exif(),
            &mut whole,
        )
        .unwrap();
        let a = image::load_from_memory(&streamed).unwrap().to_rgb8();
        let b = image::load_from_memory(&whole).unwrap().to_rgb8();
        let mean_diff = a
            .as_raw()
            .iter()
            .zip(b.as_raw())
            .map(|(&x, &y)| f64::from(x.abs_diff(y)))
            .sum::<f64>()
            / a.as_raw().len() as f64;
        assert!(mean_diff < 0.5, "mean difference {mean_diff}");
        assert!(
            read_back(&streamed)
                .get_field(Tag::Software, In::PRIMARY)
                .is_some()
        );
    }

    #[test]
    fn exif_is_carried_from_frame_bytes() {
        let mut bytes = Vec::new();
        encode(&ramp(), Format::Jpeg { quality: 80 }, &exif(), &mut bytes).unwrap();
        let carried = SourceExif::from_frame_bytes(&bytes);
        assert!(carried.fields().iter().any(|f| f.tag == Tag::Model));
        assert!(carried.fields().iter().all(|f| f.tag != Tag::Software));
        assert!(
            SourceExif::from_frame_bytes(b"not an image")
                .fields()
                .is_empty()
        );
    }

    #[test]
    fn srgb_encode_is_clamped_and_continuous() {
        assert_eq!(srgb_encode(f32::NAN), 0.0);
        assert_eq!(srgb_encode(-1.0), 0.0);
        assert_eq!(srgb_encode(f32::INFINITY), 1.0);
        let a = srgb_encode(0.003_130_8);
        let b = srgb_encode(0.003_130_9);
        assert!((a - b).abs() < 1e-4);
        assert!((srgb_encode(0.18) - 0.4613).abs() < 1e-3);
    }

    #[test]
    fn srgb_table_matches_the_formula() {
        let mut worst = 0i32;
        for i in 0..=200_000 {
            let x = 10f32.powf(-6.0 + 6.0 * i as f32 / 200_000.0);
            let exact = (srgb_encode(x) * 65535.0).round() as i32;
            worst = worst.max((i32::from(srgb_encode_u16(x)) - exact).abs());
        }
        assert!(worst <= 7, "worst {worst} of 65535");
        let mut prev = 0;
        for i in 0..=2_000_000 {
            let x = i as f32 / 2_000_000.0;
            let v = srgb_encode_u16(x);
            assert!(v >= prev, "not monotone at {x}: {v} < {prev}");
            prev = v;
        }
        assert_eq!(srgb_encode_u16(f32::NAN), 0);
        assert_eq!(srgb_encode_u16(f32::INFINITY), 65535);
        assert_eq!(srgb_encode_u16(-0.0), 0);
    }

    #[test]
    fn formats_parse() {
        assert_eq!(
            "jpeg:95".parse::<Format>().unwrap(),
            Format::Jpeg { quality: 95 }
        );
        assert_eq!("png16".parse::<Format>().unwrap(), Format::Png16);
        assert!("jpeg:0".parse::<Format>().is_err());
        assert!("gif".parse::<Format>().is_err());
    }
}
