//! `filmback inspect` end to end, and every bad input of issue 2.
//!
//! Every fixture is generated here, in a temporary folder: images are encoded with the
//! `image` crate, EXIF blocks written with kamadak-exif's writer, and broken files crafted
//! byte by byte. No binary fixture is committed.

use std::io::Cursor;
use std::path::{Path, PathBuf};
use std::process::Command;

use exif::experimental::Writer;
use exif::{Field, In, Rational, Tag, Value};
use filmback::frame::{self, BitDepth, Compression, FrameError, Limits, Samples};
use image::codecs::jpeg::JpegEncoder;
use image::codecs::png::PngEncoder;
use image::{ExtendedColorType, ImageEncoder};
use serde_json::Value as Json;

use crate::common;
use common::filmback;

// ---------------------------------------------------------------------------------------
// Fixture builders
// ---------------------------------------------------------------------------------------

fn field(tag: Tag, value: Value) -> Field {
    Field {
        tag,
        ifd_num: In::PRIMARY,
        value,
    }
}

fn ascii(text: &str) -> Value {
    Value::Ascii(vec![text.as_bytes().to_vec()])
}

/// The EXIF of a known shot: Canon EOS R5 #031021001234, 1/250 s, f/5.6, ISO 400, taken
/// 2026-03-14 09:26:53.125 at UTC+02:00, with the given orientation.
fn shot_exif(orientation: u16) -> Vec<Field> {
    vec![
        field(Tag::Make, ascii("Canon")),
        field(Tag::Model, ascii("Canon EOS R5")),
        field(Tag::BodySerialNumber, ascii("031021001234")),
        field(
            Tag::ExposureTime,
            Value::Rational(vec![Rational { num: 1, denom: 250 }]),
        ),
        field(
            Tag::FNumber,
            Value::Rational(vec![Rational { num: 56, denom: 10 }]),
        ),
        field(Tag::PhotographicSensitivity, Value::Short(vec![400])),
        field(Tag::DateTimeOriginal, ascii("2026:03:14 09:26:53")),
        field(Tag::SubSecTimeOriginal, ascii("125")),
        field(Tag::OffsetTimeOriginal, ascii("+02:00")),
        field(Tag::Orientation, Value::Short(vec![orientation])),
    ]
}

/// A bare TIFF-structured EXIF block (what JPEG APP1 and PNG eXIf carry).
fn exif_block(fields: &[Field]) -> Vec<u8> {
    let mut writer = Writer::new();
    for f in fields {
        writer.push_field(f);
    }
    let mut out = Cursor::new(Vec::new());
    writer.write(&mut out, false).unwrap();
    out.into_inner()
}

/// Pixel layout of a test image.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Layout {
    channels: usize,
    depth: BitDepth,
}

const GREY8: Layout = Layout {
    channels: 1,
    depth: BitDepth::Eight,
};
const RGB8: Layout = Layout {
    channels: 3,
    depth: BitDepth::Eight,
};
const GREY16: Layout = Layout {
    channels: 1,
    depth: BitDepth::Sixteen,
};
const RGB16: Layout = Layout {
    channels: 3,
    depth: BitDepth::Sixteen,
};

/// A deterministic test pattern: every sample distinct enough to tell positions apart.
fn pattern(width: u32, height: u32, layout: Layout) -> Samples {
    let n = width as usize * height as usize * layout.channels;
    match layout.depth {
        BitDepth::Eight => Samples::Eight((0..n).map(|i| (i * 37 % 251) as u8).collect()),
        BitDepth::Sixteen => {
            Samples::Sixteen((0..n).map(|i| (i * 2_654_435 % 65_521) as u16).collect())
        }
    }
}

fn color_type(layout: Layout) -> ExtendedColorType {
    match (layout.channels, layout.depth) {
        (1, BitDepth::Eight) => ExtendedColorType::L8,
        (3, BitDepth::Eight) => ExtendedColorType::Rgb8,
        (1, BitDepth::Sixteen) => ExtendedColorType::L16,
        _ => ExtendedColorType::Rgb16,
    }
}

fn png_bytes(width: u32, height: u32, layout: Layout, samples: &Samples, exif: &[u8]) -> Vec<u8> {
    let raw: Vec<u8> = match samples {
        Samples::Eight(v) => v.clone(),
        // image's encoders take 16-bit samples in native byte order.
        Samples::Sixteen(v) => v.iter().flat_map(|s| s.to_ne_bytes()).collect(),
    };
    let mut out = Vec::new();
    let mut encoder = PngEncoder::new(&mut out);
    if !exif.is_empty() {
        encoder.set_exif_metadata(exif.to_vec()).unwrap();
    }
    encoder
        .write_image(&raw, width, height, color_type(layout))
        .unwrap();
    out
}

fn jpeg_bytes(width: u32, height: u32, layout: Layout, samples: &[u8], exif: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    let mut encoder = JpegEncoder::new_with_quality(&mut out, 95);
    if !exif.is_empty() {
        encoder.set_exif_metadata(exif.to_vec()).unwrap();
    }
    encoder
        .write_image(samples, width, height, color_type(layout))
        .unwrap();
    out
}

/// An uncompressed TIFF written entirely by kamadak-exif's writer: image tags plus `exif`
/// fields in IFD0, the pixels as one strip.
fn tiff_bytes(
    width: u32,
    height: u32,
    layout: Layout,
    samples: &Samples,
    exif: &[Field],
    little_endian: bool,
) -> Vec<u8> {
    let strip: Vec<u8> = match samples {
        Samples::Eight(v) => v.clone(),
        Samples::Sixteen(v) if little_endian => v.iter().flat_map(|s| s.to_le_bytes()).collect(),
        Samples::Sixteen(v) => v.iter().flat_map(|s| s.to_be_bytes()).collect(),
    };
    let bits = layout.depth.bits() as u16;
    let image_fields = [
        field(Tag::ImageWidth, Value::Long(vec![width])),
        field(Tag::ImageLength, Value::Long(vec![height])),
        field(
            Tag::BitsPerSample,
            Value::Short(vec![bits; layout.channels]),
        ),
        field(Tag::Compression, Value::Short(vec![1])),
        field(
            Tag::PhotometricInterpretation,
            Value::Short(vec![if layout.channels == 1 { 1 } else { 2 }]),
        ),
        field(
            Tag::SamplesPerPixel,
            Value::Short(vec![layout.channels as u16]),
        ),
        field(Tag::RowsPerStrip, Value::Long(vec![height])),
    ];
    let strips: [&[u8]; 1] = [&strip];
    let mut writer = Writer::new();
    for f in image_fields.iter().chain(exif) {
        writer.push_field(f);
    }
    writer.set_strips(&strips, In::PRIMARY);
    let mut out = Cursor::new(Vec::new());
    writer.write(&mut out, little_endian).unwrap();
    out.into_inner()
}

/// CRC-32 (ISO-HDLC) as PNG chunks need it.
fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &b in bytes {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0xEDB8_8320
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

fn png_chunk(out: &mut Vec<u8>, kind: &[u8; 4], data: &[u8]) {
    out.extend_from_slice(&(data.len() as u32).to_be_bytes());
    let start = out.len();
    out.extend_from_slice(kind);
    out.extend_from_slice(data);
    let crc = crc32(&out[start..]);
    out.extend_from_slice(&crc.to_be_bytes());
}

/// A well-formed PNG header declaring `width × height` RGB8, followed by a token IDAT.
fn png_header_only(width: u32, height: u32) -> Vec<u8> {
    let mut out = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut ihdr = Vec::new();
    ihdr.extend_from_slice(&width.to_be_bytes());
    ihdr.extend_from_slice(&height.to_be_bytes());
    ihdr.extend_from_slice(&[8, 2, 0, 0, 0]); // 8-bit RGB, deflate, no filter, no interlace
    png_chunk(&mut out, b"IHDR", &ihdr);
    png_chunk(
        &mut out,
        b"IDAT",
        &[0x78, 0x9c, 0x03, 0x00, 0x00, 0x00, 0x00, 0x01],
    );
    png_chunk(&mut out, b"IEND", &[]);
    out
}

/// A JPEG whose APP1 EXIF block is `tiff` verbatim (possibly broken on purpose).
fn jpeg_with_raw_exif(tiff: &[u8]) -> Vec<u8> {
    let img = jpeg_bytes(16, 16, GREY8, &[128; 256], &[]);
    let mut app1 = b"Exif\0\0".to_vec();
    app1.extend_from_slice(tiff);
    let mut out = vec![0xFF, 0xD8, 0xFF, 0xE1];
    out.extend_from_slice(&((app1.len() + 2) as u16).to_be_bytes());
    out.extend_from_slice(&app1);
    out.extend_from_slice(&img[2..]); // the encoder's stream after its SOI
    out
}

/// Little-endian TIFF/EXIF block builder for deliberately broken structures.
fn ifd_entry(out: &mut Vec<u8>, tag: u16, kind: u16, count: u32, value: u32) {
    out.extend_from_slice(&tag.to_le_bytes());
    out.extend_from_slice(&kind.to_le_bytes());
    out.extend_from_slice(&count.to_le_bytes());
    out.extend_from_slice(&value.to_le_bytes());
}

// ---------------------------------------------------------------------------------------
// Running the binary
// ---------------------------------------------------------------------------------------

struct Run {
    status: i32,
    json: Json,
    stderr: String,
}

fn inspect_json(files: &[&Path]) -> Run {
    let out = filmback()
        .arg("inspect")
        .arg("--json")
        .args(files)
        .output()
        .expect("run filmback");
    let stdout = String::from_utf8(out.stdout).unwrap();
    Run {
        status: out.status.code().expect("exit status, not a signal"),
        json: serde_json::from_str(&stdout).unwrap_or_else(|e| panic!("{e}: {stdout}")),
        stderr: String::from_utf8_lossy(&out.stderr).into_owned(),
    }
}

fn write(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, bytes).unwrap();
    path
}

/// A small valid PNG to surround bad files with.
fn good_png(dir: &Path, name: &str) -> PathBuf {
    write(dir, name, &png_bytes(8, 6, RGB8, &pattern(8, 6, RGB8), &[]))
}

/// Runs `inspect --json good bad good` and checks that the bad file alone failed, with an
/// error naming it and containing `reason`, and that both good files were still reported.
fn assert_bad_file(bad: &Path, reason: &str) -> String {
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = (good_png(dir.path(), "a.png"), good_png(dir.path(), "b.png"));
    let run = inspect_json(&[&a, bad, &b]);
    assert_eq!(run.status, 1, "exit status; stderr: {}", run.stderr);
    let reports = run.json.as_array().unwrap();
    assert_eq!(reports.len(), 3);
    for good in [&reports[0], &reports[2]] {
        assert!(good.get("error").is_none(), "{good}");
        assert_eq!(good["width"], 8);
    }
    let bad_report = &reports[1];
    assert_eq!(bad_report["path"], bad.display().to_string());
    let error = bad_report["error"].as_str().expect("an error string");
    assert!(
        error.contains(&bad.display().to_string()),
        "error does not name the file: {error}"
    );
    assert!(error.contains(reason), "expected {reason:?} in {error:?}");
    assert!(run.stderr.contains(error), "stderr: {}", run.stderr);
    error.to_string()
}

// ---------------------------------------------------------------------------------------
// inspect --json contract
// ---------------------------------------------------------------------------------------

#[test]
fn inspect_json_reports_a_synthetic_jpeg_with_known_exif() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (64, 48);
    let Samples::Eight(rgb) = pattern(w, h, RGB8) else {
        unreachable!()
    };
    let path = write(
        dir.path(),
        "shot.jpg",
        &jpeg_bytes(w, h, RGB8, &rgb, &exif_block(&shot_exif(1))),
    );
    let run = inspect_json(&[&path]);
    assert_eq!(run.status, 0, "{}", run.stderr);
    let relative = 0.004 * 400.0 / (5.6 * 5.6);
    let expected = serde_json::json!([{
        "path": path.display().to_string(),
        "width": 64,
        "height": 48,
        "bit_depth": 8,
        "channels": 3,
        "camera": { "make": "Canon", "model": "Canon EOS R5", "serial": "031021001234" },
        "exposure": { "time_s": 0.004, "f_number": 5.6, "iso": 400.0, "relative_exposure": relative },
        "captured_at": "2026-03-14T09:26:53.125+02:00",
        "warnings": [],
    }]);
    assert_eq!(run.json, expected);
}

#[test]
fn inspect_json_gives_null_for_unknowns_and_warns_by_tag() {
    let dir = tempfile::tempdir().unwrap();
    let fields = vec![
        field(Tag::Make, ascii("Canon")),
        field(
            Tag::ExposureTime,
            Value::Rational(vec![Rational { num: 0, denom: 1 }]),
        ),
        field(
            Tag::FNumber,
            Value::Rational(vec![Rational { num: 0, denom: 1 }]),
        ),
        field(Tag::PhotographicSensitivity, Value::Short(vec![0])),
        field(Tag::DateTimeOriginal, ascii("0000:00:00 00:00:00")),
    ];
    let samples = pattern(8, 6, RGB8);
    let path = write(
        dir.path(),
        "absurd.png",
        &png_bytes(8, 6, RGB8, &samples, &exif_block(&fields)),
    );
    let run = inspect_json(&[&path]);
    assert_eq!(run.status, 0, "{}", run.stderr);
    let r = &run.json[0];
    assert_eq!(r["camera"]["make"], "Canon");
    assert_eq!(r["camera"]["model"], Json::Null);
    for key in ["time_s", "f_number", "iso", "relative_exposure"] {
        assert_eq!(r["exposure"][key], Json::Null, "{key}");
    }
    assert_eq!(r["captured_at"], Json::Null);
    let warnings = r["warnings"].to_string();
    for tag in [
        "ExposureTime",
        "FNumber",
        "PhotographicSensitivity",
        "DateTimeOriginal",
    ] {
        assert!(warnings.contains(tag), "{tag} not in {warnings}");
    }
}

#[test]
fn inspect_table_names_every_file() {
    let dir = tempfile::tempdir().unwrap();
    let good = good_png(dir.path(), "good.png");
    let empty = write(dir.path(), "empty.jpg", b"");
    let out = filmback()
        .arg("inspect")
        .args([&good, &empty])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let stdout = String::from_utf8(out.stdout).unwrap();
    assert!(stdout.contains(&good.display().to_string()), "{stdout}");
    assert!(stdout.contains("8×6 8-bit 3ch"), "{stdout}");
    assert!(
        stdout.contains(&format!("error: {}: file is empty", empty.display())),
        "{stdout}"
    );
}

// ---------------------------------------------------------------------------------------
// Frames: native depth and orientation
// ---------------------------------------------------------------------------------------

#[test]
fn png_and_tiff_keep_8_and_16_bit_grey_and_rgb_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (13, 7);
    for layout in [GREY8, RGB8, GREY16, RGB16] {
        let samples = pattern(w, h, layout);
        let files = [
            ("png", png_bytes(w, h, layout, &samples, &[])),
            (
                "tif",
                tiff_bytes(w, h, layout, &samples, &shot_exif(1), true),
            ),
            (
                "tiff",
                tiff_bytes(w, h, layout, &samples, &shot_exif(1), false),
            ),
        ];
        for (ext, bytes) in files {
            let path = write(dir.path(), &format!("frame.{ext}"), &bytes);
            let loaded = frame::load(&path, Limits::default())
                .unwrap_or_else(|e| panic!("{layout:?} {ext}: {e}"));
            let f = &loaded.frame;
            assert_eq!((f.width(), f.height()), (w, h), "{layout:?} {ext}");
            assert_eq!(f.channels(), layout.channels, "{layout:?} {ext}");
            assert_eq!(f.bit_depth(), layout.depth, "{layout:?} {ext}");
            assert_eq!(f.samples(), &samples, "{layout:?} {ext}");
            assert_eq!(f.compression(), Compression::Lossless, "{layout:?} {ext}");
            let run = inspect_json(&[&path]);
            assert_eq!(run.json[0]["bit_depth"], layout.depth.bits());
            assert_eq!(run.json[0]["channels"], layout.channels);
        }
    }
    // The TIFF carries its EXIF in IFD0: exposure read from the same file.
    let path = dir.path().join("frame.tif");
    let meta = frame::load(&path, Limits::default()).unwrap().metadata;
    assert_eq!(meta.exposure.iso, Some(400.0));
}

#[test]
fn jpeg_keeps_8_bit_grey_and_rgb() {
    for layout in [GREY8, RGB8] {
        let Samples::Eight(raw) = pattern(32, 16, layout) else {
            unreachable!()
        };
        let bytes = jpeg_bytes(32, 16, layout, &raw, &[]);
        let f = frame::decode(Path::new("grey.jpg"), &bytes, Limits::default())
            .unwrap()
            .frame;
        assert_eq!(f.channels(), layout.channels);
        assert_eq!(f.bit_depth(), BitDepth::Eight);
        assert_eq!((f.width(), f.height()), (32, 16));
        assert_eq!(f.compression(), Compression::Lossy);
    }
}

/// Where the upright pixel `(x, y)` of a `w × h` picture is stored in a file with EXIF
/// orientation `o` (EXIF 2.32, tag 0x0112: which visual side row 0 and column 0 hold).
/// Returns the stored size and the stored position.
fn stored(o: u16, w: u32, h: u32, x: u32, y: u32) -> ((u32, u32), (u32, u32)) {
    let (r, b) = (w - 1 - x, h - 1 - y);
    match o {
        1 => ((w, h), (x, y)),
        2 => ((w, h), (r, y)),
        3 => ((w, h), (r, b)),
        4 => ((w, h), (x, b)),
        // Transposed sizes: stored row i is a visual column.
        5 => ((h, w), (y, x)), // row 0 = visual left, column 0 = visual top
        6 => ((h, w), (y, r)), // row 0 = visual right, column 0 = visual top
        7 => ((h, w), (b, r)), // row 0 = visual right, column 0 = visual bottom
        8 => ((h, w), (b, x)), // row 0 = visual left, column 0 = visual bottom
        _ => unreachable!(),
    }
}

/// Stores the upright `w × h` picture `upright` as it would be in a file with orientation `o`.
fn store(o: u16, w: u32, h: u32, channels: usize, upright: &[u16]) -> (u32, u32, Vec<u16>) {
    let ((sw, sh), _) = stored(o, w, h, 0, 0);
    let mut out = vec![0u16; upright.len()];
    for y in 0..h {
        for x in 0..w {
            let (_, (sx, sy)) = stored(o, w, h, x, y);
            for c in 0..channels {
                out[(sy * sw + sx) as usize * channels + c] =
                    upright[(y * w + x) as usize * channels + c];
            }
        }
    }
    (sw, sh, out)
}

#[test]
fn all_eight_orientations_load_to_the_same_upright_grid_png_and_tiff() {
    let (w, h) = (5, 3);
    for layout in [RGB8, GREY16] {
        let upright: Vec<u16> = match pattern(w, h, layout) {
            Samples::Eight(v) => v.into_iter().map(u16::from).collect(),
            Samples::Sixteen(v) => v,
        };
        let as_samples = |v: Vec<u16>| match layout.depth {
            BitDepth::Eight => Samples::Eight(v.into_iter().map(|s| s as u8).collect()),
            BitDepth::Sixteen => Samples::Sixteen(v),
        };
        for o in 1..=8 {
            let (sw, sh, raw) = store(o, w, h, layout.channels, &upright);
            let samples = as_samples(raw);
            let exif = shot_exif(o);
            let files = [
                (
                    "png",
                    png_bytes(sw, sh, layout, &samples, &exif_block(&exif)),
                ),
                (
                    "tif",
                    tiff_bytes(sw, sh, layout, &samples, &exif, o % 2 == 0),
                ),
            ];
            for (ext, bytes) in files {
                let name = format!("o{o}.{ext}");
                let loaded = frame::decode(Path::new(&name), &bytes, Limits::default()).unwrap();
                assert_eq!(loaded.metadata.orientation as u16, o, "{name}");
                let f = loaded.frame;
                assert_eq!((f.width(), f.height()), (w, h), "{name} {layout:?}");
                assert_eq!(
                    f.samples(),
                    &as_samples(upright.clone()),
                    "{name} {layout:?}"
                );
            }
        }
    }
}

#[test]
fn all_eight_orientations_load_to_the_same_upright_grid_jpeg() {
    // 16×16 flat blocks survive JPEG compression (even 4:2:0 chroma) nearly exactly.
    let (bw, bh, block) = (4u32, 2u32, 16u32);
    let (w, h) = (bw * block, bh * block);
    let level = |x: u32, y: u32| 20 + 30 * (y / block * bw + x / block) as u16;
    let upright: Vec<u16> = (0..h)
        .flat_map(|y| (0..w).map(move |x| level(x, y)))
        .collect();
    for o in 1..=8 {
        let (sw, sh, raw) = store(o, w, h, 1, &upright);
        let raw: Vec<u8> = raw.into_iter().map(|s| s as u8).collect();
        let bytes = jpeg_bytes(sw, sh, GREY8, &raw, &exif_block(&shot_exif(o)));
        let f = frame::decode(Path::new("o.jpg"), &bytes, Limits::default())
            .unwrap()
            .frame;
        assert_eq!((f.width(), f.height()), (w, h), "orientation {o}");
        for y in 0..h {
            for x in 0..w {
                let got = f.code(x, y, 0) as i32;
                let want = i32::from(level(x, y));
                assert!(
                    (got - want).abs() <= 3,
                    "orientation {o}: ({x},{y}) = {got}, want {want}"
                );
            }
        }
    }
}

// ---------------------------------------------------------------------------------------
// Bad input: each a clear error naming the file; the others still reported
// ---------------------------------------------------------------------------------------

#[test]
fn zero_byte_file() {
    let dir = tempfile::tempdir().unwrap();
    let bad = write(dir.path(), "empty.jpg", b"");
    assert_bad_file(&bad, "file is empty (0 bytes)");
}

#[test]
fn truncated_jpeg() {
    let dir = tempfile::tempdir().unwrap();
    let Samples::Eight(raw) = pattern(256, 192, RGB8) else {
        unreachable!()
    };
    let bytes = jpeg_bytes(256, 192, RGB8, &raw, &exif_block(&shot_exif(1)));
    // Inside the EXIF block, mid-scan, and just the end-of-image marker missing.
    for cut in [100, bytes.len() / 2, bytes.len() - 2] {
        let bad = write(dir.path(), &format!("cut{cut}.jpg"), &bytes[..cut]);
        assert_bad_file(&bad, "cannot decode JPEG");
    }
    let whole = write(dir.path(), "whole.jpg", &bytes);
    assert!(frame::load(&whole, Limits::default()).is_ok());
}

#[test]
fn truncated_png_and_tiff() {
    let dir = tempfile::tempdir().unwrap();
    let samples = pattern(64, 48, RGB16);
    let png = png_bytes(64, 48, RGB16, &samples, &[]);
    let tiff = tiff_bytes(64, 48, RGB16, &samples, &shot_exif(1), true);
    for (name, bytes, reason) in [
        ("cut.png", &png, "cannot decode PNG"),
        ("cut.tif", &tiff, "cannot decode TIFF"),
    ] {
        let bad = write(dir.path(), name, &bytes[..bytes.len() * 2 / 3]);
        assert_bad_file(&bad, reason);
    }
}

#[test]
fn zero_width_header() {
    let mut t = b"II*\0".to_vec();
    t.extend_from_slice(&8u32.to_le_bytes());
    let entries: [(u16, u16, u32, u32); 7] = [
        (256, 4, 1, 0),  // ImageWidth 0
        (257, 4, 1, 16), // ImageLength
        (258, 3, 1, 8),
        (259, 3, 1, 1),
        (262, 3, 1, 1),
        (273, 4, 1, 8),
        (279, 4, 1, 0),
    ];
    t.extend_from_slice(&(entries.len() as u16).to_le_bytes());
    for (tag, kind, count, value) in entries {
        ifd_entry(&mut t, tag, kind, count, value);
    }
    t.extend_from_slice(&0u32.to_le_bytes());
    let dir = tempfile::tempdir().unwrap();
    let bad = write(dir.path(), "empty-image.tif", &t);
    assert_bad_file(&bad, "cannot decode TIFF");
}

#[test]
fn png_renamed_jpg_loads_by_content_with_a_warning() {
    let dir = tempfile::tempdir().unwrap();
    let png = png_bytes(8, 6, RGB8, &pattern(8, 6, RGB8), &[]);
    let path = write(dir.path(), "really-a-png.jpg", &png);
    let run = inspect_json(&[&path]);
    assert_eq!(run.status, 0, "{}", run.stderr);
    let r = &run.json[0];
    assert_eq!(
        (r["width"].as_u64(), r["height"].as_u64()),
        (Some(8), Some(6))
    );
    let warnings = r["warnings"].to_string();
    assert!(
        warnings.contains("file extension .jpg does not match its content (PNG)"),
        "{warnings}"
    );
}

#[test]
fn text_file() {
    let dir = tempfile::tempdir().unwrap();
    let bad = write(dir.path(), "notes.txt", b"exposure notes: 1/250 at f/8\n");
    assert_bad_file(&bad, "not a JPEG, PNG or TIFF image");
    let bad = write(dir.path(), "notes.jpg", b"exposure notes: 1/250 at f/8\n");
    assert_bad_file(&bad, "not a JPEG, PNG or TIFF image");
}

#[test]
fn directory_passed_as_a_file() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("DCIM.jpg");
    std::fs::create_dir(&bad).unwrap();
    assert_bad_file(&bad, "is a directory");
}

#[cfg(unix)]
#[test]
fn fifo_is_refused_without_blocking() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("pipe.jpg");
    let made = Command::new("mkfifo").arg(&bad).status();
    if !made.is_ok_and(|s| s.success()) {
        println!("note: mkfifo unavailable: FIFO case skipped");
        return;
    }
    assert_bad_file(&bad, "not a regular file");
}

#[test]
fn file_larger_than_the_limits_is_not_read() {
    let dir = tempfile::tempdir().unwrap();
    let path = good_png(dir.path(), "big.png");
    let limits = Limits { max_pixels: 0 };
    // Grow the file (sparsely) just past 8·0 + 64 MiB.
    let file = std::fs::OpenOptions::new().write(true).open(&path).unwrap();
    file.set_len(limits.max_file_bytes() + 1).unwrap();
    let err = frame::load(&path, limits).unwrap_err();
    assert!(matches!(err, FrameError::FileTooLarge { .. }), "{err}");
    assert!(err.to_string().contains("big.png"), "{err}");
}

#[test]
fn missing_file() {
    let dir = tempfile::tempdir().unwrap();
    assert_bad_file(&dir.path().join("gone.jpg"), "cannot read");
}

#[test]
fn huge_png_header_is_refused_before_decoding() {
    let bytes = png_header_only(100_000, 100_000);
    let err = frame::decode(Path::new("huge.png"), &bytes, Limits::default()).unwrap_err();
    assert!(
        matches!(
            err,
            FrameError::TooLarge {
                width: 100_000,
                height: 100_000,
                ..
            }
        ),
        "{err}"
    );
    let dir = tempfile::tempdir().unwrap();
    let bad = write(dir.path(), "huge.png", &bytes);
    assert_bad_file(&bad, "image of 100000×100000 pixels exceeds the limit");
}

#[test]
fn huge_tiff_header_is_refused_before_decoding() {
    // IFD0 declaring 100000×100000 8-bit grey in one 16-byte strip.
    let mut t = b"II*\0".to_vec();
    t.extend_from_slice(&8u32.to_le_bytes());
    let entries: [(u16, u16, u32, u32); 8] = [
        (256, 4, 1, 100_000), // ImageWidth
        (257, 4, 1, 100_000), // ImageLength
        (258, 3, 1, 8),       // BitsPerSample
        (259, 3, 1, 1),       // Compression: none
        (262, 3, 1, 1),       // PhotometricInterpretation: BlackIsZero
        (273, 4, 1, 200),     // StripOffsets
        (278, 4, 1, 100_000), // RowsPerStrip
        (279, 4, 1, 16),      // StripByteCounts
    ];
    t.extend_from_slice(&(entries.len() as u16).to_le_bytes());
    for (tag, kind, count, value) in entries {
        ifd_entry(&mut t, tag, kind, count, value);
    }
    t.extend_from_slice(&0u32.to_le_bytes());
    t.resize(216, 0x80);
    let err = frame::decode(Path::new("huge.tif"), &t, Limits::default()).unwrap_err();
    assert!(matches!(err, FrameError::TooLarge { .. }), "{err}");
    let dir = tempfile::tempdir().unwrap();
    let bad = write(dir.path(), "huge.tif", &t);
    assert_bad_file(&bad, "exceeds the limit");
}

#[test]
fn exif_offsets_outside_the_file_are_warnings_not_failures() {
    // Pixels are fine, so the frame loads (exposures may still come from the caller);
    // the broken EXIF becomes unknown values and a warning in that file's report.
    let dir = tempfile::tempdir().unwrap();

    // 1. IFD0 itself points far past the end.
    let mut t = b"II*\0".to_vec();
    t.extend_from_slice(&0x7FFF_FFF0u32.to_le_bytes());
    let whole = write(dir.path(), "ifd0-outside.jpg", &jpeg_with_raw_exif(&t));

    // 2. A valid IFD0 whose Make string and Exif sub-IFD lie outside the block, plus a
    //    Model that is fine.
    let mut t = b"II*\0".to_vec();
    t.extend_from_slice(&8u32.to_le_bytes());
    t.extend_from_slice(&3u16.to_le_bytes());
    ifd_entry(&mut t, 0x010F, 2, 40, 0x00FF_FF00); // Make: 40 bytes at 16 MiB
    ifd_entry(&mut t, 0x0110, 2, 3, u32::from_le_bytes(*b"X1\0\0")); // Model "X1"
    ifd_entry(&mut t, 0x8769, 4, 1, 0xFFFF_FFF0); // ExifIFDPointer outside
    t.extend_from_slice(&0u32.to_le_bytes());
    let partial = write(dir.path(), "subifd-outside.jpg", &jpeg_with_raw_exif(&t));

    let run = inspect_json(&[&whole, &partial]);
    assert_eq!(run.status, 0, "{}", run.stderr);
    for r in run.json.as_array().unwrap() {
        assert_eq!(r["width"], 16, "{r}");
        assert_eq!(r["exposure"]["time_s"], Json::Null, "{r}");
        assert_eq!(r["camera"]["make"], Json::Null, "{r}");
        let warnings = r["warnings"].to_string();
        assert!(warnings.contains("EXIF"), "{warnings}");
        assert!(warnings.contains("unreadable"), "{warnings}");
    }
}

#[test]
fn size_limit_is_configurable() {
    let bytes = png_bytes(8, 6, RGB8, &pattern(8, 6, RGB8), &[]);
    let err = frame::decode(Path::new("a.png"), &bytes, Limits { max_pixels: 47 }).unwrap_err();
    assert!(
        matches!(err, FrameError::TooLarge { max_pixels: 47, .. }),
        "{err}"
    );
    assert!(frame::decode(Path::new("a.png"), &bytes, Limits { max_pixels: 48 }).is_ok());
}

// ---------------------------------------------------------------------------------------
// End to end with the synthetic renderer's writer
// ---------------------------------------------------------------------------------------

#[test]
fn inspect_json_reads_back_synthetic_frames_in_every_encoding() {
    use filmback::metadata::{Camera, CaptureTime, Exposure};
    use filmback::synthetic::{self, Encoding, ResponseCurve, Sensor, Shot};

    let dir = tempfile::tempdir().unwrap();
    let scene = synthetic::scene(48, 32, 7);
    // ISO 102400 is above 65534: written as 65535 plus RecommendedExposureIndex.
    let shot = Shot {
        camera: Camera {
            make: Some("Synthetic".into()),
            model: Some("Bracket One".into()),
            serial: Some("SN-0042".into()),
            lens: None,
        },
        exposure: Exposure {
            time_s: Some(1.0 / 8000.0),
            f_number: Some(16.0),
            iso: Some(102_400.0),
        },
        captured_at: CaptureTime {
            year: 2024,
            month: 2,
            day: 29,
            hour: 23,
            minute: 59,
            second: 59,
            nanos: Some(250_000_000),
            offset_minutes: Some(-330),
        },
    };
    let cases = [
        (Encoding::Jpeg { quality: 90 }, BitDepth::Eight, "shot.jpg"),
        (Encoding::Png, BitDepth::Sixteen, "shot.png"),
        (Encoding::Tiff, BitDepth::Sixteen, "shot.tif"),
    ];
    let mut paths = Vec::new();
    for (encoding, depth, name) in cases {
        let frame = synthetic::expose(&scene, 1.0, &Sensor::noiseless(ResponseCurve::Srgb, depth));
        let path = dir.path().join(name);
        synthetic::write(&path, &frame, &shot, encoding).unwrap();
        paths.push((path, depth));
    }
    let files: Vec<&Path> = paths.iter().map(|(p, _)| p.as_path()).collect();
    let run = inspect_json(&files);
    assert_eq!(run.status, 0, "{}", run.stderr);
    for ((path, depth), r) in paths.iter().zip(run.json.as_array().unwrap()) {
        let relative = (1.0 / 8000.0) * 102_400.0 / 256.0;
        let expected = serde_json::json!({
            "path": path.display().to_string(),
            "width": 48,
            "height": 32,
            "bit_depth": depth.bits(),
            "channels": 3,
            "camera": { "make": "Synthetic", "model": "Bracket One", "serial": "SN-0042" },
            "exposure": {
                "time_s": 1.0 / 8000.0,
                "f_number": 16.0,
                "iso": 102_400.0,
                "relative_exposure": relative,
            },
            "captured_at": "2024-02-29T23:59:59.25-05:30",
            "warnings": [],
        });
        assert_eq!(r, &expected, "{}", path.display());
    }
}

// ---------------------------------------------------------------------------------------
// A reader that goes away (`filmback … | head -1`)
// ---------------------------------------------------------------------------------------

#[test]
fn every_command_exits_quietly_when_its_reader_goes_away() {
    use std::process::Stdio;
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir_all(dir.path().join("state")).unwrap();
    let state = dir.path().join("state").display().to_string();
    for args in [
        vec!["check-config"],
        vec!["films"],
        vec!["status", "--state", &state],
        vec!["--help"],
    ] {
        let mut child = Command::new(env!("CARGO_BIN_EXE_filmback"))
            .args(&args)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        // Close the pipe's read end before the command prints.
        drop(child.stdout.take());
        let out = child.wait_with_output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(stderr.is_empty(), "{args:?}: {stderr}");
        assert_ne!(out.status.code(), Some(101), "{args:?} panicked");
    }
}

// ---------------------------------------------------------------------------------------
// `filmback hook`: gphoto2's --hook-script
// ---------------------------------------------------------------------------------------

/// Runs `filmback hook --ingest INGEST` in `cwd` as gphoto2 runs its hook script: with
/// `ACTION` and, when given, `ARGUMENT` in the environment.
fn hook(cwd: &Path, ingest: &Path, action: &str, argument: Option<&str>) -> std::process::Output {
    let mut cmd = filmback();
    cmd.current_dir(cwd)
        .arg("hook")
        .arg("--ingest")
        .arg(ingest)
        .env_remove("ARGUMENT")
        .env("ACTION", action);
    if let Some(a) = argument {
        cmd.env("ARGUMENT", a);
    }
    cmd.output().expect("run filmback hook")
}

fn names_in(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

#[test]
fn hook_moves_a_download_into_ingest_and_ignores_other_actions() {
    let dir = tempfile::tempdir().unwrap();
    let (cwd, ingest) = (dir.path().join("gphoto2"), dir.path().join("ingest"));
    std::fs::create_dir_all(&cwd).unwrap();
    std::fs::create_dir_all(&ingest).unwrap();
    write(&cwd, "IMG_0001.CR2", b"raw bytes");
    for action in ["init", "start", "stop"] {
        let out = hook(&cwd, &ingest, action, None);
        assert!(out.status.success(), "{action}: {out:?}");
    }
    assert!(names_in(&ingest).is_empty(), "only download moves files");
    // gphoto2 passes the file as it named it: relative to its working folder.
    let out = hook(&cwd, &ingest, "download", Some("IMG_0001.CR2"));
    assert!(out.status.success(), "{out:?}");
    assert_eq!(names_in(&ingest), ["IMG_0001.CR2"]);
    assert_eq!(
        std::fs::read(ingest.join("IMG_0001.CR2")).unwrap(),
        b"raw bytes"
    );
    assert!(names_in(&cwd).is_empty(), "moved, not copied");
    // Without ACTION it says what it is for.
    let out = filmback()
        .args(["hook", "--ingest"])
        .arg(&ingest)
        .env_remove("ACTION")
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--hook-script"));
}

/// A download that is not there (gphoto2 named a file since moved or deleted) is said
/// to be missing, not that something "cannot write".
#[test]
fn hook_says_a_missing_download_is_missing() {
    let dir = tempfile::tempdir().unwrap();
    let ingest = dir.path().join("ingest");
    std::fs::create_dir_all(&ingest).unwrap();
    let out = hook(dir.path(), &ingest, "download", Some("IMG_0009.CR2"));
    assert_eq!(out.status.code(), Some(1), "{out:?}");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("IMG_0009.CR2: the downloaded file is missing")
            && !stderr.contains("cannot write"),
        "{stderr}"
    );
    assert!(names_in(&ingest).is_empty());
}

#[test]
fn hook_never_replaces_a_frame_and_leaves_the_download_in_place() {
    let dir = tempfile::tempdir().unwrap();
    let (cwd, ingest) = (dir.path().join("gphoto2"), dir.path().join("ingest"));
    std::fs::create_dir_all(&cwd).unwrap();
    std::fs::create_dir_all(&ingest).unwrap();
    let source = write(&cwd, "IMG_0002.JPG", b"new capture");
    write(&ingest, "IMG_0002.JPG", b"earlier capture");
    let out = hook(&cwd, &ingest, "download", Some(source.to_str().unwrap()));
    assert_eq!(out.status.code(), Some(1), "{out:?}");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains(&ingest.join("IMG_0002.JPG").display().to_string())
            && stderr.contains(&source.display().to_string())
            && stderr.contains("already exists"),
        "{stderr}"
    );
    assert_eq!(std::fs::read(&source).unwrap(), b"new capture");
    assert_eq!(
        std::fs::read(ingest.join("IMG_0002.JPG")).unwrap(),
        b"earlier capture"
    );
    assert_eq!(names_in(&ingest), ["IMG_0002.JPG"], "no staging file left");
}

/// Across file systems (a tmpfs under /dev/shm against the test folder): copied to a
/// hidden staging name, synced, published, the source removed; the capture-time mtime
/// gphoto2 set is kept. Skipped where no second file system is writable.
#[test]
fn hook_copies_across_file_systems_through_a_hidden_staging_name() {
    use std::os::unix::fs::MetadataExt;
    let dir = tempfile::tempdir().unwrap();
    let ingest = dir.path().join("ingest");
    std::fs::create_dir_all(&ingest).unwrap();
    let Ok(other) = tempfile::tempdir_in("/dev/shm") else {
        eprintln!("skipped: /dev/shm is not writable");
        return;
    };
    let dev = |p: &Path| std::fs::metadata(p).unwrap().dev();
    if dev(other.path()) == dev(&ingest) {
        eprintln!("skipped: /dev/shm is on the same file system");
        return;
    }
    let bytes: Vec<u8> = (0..300_000u32).map(|i| (i % 251) as u8).collect();
    let source = write(other.path(), "IMG_0003.NEF", &bytes);
    let captured =
        std::time::SystemTime::UNIX_EPOCH + std::time::Duration::from_secs(1_700_000_000);
    std::fs::File::options()
        .write(true)
        .open(&source)
        .unwrap()
        .set_modified(captured)
        .unwrap();
    let out = hook(
        other.path(),
        &ingest,
        "download",
        Some(source.to_str().unwrap()),
    );
    assert!(out.status.success(), "{out:?}");
    assert_eq!(names_in(&ingest), ["IMG_0003.NEF"]);
    let target = ingest.join("IMG_0003.NEF");
    assert_eq!(std::fs::read(&target).unwrap(), bytes);
    assert_eq!(
        std::fs::metadata(&target).unwrap().modified().unwrap(),
        captured
    );
    assert!(!source.exists(), "the download moved");
}
