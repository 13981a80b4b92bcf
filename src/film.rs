//! Film stocks: characteristic curves as data, and rendering a radiance map through them.
//!
//! A stock is three characteristic curves, one per dye layer (red-, green- and
//! blue-forming), each a list of points (log10 H, D): exposure `H` in lux·s against
//! diffuse density `D` (Status A for reversal film, Status M for negatives), read off the
//! manufacturer's data sheet. The built-in stocks live in `curves/*.toml`; users add
//! their own by dropping a file of the same form into a folder ([`Catalogue::with_folder`]).
//!
//! Rendering a reversal (slide) stock, per pixel and layer `c`:
//! 1. `H_c = t · k · E_c` (lux·s): `E` is the relative radiance, `t` the relative exposure
//!    (1, 1/2, 8, …) and `k` the calibration that puts the scene's key (log-average
//!    luminance, or a given grey) at the stock's metered mid-tone `H = 8/S` for ISO `S`.
//! 2. `D_c = curve_c(log10 H_c)`, interpolated monotonically (Fritsch–Carlson / PCHIP)
//!    and clamped to the end points outside the data (D-max below, D-min above).
//! 3. `T_c = 10^−(D_c − D_min,c)`: the transmittance of the slide, normalised so that the
//!    film base (D-min) is display white.
//! 4. `T` is a linear sRGB value; it is encoded with the sRGB transfer function.
//!
//! The curve is evaluated through a table indexed by the bits of the `f32` exposure
//! ([`ExposureTable`]); its error is at most [`TABLE_MAX_ERROR_D`] in density.
//!
//! Negative stocks are loaded, validated, listed and plotted, but not rendered: a negative
//! is viewed through a print, and filmback carries no print-paper curves to model one;
//! [`render`] refuses them with [`FilmError::Negative`].

use std::fmt;
use std::path::{Path, PathBuf};
use std::str::FromStr;

use rayon::prelude::*;
use serde::Deserialize;

use crate::radiance::RadianceMap;
use crate::rendering::{Depth, DisplayImage, srgb_encode, srgb_encode_u16, to_8bit};

/// Why a stock could not be loaded or a rendering could not be made.
#[derive(Debug, thiserror::Error)]
pub enum FilmError {
    /// The stock file could not be read.
    #[error("{path}: cannot read: {io}")]
    Read {
        /// The stock file.
        path: PathBuf,
        /// What the operating system said.
        io: std::io::Error,
    },
    /// The file is not TOML of the expected form (missing or unknown key, wrong type).
    #[error("{path}: {reason}")]
    Syntax {
        /// The stock file.
        path: PathBuf,
        /// The parser's message, with line and column.
        reason: String,
    },
    /// A field outside its sane range.
    #[error("{path}: {field}: {reason}")]
    Field {
        /// The stock file.
        path: PathBuf,
        /// The key.
        field: &'static str,
        /// What is wrong with it.
        reason: String,
    },
    /// A curve point that breaks the physics (range, order, monotone density).
    #[error("{path}: layer {layer}, point {point} (log H {log_h}, D {density}): {reason}")]
    Point {
        /// The stock file.
        path: PathBuf,
        /// `red`, `green` or `blue`.
        layer: &'static str,
        /// 1-based index of the point in its layer.
        point: usize,
        /// The point's log10 H.
        log_h: f64,
        /// The point's density.
        density: f64,
        /// What is wrong with it.
        reason: String,
    },
    /// A layer too short to be a curve.
    #[error("{path}: layer {layer}: {reason}")]
    Layer {
        /// The stock file.
        path: PathBuf,
        /// `red`, `green` or `blue`.
        layer: &'static str,
        /// What is wrong with it.
        reason: String,
    },
    /// Two stock files share an id.
    #[error("{path}: stock id {id:?} is already defined by {other}")]
    Duplicate {
        /// The later file.
        path: PathBuf,
        /// The id.
        id: String,
        /// The file that defined it first.
        other: String,
    },
    /// The stock folder could not be listed.
    #[error("{path}: cannot list stock folder: {io}")]
    Folder {
        /// The folder.
        path: PathBuf,
        /// What the operating system said.
        io: std::io::Error,
    },
    /// No stock has that id.
    #[error("unknown film stock {id:?} (known: {known})")]
    UnknownStock {
        /// The id asked for.
        id: String,
        /// The ids available.
        known: String,
    },
    /// A negative stock was asked to render.
    #[error(
        "{id} is a colour negative: it is viewed through a print, and filmback has no print-paper curves to model one; choose a reversal stock"
    )]
    Negative {
        /// The stock's id.
        id: String,
    },
    /// A rendering request such as `velvia50@1/2` that does not parse.
    #[error("film request {text:?}: {reason}")]
    Request {
        /// The request as typed.
        text: String,
        /// What is wrong with it.
        reason: String,
    },
}

/// Reversal (slide, viewed by transmission) or negative (viewed through a print).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Kind {
    /// Slide film: density falls as exposure rises.
    Reversal,
    /// Colour negative: density rises with exposure.
    Negative,
}

impl fmt::Display for Kind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Kind::Reversal => "reversal",
            Kind::Negative => "negative",
        })
    }
}

/// The three dye layers, named by the light they record.
pub const LAYERS: [&str; 3] = ["red", "green", "blue"];

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
    fn new(points: &[(f64, f64)]) -> Curve {
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
    pub fn max_gradient(&self) -> f64 {
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
    layers: [Curve; 3],
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
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct LayerFile {
    red: Vec<(f64, f64)>,
    green: Vec<(f64, f64)>,
    blue: Vec<(f64, f64)>,
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
        let file: StockFile = toml::from_str(text).map_err(|e| FilmError::Syntax {
            path: origin.to_path_buf(),
            reason: e.to_string(),
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
            curves.push(Curve::new(points));
        }
        let [red, green, blue]: [Curve; 3] = curves
            .try_into()
            .unwrap_or_else(|_| unreachable!("three layers were pushed"));
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

fn validate_layer(
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
    for (i, &(log_h, d)) in points.iter().enumerate() {
        if !(log_h.is_finite() && (LOG_H_RANGE.0..=LOG_H_RANGE.1).contains(&log_h)) {
            return Err(bad(
                i,
                format!(
                    "log10 H outside {}..{} (lux·s)",
                    LOG_H_RANGE.0, LOG_H_RANGE.1
                ),
            ));
        }
        if !(d.is_finite() && (DENSITY_RANGE.0..=DENSITY_RANGE.1).contains(&d)) {
            return Err(bad(
                i,
                format!("density outside {}..{}", DENSITY_RANGE.0, DENSITY_RANGE.1),
            ));
        }
        if i > 0 {
            let (prev_h, prev_d) = points[i - 1];
            if log_h <= prev_h {
                return Err(bad(
                    i,
                    format!("log H must increase (previous point at {prev_h})"),
                ));
            }
            match kind {
                Kind::Reversal if d > prev_d => {
                    return Err(bad(
                        i,
                        format!(
                            "density rises from {prev_d}; a reversal film's density must fall (or stay) as exposure rises"
                        ),
                    ));
                }
                Kind::Negative if d < prev_d => {
                    return Err(bad(
                        i,
                        format!(
                            "density falls from {prev_d}; a negative's density must rise (or stay) with exposure"
                        ),
                    ));
                }
                _ => {}
            }
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

/// The built-in stock files, embedded at build time.
const BUILTIN: [(&str, &str); 9] = [
    (
        "curves/velvia50.toml",
        include_str!("../curves/velvia50.toml"),
    ),
    (
        "curves/velvia100.toml",
        include_str!("../curves/velvia100.toml"),
    ),
    (
        "curves/provia100f.toml",
        include_str!("../curves/provia100f.toml"),
    ),
    (
        "curves/provia400.toml",
        include_str!("../curves/provia400.toml"),
    ),
    (
        "curves/ektachrome100.toml",
        include_str!("../curves/ektachrome100.toml"),
    ),
    ("curves/p1600.toml", include_str!("../curves/p1600.toml")),
    (
        "curves/kodachrome64.toml",
        include_str!("../curves/kodachrome64.toml"),
    ),
    (
        "curves/ektar100.toml",
        include_str!("../curves/ektar100.toml"),
    ),
    (
        "curves/portra400.toml",
        include_str!("../curves/portra400.toml"),
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

/// A rendering request as typed: `velvia50`, `provia400@0.5`, `p1600@1/8`, `velvia50@+1ev`.
#[derive(Debug, Clone, PartialEq)]
pub struct Request {
    /// Stock id.
    pub stock: String,
    /// Relative exposure `t` (1 = metered; 1/2 = one stop less).
    pub exposure: f64,
}

impl FromStr for Request {
    type Err = FilmError;

    fn from_str(text: &str) -> Result<Request, FilmError> {
        let (stock, exposure) = match text.split_once('@') {
            None => (text, 1.0),
            Some((stock, t)) => (
                stock,
                parse_exposure(t).map_err(|reason| FilmError::Request {
                    text: text.to_string(),
                    reason,
                })?,
            ),
        };
        if stock.is_empty() {
            return Err(FilmError::Request {
                text: text.to_string(),
                reason: "no stock id before '@'".into(),
            });
        }
        Ok(Request {
            stock: stock.to_string(),
            exposure,
        })
    }
}

/// Parses a relative exposure: `0.5`, `1/2`, `8`, `-1ev`, `+2EV` (`t = 2^ev`).
pub fn parse_exposure(text: &str) -> Result<f64, String> {
    let lower = text.trim().to_ascii_lowercase();
    let t = if let Some(ev) = lower.strip_suffix("ev") {
        let ev: f64 = ev
            .trim()
            .parse()
            .map_err(|_| format!("{text:?} is not a number of stops such as -1ev"))?;
        2f64.powf(ev)
    } else if let Some((n, d)) = lower.split_once('/') {
        let n: f64 = n
            .trim()
            .parse()
            .map_err(|_| format!("{text:?}: bad numerator"))?;
        let d: f64 = d
            .trim()
            .parse()
            .map_err(|_| format!("{text:?}: bad denominator"))?;
        n / d
    } else {
        lower
            .parse()
            .map_err(|_| format!("{text:?} is not an exposure such as 0.5, 1/2 or -1ev"))?
    };
    if t.is_finite() && t > 0.0 && (1e-6..=1e6).contains(&t) {
        Ok(t)
    } else {
        Err(format!(
            "exposure {text:?} must be a positive factor between 1e-6 and 1e6"
        ))
    }
}

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

/// Rec. 709 / sRGB luminance of linear RGB.
pub fn luminance(r: f32, g: f32, b: f32) -> f32 {
    0.2126 * r + 0.7152 * g + 0.0722 * b
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
pub struct Development {
    /// `H = scale[c] · E` per layer (lux·s per unit radiance): `t·k`, times the neutral
    /// shift of [`ColourMode::NeutralGrey`].
    pub scale: [f32; 3],
    mode: ColourMode,
    /// Per-layer display value (sRGB-encoded, 0..=65535).
    display: [ExposureTable<u16>; 3],
    /// Green-layer transmittance for the luminance mode.
    transmittance: ExposureTable<f32>,
}

impl Development {
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
    ) -> Result<Development, FilmError> {
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
        Ok(Development {
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

impl Development {
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
    let development = Development::new(stock, exposure, scene_key(map, key), mode)?;
    Ok(development.render(map, Depth::Sixteen))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn catalogue() -> Catalogue {
        Catalogue::builtin().expect("built-in stocks load")
    }

    #[test]
    fn pchip_passes_through_points_and_is_monotone() {
        for stock in catalogue().stocks() {
            for c in 0..3 {
                let curve = stock.layer(c);
                for (x, d) in curve.points() {
                    assert!((curve.density(x) - d).abs() < 1e-12);
                }
                let (a, b) = curve.log_h_range();
                let falling = stock.kind == Kind::Reversal;
                let mut prev = curve.density(a);
                for i in 1..=2000 {
                    let d = curve.density(a + (b - a) * i as f64 / 2000.0);
                    assert!(
                        if falling {
                            d <= prev + 1e-12
                        } else {
                            d >= prev - 1e-12
                        },
                        "{} layer {c} not monotone",
                        stock.id
                    );
                    prev = d;
                }
            }
        }
    }

    #[test]
    fn pchip_does_not_overshoot_a_step() {
        let curve = Curve::new(&[(0.0, 3.0), (1.0, 3.0), (2.0, 0.2), (3.0, 0.2)]);
        for i in 0..=300 {
            let d = curve.density(i as f64 / 100.0);
            assert!((0.2 - 1e-12..=3.0 + 1e-12).contains(&d), "{d} at {i}");
        }
        // Linear interpolation would give 1.6 at the midpoint; the cubic is symmetric too.
        assert!((curve.density(1.5) - 1.6).abs() < 1e-12);
    }

    #[test]
    fn table_error_is_within_the_stated_bound() {
        for stock in catalogue().stocks() {
            for (c, layer) in LAYERS.iter().enumerate() {
                let curve = stock.layer(c);
                let table = ExposureTable::new(curve, |d| d);
                let (a, b) = curve.log_h_range();
                let mut worst = 0.0f64;
                for i in 0..20_000 {
                    let x = a - 0.2 + (b - a + 0.4) * i as f64 / 20_000.0;
                    let h = 10f64.powf(x) as f32;
                    let exact = curve.density(f64::from(h).log10());
                    worst = worst.max((table.get(h) - exact).abs());
                }
                let bound = curve.max_gradient() * (1.0 + 2f64.powi(-11)).log10() / 2.0;
                println!(
                    "{} {layer}: worst {worst:.2e} D, bound {bound:.2e} D",
                    stock.id
                );
                assert!(bound <= TABLE_MAX_ERROR_D, "{} bound {bound}", stock.id);
                assert!(
                    worst <= bound * 1.05 + 1e-12,
                    "{} worst {worst} > {bound}",
                    stock.id
                );
            }
        }
    }

    #[test]
    fn requests_parse_fractions_decimals_and_stops() {
        let r: Request = "provia400@1/2".parse().unwrap();
        assert_eq!((r.stock.as_str(), r.exposure), ("provia400", 0.5));
        assert_eq!("velvia50@0.5".parse::<Request>().unwrap().exposure, 0.5);
        assert_eq!("velvia50@-1ev".parse::<Request>().unwrap().exposure, 0.5);
        assert_eq!("velvia50@+3EV".parse::<Request>().unwrap().exposure, 8.0);
        assert_eq!("velvia50".parse::<Request>().unwrap().exposure, 1.0);
        for bad in [
            "velvia50@0",
            "velvia50@-1",
            "velvia50@x",
            "@1",
            "velvia50@1/0",
        ] {
            assert!(bad.parse::<Request>().is_err(), "{bad}");
        }
    }

    #[test]
    fn a_rising_reversal_point_is_named() {
        let text = include_str!("../curves/velvia50.toml").replace("[-1.0, 1.58]", "[-1.0, 2.90]");
        let err = Stock::from_toml(&text, Path::new("bad.toml")).unwrap_err();
        let msg = err.to_string();
        assert!(
            msg.starts_with("bad.toml: layer red, point 19 (log H -1, D 2.9): density rises"),
            "{msg}"
        );
    }

    #[test]
    fn negatives_are_refused_with_a_reason() {
        let cat = catalogue();
        let portra = cat.get("portra400").unwrap();
        let err = Development::new(portra, 1.0, 0.18, ColourMode::PerLayer).unwrap_err();
        assert!(err.to_string().contains("print"));
    }
}
