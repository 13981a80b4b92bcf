//! A three-frame raw bracket to a half/PIZ OpenEXR, against decoding the three raws alone.
//!
//! `cargo bench --bench raw_speed [-- --mp 24 --runs 3]`
//!
//! Three DNGs (14-bit RGGB, lossless JPEG, 3 stops apart) of the synthetic scene at
//! `--mp` megapixels (3:2) are written to a temporary folder; then, best of `--runs`:
//! 1. **decode**: `frame::load` of the three files in parallel (what `filmback merge`
//!    does first);
//! 2. **bracket → EXR**: decode, then `darkroom::develop` (CFA merge inside the PPG
//!    demosaic's bands with white balance, colour and scale, then half/PIZ encode,
//!    publish), the whole of `filmback merge` minus process start.
//!
//! Also timed alone, on the longest frame's signal as a mosaic: our demosaic stage against
//! the one it replaced (white balance pass, rawler's PPG, the matrix while copying out),
//! best of `--runs` each, in the same run (the machine's load moves absolute times).
//!
//! Printed: the times (and the mean CPU time of a run, all threads: on two cores the
//! wall time cannot be below half of it), the ratio, the develop stages, the EXR's size
//! and the process's peak resident memory (which includes making the scene and the DNGs).

use std::time::{Duration, Instant};

use filmback::atomic::Overwrite;
use filmback::darkroom::{self, GivenResponse, Prints, ResponsePolicy};
use filmback::frame::{self, Limits, LoadedFrame};
use filmback::hdr_output::ExrOptions;
use filmback::merge::MergeOptions;
use filmback::metadata::CaptureTime;
use filmback::raw::Cfa;
use filmback::raw::demosaic;
use filmback::raw::mosaic::MergedMosaic;
use filmback::rendering::{Format, SourceExif};
use filmback::response::RatioSource;
use filmback::synthetic::{self, RawSensor, Shot, demo};
use rayon::prelude::*;

mod common;

fn peak_rss_mib() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .unwrap_or_default()
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<f64>().ok())
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

fn main() {
    let mp = common::arg_or("--mp", 24.0_f64);
    let runs = common::arg_or("--runs", 3.0_f64).max(1.0) as usize;
    let height = ((mp * 1e6 / 1.5).sqrt() as u32) & !1;
    let width = ((f64::from(height) * 1.5) as u32) & !1;
    let dir = tempfile::tempdir().expect("temporary folder");
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
    let shots = Shot::series(
        &demo::camera("Raw Bench", None),
        first,
        &[1.0 / 500.0, 1.0 / 60.0, 1.0 / 8.0],
        8.0,
        100.0,
        0.5,
    );
    let t = Instant::now();
    let scene = synthetic::scene(width, height, 1);
    let sensor = RawSensor::typical(1);
    let longest = 1.0 / 8.0;
    let paths: Vec<_> = shots
        .iter()
        .enumerate()
        .map(|(k, shot)| {
            let signal =
                synthetic::raw_signal(&scene, shot.exposure.time_s.unwrap() / longest, &sensor);
            let codes = synthetic::raw_codes(&signal, &sensor);
            let dng = synthetic::dng(&codes, width, height, &sensor, shot).expect("DNG");
            let path = dir.path().join(format!("bench-{}.dng", k + 1));
            std::fs::write(&path, dng).expect("write DNG");
            path
        })
        .collect();
    // The longest frame's signal as a mosaic, for timing the demosaicking alone.
    let mosaic = MergedMosaic {
        width: width as usize,
        height: height as usize,
        values: synthetic::raw_signal(&scene, 1.0, &sensor),
        clipped: 0,
    };
    drop(scene);
    let size: u64 = paths
        .iter()
        .map(|p| std::fs::metadata(p).map_or(0, |m| m.len()))
        .sum();
    println!(
        "{width}×{height} ({:.1} MP), 3 DNGs of {:.1} MB in all, made in {:.1} s",
        f64::from(width) * f64::from(height) / 1e6,
        size as f64 / 1e6,
        t.elapsed().as_secs_f64()
    );

    let load = || -> Vec<LoadedFrame> {
        paths
            .par_iter()
            .map(|p| frame::load(p, Limits::default()).expect("decodes"))
            .collect()
    };
    let mut decode = Duration::MAX;
    let cpu = common::cpu_seconds().unwrap_or(0.0);
    for _ in 0..runs {
        let t = Instant::now();
        let frames = load();
        decode = decode.min(t.elapsed());
        drop(frames);
    }
    let decode_cpu = (common::cpu_seconds().unwrap_or(0.0) - cpu) / runs as f64;

    let out = dir.path().join("out");
    std::fs::create_dir_all(&out).expect("out folder");
    let exif = SourceExif::default();
    let prints = Prints {
        dir: &out,
        stem: "bench",
        exr: Some(ExrOptions::default()),
        radiance_hdr: false,
        dng: false,
        looks: &[],
        format: Format::Jpeg { quality: 90 },
        space: filmback::display::ColourSpace::Srgb,
        exif: &exif,
        overwrite: Overwrite::Replace,
        luminance_calibration: 1.0,
        preview_edge: None,
        ghost_map: false,
    };
    let mut full = Duration::MAX;
    let mut stages = Vec::new();
    let cpu = common::cpu_seconds().unwrap_or(0.0);
    for _ in 0..runs {
        let t = Instant::now();
        let frames = load();
        let exposures: Vec<f64> = frames
            .iter()
            .map(|f| f.metadata.exposure.relative().expect("EXIF exposure"))
            .collect();
        let developed = darkroom::develop(
            &frames,
            &exposures,
            RatioSource::Exif,
            ResponsePolicy::Use(GivenResponse::standard(1)),
            MergeOptions::default(),
            &prints,
        )
        .expect("develops");
        let elapsed = t.elapsed();
        if elapsed < full {
            full = elapsed;
            stages = developed.stages;
        }
    }
    let full_cpu = (common::cpu_seconds().unwrap_or(0.0) - cpu) / runs as f64;
    let cfa = Cfa {
        width: 2,
        height: 2,
        colours: vec![0, 1, 1, 2],
    };
    let gains = [0.5f32, 1.0, 0.7];
    let matrix = [[1.6f32, -0.5, -0.1], [-0.2, 1.4, -0.2], [0.0, -0.4, 1.4]];
    let (mut ours, mut ours_cpu) = (Duration::MAX, 0.0);
    let (mut theirs, mut theirs_cpu) = (Duration::MAX, 0.0);
    for _ in 0..runs {
        let (t, cpu) = (Instant::now(), common::cpu_seconds().unwrap_or(0.0));
        let (rgb, _) = demosaic::demosaic(&mosaic, &cfa, gains, &matrix);
        ours = ours.min(t.elapsed());
        ours_cpu += common::cpu_seconds().unwrap_or(0.0) - cpu;
        drop(rgb);
        let m = mosaic.clone();
        let (t, cpu) = (Instant::now(), common::cpu_seconds().unwrap_or(0.0));
        let rgb = rawler_ppg(m, &cfa, gains, &matrix);
        theirs = theirs.min(t.elapsed());
        theirs_cpu += common::cpu_seconds().unwrap_or(0.0) - cpu;
        drop(rgb);
    }
    println!(
        "demosaic stage: ours (PPG) {:.0} ms (CPU {:.2} s), rawler PPG path {:.0} ms (CPU {:.2} s)",
        ours.as_secs_f64() * 1e3,
        ours_cpu / runs as f64,
        theirs.as_secs_f64() * 1e3,
        theirs_cpu / runs as f64
    );
    println!(
        "decode 3 raws:        {:7.0} ms   (CPU {:.2} s per run)",
        decode.as_secs_f64() * 1e3,
        decode_cpu
    );
    println!(
        "bracket → half/PIZ:   {:7.0} ms   (CPU {:.2} s per run)",
        full.as_secs_f64() * 1e3,
        full_cpu
    );
    println!(
        "ratio:                {:7.2} (bracket → EXR over decoding alone)",
        full.as_secs_f64() / decode.as_secs_f64()
    );
    for (stage, d) in &stages {
        println!("  {stage:<8} {:7.0} ms", d.as_secs_f64() * 1e3);
    }
    let exr_size = std::fs::metadata(out.join("bench.exr")).map_or(0, |m| m.len());
    println!("EXR:                  {:7.1} MB", exr_size as f64 / 1e6);
    println!("peak resident memory: {:7.0} MiB", peak_rss_mib());
}

/// The demosaic stage as it was before ours: white balance on the mosaic, rawler's PPG,
/// the matrix applied while copying out.
fn rawler_ppg(mut m: MergedMosaic, cfa: &Cfa, gains: [f32; 3], matrix: &[[f32; 3]; 3]) -> Vec<f32> {
    use rawler::cfa::{CFA, PlaneColor};
    use rawler::imgop::sensor::Demosaic;
    use rawler::imgop::sensor::bayer::ppg::PPGDemosaic;
    use rawler::imgop::{Dim2, Point, Rect};
    use rawler::pixarray::PixF32;
    let width = m.width;
    m.values
        .par_chunks_mut(width)
        .enumerate()
        .for_each(|(y, row)| {
            for (x, v) in row.iter_mut().enumerate() {
                *v *= gains[cfa.colour_at(x, y)];
            }
        });
    let pixels = PixF32::new_with(m.values, m.width, m.height);
    let roi = Rect::new(Point::new(0, 0), Dim2::new(m.width, m.height));
    let rgb =
        PPGDemosaic::new().demosaic(&pixels, &CFA::new(&cfa.name()), &PlaneColor::default(), roi);
    drop(pixels);
    let camera = rgb.into_inner();
    let mut out = vec![0.0f32; camera.len() * 3];
    out.par_chunks_exact_mut(3)
        .zip(camera.par_iter())
        .for_each(|(o, p)| {
            for (v, row) in o.iter_mut().zip(matrix) {
                *v = row[0] * p[0] + row[1] * p[1] + row[2] * p[2];
            }
        });
    out
}
