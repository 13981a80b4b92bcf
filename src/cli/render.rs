//! `filmback render HDR.exr --film velvia50 --film provia400@1/2 --tonemap histogram -o DIR`:
//! re-renders an existing radiance map without re-merging.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result, bail};

use filmback::atomic::Overwrite;
use filmback::film::{Catalogue, ColourMode, Key};
use filmback::rendering::{self, Format, Look, Outputs, SourceExif};
use filmback::tonemap::Operator;

/// Arguments of `filmback render`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The radiance map (OpenEXR, RGB).
    exr: PathBuf,
    /// A stock and relative exposure: `velvia50`, `provia400@0.5`, `p1600@1/8`,
    /// `velvia50@+1ev` (repeat for several renderings).
    #[arg(long, value_name = "STOCK[@t]")]
    film: Vec<String>,
    /// A tone map: `linear`, `histogram` (Ward Larson with the contrast ceiling) or
    /// `histogram-naive` (repeatable).
    #[arg(long, value_name = "OPERATOR")]
    tonemap: Vec<String>,
    /// Output folder.
    #[arg(short, long, value_name = "DIR")]
    output: PathBuf,
    /// Encoding: jpeg, jpeg:QUALITY, png, png16, tiff.
    #[arg(long, default_value = "jpeg")]
    format: String,
    /// How film layers share the light: per-layer, luminance, neutral.
    #[arg(long, default_value = "per-layer")]
    colour: String,
    /// Meter this relative radiance instead of the log-average luminance.
    #[arg(long, value_name = "RADIANCE")]
    grey: Option<f64>,
    /// Copy camera, lens, exposure, date, artist and copyright EXIF from this frame.
    #[arg(long, value_name = "FRAME")]
    exif_from: Option<PathBuf>,
    /// Folder of extra stock files.
    #[arg(long, value_name = "DIR")]
    curves: Option<PathBuf>,
    /// Replace existing renderings.
    #[arg(long)]
    overwrite: bool,
}

/// Runs `filmback render`.
pub fn run(args: Args) -> Result<ExitCode> {
    if args.film.is_empty() && args.tonemap.is_empty() {
        bail!("nothing to render: give at least one --film or --tonemap");
    }
    let mut catalogue = Catalogue::builtin()?;
    if let Some(dir) = &args.curves {
        catalogue = catalogue.with_folder(dir)?;
    }
    let colour: ColourMode = args.colour.parse().map_err(anyhow::Error::msg)?;
    let key = match args.grey {
        Some(g) if g.is_finite() && g > 0.0 => Key::Grey(g),
        Some(g) => bail!("--grey {g}: must be a positive radiance"),
        None => Key::LogAverage,
    };
    let mut looks = Vec::new();
    for request in &args.film {
        looks.push(Look::film(&catalogue, request, colour, key)?);
    }
    for name in &args.tonemap {
        let op = Operator::parse(name).with_context(|| {
            format!("--tonemap {name:?}: expected linear, histogram or histogram-naive")
        })?;
        looks.push(Look::Tonemap(op));
    }
    let format: Format = args.format.parse()?;
    let exif = match &args.exif_from {
        Some(path) => SourceExif::from_frame_bytes(
            &std::fs::read(path).with_context(|| format!("reading {}", path.display()))?,
        ),
        None => SourceExif::default(),
    };
    let map = rendering::read_exr(&args.exr)?;
    let stem = args
        .exr
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or("render")
        .to_string();
    std::fs::create_dir_all(&args.output)
        .with_context(|| format!("creating {}", args.output.display()))?;
    let outputs = Outputs {
        dir: &args.output,
        stem: &stem,
        format,
        overwrite: if args.overwrite {
            Overwrite::Replace
        } else {
            Overwrite::Refuse
        },
        exif: &exif,
    };
    for path in rendering::render_all(&map, &looks, &outputs)? {
        println!("{}", path.display());
    }
    Ok(ExitCode::SUCCESS)
}
