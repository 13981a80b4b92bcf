//! `filmback plan` and `filmback run` through the real binary, as an array-job engine
//! runs them: the same outputs as the daemon's, byte for byte; idempotent tasks; exit
//! statuses a farm can act on; the Kubernetes manifest of `docs/farm/`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::Arc;

use filmback::daemon::DarkroomLab;
use filmback::daemon::cache::ResponseCache;
use filmback::daemon::config::Config;
use filmback::farm::{EXIT_BAD_INPUT, Record, ResponsePlan, Task};

use crate::common::filmback;
use crate::common::rig::{self, Rig};

/// The rig's configuration with every bracket fitted on its own (`recalibrate =
/// "always"`): the daemon's later brackets of a body otherwise lean on the curve pooled
/// from its earlier ones, which depends on the order they were developed in, while a
/// `fitted` plan's tasks each start from an empty cache. This makes the two comparable.
fn config_text(root: &Path) -> String {
    rig::config_text(root, "").replace("[render]\n", "[render]\nrecalibrate = \"always\"\n")
}

/// Two brackets of one body, one of another, a single frame, a truncated JPEG and (with
/// the `raw` feature) a bracket shot RAW+JPEG.
fn synthetic_folder(ingest: &Path) {
    std::fs::create_dir_all(ingest).unwrap();
    #[cfg(feature = "raw")]
    {
        rig::put(ingest, &rig::raw_aeb("EOS R8", 100, "r"));
        rig::put(ingest, &rig::aeb("EOS R8", 100, "r"));
    }
    let mut frames = rig::aeb("EOS R5", 0, "a");
    frames.extend(rig::aeb("EOS R5", 20, "b"));
    frames.extend(rig::aeb("EOS R6", 40, "c"));
    frames.push(rig::aeb("EOS R6", 60, "d").remove(0));
    let (name, mut bytes) = rig::aeb("EOS R6", 80, "e").remove(0);
    bytes.truncate(bytes.len() / 2);
    frames.push((name, bytes));
    rig::put(ingest, &frames);
}

/// The real bracket beside the repository (`../shared/testdata/brackets/frobisher`)
/// copied into `ingest`, when it is there; says so when it is not.
fn real_frames(ingest: &Path) -> bool {
    let real = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/testdata/brackets/frobisher");
    let Ok(entries) = std::fs::read_dir(&real) else {
        println!(
            "note: {} absent: the farm is compared with the daemon on synthetic brackets only",
            real.display()
        );
        return false;
    };
    for path in entries.map(|e| e.unwrap().path()) {
        if path.extension().is_some_and(|e| e == "jpg") {
            std::fs::copy(&path, ingest.join(path.file_name().unwrap())).unwrap();
        }
    }
    true
}

/// `filmback plan INGEST --config CONFIG -o PLAN --out OUT [extra]`, which must succeed.
fn plan(ingest: &Path, config: &Path, plan: &Path, out: &Path, extra: &[&str]) -> String {
    let done = filmback()
        .arg("plan")
        .arg(ingest)
        .arg("--config")
        .arg(config)
        .arg("-o")
        .arg(plan)
        .arg("--out")
        .arg(out)
        .args(extra)
        .output()
        .unwrap();
    assert!(done.status.success(), "{}", text(&done.stderr));
    text(&done.stdout)
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// The plan's records.
fn records(plan: &Path) -> Vec<Record> {
    std::fs::read_to_string(plan)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

fn tasks(plan: &Path) -> Vec<Task> {
    records(plan)
        .into_iter()
        .filter_map(|r| match r {
            Record::Task(t) => Some(t),
            _ => None,
        })
        .collect()
}

/// `filmback run PLAN --index N` with `args` after it.
fn run(plan: &Path, index: usize, args: &[&str]) -> Output {
    filmback()
        .arg("run")
        .arg(plan)
        .args(["--index", &index.to_string()])
        .args(args)
        .output()
        .unwrap()
}

/// Every task of `plan`, two at a time, as an array engine runs them: `seq | xargs -P 2`.
fn run_array(plan: &Path, tasks: usize) {
    let done = Command::new("sh")
        .arg("-c")
        .arg(r#"seq 0 $(($2 - 1)) | xargs -P 2 -I{} "$0" run "$1" --index {}"#)
        .arg(env!("CARGO_BIN_EXE_filmback"))
        .arg(plan)
        .arg(tasks.to_string())
        .output()
        .unwrap();
    assert!(done.status.success(), "{}", text(&done.stderr));
}

/// The visible files of `dir` and their bytes.
fn files(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    rig::visible(dir)
        .into_iter()
        .map(|name| {
            let bytes = std::fs::read(dir.join(&name)).unwrap();
            (name, bytes)
        })
        .collect()
}

/// The daemon and the plan run by `xargs -P 2` over the same folder publish the same
/// files with the same bytes; the truncated frame is the plan's one unused file.
#[test]
fn the_plan_run_as_an_array_publishes_what_the_daemon_does() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    let ingest = root.join("ingest");
    synthetic_folder(&ingest);
    let real = real_frames(&ingest);
    let text = config_text(root);
    let config = Config::from_str(&text, Some(Path::new("test.toml"))).unwrap();
    let config_file = root.join("farm.toml");
    std::fs::write(&config_file, &text).unwrap();
    // Planned before the daemon runs: the daemon moves nothing (no archive), and the
    // plan must not see the daemon's files.
    let plan_file = root.join("plan.jsonl");
    let farm_out = root.join("farm-out");
    let said = plan(&ingest, &config_file, &plan_file, &farm_out, &[]);
    let records = records(&plan_file);
    let Record::Header(header) = &records[0] else {
        panic!("no header: {records:?}");
    };
    assert_eq!(header.version, filmback::farm::VERSION);
    let unused: Vec<_> = records
        .iter()
        .filter_map(|r| match r {
            Record::Unused(u) => Some(u),
            _ => None,
        })
        .collect();
    assert_eq!(unused.len(), 1, "{unused:?}");
    assert_eq!(unused[0].path, Path::new("e-1.jpg"));
    assert!(unused[0].reason.contains("truncated"), "{unused:?}");
    assert!(said.contains("the largest task needs"), "{said}");
    let planned = tasks(&plan_file);
    assert_eq!(planned.len(), header.tasks);
    assert!(planned.len() >= 4, "{planned:?}");
    run_array(&plan_file, planned.len());
    let expected: usize = planned.iter().map(|t| t.outputs.len()).sum();
    let farm = files(&farm_out);
    assert_eq!(farm.len(), expected, "{:?}", farm.keys());
    let mut daemon = Rig::start_with(root, config, Arc::new(DarkroomLab));
    rig::wait_for(&daemon.out(), "the daemon's outputs", |names| {
        names.len() >= expected
    });
    daemon.stop();
    let watched = files(&daemon.out());
    assert_eq!(
        farm.keys().collect::<Vec<_>>(),
        watched.keys().collect::<Vec<_>>()
    );
    for (name, bytes) in &farm {
        assert!(watched[name] == *bytes, "{name} differs from the daemon's");
    }
    #[cfg(feature = "raw")]
    {
        let raw = planned
            .iter()
            .find(|t| t.stem == "r-1")
            .expect("the raw bracket");
        assert_eq!(raw.frames.len(), 3);
        assert!(raw.frames.iter().all(|f| {
            f.path.extension().is_some_and(|e| e == "dng")
                && f.companion
                    .as_ref()
                    .is_some_and(|c| c.path.extension().is_some_and(|e| e == "jpg"))
        }));
    }
    if real {
        assert!(
            farm.keys().any(|n| n.starts_with("IMG_2600")),
            "{:?}",
            farm.keys()
        );
    }
}

/// A folder of two brackets planned under the rig's configuration, with its plan.
fn planned(root: &Path, extra: &[&str]) -> (PathBuf, PathBuf) {
    let ingest = root.join("ingest");
    std::fs::create_dir_all(&ingest).unwrap();
    let mut frames = rig::aeb("EOS R5", 0, "a");
    frames.extend(rig::aeb("EOS R5", 20, "b"));
    rig::put(&ingest, &frames);
    let config = root.join("farm.toml");
    std::fs::write(&config, config_text(root)).unwrap();
    let (plan_file, out) = (root.join("plan.jsonl"), root.join("out"));
    plan(&ingest, &config, &plan_file, &out, extra);
    (plan_file, out)
}

fn modified(path: &Path) -> std::time::SystemTime {
    std::fs::metadata(path).unwrap().modified().unwrap()
}

/// A task run twice publishes once; a finished set stays as it is unless forced; a
/// staging folder left by a killed attempt is never visible and does not stop the next.
#[test]
fn a_task_is_idempotent_and_a_finished_set_is_kept_unless_forced() {
    let dir = tempfile::tempdir().unwrap();
    let (plan_file, out) = planned(dir.path(), &[]);
    let task = &tasks(&plan_file)[0];
    assert_eq!(task.outputs, ["a-1.exr", "a-1.linear.jpg"]);
    assert!(run(&plan_file, 0, &[]).status.success());
    let first = files(&out);
    assert_eq!(first.len(), 2);
    let exr = out.join("a-1.exr");
    let when = modified(&exr);
    let again = run(&plan_file, 0, &[]);
    assert!(again.status.success());
    assert!(text(&again.stderr).contains("already done"));
    assert_eq!(files(&out), first);
    assert_eq!(modified(&exr), when, "a finished set is not written again");
    // A finished set is not replaced without --force, whatever it holds.
    std::fs::write(&exr, b"edited by hand").unwrap();
    assert!(run(&plan_file, 0, &[]).status.success());
    assert_eq!(std::fs::read(&exr).unwrap(), b"edited by hand");
    assert!(run(&plan_file, 0, &["--force"]).status.success());
    assert_eq!(files(&out), first, "forced: the same bytes again");
    // Another attempt running (holding the task's lock): retry later, nothing touched.
    let lock_path = {
        let mut name = filmback::atomic::stage_folder(&out, &task.id).into_os_string();
        name.push(".lock");
        PathBuf::from(name)
    };
    let lock = std::fs::File::create(&lock_path).unwrap();
    lock.try_lock().unwrap();
    let busy = run(&plan_file, 0, &["--force"]);
    assert_eq!(
        busy.status.code(),
        Some(i32::from(filmback::farm::EXIT_RETRY))
    );
    assert!(text(&busy.stderr).contains("another attempt"));
    drop(lock);
    assert_eq!(files(&out), first);
    // A killed attempt's unsealed staging folder: nothing visible, the next run publishes.
    for name in &task.outputs {
        std::fs::remove_file(out.join(name)).unwrap();
    }
    let stage = filmback::atomic::stage_folder(&out, &task.id);
    std::fs::create_dir_all(&stage).unwrap();
    std::fs::write(stage.join("a-1.exr"), b"half an EXR").unwrap();
    assert!(rig::visible(&out).is_empty());
    assert!(run(&plan_file, 0, &[]).status.success());
    assert_eq!(files(&out), first);
    assert!(!stage.exists());
    // Killed while renaming a sealed set into place: the next attempt finishes it.
    std::fs::create_dir_all(&stage).unwrap();
    for name in &task.outputs {
        std::fs::rename(out.join(name), stage.join(name)).unwrap();
    }
    filmback::atomic::seal_set(&stage).unwrap();
    std::fs::rename(stage.join("a-1.exr"), &exr).unwrap();
    let finished = run(&plan_file, 0, &[]);
    assert!(finished.status.success());
    assert!(text(&finished.stderr).contains("already done"));
    assert_eq!(files(&out), first);
    assert!(!stage.exists());
    // Killed while removing the staging folder of a published set: the next attempt
    // finds the set done and removes what is left.
    std::fs::create_dir_all(stage.join(".previous")).unwrap();
    let finished = run(&plan_file, 0, &[]);
    assert!(text(&finished.stderr).contains("already done"));
    assert_eq!(files(&out), first);
    assert!(!stage.exists());
}

/// `run` killed at any moment leaves the set whole or absent (or, killed between the
/// renames of a sealed set, a set the next attempt finishes), and the next run publishes.
#[test]
fn a_task_killed_at_any_moment_leaves_nothing_partial() {
    let dir = tempfile::tempdir().unwrap();
    let (plan_file, out) = planned(dir.path(), &[]);
    let task = &tasks(&plan_file)[0];
    for delay_ms in [2, 10, 25, 50, 100, 200] {
        for name in &task.outputs {
            let _ = std::fs::remove_file(out.join(name));
        }
        let mut child = filmback()
            .arg("run")
            .arg(&plan_file)
            .args(["--index", "0"])
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap();
        std::thread::sleep(std::time::Duration::from_millis(delay_ms));
        let _ = child.kill();
        child.wait().unwrap();
        // A kill between the renames of a sealed set (microseconds) leaves it for the
        // next attempt to finish, as the staging folder records.
        let seen = rig::visible(&out);
        let sealed = !filmback::atomic::interrupted_sets(&out).is_empty();
        assert!(
            seen.is_empty() || seen == task.outputs || sealed,
            "killed after {delay_ms} ms: {seen:?}"
        );
    }
    assert!(run(&plan_file, 0, &[]).status.success());
    assert_eq!(rig::visible(&out), task.outputs);
    assert!(!filmback::atomic::stage_folder(&out, &task.id).exists());
}

/// Input that retrying cannot fix exits with the bad-input status and says why: an index
/// out of range, a damaged or truncated plan, a frame changed since the plan, an index
/// variable that is not set. `--index-env` with `--index-base 1` runs task 0 for 1.
#[test]
fn bad_input_has_its_own_exit_status_and_a_reason() {
    let dir = tempfile::tempdir().unwrap();
    let (plan_file, out) = planned(dir.path(), &[]);
    let bad = |done: Output, says: &str| {
        assert_eq!(done.status.code(), Some(i32::from(EXIT_BAD_INPUT)));
        let err = text(&done.stderr);
        assert!(err.contains(says), "{err}");
    };
    bad(run(&plan_file, 2, &[]), "out of range");
    let missing = filmback()
        .arg("run")
        .arg(&plan_file)
        .args(["--index-env", "FILMBACK_TEST_NO_SUCH_INDEX"])
        .env_remove("FILMBACK_TEST_NO_SUCH_INDEX")
        .output()
        .unwrap();
    bad(missing, "FILMBACK_TEST_NO_SUCH_INDEX");
    let slurm = filmback()
        .arg("run")
        .arg(&plan_file)
        .args(["--index-env", "SLURM_ARRAY_TASK_ID", "--index-base", "1"])
        .env("SLURM_ARRAY_TASK_ID", "1")
        .output()
        .unwrap();
    assert!(slurm.status.success(), "{}", text(&slurm.stderr));
    assert!(out.join("a-1.exr").is_file());
    let lines: Vec<String> = std::fs::read_to_string(&plan_file)
        .unwrap()
        .lines()
        .map(String::from)
        .collect();
    let broken = dir.path().join("broken.jsonl");
    std::fs::write(&broken, format!("{}\n{{\"record\": \"ta\n", lines[0])).unwrap();
    bad(run(&broken, 0, &[]), "line 2");
    std::fs::write(&broken, format!("{}\n{}\n", lines[0], lines[1])).unwrap();
    bad(run(&broken, 1, &[]), "truncated");
    std::fs::write(&broken, lines[1..].join("\n")).unwrap();
    bad(run(&broken, 0, &[]), "header");
    let overlap = filmback()
        .arg("plan")
        .arg(dir.path().join("ingest"))
        .args(["-o", "/dev/null/never", "--out"])
        .arg(dir.path().join("ingest"))
        .output()
        .unwrap();
    assert!(!overlap.status.success());
    assert!(text(&overlap.stderr).contains("would be taken as frames"));
    // b-2.jpg replaced by another frame after the plan was made.
    let other = rig::aeb("EOS R5", 40, "x").remove(1).1;
    std::fs::write(dir.path().join("ingest/b-2.jpg"), other).unwrap();
    bad(run(&plan_file, 1, &[]), "changed since the plan");
    assert!(
        !out.join("b-1.exr").exists(),
        "nothing of a bad task is published"
    );
}

/// A pooled plan freezes one curve per body beside the plan; every task of the body
/// names it, and a task develops with it.
#[test]
fn a_pooled_plan_freezes_one_curve_per_body() {
    let dir = tempfile::tempdir().unwrap();
    let (plan_file, out) = planned(dir.path(), &["--response", "pooled"]);
    let records = records(&plan_file);
    let Record::Header(header) = &records[0] else {
        panic!("no header");
    };
    let ResponsePlan::Pooled { folder } = &header.response else {
        panic!("{:?}", header.response);
    };
    assert_eq!(folder, Path::new("plan.jsonl.d"));
    let planned = tasks(&plan_file);
    let file = planned[0].response.clone().expect("a frozen curve");
    assert!(planned.iter().all(|t| t.response.as_ref() == Some(&file)));
    assert!(dir.path().join(&file).is_file(), "{file}");
    let cache = ResponseCache::new(&dir.path().join(folder));
    let frozen = cache.get(&planned[0].camera).unwrap().expect("entry");
    assert_eq!(frozen.pool.len(), 2);
    assert!(run(&plan_file, 1, &[]).status.success());
    assert!(out.join("b-1.exr").is_file());
}

/// The Kubernetes manifest is an Indexed Job of the plan's task count (the `TASKS`
/// placeholder docs/farm.md fills from the header) whose pods run `filmback run` on
/// `JOB_COMPLETION_INDEX` (checked as text: no YAML parser is in the dependency tree).
#[test]
fn the_kubernetes_manifest_is_an_indexed_job_running_one_task_per_index() {
    let docs = Path::new(env!("CARGO_MANIFEST_DIR")).join("docs");
    let manifest = std::fs::read_to_string(docs.join("farm/k8s-indexed-job.yaml")).unwrap();
    let lines: Vec<&str> = manifest.lines().map(str::trim).collect();
    for line in [
        "apiVersion: batch/v1",
        "kind: Job",
        "completionMode: Indexed",
        "completions: TASKS",
        "restartPolicy: Never",
    ] {
        assert!(lines.contains(&line), "{line:?} missing");
    }
    let command = manifest
        .lines()
        .find(|l| l.contains("command:"))
        .expect("a command");
    for part in ["filmback", "run", "--index-env", "JOB_COMPLETION_INDEX"] {
        assert!(command.contains(part), "{command}");
    }
    let guide = std::fs::read_to_string(docs.join("farm.md")).unwrap();
    assert!(guide.contains("k8s-indexed-job.yaml") && guide.contains("s/TASKS/"));
}
