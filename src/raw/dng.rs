//! A merged raw bracket as a linear DNG for raw converters (Lightroom, Camera Raw,
//! darktable, RawTherapee): the merged mosaic of [`super::mosaic`] in the camera's own
//! colour filter array, as 32-bit floating point (DNG 1.4), written by rawler's DNG
//! writer.
//!
//! # What the file holds
//!
//! The mosaic before white balance and demosaicking, one sample per pixel of the colour
//! the CFA puts there, the same CFA and visible area as the frames. With `x` the merged
//! radiance in units of the longest frame's clipping point and `R = e_longest/e_shortest`
//! the bracket's exposure ratio, a sample stores
//!
//! ```text
//! v = x / R,      BlackLevel 0, WhiteLevel 1
//! ```
//!
//! so 1.0 is the clipping point of the shortest frame (the brightest value the bracket
//! records) and the longest frame's clipping point reads `1/R`. The EXR's Rec. 709
//! values are `c · M · diag(1/n) · demosaic(R·v)`, with `M` and `n` of
//! [`super::colour`] and `c` the luminance factor of [`crate::merge::exposure_scale`].
//! Samples a little below 0 (read noise below the black level) are kept; samples
//! clipped in every frame hold their lower bound, as in the EXR.
//!
//! Tags: the CFA (`CFAPattern`, `CFARepeatPatternDim`), `AsShotNeutral` (the first
//! frame's as-shot neutral), every `ColorMatrix` the frames' file has with its
//! `CalibrationIlluminant` (rawler's writer takes standard light A as the first and D65
//! or D50 as the second), `Make`, `Model`, `UniqueCameraModel`, `BaselineExposure`
//! ([`baseline_exposure`]), and in EXIF the shortest frame's exposure time, f-number and
//! ISO (the exposure whose clipping point is 1.0) and its capture time. rawler reads no
//! `ForwardMatrix` from raw files, so none is written; a converter then derives it from
//! the colour matrix, as the DNG specification allows.
//!
//! # Why floating point, and why the mosaic
//!
//! A merged bracket holds more range than 16-bit integers keep at a useful step: a
//! 14-bit sensor bracketed over 4 stops has 18 bits of range, and the merge's gain is
//! precisely in the shadows, which integer codes scaled to the brightest value would
//! round away. 32-bit float keeps every value of the merge exactly (a relative step of
//! 2⁻²⁴), so a reader gets what the EXR was made from. HDRMerge writes 16-, 24- or
//! 32-bit float with deflate; rawler's writer writes float uncompressed only (32 bits,
//! 4 bytes a pixel: 96 MB at 24 MP), and writing our own deflate and floating-point
//! predictor is not worth a smaller file here. The mosaic rather than a demosaicked
//! `LinearRaw` image: the converter then demosaicks with its own (better, and
//! per-camera) method and applies its own profile to camera RGB, the file is a third of
//! the size, and it is what HDRMerge and dnglab make of a bracket.
//!
//! # Readers
//!
//! rawler reads the file back to the same 32-bit values (`tests/dng.rs`). LibRaw (and so
//! rawpy, darktable, RawTherapee) reads it through its floating-point DNG support but
//! converts the samples to 16-bit integers on load, scaled so the largest value is
//! 16383: it sees the values to within 2⁻¹⁴ of the brightest (`tests/dng_check.py`).

use std::collections::HashMap;
use std::io::Cursor;

use rawler::cfa::{CFA, PlaneColor};
use rawler::decoders::{Camera, Orientation};
use rawler::dng::writer::DngWriter;
use rawler::dng::{CropMode, DNG_VERSION_V1_4, DngCompression, DngPhotometricConversion};
use rawler::formats::tiff::{Rational, SRational, TiffError};
use rawler::imgop::xyz::Illuminant;
use rawler::rawimage::{
    BlackLevel, CFAConfig, RawImage, RawImageData, RawPhotometricInterpretation, WhiteLevel,
};
use rawler::tags::{DngTag, ExifTag, TiffCommonTag};

use super::RawInfo;
use super::mosaic::MergedMosaic;

/// The longest edge a DNG written here may have: rawler's writer stores the active area
/// in 16-bit fields.
pub const MAX_EDGE: usize = 65_535;

/// Why a merged mosaic could not be encoded as DNG.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DngError {
    /// The mosaic is empty, its values do not fill it, or an edge exceeds [`MAX_EDGE`].
    #[error("a DNG cannot hold a mosaic of {width}×{height} pixels with {values} values")]
    Size {
        /// Width in pixels.
        width: usize,
        /// Height in pixels.
        height: usize,
        /// Values given.
        values: usize,
    },
    /// The exposure ratio is not a finite number of at least 1.
    #[error("exposure ratio {0} is not a finite number of at least 1")]
    Ratio(f64),
    /// The CFA is not one rawler's writer knows.
    #[error("colour filter array {0} cannot be written")]
    Cfa(String),
    /// rawler's TIFF writer failed.
    #[error("cannot encode the DNG")]
    Encode {
        /// What the writer said.
        #[source]
        source: TiffError,
    },
}

impl From<TiffError> for DngError {
    fn from(source: TiffError) -> DngError {
        DngError::Encode { source }
    }
}

/// What [`encode`] writes: the merged mosaic and the frames it came from.
#[derive(Debug, Clone, Copy)]
pub struct DngBracket<'a> {
    /// The merged mosaic (radiance in units of the longest frame's clipping point).
    pub mosaic: &'a MergedMosaic,
    /// The frame whose colour the EXR used (CFA, neutral, matrices, camera): the first.
    pub colour: &'a RawInfo,
    /// The shortest frame: its exposure and capture time go into EXIF.
    pub shortest: &'a RawInfo,
    /// `R`, the longest over the shortest exposure (≥ 1).
    pub ratio: f64,
}

/// `BaselineExposure`, in stops: `½·log₂ R`, which opens the file at the brightness of
/// the bracket's middle exposure (the metered frame of an odd auto-exposure bracket)
/// rather than at that of its shortest, which sets the file's 1.0.
pub fn baseline_exposure(ratio: f64) -> f64 {
    0.5 * ratio.log2()
}

/// The bytes of a DNG of `bracket` (see the module docs for its values and tags).
pub fn encode(bracket: &DngBracket<'_>) -> Result<Vec<u8>, DngError> {
    let mosaic = bracket.mosaic;
    let (width, height) = (mosaic.width, mosaic.height);
    if width == 0
        || height == 0
        || width > MAX_EDGE
        || height > MAX_EDGE
        || mosaic.values.len() != width * height
    {
        return Err(DngError::Size {
            width,
            height,
            values: mosaic.values.len(),
        });
    }
    let ratio = bracket.ratio;
    if !(ratio.is_finite() && ratio >= 1.0) {
        return Err(DngError::Ratio(ratio));
    }
    let image = raw_image(bracket)?;
    let mut buffer = Cursor::new(Vec::with_capacity(4 * width * height + (1 << 16)));
    let mut writer = DngWriter::new(&mut buffer, DNG_VERSION_V1_4)?;
    let mut raw = writer.subframe_on_root(0);
    raw.raw_image(
        &image,
        CropMode::None,
        DngCompression::Uncompressed,
        DngPhotometricConversion::Original,
        1,
    )?;
    raw.finalize()?;
    writer.load_base_tags(&image)?;
    let root = writer.root_ifd_mut();
    let stops = baseline_exposure(ratio);
    root.add_tag(
        DngTag::BaselineExposure,
        SRational::new((stops * 10_000.0).round() as i32, 10_000),
    );
    let software = format!("filmback {}", env!("CARGO_PKG_VERSION"));
    root.add_tag(TiffCommonTag::Software, software.as_str());
    exif(writer.exif_ifd_mut(), bracket.shortest);
    writer.close()?;
    Ok(buffer.into_inner())
}

/// rawler's description of the mosaic: float samples `x/R`, levels 0 and 1, the CFA,
/// neutral and matrices of [`DngBracket::colour`].
fn raw_image(bracket: &DngBracket<'_>) -> Result<RawImage, DngError> {
    let info = bracket.colour;
    let mosaic = bracket.mosaic;
    let name = info.cfa.name();
    let square = info.cfa.width == info.cfa.height && matches!(info.cfa.width, 2 | 6);
    if !square || name.contains('?') || info.cfa.colours.len() != info.cfa.width.pow(2) {
        return Err(DngError::Cfa(name));
    }
    let cfa = CFA::new(&name);
    let mut camera = Camera::new();
    camera.make = info.make.clone();
    camera.model = info.model.clone();
    camera.clean_make = info.make.clone();
    camera.clean_model = info.model.clone();
    camera.cfa = cfa.clone();
    let inverse_r = (1.0 / bracket.ratio) as f32;
    let values: Vec<f32> = mosaic.values.iter().map(|&x| x * inverse_r).collect();
    let mut color_matrix = HashMap::new();
    for &(code, m) in &info.colour_matrices {
        if let Ok(illuminant) = Illuminant::try_from(code) {
            color_matrix.insert(illuminant, m.iter().flatten().map(|&v| v as f32).collect());
        }
    }
    if color_matrix.is_empty() {
        let m = info.xyz_to_camera.iter().flatten().map(|&v| v as f32);
        color_matrix.insert(Illuminant::D65, m.collect());
    }
    let mut xyz_to_cam = [[0.0f32; 3]; 4];
    for (row, m) in xyz_to_cam.iter_mut().zip(&info.xyz_to_camera) {
        *row = m.map(|v| v as f32);
    }
    let n = info.neutral;
    Ok(RawImage {
        make: info.make.clone(),
        model: info.model.clone(),
        clean_make: info.make.clone(),
        clean_model: info.model.clone(),
        camera,
        width: mosaic.width,
        height: mosaic.height,
        cpp: 1,
        bps: 32,
        // rawler's white-balance coefficients are the reciprocal of the as-shot neutral.
        wb_coeffs: [
            (1.0 / n[0]) as f32,
            (1.0 / n[1]) as f32,
            (1.0 / n[2]) as f32,
            f32::NAN,
        ],
        whitelevel: WhiteLevel(vec![1]),
        blacklevel: BlackLevel::new(&[0u32], 1, 1, 1),
        xyz_to_cam,
        photometric: RawPhotometricInterpretation::Cfa(CFAConfig::new(
            &cfa,
            &PlaneColor::new("RGB"),
        )),
        active_area: None,
        crop_area: None,
        blackareas: Vec::new(),
        orientation: Orientation::Normal,
        data: RawImageData::Float(values),
        color_matrix,
        dng_tags: HashMap::new(),
        fuji_rotation_width: None,
    })
}

/// The EXIF of the shortest frame: exposure time, f-number, ISO, capture time.
fn exif(ifd: &mut rawler::formats::tiff::writer::DirectoryWriter, shortest: &RawInfo) {
    let micro = |v: f64| Rational::new((v * 1e6).round().clamp(0.0, 4e9) as u32, 1_000_000);
    if let Some(t) = shortest
        .exposure_time_s
        .filter(|t| t.is_finite() && *t > 0.0)
    {
        ifd.add_tag(ExifTag::ExposureTime, micro(t));
    }
    if let Some(n) = shortest.f_number.filter(|n| n.is_finite() && *n > 0.0) {
        ifd.add_tag(ExifTag::FNumber, micro(n));
    }
    if let Some(iso) = shortest.iso.filter(|i| i.is_finite() && *i > 0.0) {
        ifd.add_tag(
            ExifTag::ISOSpeedRatings,
            iso.round().clamp(1.0, 65_535.0) as u16,
        );
    }
    if let Some(date) = &shortest.captured {
        ifd.add_tag(ExifTag::DateTimeOriginal, date.as_str());
    }
}
