//! Accuracy of response recovery against ground truth, and against OpenCV's
//! CalibrateDebevec on the same pairs.
//!
//! `cargo bench --bench response_accuracy [-- --quick] [--ratio R] [--encoding lossless|jpeg|16]
//! [--scene KIND[,KIND]] [--curves all|tune|report] [--every N] [--size WxH] [--curve NAME]
//! [--frames N] [--seed N] [--per-curve] [--noise-free] [--fits-only] [--features FILE]
//! [--fit-confidence FILE[,FILE] [--target colour|scale]] [--whole-frames]`
//!
//! `--quick` takes every tenth DoRF curve (`--every N`: every N-th); `--ratio` and
//! `--encoding` restrict the sweep to one ratio or one encoding; `--scene` to some scene
//! kinds (`procedural`, `studio`, `studio-falloff`, `flat-patches`; default these four),
//! or adds **real places**: `real` makes a scene of every real bracket in
//! `../shared/testdata/brackets` (its radiance map, scaled to mid grey; see
//! `common::real_scene`) and `real:NAME` of one (skipped where the test data are absent;
//! `--real-brackets DIR` takes the bracket folders of `DIR` instead);
//! `--curves tune` keeps the DoRF records whose index is a multiple of 4 and `report` the
//! others (index ≡ 2 mod 4), the split between curves a change is tuned on and curves its
//! accuracy is reported on; `--seed` renders another realisation of each scene kind
//! (default 7; colours, positions, textures); `--size` renders smaller scenes for quick runs. `--frames N`
//! (N ≥ 3) renders a bracket of N frames `γ` apart (exposures `γ^(k − (N−1)/2)`), fits it
//! jointly and compares with each adjacent pair fitted alone.
//! `--ratio` and `--encoding` (`lossless`, `jpeg` = q95, `jpeg90`, `16`) take comma lists.
//! Fits match each pair of frames over the pixels both share, as the darkroom does
//! (`calibrate_frames`); `--whole-frames` fits from the frames' whole histograms
//! (`calibrate_bracket`) instead, to measure what leaving out a JPEG's hard-clipped
//! blocks changes (lossless frames fit the same either way).
//!
//! **Confidence.** Every run ends with two reliability tables: per channel of every DoRF
//! fit, by confidence band, the share really bad and the share worse than the sRGB inverse
//! (own error, both `g(1) = 1`), first by the measure (scale error > 0.05 stop or
//! shape error > 0.1 stop), then by what the confidence predicts, what a relative map
//! shows (shape error > 0.1 stop or the scale more than 0.05 stop from the mean of the
//! fit's channels, the map's level); `--noise-free` also fits the same frames rendered
//! without noise and counts channels flagged low whose noise-free fit is good.
//! `--features FILE` appends each channel's
//! [`ChannelFit::features`](filmback::response::ChannelFit::features) and outcome to a
//! CSV; `--fit-confidence FILES [--target colour|scale]` refits the logistic model
//! (`filmback::response::fit::CONFIDENCE_MODEL`, `colour`) on such files and prints it with
//! its reliability there. `--fits-only` skips the merges and a bracket's single pairs (for
//! collecting features quickly).
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
use filmback::histogram::{FrameCounts, Histogram};
use filmback::merge::{self, BracketFrame, MergeOptions};
use filmback::metadata::Camera;
use filmback::radiance::RadianceMap;
use filmback::response::fit::{FEATURES, logistic_confidence};
use filmback::response::{
    Calibration, CalibrationError, Degree, InverseResponse, RatioSource, calibrate_bracket,
    calibrate_frames,
};
use filmback::synthetic::{
    self, Encoding as FileEncoding, ResponseCurve as Curve, SceneKind, Sensor, measure,
};
use nalgebra::{DMatrix, DVector};

#[path = "../common/mod.rs"]
mod common;
use common::{arg, quantile};

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

#[derive(Clone, Copy, PartialEq)]
enum Encoding {
    Lossless8,
    Jpeg95,
    Jpeg90,
    Sixteen,
}

impl Encoding {
    fn name(self) -> &'static str {
        match self {
            Encoding::Lossless8 => "8-bit lossless",
            Encoding::Jpeg95 => "8-bit JPEG q95",
            Encoding::Jpeg90 => "8-bit JPEG q90",
            Encoding::Sixteen => "16-bit",
        }
    }

    fn parse(name: &str) -> Encoding {
        match name {
            "lossless" => Encoding::Lossless8,
            "jpeg" | "jpeg95" => Encoding::Jpeg95,
            "jpeg90" => Encoding::Jpeg90,
            "16" => Encoding::Sixteen,
            other => panic!("--encoding takes lossless, jpeg, jpeg90 or 16, not {other}"),
        }
    }

    fn jpeg_quality(self) -> Option<u8> {
        match self {
            Encoding::Jpeg95 => Some(95),
            Encoding::Jpeg90 => Some(90),
            _ => None,
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
    noisy: bool,
) -> (Frame, Option<Vec<u8>>) {
    let sensor = Sensor {
        curve: curve.clone(),
        bit_depth: if enc == Encoding::Sixteen {
            BitDepth::Sixteen
        } else {
            BitDepth::Eight
        },
        read_noise_dn: match (noisy, enc) {
            (false, _) => 0.0,
            (true, Encoding::Sixteen) => NOISE_16,
            (true, _) => 1.0,
        },
        full_well_electrons: None,
        seed,
    };
    let frame = synthetic::expose(scene, exposure, &sensor);
    let shot = common::shot(exposure);
    match enc {
        Encoding::Sixteen => (frame, None),
        Encoding::Lossless8 => {
            let bytes = synthetic::encode(&frame, &shot, FileEncoding::Png).unwrap();
            (frame, Some(bytes))
        }
        Encoding::Jpeg95 | Encoding::Jpeg90 => {
            let quality = enc.jpeg_quality().unwrap_or(95);
            let bytes = synthetic::encode(&frame, &shot, FileEncoding::Jpeg { quality }).unwrap();
            let decoded = frame::decode(Path::new("synthetic.jpg"), &bytes, Limits::default())
                .unwrap()
                .frame;
            (decoded, Some(bytes))
        }
    }
}

/// Fits `frames` (counted, with their exposures) jointly ([`calibrate_frames`]: each pair
/// over the pixels both share), or from the frames' whole histograms
/// ([`calibrate_bracket`]) with `whole`. Two frames give the pair's fit at its known ratio.
fn fit_frames(
    frames: &[(&FrameCounts, f64)],
    whole: bool,
) -> Result<Calibration, CalibrationError> {
    if whole {
        let input: Vec<(&Histogram, f64)> =
            frames.iter().map(|(c, e)| (c.histogram(), *e)).collect();
        calibrate_bracket(&input, RatioSource::Argument, Degree::Auto)
    } else {
        calibrate_frames(frames, RatioSource::Argument, Degree::Auto)
    }
}

/// Each frame counted once ([`FrameCounts`], every pixel), with its exposure.
fn count<'a>(frames: &[(&'a Frame, f64)]) -> Vec<(FrameCounts<'a>, f64)> {
    frames
        .iter()
        .map(|&(f, e)| (FrameCounts::of_frame(f, 1), e))
        .collect()
}

/// (own, shape) error in stops, RMS over the three channels, of `g(channel, code)`.
fn errors(curve: &Curve, g: impl Fn(usize, usize) -> f64) -> (f64, f64) {
    let e = measure::curve_errors(3, |c, b| g(c, (b * 255.0).round() as usize), curve);
    let rms = |f: fn(&measure::CurveError) -> f64| {
        (e.iter().map(|x| f(x).powi(2)).sum::<f64>() / 3.0).sqrt()
    };
    (rms(|x| x.own), rms(|x| x.shape))
}

/// A scene brackets are rendered from: a synthetic kind, or a real place
/// ([`common::real_scene`]).
struct Scene {
    name: String,
    radiance: RadianceMap,
}

/// One adjacent pair of a bracket fitted alone.
#[derive(Clone, Copy)]
struct PairFit {
    /// Largest |scale error| over channels, stops.
    scale: f64,
    /// Largest minus smallest scale error over channels, stops.
    cast: f64,
    /// Lowest channel confidence.
    confidence: f64,
}

/// The largest |scale error| and the cast (largest minus smallest) of per-channel scale
/// errors, stops.
fn scale_and_cast(scales: &[f64]) -> (f64, f64) {
    let high = scales.iter().fold(f64::NEG_INFINITY, |a, &s| a.max(s));
    let low = scales.iter().fold(f64::INFINITY, |a, &s| a.min(s));
    (
        scales.iter().fold(0.0, |a: f64, s| a.max(s.abs())),
        high - low,
    )
}

struct Outcome {
    curve: String,
    /// Index into the scenes.
    scene: usize,
    ratio: f64,
    enc: Encoding,
    own: f64,
    shape: f64,
    /// Largest |scale error| over channels, stops.
    scale: f64,
    /// The colour cast: largest minus smallest scale error over channels, stops.
    cast: f64,
    /// Merged radiance error with the true response, fraction.
    merge_true: f64,
    /// Merged radiance error with the fitted response minus `merge_true`, fraction.
    gap: f64,
    /// N-frame brackets: the adjacent pairs fitted alone; the pair with the smallest scale
    /// error, the pair with the smallest cast (both oracle choices) and the middle pair.
    best_pair: Option<PairFit>,
    best_cast_pair: Option<PairFit>,
    middle_pair: Option<PairFit>,
    confidence: f64,
    /// Effective number of parameters, median over channels.
    parameters: f64,
    failed: Option<String>,
    peer_index: Option<usize>,
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
    let mut dorf = common::dorf_curves().unwrap_or_else(|e| {
        eprintln!("(DoRF curves unavailable: {e}: skipped)");
        Vec::new()
    });
    // The DoRF records are numbered 0, 2, 4, …: tune on multiples of 4, report on the rest.
    common::keep_split(&mut dorf, arg("--curves").as_deref().unwrap_or("all"));
    let every = arg("--every")
        .map(|n| n.parse::<usize>().expect("--every takes a whole number"))
        .unwrap_or(if quick { 10 } else { 1 });
    dorf = dorf.into_iter().step_by(every.max(1)).collect();
    curves.extend(dorf);
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
    let names: Vec<String> = match arg("--scene") {
        Some(list) => list.split(',').map(str::to_string).collect(),
        None => SceneKind::ALL
            .iter()
            .map(|k| k.name().to_string())
            .collect(),
    };
    let scenes = scenes(&names, width, height, scene_seed);
    // `--curve NAME` restricts to one curve and prints its fitted and true g per 16 codes.
    let only = args
        .iter()
        .position(|a| a == "--curve")
        .and_then(|i| args.get(i + 1))
        .cloned();
    if let Some(name) = &only {
        curves.retain(|(n, _)| n == name);
    }
    if let Some(files) = arg("--fit-confidence") {
        let criterion = match arg("--target").as_deref() {
            Some("scale") => Criterion::Scale,
            None | Some("colour") => Criterion::Colour,
            Some(other) => panic!("--target takes scale or colour, not {other}"),
        };
        fit_confidence(&files, criterion);
        return;
    }
    let ratios: Vec<f64> = match arg("--ratio") {
        Some(r) => r
            .split(',')
            .map(|r| r.parse().expect("--ratio takes numbers"))
            .collect(),
        None => RATIOS.to_vec(),
    };
    let encodings: Vec<Encoding> = match arg("--encoding") {
        Some(list) => list.split(',').map(Encoding::parse).collect(),
        None => vec![Encoding::Lossless8, Encoding::Jpeg95, Encoding::Sixteen],
    };
    let noise_free = args.iter().any(|a| a == "--noise-free");
    // Only the fits and their curve errors: no merges, no single pairs of a bracket.
    let fits_only = args.iter().any(|a| a == "--fits-only");
    let whole_frames = args.iter().any(|a| a == "--whole-frames");
    let has_dorf = curves.iter().any(|(n, _)| n.starts_with("dorf-"));
    let features_out = arg("--features");
    let mut records: Vec<ChannelRecord> = Vec::new();
    let mut features_file = features_out.map(|path| {
        std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&path)
            .unwrap_or_else(|e| panic!("{path}: {e}"))
    });
    let srgb = InverseResponse::srgb(3, 1024);
    let py = peer_python();
    if py.is_none() {
        eprintln!("(OpenCV peer unavailable: comparison skipped)");
    }
    let dir = tempfile::tempdir().unwrap();
    let mut outcomes = Vec::new();
    let mut peer_cases = Vec::new();
    let started = std::time::Instant::now();
    for (si, scene) in scenes.iter().enumerate() {
        let radiance = &scene.radiance;
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
                        .map(|(k, &e)| expose(radiance, e, curve, enc, seed + 50 * k as u64, true))
                        .collect();
                    let frames: Vec<(&Frame, f64)> = rendered
                        .iter()
                        .map(|r| &r.0)
                        .zip(exposures.iter().copied())
                        .collect();
                    let counts = count(&frames);
                    let counted: Vec<(&FrameCounts, f64)> =
                        counts.iter().map(|(c, e)| (c, *e)).collect();
                    let pair_fit = |i: usize| fit_frames(&counted[i..i + 2], whole_frames);
                    let result = fit_frames(&counted, whole_frames);
                    let summary = |cal: &Calibration| -> PairFit {
                        let (scale, cast) =
                            scale_and_cast(&measure::scale_errors(&cal.response, curve));
                        PairFit {
                            scale,
                            cast,
                            confidence: cal
                                .channels
                                .iter()
                                .map(|c| c.fit.confidence)
                                .fold(1.0, f64::min),
                        }
                    };
                    let pairs: Vec<Option<PairFit>> = if frame_count > 2 && !fits_only {
                        (0..frame_count - 1)
                            .map(|i| pair_fit(i).ok().map(|c| summary(&c)))
                            .collect()
                    } else {
                        Vec::new()
                    };
                    let best_by = |key: fn(&PairFit) -> f64| {
                        pairs
                            .iter()
                            .flatten()
                            .copied()
                            .min_by(|a, b| key(a).total_cmp(&key(b)))
                    };
                    let best_pair = best_by(|p| p.scale);
                    let best_cast_pair = best_by(|p| p.cast);
                    let middle_pair = pairs.get(frame_count / 2 - 1).copied().flatten();
                    let merge_true = if fits_only {
                        f64::NAN
                    } else {
                        merged_error(radiance, &frames, &g_true).unwrap_or(f64::NAN)
                    };
                    let mut outcome = Outcome {
                        curve: name.clone(),
                        scene: si,
                        ratio,
                        enc,
                        own: f64::NAN,
                        shape: f64::NAN,
                        scale: f64::NAN,
                        cast: f64::NAN,
                        merge_true,
                        gap: f64::NAN,
                        best_pair,
                        best_cast_pair,
                        middle_pair,
                        confidence: 0.0,
                        parameters: f64::NAN,
                        failed: None,
                        peer_index: None,
                    };
                    // The same frames without noise, fitted the same way: is a good fit
                    // possible from them at all?
                    // Per channel: (good, good in colour) — see `ChannelRecord::off_colour`.
                    let noise_free_good: Option<Vec<(bool, bool)>> = noise_free.then(|| {
                        let clean: Vec<Frame> = exposures
                            .iter()
                            .enumerate()
                            .map(|(k, &e)| {
                                expose(radiance, e, curve, enc, seed + 50 * k as u64, false).0
                            })
                            .collect();
                        let clean: Vec<(&Frame, f64)> =
                            clean.iter().zip(exposures.iter().copied()).collect();
                        let counts = count(&clean);
                        let counted: Vec<(&FrameCounts, f64)> =
                            counts.iter().map(|(c, e)| (c, *e)).collect();
                        let cal = fit_frames(&counted, whole_frames);
                        match cal {
                            Ok(cal) => {
                                let errors = measure::response_errors(&cal.response, curve);
                                let level = map_level(&errors);
                                errors
                                    .iter()
                                    .zip(&cal.channels)
                                    .map(|(e, ch)| {
                                        let fitted = ch.borrowed_from.is_none();
                                        let colour = good_in_colour(e.scale, e.shape, level);
                                        (fitted && good(e), fitted && colour)
                                    })
                                    .collect()
                            }
                            Err(_) => vec![(false, false); 3],
                        }
                    });
                    if let Ok(cal) = &result
                        && (!has_dorf || name.starts_with("dorf-"))
                    {
                        let srgb_errors = measure::response_errors(&srgb, curve);
                        let errors = measure::response_errors(&cal.response, curve);
                        let level = map_level(&errors);
                        for (c, (ch, e)) in cal.channels.iter().zip(errors).enumerate() {
                            records.push(ChannelRecord {
                                scene: scene.name.clone(),
                                curve: name.clone(),
                                enc: enc.name().to_string(),
                                ratio,
                                frames: frame_count,
                                channel: c,
                                borrowed: ch.borrowed_from.is_some(),
                                features: ch.fit.features(),
                                coverage: ch.fit.coverage,
                                equations: ch.fit.equations,
                                parameters: ch.fit.effective_parameters,
                                confidence: ch.fit.confidence,
                                scale: e.scale,
                                level,
                                shape: e.shape,
                                own: e.own,
                                srgb_own: srgb_errors[c.min(srgb_errors.len() - 1)].own,
                                noise_free_good: noise_free_good.as_ref().map(|g| g[c].0),
                                noise_free_colour_good: noise_free_good.as_ref().map(|g| g[c].1),
                            });
                            if let Some(file) = &mut features_file {
                                use std::io::Write;
                                let line = records.last().map(ChannelRecord::to_csv);
                                writeln!(file, "{}", line.unwrap_or_default()).unwrap();
                            }
                        }
                    }
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
                            (outcome.scale, outcome.cast) =
                                scale_and_cast(&measure::scale_errors(&cal.response, curve));
                            if !fits_only {
                                outcome.gap = merged_error(radiance, &frames, &cal.response)
                                    .map_or(f64::NAN, |e| e - merge_true);
                            }
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
                    if py.is_some() && enc != Encoding::Sixteen && frame_count == 2 && !fits_only {
                        let ext = if enc.jpeg_quality().is_some() {
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
    println!("## Reliability of the confidence (per channel)");
    println!();
    reliability(&records);
    println!();
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
    let dorf_count = curves
        .iter()
        .filter(|(n, _)| n.starts_with("dorf-"))
        .count();
    println!(
        "# Response recovery accuracy ({width}x{height} RGB pairs, degree auto, {} curves: {} built-in + {} DoRF; scenes {}; render+calibrate+merge {ours_s:.1} s)",
        curves.len(),
        curves.len() - dorf_count,
        dorf_count,
        scenes
            .iter()
            .map(|s| s.name.as_str())
            .collect::<Vec<_>>()
            .join(", ")
    );
    println!();
    println!(
        "Errors in stops over codes 16..239, DoRF curves only (all curves if DoRF is absent). 'scale' = largest |mean log2 g - log2 g_true| over channels; 'cast' = largest minus smallest scale error over channels (the colour cast); 'true-g merge' = median relative radiance error of the merge given the true response; 'gap' = the same with the fitted response minus it, percentage points. 'confident wrong' = confidence >= 0.5 but shape error > 0.1 stop."
    );
    println!();
    println!(
        "| encoding | scene | ratio | n | fail | shape median | shape p90 | shape max | own median | scale median | scale p90 | cast median | cast p90 | true-g merge | gap median (pp) | gap p90 (pp) | low conf. | confident wrong | eff. parameters median | OpenCV shape median | OpenCV p90 | ours better |"
    );
    println!(
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
    );
    let use_dorf = outcomes.iter().any(|o| o.curve.starts_with("dorf-"));
    for &enc in &encodings {
        for (kind, scene) in scenes.iter().enumerate() {
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
                let mut cast = column(&|o| o.cast);
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
                    "| {} | {} | {ratio} | {} | {} | {:.4} | {:.4} | {:.3} | {:.4} | {:.4} | {:.4} | {:.4} | {:.4} | {:.2} % | {:.2} | {:.2} | {low} | {wrong} | {:.1} | {pm} | {pp} | {better} |",
                    enc.name(),
                    scene.name,
                    set.len(),
                    set.len() - ok.len(),
                    quantile(&mut shape, 0.5),
                    quantile(&mut shape, 0.9),
                    quantile(&mut shape, 1.0),
                    quantile(&mut own, 0.5),
                    quantile(&mut scale, 0.5),
                    quantile(&mut scale, 0.9),
                    quantile(&mut cast, 0.5),
                    quantile(&mut cast, 0.9),
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
            "Scale = largest |scale error| over channels (stops); cast = largest minus smallest scale error over channels (stops); confidence = lowest over channels. 'best pair' = the adjacent pair with the smallest scale error, 'best-cast pair' the one with the smallest cast (oracle choices); 'middle pair' = the pair a two-frame darkroom would use."
        );
        println!();
        println!(
            "| encoding | scene | ratio | n | joint scale median | joint scale p90 | joint cast median | joint cast p90 | joint confidence median | joint low conf. | best pair scale median | best pair scale p90 | best-cast pair cast median | best-cast pair cast p90 | middle pair scale median | middle pair cast median | middle pair confidence median | middle pair low conf. |"
        );
        println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
        for &enc in &encodings {
            for (kind, scene) in scenes.iter().enumerate() {
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
                    let column = |f: &dyn Fn(&Outcome) -> Option<f64>| -> Vec<f64> {
                        ok.iter().filter_map(|o| f(o)).collect()
                    };
                    let mut scale = column(&|o| Some(o.scale));
                    let mut cast = column(&|o| Some(o.cast));
                    let mut confidence = column(&|o| Some(o.confidence));
                    let mut best_scale = column(&|o| o.best_pair.map(|p| p.scale));
                    let mut best_cast = column(&|o| o.best_cast_pair.map(|p| p.cast));
                    let mut middle_scale = column(&|o| o.middle_pair.map(|p| p.scale));
                    let mut middle_cast = column(&|o| o.middle_pair.map(|p| p.cast));
                    let mut middle_conf = column(&|o| o.middle_pair.map(|p| p.confidence));
                    println!(
                        "| {} | {} | {ratio} | {} | {:.4} | {:.4} | {:.4} | {:.4} | {:.2} | {} | {:.4} | {:.4} | {:.4} | {:.4} | {:.4} | {:.4} | {:.2} | {} |",
                        enc.name(),
                        scene.name,
                        ok.len(),
                        quantile(&mut scale, 0.5),
                        quantile(&mut scale, 0.9),
                        quantile(&mut cast, 0.5),
                        quantile(&mut cast, 0.9),
                        quantile(&mut confidence, 0.5),
                        ok.iter().filter(|o| o.confidence < 0.5).count(),
                        quantile(&mut best_scale, 0.5),
                        quantile(&mut best_scale, 0.9),
                        quantile(&mut best_cast, 0.5),
                        quantile(&mut best_cast, 0.9),
                        quantile(&mut middle_scale, 0.5),
                        quantile(&mut middle_cast, 0.5),
                        quantile(&mut middle_conf, 0.5),
                        middle_conf.iter().filter(|&&c| c < 0.5).count(),
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
                scenes[o.scene].name,
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
            scenes[o.scene].name,
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
                o.curve, scenes[o.scene].name, o.shape, o.confidence, o.parameters
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

/// Good by the measure: scale error ≤ 0.05 stop and shape error ≤ 0.1 stop (the
/// confidence predicts the part a relative map shows: [`ChannelRecord::off_colour`]).
fn good(e: &measure::CurveError) -> bool {
    e.scale.abs() <= 0.05 && e.shape <= 0.1
}

/// A fit's map level error: the mean of its channels' scale errors (stops).
fn map_level(errors: &[measure::CurveError]) -> f64 {
    errors.iter().map(|e| e.scale).sum::<f64>() / errors.len() as f64
}

/// Good in what a relative map shows: shape error ≤ 0.1 stop and the scale error within
/// 0.05 stop of the map's `level` (stops).
fn good_in_colour(scale: f64, shape: f64, level: f64) -> bool {
    (scale - level).abs() <= 0.05 && shape <= 0.1
}

/// The scenes named on the command line, in order: a [`SceneKind`] by its name, rendered
/// at `width × height` with `seed`; `real` every real bracket of
/// `../shared/testdata/brackets` (or of `--real-brackets DIR`) made into a scene of about
/// as many pixels ([`common::real_scene`]), `real:NAME` one of them. Real scenes that
/// cannot be made (no test data here, an unreadable frame) are skipped with a message.
fn scenes(names: &[String], width: u32, height: u32, seed: u64) -> Vec<Scene> {
    let pixels = f64::from(width) * f64::from(height);
    let mut out = Vec::new();
    for name in names {
        let real = name
            .strip_prefix("real")
            .filter(|rest| rest.is_empty() || rest.starts_with(':'));
        let Some(rest) = real else {
            let kind: SceneKind = name.parse().unwrap_or_else(|e| panic!("{e}"));
            out.push(Scene {
                name: kind.name().to_string(),
                radiance: kind.render(width, height, seed),
            });
            continue;
        };
        let only = rest.strip_prefix(':');
        let root = arg("--real-brackets").map_or_else(common::testdata_brackets, PathBuf::from);
        let brackets = common::real_brackets(&root);
        if brackets.is_empty() {
            eprintln!("(real brackets unavailable: the real scenes are skipped)");
        }
        for (bracket, frames) in brackets {
            if only.is_some_and(|o| o != bracket) {
                continue;
            }
            match common::real_scene(&frames, pixels) {
                Ok(radiance) => out.push(Scene {
                    name: format!("real:{bracket}"),
                    radiance,
                }),
                Err(e) => eprintln!("(real scene {bracket}: {e}: skipped)"),
            }
        }
    }
    out
}

/// One channel of one fit: what the fit knew and how it came out.
struct ChannelRecord {
    scene: String,
    curve: String,
    enc: String,
    ratio: f64,
    frames: usize,
    channel: usize,
    borrowed: bool,
    features: [f64; FEATURES],
    coverage: f64,
    /// The fit's equations (tone pairs) and effective parameters, for exploring features.
    equations: usize,
    parameters: f64,
    confidence: f64,
    scale: f64,
    /// The map's level error: the mean of the fit's channels' scale errors (stops).
    level: f64,
    shape: f64,
    own: f64,
    /// The own error of the sRGB inverse against the same true curve.
    srgb_own: f64,
    /// Whether the same frames without noise give a good fit of this channel.
    noise_free_good: Option<bool>,
    /// Whether they give a channel good in colour (not [`ChannelRecord::off_colour`]).
    noise_free_colour_good: Option<bool>,
}

impl ChannelRecord {
    fn bad(&self) -> bool {
        !(self.scale.abs() <= 0.05 && self.shape <= 0.1)
    }

    /// Bad in what a relative radiance map shows: shape error > 0.1 stop or the channel's
    /// scale more than 0.05 stop from the map's level (its part of the colour cast).
    fn off_colour(&self) -> bool {
        !good_in_colour(self.scale, self.shape, self.level)
    }

    fn worse_than_srgb(&self) -> bool {
        // NaN (a failed curve) counts as worse.
        !matches!(
            self.own.partial_cmp(&self.srgb_own),
            Some(std::cmp::Ordering::Less | std::cmp::Ordering::Equal)
        )
    }

    fn to_csv(&self) -> String {
        let mut v = vec![
            self.scene.clone(),
            self.curve.clone(),
            self.enc.clone(),
            self.ratio.to_string(),
            self.frames.to_string(),
            self.channel.to_string(),
            u8::from(self.borrowed).to_string(),
        ];
        v.extend(self.features.iter().map(|x| format!("{x:.6}")));
        v.extend(
            [
                self.coverage,
                self.confidence,
                self.scale,
                self.level,
                self.shape,
                self.own,
                self.srgb_own,
            ]
            .iter()
            .map(|x| format!("{x:.6}")),
        );
        for flag in [self.noise_free_good, self.noise_free_colour_good] {
            v.push(match flag {
                None => "-".into(),
                Some(g) => u8::from(g).to_string(),
            });
        }
        v.push(self.equations.to_string());
        v.push(format!("{:.3}", self.parameters));
        v.join(",")
    }

    fn from_csv(line: &str) -> Option<ChannelRecord> {
        let f: Vec<&str> = line.split(',').collect();
        if f.len() != 7 + FEATURES + 11 {
            return None;
        }
        let num = |i: usize| f[i].parse::<f64>().ok();
        let flag = |s: &str| match s {
            "1" => Some(true),
            "0" => Some(false),
            _ => None,
        };
        let mut features = [0.0; FEATURES];
        for (k, x) in features.iter_mut().enumerate() {
            *x = num(7 + k)?;
        }
        let o = 7 + FEATURES + 1;
        Some(ChannelRecord {
            scene: f[0].into(),
            curve: f[1].into(),
            enc: f[2].into(),
            ratio: num(3)?,
            frames: f[4].parse().ok()?,
            channel: f[5].parse().ok()?,
            borrowed: f[6] == "1",
            features,
            coverage: num(o - 1)?,
            confidence: num(o)?,
            scale: num(o + 1)?,
            level: num(o + 2)?,
            shape: num(o + 3)?,
            own: num(o + 4)?,
            srgb_own: num(o + 5)?,
            noise_free_good: flag(f[o + 6]),
            noise_free_colour_good: flag(f[o + 7]),
            equations: f[o + 8].parse().ok()?,
            parameters: num(o + 9)?,
        })
    }
}

/// What "bad" means for a channel in the reliability tables and the confidence's fit.
#[derive(Clone, Copy, PartialEq)]
enum Criterion {
    /// The issue's: scale error > 0.05 stop or shape error > 0.1 stop.
    Scale,
    /// What a relative radiance map shows: [`ChannelRecord::off_colour`].
    Colour,
}

impl Criterion {
    fn bad(self, r: &ChannelRecord) -> bool {
        match self {
            Criterion::Scale => r.bad(),
            Criterion::Colour => r.off_colour(),
        }
    }

    fn noise_free_good(self, r: &ChannelRecord) -> Option<bool> {
        match self {
            Criterion::Scale => r.noise_free_good,
            Criterion::Colour => r.noise_free_colour_good,
        }
    }

    fn words(self) -> &'static str {
        match self {
            Criterion::Scale => "bad = scale error > 0.05 stop or shape error > 0.1 stop",
            Criterion::Colour => {
                "bad = the channel's scale error more than 0.05 stop from the mean of its fit's channels (the map's level) or shape error > 0.1 stop"
            }
        }
    }
}

/// Prints the reliability tables of `records` under both [`Criterion`]s.
fn reliability(records: &[ChannelRecord]) {
    for criterion in [Criterion::Scale, Criterion::Colour] {
        reliability_by(records, criterion);
        println!();
    }
}

/// Prints the reliability table of `records`: per confidence band, how many channels,
/// the share really bad under `criterion`, the share worse than the sRGB inverse (own
/// error), and per encoding and number of frames the three checks.
fn reliability_by(records: &[ChannelRecord], criterion: Criterion) {
    const BANDS: [(f64, f64); 6] = [
        (0.0, 0.1),
        (0.1, 0.3),
        (0.3, 0.5),
        (0.5, 0.7),
        (0.7, 0.9),
        (0.9, 1.01),
    ];
    let share = |n: usize, of: usize| {
        if of == 0 {
            "-".to_string()
        } else {
            format!("{:.1} %", 100.0 * n as f64 / of as f64)
        }
    };
    let bad = |r: &ChannelRecord| criterion.bad(r);
    let mut groups: Vec<(String, usize)> = Vec::new();
    for r in records {
        if !groups.iter().any(|g| g.0 == r.enc && g.1 == r.frames) {
            groups.push((r.enc.clone(), r.frames));
        }
    }
    println!(
        "Per channel; {}; worse than sRGB = own error above the sRGB inverse's (both g(1) = 1).",
        criterion.words()
    );
    println!();
    println!(
        "| encoding | frames | confidence | channels | bad | worse than sRGB | noise-free fit good |"
    );
    println!("|---|---|---|---|---|---|---|");
    for (enc, frames) in &groups {
        let set: Vec<&ChannelRecord> = records
            .iter()
            .filter(|r| &r.enc == enc && r.frames == *frames)
            .collect();
        for (lo, hi) in BANDS {
            let band: Vec<&&ChannelRecord> = set
                .iter()
                .filter(|r| r.confidence >= lo && r.confidence < hi)
                .collect();
            let clean: Vec<bool> = band
                .iter()
                .filter_map(|r| criterion.noise_free_good(r))
                .collect();
            println!(
                "| {enc} | {frames} | {lo:.1}–{:.1} | {} | {} | {} | {} |",
                hi.min(1.0),
                band.len(),
                share(band.iter().filter(|r| bad(r)).count(), band.len()),
                share(
                    band.iter().filter(|r| r.worse_than_srgb()).count(),
                    band.len()
                ),
                share(clean.iter().filter(|g| **g).count(), clean.len()),
            );
        }
    }
    println!();
    println!(
        "| encoding | frames | channels | confident (≥ 0.5) | confident and bad | low (< 0.5) | low and worse than sRGB | low and bad | low where the noise-free fit is good | bad (all) |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|");
    for (enc, frames) in &groups {
        let set: Vec<&ChannelRecord> = records
            .iter()
            .filter(|r| &r.enc == enc && r.frames == *frames)
            .collect();
        let (sure, low): (Vec<&&ChannelRecord>, Vec<&&ChannelRecord>) =
            set.iter().partition(|r| r.confidence >= 0.5);
        let low_clean = low
            .iter()
            .filter(|r| criterion.noise_free_good(r) == Some(true))
            .count();
        println!(
            "| {enc} | {frames} | {} | {} | {} | {} | {} | {} | {} | {} |",
            set.len(),
            sure.len(),
            share(sure.iter().filter(|r| bad(r)).count(), sure.len()),
            low.len(),
            share(
                low.iter().filter(|r| r.worse_than_srgb()).count(),
                low.len()
            ),
            share(low.iter().filter(|r| bad(r)).count(), low.len()),
            if low.iter().any(|r| criterion.noise_free_good(r).is_some()) {
                low_clean.to_string()
            } else {
                "-".into()
            },
            share(set.iter().filter(|r| bad(r)).count(), set.len()),
        );
    }
}

/// Fits the logistic confidence model (`filmback::response::fit::CONFIDENCE_MODEL`) by
/// maximum likelihood (Newton's method, a small ridge) to the records of the CSV `files`
/// (comma separated, written by `--features`), outcome "good" under `criterion`
/// (`--target scale` or `colour`), borrowed channels left out; prints the coefficients
/// and the reliability of the refitted model (times the coverage, as the library applies
/// it) on the same records.
fn fit_confidence(files: &str, criterion: Criterion) {
    let mut records: Vec<ChannelRecord> = files
        .split(',')
        .flat_map(|f| {
            std::fs::read_to_string(f)
                .unwrap_or_else(|e| panic!("{f}: {e}"))
                .lines()
                .filter_map(ChannelRecord::from_csv)
                .collect::<Vec<_>>()
        })
        .filter(|r| !r.borrowed && r.features.iter().all(|x| x.is_finite()))
        .collect();
    let k = FEATURES + 1;
    let row = |r: &ChannelRecord| {
        let mut x = vec![1.0];
        x.extend(r.features);
        x
    };
    let mut beta = DVector::<f64>::zeros(k);
    for _ in 0..50 {
        let mut hessian = DMatrix::<f64>::identity(k, k) * 1e-3;
        let mut gradient = -&beta * 1e-3;
        for r in &records {
            let x = DVector::from_vec(row(r));
            let p = 1.0 / (1.0 + (-x.dot(&beta)).exp());
            let y = if criterion.bad(r) { 0.0 } else { 1.0 };
            gradient += &x * (y - p);
            hessian += &x * x.transpose() * (p * (1.0 - p)).max(1e-9);
        }
        let step = hessian
            .lu()
            .solve(&gradient)
            .expect("Hessian is positive definite");
        beta += &step;
        if step.norm() < 1e-9 {
            break;
        }
    }
    println!(
        "CONFIDENCE_MODEL (fitted on {} channels, {} bad): [{}]",
        records.len(),
        records.iter().filter(|r| criterion.bad(r)).count(),
        beta.iter()
            .map(|b| format!("{b:.3}"))
            .collect::<Vec<_>>()
            .join(", ")
    );
    let beta: [f64; FEATURES + 1] = std::array::from_fn(|i| beta[i]);
    for r in &mut records {
        // As the library applies it: capped by the predicted shape error, times the coverage.
        let predicted = r.features[0].exp() - 0.001;
        let cap = 1.0 / (1.0 + (predicted / 0.2).powi(2));
        r.confidence = r.coverage * logistic_confidence(&beta, &r.features).min(cap);
    }
    println!();
    reliability(&records);
}
