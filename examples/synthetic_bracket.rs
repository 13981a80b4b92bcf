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

use std::path::PathBuf;

use filmback::frame::BitDepth;
use filmback::metadata::{Camera, CaptureTime};
use filmback::synthetic::{
    Encoding, ResponseCurve, Sensor, Shot, bracket, lens, moved, scene, write,
};

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

    let camera = Camera {
        make: Some("Filmback".to_string()),
        model: Some("Synthetic S1".to_string()),
        serial: Some("0001".to_string()),
        lens: None,
    };
    let first = CaptureTime {
        year: 2026,
        month: 11,
        day: 22,
        hour: 6,
        minute: 0,
        second: 0,
        nanos: Some(0),
        offset_minutes: Some(0),
    };
    let shots = Shot::series(
        &camera,
        first,
        &[1.0 / 500.0, 1.0 / 125.0, 1.0 / 30.0],
        8.0,
        100.0,
        0.5,
    );
    // Relative exposure of the middle shot: t·S/N² = (1/125)·100/64.
    let scale = 1.0
        / shots[1]
            .exposure
            .relative()
            .ok_or("middle shot exposure unknown")?;
    let sensor = Sensor {
        read_noise_dn: if depth == BitDepth::Eight { 0.5 } else { 8.0 },
        full_well_electrons: Some(20_000.0),
        seed: 1,
        ..Sensor::noiseless(curve, depth)
    };
    let handheld = args.next().as_deref() == Some("moved");
    // A moved camera resamples the scene: through a lens first, as a camera sees it.
    let radiance = if handheld {
        lens(&scene(1500, 1000, 1))
    } else {
        scene(1500, 1000, 1)
    };
    let mut frames = Vec::new();
    for (k, shot) in shots.iter().enumerate() {
        let seen = match k {
            1 => None,
            _ if !handheld => None,
            _ => moved(&radiance, &turned(k as f64 - 1.0)),
        };
        let seen = seen.as_ref().unwrap_or(&radiance);
        frames.extend(bracket(seen, &sensor, std::slice::from_ref(shot), scale)?);
    }
    for (k, (frame, shot)) in frames.iter().zip(&shots).enumerate() {
        let path = dir.join(format!("synthetic-{curve_name}-{k}.{extension}"));
        write(&path, frame, shot, encoding)?;
        println!("{}", path.display());
    }
    Ok(())
}

/// The transform of a frame `d` steps from the middle one: `d·(4, −3)` px and `d·0.2°`.
fn turned(d: f64) -> [[f64; 3]; 3] {
    let (sin, cos) = (d * 0.2f64).to_radians().sin_cos();
    [[cos, -sin, 4.0 * d], [sin, cos, -3.0 * d], [0.0, 0.0, 1.0]]
}
