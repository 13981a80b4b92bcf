//! An archive of brackets on a render farm: `filmback plan` turns a folder tree into a
//! plan, one JSON line per task; `filmback run PLAN --index N` develops task `N`. Any
//! array-job engine (a Kubernetes Indexed Job, a Slurm job array, OpenCue, Deadline) runs
//! one `run` per index; `docs/farm.md` has the recipes.
//!
//! The plan groups the folder as the daemon does, through the daemon's own parts: the
//! listing of the ingest folder (`daemon::intake::scan`), the probe (EXIF, header, a
//! JPEG's end), the RAW+JPEG pairing by stem (`daemon::intake::Stems`) and the
//! [`crate::daemon::bracket::Grouper`] ([`Grouper::group_all`]: a folder scanned whole,
//! as the daemon takes a settled batch). A task is developed by the daemon's lab
//! ([`crate::daemon::DarkroomLab`]) and published as one set through [`crate::atomic`]:
//! nothing of a task is visible until all of it is.
//!
//! The farm sits above the daemon: it uses the daemon's configuration, grouping, lab and
//! response-cache format, and the daemon uses nothing of it.
//!
//! [`Grouper::group_all`]: crate::daemon::bracket::Grouper::group_all

mod frozen;
mod plan;
mod run;

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::daemon::bracket::{Alone, CameraId, Input};
use crate::daemon::journal::any_path;

pub use plan::{PlanError, PlanOptions, PlanSummary, write_plan};
pub use run::{RunError, RunOptions, RunOutcome, Verdict, run_task};

/// What the first record of a plan says it is.
pub const FORMAT: &str = "filmback-plan";

/// Version of the plan format written; `run` refuses other versions.
pub const VERSION: u32 = 1;

/// Exit status of `filmback run` for input that will not get better by retrying: a
/// damaged or changed frame, a bad plan line, an index out of range (`EX_DATAERR`).
pub const EXIT_BAD_INPUT: u8 = 65;

/// Exit status of `filmback run` for a failure worth retrying later, here or on another
/// node: an output or a frame that could not be written or read now (full disk, I/O
/// error, permissions, storage away) (`EX_TEMPFAIL`).
pub const EXIT_RETRY: u8 = 75;

/// One line of a plan.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "record", rename_all = "snake_case")]
pub enum Record {
    /// The first line: what the plan is and how to read it.
    Header(Header),
    /// One bracket or single frame to develop (lines `1..=tasks`, task `N` on line `N+1`).
    Task(Task),
    /// A file of the folder that is no task, with the reason (after the tasks).
    Unused(Unused),
}

/// The first line of a plan.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Header {
    /// Always [`FORMAT`].
    pub format: String,
    /// [`VERSION`] of the writer.
    pub version: u32,
    /// The folder the frames' paths are relative to (absolute, links resolved).
    #[serde(with = "any_path")]
    pub root: PathBuf,
    /// The folder the outputs are published in (absolute).
    #[serde(with = "any_path")]
    pub out: PathBuf,
    /// Number of task lines.
    pub tasks: usize,
    /// Number of unused-file lines.
    pub unused: usize,
    /// Where the tasks' responses come from.
    pub response: ResponsePlan,
    /// The largest task's memory estimate in bytes ([`crate::daemon::job_bytes`]).
    pub largest_task_bytes: u64,
    /// The configuration the plan was made with (TOML text; empty for the defaults): the
    /// tasks' presets come from it, whatever the configuration is at run time.
    pub config: String,
}

/// Where the tasks' responses come from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "policy", rename_all = "snake_case")]
pub enum ResponsePlan {
    /// Each bracket by its preset's `recalibrate` with an empty response cache: its own
    /// fit (`auto`, `always`; the sRGB inverse when no fit is possible or, under `auto`,
    /// it is weak), or the sRGB inverse (`never`). A single frame through the sRGB inverse.
    Fitted,
    /// Each body's curve frozen by a first pass over the archive (one joint fit over the
    /// evidence of up to [`crate::daemon::cache::POOL_BRACKETS`] of its brackets, spread
    /// over its captures), in the response-cache format under `folder`; every task of a
    /// body uses that curve. A body without a good fit is developed as under `fitted`.
    Pooled {
        /// The folder of the frozen curves, relative to the plan's folder.
        #[serde(with = "any_path")]
        folder: PathBuf,
    },
}

/// What a task is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TaskKind {
    /// Two or more frames merged: an EXR (when the preset asks) and the looks.
    Bracket,
    /// One frame rendered through the response: the looks only.
    Single,
}

/// One task: a bracket or a single frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Task {
    /// Its index, from 0: the line after the header's `index` lines.
    pub index: usize,
    /// Bracket or single.
    pub kind: TaskKind,
    /// Why a single stands alone.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub alone: Option<Alone>,
    /// [`crate::daemon::bracket::fingerprint`] of the frames: the staging folder's name.
    pub id: String,
    /// The body.
    pub camera: CameraId,
    /// The frames in capture order.
    pub frames: Vec<PlannedFrame>,
    /// Stem of every output name.
    pub stem: String,
    /// The frozen curve's file, relative to the plan's folder (`pooled` plans, bodies
    /// with a good fit); absent: fitted as [`ResponsePlan::Fitted`] says.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub response: Option<String>,
    /// The looks rendered, as the preset names them (films, then tone maps).
    pub looks: Vec<String>,
    /// The file names published in the output folder, as one set.
    pub outputs: Vec<String>,
    /// Memory estimate in bytes ([`crate::daemon::job_bytes`] of the frames' decoded
    /// sizes): what a task slot must hold.
    pub memory_bytes: u64,
}

/// A frame of a task as the plan found it; `run` checks the file is still this one.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlannedFrame {
    /// Path relative to the header's `root`.
    #[serde(with = "any_path")]
    pub path: PathBuf,
    /// Size in bytes.
    pub size: u64,
    /// Modification time, nanoseconds since the Unix epoch.
    pub modified_ns: i64,
    /// Relative exposure `e = t·S/N²` from EXIF (s·ISO), when known.
    pub exposure: Option<f64>,
    /// Capture time in seconds (EXIF, camera clock; the file's mtime without EXIF).
    pub time_s: f64,
    /// For a raw shot RAW+JPEG: the camera's JPEG of the same capture (path relative to
    /// `root`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub companion: Option<Input>,
}

/// A file that is no task, as `filmback status` lists rejected files.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Unused {
    /// Path relative to the header's `root`.
    #[serde(with = "any_path")]
    pub path: PathBuf,
    /// Why.
    pub reason: String,
}
