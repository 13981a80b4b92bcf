//! Grouping frames into brackets: pure logic on what EXIF said, no files, no clocks.
//!
//! Frames are grouped per camera body (make, model, serial) in capture-time order (EXIF
//! `DateTimeOriginal` with sub-seconds; the arrival time when the file has none). A
//! bracket is a run of successive frames at most `max_gap_s` apart whose exposures all
//! differ by at least `min_step_ev` stops, where a frame's exposure in stops is
//! `log2(e)`, `e = t·S/N²`; a repeated exposure begins the next bracket, and a bracket
//! holds at most `size` frames. Frames may arrive in any order within the gap: a
//! bracket closes once it holds `size` frames, or once `max_gap_s` has passed on the
//! arrival clock since anything that could still belong to it could have arrived. A
//! group that closes with one frame is a single, never dropped: the daemon renders or
//! reports it.

use std::cmp::Ordering;
use std::collections::BTreeMap;
use std::fmt;
use std::ops::Range;
use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::atomic;
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
    pub(crate) fn frames_mut(&mut self) -> Vec<&mut Capture> {
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
    let h = keys.iter().fold(atomic::FNV_OFFSET, |h, k| {
        atomic::fnv1a(atomic::fnv1a(h, k.as_bytes()), &[0xff])
    });
    format!("{h:016x}")
}

/// The order in which the frames of one batch (a scan of a folder, a burst) enter the
/// grouper: capture time, then path. The daemon's intake and `filmback plan` both use it,
/// so a folder gives the same brackets to either.
pub(crate) fn capture_order(a: &Capture, b: &Capture) -> Ordering {
    a.time_s
        .total_cmp(&b.time_s)
        .then_with(|| a.input.path.cmp(&b.input.path))
}

/// The frames of one body not yet closed into a group.
#[derive(Debug)]
struct Open {
    /// Frames sorted by capture time, each with its arrival (the caller's clock, seconds).
    frames: Vec<(Capture, f64)>,
    /// The latest arrival (the caller's clock, seconds).
    last_arrival: f64,
    /// The last postponement ([`Grouper::postpone`]): no run closes by its gap clock
    /// within `max_gap_s` of it.
    postponed: f64,
}

/// What the grouper remembers of a body between its groups: whether its frames arrive
/// in capture order.
#[derive(Debug, Clone, Copy)]
struct Order {
    /// The latest capture time of its frames so far (seconds).
    latest_capture: f64,
    /// Arrival of its last frame captured before an earlier arrival (the caller's clock):
    /// within `max_gap_s` of it, a full run may still be a wrong one (its first frame not
    /// yet arrived), so it waits for its gap clock too.
    shuffled_at: f64,
}

impl Open {
    /// When the run `run` (of [`runs`]) last had news: for the last run, the latest
    /// arrival; for an earlier one, its own latest arrival or the first arrival of a frame
    /// captured after it, whichever is later (from then on, a frame captured within it
    /// had `max_gap_s` to arrive too). Never before the last postponement.
    fn clock(&self, run: &Range<usize>) -> f64 {
        let own = self.frames[run.clone()]
            .iter()
            .map(|(_, arrival)| *arrival)
            .fold(f64::NEG_INFINITY, f64::max);
        let news = if run.end == self.frames.len() {
            self.last_arrival
        } else {
            self.frames[run.end..]
                .iter()
                .map(|(_, arrival)| *arrival)
                .fold(f64::INFINITY, f64::min)
        };
        news.max(own).max(self.postponed)
    }
}

/// Splits one body's frames, sorted by capture time, into the runs that are its brackets:
/// a run ends where the next frame was captured more than `max_gap_s` after the run's
/// last, where its exposure repeats one of the run's (within `min_step_ev` stops), or
/// once the run holds `size` frames.
fn runs(frames: &[(Capture, f64)], rules: &BracketRules) -> Vec<Range<usize>> {
    let mut runs = Vec::new();
    let mut start = 0;
    for (k, (capture, _)) in frames.iter().enumerate().skip(1) {
        let run = &frames[start..k];
        let gap = run
            .last()
            .is_some_and(|(last, _)| capture.time_s - last.time_s > rules.max_gap_s);
        let repeat = capture.stops().is_some_and(|stops| {
            run.iter()
                .filter_map(|(c, _)| c.stops())
                .any(|s| (s - stops).abs() < rules.min_step_ev)
        });
        if gap || repeat || run.len() >= rules.size {
            runs.push(start..k);
            start = k;
        }
    }
    if start < frames.len() {
        runs.push(start..frames.len());
    }
    runs
}

/// Groups captures as they arrive (see the module docs), whatever their arrival order
/// within the gap: a body's frames are kept sorted by capture time and split into runs
/// (a run ends at a capture gap over `max_gap_s`, a repeated exposure, or `size`
/// frames); a run closes when its gap clock — the later of its own last arrival and the
/// first arrival of a frame captured after it — is more than `max_gap_s` old, so that no
/// frame captured within it can still arrive, or at once when it holds `size` frames and
/// its body's frames have arrived in capture order for the last `max_gap_s`. A frame of
/// the next bracket that arrives before the last frame of the current one therefore does
/// not split it. [`Grouper::close`] hands out no more ready groups than its caller has
/// room for (the daemon's queue); the others stay open until there is room.
#[derive(Debug)]
pub struct Grouper {
    rules: BracketRules,
    open: BTreeMap<CameraId, Open>,
    order: BTreeMap<CameraId, Order>,
    /// Frames without an exposure, each a single, in arrival order.
    alone: Vec<Capture>,
}

impl Grouper {
    /// An empty grouper.
    pub fn new(rules: BracketRules) -> Grouper {
        Grouper {
            rules,
            open: BTreeMap::new(),
            order: BTreeMap::new(),
            alone: Vec::new(),
        }
    }

    /// Replaces the rules (config reload); open groups keep their frames.
    pub(crate) fn set_rules(&mut self, rules: BracketRules) {
        self.rules = rules;
    }

    /// Frames waiting in open groups or to be closed.
    pub fn waiting(&self) -> usize {
        self.open.values().map(|o| o.frames.len()).sum::<usize>() + self.alone.len()
    }

    /// Adds a capture that arrived at `now` (seconds, any monotone clock); a frame
    /// without an exposure is a single of its own. [`Grouper::close`] hands out the
    /// groups this completes.
    pub fn push(&mut self, capture: Capture, now: f64) {
        if capture.stops().is_none() {
            self.alone.push(capture);
            return;
        }
        let camera = capture.camera.clone();
        let order = self.order.entry(camera.clone()).or_insert(Order {
            latest_capture: capture.time_s,
            shuffled_at: f64::NEG_INFINITY,
        });
        if capture.time_s < order.latest_capture {
            order.shuffled_at = now;
        }
        order.latest_capture = order.latest_capture.max(capture.time_s);
        let open = self.open.entry(camera.clone()).or_insert(Open {
            frames: Vec::new(),
            last_arrival: now,
            postponed: f64::NEG_INFINITY,
        });
        let at = open
            .frames
            .partition_point(|(c, _)| c.time_s <= capture.time_s);
        open.frames.insert(at, (capture, now));
        open.last_arrival = open.last_arrival.max(now);
    }

    /// Closes at most `room` groups that are ready at `now` (the room left in the
    /// daemon's queue): first the frames without an exposure, then the ready runs whose
    /// gap clocks are oldest, each body's in capture order. The others stay open until
    /// a later call has room.
    pub fn close(&mut self, now: f64, room: usize) -> Vec<Closed> {
        let singles = room.min(self.alone.len());
        let mut closed: Vec<Closed> = self
            .alone
            .drain(..singles)
            .map(|c| Closed::Single(c, Alone::NoExposure))
            .collect();
        let mut ready: Vec<(f64, &CameraId)> = self
            .open
            .iter()
            .flat_map(|(camera, open)| {
                self.ready(camera, open, now)
                    .into_iter()
                    .map(move |run| (open.clock(&run), camera))
            })
            .collect();
        ready.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut share: BTreeMap<CameraId, usize> = BTreeMap::new();
        for (_, camera) in ready.into_iter().take(room - singles) {
            *share.entry(camera.clone()).or_default() += 1;
        }
        for (camera, n) in share {
            closed.extend(self.close_ready(&camera, now, n));
        }
        closed
    }

    /// The runs of `camera`'s `open` frames that close at `now`: quiet for more than the
    /// gap, or full while its frames arrive in capture order.
    fn ready(&self, camera: &CameraId, open: &Open, now: f64) -> Vec<Range<usize>> {
        let gap = self.rules.max_gap_s;
        let in_order = self
            .order
            .get(camera)
            .is_none_or(|o| now - o.shuffled_at > gap);
        runs(&open.frames, &self.rules)
            .into_iter()
            .filter(|run| (in_order && run.len() >= self.rules.size) || now - open.clock(run) > gap)
            .collect()
    }

    /// Closes the first `n` ready runs of `camera`'s open frames, in capture order.
    fn close_ready(&mut self, camera: &CameraId, now: f64, n: usize) -> Vec<Closed> {
        let mut ready = match self.open.get(camera) {
            Some(open) => self.ready(camera, open, now),
            None => return Vec::new(),
        };
        ready.truncate(n);
        let Some(open) = self.open.get_mut(camera).filter(|_| !ready.is_empty()) else {
            return Vec::new();
        };
        let mut closed = Vec::with_capacity(ready.len());
        let mut kept = Vec::with_capacity(open.frames.len());
        let mut runs = ready.into_iter().peekable();
        let mut group = Vec::new();
        for (k, (capture, arrival)) in std::mem::take(&mut open.frames).into_iter().enumerate() {
            while runs.peek().is_some_and(|run| run.end <= k) {
                runs.next();
            }
            match runs.peek() {
                Some(run) if run.contains(&k) => {
                    group.push(capture);
                    if k + 1 == run.end {
                        closed.push(close(camera.clone(), std::mem::take(&mut group)));
                    }
                }
                _ => kept.push((capture, arrival)),
            }
        }
        open.frames = kept;
        if open.frames.is_empty() {
            self.open.remove(camera);
        }
        closed
    }

    /// True when [`Grouper::close`] at `now` would close a group, given room.
    pub(crate) fn due(&self, now: f64) -> bool {
        !self.alone.is_empty()
            || self
                .open
                .iter()
                .any(|(camera, o)| !self.ready(camera, o, now).is_empty())
    }

    /// Takes the frame at `path` out of its open group (its raw arrived: the JPEG of a
    /// RAW+JPEG capture is not a frame of its own); `None` when no open group holds it.
    pub(crate) fn withdraw(&mut self, path: &std::path::Path) -> Option<Capture> {
        let (camera, at) = self.open.iter().find_map(|(camera, open)| {
            open.frames
                .iter()
                .position(|(c, _)| c.input.path == path)
                .map(|at| (camera.clone(), at))
        })?;
        let open = self.open.get_mut(&camera)?;
        let (capture, _) = open.frames.remove(at);
        if open.frames.is_empty() {
            self.open.remove(&camera);
        }
        Some(capture)
    }

    /// Groups a batch of frames all on disk at once (a folder scanned whole): pushed in
    /// [`capture_order`] at one instant, as the daemon takes a settled batch, then every
    /// run closed, as the gap clock closes them once nothing more arrives. Returns the
    /// groups in the order they closed.
    pub fn group_all(rules: BracketRules, mut captures: Vec<Capture>) -> Vec<Closed> {
        captures.sort_by(capture_order);
        let mut grouper = Grouper::new(rules);
        let mut closed = Vec::with_capacity(captures.len());
        for capture in captures {
            grouper.push(capture, 0.0);
            closed.extend(grouper.close(0.0, usize::MAX));
        }
        closed.extend(grouper.close(f64::INFINITY, usize::MAX));
        closed
    }

    /// Restarts the gap clock of every open group: called while the daemon is not taking
    /// new files (queue full, a file still being written), so a bracket is not closed
    /// early for lack of frames that are in fact waiting on disk.
    pub(crate) fn postpone(&mut self, now: f64) {
        for open in self.open.values_mut() {
            open.postponed = now;
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

    /// Pushes `s` arriving at `t` and closes what is ready, with room for all.
    fn arrive(g: &mut Grouper, s: Capture, t: f64) -> Vec<Closed> {
        g.push(s, t);
        g.close(t, usize::MAX)
    }

    fn run(g: &mut Grouper, shots: Vec<Capture>) -> Vec<Closed> {
        let mut out = Vec::new();
        for (i, s) in shots.into_iter().enumerate() {
            out.extend(arrive(g, s, i as f64 * 0.1));
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
        // The full bracket closes at once; the pair once no frame captured between `b`
        // and `a2` can still arrive (the gap after the body's last arrival, `c2` at 0.4).
        assert_eq!(out.len(), 1);
        assert_eq!(names(&out[0]), ["a2", "b2", "c2"]);
        assert!(g.close(2.3, usize::MAX).is_empty());
        let late = g.close(2.5, usize::MAX);
        assert_eq!(late.len(), 1);
        assert_eq!(names(&late[0]), ["a", "b"]);
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
        // Nothing closes while a frame captured between them could still arrive.
        assert!(out.is_empty());
        assert!(!g.due(1.0));
        assert!(g.close(1.0, usize::MAX).is_empty());
        // `a` alone once `max_gap_s` passed since `b` arrived; the pair since `c` did.
        assert_eq!(
            g.close(2.15, usize::MAX),
            [Closed::Single(shot("a", &c, 0.0, 0.0), Alone::NoPartner)]
        );
        assert!(g.due(10.0));
        let late = g.close(10.0, usize::MAX);
        assert_eq!(late.len(), 1);
        assert_eq!(names(&late[0]), ["b", "c"]);
        assert_eq!(g.waiting(), 0);
        // Postponed groups wait a full gap from the postponement.
        arrive(&mut g, shot("d", &c, 0.0, 20.0), 10.0);
        g.postpone(11.5);
        assert!(g.close(13.0, usize::MAX).is_empty());
        assert_eq!(g.close(13.6, usize::MAX).len(), 1);
    }

    #[test]
    fn a_withdrawn_frame_leaves_its_group_and_an_empty_group_goes() {
        let c = cam("EOS R5");
        let mut g = Grouper::new(rules(3));
        arrive(&mut g, shot("a", &c, 0.0, 0.0), 0.0);
        arrive(&mut g, shot("b", &c, 1.0, 0.2), 0.1);
        let a = g.withdraw(Path::new("/in/a.jpg")).expect("a is open");
        assert_eq!(a, shot("a", &c, 0.0, 0.0));
        assert!(g.withdraw(Path::new("/in/a.jpg")).is_none());
        assert_eq!(g.waiting(), 1);
        assert!(g.withdraw(Path::new("/in/b.jpg")).is_some());
        assert_eq!(g.waiting(), 0);
        assert!(
            g.close(100.0, usize::MAX).is_empty(),
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
        // Out of order: the full bracket waits for the gap clock, then closes whole.
        assert!(out.is_empty());
        let out = g.close(2.3, usize::MAX);
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
        out.extend(g.close(100.0, usize::MAX));
        assert_eq!(out.len(), 5);
        assert!(
            out.iter()
                .all(|o| matches!(o, Closed::Single(_, Alone::NoPartner)))
        );
    }

    /// The first frame of the next bracket (+20 s) arrives half a second before the last
    /// frame of the current one: the current bracket stays whole, the next one waits.
    #[test]
    fn the_next_brackets_first_frame_arriving_early_does_not_split_the_current_one() {
        let c = cam("EOS R5");
        let mut g = Grouper::new(rules(3));
        assert!(arrive(&mut g, shot("a", &c, 0.0, 0.0), 0.0).is_empty());
        assert!(arrive(&mut g, shot("b", &c, -2.0, 0.3), 0.1).is_empty());
        assert!(arrive(&mut g, shot("d", &c, 0.0, 20.0), 0.2).is_empty());
        // Out of capture order: even a full run waits for its gap clock (`c`'s arrival).
        assert!(arrive(&mut g, shot("c", &c, 2.0, 0.6), 0.7).is_empty());
        assert!(arrive(&mut g, shot("e", &c, -2.0, 20.3), 0.8).is_empty());
        assert!(arrive(&mut g, shot("f", &c, 2.0, 20.6), 0.9).is_empty());
        assert!(g.close(2.6, usize::MAX).is_empty());
        let out: Vec<_> = g.close(2.8, usize::MAX).iter().map(names).collect();
        assert_eq!(out, [["a", "b", "c"], ["d", "e", "f"]]);
        assert_eq!(g.waiting(), 0);
        // Back in order for a gap: a full bracket closes at once again.
        arrive(&mut g, shot("g", &c, 0.0, 40.0), 3.1);
        arrive(&mut g, shot("h", &c, -2.0, 40.3), 3.2);
        let out = arrive(&mut g, shot("i", &c, 2.0, 40.6), 3.3);
        assert_eq!(names(&out[0]), ["g", "h", "i"]);
    }

    /// Five brackets whose frames arrived in reverse capture order all become ready at
    /// once when their gap clocks run out: each call hands out no more groups than it has
    /// room for, the frame without an exposure first, then the oldest clocks; none is
    /// lost or split.
    #[test]
    fn close_hands_out_no_more_groups_than_there_is_room_for() {
        let c = cam("EOS R5");
        let mut g = Grouper::new(rules(3));
        for k in 0..5 {
            for (i, ev) in [(2, 2.0), (1, -2.0), (0, 0.0)] {
                let t = 10.0 * f64::from(k) + 0.3 * f64::from(i);
                let arrival = 0.3 * f64::from(k) + 0.1 * f64::from(2 - i);
                g.push(shot(&format!("{k}-{i}"), &c, ev, t), arrival);
            }
        }
        let mut blind = shot("n", &c, 0.0, 100.0);
        blind.exposure = None;
        g.push(blind.clone(), 1.5);
        assert!(g.close(1.5, 0).is_empty());
        assert!(g.due(10.0));
        let first = g.close(10.0, 2);
        assert_eq!(first[0], Closed::Single(blind, Alone::NoExposure));
        assert_eq!(names(&first[1]), ["0-0", "0-1", "0-2"]);
        assert_eq!(first.len(), 2);
        let then: Vec<_> = g.close(10.0, 2).iter().map(names).collect();
        assert_eq!(then, [["1-0", "1-1", "1-2"], ["2-0", "2-1", "2-2"]]);
        assert!(g.close(10.0, 0).is_empty());
        let last: Vec<_> = g.close(10.0, 5).iter().map(names).collect();
        assert_eq!(last, [["3-0", "3-1", "3-2"], ["4-0", "4-1", "4-2"]]);
        assert_eq!(g.waiting(), 0);
    }

    /// Ten brackets of two bodies, their 30 frames arriving in a shuffled order within
    /// a second (a copy tool or a card reader): the same ten brackets as in capture order.
    #[test]
    fn shuffled_arrival_within_the_gap_gives_the_brackets_of_capture_order() {
        let bodies = [cam("EOS R5"), cam("EOS R6")];
        let mut shots = Vec::new();
        for (b, body) in bodies.iter().enumerate() {
            for k in 0..5 {
                for (i, ev) in [0.0, -2.0, 2.0].into_iter().enumerate() {
                    let t = 10.0 * f64::from(k) + 0.3 * i as f64;
                    shots.push(shot(&format!("{b}-{k}-{i}"), body, ev, t));
                }
            }
        }
        for seed in 1..=20u64 {
            // Fisher–Yates with a 64-bit LCG: a reproducible shuffle per seed.
            let mut order = shots.clone();
            let mut state = seed;
            for i in (1..order.len()).rev() {
                state = state
                    .wrapping_mul(6_364_136_223_846_793_005)
                    .wrapping_add(1_442_695_040_888_963_407);
                order.swap(i, (state >> 33) as usize % (i + 1));
            }
            let mut g = Grouper::new(rules(3));
            let mut out: Vec<Vec<String>> = Vec::new();
            for (i, s) in order.into_iter().enumerate() {
                out.extend(arrive(&mut g, s, i as f64 * 0.03).iter().map(names));
            }
            out.extend(g.close(100.0, usize::MAX).iter().map(names));
            out.sort();
            let mut expected: Vec<Vec<String>> = (0..2)
                .flat_map(|b| (0..5).map(move |k| (0..3).map(|i| format!("{b}-{k}-{i}")).collect()))
                .collect();
            expected.sort();
            assert_eq!(out, expected, "seed {seed}");
        }
    }

    /// A folder scanned whole, in any listing order, gives the groups the frames give
    /// arriving one by one in capture order and closed by the gap.
    #[test]
    fn grouping_a_batch_gives_the_groups_of_arrival_in_capture_order() {
        let (x, y) = (cam("EOS R5"), cam("EOS R6"));
        let shots = vec![
            shot("x1", &x, 0.0, 0.0),
            shot("x2", &x, 1.0, 0.3),
            shot("x3", &x, 2.0, 0.6),
            shot("y1", &y, 0.0, 0.1),
            shot("y2", &y, 1.0, 0.4),
            shot("x4", &x, 0.0, 9.0),
            shot("y3", &y, 0.0, 20.0),
        ];
        let mut arrived = Grouper::new(rules(3));
        let mut expected: Vec<Vec<String>> = Vec::new();
        let mut sorted = shots.clone();
        sorted.sort_by(capture_order);
        for (i, s) in sorted.into_iter().enumerate() {
            expected.extend(arrive(&mut arrived, s, i as f64 * 0.01).iter().map(names));
        }
        expected.extend(arrived.close(1e9, usize::MAX).iter().map(names));
        expected.sort();
        let mut reversed = shots;
        reversed.reverse();
        let mut got: Vec<Vec<String>> = Grouper::group_all(rules(3), reversed)
            .iter()
            .map(names)
            .collect();
        got.sort();
        assert_eq!(got, expected);
        assert_eq!(
            got,
            [
                vec!["x1", "x2", "x3"],
                vec!["x4"],
                vec!["y1", "y2"],
                vec!["y3"]
            ]
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
