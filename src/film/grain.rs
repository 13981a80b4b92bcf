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
//! The noise is a function of (seed, x, y) only, so a rendering is reproducible and
//! independent of threading: one SplitMix64 hash per pixel gives three 12-bit fields, one
//! per layer, each indexing a table of the 4096 normal quantiles `Φ⁻¹((i + ½)/4096)`
//! (scaled so that the table's variance is exactly 1; bounded at ±3.5 σ). Layers are
//! independent, pixels are independent: white noise at the pixel scale, as the model asks.
//! The model holds while the pixel is larger than the dye clouds (a few µm).

use std::sync::LazyLock;

use super::Stock;

/// Diameter of the granularity aperture of the data sheets, µm.
const APERTURE_UM: f64 = 48.0;

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
            // Mixed once, so that neighbouring seeds are unrelated fields (not shifts).
            seed: splitmix64(seed),
        })
    }

    /// Standard deviation of density per pixel at density `d` in layer `c`.
    #[inline]
    pub fn sigma(&self, c: usize, d: f32) -> f32 {
        self.scale[c] * (d - self.d_min[c]).max(0.0).sqrt()
    }

    /// The three layers' standard normal numbers of pixel (`x`, `y`).
    #[inline]
    pub(crate) fn normals(&self, x: usize, y: usize) -> [f32; 3] {
        let h = splitmix64(self.seed ^ ((y as u64) << 32) ^ x as u64);
        let t = &*NORMAL_QUANTILES;
        [
            t[(h & QUANTILE_MASK) as usize],
            t[((h >> QUANTILE_BITS) & QUANTILE_MASK) as usize],
            t[((h >> (2 * QUANTILE_BITS)) & QUANTILE_MASK) as usize],
        ]
    }
}

const QUANTILE_BITS: u32 = 12;
const QUANTILE_MASK: u64 = (1 << QUANTILE_BITS) - 1;

/// The `2^QUANTILE_BITS` quantiles of the standard normal at `(i + ½)/n`, from its CDF
/// integrated by Simpson's rule on a grid of 10⁻³ σ over ±8 σ, scaled to variance 1.
static NORMAL_QUANTILES: LazyLock<Vec<f32>> = LazyLock::new(|| {
    let n = 1usize << QUANTILE_BITS;
    let step = 1e-3;
    let density = |z: f64| (-0.5 * z * z).exp() / (2.0 * std::f64::consts::PI).sqrt();
    let mut quantiles = Vec::with_capacity(n);
    let (mut z, mut cdf) = (-8.0f64, 0.0f64);
    for i in 0..n {
        let p = (i as f64 + 0.5) / n as f64;
        loop {
            let next =
                cdf + step / 6.0 * (density(z) + 4.0 * density(z + step / 2.0) + density(z + step));
            if next >= p {
                // Linear between the grid points (the CDF's curvature over 10⁻³ σ is far
                // below the table's own resolution).
                quantiles.push(z + step * (p - cdf) / (next - cdf));
                break;
            }
            z += step;
            cdf = next;
        }
    }
    let mean = quantiles.iter().sum::<f64>() / n as f64;
    let sd = (quantiles.iter().map(|q| (q - mean).powi(2)).sum::<f64>() / n as f64).sqrt();
    quantiles.iter().map(|q| ((q - mean) / sd) as f32).collect()
});

/// SplitMix64's output function (Steele, Lea & Flood 2014): a bijective 64-bit mix.
fn splitmix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_quantile_table_is_a_unit_normal() {
        let t = &*NORMAL_QUANTILES;
        assert_eq!(t.len(), 4096);
        let mean = t.iter().map(|&v| f64::from(v)).sum::<f64>() / 4096.0;
        let var = t.iter().map(|&v| f64::from(v).powi(2)).sum::<f64>() / 4096.0;
        assert!(
            mean.abs() < 1e-6 && (var - 1.0).abs() < 1e-5,
            "{mean} {var}"
        );
        // The median and the quartiles where Φ puts them (±0.6745 σ).
        assert!(t[2047] < 0.0 && t[2048] > 0.0);
        assert!((t[1024] + 0.6745).abs() < 2e-3, "{}", t[1024]);
        assert!(t.windows(2).all(|w| w[0] < w[1]));
        assert!(t[4095] > 3.3 && t[4095] < 3.7, "{}", t[4095]);
    }

    #[test]
    fn the_noise_is_white_unit_and_uncorrelated_between_layers() {
        let seed = splitmix64(7);
        let grain = Grain {
            scale: [1.0; 3],
            d_min: [0.0; 3],
            seed,
        };
        let (w, h) = (512, 512);
        let n: Vec<[f32; 3]> = (0..w * h).map(|i| grain.normals(i % w, i / w)).collect();
        let count = (w * h) as f64;
        for c in 0..3 {
            let var = n.iter().map(|v| f64::from(v[c]).powi(2)).sum::<f64>() / count;
            assert!((var - 1.0).abs() < 0.01, "layer {c}: variance {var}");
        }
        let corr = |f: &dyn Fn(usize) -> Option<(f32, f32)>| {
            let pairs: Vec<(f32, f32)> = (0..w * h).filter_map(f).collect();
            pairs
                .iter()
                .map(|&(a, b)| f64::from(a) * f64::from(b))
                .sum::<f64>()
                / pairs.len() as f64
        };
        // Neighbours across, down and the next layer: no correlation beyond sampling
        // noise (1/√N ≈ 0.002).
        let across = corr(&|i| (i % w + 1 < w).then(|| (n[i][1], n[i + 1][1])));
        let down = corr(&|i| (i / w + 1 < h).then(|| (n[i][0], n[i + w][0])));
        let layers = corr(&|i| Some((n[i][0], n[i][2])));
        for r in [across, down, layers] {
            assert!(r.abs() < 0.01, "{across} {down} {layers}");
        }
        // Another seed is another field.
        let other = Grain {
            seed: splitmix64(8),
            ..grain
        };
        let same = (0..1000).filter(|&x| other.normals(x, 3) == grain.normals(x, 3));
        assert!(same.count() < 5);
    }
}
