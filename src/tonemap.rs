//! Tone-mapping operators: linear range rescaling and Ward Larson's histogram adjustment.
//!
//! Both map luminance `L = 0.2126 R + 0.7152 G + 0.0722 B` (Rec. 709, linear) to a
//! display value `v ∈ [0, 1]` and keep chromaticity: each channel becomes `v · E_c / L`,
//! scaled down together if one would exceed 1; then sRGB encoding. Pixels with `L ≤ 0`
//! or NaN display black, `L = +∞` white.

use rayon::prelude::*;

use crate::display::{DisplayImage, luminance, srgb_encode_u16, to_8bit};
use crate::radiance::RadianceMap;

/// A tone-mapping operator and its parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Operator {
    /// `v = (L − L_lo)/(L_hi − L_lo)` clamped, with `L_lo`, `L_hi` the given percentiles
    /// (in %) of the luminance: the report's equation (7) with a robust range.
    Linear {
        /// Lower percentile (%), black.
        low: f64,
        /// Upper percentile (%), white.
        high: f64,
    },
    /// Histogram adjustment (Ward Larson, Rushmeier & Piatko 1997).
    Histogram(HistogramAdjustment),
}

impl Operator {
    /// Linear on the 1st and 99th percentiles.
    pub const LINEAR: Operator = Operator::Linear {
        low: 1.0,
        high: 99.0,
    };

    /// Parses `linear`, `histogram` or `histogram-naive`.
    pub fn parse(name: &str) -> Option<Operator> {
        match name {
            "linear" => Some(Operator::LINEAR),
            "histogram" => Some(Operator::Histogram(HistogramAdjustment::default())),
            "histogram-naive" => Some(Operator::Histogram(HistogramAdjustment {
                ceiling: false,
                ..HistogramAdjustment::default()
            })),
            _ => None,
        }
    }

    /// Short name for file names.
    pub fn name(&self) -> &'static str {
        match self {
            Operator::Linear { .. } => "linear",
            Operator::Histogram(h) if h.ceiling => "histogram",
            Operator::Histogram(_) => "histogram-naive",
        }
    }

    /// Renders `map` for display.
    pub fn apply(&self, map: &RadianceMap) -> DisplayImage {
        let tone = self.prepare(map);
        let mut samples = vec![0u16; map.width() as usize * map.height() as usize * 3];
        tone.develop(map, 0, &mut samples, |v| v);
        DisplayImage::new(map.width(), map.height(), samples)
    }

    /// Measures `map` (percentiles, or the histogram's curve) for rendering it a band of
    /// rows at a time ([`Tone::render_rows_8bit`]).
    pub fn prepare(&self, map: &RadianceMap) -> Tone {
        match *self {
            Operator::Linear { low, high } => {
                let (lo, hi) = percentiles(&luminances(map), low, high);
                Tone::Linear {
                    lo,
                    span: (hi - lo).max(f32::MIN_POSITIVE),
                }
            }
            Operator::Histogram(h) => Tone::Curve(CurveTable::new(&h.fit(&luminances(map)))),
        }
    }
}

/// A tone map measured on one map: the display value `v` of a luminance.
#[derive(Debug, Clone)]
pub enum Tone {
    /// `v = (L − lo)/span`, clamped to 0..=1.
    Linear {
        /// Luminance shown black.
        lo: f32,
        /// Luminance range from black to white.
        span: f32,
    },
    /// The histogram adjustment's curve, tabulated.
    Curve(CurveTable),
}

impl Tone {
    /// The display value of luminance `l > 0`.
    #[inline]
    pub fn display_value(&self, l: f32) -> f32 {
        match self {
            Tone::Linear { lo, span } => ((l - lo) / span).clamp(0.0, 1.0),
            Tone::Curve(t) => t.get(l),
        }
    }

    /// Rows `first..first + out.len()/(3·width)` of `map` into 8-bit RGB `out` (bands of
    /// rows in parallel): the unit the streaming JPEG writer pulls.
    pub fn render_rows_8bit(&self, map: &RadianceMap, first: usize, out: &mut [u8]) {
        self.develop(map, first, out, to_8bit);
    }

    fn develop<T: Send + Copy>(
        &self,
        map: &RadianceMap,
        first: usize,
        out: &mut [T],
        convert: impl Fn(u16) -> T + Sync,
    ) {
        let ch = map.channels();
        let width = map.width() as usize;
        let rows = out.len() / (3 * width);
        let input = &map.pixels()[first * width * ch..(first + rows) * width * ch];
        out.par_chunks_mut(3 * 4096)
            .zip(input.par_chunks(ch * 4096))
            .for_each(|(out, pixels)| {
                for (o, p) in out.chunks_exact_mut(3).zip(pixels.chunks_exact(ch)) {
                    let e = if ch == 3 {
                        [p[0], p[1], p[2]]
                    } else {
                        [p[0]; 3]
                    };
                    let v = keep_chromaticity(e, |l| self.display_value(l));
                    o[0] = convert(v[0]);
                    o[1] = convert(v[1]);
                    o[2] = convert(v[2]);
                }
            });
    }
}

/// Mantissa bits of the luminance kept in [`CurveTable`]'s index: buckets of 2⁻¹¹
/// relative width.
const CURVE_MANTISSA_BITS: u32 = 11;
const CURVE_SHIFT: u32 = 23 - CURVE_MANTISSA_BITS;

/// The histogram adjustment's display value tabulated over the curve's world range,
/// indexed by the top bits of the `f32` luminance (its exponent and 11 mantissa bits),
/// each entry the curve at its bucket's centre. The curve's log–log slope is at most 1
/// with the ceiling, so an entry is within `log10(1 + 2⁻¹¹)/2 = 1.06·10⁻⁴` in
/// `log10 L_d` (0.024 %) of the exact value; without the ceiling the slope, and the
/// error, can be larger (the PSNR against the direct curve is in `docs/film.md`).
/// Luminances outside the range take the end values, as the curve does.
#[derive(Debug, Clone)]
pub struct CurveTable {
    low: f32,
    high: f32,
    base: u32,
    entries: Vec<f32>,
}

impl CurveTable {
    /// Tabulates `curve`.
    pub fn new(curve: &ToneCurve) -> CurveTable {
        let (a, b) = curve.world_range();
        let low = (10f64.powf(a) as f32).max(f32::MIN_POSITIVE);
        let high = (10f64.powf(b) as f32).clamp(low, f32::MAX);
        let base = low.to_bits() >> CURVE_SHIFT;
        let top = high.to_bits() >> CURVE_SHIFT;
        let entries = (base..=top)
            .map(|i| {
                let centre = f32::from_bits((i << CURVE_SHIFT) | (1 << (CURVE_SHIFT - 1)));
                let l = if i == base {
                    low
                } else if i == top {
                    high
                } else {
                    centre
                };
                curve.display_value(l)
            })
            .collect();
        CurveTable {
            low,
            high,
            base,
            entries,
        }
    }

    /// The display value of luminance `l`.
    #[inline]
    pub fn get(&self, l: f32) -> f32 {
        let l = if l >= self.high {
            self.high
        } else if l > self.low {
            l
        } else {
            self.low
        };
        self.entries[((l.to_bits() >> CURVE_SHIFT) - self.base) as usize]
    }
}

fn luminances(map: &RadianceMap) -> Vec<f32> {
    let ch = map.channels();
    map.pixels()
        .par_chunks(ch)
        .map(|p| {
            if ch == 3 {
                luminance(p[0], p[1], p[2])
            } else {
                p[0]
            }
        })
        .collect()
}

/// The `low` and `high` percentiles (%) of the finite luminances (0 if there are none):
/// the values of rank `round(p/100·(n − 1))` among the `n` finite ones, found exactly by
/// a histogram of their top 16 bits (order-preserving for floats of either sign) and a
/// selection inside the bucket that holds the rank.
fn percentiles(lum: &[f32], low: f64, high: f64) -> (f32, f32) {
    // Order-preserving key of a float: flip all bits of negatives, the sign of the rest.
    let key = |v: f32| {
        let b = v.to_bits();
        if b >> 31 == 1 { !b } else { b | 1 << 31 }
    };
    let counts = lum
        .par_chunks(1 << 16)
        .fold(
            || vec![0u32; 1 << 16],
            |mut counts, chunk| {
                for &l in chunk.iter().filter(|l| l.is_finite()) {
                    counts[(key(l) >> 16) as usize] += 1;
                }
                counts
            },
        )
        .reduce(
            || vec![0u32; 1 << 16],
            |mut a, b| {
                a.iter_mut().zip(b).for_each(|(a, b)| *a += b);
                a
            },
        );
    let n: u64 = counts.iter().map(|&c| u64::from(c)).sum();
    if n == 0 {
        return (0.0, 0.0);
    }
    let pick = |p: f64| {
        let rank = (((p / 100.0) * (n - 1) as f64).round() as u64).min(n - 1);
        let mut below = 0u64;
        let bucket = counts
            .iter()
            .position(|&c| {
                below += u64::from(c);
                below > rank
            })
            .unwrap_or(counts.len() - 1);
        let before = below - u64::from(counts[bucket]);
        let mut inside: Vec<f32> = lum
            .par_iter()
            .copied()
            .filter(|l| l.is_finite() && (key(*l) >> 16) as usize == bucket)
            .collect();
        let i = (rank - before) as usize;
        *inside.select_nth_unstable_by(i, f32::total_cmp).1
    };
    (pick(low), pick(high))
}

/// `v·E_c/L` for display value `v = display(L)`, scaled down together if one channel
/// would pass white, sRGB-encoded: NaN and negative radiance count as 0, `L ≤ 0` is
/// black, an infinite channel white.
#[inline]
fn keep_chromaticity(e: [f32; 3], display: impl Fn(f32) -> f32) -> [u16; 3] {
    let e = e.map(|v| if v.is_nan() { 0.0 } else { v.max(0.0) });
    let l = luminance(e[0], e[1], e[2]);
    let rgb = if l == f32::INFINITY || e.iter().any(|v| v.is_infinite()) {
        [1.0; 3]
    } else if l > 0.0 {
        let v = display(l);
        let rgb = e.map(|c| v * (c / l));
        let peak = rgb[0].max(rgb[1]).max(rgb[2]);
        if peak > 1.0 {
            rgb.map(|c| c / peak)
        } else {
            rgb
        }
    } else {
        [0.0; 3]
    };
    rgb.map(srgb_encode_u16)
}

/// Histogram adjustment parameters (Ward Larson, Rushmeier & Piatko 1997, §4–5).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HistogramAdjustment {
    /// Number of bins over the scene's log10 luminance range (the paper uses 100).
    pub bins: usize,
    /// Display luminance range `L_d,max / L_d,min` (an sRGB display: about 100:1).
    pub display_range: f64,
    /// Apply the linear contrast ceiling (the full method); `false` is the naive
    /// histogram equalisation the report also shows.
    pub ceiling: bool,
}

impl Default for HistogramAdjustment {
    fn default() -> HistogramAdjustment {
        HistogramAdjustment {
            bins: 100,
            display_range: 100.0,
            ceiling: true,
        }
    }
}

/// A fitted histogram adjustment: display log luminance as a function of world log
/// luminance, `log L_d = log L_d,min + (log L_d,max − log L_d,min) · P(log L_w)`, with
/// `P` the cumulative of the (trimmed) histogram, linear within each bin.
#[derive(Debug, Clone, PartialEq)]
pub struct ToneCurve {
    /// log10 world luminance of the first bin's lower edge.
    b_min: f64,
    /// Bin width in log10 units.
    width: f64,
    /// P at each bin edge (`bins + 1` values, 0 to 1).
    cumulative: Vec<f64>,
    /// log10(L_d,max / L_d,min).
    display_log_range: f64,
    /// When the scene's range fits the display: `log L_d = log L_d,max + (b − b_max)`.
    linear: bool,
}

impl HistogramAdjustment {
    /// Fits the tone curve to the luminances (non-finite and non-positive ones ignored).
    ///
    /// With the ceiling: a contrast no greater than the scene's (`dL_d/dL_w ≤ L_d/L_w`,
    /// i.e. slope ≤ 1 in log–log) requires `f(b_i) ≤ T·Δb / (log L_d,max − log L_d,min)`
    /// for every bin count `f(b_i)`, `T` the total count. Bins over the ceiling are
    /// trimmed and the ceiling recomputed from the new total, repeatedly (the paper's
    /// iteration), until the trimmings fall below 10⁻⁶·T — tighter than the paper's
    /// 2.5 %, so the ceiling holds to a part in 10⁶. If the total falls below 2.5 % of
    /// the pixels, or the scene's range is within the display's, the curve is linear.
    pub fn fit(&self, luminances: &[f32]) -> ToneCurve {
        // Two parallel passes over the luminances (range, then counts) instead of a
        // buffer of their logarithms: 24 MP cost 190 MB and a serial pass that way.
        let log = |l: &f32| (l.is_finite() && *l > 0.0).then(|| f64::from(*l).log10());
        let (b_min, b_max, n) = luminances
            .par_iter()
            .filter_map(log)
            .fold(
                || (f64::INFINITY, f64::NEG_INFINITY, 0usize),
                |(a, b, n), x| (a.min(x), b.max(x), n + 1),
            )
            .reduce(
                || (f64::INFINITY, f64::NEG_INFINITY, 0usize),
                |(a, b, n), (c, d, m)| (a.min(c), b.max(d), n + m),
            );
        let display_log_range = self.display_range.log10();
        let bins = self.bins.max(1);
        let linear_curve = |b_min: f64, b_max: f64| ToneCurve {
            b_min,
            width: (b_max - b_min).max(1e-12),
            cumulative: vec![0.0, 1.0],
            display_log_range,
            linear: true,
        };
        if n == 0 {
            return linear_curve(0.0, 0.0);
        }
        if self.ceiling && b_max - b_min <= display_log_range {
            return linear_curve(b_min, b_max);
        }
        let width = ((b_max - b_min) / bins as f64).max(1e-12);
        let mut counts = luminances
            .par_iter()
            .filter_map(log)
            .fold(
                || vec![0f64; bins],
                |mut counts, x| {
                    counts[(((x - b_min) / width) as usize).min(bins - 1)] += 1.0;
                    counts
                },
            )
            .reduce(
                || vec![0f64; bins],
                |mut a, b| {
                    a.iter_mut().zip(b).for_each(|(a, b)| *a += b);
                    a
                },
            );
        if self.ceiling {
            let pixels = n as f64;
            let mut converged = false;
            for _ in 0..10_000 {
                let total: f64 = counts.iter().sum();
                if total < 0.025 * pixels {
                    break;
                }
                let ceiling = total * width / display_log_range;
                let trimmed: f64 = counts.iter().map(|&f| (f - ceiling).max(0.0)).sum();
                for f in &mut counts {
                    *f = f.min(ceiling);
                }
                if trimmed <= 1e-6 * total {
                    converged = true;
                    break;
                }
            }
            if !converged {
                return linear_curve(b_min, b_max);
            }
        }
        let total: f64 = counts.iter().sum();
        let mut cumulative = Vec::with_capacity(bins + 1);
        let mut run = 0.0;
        cumulative.push(0.0);
        for f in &counts {
            run += f;
            cumulative.push(run / total);
        }
        ToneCurve {
            b_min,
            width,
            cumulative,
            display_log_range,
            linear: false,
        }
    }
}

impl ToneCurve {
    /// `log10 (L_d / L_d,max)` for world log10 luminance `b` (0 at the top, down to
    /// `−log10(display range)`).
    pub fn display_log(&self, b: f64) -> f64 {
        let bins = self.cumulative.len() - 1;
        let b_max = self.b_min + self.width * bins as f64;
        if self.linear {
            return (b.min(b_max) - b_max).max(-self.display_log_range);
        }
        let x = ((b - self.b_min) / self.width).clamp(0.0, bins as f64);
        let i = (x as usize).min(bins - 1);
        let p = self.cumulative[i] + (x - i as f64) * (self.cumulative[i + 1] - self.cumulative[i]);
        -self.display_log_range * (1.0 - p)
    }

    /// Display value `v = (L_d − L_d,min) / (L_d,max − L_d,min)` for world luminance `l`:
    /// the display's own black (`L_d,min`) is drive value 0.
    pub fn display_value(&self, l: f32) -> f32 {
        let rel = (self.display_log(f64::from(l).log10()) * std::f64::consts::LN_10).exp();
        let floor = self.display_floor();
        (((rel - floor) / (1.0 - floor)).clamp(0.0, 1.0)) as f32
    }

    /// `L_d,min / L_d,max`.
    fn display_floor(&self) -> f64 {
        (-self.display_log_range * std::f64::consts::LN_10).exp()
    }

    /// The steepest display/world slope `d log L_d / d log L_w` over the curve's range,
    /// sampled at `samples` even steps: at most 1 when the contrast ceiling holds.
    pub fn max_log_slope(&self, samples: usize) -> f64 {
        let (a, b) = self.world_range();
        let n = samples.max(1);
        let step = (b - a) / n as f64;
        (0..n)
            .map(|i| {
                let x = a + i as f64 * step;
                (self.display_log(x + step) - self.display_log(x)) / step
            })
            .fold(0.0, f64::max)
    }

    /// The world log10 luminance range the curve spans.
    pub fn world_range(&self) -> (f64, f64) {
        let bins = self.cumulative.len() - 1;
        (self.b_min, self.b_min + self.width * bins as f64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A scene with a big cluster of similar luminances (a wall) and a sparse long tail:
    /// the naive equalisation spends most of the display range on the cluster.
    fn clustered() -> Vec<f32> {
        let mut l = Vec::new();
        for i in 0..20_000 {
            l.push(0.18 * (1.0 + 0.05 * ((i % 100) as f32 / 100.0)));
        }
        for i in 0..2_000 {
            l.push(10f32.powf(-4.0 + 8.0 * i as f32 / 2000.0));
        }
        l
    }

    fn max_slope(curve: &ToneCurve) -> f64 {
        curve.max_log_slope(20_000)
    }

    #[test]
    fn ceiling_holds_and_naive_breaks_it() {
        let l = clustered();
        let full = HistogramAdjustment::default().fit(&l);
        assert!(max_slope(&full) <= 1.0 + 1e-5, "slope {}", max_slope(&full));
        let naive = HistogramAdjustment {
            ceiling: false,
            ..Default::default()
        }
        .fit(&l);
        assert!(max_slope(&naive) > 5.0, "naive slope {}", max_slope(&naive));
    }

    #[test]
    fn narrow_scene_maps_linearly() {
        let l: Vec<f32> = (0..1000).map(|i| 1.0 + i as f32 / 100.0).collect();
        let curve = HistogramAdjustment::default().fit(&l);
        let (a, b) = curve.world_range();
        let d = curve.display_log(b) - curve.display_log(a);
        assert!((d - (b - a)).abs() < 1e-9);
    }

    #[test]
    fn mapping_is_monotone_and_keeps_chromaticity() {
        // 64×64 grey-to-colour gradient over six decades; pixel 0 is black.
        let mut pixels = Vec::new();
        for i in 0..64 * 64 {
            let l = if i == 0 {
                0.0
            } else {
                10f32.powf(-3.0 + 6.0 * i as f32 / 4096.0)
            };
            pixels.extend_from_slice(&[l * 1.6, l * 0.8, l * 0.3]);
        }
        let map = RadianceMap::new(64, 64, 3, pixels).unwrap();
        for op in [Operator::LINEAR, Operator::parse("histogram").unwrap()] {
            let img = op.apply(&map);
            let s = img.samples();
            let lum: Vec<f32> = s
                .chunks(3)
                .map(|p| {
                    let lin = p
                        .iter()
                        .map(|&v| {
                            let v = f32::from(v) / 65535.0;
                            if v <= 0.04045 {
                                v / 12.92
                            } else {
                                ((v + 0.055) / 1.055).powf(2.4)
                            }
                        })
                        .collect::<Vec<_>>();
                    luminance(lin[0], lin[1], lin[2])
                })
                .collect();
            // Monotone up to the sRGB table's stated 1.1e-4 relative error (clipped pixels
            // of one chromaticity can straddle a table bucket).
            let bad = lum.windows(2).position(|w| w[1] < w[0] * (1.0 - 2.5e-4));
            assert!(
                bad.is_none(),
                "{op:?}: at {bad:?}: {:?} {:?}",
                &lum[bad.unwrap_or(0)..bad.unwrap_or(0) + 2],
                &s[bad.unwrap_or(0) * 3..bad.unwrap_or(0) * 3 + 6]
            );
            assert_eq!(&s[..3], &[0, 0, 0]);
            // A mid-tone pixel: red stays the largest channel, blue the smallest.
            let p = &s[2000 * 3..2000 * 3 + 3];
            assert!(p[0] > p[1] && p[1] > p[2], "{op:?}: {p:?}");
        }
    }
}
