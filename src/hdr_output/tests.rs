//! Round trips through the exr crate's reader, PIZ bit for bit, overflow and failures.

use super::*;
use exr::prelude::traits::*;
use std::io::Cursor;

fn ramp(width: u32, height: u32, top: f32) -> RadianceMap {
    let n = (width * height * 3) as usize;
    let pixels = (0..n).map(|i| top * i as f32 / (n - 1) as f32).collect();
    RadianceMap::new(width, height, 3, pixels).unwrap()
}

fn read_back(bytes: Vec<u8>) -> x::Image<x::Layer<x::AnyChannels<x::FlatSamples>>> {
    x::read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_buffered(Cursor::new(bytes))
        .unwrap()
}

fn channel(image: &x::Image<x::Layer<x::AnyChannels<x::FlatSamples>>>, name: &str) -> Vec<f32> {
    let c = image
        .layer_data
        .channel_data
        .list
        .iter()
        .find(|c| c.name == text(name))
        .unwrap();
    c.sample_data.values_as_f32().collect()
}

#[test]
fn half_round_trip_keeps_values_and_header() {
    let map = ramp(16, 8, 100.0);
    let provenance = Provenance {
        camera: Camera {
            make: Some("Canon".into()),
            model: Some("EOS 5D Mark II".into()),
            serial: Some("0123".into()),
            lens: None,
        },
        frames: vec![
            FrameRecord {
                name: "a.jpg".into(),
                exposure: Exposure {
                    time_s: Some(0.125),
                    f_number: Some(8.0),
                    iso: Some(100.0),
                },
                relative: 0.125 * 100.0 / 64.0,
            },
            FrameRecord {
                name: "b.jpg".into(),
                exposure: Exposure {
                    time_s: Some(1.0),
                    f_number: Some(8.0),
                    iso: Some(100.0),
                },
                relative: 100.0 / 64.0,
            },
        ],
        response: "sRGB".into(),
        weighting: "hat".into(),
        ..Provenance::default()
    };
    let conf = vec![0.5f32; 16 * 8];
    let mut bytes = Cursor::new(Vec::new());
    let w = encode_exr(
        &mut bytes,
        &map,
        Some(&conf),
        &provenance,
        ExrOptions::default(),
    )
    .unwrap();
    assert_eq!(w.scale, 1.0);
    assert!(w.warnings.is_empty());
    let image = read_back(bytes.into_inner());
    let r = channel(&image, "R");
    let c = channel(&image, "confidence.Y");
    assert_eq!(c, conf);
    for (i, v) in r.iter().enumerate() {
        let want = map.pixels()[i * 3];
        assert!((v - want).abs() <= want * 1e-3, "{v} vs {want}");
    }
    let attrs = &image.layer_data.attributes;
    assert_eq!(attrs.exposure, Some(1.0));
    assert_eq!(
        attrs.other.get(&text("cameraModel")),
        Some(&x::AttributeValue::Text(text("EOS 5D Mark II")))
    );
    assert_eq!(
        attrs.other.get(&text("filmbackExposureRatio")),
        Some(&x::AttributeValue::F64(8.0))
    );
    assert!(image.attributes.chromaticities.is_some());
}

/// Writes `map` (and `confidence`) as half PIZ through filmback's encoder, reads it
/// back with the exr crate's decoder and checks every sample bit for bit.
fn piz_round_trip(map: &RadianceMap, confidence: Option<&[f32]>) {
    let mut bytes = Cursor::new(Vec::new());
    encode_exr(
        &mut bytes,
        map,
        confidence,
        &Provenance::default(),
        ExrOptions::default(),
    )
    .unwrap();
    let image = read_back(bytes.into_inner());
    let names: &[&str] = if map.channels() == 3 {
        &["R", "G", "B"]
    } else {
        &["Y"]
    };
    for (c, name) in names.iter().enumerate() {
        let got = channel(&image, name);
        assert_eq!(got.len(), map.pixels().len() / map.channels());
        for (p, v) in got.iter().enumerate() {
            let want = f16::from_f32(map.pixels()[p * map.channels() + c]).to_f32();
            assert_eq!(
                v.to_bits(),
                want.to_bits(),
                "{name} pixel {p}: {v} vs {want}"
            );
        }
    }
    if let Some(conf) = confidence {
        let got = channel(&image, "confidence.Y");
        let want: Vec<f32> = conf.iter().map(|v| f16::from_f32(*v).to_f32()).collect();
        assert_eq!(got, want);
    }
}

/// A deterministic pseudo-random sequence in `[0, 1)` (xorshift).
fn noise(n: usize, mut state: u64) -> Vec<f32> {
    (0..n)
        .map(|_| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 40) as f32 / (1u64 << 24) as f32
        })
        .collect()
}

#[test]
fn piz_blocks_decode_bit_for_bit() {
    // A photographic-like map: smooth gradient plus noise, several blocks, a last
    // block of 5 lines, an odd width.
    let (w, h) = (123, 69);
    let n = noise(w * h * 3, 7);
    let pixels = (0..w * h * 3)
        .map(|i| (i / 3 % w) as f32 / w as f32 * 4.0 + 0.01 * n[i])
        .collect();
    let map = RadianceMap::new(w as u32, h as u32, 3, pixels).unwrap();
    let conf = noise(w * h, 11);
    piz_round_trip(&map, Some(&conf));

    // Over 2^15 distinct words in one block (the modulo-2^16 wavelet, including pairs
    // it offsets onto each other): values of either sign (the encoder takes any word),
    // magnitudes log-uniform over 2^-14..2^15.
    let (w, h) = (1500, 40);
    let pixels: Vec<f32> = noise(w * h * 3, 3)
        .iter()
        .enumerate()
        .map(|(i, u)| if i % 2 == 0 { 1.0 } else { -1.0 } * (u * 29.0 - 14.0).exp2())
        .collect();
    let first_block: std::collections::HashSet<u16> = pixels[..w * 32 * 3]
        .iter()
        .map(|v| f16::from_f32(*v).to_bits())
        .collect();
    assert!(first_block.len() > 1 << 15, "{}", first_block.len());
    piz_round_trip(
        &RadianceMap::new(w as u32, h as u32, 3, pixels).unwrap(),
        None,
    );
}

#[test]
fn piz_handles_flat_tiny_and_odd_shaped_maps() {
    // All zeros (nothing in the bitmap), one value everywhere (runs longer than 255),
    // 1×1 (stored raw: PIZ cannot shrink 6 bytes), one column, one line, grey.
    for (w, h, c, value) in [
        (300, 40, 3, 0.0),
        (300, 40, 3, 0.75),
        (1, 1, 3, 2.5),
        (1, 70, 3, 1.0),
        (517, 1, 3, 3.0),
        (33, 65, 1, 0.5),
    ] {
        let n = w * h * c;
        let ramp = noise(n, 5);
        // Flat, or flat with a sparse ramp so blocks mix runs and changes.
        let pixels = (0..n)
            .map(|i| {
                if value == 0.0 || i % 97 != 0 {
                    value
                } else {
                    ramp[i]
                }
            })
            .collect();
        let map = RadianceMap::new(w as u32, h as u32, c, pixels).unwrap();
        piz_round_trip(&map, None);
    }
}

#[test]
fn half_overflow_is_scaled_or_clamped_with_a_warning() {
    let map = ramp(8, 4, 200_000.0);
    let mut bytes = Cursor::new(Vec::new());
    let w = encode_exr(
        &mut bytes,
        &map,
        None,
        &Provenance::default(),
        ExrOptions::default(),
    )
    .unwrap();
    assert_eq!(w.scale, 0.25);
    assert_eq!(w.warnings.len(), 1);
    let g = channel(&read_back(bytes.into_inner()), "G");
    assert!(g.iter().all(|v| v.is_finite()));
    let top = g.iter().copied().fold(0.0, f32::max);
    assert!(top > 40_000.0 && top <= HALF_MAX, "{top}");

    let clamp = ExrOptions {
        overflow: Overflow::Clamp,
        ..ExrOptions::default()
    };
    let mut bytes = Cursor::new(Vec::new());
    let w = encode_exr(&mut bytes, &map, None, &Provenance::default(), clamp).unwrap();
    assert_eq!(w.scale, 1.0);
    assert!(w.warnings[0].contains("clamped"), "{:?}", w.warnings);
    let b = channel(&read_back(bytes.into_inner()), "B");
    assert!(b.iter().all(|v| v.is_finite()));
    assert_eq!(b.iter().copied().fold(0.0, f32::max), HALF_MAX);

    let float = ExrOptions {
        sample: SampleFormat::Float,
        compression: ExrCompression::Zip,
        ..ExrOptions::default()
    };
    let mut bytes = Cursor::new(Vec::new());
    let w = encode_exr(&mut bytes, &map, None, &Provenance::default(), float).unwrap();
    assert!(w.warnings.is_empty());
    let b = channel(&read_back(bytes.into_inner()), "B");
    assert_eq!(b[b.len() - 1], 200_000.0);
}

/// `n` 8-bit RGB frames of 37 × 45 pixels (45 lines: a PIZ block of 32 lines and one of
/// 13) one stop apart, of a scene spanning 22 stops through a gamma 2.2 response, with
/// pseudo-random noise of ±1 code; relative exposures `1, 2, 4, …`.
fn bracket_frames(n: usize) -> Vec<(crate::frame::Frame, f64)> {
    use crate::frame::{Frame, Samples};
    let (width, height) = (37u32, 45u32);
    let samples = (width * height * 3) as usize;
    let jitter = noise(samples * n, 7);
    (0..n)
        .map(|k| {
            let e = 2f32.powi(k as i32);
            let codes = (0..samples)
                .map(|i| {
                    let r = 2f32.powf(22.0 * i as f32 / samples as f32 - 15.0);
                    let level = 255.0 * (r * e).min(1.0).powf(1.0 / 2.2);
                    (level + 2.0 * jitter[k * samples + i] - 1.0)
                        .round()
                        .clamp(0.0, 255.0) as u8
                })
                .collect();
            (
                Frame::new(width, height, 3, Samples::Eight(codes)).unwrap(),
                f64::from(e),
            )
        })
        .collect()
}

#[test]
fn a_bracket_merged_in_bands_writes_the_merged_maps_file() {
    use crate::merge::{self, BracketFrame, BracketMerge, MergeOptions};
    let camera = Camera::default();
    let g = crate::response::InverseResponse::srgb(3, 1024);
    for n in [3, 5] {
        let frames = bracket_frames(n);
        let bracket: Vec<BracketFrame<'_>> = frames
            .iter()
            .map(|(frame, exposure)| BracketFrame {
                source: Path::new("frame.jpg"),
                frame,
                exposure: *exposure,
                camera: &camera,
            })
            .collect();
        // 1: the relative scale; 20 000: a luminance scale beyond half's range, scaled
        // down by a power of two after the exact maximum.
        for factor in [1.0f32, 20_000.0] {
            let mut map = merge::merge(&bracket, &g, MergeOptions::default())
                .unwrap()
                .radiance;
            map.pixels_mut().iter_mut().for_each(|v| *v *= factor);
            let mut banded = BracketMerge::new(&bracket, &g, Default::default()).unwrap();
            banded.scale_by(factor);
            let options = [
                ExrOptions::default(),
                ExrOptions {
                    compression: ExrCompression::Zip,
                    ..ExrOptions::default()
                },
                ExrOptions {
                    sample: SampleFormat::Float,
                    ..ExrOptions::default()
                },
            ];
            for options in options {
                let case = format!("{n} frames, factor {factor}, {options:?}");
                let encode = |source: &dyn RadianceSource| {
                    let mut bytes = Cursor::new(Vec::new());
                    let written =
                        encode_exr(&mut bytes, source, None, &Provenance::default(), options)
                            .unwrap();
                    (bytes.into_inner(), written)
                };
                let (want, want_written) = encode(&map);
                let (got, got_written) = encode(&banded);
                assert_eq!(got_written, want_written, "{case}");
                let scaled = factor > 1.0 && options.sample == SampleFormat::Half;
                assert_eq!(scaled, got_written.scale < 1.0, "{case}");
                // The file holds the map, to half's rounding.
                let image = read_back(got);
                for (c, name) in ["R", "G", "B"].iter().enumerate() {
                    for (p, v) in channel(&image, name).iter().enumerate() {
                        let exact = map.pixels()[p * 3 + c] * got_written.scale;
                        let tolerance = match options.sample {
                            SampleFormat::Half => exact.abs() * 2f32.powi(-11) + 6e-8,
                            SampleFormat::Float => 0.0,
                        };
                        assert!(
                            (v - exact).abs() <= tolerance,
                            "{case} {name}{p}: {v} {exact}"
                        );
                    }
                }
                // The map's own file holds the same samples, bit for bit (the bytes
                // differ only in the order of the header's attributes).
                let of_map = read_back(want);
                for name in ["R", "G", "B"] {
                    let bits = |image| -> Vec<u32> {
                        channel(image, name).iter().map(|v| v.to_bits()).collect()
                    };
                    assert_eq!(bits(&image), bits(&of_map), "{case} {name}");
                }
            }
        }
    }
}

#[test]
fn grey_maps_write_one_channel_and_hdr_encodes() {
    let map = RadianceMap::new(4, 2, 1, vec![0.0, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0]).unwrap();
    let mut bytes = Cursor::new(Vec::new());
    encode_exr(
        &mut bytes,
        &map,
        None,
        &Provenance::default(),
        ExrOptions::default(),
    )
    .unwrap();
    assert_eq!(channel(&read_back(bytes.into_inner()), "Y"), map.pixels());
    let mut hdr = Vec::new();
    encode_radiance_hdr(&mut hdr, &map).unwrap();
    assert!(hdr.starts_with(b"#?RADIANCE"));
}

/// A disk that fills up after `capacity` bytes.
struct FullDisk {
    bytes: Vec<u8>,
    position: usize,
    capacity: usize,
}

impl Write for FullDisk {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        if self.position + buf.len() > self.capacity {
            return Err(std::io::Error::new(
                std::io::ErrorKind::StorageFull,
                "No space left on device",
            ));
        }
        let end = self.position + buf.len();
        if self.bytes.len() < end {
            self.bytes.resize(end, 0);
        }
        self.bytes[self.position..end].copy_from_slice(buf);
        self.position = end;
        Ok(buf.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl Seek for FullDisk {
    fn seek(&mut self, to: std::io::SeekFrom) -> std::io::Result<u64> {
        let mut cursor = Cursor::new(&self.bytes);
        cursor.set_position(self.position as u64);
        self.position = cursor.seek(to)? as usize;
        Ok(self.position as u64)
    }
}

#[test]
fn a_full_disk_is_an_error_not_a_panic() {
    let map = ramp(64, 64, 10.0);
    let disk = FullDisk {
        bytes: Vec::new(),
        position: 0,
        capacity: 4096,
    };
    let err = encode_exr(
        disk,
        &map,
        None,
        &Provenance::default(),
        ExrOptions::default(),
    )
    .unwrap_err();
    assert!(err.to_string().contains("No space left"), "{err}");
}

#[test]
fn failures_leave_no_file_behind() {
    let dir = tempfile::tempdir().unwrap();
    let map = ramp(8, 8, 1.0);
    let missing = dir.path().join("no-such-folder").join("x.exr");
    let err = write_exr(
        &missing,
        Overwrite::Refuse,
        &map,
        None,
        &Provenance::default(),
        ExrOptions::default(),
    )
    .unwrap_err();
    assert!(err.to_string().contains("x.exr"), "{err}");
    // An encoder failure inside the atomic publish (confidence of the wrong size).
    let path = dir.path().join("y.exr");
    let err = write_exr(
        &path,
        Overwrite::Refuse,
        &map,
        Some(&[1.0]),
        &Provenance::default(),
        ExrOptions::default(),
    )
    .unwrap_err();
    assert!(err.to_string().contains("y.exr"), "{err}");
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    write_exr(
        &path,
        Overwrite::Refuse,
        &map,
        None,
        &Provenance::default(),
        ExrOptions::default(),
    )
    .unwrap();
    let again = write_exr(
        &path,
        Overwrite::Refuse,
        &map,
        None,
        &Provenance::default(),
        ExrOptions::default(),
    );
    assert!(matches!(
        again,
        Err(OutputError::Publish(PublishError::Exists { .. }))
    ));
    let hdr = dir.path().join("y.hdr");
    write_radiance_hdr(&hdr, Overwrite::Refuse, &map).unwrap();
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 2);
}

/// Rec. 709 → ACES: a grey stays grey (the adaptation maps D65 to the ACES white), and
/// Rec. 709 red lands on its published AP0 and AP1 values (the first column of the
/// Bradford-adapted Rec. 709 → ACES2065-1 and → ACEScg matrices, as OpenColorIO's ACES
/// configuration and colour-science list them).
#[test]
fn aces_primaries_keep_grey_and_place_red() {
    for p in [Primaries::Rec709, Primaries::Ap0, Primaries::Ap1] {
        let m = p.matrix_from_709();
        for row in m {
            let grey: f64 = row.iter().sum();
            assert!((grey - 1.0).abs() < 1e-6, "{p:?}: grey row sums to {grey}");
        }
    }
    let red = |p: Primaries| p.matrix_from_709().map(|row| row[0]);
    let ap0 = red(Primaries::Ap0);
    let ap1 = red(Primaries::Ap1);
    for (got, want) in ap0.iter().zip([0.439_701, 0.089_792_3, 0.017_544]) {
        assert!((got - want).abs() < 1e-3, "AP0 {ap0:?}");
    }
    for (got, want) in ap1.iter().zip([0.613_097, 0.070_194, 0.020_615]) {
        assert!((got - want).abs() < 1e-3, "AP1 {ap1:?}");
    }
    assert_eq!(Primaries::Rec709.matrix_from_709()[0], [1.0, 0.0, 0.0]);
}

/// `acesImageContainerFlag = 1` exactly when the file is an ACES container (AP0, half,
/// uncompressed, RGB only): not for PIZ, float, AP1 or with a confidence channel.
#[test]
fn only_an_aces_container_says_it_is_one() {
    use exr::prelude::{AttributeValue, Text};
    let map = RadianceMap::new(2, 1, 3, vec![0.5, 0.5, 0.5, 1.0, 0.0, 0.0]).unwrap();
    let container = ExrOptions {
        primaries: Primaries::Ap0,
        compression: ExrCompression::None,
        ..ExrOptions::default()
    };
    let flag = |options: ExrOptions, confidence: Option<&[f32]>| {
        let mut bytes = std::io::Cursor::new(Vec::new());
        encode_exr(
            &mut bytes,
            &map,
            confidence,
            &Provenance::default(),
            options,
        )
        .unwrap();
        let meta = exr::meta::MetaData::read_from_buffered(
            std::io::Cursor::new(bytes.into_inner()),
            false,
        )
        .unwrap();
        meta.headers[0]
            .own_attributes
            .other
            .get(&Text::from("acesImageContainerFlag"))
            .cloned()
    };
    assert_eq!(flag(container, None), Some(AttributeValue::I32(1)));
    let piz = ExrOptions {
        compression: ExrCompression::Piz,
        ..container
    };
    let float = ExrOptions {
        sample: SampleFormat::Float,
        ..container
    };
    let ap1 = ExrOptions {
        primaries: Primaries::Ap1,
        ..container
    };
    for options in [piz, float, ap1] {
        assert_eq!(flag(options, None), None, "{options:?}");
    }
    assert_eq!(flag(container, Some(&[1.0, 0.5])), None, "with confidence");
}

/// An AP1 file holds the converted values and says so: `chromaticities` are AP1's with
/// the ACES white and `colorInteropID` is `lin_ap1_scene`; a grey pixel keeps its value.
#[test]
fn an_ap1_file_states_its_primaries() {
    use exr::prelude::{AttributeValue, Text};
    let map = RadianceMap::new(2, 1, 3, vec![0.5, 0.5, 0.5, 1.0, 0.0, 0.0]).unwrap();
    let mut bytes = std::io::Cursor::new(Vec::new());
    let options = ExrOptions {
        sample: SampleFormat::Float,
        primaries: Primaries::Ap1,
        ..ExrOptions::default()
    };
    encode_exr(&mut bytes, &map, None, &Provenance::default(), options).unwrap();
    let image = exr::prelude::read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_buffered(std::io::Cursor::new(bytes.into_inner()))
        .unwrap();
    let c = image.attributes.chromaticities.unwrap();
    assert_eq!((c.red.0, c.green.1, c.white.0), (0.713, 0.830, 0.32168));
    assert_eq!(
        image
            .layer_data
            .attributes
            .other
            .get(&Text::from("colorInteropID")),
        Some(&AttributeValue::Text(Text::from("lin_ap1_scene")))
    );
    let value = |name: &str, i: usize| -> f32 {
        image
            .layer_data
            .channel_data
            .list
            .iter()
            .find(|ch| ch.name == text(name))
            .unwrap()
            .sample_data
            .values_as_f32()
            .nth(i)
            .unwrap()
    };
    for ch in ["R", "G", "B"] {
        assert!((value(ch, 0) - 0.5).abs() < 1e-6, "{ch}");
    }
    assert!((value("R", 1) - 0.613_097).abs() < 1e-3);
    assert!((value("B", 1) - 0.020_615).abs() < 1e-3);
}

#[test]
fn a_maps_maximum_and_lines_are_its_samples() {
    // 37 × 45 × 3 samples: stretches of 16 with a remainder; non-finite values ignored.
    let n = 37 * 45 * 3;
    let mut pixels: Vec<f32> = (0..n)
        .map(|i| ((i * 7919) % 1013) as f32 / 10.0 - 20.0)
        .collect();
    pixels[5] = f32::NAN;
    pixels[300] = f32::INFINITY;
    pixels[301] = f32::NEG_INFINITY;
    let plain = |p: &[f32]| {
        p.iter()
            .copied()
            .filter(|v| v.is_finite())
            .fold(0.0, f32::max)
    };
    for at in [0, 17, n - 1] {
        let mut p = pixels.clone();
        p[at] = 1e6 + at as f32;
        let map = RadianceMap::new(37, 45, 3, p.clone()).unwrap();
        assert_eq!(map.max_value(), plain(&p), "largest at {at}");
        assert_eq!(map.max_value(), 1e6 + at as f32);
    }
    let negative = RadianceMap::new(37, 45, 3, vec![-1.0; n]).unwrap();
    assert_eq!(negative.max_value(), 0.0);

    let map = RadianceMap::new(37, 45, 3, pixels.clone()).unwrap();
    let mut line = vec![0f32; 30];
    for channel in 0..3 {
        map.line(37 * 2 + 5, channel, &mut line);
        for (k, v) in line.iter().enumerate() {
            assert_eq!(v.to_bits(), map.sample(37 * 2 + 5 + k, channel).to_bits());
        }
    }
    let grey = RadianceMap::new(37, 45, 1, pixels[..37 * 45].to_vec()).unwrap();
    grey.line(40, 0, &mut line);
    assert_eq!(line, pixels[40..70]);
}

/// Everything the header can say: camera, capture time, four frames, a luminance scale
/// (so twelve attributes of filmback's own beside the standard ones).
fn full_provenance() -> Provenance {
    let frame = |k: i32| FrameRecord {
        name: format!("IMG_{k:04}.JPG"),
        exposure: Exposure {
            time_s: Some(2f64.powi(k - 3)),
            f_number: Some(8.0),
            iso: Some(100.0),
        },
        relative: 2f64.powi(k - 3) * 100.0 / 64.0,
    };
    Provenance {
        camera: Camera {
            make: Some("Canon".into()),
            model: Some("EOS 5D Mark II".into()),
            serial: Some("0123".into()),
            lens: Some("EF 24-70mm f/2.8L".into()),
        },
        captured_at: Some(crate::metadata::CaptureTime {
            year: 2026,
            month: 11,
            day: 25,
            hour: 9,
            minute: 30,
            second: 5,
            nanos: None,
            offset_minutes: Some(60),
        }),
        frames: (0..4).map(frame).collect(),
        response: "fitted polynomial, degree 5".into(),
        weighting: "hat".into(),
        clipped: (12, 3),
        scale: crate::merge::Scale::Luminance { calibration: 1.0 },
        deghost: None,
        alignment: Some("mode auto; reference frame 1".into()),
    }
}

#[test]
fn the_same_map_gives_the_same_bytes() {
    let map = ramp(40, 37, 3000.0);
    let conf = noise(40 * 37, 3);
    let provenance = full_provenance();
    // Filmback's PIZ encoder and the exr crate's compressors both.
    let options = [
        ExrOptions::default(),
        ExrOptions {
            sample: SampleFormat::Float,
            compression: ExrCompression::Zip,
            primaries: Primaries::Ap1,
            ..ExrOptions::default()
        },
    ];
    for options in options {
        let encode = || {
            let mut bytes = Cursor::new(Vec::new());
            encode_exr(&mut bytes, &map, Some(&conf), &provenance, options).unwrap();
            bytes.into_inner()
        };
        let first = encode();
        for _ in 0..3 {
            assert!(encode() == first, "{options:?}: two files differ");
        }
    }
}

/// The names of the attributes of a single-part OpenEXR file's header, in file order,
/// and the header's length (parsed here independently of `attribute_order`).
fn header_names(bytes: &[u8]) -> (Vec<String>, usize) {
    let mut at = 8;
    let mut names = Vec::new();
    let until_nul = |at: usize| at + bytes[at..].iter().position(|&b| b == 0).unwrap();
    while bytes[at] != 0 {
        let name_end = until_nul(at);
        names.push(String::from_utf8(bytes[at..name_end].to_vec()).unwrap());
        let type_end = until_nul(name_end + 1);
        let size = i32::from_le_bytes(bytes[type_end + 1..type_end + 5].try_into().unwrap());
        at = type_end + 5 + size as usize;
    }
    (names, at + 1)
}

#[test]
fn a_file_with_its_header_sorted_reads_as_the_crates_own() {
    // An image written by the exr crate alone, and the same through `SortedHeader`.
    let (width, height) = (23, 41);
    let values = noise(width * height, 11);
    let channels = x::AnyChannels::sort(SmallVec::from_vec(vec![
        x::AnyChannel::new("R", x::FlatSamples::F32(values.clone())),
        x::AnyChannel::new(
            "G",
            x::FlatSamples::F16(values.iter().map(|&v| f16::from_f32(v)).collect()),
        ),
    ]));
    let layer = x::Layer::new(
        (width, height),
        header::layer_attributes(&full_provenance(), 1.0, Primaries::Ap0),
        x::Encoding::SMALL_LOSSLESS,
        channels,
    );
    let image = x::Image::from_layer(layer);
    let mut plain = Cursor::new(Vec::new());
    image.write().to_buffered(&mut plain).unwrap();
    let mut sorted = attribute_order::SortedHeader::new(Cursor::new(Vec::new()));
    image.write().to_buffered(&mut sorted).unwrap();
    let (plain, sorted) = (plain.into_inner(), sorted.finish().unwrap().into_inner());

    assert_eq!(plain.len(), sorted.len());
    let (plain_names, plain_len) = header_names(&plain);
    let (sorted_names, sorted_len) = header_names(&sorted);
    assert_eq!(plain_len, sorted_len);
    assert!(sorted_names.is_sorted(), "{sorted_names:?}");
    let mut names = plain_names;
    names.sort();
    assert_eq!(names, sorted_names);
    assert!(names.iter().any(|n| n == "filmbackFrame3"));
    // Offset tables and blocks are untouched, and both files read as the same image.
    assert!(plain[plain_len..] == sorted[sorted_len..]);
    assert_eq!(read_back(plain), read_back(sorted));
}

/// An OpenEXR preamble (magic number, version 2 with `flags`) and `attributes` as
/// `(name, type, value)`, ended by the empty name.
fn raw_header(flags: u32, attributes: &[(&str, &str, &[u8])]) -> Vec<u8> {
    let mut bytes = vec![0x76, 0x2f, 0x31, 0x01];
    bytes.extend_from_slice(&(2 | flags).to_le_bytes());
    for (name, kind, value) in attributes {
        for text in [name, kind] {
            bytes.extend_from_slice(text.as_bytes());
            bytes.push(0);
        }
        bytes.extend_from_slice(&(value.len() as i32).to_le_bytes());
        bytes.extend_from_slice(value);
    }
    bytes.push(0);
    bytes
}

/// What `SortedHeader` says about `bytes` written one at a time, then flushed and finished.
fn sort_bytewise(bytes: &[u8]) -> std::io::Result<Vec<u8>> {
    use std::io::Write as _;
    let mut sorted = attribute_order::SortedHeader::new(Cursor::new(Vec::new()));
    for b in bytes {
        sorted.write_all(std::slice::from_ref(b))?;
    }
    sorted.flush()?;
    Ok(sorted.finish()?.into_inner())
}

#[test]
fn sorted_header_refuses_what_it_does_not_expect() {
    use std::io::{Seek as _, SeekFrom, Write as _};
    let int = 7i32.to_le_bytes();
    let refused = |bytes: &[u8], why: &str| {
        let err = sort_bytewise(bytes).unwrap_err();
        assert_eq!(err.kind(), std::io::ErrorKind::InvalidData, "{err}");
        assert!(err.to_string().contains(why), "{err} (wanted {why:?})");
    };
    let mut not_exr = raw_header(0, &[("b", "int", &int)]);
    not_exr[0] = b'P';
    refused(&not_exr, "magic number");
    refused(&raw_header(1 << 12, &[("b", "int", &int)]), "multi-part");
    let mut negative = raw_header(0, &[("b", "int", &int)]);
    negative[8 + 6..8 + 10].copy_from_slice(&(-4i32).to_le_bytes());
    refused(&negative, "size -4");
    refused(
        &raw_header(0, &[("a", "int", &int), ("a", "int", &int)]),
        "a appears twice",
    );
    // The exr crate reads neither (no required attributes), so nothing is written.
    refused(
        &raw_header(0, &[("b", "int", &int), ("a", "int", &int)]),
        "cannot read",
    );
    let whole = raw_header(0, &[("b", "int", &int)]);
    refused(&whole[..whole.len() - 1], "before the header was complete");
    let mut unfinished = attribute_order::SortedHeader::new(Cursor::new(Vec::new()));
    unfinished.write_all(&whole[..12]).unwrap();
    let err = unfinished.seek(SeekFrom::Start(0)).unwrap_err();
    assert!(err.to_string().contains("seek before the header"), "{err}");
    let err = unfinished.finish().unwrap_err();
    assert!(err.to_string().contains("ended inside the header"), "{err}");
}

#[test]
fn sorted_header_passes_a_real_header_written_bytewise_and_seeks_after_it() {
    use std::io::{Seek as _, SeekFrom, Write as _};
    let map = ramp(9, 5, 10.0);
    let mut bytes = Cursor::new(Vec::new());
    encode_exr(
        &mut bytes,
        &map,
        None,
        &full_provenance(),
        ExrOptions::default(),
    )
    .unwrap();
    let file = bytes.into_inner();
    // Already sorted: unchanged, whether written at once or a byte at a time.
    assert!(sort_bytewise(&file).unwrap() == file);
    let (_, header_len) = header_names(&file);
    let mut sorted = attribute_order::SortedHeader::new(Cursor::new(Vec::new()));
    sorted.write_all(&file[..header_len]).unwrap();
    sorted.write_all(b"abcd").unwrap();
    sorted.seek(SeekFrom::Start(header_len as u64 + 1)).unwrap();
    sorted.write_all(b"X").unwrap();
    let out = sorted.finish().unwrap().into_inner();
    assert_eq!(out[..header_len], file[..header_len]);
    assert_eq!(&out[header_len..], b"aXcd");
}
