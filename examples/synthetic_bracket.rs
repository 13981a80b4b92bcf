//! Renders a synthetic bracket and writes it with EXIF, ready for `filmback inspect`:
//!
//! `cargo run --release --example synthetic_bracket -- DIR [jpeg|png|tiff] [CURVE] [moved]`
//!
//! Three shots at f/8, ISO 100, 1/500, 1/125 and 1/30 s (two stops apart) of the
//! procedural scene (1500 × 1000, seed 1), through CURVE (linear, gamma-2.2, srgb, film-s,
//! strong-toe; default srgb) with shot and read noise; JPEG at quality 92 and 8 bits, PNG
//! and TIFF at 16 bits. Exposures are scaled so that the middle shot puts mid-grey at
//! `X = 0.18`. With `moved`, the first and last shots see the scene as a handheld camera
//! would: moved by (−4, 3) and (4, −3) px and turned by −0.2° and 0.2° about the top-left
//! corner, for trying `--align`. The scene is then first blurred as a lens would
//! ([`filmback::synthetic::lens`]), so that no frame's detail is finer than its pixels.
//! The frames are [`filmback::synthetic::example_bracket`]'s.

use std::path::PathBuf;

use filmback::frame::BitDepth;
use filmback::synthetic::{Encoding, ResponseCurve, example_bracket, write};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let dir = PathBuf::from(args.next().unwrap_or_else(|| ".".to_string()));
    let (encoding, extension, depth) = match args.next().as_deref().unwrap_or("jpeg") {
        "jpeg" => (Encoding::Jpeg { quality: 92 }, "jpg", BitDepth::Eight),
        "png" => (Encoding::Png, "png", BitDepth::Sixteen),
        "tiff" => (Encoding::Tiff, "tif", BitDepth::Sixteen),
        other => return Err(format!("unknown encoding {other:?}: jpeg, png or tiff").into()),
    };
    let curve_name = args.next().unwrap_or_else(|| "srgb".to_string());
    let curve = ResponseCurve::builtin()
        .into_iter()
        .find(|(name, _)| *name == curve_name)
        .map(|(_, curve)| curve)
        .ok_or_else(|| format!("unknown curve {curve_name:?}"))?;
    let handheld = args.next().as_deref() == Some("moved");
    for (k, (shot, frame)) in example_bracket(curve, depth, handheld)?.iter().enumerate() {
        let path = dir.join(format!("synthetic-{curve_name}-{k}.{extension}"));
        write(&path, frame, shot, encoding)?;
        println!("{}", path.display());
    }
    Ok(())
}
