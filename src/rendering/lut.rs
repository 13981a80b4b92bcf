//! Film looks as 3D LUTs (`.cube`, the Resolve / IRIDAS format) for grading software,
//! OpenColorIO and monitor LUT boxes.
//!
//! A LUT maps an input code value `v ∈ [0, 1]³` of a camera or grading encoding to a
//! display code value. Per grid point:
//!
//! 1. decode: `E_in = decode(v)` per channel, scene-linear in the encoding's gamut
//!    ([`InputEncoding`], each from its published formula);
//! 2. `E = M · E_in`, the gamut converted to filmback's working primaries (linear
//!    Rec. 709, D65; Bradford adaptation where the white differs, as for ACES);
//! 3. the film look, exactly as filmback renders a radiance map, metered on
//!    [`LUT_MID_GREY`]: scene-linear 0.18 (a neutral 18 % grey card in the input
//!    encoding) lands on the stock's metered exposure `8/S` (times `t`), so a negative
//!    prints it at 18 % reflectance;
//! 4. the display light (linear Rec. 709) converted to the output gamut and encoded
//!    ([`OutputEncoding`]).
//!
//! Only what a film does per pixel is in a LUT: grain, MTF and halation spread light
//! between pixels or depend on the position, so looks asking for them are refused, and
//! the tone maps (`linear`, `histogram`) measure the whole image, so they cannot be a
//! LUT at all.
//!
//! A negative and its print may also be two LUTs ([`LutPart`]): the negative's printing
//! density as Cineon code values (Kodak's printing-density encoding: 0.002 D per code
//! value of 1023, the film's minimum at code 95), then the print from those codes.

use std::io::{self, Write};
use std::path::Path;

use super::{Look, RenderingError};
use crate::atomic::{self, Overwrite, PublishError};
use crate::display::Depth;
use crate::film::{self, Key, Kind, PrintingDensity, Stock};
pub use crate::radiance::Gamut;
use crate::radiance::{RadianceMap, apply_matrix};

/// The scene-linear value that is the stock's metered mid grey in every LUT: an 18 %
/// grey card.
pub const LUT_MID_GREY: f64 = 0.18;

/// The grid sizes offered: 33³ (monitor boxes, quick previews) and 65³ (grading).
pub const LUT_SIZES: [usize; 2] = [33, 65];

/// Stops below and above [`LUT_MID_GREY`] that the scene-linear log shaper covers.
pub const LINEAR_LOG_STOPS: (f64, f64) = (-10.0, 8.0);

/// Cineon printing density: density per code value, and the film minimum's code value
/// (of 1023).
const CINEON_DENSITY_PER_CODE: f64 = 0.002;
/// The film minimum's Cineon code value.
const CINEON_BASE_CODE: f64 = 95.0;

/// The LUT's input: a shaper from code value to scene-linear light, and its gamut.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum InputEncoding {
    /// filmback's own log shaper over working-primaries linear light:
    /// `E = 0.18 · 2^(lo + v·(hi − lo))` with `(lo, hi)` = [`LINEAR_LOG_STOPS`].
    LinearLog,
    /// ACEScct (Academy S-2016-001), AP1 gamut.
    AcesCct,
    /// ARRI LogC4 (ARRI LogC4 specification), ARRI Wide Gamut 4.
    LogC4,
    /// Sony S-Log3 (Sony's technical summary), S-Gamut3.Cine.
    SLog3,
}

// ACEScct constants (S-2016-001).
const CCT_A: f64 = 10.540_237_741_654_5;
const CCT_B: f64 = 0.072_905_534_195_835_5;
const CCT_X_BREAK: f64 = 0.007_812_5;
const CCT_Y_BREAK: f64 = 0.155_251_141_552_511;

/// ARRI LogC4's constants `(a, b, c, s, t)` from the specification:
/// `a = (2¹⁸ − 16)/117.45`, `b = (1023 − 95)/1023`, `c = 95/1023`,
/// `s = 7·ln 2·2^(7 − 14c/b)/(a·b)`, `t = (2^(14·(−c/b) + 6) − 64)/a`.
fn logc4_constants() -> (f64, f64, f64, f64, f64) {
    let a = (2f64.powi(18) - 16.0) / 117.45;
    let b = (1023.0 - 95.0) / 1023.0;
    let c = 95.0 / 1023.0;
    let s = (7.0 * std::f64::consts::LN_2 * 2f64.powf(7.0 - 14.0 * c / b)) / (a * b);
    let t = (2f64.powf(14.0 * (-c / b) + 6.0) - 64.0) / a;
    (a, b, c, s, t)
}

// S-Log3 constants (Sony's technical summary), in 10-bit code values.
const SLOG3_BREAK_CODE: f64 = 171.210_294_692_9;

impl InputEncoding {
    /// Scene-linear light of code value `v`.
    ///
    /// - ACEScct: `v ≤ 0.155251…`: `(v − 0.0729055…)/10.5402377…`; else `2^(17.52·v − 9.72)`.
    /// - LogC4: `v ≥ 0`: `(2^(14(v − c)/b + 6) − 64)/a`; else `v·s + t`.
    /// - S-Log3: `1023v ≥ 171.2102946929`: `10^((1023v − 420)/261.5)·0.19 − 0.01`;
    ///   else `(1023v − 95)·0.01125/(171.2102946929 − 95)`.
    pub fn decode(self, v: f64) -> f64 {
        match self {
            InputEncoding::LinearLog => {
                let (lo, hi) = LINEAR_LOG_STOPS;
                LUT_MID_GREY * (lo + v * (hi - lo)).exp2()
            }
            InputEncoding::AcesCct => {
                if v <= CCT_Y_BREAK {
                    (v - CCT_B) / CCT_A
                } else {
                    (17.52 * v - 9.72).exp2()
                }
            }
            InputEncoding::LogC4 => {
                let (a, b, c, s, t) = logc4_constants();
                if v >= 0.0 {
                    ((14.0 * (v - c) / b + 6.0).exp2() - 64.0) / a
                } else {
                    v * s + t
                }
            }
            InputEncoding::SLog3 => {
                let code = 1023.0 * v;
                if code >= SLOG3_BREAK_CODE {
                    10f64.powf((code - 420.0) / 261.5) * (0.18 + 0.01) - 0.01
                } else {
                    (code - 95.0) * 0.01125 / (SLOG3_BREAK_CODE - 95.0)
                }
            }
        }
    }

    /// The code value of scene-linear light `e` (the inverse of [`InputEncoding::decode`]).
    pub fn encode(self, e: f64) -> f64 {
        match self {
            InputEncoding::LinearLog => {
                let (lo, hi) = LINEAR_LOG_STOPS;
                ((e.max(f64::MIN_POSITIVE) / LUT_MID_GREY).log2() - lo) / (hi - lo)
            }
            InputEncoding::AcesCct => {
                if e <= CCT_X_BREAK {
                    CCT_A * e + CCT_B
                } else {
                    (e.log2() + 9.72) / 17.52
                }
            }
            InputEncoding::LogC4 => {
                let (a, b, c, s, t) = logc4_constants();
                if e >= t {
                    ((a * e + 64.0).log2() - 6.0) / 14.0 * b + c
                } else {
                    (e - t) / s
                }
            }
            InputEncoding::SLog3 => {
                if e >= 0.01125 {
                    (420.0 + ((e + 0.01) / (0.18 + 0.01)).log10() * 261.5) / 1023.0
                } else {
                    (e * (SLOG3_BREAK_CODE - 95.0) / 0.01125 + 95.0) / 1023.0
                }
            }
        }
    }

    /// The encoding's gamut.
    pub fn gamut(self) -> Gamut {
        match self {
            InputEncoding::LinearLog => Gamut::REC709,
            InputEncoding::AcesCct => Gamut::AP1,
            InputEncoding::LogC4 => Gamut::AWG4,
            InputEncoding::SLog3 => Gamut::SGAMUT3_CINE,
        }
    }

    /// The name as typed (`acescct`).
    pub fn name(self) -> &'static str {
        match self {
            InputEncoding::LinearLog => "linear-log",
            InputEncoding::AcesCct => "acescct",
            InputEncoding::LogC4 => "logc4",
            InputEncoding::SLog3 => "slog3",
        }
    }

    /// What it is, for the file's comment.
    fn describe(self) -> String {
        match self {
            InputEncoding::LinearLog => format!(
                "filmback linear-log: E = 0.18 * 2^({} + v*{}), linear Rec. 709 primaries, D65",
                LINEAR_LOG_STOPS.0,
                LINEAR_LOG_STOPS.1 - LINEAR_LOG_STOPS.0
            ),
            InputEncoding::AcesCct => "ACEScct (Academy S-2016-001), ACES AP1 primaries".into(),
            InputEncoding::LogC4 => "ARRI LogC4, ARRI Wide Gamut 4".into(),
            InputEncoding::SLog3 => "Sony S-Log3, S-Gamut3.Cine".into(),
        }
    }
}

impl std::str::FromStr for InputEncoding {
    type Err = RenderingError;

    fn from_str(text: &str) -> Result<InputEncoding, RenderingError> {
        [
            InputEncoding::LinearLog,
            InputEncoding::AcesCct,
            InputEncoding::LogC4,
            InputEncoding::SLog3,
        ]
        .into_iter()
        .find(|e| e.name() == text.trim().to_ascii_lowercase())
        .ok_or_else(|| RenderingError::Parse {
            text: text.to_string(),
            reason: "unknown LUT input: expected linear-log, acescct, logc4 or slog3".into(),
        })
    }
}

/// The LUT's output: a display's primaries and encoding.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OutputEncoding {
    /// Rec. 709 primaries, ITU-R BT.1886 display (`V = L^(1/2.4)`, black at 0): a grading
    /// monitor.
    Rec709,
    /// sRGB (IEC 61966-2.1 transfer function), Rec. 709 primaries: a computer display.
    Srgb,
    /// Display P3: P3 primaries, D65, the sRGB transfer function.
    P3,
}

impl OutputEncoding {
    /// The code value of linear display light `l ∈ [0, 1]` (clamped).
    pub fn encode(self, l: f64) -> f64 {
        let l = l.clamp(0.0, 1.0);
        match self {
            OutputEncoding::Rec709 => l.powf(1.0 / 2.4),
            OutputEncoding::Srgb | OutputEncoding::P3 => srgb_encode(l),
        }
    }

    /// Linear display light of code value `v` (the inverse of [`OutputEncoding::encode`]).
    pub fn decode(self, v: f64) -> f64 {
        match self {
            OutputEncoding::Rec709 => v.max(0.0).powf(2.4),
            OutputEncoding::Srgb | OutputEncoding::P3 => srgb_decode(v),
        }
    }

    /// The display's gamut.
    pub fn gamut(self) -> Gamut {
        match self {
            OutputEncoding::Rec709 | OutputEncoding::Srgb => Gamut::REC709,
            OutputEncoding::P3 => Gamut::DISPLAY_P3,
        }
    }

    /// The name as typed (`rec709`).
    pub fn name(self) -> &'static str {
        match self {
            OutputEncoding::Rec709 => "rec709",
            OutputEncoding::Srgb => "srgb",
            OutputEncoding::P3 => "p3",
        }
    }

    fn describe(self) -> &'static str {
        match self {
            OutputEncoding::Rec709 => "Rec. 709 primaries, BT.1886 gamma 2.4 (black 0)",
            OutputEncoding::Srgb => "sRGB (IEC 61966-2.1)",
            OutputEncoding::P3 => "Display P3 (P3 primaries, D65, sRGB transfer function)",
        }
    }
}

impl std::str::FromStr for OutputEncoding {
    type Err = RenderingError;

    fn from_str(text: &str) -> Result<OutputEncoding, RenderingError> {
        [
            OutputEncoding::Rec709,
            OutputEncoding::Srgb,
            OutputEncoding::P3,
        ]
        .into_iter()
        .find(|e| e.name() == text.trim().to_ascii_lowercase())
        .ok_or_else(|| RenderingError::Parse {
            text: text.to_string(),
            reason: "unknown LUT output: expected rec709, srgb or p3".into(),
        })
    }
}

/// IEC 61966-2.1 encoding in `f64` (the LUT's values are written with 6 decimals).
fn srgb_encode(l: f64) -> f64 {
    if l <= 0.003_130_8 {
        12.92 * l
    } else {
        1.055 * l.powf(1.0 / 2.4) - 0.055
    }
}

fn srgb_decode(v: f64) -> f64 {
    if v <= 0.040_45 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

/// Which part of a negative-and-print look a LUT holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LutPart {
    /// Scene to display: the whole look (a negative with its print).
    Whole,
    /// Scene to the negative's printing density as Cineon code values
    /// (`(95 + P/0.002)/1023` per channel, `P` above the film's minimum).
    Negative,
    /// Cineon printing-density code values to display: the print.
    Print,
}

/// How a LUT is made.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LutSpec {
    /// Grid points per axis (one of [`LUT_SIZES`]).
    pub size: usize,
    /// The input encoding (ignored for [`LutPart::Print`], whose input is Cineon).
    pub input: InputEncoding,
    /// The display encoding (ignored for [`LutPart::Negative`]).
    pub output: OutputEncoding,
    /// What the LUT holds.
    pub part: LutPart,
}

/// A 3D LUT: `size³` RGB entries, red fastest, and the comment lines of its file.
#[derive(Debug, Clone, PartialEq)]
pub struct Lut {
    /// `TITLE`.
    pub title: String,
    /// Comment lines (without `#`).
    pub comments: Vec<String>,
    /// Grid points per axis.
    pub size: usize,
    /// Entries, index `r + size·(g + size·b)`.
    pub table: Vec<[f32; 3]>,
}

impl Lut {
    /// The grid's code values along one axis: `i/(size − 1)`.
    fn axis(size: usize) -> impl Iterator<Item = f64> {
        (0..size).map(move |i| i as f64 / (size - 1) as f64)
    }

    /// Every grid point's input code `[r, g, b]`, red fastest.
    fn grid(size: usize) -> impl Iterator<Item = [f64; 3]> {
        Lut::axis(size).flat_map(move |b| {
            Lut::axis(size).flat_map(move |g| Lut::axis(size).map(move |r| [r, g, b]))
        })
    }

    /// Writes the Resolve / IRIDAS `.cube` text: comments, `TITLE`, `LUT_3D_SIZE`,
    /// `DOMAIN_MIN 0 0 0`, `DOMAIN_MAX 1 1 1`, then one `R G B` line per entry, red
    /// fastest.
    pub fn write_cube(&self, out: &mut impl Write) -> io::Result<()> {
        for line in &self.comments {
            writeln!(out, "# {line}")?;
        }
        writeln!(out, "TITLE \"{}\"", self.title.replace('"', "'"))?;
        writeln!(out, "LUT_3D_SIZE {}", self.size)?;
        writeln!(out, "DOMAIN_MIN 0.0 0.0 0.0")?;
        writeln!(out, "DOMAIN_MAX 1.0 1.0 1.0")?;
        for [r, g, b] in &self.table {
            writeln!(out, "{r:.6} {g:.6} {b:.6}")?;
        }
        Ok(())
    }

    /// Writes the `.cube` file at `path`, atomically.
    pub fn publish(&self, path: &Path, overwrite: Overwrite) -> Result<(), RenderingError> {
        atomic::publish_with(path, overwrite, |w| {
            self.write_cube(w).map_err(|source| {
                RenderingError::from(PublishError::Io {
                    path: path.to_path_buf(),
                    source,
                })
            })
        })
    }

    /// The LUT at input code `v` by trilinear interpolation (the `.cube` convention;
    /// inputs clamped to the domain).
    pub fn apply(&self, v: [f64; 3]) -> [f64; 3] {
        let n = self.size;
        let top = (n - 1) as f64;
        let pos = v.map(|x| (x.clamp(0.0, 1.0) * top).min(top));
        let i0 = pos.map(|p| (p.floor() as usize).min(n - 2));
        let f = [0, 1, 2].map(|c| pos[c] - i0[c] as f64);
        let mut out = [0.0; 3];
        for corner in 0..8 {
            let bit = |c: usize| (corner >> c) & 1;
            let w: f64 = (0..3)
                .map(|c| if bit(c) == 1 { f[c] } else { 1.0 - f[c] })
                .product();
            let idx = (i0[0] + bit(0)) + n * ((i0[1] + bit(1)) + n * (i0[2] + bit(2)));
            for (o, t) in out.iter_mut().zip(self.table[idx]) {
                *o += w * f64::from(t);
            }
        }
        out
    }
}

/// The LUT of a film `look` (from [`Look::film`], metered on anything: the LUT meters
/// on [`LUT_MID_GREY`]). Refused for tone maps, for looks with grain, MTF or halation,
/// for a grid size not in [`LUT_SIZES`], and for a split of a slide.
pub fn film_lut(look: &Look, spec: LutSpec) -> Result<Lut, RenderingError> {
    let refuse = |reason: &str| RenderingError::Parse {
        text: look.name(),
        reason: reason.to_string(),
    };
    let Look::Film {
        stock,
        exposure,
        colour,
        options,
        ..
    } = look
    else {
        return Err(refuse(
            "a tone map measures the whole image (percentiles, histogram), so it is not a per-pixel look and cannot be a LUT",
        ));
    };
    if options.grain.is_some() || options.has_optics() {
        return Err(refuse(
            "grain, MTF and halation are spatial (they depend on neighbouring pixels and the position), so they cannot be in a LUT: ask for the look without them",
        ));
    }
    if !LUT_SIZES.contains(&spec.size) {
        return Err(refuse(&format!("LUT size {} is not 33 or 65", spec.size)));
    }
    let size = spec.size;
    let lut_look = Look::Film {
        stock: stock.clone(),
        exposure: *exposure,
        colour: *colour,
        key: Key::Grey(LUT_MID_GREY),
        options: options.clone(),
    };
    let to_working = spec.input.gamut().matrix_to(Gamut::REC709);
    let scene = |v: [f64; 3]| apply_matrix(&to_working, v.map(|x| spec.input.decode(x)));
    let table = match spec.part {
        LutPart::Whole => whole_table(&lut_look, &grid_map(look, size, &scene)?, spec.output)?,
        LutPart::Negative | LutPart::Print => {
            let map = grid_map(look, size, &scene)?;
            let emulsion = lut_look.emulsion(&map)?;
            let (Some(light), Some(printing)) =
                (emulsion.printer_light(), emulsion.printing_density())
            else {
                return Err(refuse("only a negative splits into a negative and a print"));
            };
            let print = options.print_setup()?;
            if spec.part == LutPart::Negative {
                negative_table(stock, &emulsion.scale, printing, size, &scene)
            } else {
                print_table(&print, light, spec.output, size)
            }
        }
    };
    Ok(Lut {
        title: format!("filmback {}{}", look.name(), part_label(spec.part)),
        comments: comments(stock, *exposure, spec),
        size,
        table,
    })
}

/// The grid of a LUT of `size` points per axis, each point mapped by `f`, as a map of
/// `size²` × `size` pixels for `look` to render.
fn grid_map(
    look: &Look,
    size: usize,
    f: &dyn Fn([f64; 3]) -> [f64; 3],
) -> Result<RadianceMap, RenderingError> {
    let pixels: Vec<f32> = Lut::grid(size)
        .flat_map(|v| f(v).map(|x| x as f32))
        .collect();
    RadianceMap::new((size * size) as u32, size as u32, 3, pixels).map_err(|source| {
        RenderingError::Grid {
            look: look.name(),
            source,
        }
    })
}

/// The whole look's table: `look` rendered of the grid `map` at 16 bits, decoded from
/// sRGB to linear Rec. 709, converted to the `output`'s gamut and encoded by it.
fn whole_table(
    look: &Look,
    map: &RadianceMap,
    output: OutputEncoding,
) -> Result<Vec<[f32; 3]>, RenderingError> {
    let img = look.render(map, Depth::Sixteen)?;
    let to_display = Gamut::REC709.matrix_to(output.gamut());
    Ok(img
        .samples()
        .chunks_exact(3)
        .map(|px| {
            let linear = [0, 1, 2].map(|c| srgb_decode(f64::from(px[c]) / 65535.0));
            apply_matrix(&to_display, linear).map(|l| output.encode(l) as f32)
        })
        .collect())
}

/// Cineon code of printing density `p` (above the film's minimum), `(95 + p/0.002)/1023`.
fn cineon_code(p: f64) -> f64 {
    ((CINEON_BASE_CODE + p / CINEON_DENSITY_PER_CODE) / 1023.0).clamp(0.0, 1.0)
}

/// Printing density above the film's minimum of Cineon code `v` (inverse of
/// [`cineon_code`]).
fn cineon_density(v: f64) -> f64 {
    (v * 1023.0 - CINEON_BASE_CODE) * CINEON_DENSITY_PER_CODE
}

/// Scene code → the negative's printing density (Cineon codes), from the layer curves
/// directly: `P_c = s_c·(D_c(log10(scale_c·E_c)) − D_min,c)`.
fn negative_table(
    stock: &Stock,
    scale: &[f32; 3],
    printing: &PrintingDensity,
    size: usize,
    scene: &dyn Fn([f64; 3]) -> [f64; 3],
) -> Vec<[f32; 3]> {
    Lut::grid(size)
        .map(|v| {
            let e = scene(v);
            [0, 1, 2].map(|c| {
                let h = f64::from(scale[c]) * e[c].max(0.0);
                let d = stock.layer(c).density(h.log10());
                cineon_code(printing.of(c, d)) as f32
            })
        })
        .collect()
}

/// Cineon printing-density codes → the print's display code, per channel.
fn print_table(
    print: &film::PrintSetup,
    light: [f64; 3],
    output: OutputEncoding,
    size: usize,
) -> Vec<[f32; 3]> {
    let to_display = Gamut::REC709.matrix_to(output.gamut());
    Lut::grid(size)
        .map(|v| {
            let linear = [0, 1, 2].map(|c| print.reflectance(c, light[c], cineon_density(v[c])));
            apply_matrix(&to_display, linear).map(|l| output.encode(l) as f32)
        })
        .collect()
}

fn part_label(part: LutPart) -> &'static str {
    match part {
        LutPart::Whole => "",
        LutPart::Negative => " (negative)",
        LutPart::Print => " (print)",
    }
}

/// The file's comment: what goes in, what comes out, the exposure convention, and what
/// is not in it.
fn comments(stock: &Stock, exposure: f64, spec: LutSpec) -> Vec<String> {
    let input = match spec.part {
        LutPart::Print => format!(
            "input: Cineon printing density of the {} negative ({CINEON_DENSITY_PER_CODE} D per code value of 1023, film minimum at code {CINEON_BASE_CODE})",
            stock.name
        ),
        _ => format!("input: {}", spec.input.describe()),
    };
    let output = match spec.part {
        LutPart::Negative => {
            "output: the negative's printing density as Cineon code values (0.002 D per code value of 1023, film minimum at 95)".to_string()
        }
        _ => format!("output: {}", spec.output.describe()),
    };
    let mut lines = vec![
        format!(
            "filmback {}: {} ({}), data sheet: {}",
            env!("CARGO_PKG_VERSION"),
            stock.name,
            stock.kind,
            stock.source
        ),
        input,
        output,
        format!(
            "exposure: scene-linear {LUT_MID_GREY} (an 18% grey card; input code {:.4}) is the stock's metered mid grey 8/ISO lux*s, times t = {exposure}",
            spec.input.encode(LUT_MID_GREY)
        ),
        "per-pixel only: grain, MTF and halation are spatial and are not in this LUT".into(),
    ];
    if stock.kind == Kind::Negative && spec.part != LutPart::Negative {
        lines.push("the negative is printed with the printer set to print that mid grey at 18% reflectance, neutral".into());
    }
    lines
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shapers_round_trip_and_put_mid_grey_at_their_published_codes() {
        // Published mid-grey codes: ACEScct 0.4135 (S-2016-001), LogC4 0.2784 (ARRI),
        // S-Log3 420/1023 (Sony).
        let published = [
            (InputEncoding::AcesCct, 0.413_588),
            (InputEncoding::LogC4, 0.278_396),
            (InputEncoding::SLog3, 420.0 / 1023.0),
            (InputEncoding::LinearLog, 10.0 / 18.0),
        ];
        for (enc, code) in published {
            assert!(
                (enc.encode(0.18) - code).abs() < 2e-4,
                "{enc:?} {}",
                enc.encode(0.18)
            );
            for v in [0.0, 0.05, 0.1, 0.3, 0.5, 0.8, 1.0] {
                let back = enc.encode(enc.decode(v));
                assert!((back - v).abs() < 1e-9, "{enc:?} {v} → {back}");
            }
        }
    }

    #[test]
    fn gamut_matrices_keep_neutrals_and_invert() {
        for g in [
            Gamut::AP1,
            Gamut::AWG4,
            Gamut::SGAMUT3_CINE,
            Gamut::DISPLAY_P3,
        ] {
            let there = g.matrix_to(Gamut::REC709);
            let back = Gamut::REC709.matrix_to(g);
            let grey = apply_matrix(&there, [0.5; 3]);
            assert!(
                grey.iter().all(|v| (v - 0.5).abs() < 1e-4),
                "{g:?} {grey:?}"
            );
            let x = apply_matrix(&back, apply_matrix(&there, [0.2, 0.5, 0.9]));
            assert!((0..3).all(|c| (x[c] - [0.2, 0.5, 0.9][c]).abs() < 1e-9));
        }
        // Rec. 709 red in P3 (the published matrix's first column: 0.8225, 0.0332, 0.0171).
        let red = apply_matrix(&Gamut::REC709.matrix_to(Gamut::DISPLAY_P3), [1.0, 0.0, 0.0]);
        for (got, want) in red.iter().zip([0.8225, 0.0332, 0.0171]) {
            assert!((got - want).abs() < 1e-3, "{red:?}");
        }
    }

    #[test]
    fn cineon_codes_round_trip() {
        for p in [0.0, 0.5, 1.2] {
            assert!((cineon_density(cineon_code(p)) - p).abs() < 1e-12);
        }
        assert!((cineon_code(0.0) * 1023.0 - 95.0).abs() < 1e-9);
    }

    #[test]
    fn trilinear_apply_reproduces_the_grid_and_is_linear_between() {
        let size = 33;
        let table = Lut::grid(size)
            .map(|v| [v[0] as f32, (0.5 * v[1]) as f32, (v[2] * v[2]) as f32])
            .collect();
        let lut = Lut {
            title: String::new(),
            comments: vec![],
            size,
            table,
        };
        let at = lut.apply([0.25, 0.5, 1.0]);
        assert!((at[0] - 0.25).abs() < 1e-6 && (at[1] - 0.25).abs() < 1e-6);
        assert!((at[2] - 1.0).abs() < 1e-6);
    }
}
