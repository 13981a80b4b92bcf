//! `filmback merge FRAME... -o DIR`: a bracket to one OpenEXR radiance map.
//!
//! Stages, each timed for `--json`: decode (frames in parallel), histogram and fit (when
//! the response is calibrated from this bracket), merge, encode, write (atomic publish).

use std::io::Cursor;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{Context, bail};
use clap::ValueEnum;
use filmback::atomic::{self, Overwrite};
use filmback::frame::{self, Limits, LoadedFrame, Samples};
use filmback::hdr_output::RadianceSource;
use filmback::hdr_output::{
    self, Compression, ExrOptions, FrameRecord, Overflow, Provenance, SampleFormat,
};
use filmback::histogram::Histogram;
use filmback::merge::{self, BracketFrame, MergeOptions, Merged, PairMerge, Weighting};
use filmback::metadata::Exposure;
use filmback::response::{self, Degree, InverseResponse, Ratio, RatioSource};
use rayon::prelude::*;
use serde_json::json;

/// Arguments of `filmback merge`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The bracket's frames (JPEG, PNG, TIFF), in any order; at least two.
    #[arg(required = true, num_args = 2..)]
    frames: Vec<PathBuf>,
    /// Output folder (created if missing); the file is DIR/<stem of the first frame>.exr.
    #[arg(short, long, value_name = "DIR")]
    output: PathBuf,
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
    #[arg(long, value_enum, default_value_t = ExrSample::Half)]
    exr: ExrSample,
    /// OpenEXR compression (b44 is lossy; pxr24 is lossy for float).
    #[arg(long, value_enum, default_value_t = ExrCompression::Piz)]
    compression: ExrCompression,
    /// Values above half's 65504: scale the image by a power of two, or clamp.
    #[arg(long, value_enum, default_value_t = HalfOverflow::Scale)]
    overflow: HalfOverflow,
    /// Merge weight: hat (robust default) or noise-aware (lower noise, needs a good response).
    #[arg(long, value_enum, default_value_t = Weight::Hat)]
    weight: Weight,
    /// Add the per-pixel confidence (weight sum) as channel `confidence.Y`.
    #[arg(long)]
    confidence: bool,
    /// Also write a Radiance RGBE file DIR/<stem>.hdr.
    #[arg(long)]
    radiance_hdr: bool,
    /// Replace existing output files.
    #[arg(long)]
    force: bool,
    /// Print a JSON report (outputs, response, frames, timings in ms).
    #[arg(long)]
    json: bool,
}

#[derive(Debug, Clone, Copy, ValueEnum)]
enum ExrSample {
    Half,
    Float,
}

#[derive(Debug, Clone, Copy, ValueEnum)]
enum ExrCompression {
    Piz,
    Zip,
    Rle,
    None,
    Pxr24,
    B44,
}

#[derive(Debug, Clone, Copy, ValueEnum)]
enum HalfOverflow {
    Scale,
    Clamp,
}

#[derive(Debug, Clone, Copy, ValueEnum)]
enum Weight {
    Hat,
    NoiseAware,
}

/// Milliseconds per stage; `None` for a stage that did not run.
#[derive(Debug, Default, serde::Serialize)]
struct Timings {
    decode: Option<f64>,
    histogram: Option<f64>,
    fit: Option<f64>,
    merge: Option<f64>,
    encode: Option<f64>,
    write: Option<f64>,
    total: f64,
}

fn ms(since: Instant) -> f64 {
    (since.elapsed().as_secs_f64() * 1e4).round() / 10.0
}

/// The merged bracket: evaluated during encoding, or held as a map.
enum Radiance<'a> {
    Fused(PairMerge<'a>),
    Buffered(Merged),
}

impl Radiance<'_> {
    /// Input order (darkest first), exposure ratio, samples clipped (high, low).
    fn summary(&self) -> (Vec<usize>, f64, (u64, u64)) {
        match self {
            Radiance::Fused(p) => (p.order.clone(), p.ratio(), (p.clipped_high, p.clipped_low)),
            Radiance::Buffered(m) => (m.order.clone(), m.ratio(), (m.clipped_high, m.clipped_low)),
        }
    }
}

/// The response used and where it came from.
struct Chosen {
    response: InverseResponse,
    report: serde_json::Value,
    summary: String,
}

/// Runs the command.
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let start = Instant::now();
    let mut timings = Timings::default();
    let overwrite = if args.force {
        Overwrite::Replace
    } else {
        Overwrite::Refuse
    };
    let stem = args.frames[0]
        .file_stem()
        .with_context(|| format!("{}: no file name", args.frames[0].display()))?;
    let exr_path = args.output.join(stem).with_extension("exr");
    let hdr_path = args.output.join(stem).with_extension("hdr");
    let mut outputs = vec![exr_path.clone()];
    if args.radiance_hdr {
        outputs.push(hdr_path.clone());
    }
    if !args.force
        && let Some(existing) = outputs.iter().find(|p| p.exists())
    {
        bail!(
            "{}: already exists (use --force to replace it)",
            existing.display()
        );
    }
    std::fs::create_dir_all(&args.output)
        .with_context(|| format!("{}: cannot create output folder", args.output.display()))?;

    let t = Instant::now();
    let frames: Vec<LoadedFrame> = args
        .frames
        .par_iter()
        .map(|p| frame::load(p, Limits::default()))
        .collect::<Result<_, _>>()?;
    timings.decode = Some(ms(t));

    let (exposures, exposure_source) = exposures(&args, &frames)?;
    let bracket: Vec<BracketFrame<'_>> = frames
        .iter()
        .zip(&exposures)
        .map(|(f, &exposure)| BracketFrame {
            source: &f.path,
            frame: &f.frame,
            exposure,
            camera: &f.metadata.camera,
        })
        .collect();
    let chosen = choose_response(&args, &bracket, exposure_source, &mut timings)?;

    let t = Instant::now();
    let options = MergeOptions {
        weighting: match args.weight {
            Weight::Hat => Weighting::Hat,
            Weight::NoiseAware => Weighting::NoiseAware,
        },
        confidence: args.confidence,
    };
    // An 8-bit pair (the usual tethered bracket) is merged while the EXR is encoded, one
    // table lookup per sample, with no radiance buffer; anything else is merged first.
    let fused = if options.confidence {
        None
    } else {
        PairMerge::new(&bracket, &chosen.response, options.weighting)?
    };
    let merged = match fused {
        Some(pair) => Radiance::Fused(pair),
        None => Radiance::Buffered(merge::merge(&bracket, &chosen.response, options)?),
    };
    timings.merge = Some(ms(t));
    let (order, ratio, clipped) = merged.summary();

    let provenance = Provenance {
        camera: frames[0].metadata.camera.clone(),
        captured_at: frames[order[0]].metadata.captured_at,
        frames: order
            .iter()
            .map(|&i| FrameRecord {
                name: file_name(&frames[i].path),
                exposure: times_or_exif(&args, &frames, i),
                relative: exposures[i],
            })
            .collect(),
        response: chosen.summary.clone(),
        weighting: format!("{:?}", options.weighting),
        clipped,
    };
    let mut warnings: Vec<String> = frames
        .iter()
        .flat_map(|f| {
            f.metadata
                .warnings
                .iter()
                .map(move |w| format!("{}: {w}", f.path.display()))
        })
        .collect();
    let frame_report: Vec<_> = order
        .iter()
        .map(|&i| json!({ "path": frames[i].path.display().to_string(), "exposure": exposures[i] }))
        .collect();
    let t = Instant::now();
    let exr_options = ExrOptions {
        sample: match args.exr {
            ExrSample::Half => SampleFormat::Half,
            ExrSample::Float => SampleFormat::Float,
        },
        compression: match args.compression {
            ExrCompression::Piz => Compression::Piz,
            ExrCompression::Zip => Compression::Zip,
            ExrCompression::Rle => Compression::Rle,
            ExrCompression::None => Compression::None,
            ExrCompression::Pxr24 => Compression::Pxr24,
            ExrCompression::B44 => Compression::B44,
        },
        overflow: match args.overflow {
            HalfOverflow::Scale => Overflow::Scale,
            HalfOverflow::Clamp => Overflow::Clamp,
        },
    };
    let mut exr = Cursor::new(Vec::new());
    let (source, confidence): (&dyn RadianceSource, Option<&[f32]>) = match &merged {
        Radiance::Fused(pair) => (pair, None),
        Radiance::Buffered(m) => (&m.radiance, m.confidence.as_deref()),
    };
    let written = hdr_output::encode_exr(&mut exr, source, confidence, &provenance, exr_options)?;
    let mut hdr = Vec::new();
    if args.radiance_hdr {
        hdr_output::encode_radiance_hdr(&mut hdr, source)?;
    }
    timings.encode = Some(ms(t));
    warnings.extend(written.warnings.iter().cloned());

    let t = Instant::now();
    atomic::publish(&exr_path, exr.get_ref(), overwrite)?;
    if args.radiance_hdr {
        atomic::publish(&hdr_path, &hdr, overwrite)?;
    }
    timings.write = Some(ms(t));
    timings.total = ms(start);

    if args.json {
        let report = json!({
            "outputs": outputs.iter().map(|p| p.display().to_string()).collect::<Vec<_>>(),
            "response": chosen.report,
            "frames": frame_report,
            "ratio": ratio,
            "weighting": options.weighting,
            "merge_mode": match merged {
                Radiance::Fused(_) => "fused into encode (8-bit pair: merge ms is the table build, the lookups are inside encode ms)",
                Radiance::Buffered(_) => "buffered",
            },
            "clipped": { "high": clipped.0, "low": clipped.1 },
            "radiance_scale": written.scale,
            "warnings": warnings,
            "timings_ms": timings,
        });
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        for w in &warnings {
            eprintln!("warning: {w}");
        }
        for p in &outputs {
            println!("{}", p.display());
        }
        println!(
            "  ratio {:.3} ({:.2} stops), response: {}, {} ms",
            ratio,
            ratio.log2(),
            chosen.summary,
            timings.total
        );
    }
    Ok(ExitCode::SUCCESS)
}

fn file_name(path: &Path) -> String {
    path.file_name().map_or_else(
        || path.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    )
}

/// The exposure settings recorded for frame `i`: EXIF, with `--times` replacing the time.
fn times_or_exif(args: &Args, frames: &[LoadedFrame], i: usize) -> Exposure {
    let mut e = frames[i].metadata.exposure;
    if let Some(t) = args.times.get(i).and_then(|t| parse_time(t).ok()) {
        e.time_s = Some(t);
    }
    e
}

fn parse_time(text: &str) -> anyhow::Result<f64> {
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
/// this bracket (the two adjacent frames in the middle of the exposure order, whose
/// histograms share the most tones), with the ratio from the exposures.
fn choose_response(
    args: &Args,
    bracket: &[BracketFrame<'_>],
    ratio_source: RatioSource,
    timings: &mut Timings,
) -> anyhow::Result<Chosen> {
    let channels = bracket[0].frame.channels();
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
        return Ok(Chosen {
            summary: format!("loaded from {} ({model})", path.display()),
            report: json!({ "source": "file", "path": path.display().to_string(), "model": model, "ratio": record.ratio }),
            response: record.response,
        });
    }
    if args.srgb {
        return Ok(Chosen {
            response: InverseResponse::srgb(channels, 1024),
            summary: "sRGB inverse (IEC 61966-2-1), default".to_string(),
            report: json!({ "source": "default", "model": "sRGB inverse (IEC 61966-2-1)" }),
        });
    }
    let mut order: Vec<usize> = (0..bracket.len()).collect();
    order.sort_by(|&a, &b| bracket[a].exposure.total_cmp(&bracket[b].exposure));
    let mid = order.len() / 2;
    let (dark, bright) = (&bracket[order[mid - 1]], &bracket[order[mid]]);
    let t = Instant::now();
    // About three million pixels are plenty for a 256- or 4096-bin histogram.
    let stride = ((dark.frame.pixel_count() as f64 / 3e6).sqrt().floor() as usize).max(1);
    let (h_dark, h_bright) = rayon::join(
        || Histogram::of_frame(dark.frame, stride),
        || Histogram::of_frame(bright.frame, stride),
    );
    timings.histogram = Some(ms(t));
    let t = Instant::now();
    let ratio = bright.exposure / dark.exposure;
    let calibration = response::calibrate(
        &h_dark,
        &h_bright,
        Ratio::Known(ratio, ratio_source),
        Degree::Auto,
    )
    .with_context(|| {
        format!(
            "cannot calibrate the response from {} and {} (use --response FILE or --srgb)",
            dark.source.display(),
            bright.source.display()
        )
    })?;
    timings.fit = Some(ms(t));
    let degrees: Vec<String> = calibration
        .channels
        .iter()
        .map(|c| format!("{} degree {}", c.name, c.fit.degree))
        .collect();
    let summary = format!(
        "calibrated from {} and {} (ratio {ratio:.4}, {}): {}, {}",
        file_name(dark.source),
        file_name(bright.source),
        ratio_source.as_str(),
        response::MODEL_NAME,
        degrees.join(", ")
    );
    let report = json!({
        "source": "fitted",
        "model": response::MODEL_NAME,
        "frames": [dark.source.display().to_string(), bright.source.display().to_string()],
        "ratio": ratio,
        "ratio_source": ratio_source.as_str(),
        "channels": calibration.channels.iter().map(|c| json!({
            "name": c.name,
            "degree": c.fit.degree,
            "covered": [c.fit.covered.0, c.fit.covered.1],
            "residual_rms_stops": c.fit.residual_rms,
            "confidence": c.fit.confidence,
            "borrowed_from": c.borrowed_from,
        })).collect::<Vec<_>>(),
    });
    Ok(Chosen {
        response: calibration.response,
        summary,
        report,
    })
}
