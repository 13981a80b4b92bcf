//! Synthetic HDR scenes exposed through a known camera response with noise and
//! quantisation, written as JPEG, PNG or TIFF with EXIF exposure tags: the demo feed of
//! `filmback watch --demo` ([`demo`]) and the contact sheet's scene ([`scene()`]).
//!
//! With the feature `ground-truth` (turned on for the tests, benchmarks and examples by
//! the package's dev-dependency on itself, off in the product) it is also the ground truth
//! every stage downstream (histograms, response recovery, alignment, merge, film rendering,
//! the daemon) is tested against end to end: more scenes (a studio set, flat patches:
//! `SceneKind`; a real place's radiance map: `real_place`), known camera motion (`moved`),
//! synthetic DNGs, response curves from the DoRF database's file (`dorf_curves`) and the
//! error measures (`measure`). The numbers are known exactly: the scene radiance
//! ([`scene()`]), the response `f` and its inverse `g` ([`ResponseCurve`]), the exposures
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

pub mod demo;
#[cfg(feature = "ground-truth")]
pub mod measure;

mod curve;
#[cfg(feature = "ground-truth")]
mod dorf;
mod encode;
#[cfg(feature = "ground-truth")]
mod example;
#[cfg(feature = "ground-truth")]
mod kinds;
#[cfg(feature = "ground-truth")]
mod motion;
#[cfg(feature = "ground-truth")]
mod place;
#[cfg(all(feature = "raw", feature = "ground-truth"))]
mod raw;
mod scene;
mod sensor;

#[cfg(feature = "ground-truth")]
use std::path::PathBuf;

#[cfg(feature = "ground-truth")]
use crate::atomic::PublishError;
use crate::metadata::{Camera, CaptureTime, Exposure};

pub use curve::ResponseCurve;
#[cfg(feature = "ground-truth")]
pub use dorf::dorf_curves;
#[cfg(feature = "ground-truth")]
pub use encode::write;
pub use encode::{Encoding, encode};
#[cfg(feature = "ground-truth")]
pub use example::{EXAMPLE_SIZE, example_bracket, example_move};
#[cfg(feature = "ground-truth")]
pub use kinds::{SceneKind, UnknownScene, studio};
#[cfg(feature = "ground-truth")]
pub use motion::{camera_move, lens, moved, waves};
#[cfg(feature = "ground-truth")]
pub use place::real_place;
#[cfg(all(feature = "raw", feature = "ground-truth"))]
pub use raw::{RawSensor, dng, raw_codes, raw_signal};
pub use scene::scene;
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

impl Shot {
    /// A bracket on one body at one aperture and ISO: shot `k` has exposure time
    /// `times_s[k]` seconds and is captured `k · interval_s` seconds after `first`
    /// (sub-seconds are recorded whenever the result has them).
    pub fn series(
        camera: &Camera,
        first: CaptureTime,
        times_s: &[f64],
        f_number: f64,
        iso: f64,
        interval_s: f64,
    ) -> Vec<Shot> {
        times_s
            .iter()
            .enumerate()
            .map(|(k, &time_s)| Shot {
                camera: camera.clone(),
                exposure: Exposure {
                    time_s: Some(time_s),
                    f_number: Some(f_number),
                    iso: Some(iso),
                },
                captured_at: first.later_by(k as f64 * interval_s),
            })
            .collect()
    }
}

/// Why synthetic material could not be made or written.
#[derive(Debug, thiserror::Error)]
pub enum SyntheticError {
    /// A file could not be read.
    #[cfg(feature = "ground-truth")]
    #[error("{path}: cannot read: {source}")]
    Read {
        /// The file.
        path: PathBuf,
        /// What the operating system said.
        source: std::io::Error,
    },
    /// A curve file has a malformed line (line 0: the file as a whole).
    #[cfg(feature = "ground-truth")]
    #[error("{path}:{line}: {reason}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        reason: String,
    },
    /// A DNG could not be written.
    #[cfg(all(feature = "raw", feature = "ground-truth"))]
    #[error("cannot write DNG: {0}")]
    Dng(#[source] DngError),
    /// A response curve breaks its invariants.
    #[error("invalid response curve: {0}")]
    Curve(#[from] CurveError),
    /// A curve of a curve file breaks its invariants.
    #[cfg(feature = "ground-truth")]
    #[error("{path}:{line}: curve {index}: invalid response curve: {source}")]
    FileCurve {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// The curve's index in the file.
        index: u32,
        /// What is wrong with it.
        #[source]
        source: CurveError,
    },
    /// A shot lacks exposure time, f-number or ISO, so its exposure is unknown.
    #[error("shot {shot}: exposure time, f-number and ISO are all needed")]
    UnknownExposure {
        /// Index of the shot in the bracket.
        shot: usize,
    },
    /// A frame or its EXIF could not be encoded.
    #[error("cannot encode {format}: {source}")]
    Encode {
        /// JPEG, PNG, TIFF or EXIF.
        format: &'static str,
        /// What went wrong.
        #[source]
        source: EncodeError,
    },
    /// The encoded file could not be published (the error names the path).
    #[cfg(feature = "ground-truth")]
    #[error(transparent)]
    Publish(#[from] PublishError),
    /// A real bracket could not be made into a scene ([`real_place`]).
    #[cfg(feature = "ground-truth")]
    #[error("cannot make a scene of the bracket: {0}")]
    Place(#[from] PlaceError),
}

/// Which invariant of a response curve is broken ([`SyntheticError::Curve`]).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CurveError {
    /// γ is not finite and positive.
    #[error("gamma {0} must be finite and positive")]
    Gamma(f64),
    /// Fewer than two samples.
    #[error("{0} samples, need at least 2")]
    TooFewSamples(usize),
    /// A sample is NaN or infinite.
    #[error("sample {0} is not finite")]
    NotFinite(usize),
    /// The first sample is not 0 or the last not 1.
    #[error("ends are {first} and {last}, must be 0 and 1")]
    Ends {
        /// The first sample.
        first: f64,
        /// The last sample.
        last: f64,
    },
    /// Samples `at` and `at + 1` do not increase.
    #[error("not strictly increasing between samples {at} and {}", at + 1)]
    NotIncreasing {
        /// Index of the first of the two samples.
        at: usize,
    },
}

/// Why a frame or its EXIF could not be encoded ([`SyntheticError::Encode`]).
#[derive(Debug, thiserror::Error)]
pub enum EncodeError {
    /// The image encoder failed.
    #[error(transparent)]
    Image(#[from] image::ImageError),
    /// The EXIF writer failed.
    #[error(transparent)]
    Exif(#[from] exif::Error),
    /// A JPEG quality outside 1..=100.
    #[error("quality {0} is outside 1..=100")]
    Quality(u8),
    /// A 16-bit frame asked for as JPEG.
    #[error("JPEG holds 8 bits per sample; write a 16-bit frame as PNG or TIFF")]
    SixteenBitJpeg,
    /// An ISO speed that is negative, not finite or beyond 32 bits.
    #[error("ISO {0} cannot be written")]
    Iso(f64),
    /// An exposure value that no unsigned 32-bit rational holds.
    #[error("{what} {value} cannot be written as an unsigned rational")]
    Rational {
        /// The EXIF field ("exposure time", "f-number").
        what: String,
        /// The value.
        value: f64,
    },
}

/// Why a DNG could not be written ([`SyntheticError::Dng`]).
#[cfg(all(feature = "raw", feature = "ground-truth"))]
#[derive(Debug, thiserror::Error)]
pub enum DngError {
    /// The mosaic does not have one code per pixel.
    #[error("{codes} codes for {width}×{height} pixels")]
    Size {
        /// Codes given.
        codes: usize,
        /// Width in pixels.
        width: usize,
        /// Height in pixels.
        height: usize,
    },
    /// The DNG writer failed.
    #[error(transparent)]
    Tiff(#[from] rawler::formats::tiff::TiffError),
}

/// Why a real bracket could not be made into a scene ([`SyntheticError::Place`]).
#[cfg(feature = "ground-truth")]
#[derive(Debug, thiserror::Error)]
pub enum PlaceError {
    /// The bracket is empty.
    #[error("no frames")]
    NoFrames,
    /// The frames are not RGB.
    #[error("{0} channels, not RGB")]
    NotRgb(usize),
    /// The bracket's response could not be calibrated.
    #[error(transparent)]
    Calibration(#[from] crate::response::CalibrationError),
    /// The bracket could not be merged.
    #[error(transparent)]
    Merge(#[from] crate::merge::MergeError),
    /// The merged map is smaller than one box of the reduction.
    #[error("{width}×{height} is smaller than one {k}×{k} box")]
    TooSmall {
        /// Width of the merged map.
        width: usize,
        /// Height of the merged map.
        height: usize,
        /// Side of the box.
        k: usize,
    },
    /// The reduced map's median luminance is zero, negative or not finite.
    #[error("its median luminance is {0}")]
    Median(f64),
    /// The reduced map could not be made.
    #[error(transparent)]
    Shape(#[from] crate::radiance::ShapeError),
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn series_advances_the_capture_time_across_midnight_and_new_year() {
        let first = CaptureTime {
            year: 2025,
            month: 12,
            day: 31,
            hour: 23,
            minute: 59,
            second: 58,
            nanos: None,
            offset_minutes: Some(60),
        };
        let shots = Shot::series(
            &Camera::default(),
            first,
            &[0.01, 0.04, 0.16],
            8.0,
            200.0,
            1.25,
        );
        assert_eq!(shots[0].captured_at, first);
        assert_eq!(
            shots[1].captured_at.to_rfc3339(),
            "2025-12-31T23:59:59.25+01:00"
        );
        assert_eq!(
            shots[2].captured_at.to_rfc3339(),
            "2026-01-01T00:00:00.5+01:00"
        );
        assert_eq!(shots[2].exposure.relative(), Some(0.16 * 200.0 / 64.0));
        let leap = CaptureTime {
            year: 2024,
            month: 2,
            day: 28,
            hour: 12,
            ..first
        };
        assert_eq!(
            leap.later_by(86_400.0).to_rfc3339(),
            "2024-02-29T12:59:58+01:00"
        );
    }
}
