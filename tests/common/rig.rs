//! A watch-folder daemon in a temporary folder, for tests outside `tests/daemon.rs`:
//! in-process ([`Rig`]) or the real binary under a memory cap ([`CappedWatch`]), with
//! short settle and gap times, and the frames to feed it.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::time::{Duration, Instant};

use filmback::daemon::config::Config;
use filmback::daemon::journal::{self, Entry};
use filmback::daemon::{self, Control, Lab};
use filmback::synthetic::demo;

/// Frame size of the rig's brackets.
pub const W: u32 = 96;
/// Frame height.
pub const H: u32 = 64;

/// How long a rig's test waits for what it expects.
pub const PATIENCE: Duration = Duration::from_secs(40);

/// The rig's configuration: folders under `root`, 150 ms settle, 1 s bracket gap,
/// brackets of 3, the linear look only; `extra` is appended (whole tables).
pub fn config_text(root: &Path, extra: &str) -> String {
    format!(
        r#"
[folders]
ingest = "{ingest}"
out = "{out}"
state = "{state}"
[watch]
settle_ms = 150
rescan_s = 2
[bracket]
max_gap_s = 1.0
size = 3
[daemon]
jobs = 2
queue = 8
retry_s = 1
[render]
films = []
tonemaps = ["linear"]
{extra}
{viewer}
"#,
        ingest = root.join("ingest").display(),
        out = root.join("out").display(),
        state = root.join("state").display(),
        // No viewer unless `extra` sets one up: its previews would cost every bracket.
        viewer = if extra.contains("[viewer]") {
            ""
        } else {
            "[viewer]\nenabled = false"
        },
    )
}

/// A daemon run in-process (its own runtime on a thread) on a temporary folder.
pub struct Rig {
    /// The folder holding `ingest/`, `out/` and `state/`.
    pub root: PathBuf,
    _dir: Option<tempfile::TempDir>,
    control: tokio::sync::mpsc::Sender<Control>,
    thread: Option<std::thread::JoinHandle<daemon::Summary>>,
}

impl Rig {
    /// Starts a daemon with `lab` on a new temporary folder.
    pub fn start(lab: Arc<dyn Lab>) -> Rig {
        let dir = tempfile::tempdir().unwrap();
        let mut rig = Rig::start_in(dir.path(), lab);
        rig._dir = Some(dir);
        rig
    }

    /// Starts a daemon with `lab` on `root` (kept when the rig ends: a restart).
    pub fn start_in(root: &Path, lab: Arc<dyn Lab>) -> Rig {
        let config = Config::from_str(&config_text(root, ""), Some(Path::new("test.toml")))
            .expect("test config is valid");
        Rig::start_with(root, config, lab)
    }

    /// Starts a daemon with `lab` on `root` under the configuration `text`.
    pub fn start_with_text(root: &Path, text: &str, lab: Arc<dyn Lab>) -> Rig {
        let config =
            Config::from_str(text, Some(Path::new("test.toml"))).expect("test config is valid");
        Rig::start_with(root, config, lab)
    }

    /// Starts a daemon with `lab` on `root` under `config` (whose folders should be
    /// those of [`config_text`]).
    pub fn start_with(root: &Path, config: Config, lab: Arc<dyn Lab>) -> Rig {
        std::fs::create_dir_all(root.join("ingest")).unwrap();
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
        Rig {
            root: root.to_path_buf(),
            _dir: None,
            control,
            thread: Some(thread),
        }
    }

    /// The ingest folder.
    pub fn ingest(&self) -> PathBuf {
        self.root.join("ingest")
    }

    /// The output folder.
    pub fn out(&self) -> PathBuf {
        self.root.join("out")
    }

    /// The state folder.
    pub fn state(&self) -> PathBuf {
        self.root.join("state")
    }

    /// Stops the daemon and waits for it.
    pub fn stop(&mut self) -> daemon::Summary {
        self.control.blocking_send(Control::Stop).unwrap();
        self.thread.take().unwrap().join().unwrap()
    }
}

/// `filmback watch --config FILE` as a child under a 4 GB address-space limit (a file
/// that makes it allocate without bound ends it, not the machine), stopped with SIGTERM
/// when dropped. Its log goes to `FILE.log`.
pub struct CappedWatch(Child);

impl CappedWatch {
    /// Starts the binary on the rig configuration of `root`.
    pub fn start(root: &Path) -> CappedWatch {
        std::fs::create_dir_all(root.join("ingest")).unwrap();
        let config = root.join("filmback.toml");
        std::fs::write(&config, config_text(root, "")).unwrap();
        CappedWatch(
            Command::new("sh")
                .arg("-c")
                .arg(r#"ulimit -v 4000000; exec "$0" watch --config "$1""#)
                .arg(env!("CARGO_BIN_EXE_filmback"))
                .arg(&config)
                .env("RUST_LOG", "info")
                .stdout(Stdio::null())
                .stderr(std::fs::File::create(config.with_extension("log")).unwrap())
                .spawn()
                .unwrap(),
        )
    }
}

impl Drop for CappedWatch {
    fn drop(&mut self) {
        let _ = Command::new("kill")
            .args(["-TERM", &self.0.id().to_string()])
            .status();
        let start = Instant::now();
        while start.elapsed() < Duration::from_secs(10) {
            if self.0.try_wait().is_ok_and(|s| s.is_some()) {
                return;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// A three-frame AEB of `model` at `second` as JPEGs, named `<prefix>-1.jpg` …
pub fn aeb(model: &str, second: u32, prefix: &str) -> Vec<(String, Vec<u8>)> {
    let shots = demo::aeb(model, None, second);
    demo::jpegs(W, H, &shots, u64::from(second))
        .unwrap()
        .into_iter()
        .enumerate()
        .map(|(i, bytes)| (format!("{prefix}-{}.jpg", i + 1), bytes))
        .collect()
}

/// [`aeb`] with a subject moving across it: a flat square of side 16, code 200 in every
/// frame whatever its exposure, its left edge at `10 + 30k` px in frame `k` (rows 24..40).
pub fn aeb_with_subject(model: &str, second: u32, prefix: &str) -> Vec<(String, Vec<u8>)> {
    use filmback::frame::{BitDepth, Frame, Samples};
    use filmback::synthetic::{self, Encoding, ResponseCurve, Sensor};
    let shots = demo::aeb(model, None, second);
    let scene = synthetic::scene(W, H, u64::from(second));
    let sensor = Sensor::noiseless(ResponseCurve::Srgb, BitDepth::Eight);
    let middle = shots[shots.len() / 2].exposure.relative().unwrap();
    let frames = synthetic::bracket(&scene, &sensor, &shots, 1.0 / middle).unwrap();
    let w = W as usize;
    frames
        .iter()
        .zip(&shots)
        .enumerate()
        .map(|(k, (frame, shot))| {
            let Samples::Eight(mut codes) = frame.samples().clone() else {
                unreachable!("the sensor is 8-bit")
            };
            let x0 = 10 + 30 * k;
            for y in 24..40 {
                codes[(y * w + x0) * 3..(y * w + x0 + 16) * 3].fill(200);
            }
            let frame = Frame::new(W, H, 3, Samples::Eight(codes)).unwrap();
            let bytes = synthetic::encode(&frame, shot, Encoding::Jpeg { quality: 90 }).unwrap();
            (format!("{prefix}-{}.jpg", k + 1), bytes)
        })
        .collect()
}

#[cfg(feature = "raw")]
/// The same AEB as DNGs (`<prefix>-1.dng` …) from a 14-bit RGGB sensor, the longest
/// frame's mid-grey at 0.18 of full scale.
pub fn raw_aeb(model: &str, second: u32, prefix: &str) -> Vec<(String, Vec<u8>)> {
    use filmback::synthetic;
    let shots = demo::aeb(model, None, second);
    let scene = synthetic::scene(W, H, u64::from(second));
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
            let dng = synthetic::dng(&codes, W, H, &sensor, shot).unwrap();
            (format!("{prefix}-{}.dng", i + 1), dng)
        })
        .collect()
}

/// Drops `frames` into `dir` as a tethering tool does (written aside, renamed in).
pub fn put(dir: &Path, frames: &[(String, Vec<u8>)]) {
    for (name, bytes) in frames {
        demo::drop_frame(dir, name, bytes).unwrap();
    }
}

/// The names in `dir` that are not hidden (staging folders, temporaries).
pub fn visible(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .map(|d| {
            d.filter_map(Result::ok)
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| !n.starts_with('.'))
                .collect()
        })
        .unwrap_or_default();
    names.sort();
    names
}

/// Waits until `ok` holds of the visible names in `dir`; panics after [`PATIENCE`].
pub fn wait_for(dir: &Path, what: &str, ok: impl Fn(&[String]) -> bool) -> Vec<String> {
    let start = Instant::now();
    loop {
        let names = visible(dir);
        if ok(&names) {
            return names;
        }
        assert!(
            start.elapsed() < PATIENCE,
            "timed out waiting for {what}: {} holds {names:?}",
            dir.display()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// The journal's rejected files: `(file name, reason)`.
pub fn rejected(state: &Path) -> Vec<(String, String)> {
    journal::read(state)
        .unwrap_or_default()
        .into_iter()
        .filter_map(|e| match e {
            Entry::Rejected { input, reason, .. } => Some((
                input.path.file_name()?.to_string_lossy().into_owned(),
                reason,
            )),
            _ => None,
        })
        .collect()
}
