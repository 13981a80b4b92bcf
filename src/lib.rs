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
//! Above the pipeline: [`synthetic`] renders ground-truth brackets (and the demo feed) for
//! tests and demos; [`daemon`] is the service `filmback watch` runs (configuration, bracket
//! grouping, journal, response cache, queue, status); [`farm`] plans a folder tree into
//! tasks with the daemon's grouping and runs one task per index on a render farm
//! (`filmback plan`, `filmback run`).

pub mod atomic;
pub mod metadata;
#[cfg(feature = "raw")]
pub mod raw;
pub mod frame;
pub mod radiance;
pub mod histogram;
pub mod response;
pub mod align;
pub mod merge;
pub mod deghost;
pub mod hdr_output;
pub mod display;
pub mod film;
pub mod tonemap;
pub mod rendering;
pub mod darkroom;
pub mod synthetic;
pub mod daemon;
pub mod farm;
