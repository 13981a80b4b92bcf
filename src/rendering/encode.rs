//! Encoding display images as files — JPEG, PNG 8/16-bit or TIFF 16-bit, each with the
//! ICC profile of its colour space (and a PNG's `cICP` chunk) and the source frame's
//! EXIF — and streaming an sRGB look into the JPEG encoder band by band.

use std::io::Cursor;
use std::path::{Path, PathBuf};
use std::str::FromStr;

use super::source_exif::Storage;
use super::{ImageEncodeError, Look, RenderingError, Shrink, SourceExif, hdr_still, jpeg};
use crate::atomic::{self, Overwrite};
use crate::display::{ColourSpace, Depth, DisplayImage};
use crate::radiance::RadianceSource;
use exif::{Field, In, Tag, Value};

/// Output encodings.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// Baseline JPEG at this quality (1–100): 4:2:0 chroma below 90, 4:4:4 from 90,
    /// restart markers between bands of rows encoded in parallel.
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
    /// The HDR still: a gain-map JPEG (Ultra HDR, ISO 21496-1) at this quality whose base
    /// is the look's [`Format::Jpeg`] rendering ([`hdr_still`]); made from a look only.
    UltraHdr {
        /// Quality of the base and of the gain map.
        quality: u8,
    },
}

impl Format {
    /// Bits per sample the format stores.
    pub fn depth(self) -> Depth {
        match self {
            Format::Jpeg { .. } | Format::UltraHdr { .. } | Format::Png8 => Depth::Eight,
            Format::Png16 | Format::Tiff16 => Depth::Sixteen,
        }
    }

    /// File extension.
    pub fn extension(self) -> &'static str {
        match self {
            Format::Jpeg { .. } | Format::UltraHdr { .. } => "jpg",
            Format::Png8 | Format::Png16 => "png",
            Format::Tiff16 => "tif",
        }
    }
}

impl std::fmt::Display for Format {
    /// As [`Format::from_str`] reads it: `jpeg:92`, `png`, `png16`, `tiff`, `ultrahdr:92`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Format::Jpeg { quality } => write!(f, "jpeg:{quality}"),
            Format::Png8 => f.write_str("png"),
            Format::Png16 => f.write_str("png16"),
            Format::Tiff16 => f.write_str("tiff"),
            Format::UltraHdr { quality } => write!(f, "ultrahdr:{quality}"),
        }
    }
}

impl FromStr for Format {
    type Err = RenderingError;

    /// `jpeg`, `jpeg:95`, `png`, `png16`, `tiff`, `ultrahdr`, `ultrahdr:95`.
    fn from_str(s: &str) -> Result<Format, RenderingError> {
        let bad = || RenderingError::Parse {
            text: s.to_string(),
            reason: "expected jpeg, jpeg:QUALITY (1-100), png, png16, tiff, ultrahdr or \
                     ultrahdr:QUALITY"
                .into(),
        };
        if let Some(q) = s.strip_prefix("ultrahdr:") {
            let quality = q
                .parse::<u8>()
                .ok()
                .filter(|q| (1..=100).contains(q))
                .ok_or_else(bad)?;
            return Ok(Format::UltraHdr { quality });
        }
        match s {
            "ultrahdr" => Ok(Format::UltraHdr { quality: 92 }),
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

/// Encodes `image` in `format` with its colour space's profile and the EXIF block, into
/// `out`.
pub fn encode(
    image: &DisplayImage,
    format: Format,
    exif: &SourceExif,
    out: &mut impl std::io::Write,
) -> Result<(), ImageEncodeError> {
    let (w, h) = (image.width(), image.height());
    match format {
        Format::Jpeg { quality } => {
            let block = exif.tiff_block(w, h, Storage::Jpeg)?;
            let rgb = image.to_u8();
            let row = w as usize * 3;
            let copy = |first: usize, band: &mut [u8]| {
                band.copy_from_slice(&rgb[first * row..][..band.len()]);
            };
            let decorate = decorate(&block, image.space());
            jpeg::encode_bands(w, h, quality, decorate, copy, out)
        }
        Format::Png8 | Format::Png16 => {
            let block = exif.tiff_block(w, h, Storage::Rgb)?;
            Ok(png(image, format == Format::Png16, block, out)?)
        }
        Format::Tiff16 => {
            let bytes = tiff16(image, exif)?;
            Ok(out.write_all(&bytes)?)
        }
        Format::UltraHdr { .. } => Err(ImageEncodeError::NeedsRadiance),
    }
}

/// A PNG of `image` (16 bits per sample when `sixteen`) with the space's ICC profile
/// (`iCCP`), its code points (`cICP`, which a PNG reader takes before `iCCP`) and the
/// EXIF block (`eXIf`).
fn png(
    image: &DisplayImage,
    sixteen: bool,
    exif: Vec<u8>,
    out: &mut impl std::io::Write,
) -> Result<(), ::png::EncodingError> {
    let mut info = ::png::Info::with_size(image.width(), image.height());
    info.color_type = ::png::ColorType::Rgb;
    info.bit_depth = if sixteen {
        ::png::BitDepth::Sixteen
    } else {
        ::png::BitDepth::Eight
    };
    info.icc_profile = Some(image.space().icc_profile().into());
    info.exif_metadata = Some(exif.into());
    let mut writer = ::png::Encoder::with_info(out, info)?.write_header()?;
    writer.write_chunk(::png::chunk::ChunkType(*b"cICP"), &image.space().cicp())?;
    if sixteen {
        let bytes: Vec<u8> = image
            .samples()
            .iter()
            .flat_map(|s| s.to_be_bytes())
            .collect();
        writer.write_image_data(&bytes)?;
    } else {
        writer.write_image_data(&image.to_u8())?;
    }
    writer.finish()
}

/// A baseline uncompressed 16-bit RGB TIFF (little-endian) with the ICC profile (tag
/// 34675) and the EXIF fields, one strip per 64 rows.
fn tiff16(image: &DisplayImage, exif: &SourceExif) -> Result<Vec<u8>, exif::Error> {
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
        tiff(
            34675,
            Value::Undefined(image.space().icc_profile().to_vec(), 0),
        ),
    ];
    fields.extend(exif.rendering_fields(w, h, Storage::Rgb));
    let mut writer = exif::experimental::Writer::new();
    for f in &fields {
        writer.push_field(f);
    }
    writer.set_strips(&strips, In::PRIMARY);
    let mut out = Cursor::new(Vec::with_capacity(bytes.len() + 4096));
    writer.write(&mut out, true)?;
    Ok(out.into_inner())
}

/// Develops `map` through a stock and encodes it as JPEG at once: bands of rows are
/// developed and encoded on every core, each band by its own encoder, joined by restart
/// markers (`rendering::jpeg`). Decodes to the 8-bit [`crate::film::Emulsion::render`] within
/// JPEG error.
/// `exposure` is the light inside the film ([`crate::film::Emulsion::expose`]).
#[cfg(test)]
pub(crate) fn encode_film_jpeg(
    exposure: &crate::film::LatentImage<'_>,
    emulsion: &crate::film::Emulsion,
    quality: u8,
    exif: &SourceExif,
    out: &mut impl std::io::Write,
) -> Result<(), ImageEncodeError> {
    let (w, h) = (exposure.width(), exposure.height());
    let develop = |first: usize, rgb: &mut [u8]| emulsion.render_rows_8bit(exposure, first, rgb);
    stream_jpeg(w, h, develop, quality, exif, out, None)
}

/// Encodes a JPEG of `w × h` whose 8-bit RGB rows `develop(first, rows)` fills, bands
/// of rows developed and encoded on every core (`rendering::jpeg`); each band is also
/// added to `shrink`.
fn stream_jpeg(
    w: u32,
    h: u32,
    develop: impl Fn(usize, &mut [u8]) + Sync,
    quality: u8,
    exif: &SourceExif,
    out: &mut impl std::io::Write,
    shrink: Option<&Shrink>,
) -> Result<(), ImageEncodeError> {
    let block = exif.tiff_block(w, h, Storage::Jpeg)?;
    let decorate = decorate(&block, ColourSpace::Srgb);
    let develop = |first: usize, rgb: &mut [u8]| {
        develop(first, rgb);
        if let Some(shrink) = shrink {
            shrink.add_rows(first, rgb);
        }
    };
    jpeg::encode_bands(w, h, quality, decorate, develop, out)
}

/// Adds the EXIF block (APP1) and then the profile of `space` (APP2) to a JPEG encoder,
/// in the order Exif (CIPA DC-008) asks: APP1 first after the JFIF header.
fn decorate(
    block: &[u8],
    space: ColourSpace,
) -> impl Fn(
    &mut rusty_jpeg::encode::Encoder<&mut Vec<u8>>,
) -> Result<(), rusty_jpeg::encode::EncodingError>
+ Sync {
    move |encoder| {
        let mut app1 = b"Exif\0\0".to_vec();
        app1.extend_from_slice(block);
        encoder.add_app_segment(1, app1)?;
        encoder.add_icc_profile(space.icc_profile())
    }
}

/// Renders `look` for `space` and encodes it in `format`; to an sRGB JPEG, film looks and
/// tone maps are developed band by band while the encoder runs (`stream_jpeg`).
/// Another space is developed at 16 bits, re-encoded ([`DisplayImage::in_space`]) and
/// then reduced to the format's depth.
pub fn encode_look(
    map: &dyn RadianceSource,
    look: &Look,
    format: Format,
    space: ColourSpace,
    exif: &SourceExif,
    out: &mut impl std::io::Write,
) -> Result<(), RenderingError> {
    encode_look_previewed(map, look, format, space, exif, out, None)
}

/// [`encode_look`], adding the rendering's 8-bit sRGB rows to `shrink` as they are made
/// (for another space, the rows before they are re-encoded for it).
pub(crate) fn encode_look_previewed(
    map: &dyn RadianceSource,
    look: &Look,
    format: Format,
    space: ColourSpace,
    exif: &SourceExif,
    out: &mut impl std::io::Write,
    shrink: Option<&Shrink>,
) -> Result<(), RenderingError> {
    let encode_error = |source| RenderingError::Encode {
        path: PathBuf::new(),
        format,
        source,
    };
    let (w, h) = (map.width(), map.height());
    match (look, format) {
        (_, Format::UltraHdr { quality }) => {
            return hdr_still::encode(map, look, quality, space, exif, out, shrink);
        }
        _ if space != ColourSpace::Srgb => {
            let srgb = look.render(map, Depth::Sixteen)?;
            add_image(shrink, &srgb);
            let image = srgb.in_space(space);
            return encode(&image.at_depth(format.depth()), format, exif, out)
                .map_err(encode_error);
        }
        (Look::Film { .. }, Format::Jpeg { quality }) => {
            let emulsion = look.emulsion(map)?;
            let exposure = emulsion.expose(map);
            let develop =
                |first: usize, rgb: &mut [u8]| emulsion.render_rows_8bit(&exposure, first, rgb);
            return stream_jpeg(w, h, develop, quality, exif, out, shrink).map_err(encode_error);
        }
        (Look::Tonemap(op), Format::Jpeg { quality }) => {
            let tone = op.prepare(map);
            let develop = |first: usize, rgb: &mut [u8]| tone.render_rows_8bit(map, first, rgb);
            return stream_jpeg(w, h, develop, quality, exif, out, shrink).map_err(encode_error);
        }
        _ => {}
    }
    let image = look.render(map, format.depth())?;
    add_image(shrink, &image);
    encode(&image, format, exif, out).map_err(encode_error)
}

/// Adds a whole rendered image to `shrink`, when there is one.
fn add_image(shrink: Option<&Shrink>, image: &DisplayImage) {
    if let Some(shrink) = shrink {
        shrink.add_rows(0, &image.to_u8());
    }
}

/// Encodes and publishes `image` at `path` atomically.
pub fn write(
    path: &Path,
    image: &DisplayImage,
    format: Format,
    exif: &SourceExif,
    overwrite: Overwrite,
) -> Result<(), RenderingError> {
    atomic::publish_with(path, overwrite, |w| {
        encode(image, format, exif, w).map_err(|source| RenderingError::Encode {
            path: path.to_path_buf(),
            format,
            source,
        })
    })
}
