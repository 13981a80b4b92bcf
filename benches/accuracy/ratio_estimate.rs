//! How well the exposure ratio is estimated when a pair has no EXIF.
//!
//! `cargo bench --bench ratio_estimate [-- --curves tune|report|all] [--size WxH]
//! [--brackets DIR]`
//!
//! Histograms alone fix the inverse response only up to a power (`g^k` with `γ^k`), so the
//! estimate rests on a prior, [`filmback::response::PRIOR_MID_GREY`]: the value of `g` at
//! mid brightness. This bench shows both sides of that prior:
//!
//! 1. **Synthetic pairs**: every scene kind exposed through the DoRF curves (split as in
//!    `response_accuracy`: `tune` = records ≡ 0 mod 4, `report` = the others; default
//!    `report`) at ratios 2, 4 and 8, 8-bit lossless with 1 DN read noise. For each the
//!    estimated ratio over the true one, and the curve's own `g(0.5)`, so a reader sees how
//!    much of the error is the prior's (a curve whose mid grey differs from the prior
//!    cannot be estimated right by any histogram method).
//! 2. **Real pairs**: the adjacent frames of `../shared/testdata/brackets/` (skipped when
//!    absent) with their known ratios: `frobisher` (EXIF), `learnopencv` (exposure time
//!    from EXIF, same aperture, no ISO), `memorial` (`exposure_times_seconds.csv`); with
//!    `--brackets DIR`, the folders of `DIR` instead (and no synthetic pairs).

use std::path::{Path, PathBuf};

use filmback::frame::{self, BitDepth, Limits};
use filmback::histogram::{FrameCounts, Histogram, shared_counts};
use filmback::response::{Degree, PRIOR_MID_GREY, Ratio, calibrate};
use filmback::synthetic::{self, SceneKind, Sensor};

#[path = "../common/mod.rs"]
mod common;
use common::arg;

const RATIOS: [f64; 3] = [2.0, 4.0, 8.0];

/// `(median, p10, p90)` of `v`, or NaNs when empty.
fn spread(v: &mut [f64]) -> (f64, f64, f64) {
    if v.is_empty() {
        return (f64::NAN, f64::NAN, f64::NAN);
    }
    (
        common::quantile(v, 0.5),
        common::quantile(v, 0.1),
        common::quantile(v, 0.9),
    )
}

/// The estimated ratio of one pair of histograms and the range it states
/// ([`filmback::response::Calibration::ratio_range`]), or `None` when the pair cannot be
/// calibrated.
fn estimate(dark: &Histogram, bright: &Histogram) -> Option<(f64, (f64, f64))> {
    let c = calibrate(dark, bright, Ratio::Estimate, Degree::Auto).ok()?;
    Some((c.ratio, c.ratio_range()?))
}

fn synthetic_pairs(split: &str, width: u32, height: u32) {
    let mut curves = match common::dorf_curves() {
        Ok(c) => c,
        Err(e) => {
            eprintln!("(DoRF curves unavailable: {e}: synthetic pairs skipped)");
            return;
        }
    };
    common::keep_split(&mut curves, split);
    let mut mids: Vec<f64> = curves.iter().map(|(_, c)| c.inverse(0.5)).collect();
    let (m, lo, hi) = spread(&mut mids);
    println!(
        "DoRF {split} ({} curves): g(0.5) median {m:.3}, p10 {lo:.3}, p90 {hi:.3}; prior {PRIOR_MID_GREY:.3}\n",
        curves.len()
    );
    println!("| scene | ratio | pairs | failed | est/true median | p10 | p90 | true in range |");
    println!("|---|---|---|---|---|---|---|---|");
    let mut all = Vec::new();
    let mut covered_all = 0;
    for kind in SceneKind::ALL {
        let scene = kind.render(width, height, 21);
        for ratio in RATIOS {
            let mut r = Vec::new();
            let (mut failed, mut covered) = (0, 0);
            for (ci, (_, curve)) in curves.iter().enumerate() {
                let sensor = |seed| Sensor {
                    read_noise_dn: 1.0,
                    seed,
                    ..Sensor::noiseless(curve.clone(), BitDepth::Eight)
                };
                let dark = synthetic::expose(&scene, 1.0 / ratio.sqrt(), &sensor(ci as u64));
                let bright = synthetic::expose(&scene, ratio.sqrt(), &sensor(ci as u64 + 7));
                match estimate(
                    &Histogram::of_frame(&dark, 1),
                    &Histogram::of_frame(&bright, 1),
                ) {
                    Some((e, (lo, hi))) => {
                        r.push(e / ratio);
                        covered += usize::from((lo..=hi).contains(&ratio));
                    }
                    None => failed += 1,
                }
            }
            all.extend_from_slice(&r);
            covered_all += covered;
            let n = r.len();
            let (m, lo, hi) = spread(&mut r);
            println!(
                "| {} | {ratio} | {n} | {failed} | {m:.3} | {lo:.3} | {hi:.3} | {:.0} % |",
                kind.name(),
                100.0 * covered as f64 / n.max(1) as f64
            );
        }
    }
    let n = all.len();
    let (m, lo, hi) = spread(&mut all);
    println!(
        "| all | 2–8 | {n} | | {m:.3} | {lo:.3} | {hi:.3} | {:.0} % |\n",
        100.0 * covered_all as f64 / n.max(1) as f64
    );
}

/// Two adjacent frames of a real set, darker first, and their true ratio.
type RealPair = (PathBuf, PathBuf, f64);

/// Each real set's name and adjacent pairs ([`common::real_brackets`]).
fn real_sets(root: &Path) -> Vec<(String, Vec<RealPair>)> {
    common::real_brackets(root)
        .into_iter()
        .map(|(name, files)| {
            let pairs = files
                .windows(2)
                .map(|w| (w[0].0.clone(), w[1].0.clone(), w[1].1 / w[0].1))
                .collect();
            (name, pairs)
        })
        .collect()
}

fn real_pairs(root: &Path) {
    let sets = real_sets(root);
    if sets.is_empty() {
        eprintln!("(real brackets unavailable: skipped)");
        return;
    }
    println!("| set | pair | true ratio | estimated | est/true | stated range |");
    println!("|---|---|---|---|---|---|");
    let mut all = Vec::new();
    let mut covered = 0;
    for (name, pairs) in sets {
        for (dark, bright, ratio) in pairs {
            let load = |p: &Path| frame::load(p, Limits::default()).map(|l| l.frame);
            let (Ok(d), Ok(b)) = (load(&dark), load(&bright)) else {
                continue;
            };
            let stride = ((d.width() as f64 * d.height() as f64) / 3e6)
                .sqrt()
                .max(1.0) as usize;
            // As `filmback calibrate` counts a pair: over the pixels both frames share.
            let (cd, cb) = (
                FrameCounts::of_frame(&d, stride),
                FrameCounts::of_frame(&b, stride),
            );
            let (hd, hb) = shared_counts(&cd, &cb);
            let est = estimate(&hd, &hb);
            let stem = |p: &Path| p.file_stem().unwrap().to_string_lossy().into_owned();
            let (est_s, rel, range) = match est {
                Some((e, (lo, hi))) => {
                    all.push(e / ratio);
                    covered += usize::from((lo..=hi).contains(&ratio));
                    (
                        format!("{e:.2}"),
                        format!("{:.3}", e / ratio),
                        format!("{lo:.2}–{hi:.2}"),
                    )
                }
                None => ("failed".into(), String::new(), String::new()),
            };
            println!(
                "| {name} | {} → {} | {ratio:.2} | {est_s} | {rel} | {range} |",
                stem(&dark),
                stem(&bright)
            );
        }
    }
    let n = all.len();
    let (m, lo, hi) = spread(&mut all);
    println!(
        "\nreal pairs: {n}, est/true median {m:.3}, p10 {lo:.3}, p90 {hi:.3}; true ratio in the stated range: {covered} of {n}"
    );
}

fn main() {
    let split = arg("--curves").unwrap_or_else(|| "report".into());
    let (width, height) = match arg("--size") {
        Some(size) => {
            let (w, h) = size.split_once('x').expect("--size takes WxH");
            (w.parse().expect("width"), h.parse().expect("height"))
        }
        None => (512, 384),
    };
    match arg("--brackets") {
        // Another folder of real brackets: its pairs alone.
        Some(dir) => real_pairs(Path::new(&dir)),
        None => {
            synthetic_pairs(&split, width, height);
            real_pairs(&common::testdata_brackets());
        }
    }
}
