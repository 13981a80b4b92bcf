//! Previews, made once when a bracket is published: per rendering a JPEG of long edge
//! [`PREVIEW_EDGE`] px and a thumbnail of [`THUMB_EDGE`] px, per frame a thumbnail, in
//! `state/previews/<stem>/`, each published atomically. The browser never pulls a full
//! rendering to show a screen.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use image::{DynamicImage, ImageReader};
use tokio::sync::mpsc;
use tracing::warn;

use super::{Event, PREVIEW_FOLDER, Published, Record, Shared, file_name};
use crate::atomic::{self, Overwrite, PublishError};

/// Long edge of a rendering's preview, pixels.
pub const PREVIEW_EDGE: u32 = 1600;

/// Long edge of a thumbnail, pixels.
pub const THUMB_EDGE: u32 = 256;

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
    /// The source is larger than [`MAX_SOURCE_BYTES`] or not a regular file.
    #[error("{path}: not a regular file of at most {MAX_SOURCE_BYTES} bytes")]
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
    /// The preview could not be written.
    #[error(transparent)]
    Publish(#[from] PublishError),
}

/// Takes published developments in turn: makes their previews on a blocking thread,
/// then files the record and announces it. Ends when the daemon's handle is dropped.
pub(crate) async fn worker(shared: Arc<Shared>, mut rx: mpsc::UnboundedReceiver<Published>) {
    while let Some(published) = rx.recv().await {
        let dir = shared.state.join(PREVIEW_FOLDER);
        let made = tokio::task::spawn_blocking(move || develop_previews(&dir, published)).await;
        let record = match made {
            Ok(record) => Arc::new(record),
            Err(e) => {
                warn!(error = %e, "making previews failed; the bracket is not shown");
                continue;
            }
        };
        {
            let mut g = shared.gallery();
            g.records.push_front(Arc::clone(&record));
            g.records.truncate(super::GALLERY);
        }
        shared.broadcast(Event::Developed(record));
    }
}

/// Makes the previews of one development and fills in its record's URLs.
fn develop_previews(dir: &Path, published: Published) -> Record {
    let Published {
        mut record,
        frame_paths,
    } = published;
    let folder = dir.join(&record.stem);
    let id = record.id;
    let mut previews = Vec::with_capacity(record.outputs.len());
    for (k, (output, path)) in record
        .outputs
        .iter_mut()
        .zip(&record.files.outputs)
        .enumerate()
    {
        output.file = format!("/file/{id}/{k}");
        let made = if output.look.is_some() {
            rendering_previews(path, &folder)
                .inspect_err(|e| warn!(error = %e, "no preview"))
                .ok()
        } else {
            None
        };
        if made.is_some() {
            output.preview = Some(format!("/preview/{id}/{k}"));
            output.thumb = Some(format!("/thumb/{id}/{k}"));
        }
        previews.push(made);
    }
    record.files.previews = previews;
    let mut thumbs = Vec::with_capacity(frame_paths.len());
    for (k, (frame, path)) in record.frames.iter_mut().zip(&frame_paths).enumerate() {
        let target = folder.join(format!("frame-{k}.jpg"));
        // Camera raws have no quick picture to show: their frames are listed by name.
        let made = (!crate::daemon::intake::is_raw(path))
            .then(|| {
                thumbnail(path, &target)
                    .inspect_err(|e| warn!(error = %e, "no frame thumbnail"))
                    .ok()
            })
            .flatten();
        if made.is_some() {
            frame.thumb = Some(format!("/frame/{id}/{k}"));
        }
        thumbs.push(made);
    }
    record.files.frames = thumbs;
    record
}

/// Decodes the image at `path` (JPEG, PNG or TIFF), refusing oversized files.
fn decode(path: &Path) -> Result<DynamicImage, PreviewError> {
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
    ImageReader::open(path)
        .map_err(|e| decode_error(image::ImageError::IoError(e)))?
        .with_guessed_format()
        .map_err(|e| decode_error(image::ImageError::IoError(e)))?
        .decode()
        .map_err(decode_error)
}

/// A rendering's preview and thumbnail, `<name>.preview.jpg` and `<name>.thumb.jpg` in
/// `folder`.
fn rendering_previews(path: &Path, folder: &Path) -> Result<(PathBuf, PathBuf), PreviewError> {
    let picture = decode(path)?;
    let name = file_name(path);
    let preview = folder.join(format!("{name}.preview.jpg"));
    let thumb = folder.join(format!("{name}.thumb.jpg"));
    let large = within(picture, PREVIEW_EDGE);
    write_jpeg(&large, &preview)?;
    write_jpeg(&within(large, THUMB_EDGE), &thumb)?;
    Ok((preview, thumb))
}

/// A frame's thumbnail at `target`.
fn thumbnail(path: &Path, target: &Path) -> Result<PathBuf, PreviewError> {
    write_jpeg(&within(decode(path)?, THUMB_EDGE), target)?;
    Ok(target.to_path_buf())
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
    let mut bytes = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut bytes, QUALITY)
        .encode_image(&rgb)
        .map_err(|source| PreviewError::Encode {
            path: path.to_path_buf(),
            source,
        })?;
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(|source| PublishError::Io {
            path: parent.to_path_buf(),
            source,
        })?;
    }
    atomic::publish(path, &bytes, Overwrite::Replace)?;
    Ok(())
}
