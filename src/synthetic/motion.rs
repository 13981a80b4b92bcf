//! Camera motion between the frames of a bracket: a scene as a frame moved by a known
//! transform sees it, resampled from a raster ([`moved`], best after [`lens`]) or rendered
//! exactly ([`waves`]).

use nalgebra::Matrix3;
use rayon::prelude::*;

use super::sensor::SplitMix64;
use crate::radiance::RadianceMap;

/// The radiance `scene` shows a camera moved so that the reference pixel `x` lands on
/// pixel `T·x` of the new frame (`transform` row-major, the convention of
/// [`crate::align`]): the new frame's pixel `y` reads the scene at `T⁻¹·y`, bilinear,
/// the scene's edge pixels extended beyond it. `None` when `T` is singular.
///
/// The interpolation blurs each pixel by its own fraction of a pixel, so where the raster
/// has detail near the pixel scale the moved frame is not what a camera moved by `T`
/// would record: registering such frames finds transforms a pixel or more off at the
/// corners of a 24 MP frame. [`lens`] first removes such detail; [`waves`] renders a
/// scene exactly through a move.
pub fn moved(scene: &RadianceMap, transform: &[[f64; 3]; 3]) -> Option<RadianceMap> {
    let t = Matrix3::from_fn(|r, c| transform[r][c]);
    let inverse = t.try_inverse()?;
    let (w, h, c) = (
        scene.width() as usize,
        scene.height() as usize,
        scene.channels(),
    );
    let source = scene.pixels();
    let mut out = vec![0f32; source.len()];
    let clamp = |v: f64, n: usize| v.clamp(0.0, (n - 1) as f64);
    out.par_chunks_mut(w * c).enumerate().for_each(|(y, row)| {
        for x in 0..w {
            let p = inverse * nalgebra::Vector3::new(x as f64, y as f64, 1.0);
            let (sx, sy) = (clamp(p.x / p.z, w), clamp(p.y / p.z, h));
            let (x0, y0) = (
                (sx as usize).min(w.saturating_sub(2)),
                (sy as usize).min(h.saturating_sub(2)),
            );
            let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
            let (fx, fy) = ((sx - x0 as f64) as f32, (sy - y0 as f64) as f32);
            for ch in 0..c {
                let at = |xx: usize, yy: usize| source[(yy * w + xx) * c + ch];
                let top = at(x0, y0) + (at(x1, y0) - at(x0, y0)) * fx;
                let bottom = at(x0, y1) + (at(x1, y1) - at(x0, y1)) * fx;
                row[x * c + ch] = top + (bottom - top) * fy;
            }
        }
    });
    RadianceMap::new(scene.width(), scene.height(), c, out).ok()
}

/// `map` through a lens: the `[1 2 1]/4` binomial blur twice in each direction (edges
/// repeated; about a Gaussian of 1 px standard deviation), so that no detail is finer than
/// the sensor samples and [`moved`] shows what a moved camera records ([`super::scene`]'s
/// stripes and glyphs are drawn in pixels, down to a period of two).
pub fn lens(map: &RadianceMap) -> RadianceMap {
    let (w, h, c) = (map.width() as usize, map.height() as usize, map.channels());
    let mut pixels = map.pixels().to_vec();
    for _ in 0..2 {
        pixels = binomial(&pixels, w, c, 1, w);
        pixels = binomial(&pixels, w, c, w, h);
    }
    RadianceMap::new(w as u32, h as u32, c, pixels).expect("the same size")
}

/// The `[1 2 1]/4` blur along one axis: neighbours `stride` pixels apart, `len` of them.
fn binomial(p: &[f32], w: usize, c: usize, stride: usize, len: usize) -> Vec<f32> {
    let mut out = vec![0f32; p.len()];
    out.par_chunks_mut(c).enumerate().for_each(|(i, px)| {
        let along = if stride == 1 { i % w } else { i / w };
        let before = if along == 0 { i } else { i - stride };
        let after = if along + 1 == len { i } else { i + stride };
        for (ch, v) in px.iter_mut().enumerate() {
            *v = 0.25 * p[before * c + ch] + 0.5 * p[i * c + ch] + 0.25 * p[after * c + ch];
        }
    });
    out
}

/// The pixel transform (reference pixel → moved frame's pixel, the convention of
/// [`moved`]) of a camera turned by `degrees` and shifted by `(dx, dy)` pixels about the
/// centre of a `width × height` frame, with the perspective terms `(px, py)`: `C·N·C⁻¹`,
/// `N = [cos θ, −sin θ, dx/s; sin θ, cos θ, dy/s; px, py, 1]` in coordinates normalised by
/// `C` (centre `((w − 1)/2, (h − 1)/2)`, unit `s`, half the longer side), scaled so that
/// its last entry is 1.
pub fn camera_move(
    width: u32,
    height: u32,
    degrees: f64,
    (dx, dy): (f64, f64),
    (px, py): (f64, f64),
) -> [[f64; 3]; 3] {
    let (cx, cy) = (f64::from(width - 1) / 2.0, f64::from(height - 1) / 2.0);
    let s = f64::from(width.max(height)) / 2.0;
    let (sin, cos) = degrees.to_radians().sin_cos();
    let n = Matrix3::new(cos, -sin, dx / s, sin, cos, dy / s, px, py, 1.0);
    let c = Matrix3::new(s, 0.0, cx, 0.0, s, cy, 0.0, 0.0, 1.0);
    let c_inv = Matrix3::new(1.0 / s, 0.0, -cx / s, 0.0, 1.0 / s, -cy / s, 0.0, 0.0, 1.0);
    let m = c * n * c_inv;
    std::array::from_fn(|r| std::array::from_fn(|k| m[(r, k)] / m[(2, 2)]))
}

/// Plane waves in the log radiance of [`waves`].
const WAVES: usize = 16;
/// The waves' lowest and highest frequencies, cycles per pixel.
const WAVE_FREQUENCIES: (f64, f64) = (0.004, 0.1);
/// The stops of a wave of the lowest frequency and unit tint.
const WAVE_STOPS: f64 = 0.27;
/// The radiance where every wave crosses zero.
const WAVES_MEAN: f64 = 0.35;

/// A `width × height` scene of plane waves in log radiance, as a camera moved by
/// `transform` (the convention of [`moved`]) sees it, rendered exactly: pixel `y` shows
/// the scene at `p = T⁻¹·y` (pixel units),
/// `E_c(p) = 0.35·2^{S_c(p)}`, `S_c(p) = Σ_k 0.27·√(f₀/f_k)·t_{k,c}·cos(2π·f_k·(u_k·p) + φ_k)`
/// over 16 waves of direction `u_k`, phase `φ_k`, frequency `f_k` log-uniform from
/// `f₀` = 0.004 to 0.1 cycles per pixel (below the 0.25 at which a Bayer mosaic's colour
/// planes alias) and per-channel tint `t_{k,c}` in `[0.5, 1.5)`, all drawn from `seed`: a
/// spread of about 0.4 stops (σ) around 0.35, which frames two stops apart both expose
/// well in part. `None` when `T` is singular.
pub fn waves(width: u32, height: u32, seed: u64, transform: &[[f64; 3]; 3]) -> Option<RadianceMap> {
    let inverse = Matrix3::from_fn(|r, c| transform[r][c]).try_inverse()?;
    let mut random = SplitMix64(seed);
    let mut unit = || (random.next() >> 11) as f64 / (1u64 << 53) as f64;
    let (low, high) = WAVE_FREQUENCIES;
    let waves: Vec<([f64; 2], f64, [f64; 3])> = (0..WAVES)
        .map(|_| {
            let f = low * (high / low).powf(unit());
            let (sin, cos) = (std::f64::consts::TAU * unit()).sin_cos();
            let phase = std::f64::consts::TAU * unit();
            let stops = WAVE_STOPS * (low / f).sqrt();
            let tint = [unit(), unit(), unit()].map(|t| stops * (0.5 + t));
            ([f * cos, f * sin], phase, tint)
        })
        .collect();
    let w = width as usize;
    let mut out = vec![0f32; w * height as usize * 3];
    out.par_chunks_mut(w * 3).enumerate().for_each(|(y, row)| {
        for (x, pixel) in row.chunks_exact_mut(3).enumerate() {
            let p = inverse * nalgebra::Vector3::new(x as f64, y as f64, 1.0);
            let (px, py) = (p.x / p.z, p.y / p.z);
            let mut s = [0.0; 3];
            for ([fx, fy], phase, tint) in &waves {
                let wave = (std::f64::consts::TAU * (fx * px + fy * py) + phase).cos();
                for (s, t) in s.iter_mut().zip(tint) {
                    *s += t * wave;
                }
            }
            for (out, s) in pixel.iter_mut().zip(s) {
                *out = (WAVES_MEAN * s.exp2()) as f32;
            }
        }
    });
    RadianceMap::new(width, height, 3, out).ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn waves_are_rendered_exactly_through_a_move() {
        let still = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let shift = [[1.0, 0.0, 3.0], [0.0, 1.0, -2.0], [0.0, 0.0, 1.0]];
        let a = waves(40, 30, 7, &still).unwrap();
        let b = waves(40, 30, 7, &shift).unwrap();
        fn at(m: &RadianceMap, x: usize, y: usize) -> &[f32] {
            &m.pixels()[(y * 40 + x) * 3..][..3]
        }
        for (x, y) in [(3, 0), (20, 10), (39, 27)] {
            let (seen, truth) = (at(&b, x, y), at(&a, x - 3, y + 2));
            for (s, t) in seen.iter().zip(truth) {
                assert!((s / t - 1.0).abs() < 1e-6, "({x}, {y}): {seen:?} {truth:?}");
            }
        }
        let other = waves(40, 30, 8, &still).unwrap();
        assert_ne!(a.pixels(), other.pixels(), "the seed draws the waves");
        let singular = [[1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 0.0, 1.0]];
        assert!(waves(40, 30, 7, &singular).is_none());
    }

    #[test]
    fn a_camera_move_turns_about_the_centre() {
        let m = camera_move(101, 51, 90.0, (2.0, -3.0), (0.0, 0.0));
        let at = |x: f64, y: f64| {
            let z = m[2][0] * x + m[2][1] * y + m[2][2];
            (
                (m[0][0] * x + m[0][1] * y + m[0][2]) / z,
                (m[1][0] * x + m[1][1] * y + m[1][2]) / z,
            )
        };
        let (x, y) = at(50.0, 25.0);
        assert!(
            (x - 52.0).abs() < 1e-9 && (y + 3.0 - 25.0).abs() < 1e-9,
            "{x} {y}"
        );
        // A quarter turn takes (60, 25), 10 px right of the centre, to 10 px below it.
        let (x, y) = at(60.0, 25.0);
        assert!(
            (x - 52.0).abs() < 1e-9 && (y - 32.0).abs() < 1e-9,
            "{x} {y}"
        );
        // The perspective row in pixels: (px/s, 0, 1 − px·cx/s), scaled to end in 1.
        let tilted = camera_move(101, 51, 0.0, (0.0, 0.0), (0.01, 0.0));
        let expected = (0.01 / 50.5) / (1.0 - 0.01 * 50.0 / 50.5);
        assert!((tilted[2][0] - expected).abs() < 1e-12, "{tilted:?}");
    }
}
