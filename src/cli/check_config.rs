//! `filmback check-config [FILE]`: validate a configuration without starting.

use std::path::PathBuf;
use std::process::ExitCode;

use filmback::daemon::config::Config;

/// Arguments of `filmback check-config`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The file to check; without it, the built-in defaults are checked.
    file: Option<PathBuf>,
}

/// Prints the checked configuration's essentials, or the error (file:line:column: key).
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let config = match &args.file {
        Some(path) => Config::load(path)?,
        None => Config::defaults(),
    };
    let f = &config.folders;
    let name = args.file.as_ref().map_or_else(
        || "<built-in defaults>".to_string(),
        |p| p.display().to_string(),
    );
    println!("{name}: ok");
    println!("  ingest  {}", f.ingest.display());
    println!("  out     {}", f.out.display());
    println!("  state   {}", f.state.display());
    if let Some(a) = &f.archive {
        println!("  archive {}", a.display());
    }
    println!(
        "  watch   {:?}, settle {} ms, bracket size {}, max gap {} s, min step {} EV, jobs {}",
        config.watch.mode,
        config.watch.settle.as_millis(),
        config.bracket.size,
        config.bracket.max_gap_s,
        config.bracket.min_step_ev,
        config.daemon.jobs
    );
    let describe = |p: &filmback::daemon::config::Preset| {
        format!(
            "exr {}, films {:?}, tonemaps {:?}, t {:+} EV, response {:?}",
            p.exr, p.films, p.tonemaps, p.t, p.recalibrate
        )
    };
    println!("  default {}", describe(&config.render));
    for c in &config.cameras {
        let who = match &c.serial {
            Some(s) => format!("{} #{s}", c.model),
            None => c.model.clone(),
        };
        println!("  camera  {who}: {}", describe(&c.preset));
    }
    Ok(ExitCode::SUCCESS)
}
