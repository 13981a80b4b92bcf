//! The physics a film rendering must hold: the stocks' own speeds, a grey ramp that
//! reproduces the curve, t = 1/2 as exactly one stop, pathological radiance, and the
//! histogram adjustment's contrast ceiling.

use std::path::Path;

use filmback::atomic::Overwrite;
use filmback::display::{luminance, srgb_encode};
use filmback::film::{
    Catalogue, ColourMode, Emulsion, FilmError, Key, Kind, Stock, TABLE_MAX_ERROR_D, render,
    scene_key,
};
use filmback::hdr_output;
use filmback::radiance::RadianceMap;
use filmback::rendering::{self, Format, Look, Outputs, SourceExif};
use filmback::synthetic;
use filmback::tonemap::{HistogramAdjustment, Operator};

fn catalogue() -> Catalogue {
    Catalogue::builtin().expect("built-in stocks are valid")
}

#[test]
fn computed_speed_agrees_with_the_rating_within_a_third_of_a_stop() {
    let mut checked = 0;
    for stock in catalogue().stocks() {
        let speed = stock
            .speed()
            .expect("every built-in curve reaches its speed points");
        let stops = (speed.iso / stock.iso).log2();
        println!(
            "{:<14} rated {:>5} computed {:>7.1} ({:+.2} stops){}",
            stock.id,
            stock.iso,
            speed.iso,
            stops,
            if stock.uncertain.is_some() {
                " [flagged uncertain]"
            } else {
                ""
            }
        );
        if stock.kind == Kind::Reversal && stock.uncertain.is_none() {
            assert!(stops.abs() <= 1.0 / 3.0, "{}: {stops:+.2} stops", stock.id);
            checked += 1;
        }
    }
    assert_eq!(
        checked, 5,
        "Velvia 50/100, Provia 100F, Ektachrome 100, Kodachrome 64"
    );
    // The two flagged stocks are flagged for a reason the numbers show.
    let cat = catalogue();
    let provia = cat.get("provia400").unwrap();
    assert!(provia.uncertain.is_some());
    assert!((provia.speed().unwrap().iso / 400.0).log2() > 1.0 / 3.0);
    assert!(cat.get("p1600").unwrap().uncertain.is_some());
}

fn srgb_decode(v: u16) -> f64 {
    let v = f64::from(v) / 65535.0;
    if v <= 0.04045 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

/// A neutral ramp of `n` pixels, `E_i = 2^(i/16)·2^-40` built from a 16-entry table times
/// exact powers of two, so that `E_{i+16} = 2·E_i` exactly in `f32`.
fn ramp(n: usize) -> RadianceMap {
    let frac: Vec<f32> = (0..16).map(|j| 2f32.powf(j as f32 / 16.0)).collect();
    let mut pixels = Vec::with_capacity(n * 3);
    for i in 0..n {
        let e = frac[i % 16] * 2f32.powi(i as i32 / 16 - 40);
        pixels.extend_from_slice(&[e, e, e]);
    }
    RadianceMap::new(n as u32, 1, 3, pixels).unwrap()
}

#[test]
fn grey_ramp_reproduces_each_stock_curve_and_is_monotone() {
    let map = ramp(16 * 80);
    for stock in catalogue()
        .stocks()
        .iter()
        .filter(|s| s.kind == Kind::Reversal)
    {
        // Meter a grey of 1.0: H = 8/S · E.
        let img = render(&map, stock, 1.0, ColourMode::PerLayer, Key::Grey(1.0)).unwrap();
        let s = img.samples();
        let mut worst = 0.0f64;
        for (i, px) in s.chunks(3).enumerate() {
            let e = f64::from(map.pixels()[i * 3]);
            let log_h = (stock.metered_exposure() * e).log10();
            for c in 0..3 {
                let curve = stock.layer(c);
                let t = srgb_decode(px[c]);
                let d_shown = curve.d_min() - t.max(1e-12).log10();
                // Compare densities where the display still resolves them (T > 1/4000).
                if t > 2.5e-4 {
                    worst = worst.max((d_shown - curve.density(log_h)).abs());
                }
                if i > 0 {
                    assert!(
                        px[c] >= s[(i - 1) * 3 + c],
                        "{} layer {c} not monotone at {i}",
                        stock.id
                    );
                }
            }
        }
        println!(
            "{:<14} worst density error through the display: {worst:.5} D",
            stock.id
        );
        // Table error (≤ 0.001 D) plus 16-bit quantisation of the encoded value.
        assert!(
            worst <= TABLE_MAX_ERROR_D + 0.004,
            "{}: {worst:.4} D",
            stock.id
        );
        // The ramp spans the whole curve: the base (white) at the top.
        assert_eq!(&s[s.len() - 3..], &[65535, 65535, 65535], "{}", stock.id);
    }
}

#[test]
fn half_exposure_is_exactly_one_stop_less_exposure() {
    let cat = catalogue();
    let stock = cat.get("provia400").unwrap();
    let full = Emulsion::new(stock, 1.0, 0.18, ColourMode::PerLayer).unwrap();
    let half = Emulsion::new(stock, 0.5, 0.18, ColourMode::PerLayer).unwrap();
    for c in 0..3 {
        assert_eq!(half.scale[c], full.scale[c] / 2.0);
    }
    let map = ramp(16 * 60);
    let at_full = render(&map, stock, 1.0, ColourMode::PerLayer, Key::Grey(1.0)).unwrap();
    let at_half = render(&map, stock, 0.5, ColourMode::PerLayer, Key::Grey(1.0)).unwrap();
    let (a, b) = (at_full.samples(), at_half.samples());
    for i in 16..map.width() as usize {
        assert_eq!(
            b[i * 3..i * 3 + 3],
            a[(i - 16) * 3..(i - 16) * 3 + 3],
            "pixel {i}"
        );
    }
    // ±ev is the same scale as the fraction.
    let ev: filmback::film::Request = "provia400@-1ev".parse().unwrap();
    assert_eq!(ev.exposure, 0.5);
}

fn poisoned() -> RadianceMap {
    let special = [
        0.0f32,
        1e-40, // subnormal
        f32::MIN_POSITIVE,
        1e30,
        f32::MAX,
        f32::NAN,
        f32::INFINITY,
        f32::NEG_INFINITY,
        -1.0,
    ];
    let mut pixels = Vec::new();
    for &v in &special {
        pixels.extend_from_slice(&[v, v, v]);
    }
    // A pixel poisoned in one channel only, and ordinary grey.
    pixels.extend_from_slice(&[f32::NAN, 0.18, 0.18]);
    pixels.extend_from_slice(&[0.18, f32::INFINITY, 0.18]);
    for _ in 0..5 {
        pixels.extend_from_slice(&[0.18, 0.18, 0.18]);
    }
    RadianceMap::new(16, 1, 3, pixels).unwrap()
}

#[test]
fn pathological_radiance_gives_valid_display_values() {
    let map = poisoned();
    let cat = catalogue();
    for stock in cat.stocks().iter().filter(|s| s.kind == Kind::Reversal) {
        for mode in [
            ColourMode::PerLayer,
            ColourMode::Luminance,
            ColourMode::NeutralGrey,
        ] {
            let img = render(&map, stock, 1.0, mode, Key::LogAverage).unwrap();
            let s = img.samples();
            let px = |i: usize| [s[i * 3], s[i * 3 + 1], s[i * 3 + 2]];
            let black = px(0);
            // No light (0, subnormal, NaN, −∞, negative) is the film's D-max; 1e30, MAX and
            // +∞ are its base (white); none of them panics or wraps.
            for i in [1, 2, 5, 7, 8] {
                assert_eq!(px(i), black, "{} {mode:?} pixel {i}", stock.id);
            }
            for i in [3, 4, 6] {
                assert_eq!(px(i), [65535; 3], "{} {mode:?} pixel {i}", stock.id);
            }
            assert!(
                black.iter().all(|&v| v < 65535 / 8),
                "{} {mode:?} {black:?}",
                stock.id
            );
        }
    }
    for op in [
        Operator::LINEAR,
        Operator::parse("histogram").unwrap(),
        Operator::parse("histogram-naive").unwrap(),
    ] {
        let s = op.apply(&map).samples().to_vec();
        assert_eq!(&s[0..3], &[0, 0, 0], "{op:?}");
        assert_eq!(&s[5 * 3..5 * 3 + 3], &[0, 0, 0], "{op:?} NaN");
        assert_eq!(&s[6 * 3..6 * 3 + 3], &[65535; 3], "{op:?} +inf");
    }
}

#[test]
fn the_key_ignores_pixels_without_finite_light() {
    let clean = ramp(320);
    let mut pixels = clean.pixels().to_vec();
    for (k, i) in (0..pixels.len()).step_by(3 * 7).enumerate() {
        let v = [f32::NAN, f32::INFINITY, 0.0, -3.0][k % 4];
        pixels[i..i + 3].copy_from_slice(&[v, v, v]);
    }
    let dirty = RadianceMap::new(320, 1, 3, pixels.clone()).unwrap();
    let (sum, n) = pixels
        .chunks(3)
        .map(|p| luminance(p[0], p[1], p[2]))
        .filter(|l| l.is_finite() && *l > 0.0)
        .fold((0.0f64, 0usize), |(s, n), l| (s + f64::from(l).ln(), n + 1));
    let expected = (sum / n as f64).exp();
    let key = scene_key(&dirty, Key::LogAverage);
    assert!(key.is_finite() && key > 0.0);
    assert!((key / expected - 1.0).abs() < 1e-9, "{key} vs {expected}");
    let black =
        RadianceMap::new(2, 1, 3, vec![0.0, 0.0, 0.0, f32::NAN, f32::NAN, f32::NAN]).unwrap();
    assert_eq!(scene_key(&black, Key::LogAverage), 1.0);
}

#[test]
fn colour_modes_behave_on_grey() {
    let cat = catalogue();
    let stock = cat.get("velvia50").unwrap();
    let grey = RadianceMap::new(1, 1, 3, vec![0.18; 3]).unwrap();
    let lum = render(&grey, stock, 1.0, ColourMode::Luminance, Key::Grey(0.18)).unwrap();
    let s = lum.samples();
    assert!(
        s[0] == s[1] && s[1] == s[2],
        "luminance mode must stay grey: {s:?}"
    );
    let neutral = render(&grey, stock, 1.0, ColourMode::NeutralGrey, Key::Grey(0.18)).unwrap();
    let n: Vec<f64> = neutral.samples().iter().map(|&v| srgb_decode(v)).collect();
    let spread = n.iter().cloned().fold(f64::NEG_INFINITY, f64::max)
        / n.iter().cloned().fold(f64::INFINITY, f64::min);
    assert!(spread < 1.01, "neutral-grey mode: metered grey {n:?}");
    // The key in luminance mode lands on the green curve at 8/S.
    let expected = srgb_encode(10f32.powf(
        -(stock.layer(1).density(stock.metered_exposure().log10()) - stock.layer(1).d_min()) as f32,
    ));
    assert!((f32::from(s[1]) / 65535.0 - expected).abs() < 2e-3);
}

fn slope_of(curve: &filmback::tonemap::ToneCurve) -> f64 {
    curve.max_log_slope(50_000)
}

#[test]
fn histogram_adjustment_never_exceeds_the_linear_ceiling() {
    for seed in [1, 2, 3] {
        let scene = synthetic::scene(256, 192, seed);
        let lum: Vec<f32> = scene
            .pixels()
            .chunks(3)
            .map(|p| luminance(p[0], p[1], p[2]))
            .collect();
        let full = HistogramAdjustment::default().fit(&lum);
        let s = slope_of(&full);
        println!("seed {seed}: steepest display/world log slope {s:.6}");
        assert!(s <= 1.0 + 1e-5, "seed {seed}: slope {s}");
        let naive = HistogramAdjustment {
            ceiling: false,
            ..Default::default()
        }
        .fit(&lum);
        assert!(
            slope_of(&naive) > 1.0,
            "the naive variant is expected to exaggerate contrast"
        );
    }
}

fn write_stock(dir: &Path, name: &str, text: &str) {
    std::fs::write(dir.join(name), text).unwrap();
}

const USER_STOCK: &str = r#"
id = "myslide"
name = "My slide film"
maker = "Me"
kind = "reversal"
iso = 200
density = "Status A"
source = "measured on my densitometer"
[layers]
red = [[-3.0, 3.0], [-2.0, 2.5], [-1.0, 1.0], [0.0, 0.2]]
green = [[-3.0, 3.1], [-2.0, 2.6], [-1.0, 1.1], [0.0, 0.2]]
blue = [[-3.0, 3.2], [-2.0, 2.7], [-1.0, 1.2], [0.0, 0.2]]
"#;

#[test]
fn user_stock_folder_adds_stocks_and_names_bad_points() {
    let dir = tempfile::tempdir().unwrap();
    write_stock(dir.path(), "myslide.toml", USER_STOCK);
    let cat = catalogue().with_folder(dir.path()).unwrap();
    let mine = cat.get("myslide").unwrap();
    assert_eq!(mine.iso, 200.0);
    assert!(mine.speed().is_some());

    let bad = tempfile::tempdir().unwrap();
    write_stock(
        bad.path(),
        "broken.toml",
        &USER_STOCK.replace("[-1.0, 1.1]", "[-1.0, 2.9]"),
    );
    let err = catalogue().with_folder(bad.path()).unwrap_err();
    let msg = err.to_string();
    assert!(
        msg.contains("broken.toml") && msg.contains("layer green, point 3"),
        "{msg}"
    );

    let dup = tempfile::tempdir().unwrap();
    write_stock(
        dup.path(),
        "v.toml",
        &USER_STOCK.replace("myslide", "velvia50"),
    );
    assert!(matches!(
        catalogue().with_folder(dup.path()),
        Err(FilmError::Duplicate { .. })
    ));

    let syntax = tempfile::tempdir().unwrap();
    write_stock(
        syntax.path(),
        "s.toml",
        &USER_STOCK.replace("iso = 200", "iso = \"fast\""),
    );
    let msg = catalogue()
        .with_folder(syntax.path())
        .unwrap_err()
        .to_string();
    assert!(msg.contains("s.toml") && msg.contains("iso"), "{msg}");

    let two_layers = USER_STOCK.replace("blue = ", "# blue = ");
    let err = Stock::from_toml(&two_layers, Path::new("two.toml")).unwrap_err();
    assert!(err.to_string().contains("blue"), "{err}");
}

#[test]
fn render_all_writes_each_look_atomically_and_refuses_to_clobber() {
    let cat = catalogue();
    let map = synthetic::scene(96, 64, 7);
    let looks = vec![
        Look::film(&cat, "velvia50@1/2", ColourMode::PerLayer, Key::LogAverage).unwrap(),
        Look::film(
            &cat,
            "portra400+cc=05y",
            ColourMode::PerLayer,
            Key::LogAverage,
        )
        .unwrap(),
        Look::Tonemap(Operator::parse("histogram").unwrap()),
    ];
    let dir = tempfile::tempdir().unwrap();
    let exif = SourceExif::default();
    let outputs = Outputs {
        dir: dir.path(),
        stem: "scene",
        format: Format::Png16,
        space: filmback::display::ColourSpace::Srgb,
        overwrite: Overwrite::Refuse,
        exif: &exif,
    };
    let written = rendering::render_all(&map, &looks, &outputs).unwrap();
    let names: Vec<String> = written
        .iter()
        .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
        .collect();
    assert_eq!(
        names,
        [
            "scene.velvia50-t0.5.png",
            "scene.portra400-t1+cc=05y.png",
            "scene.histogram.png"
        ]
    );
    assert!(rendering::render_all(&map, &looks, &outputs).is_err());
    let leftovers = std::fs::read_dir(dir.path()).unwrap().count();
    assert_eq!(leftovers, 3, "no temporary files remain");
    // Kodak gives no RMS granularity for its negatives.
    assert!(
        Look::film(
            &cat,
            "portra400+grain",
            ColourMode::PerLayer,
            Key::LogAverage
        )
        .is_err()
    );
    assert!(Look::film(&cat, "nosuchfilm@1", ColourMode::PerLayer, Key::LogAverage).is_err());
}

#[test]
fn exr_round_trip_through_the_reader() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("map.exr");
    let (w, h) = (24usize, 16usize);
    exr::prelude::write_rgb_file(&path, w, h, |x, y| {
        (x as f32 * 0.5, y as f32 * 0.25, 1e-3 * (x + y) as f32)
    })
    .unwrap();
    let map = hdr_output::read_exr(&path).unwrap();
    assert_eq!((map.width(), map.height(), map.channels()), (24, 16, 3));
    let i = (5 * w + 7) * 3;
    assert_eq!(&map.pixels()[i..i + 3], &[3.5, 1.25, 0.012]);
    let err = hdr_output::read_exr(&dir.path().join("missing.exr")).unwrap_err();
    assert!(err.to_string().contains("missing.exr"));
}

/// CIELAB (D65 white) of an sRGB-encoded 16-bit pixel: IEC 61966-2.1 decoding, the sRGB
/// primaries' RGB → XYZ matrix, then CIE 1976 L*a*b*.
fn lab(px: &[u16]) -> [f64; 3] {
    let [r, g, b] = [0, 1, 2].map(|c| srgb_decode(px[c]));
    let x = 0.4124564 * r + 0.3575761 * g + 0.1804375 * b;
    let y = 0.2126729 * r + 0.7151522 * g + 0.0721750 * b;
    let z = 0.0193339 * r + 0.1191920 * g + 0.9503041 * b;
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

#[test]
fn negative_through_print_is_neutral_at_mid_grey_and_monotone() {
    let cat = catalogue();
    // A grey scale from 8 stops under to 8 stops over the metered grey (E = 1), 16 steps
    // per stop; the ramp's pixel 16·40 is E = 1 exactly.
    let map = ramp(16 * 48);
    let key_pixel = 16 * 40;
    for request in ["portra400", "ektar100", "portra400+paper=portra-endura"] {
        let look = Look::film(&cat, request, ColourMode::PerLayer, Key::Grey(1.0)).unwrap();
        let img = look
            .render(&map, filmback::display::Depth::Sixteen)
            .unwrap();
        let s = img.samples();
        let grey = lab(&s[key_pixel * 3..key_pixel * 3 + 3]);
        println!(
            "{request}: mid grey L* {:.2} a* {:+.2} b* {:+.2}",
            grey[0], grey[1], grey[2]
        );
        for stops in [-2i32, -1, 1, 2] {
            let i = (key_pixel as i32 + 16 * stops) as usize;
            let p = lab(&s[i * 3..i * 3 + 3]);
            println!(
                "  {stops:+} stops: L* {:.1} a* {:+.2} b* {:+.2}",
                p[0], p[1], p[2]
            );
        }
        assert!(
            grey[1].abs() <= 3.0 && grey[2].abs() <= 3.0,
            "{request}: {grey:?}"
        );
        // Printed at the paper's mid grey: 18 % reflectance is L* 49.5.
        assert!((grey[0] - 49.5).abs() < 1.0, "{request}: L* {}", grey[0]);
        let mut prev = f64::NEG_INFINITY;
        let mut prev_px = [0u16; 3];
        for (i, px) in s.chunks(3).enumerate() {
            let l = lab(px)[0];
            assert!(l >= prev - 1e-9, "{request}: L* falls at {i}: {prev} → {l}");
            for c in 0..3 {
                assert!(px[c] >= prev_px[c], "{request}: layer {c} falls at {i}");
            }
            prev = l;
            prev_px = [px[0], px[1], px[2]];
        }
        // Shadow to highlight: near black eight stops under, near paper white over.
        let first = lab(&s[..3])[0];
        assert!(
            first < 15.0 && prev > 90.0,
            "{request}: L* {first} … {prev}"
        );
    }
}

/// The grey scale of every negative on every paper stays grey off the key: CIELAB of the
/// print of a neutral ramp from −2 to +2 stops (16 steps a stop) within |a*|, |b*| ≤ 3.
#[test]
fn negatives_print_a_grey_scale_grey_from_two_stops_under_to_two_over() {
    const LIMIT: f64 = 3.0;
    let cat = catalogue();
    let map = ramp(16 * 48);
    let key_pixel = 16 * 40;
    let mut checked = 0;
    let mut failures = Vec::new();
    for stock in cat.stocks().iter().filter(|s| s.kind == Kind::Negative) {
        for paper in filmback::film::Paper::builtin() {
            let request = format!("{}+paper={}", stock.id, paper.id);
            let look = Look::film(&cat, &request, ColourMode::PerLayer, Key::Grey(1.0)).unwrap();
            let img = look
                .render(&map, filmback::display::Depth::Sixteen)
                .unwrap();
            let s = img.samples();
            let (mut worst_a, mut worst_b) = (0.0f64, 0.0f64);
            let mut profile = String::new();
            for i in key_pixel - 32..=key_pixel + 32 {
                let [_, a, b] = lab(&s[i * 3..i * 3 + 3]);
                worst_a = worst_a.max(a.abs());
                worst_b = worst_b.max(b.abs());
                let stops = (i as f64 - key_pixel as f64) / 16.0;
                profile += &format!(" {stops:+.2}:{a:+.1}/{b:+.1}");
            }
            let at = |stops: i32| {
                let i = (key_pixel as i32 + 16 * stops) as usize;
                lab(&s[i * 3..i * 3 + 3])
            };
            println!(
                "{request}: −1 stop a* {:+.2} b* {:+.2}, +1 stop a* {:+.2} b* {:+.2}; worst over ±2 stops |a*| {worst_a:.2} |b*| {worst_b:.2}",
                at(-1)[1],
                at(-1)[2],
                at(1)[1],
                at(1)[2]
            );
            if !(worst_a <= LIMIT && worst_b <= LIMIT) {
                failures.push(format!(
                    "{request}: |a*| {worst_a:.2}, |b*| {worst_b:.2} within ±2 stops; stops:a*/b*{profile}"
                ));
            }
            checked += 1;
        }
    }
    assert_eq!(checked, 4, "two negatives on two papers");
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn print_exposure_and_filter_pack_move_the_print_as_in_the_darkroom() {
    let cat = catalogue();
    let map = ramp(16 * 48);
    let key_pixel = 16 * 40;
    let grey = |request: &str| {
        let look = Look::film(&cat, request, ColourMode::PerLayer, Key::Grey(1.0)).unwrap();
        let img = look
            .render(&map, filmback::display::Depth::Sixteen)
            .unwrap();
        lab(&img.samples()[key_pixel * 3..key_pixel * 3 + 3])
    };
    let neutral = grey("portra400");
    let darker = grey("portra400+print=+1/2");
    let yellow = grey("portra400+cc=20y");
    println!("neutral {neutral:?}, print +1/2 {darker:?}, cc=20y {yellow:?}");
    assert!(darker[0] < neutral[0] - 5.0, "more print exposure darkens");
    // Adding yellow filtration takes blue light: less yellow dye, a bluer print.
    assert!(yellow[2] < neutral[2] - 5.0, "cc=20y makes the print bluer");
}

/// A uniform `n`×`n` map of radiance 1.
fn uniform(n: u32) -> RadianceMap {
    RadianceMap::new(n, n, 3, vec![1.0; (n * n * 3) as usize]).unwrap()
}

/// RMS granularity as a data sheet measures it: the standard deviation of the mean
/// density over a 48 µm circular aperture (radius `24/pitch` pixels), at centres spaced
/// by the aperture's width so the readings are independent; layer `c`, ×1000.
fn granularity(img: &filmback::display::DisplayImage, c: usize, d_min: f64, pitch_um: f64) -> f64 {
    let s = img.samples();
    let (w, h) = (img.width() as usize, img.height() as usize);
    let density: Vec<f64> = s
        .chunks(3)
        .map(|p| d_min - srgb_decode(p[c]).log10())
        .collect();
    let r = 24.0 / pitch_um;
    let ri = r.ceil() as usize;
    let disc: Vec<(usize, usize)> = (0..=2 * ri)
        .flat_map(|dy| (0..=2 * ri).map(move |dx| (dx, dy)))
        .filter(|&(dx, dy)| {
            let (x, y) = (dx as f64 - ri as f64, dy as f64 - ri as f64);
            x * x + y * y <= r * r
        })
        .collect();
    let mut means = Vec::new();
    for y0 in (0..h - 2 * ri).step_by(2 * ri + 1) {
        for x0 in (0..w - 2 * ri).step_by(2 * ri + 1) {
            let sum: f64 = disc
                .iter()
                .map(|&(dx, dy)| density[(y0 + dy) * w + x0 + dx])
                .sum();
            means.push(sum / disc.len() as f64);
        }
    }
    let mean = means.iter().sum::<f64>() / means.len() as f64;
    let var = means.iter().map(|m| (m - mean).powi(2)).sum::<f64>() / (means.len() - 1) as f64;
    1000.0 * var.sqrt()
}

#[test]
fn grain_measured_through_the_sheets_aperture_matches_the_sheet() {
    let cat = catalogue();
    // 1024 px over 6.144 mm: 6 µm per pixel, a 24 MP 35 mm frame's pixel.
    let n = 1024;
    let pitch_um = 6.0;
    let mut checked = 0;
    for stock in cat.stocks().iter().filter(|s| s.granularity.is_some()) {
        let g = stock.granularity.as_ref().unwrap();
        let green = stock.layer(1);
        // Expose the patch so the green layer sits at the sheet's density.
        let target = green.d_min() + g.net_density(green.d_min());
        let h = 10f64.powf(green.log_h_at(target).expect("the curve reaches it"));
        let key = Key::Grey(stock.metered_exposure() / h);
        let request = format!("{}+grain+format=6.144mm", stock.id);
        let look = Look::film(&cat, &request, ColourMode::PerLayer, key).unwrap();
        let img = look
            .render(&uniform(n), filmback::display::Depth::Sixteen)
            .unwrap();
        let measured = granularity(&img, 1, green.d_min(), pitch_um);
        println!(
            "{:<14} sheet {:>4} measured {measured:.2} ({:+.1} %)",
            stock.id,
            g.rms,
            100.0 * (measured / g.rms - 1.0)
        );
        assert!(
            (measured / g.rms - 1.0).abs() <= 0.15,
            "{}: {measured:.2} against the sheet's {}",
            stock.id,
            g.rms
        );
        checked += 1;
    }
    assert_eq!(
        checked, 5,
        "the five stocks whose sheets give RMS granularity"
    );
}

#[test]
fn grain_is_reproducible_grows_with_density_and_with_pixel_size() {
    let cat = catalogue();
    let stock = cat.get("velvia50").unwrap();
    let green = stock.layer(1);
    let render = |request: &str, net: f64, n: u32| {
        let h = 10f64.powf(green.log_h_at(green.d_min() + net).unwrap());
        let key = Key::Grey(stock.metered_exposure() / h);
        let look = Look::film(&cat, request, ColourMode::PerLayer, key).unwrap();
        look.render(&uniform(n), filmback::display::Depth::Sixteen)
            .unwrap()
    };
    let a = render("velvia50+grain+format=3.072mm", 1.0, 512);
    let b = render("velvia50+grain+format=3.072mm", 1.0, 512);
    let c = render("velvia50+grain+format=3.072mm+seed=2", 1.0, 512);
    assert_eq!(a.samples(), b.samples(), "same seed, same grain");
    assert_ne!(a.samples(), c.samples(), "another seed, other grain");
    // Nutting–Selwyn: σ ∝ √(D − D_min); a quarter of the density, half the granularity.
    let dense = granularity(&a, 1, green.d_min(), 6.0);
    let thin = granularity(
        &render("velvia50+grain+format=3.072mm", 0.25, 512),
        1,
        green.d_min(),
        6.0,
    );
    println!("velvia50 at D-min+1: {dense:.2}; at D-min+0.25: {thin:.2}");
    assert!((thin / dense - 0.5).abs() < 0.1, "{thin} / {dense}");
    // The same 48 µm reading on a frame of half the pixels across (12 µm pixels) is
    // the same granularity: grain scales with the film, not with the pixel.
    let coarse = granularity(
        &render("velvia50+grain+format=6.144mm", 1.0, 512),
        1,
        green.d_min(),
        12.0,
    );
    println!("velvia50 on 12 µm pixels: {coarse:.2}");
    assert!((coarse / 9.0 - 1.0).abs() < 0.2, "{coarse}");
    // Without +grain a uniform patch is uniform.
    let clean = render("velvia50", 1.0, 64);
    assert!(
        clean
            .samples()
            .chunks(3)
            .all(|p| p == &clean.samples()[..3])
    );
}

/// Modulation at `cycles_per_mm` of a slanted edge rendered through `request`, measured
/// as an ISO 12233 slanted-edge reading on the effective exposure: each output value of
/// layer `c` is taken back through the display (sRGB), the print (for a negative: paper
/// curve, printer light) and the stock's curve to log H; the edge's profile is binned at
/// ¼ pixel along its normal, differentiated (line spread), and Fourier transformed.
fn slanted_edge_mtf(cat: &Catalogue, stock: &Stock, c: usize, frequencies: &[f64]) -> Vec<f64> {
    let (w, h) = (512usize, 128usize);
    let pitch_mm = 0.002; // 512 px over 1.024 mm
    let angle = 5f64.to_radians();
    let (low, high) = (1.0f32, 1.5f32);
    let mut pixels = Vec::with_capacity(w * h * 3);
    let edge_x = |y: usize| w as f64 / 2.0 + (y as f64 - h as f64 / 2.0) * angle.tan();
    for y in 0..h {
        for x in 0..w {
            let e = if x as f64 >= edge_x(y) { high } else { low };
            pixels.extend_from_slice(&[e, e, e]);
        }
    }
    let map = RadianceMap::new(w as u32, h as u32, 3, pixels).unwrap();
    let request = format!("{}+mtf+format=1.024mm", stock.id);
    let look = Look::film(cat, &request, ColourMode::PerLayer, Key::Grey(1.22)).unwrap();
    let img = look
        .render(&map, filmback::display::Depth::Sixteen)
        .unwrap();
    let emulsion = look.emulsion(&map).unwrap();
    let paper = filmback::film::Paper::get("endura-premier").unwrap();
    let curve = stock.layer(c);
    let log_h = |v: u16| -> f64 {
        let linear = srgb_decode(v).max(1e-9);
        let d = match (emulsion.printer_light(), emulsion.printing_density()) {
            (Some(light), Some(printing)) => {
                let pc = paper.layer(c);
                let x = pc.log_h_at(pc.d_min() - linear.log10()).unwrap();
                printing.status_m(c, light[c] - x)
            }
            _ => curve.d_min() - linear.log10(),
        };
        curve.log_h_at(d).unwrap()
    };
    let s = img.samples();
    let bins = 4.0;
    let reach = 240.0;
    let nbins = (2.0 * reach * bins) as usize;
    let mut sum = vec![0.0; nbins];
    let mut count = vec![0usize; nbins];
    for y in 0..h {
        for x in 0..w {
            let d = (x as f64 - edge_x(y)) * angle.cos();
            let b = ((d + reach) * bins).floor();
            if b >= 0.0 && (b as usize) < nbins {
                sum[b as usize] += 10f64.powf(log_h(s[(y * w + x) * 3 + c]));
                count[b as usize] += 1;
            }
        }
    }
    let esf: Vec<f64> = sum
        .iter()
        .zip(&count)
        .map(|(s, &n)| s / n.max(1) as f64)
        .collect();
    assert!(count.iter().all(|&n| n > 0), "every bin sampled");
    let lsf: Vec<f64> = esf.windows(2).map(|p| p[1] - p[0]).collect();
    let total: f64 = lsf.iter().sum();
    frequencies
        .iter()
        .map(|f| {
            let (mut re, mut im) = (0.0, 0.0);
            for (k, v) in lsf.iter().enumerate() {
                let x_mm = k as f64 / bins * pitch_mm;
                let phase = 2.0 * std::f64::consts::PI * f * x_mm;
                re += v * phase.cos();
                im += v * phase.sin();
            }
            (re * re + im * im).sqrt() / total
        })
        .collect()
}

#[test]
fn slanted_edge_mtf_matches_the_sheet_at_10_20_40_cycles_per_mm() {
    let cat = catalogue();
    let frequencies = [10.0, 20.0, 40.0];
    let mut checked = 0;
    for stock in cat.stocks().iter().filter(|s| s.mtf.is_some()) {
        let mtf = stock.mtf.as_ref().unwrap();
        for c in 0..3 {
            let measured = slanted_edge_mtf(&cat, stock, c, &frequencies);
            let fit = filmback::film::optics::MtfFit::new(mtf, c);
            for (f, m) in frequencies.iter().zip(&measured) {
                let sheet = mtf.response(c, *f);
                println!(
                    "{:<14} layer {c} {f:>4} c/mm: sheet {:>5.1} % measured {:>5.1} % ({:+.1} %), fit's worst {:.1} pt",
                    stock.id,
                    100.0 * sheet,
                    100.0 * m,
                    100.0 * (m / sheet - 1.0),
                    100.0 * fit.worst_error
                );
                assert!(
                    (m / sheet - 1.0).abs() <= 0.10,
                    "{} layer {c} at {f} c/mm: {m:.3} against {sheet:.3}",
                    stock.id
                );
            }
            checked += 1;
        }
    }
    assert_eq!(
        checked, 21,
        "seven stocks with an MTF sheet, three layers each"
    );
}

#[test]
fn halation_is_a_red_glow_around_highlights_only_when_asked() {
    let cat = catalogue();
    // A dark frame (E = 0.05) with a small sun (E = 1e4) in the middle; 35 mm at 2 µm
    // per pixel would be enormous, so the frame is 2.56 mm wide: 10 µm pixels.
    let n = 256usize;
    let mut pixels = vec![0.05f32; n * n * 3];
    for y in 126..130 {
        for x in 126..130 {
            pixels[(y * n + x) * 3..(y * n + x) * 3 + 3].copy_from_slice(&[1e4; 3]);
        }
    }
    let map = RadianceMap::new(n as u32, n as u32, 3, pixels).unwrap();
    let render = |request: &str| {
        let look = Look::film(&cat, request, ColourMode::PerLayer, Key::Grey(0.18)).unwrap();
        look.render(&map, filmback::display::Depth::Sixteen)
            .unwrap()
    };
    let plain = render("velvia50+format=2.56mm");
    let halo = render("velvia50+format=2.56mm+halation=0.05");
    // 100 µm from the sun's edge (10 px): brighter in red, less in green, not in blue.
    let at = |img: &filmback::display::DisplayImage, x: usize| {
        let i = (128 * n + x) * 3;
        let s = img.samples();
        [s[i], s[i + 1], s[i + 2]]
    };
    let (p, q) = (at(&plain, 140), at(&halo, 140));
    println!("100 µm from the sun: plain {p:?}, halation {q:?}");
    assert!(q[0] > p[0] + 2000, "red glows");
    assert!(q[1] > p[1] && q[1] - p[1] < q[0] - p[0], "green glows less");
    assert_eq!(q[2], p[2], "blue untouched");
    // Far from the sun (1 mm), nothing (within one 16-bit step of the tables).
    let (far_p, far_q) = (at(&plain, 10), at(&halo, 10));
    println!("1.2 mm from the sun: plain {far_p:?}, halation {far_q:?}");
    assert!((0..3).all(|c| far_p[c].abs_diff(far_q[c]) <= 2));
    // Without +halation, the dark frame stays uniform next to the sun's edge.
    assert_eq!(at(&plain, 140), at(&plain, 200));
}
