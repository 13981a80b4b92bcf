//! Film grain from the data sheet's RMS granularity.
//!
//! A sheet states `σ₄₈`, the standard deviation of density read through a 48 µm circular
//! aperture (area `A = π·(24 µm)²`) on a uniform patch at a stated density. Grain is
//! modelled as independent density noise per pixel and dye layer, added to the layer's
//! density before the density becomes light (for a negative, before the print):
//!
//! `D' = D + σ_px(D)·n`, `n` ~ N(0, 1),
//!
//! `σ_px(D) = g · σ₄₈ · √((D − D_min)/D_ref) · √A / p`
//!
//! - `√A / p` is Selwyn's law (`σ·√area` is constant for fine-grained noise): white noise
//!   of `σ_px` per pixel of side `p` (µm at film scale) averages to `σ₄₈` over the
//!   aperture's `A/p²` pixels. The pixel's size at film scale is the format's long side
//!   over the image's long side (36 mm / 6000 px = 6 µm for a 24 MP 35 mm frame), so the
//!   same stock shows coarser grain on a larger output or a smaller format.
//! - `√((D − D_min)/D_ref)` is the Nutting–Selwyn dependence on density: the variance of
//!   a layer of randomly placed dye clouds grows with the number of clouds, i.e. with the
//!   density above base; `D_ref` is the sheet's reference density above D-min. No grain
//!   at D-min (the base and fog), more in the dense parts.
//! - `g` is the user's strength (1 = the sheet).
//!
//! The noise is a function of (seed, x, y, layer) only (a SplitMix64 hash; the sum of
//! four 16-bit uniforms, an Irwin–Hall approximation of the normal with unit variance,
//! bounded at ±3.46 σ), so a rendering is reproducible and independent of threading.
//! The model holds while the pixel is larger than the dye clouds (a few µm).

use super::Stock;

/// Diameter of the granularity aperture of the data sheets, µm.
pub const APERTURE_UM: f64 = 48.0;

/// The grain of one stock at one pixel size.
#[derive(Debug, Clone)]
pub struct Grain {
    /// `g · σ₄₈ · √A / p / √D_ref` per layer: σ_px at unit density above base.
    scale: [f32; 3],
    /// D-min per layer.
    d_min: [f32; 3],
    seed: u64,
}

impl Grain {
    /// The grain of `stock` (which must carry a granularity) at strength `strength` on
    /// pixels of `pitch_um` µm at film scale. `None` if the stock's sheet gives no RMS
    /// granularity.
    pub fn new(stock: &Stock, strength: f64, pitch_um: f64, seed: u64) -> Option<Grain> {
        let g = stock.granularity.as_ref()?;
        let area = std::f64::consts::PI * (APERTURE_UM / 2.0).powi(2);
        let d_min = [0, 1, 2].map(|c| stock.layer(c).d_min());
        let scale = [0, 1, 2].map(|c| {
            let d_ref = g.net_density(d_min[c]);
            (strength * g.rms / 1000.0 * area.sqrt() / pitch_um / d_ref.sqrt()) as f32
        });
        Some(Grain {
            scale,
            d_min: d_min.map(|d| d as f32),
            seed,
        })
    }

    /// Standard deviation of density per pixel at density `d` in layer `c`.
    #[inline]
    pub fn sigma(&self, c: usize, d: f32) -> f32 {
        self.scale[c] * (d - self.d_min[c]).max(0.0).sqrt()
    }

    /// The grained density of pixel (`x`, `y`) in layer `c` whose density is `d`.
    #[inline]
    pub fn apply(&self, c: usize, d: f32, x: usize, y: usize) -> f32 {
        d + self.sigma(c, d) * normal(self.seed, x, y, c)
    }
}

/// An approximately standard normal number determined by (seed, x, y, layer).
#[inline]
pub fn normal(seed: u64, x: usize, y: usize, c: usize) -> f32 {
    let key = ((y as u64) << 34) ^ ((x as u64) << 2) ^ c as u64;
    let h = splitmix64(seed ^ key);
    let sum = (h & 0xffff) + ((h >> 16) & 0xffff) + ((h >> 32) & 0xffff) + (h >> 48);
    // Mean 4·32767.5, standard deviation √(4·(65536² − 1)/12).
    (sum as f32 - 131_070.0) * (1.0 / 37_837.23)
}

fn splitmix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}
