//! Printing density: what a colour paper sees of a negative, against what the data sheet's
//! densitometer (Status M) measured.
//!
//! A negative's sheet gives its characteristic curves in Status M density: each channel
//! `c` weighs the film's spectral transmittance by the Status M responsivity `M_c(λ)`
//! (ISO 5-3),
//!
//! `D_M,c = −log10( Σ_λ M_c(λ)·10^−D(λ) / Σ_λ M_c(λ) )`
//!
//! where `D(λ)` is the film's spectral diffuse density. The paper, though, is exposed
//! through the negative by its own spectral sensitivity `S_c(λ)`: the density that
//! matters for the print is the **printing density**
//!
//! `D_P,c = −log10( Σ_λ S_c(λ)·10^−D(λ) / Σ_λ S_c(λ) )`.
//!
//! The two differ because Status M's narrow bands and the paper's broader sensitivities
//! sit at different wavelengths on the dyes' (and the orange mask's) absorption flanks:
//! for Portra 400 the Status M blue density of a grey scale grows 1.2× as fast as the
//! green one, which printed as if it were printing density gives warm shadows and cool
//! highlights; the paper sees a blue density growing about as fast as the green one.
//!
//! With the sheet's spectral densities of the minimum (base, mask, fog) and of the
//! midscale neutral, each channel's ratio of printing to Status M density over the grey
//! scale is
//!
//! `s_c = (D_P,c(mid) − D_P,c(min)) / (D_M,c(mid) − D_M,c(min))`
//!
//! and a Status M density `D` on the layer's curve becomes the printing density above the
//! film's minimum `P_c = s_c·(D − D_min,c)`: the one-number-per-channel (diagonal) form of
//! the Status M → printing density conversion, exact on the midscale neutral and on the
//! grey scale as far as its spectral shape scales with density. The sums run over
//! 380–750 nm every 1 nm, where both spectra are given (linear between their samples).

use std::path::Path;
use std::sync::LazyLock;

use serde::Deserialize;

use super::{FilmError, Paper, Stock};

/// A spectral function sampled at increasing wavelengths, linear between its samples and
/// not defined outside them.
#[derive(Debug, Clone, PartialEq)]
pub struct Spectrum {
    nm: Vec<f64>,
    value: Vec<f64>,
}

/// Plausible wavelengths of a data sheet's spectral plot, nm.
const WAVELENGTH_RANGE_NM: (f64, f64) = (350.0, 800.0);

/// The wavelengths the printing-density sums run over, nm (every 1 nm).
const SUM_RANGE_NM: (u32, u32) = (380, 750);

/// The ratio of printing to Status M density a channel may have; outside it the spectral
/// data are taken to be wrong (a ratio of 1 is "the same density").
const PRINTING_RATIO_RANGE: (f64, f64) = (0.5, 2.0);

impl Spectrum {
    /// Validates `(nm, value)` pairs: at least 3, wavelengths increasing within
    /// 350–800 nm, values finite and within `range`; `field` names them in errors.
    pub(super) fn new(
        origin: &Path,
        field: &'static str,
        points: &[(f64, f64)],
        range: (f64, f64),
    ) -> Result<Spectrum, FilmError> {
        let bad = |reason: String| FilmError::Field {
            path: origin.to_path_buf(),
            field,
            reason,
        };
        if points.len() < 3 {
            return Err(bad(format!("{} points; a spectrum needs 3", points.len())));
        }
        for (i, &(nm, v)) in points.iter().enumerate() {
            if !(nm.is_finite() && (WAVELENGTH_RANGE_NM.0..=WAVELENGTH_RANGE_NM.1).contains(&nm)) {
                return Err(bad(format!(
                    "point {}: {nm} nm is outside {}..{} nm",
                    i + 1,
                    WAVELENGTH_RANGE_NM.0,
                    WAVELENGTH_RANGE_NM.1
                )));
            }
            if i > 0 && nm <= points[i - 1].0 {
                return Err(bad(format!("point {}: wavelengths must increase", i + 1)));
            }
            if !(v.is_finite() && (range.0..=range.1).contains(&v)) {
                return Err(bad(format!(
                    "point {} ({nm} nm): {v} is outside {}..{}",
                    i + 1,
                    range.0,
                    range.1
                )));
            }
        }
        Ok(Spectrum {
            nm: points.iter().map(|p| p.0).collect(),
            value: points.iter().map(|p| p.1).collect(),
        })
    }

    /// The value at `nm`, linear between samples; `None` outside them.
    pub fn at(&self, nm: f64) -> Option<f64> {
        let n = self.nm.len();
        if !(self.nm[0]..=self.nm[n - 1]).contains(&nm) {
            return None;
        }
        let i = (self.nm.partition_point(|&x| x <= nm) - 1).min(n - 2);
        let s = (nm - self.nm[i]) / (self.nm[i + 1] - self.nm[i]);
        Some(self.value[i] + s * (self.value[i + 1] - self.value[i]))
    }
}

/// A negative's spectral diffuse densities from its sheet.
#[derive(Debug, Clone, PartialEq)]
pub struct SpectralDensity {
    /// Minimum density: base, orange mask and fog.
    pub minimum: Spectrum,
    /// The midscale neutral (base included).
    pub midscale: Spectrum,
    /// The sheet it was read from.
    pub source: String,
}

/// `[spectral_density]` of a stock file: `[nm, D]` pairs.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct SpectralDensityFile {
    source: String,
    minimum: Vec<(f64, f64)>,
    midscale: Vec<(f64, f64)>,
}

/// Plausible spectral diffuse density.
const SPECTRAL_DENSITY_RANGE: (f64, f64) = (0.0, 6.0);

impl SpectralDensityFile {
    pub(super) fn check(self, origin: &Path) -> Result<SpectralDensity, FilmError> {
        Ok(SpectralDensity {
            minimum: Spectrum::new(
                origin,
                "spectral_density.minimum",
                &self.minimum,
                SPECTRAL_DENSITY_RANGE,
            )?,
            midscale: Spectrum::new(
                origin,
                "spectral_density.midscale",
                &self.midscale,
                SPECTRAL_DENSITY_RANGE,
            )?,
            source: self.source,
        })
    }
}

/// A paper's spectral sensitivity per layer, `log10` of relative sensitivity.
#[derive(Debug, Clone, PartialEq)]
pub struct Sensitivity {
    /// Red-, green- and blue-sensitive layers (cyan, magenta, yellow dye forming).
    pub layers: [Spectrum; 3],
    /// The sheet it was read from.
    pub source: String,
}

/// `[sensitivity]` of a paper file: `[nm, log10 S]` pairs per layer.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct SensitivityFile {
    source: String,
    red: Vec<(f64, f64)>,
    green: Vec<(f64, f64)>,
    blue: Vec<(f64, f64)>,
}

/// Plausible `log10` relative sensitivity (a sheet plots about four decades).
const LOG_SENSITIVITY_RANGE: (f64, f64) = (-10.0, 10.0);

impl SensitivityFile {
    pub(super) fn check(self, origin: &Path) -> Result<Sensitivity, FilmError> {
        let spectrum = |field, points: &[(f64, f64)]| {
            Spectrum::new(origin, field, points, LOG_SENSITIVITY_RANGE)
        };
        Ok(Sensitivity {
            layers: [
                spectrum("sensitivity.red", &self.red)?,
                spectrum("sensitivity.green", &self.green)?,
                spectrum("sensitivity.blue", &self.blue)?,
            ],
            source: self.source,
        })
    }
}

/// `curves/densitometry/status-m.toml`: `[nm, responsivity]` pairs per channel.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ResponsivityFile {
    #[serde(rename = "source")]
    _source: String,
    red: Vec<(f64, f64)>,
    green: Vec<(f64, f64)>,
    blue: Vec<(f64, f64)>,
}

const STATUS_M_FILE: (&str, &str) = (
    "curves/densitometry/status-m.toml",
    include_str!("../../curves/densitometry/status-m.toml"),
);

/// The Status M responsivities (ISO 5-3), parsed once per process.
static STATUS_M: LazyLock<[Spectrum; 3]> = LazyLock::new(|| {
    let (name, text) = STATUS_M_FILE;
    let origin = Path::new(name);
    let parsed = toml::from_str::<ResponsivityFile>(text)
        .map_err(|e| e.to_string())
        .and_then(|f| {
            let s = |field, p: &[(f64, f64)]| {
                Spectrum::new(origin, field, p, (0.0, 1.5)).map_err(|e| e.to_string())
            };
            Ok([
                s("red", &f.red)?,
                s("green", &f.green)?,
                s("blue", &f.blue)?,
            ])
        });
    // The file is embedded at build time and checked by the unit tests.
    parsed.unwrap_or_else(|e| panic!("built-in {name} is invalid: {e}"))
});

/// The density of spectral density `d` read through the weighting `weight` (linear):
/// `−log10(Σ w·10^−D / Σ w)` over [`SUM_RANGE_NM`] where both are given.
fn weighted_density(weight: impl Fn(f64) -> Option<f64>, d: &Spectrum) -> Option<f64> {
    let (mut num, mut den) = (0.0, 0.0);
    for nm in SUM_RANGE_NM.0..=SUM_RANGE_NM.1 {
        let nm = f64::from(nm);
        if let (Some(w), Some(density)) = (weight(nm), d.at(nm)) {
            num += w * 10f64.powf(-density);
            den += w;
        }
    }
    (den > 0.0 && num > 0.0).then(|| -(num / den).log10())
}

/// The conversion of a negative's Status M densities to the printing densities of one
/// paper: `P_c = s_c·(D − D_min,c)` (see the module's documentation).
#[derive(Debug, Clone, PartialEq)]
pub struct PrintingDensity {
    scale: [f64; 3],
    base: [f64; 3],
}

impl PrintingDensity {
    /// The conversion for `stock` printed on `paper`: `s_c` from the stock's spectral
    /// densities and the paper's sensitivity, or `s_c = 1` (Status M taken as printing
    /// density) when either file lacks its spectral data.
    pub fn new(stock: &Stock, paper: &Paper) -> Result<PrintingDensity, FilmError> {
        let base = [0, 1, 2].map(|c| stock.layer(c).d_min());
        let (Some(film), Some(sens)) = (&stock.spectral_density, &paper.sensitivity) else {
            return Ok(PrintingDensity {
                scale: [1.0; 3],
                base,
            });
        };
        let mut scale = [1.0; 3];
        for (c, s) in scale.iter_mut().enumerate() {
            let status_m = |nm: f64| STATUS_M[c].at(nm);
            let printing = |nm: f64| sens.layers[c].at(nm).map(|l| 10f64.powf(l));
            let ratio = (|| {
                let m = weighted_density(status_m, &film.midscale)?
                    - weighted_density(status_m, &film.minimum)?;
                let p = weighted_density(printing, &film.midscale)?
                    - weighted_density(printing, &film.minimum)?;
                Some(p / m)
            })();
            *s = ratio
                .filter(|r| (PRINTING_RATIO_RANGE.0..=PRINTING_RATIO_RANGE.1).contains(r))
                .ok_or_else(|| FilmError::NoData {
                    id: stock.id.clone(),
                    reason: format!(
                        "its spectral densities on paper {} give a {} printing/Status M density ratio of {ratio:?}, outside {}..{}",
                        paper.id,
                        super::LAYERS[c],
                        PRINTING_RATIO_RANGE.0,
                        PRINTING_RATIO_RANGE.1
                    ),
                })?;
        }
        Ok(PrintingDensity { scale, base })
    }

    /// `s_c` per channel: printing density per unit of Status M density.
    pub fn scale(&self) -> [f64; 3] {
        self.scale
    }

    /// The printing density above the film's minimum of Status M density `d` in layer `c`.
    pub fn of(&self, c: usize, d: f64) -> f64 {
        self.scale[c] * (d - self.base[c])
    }

    /// The Status M density in layer `c` whose printing density is `p` (the inverse of
    /// [`PrintingDensity::of`]).
    pub fn status_m(&self, c: usize, p: f64) -> f64 {
        self.base[c] + p / self.scale[c]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::film::Catalogue;

    #[test]
    fn status_m_file_is_valid_and_peaks_in_its_bands() {
        let peaks = STATUS_M.each_ref().map(|s| {
            (380..=750)
                .filter_map(|nm| s.at(f64::from(nm)).map(|v| (nm, v)))
                .fold((0u32, 0.0), |a, b| if b.1 > a.1 { b } else { a })
                .0
        });
        // ISO 5-3 Status M peaks: red 645, green 545, blue 445 nm (±10 nm as plotted).
        for (peak, nominal) in peaks.iter().zip([645, 545, 445]) {
            assert!(peak.abs_diff(nominal) <= 10, "{peaks:?}");
        }
    }

    #[test]
    fn a_flat_spectrum_reads_the_same_through_any_weighting() {
        let origin = Path::new("test");
        let flat = |d| {
            Spectrum::new(
                origin,
                "t",
                &[(380.0, d), (500.0, d), (750.0, d)],
                (0.0, 6.0),
            )
        };
        let (one, two) = (flat(0.3).unwrap(), flat(1.3).unwrap());
        for c in 0..3 {
            let w = |nm: f64| STATUS_M[c].at(nm);
            let diff = weighted_density(w, &two).unwrap() - weighted_density(w, &one).unwrap();
            assert!((diff - 1.0).abs() < 1e-12, "{diff}");
        }
    }

    #[test]
    fn builtin_negatives_convert_on_both_papers_and_slides_have_no_data() {
        let cat = Catalogue::builtin().unwrap();
        for paper in Paper::builtin() {
            for id in ["portra400", "ektar100"] {
                let stock = cat.get(id).unwrap();
                let p = PrintingDensity::new(stock, &paper).unwrap();
                println!("{id} on {}: s = {:?}", paper.id, p.scale());
                assert!(p.scale().iter().all(|s| (s - 1.0).abs() > 1e-3));
                assert!((p.status_m(2, p.of(2, 1.7)) - 1.7).abs() < 1e-12);
                assert_eq!(p.of(0, stock.layer(0).d_min()), 0.0);
            }
        }
        let slide = cat.get("velvia50").unwrap();
        assert!(slide.spectral_density.is_none());
    }

    #[test]
    fn bad_spectra_are_refused_with_their_field() {
        let origin = Path::new("x.toml");
        let err = Spectrum::new(
            origin,
            "f",
            &[(400.0, 1.0), (390.0, 1.0), (500.0, 1.0)],
            (0.0, 6.0),
        )
        .unwrap_err();
        assert!(err.to_string().contains("x.toml: f: point 2"), "{err}");
        let err = Spectrum::new(
            origin,
            "f",
            &[(400.0, 1.0), (450.0, 9.0), (500.0, 1.0)],
            (0.0, 6.0),
        )
        .unwrap_err();
        assert!(err.to_string().contains("outside"), "{err}");
    }
}
