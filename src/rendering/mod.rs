//! Display renderings: the looks a radiance map can be shown with (film stocks, tone
//! maps), and encoding them as files — JPEG, PNG 8/16-bit or TIFF 16-bit, for sRGB,
//! Display P3 or Rec. 2020, each with the space's ICC profile and the source frame's EXIF
//! (with `Software = filmback`), published atomically.
//!
//! JPEG goes through the `rusty_jpeg` crate (a fork of `jpeg-encoder` with AVX2 kernels
//! chosen at run time; the same bytes at 4:4:4, 1.45× faster on 24 MP, `docs/performance.md`);
//! bands of rows are developed and encoded on every core and joined by restart markers
//! into one baseline file (`jpeg.rs`, [`encode_look`]).
//! An HDR still (`ultrahdr`) is a gain-map JPEG of the look ([`hdr_still`]).
//! PNG goes through `image`'s encoder, TIFF through `kamadak-exif`'s TIFF writer so that
//! the EXIF sub-IFD (exposure, date) sits in the same file as the pixels.

use std::path::{Path, PathBuf};

use crate::atomic::{self, Overwrite, PublishError};
use crate::display::{ColourSpace, Depth, DisplayImage};
use crate::film::{self, Catalogue, ColourMode, FilmError, Key, Stock};
use crate::radiance::RadianceSource;
use crate::tonemap;

mod encode;
mod gain_map;
pub mod hdr_still;
mod jpeg;
pub mod lut;
mod shrink;
mod source_exif;

pub(crate) use encode::encode_look_previewed;
pub use encode::{Format, encode, encode_look, write};
pub use shrink::Preview;
pub(crate) use shrink::Shrink;
pub use source_exif::SourceExif;

/// Why a rendering could not be made or written.
#[derive(Debug, thiserror::Error)]
pub enum RenderingError {
    /// A stock could not be found or rendered.
    #[error(transparent)]
    Film(#[from] FilmError),
    /// The encoder failed (reported with the file it was writing; the path is empty
    /// when encoding to a writer that is no file).
    #[error("{path}: cannot encode {format}: {source}")]
    Encode {
        /// The output file.
        path: PathBuf,
        /// The format.
        format: Format,
        /// What the encoder said.
        source: ImageEncodeError,
    },
    /// The file could not be published.
    #[error(transparent)]
    Publish(#[from] PublishError),
    /// A look or format name that does not parse.
    #[error("{text:?}: {reason}")]
    Parse {
        /// As typed.
        text: String,
        /// What was expected.
        reason: String,
    },
    /// A look's LUT grid could not be made into a radiance map.
    #[error("{look:?}: {source}")]
    Grid {
        /// The look's name.
        look: String,
        /// Why the grid's buffer does not fit.
        #[source]
        source: crate::radiance::ShapeError,
    },
}

/// Why a display image could not be encoded as a file.
#[derive(Debug, thiserror::Error)]
pub enum ImageEncodeError {
    /// Wider or higher than a JPEG can state (65535 pixels).
    #[error("JPEG is limited to 65535 × 65535 pixels, not {width} × {height}")]
    JpegTooLarge {
        /// Pixels across.
        width: u32,
        /// Pixels down.
        height: u32,
    },
    /// An image without pixels.
    #[error("cannot encode an empty {width} × {height} image")]
    Empty {
        /// Pixels across.
        width: u32,
        /// Pixels down.
        height: u32,
    },
    /// The JPEG encoder refused.
    #[error("JPEG encoder: {0}")]
    Jpeg(#[from] rusty_jpeg::encode::EncodingError),
    /// The JPEG encoder wrote a stream the bands (or an HDR still's two images) cannot be
    /// joined from.
    #[error("unexpected JPEG encoder output: {0}")]
    JpegStream(&'static str),
    /// A gain-map JPEG whose images would pass the 4 GiB its MPF offsets can state.
    #[error("a gain-map JPEG is limited to 4 GiB")]
    GainMapTooLarge,
    /// An HDR still asked of a display image: it is made from a radiance map through a
    /// look.
    #[error("an HDR still is made from a radiance map through a look, not from an image")]
    NeedsRadiance,
    /// The EXIF block (or the TIFF that carries it) could not be written.
    #[error("EXIF: {0}")]
    Exif(#[from] exif::Error),
    /// The PNG encoder refused.
    #[error("PNG encoder: {0}")]
    Png(#[from] ::png::EncodingError),
    /// Writing the bytes failed.
    #[error(transparent)]
    Io(#[from] std::io::Error),
}

/// One way to show a radiance map.
#[derive(Debug, Clone)]
pub enum Look {
    /// Through a film stock (a negative through its print).
    Film {
        /// The stock (boxed: a stock is large next to a tone-map operator).
        stock: Box<Stock>,
        /// Relative exposure `t`.
        exposure: f64,
        /// How the layers share the light.
        colour: ColourMode,
        /// What is metered.
        key: Key,
        /// Grain, MTF, halation, format and print options.
        options: Box<film::Options>,
    },
    /// A tone-mapping operator.
    Tonemap(tonemap::Operator),
}

impl Look {
    /// A film look from a request such as `provia400@1/2` or `velvia50+grain+mtf`. An
    /// option the stock's sheet cannot support (grain without an RMS granularity, MTF
    /// without a curve) or an unknown paper is refused here, before anything renders.
    pub fn film(
        catalogue: &Catalogue,
        request: &str,
        colour: ColourMode,
        key: Key,
    ) -> Result<Look, RenderingError> {
        let request: film::Request = request.parse()?;
        let stock = Box::new(catalogue.get(&request.stock)?.clone());
        // Builds the emulsion once on a nominal size so that bad options fail now.
        film::Emulsion::with_options(&stock, 1.0, 1.0, colour, &request.options, (6000, 4000))?;
        Ok(Look::Film {
            stock,
            exposure: request.exposure,
            colour,
            key,
            options: Box::new(request.options),
        })
    }

    /// The look's part of an output file name: `velvia50-t0.5`, `velvia50-t1+grain`,
    /// `linear`, `histogram`.
    pub fn name(&self) -> String {
        match self {
            Look::Film {
                stock,
                exposure,
                options,
                ..
            } => format!(
                "{}-t{}{}",
                stock.id,
                exposure_label(*exposure),
                options.label
            ),
            Look::Tonemap(op) => op.name().to_string(),
        }
    }

    /// Whether the look spreads light between pixels (a film's MTF or halation), so that
    /// it is developed from the whole map at once rather than a band of rows at a time.
    pub(crate) fn has_optics(&self) -> bool {
        match self {
            Look::Film { options, .. } => options.has_optics(),
            Look::Tonemap(_) => false,
        }
    }

    /// Renders `map` in this look at `depth` bits per sample.
    pub fn render(
        &self,
        map: &dyn RadianceSource,
        depth: Depth,
    ) -> Result<DisplayImage, RenderingError> {
        match self {
            Look::Film { .. } => Ok(self.emulsion(map)?.render(map, depth)),
            Look::Tonemap(op) => Ok(op.apply(map).at_depth(depth)),
        }
    }
}

impl Look {
    /// The emulsion of a film look set up for `map` (its key and size); an error for a
    /// tone map.
    pub fn emulsion(&self, map: &dyn RadianceSource) -> Result<film::Emulsion, RenderingError> {
        match self {
            Look::Film {
                stock,
                exposure,
                colour,
                key,
                options,
            } => Ok(film::Emulsion::with_options(
                stock,
                *exposure,
                film::scene_key(map, *key),
                *colour,
                options,
                (map.width(), map.height()),
            )?),
            Look::Tonemap(op) => Err(RenderingError::Parse {
                text: op.name().to_string(),
                reason: "a tone map has no emulsion".into(),
            }),
        }
    }
}

/// `1`, `0.5`, `0.125`, `8`: the shortest decimal that round-trips (at most 4 places).
fn exposure_label(t: f64) -> String {
    let s = format!("{t:.4}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

/// `DIR/STEM.LOOK.EXT`, the file a rendering of `look` is written to.
pub(crate) fn look_path(dir: &Path, stem: &str, look: &Look, format: Format) -> PathBuf {
    dir.join(format!("{stem}.{}.{}", look.name(), format.extension()))
}

/// The looks of film requests (`velvia50`, `provia400@1/2`, …) and tone-map names
/// (`linear`, `histogram`, `histogram-naive`), in that order. Every film's relative
/// exposure is multiplied by `2^stops` (a preset's exposure offset; 0 for none).
pub fn looks(
    catalogue: &Catalogue,
    films: &[String],
    tonemaps: &[String],
    stops: f64,
    colour: ColourMode,
    key: Key,
) -> Result<Vec<Look>, RenderingError> {
    let mut looks = Vec::with_capacity(films.len() + tonemaps.len());
    for request in films {
        let mut look = Look::film(catalogue, request, colour, key)?;
        if let Look::Film { exposure, .. } = &mut look {
            *exposure *= stops.exp2();
        }
        looks.push(look);
    }
    for name in tonemaps {
        let op = tonemap::Operator::parse(name).ok_or_else(|| RenderingError::Parse {
            text: name.clone(),
            reason: "unknown tone map: expected linear, histogram or histogram-naive".into(),
        })?;
        looks.push(Look::Tonemap(op));
    }
    Ok(looks)
}

/// Where and how renderings are written.
#[derive(Debug, Clone)]
pub struct Outputs<'a> {
    /// Output folder.
    pub dir: &'a Path,
    /// File stem shared by all renderings of one map (e.g. the EXR's stem).
    pub stem: &'a str,
    /// Encoding.
    pub format: Format,
    /// The display the renderings are encoded for.
    pub space: ColourSpace,
    /// Replace existing files or refuse.
    pub overwrite: Overwrite,
    /// EXIF carried into every file.
    pub exif: &'a SourceExif,
}

/// Renders `map` in every look and writes `DIR/STEM.LOOK.EXT` for each, atomically.
/// Returns the paths written, in the order of `looks`. Stops at the first error; files
/// already written stay (each is complete).
pub fn render_all(
    map: &dyn RadianceSource,
    looks: &[Look],
    outputs: &Outputs<'_>,
) -> Result<Vec<PathBuf>, RenderingError> {
    Ok(render_previewed(map, looks, outputs, None)?.paths)
}

/// What [`render_previewed`] made.
#[derive(Debug, Clone, Default)]
pub(crate) struct Rendered {
    /// The files written, in the order of the looks.
    pub paths: Vec<PathBuf>,
    /// Per look, in the same order, its small sRGB copy (none when none was asked for).
    pub previews: Vec<Preview>,
}

/// [`render_all`], and with `preview_edge` a small sRGB copy of each rendering of long
/// edge at most that many pixels, made from the rows as they are encoded ([`Shrink`]).
pub(crate) fn render_previewed(
    map: &dyn RadianceSource,
    looks: &[Look],
    outputs: &Outputs<'_>,
    preview_edge: Option<u32>,
) -> Result<Rendered, RenderingError> {
    let mut rendered = Rendered::default();
    for look in looks {
        let path = look_path(outputs.dir, outputs.stem, look, outputs.format);
        let shrink = preview_edge.map(|edge| Shrink::new(map.width(), map.height(), edge));
        publish_look(map, look, outputs, &path, shrink.as_ref())?;
        rendered.paths.push(path);
        rendered.previews.extend(shrink.map(Shrink::finish));
    }
    Ok(rendered)
}

/// Encodes `look` of `map` and publishes it at `path` (adding its rows to `shrink`).
fn publish_look(
    map: &dyn RadianceSource,
    look: &Look,
    outputs: &Outputs<'_>,
    path: &Path,
    shrink: Option<&Shrink>,
) -> Result<(), RenderingError> {
    atomic::publish_with(path, outputs.overwrite, |w| {
        encode_look_previewed(
            map,
            look,
            outputs.format,
            outputs.space,
            outputs.exif,
            w,
            shrink,
        )
        .map_err(|e| e.at(path))
    })
}

impl RenderingError {
    /// The error with an encoder's failure reported at `path`.
    fn at(self, path: &Path) -> RenderingError {
        match self {
            RenderingError::Encode { format, source, .. } => RenderingError::Encode {
                path: path.to_path_buf(),
                format,
                source,
            },
            other => other,
        }
    }
}

#[cfg(test)]
mod tests;
