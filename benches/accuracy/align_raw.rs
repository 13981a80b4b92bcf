//! `cargo bench --bench align_raw`: how alignment treats synthetic 24 MP raw brackets,
//! still and moved by known amounts.
//!
//! Each bracket is three DNGs of a procedural scene ([`synthetic::scene`], through
//! [`synthetic::lens`]: the scene's stripes are drawn in pixels, finer than a colour
//! filter array samples each colour) through the typical 14-bit Bayer
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
//! The wall times of the estimation ([`align::align_mosaics`]) and of resampling the
//! frames found moved ([`align::warp_mosaics`]), once each. Two kinds of scene:
//! - *exact*: [`synthetic::waves`], rendered exactly through each move, at 1/125, 1/30
//!   and 1/8 s (the waves span fewer stops than the procedural scene). *Split:* seeds
//!   10–13 were looked at while setting the waves' level; seeds 14–17 were not.
//! - *resampled*: the procedural scene, each moved frame resampled from the raster
//!   ([`synthetic::moved`], bilinear), at 1/500, 1/60 and 1/8 s. The resampling blurs
//!   each pixel by its own fraction of a pixel, so these frames differ from the
//!   reference in sharpness as well as in place (see `docs/accuracy.md`). *Split:*
//!   scenes 10–11 were looked at while choosing what the raw refinement refines; scenes
//!   12–13 were not.
//!
//! Then *sharpness*: the procedural scene with the 1/60 s frame shifted by half pixels
//! (bilinear resampling at a constant offset blurs it evenly) and the 1/500 s frame by
//! whole ones, which alignment registers through the blurred frame; the found
//! transforms' corner errors.
//!
//! **Merge.** The same moved brackets merged ([`raw::develop`]) unaligned, as alignment
//! found them, and resampled back by the exact inverse of the move (the floor), against
//! the merge of the unmoved bracket (same noise seed): luminance error in stops where the
//! moved frames carry the merge (the middle frame well exposed, the reference above the
//! well-exposed range; 3 % margins left out), after one global scale.
//!
//! `cargo bench --bench align_raw -- [still | moved | merge] [--mp MP]`

use filmback::align::{self, AlignMode, Alignment, FrameAlignment, MosaicFrame};
use filmback::frame::{self, Limits, LoadedFrame, Samples};
use filmback::metadata::CaptureTime;
use filmback::radiance::RadianceMap;
use filmback::raw::{self, RawExposure};
use filmback::synthetic::{self, RawSensor, Shot, demo, measure};
use std::path::Path;

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
    let all = !args
        .iter()
        .any(|a| a == "still" || a == "moved" || a == "merge");
    let mp = common::arg_or("--mp", 24.0_f64);
    let height = ((mp * 1e6 / 1.5).sqrt() as u32) & !1;
    let width = ((f64::from(height) * 1.5) as u32) & !1;
    if all || args.iter().any(|a| a == "still") {
        still(width, height);
    }
    if all || args.iter().any(|a| a == "moved") {
        moved(width, height);
    }
    if all || args.iter().any(|a| a == "merge") {
        merge(width, height);
    }
}

fn still(width: u32, height: u32) {
    println!("still raw brackets, {width}×{height}: frames resampled (of two per bracket)");
    println!("| scene | shutter | noise seeds | frames resampled | largest corner shift found |");
    println!("|---|---|---|---|---|");
    let (mut resampled, mut frames) = (0, 0);
    for (scene_seed, times, seeds) in STILL {
        let scene = synthetic::lens(&synthetic::scene(width, height, scene_seed));
        let (mut moved, mut largest) = (0, 0.0f64);
        for &seed in seeds {
            let (alignment, _) = aligned([&scene; 3], times, seed);
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
    let exact = |&seed: &u64, _: usize, view: &[[f64; 3]; 3]| {
        synthetic::waves(width, height, seed, view).expect("invertible")
    };
    println!("moved raw brackets, {width}×{height}, exact (waves rendered through each move)");
    moved_table(
        width,
        height,
        10..=17,
        [125.0, 30.0, 8.0],
        |seed| seed,
        exact,
    );
    println!("moved raw brackets, {width}×{height}, resampled (the procedural scene, bilinear)");
    let raster = |seed: u64| synthetic::lens(&synthetic::scene(width, height, seed));
    let resampled = |scene: &RadianceMap, _: usize, view: &[[f64; 3]; 3]| {
        if *view == align::IDENTITY {
            scene.clone()
        } else {
            synthetic::moved(scene, view).expect("invertible")
        }
    };
    moved_table(
        width,
        height,
        10..=13,
        [500.0, 60.0, 8.0],
        raster,
        resampled,
    );
    sharpness(width, height);
}

/// Shifts in pixels of the 1/500 s and 1/60 s frames of [`sharpness`]: the middle frame's
/// half pixels blur it.
const SHIFTS: [[(f64, f64); 2]; 2] = [[(4.0, -2.0), (2.5, -1.5)], [(-3.0, 2.0), (-1.5, 0.5)]];

/// Frames that differ in sharpness: the procedural scene with the 1/60 s frame shifted by
/// half pixels (bilinear resampling at a constant offset blurs it evenly) and the 1/500 s
/// frame by whole ones (not blurred), which alignment registers through the blurred one.
/// The found transforms' corner errors.
fn sharpness(width: u32, height: u32) {
    println!(
        "shifted raw brackets, {width}×{height}: the 1/60 s frame blurred by a half-pixel \
         shift (the procedural scene, 1/500, 1/60 and 1/8 s)"
    );
    println!("| scene | shifts (1/500 s; 1/60 s) | 1/500 s frame | 1/60 s frame |");
    println!("|---|---|---|---|");
    for scene_seed in 10..=13 {
        let scene = synthetic::lens(&synthetic::scene(width, height, scene_seed));
        for shifts in SHIFTS {
            let truths = shifts.map(|(dx, dy)| [[1.0, 0.0, dx], [0.0, 1.0, dy], [0.0, 0.0, 1.0]]);
            let moved = truths.map(|t| synthetic::moved(&scene, &t).expect("invertible"));
            let times = [500.0, 60.0, 8.0];
            let (alignment, _) = aligned([&moved[0], &moved[1], &scene], times, scene_seed);
            let cells: Vec<String> = (0..2)
                .map(|k| {
                    let context = format!("scene {scene_seed}, {shifts:?}, frame {k}");
                    cell(width, height, &alignment[k], &truths[k], &context)
                })
                .collect();
            println!(
                "| {scene_seed} | {:?}; {:?} | {} | {} |",
                shifts[0], shifts[1], cells[0], cells[1]
            );
        }
    }
    println!();
}

/// A table cell for a frame's alignment `f` against the true move `truth`: the largest
/// corner error and the model found; its note, if any, printed after `context`.
fn cell(
    width: u32,
    height: u32,
    f: &FrameAlignment,
    truth: &[[f64; 3]; 3],
    context: &str,
) -> String {
    let error = measure::corner_error(width, height, &found(f), truth);
    if let Some(note) = &f.note {
        println!("({context}: {note})");
    }
    format!(
        "{error:.2} px ({})",
        f.motion.map_or("unmoved", |m| m.as_str())
    )
}

/// The moved table's rows: per scene seed and move, the found transform's largest corner
/// error for the two shorter frames, and the estimation's and resampling's wall times.
/// `render(&scene(seed), k, view)` is the scene of `seed` as frame `k` (the reference: 2)
/// sees it through a camera moved by `view`.
fn moved_table<S>(
    width: u32,
    height: u32,
    seeds: std::ops::RangeInclusive<u64>,
    times: [f64; 3],
    scene: impl Fn(u64) -> S,
    render: impl Fn(&S, usize, &[[f64; 3]; 3]) -> RadianceMap,
) {
    println!(
        "| scene | move | 1/{} s frame | 1/{} s frame | estimation | resampling |",
        times[0], times[1]
    );
    println!("|---|---|---|---|---|---|");
    for scene_seed in seeds {
        let scene = scene(scene_seed);
        let reference = render(&scene, 2, &align::IDENTITY);
        for common::Move { name, outer } in &common::MOVES {
            let truths = [
                common::matrix(width, height, outer[0]),
                common::matrix(width, height, outer[1]),
            ];
            let moved = [render(&scene, 0, &truths[0]), render(&scene, 1, &truths[1])];
            let seen = [&moved[0], &moved[1], &reference];
            let (alignment, [estimation, resampling]) = aligned(seen, times, scene_seed);
            let cells: Vec<String> = (0..2)
                .map(|k| {
                    let context = format!("scene {scene_seed}, {name}, frame {k}");
                    cell(width, height, &alignment[k], &truths[k], &context)
                })
                .collect();
            println!(
                "| {scene_seed} | {name} | {} | {} | {:.0} ms | {:.0} ms |",
                cells[0],
                cells[1],
                estimation * 1000.0,
                resampling * 1000.0
            );
        }
    }
    println!();
}

fn merge(width: u32, height: u32) {
    println!(
        "moved raw brackets, {width}×{height}: luminance error of the merge against the \
         unmoved bracket's, in stops (median / p95 / share > 0.1 stop), where the moved \
         frames carry it"
    );
    println!("| scene | move | unaligned | `--align auto` | move undone (floor) |");
    println!("|---|---|---|---|---|");
    let times = [500.0, 60.0, 8.0];
    for scene_seed in [10, 11, 12, 13] {
        let scene = synthetic::lens(&synthetic::scene(width, height, scene_seed));
        let dir = tempfile::tempdir().expect("temporary folder");
        let still = bracket(&scene, &[None, None, None], times, scene_seed, dir.path());
        let truth = developed(&still, times, None);
        let mask = carried(&still[1], &still[2]);
        let share = mask.iter().filter(|&&m| m).count() as f64 / mask.len() as f64;
        println!(
            "(scene {scene_seed}: {:.1} % of the pixels compared)",
            100.0 * share
        );
        for common::Move { name, outer } in &common::MOVES {
            let views = [
                Some(common::matrix(width, height, outer[0])),
                Some(common::matrix(width, height, outer[1])),
                None,
            ];
            let dir = tempfile::tempdir().expect("temporary folder");
            let moved = bracket(&scene, &views, times, scene_seed, dir.path());
            let frames = mosaics(&moved, times);
            let found = align::align_mosaics(&frames, AlignMode::Auto);
            let undone = Alignment {
                frames: views
                    .iter()
                    .map(|view| FrameAlignment {
                        transform: view.unwrap_or(align::IDENTITY),
                        motion: view.map(|_| align::Motion::Homography),
                        displacement_px: 0.0,
                        note: None,
                    })
                    .collect(),
                ..found.clone()
            };
            let cells: Vec<String> = [None, Some(&found), Some(&undone)]
                .into_iter()
                .map(|alignment| error(&truth, &developed(&moved, times, alignment), &mask))
                .collect();
            println!(
                "| {scene_seed} | {name} | {} | {} | {} |",
                cells[0], cells[1], cells[2]
            );
        }
    }
}

/// The luminance `0.2126 R + 0.7152 G + 0.0722 B` of the bracket's raw merge
/// ([`raw::develop`]), its frames resampled as `alignment` says (none: as they are).
fn developed(loaded: &[LoadedFrame], times: [f64; 3], alignment: Option<&Alignment>) -> Vec<f32> {
    let frames = mosaics(loaded, times);
    let warped = alignment.map_or_else(|| vec![None; 3], |a| align::warp_mosaics(&frames, a));
    let exposures: Vec<RawExposure<'_>> = frames
        .iter()
        .zip(loaded)
        .zip(&warped)
        .map(|((f, l), w)| RawExposure {
            path: &l.path,
            codes: w.as_deref().unwrap_or(f.codes),
            width: f.width as u32,
            height: f.height as u32,
            info: f.info,
            exposure: f.exposure,
        })
        .collect();
    let rgb = raw::develop(&exposures, 1.0).expect("develops").rgb;
    rgb.chunks_exact(3)
        .map(|p| 0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2])
        .collect()
}

/// The pixels the moved frames carry: where the middle frame's signal is well exposed
/// ([`align::WELL_EXPOSED_LOW`] to [`align::WELL_EXPOSED_HIGH`] of its range) and the
/// reference's (the longest frame's) is above that range, 3 % of each side left out.
fn carried(middle: &LoadedFrame, reference: &LoadedFrame) -> Vec<bool> {
    let (a, b) = (signals(middle), signals(reference));
    let (w, h) = (
        middle.frame.width() as usize,
        middle.frame.height() as usize,
    );
    let (mx, my) = (w * 3 / 100, h * 3 / 100);
    let exposed = align::WELL_EXPOSED_LOW..=align::WELL_EXPOSED_HIGH;
    (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            let inside = (mx..w - mx).contains(&x) && (my..h - my).contains(&y);
            inside && exposed.contains(&a[i]) && b[i] > align::WELL_EXPOSED_HIGH
        })
        .collect()
}

/// A raw frame's normalised signal `(k − b)/(w − b)` per pixel.
fn signals(frame: &LoadedFrame) -> Vec<f64> {
    let info = frame.raw.as_deref().expect("raw");
    let Samples::Sixteen(codes) = frame.frame.samples() else {
        panic!("a raw frame holds 16-bit codes")
    };
    let w = frame.frame.width() as usize;
    let (bw, bh) = (info.black_width.max(1), info.black_height.max(1));
    codes
        .iter()
        .enumerate()
        .map(|(i, &k)| {
            let b = info.black[(i / w % bh) * bw + i % w % bw];
            f64::from((f32::from(k) - b) / (info.white - b))
        })
        .collect()
}

/// `log₂(test/truth)` over `mask`, after one global scale (the median ratio): median and
/// 95th percentile of its magnitude and the share above 0.1 stop.
fn error(truth: &[f32], test: &[f32], mask: &[bool]) -> String {
    let mut logs: Vec<f64> = truth
        .iter()
        .zip(test)
        .zip(mask)
        .filter(|&((&t, &v), &m)| m && t > 0.0 && v > 0.0)
        .map(|((&t, &v), _)| f64::from(v / t).log2())
        .collect();
    logs.sort_by(f64::total_cmp);
    let scale = logs[logs.len() / 2];
    let mut off: Vec<f64> = logs.iter().map(|l| (l - scale).abs()).collect();
    off.sort_by(f64::total_cmp);
    let at = |q: f64| off[((off.len() - 1) as f64 * q) as usize];
    let share = off.iter().filter(|&&e| e > 0.1).count() as f64 / off.len() as f64;
    format!("{:.3} / {:.3} / {:.2} %", at(0.5), at(0.95), 100.0 * share)
}

/// The alignment of three DNGs of the radiance frame `k` sees, `seen[k]`, at shutter
/// times `1/times[k]` s, through the typical sensor with noise seed `seed`, and the wall
/// times, in seconds, of [`align::align_mosaics`] (estimation) and of
/// [`align::warp_mosaics`] (resampling the frames found moved), once each.
fn aligned(seen: [&RadianceMap; 3], times: [f64; 3], seed: u64) -> (Vec<FrameAlignment>, [f64; 2]) {
    let dir = tempfile::tempdir().expect("temporary folder");
    let loaded = dngs(seen, times, seed, dir.path());
    let frames = mosaics(&loaded, times);
    let start = std::time::Instant::now();
    let alignment = align::align_mosaics(&frames, AlignMode::Auto);
    let estimation = start.elapsed().as_secs_f64();
    let start = std::time::Instant::now();
    let resampled = align::warp_mosaics(&frames, &alignment);
    let resampling = start.elapsed().as_secs_f64();
    drop(resampled);
    assert_eq!(alignment.reference, 2, "the longest frame is the reference");
    (alignment.frames, [estimation, resampling])
}

/// Three DNGs of `scene` at shutter times `1/times[k]` s, frame `k` seeing it moved by
/// `views[k]` (resampled, [`synthetic::moved`]), as [`dngs`] makes them.
fn bracket(
    scene: &RadianceMap,
    views: &[Option<[[f64; 3]; 3]>; 3],
    times: [f64; 3],
    seed: u64,
    dir: &Path,
) -> Vec<LoadedFrame> {
    let moved: Vec<Option<RadianceMap>> = views
        .iter()
        .map(|v| v.map(|t| synthetic::moved(scene, &t).expect("invertible")))
        .collect();
    let seen = [0, 1, 2].map(|k| moved[k].as_ref().unwrap_or(scene));
    dngs(seen, times, seed, dir)
}

/// Three DNGs of the radiance `seen[k]` at shutter times `1/times[k]` s, through the
/// typical sensor with noise seed `seed`, written into `dir` and decoded as the pipeline
/// decodes them.
fn dngs(seen: [&RadianceMap; 3], times: [f64; 3], seed: u64, dir: &Path) -> Vec<LoadedFrame> {
    let (width, height) = (seen[0].width(), seen[0].height());
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
    shots
        .iter()
        .zip(seen)
        .enumerate()
        .map(|(k, (shot, radiance))| {
            let exposure = seconds[k] / seconds[2];
            let signal = synthetic::raw_signal(radiance, exposure, &sensor);
            let codes = synthetic::raw_codes(&signal, &sensor);
            let dng = synthetic::dng(&codes, width, height, &sensor, shot).expect("DNG");
            let path = dir.join(format!("frame-{k}.dng"));
            std::fs::write(&path, dng).expect("write DNG");
            frame::load(&path, Limits::default()).expect("decodes")
        })
        .collect()
}

/// The mosaics of a [`bracket`] shot at `1/times[k]` s.
fn mosaics(loaded: &[LoadedFrame], times: [f64; 3]) -> Vec<MosaicFrame<'_>> {
    loaded
        .iter()
        .zip(times)
        .map(|(f, t)| {
            let Samples::Sixteen(codes) = f.frame.samples() else {
                panic!("a raw frame holds 16-bit codes")
            };
            MosaicFrame {
                codes,
                width: f.frame.width() as usize,
                height: f.frame.height() as usize,
                info: f.raw.as_deref().expect("raw"),
                exposure: times[2] / t,
            }
        })
        .collect()
}

/// The transform alignment found for a frame (the identity when merged unmoved).
fn found(f: &FrameAlignment) -> [[f64; 3]; 3] {
    if f.motion.is_some() {
        f.transform
    } else {
        [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    }
}
