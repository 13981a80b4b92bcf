//! `cargo bench --bench encoders`: filmback's two encoders against the fastest available
//! implementations of the same formats, on the same pixels, in one run, as ratios.
//!
//! * JPEG q92: the banded `rusty_jpeg` of `rendering::encode` (4:4:4 from quality 90,
//!   standard Huffman tables) against libjpeg-turbo through Pillow (same quality, same
//!   4:4:4, no Huffman optimisation), on one thread and on two (libjpeg-turbo banded the
//!   same way: bands of 64 rows joined by restart markers, two Python threads);
//! * OpenEXR half RGB, PIZ: filmback's own PIZ encoder (`hdr_output::encode_exr`) against
//!   OpenEXR's C++ library through its Python package, with its global thread pool at 0
//!   (everything on the calling thread), 1 and 2 threads.
//!
//! The image is a 24 MP (6000×4000) synthetic JPEG pair (sRGB curve, 1 DN read noise,
//! ratio 4, q95, cached in `target/bench-data/encoders/`) merged as `merge_speed`'s I/O
//! floor does, rounded to half so that both EXR encoders store the same samples, and the
//! Velvia 50 rendering of it at 8 bits. Both are written as raw files beside our outputs;
//! `benches/encoders.py` reads them, times its encoders, checks the EXRs decode to the
//! same halves, and reports sizes and the JPEGs' PSNR against the 8-bit source (both
//! decoded by Pillow). The Python side runs with `FILMBACK_ENCODERS_PYTHON`, else
//! `/tmp/filmback-encoders-venv/bin/python` or CI's `/tmp/filmback-check-venv/bin/python`
//! when present, else `python3`; a missing package skips its half of the comparison.
//! Ours and theirs alternate, `--rounds R` times (default 2), each timing the best of
//! `--runs N` calls (default 3); the table keeps each one's best over the rounds.
//!
//! `cargo bench --bench encoders -- --piz` times only our half PIZ EXR, on one thread,
//! on two 24 MP maps: the merged pair above and a noisy raw-like map (each channel a
//! 14-bit count of the synthetic scene with shot and read noise, σ² = 9 + DN/2 DN²,
//! divided by 2¹⁴), the kind of halves a raw bracket's merge writes. It prints each
//! file's size and the FNV-1a hash of its offset table and blocks (equal hashes: the same
//! pixels' bytes, whatever the header says) and writes them as
//! `piz-merged.exr` and `piz-noisy.exr` beside the other outputs.

use std::io::Cursor;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use filmback::display::Depth;
use filmback::film::{Catalogue, ColourMode, Key};
use filmback::frame::{self, BitDepth, Limits, Samples};
use filmback::hdr_output::{self, ExrOptions, Provenance};
use filmback::merge::{self, BracketFrame, MergeOptions};
use filmback::radiance::RadianceMap;
use filmback::rendering::{self, Format, Look, SourceExif};
use filmback::response::InverseResponse;
use filmback::synthetic::{ResponseCurve, Sensor, expose, scene};
use half::f16;
use half::slice::HalfFloatSliceExt;
use rayon::prelude::*;

mod common;

const WIDTH: u32 = 6000;
const HEIGHT: u32 = 4000;
const QUALITY: u8 = 92;
/// Exposure times of the pair; the scene is exposed at `k = 25·t` (0.25 and 1.0).
const TIMES: [f64; 2] = [0.01, 0.04];

/// The best wall time and the least CPU time (ms) of `runs` calls of `f`, and its last
/// result.
fn best<T>(runs: usize, mut f: impl FnMut() -> T) -> ((f64, f64), T) {
    let (mut wall, mut cpu) = (f64::INFINITY, f64::INFINITY);
    let mut last = None;
    for _ in 0..runs.max(1) {
        let (start, start_cpu) = (Instant::now(), cpu_ms());
        let out = std::hint::black_box(f());
        wall = wall.min(start.elapsed().as_secs_f64() * 1e3);
        cpu = cpu.min(cpu_ms() - start_cpu);
        last = Some(out);
    }
    ((wall, cpu), last.expect("at least one run"))
}

/// CPU time (ms) run so far by this process's live threads: the sum of the first field
/// of Linux's `/proc/self/task/*/schedstat` (ns on the CPU); NaN elsewhere. The thread
/// pools live through every measurement, so a difference counts all their work.
fn cpu_ms() -> f64 {
    let Ok(tasks) = std::fs::read_dir("/proc/self/task") else {
        return f64::NAN;
    };
    tasks
        .filter_map(|t| std::fs::read_to_string(t.ok()?.path().join("schedstat")).ok())
        .filter_map(|s| s.split_whitespace().next()?.parse::<f64>().ok())
        .sum::<f64>()
        / 1e6
}

fn main() {
    let runs: usize = common::arg("--runs").map_or(3, |r| r.parse().expect("--runs N"));
    let rounds: usize = common::arg("--rounds").map_or(2, |r| r.parse().expect("--rounds N"));
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/bench-data/encoders");
    std::fs::create_dir_all(&dir).expect("bench data folder");
    if std::env::args().any(|a| a == "--piz") {
        piz_only(&dir, runs, rounds);
        return;
    }
    println!(
        "encoders: {WIDTH}×{HEIGHT} synthetic pair, JPEG q{QUALITY}, half PIZ EXR, best of \
         {runs} × {rounds} rounds"
    );

    let start = Instant::now();
    let map = merged_map(&dir);
    let look = Look::Film {
        stock: Box::new(
            Catalogue::builtin()
                .expect("built-in stocks")
                .get("velvia50")
                .expect("velvia50")
                .clone(),
        ),
        exposure: 1.0,
        colour: ColourMode::PerLayer,
        key: Key::LogAverage,
        options: Box::default(),
    };
    let image = look.render(&map, Depth::Eight).expect("renders");
    // The raw files the script reads (not kept in memory).
    write_raw(&dir.join("velvia50.rgb8"), &image.to_u8());
    let halves: Vec<u8> = map
        .pixels()
        .par_chunks(1 << 16)
        .flat_map_iter(|c| c.iter().flat_map(|&v| f16::from_f32(v).to_le_bytes()))
        .collect();
    write_raw(&dir.join("radiance.f16"), &halves);
    drop(halves);
    println!(
        "merged map, Velvia 50 look and raw files ready in {:.1} s (not timed)\n",
        start.elapsed().as_secs_f64()
    );

    // --- ours and theirs, interleaved so that both see the same load ---
    let exif = SourceExif::default();
    let pools: Vec<(usize, rayon::ThreadPool)> = [1, 2]
        .into_iter()
        .map(|threads| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("thread pool");
            (threads, pool)
        })
        .collect();
    let mut ours: Vec<Ours> = pools
        .iter()
        .map(|(threads, _)| Ours {
            threads: *threads,
            jpeg: (f64::INFINITY, f64::INFINITY),
            exr: (f64::INFINITY, f64::INFINITY),
        })
        .collect();
    let (mut jpeg, mut exr) = (Vec::new(), Vec::new());
    let mut theirs: Option<serde_json::Value> = None;
    let python = python();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/encoders.py");
    for round in 1..=rounds {
        println!("round {round} of {rounds}");
        for ((threads, pool), kept) in pools.iter().zip(&mut ours) {
            let (t_jpeg, bytes) = pool.install(|| {
                best(runs, || {
                    let mut out = Vec::with_capacity(16 << 20);
                    let format = Format::Jpeg { quality: QUALITY };
                    rendering::encode(&image, format, &exif, &mut out).expect("encodes");
                    out
                })
            });
            jpeg = bytes;
            let (t_exr, bytes) = pool.install(|| {
                best(runs, || {
                    let mut out = Cursor::new(Vec::with_capacity(64 << 20));
                    let (provenance, options) = (Provenance::default(), ExrOptions::default());
                    hdr_output::encode_exr(&mut out, &map, None, &provenance, options)
                        .expect("encodes");
                    out.into_inner()
                })
            });
            exr = bytes;
            kept.jpeg = (kept.jpeg.0.min(t_jpeg.0), kept.jpeg.1.min(t_jpeg.1));
            kept.exr = (kept.exr.0.min(t_exr.0), kept.exr.1.min(t_exr.1));
            println!(
                "  ours, {threads} thread(s): JPEG {:.1} ms (CPU {:.1}), EXR {:.1} ms (CPU {:.1})",
                t_jpeg.0, t_jpeg.1, t_exr.0, t_exr.1
            );
        }
        if round == 1 {
            write_raw(&dir.join("ours.jpg"), &jpeg);
            write_raw(&dir.join("ours.exr"), &exr);
        }
        let Some(result) = run_script(&python, &script, &dir, runs, round == 1) else {
            return;
        };
        theirs = Some(match theirs {
            None => result,
            Some(kept) => fastest(kept, &result),
        });
    }
    // What our EXR time includes and OpenEXR's does not: f32 → half of the map.
    let (t_half, _) = pools[0].1.install(|| {
        best(runs, || {
            let mut out = vec![f16::ZERO; map.pixels().len()];
            out.convert_from_f32_slice(map.pixels());
            out
        })
    });
    println!(
        "\nour EXR time includes f32 → half of the map: {:.1} ms (CPU {:.1}) on one thread",
        t_half.0, t_half.1
    );
    if let Some(theirs) = theirs {
        report(&ours, &theirs, jpeg.len(), exr.len());
    }
}

/// Runs `encoders.py` once (with its checks on request): its result, or `None` (said
/// why) when it cannot run.
fn run_script(
    python: &str,
    script: &Path,
    dir: &Path,
    runs: usize,
    checks: bool,
) -> Option<serde_json::Value> {
    let mut command = Command::new(python);
    command
        .arg(script)
        .args(["--dir", &dir.display().to_string()])
        .args([
            "--width",
            &WIDTH.to_string(),
            "--height",
            &HEIGHT.to_string(),
        ])
        .args([
            "--quality",
            &QUALITY.to_string(),
            "--runs",
            &runs.to_string(),
        ]);
    if checks {
        command.arg("--checks");
        println!("  {python} {}", script.display());
    }
    match command.output() {
        Ok(out) if out.status.success() => {
            let text = String::from_utf8_lossy(&out.stdout);
            for line in text.lines().filter(|l| !l.starts_with("RESULT ")) {
                println!("  {line}");
            }
            let result = text
                .lines()
                .find_map(|l| l.strip_prefix("RESULT "))
                .and_then(|json| serde_json::from_str(json).ok());
            if result.is_none() {
                println!("  skipped: the script printed no result");
            }
            result
        }
        Ok(out) => {
            println!(
                "  skipped: the script failed: {}",
                String::from_utf8_lossy(&out.stderr).trim()
            );
            None
        }
        Err(e) => {
            println!("  skipped: cannot run {python}: {e}");
            None
        }
    }
}

/// `kept` with each of its times replaced by the smaller of it and `round`'s.
fn fastest(mut kept: serde_json::Value, round: &serde_json::Value) -> serde_json::Value {
    for part in ["jpeg", "exr"] {
        for key in ["ms", "cpu_ms"] {
            if let Some(times) = kept[part][key].as_object_mut() {
                for (threads, t) in times.iter_mut() {
                    if let (Some(a), Some(b)) = (t.as_f64(), round[part][key][threads].as_f64()) {
                        *t = serde_json::json!(a.min(b));
                    }
                }
            }
        }
    }
    kept
}

/// Our best times on one thread count: (wall ms, CPU ms) of each encoder.
struct Ours {
    threads: usize,
    jpeg: (f64, f64),
    exr: (f64, f64),
}

/// The side-by-side table: wall and CPU time per encoder and thread count, theirs ÷ ours
/// (above 1: ours is faster), sizes and the JPEGs' PSNR.
fn report(ours: &[Ours], theirs: &serde_json::Value, jpeg_bytes: usize, exr_bytes: usize) {
    println!(
        "\n{:<34} {:>7} {:>9} {:>10} {:>7} {:>9} {:>10} {:>7}",
        "encoder", "threads", "ours ms", "theirs ms", "ratio", "ours CPU", "theirs CPU", "ratio"
    );
    let rows = [
        ("JPEG q92 (libjpeg-turbo, Pillow)", "jpeg"),
        ("half PIZ EXR (OpenEXR)", "exr"),
    ];
    for (name, part) in rows {
        let Some(times) = theirs[part]["ms"].as_object() else {
            println!(
                "{name:<34} skipped: {}",
                theirs[part]["skipped"].as_str().unwrap_or("no result")
            );
            continue;
        };
        for (threads, their_ms) in times {
            let their_ms = their_ms.as_f64().unwrap_or(f64::NAN);
            let their_cpu = theirs[part]["cpu_ms"][threads].as_f64().unwrap_or(f64::NAN);
            // OpenEXR's pool of 0 threads runs on the caller: compare with our one.
            let ours_threads = threads.parse::<usize>().unwrap_or(0).max(1);
            let (our_ms, our_cpu) =
                ours.iter()
                    .find(|o| o.threads == ours_threads)
                    .map_or((f64::NAN, f64::NAN), |o| {
                        if part == "jpeg" { o.jpeg } else { o.exr }
                    });
            println!(
                "{name:<34} {threads:>7} {our_ms:>9.1} {their_ms:>10.1} {:>7.2} {our_cpu:>9.1} \
                 {their_cpu:>10.1} {:>7.2}",
                their_ms / our_ms,
                their_cpu / our_cpu
            );
        }
    }
    let mb = |v: &serde_json::Value| v.as_f64().map_or(f64::NAN, |b| b / 1e6);
    if theirs["jpeg"]["bytes"].is_number() {
        println!(
            "JPEG size: ours {:.2} MB, libjpeg-turbo {:.2} MB; PSNR against the 8-bit look: \
             ours {:.2} dB, libjpeg-turbo {:.2} dB; same quantisation tables: {}",
            jpeg_bytes as f64 / 1e6,
            mb(&theirs["jpeg"]["bytes"]),
            theirs["jpeg"]["ours_psnr"].as_f64().unwrap_or(f64::NAN),
            theirs["jpeg"]["psnr"].as_f64().unwrap_or(f64::NAN),
            theirs["jpeg"]["same_tables"]
        );
    }
    if theirs["exr"]["bytes"].is_number() {
        println!(
            "EXR size: ours {:.2} MB, OpenEXR {:.2} MB; both decode to the source halves: {}",
            exr_bytes as f64 / 1e6,
            mb(&theirs["exr"]["bytes"]),
            theirs["exr"]["same_pixels"]
        );
    }
}

/// The `--piz` mode: our half PIZ EXR of the merged map and of a noisy raw-like map on
/// one thread, the two alternating `rounds` times, best of `runs` CPU times each.
fn piz_only(dir: &Path, runs: usize, rounds: usize) {
    let maps = [("merged", merged_map(dir)), ("noisy", noisy_map())];
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("thread pool");
    println!("half PIZ EXR of two {WIDTH}×{HEIGHT} maps, one thread, best of {runs}");
    let mut kept = [(f64::INFINITY, f64::INFINITY); 2];
    for round in 1..=rounds {
        for ((name, map), kept) in maps.iter().zip(&mut kept) {
            let ((ms, cpu), bytes) = pool.install(|| {
                best(runs, || {
                    let mut out = Cursor::new(Vec::with_capacity(64 << 20));
                    let (provenance, options) = (Provenance::default(), ExrOptions::default());
                    hdr_output::encode_exr(&mut out, map, None, &provenance, options)
                        .expect("encodes");
                    out.into_inner()
                })
            });
            *kept = (kept.0.min(ms), kept.1.min(cpu));
            // FNV-1a, 64 bits, of the offset table and blocks (the pixels' bytes).
            let hash = bytes[header_end(&bytes)..]
                .iter()
                .fold(0xcbf2_9ce4_8422_2325_u64, |h, &b| {
                    (h ^ u64::from(b)).wrapping_mul(0x100_0000_01b3)
                });
            println!(
                "  round {round}, {name}: {ms:.1} ms (CPU {cpu:.1}), {} bytes, blocks' FNV-1a \
                 {hash:016x}",
                bytes.len()
            );
            if round == 1 {
                write_raw(&dir.join(format!("piz-{name}.exr")), &bytes);
            }
        }
    }
    for ((name, _), (ms, cpu)) in maps.iter().zip(kept) {
        println!("best, {name}: {ms:.1} ms (CPU {cpu:.1})");
    }
}

/// Where a single-part OpenEXR file's header ends: after the magic number and version (8
/// bytes), attributes `name\0 type\0 size:i32 value` up to an empty name.
fn header_end(bytes: &[u8]) -> usize {
    let string_end = |at: usize| at + bytes[at..].iter().position(|&b| b == 0).expect("a name");
    let mut at = 8;
    loop {
        let name_end = string_end(at);
        if name_end == at {
            return at + 1;
        }
        let type_end = string_end(name_end + 1);
        let size = i32::from_le_bytes(bytes[type_end + 1..type_end + 5].try_into().expect("4"));
        at = type_end + 5 + usize::try_from(size).expect("a size");
    }
}

/// A 24 MP raw-like map: per channel, `DN = round(4 000·s + n)` clamped to `0..2¹⁴` for
/// the scene's value `s`, with `n` of variance `9 + 4 000·s/2` DN² (read and shot noise;
/// the sum of four uniform deviates, near-Gaussian), divided by 2¹⁴.
fn noisy_map() -> RadianceMap {
    let truth = scene(WIDTH, HEIGHT, 24);
    let mut pixels = truth.into_pixels();
    pixels.par_iter_mut().enumerate().for_each(|(i, v)| {
        // splitmix64 of the index: four 16-bit uniforms.
        let mut z = (i as u64).wrapping_add(0x9e37_79b9_7f4a_7c15);
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^= z >> 31;
        let sum: f64 = (0..4)
            .map(|k| ((z >> (16 * k)) & 0xffff) as f64 / 65536.0)
            .sum();
        // Four uniforms: mean 2, variance 1/3.
        let unit = (sum - 2.0) * 3f64.sqrt();
        let signal = 4000.0 * f64::from(*v);
        let dn = (signal + unit * (9.0 + signal / 2.0).sqrt()).round();
        *v = (dn.clamp(0.0, 16383.0) / 16384.0) as f32;
    });
    RadianceMap::new(WIDTH, HEIGHT, 3, pixels).expect("a 3-channel map")
}

/// The merged 24 MP map, rounded to half precision (what both EXR encoders store).
fn merged_map(dir: &Path) -> RadianceMap {
    let truth = scene(WIDTH, HEIGHT, 24);
    let sensor = Sensor {
        read_noise_dn: 1.0,
        seed: 24,
        ..Sensor::noiseless(ResponseCurve::Srgb, BitDepth::Eight)
    };
    let paths: Vec<PathBuf> = ["dark", "bright"]
        .iter()
        .zip(TIMES)
        .map(|(name, time)| {
            let path = dir.join(format!("{name}.jpg"));
            if !path.exists() {
                let frame = expose(&truth, time * 25.0, &sensor);
                let Samples::Eight(codes) = frame.samples() else {
                    unreachable!("8-bit sensor")
                };
                rusty_jpeg::encode::Encoder::new_file(&path, 95)
                    .expect("frame file")
                    .encode(
                        codes,
                        WIDTH as u16,
                        HEIGHT as u16,
                        rusty_jpeg::encode::ColorType::Rgb,
                    )
                    .expect("frame encodes");
            }
            path
        })
        .collect();
    drop(truth);
    let loaded: Vec<_> = paths
        .par_iter()
        .map(|p| frame::load(p, Limits::default()).expect("frame loads"))
        .collect();
    let bracket: Vec<BracketFrame<'_>> = loaded
        .iter()
        .zip(TIMES)
        .map(|(f, time)| BracketFrame {
            source: &f.path,
            frame: &f.frame,
            exposure: time,
            camera: &f.metadata.camera,
        })
        .collect();
    let mut map = merge::merge(
        &bracket,
        &InverseResponse::srgb(3, 1024),
        MergeOptions::default(),
    )
    .expect("merges")
    .radiance;
    map.pixels_mut()
        .par_iter_mut()
        .for_each(|v| *v = f16::from_f32(*v).to_f32());
    map
}

fn write_raw(path: &Path, bytes: &[u8]) {
    std::fs::write(path, bytes).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
}

/// The Python that runs `encoders.py` (see the module's documentation).
fn python() -> String {
    if let Ok(p) = std::env::var("FILMBACK_ENCODERS_PYTHON") {
        return p;
    }
    [
        "/tmp/filmback-encoders-venv/bin/python",
        "/tmp/filmback-check-venv/bin/python",
    ]
    .into_iter()
    .find(|p| Path::new(p).exists())
    .unwrap_or("python3")
    .to_string()
}
