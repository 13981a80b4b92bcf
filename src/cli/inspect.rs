//! `filmback inspect FILE... [--json]`.

use std::path::PathBuf;
use std::process::ExitCode;

use filmback::frame::{self, Limits, LoadedFrame};
use serde_json::{Value, json};

/// Arguments of `filmback inspect`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Image files (JPEG, PNG, TIFF).
    #[arg(required = true)]
    files: Vec<PathBuf>,
    /// Print a JSON array, one object per file, instead of a table.
    #[arg(long)]
    json: bool,
}

/// One file's report as JSON (the `--json` contract).
fn report(loaded: &LoadedFrame) -> Value {
    let m = &loaded.metadata;
    let f = &loaded.frame;
    json!({
        "path": loaded.path.display().to_string(),
        "width": f.width(),
        "height": f.height(),
        "bit_depth": f.bit_depth().bits(),
        "channels": f.channels(),
        "camera": {
            "make": m.camera.make,
            "model": m.camera.model,
            "serial": m.camera.serial,
            "lens": m.camera.lens,
        },
        "exposure": {
            "time_s": m.exposure.time_s,
            "f_number": m.exposure.f_number,
            "iso": m.exposure.iso,
            "relative_exposure": m.exposure.relative(),
            "ev100": m.exposure.ev100(),
        },
        "captured_at": m.captured_at.map(|t| t.to_rfc3339()),
        "orientation": m.orientation,
        "warnings": m.warnings,
    })
}

/// Runs the command; exit status 1 if any file failed.
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let mut failed = false;
    let mut reports = Vec::new();
    for path in &args.files {
        match frame::load(path, Limits::default()) {
            Ok(loaded) => reports.push(report(&loaded)),
            Err(e) => {
                failed = true;
                reports.push(json!({ "path": path.display().to_string(), "error": e.to_string() }));
            }
        }
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&reports)?);
    } else {
        print_table(&reports);
    }
    Ok(if failed {
        ExitCode::FAILURE
    } else {
        ExitCode::SUCCESS
    })
}

fn print_table(reports: &[Value]) {
    let text = |v: &Value| match v {
        Value::Null => "?".to_string(),
        Value::String(s) => s.clone(),
        other => other.to_string(),
    };
    for r in reports {
        if let Some(err) = r.get("error") {
            println!("{}\n  error: {}", text(&r["path"]), text(err));
            continue;
        }
        let e = &r["exposure"];
        let time = e["time_s"].as_f64().map_or("?".to_string(), shutter);
        println!(
            "{}\n  {}×{} {}-bit {}ch  {} {} (serial {})\n  {}  f/{}  ISO {}  e={}  captured {}",
            text(&r["path"]),
            r["width"],
            r["height"],
            r["bit_depth"],
            r["channels"],
            text(&r["camera"]["make"]),
            text(&r["camera"]["model"]),
            text(&r["camera"]["serial"]),
            time,
            text(&e["f_number"]),
            text(&e["iso"]),
            e["relative_exposure"]
                .as_f64()
                .map_or("?".to_string(), |v| format!("{v:.4}")),
            text(&r["captured_at"]),
        );
        for w in r["warnings"].as_array().into_iter().flatten() {
            println!("  warning: {}", text(w));
        }
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
