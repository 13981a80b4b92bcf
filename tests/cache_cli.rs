//! `filmback cache show CAMERA --plot FILE.png`: the cached curve drawn with the g panel of
//! `calibrate --plot`, published atomically, replaced on a second run (as calibrate's plot
//! is), and a clear error when the folder does not exist.

use std::path::Path;
use std::process::Output;

use filmback::daemon::bracket::CameraId;
use filmback::daemon::cache::{CachedResponse, ResponseCache};
use filmback::response::InverseResponse;
use image::RgbImage;

use crate::common;
use common::filmback;

/// Panel width of the figure (one panel per channel) and its height (title strip + panel).
const PANEL_W: u32 = 300;
const HEIGHT: u32 = 256;

fn camera() -> CameraId {
    CameraId {
        make: Some("Canon".to_string()),
        model: Some("Canon EOS R5".to_string()),
        serial: Some("042".to_string()),
    }
}

/// A state folder whose cache holds an sRGB curve of `channels` channels for [`camera`].
fn state_with_entry(dir: &Path, channels: usize) {
    ResponseCache::new(dir)
        .put(&CachedResponse {
            camera: camera(),
            response: InverseResponse::srgb(channels, 1024),
            confidence: vec![0.8; channels],
            brackets: 3,
            updated: 1_700_000_000,
            pool: Vec::new(),
            dissent: Vec::new(),
            measured: None,
        })
        .unwrap();
}

fn cache(state: &Path, args: &[&std::ffi::OsStr]) -> Output {
    filmback()
        .arg("cache")
        .arg("--state")
        .arg(state)
        .args(args)
        .output()
        .unwrap()
}

fn show_plot(state: &Path, camera: &str, png: &Path) -> Output {
    cache(
        state,
        &[
            "show".as_ref(),
            camera.as_ref(),
            "--plot".as_ref(),
            png.as_os_str(),
        ],
    )
}

fn assert_success(out: &Output) {
    assert!(
        out.status.success(),
        "status {:?}\nstdout: {}\nstderr: {}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Columns (x) of the pixels matching `is`, per panel of width [`PANEL_W`].
fn columns_per_panel(image: &RgbImage, is: impl Fn([u8; 3]) -> bool) -> Vec<usize> {
    let mut per_panel = vec![0; (image.width() / PANEL_W) as usize + 1];
    for (x, _, p) in image.enumerate_pixels() {
        if is(p.0) {
            per_panel[(x / PANEL_W) as usize] += 1;
        }
    }
    per_panel
}

#[test]
fn show_plot_draws_each_channel_in_its_colour_and_replaces_on_rerun() {
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("state");
    state_with_entry(&state, 3);
    let png = dir.path().join("out.png");

    let out = show_plot(&state, "eos r5", &png);
    assert_success(&out);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("Canon EOS R5 #042"), "{stdout}");
    assert!(stdout.contains(&png.display().to_string()), "{stdout}");

    let figure = image::open(&png).unwrap().to_rgb8();
    assert_eq!((figure.width(), figure.height()), (3 * PANEL_W, HEIGHT));
    // R, G and B curves, each in its own panel (left to right), none elsewhere.
    let red = columns_per_panel(&figure, |[r, g, b]| r > 180 && g < 80 && b < 80);
    let green = columns_per_panel(&figure, |[r, g, b]| g > 120 && r < 60 && b < 80);
    let blue = columns_per_panel(&figure, |[r, g, b]| b > 180 && r < 60 && g < 100);
    for (k, counts) in [red, green, blue].iter().enumerate() {
        for (panel, &n) in counts.iter().enumerate() {
            if panel == k {
                // The curve spans the panel: at least one pixel per plotted column.
                assert!(n > 200, "channel {k}: only {n} curve pixels in its panel");
            } else {
                assert_eq!(n, 0, "channel {k}'s colour in panel {panel}");
            }
        }
    }
    // The sRGB curve is convex: at B = 0.5 it is near g = 0.21, well below the diagonal.
    // In the R panel (plot area x 34..290, y 48..234), find the curve at the middle column.
    let x_mid = 34 + (290 - 34) / 2;
    let ys: Vec<u32> = (0..figure.height())
        .filter(|&y| {
            let [r, g, b] = figure.get_pixel(x_mid, y).0;
            r > 180 && g < 80 && b < 80
        })
        .collect();
    assert!(!ys.is_empty(), "no R curve pixel at the middle column");
    let g_at_mid = (234.0 - f64::from(ys[0])) / (234.0 - 48.0);
    assert!(
        (g_at_mid - 0.214).abs() < 0.03,
        "g(0.5) drawn at {g_at_mid}"
    );

    // Second run without removing the file: replaced, like `calibrate --plot` does.
    std::fs::write(&png, b"not a png").unwrap();
    let out = show_plot(&state, "eos r5", &png);
    assert_success(&out);
    let again = image::open(&png).unwrap().to_rgb8();
    assert_eq!(again, figure, "the rerun draws the same figure");
    let names: Vec<String> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(
        names.iter().all(|n| !n.contains("filmback-tmp")),
        "temporary file left behind: {names:?}"
    );
}

#[test]
fn show_plot_of_a_grey_response_is_one_grey_curve() {
    let dir = tempfile::tempdir().unwrap();
    state_with_entry(dir.path(), 1);
    let png = dir.path().join("grey.png");
    assert_success(&show_plot(dir.path(), "canon", &png));
    let figure = image::open(&png).unwrap().to_rgb8();
    // One panel; wider than it only if the title needs the room.
    assert!(figure.width() >= PANEL_W, "{}", figure.width());
    assert_eq!(figure.height(), HEIGHT);
    let grey = figure
        .pixels()
        .filter(|p| {
            let [r, g, b] = p.0;
            r == g && g == b && (80..=150).contains(&r)
        })
        .count();
    assert!(grey > 200, "only {grey} grey curve pixels");
    let coloured = figure
        .pixels()
        .filter(|p| {
            let [r, g, b] = p.0;
            r.max(g).max(b) - r.min(g).min(b) > 60
        })
        .count();
    assert_eq!(coloured, 0, "a grey response has no coloured curve");
}

#[test]
fn show_plot_into_a_missing_folder_names_the_path() {
    let dir = tempfile::tempdir().unwrap();
    state_with_entry(dir.path(), 3);
    let png = dir.path().join("no-such-folder").join("out.png");
    let out = show_plot(dir.path(), "eos r5", &png);
    assert!(!out.status.success(), "{out:?}");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains(&png.display().to_string()), "{stderr}");
    assert!(stderr.contains("cannot write"), "{stderr}");
    assert!(!png.exists());
    assert!(!png.parent().unwrap().exists());
}

/// `cache show` of a body with a curve measured from RAW+JPEG prints it with its source
/// and coverage, and how far the recovered curve is from it, in stops per channel.
#[test]
fn show_compares_the_measured_curve_with_the_recovered_one() {
    use filmback::response::{MeasuredResponse, stops_apart};
    let dir = tempfile::tempdir().unwrap();
    state_with_entry(dir.path(), 3);
    let g: Vec<f64> = (0..256).map(|k| (f64::from(k) / 255.0).powf(2.0)).collect();
    let measured = MeasuredResponse {
        response: InverseResponse::from_samples(vec![g; 3]).unwrap(),
        coverage: vec![0.9, 0.95, 0.8],
        codes: vec![(2, 251); 3],
        samples: 10_000,
        captures: 1,
    };
    ResponseCache::new(dir.path())
        .put_measured(&camera(), &measured, 1_700_000_100)
        .unwrap();
    let out = cache(dir.path(), &["show".as_ref(), "r5".as_ref()]);
    assert_success(&out);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("measured from raw"), "{text}");
    assert!(text.contains("recovered from histograms"), "{text}");
    assert!(text.contains("coverage  90 %, 95 %, 80 %"), "{text}");
    let apart = stops_apart(&InverseResponse::srgb(3, 1024), &measured.response);
    for (c, (rms, max)) in apart.iter().enumerate() {
        let line = format!("channel {c}: RMS {rms:.3} stops, max {max:.3} stops");
        assert!(text.contains(&line), "{line} missing in {text}");
    }
    assert!(apart[0].0 > 0.05, "sRGB and gamma 2 differ");
}

/// `cache show` of a pooled body says how many brackets the curve rests on, how sure it
/// is per channel, and for each pooled bracket and dissent how far its own fit and the
/// body's curve are from its tone pairs.
#[test]
fn show_lists_the_pooled_brackets_and_the_dissents() {
    use filmback::daemon::cache::PooledBracket;
    use filmback::histogram::TonePair;
    use filmback::response::pool::{Evidence, PairSet};
    let dir = tempfile::tempdir().unwrap();
    state_with_entry(dir.path(), 3);
    // Tone pairs of an sRGB body at ratio 4, from the curve itself.
    let srgb = InverseResponse::srgb(3, 1024);
    let pairs: Vec<TonePair> = (10..120)
        .map(|k| {
            let dark = f64::from(k) / 255.0;
            let target = 4.0 * srgb.eval(0, dark);
            let bright = (0..=4096)
                .map(|i| f64::from(i) / 4096.0)
                .find(|&b| srgb.eval(0, b) >= target)
                .unwrap_or(1.0);
            TonePair {
                dark,
                bright,
                sigma_dark: 0.002,
                sigma_bright: 0.002,
                quantile: dark,
            }
        })
        .collect();
    let bracket = |name: &str| PooledBracket {
        name: name.to_string(),
        at: 1_700_000_000,
        own_confidence: 0.75,
        own_misfit: 0.01,
        evidence: Evidence {
            frames: 2,
            channels: vec![
                vec![PairSet {
                    log_ratio: 4f64.ln(),
                    pairs: pairs.clone()
                }];
                3
            ],
        },
    };
    let cache_dir = ResponseCache::new(dir.path());
    let mut entry = cache_dir.find("r5").unwrap();
    entry.pool = vec![bracket("IMG_0001"), bracket("IMG_0004")];
    entry.dissent = vec![bracket("IMG_0009")];
    cache_dir.put(&entry).unwrap();
    let out = cache(dir.path(), &["show".as_ref(), "r5".as_ref()]);
    assert_success(&out);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("pooled    2 "), "{text}");
    assert!(text.contains("confidence R 0.80, G 0.80, B 0.80"), "{text}");
    assert!(text.contains("1 of 3 in a row"), "{text}");
    for name in ["IMG_0001", "IMG_0004", "IMG_0009"] {
        let line = text
            .lines()
            .find(|l| l.trim_start().starts_with(name))
            .unwrap_or_else(|| panic!("{name} missing in {text}"));
        // Own confidence, own misfit, and the body's sRGB curve on sRGB tone pairs: the
        // last is the 8-bit search's rounding, far under a hundredth of a stop.
        let cells: Vec<&str> = line.split_whitespace().collect();
        assert_eq!(cells[2..4], ["0.75", "0.010"], "{line}");
        let body: f64 = cells[4].parse().unwrap();
        assert!(body < 0.01, "{line}");
    }
    let list = cache(dir.path(), &["list".as_ref()]);
    let text = String::from_utf8_lossy(&list.stdout);
    assert!(text.contains("pool of 2, confidence 0.80"), "{text}");
}
