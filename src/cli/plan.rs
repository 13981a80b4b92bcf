//! `filmback plan DIR [--config FILE] -o PLAN.jsonl [--out DIR] [--response pooled]`.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use filmback::daemon::config::Config;
use filmback::farm::{self, PlanOptions};

/// Arguments of `filmback plan`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The folder tree of frames (walked as the configuration's `[watch]` says).
    #[arg(value_name = "DIR")]
    dir: PathBuf,
    /// Configuration file (TOML): grouping rules and presets; without it the defaults.
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// The plan to write: one JSON line per task (docs/farm.md).
    #[arg(short = 'o', long = "output", value_name = "PLAN.jsonl")]
    plan: PathBuf,
    /// Where the tasks publish (default: the configuration's `[folders] out`).
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
    /// `fitted`: each bracket's own fit; `pooled`: one curve per body, frozen by a first
    /// pass over the archive into `PLAN.jsonl.d/responses/`.
    #[arg(long, value_name = "POLICY", default_value = "fitted", value_parser = ["fitted", "pooled"])]
    response: String,
}

/// Writes the plan and prints what it holds, with the largest task's memory estimate.
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let (config, text) = match &args.config {
        Some(path) => {
            let text = std::fs::read_to_string(path)
                .with_context(|| format!("{}: cannot read", path.display()))?;
            (Config::from_str(&text, Some(path))?, text)
        }
        None => (Config::defaults(), String::new()),
    };
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| config.folders.out.clone());
    let summary = farm::write_plan(&PlanOptions {
        root: &args.dir,
        out: &out,
        config: &config,
        config_text: &text,
        pooled: args.response == "pooled",
        plan: &args.plan,
    })?;
    println!(
        "{}: {} task(s) ({} bracket(s), {} single(s)), {} file(s) unused; the largest task needs {} MB",
        args.plan.display(),
        summary.tasks,
        summary.brackets,
        summary.tasks - summary.brackets,
        summary.unused,
        summary.largest_task_bytes.div_ceil(1_000_000)
    );
    for file in &summary.responses {
        println!("frozen response: {}", file.display());
    }
    Ok(ExitCode::SUCCESS)
}
