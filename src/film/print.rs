//! Colour negatives through a print: the paper's characteristic curves and the printer's
//! light.
//!
//! A negative's layer `c` has Status M density `D_n,c(log10 H_c)` (its sheet's curve). The
//! paper sees it through its own spectral sensitivity, as the printing density above the
//! film's minimum `P_c = s_c·(D_n,c − D_min,c)` ([`super::spectral`]: `s_c` from the
//! film's spectral densities and the paper's spectral sensitivity). Each negative dye
//! layer modulates the paper layer that forms the complementary dye (the small cross-talk
//! between layers is not modelled). The paper's exposure, in log10 lux·s on the paper
//! sheet's axis, is
//!
//! `log10 H_p,c = L_c − P_c`
//!
//! where `L_c` is the printer light of channel `c` (log10, the filter pack included). The
//! print is viewed by reflection: `R_c = 10^−(D_p,c(log10 H_p,c) − D_min,p,c)`, paper
//! white being display white, and `R_c` is the linear sRGB value.
//!
//! **Setting the printer** as a printer does: the scene's key (the metered mid grey) is
//! printed at the paper's mid grey, 18 % reflectance over paper white
//! (`D_p,c = D_min,p,c + log10(1/0.18) = D_min,p,c + 0.745`), in every layer, so it is
//! neutral: `L_c = D_p,c⁻¹(D_min,p,c + 0.745) + P_c(log10 H_key,c)`. Like an automatic
//! printer that integrates the negative's density, this prints an under- or over-exposed
//! negative back to the same mid grey: the film exposure `t` shows in the tone scale's
//! shape (shadow and highlight compression), not in the print's brightness. Off the key,
//! the grey scale stays grey as far as the three layers' printing densities grow alike
//! (within 10 % for the built-in negatives on their papers; their Status M densities
//! do not: the blue grows 1.2× as fast as the green).
//!
//! **The photographer's knobs**: the print exposure `P` in stops (`L_c += log10 2^P`:
//! more printing light gives a denser, darker print) and a filter pack change in Kodak
//! CC units (density × 100) of yellow, magenta and cyan: a yellow filter of `y` CC
//! takes `y/100` from the blue light (`L_b −= y/100`), magenta from green, cyan from red.
//! Less blue light forms less yellow dye, so adding yellow makes the print bluer, as in
//! the darkroom ("add the colour of the cast").

use std::path::Path;
use std::str::FromStr;
use std::sync::LazyLock;

use serde::Deserialize;

use super::spectral::{Sensitivity, SensitivityFile};
use super::stock::{LayerFile, validate_layer};
use super::{Curve, FilmError, Kind, LAYERS};

/// Reflection density of mid grey above paper white: `log10(1/0.18)`.
const MID_GREY_DENSITY: f64 = 0.744_727_494_896_693_9;

/// A colour print paper: three reflection characteristic curves.
#[derive(Debug, Clone, PartialEq)]
pub struct Paper {
    /// Short typable id (`endura-premier`).
    pub id: String,
    /// Full name.
    pub name: String,
    /// Manufacturer.
    pub maker: String,
    /// Density measure (Status A reflection).
    pub density_measure: String,
    /// The data sheet the curves were read from.
    pub source: String,
    /// The layers' spectral sensitivity, if given: what a negative's printing density is
    /// measured by ([`super::spectral`]).
    pub sensitivity: Option<Sensitivity>,
    layers: [Curve; 3],
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct PaperFile {
    id: String,
    name: String,
    maker: String,
    density: String,
    source: String,
    layers: LayerFile,
    sensitivity: Option<SensitivityFile>,
}

/// The built-in papers, embedded at build time; the first is the default.
const BUILTIN: [(&str, &str); 2] = [
    (
        "curves/papers/endura-premier.toml",
        include_str!("../../curves/papers/endura-premier.toml"),
    ),
    (
        "curves/papers/portra-endura.toml",
        include_str!("../../curves/papers/portra-endura.toml"),
    ),
];

/// The built-in papers, parsed and validated once per process (every look that prints a
/// negative asks for its paper).
static BUILTIN_PAPERS: LazyLock<Vec<Paper>> = LazyLock::new(|| {
    BUILTIN
        .iter()
        .map(|(name, text)| {
            Paper::from_toml(text, Path::new(name))
                .unwrap_or_else(|e| panic!("built-in paper {name} is invalid: {e}"))
        })
        .collect()
});

/// The default paper's id: Kodak Endura Premier, the general-purpose RA-4 paper.
pub(crate) const DEFAULT_PAPER: &str = "endura-premier";

impl Paper {
    /// Parses and validates a paper file (density must rise with exposure, as a
    /// negative's does); `origin` names it in errors.
    pub fn from_toml(text: &str, origin: &Path) -> Result<Paper, FilmError> {
        let file: PaperFile = toml::from_str(text).map_err(|source| FilmError::Syntax {
            path: origin.to_path_buf(),
            source,
        })?;
        let layers = [file.layers.red, file.layers.green, file.layers.blue];
        for (name, points) in LAYERS.iter().zip(&layers) {
            validate_layer(origin, name, Kind::Negative, points)?;
        }
        Ok(Paper {
            id: file.id,
            name: file.name,
            maker: file.maker,
            density_measure: file.density,
            source: file.source,
            sensitivity: file.sensitivity.map(|s| s.check(origin)).transpose()?,
            layers: layers.map(|p| Curve::new(&p)),
        })
    }

    /// The built-in papers.
    pub fn builtin() -> Vec<Paper> {
        BUILTIN_PAPERS.clone()
    }

    /// The built-in paper with that id.
    pub fn get(id: &str) -> Result<Paper, FilmError> {
        BUILTIN_PAPERS
            .iter()
            .find(|p| p.id == id)
            .cloned()
            .ok_or_else(|| FilmError::UnknownPaper {
                id: id.to_string(),
                known: BUILTIN_PAPERS
                    .iter()
                    .map(|p| p.id.as_str())
                    .collect::<Vec<_>>()
                    .join(", "),
            })
    }

    /// The curve of layer 0 (red), 1 (green) or 2 (blue).
    pub fn layer(&self, index: usize) -> &Curve {
        &self.layers[index]
    }
}

/// A filter pack change in Kodak CC units (density × 100): `[cyan, magenta, yellow]`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct FilterPack(pub [f64; 3]);

/// What is wrong with a filter pack as typed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FilterError {
    /// Nothing given.
    #[error("empty filter pack: expected e.g. 10y or 05m10y")]
    Empty,
    /// A value without its filter letter.
    #[error("{0:?}: a value needs a filter letter (c m y r g b)")]
    NoLetter(String),
    /// A value that is not a number.
    #[error("{text:?}: {value:?} is not a CC value")]
    NotCc {
        /// The pack as typed.
        text: String,
        /// The value as typed.
        value: String,
    },
    /// A value beyond ±200 CC.
    #[error("{0:?}: CC values are within ±200")]
    Range(String),
    /// A letter that names no filter.
    #[error("{text:?}: unknown filter {letter:?} (c m y r g b)")]
    Letter {
        /// The pack as typed.
        text: String,
        /// The letter.
        letter: char,
    },
}

impl FromStr for FilterPack {
    type Err = FilterError;

    /// `10y`, `05m10y`, `-5c`, `20r` (red = magenta + yellow), `10g`, `10b`.
    fn from_str(text: &str) -> Result<FilterPack, FilterError> {
        let mut pack = [0.0; 3];
        let mut rest = text.trim();
        if rest.is_empty() {
            return Err(FilterError::Empty);
        }
        while !rest.is_empty() {
            let end = rest
                .find(|c: char| c.is_ascii_alphabetic())
                .ok_or_else(|| FilterError::NoLetter(text.to_string()))?;
            let value: f64 = rest[..end].parse().map_err(|_| FilterError::NotCc {
                text: text.to_string(),
                value: rest[..end].to_string(),
            })?;
            if !(value.is_finite() && value.abs() <= 200.0) {
                return Err(FilterError::Range(text.to_string()));
            }
            let letter = rest[end..].chars().next().unwrap_or('?');
            let add: [f64; 3] = match letter.to_ascii_lowercase() {
                'c' => [1.0, 0.0, 0.0],
                'm' => [0.0, 1.0, 0.0],
                'y' => [0.0, 0.0, 1.0],
                'r' => [0.0, 1.0, 1.0],
                'g' => [1.0, 0.0, 1.0],
                'b' => [1.0, 1.0, 0.0],
                letter => {
                    return Err(FilterError::Letter {
                        text: text.to_string(),
                        letter,
                    });
                }
            };
            for (p, a) in pack.iter_mut().zip(add) {
                *p += a * value;
            }
            rest = &rest[end + letter.len_utf8()..];
        }
        Ok(FilterPack(pack))
    }
}

/// How a negative is printed: the paper, the print exposure and the filter pack change
/// from the neutral setting.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct PrintSetup {
    /// The paper.
    pub paper: Paper,
    /// Print exposure in stops from the setting that prints mid grey at mid grey.
    pub exposure_stops: f64,
    /// Filter pack change (CC units) from the neutral pack.
    pub filter: FilterPack,
}

impl Default for PrintSetup {
    fn default() -> PrintSetup {
        PrintSetup {
            paper: Paper::get(DEFAULT_PAPER).unwrap_or_else(|e| panic!("{e}")),
            exposure_stops: 0.0,
            filter: FilterPack::default(),
        }
    }
}

impl PrintSetup {
    /// The printer light `L_c` (log10) per channel for a negative whose printing densities
    /// at the scene's key are `key_density`: mid grey at `D_min,p + 0.745`, plus the print
    /// exposure, minus the filter pack's density in that channel.
    pub fn printer_light(&self, key_density: [f64; 3]) -> [f64; 3] {
        [0, 1, 2].map(|c| {
            let curve = self.paper.layer(c);
            let target = curve.d_min() + MID_GREY_DENSITY;
            let x = curve
                .log_h_at(target)
                .unwrap_or_else(|| curve.log_h_range().1);
            x + key_density[c] + self.exposure_stops * std::f64::consts::LOG10_2
                - self.filter.0[c] / 100.0
        })
    }

    /// Print reflectance over paper white, `R_c = 10^−(D_p,c(L_c − P) − D_min,p,c)`, of
    /// a negative's printing density `d_neg` (`P`) in channel `c` under printer light
    /// `light` (log10).
    pub fn reflectance(&self, c: usize, light: f64, d_neg: f64) -> f64 {
        let curve = self.paper.layer(c);
        10f64.powf(-(curve.density(light - d_neg) - curve.d_min()))
    }
}
