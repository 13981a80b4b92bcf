//! `filmback merge FRAME... -o DIR [--film STOCK[@t]]... [--tonemap OP]...`: a bracket to
//! one OpenEXR radiance map and its renderings, through [`filmback::darkroom`].
//!
//! Stages, each timed for `--json`: decode (frames in parallel), histogram and fit (when
//! the response is calibrated from this bracket), merge, encode and write (the EXR),
//! render (the renderings).

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use filmback::align::AlignMode;
use filmback::atomic::Overwrite;
use filmback::darkroom::{self, GivenResponse, Prints, ResponsePolicy, Source};
use filmback::frame::{self, Limits, LoadedFrame, Samples};
use filmback::hdr_output::{ExrCompression, ExrOptions, Overflow, Primaries, SampleFormat};
use filmback::merge::{Deghost, MergeOptions, Weighting};
use filmback::metadata::Exposure;
use filmback::rendering::SourceExif;
use filmback::response::{self, RatioSource};
use rayon::prelude::*;
use serde_json::json;

use super::looks::LookArgs;

/// Arguments of `filmback merge`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The bracket's frames (JPEG, PNG, TIFF or camera raw), in any order; at least two.
    #[arg(required = true, num_args = 2..)]
    frames: Vec<PathBuf>,
    /// Output folder (created if missing); the file is DIR/<stem of the first frame>.exr,
    /// each rendering DIR/<stem>.<look>.<jpg, png or tif as --format says>.
    #[arg(short, long, value_name = "DIR")]
    output: PathBuf,
    #[command(flatten)]
    looks: LookArgs,
    /// Use this response file (written by `filmback calibrate -o`) instead of calibrating.
    #[arg(long, value_name = "FILE", conflicts_with = "srgb")]
    response: Option<PathBuf>,
    /// Use the sRGB inverse as the response instead of calibrating.
    #[arg(long)]
    srgb: bool,
    /// Exposure ratio between successive frames when EXIF lacks exposures: frames are
    /// ordered by EXIF exposure when all have one, else by mean brightness, and the k-th
    /// darkest gets exposure R^k.
    #[arg(long, value_name = "R", conflicts_with = "times")]
    ratio: Option<f64>,
    /// Exposure times in seconds, one per frame in command-line order (for frames
    /// without EXIF); fractions like 1/60 are accepted.
    #[arg(long, value_name = "T,T,...", value_delimiter = ',')]
    times: Vec<String>,
    /// Sample type of the OpenEXR file.
    #[arg(long, value_enum, default_value_t = SampleFormat::Half)]
    exr: SampleFormat,
    /// OpenEXR compression (b44 is lossy; pxr24 is lossy for float).
    #[arg(long, value_enum, default_value_t = ExrCompression::Piz)]
    compression: ExrCompression,
    /// Values above half's 65504: scale the image by a power of two, or clamp.
    #[arg(long, value_enum, default_value_t = Overflow::Scale)]
    overflow: Overflow,
    /// RGB primaries of the OpenEXR file (the renderings stay Rec. 709 / sRGB): rec709,
    /// ap0 (ACES2065-1) or ap1 (ACEScg).
    #[arg(long, value_enum, default_value_t = Primaries::Rec709)]
    primaries: Primaries,
    /// Calibration factor of the luminance scale: values are this times the nominal
    /// cd/m² from the EXIF exposure (grey card: its metered cd/m² over the value read).
    #[arg(long, value_name = "FACTOR", default_value_t = 1.0, value_parser = positive)]
    luminance_calibration: f64,
    /// Merge weight: hat (robust default) or noise-aware (lower noise, needs a good response).
    #[arg(long, value_enum, default_value_t = Weighting::Hat)]
    weight: Weighting,
    /// Leave a frame out where it disagrees with the reference frame beyond its noise (a
    /// moving subject): on, or off to blend every frame (moving subjects translucent).
    #[arg(long, value_enum, default_value_t = Deghost::On)]
    deghost: Deghost,
    /// Align the frames onto the best-exposed one before merging: auto (the most general
    /// model the texture determines; falls back, and says so, when it cannot), off, or
    /// at most translation, rigid (rotation too) or homography (perspective too).
    #[arg(long, value_enum, default_value_t = AlignMode::Auto)]
    align: AlignMode,
    /// Add the per-pixel confidence (weight sum) as channel `confidence.Y`.
    #[arg(long)]
    confidence: bool,
    /// Also write a Radiance RGBE file DIR/<stem>.hdr.
    #[arg(long)]
    radiance_hdr: bool,
    /// Also write the merged mosaic as a linear DNG DIR/<stem>.dng for raw converters
    /// (Lightroom, Camera Raw): 32-bit float CFA with the camera's colour matrices and
    /// as-shot neutral. Camera raw brackets only.
    #[arg(long)]
    dng: bool,
    /// Also write DIR/<stem>.ghosts.png, where deghosting left frames out: 8-bit grey, per
    /// pixel the least weight the merge kept of any frame (white where every frame was
    /// merged, black where some frame was left out).
    #[arg(long)]
    ghost_map: bool,
    /// Replace existing output files (EXR, HDR, DNG, renderings and the ghost map).
    #[arg(long)]
    force: bool,
    /// Print a JSON report (outputs, response, frames, timings in ms).
    #[arg(long)]
    json: bool,
}

/// A positive finite number (the luminance calibration).
fn positive(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        _ => Err(format!("{s:?} is not a positive number")),
    }
}

/// Runs the command.
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let start = Instant::now();
    let (looks, format) = args.looks.looks()?;
    let stem = args.frames[0]
        .file_stem()
        .and_then(|s| s.to_str())
        .with_context(|| format!("{}: no usable file name", args.frames[0].display()))?;
    // A long frame name is shortened so its outputs' names fit the file system.
    let stem = filmback::atomic::fitting_stem(stem).into_owned();
    let exif = SourceExif::from_frame_bytes(
        &std::fs::read(&args.frames[0])
            .with_context(|| format!("{}: cannot read", args.frames[0].display()))?,
    );
    let prints = Prints {
        dir: &args.output,
        stem: &stem,
        exr: Some(ExrOptions {
            sample: args.exr,
            compression: args.compression,
            overflow: args.overflow,
            primaries: args.primaries,
        }),
        luminance_calibration: args.luminance_calibration,
        preview_edge: None,
        ghost_map: args.ghost_map,
        radiance_hdr: args.radiance_hdr,
        dng: args.dng,
        looks: &looks,
        format,
        space: args.looks.colour_space()?,
        exif: &exif,
        overwrite: if args.force {
            Overwrite::Replace
        } else {
            Overwrite::Refuse
        },
    };
    let planned = prints.paths();
    if !args.force
        && let Some(existing) = planned.iter().find(|p| p.exists())
    {
        bail!(
            "{}: already exists (use --force to replace it)",
            existing.display()
        );
    }
    std::fs::create_dir_all(&args.output)
        .with_context(|| format!("{}: cannot create output folder", args.output.display()))?;

    let t = Instant::now();
    let mut frames: Vec<LoadedFrame> = args
        .frames
        .par_iter()
        .map(|p| frame::load(p, Limits::default()))
        .collect::<Result<_, _>>()?;
    let decode = t.elapsed();
    let (exposures, ratio_source) = exposures(&args, &frames)?;
    for (f, t) in frames.iter_mut().zip(&args.times) {
        f.metadata.exposure.time_s = Some(parse_time(t)?);
    }
    let policy = response_policy(&args, frames[0].frame.channels())?;
    let options = MergeOptions {
        weighting: args.weight,
        confidence: args.confidence,
        deghost: args.deghost,
        align: args.align,
    };
    let mut developed =
        darkroom::develop(&frames, &exposures, ratio_source, policy, options, &prints)?;
    developed.stages.insert(0, ("decode", decode));
    let total = start.elapsed();

    if args.json {
        print_report(&developed, &frames, &exposures, options.weighting, total)?;
    } else {
        print_summary(&developed, &frames, total);
    }
    Ok(ExitCode::SUCCESS)
}

/// Prints the `--json` report of `developed` from `frames` of relative `exposures`,
/// merged with `weighting`, in `total`.
fn print_report(
    developed: &darkroom::Developed,
    frames: &[LoadedFrame],
    exposures: &[f64],
    weighting: Weighting,
    total: Duration,
) -> anyhow::Result<()> {
    let mut timings = serde_json::Map::new();
    for (stage, d) in &developed.stages {
        timings.insert((*stage).to_string(), json!(ms(*d)));
    }
    timings.insert("total".into(), json!(ms(total)));
    let report = json!({
        "outputs": developed.outputs.iter().map(|p| p.display().to_string()).collect::<Vec<_>>(),
        "response": developed.response.report,
        "frames": developed.order.iter().map(|&i| json!({
            "path": frames[i].path.display().to_string(),
            "exposure": exposures[i],
        })).collect::<Vec<_>>(),
        "ratio": developed.ratio,
        "weighting": if developed.response.source == Source::Raw {
            json!("noise-optimal (linear sensor)")
        } else {
            json!(weighting)
        },
        "merge_mode": if developed.fused {
            "fused into encode (merge ms is the tables and the clipped count; the merge itself is inside encode ms)"
        } else {
            "buffered"
        },
        "clipped": { "high": developed.clipped.0, "low": developed.clipped.1 },
        "deghost": developed.deghost,
        "alignment": alignment_report(developed, frames),
        "radiance_scale": developed.exr_scale,
        "scale": { "kind": developed.scale.kind(), "convention": developed.scale.describe() },
        "warnings": developed.warnings,
        "timings_ms": timings,
    });
    println!("{}", serde_json::to_string_pretty(&report)?);
    Ok(())
}

/// Prints the warnings of `developed` (to stderr), its outputs, and a summary of the
/// deghosting, the ratio, the response and the `total` time.
fn print_summary(developed: &darkroom::Developed, frames: &[LoadedFrame], total: Duration) {
    for w in &developed.warnings {
        eprintln!("warning: {w}");
    }
    for p in &developed.outputs {
        println!("{}", p.display());
    }
    if let Some(d) = developed.deghost.as_ref().filter(|d| d.share > 0.0) {
        println!(
            "  deghosted: {:.1} % of pixels merged without some frame (reference {})",
            100.0 * d.share,
            frames[d.reference].path.display()
        );
    }
    println!(
        "  ratio {:.3} ({:.2} stops), response: {}, {:.0} ms",
        developed.ratio,
        developed.ratio.log2(),
        developed.response.summary,
        ms(total)
    );
}

/// What alignment did, for `--json`: the mode, the reference frame's path, and per frame
/// (command-line order) its model, shift at the centre (px), rotation (degrees), largest
/// displacement (px), 3 × 3 matrix (reference pixel → frame pixel) and any fallback.
fn alignment_report(developed: &darkroom::Developed, frames: &[LoadedFrame]) -> serde_json::Value {
    let Some(alignment) = &developed.alignment else {
        return serde_json::Value::Null;
    };
    let (w, h) = (frames[0].frame.width(), frames[0].frame.height());
    json!({
        "mode": alignment.mode,
        "reference": frames[alignment.reference].path.display().to_string(),
        "frames": alignment.frames.iter().zip(frames).map(|(a, f)| {
            let ((dx, dy), angle) = a.shift_and_rotation(w, h);
            json!({
                "path": f.path.display().to_string(),
                "motion": a.motion,
                "shift_px": [dx, dy],
                "rotation_deg": angle,
                "displacement_px": a.displacement_px,
                "matrix": a.transform,
                "note": a.note,
            })
        }).collect::<Vec<_>>(),
    })
}

/// Milliseconds to 0.1 ms.
fn ms(d: Duration) -> f64 {
    (d.as_secs_f64() * 1e4).round() / 10.0
}

pub(crate) fn parse_time(text: &str) -> anyhow::Result<f64> {
    let text = text.trim();
    let value = match text.split_once('/') {
        Some((n, d)) => n.trim().parse::<f64>()? / d.trim().parse::<f64>()?,
        None => text.parse::<f64>()?,
    };
    if !(value.is_finite() && value > 0.0) {
        bail!("exposure time {text:?} is not a positive number of seconds");
    }
    Ok(value)
}

/// Relative exposure of every frame (command-line order) and where it came from.
///
/// * `--times`: `e = t·S/N²` with S and N from EXIF when every frame has both, else
///   `e = t` (all frames then assumed at one aperture and ISO).
/// * `--ratio R`: the k-th darkest frame (by EXIF exposure if all have one, else by mean
///   brightness) gets `R^k`.
/// * otherwise EXIF: `e = t·S/N²`; when every frame lacks ISO (some cameras omit it) or
///   every frame lacks the f-number, that factor is assumed common and left out.
fn exposures(args: &Args, frames: &[LoadedFrame]) -> anyhow::Result<(Vec<f64>, RatioSource)> {
    let exif: Vec<Exposure> = frames.iter().map(|f| f.metadata.exposure).collect();
    let all_iso = exif.iter().all(|e| e.iso.is_some());
    let all_aperture = exif.iter().all(|e| e.f_number.is_some());
    let factor = |e: &Exposure| {
        let s = if all_iso { e.iso.unwrap_or(1.0) } else { 1.0 };
        let n = if all_aperture {
            e.f_number.unwrap_or(1.0)
        } else {
            1.0
        };
        s / (n * n)
    };
    if !args.times.is_empty() {
        if args.times.len() != frames.len() {
            bail!(
                "--times gives {} exposure times for {} frames",
                args.times.len(),
                frames.len()
            );
        }
        let mut out = Vec::new();
        for (t, f) in args.times.iter().zip(frames) {
            let t =
                parse_time(t).with_context(|| format!("--times value for {}", f.path.display()))?;
            out.push(t * factor(&f.metadata.exposure));
        }
        return Ok((out, RatioSource::Argument));
    }
    if let Some(r) = args.ratio {
        if !(r.is_finite() && r > 1.0) {
            bail!("--ratio {r}: must be a number above 1");
        }
        let key: Vec<f64> = if exif.iter().all(|e| e.time_s.is_some()) {
            exif.iter()
                .map(|e| e.time_s.unwrap_or(0.0) * factor(e))
                .collect()
        } else {
            frames
                .iter()
                .map(|f| mean_code(f.frame.samples()))
                .collect()
        };
        let mut order: Vec<usize> = (0..frames.len()).collect();
        order.sort_by(|&a, &b| key[a].total_cmp(&key[b]));
        let mut out = vec![0.0; frames.len()];
        for (rank, &i) in order.iter().enumerate() {
            out[i] = r.powi(rank as i32);
        }
        return Ok((out, RatioSource::Argument));
    }
    let mut out = Vec::new();
    for f in frames {
        let e = &f.metadata.exposure;
        let Some(t) = e.time_s else {
            bail!(
                "{}: exposure time unknown (no EXIF ExposureTime): give --times or --ratio",
                f.path.display()
            );
        };
        out.push(t * factor(e));
    }
    Ok((out, RatioSource::Exif))
}

fn mean_code(samples: &Samples) -> f64 {
    let (sum, n) = match samples {
        Samples::Eight(v) => (v.par_iter().map(|&c| u64::from(c)).sum::<u64>(), v.len()),
        Samples::Sixteen(v) => (v.par_iter().map(|&c| u64::from(c)).sum::<u64>(), v.len()),
    };
    sum as f64 / n.max(1) as f64
}

/// Which response the merge uses: `--response FILE`; `--srgb`; otherwise calibrated from
/// this bracket (see [`darkroom::choose_response`]), an error if that fails.
fn response_policy(args: &Args, channels: usize) -> anyhow::Result<ResponsePolicy> {
    if let Some(path) = &args.response {
        let record = response::load(path)?;
        if record.response.channels() != channels {
            bail!(
                "{}: response has {} channel(s) but the frames have {channels}",
                path.display(),
                record.response.channels()
            );
        }
        let model = record
            .channels
            .first()
            .map_or_else(String::new, |c| c.model.clone());
        return Ok(ResponsePolicy::Use(GivenResponse {
            response: record.response,
            source: Source::File,
            label: format!("loaded from {} ({model})", path.display()),
        }));
    }
    if args.srgb {
        return Ok(ResponsePolicy::Use(GivenResponse::standard(channels)));
    }
    Ok(ResponsePolicy::Fit {
        fallback: None,
        min_confidence: 0.0,
        pool: None,
    })
}
