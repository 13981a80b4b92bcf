//! `filmback inspect FILE... [--json]`.

use std::path::PathBuf;
use std::process::ExitCode;

use filmback::frame::{self, FrameError, Limits, LoadedFrame};
use serde_json::{Value, json};

/// Arguments of `filmback inspect`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Image files (JPEG, PNG, TIFF, camera raw).
    #[arg(required = true)]
    files: Vec<PathBuf>,
    /// Print a JSON array, one object per file, instead of a table.
    #[arg(long)]
    json: bool,
}

/// One file's report as JSON: exactly the fields of the `--json` contract, `null` where
/// unknown.
fn report(loaded: &LoadedFrame) -> Value {
    let m = &loaded.metadata;
    let f = &loaded.frame;
    let mut report = json!({
        "path": loaded.path.display().to_string(),
        "width": f.width(),
        "height": f.height(),
        "bit_depth": f.bit_depth().bits(),
        "channels": f.channels(),
        "camera": {
            "make": m.camera.make,
            "model": m.camera.model,
            "serial": m.camera.serial,
        },
        "exposure": {
            "time_s": m.exposure.time_s,
            "f_number": m.exposure.f_number,
            "iso": m.exposure.iso,
            "relative_exposure": m.exposure.relative(),
        },
        "captured_at": m.captured_at.map(|t| t.to_rfc3339()),
        "warnings": m.warnings,
    });
    if let Some(raw) = raw_report(loaded) {
        report["raw"] = raw;
    }
    report
}

/// A raw's levels, CFA and colour, under the key `raw` (absent for other files).
/// `bit_depth` is then the container's 16 bits; `raw.bits` is the sensor's.
fn raw_report(loaded: &LoadedFrame) -> Option<Value> {
    #[cfg(feature = "raw")]
    if let Some(info) = loaded.raw.as_deref() {
        return Some(json!({
            "camera": info.camera(),
            "bits": info.bits,
            "black": info.black,
            "white": info.white,
            "cfa": info.cfa.name(),
            "as_shot_neutral": info.neutral,
            "matrix_illuminant": info.matrix_illuminant,
            "response": "linear (raw)",
        }));
    }
    #[cfg(not(feature = "raw"))]
    let _ = loaded;
    None
}

/// Runs the command; exit status 1 if any file failed. Every file is reported, in order,
/// whatever happened to the others.
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let results: Vec<Result<LoadedFrame, FrameError>> = args
        .files
        .iter()
        .map(|path| frame::load(path, Limits::default()))
        .collect();
    let mut failed = false;
    for e in results.iter().filter_map(|r| r.as_ref().err()) {
        failed = true;
        eprintln!("filmback inspect: {e}");
    }
    if args.json {
        let reports: Vec<Value> = results
            .iter()
            .zip(&args.files)
            .map(|(r, path)| match r {
                Ok(loaded) => report(loaded),
                Err(e) => json!({ "path": path.display().to_string(), "error": e.to_string() }),
            })
            .collect();
        println!("{}", serde_json::to_string_pretty(&reports)?);
    } else {
        for (r, path) in results.iter().zip(&args.files) {
            match r {
                Ok(loaded) => print_frame(loaded),
                Err(e) => println!("{}\n  error: {e}", path.display()),
            }
        }
    }
    Ok(if failed {
        ExitCode::FAILURE
    } else {
        ExitCode::SUCCESS
    })
}

/// The readable table: one block per file, `?` where unknown.
fn print_frame(loaded: &LoadedFrame) {
    fn or_unknown<T: std::fmt::Display>(v: Option<T>) -> String {
        v.map_or_else(|| "?".to_string(), |v| v.to_string())
    }
    let (m, f) = (&loaded.metadata, &loaded.frame);
    let e = &m.exposure;
    println!(
        "{}\n  {}×{} {}-bit {}ch  {} {} (serial {}, lens {})",
        loaded.path.display(),
        f.width(),
        f.height(),
        f.bit_depth().bits(),
        f.channels(),
        or_unknown(m.camera.make.as_deref()),
        or_unknown(m.camera.model.as_deref()),
        or_unknown(m.camera.serial.as_deref()),
        or_unknown(m.camera.lens.as_deref()),
    );
    println!(
        "  {}  f/{}  ISO {}  e={}  EV100 {}  captured {}",
        e.time_s.map_or_else(|| "?".to_string(), shutter),
        or_unknown(e.f_number),
        or_unknown(e.iso),
        e.relative()
            .map_or_else(|| "?".to_string(), |v| format!("{v:.4}")),
        e.ev100()
            .map_or_else(|| "?".to_string(), |v| format!("{v:.2}")),
        or_unknown(m.captured_at.map(|t| t.to_rfc3339())),
    );
    #[cfg(feature = "raw")]
    if let Some(info) = loaded.raw.as_deref() {
        println!(
            "  raw: {}  {}-bit  black {:?}  white {}  CFA {}  neutral {:.3?}  response linear (raw)",
            info.camera(),
            info.bits,
            info.black,
            info.white,
            info.cfa.name(),
            info.neutral,
        );
    }
    for w in &m.warnings {
        println!("  warning: {w}");
    }
}

/// Exposure time as photographers write it: `1/250 s` below one second, `2.5 s` above.
fn shutter(t: f64) -> String {
    if t < 1.0 {
        format!("1/{} s", (1.0 / t).round())
    } else {
        format!("{t} s")
    }
}
