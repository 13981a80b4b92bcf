//! Deghosting against synthetic ground truth: a subject that moves between the frames of
//! a bracket is merged as the reference frame shows it, and a still bracket is merged
//! exactly as without deghosting; `filmback merge --ghost-map` shows where frames were
//! left out.

use std::path::Path;

use filmback::align;
use filmback::deghost::{self, GhostMasks};
use filmback::frame::{BitDepth, Frame};
use filmback::merge::{self, BracketFrame, MergeOptions};
use filmback::metadata::Camera;
use filmback::radiance::RadianceMap;
use filmback::response::InverseResponse;
use filmback::synthetic::{self, Encoding, ResponseCurve, Sensor, demo, expose, scene};

use crate::common;

const WIDTH: u32 = 384;
const HEIGHT: u32 = 256;
/// Three frames two stops apart.
const EXPOSURES: [f64; 3] = [0.25, 1.0, 4.0];
/// The subject's side, pixels.
const SUBJECT: usize = 48;

/// The true inverse response of `curve`, sampled at every 8-bit code.
fn true_response(curve: &ResponseCurve) -> InverseResponse {
    let g: Vec<f64> = (0..256).map(|k| curve.inverse(k as f64 / 255.0)).collect();
    InverseResponse::from_samples(vec![g; 3]).unwrap()
}

/// The scene with a square subject (a brighter, shifted copy of the scene's own texture)
/// whose left edge is at `x0`, rows 100..148.
fn with_subject(base: &RadianceMap, x0: usize) -> RadianceMap {
    let mut map = base.clone();
    let w = WIDTH as usize;
    let source = base.pixels().to_vec();
    let pixels = map.pixels_mut();
    for y in 100..100 + SUBJECT {
        for x in x0..x0 + SUBJECT {
            let from = ((y + 40) * w + (x + 60) % w) * 3;
            for c in 0..3 {
                pixels[(y * w + x) * 3 + c] = 3.0 * source[from + c] + 0.02;
            }
        }
    }
    map
}

fn sensor(seed: u64) -> Sensor {
    Sensor {
        read_noise_dn: 1.0,
        seed,
        ..Sensor::noiseless(ResponseCurve::Srgb, BitDepth::Eight)
    }
}

/// The bracket's frames with the subject at `positions[k]` in frame `k`.
fn shoot(base: &RadianceMap, positions: [usize; 3]) -> Vec<Frame> {
    EXPOSURES
        .iter()
        .zip(positions)
        .map(|(&e, x0)| expose(&with_subject(base, x0), e, &sensor(9)))
        .collect()
}

/// The ghost masks of `frames` onto the reference alignment would choose.
fn masks_onto_chosen(frames: &[Frame], camera: &Camera, g: &InverseResponse) -> GhostMasks {
    let reference = align::choose_reference(&frames.iter().collect::<Vec<_>>());
    deghost::ghost_masks(&bracket(frames, camera), g, reference)
}

fn bracket<'a>(frames: &'a [Frame], camera: &'a Camera) -> Vec<BracketFrame<'a>> {
    frames
        .iter()
        .zip(EXPOSURES)
        .map(|(frame, exposure)| BracketFrame {
            source: Path::new("synthetic"),
            frame,
            exposure,
            camera,
        })
        .collect()
}

fn merged(frames: &[Frame], g: &InverseResponse, masks: Option<&GhostMasks>) -> RadianceMap {
    let camera = Camera::default();
    let b = bracket(frames, &camera);
    let masks = masks.map(GhostMasks::masks).unwrap_or_default();
    merge::merge_masked(&b, g, MergeOptions::default(), &masks)
        .unwrap()
        .radiance
}

/// Median and 95th percentile of `|log₂(a/b)|` of the luminance over the pixels of the
/// rows 100..148 and columns `x0..x1` (the area the subject sweeps).
fn error_in_stops(a: &RadianceMap, b: &RadianceMap, x0: usize, x1: usize) -> (f64, f64) {
    let w = WIDTH as usize;
    let luminance = |m: &RadianceMap, p: usize| {
        let px = &m.pixels()[p * 3..p * 3 + 3];
        0.2126 * f64::from(px[0]) + 0.7152 * f64::from(px[1]) + 0.0722 * f64::from(px[2])
    };
    let mut errors: Vec<f64> = (100..100 + SUBJECT)
        .flat_map(|y| (x0..x1).map(move |x| y * w + x))
        .map(|p| {
            (luminance(a, p).max(1e-9) / luminance(b, p).max(1e-9))
                .log2()
                .abs()
        })
        .collect();
    errors.sort_by(f64::total_cmp);
    let at = |q: f64| errors[((errors.len() - 1) as f64 * q).round() as usize];
    (at(0.5), at(0.95))
}

#[test]
fn a_moving_subject_is_merged_as_the_reference_shows_it() {
    let base = scene(WIDTH, HEIGHT, 5);
    let g = true_response(&ResponseCurve::Srgb);
    // The subject moves by 1/8 of the width from frame to frame.
    let step = WIDTH as usize / 8;
    let positions = [100, 100 + step, 100 + 2 * step];
    let moving = shoot(&base, positions);
    let camera = Camera::default();
    let masks = masks_onto_chosen(&moving, &camera, &g);
    let still = shoot(&base, [positions[masks.reference]; 3]);
    let truth = merged(&still, &g, None);

    let swept = (positions[0], positions[2] + SUBJECT);
    let (median, p95) =
        error_in_stops(&merged(&moving, &g, Some(&masks)), &truth, swept.0, swept.1);
    assert!(
        median <= 0.03 && p95 <= 0.3,
        "deghosted: median {median:.4}, p95 {p95:.4} stop"
    );
    let (median_off, p95_off) =
        error_in_stops(&merged(&moving, &g, None), &truth, swept.0, swept.1);
    assert!(
        p95_off > 3.0 * p95.max(0.05),
        "blended: median {median_off:.4}, p95 {p95_off:.4} stop, not worse than deghosted"
    );
    // Away from the subject nothing was left out.
    for mask in masks.masks.iter().flatten() {
        assert!(mask[20 * WIDTH as usize + 20] == 255 && mask[240 * WIDTH as usize + 370] == 255);
    }
    assert!(
        masks.share() < 0.2,
        "{:.3} of the pixels left out",
        masks.share()
    );
}

#[test]
fn a_still_bracket_is_merged_exactly_as_without_deghosting() {
    let base = scene(WIDTH, HEIGHT, 11);
    let g = true_response(&ResponseCurve::Srgb);
    let frames = shoot(&base, [200; 3]);
    let camera = Camera::default();
    let masks = masks_onto_chosen(&frames, &camera, &g);
    assert!(masks.is_empty(), "left out: {:?}", masks.left_out);
    let plain = merge::merge(&bracket(&frames, &camera), &g, MergeOptions::default()).unwrap();
    assert_eq!(
        merged(&frames, &g, Some(&masks)).pixels(),
        plain.radiance.pixels()
    );
}

#[test]
fn a_wrong_response_does_not_make_ghosts() {
    // A gamma 2.2 camera merged through the sRGB inverse: up to ~0.1 stop off in places.
    let base = scene(WIDTH, HEIGHT, 13);
    let g = true_response(&ResponseCurve::Srgb);
    let frames: Vec<Frame> = EXPOSURES
        .iter()
        .map(|&e| {
            let sensor = Sensor {
                curve: ResponseCurve::Gamma(2.2),
                ..sensor(3)
            };
            expose(&base, e, &sensor)
        })
        .collect();
    let camera = Camera::default();
    let masks = masks_onto_chosen(&frames, &camera, &g);
    assert!(
        masks.share() < 0.01,
        "{:.4} of the pixels left out",
        masks.share()
    );
}

#[test]
fn a_tone_curve_the_response_does_not_model_does_not_make_ghosts() {
    // The short frame through gamma 1.8, the others through sRGB, all merged through the
    // sRGB inverse: the short frame reads 0.25–0.7 stop dark, by tone, all over the frame.
    let base = scene(WIDTH, HEIGHT, 17);
    let g = true_response(&ResponseCurve::Srgb);
    let frames: Vec<Frame> = EXPOSURES
        .iter()
        .enumerate()
        .map(|(k, &e)| {
            let curve = if k == 0 {
                ResponseCurve::Gamma(1.8)
            } else {
                ResponseCurve::Srgb
            };
            expose(&base, e, &Sensor { curve, ..sensor(4) })
        })
        .collect();
    let camera = Camera::default();
    let masks = masks_onto_chosen(&frames, &camera, &g);
    assert!(
        masks.share() < 0.01,
        "{:.4} of the pixels left out",
        masks.share()
    );
}

/// `frames` as PNGs in `dir` (1/250, 1/60 and 1/15 s: two stops apart, as
/// [`EXPOSURES`]), merged by `filmback merge --ghost-map`: the ghost map read back, and
/// the command's stderr.
fn ghost_map(frames: &[Frame], dir: &Path) -> (Option<Vec<u8>>, String) {
    let shots = demo::aeb("Ghost Body", None, 10);
    let paths: Vec<_> = frames
        .iter()
        .zip(&shots)
        .enumerate()
        .map(|(k, (frame, shot))| {
            let path = dir.join(format!("g{k}.png"));
            synthetic::write(&path, frame, shot, Encoding::Png).unwrap();
            path
        })
        .collect();
    let out = dir.join("out");
    let run = common::filmback()
        .arg("merge")
        .args(&paths)
        .args(["--srgb", "--tonemap", "linear", "--ghost-map", "-o"])
        .arg(&out)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&run.stderr).into_owned();
    if !run.status.success() {
        return (None, stderr);
    }
    let decoder = png::Decoder::new(std::io::BufReader::new(
        std::fs::File::open(out.join("g0.ghosts.png")).unwrap(),
    ));
    let mut reader = decoder.read_info().unwrap();
    let mut pixels = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut pixels).unwrap();
    assert_eq!(
        (info.width, info.height, info.color_type, info.bit_depth),
        (
            WIDTH,
            HEIGHT,
            png::ColorType::Grayscale,
            png::BitDepth::Eight
        )
    );
    (Some(pixels), stderr)
}

/// The ghost map is black where the subject swept (some frame left out) and white away
/// from it; a still bracket's is white everywhere; an existing map is not replaced
/// without `--force`.
#[test]
fn the_ghost_map_shows_where_frames_were_left_out() {
    let base = scene(WIDTH, HEIGHT, 5);
    let step = WIDTH as usize / 8;
    let dir = tempfile::tempdir().unwrap();
    let moving = shoot(&base, [100, 100 + step, 100 + 2 * step]);
    let (map, stderr) = ghost_map(&moving, dir.path());
    let map = map.unwrap_or_else(|| panic!("merge failed: {stderr}"));
    let at = |x: usize, y: usize| map[y * WIDTH as usize + x];
    // Inside the subject in one frame but not the reference: left out.
    assert_eq!(at(110, 124), 0, "a ghost kept");
    assert_eq!(
        (at(20, 20), at(370, 240)),
        (255, 255),
        "a still area left out"
    );

    // Every output but the map removed: the map alone stops the second run.
    for entry in std::fs::read_dir(dir.path().join("out")).unwrap() {
        let path = entry.unwrap().path();
        if !path.to_string_lossy().ends_with(".ghosts.png") {
            std::fs::remove_file(path).unwrap();
        }
    }
    let (again, stderr) = ghost_map(&moving, dir.path());
    assert!(
        again.is_none() && stderr.contains("g0.ghosts.png"),
        "{stderr}"
    );

    let still = tempfile::tempdir().unwrap();
    let frames = shoot(&base, [200; 3]);
    let (map, stderr) = ghost_map(&frames, still.path());
    let map = map.unwrap_or_else(|| panic!("merge failed: {stderr}"));
    assert!(
        map.iter().all(|&v| v == 255),
        "a still bracket's map is not white"
    );
}
