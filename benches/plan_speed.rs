//! How fast `filmback plan` groups a large archive: 10,000 small JPEGs with EXIF (3,333
//! three-frame brackets of two bodies and one single), listed, probed, paired and grouped
//! into a plan, twice (the second time with the files in the page cache).
//!
//! `cargo bench --bench plan_speed [-- --frames 10000 --size 32]`
//!
//! Frames are `size × size` pixels (the probe reads the whole file, the EXIF and the image
//! header; pixels are not decoded): the time is the intake's per-file cost, which does not
//! grow with the pixels beyond the file's read. Printed: frames, tasks, seconds and frames
//! per second per run, and the plan's size.

use std::path::Path;
use std::time::Instant;

use filmback::daemon::config::Config;
use filmback::farm::{PlanOptions, write_plan};
use filmback::synthetic::demo;

mod common;

/// Writes `frames` JPEGs into `dir`: three-frame brackets 11 s apart (the default gap is
/// 10 s), bodies alternating, the remainder as singles.
fn archive(dir: &Path, frames: u32, size: u32) {
    std::fs::create_dir_all(dir).expect("archive folder");
    let brackets = frames / 3;
    for k in 0..brackets {
        let model = if k % 2 == 0 { "EOS R5" } else { "EOS R6" };
        let shots = demo::aeb(model, None, 11 * (k / 2));
        let jpegs = demo::jpegs(size, size, &shots, u64::from(k % 16)).expect("JPEGs");
        for (i, bytes) in jpegs.iter().enumerate() {
            std::fs::write(dir.join(format!("IMG_{k:05}_{i}.jpg")), bytes).expect("frame");
        }
    }
    for k in brackets * 3..frames {
        let shots = demo::aeb("EOS R5", None, 11 * (brackets / 2 + 1 + k - brackets * 3));
        let jpeg = demo::jpegs(size, size, &shots[..1], 0).expect("JPEG");
        std::fs::write(dir.join(format!("IMG_single_{k:05}.jpg")), &jpeg[0]).expect("frame");
    }
}

fn main() {
    let frames = common::arg_or("--frames", 10_000_u32);
    let size = common::arg_or("--size", 32_u32);
    let dir = tempfile::tempdir().expect("temporary folder");
    let ingest = dir.path().join("archive");
    let t = Instant::now();
    archive(&ingest, frames, size);
    println!(
        "wrote {frames} frames of {size}×{size} in {:.1} s",
        t.elapsed().as_secs_f64()
    );
    let config = Config::defaults();
    let plan = dir.path().join("plan.jsonl");
    for run in ["first", "second"] {
        let t = Instant::now();
        let summary = write_plan(&PlanOptions {
            root: &ingest,
            out: &dir.path().join("out"),
            config: &config,
            config_text: "",
            pooled: false,
            plan: &plan,
        })
        .expect("plan");
        let s = t.elapsed().as_secs_f64();
        let bytes = std::fs::metadata(&plan).map_or(0, |m| m.len());
        println!(
            "{run} run: {frames} frames -> {} tasks ({} brackets), {} unused in {s:.2} s ({:.0} frames/s); plan {:.1} MB",
            summary.tasks,
            summary.brackets,
            summary.unused,
            f64::from(frames) / s,
            bytes as f64 / 1e6
        );
    }
}
