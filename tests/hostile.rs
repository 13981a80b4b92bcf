//! Hostile inputs and outputs (issue 32): a raw whose IFD chain loops, a damaged raw in a
//! RAW+JPEG bracket, frame names at the file system's limit, and an output set whose
//! publication was cut between its renames. Each through the command line or the
//! daemon, on the real file system.

use std::path::Path;
use std::sync::Arc;

use filmback::atomic;
use filmback::daemon::{DarkroomLab, Job, Lab};

use crate::common::filmback;
use crate::common::rig::{self, Rig};

/// A frame name of 246 characters (the stem 239, `-1.jpg`): legal, but its outputs'
/// names with a look and a temporary suffix would not fit in 255 bytes.
fn long_prefix() -> String {
    "x".repeat(240)
}

/// Checks `names` are one EXR and one linear rendering, each under 255 bytes and named
/// after the long stem.
fn assert_long_outputs(names: &[String]) {
    assert_eq!(names.len(), 2, "{names:?}");
    assert!(names.iter().any(|n| n.ends_with(".exr")), "{names:?}");
    assert!(
        names.iter().any(|n| n.ends_with(".linear.jpg")),
        "{names:?}"
    );
    for n in names {
        assert!(n.len() <= 255 && n.starts_with(&"x".repeat(100)), "{n}");
    }
}

/// `filmback merge` of frames with 246-character names writes its outputs under a
/// shortened stem instead of failing with "File name too long".
#[test]
fn merge_takes_frames_with_names_at_the_file_systems_limit() {
    let dir = tempfile::tempdir().unwrap();
    let frames = rig::aeb("Body L", 10, &long_prefix());
    rig::put(dir.path(), &frames);
    let out = dir.path().join("out");
    let o = filmback()
        .arg("merge")
        .args(frames.iter().map(|(n, _)| dir.path().join(n)))
        .args(["--tonemap", "linear", "-o"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_long_outputs(&rig::visible(&out));
}

/// The daemon develops a bracket whose frames have 246-character names (it retried the
/// staging folder's "File name too long" for ever).
#[test]
fn the_daemon_develops_frames_with_names_at_the_file_systems_limit() {
    let mut rig = Rig::start(Arc::new(DarkroomLab));
    rig::put(&rig.ingest(), &rig::aeb("Body L", 10, &long_prefix()));
    let names = rig::wait_for(&rig.out(), "the bracket's outputs", |n| n.len() == 2);
    assert_long_outputs(&names);
    rig.stop();
}

/// The job the daemon makes of a RAW+JPEG bracket of three in `dir` (`r-1.dng`,
/// `r-2.jpg`, `r-3.dng`) whose second raw was rejected as damaged, so that its JPEG
/// stands for the capture; with `companions`, the other captures' JPEGs beside their
/// raws (`r-1.jpg`, `r-3.jpg`).
#[cfg(feature = "raw")]
fn mixed_job(dir: &Path, companions: bool) -> Job {
    use filmback::daemon::bracket::{CameraId, Capture, Input};
    use filmback::daemon::config::Config;
    let shots = filmback::synthetic::demo::aeb("Body R", None, 20);
    let (jpegs, raws) = (rig::aeb("Body R", 20, "r"), rig::raw_aeb("Body R", 20, "r"));
    let input = |name: &str, bytes: &[u8]| {
        std::fs::write(dir.join(name), bytes).unwrap();
        Input {
            path: dir.join(name),
            size: bytes.len() as u64,
            modified_ns: 0,
        }
    };
    let camera = CameraId {
        make: Some("filmback".into()),
        model: Some("Body R".into()),
        serial: None,
    };
    let frames = (0..3)
        .map(|k| {
            let (frame, companion) = if k == 1 {
                (input(&jpegs[k].0, &jpegs[k].1), None)
            } else {
                let jpeg = companions.then(|| input(&jpegs[k].0, &jpegs[k].1));
                (input(&raws[k].0, &raws[k].1), jpeg)
            };
            Capture {
                input: frame,
                camera: camera.clone(),
                exposure: shots[k].exposure.relative(),
                time_s: 0.3 * k as f64,
                companion,
            }
        })
        .collect();
    let config = Config::from_str(&rig::config_text(dir, ""), None).unwrap();
    Job {
        id: format!("mixed{companions}"),
        camera,
        frames,
        preset: config.preset_for(Some("Body R"), None).clone(),
        cached: None,
        out: dir.join("out"),
        stem: "r-1".to_string(),
        stocks: None,
        previews: false,
    }
}

/// A RAW+JPEG bracket whose second raw was rejected (its JPEG stands for the capture) is
/// developed from every capture's JPEG, or without that capture when the others have no
/// JPEG, and the job's notes (a warning in the log) name what was left out; it failed
/// whole with "a bracket is either all raw or all JPEG/PNG/TIFF".
#[cfg(feature = "raw")]
#[test]
fn a_raw_plus_jpeg_bracket_with_a_rejected_raw_is_developed_from_the_rest() {
    let dir = tempfile::tempdir().unwrap();
    let done = DarkroomLab
        .process(&mixed_job(dir.path(), true))
        .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(
        rig::visible(&dir.path().join("out")),
        ["r-1.exr", "r-1.linear.jpg"]
    );
    assert_ne!(
        done.source,
        filmback::darkroom::Source::Raw,
        "from the JPEGs"
    );
    let notes = done.notes.join("\n");
    assert!(
        notes.contains("r-1.dng, ")
            && notes.contains("r-3.dng left out")
            && notes.contains("r-2.jpg"),
        "{notes}"
    );
    let dir = tempfile::tempdir().unwrap();
    let done = DarkroomLab
        .process(&mixed_job(dir.path(), false))
        .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(
        rig::visible(&dir.path().join("out")),
        ["r-1.exr", "r-1.linear.jpg"]
    );
    assert_eq!(
        done.source,
        filmback::darkroom::Source::Raw,
        "from the raws"
    );
    let notes = done.notes.join("\n");
    assert!(notes.contains("r-2.jpg left out"), "{notes}");
}

/// A DNG whose first IFD's "next IFD" points to itself in ingest: the daemon (the real
/// binary, under a 4 GB limit it exceeded within seconds) rejects it with that reason
/// and develops the bracket after it.
#[cfg(feature = "raw")]
#[test]
fn a_dng_whose_ifd_chain_loops_is_rejected_by_the_daemon() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    std::fs::create_dir_all(root.join("ingest")).unwrap();
    let (_, mut dng) = rig::raw_aeb("Body D", 10, "d").swap_remove(0);
    let first: [u8; 4] = dng[4..8].try_into().unwrap();
    assert_eq!(&dng[..2], b"II", "rawler writes little-endian DNGs");
    let offset = u32::from_le_bytes(first) as usize;
    let entries = usize::from(u16::from_le_bytes([dng[offset], dng[offset + 1]]));
    let next = offset + 2 + 12 * entries;
    dng[next..next + 4].copy_from_slice(&first);
    rig::put(&root.join("ingest"), &[("loop.dng".to_string(), dng)]);
    let watch = rig::CappedWatch::start(root);
    rig::put(&root.join("ingest"), &rig::aeb("Body J", 30, "j"));
    let names = rig::wait_for(&root.join("out"), "the JPEG bracket's outputs", |n| {
        n.len() == 2
    });
    assert_eq!(names, ["j-1.exr", "j-1.linear.jpg"]);
    drop(watch);
    let rejected = rig::rejected(&root.join("state"));
    assert!(
        rejected
            .iter()
            .any(|(name, why)| name == "loop.dng" && why.contains("loops back to the IFD")),
        "{rejected:?}"
    );
}

/// A bracket's outputs whose publication was cut after the first rename (a `kill -9`
/// there; the set sealed by the real code, then one file moved as the first rename
/// does): `filmback status` names the set and what is missing, and the daemon's next
/// start completes it.
#[test]
fn status_names_a_set_cut_between_renames_and_the_next_start_completes_it() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    let mut rig = Rig::start_in(root, Arc::new(DarkroomLab));
    rig::put(&rig.ingest(), &rig::aeb("Body S", 10, "s"));
    rig::wait_for(&rig.out(), "the bracket's outputs", |n| n.len() == 2);
    rig.stop();
    let out = rig.out();
    let stage = atomic::stage_folder(&out, "00c0ffee00c0ffee");
    std::fs::create_dir(&stage).unwrap();
    for (from, to) in [("s-1.exr", "t-1.exr"), ("s-1.linear.jpg", "t-1.linear.jpg")] {
        std::fs::copy(out.join(from), stage.join(to)).unwrap();
    }
    atomic::seal_set(&stage).unwrap();
    std::fs::rename(stage.join("t-1.exr"), out.join("t-1.exr")).unwrap();
    let status = |json: bool| {
        let mut cmd = filmback();
        cmd.arg("status").arg("--state").arg(rig.state());
        if json {
            cmd.arg("--json");
        }
        let o = cmd.output().unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        String::from_utf8(o.stdout).unwrap()
    };
    let report: serde_json::Value = serde_json::from_str(&status(true)).unwrap();
    let sets = report["interrupted_sets"].as_array().expect("listed");
    assert_eq!(sets.len(), 1, "{report}");
    let path = |name: &str| serde_json::json!([out.join(name).display().to_string()]);
    assert_eq!(sets[0]["published"], path("t-1.exr"), "{report}");
    assert_eq!(sets[0]["pending"], path("t-1.linear.jpg"), "{report}");
    let text = status(false);
    assert!(
        text.contains("interrupted   1 output set") && text.contains("t-1.linear.jpg"),
        "{text}"
    );
    let mut rig = Rig::start_in(root, Arc::new(DarkroomLab));
    rig::wait_for(&out, "the set completed", |n| {
        n.iter().any(|n| n == "t-1.linear.jpg")
    });
    rig.stop();
    let report: serde_json::Value = serde_json::from_str(&status(true)).unwrap();
    assert_eq!(
        report["interrupted_sets"],
        serde_json::json!([]),
        "{report}"
    );
    assert!(!Path::new(&stage).exists());
}
