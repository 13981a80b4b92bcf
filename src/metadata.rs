//! EXIF metadata: which camera took a frame, how it was exposed, and when.
//!
//! Reading never fails: a file without EXIF, or with a missing or absurd tag, yields
//! `None` for that value and a warning that names the tag and the reason. Nothing is
//! invented: an unknown exposure stays unknown until the caller supplies one.
//!
//! Relative exposure `e = t·S/N²` (t exposure time in s, S ISO speed, N f-number) is what
//! the merge divides by; EV100 `= log2(N²/t) − log2(S/100)`.

use std::io::Cursor;

use exif::{In, Tag, Value};
use serde::Serialize;

/// The body that took the frame. A bracket is never formed across two bodies.
#[derive(Debug, Clone, Default, PartialEq, Eq, Hash, Serialize)]
pub struct Camera {
    /// Manufacturer (EXIF `Make`).
    pub make: Option<String>,
    /// Model (EXIF `Model`).
    pub model: Option<String>,
    /// Body serial number (EXIF `BodySerialNumber`), when the camera writes it.
    pub serial: Option<String>,
    /// Lens model (EXIF `LensModel`), when present.
    pub lens: Option<String>,
}

/// How the frame was exposed. `None` means unknown (missing or absurd in the file).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct Exposure {
    /// Exposure time in seconds.
    pub time_s: Option<f64>,
    /// Aperture as an f-number N.
    pub f_number: Option<f64>,
    /// ISO speed S (arithmetic).
    pub iso: Option<f64>,
}

impl Exposure {
    /// Relative exposure `e = t·S/N²` (seconds · ISO / f-number²), `None` if any part is unknown.
    pub fn relative(&self) -> Option<f64> {
        let (t, n, s) = (self.time_s?, self.f_number?, self.iso?);
        Some(t * s / (n * n))
    }

    /// Exposure value at ISO 100: `EV100 = log2(N²/t) − log2(S/100)`.
    pub fn ev100(&self) -> Option<f64> {
        let (t, n, s) = (self.time_s?, self.f_number?, self.iso?);
        Some((n * n / t).log2() - (s / 100.0).log2())
    }
}

/// Capture time as the camera recorded it: a civil date-time, optional sub-seconds and
/// optional UTC offset (EXIF `DateTimeOriginal`, `SubSecTimeOriginal`, `OffsetTimeOriginal`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CaptureTime {
    /// Year (1..=9999).
    pub year: u16,
    /// Month 1..=12.
    pub month: u8,
    /// Day 1..=31.
    pub day: u8,
    /// Hour 0..=23.
    pub hour: u8,
    /// Minute 0..=59.
    pub minute: u8,
    /// Second 0..=60.
    pub second: u8,
    /// Nanoseconds, when sub-seconds were recorded.
    pub nanos: Option<u32>,
    /// Offset from UTC in minutes, when recorded.
    pub offset_minutes: Option<i16>,
}

impl CaptureTime {
    /// Seconds since 1970-01-01T00:00:00 of the civil time *as recorded* (offset ignored),
    /// with sub-seconds. Frames of one body share one clock, so differences between
    /// them are exact even when the camera's time zone is unknown.
    pub fn local_seconds(&self) -> f64 {
        let days = days_from_civil(
            i64::from(self.year),
            i64::from(self.month),
            i64::from(self.day),
        );
        let secs = days * 86_400
            + i64::from(self.hour) * 3600
            + i64::from(self.minute) * 60
            + i64::from(self.second);
        secs as f64 + f64::from(self.nanos.unwrap_or(0)) * 1e-9
    }

    /// RFC 3339 text, with sub-seconds when recorded and the offset when recorded
    /// (without an offset the time is local to the camera and printed without a zone).
    pub fn to_rfc3339(&self) -> String {
        let mut s = format!(
            "{:04}-{:02}-{:02}T{:02}:{:02}:{:02}",
            self.year, self.month, self.day, self.hour, self.minute, self.second
        );
        if let Some(n) = self.nanos {
            let digits = format!("{n:09}");
            let trimmed = digits.trim_end_matches('0');
            if !trimmed.is_empty() {
                s.push('.');
                s.push_str(trimmed);
            }
        }
        if let Some(off) = self.offset_minutes {
            let sign = if off < 0 { '-' } else { '+' };
            let a = off.unsigned_abs();
            s.push_str(&format!("{sign}{:02}:{:02}", a / 60, a % 60));
        }
        s
    }
}

impl Serialize for CaptureTime {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(&self.to_rfc3339())
    }
}

/// Days since 1970-01-01 of a proleptic Gregorian date (H. Hinnant's algorithm).
fn days_from_civil(y: i64, m: i64, d: i64) -> i64 {
    let y = if m <= 2 { y - 1 } else { y };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let mp = (m + 9) % 12;
    let doy = (153 * mp + 2) / 5 + d - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    era * 146_097 + doe - 719_468
}

/// Everything filmback reads from a frame's EXIF.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Metadata {
    /// The camera body.
    pub camera: Camera,
    /// Exposure settings.
    pub exposure: Exposure,
    /// When the frame was captured.
    pub captured_at: Option<CaptureTime>,
    /// EXIF orientation 1..=8 (1 = upright; 1 when absent or invalid).
    pub orientation: u8,
    /// One line per missing or absurd tag, naming the tag and the reason.
    pub warnings: Vec<String>,
}

impl Default for Metadata {
    fn default() -> Self {
        Metadata {
            camera: Camera::default(),
            exposure: Exposure::default(),
            captured_at: None,
            orientation: 1,
            warnings: Vec::new(),
        }
    }
}

/// Reads EXIF from a JPEG, PNG, TIFF, WebP or HEIF file held in memory. Never fails:
/// problems become warnings and unknown values.
pub fn read(bytes: &[u8]) -> Metadata {
    let mut meta = Metadata::default();
    let exif = match exif::Reader::new().read_from_container(&mut Cursor::new(bytes)) {
        Ok(e) => e,
        Err(exif::Error::NotFound(_)) => {
            meta.warnings
                .push("no EXIF data: camera, exposure and capture time unknown".to_string());
            return meta;
        }
        Err(e) => {
            meta.warnings.push(format!(
                "EXIF unreadable ({e}): camera, exposure and capture time unknown"
            ));
            return meta;
        }
    };
    let mut r = TagReader {
        exif: &exif,
        warnings: &mut meta.warnings,
    };
    meta.camera = Camera {
        make: r.text(Tag::Make),
        model: r.text(Tag::Model),
        serial: r.text(Tag::BodySerialNumber),
        lens: r.text(Tag::LensModel),
    };
    meta.exposure = Exposure {
        time_s: r.positive(Tag::ExposureTime, "exposure time", 1e-6, 3600.0 * 24.0),
        f_number: r.positive(Tag::FNumber, "f-number", 0.5, 1024.0),
        iso: r.iso(),
    };
    meta.captured_at = r.capture_time();
    meta.orientation = r.orientation();
    meta
}

struct TagReader<'a> {
    exif: &'a exif::Exif,
    warnings: &'a mut Vec<String>,
}

impl TagReader<'_> {
    fn field(&self, tag: Tag) -> Option<&exif::Field> {
        self.exif.get_field(tag, In::PRIMARY)
    }

    fn text(&mut self, tag: Tag) -> Option<String> {
        let field = self.field(tag)?;
        match &field.value {
            Value::Ascii(parts) => {
                let joined: Vec<u8> = parts.iter().flatten().copied().collect();
                let text = String::from_utf8_lossy(&joined)
                    .trim_matches(|c: char| c == '\0' || c.is_whitespace())
                    .to_string();
                (!text.is_empty()).then_some(text)
            }
            _ => {
                self.warnings.push(format!("EXIF {tag}: not text, ignored"));
                None
            }
        }
    }

    fn number(&self, tag: Tag) -> Option<f64> {
        let field = self.field(tag)?;
        match &field.value {
            Value::Rational(v) => v.first().map(|r| r.to_f64()),
            Value::SRational(v) => v.first().map(|r| r.to_f64()),
            Value::Short(v) => v.first().map(|&x| f64::from(x)),
            Value::Long(v) => v.first().map(|&x| f64::from(x)),
            Value::Float(v) => v.first().map(|&x| f64::from(x)),
            Value::Double(v) => v.first().copied(),
            _ => None,
        }
    }

    /// A value that must be finite and within `[lo, hi]`; otherwise unknown with a warning.
    fn positive(&mut self, tag: Tag, what: &str, lo: f64, hi: f64) -> Option<f64> {
        if self.field(tag).is_none() {
            self.warnings
                .push(format!("EXIF {tag} missing: {what} unknown"));
            return None;
        }
        match self.number(tag) {
            Some(v) if v.is_finite() && v >= lo && v <= hi => Some(v),
            Some(v) => {
                self.warnings.push(format!(
                    "EXIF {tag} = {v} is absurd (expected {lo}..{hi}): {what} unknown"
                ));
                None
            }
            None => {
                self.warnings
                    .push(format!("EXIF {tag} has no numeric value: {what} unknown"));
                None
            }
        }
    }

    /// ISO from PhotographicSensitivity (0x8827); 65535 means "see
    /// RecommendedExposureIndex / ISOSpeed" (EXIF 2.3).
    fn iso(&mut self) -> Option<f64> {
        let primary = self.number(Tag::PhotographicSensitivity);
        match primary {
            Some(v) if v > 0.0 && v < 65535.0 => return Some(v),
            Some(0.0) => {
                self.warnings
                    .push("EXIF PhotographicSensitivity = 0 is absurd: ISO unknown".to_string());
                return None;
            }
            _ => {}
        }
        for tag in [Tag::RecommendedExposureIndex, Tag::ISOSpeed] {
            if let Some(v) = self.number(tag).filter(|v| *v > 0.0 && v.is_finite()) {
                return Some(v);
            }
        }
        self.warnings.push(if primary.is_some() {
            "EXIF PhotographicSensitivity = 65535 and no RecommendedExposureIndex/ISOSpeed: ISO unknown"
                .to_string()
        } else {
            "EXIF PhotographicSensitivity missing: ISO unknown".to_string()
        });
        None
    }

    fn capture_time(&mut self) -> Option<CaptureTime> {
        let field = self.field(Tag::DateTimeOriginal)?;
        let Value::Ascii(parts) = &field.value else {
            self.warnings
                .push("EXIF DateTimeOriginal is not text: capture time unknown".to_string());
            return None;
        };
        let raw = parts.first()?;
        let dt = match exif::DateTime::from_ascii(raw) {
            Ok(dt) => dt,
            Err(e) => {
                self.warnings.push(format!(
                    "EXIF DateTimeOriginal {:?} unreadable ({e}): capture time unknown",
                    String::from_utf8_lossy(raw)
                ));
                return None;
            }
        };
        let valid = (1..=9999).contains(&dt.year)
            && (1..=12).contains(&dt.month)
            && (1..=31).contains(&dt.day)
            && dt.hour < 24
            && dt.minute < 60
            && dt.second <= 60;
        if !valid {
            self.warnings.push(format!(
                "EXIF DateTimeOriginal {:?} is not a real date: capture time unknown",
                String::from_utf8_lossy(raw)
            ));
            return None;
        }
        let nanos = self
            .field(Tag::SubSecTimeOriginal)
            .and_then(|f| match &f.value {
                Value::Ascii(p) => p.first().and_then(|digits| subsec_nanos(digits)),
                _ => None,
            });
        let offset_minutes = self
            .field(Tag::OffsetTimeOriginal)
            .and_then(|f| match &f.value {
                Value::Ascii(p) => p.first().and_then(|s| parse_offset(s)),
                _ => None,
            });
        Some(CaptureTime {
            year: dt.year,
            month: dt.month,
            day: dt.day,
            hour: dt.hour,
            minute: dt.minute,
            second: dt.second,
            nanos,
            offset_minutes,
        })
    }

    fn orientation(&mut self) -> u8 {
        match self.number(Tag::Orientation) {
            None => 1,
            Some(v) if (1.0..=8.0).contains(&v) && v.fract() == 0.0 => v as u8,
            Some(v) => {
                self.warnings.push(format!(
                    "EXIF Orientation = {v} is invalid: treated as upright"
                ));
                1
            }
        }
    }
}

/// `"123"` → 0.123 s in nanoseconds; digits only, at most 9 used.
fn subsec_nanos(digits: &[u8]) -> Option<u32> {
    let digits: Vec<u8> = digits
        .iter()
        .copied()
        .take_while(u8::is_ascii_digit)
        .take(9)
        .collect();
    if digits.is_empty() {
        return None;
    }
    let mut n: u32 = 0;
    for d in &digits {
        n = n * 10 + u32::from(d - b'0');
    }
    Some(n * 10u32.pow(9 - digits.len() as u32))
}

/// `"+02:00"` / `"-05:30"` → minutes east of UTC.
fn parse_offset(s: &[u8]) -> Option<i16> {
    let s = std::str::from_utf8(s)
        .ok()?
        .trim_matches(char::from(0))
        .trim();
    let (sign, rest) = match s.as_bytes().first()? {
        b'+' => (1, &s[1..]),
        b'-' => (-1, &s[1..]),
        _ => return None,
    };
    let (h, m) = rest.split_once(':')?;
    let (h, m): (i16, i16) = (h.parse().ok()?, m.parse().ok()?);
    (h <= 14 && m < 60).then_some(sign * (h * 60 + m))
}
