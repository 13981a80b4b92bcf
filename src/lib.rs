//! filmback: a tethered camera as an extended-sensitivity sensor with the look of slide film.
//!
//! The pipeline, one module per stage (see `DESIGN.md` of the project):
//! [`frame`] and [`metadata`] read a capture; [`histogram`] and [`response`] recover the
//! camera's inverse response from two frames' histograms; [`merge`] builds a
//! [`radiance::RadianceMap`]; [`hdr_output`] writes it as OpenEXR; [`tonemap`] and
//! [`film`] render it for display. [`synthetic`] renders ground-truth brackets for tests
//! and demos; [`atomic`] publishes every output file without ever exposing a partial one.

pub mod atomic;
pub mod bracket;
pub mod cache;
pub mod config;
pub mod daemon;
pub mod darkroom;
pub mod film;
pub mod frame;
pub mod hdr_output;
pub mod histogram;
pub mod journal;
pub mod merge;
pub mod metadata;
pub mod radiance;
pub mod rendering;
pub mod response;
pub mod synthetic;
pub mod tonemap;
