//! `filmback run`: one task of a plan, developed and published as the daemon does.
//!
//! A task is done when every output the plan names is in the output folder: running it
//! again changes nothing unless forced. Otherwise its frames are read again (each must
//! still be the file the plan found: same size and modification time), developed by the
//! daemon's lab into a hidden staging folder and published as one set
//! ([`crate::atomic::publish_set`]): a task killed before the set is sealed leaves
//! nothing visible (the next attempt removes its staging folder), one killed while the
//! sealed set is being renamed into place is finished by the next attempt.

use std::io::BufRead;
use std::path::{Path, PathBuf};

use super::plan::preset_of;
use super::{
    EXIT_BAD_INPUT, EXIT_RETRY, FORMAT, Header, PlannedFrame, Record, ResponsePlan, Task, VERSION,
};
use crate::atomic;
use crate::daemon::bracket::{Capture, fingerprint};
use crate::daemon::cache::{CacheError, CachedResponse, ResponseCache};
use crate::daemon::config::{Config, ConfigError, Recalibrate};
use crate::daemon::intake::{self, Probe};
use crate::daemon::{DarkroomLab, Job, JobError, Lab};

/// What a farm engine should do after a failed task.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    /// Run it again later (exit status [`EXIT_RETRY`]).
    RetryLater,
    /// Retrying will not help: fix the input or the plan ([`EXIT_BAD_INPUT`]).
    BadInput,
}

impl Verdict {
    /// The process exit status for this verdict.
    pub fn exit_code(self) -> u8 {
        match self {
            Verdict::RetryLater => EXIT_RETRY,
            Verdict::BadInput => EXIT_BAD_INPUT,
        }
    }
}

/// Why a task could not be run.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RunError {
    /// The plan could not be read.
    #[error("{path}: cannot read the plan: {source}")]
    ReadPlan {
        /// The plan.
        path: PathBuf,
        /// What the operating system said.
        source: std::io::Error,
    },
    /// A line of the plan is not a record of this format.
    #[error("{path}, line {line}: not a plan record: {source}")]
    BadLine {
        /// The plan.
        path: PathBuf,
        /// The line, from 1.
        line: usize,
        /// What the parser said.
        source: serde_json::Error,
    },
    /// The plan does not say what it must (its header, the task where it belongs).
    #[error("{path}, line {line}: {what}")]
    NotAPlan {
        /// The plan.
        path: PathBuf,
        /// The line, from 1.
        line: usize,
        /// What was expected there.
        what: String,
    },
    /// The index is not one of the plan's tasks.
    #[error("{path}: task {index} is out of range: the plan has {tasks} task(s), numbered from 0")]
    OutOfRange {
        /// The plan.
        path: PathBuf,
        /// The index asked for.
        index: usize,
        /// The plan's number of tasks.
        tasks: usize,
    },
    /// The configuration in the plan's header is not valid here.
    #[error("the plan's configuration: {0}")]
    Config(#[source] ConfigError),
    /// A frame is not the file the plan found (replaced, damaged, moved).
    #[error("{path}: {reason}; make the plan again")]
    Frame {
        /// The frame.
        path: PathBuf,
        /// What is wrong with it.
        reason: String,
    },
    /// A frame could not be read now (I/O error, permissions, still being written).
    #[error("{path}: cannot read now: {reason}")]
    Unreadable {
        /// The frame.
        path: PathBuf,
        /// What the intake said.
        reason: String,
    },
    /// The body's frozen response could not be read.
    #[error("frozen response: {0}")]
    Response(#[source] CacheError),
    /// The lab failed: a frame that does not decode, outputs that cannot be written, a
    /// bracket that cannot be developed.
    #[error(transparent)]
    Job(#[from] JobError),
    /// Another attempt at the task, or a daemon developing the same bracket into the same
    /// folder, holds its staging folder's lock ([`atomic::StageLock`]).
    #[error(
        "{path}: another attempt at this task, or a daemon developing the same bracket, holds its lock; retry later"
    )]
    Busy {
        /// The lock file.
        path: PathBuf,
    },
    /// The output folder, or the task's lock file in it, cannot be created.
    #[error("{path}: cannot create: {source}")]
    Out {
        /// The folder.
        path: PathBuf,
        /// What the operating system said.
        source: std::io::Error,
    },
}

impl RunError {
    /// Whether retrying may help.
    pub fn verdict(&self) -> Verdict {
        let transient =
            |e: &std::io::Error| intake::transient(e) || e.raw_os_error() == Some(libc::ENOSPC);
        match self {
            RunError::ReadPlan { source, .. } | RunError::Out { source, .. }
                if transient(source) =>
            {
                Verdict::RetryLater
            }
            RunError::Response(CacheError::Io { source, .. }) if transient(source) => {
                Verdict::RetryLater
            }
            RunError::Unreadable { .. }
            | RunError::Busy { .. }
            | RunError::Job(JobError::Output { .. }) => Verdict::RetryLater,
            _ => Verdict::BadInput,
        }
    }
}

/// Which task to run, and how.
#[derive(Debug, Clone, Copy)]
pub struct RunOptions<'a> {
    /// The plan file.
    pub plan: &'a Path,
    /// The task's index, from 0.
    pub index: usize,
    /// Where the frames are, when not where the plan found them (another mount point).
    pub root: Option<&'a Path>,
    /// Where to publish, when not the plan's output folder.
    pub out: Option<&'a Path>,
    /// Develop and publish even when the task's outputs are all there already.
    pub force: bool,
}

/// What running a task did.
#[derive(Debug, Clone, PartialEq)]
pub enum RunOutcome {
    /// Developed and published now.
    Developed {
        /// The files published.
        outputs: Vec<PathBuf>,
        /// Things worth a warning (the lab's notes).
        notes: Vec<String>,
    },
    /// Every output was there already (nothing written), or a set an earlier attempt
    /// had sealed was finished.
    AlreadyDone {
        /// The task's outputs.
        outputs: Vec<PathBuf>,
    },
}

/// Runs task `options.index` of the plan (see the module docs).
pub fn run_task(options: &RunOptions<'_>) -> Result<RunOutcome, RunError> {
    let (header, task) = read_task(options.plan, options.index)?;
    let config = Config::from_str(&header.config, None).map_err(RunError::Config)?;
    let root = options.root.unwrap_or(&header.root);
    let out = options.out.unwrap_or(&header.out);
    let outputs: Vec<PathBuf> = task.outputs.iter().map(|name| out.join(name)).collect();
    std::fs::create_dir_all(out).map_err(|source| RunError::Out {
        path: out.to_path_buf(),
        source,
    })?;
    if finished(out, &task.id, &outputs)? && !options.force {
        return Ok(RunOutcome::AlreadyDone { outputs });
    }
    let job = job_of(options, &header, &config, task, root, out)?;
    let processed = develop(&job)?;
    Ok(RunOutcome::Developed {
        outputs: processed.outputs,
        notes: processed.notes,
    })
}

/// True when every output is in `out`, after dealing with the staging folder a killed
/// attempt at task `id` left: a set sealed before the kill is finished, anything else in
/// it (never visible, or left after its set was published) is removed. Done under the
/// folder's [`atomic::StageLock`], released before the lab takes it again to develop:
/// [`RunError::Busy`] while another attempt, or a daemon, develops the set.
fn finished(out: &Path, id: &str, outputs: &[PathBuf]) -> Result<bool, RunError> {
    let stage = atomic::stage_folder(out, id);
    let _lock = atomic::StageLock::take(&stage).map_err(|e| match e {
        atomic::PublishError::Io { path, source } => RunError::Out { path, source },
        other => RunError::Busy {
            path: other.path().to_path_buf(),
        },
    })?;
    if std::fs::symlink_metadata(&stage).is_ok_and(|m| m.is_dir()) {
        atomic::recover_set(&stage, out);
    }
    Ok(outputs
        .iter()
        .all(|p| std::fs::symlink_metadata(p).is_ok_and(|m| m.is_file())))
}

/// The daemon's job for `task`: its frames read again and checked, the preset of its
/// body under the plan's configuration, its frozen curve if it names one (used as is:
/// `recalibrate = "never"`).
fn job_of(
    options: &RunOptions<'_>,
    header: &Header,
    config: &Config,
    task: Task,
    root: &Path,
    out: &Path,
) -> Result<Job, RunError> {
    let cached = frozen_response(options.plan, header, &task)?;
    let frames = task
        .frames
        .iter()
        .map(|f| reread(root, f))
        .collect::<Result<Vec<Capture>, RunError>>()?;
    if fingerprint(frames.iter().map(|c| &c.input)) != task.id {
        return Err(not_a_plan(
            options.plan,
            options.index + 2,
            format!("task {}: its id does not match its frames", task.index),
        ));
    }
    let mut preset = preset_of(config, &task.camera).clone();
    if cached.is_some() {
        preset.recalibrate = Recalibrate::Never;
    }
    Ok(Job {
        id: task.id,
        camera: task.camera,
        frames,
        preset,
        cached,
        out: out.to_path_buf(),
        stem: task.stem,
        stocks: config.folders.stocks.clone(),
        previews: false,
    })
}

/// The lab's development of `job`; a panic of the pipeline is the task's failure.
fn develop(job: &Job) -> Result<crate::daemon::Processed, RunError> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| DarkroomLab.process(job)))
        .unwrap_or_else(|panic| {
            let what = panic
                .downcast_ref::<&str>()
                .map(|s| (*s).to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_default();
            Err(JobError::Bracket(
                format!("the pipeline failed: {what}").into(),
            ))
        })
        .map_err(RunError::from)
}

/// The body's frozen curve, for a task that names one.
fn frozen_response(
    plan: &Path,
    header: &Header,
    task: &Task,
) -> Result<Option<CachedResponse>, RunError> {
    let (ResponsePlan::Pooled { folder }, Some(file)) = (&header.response, &task.response) else {
        return Ok(None);
    };
    let state = plan.parent().unwrap_or(Path::new("")).join(folder);
    let cache = ResponseCache::new(&state);
    match cache.get(&task.camera).map_err(RunError::Response)? {
        Some(entry) => Ok(Some(entry)),
        None => Err(RunError::Frame {
            path: plan.parent().unwrap_or(Path::new("")).join(file),
            reason: format!("the frozen response of {} is missing", task.camera),
        }),
    }
}

/// Probes a planned frame again, as the daemon's intake does, and checks it is the file
/// the plan found; its companion JPEG is taken as it is now (when it is still there).
fn reread(root: &Path, planned: &PlannedFrame) -> Result<Capture, RunError> {
    let path = root.join(&planned.path);
    let frame_error = |reason: String| RunError::Frame {
        path: path.clone(),
        reason,
    };
    let mut capture = match intake::probe_guarded(&path, u64::MAX) {
        Probe::Frame(capture, _) => capture,
        Probe::Rejected(_, reason) => return Err(frame_error(reason)),
        Probe::Unreadable(reason) => {
            return Err(RunError::Unreadable {
                path: path.clone(),
                reason,
            });
        }
        Probe::Changed => {
            return Err(RunError::Unreadable {
                path: path.clone(),
                reason: "it changed while it was read".to_string(),
            });
        }
        Probe::Gone => return Err(frame_error("not found".to_string())),
    };
    if (capture.input.size, capture.input.modified_ns) != (planned.size, planned.modified_ns) {
        return Err(frame_error(format!(
            "changed since the plan ({} bytes, mtime {} ns; the plan found {} bytes, mtime {} ns)",
            capture.input.size, capture.input.modified_ns, planned.size, planned.modified_ns
        )));
    }
    capture.companion = planned
        .companion
        .as_ref()
        .and_then(|c| intake::identify(&root.join(&c.path)).ok());
    Ok(capture)
}

/// The header and task `index` of the plan at `path`; task `N` is line `N + 2` (from 1).
fn read_task(path: &Path, index: usize) -> Result<(Header, Task), RunError> {
    let read_error = |source| RunError::ReadPlan {
        path: path.to_path_buf(),
        source,
    };
    let file = std::fs::File::open(path).map_err(read_error)?;
    let mut lines = std::io::BufReader::new(file).lines();
    let header = match parse(path, 1, lines.next())? {
        Record::Header(h) if h.format == FORMAT && h.version == VERSION => h,
        Record::Header(h) => {
            return Err(not_a_plan(
                path,
                1,
                format!(
                    "a {} plan of version {}; this filmback reads {FORMAT} version {VERSION}",
                    h.format, h.version
                ),
            ));
        }
        _ => {
            return Err(not_a_plan(
                path,
                1,
                "the first line is not the plan's header",
            ));
        }
    };
    if index >= header.tasks {
        return Err(RunError::OutOfRange {
            path: path.to_path_buf(),
            index,
            tasks: header.tasks,
        });
    }
    let line = index + 2;
    match parse(path, line, lines.nth(index))? {
        Record::Task(task) if task.index == index => Ok((header, task)),
        _ => Err(not_a_plan(path, line, format!("task {index} belongs here"))),
    }
}

fn not_a_plan(path: &Path, line: usize, what: impl Into<String>) -> RunError {
    RunError::NotAPlan {
        path: path.to_path_buf(),
        line,
        what: what.into(),
    }
}

/// Parses line `line` (from 1) of the plan; a missing line is a truncated plan.
fn parse(
    path: &Path,
    line: usize,
    text: Option<std::io::Result<String>>,
) -> Result<Record, RunError> {
    let text = text
        .ok_or_else(|| not_a_plan(path, line, "the plan ends before this line (truncated?)"))?
        .map_err(|source| RunError::ReadPlan {
            path: path.to_path_buf(),
            source,
        })?;
    serde_json::from_str(&text).map_err(|source| RunError::BadLine {
        path: path.to_path_buf(),
        line,
        source,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn io(code: i32) -> std::io::Error {
        std::io::Error::from_raw_os_error(code)
    }

    /// Output failures, a full disk and transient read errors are retried; everything
    /// about the input or the plan is not.
    #[test]
    fn what_a_farm_should_do_follows_the_error() {
        let path = PathBuf::from("x");
        let retry = [
            RunError::Job(JobError::Output {
                path: path.clone(),
                reason: "No space left on device".into(),
            }),
            RunError::ReadPlan {
                path: path.clone(),
                source: io(libc::EIO),
            },
            RunError::Out {
                path: path.clone(),
                source: io(libc::ENOSPC),
            },
            RunError::Unreadable {
                path: path.clone(),
                reason: "permission denied".into(),
            },
            RunError::Busy { path: path.clone() },
        ];
        for e in retry {
            assert_eq!(e.verdict(), Verdict::RetryLater, "{e}");
            assert_eq!(e.verdict().exit_code(), EXIT_RETRY);
        }
        let bad = [
            RunError::Job(JobError::Frame {
                path: path.clone(),
                reason: "corrupt".into(),
            }),
            RunError::Job(JobError::Bracket("sizes differ".into())),
            RunError::ReadPlan {
                path: path.clone(),
                source: io(libc::ENOENT),
            },
            RunError::OutOfRange {
                path: path.clone(),
                index: 3,
                tasks: 3,
            },
        ];
        for e in bad {
            assert_eq!(e.verdict(), Verdict::BadInput, "{e}");
            assert_eq!(e.verdict().exit_code(), EXIT_BAD_INPUT);
        }
    }
}
