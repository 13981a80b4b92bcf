//! Film looks as 3D LUTs: the `.cube` file's form, its match with filmback's own rendering
//! of the same inputs (by the LUT's trilinear interpolation here, and by OpenColorIO's
//! Python package through `tests/lut_check.py`, skipped visibly where it is not
//! installed), the split negative and print, and what is refused.

use std::path::Path;
use std::process::Command;

use filmback::display::Depth;
use filmback::film::{Catalogue, ColourMode, Key, scene_key};
use filmback::radiance::RadianceMap;
use filmback::rendering::Look;
use filmback::rendering::lut::{
    self, Gamut, InputEncoding, LUT_MID_GREY, LutPart, LutSpec, OutputEncoding,
};

use crate::common::{filmback, reference_python};

/// The limits of the issue: ΔE2000 p95 ≤ 1.0 and max ≤ 3 at 65³.
const P95_LIMIT: f64 = 1.0;
const MAX_LIMIT: f64 = 3.0;

fn catalogue() -> Catalogue {
    Catalogue::builtin().unwrap()
}

fn look(request: &str) -> Look {
    Look::film(
        &catalogue(),
        request,
        ColourMode::PerLayer,
        Key::Grey(LUT_MID_GREY),
    )
    .unwrap()
}

fn spec(size: usize, input: InputEncoding, output: OutputEncoding, part: LutPart) -> LutSpec {
    LutSpec {
        size,
        input,
        output,
        part,
    }
}

/// CIELAB (D65) of display light `rgb` (linear) in `gamut`.
fn lab(rgb: [f64; 3], gamut: Gamut) -> [f64; 3] {
    let m = gamut.matrix_to(Gamut::REC709);
    let l: Vec<f64> = (0..3)
        .map(|r| m[r][0] * rgb[0] + m[r][1] * rgb[1] + m[r][2] * rgb[2])
        .collect();
    let x = 0.4124564 * l[0] + 0.3575761 * l[1] + 0.1804375 * l[2];
    let y = 0.2126729 * l[0] + 0.7151522 * l[1] + 0.0721750 * l[2];
    let z = 0.0193339 * l[0] + 0.1191920 * l[1] + 0.9503041 * l[2];
    let f = |t: f64| {
        if t > (6.0f64 / 29.0).powi(3) {
            t.cbrt()
        } else {
            t / (3.0 * (6.0f64 / 29.0).powi(2)) + 4.0 / 29.0
        }
    };
    let (fx, fy, fz) = (f(x / 0.95047), f(y), f(z / 1.08883));
    [116.0 * fy - 16.0, 500.0 * (fx - fy), 200.0 * (fy - fz)]
}

/// CIELAB (D65) of sRGB code values `v ∈ [0, 1]` (IEC 61966-2.1).
pub(crate) fn srgb_lab(v: [f64; 3]) -> [f64; 3] {
    lab(v.map(|x| OutputEncoding::Srgb.decode(x)), Gamut::REC709)
}

/// CIEDE2000 (Sharma, Wu & Dalal 2005, kL = kC = kH = 1).
pub(crate) fn delta_e2000(a: [f64; 3], b: [f64; 3]) -> f64 {
    use std::f64::consts::PI;
    let (l1, a1, b1) = (a[0], a[1], a[2]);
    let (l2, a2, b2) = (b[0], b[1], b[2]);
    let c_bar = ((a1 * a1 + b1 * b1).sqrt() + (a2 * a2 + b2 * b2).sqrt()) / 2.0;
    let g = 0.5 * (1.0 - (c_bar.powi(7) / (c_bar.powi(7) + 25f64.powi(7))).sqrt());
    let (a1p, a2p) = ((1.0 + g) * a1, (1.0 + g) * a2);
    let (c1p, c2p) = ((a1p * a1p + b1 * b1).sqrt(), (a2p * a2p + b2 * b2).sqrt());
    let hue = |b: f64, a: f64| {
        if a == 0.0 && b == 0.0 {
            0.0
        } else {
            b.atan2(a).rem_euclid(2.0 * PI)
        }
    };
    let (h1p, h2p) = (hue(b1, a1p), hue(b2, a2p));
    let dl = l2 - l1;
    let dc = c2p - c1p;
    let mut dh = h2p - h1p;
    if c1p * c2p != 0.0 {
        if dh > PI {
            dh -= 2.0 * PI;
        } else if dh < -PI {
            dh += 2.0 * PI;
        }
    } else {
        dh = 0.0;
    }
    let dhh = 2.0 * (c1p * c2p).sqrt() * (dh / 2.0).sin();
    let l_bar = (l1 + l2) / 2.0;
    let cp_bar = (c1p + c2p) / 2.0;
    let h_bar = if c1p * c2p == 0.0 {
        h1p + h2p
    } else if (h1p - h2p).abs() <= PI {
        (h1p + h2p) / 2.0
    } else if h1p + h2p < 2.0 * PI {
        (h1p + h2p + 2.0 * PI) / 2.0
    } else {
        (h1p + h2p - 2.0 * PI) / 2.0
    };
    let t = 1.0 - 0.17 * (h_bar - PI / 6.0).cos()
        + 0.24 * (2.0 * h_bar).cos()
        + 0.32 * (3.0 * h_bar + PI / 30.0).cos()
        - 0.20 * (4.0 * h_bar - 63f64.to_radians()).cos();
    let d_theta = 30f64.to_radians() * (-((h_bar.to_degrees() - 275.0) / 25.0).powi(2)).exp();
    let rc = 2.0 * (cp_bar.powi(7) / (cp_bar.powi(7) + 25f64.powi(7))).sqrt();
    let sl = 1.0 + 0.015 * (l_bar - 50.0).powi(2) / (20.0 + (l_bar - 50.0).powi(2)).sqrt();
    let sc = 1.0 + 0.045 * cp_bar;
    let sh = 1.0 + 0.015 * cp_bar * t;
    let rt = -(2.0 * d_theta).sin() * rc;
    ((dl / sl).powi(2) + (dc / sc).powi(2) + (dhh / sh).powi(2) + rt * (dc / sc) * (dhh / sh))
        .sqrt()
}

/// The X-Rite ColorChecker's 24 patches as 8-bit sRGB (the commonly published values of
/// the post-2009 chart).
const COLORCHECKER: [[u8; 3]; 24] = [
    [115, 82, 68],
    [194, 150, 130],
    [98, 122, 157],
    [87, 108, 67],
    [133, 128, 177],
    [103, 189, 170],
    [214, 126, 44],
    [80, 91, 166],
    [193, 90, 99],
    [94, 60, 108],
    [157, 188, 64],
    [224, 163, 46],
    [56, 61, 150],
    [70, 148, 73],
    [175, 54, 60],
    [231, 199, 31],
    [187, 86, 149],
    [8, 133, 161],
    [243, 243, 242],
    [200, 200, 200],
    [160, 160, 160],
    [122, 122, 121],
    [85, 85, 85],
    [52, 52, 52],
];

/// The test chart in working (linear Rec. 709) radiance: the synthetic scene scaled so its
/// key is mid grey, a grey ramp from −8 to +8 stops, and the ColorChecker (neutral 5 at
/// about 0.19) from −3 to +3 stops in half stops.
fn chart() -> Vec<[f64; 3]> {
    let scene = filmback::synthetic::scene(96, 64, 3);
    let scale = LUT_MID_GREY / scene_key(&scene, Key::LogAverage);
    let mut pixels: Vec<[f64; 3]> = scene
        .pixels()
        .chunks_exact(3)
        .map(|p| [0, 1, 2].map(|c| f64::from(p[c]) * scale))
        .collect();
    for i in 0..=64 {
        let e = LUT_MID_GREY * (f64::from(i) / 4.0 - 8.0).exp2();
        pixels.push([e; 3]);
    }
    for patch in COLORCHECKER {
        let linear = patch.map(|v| {
            let v = f64::from(v) / 255.0;
            if v <= 0.04045 {
                v / 12.92
            } else {
                ((v + 0.055) / 1.055).powf(2.4)
            }
        });
        for s in -6..=6 {
            let k = (f64::from(s) / 2.0).exp2();
            pixels.push(linear.map(|v| v * k));
        }
    }
    pixels
}

/// The chart as input code values of `input` (converted to its gamut, encoded, clamped
/// to the LUT's domain).
fn encode_chart(chart: &[[f64; 3]], input: InputEncoding) -> Vec<[f64; 3]> {
    let m = Gamut::REC709.matrix_to(input.gamut());
    chart
        .iter()
        .map(|e| {
            [0, 1, 2].map(|r| {
                let v = m[r][0] * e[0] + m[r][1] * e[1] + m[r][2] * e[2];
                input.encode(v).clamp(0.0, 1.0)
            })
        })
        .collect()
}

/// filmback's own rendering of input codes: decoded, to working primaries, through the
/// look (metered on mid grey), then to the display encoding.
fn reference(
    request: &str,
    codes: &[[f64; 3]],
    input: InputEncoding,
    output: OutputEncoding,
) -> Vec<[f64; 3]> {
    let m = input.gamut().matrix_to(Gamut::REC709);
    let pixels: Vec<f32> = codes
        .iter()
        .flat_map(|v| {
            let e = v.map(|x| input.decode(x));
            [0, 1, 2].map(|r| (m[r][0] * e[0] + m[r][1] * e[1] + m[r][2] * e[2]) as f32)
        })
        .collect();
    let map = RadianceMap::new(codes.len() as u32, 1, 3, pixels).unwrap();
    let img = look(request).render(&map, Depth::Sixteen).unwrap();
    let to_display = Gamut::REC709.matrix_to(output.gamut());
    img.samples()
        .chunks_exact(3)
        .map(|px| {
            let l = [0, 1, 2].map(|c| {
                let v = f64::from(px[c]) / 65535.0;
                if v <= 0.04045 {
                    v / 12.92
                } else {
                    ((v + 0.055) / 1.055).powf(2.4)
                }
            });
            [0, 1, 2].map(|r| {
                output.encode(
                    to_display[r][0] * l[0] + to_display[r][1] * l[1] + to_display[r][2] * l[2],
                )
            })
        })
        .collect()
}

/// ΔE2000 p95 and max between display codes `a` and `b` of `output`.
fn delta_e_stats(a: &[[f64; 3]], b: &[[f64; 3]], output: OutputEncoding) -> (f64, f64) {
    let to_lab = |v: &[f64; 3]| lab(v.map(|x| output.decode(x)), output.gamut());
    let mut d: Vec<f64> = a
        .iter()
        .zip(b)
        .map(|(x, y)| delta_e2000(to_lab(x), to_lab(y)))
        .collect();
    d.sort_by(f64::total_cmp);
    let p95 = d[(d.len() as f64 * 0.95) as usize];
    (p95, d[d.len() - 1])
}

#[test]
fn delta_e2000_matches_sharmas_published_pairs() {
    // Sharma, Wu & Dalal (2005), Table 1, pairs 1, 7 and 17.
    let pairs = [
        ([50.0, 2.6772, -79.7751], [50.0, 0.0, -82.7485], 2.0425),
        ([50.0, 0.0, 0.0], [50.0, -1.0, 2.0], 2.3669),
        ([50.0, 2.5, 0.0], [73.0, 25.0, -18.0], 27.1492),
    ];
    for (a, b, want) in pairs {
        assert!((delta_e2000(a, b) - want).abs() < 1e-4, "{a:?} {b:?}");
    }
}

#[test]
fn the_cube_file_has_the_standard_form_and_says_what_it_holds() {
    let lut = lut::film_lut(
        &look("velvia50"),
        spec(
            33,
            InputEncoding::AcesCct,
            OutputEncoding::Rec709,
            LutPart::Whole,
        ),
    )
    .unwrap();
    let mut text = Vec::new();
    lut.write_cube(&mut text).unwrap();
    let text = String::from_utf8(text).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    let header: Vec<&str> = lines
        .iter()
        .filter(|l| l.starts_with('#'))
        .copied()
        .collect();
    assert!(
        header
            .iter()
            .any(|l| l.contains("grain, MTF and halation are spatial"))
    );
    assert!(
        header
            .iter()
            .any(|l| l.contains("scene-linear 0.18") && l.contains("0.4136"))
    );
    assert!(header.iter().any(|l| l.contains("ACEScct")));
    assert!(lines.contains(&"LUT_3D_SIZE 33"));
    assert!(lines.contains(&"DOMAIN_MIN 0.0 0.0 0.0"));
    assert!(lines.contains(&"DOMAIN_MAX 1.0 1.0 1.0"));
    assert!(
        lines
            .iter()
            .any(|l| l.starts_with("TITLE \"filmback velvia50"))
    );
    let data: Vec<[f64; 3]> = lines
        .iter()
        .filter(|l| l.starts_with(|c: char| c.is_ascii_digit() || c == '-'))
        .map(|l| {
            let v: Vec<f64> = l.split(' ').map(|x| x.parse().unwrap()).collect();
            [v[0], v[1], v[2]]
        })
        .collect();
    assert_eq!(data.len(), 33 * 33 * 33);
    // Red fastest: along the first 33 entries only red rises (a slide: more light, more
    // red transmitted), green and blue stay.
    assert!(data[32][0] > data[0][0] + 0.5);
    assert!((data[32][1] - data[0][1]).abs() < 1e-6 && (data[32][2] - data[0][2]).abs() < 1e-6);
    // The written values are the LUT's.
    assert!((data[1234][1] - f64::from(lut.table[1234][1])).abs() < 1e-6);
}

#[test]
fn each_input_encoding_matches_filmbacks_rendering_at_65() {
    let chart = chart();
    for request in ["velvia50", "portra400"] {
        for input in [
            InputEncoding::LinearLog,
            InputEncoding::AcesCct,
            InputEncoding::LogC4,
            InputEncoding::SLog3,
        ] {
            let output = OutputEncoding::Srgb;
            let lut =
                lut::film_lut(&look(request), spec(65, input, output, LutPart::Whole)).unwrap();
            let codes = encode_chart(&chart, input);
            let want = reference(request, &codes, input, output);
            let got: Vec<[f64; 3]> = codes.iter().map(|v| lut.apply(*v)).collect();
            let (p95, max) = delta_e_stats(&got, &want, output);
            println!(
                "{request} {}: ΔE2000 p95 {p95:.3} max {max:.3}",
                input.name()
            );
            assert!(
                p95 <= P95_LIMIT && max <= MAX_LIMIT,
                "{request} {input:?}: {p95} {max}"
            );
        }
    }
}

#[test]
fn a_split_negative_and_print_chain_to_the_whole_look() {
    let chart = chart();
    let input = InputEncoding::LogC4;
    let output = OutputEncoding::Rec709;
    let l = look("ektar100");
    let whole = lut::film_lut(&l, spec(65, input, output, LutPart::Whole)).unwrap();
    let negative = lut::film_lut(&l, spec(65, input, output, LutPart::Negative)).unwrap();
    let print = lut::film_lut(&l, spec(65, input, output, LutPart::Print)).unwrap();
    let codes = encode_chart(&chart, input);
    let chained: Vec<[f64; 3]> = codes
        .iter()
        .map(|v| print.apply(negative.apply(*v)))
        .collect();
    let one: Vec<[f64; 3]> = codes.iter().map(|v| whole.apply(*v)).collect();
    let (p95, max) = delta_e_stats(&chained, &one, output);
    println!("ektar100 split against whole: ΔE2000 p95 {p95:.3} max {max:.3}");
    assert!(p95 <= P95_LIMIT && max <= MAX_LIMIT, "{p95} {max}");
    // Mid grey prints at 18 % reflectance, through both LUTs and through the one.
    let grey = InputEncoding::LogC4.encode(LUT_MID_GREY);
    for p in [
        print.apply(negative.apply([grey; 3])),
        whole.apply([grey; 3]),
    ] {
        for v in p {
            assert!((output.decode(v) - 0.18).abs() < 0.005, "{p:?}");
        }
    }
}

#[test]
fn spatial_options_tone_maps_odd_sizes_and_split_slides_are_refused() {
    let s = spec(
        65,
        InputEncoding::AcesCct,
        OutputEncoding::Rec709,
        LutPart::Whole,
    );
    let grain = lut::film_lut(&look("velvia50+grain"), s).unwrap_err();
    assert!(grain.to_string().contains("spatial"), "{grain}");
    let mtf = lut::film_lut(&look("portra400+mtf"), s).unwrap_err();
    assert!(mtf.to_string().contains("spatial"), "{mtf}");
    let tonemap = Look::Tonemap(filmback::tonemap::Operator::LINEAR);
    assert!(
        lut::film_lut(&tonemap, s)
            .unwrap_err()
            .to_string()
            .contains("whole image")
    );
    let odd = lut::film_lut(&look("velvia50"), LutSpec { size: 17, ..s }).unwrap_err();
    assert!(odd.to_string().contains("33 or 65"), "{odd}");
    let split = lut::film_lut(
        &look("velvia50"),
        LutSpec {
            part: LutPart::Negative,
            ..s
        },
    )
    .unwrap_err();
    assert!(split.to_string().contains("negative"), "{split}");
}

#[test]
fn films_lut_writes_one_or_two_cube_files() {
    let dir = tempfile::tempdir().unwrap();
    let one = dir.path().join("velvia.cube");
    let out = filmback()
        .args([
            "films",
            "--lut",
            "velvia50@1/2",
            "--lut-size",
            "33",
            "--input",
            "slog3",
        ])
        .args(["--display", "p3", "-o"])
        .arg(&one)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = std::fs::read_to_string(&one).unwrap();
    assert!(
        text.contains("LUT_3D_SIZE 33") && text.contains("S-Log3") && text.contains("Display P3")
    );
    let out = filmback()
        .args(["films", "--lut", "portra400", "--split", "-o"])
        .arg(dir.path().join("portra.cube"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for name in ["portra.negative.cube", "portra.print.cube"] {
        let text = std::fs::read_to_string(dir.path().join(name)).unwrap();
        assert!(
            text.contains("LUT_3D_SIZE 65") && text.contains("Cineon"),
            "{name}"
        );
    }
    let out = filmback()
        .args(["films", "--lut", "velvia50+grain", "-o"])
        .arg(dir.path().join("x.cube"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("spatial"));
}

fn write_codes(path: &Path, values: &[[f64; 3]]) {
    let bytes: Vec<u8> = values
        .iter()
        .flat_map(|v| v.map(|x| (x as f32).to_le_bytes()))
        .flatten()
        .collect();
    std::fs::write(path, bytes).unwrap();
}

/// A real radiance map when the shared brackets are there (`brackets/memorial` under
/// `FILMBACK_TESTDATA`, else `../shared/testdata`; 32 s and 16 s): `filmback merge` of two
/// frames, every 7th pixel, scaled so its log-average is mid grey. `None` (said) where
/// they are absent.
fn real_map(dir: &Path) -> Option<Vec<[f64; 3]>> {
    let testdata = std::env::var_os("FILMBACK_TESTDATA")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/testdata"));
    let frames = testdata.join("brackets/memorial");
    if !frames.is_dir() {
        println!(
            "note: {} absent: the LUT check uses the synthetic chart only",
            frames.display()
        );
        return None;
    }
    let out = filmback()
        .args(["merge", "--times", "32,16", "--exr", "float", "-o"])
        .arg(dir)
        .arg(frames.join("memorial0061.png"))
        .arg(frames.join("memorial0062.png"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let map = filmback::hdr_output::read_exr(&dir.join("memorial0061.exr")).unwrap();
    let scale = LUT_MID_GREY / scene_key(&map, Key::LogAverage);
    Some(
        map.pixels()
            .chunks_exact(3)
            .step_by(7)
            .map(|p| [0, 1, 2].map(|c| f64::from(p[c]) * scale))
            .collect(),
    )
}

#[test]
fn opencolorio_applies_the_cube_as_filmback_renders() {
    let dir = tempfile::tempdir().unwrap();
    let mut chart = chart();
    if let Some(real) = real_map(dir.path()) {
        println!("memorial: {} pixels of a real radiance map", real.len());
        chart.extend(real);
    }
    let mut cases = Vec::new();
    for (request, input, output) in [
        ("velvia50", InputEncoding::AcesCct, OutputEncoding::Srgb),
        ("portra400", InputEncoding::LogC4, OutputEncoding::Rec709),
        ("ektar100", InputEncoding::SLog3, OutputEncoding::P3),
        ("provia100f", InputEncoding::LinearLog, OutputEncoding::Srgb),
    ] {
        let name = format!("{request}-{}-{}", input.name(), output.name());
        let lut = lut::film_lut(&look(request), spec(65, input, output, LutPart::Whole)).unwrap();
        lut.publish(
            &dir.path().join(format!("{name}.cube")),
            filmback::atomic::Overwrite::Replace,
        )
        .unwrap();
        let codes = encode_chart(&chart, input);
        write_codes(&dir.path().join(format!("{name}.in.f32")), &codes);
        write_codes(
            &dir.path().join(format!("{name}.want.f32")),
            &reference(request, &codes, input, output),
        );
        cases.push(format!("{name}:{}", output.name()));
    }
    let out = Command::new(reference_python("FILMBACK_OCIO_PYTHON"))
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/lut_check.py"))
        .arg(dir.path())
        .args(&cases)
        .output();
    let Ok(out) = out else {
        println!("lut_check: skipped (no python3 to run OpenColorIO)");
        return;
    };
    let stdout = String::from_utf8_lossy(&out.stdout);
    print!("{stdout}{}", String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "tests/lut_check.py failed");
    assert!(
        stdout.contains("skipped")
            || stdout.lines().filter(|l| l.contains("ok")).count() == cases.len()
    );
}
