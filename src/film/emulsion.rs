//! A stock set up for one exposure: the scene key, the per-layer exposure tables and the
//! per-pixel emulsion of radiance into display values.

use std::str::FromStr;

use rayon::prelude::*;

use super::{Curve, FilmError, Kind, Stock};
use crate::display::{Depth, DisplayImage, luminance, srgb_encode, srgb_encode_u16, to_8bit};
use crate::radiance::RadianceMap;

/// How the three layers share the light.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ColourMode {
    /// Each channel through its own layer: the stock's own colour character.
    #[default]
    PerLayer,
    /// Luminance through the green layer, chromaticity kept: no colour shift.
    Luminance,
    /// Each layer shifted along log H so that the key (18 % grey) comes out neutral.
    NeutralGrey,
}

impl FromStr for ColourMode {
    type Err = String;

    fn from_str(s: &str) -> Result<ColourMode, String> {
        match s {
            "per-layer" | "layers" => Ok(ColourMode::PerLayer),
            "luminance" => Ok(ColourMode::Luminance),
            "neutral" | "neutral-grey" => Ok(ColourMode::NeutralGrey),
            _ => Err(format!(
                "colour mode {s:?}: expected per-layer, luminance or neutral"
            )),
        }
    }
}

/// What the calibration `k` puts at the stock's metered exposure `8/S`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum Key {
    /// The log-average luminance `exp(mean ln L)` of the scene's lit pixels.
    #[default]
    LogAverage,
    /// A given relative radiance (e.g. a grey card's).
    Grey(f64),
}

/// The scene's key as relative radiance. `LogAverage` is `exp(mean(ln L))` over pixels
/// with finite `L > 0`, on a regular subsample of at most 2²⁰ pixels (enough for a mean
/// of logs; it keeps 24 MP maps fast). A scene with no lit pixel has key 1.
pub fn scene_key(map: &RadianceMap, key: Key) -> f64 {
    if let Key::Grey(g) = key {
        return g;
    }
    let ch = map.channels();
    let pixels = map.pixels();
    let count = pixels.len() / ch;
    let stride = count.div_ceil(1 << 20).max(1);
    let (sum, n) = (0..count.div_ceil(stride))
        .into_par_iter()
        .map(|j| {
            let i = j * stride;
            let p = &pixels[i * ch..i * ch + ch];
            if ch == 3 {
                luminance(p[0], p[1], p[2])
            } else {
                p[0]
            }
        })
        .filter(|l| l.is_finite() && *l > 0.0)
        .map(|l| (f64::from(l).ln(), 1usize))
        .reduce(|| (0.0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
    if n == 0 { 1.0 } else { (sum / n as f64).exp() }
}

/// Mantissa bits kept in the table index: buckets of 2⁻¹¹ relative width, 1.06·10⁻⁴ in
/// log10 H either side of the bucket centre.
const TABLE_MANTISSA_BITS: u32 = 11;
const TABLE_SHIFT: u32 = 23 - TABLE_MANTISSA_BITS;

/// The stated bound on the table's density error (checked per layer when a table is built
/// against the curve's steepest gradient, and measured in the tests).
pub const TABLE_MAX_ERROR_D: f64 = 0.001;

/// A per-layer lookup from exposure `H` (lux·s, `f32`) to a value of the curve, indexed
/// by the top bits of the float: `index = bits(H) >> 12`, i.e. its exponent and 11
/// mantissa bits. Each entry is the curve at the bucket's centre, so the density error is
/// at most `max |dD/dlog10 H| · log10(1 + 2⁻¹¹)/2` (the two end buckets hold the end
/// points, where the curves are flat) — for the steepest built-in stock
/// (gradient ≈ 3) about 3·10⁻⁴ D, under [`TABLE_MAX_ERROR_D`]. Exposures outside the
/// data (and NaN, ±∞, zero, subnormals) clamp to the end buckets: D-max or D-min.
#[derive(Debug, Clone)]
pub struct ExposureTable<T> {
    low: f32,
    high: f32,
    base: u32,
    entries: Vec<T>,
}

impl<T: Copy> ExposureTable<T> {
    /// Tabulates `value(D)` of the curve over its data's exposure range.
    pub fn new(curve: &Curve, value: impl Fn(f64) -> T) -> ExposureTable<T> {
        let (a, b) = curve.log_h_range();
        let low = 10f32.powf(a as f32);
        let high = 10f32.powf(b as f32);
        let base = low.to_bits() >> TABLE_SHIFT;
        let top = high.to_bits() >> TABLE_SHIFT;
        // The end buckets take the end points themselves, so that everything clamped to
        // them is exactly D-max or D-min (the film base stays exactly white).
        let entries = (base..=top)
            .map(|i| {
                let centre = f32::from_bits((i << TABLE_SHIFT) | (1 << (TABLE_SHIFT - 1)));
                let h = if i == base {
                    low
                } else if i == top {
                    high
                } else {
                    centre
                };
                value(curve.density(f64::from(h).log10()))
            })
            .collect();
        ExposureTable {
            low,
            high,
            base,
            entries,
        }
    }

    /// The entry for exposure `h` (lux·s); any `f32` is valid.
    #[inline]
    pub fn get(&self, h: f32) -> T {
        // NaN fails both comparisons and lands on `low`: no light.
        let h = if h >= self.high {
            self.high
        } else if h > self.low {
            h
        } else {
            self.low
        };
        self.entries[((h.to_bits() >> TABLE_SHIFT) - self.base) as usize]
    }

    /// Number of entries.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// Never true: a table spans at least one bucket.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }
}

/// Everything the per-pixel loop needs for one stock, exposure and colour mode.
#[derive(Debug, Clone)]
pub struct Emulsion {
    /// `H = scale[c] · E` per layer (lux·s per unit radiance): `t·k`, times the neutral
    /// shift of [`ColourMode::NeutralGrey`].
    pub scale: [f32; 3],
    mode: ColourMode,
    /// Per-layer display value (sRGB-encoded, 0..=65535).
    display: [ExposureTable<u16>; 3],
    /// Green-layer transmittance for the luminance mode.
    transmittance: ExposureTable<f32>,
}

impl Emulsion {
    /// Prepares a stock for a map whose key (relative radiance) is `key`.
    ///
    /// `k = (8/S) / key`; the layers' scale is `t·k`; in the neutral-grey mode layer `c`
    /// is further multiplied by `10^s_c`, where `s_c` makes
    /// `D_c(log H_key + s_c) − D_min,c = D_g(log H_key) − D_min,g`.
    pub fn new(
        stock: &Stock,
        exposure: f64,
        key: f64,
        mode: ColourMode,
    ) -> Result<Emulsion, FilmError> {
        if stock.kind == Kind::Negative {
            return Err(FilmError::Negative {
                id: stock.id.clone(),
            });
        }
        let h_key = stock.metered_exposure();
        let k = h_key / key;
        let mut scale = [(exposure * k) as f32; 3];
        if mode == ColourMode::NeutralGrey {
            let green = stock.layer(1);
            let above_base = green.density(h_key.log10()) - green.d_min();
            for (c, s) in scale.iter_mut().enumerate() {
                let curve = stock.layer(c);
                if let Some(x) = curve.log_h_at(curve.d_min() + above_base) {
                    *s *= 10f64.powf(x - h_key.log10()) as f32;
                }
            }
        }
        let display = [0, 1, 2].map(|c| {
            let d_min = stock.layer(c).d_min();
            ExposureTable::new(stock.layer(c), move |d| {
                let t = 10f64.powf(-(d - d_min)) as f32;
                (srgb_encode(t) * 65535.0).round() as u16
            })
        });
        let green_min = stock.layer(1).d_min();
        let transmittance =
            ExposureTable::new(stock.layer(1), move |d| 10f64.powf(-(d - green_min)) as f32);
        Ok(Emulsion {
            scale,
            mode,
            display,
            transmittance,
        })
    }

    /// Develops one pixel of linear radiance into sRGB-encoded 16-bit values.
    #[inline]
    pub fn pixel(&self, e: [f32; 3]) -> [u16; 3] {
        match self.mode {
            ColourMode::PerLayer | ColourMode::NeutralGrey => [
                self.display[0].get(e[0] * self.scale[0]),
                self.display[1].get(e[1] * self.scale[1]),
                self.display[2].get(e[2] * self.scale[2]),
            ],
            ColourMode::Luminance => {
                let e = e.map(|v| {
                    if v.is_finite() {
                        v.max(0.0)
                    } else if v > 0.0 {
                        f32::MAX
                    } else {
                        0.0
                    }
                });
                let l = luminance(e[0], e[1], e[2]);
                let t = self.transmittance.get(l * self.scale[1]);
                let rgb = if l > 0.0 && l.is_finite() {
                    e.map(|v| t * (v / l))
                } else {
                    [t; 3]
                };
                // Keep chromaticity: scale a channel above white down with the others.
                let peak = rgb[0].max(rgb[1]).max(rgb[2]);
                let norm = if peak > 1.0 { 1.0 / peak } else { 1.0 };
                rgb.map(|v| srgb_encode_u16(if v.is_finite() { v * norm } else { 1.0 }))
            }
        }
    }
}

impl Emulsion {
    /// Develops a whole map at `depth` bits per sample (rows in parallel).
    pub fn render(&self, map: &RadianceMap, depth: Depth) -> DisplayImage {
        let ch = map.channels();
        let width = map.width() as usize;
        let height = map.height() as usize;
        let rows = map.pixels().par_chunks(width * ch);
        let colour = |p: &[f32]| {
            if ch == 3 {
                [p[0], p[1], p[2]]
            } else {
                [p[0]; 3]
            }
        };
        match depth {
            Depth::Sixteen => {
                let mut samples = vec![0u16; width * height * 3];
                samples
                    .par_chunks_mut(width * 3)
                    .zip(rows)
                    .for_each(|(out, row)| {
                        for (o, p) in out.chunks_exact_mut(3).zip(row.chunks_exact(ch)) {
                            o.copy_from_slice(&self.pixel(colour(p)));
                        }
                    });
                DisplayImage::new(map.width(), map.height(), samples)
            }
            Depth::Eight => {
                let mut samples = vec![0u8; width * height * 3];
                self.render_rows_8bit(map, 0, &mut samples);
                DisplayImage::new_8bit(map.width(), map.height(), samples)
            }
        }
    }

    /// Develops rows `first..first + out.len()/(3·width)` of `map` into 8-bit RGB `out`
    /// (rows in parallel): the unit the streaming JPEG writer pulls.
    pub fn render_rows_8bit(&self, map: &RadianceMap, first: usize, out: &mut [u8]) {
        let ch = map.channels();
        let width = map.width() as usize;
        let rows = out.len() / (width * 3);
        let input = &map.pixels()[first * width * ch..(first + rows) * width * ch];
        out.par_chunks_mut(width * 3)
            .zip(input.par_chunks(width * ch))
            .for_each(|(out, row)| {
                for (o, p) in out.chunks_exact_mut(3).zip(row.chunks_exact(ch)) {
                    let e = if ch == 3 {
                        [p[0], p[1], p[2]]
                    } else {
                        [p[0]; 3]
                    };
                    let v = self.pixel(e);
                    o.copy_from_slice(&[to_8bit(v[0]), to_8bit(v[1]), to_8bit(v[2])]);
                }
            });
    }
}

/// Renders `map` through a reversal stock at relative exposure `t`, 16 bits per sample.
pub fn render(
    map: &RadianceMap,
    stock: &Stock,
    exposure: f64,
    mode: ColourMode,
    key: Key,
) -> Result<DisplayImage, FilmError> {
    let emulsion = Emulsion::new(stock, exposure, scene_key(map, key), mode)?;
    Ok(emulsion.render(map, Depth::Sixteen))
}
