//! The daemon's configuration: one TOML file, parsed in two stages.
//!
//! [`RawConfig`] mirrors the file (serde, `deny_unknown_fields`, every value checked while
//! it is read so the error carries its line and column); [`Config`] is the checked form
//! the daemon runs on. The defaults are `config/filmback.toml`, embedded in the binary, so
//! the daemon runs without any file; a user's file is read over them key by key.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Duration;

use serde::Deserialize;

/// The commented example configuration, which is also the source of every default.
pub const DEFAULT_TOML: &str = include_str!("../../config/filmback.toml");

/// Why a configuration cannot be used. Each variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file could not be read.
    #[error("{path}: cannot read: {source}")]
    Read {
        /// The file.
        path: PathBuf,
        /// What the operating system said.
        source: std::io::Error,
    },
    /// A syntax error, an unknown key or a bad value.
    #[error("{path}:{line}:{column}: {key}: {message}")]
    Invalid {
        /// The file (`<built-in defaults>` for the embedded file).
        path: PathBuf,
        /// 1-based line.
        line: usize,
        /// 1-based column.
        column: usize,
        /// The key (or table header) on that line.
        key: String,
        /// What is wrong.
        message: String,
    },
    /// The folders are valid one by one but not together.
    #[error("{path}: [folders]: {reason}")]
    Folders {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
}

/// How the ingest folder is watched.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum WatchMode {
    /// Kernel events (inotify).
    Notify,
    /// Compare listings every `poll_ms` (network shares deliver no events).
    Poll,
}

/// What happens to a frame that ends up alone.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Singles {
    /// Render it through the camera's cached response.
    Render,
    /// Only report it (journal and log).
    Report,
}

/// Where a bracket's response curve comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Recalibrate {
    /// Fit each bracket; use the cached curve when the fit is weak.
    Auto,
    /// Only the bracket's own fit.
    Always,
    /// Only the cached curve.
    Never,
}

/// A number checked while it is read, so a bad value is reported at its line.
macro_rules! bounded {
    ($name:ident, $t:ty, $lo:expr, $hi:expr, $what:expr) => {
        #[doc = concat!("A value in `", stringify!($lo), "..=", stringify!($hi), "` (", $what, ").")]
        #[derive(Debug, Clone, Copy, PartialEq, PartialOrd, Deserialize)]
        #[serde(try_from = "toml::Value")]
        pub struct $name(pub $t);

        impl TryFrom<toml::Value> for $name {
            type Error = String;
            fn try_from(v: toml::Value) -> Result<Self, String> {
                #[allow(clippy::cast_precision_loss, clippy::cast_possible_truncation)]
                let x: f64 = match v {
                    toml::Value::Integer(i) => i as f64,
                    toml::Value::Float(f) => f,
                    other => return Err(format!("expected a number, found {}", other.type_str())),
                };
                let (lo, hi) = ($lo as f64, $hi as f64);
                if !(x >= lo && x <= hi) {
                    return Err(format!("{x} is outside {lo}..={hi} ({})", $what));
                }
                let v = x as $t;
                if v as f64 != x {
                    return Err(format!("{x} must be a whole number ({})", $what));
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
bounded!(Stops, f64, -10.0, 10.0, "stops");
bounded!(Quality, u8, 1, 100, "JPEG quality");
bounded!(Fraction, f64, 0.0, 1.0, "confidence");

/// A film stock or tone map name: lower-case letters, digits, `-` and `_`, so it can be
/// part of an output file name.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Deserialize)]
#[serde(try_from = "String")]
pub struct LookName(pub String);

impl TryFrom<String> for LookName {
    type Error = String;
    /// A name, optionally followed by `@t` (a film's relative exposure: `0.5`, `1/2`,
    /// `-1ev`) and a film's `+options` (`+grain`, `+print=-1/3`). Whether the stock or
    /// tone map exists is checked once the whole file is read (user stocks come from
    /// `folders.stocks`).
    fn try_from(s: String) -> Result<Self, String> {
        let request: crate::film::Request = s.parse().map_err(|e| format!("{e}"))?;
        let name = request.stock.as_str();
        if name.is_empty()
            || !name
                .chars()
                .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '-' || c == '_')
        {
            return Err(format!(
                "{s:?} is not a valid name (lower-case letters, digits, '-', '_', then optionally @t and +options)"
            ));
        }
        Ok(LookName(s))
    }
}

/// The file as written (every key optional: absent keys keep the default).
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawConfig {
    folders: Option<RawFolders>,
    watch: Option<RawWatch>,
    bracket: Option<RawBracket>,
    daemon: Option<RawDaemon>,
    render: Option<RawRender>,
    #[serde(default)]
    camera: BTreeMap<String, RawPreset>,
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
}

#[derive(Debug, Default, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawRender {
    exr: Option<bool>,
    films: Option<Vec<LookName>>,
    tonemaps: Option<Vec<LookName>>,
    t: Option<Stops>,
    jpeg_quality: Option<Quality>,
    recalibrate: Option<Recalibrate>,
    min_confidence: Option<Fraction>,
}

#[derive(Debug, Default, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawPreset {
    model: Option<String>,
    serial: Option<String>,
    // The [render] keys, spelled out: serde's `flatten` would lose the unknown key's span.
    exr: Option<bool>,
    films: Option<Vec<LookName>>,
    tonemaps: Option<Vec<LookName>>,
    t: Option<Stops>,
    jpeg_quality: Option<Quality>,
    recalibrate: Option<Recalibrate>,
    min_confidence: Option<Fraction>,
}

impl RawPreset {
    fn render(&self) -> RawRender {
        RawRender {
            exr: self.exr,
            films: self.films.clone(),
            tonemaps: self.tonemaps.clone(),
            t: self.t,
            jpeg_quality: self.jpeg_quality,
            recalibrate: self.recalibrate,
            min_confidence: self.min_confidence,
        }
    }
}

/// The folders the daemon reads and writes.
#[derive(Debug, Clone, PartialEq)]
pub struct Folders {
    /// Frames arrive here.
    pub ingest: PathBuf,
    /// Outputs are published here.
    pub out: PathBuf,
    /// Journal, response cache and status.
    pub state: PathBuf,
    /// Finished inputs are moved here, when set.
    pub archive: Option<PathBuf>,
    /// Extra film stock files (`*.toml`) beside the built-in ones, when set.
    pub stocks: Option<PathBuf>,
}

/// How files are noticed and when they count as complete.
#[derive(Debug, Clone, PartialEq)]
pub struct Watch {
    /// Events or polling.
    pub mode: WatchMode,
    /// Polling interval.
    pub poll: Duration,
    /// Periodic full rescan; `None` disables it.
    pub rescan: Option<Duration>,
    /// Watch sub-folders too.
    pub recursive: bool,
    /// Size and mtime must be stable this long.
    pub settle: Duration,
    /// Temporary-name patterns (`*` wildcard).
    pub ignore: Vec<String>,
    /// Accepted extensions, lower case, without the dot.
    pub extensions: Vec<String>,
}

/// How frames are grouped into brackets.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BracketRules {
    /// Largest capture-time gap between successive frames, seconds.
    pub max_gap_s: f64,
    /// Smallest exposure difference within a bracket, stops.
    pub min_step_ev: f64,
    /// Frames per bracket (closes when reached).
    pub size: usize,
    /// Render or report frames left alone.
    pub singles: Singles,
}

/// Concurrency and retries.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Daemon {
    /// Brackets developed at once.
    pub jobs: usize,
    /// Closed brackets waiting for a job.
    pub queue: usize,
    /// First retry delay after an output failure.
    pub retry: Duration,
}

/// What a camera's brackets are developed into (defaults merged with its preset).
#[derive(Debug, Clone, PartialEq)]
pub struct Preset {
    /// The preset's table name, or `None` for the `[render]` defaults.
    pub name: Option<String>,
    /// Write the EXR radiance map.
    pub exr: bool,
    /// Film stocks to render.
    pub films: Vec<String>,
    /// Tone maps to render.
    pub tonemaps: Vec<String>,
    /// Film exposure relative to metered mid-grey, stops.
    pub t: f64,
    /// JPEG quality 1..=100.
    pub jpeg_quality: u8,
    /// Where the response comes from.
    pub recalibrate: Recalibrate,
    /// Fits below this confidence are weak.
    pub min_confidence: f64,
}

/// A per-camera preset and what it matches.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraPreset {
    /// EXIF model it applies to.
    pub model: String,
    /// Body serial it is restricted to, if any.
    pub serial: Option<String>,
    /// The merged settings.
    pub preset: Preset,
}

/// The checked configuration the daemon runs on.
#[derive(Debug, Clone, PartialEq)]
pub struct Config {
    /// Where the file came from (`None`: built-in defaults only).
    pub source: Option<PathBuf>,
    /// Folders.
    pub folders: Folders,
    /// Watching and settling.
    pub watch: Watch,
    /// Grouping.
    pub bracket: BracketRules,
    /// Concurrency.
    pub daemon: Daemon,
    /// Settings for cameras without a preset.
    pub render: Preset,
    /// Per-camera presets.
    pub cameras: Vec<CameraPreset>,
}

impl Config {
    /// The built-in defaults.
    pub fn defaults() -> Config {
        Config::from_str(DEFAULT_TOML, None).expect("the embedded config/filmback.toml is valid")
    }

    /// Reads and checks a file over the defaults.
    pub fn load(path: &Path) -> Result<Config, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        Config::from_str(&text, Some(path))
    }

    /// Checks `text` (the contents of `path`, if any) over the defaults.
    pub fn from_str(text: &str, path: Option<&Path>) -> Result<Config, ConfigError> {
        let label = path.map_or_else(|| PathBuf::from("<built-in defaults>"), Path::to_path_buf);
        let defaults: RawConfig = parse(DEFAULT_TOML, Path::new("<built-in defaults>"))?;
        let user: RawConfig = parse(text, &label)?;
        let config = merge(defaults, user, path.map(Path::to_path_buf));
        config.check_folders(&label)?;
        config.check_looks(&label, text)?;
        Ok(config)
    }

    /// Checks that every preset's films and tone maps exist and can be rendered (with
    /// the options their stocks' sheets support), with the stocks of `folders.stocks` if set. An error names
    /// the line where the name appears in `text`.
    fn check_looks(&self, label: &Path, text: &str) -> Result<(), ConfigError> {
        let catalogue =
            crate::film::Catalogue::builtin().and_then(|c| match &self.folders.stocks {
                Some(dir) => c.with_folder(dir),
                None => Ok(c),
            });
        let catalogue = catalogue.map_err(|e| ConfigError::Invalid {
            path: label.to_path_buf(),
            line: line_of_key(text, "stocks"),
            column: 1,
            key: "folders.stocks".into(),
            message: e.to_string(),
        })?;
        let presets = std::iter::once(("render".to_string(), &self.render)).chain(
            self.cameras.iter().map(|c| {
                (
                    format!("camera.{:?}", c.preset.name.as_deref().unwrap_or("")),
                    &c.preset,
                )
            }),
        );
        for (table, preset) in presets {
            for (key, names) in [("films", &preset.films), ("tonemaps", &preset.tonemaps)] {
                for name in names {
                    let (films, tonemaps) = if key == "films" {
                        (std::slice::from_ref(name), &[][..])
                    } else {
                        (&[][..], std::slice::from_ref(name))
                    };
                    crate::rendering::looks(
                        &catalogue,
                        films,
                        tonemaps,
                        0.0,
                        crate::film::ColourMode::PerLayer,
                        crate::film::Key::LogAverage,
                    )
                    .map_err(|e| ConfigError::Invalid {
                        path: label.to_path_buf(),
                        line: line_of(text, &format!("\"{name}\"")),
                        column: 1,
                        key: format!("{table}.{key}"),
                        message: e.to_string(),
                    })?;
                }
            }
        }
        Ok(())
    }

    /// Checks the folders together (again after command-line overrides): outputs written
    /// into the watched folder would come back as frames. `label` names the source.
    pub fn check_folders(&self, label: &Path) -> Result<(), ConfigError> {
        let f = &self.folders;
        let inside =
            |dir: &Path| dir == f.ingest || (self.watch.recursive && dir.starts_with(&f.ingest));
        for (name, dir) in [("out", &f.out), ("state", &f.state)]
            .into_iter()
            .chain(f.archive.as_ref().map(|a| ("archive", a)))
        {
            if inside(dir) {
                return Err(ConfigError::Folders {
                    path: label.to_path_buf(),
                    reason: format!(
                        "{name} = {:?} is (inside) the watched ingest folder {:?}; its files would be taken as frames",
                        dir, f.ingest
                    ),
                });
            }
        }
        Ok(())
    }

    /// The preset for a camera body: a preset naming this model and serial, else one
    /// naming the model without a serial, else the `[render]` defaults.
    pub fn preset_for(&self, model: Option<&str>, serial: Option<&str>) -> &Preset {
        let Some(model) = model else {
            return &self.render;
        };
        let by_serial = self
            .cameras
            .iter()
            .find(|c| c.model == model && c.serial.is_some() && c.serial.as_deref() == serial);
        let by_model = || {
            self.cameras
                .iter()
                .find(|c| c.model == model && c.serial.is_none())
        };
        by_serial
            .or_else(by_model)
            .map_or(&self.render, |c| &c.preset)
    }
}

/// Deserialises with every error turned into file, line, column and key.
fn parse(text: &str, path: &Path) -> Result<RawConfig, ConfigError> {
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
fn line_of(text: &str, needle: &str) -> usize {
    text.lines()
        .position(|l| {
            l.split('#')
                .next()
                .is_some_and(|code| code.contains(needle))
        })
        .map_or(1, |i| i + 1)
}

/// The 1-based line that assigns `key` (`key = …`), 1 if none does.
fn line_of_key(text: &str, key: &str) -> usize {
    text.lines()
        .position(|l| {
            l.trim_start()
                .strip_prefix(key)
                .is_some_and(|rest| rest.trim_start().starts_with('='))
        })
        .map_or(1, |i| i + 1)
}

/// User values over defaults. The defaults file sets every key, so each `expect` holds
/// by construction (and the embedded-defaults test checks it).
fn merge(d: RawConfig, u: RawConfig, source: Option<PathBuf>) -> Config {
    let df = d.folders.unwrap_or_default();
    let uf = u.folders.unwrap_or_default();
    let dw = d.watch.unwrap_or_default();
    let uw = u.watch.unwrap_or_default();
    let db = d.bracket.unwrap_or_default();
    let ub = u.bracket.unwrap_or_default();
    let dd = d.daemon.unwrap_or_default();
    let ud = u.daemon.unwrap_or_default();
    let dr = d.render.unwrap_or_default();
    let ur = u.render.unwrap_or_default();
    const MISSING: &str = "key set in config/filmback.toml";
    let render = overlay(&dr, &ur);
    let rescan = uw.rescan_s.or(dw.rescan_s).expect(MISSING).0;
    let cameras = u
        .camera
        .into_iter()
        .map(|(name, p)| CameraPreset {
            model: p.model.clone().unwrap_or_else(|| name.clone()),
            serial: p.serial.clone(),
            preset: Preset {
                name: Some(name),
                ..preset(&overlay(&render, &p.render()))
            },
        })
        .collect();
    Config {
        source,
        folders: Folders {
            ingest: uf.ingest.or(df.ingest).expect(MISSING),
            out: uf.out.or(df.out).expect(MISSING),
            state: uf.state.or(df.state).expect(MISSING),
            archive: uf.archive.or(df.archive),
            stocks: uf.stocks.or(df.stocks),
        },
        watch: Watch {
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
        },
        bracket: BracketRules {
            max_gap_s: ub.max_gap_s.or(db.max_gap_s).expect(MISSING).0,
            min_step_ev: ub.min_step_ev.or(db.min_step_ev).expect(MISSING).0,
            size: ub.size.or(db.size).expect(MISSING).0,
            singles: ub.singles.or(db.singles).expect(MISSING),
        },
        daemon: Daemon {
            jobs: ud.jobs.or(dd.jobs).expect(MISSING).0,
            queue: ud.queue.or(dd.queue).expect(MISSING).0,
            retry: Duration::from_secs(ud.retry_s.or(dd.retry_s).expect(MISSING).0),
        },
        render: preset(&render),
        cameras,
    }
}

fn overlay(base: &RawRender, over: &RawRender) -> RawRender {
    RawRender {
        exr: over.exr.or(base.exr),
        films: over.films.clone().or_else(|| base.films.clone()),
        tonemaps: over.tonemaps.clone().or_else(|| base.tonemaps.clone()),
        t: over.t.or(base.t),
        jpeg_quality: over.jpeg_quality.or(base.jpeg_quality),
        recalibrate: over.recalibrate.or(base.recalibrate),
        min_confidence: over.min_confidence.or(base.min_confidence),
    }
}

fn preset(r: &RawRender) -> Preset {
    const MISSING: &str = "key set in config/filmback.toml";
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
        films: names(&r.films),
        tonemaps: names(&r.tonemaps),
        t: r.t.expect(MISSING).0,
        jpeg_quality: r.jpeg_quality.expect(MISSING).0,
        recalibrate: r.recalibrate.expect(MISSING),
        min_confidence: r.min_confidence.expect(MISSING).0,
    }
}

/// True when `name` matches `pattern`, where `*` matches any run of characters.
pub fn glob_match(pattern: &str, name: &str) -> bool {
    let (p, n): (Vec<char>, Vec<char>) = (pattern.chars().collect(), name.chars().collect());
    // Classic two-pointer wildcard match with backtracking to the last `*`.
    let (mut pi, mut ni) = (0, 0);
    let mut star: Option<(usize, usize)> = None;
    while ni < n.len() {
        if pi < p.len() && p[pi] == '*' {
            star = Some((pi, ni));
            pi += 1;
        } else if pi < p.len() && p[pi] == n[ni] {
            pi += 1;
            ni += 1;
        } else if let Some((sp, sn)) = star {
            pi = sp + 1;
            ni = sn + 1;
            star = Some((sp, sn + 1));
        } else {
            return false;
        }
    }
    p[pi..].iter().all(|&c| c == '*')
}

impl Watch {
    /// Whether a file name is a frame to take: not a temporary name, with an accepted
    /// extension. (Files written by [`crate::atomic`] are temporary names too.)
    pub fn takes(&self, name: &str) -> bool {
        if self.ignore.iter().any(|p| glob_match(p, name)) {
            return false;
        }
        let ext = Path::new(name)
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        ext.is_some_and(|e| self.extensions.contains(&e))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn invalid(text: &str) -> (usize, usize, String, String) {
        match Config::from_str(text, Some(Path::new("studio.toml"))).unwrap_err() {
            ConfigError::Invalid {
                path,
                line,
                column,
                key,
                message,
            } => {
                assert_eq!(path, Path::new("studio.toml"));
                (line, column, key, message)
            }
            other => panic!("{other}"),
        }
    }

    #[test]
    fn embedded_defaults_set_every_key() {
        let c = Config::defaults();
        assert_eq!(c.folders.ingest, Path::new("ingest"));
        assert_eq!(c.folders.out, Path::new("out"));
        assert_eq!(c.folders.state, Path::new(".filmback"));
        assert_eq!(c.folders.archive, None);
        assert_eq!(c.watch.mode, WatchMode::Notify);
        assert_eq!(c.watch.settle, Duration::from_millis(1000));
        assert_eq!(c.watch.rescan, Some(Duration::from_secs(60)));
        assert_eq!(c.bracket.size, 3);
        assert_eq!(c.bracket.singles, Singles::Render);
        assert_eq!(c.daemon.jobs, 2);
        assert_eq!(c.render.films, vec!["velvia50".to_string()]);
        assert_eq!(c.render.tonemaps, vec!["linear".to_string()]);
        assert_eq!(c.render.recalibrate, Recalibrate::Auto);
        assert!(c.cameras.is_empty());
        // An empty file is the defaults.
        let empty = Config::from_str("", Some(Path::new("e.toml"))).unwrap();
        assert_eq!(empty.render, c.render);
        assert_eq!(empty.watch, c.watch);
    }

    #[test]
    fn user_values_override_and_presets_match_model_then_serial() {
        let text = r#"
[folders]
ingest = "/srv/in"
[watch]
mode = "poll"
rescan_s = 0
[render]
films = ["provia400"]
t = 0.5
[camera."Canon EOS R5"]
films = ["velvia50", "ektachrome100"]
recalibrate = "never"
[camera.studio-b]
model = "Canon EOS R5"
serial = "042"
t = -1
"#;
        let c = Config::from_str(text, Some(Path::new("s.toml"))).unwrap();
        assert_eq!(c.folders.ingest, Path::new("/srv/in"));
        assert_eq!(c.folders.out, Path::new("out"));
        assert_eq!(c.watch.mode, WatchMode::Poll);
        assert_eq!(c.watch.rescan, None);
        let p = c.preset_for(Some("Canon EOS R5"), Some("001"));
        assert_eq!(p.name.as_deref(), Some("Canon EOS R5"));
        assert_eq!(p.films, vec!["velvia50", "ektachrome100"]);
        assert_eq!(p.t, 0.5, "inherits [render]");
        assert_eq!(p.recalibrate, Recalibrate::Never);
        let b = c.preset_for(Some("Canon EOS R5"), Some("042"));
        assert_eq!(b.name.as_deref(), Some("studio-b"));
        assert_eq!(b.t, -1.0);
        assert_eq!(b.films, vec!["provia400"]);
        let other = c.preset_for(Some("NIKON Z 8"), None);
        assert_eq!(other.name, None);
        assert_eq!(other.films, vec!["provia400"]);
        assert_eq!(c.preset_for(None, None).name, None);
    }

    #[test]
    fn unknown_key_names_file_line_and_key() {
        let (line, _, key, message) = invalid("[watch]\nsettle_ms = 10\nsetle = 5\n");
        assert_eq!(line, 3);
        assert_eq!(key, "setle");
        assert!(message.contains("unknown field"), "{message}");
        let (line, _, key, _) = invalid("\n[camera.x]\nfilms = []\ncolour = 1\n");
        assert_eq!((line, key.as_str()), (4, "colour"));
        let (line, _, key, _) = invalid("[wach]\n");
        assert_eq!((line, key.as_str()), (1, "[wach]"));
    }

    #[test]
    fn bad_values_name_line_key_and_range() {
        let (line, column, key, message) = invalid("[daemon]\njobs = 0\n");
        assert_eq!((line, column, key.as_str()), (2, 8, "jobs"));
        assert!(message.contains("outside 1..=64"), "{message}");
        let (_, _, key, message) = invalid("[bracket]\nsize = 2.5\n");
        assert_eq!(key, "size");
        assert!(message.contains("whole number"), "{message}");
        let (_, _, key, message) = invalid("[watch]\nmode = \"inotify\"\n");
        assert_eq!(key, "mode");
        assert!(message.contains("notify"), "{message}");
        let (_, _, key, message) = invalid("[render]\nfilms = [\"Velvia 50\"]\n");
        assert_eq!(key, "films");
        assert!(message.contains("not a valid name"), "{message}");
        let (_, _, key, _) = invalid("[render]\nmin_confidence = \"high\"\n");
        assert_eq!(key, "min_confidence");
        let (line, _, _, _) = invalid("[render\n");
        assert_eq!(line, 1);
        let msg = Config::from_str("[daemon]\njobs = -3\n", Some(Path::new("/etc/f.toml")))
            .unwrap_err()
            .to_string();
        assert!(msg.starts_with("/etc/f.toml:2:8: jobs: "), "{msg}");
    }

    #[test]
    fn outputs_inside_the_ingest_folder_are_refused() {
        let err = Config::from_str("[folders]\nout = \"ingest\"\n", Some(Path::new("s.toml")))
            .unwrap_err()
            .to_string();
        assert!(err.starts_with("s.toml: [folders]: out = "), "{err}");
        let text = "[folders]\nout = \"ingest/out\"\n[watch]\nrecursive = true\n";
        assert!(Config::from_str(text, Some(Path::new("s.toml"))).is_err());
        let text = "[folders]\nout = \"ingest/out\"\n";
        assert!(Config::from_str(text, Some(Path::new("s.toml"))).is_ok());
    }

    #[test]
    fn missing_file_is_a_read_error_naming_it() {
        let err = Config::load(Path::new("/nonexistent/filmback.toml")).unwrap_err();
        assert!(
            err.to_string().contains("/nonexistent/filmback.toml"),
            "{err}"
        );
    }

    #[test]
    fn temporary_names_are_ignored() {
        let w = Config::defaults().watch;
        for name in [
            "IMG_1.JPG",
            "a.jpeg",
            "scan.tif",
            "x.png",
            "IMG_0001.CR3.jpg",
        ] {
            assert!(w.takes(name), "{name}");
        }
        for name in [
            ".IMG_1.jpg",
            "IMG_1.jpg.tmp",
            "IMG_1.jpg.part",
            "IMG_1.jpg~",
            "IMG_1.jpg.crdownload",
            ".~lock.jpg",
            "notes.txt",
            "IMG_1",
            ".a.jpg.filmback-tmp-12",
        ] {
            assert!(!w.takes(name), "{name}");
        }
    }

    #[test]
    fn glob() {
        assert!(glob_match("*.tmp", "a.tmp"));
        assert!(glob_match("*.tmp", ".tmp"));
        assert!(!glob_match("*.tmp", "a.tmpx"));
        assert!(glob_match("a*b*c", "aXXbYbc"));
        assert!(!glob_match("a*b*c", "aXXbY"));
        assert!(glob_match("*", ""));
    }

    // ---- films, tone maps and the stocks folder ----

    fn load(text: &str) -> Result<Config, ConfigError> {
        Config::from_str(text, Some(Path::new("studio.toml")))
    }

    /// A copy of the built-in Velvia 50 file under another id, in `dir/<file>`.
    fn user_stock(dir: &Path, file: &str, id: &str) {
        let velvia = include_str!("../../curves/velvia50.toml");
        assert!(velvia.contains("id = \"velvia50\"\n"));
        let text = velvia
            .replace("id = \"velvia50\"\n", &format!("id = \"{id}\"\n"))
            .replace("name = \"Fujifilm", "name = \"Studio copy of Fujifilm");
        std::fs::write(dir.join(file), text).unwrap();
    }

    fn toml_string(path: &Path) -> String {
        format!("{:?}", path.to_str().unwrap())
    }

    #[test]
    fn known_films_with_exposures_load() {
        let text = "[render]\nfilms = [\"velvia50\", \"provia400@1/2\", \"p1600@-1ev\"]\n\
                    tonemaps = [\"linear\", \"histogram\", \"histogram-naive\"]\n\
                    [camera.\"X\"]\nfilms = [\"ektachrome100@2\"]\ntonemaps = []\n";
        let c = load(text).unwrap();
        assert_eq!(c.render.films, ["velvia50", "provia400@1/2", "p1600@-1ev"]);
        assert_eq!(
            c.render.tonemaps,
            ["linear", "histogram", "histogram-naive"]
        );
        let x = c.preset_for(Some("X"), None);
        assert_eq!(x.films, ["ektachrome100@2"]);
        assert!(x.tonemaps.is_empty());
    }

    #[test]
    fn unknown_stock_names_its_line_and_key() {
        // `velvia5` is a prefix of a good name that comes first, and appears unquoted in a
        // comment: the line reported is the one holding the bad name.
        let text = "# velvia5 was a typo\n[render]\nfilms = [\"velvia50\"]\n\
                    [camera.\"X\"]\nt = 1\nfilms = [\"velvia50\",\n  \"velvia5\"]\n";
        let (line, _, key, message) = invalid(text);
        assert_eq!((line, key.as_str()), (7, "camera.\"X\".films"));
        assert!(
            message.contains("unknown film stock \"velvia5\""),
            "{message}"
        );
        assert!(
            message.contains("velvia50"),
            "lists the known stocks: {message}"
        );

        let (line, _, key, message) = invalid("\n\n[render]\nt = 0\nfilms = [\"velvia5\"]\n");
        assert_eq!((line, key.as_str()), (5, "render.films"));
        assert!(message.contains("\"velvia5\""), "{message}");
        let err = load("[render]\nfilms = [\"velvia5@1/2\"]\n")
            .unwrap_err()
            .to_string();
        assert!(
            err.starts_with("studio.toml:2:1: render.films: ") && err.contains("\"velvia5\""),
            "{err}"
        );
    }

    #[test]
    fn negatives_render_and_an_option_without_sheet_data_is_refused() {
        let text = "[render]\nfilms = [\"velvia50\"]\n\n[camera.\"Canon EOS R5\"]\nt = 0.5\n\
                    films = [\"velvia50\", \"portra400\", \"ektar100@1/2+print=-1/3\"]\n";
        if let Err(e) = load(text) {
            panic!("{e}");
        }
        // Kodak gives no RMS granularity for its negatives: +grain is refused, by line.
        let text = "[render]\nfilms = [\"velvia50\"]\n\n[camera.\"Canon EOS R5\"]\nt = 0.5\n\
                    films = [\"velvia50\", \"portra400+grain\"]\n";
        let (line, _, key, message) = invalid(text);
        assert_eq!(line, 6);
        assert_eq!(key, "camera.\"Canon EOS R5\".films");
        assert!(message.contains("RMS granularity"), "{message}");
    }

    #[test]
    fn unknown_tonemap_is_refused() {
        let (line, _, key, message) = invalid("[render]\nfilms = []\ntonemaps = [\"sepia\"]\n");
        assert_eq!((line, key.as_str()), (3, "render.tonemaps"));
        assert!(
            message.contains("\"sepia\"") && message.contains("unknown tone map"),
            "{message}"
        );
        let (line, _, key, _) = invalid("[camera.x]\ntonemaps = [\"linear\", \"velvia50\"]\n");
        assert_eq!((line, key.as_str()), (2, "camera.\"x\".tonemaps"));
    }

    #[test]
    fn bad_film_exposure_fails_while_parsing() {
        let (line, column, key, message) = invalid("[render]\nt = 1\nfilms = [\"velvia50@abc\"]\n");
        assert_eq!((line, key.as_str()), (3, "films"));
        assert!(column > 1, "points into the value: column {column}");
        assert!(message.contains("velvia50@abc"), "{message}");
        assert!(message.contains("abc"), "{message}");
        for bad in ["velvia50@0", "velvia50@-1", "@1/2", "velvia50@1/0"] {
            let (_, _, key, message) = invalid(&format!("[render]\nfilms = [\"{bad}\"]\n"));
            assert_eq!(key, "films", "{bad}");
            assert!(message.contains(bad), "{bad}: {message}");
        }
    }

    #[test]
    fn stocks_folder_adds_user_stocks() {
        let stocks = tempfile::tempdir().unwrap();
        user_stock(stocks.path(), "studio.toml", "studio-slide");
        let text = format!(
            "[folders]\nstocks = {}\n[render]\nfilms = [\"studio-slide\", \"studio-slide@1/2\", \"velvia50\"]\n",
            toml_string(stocks.path())
        );
        let c = load(&text).unwrap();
        assert_eq!(c.folders.stocks.as_deref(), Some(stocks.path()));
        assert_eq!(
            c.render.films,
            ["studio-slide", "studio-slide@1/2", "velvia50"]
        );
        // Without the folder the same name is unknown.
        let (line, _, key, message) =
            invalid("[render]\nfilms = [\"studio-slide\", \"velvia50\"]\n");
        assert_eq!((line, key.as_str()), (2, "render.films"));
        assert!(message.contains("studio-slide"), "{message}");
        // Another folder's stocks do not count.
        let empty = tempfile::tempdir().unwrap();
        let text = format!(
            "[folders]\nstocks = {}\n[camera.x]\nfilms = [\"studio-slide\"]\n",
            toml_string(empty.path())
        );
        let (line, _, key, _) = invalid(&text);
        assert_eq!((line, key.as_str()), (4, "camera.\"x\".films"));
    }

    #[test]
    fn bad_stocks_folder_is_refused_at_its_key() {
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("missing");
        let text = format!(
            "[render]\nfilms = [\"velvia50\"]\n[folders]\nstocks = {}\n",
            toml_string(&missing)
        );
        let (line, _, key, message) = invalid(&text);
        assert_eq!((line, key.as_str()), (4, "folders.stocks"));
        assert!(message.contains("missing"), "{message}");
        // The line of the key, not of an earlier mention of the word.
        let text = format!(
            "# stocks: see below\n[folders]\nout = \"/srv/stocks-out\"\nstocks = {}\n",
            toml_string(&missing)
        );
        let (line, _, key, _) = invalid(&text);
        assert_eq!((line, key.as_str()), (4, "folders.stocks"));

        // A user stock reusing a built-in id.
        user_stock(dir.path(), "dup.toml", "velvia50");
        let text = format!("[folders]\nstocks = {}\n", toml_string(dir.path()));
        let (line, _, key, message) = invalid(&text);
        assert_eq!((line, key.as_str()), (2, "folders.stocks"));
        assert!(message.contains("already defined"), "{message}");
    }

    #[test]
    fn errors_in_the_example_file_point_at_the_edited_line() {
        // The shipped example, copied and edited: the stocks folder enabled (it does not
        // exist) and a film replaced. Its comments mention both.
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("no-such-stocks");
        let line_holding = |text: &str, needle: &str| {
            text.lines().position(|l| l.starts_with(needle)).unwrap() + 1
        };
        let text = DEFAULT_TOML.replace(
            "# stocks = \"stocks\"",
            &format!("stocks = {}", toml_string(&missing)),
        );
        let (line, _, key, _) = invalid(&text);
        assert_eq!(key, "folders.stocks");
        assert_eq!(line, line_holding(&text, "stocks = "));

        let text = DEFAULT_TOML.replace("films = [\"velvia50\"]", "films = [\"provia100\"]");
        let (line, _, key, message) = invalid(&text);
        assert_eq!(key, "render.films");
        assert_eq!(line, line_holding(&text, "films = [\"provia100\"]"));
        assert!(message.contains("provia100"), "{message}");
    }
}
