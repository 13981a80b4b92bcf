//! Decoding a raw file with rawler into a [`RawMosaic`].

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::Path;

use rawler::decoders::RawDecodeParams;
use rawler::imgop::xyz::Illuminant;
use rawler::rawimage::{RawImageData, RawPhotometricInterpretation};
use rawler::rawsource::RawSource;
use rawler::{CFA, RawlerError};

use super::{Cfa, RawError, RawInfo, RawMosaic};

/// File extensions (lower case) read as camera raw.
pub(crate) const RAW_EXTENSIONS: &[&str] = &[
    "dng", "cr2", "cr3", "crw", "nef", "nrw", "arw", "srf", "sr2", "raf", "orf", "rw2", "pef",
    "srw", "iiq", "3fr", "erf", "kdc", "dcr", "mos", "mef", "mrw", "x3f",
];

/// True when `path`'s extension names a camera raw format.
pub(crate) fn is_raw_extension(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| RAW_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
}

/// Decodes the raw in `bytes` (`path` names it in errors): the visible area of its mosaic
/// (the crop the file recommends, else its active area) with levels, CFA, colour matrix,
/// as-shot neutral and EXIF exposure.
///
/// Refused, with the camera's name and the reason: cameras rawler does not support,
/// sensors that are not RGB Bayer or X-Trans (monochrome, CYGM, Foveon), and raws already
/// demosaicked (linear DNG, sRAW). The mosaic is not rotated: raw frames keep the
/// sensor's orientation.
///
/// The sensor's size is read first, without decoding (rawler's "dummy" image): a file
/// declaring more than `max_pixels` is refused before its pixels are allocated. Before
/// that, a TIFF-based file's IFDs are walked and a damaged structure refused
/// ([`RawError::Structure`]).
pub fn decode(path: &Path, bytes: &[u8], max_pixels: u64) -> Result<RawMosaic, RawError> {
    sound_structure(path, bytes)?;
    let _file = decoder_span(path).entered();
    catch_unwind(AssertUnwindSafe(|| {
        decode_unguarded(path, bytes, max_pixels)
    }))
    .unwrap_or_else(|_| Err(panicked(path)))
}

/// What a raw's metadata says about its capture, read without decoding the image.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct RawExif {
    /// Maker.
    pub make: String,
    /// Model.
    pub model: String,
    /// Exposure time in seconds.
    pub exposure_time_s: Option<f64>,
    /// F-number.
    pub f_number: Option<f64>,
    /// ISO speed.
    pub iso: Option<f64>,
    /// Capture time as written (`YYYY:MM:DD HH:MM:SS`).
    pub captured: Option<String>,
}

/// Reads the capture metadata of the raw in `bytes` (camera, exposure, capture time) and
/// its sensor's size `(width, height)` in pixels, without decoding its pixels: an
/// unsupported camera, or a damaged TIFF structure ([`RawError::Structure`]), is refused
/// here already.
pub fn probe(path: &Path, bytes: &[u8]) -> Result<(RawExif, (u32, u32)), RawError> {
    sound_structure(path, bytes)?;
    let _file = decoder_span(path).entered();
    let guarded = catch_unwind(AssertUnwindSafe(|| {
        let source = RawSource::new_from_slice(bytes);
        let params = RawDecodeParams::default();
        let decoder = rawler::get_decoder(&source).map_err(|e| failed(path, e))?;
        let metadata = decoder
            .raw_metadata(&source, &params)
            .map_err(|e| failed(path, e))?;
        let header = decoder
            .raw_image(&source, &params, true)
            .map_err(|e| failed(path, e))?;
        let size = (
            u32::try_from(header.width).unwrap_or(u32::MAX),
            u32::try_from(header.height).unwrap_or(u32::MAX),
        );
        Ok((exif_of(metadata.make, metadata.model, &metadata.exif), size))
    }));
    guarded.unwrap_or_else(|_| Err(panicked(path)))
}

/// The span rawler's own warnings (through `log`) are logged in: they name no file, the
/// span does (`raw{file=IMG_1.CR2}: …`).
fn decoder_span(path: &Path) -> tracing::Span {
    tracing::info_span!("raw", file = %path.display())
}

/// A camera's name for messages, `make model`; "an unknown camera" when the file names
/// none.
fn camera_name(make: &str, model: &str) -> String {
    let name = format!("{make} {model}").trim().to_string();
    if name.is_empty() {
        "an unknown camera".to_string()
    } else {
        name
    }
}

/// [`super::structure::check`] with the file named in the error.
fn sound_structure(path: &Path, bytes: &[u8]) -> Result<(), RawError> {
    super::structure::check(bytes).map_err(|source| RawError::Structure {
        path: path.to_path_buf(),
        source,
    })
}

fn panicked(path: &Path) -> RawError {
    RawError::Decode {
        path: path.to_path_buf(),
        reason: "the raw decoder panicked on this file (malformed data)".to_string(),
    }
}

fn exif_of(make: String, model: String, exif: &rawler::exif::Exif) -> RawExif {
    let rational =
        |r: &rawler::formats::tiff::Rational| (r.d != 0).then(|| f64::from(r.n) / f64::from(r.d));
    RawExif {
        make,
        model,
        exposure_time_s: exif.exposure_time.as_ref().and_then(rational),
        f_number: exif.fnumber.as_ref().and_then(rational),
        iso: exif
            .iso_speed_ratings
            .map(f64::from)
            .or(exif.iso_speed.map(f64::from)),
        captured: exif.date_time_original.clone(),
    }
}

fn failed(path: &Path, error: RawlerError) -> RawError {
    match error {
        RawlerError::Unsupported {
            what, model, make, ..
        } => RawError::Unsupported {
            path: path.to_path_buf(),
            camera: camera_name(&make, &model),
            reason: what,
        },
        RawlerError::DecoderFailed(reason) => RawError::Decode {
            path: path.to_path_buf(),
            reason,
        },
    }
}

/// Keeps the `width × height` area at `(x0, y0)` of the row-major `data` (rows of
/// `stride` samples), compacted to its start: each row moves to a lower index, so rows
/// copied in order never overwrite one still to come. The area lies within `data`.
fn crop_in_place(
    data: &mut Vec<u16>,
    stride: usize,
    (x0, y0, width, height): (usize, usize, usize, usize),
) {
    if (x0, y0, width) != (0, 0, stride) {
        for row in 0..height {
            let from = (y0 + row) * stride + x0;
            data.copy_within(from..from + width, row * width);
        }
    }
    data.truncate(width * height);
}

/// [`decode`] without its guard against the decoder's panics: the image decoded within
/// `max_pixels`, its mosaic checked, then its visible area, levels and colour read.
fn decode_unguarded(path: &Path, bytes: &[u8], max_pixels: u64) -> Result<RawMosaic, RawError> {
    let Decoded { mut image, exif } = decode_image(path, bytes, max_pixels)?;
    let refuse = Refusal {
        path,
        camera: camera_name(&image.clean_make, &image.clean_model),
    };
    let cfa = bayer_or_xtrans(&image, &refuse)?;
    let RawImageData::Integer(data) = &image.data else {
        return Err(refuse.unsupported(FLOAT_DATA));
    };
    let area = visible_area(path, &image, data.len())?;
    let cfa = visible_cfa(&cfa, area);
    let levels = levels(path, &image, area)?;
    let neutral = as_shot_neutral(&image);
    let colour = colour_matrices(&image, &refuse)?;
    let codes = visible_codes(&mut image, area, &refuse)?;
    Ok(RawMosaic {
        width: u32::try_from(area.width).map_err(|_| refuse.unsupported("too wide"))?,
        height: u32::try_from(area.height).map_err(|_| refuse.unsupported("too tall"))?,
        codes,
        info: RawInfo {
            make: image.clean_make.clone(),
            model: image.clean_model.clone(),
            bits: image.bps as u32,
            cfa,
            black: levels.black,
            black_width: levels.black_width,
            black_height: levels.black_height,
            white: levels.white,
            neutral,
            xyz_to_camera: colour.xyz_to_camera,
            matrix_illuminant: light_source_name(colour.illuminant).to_string(),
            colour_matrices: colour.all,
            exposure_time_s: exif.exposure_time_s,
            f_number: exif.f_number,
            iso: exif.iso,
            captured: exif.captured,
        },
    })
}

/// The reason a raw of floating-point samples is refused.
const FLOAT_DATA: &str = "floating-point raw data: only integer mosaics are merged";

/// A decoded raw image and its capture metadata (defaults when the file has none).
struct Decoded {
    image: rawler::RawImage,
    exif: RawExif,
}

/// Decodes the image in `bytes`, refusing one of more than `max_pixels` pixels twice: by
/// the size its header declares, before the pixels are decoded, and by the size decoded,
/// so that a file whose header understates its size is refused before anything larger
/// (the demosaicked map) is made of it.
fn decode_image(path: &Path, bytes: &[u8], max_pixels: u64) -> Result<Decoded, RawError> {
    let failed = |error: RawlerError| failed(path, error);
    let source = RawSource::new_from_slice(bytes);
    let params = RawDecodeParams::default();
    let within_limit = |width: usize, height: usize| {
        if (width as u64).saturating_mul(height as u64) > max_pixels {
            return Err(RawError::TooLarge {
                path: path.to_path_buf(),
                width,
                height,
                max_pixels,
            });
        }
        Ok(())
    };
    let decoder = rawler::get_decoder(&source).map_err(failed)?;
    let header = decoder.raw_image(&source, &params, true).map_err(failed)?;
    within_limit(header.width, header.height)?;
    drop(header);
    let image = decoder.raw_image(&source, &params, false).map_err(failed)?;
    within_limit(image.width, image.height)?;
    let exif = decoder.raw_metadata(&source, &params).map(|m| m.exif).ok();
    let exif = exif_of(
        image.clean_make.clone(),
        image.clean_model.clone(),
        &exif.unwrap_or_default(),
    );
    Ok(Decoded { image, exif })
}

/// The file and camera an unsupported raw's error names.
struct Refusal<'a> {
    path: &'a Path,
    camera: String,
}

impl Refusal<'_> {
    /// [`RawError::Unsupported`] for this file and camera, with `reason`.
    fn unsupported(&self, reason: impl Into<String>) -> RawError {
        RawError::Unsupported {
            path: self.path.to_path_buf(),
            camera: self.camera.clone(),
            reason: reason.into(),
        }
    }
}

/// [`RawError::Decode`] for `path`, with `reason`.
fn malformed(path: &Path, reason: impl Into<String>) -> RawError {
    RawError::Decode {
        path: path.to_path_buf(),
        reason: reason.into(),
    }
}

/// The sensor's colour filter array when it is an RGB mosaic of one sample a pixel that
/// the demosaicking reads: Bayer (2×2, its two greens on a diagonal, the demosaicking's
/// premise) or X-Trans (6×6). Refused otherwise, and for linear raws and monochrome
/// sensors.
fn bayer_or_xtrans(image: &rawler::RawImage, refuse: &Refusal) -> Result<CFA, RawError> {
    let cfa = match &image.photometric {
        RawPhotometricInterpretation::Cfa(config) if image.cpp == 1 && config.cfa.is_rgb() => {
            config.cfa.clone()
        }
        RawPhotometricInterpretation::Cfa(config) => {
            return Err(
                refuse.unsupported(format!("colour filter array {} is not RGB", config.cfa))
            );
        }
        RawPhotometricInterpretation::LinearRaw => {
            return Err(
                refuse.unsupported("already demosaicked (linear raw): only mosaic raws are merged")
            );
        }
        RawPhotometricInterpretation::BlackIsZero => {
            return Err(refuse.unsupported("monochrome sensor"));
        }
    };
    let is_bayer = cfa.width == 2 && cfa.height == 2;
    let is_xtrans = cfa.width == 6 && cfa.height == 6;
    if !(is_bayer || is_xtrans) {
        return Err(refuse.unsupported(format!(
            "colour filter array {cfa} is neither Bayer (2×2) nor X-Trans (6×6)"
        )));
    }
    let diagonal_greens = (cfa.color_at(0, 0) == 1 && cfa.color_at(1, 1) == 1)
        || (cfa.color_at(0, 1) == 1 && cfa.color_at(1, 0) == 1);
    if is_bayer && !diagonal_greens {
        return Err(refuse.unsupported(format!(
            "colour filter array {cfa} is 2×2 without its greens on a diagonal"
        )));
    }
    Ok(cfa)
}

/// A rectangle of the sensor, in pixels.
#[derive(Debug, Clone, Copy)]
struct Area {
    /// Left column.
    x: usize,
    /// Top row.
    y: usize,
    /// Width.
    width: usize,
    /// Height.
    height: usize,
}

/// The visible area of the sensor: the crop the file recommends, else its active area,
/// else the whole sensor. Refused when it is empty or leaves the sensor, or when the
/// image's `samples` do not cover the sensor.
fn visible_area(path: &Path, image: &rawler::RawImage, samples: usize) -> Result<Area, RawError> {
    let (full_width, full_height) = (image.width, image.height);
    let area = match image.crop_area.or(image.active_area) {
        Some(r) => Area {
            x: r.x(),
            y: r.y(),
            width: r.width(),
            height: r.height(),
        },
        None => Area {
            x: 0,
            y: 0,
            width: full_width,
            height: full_height,
        },
    };
    let Area {
        x,
        y,
        width,
        height,
    } = area;
    if width == 0 || height == 0 || x + width > full_width || y + height > full_height {
        return Err(malformed(
            path,
            format!(
                "visible area {width}×{height} at ({x}, {y}) outside the \
                 {full_width}×{full_height} sensor"
            ),
        ));
    }
    if samples < full_width * full_height {
        return Err(malformed(path, "fewer samples than the sensor's size"));
    }
    Ok(area)
}

/// The colour filter array `cfa` of the sensor as the visible `area` starts it, colour
/// indices (0 red, 1 green, 2 blue) row by row.
fn visible_cfa(cfa: &CFA, area: Area) -> Cfa {
    let tile = cfa.shift(area.x, area.y);
    Cfa {
        width: tile.width,
        height: tile.height,
        colours: (0..tile.height)
            .flat_map(|y| (0..tile.width).map(move |x| (y, x)))
            .map(|(y, x)| tile.color_at(y, x) as u8)
            .collect(),
    }
}

/// The black-level tile aligned on the visible area and the white level, in codes.
struct Levels {
    /// Black level per position of the tile, row by row.
    black: Vec<f32>,
    /// Width of the tile.
    black_width: usize,
    /// Height of the tile.
    black_height: usize,
    /// White level (the clipping code).
    white: f32,
}

/// The image's black and white levels over the visible `area`: refused when the black
/// tile is malformed or a black level is not in `[0, white)`.
fn levels(path: &Path, image: &rawler::RawImage, area: Area) -> Result<Levels, RawError> {
    let black = image.blacklevel.shift(area.x, area.y);
    let black_values: Vec<f32> = black.levels.iter().map(|r| r.as_f32()).collect();
    if black.width == 0 || black.height == 0 || black_values.len() < black.width * black.height {
        return Err(malformed(path, "malformed black level"));
    }
    let white = image.whitelevel.0.first().copied().unwrap_or(0) as f32;
    if black_values.iter().any(|&b| !(b >= 0.0 && b < white)) {
        return Err(malformed(
            path,
            format!("black level {black_values:?} not below the white level {white}"),
        ));
    }
    Ok(Levels {
        black: black_values,
        black_width: black.width,
        black_height: black.height,
        white,
    })
}

/// The as-shot neutral, camera RGB of a white surface normalised to green = 1:
/// `[wb_G/wb_R, 1, wb_G/wb_B]` from rawler's white-balance coefficients, which are camera
/// multipliers (the reciprocal of the neutral); from a D65 neutral of the colour matrix
/// when the file has none (rawler's coefficients are then NaN).
fn as_shot_neutral(image: &rawler::RawImage) -> [f64; 3] {
    let wb = if image.wb_coeffs[..3]
        .iter()
        .all(|c| c.is_finite() && *c > 0.0)
    {
        image.wb_coeffs
    } else {
        image.neutralwb()
    };
    [f64::from(wb[1] / wb[0]), 1.0, f64::from(wb[1] / wb[2])]
}

/// The file's colour matrices, XYZ → camera RGB, row-major.
struct ColourMatrices {
    /// The matrix the conversion uses: D65's, else D50's, else the first the file has.
    xyz_to_camera: [[f64; 3]; 3],
    /// The EXIF `LightSource` code of that matrix's calibration illuminant.
    illuminant: u16,
    /// Every matrix of at least 9 entries with its illuminant's code, by code.
    all: Vec<(u16, [[f64; 3]; 3])>,
}

/// The image's colour matrices; refused when it has none or the chosen one has fewer
/// than 9 entries.
fn colour_matrices(image: &rawler::RawImage, refuse: &Refusal) -> Result<ColourMatrices, RawError> {
    let (illuminant, matrix) = image
        .color_matrix_find_first([Illuminant::D65, Illuminant::D50])
        .or_else(|| {
            image
                .color_matrix
                .iter()
                .next()
                .map(|(i, m)| (*i, m.clone()))
        })
        .ok_or_else(|| refuse.unsupported("no colour matrix for this camera"))?;
    if matrix.len() < 9 {
        return Err(refuse.unsupported("colour matrix has fewer than 9 entries"));
    }
    let m = |r: usize, c: usize| f64::from(matrix[r * 3 + c]);
    let xyz_to_camera = [
        [m(0, 0), m(0, 1), m(0, 2)],
        [m(1, 0), m(1, 1), m(1, 2)],
        [m(2, 0), m(2, 1), m(2, 2)],
    ];
    let mut all: Vec<(u16, [[f64; 3]; 3])> = image
        .color_matrix
        .iter()
        .filter(|(_, m)| m.len() >= 9)
        .map(|(i, m)| {
            let m = |r: usize, c: usize| f64::from(m[r * 3 + c]);
            (u16::from(*i), [0, 1, 2].map(|r| [0, 1, 2].map(|c| m(r, c))))
        })
        .collect();
    all.sort_by_key(|&(illuminant, _)| illuminant);
    Ok(ColourMatrices {
        xyz_to_camera,
        illuminant: u16::from(illuminant),
        all,
    })
}

/// The codes of the visible `area`, row by row: moved out of the decoded image and cropped
/// in place.
fn visible_codes(
    image: &mut rawler::RawImage,
    area: Area,
    refuse: &Refusal,
) -> Result<Vec<u16>, RawError> {
    let RawImageData::Integer(mut codes) =
        std::mem::replace(&mut image.data, RawImageData::Integer(Vec::new()))
    else {
        return Err(refuse.unsupported(FLOAT_DATA));
    };
    let stride = image.width;
    crop_in_place(
        &mut codes,
        stride,
        (area.x, area.y, area.width, area.height),
    );
    Ok(codes)
}

/// The name of an EXIF `LightSource` code (CIPA DC-008 table, as DNG's
/// `CalibrationIlluminant` uses it): `D65` for 21, `Standard light A` for 17; the code
/// itself for one outside the table.
fn light_source_name(code: u16) -> std::borrow::Cow<'static, str> {
    let name = match code {
        0 => "unknown",
        1 => "Daylight",
        2 => "Fluorescent",
        3 => "Tungsten",
        4 => "Flash",
        9 => "Fine weather",
        10 => "Cloudy weather",
        11 => "Shade",
        12 => "Daylight fluorescent",
        13 => "Day white fluorescent",
        14 => "Cool white fluorescent",
        15 => "White fluorescent",
        16 => "Warm white fluorescent",
        17 => "Standard light A",
        18 => "Standard light B",
        19 => "Standard light C",
        20 => "D55",
        21 => "D65",
        22 => "D75",
        23 => "D50",
        24 => "ISO studio tungsten",
        _ => return format!("light source {code}").into(),
    };
    name.into()
}

#[cfg(test)]
mod tests {
    use super::crop_in_place;

    #[test]
    fn the_visible_area_is_cropped_in_place() {
        // 5 × 4, sample = 10·row + column.
        let full: Vec<u16> = (0..4)
            .flat_map(|y| (0..5).map(move |x| 10 * y + x))
            .collect();
        let mut data = full.clone();
        crop_in_place(&mut data, 5, (1, 1, 3, 2));
        assert_eq!(data, [11, 12, 13, 21, 22, 23]);
        let mut data = full.clone();
        crop_in_place(&mut data, 5, (0, 0, 5, 3));
        assert_eq!(data, full[..15]);
        let mut data = full.clone();
        crop_in_place(&mut data, 5, (2, 0, 3, 4));
        assert_eq!(data, [2, 3, 4, 12, 13, 14, 22, 23, 24, 32, 33, 34]);
    }
}
