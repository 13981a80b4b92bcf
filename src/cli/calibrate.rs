//! `filmback calibrate FRAME FRAME [FRAME…] [--ratio R | --times T,T,…] [--degree
//! auto|N] [--stride N] [--json] [--plot FILE.png] [-o response.toml]`: the camera's
//! inverse response from two exposures, or from every frame of a bracket jointly (the
//! curve `merge` and the daemon fit for a bracket of more than two exposures).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, bail};
use filmback::atomic::Overwrite;
use filmback::frame::{self, Limits, LoadedFrame};
use filmback::histogram::{FrameCounts, Histogram, shared_counts};
use filmback::response::{self, Calibration, Degree, PRIOR_MID_GREY, Ratio, RatioSource};
use serde_json::{Value, json};

pub(crate) mod plot;

use super::merge::parse_time;

/// Arguments of `filmback calibrate`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Two or more exposures of the same scene, in any order (sorted by exposure). More
    /// than two are fitted jointly: every two frames adjacent in exposure give equations.
    #[arg(required = true, num_args = 2..)]
    frames: Vec<PathBuf>,
    /// Exposure ratio bright/dark (> 1) of two frames; overrides EXIF. Without it and
    /// without EXIF the ratio is estimated (see `ratio_prior` in the output).
    #[arg(long, conflicts_with = "times")]
    ratio: Option<f64>,
    /// Exposure times in seconds, one per frame in command-line order, all at one
    /// aperture and ISO (fractions like 1/60 are accepted); override EXIF. More than two
    /// frames need these or EXIF exposures.
    #[arg(long, value_delimiter = ',', value_name = "T,T,…")]
    times: Vec<String>,
    /// Model: `auto` (a cubic spline whose smoothness the data choose) or one polynomial
    /// of degree 1..=16 (the report's model was degree 6).
    #[arg(long, default_value = "auto", value_parser = parse_degree)]
    degree: Degree,
    /// Count every N-th pixel of every N-th row (a speed knob; 1 = all pixels).
    #[arg(long, default_value_t = 1)]
    stride: usize,
    /// Print JSON instead of a table.
    #[arg(long)]
    json: bool,
    /// Draw histograms, cumulative histograms, τ and g per channel into this PNG (more
    /// than two frames: g per channel).
    #[arg(long, value_name = "FILE.png")]
    plot: Option<PathBuf>,
    /// Save the response as a versioned TOML file (read by `merge` and the daemon).
    #[arg(short = 'o', long = "output", value_name = "response.toml")]
    output: Option<PathBuf>,
}

fn parse_degree(s: &str) -> Result<Degree, String> {
    if s == "auto" {
        return Ok(Degree::Auto);
    }
    match s.parse::<usize>() {
        Ok(n) if (1..=response::fit::MAX_DEGREE).contains(&n) => Ok(Degree::Fixed(n)),
        _ => Err(format!(
            "expected `auto` or a degree 1..={}",
            response::fit::MAX_DEGREE
        )),
    }
}

/// Mean brightness over all channels, from a histogram (for ordering frames without EXIF).
fn mean_brightness(h: &Histogram) -> f64 {
    let mut sum = 0.0;
    let mut n = 0.0;
    for c in 0..h.channels() {
        let cum = h.cumulative(c);
        let e = cum.edges();
        for (k, &count) in h.counts(c).iter().enumerate() {
            sum += count as f64 * 0.5 * (e[k] + e[k + 1]);
            n += count as f64;
        }
    }
    sum / n.max(1.0)
}

/// Runs the command.
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    if args.stride == 0 {
        bail!("--stride must be at least 1");
    }
    let loaded = load_alike(&args.frames)?;
    let counts: Vec<FrameCounts> = loaded
        .iter()
        .map(|l| FrameCounts::of_frame(&l.frame, args.stride))
        .collect();
    let exif: Vec<Option<f64>> = loaded
        .iter()
        .map(|l| l.metadata.exposure.relative())
        .collect();
    let times = given_times(&args.times, &loaded)?;
    if loaded.len() > 2 {
        return run_bracket(&args, &loaded, &counts, &exif, times);
    }
    let (exif, given_source) = if times.is_empty() {
        (exif, RatioSource::Exif)
    } else {
        (times.into_iter().map(Some).collect(), RatioSource::Argument)
    };
    let (dark, ratio) = pair_ratio(args.ratio, &loaded, &counts, &exif, given_source)?;
    let bright = 1 - dark;
    // The two frames' histograms over the pixels they share (a JPEG's hard-clipped
    // blocks left out of both).
    let (h_dark, h_bright) = shared_counts(&counts[dark], &counts[bright]);
    let calibration =
        response::calibrate(&h_dark, &h_bright, ratio, args.degree).with_context(|| {
            format!(
                "calibrating {} (dark) against {} (bright)",
                loaded[dark].path.display(),
                loaded[bright].path.display()
            )
        })?;
    if let Some(path) = &args.output {
        response::save(path, &calibration.record(), Overwrite::Replace)?;
    }
    if let Some(path) = &args.plot {
        plot::write(path, &h_dark, &h_bright, &calibration)?;
    }
    let mut report = report(&calibration);
    report["dark"] = json!(loaded[dark].path.display().to_string());
    report["bright"] = json!(loaded[bright].path.display().to_string());
    print_report(&report, args.json)
}

/// Decodes `paths`; all must have the first's channels and bit depth.
fn load_alike(paths: &[PathBuf]) -> anyhow::Result<Vec<LoadedFrame>> {
    let loaded: Vec<LoadedFrame> = paths
        .iter()
        .map(|p| frame::load(p, Limits::default()))
        .collect::<Result<_, _>>()?;
    for l in &loaded {
        if l.frame.channels() != loaded[0].frame.channels()
            || l.frame.bit_depth() != loaded[0].frame.bit_depth()
        {
            bail!(
                "{} and {} differ in channels or bit depth ({}×{}-bit against {}×{}-bit)",
                loaded[0].path.display(),
                l.path.display(),
                loaded[0].frame.channels(),
                loaded[0].frame.bit_depth().bits(),
                l.frame.channels(),
                l.frame.bit_depth().bits()
            );
        }
    }
    Ok(loaded)
}

/// The exposure times of `--times` in seconds, one per frame of `loaded` (none when
/// none is given).
fn given_times(times: &[String], loaded: &[LoadedFrame]) -> anyhow::Result<Vec<f64>> {
    if !times.is_empty() && times.len() != loaded.len() {
        bail!(
            "--times gives {} exposure times for {} frames: give one per frame, in the order given",
            times.len(),
            loaded.len()
        );
    }
    times
        .iter()
        .zip(loaded)
        .map(|(t, l)| {
            parse_time(t).with_context(|| format!("--times value for {}", l.path.display()))
        })
        .collect()
}

/// Which frame of a pair is the darker (0 or 1) and their ratio: the `--ratio` given
/// (the darker by `exif` exposure, or by mean brightness), else from the `exif` (or
/// `--times`) exposures of `given_source`, else estimated (the darker by brightness).
fn pair_ratio(
    ratio: Option<f64>,
    loaded: &[LoadedFrame],
    counts: &[FrameCounts],
    exif: &[Option<f64>],
    given_source: RatioSource,
) -> anyhow::Result<(usize, Ratio)> {
    Ok(match (ratio, exif[0], exif[1]) {
        (Some(r), ..) => {
            if !(r.is_finite() && r > 1.0) {
                bail!("--ratio {r}: must be a number above 1 (bright over dark exposure)");
            }
            let dark = match (exif[0], exif[1]) {
                (Some(a), Some(b)) if a != b => usize::from(b < a),
                _ => usize::from(
                    mean_brightness(counts[1].histogram()) < mean_brightness(counts[0].histogram()),
                ),
            };
            (dark, Ratio::Known(r, RatioSource::Argument))
        }
        (None, Some(a), Some(b)) if a == b => bail!(
            "{} and {} have the same exposure ({a}): give --ratio if they differ",
            loaded[0].path.display(),
            loaded[1].path.display()
        ),
        (None, Some(a), Some(b)) => {
            let dark = usize::from(b < a);
            (dark, Ratio::Known(a.max(b) / a.min(b), given_source))
        }
        _ => (
            usize::from(
                mean_brightness(counts[1].histogram()) < mean_brightness(counts[0].histogram()),
            ),
            Ratio::Estimate,
        ),
    })
}

/// More than two frames: one joint fit over every two frames adjacent in exposure
/// ([`response::calibrate_frames`]), with the exposures from `--times` or EXIF.
fn run_bracket(
    args: &Args,
    loaded: &[LoadedFrame],
    counts: &[FrameCounts],
    exif: &[Option<f64>],
    times: Vec<f64>,
) -> anyhow::Result<ExitCode> {
    if args.ratio.is_some() {
        bail!(
            "--ratio is for two frames: give --times T,T,… for {} frames",
            loaded.len()
        );
    }
    let (exposures, source) = if times.is_empty() {
        let mut exposures = Vec::with_capacity(loaded.len());
        for (l, e) in loaded.iter().zip(exif) {
            let Some(e) = e else {
                bail!(
                    "{}: no EXIF exposure (time, aperture, ISO); give --times T,T,… for every frame",
                    l.path.display()
                );
            };
            exposures.push(*e);
        }
        (exposures, RatioSource::Exif)
    } else {
        (times, RatioSource::Argument)
    };
    let frames: Vec<(&FrameCounts, f64)> = counts.iter().zip(exposures.iter().copied()).collect();
    let calibration = response::calibrate_frames(&frames, source, args.degree)
        .with_context(|| format!("calibrating the {} frames jointly", loaded.len()))?;
    if let Some(path) = &args.output {
        response::save(path, &calibration.record(), Overwrite::Replace)?;
    }
    if let Some(path) = &args.plot {
        let title = format!("joint fit of {} frames", loaded.len());
        plot::write_response(path, &calibration.response, &title)?;
    }
    let mut order: Vec<usize> = (0..loaded.len()).collect();
    order.sort_by(|&a, &b| exposures[a].total_cmp(&exposures[b]));
    let darkest = exposures[order[0]];
    let mut report = report(&calibration);
    report["frames"] = order
        .iter()
        .map(|&k| {
            json!({
                "path": loaded[k].path.display().to_string(),
                "exposure": exposures[k] / darkest,
            })
        })
        .collect();
    print_report(&report, args.json)
}

/// Prints the report as JSON or as a table.
fn print_report(report: &Value, json: bool) -> anyhow::Result<ExitCode> {
    let text = if json {
        serde_json::to_string_pretty(report)? + "\n"
    } else {
        table(report)
    };
    // A closed pipe (`| head`) is not worth a panic.
    let _ = std::io::Write::write_all(&mut std::io::stdout().lock(), text.as_bytes());
    Ok(ExitCode::SUCCESS)
}

/// Finite numbers as JSON numbers, anything else as `null`.
fn number(x: f64) -> Value {
    if x.is_finite() { json!(x) } else { Value::Null }
}

/// The `--json` report: the ratio, and per channel the curve summary and its confidence
/// (the caller adds which frames: `dark` and `bright`, or `frames`).
fn report(cal: &Calibration) -> Value {
    let channels: Vec<Value> = cal
        .channels
        .iter()
        .enumerate()
        .map(|(c, ch)| {
            let f = &ch.fit;
            let g: Vec<f64> = (0..=255)
                .map(|k| cal.response.eval(c, f64::from(k) / 255.0))
                .collect();
            json!({
                "name": ch.name,
                "model": f.model(),
                "family": f.family(),
                "degree": f.degree,
                "pieces": f.knots.len() + 1,
                "knots": f.knots.iter().map(|x| x.exp()).collect::<Vec<_>>(),
                "effective_parameters": number(f.effective_parameters),
                "smoothing": number(f.smoothing),
                "coefficients": f.coefficients,
                "inverse_response": g,
                "covered": [f.covered.0, f.covered.1],
                "extrapolated": [[0.0, f.covered.0], [f.covered.1, 1.0]],
                "residual_rms": number(f.residual_rms),
                "equations": f.equations,
                "condition_number": number(f.condition),
                "predicted_error_stops": number(f.predicted_error),
                "predicted_shape_error_stops": number(f.predicted_shape_error),
                "misfit": number(f.misfit),
                "top_span_stops": number(f.top_span),
                "coverage": number(f.coverage),
                "confidence": f.confidence,
                "low_confidence": f.confidence < filmback::response::fit::LOW_CONFIDENCE,
                "borrowed_from": ch.borrowed_from,
            })
        })
        .collect();
    json!({
        "ratio": cal.ratio,
        "ratio_source": cal.ratio_source.as_str(),
        "ratio_prior": (cal.ratio_source == RatioSource::Estimated).then(|| format!(
            "g(0.5) = {PRIOR_MID_GREY:.4}, a real camera's on the median (g and the ratio trade off as g^k, ratio^k)"
        )),
        "ratio_range": cal.ratio_range().map(|(lo, hi)| [lo, hi]),
        "channels": channels,
    })
}

/// The text report of `r` ([`report`], with its frames or its pair): the frames and
/// ratio, a row per channel, the models and the notes.
fn table(r: &Value) -> String {
    let mut out = String::new();
    write_ratio(&mut out, r);
    write_channels(&mut out, r);
    write_notes(&mut out, r);
    out
}

/// The frames (or the pair), the ratio and where it came from, and its range when it
/// was estimated.
fn write_ratio(out: &mut String, r: &Value) {
    use std::fmt::Write;
    if let Some(frames) = r["frames"].as_array() {
        for f in frames {
            let _ = writeln!(
                out,
                "frame {}  exposure ×{:.4}",
                f["path"].as_str().unwrap_or("?"),
                f["exposure"].as_f64().unwrap_or(f64::NAN)
            );
        }
    } else {
        let _ = writeln!(
            out,
            "dark {}  bright {}",
            r["dark"].as_str().unwrap_or("?"),
            r["bright"].as_str().unwrap_or("?")
        );
    }
    let _ = writeln!(
        out,
        "ratio {:.4} ({}){}",
        r["ratio"].as_f64().unwrap_or(f64::NAN),
        r["ratio_source"].as_str().unwrap_or("?"),
        r["ratio_prior"]
            .as_str()
            .map_or(String::new(), |p| format!(", assuming {p}"))
    );
    if let Some([lo, hi]) = r["ratio_range"].as_array().map(|a| {
        [
            a[0].as_f64().unwrap_or(f64::NAN),
            a[1].as_f64().unwrap_or(f64::NAN),
        ]
    }) {
        let _ = writeln!(
            out,
            "the true ratio is {lo:.2}..{hi:.2} for four camera curves in five: give --ratio or EXIF for more"
        );
    }
}

/// A header and a row per channel: its fit's figures and `g` at codes 64, 128 and 191.
fn write_channels(out: &mut String, r: &Value) {
    use std::fmt::Write;
    let _ = writeln!(
        out,
        "{:<3} {:>6} {:>6} {:>9} {:>9} {:>15} {:>9} {:>9} {:>10} {:>10}  g(0.25) g(0.5) g(0.75)",
        "ch",
        "degree",
        "pieces",
        "eff.par.",
        "smoothing",
        "covered",
        "residual",
        "equations",
        "condition",
        "confidence"
    );
    for ch in r["channels"].as_array().into_iter().flatten() {
        let g = |k: usize| ch["inverse_response"][k].as_f64().unwrap_or(f64::NAN);
        let f = |k: &str| ch[k].as_f64().unwrap_or(f64::NAN);
        let mut note = String::new();
        if let Some(d) = ch["borrowed_from"].as_str() {
            note = format!("  (not fitted: curve borrowed from {d})");
        } else if ch["low_confidence"].as_bool() == Some(true) {
            note = "  LOW CONFIDENCE".to_string();
        }
        let _ = writeln!(
            out,
            "{:<3} {:>6} {:>6} {:>9.1} {:>9.1e} {:>7.4}..{:<6.4} {:>8.4}s {:>9} {:>10.2e} {:>10.2}  {:.4} {:.4} {:.4}{note}",
            ch["name"].as_str().unwrap_or("?"),
            ch["degree"].as_u64().unwrap_or(0),
            ch["pieces"].as_u64().unwrap_or(0),
            f("effective_parameters"),
            f("smoothing"),
            ch["covered"][0].as_f64().unwrap_or(f64::NAN),
            ch["covered"][1].as_f64().unwrap_or(f64::NAN),
            f("residual_rms"),
            ch["equations"].as_u64().unwrap_or(0),
            f("condition_number"),
            f("confidence"),
            g(64),
            g(128),
            g(191),
        );
    }
}

/// The models fitted, what the curve is outside the covered tones, what the confidence
/// means, and a warning when frames are further apart than it was calibrated on.
fn write_notes(out: &mut String, r: &Value) {
    use std::fmt::Write;
    let mut models: Vec<&str> = r["channels"]
        .as_array()
        .into_iter()
        .flatten()
        .filter(|ch| ch["borrowed_from"].is_null())
        .filter_map(|ch| ch["family"].as_str())
        .collect();
    models.dedup();
    for model in models {
        let _ = writeln!(out, "model: {model}");
    }
    out.push_str("outside the covered tones the curve is extrapolated\n");
    out.push_str(
        "confidence: the probability that a channel's shape and colour are right; the \
         common level, set by g(1) = 1 above the brightest tone matched, is not in it \
         (docs/accuracy.md)\n",
    );
    if let Some(step) = response::beyond_calibrated_ratios(&exposures(r)) {
        let _ = writeln!(
            out,
            "warning: frames {:.1} stops apart, beyond the four stops the confidence was \
             calibrated on: there up to one trusted 8-bit channel in six is off in shape \
             or colour (docs/accuracy.md); a frame between them makes the fit surer",
            step.log2()
        );
    }
}

/// The frames' relative exposures: those listed for a bracket, `[1, ratio]` for a pair.
fn exposures(r: &Value) -> Vec<f64> {
    match r["frames"].as_array() {
        Some(frames) => frames
            .iter()
            .filter_map(|f| f["exposure"].as_f64())
            .collect(),
        None => r["ratio"].as_f64().map_or_else(Vec::new, |k| vec![1.0, k]),
    }
}
