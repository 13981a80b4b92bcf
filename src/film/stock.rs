//! Stock files: characteristic curves read off data sheets, validated, and the catalogue
//! of built-in and user stocks.

use std::path::{Path, PathBuf};

use serde::Deserialize;

use super::spectral::{SpectralDensity, SpectralDensityFile};
use super::{FilmError, Kind, LAYERS};

/// A characteristic curve: density `D` against `log10 H` (H in lux·s), interpolated by a
/// monotone piecewise cubic (Fritsch–Carlson / PCHIP), constant beyond the end points.
#[derive(Debug, Clone, PartialEq)]
pub struct Curve {
    log_h: Vec<f64>,
    density: Vec<f64>,
    /// dD/dlog10H at each point, chosen so the cubic never overshoots the data.
    slope: Vec<f64>,
}

impl Curve {
    /// Builds the interpolant of points sorted by increasing log H (at least two).
    ///
    /// Interior slopes are the weighted harmonic mean of the neighbouring secants (zero
    /// where they differ in sign or either is zero); end slopes the shape-preserving
    /// three-point formula. Together these keep the cubic monotone between monotone data
    /// (Fritsch & Carlson 1980; Fritsch & Butland 1984; as in SciPy's `PchipInterpolator`).
    pub(super) fn new(points: &[(f64, f64)]) -> Curve {
        let log_h: Vec<f64> = points.iter().map(|p| p.0).collect();
        let density: Vec<f64> = points.iter().map(|p| p.1).collect();
        let n = points.len();
        let h: Vec<f64> = log_h.windows(2).map(|w| w[1] - w[0]).collect();
        let secant: Vec<f64> = (0..n - 1)
            .map(|i| (density[i + 1] - density[i]) / h[i])
            .collect();
        let mut slope = vec![0.0; n];
        if n == 2 {
            slope = vec![secant[0]; 2];
        } else {
            for k in 1..n - 1 {
                let (s0, s1) = (secant[k - 1], secant[k]);
                if s0 * s1 > 0.0 {
                    let w1 = 2.0 * h[k] + h[k - 1];
                    let w2 = h[k] + 2.0 * h[k - 1];
                    slope[k] = (w1 + w2) / (w1 / s0 + w2 / s1);
                }
            }
            slope[0] = end_slope(h[0], h[1], secant[0], secant[1]);
            slope[n - 1] = end_slope(h[n - 2], h[n - 3], secant[n - 2], secant[n - 3]);
        }
        Curve {
            log_h,
            density,
            slope,
        }
    }

    /// Density at `log_h` (log10 lux·s); the end densities outside the data.
    pub fn density(&self, log_h: f64) -> f64 {
        let n = self.log_h.len();
        if log_h.is_nan() || log_h <= self.log_h[0] {
            return self.density[0];
        }
        if log_h >= self.log_h[n - 1] {
            return self.density[n - 1];
        }
        let i = self.log_h.partition_point(|&x| x <= log_h) - 1;
        let h = self.log_h[i + 1] - self.log_h[i];
        let s = (log_h - self.log_h[i]) / h;
        let (d0, d1) = (self.density[i], self.density[i + 1]);
        let (m0, m1) = (self.slope[i] * h, self.slope[i + 1] * h);
        let s2 = s * s;
        let s3 = s2 * s;
        (2.0 * s3 - 3.0 * s2 + 1.0) * d0
            + (s3 - 2.0 * s2 + s) * m0
            + (-2.0 * s3 + 3.0 * s2) * d1
            + (s3 - s2) * m1
    }

    /// The data points (log10 H, D).
    pub fn points(&self) -> impl Iterator<Item = (f64, f64)> + '_ {
        self.log_h.iter().copied().zip(self.density.iter().copied())
    }

    /// The data's log10 H range.
    pub fn log_h_range(&self) -> (f64, f64) {
        (self.log_h[0], self.log_h[self.log_h.len() - 1])
    }

    /// Lowest density of the curve (the film base plus fog).
    pub fn d_min(&self) -> f64 {
        self.density.iter().copied().fold(f64::INFINITY, f64::min)
    }

    /// Highest density of the curve.
    pub fn d_max(&self) -> f64 {
        self.density
            .iter()
            .copied()
            .fold(f64::NEG_INFINITY, f64::max)
    }

    /// The log10 H at which the (monotone) curve reaches `density`, if it does.
    pub fn log_h_at(&self, density: f64) -> Option<f64> {
        if !(self.d_min()..=self.d_max()).contains(&density) {
            return None;
        }
        let rising = self.density[self.density.len() - 1] > self.density[0];
        let (mut lo, mut hi) = self.log_h_range();
        // Bisection on the monotone interpolant: 60 halvings reach f64 resolution.
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if (self.density(mid) < density) == rising {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        Some(0.5 * (lo + hi))
    }

    /// The steepest |dD/dlog10H| of the interpolant, sampled finely (used to bound the
    /// table error).
    #[cfg(test)]
    pub(crate) fn max_gradient(&self) -> f64 {
        let (a, b) = self.log_h_range();
        let steps = 4000;
        let dx = (b - a) / steps as f64;
        (0..steps)
            .map(|i| {
                let x = a + i as f64 * dx;
                ((self.density(x + dx) - self.density(x)) / dx).abs()
            })
            .fold(0.0, f64::max)
    }
}

fn end_slope(h0: f64, h1: f64, s0: f64, s1: f64) -> f64 {
    let d = ((2.0 * h0 + h1) * s0 - h0 * s1) / (h0 + h1);
    if d.signum() != s0.signum() || s0 == 0.0 {
        0.0
    } else if s0.signum() != s1.signum() && d.abs() > 3.0 * s0.abs() {
        3.0 * s0
    } else {
        d
    }
}

/// A film stock: what it is, where its curves come from, and the curves.
#[derive(Debug, Clone, PartialEq)]
pub struct Stock {
    /// Short typable id (`velvia50`).
    pub id: String,
    /// Full name.
    pub name: String,
    /// Manufacturer.
    pub maker: String,
    /// Reversal or negative.
    pub kind: Kind,
    /// The manufacturer's rating (ISO speed, or exposure index for a push).
    pub iso: f64,
    /// Density measure of the curves (Status A, Status M).
    pub density_measure: String,
    /// The data sheet the curves were read from.
    pub source: String,
    /// Why the curves or the rating are not to be trusted as a speed check, if they are not.
    pub uncertain: Option<String>,
    /// The file it was loaded from (`curves/…` for built-in stocks).
    pub origin: PathBuf,
    /// The sheet's RMS granularity, if it gives one.
    pub granularity: Option<Granularity>,
    /// The sheet's modulation transfer function per layer, if it gives one.
    pub mtf: Option<Mtf>,
    /// A negative's spectral densities (minimum and midscale neutral), if given: what
    /// converts its Status M curves to a paper's printing densities.
    pub spectral_density: Option<SpectralDensity>,
    layers: [Curve; 3],
}

/// Diffuse RMS granularity as a data sheet states it: `1000·σ_D`, the standard deviation
/// of density read through a 48 µm circular aperture on a uniformly exposed patch of the
/// stated density.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Granularity {
    /// `1000·σ_D` (dimensionless: density × 1000).
    pub rms: f64,
    /// The density the sheet measured at.
    pub density: f64,
    /// Whether `density` is above D-min (Fujifilm) or gross, base included (Kodak).
    pub reference: DensityReference,
    /// The sheet it was read from.
    pub source: String,
}

/// How a sheet states the density of a granularity reading.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum DensityReference {
    /// Density above the film's D-min.
    AboveBase,
    /// Gross density, base and fog included.
    Gross,
}

impl Granularity {
    /// The reference density above D-min for a layer whose D-min is `d_min`.
    pub fn net_density(&self, d_min: f64) -> f64 {
        match self.reference {
            DensityReference::AboveBase => self.density,
            DensityReference::Gross => (self.density - d_min).max(0.05),
        }
    }
}

/// A data sheet's modulation transfer function: response (1 = 100 %) against spatial
/// frequency in cycles/mm at film scale, per layer.
#[derive(Debug, Clone, PartialEq)]
pub struct Mtf {
    /// Frequencies, cycles/mm, increasing.
    pub cycles_per_mm: Vec<f64>,
    /// Response per layer (red, green, blue) at those frequencies, as a fraction.
    pub layers: [Vec<f64>; 3],
    /// The sheet it was read from.
    pub source: String,
}

impl Mtf {
    /// Response of layer `c` at `f` cycles/mm: 1 at 0, linear between the sheet's points
    /// (from 1 at 0 to the first point), and beyond the last point falling like the last
    /// segment's ratio per cycle/mm (`M(f) = M_n·(M_n/M_{n−1})^((f−f_n)/(f_n−f_{n−1}))`),
    /// never below 0.
    pub fn response(&self, c: usize, f: f64) -> f64 {
        let x = &self.cycles_per_mm;
        let y = &self.layers[c];
        let n = x.len();
        let f = f.abs();
        if f <= x[0] {
            return 1.0 + (y[0] - 1.0) * f / x[0];
        }
        if f >= x[n - 1] {
            let ratio = (y[n - 1] / y[n - 2]).min(1.0);
            return y[n - 1] * ratio.powf((f - x[n - 1]) / (x[n - 1] - x[n - 2]));
        }
        let i = x.partition_point(|&v| v <= f) - 1;
        let s = (f - x[i]) / (x[i + 1] - x[i]);
        y[i] + s * (y[i + 1] - y[i])
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct MtfFile {
    source: String,
    cycles_per_mm: Vec<f64>,
    red: Vec<f64>,
    green: Vec<f64>,
    blue: Vec<f64>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct StockFile {
    id: String,
    name: String,
    maker: String,
    kind: Kind,
    iso: f64,
    density: String,
    source: String,
    uncertain: Option<String>,
    layers: LayerFile,
    grain: Option<Granularity>,
    mtf: Option<MtfFile>,
    spectral_density: Option<SpectralDensityFile>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct LayerFile {
    pub(super) red: Vec<(f64, f64)>,
    pub(super) green: Vec<(f64, f64)>,
    pub(super) blue: Vec<(f64, f64)>,
}

/// Plausible log10 H of a data sheet (lux·s): 10⁻⁶ to 10³ lux·s.
const LOG_H_RANGE: (f64, f64) = (-6.0, 3.0);
/// Plausible diffuse density.
const DENSITY_RANGE: (f64, f64) = (0.0, 6.0);

/// A stock's speed computed from its own green curve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Speed {
    /// The computed speed (ISO arithmetic).
    pub iso: f64,
    /// The exposure(s) it was computed from, lux·s: (shadow point, highlight point) for a
    /// reversal stock, (speed point, speed point) for a negative.
    pub points_lux_s: (f64, f64),
}

impl Stock {
    /// Parses and validates a stock file's text; `origin` names it in errors.
    pub fn from_toml(text: &str, origin: &Path) -> Result<Stock, FilmError> {
        let file: StockFile = toml::from_str(text).map_err(|source| FilmError::Syntax {
            path: origin.to_path_buf(),
            source,
        })?;
        let field = |field: &'static str, reason: String| FilmError::Field {
            path: origin.to_path_buf(),
            field,
            reason,
        };
        let id_ok = !file.id.is_empty()
            && file
                .id
                .chars()
                .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '-');
        if !id_ok {
            return Err(field(
                "id",
                format!(
                    "{:?} must be short and typable: lower-case letters, digits, '-'",
                    file.id
                ),
            ));
        }
        if !(file.iso.is_finite() && (1.0..=100_000.0).contains(&file.iso)) {
            return Err(field("iso", format!("{} is outside 1..=100000", file.iso)));
        }
        let layers = [file.layers.red, file.layers.green, file.layers.blue];
        let mut curves = Vec::with_capacity(3);
        for (name, points) in LAYERS.iter().zip(&layers) {
            validate_layer(origin, name, file.kind, points)?;
            curves.push(match file.kind {
                Kind::Reversal => Curve::new(points),
                Kind::Negative => Curve::new(&smooth_readings(points)),
            });
        }
        let [red, green, blue]: [Curve; 3] = curves
            .try_into()
            .unwrap_or_else(|_| unreachable!("three layers were pushed"));
        if let Some(g) = &file.grain
            && !(g.rms.is_finite() && (0.5..=200.0).contains(&g.rms))
        {
            return Err(field(
                "grain.rms",
                format!("{} is outside 0.5..=200", g.rms),
            ));
        }
        if let Some(g) = &file.grain
            && !(g.density.is_finite() && (0.1..=4.0).contains(&g.density))
        {
            return Err(field(
                "grain.density",
                format!("{} is outside 0.1..=4", g.density),
            ));
        }
        let mtf = file.mtf.map(|m| check_mtf(m, origin)).transpose()?;
        let spectral_density = file.spectral_density.map(|s| s.check(origin)).transpose()?;
        Ok(Stock {
            id: file.id,
            name: file.name,
            maker: file.maker,
            kind: file.kind,
            iso: file.iso,
            density_measure: file.density,
            source: file.source,
            uncertain: file.uncertain,
            origin: origin.to_path_buf(),
            granularity: file.grain,
            mtf,
            spectral_density,
            layers: [red, green, blue],
        })
    }

    /// Reads and validates a stock file.
    pub fn load(path: &Path) -> Result<Stock, FilmError> {
        let text = std::fs::read_to_string(path).map_err(|io| FilmError::Read {
            path: path.to_path_buf(),
            io,
        })?;
        Stock::from_toml(&text, path)
    }

    /// The curve of layer 0 (red), 1 (green) or 2 (blue).
    pub fn layer(&self, index: usize) -> &Curve {
        &self.layers[index]
    }

    /// The metered mid-tone exposure `H = 8/S` lux·s for the rating `S` (the exposure a
    /// reflected-light meter gives an 18 % grey card, ISO 2720's K ≈ 12.5 with the
    /// camera's optics folded in).
    pub fn metered_exposure(&self) -> f64 {
        8.0 / self.iso
    }

    /// The speed computed from the green curve.
    ///
    /// Reversal (ISO 2240): `H₁` where `D = D_min + 0.2` (highlights), `H₂` where
    /// `D = D_min + 2.0` (shadows), `H_m = √(H₁·H₂)`, `S = 10 / H_m`.
    /// Negative (ISO 5800, speed point only): `H_m` where `D = D_min + 0.1`,
    /// `S = 0.8 / H_m` (the standard's contrast condition is not checked).
    /// `None` when the curve does not reach those densities.
    pub fn speed(&self) -> Option<Speed> {
        let green = &self.layers[1];
        let d_min = green.d_min();
        match self.kind {
            Kind::Reversal => {
                let h1 = 10f64.powf(green.log_h_at(d_min + 0.2)?);
                let h2 = 10f64.powf(green.log_h_at(d_min + 2.0)?);
                Some(Speed {
                    iso: 10.0 / (h1 * h2).sqrt(),
                    points_lux_s: (h2, h1),
                })
            }
            Kind::Negative => {
                let h = 10f64.powf(green.log_h_at(d_min + 0.1)?);
                Some(Speed {
                    iso: 0.8 / h,
                    points_lux_s: (h, h),
                })
            }
        }
    }
}

fn check_mtf(m: MtfFile, origin: &Path) -> Result<Mtf, FilmError> {
    let field = |field: &'static str, reason: String| FilmError::Field {
        path: origin.to_path_buf(),
        field,
        reason,
    };
    let x = &m.cycles_per_mm;
    if x.len() < 2
        || x.windows(2)
            .any(|w| w[1].partial_cmp(&w[0]) != Some(std::cmp::Ordering::Greater))
        || x[0].partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater)
    {
        return Err(field(
            "mtf.cycles_per_mm",
            "needs at least 2 positive frequencies, increasing".into(),
        ));
    }
    let layers = [m.red, m.green, m.blue];
    for (name, values) in ["mtf.red", "mtf.green", "mtf.blue"]
        .into_iter()
        .zip(&layers)
    {
        if values.len() != x.len() {
            return Err(field(
                name,
                format!("{} values for {} frequencies", values.len(), x.len()),
            ));
        }
        if let Some(v) = values
            .iter()
            .find(|v| !(v.is_finite() && (0.5..=300.0).contains(*v)))
        {
            return Err(field(name, format!("{v} % is outside 0.5..=300")));
        }
    }
    Ok(Mtf {
        cycles_per_mm: m.cycles_per_mm,
        layers: layers.map(|l| l.into_iter().map(|v| v / 100.0).collect()),
        source: m.source,
    })
}

/// A negative's readings with their rounding smoothed: each interior point becomes
/// `D'_i = ½·D_i + ½·D̂_i`, `D̂_i` the straight line through its neighbours at `log H_i`
/// (the binomial filter `[¼, ½, ¼]` on evenly spaced points); the end points are kept.
///
/// Why: the sheets' readings are rounded to 0.01 D every 0.1 log H, so the slope between
/// two readings is off by up to ±0.1 (a fifth of a negative's gradient of about 0.6),
/// and a print multiplies a negative's density by the paper's gradient (about 4): the
/// rounding alone swings a grey scale's print by up to 4 ΔE within a stop. The filter
/// keeps a straight line exactly, keeps monotone readings monotone, moves a point by
/// `h²/4·D''` (0.001–0.004 D in the toe at `h` = 0.1) and halves the rounding's slope
/// noise. Slides are viewed directly (gradient 1) and keep their readings.
pub(super) fn smooth_readings(points: &[(f64, f64)]) -> Vec<(f64, f64)> {
    let mut out = points.to_vec();
    for (i, w) in points.windows(3).enumerate() {
        let [(x0, d0), (x, d), (x1, d1)] = [w[0], w[1], w[2]];
        let line = d0 + (d1 - d0) * (x - x0) / (x1 - x0);
        out[i + 1].1 = 0.5 * d + 0.5 * line;
    }
    out
}

pub(super) fn validate_layer(
    path: &Path,
    layer: &'static str,
    kind: Kind,
    points: &[(f64, f64)],
) -> Result<(), FilmError> {
    if points.len() < 3 {
        return Err(FilmError::Layer {
            path: path.to_path_buf(),
            layer,
            reason: format!("{} points; a curve needs at least 3", points.len()),
        });
    }
    let bad = |i: usize, reason: String| FilmError::Point {
        path: path.to_path_buf(),
        layer,
        point: i + 1,
        log_h: points[i].0,
        density: points[i].1,
        reason,
    };
    for i in 0..points.len() {
        if let Some(reason) = point_fault(kind, points, i) {
            return Err(bad(i, reason));
        }
    }
    let first = points[0].1;
    let last = points[points.len() - 1].1;
    if (first - last).abs() < 0.3 {
        return Err(FilmError::Layer {
            path: path.to_path_buf(),
            layer,
            reason: format!(
                "density spans only {:.2} (from {first} to {last}); not a characteristic curve",
                (first - last).abs()
            ),
        });
    }
    Ok(())
}

/// What is wrong with point `i` of a layer of a film of `kind`, if anything: its log H
/// and density within range, log H increasing, and density monotonic in the film's
/// sense (rising for a negative, falling for a slide).
fn point_fault(kind: Kind, points: &[(f64, f64)], i: usize) -> Option<String> {
    let (log_h, d) = points[i];
    if !(log_h.is_finite() && (LOG_H_RANGE.0..=LOG_H_RANGE.1).contains(&log_h)) {
        return Some(format!(
            "log10 H outside {}..{} (lux·s)",
            LOG_H_RANGE.0, LOG_H_RANGE.1
        ));
    }
    if !(d.is_finite() && (DENSITY_RANGE.0..=DENSITY_RANGE.1).contains(&d)) {
        return Some(format!(
            "density outside {}..{}",
            DENSITY_RANGE.0, DENSITY_RANGE.1
        ));
    }
    if i == 0 {
        return None;
    }
    let (prev_h, prev_d) = points[i - 1];
    if log_h <= prev_h {
        return Some(format!("log H must increase (previous point at {prev_h})"));
    }
    match kind {
        Kind::Reversal if d > prev_d => Some(format!(
            "density rises from {prev_d}; a reversal film's density must fall (or stay) as exposure rises"
        )),
        Kind::Negative if d < prev_d => Some(format!(
            "density falls from {prev_d}; a negative's density must rise (or stay) with exposure"
        )),
        _ => None,
    }
}

/// The built-in stock files, embedded at build time.
const BUILTIN: [(&str, &str); 9] = [
    (
        "curves/velvia50.toml",
        include_str!("../../curves/velvia50.toml"),
    ),
    (
        "curves/velvia100.toml",
        include_str!("../../curves/velvia100.toml"),
    ),
    (
        "curves/provia100f.toml",
        include_str!("../../curves/provia100f.toml"),
    ),
    (
        "curves/provia400.toml",
        include_str!("../../curves/provia400.toml"),
    ),
    (
        "curves/ektachrome100.toml",
        include_str!("../../curves/ektachrome100.toml"),
    ),
    ("curves/p1600.toml", include_str!("../../curves/p1600.toml")),
    (
        "curves/kodachrome64.toml",
        include_str!("../../curves/kodachrome64.toml"),
    ),
    (
        "curves/ektar100.toml",
        include_str!("../../curves/ektar100.toml"),
    ),
    (
        "curves/portra400.toml",
        include_str!("../../curves/portra400.toml"),
    ),
];

/// The stocks available: the built-in ones plus any from a user folder.
#[derive(Debug, Clone)]
pub struct Catalogue {
    stocks: Vec<Stock>,
}

impl Catalogue {
    /// The stocks shipped in `curves/` (validated like any other stock file).
    pub fn builtin() -> Result<Catalogue, FilmError> {
        let stocks = BUILTIN
            .iter()
            .map(|(name, text)| Stock::from_toml(text, Path::new(name)))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Catalogue { stocks })
    }

    /// Adds every `*.toml` in `folder` (sorted by name). A user stock may not reuse an id.
    pub fn with_folder(mut self, folder: &Path) -> Result<Catalogue, FilmError> {
        let listing = std::fs::read_dir(folder).map_err(|io| FilmError::Folder {
            path: folder.to_path_buf(),
            io,
        })?;
        let mut paths = Vec::new();
        for entry in listing {
            let entry = entry.map_err(|io| FilmError::Folder {
                path: folder.to_path_buf(),
                io,
            })?;
            let path = entry.path();
            if path.extension().is_some_and(|e| e == "toml") {
                paths.push(path);
            }
        }
        paths.sort();
        for path in paths {
            let stock = Stock::load(&path)?;
            if let Some(other) = self.stocks.iter().find(|s| s.id == stock.id) {
                return Err(FilmError::Duplicate {
                    path,
                    id: stock.id,
                    other: other.origin.display().to_string(),
                });
            }
            self.stocks.push(stock);
        }
        Ok(self)
    }

    /// All stocks, built-in first.
    pub fn stocks(&self) -> &[Stock] {
        &self.stocks
    }

    /// The stock with that id.
    pub fn get(&self, id: &str) -> Result<&Stock, FilmError> {
        self.stocks
            .iter()
            .find(|s| s.id == id)
            .ok_or_else(|| FilmError::UnknownStock {
                id: id.to_string(),
                known: self
                    .stocks
                    .iter()
                    .map(|s| s.id.as_str())
                    .collect::<Vec<_>>()
                    .join(", "),
            })
    }
}
