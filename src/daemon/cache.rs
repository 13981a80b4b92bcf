//! The response cache: one inverse response per camera body, in the state folder under
//! `responses/<camera>.toml` (versioned TOML, written atomically).
//!
//! A bracket whose own fit is weak (γ near 1, little overlap, low confidence), or whose
//! preset says `recalibrate = "never"`, is merged with its body's cached curve. Good fits
//! **pool their evidence**: the entry keeps the thinned tone pairs of the body's latest
//! good brackets ([`PooledBracket`], at most [`POOL_BRACKETS`] brackets and
//! [`POOL_SETS`] frame pairs per channel, the oldest dropped first), and its curve is one
//! joint fit over all of them ([`crate::response::pool`]), made by the lab after it
//! publishes a good bracket that agrees with the pool. With two jobs of one body in
//! flight at once, each refits the pool as it was when it started, so the stored curve
//! may lack the other's bracket until the next refit; the stored evidence never does.
//!
//! A good bracket that the cached curve explains worse than its own fit by more than
//! [`CONTRADICTION_STOPS`] (a picture style or setting changed) is not pooled: it is kept
//! aside as a *dissent*. [`DISSENTS_TO_REPLACE`] dissents in a row that one joint fit
//! explains (each within [`CONTRADICTION_STOPS`] of its own fit) replace the pool: the
//! body's processing has changed and the cache follows it. A bracket that agrees with the
//! pool clears the dissents.
//!
//! Beside that curve *recovered from histograms*, an entry may hold a curve *measured
//! from raw*: the body's JPEG response read off RAW+JPEG captures
//! ([`crate::response::measured`]), the latest measurement replacing the previous one.
//! When present it is the curve the body's JPEG-only brackets are merged with. A body
//! measured before any bracket recovered a curve has `brackets = 0`: its recovered curve
//! is then a copy of the measured one with a negligible weight, which the first good fit
//! replaces.

use std::fs;
use std::io;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::atomic::{self, Overwrite};
use crate::daemon::bracket::CameraId;
use crate::darkroom::CONTRADICTION_STOPS;
use crate::histogram::TonePair;
use crate::response::pool::{self, Evidence, PairSet};
use crate::response::{Degree, InverseResponse, ResponseError};

/// Version written into each cache file. Version 1 files (a running mean, no evidence)
/// are read as a curve without evidence, which the first pooled bracket replaces; other
/// versions are refused.
pub const VERSION: u32 = 2;

/// Most brackets a body's pool keeps.
pub const POOL_BRACKETS: usize = 16;

/// Most frame pairs per channel a body's pool keeps (a 9-frame bracket gives 8).
pub const POOL_SETS: usize = 48;

/// Dissenting brackets in a row that replace a body's pool (see the module docs).
pub const DISSENTS_TO_REPLACE: usize = 3;

/// Why the cache cannot be read or written.
#[derive(Debug, thiserror::Error)]
pub enum CacheError {
    /// Reading, listing or publishing failed.
    #[error("{path}: {source}")]
    Io {
        /// The file or folder.
        path: PathBuf,
        /// What the operating system said.
        source: io::Error,
    },
    /// The file is not a cache entry of this version.
    #[error("{path}: not a usable response cache entry: {reason}")]
    Invalid {
        /// The file.
        path: PathBuf,
        /// Why.
        reason: String,
    },
    /// The file is not TOML of a cache entry's shape.
    #[error("{path}: not a usable response cache entry: {source}")]
    Syntax {
        /// The file.
        path: PathBuf,
        /// The parser's error, with line and column.
        #[source]
        source: toml::de::Error,
    },
    /// The entry could not be written as TOML.
    #[error("{path}: not a usable response cache entry: {source}")]
    Serialise {
        /// The file.
        path: PathBuf,
        /// The serialiser's error.
        #[source]
        source: toml::ser::Error,
    },
    /// The entry's recovered curve is not a valid inverse response.
    #[error("{path}: not a usable response cache entry: {source}")]
    Curve {
        /// The file.
        path: PathBuf,
        /// What is wrong with the curve.
        #[source]
        source: ResponseError,
    },
    /// The entry's measured curve is not a valid inverse response.
    #[error("{path}: not a usable response cache entry: measured curve: {source}")]
    MeasuredCurve {
        /// The file.
        path: PathBuf,
        /// What is wrong with the curve.
        #[source]
        source: ResponseError,
    },
    /// Publishing the updated entry failed.
    #[error(transparent)]
    Publish(#[from] atomic::PublishError),
    /// No entry matches the name given on the command line.
    #[error("no cached response matches {query:?} (see `filmback cache list`)")]
    NotFound {
        /// What was asked for.
        query: String,
    },
    /// Several entries match the name given on the command line.
    #[error("{query:?} matches several cameras: {matches}; be more specific")]
    Ambiguous {
        /// What was asked for.
        query: String,
        /// The matching camera names.
        matches: String,
    },
}

/// A camera body's cached inverse response.
#[derive(Debug, Clone, PartialEq)]
pub struct CachedResponse {
    /// The body.
    pub camera: CameraId,
    /// The curve.
    pub response: InverseResponse,
    /// Per channel, the curve's confidence in `[0, 1]` (empty when unknown: a version-1
    /// entry, or a placeholder).
    pub confidence: Vec<f64>,
    /// Good brackets folded in since the entry began (the pool keeps the latest).
    pub brackets: u64,
    /// Last update, Unix seconds.
    pub updated: u64,
    /// The evidence of the latest good brackets, oldest first.
    pub pool: Vec<PooledBracket>,
    /// Good brackets in a row that contradicted the pool, oldest first.
    pub dissent: Vec<PooledBracket>,
    /// The curve measured from RAW+JPEG captures, if any.
    pub measured: Option<MeasuredCurve>,
}

/// One good bracket's evidence in a body's pool.
#[derive(Debug, Clone, PartialEq)]
pub struct PooledBracket {
    /// The bracket's output name.
    pub name: String,
    /// When it was developed, Unix seconds.
    pub at: u64,
    /// Its own fit's confidence (lowest channel).
    pub own_confidence: f64,
    /// How far its own fit is from its evidence, RMS stops ([`pool::agreement`]).
    pub own_misfit: f64,
    /// The thinned tone pairs.
    pub evidence: Evidence,
}

impl CachedResponse {
    /// The lowest channel confidence, if known.
    pub fn min_confidence(&self) -> Option<f64> {
        self.confidence.iter().copied().reduce(f64::min)
    }
}

/// What [`ResponseCache::dissent`] did.
#[derive(Debug, Clone, PartialEq)]
pub enum Dissent {
    /// The bracket was kept aside; this many dissents are now in a row.
    Kept(usize),
    /// The dissents replaced the pool (the body's processing changed).
    Replaced,
}

/// A body's JPEG curve measured from raw (see the module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct MeasuredCurve {
    /// The curve, one sample per JPEG code.
    pub response: InverseResponse,
    /// Per channel, the fraction of codes 1..=254 measured.
    pub coverage: Vec<f64>,
    /// RAW+JPEG captures of the measurement.
    pub captures: u64,
    /// When it was measured, Unix seconds.
    pub updated: u64,
}

/// What the cache file says a measured curve came from.
pub const MEASURED_SOURCE: &str = "measured from raw (RAW+JPEG captures)";

/// What the cache file says the bracket curve came from.
pub const RECOVERED_SOURCE: &str = "recovered from histograms";

/// The measured part of the file.
#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct MeasuredFile {
    source: String,
    captures: u64,
    updated: u64,
    coverage: Vec<f64>,
    /// Per channel, `g(k/255)`.
    channels: Vec<Vec<f64>>,
}

/// One frame pair's tone pairs in the file: `[dark, bright, σ_dark, σ_bright, quantile]`.
#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct SetFile {
    channel: usize,
    log_ratio: f64,
    pairs: Vec<[f64; 5]>,
}

/// A pooled bracket in the file.
#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct BracketFile {
    name: String,
    at: u64,
    frames: usize,
    own_confidence: f64,
    own_misfit: f64,
    sets: Vec<SetFile>,
}

/// The file layout.
#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct CacheFile {
    version: u32,
    camera: CameraId,
    /// The running mean's weight (version 1 only).
    #[serde(default, skip_serializing)]
    weight: Option<f64>,
    brackets: u64,
    updated: u64,
    /// Where `channels` came from ([`RECOVERED_SOURCE`]); absent in older files.
    #[serde(default)]
    source: Option<String>,
    /// Per channel, the curve's confidence.
    #[serde(default)]
    confidence: Vec<f64>,
    /// Per channel, `g(i/(n−1))`.
    channels: Vec<Vec<f64>>,
    /// The measured curve, if any.
    #[serde(default)]
    measured: Option<MeasuredFile>,
    /// The pool's brackets, oldest first.
    #[serde(default)]
    pool: Vec<BracketFile>,
    /// The dissenting brackets, oldest first.
    #[serde(default)]
    dissent: Vec<BracketFile>,
}

/// `v` rounded to 6 significant digits: the file's precision for tones and their
/// standard deviations (an 8-bit code is 0.0039).
fn round6(v: f64) -> f64 {
    if v == 0.0 || !v.is_finite() {
        return v;
    }
    let scale = 10f64.powi(5 - v.abs().log10().floor() as i32);
    (v * scale).round() / scale
}

/// `b` at the file's precision ([`round6`]), so an entry in memory equals it read back.
fn rounded(mut b: PooledBracket) -> PooledBracket {
    for p in b
        .evidence
        .channels
        .iter_mut()
        .flatten()
        .flat_map(|s| s.pairs.iter_mut())
    {
        p.dark = round6(p.dark);
        p.bright = round6(p.bright);
        p.sigma_dark = round6(p.sigma_dark);
        p.sigma_bright = round6(p.sigma_bright);
        p.quantile = round6(p.quantile);
    }
    b
}

fn bracket_file(b: &PooledBracket) -> BracketFile {
    BracketFile {
        name: b.name.clone(),
        at: b.at,
        frames: b.evidence.frames,
        own_confidence: b.own_confidence,
        own_misfit: b.own_misfit,
        sets: b
            .evidence
            .channels
            .iter()
            .enumerate()
            .flat_map(|(channel, sets)| {
                sets.iter().map(move |s| SetFile {
                    channel,
                    log_ratio: s.log_ratio,
                    pairs: s
                        .pairs
                        .iter()
                        .map(|p| {
                            [p.dark, p.bright, p.sigma_dark, p.sigma_bright, p.quantile].map(round6)
                        })
                        .collect(),
                })
            })
            .collect(),
    }
}

/// A pooled bracket as stored, checked: each tone pair set on a channel the curve has,
/// with a positive log ratio and finite, non-negative pairs (else why not, for `path`).
fn pooled_bracket(
    f: BracketFile,
    channels: usize,
    path: &Path,
) -> Result<PooledBracket, CacheError> {
    let invalid = |reason: String| CacheError::Invalid {
        path: path.to_path_buf(),
        reason,
    };
    let mut per_channel: Vec<Vec<PairSet>> = vec![Vec::new(); channels];
    for set in f.sets {
        let slot = per_channel.get_mut(set.channel).ok_or_else(|| {
            invalid(format!(
                "bracket {}: channel {} of {channels}",
                f.name, set.channel
            ))
        })?;
        let ok = |v: f64| v.is_finite() && v >= 0.0;
        if !(set.log_ratio.is_finite() && set.log_ratio > 0.0)
            || set.pairs.iter().flatten().any(|&v| !ok(v))
        {
            return Err(invalid(format!(
                "bracket {}: a tone pair is not usable",
                f.name
            )));
        }
        slot.push(PairSet {
            log_ratio: set.log_ratio,
            pairs: set
                .pairs
                .iter()
                .map(|p| TonePair {
                    dark: p[0],
                    bright: p[1],
                    sigma_dark: p[2],
                    sigma_bright: p[3],
                    quantile: p[4],
                })
                .collect(),
        });
    }
    if f.frames < 2 {
        return Err(invalid(format!("bracket {}: {} frames", f.name, f.frames)));
    }
    Ok(PooledBracket {
        name: f.name,
        at: f.at,
        own_confidence: f.own_confidence,
        own_misfit: f.own_misfit,
        evidence: Evidence {
            frames: f.frames,
            channels: per_channel,
        },
    })
}

/// Drops the oldest brackets until at most [`POOL_BRACKETS`] remain with at most
/// [`POOL_SETS`] frame pairs in any channel (the newest is always kept).
fn trim(pool: &mut Vec<PooledBracket>) {
    let most_sets = |p: &[PooledBracket]| {
        let channels = p
            .iter()
            .map(|b| b.evidence.channels.len())
            .max()
            .unwrap_or(0);
        (0..channels)
            .map(|c| {
                p.iter()
                    .map(|b| b.evidence.channels.get(c).map_or(0, Vec::len))
                    .sum::<usize>()
            })
            .max()
            .unwrap_or(0)
    };
    while pool.len() > 1 && (pool.len() > POOL_BRACKETS || most_sets(pool) > POOL_SETS) {
        pool.remove(0);
    }
}

/// The cache folder of a state folder.
#[derive(Debug, Clone)]
pub struct ResponseCache {
    dir: PathBuf,
}

/// Readable form of a camera: lower-case letters and digits, other runs become `-`
/// (`Canon EOS R5 #042` → `canon-eos-r5-042`). Two bodies may share one (`Cam "A"/../x`
/// and `cam-a-x`): the cache file is named by [`key`].
pub fn slug(camera: &CameraId) -> String {
    let mut s = String::new();
    for c in camera.to_string().chars() {
        if c.is_ascii_alphanumeric() {
            s.push(c.to_ascii_lowercase());
        } else if !s.ends_with('-') {
            s.push('-');
        }
    }
    s.trim_matches('-').to_string()
}

/// Longest readable part of a cache key, in bytes: an EXIF model may be any length, a
/// file name may not.
pub const KEY_SLUG_BYTES: usize = 64;

/// Hex digits of the identity digest in a cache key (32 bits: bodies of one studio never
/// meet; the file's own `camera` table is compared on reading all the same).
pub const KEY_DIGEST_DIGITS: usize = 8;

/// A body's cache key, the stem of its file: its [`slug`] (at most [`KEY_SLUG_BYTES`])
/// and the first [`KEY_DIGEST_DIGITS`] hex digits of [`atomic::name_digest`] of its exact
/// identity (make, model and serial as EXIF gave them, absent fields told from empty
/// ones): `canon-eos-r5-042-1a2b3c4d`. Bodies whose names reduce to one slug get
/// different keys.
pub fn key(camera: &CameraId) -> String {
    let slug = slug(camera);
    let mut end = slug.len().min(KEY_SLUG_BYTES);
    while !slug.is_char_boundary(end) {
        end -= 1;
    }
    let digest = atomic::name_digest(identity(camera).as_bytes());
    format!("{}-{}", &slug[..end], &digest[..KEY_DIGEST_DIGITS])
}

/// The exact identity of a body as [`key`] digests it: its fields as JSON (`null` for an
/// absent one), so no two bodies give the same text.
fn identity(camera: &CameraId) -> String {
    serde_json::json!([camera.make, camera.model, camera.serial]).to_string()
}

impl ResponseCache {
    /// The cache under `state/responses/` (created on first write).
    pub fn new(state: &Path) -> ResponseCache {
        ResponseCache {
            dir: state.join("responses"),
        }
    }

    /// The folder holding the entries.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Where a body's entry is written: `<key>.toml` ([`key`]).
    pub fn path_for(&self, camera: &CameraId) -> PathBuf {
        self.dir.join(format!("{}.toml", key(camera)))
    }

    /// Where earlier versions wrote a body's entry, `<slug>.toml`: read when the body has
    /// no entry under its key and this one holds exactly this body, removed once the
    /// entry is written under its key.
    fn legacy_path_for(&self, camera: &CameraId) -> PathBuf {
        self.dir.join(format!("{}.toml", slug(camera)))
    }

    /// The file holding the body's entry: under its key, else its earlier name when that
    /// holds this body; `None` when neither does.
    pub fn file_of(&self, camera: &CameraId) -> Option<PathBuf> {
        let path = self.path_for(camera);
        if path.is_file() {
            return Some(path);
        }
        let legacy = self.legacy_path_for(camera);
        matches!(self.read(&legacy), Ok(Some(e)) if e.camera == *camera).then_some(legacy)
    }

    /// The entry in the file at `path`, `None` if there is none.
    fn read(&self, path: &Path) -> Result<Option<CachedResponse>, CacheError> {
        match fs::read_to_string(path) {
            Ok(text) => parse(path, &text).map(Some),
            Err(e) if e.kind() == io::ErrorKind::NotFound => Ok(None),
            Err(source) => Err(CacheError::Io {
                path: path.to_path_buf(),
                source,
            }),
        }
    }

    /// The body's cached curve, `None` if there is none: the entry under its key, else
    /// the one under its earlier name if it holds exactly this body (another body whose
    /// name reduced to the same slug is not this one).
    pub fn get(&self, camera: &CameraId) -> Result<Option<CachedResponse>, CacheError> {
        let path = self.path_for(camera);
        if let Some(entry) = self.read(&path)? {
            if entry.camera != *camera {
                return Err(CacheError::Invalid {
                    path,
                    reason: format!("holds the curve of {}, not of {camera}", entry.camera),
                });
            }
            return Ok(Some(entry));
        }
        let legacy = self.legacy_path_for(camera);
        Ok(self.read(&legacy)?.filter(|e| e.camera == *camera))
    }

    /// Adds a good bracket to the body's pool (see the module docs), with `curve` and
    /// its channels' `confidence` as the body's curve (the lab's refit of the pool
    /// with this bracket, or the bracket's own fit when it starts the pool), clears the
    /// dissents and publishes the entry. An entry of another channel count is replaced.
    pub fn pool(
        &self,
        camera: &CameraId,
        bracket: PooledBracket,
        curve: &InverseResponse,
        confidence: Vec<f64>,
        now: u64,
    ) -> Result<CachedResponse, CacheError> {
        let old = self
            .get(camera)?
            .filter(|o| o.response.channels() == curve.channels());
        let (mut entry, measured) = match old {
            Some(o) => {
                let measured = o.measured.clone();
                (o, measured)
            }
            None => (self.empty(camera, curve), None),
        };
        entry.pool.push(rounded(bracket));
        trim(&mut entry.pool);
        entry.dissent.clear();
        entry.response = curve.clone();
        entry.confidence = confidence;
        entry.brackets += 1;
        entry.updated = now;
        entry.measured = measured;
        self.put(&entry)?;
        Ok(entry)
    }

    /// Keeps a good bracket that contradicted the body's curve aside (see the module
    /// docs); the [`DISSENTS_TO_REPLACE`]-th in a row that one joint fit explains with
    /// the others replaces the pool. Publishes the entry.
    pub fn dissent(
        &self,
        camera: &CameraId,
        bracket: PooledBracket,
        now: u64,
    ) -> Result<(CachedResponse, Dissent), CacheError> {
        let channels = bracket.evidence.channels.len();
        let Some(mut entry) = self
            .get(camera)?
            .filter(|o| o.response.channels() == channels)
        else {
            return Err(CacheError::Invalid {
                path: self.path_for(camera),
                reason: "no entry of this channel count to dissent from".into(),
            });
        };
        entry.dissent.push(rounded(bracket));
        while entry.dissent.len() > DISSENTS_TO_REPLACE {
            entry.dissent.remove(0);
        }
        entry.updated = now;
        let mut outcome = Dissent::Kept(entry.dissent.len());
        if entry.dissent.len() == DISSENTS_TO_REPLACE {
            let evidence: Vec<&Evidence> = entry.dissent.iter().map(|b| &b.evidence).collect();
            if let Ok(refit) = pool::refit(&evidence, Degree::Auto)
                && entry.dissent.iter().all(|b| {
                    pool::agreement(&b.evidence, &refit.response)
                        <= b.own_misfit + CONTRADICTION_STOPS
                })
            {
                entry.pool = std::mem::take(&mut entry.dissent);
                entry.response = refit.response;
                entry.confidence = refit.channels.iter().map(|c| c.fit.confidence).collect();
                entry.brackets += DISSENTS_TO_REPLACE as u64;
                outcome = Dissent::Replaced;
            }
        }
        self.put(&entry)?;
        Ok((entry, outcome))
    }

    /// A new entry holding `curve` and nothing else.
    fn empty(&self, camera: &CameraId, curve: &InverseResponse) -> CachedResponse {
        CachedResponse {
            camera: camera.clone(),
            response: curve.clone(),
            confidence: Vec::new(),
            brackets: 0,
            updated: 0,
            pool: Vec::new(),
            dissent: Vec::new(),
            measured: None,
        }
    }

    /// Stores `measured` as the body's measured curve (replacing an earlier one) and
    /// publishes the entry; a body without an entry gets one (see the module docs).
    pub fn put_measured(
        &self,
        camera: &CameraId,
        measured: &crate::response::MeasuredResponse,
        now: u64,
    ) -> Result<CachedResponse, CacheError> {
        let curve = MeasuredCurve {
            response: measured.response.clone(),
            coverage: measured.coverage.clone(),
            captures: measured.captures,
            updated: now,
        };
        let entry = match self.get(camera)? {
            Some(old) => CachedResponse {
                measured: Some(curve),
                ..old
            },
            None => CachedResponse {
                updated: now,
                measured: Some(curve),
                ..self.empty(camera, &measured.response)
            },
        };
        self.put(&entry)?;
        Ok(entry)
    }

    /// Writes an entry as is.
    pub fn put(&self, entry: &CachedResponse) -> Result<(), CacheError> {
        fs::create_dir_all(&self.dir).map_err(|source| CacheError::Io {
            path: self.dir.clone(),
            source,
        })?;
        let file = CacheFile {
            version: VERSION,
            camera: entry.camera.clone(),
            weight: None,
            brackets: entry.brackets,
            updated: entry.updated,
            source: Some(RECOVERED_SOURCE.to_string()),
            confidence: entry.confidence.clone(),
            pool: entry.pool.iter().map(bracket_file).collect(),
            dissent: entry.dissent.iter().map(bracket_file).collect(),
            channels: (0..entry.response.channels())
                .map(|c| entry.response.samples(c).to_vec())
                .collect(),
            measured: entry.measured.as_ref().map(|m| MeasuredFile {
                source: MEASURED_SOURCE.to_string(),
                captures: m.captures,
                updated: m.updated,
                coverage: m.coverage.clone(),
                channels: (0..m.response.channels())
                    .map(|c| m.response.samples(c).to_vec())
                    .collect(),
            }),
        };
        let text = toml::to_string(&file).map_err(|source| CacheError::Serialise {
            path: self.path_for(&entry.camera),
            source,
        })?;
        let text = format!(
            "# filmback response cache: inverse response g(B) of {}, sampled at B = i/(n-1).\n{text}",
            comment_safe(&entry.camera.to_string())
        );
        atomic::publish(
            &self.path_for(&entry.camera),
            text.as_bytes(),
            Overwrite::Replace,
        )?;
        // The entry under its earlier name is now superseded.
        let legacy = self.legacy_path_for(&entry.camera);
        if matches!(self.read(&legacy), Ok(Some(e)) if e.camera == entry.camera) {
            let _ = fs::remove_file(&legacy);
        }
        Ok(())
    }

    /// Every entry, by camera name; unreadable entries are returned as errors in place.
    pub fn list(&self) -> Result<Vec<Result<CachedResponse, CacheError>>, CacheError> {
        let dir = match fs::read_dir(&self.dir) {
            Ok(d) => d,
            Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(Vec::new()),
            Err(source) => {
                return Err(CacheError::Io {
                    path: self.dir.clone(),
                    source,
                });
            }
        };
        let mut paths: Vec<PathBuf> = dir
            .filter_map(Result::ok)
            .map(|e| e.path())
            .filter(|p| p.extension().is_some_and(|e| e == "toml") && !atomic::is_temporary(p))
            .collect();
        paths.sort();
        Ok(paths
            .into_iter()
            .map(|path| {
                let text = fs::read_to_string(&path).map_err(|source| CacheError::Io {
                    path: path.clone(),
                    source,
                })?;
                parse(&path, &text)
            })
            .collect())
    }

    /// The one entry whose camera name or file name contains `query` (case-insensitive);
    /// an exact match wins over partial ones.
    pub fn find(&self, query: &str) -> Result<CachedResponse, CacheError> {
        let q = query.to_lowercase();
        let all: Vec<CachedResponse> = self.list()?.into_iter().filter_map(Result::ok).collect();
        let names = |e: &CachedResponse| (e.camera.to_string().to_lowercase(), slug(&e.camera));
        if let Some(e) = all.iter().find(|e| {
            let (n, s) = names(e);
            n == q || s == q
        }) {
            return Ok(e.clone());
        }
        let hits: Vec<&CachedResponse> = all
            .iter()
            .filter(|e| {
                let (n, s) = names(e);
                n.contains(&q) || s.contains(&q)
            })
            .collect();
        match hits.as_slice() {
            [] => Err(CacheError::NotFound {
                query: query.to_string(),
            }),
            [one] => Ok((*one).clone()),
            many => Err(CacheError::Ambiguous {
                query: query.to_string(),
                matches: many
                    .iter()
                    .map(|e| e.camera.to_string())
                    .collect::<Vec<_>>()
                    .join(", "),
            }),
        }
    }

    /// Deletes the entry of `query` (see [`ResponseCache::find`]); returns its camera.
    pub fn reset(&self, query: &str) -> Result<CameraId, CacheError> {
        let entry = self.find(query)?;
        while let Some(path) = self.file_of(&entry.camera) {
            fs::remove_file(&path).map_err(|source| CacheError::Io { path, source })?;
        }
        Ok(entry.camera)
    }
}

/// `text` fit for one TOML comment line: control characters (a newline in an EXIF model)
/// written as Rust escapes (`\n`), everything else as it is.
fn comment_safe(text: &str) -> String {
    text.chars()
        .map(|c| {
            if c.is_control() {
                c.escape_default().to_string()
            } else {
                c.to_string()
            }
        })
        .collect()
}

fn parse(path: &Path, text: &str) -> Result<CachedResponse, CacheError> {
    let invalid = |reason: String| CacheError::Invalid {
        path: path.to_path_buf(),
        reason,
    };
    let file: CacheFile = toml::from_str(text).map_err(|source| CacheError::Syntax {
        path: path.to_path_buf(),
        source,
    })?;
    if !(file.version == 1 || file.version == VERSION) {
        return Err(invalid(format!(
            "version {} (this filmback reads versions 1 and {VERSION}); reset it",
            file.version
        )));
    }
    if file.version == 1 && !file.weight.is_some_and(|w| w.is_finite() && w > 0.0) {
        return Err(invalid(format!("weight {:?} is not positive", file.weight)));
    }
    let response =
        InverseResponse::from_samples(file.channels).map_err(|source| CacheError::Curve {
            path: path.to_path_buf(),
            source,
        })?;
    let channels = response.channels();
    if !(file.confidence.is_empty() || file.confidence.len() == channels)
        || file.confidence.iter().any(|c| !(0.0..=1.0).contains(c))
    {
        return Err(invalid(format!(
            "confidence {:?} does not fit {channels} channel(s)",
            file.confidence
        )));
    }
    let brackets = |list: Vec<BracketFile>| -> Result<Vec<PooledBracket>, CacheError> {
        list.into_iter()
            .map(|b| pooled_bracket(b, channels, path))
            .collect()
    };
    let pool = brackets(file.pool)?;
    let dissent = brackets(file.dissent)?;
    let measured = match file.measured {
        Some(m) => Some(MeasuredCurve {
            response: InverseResponse::from_samples(m.channels).map_err(|source| {
                CacheError::MeasuredCurve {
                    path: path.to_path_buf(),
                    source,
                }
            })?,
            coverage: m.coverage,
            captures: m.captures,
            updated: m.updated,
        }),
        None => None,
    };
    Ok(CachedResponse {
        camera: file.camera,
        response,
        confidence: file.confidence,
        brackets: file.brackets,
        updated: file.updated,
        pool,
        dissent,
        measured,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn body(serial: Option<&str>) -> CameraId {
        CameraId {
            make: Some("Canon".into()),
            model: Some("Canon EOS R5".into()),
            serial: serial.map(str::to_string),
        }
    }

    fn power(p: f64) -> InverseResponse {
        let g: Vec<f64> = (0..33).map(|i| (f64::from(i) / 32.0).powf(p)).collect();
        InverseResponse::from_samples(vec![g.clone(), g.clone(), g]).unwrap()
    }

    /// The evidence a body of `g = b^p` gives in a pair at ratio 4: tone pairs
    /// `τ = 4^(1/p)·b` over the tones both frames hold.
    fn evidence(p: f64, sets: usize) -> Evidence {
        let step = 4f64.powf(1.0 / p);
        let set = PairSet {
            log_ratio: 4f64.ln(),
            pairs: (0..200)
                .map(|i| {
                    let dark = 0.02 + (0.97 / step - 0.02) * f64::from(i) / 199.0;
                    TonePair {
                        dark,
                        bright: dark * step,
                        sigma_dark: 0.002,
                        sigma_bright: 0.002,
                        quantile: f64::from(i) / 200.0,
                    }
                })
                .collect(),
        };
        Evidence {
            frames: sets + 1,
            channels: vec![vec![set; sets]; 3],
        }
    }

    fn bracket(name: &str, p: f64, sets: usize) -> PooledBracket {
        PooledBracket {
            name: name.to_string(),
            at: 1,
            own_confidence: 0.9,
            own_misfit: 0.0,
            evidence: evidence(p, sets),
        }
    }

    /// Good brackets join the pool, the newest last; past the bounds the oldest leave,
    /// and the entry reads back as written (tones at six significant digits).
    #[test]
    fn good_brackets_pool_and_the_oldest_leave() {
        let dir = tempfile::tempdir().unwrap();
        let cache = ResponseCache::new(dir.path());
        let cam = body(Some("042"));
        assert_eq!(cache.get(&cam).unwrap(), None);
        let first = cache
            .pool(&cam, bracket("b0", 2.2, 1), &power(2.2), vec![0.8; 3], 10)
            .unwrap();
        assert_eq!((first.brackets, first.pool.len()), (1, 1));
        assert_eq!(first.min_confidence(), Some(0.8));
        let back = cache.get(&cam).unwrap().unwrap();
        assert_eq!(back.response, first.response);
        let (a, b) = (&back.pool[0].evidence, &first.pool[0].evidence);
        assert_eq!(a.channels[2][0].pairs.len(), b.channels[2][0].pairs.len());
        let d = a.channels[2][0].pairs[7].dark / b.channels[2][0].pairs[7].dark;
        assert!((d - 1.0).abs() < 1e-5, "{d}");
        for k in 1..20 {
            cache
                .pool(
                    &cam,
                    bracket(&format!("b{k}"), 2.2, 1),
                    &power(2.2),
                    vec![0.8; 3],
                    10,
                )
                .unwrap();
        }
        let e = cache.get(&cam).unwrap().unwrap();
        assert_eq!((e.brackets, e.pool.len()), (20, POOL_BRACKETS));
        assert_eq!(e.pool[0].name, "b4");
        // Nine-frame brackets: eight frame pairs each, at most POOL_SETS per channel.
        let e = cache
            .pool(&cam, bracket("wide", 2.2, 8), &power(2.2), vec![0.8; 3], 11)
            .unwrap();
        let sets: usize = e.pool.iter().map(|b| b.evidence.channels[0].len()).sum();
        assert!(sets <= POOL_SETS, "{sets}");
        assert_eq!(e.pool.last().unwrap().name, "wide");
    }

    fn model(name: &str) -> CameraId {
        CameraId {
            make: None,
            model: Some(name.to_string()),
            serial: None,
        }
    }

    /// A model with a newline, quotes and a backslash (EXIF says what it likes) is written
    /// so that the entry reads back, comment line included.
    #[test]
    fn a_newline_in_the_model_round_trips() {
        let dir = tempfile::tempdir().unwrap();
        let cache = ResponseCache::new(dir.path());
        let cam = model("EOS\nR5 \"x\" \\ y");
        cache
            .pool(&cam, bracket("b0", 2.2, 1), &power(2.2), vec![0.8; 3], 10)
            .unwrap();
        let back = cache.get(&cam).unwrap().expect("the entry reads back");
        assert_eq!(back.camera, cam);
        let listed = cache.list().unwrap();
        assert_eq!(listed.len(), 1);
        assert_eq!(listed[0].as_ref().unwrap().camera, cam);
    }

    /// Two bodies whose names reduce to one slug keep two files and two pools: the
    /// second's first bracket is not merged with the first's curve.
    #[test]
    fn bodies_of_one_slug_keep_their_own_entries() {
        let dir = tempfile::tempdir().unwrap();
        let cache = ResponseCache::new(dir.path());
        let (a, b) = (model("Cam \"A\"/../x"), model("cam-a-x"));
        assert_eq!(slug(&a), slug(&b));
        cache
            .pool(&a, bracket("a0", 2.2, 1), &power(2.2), vec![0.8; 3], 10)
            .unwrap();
        assert_eq!(cache.get(&b).unwrap(), None, "b has no curve yet");
        cache
            .pool(&b, bracket("b0", 1.4, 1), &power(1.4), vec![0.8; 3], 11)
            .unwrap();
        let (ea, eb) = (
            cache.get(&a).unwrap().unwrap(),
            cache.get(&b).unwrap().unwrap(),
        );
        assert_eq!(
            (ea.camera, ea.response, ea.pool.len()),
            (a.clone(), power(2.2), 1)
        );
        assert_eq!(
            (eb.camera, eb.response, eb.pool.len()),
            (b.clone(), power(1.4), 1)
        );
        assert_ne!(cache.path_for(&a), cache.path_for(&b));
        assert_eq!(cache.list().unwrap().len(), 2);
    }

    /// An entry written under the earlier name (the bare slug) is found, rewritten under
    /// the body's key at its next update, and reset; another body's entry under that
    /// name is not taken for this body's.
    #[test]
    fn entries_under_the_earlier_name_are_found_and_moved() {
        let dir = tempfile::tempdir().unwrap();
        let cache = ResponseCache::new(dir.path());
        let cam = body(Some("7"));
        cache
            .pool(&cam, bracket("b0", 2.2, 1), &power(2.2), vec![0.8; 3], 10)
            .unwrap();
        let legacy = cache.dir().join(format!("{}.toml", slug(&cam)));
        fs::rename(cache.path_for(&cam), &legacy).unwrap();
        assert_eq!(cache.get(&cam).unwrap().unwrap().brackets, 1);
        assert_eq!(cache.file_of(&cam), Some(legacy.clone()));
        let other = CameraId {
            serial: Some("8".into()),
            ..cam.clone()
        };
        let other_legacy = cache.dir().join(format!("{}.toml", slug(&other)));
        fs::copy(&legacy, &other_legacy).unwrap();
        assert_eq!(cache.get(&other).unwrap(), None, "holds body #7, not #8");
        fs::remove_file(&other_legacy).unwrap();
        cache
            .pool(&cam, bracket("b1", 2.2, 1), &power(2.2), vec![0.8; 3], 11)
            .unwrap();
        assert!(!legacy.exists() && cache.path_for(&cam).is_file());
        assert_eq!(cache.get(&cam).unwrap().unwrap().brackets, 2);
        fs::rename(cache.path_for(&cam), &legacy).unwrap();
        assert_eq!(cache.reset("eos-r5-7").unwrap(), cam);
        assert!(!legacy.exists());
        assert_eq!(cache.list().unwrap().len(), 0);
    }

    /// Three dissents in a row that agree with one another replace the pool; a bracket
    /// that agrees with the pool in between clears them.
    #[test]
    fn dissents_in_a_row_replace_the_pool() {
        let dir = tempfile::tempdir().unwrap();
        let cache = ResponseCache::new(dir.path());
        let cam = body(Some("9"));
        cache
            .pool(&cam, bracket("old", 2.2, 1), &power(2.2), vec![0.8; 3], 1)
            .unwrap();
        for k in 0..2 {
            let (e, d) = cache
                .dissent(&cam, bracket(&format!("d{k}"), 1.4, 1), 2)
                .unwrap();
            assert_eq!(d, Dissent::Kept(k + 1));
            assert_eq!(e.response, power(2.2));
        }
        let e = cache
            .pool(
                &cam,
                bracket("agrees", 2.2, 1),
                &power(2.2),
                vec![0.8; 3],
                3,
            )
            .unwrap();
        assert!(e.dissent.is_empty());
        for k in 0..2 {
            cache
                .dissent(&cam, bracket(&format!("n{k}"), 1.4, 1), 4)
                .unwrap();
        }
        let (e, d) = cache.dissent(&cam, bracket("n2", 1.4, 1), 5).unwrap();
        assert_eq!(d, Dissent::Replaced);
        assert_eq!(e.pool.len(), DISSENTS_TO_REPLACE);
        assert!(e.dissent.is_empty());
        let g = e.response.eval(1, 0.5);
        assert!((g.log2() - 0.5f64.powf(1.4).log2()).abs() < 0.05, "{g}");
        assert_eq!(cache.get(&cam).unwrap().unwrap(), e);
    }

    /// Three dissents that do not agree with one another (two processings) do not replace
    /// the pool.
    #[test]
    fn dissents_that_disagree_keep_the_pool() {
        let dir = tempfile::tempdir().unwrap();
        let cache = ResponseCache::new(dir.path());
        let cam = body(None);
        cache
            .pool(&cam, bracket("old", 2.2, 1), &power(2.2), vec![0.8; 3], 1)
            .unwrap();
        for (k, p) in [1.4, 3.2, 1.4].into_iter().enumerate() {
            let (e, d) = cache
                .dissent(&cam, bracket(&format!("d{k}"), p, 1), 2)
                .unwrap();
            assert_eq!(d, Dissent::Kept(k + 1));
            assert_eq!(e.pool[0].name, "old");
        }
    }

    /// An entry of version 1 (a running mean) reads as a curve without evidence.
    #[test]
    fn version_one_entries_read_as_a_curve_without_evidence() {
        let dir = tempfile::tempdir().unwrap();
        let cache = ResponseCache::new(dir.path());
        let cam = body(Some("1"));
        std::fs::create_dir_all(cache.dir()).unwrap();
        std::fs::write(
            cache.path_for(&cam),
            "version = 1\nweight = 2.5\nbrackets = 3\nupdated = 5\n\
             channels = [[0.0, 0.25, 1.0], [0.0, 0.25, 1.0], [0.0, 0.25, 1.0]]\n\
             [camera]\nmake = \"Canon\"\nmodel = \"Canon EOS R5\"\nserial = \"1\"\n",
        )
        .unwrap();
        let e = cache.get(&cam).unwrap().unwrap();
        assert_eq!((e.brackets, e.pool.len()), (3, 0));
        assert_eq!(e.min_confidence(), None);
        assert!((e.response.eval(0, 0.5) - 0.25).abs() < 1e-12);
    }

    #[test]
    fn list_find_reset() {
        let dir = tempfile::tempdir().unwrap();
        let cache = ResponseCache::new(dir.path());
        let one = |serial: &str, p: f64| {
            cache
                .pool(
                    &body(Some(serial)),
                    bracket("b", p, 1),
                    &power(p),
                    vec![1.0; 3],
                    1,
                )
                .unwrap()
        };
        one("1", 2.0);
        one("2", 2.2);
        assert_eq!(cache.list().unwrap().len(), 2);
        assert!(matches!(
            cache.find("eos r5"),
            Err(CacheError::Ambiguous { .. })
        ));
        assert_eq!(
            cache.find("Canon EOS R5 #2").unwrap().camera,
            body(Some("2"))
        );
        assert_eq!(
            cache.find("canon-eos-r5-1").unwrap().camera,
            body(Some("1"))
        );
        assert!(matches!(
            cache.find("nikon"),
            Err(CacheError::NotFound { .. })
        ));
        assert_eq!(cache.reset("#1").unwrap(), body(Some("1")));
        assert_eq!(cache.list().unwrap().len(), 1);
    }

    fn measurement(p: f64) -> crate::response::MeasuredResponse {
        let g: Vec<f64> = (0..256).map(|i| (f64::from(i) / 255.0).powf(p)).collect();
        crate::response::MeasuredResponse {
            response: InverseResponse::from_samples(vec![g.clone(), g.clone(), g]).unwrap(),
            coverage: vec![0.9, 0.95, 0.8],
            codes: vec![(3, 250); 3],
            samples: 1000,
            captures: 2,
        }
    }

    /// A measured curve is stored beside the recovered one, survives later fits, and
    /// a body measured before any fit gets a placeholder that the first fit replaces.
    #[test]
    fn measured_curves_are_kept_beside_the_recovered_one() {
        let dir = tempfile::tempdir().unwrap();
        let cache = ResponseCache::new(dir.path());
        let cam = body(Some("7"));
        let first = cache.put_measured(&cam, &measurement(2.2), 5).unwrap();
        assert_eq!(first.brackets, 0);
        let m = first.measured.clone().unwrap();
        assert_eq!((m.captures, m.updated), (2, 5));
        assert_eq!(cache.get(&cam).unwrap().unwrap(), first);
        let text = fs::read_to_string(cache.path_for(&cam)).unwrap();
        assert!(text.contains(MEASURED_SOURCE) && text.contains(RECOVERED_SOURCE));
        // The first fit replaces the placeholder, the measured curve stays.
        let fitted = cache
            .pool(&cam, bracket("b", 1.0, 1), &power(1.0), vec![1.0; 3], 6)
            .unwrap();
        assert!((fitted.response.eval(0, 0.5) - 0.5).abs() < 1e-6);
        assert_eq!(fitted.measured, first.measured);
        assert_eq!(fitted.brackets, 1);
        // A new measurement replaces the old one, not the recovered curve.
        let again = cache.put_measured(&cam, &measurement(2.0), 7).unwrap();
        assert_eq!(again.response, fitted.response);
        assert!((again.measured.unwrap().response.eval(1, 0.5) - 0.25).abs() < 1e-3);
    }

    #[test]
    fn foreign_or_damaged_entries_are_errors_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let cache = ResponseCache::new(dir.path());
        let cam = body(None);
        cache
            .pool(&cam, bracket("b", 2.0, 1), &power(2.0), vec![1.0; 3], 1)
            .unwrap();
        let path = cache.path_for(&cam);
        let text = fs::read_to_string(&path).unwrap();
        fs::write(&path, text.replace("version = 2", "version = 7")).unwrap();
        let name = path.display().to_string();
        let err = cache.get(&cam).unwrap_err().to_string();
        assert!(err.contains(&name) && err.contains("version 7"), "{err}");
        let damaged = text.replacen("log_ratio = 1.3", "log_ratio = -1.3", 1);
        assert_ne!(damaged, text);
        fs::write(&path, damaged).unwrap();
        let err = cache.get(&cam).unwrap_err().to_string();
        assert!(err.contains(&name) && err.contains("not usable"), "{err}");
        fs::write(&path, "version = 1\n").unwrap();
        assert!(cache.get(&cam).is_err());
    }
}
