//! Integration tests of the radiance merge against synthetic ground truth, and of the
//! `filmback merge` command through the real file system.

use std::path::{Path, PathBuf};

use filmback::frame::{BitDepth, Frame, Samples};
use filmback::histogram::{FrameCounts, shared_counts};
use filmback::merge::{self, BracketFrame, MergeOptions, Merged, Weighting};
use filmback::metadata::Camera;
use filmback::radiance::RadianceMap;
use filmback::response::{self, Degree, InverseResponse, Ratio, RatioSource};
use filmback::synthetic::{ResponseCurve, SceneKind, Sensor, expose, measure, scene};

use crate::common;
use common::filmback;

const WIDTH: u32 = 256;
const HEIGHT: u32 = 192;
/// Exposures of the pair: ratio 4, the bright frame puts mid-grey (0.18) at X = 0.18.
const DARK: f64 = 0.25;
const BRIGHT: f64 = 1.0;

fn sensor(curve: ResponseCurve, depth: BitDepth, seed: u64) -> Sensor {
    Sensor {
        read_noise_dn: 1.0,
        seed,
        ..Sensor::noiseless(curve, depth)
    }
}

/// The true inverse response sampled exactly at the frame's codes.
fn true_response(curve: &ResponseCurve, levels: usize) -> InverseResponse {
    let g: Vec<f64> = (0..levels)
        .map(|k| curve.inverse(k as f64 / (levels - 1) as f64))
        .collect();
    InverseResponse::from_samples(vec![g; 3]).unwrap()
}

fn merge_frames(frames: &[(&Frame, f64)], g: &InverseResponse, weighting: Weighting) -> Merged {
    let camera = Camera::default();
    let bracket: Vec<BracketFrame<'_>> = frames
        .iter()
        .map(|&(frame, exposure)| BracketFrame {
            source: Path::new("synthetic"),
            frame,
            exposure,
            camera: &camera,
        })
        .collect();
    let options = MergeOptions {
        weighting,
        confidence: true,
        ..MergeOptions::default()
    };
    merge::merge(&bracket, g, options).unwrap()
}

/// Median of `|s·E/e_ref − E_true| / E_true` over samples well exposed (code within 5–95 %
/// of the range) in at least one frame. The merge's scale is `e_ref = BRIGHT` times the
/// scene's, since `g(B) = X = e·E`; `s` is one global factor for all channels (the median
/// of `E_true·e_ref/E`), because a radiance map is relative: what matters is every
/// sample against every other, colour balance included (one factor for all channels). The
/// absolute level rests on the `g(1) = 1` anchor, which the calibration accuracy bench
/// measures on its own ("own normalisation"). Returns the error and `s`; with the true
/// response `s` must be 1 to within noise (checked by the callers: a merge that scaled
/// everything wrongly would fail there).
fn median_error(merged: &RadianceMap, truth: &RadianceMap, frames: &[&Frame]) -> (f64, f64) {
    let max = f64::from(frames[0].bit_depth().max_code());
    let code = |f: &Frame, i: usize| match f.samples() {
        Samples::Eight(v) => f64::from(v[i]),
        Samples::Sixteen(v) => f64::from(v[i]),
    };
    let region: Vec<usize> = (0..truth.pixels().len())
        .filter(|&i| {
            frames.iter().any(|f| {
                let b = code(f, i) / max;
                (0.05..=0.95).contains(&b)
            })
        })
        .collect();
    assert!(region.len() > truth.pixels().len() / 2, "region too small");
    let value = |i: usize| f64::from(merged.pixels()[i]) / BRIGHT;
    let mut ratios: Vec<f64> = region
        .iter()
        .map(|&i| f64::from(truth.pixels()[i]) / value(i))
        .collect();
    ratios.sort_by(f64::total_cmp);
    let s = ratios[ratios.len() / 2];
    let mut errors: Vec<f64> = region
        .iter()
        .map(|&i| {
            let t = f64::from(truth.pixels()[i]);
            (s * value(i) - t).abs() / t
        })
        .collect();
    errors.sort_by(f64::total_cmp);
    (errors[errors.len() / 2], s)
}

/// The error of a merge with the true response, checking that it needs no rescaling.
fn true_response_error(merged: &RadianceMap, truth: &RadianceMap, frames: &[&Frame]) -> f64 {
    let (e, s) = median_error(merged, truth, frames);
    assert!(
        (s - 1.0).abs() < 0.01,
        "the true response's merge is off by {s}"
    );
    e
}

/// The response fitted from the pair as the darkroom fits it: over the pixels both frames
/// share (for JPEG frames, their hard-clipped blocks left out of both).
fn recovered(dark: &Frame, bright: &Frame) -> InverseResponse {
    fitted(dark, bright).0
}

/// [`recovered`] with its channels' lowest confidence.
fn fitted(dark: &Frame, bright: &Frame) -> (InverseResponse, f64) {
    let (dark, bright) = (
        FrameCounts::of_frame(dark, 1),
        FrameCounts::of_frame(bright, 1),
    );
    let (dark, bright) = shared_counts(&dark, &bright);
    let calibration = response::calibrate(
        &dark,
        &bright,
        Ratio::Known(BRIGHT / DARK, RatioSource::Exif),
        Degree::Auto,
    )
    .unwrap();
    let confidence = calibration
        .channels
        .iter()
        .map(|c| c.fit.confidence)
        .fold(1.0, f64::min);
    (calibration.response, confidence)
}

/// The accuracy criterion for one curve: 8-bit, 1 DN noise, ratio 4. With the true
/// response the error is the noise floor (at most 2 %, and the noise-aware weight must not
/// do worse than the hat there); with the response recovered from the two histograms the
/// error must stay at most 2 % and within 0.3 percentage points of that floor.
fn accuracy(name: &str, curve: ResponseCurve) {
    let truth = scene(WIDTH, HEIGHT, 11);
    let s = sensor(curve.clone(), BitDepth::Eight, 5);
    let dark = expose(&truth, DARK, &s);
    let bright = expose(&truth, BRIGHT, &s);
    let frames = [(&dark, DARK), (&bright, BRIGHT)];
    let codes = [&dark, &bright];
    let g_true = true_response(&curve, 256);
    let g_fit = recovered(&dark, &bright);
    let err = |g: &InverseResponse, w: Weighting| {
        median_error(&merge_frames(&frames, g, w).radiance, &truth, &codes).0
    };
    let true_err = |w: Weighting| {
        true_response_error(&merge_frames(&frames, &g_true, w).radiance, &truth, &codes)
    };
    let (true_hat, true_noise) = (true_err(Weighting::Hat), true_err(Weighting::NoiseAware));
    let (fit_hat, fit_noise) = (
        err(&g_fit, Weighting::Hat),
        err(&g_fit, Weighting::NoiseAware),
    );
    let srgb = err(&InverseResponse::srgb(3, 1024), Weighting::Hat);
    eprintln!(
        "{name:>10}: median relative error  true g: hat {:.2} % noise-aware {:.2} %  \
         recovered g: hat {:.2} % noise-aware {:.2} %  sRGB guess: hat {:.2} %",
        true_hat * 100.0,
        true_noise * 100.0,
        fit_hat * 100.0,
        fit_noise * 100.0,
        srgb * 100.0
    );
    assert!(
        true_hat <= 0.02 && true_noise <= 0.02,
        "{name}: floor above 2 %"
    );
    assert!(
        true_noise <= true_hat,
        "{name}: noise-aware should not lose to the hat with the true g"
    );
    assert!(
        fit_hat <= 0.02,
        "{name}: recovered-response error {fit_hat} above 2 %"
    );
    assert!(
        fit_hat - true_hat <= 0.003,
        "{name}: recovered {fit_hat} vs floor {true_hat}: more than 0.3 pp apart"
    );
}

/// A pair at ratio 4 of a scene through a curve, and what its recovered response costs.
struct PairOutcome {
    dark: Frame,
    bright: Frame,
    /// Median relative radiance error of the merge given the true response.
    floor: f64,
    /// The same with the recovered response, minus `floor`.
    gap: f64,
    /// Each channel's scale error, stops.
    scale: Vec<f64>,
}

/// `truth` exposed at [`DARK`] and [`BRIGHT`] through `curve` (8-bit, 1 DN read noise,
/// noise seed `seed`), the response recovered from the pair, and its cost.
fn pair_outcome(truth: &RadianceMap, curve: &ResponseCurve, seed: u64) -> PairOutcome {
    let s = sensor(curve.clone(), BitDepth::Eight, seed);
    let dark = expose(truth, DARK, &s);
    let bright = expose(truth, BRIGHT, &s);
    let error = |g: &InverseResponse| {
        let merged = merge_frames(&[(&dark, DARK), (&bright, BRIGHT)], g, Weighting::Hat);
        measure::radiance_error(&merged.radiance, truth, BRIGHT, &[&dark, &bright]).unwrap()
    };
    let g_fit = recovered(&dark, &bright);
    let floor = error(&measure::true_response(curve, 256));
    let gap = error(&g_fit) - floor;
    let scale = measure::scale_errors(&g_fit, curve);
    PairOutcome {
        dark,
        bright,
        floor,
        gap,
        scale,
    }
}

/// Largest minus smallest of the channels' scale errors: the colour cast, stops.
fn spread(scale: &[f64]) -> f64 {
    scale.iter().fold(f64::NEG_INFINITY, |a, &b| a.max(b))
        - scale.iter().fold(f64::INFINITY, |a, &b| a.min(b))
}

/// The user's metric on the scenes a studio shoots (a seamless backdrop over most of the
/// frame, a grey card, a product with speculars; and flat patches, one channel each):
/// 8-bit, 1 DN read noise, ratio 4. On the studio sets the merge with the recovered
/// response may be at most 0.3 percentage points worse than the same merge given the true
/// response (the target of issue 15); on flat patches at most 0.5 (a regression guard: the
/// film S curve there is 0.40 short of the target, see docs/accuracy.md). No channel's
/// level may be off by more than 0.06 stop (a visible colour cast).
#[test]
fn studio_and_flat_patch_merges_stay_near_the_true_response() {
    for kind in [
        SceneKind::Studio,
        SceneKind::StudioFalloff,
        SceneKind::FlatPatches,
    ] {
        let truth = kind.render(WIDTH, HEIGHT, 3);
        for curve in [ResponseCurve::Srgb, ResponseCurve::FilmS] {
            let PairOutcome {
                floor, gap, scale, ..
            } = pair_outcome(&truth, &curve, 9);
            let fitted = floor + gap;
            eprintln!(
                "{} {curve:?}: true g {:.2} %, recovered {:.2} % (gap {:+.2} pp); channel scale {scale:+.4?} stops",
                kind.name(),
                100.0 * floor,
                100.0 * fitted,
                100.0 * gap
            );
            let bound = if kind == SceneKind::FlatPatches {
                0.005
            } else {
                0.003
            };
            assert!(
                gap <= bound,
                "{} {curve:?}: gap {:.2} pp",
                kind.name(),
                100.0 * gap
            );
            assert!(
                scale.iter().all(|s| s.abs() <= 0.06),
                "{} {curve:?}: channel scale {scale:?}",
                kind.name()
            );
        }
    }
}

/// The real brackets of `../shared/testdata/brackets` (none when absent), each frame
/// decoded, with its relative exposure, darkest first.
fn real_brackets() -> Vec<(String, Vec<(Frame, f64)>)> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/testdata/brackets");
    common::brackets::real_brackets(&root)
        .into_iter()
        .map(|(name, files)| {
            let frames = files
                .iter()
                .map(|(p, e)| {
                    let loaded = filmback::frame::load(p, filmback::frame::Limits::default());
                    (loaded.unwrap().frame, *e)
                })
                .collect();
            (name, frames)
        })
        .collect()
}

/// The user's metric on scenes of real places (`synthetic::real_place`: the radiance maps
/// of the real brackets of `../shared/testdata/brackets`; skipped where they are absent):
/// a pair at ratio 4 rendered from each through curves that are not DoRF's, 8-bit, 1 DN
/// read noise. The merge with the recovered response may be at most 0.3 percentage points
/// worse than the same merge given the true response (issue 15's target), and the
/// channels' levels at most 0.01 stop apart (no colour cast). The same pair as JPEG q90,
/// fitted over the pixels both frames share: every channel's level within 0.4 stop (the
/// whole frames' histograms put memorial's 1.35–1.53 stops off through the film and toe
/// curves), and no colour cast over 0.05 stop unless the confidence, the probability that
/// a channel's shape and colour are right, flags a channel low (< 0.5). Memorial's blue
/// has no tone above 0.5–0.74 left in the shared pixels at this size: its level is
/// extrapolated 1.2–1.8 stops, and through the film S curve it sits 0.11 stop above red
/// and green at confidence 0.19.
#[test]
fn real_places_merge_near_the_true_response() {
    let brackets = real_brackets();
    if brackets.is_empty() {
        eprintln!("skipped: no real brackets in ../shared/testdata/brackets");
        return;
    }
    for (name, frames) in &brackets {
        let borrowed: Vec<(&Frame, f64)> = frames.iter().map(|(f, e)| (f, *e)).collect();
        let truth = filmback::synthetic::real_place(&borrowed, f64::from(WIDTH * HEIGHT)).unwrap();
        for curve in [
            ResponseCurve::Srgb,
            ResponseCurve::FilmS,
            ResponseCurve::StrongToe,
        ] {
            let PairOutcome {
                dark,
                bright,
                floor,
                gap,
                scale,
            } = pair_outcome(&truth, &curve, 13);
            let cast = spread(&scale);
            eprintln!(
                "{name} {curve:?}: true g {:.2} %, gap {:+.2} pp, channel scale {scale:+.4?} stops",
                100.0 * floor,
                100.0 * gap
            );
            assert!(gap <= 0.003, "{name} {curve:?}: gap {:.2} pp", 100.0 * gap);
            assert!(
                cast <= 0.01,
                "{name} {curve:?}: channels {cast:.4} stop apart"
            );
            let (g_jpeg, sure) = fitted(
                &common::through_jpeg(&dark, DARK),
                &common::through_jpeg(&bright, BRIGHT),
            );
            let scale = measure::scale_errors(&g_jpeg, &curve);
            let cast = spread(&scale);
            let level = scale.iter().fold(0.0f64, |a, s| a.max(s.abs()));
            eprintln!(
                "{name} {curve:?} JPEG q90: channel scale {scale:+.4?} stops, confidence {sure:.2}"
            );
            assert!(
                level <= 0.4,
                "{name} {curve:?} JPEG: level {level:.4} stop off"
            );
            assert!(
                cast <= 0.05 || sure < 0.5,
                "{name} {curve:?} JPEG: channels {cast:.4} stop apart at confidence {sure:.2}"
            );
        }
    }
}

#[test]
fn accuracy_srgb() {
    accuracy("srgb", ResponseCurve::Srgb);
}

#[test]
fn accuracy_gamma() {
    accuracy("gamma-2.2", ResponseCurve::Gamma(2.2));
}

#[test]
fn accuracy_film_s() {
    accuracy("film-s", ResponseCurve::FilmS);
}

/// The merge's own floor on the film-like S-curve, with the true response.
#[test]
fn film_s_floor_with_true_response() {
    let truth = scene(WIDTH, HEIGHT, 11);
    let curve = ResponseCurve::FilmS;
    let s = sensor(curve.clone(), BitDepth::Eight, 5);
    let (dark, bright) = (expose(&truth, DARK, &s), expose(&truth, BRIGHT, &s));
    let merged = merge_frames(
        &[(&dark, DARK), (&bright, BRIGHT)],
        &true_response(&curve, 256),
        Weighting::Hat,
    );
    let e = true_response_error(&merged.radiance, &truth, &[&dark, &bright]);
    assert!(e <= 0.02, "film-s floor {e}");
}

/// 16-bit frames go through 65 536-entry tables and are far more accurate.
#[test]
fn sixteen_bit_accuracy() {
    let truth = scene(128, 96, 3);
    let curve = ResponseCurve::Srgb;
    let s = sensor(curve.clone(), BitDepth::Sixteen, 2);
    let dark = expose(&truth, DARK, &s);
    let bright = expose(&truth, BRIGHT, &s);
    let merged = merge_frames(
        &[(&dark, DARK), (&bright, BRIGHT)],
        &true_response(&curve, 65536),
        Weighting::Hat,
    );
    let e = true_response_error(&merged.radiance, &truth, &[&dark, &bright]);
    assert!(e < 0.002, "16-bit median error {e}");
}

/// The sun (+10 stops) is clipped in both frames: it takes the darkest frame's value, is
/// flagged, and nothing is NaN, infinite or a hole; the radiance stays monotone across the
/// clip boundary (noiseless, so the order of true radiance must be kept).
#[test]
fn sun_clipped_in_both_frames() {
    let truth = scene(WIDTH, HEIGHT, 1);
    let curve = ResponseCurve::Srgb;
    let s = Sensor::noiseless(curve.clone(), BitDepth::Eight);
    let dark = expose(&truth, DARK, &s);
    let bright = expose(&truth, BRIGHT, &s);
    let merged = merge_frames(
        &[(&bright, BRIGHT), (&dark, DARK)],
        &true_response(&curve, 256),
        Weighting::Hat,
    );
    let values = merged.radiance.pixels();
    assert!(values.iter().all(|v| v.is_finite() && *v >= 0.0));
    assert!(
        merged.bracket.clipped_high > 0,
        "the sun must be clipped in both frames"
    );
    let bound = (BRIGHT / DARK) as f32; // g(1)·e_ref/e_dark
    let conf = merged.confidence.as_ref().unwrap();
    let mut clipped = 0;
    // Code 255 in the dark frame (and so in the bright one): X ≥ f⁻¹(254.5/255).
    let saturating = curve.inverse(254.5 / 255.0);
    for (i, &t) in truth.pixels().iter().enumerate() {
        if f64::from(t) * DARK >= saturating {
            clipped += 1;
            assert_eq!(
                values[i], bound,
                "sample {i} (true {t}) is clipped everywhere"
            );
            assert_eq!(conf[i / 3], 0.0, "clipped pixels are flagged");
        }
    }
    assert_eq!(clipped as u64, merged.bracket.clipped_high);
    // Monotone: sorted by true radiance, the merge never steps down by more than the
    // quantisation of one code, and no estimate exceeds the clipped bound.
    let mut order: Vec<usize> = (0..values.len()).collect();
    order.sort_by(|&a, &b| truth.pixels()[a].total_cmp(&truth.pixels()[b]));
    let mut highest = 0.0f32;
    for &i in &order {
        assert!(values[i] <= bound);
        let t = truth.pixels()[i];
        if t > 0.05 {
            assert!(
                values[i] >= highest * 0.97,
                "drop at true {t}: {} after {highest}",
                values[i]
            );
        }
        highest = highest.max(values[i]);
    }
    let brightest_estimate = values
        .iter()
        .copied()
        .filter(|&v| v < bound)
        .fold(0.0f32, f32::max);
    assert!(
        brightest_estimate > 0.9 * bound,
        "{brightest_estimate}: a gap at the clip boundary"
    );
}

/// Moving subject: an object shifted between the frames (no registration). The result is
/// finite, within the bracket's range, and every sample lies between the frames' own
/// estimates (a convex combination: blur, never an overshoot or a colour fringe beyond it).
#[test]
fn moving_subject_stays_finite_and_bounded() {
    // A red block (4 stops over mid-grey in red) 30 px wide over the sky and the ground,
    // 24 px further right in the bright frame.
    let with_block = |x0: usize| {
        let mut map = scene(WIDTH, HEIGHT, 4);
        let w = WIDTH as usize;
        let px = map.pixels_mut();
        for y in 60..120 {
            for x in x0..x0 + 30 {
                let i = (y * w + x) * 3;
                px[i..i + 3].copy_from_slice(&[2.9, 0.1, 0.05]);
            }
        }
        map
    };
    let (first, moved) = (with_block(76), with_block(100));
    let curve = ResponseCurve::Srgb;
    let s = sensor(curve.clone(), BitDepth::Eight, 9);
    let dark = expose(&first, DARK, &s);
    let bright = expose(&moved, BRIGHT, &s);
    let g = true_response(&curve, 256);
    for weighting in [Weighting::Hat, Weighting::NoiseAware] {
        let merged = merge_frames(&[(&dark, DARK), (&bright, BRIGHT)], &g, weighting);
        let estimate = |f: &Frame, e: f64, i: usize| {
            let Samples::Eight(v) = f.samples() else {
                unreachable!()
            };
            (g.eval(i % 3, f64::from(v[i]) / 255.0) * BRIGHT / e) as f32
        };
        for (i, &v) in merged.radiance.pixels().iter().enumerate() {
            assert!(v.is_finite() && (0.0..=4.0).contains(&v), "sample {i}: {v}");
            let (a, b) = (estimate(&dark, DARK, i), estimate(&bright, BRIGHT, i));
            let (lo, hi) = (a.min(b), a.max(b));
            assert!(
                v >= lo * (1.0 - 1e-5) && v <= hi * (1.0 + 1e-5),
                "{weighting:?} sample {i}: {v} outside the frames' estimates {lo}..{hi}"
            );
        }
    }
}

/// Two frames of equal exposure are merged as duplicates: averaging them lowers the noise.
#[test]
fn equal_exposures_average_as_duplicates() {
    let truth = scene(WIDTH, HEIGHT, 6);
    let curve = ResponseCurve::Srgb;
    let dark = expose(&truth, DARK, &sensor(curve.clone(), BitDepth::Eight, 1));
    let bright = expose(&truth, BRIGHT, &sensor(curve.clone(), BitDepth::Eight, 1));
    let again = expose(&truth, BRIGHT, &sensor(curve.clone(), BitDepth::Eight, 2));
    let g = true_response(&curve, 256);
    let pair = merge_frames(&[(&dark, DARK), (&bright, BRIGHT)], &g, Weighting::Hat);
    let three = merge_frames(
        &[(&dark, DARK), (&bright, BRIGHT), (&again, BRIGHT)],
        &g,
        Weighting::Hat,
    );
    let e2 = true_response_error(&pair.radiance, &truth, &[&dark, &bright]);
    let e3 = true_response_error(&three.radiance, &truth, &[&dark, &bright, &again]);
    assert!(e3 < e2, "duplicate did not help: {e3} vs {e2}");
}

// ---- the command line ----

/// Writes a synthetic 8-bit sRGB frame as PNG (no EXIF: exposures go in `--times`).
fn write_png(path: &Path, truth: &RadianceMap, exposure: f64) {
    let frame = expose(
        truth,
        exposure,
        &Sensor::noiseless(ResponseCurve::Srgb, BitDepth::Eight),
    );
    let Samples::Eight(codes) = frame.samples() else {
        unreachable!()
    };
    image::save_buffer(
        path,
        codes,
        frame.width(),
        frame.height(),
        image::ExtendedColorType::Rgb8,
    )
    .unwrap();
}

fn pair(dir: &Path) -> (PathBuf, PathBuf) {
    let truth = scene(96, 64, 8);
    let (a, b) = (dir.join("a.png"), dir.join("b.png"));
    write_png(&a, &truth, DARK);
    write_png(&b, &truth, BRIGHT);
    (a, b)
}

#[test]
fn cli_writes_once_and_reports_json() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = pair(dir.path());
    let out = dir.path().join("out");
    let run = |extra: &[&str]| {
        filmback()
            .arg("merge")
            .args([&b, &a])
            .args([
                "-o",
                out.to_str().unwrap(),
                "--times",
                "1/25,1/100",
                "--json",
            ])
            .args(extra)
            .output()
            .unwrap()
    };
    let first = run(&["--srgb"]);
    assert!(
        first.status.success(),
        "{}",
        String::from_utf8_lossy(&first.stderr)
    );
    let report: serde_json::Value = serde_json::from_slice(&first.stdout).unwrap();
    let exr = out.join("b.exr");
    assert_eq!(report["outputs"][0], exr.display().to_string());
    assert_eq!(report["response"]["source"], "standard");
    assert!((report["ratio"].as_f64().unwrap() - 4.0).abs() < 1e-9);
    for stage in ["decode", "merge", "encode", "write"] {
        assert!(
            report["timings_ms"][stage].as_f64().unwrap() >= 0.0,
            "{stage}"
        );
    }
    assert!(report["timings_ms"]["fit"].is_null(), "no fit with --srgb");
    let bytes = std::fs::read(&exr).unwrap();
    assert_eq!(
        &bytes[..4],
        &[0x76, 0x2f, 0x31, 0x01],
        "OpenEXR magic number"
    );

    let again = run(&["--srgb"]);
    assert!(!again.status.success());
    assert!(String::from_utf8_lossy(&again.stderr).contains("already exists"));
    assert_eq!(std::fs::read(&exr).unwrap(), bytes, "not overwritten");

    // Calibrated from the bracket itself, replacing the file, with a Radiance .hdr too.
    let forced = run(&["--force", "--radiance-hdr"]);
    assert!(
        forced.status.success(),
        "{}",
        String::from_utf8_lossy(&forced.stderr)
    );
    let report: serde_json::Value = serde_json::from_slice(&forced.stdout).unwrap();
    assert_eq!(report["response"]["source"], "fitted");
    assert!(report["timings_ms"]["fit"].as_f64().is_some());
    assert!(out.join("b.hdr").exists());
    let names: Vec<_> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names.len(), 2, "no temporary files left: {names:?}");
}

#[test]
fn cli_refuses_bad_brackets_naming_the_files() {
    let dir = tempfile::tempdir().unwrap();
    let (a, _) = pair(dir.path());
    let small = dir.path().join("small.png");
    write_png(&small, &scene(48, 32, 8), BRIGHT);
    let out = dir.path().join("out");
    let o = filmback()
        .args(["merge", a.to_str().unwrap(), small.to_str().unwrap(), "-o"])
        .arg(&out)
        .args(["--times", "1/100,1/25", "--srgb"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(err.contains("a.png") && err.contains("small.png"), "{err}");

    // Same exposure for both: not a bracket.
    let o = filmback()
        .args(["merge", a.to_str().unwrap(), a.to_str().unwrap(), "-o"])
        .arg(&out)
        .args(["--times", "1/100,1/100", "--srgb"])
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("same exposure"));

    // No EXIF and no --times: the exposure is unknown.
    let o = filmback()
        .args(["merge", a.to_str().unwrap(), small.to_str().unwrap(), "-o"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(String::from_utf8_lossy(&o.stderr).contains("exposure time unknown"));
    assert_eq!(std::fs::read_dir(&out).map(|d| d.count()).unwrap_or(0), 0);
}

#[test]
fn cli_unwritable_output_leaves_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = pair(dir.path());
    let blocker = dir.path().join("file");
    std::fs::write(&blocker, b"not a folder").unwrap();
    let o = filmback()
        .args(["merge", a.to_str().unwrap(), b.to_str().unwrap(), "-o"])
        .arg(blocker.join("out"))
        .args(["--times", "1/100,1/25", "--srgb"])
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("file/out"));
    let names: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names.len(), 3, "{names:?}");
}

/// JPEGs with EXIF (as a tethered camera writes them): exposures come from EXIF, the
/// header carries camera, capture date, frames and ratio; another body is refused.
#[test]
fn cli_reads_exif_and_fills_the_header() {
    use exr::prelude::{AttributeValue, ReadChannels, ReadLayers, Text};
    use filmback::metadata::CaptureTime;
    use filmback::synthetic::{Encoding, Shot, write};

    let dir = tempfile::tempdir().unwrap();
    let truth = scene(96, 64, 12);
    let camera = Camera {
        make: Some("Filmback".into()),
        model: Some("Synthetic One".into()),
        serial: Some("0042".into()),
        lens: None,
    };
    let first = CaptureTime {
        year: 2026,
        month: 11,
        day: 22,
        hour: 5,
        minute: 30,
        second: 0,
        nanos: None,
        offset_minutes: Some(60),
    };
    let shots = Shot::series(&camera, first, &[0.01, 0.04], 8.0, 100.0, 0.5);
    let s = Sensor::noiseless(ResponseCurve::Srgb, BitDepth::Eight);
    let mut paths = Vec::new();
    for (k, shot) in shots.iter().enumerate() {
        let frame = expose(&truth, shot.exposure.time_s.unwrap() * 25.0, &s);
        let path = dir.path().join(format!("f{k}.jpg"));
        write(&path, &frame, shot, Encoding::Jpeg { quality: 95 }).unwrap();
        paths.push(path);
    }
    let out = dir.path().join("out");
    let o = filmback()
        .arg("merge")
        .args([&paths[1], &paths[0]])
        .arg("-o")
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let image = exr::prelude::read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_file(out.join("f1.exr"))
        .unwrap();
    let attrs = &image.layer_data.attributes;
    let text = |name: &str| match attrs.other.get(&Text::from(name)) {
        Some(AttributeValue::Text(t)) => t.to_string(),
        other => panic!("{name}: {other:?}"),
    };
    assert_eq!(text("cameraModel"), "Synthetic One");
    assert_eq!(text("cameraSerialNumber"), "0042");
    assert!(
        text("filmbackFrame0").starts_with("f0.jpg: time 0.01 s"),
        "{}",
        text("filmbackFrame0")
    );
    assert!(text("filmbackResponse").contains("calibrated from f0.jpg and f1.jpg"));
    assert_eq!(
        attrs.other.get(&Text::from("filmbackExposureRatio")),
        Some(&AttributeValue::F64(4.0))
    );
    assert_eq!(
        attrs
            .capture_date
            .as_ref()
            .map(|t| t.to_string())
            .as_deref(),
        Some("2026:11:22 05:30:00")
    );
    assert_eq!(attrs.utc_offset, Some(-3600.0));
    assert_eq!(attrs.exposure, Some(0.04));
    assert!(image.attributes.chromaticities.is_some());

    // The same scene from another body is not a bracket.
    let other = Camera {
        serial: Some("0043".into()),
        ..camera.clone()
    };
    let shot = Shot {
        camera: other,
        ..shots[1].clone()
    };
    let stranger = dir.path().join("stranger.jpg");
    write(
        &stranger,
        &expose(&truth, 1.0, &s),
        &shot,
        Encoding::Jpeg { quality: 95 },
    )
    .unwrap();
    let o = filmback()
        .arg("merge")
        .args([&paths[0], &stranger])
        .arg("-o")
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("f0.jpg") && err.contains("stranger.jpg") && err.contains("0043"),
        "{err}"
    );
}

// ---- renderings: --film, --tonemap, --format ----

/// `filmback merge b.png a.png -o OUT --times 1/25,1/100 EXTRA...` (b is the bright frame
/// and gives the outputs their stem).
fn merge_pair(a: &Path, b: &Path, out: &Path, extra: &[&str]) -> std::process::Output {
    filmback()
        .arg("merge")
        .args([b, a])
        .arg("-o")
        .arg(out)
        .args(["--times", "1/25,1/100"])
        .args(extra)
        .output()
        .unwrap()
}

/// Decodes `path`, checking that its content (not only its name) is `format`.
fn decode(path: &Path, format: image::ImageFormat) -> image::DynamicImage {
    let reader = image::ImageReader::open(path)
        .unwrap()
        .with_guessed_format()
        .unwrap();
    assert_eq!(reader.format(), Some(format), "{}", path.display());
    reader.decode().unwrap()
}

fn mean_rgb8(image: &image::DynamicImage) -> f64 {
    let rgb = image.to_rgb8();
    let samples = rgb.as_raw();
    samples.iter().map(|&v| f64::from(v)).sum::<f64>() / samples.len() as f64
}

fn files_in(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .map(|d| {
            d.map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                .collect()
        })
        .unwrap_or_default();
    names.sort();
    names
}

#[test]
fn cli_renders_films_and_tonemaps_beside_the_exr() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = pair(dir.path());
    let out = dir.path().join("out");
    let args = [
        "--film",
        "velvia50",
        "--film",
        "provia400@1/2",
        "--tonemap",
        "histogram",
        "--json",
    ];
    let first = merge_pair(&a, &b, &out, &args);
    assert!(
        first.status.success(),
        "{}",
        String::from_utf8_lossy(&first.stderr)
    );
    let report: serde_json::Value = serde_json::from_slice(&first.stdout).unwrap();
    let expected: Vec<PathBuf> = [
        "b.exr",
        "b.velvia50-t1.jpg",
        "b.provia400-t0.5.jpg",
        "b.histogram.jpg",
    ]
    .iter()
    .map(|n| out.join(n))
    .collect();
    let listed: Vec<String> = report["outputs"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap().to_string())
        .collect();
    let wanted: Vec<String> = expected.iter().map(|p| p.display().to_string()).collect();
    assert_eq!(listed, wanted);
    assert!(
        report["timings_ms"]["render"].as_f64().unwrap() >= 0.0,
        "{}",
        report["timings_ms"]
    );
    assert_eq!(
        files_in(&out),
        [
            "b.exr",
            "b.histogram.jpg",
            "b.provia400-t0.5.jpg",
            "b.velvia50-t1.jpg"
        ],
        "no temporary files left"
    );
    let mut means = Vec::new();
    for path in &expected[1..] {
        let image = decode(path, image::ImageFormat::Jpeg);
        assert_eq!(
            (image.width(), image.height()),
            (96, 64),
            "{}",
            path.display()
        );
        means.push(mean_rgb8(&image));
    }
    // velvia50 at t = 1 against provia400 at t = 1/2 (about 122 and 112 today): the two
    // film renderings really differ, the half-exposed one darker.
    let (velvia, provia_half) = (means[0], means[1]);
    assert!(
        provia_half + 5.0 < velvia,
        "t = 1/2 should print darker than t = 1: means {means:?}"
    );
    for m in &means {
        assert!(
            (5.0..250.0).contains(m),
            "not a blank frame: means {means:?}"
        );
    }

    // The same stock at t = 1 and t = 1/2 (about 138 and 112 today): one stop less light
    // on a reversal film is a denser, darker slide.
    let other = dir.path().join("provia");
    let o = merge_pair(
        &a,
        &b,
        &other,
        &["--film", "provia400", "--film", "provia400@1/2"],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let full = mean_rgb8(&decode(
        &other.join("b.provia400-t1.jpg"),
        image::ImageFormat::Jpeg,
    ));
    let half = mean_rgb8(&decode(
        &other.join("b.provia400-t0.5.jpg"),
        image::ImageFormat::Jpeg,
    ));
    assert!(half + 10.0 < full, "provia400: t=1 {full}, t=1/2 {half}");
    assert!(
        (half - provia_half).abs() < 1.0,
        "the same look of the same bracket: {half} vs {provia_half}"
    );

    // The same again without --force: refused before decoding, naming an output, and
    // nothing is touched.
    let before: Vec<Vec<u8>> = expected.iter().map(|p| std::fs::read(p).unwrap()).collect();
    let again = merge_pair(&a, &b, &out, &args);
    let err = String::from_utf8_lossy(&again.stderr);
    assert!(!again.status.success());
    assert!(err.contains("already exists"), "{err}");
    assert!(
        expected
            .iter()
            .any(|p| err.contains(&p.display().to_string())),
        "{err}"
    );
    for (path, bytes) in expected.iter().zip(&before) {
        assert_eq!(&std::fs::read(path).unwrap(), bytes, "{}", path.display());
    }

    // One rendering present, the EXR gone: still refused, naming that rendering.
    std::fs::remove_file(&expected[0]).unwrap();
    let again = merge_pair(&a, &b, &out, &args);
    let err = String::from_utf8_lossy(&again.stderr);
    assert!(!again.status.success());
    assert!(err.contains("b.velvia50-t1.jpg"), "{err}");
    assert!(!expected[0].exists(), "refused before writing the EXR");

    let forced = merge_pair(&a, &b, &out, &[&args[..], &["--force"]].concat());
    assert!(
        forced.status.success(),
        "{}",
        String::from_utf8_lossy(&forced.stderr)
    );
    let report: serde_json::Value = serde_json::from_slice(&forced.stdout).unwrap();
    assert_eq!(report["outputs"].as_array().unwrap().len(), 4);
    assert_eq!(files_in(&out).len(), 4);
    for path in &expected {
        assert!(path.exists(), "{}", path.display());
    }
}

#[test]
fn cli_refuses_unknown_or_unrenderable_looks_before_writing() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = pair(dir.path());
    let out = dir.path().join("out");
    let cases: [(&[&str], &[&str]); 3] = [
        (
            &["--film", "nosuchstock"],
            &["nosuchstock", "unknown film stock"],
        ),
        (
            &["--film", "portra400+grain"],
            &["portra400", "RMS granularity"],
        ),
        (&["--tonemap", "foo"], &["\"foo\"", "unknown tone map"]),
    ];
    for (extra, needles) in cases {
        // A good look first: the bad one must still stop everything.
        let args = [&["--tonemap", "linear", "--srgb"][..], extra].concat();
        let o = merge_pair(&a, &b, &out, &args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{extra:?} succeeded");
        for needle in needles {
            assert!(err.contains(needle), "{extra:?}: {err}");
        }
        assert!(
            files_in(&out).is_empty(),
            "{extra:?} wrote {:?}",
            files_in(&out)
        );
    }
}

#[test]
fn cli_png16_writes_sixteen_bit_renderings() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = pair(dir.path());
    let out = dir.path().join("out");
    let o = merge_pair(
        &a,
        &b,
        &out,
        &["--format", "png16", "--tonemap", "linear", "--srgb"],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let path = out.join("b.linear.png");
    let image = decode(&path, image::ImageFormat::Png);
    assert_eq!(image.color(), image::ColorType::Rgb16);
    assert_eq!((image.width(), image.height()), (96, 64));
    // Really 16 bits: more distinct values than an 8-bit image can hold per channel.
    let rgb = image.to_rgb16();
    let mut values: Vec<u16> = rgb.as_raw().iter().step_by(3).copied().collect();
    values.sort_unstable();
    values.dedup();
    assert!(values.len() > 256, "{} distinct red values", values.len());
    assert_eq!(files_in(&out), ["b.exr", "b.linear.png"]);
}

/// Merges a JPEG pair of `truth` shot at times `times` (f/`n`, ISO `s`) through the CLI
/// (`--srgb`, float EXR) and returns the EXR's RGB values and layer attributes. The
/// sensor receives `k · t·S/N²` of the scene (`k` fixed), as a real camera would.
fn exif_pair_exr(
    dir: &Path,
    name: &str,
    truth: &RadianceMap,
    (times, n, s): (&[f64], f64, f64),
    extra: &[&str],
) -> (Vec<f32>, exr::prelude::LayerAttributes) {
    use filmback::metadata::CaptureTime;
    use filmback::synthetic::{Encoding, Shot, write};
    let camera = Camera {
        make: Some("Filmback".into()),
        model: Some("Synthetic One".into()),
        serial: None,
        lens: None,
    };
    let first = CaptureTime {
        year: 2026,
        month: 11,
        day: 24,
        hour: 12,
        minute: 0,
        second: 0,
        nanos: None,
        offset_minutes: None,
    };
    let shots = filmback::synthetic::Shot::series(&camera, first, times, n, s, 0.5);
    let sensor = Sensor::noiseless(ResponseCurve::Srgb, BitDepth::Eight);
    let mut paths = Vec::new();
    for (k, shot) in shots.iter().enumerate() {
        let shot: &Shot = shot;
        let frame = expose(truth, SCALE_K * shot.exposure.relative().unwrap(), &sensor);
        let path = dir.join(format!("{name}{k}.jpg"));
        write(&path, &frame, shot, Encoding::Jpeg { quality: 100 }).unwrap();
        paths.push(path);
    }
    let out = dir.join(format!("out-{name}"));
    let o = filmback()
        .arg("merge")
        .args(&paths)
        .arg("-o")
        .arg(&out)
        .args(["--srgb", "--exr", "float"])
        .args(extra)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    common::read_exr(&out.join(format!("{name}0.exr")))
}

/// `k` of [`exif_pair_exr`]: at 1/100 s, f/8, ISO 100 mid-grey (0.18) lands at 0.18 of
/// the sensor's white.
const SCALE_K: f64 = 1.0 / (0.01 * 100.0 / 64.0);

/// Equal scene luminance gives equal values across settings: the same scene shot as JPEG
/// pairs at 1/100 + 1/25 s, f/8, ISO 100; at the same times, f/5.6, ISO 200 (two stops
/// more signal); and at 1/200 + 1/50 s, f/8, ISO 100 (one stop less) merges to the same
/// values, 120·g·N²/(t·S) cd/m² (`merge::exposure_scale`), and the header says so.
#[test]
fn exif_anchored_scale_is_the_same_across_settings() {
    use exr::prelude::{AttributeValue, Text};
    let dir = tempfile::tempdir().unwrap();
    let truth = scene(96, 64, 21);
    let (a, attrs) = exif_pair_exr(dir.path(), "a", &truth, (&[0.01, 0.04], 8.0, 100.0), &[]);
    let (b, _) = exif_pair_exr(dir.path(), "b", &truth, (&[0.01, 0.04], 5.6, 200.0), &[]);
    let (c, _) = exif_pair_exr(dir.path(), "c", &truth, (&[0.005, 0.02], 8.0, 100.0), &[]);
    // Expected: the sensor saw k·(t·S/N²)·x, so g = k·(t·S/N²)·x and the value is
    // 120·k·x whatever the settings.
    let expect: Vec<f64> = truth
        .pixels()
        .iter()
        .map(|&x| 120.0 * SCALE_K * f64::from(x))
        .collect();
    let median_error = |v: &[f32]| {
        let mut e: Vec<f64> = v
            .iter()
            .zip(&expect)
            // Scene 0.02..0.2: within the range every pair covers unclipped.
            .filter(|&(_, &t)| t > 150.0 && t < 1500.0)
            .map(|(&v, &t)| (f64::from(v) / t - 1.0).abs())
            .collect();
        e.sort_by(f64::total_cmp);
        e[e.len() / 2]
    };
    for (name, v) in [("a", &a), ("b", &b), ("c", &c)] {
        let err = median_error(v);
        println!("{name}: median error against 120·k·x: {:.3} %", 100.0 * err);
        assert!(err < 0.02, "{name}: {err}");
    }
    let text = |name: &str| match attrs.other.get(&Text::from(name)) {
        Some(AttributeValue::Text(t)) => t.to_string(),
        other => panic!("{name}: {other:?}"),
    };
    assert_eq!(text("filmbackScaleKind"), "luminance");
    assert!(
        text("filmbackScale").contains("cd/m2"),
        "{}",
        text("filmbackScale")
    );
    assert_eq!(attrs.white_luminance, Some(1.0));

    // A calibration factor multiplies the values and is stated.
    let (d, attrs) = exif_pair_exr(
        dir.path(),
        "d",
        &truth,
        (&[0.01, 0.04], 8.0, 100.0),
        &["--luminance-calibration", "2"],
    );
    let ratio: Vec<f64> = d
        .iter()
        .zip(&a)
        .filter(|&(_, &x)| x > 1.0)
        .map(|(&y, &x)| f64::from(y) / f64::from(x))
        .collect();
    assert!(ratio.iter().all(|r| (r - 2.0).abs() < 1e-5));
    let kind = attrs.other.get(&Text::from("filmbackScaleKind"));
    assert_eq!(
        kind,
        Some(&AttributeValue::Text(Text::from("luminance-calibrated")))
    );
}

/// Frames without EXIF keep the relative scale (1.0 = white in the longest frame), with
/// a warning, and the header says which scale it carries.
#[test]
fn frames_without_exif_keep_the_relative_scale_and_say_so() {
    use exr::prelude::{AttributeValue, Text};
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = pair(dir.path());
    let out = dir.path().join("out");
    let o = merge_pair(&a, &b, &out, &["--srgb", "--json"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let report: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(report["scale"]["kind"], "relative", "{report}");
    assert!(
        report["warnings"]
            .as_array()
            .unwrap()
            .iter()
            .any(|w| w.as_str().unwrap().contains("relative scale")),
        "{report}"
    );
    let exr_path = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.extension().is_some_and(|e| e == "exr"))
        .unwrap();
    let (_, attrs) = common::read_exr(&exr_path);
    assert_eq!(
        attrs.other.get(&Text::from("filmbackScaleKind")),
        Some(&AttributeValue::Text(Text::from("relative")))
    );
    assert_eq!(attrs.white_luminance, None);
}

/// The same bracket merged twice, by two processes a second apart, gives the same files
/// byte for byte: the EXR (its header's attributes in a fixed order) and every rendering
/// (the ICC profile's date fixed), at 8 and 16 bits.
#[test]
fn cli_outputs_are_byte_reproducible() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = pair(dir.path());
    let run = |name: &str, format: &str| {
        let out = dir.path().join(name);
        let args = [
            "--film",
            "velvia50",
            "--tonemap",
            "linear",
            "--format",
            format,
        ];
        let done = merge_pair(&a, &b, &out, &args);
        assert!(
            done.status.success(),
            "{}",
            String::from_utf8_lossy(&done.stderr)
        );
        out
    };
    for format in ["jpeg", "png16"] {
        let first = run(&format!("first-{format}"), format);
        std::thread::sleep(std::time::Duration::from_millis(1100));
        let second = run(&format!("second-{format}"), format);
        let names = files_in(&first);
        assert_eq!(names.len(), 3, "{names:?}");
        assert_eq!(names, files_in(&second));
        for name in &names {
            let read = |d: &Path| std::fs::read(d.join(name)).unwrap();
            assert!(
                read(&first) == read(&second),
                "{name} differs between two runs"
            );
        }
    }
}
