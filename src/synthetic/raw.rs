//! Synthetic camera raws: the scene through a colour filter array onto a linear sensor,
//! written as DNG by rawler's DNG writer (the same library that reads raws, so the files
//! are the ones dnglab's converter would make).

use std::collections::HashMap;
use std::io::Cursor;

use rawler::cfa::{CFA, PlaneColor};
use rawler::decoders::{Camera as RawCamera, Orientation};
use rawler::dng::writer::DngWriter;
use rawler::dng::{CropMode, DNG_VERSION_V1_4, DngCompression, DngPhotometricConversion};
use rawler::formats::tiff::Rational;
use rawler::formats::tiff::writer::DirectoryWriter;
use rawler::imgop::xyz::Illuminant;
use rawler::rawimage::{
    BlackLevel, CFAConfig, RawImage, RawImageData, RawPhotometricInterpretation, WhiteLevel,
};
use rawler::tags::ExifTag;
use rayon::prelude::*;

use super::sensor::{Normals, row_seed};
use super::{DngError, Shot, SyntheticError};
use crate::radiance::RadianceMap;

/// Linear Rec. 709 → CIE XYZ (D65), IEC 61966-2-1.
const REC709_TO_XYZ: [[f64; 3]; 3] = [
    [0.412_456_4, 0.357_576_1, 0.180_437_5],
    [0.212_672_9, 0.715_152_2, 0.072_175_0],
    [0.019_333_9, 0.119_192_0, 0.950_304_1],
];

/// A simulated raw sensor: CFA, levels, colour and noise.
#[derive(Debug, Clone, PartialEq)]
pub struct RawSensor {
    /// The CFA tile's colours as letters (`RGGB`).
    pub cfa: &'static str,
    /// Black level, in codes.
    pub black: u16,
    /// White level (clipping code).
    pub white: u16,
    /// Bits per sample the converter delivers.
    pub bits: u32,
    /// XYZ → camera RGB, at 1/10 000 resolution (DNG stores it so).
    pub xyz_to_camera: [[f64; 3]; 3],
    /// Electrons at the clipping point (shot noise); 0 for none.
    pub full_well_electrons: f64,
    /// Read noise in codes.
    pub read_noise_dn: f64,
    /// Seed of the noise generator.
    pub seed: u64,
}

impl RawSensor {
    /// A 14-bit Bayer (RGGB) sensor: black 512, white 15 000, full well 30 000 e⁻, 3 DN of
    /// read noise, and the colour matrix of a Canon EOS 5D Mark II under D65 (Adobe's
    /// `ColorMatrix2`).
    pub fn typical(seed: u64) -> RawSensor {
        RawSensor {
            cfa: "RGGB",
            black: 512,
            white: 15_000,
            bits: 14,
            xyz_to_camera: [
                [0.4716, 0.0603, -0.0830],
                [-0.7798, 1.5474, 0.2480],
                [-0.1496, 0.1937, 0.6651],
            ],
            full_well_electrons: 30_000.0,
            read_noise_dn: 3.0,
            seed,
        }
    }

    /// Camera RGB of D65 white, normalised to green = 1: the as-shot neutral of a scene lit
    /// by D65.
    pub fn neutral(&self) -> [f64; 3] {
        let white = [0.950_47, 1.0, 1.088_83];
        let cam = self
            .xyz_to_camera
            .map(|row| (0..3).map(|j| row[j] * white[j]).sum::<f64>());
        [cam[0] / cam[1], 1.0, cam[2] / cam[1]]
    }

    /// Linear Rec. 709 → camera RGB.
    fn rec709_to_camera(&self) -> [[f64; 3]; 3] {
        let m = self.xyz_to_camera;
        [0, 1, 2]
            .map(|r| [0, 1, 2].map(|c| (0..3).map(|k| m[r][k] * REC709_TO_XYZ[k][c]).sum::<f64>()))
    }

    fn colour_at(&self, x: usize, y: usize) -> usize {
        let side = if self.cfa.len() == 36 { 6 } else { 2 };
        match self.cfa.as_bytes()[(y % side) * side + x % side] {
            b'R' => 0,
            b'G' => 1,
            _ => 2,
        }
    }
}

/// The normalised signal `s` of every pixel when an RGB `scene` is exposed at `exposure`
/// (relative, in units of the clipping point) on `sensor`: per pixel, the camera channel
/// its CFA colour passes, `s = exposure · (M · XYZ(E))_c / n_G` (`n_G` the neutral's green,
/// so a neutral at `exposure · E = 1` clips in green), plus shot noise
/// `√(s/W)·z₁` and read noise `σ/(w − b)·z₂`; `s ≥ 1` reads exactly 1 (clipped).
pub fn raw_signal(scene: &RadianceMap, exposure: f64, sensor: &RawSensor) -> Vec<f32> {
    let width = scene.width() as usize;
    let to_camera = sensor.rec709_to_camera();
    let white = [0.950_47, 1.0, 1.088_83];
    let green: f64 = (0..3).map(|j| sensor.xyz_to_camera[1][j] * white[j]).sum();
    let read = sensor.read_noise_dn / f64::from(sensor.white - sensor.black);
    let mut out = vec![0.0f32; width * scene.height() as usize];
    out.par_chunks_mut(width.max(1))
        .zip(scene.pixels().par_chunks((width * 3).max(1)))
        .enumerate()
        .for_each(|(y, (row, rgb))| {
            let mut noise = Normals::new(row_seed(sensor.seed, exposure, y));
            for (x, s) in row.iter_mut().enumerate() {
                let c = sensor.colour_at(x, y);
                let e = &rgb[x * 3..x * 3 + 3];
                let cam: f64 = (0..3).map(|k| to_camera[c][k] * f64::from(e[k])).sum();
                let mut signal = exposure * cam.max(0.0) / green;
                if sensor.full_well_electrons > 0.0 && signal > 0.0 {
                    signal += (signal / sensor.full_well_electrons).sqrt() * noise.next();
                }
                signal += read * noise.next();
                *s = if signal >= 1.0 { 1.0 } else { signal as f32 };
            }
        });
    out
}

/// Codes of `signal` on `sensor`: `round(b + s·(w − b))` within `0..=w`.
pub fn raw_codes(signal: &[f32], sensor: &RawSensor) -> Vec<u16> {
    let (b, w) = (f64::from(sensor.black), f64::from(sensor.white));
    signal
        .iter()
        .map(|&s| (b + f64::from(s) * (w - b)).round().clamp(0.0, w) as u16)
        .collect()
}

/// A DNG of the `width × height` mosaic `codes` from `sensor` (lossless JPEG), with the
/// sensor's levels, CFA, colour matrix (D65), the as-shot neutral of D65 and the EXIF of
/// `shot` (make, model, exposure time, f-number, ISO, capture time).
pub fn dng(
    codes: &[u16],
    width: u32,
    height: u32,
    sensor: &RawSensor,
    shot: &Shot,
) -> Result<Vec<u8>, SyntheticError> {
    let fail = |e: rawler::formats::tiff::TiffError| SyntheticError::Dng(e.into());
    let (width, height) = (width as usize, height as usize);
    if codes.len() != width * height || width == 0 || height == 0 {
        return Err(SyntheticError::Dng(DngError::Size {
            codes: codes.len(),
            width,
            height,
        }));
    }
    let image = raw_image(codes, width, height, sensor, shot);
    let mut buffer = Cursor::new(Vec::new());
    let mut writer = DngWriter::new(&mut buffer, DNG_VERSION_V1_4).map_err(fail)?;
    let mut raw = writer.subframe_on_root(0);
    raw.raw_image(
        &image,
        CropMode::None,
        DngCompression::Lossless,
        DngPhotometricConversion::Original,
        1,
    )
    .map_err(fail)?;
    raw.finalize().map_err(fail)?;
    writer.load_base_tags(&image).map_err(fail)?;
    write_exposure(writer.exif_ifd_mut(), shot);
    writer.close().map_err(fail)?;
    Ok(buffer.into_inner())
}

/// rawler's description of the mosaic: the body of `shot`, the sensor's bit depth,
/// levels, CFA and XYZ → camera matrix (D65), white balance `1/neutral` (green 1).
fn raw_image(
    codes: &[u16],
    width: usize,
    height: usize,
    sensor: &RawSensor,
    shot: &Shot,
) -> RawImage {
    let mut camera = RawCamera::new();
    camera.make = shot.camera.make.clone().unwrap_or_default();
    camera.model = shot.camera.model.clone().unwrap_or_default();
    camera.clean_make = camera.make.clone();
    camera.clean_model = camera.model.clone();
    camera.real_bps = sensor.bits as usize;
    let cfa = CFA::new(sensor.cfa);
    camera.cfa = cfa.clone();
    let neutral = sensor.neutral();
    let matrix: Vec<f32> = sensor
        .xyz_to_camera
        .iter()
        .flatten()
        .map(|&v| v as f32)
        .collect();
    let mut xyz_to_cam = [[0.0f32; 3]; 4];
    for (r, row) in sensor.xyz_to_camera.iter().enumerate() {
        xyz_to_cam[r] = row.map(|v| v as f32);
    }
    RawImage {
        make: camera.make.clone(),
        model: camera.model.clone(),
        clean_make: camera.clean_make.clone(),
        clean_model: camera.clean_model.clone(),
        camera,
        width,
        height,
        cpp: 1,
        bps: sensor.bits as usize,
        wb_coeffs: [
            (1.0 / neutral[0]) as f32,
            1.0,
            (1.0 / neutral[2]) as f32,
            f32::NAN,
        ],
        whitelevel: WhiteLevel(vec![u32::from(sensor.white)]),
        blacklevel: BlackLevel::new(&[u32::from(sensor.black); 4], 2, 2, 1),
        xyz_to_cam,
        photometric: RawPhotometricInterpretation::Cfa(CFAConfig::new(
            &cfa,
            &PlaneColor::new("RGB"),
        )),
        active_area: None,
        crop_area: None,
        blackareas: Vec::new(),
        orientation: Orientation::Normal,
        data: RawImageData::Integer(codes.to_vec()),
        color_matrix: HashMap::from([(Illuminant::D65, matrix)]),
        dng_tags: HashMap::new(),
        fuji_rotation_width: None,
    }
}

/// The EXIF of `shot` into the DNG's EXIF directory: exposure time and f-number as
/// rationals of 10⁻⁶, ISO (1..=65 535) and the capture time (`YYYY:MM:DD HH:MM:SS`).
fn write_exposure(exif: &mut DirectoryWriter, shot: &Shot) {
    let micro = |v: f64| Rational::new((v * 1e6).round() as u32, 1_000_000);
    if let Some(t) = shot.exposure.time_s {
        exif.add_tag(ExifTag::ExposureTime, micro(t));
    }
    if let Some(n) = shot.exposure.f_number {
        exif.add_tag(ExifTag::FNumber, micro(n));
    }
    if let Some(iso) = shot.exposure.iso {
        exif.add_tag(
            ExifTag::ISOSpeedRatings,
            iso.round().clamp(1.0, 65_535.0) as u16,
        );
    }
    let t = &shot.captured_at;
    let date = format!(
        "{:04}:{:02}:{:02} {:02}:{:02}:{:02}",
        t.year, t.month, t.day, t.hour, t.minute, t.second
    );
    exif.add_tag(ExifTag::DateTimeOriginal, date.as_str());
}
