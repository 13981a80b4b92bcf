//! The HDR still: a look written as a gain-map JPEG (Ultra HDR, ISO 21496-1,
//! `--format ultrahdr`). Every viewer shows its primary image, the look's SDR rendering
//! exactly as a plain JPEG of the look holds it; a viewer on an HDR display (Chromium
//! and Chrome from M116, Android 14, recent Apple systems) multiplies it by the gain map
//! and shows the highlights the look compressed up to [`HEADROOM_STOPS`] above SDR white.
//!
//! # The HDR rendition
//!
//! In linear light of the base's primaries, with SDR white at 1:
//!
//! `HDR_c = SDR_c · boost(k·Y)`,
//!
//! `Y` the pixel's scene luminance (Rec. 709 weights of the radiance map), `k` the scale
//! that puts the scene on the look's mid-tones ([`scene_scale`]: the median of
//! `Y_sdr/Y` over pixels whose SDR luminance is within [`MIDTONES`]), and
//!
//! `boost(x) = 1` for `x ≤ 1`, `1 + (P − 1)·(1 − e^{−(x − 1)/(P − 1)})` above, `P = 2^HEADROOM_STOPS`:
//!
//! what a linear rendering at the look's mid-tone exposure would put at or below white is
//! left as the look has it; above, the boost rises with slope 1 and approaches the peak
//! `P` (a highlight 2 stops over that white is boosted 2.9×, 4 stops over 4.0× to 1 %).
//! One scalar per pixel, so the look's colours are kept. With SDR white at BT.2408's
//! 203 cd/m², the peak is 812 cd/m².
//!
//! # The gain map
//!
//! One 8-bit channel at full resolution: the code of `log₂ boost(k·Y)` on `[0,
//! HEADROOM_STOPS]` stops, gamma 1, offsets 0 ([`metadata`]), so a display with headroom
//! `H ≥ P` shows `SDR · 2^(L)` = the rendition above to quantisation (±1/255 of the span:
//! ±0.4 % in linear light, before JPEG), and one with `1 < H < P` shows it with the log
//! gain scaled by `log₂H / HEADROOM_STOPS`.

use std::io::Write;

use rayon::prelude::*;
use rusty_jpeg::encode::{ColorType, Encoder};

use super::gain_map;
pub use super::gain_map::GainMapMetadata;
use super::source_exif::Storage;
use super::{Format, ImageEncodeError, Look, RenderingError, Shrink, SourceExif, jpeg};
use crate::display::{ColourSpace, Depth, DisplayImage, luminance};
use crate::radiance::RadianceSource;

/// Peak of the HDR rendition over SDR white, in stops: 2, i.e. 4× SDR white (812 cd/m²
/// for BT.2408's 203 cd/m² white).
pub const HEADROOM_STOPS: f32 = 2.0;

/// The linear SDR luminance of the pixels [`scene_scale`] fits the scale on: mid-tones,
/// away from the look's toe and shoulder.
pub const MIDTONES: (f32, f32) = (0.05, 0.5);

/// Fewest mid-tone pixels [`scene_scale`] fits on; with fewer the scale comes from every
/// pixel the look shows above black.
const MIN_SAMPLES: usize = 64;

/// [`scene_scale`] reads every `STRIDE`-th pixel of every `STRIDE`-th row.
const STRIDE: usize = 4;

/// `boost(x)` of the module's formula: 1 up to `x = 1`, then rising with slope 1 towards
/// `2^HEADROOM_STOPS`. NaN and negatives give 1.
pub fn boost(x: f32) -> f32 {
    let peak = HEADROOM_STOPS.exp2();
    if x.is_nan() || x <= 1.0 {
        return 1.0;
    }
    1.0 + (peak - 1.0) * (1.0 - (-(x - 1.0) / (peak - 1.0)).exp())
}

/// The gain map's metadata: log₂ gains on `[0, HEADROOM_STOPS]`, gamma 1, offsets 0,
/// applied from a headroom of 1 (none) in proportion up to `2^HEADROOM_STOPS`.
pub fn metadata() -> GainMapMetadata {
    GainMapMetadata {
        min_log2: 0.0,
        max_log2: HEADROOM_STOPS,
        gamma: 1.0,
        offset_sdr: 0.0,
        offset_hdr: 0.0,
        capacity_min_log2: 0.0,
        capacity_max_log2: HEADROOM_STOPS,
    }
}

/// Rec. 709 luminance of `pixel` of `map` (its value for a grey map).
fn scene_luminance(map: &dyn RadianceSource, pixel: usize) -> f32 {
    if map.channels() >= 3 {
        luminance(
            map.sample(pixel, 0),
            map.sample(pixel, 1),
            map.sample(pixel, 2),
        )
    } else {
        map.sample(pixel, 0)
    }
}

/// The scale `k` that puts the scene luminance `Y` of `map` on the linear luminance of
/// its SDR rendering `sdr` (8-bit RGB encoded for `space`, `Y_sdr` with Rec. 709 weights):
/// the median of `Y_sdr/Y` over the pixels with `Y_sdr` within [`MIDTONES`] and `Y > 0`
/// (every 4th pixel of every 4th row); over every pixel with `Y_sdr > 0`
/// when fewer than 64 are mid-tones; 0 (no boost anywhere) when none is.
pub fn scene_scale(map: &dyn RadianceSource, sdr: &[u8], space: ColourSpace) -> f32 {
    let (w, h) = (map.width() as usize, map.height() as usize);
    let decode: Vec<f32> = (0..=255u8)
        .map(|v| space.decode(f32::from(v) / 255.0))
        .collect();
    let mut ratios = Vec::new();
    let mut fallback = Vec::new();
    for y in (0..h).step_by(STRIDE) {
        for x in (0..w).step_by(STRIDE) {
            let i = y * w + x;
            let Some(rgb) = sdr.get(3 * i..3 * i + 3) else {
                continue;
            };
            let shown = luminance(
                decode[usize::from(rgb[0])],
                decode[usize::from(rgb[1])],
                decode[usize::from(rgb[2])],
            );
            let scene = scene_luminance(map, i);
            if !(scene > 0.0 && scene.is_finite() && shown > 0.0) {
                continue;
            }
            if (MIDTONES.0..=MIDTONES.1).contains(&shown) {
                ratios.push(shown / scene);
            } else {
                fallback.push(shown / scene);
            }
        }
    }
    if ratios.len() < MIN_SAMPLES {
        ratios.extend(fallback);
    }
    if ratios.is_empty() {
        return 0.0;
    }
    let middle = ratios.len() / 2;
    *ratios.select_nth_unstable_by(middle, f32::total_cmp).1
}

/// The gain map of `map` at scale `k` ([`scene_scale`]): per pixel, row-major, the code
/// ([`GainMapMetadata::code`] of [`metadata`]) of `log₂ boost(k·Y)`.
pub fn gain_map(map: &dyn RadianceSource, k: f32) -> Vec<u8> {
    let (w, h) = (map.width() as usize, map.height() as usize);
    let m = metadata();
    let mut codes = vec![0u8; w * h];
    codes
        .par_chunks_mut(w.max(1))
        .enumerate()
        .for_each(|(y, row)| {
            for (x, code) in row.iter_mut().enumerate() {
                let scene = scene_luminance(map, y * w + x);
                *code = m.code(boost(k * scene).log2());
            }
        });
    codes
}

/// Encodes `look` of `map` as a gain-map JPEG at `quality` (base and gain map) for
/// `space` into `out`, with the source frame's EXIF and the space's ICC profile; adds the
/// sRGB rendering's rows to `shrink`. The base is developed whole (`3·P` bytes for `P`
/// pixels), then the gain map (`P` bytes) and both JPEGs are held until the file is
/// joined.
pub(super) fn encode(
    map: &dyn RadianceSource,
    look: &Look,
    quality: u8,
    space: ColourSpace,
    exif: &SourceExif,
    out: &mut impl Write,
    shrink: Option<&Shrink>,
) -> Result<(), RenderingError> {
    let failed = |source: ImageEncodeError| RenderingError::Encode {
        path: Default::default(),
        format: Format::UltraHdr { quality },
        source,
    };
    let depth = if space == ColourSpace::Srgb {
        Depth::Eight
    } else {
        Depth::Sixteen
    };
    // The pixels the plain JPEG of the look holds: a tone map to an sRGB JPEG is
    // prepared from the streamed histogram, as `encode_look` does.
    let srgb = match look {
        Look::Tonemap(op) if space == ColourSpace::Srgb => {
            let (w, h) = (map.width(), map.height());
            let mut rgb = vec![0u8; w as usize * h as usize * 3];
            op.prepare(map).render_rows_8bit(map, 0, &mut rgb);
            DisplayImage::new_8bit(w, h, rgb)
        }
        _ => look.render(map, depth)?,
    };
    if let Some(shrink) = shrink {
        shrink.add_rows(0, &srgb.to_u8());
    }
    let base = srgb.in_space(space).at_depth(Depth::Eight);
    let rgb = base.to_u8();
    let (w, h) = (base.width(), base.height());
    let k = scene_scale(map, &rgb, space);
    let gains = gain_map(map, k);
    let gain_jpeg = encode_gain_map(w, h, &gains, quality).map_err(failed)?;
    let block = exif
        .tiff_block(w, h, Storage::Jpeg)
        .map_err(|e| failed(e.into()))?;
    let xmp = gain_map::xmp_payload(&gain_map::primary_xmp(gain_jpeg.len()));
    let decorate = |encoder: &mut Encoder<&mut Vec<u8>>| {
        encoder.add_app_segment(1, [&b"Exif\0\0"[..], &block].concat())?;
        encoder.add_app_segment(1, xmp.clone())?;
        encoder.add_icc_profile(space.icc_profile())?;
        encoder.add_app_segment(2, gain_map::iso_version_payload())
    };
    let row = w as usize * 3;
    let copy = |first: usize, band: &mut [u8]| {
        band.copy_from_slice(&rgb[first * row..][..band.len()]);
    };
    let mut primary = Vec::with_capacity(rgb.len() / 4);
    jpeg::encode_bands(w, h, quality, decorate, copy, &mut primary).map_err(failed)?;
    let file = gain_map::assemble(&primary, &gain_jpeg).map_err(failed)?;
    out.write_all(&file).map_err(|e| failed(e.into()))
}

/// The gain map as a one-channel baseline JPEG at `quality`, carrying [`metadata`] as XMP
/// (APP1) and ISO 21496-1 (APP2).
fn encode_gain_map(w: u32, h: u32, codes: &[u8], quality: u8) -> Result<Vec<u8>, ImageEncodeError> {
    let too_large = || ImageEncodeError::JpegTooLarge {
        width: w,
        height: h,
    };
    let w16 = u16::try_from(w).map_err(|_| too_large())?;
    let h16 = u16::try_from(h).map_err(|_| too_large())?;
    let m = metadata();
    let mut bytes = Vec::with_capacity(codes.len() / 8);
    let mut encoder = Encoder::new(&mut bytes, quality);
    encoder.add_app_segment(1, gain_map::xmp_payload(&gain_map::gain_map_xmp(&m)))?;
    encoder.add_app_segment(2, gain_map::iso_metadata_payload(&m))?;
    encoder.encode(codes, w16, h16, ColorType::Luma)?;
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::radiance::RadianceMap;

    #[test]
    fn the_boost_is_one_up_to_white_then_rises_to_the_peak() {
        let peak = HEADROOM_STOPS.exp2();
        assert_eq!(boost(0.0), 1.0);
        assert_eq!(boost(1.0), 1.0);
        assert_eq!(boost(f32::NAN), 1.0);
        assert_eq!(boost(-3.0), 1.0);
        // Slope 1 just above white, monotone (strictly where f32 resolves it), never
        // above the peak, near it 4 stops over.
        assert!((boost(1.001) - 1.001).abs() < 1e-5);
        let mut last = 1.0;
        for i in 1..400 {
            let b = boost(1.0 + i as f32 * 0.1);
            assert!(b >= last && b <= peak, "{i}: {b}");
            assert!(i > 100 || b > last, "{i}: {b}");
            last = b;
        }
        assert!((boost(4.0) - 2.896).abs() < 1e-3);
        assert!(boost(16.0) > 0.99 * peak);
        assert!(boost(f32::INFINITY) <= peak);
    }

    #[test]
    fn the_scale_is_the_midtone_ratio_and_the_gain_follows_it() {
        // A grey ramp 0.01..10 rendered as sRGB of min(Y/4, 1): k = 1/4.
        let (w, h) = (256u32, 16u32);
        let values: Vec<f32> = (0..w * h)
            .map(|i| 0.01 * 1000f32.powf((i % w) as f32 / (w - 1) as f32))
            .collect();
        let map = RadianceMap::new(w, h, 1, values.clone()).unwrap();
        let sdr: Vec<u8> = values
            .iter()
            .flat_map(|&y| {
                let v = (ColourSpace::Srgb.encode(y / 4.0) * 255.0).round() as u8;
                [v, v, v]
            })
            .collect();
        let k = scene_scale(&map, &sdr, ColourSpace::Srgb);
        assert!((k - 0.25).abs() < 0.01, "{k}");
        let codes = gain_map(&map, k);
        let m = metadata();
        for (i, &y) in values.iter().enumerate() {
            let expected = boost(k * y).log2();
            assert!(
                (m.log2_gain(codes[i]) - expected).abs() <= 1.0 / 255.0,
                "{i}"
            );
        }
        // Dark and blank renderings: no boost.
        assert_eq!(
            scene_scale(&map, &vec![0; sdr.len()], ColourSpace::Srgb),
            0.0
        );
        assert!(gain_map(&map, 0.0).iter().all(|&c| c == 0));
    }
}
