//! `filmback films`: list the stocks, plot their characteristic curves (the report's
//! Figure 5), or make the contact sheet of the report's Figure 8 from the synthetic scene.

use std::io::Write;
use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use image::Rgb;

use filmback::atomic::Overwrite;
use filmback::film::{Catalogue, ColourMode, Key, Stock};
use filmback::rendering::Look;
use filmback::rendering::lut::{
    self, InputEncoding, LUT_MID_GREY, LutPart, LutSpec, OutputEncoding,
};
use filmback::tonemap::Operator;

use super::canvas::Canvas;

/// Arguments of `filmback films`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Print the list as JSON.
    #[arg(long)]
    json: bool,
    /// Folder of extra stock files (`*.toml`, same form as `curves/`).
    #[arg(long, value_name = "DIR")]
    curves: Option<PathBuf>,
    /// Plot density against log H per layer for this stock (repeat to overlay stocks).
    #[arg(long, value_name = "STOCK")]
    plot: Vec<String>,
    /// Render the synthetic scene as the report's Figure 8 (Provia 400 at t = 1, 1/2,
    /// 1/4, Velvia 50, Ektachrome 100, P1600 at t = 1/8, linear, histogram).
    #[arg(long, conflicts_with = "plot")]
    contact_sheet: bool,
    /// Write this film look as a 3D LUT (`.cube`): `velvia50`, `provia400@1/2`,
    /// `portra400+print=-1/3+paper=portra-endura` (per-pixel options only).
    #[arg(long, value_name = "STOCK[@t][+print=...]", conflicts_with_all = ["plot", "contact_sheet"])]
    lut: Option<String>,
    /// The LUT's grid points per axis: 33 or 65.
    #[arg(long, default_value_t = 65, requires = "lut")]
    lut_size: usize,
    /// The LUT's input encoding: linear-log (filmback's log2 shaper, working primaries),
    /// acescct (AP1), logc4 (ARRI Wide Gamut 4), slog3 (S-Gamut3.Cine).
    #[arg(long, default_value = "acescct", requires = "lut")]
    input: String,
    /// The LUT's display encoding: rec709 (BT.1886 gamma 2.4), srgb, p3 (Display P3).
    #[arg(long, default_value = "rec709", requires = "lut")]
    display: String,
    /// For a negative: two LUTs, FILE.negative.cube (scene → Cineon printing density)
    /// and FILE.print.cube (Cineon → display), instead of one.
    #[arg(long, requires = "lut")]
    split: bool,
    /// Output PNG for --plot or --contact-sheet; the .cube for --lut.
    #[arg(short, long, value_name = "FILE")]
    output: Option<PathBuf>,
}

/// Runs `filmback films`.
pub fn run(args: Args) -> Result<std::process::ExitCode> {
    let mut catalogue = Catalogue::builtin()?;
    if let Some(dir) = &args.curves {
        catalogue = catalogue.with_folder(dir)?;
    }
    if let Some(request) = &args.lut {
        return write_luts(&catalogue, request, &args);
    }
    if !args.plot.is_empty() || args.contact_sheet {
        return write_chart(&catalogue, &args);
    }
    if args.json {
        print_json(&catalogue)?;
    } else {
        print_table(&catalogue)?;
    }
    Ok(std::process::ExitCode::SUCCESS)
}

/// `--plot` or `--contact-sheet`: the PNG.
fn write_chart(catalogue: &Catalogue, args: &Args) -> Result<std::process::ExitCode> {
    let Some(output) = &args.output else {
        bail!("--plot and --contact-sheet need -o FILE.png");
    };
    let image = if args.contact_sheet {
        contact_sheet(catalogue)?
    } else {
        let stocks = args
            .plot
            .iter()
            .map(|id| catalogue.get(id))
            .collect::<Result<Vec<_>, _>>()?;
        plot(&stocks)
    };
    image
        .publish_png(output, Overwrite::Replace)
        .with_context(|| format!("writing {}", output.display()))?;
    println!("{}", output.display());
    Ok(std::process::ExitCode::SUCCESS)
}

/// `--json`: the catalogue's stocks, each with its computed speed.
fn print_json(catalogue: &Catalogue) -> Result<()> {
    let list: Vec<_> = catalogue
        .stocks()
        .iter()
        .map(|s| {
            let speed = s.speed();
            serde_json::json!({
                "id": s.id,
                "name": s.name,
                "maker": s.maker,
                "kind": s.kind,
                "iso": s.iso,
                "computed_speed": speed.map(|v| v.iso),
                "computed_minus_rated_stops": speed.map(|v| (v.iso / s.iso).log2()),
                "density": s.density_measure,
                "source": s.source,
                "uncertain": s.uncertain,
                "file": s.origin,
            })
        })
        .collect();
    println!("{}", serde_json::to_string_pretty(&list)?);
    Ok(())
}

/// The catalogue's stocks as a table, each with its computed speed and source, and how
/// the speed is computed.
fn print_table(catalogue: &Catalogue) -> Result<()> {
    let mut out = std::io::stdout().lock();
    writeln!(
        out,
        "{:<14} {:<9} {:>5} {:>9} {:>7}  {:<9} name / source",
        "id", "kind", "ISO", "computed", "stops", "density"
    )?;
    for s in catalogue.stocks() {
        let (speed, stops) = match s.speed() {
            Some(v) => (
                format!("{:.0}", v.iso),
                format!("{:+.2}", (v.iso / s.iso).log2()),
            ),
            None => ("-".into(), "-".into()),
        };
        writeln!(
            out,
            "{:<14} {:<9} {:>5} {:>9} {:>7}  {:<9} {}{}",
            s.id,
            s.kind.to_string(),
            s.iso,
            speed,
            stops,
            s.density_measure,
            s.name,
            if s.uncertain.is_some() {
                "  [uncertain]"
            } else {
                ""
            }
        )?;
        writeln!(out, "{:<60}   {}", "", s.source)?;
    }
    writeln!(
        out,
        "computed: reversal ISO 2240 from the green curve, S = 10/sqrt(H1·H2), H1 at D-min+0.2, H2 at D-min+2.0; negative ISO 5800 speed point only, S = 0.8/H at D-min+0.1"
    )?;
    Ok(())
}

/// `--lut`: the look's `.cube` (or, with `--split`, the negative's and the print's).
fn write_luts(catalogue: &Catalogue, request: &str, args: &Args) -> Result<std::process::ExitCode> {
    let Some(output) = &args.output else {
        bail!("--lut needs -o FILE.cube");
    };
    let look = Look::film(
        catalogue,
        request,
        ColourMode::PerLayer,
        Key::Grey(LUT_MID_GREY),
    )
    .with_context(|| format!("--lut {request}"))?;
    let input: InputEncoding = args.input.parse().context("--input")?;
    let display: OutputEncoding = args.display.parse().context("--display")?;
    let spec = |part| LutSpec {
        size: args.lut_size,
        input,
        output: display,
        part,
    };
    let parts: Vec<(LutPart, PathBuf)> = if args.split {
        let stem = output.with_extension("");
        vec![
            (LutPart::Negative, stem.with_extension("negative.cube")),
            (LutPart::Print, stem.with_extension("print.cube")),
        ]
    } else {
        vec![(LutPart::Whole, output.clone())]
    };
    for (part, path) in parts {
        let lut = lut::film_lut(&look, spec(part)).with_context(|| format!("--lut {request}"))?;
        lut.publish(&path, Overwrite::Replace)?;
        println!("{}", path.display());
    }
    Ok(std::process::ExitCode::SUCCESS)
}

/// Dash patterns (on, off) in pixels of path length, one per overlaid stock.
const DASHES: [(f64, f64); 4] = [(1.0, 0.0), (14.0, 7.0), (3.0, 5.0), (22.0, 6.0)];

const LAYER_COLOURS: [Rgb<u8>; 3] = [Rgb([205, 30, 30]), Rgb([20, 140, 40]), Rgb([30, 60, 210])];

/// The report's Figure 5: density against log10 H for each layer of each stock, stocks
/// told apart by dash pattern.
fn plot(stocks: &[&Stock]) -> Canvas {
    let (w, h) = (1400i64, 900i64);
    let mut img = Canvas::new(
        w as u32,
        h as u32 + 26 * stocks.len() as u32,
        Rgb([255, 255, 255]),
    );
    let chart = Chart::of(stocks, w, img.height() as i64);
    chart.draw_grid(&mut img);
    chart.draw_axes(&mut img);
    for (i, s) in stocks.iter().enumerate() {
        chart.draw_stock(&mut img, i, s);
    }
    img
}

/// Ink of the axes, ticks and labels.
const INK: Rgb<u8> = Rgb([20, 20, 20]);

/// Where [`plot`] draws: the canvas's size and margins (px) and the ranges of log10 H
/// and density it shows.
struct Chart {
    w: i64,
    h: i64,
    left: i64,
    right: i64,
    top: i64,
    bottom: i64,
    /// log10 H at the left and right of the plot area, on half units.
    x_min: f64,
    x_max: f64,
    /// Density at the top of the plot area, on half units (0 at the bottom).
    d_top: f64,
}

impl Chart {
    /// The chart of `stocks` on a canvas `w` × `h`, with a legend row per stock below
    /// the axis title: every layer's curve fits.
    fn of(stocks: &[&Stock], w: i64, h: i64) -> Chart {
        let (mut x_min, mut x_max, mut d_max) = (f64::INFINITY, f64::NEG_INFINITY, 0.0f64);
        for s in stocks {
            for c in 0..3 {
                let (a, b) = s.layer(c).log_h_range();
                x_min = x_min.min(a);
                x_max = x_max.max(b);
                d_max = d_max.max(s.layer(c).d_max());
            }
        }
        Chart {
            w,
            h,
            left: 110,
            right: 40,
            top: 70,
            bottom: 110 + 26 * stocks.len() as i64,
            x_min: (x_min * 2.0).floor() / 2.0,
            x_max: (x_max * 2.0).ceil() / 2.0,
            d_top: (d_max * 2.0).ceil() / 2.0,
        }
    }

    /// Canvas x of log10 H `x`.
    fn px(&self, x: f64) -> f64 {
        self.left as f64
            + (x - self.x_min) / (self.x_max - self.x_min)
                * (self.w - self.left - self.right) as f64
    }

    /// Canvas y of density `d`.
    fn py(&self, d: f64) -> f64 {
        (self.h - self.bottom) as f64 - d / self.d_top * (self.h - self.bottom - self.top) as f64
    }

    /// Grid lines and tick labels every 0.5 of log10 H and of density.
    fn draw_grid(&self, img: &mut Canvas) {
        let (w, h, left, right, top, bottom) =
            (self.w, self.h, self.left, self.right, self.top, self.bottom);
        let grid = Rgb([225, 225, 225]);
        let mut x = self.x_min;
        while x <= self.x_max + 1e-9 {
            let xp = self.px(x).round() as i64;
            img.fill(xp, top, 1, h - bottom - top, grid);
            img.fill(xp, h - bottom, 1, 8, INK);
            let label = format!("{x:.1}");
            img.text(
                xp - Canvas::text_width(&label, 2) / 2,
                h - bottom + 14,
                2,
                INK,
                &label,
            );
            x += 0.5;
        }
        let mut d = 0.0;
        while d <= self.d_top + 1e-9 {
            let yp = self.py(d).round() as i64;
            img.fill(left, yp, w - left - right, 1, grid);
            img.fill(left - 8, yp, 8, 1, INK);
            let label = format!("{d:.1}");
            img.text(
                left - 14 - Canvas::text_width(&label, 2),
                yp - 7,
                2,
                INK,
                &label,
            );
            d += 0.5;
        }
    }

    /// The axes, their titles and the chart's title.
    fn draw_axes(&self, img: &mut Canvas) {
        let (w, h, left, right, top, bottom) =
            (self.w, self.h, self.left, self.right, self.top, self.bottom);
        img.fill(left, top, 2, h - bottom - top + 1, INK);
        img.fill(left, h - bottom, w - left - right, 2, INK);
        let x_title = "LOG10 H (LUX·S)";
        img.text(
            left + (w - left - right - Canvas::text_width(x_title, 2)) / 2,
            h - bottom + 44,
            2,
            INK,
            x_title,
        );
        img.text(12, top - 40, 2, INK, "DENSITY D");
        let title = "CHARACTERISTIC CURVES (RED, GREEN, BLUE LAYERS)";
        img.text(
            left + (w - left - right - Canvas::text_width(title, 3)) / 2,
            16,
            3,
            INK,
            title,
        );
    }

    /// The layers' curves of stock `s`, the `i`-th, in its dash pattern, and its legend
    /// row under the axis title.
    fn draw_stock(&self, img: &mut Canvas, i: usize, s: &Stock) {
        let dash = DASHES[i % DASHES.len()];
        for (c, colour) in LAYER_COLOURS.iter().enumerate() {
            let curve = s.layer(c);
            let (a, b) = curve.log_h_range();
            let points: Vec<(f64, f64)> = (0..=600)
                .map(|k| {
                    let x = a + (b - a) * k as f64 / 600.0;
                    (self.px(x), self.py(curve.density(x)))
                })
                .collect();
            img.stroke(&points, 3, dash, *colour);
        }
        let left = self.left;
        let y = self.h - self.bottom + 80 + 26 * i as i64;
        img.stroke(
            &[
                (left as f64, y as f64 + 7.0),
                (left as f64 + 90.0, y as f64 + 7.0),
            ],
            3,
            dash,
            INK,
        );
        let label = format!(
            "{}  {}  ISO {}{}",
            s.id,
            s.name,
            s.iso,
            if s.uncertain.is_some() {
                "  (UNCERTAIN)"
            } else {
                ""
            }
        );
        img.text(left + 110, y, 2, INK, &label);
    }
}

/// The report's Figure 8 made from the synthetic scene: eight renderings of one map,
/// each labelled, in a 4 × 2 grid, and a third row: the two colour negatives printed on
/// Endura Premier, and Velvia 50 without and with grain and MTF at 6 µm per pixel (the
/// scale of a 24 MP 35 mm frame, so those two tiles are 100 % crops of such a frame).
fn contact_sheet(catalogue: &Catalogue) -> Result<Canvas> {
    let (tw, th, label_h, gap) = (480u32, 320u32, 30u32, 10u32);
    let map = filmback::synthetic::scene(tw, th, 1);
    let mut looks = Vec::new();
    for (request, label) in [
        ("provia400@1", "PROVIA 400 T=1"),
        ("provia400@1/2", "PROVIA 400 T=1/2"),
        ("provia400@1/4", "PROVIA 400 T=1/4"),
        ("velvia50@1", "VELVIA 50 T=1"),
        ("ektachrome100@1", "EKTACHROME 100 T=1"),
        ("p1600@1/8", "P1600 T=1/8"),
    ] {
        looks.push((
            Look::film(catalogue, request, ColourMode::PerLayer, Key::LogAverage)?,
            label,
        ));
    }
    looks.push((Look::Tonemap(Operator::LINEAR), "LINEAR (P1-P99)"));
    looks.push((
        Look::Tonemap(Operator::parse("histogram").expect("known operator")),
        "HISTOGRAM ADJUSTMENT",
    ));
    for (request, label) in [
        ("portra400", "PORTRA 400 PRINT"),
        ("ektar100", "EKTAR 100 PRINT"),
        ("velvia50+format=2.88mm", "VELVIA 50 1:1 (6 UM PX)"),
        (
            "velvia50+grain+mtf+format=2.88mm",
            "VELVIA 50 +GRAIN +MTF 1:1",
        ),
    ] {
        looks.push((
            Look::film(catalogue, request, ColourMode::PerLayer, Key::LogAverage)?,
            label,
        ));
    }
    let cols = 4u32;
    let rows = (looks.len() as u32).div_ceil(cols);
    let mut sheet = Canvas::new(
        cols * (tw + gap) + gap,
        rows * (th + label_h + gap) + gap,
        Rgb([24, 24, 24]),
    );
    for (i, (look, label)) in looks.iter().enumerate() {
        let display = look.render(&map, filmback::display::Depth::Eight)?;
        let rgb = display.to_u8();
        let (col, row) = (i as u32 % cols, i as u32 / cols);
        let (x0, y0) = (gap + col * (tw + gap), gap + row * (th + label_h + gap));
        sheet.paste(x0, y0, tw, th, &rgb);
        sheet.text(
            x0 as i64 + 4,
            (y0 + th + 8) as i64,
            2,
            Rgb([235, 235, 235]),
            label,
        );
    }
    Ok(sheet)
}
