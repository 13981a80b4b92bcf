//! Scene kinds beside the procedural landscape: a studio set and flat patches.
//!
//! Radiance is relative, as in [`super::scene`]: an 18 % reflector under the key light
//! reads [`MID_GREY`] (`0.18`), so a reflectance `ρ` under illumination `I` (1 at the key
//! light's full strength) has radiance `E = ρ·I`. Exposed at 1, mid-grey lands at `X = 0.18`.
//!
//! What the kinds are for: histograms of real studio work hold narrow peaks — a seamless
//! backdrop filling half the frame, a grey card, the flat faces of a product — and the
//! response recovery must not be biased by them under noise ([`SceneKind::Studio`],
//! [`SceneKind::StudioFalloff`]); [`SceneKind::FlatPatches`] isolates the failure: a few
//! areas uniform in one channel each, on a smooth background.

use std::str::FromStr;

use rayon::prelude::*;

use super::scene::{MID_GREY, scene};
use crate::radiance::RadianceMap;

/// Which synthetic scene to render (see [`SceneKind::render`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SceneKind {
    /// The procedural landscape of [`super::scene()`]: sky, sun, ground, charts, wedge.
    Procedural,
    /// A studio set on an evenly lit seamless backdrop (see [`studio`]).
    Studio,
    /// The same set with the key light falling off across the backdrop by up to 1.5 stops.
    StudioFalloff,
    /// Four areas uniform in one channel each on a smooth background (see `kinds::flat_patches`).
    FlatPatches,
}

impl SceneKind {
    /// Every kind, in the order benches report them.
    pub const ALL: [SceneKind; 4] = [
        SceneKind::Procedural,
        SceneKind::Studio,
        SceneKind::StudioFalloff,
        SceneKind::FlatPatches,
    ];

    /// Short name: `procedural`, `studio`, `studio-falloff`, `flat-patches`.
    pub fn name(self) -> &'static str {
        match self {
            SceneKind::Procedural => "procedural",
            SceneKind::Studio => "studio",
            SceneKind::StudioFalloff => "studio-falloff",
            SceneKind::FlatPatches => "flat-patches",
        }
    }

    /// The scene, `width × height` linear RGB radiance; the same arguments always give the
    /// same pixels, and the seed varies colours and positions, not the layout's proportions.
    pub fn render(self, width: u32, height: u32, seed: u64) -> RadianceMap {
        match self {
            SceneKind::Procedural => scene(width, height, seed),
            SceneKind::Studio => studio(width, height, seed, false),
            SceneKind::StudioFalloff => studio(width, height, seed, true),
            SceneKind::FlatPatches => flat_patches(width, height, seed),
        }
    }
}

/// A scene kind's name that is none of [`SceneKind::ALL`].
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown scene kind {0:?}: procedural, studio, studio-falloff or flat-patches")]
pub struct UnknownScene(pub String);

impl FromStr for SceneKind {
    type Err = UnknownScene;

    fn from_str(s: &str) -> Result<SceneKind, UnknownScene> {
        SceneKind::ALL
            .into_iter()
            .find(|k| k.name() == s)
            .ok_or_else(|| UnknownScene(s.to_string()))
    }
}

/// Seamless backdrop reflectances (linear RGB): white, warm grey, cool grey, pale blue.
const BACKDROPS: [[f64; 3]; 4] = [
    [0.60, 0.60, 0.60],
    [0.52, 0.46, 0.38],
    [0.36, 0.40, 0.46],
    [0.30, 0.42, 0.55],
];

/// Product colours (reflectance): red, deep blue, green, orange.
const PRODUCTS: [[f64; 3]; 4] = [
    [0.55, 0.06, 0.05],
    [0.05, 0.09, 0.45],
    [0.08, 0.40, 0.10],
    [0.70, 0.30, 0.04],
];

/// The 24 patches of a colour rendition chart, approximate linear-sRGB reflectances, in
/// rows of six (dark skin … black).
const CHART: [[f64; 3]; 24] = [
    [0.17, 0.08, 0.05],
    [0.55, 0.30, 0.22],
    [0.12, 0.20, 0.34],
    [0.10, 0.15, 0.05],
    [0.24, 0.22, 0.44],
    [0.13, 0.52, 0.41],
    [0.68, 0.20, 0.03],
    [0.07, 0.10, 0.39],
    [0.55, 0.09, 0.12],
    [0.10, 0.04, 0.14],
    [0.33, 0.50, 0.05],
    [0.78, 0.36, 0.02],
    [0.02, 0.05, 0.29],
    [0.05, 0.29, 0.07],
    [0.45, 0.03, 0.04],
    [0.85, 0.58, 0.01],
    [0.52, 0.08, 0.30],
    [0.00, 0.23, 0.38],
    [0.89, 0.89, 0.88],
    [0.58, 0.59, 0.59],
    [0.36, 0.36, 0.36],
    [0.19, 0.19, 0.19],
    [0.09, 0.09, 0.09],
    [0.03, 0.03, 0.03],
];

/// Rectangles `(u0, u1, v0, v1)` in fractions of width and height.
type Rect = (f64, f64, f64, f64);

/// The cylindrical product (a bottle).
const BOTTLE: Rect = (0.36, 0.64, 0.20, 0.92);
/// A box with two flat faces, left of the bottle.
const BOX: Rect = (0.10, 0.30, 0.26, 0.48);
/// The 18 % grey card.
const CARD: Rect = (0.08, 0.22, 0.56, 0.80);
/// The colour chart (6 × 4 patches on a black frame).
const CHART_AREA: Rect = (0.68, 0.96, 0.45, 0.88);

fn inside((u0, u1, v0, v1): Rect, u: f64, v: f64) -> bool {
    u >= u0 && u < u1 && v >= v0 && v < v1
}

/// A studio product set: `width × height` RGB radiance.
///
/// | element | where (u = x/width, v = y/height) | radiance |
/// |---|---|---|
/// | seamless backdrop | everywhere else (about 62 % of the frame) | one of four backdrop reflectances (0.30–0.60) × illumination |
/// | bottle | u 0.36–0.64, v 0.20–0.92 | a saturated colour, Lambertian cylinder lit from 35° left (`max(0.04, cos(θ + 35°))`), a vertical specular stripe 6.5 stops above mid-grey (Gaussian, 3 % of the bottle's width) and a cap highlight |
/// | box | u 0.10–0.30, v 0.26–0.48 | two flat faces of one colour, lit 1 and 0.35 |
/// | grey card | u 0.08–0.22, v 0.56–0.80 | reflectance 0.18, neutral |
/// | colour chart | u 0.68–0.96, v 0.45–0.88 | 6 × 4 patches of the usual rendition chart on a 0.03 black frame |
/// | bottle shadow | ellipse under the bottle, v 0.90–0.97 | backdrop × `1 − 0.7·(1 − d²)²` inside the ellipse (`d` its normalised radius) |
///
/// Illumination is 1 everywhere (`falloff = false`) or `2^(−1.5·r²)` with `r` the distance
/// from the key light's centre (top left or top right, by seed) over the frame's diagonal
/// in heights (`falloff = true`). The seed chooses the backdrop, the product colour and the
/// light's side.
pub fn studio(width: u32, height: u32, seed: u64, falloff: bool) -> RadianceMap {
    let pick = |salt: u64, n: usize| (mix64(seed ^ salt) % n as u64) as usize;
    let backdrop = BACKDROPS[pick(0x51, BACKDROPS.len())];
    let product = PRODUCTS[pick(0x52, PRODUCTS.len())];
    let light = if pick(0x53, 2) == 0 {
        (0.15, 0.05)
    } else {
        (0.85, 0.05)
    };
    let aspect = f64::from(width) / f64::from(height.max(1));
    let diagonal2 = aspect * aspect + 1.0;
    render(width, height, |u, v| {
        let illumination = if falloff {
            let r2 = ((u - light.0) * aspect).powi(2) + (v - light.1).powi(2);
            (-1.5 * r2 / diagonal2).exp2()
        } else {
            1.0
        };
        let lit = |rho: [f64; 3], k: f64| rho.map(|c| c * illumination * k);
        if inside(BOTTLE, u, v) {
            let (u0, u1, v0, _) = BOTTLE;
            // Across the cylinder: s ∈ [−1, 1], surface normal at angle θ = asin(s).
            let s = 2.0 * (u - u0) / (u1 - u0) - 1.0;
            let theta = s.clamp(-1.0, 1.0).asin();
            let diffuse = (theta + 35f64.to_radians()).cos().max(0.04);
            let stripe = (-0.5 * ((s + 0.35) / 0.06).powi(2)).exp();
            let cap = if v < v0 + 0.04 {
                (-0.5 * ((s + 0.1) / 0.3).powi(2)).exp()
            } else {
                0.0
            };
            let specular = MID_GREY * 6.5f64.exp2() * (stripe + 0.5 * cap) * illumination;
            return lit(product, diffuse).map(|c| c + specular);
        }
        if inside(BOX, u, v) {
            let face = if u < 0.5 * (BOX.0 + BOX.1) { 1.0 } else { 0.35 };
            return lit(product.map(|c| 0.4 * c + 0.25), face);
        }
        if inside(CARD, u, v) {
            return lit([MID_GREY; 3], 1.0);
        }
        if inside(CHART_AREA, u, v) {
            let (u0, u1, v0, v1) = CHART_AREA;
            let (fx, fy) = ((u - u0) / (u1 - u0) * 6.0, (v - v0) / (v1 - v0) * 4.0);
            let (gx, gy) = (fx - fx.floor(), fy - fy.floor());
            if (0.1..0.9).contains(&gx) && (0.1..0.9).contains(&gy) {
                let k = (fy.floor().min(3.0) * 6.0 + fx.floor().min(5.0)) as usize;
                return lit(CHART[k], 1.0);
            }
            return lit([0.03; 3], 1.0);
        }
        // Soft shadow of the bottle on the floor sweep.
        let (cx, cy) = (0.5 * (BOTTLE.0 + BOTTLE.1), 0.935);
        let d2 = ((u - cx) / 0.2).powi(2) + ((v - cy) / 0.035).powi(2);
        let shade = if d2 < 1.0 {
            1.0 - 0.7 * (1.0 - d2).powi(2)
        } else {
            1.0
        };
        lit(backdrop, shade)
    })
}

/// Share of the frame covered by each flat patch.
const PATCH_AREA: f64 = 0.03;

/// Flat patches on a smooth background: `width × height` RGB radiance.
///
/// The background is a smooth field over about 7 stops,
/// `E_c = MID_GREY·2^(−1.5 + 3.5·s(u, v) + 0.4·t_c(u, v))`: `s = (sin(2πu + φ₀) +
/// sin(2πv + φ₁))/2` runs one whole period across the width and the height, so it spans
/// `[−1, 1]` in every frame whatever the seeded phases; `t_c`, a sum of two slower seeded
/// sinusoids in `[−1, 1]`, is a per-channel tint. Four squares of 3 % of
/// the frame each are uniform in **one** channel — R, G, B and R again — at a seeded level
/// from 2 stops below to 1 stop above mid-grey; their other channels keep the background.
/// Each channel's histogram thus holds one or two narrow peaks of about 3 % of the pixels.
pub fn flat_patches(width: u32, height: u32, seed: u64) -> RadianceMap {
    // A seeded value in [0, 1).
    let unit = |salt: u64| (mix64(seed ^ salt) >> 11) as f64 / (1u64 << 53) as f64;
    let phase = |salt: u64| unit(salt) * std::f64::consts::TAU;
    let phases: Vec<f64> = (0..10).map(|k| phase(0x60 + k)).collect();
    let aspect = f64::from(width) / f64::from(height.max(1));
    // A square of `PATCH_AREA·width·height` pixels, in fractions of height and width.
    let side_v = (PATCH_AREA * aspect).sqrt();
    let side_u = (PATCH_AREA / aspect).sqrt();
    let centres = [(0.2, 0.25), (0.7, 0.3), (0.3, 0.72), (0.78, 0.75)];
    let levels: Vec<f64> = (0..4)
        .map(|k| MID_GREY * (-2.0 + 3.0 * unit(0x70 + k)).exp2())
        .collect();
    render(width, height, |u, v| {
        let tau = std::f64::consts::TAU;
        let s = 0.5 * (tau * u + phases[0]).sin() + 0.5 * (tau * v + phases[1]).sin();
        let mut rgb = [0usize, 1, 2].map(|c| {
            let t = 0.5 * (1.7 * u + phases[2 + 2 * c]).sin()
                + 0.5 * (2.1 * v + phases[3 + 2 * c]).sin();
            MID_GREY * (-1.5 + 3.5 * s + 0.4 * t).exp2()
        });
        for (k, &(cu, cv)) in centres.iter().enumerate() {
            if (u - cu).abs() < 0.5 * side_u && (v - cv).abs() < 0.5 * side_v {
                rgb[k % 3] = levels[k];
            }
        }
        rgb
    })
}

/// Renders `radiance(u, v)` at pixel centres, rows in parallel.
fn render(width: u32, height: u32, radiance: impl Fn(f64, f64) -> [f64; 3] + Sync) -> RadianceMap {
    let row_len = width as usize * 3;
    let mut pixels = vec![0.0_f32; row_len * height as usize];
    if row_len > 0 {
        let (w, h) = (f64::from(width), f64::from(height));
        pixels
            .par_chunks_mut(row_len)
            .enumerate()
            .for_each(|(y, row)| {
                let v = (y as f64 + 0.5) / h;
                for (x, pixel) in row.chunks_exact_mut(3).enumerate() {
                    let rgb = radiance((x as f64 + 0.5) / w, v);
                    for (out, value) in pixel.iter_mut().zip(rgb) {
                        *out = value as f32;
                    }
                }
            });
    }
    RadianceMap::new(width, height, 3, pixels).expect("buffer sized width × height × 3")
}

/// The splitmix64 finaliser: a well-mixed 64-bit value from a seed.
fn mix64(seed: u64) -> u64 {
    let mut z = seed.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Share of pixels whose channel `c` equals the most frequent value of that channel.
    fn mode_share(map: &RadianceMap, c: usize) -> f64 {
        let mut values: Vec<u32> = map
            .pixels()
            .chunks_exact(3)
            .map(|p| p[c].to_bits())
            .collect();
        values.sort_unstable();
        let (mut best, mut run) = (0usize, 0usize);
        for (i, v) in values.iter().enumerate() {
            run = if i > 0 && values[i - 1] == *v {
                run + 1
            } else {
                1
            };
            best = best.max(run);
        }
        best as f64 / values.len() as f64
    }

    #[test]
    fn kinds_are_deterministic_finite_and_named() {
        for kind in SceneKind::ALL {
            let a = kind.render(96, 64, 3);
            assert_eq!(a, kind.render(96, 64, 3), "{kind:?}");
            assert!(a.pixels().iter().all(|v| v.is_finite() && *v >= 0.0));
            assert_eq!(kind.name().parse::<SceneKind>(), Ok(kind));
        }
        assert!("studio-lights".parse::<SceneKind>().is_err());
    }

    #[test]
    fn studio_backdrop_fills_40_to_70_percent_and_highlights_clip() {
        for seed in 0..4 {
            let map = studio(300, 200, seed, false);
            let share = mode_share(&map, 1);
            assert!(
                (0.4..=0.7).contains(&share),
                "seed {seed}: backdrop {share}"
            );
            let peak = map.pixels().iter().fold(0.0f32, |a, &b| a.max(b));
            // The specular stripe is over 6 stops above mid-grey.
            assert!(
                f64::from(peak) > MID_GREY * 64.0,
                "seed {seed}: peak {peak}"
            );
            // The grey card reads mid-grey.
            let x = (0.15 * 300.0) as usize;
            let y = (0.68 * 200.0) as usize;
            let j = (y * 300 + x) * 3;
            assert_eq!(map.pixels()[j..j + 3], [MID_GREY as f32; 3]);
        }
        // With fall-off no single value holds more than a few percent of the frame, and
        // the backdrop spans at most 1.5 stops.
        let map = studio(300, 200, 1, true);
        assert!(mode_share(&map, 1) < 0.1);
    }

    #[test]
    fn flat_patches_put_one_narrow_peak_per_channel() {
        let map = flat_patches(300, 200, 5);
        // R holds two patches, G and B one each; the background is smooth (no value
        // repeats on more than a fraction of a percent).
        let (r, g, b) = (
            mode_share(&map, 0),
            mode_share(&map, 1),
            mode_share(&map, 2),
        );
        assert!((0.025..0.035).contains(&g), "G {g}");
        assert!((0.025..0.035).contains(&b), "B {b}");
        assert!((0.025..0.07).contains(&r), "R {r}");
        let stops: Vec<f64> = map
            .pixels()
            .iter()
            .map(|&e| (f64::from(e) / MID_GREY).log2())
            .collect();
        let (lo, hi) = stops
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &s| {
                (a.min(s), b.max(s))
            });
        assert!(hi - lo > 6.0 && hi - lo < 10.0, "{lo}..{hi}");
        // Every seed spans the range: a frame exposed at 1 reaches 2 stops over mid-grey.
        for seed in 0..8 {
            let map = flat_patches(64, 48, seed);
            let top = map.pixels().iter().fold(0.0f32, |a, &b| a.max(b));
            assert!(f64::from(top) > 3.5 * MID_GREY, "seed {seed}: {top}");
        }
    }
}
