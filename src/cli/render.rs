//! `filmback render HDR.exr --film velvia50 --film provia400@1/2 --tonemap histogram -o DIR`:
//! re-renders an existing radiance map without re-merging.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result, bail};

use filmback::atomic::Overwrite;
use filmback::rendering::{self, Outputs, SourceExif};

use super::looks::LookArgs;

/// Arguments of `filmback render`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The radiance map (OpenEXR, RGB).
    exr: PathBuf,
    #[command(flatten)]
    looks: LookArgs,
    /// Output folder.
    #[arg(short, long, value_name = "DIR")]
    output: PathBuf,
    /// Copy camera, lens, exposure, date, artist and copyright EXIF from this frame.
    #[arg(long, value_name = "FRAME")]
    exif_from: Option<PathBuf>,
    /// Replace existing renderings.
    #[arg(long)]
    force: bool,
}

/// Runs `filmback render`.
pub fn run(args: Args) -> Result<ExitCode> {
    if args.looks.film.is_empty() && args.looks.tonemap.is_empty() {
        bail!("nothing to render: give at least one --film or --tonemap");
    }
    let (looks, format) = args.looks.looks()?;
    let exif = match &args.exif_from {
        Some(path) => SourceExif::from_frame_bytes(
            &std::fs::read(path).with_context(|| format!("reading {}", path.display()))?,
        ),
        None => SourceExif::default(),
    };
    let map = filmback::hdr_output::read_exr(&args.exr)?;
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
        space: args.looks.colour_space()?,
        overwrite: if args.force {
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
