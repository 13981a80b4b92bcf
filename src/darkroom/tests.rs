use super::*;
use crate::frame::{BitDepth, Frame};
use crate::hdr_output::EncodeError;
use crate::metadata::{Camera, Exposure, Metadata};
use crate::synthetic::{ResponseCurve, Sensor, expose, scene};

fn loaded(name: &str, frame: Frame) -> LoadedFrame {
    LoadedFrame {
        path: PathBuf::from(name),
        frame,
        metadata: Metadata {
            camera: Camera::default(),
            exposure: Exposure::default(),
            captured_at: None,
            orientation: 1,
            warnings: Vec::new(),
        },
        #[cfg(feature = "raw")]
        raw: None,
    }
}

/// Where the tests' developments go: `dir/STEM.exr` (half PIZ) and `looks` in `format`,
/// never replacing a file, on the nominal luminance scale.
fn prints<'a>(
    dir: &'a Path,
    stem: &'a str,
    looks: &'a [Look],
    format: Format,
    exif: &'a SourceExif,
) -> Prints<'a> {
    Prints {
        dir,
        stem,
        exr: Some(ExrOptions::default()),
        radiance_hdr: false,
        dng: false,
        looks,
        format,
        space: crate::display::ColourSpace::Srgb,
        exif,
        overwrite: Overwrite::Refuse,
        luminance_calibration: 1.0,
        preview_edge: None,
        ghost_map: false,
    }
}

/// The built-in stocks' `films` and the tone maps `tonemaps`, per layer, metered on the
/// log-average.
fn looks_of(films: &[&str], tonemaps: &[&str]) -> Vec<Look> {
    let catalogue = crate::film::Catalogue::builtin().unwrap();
    let owned = |names: &[&str]| names.iter().map(|n| n.to_string()).collect::<Vec<_>>();
    rendering::looks(
        &catalogue,
        &owned(films),
        &owned(tonemaps),
        0.0,
        crate::film::ColourMode::PerLayer,
        crate::film::Key::LogAverage,
    )
    .unwrap()
}

/// The response `policy` chooses for a noiseless 8-bit pair of scene `seed` through
/// `curve`, exposed 1 and 4.
fn choose_for_pair(curve: ResponseCurve, seed: u64, policy: ResponsePolicy) -> ChosenResponse {
    choose_for_pair_at(curve, seed, 4.0, policy)
}

/// As [`choose_for_pair`], exposed 1 and `ratio`.
fn choose_for_pair_at(
    curve: ResponseCurve,
    seed: u64,
    ratio: f64,
    policy: ResponsePolicy,
) -> ChosenResponse {
    let truth = scene(240, 160, seed);
    let sensor = Sensor::noiseless(curve, BitDepth::Eight);
    let frames = [
        loaded("a.png", expose(&truth, 1.0, &sensor)),
        loaded("b.png", expose(&truth, ratio, &sensor)),
    ];
    let bracket = bracket(&frames, &[1.0, ratio]);
    choose_response(&bracket, RatioSource::Argument, policy, &mut Stages::new()).unwrap()
}

/// 1/60, 1/60, 1/15: the middle pair is a duplicate; the fit must take the pair that
/// differs, not fail on a ratio of 1.
#[test]
fn duplicate_exposures_in_the_middle_do_not_stop_the_fit() {
    let truth = scene(240, 160, 3);
    let sensor = Sensor::noiseless(ResponseCurve::Srgb, BitDepth::Eight);
    let exposures = [1.0 / 60.0, 1.0 / 60.0, 1.0 / 15.0];
    let frames: Vec<LoadedFrame> = exposures
        .iter()
        .enumerate()
        .map(|(i, &e)| loaded(&format!("f{i}.png"), expose(&truth, e * 15.0, &sensor)))
        .collect();
    let bracket = bracket(&frames, &exposures);
    let policy = ResponsePolicy::Fit {
        fallback: None,
        min_confidence: 0.0,
        pool: None,
    };
    let chosen = choose_response(&bracket, RatioSource::Argument, policy, &mut Stages::new())
        .expect("the distinct pair is fitted");
    assert_eq!(chosen.source, Source::Fitted);
    assert!((chosen.report["ratio"].as_f64().unwrap() - 4.0).abs() < 1e-9);
    assert!(chosen.summary.contains("f2.png"), "{}", chosen.summary);
}

/// Three distinct exposures are calibrated jointly from all frames, and the
/// contradiction check weighs each tone pair at its own ratio: frames through a film
/// S curve still contradict sRGB.
#[test]
fn three_exposures_are_fitted_from_every_frame() {
    let truth = scene(240, 160, 5);
    let sensor = Sensor::noiseless(ResponseCurve::FilmS, BitDepth::Eight);
    let exposures = [0.25, 1.0, 4.0];
    let frames: Vec<LoadedFrame> = exposures
        .iter()
        .enumerate()
        .map(|(i, &e)| loaded(&format!("f{i}.png"), expose(&truth, e, &sensor)))
        .collect();
    let bracket = bracket(&frames, &exposures);
    let policy = ResponsePolicy::Fit {
        fallback: Some(GivenResponse::standard(3)),
        min_confidence: 1.01,
        pool: None,
    };
    let chosen =
        choose_response(&bracket, RatioSource::Argument, policy, &mut Stages::new()).unwrap();
    assert_eq!(chosen.source, Source::Fitted, "{:?}", chosen.notes);
    assert!(
        chosen.summary.contains("all 3 frames"),
        "{}",
        chosen.summary
    );
    assert_eq!(chosen.report["frames"].as_array().unwrap().len(), 3);
    assert!((chosen.report["ratio"].as_f64().unwrap() - 16.0).abs() < 1e-9);
    assert!(
        chosen.notes[0].contains("contradicts"),
        "{:?}",
        chosen.notes
    );
}

/// Frames more than four stops apart are fitted, with a note that the confidence does
/// not reach that far; a pair two stops apart has no such note.
#[test]
fn frames_further_apart_than_the_confidence_knows_are_noted() {
    let fit_only = || ResponsePolicy::Fit {
        fallback: None,
        min_confidence: 0.0,
        pool: None,
    };
    let wide = choose_for_pair_at(ResponseCurve::Srgb, 6, 32.0, fit_only());
    assert_eq!(wide.source, Source::Fitted);
    assert!(
        wide.notes
            .iter()
            .any(|n| n.starts_with("frames 5.0 stops apart in a.png and b.png")),
        "{:?}",
        wide.notes
    );
    let near = choose_for_pair(ResponseCurve::Srgb, 6, fit_only());
    assert!(
        near.notes.iter().all(|n| !n.contains("stops apart")),
        "{:?}",
        near.notes
    );
}

/// A weak fit below `min_confidence` gives way to the fallback, and says so; the fit
/// itself is still reported (the daemon decides whether the cache learns from it).
#[test]
fn a_fit_below_min_confidence_uses_the_fallback() {
    let policy = ResponsePolicy::Fit {
        fallback: Some(GivenResponse::standard(3)),
        min_confidence: 1.01,
        pool: None,
    };
    let chosen = choose_for_pair(ResponseCurve::Srgb, 4, policy);
    assert_eq!(chosen.source, Source::Standard);
    assert!(chosen.fit.is_some());
    assert!(chosen.notes[0].contains("confidence"), "{:?}", chosen.notes);
    assert_eq!(chosen.report["rejected_fit"]["source"], "fitted");
}

/// A weak fit is kept when the fallback contradicts the bracket: frames through a film
/// S curve are not explained by sRGB.
#[test]
fn a_fallback_the_bracket_contradicts_is_not_used() {
    let policy = ResponsePolicy::Fit {
        fallback: Some(GivenResponse::standard(3)),
        min_confidence: 1.01,
        pool: None,
    };
    let chosen = choose_for_pair(ResponseCurve::FilmS, 4, policy);
    assert_eq!(chosen.source, Source::Fitted, "{:?}", chosen.notes);
    assert!(
        chosen.notes[0].contains("contradicts"),
        "{:?}",
        chosen.notes
    );
}

/// A good fit that the camera's cached curve contradicts (frames through a film S curve,
/// a cache holding sRGB) is used and flagged, so the daemon leaves the cache alone; a
/// cached curve that agrees with the bracket is refined as before.
#[test]
fn a_good_fit_that_contradicts_the_cached_curve_is_flagged() {
    let develop = |curve: ResponseCurve| {
        let cached = GivenResponse {
            source: Source::Cached,
            label: "cached curve of Body (5 bracket(s))".to_string(),
            ..GivenResponse::standard(3)
        };
        let policy = ResponsePolicy::Fit {
            fallback: Some(cached),
            min_confidence: 0.0,
            pool: None,
        };
        choose_for_pair(curve, 6, policy)
    };
    let other = develop(ResponseCurve::FilmS);
    assert_eq!(other.source, Source::Fitted);
    assert!(other.contradicts_cache, "{:?}", other.notes);
    assert!(
        other
            .notes
            .iter()
            .any(|n| n.contains("contradicts the cached curve")),
        "{:?}",
        other.notes
    );
    let same = develop(ResponseCurve::Srgb);
    assert_eq!(same.source, Source::Fitted);
    assert!(!same.contradicts_cache, "{:?}", same.notes);
}

/// A good fit that agrees with the body's pooled curve is merged with it when the pool
/// is trusted (≥ 0.5) or at least as confident, else with its own fit; either way its
/// evidence comes back for the pool. One that contradicts the pool keeps its own fit, its
/// evidence a dissent.
#[test]
fn a_good_fit_that_agrees_with_the_bodys_pool_is_merged_with_it() {
    let first = choose_for_pair(
        ResponseCurve::Srgb,
        6,
        ResponsePolicy::Fit {
            fallback: None,
            min_confidence: 0.0,
            pool: None,
        },
    );
    assert_eq!(first.source, Source::Fitted);
    let own = first.pooling.expect("a good fit gives evidence");
    assert!(own.pooled.is_none(), "the darkroom never refits the pool");
    assert_eq!(own.own_confidence.len(), 3);
    let body = GivenResponse {
        source: Source::Cached,
        label: "cached curve of Body (pooled from 5 bracket(s))".to_string(),
        response: InverseResponse::srgb(3, 1024),
    };
    let policy = |confidence: f64| ResponsePolicy::Fit {
        fallback: Some(body.clone()),
        min_confidence: 0.0,
        pool: Some(BodyPool {
            brackets: 5,
            confidence,
        }),
    };
    let pooled = choose_for_pair(ResponseCurve::Srgb, 8, policy(1.0));
    assert_eq!(pooled.source, Source::Pooled, "{:?}", pooled.notes);
    assert_eq!(pooled.response, body.response);
    assert!(pooled.summary.contains("agrees"), "{}", pooled.summary);
    assert_eq!(pooled.report["brackets"], 5);
    assert!(pooled.pooling.is_some());
    // A trusted pool less sure than the bracket's own fit: still the pool.
    let trusted = choose_for_pair(ResponseCurve::Srgb, 8, policy(0.6));
    let own_confidence = trusted.fit.as_ref().map_or(0.0, |f| f.1);
    assert!(own_confidence > 0.6, "{own_confidence}");
    assert_eq!(trusted.source, Source::Pooled, "{:?}", trusted.notes);
    // A low pool less sure than the bracket's own fit: the own fit, still pooled.
    let own_better = choose_for_pair(ResponseCurve::Srgb, 8, policy(0.3));
    assert_eq!(own_better.source, Source::Fitted);
    assert!(own_better.pooling.is_some() && !own_better.contradicts_cache);
    let other = choose_for_pair(ResponseCurve::FilmS, 8, policy(1.0));
    assert_eq!(other.source, Source::Fitted);
    assert!(other.contradicts_cache, "{:?}", other.notes);
    assert!(other.pooling.is_some(), "a dissent's evidence");
}

#[test]
fn job_memory_grows_by_each_frames_decoded_and_aligned_size_and_mask() {
    let pair = job_memory_bytes(6000, 4000, 2, 3, 1, 2);
    let five = job_memory_bytes(6000, 4000, 5, 3, 1, 2);
    assert_eq!(
        five - pair,
        3 * (2 * 6000 * 4000 * 3 + 6000 * 4000),
        "three more 8-bit frames, their resampled copies and their deghosting masks"
    );
    let sixteen = job_memory_bytes(6000, 4000, 2, 3, 2, 2);
    assert_eq!(
        sixteen - pair,
        3 * 6000 * 4000 * 3,
        "16-bit frames (and the resampled one) hold twice the bytes; a mask does not"
    );
    // The EXR alone is merged while it is encoded: no map, no look, no JPEG bands.
    let no_looks = job_memory_bytes(6000, 4000, 2, 3, 1, 0);
    assert_eq!(
        pair - no_looks,
        (4 * 3 + 8) * 6000 * 4000 + 18 * 64 * 6000,
        "the map, one look's working set and the JPEG bands"
    );
    // The figures the documentation states: a 24 MP pair with two looks, five 24 MP
    // frames and seven 45 MP frames written only as EXR.
    assert_eq!(pair / 1_000_000, 870);
    assert_eq!(job_memory_bytes(6000, 4000, 5, 3, 1, 0) / 1_000_000, 888);
    assert_eq!(job_memory_bytes(8256, 5504, 7, 3, 1, 0) / 10_000_000, 231);
    assert_eq!(job_memory_bytes(8256, 5504, 7, 3, 1, 2) / 10_000_000, 323);
}

/// Three frames written only as EXR are merged inside the encoder (no map), on the
/// luminance scale of their EXIF, and the file holds the same samples as the map the
/// darkroom builds when it must (here for a confidence layer).
#[test]
fn an_exr_only_bracket_is_merged_in_bands_with_the_maps_values() {
    let truth = scene(90, 70, 11);
    let sensor = Sensor::noiseless(ResponseCurve::Srgb, BitDepth::Eight);
    let times = [1.0 / 400.0, 1.0 / 100.0, 1.0 / 25.0];
    let frames: Vec<LoadedFrame> = times
        .iter()
        .enumerate()
        .map(|(i, &t)| {
            let mut f = loaded(&format!("f{i}.png"), expose(&truth, t * 25.0, &sensor));
            f.metadata.exposure = Exposure {
                time_s: Some(t),
                f_number: Some(8.0),
                iso: Some(100.0),
            };
            f
        })
        .collect();
    let exposures: Vec<f64> = times.iter().map(|t| t * 100.0 / 64.0).collect();
    let dir = tempfile::tempdir().unwrap();
    let exif = SourceExif::default();
    let develop_with = |stem: &str, confidence: bool| {
        let prints = prints(dir.path(), stem, &[], Format::Jpeg { quality: 90 }, &exif);
        let options = MergeOptions {
            confidence,
            ..MergeOptions::default()
        };
        let policy = ResponsePolicy::Use(GivenResponse::standard(3));
        develop(
            &frames,
            &exposures,
            RatioSource::Exif,
            policy,
            options,
            &prints,
        )
        .unwrap()
    };
    let banded = develop_with("banded", false);
    let buffered = develop_with("buffered", true);
    assert!(banded.fused && !buffered.fused);
    assert!(matches!(banded.scale, merge::Scale::Luminance { .. }));
    assert_eq!(banded.clipped, buffered.clipped);
    assert_eq!(banded.order, vec![0, 1, 2]);
    let read = |stem: &str| hdr_output::read_exr(&dir.path().join(format!("{stem}.exr"))).unwrap();
    let (a, b) = (read("banded"), read("buffered"));
    let bits = |m: &RadianceMap| m.pixels().iter().map(|v| v.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&a), bits(&b));
    assert!(
        a.pixels().iter().any(|&v| v > 1.0),
        "luminance, not the relative scale"
    );
}

/// An 8-bit pair with looks is merged while the EXR is encoded and the looks developed
/// (no map), and every file it writes is the same, byte for byte, as the one developed
/// from the map the darkroom builds when it must (here for a confidence layer, whose EXR
/// then differs by that layer only). A look with optics reads the whole map.
#[test]
fn a_pair_with_looks_is_developed_from_the_merge_with_the_maps_files() {
    let truth = scene(130, 90, 5);
    let sensor = Sensor::noiseless(ResponseCurve::Srgb, BitDepth::Eight);
    let rgb = [
        loaded("a.png", expose(&truth, 1.0, &sensor)),
        loaded("b.png", expose(&truth, 4.0, &sensor)),
    ];
    // The same frames' green channel as grey frames.
    let grey = rgb.each_ref().map(|f| {
        let Samples::Eight(codes) = f.frame.samples() else {
            unreachable!("8-bit frames")
        };
        let green = codes.iter().skip(1).step_by(3).copied().collect();
        let frame = Frame::new(f.frame.width(), f.frame.height(), 1, Samples::Eight(green));
        loaded("grey.png", frame.unwrap())
    });
    let exposures = [1.0, 4.0];
    let looks = looks_of(
        &["velvia50", "provia100f+grain", "portra400"],
        &["linear", "histogram"],
    );
    let exif = SourceExif::default();
    let dir = tempfile::tempdir().unwrap();
    let develop_with = |frames: &[LoadedFrame], stem: &str, looks: &[Look], format, confidence| {
        let prints = prints(dir.path(), stem, looks, format, &exif);
        let options = MergeOptions {
            confidence,
            ..MergeOptions::default()
        };
        // Fitted, so that each channel has a curve of its own.
        let policy = ResponsePolicy::Fit {
            fallback: None,
            min_confidence: 0.0,
            pool: None,
        };
        develop(
            frames,
            &exposures,
            RatioSource::Argument,
            policy,
            options,
            &prints,
        )
        .unwrap()
    };
    let bytes = |name: String| std::fs::read(dir.path().join(name)).unwrap();
    let formats = [Format::Jpeg { quality: 92 }, Format::Tiff16];
    for ((kind, frames), format) in [("rgb", &rgb), ("grey", &grey)]
        .into_iter()
        .flat_map(|frames| formats.map(|format| (frames, format)))
    {
        let (lazy, map) = (
            format!("lazy-{kind}-{format:?}"),
            format!("map-{kind}-{format:?}"),
        );
        let fused = develop_with(frames, &lazy, &looks, format, false);
        let buffered = develop_with(frames, &map, &looks, format, true);
        assert!(fused.fused && !buffered.fused);
        assert_eq!(fused.outputs.len(), 1 + looks.len());
        for look in &looks {
            let name = |stem: &str| format!("{stem}.{}.{}", look.name(), format.extension());
            assert!(
                bytes(name(&lazy)) == bytes(name(&map)),
                "{} differs between the lazy merge and the map ({kind}, {format:?})",
                look.name()
            );
        }
        let read = |stem: &str| hdr_output::read_exr(&dir.path().join(format!("{stem}.exr")));
        if kind == "rgb" {
            assert_eq!(read(&lazy).unwrap(), read(&map).unwrap());
        }
    }
    let halation = looks_of(&["velvia50+halation"], &[]);
    let optics = develop_with(
        &rgb,
        "optics",
        &halation,
        Format::Jpeg { quality: 92 },
        false,
    );
    assert!(!optics.fused);
}

/// An encoder's refusal names the file but is not a failure to write: the daemon records
/// the bracket as failed rather than retrying it, while a failed publish is retried.
#[test]
fn an_encoder_refusal_is_not_retried_as_a_failed_write() {
    let path = PathBuf::from("/out/b.exr");
    let refused = DarkroomError::Output(OutputError::Encode {
        path: path.clone(),
        source: EncodeError::Exr(exr::error::Error::Invalid("header refused".into())),
    });
    assert_eq!(refused.output_path(), None);
    assert!(refused.to_string().contains("/out/b.exr"), "{refused}");
    let full = DarkroomError::Publish(PublishError::Io {
        path: path.clone(),
        source: std::io::Error::from_raw_os_error(28),
    });
    assert_eq!(full.output_path(), Some(path.as_path()));
}

/// Frames of one pixel, one row or one column develop with looks from the lazy pair as
/// from the map (bands shorter than a band, a single sample for the scene key).
#[test]
fn tiny_pairs_develop_their_looks_from_the_merge_as_from_the_map() {
    let looks = looks_of(&["velvia50"], &["linear", "histogram"]);
    let exif = SourceExif::default();
    let dir = tempfile::tempdir().unwrap();
    let sensor = Sensor::noiseless(ResponseCurve::Srgb, BitDepth::Eight);
    for (w, h) in [(1, 1), (5, 1), (1, 7)] {
        let truth = scene(w, h, 3);
        let frames = [
            loaded("a.png", expose(&truth, 1.0, &sensor)),
            loaded("b.png", expose(&truth, 4.0, &sensor)),
        ];
        let develop_with = |stem: &str, confidence: bool| {
            let prints = prints(
                dir.path(),
                stem,
                &looks,
                Format::Jpeg { quality: 92 },
                &exif,
            );
            let options = MergeOptions {
                confidence,
                ..MergeOptions::default()
            };
            let policy = ResponsePolicy::Use(GivenResponse::standard(3));
            develop(
                &frames,
                &[1.0, 4.0],
                RatioSource::Argument,
                policy,
                options,
                &prints,
            )
            .unwrap()
        };
        let (lazy, map) = (format!("lazy{w}x{h}"), format!("map{w}x{h}"));
        assert!(develop_with(&lazy, false).fused);
        assert!(!develop_with(&map, true).fused);
        for look in &looks {
            let read = |stem: &str| {
                std::fs::read(dir.path().join(format!("{stem}.{}.jpg", look.name()))).unwrap()
            };
            assert!(read(&lazy) == read(&map), "{} at {w}×{h}", look.name());
        }
    }
}
