//! `cargo bench --bench align`: how well alignment undoes a known move of real frames, and
//! what it costs at 24 MP.
//!
//! **Accuracy.** Three frames of each real tripod bracket of `../shared/testdata/brackets`
//! (skipped when absent); the two other than the reference ([`align::choose_reference`],
//! which stays where it is) are resampled ([`align::warp_frame`]) by a known transform: a *nudge* (≤ 3 px and 0.1°) or a *handheld* move (≤ 12 px and 0.5°, with a
//! mild perspective, the corners moved by ≈ 0.4 % of the longer side). Each is merged
//! (one response, fitted on the unmoved frames; no deghosting) after: nothing; filmback's
//! alignment (`--align auto`); the exact inverse move (the floor an aligner can reach:
//! the frames were resampled twice); and, when Python with OpenCV is found
//! (`FILMBACK_PYTHON`, else `python3`), OpenCV's `AlignMTB` (`benches/accuracy/opencv_align.py`).
//! Against the merge of the unmoved frames: the luminance error in stops (median, p95,
//! share of pixels off by more than 0.1 stop) over the pixels the reference exposes
//! well (every channel within codes 10..245), a margin of 3 % of the longer side left
//! out, after one global scale (the median ratio). No constant of `align` was set on
//! these frames (they were set on synthetic scenes, `tests/align.rs`); the memorial
//! triples three stops apart were never looked at while changing `align`.
//!
//! **Cost.** `align::align` and `align::warp_frames` on three 6000×4000 8-bit frames two
//! stops apart (the synthetic procedural scene), the two other than the reference moved
//! as a handheld bracket, and `align::align` on the same frames unmoved (a tripod
//! bracket); best of `--runs N` (default 3). Each frame's found and true
//! transform are printed, and the merge's error as above (against the merge of the
//! frames before the move): unaligned, aligned, and with the move undone.
//!
//! **Still.** Still JPEG brackets (quality 92) of the synthetic procedural scene, as
//! `filmback watch --demo` drops them (1/250, 1/60, 1/15 s: the darkest frame exposes the
//! scene best and is the reference, the brightest is four stops from it): three sizes, a
//! noiseless sensor (the demo's) and one with shot and read noise, scenes of seeds 60–65
//! (held out: the rules for still frames were chosen on seeds 1–16 at 1400×1000, seeds
//! 20–25 and 40–45 and the demo's scene). How many of the frames other than the
//! reference alignment resamples (one response fitted per bracket, as the pipeline fits
//! it), and the largest move it found.
//!
//! `cargo bench --bench align -- [accuracy | still | speed] [--runs N] [--only LABEL]`

use std::path::{Path, PathBuf};
use std::process::Command;

use filmback::align::{self, AlignFrame, AlignMode};
use filmback::frame::{self, BitDepth, Frame, Limits, Samples};
use filmback::merge::{self, MergeOptions};
use filmback::metadata::Camera;
use filmback::radiance::RadianceMap;
use filmback::response::InverseResponse;

use filmback::synthetic::{self, ResponseCurve, SceneKind, Sensor, expose};

#[path = "../common/mod.rs"]
mod common;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let all = !args
        .iter()
        .any(|a| a == "accuracy" || a == "still" || a == "speed");
    let runs = common::arg("--runs").map_or(3, |r| r.parse().expect("--runs N"));
    if all || args.iter().any(|a| a == "accuracy") {
        accuracy();
    }
    if all || args.iter().any(|a| a == "still") {
        still();
    }
    if all || args.iter().any(|a| a == "speed") {
        speed(runs);
    }
}

fn inverse(t: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let m = nalgebra::Matrix3::from_fn(|r, c| t[r][c]);
    common::to_array(&m.try_inverse().expect("an invertible move"))
}

/// `frame` resampled so that pixel `x` shows what `frame` shows at `T·x`.
fn warped(frame: &Frame, t: &[[f64; 3]; 3]) -> Frame {
    align::warp_frame(frame, frame, t).expect("same shape")
}

/// A real bracket: its label, its folder and each file with its relative exposure.
struct RealBracket {
    label: &'static str,
    folder: &'static str,
    files: [(&'static str, f64); 3],
}

/// Three frames of each real bracket, two or three stops apart. The memorial triples three
/// stops apart are held out: no rule of `align` was chosen by looking at them.
const REAL_BRACKETS: [RealBracket; 5] = [
    RealBracket {
        label: "frobisher",
        folder: "frobisher",
        files: [
            ("IMG_2600.jpg", 0.125),
            ("IMG_2601.jpg", 1.0),
            ("IMG_2602.jpg", 8.0),
        ],
    },
    RealBracket {
        label: "memorial 65–69",
        folder: "memorial",
        files: [
            ("memorial0069.png", 0.125),
            ("memorial0067.png", 0.5),
            ("memorial0065.png", 2.0),
        ],
    },
    RealBracket {
        label: "memorial 61–67",
        folder: "memorial",
        files: [
            ("memorial0067.png", 0.5),
            ("memorial0064.png", 4.0),
            ("memorial0061.png", 32.0),
        ],
    },
    RealBracket {
        label: "memorial 68–74",
        folder: "memorial",
        files: [
            ("memorial0074.png", 1.0 / 256.0),
            ("memorial0071.png", 1.0 / 32.0),
            ("memorial0068.png", 0.25),
        ],
    },
    RealBracket {
        label: "learnopencv",
        folder: "learnopencv",
        files: [
            ("img_0.033.jpg", 1.0 / 30.0),
            ("img_0.25.jpg", 0.25),
            ("img_2.5.jpg", 2.5),
        ],
    },
];

/// The real brackets whose label contains `--only`'s text (all without it), loaded.
fn real_cases() -> Vec<(String, Vec<(Frame, f64)>)> {
    let dir = common::testdata_brackets();
    let only = common::arg("--only");
    let brackets = REAL_BRACKETS
        .iter()
        .filter(|b| only.as_deref().is_none_or(|o| b.label.contains(o)));
    let mut cases = Vec::new();
    for &RealBracket {
        label: name,
        folder,
        files,
    } in brackets
    {
        let paths: Vec<(PathBuf, f64)> = files
            .iter()
            .map(|(f, e)| (dir.join(folder).join(f), *e))
            .collect();
        if !paths.iter().all(|(p, _)| p.exists()) {
            println!("skipped {name}: {} is absent", dir.join(folder).display());
            continue;
        }
        let frames = paths
            .iter()
            .map(|(p, e)| {
                let frame = frame::load(p, Limits::default()).expect("a real frame");
                (frame.frame, *e)
            })
            .collect();
        cases.push((name.to_string(), frames));
    }
    cases
}

fn accuracy() {
    println!("real frames moved by known transforms: luminance error in stops");
    println!("| bracket | move | unaligned | filmback | move undone (floor) | OpenCV AlignMTB |");
    println!("|---|---|---|---|---|---|");
    let python = std::env::var("FILMBACK_PYTHON").unwrap_or_else(|_| "python3".to_string());
    let opencv = Command::new(&python)
        .args(["-c", "import cv2"])
        .status()
        .is_ok_and(|s| s.success());
    if !opencv {
        println!("(OpenCV column skipped: `{python} -c 'import cv2'` failed; set FILMBACK_PYTHON)");
    }
    let mut found = Vec::new();
    for (name, frames) in real_cases() {
        let g = common::fitted(&frames);
        let truth = merged(&frames, &g);
        let (w, h) = (frames[0].0.width(), frames[0].0.height());
        // The frame alignment registers the others onto stays where it is.
        let views: Vec<&Frame> = frames.iter().map(|(f, _)| f).collect();
        let reference = align::choose_reference(&views);
        for m in &common::MOVES {
            let mut outer = m.outer.iter();
            let moves: Vec<Option<[[f64; 3]; 3]>> = (0..frames.len())
                .map(|k| {
                    (k != reference)
                        .then(|| outer.next().map(|&f| common::matrix(w, h, f)))
                        .flatten()
                })
                .collect();
            let moved: Vec<(Frame, f64)> = frames
                .iter()
                .zip(&moves)
                .map(|((f, e), t)| (t.map_or_else(|| f.clone(), |t| warped(f, &t)), *e))
                .collect();
            let undone: Vec<(Frame, f64)> = moved
                .iter()
                .zip(&moves)
                .map(|((f, e), t)| (t.map_or_else(|| f.clone(), |t| warped(f, &inverse(&t))), *e))
                .collect();
            let error = |fs: &[(Frame, f64)]| errors(&merged(fs, &g), &truth, &frames[reference].0);
            let cv = if opencv {
                opencv_aligned(&python, &name, m.name, &moved, reference)
                    .map_or_else(|e| format!("failed: {e}"), |fs| error(&fs))
            } else {
                "skipped".to_string()
            };
            let (ours, what) = aligned(&moved, &g);
            println!(
                "| {name} ({w}×{h}) | {} | {} | {} | {} | {cv} |",
                m.name,
                error(&moved),
                error(&ours),
                error(&undone),
            );
            let truth: Vec<String> = moves
                .iter()
                .enumerate()
                .filter_map(|(k, t)| t.map(|t| (k, inverse(&t))))
                .map(|(k, t)| {
                    let ((dx, dy), angle) = align::FrameAlignment {
                        transform: t,
                        ..align::FrameAlignment::unmoved(None)
                    }
                    .shift_and_rotation(w, h);
                    format!("frame {k}: ({dx:.2}, {dy:.2}) px {angle:.3}°")
                })
                .collect();
            found.push(format!(
                "{name}, {}: true {}; found {what}",
                m.name,
                truth.join("; ")
            ));
        }
    }
    println!("\nwhat the aligner found (reference pixel → frame pixel):");
    found.iter().for_each(|line| println!("{line}"));
}

/// The still brackets of the module's docs: per size and sensor, the frames resampled
/// and the largest move found.
fn still() {
    println!("still JPEG brackets (q92) of the procedural scene, seeds 60–65: frames resampled");
    println!("| size | sensor | frames resampled (of 12) | largest move found |");
    println!("|---|---|---|---|");
    let shots = synthetic::demo::aeb("Still Body", None, 0);
    let middle = shots[1].exposure.relative().expect("EXIF exposure");
    for (w, h) in [(800, 600), (1400, 1000), (2400, 1600)] {
        for noisy in [false, true] {
            let mut resampled = 0;
            let mut largest = 0f64;
            for seed in 60..=65 {
                let sensor = Sensor {
                    read_noise_dn: if noisy { 0.5 } else { 0.0 },
                    full_well_electrons: noisy.then_some(20_000.0),
                    seed,
                    ..Sensor::noiseless(ResponseCurve::Srgb, BitDepth::Eight)
                };
                let scene = synthetic::scene(w, h, seed);
                let frames: Vec<(Frame, f64)> =
                    synthetic::bracket(&scene, &sensor, &shots, 1.0 / middle)
                        .expect("a bracket")
                        .iter()
                        .zip(&shots)
                        .map(|(f, shot)| {
                            let jpeg = synthetic::encode(
                                f,
                                shot,
                                synthetic::Encoding::Jpeg { quality: 92 },
                            )
                            .expect("a JPEG");
                            let loaded =
                                frame::decode(Path::new("still.jpg"), &jpeg, Limits::default())
                                    .expect("our JPEG");
                            (
                                loaded.frame,
                                shot.exposure.relative().expect("EXIF exposure"),
                            )
                        })
                        .collect();
                let g = common::fitted(&frames);
                let alignment = align::align(&views(&frames), &g, AlignMode::Auto);
                for f in alignment.frames.iter().filter(|f| f.motion.is_some()) {
                    resampled += 1;
                    largest = largest.max(f.displacement_px);
                }
            }
            let sensor = if noisy {
                "shot + read noise"
            } else {
                "noiseless"
            };
            println!("| {w}×{h} | {sensor} | {resampled} | {largest:.2} px |");
        }
    }
}

/// `frames` (with their exposures) as alignment reads them.
fn views(frames: &[(Frame, f64)]) -> Vec<AlignFrame<'_>> {
    frames
        .iter()
        .map(|(frame, exposure)| AlignFrame {
            frame,
            exposure: *exposure,
        })
        .collect()
}

/// `frames` after filmback's alignment (mode auto), and one line per frame saying what it
/// found (model, shift at the centre, rotation, note).
fn aligned(frames: &[(Frame, f64)], g: &InverseResponse) -> (Vec<(Frame, f64)>, String) {
    let views = views(frames);
    let alignment = align::align(&views, g, AlignMode::Auto);
    let (w, h) = (frames[0].0.width(), frames[0].0.height());
    let found: Vec<String> = alignment
        .frames
        .iter()
        .enumerate()
        .map(|(k, f)| {
            let ((dx, dy), angle) = f.shift_and_rotation(w, h);
            let note = f.note.as_deref().unwrap_or("");
            format!(
                "frame {k}: {:?} ({dx:.2}, {dy:.2}) px {angle:.3}° {note}",
                f.motion
            )
        })
        .collect();
    let warped = align::warp_frames(&views, &alignment);
    let frames = frames
        .iter()
        .zip(warped)
        .map(|((f, e), w)| (w.unwrap_or_else(|| f.clone()), *e))
        .collect();
    (frames, found.join("; "))
}

/// `frames` aligned by OpenCV's AlignMTB onto frame `reference` through
/// `benches/accuracy/opencv_align.py` (frames written as binary PPM, read back as PNG), or why not.
fn opencv_aligned(
    python: &str,
    bracket: &str,
    case: &str,
    frames: &[(Frame, f64)],
    reference: usize,
) -> Result<Vec<(Frame, f64)>, String> {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join("align-bench")
        .join(format!(
            "{bracket}-{}",
            case.split(' ').next().unwrap_or("move")
        ));
    std::fs::create_dir_all(&dir).map_err(|e| e.to_string())?;
    let mut args = vec![
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("benches/accuracy/opencv_align.py")
            .display()
            .to_string(),
        reference.to_string(),
    ];
    for (k, (f, _)) in frames.iter().enumerate() {
        let (input, output) = (
            dir.join(format!("{k}.ppm")),
            dir.join(format!("{k}-mtb.png")),
        );
        write_ppm(f, &input).map_err(|e| e.to_string())?;
        args.extend([input.display().to_string(), output.display().to_string()]);
    }
    let status = Command::new(python)
        .args(&args)
        .status()
        .map_err(|e| e.to_string())?;
    if !status.success() {
        return Err(format!("opencv_align.py: {status}"));
    }
    frames
        .iter()
        .enumerate()
        .map(|(k, (_, e))| {
            frame::load(&dir.join(format!("{k}-mtb.png")), Limits::default())
                .map(|l| (l.frame, *e))
                .map_err(|e| e.to_string())
        })
        .collect()
}

/// An 8-bit RGB frame as binary PPM.
fn write_ppm(frame: &Frame, path: &Path) -> std::io::Result<()> {
    let Samples::Eight(codes) = frame.samples() else {
        return Err(std::io::Error::other("8-bit frames only"));
    };
    let mut bytes = format!("P6\n{} {}\n255\n", frame.width(), frame.height()).into_bytes();
    bytes.extend_from_slice(codes);
    std::fs::write(path, bytes)
}

fn merged(frames: &[(Frame, f64)], g: &InverseResponse) -> RadianceMap {
    let camera = Camera::default();
    merge::merge(
        &common::bracket(frames, &camera),
        g,
        MergeOptions::default(),
    )
    .expect("a bracket")
    .radiance
}

/// `median / p95 / share > 0.1` of `|log₂(a/b)|` of the luminance, after one global
/// scale (the median ratio), over the pixels `middle` (the reference) exposes well, a
/// margin left out.
fn errors(a: &RadianceMap, b: &RadianceMap, middle: &Frame) -> String {
    let (w, h) = (middle.width() as usize, middle.height() as usize);
    let margin = (0.03 * w.max(h) as f64).ceil() as usize;
    let good = |x: usize, y: usize| {
        (0..middle.channels()).all(|c| (10..=245).contains(&middle.code(x as u32, y as u32, c)))
    };
    let pixels: Vec<usize> = (margin..h - margin)
        .flat_map(|y| (margin..w - margin).map(move |x| (x, y)))
        .filter(|&(x, y)| good(x, y))
        .map(|(x, y)| y * w + x)
        .collect();
    let mut ratio: Vec<f64> = pixels
        .iter()
        .map(|&p| (common::luminance(a, p) / common::luminance(b, p)).log2())
        .collect();
    let scale = common::quantile(&mut ratio.clone(), 0.5);
    ratio.iter_mut().for_each(|r| *r = (*r - scale).abs());
    let off = ratio.iter().filter(|&&v| v > 0.1).count() as f64 / ratio.len().max(1) as f64;
    let median = common::quantile(&mut ratio, 0.5);
    let p95 = common::quantile(&mut ratio, 0.95);
    format!("{median:.4} / {p95:.3} / {:.1} %", 100.0 * off)
}

fn speed(runs: usize) {
    let (w, h) = (6000, 4000);
    println!("\ncost at {w}×{h}, three 8-bit frames two stops apart, best of {runs}");
    let radiance = synthetic::lens(&SceneKind::Procedural.render(w, h, 7));
    let sensor = Sensor {
        read_noise_dn: 1.0,
        seed: 7,
        ..Sensor::noiseless(ResponseCurve::Srgb, BitDepth::Eight)
    };
    let exposures = [0.25, 1.0, 4.0];
    // As in `accuracy`: the frame alignment registers the others onto stays where it is.
    let still: Vec<(Frame, f64)> = exposures
        .iter()
        .map(|&e| (expose(&radiance, e, &sensor), e))
        .collect();
    let reference = align::choose_reference(&still.iter().map(|(f, _)| f).collect::<Vec<_>>());
    let mut outer = common::MOVES[1].outer.iter();
    // Reference pixel → moved frame's pixel: the moved camera sees the scene moved.
    let moves: Vec<Option<[[f64; 3]; 3]>> = (0..exposures.len())
        .map(|k| {
            (k != reference)
                .then(|| inverse(&common::matrix(w, h, *outer.next().expect("two moves"))))
        })
        .collect();
    let frames: Vec<(Frame, f64)> = still
        .iter()
        .zip(&moves)
        .map(|((f, e), t)| match t {
            None => (f.clone(), *e),
            Some(t) => {
                let seen = synthetic::moved(&radiance, t).expect("an invertible move");
                (expose(&seen, *e, &sensor), *e)
            }
        })
        .collect();
    let (moved, tripod) = (views(&frames), views(&still));
    let g = InverseResponse::srgb(3, 1024);
    let alignment = align::align(&moved, &g, AlignMode::Auto);
    let estimate = common::best_of(runs, &|| {
        align::align(&moved, &g, AlignMode::Auto);
    });
    let warp = common::best_of(runs, &|| {
        align::warp_frames(&moved, &alignment);
    });
    let unmoved = align::align(&tripod, &g, AlignMode::Auto);
    assert!(
        unmoved.frames.iter().all(|f| f.motion.is_none()),
        "a still frame moved: {unmoved:?}"
    );
    let estimate_still = common::best_of(runs, &|| {
        align::align(&tripod, &g, AlignMode::Auto);
    });
    println!("wall time, and CPU time of all threads in parentheses");
    println!("| step | handheld move | tripod (no move) |");
    println!("|---|---|---|");
    let cell = |(wall, cpu): (f64, f64)| format!("{wall:.3} s ({cpu:.2} s)");
    println!(
        "| `align::align` (estimation) | {} | {} |",
        cell(estimate),
        cell(estimate_still)
    );
    println!(
        "| `align::warp_frames` (two frames) | {} | nothing to resample |",
        cell(warp)
    );
    for (k, f) in alignment.frames.iter().enumerate() {
        let ((dx, dy), angle) = f.shift_and_rotation(w, h);
        let truth = moves[k].map_or_else(String::new, |t| {
            let truth = align::FrameAlignment {
                transform: t,
                ..align::FrameAlignment::unmoved(None)
            };
            let ((tx, ty), ta) = truth.shift_and_rotation(w, h);
            format!(" (true ({tx:.2}, {ty:.2}) px, {ta:.3}°)")
        });
        println!(
            "frame {k}: {:?}, shift ({dx:.2}, {dy:.2}) px, {angle:.3}°{truth}, note {:?}",
            f.motion, f.note
        );
    }
    merge_errors(&still, &frames, &moves, reference, &g);
}

/// The luminance error (as in `accuracy`) of the merge of `moved` (`moves[k]` takes a
/// reference pixel to frame `k`'s) against the merge of `still`: unaligned, aligned, and
/// with the exact move undone.
fn merge_errors(
    still: &[(Frame, f64)],
    moved: &[(Frame, f64)],
    moves: &[Option<[[f64; 3]; 3]>],
    reference: usize,
    g: &InverseResponse,
) {
    let truth = merged(still, g);
    let error = |fs: &[(Frame, f64)]| errors(&merged(fs, g), &truth, &still[reference].0);
    let undone: Vec<(Frame, f64)> = moved
        .iter()
        .zip(moves)
        .map(|((f, e), t)| (t.map_or_else(|| f.clone(), |t| warped(f, &t)), *e))
        .collect();
    println!("\nthe merge against the still frames' (median / p95 / share > 0.1 stop)");
    println!("| unaligned | filmback | move undone (floor) |");
    println!("|---|---|---|");
    println!(
        "| {} | {} | {} |",
        error(moved),
        error(&aligned(moved, g).0),
        error(&undone)
    );
}
