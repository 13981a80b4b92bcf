//! The response file: a versioned TOML document that `calibrate -o` writes and `merge` and
//! the daemon read back.
//!
//! ```toml
//! format = "filmback-response"
//! version = 1
//! ratio = 4.0                 # γ used by the calibration (optional)
//! ratio_source = "exif"       # "exif" | "argument" | "estimated" (optional)
//!
//! [[channel]]
//! name = "R"
//! model = "monotone cubic spline of ln g over ln b (10 pieces, 5.2 effective parameters)"
//! degree = 3                  # optional: degree of the polynomial pieces
//! covered = [0.01, 0.98]      # optional: tone range the data covered
//! residual_rms = 0.004        # optional, stops
//! confidence = 0.97           # optional, 0..1
//! g = [0.0, …, 1.0]           # g(i/(n−1)), i = 0..n
//! ```
//!
//! Unknown keys are rejected, so a typo is an error rather than a silently ignored value.
//! Files are published atomically ([`crate::atomic`]).

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::{Calibration, InverseResponse, RatioSource, ResponseError};
use crate::atomic::{self, Overwrite};

/// The `format` value of a response file.
pub const FORMAT: &str = "filmback-response";
/// The current `version`.
pub const VERSION: u32 = 1;

/// Why a response file could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum ResponseFileError {
    /// Writing failed.
    #[error(transparent)]
    Publish(#[from] atomic::PublishError),
    /// Reading failed.
    #[error("{path}: cannot read: {source}")]
    Read {
        /// The file.
        path: PathBuf,
        /// What the operating system said.
        source: std::io::Error,
    },
    /// A wrong format or version.
    #[error("{path}: {reason}")]
    Invalid {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// Not valid TOML of the expected shape.
    #[error("{path}: {source}")]
    Syntax {
        /// The file.
        path: PathBuf,
        /// The parser's error, with line and column.
        #[source]
        source: toml::de::Error,
    },
    /// The file's curves are not a valid inverse response.
    #[error("{path}: {source}")]
    Curve {
        /// The file.
        path: PathBuf,
        /// What is wrong with them.
        #[source]
        source: ResponseError,
    },
    /// The record could not be written as TOML.
    #[error("{path}: cannot encode: {source}")]
    Encode {
        /// The file.
        path: PathBuf,
        /// The serialiser's error.
        #[source]
        source: toml::ser::Error,
    },
}

/// What the file says about one channel besides its curve.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChannelSummary {
    /// Channel name ("R", "G", "B" or "Y").
    pub name: String,
    /// How the curve was obtained.
    pub model: String,
    /// Degree of the fitted polynomial (pieces), when fitted.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub degree: Option<usize>,
    /// Tone range the data covered.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub covered: Option<[f64; 2]>,
    /// Equation residual, stops.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub residual_rms: Option<f64>,
    /// Confidence 0..1.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub confidence: Option<f64>,
}

/// A response with its provenance: the content of a response file.
#[derive(Debug, Clone, PartialEq)]
pub struct ResponseRecord {
    /// The curves.
    pub response: InverseResponse,
    /// Exposure ratio of the calibration, if any.
    pub ratio: Option<f64>,
    /// Where that ratio came from.
    pub ratio_source: Option<RatioSource>,
    /// One summary per channel of `response`.
    pub channels: Vec<ChannelSummary>,
}

impl ResponseRecord {
    /// A record for a response without calibration details (e.g. the sRGB default).
    #[cfg(test)]
    fn from_response(response: InverseResponse, model: &str) -> ResponseRecord {
        let names: &[&str] = if response.channels() == 1 {
            &["Y"]
        } else {
            &["R", "G", "B"]
        };
        let channels = names
            .iter()
            .map(|n| ChannelSummary {
                name: (*n).to_string(),
                model: model.to_string(),
                degree: None,
                covered: None,
                residual_rms: None,
                confidence: None,
            })
            .collect();
        ResponseRecord {
            response,
            ratio: None,
            ratio_source: None,
            channels,
        }
    }
}

impl Calibration {
    /// The calibration as a record for [`save`].
    pub fn record(&self) -> ResponseRecord {
        let channels = self
            .channels
            .iter()
            .map(|ch| ChannelSummary {
                name: ch.name.to_string(),
                model: match ch.borrowed_from {
                    None => ch.fit.model(),
                    Some(donor) => format!("borrowed from {donor} (no usable tones)"),
                },
                degree: Some(ch.fit.degree),
                covered: ch
                    .borrowed_from
                    .is_none()
                    .then_some([ch.fit.covered.0, ch.fit.covered.1]),
                residual_rms: Some(ch.fit.residual_rms),
                confidence: Some(ch.fit.confidence),
            })
            .collect();
        ResponseRecord {
            response: self.response.clone(),
            ratio: Some(self.ratio),
            ratio_source: Some(self.ratio_source),
            channels,
        }
    }
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Document {
    format: String,
    version: u32,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    ratio: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    ratio_source: Option<RatioSource>,
    channel: Vec<ChannelDocument>,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ChannelDocument {
    #[serde(flatten)]
    summary: ChannelSummary,
    g: Vec<f64>,
}

/// Writes `record` to `path` as TOML, atomically.
pub fn save(
    path: &Path,
    record: &ResponseRecord,
    overwrite: Overwrite,
) -> Result<(), ResponseFileError> {
    let channel = record
        .channels
        .iter()
        .enumerate()
        .map(|(c, summary)| ChannelDocument {
            summary: summary.clone(),
            g: record.response.samples(c).to_vec(),
        })
        .collect();
    let doc = Document {
        format: FORMAT.to_string(),
        version: VERSION,
        ratio: record.ratio,
        ratio_source: record.ratio_source,
        channel,
    };
    let text = toml::to_string(&doc).map_err(|source| ResponseFileError::Encode {
        path: path.to_path_buf(),
        source,
    })?;
    atomic::publish(path, text.as_bytes(), overwrite)?;
    Ok(())
}

/// Reads a response file written by [`save`], checking format, version and the curves.
pub fn load(path: &Path) -> Result<ResponseRecord, ResponseFileError> {
    let text = std::fs::read_to_string(path).map_err(|source| ResponseFileError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    let invalid = |reason: String| ResponseFileError::Invalid {
        path: path.to_path_buf(),
        reason,
    };
    let doc: Document = toml::from_str(&text).map_err(|source| ResponseFileError::Syntax {
        path: path.to_path_buf(),
        source,
    })?;
    if doc.format != FORMAT {
        return Err(invalid(format!(
            "format is {:?}, expected {FORMAT:?}",
            doc.format
        )));
    }
    if doc.version != VERSION {
        return Err(invalid(format!(
            "version {} is not supported (this filmback reads version {VERSION})",
            doc.version
        )));
    }
    let (channels, curves): (Vec<_>, Vec<_>) =
        doc.channel.into_iter().map(|c| (c.summary, c.g)).unzip();
    let response =
        InverseResponse::from_samples(curves).map_err(|source| ResponseFileError::Curve {
            path: path.to_path_buf(),
            source,
        })?;
    Ok(ResponseRecord {
        response,
        ratio: doc.ratio,
        ratio_source: doc.ratio_source,
        channels,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips_and_rejects_other_versions() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("response.toml");
        let mut record = ResponseRecord::from_response(InverseResponse::srgb(3, 64), "sRGB");
        record.ratio = Some(4.0);
        record.ratio_source = Some(RatioSource::Exif);
        save(&path, &record, Overwrite::Refuse).unwrap();
        assert_eq!(load(&path).unwrap(), record);
        let text = std::fs::read_to_string(&path)
            .unwrap()
            .replace("version = 1", "version = 9");
        std::fs::write(&path, text).unwrap();
        let err = load(&path).unwrap_err().to_string();
        assert!(
            err.contains("version 9") && err.contains("response.toml"),
            "{err}"
        );
    }
}
