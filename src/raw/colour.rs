//! From white-balanced camera RGB to linear Rec. 709, with the file's colour matrix.
//!
//! With `M` the file's XYZ → camera matrix and `n` the as-shot neutral (camera RGB of the
//! scene's white, green = 1), white balance divides each camera channel by `n` (done on
//! the mosaic, before demosaicking). The balanced camera RGB `c'` then goes to Rec. 709 by
//!
//! ```text
//! rgb = k · XYZ→709 · CAT(W → D65) · M⁻¹ · diag(n) · c',      W = M⁻¹ n
//! ```
//!
//! where `CAT` is the Bradford adaptation from the scene white `W` to D65 (the white
//! of Rec. 709) and `k` the scalar that maps `c' = (1, 1, 1)` (the scene's white at the
//! level of the longest frame's clipping point in green) to luminance 1. Only the file's
//! one matrix is used (the D65 one when it has it); DNG's interpolation between two
//! calibration illuminants by colour temperature is not done.

use std::path::Path;

use nalgebra::{Matrix3, Vector3};

use super::{RawError, RawInfo};

/// CIE XYZ → linear Rec. 709 / sRGB primaries, D65 white (IEC 61966-2-1).
const XYZ_TO_709: [[f64; 3]; 3] = [
    [3.240_454_2, -1.537_138_5, -0.498_531_4],
    [-0.969_266_0, 1.876_010_8, 0.041_556_0],
    [0.055_643_4, -0.204_025_9, 1.057_225_2],
];

/// D65 white in XYZ, `Y = 1`.
const D65: [f64; 3] = [0.950_47, 1.0, 1.088_83];

/// Bradford cone response matrix.
const BRADFORD: [[f64; 3]; 3] = [
    [0.8951, 0.2664, -0.1614],
    [-0.7502, 1.7135, 0.0367],
    [0.0389, -0.0685, 1.0296],
];

fn matrix(m: [[f64; 3]; 3]) -> Matrix3<f64> {
    Matrix3::from_fn(|r, c| m[r][c])
}

/// The white balance gains `1/n` per camera channel.
pub fn white_balance(info: &RawInfo) -> [f32; 3] {
    info.neutral.map(|n| (1.0 / n) as f32)
}

/// The 3×3 matrix from white-balanced camera RGB to linear Rec. 709 (row-major), see the
/// module docs; `path` names the file when the matrix is singular.
pub fn camera_to_709(info: &RawInfo, path: &Path) -> Result<[[f32; 3]; 3], RawError> {
    let singular = || RawError::SingularMatrix {
        path: path.to_path_buf(),
    };
    let camera_to_xyz = matrix(info.xyz_to_camera)
        .try_inverse()
        .ok_or_else(singular)?;
    let n = Vector3::from(info.neutral);
    let white = camera_to_xyz * n;
    let bradford = matrix(BRADFORD);
    let source = bradford * white;
    let target = bradford * Vector3::from(D65);
    if source.iter().any(|v| v.is_nan() || v.abs() <= 1e-12) {
        return Err(singular());
    }
    let scale = Matrix3::from_diagonal(&target.component_div(&source));
    let cat = bradford.try_inverse().ok_or_else(singular)? * scale * bradford;
    let t = matrix(XYZ_TO_709) * cat * camera_to_xyz * Matrix3::from_diagonal(&n);
    // Luminance of c' = (1, 1, 1): Y of the adapted white.
    let y = (cat * camera_to_xyz * n)[1];
    if !(y.is_finite() && y > 0.0) {
        return Err(singular());
    }
    let t = t / y;
    Ok([0, 1, 2].map(|r| [0, 1, 2].map(|c| t[(r, c)] as f32)))
}

/// Applies `m` to every pixel of interleaved RGB `pixels`, in place.
pub fn apply(m: &[[f32; 3]; 3], pixels: &mut [f32]) {
    use rayon::prelude::*;
    pixels.par_chunks_exact_mut(3).for_each(|p| {
        let (r, g, b) = (p[0], p[1], p[2]);
        for (out, row) in p.iter_mut().zip(m) {
            *out = row[0] * r + row[1] * g + row[2] * b;
        }
    });
}
