//! Demosaicking a merged mosaic into linear output RGB, in one pass with the white
//! balance before it and the colour matrix and exposure scale after it.
//!
//! # Bayer sensors: Patterned Pixel Grouping
//!
//! Written from Chuan-kai Lin's published description of *Pixel Grouping* ("Demosaic:
//! Pixel Grouping", 2003, rewritten 2010). With the 5×5 neighbourhood of a pixel numbered
//! row by row `1 … 25` (the pixel itself is 13, its north neighbour 8, its north-east
//! diagonal 9):
//!
//! 1. **Green at red and blue pixels.** With `C` the pixel's own colour, the gradients
//!    `ΔN = 2|C13 − C3| + |G8 − G18|`, `ΔS = 2|C13 − C23| + |G8 − G18|`,
//!    `ΔE = 2|C13 − C15| + |G12 − G14|`, `ΔW = 2|C13 − C11| + |G12 − G14|`; along the
//!    smallest (ties: N, E, W, S), e.g. north `G13 = (3·G8 + G18 + C13 − C3)/4`.
//! 2. **Red and blue at green pixels**, from the colour on each side and the green plane:
//!    `hue_transit(L1, L2, L3, V1, V3)` is `V1 + (V3 − V1)·(L2 − L1)/(L3 − L1)` when `L2`
//!    lies strictly between `L1` and `L3`, else `(V1 + V3)/2 + (2·L2 − L1 − L3)/4`; the
//!    horizontal neighbours' colour is `hue_transit(G12, G13, G14, V12, V14)`, the
//!    vertical neighbours' `hue_transit(G8, G13, G18, V8, V18)`.
//! 3. **Blue at red pixels (and red at blue)**, from the diagonal of the smaller gradient:
//!    `ΔNE = |V9 − V17| + |C5 − C13| + |C13 − C21| + |G9 − G13| + |G13 − G17|`, `ΔNW` the
//!    same on the other diagonal (`7, 19, 1, 25`); if `ΔNE < ΔNW`,
//!    `V13 = hue_transit(G9, G13, G17, V9, V17)`, else the same along `7, 19`.
//!
//! Steps 2 and 3 read only the mosaic and the green of step 1, so the image is cut into
//! bands of rows, each developed on its own core from a working copy of its rows and a
//! three-row apron (step 1 needs the mosaic two rows beyond the green it makes, steps 2
//! and 3 the green one row beyond the band). Beyond the image's edges the mosaic is
//! mirrored about the edge pixel (`x = −k` reads `x = k`), which keeps the CFA's colours
//! in place, so edge pixels are interpolated like any other.
//!
//! A working row is kept as two halves, its even and its odd columns: in a Bayer row each
//! half is one colour, so every step is a loop over the pixels of one colour at unit
//! stride, whose neighbours are the same or the other half shifted by a value, and the
//! compiler turns it into vector instructions. A row's output is made per half, three
//! planes of colour, in chunks of 256 pixel pairs (in the first-level cache), and then
//! interleaved.
//!
//! # X-Trans sensors
//!
//! The 6×6 X-Trans mosaic is interpolated by rawler's bilinear demosaicker (its
//! Markesteijn demosaicker panics in rawler 0.8), the white balance before it and the
//! matrix on every core while its pixels are copied out.
//!
//! # The pass
//!
//! Each band reads the merged mosaic `v`, white-balances it (`v·gain[colour]`, so that the
//! interpolation sees neutral edges as neutral), interpolates, and writes
//! `out = M · (r, g, b)` with `M` the camera → output matrix already multiplied by the
//! exposure scale: interleaved RGB, `width × height × 3` values, in the units of the
//! mosaic times `M`'s.

use rayon::prelude::*;

use super::Cfa;
use super::mosaic::MosaicRows;

/// Rows of output per band: the working copies of a band (mosaic and green, `BAND + 6`
/// rows each) stay within a core's cache for rows of a few thousand pixels.
const BAND: usize = 16;

/// Rows of apron above and below a band's working copy: the green of step 1 is needed one
/// row beyond the band and reads the mosaic two rows beyond that.
const PAD: usize = 3;

/// Columns of apron left and right of a working row before it is split into its even and
/// odd columns: the three columns that step 1 reads beyond the image (as [`PAD`] rows),
/// and one more so that both halves start at an even column (`x = −4` and `x = −3`).
const APRON: usize = 4;

/// Pixel pairs per chunk of a row whose RGB is made before it is interleaved: the six
/// planes of a chunk stay in the first-level cache.
const CHUNK: usize = 256;

/// Which interpolator [`demosaic`] uses for `cfa`.
pub fn method(cfa: &Cfa) -> &'static str {
    if cfa.width == 6 {
        "bilinear (X-Trans, rawler)"
    } else {
        "PPG (patterned pixel grouping, Lin)"
    }
}

/// Interpolates the two missing colours of every pixel of `mosaic` (laid out as `cfa`,
/// read row by row, so a [`super::mosaic::Merge`] is merged as the bands need it) after
/// multiplying each sample by `gains[colour]`, and applies the 3×3 matrix `to_output`
/// (row-major, `out_r = Σ_c m[r][c]·in_c`, the exposure scale folded in) to each pixel:
/// interleaved RGB, `width × height × 3`, and the samples clipped in every frame. See
/// the module docs.
pub fn demosaic<S: MosaicRows>(
    mosaic: &S,
    cfa: &Cfa,
    gains: [f32; 3],
    to_output: &[[f32; 3]; 3],
) -> (Vec<f32>, u64) {
    if cfa.width == 2 && cfa.height == 2 {
        bayer(mosaic, cfa, gains, to_output)
    } else {
        xtrans(mosaic, cfa, gains, to_output)
    }
}

/// The identity matrix, for [`demosaic`] to camera RGB.
pub const CAMERA_RGB: [[f32; 3]; 3] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

/// No white balance: every gain 1.
pub const UNBALANCED: [f32; 3] = [1.0; 3];

/// `i` mirrored into `0..n` about the first and last pixel (`−k → k`, `n − 1 + k →
/// n − 1 − k`), clamped when `n` is too small to mirror.
fn mirror(i: isize, n: usize) -> usize {
    let last = n as isize - 1;
    let i = if i < 0 { -i } else { i };
    let i = if i > last { 2 * last - i } else { i };
    i.clamp(0, last.max(0)) as usize
}

/// What a pixel of the 2×2 tile is: green (with the colours of its horizontal and
/// vertical neighbours) or red/blue (with its own colour).
#[derive(Debug, Clone, Copy)]
enum Site {
    Green { across: usize, down: usize },
    Chroma { own: usize },
}

impl Site {
    /// The columns of `matrix` that the site's three values are multiplied by: for green,
    /// its own sample, the interpolated horizontal and vertical neighbours' colours; for
    /// red or blue, its own sample, the green and the other colour.
    fn columns(self, matrix: &[[f32; 3]; 3]) -> [[f32; 3]; 3] {
        let column = |c: usize| [matrix[0][c], matrix[1][c], matrix[2][c]];
        match self {
            Site::Green { across, down } => [column(1), column(across), column(down)],
            Site::Chroma { own } => [column(own), column(1), column(2 - own)],
        }
    }
}

/// The site of each position `[y & 1][x & 1]` of the tile.
fn sites(cfa: &Cfa) -> [[Site; 2]; 2] {
    // Colours beyond blue (none in a tile decode accepts) read as blue.
    let at = |x: usize, y: usize| cfa.colour_at(x, y).min(2);
    [0, 1].map(|y| {
        [0, 1].map(|x| match at(x, y) {
            1 => Site::Green {
                across: at(x + 1, y),
                down: at(x, y + 1),
            },
            own => Site::Chroma { own },
        })
    })
}

/// A band's working copies, each working row split into its even and its odd image
/// columns (two *halves* of `half` values, half `p` at `(2r + p)·half`, value `k` of half
/// `p` being image column `x = 2k − APRON + p`), so that every step reads pixels of one
/// colour at unit stride: the white-balanced mosaic and the green plane, `rows + 2·PAD`
/// working rows, row `r` holding image row `y0 + r − PAD`. Besides: one row before it is
/// split, the six planes (three colours, two halves) of a chunk of output, and the
/// source's working memory.
struct Band {
    half: usize,
    mosaic: Vec<f32>,
    green: Vec<f32>,
    line: Vec<f32>,
    rgb: Vec<f32>,
    scratch: Vec<f32>,
}

impl Band {
    fn new(width: usize) -> Band {
        let half = (width + 2 * APRON).div_ceil(2);
        let len = 2 * half * (BAND + 2 * PAD);
        Band {
            half,
            mosaic: vec![0.0; len],
            green: vec![0.0; len],
            line: vec![0.0; 2 * half],
            rgb: vec![0.0; 6 * CHUNK],
            scratch: Vec::new(),
        }
    }

    /// Reads image row `y` (mirrored beyond the image) of `source` into working row `r`,
    /// each sample times its colour's gain, the row mirrored into its apron columns and
    /// split into its halves. Returns the row's samples clipped in every frame when `y`
    /// is one of `own` (so that rows read twice, as aprons or mirrors, are counted once).
    fn load_row<S: MosaicRows>(
        &mut self,
        source: &S,
        r: usize,
        y: isize,
        own: &std::ops::Range<usize>,
        cfa: &Cfa,
        gains: [f32; 3],
    ) -> u64 {
        let w = source.width();
        let y_in = mirror(y, source.height());
        let line = &mut self.line;
        let clipped = source.row(y_in, &mut line[APRON..APRON + w], &mut self.scratch);
        let g = [gains[cfa.colour_at(0, y_in)], gains[cfa.colour_at(1, y_in)]];
        let mut pairs = line[APRON..APRON + w].chunks_exact_mut(2);
        for pair in &mut pairs {
            pair[0] *= g[0];
            pair[1] *= g[1];
        }
        for v in pairs.into_remainder() {
            *v *= g[0];
        }
        // Image column x is line[APRON + x]; the apron reads its mirror.
        for j in (0..APRON).chain(APRON + w..line.len()) {
            let x = j as isize - APRON as isize;
            line[j] = line[APRON + mirror(x, w)];
        }
        let (even, odd) =
            self.mosaic[2 * r * self.half..2 * (r + 1) * self.half].split_at_mut(self.half);
        for ((pair, e), o) in line.chunks_exact(2).zip(even).zip(odd) {
            *e = pair[0];
            *o = pair[1];
        }
        if y >= 0 && own.contains(&(y as usize)) {
            clipped
        } else {
            0
        }
    }
}

/// `n` values of half `p` of working row `r` of `plane` (halves of `half` values, see
/// [`Band`]) from value `start`.
#[inline(always)]
fn run(plane: &[f32], half: usize, r: usize, p: usize, start: usize, n: usize) -> &[f32] {
    let at = (2 * r + p) * half + start;
    &plane[at..at + n]
}

/// `hue_transit` of Lin's description (module docs, step 2): `v1 … v3` carried along the
/// green `l1 … l3`. Both branches are computed and one is selected, without a jump.
#[inline(always)]
fn hue_transit(l1: f32, l2: f32, l3: f32, v1: f32, v3: f32) -> f32 {
    let (d1, d3) = (l2 - l1, l3 - l2);
    let between = (d1 > 0.0) & (d3 > 0.0) | (d1 < 0.0) & (d3 < 0.0);
    let along = v1 + (v3 - v1) * d1 / (l3 - l1);
    let mean = (v1 + v3) * 0.5 + (d1 - d3) * 0.25;
    if between { along } else { mean }
}

/// Step 1 at a red or blue sample `c`, from its own colour two pixels north, south, west
/// and east (`[c3, c23, c11, c15]`) and the green beside it (`[g8, g18, g12, g14]`).
#[inline(always)]
fn ppg_green(c: f32, [cn, cs, cw, ce]: [f32; 4], [gn, gs, gw, ge]: [f32; 4]) -> f32 {
    let vertical = (gn - gs).abs();
    let horizontal = (gw - ge).abs();
    let dn = 2.0 * (c - cn).abs() + vertical;
    let ds = 2.0 * (c - cs).abs() + vertical;
    let de = 2.0 * (c - ce).abs() + horizontal;
    let dw = 2.0 * (c - cw).abs() + horizontal;
    // Ties go to the first of N, E, W, S.
    let (mut best, mut value) = (dn, 3.0 * gn + gs + c - cn);
    let east = 3.0 * ge + gw + c - ce;
    let west = 3.0 * gw + ge + c - cw;
    let south = 3.0 * gs + gn + c - cs;
    if de < best {
        (best, value) = (de, east);
    }
    if dw < best {
        (best, value) = (dw, west);
    }
    if ds < best {
        value = south;
    }
    value * 0.25
}

/// Step 1 on working row `r` of the band's mosaic `m` into its green plane `green`
/// (halves of `half` values, see [`Band`]): half `p` of the green is the mosaic's where
/// the row is green, else `ppg_green` of every value but the first and last of the half
/// (their neighbours lie beyond the working row). Separate slices, so that the compiler
/// knows the green written is not the mosaic read.
fn green_row(m: &[f32], green: &mut [f32], half: usize, row_sites: &[Site; 2], r: usize) {
    for (p, site) in row_sites.iter().enumerate() {
        let dst = &mut green[(2 * r + p) * half..(2 * r + p + 1) * half];
        match site {
            Site::Green { .. } => dst.copy_from_slice(run(m, half, r, p, 0, half)),
            Site::Chroma { .. } => {
                let n = half - 2;
                // Value k of half p, image column x; x ± 1 is value k − 1 + p and k + p
                // of the other half.
                let c = run(m, half, r, p, 1, n);
                let (cw, ce) = (run(m, half, r, p, 0, n), run(m, half, r, p, 2, n));
                let (cn, cs) = (run(m, half, r - 2, p, 1, n), run(m, half, r + 2, p, 1, n));
                let (gn, gs) = (run(m, half, r - 1, p, 1, n), run(m, half, r + 1, p, 1, n));
                let gw = run(m, half, r, 1 - p, p, n);
                let ge = run(m, half, r, 1 - p, 1 + p, n);
                for (k, g) in dst[1..1 + n].iter_mut().enumerate() {
                    *g = ppg_green(
                        c[k],
                        [cn[k], cs[k], cw[k], ce[k]],
                        [gn[k], gs[k], gw[k], ge[k]],
                    );
                }
            }
        }
    }
}

/// Steps 2 and 3 and the matrix for `n` pixels of half `p` of working row `r`, from value
/// `k0 + 2` of the half (image column `2·k0 + p`): the output's three colours into
/// `rgb[0..n]`, `rgb[CHUNK..CHUNK + n]` and `rgb[2·CHUNK..2·CHUNK + n]`.
// Kept whole: both sites' kernels share the run offsets and the matrix writer; split,
// each would take a dozen loose arguments.
fn colour_run(
    m: &[f32],
    g: &[f32],
    half: usize,
    site: Site,
    matrix: &[[f32; 3]; 3],
    (r, p, k0, n): (usize, usize, usize, usize),
    rgb: &mut [f32],
) {
    let columns = site.columns(matrix);
    let (red, rest) = rgb.split_at_mut(CHUNK);
    let (green, blue) = rest.split_at_mut(CHUNK);
    let (red, green, blue) = (&mut red[..n], &mut green[..n], &mut blue[..n]);
    let k = k0 + 2;
    // Value k of half p, image column x; x ± 1 is value k − 1 + p and k + p of the other
    // half.
    let (west, east) = (k - 1 + p, k + p);
    let q = 1 - p;
    let mut write = |j: usize, a: f32, b: f32, c: f32| {
        red[j] = columns[0][0] * a + columns[1][0] * b + columns[2][0] * c;
        green[j] = columns[0][1] * a + columns[1][1] * b + columns[2][1] * c;
        blue[j] = columns[0][2] * a + columns[1][2] * b + columns[2][2] * c;
    };
    match site {
        Site::Green { .. } => {
            let (mc, gc) = (run(m, half, r, p, k, n), run(g, half, r, p, k, n));
            let (mw, me) = (run(m, half, r, q, west, n), run(m, half, r, q, east, n));
            let (gw, ge) = (run(g, half, r, q, west, n), run(g, half, r, q, east, n));
            let (mn, ms) = (run(m, half, r - 1, p, k, n), run(m, half, r + 1, p, k, n));
            let (gn, gs) = (run(g, half, r - 1, p, k, n), run(g, half, r + 1, p, k, n));
            for j in 0..n {
                let across = hue_transit(gw[j], gc[j], ge[j], mw[j], me[j]);
                let down = hue_transit(gn[j], gc[j], gs[j], mn[j], ms[j]);
                write(j, mc[j], across, down);
            }
        }
        Site::Chroma { .. } => {
            let (mc, gc) = (run(m, half, r, p, k, n), run(g, half, r, p, k, n));
            // The diagonal neighbours (other colour) and the own colour two pixels away
            // along each diagonal.
            let (m_ne, g_ne) = (
                run(m, half, r - 1, q, east, n),
                run(g, half, r - 1, q, east, n),
            );
            let (m_sw, g_sw) = (
                run(m, half, r + 1, q, west, n),
                run(g, half, r + 1, q, west, n),
            );
            let (m_nw, g_nw) = (
                run(m, half, r - 1, q, west, n),
                run(g, half, r - 1, q, west, n),
            );
            let (m_se, g_se) = (
                run(m, half, r + 1, q, east, n),
                run(g, half, r + 1, q, east, n),
            );
            let (c_ne, c_sw) = (
                run(m, half, r - 2, p, k + 1, n),
                run(m, half, r + 2, p, k - 1, n),
            );
            let (c_nw, c_se) = (
                run(m, half, r - 2, p, k - 1, n),
                run(m, half, r + 2, p, k + 1, n),
            );
            for j in 0..n {
                let (c, gc) = (mc[j], gc[j]);
                let d_ne = (m_ne[j] - m_sw[j]).abs()
                    + (c_ne[j] - c).abs()
                    + (c - c_sw[j]).abs()
                    + (g_ne[j] - gc).abs()
                    + (gc - g_sw[j]).abs();
                let d_nw = (m_nw[j] - m_se[j]).abs()
                    + (c_nw[j] - c).abs()
                    + (c - c_se[j]).abs()
                    + (g_nw[j] - gc).abs()
                    + (gc - g_se[j]).abs();
                let along_ne = hue_transit(g_ne[j], gc, g_sw[j], m_ne[j], m_sw[j]);
                let along_nw = hue_transit(g_nw[j], gc, g_se[j], m_nw[j], m_se[j]);
                let other = if d_ne < d_nw { along_ne } else { along_nw };
                write(j, c, gc, other);
            }
        }
    }
}

/// Develops one band of `rows` output rows from image row `y0` into `out` (interleaved
/// RGB of those rows): steps 1–3 of the module docs, then the matrix, each a loop over the
/// pixels of one half of a working row (one colour), then the two halves interleaved.
fn ppg_band(
    band: &mut Band,
    sites: &[[Site; 2]; 2],
    y0: usize,
    rows: usize,
    width: usize,
    matrix: &[[f32; 3]; 3],
    out: &mut [f32],
) {
    // Step 1 on working rows PAD − 1 ..= PAD + rows; the image row of r is y0 + r − PAD,
    // of the parity of y0 + r + 1 (PAD being 3).
    for r in PAD - 1..PAD + rows + 1 {
        let row_sites = &sites[(y0 + r + 1) & 1];
        green_row(&band.mosaic, &mut band.green, band.half, row_sites, r);
    }
    let half = band.half;
    // Pixels of each half of a row: image columns 2k' and 2k' + 1.
    let counts = [width.div_ceil(2), width / 2];
    for j in 0..rows {
        let r = PAD + j;
        let row_sites = &sites[(y0 + j) & 1];
        let dst = &mut out[j * width * 3..(j + 1) * width * 3];
        for k0 in (0..counts[0]).step_by(CHUNK) {
            let n = [
                (counts[0] - k0).min(CHUNK),
                counts[1].saturating_sub(k0).min(CHUNK),
            ];
            let (even, odd) = band.rgb.split_at_mut(3 * CHUNK);
            for (p, rgb) in [even, odd].into_iter().enumerate() {
                let run = (r, p, k0, n[p]);
                colour_run(
                    &band.mosaic,
                    &band.green,
                    half,
                    row_sites[p],
                    matrix,
                    run,
                    rgb,
                );
            }
            // Interleave: pixel 2k' from the even half, 2k' + 1 from the odd.
            let rgb = &band.rgb;
            let planes = |p: usize, len: usize| {
                let at = 3 * CHUNK * p;
                (
                    &rgb[at..at + len],
                    &rgb[at + CHUNK..at + CHUNK + len],
                    &rgb[at + 2 * CHUNK..at + 2 * CHUNK + len],
                )
            };
            let ((r0, g0, b0), (r1, g1, b1)) = (planes(0, n[0]), planes(1, n[1]));
            let chunk_out = &mut dst[6 * k0..(6 * k0 + 3 * (n[0] + n[1]))];
            let mut pairs = chunk_out.chunks_exact_mut(6);
            for (i, px) in (&mut pairs).enumerate() {
                px.copy_from_slice(&[r0[i], g0[i], b0[i], r1[i], g1[i], b1[i]]);
            }
            let last = pairs.into_remainder();
            if !last.is_empty() {
                let i = n[0] - 1;
                last.copy_from_slice(&[r0[i], g0[i], b0[i]]);
            }
        }
    }
}

/// PPG on bands of [`BAND`] rows. The image is cut into a few runs of bands per thread;
/// each run slides its working copy down the image, so a source row is read once per run
/// (apart from the apron above the run's first band) and a merge is evaluated once.
fn bayer<S: MosaicRows>(
    source: &S,
    cfa: &Cfa,
    gains: [f32; 3],
    matrix: &[[f32; 3]; 3],
) -> (Vec<f32>, u64) {
    let (width, height) = (source.width(), source.height());
    let mut out = vec![0.0f32; width * height * 3];
    if width == 0 || height == 0 {
        return (out, 0);
    }
    let sites = sites(cfa);
    let runs = 4 * rayon::current_num_threads();
    let run_rows = height.div_ceil(runs).div_ceil(BAND) * BAND;
    let clipped = out
        .par_chunks_mut(run_rows * width * 3)
        .enumerate()
        .map_init(
            || Band::new(width),
            |band, (k, out)| {
                let y_start = k * run_rows;
                let own = y_start..y_start + out.len() / (width * 3);
                let mut clipped = 0;
                for (b, out) in out.chunks_mut(BAND * width * 3).enumerate() {
                    let (y0, rows) = (y_start + b * BAND, out.len() / (width * 3));
                    // Every band but a run's last is BAND rows: the previous band's last
                    // 2·PAD working rows are this band's first.
                    let first = if b == 0 {
                        0
                    } else {
                        let s = 2 * band.half;
                        band.mosaic.copy_within(BAND * s..(BAND + 2 * PAD) * s, 0);
                        2 * PAD
                    };
                    for r in first..rows + 2 * PAD {
                        let y = (y0 + r) as isize - PAD as isize;
                        clipped += band.load_row(source, r, y, &own, cfa, gains);
                    }
                    ppg_band(band, &sites, y0, rows, width, matrix, out);
                }
                clipped
            },
        )
        .sum();
    (out, clipped)
}

/// X-Trans through rawler's bilinear interpolation (module docs): the mosaic is read
/// into memory, white-balanced, interpolated, and the matrix applied while copying out.
fn xtrans<S: MosaicRows>(
    source: &S,
    cfa: &Cfa,
    gains: [f32; 3],
    matrix: &[[f32; 3]; 3],
) -> (Vec<f32>, u64) {
    use rawler::cfa::{CFA, PlaneColor};
    use rawler::imgop::sensor::Demosaic;
    use rawler::imgop::sensor::xtrans::bilinear::XTransBilinearDemosaic;
    use rawler::imgop::{Dim2, Point, Rect};
    use rawler::pixarray::PixF32;

    let (width, height) = (source.width(), source.height());
    let mut values = vec![0.0f32; width * height];
    let clipped = values
        .par_chunks_mut(width.max(1))
        .enumerate()
        .map_init(Vec::new, |scratch, (y, row)| {
            let clipped = source.row(y, row, scratch);
            for (x, v) in row.iter_mut().enumerate() {
                *v *= gains[cfa.colour_at(x, y)];
            }
            clipped
        })
        .sum();
    let pixels = PixF32::new_with(values, width, height);
    let roi = Rect::new(Point::new(0, 0), Dim2::new(width, height));
    let rgb = XTransBilinearDemosaic::new().demosaic(
        &pixels,
        &CFA::new(&cfa.name()),
        &PlaneColor::default(),
        roi,
    );
    drop(pixels);
    let camera = rgb.into_inner();
    let mut out = vec![0.0f32; camera.len() * 3];
    out.par_chunks_exact_mut(3)
        .zip(camera.par_iter())
        .for_each(|(o, p)| {
            for (v, row) in o.iter_mut().zip(matrix) {
                *v = row[0] * p[0] + row[1] * p[1] + row[2] * p[2];
            }
        });
    (out, clipped)
}

#[cfg(test)]
mod tests {
    use super::super::mosaic::{self, Linear, Merge, MergedMosaic, Noise, Signal};
    use super::*;

    fn cfa(name: &str) -> Cfa {
        Cfa::bayer(name).expect("a Bayer pattern")
    }

    /// The mosaic of a uniform camera colour `rgb`.
    fn flat(rgb: [f32; 3], cfa: &Cfa, width: usize, height: usize) -> MergedMosaic {
        MergedMosaic {
            width,
            height,
            values: (0..width * height)
                .map(|i| rgb[cfa.colour_at(i % width, i / width)])
                .collect(),
            clipped: 0,
        }
    }

    const MATRIX: [[f32; 3]; 3] = [[1.7, -0.5, -0.2], [-0.3, 1.5, -0.2], [0.1, -0.6, 1.5]];

    /// A uniform colour comes out as `M · (gains ∘ rgb)` at every pixel, edges and corners
    /// included, for every Bayer pattern and for odd sizes and heights that end a band
    /// part-way: the mirrored apron keeps each colour in its place.
    #[test]
    fn a_uniform_colour_is_exact_to_the_edges() {
        let rgb = [0.8f32, 0.5, 0.2];
        let gains = [0.6f32, 1.0, 1.4];
        let expected: Vec<f32> = MATRIX
            .iter()
            .map(|row| (0..3).map(|c| row[c] * gains[c] * rgb[c]).sum())
            .collect();
        for name in ["RGGB", "BGGR", "GRBG", "GBRG"] {
            let cfa = cfa(name);
            for (w, h) in [
                (3, 3),
                (4, 5),
                (7, 2 * BAND + 5),
                (33, 17),
                (64, BAND),
                (9, 301),
            ] {
                let (out, _) = demosaic(&flat(rgb, &cfa, w, h), &cfa, gains, &MATRIX);
                assert_eq!(out.len(), w * h * 3);
                for (i, p) in out.chunks_exact(3).enumerate() {
                    for c in 0..3 {
                        assert!(
                            (p[c] - expected[c]).abs() < 1e-5,
                            "{name} {w}×{h}: pixel ({}, {}) reads {p:?}, not {expected:?}",
                            i % w,
                            i / w
                        );
                    }
                }
            }
        }
    }

    /// A grey ramp down the image is linear, and PPG reproduces a linear grey exactly:
    /// every row away from the mirrored top and bottom reads its own level, so bands and
    /// the runs of bands that slide their working rows down the image line up.
    #[test]
    fn a_grey_ramp_is_exact_across_bands() {
        let (w, h) = (11, 301);
        for name in ["RGGB", "GBRG"] {
            let cfa = cfa(name);
            let ramp = MergedMosaic {
                width: w,
                height: h,
                values: (0..w * h).map(|i| 0.1 + (i / w) as f32 * 0.003).collect(),
                clipped: 0,
            };
            let (out, _) = demosaic(&ramp, &cfa, UNBALANCED, &CAMERA_RGB);
            for y in 3..h - 3 {
                let level = 0.1 + y as f32 * 0.003;
                for v in &out[y * w * 3..(y + 1) * w * 3] {
                    assert!((v - level).abs() < 1e-5, "{name} row {y}: {v} for {level}");
                }
            }
        }
    }

    /// Merging row by row inside the bands gives the same pixels and the same count of
    /// samples clipped in every frame as merging into memory first.
    #[test]
    fn merging_in_the_bands_equals_merging_first() {
        let (w, h) = (23, 157);
        let cfa = cfa("GRBG");
        let frame = |scale: f32| -> Vec<f32> {
            (0..w * h)
                .map(|i| {
                    let (x, y) = ((i % w) as f32, (i / w) as f32);
                    (scale * (0.3 + 0.7 * ((x * 0.37).sin() * (y * 0.21).cos()).abs())).min(1.0)
                })
                .collect()
        };
        let (short, long) = (frame(1.2), frame(9.6));
        let signals = [
            Linear {
                signal: &short,
                width: w,
            },
            Linear {
                signal: &long,
                width: w,
            },
        ];
        let noise = Noise {
            shot: 1e-4,
            read: 1e-3,
        };
        let inputs: Vec<(&dyn Signal, f64, Noise)> =
            vec![(&signals[0], 1.0, noise), (&signals[1], 8.0, noise)];
        let gains = [0.7, 1.0, 1.3];
        let merged = mosaic::merge(&inputs, w, h);
        assert!(merged.clipped > 0, "the test needs samples clipped in both");
        let (first, clipped_first) = demosaic(&merged, &cfa, gains, &MATRIX);
        let (fused, clipped_fused) = demosaic(&Merge::new(&inputs, w, h), &cfa, gains, &MATRIX);
        assert_eq!(clipped_fused, merged.clipped);
        assert_eq!(clipped_first, 0, "a merged mosaic counts nothing again");
        assert_eq!(fused, first);
    }

    /// Mosaics too small to mirror (one or two pixels across) come out finite, at their
    /// size, without a panic.
    #[test]
    fn tiny_mosaics_come_out_finite() {
        let cfa = cfa("RGGB");
        for (w, h) in [(1, 1), (1, 4), (2, 2), (4, 1), (2, 5), (0, 3)] {
            let (out, _) = demosaic(
                &flat([0.3, 0.6, 0.9], &cfa, w, h),
                &cfa,
                UNBALANCED,
                &MATRIX,
            );
            assert_eq!(out.len(), w * h * 3, "{w}×{h}");
            assert!(out.iter().all(|v| v.is_finite()), "{w}×{h}: {out:?}");
        }
    }

    /// Lin's rules on a 5×5 patch worked by hand: a red pixel whose smallest gradient is
    /// east takes green from the east (`(3·G14 + G12 + R13 − R15)/4`), and `hue_transit`
    /// carries a colour along a monotone green and averages otherwise.
    #[test]
    fn the_published_rules_hold_on_a_worked_patch() {
        assert_eq!(hue_transit(1.0, 2.0, 3.0, 10.0, 30.0), 20.0);
        assert_eq!(
            hue_transit(1.0, 4.0, 3.0, 10.0, 30.0),
            20.0 + (8.0 - 1.0 - 3.0) * 0.25
        );
        // R13 = 0.5; R3 = 0.9 and R23 = 0.1 differ, R11 = 0.2, R15 = 0.45 nearly equal;
        // G8 = 0.6, G18 = 0.4, G12 = 0.55, G14 = 0.52.
        let green = ppg_green(0.5, [0.9, 0.1, 0.2, 0.45], [0.6, 0.4, 0.55, 0.52]);
        let east = (3.0 * 0.52 + 0.55 + 0.5 - 0.45) * 0.25;
        assert!((green - east).abs() < 1e-6);
    }

    /// PPG written pixel by pixel over the whole image, from the module docs: the
    /// white-balanced mosaic mirrored beyond the edges, the green of step 1 wherever steps
    /// 2 and 3 read it, then the matrix, each sum in the order the bands evaluate it.
    fn reference(m: &MergedMosaic, cfa: &Cfa, gains: [f32; 3], matrix: &[[f32; 3]; 3]) -> Vec<f32> {
        let (w, h) = (m.width, m.height);
        let v = |x: isize, y: isize| {
            let (x, y) = (mirror(x, w), mirror(y, h));
            m.values[y * w + x] * gains[cfa.colour_at(x, y)]
        };
        let colour = |x: isize, y: isize| {
            cfa.colour_at(x.rem_euclid(2) as usize, y.rem_euclid(2) as usize)
                .min(2)
        };
        let green = |x: isize, y: isize| {
            if colour(x, y) == 1 {
                return v(x, y);
            }
            let c = v(x, y);
            let (cn, cs, cw, ce) = (v(x, y - 2), v(x, y + 2), v(x - 2, y), v(x + 2, y));
            let (gn, gs, gw, ge) = (v(x, y - 1), v(x, y + 1), v(x - 1, y), v(x + 1, y));
            let vertical = (gn - gs).abs();
            let horizontal = (gw - ge).abs();
            let gradients = [
                2.0 * (c - cn).abs() + vertical,
                2.0 * (c - ce).abs() + horizontal,
                2.0 * (c - cw).abs() + horizontal,
                2.0 * (c - cs).abs() + vertical,
            ];
            let values = [
                3.0 * gn + gs + c - cn,
                3.0 * ge + gw + c - ce,
                3.0 * gw + ge + c - cw,
                3.0 * gs + gn + c - cs,
            ];
            // The first smallest of N, E, W, S.
            let mut best = 0;
            for d in 1..4 {
                if gradients[d] < gradients[best] {
                    best = d;
                }
            }
            values[best] * 0.25
        };
        let mut out = Vec::with_capacity(w * h * 3);
        for y in 0..h as isize {
            for x in 0..w as isize {
                let (a, b, c, columns) = if colour(x, y) == 1 {
                    let across = hue_transit(
                        green(x - 1, y),
                        green(x, y),
                        green(x + 1, y),
                        v(x - 1, y),
                        v(x + 1, y),
                    );
                    let down = hue_transit(
                        green(x, y - 1),
                        green(x, y),
                        green(x, y + 1),
                        v(x, y - 1),
                        v(x, y + 1),
                    );
                    (
                        v(x, y),
                        across,
                        down,
                        [1, colour(x + 1, y), colour(x, y + 1)],
                    )
                } else {
                    let (c, gc) = (v(x, y), green(x, y));
                    let diagonal = |dx: isize| {
                        let (n, s) = ((x + dx, y - 1), (x - dx, y + 1));
                        let gradient = (v(n.0, n.1) - v(s.0, s.1)).abs()
                            + (v(x + 2 * dx, y - 2) - c).abs()
                            + (c - v(x - 2 * dx, y + 2)).abs()
                            + (green(n.0, n.1) - gc).abs()
                            + (gc - green(s.0, s.1)).abs();
                        let along = hue_transit(
                            green(n.0, n.1),
                            gc,
                            green(s.0, s.1),
                            v(n.0, n.1),
                            v(s.0, s.1),
                        );
                        (gradient, along)
                    };
                    let ((d_ne, ne), (d_nw, nw)) = (diagonal(1), diagonal(-1));
                    let own = colour(x, y);
                    (c, gc, if d_ne < d_nw { ne } else { nw }, [own, 1, 2 - own])
                };
                for row in matrix {
                    out.push(row[columns[0]] * a + row[columns[1]] * b + row[columns[2]] * c);
                }
            }
        }
        out
    }

    /// The bands, with each row split into its two colours, give the pixel-by-pixel
    /// reference bit for bit: every 2×2 tile (the four Bayer patterns and one without
    /// its greens on a diagonal), odd and even sizes from one pixel to several runs of
    /// bands, on smooth random values and on a few levels repeated (ties between
    /// gradients).
    #[test]
    fn the_bands_equal_the_pixel_by_pixel_reference() {
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut random = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 40) as f32 / (1u64 << 24) as f32
        };
        let gains = [0.55f32, 1.0, 1.35];
        for name in ["RGGB", "BGGR", "GRBG", "GBRG", "RGBG"] {
            let cfa = cfa(name);
            for (w, h) in [
                (1, 1),
                (2, 3),
                (3, 2),
                (5, 7),
                (37, 2 * BAND + 5),
                (64, BAND),
                (2 * CHUNK + 3, 9),
                (29, 301),
            ] {
                for levels in [None, Some(3.0f32)] {
                    let values = (0..w * h)
                        .map(|_| {
                            let v = random();
                            levels.map_or(v, |l| (v * l).floor() / l)
                        })
                        .collect();
                    let m = MergedMosaic {
                        width: w,
                        height: h,
                        values,
                        clipped: 0,
                    };
                    let (bands, _) = demosaic(&m, &cfa, gains, &MATRIX);
                    let expected = reference(&m, &cfa, gains, &MATRIX);
                    assert_eq!(bands.len(), expected.len());
                    for (i, (a, b)) in bands.iter().zip(&expected).enumerate() {
                        assert!(
                            a.to_bits() == b.to_bits(),
                            "{name} {w}×{h} levels {levels:?}: pixel ({}, {}) channel {} reads {a}, the reference {b}",
                            i / 3 % w,
                            i / 3 / w,
                            i % 3
                        );
                    }
                }
            }
        }
    }
}
