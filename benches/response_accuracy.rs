//! Accuracy of response recovery against ground truth, and against OpenCV's
//! CalibrateDebevec on the same pairs.
//!
//! `cargo bench --bench response_accuracy [-- --quick] [--ratio R] [--encoding lossless|jpeg|16]
//! [--scene KIND[,KIND]] [--curves all|tune|report] [--every N] [--size WxH] [--curve NAME]
//! [--frames N] [--seed N] [--per-curve]`
//!
//! `--quick` takes every tenth DoRF curve (`--every N`: every N-th); `--ratio` and
//! `--encoding` restrict the sweep to one ratio or one encoding; `--scene` to some scene
//! kinds (`procedural`, `studio`, `studio-falloff`, `flat-patches`; default all);
//! `--curves tune` keeps the DoRF records whose index is a multiple of 4 and `report` the
//! others (index ≡ 2 mod 4), the split between curves a change is tuned on and curves its
//! accuracy is reported on; `--seed` renders another realisation of each scene kind
//! (default 7; colours, positions, textures); `--size` renders smaller scenes for quick runs. `--frames N`
//! (N ≥ 3) renders a bracket of N frames `γ` apart (exposures `γ^(k − (N−1)/2)`), fits it
//! jointly (`calibrate_bracket`) and compares with each adjacent pair fitted alone.
//!
//! Each scene kind (`filmback::synthetic::SceneKind`, default 1024×768) is exposed at `1/√γ` and `√γ` through a
//! known curve `f` (gamma 2.2, sRGB, film S, strong toe, and the DoRF curves of
//! `../shared/testdata/response-curves/dorf-even.csv` when present), with Gaussian noise
//! of 1 DN (8-bit) or 0.5/255 (16-bit), as 8-bit lossless, 8-bit JPEG q95, and 16-bit.
//! Error = RMSE of `log₂ g − log₂ g_true` over codes 16..239 (stops), averaged (RMS) over
//! the three channels; "own" uses the fit's normalisation `g(1) = 1`, "shape" removes the
//! best global scale per channel (the mean log difference). OpenCV (optional: the peer's
//! venv, `/work/shared/peer/setup.sh`) only has the shape error (its scale is arbitrary).
//!
//! What a wrong response costs the user: the pair is merged (hat weight) with the fitted
//! and with the true response, and the **gap** is the difference of their median relative
//! radiance errors in percentage points (`filmback::synthetic::measure::radiance_error`);
//! the **scale error** of a channel is its mean `log₂ g − log₂ g_true` over codes 16..239,
//! and the table gives the largest over the three channels.

use std::path::{Path, PathBuf};
use std::process::Command;

use filmback::frame::{self, BitDepth, Frame, Limits};
use filmback::histogram::Histogram;
use filmback::merge::{self, BracketFrame, MergeOptions};
use filmback::metadata::{Camera, CaptureTime, Exposure};
use filmback::radiance::RadianceMap;
use filmback::response::{
    Calibration, Degree, InverseResponse, Ratio, RatioSource, calibrate, calibrate_bracket,
};
use filmback::synthetic::{
    self, Encoding as FileEncoding, ResponseCurve as Curve, SceneKind, Sensor, Shot, measure,
};

const RATIOS: [f64; 7] = [1.25, 2.0, 4.0, 8.0, 16.0, 64.0, 256.0];
const WIDTH: u32 = 1024;
const HEIGHT: u32 = 768;
/// Median relative radiance error of the hat-weighted merge of `frames` under `g`.
fn merged_error(truth: &RadianceMap, frames: &[(&Frame, f64)], g: &InverseResponse) -> Option<f64> {
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
    let merged = merge::merge(&bracket, g, MergeOptions::default()).ok()?;
    let e_ref = frames.iter().map(|f| f.1).fold(0.0, f64::max);
    let codes: Vec<&Frame> = frames.iter().map(|f| f.0).collect();
    measure::radiance_error(&merged.radiance, truth, e_ref, &codes)
}

/// Read noise of the 16-bit sensor in 16-bit codes (a quarter of an 8-bit code).
const NOISE_16: f64 = 64.0;

fn dorf_curves() -> Vec<(String, Curve)> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/testdata/response-curves/dorf-even.csv");
    match synthetic::dorf_curves(&path) {
        Ok(curves) => curves,
        Err(e) => {
            eprintln!("(DoRF curves unavailable: {e}: skipped)");
            Vec::new()
        }
    }
}

#[derive(Clone, Copy, PartialEq)]
enum Encoding {
    Lossless8,
    Jpeg95,
    Sixteen,
}

impl Encoding {
    fn name(self) -> &'static str {
        match self {
            Encoding::Lossless8 => "8-bit lossless",
            Encoding::Jpeg95 => "8-bit JPEG q95",
            Encoding::Sixteen => "16-bit",
        }
    }
}

/// Exposes the scene through `curve` (1 DN read noise at 8 bits, [`NOISE_16`] at 16),
/// round-trips JPEG through the file codec, and returns the frame and its file bytes
/// (PNG or JPEG with EXIF; none for 16-bit, which OpenCV's Debevec does not take).
fn expose(
    scene: &RadianceMap,
    exposure: f64,
    curve: &Curve,
    enc: Encoding,
    seed: u64,
) -> (Frame, Option<Vec<u8>>) {
    let sensor = Sensor {
        curve: curve.clone(),
        bit_depth: if enc == Encoding::Sixteen {
            BitDepth::Sixteen
        } else {
            BitDepth::Eight
        },
        read_noise_dn: if enc == Encoding::Sixteen {
            NOISE_16
        } else {
            1.0
        },
        full_well_electrons: None,
        seed,
    };
    let frame = synthetic::expose(scene, exposure, &sensor);
    let shot = Shot {
        camera: Camera::default(),
        exposure: Exposure {
            time_s: Some(exposure),
            f_number: Some(1.0),
            iso: Some(100.0),
        },
        captured_at: CaptureTime {
            year: 2026,
            month: 1,
            day: 1,
            hour: 0,
            minute: 0,
            second: 0,
            nanos: None,
            offset_minutes: None,
        },
    };
    match enc {
        Encoding::Sixteen => (frame, None),
        Encoding::Lossless8 => {
            let bytes = synthetic::encode(&frame, &shot, FileEncoding::Png).unwrap();
            (frame, Some(bytes))
        }
        Encoding::Jpeg95 => {
            let bytes =
                synthetic::encode(&frame, &shot, FileEncoding::Jpeg { quality: 95 }).unwrap();
            let decoded = frame::decode(Path::new("synthetic.jpg"), &bytes, Limits::default())
                .unwrap()
                .frame;
            (decoded, Some(bytes))
        }
    }
}

/// (own, shape) error in stops, RMS over the three channels, of `g(channel, code)`.
fn errors(curve: &Curve, g: impl Fn(usize, usize) -> f64) -> (f64, f64) {
    let e = measure::curve_errors(3, |c, b| g(c, (b * 255.0).round() as usize), curve);
    let rms = |f: fn(&measure::CurveError) -> f64| {
        (e.iter().map(|x| f(x).powi(2)).sum::<f64>() / 3.0).sqrt()
    };
    (rms(|x| x.own), rms(|x| x.shape))
}

struct Outcome {
    curve: String,
    scene: SceneKind,
    ratio: f64,
    enc: Encoding,
    own: f64,
    shape: f64,
    /// Largest |scale error| over channels, stops.
    scale: f64,
    /// Merged radiance error with the true response, fraction.
    merge_true: f64,
    /// Merged radiance error with the fitted response minus `merge_true`, fraction.
    gap: f64,
    /// N-frame brackets: the adjacent pairs fitted alone, (largest |scale error|, lowest
    /// channel confidence) of the pair with the smallest scale error, and of the middle pair.
    best_pair: Option<(f64, f64)>,
    middle_pair: Option<(f64, f64)>,
    confidence: f64,
    /// Effective number of parameters, median over channels.
    parameters: f64,
    failed: Option<String>,
    peer_index: Option<usize>,
}

fn quantile(v: &mut [f64], q: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
}

fn peer_python() -> Option<String> {
    let out = Command::new("/work/shared/peer/setup.sh").output().ok()?;
    let py = String::from_utf8(out.stdout).ok()?.trim().to_string();
    let ok = Command::new(&py)
        .args(["-c", "import cv2"])
        .status()
        .ok()?
        .success();
    ok.then_some(py)
}

fn main() {
    let quick = std::env::args().any(|a| a == "--quick");
    let mut curves: Vec<(String, Curve)> = Curve::builtin()
        .into_iter()
        .filter(|(n, _)| n != "linear")
        .collect();
    let args: Vec<String> = std::env::args().collect();
    let arg = |flag: &str| {
        args.iter()
            .position(|a| a == flag)
            .and_then(|i| args.get(i + 1))
            .cloned()
    };
    let mut dorf = dorf_curves();
    // The DoRF records are numbered 0, 2, 4, …: tune on multiples of 4, report on the rest.
    let record = |name: &str| -> u32 { name.trim_start_matches("dorf-").parse().unwrap_or(0) };
    match arg("--curves").as_deref() {
        None | Some("all") => {}
        Some("tune") => dorf.retain(|(n, _)| record(n) % 4 == 0),
        Some("report") => dorf.retain(|(n, _)| record(n) % 4 != 0),
        Some(other) => panic!("--curves takes all, tune or report, not {other}"),
    }
    let every = arg("--every")
        .map(|n| n.parse::<usize>().expect("--every takes a whole number"))
        .unwrap_or(if quick { 10 } else { 1 });
    dorf = dorf.into_iter().step_by(every.max(1)).collect();
    curves.extend(dorf);
    let scenes: Vec<SceneKind> = match arg("--scene") {
        Some(list) => list
            .split(',')
            .map(|k| k.parse().unwrap_or_else(|e: String| panic!("{e}")))
            .collect(),
        None => SceneKind::ALL.to_vec(),
    };
    let scene_seed: u64 = arg("--seed")
        .map(|n| n.parse().expect("--seed takes a whole number"))
        .unwrap_or(7);
    let frame_count: usize = arg("--frames")
        .map(|n| n.parse().expect("--frames takes a whole number"))
        .unwrap_or(2)
        .max(2);
    let (width, height) = match arg("--size") {
        Some(size) => {
            let (w, h) = size.split_once('x').expect("--size takes WxH");
            (w.parse().expect("width"), h.parse().expect("height"))
        }
        None => (WIDTH, HEIGHT),
    };
    // `--curve NAME` restricts to one curve and prints its fitted and true g per 16 codes.
    let only = args
        .iter()
        .position(|a| a == "--curve")
        .and_then(|i| args.get(i + 1))
        .cloned();
    if let Some(name) = &only {
        curves.retain(|(n, _)| n == name);
    }
    let ratios: Vec<f64> = match arg("--ratio") {
        Some(r) => vec![r.parse().expect("--ratio takes a number")],
        None => RATIOS.to_vec(),
    };
    let encodings: Vec<Encoding> = match arg("--encoding").as_deref() {
        Some("lossless") => vec![Encoding::Lossless8],
        Some("jpeg") => vec![Encoding::Jpeg95],
        Some("16") => vec![Encoding::Sixteen],
        Some(other) => panic!("--encoding takes lossless, jpeg or 16, not {other}"),
        None => vec![Encoding::Lossless8, Encoding::Jpeg95, Encoding::Sixteen],
    };
    let py = peer_python();
    if py.is_none() {
        eprintln!("(OpenCV peer unavailable: comparison skipped)");
    }
    let dir = tempfile::tempdir().unwrap();
    let mut outcomes = Vec::new();
    let mut peer_cases = Vec::new();
    let started = std::time::Instant::now();
    for (si, &kind) in scenes.iter().enumerate() {
        let radiance = kind.render(width, height, scene_seed);
        for (ci, (name, curve)) in curves.iter().enumerate() {
            let g_true = measure::true_response(curve, 4096);
            for &enc in &encodings {
                for &ratio in &ratios {
                    let ri = RATIOS
                        .iter()
                        .position(|r| *r == ratio)
                        .unwrap_or(RATIOS.len());
                    let seed = (si * 100_000 + ci * 100 + ri) as u64;
                    let exposures: Vec<f64> = (0..frame_count)
                        .map(|k| ratio.powf(k as f64 - (frame_count - 1) as f64 / 2.0))
                        .collect();
                    let rendered: Vec<(Frame, Option<Vec<u8>>)> = exposures
                        .iter()
                        .enumerate()
                        .map(|(k, &e)| expose(&radiance, e, curve, enc, seed + 50 * k as u64))
                        .collect();
                    let histograms: Vec<Histogram> = rendered
                        .iter()
                        .map(|(f, _)| Histogram::of_frame(f, 1))
                        .collect();
                    let pair_fit = |i: usize| {
                        calibrate(
                            &histograms[i],
                            &histograms[i + 1],
                            Ratio::Known(ratio, RatioSource::Argument),
                            Degree::Auto,
                        )
                    };
                    let result = if frame_count > 2 {
                        let frames: Vec<(&Histogram, f64)> =
                            histograms.iter().zip(exposures.iter().copied()).collect();
                        calibrate_bracket(&frames, RatioSource::Argument, Degree::Auto)
                    } else {
                        pair_fit(0)
                    };
                    let summary = |cal: &Calibration| -> (f64, f64) {
                        (
                            measure::scale_errors(&cal.response, curve)
                                .into_iter()
                                .fold(0.0, |a: f64, s| a.max(s.abs())),
                            cal.channels
                                .iter()
                                .map(|c| c.fit.confidence)
                                .fold(1.0, f64::min),
                        )
                    };
                    let pairs: Vec<Option<(f64, f64)>> = if frame_count > 2 {
                        (0..frame_count - 1)
                            .map(|i| pair_fit(i).ok().map(|c| summary(&c)))
                            .collect()
                    } else {
                        Vec::new()
                    };
                    let best_pair = pairs
                        .iter()
                        .flatten()
                        .copied()
                        .min_by(|a, b| a.0.total_cmp(&b.0));
                    let middle_pair = pairs.get(frame_count / 2 - 1).copied().flatten();
                    let frames: Vec<(&Frame, f64)> = rendered
                        .iter()
                        .map(|r| &r.0)
                        .zip(exposures.iter().copied())
                        .collect();
                    let merge_true = merged_error(&radiance, &frames, &g_true).unwrap_or(f64::NAN);
                    let mut outcome = Outcome {
                        curve: name.clone(),
                        scene: kind,
                        ratio,
                        enc,
                        own: f64::NAN,
                        shape: f64::NAN,
                        scale: f64::NAN,
                        merge_true,
                        gap: f64::NAN,
                        best_pair,
                        middle_pair,
                        confidence: 0.0,
                        parameters: f64::NAN,
                        failed: None,
                        peer_index: None,
                    };
                    match result {
                        Ok(cal) => {
                            if only.is_some() {
                                let ch = &cal.channels[1];
                                println!(
                                    "{} ratio {ratio}: {} covered {:.4}..{:.4} eq {} resid {:.4} cond {:.1e} pred {:.4} conf {:.2}",
                                    enc.name(),
                                    ch.fit.model(),
                                    ch.fit.covered.0,
                                    ch.fit.covered.1,
                                    ch.fit.equations,
                                    ch.fit.residual_rms,
                                    ch.fit.condition,
                                    ch.fit.predicted_error,
                                    ch.fit.confidence
                                );
                                let line: Vec<String> = (0..=255)
                                    .step_by(16)
                                    .chain([239, 250, 255])
                                    .map(|k| {
                                        let b = k as f64 / 255.0;
                                        format!(
                                            "{k}:{:+.3}",
                                            cal.response.eval(1, b).log2()
                                                - curve.inverse(b).log2()
                                        )
                                    })
                                    .collect();
                                println!("  log2 g - log2 g_true: {}", line.join(" "));
                            }
                            let (own, shape) =
                                errors(curve, |c, k| cal.response.eval(c, k as f64 / 255.0));
                            outcome.own = own;
                            outcome.shape = shape;
                            outcome.scale = measure::scale_errors(&cal.response, curve)
                                .into_iter()
                                .fold(0.0, |a: f64, s| a.max(s.abs()));
                            outcome.gap = merged_error(&radiance, &frames, &cal.response)
                                .map_or(f64::NAN, |e| e - merge_true);
                            outcome.confidence = cal
                                .channels
                                .iter()
                                .map(|c| c.fit.confidence)
                                .fold(1.0, f64::min);
                            let mut p: Vec<f64> = cal
                                .channels
                                .iter()
                                .map(|c| c.fit.effective_parameters)
                                .collect();
                            outcome.parameters = quantile(&mut p, 0.5);
                        }
                        Err(e) => outcome.failed = Some(e.to_string()),
                    }
                    if py.is_some() && enc != Encoding::Sixteen && frame_count == 2 {
                        let ext = if enc == Encoding::Jpeg95 {
                            "jpg"
                        } else {
                            "png"
                        };
                        let stem: PathBuf =
                            dir.path().join(format!("s{si}_c{ci}_{}_{ri}", enc as u8));
                        let (d, b) = (
                            stem.with_extension(format!("d.{ext}")),
                            stem.with_extension(format!("b.{ext}")),
                        );
                        std::fs::write(&d, rendered[0].1.as_ref().unwrap()).unwrap();
                        std::fs::write(&b, rendered[1].1.as_ref().unwrap()).unwrap();
                        outcome.peer_index = Some(peer_cases.len());
                        peer_cases.push(serde_json::json!({"dark": d, "bright": b, "t_dark": 1.0, "t_bright": ratio}));
                    }
                    outcomes.push(outcome);
                }
            }
        }
    }
    let ours_s = started.elapsed().as_secs_f64();
    let peer_curves: Vec<Vec<Vec<f64>>> = match &py {
        Some(py) => {
            let manifest = dir.path().join("cases.json");
            std::fs::write(&manifest, serde_json::to_vec(&peer_cases).unwrap()).unwrap();
            let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/opencv_debevec.py");
            let out = Command::new(py)
                .arg(script)
                .arg(&manifest)
                .output()
                .unwrap();
            if !out.status.success() {
                eprintln!(
                    "(OpenCV helper failed: {})",
                    String::from_utf8_lossy(&out.stderr)
                );
                Vec::new()
            } else {
                let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
                serde_json::from_value(v["curves"].clone()).unwrap()
            }
        }
        None => Vec::new(),
    };
    let peer_shape = |o: &Outcome| -> Option<f64> {
        let pc = peer_curves.get(o.peer_index?)?;
        let curve = &curves.iter().find(|(n, _)| *n == o.curve)?.1;
        Some(errors(curve, |c, k| pc[k][c]).1)
    };
    println!(
        "# Response recovery accuracy ({width}x{height} RGB pairs, degree auto, {} curves: 4 built-in + {} DoRF; scenes {}; render+calibrate+merge {ours_s:.1} s)",
        curves.len(),
        curves.len() - 4,
        scenes
            .iter()
            .map(|k| k.name())
            .collect::<Vec<_>>()
            .join(", ")
    );
    println!();
    println!(
        "Errors in stops over codes 16..239, DoRF curves only (all curves if DoRF is absent). 'scale' = largest |mean log2 g - log2 g_true| over channels; 'true-g merge' = median relative radiance error of the merge given the true response; 'gap' = the same with the fitted response minus it, percentage points. 'confident wrong' = confidence >= 0.5 but shape error > 0.1 stop."
    );
    println!();
    println!(
        "| encoding | scene | ratio | n | fail | shape median | shape p90 | shape max | own median | scale median | scale p90 | true-g merge | gap median (pp) | gap p90 (pp) | low conf. | confident wrong | eff. parameters median | OpenCV shape median | OpenCV p90 | ours better |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    let use_dorf = outcomes.iter().any(|o| o.curve.starts_with("dorf-"));
    for &enc in &encodings {
        for &kind in &scenes {
            for &ratio in &ratios {
                let set: Vec<&Outcome> = outcomes
                    .iter()
                    .filter(|o| {
                        o.enc == enc
                            && o.scene == kind
                            && o.ratio == ratio
                            && (!use_dorf || o.curve.starts_with("dorf-"))
                    })
                    .collect();
                let ok: Vec<&&Outcome> = set.iter().filter(|o| o.failed.is_none()).collect();
                let column = |f: &dyn Fn(&Outcome) -> f64| -> Vec<f64> {
                    ok.iter().map(|o| f(o)).filter(|v| v.is_finite()).collect()
                };
                let mut own = column(&|o| o.own);
                let mut shape = column(&|o| o.shape);
                let mut scale = column(&|o| o.scale);
                let mut merge_true: Vec<f64> = set
                    .iter()
                    .map(|o| o.merge_true)
                    .filter(|v| v.is_finite())
                    .collect();
                let mut gap = column(&|o| o.gap);
                let mut parameters = column(&|o| o.parameters);
                let low = ok.iter().filter(|o| o.confidence < 0.5).count();
                let wrong = ok
                    .iter()
                    .filter(|o| o.confidence >= 0.5 && o.shape > 0.1)
                    .count();
                let peer: Vec<(f64, f64)> = set
                    .iter()
                    .filter_map(|o| {
                        Some((
                            peer_shape(o)?,
                            if o.failed.is_none() {
                                o.shape
                            } else {
                                f64::INFINITY
                            },
                        ))
                    })
                    .collect();
                let (pm, pp, better) = if peer.is_empty() {
                    ("-".to_string(), "-".to_string(), "-".to_string())
                } else {
                    let mut p: Vec<f64> = peer.iter().map(|x| x.0).collect();
                    let wins = peer.iter().filter(|(p, o)| o < p).count();
                    (
                        format!("{:.4}", quantile(&mut p, 0.5)),
                        format!("{:.4}", quantile(&mut p.clone(), 0.9)),
                        format!("{:.0} %", 100.0 * wins as f64 / peer.len() as f64),
                    )
                };
                println!(
                    "| {} | {} | {ratio} | {} | {} | {:.4} | {:.4} | {:.3} | {:.4} | {:.4} | {:.4} | {:.2} % | {:.2} | {:.2} | {low} | {wrong} | {:.1} | {pm} | {pp} | {better} |",
                    enc.name(),
                    kind.name(),
                    set.len(),
                    set.len() - ok.len(),
                    quantile(&mut shape, 0.5),
                    quantile(&mut shape, 0.9),
                    quantile(&mut shape, 1.0),
                    quantile(&mut own, 0.5),
                    quantile(&mut scale, 0.5),
                    quantile(&mut scale, 0.9),
                    100.0 * quantile(&mut merge_true, 0.5),
                    100.0 * quantile(&mut gap, 0.5),
                    100.0 * quantile(&mut gap, 0.9),
                    quantile(&mut parameters, 0.5),
                );
            }
        }
    }
    if frame_count > 2 {
        println!();
        println!(
            "## {frame_count}-frame brackets ({ratio_list} apart): the joint fit against adjacent pairs fitted alone",
            ratio_list = ratios
                .iter()
                .map(|r| r.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        );
        println!();
        println!(
            "Scale = largest |scale error| over channels (stops); confidence = lowest over channels. 'best pair' = the adjacent pair with the smallest scale error (an oracle choice); 'middle pair' = the pair a two-frame darkroom would use."
        );
        println!();
        println!(
            "| encoding | scene | ratio | n | joint scale median | joint scale p90 | joint confidence median | joint low conf. | best pair scale median | best pair scale p90 | best pair confidence median | middle pair scale median | middle pair confidence median | middle pair low conf. |"
        );
        println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
        for &enc in &encodings {
            for &kind in &scenes {
                for &ratio in &ratios {
                    let ok: Vec<&Outcome> = outcomes
                        .iter()
                        .filter(|o| {
                            o.enc == enc
                                && o.scene == kind
                                && o.ratio == ratio
                                && o.failed.is_none()
                                && (!use_dorf || o.curve.starts_with("dorf-"))
                        })
                        .collect();
                    let mut scale: Vec<f64> = ok.iter().map(|o| o.scale).collect();
                    let mut confidence: Vec<f64> = ok.iter().map(|o| o.confidence).collect();
                    let best: Vec<(f64, f64)> = ok.iter().filter_map(|o| o.best_pair).collect();
                    let middle: Vec<(f64, f64)> = ok.iter().filter_map(|o| o.middle_pair).collect();
                    let mut best_scale: Vec<f64> = best.iter().map(|b| b.0).collect();
                    let mut best_conf: Vec<f64> = best.iter().map(|b| b.1).collect();
                    let mut middle_scale: Vec<f64> = middle.iter().map(|b| b.0).collect();
                    let mut middle_conf: Vec<f64> = middle.iter().map(|b| b.1).collect();
                    println!(
                        "| {} | {} | {ratio} | {} | {:.4} | {:.4} | {:.2} | {} | {:.4} | {:.4} | {:.2} | {:.4} | {:.2} | {} |",
                        enc.name(),
                        kind.name(),
                        ok.len(),
                        quantile(&mut scale, 0.5),
                        quantile(&mut scale, 0.9),
                        quantile(&mut confidence, 0.5),
                        ok.iter().filter(|o| o.confidence < 0.5).count(),
                        quantile(&mut best_scale, 0.5),
                        quantile(&mut best_scale, 0.9),
                        quantile(&mut best_conf, 0.5),
                        quantile(&mut middle_scale, 0.5),
                        quantile(&mut middle_conf, 0.5),
                        middle.iter().filter(|m| m.1 < 0.5).count(),
                    );
                }
            }
        }
    }
    if args.iter().any(|a| a == "--per-curve") {
        println!();
        println!(
            "| curve | scene | encoding | ratio | own | shape | scale | gap (pp) | confidence | OpenCV shape |"
        );
        println!("|---|---|---|---|---|---|---|---|---|---|");
        for o in &outcomes {
            println!(
                "| {} | {} | {} | {} | {:.4} | {:.4} | {:.4} | {:.2} | {:.2} | {} |",
                o.curve,
                o.scene.name(),
                o.enc.name(),
                o.ratio,
                o.own,
                o.shape,
                o.scale,
                100.0 * o.gap,
                o.confidence,
                peer_shape(o).map_or("-".into(), |p| format!("{p:.4}"))
            );
        }
    }
    println!();
    println!("## Named curves at ratio 4");
    println!();
    println!(
        "| curve | scene | encoding | own | shape | confidence | eff. parameters | OpenCV shape |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for o in outcomes
        .iter()
        .filter(|o| o.ratio == 4.0 && !o.curve.starts_with("dorf-"))
    {
        println!(
            "| {} | {} | {} | {:.4} | {:.4} | {:.2} | {:.1} | {} |",
            o.curve,
            o.scene.name(),
            o.enc.name(),
            o.own,
            o.shape,
            o.confidence,
            o.parameters,
            peer_shape(o).map_or("-".into(), |p| format!("{p:.4}"))
        );
    }
    let worst: Vec<&Outcome> = {
        let mut v: Vec<&Outcome> = outcomes
            .iter()
            .filter(|o| o.ratio == 4.0 && o.enc == Encoding::Lossless8)
            .collect();
        v.sort_by(|a, b| b.shape.total_cmp(&a.shape));
        v.into_iter().take(5).collect()
    };
    println!();
    println!(
        "Worst at ratio 4, 8-bit lossless: {}",
        worst
            .iter()
            .map(|o| format!(
                "{} on {} {:.3} (conf {:.2}, {:.1} eff. parameters)",
                o.curve,
                o.scene.name(),
                o.shape,
                o.confidence,
                o.parameters
            ))
            .collect::<Vec<_>>()
            .join("; ")
    );
    for o in outcomes.iter().filter(|o| o.failed.is_some()).take(5) {
        println!(
            "failed: {} {} ratio {}: {}",
            o.curve,
            o.enc.name(),
            o.ratio,
            o.failed.as_deref().unwrap_or("")
        );
    }
}
