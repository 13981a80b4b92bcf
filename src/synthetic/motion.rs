//! Camera motion between the frames of a bracket: a scene as a frame moved by a known
//! transform sees it.

use nalgebra::Matrix3;
use rayon::prelude::*;

use crate::radiance::RadianceMap;

/// The radiance `scene` shows a camera moved so that the reference pixel `x` lands on
/// pixel `T·x` of the new frame (`transform` row-major, the convention of
/// [`crate::align`]): the new frame's pixel `y` reads the scene at `T⁻¹·y`, bilinear,
/// the scene's edge pixels extended beyond it. `None` when `T` is singular.
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
