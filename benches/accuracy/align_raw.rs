//! `cargo bench --bench align_raw`: how alignment treats synthetic 24 MP raw brackets,
//! still and moved by known amounts.
//!
//! Each bracket is three DNGs of a procedural scene ([`synthetic::scene`], through the
//! lens blur of `cargo bench --bench align`: the scene's stripes are drawn in pixels,
//! finer than a colour filter array samples each colour) through the typical 14-bit Bayer
//! sensor ([`RawSensor::typical`], shot and read noise, one seed per bracket), exposed at
//! the listed shutter times (the longest is the reference, as [`align::align_mosaics`]
//! chooses it), decoded as the pipeline decodes them.
//!
//! **Still.** Nothing moves: every frame should be merged as it is. Per bracket, how many
//! of the two other frames alignment resamples, and the largest corner displacement it
//! found. *Split:* scenes 1–4 (seeds 1–6) were looked at while choosing when a homography
//! is kept; scenes 5–9 (seeds 7–8) were not.
//!
//! **Moved.** The two shorter frames see the scene moved by the nudge or handheld moves of
//! `cargo bench --bench align` (`common::MOVES`: shifts in pixels, rotations, and the
//! perspective in normalised coordinates); the found transform's error is the largest
//! distance, over the frame's corners, between where it and the true move send them.
//! *Split:* scenes 10–11 were looked at while choosing what the raw refinement refines;
//! scenes 12–13 were not.
//!
//! `cargo bench --bench align_raw -- [still | moved] [--mp MP]`

use filmback::align::{self, AlignMode, FrameAlignment, MosaicFrame};
use filmback::frame::{self, Limits, LoadedFrame, Samples};
use filmback::metadata::CaptureTime;
use filmback::radiance::RadianceMap;
use filmback::synthetic::{self, RawSensor, Shot, demo};
use nalgebra::{Matrix3, Vector3};

#[path = "../common/mod.rs"]
mod common;

/// A still bracket: scene seed, shutter times' denominators and sensor noise seeds.
const STILL: [(u64, [f64; 3], &[u64]); 9] = [
    (1, [500.0, 60.0, 8.0], &[1, 2, 3]),
    (2, [500.0, 60.0, 8.0], &[4, 5, 6]),
    (3, [500.0, 60.0, 8.0], &[4, 5, 6]),
    (4, [500.0, 60.0, 8.0], &[4, 5, 6]),
    (5, [1000.0, 125.0, 15.0], &[7, 8]),
    (6, [1000.0, 125.0, 15.0], &[7, 8]),
    (7, [32.0, 8.0, 2.0], &[7, 8]),
    (8, [250.0, 30.0, 4.0], &[7, 8]),
    (9, [500.0, 60.0, 8.0], &[7, 8]),
];

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let all = !args.iter().any(|a| a == "still" || a == "moved");
    let mp = common::arg_or("--mp", 24.0_f64);
    let height = ((mp * 1e6 / 1.5).sqrt() as u32) & !1;
    let width = ((f64::from(height) * 1.5) as u32) & !1;
    if all || args.iter().any(|a| a == "still") {
        still(width, height);
    }
    if all || args.iter().any(|a| a == "moved") {
        moved(width, height);
    }
}

fn still(width: u32, height: u32) {
    println!("still raw brackets, {width}×{height}: frames resampled (of two per bracket)");
    println!("| scene | shutter | noise seeds | frames resampled | largest corner shift found |");
    println!("|---|---|---|---|---|");
    let (mut resampled, mut frames) = (0, 0);
    for (scene_seed, times, seeds) in STILL {
        let scene = common::lens(&synthetic::scene(width, height, scene_seed));
        let (mut moved, mut largest) = (0, 0.0f64);
        for &seed in seeds {
            let views = [None, None, None];
            let (alignment, _) = aligned(&scene, &views, times, seed);
            for (k, f) in alignment.iter().enumerate().filter(|&(k, _)| k != 2) {
                moved += usize::from(f.motion.is_some());
                largest = largest.max(f.displacement_px);
                if let Some(note) = &f.note {
                    println!("(scene {scene_seed}, seed {seed}, frame {k}: {note})");
                }
            }
        }
        resampled += moved;
        frames += 2 * seeds.len();
        println!(
            "| {scene_seed} | 1/{} 1/{} 1/{} s | {seeds:?} | {moved} of {} | {largest:.3} px |",
            times[0],
            times[1],
            times[2],
            2 * seeds.len()
        );
    }
    println!("all: {resampled} of {frames} frames resampled\n");
}

fn moved(width: u32, height: u32) {
    println!("moved raw brackets, {width}×{height}: the found transform's largest corner error");
    println!("| scene | move | 1/500 s frame | 1/60 s frame | estimation |");
    println!("|---|---|---|---|---|");
    let times = [500.0, 60.0, 8.0];
    for scene_seed in [10, 11, 12, 13] {
        let scene = common::lens(&synthetic::scene(width, height, scene_seed));
        for common::Move { name, outer } in &common::MOVES {
            let views = [
                Some(common::matrix(width, height, outer[0])),
                Some(common::matrix(width, height, outer[1])),
                None,
            ];
            let (alignment, seconds) = aligned(&scene, &views, times, scene_seed);
            let cells: Vec<String> = (0..2)
                .map(|k| {
                    let truth = views[k].expect("moved");
                    let f = &alignment[k];
                    let error = corner_error(width, height, &found(f), &truth);

                    if let Some(note) = &f.note {
                        println!("(scene {scene_seed}, {name}, frame {k}: {note})");
                    }
                    format!(
                        "{error:.2} px ({})",
                        f.motion.map_or("unmoved", |m| m.as_str())
                    )
                })
                .collect();
            println!(
                "| {scene_seed} | {name} | {} | {} | {:.0} ms |",
                cells[0],
                cells[1],
                seconds * 1000.0
            );
        }
    }
}

/// The alignment of three DNGs of `scene` at shutter times `1/times[k]` s, frame `k` seeing
/// it moved by `views[k]` (reference pixel → frame pixel), through the typical sensor with
/// noise seed `seed`, and the wall time of [`align::align_mosaics`] (once: estimation,
/// no resampling) in seconds.
fn aligned(
    scene: &RadianceMap,
    views: &[Option<[[f64; 3]; 3]>; 3],
    times: [f64; 3],
    seed: u64,
) -> (Vec<FrameAlignment>, f64) {
    let (width, height) = (scene.width(), scene.height());
    let first = CaptureTime {
        year: 2026,
        month: 11,
        day: 29,
        hour: 12,
        minute: 0,
        second: 0,
        nanos: None,
        offset_minutes: None,
    };
    let seconds = times.map(|t| 1.0 / t);
    let shots = Shot::series(
        &demo::camera("Raw Align", None),
        first,
        &seconds,
        8.0,
        100.0,
        0.5,
    );
    let sensor = RawSensor::typical(seed);
    let dir = tempfile::tempdir().expect("temporary folder");
    let loaded: Vec<LoadedFrame> = shots
        .iter()
        .zip(views)
        .enumerate()
        .map(|(k, (shot, view))| {
            let seen = view.map(|t| synthetic::moved(scene, &t).expect("invertible"));
            let exposure = seconds[k] / seconds[2];
            let signal = synthetic::raw_signal(seen.as_ref().unwrap_or(scene), exposure, &sensor);
            let codes = synthetic::raw_codes(&signal, &sensor);
            let dng = synthetic::dng(&codes, width, height, &sensor, shot).expect("DNG");
            let path = dir.path().join(format!("frame-{k}.dng"));
            std::fs::write(&path, dng).expect("write DNG");
            frame::load(&path, Limits::default()).expect("decodes")
        })
        .collect();
    let mosaics: Vec<MosaicFrame<'_>> = loaded
        .iter()
        .zip(seconds)
        .map(|(f, t)| {
            let Samples::Sixteen(codes) = f.frame.samples() else {
                panic!("a raw frame holds 16-bit codes")
            };
            MosaicFrame {
                codes,
                width: width as usize,
                height: height as usize,
                info: f.raw.as_deref().expect("raw"),
                exposure: t / seconds[2],
            }
        })
        .collect();
    let start = std::time::Instant::now();
    let alignment = align::align_mosaics(&mosaics, AlignMode::Auto);
    let seconds = start.elapsed().as_secs_f64();
    assert_eq!(alignment.reference, 2, "the longest frame is the reference");
    (alignment.frames, seconds)
}

/// The transform alignment found for a frame (the identity when merged unmoved).
fn found(f: &FrameAlignment) -> [[f64; 3]; 3] {
    if f.motion.is_some() {
        f.transform
    } else {
        [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    }
}

/// The largest distance, in pixels, between where `a` and `b` send a corner of a `w × h`
/// frame.
fn corner_error(w: u32, h: u32, a: &[[f64; 3]; 3], b: &[[f64; 3]; 3]) -> f64 {
    let apply = |m: &[[f64; 3]; 3], x: f64, y: f64| {
        let p = Matrix3::from_fn(|r, c| m[r][c]) * Vector3::new(x, y, 1.0);
        (p.x / p.z, p.y / p.z)
    };
    let (xs, ys) = (f64::from(w - 1), f64::from(h - 1));
    [(0.0, 0.0), (xs, 0.0), (0.0, ys), (xs, ys)]
        .iter()
        .map(|&(x, y)| {
            let ((ax, ay), (bx, by)) = (apply(a, x, y), apply(b, x, y));
            (ax - bx).hypot(ay - by)
        })
        .fold(0.0, f64::max)
}
