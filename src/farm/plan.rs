//! `filmback plan`: a folder tree into tasks, grouped as the daemon groups it.

use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};

use rayon::prelude::*;

use super::{
    FORMAT, Header, PlannedFrame, Record, ResponsePlan, Task, TaskKind, Unused, VERSION, frozen,
};
use crate::atomic::{self, Overwrite, PublishError};
use crate::daemon::bracket::{CameraId, Capture, Closed, Grouper, Input, capture_order};
use crate::daemon::config::{Config, Preset, Singles};
use crate::daemon::intake::{self, Probe, Stems, Taken};
use crate::daemon::lab::{self, Job, JobError};
use crate::daemon::{Footprint, job_bytes};
use crate::rendering::{Look, SourceExif};

/// Why a plan could not be made.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PlanError {
    /// The folder to plan is not a folder that can be read.
    #[error("{path}: not a folder to plan: {source}")]
    Root {
        /// The folder.
        path: PathBuf,
        /// What the operating system said.
        source: std::io::Error,
    },
    /// A preset's looks cannot be rendered (an unknown film or tone map).
    #[error("preset {preset}: {source}")]
    Looks {
        /// The preset's name (`render` for the defaults).
        preset: String,
        /// Why.
        source: JobError,
    },
    /// A body's frozen response could not be written.
    #[error("frozen response of {camera}: {source}")]
    Response {
        /// The body, as the cache names it.
        camera: String,
        /// Why.
        source: Box<crate::daemon::cache::CacheError>,
    },
    /// The output folder is the planned folder, or inside it when sub-folders are
    /// planned: the outputs would be taken as frames by the next plan.
    #[error(
        "output folder {out} is inside the planned folder {root}; its files would be taken as frames"
    )]
    Overlap {
        /// The output folder.
        out: PathBuf,
        /// The planned folder.
        root: PathBuf,
    },
    /// A record could not be encoded.
    #[error("{path}: cannot encode a record: {source}")]
    Encode {
        /// The plan.
        path: PathBuf,
        /// Why.
        source: serde_json::Error,
    },
    /// The plan could not be written.
    #[error(transparent)]
    Write(#[from] PublishError),
}

/// What to plan.
#[derive(Debug, Clone, Copy)]
pub struct PlanOptions<'a> {
    /// The folder tree of frames (walked as the daemon's `[watch]` section says:
    /// `recursive`, `extensions`, `ignore`; links are not followed).
    pub root: &'a Path,
    /// Where the tasks publish their outputs.
    pub out: &'a Path,
    /// The configuration (grouping rules, presets).
    pub config: &'a Config,
    /// Its text, carried in the plan's header (empty for the defaults).
    pub config_text: &'a str,
    /// Freeze one curve per body from a first pass ([`ResponsePlan::Pooled`]) instead of
    /// fitting each bracket.
    pub pooled: bool,
    /// The plan file to write (JSON lines, published atomically).
    pub plan: &'a Path,
}

/// What a plan holds.
#[derive(Debug, Clone, PartialEq)]
pub struct PlanSummary {
    /// Task lines.
    pub tasks: usize,
    /// Of which brackets.
    pub brackets: usize,
    /// Files listed as unused, with their reasons.
    pub unused: usize,
    /// The largest task's memory estimate, bytes.
    pub largest_task_bytes: u64,
    /// The frozen curves written (`pooled` plans).
    pub responses: Vec<PathBuf>,
}

/// What the daemon's intake makes of a folder scanned whole.
#[derive(Debug, Default)]
struct Survey {
    /// The frames (raws with their companion JPEG named).
    captures: Vec<Capture>,
    /// Each frame's decoded size and digest, by path.
    taken: HashMap<PathBuf, Taken>,
    /// Files that are no frame, with the reason.
    unused: Vec<(PathBuf, String)>,
}

impl Survey {
    /// Probes `paths` (in parallel) as the daemon's intake does a settled file.
    fn probe(&mut self, paths: &[PathBuf]) {
        let probed: Vec<(&PathBuf, Probe)> = paths
            .par_iter()
            .map(|p| (p, intake::probe_guarded(p, u64::MAX)))
            .collect();
        for (path, probe) in probed {
            match probe {
                Probe::Frame(capture, taken) => {
                    self.taken.insert(path.clone(), taken);
                    self.captures.push(capture);
                }
                Probe::Rejected(_, reason) => self.unused.push((path.clone(), reason)),
                Probe::Unreadable(reason) => self.unused.push((path.clone(), reason)),
                Probe::Changed => self.unused.push((
                    path.clone(),
                    "changed while it was read (still being written?)".to_string(),
                )),
                Probe::Gone => {}
            }
        }
    }
}

/// Lists and probes the frames under `root` with the daemon's intake: the JPEG of a
/// RAW+JPEG capture ([`Stems`]) is its raw's companion, not a frame, unless the raw is
/// rejected; then it is the frame.
fn survey(root: &Path, config: &Config) -> Survey {
    let paths = intake::scan(&config.watch, root);
    let mut stems = Stems::default();
    for p in &paths {
        stems.insert(p);
    }
    let (paired, first): (Vec<PathBuf>, Vec<PathBuf>) =
        paths.into_iter().partition(|p| stems.raw_of(p).is_some());
    let mut survey = Survey::default();
    survey.probe(&first);
    let mut companion_of_raw: HashMap<PathBuf, Input> = HashMap::new();
    let mut alone = Vec::new();
    for jpeg in paired {
        match stems
            .raw_of(&jpeg)
            .filter(|raw| survey.taken.contains_key(raw))
        {
            Some(raw) => match intake::identify(&jpeg) {
                Ok(input) => {
                    companion_of_raw.insert(raw, input);
                }
                Err(e) => survey.unused.push((jpeg, format!("cannot read: {e}"))),
            },
            None => alone.push(jpeg),
        }
    }
    survey.probe(&alone);
    for capture in &mut survey.captures {
        capture.companion = companion_of_raw.remove(&capture.input.path);
    }
    survey
}

/// Writes the plan of `options.root` (see the module docs of [`crate::farm`]).
pub fn write_plan(options: &PlanOptions<'_>) -> Result<PlanSummary, PlanError> {
    let (root, out) = folders(options)?;
    let config = options.config;
    let mut survey = survey(&root, config);
    let captures = std::mem::take(&mut survey.captures);
    let mut groups = Grouper::group_all(config.bracket, captures);
    groups.sort_by(|a, b| capture_order(a.frames()[0], b.frames()[0]));
    let state = sidecar(options.plan);
    let plan_dir = options.plan.parent().unwrap_or(Path::new(""));
    let frozen = if options.pooled {
        frozen::freeze(&groups, config, &state)?
    } else {
        HashMap::new()
    };
    let mut planner = Planner::new(options.config, out, &root, plan_dir, &survey, frozen);
    let tasks = planner.tasks(groups)?;
    let Planner {
        out,
        frozen,
        mut unused,
        ..
    } = planner;
    unused.sort_by(|a, b| a.path.cmp(&b.path));
    let response = if options.pooled {
        ResponsePlan::Pooled {
            folder: relative_to(plan_dir, &state),
        }
    } else {
        ResponsePlan::Fitted
    };
    let header = Header {
        format: FORMAT.to_string(),
        version: VERSION,
        root: root.clone(),
        out,
        tasks: tasks.len(),
        unused: unused.len(),
        response,
        largest_task_bytes: tasks.iter().map(|t| t.memory_bytes).max().unwrap_or(0),
        config: options.config_text.to_string(),
    };
    let mut responses: Vec<PathBuf> = frozen.into_values().collect();
    responses.sort();
    let summary = PlanSummary {
        tasks: tasks.len(),
        brackets: tasks.iter().filter(|t| t.kind == TaskKind::Bracket).count(),
        unused: unused.len(),
        largest_task_bytes: header.largest_task_bytes,
        responses,
    };
    let records = std::iter::once(Record::Header(header))
        .chain(tasks.into_iter().map(Record::Task))
        .chain(unused.into_iter().map(Record::Unused));
    publish(options.plan, records)?;
    Ok(summary)
}

/// The planned folder (resolved) and the output folder (absolute; resolved when it
/// exists), refused when the outputs would land among the planned frames.
fn folders(options: &PlanOptions<'_>) -> Result<(PathBuf, PathBuf), PlanError> {
    let root_error = |source| PlanError::Root {
        path: options.root.to_path_buf(),
        source,
    };
    let root = std::fs::canonicalize(options.root).map_err(root_error)?;
    std::fs::read_dir(&root).map_err(root_error)?;
    let out = std::path::absolute(options.out).unwrap_or_else(|_| options.out.to_path_buf());
    let out = std::fs::canonicalize(&out).unwrap_or(out);
    if out == root || (options.config.watch.recursive && out.starts_with(&root)) {
        return Err(PlanError::Overlap { out, root });
    }
    Ok((root, out))
}

/// What turns closed groups into task lines.
struct Planner<'a> {
    config: &'a Config,
    /// The output folder, absolute.
    out: PathBuf,
    /// The planned folder, resolved.
    root: &'a Path,
    /// The plan's folder.
    plan_dir: &'a Path,
    /// Each body's frozen curve (`pooled` plans).
    frozen: HashMap<CameraId, PathBuf>,
    /// Each frame's decoded size, by path.
    taken: &'a HashMap<PathBuf, Taken>,
    looks: LooksByPreset,
    /// The output stems given so far.
    stems: HashSet<String>,
    /// Files that are no task, with the reason.
    unused: Vec<Unused>,
}

impl<'a> Planner<'a> {
    /// A planner of `root` publishing into `out`, with its survey and frozen curves.
    fn new(
        config: &'a Config,
        out: PathBuf,
        root: &'a Path,
        plan_dir: &'a Path,
        survey: &'a Survey,
        frozen: HashMap<CameraId, PathBuf>,
    ) -> Planner<'a> {
        Planner {
            config,
            out,
            root,
            plan_dir,
            frozen,
            taken: &survey.taken,
            looks: LooksByPreset::default(),
            stems: HashSet::new(),
            unused: survey
                .unused
                .iter()
                .map(|(path, reason)| Unused {
                    path: relative_to(root, path),
                    reason: reason.clone(),
                })
                .collect(),
        }
    }

    /// One task per group, in order; a single is an unused file under `singles = "report"`.
    fn tasks(&mut self, groups: Vec<Closed>) -> Result<Vec<Task>, PlanError> {
        let mut tasks = Vec::with_capacity(groups.len());
        for closed in groups {
            if let Closed::Single(c, alone) = &closed
                && self.config.bracket.singles == Singles::Report
            {
                self.unused.push(Unused {
                    path: relative_to(self.root, &c.input.path),
                    reason: format!("a single frame ({alone}); [bracket] singles = \"report\""),
                });
                continue;
            }
            let stem = unique_stem(&closed, &mut self.stems);
            let job = job_of(&closed, self.config, &self.out, stem);
            let outputs = self.looks.names(&job)?;
            let footprints: Vec<Footprint> = closed
                .frames()
                .iter()
                .filter_map(|c| self.taken.get(&c.input.path).map(|t| t.footprint))
                .collect();
            let response = self.frozen.get(&job.camera).map(|file| {
                relative_to(self.plan_dir, file)
                    .to_string_lossy()
                    .into_owned()
            });
            let planned = Planned {
                outputs,
                response,
                memory_bytes: job_bytes(&footprints),
            };
            tasks.push(task(tasks.len(), &closed, job, planned, self.root));
        }
        Ok(tasks)
    }
}

/// The folder beside a plan that holds its frozen curves: `PLAN.d` (the response cache
/// format under `PLAN.d/responses/`).
fn sidecar(plan: &Path) -> PathBuf {
    let mut name = plan.file_name().unwrap_or_default().to_os_string();
    name.push(".d");
    plan.with_file_name(name)
}

/// `path` relative to `dir` when it is below it, else `path`.
fn relative_to(dir: &Path, path: &Path) -> PathBuf {
    path.strip_prefix(dir).unwrap_or(path).to_path_buf()
}

/// Writes `records`, one JSON line each, to `plan` atomically.
fn publish(plan: &Path, records: impl Iterator<Item = Record>) -> Result<(), PlanError> {
    let mut bytes = Vec::new();
    for record in records {
        serde_json::to_writer(&mut bytes, &record).map_err(|source| PlanError::Encode {
            path: plan.to_path_buf(),
            source,
        })?;
        bytes.push(b'\n');
    }
    atomic::publish(plan, &bytes, Overwrite::Replace)?;
    Ok(())
}

/// The group's output stem ([`Closed::stem`]), or, when an earlier task of the plan has
/// it, `<stem>-<first 8 hex digits of its id>`, as the daemon names a second bracket
/// whose first frame has an earlier one's stem.
fn unique_stem(closed: &Closed, taken: &mut HashSet<String>) -> String {
    let stem = closed.stem();
    let stem = if taken.contains(&stem) {
        format!("{stem}-{}", &closed.id()[..8])
    } else {
        stem
    };
    taken.insert(stem.clone());
    stem
}

/// The daemon's job for `closed` with an empty response cache.
pub(super) fn job_of(closed: &Closed, config: &Config, out: &Path, stem: String) -> Job {
    let camera = closed.camera().clone();
    Job {
        id: closed.id(),
        preset: preset_of(config, &camera).clone(),
        camera,
        frames: closed.frames().into_iter().cloned().collect(),
        cached: None,
        out: out.to_path_buf(),
        stem,
        stocks: config.folders.stocks.clone(),
        previews: false,
    }
}

/// The preset the daemon develops `camera`'s brackets with.
pub(super) fn preset_of<'a>(config: &'a Config, camera: &CameraId) -> &'a Preset {
    config.preset_for(camera.model.as_deref(), camera.serial.as_deref())
}

/// The looks of each preset, made once.
#[derive(Default)]
struct LooksByPreset(HashMap<Option<String>, Vec<Look>>);

impl LooksByPreset {
    /// The output file names of `job`, as the lab writes them.
    fn names(&mut self, job: &Job) -> Result<Vec<String>, PlanError> {
        let key = job.preset.name.clone();
        if !self.0.contains_key(&key) {
            let looks = lab::looks_of(&job.preset, job.stocks.as_deref()).map_err(|source| {
                PlanError::Looks {
                    preset: key.clone().unwrap_or_else(|| "render".to_string()),
                    source,
                }
            })?;
            self.0.insert(key.clone(), looks);
        }
        let looks = self.0.get(&key).map(Vec::as_slice).unwrap_or_default();
        let exif = SourceExif::default();
        Ok(lab::prints(job, looks, &exif, Path::new(""))
            .paths()
            .iter()
            .map(|p| p.to_string_lossy().into_owned())
            .collect())
    }
}

/// What the plan adds to a job for its line.
struct Planned {
    /// The output file names.
    outputs: Vec<String>,
    /// The frozen curve's file, relative to the plan's folder.
    response: Option<String>,
    /// The memory estimate, bytes.
    memory_bytes: u64,
}

/// The plan's line for a job; paths relative to `root`.
fn task(index: usize, closed: &Closed, job: Job, planned: Planned, root: &Path) -> Task {
    let relative = |p: &Path| relative_to(root, p);
    let frames = job
        .frames
        .iter()
        .map(|c| PlannedFrame {
            path: relative(&c.input.path),
            size: c.input.size,
            modified_ns: c.input.modified_ns,
            exposure: c.exposure,
            time_s: c.time_s,
            companion: c.companion.as_ref().map(|i| Input {
                path: relative(&i.path),
                ..i.clone()
            }),
        })
        .collect();
    let (kind, alone) = match closed {
        Closed::Bracket(_) => (TaskKind::Bracket, None),
        Closed::Single(_, alone) => (TaskKind::Single, Some(*alone)),
    };
    Task {
        index,
        kind,
        alone,
        id: job.id,
        camera: job.camera,
        frames,
        stem: job.stem,
        response: planned.response,
        looks: job
            .preset
            .films
            .iter()
            .chain(&job.preset.tonemaps)
            .cloned()
            .collect(),
        outputs: planned.outputs,
        memory_bytes: planned.memory_bytes,
    }
}
