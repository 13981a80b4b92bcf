//! Writing a radiance map: OpenEXR (the default) or Radiance `.hdr`.
//!
//! Values are written on the scale the darkroom chose ([`crate::merge::Scale`]): luminance
//! in cd/m² anchored to the EXIF exposure (then the standard `whiteLuminance` says cd/m² of
//! RGB (1, 1, 1)), or, without usable EXIF, the merge's relative scale (1.0 = brightness
//! `g⁻¹(1)` in the longest exposure, no `whiteLuminance`). The OpenEXR header says where
//! they came from: chromaticities (Rec.709/sRGB primaries, D65 white by default — filmback
//! reads no ICC profile, and camera JPEGs are sRGB unless set otherwise — or ACES AP0/AP1,
//! see [`Primaries`]), the Color Interop Forum's `colorInteropID` string (`lin_rec709_scene`,
//! `lin_ap0_scene`, `lin_ap1_scene`), `software`, `capDate`/`utcOffset`, the
//! standard `cameraMake`, `cameraModel`, `cameraSerialNumber`, and the standard
//! `expTime`/`aperture`/`isoSpeed` of the longest frame (the reference of the scale).
//! filmback's own string attributes: `filmbackFrame<k>` (one per frame, darkest first:
//! file, time, f-number, ISO, relative exposure), `filmbackExposureRatio` (double,
//! `e_max/e_min`), `filmbackResponse` (the response model summary), `filmbackWeighting`,
//! `filmbackClipped` (samples clipped in every frame), `filmbackScale` (the convention in
//! words), `filmbackScaleKind` (`luminance`, `luminance-calibrated` or `relative`),
//! `filmbackAlignment` (the reference frame and each frame's transform, see
//! [`crate::align::Alignment::describe`]) and
//! `filmbackRadianceScale` (float: the factor applied for half overflow, else 1; the
//! `whiteLuminance` already accounts for it).
//!
//! Half (`f16`, default) keeps 10 bits of mantissa over 30 stops, ample for radiance that
//! came from 8–16-bit frames, in half the space of `f32`. Its largest value is 65 504:
//! with a bracket spanning more than 16 stops the brightest samples would overflow to ∞,
//! so they are either scaled (the whole image by a power of two, exact in binary
//! floating point, recorded in `filmbackRadianceScale`) or clamped, with a warning.
//!
//! Compression (see [`ExrCompression`]): PIZ by default, a lossless wavelet coder that does
//! best on noisy photographic data; lossy coders only when asked for by name. Half PIZ
//! blocks are compressed by filmback's own encoder (`piz`: the same format and size as
//! exr's, faster; `docs/performance.md`); everything else by the exr crate.
//!
//! The same input gives the same file, byte for byte: the header's attributes are
//! written sorted by name (`attribute_order`), the blocks in increasing line order.
//!
//! Every file is published through [`crate::atomic`]: a failure (unwritable
//! folder, full disk, encoder error) leaves no partial file.

use std::io::{Seek, Write};
use std::path::{Path, PathBuf};

use exr::block::chunk::{Chunk, CompressedBlock, CompressedScanLineBlock};
use exr::block::writer::ChunksWriter;
use exr::block::{BlockIndex, UncompressedBlock};
use exr::meta::BlockDescription;
use exr::meta::header::Header;
use exr::prelude::{self as x, ChannelDescription, LineOrder, SampleType, SmallVec, Vec2, f16};
use half::slice::{HalfBitsSliceExt, HalfFloatSliceExt};
use rayon::prelude::*;

use crate::atomic::{self, Overwrite, PublishError};
use crate::metadata::{Camera, CaptureTime, Exposure};
use crate::radiance::{Gamut, RadianceMap, RadianceSource};

mod attribute_order;
mod header;
mod piz;

use header::{image_attributes, layer_attributes, text};

/// The largest finite half-precision value.
pub const HALF_MAX: f32 = 65504.0;

/// Sample type of the OpenEXR channels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum SampleFormat {
    /// 16-bit float: 10-bit mantissa, at most 65 504 (default).
    #[default]
    Half,
    /// 32-bit float.
    Float,
}

/// OpenEXR compression. Lossless unless the name says otherwise.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum ExrCompression {
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

impl ExrCompression {
    fn exr(self) -> x::Compression {
        match self {
            ExrCompression::None => x::Compression::Uncompressed,
            ExrCompression::Rle => x::Compression::RLE,
            ExrCompression::Zip => x::Compression::ZIP16,
            ExrCompression::Piz => x::Compression::PIZ,
            ExrCompression::Pxr24 => x::Compression::PXR24,
            ExrCompression::B44 => x::Compression::B44,
        }
    }
}

/// What to do with values above [`HALF_MAX`] when writing half.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum Overflow {
    /// Multiply the whole image by the largest power of two `2⁻ⁿ` that brings the maximum
    /// to at most 65 504 (default): nothing is lost, the factor is in the header.
    #[default]
    Scale,
    /// Clamp those samples to 65 504: the rest keeps the merge's scale.
    Clamp,
}

/// The RGB primaries of the OpenEXR file. The merge works in linear Rec. 709 (D65);
/// the others are converted to when the file is written (the renderings stay Rec. 709 /
/// sRGB). With `M_P` the RGB → XYZ matrix of primaries `P` and white `W_P` (from their
/// chromaticities, `Y_W = 1`) and the Bradford adaptation `CAT(D65 → W_P)`:
///
/// `rgb_P = M_P⁻¹ · CAT(D65 → W_P) · M_709 · rgb_709`
///
/// so a Rec. 709 neutral stays neutral (R = G = B) in every output.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Primaries {
    /// ITU-R BT.709 / sRGB primaries, D65 white (default).
    #[default]
    Rec709,
    /// ACES2065-1: AP0 primaries, ACES white (x 0.32168, y 0.33767).
    Ap0,
    /// ACEScg: AP1 primaries, ACES white.
    Ap1,
}

impl Primaries {
    /// The gamut: red, green, blue and white chromaticities `(x, y)`.
    pub fn gamut(self) -> Gamut {
        match self {
            Primaries::Rec709 => Gamut::REC709,
            Primaries::Ap0 => Gamut::AP0,
            Primaries::Ap1 => Gamut::AP1,
        }
    }

    /// The Color Interop Forum identifier of linear scene-referred data in these primaries.
    pub(crate) fn interop_id(self) -> &'static str {
        match self {
            Primaries::Rec709 => "lin_rec709_scene",
            Primaries::Ap0 => "lin_ap0_scene",
            Primaries::Ap1 => "lin_ap1_scene",
        }
    }

    /// The 3×3 matrix (row-major) from linear Rec. 709 to these primaries (see the type's
    /// docs); the identity for Rec. 709.
    pub(crate) fn matrix_from_709(self) -> [[f64; 3]; 3] {
        Gamut::REC709.matrix_to(self.gamut())
    }
}

/// How to write the OpenEXR file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ExrOptions {
    /// Half (default) or float.
    pub sample: SampleFormat,
    /// ExrCompression (default PIZ).
    pub compression: ExrCompression,
    /// Half overflow handling (default: scale).
    pub overflow: Overflow,
    /// RGB primaries of the file (default Rec. 709).
    pub primaries: Primaries,
}

impl ExrOptions {
    /// Whether an RGB map written with these options is an ACES image container file
    /// (SMPTE ST 2065-4: AP0 primaries with the ACES white, half floats, no compression,
    /// scan lines, R, G and B only — so no confidence channel), whose header then carries
    /// `acesImageContainerFlag = 1`.
    fn is_aces_container(&self) -> bool {
        self.primaries == Primaries::Ap0
            && self.sample == SampleFormat::Half
            && self.compression == ExrCompression::None
    }
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
    /// The scale of the values.
    pub scale: crate::merge::Scale,
    /// What deghosting did (reference frame, share of pixels), when it left any frame out.
    pub deghost: Option<String>,
    /// The frames' alignment as [`crate::align::Alignment::describe`] writes it (reference
    /// frame, per frame its model and matrix); `None` when not recorded.
    pub alignment: Option<String>,
}

/// What writing did beyond the pixels.
#[derive(Debug, Clone, PartialEq)]
pub struct Written {
    /// Factor applied to every value (1 unless half overflow was scaled).
    pub scale: f32,
    /// Human-readable warnings (overflow handling).
    pub warnings: Vec<String>,
}

/// Why a radiance map could not be encoded (encoding it again would fail again).
#[derive(Debug, thiserror::Error)]
pub enum EncodeError {
    /// The OpenEXR encoder failed.
    #[error("cannot encode OpenEXR: {0}")]
    Exr(#[source] exr::error::Error),
    /// The Radiance HDR encoder failed.
    #[error("cannot encode Radiance HDR: {0}")]
    Hdr(#[source] image::ImageError),
    /// The confidence layer does not have one value per pixel.
    #[error("confidence layer has {got} values for {expected} pixels")]
    ConfidenceShape {
        /// Values given.
        got: usize,
        /// Pixels in the map.
        expected: usize,
    },
}

/// Why a radiance map could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    /// The file could not be published (it exists, unwritable folder, full disk);
    /// nothing was left behind.
    #[error(transparent)]
    Publish(#[from] PublishError),
    /// The encoder refused the radiance (not a failure to write: writing again would fail
    /// again); nothing was left behind.
    #[error("{path}: {source}")]
    Encode {
        /// The file it was encoding.
        path: PathBuf,
        /// Why.
        source: EncodeError,
    },
    /// An OpenEXR file could not be read.
    #[error("{path}: cannot read OpenEXR: {source}")]
    Read {
        /// The EXR file.
        path: PathBuf,
        /// What the reader said.
        source: exr::error::Error,
    },
    /// An OpenEXR file's first RGB layer is not a whole picture.
    #[error("{path}: {source}")]
    Shape {
        /// The EXR file.
        path: PathBuf,
        /// How the layer falls short.
        source: crate::radiance::ShapeError,
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
    atomic::publish_with(path, overwrite, |w| {
        encode_exr(w, map, confidence, provenance, options).map_err(|source| OutputError::Encode {
            path: path.to_path_buf(),
            source,
        })
    })
}

/// Encodes `map` as OpenEXR into `writer` (see [`write_exr`]): the header
/// (`exr_layout`), then the scan-line blocks, PIZ on half samples by filmback's own
/// encoder (`piz_chunk`), every other compression by `exr`'s, the samples pulled from
/// `map` on rayon's threads (`SampleSource`).
pub fn encode_exr<W: Write + Seek, S: RadianceSource + ?Sized>(
    writer: W,
    map: &S,
    confidence: Option<&[f32]>,
    provenance: &Provenance,
    options: ExrOptions,
) -> Result<Written, EncodeError> {
    let (width, height) = (map.width() as usize, map.height() as usize);
    if let Some(conf) = confidence
        && conf.len() != width * height
    {
        return Err(EncodeError::ConfidenceShape {
            got: conf.len(),
            expected: width * height,
        });
    }
    let (scale, limit, warnings) = overflow(map, options);
    let layout = exr_layout(map, confidence, provenance, options, scale);
    let samples = SampleSource {
        map,
        matrix: (layout.primaries != Primaries::Rec709).then(|| {
            layout
                .primaries
                .matrix_from_709()
                .map(|row| row.map(|v| v as f32))
        }),
        scale,
        limit,
    };
    let (planes, sample) = (&layout.planes, layout.sample);
    let piz_half = options.compression == ExrCompression::Piz && sample == SampleType::F16;
    // The header's attributes sorted by name, so that the same input gives the same bytes.
    let mut sorted = attribute_order::SortedHeader::new(writer);
    exr::block::write(
        &mut sorted,
        smallvec_of(layout.header),
        true,
        |meta, chunks| {
            let indices: Vec<(usize, BlockIndex)> =
                meta.enumerate_ordered_header_block_indices().collect();
            if piz_half {
                // Blocks compressed a batch at a time on rayon's threads, written in order.
                let batch = 4 * rayon::current_num_threads();
                for batch in indices.chunks(batch) {
                    let compressed: Vec<(usize, Chunk)> = batch
                        .par_iter()
                        .map(|&(i, index)| (i, piz_chunk(index, width, planes, &samples)))
                        .collect();
                    for (i, chunk) in compressed {
                        chunks.write_chunk(i, chunk)?;
                    }
                }
                return Ok(());
            }
            // exr compresses on its own threads but asks for blocks on this one: fill them a
            // few at a time on rayon's threads so that the samples, not just the
            // compression, are computed in parallel.
            let batch = 2 * rayon::current_num_threads();
            let blocks = indices.chunks(batch).flat_map(|batch| {
                batch
                    .par_iter()
                    .map(|&(i, index)| {
                        let data = block_bytes(index, width, planes, sample, &samples);
                        (i, UncompressedBlock { index, data })
                    })
                    .collect::<Vec<_>>()
            });
            chunks
                .on_progress(|_| {})
                .compress_all_blocks_parallel(&meta, blocks)
        },
    )
    .map_err(EncodeError::Exr)?;
    sorted.finish().map_err(|e| EncodeError::Exr(e.into()))?;
    Ok(Written { scale, warnings })
}

/// An EXR file's header and the channels it stores.
struct ExrLayout<'c> {
    /// The header (attributes unsorted: [`attribute_order`] sorts them on the way out).
    header: Header,
    /// The file's channels in its (alphabetical) order, each with where its values come
    /// from.
    planes: Vec<(&'static str, Plane<'c>)>,
    /// Half or float.
    sample: SampleType,
    /// The primaries the colour channels are in (Rec. 709 for a grey map).
    primaries: Primaries,
}

/// The header of `map`'s EXR file: its channels (`B G R` or `Y`, and `confidence.Y` with
/// a confidence layer), the compression, the provenance and primaries attributes, and
/// `acesImageContainerFlag` when the file is an ACES container.
fn exr_layout<'c, S: RadianceSource + ?Sized>(
    map: &S,
    confidence: Option<&'c [f32]>,
    provenance: &Provenance,
    options: ExrOptions,
    scale: f32,
) -> ExrLayout<'c> {
    let sample = match options.sample {
        SampleFormat::Half => SampleType::F16,
        SampleFormat::Float => SampleType::F32,
    };
    let mut planes: Vec<(&'static str, Plane<'c>)> = match map.channels() {
        3 => vec![
            ("B", Plane::Colour(2)),
            ("G", Plane::Colour(1)),
            ("R", Plane::Colour(0)),
        ],
        _ => vec![("Y", Plane::Colour(0))],
    };
    if let Some(conf) = confidence {
        planes.push(("confidence.Y", Plane::Confidence(conf)));
    }
    let descriptions = planes
        .iter()
        .map(|(name, plane)| {
            ChannelDescription::new(*name, sample, matches!(plane, Plane::Confidence(_)))
        })
        .collect();
    let size = Vec2(map.width() as usize, map.height() as usize);
    let mut header = Header::new(text("radiance"), size, SmallVec::from_vec(descriptions))
        .with_encoding(
            options.compression.exr(),
            BlockDescription::ScanLines,
            LineOrder::Increasing,
        );
    let primaries = if map.channels() == 3 {
        options.primaries
    } else {
        Primaries::Rec709
    };
    header.own_attributes = layer_attributes(provenance, scale, primaries);
    header.shared_attributes = image_attributes(size, primaries);
    if options.is_aces_container() && map.channels() == 3 && confidence.is_none() {
        header
            .own_attributes
            .other
            .insert(text("acesImageContainerFlag"), x::AttributeValue::I32(1));
    }
    ExrLayout {
        header,
        planes,
        sample,
        primaries,
    }
}

/// Where a file channel's values come from.
enum Plane<'c> {
    /// Channel `c` of the radiance.
    Colour(usize),
    /// The confidence layer, one value per pixel.
    Confidence(&'c [f32]),
}

/// The samples an EXR stores, pulled from the radiance map a line at a time (so a lazy
/// merge is evaluated on the worker threads): `min(scale · M·v, limit)`, `M` the Rec. 709
/// → file primaries matrix (none for Rec. 709) and `v` the map's RGB.
struct SampleSource<'m, S: ?Sized> {
    /// The radiance.
    map: &'m S,
    /// Rec. 709 → the file's primaries, when they differ.
    matrix: Option<[[f32; 3]; 3]>,
    /// The overflow factor ([`Written::scale`]).
    scale: f32,
    /// The largest value stored.
    limit: f32,
}

impl<S: RadianceSource + ?Sized> SampleSource<'_, S> {
    /// Fills `line` with the values of `plane` from pixel `start` on.
    fn fill(&self, plane: &Plane<'_>, start: usize, line: &mut [f32]) {
        match plane {
            Plane::Colour(c) => {
                match &self.matrix {
                    None => self.map.line(start, *c, line),
                    Some(m) => {
                        // One row of the matrix over the three Rec. 709 channels.
                        let mut other = vec![0f32; line.len()];
                        self.map.line(start, 0, line);
                        for v in line.iter_mut() {
                            *v *= m[*c][0];
                        }
                        for (k, &weight) in m[*c].iter().enumerate().skip(1) {
                            self.map.line(start, k, &mut other);
                            for (v, o) in line.iter_mut().zip(&other) {
                                *v += weight * o;
                            }
                        }
                    }
                }
                for v in line.iter_mut() {
                    *v = (*v * self.scale).min(self.limit);
                }
            }
            Plane::Confidence(conf) => line.copy_from_slice(&conf[start..start + line.len()]),
        }
    }
}

/// The uncompressed bytes of one scan-line block for `exr`'s compressors: per line, per
/// channel, the samples as `sample` in native-endian order.
fn block_bytes<S: RadianceSource + ?Sized>(
    index: BlockIndex,
    width: usize,
    planes: &[(&str, Plane<'_>)],
    sample: SampleType,
    samples: &SampleSource<'_, S>,
) -> Vec<u8> {
    let (x0, y0) = (index.pixel_position.0, index.pixel_position.1);
    let (w, h) = (index.pixel_size.0, index.pixel_size.1);
    let bytes = if sample == SampleType::F16 { 2 } else { 4 };
    let mut data = Vec::with_capacity(w * h * planes.len() * bytes);
    let mut line = vec![0f32; w];
    let mut halves = vec![f16::ZERO; w];
    for y in y0..y0 + h {
        for (_, plane) in planes {
            samples.fill(plane, y * width + x0, &mut line);
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
}

/// One scan-line block compressed by [`piz::compress`]: the block's samples as half, plane
/// by plane in the file's channel order, each plane's lines contiguous. A block that PIZ
/// does not shrink is stored raw (per line, per channel, little-endian), as the format
/// requires.
fn piz_chunk<S: RadianceSource + ?Sized>(
    index: BlockIndex,
    width: usize,
    planes: &[(&str, Plane<'_>)],
    samples: &SampleSource<'_, S>,
) -> Chunk {
    let (x0, y0) = (index.pixel_position.0, index.pixel_position.1);
    let (w, h) = (index.pixel_size.0, index.pixel_size.1);
    let mut line = vec![0f32; w];
    let mut fill = |words: &mut [u16]| {
        let halves: &mut [f16] = words.reinterpret_cast_mut();
        for ((_, plane), plane_halves) in planes.iter().zip(halves.chunks_exact_mut(w * h)) {
            for (y, out) in (y0..y0 + h).zip(plane_halves.chunks_exact_mut(w)) {
                samples.fill(plane, y * width + x0, &mut line);
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
    if map.max_value() <= HALF_MAX {
        return (1.0, HALF_MAX, Vec::new());
    }
    let max = map.exact_max();
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

/// Reads the first RGB(A) layer of an OpenEXR file as a radiance map (alpha dropped).
pub fn read_exr(path: &Path) -> Result<RadianceMap, OutputError> {
    let image = exr::prelude::read_first_rgba_layer_from_file(
        path,
        |size, _| (size.width(), vec![0f32; size.width() * size.height() * 3]),
        |(width, pixels): &mut (usize, Vec<f32>), pos, (r, g, b, _a): (f32, f32, f32, f32)| {
            let i = (pos.y() * *width + pos.x()) * 3;
            pixels[i..i + 3].copy_from_slice(&[r, g, b]);
        },
    )
    .map_err(|source| OutputError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    let size = image.layer_data.size;
    let (_, pixels) = image.layer_data.channel_data.pixels;
    RadianceMap::new(size.width() as u32, size.height() as u32, 3, pixels).map_err(|source| {
        OutputError::Shape {
            path: path.to_path_buf(),
            source,
        }
    })
}

/// Writes `map` as a Radiance RGBE `.hdr` file at `path`, atomically (grey maps are
/// written as three equal channels).
pub fn write_radiance_hdr<S: RadianceSource + ?Sized>(
    path: &Path,
    overwrite: Overwrite,
    map: &S,
) -> Result<(), OutputError> {
    atomic::publish_with(path, overwrite, |w| {
        encode_radiance_hdr(w, map).map_err(|source| OutputError::Encode {
            path: path.to_path_buf(),
            source,
        })
    })
}

/// Encodes `map` as Radiance RGBE into `writer` (see [`write_radiance_hdr`]).
pub(crate) fn encode_radiance_hdr<W: Write, S: RadianceSource + ?Sized>(
    writer: W,
    map: &S,
) -> Result<(), EncodeError> {
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
        .map_err(EncodeError::Hdr)
}

#[cfg(test)]
mod tests;
