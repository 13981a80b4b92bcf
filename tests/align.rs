//! Alignment end to end: synthetic brackets whose outer frames are moved by known
//! transforms, merged after alignment and compared with the merge of the unmoved frames;
//! an aligned bracket through `filmback merge` gives the same radiance with alignment on
//! and off, the demo's still JPEGs stay where they are, and the example's handheld JPEGs
//! are aligned; a DNG bracket moved by a known shift.

use std::path::{Path, PathBuf};

use filmback::align::{self, AlignFrame, AlignMode, IDENTITY};
use filmback::frame::{BitDepth, Frame};
use filmback::merge::{self, BracketFrame, MergeOptions};
use filmback::metadata::{Camera, CaptureTime};
use filmback::radiance::RadianceMap;
use filmback::response::InverseResponse;
use filmback::synthetic::{self, Encoding, ResponseCurve, Sensor, Shot, demo, measure};

use crate::common;

const W: u32 = 320;
const H: u32 = 240;

/// Two stops apart; the middle frame exposes the synthetic scene best.
const EXPOSURES: [f64; 3] = [0.0625, 0.25, 1.0];

fn sensor() -> Sensor {
    Sensor {
        curve: ResponseCurve::Srgb,
        bit_depth: BitDepth::Eight,
        read_noise_dn: 0.5,
        full_well_electrons: Some(20_000.0),
        seed: 5,
    }
}

/// A shift by `(dx, dy)` and a rotation by `degrees` about the frame's centre.
fn rigid(degrees: f64, dx: f64, dy: f64) -> [[f64; 3]; 3] {
    let (cx, cy) = (f64::from(W - 1) / 2.0, f64::from(H - 1) / 2.0);
    let (s, c) = degrees.to_radians().sin_cos();
    [
        [c, -s, cx - c * cx + s * cy + dx],
        [s, c, cy - s * cx - c * cy + dy],
        [0.0, 0.0, 1.0],
    ]
}

/// The scene at twice the frames' resolution, through a lens ([`binomial`]).
fn scene(seed: u64) -> RadianceMap {
    binomial(&synthetic::scene(2 * W, 2 * H, seed))
}

/// The frame at `exposure` of a camera moved by `t` (frame pixels).
fn frame(scene: &RadianceMap, exposure: f64, t: &[[f64; 3]; 3]) -> Frame {
    synthetic::expose(&view(scene, t), exposure, &sensor())
}

/// The radiance a camera moved by `t` (frame pixels) sees: the fine scene moved, then
/// 2 × 2 means.
fn view(scene: &RadianceMap, t: &[[f64; 3]; 3]) -> RadianceMap {
    // Frame pixel u is centred on fine pixel 2u + 0.5: T_fine = F·T·F⁻¹.
    let fine = |m: &[[f64; 3]; 3]| {
        let a = [[2.0, 0.0, 0.5], [0.0, 2.0, 0.5], [0.0, 0.0, 1.0]];
        let b = [[0.5, 0.0, -0.25], [0.0, 0.5, -0.25], [0.0, 0.0, 1.0]];
        let mul = |x: &[[f64; 3]; 3], y: &[[f64; 3]; 3]| {
            [0, 1, 2].map(|r| [0, 1, 2].map(|c| (0..3).map(|k| x[r][k] * y[k][c]).sum::<f64>()))
        };
        mul(&mul(&a, m), &b)
    };
    let moved = synthetic::moved(scene, &fine(t)).unwrap();
    let (w, c) = (W as usize, 3);
    let p = moved.pixels();
    let mut out = vec![0f32; (W * H * 3) as usize];
    for y in 0..H as usize {
        for x in 0..w {
            for ch in 0..c {
                let at = |xx: usize, yy: usize| p[(yy * 2 * w + xx) * c + ch];
                out[(y * w + x) * c + ch] = (at(2 * x, 2 * y)
                    + at(2 * x + 1, 2 * y)
                    + at(2 * x, 2 * y + 1)
                    + at(2 * x + 1, 2 * y + 1))
                    / 4.0;
            }
        }
    }
    RadianceMap::new(W, H, 3, out).unwrap()
}

fn merged(frames: &[&Frame]) -> RadianceMap {
    let camera = Camera::default();
    let bracket: Vec<BracketFrame<'_>> = frames
        .iter()
        .zip(EXPOSURES)
        .map(|(frame, exposure)| BracketFrame {
            source: Path::new("frame"),
            frame,
            exposure,
            camera: &camera,
        })
        .collect();
    let g = InverseResponse::srgb(3, 1024);
    merge::merge(&bracket, &g, MergeOptions::default())
        .unwrap()
        .radiance
}

/// The luminance error in stops of `map` against `truth` over the pixels well exposed in
/// `reference`: median and 95th percentile.
fn error_stops(map: &RadianceMap, truth: &RadianceMap, reference: &Frame) -> (f64, f64) {
    let (low, high) = align::well_exposed_codes(255);
    let luminance = |p: &[f32]| 0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2];
    let mut errors: Vec<f64> = map
        .pixels()
        .chunks(3)
        .zip(truth.pixels().chunks(3))
        .enumerate()
        .filter(|&(i, _)| {
            let (x, y) = ((i % W as usize) as u32, (i / W as usize) as u32);
            (0..3).all(|c| (low..=high).contains(&reference.code(x, y, c)))
        })
        .map(|(_, (a, b))| f64::from(luminance(a) / luminance(b)).log2().abs())
        .collect();
    errors.sort_by(f64::total_cmp);
    let at = |q: f64| errors[((errors.len() - 1) as f64 * q) as usize];
    (at(0.5), at(0.95))
}

#[test]
fn a_moved_bracket_merges_close_to_the_unmoved_one() {
    let scene = scene(21);
    let still: Vec<Frame> = EXPOSURES
        .iter()
        .map(|&e| frame(&scene, e, &IDENTITY))
        .collect();
    let moves = [rigid(0.4, 6.5, -3.2), IDENTITY, rigid(-0.3, -5.1, 4.4)];
    let moved: Vec<Frame> = EXPOSURES
        .iter()
        .zip(&moves)
        .map(|(&e, t)| frame(&scene, e, t))
        .collect();
    let truth = merged(&still.iter().collect::<Vec<_>>());
    let inputs: Vec<AlignFrame<'_>> = moved
        .iter()
        .zip(EXPOSURES)
        .map(|(frame, exposure)| AlignFrame { frame, exposure })
        .collect();
    let alignment = align::align(&inputs, &InverseResponse::srgb(3, 1024), AlignMode::Auto);
    assert_eq!(alignment.reference, 1);
    assert!(alignment.frames[0].motion.is_some() && alignment.frames[2].motion.is_some());
    let warped = align::warp_frames(&inputs, &alignment);
    let aligned: Vec<&Frame> = moved
        .iter()
        .zip(&warped)
        .map(|(f, w)| w.as_ref().unwrap_or(f))
        .collect();
    let (median, p95) = error_stops(&merged(&aligned), &truth, &still[1]);
    let (median_off, p95_off) = error_stops(
        &merged(&moved.iter().collect::<Vec<_>>()),
        &truth,
        &still[1],
    );
    assert!(
        median < 0.02 && p95 < 0.25,
        "aligned: median {median:.4}, p95 {p95:.4} stop (unaligned {median_off:.4}, {p95_off:.4})"
    );
    assert!(
        p95 < p95_off / 4.0,
        "aligned p95 {p95:.4} against {p95_off:.4} unaligned"
    );
}

/// 1/60, 1/15, 1/4 s at f/8, ISO 100.
fn shots() -> Vec<Shot> {
    let first = CaptureTime {
        year: 2026,
        month: 11,
        day: 27,
        hour: 9,
        minute: 0,
        second: 0,
        nanos: None,
        offset_minutes: None,
    };
    Shot::series(
        &demo::camera("Align Body", None),
        first,
        &[1.0 / 60.0, 1.0 / 15.0, 0.25],
        8.0,
        100.0,
        0.5,
    )
}

#[test]
fn an_aligned_bracket_develops_identically_with_alignment_on_and_off() {
    let dir = tempfile::tempdir().unwrap();
    let scene = scene(23);
    let mut paths = Vec::new();
    for (k, (shot, e)) in shots().iter().zip(EXPOSURES).enumerate() {
        let path = dir.path().join(format!("f{k}.png"));
        synthetic::write(&path, &frame(&scene, e, &IDENTITY), shot, Encoding::Png).unwrap();
        paths.push(path);
    }
    let mut maps = Vec::new();
    for mode in ["off", "auto"] {
        let out = dir.path().join(mode);
        let args = ["--srgb", "--tonemap", "linear", "--align", mode];
        let report = merged_report(&paths, &args, &out);
        assert_eq!(report["alignment"]["mode"], mode);
        let (pixels, attributes) = common::read_exr(&out.join("f0.exr"));
        let record = format!("{:?}", attributes.other);
        assert!(
            record.contains("filmbackAlignment") && record.contains("reference frame 1"),
            "{record}"
        );
        maps.push(pixels);
    }
    assert!(
        maps[0] == maps[1],
        "alignment changed an aligned bracket's radiance"
    );
}

/// The bracket `filmback watch --demo` drops (still JPEGs, the darkest frame exposing the
/// scene best, so the brightest, four stops from it, shares a fifth of its blocks): each
/// frame merged where it is. Registered directly on that fifth, it was taken for a
/// homography 0.2 px off.
#[test]
fn the_demo_bracket_is_merged_unmoved() {
    let dir = tempfile::tempdir().unwrap();
    let shots = demo::aeb("Demo Camera", Some("0001"), 10);
    let (width, height) = demo::SIZE;
    let mut paths = Vec::new();
    for (k, bytes) in demo::jpegs(width, height, &shots, demo::SCENE)
        .unwrap()
        .iter()
        .enumerate()
    {
        paths.push(demo::drop_frame(dir.path(), &format!("demo-{k}.jpg"), bytes).unwrap());
    }
    let report = merged_report(&paths, &["--tonemap", "linear"], &dir.path().join("out"));
    for frame in report["alignment"]["frames"].as_array().unwrap() {
        assert!(frame["motion"].is_null(), "a still frame moved: {frame}");
    }
}

/// The example's handheld bracket (`cargo run --example synthetic_bracket -- DIR jpeg
/// CURVE moved`) through `filmback merge`, its response recovered from the JPEGs: both
/// moved frames within half a pixel of their true moves at every corner. Through the
/// film-S curve the middle frame is registered on the finer levels only, the first of them
/// starting hundreds of pixels off, and its homography is not determined: the rigid model
/// that replaces it must start from the homography's estimate, not from there.
#[test]
fn the_example_handheld_bracket_is_aligned() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = synthetic::EXAMPLE_SIZE;
    for (curve, response) in [
        ("srgb", ResponseCurve::Srgb),
        ("film-s", ResponseCurve::FilmS),
    ] {
        let shots = synthetic::example_bracket(response, BitDepth::Eight, true).unwrap();
        let mut paths = Vec::new();
        for (k, (shot, frame)) in shots.iter().enumerate() {
            let path = dir.path().join(format!("{curve}-{k}.jpg"));
            synthetic::write(&path, frame, shot, Encoding::Jpeg { quality: 92 }).unwrap();
            paths.push(path);
        }
        let out = dir.path().join(curve);
        let report = merged_report(&paths, &["--tonemap", "linear"], &out);
        let alignment = &report["alignment"];
        assert!(
            alignment["reference"].as_str().unwrap().ends_with("-0.jpg"),
            "{alignment}"
        );
        let first = matrix(&synthetic::example_move(-1.0));
        for k in [1, 2] {
            let truth =
                matrix(&synthetic::example_move(k as f64 - 1.0)) * first.try_inverse().unwrap();
            let truth = [0, 1, 2].map(|r| [0, 1, 2].map(|c| truth[(r, c)]));
            let found: [[f64; 3]; 3] =
                serde_json::from_value(alignment["frames"][k]["matrix"].clone()).unwrap();
            let error = measure::corner_error(w, h, &found, &truth);
            assert!(
                error < 0.5,
                "{curve}, frame {k}: corners {error:.2} px off: {}",
                alignment["frames"][k]
            );
        }
    }
}

/// A row-major pixel transform as a matrix.
fn matrix(m: &[[f64; 3]; 3]) -> nalgebra::Matrix3<f64> {
    nalgebra::Matrix3::from_fn(|r, c| m[r][c])
}

/// `filmback merge PATHS ARGS -o OUT --json`, which must succeed: its report.
fn merged_report(paths: &[PathBuf], args: &[&str], out: &Path) -> serde_json::Value {
    let run = common::filmback()
        .arg("merge")
        .args(paths)
        .args(args)
        .arg("-o")
        .arg(out)
        .arg("--json")
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    serde_json::from_slice(&run.stdout).unwrap()
}

/// Three DNGs (the typical Bayer sensor, noise seed 3) at [`EXPOSURES`] of `views`, each
/// a `width × height` radiance map, decoded as the pipeline decodes them.
#[cfg(feature = "raw")]
fn dng_bracket(views: [RadianceMap; 3], dir: &Path) -> Vec<filmback::frame::LoadedFrame> {
    use filmback::frame::{self, Limits};
    use filmback::synthetic::RawSensor;
    let sensor = RawSensor::typical(3);
    let (width, height) = (views[0].width(), views[0].height());
    shots()
        .iter()
        .zip(EXPOSURES)
        .zip(views)
        .enumerate()
        .map(|(k, ((shot, e), view))| {
            let signal = synthetic::raw_signal(&view, e, &sensor);
            let codes = synthetic::raw_codes(&signal, &sensor);
            let bytes = synthetic::dng(&codes, width, height, &sensor, shot).unwrap();
            let path = dir.join(format!("r{k}.dng"));
            std::fs::write(&path, bytes).unwrap();
            frame::load(&path, Limits::default()).unwrap()
        })
        .collect()
}

/// The mosaics of `loaded` DNGs at [`EXPOSURES`].
#[cfg(feature = "raw")]
fn mosaics(loaded: &[filmback::frame::LoadedFrame]) -> Vec<align::MosaicFrame<'_>> {
    use filmback::frame::Samples;
    loaded
        .iter()
        .zip(EXPOSURES)
        .map(|(f, exposure)| {
            let Samples::Sixteen(codes) = f.frame.samples() else {
                panic!("a raw frame holds 16-bit codes")
            };
            align::MosaicFrame {
                codes,
                width: f.frame.width() as usize,
                height: f.frame.height() as usize,
                info: f.raw.as_deref().unwrap(),
                exposure,
            }
        })
        .collect()
}

#[cfg(feature = "raw")]
#[test]
fn a_shifted_dng_bracket_is_aligned_in_cfa_space() {
    let dir = tempfile::tempdir().unwrap();
    let scene = scene(25);
    let shift = rigid(0.0, 3.4, -2.6);
    let views = [
        view(&scene, &shift),
        view(&scene, &IDENTITY),
        view(&scene, &IDENTITY),
    ];
    let loaded = dng_bracket(views, dir.path());
    let mosaics = mosaics(&loaded);
    let alignment = align::align_mosaics(&mosaics, AlignMode::Auto);
    // A linear sensor's brighter frames have the less noisy mid-tones.
    let reference = alignment.reference;
    assert_ne!(reference, 0);
    let f = &alignment.frames[0];
    assert!(f.motion.is_some(), "{f:?}");
    let ((dx, dy), angle) = f.shift_and_rotation(W, H);
    // Estimated on 2 × 2 CFA tiles of a 320 × 240 mosaic: about 0.15 px off (a known gap
    // to the 0.1 px of the JPEG path).
    assert!(
        (dx - 3.4).abs() < 0.25 && (dy + 2.6).abs() < 0.25 && angle.abs() < 0.05,
        "shift ({dx:.3}, {dy:.3}), rotation {angle:.4}"
    );
    let other = 3 - reference;
    assert_eq!(
        alignment.frames[other].motion, None,
        "{:?}",
        alignment.frames[other]
    );
    let warped = align::warp_mosaics(&mosaics, &alignment);
    assert!(warped[0].is_some() && warped[1].is_none() && warped[2].is_none());
}

/// A DNG bracket large enough to be estimated on blocks of several CFA tiles (1600 × 1200:
/// blocks of 4 pixels) is refined on the tiles: its two shorter frames, each nudged by a
/// shift and a tenth of a degree, are found rigid (the darkest one's estimate on the
/// blocks alone is a homography 0.8 px off, refined on the tiles one 1.5 px off) and
/// within 0.15 px at every corner.
#[cfg(feature = "raw")]
#[test]
fn a_nudged_dng_bracket_is_refined_on_cfa_tiles() {
    let (w, h) = RIGID_BRACKET;
    found_rigid([
        synthetic::camera_move(w, h, 0.08, (2.3, -1.7), (0.0, 0.0)),
        synthetic::camera_move(w, h, -0.1, (-2.8, 1.2), (0.0, 0.0)),
    ]);
}

/// The size of [`found_rigid`]'s frames.
#[cfg(feature = "raw")]
const RIGID_BRACKET: (u32, u32) = (1600, 1200);

/// A DNG bracket of the procedural scene (seed 31, through a lens) whose two shorter
/// frames are resampled by `moves` ([`synthetic::moved`]): both are found rigid and within
/// 0.15 px at every corner, the reference unmoved.
#[cfg(feature = "raw")]
fn found_rigid(moves: [[[f64; 3]; 3]; 2]) {
    let (w, h) = RIGID_BRACKET;
    let dir = tempfile::tempdir().unwrap();
    let scene = binomial(&synthetic::scene(w, h, 31));
    let views = [
        synthetic::moved(&scene, &moves[0]).unwrap(),
        synthetic::moved(&scene, &moves[1]).unwrap(),
        scene.clone(),
    ];
    let loaded = dng_bracket(views, dir.path());
    let alignment = align::align_mosaics(&mosaics(&loaded), AlignMode::Auto);
    for (f, truth) in alignment.frames.iter().zip(&moves) {
        let error = measure::corner_error(w, h, &f.transform, truth);
        assert!(
            f.motion == Some(align::Motion::Rigid) && error < 0.15,
            "corner error {error:.3} px: {f:?}"
        );
    }
    assert_eq!(alignment.frames[2].motion, None);
}

/// A DNG bracket rendered exactly through a handheld move with perspective (0.4°, 12 px,
/// a corner moved by up to 6 px more; [`synthetic::waves`], nothing resampled) and a
/// nudge is aligned within 0.03 px at every corner of its 1600 × 1200 frames (the
/// homography kept at the blocks' estimate was 0.05 px off; the best rigid model of the
/// handheld move is 5.4 px off).
#[cfg(feature = "raw")]
#[test]
fn a_dng_bracket_moved_with_perspective_is_aligned() {
    let (w, h) = (1600u32, 1200u32);
    let dir = tempfile::tempdir().unwrap();
    let moves = [
        synthetic::camera_move(w, h, 0.08, (2.3, -1.7), (0.0, 0.0)),
        synthetic::camera_move(w, h, -0.4, (-9.5, 7.2), (0.004, -0.003)),
    ];
    let seen = |m: &[[f64; 3]; 3]| synthetic::waves(w, h, 41, m).unwrap();
    let views = [seen(&moves[0]), seen(&moves[1]), seen(&IDENTITY)];
    let loaded = dng_bracket(views, dir.path());
    let alignment = align::align_mosaics(&mosaics(&loaded), AlignMode::Auto);
    assert_eq!(alignment.reference, 2);
    for (f, truth) in alignment.frames.iter().zip(&moves) {
        let error = measure::corner_error(w, h, &f.transform, truth);
        assert!(
            f.motion.is_some() && error < 0.03,
            "corner error {error:.3} px: {f:?}"
        );
    }
    assert_eq!(alignment.frames[2].motion, None);
}

/// Frames that differ in sharpness: the middle frame of a DNG bracket shifted by half
/// pixels (resampled at a constant offset: blurred evenly), the darkest by whole ones
/// (sharp) and registered through the blurred one. Both are found rigid within 0.15 px
/// ([`found_rigid`]): a homography refined on the tiles fits the blur as perspective.
#[cfg(feature = "raw")]
#[test]
fn a_dng_frame_blurred_by_a_half_pixel_shift_is_aligned() {
    let (w, h) = RIGID_BRACKET;
    found_rigid([
        synthetic::camera_move(w, h, 0.0, (4.0, -2.0), (0.0, 0.0)),
        synthetic::camera_move(w, h, 0.0, (2.5, -1.5), (0.0, 0.0)),
    ]);
}

/// `map` through the `[1 2 1]/4` binomial in both directions (a lens: no detail finer than
/// the sensor samples); its edge pixels as they are.
fn binomial(map: &RadianceMap) -> RadianceMap {
    let (w, h) = (map.width() as usize, map.height() as usize);
    let p = map.pixels();
    let mut out = p.to_vec();
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            for c in 0..3 {
                let at = |xx: usize, yy: usize| p[(yy * w + xx) * 3 + c];
                let row = |yy: usize| at(x - 1, yy) + 2.0 * at(x, yy) + at(x + 1, yy);
                out[(y * w + x) * 3 + c] = (row(y - 1) + 2.0 * row(y) + row(y + 1)) / 16.0;
            }
        }
    }
    RadianceMap::new(map.width(), map.height(), 3, out).unwrap()
}
