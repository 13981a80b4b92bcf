//! Writing a radiance map: OpenEXR (the default) or Radiance `.hdr`.
//!
//! Values are written as the merge made them: linear relative radiance, 1.0 = brightness
//! `g⁻¹(1)` in the longest exposure (see `merge`). The OpenEXR header says where they came
//! from: chromaticities (Rec.709/sRGB primaries, D65 white: filmback reads no ICC profile,
//! and camera JPEGs are sRGB unless set otherwise), `software`, `capDate`/`utcOffset`, the
//! standard `cameraMake`, `cameraModel`, `cameraSerialNumber`, and the standard
//! `expTime`/`aperture`/`isoSpeed` of the longest frame (the reference of the scale).
//! filmback's own string attributes: `filmbackFrame<k>` (one per frame, darkest first:
//! file, time, f-number, ISO, relative exposure), `filmbackExposureRatio` (double,
//! `e_max/e_min`), `filmbackResponse` (the response model summary), `filmbackWeighting`,
//! `filmbackClipped` (samples clipped in every frame), `filmbackScale` (the convention)
//! and `filmbackRadianceScale` (float: the factor applied for half overflow, else 1).
//!
//! Half (`f16`, default) keeps 10 bits of mantissa over 30 stops, ample for radiance that
//! came from 8–16-bit frames, in half the space of `f32`. Its largest value is 65 504:
//! with a bracket spanning more than 16 stops the brightest samples would overflow to ∞,
//! so they are either scaled (the whole image by a power of two, exact in binary
//! floating point, recorded in `filmbackRadianceScale`) or clamped, with a warning.
//!
//! Compression (see [`Compression`]): PIZ by default, a lossless wavelet coder that does
//! best on noisy photographic data; lossy coders only when asked for by name. Half PIZ
//! blocks are compressed by filmback's own encoder (`piz`, 1.5× faster than exr's on a
//! 24 MP map, same format and size); everything else by the exr crate.
//!
//! Every file is published through [`crate::atomic`]: a failure (unwritable
//! folder, full disk, encoder error) leaves no partial file.

use std::io::{Seek, Write};
use std::path::Path;

use exr::block::chunk::{Chunk, CompressedBlock, CompressedScanLineBlock};
use exr::block::writer::ChunksWriter;
use exr::block::{BlockIndex, UncompressedBlock};
use exr::meta::BlockDescription;
use exr::meta::attribute::Chromaticities;
use exr::meta::header::Header;
use exr::prelude::{
    self as x, ChannelDescription, ImageAttributes, IntegerBounds, LayerAttributes, LineOrder,
    SampleType, SmallVec, Text, Vec2, f16,
};
use half::slice::{HalfBitsSliceExt, HalfFloatSliceExt};
use rayon::prelude::*;

use crate::atomic::{self, Overwrite, PublishError};
use crate::merge::PairMerge;
use crate::metadata::{Camera, CaptureTime, Exposure};
use crate::radiance::RadianceMap;

mod piz;

/// Anything the writers can pull radiance from, sample by sample: a [`RadianceMap`], or
/// a [`PairMerge`] evaluated while the file is encoded (no radiance buffer at all).
pub trait RadianceSource: Sync {
    /// Width in pixels.
    fn width(&self) -> u32;
    /// Height in pixels.
    fn height(&self) -> u32;
    /// 1 (grey) or 3 (RGB).
    fn channels(&self) -> usize;
    /// Linear relative radiance of `channel` of `pixel` (row-major index).
    fn sample(&self, pixel: usize, channel: usize) -> f32;
    /// Channel `channel` of the `out.len()` pixels from `pixel` on (one line or part of one).
    #[inline]
    fn line(&self, pixel: usize, channel: usize, out: &mut [f32]) {
        for (k, v) in out.iter_mut().enumerate() {
            *v = self.sample(pixel + k, channel);
        }
    }
    /// An upper bound of the finite values (decides half-overflow handling).
    fn max_value(&self) -> f32;
}

impl RadianceSource for RadianceMap {
    fn width(&self) -> u32 {
        RadianceMap::width(self)
    }
    fn height(&self) -> u32 {
        RadianceMap::height(self)
    }
    fn channels(&self) -> usize {
        RadianceMap::channels(self)
    }
    #[inline]
    fn sample(&self, pixel: usize, channel: usize) -> f32 {
        self.pixels()[pixel * RadianceMap::channels(self) + channel]
    }
    fn max_value(&self) -> f32 {
        use rayon::prelude::*;
        self.pixels()
            .par_iter()
            .copied()
            .filter(|v| v.is_finite())
            .reduce(|| 0.0, f32::max)
    }
}

impl RadianceSource for PairMerge<'_> {
    fn width(&self) -> u32 {
        PairMerge::width(self)
    }
    fn height(&self) -> u32 {
        PairMerge::height(self)
    }
    fn channels(&self) -> usize {
        PairMerge::channels(self)
    }
    #[inline]
    fn sample(&self, pixel: usize, channel: usize) -> f32 {
        PairMerge::sample(self, pixel, channel)
    }
    fn max_value(&self) -> f32 {
        PairMerge::max_value(self)
    }
}

/// The largest finite half-precision value.
pub const HALF_MAX: f32 = 65504.0;

/// Sample type of the OpenEXR channels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SampleFormat {
    /// 16-bit float: 10-bit mantissa, at most 65 504 (default).
    #[default]
    Half,
    /// 32-bit float.
    Float,
}

/// OpenEXR compression. Lossless unless the name says otherwise.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Compression {
    /// None: largest files, fastest to write and read.
    None,
    /// Run-length: fast, small gains on photographs (helps on flat areas).
    Rle,
    /// zlib over 16 scan lines: small files, slower to write.
    Zip,
    /// Wavelet + Huffman (default): smallest lossless files for noisy photographs,
    /// symmetric speed.
    #[default]
    Piz,
    /// PXR24: lossless for half; **lossy** for float (rounds to 24 bits).
    Pxr24,
    /// B44: **lossy**, fixed 2.3:1 for half (float channels are stored uncompressed).
    B44,
}

impl Compression {
    fn exr(self) -> x::Compression {
        match self {
            Compression::None => x::Compression::Uncompressed,
            Compression::Rle => x::Compression::RLE,
            Compression::Zip => x::Compression::ZIP16,
            Compression::Piz => x::Compression::PIZ,
            Compression::Pxr24 => x::Compression::PXR24,
            Compression::B44 => x::Compression::B44,
        }
    }
}

/// What to do with values above [`HALF_MAX`] when writing half.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Overflow {
    /// Multiply the whole image by the largest power of two `2⁻ⁿ` that brings the maximum
    /// to at most 65 504 (default): nothing is lost, the factor is in the header.
    #[default]
    Scale,
    /// Clamp those samples to 65 504: the rest keeps the merge's scale.
    Clamp,
}

/// How to write the OpenEXR file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ExrOptions {
    /// Half (default) or float.
    pub sample: SampleFormat,
    /// Compression (default PIZ).
    pub compression: Compression,
    /// Half overflow handling (default: scale).
    pub overflow: Overflow,
}

/// One input frame as recorded in the header.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameRecord {
    /// File name (or any label).
    pub name: String,
    /// Exposure settings as known (EXIF or given on the command line).
    pub exposure: Exposure,
    /// Relative exposure used by the merge, `e = t·S/N²`.
    pub relative: f64,
}

/// Where a radiance map came from; becomes the OpenEXR header.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Provenance {
    /// The camera body.
    pub camera: Camera,
    /// Capture time of the first frame.
    pub captured_at: Option<CaptureTime>,
    /// The frames, darkest first.
    pub frames: Vec<FrameRecord>,
    /// Response model summary, e.g. `"sRGB inverse (default)"`.
    pub response: String,
    /// Weighting used by the merge.
    pub weighting: String,
    /// Samples clipped high / low in every frame.
    pub clipped: (u64, u64),
}

/// What writing did beyond the pixels.
#[derive(Debug, Clone, PartialEq)]
pub struct Written {
    /// Factor applied to every value (1 unless half overflow was scaled).
    pub scale: f32,
    /// Human-readable warnings (overflow handling).
    pub warnings: Vec<String>,
}

/// Why a radiance map could not be written.
#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    /// The file could not be published (it exists, unwritable folder, full disk, or the
    /// encoder failed); nothing was left behind.
    #[error(transparent)]
    Publish(#[from] PublishError),
    /// The OpenEXR encoder failed.
    #[error("cannot encode OpenEXR: {0}")]
    Exr(String),
    /// The Radiance HDR encoder failed.
    #[error("cannot encode Radiance HDR: {0}")]
    Hdr(String),
    /// The confidence layer does not have one value per pixel.
    #[error("confidence layer has {got} values for {expected} pixels")]
    ConfidenceShape {
        /// Values given.
        got: usize,
        /// Pixels in the map.
        expected: usize,
    },
}

/// Writes `map` (and, if given, the per-pixel `confidence` as channel `confidence.Y`) as
/// an OpenEXR file at `path`, atomically.
pub fn write_exr<S: RadianceSource + ?Sized>(
    path: &Path,
    overwrite: Overwrite,
    map: &S,
    confidence: Option<&[f32]>,
    provenance: &Provenance,
    options: ExrOptions,
) -> Result<Written, OutputError> {
    let mut written = None;
    atomic::publish_with(path, overwrite, |w| {
        written =
            Some(encode_exr(w, map, confidence, provenance, options).map_err(|e| e.to_string())?);
        Ok(())
    })?;
    Ok(written.expect("set by the producer on success"))
}

/// Encodes `map` as OpenEXR into `writer` (see [`write_exr`]).
pub fn encode_exr<W: Write + Seek, S: RadianceSource + ?Sized>(
    writer: W,
    map: &S,
    confidence: Option<&[f32]>,
    provenance: &Provenance,
    options: ExrOptions,
) -> Result<Written, OutputError> {
    let (width, height) = (map.width() as usize, map.height() as usize);
    if let Some(conf) = confidence
        && conf.len() != width * height
    {
        return Err(OutputError::ConfidenceShape {
            got: conf.len(),
            expected: width * height,
        });
    }
    let (scale, limit, warnings) = overflow(map, options);
    let sample = match options.sample {
        SampleFormat::Half => SampleType::F16,
        SampleFormat::Float => SampleType::F32,
    };
    // Channels in the file's (alphabetical) order and where each one's values come from.
    let mut planes: Vec<(&str, Plane)> = match map.channels() {
        3 => vec![
            ("B", Plane::Colour(2)),
            ("G", Plane::Colour(1)),
            ("R", Plane::Colour(0)),
        ],
        _ => vec![("Y", Plane::Colour(0))],
    };
    if confidence.is_some() {
        planes.push(("confidence.Y", Plane::Confidence));
    }
    let descriptions = planes
        .iter()
        .map(|(name, plane)| {
            ChannelDescription::new(*name, sample, matches!(plane, Plane::Confidence))
        })
        .collect();
    let size = Vec2(width, height);
    let mut header = Header::new(text("radiance"), size, SmallVec::from_vec(descriptions))
        .with_encoding(
            options.compression.exr(),
            BlockDescription::ScanLines,
            LineOrder::Increasing,
        );
    header.own_attributes = layer_attributes(provenance, scale);
    header.shared_attributes = image_attributes(size);

    // One line of one plane, scaled and clamped. The samples are pulled from the source
    // here, so a lazy merge is evaluated on the worker threads.
    let fill_line = |plane: &Plane, start: usize, line: &mut [f32]| match plane {
        Plane::Colour(c) => {
            map.line(start, *c, line);
            for v in line.iter_mut() {
                *v = (*v * scale).min(limit);
            }
        }
        Plane::Confidence => {
            let conf = confidence.expect("a confidence plane only with confidence");
            line.copy_from_slice(&conf[start..start + line.len()]);
        }
    };
    let piz_half = options.compression == Compression::Piz && sample == SampleType::F16;
    exr::block::write(writer, smallvec_of(header), true, |meta, chunks| {
        let indices: Vec<(usize, BlockIndex)> =
            meta.enumerate_ordered_header_block_indices().collect();
        if piz_half {
            // filmback's PIZ encoder (see `piz`): blocks compressed a batch at a time on
            // rayon's threads, written in order.
            let batch = 4 * rayon::current_num_threads();
            for batch in indices.chunks(batch) {
                let compressed: Vec<(usize, Chunk)> = batch
                    .par_iter()
                    .map(|&(i, index)| (i, piz_chunk(index, width, &planes, &fill_line)))
                    .collect();
                for (i, chunk) in compressed {
                    chunks.write_chunk(i, chunk)?;
                }
            }
            return Ok(());
        }
        // The uncompressed bytes of one block: per line, per channel, the samples in
        // native-endian order.
        let block_bytes = |index: BlockIndex| -> Vec<u8> {
            let (x0, y0) = (index.pixel_position.0, index.pixel_position.1);
            let (w, h) = (index.pixel_size.0, index.pixel_size.1);
            let bytes = if sample == SampleType::F16 { 2 } else { 4 };
            let mut data = Vec::with_capacity(w * h * planes.len() * bytes);
            let mut line = vec![0f32; w];
            let mut halves = vec![f16::ZERO; w];
            for y in y0..y0 + h {
                for (_, plane) in &planes {
                    fill_line(plane, y * width + x0, &mut line);
                    if sample == SampleType::F16 {
                        halves.convert_from_f32_slice(&line);
                        for v in &halves {
                            data.extend_from_slice(&v.to_ne_bytes());
                        }
                    } else {
                        for v in &line {
                            data.extend_from_slice(&v.to_ne_bytes());
                        }
                    }
                }
            }
            data
        };
        // exr compresses on its own threads but asks for blocks on this one: fill them a
        // few at a time on rayon's threads so that the samples, not just the
        // compression, are computed in parallel.
        let batch = 2 * rayon::current_num_threads();
        let blocks = indices.chunks(batch).flat_map(|batch| {
            batch
                .par_iter()
                .map(|&(i, index)| {
                    let data = block_bytes(index);
                    (i, UncompressedBlock { index, data })
                })
                .collect::<Vec<_>>()
        });
        chunks
            .on_progress(|_| {})
            .compress_all_blocks_parallel(&meta, blocks)
    })
    .map_err(|e| OutputError::Exr(e.to_string()))?;
    Ok(Written { scale, warnings })
}

/// Where a file channel's values come from.
enum Plane {
    /// Channel `c` of the radiance.
    Colour(usize),
    /// The confidence layer.
    Confidence,
}

/// One scan-line block compressed by [`piz::compress`]: the block's samples as half, plane
/// by plane in the file's channel order, each plane's lines contiguous. A block that PIZ
/// does not shrink is stored raw (per line, per channel, little-endian), as the format
/// requires.
fn piz_chunk(
    index: BlockIndex,
    width: usize,
    planes: &[(&str, Plane)],
    fill_line: &impl Fn(&Plane, usize, &mut [f32]),
) -> Chunk {
    let (x0, y0) = (index.pixel_position.0, index.pixel_position.1);
    let (w, h) = (index.pixel_size.0, index.pixel_size.1);
    let mut line = vec![0f32; w];
    let mut fill = |words: &mut [u16]| {
        let halves: &mut [f16] = words.reinterpret_cast_mut();
        for ((_, plane), samples) in planes.iter().zip(halves.chunks_exact_mut(w * h)) {
            for (y, out) in (y0..y0 + h).zip(samples.chunks_exact_mut(w)) {
                fill_line(plane, y * width + x0, &mut line);
                out.convert_from_f32_slice(&line);
            }
        }
    };
    let mut words = vec![0u16; w * h * planes.len()];
    let raw_bytes = 2 * words.len();
    fill(&mut words);
    let compressed = piz::compress(&mut words, w, h).filter(|c| c.len() < raw_bytes);
    let compressed_pixels_le = compressed.unwrap_or_else(|| {
        // The compressor overwrote the words: pull them again (rare: noise-like data).
        fill(&mut words);
        let mut raw = Vec::with_capacity(raw_bytes);
        for y in 0..h {
            for samples in words.chunks_exact(w * h) {
                for v in &samples[y * w..(y + 1) * w] {
                    raw.extend_from_slice(&v.to_le_bytes());
                }
            }
        }
        raw
    });
    Chunk {
        layer_index: 0,
        compressed_block: CompressedBlock::ScanLine(CompressedScanLineBlock {
            y_coordinate: y0 as i32,
            compressed_pixels_le,
        }),
    }
}

fn smallvec_of(header: Header) -> exr::meta::Headers {
    SmallVec::from_vec(vec![header])
}

/// The scale factor and clamp limit for the chosen sample type, with a warning if used.
fn overflow<S: RadianceSource + ?Sized>(map: &S, options: ExrOptions) -> (f32, f32, Vec<String>) {
    if options.sample == SampleFormat::Float {
        return (1.0, f32::MAX, Vec::new());
    }
    let max = map.max_value();
    if max <= HALF_MAX {
        return (1.0, HALF_MAX, Vec::new());
    }
    match options.overflow {
        Overflow::Scale => {
            let n = (max / HALF_MAX).log2().ceil() as i32;
            let scale = 2f32.powi(-n);
            let warning = format!(
                "radiance up to {max} exceeds half's 65504: every value scaled by 2^-{n} \
                 (recorded as filmbackRadianceScale); write float to keep the scale"
            );
            (scale, HALF_MAX, vec![warning])
        }
        Overflow::Clamp => {
            let warning = format!(
                "radiance up to {max} exceeds half's 65504: larger samples clamped to 65504; \
                 write float to keep them"
            );
            (1.0, HALF_MAX, vec![warning])
        }
    }
}

/// Text attribute from UTF-8 (OpenEXR strings are byte strings; readers take them as UTF-8).
fn text(s: &str) -> Text {
    Text::from_slice_unchecked(s.as_bytes())
}

fn image_attributes(size: Vec2<usize>) -> ImageAttributes {
    let mut attributes = ImageAttributes::new(IntegerBounds::from_dimensions(size));
    // ITU-R BT.709 / sRGB primaries, D65 white.
    attributes.chromaticities = Some(Chromaticities {
        red: Vec2(0.64, 0.33),
        green: Vec2(0.30, 0.60),
        blue: Vec2(0.15, 0.06),
        white: Vec2(0.3127, 0.3290),
    });
    attributes
}

fn layer_attributes(p: &Provenance, scale: f32) -> LayerAttributes {
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
    a.comments = Some(text(
        "linear relative radiance; 1.0 = brightness g^-1(1) in the longest exposure",
    ));
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
    put(
        "filmbackScale",
        V::Text(text(
            "value = g(B_k) * e_longest / e_k, weighted over frames; 1.0 = B=1 in the longest exposure",
        )),
    );
    put("filmbackRadianceScale", V::F32(scale));
    a
}

/// Writes `map` as a Radiance RGBE `.hdr` file at `path`, atomically (grey maps are
/// written as three equal channels).
pub fn write_radiance_hdr<S: RadianceSource + ?Sized>(
    path: &Path,
    overwrite: Overwrite,
    map: &S,
) -> Result<(), OutputError> {
    atomic::publish_with(path, overwrite, |w| {
        encode_radiance_hdr(w, map).map_err(|e| e.to_string())
    })?;
    Ok(())
}

/// Encodes `map` as Radiance RGBE into `writer` (see [`write_radiance_hdr`]).
pub fn encode_radiance_hdr<W: Write, S: RadianceSource + ?Sized>(
    writer: W,
    map: &S,
) -> Result<(), OutputError> {
    let pixels = map.width() as usize * map.height() as usize;
    let grey = map.channels() == 1;
    let rgb: Vec<image::Rgb<f32>> = (0..pixels)
        .map(|p| {
            let s = |c: usize| map.sample(p, if grey { 0 } else { c });
            image::Rgb([s(0), s(1), s(2)])
        })
        .collect();
    image::codecs::hdr::HdrEncoder::new(writer)
        .encode(&rgb, map.width() as usize, map.height() as usize)
        .map_err(|e| OutputError::Hdr(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use exr::prelude::traits::*;
    use std::io::Cursor;

    fn ramp(width: u32, height: u32, top: f32) -> RadianceMap {
        let n = (width * height * 3) as usize;
        let pixels = (0..n).map(|i| top * i as f32 / (n - 1) as f32).collect();
        RadianceMap::new(width, height, 3, pixels).unwrap()
    }

    fn read_back(bytes: Vec<u8>) -> x::Image<x::Layer<x::AnyChannels<x::FlatSamples>>> {
        x::read()
            .no_deep_data()
            .largest_resolution_level()
            .all_channels()
            .first_valid_layer()
            .all_attributes()
            .from_buffered(Cursor::new(bytes))
            .unwrap()
    }

    fn channel(image: &x::Image<x::Layer<x::AnyChannels<x::FlatSamples>>>, name: &str) -> Vec<f32> {
        let c = image
            .layer_data
            .channel_data
            .list
            .iter()
            .find(|c| c.name == text(name))
            .unwrap();
        c.sample_data.values_as_f32().collect()
    }

    #[test]
    fn half_round_trip_keeps_values_and_header() {
        let map = ramp(16, 8, 100.0);
        let provenance = Provenance {
            camera: Camera {
                make: Some("Canon".into()),
                model: Some("EOS 5D Mark II".into()),
                serial: Some("0123".into()),
                lens: None,
            },
            frames: vec![
                FrameRecord {
                    name: "a.jpg".into(),
                    exposure: Exposure {
                        time_s: Some(0.125),
                        f_number: Some(8.0),
                        iso: Some(100.0),
                    },
                    relative: 0.125 * 100.0 / 64.0,
                },
                FrameRecord {
                    name: "b.jpg".into(),
                    exposure: Exposure {
                        time_s: Some(1.0),
                        f_number: Some(8.0),
                        iso: Some(100.0),
                    },
                    relative: 100.0 / 64.0,
                },
            ],
            response: "sRGB".into(),
            weighting: "hat".into(),
            ..Provenance::default()
        };
        let conf = vec![0.5f32; 16 * 8];
        let mut bytes = Cursor::new(Vec::new());
        let w = encode_exr(
            &mut bytes,
            &map,
            Some(&conf),
            &provenance,
            ExrOptions::default(),
        )
        .unwrap();
        assert_eq!(w.scale, 1.0);
        assert!(w.warnings.is_empty());
        let image = read_back(bytes.into_inner());
        let r = channel(&image, "R");
        let c = channel(&image, "confidence.Y");
        assert_eq!(c, conf);
        for (i, v) in r.iter().enumerate() {
            let want = map.pixels()[i * 3];
            assert!((v - want).abs() <= want * 1e-3, "{v} vs {want}");
        }
        let attrs = &image.layer_data.attributes;
        assert_eq!(attrs.exposure, Some(1.0));
        assert_eq!(
            attrs.other.get(&text("cameraModel")),
            Some(&x::AttributeValue::Text(text("EOS 5D Mark II")))
        );
        assert_eq!(
            attrs.other.get(&text("filmbackExposureRatio")),
            Some(&x::AttributeValue::F64(8.0))
        );
        assert!(image.attributes.chromaticities.is_some());
    }

    /// Writes `map` (and `confidence`) as half PIZ through filmback's encoder, reads it
    /// back with the exr crate's decoder and checks every sample bit for bit.
    fn piz_round_trip(map: &RadianceMap, confidence: Option<&[f32]>) {
        let mut bytes = Cursor::new(Vec::new());
        encode_exr(
            &mut bytes,
            map,
            confidence,
            &Provenance::default(),
            ExrOptions::default(),
        )
        .unwrap();
        let image = read_back(bytes.into_inner());
        let names: &[&str] = if map.channels() == 3 {
            &["R", "G", "B"]
        } else {
            &["Y"]
        };
        for (c, name) in names.iter().enumerate() {
            let got = channel(&image, name);
            assert_eq!(got.len(), map.pixels().len() / map.channels());
            for (p, v) in got.iter().enumerate() {
                let want = f16::from_f32(map.pixels()[p * map.channels() + c]).to_f32();
                assert_eq!(
                    v.to_bits(),
                    want.to_bits(),
                    "{name} pixel {p}: {v} vs {want}"
                );
            }
        }
        if let Some(conf) = confidence {
            let got = channel(&image, "confidence.Y");
            let want: Vec<f32> = conf.iter().map(|v| f16::from_f32(*v).to_f32()).collect();
            assert_eq!(got, want);
        }
    }

    /// A deterministic pseudo-random sequence in `[0, 1)` (xorshift).
    fn noise(n: usize, mut state: u64) -> Vec<f32> {
        (0..n)
            .map(|_| {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                (state >> 40) as f32 / (1u64 << 24) as f32
            })
            .collect()
    }

    #[test]
    fn piz_blocks_decode_bit_for_bit() {
        // A photographic-like map: smooth gradient plus noise, several blocks, a last
        // block of 5 lines, an odd width.
        let (w, h) = (123, 69);
        let n = noise(w * h * 3, 7);
        let pixels = (0..w * h * 3)
            .map(|i| (i / 3 % w) as f32 / w as f32 * 4.0 + 0.01 * n[i])
            .collect();
        let map = RadianceMap::new(w as u32, h as u32, 3, pixels).unwrap();
        let conf = noise(w * h, 11);
        piz_round_trip(&map, Some(&conf));

        // Over 2^15 distinct words in one block (the modulo-2^16 wavelet, including pairs
        // it offsets onto each other): values of either sign (the encoder takes any word),
        // magnitudes log-uniform over 2^-14..2^15.
        let (w, h) = (1500, 40);
        let pixels: Vec<f32> = noise(w * h * 3, 3)
            .iter()
            .enumerate()
            .map(|(i, u)| if i % 2 == 0 { 1.0 } else { -1.0 } * (u * 29.0 - 14.0).exp2())
            .collect();
        let first_block: std::collections::HashSet<u16> = pixels[..w * 32 * 3]
            .iter()
            .map(|v| f16::from_f32(*v).to_bits())
            .collect();
        assert!(first_block.len() > 1 << 15, "{}", first_block.len());
        piz_round_trip(
            &RadianceMap::new(w as u32, h as u32, 3, pixels).unwrap(),
            None,
        );
    }

    #[test]
    fn piz_handles_flat_tiny_and_odd_shaped_maps() {
        // All zeros (nothing in the bitmap), one value everywhere (runs longer than 255),
        // 1×1 (stored raw: PIZ cannot shrink 6 bytes), one column, one line, grey.
        for (w, h, c, value) in [
            (300, 40, 3, 0.0),
            (300, 40, 3, 0.75),
            (1, 1, 3, 2.5),
            (1, 70, 3, 1.0),
            (517, 1, 3, 3.0),
            (33, 65, 1, 0.5),
        ] {
            let n = w * h * c;
            let ramp = noise(n, 5);
            // Flat, or flat with a sparse ramp so blocks mix runs and changes.
            let pixels = (0..n)
                .map(|i| {
                    if value == 0.0 || i % 97 != 0 {
                        value
                    } else {
                        ramp[i]
                    }
                })
                .collect();
            let map = RadianceMap::new(w as u32, h as u32, c, pixels).unwrap();
            piz_round_trip(&map, None);
        }
    }

    #[test]
    fn half_overflow_is_scaled_or_clamped_with_a_warning() {
        let map = ramp(8, 4, 200_000.0);
        let mut bytes = Cursor::new(Vec::new());
        let w = encode_exr(
            &mut bytes,
            &map,
            None,
            &Provenance::default(),
            ExrOptions::default(),
        )
        .unwrap();
        assert_eq!(w.scale, 0.25);
        assert_eq!(w.warnings.len(), 1);
        let g = channel(&read_back(bytes.into_inner()), "G");
        assert!(g.iter().all(|v| v.is_finite()));
        let top = g.iter().copied().fold(0.0, f32::max);
        assert!(top > 40_000.0 && top <= HALF_MAX, "{top}");

        let clamp = ExrOptions {
            overflow: Overflow::Clamp,
            ..ExrOptions::default()
        };
        let mut bytes = Cursor::new(Vec::new());
        let w = encode_exr(&mut bytes, &map, None, &Provenance::default(), clamp).unwrap();
        assert_eq!(w.scale, 1.0);
        assert!(w.warnings[0].contains("clamped"), "{:?}", w.warnings);
        let b = channel(&read_back(bytes.into_inner()), "B");
        assert!(b.iter().all(|v| v.is_finite()));
        assert_eq!(b.iter().copied().fold(0.0, f32::max), HALF_MAX);

        let float = ExrOptions {
            sample: SampleFormat::Float,
            compression: Compression::Zip,
            ..ExrOptions::default()
        };
        let mut bytes = Cursor::new(Vec::new());
        let w = encode_exr(&mut bytes, &map, None, &Provenance::default(), float).unwrap();
        assert!(w.warnings.is_empty());
        let b = channel(&read_back(bytes.into_inner()), "B");
        assert_eq!(b[b.len() - 1], 200_000.0);
    }

    #[test]
    fn grey_maps_write_one_channel_and_hdr_encodes() {
        let map =
            RadianceMap::new(4, 2, 1, vec![0.0, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0]).unwrap();
        let mut bytes = Cursor::new(Vec::new());
        encode_exr(
            &mut bytes,
            &map,
            None,
            &Provenance::default(),
            ExrOptions::default(),
        )
        .unwrap();
        assert_eq!(channel(&read_back(bytes.into_inner()), "Y"), map.pixels());
        let mut hdr = Vec::new();
        encode_radiance_hdr(&mut hdr, &map).unwrap();
        assert!(hdr.starts_with(b"#?RADIANCE"));
    }

    /// A disk that fills up after `capacity` bytes.
    struct FullDisk {
        bytes: Vec<u8>,
        position: usize,
        capacity: usize,
    }

    impl Write for FullDisk {
        fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
            if self.position + buf.len() > self.capacity {
                return Err(std::io::Error::new(
                    std::io::ErrorKind::StorageFull,
                    "No space left on device",
                ));
            }
            let end = self.position + buf.len();
            if self.bytes.len() < end {
                self.bytes.resize(end, 0);
            }
            self.bytes[self.position..end].copy_from_slice(buf);
            self.position = end;
            Ok(buf.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    impl Seek for FullDisk {
        fn seek(&mut self, to: std::io::SeekFrom) -> std::io::Result<u64> {
            let mut cursor = Cursor::new(&self.bytes);
            cursor.set_position(self.position as u64);
            self.position = cursor.seek(to)? as usize;
            Ok(self.position as u64)
        }
    }

    #[test]
    fn a_full_disk_is_an_error_not_a_panic() {
        let map = ramp(64, 64, 10.0);
        let disk = FullDisk {
            bytes: Vec::new(),
            position: 0,
            capacity: 4096,
        };
        let err = encode_exr(
            disk,
            &map,
            None,
            &Provenance::default(),
            ExrOptions::default(),
        )
        .unwrap_err();
        assert!(err.to_string().contains("No space left"), "{err}");
    }

    #[test]
    fn failures_leave_no_file_behind() {
        let dir = tempfile::tempdir().unwrap();
        let map = ramp(8, 8, 1.0);
        let missing = dir.path().join("no-such-folder").join("x.exr");
        let err = write_exr(
            &missing,
            Overwrite::Refuse,
            &map,
            None,
            &Provenance::default(),
            ExrOptions::default(),
        )
        .unwrap_err();
        assert!(err.to_string().contains("x.exr"), "{err}");
        // An encoder failure inside the atomic publish (confidence of the wrong size).
        let path = dir.path().join("y.exr");
        let err = write_exr(
            &path,
            Overwrite::Refuse,
            &map,
            Some(&[1.0]),
            &Provenance::default(),
            ExrOptions::default(),
        )
        .unwrap_err();
        assert!(err.to_string().contains("y.exr"), "{err}");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
        write_exr(
            &path,
            Overwrite::Refuse,
            &map,
            None,
            &Provenance::default(),
            ExrOptions::default(),
        )
        .unwrap();
        let again = write_exr(
            &path,
            Overwrite::Refuse,
            &map,
            None,
            &Provenance::default(),
            ExrOptions::default(),
        );
        assert!(matches!(
            again,
            Err(OutputError::Publish(PublishError::Exists { .. }))
        ));
        let hdr = dir.path().join("y.hdr");
        write_radiance_hdr(&hdr, Overwrite::Refuse, &map).unwrap();
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 2);
    }
}
