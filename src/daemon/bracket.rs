//! Grouping frames into brackets: pure logic on what EXIF said, no files, no clocks.
//!
//! Frames are grouped per camera body (make, model, serial) in capture-time order (EXIF
//! `DateTimeOriginal` with sub-seconds; the arrival time when the file has none). A
//! bracket is a run of successive frames at most `max_gap_s` apart whose exposures all
//! differ by at least `min_step_ev` stops, where a frame's exposure in stops is
//! `log2(e)`, `e = t·S/N²`. A bracket closes when an exposure repeats (the next bracket
//! has begun), when the gap passes, or when it holds `size` frames. A group that closes
//! with one frame is a single, never dropped: the daemon renders or reports it.

use std::collections::BTreeMap;
use std::fmt;
use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::daemon::config::BracketRules;

/// The camera body a frame came from; brackets never mix bodies.
#[derive(Debug, Clone, Default, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub struct CameraId {
    /// EXIF `Make`.
    pub make: Option<String>,
    /// EXIF `Model`.
    pub model: Option<String>,
    /// EXIF `BodySerialNumber`.
    pub serial: Option<String>,
}

impl fmt::Display for CameraId {
    /// `Canon EOS R5 #042`, `unknown camera` when EXIF named none.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let model = self.model.as_deref().unwrap_or("");
        let make = self.make.as_deref().unwrap_or("");
        // Models usually repeat the make ("Canon EOS R5"); don't print it twice.
        let name = if model.is_empty() {
            make.to_string()
        } else if make.is_empty() || model.to_lowercase().starts_with(&make.to_lowercase()) {
            model.to_string()
        } else {
            format!("{make} {model}")
        };
        let name = if name.is_empty() {
            "unknown camera"
        } else {
            name.as_str()
        };
        match &self.serial {
            Some(s) => write!(f, "{name} #{s}"),
            None => write!(f, "{name}"),
        }
    }
}

/// One input file as it was when taken: its identity for the journal.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub struct Input {
    /// Where it is (any name the file system allows; see [`crate::daemon::journal::any_path`]).
    #[serde(with = "crate::daemon::journal::any_path")]
    pub path: PathBuf,
    /// Size in bytes.
    pub size: u64,
    /// Modification time, nanoseconds since the Unix epoch.
    pub modified_ns: i64,
}

/// A settled frame with what its EXIF said (pixels are not loaded yet).
#[derive(Debug, Clone, PartialEq)]
pub struct Capture {
    /// The file.
    pub input: Input,
    /// The body.
    pub camera: CameraId,
    /// Relative exposure `e = t·S/N²` (s·ISO), `None` when EXIF lacks a part of it.
    pub exposure: Option<f64>,
    /// Capture time in seconds (EXIF, camera clock), or arrival time when EXIF has none.
    pub time_s: f64,
    /// For a raw shot RAW+JPEG: the camera's JPEG (or PNG, TIFF) of the same capture, as
    /// it was when the daemon set it aside. It is not a frame (the raw is merged); a lab
    /// may read it beside the raw, e.g. to measure the body's JPEG response.
    pub companion: Option<Input>,
}

impl Capture {
    /// Exposure in stops, `log2(e)`.
    pub fn stops(&self) -> Option<f64> {
        self.exposure.filter(|e| *e > 0.0).map(f64::log2)
    }
}

/// Two or more frames of one body, in capture-time order.
#[derive(Debug, Clone, PartialEq)]
pub struct Bracket {
    /// The body.
    pub camera: CameraId,
    /// The frames, in capture-time order (each with a known exposure).
    pub frames: Vec<Capture>,
}

/// Why a frame stands alone.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Alone {
    /// No partner within the gap and exposure rules.
    NoPartner,
    /// EXIF lacks exposure time, f-number or ISO, so it cannot join a bracket.
    NoExposure,
}

impl fmt::Display for Alone {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Alone::NoPartner => "no partner frame within the gap and exposure rules",
            Alone::NoExposure => "EXIF lacks exposure time, f-number or ISO",
        })
    }
}

/// What a closed group is.
#[derive(Debug, Clone, PartialEq)]
pub enum Closed {
    /// A bracket to merge.
    Bracket(Bracket),
    /// A frame alone.
    Single(Capture, Alone),
}

impl Closed {
    /// The frames, in capture order.
    pub fn frames(&self) -> Vec<&Capture> {
        match self {
            Closed::Bracket(b) => b.frames.iter().collect(),
            Closed::Single(c, _) => vec![c],
        }
    }

    /// The frames, in capture order, to amend (e.g. with their companions).
    pub fn frames_mut(&mut self) -> Vec<&mut Capture> {
        match self {
            Closed::Bracket(b) => b.frames.iter_mut().collect(),
            Closed::Single(c, _) => vec![c],
        }
    }

    /// The body.
    pub fn camera(&self) -> &CameraId {
        match self {
            Closed::Bracket(b) => &b.camera,
            Closed::Single(c, _) => &c.camera,
        }
    }

    /// Deterministic id: [`fingerprint`] of the inputs.
    pub fn id(&self) -> String {
        fingerprint(self.frames().iter().map(|c| &c.input))
    }

    /// Output name stem: the first frame's file stem, shortened by
    /// [`crate::atomic::fitting_stem`] when the outputs' names would not fit.
    pub fn stem(&self) -> String {
        let first = self.frames()[0];
        let stem = first
            .input
            .path
            .file_stem()
            .map_or_else(|| "frame".to_string(), |s| s.to_string_lossy().into_owned());
        crate::atomic::fitting_stem(&stem).into_owned()
    }
}

impl Bracket {
    /// Exposure ratio of the brightest to the darkest frame, `e_max / e_min`.
    pub fn ratio(&self) -> f64 {
        let e: Vec<f64> = self.frames.iter().filter_map(|c| c.exposure).collect();
        let max = e.iter().copied().fold(f64::MIN, f64::max);
        let min = e.iter().copied().fold(f64::MAX, f64::min);
        max / min
    }
}

/// A deterministic 64-bit FNV-1a hash, in hex, of the inputs' file names, sizes and
/// modification times, independent of their order: the same files give the same id
/// after a restart, a rewritten file gives a new one.
pub fn fingerprint<'a>(inputs: impl IntoIterator<Item = &'a Input>) -> String {
    let mut keys: Vec<String> = inputs
        .into_iter()
        .map(|i| {
            let name = i
                .path
                .file_name()
                .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
            format!("{name}\u{0}{}\u{0}{}", i.size, i.modified_ns)
        })
        .collect();
    keys.sort();
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for k in keys {
        for b in k.bytes().chain(std::iter::once(0xff)) {
            h ^= u64::from(b);
            h = h.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
    format!("{h:016x}")
}

/// An open group of one body.
#[derive(Debug)]
struct Open {
    /// Frames sorted by capture time.
    frames: Vec<Capture>,
    /// When the last frame arrived (the caller's clock, seconds).
    last_arrival: f64,
}

/// Groups captures as they arrive (see the module docs).
#[derive(Debug)]
pub struct Grouper {
    rules: BracketRules,
    open: BTreeMap<CameraId, Open>,
}

impl Grouper {
    /// An empty grouper.
    pub fn new(rules: BracketRules) -> Grouper {
        Grouper {
            rules,
            open: BTreeMap::new(),
        }
    }

    /// Replaces the rules (config reload); open groups keep their frames.
    pub fn set_rules(&mut self, rules: BracketRules) {
        self.rules = rules;
    }

    /// Frames waiting in open groups.
    pub fn waiting(&self) -> usize {
        self.open.values().map(|o| o.frames.len()).sum()
    }

    /// Adds a capture that arrived at `now` (seconds, any monotone clock); returns the
    /// groups it closed. Captures of one body should be pushed in capture-time order
    /// (a batch found at start-up is sorted first); small reorderings within one open
    /// group are absorbed.
    pub fn push(&mut self, capture: Capture, now: f64) -> Vec<Closed> {
        let Some(stops) = capture.stops() else {
            return vec![Closed::Single(capture, Alone::NoExposure)];
        };
        let mut closed = Vec::new();
        let rules = self.rules;
        if let Some(open) = self.open.get(&capture.camera) {
            let first = open.frames.first().map_or(capture.time_s, |c| c.time_s);
            let last = open.frames.last().map_or(capture.time_s, |c| c.time_s);
            let gap =
                capture.time_s - last > rules.max_gap_s || first - capture.time_s > rules.max_gap_s;
            let repeat = open
                .frames
                .iter()
                .filter_map(Capture::stops)
                .any(|s| (s - stops).abs() < rules.min_step_ev);
            if gap || repeat {
                let open = self.open.remove(&capture.camera).expect("checked above");
                closed.push(close(capture.camera.clone(), open.frames));
            }
        }
        let camera = capture.camera.clone();
        let open = self.open.entry(camera.clone()).or_insert(Open {
            frames: Vec::new(),
            last_arrival: now,
        });
        let at = open.frames.partition_point(|c| c.time_s <= capture.time_s);
        open.frames.insert(at, capture);
        open.last_arrival = now;
        if open.frames.len() >= rules.size {
            let open = self.open.remove(&camera).expect("just inserted");
            closed.push(close(camera, open.frames));
        }
        closed
    }

    /// True when [`Grouper::expire`] at `now` would close a group.
    pub fn due(&self, now: f64) -> bool {
        self.open.values().any(|o| self.stale(o, now))
    }

    /// Closes every group whose last frame arrived more than `max_gap_s` before `now`:
    /// no further frame of that bracket can still come.
    pub fn expire(&mut self, now: f64) -> Vec<Closed> {
        let stale: Vec<CameraId> = self
            .open
            .iter()
            .filter(|(_, o)| self.stale(o, now))
            .map(|(k, _)| k.clone())
            .collect();
        stale
            .into_iter()
            .map(|k| {
                let open = self.open.remove(&k).expect("listed above");
                close(k, open.frames)
            })
            .collect()
    }

    /// Takes the frame at `path` out of its open group (its raw arrived: the JPEG of a
    /// RAW+JPEG capture is not a frame of its own); `None` when no open group holds it.
    pub fn withdraw(&mut self, path: &std::path::Path) -> Option<Capture> {
        let (camera, at) = self.open.iter().find_map(|(camera, open)| {
            open.frames
                .iter()
                .position(|c| c.input.path == path)
                .map(|at| (camera.clone(), at))
        })?;
        let open = self.open.get_mut(&camera).expect("found above");
        let capture = open.frames.remove(at);
        if open.frames.is_empty() {
            self.open.remove(&camera);
        }
        Some(capture)
    }

    fn stale(&self, open: &Open, now: f64) -> bool {
        now - open.last_arrival > self.rules.max_gap_s
    }

    /// Restarts the gap clock of every open group: called while the daemon is not taking
    /// new files (queue full), so a bracket is not closed early for lack of frames that
    /// are in fact waiting on disk.
    pub fn postpone(&mut self, now: f64) {
        for open in self.open.values_mut() {
            open.last_arrival = now;
        }
    }
}

fn close(camera: CameraId, mut frames: Vec<Capture>) -> Closed {
    if frames.len() == 1 {
        Closed::Single(frames.pop().expect("one frame"), Alone::NoPartner)
    } else {
        Closed::Bracket(Bracket { camera, frames })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::daemon::config::Singles;
    use std::path::Path;

    fn rules(size: usize) -> BracketRules {
        BracketRules {
            max_gap_s: 2.0,
            min_step_ev: 0.5,
            size,
            singles: Singles::Render,
        }
    }

    fn cam(model: &str) -> CameraId {
        CameraId {
            make: Some("Canon".into()),
            model: Some(model.into()),
            serial: None,
        }
    }

    fn shot(name: &str, camera: &CameraId, ev: f64, t: f64) -> Capture {
        Capture {
            input: Input {
                path: PathBuf::from(format!("/in/{name}.jpg")),
                size: 1000,
                modified_ns: 5,
            },
            camera: camera.clone(),
            exposure: Some(2f64.powf(ev)),
            time_s: t,
            companion: None,
        }
    }

    fn names(c: &Closed) -> Vec<String> {
        c.frames()
            .iter()
            .map(|f| {
                f.input
                    .path
                    .file_stem()
                    .unwrap()
                    .to_string_lossy()
                    .into_owned()
            })
            .collect()
    }

    fn run(g: &mut Grouper, shots: Vec<Capture>) -> Vec<Closed> {
        let mut out = Vec::new();
        for (i, s) in shots.into_iter().enumerate() {
            out.extend(g.push(s, i as f64 * 0.1));
        }
        out
    }

    #[test]
    fn closes_on_size() {
        let c = cam("EOS R5");
        let mut g = Grouper::new(rules(3));
        let out = run(
            &mut g,
            vec![
                shot("a", &c, 0.0, 0.0),
                shot("b", &c, -2.0, 0.3),
                shot("c", &c, 2.0, 0.6),
                shot("d", &c, 0.0, 10.0),
            ],
        );
        assert_eq!(out.len(), 1);
        assert!(matches!(out[0], Closed::Bracket(_)));
        assert_eq!(names(&out[0]), ["a", "b", "c"]);
        assert_eq!(g.waiting(), 1);
        if let Closed::Bracket(b) = &out[0] {
            assert!((b.ratio() - 16.0).abs() < 1e-9);
        }
    }

    #[test]
    fn repeated_exposure_starts_a_new_bracket() {
        let c = cam("EOS R5");
        let mut g = Grouper::new(rules(3));
        let out = run(
            &mut g,
            vec![
                shot("a", &c, 0.0, 0.0),
                shot("b", &c, 1.0, 0.2),
                shot("a2", &c, 0.2, 0.4), // within 0.5 EV of a: a repeat
                shot("b2", &c, 1.0, 0.6),
                shot("c2", &c, 2.0, 0.8),
            ],
        );
        assert_eq!(out.len(), 2);
        assert_eq!(names(&out[0]), ["a", "b"]);
        assert_eq!(names(&out[1]), ["a2", "b2", "c2"]);
    }

    #[test]
    fn gap_closes_and_lone_frame_is_a_single() {
        let c = cam("EOS R5");
        let mut g = Grouper::new(rules(3));
        let out = run(
            &mut g,
            vec![
                shot("a", &c, 0.0, 0.0),
                shot("b", &c, 1.0, 5.0), // 5 s later: gap
                shot("c", &c, 2.0, 5.5),
            ],
        );
        assert_eq!(out.len(), 1);
        assert_eq!(
            out[0],
            Closed::Single(shot("a", &c, 0.0, 0.0), Alone::NoPartner)
        );
        // Nothing more arrives: the open pair expires by the arrival clock.
        assert!(!g.due(1.0));
        assert!(g.expire(1.0).is_empty());
        assert!(g.due(10.0));
        let late = g.expire(10.0);
        assert_eq!(late.len(), 1);
        assert_eq!(names(&late[0]), ["b", "c"]);
        assert_eq!(g.waiting(), 0);
        // Postponed groups wait a full gap from the postponement.
        g.push(shot("d", &c, 0.0, 20.0), 10.0);
        g.postpone(11.5);
        assert!(g.expire(13.0).is_empty());
        assert_eq!(g.expire(13.6).len(), 1);
    }

    #[test]
    fn a_withdrawn_frame_leaves_its_group_and_an_empty_group_goes() {
        let c = cam("EOS R5");
        let mut g = Grouper::new(rules(3));
        g.push(shot("a", &c, 0.0, 0.0), 0.0);
        g.push(shot("b", &c, 1.0, 0.2), 0.1);
        let a = g.withdraw(Path::new("/in/a.jpg")).expect("a is open");
        assert_eq!(a, shot("a", &c, 0.0, 0.0));
        assert!(g.withdraw(Path::new("/in/a.jpg")).is_none());
        assert_eq!(g.waiting(), 1);
        assert!(g.withdraw(Path::new("/in/b.jpg")).is_some());
        assert_eq!(g.waiting(), 0);
        assert!(
            g.expire(100.0).is_empty(),
            "no empty group is left to close"
        );
    }

    #[test]
    fn interleaved_cameras_form_separate_brackets() {
        let (x, y) = (cam("EOS R5"), cam("EOS R6"));
        let mut y_serial = y.clone();
        y_serial.serial = Some("2".into());
        let mut g = Grouper::new(rules(2));
        let out = run(
            &mut g,
            vec![
                shot("x1", &x, 0.0, 0.0),
                shot("y1", &y, 0.0, 0.1),
                shot("z1", &y_serial, 0.0, 0.15),
                shot("x2", &x, 1.0, 0.2),
                shot("y2", &y, 1.0, 0.3),
                shot("z2", &y_serial, 1.0, 0.35),
            ],
        );
        let got: Vec<_> = out.iter().map(names).collect();
        assert_eq!(got, [vec!["x1", "x2"], vec!["y1", "y2"], vec!["z1", "z2"]]);
        assert_eq!(out[0].camera(), &x);
    }

    #[test]
    fn reordered_arrival_is_sorted_by_capture_time() {
        let c = cam("EOS R5");
        let mut g = Grouper::new(rules(3));
        let out = run(
            &mut g,
            vec![
                shot("b", &c, -1.0, 0.5),
                shot("a", &c, 0.0, 0.0),
                shot("c", &c, 1.0, 1.0),
            ],
        );
        assert_eq!(names(&out[0]), ["a", "b", "c"]);
        assert_eq!(out[0].stem(), "a");
    }

    #[test]
    fn unknown_exposure_is_a_single_and_keeps_the_group() {
        let c = cam("EOS R5");
        let mut g = Grouper::new(rules(2));
        let mut blind = shot("n", &c, 0.0, 0.1);
        blind.exposure = None;
        let out = run(
            &mut g,
            vec![
                shot("a", &c, 0.0, 0.0),
                blind.clone(),
                shot("b", &c, 1.0, 0.2),
            ],
        );
        assert_eq!(out[0], Closed::Single(blind, Alone::NoExposure));
        assert_eq!(names(&out[1]), ["a", "b"]);
    }

    #[test]
    fn step_below_min_is_a_repeat_and_singles_are_never_lost() {
        let c = cam("EOS R5");
        let mut g = Grouper::new(rules(3));
        // Five frames at the same exposure: five singles.
        let mut out = run(
            &mut g,
            (0..5)
                .map(|i| shot(&format!("s{i}"), &c, 0.0, f64::from(i) * 0.1))
                .collect(),
        );
        out.extend(g.expire(100.0));
        assert_eq!(out.len(), 5);
        assert!(
            out.iter()
                .all(|o| matches!(o, Closed::Single(_, Alone::NoPartner)))
        );
    }

    #[test]
    fn fingerprint_is_order_free_and_sees_changes() {
        let a = Input {
            path: "/x/a.jpg".into(),
            size: 10,
            modified_ns: 1,
        };
        let b = Input {
            path: "/y/b.jpg".into(),
            size: 20,
            modified_ns: 2,
        };
        assert_eq!(fingerprint([&a, &b]), fingerprint([&b, &a]));
        assert_eq!(fingerprint([&a]).len(), 16);
        let mut b2 = b.clone();
        b2.modified_ns = 3;
        assert_ne!(fingerprint([&a, &b]), fingerprint([&a, &b2]));
        // Pinned: ids in existing journals must stay valid across versions.
        assert_eq!(fingerprint([&a]), "0890d6a79e98a87e");
    }

    #[test]
    fn camera_names_read_well() {
        assert_eq!(cam("EOS R5").to_string(), "Canon EOS R5");
        let mut c = cam("Canon EOS R5");
        c.serial = Some("042".into());
        assert_eq!(c.to_string(), "Canon EOS R5 #042");
        assert_eq!(CameraId::default().to_string(), "unknown camera");
    }
}
