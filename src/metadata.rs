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
    /// Year (1..=9998; 0000 and 9999 are placeholders).
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

    /// This time advanced by `seconds` (≥ 0; negative counts as 0) on the camera's clock,
    /// to the nanosecond; the offset is kept. Sub-seconds are recorded when this time has
    /// them or the result falls between whole seconds.
    pub(crate) fn later_by(&self, seconds: f64) -> CaptureTime {
        let whole = CaptureTime {
            nanos: None,
            ..*self
        }
        .local_seconds() as i64;
        let total = i128::from(whole) * 1_000_000_000
            + i128::from(self.nanos.unwrap_or(0))
            + (seconds.max(0.0) * 1e9).round() as i128;
        let (secs, nanos) = (
            total.div_euclid(1_000_000_000) as i64,
            total.rem_euclid(1_000_000_000) as u32,
        );
        let (days, of_day) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
        let (year, month, day) = civil_from_days(days);
        CaptureTime {
            year: year as u16,
            month: month as u8,
            day: day as u8,
            hour: (of_day / 3600) as u8,
            minute: (of_day / 60 % 60) as u8,
            second: (of_day % 60) as u8,
            nanos: (self.nanos.is_some() || nanos != 0).then_some(nanos),
            offset_minutes: self.offset_minutes,
        }
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

/// The proleptic Gregorian date `(year, month, day)` of a day count since 1970-01-01: the
/// inverse of [`days_from_civil`] (H. Hinnant's algorithm).
fn civil_from_days(days: i64) -> (i64, i64, i64) {
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    (yoe + era * 400 + i64::from(month <= 2), month, day)
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
    let mut reader = exif::Reader::new();
    // One broken IFD (say a GPS pointer outside the file) must not hide the exposure tags
    // that were read fine: keep the partial result and say what was skipped.
    reader.continue_on_error(true);
    let exif = match reader.read_from_container(&mut Cursor::new(bytes)) {
        Ok(e) => e,
        Err(exif::Error::PartialResult(partial)) => {
            let (exif, errors) = partial.into_inner();
            let reasons: Vec<String> = errors.iter().map(ToString::to_string).collect();
            meta.warnings.push(format!(
                "EXIF partly unreadable ({}): tags there are ignored",
                reasons.join("; ")
            ));
            exif
        }
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

    /// ISO from PhotographicSensitivity (0x8827, formerly ISOSpeedRatings). The value
    /// 65535 means "65535 or more: see RecommendedExposureIndex / ISOSpeed" (EXIF 2.3), and
    /// those two tags are also used when 0x8827 is missing. Zero or non-finite is absurd.
    fn iso(&mut self) -> Option<f64> {
        const SATURATED: f64 = 65535.0;
        let primary = self
            .field(Tag::PhotographicSensitivity)
            .map(|_| self.number(Tag::PhotographicSensitivity));
        match primary {
            Some(Some(v)) if v.is_finite() && v > 0.0 && v < SATURATED => return Some(v),
            Some(Some(v)) if v != SATURATED => {
                self.warnings.push(format!(
                    "EXIF PhotographicSensitivity = {v} is absurd (expected 1..65535): ISO unknown"
                ));
                return None;
            }
            Some(None) => {
                self.warnings.push(
                    "EXIF PhotographicSensitivity has no numeric value: ISO unknown".to_string(),
                );
                return None;
            }
            _ => {}
        }
        for tag in [Tag::RecommendedExposureIndex, Tag::ISOSpeed] {
            match self.number(tag) {
                Some(v) if v.is_finite() && v > 0.0 => return Some(v),
                Some(v) => self
                    .warnings
                    .push(format!("EXIF {tag} = {v} is absurd: ignored")),
                None => {}
            }
        }
        self.warnings.push(if primary.is_some() {
            "EXIF PhotographicSensitivity = 65535 (saturated) and no RecommendedExposureIndex or ISOSpeed: ISO unknown"
                .to_string()
        } else {
            "EXIF PhotographicSensitivity missing: ISO unknown".to_string()
        });
        None
    }

    fn capture_time(&mut self) -> Option<CaptureTime> {
        let Some(field) = self.field(Tag::DateTimeOriginal) else {
            self.warnings
                .push("EXIF DateTimeOriginal missing: capture time unknown".to_string());
            return None;
        };
        let Value::Ascii(parts) = &field.value else {
            self.warnings
                .push("EXIF DateTimeOriginal is not text: capture time unknown".to_string());
            return None;
        };
        let Some(raw) = parts.first() else {
            self.warnings
                .push("EXIF DateTimeOriginal is empty: capture time unknown".to_string());
            return None;
        };
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
        // Year 9999 is EXIF's largest, written as a placeholder the way 0000 is.
        if dt.year == 9999 {
            self.warnings.push(format!(
                "EXIF DateTimeOriginal {:?} is a placeholder (year 9999), not a real date: capture time unknown",
                String::from_utf8_lossy(raw)
            ));
            return None;
        }
        let valid = is_real_date(dt.year, dt.month, dt.day, dt.hour, dt.minute, dt.second);
        if !valid {
            self.warnings.push(format!(
                "EXIF DateTimeOriginal {:?} is not a real date: capture time unknown",
                String::from_utf8_lossy(raw)
            ));
            return None;
        }
        let nanos = self.ascii(Tag::SubSecTimeOriginal).and_then(|digits| {
            let nanos = subsec_nanos(&digits);
            if nanos.is_none() {
                self.warnings.push(format!(
                    "EXIF SubSecTimeOriginal {:?} is not digits: sub-seconds unknown",
                    String::from_utf8_lossy(&digits)
                ));
            }
            nanos
        });
        let offset_minutes = self.ascii(Tag::OffsetTimeOriginal).and_then(|text| {
            let offset = parse_offset(&text);
            if offset.is_none() {
                self.warnings.push(format!(
                    "EXIF OffsetTimeOriginal {:?} is not ±HH:MM: UTC offset unknown",
                    String::from_utf8_lossy(&text)
                ));
            }
            offset
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

    /// The first string of an ASCII field, without trailing NULs and blanks; `None` when
    /// the tag is absent or blank (cameras pad unused fields with spaces).
    fn ascii(&self, tag: Tag) -> Option<Vec<u8>> {
        let Value::Ascii(parts) = &self.field(tag)?.value else {
            return None;
        };
        let text = parts.first()?;
        let end = text
            .iter()
            .rposition(|&c| c != 0 && c != b' ')
            .map_or(0, |i| i + 1);
        (end > 0).then(|| text[..end].to_vec())
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

/// Days in `month` of `year` (proleptic Gregorian).
/// Whether a recorded date-time is a real one: year 1..=9998 (0000 and 9999 are
/// placeholders cameras write), a day that exists in its month, a time of day (a leap
/// second allowed).
pub(crate) fn is_real_date(
    year: u16,
    month: u8,
    day: u8,
    hour: u8,
    minute: u8,
    second: u8,
) -> bool {
    (1..=9998).contains(&year)
        && (1..=12).contains(&month)
        && (1..=days_in_month(year, month)).contains(&day)
        && hour < 24
        && minute < 60
        && second <= 60
}

fn days_in_month(year: u16, month: u8) -> u8 {
    match month {
        2 if year.is_multiple_of(4) && (!year.is_multiple_of(100) || year.is_multiple_of(400)) => {
            29
        }
        2 => 28,
        4 | 6 | 9 | 11 => 30,
        _ => 31,
    }
}

/// `"123"` → 0.123 s in nanoseconds; digits only (anything else is unreadable), at most
/// 9 used.
fn subsec_nanos(digits: &[u8]) -> Option<u32> {
    if digits.is_empty() || !digits.iter().all(u8::is_ascii_digit) {
        return None;
    }
    let digits = &digits[..digits.len().min(9)];
    let mut n: u32 = 0;
    for d in digits {
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
    let two_digits = |t: &str| t.len() == 2 && t.bytes().all(|c| c.is_ascii_digit());
    if !two_digits(h) || !two_digits(m) {
        return None;
    }
    let (h, m): (i16, i16) = (h.parse().ok()?, m.parse().ok()?);
    (h <= 14 && m < 60).then_some(sign * (h * 60 + m))
}

#[cfg(test)]
mod tests {
    use super::*;
    use exif::experimental::Writer;
    use exif::{Field, Rational, SRational};

    fn field(tag: Tag, value: Value) -> Field {
        Field {
            tag,
            ifd_num: In::PRIMARY,
            value,
        }
    }

    fn ascii(text: &str) -> Value {
        Value::Ascii(vec![text.as_bytes().to_vec()])
    }

    fn rational(num: u32, denom: u32) -> Value {
        Value::Rational(vec![Rational { num, denom }])
    }

    /// A TIFF (bare EXIF block) holding `fields`, as `metadata::read` sees it.
    fn tiff(fields: &[Field]) -> Vec<u8> {
        let mut writer = Writer::new();
        for f in fields {
            writer.push_field(f);
        }
        let mut out = std::io::Cursor::new(Vec::new());
        writer.write(&mut out, true).unwrap();
        out.into_inner()
    }

    fn good() -> Vec<Field> {
        vec![
            field(Tag::Make, ascii("Nikon")),
            field(Tag::Model, ascii("Z 6")),
            field(Tag::BodySerialNumber, ascii("6012345")),
            field(Tag::LensModel, ascii("NIKKOR Z 24-70mm f/4 S")),
            field(Tag::ExposureTime, rational(1, 250)),
            field(Tag::FNumber, rational(56, 10)),
            field(Tag::PhotographicSensitivity, Value::Short(vec![400])),
            field(Tag::DateTimeOriginal, ascii("2026:03:14 09:26:53")),
            field(Tag::SubSecTimeOriginal, ascii("125")),
            field(Tag::OffsetTimeOriginal, ascii("+02:00")),
            field(Tag::Orientation, Value::Short(vec![6])),
        ]
    }

    /// `good()` with `tag` replaced by `value` (or removed when `None`).
    fn with(tag: Tag, value: Option<Value>) -> Metadata {
        let mut fields: Vec<Field> = good().into_iter().filter(|f| f.tag != tag).collect();
        if let Some(v) = value {
            fields.push(field(tag, v));
        }
        read(&tiff(&fields))
    }

    fn warned(meta: &Metadata, needle: &str) -> bool {
        meta.warnings.iter().any(|w| w.contains(needle))
    }

    #[test]
    fn reads_every_field_of_a_complete_block() {
        let m = read(&tiff(&good()));
        assert_eq!(m.warnings, Vec::<String>::new());
        assert_eq!(m.camera.make.as_deref(), Some("Nikon"));
        assert_eq!(m.camera.model.as_deref(), Some("Z 6"));
        assert_eq!(m.camera.serial.as_deref(), Some("6012345"));
        assert_eq!(m.camera.lens.as_deref(), Some("NIKKOR Z 24-70mm f/4 S"));
        assert_eq!(m.exposure.time_s, Some(0.004));
        assert_eq!(m.exposure.f_number, Some(5.6));
        assert_eq!(m.exposure.iso, Some(400.0));
        assert_eq!(m.orientation, 6);
        let t = m.captured_at.unwrap();
        assert_eq!(t.to_rfc3339(), "2026-03-14T09:26:53.125+02:00");
        // e = t·S/N² = 0.004 · 400 / 5.6²
        let e = m.exposure.relative().unwrap();
        assert!((e - 0.004 * 400.0 / (5.6 * 5.6)).abs() < 1e-12);
        // EV100 = log2(N²/t) − log2(S/100) = log2(31.36 · 250) − 2
        let ev = m.exposure.ev100().unwrap();
        assert!((ev - ((5.6f64 * 5.6 * 250.0).log2() - 2.0)).abs() < 1e-12);
    }

    #[test]
    fn iso_65535_falls_back_to_recommended_exposure_index_then_iso_speed() {
        let saturated = field(Tag::PhotographicSensitivity, Value::Short(vec![65535]));
        let mut fields: Vec<Field> = good()
            .into_iter()
            .filter(|f| f.tag != Tag::PhotographicSensitivity)
            .collect();
        fields.push(saturated);
        let mut rei = fields.clone();
        rei.push(field(
            Tag::RecommendedExposureIndex,
            Value::Long(vec![102_400]),
        ));
        rei.push(field(Tag::ISOSpeed, Value::Long(vec![99_999])));
        let m = read(&tiff(&rei));
        assert_eq!(m.exposure.iso, Some(102_400.0));
        assert!(m.warnings.is_empty(), "{:?}", m.warnings);

        let mut speed = fields.clone();
        speed.push(field(Tag::ISOSpeed, Value::Long(vec![81_920])));
        assert_eq!(read(&tiff(&speed)).exposure.iso, Some(81_920.0));

        let m = read(&tiff(&fields));
        assert_eq!(m.exposure.iso, None);
        assert!(
            warned(&m, "PhotographicSensitivity = 65535"),
            "{:?}",
            m.warnings
        );
    }

    #[test]
    fn absurd_values_become_unknown_with_a_warning_naming_the_tag() {
        let cases = [
            (Tag::ExposureTime, rational(0, 1), "ExposureTime = 0"),
            (Tag::ExposureTime, rational(1, 0), "ExposureTime = inf"),
            (
                Tag::ExposureTime,
                Value::SRational(vec![SRational { num: -1, denom: 60 }]),
                "ExposureTime = -0.01",
            ),
            (Tag::FNumber, rational(0, 10), "FNumber = 0"),
            (
                Tag::PhotographicSensitivity,
                Value::Short(vec![0]),
                "PhotographicSensitivity = 0",
            ),
        ];
        for (tag, value, needle) in cases {
            let m = with(tag, Some(value));
            assert!(warned(&m, needle), "{needle}: {:?}", m.warnings);
            assert!(warned(&m, "absurd"), "{needle}: {:?}", m.warnings);
            assert_eq!(m.exposure.relative(), None, "{needle}");
        }
        let m = with(Tag::DateTimeOriginal, Some(ascii("0000:00:00 00:00:00")));
        assert_eq!(m.captured_at, None);
        assert!(warned(&m, "DateTimeOriginal"), "{:?}", m.warnings);
        let m = with(Tag::DateTimeOriginal, Some(ascii("9999:12:31 23:59:59")));
        assert_eq!(m.captured_at, None);
        assert!(warned(&m, "placeholder (year 9999)"), "{:?}", m.warnings);
        let m = with(Tag::DateTimeOriginal, Some(ascii("2023:02:30 10:00:00")));
        assert_eq!(m.captured_at, None);
        assert!(warned(&m, "not a real date"), "{:?}", m.warnings);
        let m = with(Tag::Orientation, Some(Value::Short(vec![9])));
        assert_eq!(m.orientation, 1);
        assert!(warned(&m, "Orientation = 9"), "{:?}", m.warnings);
    }

    #[test]
    fn missing_tags_are_unknown_with_a_warning_naming_the_tag() {
        for (tag, needle) in [
            (Tag::ExposureTime, "ExposureTime missing"),
            (Tag::FNumber, "FNumber missing"),
            (
                Tag::PhotographicSensitivity,
                "PhotographicSensitivity missing",
            ),
            (Tag::DateTimeOriginal, "DateTimeOriginal missing"),
        ] {
            let m = with(tag, None);
            assert!(warned(&m, needle), "{needle}: {:?}", m.warnings);
        }
        let m = read(b"\xff\xd8\xff\xd9");
        assert_eq!(m.exposure, Exposure::default());
        assert!(warned(&m, "no EXIF"), "{:?}", m.warnings);
    }

    #[test]
    fn capture_time_without_sub_seconds_or_offset_is_plain_local_time() {
        let mut fields: Vec<Field> = good()
            .into_iter()
            .filter(|f| f.tag != Tag::SubSecTimeOriginal && f.tag != Tag::OffsetTimeOriginal)
            .collect();
        assert_eq!(
            read(&tiff(&fields)).captured_at.unwrap().to_rfc3339(),
            "2026-03-14T09:26:53"
        );
        fields.push(field(Tag::SubSecTimeOriginal, ascii("07")));
        fields.push(field(Tag::OffsetTimeOriginal, ascii("-05:30")));
        let m = read(&tiff(&fields));
        assert_eq!(
            m.captured_at.unwrap().to_rfc3339(),
            "2026-03-14T09:26:53.07-05:30"
        );
        let m = with(Tag::OffsetTimeOriginal, Some(ascii("+2:00")));
        assert_eq!(m.captured_at.unwrap().offset_minutes, None);
        assert!(warned(&m, "OffsetTimeOriginal"), "{:?}", m.warnings);
        let m = with(Tag::SubSecTimeOriginal, Some(ascii("1a")));
        assert_eq!(m.captured_at.unwrap().nanos, None);
        assert!(warned(&m, "SubSecTimeOriginal"), "{:?}", m.warnings);
        // Blank padding, as many cameras write, is not a warning.
        let m = with(Tag::SubSecTimeOriginal, Some(ascii("   ")));
        assert!(m.warnings.is_empty(), "{:?}", m.warnings);
    }

    #[test]
    fn local_seconds_counts_from_the_epoch() {
        let t = CaptureTime {
            year: 2000,
            month: 3,
            day: 1,
            hour: 0,
            minute: 0,
            second: 1,
            nanos: Some(500_000_000),
            offset_minutes: None,
        };
        // 2000-03-01 is day 11017 after 1970-01-01.
        assert_eq!(t.local_seconds(), 11_017.0 * 86_400.0 + 1.5);
    }

    #[test]
    fn civil_dates_and_day_counts_are_inverse() {
        for days in (-800_000..3_000_000).step_by(997) {
            let (y, m, d) = civil_from_days(days);
            assert!((1..=12).contains(&m) && (1..=31).contains(&d), "{days}");
            assert_eq!(days_from_civil(y, m, d), days, "{y}-{m}-{d}");
        }
        assert_eq!(civil_from_days(11_017), (2000, 3, 1));
        assert_eq!(civil_from_days(-1), (1969, 12, 31));
    }
}
