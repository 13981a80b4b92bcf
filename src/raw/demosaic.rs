//! Demosaicking a merged mosaic into camera RGB, through rawler's interpolators.
//!
//! Bayer sensors use PPG, Patterned Pixel Grouping (Chuan-kai Lin): green is interpolated
//! along the direction of the smaller gradient, then red and blue from colour
//! differences to it, so edges keep their sharpness and zipper artefacts stay small (dcraw's
//! "-q 2"). X-Trans sensors use rawler's bilinear interpolation over the 6×6 pattern
//! (rawler 0.8's Markesteijn demosaicker panics on an index overflow). Both work on
//! floating point, so the merged radiance (values above the longest frame's clipping
//! point) is interpolated without being clipped first.

use rawler::cfa::{CFA, PlaneColor};
use rawler::imgop::sensor::Demosaic;
use rawler::imgop::sensor::bayer::ppg::PPGDemosaic;
use rawler::imgop::sensor::xtrans::bilinear::XTransBilinearDemosaic;
use rawler::imgop::{Dim2, Point, Rect};
use rawler::pixarray::PixF32;

use super::Cfa;
use super::mosaic::MergedMosaic;

/// Which interpolator [`demosaic`] uses for `cfa`.
pub fn method(cfa: &Cfa) -> &'static str {
    if cfa.width == 6 {
        "bilinear (X-Trans)"
    } else {
        "PPG (patterned pixel grouping)"
    }
}

/// Interpolates the two missing colours of every pixel of `mosaic` (laid out as `cfa`)
/// and applies the 3×3 matrix `to_output` (row-major, `out_r = Σ_c m[r][c]·in_c`) to each
/// camera RGB pixel: interleaved RGB, `width × height × 3`. The interpolation is rawler's;
/// the matrix is applied on every core while its pixels are copied out.
pub fn demosaic(mosaic: MergedMosaic, cfa: &Cfa, to_output: &[[f32; 3]; 3]) -> Vec<f32> {
    use rayon::prelude::*;
    let (width, height) = (mosaic.width, mosaic.height);
    let pattern = CFA::new(&cfa.name());
    let colours = PlaneColor::default();
    let pixels = PixF32::new_with(mosaic.values, width, height);
    let roi = Rect::new(Point::new(0, 0), Dim2::new(width, height));
    let rgb = if cfa.width == 6 {
        XTransBilinearDemosaic::new().demosaic(&pixels, &pattern, &colours, roi)
    } else {
        PPGDemosaic::new().demosaic(&pixels, &pattern, &colours, roi)
    };
    drop(pixels);
    let camera = rgb.into_inner();
    let mut out = vec![0.0f32; camera.len() * 3];
    out.par_chunks_exact_mut(3)
        .zip(camera.par_iter())
        .for_each(|(o, p)| {
            for (v, row) in o.iter_mut().zip(to_output) {
                *v = row[0] * p[0] + row[1] * p[1] + row[2] * p[2];
            }
        });
    out
}

/// The identity matrix, for [`demosaic`] to camera RGB.
pub const CAMERA_RGB: [[f32; 3]; 3] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
