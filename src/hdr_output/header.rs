//! The OpenEXR header filmback writes: chromaticities, capture date, camera and exposure
//! of the longest frame (standard attributes), and filmback's own provenance attributes
//! (see the parent module for the list).

use exr::meta::attribute::Chromaticities;
use exr::prelude::{self as x, ImageAttributes, IntegerBounds, LayerAttributes, Text, Vec2};

use super::{Primaries, Provenance};

/// Text attribute from UTF-8 (OpenEXR strings are byte strings; readers take them as UTF-8).
pub(super) fn text(s: &str) -> Text {
    Text::from_slice_unchecked(s.as_bytes())
}

pub(super) fn image_attributes(size: Vec2<usize>, primaries: Primaries) -> ImageAttributes {
    let mut attributes = ImageAttributes::new(IntegerBounds::from_dimensions(size));
    let [r, g, b, w] = primaries.gamut().0.map(|(x, y)| Vec2(x as f32, y as f32));
    attributes.chromaticities = Some(Chromaticities {
        red: r,
        green: g,
        blue: b,
        white: w,
    });
    attributes
}

/// The layer's attributes from the provenance `p`: the capture date, the longest
/// frame's exposure, the camera, each frame, the response, the scale (the file's values
/// are the radiance times `scale`) and the `primaries`' interop id.
// Kept whole: a linear list of the header's attributes, each set from the provenance;
// split, it would only scatter them.
pub(super) fn layer_attributes(
    p: &Provenance,
    scale: f32,
    primaries: Primaries,
) -> LayerAttributes {
    use x::AttributeValue as V;
    let mut a = LayerAttributes {
        software_name: Some(text(&format!("filmback {}", env!("CARGO_PKG_VERSION")))),
        ..LayerAttributes::default()
    };
    if let Some(t) = p.captured_at {
        // OpenEXR's capDate is "YYYY:MM:DD hh:mm:ss" local time; utcOffset is the
        // seconds to add to it to get UTC.
        a.capture_date = Some(text(&format!(
            "{:04}:{:02}:{:02} {:02}:{:02}:{:02}",
            t.year, t.month, t.day, t.hour, t.minute, t.second
        )));
        a.utc_offset = t.offset_minutes.map(|m| -f32::from(m) * 60.0);
    }
    if let Some(longest) = p.frames.last() {
        a.exposure = longest.exposure.time_s.map(|v| v as f32);
        a.aperture = longest.exposure.f_number.map(|v| v as f32);
        a.iso_speed = longest.exposure.iso.map(|v| v as f32);
    }
    a.comments = Some(text(match p.scale.white_luminance() {
        Some(_) => "linear scene luminance in cd/m2 (see whiteLuminance and filmbackScale)",
        None => "linear relative radiance; 1.0 = brightness g^-1(1) in the longest exposure",
    }));
    // cd/m² of RGB (1, 1, 1) in the file: the half-overflow factor divides it.
    a.white_luminance = p
        .scale
        .white_luminance()
        .map(|l| (l / f64::from(scale)) as f32);
    let mut put = |name: &str, value: V| {
        a.other.insert(text(name), value);
    };
    for (name, value) in [
        ("cameraMake", &p.camera.make),
        ("cameraModel", &p.camera.model),
        ("cameraSerialNumber", &p.camera.serial),
        ("lensModel", &p.camera.lens),
    ] {
        if let Some(v) = value {
            put(name, V::Text(text(v)));
        }
    }
    let known = |v: Option<f64>| v.map_or("?".to_string(), |v| format!("{v}"));
    for (k, f) in p.frames.iter().enumerate() {
        put(
            &format!("filmbackFrame{k}"),
            V::Text(text(&format!(
                "{}: time {} s, f/{}, ISO {}, relative exposure {}",
                f.name,
                known(f.exposure.time_s),
                known(f.exposure.f_number),
                known(f.exposure.iso),
                f.relative
            ))),
        );
    }
    if let (Some(first), Some(last)) = (p.frames.first(), p.frames.last()) {
        put(
            "filmbackExposureRatio",
            V::F64(last.relative / first.relative),
        );
    }
    put("filmbackResponse", V::Text(text(&p.response)));
    put("filmbackWeighting", V::Text(text(&p.weighting)));
    put(
        "filmbackClipped",
        V::Text(text(&format!(
            "{} samples clipped high in every frame (lower bounds), {} clipped low (upper bounds)",
            p.clipped.0, p.clipped.1
        ))),
    );
    if let Some(deghost) = &p.deghost {
        put("filmbackDeghost", V::Text(text(deghost)));
    }
    if let Some(alignment) = &p.alignment {
        put("filmbackAlignment", V::Text(text(alignment)));
    }
    put("filmbackScale", V::Text(text(&p.scale.describe())));
    put("filmbackScaleKind", V::Text(text(p.scale.kind())));
    put("colorInteropID", V::Text(text(primaries.interop_id())));
    put("filmbackRadianceScale", V::F32(scale));
    a
}
