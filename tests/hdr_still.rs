//! The HDR still (`--format ultrahdr`): a gain-map JPEG read back by a small parser of
//! its own here (markers, the MPF index, XMP, ISO 21496-1), the HDR rendition recovered
//! from base × gain map against the one intended, the file written by `filmback
//! render`, and the file in Chromium.

use std::path::Path;
use std::process::Command;

use filmback::display::{ColourSpace, Depth, luminance, srgb_decode};
use filmback::film::{Catalogue, ColourMode, Key};
use filmback::hdr_output;
use filmback::radiance::RadianceMap;
use filmback::rendering::{self, Format, Look, SourceExif, hdr_still};

use crate::common;

/// A scene with mid-tones, colour and highlights far above them: a horizontal ramp over
/// 12 stops (grey, warm and cool bands), a bright disc (a sun) of 2^10 times the ramp's
/// middle and a blue light (a neon sign) whose red and green stay below white in the look.
fn scene(w: u32, h: u32) -> RadianceMap {
    let mut pixels = Vec::with_capacity((w * h * 3) as usize);
    for y in 0..h {
        for x in 0..w {
            let stops = -6.0 + 12.0 * x as f32 / (w - 1) as f32;
            let v = stops.exp2() * 0.18;
            let tint = match 3 * y / h {
                0 => [1.0, 1.0, 1.0],
                1 => [1.3, 0.9, 0.6],
                _ => [0.6, 0.9, 1.4],
            };
            let (dx, dy) = (x as f32 - 0.25 * w as f32, y as f32 - 0.3 * h as f32);
            let sun = if dx * dx + dy * dy < (0.08 * h as f32).powi(2) {
                180.0
            } else {
                0.0
            };
            let neon = if x > w / 20 && x < w / 5 && y > 3 * h / 4 && y < 9 * h / 10 {
                [1.0, 2.0, 400.0]
            } else {
                [0.0; 3]
            };
            let mut rgb = tint.map(|t| t * v + sun);
            for (c, n) in rgb.iter_mut().zip(neon) {
                *c += n;
            }
            pixels.extend(rgb);
        }
    }
    RadianceMap::new(w, h, 3, pixels).unwrap()
}

fn velvia() -> Look {
    let catalogue = Catalogue::builtin().unwrap();
    let looks = rendering::looks(
        &catalogue,
        &["velvia50".to_string()],
        &[],
        0.0,
        ColourMode::PerLayer,
        Key::LogAverage,
    )
    .unwrap();
    looks.into_iter().next().unwrap()
}

/// The HDR still of `map` through `look`, sRGB, quality 95.
fn hdr_still(map: &RadianceMap, look: &Look) -> Vec<u8> {
    let mut bytes = Vec::new();
    rendering::encode_look(
        map,
        look,
        Format::UltraHdr { quality: 95 },
        ColourSpace::Srgb,
        &SourceExif::default(),
        &mut bytes,
    )
    .unwrap();
    bytes
}

/// One marker segment of a JPEG's header: its marker, where it starts, its payload.
struct Segment<'a> {
    marker: u8,
    at: usize,
    payload: &'a [u8],
}

/// The marker segments of the JPEG at `bytes` from SOI up to SOS.
fn segments(bytes: &[u8]) -> Vec<Segment<'_>> {
    assert_eq!(&bytes[..2], &[0xFF, 0xD8], "no SOI");
    let mut at = 2;
    let mut out = Vec::new();
    loop {
        assert_eq!(bytes[at], 0xFF, "a marker at {at}");
        let marker = bytes[at + 1];
        let length = usize::from(u16::from_be_bytes([bytes[at + 2], bytes[at + 3]]));
        out.push(Segment {
            marker,
            at,
            payload: &bytes[at + 4..at + 2 + length],
        });
        if marker == 0xDA {
            return out;
        }
        at += 2 + length;
    }
}

/// The payload after `signature` of the first APPn segment (`marker`) that starts with it.
fn app<'a>(segments: &[Segment<'a>], marker: u8, signature: &[u8]) -> Option<&'a [u8]> {
    segments
        .iter()
        .find(|s| s.marker == marker && s.payload.starts_with(signature))
        .map(|s| &s.payload[signature.len()..])
}

/// An image the MPF index lists: attribute, size, absolute offset in the file.
#[derive(Debug)]
struct MpEntry {
    attribute: u32,
    size: usize,
    offset: usize,
}

/// The images the primary's MPF segment lists (CIPA DC-007, big- or little-endian).
fn mpf_entries(file: &[u8]) -> Vec<MpEntry> {
    let segments = segments(file);
    let segment = segments
        .iter()
        .find(|s| s.marker == 0xE2 && s.payload.starts_with(b"MPF\0"))
        .expect("an MPF APP2 segment");
    let tiff = &segment.payload[4..];
    let header = segment.at + 8;
    let big = match &tiff[..4] {
        b"MM\0\x2A" => true,
        b"II\x2A\0" => false,
        other => panic!("not a TIFF header: {other:?}"),
    };
    let u16_at = |i: usize| {
        let b = [tiff[i], tiff[i + 1]];
        if big {
            u16::from_be_bytes(b)
        } else {
            u16::from_le_bytes(b)
        }
    };
    let u32_at = |i: usize| {
        let b = [tiff[i], tiff[i + 1], tiff[i + 2], tiff[i + 3]];
        if big {
            u32::from_be_bytes(b)
        } else {
            u32::from_le_bytes(b)
        }
    };
    let ifd = u32_at(4) as usize;
    let mut images = 0;
    let mut entries_at = None;
    for e in 0..usize::from(u16_at(ifd)) {
        let entry = ifd + 2 + 12 * e;
        match u16_at(entry) {
            0xB000 => assert_eq!(&tiff[entry + 8..entry + 12], b"0100"),
            0xB001 => images = u32_at(entry + 8) as usize,
            0xB002 => {
                assert_eq!(u32_at(entry + 4) as usize, 16 * images);
                entries_at = Some(u32_at(entry + 8) as usize);
            }
            tag => panic!("unexpected MP index tag {tag:#x}"),
        }
    }
    let first = entries_at.expect("an MPEntry tag");
    (0..images)
        .map(|i| {
            let at = first + 16 * i;
            let offset = u32_at(at + 8) as usize;
            MpEntry {
                attribute: u32_at(at),
                size: u32_at(at + 4) as usize,
                offset: if offset == 0 { 0 } else { header + offset },
            }
        })
        .collect()
}

/// The value of attribute `name` in an XMP packet, parsed as a number.
fn xmp_number(xmp: &str, name: &str) -> f32 {
    let start = xmp
        .find(&format!("{name}=\""))
        .unwrap_or_else(|| panic!("{name} missing from {xmp}"))
        + name.len()
        + 2;
    let end = start + xmp[start..].find('"').unwrap();
    xmp[start..end].parse().unwrap()
}

const XMP: &[u8] = b"http://ns.adobe.com/xap/1.0/\0";
const ISO: &[u8] = b"urn:iso:std:iso:ts:21496:-1\0";

/// What a reader of the file finds: the two images decoded, the gain map's XMP values.
struct Read {
    base: image::RgbImage,
    gain: image::GrayImage,
    /// min, max (stops), gamma, offset SDR, offset HDR, capacity min, max (stops).
    hdrgm: [f32; 7],
}

/// Reads a gain-map JPEG as a viewer does, asserting its structure on the way.
fn read(file: &[u8]) -> Read {
    let entries = mpf_entries(file);
    assert_eq!(entries.len(), 2, "{entries:?}");
    assert_eq!(
        entries[0].attribute & 0x00FF_FFFF,
        0x03_0000,
        "primary type"
    );
    assert_eq!(entries[0].offset, 0);
    assert_eq!(entries[0].size + entries[1].size, file.len());
    assert_eq!(entries[1].offset, entries[0].size, "gain map right after");
    let primary = &file[..entries[0].size];
    let secondary = &file[entries[1].offset..][..entries[1].size];
    assert_eq!(&primary[primary.len() - 2..], &[0xFF, 0xD9]);
    let head = segments(primary);
    let xmp = String::from_utf8(app(&head, 0xE1, XMP).expect("primary XMP").to_vec()).unwrap();
    assert!(xmp.contains("hdrgm:Version=\"1.0\""), "{xmp}");
    assert!(xmp.contains("Item:Semantic=\"GainMap\""), "{xmp}");
    assert_eq!(xmp_number(&xmp, "Item:Length") as usize, secondary.len());
    assert_eq!(
        app(&head, 0xE2, ISO),
        Some(&[0u8, 0, 0, 0][..]),
        "ISO version"
    );
    assert!(app(&head, 0xE2, b"ICC_PROFILE\0").is_some());
    let gain_head = segments(secondary);
    let gain_xmp = app(&gain_head, 0xE1, XMP).expect("gain map XMP");
    let gain_xmp = String::from_utf8(gain_xmp.to_vec()).unwrap();
    let hdrgm = [
        "GainMapMin",
        "GainMapMax",
        "Gamma",
        "OffsetSDR",
        "OffsetHDR",
        "HDRCapacityMin",
        "HDRCapacityMax",
    ]
    .map(|n| xmp_number(&gain_xmp, &format!("hdrgm:{n}")));
    assert!(gain_xmp.contains("hdrgm:BaseRenditionIsHDR=\"False\""));
    // The ISO block states the same values (pairs of numerator and denominator).
    let iso = app(&gain_head, 0xE2, ISO).expect("gain map ISO 21496-1");
    assert_eq!(&iso[..5], &[0, 0, 0, 0, 0x40]);
    let pair = |i: usize| {
        let at = 5 + 8 * i;
        let n = i32::from_be_bytes(iso[at..at + 4].try_into().unwrap());
        let d = u32::from_be_bytes(iso[at + 4..at + 8].try_into().unwrap());
        n as f32 / d as f32
    };
    let iso_values = [
        pair(2),
        pair(3),
        pair(4),
        pair(5),
        pair(6),
        pair(0),
        pair(1),
    ];
    assert_eq!(iso_values, hdrgm, "ISO and XMP agree");
    let base = image::load_from_memory_with_format(primary, image::ImageFormat::Jpeg)
        .unwrap()
        .to_rgb8();
    let gain = image::load_from_memory_with_format(secondary, image::ImageFormat::Jpeg)
        .unwrap()
        .to_luma8();
    Read { base, gain, hdrgm }
}

/// Percentile `p` (0..=1) of `values`.
fn percentile(values: &mut [f32], p: f64) -> f32 {
    values.sort_by(f32::total_cmp);
    values[((values.len() - 1) as f64 * p).round() as usize]
}

/// The file parses as an Ultra HDR JPEG, its base is the look's JPEG, and base × gain map
/// gives back the intended HDR rendition `SDR·boost(k·Y)` within quantisation.
#[test]
fn the_hdr_still_recovers_the_intended_rendition() {
    let (w, h) = (320, 200);
    let map = scene(w, h);
    let look = velvia();
    let file = hdr_still(&map, &look);
    let read = read(&file);
    let [
        min,
        max,
        gamma,
        offset_sdr,
        offset_hdr,
        capacity_min,
        capacity_max,
    ] = read.hdrgm;
    assert_eq!((min, max, gamma), (0.0, hdr_still::HEADROOM_STOPS, 1.0));
    assert_eq!((offset_sdr, offset_hdr), (0.0, 0.0));
    assert_eq!(
        (capacity_min, capacity_max),
        (0.0, hdr_still::HEADROOM_STOPS)
    );
    assert_eq!(read.base.dimensions(), (w, h));
    assert_eq!(read.gain.dimensions(), (w, h));

    // The intended rendition, from the look's 8-bit rendering before JPEG.
    let sdr = look.render(&map, Depth::Eight).unwrap();
    let sdr = sdr.to_u8();
    let k = hdr_still::scene_scale(&map, &sdr, ColourSpace::Srgb);
    assert!(k > 0.0, "{k}");
    // The base is the look's rendering within JPEG error.
    let base_error = read
        .base
        .as_raw()
        .iter()
        .zip(sdr.iter())
        .map(|(a, b)| (i32::from(*a) - i32::from(*b)).abs())
        .max()
        .unwrap();
    assert!(
        base_error <= 24,
        "base differs from the look by {base_error} codes"
    );

    let pixels = map.pixels();
    let mut gain_error = Vec::new();
    let mut relative = Vec::new();
    let mut peak: f32 = 0.0;
    for i in 0..(w * h) as usize {
        let y = luminance(pixels[3 * i], pixels[3 * i + 1], pixels[3 * i + 2]);
        let boost = hdr_still::boost(k * y);
        // What a display with the full headroom computes (weight 1).
        let code = f32::from(read.gain.as_raw()[i]) / 255.0;
        let log_gain = min + (max - min) * code.powf(1.0 / gamma);
        gain_error.push((log_gain - boost.log2()).abs());
        let linear = |v: u8| srgb_decode(f32::from(v) / 255.0);
        let base = &read.base.as_raw()[3 * i..3 * i + 3];
        let hdr: Vec<f32> = base
            .iter()
            .map(|&v| (linear(v) + offset_sdr) * log_gain.exp2() - offset_hdr)
            .collect();
        let intended: Vec<f32> = sdr[3 * i..3 * i + 3]
            .iter()
            .map(|&v| linear(v) * boost)
            .collect();
        let shown = luminance(hdr[0], hdr[1], hdr[2]);
        let meant = luminance(intended[0], intended[1], intended[2]);
        peak = peak.max(shown);
        if meant > 0.05 {
            relative.push((shown / meant - 1.0).abs());
        }
    }
    let gain_p99 = percentile(&mut gain_error, 0.99);
    let gain_max = percentile(&mut gain_error, 1.0);
    let rel_p50 = percentile(&mut relative, 0.5);
    let rel_p99 = percentile(&mut relative, 0.99);
    println!(
        "k = {k:.4}; gain map error: p99 {gain_p99:.4}, max {gain_max:.4} stop; \
         HDR luminance relative error: median {rel_p50:.4}, p99 {rel_p99:.4}; peak {peak:.3}×SDR white"
    );
    // Quantisation is half a step of 2 stops/255 (0.004 stop); JPEG at q95 adds a little.
    assert!(gain_p99 < 0.02 && gain_max < 0.1, "{gain_p99} {gain_max}");
    assert!(rel_p50 < 0.01 && rel_p99 < 0.05, "{rel_p50} {rel_p99}");
    // The sun uses the headroom: near 4× SDR white, never beyond it.
    let top = hdr_still::HEADROOM_STOPS.exp2();
    assert!(peak > 0.9 * top && peak < 1.02 * top, "peak {peak}");
}

/// The base decodes to the very pixels of the look's plain JPEG at the same quality, for
/// a film and a tone map: an SDR viewer sees what `--format jpeg` gives.
#[test]
fn the_base_is_the_looks_jpeg() {
    let map = scene(200, 120);
    let catalogue = Catalogue::builtin().unwrap();
    let linear = rendering::looks(
        &catalogue,
        &[],
        &["linear".to_string()],
        0.0,
        ColourMode::PerLayer,
        Key::LogAverage,
    )
    .unwrap();
    for look in [velvia(), linear[0].clone()] {
        let mut plain = Vec::new();
        rendering::encode_look(
            &map,
            &look,
            Format::Jpeg { quality: 95 },
            ColourSpace::Srgb,
            &SourceExif::default(),
            &mut plain,
        )
        .unwrap();
        let plain = image::load_from_memory(&plain).unwrap().to_rgb8();
        assert!(
            read(&hdr_still(&map, &look)).base == plain,
            "{}",
            look.name()
        );
    }
}

/// `filmback render MAP.exr --format ultrahdr` writes the HDR still under the look's name.
#[test]
fn render_writes_an_hdr_still() {
    let dir = tempfile::tempdir().unwrap();
    let exr = dir.path().join("scene.exr");
    let map = scene(160, 100);
    let mut bytes = Vec::new();
    hdr_output::encode_exr(
        &mut std::io::Cursor::new(&mut bytes),
        &map,
        None,
        &hdr_output::Provenance::default(),
        hdr_output::ExrOptions::default(),
    )
    .unwrap();
    std::fs::write(&exr, bytes).unwrap();
    let out = dir.path().join("out");
    let status = common::filmback()
        .args(["render", exr.to_str().unwrap(), "--film", "velvia50"])
        .args(["--format", "ultrahdr", "-o", out.to_str().unwrap()])
        .status()
        .unwrap();
    assert!(status.success());
    let file = std::fs::read(out.join("scene.velvia50-t1.jpg")).unwrap();
    let read = read(&file);
    assert_eq!(read.base.dimensions(), (160, 100));
    assert!(
        read.gain.as_raw().iter().any(|&c| c > 200),
        "the sun is boosted"
    );
}

/// `filmback merge --format ultrahdr` writes the HDR still beside the EXR, through the
/// darkroom (the merge evaluated while the look is developed).
#[test]
fn merge_writes_an_hdr_still_beside_the_exr() {
    let dir = tempfile::tempdir().unwrap();
    let shots = filmback::synthetic::demo::aeb("Studio Cam", None, 70);
    let frames = filmback::synthetic::demo::jpegs(240, 160, &shots, 7).unwrap();
    let mut paths = Vec::new();
    for (i, bytes) in frames.iter().enumerate() {
        let path = dir.path().join(format!("S-{}.jpg", i + 1));
        std::fs::write(&path, bytes).unwrap();
        paths.push(path);
    }
    let out = dir.path().join("out");
    let status = common::filmback()
        .arg("merge")
        .args(&paths)
        .args(["--film", "velvia50", "--format", "ultrahdr:90", "-o"])
        .arg(&out)
        .status()
        .unwrap();
    assert!(status.success());
    assert!(out.join("S-1.exr").is_file());
    let read = read(&std::fs::read(out.join("S-1.velvia50-t1.jpg")).unwrap());
    assert_eq!(read.base.dimensions(), (240, 160));
    assert_eq!(read.gain.dimensions(), (240, 160));
}

/// Runs headless Chromium on `page` and returns the DOM it ends with (`--dump-dom`,
/// after the page's scripts ran within a virtual 10 s).
fn dump_dom(binary: &Path, page: &Path, flags: &[&str]) -> String {
    let profile = tempfile::tempdir().unwrap();
    let output = Command::new(binary)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--allow-file-access-from-files",
            "--virtual-time-budget=10000",
            "--dump-dom",
        ])
        .args(flags)
        .arg(format!("--user-data-dir={}", profile.path().display()))
        .arg(format!("file://{}", page.display()))
        .output()
        .unwrap();
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    String::from_utf8(output.stdout).unwrap()
}

/// The text of `#result` in the DOM Chromium ends `page` with ([`dump_dom`]).
fn page_result(binary: &Path, page: &Path, flags: &[&str]) -> String {
    let dom = dump_dom(binary, page, flags);
    dom.split("<pre id=\"result\">")
        .nth(1)
        .and_then(|r| r.split("</pre>").next())
        .unwrap_or_else(|| panic!("no result in {dom}"))
        .to_string()
}

/// Chromium decodes the HDR still: an `<img>` of it loads at its size and, drawn on a
/// canvas, shows the base (the film look) — what any SDR display shows.
#[test]
fn chromium_decodes_the_hdr_still() {
    let Some(binary) = common::chromium() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (320, 200);
    let map = scene(w, h);
    let look = velvia();
    let file = hdr_still(&map, &look);
    std::fs::write(dir.path().join("still.jpg"), &file).unwrap();
    if let Some(keep) = std::env::var_os("FILMBACK_HDR_STILL") {
        std::fs::write(keep, &file).unwrap();
    }
    let page = dir.path().join("page.html");
    std::fs::write(&page, PAGE).unwrap();
    let result = page_result(&binary, &page, &[]);
    println!("chromium: {result}");
    let fields: Vec<&str> = result.split_whitespace().collect();
    assert_eq!(fields.first(), Some(&"decoded"), "{result}");
    assert_eq!(fields[1..3], [w.to_string(), h.to_string()]);
    // The canvas shows the base: the middle of the grey band as the base JPEG has it.
    let base = read(&file).base;
    let expected = base.get_pixel(w / 2, h / 6).0;
    let shown: Vec<u8> = fields[3..6].iter().map(|v| v.parse().unwrap()).collect();
    for (a, b) in shown.iter().zip(expected) {
        assert!(
            (i32::from(*a) - i32::from(b)).abs() <= 3,
            "{shown:?} vs {expected:?}"
        );
    }
}

/// Chromium applies the gain map: drawn on a half-float, linear-light canvas given the
/// headroom of a display two stops above SDR white (`globalHDRHeadroom`, an experimental
/// canvas feature, so the flag that enables those), each pixel reads `base·2^gain` as the
/// file's metadata says, highlights above 1.0 and mid-tones as in the base; the base alone
/// never goes above 1.0. A headless browser has no HDR display, so this is as far as a
/// test sees what a viewer on an HDR screen is shown.
#[test]
fn chromium_applies_the_gain_map_given_hdr_headroom() {
    let Some(binary) = common::chromium() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (160, 100);
    let file = hdr_still(&scene(w, h), &velvia());
    let read = read(&file);
    let primary = mpf_entries(&file)[0].size;
    std::fs::write(dir.path().join("still.jpg"), &file).unwrap();
    std::fs::write(dir.path().join("base.jpg"), &file[..primary]).unwrap();
    let page = dir.path().join("page.html");
    std::fs::write(&page, HEADROOM_PAGE).unwrap();
    let flags = ["--enable-experimental-web-platform-features"];
    let result = page_result(&binary, &page, &flags);
    if result.starts_with("unsupported") {
        eprintln!("skipped: this Chromium has no canvas HDR headroom ({result})");
        return;
    }
    let values = |name: &str| -> Vec<f32> {
        let line = result
            .lines()
            .find(|l| l.starts_with(name))
            .unwrap_or_else(|| panic!("no {name} in {result}"));
        line.split_whitespace()
            .skip(1)
            .map(|v| v.parse().unwrap())
            .collect()
    };
    let (still, base) = (values("still.jpg"), values("base.jpg"));
    assert_eq!(still.len(), (3 * w * h) as usize, "{result:.200}");
    let [min, max, gamma, offset_sdr, offset_hdr, ..] = read.hdrgm;
    let linear = |v: u8| srgb_decode(f32::from(v) / 255.0);
    let (mut worst, mut above_white, mut mid_worst) = (0f32, 0, 0f32);
    for i in 0..(w * h) as usize {
        let code = f32::from(read.gain.as_raw()[i]) / 255.0;
        let log_gain = min + (max - min) * code.powf(1.0 / gamma);
        for c in 0..3 {
            let sdr = linear(read.base.as_raw()[3 * i + c]);
            let expected = (sdr + offset_sdr) * log_gain.exp2() - offset_hdr;
            let shown = still[3 * i + c];
            // Chromium's JPEG decoder and ours may differ by a code or two: 3 % and a
            // little (a gain map it ignored would be off by a factor of up to 4).
            worst = worst.max((shown - expected).abs() / (0.03 * expected + 0.005));
            if code == 0.0 {
                mid_worst = mid_worst.max((shown - base[3 * i + c]).abs());
            }
            above_white += usize::from(shown > 1.05);
            assert!(
                base[3 * i + c] <= 1.0,
                "the base alone reads {}",
                base[3 * i + c]
            );
        }
    }
    let peak = still.iter().copied().fold(0f32, f32::max);
    println!(
        "chromium, headroom {max} stops: peak {peak:.3}, {above_white} samples above 1.05, \
         worst error {worst:.2} of the tolerance, gain-free pixels within {mid_worst:.4} of the base"
    );
    assert!(worst <= 1.0, "{worst}");
    assert!(mid_worst <= 0.004, "{mid_worst}");
    assert!(peak > 0.9 * max.exp2(), "peak {peak}");
    assert!(above_white > (w * h / 50) as usize, "{above_white}");
}

/// Draws `still.jpg` and `base.jpg` on a half-float `srgb-linear` canvas with
/// `globalHDRHeadroom` 2 and writes, per image, its name and every sample (RGB, row by
/// row) into `#result`; `unsupported …` when the canvas lacks either.
const HEADROOM_PAGE: &str = r#"<!doctype html>
<html><body><pre id="result">pending</pre>
<script>
const result = document.getElementById('result');
const load = src => new Promise((ok, fail) => {
  const i = new Image(); i.onload = () => ok(i); i.onerror = () => fail(src); i.src = src;
});
(async () => {
  const lines = [];
  for (const name of ['still.jpg', 'base.jpg']) {
    const img = await load(name);
    const c = document.createElement('canvas');
    c.width = img.naturalWidth; c.height = img.naturalHeight;
    let g;
    try { g = c.getContext('2d', {colorType: 'float16', colorSpace: 'srgb-linear'}); }
    catch (e) { result.textContent = 'unsupported srgb-linear float16 canvas'; return; }
    if (!g || !('globalHDRHeadroom' in g)) {
      result.textContent = 'unsupported globalHDRHeadroom'; return;
    }
    g.globalHDRHeadroom = 2;
    g.drawImage(img, 0, 0);
    const d = g.getImageData(0, 0, c.width, c.height, {pixelFormat: 'rgba-float16'}).data;
    const v = [];
    for (let i = 0; i < d.length; i += 4) {
      v.push(d[i].toFixed(4), d[i + 1].toFixed(4), d[i + 2].toFixed(4));
    }
    lines.push(name + ' ' + v.join(' '));
  }
  result.textContent = lines.join('\n');
})().catch(e => { result.textContent = 'failed ' + e; });
</script></body></html>
"#;

/// Loads `still.jpg` in an `<img>`, draws it on a canvas and writes
/// `decoded WIDTH HEIGHT R G B` (the pixel at (w/2, h/6)) or `failed …` into `#result`.
const PAGE: &str = r#"<!doctype html>
<html><body><pre id="result">pending</pre>
<script>
const result = document.getElementById('result');
const img = new Image();
img.onload = () => {
  const c = document.createElement('canvas');
  c.width = img.naturalWidth; c.height = img.naturalHeight;
  const g = c.getContext('2d');
  g.drawImage(img, 0, 0);
  const p = g.getImageData(Math.floor(c.width / 2), Math.floor(c.height / 6), 1, 1).data;
  result.textContent = `decoded ${img.naturalWidth} ${img.naturalHeight} ${p[0]} ${p[1]} ${p[2]}`;
};
img.onerror = () => { result.textContent = 'failed to decode'; };
img.src = 'still.jpg';
</script></body></html>
"#;
