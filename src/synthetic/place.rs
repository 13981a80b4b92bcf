//! Scenes of real places: the radiance map of a real bracket, to render synthetic brackets
//! from through known curves (real scene statistics, known ground truth).

use std::path::Path;

use super::scene::MID_GREY;
use super::{PlaceError, SyntheticError};
use crate::darkroom::CALIBRATION_PIXELS;
use crate::display::luminance;
use crate::frame::Frame;
use crate::histogram::FrameCounts;
use crate::merge::{self, BracketFrame, MergeOptions};
use crate::metadata::Camera;
use crate::radiance::RadianceMap;
use crate::response::{Degree, RatioSource, calibrate_frames};

/// The radiance map of a real bracket as a scene: `frames` with their relative exposures
/// `e = t·S/N²` (any order), merged with filmback's own bracket pipeline — the joint fit of
/// every frame ([`calibrate_frames`], histograms of [`CALIBRATION_PIXELS`] a frame,
/// degree auto) and the hat-weighted merge —, box-averaged by the whole factor `k =
/// round(√(pixels_in / pixels))` (at least 1) that brings it nearest `pixels` pixels, and
/// scaled so that its median Rec. 709 luminance ([`luminance`]) is `MID_GREY` (0.18), where a
/// photographer's middle exposure puts a scene's middle.
///
/// What it lends an accuracy measurement is a real scene's statistics — its radiance
/// histogram, colours, flat and textured areas, highlights — rather than its exact
/// radiances: the map carries the fitted curve's errors, the frames' noise and, where they
/// are not aligned, doubled edges. RGB frames only.
pub fn real_place(frames: &[(&Frame, f64)], pixels: f64) -> Result<RadianceMap, SyntheticError> {
    let Some(&(first, _)) = frames.first() else {
        return Err(PlaceError::NoFrames.into());
    };
    if first.channels() != 3 {
        return Err(PlaceError::NotRgb(first.channels()).into());
    }
    let stride = ((f64::from(first.width()) * f64::from(first.height())) / CALIBRATION_PIXELS)
        .sqrt()
        .max(1.0) as usize;
    let counts: Vec<FrameCounts> = frames
        .iter()
        .map(|(f, _)| FrameCounts::of_frame(f, stride))
        .collect();
    let input: Vec<(&FrameCounts, f64)> = counts.iter().zip(frames.iter().map(|f| f.1)).collect();
    let calibration =
        calibrate_frames(&input, RatioSource::Argument, Degree::Auto).map_err(PlaceError::from)?;
    let camera = Camera::default();
    let bracket: Vec<BracketFrame<'_>> = frames
        .iter()
        .map(|&(frame, exposure)| BracketFrame {
            source: Path::new("real place"),
            frame,
            exposure,
            camera: &camera,
        })
        .collect();
    let merged = merge::merge(&bracket, &calibration.response, MergeOptions::default())
        .map_err(PlaceError::from)?;
    let map = merged.radiance;
    let (w, h) = (map.width() as usize, map.height() as usize);
    let k = ((w * h) as f64 / pixels).sqrt().round().max(1.0) as usize;
    let (ow, oh) = (w / k, h / k);
    if ow == 0 || oh == 0 {
        return Err(PlaceError::TooSmall {
            width: w,
            height: h,
            k,
        }
        .into());
    }
    let src = map.pixels();
    let mut out = vec![0f32; ow * oh * 3];
    for (i, px) in out.chunks_exact_mut(3).enumerate() {
        let (x, y) = (i % ow, i / ow);
        for (c, v) in px.iter_mut().enumerate() {
            let mut sum = 0f64;
            for dy in 0..k {
                let row = (y * k + dy) * w;
                for dx in 0..k {
                    sum += f64::from(src[(row + x * k + dx) * 3 + c]);
                }
            }
            *v = (sum / (k * k) as f64) as f32;
        }
    }
    let mut lum: Vec<f64> = out
        .chunks_exact(3)
        .map(|p| f64::from(luminance(p[0], p[1], p[2])))
        .collect();
    let mid = lum.len() / 2;
    let median = *lum.select_nth_unstable_by(mid, f64::total_cmp).1;
    if !(median.is_finite() && median > 0.0) {
        return Err(PlaceError::Median(median).into());
    }
    let scale = (MID_GREY / median) as f32;
    out.iter_mut().for_each(|v| *v *= scale);
    RadianceMap::new(ow as u32, oh as u32, 3, out).map_err(|e| PlaceError::from(e).into())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::BitDepth;
    use crate::synthetic::{ResponseCurve, Sensor, expose, scene};

    #[test]
    fn a_bracket_of_a_scene_gives_back_the_scene_at_mid_grey() {
        // The procedural scene through sRGB, three frames two stops apart, no noise: the
        // place is that scene, box-averaged by 2 and scaled to mid grey.
        let truth = scene(128, 96, 5);
        let sensor = Sensor::noiseless(ResponseCurve::Srgb, BitDepth::Eight);
        let shots: Vec<(Frame, f64)> = [0.25, 1.0, 4.0]
            .iter()
            .map(|&e| (expose(&truth, e, &sensor), e))
            .collect();
        let frames: Vec<(&Frame, f64)> = shots.iter().map(|(f, e)| (f, *e)).collect();
        let place = real_place(&frames, 64.0 * 48.0).unwrap();
        assert_eq!(
            (place.width(), place.height(), place.channels()),
            (64, 48, 3)
        );
        let y = |p: &[f32]| f64::from(luminance(p[0], p[1], p[2]));
        let mut lum: Vec<f64> = place.pixels().chunks_exact(3).map(y).collect();
        lum.sort_by(f64::total_cmp);
        assert!((lum[lum.len() / 2] - MID_GREY).abs() < 1e-6);
        // Against the scene averaged the same way, after one scale: within a few per cent
        // where a frame exposed it well (not the sun, clipped in all three).
        let src = truth.pixels();
        let mut ratios = Vec::new();
        for y0 in 0..48 {
            for x0 in 0..64 {
                for c in 0..3 {
                    let mut sum = 0.0;
                    for (dy, dx) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
                        sum += f64::from(src[((2 * y0 + dy) * 128 + 2 * x0 + dx) * 3 + c]);
                    }
                    let v = f64::from(place.pixels()[(y0 * 64 + x0) * 3 + c]);
                    if (0.01..2.0).contains(&(sum / 4.0)) {
                        ratios.push(v / (sum / 4.0));
                    }
                }
            }
        }
        ratios.sort_by(f64::total_cmp);
        let median = ratios[ratios.len() / 2];
        let mut spread: Vec<f64> = ratios.iter().map(|r| (r / median - 1.0).abs()).collect();
        spread.sort_by(f64::total_cmp);
        let p90 = spread[spread.len() * 9 / 10];
        assert!(p90 < 0.05, "p90 {p90}");
    }

    #[test]
    fn no_frames_are_refused() {
        assert!(matches!(
            real_place(&[], 100.0),
            Err(SyntheticError::Place(_))
        ));
    }
}
