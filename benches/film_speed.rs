//! 24 MP radiance map in memory → film rendering → encoded JPEG (target ≤ 0.4 s on the
//! 2-core machine), per colour mode and JPEG quality, with the error each knob costs; the
//! `image` crate's JPEG encoder for comparison; and the peer (OpenCV's Reinhard tone map +
//! JPEG q95, the same calls as `shared/peer/opencv_merge.py`) on the same map, as a ratio.
//!
//! `cargo bench --bench film_speed` (set FILMBACK_PEER_PYTHON to the peer's venv python;
//! default `/tmp/filmback-peer-venv/bin/python`, skipped when absent).

use std::hint::black_box;
use std::path::Path;
use std::time::{Duration, Instant};

use filmback::display::ColourSpace::Srgb;
use filmback::display::Depth;
use filmback::film::{self, Catalogue, ColourMode, Key};
use filmback::radiance::RadianceMap;
use filmback::rendering::{self, Format, Look, SourceExif};
use filmback::synthetic;

const RUNS: usize = 3;

fn best<T>(mut f: impl FnMut() -> T) -> (Duration, T) {
    let mut best = Duration::MAX;
    let mut last = None;
    for _ in 0..RUNS {
        let start = Instant::now();
        let out = black_box(f());
        best = best.min(start.elapsed());
        last = Some(out);
    }
    (best, last.expect("RUNS > 0"))
}

/// Grain, MTF and printing: the extra time each costs on the 24 MP map (developed to
/// 8 bits, the optics pass included, key metered once outside the timing), and a colour
/// negative through its print against a reversal stock. `cargo bench --bench film_speed
/// -- options` runs only this part.
fn film_options(map: &RadianceMap, catalogue: &Catalogue) {
    let key = film::scene_key(map, Key::LogAverage);
    let time = |request: &str| {
        let r: film::Request = request.parse().expect("request");
        let stock = catalogue.get(&r.stock).expect("stock");
        let (t, _) = best(|| {
            let emulsion = film::Emulsion::with_options(
                stock,
                r.exposure,
                key,
                ColourMode::PerLayer,
                &r.options,
                (map.width(), map.height()),
            )
            .expect("emulsion");
            emulsion.render(map, Depth::Eight)
        });
        t
    };
    println!("film options, 8-bit development of the whole map (ms, best of {RUNS}):");
    let base = time("velvia50");
    println!("  {:<28} {:>8.1}", "velvia50", ms(base));
    for request in [
        "velvia50+grain",
        "velvia50+mtf",
        "velvia50+grain+mtf",
        "velvia50+halation",
    ] {
        let t = time(request);
        println!(
            "  {request:<28} {:>8.1}  (+{:.1} ms)",
            ms(t),
            ms(t.saturating_sub(base))
        );
    }
    for request in ["portra400", "ektar100"] {
        let t = time(request);
        println!(
            "  {request:<28} {:>8.1}  ({:.2}× velvia50)",
            ms(t),
            t.as_secs_f64() / base.as_secs_f64()
        );
    }
    let stock = catalogue.get("velvia50").expect("velvia50");
    let mtf = stock.mtf.as_ref().expect("velvia50 has an MTF sheet");
    let fit = film::optics::MtfFit::new(mtf, 1);
    println!(
        "  MTF as {} Gaussians: worst {:.1} points from the sheet's points",
        fit.terms.len(),
        100.0 * fit.worst_error
    );
    optics_psnr(catalogue);
}

/// PSNR of the fast optics ([`film::optics::filter`]) against the direct sum of sampled
/// Gaussians ([`film::optics::filter_direct`]), both developed through the same emulsion
/// to 8 bits, on a 3000×2000 map of an 18 mm format (the 24 MP map's 6 µm pixels).
fn optics_psnr(catalogue: &Catalogue) {
    let (w, h) = (3000usize, 2000usize);
    let map = synthetic::scene(w as u32, h as u32, 2);
    let key = film::scene_key(&map, Key::LogAverage);
    let pitch_mm = 18.0 / w as f64;
    let expose = |terms: &dyn Fn(usize) -> Vec<Vec<(f64, f64)>>, direct: bool| {
        let mut out = vec![0f32; w * h * 3];
        for c in 0..3 {
            let mut plane: Vec<f32> = map
                .pixels()
                .iter()
                .skip(c)
                .step_by(3)
                .map(|v| v.max(0.0))
                .collect();
            for t in terms(c) {
                plane = if direct {
                    film::optics::filter_direct(&plane, w, h, &t)
                } else {
                    film::optics::filter(&plane, w, h, &t)
                };
            }
            for (o, v) in out.iter_mut().skip(c).step_by(3).zip(plane) {
                *o = v.max(0.0);
            }
        }
        RadianceMap::new(w as u32, h as u32, 3, out).expect("shape")
    };
    println!("  fast optics against the direct convolution, 3000×2000 at 6 µm, 8-bit rendering:");
    for stock_id in ["velvia50", "provia100f", "portra400"] {
        let stock = catalogue.get(stock_id).expect("stock");
        let mtf = stock.mtf.as_ref().expect("MTF sheet");
        let fits = [0, 1, 2].map(|c| film::optics::MtfFit::new(mtf, c));
        let emulsion =
            film::Emulsion::new(stock, 1.0, key, ColourMode::PerLayer).expect("emulsion");
        let mtf_terms = |c: usize| vec![fits[c].terms_px(pitch_mm)];
        let halo_terms = |c: usize| {
            let s = [film::DEFAULT_HALATION, film::DEFAULT_HALATION / 4.0, 0.0][c];
            let sigma = film::optics::HALATION_SIGMA_MM / pitch_mm;
            if s > 0.0 {
                vec![film::optics::halation_terms(s, sigma)]
            } else {
                vec![]
            }
        };
        for (name, terms) in [
            ("mtf", &mtf_terms as &dyn Fn(usize) -> _),
            ("halation", &halo_terms),
        ] {
            let (t_fast, fast) = best(|| expose(terms, false));
            let start = Instant::now();
            let direct = expose(terms, true);
            let t_direct = start.elapsed();
            let a = emulsion.render(&fast, Depth::Eight).to_u8().into_owned();
            let b = emulsion.render(&direct, Depth::Eight).to_u8().into_owned();
            println!(
                "    {stock_id:<11} +{name:<9} fast {:>7.1} ms, direct {:>8.1} ms ({:.0}×), PSNR {:.1} dB",
                ms(t_fast),
                ms(t_direct),
                t_direct.as_secs_f64() / t_fast.as_secs_f64(),
                psnr_u8(&b, &a)
            );
        }
    }
    println!();
}

/// PSNR (dB) of two 8-bit images (∞ when identical).
fn psnr_u8(reference: &[u8], other: &[u8]) -> f64 {
    let se: f64 = reference
        .iter()
        .zip(other)
        .map(|(&a, &b)| (f64::from(a) - f64::from(b)).powi(2))
        .sum();
    10.0 * (255.0f64 * 255.0 / (se / reference.len() as f64)).log10()
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// PSNR (dB) of a decoded JPEG against the 8-bit image it encoded.
fn psnr(reference: &[u8], jpeg: &[u8]) -> f64 {
    let decoded = image::load_from_memory(jpeg)
        .expect("our JPEG decodes")
        .to_rgb8();
    let se: f64 = reference
        .iter()
        .zip(decoded.as_raw())
        .map(|(&a, &b)| (f64::from(a) - f64::from(b)).powi(2))
        .sum();
    let mse = se / reference.len() as f64;
    10.0 * (255.0f64 * 255.0 / mse).log10()
}

/// `cargo bench --bench film_speed -- look REQUEST [WIDTH HEIGHT [RUNS]]`: develops one
/// look of the synthetic scene to 8 bits `RUNS` times (default 6000 × 4000, 1 run) and
/// prints each time, for a profiler (`perf record`, `valgrind --tool=callgrind`): a
/// look's instruction count minus plain `velvia50`'s at the same size is what its options
/// cost. With `FILMBACK_LOOK_DUMP=PATH` the last rendering's 8-bit RGB is written to
/// `PATH` (to compare two builds' output).
fn one_look(args: &[String]) {
    let request = args.first().map_or("velvia50", String::as_str);
    let number = |i: usize, default: u32| {
        args.get(i)
            .map_or(default, |v| v.parse().expect("a whole number"))
    };
    let (w, h, runs) = (number(1, 6000), number(2, 4000), number(3, 1));
    let map = synthetic::scene(w, h, 1);
    let catalogue = Catalogue::builtin().expect("built-in stocks");
    let r: film::Request = request.parse().expect("request");
    let stock = catalogue.get(&r.stock).expect("stock");
    let key = film::scene_key(&map, Key::LogAverage);
    for _ in 0..runs {
        let start = Instant::now();
        let emulsion = film::Emulsion::with_options(
            stock,
            r.exposure,
            key,
            ColourMode::PerLayer,
            &r.options,
            (w, h),
        )
        .expect("emulsion");
        let image = black_box(emulsion.render(&map, Depth::Eight));
        println!("{request} {w}×{h}: {:.1} ms", ms(start.elapsed()));
        if let Ok(path) = std::env::var("FILMBACK_LOOK_DUMP") {
            std::fs::write(&path, image.to_u8()).expect("dump written");
        }
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if let Some(i) = args.iter().position(|a| a == "look") {
        one_look(&args[i + 1..]);
        return;
    }
    let (w, h) = (6000u32, 4000u32);
    println!(
        "film_speed: {w}×{h} ({:.0} MP) synthetic scene, {} rayon threads, best of {RUNS}",
        f64::from(w * h) / 1e6,
        rayon::current_num_threads()
    );
    let start = Instant::now();
    let map = synthetic::scene(w, h, 1);
    println!(
        "scene built in {:.0} ms (not timed below)\n",
        ms(start.elapsed())
    );
    let catalogue = Catalogue::builtin().expect("built-in stocks");
    if std::env::args().any(|a| a == "looks") {
        looks_alone(&map, &catalogue);
        return;
    }
    if std::env::args().any(|a| a == "tonemaps") {
        tone_maps(&map);
        return;
    }
    film_options(&map, &catalogue);
    if std::env::args().any(|a| a == "options") {
        return;
    }
    let stock = catalogue.get("velvia50").expect("velvia50");

    println!(
        "{:<12} {:>7} {:>8} {:>12} {:>9} {:>10} {:>11} {:>9} {:>9}",
        "colour",
        "quality",
        "key ms",
        "film→8bit ms",
        "jpeg ms",
        "serial ms",
        "streamed ms",
        "PSNR dB",
        "PSNR str"
    );
    let exif = SourceExif::default();
    let mut reference_u8 = Vec::new();
    let mut ours_q95 = Duration::ZERO;
    for (mode, name) in [
        (ColourMode::PerLayer, "per-layer"),
        (ColourMode::Luminance, "luminance"),
        (ColourMode::NeutralGrey, "neutral"),
    ] {
        for quality in [85u8, 92, 95] {
            let (t_key, key) = best(|| film::scene_key(&map, Key::LogAverage));
            let emulsion = film::Emulsion::new(stock, 1.0, key, mode).expect("reversal");
            let (t_film, image) = best(|| emulsion.render(&map, Depth::Eight));
            let rgb = image.to_u8().into_owned();
            let (t_jpeg, jpeg) = best(|| {
                let mut out = Vec::with_capacity(8 << 20);
                rendering::encode(&image, Format::Jpeg { quality }, &exif, &mut out)
                    .expect("encodes");
                out
            });
            // End to end in one go, as `render_all` does it (key + film + 8-bit + JPEG).
            let look = Look::Film {
                stock: Box::new(stock.clone()),
                exposure: 1.0,
                colour: mode,
                key: Key::LogAverage,
                options: Box::default(),
            };
            // End to end as `render_all` does it: key, then developing streamed into the
            // encoder (developing on one core while the encoder runs on the other) …
            let (t_total, streamed) = best(|| {
                let mut out = Vec::with_capacity(8 << 20);
                rendering::encode_look(
                    &map,
                    &look,
                    Format::Jpeg { quality },
                    Srgb,
                    &exif,
                    &mut out,
                )
                .expect("encodes");
                out
            });
            // … against the two stages one after the other.
            let (t_serial, _) = best(|| {
                let image = look.render(&map, Depth::Eight).expect("renders");
                let mut out = Vec::with_capacity(8 << 20);
                rendering::encode(&image, Format::Jpeg { quality }, &exif, &mut out)
                    .expect("encodes");
                out.len()
            });
            println!(
                "{name:<12} {quality:>7} {:>8.1} {:>12.1} {:>9.1} {:>10.1} {:>11.1} {:>9.2} {:>9.2}",
                ms(t_key),
                ms(t_film),
                ms(t_jpeg),
                ms(t_serial),
                ms(t_total),
                psnr(&rgb, &jpeg),
                psnr(&rgb, &streamed)
            );
            if mode == ColourMode::PerLayer && quality == 95 {
                ours_q95 = t_total;
                reference_u8 = rgb;
            }
        }
    }
    let mut worst = 0.0f64;
    for c in 0..3 {
        let curve = stock.layer(c);
        let table = film::ExposureTable::new(curve, |d| d);
        let (a, b) = curve.log_h_range();
        for i in 0..100_000 {
            let h = 10f64.powf(a + (b - a) * f64::from(i) / 1e5) as f32;
            worst = worst.max((table.get(h) - curve.density(f64::from(h).log10())).abs());
        }
    }
    println!(
        "\ndensity table ({}): worst {worst:.2e} D over 100k exposures per layer (stated bound {} D)",
        stock.id,
        film::TABLE_MAX_ERROR_D
    );

    // The `image` crate's baseline encoder on the same 8-bit buffer, quality 95.
    let (t_ours, ours) = best(|| {
        let mut out = Vec::new();
        rusty_jpeg::encode::Encoder::new(&mut out, 95)
            .encode(
                &reference_u8,
                w as u16,
                h as u16,
                rusty_jpeg::encode::ColorType::Rgb,
            )
            .expect("encodes");
        out
    });
    let (t_image, theirs) = best(|| {
        let mut out = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, 95)
            .encode(&reference_u8, w, h, image::ExtendedColorType::Rgb8)
            .expect("encodes");
        out
    });
    println!("\nJPEG encoder, q95, same 8-bit 24 MP buffer:");
    println!(
        "  rusty_jpeg (simd)     {:>7.1} ms  {:>6.2} MB  PSNR {:.2} dB",
        ms(t_ours),
        ours.len() as f64 / 1e6,
        psnr(&reference_u8, &ours)
    );
    println!(
        "  image::JpegEncoder    {:>7.1} ms  {:>6.2} MB  PSNR {:.2} dB   ({:.2}× slower)",
        ms(t_image),
        theirs.len() as f64 / 1e6,
        psnr(&reference_u8, &theirs),
        t_image.as_secs_f64() / t_ours.as_secs_f64()
    );

    tone_maps(&map);
    peer(&map, ours_q95);
}

/// Each look alone on the 24 MP map, as `render_all` makes it (key, developing streamed
/// into a q92 JPEG, the daemon's default), against the JPEG encoder alone on the same
/// look's 8-bit image, in the same run: the difference is what the look itself costs
/// (issue 16's target: at most 150 ms plus its encoder). `cargo bench --bench film_speed
/// -- looks` runs only this part.
fn looks_alone(map: &RadianceMap, catalogue: &Catalogue) {
    let exif = SourceExif::default();
    let format = Format::Jpeg { quality: 92 };
    let mut looks: Vec<(String, Look)> = catalogue
        .stocks()
        .iter()
        .map(|stock| {
            let look = Look::Film {
                stock: Box::new(stock.clone()),
                exposure: 1.0,
                colour: ColourMode::PerLayer,
                key: Key::LogAverage,
                options: Box::default(),
            };
            (stock.id.clone(), look)
        })
        .collect();
    for name in ["linear", "histogram", "histogram-naive"] {
        let op = filmback::tonemap::Operator::parse(name).expect("known operator");
        looks.push((name.to_string(), Look::Tonemap(op)));
    }
    println!("each look alone, 24 MP → JPEG q92 (ms, best of {RUNS}):");
    println!(
        "  {:<16} {:>9} {:>12} {:>12}",
        "look", "look+JPEG", "JPEG alone", "difference"
    );
    for (name, look) in &looks {
        let (t_all, _) = best(|| {
            let mut out = Vec::with_capacity(8 << 20);
            rendering::encode_look(map, look, format, Srgb, &exif, &mut out).expect("encodes");
            out.len()
        });
        let image = look.render(map, Depth::Eight).expect("renders");
        let (t_jpeg, _) = best(|| {
            let mut out = Vec::with_capacity(8 << 20);
            rendering::encode(&image, format, &exif, &mut out).expect("encodes");
            out.len()
        });
        println!(
            "  {name:<16} {:>9.1} {:>12.1} {:>+12.1}",
            ms(t_all),
            ms(t_jpeg),
            ms(t_all) - ms(t_jpeg)
        );
        if name == "velvia50" {
            // The same image through one `rusty_jpeg` encoder on one thread (the file before
            // banding), for the encoder's own speed-up.
            let rgb = image.to_u8();
            let (t_single, _) = best(|| {
                let mut out = Vec::with_capacity(8 << 20);
                let encoder = rusty_jpeg::encode::Encoder::new(&mut out, 92);
                let (w, h) = (map.width() as u16, map.height() as u16);
                encoder
                    .encode(&rgb, w, h, rusty_jpeg::encode::ColorType::Rgb)
                    .expect("encodes");
                out.len()
            });
            println!(
                "  {:<16} {:>9} {:>12.1}   (banded encoder: {:.2}× faster)",
                "  one thread",
                "",
                ms(t_single),
                ms(t_single) / ms(t_jpeg)
            );
        }
        if let Look::Tonemap(op) = look {
            // The streamed measurement against the direct one, 8-bit RGB over the map.
            let render = |tone: filmback::tonemap::Tone| {
                let mut rgb = vec![0u8; map.pixels().len() / map.channels() * 3];
                tone.render_rows_8bit(map, 0, &mut rgb);
                rgb
            };
            let ours = render(op.prepare(map));
            let direct = render(op.prepare_exact(map));
            println!(
                "  {:<16} PSNR {:.1} dB against the direct measurement",
                "",
                psnr_u8(&direct, &ours)
            );
        }
    }
}

/// The tone maps (no knob of their own beyond the operator): map → encoded JPEG q92, the
/// daemon's default quality, split into the operator (to 16-bit display values) and the
/// rest (8-bit conversion and encoding).
fn tone_maps(map: &RadianceMap) {
    println!("\ntone maps, 24 MP → JPEG q92 (best of {RUNS}):");
    for name in ["linear", "histogram", "histogram-naive"] {
        let op = filmback::tonemap::Operator::parse(name).expect("known operator");
        let (t_apply, _) = best(|| op.apply(map));
        let (t_prepare, _) = best(|| op.prepare(map));
        let (t_exact, _) = best(|| op.prepare_exact(map));
        println!(
            "  {name:<16} measuring the map: streamed histogram {:>7.1} ms, direct {:>7.1} ms ({:.2}×)",
            ms(t_prepare),
            ms(t_exact),
            ms(t_exact) / ms(t_prepare)
        );
        let look = Look::Tonemap(op);
        let (t_all, bytes) = best(|| {
            let mut out = Vec::new();
            rendering::encode_look(
                map,
                &look,
                Format::Jpeg { quality: 92 },
                Srgb,
                &SourceExif::default(),
                &mut out,
            )
            .expect("encodes");
            out
        });
        println!(
            "  {name:<16} operator {:>7.1} ms   total {:>7.1} ms   {:.2} MB",
            ms(t_apply),
            ms(t_all),
            bytes.len() as f64 / 1e6
        );
        // The table against the curve itself: the display value of every pixel's
        // luminance, sRGB-encoded to 8 bits (the chromaticity step is the same for both).
        if let filmback::tonemap::Operator::Histogram(h) = op {
            let lum: Vec<f32> = map
                .pixels()
                .chunks(3)
                .map(|p| filmback::display::luminance(p[0], p[1], p[2]))
                .collect();
            let curve = h.fit(&lum);
            let table = filmback::tonemap::CurveTable::new(&curve);
            let code = |v: f32| filmback::display::to_8bit(filmback::display::srgb_encode_u16(v));
            let (direct, tabled): (Vec<u8>, Vec<u8>) = lum
                .iter()
                .filter(|l| l.is_finite() && **l > 0.0)
                .step_by(7)
                .map(|&l| (code(curve.display_value(l)), code(table.get(l))))
                .unzip();
            println!(
                "    table against the curve: PSNR {:.1} dB (8-bit grey)",
                psnr_u8(&direct, &tabled)
            );
        }
    }
}

/// The peer's tone-map + JPEG stage on the same map: `cv2.createTonemapReinhard(2.2)` and a
/// q95 JPEG, timed inside Python (load excluded).
fn peer(map: &RadianceMap, ours: Duration) {
    let python = std::env::var("FILMBACK_PEER_PYTHON")
        .unwrap_or_else(|_| "/tmp/filmback-peer-venv/bin/python".into());
    if !Path::new(&python).exists() {
        println!("\npeer: skipped ({python} absent; run shared/peer/setup.sh)");
        return;
    }
    let dir = std::env::temp_dir().join(format!("filmback-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let raw = dir.join("map.f32");
    // OpenCV wants BGR.
    let bgr: Vec<u8> = map
        .pixels()
        .chunks(3)
        .flat_map(|p| [p[2], p[1], p[0]])
        .flat_map(f32::to_le_bytes)
        .collect();
    std::fs::write(&raw, &bgr).expect("write raw map");
    let script = format!(
        r#"
import time, numpy as np, cv2
hdr = np.fromfile({raw:?}, dtype='<f4').reshape({h}, {w}, 3)
best = 1e9
for _ in range({RUNS}):
    t = time.perf_counter()
    ldr = cv2.createTonemapReinhard(2.2).process(hdr)
    ok, buf = cv2.imencode('.jpg', np.clip(np.nan_to_num(ldr) * 255 + 0.5, 0, 255).astype(np.uint8), [cv2.IMWRITE_JPEG_QUALITY, 95])
    best = min(best, time.perf_counter() - t)
print(best * 1000)
"#,
        raw = raw.display().to_string(),
        h = map.height(),
        w = map.width(),
    );
    let out = std::process::Command::new(&python)
        .arg("-c")
        .arg(script)
        .output();
    let _ = std::fs::remove_dir_all(&dir);
    match out {
        Ok(o) if o.status.success() => {
            let peer_ms: f64 = String::from_utf8_lossy(&o.stdout)
                .trim()
                .parse()
                .unwrap_or(f64::NAN);
            println!(
                "\npeer (OpenCV Reinhard + JPEG q95): {peer_ms:.1} ms; filmback film + JPEG q95 (streamed): {:.1} ms; ratio peer/filmback {:.2}×",
                ms(ours),
                peer_ms / ms(ours)
            );
        }
        Ok(o) => println!("\npeer: failed: {}", String::from_utf8_lossy(&o.stderr)),
        Err(e) => println!("\npeer: cannot run {python}: {e}"),
    }
}
