//! `filmback status [--state DIR] [--json]`: what the daemon has done and is doing.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use filmback::daemon::cache::ResponseCache;
use filmback::daemon::journal::{self, Entry};
use filmback::daemon::{self, Snapshot};
use serde_json::{Value, json};

/// Arguments of `filmback status`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// State folder of the daemon.
    #[arg(long, value_name = "DIR", default_value = ".filmback")]
    state: PathBuf,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
}

/// True when the daemon runs: it holds the state folder's lock; without a lock file (a
/// daemon of an older version), when the snapshot says so and its process is alive.
fn alive(state: &Path, snap: &Snapshot) -> bool {
    daemon::lock_held(state)
        .unwrap_or_else(|| snap.running && Path::new(&format!("/proc/{}", snap.pid)).exists())
}

/// Reads journal, status snapshot and cache; prints them.
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    if !args.state.is_dir() {
        anyhow::bail!(
            "{}: no state folder (has `filmback watch` run here? use --state DIR)",
            args.state.display()
        );
    }
    let entries = journal::read(&args.state)?;
    let tally = Tally::of(&entries);
    let mut snap = daemon::read_snapshot(&args.state);
    let running = snap.as_ref().is_some_and(|s| alive(&args.state, s));
    if let Some(s) = snap.as_mut().filter(|_| !running) {
        // The last snapshot of a daemon that was killed still says it runs.
        s.running = false;
        s.watching = false;
        s.viewer = None;
    }
    // A daemon that can no longer replace status.json leaves an old snapshot behind.
    let stale = running && !daemon::state_writable(&args.state);
    let cached = cached_responses(&args.state)?;
    let interrupted = interrupted_sets(snap.as_ref());
    let report = json!({
        "state": args.state.display().to_string(),
        "interrupted_sets": interrupted,
        "running": running,
        "stale": stale,
        "daemon": snap.as_ref().map(|s| json!(s)),
        "brackets_done": tally.brackets,
        "singles_done": tally.singles,
        "failed": tally.failed,
        "rejected": tally.rejected,
        "cache": cached,
    });
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
        return Ok(ExitCode::SUCCESS);
    }
    println!("state folder  {}", args.state.display());
    if stale {
        println!(
            "warning       the state folder is not writable: the daemon cannot update its status, and what follows may be stale"
        );
    }
    print_daemon(snap.as_ref(), running);
    print_work(&tally, &interrupted);
    print_cache(&cached);
    Ok(ExitCode::SUCCESS)
}

/// What the journal says was done.
struct Tally {
    /// Brackets developed.
    brackets: usize,
    /// Single frames rendered or reported.
    singles: usize,
    /// Brackets whose latest word is a failure: their inputs and the reason.
    failed: Vec<Value>,
    /// Files whose latest word is a rejection: the file and the reason.
    rejected: Vec<Value>,
}

impl Tally {
    /// Counts the `entries`; a file's latest entry decides, so a rejected file that was
    /// rewritten and then developed is no longer listed as rejected.
    fn of(entries: &[Entry]) -> Tally {
        let mut latest: HashMap<&Path, &Entry> = HashMap::new();
        for e in entries {
            for i in e.inputs() {
                latest.insert(i.path.as_path(), e);
            }
        }
        let (mut brackets, mut singles, mut failed) = (0usize, 0usize, Vec::new());
        let mut rejected = Vec::new();
        for e in entries {
            match e {
                Entry::Bracket { .. } => brackets += 1,
                Entry::Single { .. } => singles += 1,
                Entry::Failed { inputs, reason, .. } => {
                    if inputs
                        .iter()
                        .all(|i| std::ptr::eq(latest[i.path.as_path()], e))
                    {
                        failed.push(json!({"inputs": inputs.iter().map(|i| i.path.display().to_string()).collect::<Vec<_>>(), "reason": reason}));
                    }
                }
                Entry::Unchanged { .. } => {}
                Entry::Rejected { input, reason, .. } => {
                    if std::ptr::eq(latest[input.path.as_path()], e) {
                        rejected.push(
                            json!({"file": input.path.display().to_string(), "reason": reason}),
                        );
                    }
                }
            }
        }
        Tally {
            brackets,
            singles,
            failed,
            rejected,
        }
    }
}

/// Each camera's entry in the response cache of `state`: its bracket count, pooled
/// brackets, confidence and update time, or why it is unusable.
fn cached_responses(state: &Path) -> anyhow::Result<Vec<Value>> {
    let cache = ResponseCache::new(state);
    Ok(cache
        .list()?
        .into_iter()
        .map(|r| match r {
            Ok(c) => json!({"camera": c.camera.to_string(), "brackets": c.brackets, "pooled": c.pool.len(), "confidence": c.min_confidence(), "updated": c.updated}),
            Err(e) => json!({"error": e.to_string()}),
        })
        .collect())
}

/// Output sets a killed daemon left half published in the output folder of `snap`: the
/// rest appears at its next start.
fn interrupted_sets(snap: Option<&Snapshot>) -> Vec<Value> {
    snap.map(|s| filmback::atomic::interrupted_sets(&s.out))
        .unwrap_or_default()
        .iter()
        .map(|set| {
            let paths = |p: &[PathBuf]| -> Vec<String> {
                p.iter().map(|p| p.display().to_string()).collect()
            };
            json!({"staging": set.stage.display().to_string(), "published": paths(&set.published), "pending": paths(&set.pending)})
        })
        .collect()
}

/// Prints whether the daemon runs and, when it does, its pending work, viewer and
/// retries.
fn print_daemon(snap: Option<&Snapshot>, running: bool) {
    match snap {
        Some(s) if running => println!(
            "daemon        running (pid {}), watching {}{}\n  pending     {} settling, {} in open brackets, {} queued, {} developing, {} retrying",
            s.pid,
            s.ingest.display(),
            if s.watching { "" } else { " (folder missing!)" },
            s.settling,
            s.grouping,
            s.queued,
            s.in_flight,
            s.retrying
        ),
        Some(s) => println!("daemon        not running (last pid {})", s.pid),
        None => println!("daemon        never ran here"),
    }
    if let Some(s) = snap.filter(|_| running) {
        if let Some(url) = &s.viewer {
            println!("  viewer      {url}");
        }
        let now = journal::unix_now();
        for r in &s.retries {
            println!(
                "  retry       {}: {} (attempt {}, next in {} s)",
                r.what,
                r.reason,
                r.attempts,
                r.next.saturating_sub(now)
            );
        }
    }
}

/// Prints what was done, the output sets left `interrupted`, and what failed or was
/// rejected.
fn print_work(tally: &Tally, interrupted: &[Value]) {
    println!(
        "done          {} brackets, {} single frames",
        tally.brackets, tally.singles
    );
    if !interrupted.is_empty() {
        println!(
            "interrupted   {} output set(s) partly published (the daemon was killed while renaming them); the rest appears at its next start",
            interrupted.len()
        );
        for set in interrupted {
            println!(
                "  published {}; pending {}",
                set["published"], set["pending"]
            );
        }
    }
    println!("failed        {}", tally.failed.len());
    for f in &tally.failed {
        println!("  {}: {}", f["inputs"], f["reason"].as_str().unwrap_or(""));
    }
    println!("rejected      {}", tally.rejected.len());
    for r in &tally.rejected {
        println!(
            "  {}: {}",
            r["file"].as_str().unwrap_or(""),
            r["reason"].as_str().unwrap_or("")
        );
    }
}

/// Prints the response cache's entries.
fn print_cache(cached: &[Value]) {
    println!("cache         {} camera(s)", cached.len());
    for c in cached {
        match c.get("error") {
            Some(e) => println!("  unusable: {}", e.as_str().unwrap_or("")),
            None => println!(
                "  {} ({} brackets, {} pooled, confidence {})",
                c["camera"].as_str().unwrap_or(""),
                c["brackets"],
                c["pooled"],
                c["confidence"]
                    .as_f64()
                    .map_or_else(|| "unknown".to_string(), |v| format!("{v:.2}"))
            ),
        }
    }
}
