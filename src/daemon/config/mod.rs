//! The daemon's configuration: one TOML file, parsed in two stages.
//!
//! `raw::RawConfig` mirrors the file (serde, `deny_unknown_fields`, every value checked while
//! it is read so the error carries its line and column); [`Config`] is the checked form
//! the daemon runs on. The defaults are `config/filmback.toml`, embedded in the binary, so
//! the daemon runs without any file; a user's file is read over them key by key.

use std::path::{Path, PathBuf};
use std::time::Duration;

use serde::Deserialize;

/// The commented example configuration, which is also the source of every default.
pub(crate) const DEFAULT_TOML: &str = include_str!("../../../config/filmback.toml");

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
    /// The stock folder or a film or tone map a preset names does not load.
    #[error("{path}:{line}:{column}: {key}: {source}")]
    Looks {
        /// The file (`<built-in defaults>` for the embedded file).
        path: PathBuf,
        /// 1-based line.
        line: usize,
        /// 1-based column.
        column: usize,
        /// The key (`folders.stocks`, or the preset's `films` or `tonemaps`).
        key: String,
        /// Why it does not load.
        #[source]
        source: Box<LooksError>,
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

/// Why the looks a configuration names do not load ([`ConfigError::Looks`]).
#[derive(Debug, thiserror::Error)]
pub enum LooksError {
    /// The stock folder, or a stock in it, does not load.
    #[error(transparent)]
    Stocks(#[from] crate::film::FilmError),
    /// A film or tone map name that does not resolve.
    #[error(transparent)]
    Look(#[from] crate::rendering::RenderingError),
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

mod raw;

use raw::{RawConfig, line_of, line_of_key, merge, parse};

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
    /// Watch sub-folders too (see [`Watch::descends`]).
    pub recursive: bool,
    /// Size, mtime, change time and inode must be stable this long.
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
    /// First retry delay after an output failure (or a read error).
    pub retry: Duration,
    /// Memory budget of the brackets developing at once, in MB (10^6 bytes); a job is
    /// admitted when its estimate ([`crate::daemon::job_bytes`]) fits beside the others.
    pub memory_mb: u64,
}

/// What a camera's brackets are developed into (defaults merged with its preset).
#[derive(Debug, Clone, PartialEq)]
pub struct Preset {
    /// The preset's table name, or `None` for the `[render]` defaults.
    pub name: Option<String>,
    /// Write the EXR radiance map.
    pub exr: bool,
    /// Write a camera raw bracket's merged mosaic as linear DNG (other brackets have
    /// none; [`crate::raw::dng`]).
    pub dng: bool,
    /// Write `STEM.ghosts.png`, where deghosting left frames out
    /// ([`crate::darkroom::Prints::ghost_map`]).
    pub ghost_map: bool,
    /// Film stocks to render.
    pub films: Vec<String>,
    /// Tone maps to render.
    pub tonemaps: Vec<String>,
    /// Film exposure relative to metered mid-grey, stops.
    pub t: f64,
    /// JPEG quality 1..=100.
    pub jpeg_quality: u8,
    /// Write each look as an HDR still, a gain-map JPEG
    /// ([`crate::rendering::hdr_still`]), instead of a plain JPEG.
    pub hdr_still: bool,
    /// Where the response comes from.
    pub recalibrate: Recalibrate,
    /// Fits below this confidence are weak.
    pub min_confidence: f64,
    /// Calibration factor `c` of the EXR's luminance scale (1: nominal cd/m² from the
    /// EXIF exposure; see `merge`'s "Absolute scale").
    pub luminance_calibration: f64,
    /// RGB primaries of the EXR.
    pub primaries: crate::hdr_output::Primaries,
    /// The display the renderings are encoded for.
    pub colour_space: crate::display::ColourSpace,
    /// How the frames are aligned before the merge (`[merge] align`, or the camera's).
    pub align: crate::align::AlignMode,
    /// Whether frames that disagree with the reference are left out (`[merge] deghost`,
    /// or the camera's).
    pub deghost: crate::merge::Deghost,
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
    /// The tether station's page, events and metrics.
    pub viewer: Viewer,
    /// Commands run on the daemon's events.
    pub hooks: Hooks,
}

/// Commands run on the daemon's events (`[hooks]`).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Hooks {
    /// Run by `/bin/sh -c` after a bracket or single frame is published, with its outputs
    /// as the positional parameters (`"$@"`) and `FILMBACK_STEM`, `FILMBACK_CAMERA` set.
    pub on_developed: Option<String>,
}

/// Shortest token accepted for the viewer (characters).
pub const MIN_TOKEN_CHARS: usize = 16;

/// A secret the viewer's clients present (`Authorization: Bearer …` or `?token=…`):
/// printable ASCII without spaces, at least [`MIN_TOKEN_CHARS`] long once checked. Its
/// `Debug` form never shows it.
#[derive(Clone, PartialEq, Eq)]
pub struct Token(pub(crate) String);

impl Token {
    /// The secret itself.
    pub fn expose(&self) -> &str {
        &self.0
    }

    /// Why this text is not a usable token, if it is not.
    fn fault(&self) -> Option<String> {
        if self.0.chars().count() < MIN_TOKEN_CHARS {
            return Some(format!(
                "a token needs at least {MIN_TOKEN_CHARS} characters"
            ));
        }
        if !self.0.chars().all(|c| c.is_ascii_graphic()) {
            return Some("a token is printable ASCII without spaces".to_string());
        }
        None
    }
}

impl std::fmt::Debug for Token {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Token(…)")
    }
}

/// Where and how the viewer is served (`[viewer]`).
#[derive(Debug, Clone, PartialEq)]
pub struct Viewer {
    /// Serve it at all.
    pub enabled: bool,
    /// Address and port to listen on (port 0: the system chooses).
    pub address: std::net::SocketAddr,
    /// The token every request must carry; always set when `address` is not loopback.
    pub token: Option<Token>,
    /// The file the token was read from, if it came from one.
    pub token_file: Option<PathBuf>,
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
        let mut config = merge(defaults, user, path.map(Path::to_path_buf));
        config.check_folders(&label)?;
        config.check_looks(&label, text)?;
        config.check_viewer(&label, text)?;
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
        let catalogue = catalogue.map_err(|e| ConfigError::Looks {
            path: label.to_path_buf(),
            line: line_of_key(text, "stocks"),
            column: 1,
            key: "folders.stocks".into(),
            source: Box::new(e.into()),
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
                    .map_err(|e| ConfigError::Looks {
                        path: label.to_path_buf(),
                        line: line_of(text, &format!("\"{name}\"")),
                        column: 1,
                        key: format!("{table}.{key}"),
                        source: Box::new(e.into()),
                    })?;
                }
            }
        }
        Ok(())
    }

    /// Reads the viewer's token file, checks the token, and refuses a bind address other
    /// than loopback without one. An error names the line of the key in `text`.
    fn check_viewer(&mut self, label: &Path, text: &str) -> Result<(), ConfigError> {
        let invalid = |key: &str, message: String| ConfigError::Invalid {
            path: label.to_path_buf(),
            line: line_of_key(text, key),
            column: 1,
            key: format!("viewer.{key}"),
            message,
        };
        let v = &mut self.viewer;
        if let Some(file) = &v.token_file {
            if v.token.is_some() {
                return Err(invalid(
                    "token_file",
                    "give the token or a token file, not both".into(),
                ));
            }
            let read = std::fs::read_to_string(file).map_err(|source| ConfigError::Read {
                path: file.clone(),
                source,
            })?;
            v.token = Some(Token(read.lines().next().unwrap_or("").trim().to_string()));
        }
        let key = if v.token_file.is_some() {
            "token_file"
        } else {
            "token"
        };
        if let Some(fault) = v.token.as_ref().and_then(Token::fault) {
            return Err(invalid(key, fault));
        }
        if !v.address.ip().is_loopback() && v.token.is_none() {
            return Err(invalid(
                "bind",
                format!(
                    "{} is not a loopback address: the viewer then requires `token` or `token_file`",
                    v.address.ip()
                ),
            ));
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

/// True when `name` matches `pattern`, where `*` matches any run of characters.
pub(crate) fn glob_match(pattern: &str, name: &str) -> bool {
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

/// Folders the tethering tools keep their own files in, beside the frames: never
/// descended into, whatever `[watch] ignore` says. Capture One keeps `CaptureOne/` in
/// every image folder (settings `.cos`, previews `.cop`, thumbnails `.cot`, masks
/// `.comask`, caches).
pub(crate) const TOOL_FOLDERS: &[&str] = &["CaptureOne"];

impl Watch {
    /// Whether a file name is a frame to take: not hidden, not a temporary name, with an
    /// accepted extension. Hidden names (a leading `.`: macOS `.DS_Store` and `._*`
    /// AppleDouble files, the staging names of [`crate::atomic`] and `filmback hook`) are
    /// never frames, whatever `ignore` says; sidecars (`x.xmp`, `x.cr2.xmp`, `.cos`,
    /// `Thumbs.db`) and gphoto2's `tmpfileXXXXXX` fail the extension test.
    pub fn takes(&self, name: &str) -> bool {
        if name.starts_with('.') || self.ignore.iter().any(|p| glob_match(p, name)) {
            return false;
        }
        let ext = Path::new(name)
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        ext.is_some_and(|e| self.extensions.contains(&e))
    }

    /// Whether a sub-folder named `name` is descended into (when `recursive`): not hidden,
    /// not one of the [`TOOL_FOLDERS`].
    pub fn descends(&self, name: &str) -> bool {
        self.recursive
            && !name.starts_with('.')
            && !TOOL_FOLDERS.iter().any(|f| f.eq_ignore_ascii_case(name))
    }

    /// Whether the file at `path`, below the ingest folder `root`, is a frame to take: its
    /// name is taken ([`Watch::takes`]) and every folder between `root` and it is
    /// descended into ([`Watch::descends`]). A path not below `root` is judged by its name.
    pub(crate) fn takes_path(&self, root: &Path, path: &Path) -> bool {
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy())
            .unwrap_or_default();
        if !self.takes(&name) {
            return false;
        }
        let Some(rest) = path.parent().and_then(|p| p.strip_prefix(root).ok()) else {
            return true;
        };
        rest.components()
            .all(|c| self.descends(&c.as_os_str().to_string_lossy()))
    }
}

#[cfg(test)]
mod tests;
