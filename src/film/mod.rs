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
//! A negative stock is rendered through a print ([`mod@print`]): its densities filter the
//! printer's light onto a colour paper's curves, and the print is viewed by reflection.
//!
//! Options of a look (`velvia50+grain+mtf`, [`Options`]): grain from the sheet's RMS
//! granularity ([`grain`]), the sheet's MTF and halation ([`optics`]), the film format
//! that sets the pixel's size at film scale, and for negatives the paper, print exposure
//! and filter pack.

mod emulsion;
pub mod grain;
pub mod optics;
pub mod print;
pub mod spectral;
mod stock;

use std::fmt;
use std::path::PathBuf;
use std::str::FromStr;

use serde::Deserialize;

pub use emulsion::{
    ColourMode, Emulsion, ExposureTable, Key, LatentImage, TABLE_MAX_ERROR_D, UnknownColourMode,
    render, scene_key,
};
pub(crate) use print::PrintSetup;
pub use print::{FilterError, FilterPack, Paper};
pub use spectral::PrintingDensity;
pub use stock::{Catalogue, Curve, DensityReference, Granularity, Mtf, Speed, Stock};

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
    #[error("{path}: {source}")]
    Syntax {
        /// The stock file.
        path: PathBuf,
        /// The parser's error, with line and column.
        #[source]
        source: toml::de::Error,
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
    /// No paper has that id.
    #[error("unknown print paper {id:?} (known: {known})")]
    UnknownPaper {
        /// The id asked for.
        id: String,
        /// The ids available.
        known: String,
    },
    /// An option asks for data the stock's sheet does not give.
    #[error("{id}: {reason}")]
    NoData {
        /// The stock's id.
        id: String,
        /// What is missing.
        reason: String,
    },
    /// A rendering request such as `velvia50@1/2` that does not parse.
    #[error("film request {text:?}: {source}")]
    Request {
        /// The request as typed.
        text: String,
        /// What is wrong with it.
        source: RequestError,
    },
}

/// What is wrong with a film request's exposure or options.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RequestError {
    /// Nothing before `@`.
    #[error("no stock id before '@'")]
    NoStock,
    /// An exposure in stops that is not a number.
    #[error("{0:?} is not a number of stops such as -1ev")]
    Stops(String),
    /// An exposure fraction whose numerator or denominator is not a number.
    #[error("{text:?}: bad {part}")]
    Fraction {
        /// As typed.
        text: String,
        /// `numerator` or `denominator`.
        part: &'static str,
    },
    /// An exposure that is not a number.
    #[error("{0:?} is not an exposure such as 0.5, 1/2 or -1ev")]
    Exposure(String),
    /// An exposure outside `1e-6 ..= 1e6`.
    #[error("exposure {0:?} must be a positive factor between 1e-6 and 1e6")]
    ExposureRange(String),
    /// An option given twice.
    #[error("+{0} is given twice")]
    Twice(String),
    /// An option given without the value it needs (the message says which).
    #[error("{0}")]
    Missing(&'static str),
    /// A numeric option given without its value.
    #[error("{0} needs a value ({0}=…)")]
    NeedsValue(String),
    /// A numeric option's value that is not a number.
    #[error("{name}={value}: not a number")]
    NotANumber {
        /// The option.
        name: String,
        /// As typed.
        value: String,
    },
    /// A numeric option's value outside its range.
    #[error("{name}={value}: must be within {lo}..={hi}")]
    Outside {
        /// The option.
        name: String,
        /// As typed.
        value: String,
        /// Least allowed.
        lo: f64,
        /// Greatest allowed.
        hi: f64,
    },
    /// A film format that is none of the known ones nor a width in mm.
    #[error("format={0}: expected 35mm, 645, 6x6, 6x7, 4x5 or Nmm (1–1000)")]
    Format(String),
    /// A grain seed that is not an integer.
    #[error("seed={0}: not an integer")]
    Seed(String),
    /// A print exposure that does not parse or exceeds ±6 stops.
    #[error("print={value}: {problem}")]
    Print {
        /// As typed.
        value: String,
        /// What is wrong.
        problem: &'static str,
    },
    /// A filter pack that does not parse.
    #[error(transparent)]
    Filter(#[from] FilterError),
    /// An option filmback does not know.
    #[error(
        "unknown option {0:?}: expected grain, mtf, halation, format=, seed=, paper=, print=, cc="
    )]
    Unknown(String),
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

/// A rendering request as typed: `velvia50`, `provia400@0.5`, `p1600@1/8`, `velvia50@+1ev`,
/// with options after `+`: `velvia50+grain+mtf`, `portra400@1/2+print=-1/3ev+cc=05y`.
#[derive(Debug, Clone, PartialEq)]
pub struct Request {
    /// Stock id.
    pub stock: String,
    /// Relative exposure `t` (1 = metered; 1/2 = one stop less).
    pub exposure: f64,
    /// Grain, sharpness, format and print options.
    pub options: Options,
}

/// The options of a film look, each typed as `+name` or `+name=value` after the stock.
///
/// | option | meaning | default |
/// |---|---|---|
/// | `grain`, `grain=G` | grain from the sheet's RMS granularity, `G` times as strong | off |
/// | `mtf` | the sheet's MTF per layer at the format's scale | off |
/// | `halation`, `halation=S` | red halo of strength `S` around highlights | off; `S` = 0.1 |
/// | `format=F` | film format: `35mm` (36 mm long side), `645`, `6x6`, `6x7`, `4x5`, or `Nmm` | `35mm` |
/// | `seed=N` | the grain's seed | 1 |
/// | `paper=ID` | print paper for a negative (`endura-premier`, `portra-endura`) | `endura-premier` |
/// | `print=P` | print exposure in stops (`+1/3`, `-0.5`, `-1ev`): more is a darker print | 0 |
/// | `cc=F` | filter pack change in CC units: `10y`, `05m10y`, `-5c` | none |
#[derive(Debug, Clone, PartialEq)]
pub struct Options {
    /// Grain strength (1 = the sheet), if on.
    pub grain: Option<f64>,
    /// Apply the sheet's MTF.
    pub mtf: bool,
    /// Halation strength, if on.
    pub halation: Option<f64>,
    /// The film format's long side, mm (36 for 35 mm).
    pub format_mm: f64,
    /// The grain's seed.
    pub seed: u64,
    /// Print paper id (negatives).
    pub paper: String,
    /// Print exposure, stops (negatives).
    pub print_stops: f64,
    /// Filter pack change (negatives).
    pub filter: FilterPack,
    /// The options as typed, for file names (`+grain+mtf`, `+print=-1_3`): a `/` (from a
    /// fraction) becomes `_`, since it would name a folder.
    pub label: String,
}

impl Options {
    /// Whether the options spread light between pixels (MTF, halation): such a look is
    /// developed from the whole map at once, not pixel by pixel.
    pub(crate) fn has_optics(&self) -> bool {
        self.mtf || self.halation.is_some()
    }
}

impl Default for Options {
    fn default() -> Options {
        Options {
            grain: None,
            mtf: false,
            halation: None,
            format_mm: 36.0,
            seed: 1,
            paper: print::DEFAULT_PAPER.to_string(),
            print_stops: 0.0,
            filter: FilterPack::default(),
            label: String::new(),
        }
    }
}

/// Default halation strength for `+halation`: about what a film without its
/// anti-halation layer shows around a bare bulb.
pub const DEFAULT_HALATION: f64 = 0.1;

/// The number `v` of option `name`, which must lie in `[lo, hi]`.
fn option_number(name: &str, v: Option<&str>, lo: f64, hi: f64) -> Result<f64, RequestError> {
    let v = v.ok_or_else(|| RequestError::NeedsValue(name.to_string()))?;
    let (name, value) = (name.to_string(), v.to_string());
    let x: f64 = v.parse().map_err(|_| RequestError::NotANumber {
        name: name.clone(),
        value: value.clone(),
    })?;
    if x.is_finite() && (lo..=hi).contains(&x) {
        Ok(x)
    } else {
        Err(RequestError::Outside {
            name,
            value,
            lo,
            hi,
        })
    }
}

/// The long side in mm of the film format `value` of `+format=`: a named format
/// (`35mm` or `135`, `645`, `6x6` or `120`, `6x7`, `4x5`) or `<mm>mm` within 1–1000 mm.
fn format_mm(value: Option<&str>) -> Result<f64, RequestError> {
    let v = value.ok_or(RequestError::Missing(
        "format needs a value such as 35mm or 6x7",
    ))?;
    Ok(match v {
        "35mm" | "135" => 36.0,
        "645" => 56.0,
        "6x6" | "120" => 56.0,
        "6x7" => 70.0,
        "4x5" => 120.0,
        mm => mm
            .strip_suffix("mm")
            .and_then(|n| n.parse::<f64>().ok())
            .filter(|n| n.is_finite() && (1.0..=1000.0).contains(n))
            .ok_or_else(|| RequestError::Format(v.to_string()))?,
    })
}

impl Options {
    /// Parses the options after the stock (each without its `+`).
    pub fn parse<'a>(items: impl IntoIterator<Item = &'a str>) -> Result<Options, RequestError> {
        let mut o = Options::default();
        let mut labels = Vec::new();
        let mut seen: Vec<&str> = Vec::new();
        for item in items {
            let (name, value) = match item.split_once('=') {
                Some((n, v)) => (n, Some(v)),
                None => (item, None),
            };
            if seen.contains(&name) {
                return Err(RequestError::Twice(name.to_string()));
            }
            seen.push(name);
            let number = |v: Option<&str>, lo: f64, hi: f64| option_number(name, v, lo, hi);
            match name {
                "grain" => {
                    o.grain = Some(match value {
                        None => 1.0,
                        v => number(v, 0.0, 20.0)?,
                    })
                }
                "mtf" if value.is_none() => o.mtf = true,
                "halation" => {
                    o.halation = Some(match value {
                        None => DEFAULT_HALATION,
                        v => number(v, 0.0, 10.0)?,
                    })
                }
                "format" => o.format_mm = format_mm(value)?,
                "seed" => {
                    let v = value.ok_or(RequestError::Missing("seed needs a value"))?;
                    o.seed = v.parse().map_err(|_| RequestError::Seed(v.to_string()))?;
                }
                "paper" => {
                    o.paper = value
                        .ok_or(RequestError::Missing("paper needs an id"))?
                        .to_string()
                }
                "print" => {
                    let v = value.ok_or(RequestError::Missing("print needs stops such as -1/3"))?;
                    o.print_stops = print_stops(v)?;
                }
                "cc" => {
                    o.filter = value
                        .ok_or(RequestError::Missing("cc needs filters such as 10y"))?
                        .parse()?
                }
                _ => return Err(RequestError::Unknown(item.to_string())),
            }
            labels.push(item.to_string());
        }
        o.label = labels
            .iter()
            .map(|l| format!("+{}", l.replace('/', "_")))
            .collect();
        Ok(o)
    }

    /// The print setup these options ask for.
    pub(crate) fn print_setup(&self) -> Result<PrintSetup, FilmError> {
        Ok(PrintSetup {
            paper: Paper::get(&self.paper)?,
            exposure_stops: self.print_stops,
            filter: self.filter,
        })
    }
}

/// A print exposure in stops: `-1/3`, `0.5`, `+1ev`, within ±6.
fn print_stops(v: &str) -> Result<f64, RequestError> {
    let value = v.trim_end_matches("ev").trim_end_matches("EV");
    let problem = |problem| RequestError::Print {
        value: value.to_string(),
        problem,
    };
    let stops = if let Some((n, d)) = value.split_once('/') {
        let n: f64 = n.parse().map_err(|_| problem("bad numerator"))?;
        let d: f64 = d.parse().map_err(|_| problem("bad denominator"))?;
        n / d
    } else {
        value
            .parse()
            .map_err(|_| problem("not a number of stops"))?
    };
    if !(stops.is_finite() && stops.abs() <= 6.0) {
        return Err(problem("within ±6 stops"));
    }
    Ok(stops)
}

impl FromStr for Request {
    type Err = FilmError;

    fn from_str(text: &str) -> Result<Request, FilmError> {
        // Options start at a '+' followed by a letter ('+' before a digit is a sign).
        let bytes = text.as_bytes();
        let cut = (0..bytes.len())
            .find(|&i| bytes[i] == b'+' && bytes.get(i + 1).is_some_and(u8::is_ascii_alphabetic))
            .unwrap_or(text.len());
        let (head, tail) = text.split_at(cut);
        let mut items = Vec::new();
        let mut rest = tail;
        while let Some(r) = rest.strip_prefix('+') {
            let bytes = r.as_bytes();
            let end = (0..bytes.len())
                .find(|&i| {
                    bytes[i] == b'+' && bytes.get(i + 1).is_some_and(u8::is_ascii_alphabetic)
                })
                .unwrap_or(r.len());
            items.push(&r[..end]);
            rest = &r[end..];
        }
        let options = Options::parse(items).map_err(|source| FilmError::Request {
            text: text.to_string(),
            source,
        })?;
        let text_all = text;
        let text = head;
        let (stock, exposure) = match text.split_once('@') {
            None => (text, 1.0),
            Some((stock, t)) => (
                stock,
                parse_exposure(t).map_err(|source| FilmError::Request {
                    text: text_all.to_string(),
                    source,
                })?,
            ),
        };
        if stock.is_empty() {
            return Err(FilmError::Request {
                text: text_all.to_string(),
                source: RequestError::NoStock,
            });
        }
        Ok(Request {
            stock: stock.to_string(),
            exposure,
            options,
        })
    }
}

/// Parses a relative exposure: `0.5`, `1/2`, `8`, `-1ev`, `+2EV` (`t = 2^ev`).
fn parse_exposure(text: &str) -> Result<f64, RequestError> {
    let lower = text.trim().to_ascii_lowercase();
    let fraction = |part| RequestError::Fraction {
        text: text.to_string(),
        part,
    };
    let t = if let Some(ev) = lower.strip_suffix("ev") {
        let ev: f64 = ev
            .trim()
            .parse()
            .map_err(|_| RequestError::Stops(text.to_string()))?;
        2f64.powf(ev)
    } else if let Some((n, d)) = lower.split_once('/') {
        let n: f64 = n.trim().parse().map_err(|_| fraction("numerator"))?;
        let d: f64 = d.trim().parse().map_err(|_| fraction("denominator"))?;
        n / d
    } else {
        lower
            .parse()
            .map_err(|_| RequestError::Exposure(text.to_string()))?
    };
    if t.is_finite() && t > 0.0 && (1e-6..=1e6).contains(&t) {
        Ok(t)
    } else {
        Err(RequestError::ExposureRange(text.to_string()))
    }
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use super::*;

    fn catalogue() -> Catalogue {
        Catalogue::builtin().expect("built-in stocks load")
    }

    /// The log-average key of a 4 MP map (over a million samples) is the same, to the last
    /// bit, on one thread and on four: a rendering does not depend on the machine.
    #[test]
    fn the_key_is_the_same_on_any_number_of_threads() {
        let (w, h) = (2048u32, 2048u32);
        let pixels: Vec<f32> = (0..w * h * 3)
            .map(|i| 1e-3 + ((i as f32 * 0.618_034).fract()).powi(3) * 50.0)
            .collect();
        let map = crate::radiance::RadianceMap::new(w, h, 3, pixels).unwrap();
        let on = |threads| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| scene_key(&map, Key::LogAverage))
        };
        assert_eq!(on(1).to_bits(), on(4).to_bits());
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
        let text =
            include_str!("../../curves/velvia50.toml").replace("[-1.0, 1.58]", "[-1.0, 2.90]");
        let err = Stock::from_toml(&text, Path::new("bad.toml")).unwrap_err();
        let msg = err.to_string();
        assert!(
            msg.starts_with("bad.toml: layer red, point 19 (log H -1, D 2.9): density rises"),
            "{msg}"
        );
    }

    #[test]
    fn options_parse_and_name_the_look() {
        let r: Request = "portra400@+1ev+print=-1/3ev+cc=05m10y+paper=portra-endura"
            .parse()
            .unwrap();
        assert_eq!((r.stock.as_str(), r.exposure), ("portra400", 2.0));
        assert!((r.options.print_stops + 1.0 / 3.0).abs() < 1e-12);
        assert_eq!(r.options.filter, FilterPack([0.0, 5.0, 10.0]));
        assert_eq!(r.options.paper, "portra-endura");
        assert_eq!(
            r.options.label,
            "+print=-1_3ev+cc=05m10y+paper=portra-endura"
        );
        let r: Request = "velvia50+grain=2+mtf+halation+format=6x7".parse().unwrap();
        assert_eq!(r.exposure, 1.0);
        assert_eq!(r.options.grain, Some(2.0));
        assert!(r.options.mtf);
        assert_eq!(r.options.halation, Some(DEFAULT_HALATION));
        assert_eq!(r.options.format_mm, 70.0);
        assert_eq!(
            "20r".parse::<FilterPack>().unwrap(),
            FilterPack([0.0, 20.0, 20.0])
        );
        for bad in [
            "velvia50+grainy",
            "velvia50+grain=x",
            "velvia50+format=9x9",
            "portra400+cc=10q",
            "portra400+print=9",
            "velvia50+mtf=2",
            "velvia50+grain+grain=2",
            "portra400+print=1+print=-1",
        ] {
            assert!(bad.parse::<Request>().is_err(), "{bad}");
        }
    }

    #[test]
    fn options_a_sheet_cannot_support_are_refused_with_a_reason() {
        let cat = catalogue();
        let portra = cat.get("portra400").unwrap();
        let grain: Request = "portra400+grain".parse().unwrap();
        let err = Emulsion::with_options(
            portra,
            1.0,
            0.18,
            ColourMode::PerLayer,
            &grain.options,
            (600, 400),
        )
        .unwrap_err();
        assert!(err.to_string().contains("RMS granularity"), "{err}");
        let paper: Request = "portra400+paper=crystal".parse().unwrap();
        let err = Emulsion::with_options(
            portra,
            1.0,
            0.18,
            ColourMode::PerLayer,
            &paper.options,
            (600, 400),
        )
        .unwrap_err();
        assert!(err.to_string().contains("endura-premier"), "{err}");
        let p1600 = cat.get("p1600").unwrap();
        let mtf: Request = "p1600+mtf".parse().unwrap();
        assert!(
            Emulsion::with_options(
                p1600,
                1.0,
                0.18,
                ColourMode::PerLayer,
                &mtf.options,
                (600, 400)
            )
            .is_err()
        );
    }
}
