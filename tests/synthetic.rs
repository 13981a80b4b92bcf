//! Integration tests of the synthetic ground truth (`filmback::synthetic`).

use std::path::Path;

use filmback::frame::{self, BitDepth, Frame, Limits};
use filmback::metadata::{Camera, CaptureTime, Exposure};
use filmback::radiance::RadianceMap;
use filmback::synthetic::{
    Encoding, ResponseCurve, Sensor, Shot, SyntheticError, dorf_curves, encode, expose, scene,
    write,
};

fn shot(iso: f64) -> Shot {
    Shot {
        camera: Camera {
            make: Some("Filmback".to_string()),
            model: Some("Synthetic S1".to_string()),
            serial: Some("SN-0042".to_string()),
            lens: None,
        },
        exposure: Exposure {
            time_s: Some(1.0 / 125.0),
            f_number: Some(5.6),
            iso: Some(iso),
        },
        captured_at: CaptureTime {
            year: 2026,
            month: 3,
            day: 14,
            hour: 15,
            minute: 9,
            second: 26,
            nanos: Some(535_000_000),
            offset_minutes: Some(-330),
        },
    }
}

/// A small noisy frame: RGB from the scene, or grey from its green channel.
fn frame(depth: BitDepth, channels: usize) -> Frame {
    let rgb = scene(64, 48, 5);
    let radiance = if channels == 3 {
        rgb
    } else {
        let green = rgb.pixels().chunks_exact(3).map(|p| p[1]).collect();
        RadianceMap::new(64, 48, 1, green).unwrap()
    };
    let sensor = Sensor {
        read_noise_dn: 1.0,
        full_well_electrons: Some(10_000.0),
        seed: 3,
        ..Sensor::noiseless(ResponseCurve::Srgb, depth)
    };
    expose(&radiance, 1.0, &sensor)
}

fn assert_metadata_round_trips(loaded: &frame::LoadedFrame, shot: &Shot) {
    let meta = &loaded.metadata;
    assert!(meta.warnings.is_empty(), "{:?}", meta.warnings);
    assert_eq!(meta.camera, shot.camera);
    assert_eq!(meta.exposure, shot.exposure);
    assert_eq!(meta.captured_at, Some(shot.captured_at));
    assert_eq!(meta.orientation, 1);
}

/// Every container and depth decodes with the same pixels (JPEG: close) and gives back the
/// time, f-number, ISO, camera and capture time it was written with.
#[test]
fn encoded_frames_round_trip_with_their_exif() {
    let shot = shot(400.0);
    for channels in [3, 1] {
        for depth in [BitDepth::Eight, BitDepth::Sixteen] {
            let original = frame(depth, channels);
            for (encoding, name) in [
                (Encoding::Png, "f.png"),
                (Encoding::Tiff, "f.tif"),
                (Encoding::Jpeg { quality: 95 }, "f.jpg"),
            ] {
                let label = format!("{name} {depth:?} {channels} channel(s)");
                if matches!(encoding, Encoding::Jpeg { .. }) && depth == BitDepth::Sixteen {
                    let error = encode(&original, &shot, encoding).unwrap_err();
                    assert!(error.to_string().contains("8 bits"), "{label}: {error}");
                    continue;
                }
                let bytes = encode(&original, &shot, encoding).unwrap();
                let loaded = frame::decode(Path::new(name), &bytes, Limits::default())
                    .unwrap_or_else(|e| panic!("{label}: {e}"));
                assert_metadata_round_trips(&loaded, &shot);
                let decoded = &loaded.frame;
                assert_eq!(decoded.bit_depth(), depth, "{label}");
                assert_eq!(decoded.channels(), channels, "{label}");
                assert_eq!((decoded.width(), decoded.height()), (64, 48), "{label}");
                if let Encoding::Jpeg { .. } = encoding {
                    let mut error = 0.0;
                    for y in 0..48 {
                        for x in 0..64 {
                            for c in 0..channels {
                                let d = f64::from(decoded.code(x, y, c))
                                    - f64::from(original.code(x, y, c));
                                error += d.abs();
                            }
                        }
                    }
                    let mean = error / (64.0 * 48.0 * channels as f64);
                    assert!(mean < 4.0, "{label}: mean |error| {mean} codes");
                } else {
                    assert_eq!(decoded, &original, "{label}");
                }
            }
        }
    }
}

#[test]
fn iso_above_65534_is_written_as_recommended_exposure_index() {
    let shot = shot(102_400.0);
    let bytes = encode(&frame(BitDepth::Eight, 3), &shot, Encoding::Png).unwrap();
    let loaded = frame::decode(Path::new("high.png"), &bytes, Limits::default()).unwrap();
    assert_metadata_round_trips(&loaded, &shot);
}

#[test]
fn unknown_exposure_values_are_left_out() {
    let mut shot = shot(100.0);
    shot.exposure.time_s = None;
    shot.camera.serial = None;
    let bytes = encode(
        &frame(BitDepth::Eight, 3),
        &shot,
        Encoding::Jpeg { quality: 80 },
    )
    .unwrap();
    let meta = frame::decode(Path::new("a.jpg"), &bytes, Limits::default())
        .unwrap()
        .metadata;
    assert_eq!(meta.exposure.time_s, None);
    assert_eq!(meta.exposure.f_number, Some(5.6));
    assert_eq!(meta.camera.serial, None);
    assert!(
        meta.warnings.iter().any(|w| w.contains("ExposureTime")),
        "{:?}",
        meta.warnings
    );
}

#[test]
fn write_publishes_a_loadable_file_and_names_the_path_on_failure() {
    let dir = tempfile::tempdir().unwrap();
    let shot = shot(200.0);
    let original = frame(BitDepth::Sixteen, 3);
    let path = dir.path().join("bracket-0.tif");
    write(&path, &original, &shot, Encoding::Tiff).unwrap();
    let loaded = frame::load(&path, Limits::default()).unwrap();
    assert_eq!(loaded.frame, original);
    assert_metadata_round_trips(&loaded, &shot);
    assert_eq!(
        std::fs::read_dir(dir.path()).unwrap().count(),
        1,
        "no temporary left"
    );

    let missing = dir.path().join("no-such-folder").join("x.png");
    let error = write(&missing, &original, &shot, Encoding::Png).unwrap_err();
    assert!(matches!(error, SyntheticError::Publish(_)));
    assert!(error.to_string().contains("no-such-folder"), "{error}");
    let error = encode(
        &frame(BitDepth::Eight, 3),
        &shot,
        Encoding::Jpeg { quality: 0 },
    )
    .unwrap_err();
    assert!(error.to_string().contains("quality 0"), "{error}");
}

/// The real curves of the Database of Response Functions, when the shared test data is
/// present (it is not part of the repository): all 101 load, are normalised, strictly
/// increasing, and invert exactly.
#[test]
fn dorf_database_loads_when_present() {
    let path = Path::new("/work/shared/testdata/response-curves/dorf-even.csv");
    if !path.exists() {
        eprintln!("skipped: {} is absent", path.display());
        return;
    }
    let curves = dorf_curves(path).unwrap();
    assert_eq!(curves.len(), 101);
    assert_eq!(curves[0].0, "dorf-0");
    assert_eq!(curves[100].0, "dorf-200");
    for (name, curve) in &curves {
        let ResponseCurve::Sampled(samples) = curve else {
            panic!("{name} is not sampled")
        };
        assert_eq!(samples.len(), 1024, "{name}");
        curve.check().unwrap();
        for i in 0..=200 {
            let x = f64::from(i) / 200.0;
            let back = curve.inverse(curve.brightness(x));
            assert!((back - x).abs() < 1e-9, "{name}: g(f({x})) = {back}");
        }
    }
}

/// Time and dynamic range of a full-size (24 MP) scene and one noisy 16-bit exposure.
/// Prints its figures; run with `cargo test --release --test all synthetic:: -- --ignored --nocapture`.
#[test]
#[ignore = "one-off measurement at 6000×4000; run in release"]
fn full_size_scene_timing_and_range() {
    use filmback::frame::BitDepth;
    use filmback::synthetic::{Sensor, expose, scene};
    use std::time::Instant;

    // Wall time and this process's CPU time (user + system, from /proc; the machine may be
    // shared, so CPU seconds / threads is the wall time on otherwise idle cores).
    let cpu_seconds = || -> Option<f64> {
        let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
        let fields: Vec<&str> = stat.rsplit_once(')')?.1.split_whitespace().collect();
        let ticks: f64 = fields[11].parse::<f64>().ok()? + fields[12].parse::<f64>().ok()?;
        Some(ticks / 100.0)
    };
    let measure = |what: &str, run: &mut dyn FnMut()| {
        let (start, cpu) = (Instant::now(), cpu_seconds());
        run();
        let wall = start.elapsed().as_secs_f64();
        let cpu = cpu_seconds().zip(cpu).map(|(b, a)| format!("{:.2}", b - a));
        println!(
            "{what}: wall {wall:.3} s, CPU {} s",
            cpu.unwrap_or_else(|| "n/a".into())
        );
    };
    println!("6000x4000 on {} threads", rayon::current_num_threads());
    let mut radiance = None;
    measure("scene", &mut || radiance = Some(scene(6000, 4000, 1)));
    let radiance = radiance.unwrap();
    let sensor = Sensor {
        read_noise_dn: 4.0,
        full_well_electrons: Some(30_000.0),
        seed: 1,
        ..Sensor::noiseless(ResponseCurve::FilmS, BitDepth::Sixteen)
    };
    measure("expose film-s 16-bit, read + shot noise", &mut || {
        assert_eq!(expose(&radiance, 1.0, &sensor).pixel_count(), 24_000_000);
    });
    let srgb = Sensor::noiseless(ResponseCurve::Srgb, BitDepth::Eight);
    measure("expose sRGB 8-bit, noiseless", &mut || {
        assert_eq!(expose(&radiance, 1.0, &srgb).pixel_count(), 24_000_000);
    });

    let mut y: Vec<f64> = radiance
        .pixels()
        .chunks_exact(3)
        .map(|p| 0.2126 * f64::from(p[0]) + 0.7152 * f64::from(p[1]) + 0.0722 * f64::from(p[2]))
        .collect();
    y.sort_unstable_by(f64::total_cmp);
    let at = |p: f64| y[((y.len() - 1) as f64 * p).round() as usize];
    let range = (at(0.999) / at(0.001)).log2();
    println!(
        "luminance p0.1 = {:.3e}, p50 = {:.3}, p99.9 = {:.1}: dynamic range {range:.2} stops",
        at(0.001),
        at(0.5),
        at(0.999)
    );
    assert!(range >= 16.0);
}
