//! The response cache: one inverse response per camera body, in the state folder under
//! `responses/<camera>.toml` (versioned TOML, written atomically).
//!
//! A bracket whose own fit is weak (γ near 1, little overlap, low confidence), or whose
//! preset says `recalibrate = "never"`, is merged with its body's cached curve. Good fits
//! refine the cache by a confidence-weighted running mean, sample by sample:
//!
//! `g_new(B) = (W·g_old(B) + c·g_fit(B)) / (W + c)`, then `W ← min(W + c, MEMORY)`,
//!
//! with `c ∈ (0, 1]` the fit's confidence and `W` the accumulated weight (dimensionless).
//! A weighted mean of non-decreasing curves with `g(0)=0, g(1)=1` keeps both properties
//! (IEEE rounding is monotone, and `(W+c)/(W+c)` is exactly 1). Capping `W` at
//! [`MEMORY`] lets the curve follow a body whose processing changed (firmware, picture
//! style) instead of freezing after many brackets.
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
use crate::response::InverseResponse;

/// Version written into each cache file; files of another version are refused.
pub const VERSION: u32 = 1;

/// Largest accumulated weight `W` (about twenty good brackets' worth).
pub const MEMORY: f64 = 20.0;

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
    /// Accumulated weight `W` (see module docs).
    pub weight: f64,
    /// Brackets that contributed.
    pub brackets: u64,
    /// Last update, Unix seconds.
    pub updated: u64,
    /// The curve measured from RAW+JPEG captures, if any.
    pub measured: Option<MeasuredCurve>,
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

/// A weight small enough that the first fit replaces the placeholder curve of a body
/// only measured so far.
const PLACEHOLDER_WEIGHT: f64 = 1e-9;

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

/// The file layout.
#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct CacheFile {
    version: u32,
    camera: CameraId,
    weight: f64,
    brackets: u64,
    updated: u64,
    /// Where `channels` came from ([`RECOVERED_SOURCE`]); absent in older files.
    #[serde(default)]
    source: Option<String>,
    /// Per channel, `g(i/(n−1))`.
    channels: Vec<Vec<f64>>,
    /// The measured curve, if any.
    #[serde(default)]
    measured: Option<MeasuredFile>,
}

/// The cache folder of a state folder.
#[derive(Debug, Clone)]
pub struct ResponseCache {
    dir: PathBuf,
}

/// File-name form of a camera: lower-case letters and digits, other runs become `-`.
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

    /// Where a body's entry lives.
    pub fn path_for(&self, camera: &CameraId) -> PathBuf {
        self.dir.join(format!("{}.toml", slug(camera)))
    }

    /// The body's cached curve, `None` if there is none.
    pub fn get(&self, camera: &CameraId) -> Result<Option<CachedResponse>, CacheError> {
        let path = self.path_for(camera);
        match fs::read_to_string(&path) {
            Ok(text) => parse(&path, &text).map(Some),
            Err(e) if e.kind() == io::ErrorKind::NotFound => Ok(None),
            Err(source) => Err(CacheError::Io { path, source }),
        }
    }

    /// Folds a fit of confidence `c ∈ (0, 1]` into the body's entry (see module docs) and
    /// publishes it. A cached curve of another channel count is replaced.
    pub fn update(
        &self,
        camera: &CameraId,
        fit: &InverseResponse,
        confidence: f64,
        now: u64,
    ) -> Result<CachedResponse, CacheError> {
        let c = confidence.clamp(1e-6, 1.0);
        let old = self.get(camera)?;
        let measured = old.as_ref().and_then(|o| o.measured.clone());
        let entry = match old.filter(|o| o.response.channels() == fit.channels()) {
            Some(old) => {
                let w = old.weight;
                let channels = (0..fit.channels())
                    .map(|ch| {
                        let g = old.response.samples(ch);
                        let n = g.len();
                        g.iter()
                            .enumerate()
                            .map(|(i, &g_old)| {
                                let b = i as f64 / (n - 1) as f64;
                                (w * g_old + c * fit.eval(ch, b)) / (w + c)
                            })
                            .collect()
                    })
                    .collect();
                let response =
                    InverseResponse::from_samples(channels).map_err(|e| CacheError::Invalid {
                        path: self.path_for(camera),
                        reason: e.to_string(),
                    })?;
                CachedResponse {
                    camera: camera.clone(),
                    response,
                    weight: (w + c).min(MEMORY),
                    brackets: old.brackets + 1,
                    updated: now,
                    measured,
                }
            }
            None => CachedResponse {
                camera: camera.clone(),
                response: fit.clone(),
                weight: c,
                brackets: 1,
                updated: now,
                measured,
            },
        };
        self.put(&entry)?;
        Ok(entry)
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
                camera: camera.clone(),
                response: measured.response.clone(),
                weight: PLACEHOLDER_WEIGHT,
                brackets: 0,
                updated: now,
                measured: Some(curve),
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
            weight: entry.weight,
            brackets: entry.brackets,
            updated: entry.updated,
            source: Some(RECOVERED_SOURCE.to_string()),
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
        let text = toml::to_string(&file).map_err(|e| CacheError::Invalid {
            path: self.path_for(&entry.camera),
            reason: e.to_string(),
        })?;
        let text = format!(
            "# filmback response cache: inverse response g(B) of {}, sampled at B = i/(n-1).\n{text}",
            entry.camera
        );
        atomic::publish(
            &self.path_for(&entry.camera),
            text.as_bytes(),
            Overwrite::Replace,
        )?;
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
        let path = self.path_for(&entry.camera);
        fs::remove_file(&path).map_err(|source| CacheError::Io { path, source })?;
        Ok(entry.camera)
    }
}

fn parse(path: &Path, text: &str) -> Result<CachedResponse, CacheError> {
    let invalid = |reason: String| CacheError::Invalid {
        path: path.to_path_buf(),
        reason,
    };
    let file: CacheFile = toml::from_str(text).map_err(|e| invalid(e.to_string()))?;
    if file.version != VERSION {
        return Err(invalid(format!(
            "version {} (this filmback reads version {VERSION}); reset it",
            file.version
        )));
    }
    if !(file.weight.is_finite() && file.weight > 0.0) {
        return Err(invalid(format!("weight {} is not positive", file.weight)));
    }
    let response =
        InverseResponse::from_samples(file.channels).map_err(|e| invalid(e.to_string()))?;
    let measured = match file.measured {
        Some(m) => Some(MeasuredCurve {
            response: InverseResponse::from_samples(m.channels)
                .map_err(|e| invalid(format!("measured curve: {e}")))?,
            coverage: m.coverage,
            captures: m.captures,
            updated: m.updated,
        }),
        None => None,
    };
    Ok(CachedResponse {
        camera: file.camera,
        response,
        weight: file.weight,
        brackets: file.brackets,
        updated: file.updated,
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

    #[test]
    fn first_fit_is_stored_then_weighted_means_follow() {
        let dir = tempfile::tempdir().unwrap();
        let cache = ResponseCache::new(dir.path());
        let cam = body(Some("042"));
        assert_eq!(cache.get(&cam).unwrap(), None);
        let first = cache.update(&cam, &power(2.0), 0.5, 10).unwrap();
        assert_eq!(first.brackets, 1);
        assert_eq!(first.response, power(2.0));
        // W = 0.5; a fit of confidence 1.0 weighs twice as much:
        // g(0.5) = (0.5·0.25 + 1.0·0.5) / 1.5.
        let second = cache.update(&cam, &power(1.0), 1.0, 11).unwrap();
        let expect = (0.5 * 0.25 + 0.5) / 1.5;
        assert!((second.response.eval(1, 0.5) - expect).abs() < 1e-12);
        assert_eq!(second.brackets, 2);
        assert_eq!(second.weight, 1.5);
        // Persisted exactly (TOML floats round-trip).
        assert_eq!(cache.get(&cam).unwrap().unwrap(), second);
        assert_eq!(second.response.eval(0, 1.0), 1.0);
    }

    #[test]
    fn weight_is_capped_so_the_curve_keeps_following() {
        let dir = tempfile::tempdir().unwrap();
        let cache = ResponseCache::new(dir.path());
        let cam = body(None);
        for i in 0..30 {
            cache.update(&cam, &power(2.0), 1.0, i).unwrap();
        }
        let e = cache.update(&cam, &power(1.0), 1.0, 99).unwrap();
        assert_eq!(e.weight, MEMORY);
        let expect = (MEMORY * 0.25 + 0.5) / (MEMORY + 1.0);
        assert!((e.response.eval(0, 0.5) - expect).abs() < 1e-12);
    }

    #[test]
    fn list_find_reset() {
        let dir = tempfile::tempdir().unwrap();
        let cache = ResponseCache::new(dir.path());
        cache.update(&body(Some("1")), &power(2.0), 1.0, 1).unwrap();
        cache.update(&body(Some("2")), &power(2.2), 1.0, 1).unwrap();
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
        let fitted = cache.update(&cam, &power(1.0), 1.0, 6).unwrap();
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
        cache.update(&cam, &power(2.0), 1.0, 1).unwrap();
        let path = cache.path_for(&cam);
        let text = fs::read_to_string(&path).unwrap();
        fs::write(&path, text.replace("version = 1", "version = 7")).unwrap();
        let err = cache.get(&cam).unwrap_err().to_string();
        assert!(
            err.contains("canon-eos-r5.toml") && err.contains("version 7"),
            "{err}"
        );
        fs::write(&path, "version = 1\n").unwrap();
        assert!(cache.get(&cam).is_err());
    }
}
