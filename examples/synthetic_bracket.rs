//! Renders the synthetic scene through the sRGB curve at three exposures two stops apart
//! and writes them as 8-bit PNG files: `cargo run --release --example synthetic_bracket -- DIR`.

use std::path::PathBuf;

use filmback::frame::{BitDepth, Samples};
use filmback::synthetic::{ResponseCurve, Sensor, expose, scene};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dir = PathBuf::from(std::env::args().nth(1).unwrap_or_else(|| ".".to_string()));
    let radiance = scene(1200, 800, 1);
    let sensor = Sensor {
        read_noise_dn: 0.5,
        full_well_electrons: Some(20_000.0),
        seed: 1,
        ..Sensor::noiseless(ResponseCurve::Srgb, BitDepth::Eight)
    };
    for stops in [-2, 0, 2] {
        let frame = expose(&radiance, f64::from(stops).exp2(), &sensor);
        let Samples::Eight(codes) = frame.samples() else {
            unreachable!("8-bit sensor")
        };
        let path = dir.join(format!("synthetic_{stops:+}.png"));
        image::save_buffer(
            &path,
            codes,
            frame.width(),
            frame.height(),
            image::ExtendedColorType::Rgb8,
        )?;
        println!("{}", path.display());
    }
    Ok(())
}
