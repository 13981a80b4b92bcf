//! A body's curve from many brackets: how the pooled refit converges as the camera shoots,
//! and whether a bracket of another curve is told apart.
//!
//! `cargo bench --bench pool_accuracy [-- --curves tune|report] [--every N] [--brackets K]
//! [--encoding lossless|jpeg90] [--size WxH] [--seed N]`
//!
//! For each DoRF curve of the chosen split (`tune`: records ≡ 0 mod 4; `report`, the
//! default: the others), a body shoots `K` (default 8) pairs at ratio 4, each of another
//! scene (the four synthetic scene kinds in turn, each seed different) and at another
//! exposure (the pair's geometric mean `2^u`, `u` spread over −1.5..1.5 stops), with
//! 1 DN read noise, as 8-bit JPEG q90 (default) or lossless. Each pair is fitted alone
//! (`response::calibrate`); then its [`Evidence`] joins the pool and the pool is refitted
//! (`response::pool::refit`). Printed per pool size `n`: over curves, the median and 90th
//! percentile of the largest |channel scale error| and of the RMS shape error (stops,
//! codes 16..239, as `response_accuracy`), and the lowest channel confidence — for the
//! `n`-th bracket's own fit and for the pool of the first `n`.
//!
//! Contradiction: a ninth-like pair of the *same* curve and a pair of *another* curve (the
//! next record of the split) are each compared with the full pool: flagged when the pool
//! explains the pair worse than the pair's own fit by more than
//! `darkroom::CONTRADICTION_STOPS` ([`pool::agreement`]). Printed: the share of foreign
//! pairs flagged and of own pairs flagged (false alarms).

use std::path::Path;

use filmback::darkroom::CONTRADICTION_STOPS;
use filmback::frame::{self, BitDepth, Frame, Limits};
use filmback::histogram::Histogram;
use filmback::response::pool::{self, Evidence};
use filmback::response::{Calibration, Degree, Ratio, RatioSource, calibrate};
use filmback::synthetic::{
    self, Encoding as FileEncoding, ResponseCurve as Curve, SceneKind, Sensor, measure,
};

#[path = "../common/mod.rs"]
mod common;
use common::arg;

const RATIO: f64 = 4.0;

/// One frame of `scene` at `exposure` through `curve`, 1 DN noise, JPEG-coded at
/// `quality` (decoded back) or lossless.
fn expose(
    scene: &filmback::radiance::RadianceMap,
    exposure: f64,
    curve: &Curve,
    quality: Option<u8>,
    seed: u64,
) -> Frame {
    let sensor = Sensor {
        curve: curve.clone(),
        bit_depth: BitDepth::Eight,
        read_noise_dn: 1.0,
        full_well_electrons: None,
        seed,
    };
    let frame = synthetic::expose(scene, exposure, &sensor);
    let Some(quality) = quality else {
        return frame;
    };
    let bytes = synthetic::encode(
        &frame,
        &common::shot(exposure),
        FileEncoding::Jpeg { quality },
    )
    .unwrap();
    frame::decode(Path::new("synthetic.jpg"), &bytes, Limits::default())
        .unwrap()
        .frame
}

/// The `k`-th pair a body of `curve` shoots, fitted alone.
fn shoot(
    curve: &Curve,
    k: usize,
    seed: u64,
    size: (u32, u32),
    quality: Option<u8>,
) -> Option<Calibration> {
    let kind = SceneKind::ALL[k % SceneKind::ALL.len()];
    let scene = kind.render(size.0, size.1, seed + 101 * k as u64);
    // Exposures spread over ±1.5 stops around the scene's nominal one.
    let u = -1.5 + 3.0 * ((k * 5) % 8) as f64 / 7.0;
    let mid = 2f64.powf(u);
    let (dark, bright) = (mid / RATIO.sqrt(), mid * RATIO.sqrt());
    let a = expose(&scene, dark, curve, quality, seed + 2 * k as u64);
    let b = expose(&scene, bright, curve, quality, seed + 2 * k as u64 + 1);
    calibrate(
        &Histogram::of_frame(&a, 1),
        &Histogram::of_frame(&b, 1),
        Ratio::Known(RATIO, RatioSource::Exif),
        Degree::Auto,
    )
    .ok()
}

/// (largest |scale error|, RMS shape error) over channels, stops.
fn errors(c: &Calibration, curve: &Curve) -> (f64, f64) {
    let e = measure::response_errors(&c.response, curve);
    let scale = e.iter().map(|x| x.scale.abs()).fold(0.0, f64::max);
    let shape = (e.iter().map(|x| x.shape.powi(2)).sum::<f64>() / e.len() as f64).sqrt();
    (scale, shape)
}

fn confidence(c: &Calibration) -> f64 {
    c.channels
        .iter()
        .map(|ch| ch.fit.confidence)
        .fold(f64::INFINITY, f64::min)
}

fn main() {
    let split = arg("--curves").unwrap_or_else(|| "report".into());
    let mut curves = common::dorf_curves().unwrap_or_else(|e| {
        eprintln!("(DoRF curves unavailable: {e}: nothing to measure)");
        Vec::new()
    });
    common::keep_split(&mut curves, &split);
    let every: usize = arg("--every").map_or(4, |n| n.parse().expect("--every takes a number"));
    let curves: Vec<(String, Curve)> = curves.into_iter().step_by(every.max(1)).collect();
    let brackets: usize =
        arg("--brackets").map_or(8, |n| n.parse().expect("--brackets takes a number"));
    let seed: u64 = arg("--seed").map_or(21, |n| n.parse().expect("--seed takes a number"));
    let quality = match arg("--encoding").as_deref() {
        None | Some("jpeg90") => Some(90),
        Some("lossless") => None,
        Some(other) => panic!("--encoding takes jpeg90 or lossless, not {other}"),
    };
    let size = match arg("--size") {
        Some(s) => {
            let (w, h) = s.split_once('x').expect("--size takes WxH");
            (w.parse().unwrap(), h.parse().unwrap())
        }
        None => (512, 384),
    };
    println!(
        "{} DoRF curves ({split} split, every {every}), {brackets} pairs each at ratio {RATIO}, {}, {}×{}, seed {seed}",
        curves.len(),
        quality.map_or("8-bit lossless".to_string(), |q| format!("8-bit JPEG q{q}")),
        size.0,
        size.1
    );
    // Per pool size: (own scale, own shape, own confidence, pool scale, pool shape, pool confidence).
    let mut by_n: Vec<[Vec<f64>; 6]> = (0..brackets).map(|_| Default::default()).collect();
    let (mut foreign_flagged, mut foreign_total, mut own_flagged, mut own_total) = (0, 0, 0, 0);
    let mut refit_ms = Vec::new();
    for (i, (name, curve)) in curves.iter().enumerate() {
        let mut evidence: Vec<Evidence> = Vec::new();
        let mut pooled = None;
        for k in 0..brackets {
            let Some(own) = shoot(curve, k, seed, size, quality) else {
                eprintln!("{name}: pair {k} could not be fitted");
                continue;
            };
            evidence.push(Evidence::of(&own, 2));
            let t = std::time::Instant::now();
            let refs: Vec<&Evidence> = evidence.iter().collect();
            let Ok(pool) = pool::refit(&refs, Degree::Auto) else {
                eprintln!("{name}: pool of {} could not be fitted", refs.len());
                continue;
            };
            refit_ms.push(t.elapsed().as_secs_f64() * 1e3);
            let n = evidence.len() - 1;
            let (s, h) = errors(&own, curve);
            let (ps, ph) = errors(&pool, curve);
            let row = &mut by_n[n];
            row[0].push(s);
            row[1].push(h);
            row[2].push(confidence(&own));
            row[3].push(ps);
            row[4].push(ph);
            row[5].push(confidence(&pool));
            pooled = Some(pool);
        }
        let Some(pool) = pooled else { continue };
        let flagged = |c: &Calibration| {
            let e = Evidence::of(c, 2);
            pool::agreement(&e, &pool.response)
                > pool::agreement(&e, &c.response) + CONTRADICTION_STOPS
        };
        if let Some(c) = shoot(curve, brackets, seed + 7, size, quality) {
            own_total += 1;
            own_flagged += usize::from(flagged(&c));
        }
        let (_, other) = &curves[(i + 1) % curves.len()];
        if let Some(c) = shoot(other, 3, seed + 13, size, quality) {
            foreign_total += 1;
            foreign_flagged += usize::from(flagged(&c));
        }
        eprintln!("{name} done");
    }
    println!();
    println!(
        "| brackets n | n-th alone: scale med | p90 | shape med | p90 | min conf med | pool of n: scale med | p90 | shape med | p90 | min conf med |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    for (n, row) in by_n.iter_mut().enumerate() {
        if row[0].is_empty() {
            continue;
        }
        let mut cells = Vec::new();
        for (j, v) in row.iter_mut().enumerate() {
            let med = common::quantile(v, 0.5);
            if j == 2 || j == 5 {
                cells.push(format!("{med:.2}"));
            } else {
                cells.push(format!("{med:.3}"));
                cells.push(format!("{:.3}", common::quantile(v, 0.9)));
            }
        }
        println!("| {} | {} |", n + 1, cells.join(" | "));
    }
    println!();
    println!(
        "contradiction (> {CONTRADICTION_STOPS} stop worse than the pair's own fit): another curve's pair flagged {foreign_flagged}/{foreign_total}; a new pair of the same curve flagged {own_flagged}/{own_total}"
    );
    println!(
        "refit time per pool, median {:.0} ms, largest {:.0} ms (this machine, as loaded)",
        common::quantile(&mut refit_ms.clone(), 0.5),
        refit_ms.iter().copied().fold(0.0, f64::max)
    );
}
