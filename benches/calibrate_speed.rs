//! Speed against accuracy of `calibrate` on a 24 MP pair, for every stride × degree knob,
//! beside OpenCV's CalibrateDebevec on the same pair (when the peer's Python is present).
//!
//! `cargo bench --bench calibrate_speed [-- --small]` (`--small`: 6 MP, for a quick look).
//!
//! The pair: the synthetic scene (6000×4000) through the sRGB curve and a film-S curve,
//! 8-bit with 1 DN read noise, ratio 4, JPEG q95 (decoded once; decode time is not part
//! of either side's figure). Histograms are counted as the darkroom counts them (each
//! frame, its hard-clipped JPEG blocks, the pixels the pair shares: `shared_counts`).
//! Times are the median of 5 runs; error as in
//! `response_accuracy` (stops over codes 16..239; shape = after the best scale).
//!
//! Then a 5-frame bracket (sRGB, exposures 1/4 … 4, one stop apart, 8-bit with 1 DN
//! read noise), lossless and as JPEG q95: histograms at the balanced stride and the joint
//! fit of all ten pairs (`calibrate_frames`, which shares a JPEG pair's pixels first), as
//! the darkroom runs it.

use std::path::Path;
use std::process::Command;
use std::time::Instant;

use filmback::frame::{self, BitDepth, Frame, Limits};
use filmback::histogram::{FrameCounts, Histogram, shared_counts};
use filmback::response::{Degree, Ratio, RatioSource, calibrate, calibrate_frames};
use filmback::synthetic::{self, Encoding, ResponseCurve, Sensor, measure};

mod common;

fn median_ms(mut f: impl FnMut()) -> f64 {
    let mut t: Vec<f64> = (0..5)
        .map(|_| {
            let s = Instant::now();
            f();
            s.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    t.sort_by(f64::total_cmp);
    t[2]
}

/// (own, shape) error in stops, RMS over the three channels, of `g(channel, code)`.
fn errors(curve: &ResponseCurve, g: impl Fn(usize, usize) -> f64) -> (f64, f64) {
    let e = measure::curve_errors(3, |c, b| g(c, (b * 255.0).round() as usize), curve);
    let rms = |f: fn(&measure::CurveError) -> f64| {
        (e.iter().map(|x| f(x).powi(2)).sum::<f64>() / 3.0).sqrt()
    };
    (rms(|x| x.own), rms(|x| x.shape))
}

fn peer(dir: &Path, ratio: f64) -> Option<(f64, Vec<Vec<f64>>)> {
    let out = Command::new("/work/shared/peer/setup.sh").output().ok()?;
    let py = String::from_utf8(out.stdout).ok()?.trim().to_string();
    let cases = serde_json::json!([{"dark": dir.join("dark.jpg"), "bright": dir.join("bright.jpg"), "t_dark": 1.0, "t_bright": ratio}]);
    let manifest = dir.join("cases.json");
    std::fs::write(&manifest, serde_json::to_vec(&cases).ok()?).ok()?;
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/opencv_debevec.py");
    let out = Command::new(py).arg(script).arg(&manifest).output().ok()?;
    if !out.status.success() {
        eprintln!(
            "(OpenCV helper failed: {})",
            String::from_utf8_lossy(&out.stderr)
        );
        return None;
    }
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).ok()?;
    let curve: Vec<Vec<f64>> = serde_json::from_value(v["curves"][0].clone()).ok()?;
    Some((v["ms"][0].as_f64()?, curve))
}

fn main() {
    let small = std::env::args().any(|a| a == "--small");
    let (w, h) = if small { (3000, 2000) } else { (6000, 4000) };
    let ratio = 4.0;
    let started = Instant::now();
    let scene = synthetic::scene(w, h, 3);
    eprintln!("scene {w}x{h} in {:.1} s", started.elapsed().as_secs_f64());
    let dir = tempfile::tempdir().unwrap();
    for (name, curve) in [
        ("srgb", ResponseCurve::Srgb),
        ("film-s", ResponseCurve::FilmS),
    ] {
        let sensor = Sensor {
            curve: curve.clone(),
            bit_depth: BitDepth::Eight,
            read_noise_dn: 1.0,
            full_well_electrons: None,
            seed: 11,
        };
        let frames: Vec<Frame> = [("dark.jpg", 0.5), ("bright.jpg", 2.0)]
            .iter()
            .map(|&(file, e)| {
                let f = synthetic::expose(&scene, e, &sensor);
                let bytes = synthetic::encode(&f, &common::shot(e), Encoding::Jpeg { quality: 95 })
                    .unwrap();
                std::fs::write(dir.path().join(file), &bytes).unwrap();
                frame::decode(Path::new(file), &bytes, Limits::default())
                    .unwrap()
                    .frame
            })
            .collect();
        let peer = peer(dir.path(), ratio);
        println!("\n## {w}×{h} JPEG q95 pair, {name} curve, ratio {ratio}\n");
        println!(
            "| stride | degree | eff. parameters | histograms (ms) | of which the blocks | fit (ms) | total (ms) | own error | shape error | min confidence | vs OpenCV time | vs OpenCV shape error |"
        );
        println!("|---|---|---|---|---|---|---|---|---|---|---|---|");
        for stride in [1, 2, 4, 8, 16] {
            // The frames' histograms alone, for the cost of finding the blocks and sharing.
            let plain_ms = median_ms(|| {
                frames.iter().for_each(|f| {
                    std::hint::black_box(Histogram::of_frame(f, stride));
                })
            });
            // As the darkroom counts a pair: both frames, then the pixels they share.
            let mut hists = Vec::new();
            let hist_ms = median_ms(|| {
                let counts: Vec<FrameCounts> = frames
                    .iter()
                    .map(|f| FrameCounts::of_frame(f, stride))
                    .collect();
                let (dark, bright) = shared_counts(&counts[0], &counts[1]);
                hists = vec![dark.into_owned(), bright.into_owned()];
            });
            for (label, degree) in [
                ("3", Degree::Fixed(3)),
                ("6", Degree::Fixed(6)),
                ("auto", Degree::Auto),
            ] {
                let mut result = None;
                let fit_ms = median_ms(|| {
                    result = Some(calibrate(
                        &hists[0],
                        &hists[1],
                        Ratio::Known(ratio, RatioSource::Argument),
                        degree,
                    ));
                });
                let cal = result.unwrap().unwrap();
                let (own, shape) = errors(&curve, |c, k| cal.response.eval(c, k as f64 / 255.0));
                let conf = cal
                    .channels
                    .iter()
                    .map(|c| c.fit.confidence)
                    .fold(1.0, f64::min);
                let mut parameters: Vec<f64> = cal
                    .channels
                    .iter()
                    .map(|c| c.fit.effective_parameters)
                    .collect();
                parameters.sort_by(f64::total_cmp);
                let parameters = parameters[parameters.len() / 2];
                let (vt, ve) = match &peer {
                    Some((ms, pc)) => {
                        let (_, ps) = errors(&curve, |c, k| pc[k][c]);
                        (
                            format!("{:.2}×", (hist_ms + fit_ms) / ms),
                            format!("{:.2}×", shape / ps),
                        )
                    }
                    None => ("-".into(), "-".into()),
                };
                println!(
                    "| {stride} | {label} | {parameters:.1} | {hist_ms:.1} | {:.1} | {fit_ms:.1} | {:.1} | {own:.4} | {shape:.4} | {conf:.2} | {vt} | {ve} |",
                    hist_ms - plain_ms,
                    hist_ms + fit_ms
                );
            }
        }
        match &peer {
            Some((ms, pc)) => {
                let (_, ps) = errors(&curve, |c, k| pc[k][c]);
                println!(
                    "| OpenCV CalibrateDebevec | 70 samples, λ 10 | - | - | - | - | {ms:.1} | - | {ps:.4} | - | 1× | 1× |"
                );
            }
            None => println!("(OpenCV peer unavailable: skipped)"),
        }
    }
    let sensor = Sensor {
        curve: ResponseCurve::Srgb,
        bit_depth: BitDepth::Eight,
        read_noise_dn: 1.0,
        full_well_electrons: None,
        seed: 11,
    };
    let exposures = [0.25, 0.5, 1.0, 2.0, 4.0];
    // Every 4th pixel of every 4th row (the darkroom takes 2 at 24 MP, `docs/performance.md`).
    let stride = 4;
    println!("\n## {w}×{h} 5-frame bracket (sRGB, one stop apart), stride {stride}\n");
    println!(
        "| frames | histograms (ms) | joint fit (ms) | total (ms) | own error | shape error | min confidence |"
    );
    println!("|---|---|---|---|---|---|---|");
    for jpeg in [false, true] {
        let frames: Vec<Frame> = exposures
            .iter()
            .map(|&e| {
                let f = synthetic::expose(&scene, e, &sensor);
                if !jpeg {
                    return f;
                }
                let bytes = synthetic::encode(&f, &common::shot(e), Encoding::Jpeg { quality: 95 })
                    .unwrap();
                frame::decode(Path::new("frame.jpg"), &bytes, Limits::default())
                    .unwrap()
                    .frame
            })
            .collect();
        let mut counts = Vec::new();
        let hist_ms = median_ms(|| {
            counts = frames
                .iter()
                .map(|f| FrameCounts::of_frame(f, stride))
                .collect();
        });
        // The joint fit shares each pair's pixels (JPEG) before it fits.
        let mut result = None;
        let fit_ms = median_ms(|| {
            let input: Vec<(&FrameCounts, f64)> = counts.iter().zip(exposures).collect();
            result = Some(calibrate_frames(
                &input,
                RatioSource::Argument,
                Degree::Auto,
            ));
        });
        let cal = result.unwrap().unwrap();
        let (own, shape) = errors(&ResponseCurve::Srgb, |c, k| {
            cal.response.eval(c, k as f64 / 255.0)
        });
        println!(
            "| {} | {hist_ms:.1} | {fit_ms:.1} | {:.1} | {own:.4} | {shape:.4} | {:.2} |",
            if jpeg { "JPEG q95" } else { "8-bit lossless" },
            hist_ms + fit_ms,
            cal.channels
                .iter()
                .map(|c| c.fit.confidence)
                .fold(1.0, f64::min)
        );
    }
}
