//! The simulated sensor: exposure, response curve, noise and quantisation.

use rayon::prelude::*;

use super::{ResponseCurve, Shot, SyntheticError};
use crate::frame::{BitDepth, Frame, Samples};
use crate::radiance::RadianceMap;

/// A simulated camera sensor and its processing (see [`expose`] for the model).
#[derive(Debug, Clone, PartialEq)]
pub struct Sensor {
    /// Response `f` from normalised exposure to brightness.
    pub curve: ResponseCurve,
    /// Bits per sample of the output frames.
    pub bit_depth: BitDepth,
    /// Standard deviation of the read noise, in output codes (DN), added after `f`.
    pub read_noise_dn: f64,
    /// Full-well capacity in electrons; `Some` enables shot noise, `None` disables it.
    pub full_well_electrons: Option<f64>,
    /// Seed of the noise generator.
    pub seed: u64,
}

impl Sensor {
    /// A noiseless sensor: only clipping and quantisation separate its frames from `f`.
    pub fn noiseless(curve: ResponseCurve, bit_depth: BitDepth) -> Sensor {
        Sensor {
            curve,
            bit_depth,
            read_noise_dn: 0.0,
            full_well_electrons: None,
            seed: 0,
        }
    }
}

/// Exposes `scene` on `sensor`: one frame with the scene's channels (RGB for RGB scenes).
///
/// Per sample, with scene radiance `E` and `exposure` `k` (relative, unitless):
/// 1. signal `S = k·E` in units of the clipping point; with shot noise
///    (`full_well_electrons = Some(W)`) the `S·W` collected electrons are Poisson,
///    approximated by a Gaussian: `S ← S + √(S/W)·z₁`;
/// 2. normalised exposure `X = clamp(S, 0, 1)`;
/// 3. brightness `B = f(X)` through the response curve;
/// 4. read noise in output codes and quantisation:
///    `code = clamp(round(B·max_code + σ_read·z₂), 0, max_code)`, `max_code = 2^bits − 1`,
///    except that a clipped sample (`S ≥ 1`) reads exactly `max_code`, as a camera whose
///    converter clips after the noise does.
///
/// `z₁, z₂` are independent standard normal draws (Box–Muller over splitmix64). The noise
/// stream of each row is seeded from `(sensor.seed, exposure, row)`: a frame is the same
/// every time it is rendered, and frames at different exposures have independent noise.
/// A negative or NaN exposure gives a black frame.
pub fn expose(scene: &RadianceMap, exposure: f64, sensor: &Sensor) -> Frame {
    let samples = match sensor.bit_depth {
        // `code` is already rounded and within 0..=max_code, so the casts are exact.
        BitDepth::Eight => Samples::Eight(render(scene, exposure, sensor, |code| code as u8)),
        BitDepth::Sixteen => Samples::Sixteen(render(scene, exposure, sensor, |code| code as u16)),
    };
    Frame::new(scene.width(), scene.height(), scene.channels(), samples)
        .expect("samples sized like the scene")
}

/// The per-sample model of [`expose`], rows in parallel; `to_code` stores a code.
fn render<T: Copy + Default + Send>(
    scene: &RadianceMap,
    exposure: f64,
    sensor: &Sensor,
    to_code: impl Fn(f64) -> T + Sync,
) -> Vec<T> {
    let max_code = f64::from(sensor.bit_depth.max_code());
    let read_noise = sensor.read_noise_dn > 0.0;
    let row_len = scene.width() as usize * scene.channels();
    let mut codes = vec![T::default(); scene.pixels().len()];
    if row_len == 0 {
        return codes;
    }
    codes
        .par_chunks_mut(row_len)
        .zip(scene.pixels().par_chunks(row_len))
        .enumerate()
        .for_each(|(row, (out, radiance))| {
            let mut noise = Normals::new(row_seed(sensor.seed, exposure, row));
            for (code, &e) in out.iter_mut().zip(radiance) {
                let mut signal = exposure * f64::from(e);
                if let Some(well) = sensor.full_well_electrons
                    && signal > 0.0
                {
                    signal += (signal / well).sqrt() * noise.next();
                }
                if signal >= 1.0 {
                    *code = to_code(max_code);
                    continue;
                }
                let mut value = sensor.curve.brightness(signal) * max_code;
                if read_noise {
                    value += sensor.read_noise_dn * noise.next();
                }
                let value = value.round();
                // `!(value > 0)` also sends NaN (a NaN exposure) to black.
                *code = to_code(if value > 0.0 {
                    value.min(max_code)
                } else {
                    0.0
                });
            }
        });
    codes
}

/// Exposes `scene` once per shot, at exposure `scale · shots[k].exposure.relative()`
/// (`relative = t·S/N²`), so EXIF and pixels agree up to the common factor `scale`.
pub fn bracket(
    scene: &RadianceMap,
    sensor: &Sensor,
    shots: &[Shot],
    scale: f64,
) -> Result<Vec<Frame>, SyntheticError> {
    shots
        .iter()
        .enumerate()
        .map(|(index, shot)| {
            let relative = shot
                .exposure
                .relative()
                .ok_or(SyntheticError::UnknownExposure { shot: index })?;
            Ok(expose(scene, scale * relative, sensor))
        })
        .collect()
}

/// Seed of one row's noise stream.
pub(super) fn row_seed(seed: u64, exposure: f64, row: usize) -> u64 {
    let mut mixer = SplitMix64(seed ^ exposure.to_bits().rotate_left(17));
    mixer.next() ^ (row as u64).wrapping_mul(0xD1B5_4A32_D192_ED03)
}

/// The splitmix64 generator (Steele, Lea, Flood 2014): a 64-bit counter through a mixer.
pub(super) struct SplitMix64(pub(super) u64);

impl SplitMix64 {
    pub(super) fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
}

/// Standard normal draws by the Box–Muller transform, each transform giving two.
pub(super) struct Normals {
    source: SplitMix64,
    spare: Option<f64>,
}

impl Normals {
    pub(super) fn new(seed: u64) -> Normals {
        Normals {
            source: SplitMix64(seed),
            spare: None,
        }
    }

    /// One N(0, 1) draw. From one 64-bit draw, `u₁ ∈ (0, 1]` and `u₂ ∈ [0, 1)` of 24 bits
    /// each give `r = √(−2 ln u₁)` and the pair `(r cos 2πu₂, r sin 2πu₂)`, computed in
    /// `f32` (ample for noise; tails reach 5.7σ).
    pub(super) fn next(&mut self) -> f64 {
        if let Some(z) = self.spare.take() {
            return z;
        }
        const UNIT: f32 = 1.0 / (1u32 << 24) as f32;
        let bits = self.source.next();
        let u1 = ((bits >> 40) + 1) as f32 * UNIT;
        let u2 = ((bits >> 16) & 0xFF_FFFF) as f32 * UNIT;
        let r = (-2.0 * u1.ln()).sqrt();
        let (sin, cos) = (std::f32::consts::TAU * u2).sin_cos();
        self.spare = Some(f64::from(r * sin));
        f64::from(r * cos)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metadata::{Camera, CaptureTime, Exposure};
    use crate::synthetic::scene;

    fn flat(value: f32, width: u32, height: u32) -> RadianceMap {
        RadianceMap::new(width, height, 1, vec![value; (width * height) as usize]).unwrap()
    }

    fn codes(frame: &Frame) -> Vec<f64> {
        match frame.samples() {
            Samples::Eight(v) => v.iter().map(|&c| f64::from(c)).collect(),
            Samples::Sixteen(v) => v.iter().map(|&c| f64::from(c)).collect(),
        }
    }

    fn mean_and_sd(v: &[f64]) -> (f64, f64) {
        let mean = v.iter().sum::<f64>() / v.len() as f64;
        let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (v.len() - 1) as f64;
        (mean, var.sqrt())
    }

    #[test]
    fn noiseless_exposure_is_the_curve_quantised() {
        let map = scene(96, 64, 5);
        for (name, curve) in ResponseCurve::builtin() {
            for depth in [BitDepth::Eight, BitDepth::Sixteen] {
                let sensor = Sensor::noiseless(curve.clone(), depth);
                let frame = expose(&map, 0.5, &sensor);
                assert_eq!(frame.bit_depth(), depth);
                assert_eq!(frame.channels(), 3);
                let max = f64::from(depth.max_code());
                for (code, &e) in codes(&frame).iter().zip(map.pixels()) {
                    let x = (0.5 * f64::from(e)).min(1.0);
                    assert_eq!(*code, (curve.brightness(x) * max).round(), "{name}");
                }
            }
        }
    }

    #[test]
    fn highlights_clip_and_bad_exposures_are_black() {
        let sensor = Sensor::noiseless(ResponseCurve::Linear, BitDepth::Sixteen);
        assert!(
            codes(&expose(&flat(2.0, 8, 8), 1.0, &sensor))
                .iter()
                .all(|&c| c == 65535.0)
        );
        for exposure in [-1.0, f64::NAN] {
            assert!(
                codes(&expose(&flat(0.3, 8, 8), exposure, &sensor))
                    .iter()
                    .all(|&c| c == 0.0)
            );
        }
    }

    #[test]
    fn clipped_samples_read_full_scale_despite_noise() {
        let sensor = Sensor {
            read_noise_dn: 3.0,
            full_well_electrons: Some(1000.0),
            seed: 5,
            ..Sensor::noiseless(ResponseCurve::Srgb, BitDepth::Eight)
        };
        let frame = expose(&flat(1.5, 50, 40), 1.0, &sensor);
        assert!(codes(&frame).iter().all(|&c| c == 255.0));
        // Just below the clipping point some samples clip and some do not.
        let frame = expose(&flat(0.999, 50, 40), 1.0, &sensor);
        let clipped = codes(&frame).iter().filter(|&&c| c == 255.0).count();
        assert!(clipped > 200 && clipped < 1800, "{clipped} of 2000 clipped");
    }

    #[test]
    fn read_noise_has_the_requested_spread_and_is_reproducible() {
        let sensor = Sensor {
            read_noise_dn: 10.0,
            seed: 42,
            ..Sensor::noiseless(ResponseCurve::Linear, BitDepth::Sixteen)
        };
        let frame = expose(&flat(0.25, 200, 100), 1.0, &sensor);
        let (mean, sd) = mean_and_sd(&codes(&frame));
        assert!((mean - 0.25 * 65535.0).abs() < 0.5, "mean {mean}");
        assert!((sd / 10.0 - 1.0).abs() < 0.03, "sd {sd}");
        assert_eq!(frame, expose(&flat(0.25, 200, 100), 1.0, &sensor));
        let reseeded = Sensor { seed: 43, ..sensor };
        assert_ne!(frame, expose(&flat(0.25, 200, 100), 1.0, &reseeded));
    }

    #[test]
    fn frames_at_different_exposures_have_independent_noise() {
        let sensor = Sensor {
            read_noise_dn: 20.0,
            seed: 1,
            ..Sensor::noiseless(ResponseCurve::Linear, BitDepth::Sixteen)
        };
        let scene = flat(0.25, 200, 100);
        let a = codes(&expose(&scene, 1.0, &sensor));
        let b = codes(&expose(&scene, 1.0 + 1e-9, &sensor));
        let (ma, sa) = mean_and_sd(&a);
        let (mb, sb) = mean_and_sd(&b);
        let covariance = a
            .iter()
            .zip(&b)
            .map(|(x, y)| (x - ma) * (y - mb))
            .sum::<f64>()
            / (a.len() - 1) as f64;
        let correlation = covariance / (sa * sb);
        assert!(correlation.abs() < 0.02, "correlation {correlation}");
    }

    #[test]
    fn shot_noise_follows_the_full_well() {
        // X = 0.25 of a 1000-electron well: σ_X = √(0.25/1000), in 16-bit codes ≈ 1036.
        let sensor = Sensor {
            full_well_electrons: Some(1000.0),
            seed: 9,
            ..Sensor::noiseless(ResponseCurve::Linear, BitDepth::Sixteen)
        };
        let (mean, sd) = mean_and_sd(&codes(&expose(&flat(0.25, 200, 100), 1.0, &sensor)));
        let expected = (0.25_f64 / 1000.0).sqrt() * 65535.0;
        assert!((mean / (0.25 * 65535.0) - 1.0).abs() < 0.002, "mean {mean}");
        assert!(
            (sd / expected - 1.0).abs() < 0.03,
            "sd {sd}, expected {expected}"
        );
    }

    #[test]
    fn bracket_exposes_each_shot_by_its_relative_exposure() {
        let map = scene(48, 32, 2);
        let sensor = Sensor::noiseless(ResponseCurve::Gamma(2.2), BitDepth::Eight);
        let shot = |time_s: Option<f64>| Shot {
            camera: Camera::default(),
            exposure: Exposure {
                time_s,
                f_number: Some(8.0),
                iso: Some(100.0),
            },
            captured_at: CaptureTime {
                year: 2026,
                month: 1,
                day: 2,
                hour: 3,
                minute: 4,
                second: 5,
                nanos: None,
                offset_minutes: None,
            },
        };
        let shots = [shot(Some(0.01)), shot(Some(0.04))];
        let frames = bracket(&map, &sensor, &shots, 2.0).unwrap();
        assert_eq!(frames[0], expose(&map, 2.0 * 0.01 * 100.0 / 64.0, &sensor));
        assert_eq!(frames[1], expose(&map, 2.0 * 0.04 * 100.0 / 64.0, &sensor));
        let error = bracket(&map, &sensor, &[shots[0].clone(), shot(None)], 1.0).unwrap_err();
        assert!(matches!(error, SyntheticError::UnknownExposure { shot: 1 }));
    }
}
