//! The rendering flags shared by `filmback merge` and `filmback render`.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use filmback::display::ColourSpace;
use filmback::film::{Catalogue, ColourMode, Key};
use filmback::rendering::{self, Format, Look};

/// `--film`, `--tonemap` and how the renderings are made.
#[derive(Debug, Clone, clap::Args)]
pub struct LookArgs {
    /// A stock and relative exposure: `velvia50`, `provia400@0.5`, `p1600@1/8`,
    /// `velvia50@+1ev` (repeat for several renderings; `filmback films` lists stocks).
    #[arg(long, value_name = "STOCK[@t]")]
    pub film: Vec<String>,
    /// A tone map: `linear`, `histogram` (Ward Larson with the contrast ceiling) or
    /// `histogram-naive` (repeatable).
    #[arg(long, value_name = "OPERATOR")]
    pub tonemap: Vec<String>,
    /// Encoding of the renderings: jpeg, jpeg:QUALITY, png, png16, tiff, or ultrahdr,
    /// ultrahdr:QUALITY (the HDR still: a gain-map JPEG, docs/film.md).
    #[arg(long, default_value = "jpeg")]
    pub format: String,
    /// The display the renderings are encoded for: srgb, p3 (Display P3) or rec2020; each
    /// file carries the space's ICC profile.
    #[arg(long, default_value = "srgb", value_name = "SPACE")]
    pub colour_space: String,
    /// How film layers share the light: per-layer, luminance, neutral.
    #[arg(long, default_value = "per-layer")]
    pub colour: String,
    /// Meter this relative radiance instead of the log-average luminance.
    #[arg(long, value_name = "RADIANCE")]
    pub grey: Option<f64>,
    /// Folder of extra stock files (*.toml) beside the built-in ones.
    #[arg(long, value_name = "DIR")]
    pub curves: Option<PathBuf>,
}

impl LookArgs {
    /// The requested looks (films first, then tone maps) and their encoding.
    pub fn looks(&self) -> Result<(Vec<Look>, Format)> {
        let mut catalogue = Catalogue::builtin()?;
        if let Some(dir) = &self.curves {
            catalogue = catalogue.with_folder(dir)?;
        }
        let colour: ColourMode = self.colour.parse()?;
        let key = match self.grey {
            Some(g) if g.is_finite() && g > 0.0 => Key::Grey(g),
            Some(g) => bail!("--grey {g}: must be a positive radiance"),
            None => Key::LogAverage,
        };
        let looks = rendering::looks(&catalogue, &self.film, &self.tonemap, 0.0, colour, key)
            .context("--film/--tonemap")?;
        Ok((looks, self.format.parse()?))
    }

    /// The display the renderings are encoded for (`--colour-space`).
    pub fn colour_space(&self) -> Result<ColourSpace> {
        self.colour_space
            .parse()
            .map_err(|e: filmback::display::UnknownColourSpace| {
                anyhow::anyhow!("--colour-space: {e}")
            })
    }
}
