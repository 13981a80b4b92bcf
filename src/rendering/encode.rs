//! Encoding display images as files — JPEG, PNG 8/16-bit or TIFF 16-bit, each with an
//! embedded sRGB ICC profile and the source frame's EXIF — and streaming a film look
//! into the JPEG encoder band by band.

use std::io::Cursor;
use std::path::{Path, PathBuf};
use std::str::FromStr;

use exif::{Field, In, Tag, Value};
use rayon::prelude::*;

use super::{Look, RenderingError, SourceExif};
use crate::atomic::{self, Overwrite, PublishError};
use crate::display::{Depth, DisplayImage, srgb_icc_profile};
use crate::film;
use crate::radiance::RadianceMap;

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
    let (w, h) = (image.width(), image.height());
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
    let (w, h) = (image.width(), image.height());
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
/// 2-core machine. Decodes to the 8-bit [`film::Emulsion::render`] within JPEG error.
/// `exposure` is the light inside the film ([`film::Emulsion::expose`]).
pub fn encode_film_jpeg(
    exposure: &film::Exposure<'_>,
    emulsion: &film::Emulsion,
    quality: u8,
    exif: &SourceExif,
    out: &mut impl std::io::Write,
) -> Result<(), String> {
    let (w, h) = (exposure.width(), exposure.height());
    stream_jpeg(
        w,
        h,
        |first, rgb| emulsion.render_rows_8bit(exposure, first, rgb),
        quality,
        exif,
        out,
    )
}

/// Encodes a JPEG of `w × h` whose 8-bit RGB rows `develop(first, rows)` fills, a band
/// of 64 rows at a time on a thread of its own while the encoder consumes the bands.
fn stream_jpeg(
    w: u32,
    h: u32,
    develop: impl Fn(usize, &mut [u8]) + Sync,
    quality: u8,
    exif: &SourceExif,
    out: &mut impl std::io::Write,
) -> Result<(), String> {
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
    let develop = &develop;
    std::thread::scope(|scope| {
        scope.spawn(move || {
            for first in (0..h as usize).step_by(BAND_ROWS) {
                let rows = BAND_ROWS.min(h as usize - first);
                let mut rgb = vec![0u8; rows * w * 3];
                develop(first, &mut rgb);
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

/// Renders `look` and encodes it in `format`; to JPEG, film looks and tone maps are
/// developed band by band while the encoder runs ([`encode_film_jpeg`]).
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
    match (look, format) {
        (Look::Film { .. }, Format::Jpeg { quality }) => {
            let emulsion = look.emulsion(map)?;
            let exposure = emulsion.expose(map);
            return encode_film_jpeg(&exposure, &emulsion, quality, exif, out)
                .map_err(encode_error);
        }
        (Look::Tonemap(op), Format::Jpeg { quality }) => {
            let tone = op.prepare(map);
            let develop = |first: usize, rgb: &mut [u8]| tone.render_rows_8bit(map, first, rgb);
            return stream_jpeg(map.width(), map.height(), develop, quality, exif, out)
                .map_err(encode_error);
        }
        _ => {}
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
