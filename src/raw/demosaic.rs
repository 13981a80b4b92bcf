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

/// Pixels of apron around a band's working copy: the green of step 1 is needed one pixel
/// beyond the band and reads the mosaic two pixels beyond that.
const PAD: usize = 3;

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

/// A band's working copies: the white-balanced mosaic and the green plane, `rows + 2·PAD`
/// rows of `width + 2·PAD` values, row `r` holding image row `y0 + r − PAD`; and the
/// source's working memory.
struct Band {
    stride: usize,
    mosaic: Vec<f32>,
    green: Vec<f32>,
    scratch: Vec<f32>,
}

impl Band {
    fn new(width: usize) -> Band {
        let stride = width + 2 * PAD;
        let len = stride * (BAND + 2 * PAD);
        Band {
            stride,
            mosaic: vec![0.0; len],
            green: vec![0.0; len],
            scratch: Vec::new(),
        }
    }

    /// Reads image row `y` (mirrored beyond the image) of `source` into working row `r`,
    /// each sample times its colour's gain, the row mirrored into its apron columns.
    /// Returns the row's samples clipped in every frame when `y` is one of `own` (so that
    /// rows read twice, as aprons or mirrors, are counted once).
    fn load_row<S: MosaicRows>(
        &mut self,
        source: &S,
        r: usize,
        y: isize,
        own: &std::ops::Range<usize>,
        cfa: &Cfa,
        gains: [f32; 3],
    ) -> u64 {
        let (w, s) = (source.width(), self.stride);
        let y_in = mirror(y, source.height());
        let dst = &mut self.mosaic[r * s..(r + 1) * s];
        let clipped = source.row(y_in, &mut dst[PAD..PAD + w], &mut self.scratch);
        let g = [gains[cfa.colour_at(0, y_in)], gains[cfa.colour_at(1, y_in)]];
        for (x, v) in dst[PAD..PAD + w].iter_mut().enumerate() {
            *v *= g[x & 1];
        }
        for k in 1..=PAD {
            dst[PAD - k] = dst[PAD + mirror(-(k as isize), w)];
            dst[PAD + w - 1 + k] = dst[PAD + mirror((w - 1 + k) as isize, w)];
        }
        if y >= 0 && own.contains(&(y as usize)) {
            clipped
        } else {
            0
        }
    }
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

/// Step 1 at the red or blue sample `i` of `m` (row stride `s`).
#[inline(always)]
fn ppg_green(m: &[f32], i: usize, s: usize) -> f32 {
    let c = m[i];
    let (cn, cs, cw, ce) = (m[i - 2 * s], m[i + 2 * s], m[i - 2], m[i + 2]);
    let (gn, gs, gw, ge) = (m[i - s], m[i + s], m[i - 1], m[i + 1]);
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

/// `columns · (a, b, c)` into `out`.
#[inline(always)]
fn write(out: &mut [f32], columns: &[[f32; 3]; 3], a: f32, b: f32, c: f32) {
    for (k, o) in out.iter_mut().enumerate() {
        *o = columns[0][k] * a + columns[1][k] * b + columns[2][k] * c;
    }
}

/// Develops one band of `rows` output rows from image row `y0` into `out` (interleaved
/// RGB of those rows): steps 1–3 of the module docs, then the matrix.
fn ppg_band(
    band: &mut Band,
    sites: &[[Site; 2]; 2],
    y0: usize,
    rows: usize,
    width: usize,
    matrix: &[[f32; 3]; 3],
    out: &mut [f32],
) {
    let s = band.stride;
    // Step 1 on rows PAD − 1 ..= PAD + rows, columns PAD − 1 ..= PAD + width; the image
    // row of r is y0 + r − PAD, the image column of c is c − PAD (both of the parity
    // of r + 1 and c + 1, PAD being 3).
    for r in PAD - 1..PAD + rows + 1 {
        let row = r * s..(r + 1) * s;
        band.green[row.clone()].copy_from_slice(&band.mosaic[row]);
        let row_sites = &sites[(y0 + r + 1) & 1];
        for (parity, site) in row_sites.iter().enumerate() {
            if let Site::Chroma { .. } = site {
                // The first column ≥ PAD − 1 whose image column has this parity.
                let first = PAD - 1 + ((parity + PAD - 1 + 1) & 1);
                for c in (first..PAD + width + 1).step_by(2) {
                    let i = r * s + c;
                    band.green[i] = ppg_green(&band.mosaic, i, s);
                }
            }
        }
    }
    let (m, g) = (&band.mosaic, &band.green);
    for j in 0..rows {
        let base = (PAD + j) * s + PAD;
        let dst = &mut out[j * width * 3..(j + 1) * width * 3];
        for (parity, &site) in sites[(y0 + j) & 1].iter().enumerate() {
            let columns = site.columns(matrix);
            let pixels = dst.chunks_exact_mut(3).enumerate().skip(parity).step_by(2);
            match site {
                Site::Green { .. } => {
                    for (x, px) in pixels {
                        let i = base + x;
                        let across = hue_transit(g[i - 1], g[i], g[i + 1], m[i - 1], m[i + 1]);
                        let down = hue_transit(g[i - s], g[i], g[i + s], m[i - s], m[i + s]);
                        write(px, &columns, m[i], across, down);
                    }
                }
                Site::Chroma { .. } => {
                    for (x, px) in pixels {
                        let i = base + x;
                        let (c, gc) = (m[i], g[i]);
                        let (ne, sw) = (i - s + 1, i + s - 1);
                        let (nw, se) = (i - s - 1, i + s + 1);
                        let d_ne = (m[ne] - m[sw]).abs()
                            + (m[i - 2 * s + 2] - c).abs()
                            + (c - m[i + 2 * s - 2]).abs()
                            + (g[ne] - gc).abs()
                            + (gc - g[sw]).abs();
                        let d_nw = (m[nw] - m[se]).abs()
                            + (m[i - 2 * s - 2] - c).abs()
                            + (c - m[i + 2 * s + 2]).abs()
                            + (g[nw] - gc).abs()
                            + (gc - g[se]).abs();
                        let along_ne = hue_transit(g[ne], gc, g[sw], m[ne], m[sw]);
                        let along_nw = hue_transit(g[nw], gc, g[se], m[nw], m[se]);
                        let other = if d_ne < d_nw { along_ne } else { along_nw };
                        write(px, &columns, c, gc, other);
                    }
                }
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
                        let s = band.stride;
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
        // 5×5, stride 5, centre 12 (R); rows: R G R G R / G B G B G / ...
        let mut m = vec![0.0f32; 25];
        let set = |m: &mut Vec<f32>, x: usize, y: usize, v: f32| m[y * 5 + x] = v;
        set(&mut m, 2, 2, 0.5); // R13
        set(&mut m, 2, 0, 0.9); // R3: north differs
        set(&mut m, 2, 4, 0.1); // R23: south differs
        set(&mut m, 0, 2, 0.2); // R11
        set(&mut m, 4, 2, 0.45); // R15: east nearly equal
        set(&mut m, 2, 1, 0.6); // G8
        set(&mut m, 2, 3, 0.4); // G18
        set(&mut m, 1, 2, 0.55); // G12
        set(&mut m, 3, 2, 0.52); // G14
        let east = (3.0 * 0.52 + 0.55 + 0.5 - 0.45) * 0.25;
        assert!((ppg_green(&m, 12, 5) - east).abs() < 1e-6);
    }
}
