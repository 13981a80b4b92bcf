//! `--plot`: the report's Figure 3 per channel (one row each): the two histograms, the
//! cumulative histograms, the intensity mapping τ, and the recovered g. Drawn on the CLI's
//! [`Canvas`] (its 5×7 bitmap font at 1×), written atomically as PNG.
//!
//! [`write_response`] draws the g panel alone, per channel, for any [`InverseResponse`]
//! (`filmback cache show --plot`); both figures share [`draw_response`] and [`publish_png`],
//! so the panels look the same and the file is published under the same policy.

use std::path::Path;

use filmback::atomic::Overwrite;
use filmback::histogram::Histogram;
use filmback::response::{Calibration, InverseResponse};
use image::Rgb;

use crate::cli::canvas::Canvas;

const PANEL_W: u32 = 300;
const PANEL_H: u32 = 230;
const LEFT: u32 = 34;
const RIGHT: u32 = 10;
const TOP: u32 = 22;
const BOTTOM: u32 = 22;
const DARK: Rgb<u8> = Rgb([30, 90, 200]);
const BRIGHT: Rgb<u8> = Rgb([230, 120, 20]);
const INK: Rgb<u8> = Rgb([20, 20, 20]);
const GRID: Rgb<u8> = Rgb([215, 215, 215]);
const COVERED: Rgb<u8> = Rgb([225, 245, 225]);
/// Curve colours of the R, G and B channels in [`write_response`].
const CHANNEL: [Rgb<u8>; 3] = [Rgb([210, 30, 30]), Rgb([20, 150, 40]), Rgb([30, 60, 220])];
/// Curve colour of a single-channel (grey) response in [`write_response`].
const GREY: Rgb<u8> = Rgb([110, 110, 110]);
/// Height of the title strip above the panels of [`write_response`].
const HEADER: u32 = 26;
/// Whether a plot may replace an existing file: yes, like `-o` (a plot is a view of data
/// kept elsewhere, so regenerating it in place is the normal use).
const PLOT_OVERWRITE: Overwrite = Overwrite::Replace;

/// One panel's plotting area: maps `[0,1]²` to pixels.
struct Panel {
    x0: f64,
    y0: f64,
    w: f64,
    h: f64,
}

impl Panel {
    /// The panel in column `col` and row `row` of a grid of `PANEL_W × PANEL_H` cells
    /// starting `top` pixels below the image's top edge.
    fn cell(col: u32, row: u32, top: u32) -> Panel {
        Panel {
            x0: f64::from(col * PANEL_W + LEFT),
            y0: f64::from(top + row * PANEL_H + TOP),
            w: f64::from(PANEL_W - LEFT - RIGHT),
            h: f64::from(PANEL_H - TOP - BOTTOM),
        }
    }

    fn at(&self, u: f64, v: f64) -> (f64, f64) {
        (
            self.x0 + u.clamp(0.0, 1.0) * self.w,
            self.y0 + (1.0 - v.clamp(0.0, 1.0)) * self.h,
        )
    }

    fn frame(&self, canvas: &mut Canvas, title: &str) {
        for t in [0.0, 0.25, 0.5, 0.75, 1.0] {
            canvas.line(self.at(t, 0.0), self.at(t, 1.0), GRID);
            canvas.line(self.at(0.0, t), self.at(1.0, t), GRID);
        }
        canvas.line(self.at(0.0, 0.0), self.at(1.0, 0.0), INK);
        canvas.line(self.at(0.0, 0.0), self.at(0.0, 1.0), INK);
        for (t, label) in [(0.0, "0"), (0.5, "0.5"), (1.0, "1")] {
            let (x, y) = self.at(t, 0.0);
            let w = Canvas::text_width(label, 1);
            canvas.text(x as i64 - w / 2, y as i64 + 5, 1, INK, label);
            let (x, y) = self.at(0.0, t);
            canvas.text(x as i64 - w - 4, y as i64 - 3, 1, INK, label);
        }
        canvas.text(self.x0 as i64, self.y0 as i64 - 18, 1, INK, title);
    }

    fn polyline(&self, canvas: &mut Canvas, points: &[(f64, f64)], colour: Rgb<u8>) {
        for w in points.windows(2) {
            canvas.line(self.at(w[0].0, w[0].1), self.at(w[1].0, w[1].1), colour);
        }
    }
}

/// Draws the g panel of channel `c` of `response` into `p`: the `covered` tone range
/// shaded (outside it the curve is extrapolated), grid, axes, labels, `title`, and
/// `g_c(B)` sampled at 401 points in `colour`.
fn draw_response(
    canvas: &mut Canvas,
    p: &Panel,
    response: &InverseResponse,
    c: usize,
    title: &str,
    colour: Rgb<u8>,
    covered: Option<(f64, f64)>,
) {
    if let Some((lo, hi)) = covered {
        let (xa, _) = p.at(lo, 0.0);
        let (xb, _) = p.at(hi, 0.0);
        let (x, y) = (xa as i64, p.y0 as i64);
        canvas.fill(x, y, xb as i64 - x + 1, p.h as i64, COVERED);
    }
    p.frame(canvas, title);
    let pts: Vec<(f64, f64)> = (0..=400)
        .map(|i| {
            let b = f64::from(i) / 400.0;
            (b, response.eval(c, b))
        })
        .collect();
    p.polyline(canvas, &pts, colour);
}

/// Publishes `canvas` as PNG atomically at `path` (replacing a file there).
fn publish_png(path: &Path, canvas: &Canvas) -> anyhow::Result<()> {
    // The error's own text already carries the path and the OS reason; as a message it is
    // printed once (as a source it would be repeated by `{:#}`).
    canvas
        .publish_png(path, PLOT_OVERWRITE)
        .map_err(|e| anyhow::anyhow!("writing the plot: {e}"))
}

/// Draws the figure and publishes it atomically at `path`.
pub fn write(
    path: &Path,
    dark: &Histogram,
    bright: &Histogram,
    cal: &Calibration,
) -> anyhow::Result<()> {
    let rows = cal.channels.len() as u32;
    let mut canvas = Canvas::new(4 * PANEL_W, rows * PANEL_H, Rgb([255, 255, 255]));
    for (c, ch) in cal.channels.iter().enumerate() {
        let panel = |i: u32| Panel::cell(i, c as u32, 0);
        let (ca, cb) = (dark.cumulative(c), bright.cumulative(c));
        // 1. Histograms, scaled to the 99th-percentile bin so clipping spikes stay visible
        //    without flattening the rest.
        let p = panel(0);
        p.frame(&mut canvas, &format!("{} HISTOGRAMS", ch.name));
        canvas.text(p.x0 as i64 + 150, p.y0 as i64 + 4, 1, DARK, "DARK");
        canvas.text(p.x0 as i64 + 150, p.y0 as i64 + 16, 1, BRIGHT, "BRIGHT");
        let mut all: Vec<u64> = ca.counts().iter().chain(cb.counts()).copied().collect();
        all.sort_unstable();
        let top = all[(all.len() - 1) * 99 / 100].max(1) as f64;
        for (cum, colour) in [(&ca, DARK), (&cb, BRIGHT)] {
            let e = cum.edges();
            let pts: Vec<(f64, f64)> = cum
                .counts()
                .iter()
                .enumerate()
                .map(|(k, &n)| (0.5 * (e[k] + e[k + 1]), n as f64 / top))
                .collect();
            p.polyline(&mut canvas, &pts, colour);
        }
        // 2. Cumulative histograms.
        let p = panel(1);
        p.frame(&mut canvas, "CUMULATIVE H(B)");
        for (cum, colour) in [(&ca, DARK), (&cb, BRIGHT)] {
            let pts: Vec<(f64, f64)> = cum
                .edges()
                .iter()
                .zip(cum.at_edges())
                .map(|(&b, &h)| (b, h))
                .collect();
            p.polyline(&mut canvas, &pts, colour);
        }
        // 3. τ: each tone pair as a dot, over the diagonal.
        let p = panel(2);
        p.frame(&mut canvas, "TAU: DARK B TO BRIGHT B");
        p.polyline(&mut canvas, &[(0.0, 0.0), (1.0, 1.0)], GRID);
        for pair in &ch.pairs {
            let (x, y) = p.at(pair.dark, pair.bright);
            canvas.fill(x as i64, y as i64, 2, 2, INK);
        }
        // 4. g, with the covered tone range shaded (outside it: extrapolated).
        let title = match ch.borrowed_from {
            Some(d) => format!("G(B) BORROWED FROM {d}"),
            None => format!("G(B) CONF {:.2}", ch.fit.confidence),
        };
        let covered = ch.borrowed_from.is_none().then_some(ch.fit.covered);
        draw_response(
            &mut canvas,
            &panel(3),
            &cal.response,
            c,
            &title,
            INK,
            covered,
        );
    }
    publish_png(path, &canvas)
}

/// Draws `response` as g panels, one per channel side by side (R, G and B curves in their
/// colours, a single channel in grey), under `title`, and publishes the PNG atomically at
/// `path` (replacing a file there, as `calibrate --plot` does).
///
/// The image is `channels × 300` pixels wide (wider if `title` needs it) and 256 high.
pub fn write_response(path: &Path, response: &InverseResponse, title: &str) -> anyhow::Result<()> {
    let channels = response.channels();
    let names: &[&str] = if channels == 1 {
        &["Y"]
    } else {
        &["R", "G", "B"]
    };
    let title_w = LEFT + Canvas::text_width(title, 1).max(0) as u32 + RIGHT;
    let width = (channels as u32 * PANEL_W).max(title_w);
    let mut canvas = Canvas::new(width, HEADER + PANEL_H, Rgb([255, 255, 255]));
    canvas.text(i64::from(LEFT), 8, 1, INK, title);
    for c in 0..channels {
        let colour = if channels == 1 { GREY } else { CHANNEL[c % 3] };
        let name = names.get(c).copied().unwrap_or("?");
        draw_response(
            &mut canvas,
            &Panel::cell(c as u32, 0, HEADER),
            response,
            c,
            &format!("{name} G(B)"),
            colour,
            None,
        );
    }
    publish_png(path, &canvas)
}
