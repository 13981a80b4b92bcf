//! The source frame's EXIF carried into every rendering, with `Software = filmback`.

use std::io::Cursor;

use exif::{Field, In, Tag, Value};

/// How a rendering's pixels are stored, which decides the EXIF tags it must carry.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Storage {
    /// Baseline JPEG (Y′CbCr).
    Jpeg,
    /// Uncompressed or losslessly compressed RGB samples (PNG, TIFF).
    Rgb,
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

#[cfg(test)]
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
    #[cfg(test)]
    pub(crate) fn from_metadata(metadata: &crate::metadata::Metadata) -> SourceExif {
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

    /// The carried fields and the rendering's own, those Exif 2.32 (CIPA DC-008 §4.6.8)
    /// requires of a `width × height` image stored as `storage`: `Software = filmback
    /// <version>`, ExifVersion 2.32, FlashpixVersion 1.0, ColorSpace sRGB (the embedded
    /// profile's), the pixel dimensions, 72 pixels per inch (no physical size is known),
    /// and for JPEG the Y′CbCr component order and centred chroma siting.
    pub(super) fn rendering_fields(&self, width: u32, height: u32, storage: Storage) -> Vec<Field> {
        let field = |tag: Tag, value: Value| Field {
            tag,
            ifd_num: In::PRIMARY,
            value,
        };
        let mut own = vec![
            ascii(
                Tag::Software,
                concat!("filmback ", env!("CARGO_PKG_VERSION")),
            ),
            field(Tag::ExifVersion, Value::Undefined(b"0232".to_vec(), 0)),
            field(Tag::FlashpixVersion, Value::Undefined(b"0100".to_vec(), 0)),
            field(Tag::ColorSpace, Value::Short(vec![1])),
            field(Tag::PixelXDimension, Value::Long(vec![width])),
            field(Tag::PixelYDimension, Value::Long(vec![height])),
            field(Tag::XResolution, Value::Rational(vec![(72, 1).into()])),
            field(Tag::YResolution, Value::Rational(vec![(72, 1).into()])),
            field(Tag::ResolutionUnit, Value::Short(vec![2])),
        ];
        if storage == Storage::Jpeg {
            own.push(field(
                Tag::ComponentsConfiguration,
                Value::Undefined(vec![1, 2, 3, 0], 0),
            ));
            own.push(field(Tag::YCbCrPositioning, Value::Short(vec![1])));
        }
        let mut fields: Vec<Field> = self
            .fields
            .iter()
            .filter(|f| own.iter().all(|o| o.tag != f.tag))
            .cloned()
            .collect();
        fields.extend(own);
        fields
    }

    /// A TIFF-structured EXIF block of [`SourceExif::rendering_fields`] (as embedded in
    /// JPEG APP1 after `Exif\0\0`, or in a PNG `eXIf` chunk).
    pub(super) fn tiff_block(
        &self,
        width: u32,
        height: u32,
        storage: Storage,
    ) -> Result<Vec<u8>, exif::Error> {
        let fields = self.rendering_fields(width, height, storage);
        let mut writer = exif::experimental::Writer::new();
        for f in &fields {
            writer.push_field(f);
        }
        let mut out = Cursor::new(Vec::new());
        writer.write(&mut out, false)?;
        Ok(out.into_inner())
    }
}
