//! Fault tests of the watch-folder daemon on the real file system.
//!
//! Each test drives the daemon (in-process, or the real binary where a process must be
//! killed or run as another user) through a temporary folder and asserts the exact set
//! of outputs: nothing missing, nothing twice, no temporary file left, every EXR readable.
//! Frames are small JPEGs with EXIF from `filmback::synthetic::demo`; settle times are short.

use std::collections::BTreeSet;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use filmback::atomic::{self, Overwrite};
use filmback::daemon::config::Config;
use filmback::daemon::journal::{self, Entry};
use filmback::daemon::{self, Control, DarkroomLab, Job, JobError, Lab, Processed};
use filmback::frame::BitDepth;
use filmback::synthetic::demo;
use filmback::synthetic::{self, Encoding, ResponseCurve, Sensor};

use crate::common::rig;

const W: u16 = 96;
const H: u16 = 64;

/// The rig's settings ([`rig::config_text`]: short settle and gap, small queue, no
/// viewer). `overrides` are `(section, line)`
/// pairs: the line replaces that key's default line (or is added to the section).
fn config_text(root: &Path, overrides: &[(&str, &str)]) -> String {
    let mut text = rig::config_text(root, "");
    for (section, line) in overrides {
        let key = line.split('=').next().unwrap().trim();
        text = text
            .lines()
            .filter(|l| l.split('=').next().unwrap().trim() != key)
            .collect::<Vec<_>>()
            .join("\n");
        text = text.replace(&format!("[{section}]"), &format!("[{section}]\n{line}"));
    }
    text
}

struct Rig {
    _dir: tempfile::TempDir,
    root: PathBuf,
    control: tokio::sync::mpsc::Sender<Control>,
    thread: Option<std::thread::JoinHandle<daemon::Summary>>,
}

impl Rig {
    /// Starts the daemon in-process (its own runtime on a thread).
    fn start(overrides: &[(&str, &str)], lab: Arc<dyn Lab>, before: impl FnOnce(&Path)) -> Rig {
        Rig::start_with(overrides, "", lab, before)
    }

    /// As [`Rig::start`], with `tables` (e.g. camera presets) appended to the config.
    fn start_with(
        overrides: &[(&str, &str)],
        tables: &str,
        lab: Arc<dyn Lab>,
        before: impl FnOnce(&Path),
    ) -> Rig {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path().to_path_buf();
        std::fs::create_dir_all(root.join("ingest")).unwrap();
        before(&root);
        let text = config_text(&root, overrides) + "\n" + tables;
        let config =
            Config::from_str(&text, Some(Path::new("test.toml"))).expect("test config is valid");
        let (control, rx) = tokio::sync::mpsc::channel(4);
        let thread = std::thread::spawn(move || {
            let rt = tokio::runtime::Builder::new_multi_thread()
                .worker_threads(2)
                .enable_all()
                .build()
                .unwrap();
            rt.block_on(daemon::run(config, lab, rx))
                .expect("daemon ran")
        });
        // Frames put before the watcher runs would be found by the start-up scan with no
        // writer's close seen, and wait the whole settle window.
        wait_for_status(&root.join("state"), |s| s.watching);
        Rig {
            _dir: dir,
            root,
            control,
            thread: Some(thread),
        }
    }

    fn ingest(&self) -> PathBuf {
        self.root.join("ingest")
    }

    fn out(&self) -> PathBuf {
        self.root.join("out")
    }

    fn state(&self) -> PathBuf {
        self.root.join("state")
    }

    fn stop(&mut self) -> daemon::Summary {
        self.control.blocking_send(Control::Stop).unwrap();
        self.thread.take().unwrap().join().unwrap()
    }
}

/// A three-frame AEB of `model` at `second`, named `<prefix>-1.jpg` …
fn aeb(model: &str, second: u32, prefix: &str) -> Vec<(String, Vec<u8>)> {
    let shots = demo::aeb(model, None, second);
    demo::jpegs(u32::from(W), u32::from(H), &shots, u64::from(second))
        .unwrap()
        .into_iter()
        .enumerate()
        .map(|(i, bytes)| (format!("{prefix}-{}.jpg", i + 1), bytes))
        .collect()
}

fn put(dir: &Path, frames: &[(String, Vec<u8>)]) {
    for (name, bytes) in frames {
        demo::drop_frame(dir, name, bytes).unwrap();
    }
}

fn bracket_outputs(stems: &[&str]) -> BTreeSet<String> {
    stems
        .iter()
        .flat_map(|s| [format!("{s}.exr"), format!("{s}.linear.jpg")])
        .collect()
}

fn listing(dir: &Path) -> BTreeSet<String> {
    std::fs::read_dir(dir)
        .map(|d| {
            d.filter_map(Result::ok)
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .collect()
        })
        .unwrap_or_default()
}

/// Waits until `out` holds exactly `expected`, then a little longer to see that nothing
/// else appears; checks no temporary file is left and every EXR reads back.
fn expect_outputs(out: &Path, expected: &BTreeSet<String>, timeout: Duration) {
    let start = Instant::now();
    while listing(out) != *expected {
        assert!(
            start.elapsed() < timeout,
            "timed out after {timeout:?}: out holds {:?}, expected {expected:?}",
            listing(out)
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    std::thread::sleep(Duration::from_millis(1500));
    assert_eq!(listing(out), *expected, "nothing extra appears later");
    for name in expected.iter().filter(|n| n.ends_with(".exr")) {
        let image = exr::prelude::read_all_flat_layers_from_file(out.join(name))
            .unwrap_or_else(|e| panic!("{name} unreadable: {e}"));
        let size = image.layer_data[0].size;
        assert_eq!(
            (size.x(), size.y()),
            (usize::from(W), usize::from(H)),
            "{name}"
        );
    }
}

/// Every input developed at most once, and the journal's brackets by first input stem.
fn journaled_brackets(state: &Path) -> Vec<String> {
    let entries = journal::read(state).unwrap();
    let mut seen = BTreeSet::new();
    let mut stems = Vec::new();
    for e in &entries {
        match e {
            Entry::Bracket { inputs, .. } => {
                for i in inputs {
                    assert!(
                        seen.insert(i.clone()),
                        "{} developed twice",
                        i.path.display()
                    );
                }
                stems.push(
                    inputs[0]
                        .path
                        .file_stem()
                        .unwrap()
                        .to_string_lossy()
                        .into_owned(),
                );
            }
            Entry::Single { input, .. } => {
                assert!(
                    seen.insert(input.clone()),
                    "{} developed twice",
                    input.path.display()
                );
            }
            _ => {}
        }
    }
    stems.sort();
    stems
}

fn rejected(state: &Path) -> Vec<(String, String)> {
    journal::read(state)
        .unwrap()
        .into_iter()
        .filter_map(|e| match e {
            Entry::Rejected { input, reason, .. } => Some((
                input
                    .path
                    .file_name()
                    .unwrap()
                    .to_string_lossy()
                    .into_owned(),
                reason,
            )),
            _ => None,
        })
        .collect()
}

const T: Duration = Duration::from_secs(30);

#[test]
fn files_present_before_start_are_developed() {
    let mut rig = Rig::start(&[], Arc::new(DarkroomLab), |root| {
        put(&root.join("ingest"), &aeb("Body A", 10, "a"));
        put(&root.join("ingest"), &aeb("Body A", 20, "b"));
    });
    expect_outputs(&rig.out(), &bracket_outputs(&["a-1", "b-1"]), T);
    let state = rig.state();
    let summary = rig.stop();
    assert_eq!(summary.finished, 2);
    assert_eq!(journaled_brackets(&state), ["a-1", "b-1"]);
}

/// A RAW+JPEG bracket of `model` dropped into `dir`, each capture's raw then its JPEG.
#[cfg(feature = "raw")]
fn put_raw_plus_jpeg(dir: &Path, model: &str, second: u32, prefix: &str) {
    let jpegs = aeb(model, second, prefix);
    for (raw, jpeg) in raw_aeb(model, second, prefix).iter().zip(&jpegs) {
        put(dir, std::slice::from_ref(raw));
        put(dir, std::slice::from_ref(jpeg));
    }
}

/// A three-frame AEB as DNGs (`<prefix>-1.dng` …) from a 14-bit RGGB sensor, the longest
/// frame's mid-grey at 0.18 of full scale.
#[cfg(feature = "raw")]
fn raw_aeb(model: &str, second: u32, prefix: &str) -> Vec<(String, Vec<u8>)> {
    let shots = demo::aeb(model, None, second);
    let scene = synthetic::scene(u32::from(W), u32::from(H), u64::from(second));
    let sensor = synthetic::RawSensor::typical(u64::from(second));
    let longest = shots
        .iter()
        .map(|s| s.exposure.relative().unwrap())
        .fold(0.0, f64::max);
    shots
        .iter()
        .enumerate()
        .map(|(i, shot)| {
            let signal =
                synthetic::raw_signal(&scene, shot.exposure.relative().unwrap() / longest, &sensor);
            let codes = synthetic::raw_codes(&signal, &sensor);
            let dng = synthetic::dng(&codes, u32::from(W), u32::from(H), &sensor, shot).unwrap();
            (format!("{prefix}-{}.dng", i + 1), dng)
        })
        .collect()
}

/// A raw-only bracket dropped into ingest gives exactly one EXR ("linear (raw)") and the
/// configured look.
#[cfg(feature = "raw")]
#[test]
fn raw_only_bracket_gives_one_exr_and_the_looks() {
    use exr::prelude::{ReadChannels, ReadLayers};
    let mut rig = Rig::start(&[], Arc::new(DarkroomLab), |_| {});
    put(&rig.ingest(), &raw_aeb("Raw Body", 10, "r"));
    expect_outputs(&rig.out(), &bracket_outputs(&["r-1"]), T);
    let image = exr::prelude::read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_file(rig.out().join("r-1.exr"))
        .unwrap();
    let response = image
        .layer_data
        .attributes
        .other
        .get(&exr::prelude::Text::from("filmbackResponse"))
        .cloned();
    assert_eq!(
        response,
        Some(exr::prelude::AttributeValue::Text(
            exr::prelude::Text::from("linear (raw)")
        ))
    );
    let state = rig.state();
    let summary = rig.stop();
    assert_eq!(summary.finished, 1);
    assert!(rejected(&state).is_empty(), "{:?}", rejected(&state));
}

/// Each frame a lab was given, by file name, with its companion's file name.
#[cfg(feature = "raw")]
type FramesSeen = Arc<std::sync::Mutex<Vec<(String, Option<String>)>>>;

/// The real lab, recording each job's frames with their companions.
#[cfg(feature = "raw")]
fn companion_recording_darkroom() -> (FramesSeen, Arc<dyn Lab>) {
    let seen = Arc::new(std::sync::Mutex::new(Vec::new()));
    let record = Arc::clone(&seen);
    let name = |p: &Path| p.file_name().unwrap().to_string_lossy().into_owned();
    let lab = move |job: &Job| -> Result<Processed, JobError> {
        record.lock().unwrap().extend(job.frames.iter().map(|f| {
            (
                name(&f.input.path),
                f.companion.as_ref().map(|c| name(&c.path)),
            )
        }));
        DarkroomLab.process(job)
    };
    (seen, Arc::new(lab))
}

/// Checks a RAW+JPEG bracket's journal: one bracket of the three raws, no file rejected
/// (the JPEGs are companions, not rejects).
#[cfg(feature = "raw")]
fn assert_one_raw_bracket(state: &Path) {
    assert_eq!(journaled_brackets(state), ["r-1"]);
    let rejected = rejected(state);
    assert!(rejected.is_empty(), "{rejected:?}");
    let entries = journal::read(state).unwrap();
    let inputs: Vec<String> = entries
        .iter()
        .flat_map(Entry::inputs)
        .map(|i| i.path.file_name().unwrap().to_string_lossy().into_owned())
        .collect();
    assert_eq!(inputs, ["r-1.dng", "r-2.dng", "r-3.dng"]);
}

/// RAW+JPEG, the raw first: each capture arrives as `r-k.dng` then `r-k.jpg` in one
/// folder; the raws make the one bracket, the JPEGs are set aside as their companions
/// (never a second bracket, never a reject).
#[cfg(feature = "raw")]
#[test]
fn raw_plus_jpeg_gives_one_bracket_from_the_raws() {
    let mut rig = Rig::start(&[], Arc::new(DarkroomLab), |_| {});
    put_raw_plus_jpeg(&rig.ingest(), "Raw Body", 10, "r");
    expect_outputs(&rig.out(), &bracket_outputs(&["r-1"]), T);
    let state = rig.state();
    let summary = rig.stop();
    assert_eq!((summary.finished, summary.rejected), (1, 0));
    assert_one_raw_bracket(&state);
    // The JPEGs are the camera's rendering of the same captures (the demo camera's sRGB
    // curve): measured against the raws, they give the body's JPEG curve in the cache.
    let cached = filmback::daemon::cache::ResponseCache::new(&state)
        .find("Raw Body")
        .unwrap();
    let measured = cached.measured.expect("a curve measured from RAW+JPEG");
    assert_eq!(measured.captures, 3);
    for c in 0..3 {
        for code in [64u32, 128, 192] {
            let b = f64::from(code) / 255.0;
            let stops = (measured.response.eval(c, b) / ResponseCurve::Srgb.inverse(b)).log2();
            assert!(
                stops.abs() < 0.25,
                "channel {c} code {code}: {stops:+.3} stop"
            );
        }
    }
}

/// RAW+JPEG in sibling folders (`RAW/r-k.dng`, `JPG/r-k.jpg`), the JPEG first and
/// settled before its raw arrives: the first JPEG gives way to its raw in the open
/// bracket, the later ones wait for theirs (the body is known to shoot RAW+JPEG); one
/// EXR from the raws, and the lab is told each raw's JPEG.
#[cfg(feature = "raw")]
#[test]
fn raw_plus_jpeg_in_sibling_folders_jpeg_first_gives_one_bracket_from_the_raws() {
    let (seen, lab) = companion_recording_darkroom();
    let mut rig = Rig::start(
        &[
            ("watch", "recursive = true"),
            ("bracket", "max_gap_s = 4.0"),
        ],
        lab,
        |root| {
            std::fs::create_dir_all(root.join("ingest/RAW")).unwrap();
            std::fs::create_dir_all(root.join("ingest/JPG")).unwrap();
        },
    );
    let jpegs = aeb("Raw Body", 10, "r");
    let raws = raw_aeb("Raw Body", 10, "r");
    for (raw, jpeg) in raws.iter().zip(&jpegs) {
        put(&rig.ingest().join("JPG"), std::slice::from_ref(jpeg));
        // Settle time 150 ms: the JPEG is taken before its raw appears.
        std::thread::sleep(Duration::from_millis(600));
        put(&rig.ingest().join("RAW"), std::slice::from_ref(raw));
        std::thread::sleep(Duration::from_millis(300));
    }
    expect_outputs(&rig.out(), &bracket_outputs(&["r-1"]), T);
    let state = rig.state();
    let summary = rig.stop();
    assert_eq!((summary.finished, summary.rejected), (1, 0));
    assert_one_raw_bracket(&state);
    let seen = seen.lock().unwrap().clone();
    let expected: Vec<(String, Option<String>)> = (1..=3)
        .map(|k| (format!("r-{k}.dng"), Some(format!("r-{k}.jpg"))))
        .collect();
    assert_eq!(seen, expected);
    // The JPEGs in the sibling folder were measured against their raws.
    let cached = filmback::daemon::cache::ResponseCache::new(&state)
        .find("Raw Body")
        .unwrap();
    assert_eq!(cached.measured.map(|m| m.captures), Some(3));
}

/// A body seen shooting RAW+JPEG then shoots JPEG only: its JPEGs wait the bracket gap
/// for a raw that never comes, then are frames; nothing is lost or rejected. That
/// JPEG-only bracket is developed with the body's curve measured from the RAW+JPEG
/// captures (the EXR header and the journal say so), not with a fitted or standard one.
#[cfg(feature = "raw")]
#[test]
fn jpegs_of_a_raw_plus_jpeg_body_are_frames_after_the_gap_with_its_measured_curve() {
    let mut rig = Rig::start(&[], Arc::new(DarkroomLab), |_| {});
    put_raw_plus_jpeg(&rig.ingest(), "Raw Body", 10, "r");
    expect_outputs(&rig.out(), &bracket_outputs(&["r-1"]), T);
    put(&rig.ingest(), &aeb("Raw Body", 30, "j"));
    expect_outputs(&rig.out(), &bracket_outputs(&["r-1", "j-1"]), T);
    let meta = exr::meta::MetaData::read_from_file(rig.out().join("j-1.exr"), false).unwrap();
    let response = match meta.headers[0]
        .own_attributes
        .other
        .get(&exr::prelude::Text::from("filmbackResponse"))
    {
        Some(exr::prelude::AttributeValue::Text(t)) => t.to_string(),
        other => panic!("filmbackResponse: {other:?}"),
    };
    assert!(
        response.starts_with("measured curve of ")
            && response.ends_with("(raw+JPEG, 3 capture(s))"),
        "{response}"
    );
    let state = rig.state();
    let summary = rig.stop();
    assert_eq!((summary.finished, summary.rejected), (2, 0));
    assert_eq!(journaled_brackets(&state), ["j-1", "r-1"]);
    assert_eq!(
        response_of(&state, "j-1"),
        filmback::darkroom::Source::Cached
    );
}

/// gphoto2, Capture One, macOS and Windows leave files beside the frames: none of them is
/// a frame or a reject, and Capture One's folder is not descended into, even with an empty
/// `ignore` list.
#[test]
fn tethering_tools_litter_is_neither_a_frame_nor_a_reject() {
    let mut rig = Rig::start(
        &[("watch", "recursive = true"), ("watch", "ignore = []")],
        Arc::new(DarkroomLab),
        |root| {
            let ingest = root.join("ingest");
            let c1 = ingest.join("CaptureOne");
            std::fs::create_dir_all(c1.join("Settings153")).unwrap();
            std::fs::create_dir_all(c1.join("Cache/Proxies")).unwrap();
            std::fs::write(c1.join("Settings153/t-1.jpg.cos"), b"<xml/>").unwrap();
            std::fs::write(c1.join("Settings153/t-1.jpg.comask"), b"mask").unwrap();
            std::fs::write(c1.join("Cache/Proxies/t-1.jpg.cop"), b"preview").unwrap();
            // A name the extension test takes, inside the tool's folder.
            std::fs::write(c1.join("Cache/Proxies/t-1.jpg"), b"not a frame").unwrap();
            for (name, bytes) in [
                ("._t-1.jpg", &b"AppleDouble"[..]),
                (".DS_Store", b"Bud1"),
                ("Thumbs.db", b"thumbs"),
                ("t-1.xmp", b"<x:xmpmeta/>"),
                ("t-1.jpg.xmp", b"<x:xmpmeta/>"),
                ("tmpfileQ3xZ9a", b"half a download"),
                ("t-9.jpg.part", b"partial"),
                ("t-9.jpg.crdownload", b"partial"),
                ("t-9.jpg.tmp", b"partial"),
            ] {
                std::fs::write(ingest.join(name), bytes).unwrap();
            }
        },
    );
    put(&rig.ingest(), &aeb("Body A", 10, "t"));
    expect_outputs(&rig.out(), &bracket_outputs(&["t-1"]), T);
    let state = rig.state();
    let summary = rig.stop();
    assert_eq!((summary.finished, summary.rejected), (1, 0));
    assert!(rejected(&state).is_empty(), "{:?}", rejected(&state));
    assert_eq!(journaled_brackets(&state), ["t-1"]);
}

/// gphoto2 across file systems: the frame is copied under its final name in pieces, and
/// its mtime is the capture time (an hour ago) all along. It is taken only once complete.
#[test]
fn a_file_written_in_pieces_with_an_old_mtime_is_taken_only_when_complete() {
    let mut rig = Rig::start(
        &[("watch", "settle_ms = 400")],
        Arc::new(DarkroomLab),
        |_| {},
    );
    let frames = aeb("Body A", 10, "g");
    put(&rig.ingest(), &frames[..2]);
    let (name, bytes) = &frames[2];
    let past = std::time::SystemTime::now() - Duration::from_secs(3600);
    let mut f = std::fs::File::create(rig.ingest().join(name)).unwrap();
    for chunk in bytes.chunks(bytes.len().div_ceil(12)) {
        f.write_all(chunk).unwrap();
        f.set_modified(past).unwrap();
        std::thread::sleep(Duration::from_millis(150));
    }
    drop(f);
    expect_outputs(&rig.out(), &bracket_outputs(&["g-1"]), T);
    let state = rig.state();
    rig.stop();
    assert!(rejected(&state).is_empty(), "{:?}", rejected(&state));
    let entries = journal::read(&state).unwrap();
    assert!(
        matches!(&entries[..], [Entry::Bracket { inputs, .. }] if inputs.len() == 3),
        "{entries:?}"
    );
}

/// digiCamControl: the file appears whole, then its EXIF is rewritten in place just after.
/// The second version is the one developed, and only once.
#[test]
fn exif_rewritten_just_after_the_file_appears_develops_the_second_version_once() {
    let (calls, lab) = counting_darkroom();
    let mut rig = Rig::start(&[("watch", "settle_ms = 300")], lab, |_| {});
    let frames = aeb("Body A", 10, "d");
    put(&rig.ingest(), &frames[..2]);
    // The first version carries another capture time (30 s later: not of this bracket).
    let (name, second) = &frames[2];
    let first = &aeb("Body A", 40, "d")[2].1;
    std::fs::write(rig.ingest().join(name), first).unwrap();
    std::thread::sleep(Duration::from_millis(100));
    std::fs::write(rig.ingest().join(name), second).unwrap();
    expect_outputs(&rig.out(), &bracket_outputs(&["d-1"]), T);
    let state = rig.state();
    rig.stop();
    assert_eq!(calls.load(Ordering::SeqCst), 1, "developed once");
    let entries = journal::read(&state).unwrap();
    match &entries[..] {
        [
            Entry::Bracket {
                inputs, digests, ..
            },
        ] => {
            assert_eq!(inputs.len(), 3);
            assert_eq!(
                digests[2],
                journal::content_digest(second),
                "the second version"
            );
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn a_frame_its_writer_closed_is_taken_without_the_whole_settle_window() {
    // A minute of settling for files nobody says are finished; frames written and closed
    // (or renamed into place) are taken a quarter of a second after the close.
    let (calls, lab) = counting_darkroom();
    let mut rig = Rig::start(&[("watch", "settle_ms = 60000")], lab, |_| {});
    put(&rig.ingest(), &aeb("Body A", 10, "c"));
    expect_outputs(&rig.out(), &bracket_outputs(&["c-1"]), T);
    rig.stop();
    assert_eq!(calls.load(Ordering::SeqCst), 1);
}

#[test]
fn a_frame_handed_over_by_the_hook_is_taken_at_once() {
    // `filmback hook` (atomic::move_into) renames each download into place from a
    // filmback temporary name, which the daemon takes without the settle window; a hard
    // link (as before) waited the whole minute. (That it skips the quarter second a
    // closed file waits too is intake's and settling's unit tests' and the bench's.)
    let (calls, lab) = counting_darkroom();
    let mut rig = Rig::start(&[("watch", "settle_ms = 60000")], lab, |root| {
        std::fs::create_dir_all(root.join("downloads")).unwrap();
    });
    let downloads = rig.root.join("downloads");
    for (name, bytes) in &aeb("Body A", 10, "h") {
        let download = downloads.join(name);
        std::fs::write(&download, bytes).unwrap();
        let moved = atomic::move_into(&download, &rig.ingest()).unwrap();
        assert_eq!(moved, rig.ingest().join(name));
    }
    expect_outputs(&rig.out(), &bracket_outputs(&["h-1"]), T);
    rig.stop();
    assert_eq!(calls.load(Ordering::SeqCst), 1);
    assert_eq!(std::fs::read_dir(&downloads).unwrap().count(), 0);
}

#[test]
fn slow_writer_is_taken_only_when_complete() {
    let mut rig = Rig::start(
        &[("watch", "settle_ms = 400")],
        Arc::new(DarkroomLab),
        |_| {},
    );
    let frames = aeb("Body A", 10, "s");
    put(&rig.ingest(), &frames[..2]);
    // The third frame trickles in over 3 s through one open handle.
    let (name, bytes) = &frames[2];
    let mut f = std::fs::File::create(rig.ingest().join(name)).unwrap();
    let chunks: Vec<&[u8]> = bytes.chunks(bytes.len().div_ceil(20)).collect();
    for chunk in chunks {
        f.write_all(chunk).unwrap();
        f.flush().unwrap();
        std::thread::sleep(Duration::from_millis(150));
    }
    drop(f);
    expect_outputs(&rig.out(), &bracket_outputs(&["s-1"]), T);
    let state = rig.state();
    rig.stop();
    assert!(rejected(&state).is_empty(), "{:?}", rejected(&state));
    // All three frames in one bracket: the partial file was never taken.
    let entries = journal::read(&state).unwrap();
    assert!(matches!(&entries[..], [Entry::Bracket { inputs, .. }] if inputs.len() == 3));
}

#[test]
fn temporary_names_wait_for_the_rename() {
    let mut rig = Rig::start(&[], Arc::new(DarkroomLab), |_| {});
    let frames = aeb("Body A", 10, "r");
    // Written under temporary names first; nothing may happen yet.
    for (i, (name, bytes)) in frames.iter().enumerate() {
        let tmp = match i {
            0 => format!("{name}.tmp"),
            1 => format!(".{name}"),
            _ => format!("{name}.part"),
        };
        std::fs::write(rig.ingest().join(tmp), bytes).unwrap();
    }
    std::fs::write(
        rig.ingest().join("never-renamed.jpg.crdownload"),
        &frames[0].1,
    )
    .unwrap();
    std::thread::sleep(Duration::from_millis(1000));
    assert!(listing(&rig.out()).is_empty());
    for (i, (name, _)) in frames.iter().enumerate() {
        let tmp = match i {
            0 => format!("{name}.tmp"),
            1 => format!(".{name}"),
            _ => format!("{name}.part"),
        };
        std::fs::rename(rig.ingest().join(tmp), rig.ingest().join(name)).unwrap();
    }
    expect_outputs(&rig.out(), &bracket_outputs(&["r-1"]), T);
    let state = rig.state();
    rig.stop();
    assert_eq!(journaled_brackets(&state), ["r-1"]);
}

#[test]
fn corrupt_frames_are_set_aside_and_the_rest_developed() {
    let mut rig = Rig::start(&[], Arc::new(DarkroomLab), |_| {});
    let frames = aeb("Body A", 10, "c");
    let good = aeb("Body A", 30, "d");
    // c-2 is garbage with a JPEG name: rejected at the header; c-1 and c-3 still merge.
    put(&rig.ingest(), &[frames[0].clone()]);
    demo::drop_frame(&rig.ingest(), "c-2.jpg", b"this is not a JPEG at all").unwrap();
    put(&rig.ingest(), &[frames[2].clone()]);
    // d-2 has a valid header but its data is cut short: the decoder rejects it during
    // development, and d-1 with d-3 is developed without it.
    let mut cut = good[1].1.clone();
    cut.truncate(cut.len() / 3);
    put(
        &rig.ingest(),
        &[
            good[0].clone(),
            ("d-2.jpg".to_string(), cut),
            good[2].clone(),
        ],
    );
    expect_outputs(&rig.out(), &bracket_outputs(&["c-1", "d-1"]), T);
    let state = rig.state();
    rig.stop();
    let names: Vec<String> = rejected(&state).into_iter().map(|(n, _)| n).collect();
    assert!(names.contains(&"c-2.jpg".to_string()), "{names:?}");
    assert!(names.contains(&"d-2.jpg".to_string()), "{names:?}");
    assert_eq!(names.len(), 2, "{names:?}");
    assert_eq!(journaled_brackets(&state), ["c-1", "d-1"]);
    // `status` lists them with reasons.
    let out = Command::new(env!("CARGO_BIN_EXE_filmback"))
        .args(["status", "--json", "--state"])
        .arg(&state)
        .output()
        .unwrap();
    let status: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(status["brackets_done"], 2);
    let listed: Vec<&str> = status["rejected"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r["file"].as_str().unwrap())
        .collect();
    assert!(listed.iter().any(|f| f.ends_with("c-2.jpg")), "{listed:?}");
    assert!(
        status["rejected"][0]["reason"]
            .as_str()
            .unwrap()
            .contains("not a JPEG"),
        "{status}"
    );
}

#[test]
fn interleaved_cameras_and_repeated_exposure() {
    let mut rig = Rig::start(&[], Arc::new(DarkroomLab), |_| {});
    let a = aeb("Body A", 10, "a");
    let b = aeb("Body B", 10, "b");
    for i in 0..3 {
        put(&rig.ingest(), &[a[i].clone(), b[i].clone()]);
    }
    // Body C: −2, 0, 0 (repeat), +2 EV → brackets [x-1, x-2] and [y-2, y-3].
    let c = aeb("Body C", 40, "x");
    let c2 = aeb("Body C", 41, "y");
    put(
        &rig.ingest(),
        &[c[0].clone(), c[1].clone(), c2[1].clone(), c2[2].clone()],
    );
    expect_outputs(
        &rig.out(),
        &bracket_outputs(&["a-1", "b-1", "x-1", "y-2"]),
        T,
    );
    let state = rig.state();
    rig.stop();
    assert_eq!(journaled_brackets(&state), ["a-1", "b-1", "x-1", "y-2"]);
}

/// The real lab, counting the jobs it is given.
fn counting_darkroom() -> (Arc<AtomicUsize>, Arc<dyn Lab>) {
    let calls = Arc::new(AtomicUsize::new(0));
    let counted = Arc::clone(&calls);
    let lab = move |job: &Job| -> Result<Processed, JobError> {
        counted.fetch_add(1, Ordering::SeqCst);
        DarkroomLab.process(job)
    };
    (calls, Arc::new(lab))
}

#[test]
fn output_write_error_is_retried_and_the_daemon_stays_alive() {
    let (calls, lab) = counting_darkroom();
    let mut rig = Rig::start(&[], lab, |root| {
        // The EXR's name is occupied by a folder: publishing fails with a real I/O error
        // (as on a full or read-only file system) until the folder goes away.
        std::fs::create_dir_all(root.join("out/e-1.exr")).unwrap();
    });
    put(&rig.ingest(), &aeb("Body A", 10, "e"));
    let start = Instant::now();
    while calls.load(Ordering::SeqCst) < 2 {
        assert!(start.elapsed() < T, "no retry happened");
        std::thread::sleep(Duration::from_millis(50));
    }
    // Meanwhile other work goes on.
    put(&rig.ingest(), &aeb("Body A", 30, "f"));
    let start = Instant::now();
    while !rig.out().join("f-1.exr").exists() {
        assert!(start.elapsed() < T, "daemon stalled");
        std::thread::sleep(Duration::from_millis(50));
    }
    std::fs::remove_dir(rig.out().join("e-1.exr")).unwrap();
    expect_outputs(&rig.out(), &bracket_outputs(&["e-1", "f-1"]), T);
    let state = rig.state();
    rig.stop();
    assert_eq!(journaled_brackets(&state), ["e-1", "f-1"]);
    assert!(calls.load(Ordering::SeqCst) >= 3);
}

/// Another filmback on the same output folder (a farm task, a second daemon) holds the
/// staging folders it develops into locked: the daemon's start-up recovery leaves them
/// alone, and a bracket whose folder is held is retried once it is free.
#[test]
fn sets_another_filmback_is_developing_are_left_to_it() {
    let farm = std::sync::Mutex::new(None);
    let (calls, held) = (
        Arc::new(AtomicUsize::new(0)),
        Arc::new(std::sync::Mutex::new(None)),
    );
    let lab = {
        let (calls, held) = (Arc::clone(&calls), Arc::clone(&held));
        move |job: &Job| -> Result<Processed, JobError> {
            if calls.fetch_add(1, Ordering::SeqCst) == 0 {
                let stage = atomic::stage_folder(&job.out, &job.id);
                *held.lock().unwrap() = Some(atomic::StageLock::take(&stage).unwrap());
            }
            DarkroomLab.process(job)
        }
    };
    let mut rig = Rig::start(&[], Arc::new(lab), |root| {
        let stage = atomic::stage_folder(&root.join("out"), "a-farm-task");
        std::fs::create_dir_all(&stage).unwrap();
        std::fs::write(stage.join("t-1.exr"), b"half an EXR").unwrap();
        *farm.lock().unwrap() = Some((stage.clone(), atomic::StageLock::take(&stage).unwrap()));
    });
    put(&rig.ingest(), &aeb("Body A", 10, "e"));
    let start = Instant::now();
    while calls.load(Ordering::SeqCst) < 2 {
        assert!(start.elapsed() < T, "no retry happened");
        std::thread::sleep(Duration::from_millis(50));
    }
    assert!(
        rig::visible(&rig.out()).is_empty(),
        "nothing published while held"
    );
    drop(held.lock().unwrap().take());
    let start = Instant::now();
    while !rig.out().join("e-1.exr").exists() {
        assert!(start.elapsed() < T, "not developed once free");
        std::thread::sleep(Duration::from_millis(50));
    }
    let (stage, lock) = farm.lock().unwrap().take().unwrap();
    assert!(
        stage.join("t-1.exr").is_file(),
        "the farm task's folder was not touched"
    );
    // The farm task ends: its folder and its lock go.
    std::fs::remove_dir_all(&stage).unwrap();
    drop(lock);
    expect_outputs(&rig.out(), &bracket_outputs(&["e-1"]), T);
    let state = rig.state();
    rig.stop();
    assert_eq!(journaled_brackets(&state), ["e-1"]);
}

#[test]
fn ingest_folder_deleted_and_recreated() {
    let mut rig = Rig::start(&[], Arc::new(DarkroomLab), |_| {});
    put(&rig.ingest(), &aeb("Body A", 10, "g"));
    expect_outputs(&rig.out(), &bracket_outputs(&["g-1"]), T);
    std::fs::remove_dir_all(rig.ingest()).unwrap();
    wait_for_status(&rig.state(), |s| !s.watching);
    std::fs::create_dir(rig.ingest()).unwrap();
    wait_for_status(&rig.state(), |s| s.watching);
    put(&rig.ingest(), &aeb("Body A", 30, "h"));
    expect_outputs(&rig.out(), &bracket_outputs(&["g-1", "h-1"]), T);
    let state = rig.state();
    rig.stop();
    assert_eq!(journaled_brackets(&state), ["g-1", "h-1"]);
}

#[test]
fn single_frames_are_rendered_or_reported() {
    let mut rig = Rig::start(&[], Arc::new(DarkroomLab), |_| {});
    let a = aeb("Body A", 10, "solo");
    put(&rig.ingest(), &a[..1]);
    // A single has no extended range: renderings only, no EXR.
    let expected: BTreeSet<String> = ["solo-1.linear.jpg".to_string()].into();
    expect_outputs(&rig.out(), &expected, T);
    let state = rig.state();
    rig.stop();
    let entries = journal::read(&state).unwrap();
    assert!(matches!(&entries[..], [Entry::Single { outputs, .. }] if outputs.len() == 1));

    let mut rig = Rig::start(
        &[("bracket", "singles = \"report\"")],
        Arc::new(DarkroomLab),
        |_| {},
    );
    put(&rig.ingest(), &a[..1]);
    let start = Instant::now();
    while journal::read(&rig.state()).unwrap().is_empty() {
        assert!(start.elapsed() < T);
        std::thread::sleep(Duration::from_millis(50));
    }
    assert!(listing(&rig.out()).is_empty());
    let state = rig.state();
    rig.stop();
    let entries = journal::read(&state).unwrap();
    assert!(matches!(&entries[..], [Entry::Single { outputs, .. }] if outputs.is_empty()));
}

// --- The real binary as a child process --------------------------------------------

fn spawn_binary(config: &Path) -> Watch {
    Watch(
        Command::new(env!("CARGO_BIN_EXE_filmback"))
            .args(["watch", "--config"])
            .arg(config)
            .env("RUST_LOG", "info")
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(config.with_extension("log")).unwrap())
            .spawn()
            .unwrap(),
    )
}

/// A `filmback watch` child that is killed when dropped, so a test that fails before it
/// stops its daemon leaves none running (one left over loads the machine for the rest).
struct Watch(Child);

impl std::ops::Deref for Watch {
    type Target = Child;
    fn deref(&self) -> &Child {
        &self.0
    }
}

impl std::ops::DerefMut for Watch {
    fn deref_mut(&mut self) -> &mut Child {
        &mut self.0
    }
}

impl Drop for Watch {
    fn drop(&mut self) {
        // Already reaped (stopped by the test): nothing is signalled.
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn terminate(child: &mut Child) -> Duration {
    let start = Instant::now();
    Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
    let status = child.wait().unwrap();
    assert!(status.success(), "{status}");
    start.elapsed()
}

fn wait_for_status(state: &Path, ok: impl Fn(&daemon::Snapshot) -> bool) {
    let start = Instant::now();
    loop {
        if daemon::read_snapshot(state).is_some_and(|s| ok(&s)) {
            return;
        }
        assert!(start.elapsed() < T, "status never matched");
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn kill_9_mid_merge_then_restart_loses_and_repeats_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    std::fs::create_dir_all(root.join("ingest")).unwrap();
    let config = root.join("filmback.toml");
    std::fs::write(&config, config_text(root, &[])).unwrap();
    // Frames large enough that developing a bracket takes a while.
    let (w, h) = (1600, 1100);
    let frames: Vec<(String, Vec<u8>)> = ["k", "m"]
        .iter()
        .enumerate()
        .flat_map(|(b, prefix)| {
            let shots = demo::aeb("Body K", None, 10 + 20 * b as u32);
            demo::jpegs(w, h, &shots, b as u64)
                .unwrap()
                .into_iter()
                .enumerate()
                .map(|(i, bytes)| (format!("{prefix}-{}.jpg", i + 1), bytes))
                .collect::<Vec<_>>()
        })
        .collect();
    let mut child = spawn_binary(&config);
    // The frames are copied in while the daemon starts: some are found by its start-up
    // scan, some arrive as events; each bracket must still be grouped whole.
    put(&root.join("ingest"), &frames);
    // Killed as soon as a bracket is in flight (the lab is fast enough at
    // opt-level 1 that a pause here lets both brackets finish first).
    wait_for_status(&root.join("state"), |s| s.in_flight > 0);
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
    // Its last snapshot still says it runs; `status` tells by the lock that it does not.
    let shown = Command::new(env!("CARGO_BIN_EXE_filmback"))
        .args(["status", "--json", "--state"])
        .arg(root.join("state"))
        .output()
        .unwrap();
    let report: serde_json::Value = serde_json::from_slice(&shown.stdout).unwrap();
    assert_eq!(report["running"], false, "{report}");
    assert_eq!(report["daemon"]["running"], false, "{report}");
    let done_before = journal::read(&root.join("state")).unwrap().len();
    assert!(done_before < 2, "killed before both brackets finished");

    // Restart, and stop it with SIGTERM while it develops: it exits cleanly within 10 s.
    let mut child = spawn_binary(&config);
    let pid = child.id();
    wait_for_status(&root.join("state"), |s| s.pid == pid && s.in_flight > 0);
    let took = terminate(&mut child);
    assert!(took < Duration::from_secs(10), "stop took {took:?}");

    let mut child = spawn_binary(&config);
    let pid = child.id();
    // (Its signal handlers are in place once it reports.)
    wait_for_status(&root.join("state"), |s| s.pid == pid && s.running);
    let out = root.join("out");
    let expected = bracket_outputs(&["k-1", "m-1"]);
    let start = Instant::now();
    while listing(&out) != expected || journal::read(&root.join("state")).unwrap().len() < 2 {
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "out holds {:?}",
            listing(&out)
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let took = terminate(&mut child);
    assert!(took < Duration::from_secs(10), "stop took {took:?}");
    assert_eq!(listing(&out), expected, "no temporary file left");
    for name in ["k-1.exr", "m-1.exr"] {
        let image = exr::prelude::read_all_flat_layers_from_file(out.join(name)).unwrap();
        assert_eq!(image.layer_data[0].size.x(), w as usize);
    }
    assert_eq!(journaled_brackets(&root.join("state")), ["k-1", "m-1"]);

    // A third start finds everything done and does nothing.
    let mut child = spawn_binary(&config);
    wait_for_status(&root.join("state"), |s| s.running && s.pid == child.id());
    std::thread::sleep(Duration::from_millis(800));
    terminate(&mut child);
    assert_eq!(journal::read(&root.join("state")).unwrap().len(), 2);
    // The last snapshot says it stopped, and so no longer watches.
    let last = daemon::read_snapshot(&root.join("state")).unwrap();
    assert!(!last.running && !last.watching, "{last:?}");
}

#[test]
fn burst_of_200_frames_is_worked_off_with_nothing_dropped() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    std::fs::create_dir_all(root.join("ingest")).unwrap();
    let config = root.join("filmback.toml");
    std::fs::write(&config, config_text(root, &[])).unwrap();
    // 66 brackets of 3 and one of 2, 2 s apart in capture time; the three exposures of
    // the scene are shared, the EXIF differs per frame. Names run against capture order
    // within a bracket (`-3` is captured first), so frames taken in name order arrive
    // shuffled and full brackets wait for their gap clocks, then become ready together.
    let first = demo::aeb("Body B", None, 10);
    let scene = synthetic::scene(320, 240, 3);
    let sensor = Sensor::noiseless(ResponseCurve::Srgb, BitDepth::Eight);
    let scale = 1.0 / first[1].exposure.relative().unwrap();
    let exposed = synthetic::bracket(&scene, &sensor, &first, scale).unwrap();
    let frames: Vec<(String, Vec<u8>)> = (0..200)
        .map(|i| {
            let shot = &demo::aeb("Body B", None, 10 + 2 * (i / 3) as u32)[i % 3];
            let name = format!("b{:03}-{}.jpg", i / 3, 3 - i % 3);
            let jpeg = synthetic::encode(&exposed[i % 3], shot, Encoding::Jpeg { quality: 90 });
            (name, jpeg.unwrap())
        })
        .collect();
    let mut child = spawn_binary(&config);
    wait_for_status(&root.join("state"), |s| s.running);
    let start = Instant::now();
    for (name, bytes) in &frames {
        atomic::publish(&root.join("ingest").join(name), bytes, Overwrite::Replace).unwrap();
    }
    let expected: BTreeSet<String> = (0..67)
        .flat_map(|b| bracket_outputs(&[&format!("b{b:03}-3")]))
        .collect();
    let out = root.join("out");
    let mut peak_queue = 0;
    while listing(&out) != expected {
        let got = listing(&out);
        assert!(
            start.elapsed() < Duration::from_secs(120),
            "{} of {} outputs; extra {:?}",
            got.len(),
            expected.len(),
            got.difference(&expected).collect::<Vec<_>>()
        );
        if let Some(s) = daemon::read_snapshot(&root.join("state")) {
            assert!(s.in_flight <= 2, "at most `jobs` in flight: {s:?}");
            assert!(s.queued <= 8, "queue bounded: {s:?}");
            peak_queue = peak_queue.max(s.queued);
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let took = start.elapsed();
    let status = std::fs::read_to_string(format!("/proc/{}/status", child.id())).unwrap();
    let peak_kb: u64 = status
        .lines()
        .find(|l| l.starts_with("VmHWM:"))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|v| v.parse().ok())
        .unwrap();
    eprintln!(
        "burst: 200 frames (320x240) -> 67 brackets in {:.1} s, peak RSS {} MiB, peak queue {peak_queue}",
        took.as_secs_f64(),
        peak_kb / 1024
    );
    terminate(&mut child);
    let brackets = journaled_brackets(&root.join("state"));
    assert_eq!(brackets.len(), 67);
    assert_eq!(listing(&out), expected);
}

/// A root-owned test runs the daemon as `nobody` (permissions do not bind root).
fn unprivileged(program: &str) -> Command {
    let is_root = Command::new("id").arg("-u").output().unwrap().stdout == b"0\n";
    if is_root {
        let mut c = Command::new("setpriv");
        c.args(["--reuid=65534", "--regid=65534", "--clear-groups"])
            .arg(program);
        c
    } else {
        Command::new(program)
    }
}

/// Folders `nobody` may write, under a root it may enter.
fn open_folders(root: &Path) {
    use std::os::unix::fs::PermissionsExt;
    for d in ["ingest", "out", "state"] {
        std::fs::create_dir_all(root.join(d)).unwrap();
        std::fs::set_permissions(root.join(d), std::fs::Permissions::from_mode(0o777)).unwrap();
    }
    std::fs::set_permissions(root, std::fs::Permissions::from_mode(0o755)).unwrap();
}

#[test]
fn unreadable_frame_is_retried_until_readable_and_its_bracket_made_whole() {
    use std::os::unix::fs::PermissionsExt;
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    open_folders(root);
    let config = root.join("filmback.toml");
    std::fs::write(&config, config_text(root, &[])).unwrap();
    let frames = aeb("Body U", 10, "u");
    put(&root.join("ingest"), &frames);
    let locked = root.join("ingest/u-2.jpg");
    std::fs::set_permissions(&locked, std::fs::Permissions::from_mode(0o000)).unwrap();
    let mut child = unprivileged(env!("CARGO_BIN_EXE_filmback"))
        .args(["watch", "--config"])
        .arg(&config)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    // `status` says what is retried, why, and when next.
    wait_for_status(&root.join("state"), |s| {
        s.retries.iter().any(|r| {
            r.what.ends_with("u-2.jpg") && r.reason.contains("ermission denied") && r.next > 0
        })
    });
    let shown = Command::new(env!("CARGO_BIN_EXE_filmback"))
        .args(["status", "--state"])
        .arg(root.join("state"))
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&shown.stdout);
    assert!(
        text.lines().any(|l| l.contains("u-2.jpg")
            && l.contains("ermission denied")
            && l.contains("next in")),
        "{text}"
    );
    std::thread::sleep(Duration::from_secs(2));
    assert!(
        listing(&root.join("out")).is_empty(),
        "the bracket waits for its frame"
    );
    std::fs::set_permissions(&locked, std::fs::Permissions::from_mode(0o644)).unwrap();
    expect_outputs(&root.join("out"), &bracket_outputs(&["u-1"]), T);
    terminate(&mut child);
    assert!(rejected(&root.join("state")).is_empty());
    let entries = journal::read(&root.join("state")).unwrap();
    assert!(
        matches!(&entries[..], [Entry::Bracket { inputs, .. }] if inputs.len() == 3),
        "{entries:?}"
    );
}

#[test]
fn any_file_name_is_journaled_and_logged_on_one_line() {
    use std::os::unix::ffi::OsStrExt;
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    let ingest = root.join("ingest");
    std::fs::create_dir_all(&ingest).unwrap();
    let config = root.join("filmback.toml");
    std::fs::write(&config, config_text(root, &[])).unwrap();
    let mut names = Vec::new();
    for (i, (_, bytes)) in aeb("Body N", 10, "n").iter().enumerate() {
        let name = [b"bad\xff-".as_slice(), format!("{}.jpg", i + 1).as_bytes()].concat();
        let path = ingest.join(std::ffi::OsStr::from_bytes(&name));
        std::fs::write(&path, bytes).unwrap();
        names.push(path);
    }
    std::fs::write(ingest.join("evil\nERROR forged line.jpg"), b"not an image").unwrap();
    let state = root.join("state");
    for round in 0..2 {
        let mut child = spawn_binary(&config);
        expect_outputs(&root.join("out"), &bracket_outputs(&["bad\u{fffd}-1"]), T);
        let start = Instant::now();
        while rejected(&state).is_empty() {
            assert!(start.elapsed() < T, "never rejected");
            std::thread::sleep(Duration::from_millis(50));
        }
        std::thread::sleep(Duration::from_millis(300));
        terminate(&mut child);
        if round == 0 {
            let log = std::fs::read_to_string(config.with_extension("log")).unwrap();
            assert!(
                !log.lines().any(|l| l.starts_with("ERROR forged")),
                "a name forged a log line:\n{log}"
            );
            assert!(log.contains("evil\\nERROR forged line.jpg"), "{log}");
        }
    }
    // The second start redid nothing and found every name in the journal.
    let entries = journal::read(&state).unwrap();
    assert_eq!(entries.len(), 2, "{entries:?}");
    let journaled: Vec<PathBuf> = entries
        .iter()
        .flat_map(|e| e.inputs().into_iter().map(|i| i.path.clone()))
        .collect();
    for n in &names {
        assert!(journaled.contains(n), "{} not journaled", n.display());
    }
}

#[test]
fn links_in_ingest_are_never_followed_and_refused_with_a_reason() {
    use std::os::unix::fs::symlink;
    let outside = tempfile::tempdir().unwrap();
    put(outside.path(), &aeb("Body L", 40, "stray"));
    let mut rig = Rig::start(
        &[("watch", "recursive = true")],
        Arc::new(DarkroomLab),
        |root| {
            let ingest = root.join("ingest");
            // A loop up to the root reaches out/: outputs must not come back as frames.
            symlink("..", ingest.join("loop")).unwrap();
            symlink(outside.path(), ingest.join("linked-folder")).unwrap();
            symlink(
                outside.path().join("stray-1.jpg"),
                ingest.join("stray-1.jpg"),
            )
            .unwrap();
            symlink(root.join("nowhere.jpg"), ingest.join("dangling.jpg")).unwrap();
            put(&ingest, &aeb("Body L", 10, "l"));
        },
    );
    expect_outputs(&rig.out(), &bracket_outputs(&["l-1"]), T);
    // A later bracket's outputs appear under ingest/loop/out too: still nothing extra.
    put(&rig.ingest(), &aeb("Body L", 70, "m"));
    expect_outputs(&rig.out(), &bracket_outputs(&["l-1", "m-1"]), T);
    std::thread::sleep(Duration::from_secs(3));
    assert_eq!(listing(&rig.out()), bracket_outputs(&["l-1", "m-1"]));
    let state = rig.state();
    rig.stop();
    let mut r = rejected(&state);
    r.sort();
    assert_eq!(r.len(), 2, "{r:?}");
    assert_eq!(r[0].0, "dangling.jpg");
    assert!(
        r[0].1.contains("symbolic link") && r[0].1.contains("dangling"),
        "{r:?}"
    );
    assert_eq!(r[1].0, "stray-1.jpg");
    assert!(
        r[1].1.contains("symbolic link") && r[1].1.contains("not followed"),
        "{r:?}"
    );
    assert_eq!(journaled_brackets(&state), ["l-1", "m-1"]);
}

#[test]
fn an_out_folder_reachable_from_ingest_through_a_link_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    std::fs::create_dir_all(root.join("real/ingest")).unwrap();
    // The configured ingest is a link to real/ingest; out is real/ingest/out.
    std::os::unix::fs::symlink(root.join("real/ingest"), root.join("ingest")).unwrap();
    let text = config_text(root, &[("watch", "recursive = true")]).replace(
        &format!("out = \"{}\"", root.join("out").display()),
        &format!("out = \"{}\"", root.join("real/ingest/out").display()),
    );
    let config = Config::from_str(&text, Some(Path::new("t.toml"))).expect("lexically fine");
    let (control, rx) = tokio::sync::mpsc::channel(1);
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .unwrap();
    let result = rt.block_on(async move {
        let stop = tokio::spawn(async move {
            tokio::time::sleep(Duration::from_secs(1)).await;
            let _ = control.send(Control::Stop).await;
        });
        let r = daemon::run(config, Arc::new(DarkroomLab), rx).await;
        stop.abort();
        r
    });
    let err = result.expect_err("out inside the watched folder must be refused");
    assert!(
        err.to_string().contains("inside the watched ingest"),
        "{err}"
    );
}

#[test]
fn a_brackets_outputs_appear_together_or_not_at_all() {
    let (calls, lab) = counting_darkroom();
    let mut rig = Rig::start(&[], lab, |root| {
        // The rendering's name is occupied (as by a full disk for its last file): the
        // EXR, written fine, must not be visible alone.
        std::fs::create_dir_all(root.join("out/s-1.linear.jpg")).unwrap();
    });
    put(&rig.ingest(), &aeb("Body A", 10, "s"));
    let start = Instant::now();
    while calls.load(Ordering::SeqCst) < 2 {
        assert!(start.elapsed() < T, "no retry happened");
        std::thread::sleep(Duration::from_millis(20));
        assert!(
            !rig.out().join("s-1.exr").exists(),
            "the EXR appeared without its rendering"
        );
    }
    wait_for_status(&rig.state(), |s| {
        s.retries
            .iter()
            .any(|r| r.what == "s-1" && r.reason.contains("s-1.linear.jpg"))
    });
    let visible: BTreeSet<String> = listing(&rig.out())
        .into_iter()
        .filter(|n| !n.starts_with('.'))
        .collect();
    assert_eq!(visible, ["s-1.linear.jpg".to_string()].into());
    std::fs::remove_dir(rig.out().join("s-1.linear.jpg")).unwrap();
    expect_outputs(&rig.out(), &bracket_outputs(&["s-1"]), T);
    rig.stop();
}

#[test]
fn the_memory_budget_rejects_what_cannot_fit_and_runs_the_rest_in_turn() {
    let running = Arc::new(AtomicUsize::new(0));
    let peak = Arc::new(AtomicUsize::new(0));
    let (r, p) = (Arc::clone(&running), Arc::clone(&peak));
    let lab = move |_: &Job| -> Result<Processed, JobError> {
        let now = r.fetch_add(1, Ordering::SeqCst) + 1;
        p.fetch_max(now, Ordering::SeqCst);
        std::thread::sleep(Duration::from_millis(600));
        r.fetch_sub(1, Ordering::SeqCst);
        Ok(Processed {
            outputs: Vec::new(),
            source: filmback::darkroom::Source::Standard,
            fit: None,
            pooling: None,
            contradicts_cache: false,
            stages: Vec::new(),
            notes: Vec::new(),
            measured: None,
            facts: Default::default(),
            pictures: None,
        })
    };
    // Each bracket (`daemon::job_bytes`): 1400 × 1000 px × (3 frames × 3 B + 2 resampled
    // frames and masks × 4 B + 26 B) + 18 × 64 × 1400 B of JPEG bands = 61.8 MB; two do
    // not fit in 64 MB. The grey PNG: 2500 × 1000 × (1 + 26) + 18 × 64 × 2500 = 70.4 MB,
    // never fits.
    let shots = |model: &str, second: u32| {
        let shots = demo::aeb(model, None, second);
        demo::jpegs(1400, 1000, &shots, u64::from(second))
            .unwrap()
            .into_iter()
            .enumerate()
            .map(|(i, bytes)| (format!("{}{second}-{}.jpg", &model[5..], i + 1), bytes))
            .collect::<Vec<_>>()
    };
    let (one, two) = (shots("Body P", 10), shots("Body Q", 10));
    let mut rig = Rig::start(&[("daemon", "memory_mb = 64")], Arc::new(lab), |root| {
        put(&root.join("ingest"), &one);
        put(&root.join("ingest"), &two);
        image::GrayImage::new(2500, 1000)
            .save(root.join("ingest/huge.png"))
            .unwrap();
    });
    let start = Instant::now();
    while journaled_brackets(&rig.state()).len() < 2 {
        assert!(start.elapsed() < T, "brackets not developed");
        std::thread::sleep(Duration::from_millis(50));
    }
    let state = rig.state();
    rig.stop();
    assert_eq!(
        peak.load(Ordering::SeqCst),
        1,
        "two brackets developed at once"
    );
    let r = rejected(&state);
    assert_eq!(r.len(), 1, "{r:?}");
    assert_eq!(r[0].0, "huge.png");
    assert!(
        r[0].1.contains("71 MB") && r[0].1.contains("memory_mb = 64"),
        "{r:?}"
    );
}

#[test]
fn sighup_with_a_bad_config_keeps_the_running_one() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    std::fs::create_dir_all(root.join("ingest")).unwrap();
    let config = root.join("filmback.toml");
    std::fs::write(&config, config_text(root, &[])).unwrap();
    let mut child = spawn_binary(&config);
    wait_for_status(&root.join("state"), |s| s.running);
    std::fs::write(&config, "[daemon]\njobs = 0\n").unwrap();
    Command::new("kill")
        .args(["-HUP", &child.id().to_string()])
        .status()
        .unwrap();
    let log = config.with_extension("log");
    let start = Instant::now();
    while !std::fs::read_to_string(&log).is_ok_and(|l| l.contains("keeping the running one")) {
        assert!(start.elapsed() < T, "the bad reload was never reported");
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(
        child.try_wait().unwrap().is_none(),
        "daemon survived the bad reload"
    );
    put(&root.join("ingest"), &aeb("Body A", 10, "v"));
    expect_outputs(&root.join("out"), &bracket_outputs(&["v-1"]), T);
    terminate(&mut child);
}

#[test]
fn frame_failing_in_development_is_rejected_and_the_rest_regrouped() {
    // The lab finds frame 2 unusable only when decoding it (as a real decoder may).
    let lab = |job: &Job| -> Result<Processed, JobError> {
        if let Some(bad) = job
            .frames
            .iter()
            .find(|c| c.input.path.ends_with("p-2.jpg"))
        {
            return Err(JobError::Frame {
                path: bad.input.path.clone(),
                reason: "decoder: corrupt entropy data".into(),
            });
        }
        DarkroomLab.process(job)
    };
    let mut rig = Rig::start(&[], Arc::new(lab), |_| {});
    put(&rig.ingest(), &aeb("Body A", 10, "p"));
    expect_outputs(&rig.out(), &bracket_outputs(&["p-1"]), T);
    let state = rig.state();
    rig.stop();
    assert_eq!(
        rejected(&state),
        [(
            "p-2.jpg".to_string(),
            "decoder: corrupt entropy data".to_string()
        )]
    );
    let entries = journal::read(&state).unwrap();
    assert!(
        entries
            .iter()
            .any(|e| matches!(e, Entry::Bracket { inputs, .. } if inputs.len() == 2)),
        "{entries:?}"
    );
}

#[test]
fn good_fits_refine_the_camera_cache_and_later_brackets_receive_it() {
    use filmback::darkroom::Pooling;
    use filmback::histogram::TonePair;
    use filmback::response::InverseResponse;
    use filmback::response::pool::{Evidence, PairSet};
    let seen_cached = Arc::new(AtomicUsize::new(0));
    let seen = Arc::clone(&seen_cached);
    // A lab whose fits say gamma 2.2 at confidence 0.9, with the tone pairs of such a
    // body at ratio 4 as evidence.
    let lab = move |job: &Job| -> Result<Processed, JobError> {
        if job.cached.is_some() {
            seen.fetch_add(1, Ordering::SeqCst);
        }
        let mut dev = DarkroomLab.process(job)?;
        let g: Vec<f64> = (0..65).map(|i| (f64::from(i) / 64.0).powf(2.2)).collect();
        dev.fit = Some((InverseResponse::from_samples(vec![g; 3]).unwrap(), 0.9));
        let step = 4f64.powf(1.0 / 2.2);
        let set = PairSet {
            log_ratio: 4f64.ln(),
            pairs: (0..50)
                .map(|i| {
                    let dark = 0.02 + 0.5 * f64::from(i) / 50.0;
                    TonePair {
                        dark,
                        bright: dark * step,
                        sigma_dark: 0.002,
                        sigma_bright: 0.002,
                        quantile: f64::from(i) / 50.0,
                    }
                })
                .collect(),
        };
        dev.pooling = Some(Pooling {
            evidence: Evidence {
                frames: 2,
                channels: vec![vec![set]; 3],
            },
            own_misfit: 0.0,
            own_confidence: vec![0.9; 3],
            pooled: None,
        });
        dev.contradicts_cache = false;
        Ok(dev)
    };
    let mut rig = Rig::start(&[], Arc::new(lab), |_| {});
    put(&rig.ingest(), &aeb("Body F", 10, "q"));
    expect_outputs(&rig.out(), &bracket_outputs(&["q-1"]), T);
    put(&rig.ingest(), &aeb("Body F", 30, "s"));
    expect_outputs(&rig.out(), &bracket_outputs(&["q-1", "s-1"]), T);
    let state = rig.state();
    rig.stop();
    assert_eq!(
        seen_cached.load(Ordering::SeqCst),
        1,
        "the second bracket got the cache"
    );
    let cache = filmback::daemon::cache::ResponseCache::new(&state);
    let entry = cache.find("Body F").unwrap();
    assert_eq!((entry.brackets, entry.pool.len()), (2, 2));
    assert_eq!(entry.min_confidence(), Some(0.9));
    assert!((entry.response.eval(0, 0.5) - 0.5f64.powf(2.2)).abs() < 1e-9);
    let out = Command::new(env!("CARGO_BIN_EXE_filmback"))
        .args(["cache", "list", "--state"])
        .arg(&state)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("Body F") && text.contains("2 brackets"),
        "{text}"
    );
    let out = Command::new(env!("CARGO_BIN_EXE_filmback"))
        .args(["cache", "reset", "body f", "--state"])
        .arg(&state)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(cache.list().unwrap().is_empty());
}

/// The journal's response source of the bracket whose first input is `<stem>.jpg`.
fn response_of(state: &Path, stem: &str) -> filmback::darkroom::Source {
    journal::read(state)
        .unwrap()
        .into_iter()
        .find_map(|e| match e {
            Entry::Bracket {
                inputs, response, ..
            } if inputs[0].path.ends_with(format!("{stem}.jpg")) => Some(response),
            _ => None,
        })
        .unwrap_or_else(|| panic!("no bracket {stem} in the journal"))
}

#[test]
fn the_darkroom_fits_renders_each_cameras_looks_and_refines_the_cache() {
    use filmback::darkroom::Source;
    // Films at t = 1 stop on top of the request's own @1/2: velvia50 at t = 1. Body P's
    // preset replaces the films and drops the tone map, and never recalibrates. The
    // confidence bar is set low (0.25): this test is about the cache's refinement, not
    // about the bar.
    let mut rig = Rig::start_with(
        &[
            ("render", "films = [\"velvia50@1/2\"]"),
            ("render", "t = 1.0"),
            ("render", "min_confidence = 0.25"),
        ],
        "[camera.\"Body P\"]\nfilms = [\"provia100f\"]\ntonemaps = []\nrecalibrate = \"never\"\n",
        Arc::new(DarkroomLab),
        |_| {},
    );
    // At 96×64 the frames share few pixels outside their hard-clipped JPEG blocks, so
    // the sparse tones' matches are noisy: the contradiction check weighs each tone pair
    // by its noise (`pool::misfit`), else the second bracket "contradicts" the first.
    put(&rig.ingest(), &aeb("Body A", 10, "a"));
    put(&rig.ingest(), &aeb("Body P", 10, "p"));
    let expected: BTreeSet<String> = [
        "a-1.exr",
        "a-1.velvia50-t1.jpg",
        "a-1.linear.jpg",
        "p-1.exr",
        "p-1.provia100f-t2.jpg",
    ]
    .map(String::from)
    .into();
    expect_outputs(&rig.out(), &expected, T);
    put(&rig.ingest(), &aeb("Body A", 30, "b"));
    let mut expected = expected;
    expected.extend(["b-1.exr", "b-1.velvia50-t1.jpg", "b-1.linear.jpg"].map(String::from));
    expect_outputs(&rig.out(), &expected, T);
    let state = rig.state();
    rig.stop();
    // Body A: a noiseless sRGB bracket at ±2 EV fits above the bar and starts the body's
    // pool. The second agrees with it and is merged with the pool, which is trusted
    // (confidence ≥ 0.5; `darkroom::tests` covers the other cases); its tone pairs join
    // the pool, refitted over both brackets. Body P never fits, has no cache, and takes
    // sRGB.
    assert_eq!(response_of(&state, "a-1"), Source::Fitted);
    assert_eq!(response_of(&state, "b-1"), Source::Pooled);
    assert_eq!(response_of(&state, "p-1"), Source::Standard);
    let cache = filmback::daemon::cache::ResponseCache::new(&state);
    let entry = cache.find("Body A").unwrap();
    assert_eq!((entry.brackets, entry.pool.len()), (2, 2));
    assert!(entry.min_confidence().is_some_and(|c| c > 0.0));
    // The frames were rendered through sRGB: the cached curve is close to its inverse.
    let srgb_mid = ((0.5f64 + 0.055) / 1.055).powf(2.4);
    let g_mid = entry.response.eval(1, 0.5);
    assert!(
        (g_mid.log2() - srgb_mid.log2()).abs() < 0.15,
        "g(0.5) = {g_mid}, sRGB {srgb_mid}"
    );
    assert!(cache.find("Body P").is_err(), "Body P never calibrates");
    // The film rendering carries the camera's EXIF and is upright at the frame's size.
    let jpeg = std::fs::read(rig_out_path(&state, "a-1.velvia50-t1.jpg")).unwrap();
    let exif = exif::Reader::new()
        .read_from_container(&mut std::io::Cursor::new(&jpeg))
        .expect("EXIF carried into the rendering");
    let model = exif
        .get_field(exif::Tag::Model, exif::In::PRIMARY)
        .map(|f| f.display_value().to_string());
    assert!(model.is_some_and(|m| m.contains("Body A")), "model carried");
    let decoded = image::load_from_memory(&jpeg).unwrap();
    assert_eq!(
        (decoded.width(), decoded.height()),
        (u32::from(W), u32::from(H))
    );
}

/// `out/<name>` of the rig whose state folder is `state` (they are siblings).
fn rig_out_path(state: &Path, name: &str) -> PathBuf {
    state.parent().unwrap().join("out").join(name)
}

#[test]
fn check_config_names_file_line_and_key() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("studio.toml");
    std::fs::write(&bad, "[watch]\nsettle_ms = 500\n\n[bracket]\nmax_gap = 3\n").unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_filmback"))
        .args(["check-config"])
        .arg(&bad)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains(&format!("{}:5:1: max_gap: unknown field", bad.display())),
        "{err}"
    );
    // The commented example is valid and equals the built-in defaults.
    let example = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/filmback.toml");
    let out = Command::new(env!("CARGO_BIN_EXE_filmback"))
        .args(["check-config"])
        .arg(&example)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let mut from_file = Config::load(&example).unwrap();
    from_file.source = None;
    assert_eq!(from_file, Config::defaults());
}

#[test]
fn reused_file_names_never_replace_finished_outputs() {
    let mut rig = Rig::start(&[], Arc::new(DarkroomLab), |_| {});
    put(&rig.ingest(), &aeb("Body A", 10, "n"));
    expect_outputs(&rig.out(), &bracket_outputs(&["n-1"]), T);
    let first_exr = std::fs::read(rig.out().join("n-1.exr")).unwrap();
    // The camera's counter wraps: new frames arrive under the same names.
    for i in 1..=3 {
        std::fs::remove_file(rig.ingest().join(format!("n-{i}.jpg"))).unwrap();
    }
    put(&rig.ingest(), &aeb("Body A", 50, "n"));
    let start = Instant::now();
    while journaled_brackets(&rig.state()).len() < 2 {
        assert!(start.elapsed() < T);
        std::thread::sleep(Duration::from_millis(50));
    }
    let id = match journal::read(&rig.state()).unwrap().pop() {
        Some(Entry::Bracket { id, .. }) => id,
        other => panic!("{other:?}"),
    };
    let second = format!("n-1-{}", &id[..8]);
    expect_outputs(&rig.out(), &bracket_outputs(&["n-1", &second]), T);
    assert_eq!(std::fs::read(rig.out().join("n-1.exr")).unwrap(), first_exr);
    rig.stop();
}

#[test]
fn touched_frames_are_not_redone_and_a_reshot_frame_replaces_its_brackets_outputs() {
    let mut rig = Rig::start(&[], Arc::new(DarkroomLab), |_| {});
    put(&rig.ingest(), &aeb("Body A", 10, "t"));
    expect_outputs(&rig.out(), &bracket_outputs(&["t-1"]), T);
    let first_exr = std::fs::read(rig.out().join("t-1.exr")).unwrap();
    // A tool touches every frame: new modification times, same content.
    let later = std::time::SystemTime::now() + Duration::from_secs(5);
    for i in 1..=3 {
        std::fs::File::options()
            .write(true)
            .open(rig.ingest().join(format!("t-{i}.jpg")))
            .unwrap()
            .set_modified(later)
            .unwrap();
    }
    let start = Instant::now();
    let unchanged = |state: &Path| {
        journal::read(state)
            .unwrap()
            .iter()
            .filter(|e| matches!(e, Entry::Unchanged { .. }))
            .count()
    };
    while unchanged(&rig.state()) < 3 {
        assert!(start.elapsed() < T, "touched frames not noticed");
        std::thread::sleep(Duration::from_millis(50));
    }
    expect_outputs(&rig.out(), &bracket_outputs(&["t-1"]), T);
    assert_eq!(std::fs::read(rig.out().join("t-1.exr")).unwrap(), first_exr);
    // The middle frame is shot again under its name: the bracket is developed again,
    // in place; no second EXR, no single.
    let again = aeb("Body A", 50, "t").remove(1);
    put(&rig.ingest(), &[again]);
    let start = Instant::now();
    while journaled_brackets_all(&rig.state()) < 2 {
        assert!(start.elapsed() < T, "re-shot frame not developed");
        std::thread::sleep(Duration::from_millis(50));
    }
    expect_outputs(&rig.out(), &bracket_outputs(&["t-1"]), T);
    assert_ne!(std::fs::read(rig.out().join("t-1.exr")).unwrap(), first_exr);
    rig.stop();
}

/// Bracket entries in the journal, superseded ones included.
fn journaled_brackets_all(state: &Path) -> usize {
    journal::read(state)
        .unwrap()
        .iter()
        .filter(|e| matches!(e, Entry::Bracket { .. }))
        .count()
}

#[test]
fn deleted_outputs_stay_deleted_until_filmback_redo() {
    let mut rig = Rig::start(&[], Arc::new(DarkroomLab), |_| {});
    put(&rig.ingest(), &aeb("Body A", 10, "d"));
    expect_outputs(&rig.out(), &bracket_outputs(&["d-1"]), T);
    std::fs::remove_file(rig.out().join("d-1.exr")).unwrap();
    std::thread::sleep(Duration::from_secs(3));
    assert_eq!(listing(&rig.out()), ["d-1.linear.jpg".to_string()].into());
    let redo = |stems: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_filmback"))
            .arg("redo")
            .args(stems)
            .arg("--state")
            .arg(rig.state())
            .output()
            .unwrap()
    };
    let unknown = redo(&["nothing-1"]);
    assert!(!unknown.status.success());
    assert!(
        String::from_utf8_lossy(&unknown.stderr).contains("nothing-1: no finished bracket"),
        "{unknown:?}"
    );
    // All or nothing: one unknown stem queues none of them.
    let mixed = redo(&["d-1", "nothing-1"]);
    assert!(!mixed.status.success());
    assert!(
        String::from_utf8_lossy(&mixed.stderr).contains("nothing queued"),
        "{mixed:?}"
    );
    assert!(
        listing(&rig.state().join("redo")).is_empty(),
        "no request left"
    );
    std::thread::sleep(Duration::from_millis(1500));
    assert_eq!(listing(&rig.out()), ["d-1.linear.jpg".to_string()].into());
    let done = redo(&["d-1"]);
    assert!(done.status.success(), "{done:?}");
    expect_outputs(&rig.out(), &bracket_outputs(&["d-1"]), T);
    assert!(
        listing(&rig.state().join("redo")).is_empty(),
        "request taken"
    );
    rig.stop();
}

#[test]
fn polling_mode_and_archive_folder() {
    let dir = tempfile::tempdir().unwrap();
    let archive = dir.path().join("archive");
    let archive_line = format!("archive = \"{}\"", archive.display());
    let mut rig = Rig::start(
        &[
            ("watch", "mode = \"poll\""),
            ("watch", "poll_ms = 100"),
            ("folders", &archive_line),
        ],
        Arc::new(DarkroomLab),
        |_| {},
    );
    let first = aeb("Body P", 10, "w");
    put(&rig.ingest(), &first);
    expect_outputs(&rig.out(), &bracket_outputs(&["w-1"]), T);
    let expected: BTreeSet<String> = (1..=3).map(|i| format!("w-{i}.jpg")).collect();
    let start = Instant::now();
    while listing(&archive) != expected {
        assert!(start.elapsed() < T, "archive holds {:?}", listing(&archive));
        std::thread::sleep(Duration::from_millis(50));
    }
    // The camera's counter wraps: the same names again, other frames. The archive keeps
    // both sets, the second numbered.
    let second = aeb("Body P", 40, "w");
    put(&rig.ingest(), &second);
    let expected: BTreeSet<String> = (1..=3)
        .flat_map(|i| [format!("w-{i}.jpg"), format!("w-{i}-1.jpg")])
        .collect();
    let start = Instant::now();
    while listing(&archive) != expected {
        assert!(start.elapsed() < T, "archive holds {:?}", listing(&archive));
        std::thread::sleep(Duration::from_millis(50));
    }
    rig.stop();
    assert!(listing(&rig.ingest()).is_empty(), "inputs moved away");
    for (i, ((_, one), (_, two))) in first.iter().zip(&second).enumerate() {
        let k = i + 1;
        assert_eq!(
            &std::fs::read(archive.join(format!("w-{k}.jpg"))).unwrap(),
            one
        );
        assert_eq!(
            &std::fs::read(archive.join(format!("w-{k}-1.jpg"))).unwrap(),
            two
        );
    }
}

/// A frame on disk before its bracket's gap ran out belongs to it, even when the
/// watcher has not reported it yet: here a polling interval (4 s) longer than the gap
/// (1 s) reports the third frame about 3 s after the first two were taken.
#[test]
fn a_frame_the_watcher_has_not_reported_still_joins_its_bracket() {
    let mut rig = Rig::start(
        &[
            ("watch", "mode = \"poll\""),
            ("watch", "poll_ms = 4000"),
            ("watch", "rescan_s = 0"),
        ],
        Arc::new(DarkroomLab),
        |_| {},
    );
    let frames = aeb("Body L", 10, "l");
    put(&rig.ingest(), &frames[..2]);
    wait_for_status(&rig.state(), |s| s.grouping == 2);
    put(&rig.ingest(), &frames[2..]);
    expect_outputs(&rig.out(), &bracket_outputs(&["l-1"]), T);
    rig.stop();
    let entries = journal::read(&rig.state()).unwrap();
    let developed: Vec<usize> = entries
        .iter()
        .map(|e| match e {
            Entry::Bracket { inputs, .. } => inputs.len(),
            other => panic!("one bracket of three expected, journaled {other:?}"),
        })
        .collect();
    assert_eq!(developed, [3], "one bracket of three");
}

#[test]
fn reload_applies_new_rules_but_keeps_folders() {
    let mut rig = Rig::start(&[], Arc::new(DarkroomLab), |_| {});
    let mut text = config_text(&rig.root, &[("bracket", "size = 2")]);
    text = text.replace(
        &format!("out = \"{}\"", rig.out().display()),
        "out = \"/nonexistent/elsewhere\"",
    );
    let config = Config::from_str(&text, Some(Path::new("reloaded.toml"))).unwrap();
    rig.control
        .blocking_send(Control::Reload(Box::new(config)))
        .unwrap();
    std::thread::sleep(Duration::from_millis(200));
    // Size 2 now: a three-frame AEB gives a pair and a single.
    put(&rig.ingest(), &aeb("Body R", 10, "z"));
    let expected: BTreeSet<String> = bracket_outputs(&["z-1"])
        .into_iter()
        .chain(["z-3.linear.jpg".to_string()])
        .collect();
    expect_outputs(&rig.out(), &expected, T);
    rig.stop();
}

#[test]
fn recursive_watch_takes_frames_in_sub_folders() {
    let mut rig = Rig::start(
        &[("watch", "recursive = true")],
        Arc::new(DarkroomLab),
        |root| {
            // Present before start, one level down.
            let early = root.join("ingest/session-1");
            std::fs::create_dir_all(&early).unwrap();
            put(&early, &aeb("Body S", 10, "i"));
        },
    );
    // A folder made while running, then filled.
    let late = rig.ingest().join("session-2");
    std::fs::create_dir(&late).unwrap();
    std::thread::sleep(Duration::from_millis(300));
    put(&late, &aeb("Body S", 30, "j"));
    expect_outputs(&rig.out(), &bracket_outputs(&["i-1", "j-1"]), T);
    rig.stop();
}

/// The README's main command: `filmback watch --demo` with no configuration file, in a
/// fresh folder, develops its synthetic bracket into `./out` with the embedded defaults'
/// looks, says so on stdout, keeps watching, and stops cleanly on SIGTERM.
#[test]
fn watch_demo_on_embedded_defaults_develops_its_bracket_and_keeps_watching() {
    use std::io::{BufRead, BufReader};
    let dir = tempfile::tempdir().unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_filmback"))
        .args(["watch", "--demo"])
        .current_dir(dir.path())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    let stdout = child.stdout.take().unwrap();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    let mut lines = Vec::new();
    while !lines
        .iter()
        .any(|l: &String| l.starts_with("still watching"))
    {
        match rx.recv_timeout(Duration::from_secs(60)) {
            Ok(line) => lines.push(line),
            Err(e) => panic!("no demo report ({e}); stdout so far: {lines:?}"),
        }
    }
    // What the README shows: the demo camera is an sRGB one at JPEG q90 and one fixed
    // scene; its three frames fit to within 0.01 stop of sRGB at confidence 0.99 or more
    // (above the 0.5 the daemon trusts), so the daemon uses the fit. A change of the fit
    // that moves this changes the README's first command's output too.
    // The viewer's address comes first, unless its port was taken (then the daemon
    // runs without it and says so in its log).
    let report = match lines[0].strip_prefix("the tether station: open ") {
        Some(url) => {
            assert!(url.starts_with("http://127.0.0.1:8750/"), "{lines:?}");
            &lines[1..]
        }
        None => &lines[..],
    };
    assert!(
        report[0].starts_with("demo bracket developed (response: fitted)"),
        "{lines:?}"
    );
    let out: BTreeSet<String> = listing(&dir.path().join("out"));
    let stem = out
        .iter()
        .find_map(|n| n.strip_suffix(".exr"))
        .unwrap_or_else(|| panic!("no EXR in out: {out:?}"))
        .to_string();
    let expected: BTreeSet<String> = [
        format!("{stem}.exr"),
        format!("{stem}.velvia50-t1.jpg"),
        format!("{stem}.linear.jpg"),
    ]
    .into();
    assert_eq!(out, expected);
    for name in &expected {
        assert!(
            lines.iter().any(|l| l.ends_with(name.as_str())),
            "{lines:?}"
        );
    }
    assert!(child.try_wait().unwrap().is_none(), "still running");
    let took = terminate(&mut child);
    assert!(took < Duration::from_secs(10), "stopped in {took:?}");
    assert!(
        dir.path().join(".filmback").is_dir(),
        "state in ./.filmback"
    );
    assert_eq!(
        listing(&dir.path().join("ingest")).len(),
        3,
        "inputs untouched"
    );
}

// --- Issue 32: one identity per file, one daemon per state folder, frames that move ---

/// `filmback watch` in `root` (its working folder) with `config` and `extra` arguments,
/// stdout piped, stderr to `log`.
fn spawn_in(root: &Path, config: &Path, extra: &[&str], log: &Path) -> Watch {
    Watch(
        Command::new(env!("CARGO_BIN_EXE_filmback"))
            .args(["watch", "--config"])
            .arg(config)
            .args(extra)
            .current_dir(root)
            .env("RUST_LOG", "info")
            .stdout(Stdio::piped())
            .stderr(std::fs::File::create(log).unwrap())
            .spawn()
            .unwrap(),
    )
}

/// Modification times of the files in `dir`, by name.
fn mtimes(dir: &Path) -> Vec<(String, std::time::SystemTime)> {
    let mut all: Vec<_> = listing(dir)
        .into_iter()
        .map(|n| {
            let t = std::fs::metadata(dir.join(&n)).unwrap().modified().unwrap();
            (n, t)
        })
        .collect();
    all.sort();
    all
}

/// Issue 32, item 1: with folders given relative to the working folder (`./ingest`,
/// `out/`), the watcher's absolute paths and the rescan's listing are one file: the demo
/// bracket is developed once, its outputs are not rewritten by later rescans (every
/// second here), nor after a restart.
#[test]
fn relative_folders_develop_the_demo_bracket_once_across_rescans_and_a_restart() {
    use std::io::{BufRead, BufReader};
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    let config = root.join("relative.toml");
    std::fs::write(
        &config,
        "[folders]\ningest = \"./ingest\"\nout = \"out/\"\nstate = \".filmback\"\n\
         [watch]\nsettle_ms = 150\nrescan_s = 1\n[bracket]\nmax_gap_s = 1.0\n\
         [render]\nfilms = []\ntonemaps = [\"linear\"]\n[viewer]\nenabled = false\n",
    )
    .unwrap();
    let mut child = spawn_in(root, &config, &["--demo"], &root.join("first.log"));
    let stdout = child.stdout.take().unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    let mut lines: Vec<String> = Vec::new();
    while !lines.iter().any(|l| l.starts_with("still watching")) {
        match rx.recv_timeout(Duration::from_secs(60)) {
            Ok(line) => lines.push(line),
            Err(e) => panic!("no demo report ({e}); stdout so far: {lines:?}"),
        }
    }
    assert!(
        lines
            .first()
            .is_some_and(|l| l.starts_with("demo bracket developed")),
        "{lines:?}"
    );
    let state = root.join(".filmback");
    let out = root.join("out");
    let developed = mtimes(&out);
    assert_eq!(developed.len(), 2, "{developed:?}");
    // Three rescans.
    std::thread::sleep(Duration::from_millis(3500));
    assert_eq!(journal::read(&state).unwrap().len(), 1, "developed once");
    assert_eq!(mtimes(&out), developed, "outputs not rewritten");
    terminate(&mut child);
    let mut child = spawn_in(root, &config, &[], &root.join("second.log"));
    wait_for_status(&state, |s| s.running && s.pid == child.id());
    std::thread::sleep(Duration::from_millis(2500));
    terminate(&mut child);
    assert_eq!(
        journal::read(&state).unwrap().len(),
        1,
        "not again after a restart"
    );
    assert_eq!(mtimes(&out), developed);
}

/// Issue 32, 2.5: a second daemon on a state folder in use refuses to start, naming the
/// folder and the pid holding it; the first goes on working.
#[test]
fn a_second_daemon_on_the_same_state_folder_refuses_to_start() {
    let mut rig = Rig::start(&[], Arc::new(DarkroomLab), |_| {});
    wait_for_status(&rig.state(), |s| s.running);
    let config = rig.root.join("second.toml");
    std::fs::write(&config, config_text(&rig.root, &[])).unwrap();
    let mut second = Command::new(env!("CARGO_BIN_EXE_filmback"))
        .args(["watch", "--config"])
        .arg(&config)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    let status = loop {
        if let Some(status) = second.try_wait().unwrap() {
            break status;
        }
        if start.elapsed() > Duration::from_secs(20) {
            let _ = second.kill();
            let _ = second.wait();
            panic!("a second daemon started on the same state folder");
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    let mut said = String::new();
    std::io::Read::read_to_string(&mut second.stderr.take().unwrap(), &mut said).unwrap();
    assert!(!status.success());
    assert!(said.contains(&rig.state().display().to_string()), "{said}");
    assert!(
        said.contains(&format!("pid {}", std::process::id())),
        "{said}"
    );
    put(&rig.ingest(), &aeb("Body A", 10, "q"));
    expect_outputs(&rig.out(), &bracket_outputs(&["q-1"]), T);
    rig.stop();
}

/// Issue 32, 2.6: a frame moved away while its bracket is open, and moved back, is
/// waited for (shown in `status`), never rejected; its bracket is developed whole.
#[test]
fn a_frame_missing_for_a_moment_is_waited_for_not_rejected() {
    let mut rig = Rig::start(&[("bracket", "size = 4")], Arc::new(DarkroomLab), |_| {});
    put(&rig.ingest(), &aeb("Body M", 10, "v"));
    wait_for_status(&rig.state(), |s| s.grouping == 3);
    let (here, away) = (rig.ingest().join("v-2.jpg"), rig.root.join("v-2.jpg"));
    std::fs::rename(&here, &away).unwrap();
    wait_for_status(&rig.state(), |s| {
        s.retries
            .iter()
            .any(|r| r.what == "v-1" && r.reason.contains("v-2.jpg"))
    });
    std::fs::rename(&away, &here).unwrap();
    expect_outputs(&rig.out(), &bracket_outputs(&["v-1"]), T);
    let state = rig.state();
    rig.stop();
    assert!(rejected(&state).is_empty(), "{:?}", rejected(&state));
    let entries = journal::read(&state).unwrap();
    assert!(
        matches!(&entries[..], [Entry::Bracket { inputs, .. }] if inputs.len() == 3),
        "{entries:?}"
    );
}

/// Issue 32, 2.7: a frame replaced while its bracket develops (no periodic rescan to
/// catch it) is developed again with the new frame, its outputs replaced in place.
#[test]
fn a_frame_replaced_while_its_bracket_develops_is_developed_again() {
    let gate = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let calls = Arc::new(AtomicUsize::new(0));
    let (g, c) = (Arc::clone(&gate), Arc::clone(&calls));
    let lab = move |job: &Job| -> Result<Processed, JobError> {
        c.fetch_add(1, Ordering::SeqCst);
        while !g.load(Ordering::SeqCst) {
            std::thread::sleep(Duration::from_millis(10));
        }
        DarkroomLab.process(job)
    };
    let mut rig = Rig::start(&[("watch", "rescan_s = 0")], Arc::new(lab), |_| {});
    put(&rig.ingest(), &aeb("Body N", 10, "n"));
    let start = Instant::now();
    while calls.load(Ordering::SeqCst) == 0 {
        assert!(start.elapsed() < T, "the bracket never started developing");
        std::thread::sleep(Duration::from_millis(20));
    }
    let replacement = aeb("Body N", 50, "n").swap_remove(1).1;
    let path = rig.ingest().join("n-2.jpg");
    atomic::publish(&path, &replacement, Overwrite::Replace).unwrap();
    gate.store(true, Ordering::SeqCst);
    let state = rig.state();
    let start = Instant::now();
    while journaled_brackets_all(&state) < 2 {
        assert!(
            start.elapsed() < T,
            "not developed again: {:?}",
            journal::read(&state).unwrap()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    expect_outputs(&rig.out(), &bracket_outputs(&["n-1"]), T);
    rig.stop();
    let now = std::fs::metadata(&path).unwrap();
    let entries = journal::read(&state).unwrap();
    let Some(Entry::Bracket { inputs, .. }) = entries.last() else {
        panic!("{entries:?}");
    };
    let new = inputs.iter().find(|i| i.path.ends_with("n-2.jpg")).unwrap();
    assert_eq!(new.size, now.len(), "the new frame was developed");
    assert_eq!(journaled_brackets_all(&state), 2);
}

/// Issue 32, 2.11: a state folder the daemon can no longer write leaves `status.json`
/// behind; `status` says its data may be stale. Run as `nobody` when root (permissions
/// do not bind root).
#[test]
fn status_says_when_the_state_folder_is_not_writable() {
    use std::os::unix::fs::PermissionsExt;
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    open_folders(root);
    let config = root.join("filmback.toml");
    std::fs::write(&config, config_text(root, &[])).unwrap();
    let mut child = Watch(
        unprivileged(env!("CARGO_BIN_EXE_filmback"))
            .args(["watch", "--config"])
            .arg(&config)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    let state = root.join("state");
    wait_for_status(&state, |s| s.running);
    let status = || {
        let shown = unprivileged(env!("CARGO_BIN_EXE_filmback"))
            .args(["status", "--state"])
            .arg(&state)
            .output()
            .unwrap();
        String::from_utf8_lossy(&shown.stdout).into_owned()
    };
    assert!(!status().contains("stale"), "{}", status());
    std::fs::set_permissions(&state, std::fs::Permissions::from_mode(0o555)).unwrap();
    let shown = status();
    std::fs::set_permissions(&state, std::fs::Permissions::from_mode(0o777)).unwrap();
    assert!(shown.contains("may be stale"), "{shown}");
    terminate(&mut child);
}

/// The daemon under `[render] ghost_map = true` writes each bracket's ghost map beside its
/// EXR and looks.
#[test]
fn the_daemon_writes_the_ghost_map_when_its_preset_asks() {
    let dir = tempfile::tempdir().unwrap();
    let text = rig::config_text(dir.path(), "ghost_map = true\n");
    let mut rig = rig::Rig::start_with_text(dir.path(), &text, Arc::new(DarkroomLab));
    rig::put(&rig.ingest(), &rig::aeb("Ghost Body", 30, "g"));
    let expected = ["g-1.exr", "g-1.linear.jpg", "g-1.ghosts.png"];
    let done = |names: &[String]| expected.iter().all(|n| names.iter().any(|m| m == n));
    rig::wait_for(&rig.out(), "the bracket's outputs", done);
    rig.stop();
}
