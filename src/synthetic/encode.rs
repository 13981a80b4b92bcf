//! Writing synthetic frames as JPEG, PNG or TIFF with EXIF exposure tags.
//!
//! The EXIF block is made by kamadak-exif's `exif::experimental::Writer` (a TIFF structure,
//! little-endian). JPEG and PNG carry it through `image`'s encoders (`APP1` segment and
//! `eXIf` chunk). `image`'s TIFF encoder cannot take EXIF, so a TIFF is written whole by
//! the same EXIF writer: the primary IFD holds the baseline tags of an uncompressed image
//! (width, length, bits per sample, photometric interpretation, strips) plus the camera
//! tags, with the exposure tags in its Exif IFD — a TIFF file *is* that structure.

use std::io::Cursor;

use exif::experimental::Writer;
use exif::{Field, In, Rational, Tag, Value};
use image::{ExtendedColorType, ImageEncoder};

use super::{EncodeError, Shot, SyntheticError};
use crate::frame::{Frame, Samples};
use crate::metadata::CaptureTime;

/// Container and compression of an encoded frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Encoding {
    /// Baseline JPEG, 8-bit only, lossy; quality 1 (smallest) to 100 (best).
    Jpeg {
        /// JPEG quality, 1..=100.
        quality: u8,
    },
    /// PNG, lossless, 8- or 16-bit.
    Png,
    /// Uncompressed baseline TIFF, lossless, 8- or 16-bit.
    Tiff,
}

/// Encodes `frame` in `encoding` with EXIF from `shot`: Make, Model, BodySerialNumber (each
/// when known), Orientation = 1, ExposureTime and FNumber (rationals), ISO as
/// PhotographicSensitivity (or, above 65534, 65535 with SensitivityType = 2 and
/// RecommendedExposureIndex), DateTimeOriginal with SubSecTimeOriginal and
/// OffsetTimeOriginal when recorded, ExifVersion 0232. Unknown exposure values are left out.
pub fn encode(frame: &Frame, shot: &Shot, encoding: Encoding) -> Result<Vec<u8>, SyntheticError> {
    let fields = exif_fields(shot)?;
    match encoding {
        Encoding::Jpeg { quality } => encode_jpeg(frame, &fields, quality),
        Encoding::Png => encode_png(frame, &fields),
        Encoding::Tiff => encode_tiff(frame, fields),
    }
}

/// Encodes like [`encode`] and publishes the file atomically at `path` (replacing it).
#[cfg(feature = "ground-truth")]
pub fn write(
    path: &std::path::Path,
    frame: &Frame,
    shot: &Shot,
    encoding: Encoding,
) -> Result<(), SyntheticError> {
    let bytes = encode(frame, shot, encoding)?;
    crate::atomic::publish(path, &bytes, crate::atomic::Overwrite::Replace)?;
    Ok(())
}

fn encode_error(format: &'static str, source: impl Into<EncodeError>) -> SyntheticError {
    SyntheticError::Encode {
        format,
        source: source.into(),
    }
}

/// The EXIF block (a little-endian TIFF structure) of `fields`, without image data.
fn exif_block(fields: &[Field]) -> Result<Vec<u8>, SyntheticError> {
    let mut writer = Writer::new();
    for field in fields {
        writer.push_field(field);
    }
    let mut block = Cursor::new(Vec::new());
    writer
        .write(&mut block, true)
        .map_err(|e| encode_error("EXIF", e))?;
    Ok(block.into_inner())
}

fn encode_jpeg(frame: &Frame, fields: &[Field], quality: u8) -> Result<Vec<u8>, SyntheticError> {
    if !(1..=100).contains(&quality) {
        return Err(encode_error("JPEG", EncodeError::Quality(quality)));
    }
    let Samples::Eight(codes) = frame.samples() else {
        return Err(encode_error("JPEG", EncodeError::SixteenBitJpeg));
    };
    let colour = match frame.channels() {
        1 => ExtendedColorType::L8,
        _ => ExtendedColorType::Rgb8,
    };
    let mut bytes = Vec::new();
    let mut encoder = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut bytes, quality);
    encoder
        .set_exif_metadata(exif_block(fields)?)
        .map_err(|e| encode_error("JPEG", image::ImageError::Unsupported(e)))?;
    encoder
        .write_image(codes, frame.width(), frame.height(), colour)
        .map_err(|e| encode_error("JPEG", e))?;
    Ok(bytes)
}

fn encode_png(frame: &Frame, fields: &[Field]) -> Result<Vec<u8>, SyntheticError> {
    let (buffer, colour) = match (frame.samples(), frame.channels()) {
        (Samples::Eight(v), 1) => (v.clone(), ExtendedColorType::L8),
        (Samples::Eight(v), _) => (v.clone(), ExtendedColorType::Rgb8),
        // `image` takes 16-bit samples as native-endian bytes and stores them big-endian.
        (Samples::Sixteen(v), c) => (
            v.iter().flat_map(|s| s.to_ne_bytes()).collect(),
            if c == 1 {
                ExtendedColorType::L16
            } else {
                ExtendedColorType::Rgb16
            },
        ),
    };
    let mut bytes = Vec::new();
    let mut encoder = image::codecs::png::PngEncoder::new(&mut bytes);
    encoder
        .set_exif_metadata(exif_block(fields)?)
        .map_err(|e| encode_error("PNG", image::ImageError::Unsupported(e)))?;
    encoder
        .write_image(&buffer, frame.width(), frame.height(), colour)
        .map_err(|e| encode_error("PNG", e))?;
    Ok(bytes)
}

/// An uncompressed, chunky (interleaved), little-endian baseline TIFF with EXIF.
fn encode_tiff(frame: &Frame, mut fields: Vec<Field>) -> Result<Vec<u8>, SyntheticError> {
    let (pixels, bits): (Vec<u8>, u16) = match frame.samples() {
        Samples::Eight(v) => (v.clone(), 8),
        Samples::Sixteen(v) => (v.iter().flat_map(|s| s.to_le_bytes()).collect(), 16),
    };
    let channels = frame.channels();
    let row_bytes = (frame.width() as usize * channels * usize::from(bits / 8)).max(1);
    // Strips of about 64 KiB, as TIFF 6.0 recommends (8 KiB) within reason for big frames.
    let rows_per_strip = (65_536 / row_bytes).max(1);
    let strips: Vec<&[u8]> = pixels.chunks(rows_per_strip * row_bytes).collect();
    let primary = |tag, value| Field {
        tag,
        ifd_num: In::PRIMARY,
        value,
    };
    let short = |v: u16| Value::Short(vec![v]);
    let resolution = || Value::Rational(vec![Rational { num: 72, denom: 1 }]);
    fields.extend([
        primary(Tag::ImageWidth, Value::Long(vec![frame.width()])),
        primary(Tag::ImageLength, Value::Long(vec![frame.height()])),
        primary(Tag::BitsPerSample, Value::Short(vec![bits; channels])),
        primary(Tag::Compression, short(1)),
        // 2 = RGB, 1 = grey with 0 as black.
        primary(
            Tag::PhotometricInterpretation,
            short(if channels == 3 { 2 } else { 1 }),
        ),
        primary(Tag::SamplesPerPixel, short(channels as u16)),
        primary(
            Tag::RowsPerStrip,
            Value::Long(vec![u32::try_from(rows_per_strip).unwrap_or(u32::MAX)]),
        ),
        primary(Tag::PlanarConfiguration, short(1)),
        primary(Tag::XResolution, resolution()),
        primary(Tag::YResolution, resolution()),
        primary(Tag::ResolutionUnit, short(2)),
    ]);
    let mut writer = Writer::new();
    for field in &fields {
        writer.push_field(field);
    }
    if !strips.is_empty() {
        writer.set_strips(&strips, In::PRIMARY);
    }
    let mut bytes = Cursor::new(Vec::new());
    writer
        .write(&mut bytes, true)
        .map_err(|e| encode_error("TIFF", e))?;
    Ok(bytes.into_inner())
}

/// The EXIF fields describing `shot` (see [`encode`]).
fn exif_fields(shot: &Shot) -> Result<Vec<Field>, SyntheticError> {
    let field = |tag, value| Field {
        tag,
        ifd_num: In::PRIMARY,
        value,
    };
    let ascii = |text: &str| Value::Ascii(vec![text.as_bytes().to_vec()]);
    let mut fields = vec![
        field(Tag::Orientation, Value::Short(vec![1])),
        field(Tag::ExifVersion, Value::Undefined(b"0232".to_vec(), 0)),
    ];
    let camera = &shot.camera;
    for (tag, text) in [
        (Tag::Make, &camera.make),
        (Tag::Model, &camera.model),
        (Tag::BodySerialNumber, &camera.serial),
    ] {
        if let Some(text) = text {
            fields.push(field(tag, ascii(text)));
        }
    }
    let exposure = &shot.exposure;
    if let Some(time) = exposure.time_s {
        fields.push(field(
            Tag::ExposureTime,
            Value::Rational(vec![rational(time, "exposure time")?]),
        ));
    }
    if let Some(n) = exposure.f_number {
        fields.push(field(
            Tag::FNumber,
            Value::Rational(vec![rational(n, "f-number")?]),
        ));
    }
    if let Some(iso) = exposure.iso {
        if !(iso.is_finite() && iso >= 0.0 && iso <= f64::from(u32::MAX)) {
            return Err(encode_error("EXIF", EncodeError::Iso(iso)));
        }
        let iso = iso.round();
        if iso <= 65_534.0 {
            fields.push(field(
                Tag::PhotographicSensitivity,
                Value::Short(vec![iso as u16]),
            ));
        } else {
            fields.push(field(
                Tag::PhotographicSensitivity,
                Value::Short(vec![65_535]),
            ));
            // 2 = PhotographicSensitivity reports the recommended exposure index.
            fields.push(field(Tag::SensitivityType, Value::Short(vec![2])));
            fields.push(field(
                Tag::RecommendedExposureIndex,
                Value::Long(vec![iso as u32]),
            ));
        }
    }
    let t = &shot.captured_at;
    fields.push(field(Tag::DateTimeOriginal, ascii(&exif_date_time(t))));
    if let Some(nanos) = t.nanos {
        let digits = format!("{nanos:09}");
        let digits = digits.trim_end_matches('0');
        fields.push(field(
            Tag::SubSecTimeOriginal,
            ascii(if digits.is_empty() { "0" } else { digits }),
        ));
    }
    if let Some(offset) = t.offset_minutes {
        let sign = if offset < 0 { '-' } else { '+' };
        let a = offset.unsigned_abs();
        fields.push(field(
            Tag::OffsetTimeOriginal,
            ascii(&format!("{sign}{:02}:{:02}", a / 60, a % 60)),
        ));
    }
    Ok(fields)
}

/// EXIF date-time text `YYYY:MM:DD HH:MM:SS`.
fn exif_date_time(t: &CaptureTime) -> String {
    format!(
        "{:04}:{:02}:{:02} {:02}:{:02}:{:02}",
        t.year, t.month, t.day, t.hour, t.minute, t.second
    )
}

/// The closest fraction `p/q` with `p, q < 2³²` to a non-negative `value`, by continued
/// fractions: exact for `1/125`, `2.8 = 14/5`, `30`; within 10⁻¹² relative otherwise.
fn rational(value: f64, what: &str) -> Result<Rational, SyntheticError> {
    if !(value.is_finite() && value >= 0.0 && value <= f64::from(u32::MAX)) {
        return Err(encode_error(
            "EXIF",
            EncodeError::Rational {
                what: what.to_string(),
                value,
            },
        ));
    }
    // Convergents h/k, starting from h₋₂/k₋₂ = 0/1 and h₋₁/k₋₁ = 1/0.
    let (mut h0, mut h1, mut k0, mut k1) = (0_u64, 1_u64, 1_u64, 0_u64);
    let mut x = value;
    loop {
        let a = x.floor() as u64;
        let next = a
            .checked_mul(h1)
            .and_then(|v| v.checked_add(h0))
            .zip(a.checked_mul(k1).and_then(|v| v.checked_add(k0)));
        match next {
            Some((h, k)) if h <= u64::from(u32::MAX) && k <= u64::from(u32::MAX) => {
                (h0, h1, k0, k1) = (h1, h, k1, k);
            }
            _ => break,
        }
        let fraction = x - x.floor();
        if fraction < 1e-12 || (h1 as f64 / k1 as f64 - value).abs() <= 1e-12 * value {
            break;
        }
        x = fraction.recip();
    }
    Ok(Rational {
        num: h1 as u32,
        denom: k1 as u32,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rationals_are_exact_for_camera_values() {
        for (value, num, denom) in [
            (1.0 / 125.0, 1, 125),
            (1.0 / 8000.0, 1, 8000),
            (2.8, 14, 5),
            (30.0, 30, 1),
            (0.0, 0, 1),
            (0.3, 3, 10),
        ] {
            let r = rational(value, "test").unwrap();
            assert_eq!((r.num, r.denom), (num, denom), "{value}");
        }
        let r = rational(std::f64::consts::PI, "pi").unwrap();
        assert!((r.to_f64() - std::f64::consts::PI).abs() < 1e-12 * std::f64::consts::PI);
        assert!(rational(-1.0, "exposure time").is_err());
        assert!(rational(f64::NAN, "f-number").is_err());
    }
}
