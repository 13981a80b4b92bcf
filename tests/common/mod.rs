//! What the integration tests share (`crate::common` in each module of `tests/all.rs`).

use std::path::{Path, PathBuf};
use std::process::Command;

use filmback::frame::Frame;

pub mod brackets;
pub mod rig;

/// The Python that runs a reference check (`tests/*_check.py`): the one `variable` names,
/// else the venv `.ci/run` makes, else `python3`.
pub fn reference_python(variable: &str) -> String {
    if let Ok(p) = std::env::var(variable) {
        return p;
    }
    let tmp = std::env::var("TMPDIR").unwrap_or_else(|_| "/tmp".into());
    let venv = Path::new(&tmp).join("filmback-check-venv/bin/python");
    if venv.exists() {
        venv.display().to_string()
    } else {
        "python3".into()
    }
}

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

/// `frame` (exposed `exposure` s at f/1, ISO 100) encoded as a JPEG of quality 90 and
/// decoded again.
pub fn through_jpeg(frame: &Frame, exposure: f64) -> Frame {
    use filmback::metadata::{Camera, CaptureTime};
    use filmback::synthetic::{Encoding, Shot, encode};
    let first = CaptureTime {
        year: 2026,
        month: 11,
        day: 26,
        hour: 12,
        minute: 0,
        second: 0,
        nanos: None,
        offset_minutes: None,
    };
    let shot = &Shot::series(&Camera::default(), first, &[exposure], 1.0, 100.0, 0.0)[0];
    let bytes = encode(frame, shot, Encoding::Jpeg { quality: 90 }).unwrap();
    let limits = filmback::frame::Limits::default();
    filmback::frame::decode(Path::new("frame.jpg"), &bytes, limits)
        .unwrap()
        .frame
}

/// Chromium, when installed: `$CHROMIUM`, else `chromium` on the `PATH`; when it is not,
/// says on stderr that the calling test skipped.
pub fn chromium() -> Option<PathBuf> {
    let found = std::env::var_os("CHROMIUM").map(PathBuf::from).or_else(|| {
        std::env::split_paths(&std::env::var_os("PATH")?)
            .map(|dir| dir.join("chromium"))
            .find(|p| p.is_file())
    });
    if found.is_none() {
        eprintln!("skipped: no chromium on the PATH (apt-get install chromium, or set CHROMIUM)");
    }
    found
}
