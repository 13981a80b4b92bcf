//! `filmback merge --dng`: the merged mosaic of a raw bracket as a linear (32-bit float,
//! CFA) DNG, read back by rawler here and by LibRaw through rawpy
//! (`tests/dng_check.py`), against the library's in-memory merge and the EXR written
//! beside it. The brackets are synthetic DNGs made here, as in `tests/raw.rs`.
#![cfg(feature = "raw")]

use std::path::{Path, PathBuf};
use std::process::Command;

use filmback::frame::{self, Limits, LoadedFrame, Samples};
use filmback::metadata::CaptureTime;
use filmback::raw::{self, RawExposure, RawInfo, colour};
use filmback::synthetic::{self, RawSensor, Shot, demo};
use rawler::rawimage::{RawImageData, RawPhotometricInterpretation};
use rawler::rawsource::RawSource;

use crate::common::{self, filmback, reference_python};

const W: u32 = 120;
const H: u32 = 80;

/// 1/500, 1/125, 1/30 s at f/8, ISO 100 (two stops apart, `R` = 16.7) of the synthetic
/// scene on `sensor`, the longest frame's scene 1.0 at its clipping point: DNGs
/// `b-1.dng` … in `dir`.
fn bracket(dir: &Path, sensor: &RawSensor) -> Vec<PathBuf> {
    let first = CaptureTime {
        year: 2026,
        month: 11,
        day: 27,
        hour: 9,
        minute: 30,
        second: 0,
        nanos: None,
        offset_minutes: None,
    };
    let times = [1.0 / 500.0, 1.0 / 125.0, 1.0 / 30.0];
    let shots = Shot::series(
        &demo::camera("Dng Body", None),
        first,
        &times,
        8.0,
        100.0,
        0.0,
    );
    let scene = synthetic::scene(W, H, sensor.seed);
    shots
        .iter()
        .enumerate()
        .map(|(i, shot)| {
            let e = times[i] / times[2];
            let codes = synthetic::raw_codes(&synthetic::raw_signal(&scene, e, sensor), sensor);
            let bytes = synthetic::dng(&codes, W, H, sensor, shot).unwrap();
            let path = dir.join(format!("b-{}.dng", i + 1));
            std::fs::write(&path, bytes).unwrap();
            path
        })
        .collect()
}

/// `filmback merge PATHS -o OUT --dng --exr float --compression none --align off`.
fn merge_with_dng(paths: &[PathBuf], out: &Path) -> std::process::Output {
    filmback()
        .arg("merge")
        .args(paths)
        .arg("-o")
        .arg(out)
        .args(["--dng", "--exr", "float", "--compression", "none"])
        .args(["--align", "off"])
        .output()
        .unwrap()
}

/// The library's merge of `frames` kept in memory (what the DNG should hold, before
/// `1/R`), the developed radiance beside it, and `R`.
fn in_memory(frames: &[LoadedFrame]) -> (raw::DevelopedRaw, f64) {
    let inputs: Vec<RawExposure<'_>> = frames
        .iter()
        .map(|f| {
            let Samples::Sixteen(codes) = f.frame.samples() else {
                panic!("a raw frame holds 16-bit codes")
            };
            RawExposure {
                path: &f.path,
                codes,
                width: f.frame.width(),
                height: f.frame.height(),
                info: f.raw.as_deref().unwrap(),
                exposure: f.metadata.exposure.relative().unwrap(),
            }
        })
        .collect();
    let developed = raw::develop_keeping(&inputs, 1.0, true).unwrap();
    let e: Vec<f64> = inputs.iter().map(|i| i.exposure).collect();
    let ratio = e.iter().cloned().fold(0.0, f64::max) / e.iter().cloned().fold(f64::MAX, f64::min);
    (developed, ratio)
}

/// The DNG as rawler decodes it: float samples, levels, CFA, neutral, matrices, camera.
struct Decoded {
    values: Vec<f32>,
    black: Vec<f32>,
    white: u32,
    cfa: String,
    wb: [f32; 4],
    matrices: Vec<(rawler::imgop::xyz::Illuminant, Vec<f32>)>,
    camera: (String, String),
}

fn decode_with_rawler(path: &Path) -> Decoded {
    let source = RawSource::new(path).unwrap();
    let decoder = rawler::get_decoder(&source).unwrap();
    let image = decoder
        .raw_image(&source, &Default::default(), false)
        .unwrap();
    let RawImageData::Float(values) = image.data.clone() else {
        panic!("the DNG holds floating-point samples")
    };
    let RawPhotometricInterpretation::Cfa(config) = &image.photometric else {
        panic!("the DNG is a CFA image: {:?}", image.photometric)
    };
    assert_eq!(
        (image.width, image.height, image.cpp),
        (W as usize, H as usize, 1)
    );
    Decoded {
        values,
        black: image.blacklevel.levels.iter().map(|r| r.as_f32()).collect(),
        white: image.whitelevel.0[0],
        cfa: config.cfa.to_string(),
        wb: image.wb_coeffs,
        matrices: image
            .color_matrix
            .iter()
            .map(|(i, m)| (*i, m.clone()))
            .collect(),
        camera: (image.make.clone(), image.model.clone()),
    }
}

/// The DNG of a merged Bayer bracket reads back in rawler with every sample equal to the
/// library's in-memory merge over `R` (bit for bit: 32-bit float is exact), with its
/// levels (0, 1), CFA, as-shot neutral, D65 colour matrix and camera; and the EXR
/// written beside it, taken back through its colour matrix, gives the same samples at
/// every pixel's own CFA colour within float rounding.
/// A bracket merged twice: by `filmback merge --dng` (which must succeed) and in memory.
struct MergedDng {
    /// The frames' files.
    paths: Vec<PathBuf>,
    /// The output folder.
    out: PathBuf,
    /// What the command printed.
    stdout: String,
    /// The frames, decoded.
    frames: Vec<LoadedFrame>,
    /// Their merge in memory ([`in_memory`]).
    developed: raw::DevelopedRaw,
    /// The bracket's exposure ratio `R`.
    ratio: f64,
}

/// A synthetic bracket of `sensor` in `dir`, merged into `dir/out` with its DNG and in
/// memory.
fn merged_with_dng(dir: &Path, sensor: &RawSensor) -> MergedDng {
    let paths = bracket(dir, sensor);
    let out = dir.join("out");
    let o = merge_with_dng(&paths, &out);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let frames: Vec<LoadedFrame> = paths
        .iter()
        .map(|p| frame::load(p, Limits::default()).unwrap())
        .collect();
    let (developed, ratio) = in_memory(&frames);
    MergedDng {
        paths,
        out,
        stdout: String::from_utf8_lossy(&o.stdout).into_owned(),
        frames,
        developed,
        ratio,
    }
}

#[test]
fn a_merged_dng_reads_back_in_rawler_as_the_merge_and_the_exr() {
    let dir = tempfile::tempdir().unwrap();
    let sensor = RawSensor::typical(61);
    let MergedDng {
        paths,
        out,
        stdout,
        frames,
        developed,
        ratio,
    } = merged_with_dng(dir.path(), &sensor);
    assert!(stdout.contains("b-1.dng"), "{stdout}");
    let merged = developed.mosaic.as_ref().unwrap();
    let dng = decode_with_rawler(&out.join("b-1.dng"));

    assert_eq!(dng.values.len(), merged.values.len());
    let inverse = (1.0 / ratio) as f32;
    for (i, (&read, &x)) in dng.values.iter().zip(&merged.values).enumerate() {
        assert_eq!(
            read.to_bits(),
            (x * inverse).to_bits(),
            "sample {i}: {read} vs {x}/R"
        );
    }
    let brightest = dng.values.iter().cloned().fold(f32::MIN, f32::max);
    assert!(
        brightest <= 1.0 && brightest > 0.9,
        "brightest sample {brightest}"
    );
    assert!(dng.black.iter().all(|&b| b == 0.0), "{:?}", dng.black);
    assert_eq!(dng.white, 1);
    assert_eq!(dng.cfa, "RGGB");
    let info = frames[0].raw.as_deref().unwrap();
    for c in 0..3 {
        let neutral = 1.0 / f64::from(dng.wb[c]);
        assert!(
            (neutral - info.neutral[c]).abs() < 1e-4,
            "neutral {c}: {neutral} vs {:?}",
            info.neutral
        );
    }
    assert_eq!(dng.matrices.len(), 1, "{:?}", dng.matrices);
    assert_eq!(dng.matrices[0].0, rawler::imgop::xyz::Illuminant::D65);
    for (read, want) in dng.matrices[0]
        .1
        .iter()
        .zip(sensor.xyz_to_camera.iter().flatten())
    {
        assert!((f64::from(*read) - want).abs() < 1e-4, "{:?}", dng.matrices);
    }
    assert_eq!(dng.camera, ("filmback".to_string(), "Dng Body".to_string()));

    // The EXR: `c · M · diag(1/n) · demosaic(x)` keeps each pixel's own CFA sample, so
    // `(M⁻¹ · rgb / c)[colour] · n[colour]` is `x` there.
    let (rgb, _) = common::read_exr(&out.join("b-1.exr"));
    let exif: Vec<_> = frames.iter().map(|f| f.metadata.exposure).collect();
    let relative: Vec<f64> = frames
        .iter()
        .map(|f| f.metadata.exposure.relative().unwrap())
        .collect();
    let (_, c) = filmback::merge::exposure_scale(&exif, &relative, 1.0);
    let m = colour::camera_to_709(info, &paths[0]).unwrap();
    let m = nalgebra::Matrix3::from_fn(|r, k| f64::from(m[r][k]) * c);
    let inverse_m = m.try_inverse().unwrap();
    let mut worst = 0.0f64;
    for y in 0..H as usize {
        for x in 0..W as usize {
            let i = y * W as usize + x;
            let p = nalgebra::Vector3::from_fn(|k, _| f64::from(rgb[3 * i + k]));
            let balanced = inverse_m * p;
            let colour = info.cfa.colour_at(x, y);
            let from_exr = balanced[colour] * info.neutral[colour];
            let scale = balanced.amax() * 3.0 + 1e-6;
            let error = (f64::from(dng.values[i]) * ratio - from_exr).abs() / scale;
            worst = worst.max(error);
        }
    }
    println!(
        "DNG against the float EXR: largest difference {worst:.2e} of the pixel's largest channel"
    );
    assert!(worst < 1e-5, "DNG and EXR differ by {worst:.2e}");
}

/// An X-Trans bracket's DNG keeps the 6×6 CFA and the merge's samples.
#[test]
fn an_xtrans_dng_keeps_its_six_by_six_cfa() {
    let dir = tempfile::tempdir().unwrap();
    let sensor = RawSensor {
        cfa: "GGRGGBGGBGGRBRGRBGGGBGGRGGRGGBRBGBRG",
        ..RawSensor::typical(67)
    };
    let MergedDng {
        out,
        developed,
        ratio,
        ..
    } = merged_with_dng(dir.path(), &sensor);
    let merged = developed.mosaic.unwrap();
    let dng = decode_with_rawler(&out.join("b-1.dng"));
    assert_eq!(dng.cfa, sensor.cfa);
    let inverse = (1.0 / ratio) as f32;
    assert!(
        dng.values
            .iter()
            .zip(&merged.values)
            .all(|(&read, &x)| read.to_bits() == (x * inverse).to_bits())
    );
}

/// A JPEG bracket asking for a DNG is refused before anything is written, naming the
/// frame and why.
#[test]
fn a_jpeg_bracket_asking_for_a_dng_is_refused_naming_the_frame() {
    let dir = tempfile::tempdir().unwrap();
    let frames = common::rig::aeb("Jpeg Body", 5, "j");
    let paths: Vec<PathBuf> = frames
        .iter()
        .map(|(name, bytes)| {
            let path = dir.path().join(name);
            std::fs::write(&path, bytes).unwrap();
            path
        })
        .collect();
    let out = dir.path().join("out");
    let o = filmback()
        .arg("merge")
        .args(&paths)
        .arg("-o")
        .arg(&out)
        .arg("--dng")
        .output()
        .unwrap();
    assert!(!o.status.success());
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(
        stderr.contains("j-1.jpg") && stderr.contains("only of a camera raw bracket"),
        "{stderr}"
    );
    assert!(stderr.contains("JPG, not camera raw"), "{stderr}");
    let written: Vec<_> = std::fs::read_dir(&out)
        .map(|d| d.flatten().map(|e| e.file_name()).collect())
        .unwrap_or_default();
    assert!(written.is_empty(), "{written:?}");
}

/// LibRaw (through rawpy from PyPI) reads the DNG of a Bayer and of an X-Trans bracket:
/// `tests/dng_check.py` compares its samples, levels, CFA, white balance and colour
/// matrix with the merge, and develops the file. Skipped, with the reason printed, when
/// rawpy is not installed.
#[test]
fn libraw_reads_the_merged_dng() {
    let xtrans = RawSensor {
        cfa: "GGRGGBGGBGGRBRGRBGGGBGGRGGRGGBRBGBRG",
        ..RawSensor::typical(73)
    };
    for sensor in [RawSensor::typical(71), xtrans] {
        if !libraw_check(&sensor) {
            return;
        }
    }
}

/// [`libraw_reads_the_merged_dng`] for one sensor: false when the check was skipped.
fn libraw_check(sensor: &RawSensor) -> bool {
    let dir = tempfile::tempdir().unwrap();
    let MergedDng {
        out,
        frames,
        developed,
        ratio,
        ..
    } = merged_with_dng(dir.path(), sensor);
    let merged = developed.mosaic.unwrap();
    // The expected samples, `x/R` as little-endian f32, and what the tags should say.
    let expected = dir.path().join("expected.f32");
    let inverse = (1.0 / ratio) as f32;
    let bytes: Vec<u8> = merged
        .values
        .iter()
        .flat_map(|&x| (x * inverse).to_le_bytes())
        .collect();
    std::fs::write(&expected, bytes).unwrap();
    let info: &RawInfo = frames[0].raw.as_deref().unwrap();
    let tags = serde_json::json!({
        "width": W, "height": H, "cfa": sensor.cfa,
        "neutral": info.neutral, "colour_matrix": sensor.xyz_to_camera,
    });
    let tags_path = dir.path().join("expected.json");
    std::fs::write(&tags_path, tags.to_string()).unwrap();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/dng_check.py");
    let Ok(o) = Command::new(reference_python("FILMBACK_PILLOW_PYTHON"))
        .arg(script)
        .arg(out.join("b-1.dng"))
        .arg(&expected)
        .arg(&tags_path)
        .output()
    else {
        println!("dng_check: skipped (no python3 to run LibRaw)");
        return false;
    };
    let stdout = String::from_utf8_lossy(&o.stdout);
    print!("{stdout}{}", String::from_utf8_lossy(&o.stderr));
    assert!(o.status.success(), "tests/dng_check.py failed");
    assert!(
        stdout.contains("skipped") || stdout.contains("dng_check: ok"),
        "{stdout}"
    );
    !stdout.contains("skipped")
}

/// The daemon under `[render] dng = true` writes a raw bracket's DNG with its EXR and
/// look, and develops a JPEG bracket of another body without one.
#[test]
fn the_daemon_writes_a_raw_brackets_dng_when_its_preset_asks() {
    use crate::common::rig::{self, Rig};
    use filmback::daemon::DarkroomLab;
    let dir = tempfile::tempdir().unwrap();
    let text = rig::config_text(dir.path(), "dng = true\n");
    let mut rig = Rig::start_with_text(dir.path(), &text, std::sync::Arc::new(DarkroomLab));
    rig::put(&rig.ingest(), &rig::raw_aeb("Raw Body", 10, "r"));
    rig::put(&rig.ingest(), &rig::aeb("Jpeg Body", 30, "j"));
    let expected = [
        "r-1.dng",
        "r-1.exr",
        "r-1.linear.jpg",
        "j-1.exr",
        "j-1.linear.jpg",
    ];
    let done = |names: &[String]| expected.iter().all(|n| names.iter().any(|m| m == n));
    rig::wait_for(&rig.out(), "both brackets' outputs", done);
    rig.stop();
    let names = rig::visible(&rig.out());
    assert!(!names.iter().any(|n| n == "j-1.dng"), "{names:?}");
    let dng = RawSource::new(&rig.out().join("r-1.dng")).unwrap();
    let image = rawler::get_decoder(&dng)
        .unwrap()
        .raw_image(&dng, &Default::default(), false)
        .unwrap();
    assert!(matches!(image.data, RawImageData::Float(_)));
}
