//! Integration tests of the synthetic ground truth (`filmback::synthetic`).

use std::path::Path;

use filmback::synthetic::{ResponseCurve, dorf_curves};

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
/// Prints its figures; run with `cargo test --release --test synthetic -- --ignored --nocapture`.
#[test]
#[ignore = "one-off measurement at 6000×4000; run in release"]
fn full_size_scene_timing_and_range() {
    use filmback::frame::BitDepth;
    use filmback::synthetic::{Sensor, expose, scene};
    use std::time::Instant;

    let start = Instant::now();
    let radiance = scene(6000, 4000, 1);
    let scene_s = start.elapsed().as_secs_f64();
    let sensor = Sensor {
        read_noise_dn: 4.0,
        full_well_electrons: Some(30_000.0),
        seed: 1,
        ..Sensor::noiseless(ResponseCurve::FilmS, BitDepth::Sixteen)
    };
    let start = Instant::now();
    let frame = expose(&radiance, 1.0, &sensor);
    let expose_s = start.elapsed().as_secs_f64();
    let start = Instant::now();
    let noiseless = expose(
        &radiance,
        1.0,
        &Sensor::noiseless(ResponseCurve::Srgb, BitDepth::Eight),
    );
    let noiseless_s = start.elapsed().as_secs_f64();
    assert_eq!(frame.pixel_count(), noiseless.pixel_count());

    let mut y: Vec<f64> = radiance
        .pixels()
        .chunks_exact(3)
        .map(|p| 0.2126 * f64::from(p[0]) + 0.7152 * f64::from(p[1]) + 0.0722 * f64::from(p[2]))
        .collect();
    y.sort_unstable_by(f64::total_cmp);
    let at = |p: f64| y[((y.len() - 1) as f64 * p).round() as usize];
    let range = (at(0.999) / at(0.001)).log2();
    println!(
        "6000x4000 on {} threads: scene {scene_s:.3} s, expose (film-s, 16-bit, read+shot noise) {expose_s:.3} s, expose (sRGB, 8-bit, noiseless) {noiseless_s:.3} s",
        rayon::current_num_threads()
    );
    println!(
        "luminance p0.1 = {:.3e}, p50 = {:.3}, p99.9 = {:.1}: dynamic range {range:.2} stops",
        at(0.001),
        at(0.5),
        at(0.999)
    );
    assert!(range >= 16.0);
}
