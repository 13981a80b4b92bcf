//! The display end of the pipeline: an RGB image at 8 or 16 bits, developed for sRGB
//! and re-encoded for a wide-gamut display on request ([`ColourSpace`]), the transfer
//! functions and ICC profiles, and Rec. 709 luminance. Film stocks and tone maps
//! produce a [`DisplayImage`]; the rendering encoders write it.

use std::borrow::Cow;
use std::sync::OnceLock;

use rayon::prelude::*;

use crate::radiance::Gamut;

/// Rec. 709 / sRGB luminance of linear RGB: `L = 0.2126 R + 0.7152 G + 0.0722 B`.
pub fn luminance(r: f32, g: f32, b: f32) -> f32 {
    0.2126 * r + 0.7152 * g + 0.0722 * b
}

/// Bits per sample of a display image.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Depth {
    /// 8 bits (JPEG, PNG 8).
    Eight,
    /// 16 bits (PNG 16, TIFF 16).
    Sixteen,
}

/// A display image: RGB encoded for a display ([`ColourSpace`], sRGB unless
/// [`DisplayImage::in_space`] re-encoded it), 8 or 16 bits per sample.
#[derive(Debug, Clone, PartialEq)]
pub struct DisplayImage {
    width: u32,
    height: u32,
    samples: Samples,
    space: ColourSpace,
}

#[derive(Debug, Clone, PartialEq)]
enum Samples {
    Eight(Vec<u8>),
    Sixteen(Vec<u16>),
}

/// `round(v · 255 / 65535)`: a 16-bit sample at 8 bits.
#[inline]
pub fn to_8bit(v: u16) -> u8 {
    ((u32::from(v) * 255 + 32767) / 65535) as u8
}

impl DisplayImage {
    /// Wraps interleaved 16-bit RGB samples (`width·height·3` of them).
    ///
    /// # Panics
    /// If the length does not match: callers build the buffer from the same dimensions.
    pub fn new(width: u32, height: u32, samples: Vec<u16>) -> DisplayImage {
        assert_eq!(samples.len(), width as usize * height as usize * 3);
        DisplayImage {
            width,
            height,
            samples: Samples::Sixteen(samples),
            space: ColourSpace::Srgb,
        }
    }

    /// Wraps interleaved 8-bit RGB samples.
    ///
    /// # Panics
    /// If the length does not match.
    pub(crate) fn new_8bit(width: u32, height: u32, samples: Vec<u8>) -> DisplayImage {
        assert_eq!(samples.len(), width as usize * height as usize * 3);
        DisplayImage {
            width,
            height,
            samples: Samples::Eight(samples),
            space: ColourSpace::Srgb,
        }
    }

    /// Width in pixels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// The display the samples are encoded for.
    pub fn space(&self) -> ColourSpace {
        self.space
    }

    /// Bits per sample.
    pub fn depth(&self) -> Depth {
        match self.samples {
            Samples::Eight(_) => Depth::Eight,
            Samples::Sixteen(_) => Depth::Sixteen,
        }
    }

    /// Interleaved encoded RGB at 16 bits (8-bit images scaled by 257).
    pub fn samples(&self) -> Cow<'_, [u16]> {
        match &self.samples {
            Samples::Sixteen(s) => Cow::Borrowed(s),
            Samples::Eight(s) => Cow::Owned(s.iter().map(|&v| u16::from(v) * 257).collect()),
        }
    }

    /// Interleaved encoded RGB at 8 bits ([`to_8bit`] of 16-bit images).
    pub fn to_u8(&self) -> Cow<'_, [u8]> {
        match &self.samples {
            Samples::Eight(s) => Cow::Borrowed(s),
            Samples::Sixteen(s) => {
                let mut out = vec![0u8; s.len()];
                out.par_chunks_mut(1 << 16)
                    .zip(s.par_chunks(1 << 16))
                    .for_each(|(o, s)| {
                        for (o, &s) in o.iter_mut().zip(s) {
                            *o = to_8bit(s);
                        }
                    });
                Cow::Owned(out)
            }
        }
    }

    /// The image at `depth` (a copy only when it differs).
    pub(crate) fn at_depth(self, depth: Depth) -> DisplayImage {
        let samples = match (depth, &self.samples) {
            (Depth::Eight, Samples::Sixteen(_)) => Samples::Eight(self.to_u8().into_owned()),
            (Depth::Sixteen, Samples::Eight(_)) => Samples::Sixteen(self.samples().into_owned()),
            _ => return self,
        };
        DisplayImage { samples, ..self }
    }
}

/// The sRGB transfer function (IEC 61966-2.1): linear `x ∈ [0,1]` to encoded value;
/// `12.92·x` below 0.0031308, `1.055·x^(1/2.4) − 0.055` above. Out-of-range and NaN
/// inputs clamp to `[0, 1]` (NaN to 0).
pub fn srgb_encode(x: f32) -> f32 {
    if x.is_nan() || x <= 0.0 {
        0.0
    } else if x >= 1.0 {
        1.0
    } else if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    }
}

/// `round(65535 · srgb_encode(x))` through a table: below 2⁻¹² (on the linear segment) it
/// is computed, above it looked up by the float's exponent and 11 mantissa bits at the
/// bucket centre — at most 1.1·10⁻⁴ relative error, under 7 of 65535 (0.03 of an 8-bit
/// step). Any `f32` is valid: NaN and negatives give 0, 1 and above 65535.
#[inline]
pub fn srgb_encode_u16(x: f32) -> u16 {
    const SHIFT: u32 = 12;
    static TABLE: OnceLock<(u32, Vec<u16>)> = OnceLock::new();
    let low = 2f32.powi(-12);
    if x.is_nan() || x <= 0.0 {
        return 0;
    }
    if x >= 1.0 {
        return 65535;
    }
    if x < low {
        return (12.92 * x * 65535.0).round() as u16;
    }
    let (base, table) = TABLE.get_or_init(|| {
        let base = low.to_bits() >> SHIFT;
        let top = 1f32.to_bits() >> SHIFT;
        let table = (base..top)
            .map(|i| {
                let centre = f32::from_bits((i << SHIFT) | (1 << (SHIFT - 1)));
                (srgb_encode(centre) * 65535.0).round() as u16
            })
            .collect();
        (base, table)
    });
    table[((x.to_bits() >> SHIFT) - base) as usize]
}

/// `to_8bit(srgb_encode_u16(x))` in one look-up: the same value for every `f32`, from a
/// table of the same buckets holding the 8-bit codes.
#[inline]
pub(crate) fn srgb_encode_u8(x: f32) -> u8 {
    const SHIFT: u32 = 12;
    static TABLE: OnceLock<(u32, Vec<u8>)> = OnceLock::new();
    let low = 2f32.powi(-12);
    if !(x >= low && x < 1.0) {
        return to_8bit(srgb_encode_u16(x));
    }
    let (base, table) = TABLE.get_or_init(|| {
        let base = low.to_bits() >> SHIFT;
        let top = 1f32.to_bits() >> SHIFT;
        let table = (base..top)
            .map(|i| to_8bit(srgb_encode_u16(f32::from_bits(i << SHIFT))))
            .collect();
        (base, table)
    });
    table[((x.to_bits() >> SHIFT) - base) as usize]
}

/// The display a rendering is encoded for: its primaries (all with a D65 white) and
/// transfer function. Looks are developed in linear Rec. 709 light; a wider space holds
/// the same colours (`rgb_space = M · rgb_709`, [`Gamut::matrix_to`]) in a container a
/// wide-gamut pipeline takes as it is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ColourSpace {
    /// sRGB (IEC 61966-2.1): Rec. 709 primaries, the sRGB transfer function (default).
    #[default]
    Srgb,
    /// Display P3: P3 primaries (SMPTE EG 432-1), D65, the sRGB transfer function.
    #[serde(rename = "p3")]
    DisplayP3,
    /// ITU-R BT.2020 primaries, D65, the BT.2020 / BT.709 transfer function
    /// (`V = 4.5·L` below `β = 0.018054`, `α·L^0.45 − (α − 1)` above, `α = 1.099297`).
    Rec2020,
}

impl ColourSpace {
    /// Every space, in the order the docs list them.
    pub const ALL: [ColourSpace; 3] = [
        ColourSpace::Srgb,
        ColourSpace::DisplayP3,
        ColourSpace::Rec2020,
    ];

    /// The name as typed (`--colour-space p3`, `colour_space = "rec2020"`).
    pub fn name(self) -> &'static str {
        match self {
            ColourSpace::Srgb => "srgb",
            ColourSpace::DisplayP3 => "p3",
            ColourSpace::Rec2020 => "rec2020",
        }
    }

    /// The space's primaries and white.
    pub fn gamut(self) -> Gamut {
        match self {
            ColourSpace::Srgb => Gamut::REC709,
            ColourSpace::DisplayP3 => Gamut::DISPLAY_P3,
            ColourSpace::Rec2020 => Gamut::REC2020,
        }
    }

    /// The code value of linear display light `l` (clamped to `[0, 1]`, NaN to 0).
    pub fn encode(self, l: f32) -> f32 {
        match self {
            ColourSpace::Srgb | ColourSpace::DisplayP3 => srgb_encode(l),
            ColourSpace::Rec2020 => rec2020_encode(l),
        }
    }

    /// The linear display light of code value `v ∈ [0, 1]` (the inverse of [`Self::encode`]).
    pub fn decode(self, v: f32) -> f32 {
        match self {
            ColourSpace::Srgb | ColourSpace::DisplayP3 => srgb_decode(v),
            ColourSpace::Rec2020 => rec2020_decode(v),
        }
    }

    /// The ITU-T H.273 code points of a PNG `cICP` chunk: colour primaries (1 BT.709,
    /// 12 P3 D65, 9 BT.2020), transfer (13 sRGB, 1 BT.709), matrix 0 (RGB), full range 1.
    pub fn cicp(self) -> [u8; 4] {
        match self {
            ColourSpace::Srgb => [1, 13, 0, 1],
            ColourSpace::DisplayP3 => [12, 13, 0, 1],
            ColourSpace::Rec2020 => [9, 1, 0, 1],
        }
    }

    /// The ICC profile embedded in every file of this space, built by the `moxcms` crate
    /// (colorants adapted to the D50 PCS, the transfer function as a parametric curve),
    /// with a fixed creation date so that the same rendering gives the same file.
    pub fn icc_profile(self) -> &'static [u8] {
        static PROFILES: [OnceLock<Vec<u8>>; 3] =
            [OnceLock::new(), OnceLock::new(), OnceLock::new()];
        let (slot, build): (usize, fn() -> moxcms::ColorProfile) = match self {
            ColourSpace::Srgb => (0, moxcms::ColorProfile::new_srgb),
            ColourSpace::DisplayP3 => (1, moxcms::ColorProfile::new_display_p3),
            ColourSpace::Rec2020 => (2, moxcms::ColorProfile::new_bt2020),
        };
        PROFILES[slot].get_or_init(|| fixed_date_profile(build()))
    }
}

/// A colour space's name that is none of [`ColourSpace`]'s.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0:?} is not a colour space: expected srgb, p3 or rec2020")]
pub struct UnknownColourSpace(pub String);

impl std::str::FromStr for ColourSpace {
    type Err = UnknownColourSpace;

    /// `srgb`, `p3` (or `display-p3`), `rec2020` (or `bt2020`), any case.
    fn from_str(text: &str) -> Result<ColourSpace, UnknownColourSpace> {
        match text.trim().to_ascii_lowercase().as_str() {
            "srgb" => Ok(ColourSpace::Srgb),
            "p3" | "display-p3" | "displayp3" => Ok(ColourSpace::DisplayP3),
            "rec2020" | "bt2020" | "rec.2020" => Ok(ColourSpace::Rec2020),
            _ => Err(UnknownColourSpace(text.to_string())),
        }
    }
}

/// BT.2020's transfer function (the BT.709 OETF at 12-bit precision) of linear `l`,
/// clamped to `[0, 1]` (NaN to 0).
fn rec2020_encode(l: f32) -> f32 {
    const ALPHA: f32 = 1.099_296_8;
    const BETA: f32 = 0.018_053_97;
    if l.is_nan() || l <= 0.0 {
        0.0
    } else if l >= 1.0 {
        1.0
    } else if l < BETA {
        4.5 * l
    } else {
        ALPHA * l.powf(0.45) - (ALPHA - 1.0)
    }
}

/// Linear light of a BT.2020 code value `v ∈ [0, 1]` (the inverse of
/// [`rec2020_encode`]): `v / 4.5` below `4.5·β`, `((v + α − 1) / α)^(1/0.45)` above.
fn rec2020_decode(v: f32) -> f32 {
    const ALPHA: f32 = 1.099_296_8;
    const BETA: f32 = 0.018_053_97;
    if v < 4.5 * BETA {
        v / 4.5
    } else {
        ((v + (ALPHA - 1.0)) / ALPHA).powf(1.0 / 0.45)
    }
}

/// Linear light of an sRGB code value `v ∈ [0, 1]` (the inverse of [`srgb_encode`]).
pub fn srgb_decode(v: f32) -> f32 {
    if v <= 0.040_45 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

impl DisplayImage {
    /// The image, developed for sRGB, encoded for `space` instead: each pixel decoded to
    /// linear Rec. 709 light, taken to the space's primaries, clamped to `[0, 1]` and
    /// encoded with its transfer function at the image's depth. sRGB returns it as is.
    pub fn in_space(self, space: ColourSpace) -> DisplayImage {
        if space == ColourSpace::Srgb {
            return self;
        }
        let m = Gamut::REC709
            .matrix_to(space.gamut())
            .map(|row| row.map(|v| v as f32));
        let depth = self.depth();
        let decode: Vec<f32> = (0..=u16::MAX)
            .map(|v| srgb_decode(f32::from(v) / 65535.0))
            .collect();
        let mut samples = self.samples().into_owned();
        samples.par_chunks_mut(3 << 12).for_each(|band| {
            for px in band.chunks_exact_mut(3) {
                let l = [0, 1, 2].map(|c| decode[usize::from(px[c])]);
                for (out, row) in px.iter_mut().zip(&m) {
                    let v = row[0] * l[0] + row[1] * l[1] + row[2] * l[2];
                    *out = (space.encode(v) * 65535.0).round() as u16;
                }
            }
        });
        let wide = DisplayImage {
            samples: Samples::Sixteen(samples),
            space,
            ..self
        };
        wide.at_depth(depth)
    }
}

/// The sRGB ICC profile ([`ColourSpace::icc_profile`]): the IEC 61966-2.1 colorants
/// (primaries x,y = 0.64,0.33 / 0.30,0.60 / 0.15,0.06, D65 white, adapted to the D50 PCS)
/// and the sRGB parametric tone curve (γ 2.4, linear toe below 0.04045); about 0.5 kB.
#[cfg(test)]
fn srgb_icc_profile() -> &'static [u8] {
    ColourSpace::Srgb.icc_profile()
}

/// `profile` encoded without its `cicp` tag (moxcms tags its profiles with code points for
/// limited-range Y'CbCr video, matrix BT.709, narrow range; the colorants and curves say
/// all there is), its creation date (header bytes 24–35, which the encoder sets to the
/// time of encoding; the profile carries no MD5 ID that would cover it) fixed at
/// IEC 61966-2-1's publication, 1999-10-18 00:00:00.
fn fixed_date_profile(mut profile: moxcms::ColorProfile) -> Vec<u8> {
    profile.cicp = None;
    let mut bytes = profile
        .encode()
        .unwrap_or_else(|e| panic!("moxcms cannot encode its own profile: {e:?}"));
    let date: Vec<u8> = [1999u16, 10, 18, 0, 0, 0]
        .iter()
        .flat_map(|v| v.to_be_bytes())
        .collect();
    bytes[24..36].copy_from_slice(&date);
    bytes
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The profile is an sRGB display profile whose header reads back with the fixed
    /// creation date and no profile ID.
    #[test]
    fn the_icc_profile_has_a_fixed_date() {
        let icc = srgb_icc_profile();
        assert_eq!(&icc[36..40], b"acsp");
        assert_eq!(&icc[12..20], b"mntrRGB ");
        let read = moxcms::ColorProfile::new_from_slice(icc).unwrap();
        let date = read.creation_date_time;
        assert_eq!(
            (date.year, date.month, date.day_of_the_month),
            (1999, 10, 18)
        );
        assert_eq!((date.hours, date.minutes, date.seconds), (0, 0, 0));
        assert!(icc[84..100].iter().all(|&b| b == 0), "no MD5 profile ID");
    }

    /// The 8-bit table gives exactly the 16-bit encoder's value at 8 bits, for every
    /// bucket of the table and the values around and outside it.
    #[test]
    fn srgb_encode_u8_is_the_16_bit_value_at_8_bits() {
        let mut x = 1e-6f32;
        while x < 1.5 {
            assert_eq!(srgb_encode_u8(x), to_8bit(srgb_encode_u16(x)), "{x}");
            x = f32::from_bits(x.to_bits() + 997);
        }
        for x in [f32::NAN, -1.0, 0.0, 2f32.powi(-12), 1.0, f32::INFINITY] {
            assert_eq!(srgb_encode_u8(x), to_8bit(srgb_encode_u16(x)), "{x}");
        }
    }

    #[test]
    fn icc_profile_is_a_valid_srgb_profile() {
        let p = srgb_icc_profile();
        let size = u32::from_be_bytes([p[0], p[1], p[2], p[3]]) as usize;
        assert_eq!(size, p.len());
        assert_eq!(&p[36..40], b"acsp");
        assert_eq!(&p[12..16], b"mntr");
        assert_eq!(&p[16..20], b"RGB ");
        assert_eq!(&p[20..24], b"XYZ ");
        // ICC.1 §7.2.16: the PCS illuminant is D50 exactly, as s15Fixed16 numbers.
        let be = |at: usize| u32::from_be_bytes([p[at], p[at + 1], p[at + 2], p[at + 3]]);
        assert_eq!([be(68), be(72), be(76)], [0xF6D6, 0x1_0000, 0xD32D]);
        // §7.3.1: every tagged element starts on a 4-byte boundary, inside the profile.
        let tags = be(128) as usize;
        for k in 0..tags {
            let (offset, length) = (be(132 + 12 * k + 4) as usize, be(132 + 12 * k + 8) as usize);
            assert_eq!(offset % 4, 0, "tag {k} at {offset}");
            assert!(
                offset >= 132 + 12 * tags && offset + length <= size,
                "tag {k}"
            );
            // ICC.1:2022 §10.3: on RGB data a `cicp` tag says identity matrix, full range;
            // anything else tells a reader the pixels are limited-range video.
            if &p[132 + 12 * k..136 + 12 * k] == b"cicp" {
                assert_eq!(&p[offset + 10..offset + 12], &[0, 1], "cicp matrix, range");
            }
        }
        let profile = moxcms::ColorProfile::new_from_slice(p).expect("parses back");
        // Published D50-adapted colorants of IEC 61966-2.1 (red X,Y,Z).
        let r = profile.red_colorant;
        assert!(
            (r.x - 0.4361).abs() < 1e-3 && (r.y - 0.2225).abs() < 1e-3,
            "{r:?}"
        );
    }

    #[test]
    fn srgb_encode_is_clamped_and_continuous() {
        assert_eq!(srgb_encode(f32::NAN), 0.0);
        assert_eq!(srgb_encode(-1.0), 0.0);
        assert_eq!(srgb_encode(f32::INFINITY), 1.0);
        let a = srgb_encode(0.003_130_8);
        let b = srgb_encode(0.003_130_9);
        assert!((a - b).abs() < 1e-4);
        assert!((srgb_encode(0.18) - 0.4613).abs() < 1e-3);
    }

    #[test]
    fn srgb_table_matches_the_formula() {
        let mut worst = 0i32;
        for i in 0..=200_000 {
            let x = 10f32.powf(-6.0 + 6.0 * i as f32 / 200_000.0);
            let exact = (srgb_encode(x) * 65535.0).round() as i32;
            worst = worst.max((i32::from(srgb_encode_u16(x)) - exact).abs());
        }
        assert!(worst <= 7, "worst {worst} of 65535");
        let mut prev = 0;
        for i in 0..=2_000_000 {
            let x = i as f32 / 2_000_000.0;
            let v = srgb_encode_u16(x);
            assert!(v >= prev, "not monotone at {x}: {v} < {prev}");
            prev = v;
        }
        assert_eq!(srgb_encode_u16(f32::NAN), 0);
        assert_eq!(srgb_encode_u16(f32::INFINITY), 65535);
        assert_eq!(srgb_encode_u16(-0.0), 0);
    }
}
