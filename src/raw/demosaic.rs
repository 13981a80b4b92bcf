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

/// Interpolates the two missing colours of every pixel of `mosaic` (laid out as `cfa`):
/// interleaved camera RGB, `width × height × 3`.
pub fn demosaic(mosaic: MergedMosaic, cfa: &Cfa) -> Vec<f32> {
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
    rgb.into_inner().into_iter().flatten().collect()
}
