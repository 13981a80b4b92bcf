//! A demo feed: bracketed JPEG frames with EXIF (camera, exposure, capture time) of the
//! synthetic HDR scene ([`crate::synthetic`]), dropped into the ingest folder the way a
//! tethering tool does (temporary name, then rename). Used by `filmback watch --demo`,
//! the fault tests and the latency benchmark.

use std::io::Write;
use std::path::{Path, PathBuf};

use crate::frame::BitDepth;
use crate::metadata::{Camera, CaptureTime};
use crate::synthetic::{self, Encoding, ResponseCurve, Sensor, Shot, SyntheticError};

/// The seed of the synthetic scene `filmback watch --demo` drops (one scene every time,
/// so the demonstration shows the same thing on every machine).
pub const SCENE: u64 = 7;

/// The size of the frames `filmback watch --demo` drops, width × height.
pub const SIZE: (u32, u32) = (1200, 800);

/// Why a demo frame could not be made or dropped.
#[derive(Debug, thiserror::Error)]
pub enum DemoError {
    /// Rendering or encoding failed.
    #[error(transparent)]
    Synthetic(#[from] SyntheticError),
    /// Writing or renaming failed.
    #[error("{path}: {source}")]
    Write {
        /// The file.
        path: PathBuf,
        /// What the operating system said.
        #[source]
        source: std::io::Error,
    },
}

/// The demo body: make "filmback", the given model and serial.
pub fn camera(model: &str, serial: Option<&str>) -> Camera {
    Camera {
        make: Some("filmback".to_string()),
        model: Some(model.to_string()),
        serial: serial.map(str::to_string),
        lens: None,
    }
}

/// The usual three-frame AEB: 1/250, 1/60, 1/15 s at f/8, ISO 100 (−2, 0, +2 EV), 0.3 s
/// apart, the first at `second` seconds past 2026-01-01 12:00:00 (camera clock).
pub fn aeb(model: &str, serial: Option<&str>, second: u32) -> Vec<Shot> {
    let first = CaptureTime {
        year: 2026,
        month: 1,
        day: 1,
        hour: (12 + second / 3600) as u8,
        minute: (second / 60 % 60) as u8,
        second: (second % 60) as u8,
        nanos: Some(0),
        offset_minutes: None,
    };
    Shot::series(
        &camera(model, serial),
        first,
        &[1.0 / 250.0, 1.0 / 60.0, 1.0 / 15.0],
        8.0,
        100.0,
        0.3,
    )
}

/// JPEGs (quality 90, with EXIF) of the synthetic scene (`seed`) as `shots` record it
/// through an sRGB camera; the exposure scale puts the *middle* shot's mid-grey at
/// `srgb(0.18)`.
pub fn jpegs(
    width: u32,
    height: u32,
    shots: &[Shot],
    seed: u64,
) -> Result<Vec<Vec<u8>>, DemoError> {
    let scene = synthetic::scene(width, height, seed);
    let sensor = Sensor::noiseless(ResponseCurve::Srgb, BitDepth::Eight);
    let middle = shots[shots.len() / 2].exposure.relative().unwrap_or(1.0);
    let frames = synthetic::bracket(&scene, &sensor, shots, 1.0 / middle)?;
    frames
        .iter()
        .zip(shots)
        .map(|(f, s)| Ok(synthetic::encode(f, s, Encoding::Jpeg { quality: 90 })?))
        .collect()
}

/// Writes one frame into `dir` as a tethering tool does: to `<name>.part`, then renamed
/// to `<name>` (so the daemon never sees a partial file under the final name).
pub fn drop_frame(dir: &Path, name: &str, bytes: &[u8]) -> Result<PathBuf, DemoError> {
    let path = dir.join(name);
    let part = dir.join(format!("{name}.part"));
    let err = |source: std::io::Error| DemoError::Write {
        path: path.clone(),
        source,
    };
    let mut f = std::fs::File::create(&part).map_err(err)?;
    f.write_all(bytes).map_err(err)?;
    f.sync_all().map_err(err)?;
    drop(f);
    std::fs::rename(&part, &path).map_err(err)?;
    Ok(path)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metadata;

    #[test]
    fn demo_frames_carry_readable_exif() {
        let shots = aeb("Demo Body", Some("7"), 61);
        let bytes = jpegs(64, 48, &shots, 1).unwrap();
        let m = metadata::read(&bytes[2]);
        assert_eq!(m.camera.model.as_deref(), Some("Demo Body"));
        assert_eq!(m.camera.serial.as_deref(), Some("7"));
        assert_eq!(m.exposure.time_s, Some(1.0 / 15.0));
        assert_eq!(m.exposure.f_number, Some(8.0));
        assert_eq!(m.exposure.iso, Some(100.0));
        let t = m.captured_at.unwrap();
        assert_eq!((t.hour, t.minute, t.second), (12, 1, 1));
        assert_eq!(t.nanos.map(|n| (n + 500) / 1000), Some(600_000));
        let loaded =
            crate::frame::decode(Path::new("x.jpg"), &bytes[0], Default::default()).unwrap();
        assert_eq!((loaded.frame.width(), loaded.frame.height()), (64, 48));
    }
}
