//! Tone-mapping operators: linear range rescaling and Ward Larson's histogram adjustment.
//!
//! Both map luminance `L = 0.2126 R + 0.7152 G + 0.0722 B` (Rec. 709, linear) to a
//! display value `v ∈ [0, 1]` and keep chromaticity: each channel becomes `v · E_c / L`,
//! scaled down together if one would exceed 1; then sRGB encoding. Pixels with `L ≤ 0`
//! or NaN display black, `L = +∞` white.

use rayon::prelude::*;

use crate::display::{DisplayImage, luminance, srgb_encode_u8, srgb_encode_u16};
use crate::radiance::{self, RadianceMap, RadianceSource};

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
    pub fn apply(&self, map: &dyn RadianceSource) -> DisplayImage {
        let tone = self.prepare(map);
        let mut samples = vec![0u16; map.width() as usize * map.height() as usize * 3];
        tone.develop(map, 0, &mut samples, srgb_encode_u16);
        DisplayImage::new(map.width(), map.height(), samples)
    }

    /// Measures `map` (percentiles, or the histogram's curve) for rendering it a band of
    /// rows at a time ([`Tone::render_rows_8bit`]), from one streamed pass over the map
    /// ([`LuminanceHistogram`]): no luminance buffer.
    pub fn prepare(&self, map: &dyn RadianceSource) -> Tone {
        let histogram = LuminanceHistogram::of_map(map);
        match *self {
            Operator::Linear { low, high } => {
                Tone::linear(histogram.percentile(low), histogram.percentile(high))
            }
            Operator::Histogram(h) => Tone::Curve(CurveTable::new(&h.fit_histogram(&histogram))),
        }
    }

    /// [`Operator::prepare`] the direct way, the reference its accuracy is stated
    /// against: a buffer of every luminance, exact percentiles (ranks found by
    /// selection) and the histogram adjustment binned by each pixel's `f64` `log10`.
    pub fn prepare_exact(&self, map: &RadianceMap) -> Tone {
        let lum = luminances(map);
        match *self {
            Operator::Linear { low, high } => {
                let finite: Vec<f32> = lum.iter().copied().filter(|l| l.is_finite()).collect();
                Tone::linear(
                    exact_percentile(&finite, low),
                    exact_percentile(&finite, high),
                )
            }
            Operator::Histogram(h) => Tone::Curve(CurveTable::new(&h.fit_exact(&lum))),
        }
    }
}

/// A tone map measured on one map: the display value `v` of a luminance.
#[derive(Debug, Clone)]
pub enum Tone {
    /// `v = (L − lo)·scale`, clamped to 0..=1.
    Linear {
        /// Luminance shown black.
        lo: f32,
        /// `1/(L_white − lo)`, per unit luminance.
        scale: f32,
    },
    /// The histogram adjustment's curve, tabulated.
    Curve(CurveTable),
}

impl Tone {
    /// The linear map from `lo` (black) to `hi` (white); a span under the smallest normal
    /// float counts as that.
    fn linear(lo: f32, hi: f32) -> Tone {
        Tone::Linear {
            lo,
            scale: 1.0 / (hi - lo).max(f32::MIN_POSITIVE),
        }
    }

    /// The display value of luminance `l > 0`.
    #[inline]
    pub fn display_value(&self, l: f32) -> f32 {
        match self {
            &Tone::Linear { lo, scale } => linear_display(l, lo, scale),
            Tone::Curve(t) => t.get(l),
        }
    }

    /// Rows `first..first + out.len()/(3·width)` of `map` into 8-bit RGB `out` (bands of
    /// rows in parallel): the unit the streaming JPEG writer pulls.
    pub fn render_rows_8bit(&self, map: &dyn RadianceSource, first: usize, out: &mut [u8]) {
        self.develop(map, first, out, srgb_encode_u8);
    }

    /// Develops rows into `out` through `encode`, with the operator chosen once (not per
    /// pixel).
    fn develop<T: Send + Copy>(
        &self,
        map: &dyn RadianceSource,
        first: usize,
        out: &mut [T],
        encode: impl Fn(f32) -> T + Sync,
    ) {
        match self {
            &Tone::Linear { lo, scale } => {
                develop_rows(map, first, out, encode, |l| linear_display(l, lo, scale))
            }
            Tone::Curve(t) => develop_rows(map, first, out, encode, |l| t.get(l)),
        }
    }
}

/// `(L − lo)·scale` clamped to 0..=1: [`Tone::Linear`]'s display value.
#[inline]
fn linear_display(l: f32, lo: f32, scale: f32) -> f32 {
    ((l - lo) * scale).clamp(0.0, 1.0)
}

/// Rows `first..` of `map` into `out` (3 samples a pixel), each pixel's luminance through
/// `display` ([`keep_chromaticity`]) and each channel through `encode`, bands of rows in
/// parallel.
fn develop_rows<T: Send + Copy>(
    map: &dyn RadianceSource,
    first: usize,
    out: &mut [T],
    encode: impl Fn(f32) -> T + Sync,
    display: impl Fn(f32) -> f32 + Sync,
) {
    const PIXELS: usize = 4096;
    let ch = map.channels();
    let first = first * map.width() as usize;
    out.par_chunks_mut(3 * PIXELS)
        .enumerate()
        .for_each(|(part, out)| {
            let count = out.len() / 3;
            radiance::with_pixels(map, first + part * PIXELS, count, |pixels| {
                for (o, p) in out.chunks_exact_mut(3).zip(pixels.chunks_exact(ch)) {
                    let e = if ch == 3 {
                        [p[0], p[1], p[2]]
                    } else {
                        [p[0]; 3]
                    };
                    let v = keep_chromaticity(e, &display);
                    o[0] = encode(v[0]);
                    o[1] = encode(v[1]);
                    o[2] = encode(v[2]);
                }
            })
        });
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

/// Bits of an order-preserving luminance key dropped in a [`LuminanceHistogram`] bucket:
/// the key's top 20 bits (sign, exponent, 11 mantissa bits) index it, so a bucket spans
/// a relative width of 2⁻¹¹ (`log10` width 2.1·10⁻⁴) of positive luminances.
const KEY_SHIFT: u32 = 12;

/// Order-preserving key of a float: all bits of negatives flipped, the sign of the rest.
#[inline]
fn key(v: f32) -> u32 {
    let b = v.to_bits();
    if b >> 31 == 1 { !b } else { b | 1 << 31 }
}

/// The float of a key ([`key`]'s inverse).
fn unkey(k: u32) -> f32 {
    f32::from_bits(if k >> 31 == 1 { k & !(1 << 31) } else { !k })
}

/// Luminances a tone map measures at least ([`LuminanceHistogram::of_map`]).
const SAMPLED_LUMINANCES: usize = 4_000_000;

/// A histogram of a map's finite luminances in 2²⁰ buckets of their `f32` bits (2⁻¹¹
/// relative width each), with their exact extremes: what both tone maps measure, built
/// in one streamed pass (no luminance buffer; `4·2²⁰` bytes per part being counted).
#[derive(Debug, Clone)]
pub struct LuminanceHistogram {
    counts: Vec<u32>,
    /// Finite luminances counted.
    finite: u64,
    /// Their least and greatest.
    range: (f32, f32),
    /// Luminances `> 0` (finite) and their least and greatest.
    positive: u64,
    positive_range: (f32, f32),
}

impl LuminanceHistogram {
    fn empty() -> LuminanceHistogram {
        LuminanceHistogram {
            counts: vec![0; 1 << (32 - KEY_SHIFT)],
            finite: 0,
            range: (f32::INFINITY, f32::NEG_INFINITY),
            positive: 0,
            positive_range: (f32::INFINITY, f32::NEG_INFINITY),
        }
    }

    /// Counts one luminance.
    #[inline]
    fn add(&mut self, l: f32) {
        if !l.is_finite() {
            return;
        }
        // Zero counts as −0, below every positive luminance's bucket.
        let k = key(if l == 0.0 { -0.0 } else { l });
        self.counts[(k >> KEY_SHIFT) as usize] += 1;
        self.finite += 1;
        self.range = (self.range.0.min(l), self.range.1.max(l));
        if l > 0.0 {
            self.positive += 1;
            self.positive_range = (self.positive_range.0.min(l), self.positive_range.1.max(l));
        }
    }

    fn merge(mut self, other: LuminanceHistogram) -> LuminanceHistogram {
        self.counts
            .iter_mut()
            .zip(&other.counts)
            .for_each(|(a, b)| *a += b);
        self.finite += other.finite;
        self.range = (
            self.range.0.min(other.range.0),
            self.range.1.max(other.range.1),
        );
        self.positive += other.positive;
        self.positive_range = (
            self.positive_range.0.min(other.positive_range.0),
            self.positive_range.1.max(other.positive_range.1),
        );
        self
    }

    /// The histogram of these luminances.
    pub fn of(luminances: &[f32]) -> LuminanceHistogram {
        let mut h = LuminanceHistogram::empty();
        luminances.iter().for_each(|&l| h.add(l));
        h
    }

    /// The histogram of `map`'s luminances `L = 0.2126 R + 0.7152 G + 0.0722 B` (the
    /// sample itself for one channel) over every `s`-th row, `s = max(1, ⌊P / 4·10⁶⌋)`
    /// for `P` pixels: at least four million luminances (every row up to 8 MP, every 6th
    /// of a 24 MP map), counted in parallel by contiguous groups of rows. A percentile's
    /// rank error from the sample is about `√(p(1−p)/n)`, under 0.03 % of the pixels;
    /// the rows not read may hold luminances beyond the sample's extremes, which the
    /// maps clamp as they clamp every luminance outside their range.
    pub(crate) fn of_map(map: &dyn RadianceSource) -> LuminanceHistogram {
        let ch = map.channels();
        let width = map.width() as usize;
        let height = map.height() as usize;
        let stride = (width * height / SAMPLED_LUMINANCES).max(1);
        let rows: Vec<usize> = (0..height).step_by(stride).collect();
        let parts = (4 * rayon::current_num_threads()).clamp(1, 32);
        let per_part = rows.len().div_ceil(parts).max(1);
        rows.par_chunks(per_part)
            .map(|group| {
                let mut h = LuminanceHistogram::empty();
                for &y in group {
                    radiance::with_pixels(map, y * width, width, |row| {
                        if ch == 3 {
                            for p in row.chunks_exact(3) {
                                h.add(luminance(p[0], p[1], p[2]));
                            }
                        } else {
                            row.iter().for_each(|&l| h.add(l));
                        }
                    })
                }
                h
            })
            .reduce_with(LuminanceHistogram::merge)
            .unwrap_or_else(LuminanceHistogram::empty)
    }

    /// The `p`-th percentile (%) of the finite luminances (0 if there are none): the
    /// value of rank `r = round(p/100·(n − 1))`, located in its bucket and placed inside
    /// it by rank, linearly in the float's bits (for positive luminances, in `log L`
    /// within 2⁻¹¹ relative), then held to the exact extremes. Within one bucket of the
    /// exact order statistic: at most 2⁻¹¹ relative for positive luminances.
    pub fn percentile(&self, p: f64) -> f32 {
        let n = self.finite;
        if n == 0 {
            return 0.0;
        }
        let rank = ((p / 100.0 * (n - 1) as f64).round().max(0.0) as u64).min(n - 1);
        let mut below = 0u64;
        for (bucket, &c) in self.counts.iter().enumerate() {
            let c = u64::from(c);
            if below + c > rank {
                let inside = (rank - below) as f64 + 0.5;
                let offset = (inside / c as f64 * f64::from(1u32 << KEY_SHIFT)) as u32;
                let k = ((bucket as u32) << KEY_SHIFT) | offset.min((1 << KEY_SHIFT) - 1);
                return unkey(k).clamp(self.range.0, self.range.1);
            }
            below += c;
        }
        self.range.1
    }

    /// The positive luminances' counts as `(log10 lower edge, log10 upper edge, count)`
    /// per non-empty bucket, edges held to the exact extremes.
    fn positive_buckets(&self) -> impl Iterator<Item = (f64, f64, f64)> + '_ {
        let (least, greatest) = self.positive_range;
        let (first, last) = if self.positive == 0 {
            (1, 0)
        } else {
            (
                (key(least) >> KEY_SHIFT) as usize,
                (key(greatest) >> KEY_SHIFT) as usize,
            )
        };
        let (least, greatest) = (f64::from(least), f64::from(greatest));
        (first..=last).filter_map(move |b| {
            let c = self.counts.get(b).copied().unwrap_or(0);
            (c > 0).then(|| {
                let lo = f64::from(unkey((b as u32) << KEY_SHIFT)).max(least);
                let hi = f64::from(unkey(((b as u32) << KEY_SHIFT) | ((1 << KEY_SHIFT) - 1)))
                    .min(greatest);
                (lo.log10(), hi.max(lo).log10(), f64::from(c))
            })
        })
    }
}

fn exact_percentile(finite: &[f32], p: f64) -> f32 {
    if finite.is_empty() {
        return 0.0;
    }
    let n = finite.len();
    let rank = ((p / 100.0 * (n - 1) as f64).round().max(0.0) as usize).min(n - 1);
    let mut values = finite.to_vec();
    *values.select_nth_unstable_by(rank, f32::total_cmp).1
}

/// `E_c·(v/L)` for display value `v = display(L)` (one division a pixel), scaled down
/// together if one channel would pass white (to `E_c/max E`): linear display RGB in
/// `[0, 1]` for the sRGB encoder. NaN and negative radiance count as 0, `L ≤ 0` is black,
/// an infinite channel white.
#[inline]
fn keep_chromaticity(e: [f32; 3], display: impl Fn(f32) -> f32) -> [f32; 3] {
    // `max` takes the other operand for NaN: NaN and negative samples read 0.
    let (r, g, b) = (e[0].max(0.0), e[1].max(0.0), e[2].max(0.0));
    let l = luminance(r, g, b);
    let (r, g, b) = if l == f32::INFINITY || r.max(g).max(b) == f32::INFINITY {
        (1.0, 1.0, 1.0)
    } else if l > 0.0 {
        let k = display(l) / l;
        let peak = r.max(g).max(b);
        if peak * k > 1.0 {
            // Clipped: the brightest channel white, whatever `v`.
            (r / peak, g / peak, b / peak)
        } else {
            (r * k, g * k, b * k)
        }
    } else {
        (0.0, 0.0, 0.0)
    };
    [r, g, b]
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
    /// Fits the tone curve to the luminances (non-finite and non-positive ones ignored),
    /// through their [`LuminanceHistogram`] ([`HistogramAdjustment::fit_histogram`]).
    pub fn fit(&self, luminances: &[f32]) -> ToneCurve {
        self.fit_histogram(&LuminanceHistogram::of(luminances))
    }

    /// Fits the tone curve to a luminance histogram. The scene's range `b_min..b_max` is
    /// exact (`log10` of the least and greatest positive luminance); each bucket's count
    /// is spread over the bins its `log10` span overlaps, in proportion, so a bin's count
    /// differs from the direct one only by the pixels of the one bucket (2.1·10⁻⁴ wide
    /// in `log10 L`) that straddles each of its edges.
    pub(crate) fn fit_histogram(&self, histogram: &LuminanceHistogram) -> ToneCurve {
        let n = histogram.positive as usize;
        let (least, greatest) = histogram.positive_range;
        let (b_min, b_max) = (f64::from(least).log10(), f64::from(greatest).log10());
        self.fit_counts(n, b_min, b_max, |bins, width| {
            let mut counts = vec![0f64; bins];
            let last = bins as f64;
            for (lo, hi, c) in histogram.positive_buckets() {
                let x0 = ((lo - b_min) / width).clamp(0.0, last);
                let x1 = ((hi - b_min) / width).clamp(0.0, last);
                let first = (x0 as usize).min(bins - 1);
                if x1 - x0 < 1e-12 || x1 <= (first + 1) as f64 {
                    counts[first] += c;
                    continue;
                }
                let per = c / (x1 - x0);
                let mut at = x0;
                for (i, count) in counts.iter_mut().enumerate().skip(first) {
                    let edge = ((i + 1) as f64).min(x1);
                    *count += per * (edge - at);
                    at = edge;
                    if at >= x1 {
                        break;
                    }
                }
            }
            counts
        })
    }

    /// [`HistogramAdjustment::fit`] the direct way, each luminance's bin from its `f64`
    /// `log10`: the reference for [`HistogramAdjustment::fit_histogram`].
    fn fit_exact(&self, luminances: &[f32]) -> ToneCurve {
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
        self.fit_counts(n, b_min, b_max, |bins, width| {
            luminances
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
                )
        })
    }

    /// The curve of `n` positive luminances spanning `b_min..b_max` (`log10`), whose
    /// counts per bin `count(bins, width)` gives.
    ///
    /// With the ceiling: a contrast no greater than the scene's (`dL_d/dL_w ≤ L_d/L_w`,
    /// i.e. slope ≤ 1 in log–log) requires `f(b_i) ≤ T·Δb / (log L_d,max − log L_d,min)`
    /// for every bin count `f(b_i)`, `T` the total count. Bins over the ceiling are
    /// trimmed and the ceiling recomputed from the new total, repeatedly (the paper's
    /// iteration), until the trimmings fall below 10⁻⁶·T — tighter than the paper's
    /// 2.5 %, so the ceiling holds to a part in 10⁶. If the total falls below 2.5 % of
    /// the pixels, or the scene's range is within the display's, the curve is linear.
    fn fit_counts(
        &self,
        n: usize,
        b_min: f64,
        b_max: f64,
        count: impl FnOnce(usize, f64) -> Vec<f64>,
    ) -> ToneCurve {
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
        let mut counts = count(bins, width);
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
    fn display_log(&self, b: f64) -> f64 {
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
    fn world_range(&self) -> (f64, f64) {
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

    /// A deterministic spread of luminances over eight decades, with zeros, negatives
    /// and non-finite values mixed in.
    fn spread(n: usize) -> Vec<f32> {
        (0..n)
            .map(|i| {
                let u = ((i as u64 * 2_654_435_761) % 1_000_003) as f32 / 1_000_003.0;
                match i % 97 {
                    0 => 0.0,
                    1 => -u,
                    2 => f32::NAN,
                    3 => f32::INFINITY,
                    _ => 10f32.powf(-4.0 + 8.0 * u * u),
                }
            })
            .collect()
    }

    #[test]
    fn percentiles_from_the_histogram_are_within_a_bucket() {
        for lum in [
            spread(100_003),
            clustered(),
            vec![0.18; 1000],
            vec![-2.0, 0.0, 3.0],
        ] {
            let histogram = LuminanceHistogram::of(&lum);
            let finite: Vec<f32> = lum.iter().copied().filter(|l| l.is_finite()).collect();
            for p in [0.0, 0.5, 1.0, 25.0, 50.0, 99.0, 99.9, 100.0] {
                let (ours, exact) = (histogram.percentile(p), exact_percentile(&finite, p));
                let tolerance = exact.abs() * 2f32.powi(-11) + f32::MIN_POSITIVE;
                assert!(
                    (ours - exact).abs() <= tolerance,
                    "p{p}: {ours} against {exact} (n = {})",
                    lum.len()
                );
            }
        }
        assert_eq!(LuminanceHistogram::of(&[f32::NAN]).percentile(50.0), 0.0);
        assert_eq!(LuminanceHistogram::of(&[]).percentile(1.0), 0.0);
    }

    #[test]
    fn streamed_fit_follows_the_direct_fit() {
        for adjustment in [
            HistogramAdjustment::default(),
            HistogramAdjustment {
                ceiling: false,
                ..Default::default()
            },
        ] {
            for lum in [spread(200_000), clustered()] {
                let (ours, exact) = (adjustment.fit(&lum), adjustment.fit_exact(&lum));
                assert_eq!(ours.world_range(), exact.world_range());
                let worst = ours
                    .cumulative
                    .iter()
                    .zip(&exact.cumulative)
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0, f64::max);
                assert!(worst < 2e-3, "{adjustment:?}: cumulative off by {worst}");
            }
        }
        let none = HistogramAdjustment::default().fit(&[0.0, -1.0, f32::NAN]);
        assert!(none.linear);
    }

    /// The 8-bit rendering of a synthetic scene prepared from the streamed histogram
    /// against the direct measurement: PSNR over all samples.
    #[test]
    fn streamed_rendering_matches_the_direct_one() {
        let map = crate::synthetic::scene(384, 256, 7);
        for name in ["linear", "histogram", "histogram-naive"] {
            let op = Operator::parse(name).expect("known operator");
            let render = |tone: Tone| {
                let mut rgb = vec![0u8; 384 * 256 * 3];
                tone.render_rows_8bit(&map, 0, &mut rgb);
                rgb
            };
            let (ours, exact) = (render(op.prepare(&map)), render(op.prepare_exact(&map)));
            let mse = ours
                .iter()
                .zip(&exact)
                .map(|(&a, &b)| (f64::from(a) - f64::from(b)).powi(2))
                .sum::<f64>()
                / ours.len() as f64;
            let psnr = 10.0 * (255.0f64.powi(2) / mse.max(1e-12)).log10();
            eprintln!("{name}: PSNR {psnr:.1} dB against the direct measurement");
            assert!(psnr >= 45.0, "{name}: PSNR {psnr:.1} dB");
        }
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
