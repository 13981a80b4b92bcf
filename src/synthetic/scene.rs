//! The procedural HDR test scene.

use rayon::prelude::*;

use crate::radiance::RadianceMap;

/// Scene-referred mid-grey: the radiance of an 18 % reflector.
pub const MID_GREY: f64 = 0.18;

/// Height of the horizon (fraction of the image height from the top).
const HORIZON: f64 = 0.42;
/// Sun centre (x as a fraction of the width, y of the height) and radius (of the height).
const SUN: (f64, f64, f64) = (0.72, 0.16, 0.045);
/// Sun disk centre radiance, stops above mid-grey.
const SUN_STOPS: f64 = 10.0;
/// Halo radiance at the disk's rim, stops above mid-grey; it falls as `(r_sun/r)^2.5`.
const HALO_STOPS: f64 = 9.0;
/// Deep-shadow box `(x0, x1)` as fractions of the width, `(y0, y1)` of the height.
const SHADOW: (f64, f64, f64, f64) = (0.04, 0.30, 0.52, 0.96);
/// Colour-patch grid, right-hand column of charts (fractions of width / height).
const PATCHES: (f64, f64, f64, f64) = (0.36, 0.96, 0.47, 0.61);
/// Fine-detail block: stripes (left half) and text-like glyphs (right half).
const DETAIL: (f64, f64, f64, f64) = (0.36, 0.96, 0.64, 0.84);
/// Grey step wedge: 16 neutral steps, one stop apart, from −9 to +6 stops.
const WEDGE: (f64, f64, f64, f64) = (0.36, 0.96, 0.88, 0.96);
/// The six saturated patch colours: R, G, B, C, M, Y (linear; minor channels 3 % of major).
const PATCH_COLOURS: [[f64; 3]; 6] = [
    [1.0, 0.03, 0.03],
    [0.03, 1.0, 0.03],
    [0.03, 0.03, 1.0],
    [0.03, 1.0, 1.0],
    [1.0, 0.03, 1.0],
    [1.0, 1.0, 0.03],
];

/// Renders the seeded procedural HDR scene: `width × height` RGB linear radiance (`f32`),
/// mid-grey `0.18`, 18.9 stops of luminance from p0.1 (deep shadow) to p99.9 (sun disk).
///
/// The same `(width, height, seed)` always gives the same pixels; the seed changes the
/// textures (clouds, ground, shadow grain, glyphs), not the layout. Layout, in fractions of
/// the width (x) and height (y), brightness in stops relative to mid-grey
/// (`E = 0.18·2^stops`):
///
/// | region | where | radiance |
/// |---|---|---|
/// | sky | y < 0.42 | +1 at the zenith to +2.5 at the horizon, ±0.4 clouds (fractal noise), blue |
/// | sun disk | centre (0.72, 0.16), radius 0.045·height | +10 at the centre, +9.5 at the rim, warm white |
/// | sun halo | around the disk | +9 at the rim falling as `(r_sun/r)^2.5`, added to the sky |
/// | ground | y ≥ 0.42 | +0.5 at the horizon to −2.5 at the bottom, ±2.5 fractal texture, earth/green tints |
/// | deep shadow | x 0.04–0.30, y 0.52–0.96 | −5 at its edge to −9 at its centre, ±0.3 grain |
/// | colour patches | x 0.36–0.96, y 0.47–0.61 | 6 × 2 grid R G B C M Y; major channel at +1.5 (top row) and −1.5 (bottom row) stops, minor channels 3 % of it |
/// | fine detail | x 0.36–0.66, y 0.64–0.84 | square-wave stripes, periods 2, 3, 5 and 8 pixels (vertical then horizontal), −1.5 / +1.5 |
/// | text | x 0.66–0.96, y 0.64–0.84 | random 5 × 7-pixel glyphs in 6 × 9-pixel cells, ink −3 on paper +1 |
/// | grey wedge | x 0.36–0.96, y 0.88–0.96 | 16 neutral steps, −9 to +6 stops |
///
/// Textures are in fractions of the height (the scene looks the same at every size); the
/// stripes and glyphs are in pixels (fine detail at every size). Log luminance covers every
/// stop from −9 to +10 (tested).
pub fn scene(width: u32, height: u32, seed: u64) -> RadianceMap {
    let layout = Layout {
        width: f64::from(width),
        height: f64::from(height.max(1)),
        seed,
    };
    let row_len = width as usize * 3;
    let mut pixels = vec![0.0_f32; row_len * height as usize];
    if row_len > 0 {
        pixels
            .par_chunks_mut(row_len)
            .enumerate()
            .for_each(|(y, row)| {
                let mut textures = layout.row_textures(y as u32);
                for (x, pixel) in row.chunks_exact_mut(3).enumerate() {
                    let rgb = layout.radiance(&mut textures, x as u32, y as u32);
                    for (out, value) in pixel.iter_mut().zip(rgb) {
                        *out = value as f32;
                    }
                }
            });
    }
    RadianceMap::new(width, height, 3, pixels).expect("buffer sized width × height × 3")
}

struct Layout {
    width: f64,
    height: f64,
    seed: u64,
}

/// Which fractal texture: each gets its own lattice.
#[derive(Clone, Copy)]
enum Texture {
    Clouds = 1,
    Ground = 2,
    Tint = 3,
    Grain = 4,
    Glyphs = 5,
}

/// The fractal textures along one row of pixels.
struct RowTextures {
    clouds: Fbm,
    ground: Fbm,
    tint: Fbm,
    grain: Fbm,
}

impl Layout {
    /// The textures of row `y`, with their frequencies in cycles per image height.
    fn row_textures(&self, y: u32) -> RowTextures {
        let py = (f64::from(y) + 0.5) / self.height;
        RowTextures {
            clouds: Fbm::new(self.seed, Texture::Clouds, 3.0, 6.0 * py, 3),
            ground: Fbm::new(self.seed, Texture::Ground, 4.0, 4.0 * py, 4),
            tint: Fbm::new(self.seed, Texture::Tint, 2.0, 2.0 * py, 2),
            grain: Fbm::new(self.seed, Texture::Grain, 40.0, 40.0 * py, 2),
        }
    }

    /// Linear RGB radiance of pixel `(x, y)`; `textures` are those of row `y`.
    fn radiance(&self, textures: &mut RowTextures, x: u32, y: u32) -> [f64; 3] {
        // Position in fractions of width (u) and height (v); (px, py) in heights.
        let (px, py) = (
            (f64::from(x) + 0.5) / self.height,
            (f64::from(y) + 0.5) / self.height,
        );
        let (u, v) = (px * self.height / self.width, py);
        let inside =
            |(x0, x1, y0, y1): (f64, f64, f64, f64)| u >= x0 && u < x1 && v >= y0 && v < y1;
        if v < HORIZON {
            return self.sky(&mut textures.clouds, px, py);
        }
        if inside(SHADOW) {
            return self.shadow(&mut textures.grain, u, v, px);
        }
        if inside(PATCHES)
            && let Some(rgb) = patch(u, v)
        {
            return rgb;
        }
        if inside(DETAIL) {
            return self.detail(u, x, y);
        }
        if inside(WEDGE) {
            let step = ((u - WEDGE.0) / (WEDGE.1 - WEDGE.0) * 16.0)
                .floor()
                .min(15.0);
            let e = grey(step - 9.0);
            return [e, e, e];
        }
        self.ground(textures, px, py)
    }

    fn sky(&self, clouds: &mut Fbm, px: f64, py: f64) -> [f64; 3] {
        let t = py / HORIZON;
        let stops = 1.0 + 1.5 * t + 0.4 * clouds.at(px);
        let tint = mix(
            unit_luminance([0.55, 0.8, 1.3]),
            unit_luminance([0.95, 1.0, 1.05]),
            t,
        );
        let sky = grey(stops);
        let sun_tint = unit_luminance([1.05, 1.0, 0.88]);
        let (sx, sy, r_sun) = (SUN.0 * self.width / self.height, SUN.1, SUN.2);
        let r = ((px - sx).powi(2) + (py - sy).powi(2)).sqrt() / r_sun;
        if r <= 1.0 {
            let e = grey(SUN_STOPS - 0.5 * r * r);
            return sun_tint.map(|c| c * e);
        }
        let halo = grey(HALO_STOPS) * r.powf(-2.5);
        [0, 1, 2].map(|c| tint[c] * sky + sun_tint[c] * halo)
    }

    fn ground(&self, textures: &mut RowTextures, px: f64, py: f64) -> [f64; 3] {
        let depth = (py - HORIZON) / (1.0 - HORIZON);
        let stops = 0.5 - 3.0 * depth + 2.5 * textures.ground.at(px);
        let t = 0.5 + 0.5 * textures.tint.at(px);
        let tint = mix(
            unit_luminance([1.2, 1.0, 0.7]),
            unit_luminance([0.7, 1.05, 0.8]),
            t.clamp(0.0, 1.0),
        );
        let e = grey(stops);
        tint.map(|c| c * e)
    }

    /// Deep shadow: −5 stops at the box edge to −9 at its centre, with a little grain.
    fn shadow(&self, grain: &mut Fbm, u: f64, v: f64, px: f64) -> [f64; 3] {
        let (x0, x1, y0, y1) = SHADOW;
        // Distance to the nearest edge in heights, normalised by the half-size of the
        // shorter side: 0 at the edge, 1 at the centre line.
        let wx = (x1 - x0) * self.width / self.height;
        let dx = (u - x0).min(x1 - u) * self.width / self.height;
        let dy = (v - y0).min(y1 - v);
        let half = 0.5 * wx.min(y1 - y0);
        let d = (dx.min(dy) / half).clamp(0.0, 1.0);
        let stops = -5.0 - 4.0 * d + 0.3 * grain.at(px);
        let tint = unit_luminance([1.0, 0.95, 0.9]);
        let e = grey(stops);
        tint.map(|c| c * e)
    }

    /// Stripes (left half) and glyphs (right half), in pixel units.
    fn detail(&self, u: f64, x: u32, y: u32) -> [f64; 3] {
        let (x0, x1, y0, y1) = DETAIL;
        let top = (y0 * self.height).ceil() as u32;
        let bottom = (y1 * self.height).ceil() as u32;
        let stops = if u < 0.5 * (x0 + x1) {
            // Four bands; periods 2, 3, 5, 8 px; first two vertical stripes, last two horizontal.
            let band = ((y.saturating_sub(top)) * 4 / (bottom - top).max(1)).min(3);
            let period = [2, 3, 5, 8][band as usize];
            let along = if band < 2 { x } else { y };
            if (along / period) % 2 == 0 { 1.5 } else { -1.5 }
        } else {
            let (cx, cy) = (x / 6, y.saturating_sub(top) / 9);
            let (gx, gy) = (x % 6, y.saturating_sub(top) % 9);
            let cell = lattice(
                self.seed ^ Texture::Glyphs as u64,
                i64::from(cx),
                i64::from(cy),
            );
            // One cell in six is a word space; glyph pixels are inked with probability 0.45.
            let ink = cell > -2.0 / 3.0 && gx < 5 && gy < 7 && {
                let bit = hash(
                    self.seed ^ ((Texture::Glyphs as u64) << 8),
                    i64::from(x),
                    i64::from(y),
                );
                (bit >> 40) % 100 < 45
            };
            if ink { -3.0 } else { 1.0 }
        };
        let e = grey(stops);
        [e, e, e]
    }
}

/// Fractal value noise along one row: up to four octaves, each half the amplitude and about
/// twice the frequency of the last, normalised to `[−1, 1]`.
struct Fbm {
    octaves: [Octave; 4],
    count: usize,
    norm: f64,
}

impl Fbm {
    /// The texture on the row at `y` (in lattice units of the first octave), with
    /// `frequency` lattice cells per image height along x.
    fn new(seed: u64, texture: Texture, frequency: f64, y: f64, count: u32) -> Fbm {
        let mut octaves = [Octave::default(); 4];
        let (mut amplitude, mut scale, mut norm) = (1.0, 1.0, 0.0);
        for (o, octave) in octaves.iter_mut().enumerate().take(count as usize) {
            let seed = seed ^ ((texture as u64) << 56) ^ ((o as u64) << 48);
            *octave = Octave::new(seed, frequency * scale, amplitude, y * scale);
            norm += amplitude;
            amplitude *= 0.5;
            scale *= 2.03;
        }
        Fbm {
            octaves,
            count: count as usize,
            norm,
        }
    }

    /// The texture at `px` (in image heights from the left edge).
    fn at(&mut self, px: f64) -> f64 {
        let sum: f64 = self.octaves[..self.count]
            .iter_mut()
            .map(|o| o.at(px))
            .sum();
        sum / self.norm
    }
}

/// One octave of value noise on one row. The four lattice values around the current cell
/// are kept, so walking along the row hashes only when it enters a new cell.
#[derive(Clone, Copy, Default)]
struct Octave {
    seed: u64,
    frequency: f64,
    amplitude: f64,
    iy: i64,
    /// Smoothstep of the row's position within its lattice cell.
    sy: f64,
    ix: Option<i64>,
    corners: [f64; 4],
}

impl Octave {
    fn new(seed: u64, frequency: f64, amplitude: f64, y: f64) -> Octave {
        let fy = y.floor();
        Octave {
            seed,
            frequency,
            amplitude,
            iy: fy as i64,
            sy: smoothstep(y - fy),
            ix: None,
            corners: [0.0; 4],
        }
    }

    /// `amplitude · noise(px·frequency, y)`: lattice values in `[−1, 1]` blended by
    /// smoothsteps.
    fn at(&mut self, px: f64) -> f64 {
        let x = px * self.frequency;
        let fx = x.floor();
        let ix = fx as i64;
        if self.ix != Some(ix) {
            let (seed, iy) = (self.seed, self.iy);
            self.corners = [
                lattice(seed, ix, iy),
                lattice(seed, ix + 1, iy),
                lattice(seed, ix, iy + 1),
                lattice(seed, ix + 1, iy + 1),
            ];
            self.ix = Some(ix);
        }
        let sx = smoothstep(x - fx);
        let [a, b, c, d] = self.corners;
        let top = a + sx * (b - a);
        let bottom = c + sx * (d - c);
        self.amplitude * (top + self.sy * (bottom - top))
    }
}

/// `3t² − 2t³`: zero slope at both ends of a lattice cell.
fn smoothstep(t: f64) -> f64 {
    t * t * (3.0 - 2.0 * t)
}

/// Saturated patch colour at `(u, v)` inside the patch grid, or `None` in the gaps.
fn patch(u: f64, v: f64) -> Option<[f64; 3]> {
    let (x0, x1, y0, y1) = PATCHES;
    let (fx, fy) = ((u - x0) / (x1 - x0) * 6.0, (v - y0) / (y1 - y0) * 2.0);
    let (column, row) = (fx.floor().min(5.0), fy.floor().min(1.0));
    // 10 % of each cell is a gap showing the ground between patches.
    let (gx, gy) = (fx - column, fy - row);
    if !(0.05..0.95).contains(&gx) || !(0.05..0.95).contains(&gy) {
        return None;
    }
    let level = grey(if row == 0.0 { 1.5 } else { -1.5 });
    Some(PATCH_COLOURS[column as usize].map(|c| c * level))
}

/// Radiance `0.18·2^stops`.
fn grey(stops: f64) -> f64 {
    MID_GREY * stops.exp2()
}

/// Scales a colour to unit Rec. 709 luminance `Y = 0.2126 R + 0.7152 G + 0.0722 B`.
fn unit_luminance(c: [f64; 3]) -> [f64; 3] {
    let y = 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2];
    c.map(|v| v / y)
}

fn mix(a: [f64; 3], b: [f64; 3], t: f64) -> [f64; 3] {
    [0, 1, 2].map(|c| a[c] + t * (b[c] - a[c]))
}

/// A 64-bit hash of a lattice point (the splitmix64 finaliser of a mixed key).
fn hash(seed: u64, ix: i64, iy: i64) -> u64 {
    let mut h = seed
        ^ (ix as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (iy as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
    h = (h ^ (h >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    h = (h ^ (h >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    h ^ (h >> 31)
}

/// Pseudo-random value in `[−1, 1)` at a lattice point.
fn lattice(seed: u64, ix: i64, iy: i64) -> f64 {
    (hash(seed, ix, iy) >> 11) as f64 * (2.0 / (1u64 << 53) as f64) - 1.0
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rec. 709 luminance of every pixel.
    fn luminances(map: &RadianceMap) -> Vec<f64> {
        map.pixels()
            .chunks_exact(3)
            .map(|p| 0.2126 * f64::from(p[0]) + 0.7152 * f64::from(p[1]) + 0.0722 * f64::from(p[2]))
            .collect()
    }

    fn percentile(sorted: &[f64], p: f64) -> f64 {
        sorted[((sorted.len() - 1) as f64 * p).round() as usize]
    }

    fn at(map: &RadianceMap, u: f64, v: f64) -> [f32; 3] {
        let x = (u * f64::from(map.width())) as usize;
        let y = (v * f64::from(map.height())) as usize;
        let i = (y * map.width() as usize + x) * 3;
        [map.pixels()[i], map.pixels()[i + 1], map.pixels()[i + 2]]
    }

    #[test]
    fn scene_is_deterministic_and_seeded() {
        let a = scene(96, 64, 1);
        assert_eq!(a, scene(96, 64, 1));
        assert_ne!(a, scene(96, 64, 2));
        assert!(a.pixels().iter().all(|v| v.is_finite() && *v > 0.0));
        assert_eq!(scene(0, 0, 1).pixels().len(), 0);
    }

    #[test]
    fn scene_spans_more_than_sixteen_stops_with_tones_in_every_stop() {
        let map = scene(384, 256, 11);
        let mut y = luminances(&map);
        y.sort_by(f64::total_cmp);
        let range = (percentile(&y, 0.999) / percentile(&y, 0.001)).log2();
        assert!(range >= 16.0, "dynamic range {range} stops");
        // Histogram of log2(Y / 0.18) in one-stop bins from −9 to +10.
        let mut bins = [0usize; 19];
        for v in &y {
            let stop = (v / MID_GREY).log2().floor() + 9.0;
            if (0.0..19.0).contains(&stop) {
                bins[stop as usize] += 1;
            }
        }
        let fractions: Vec<f64> = bins.iter().map(|&n| n as f64 / y.len() as f64).collect();
        println!("range {range:.2} stops; fraction per stop from -9: {fractions:.4?}");
        for (i, f) in fractions.iter().enumerate() {
            assert!(*f >= 0.001, "stop {} holds only {f}", i as i32 - 9);
        }
    }

    #[test]
    fn regions_have_their_documented_radiance() {
        let map = scene(600, 400, 3);
        // Grey wedge step 9 is mid-grey exactly; step 0 is −9 stops.
        let step = |k: f64| at(&map, WEDGE.0 + (k + 0.5) / 16.0 * (WEDGE.1 - WEDGE.0), 0.92);
        assert_eq!(step(9.0), [0.18_f32; 3]);
        assert_eq!(step(0.0), [(0.18 / 512.0) as f32; 3]);
        // The sun's centre is 2^10 above mid-grey (in luminance).
        let sun = at(&map, SUN.0, SUN.1);
        let y =
            0.2126 * f64::from(sun[0]) + 0.7152 * f64::from(sun[1]) + 0.0722 * f64::from(sun[2]);
        assert!((y / MID_GREY).log2() > 9.9, "sun {sun:?}");
        // The deep shadow's centre is about 2^−9 below mid-grey.
        let deep = at(
            &map,
            0.5 * (SHADOW.0 + SHADOW.1),
            0.5 * (SHADOW.2 + SHADOW.3),
        );
        assert!(
            (f64::from(deep[1]) / MID_GREY).log2() < -8.5,
            "shadow {deep:?}"
        );
        // Top-left patch is saturated red; the third, blue.
        let cell = |c: f64, r: f64| {
            at(
                &map,
                PATCHES.0 + (c + 0.5) / 6.0 * (PATCHES.1 - PATCHES.0),
                PATCHES.2 + (r + 0.5) / 2.0 * (PATCHES.3 - PATCHES.2),
            )
        };
        let red = cell(0.0, 0.0);
        assert!(red[0] > 30.0 * red[1] && red[0] > 30.0 * red[2], "{red:?}");
        let blue = cell(2.0, 1.0);
        assert!(
            blue[2] > 30.0 * blue[0] && blue[2] > 30.0 * blue[1],
            "{blue:?}"
        );
        // Finest stripes alternate every pixel pair: 3 stops between neighbours two apart.
        let x = (0.40 * 600.0) as usize;
        let y = (DETAIL.2 * 400.0).ceil() as usize + 2;
        let g = |x: usize| map.pixels()[(y * 600 + x) * 3 + 1];
        assert!((f64::from(g(x)) / f64::from(g(x + 2))).log2().abs() > 2.9);
        assert_eq!(g(x), g(x + 4));
    }
}
