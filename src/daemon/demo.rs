//! A demo feed: bracketed JPEG frames with EXIF (camera, exposure, capture time) of a
//! synthetic high-dynamic-range scene, dropped into the ingest folder the way a tethering
//! tool does (temporary name, then rename). Used by `filmback watch --demo`, the fault
//! tests and the latency benchmark.
//!
//! Scene radiance `E(x, y)` spans about 2¹² (a bright window over a dark room with a
//! grey ramp); frame `k` records `B = srgb(clip(E · e_k / e_ref))`, where
//! `e_k = t_k·S/N²` comes from the EXIF written into the same file.

use std::io::Write;
use std::path::{Path, PathBuf};

use exif::{Field, In, Rational, Tag, Value};

use crate::atomic::{self, Overwrite};

/// One exposure of the demo camera.
#[derive(Debug, Clone)]
pub struct DemoShot {
    /// EXIF `Model` (`Make` is "filmback").
    pub model: String,
    /// EXIF `BodySerialNumber`.
    pub serial: Option<String>,
    /// Exposure time `1/denominator` s.
    pub time_denominator: u32,
    /// f-number.
    pub f_number: f64,
    /// ISO speed.
    pub iso: u16,
    /// `DateTimeOriginal`, `YYYY:MM:DD HH:MM:SS`.
    pub captured_at: String,
    /// `SubSecTimeOriginal` in milliseconds.
    pub millis: u16,
}

impl DemoShot {
    /// Relative exposure `e = t·S/N²`.
    pub fn exposure(&self) -> f64 {
        f64::from(self.iso) / f64::from(self.time_denominator) / (self.f_number * self.f_number)
    }
}

/// Why a demo frame could not be made.
#[derive(Debug, thiserror::Error)]
pub enum DemoError {
    /// JPEG or EXIF encoding failed.
    #[error("cannot encode demo frame: {0}")]
    Encode(String),
    /// Writing or renaming failed.
    #[error("{path}: {reason}")]
    Write {
        /// The file.
        path: PathBuf,
        /// Why.
        reason: String,
    },
}

/// Scene radiance at `(u, v) ∈ [0, 1]²`, relative to mid-grey 0.18.
fn scene(u: f64, v: f64) -> f64 {
    let window = if (0.6..0.9).contains(&u) && (0.1..0.45).contains(&v) {
        40.0
    } else {
        0.0
    };
    let ramp = 0.01 * 2f64.powf(8.0 * u);
    let lamp = 200.0 * (-((u - 0.25).powi(2) + (v - 0.7).powi(2)) / 0.002).exp();
    0.18 * (ramp + window + lamp + 0.05 * (20.0 * v).sin().abs())
}

fn srgb(x: f64) -> f64 {
    if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    }
}

/// JPEG bytes of the scene as `shot` records it, with EXIF; `e_ref` is the exposure that
/// renders mid-grey at `srgb(0.18)`.
pub fn encode(width: u16, height: u16, shot: &DemoShot, e_ref: f64) -> Result<Vec<u8>, DemoError> {
    let pixels = render(width, height, shot.exposure() / e_ref);
    encode_pixels(&pixels, width, height, shot)
}

/// Interleaved 8-bit RGB of the scene at relative exposure `gain` (1 = mid-grey at
/// `srgb(0.18)`).
pub fn render(width: u16, height: u16, gain: f64) -> Vec<u8> {
    let mut pixels = Vec::with_capacity(usize::from(width) * usize::from(height) * 3);
    for y in 0..height {
        for x in 0..width {
            let (u, v) = (
                f64::from(x) / f64::from(width),
                f64::from(y) / f64::from(height),
            );
            let e = scene(u, v) * gain;
            // A slight colour cast per channel so the three channels differ.
            for tint in [1.0, 0.9, 0.75] {
                pixels.push((srgb((e * tint).clamp(0.0, 1.0)) * 255.0 + 0.5) as u8);
            }
        }
    }
    pixels
}

/// JPEG bytes of already rendered RGB pixels, with `shot`'s EXIF.
pub fn encode_pixels(
    pixels: &[u8],
    width: u16,
    height: u16,
    shot: &DemoShot,
) -> Result<Vec<u8>, DemoError> {
    let exif = exif_bytes(shot)?;
    let mut out = Vec::new();
    let mut encoder = jpeg_encoder::Encoder::new(&mut out, 90);
    encoder
        .add_exif_metadata(&exif)
        .map_err(|e| DemoError::Encode(e.to_string()))?;
    encoder
        .encode(pixels, width, height, jpeg_encoder::ColorType::Rgb)
        .map_err(|e| DemoError::Encode(e.to_string()))?;
    Ok(out)
}

fn exif_bytes(shot: &DemoShot) -> Result<Vec<u8>, DemoError> {
    let ascii = |tag, s: &str| Field {
        tag,
        ifd_num: In::PRIMARY,
        value: Value::Ascii(vec![s.as_bytes().to_vec()]),
    };
    let fnum = Rational {
        num: (shot.f_number * 10.0).round() as u32,
        denom: 10,
    };
    let mut fields = vec![
        ascii(Tag::Make, "filmback"),
        ascii(Tag::Model, &shot.model),
        ascii(Tag::DateTimeOriginal, &shot.captured_at),
        ascii(Tag::SubSecTimeOriginal, &format!("{:03}", shot.millis)),
        Field {
            tag: Tag::ExposureTime,
            ifd_num: In::PRIMARY,
            value: Value::Rational(vec![Rational {
                num: 1,
                denom: shot.time_denominator,
            }]),
        },
        Field {
            tag: Tag::FNumber,
            ifd_num: In::PRIMARY,
            value: Value::Rational(vec![fnum]),
        },
        Field {
            tag: Tag::PhotographicSensitivity,
            ifd_num: In::PRIMARY,
            value: Value::Short(vec![shot.iso]),
        },
    ];
    if let Some(s) = &shot.serial {
        fields.push(ascii(Tag::BodySerialNumber, s));
    }
    let mut writer = exif::experimental::Writer::new();
    for f in &fields {
        writer.push_field(f);
    }
    let mut buf = std::io::Cursor::new(Vec::new());
    writer
        .write(&mut buf, false)
        .map_err(|e| DemoError::Encode(e.to_string()))?;
    Ok(buf.into_inner())
}

/// The usual three-frame AEB of the demo camera: 1/250, 1/60, 1/15 s at f/8, ISO 100
/// (−2, 0, +2 EV), 0.3 s apart, starting at `second` past 12:00:00 on 2026-01-01.
pub fn aeb(model: &str, serial: Option<&str>, second: u32) -> Vec<DemoShot> {
    [250, 60, 15]
        .iter()
        .enumerate()
        .map(|(i, &den)| {
            let ms = second * 1000 + 300 * i as u32;
            DemoShot {
                model: model.to_string(),
                serial: serial.map(str::to_string),
                time_denominator: den,
                f_number: 8.0,
                iso: 100,
                captured_at: format!(
                    "2026:01:01 {:02}:{:02}:{:02}",
                    12 + ms / 3_600_000,
                    (ms / 60_000) % 60,
                    (ms / 1000) % 60
                ),
                millis: (ms % 1000) as u16,
            }
        })
        .collect()
}

/// Writes one frame into `dir` as a tethering tool does: to `<name>.part`, then renamed
/// to `<name>` (so the daemon never sees a partial file under the final name).
pub fn drop_frame(dir: &Path, name: &str, bytes: &[u8]) -> Result<PathBuf, DemoError> {
    let path = dir.join(name);
    let part = dir.join(format!("{name}.part"));
    let err = |e: std::io::Error| DemoError::Write {
        path: path.clone(),
        reason: e.to_string(),
    };
    let mut f = std::fs::File::create(&part).map_err(err)?;
    f.write_all(bytes).map_err(err)?;
    f.sync_all().map_err(err)?;
    drop(f);
    std::fs::rename(&part, &path).map_err(err)?;
    Ok(path)
}

/// Publishes a frame directly (atomically) under `dir/name`.
pub fn publish_frame(dir: &Path, name: &str, bytes: &[u8]) -> Result<PathBuf, DemoError> {
    let path = dir.join(name);
    atomic::publish(&path, bytes, Overwrite::Replace).map_err(|e| DemoError::Write {
        path: path.clone(),
        reason: e.to_string(),
    })?;
    Ok(path)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metadata;

    #[test]
    fn demo_frames_carry_readable_exif() {
        let shots = aeb("Demo Body", Some("7"), 61);
        let bytes = encode(64, 48, &shots[2], shots[1].exposure()).unwrap();
        let m = metadata::read(&bytes);
        assert_eq!(m.camera.model.as_deref(), Some("Demo Body"));
        assert_eq!(m.camera.serial.as_deref(), Some("7"));
        assert_eq!(m.exposure.time_s, Some(1.0 / 15.0));
        assert_eq!(m.exposure.f_number, Some(8.0));
        assert_eq!(m.exposure.iso, Some(100.0));
        let t = m.captured_at.unwrap();
        assert_eq!(
            (t.hour, t.minute, t.second, t.nanos),
            (12, 1, 1, Some(600_000_000))
        );
        let loaded = crate::frame::decode(Path::new("x.jpg"), &bytes, Default::default()).unwrap();
        assert_eq!((loaded.frame.width(), loaded.frame.height()), (64, 48));
    }
}
