//! What the integration tests share (`crate::common` in each module of `tests/all.rs`).

use std::path::Path;
use std::process::Command;

pub mod brackets;

/// The `filmback` binary Cargo built for these tests.
pub fn filmback() -> Command {
    Command::new(env!("CARGO_BIN_EXE_filmback"))
}

/// The interleaved RGB samples (through the library's reader, as `render` reads a map)
/// and the layer attributes of the OpenEXR file at `path`.
pub fn read_exr(path: &Path) -> (Vec<f32>, exr::prelude::LayerAttributes) {
    let map = filmback::hdr_output::read_exr(path).unwrap();
    let meta = exr::meta::MetaData::read_from_file(path, false).unwrap();
    (
        map.pixels().to_vec(),
        meta.headers[0].own_attributes.clone(),
    )
}
