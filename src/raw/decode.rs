//! Decoding a raw file with rawler into a [`RawMosaic`].

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::Path;

use rawler::RawlerError;
use rawler::decoders::RawDecodeParams;
use rawler::imgop::xyz::Illuminant;
use rawler::rawimage::{RawImageData, RawPhotometricInterpretation};
use rawler::rawsource::RawSource;

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

fn decode_unguarded(path: &Path, bytes: &[u8], max_pixels: u64) -> Result<RawMosaic, RawError> {
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
    let mut image = decoder.raw_image(&source, &params, false).map_err(failed)?;
    // The decoded image again: a file whose header understates its size is refused before
    // anything larger (the demosaicked map) is made of it.
    within_limit(image.width, image.height)?;
    let exif = decoder.raw_metadata(&source, &params).map(|m| m.exif).ok();
    let camera = camera_name(&image.clean_make, &image.clean_model);
    let unsupported = |reason: String| RawError::Unsupported {
        path: path.to_path_buf(),
        camera: camera.clone(),
        reason,
    };
    let cfa = match &image.photometric {
        RawPhotometricInterpretation::Cfa(config) if image.cpp == 1 && config.cfa.is_rgb() => {
            config.cfa.clone()
        }
        RawPhotometricInterpretation::Cfa(config) => {
            return Err(unsupported(format!(
                "colour filter array {} is not RGB",
                config.cfa
            )));
        }
        RawPhotometricInterpretation::LinearRaw => {
            return Err(unsupported(
                "already demosaicked (linear raw): only mosaic raws are merged".to_string(),
            ));
        }
        RawPhotometricInterpretation::BlackIsZero => {
            return Err(unsupported("monochrome sensor".to_string()));
        }
    };
    let is_bayer = cfa.width == 2 && cfa.height == 2;
    let is_xtrans = cfa.width == 6 && cfa.height == 6;
    if !(is_bayer || is_xtrans) {
        return Err(unsupported(format!(
            "colour filter array {cfa} is neither Bayer (2×2) nor X-Trans (6×6)"
        )));
    }
    // Bayer: one red, one blue, and the two greens on a diagonal (the demosaicking's
    // premise).
    let diagonal_greens = (cfa.color_at(0, 0) == 1 && cfa.color_at(1, 1) == 1)
        || (cfa.color_at(0, 1) == 1 && cfa.color_at(1, 0) == 1);
    if is_bayer && !diagonal_greens {
        return Err(unsupported(format!(
            "colour filter array {cfa} is 2×2 without its greens on a diagonal"
        )));
    }
    let RawImageData::Integer(data) = &image.data else {
        return Err(unsupported(
            "floating-point raw data: only integer mosaics are merged".to_string(),
        ));
    };
    let full = (image.width, image.height);
    let area = image.crop_area.or(image.active_area);
    let (x0, y0, width, height) = match area {
        Some(r) => (r.x(), r.y(), r.width(), r.height()),
        None => (0, 0, full.0, full.1),
    };
    if width == 0 || height == 0 || x0 + width > full.0 || y0 + height > full.1 {
        return Err(RawError::Decode {
            path: path.to_path_buf(),
            reason: format!(
                "visible area {width}×{height} at ({x0}, {y0}) outside the {}×{} sensor",
                full.0, full.1
            ),
        });
    }
    if data.len() < full.0 * full.1 {
        return Err(RawError::Decode {
            path: path.to_path_buf(),
            reason: "fewer samples than the sensor's size".to_string(),
        });
    }
    let tile = cfa.shift(x0, y0);
    let cfa = Cfa {
        width: tile.width,
        height: tile.height,
        colours: (0..tile.height)
            .flat_map(|y| (0..tile.width).map(move |x| (y, x)))
            .map(|(y, x)| tile.color_at(y, x) as u8)
            .collect(),
    };
    let black = image.blacklevel.shift(x0, y0);
    let black_values: Vec<f32> = black.levels.iter().map(|r| r.as_f32()).collect();
    if black.width == 0 || black.height == 0 || black_values.len() < black.width * black.height {
        return Err(RawError::Decode {
            path: path.to_path_buf(),
            reason: "malformed black level".to_string(),
        });
    }
    let white = image.whitelevel.0.first().copied().unwrap_or(0) as f32;
    if black_values.iter().any(|&b| !(b >= 0.0 && b < white)) {
        return Err(RawError::Decode {
            path: path.to_path_buf(),
            reason: format!("black level {black_values:?} not below the white level {white}"),
        });
    }
    // rawler's white-balance coefficients are camera multipliers, the reciprocal of the
    // as-shot neutral; NaN when the file has none (then a D65 neutral from the matrix).
    let wb = if image.wb_coeffs[..3]
        .iter()
        .all(|c| c.is_finite() && *c > 0.0)
    {
        image.wb_coeffs
    } else {
        image.neutralwb()
    };
    let neutral = [f64::from(wb[1] / wb[0]), 1.0, f64::from(wb[1] / wb[2])];
    let (illuminant, matrix) = image
        .color_matrix_find_first([Illuminant::D65, Illuminant::D50])
        .or_else(|| {
            image
                .color_matrix
                .iter()
                .next()
                .map(|(i, m)| (*i, m.clone()))
        })
        .ok_or_else(|| unsupported("no colour matrix for this camera".to_string()))?;
    if matrix.len() < 9 {
        return Err(unsupported(
            "colour matrix has fewer than 9 entries".to_string(),
        ));
    }
    let m = |r: usize, c: usize| f64::from(matrix[r * 3 + c]);
    let xyz_to_camera = [
        [m(0, 0), m(0, 1), m(0, 2)],
        [m(1, 0), m(1, 1), m(1, 2)],
        [m(2, 0), m(2, 1), m(2, 2)],
    ];
    let mut colour_matrices: Vec<(u16, [[f64; 3]; 3])> = image
        .color_matrix
        .iter()
        .filter(|(_, m)| m.len() >= 9)
        .map(|(i, m)| {
            let m = |r: usize, c: usize| f64::from(m[r * 3 + c]);
            (u16::from(*i), [0, 1, 2].map(|r| [0, 1, 2].map(|c| m(r, c))))
        })
        .collect();
    colour_matrices.sort_by_key(|&(illuminant, _)| illuminant);
    let exif = exif_of(
        image.clean_make.clone(),
        image.clean_model.clone(),
        &exif.unwrap_or_default(),
    );
    // The visible area, moved out of the decoded image and cropped in place.
    let RawImageData::Integer(mut codes) =
        std::mem::replace(&mut image.data, RawImageData::Integer(Vec::new()))
    else {
        return Err(unsupported(
            "floating-point raw data: only integer mosaics are merged".to_string(),
        ));
    };
    crop_in_place(&mut codes, full.0, (x0, y0, width, height));
    Ok(RawMosaic {
        width: u32::try_from(width).map_err(|_| unsupported("too wide".to_string()))?,
        height: u32::try_from(height).map_err(|_| unsupported("too tall".to_string()))?,
        codes,
        info: RawInfo {
            make: image.clean_make.clone(),
            model: image.clean_model.clone(),
            bits: image.bps as u32,
            cfa,
            black: black_values,
            black_width: black.width,
            black_height: black.height,
            white,
            neutral,
            xyz_to_camera,
            matrix_illuminant: light_source_name(u16::from(illuminant)).to_string(),
            colour_matrices,
            exposure_time_s: exif.exposure_time_s,
            f_number: exif.f_number,
            iso: exif.iso,
            captured: exif.captured,
        },
    })
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
