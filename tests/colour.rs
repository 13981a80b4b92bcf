//! Wide-gamut renderings: a look encoded for Display P3 or Rec. 2020 carries the space's
//! ICC profile (and a PNG its `cICP` code points) and, converted back to sRGB by a
//! colour-managed reader, is the sRGB rendering: by `moxcms` here, and by Little CMS 2
//! (Pillow's ImageCms) through `tests/colour_check.py`, skipped visibly where Pillow is
//! not installed.

use std::io::Cursor;
use std::path::Path;
use std::process::Command;

use filmback::atomic::Overwrite;
use filmback::display::ColourSpace;
use filmback::film::{Catalogue, ColourMode, Key};
use filmback::hdr_output::{self, ExrOptions, Provenance};
use filmback::radiance::RadianceMap;
use filmback::rendering::{self, Format, Look, SourceExif};

use crate::common::{filmback, reference_python};
use crate::lut::{delta_e2000, srgb_lab};

/// A chart of 96 × 48: a grey ramp from 2⁻⁶ to 2⁴ times mid grey along the top half, and
/// below it hues around the circle in three bands of 8 rows (saturations 0.3, 0.6, 0.9 at
/// half, once and twice mid grey).
fn chart() -> RadianceMap {
    let (w, h) = (96usize, 48usize);
    let mut pixels = Vec::with_capacity(w * h * 3);
    for y in 0..h {
        for x in 0..w {
            let t = x as f32 / (w - 1) as f32;
            let rgb = if y < h / 2 {
                [0.18 * (10.0 * t - 6.0).exp2(); 3]
            } else {
                let hue = t * std::f32::consts::TAU;
                let band = (y - h / 2) / 8;
                let (saturation, level) = ([0.3, 0.6, 0.9][band], [0.09, 0.18, 0.36][band]);
                [0.0, 2.094, 4.189].map(|phase| level * (1.0 + saturation * (hue - phase).cos()))
            };
            pixels.extend_from_slice(&rgb);
        }
    }
    RadianceMap::new(w as u32, h as u32, 3, pixels).unwrap()
}

fn looks() -> Vec<Look> {
    let catalogue = Catalogue::builtin().unwrap();
    let (colour, key) = (ColourMode::PerLayer, Key::Grey(0.18));
    rendering::looks(
        &catalogue,
        &["velvia50".into(), "portra400".into()],
        &["linear".into()],
        0.0,
        colour,
        key,
    )
    .unwrap()
}

fn encoded(map: &RadianceMap, look: &Look, format: Format, space: ColourSpace) -> Vec<u8> {
    let mut out = Vec::new();
    rendering::encode_look(map, look, format, space, &SourceExif::default(), &mut out).unwrap();
    out
}

/// A 16-bit PNG's samples, ICC profile and `cICP` code points.
fn read_png16(bytes: &[u8]) -> (Vec<u16>, Vec<u8>, [u8; 4]) {
    let mut reader = png::Decoder::new(Cursor::new(bytes)).read_info().unwrap();
    let icc = reader.info().icc_profile.clone().unwrap().into_owned();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    reader.next_frame(&mut buf).unwrap();
    let samples = buf
        .chunks_exact(2)
        .map(|b| u16::from_be_bytes([b[0], b[1]]))
        .collect();
    let at = bytes
        .windows(4)
        .position(|w| w == b"cICP")
        .expect("a cICP chunk");
    let cicp = bytes[at + 4..at + 8].try_into().unwrap();
    (samples, icc, cicp)
}

/// sRGB code values (16-bit) to CIELAB.
fn lab_of(samples: &[u16]) -> Vec<[f64; 3]> {
    samples
        .chunks_exact(3)
        .map(|p| srgb_lab([0, 1, 2].map(|c| f64::from(p[c]) / 65535.0)))
        .collect()
}

/// Each space's 16-bit PNG names its primaries and transfer in `cICP` and embeds its own
/// profile; `moxcms` converting it back to sRGB gives the sRGB rendering within
/// ΔE2000 0.1 (16-bit rounding), for film looks and a tone map.
#[test]
fn wide_gamut_pngs_carry_their_space_and_convert_back_to_the_srgb_rendering() {
    let map = chart();
    let srgb = moxcms::ColorProfile::new_srgb();
    for look in looks() {
        let (want, _, cicp) = read_png16(&encoded(&map, &look, Format::Png16, ColourSpace::Srgb));
        assert_eq!(cicp, [1, 13, 0, 1]);
        for (space, code_points) in [
            (ColourSpace::DisplayP3, [12, 13, 0, 1]),
            (ColourSpace::Rec2020, [9, 1, 0, 1]),
        ] {
            let (wide, icc, cicp) = read_png16(&encoded(&map, &look, Format::Png16, space));
            assert_eq!(cicp, code_points, "{}", space.name());
            assert_eq!(icc, space.icc_profile());
            assert_ne!(wide, want, "{}: the samples are re-encoded", space.name());
            let profile = moxcms::ColorProfile::new_from_slice(&icc).unwrap();
            let layout = moxcms::Layout::Rgb;
            let options = moxcms::TransformOptions::default();
            let back = profile
                .create_transform_16bit(layout, &srgb, layout, options)
                .unwrap();
            let mut got = vec![0u16; wide.len()];
            back.transform(&wide, &mut got).unwrap();
            let worst = lab_of(&got)
                .iter()
                .zip(lab_of(&want))
                .map(|(a, b)| delta_e2000(*a, b))
                .fold(0.0, f64::max);
            assert!(
                worst < 0.1,
                "{} {}: ΔE2000 {worst}",
                look.name(),
                space.name()
            );
        }
    }
}

/// JPEG and TIFF carry the space's profile too.
#[test]
fn wide_gamut_jpeg_and_tiff_embed_the_profile() {
    let map = chart();
    let look = &looks()[0];
    for space in [ColourSpace::DisplayP3, ColourSpace::Rec2020] {
        for format in [Format::Jpeg { quality: 95 }, Format::Tiff16] {
            let bytes = encoded(&map, look, format, space);
            let icc = space.icc_profile();
            assert!(
                bytes.windows(icc.len()).any(|w| w == icc),
                "{format:?} {}",
                space.name()
            );
        }
    }
}

/// `filmback render --colour-space` writes every format in P3 and Rec. 2020, and Little
/// CMS reads each back as the sRGB rendering (`tests/colour_check.py`).
#[test]
fn little_cms_reads_the_wide_gamut_files_as_the_srgb_rendering() {
    let dir = tempfile::tempdir().unwrap();
    let exr = dir.path().join("chart.exr");
    let provenance = Provenance::default();
    let options = ExrOptions::default();
    hdr_output::write_exr(
        &exr,
        Overwrite::Refuse,
        &chart(),
        None,
        &provenance,
        options,
    )
    .unwrap();
    let render = |space: &str, format: &str| {
        let out = dir
            .path()
            .join(format!("{space}-{}", format.replace(':', "")));
        let run = filmback()
            .args([
                "render", "--film", "velvia50", "--grey", "0.18", "--format", format,
            ])
            .args(["--colour-space", space, "-o"])
            .args([&out, &exr])
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&run.stderr);
        assert!(run.status.success(), "render {space} {format}: {stderr}");
        let name = std::fs::read_dir(&out).unwrap().next().unwrap().unwrap();
        name.path()
    };
    let reference = render("srgb", "png16");
    let mut wide = Vec::new();
    for space in ["p3", "rec2020"] {
        for format in ["jpeg:95", "png", "png16", "tiff"] {
            wide.push(render(space, format));
        }
    }
    run_colour_check(&reference, &wide);
}

fn run_colour_check(reference: &Path, wide: &[std::path::PathBuf]) {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/colour_check.py");
    let Ok(out) = Command::new(reference_python("FILMBACK_PILLOW_PYTHON"))
        .arg(script)
        .arg(reference)
        .args(wide)
        .output()
    else {
        println!("colour_check: skipped (no python3 to run Little CMS)");
        return;
    };
    let stdout = String::from_utf8_lossy(&out.stdout);
    print!("{stdout}{}", String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "tests/colour_check.py failed");
    assert!(
        stdout.contains("skipped")
            || stdout.lines().filter(|l| l.ends_with(" ok")).count() == wide.len()
    );
}
