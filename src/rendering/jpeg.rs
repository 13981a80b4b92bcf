//! Baseline JPEG on every core: the image is cut into horizontal bands of whole MCU rows,
//! each band is encoded on its own by `rusty_jpeg` with the same quantisation and
//! (standard) Huffman tables, and the bands' entropy-coded segments are joined by restart
//! markers `RST0..RST7` under one header whose `DRI` restart interval is the MCU count of
//! a band.
//!
//! A restart resets the DC predictors and byte-aligns the bit stream (padding with 1
//! bits), which is exactly how each band's own scan starts and ends, so the joined file
//! is a valid baseline JPEG whose coefficients equal those of a single-threaded encoding
//! of the whole image: band edges fall on MCU rows, and the last band repeats the image's
//! last row below it as the whole-image encoder does. It decodes to the same pixels.

use std::io::Write;
use std::ops::Range;

use rayon::prelude::*;
use rusty_jpeg::encode::{ColorType, Encoder, EncodingError, SamplingFactor};

use super::ImageEncodeError;

/// Rows per band at most (a multiple of both MCU heights, 8 and 16 rows): 64 rows of a
/// 24 MP frame are 1.1 MB of RGB, so a band in flight per core stays in cache-sized work.
const BAND_ROWS: usize = 64;

/// The largest restart interval the `DRI` segment can state, in MCUs.
const MAX_INTERVAL: usize = u16::MAX as usize;

/// The chroma sampling `rusty_jpeg` chooses by itself at this quality, stated so that
/// every band agrees: 4:2:0 (16 × 16-pixel MCUs) below quality 90, 4:4:4 (8 × 8) from 90.
pub(super) fn sampling(quality: u8) -> SamplingFactor {
    if quality < 90 {
        SamplingFactor::F_2_2
    } else {
        SamplingFactor::F_1_1
    }
}

/// The layout of the bands: `(rows per band, restart interval in MCUs)` for an image of
/// `width` pixels at this quality. A band is `k` MCU rows with `k·⌈width/mcu⌉ ≤ 65 535`
/// (at least one MCU row: `⌈65 535/8⌉ = 8192` MCUs per row at most) and `k·mcu ≤ 64`.
fn layout(width: usize, quality: u8) -> (usize, usize) {
    let mcu = if quality < 90 { 16 } else { 8 };
    let per_row = width.div_ceil(mcu).max(1);
    let mcu_rows = (BAND_ROWS / mcu).min(MAX_INTERVAL / per_row).max(1);
    (mcu_rows * mcu, mcu_rows * per_row)
}

/// One band encoded as a JPEG of its own.
struct Band {
    bytes: Vec<u8>,
    /// The entropy-coded segment: after the `SOS` header, before `EOI`.
    scan: Range<usize>,
    /// Where the `SOF0` segment starts.
    frame: usize,
}

/// Encodes a `width × height` image at `quality` whose 8-bit RGB rows `develop(first,
/// rgb)` fills (rows `first .. first + rgb.len()/(3·width)`), bands in parallel, into
/// `out`; `decorate` adds the APP segments (profile, EXIF) to the encoder of the first
/// band, whose header the file takes. `develop` is called once per band, concurrently.
pub(super) fn encode_bands(
    width: u32,
    height: u32,
    quality: u8,
    decorate: impl Fn(&mut Encoder<&mut Vec<u8>>) -> Result<(), EncodingError> + Sync,
    develop: impl Fn(usize, &mut [u8]) + Sync,
    out: &mut impl Write,
) -> Result<(), ImageEncodeError> {
    let too_large = || ImageEncodeError::JpegTooLarge { width, height };
    let w16 = u16::try_from(width).map_err(|_| too_large())?;
    let h16 = u16::try_from(height).map_err(|_| too_large())?;
    if w16 == 0 || h16 == 0 {
        return Err(ImageEncodeError::Empty { width, height });
    }
    let (w, h) = (usize::from(w16), usize::from(h16));
    let (band_rows, interval) = layout(w, quality);
    let interval16 = u16::try_from(interval)
        .map_err(|_| ImageEncodeError::JpegStream("restart interval over 65535"))?;
    let bands = (0..h.div_ceil(band_rows))
        .into_par_iter()
        .map(|i| {
            let first = i * band_rows;
            let rows = band_rows.min(h - first);
            let mut rgb = vec![0u8; rows * w * 3];
            develop(first, &mut rgb);
            let mut bytes = Vec::with_capacity(rgb.len() / 4);
            let mut encoder = Encoder::new(&mut bytes, quality);
            encoder.set_sampling_factor(sampling(quality));
            encoder.set_restart_interval(interval16);
            if i == 0 {
                decorate(&mut encoder)?;
            }
            // `rows ≤ h ≤ 65535`.
            encoder.encode(&rgb, w16, rows as u16, ColorType::Rgb)?;
            let (frame, scan) = scan_of(&bytes).map_err(ImageEncodeError::JpegStream)?;
            Ok(Band { bytes, scan, frame })
        })
        .collect::<Result<Vec<Band>, ImageEncodeError>>()?;
    let first = bands
        .first()
        .ok_or(ImageEncodeError::Empty { width, height })?;
    let mut header = first.bytes[..first.scan.start].to_vec();
    // SOF0: FF C0, length (2), precision (1), height (2), width (2).
    let height_at = first.frame + 5;
    header
        .get_mut(height_at..height_at + 2)
        .ok_or(ImageEncodeError::JpegStream("a short frame header"))?
        .copy_from_slice(&h16.to_be_bytes());
    out.write_all(&header)?;
    for (i, band) in bands.iter().enumerate() {
        if i > 0 {
            out.write_all(&[0xFF, 0xD0 + ((i - 1) % 8) as u8])?;
        }
        out.write_all(&band.bytes[band.scan.clone()])?;
    }
    Ok(out.write_all(&[0xFF, 0xD9])?)
}

/// The start of the `SOF0` segment and the entropy-coded segment of a baseline JPEG as
/// `rusty_jpeg` writes it (marker segments up to `SOS`, one scan, `EOI` last).
fn scan_of(bytes: &[u8]) -> Result<(usize, Range<usize>), &'static str> {
    if bytes.get(..2) != Some(&[0xFF, 0xD8]) {
        return Err("no SOI");
    }
    if bytes.len() < 4 || bytes[bytes.len() - 2..] != [0xFF, 0xD9] {
        return Err("no EOI");
    }
    let mut pos = 2;
    let mut frame = None;
    loop {
        let segment = bytes.get(pos..pos + 4).ok_or("no SOS")?;
        if segment[0] != 0xFF {
            return Err("a marker expected");
        }
        let length = usize::from(u16::from_be_bytes([segment[2], segment[3]]));
        match segment[1] {
            0xC0 => frame = Some(pos),
            0xC1..=0xCF if segment[1] != 0xC4 && segment[1] != 0xC8 && segment[1] != 0xCC => {
                return Err("not a baseline frame");
            }
            0xDA => {
                let start = pos + 2 + length;
                let end = bytes.len() - 2;
                let frame = frame.ok_or("SOS before SOF0")?;
                return if start <= end {
                    Ok((frame, start..end))
                } else {
                    Err("SOS runs past the end")
                };
            }
            _ => {}
        }
        pos += 2 + length;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A deterministic busy image: gradients, a few hard edges and hashed noise.
    fn busy(w: usize, h: usize) -> Vec<u8> {
        let mut rgb = Vec::with_capacity(w * h * 3);
        for y in 0..h {
            for x in 0..w {
                let n = ((x * 7919 + y * 104_729) ^ (x * y)) as u32;
                let noise = (n.wrapping_mul(2_654_435_761) >> 27) as usize;
                let edge = if (x / 13 + y / 11) % 2 == 0 { 60 } else { 0 };
                rgb.push(((x * 255 / w.max(1)) + noise) as u8);
                rgb.push(((y * 255 / h.max(1)) / 2 + edge + noise) as u8);
                rgb.push((((x + y) * 3) % 256) as u8);
            }
        }
        rgb
    }

    fn banded(rgb: &[u8], w: usize, h: usize, quality: u8) -> Vec<u8> {
        let mut out = Vec::new();
        encode_bands(
            w as u32,
            h as u32,
            quality,
            |e| e.add_app_segment(1, b"Exif\0\0test".to_vec()),
            |first, band| band.copy_from_slice(&rgb[first * w * 3..][..band.len()]),
            &mut out,
        )
        .unwrap_or_else(|e| panic!("{w}×{h} q{quality}: {e}"));
        out
    }

    fn single(rgb: &[u8], w: usize, h: usize, quality: u8) -> Vec<u8> {
        let mut out = Vec::new();
        let mut encoder = Encoder::new(&mut out, quality);
        encoder.set_sampling_factor(sampling(quality));
        encoder
            .encode(rgb, w as u16, h as u16, ColorType::Rgb)
            .expect("single-threaded encode");
        out
    }

    fn decode(bytes: &[u8]) -> (u32, u32, Vec<u8>) {
        let image = image::load_from_memory_with_format(bytes, image::ImageFormat::Jpeg)
            .expect("decodes")
            .to_rgb8();
        (image.width(), image.height(), image.into_raw())
    }

    #[test]
    fn bands_decode_to_the_single_encodings_pixels() {
        // Odd sizes, one MCU, one band, a band edge exactly at the bottom, many bands
        // (more than 8, so the RST numbers wrap), at 4:2:0 (q85) and 4:4:4 (q92).
        for (w, h) in [
            (1, 1),
            (7, 5),
            (17, 33),
            (33, 64),
            (100, 129),
            (250, 700),
            (16, 1000),
        ] {
            let rgb = busy(w, h);
            for quality in [85, 92] {
                let ours = banded(&rgb, w, h, quality);
                let reference = single(&rgb, w, h, quality);
                let (bw, bh, pixels) = decode(&ours);
                assert_eq!((bw, bh), (w as u32, h as u32), "{w}×{h} q{quality}");
                assert!(
                    decode(&reference).2 == pixels,
                    "{w}×{h} q{quality}: banded pixels differ from the single encoding"
                );
                let (band_rows, _) = layout(w, quality);
                let restarts = ours
                    .windows(2)
                    .filter(|m| m[0] == 0xFF && (0xD0..=0xD7).contains(&m[1]))
                    .count();
                assert_eq!(restarts, h.div_ceil(band_rows) - 1, "{w}×{h} q{quality}");
                assert!(ours.windows(10).any(|s| s == b"Exif\0\0test"));
            }
        }
    }

    #[test]
    fn the_restart_interval_fits_its_field() {
        for quality in [50, 95] {
            for w in [1, 8, 16, 6000, 8256, 65_535] {
                let (rows, interval) = layout(w, quality);
                assert!(
                    rows > 0 && rows % 8 == 0 && interval <= MAX_INTERVAL,
                    "{w} q{quality}"
                );
                assert_eq!(interval % w.div_ceil(if quality < 90 { 16 } else { 8 }), 0);
            }
        }
        // 45 MP, 8256 wide, q92: 1032 MCUs per row, 8 rows of MCUs per band.
        assert_eq!(layout(8256, 92), (64, 8256));
        assert_eq!(layout(65_535, 92), (56, 57_344));
    }

    #[test]
    fn bad_sizes_are_errors() {
        let fill = |_: usize, _: &mut [u8]| {};
        for (w, h) in [(0, 10), (10, 0), (70_000, 8), (8, 70_000)] {
            let mut out = Vec::new();
            let r = encode_bands(w, h, 92, |_| Ok(()), fill, &mut out);
            assert!(r.is_err(), "{w}×{h}");
        }
        assert!(scan_of(b"").is_err());
        assert!(scan_of(&[0xFF, 0xD8, 0xFF, 0xD9]).is_err());
        assert!(scan_of(&[0xFF, 0xD8, 0xFF, 0xC0, 0x00, 0x40, 0xFF, 0xD9]).is_err());
        assert!(scan_of(&[0xFF, 0xD8, 0xFF, 0xDA, 0x00, 0x02, 0xFF, 0xD9]).is_err());
    }
}
