//! Previews, made once when a bracket is published: per rendering a JPEG of long edge
//! [`PREVIEW_EDGE`] px and a thumbnail of [`THUMB_EDGE`] px, per frame a thumbnail, in
//! `state/previews/<stem>/`, each published atomically, beside the bracket's record
//! ([`RECORD_FILE`]). The browser never pulls a full rendering to show a screen.

use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use image::{DynamicImage, ImageDecoder, ImageEncoder, ImageReader};
use tokio::sync::mpsc::{self, error::TryRecvError};
use tracing::warn;

use super::{Event, PREVIEW_FOLDER, Published, Record, Shared};
use crate::atomic::{self, Overwrite, PublishError};
use crate::deghost::KeptMap;
use crate::display::ColourSpace;
use crate::merge::{Clip, ClipMap};
use crate::rendering::Preview;

/// Long edge of a rendering's preview, pixels.
pub(crate) const PREVIEW_EDGE: u32 = 1600;

/// Long edge of a thumbnail, pixels.
pub(crate) const THUMB_EDGE: u32 = 256;

/// JPEG quality of previews and thumbnails.
const QUALITY: u8 = 85;

/// Largest file read to make a preview (a rendering or a frame), bytes.
const MAX_SOURCE_BYTES: u64 = 512 * 1024 * 1024;

/// Why one preview could not be made (logged; the page shows the name instead).
#[derive(Debug, thiserror::Error)]
pub(crate) enum PreviewError {
    /// The source could not be opened or decoded.
    #[error("{path}: cannot decode for a preview: {source}")]
    Decode {
        /// The source file.
        path: PathBuf,
        /// What the decoder said.
        source: image::ImageError,
    },
    /// The source is larger than [`MAX_SOURCE_BYTES`] or not a regular file, or the
    /// lab's copy of it is not a whole picture.
    #[error("{path}: not a regular file of at most {MAX_SOURCE_BYTES} bytes, nor a whole copy")]
    Unsuitable {
        /// The source file.
        path: PathBuf,
    },
    /// The preview could not be encoded.
    #[error("{path}: cannot encode the preview: {source}")]
    Encode {
        /// The preview file.
        path: PathBuf,
        /// What the encoder said.
        source: image::ImageError,
    },
    /// The bracket's record could not be serialised.
    #[error("{path}: cannot write the record: {source}")]
    Record {
        /// The record file.
        path: PathBuf,
        /// What the serialiser said.
        source: serde_json::Error,
    },
    /// The preview could not be written.
    #[error(transparent)]
    Publish(#[from] PublishError),
}

/// File in a bracket's preview folder holding its record as JSON, so that a restart
/// can show it again ([`super::restore`]).
pub(crate) const RECORD_FILE: &str = "record.json";

/// Whether previews already on disk are made again.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Make {
    /// Every preview (a development just published: a redo replaces the old ones).
    All,
    /// Only those missing (a record restored after a restart).
    Missing,
}

/// Takes published developments in turn, and between them the restored records whose
/// previews are missing: makes their previews on a blocking thread, then files the
/// record (a development is announced; a restored record replaces its earlier self).
/// A published development always goes first. Ends when the daemon's handle is dropped.
pub(crate) async fn worker(
    shared: Arc<Shared>,
    mut rx: mpsc::UnboundedReceiver<Published>,
    mut restored: VecDeque<Published>,
) {
    loop {
        let next = match rx.try_recv() {
            Ok(published) => Some((published, Make::All)),
            Err(TryRecvError::Empty) => restored.pop_front().map(|p| (p, Make::Missing)),
            Err(TryRecvError::Disconnected) => return,
        };
        let (published, make) = match next {
            Some(next) => next,
            None => match rx.recv().await {
                Some(published) => (published, Make::All),
                None => return,
            },
        };
        let dir = shared.state.join(PREVIEW_FOLDER);
        let made =
            tokio::task::spawn_blocking(move || develop_previews(&dir, published, make)).await;
        let record = match made {
            Ok(record) => Arc::new(record),
            Err(e) => {
                warn!(error = %e, "making previews failed; the bracket is not shown");
                continue;
            }
        };
        match make {
            Make::All => {
                shared.gallery().file(Arc::clone(&record));
                shared.broadcast(Event::Developed(record));
            }
            Make::Missing => shared.gallery().replace(record),
        }
    }
}

/// Makes the previews of one development (all, or only those missing), fills in its
/// record's URLs and keeps the record beside them as [`RECORD_FILE`].
fn develop_previews(dir: &Path, published: Published, make: Make) -> Record {
    let Published {
        mut record,
        frame_paths,
        pictures,
    } = published;
    let pictures = pictures.unwrap_or_default();
    let folder = dir.join(&record.stem);
    let wanted = |target: &Path| make == Make::All || !target.is_file();
    for (output, path) in record.outputs.iter().zip(&record.files.outputs) {
        let (preview, thumb) = rendering_preview_paths(&folder, &output.name);
        if output.look.is_some() && (wanted(&preview) || wanted(&thumb)) {
            let copy = pictures.renderings.iter().find(|r| r.name == output.name);
            let _ = match copy {
                Some(copy) => picture(&copy.preview, path)
                    .and_then(|large| write_previews(large, &preview, &thumb)),
                None => rendering_previews(path, &preview, &thumb),
            }
            .inspect_err(|e| warn!(error = %e, "no preview"));
        }
    }
    for (k, path) in frame_paths.iter().enumerate() {
        let target = frame_thumb_path(&folder, k);
        // Camera raws have no quick picture to show: their frames are listed by name.
        if wanted(&target) && !crate::daemon::intake::is_raw(path) {
            let _ = match pictures.frames.get(k).and_then(Option::as_ref) {
                Some(copy) => picture(copy, path)
                    .and_then(|small| write_jpeg(&within(small, THUMB_EDGE), &target)),
                None => thumbnail(path, &target),
            }
            .inspect_err(|e| warn!(error = %e, "no frame thumbnail"));
        }
    }
    let clipped = pictures.clipped.as_ref().filter(|map| map.any());
    let overlays = [
        (clip_overlay_path(&folder), clipped.map(clip_overlay)),
        (
            left_out_overlay_path(&folder),
            pictures.left_out.as_ref().map(left_out_overlay),
        ),
    ];
    for (path, overlay) in overlays {
        match overlay {
            Some(overlay) if wanted(&path) => {
                let _ = overlay
                    .publish(&path)
                    .inspect_err(|e| warn!(error = %e, "no overlay"));
            }
            Some(_) => {}
            // A development again that marks nothing must not show the last one's overlay.
            None if make == Make::All => remove_stale(&path),
            None => {}
        }
    }
    link(&mut record, &folder);
    keep_record(&record, &folder);
    record
}

/// `<folder>/clipped.png`: the overlay of what no frame exposed well.
fn clip_overlay_path(folder: &Path) -> PathBuf {
    folder.join("clipped.png")
}

/// Colours of the overlay, RGBA: clipped high in every frame (warm), low (cool).
const CLIPPED_HIGH: [u8; 4] = [255, 40, 40, 170];
const CLIPPED_LOW: [u8; 4] = [40, 110, 255, 170];

/// An overlay's RGBA pixels, rows top down.
struct Overlay {
    width: u32,
    height: u32,
    pixels: Vec<u8>,
}

impl Overlay {
    /// Publishes the overlay at `path` as an RGBA PNG.
    fn publish(&self, path: &Path) -> Result<(), PreviewError> {
        publish_encoded(path, |bytes| {
            image::codecs::png::PngEncoder::new(bytes).write_image(
                &self.pixels,
                self.width,
                self.height,
                image::ExtendedColorType::Rgba8,
            )
        })
    }
}

/// `map` as an overlay, transparent where some frame exposed well.
fn clip_overlay(map: &ClipMap) -> Overlay {
    let pixels = map
        .clips
        .iter()
        .flat_map(|clip| match clip {
            Clip::High => CLIPPED_HIGH,
            Clip::Low => CLIPPED_LOW,
            Clip::Measured => [0; 4],
        })
        .collect();
    Overlay {
        width: map.width,
        height: map.height,
        pixels,
    }
}

/// `<folder>/left-out.png`: the overlay of where deghosting left frames out.
fn left_out_overlay_path(folder: &Path) -> PathBuf {
    folder.join("left-out.png")
}

/// Colour of the left-out overlay, RGB (magenta: neither clipped overlay's colour), and
/// its opacity where a frame was left out entirely.
const LEFT_OUT: [u8; 3] = [230, 40, 230];
const LEFT_OUT_ALPHA: u32 = 170;

/// `map` as an overlay of opacity `170·(255 − least)/255`: clear where every frame was
/// merged.
fn left_out_overlay(map: &KeptMap) -> Overlay {
    let [r, g, b] = LEFT_OUT;
    let pixels = map
        .least
        .iter()
        .flat_map(|&least| {
            let alpha = (LEFT_OUT_ALPHA * u32::from(255 - least) + 127) / 255;
            [r, g, b, alpha as u8]
        })
        .collect();
    Overlay {
        width: map.width,
        height: map.height,
        pixels,
    }
}

/// Encodes a preview with `encode` and publishes it at `path`, creating its folder.
fn publish_encoded(
    path: &Path,
    encode: impl FnOnce(&mut Vec<u8>) -> Result<(), image::ImageError>,
) -> Result<(), PreviewError> {
    let mut bytes = Vec::new();
    encode(&mut bytes).map_err(|source| PreviewError::Encode {
        path: path.to_path_buf(),
        source,
    })?;
    if let Some(parent) = path.parent() {
        create_folder(parent)?;
    }
    atomic::publish(path, &bytes, Overwrite::Replace)?;
    Ok(())
}

/// Removes a preview file left by an earlier development (logged unless it is absent).
fn remove_stale(path: &Path) {
    if let Err(e) = std::fs::remove_file(path)
        && e.kind() != std::io::ErrorKind::NotFound
    {
        warn!(path = %path.display(), error = %e, "an earlier overlay could not be removed");
    }
}

/// `<folder>/<name>.preview.jpg` and `<folder>/<name>.thumb.jpg`: the preview and the
/// thumbnail of the rendering named `name`.
fn rendering_preview_paths(folder: &Path, name: &str) -> (PathBuf, PathBuf) {
    (
        folder.join(format!("{name}.preview.jpg")),
        folder.join(format!("{name}.thumb.jpg")),
    )
}

/// `<folder>/frame-<k>.jpg`: the thumbnail of frame `k`.
fn frame_thumb_path(folder: &Path, k: usize) -> PathBuf {
    folder.join(format!("frame-{k}.jpg"))
}

/// Fills in `record`'s URLs and files from the previews in `folder` (those missing stay
/// without a URL); its outputs are listed whether or not they are still there.
pub(crate) fn link(record: &mut Record, folder: &Path) {
    let id = record.id;
    let mut previews = Vec::with_capacity(record.outputs.len());
    for (k, output) in record.outputs.iter_mut().enumerate() {
        output.file = format!("/file/{id}/{k}");
        let (preview, thumb) = rendering_preview_paths(folder, &output.name);
        let made = (output.look.is_some() && preview.is_file() && thumb.is_file())
            .then_some((preview, thumb));
        output.preview = made.as_ref().map(|_| format!("/preview/{id}/{k}"));
        output.thumb = made.as_ref().map(|_| format!("/thumb/{id}/{k}"));
        previews.push(made);
    }
    record.files.previews = previews;
    let mut thumbs = Vec::with_capacity(record.frames.len());
    for (k, frame) in record.frames.iter_mut().enumerate() {
        let made = Some(frame_thumb_path(folder, k)).filter(|t| t.is_file());
        frame.thumb = made.as_ref().map(|_| format!("/frame/{id}/{k}"));
        thumbs.push(made);
    }
    record.files.frames = thumbs;
    let overlay = Some(clip_overlay_path(folder)).filter(|p| p.is_file());
    record.clipped = overlay.as_ref().map(|_| format!("/clipped/{id}"));
    record.files.clipped = overlay;
    let overlay = Some(left_out_overlay_path(folder)).filter(|p| p.is_file());
    record.left_out = overlay.as_ref().map(|_| format!("/left-out/{id}"));
    record.files.left_out = overlay;
}

/// True when every preview `record` can have is linked: a preview and thumbnail per
/// rendering, a thumbnail per frame whose file is still there and not a camera raw.
pub(crate) fn complete(record: &Record, frame_paths: &[PathBuf]) -> bool {
    let renderings = record
        .outputs
        .iter()
        .all(|o| o.look.is_none() || o.preview.is_some());
    let frames = record.frames.iter().zip(frame_paths).all(|(f, path)| {
        f.thumb.is_some() || crate::daemon::intake::is_raw(path) || !path.is_file()
    });
    renderings && frames
}

/// Writes `record` as [`RECORD_FILE`] in `folder` (logged when it cannot be: the record
/// is then rebuilt from the journal alone after a restart).
fn keep_record(record: &Record, folder: &Path) {
    let path = folder.join(RECORD_FILE);
    let kept = serde_json::to_vec(record)
        .map_err(|source| PreviewError::Record {
            path: path.clone(),
            source,
        })
        .and_then(|bytes| {
            create_folder(folder)?;
            Ok(atomic::publish(&path, &bytes, Overwrite::Replace)?)
        });
    if let Err(e) = kept {
        warn!(error = %e, "the bracket's record is not kept for a restart");
    }
}

/// Creates `folder` and its parents.
fn create_folder(folder: &Path) -> Result<(), PublishError> {
    std::fs::create_dir_all(folder).map_err(|source| PublishError::Io {
        path: folder.to_path_buf(),
        source,
    })
}

/// Decodes the image at `path` (JPEG, PNG or TIFF), refusing oversized files, and scales
/// it within `edge` pixels; one encoded for Display P3 or Rec. 2020 (its ICC profile is
/// the one filmback embeds for that space) is re-encoded for sRGB ([`to_srgb`]).
fn decode(path: &Path, edge: u32) -> Result<DynamicImage, PreviewError> {
    let unsuitable = || PreviewError::Unsuitable {
        path: path.to_path_buf(),
    };
    let meta = std::fs::metadata(path).map_err(|_| unsuitable())?;
    if !meta.is_file() || meta.len() > MAX_SOURCE_BYTES {
        return Err(unsuitable());
    }
    let decode_error = |source| PreviewError::Decode {
        path: path.to_path_buf(),
        source,
    };
    let mut decoder = ImageReader::open(path)
        .map_err(|e| decode_error(image::ImageError::IoError(e)))?
        .with_guessed_format()
        .map_err(|e| decode_error(image::ImageError::IoError(e)))?
        .into_decoder()
        .map_err(decode_error)?;
    let icc = decoder.icc_profile().ok().flatten();
    let picture = within(
        DynamicImage::from_decoder(decoder).map_err(decode_error)?,
        edge,
    );
    let wide = [ColourSpace::DisplayP3, ColourSpace::Rec2020]
        .into_iter()
        .find(|s| icc.as_deref() == Some(s.icc_profile()));
    Ok(match wide {
        Some(space) => DynamicImage::ImageRgb8(to_srgb(picture.to_rgb8(), space)),
        None => picture,
    })
}

/// `picture`, 8-bit codes for `space`, re-encoded for sRGB: each decoded to linear light
/// by the space's transfer function, taken to Rec. 709 primaries
/// ([`crate::radiance::Gamut::matrix_to`]), clamped to `[0, 1]` and sRGB-encoded.
fn to_srgb(mut picture: image::RgbImage, space: ColourSpace) -> image::RgbImage {
    let m = space
        .gamut()
        .matrix_to(crate::radiance::Gamut::REC709)
        .map(|row| row.map(|v| v as f32));
    let linear: Vec<f32> = (0..=255u8)
        .map(|v| space.decode(f32::from(v) / 255.0))
        .collect();
    for px in picture.pixels_mut() {
        let l = px.0.map(|v| linear[usize::from(v)]);
        px.0 = m.map(|row| {
            let v = row[0] * l[0] + row[1] * l[1] + row[2] * l[2];
            (ColourSpace::Srgb.encode(v) * 255.0).round() as u8
        });
    }
    picture
}

/// A rendering's preview (long edge [`PREVIEW_EDGE`]) at `preview` and its thumbnail
/// (long edge [`THUMB_EDGE`]) at `thumb`, decoded from its file.
fn rendering_previews(path: &Path, preview: &Path, thumb: &Path) -> Result<(), PreviewError> {
    write_previews(decode(path, PREVIEW_EDGE)?, preview, thumb)
}

/// `picture` within [`PREVIEW_EDGE`] at `preview` and within [`THUMB_EDGE`] at `thumb`.
fn write_previews(picture: DynamicImage, preview: &Path, thumb: &Path) -> Result<(), PreviewError> {
    let large = within(picture, PREVIEW_EDGE);
    write_jpeg(&large, preview)?;
    write_jpeg(&within(large, THUMB_EDGE), thumb)
}

/// The lab's copy of the picture in the file at `path` as an image.
fn picture(copy: &Preview, path: &Path) -> Result<DynamicImage, PreviewError> {
    image::RgbImage::from_raw(copy.width, copy.height, copy.rgb.clone())
        .map(DynamicImage::ImageRgb8)
        .ok_or_else(|| PreviewError::Unsuitable {
            path: path.to_path_buf(),
        })
}

/// A frame's thumbnail at `target`.
fn thumbnail(path: &Path, target: &Path) -> Result<(), PreviewError> {
    write_jpeg(&decode(path, THUMB_EDGE)?, target)
}

/// `picture` scaled down to a long edge of `edge` pixels (aspect kept), or as it is when
/// it is no larger.
fn within(picture: DynamicImage, edge: u32) -> DynamicImage {
    if picture.width() <= edge && picture.height() <= edge {
        picture
    } else {
        picture.thumbnail(edge, edge)
    }
}

/// Encodes `picture` as an 8-bit sRGB JPEG of [`QUALITY`] and publishes it at `path`.
fn write_jpeg(picture: &DynamicImage, path: &Path) -> Result<(), PreviewError> {
    let rgb = picture.to_rgb8();
    publish_encoded(path, |bytes| {
        image::codecs::jpeg::JpegEncoder::new_with_quality(bytes, QUALITY).encode_image(&rgb)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::display::DisplayImage;
    use crate::rendering::{Format, SourceExif};

    /// A JPEG of saturated red, orange and grey encoded for `space` with its profile, as
    /// a rendering for it is written.
    fn written_for(space: ColourSpace, dir: &Path) -> PathBuf {
        let srgb: Vec<u8> = [[255, 0, 0], [230, 140, 20], [128, 128, 128]]
            .iter()
            .flat_map(|px| std::iter::repeat_n(*px, 64 * 16).flatten())
            .collect();
        let image = DisplayImage::new_8bit(64, 48, srgb).in_space(space);
        let mut bytes = Vec::new();
        let format = Format::Jpeg { quality: 98 };
        crate::rendering::encode(&image, format, &SourceExif::default(), &mut bytes).unwrap();
        let path = dir.join(format!("{}.jpg", space.name()));
        std::fs::write(&path, bytes).unwrap();
        path
    }

    #[test]
    fn wide_gamut_renderings_are_previewed_in_srgb() {
        let dir = tempfile::tempdir().unwrap();
        for space in ColourSpace::ALL {
            let path = written_for(space, dir.path());
            let preview = decode(&path, PREVIEW_EDGE).unwrap().to_rgb8();
            let raw = image::open(&path).unwrap().to_rgb8();
            for (y, want) in [
                (8, [255, 0, 0]),
                (24, [230, 140, 20]),
                (40, [128, 128, 128]),
            ] {
                let got = preview.get_pixel(32, y).0;
                let off = got.iter().zip(want).map(|(a, b)| a.abs_diff(b)).max();
                assert!(off <= Some(4), "{space:?} row {y}: {got:?} for {want:?}");
            }
            // The file's own codes are not sRGB's, but for sRGB itself.
            let red = raw.get_pixel(32, 8).0;
            assert_eq!(
                space == ColourSpace::Srgb,
                red[1] < 10,
                "{space:?}: {red:?}"
            );
        }
    }
}
