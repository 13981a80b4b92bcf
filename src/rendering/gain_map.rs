//! The container of a gain-map JPEG (Ultra HDR, ISO 21496-1): a primary JPEG, the SDR
//! base, followed by a second JPEG, the gain map, joined by a Multi-Picture Format index
//! (CIPA DC-007) in the primary, with the gain map's metadata twice — as Adobe's XMP
//! `hdrgm:` attributes (Ultra HDR v1) and as ISO 21496-1's binary block.
//!
//! Written here rather than taken from a crate: the pure-Rust gain-map crates on
//! crates.io (`ultrahdr-rs`, `ultrahdr-core`, `ultrajpeg`) are pre-1.0 with renames
//! announced between point releases and bring a second JPEG codec, while the container
//! is four small marker segments around the two JPEGs `rusty_jpeg` already writes.
//!
//! Layout of the file, as Chromium (Skia's `SkJpegGainmap`), Android and libultrahdr read
//! it:
//!
//! ```text
//! primary:  SOI  APP1 Exif  APP1 XMP (hdrgm:Version, Container:Directory with the gain
//!           map's Item:Length)  APP2 ICC  APP2 ISO 21496-1 (version only)  APP2 MPF
//!           … the SDR image … EOI
//! gain map: SOI  APP1 XMP (hdrgm: the metadata)  APP2 ISO 21496-1 (the metadata)
//!           … one 8-bit channel … EOI
//! ```
//!
//! The MPF index lists both images: the primary (type `0x030000`, offset 0) and the gain
//! map, whose offset counts from the MPF segment's TIFF header (the byte after `MPF\0`).

use super::ImageEncodeError;

/// The signature opening an XMP APP1 segment.
pub(crate) const XMP_SIGNATURE: &[u8] = b"http://ns.adobe.com/xap/1.0/\0";

/// The signature opening an ISO 21496-1 APP2 segment.
pub(crate) const ISO_SIGNATURE: &[u8] = b"urn:iso:std:iso:ts:21496:-1\0";

/// The signature opening an MPF APP2 segment.
const MPF_SIGNATURE: &[u8] = b"MPF\0";

/// Bytes of the MPF segment written by [`mpf_segment`]: marker and length (4), signature
/// (4), TIFF header (8), IFD count (2), three entries (36), next-IFD offset (4), two MP
/// entries (32).
const MPF_SEGMENT_BYTES: usize = 4 + 4 + 8 + 2 + 36 + 4 + 32;

/// How a gain map's codes become a gain, and when a display applies it. The values are
/// those of ISO 21496-1 and Adobe's `hdrgm:` namespace, with the log₂ quantities in
/// stops: a code `c ∈ [0, 255]` is the log₂ gain
/// `L = min + (max − min)·(c/255)^(1/gamma)`, and a display with headroom `H` (its peak
/// over SDR white) shows `HDR = (SDR + offset_sdr)·2^(L·w) − offset_hdr` in linear light
/// of the base's primaries, with `w = clamp((log₂H − capacity_min)/(capacity_max −
/// capacity_min), 0, 1)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GainMapMetadata {
    /// `GainMapMin`, log₂ of the smallest gain (stops).
    pub min_log2: f32,
    /// `GainMapMax`, log₂ of the largest gain (stops).
    pub max_log2: f32,
    /// `Gamma` of the code's encoding.
    pub gamma: f32,
    /// `OffsetSDR`, added to the base's linear values.
    pub offset_sdr: f32,
    /// `OffsetHDR`, taken from the result.
    pub offset_hdr: f32,
    /// `HDRCapacityMin`, log₂ of the headroom from which the map starts to apply (stops).
    pub capacity_min_log2: f32,
    /// `HDRCapacityMax`, log₂ of the headroom at which it applies in full (stops).
    pub capacity_max_log2: f32,
}

impl GainMapMetadata {
    /// The log₂ gain (stops) of code `c` ([`GainMapMetadata`]'s formula).
    pub fn log2_gain(&self, code: u8) -> f32 {
        let t = (f32::from(code) / 255.0).powf(1.0 / self.gamma);
        self.min_log2 + (self.max_log2 - self.min_log2) * t
    }

    /// The code of log₂ gain `g` (stops), clamped to `[min, max]`; the inverse of
    /// [`Self::log2_gain`] to half a code.
    pub fn code(&self, g: f32) -> u8 {
        let span = self.max_log2 - self.min_log2;
        let t = if span > 0.0 {
            ((g - self.min_log2) / span).clamp(0.0, 1.0)
        } else {
            0.0
        };
        (255.0 * t.powf(self.gamma)).round() as u8
    }
}

/// The gain map's XMP packet: every `hdrgm:` value as an attribute.
pub(crate) fn gain_map_xmp(m: &GainMapMetadata) -> String {
    format!(
        concat!(
            "<x:xmpmeta xmlns:x=\"adobe:ns:meta/\" x:xmptk=\"filmback\">\n",
            " <rdf:RDF xmlns:rdf=\"http://www.w3.org/1999/02/22-rdf-syntax-ns#\">\n",
            "  <rdf:Description rdf:about=\"\"\n",
            "    xmlns:hdrgm=\"http://ns.adobe.com/hdr-gain-map/1.0/\"\n",
            "    hdrgm:Version=\"1.0\"\n",
            "    hdrgm:GainMapMin=\"{}\"\n",
            "    hdrgm:GainMapMax=\"{}\"\n",
            "    hdrgm:Gamma=\"{}\"\n",
            "    hdrgm:OffsetSDR=\"{}\"\n",
            "    hdrgm:OffsetHDR=\"{}\"\n",
            "    hdrgm:HDRCapacityMin=\"{}\"\n",
            "    hdrgm:HDRCapacityMax=\"{}\"\n",
            "    hdrgm:BaseRenditionIsHDR=\"False\"/>\n",
            " </rdf:RDF>\n",
            "</x:xmpmeta>\n"
        ),
        m.min_log2,
        m.max_log2,
        m.gamma,
        m.offset_sdr,
        m.offset_hdr,
        m.capacity_min_log2,
        m.capacity_max_log2,
    )
}

/// The primary's XMP packet: `hdrgm:Version` and the container directory (the primary,
/// then the gain map of `gain_map_bytes` bytes).
pub(crate) fn primary_xmp(gain_map_bytes: usize) -> String {
    format!(
        concat!(
            "<x:xmpmeta xmlns:x=\"adobe:ns:meta/\" x:xmptk=\"filmback\">\n",
            " <rdf:RDF xmlns:rdf=\"http://www.w3.org/1999/02/22-rdf-syntax-ns#\">\n",
            "  <rdf:Description rdf:about=\"\"\n",
            "    xmlns:Container=\"http://ns.google.com/photos/1.0/container/\"\n",
            "    xmlns:Item=\"http://ns.google.com/photos/1.0/container/item/\"\n",
            "    xmlns:hdrgm=\"http://ns.adobe.com/hdr-gain-map/1.0/\"\n",
            "    hdrgm:Version=\"1.0\">\n",
            "   <Container:Directory>\n",
            "    <rdf:Seq>\n",
            "     <rdf:li rdf:parseType=\"Resource\">\n",
            "      <Container:Item Item:Semantic=\"Primary\" Item:Mime=\"image/jpeg\"/>\n",
            "     </rdf:li>\n",
            "     <rdf:li rdf:parseType=\"Resource\">\n",
            "      <Container:Item Item:Semantic=\"GainMap\" Item:Mime=\"image/jpeg\" Item:Length=\"{}\"/>\n",
            "     </rdf:li>\n",
            "    </rdf:Seq>\n",
            "   </Container:Directory>\n",
            "  </rdf:Description>\n",
            " </rdf:RDF>\n",
            "</x:xmpmeta>\n"
        ),
        gain_map_bytes
    )
}

/// An APP1 payload: the XMP signature and `packet`.
pub(crate) fn xmp_payload(packet: &str) -> Vec<u8> {
    [XMP_SIGNATURE, packet.as_bytes()].concat()
}

/// The primary's ISO 21496-1 APP2 payload: the signature and the version alone
/// (minimum reader version 0, writer version 0, big-endian `u16`s), which says a gain map
/// follows.
pub(crate) fn iso_version_payload() -> Vec<u8> {
    [ISO_SIGNATURE, &[0, 0, 0, 0]].concat()
}

/// Denominator of the rationals written into the ISO block: values are stated to
/// 1/10 000.
const ISO_DENOMINATOR: u32 = 10_000;

/// The gain map's ISO 21496-1 APP2 payload: the signature, the version (0, 0), flags
/// (`0x40`: the gain is applied in the base's colour space; one channel; no common
/// denominator), then as big-endian numerator/denominator pairs the base and alternate
/// headroom (`capacity_min`, `capacity_max`, stops) and for the one channel `min`, `max`
/// (signed, stops), `gamma` (unsigned), `offset_sdr`, `offset_hdr` (signed).
pub(crate) fn iso_metadata_payload(m: &GainMapMetadata) -> Vec<u8> {
    let mut out = iso_version_payload();
    out.push(0x40);
    let unsigned = |out: &mut Vec<u8>, v: f32| {
        let n = (f64::from(v.max(0.0)) * f64::from(ISO_DENOMINATOR)).round() as u32;
        out.extend_from_slice(&n.to_be_bytes());
        out.extend_from_slice(&ISO_DENOMINATOR.to_be_bytes());
    };
    let signed = |out: &mut Vec<u8>, v: f32| {
        let n = (f64::from(v) * f64::from(ISO_DENOMINATOR)).round() as i32;
        out.extend_from_slice(&n.to_be_bytes());
        out.extend_from_slice(&ISO_DENOMINATOR.to_be_bytes());
    };
    unsigned(&mut out, m.capacity_min_log2);
    unsigned(&mut out, m.capacity_max_log2);
    signed(&mut out, m.min_log2);
    signed(&mut out, m.max_log2);
    unsigned(&mut out, m.gamma);
    signed(&mut out, m.offset_sdr);
    signed(&mut out, m.offset_hdr);
    out
}

/// The MPF APP2 segment (marker included) of a primary image of `primary_bytes` bytes
/// (this segment included) whose segment starts at byte `at` of it, followed by a gain map
/// of `gain_map_bytes` bytes. Big-endian TIFF structure: the MP Index IFD with
/// `MPFVersion` "0100", `NumberOfImages` 2 and the two 16-byte `MPEntry` records
/// (attribute, size, offset, two dependent-image entries).
fn mpf_segment(primary_bytes: u32, at: u32, gain_map_bytes: u32) -> Vec<u8> {
    // The TIFF header is the byte after the marker, length and signature.
    let header = at + 4 + MPF_SIGNATURE.len() as u32;
    let gain_map_offset = primary_bytes - header;
    let mut s = Vec::with_capacity(MPF_SEGMENT_BYTES);
    s.extend_from_slice(&[0xFF, 0xE2]);
    s.extend_from_slice(&((MPF_SEGMENT_BYTES - 2) as u16).to_be_bytes());
    s.extend_from_slice(MPF_SIGNATURE);
    s.extend_from_slice(b"MM\0\x2A");
    s.extend_from_slice(&8u32.to_be_bytes());
    s.extend_from_slice(&3u16.to_be_bytes());
    let entry = |s: &mut Vec<u8>, tag: u16, kind: u16, count: u32, value: [u8; 4]| {
        s.extend_from_slice(&tag.to_be_bytes());
        s.extend_from_slice(&kind.to_be_bytes());
        s.extend_from_slice(&count.to_be_bytes());
        s.extend_from_slice(&value);
    };
    // Types: 7 UNDEFINED, 4 LONG. The entries' data follows the IFD and its next-IFD
    // offset: 8 + 2 + 3·12 + 4 = 50 bytes from the TIFF header.
    entry(&mut s, 0xB000, 7, 4, *b"0100");
    entry(&mut s, 0xB001, 4, 1, 2u32.to_be_bytes());
    entry(&mut s, 0xB002, 7, 32, 50u32.to_be_bytes());
    s.extend_from_slice(&0u32.to_be_bytes());
    for (attribute, size, offset) in [
        (0x0003_0000u32, primary_bytes, 0u32),
        (0, gain_map_bytes, gain_map_offset),
    ] {
        s.extend_from_slice(&attribute.to_be_bytes());
        s.extend_from_slice(&size.to_be_bytes());
        s.extend_from_slice(&offset.to_be_bytes());
        s.extend_from_slice(&[0, 0, 0, 0]);
    }
    s
}

/// The end of the APPn segments that follow a JPEG's SOI: where the MPF segment goes.
fn after_app_segments(jpeg: &[u8]) -> Result<usize, ImageEncodeError> {
    if jpeg.get(..2) != Some(&[0xFF, 0xD8]) {
        return Err(ImageEncodeError::JpegStream(
            "the base image is not a JPEG (no SOI)",
        ));
    }
    let mut at = 2;
    while let Some(&[0xFF, marker, hi, lo]) = jpeg.get(at..at + 4) {
        if !(0xE0..=0xEF).contains(&marker) {
            return Ok(at);
        }
        at += 2 + usize::from(u16::from_be_bytes([hi, lo]));
    }
    Err(ImageEncodeError::JpegStream(
        "the base image ends inside its header",
    ))
}

/// The gain-map JPEG: `primary` (which already holds the XMP directory and the ISO
/// version, [`primary_xmp`], [`iso_version_payload`]) with the MPF index inserted after
/// its APPn segments, then `gain_map`. Fails when either image would pass 4 GiB (MPF
/// offsets are 32-bit) or `primary` is not a JPEG.
pub(crate) fn assemble(primary: &[u8], gain_map: &[u8]) -> Result<Vec<u8>, ImageEncodeError> {
    let at = after_app_segments(primary)?;
    let too_big = || ImageEncodeError::GainMapTooLarge;
    let primary_bytes = u32::try_from(primary.len() + MPF_SEGMENT_BYTES).map_err(|_| too_big())?;
    let gain_map_bytes = u32::try_from(gain_map.len()).map_err(|_| too_big())?;
    let at32 = u32::try_from(at).map_err(|_| too_big())?;
    let mut out = Vec::with_capacity(primary.len() + MPF_SEGMENT_BYTES + gain_map.len());
    out.extend_from_slice(&primary[..at]);
    out.extend_from_slice(&mpf_segment(primary_bytes, at32, gain_map_bytes));
    out.extend_from_slice(&primary[at..]);
    out.extend_from_slice(gain_map);
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn metadata() -> GainMapMetadata {
        GainMapMetadata {
            min_log2: 0.0,
            max_log2: 2.0,
            gamma: 1.0,
            offset_sdr: 0.0,
            offset_hdr: 0.0,
            capacity_min_log2: 0.0,
            capacity_max_log2: 2.0,
        }
    }

    #[test]
    fn codes_round_trip_to_half_a_step() {
        for gamma in [1.0, 0.5, 2.0] {
            let m = GainMapMetadata {
                gamma,
                ..metadata()
            };
            for c in 0..=255u8 {
                assert_eq!(m.code(m.log2_gain(c)), c, "gamma {gamma} code {c}");
            }
            assert_eq!(m.code(-1.0), 0);
            assert_eq!(m.code(9.0), 255);
            assert_eq!(m.code(f32::NAN), 0);
        }
    }

    #[test]
    fn the_iso_block_has_the_layout_readers_expect() {
        let block = iso_metadata_payload(&metadata());
        let body = &block[ISO_SIGNATURE.len()..];
        // Version (4), flags (1), two headrooms and five channel values as pairs.
        assert_eq!(body.len(), 4 + 1 + 7 * 8);
        assert_eq!(&body[..5], &[0, 0, 0, 0, 0x40]);
        let pair = |i: usize| {
            let at = 5 + 8 * i;
            let n = i32::from_be_bytes(body[at..at + 4].try_into().unwrap());
            let d = u32::from_be_bytes(body[at + 4..at + 8].try_into().unwrap());
            n as f64 / d as f64
        };
        let values: Vec<f64> = (0..7).map(pair).collect();
        assert_eq!(values, [0.0, 2.0, 0.0, 2.0, 1.0, 0.0, 0.0]);
    }

    #[test]
    fn the_mpf_index_points_at_the_gain_map() {
        // A minimal "JPEG": SOI, one APP0, then the rest.
        let primary = [
            &[0xFF, 0xD8, 0xFF, 0xE0, 0x00, 0x04, 1, 2][..],
            &[0xFF, 0xDB, 0, 2, 0xFF, 0xD9],
        ]
        .concat();
        let gain_map = [0xFF, 0xD8, 7, 7, 0xFF, 0xD9];
        let file = assemble(&primary, &gain_map).unwrap();
        assert_eq!(
            file.len(),
            primary.len() + MPF_SEGMENT_BYTES + gain_map.len()
        );
        let at = 8;
        assert_eq!(&file[at..at + 2], &[0xFF, 0xE2]);
        assert_eq!(&file[at + 4..at + 8], MPF_SIGNATURE);
        let header = at + 8;
        let entries = header + 50;
        let read = |i: usize| u32::from_be_bytes(file[i..i + 4].try_into().unwrap()) as usize;
        assert_eq!(read(entries), 0x0003_0000);
        assert_eq!(read(entries + 4), primary.len() + MPF_SEGMENT_BYTES);
        assert_eq!(read(entries + 8), 0);
        assert_eq!(read(entries + 20), gain_map.len());
        assert_eq!(&file[header + read(entries + 24)..], &gain_map);
        assert!(assemble(b"not a jpeg", &gain_map).is_err());
        assert!(assemble(&[0xFF, 0xD8, 0xFF, 0xE1, 0x10, 0x00], &gain_map).is_err());
    }
}
