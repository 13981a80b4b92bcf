//! filmback: a tethered camera as an extended-sensitivity sensor with the look of film.
//!
//! The pipeline, one module per stage, bottom to top (a module uses only those above it
//! in this list; `tests/layers.rs` checks it):
//!
//! | stage | module |
//! |---|---|
//! | publishing files (temporary name, fsync, rename) | [`atomic`] |
//! | a capture's EXIF | [`metadata`] |
//! | camera raw: decoding, CFA merge, demosaicking, colour (feature `raw`) | `raw` |
//! | decoding a frame at its native depth | [`frame`] |
//! | the relative radiance map | [`radiance`] |
//! | histograms and the intensity mapping `τ` | [`histogram`] |
//! | the camera's inverse response `g` from two or more frames | [`response`] |
//! | registering a bracket's frames onto a reference frame | [`align`] |
//! | frames and `g` into radiance | [`merge`] |
//! | where a frame disagrees with the reference (moving subjects) | [`deghost`] |
//! | OpenEXR and Radiance `.hdr` | [`hdr_output`] |
//! | the display image, sRGB and luminance | [`display`] |
//! | film stocks through their dye layers | [`film`] |
//! | tone-mapping operators | [`tonemap`] |
//! | looks and their encoders | [`rendering`] |
//! | one bracket end to end | [`darkroom`] |
//!
//! Above the pipeline: [`synthetic`] renders the demo feed's scene and, with the feature
//! `ground-truth` (tests, benchmarks and examples only), the tests' ground-truth brackets; [`daemon`] is the service `filmback watch` runs (configuration, bracket
//! grouping, journal, response cache, queue, status); [`farm`] plans a folder tree into
//! tasks with the daemon's grouping and runs one task per index on a render farm
//! (`filmback plan`, `filmback run`).
//!
//! # The library's surface
//!
//! What a program that develops brackets needs is re-exported here, flat: load frames
//! ([`load`]), develop them ([`develop`], [`develop_single`]) into the outputs a [`Prints`]
//! names, read and write radiance maps ([`read_exr`], [`write_exr`]), and run the service
//! ([`watch`]) or a farm task ([`write_plan`], [`run_task`]). The modules themselves are
//! public for the command line, the tests and the benchmarks, but hidden from these docs:
//! their items may change between any two versions.
//!
//! ```no_run
//! use filmback::{
//!     ColourSpace, Format, GivenResponse, Limits, MergeOptions, Overwrite, Prints,
//!     RatioSource, ResponsePolicy, SourceExif, develop, load,
//! };
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let frames = vec![
//!     load("dark.jpg".as_ref(), Limits::default())?,
//!     load("bright.jpg".as_ref(), Limits::default())?,
//! ];
//! let exif = SourceExif::default();
//! let prints = Prints {
//!     dir: "out".as_ref(),
//!     stem: "bracket",
//!     exr: Some(Default::default()),
//!     radiance_hdr: false,
//!     dng: false,
//!     looks: &[],
//!     format: Format::Jpeg { quality: 92 },
//!     space: ColourSpace::Srgb,
//!     exif: &exif,
//!     overwrite: Overwrite::Refuse,
//!     luminance_calibration: 1.0,
//!     preview_edge: None,
//!     ghost_map: false,
//! };
//! let policy = ResponsePolicy::Use(GivenResponse::standard(3));
//! let developed = develop(
//!     &frames,
//!     &[1.0, 4.0],
//!     RatioSource::Exif,
//!     policy,
//!     MergeOptions::default(),
//!     &prints,
//! )?;
//! println!("{:?}", developed.outputs);
//! # Ok(())
//! # }
//! ```

#[doc(hidden)]
pub mod atomic;
#[doc(hidden)]
pub mod metadata;
#[cfg(feature = "raw")]
#[doc(hidden)]
pub mod raw;
#[doc(hidden)]
pub mod frame;
#[doc(hidden)]
pub mod radiance;
#[doc(hidden)]
pub mod histogram;
#[doc(hidden)]
pub mod response;
#[doc(hidden)]
pub mod align;
#[doc(hidden)]
pub mod merge;
#[doc(hidden)]
pub mod deghost;
#[doc(hidden)]
pub mod hdr_output;
#[doc(hidden)]
pub mod display;
#[doc(hidden)]
pub mod film;
#[doc(hidden)]
pub mod tonemap;
#[doc(hidden)]
pub mod rendering;
#[doc(hidden)]
pub mod darkroom;
#[doc(hidden)]
pub mod synthetic;
#[doc(hidden)]
pub mod daemon;
#[doc(hidden)]
pub mod farm;

pub use align::AlignMode;
pub use atomic::{Overwrite, PublishError};
pub use daemon::config::{Config, ConfigError};
pub use daemon::{Control, DaemonError, DarkroomLab, Lab, Summary, run as watch};
pub use darkroom::{
    DarkroomError, Developed, GivenResponse, Prints, ResponsePolicy, develop, develop_single,
    job_memory_bytes,
};
pub use display::ColourSpace;
pub use farm::{PlanError, PlanOptions, RunError, RunOptions, RunOutcome, run_task, write_plan};
pub use film::{Catalogue, ColourMode, FilmError, Key, Stock};
pub use frame::{FrameError, Limits, LoadedFrame, load};
pub use hdr_output::{ExrOptions, OutputError, read_exr, write_exr, write_radiance_hdr};
pub use merge::{Deghost, MergeError, MergeOptions, Weighting};
pub use metadata::Metadata;
pub use radiance::{RadianceMap, RadianceSource};
pub use rendering::{Format, Look, RenderingError, SourceExif, looks};
pub use response::{CalibrationError, InverseResponse, RatioSource};
pub use tonemap::Operator;
