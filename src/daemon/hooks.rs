//! `[hooks] on_developed`: a command run after each bracket is published, as gphoto2's
//! and Breeze's hooks are, beside the darkroom and never in its way.

use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use tracing::{info, warn};

/// How long a hook may run before it is killed.
const HOOK_TIMEOUT: Duration = Duration::from_secs(60);

/// One run of the `on_developed` hook.
#[derive(Debug, Clone)]
pub(crate) struct Developed {
    /// The command line (`/bin/sh -c`).
    pub command: String,
    /// The output stem (`FILMBACK_STEM`).
    pub stem: String,
    /// The body (`FILMBACK_CAMERA`).
    pub camera: String,
    /// The outputs, the command's arguments.
    pub outputs: Vec<PathBuf>,
}

/// Why a hook did not succeed (logged).
#[derive(Debug, thiserror::Error)]
pub(crate) enum HookError {
    /// The shell could not be started or waited for.
    #[error("cannot run the on_developed hook: {0}")]
    Spawn(#[from] std::io::Error),
    /// It ran longer than [`HOOK_TIMEOUT`] and was killed.
    #[error("the on_developed hook ran longer than {} s and was killed", HOOK_TIMEOUT.as_secs())]
    Timeout,
    /// It exited unsuccessfully.
    #[error("the on_developed hook failed: {0}")]
    Failed(std::process::ExitStatus),
}

/// A queue of hook runs, one at a time on a thread of its own.
#[derive(Debug, Clone)]
pub struct Hooks {
    runs: std::sync::mpsc::Sender<Developed>,
}

impl Hooks {
    /// Starts the thread that runs hooks in turn.
    pub(crate) fn start() -> Hooks {
        let (runs, rx) = std::sync::mpsc::channel::<Developed>();
        std::thread::spawn(move || {
            for run in rx {
                match run_hook(&run) {
                    Ok(()) => info!(bracket = %run.stem, "on_developed hook ran"),
                    Err(e) => warn!(bracket = %run.stem, error = %e, "hook"),
                }
            }
        });
        Hooks { runs }
    }

    /// Queues a run; returns at once.
    pub(crate) fn developed(&self, run: Developed) {
        if self.runs.send(run).is_err() {
            warn!("the hook thread has stopped; on_developed is not run");
        }
    }
}

/// Runs the hook and waits for it, at most [`HOOK_TIMEOUT`].
fn run_hook(run: &Developed) -> Result<(), HookError> {
    let mut child = Command::new("/bin/sh")
        .arg("-c")
        .arg(&run.command)
        .arg("filmback-hook")
        .args(&run.outputs)
        .env("FILMBACK_STEM", &run.stem)
        .env("FILMBACK_CAMERA", &run.camera)
        .stdin(Stdio::null())
        .spawn()?;
    let start = Instant::now();
    loop {
        if let Some(status) = child.try_wait()? {
            return if status.success() {
                Ok(())
            } else {
                Err(HookError::Failed(status))
            };
        }
        if start.elapsed() > HOOK_TIMEOUT {
            let _ = child.kill();
            let _ = child.wait();
            return Err(HookError::Timeout);
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}
