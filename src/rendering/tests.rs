//! Encoders carry the profile and EXIF; the streamed JPEG matches the direct rendering.

use std::io::Cursor;

use exif::{In, Tag};

use super::encode::encode_film_jpeg;
use super::*;
use crate::metadata::Metadata;

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
        let decoded = image::load_from_memory(&bytes).unwrap_or_else(|e| panic!("{format:?}: {e}"));
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
        // What Exif 2.32 requires of every image (JPEG: the Y'CbCr tags as well).
        let mut required = vec![
            (Tag::ExifVersion, "2.32"),
            (Tag::FlashpixVersion, "1.0"),
            (Tag::ColorSpace, "sRGB"),
            (Tag::PixelXDimension, "32"),
            (Tag::PixelYDimension, "8"),
            (Tag::XResolution, "72"),
            (Tag::YResolution, "72"),
            (Tag::ResolutionUnit, "inch"),
        ];
        if let Format::Jpeg { .. } = format {
            required.push((Tag::ComponentsConfiguration, "YCbCr_"));
            required.push((Tag::YCbCrPositioning, "centered"));
        }
        for (tag, value) in required {
            assert_eq!(get(tag).as_deref(), Some(value), "{format:?} {tag}");
        }
        let icc_tag = b"ICC_PROFILE";
        let has_icc = match format {
            Format::Jpeg { .. } | Format::UltraHdr { .. } => {
                bytes.windows(icc_tag.len()).any(|w| w == icc_tag)
            }
            Format::Png8 | Format::Png16 => bytes.windows(4).any(|w| w == b"iCCP"),
            Format::Tiff16 => e
                .get_field(Tag(exif::Context::Tiff, 34675), In::PRIMARY)
                .is_some(),
        };
        assert!(has_icc, "{format:?} lacks the ICC profile");
        if let Format::Jpeg { .. } = format {
            // Exif's APP1 comes first after the JFIF header, before the profile's APP2.
            let at = |tag: &[u8]| bytes.windows(tag.len()).position(|w| w == tag);
            assert!(at(b"Exif\0\0") < at(icc_tag), "APP1 after APP2");
        }
    }
}

#[test]
fn streaming_jpeg_decodes_to_the_developed_image() {
    let catalogue = film::Catalogue::builtin().unwrap();
    let stock = catalogue.get("velvia50").unwrap();
    let map = crate::synthetic::scene(200, 150, 3);
    let emulsion = film::Emulsion::new(
        stock,
        1.0,
        film::scene_key(&map, Key::LogAverage),
        ColourMode::PerLayer,
    )
    .unwrap();
    let reference = emulsion.render(&map, Depth::Eight);
    let mut streamed = Vec::new();
    encode_film_jpeg(
        &emulsion.expose(&map),
        &emulsion,
        95,
        &exif(),
        &mut streamed,
    )
    .unwrap();
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
fn formats_parse() {
    assert_eq!(
        "jpeg:95".parse::<Format>().unwrap(),
        Format::Jpeg { quality: 95 }
    );
    assert_eq!("png16".parse::<Format>().unwrap(), Format::Png16);
    assert!("jpeg:0".parse::<Format>().is_err());
    assert!("gif".parse::<Format>().is_err());
    assert_eq!(
        "ultrahdr".parse::<Format>().unwrap(),
        Format::UltraHdr { quality: 92 }
    );
    assert_eq!(
        "ultrahdr:80".parse::<Format>().unwrap(),
        Format::UltraHdr { quality: 80 }
    );
    assert_eq!(Format::UltraHdr { quality: 80 }.extension(), "jpg");
    assert!("ultrahdr:101".parse::<Format>().is_err());
    assert!("ultrahdr:".parse::<Format>().is_err());
    // An HDR still needs the radiance map: an image alone is refused.
    let image = DisplayImage::new_8bit(2, 2, vec![0; 12]);
    let mut out = Vec::new();
    let refused = encode(
        &image,
        Format::UltraHdr { quality: 90 },
        &SourceExif::default(),
        &mut out,
    );
    assert!(refused.is_err() && out.is_empty());
}

#[test]
fn previews_are_the_srgb_rendering_shrunk_whatever_the_output() {
    let catalogue = film::Catalogue::builtin().unwrap();
    let map = crate::synthetic::scene(200, 150, 3);
    let velvia = Look::film(
        &catalogue,
        "velvia50",
        ColourMode::PerLayer,
        Key::LogAverage,
    )
    .unwrap();
    let linear = Look::Tonemap(crate::tonemap::Operator::parse("linear").unwrap());
    for look in [velvia, linear] {
        let reference = Shrink::new(200, 150, 64);
        reference.add_rows(0, &look.render(&map, Depth::Eight).unwrap().to_u8());
        let reference = reference.finish();
        for (format, space) in [
            (Format::Jpeg { quality: 90 }, ColourSpace::Srgb),
            (Format::Png8, ColourSpace::Srgb),
            (Format::Jpeg { quality: 90 }, ColourSpace::DisplayP3),
            (Format::Tiff16, ColourSpace::Rec2020),
        ] {
            let shrink = Shrink::new(200, 150, 64);
            encode_look_previewed(
                &map,
                &look,
                format,
                space,
                &exif(),
                &mut Vec::new(),
                Some(&shrink),
            )
            .unwrap();
            let preview = shrink.finish();
            // ⌈200/64⌉ = 4: 50 × 38 blocks.
            assert_eq!((preview.width, preview.height), (50, 38));
            let worst = preview
                .rgb
                .iter()
                .zip(&reference.rgb)
                .map(|(a, b)| a.abs_diff(*b))
                .max()
                .unwrap();
            assert!(
                worst <= 1,
                "{} {format:?} {space:?}: off by {worst}",
                look.name()
            );
        }
    }
}
