//! The bracket of `cargo run --example synthetic_bracket`, for the example and for the
//! tests that reproduce what a user trying it meets.

use super::{ResponseCurve, Sensor, Shot, SyntheticError, bracket, lens, moved, scene};
use crate::frame::{BitDepth, Frame};
use crate::metadata::{Camera, CaptureTime};

/// The example's size, in pixels.
pub const EXAMPLE_SIZE: (u32, u32) = (1500, 1000);

/// The example bracket's three shots and frames: the procedural scene ([`scene()`],
/// [`EXAMPLE_SIZE`], seed 1) at f/8, ISO 100 and 1/500, 1/125 and 1/30 s, exposures scaled
/// so that the middle shot puts mid-grey at `X = 0.18`, through `curve` at `depth` with
/// shot noise (20 000 e⁻ full well) and read noise (0.5 DN at 8 bits, 8 DN at 16). With
/// `handheld`, the scene is first blurred as a lens would ([`lens`]) and shot `k` sees it
/// moved by [`example_move`]`(k − 1)`.
pub fn example_bracket(
    curve: ResponseCurve,
    depth: BitDepth,
    handheld: bool,
) -> Result<Vec<(Shot, Frame)>, SyntheticError> {
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
    let times = [1.0 / 500.0, 1.0 / 125.0, 1.0 / 30.0];
    let shots = Shot::series(&camera, first, &times, 8.0, 100.0, 0.5);
    let middle = shots[1]
        .exposure
        .relative()
        .ok_or(SyntheticError::UnknownExposure { shot: 1 })?;
    let sensor = Sensor {
        read_noise_dn: if depth == BitDepth::Eight { 0.5 } else { 8.0 },
        full_well_electrons: Some(20_000.0),
        seed: 1,
        ..Sensor::noiseless(curve, depth)
    };
    let (width, height) = EXAMPLE_SIZE;
    let radiance = scene(width, height, 1);
    let radiance = if handheld { lens(&radiance) } else { radiance };
    let mut frames = Vec::new();
    for (k, shot) in shots.iter().enumerate() {
        let seen = (handheld && k != 1)
            .then(|| moved(&radiance, &example_move(k as f64 - 1.0)))
            .flatten();
        let seen = seen.as_ref().unwrap_or(&radiance);
        let frame = bracket(seen, &sensor, std::slice::from_ref(shot), 1.0 / middle)?;
        frames.extend(frame.into_iter().map(|f| (shot.clone(), f)));
    }
    Ok(frames)
}

/// The handheld example's move of shot `d + 1` from the middle one (pixel transform,
/// row-major, the convention of [`crate::align`]): a shift by `d·(4, −3)` px and a turn by
/// `d·0.2°` about the top-left corner.
pub fn example_move(d: f64) -> [[f64; 3]; 3] {
    let (sin, cos) = (d * 0.2f64).to_radians().sin_cos();
    [[cos, -sin, 4.0 * d], [sin, cos, -3.0 * d], [0.0, 0.0, 1.0]]
}
