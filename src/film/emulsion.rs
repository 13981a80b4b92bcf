//! A stock set up for one exposure: the scene key, the per-layer exposure tables and the
//! per-pixel emulsion of radiance into display values.

use std::str::FromStr;

use rayon::prelude::*;

use super::grain::Grain;
use super::print::PrintSetup;
use super::spectral::PrintingDensity;
use super::{Curve, FilmError, Kind, Options, Stock, optics};
use crate::display::{Depth, DisplayImage, luminance, srgb_encode, srgb_encode_u16, to_8bit};
use crate::radiance::{self, CodePairs, RadianceMap, RadianceSource};

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

/// A colour mode's name that is none of [`ColourMode`]'s.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("colour mode {0:?}: expected per-layer, luminance or neutral")]
pub struct UnknownColourMode(pub String);

impl FromStr for ColourMode {
    type Err = UnknownColourMode;

    fn from_str(s: &str) -> Result<ColourMode, UnknownColourMode> {
        match s {
            "per-layer" | "layers" => Ok(ColourMode::PerLayer),
            "luminance" => Ok(ColourMode::Luminance),
            "neutral" | "neutral-grey" => Ok(ColourMode::NeutralGrey),
            _ => Err(UnknownColourMode(s.to_string())),
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
pub fn scene_key(map: &(impl RadianceSource + ?Sized), key: Key) -> f64 {
    if let Key::Grey(g) = key {
        return g;
    }
    let ch = map.channels();
    let count = map.width() as usize * map.height() as usize;
    let stride = count.div_ceil(1 << 20).max(1);
    let samples = count.div_ceil(stride);
    // Fixed groups of samples, their sums added in order: the same key, to the last bit,
    // however the threads share the work.
    let groups: Vec<(f64, usize)> = (0..samples.div_ceil(SAMPLES_PER_GROUP))
        .into_par_iter()
        .map(|g| {
            let mut p = [0f32; 3];
            let (mut sum, mut n) = (0.0, 0usize);
            for j in g * SAMPLES_PER_GROUP..((g + 1) * SAMPLES_PER_GROUP).min(samples) {
                map.pixels_into(j * stride, &mut p[..ch]);
                let l = if ch == 3 {
                    luminance(p[0], p[1], p[2])
                } else {
                    p[0]
                };
                if l.is_finite() && l > 0.0 {
                    sum += f64::from(l).ln();
                    n += 1;
                }
            }
            (sum, n)
        })
        .collect();
    let (sum, n) = groups.iter().fold((0.0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
    if n == 0 { 1.0 } else { (sum / n as f64).exp() }
}

/// Samples of the key's mean summed in one task.
const SAMPLES_PER_GROUP: usize = 4096;

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

    /// The same buckets, each entry through `f`.
    pub fn map<U>(&self, f: impl Fn(T) -> U) -> ExposureTable<U> {
        ExposureTable {
            low: self.low,
            high: self.high,
            base: self.base,
            entries: self.entries.iter().map(|&v| f(v)).collect(),
        }
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

/// Density to display value of one layer, on a uniform grid of [`DENSITY_STEP`] D:
/// used when grain moves a pixel's density off its curve.
#[derive(Debug, Clone)]
struct DensityTable {
    low: f32,
    /// The last entry's index, as a float (the clamp of [`DensityTable::at`]).
    top: f32,
    /// sRGB-encoded, 0..=65535.
    display: Vec<u16>,
    /// The same, 8-bit ([`to_8bit`] of `display`).
    display8: Vec<u8>,
    /// Linear light.
    linear: Vec<f32>,
}

/// Grid step of [`DensityTable`], D: the display error is at most half a step times the
/// steepest `|dlog10 R/dD|` (1 for a slide, the paper's gradient for a print).
const DENSITY_STEP: f32 = 1.0 / 2048.0;

impl DensityTable {
    fn new(low: f64, high: f64, linear: impl Fn(f64) -> f64) -> DensityTable {
        let n = ((high - low) / f64::from(DENSITY_STEP)).ceil() as usize + 1;
        let linear: Vec<f32> = (0..n)
            .map(|i| linear(low + i as f64 * f64::from(DENSITY_STEP)) as f32)
            .collect();
        let display: Vec<u16> = linear
            .iter()
            .map(|&t| (srgb_encode(t) * 65535.0).round() as u16)
            .collect();
        assert!(display.len() < 1 << 22, "a density table spans a few D");
        DensityTable {
            low: low as f32,
            top: (display.len() - 1) as f32,
            display8: display.iter().map(|&v| to_8bit(v)).collect(),
            display,
            linear,
        }
    }

    /// Density `d` in the table's units, `(d − low)/step`: entry `i` is at `i`.
    fn units(&self, d: f32) -> f32 {
        (d - self.low) * (1.0 / DENSITY_STEP)
    }

    /// The entry nearest `u` table units ([`DensityTable::units`]), clamped to the table
    /// (NaN to the first entry). Rounding is by adding 2²³: the sum's mantissa is then
    /// the rounded integer (ties to even), without a float-to-integer conversion and its
    /// saturation checks.
    #[inline]
    fn at(&self, u: f32) -> usize {
        // `max` takes the number of a NaN pair.
        let u = u.max(0.0).min(self.top);
        ((u + 8_388_608.0).to_bits() & 0x7f_ffff) as usize
    }
}

/// What grain needs: the layers' densities with their grain's σ, and display values by
/// density.
#[derive(Debug, Clone)]
struct Grained {
    grain: Grain,
    /// `[u(D), σ_px(D)/step]` by exposure, in units of [`DensityTable`]'s grid: the density
    /// ([`DensityTable::units`]) and the grain's standard deviation there, both at the
    /// bucket's centre (σ's error is `|dσ/dD|` times the density's), so that a grained
    /// sample is the entry at `u + (σ/step)·n`.
    density: [ExposureTable<[f32; 2]>; 3],
    from_density: [DensityTable; 3],
}

/// A negative's print as set for one map: the paper and knobs, the Status M → printing
/// density conversion, and the printer light that prints the key at mid grey.
struct Printer {
    setup: PrintSetup,
    printing: PrintingDensity,
    light: [f64; 3],
}

impl Printer {
    /// The printer for `stock` exposed at `scale` (lux·s per unit radiance) on a map whose
    /// key is `key`: `L_c` from the printing densities of the key ([`super::print`]).
    fn new(
        stock: &Stock,
        options: &Options,
        scale: &[f32; 3],
        key: f64,
    ) -> Result<Printer, FilmError> {
        let setup = options.print_setup()?;
        let printing = PrintingDensity::new(stock, &setup.paper)?;
        let key_density = [0, 1, 2].map(|c| {
            let d = stock.layer(c).density((f64::from(scale[c]) * key).log10());
            printing.of(c, d)
        });
        let light = setup.printer_light(key_density);
        Ok(Printer {
            setup,
            printing,
            light,
        })
    }
}

/// Everything the per-pixel loop needs for one stock, exposure, colour mode and options.
#[derive(Debug, Clone)]
pub struct Emulsion {
    /// `H = scale[c] · E` per layer (lux·s per unit radiance): `t·k`, times the neutral
    /// shift of [`ColourMode::NeutralGrey`].
    pub scale: [f32; 3],
    mode: ColourMode,
    /// Per-layer display value (sRGB-encoded, 0..=65535).
    display: [ExposureTable<u16>; 3],
    /// The same, 8-bit ([`to_8bit`] of `display`), for 8-bit development.
    display8: [ExposureTable<u8>; 3],
    /// Green-layer linear light for the luminance mode.
    transmittance: ExposureTable<f32>,
    grained: Option<Grained>,
    /// MTF per layer and the pixel's size at film scale, mm.
    kernels: Option<([optics::MtfFit; 3], f64)>,
    /// Halation strength and σ in pixels.
    halation: Option<(f32, f64)>,
    /// The printer light per channel (log10), for a negative.
    printer_light: Option<[f64; 3]>,
    /// A negative's Status M → printing density conversion on its paper.
    printing_density: Option<PrintingDensity>,
}

impl Emulsion {
    /// Prepares a stock for a map whose key (relative radiance) is `key`, without
    /// options (a negative printed with the default setup).
    pub fn new(
        stock: &Stock,
        exposure: f64,
        key: f64,
        mode: ColourMode,
    ) -> Result<Emulsion, FilmError> {
        Emulsion::with_options(stock, exposure, key, mode, &Options::default(), (1, 1))
    }

    /// Prepares a stock with `options` for a map of `size` (width, height) pixels whose
    /// key is `key`.
    ///
    /// `k = (8/S) / key`; the layers' scale is `t·k`; in the neutral-grey mode layer `c`
    /// is further multiplied by `10^s_c`, where `s_c` makes
    /// `D_c(log H_key + s_c) − D_min,c = D_g(log H_key) − D_min,g`. A negative's printer
    /// is set on the key's densities ([`super::print`]). The pixel's size at film scale is
    /// `p = format_mm / max(width, height)`.
    pub fn with_options(
        stock: &Stock,
        exposure: f64,
        key: f64,
        mode: ColourMode,
        options: &Options,
        size: (u32, u32),
    ) -> Result<Emulsion, FilmError> {
        let scale = layer_scales(stock, exposure, key, mode);
        let print = match stock.kind {
            Kind::Reversal => None,
            Kind::Negative => Some(Printer::new(stock, options, &scale, key)?),
        };
        // Linear display light of Status A/M density `d` in layer `c`: the slide's
        // transmittance or the print's reflectance, over the base / paper white.
        let linear = |c: usize, d: f64| -> f64 {
            match &print {
                Some(p) => p.setup.reflectance(c, p.light[c], p.printing.of(c, d)),
                None => 10f64.powf(-(d - stock.layer(c).d_min())),
            }
        };
        let printer_light = print.as_ref().map(|p| p.light);
        let printing_density = print.as_ref().map(|p| p.printing.clone());
        let display = [0, 1, 2].map(|c| {
            ExposureTable::new(stock.layer(c), |d| {
                (srgb_encode(linear(c, d) as f32) * 65535.0).round() as u16
            })
        });
        let display8 = [0, 1, 2].map(|c| display[c].map(to_8bit));
        let transmittance = ExposureTable::new(stock.layer(1), |d| linear(1, d) as f32);
        let long_side = f64::from(size.0.max(size.1).max(1));
        let pitch_mm = options.format_mm / long_side;
        let grained = match options.grain {
            None => None,
            Some(strength) => Some(grained(stock, strength, pitch_mm, options.seed, linear)?),
        };
        let kernels = if options.mtf {
            let mtf = stock.mtf.as_ref().ok_or_else(|| FilmError::NoData {
                id: stock.id.clone(),
                reason: "its data sheet gives no MTF curve, so +mtf cannot be modelled".into(),
            })?;
            Some(([0, 1, 2].map(|c| optics::MtfFit::new(mtf, c)), pitch_mm))
        } else {
            None
        };
        let halation = options
            .halation
            .map(|s| (s as f32, optics::HALATION_SIGMA_MM / pitch_mm));
        Ok(Emulsion {
            scale,
            mode,
            display,
            display8,
            transmittance,
            grained,
            kernels,
            halation,
            printer_light,
            printing_density,
        })
    }

    /// The printer light `L_c` (log10) of a negative, `None` for a slide.
    pub fn printer_light(&self) -> Option<[f64; 3]> {
        self.printer_light
    }

    /// A negative's Status M → printing density conversion on its paper, `None` for a
    /// slide.
    pub fn printing_density(&self) -> Option<&PrintingDensity> {
        self.printing_density.as_ref()
    }

    /// Whether the look needs the optics pass ([`Emulsion::expose`]) before developing.
    pub(crate) fn has_optics(&self) -> bool {
        self.kernels.is_some() || self.halation.is_some()
    }

    /// The light inside the film: `map` through the MTF and halation if the look asks for
    /// them ([`super::optics`]), else `map` itself, delivered a band of rows at a time
    /// (the optics' wide terms are computed here; a source that does not hold its pixels,
    /// a merge evaluated on demand, is evaluated whole for them). Radiance that is NaN or
    /// negative counts as no light, `+∞` as 10³⁰.
    pub fn expose<'a>(&self, map: &'a dyn RadianceSource) -> LatentImage<'a> {
        if !self.has_optics() {
            let by_code = map
                .code_pairs()
                .filter(|_| self.grained.is_none() && self.mode != ColourMode::Luminance)
                .map(|pairs| self.by_code(&pairs));
            return LatentImage {
                map,
                filter: None,
                by_code,
            };
        }
        let (w, h) = (map.width() as usize, map.height() as usize);
        let terms: Vec<Vec<(f64, f64)>> = (0..3)
            .map(|c| {
                let mut terms = vec![(0.0, 1.0)];
                if let Some((strength, sigma)) = self.halation {
                    // Red takes the halo at full strength, green at a quarter, blue none.
                    let s = f64::from([strength, strength / 4.0, 0.0][c]);
                    if s > 0.0 {
                        terms = optics::halation_terms(s, sigma);
                    }
                }
                if let Some((fits, pitch_mm)) = &self.kernels {
                    terms = optics::compose(&terms, &fits[c].terms_px(*pitch_mm));
                }
                terms
            })
            .collect();
        let pixels = match map.held() {
            Some(held) => std::borrow::Cow::Borrowed(held),
            None => {
                let mut all = vec![0.0; w * h * map.channels()];
                map.pixels_into(0, &mut all);
                std::borrow::Cow::Owned(all)
            }
        };
        let filter = optics::Filter::new(pixels, map.channels(), w, h, &terms);
        LatentImage {
            map,
            filter: Some(filter),
            by_code: None,
        }
    }

    /// Each layer's display value by code pair of a merged pair, without grain: entry
    /// `(dark << 8) | bright` of layer `c` is the layer's table at `scale_c · E`, `E` the
    /// pair's value of channel `c` (of its one channel if grey) for those codes, so that
    /// a sample develops by one lookup to the same value as [`Emulsion::pixel`] gives.
    fn by_code(&self, pairs: &CodePairs<'_>) -> ByCode {
        let layer = |c: usize| -> (Vec<u16>, Vec<u8>) {
            let channel = c.min(pairs.channels - 1);
            let values = &pairs.values[channel << 16..(channel + 1) << 16];
            values
                .iter()
                .map(|&e| {
                    let h = e * self.scale[c];
                    (self.display[c].get(h), self.display8[c].get(h))
                })
                .unzip()
        };
        let [(r16, r8), (g16, g8), (b16, b8)] = [0, 1, 2].map(layer);
        ByCode {
            sixteen: [r16, g16, b16],
            eight: [r8, g8, b8],
        }
    }

    /// Develops one pixel of linear radiance into sRGB-encoded 16-bit values, without
    /// grain.
    #[inline]
    pub fn pixel(&self, e: [f32; 3]) -> [u16; 3] {
        self.develop_pixel(e)
    }

    /// One pixel without grain, at the depth of `T`.
    #[inline]
    fn develop_pixel<T: Sample>(&self, e: [f32; 3]) -> [T; 3] {
        match self.mode {
            ColourMode::PerLayer | ColourMode::NeutralGrey => {
                let d = T::exposure_tables(self);
                [
                    d[0].get(e[0] * self.scale[0]),
                    d[1].get(e[1] * self.scale[1]),
                    d[2].get(e[2] * self.scale[2]),
                ]
            }
            ColourMode::Luminance => {
                let (e, l) = luminance_of(e);
                let t = self.transmittance.get(l * self.scale[1]);
                keep_chromaticity(e, l, t).map(T::from_u16)
            }
        }
    }

    /// One pixel with the grain of (`x`, `y`), at the depth of `T`.
    #[inline]
    fn develop_grained<T: Sample>(&self, g: &Grained, e: [f32; 3], x: usize, y: usize) -> [T; 3] {
        let n = g.grain.normals(x, y);
        match self.mode {
            ColourMode::PerLayer | ColourMode::NeutralGrey => {
                let layer = |c: usize| {
                    let [u, sigma] = g.density[c].get(e[c] * self.scale[c]);
                    let t = &g.from_density[c];
                    T::density_table(t)[t.at(u + sigma * n[c])]
                };
                [layer(0), layer(1), layer(2)]
            }
            ColourMode::Luminance => {
                let (e, l) = luminance_of(e);
                let [u, sigma] = g.density[1].get(l * self.scale[1]);
                let t = &g.from_density[1];
                let u = u + sigma * n[1];
                keep_chromaticity(e, l, t.linear[t.at(u)]).map(T::from_u16)
            }
        }
    }
}

/// A display sample's depth: the tables kept at it, so that 8-bit development reads
/// 8-bit tables (each entry [`to_8bit`] of the 16-bit one: the same output as converting
/// after).
trait Sample: Copy + Send + Sync {
    /// The per-layer display tables by exposure.
    fn exposure_tables(e: &Emulsion) -> &[ExposureTable<Self>; 3];
    /// A layer's display values by density.
    fn density_table(t: &DensityTable) -> &[Self];
    /// A 16-bit display value at this depth.
    fn from_u16(v: u16) -> Self;
    /// The display tables by code pair at this depth.
    fn by_code(b: &ByCode) -> &[Vec<Self>; 3];
}

impl Sample for u16 {
    fn exposure_tables(e: &Emulsion) -> &[ExposureTable<u16>; 3] {
        &e.display
    }
    fn density_table(t: &DensityTable) -> &[u16] {
        &t.display
    }
    fn from_u16(v: u16) -> u16 {
        v
    }
    fn by_code(b: &ByCode) -> &[Vec<u16>; 3] {
        &b.sixteen
    }
}

impl Sample for u8 {
    fn exposure_tables(e: &Emulsion) -> &[ExposureTable<u8>; 3] {
        &e.display8
    }
    fn density_table(t: &DensityTable) -> &[u8] {
        &t.display8
    }
    fn from_u16(v: u16) -> u8 {
        to_8bit(v)
    }
    fn by_code(b: &ByCode) -> &[Vec<u8>; 3] {
        &b.eight
    }
}

/// Radiance made safe for the luminance mode (non-finite and negative to 0, `+∞` to
/// `f32::MAX`) and its luminance.
#[inline]
fn luminance_of(e: [f32; 3]) -> ([f32; 3], f32) {
    let e = e.map(|v| {
        if v.is_finite() {
            v.max(0.0)
        } else if v > 0.0 {
            f32::MAX
        } else {
            0.0
        }
    });
    (e, luminance(e[0], e[1], e[2]))
}

/// `t · E_c / L`, scaled down with the other channels if one would pass white, encoded.
#[inline]
fn keep_chromaticity(e: [f32; 3], l: f32, t: f32) -> [u16; 3] {
    let rgb = if l > 0.0 && l.is_finite() {
        e.map(|v| t * (v / l))
    } else {
        [t; 3]
    };
    let peak = rgb[0].max(rgb[1]).max(rgb[2]);
    let norm = if peak > 1.0 { 1.0 / peak } else { 1.0 };
    rgb.map(|v| srgb_encode_u16(if v.is_finite() { v * norm } else { 1.0 }))
}

/// The light inside the film ([`Emulsion::expose`]): the radiance map, through the
/// look's optics if it has any, a band of rows at a time.
pub struct LatentImage<'a> {
    map: &'a dyn RadianceSource,
    filter: Option<optics::Filter<'a>>,
    /// The display tables by code pair, when the map is a merged pair and the look
    /// develops each layer alone ([`Emulsion::by_code`]).
    by_code: Option<ByCode>,
}

/// Per layer, the display value by code pair, `(dark << 8) | bright`, at both depths.
struct ByCode {
    sixteen: [Vec<u16>; 3],
    eight: [Vec<u8>; 3],
}

impl LatentImage<'_> {
    /// Width in pixels.
    pub fn width(&self) -> u32 {
        self.map.width()
    }

    /// Height in pixels.
    pub fn height(&self) -> u32 {
        self.map.height()
    }

    /// Calls `f` with rows `first .. first + count` (interleaved) and their channel count.
    fn with_rows<R>(&self, first: usize, count: usize, f: impl FnOnce(&[f32], usize) -> R) -> R {
        let width = self.map.width() as usize;
        match &self.filter {
            None => {
                let ch = self.map.channels();
                radiance::with_pixels(self.map, first * width, count * width, |rows| f(rows, ch))
            }
            Some(filter) => FILTERED.with_borrow_mut(|rows| {
                rows.resize(count * width * 3, 0.0);
                filter.rows(first, rows);
                f(rows, 3)
            }),
        }
    }
}

thread_local! {
    /// A band of filtered rows, per thread (kept between bands).
    static FILTERED: std::cell::RefCell<Vec<f32>> = std::cell::RefCell::default();
}

/// Rows developed per task (and filtered per band of the optics).
const DEVELOP_ROWS: usize = optics::BAND;

impl Emulsion {
    /// Develops a whole map at `depth` bits per sample (bands of rows in parallel), the
    /// optics included.
    pub fn render(&self, map: &dyn RadianceSource, depth: Depth) -> DisplayImage {
        let exposure = self.expose(map);
        let width = map.width() as usize;
        let height = map.height() as usize;
        match depth {
            Depth::Sixteen => {
                let mut samples = vec![0u16; width * height * 3];
                self.develop(&exposure, 0, &mut samples);
                DisplayImage::new(map.width(), map.height(), samples)
            }
            Depth::Eight => {
                let mut samples = vec![0u8; width * height * 3];
                self.render_rows_8bit(&exposure, 0, &mut samples);
                DisplayImage::new_8bit(map.width(), map.height(), samples)
            }
        }
    }

    /// Develops rows `first..first + out.len()/(3·width)` of the exposure into 8-bit RGB
    /// `out` (bands of rows in parallel): the unit the streaming JPEG writer pulls.
    pub fn render_rows_8bit(&self, exposure: &LatentImage<'_>, first: usize, out: &mut [u8]) {
        self.develop(exposure, first, out);
    }

    /// Develops rows from `first` into RGB `out` at the depth of `T`.
    fn develop<T: Sample>(&self, exposure: &LatentImage<'_>, first: usize, out: &mut [T]) {
        let width = exposure.width() as usize;
        if let (Some(by_code), Some(pairs)) = (&exposure.by_code, exposure.map.code_pairs()) {
            let tables = T::by_code(by_code);
            let ch = pairs.channels;
            let start = first * width;
            out.par_chunks_mut(width * 3 * DEVELOP_ROWS)
                .enumerate()
                .for_each(|(band, out)| {
                    let pixel = start + band * DEVELOP_ROWS * width;
                    let count = out.len() / 3;
                    let range = pixel * ch..(pixel + count) * ch;
                    let (dark, bright) = (&pairs.dark[range.clone()], &pairs.bright[range]);
                    let code = |i: usize| (usize::from(dark[i]) << 8) | usize::from(bright[i]);
                    if ch == 3 {
                        for (p, o) in out.chunks_exact_mut(3).enumerate() {
                            for (c, (o, table)) in o.iter_mut().zip(tables).enumerate() {
                                *o = table[code(3 * p + c)];
                            }
                        }
                    } else {
                        for (p, o) in out.chunks_exact_mut(3).enumerate() {
                            let k = code(p);
                            for (o, table) in o.iter_mut().zip(tables) {
                                *o = table[k];
                            }
                        }
                    }
                });
            return;
        }
        out.par_chunks_mut(width * 3 * DEVELOP_ROWS)
            .enumerate()
            .for_each(|(band, out)| {
                let y0 = first + band * DEVELOP_ROWS;
                let count = out.len() / (width * 3);
                exposure.with_rows(y0, count, |rows, ch| {
                    for (i, (out, row)) in out
                        .chunks_exact_mut(width * 3)
                        .zip(rows.chunks_exact(width * ch))
                        .enumerate()
                    {
                        let pixels = out.chunks_exact_mut(3).zip(row.chunks_exact(ch));
                        match &self.grained {
                            None => {
                                for (o, p) in pixels {
                                    o.copy_from_slice(&self.develop_pixel::<T>(colour(p, ch)));
                                }
                            }
                            Some(g) => {
                                for (x, (o, p)) in pixels.enumerate() {
                                    let v = self.develop_grained::<T>(g, colour(p, ch), x, y0 + i);
                                    o.copy_from_slice(&v);
                                }
                            }
                        }
                    }
                })
            });
    }
}

#[inline]
fn colour(p: &[f32], ch: usize) -> [f32; 3] {
    if ch == 3 {
        [p[0], p[1], p[2]]
    } else {
        [p[0]; 3]
    }
}

/// Renders `map` through a stock (a negative through its default print) at relative
/// exposure `t`, 16 bits per sample.
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

/// Each layer's scale: `exposure · H_key / key`, and in the neutral-grey mode layer `c`
/// further multiplied by `10^s_c` (see [`Emulsion::with_options`]).
fn layer_scales(stock: &Stock, exposure: f64, key: f64, mode: ColourMode) -> [f32; 3] {
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
    scale
}

/// The grain of `stock` at `strength` (seeded by `seed`) for pixels of `pitch_mm` at film scale, with its
/// tables: each layer's display light by density, `linear(c, d)` capped at 1, and each
/// layer's density and grain by exposure. A stock whose data sheet gives no RMS
/// granularity cannot be grained.
fn grained(
    stock: &Stock,
    strength: f64,
    pitch_mm: f64,
    seed: u64,
    linear: impl Fn(usize, f64) -> f64,
) -> Result<Grained, FilmError> {
    let grain = Grain::new(stock, strength, pitch_mm * 1000.0, seed)
        .ok_or_else(|| FilmError::NoData {
            id: stock.id.clone(),
            reason: "its data sheet gives no RMS granularity, so +grain cannot be modelled (Kodak gives only a Print Grain Index for colour negatives)".into(),
        })?;
    let from_density = [0, 1, 2].map(|c| {
        let curve = stock.layer(c);
        DensityTable::new(curve.d_min() - 1.0, curve.d_max() + 1.0, |d| {
            linear(c, d).min(1.0)
        })
    });
    let density = [0, 1, 2].map(|c| {
        ExposureTable::new(stock.layer(c), |d| {
            let d = d as f32;
            [
                from_density[c].units(d),
                grain.sigma(c, d) * (1.0 / DENSITY_STEP),
            ]
        })
    });
    Ok(Grained {
        grain,
        density,
        from_density,
    })
}
