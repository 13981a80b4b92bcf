//! Daemon latency and throughput on 24 MP JPEG pairs.
//!
//! `cargo bench --bench daemon_latency [-- --mp 24 --stream 6]`
//!
//! 1. **Direct**: the lab alone (decode, merge, EXR, two JPEG renderings, Velvia 50 and linear) on a pair,
//!    called as a function: the work the daemon wraps.
//! 2. **Latency**: the daemon running; the pair is renamed into the ingest folder the way a
//!    tethering tool does, and then handed over as `filmback hook` does
//!    (`atomic::move_into`); time from the rename of the last frame to all outputs (EXR +
//!    two JPEGs) being in place. Printed with its ratio to (1).
//! 3. **Stream**: `--stream N` pairs renamed in at once; brackets per minute and CPU use
//!    (user + system time over wall time, in cores; the machine's core count for scale).
//!
//! The lab is the one `filmback watch` runs ([`DarkroomLab`]: response fit, merge, EXR
//! and the configured renderings).

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use filmback::daemon::bracket::{CameraId, Capture, Input};
use filmback::daemon::config::Config;
use filmback::daemon::{self, Control, DarkroomLab, Job, Lab};
use filmback::metadata;
use filmback::synthetic::demo;

mod common;

fn peak_rss_mib() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|v| v.parse::<u64>().ok())
        })
        .map_or(0, |kb| kb / 1024)
}

fn capture(path: &Path, bytes: &[u8]) -> Capture {
    let m = metadata::read(bytes);
    Capture {
        input: Input {
            path: path.to_path_buf(),
            size: bytes.len() as u64,
            modified_ns: 0,
        },
        camera: CameraId {
            make: m.camera.make,
            model: m.camera.model,
            serial: m.camera.serial,
        },
        exposure: m.exposure.relative(),
        time_s: m.captured_at.map_or(0.0, |t| t.local_seconds()),
        companion: None,
    }
}

fn wait_for(paths: &[PathBuf], timeout: Duration) -> Duration {
    let start = Instant::now();
    while !paths.iter().all(|p| p.exists()) {
        assert!(
            start.elapsed() < timeout,
            "outputs did not appear: {paths:?}"
        );
        std::thread::sleep(Duration::from_millis(1));
    }
    start.elapsed()
}

fn main() {
    let mp = common::arg_or("--mp", 24_u32);
    let stream = common::arg_or("--stream", 6_u32) as usize;
    let (w, h) = if mp >= 24 {
        (6000u32, 4000u32)
    } else {
        (1500, 1000)
    };
    let dir = tempfile::tempdir().expect("temp folder");
    let root = dir.path();
    let staging = root.join("staging");
    std::fs::create_dir_all(&staging).unwrap();

    let t = Instant::now();
    let shots = demo::aeb("Bench Body", None, 10);
    let pair = &shots[..2];
    let jpegs = demo::jpegs(w, h, pair, 5).expect("synthetic pair");
    println!(
        "pair: 2 × {w}×{h} JPEG ({:.1} + {:.1} MB), made in {:.1} s",
        jpegs[0].len() as f64 / 1e6,
        jpegs[1].len() as f64 / 1e6,
        t.elapsed().as_secs_f64()
    );

    // 1. Direct.
    let config = Config::from_str(
        &format!(
            "[folders]\ningest = \"{}\"\nout = \"{}\"\nstate = \"{}\"\n[bracket]\nsize = 2\n[render]\nfilms = [\"velvia50\"]\ntonemaps = [\"linear\"]\n",
            root.join("ingest").display(),
            root.join("out").display(),
            root.join("state").display()
        ),
        Some(Path::new("bench.toml")),
    )
    .unwrap();
    let direct_out = root.join("direct");
    std::fs::create_dir_all(&direct_out).unwrap();
    let frames: Vec<Capture> = jpegs
        .iter()
        .enumerate()
        .map(|(i, b)| {
            let p = staging.join(format!("direct-{i}.jpg"));
            std::fs::write(&p, b).unwrap();
            capture(&p, b)
        })
        .collect();
    let job = Job {
        id: "bench".into(),
        camera: frames[0].camera.clone(),
        frames,
        preset: config.render.clone(),
        cached: None,
        out: direct_out,
        stem: "direct".into(),
        stocks: None,
        previews: false,
    };
    let mut direct = Vec::new();
    for _ in 0..3 {
        let t = Instant::now();
        let dev = DarkroomLab.process(&job).expect("direct develop");
        direct.push(t.elapsed());
        assert_eq!(dev.outputs.len(), 3);
    }
    direct.sort();
    let direct_median = direct[1];
    let stages = DarkroomLab.process(&job).unwrap().stages;
    println!(
        "direct develop (median of 3): {:.2} s  [{}]",
        direct_median.as_secs_f64(),
        stages
            .iter()
            .map(|(s, d)| format!("{s} {:.2} s", d.as_secs_f64()))
            .collect::<Vec<_>>()
            .join(", ")
    );
    let sum: f64 = stages.iter().map(|(_, d)| d.as_secs_f64()).sum();
    println!(
        "  stages add up to {sum:.2} s: the EXR and the renderings run side by side, wall/sum {:.2}",
        direct_median.as_secs_f64() / sum
    );

    // 2. and 3. through the daemon.
    let (control, rx) = tokio::sync::mpsc::channel(4);
    let daemon_config = config.clone();
    let thread = std::thread::spawn(move || {
        let rt = tokio::runtime::Builder::new_multi_thread()
            .enable_all()
            .build()
            .unwrap();
        rt.block_on(daemon::run(daemon_config, Arc::new(DarkroomLab), rx))
    });
    let ingest = root.join("ingest");
    let out = root.join("out");
    while !ingest.exists() {
        std::thread::sleep(Duration::from_millis(10));
    }
    std::thread::sleep(Duration::from_millis(300));
    // Stage a pair in the same file system, then rename it in (what tethering tools do).
    let stage = |name: &str, second: u32| -> Vec<(PathBuf, PathBuf)> {
        let shots = demo::aeb("Bench Body", None, second);
        (0..2)
            .map(|i| {
                // Same pixels, fresh EXIF (capture time) per pair.
                let bytes = rewrite_exif(&jpegs[i], &shots[i]);
                let tmp = staging.join(format!("{name}-{}.jpg", i + 1));
                std::fs::write(&tmp, bytes).unwrap();
                (tmp, ingest.join(format!("{name}-{}.jpg", i + 1)))
            })
            .collect()
    };
    let outputs = |name: &str| {
        vec![
            out.join(format!("{name}-1.exr")),
            out.join(format!("{name}-1.velvia50-t1.jpg")),
            out.join(format!("{name}-1.linear.jpg")),
        ]
    };
    // The median of three pairs delivered by `deliver(staged, final)`, the second frame
    // 100 ms after the first: from its delivery to all outputs in place.
    let latency = |prefix: &str, second: u32, deliver: &dyn Fn(&Path, &Path)| {
        let mut took: Vec<Duration> = (0..3)
            .map(|run| {
                let name = format!("{prefix}{run}");
                let files = stage(&name, second + 20 * run);
                deliver(&files[0].0, &files[0].1);
                std::thread::sleep(Duration::from_millis(100));
                deliver(&files[1].0, &files[1].1);
                let t = wait_for(&outputs(&name), Duration::from_secs(300));
                std::thread::sleep(Duration::from_millis(500));
                t
            })
            .collect();
        took.sort();
        took[1]
    };
    let report = |how: &str, t: Duration| {
        println!(
            "latency, last frame {how} → EXR + JPEG in place (median of 3): {:.2} s = {:.2}× direct",
            t.as_secs_f64(),
            t.as_secs_f64() / direct_median.as_secs_f64()
        )
    };
    let renamed = latency("lat", 100, &|from, to| std::fs::rename(from, to).unwrap());
    report("renamed in", renamed);
    // The same through `filmback hook` (gphoto2's hand-over): complete on arrival, so
    // taken without the quiet window a renamed file waits.
    let handed = latency("hook", 200, &|from, _| {
        filmback::atomic::move_into(from, &ingest).unwrap();
    });
    report("handed over by `filmback hook`", handed);

    let staged: Vec<(String, Vec<(PathBuf, PathBuf)>)> = (0..stream)
        .map(|i| {
            let name = format!("str{i}");
            let files = stage(&name, 400 + 20 * i as u32);
            (name, files)
        })
        .collect();
    let cpu0 = common::cpu_seconds().unwrap_or(0.0);
    let t = Instant::now();
    for (_, files) in &staged {
        for (tmp, dest) in files {
            std::fs::rename(tmp, dest).unwrap();
        }
    }
    for (name, _) in &staged {
        wait_for(&outputs(name), Duration::from_secs(600));
    }
    let wall = t.elapsed().as_secs_f64();
    let cpu = common::cpu_seconds().unwrap_or(0.0) - cpu0;
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    println!(
        "stream: {stream} pairs in {wall:.1} s = {:.1} brackets/min; CPU {:.2} cores busy of {cores} ({:.0} %); jobs = {}",
        stream as f64 * 60.0 / wall,
        cpu / wall,
        100.0 * cpu / wall / cores as f64,
        config.daemon.jobs
    );
    println!(
        "peak RSS of the whole benchmark process: {} MiB",
        peak_rss_mib()
    );
    control.blocking_send(Control::Stop).unwrap();
    thread.join().unwrap().unwrap();
}

/// The same JPEG with the EXIF of `shot` (re-encoding 24 MP per pair would dominate the
/// set-up time): decode once, re-encode with the new EXIF through the synthetic writer.
fn rewrite_exif(jpeg: &[u8], shot: &filmback::synthetic::Shot) -> Vec<u8> {
    let frame = filmback::frame::decode(Path::new("bench.jpg"), jpeg, Default::default())
        .unwrap()
        .frame;
    filmback::synthetic::encode(
        &frame,
        shot,
        filmback::synthetic::Encoding::Jpeg { quality: 90 },
    )
    .unwrap()
}
