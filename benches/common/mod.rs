//! What the benchmarks share: the DoRF curves and their split, the real brackets and the
//! scenes made from them, the synthetic shot's EXIF, quantiles. Each bench uses part of it.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

use filmback::darkroom::{self, GivenResponse, ResponsePolicy, Stages};
use filmback::frame::{self, Frame, Limits};
use filmback::merge::BracketFrame;
use filmback::metadata::{Camera, CaptureTime, Exposure};
use filmback::radiance::RadianceMap;
use filmback::response::{InverseResponse, RatioSource};
use filmback::synthetic::{self, ResponseCurve, Shot, SyntheticError};

// The real brackets' listing, shared with the integration tests (not every bench uses it).
#[path = "../../tests/common/brackets.rs"]
mod brackets;
#[allow(unused_imports)]
pub use brackets::real_brackets;

/// The DoRF curves of `../shared/testdata/response-curves/dorf-even.csv`, found beside
/// the repository or, for a git worktree in a folder, beside its parent.
pub fn dorf_curves() -> Result<Vec<(String, ResponseCurve)>, SyntheticError> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let path = ["..", "../.."]
        .iter()
        .map(|up| {
            root.join(up)
                .join("shared/testdata/response-curves/dorf-even.csv")
        })
        .find(|p| p.exists())
        .unwrap_or_else(|| root.join("../shared/testdata/response-curves/dorf-even.csv"));
    synthetic::dorf_curves(&path)
}

/// Keeps the DoRF records of `split`: `all`, `tune` (records numbered ≡ 0 mod 4, the
/// curves a change is tuned on) or `report` (the others, ≡ 2 mod 4, where its accuracy
/// is reported).
pub fn keep_split(curves: &mut Vec<(String, ResponseCurve)>, split: &str) {
    let record = |name: &str| -> u32 { name.trim_start_matches("dorf-").parse().unwrap_or(0) };
    match split {
        "all" => {}
        "tune" => curves.retain(|(n, _)| record(n) % 4 == 0),
        "report" => curves.retain(|(n, _)| record(n) % 4 != 0),
        other => panic!("--curves takes all, tune or report, not {other}"),
    }
}

/// The word after `flag` on the command line, if any.
pub fn arg(flag: &str) -> Option<String> {
    let args: Vec<String> = std::env::args().collect();
    args.iter()
        .position(|a| a == flag)
        .and_then(|i| args.get(i + 1))
        .cloned()
}

/// The value after `flag` on the command line parsed as a `T`, else `default`.
pub fn arg_or<T: std::str::FromStr>(flag: &str, default: T) -> T {
    arg(flag).and_then(|v| v.parse().ok()).unwrap_or(default)
}

/// The value of rank `round(q·(n − 1))` of `v` (sorted in place); NaN when empty.
pub fn quantile(v: &mut [f64], q: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
}

/// A synthetic frame's EXIF: exposure time `exposure` s at f/1, ISO 100, the default
/// camera, 2026-01-01 00:00:00.
pub fn shot(exposure: f64) -> Shot {
    Shot {
        camera: Camera::default(),
        exposure: Exposure {
            time_s: Some(exposure),
            f_number: Some(1.0),
            iso: Some(100.0),
        },
        captured_at: CaptureTime {
            year: 2026,
            month: 1,
            day: 1,
            hour: 0,
            minute: 0,
            second: 0,
            nanos: None,
            offset_minutes: None,
        },
    }
}

/// `../shared/testdata/brackets`, the real brackets beside the repository.
pub fn testdata_brackets() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/testdata/brackets")
}

/// A scene of a real place ([`synthetic::real_place`]) from a real bracket's files with
/// their relative exposures, of about `pixels` pixels.
pub fn real_scene(frames: &[(PathBuf, f64)], pixels: f64) -> Result<RadianceMap, String> {
    let loaded: Vec<(Frame, f64)> = frames
        .iter()
        .map(|(p, e)| {
            frame::load(p, Limits::default())
                .map(|l| (l.frame, *e))
                .map_err(|e| e.to_string())
        })
        .collect::<Result<_, _>>()?;
    let borrowed: Vec<(&Frame, f64)> = loaded.iter().map(|(f, e)| (f, *e)).collect();
    synthetic::real_place(&borrowed, pixels).map_err(|e| e.to_string())
}

/// The CPU time this process has used so far, all threads, user and system, in seconds
/// (`/proc/self/stat`, in the kernel's fixed 1/100 s ticks); `None` where it cannot be
/// read. On a busy machine wall time includes the waits for a core; CPU time divided by
/// the cores a step keeps busy is what the step costs on an idle machine.
pub fn cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // The fields after the command name (in parentheses, which may hold spaces).
    let fields: Vec<&str> = stat.rsplit_once(')')?.1.split_whitespace().collect();
    let ticks = |i: usize| fields.get(i)?.parse::<f64>().ok();
    // utime and stime are fields 14 and 15 of the line; the state, field 3, is index 0.
    Some((ticks(11)? + ticks(12)?) / 100.0)
}

/// The least wall time and the least CPU time (all threads) of `runs` runs of `f`, in
/// seconds (CPU time NaN where it cannot be read).
pub fn best_of(runs: usize, f: &dyn Fn()) -> (f64, f64) {
    let (mut wall, mut cpu) = (f64::INFINITY, f64::INFINITY);
    for _ in 0..runs.max(1) {
        let (t, c) = (std::time::Instant::now(), cpu_seconds());
        f();
        wall = wall.min(t.elapsed().as_secs_f64());
        cpu = cpu.min(match (c, cpu_seconds()) {
            (Some(a), Some(b)) => b - a,
            _ => f64::NAN,
        });
    }
    (wall, cpu)
}

/// `frames` with their relative exposures as one bracket of `camera`.
pub fn bracket<'a>(frames: &'a [(Frame, f64)], camera: &'a Camera) -> Vec<BracketFrame<'a>> {
    frames
        .iter()
        .map(|(frame, exposure)| BracketFrame {
            source: Path::new("bench"),
            frame,
            exposure: *exposure,
            camera,
        })
        .collect()
}

/// The response the darkroom fits to `frames` (the sRGB inverse when the fit is weak).
pub fn fitted(frames: &[(Frame, f64)]) -> InverseResponse {
    let camera = Camera::default();
    let policy = ResponsePolicy::Fit {
        fallback: Some(GivenResponse::standard(frames[0].0.channels())),
        min_confidence: 0.5,
        pool: None,
    };
    let mut stages = Stages::new();
    darkroom::choose_response(
        &bracket(frames, &camera),
        RatioSource::Argument,
        policy,
        &mut stages,
    )
    .expect("a response")
    .response
}

/// The Rec. 709 luminance of pixel `p` of `m` (its one channel for a grey map), at least
/// 1e-9.
pub fn luminance(m: &RadianceMap, p: usize) -> f64 {
    let c = m.channels();
    let px = &m.pixels()[p * c..p * c + c];
    let y = if c == 3 {
        0.2126 * f64::from(px[0]) + 0.7152 * f64::from(px[1]) + 0.0722 * f64::from(px[2])
    } else {
        f64::from(px[0])
    };
    y.max(1e-9)
}

/// One outer frame's move: a shift `(dx, dy)` in pixels, a rotation in degrees about the
/// centre, and the perspective terms `(px, py)` in coordinates normalised by half the
/// longer side.
#[derive(Clone, Copy)]
pub struct FrameMove(pub (f64, f64), pub f64, pub (f64, f64));

/// A move of the outer frames, first and last.
pub struct Move {
    pub name: &'static str,
    pub outer: [FrameMove; 2],
}

/// The moves `cargo bench --bench align` and `align_raw` apply: a nudged tripod and a
/// handheld bracket.
pub const MOVES: [Move; 2] = [
    Move {
        name: "nudge (≤ 3 px, 0.1°)",
        outer: [
            FrameMove((2.3, -1.7), 0.08, (0.0, 0.0)),
            FrameMove((-2.8, 1.2), -0.1, (0.0, 0.0)),
        ],
    },
    Move {
        name: "handheld (≤ 12 px, 0.5°, perspective)",
        outer: [
            FrameMove((9.5, -7.2), 0.4, (0.004, -0.003)),
            FrameMove((-11.3, 6.1), -0.5, (-0.003, 0.004)),
        ],
    },
];

/// The pixel matrix (reference pixel → moved frame's pixel) of one outer frame's move in
/// a `w × h` frame ([`synthetic::camera_move`]).
pub fn matrix(w: u32, h: u32, m: FrameMove) -> [[f64; 3]; 3] {
    let FrameMove(shift, degrees, perspective) = m;
    synthetic::camera_move(w, h, degrees, shift, perspective)
}

pub fn to_array(m: &nalgebra::Matrix3<f64>) -> [[f64; 3]; 3] {
    let mut out = [[0.0; 3]; 3];
    for (r, row) in out.iter_mut().enumerate() {
        for (c, v) in row.iter_mut().enumerate() {
            *v = m[(r, c)] / m[(2, 2)];
        }
    }
    out
}
