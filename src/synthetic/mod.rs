//! Synthetic ground truth: a procedural HDR scene, exposed through a known camera response
//! with noise and quantisation, written as JPEG, PNG or TIFF with EXIF exposure tags.
//!
//! Every stage downstream (histograms, response recovery, merge, film rendering, the
//! daemon) can be tested end to end against numbers known exactly: the scene radiance
//! ([`scene`]), the response `f` and its inverse `g` ([`ResponseCurve`]), the exposures
//! ([`Shot`]) and the sensor noise ([`Sensor`]).
//!
//! ```
//! use filmback::frame::BitDepth;
//! use filmback::synthetic::{expose, scene, ResponseCurve, Sensor};
//!
//! let radiance = scene(64, 48, 7);
//! let sensor = Sensor::noiseless(ResponseCurve::Srgb, BitDepth::Eight);
//! let frame = expose(&radiance, 1.0, &sensor);
//! assert_eq!((frame.width(), frame.height(), frame.channels()), (64, 48, 3));
//! ```

mod curve;
mod scene;
mod sensor;

use std::path::PathBuf;

use crate::metadata::{Camera, CaptureTime, Exposure};

pub use curve::{ResponseCurve, dorf_curves};
pub use scene::{MID_GREY, scene};
pub use sensor::{Sensor, bracket, expose};

/// How one synthetic frame was taken: what goes into its EXIF.
#[derive(Debug, Clone, PartialEq)]
pub struct Shot {
    /// The camera body (make, model, serial; the lens is not written).
    pub camera: Camera,
    /// Exposure time, f-number and ISO; all three are needed to expose and to encode.
    pub exposure: Exposure,
    /// Capture time (with sub-seconds and UTC offset when set).
    pub captured_at: CaptureTime,
}

/// Why synthetic material could not be made or written.
#[derive(Debug, thiserror::Error)]
pub enum SyntheticError {
    /// A file could not be read.
    #[error("{path}: cannot read: {source}")]
    Read {
        /// The file.
        path: PathBuf,
        /// What the operating system said.
        source: std::io::Error,
    },
    /// A curve file has a malformed line (line 0: the file as a whole).
    #[error("{path}:{line}: {reason}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        reason: String,
    },
    /// A response curve breaks its invariants.
    #[error("invalid response curve: {0}")]
    Curve(String),
    /// A shot lacks exposure time, f-number or ISO, so its exposure is unknown.
    #[error("shot {shot}: exposure time, f-number and ISO are all needed")]
    UnknownExposure {
        /// Index of the shot in the bracket.
        shot: usize,
    },
}
