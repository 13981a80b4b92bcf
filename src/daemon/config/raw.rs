//! The configuration file as written: serde types that mirror the TOML (every key
//! optional, every value checked as it is read), and the overlay of a user's file on
//! the embedded defaults that yields the checked [`Config`].

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Duration;

use serde::Deserialize;

use crate::align::AlignMode;
use crate::display::ColourSpace;
use crate::merge::Deghost;

use super::{
    BracketRules, CameraPreset, Config, ConfigError, Daemon, Folders, Hooks, Preset, Recalibrate,
    Singles, Viewer, Watch, WatchMode,
};

/// Why a value of the file is refused where it is read (reported at its line).
#[derive(Debug, thiserror::Error)]
pub enum ValueError {
    /// Not a number where one is expected.
    #[error("expected a number, found {0}")]
    NotANumber(&'static str),
    /// A number outside its range.
    #[error("{value} is outside {lo}..={hi} ({unit})")]
    Outside {
        /// As read.
        value: f64,
        /// Least allowed.
        lo: f64,
        /// Greatest allowed.
        hi: f64,
        /// What it counts.
        unit: &'static str,
    },
    /// A fraction where a whole number is expected.
    #[error("{value} must be a whole number ({unit})")]
    NotWhole {
        /// As read.
        value: f64,
        /// What it counts.
        unit: &'static str,
    },
    /// A look request that does not parse.
    #[error(transparent)]
    Look(#[from] crate::film::FilmError),
    /// A look name that cannot be part of a file name.
    #[error(
        "{0:?} is not a valid name (lower-case letters, digits, '-', '_', then optionally @t and +options)"
    )]
    LookName(String),
    /// An empty hook command.
    #[error("an empty command; leave the key out to run none")]
    EmptyCommand,
}

/// A number checked while it is read, so a bad value is reported at its line.
macro_rules! bounded {
    ($name:ident, $t:ty, $lo:expr, $hi:expr, $what:expr) => {
        #[doc = concat!("A value in `", stringify!($lo), "..=", stringify!($hi), "` (", $what, ").")]
        #[derive(Debug, Clone, Copy, PartialEq, PartialOrd, Deserialize)]
        #[serde(try_from = "toml::Value")]
        pub struct $name(pub $t);

        impl TryFrom<toml::Value> for $name {
            type Error = ValueError;
            fn try_from(v: toml::Value) -> Result<Self, ValueError> {
                #[allow(clippy::cast_precision_loss, clippy::cast_possible_truncation)]
                let x: f64 = match v {
                    toml::Value::Integer(i) => i as f64,
                    toml::Value::Float(f) => f,
                    other => return Err(ValueError::NotANumber(other.type_str())),
                };
                let (lo, hi) = ($lo as f64, $hi as f64);
                if !(x >= lo && x <= hi) {
                    return Err(ValueError::Outside {
                        value: x,
                        lo,
                        hi,
                        unit: $what,
                    });
                }
                let v = x as $t;
                if v as f64 != x {
                    return Err(ValueError::NotWhole {
                        value: x,
                        unit: $what,
                    });
                }
                Ok($name(v))
            }
        }
    };
}

bounded!(Millis, u64, 1, 3_600_000, "milliseconds");
bounded!(Seconds, u64, 0, 86_400, "seconds");
bounded!(Gap, f64, 0.0, 3600.0, "seconds");
bounded!(Step, f64, 0.05, 10.0, "stops");
bounded!(BracketSize, usize, 2, 9, "frames");
bounded!(Jobs, usize, 1, 64, "brackets");
bounded!(QueueLen, usize, 1, 100_000, "brackets");
bounded!(RetrySeconds, u64, 1, 3600, "seconds");
bounded!(MemoryMb, u64, 64, 16_777_216, "MB");
bounded!(Port, u16, 0, 65_535, "TCP port");
bounded!(Stops, f64, -10.0, 10.0, "stops");
bounded!(Quality, u8, 1, 100, "JPEG quality");
bounded!(Fraction, f64, 0.0, 1.0, "confidence");
bounded!(
    Calibration,
    f64,
    0.001,
    1000.0,
    "luminance calibration factor"
);

/// A film stock or tone map name: lower-case letters, digits, `-` and `_`, so it can be
/// part of an output file name.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Deserialize)]
#[serde(try_from = "String")]
pub(crate) struct LookName(pub String);

impl TryFrom<String> for LookName {
    type Error = ValueError;
    /// A name, optionally followed by `@t` (a film's relative exposure: `0.5`, `1/2`,
    /// `-1ev`) and a film's `+options` (`+grain`, `+print=-1/3`). Whether the stock or
    /// tone map exists is checked once the whole file is read (user stocks come from
    /// `folders.stocks`).
    fn try_from(s: String) -> Result<Self, ValueError> {
        let request: crate::film::Request = s.parse()?;
        let name = request.stock.as_str();
        if name.is_empty()
            || !name
                .chars()
                .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '-' || c == '_')
        {
            return Err(ValueError::LookName(s));
        }
        Ok(LookName(s))
    }
}

/// The file as written (every key optional: absent keys keep the default).
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawConfig {
    folders: Option<RawFolders>,
    watch: Option<RawWatch>,
    bracket: Option<RawBracket>,
    daemon: Option<RawDaemon>,
    render: Option<RawRender>,
    merge: Option<RawMerge>,
    viewer: Option<RawViewer>,
    hooks: Option<RawHooks>,
    #[serde(default)]
    camera: BTreeMap<String, RawPreset>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawHooks {
    on_developed: Option<HookCommand>,
}

/// A shell command line, not empty.
#[derive(Debug, Clone, Deserialize)]
#[serde(try_from = "String")]
struct HookCommand(String);

impl TryFrom<String> for HookCommand {
    type Error = ValueError;
    fn try_from(s: String) -> Result<Self, ValueError> {
        if s.trim().is_empty() {
            return Err(ValueError::EmptyCommand);
        }
        Ok(HookCommand(s))
    }
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawViewer {
    enabled: Option<bool>,
    bind: Option<std::net::IpAddr>,
    port: Option<Port>,
    token: Option<String>,
    token_file: Option<PathBuf>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawMerge {
    align: Option<AlignMode>,
    deghost: Option<Deghost>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawFolders {
    ingest: Option<PathBuf>,
    out: Option<PathBuf>,
    state: Option<PathBuf>,
    archive: Option<PathBuf>,
    stocks: Option<PathBuf>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawWatch {
    mode: Option<WatchMode>,
    poll_ms: Option<Millis>,
    rescan_s: Option<Seconds>,
    recursive: Option<bool>,
    settle_ms: Option<Millis>,
    ignore: Option<Vec<String>>,
    extensions: Option<Vec<String>>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawBracket {
    max_gap_s: Option<Gap>,
    min_step_ev: Option<Step>,
    size: Option<BracketSize>,
    singles: Option<Singles>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawDaemon {
    jobs: Option<Jobs>,
    queue: Option<QueueLen>,
    retry_s: Option<RetrySeconds>,
    memory_mb: Option<MemoryMb>,
}

#[derive(Debug, Default, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawRender {
    exr: Option<bool>,
    dng: Option<bool>,
    ghost_map: Option<bool>,
    films: Option<Vec<LookName>>,
    tonemaps: Option<Vec<LookName>>,
    t: Option<Stops>,
    jpeg_quality: Option<Quality>,
    hdr_still: Option<bool>,
    recalibrate: Option<Recalibrate>,
    min_confidence: Option<Fraction>,
    luminance_calibration: Option<Calibration>,
    primaries: Option<crate::hdr_output::Primaries>,
    colour_space: Option<ColourSpace>,
}

#[derive(Debug, Default, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawPreset {
    model: Option<String>,
    serial: Option<String>,
    // The [render] keys, spelled out: serde's `flatten` would lose the unknown key's span.
    exr: Option<bool>,
    dng: Option<bool>,
    ghost_map: Option<bool>,
    films: Option<Vec<LookName>>,
    tonemaps: Option<Vec<LookName>>,
    t: Option<Stops>,
    jpeg_quality: Option<Quality>,
    hdr_still: Option<bool>,
    recalibrate: Option<Recalibrate>,
    min_confidence: Option<Fraction>,
    luminance_calibration: Option<Calibration>,
    primaries: Option<crate::hdr_output::Primaries>,
    colour_space: Option<ColourSpace>,
    // The [merge] keys a camera may override.
    align: Option<AlignMode>,
    deghost: Option<Deghost>,
}

impl RawPreset {
    fn render(&self) -> RawRender {
        RawRender {
            exr: self.exr,
            dng: self.dng,
            ghost_map: self.ghost_map,
            films: self.films.clone(),
            tonemaps: self.tonemaps.clone(),
            t: self.t,
            jpeg_quality: self.jpeg_quality,
            hdr_still: self.hdr_still,
            recalibrate: self.recalibrate,
            min_confidence: self.min_confidence,
            luminance_calibration: self.luminance_calibration,
            primaries: self.primaries,
            colour_space: self.colour_space,
        }
    }
}

/// Deserialises with every error turned into file, line, column and key.
pub(super) fn parse(text: &str, path: &Path) -> Result<RawConfig, ConfigError> {
    toml::from_str(text).map_err(|e| {
        let offset = e.span().map_or(0, |s| s.start);
        let (line, column) = line_column(text, offset);
        let line_text = text.lines().nth(line - 1).unwrap_or("");
        let key = line_text.split('=').next().unwrap_or("").trim().to_string();
        ConfigError::Invalid {
            path: path.to_path_buf(),
            line,
            column,
            key: if key.is_empty() {
                "(file)".to_string()
            } else {
                key
            },
            message: e.message().trim().to_string(),
        }
    })
}

/// 1-based line and column (in characters) of a byte offset.
fn line_column(text: &str, offset: usize) -> (usize, usize) {
    let before = &text[..offset.min(text.len())];
    let line = before.matches('\n').count() + 1;
    let column = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
    (line, column)
}

/// The 1-based line of the first occurrence of `needle` in `text` outside a `#` comment
/// (1 if absent: the value came from the defaults).
pub(super) fn line_of(text: &str, needle: &str) -> usize {
    text.lines()
        .position(|l| {
            l.split('#')
                .next()
                .is_some_and(|code| code.contains(needle))
        })
        .map_or(1, |i| i + 1)
}

/// The 1-based line that assigns `key` (`key = …`), 1 if none does.
pub(super) fn line_of_key(text: &str, key: &str) -> usize {
    text.lines()
        .position(|l| {
            l.trim_start()
                .strip_prefix(key)
                .is_some_and(|rest| rest.trim_start().starts_with('='))
        })
        .map_or(1, |i| i + 1)
}

/// What a missing default says: the defaults file sets every key.
const MISSING: &str = "key set in config/filmback.toml";

/// User values over defaults. The defaults file sets every key, so each `expect` holds
/// by construction (and the embedded-defaults test checks it).
pub(super) fn merge(d: RawConfig, u: RawConfig, source: Option<PathBuf>) -> Config {
    let render = overlay(&d.render.unwrap_or_default(), &u.render.unwrap_or_default());
    let (dm, um) = (d.merge.unwrap_or_default(), u.merge.unwrap_or_default());
    let align = um.align.or(dm.align).expect(MISSING);
    let deghost = um.deghost.or(dm.deghost).expect(MISSING);
    let viewer = viewer(d.viewer.unwrap_or_default(), u.viewer.unwrap_or_default());
    let cameras = u
        .camera
        .into_iter()
        .map(|(name, p)| CameraPreset {
            model: p.model.clone().unwrap_or_else(|| name.clone()),
            serial: p.serial.clone(),
            preset: Preset {
                name: Some(name),
                align: p.align.unwrap_or(align),
                deghost: p.deghost.unwrap_or(deghost),
                ..preset(&overlay(&render, &p.render()))
            },
        })
        .collect();
    Config {
        source,
        folders: folders(d.folders.unwrap_or_default(), u.folders.unwrap_or_default()),
        watch: watch(d.watch.unwrap_or_default(), u.watch.unwrap_or_default()),
        bracket: bracket_rules(d.bracket.unwrap_or_default(), u.bracket.unwrap_or_default()),
        daemon: daemon(d.daemon.unwrap_or_default(), u.daemon.unwrap_or_default()),
        render: Preset {
            align,
            deghost,
            ..preset(&render)
        },
        cameras,
        viewer,
        hooks: Hooks {
            on_developed: u
                .hooks
                .and_then(|h| h.on_developed)
                .or_else(|| d.hooks.and_then(|h| h.on_developed))
                .map(|c| c.0),
        },
    }
}

/// `[folders]`: the user's `uf` over the defaults `df`.
fn folders(df: RawFolders, uf: RawFolders) -> Folders {
    Folders {
        ingest: uf.ingest.or(df.ingest).expect(MISSING),
        out: uf.out.or(df.out).expect(MISSING),
        state: uf.state.or(df.state).expect(MISSING),
        archive: uf.archive.or(df.archive),
        stocks: uf.stocks.or(df.stocks),
    }
}

/// `[watch]`: the user's `uw` over the defaults `dw`; a rescan period of 0 is none, and
/// the extensions are kept without their dot, in lower case.
fn watch(dw: RawWatch, uw: RawWatch) -> Watch {
    let rescan = uw.rescan_s.or(dw.rescan_s).expect(MISSING).0;
    Watch {
        mode: uw.mode.or(dw.mode).expect(MISSING),
        poll: Duration::from_millis(uw.poll_ms.or(dw.poll_ms).expect(MISSING).0),
        rescan: (rescan > 0).then(|| Duration::from_secs(rescan)),
        recursive: uw.recursive.or(dw.recursive).expect(MISSING),
        settle: Duration::from_millis(uw.settle_ms.or(dw.settle_ms).expect(MISSING).0),
        ignore: uw.ignore.or(dw.ignore).expect(MISSING),
        extensions: uw
            .extensions
            .or(dw.extensions)
            .expect(MISSING)
            .into_iter()
            .map(|e| e.trim_start_matches('.').to_ascii_lowercase())
            .collect(),
    }
}

/// `[bracket]`: the user's `ub` over the defaults `db`.
fn bracket_rules(db: RawBracket, ub: RawBracket) -> BracketRules {
    BracketRules {
        max_gap_s: ub.max_gap_s.or(db.max_gap_s).expect(MISSING).0,
        min_step_ev: ub.min_step_ev.or(db.min_step_ev).expect(MISSING).0,
        size: ub.size.or(db.size).expect(MISSING).0,
        singles: ub.singles.or(db.singles).expect(MISSING),
    }
}

/// `[daemon]`: the user's `ud` over the defaults `dd`.
fn daemon(dd: RawDaemon, ud: RawDaemon) -> Daemon {
    Daemon {
        jobs: ud.jobs.or(dd.jobs).expect(MISSING).0,
        queue: ud.queue.or(dd.queue).expect(MISSING).0,
        retry: Duration::from_secs(ud.retry_s.or(dd.retry_s).expect(MISSING).0),
        memory_mb: ud.memory_mb.or(dd.memory_mb).expect(MISSING).0,
    }
}

/// `[viewer]`: the user's `uv` over the defaults `dv`; the token is the user's alone.
fn viewer(dv: RawViewer, uv: RawViewer) -> Viewer {
    Viewer {
        enabled: uv.enabled.or(dv.enabled).expect(MISSING),
        address: std::net::SocketAddr::new(
            uv.bind.or(dv.bind).expect(MISSING),
            uv.port.or(dv.port).expect(MISSING).0,
        ),
        token: uv.token.map(super::Token),
        token_file: uv.token_file,
    }
}

fn overlay(base: &RawRender, over: &RawRender) -> RawRender {
    RawRender {
        exr: over.exr.or(base.exr),
        dng: over.dng.or(base.dng),
        ghost_map: over.ghost_map.or(base.ghost_map),
        films: over.films.clone().or_else(|| base.films.clone()),
        tonemaps: over.tonemaps.clone().or_else(|| base.tonemaps.clone()),
        t: over.t.or(base.t),
        jpeg_quality: over.jpeg_quality.or(base.jpeg_quality),
        hdr_still: over.hdr_still.or(base.hdr_still),
        recalibrate: over.recalibrate.or(base.recalibrate),
        min_confidence: over.min_confidence.or(base.min_confidence),
        luminance_calibration: over.luminance_calibration.or(base.luminance_calibration),
        primaries: over.primaries.or(base.primaries),
        colour_space: over.colour_space.or(base.colour_space),
    }
}

fn preset(r: &RawRender) -> Preset {
    let names = |v: &Option<Vec<LookName>>| {
        v.clone()
            .expect(MISSING)
            .into_iter()
            .map(|n| n.0)
            .collect::<Vec<_>>()
    };
    Preset {
        name: None,
        exr: r.exr.expect(MISSING),
        dng: r.dng.expect(MISSING),
        ghost_map: r.ghost_map.expect(MISSING),
        films: names(&r.films),
        tonemaps: names(&r.tonemaps),
        t: r.t.expect(MISSING).0,
        jpeg_quality: r.jpeg_quality.expect(MISSING).0,
        hdr_still: r.hdr_still.expect(MISSING),
        recalibrate: r.recalibrate.expect(MISSING),
        min_confidence: r.min_confidence.expect(MISSING).0,
        luminance_calibration: r.luminance_calibration.expect(MISSING).0,
        primaries: r.primaries.expect(MISSING),
        colour_space: r.colour_space.expect(MISSING),
        align: AlignMode::default(),
        deghost: Deghost::default(),
    }
}
