//! `cargo bench --bench deghost`: how well deghosting merges a moving subject, and what it
//! costs at 24 MP.
//!
//! **Accuracy.** A subject (a square of the frame's own texture copied from 5/8 of the width
//! and 47 % of the height, 1/5 of the height on a side) moves
//! by 1/8 of the width from frame to frame of a three-frame bracket. The merge with
//! deghosting is compared with the merge of the same frames with the subject standing
//! still where the reference frame shows it, both through one response (fitted on the
//! still frames, as the darkroom fits it): the error in stops of the luminance over the
//! area the subject sweeps (median, p95, share of pixels off by more than 0.1 stop), beside
//! the blended merge (`--deghost off`). Also the share of the whole image some frame was
//! left out of, and, for the still frames, the largest difference deghosting makes (0:
//! the merge is bit-identical). Split: the constants of `deghost` were set on the
//! synthetic procedural scene of seed 5 (`tests/deghost.rs`) and the tile vote on memorial
//! frames 65–69 (the row says so); the other rows are other seeds and scene kinds, and the
//! real brackets of `../shared/testdata/brackets` (frobisher, memorial frames 62–66,
//! learnopencv's two triples; skipped when absent).
//!
//! **Cost.** `deghost::ghost_masks` on three 6000×4000 8-bit frames two stops apart (a
//! still bracket, and the same with the subject moving; the reference given, as alignment
//! chose it), and the buffered merge with and
//! without masks; best of `--runs N` (default 3).
//!
//! `cargo bench --bench deghost -- [accuracy | speed] [--runs N]`

use std::path::PathBuf;

use filmback::align;
use filmback::deghost::{self, GhostMasks};
use filmback::frame::{self, BitDepth, Frame, Limits, Samples};
use filmback::merge::{self, MergeOptions};
use filmback::metadata::Camera;
use filmback::radiance::RadianceMap;
use filmback::response::InverseResponse;
use filmback::synthetic::{ResponseCurve, SceneKind, Sensor, expose};

#[path = "../common/mod.rs"]
mod common;

/// Frames with their relative exposures.
type Frames = [(Frame, f64)];

/// A bracket: its frames with relative exposures, and a name.
struct Case {
    name: String,
    frames: Vec<(Frame, f64)>,
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let all = !args.iter().any(|a| a == "accuracy" || a == "speed");
    let runs = common::arg("--runs").map_or(3, |r| r.parse().expect("--runs N"));
    if all || args.iter().any(|a| a == "accuracy") {
        accuracy();
    }
    if all || args.iter().any(|a| a == "speed") {
        speed(runs);
    }
}

fn accuracy() {
    println!("moving subject, 1/8 of the width per frame: error in stops over the swept area");
    println!(
        "| bracket | size | deghosted median / p95 / > 0.1 stop | deghosted p95 where the reference exposes well / elsewhere (share) | blended median / p95 / > 0.1 stop | left out (image) | still: left out / samples > 0.1 stop / largest |"
    );
    println!("|---|---|---|---|---|---|---|");
    let mut cases = synthetic_cases();
    cases.extend(real_cases());
    for case in &cases {
        report(case);
    }
}

/// Synthetic brackets (sRGB curve, 1 DN read noise, 8-bit, two stops apart) of scenes
/// the constants were not set on.
fn synthetic_cases() -> Vec<Case> {
    let sensor = Sensor {
        read_noise_dn: 1.0,
        seed: 21,
        ..Sensor::noiseless(ResponseCurve::Srgb, BitDepth::Eight)
    };
    [
        (SceneKind::Procedural, 21),
        (SceneKind::Procedural, 33),
        (SceneKind::Studio, 21),
    ]
    .into_iter()
    .map(|(kind, seed)| {
        let radiance = kind.render(768, 512, seed);
        let frames = [0.25, 1.0, 4.0]
            .iter()
            .map(|&e| (expose(&radiance, e, &sensor), e))
            .collect();
        Case {
            name: format!("synthetic {kind:?} seed {seed}"),
            frames,
        }
    })
    .collect()
}

/// Three files of a bracket with their relative exposures.
type Files = [(&'static str, f64); 3];

/// Three frames of each real bracket, about two or three stops apart.
fn real_cases() -> Vec<Case> {
    let dir = common::testdata_brackets();
    let brackets: [(&str, &str, Files); 5] = [
        (
            "frobisher",
            "frobisher",
            [
                ("IMG_2600.jpg", 0.125),
                ("IMG_2601.jpg", 1.0),
                ("IMG_2602.jpg", 8.0),
            ],
        ),
        (
            "memorial",
            "memorial 65–69 (tuned on)",
            [
                ("memorial0069.png", 0.125),
                ("memorial0067.png", 0.5),
                ("memorial0065.png", 2.0),
            ],
        ),
        (
            "memorial",
            "memorial 62–66",
            [
                ("memorial0066.png", 1.0),
                ("memorial0064.png", 4.0),
                ("memorial0062.png", 16.0),
            ],
        ),
        (
            "learnopencv",
            "learnopencv 1/30–2.5 s",
            [
                ("img_0.033.jpg", 1.0 / 30.0),
                ("img_0.25.jpg", 0.25),
                ("img_2.5.jpg", 2.5),
            ],
        ),
        (
            "learnopencv",
            "learnopencv 1/4–15 s",
            [
                ("img_0.25.jpg", 0.25),
                ("img_2.5.jpg", 2.5),
                ("img_15.jpg", 15.0),
            ],
        ),
    ];
    let mut cases = Vec::new();
    for (name, label, files) in brackets {
        let paths: Vec<(PathBuf, f64)> = files
            .iter()
            .map(|(f, e)| (dir.join(name).join(f), *e))
            .collect();
        if !paths.iter().all(|(p, _)| p.exists()) {
            println!("skipped {name}: {} is absent", dir.join(name).display());
            continue;
        }
        let frames = paths
            .iter()
            .map(|(p, e)| {
                (
                    frame::load(p, Limits::default())
                        .expect("a real frame")
                        .frame,
                    *e,
                )
            })
            .collect();
        cases.push(Case {
            name: format!("real {label}"),
            frames,
        });
    }
    cases
}

/// The frame with a square of side `side` copied from `(sx, sy)` to `(x0, y0)` (the
/// frame's own texture, so it is exposed as the frame is).
fn paste(frame: &Frame, side: usize, from: (usize, usize), to: (usize, usize)) -> Frame {
    let (w, c) = (frame.width() as usize, frame.channels());
    let copy = |v: &mut Vec<u8>| {
        let source = v.clone();
        for y in 0..side {
            for x in 0..side {
                let s = ((from.1 + y) * w + from.0 + x) * c;
                let d = ((to.1 + y) * w + to.0 + x) * c;
                v[d..d + c].copy_from_slice(&source[s..s + c]);
            }
        }
    };
    let Samples::Eight(codes) = frame.samples() else {
        panic!("8-bit frames only");
    };
    let mut codes = codes.clone();
    copy(&mut codes);
    Frame::new(frame.width(), frame.height(), c, Samples::Eight(codes)).expect("same size")
}

/// The subject's square side and where it is copied from and to, in frame `k`.
fn subject(frame: &Frame, k: usize) -> (usize, (usize, usize), (usize, usize)) {
    let (w, h) = (frame.width() as usize, frame.height() as usize);
    let side = h / 5;
    let x = w / 8 + k * w / 8;
    (side, (w * 5 / 8, h * 47 / 100), (x, h / 2))
}

/// `frames` with the moving subject pasted into each ([`subject`], [`paste`]).
fn with_subject(frames: &[(Frame, f64)]) -> Vec<(Frame, f64)> {
    frames
        .iter()
        .enumerate()
        .map(|(k, (f, e))| {
            let (side, from, to) = subject(f, k);
            (paste(f, side, from, to), *e)
        })
        .collect()
}

fn report(case: &Case) {
    let camera = Camera::default();
    let moved = with_subject(&case.frames);
    let views: Vec<&Frame> = moved.iter().map(|(f, _)| f).collect();
    let r = align::choose_reference(&views);
    let still: Vec<(Frame, f64)> = case
        .frames
        .iter()
        .map(|(f, e)| {
            let (side, from, _) = subject(f, 0);
            (paste(f, side, from, subject(f, r).2), *e)
        })
        .collect();
    let g = common::fitted(&still);
    let masks = deghost::ghost_masks(&common::bracket(&moved, &camera), &g, r);
    let truth = merged(&still, &g, None);
    let first = &case.frames[0].0;
    let (side, _, start) = subject(first, 0);
    let end = subject(first, 2).2.0 + side;
    let area = (start.0..end, start.1..start.1 + side);
    let area: Vec<usize> = area
        .1
        .flat_map(|y| area.0.clone().map(move |x| y * first.width() as usize + x))
        .collect();
    let deghosted_map = merged(&moved, &g, Some(&masks));
    let deghosted = errors(&deghosted_map, &truth, &area);
    let (well, poorly): (Vec<usize>, Vec<usize>) =
        area.iter().partition(|&&p| well_exposed(&moved[r].0, p));
    let split = format!(
        "{} / {} ({:.1} %)",
        p95(&deghosted_map, &truth, &well),
        p95(&deghosted_map, &truth, &poorly),
        100.0 * poorly.len() as f64 / area.len() as f64
    );
    let blended = errors(&merged(&moved, &g, None), &truth, &area);
    let still_masks = deghost::ghost_masks(&common::bracket(&still, &camera), &g, r);
    let change = change(&merged(&still, &g, Some(&still_masks)), &truth);
    println!(
        "| {} | {}×{} | {} | {split} | {} | {:.1} % | {:.2} % / {change} |",
        case.name,
        first.width(),
        first.height(),
        deghosted,
        blended,
        100.0 * masks.share(),
        100.0 * still_masks.share()
    );
}

fn merged(frames: &[(Frame, f64)], g: &InverseResponse, masks: Option<&GhostMasks>) -> RadianceMap {
    let camera = Camera::default();
    let masks = masks.map(GhostMasks::masks).unwrap_or_default();
    merge::merge_masked(
        &common::bracket(frames, &camera),
        g,
        MergeOptions::default(),
        &masks,
    )
    .expect("a bracket")
    .radiance
}

/// Whether `frame` exposes every channel of pixel `p` well (`deghost::WELL_EXPOSED`):
/// elsewhere its sample is only a bound, and what it shows there no other frame of a
/// moved bracket measures.
fn well_exposed(frame: &Frame, p: usize) -> bool {
    let Samples::Eight(codes) = frame.samples() else {
        panic!("8-bit frames only");
    };
    let c = frame.channels();
    let (low, high) = deghost::WELL_EXPOSED;
    codes[p * c..(p + 1) * c].iter().all(|&k| {
        let b = f64::from(k) / 255.0;
        (low..=high).contains(&b)
    })
}

/// `|log₂(a/b)|` of the luminance at each of `pixels`.
fn stops(a: &RadianceMap, b: &RadianceMap, pixels: &[usize]) -> Vec<f64> {
    pixels
        .iter()
        .map(|&p| {
            (common::luminance(a, p) / common::luminance(b, p))
                .log2()
                .abs()
        })
        .collect()
}

/// The 95th percentile of [`stops`] over `pixels`, or "—" for none.
fn p95(a: &RadianceMap, b: &RadianceMap, pixels: &[usize]) -> String {
    if pixels.is_empty() {
        return "—".into();
    }
    format!("{:.3}", common::quantile(&mut stops(a, b, pixels), 0.95))
}

/// `median / p95 / share > 0.1` of [`stops`] over `area`.
fn errors(a: &RadianceMap, b: &RadianceMap, area: &[usize]) -> String {
    let mut e = stops(a, b, area);
    let off = e.iter().filter(|&&v| v > 0.1).count() as f64 / e.len() as f64;
    let median = common::quantile(&mut e, 0.5);
    let p95 = common::quantile(&mut e, 0.95);
    format!("{median:.4} / {p95:.3} / {:.1} %", 100.0 * off)
}

/// The share of samples that differ by more than 0.1 stop, and the largest difference.
fn change(a: &RadianceMap, b: &RadianceMap) -> String {
    let d: Vec<f64> = a
        .pixels()
        .iter()
        .zip(b.pixels())
        .map(|(&x, &y)| {
            (f64::from(x).max(1e-9) / f64::from(y).max(1e-9))
                .log2()
                .abs()
        })
        .collect();
    let off = d.iter().filter(|&&v| v > 0.1).count() as f64 / d.len() as f64;
    let largest = d.iter().copied().fold(0.0, f64::max);
    format!("{:.3} % / {largest:.3} stop", 100.0 * off)
}

fn speed(runs: usize) {
    let (w, h) = (6000, 4000);
    println!("\ncost at {w}×{h}, three 8-bit frames two stops apart, best of {runs}");
    let radiance = SceneKind::Procedural.render(w, h, 7);
    let sensor = Sensor {
        read_noise_dn: 1.0,
        seed: 7,
        ..Sensor::noiseless(ResponseCurve::Srgb, BitDepth::Eight)
    };
    let still: Vec<(Frame, f64)> = [0.25, 1.0, 4.0]
        .iter()
        .map(|&e| (expose(&radiance, e, &sensor), e))
        .collect();
    let moved = with_subject(&still);
    let g = InverseResponse::srgb(3, 1024);
    let camera = Camera::default();
    println!("wall time, and CPU time of all threads in parentheses");
    println!("| step | still | moving subject |");
    println!("|---|---|---|");
    // The reference comes with the alignment (`Alignment::reference`), chosen once.
    let reference = |frames: &Frames| {
        align::choose_reference(&frames.iter().map(|(f, _)| f).collect::<Vec<_>>())
    };
    let references = (reference(&still), reference(&moved));
    let masks_of = |frames: &[(Frame, f64)], r: usize| {
        deghost::ghost_masks(&common::bracket(frames, &camera), &g, r)
    };
    let masks = (
        masks_of(&still, references.0),
        masks_of(&moved, references.1),
    );
    let row = |name: &str, f: &dyn Fn(&Frames, &GhostMasks)| {
        let still_t = common::best_of(runs, &|| f(&still, &masks.0));
        let moved_t = common::best_of(runs, &|| f(&moved, &masks.1));
        println!(
            "| {name} | {:.3} s ({:.2} s) | {:.3} s ({:.2} s) |",
            still_t.0, still_t.1, moved_t.0, moved_t.1
        );
    };
    row("ghost masks", &|frames, m| {
        masks_of(frames, m.reference);
    });
    row("merge, no masks", &|frames, _| {
        merged(frames, &g, None);
    });
    row("merge with the masks", &|frames, m| {
        merged(frames, &g, Some(m));
    });
}
