//! `filmback run PLAN.jsonl (--index N | --index-env VAR) [--index-base B] [--force]`:
//! one task of a plan, with an exit status a farm engine can act on.

use std::path::PathBuf;
use std::process::ExitCode;

use filmback::farm::{self, EXIT_BAD_INPUT, RunOptions, RunOutcome};

/// Arguments of `filmback run`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The plan written by `filmback plan`.
    #[arg(value_name = "PLAN.jsonl")]
    plan: PathBuf,
    /// The task's index.
    #[arg(
        long,
        value_name = "N",
        required_unless_present = "index_env",
        conflicts_with = "index_env"
    )]
    index: Option<usize>,
    /// Read the index from this environment variable (JOB_COMPLETION_INDEX,
    /// SLURM_ARRAY_TASK_ID, CUE_IFRAME, …).
    #[arg(long, value_name = "VAR")]
    index_env: Option<String>,
    /// The index the engine gives the first task (1 for `sbatch --array=1-N` or an
    /// OpenCue frame range 1-N); the task run is `index - base`.
    #[arg(long, value_name = "B", default_value_t = 0)]
    index_base: usize,
    /// Where the frames are, when not where the plan found them (another mount point).
    #[arg(long, value_name = "DIR")]
    root: Option<PathBuf>,
    /// Where to publish, when not the plan's output folder.
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
    /// Develop and publish even when every output of the task is there already.
    #[arg(long)]
    force: bool,
}

/// The task index the arguments name, or why there is none.
fn index(args: &Args) -> Result<usize, String> {
    let given = match (&args.index, &args.index_env) {
        (Some(n), _) => *n,
        (None, Some(var)) => {
            let text = std::env::var(var).map_err(|e| format!("${var}: {e}"))?;
            text.trim()
                .parse()
                .map_err(|e| format!("${var} = {text:?}: not a task index: {e}"))?
        }
        (None, None) => return Err("give --index N or --index-env VAR".to_string()),
    };
    given
        .checked_sub(args.index_base)
        .ok_or_else(|| format!("index {given} is below --index-base {}", args.index_base))
}

/// Runs the task; exit status 0 when it is done (now or before), 75 to retry later, 65
/// for bad input (docs/farm.md).
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let index = match index(&args) {
        Ok(i) => i,
        Err(why) => {
            eprintln!("filmback: {}: {why}", args.plan.display());
            return Ok(ExitCode::from(EXIT_BAD_INPUT));
        }
    };
    let options = RunOptions {
        plan: &args.plan,
        index,
        root: args.root.as_deref(),
        out: args.out.as_deref(),
        force: args.force,
    };
    match farm::run_task(&options) {
        Ok(RunOutcome::Developed { outputs, notes }) => {
            for note in notes {
                eprintln!("filmback: task {index}: {note}");
            }
            for p in outputs {
                println!("{}", p.display());
            }
            Ok(ExitCode::SUCCESS)
        }
        Ok(RunOutcome::AlreadyDone { .. }) => {
            eprintln!(
                "filmback: task {index}: already done (every output is there; --force develops it again)"
            );
            Ok(ExitCode::SUCCESS)
        }
        Err(e) => {
            let code = e.verdict().exit_code();
            eprintln!(
                "filmback: task {index}: {}",
                super::chain_text(&anyhow::Error::new(e))
            );
            Ok(ExitCode::from(code))
        }
    }
}
