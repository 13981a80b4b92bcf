//! Demosaicking quality against the truth: full-RGB synthetic scenes are mosaicked through
//! each Bayer pattern and interpolated back, by ours (`raw::demosaic`, PPG from Lin's
//! description), by a bilinear baseline written here and by rawler's PPG (the
//! interpolator filmback used before, LGPL-2.1, called through its public API).
//!
//! `cargo test --test all demosaic:: -- --nocapture` prints the table of `docs/accuracy.md`.
#![cfg(feature = "raw")]

use filmback::raw::Cfa;
use filmback::raw::demosaic::{self, CAMERA_RGB, UNBALANCED};
use filmback::raw::mosaic::MergedMosaic;
use filmback::synthetic::SceneKind;

const PATTERNS: [&str; 4] = ["RGGB", "BGGR", "GRBG", "GBRG"];

fn cfa(name: &str) -> Cfa {
    Cfa::bayer(name).expect("a Bayer pattern")
}

/// A scene: `width × height` interleaved RGB in `[0, 1]`.
struct Scene {
    name: &'static str,
    width: usize,
    height: usize,
    rgb: Vec<f32>,
}

/// A rendered kind scaled so that its 99th percentile channel value is 1, clipped there.
fn normalised(name: &'static str, kind: SceneKind, width: u32, height: u32) -> Scene {
    let map = kind.render(width, height, 3);
    let mut sorted = map.pixels().to_vec();
    sorted.sort_by(f32::total_cmp);
    let p99 = sorted[sorted.len() * 99 / 100].max(1e-6);
    Scene {
        name,
        width: width as usize,
        height: height as usize,
        rgb: map
            .pixels()
            .iter()
            .map(|v| (v / p99).clamp(0.0, 1.0))
            .collect(),
    }
}

/// Fine detail at an odd size: the left half hard-edged rectangles of saturated colours
/// (16 × 12 pixels, so edges fall on odd and even pixels alike, each row of cells shifted
/// by 5 pixels from the last), the right half a colour-tinted zone plate
/// `0.5 + 0.45·cos(k·r²)` whose frequency reaches ⅓ cycle per pixel at the half's corners
/// (beyond the red and blue samples' limit of ¼, within green's).
fn detail(width: usize, height: usize) -> Scene {
    let colours = [
        [0.9, 0.1, 0.1],
        [0.1, 0.8, 0.2],
        [0.1, 0.2, 0.9],
        [0.9, 0.8, 0.1],
        [0.8, 0.1, 0.8],
        [0.1, 0.8, 0.8],
        [0.95, 0.95, 0.95],
        [0.05, 0.05, 0.05],
    ];
    let half = width / 2;
    let (cx, cy) = (half as f64 + half as f64 / 2.0, height as f64 / 2.0);
    let r_max = ((half as f64 / 2.0).powi(2) + cy * cy).sqrt();
    // Local frequency k·r/π cycles per pixel: ⅓ at r_max.
    let k = std::f64::consts::PI / (3.0 * r_max);
    let mut rgb = vec![0.0f32; width * height * 3];
    for y in 0..height {
        for x in 0..width {
            let p = if x < half {
                let (row, column) = (y / 12, (x + 5 * (y / 12)) / 16);
                colours[(row * 3 + column) % colours.len()]
            } else {
                let (dx, dy) = (x as f64 - cx, y as f64 - cy);
                let z = 0.5 + 0.45 * (k * (dx * dx + dy * dy)).cos();
                let tint = [1.0, 0.8, 0.55];
                [0, 1, 2].map(|c| z * tint[c])
            };
            for c in 0..3 {
                rgb[(y * width + x) * 3 + c] = p[c] as f32;
            }
        }
    }
    Scene {
        name: "detail (edges, zone plate)",
        width,
        height,
        rgb,
    }
}

fn scenes() -> Vec<Scene> {
    vec![
        normalised("landscape", SceneKind::Procedural, 384, 256),
        normalised("studio", SceneKind::Studio, 384, 256),
        detail(301, 203),
    ]
}

fn mosaic(scene: &Scene, cfa: &Cfa) -> MergedMosaic {
    let w = scene.width;
    MergedMosaic {
        width: w,
        height: scene.height,
        values: (0..w * scene.height)
            .map(|i| scene.rgb[i * 3 + cfa.colour_at(i % w, i / w)])
            .collect(),
        clipped: 0,
    }
}

/// Bilinear interpolation: each missing colour is the mean of that colour's samples among
/// the pixel's eight neighbours (within the image).
fn bilinear(m: &MergedMosaic, cfa: &Cfa) -> Vec<f32> {
    let (w, h) = (m.width as isize, m.height as isize);
    let mut out = vec![0.0f32; m.values.len() * 3];
    for y in 0..h {
        for x in 0..w {
            let own = cfa.colour_at(x as usize, y as usize);
            let (mut sum, mut n) = ([0.0f32; 3], [0u32; 3]);
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let (nx, ny) = (x + dx, y + dy);
                    if nx < 0 || ny < 0 || nx >= w || ny >= h {
                        continue;
                    }
                    let c = cfa.colour_at(nx as usize, ny as usize);
                    sum[c] += m.values[(ny * w + nx) as usize];
                    n[c] += 1;
                }
            }
            let i = (y * w + x) as usize;
            for c in 0..3 {
                out[i * 3 + c] = if c == own {
                    m.values[i]
                } else {
                    sum[c] / n[c].max(1) as f32
                };
            }
        }
    }
    out
}

/// rawler's PPG, as `raw::demosaic` called it before.
fn rawler_ppg(m: &MergedMosaic, cfa: &Cfa) -> Vec<f32> {
    use rawler::cfa::{CFA, PlaneColor};
    use rawler::imgop::sensor::Demosaic;
    use rawler::imgop::sensor::bayer::ppg::PPGDemosaic;
    use rawler::imgop::{Dim2, Point, Rect};
    use rawler::pixarray::PixF32;
    let pixels = PixF32::new_with(m.values.clone(), m.width, m.height);
    let roi = Rect::new(Point::new(0, 0), Dim2::new(m.width, m.height));
    let rgb =
        PPGDemosaic::new().demosaic(&pixels, &CFA::new(&cfa.name()), &PlaneColor::default(), roi);
    rgb.into_inner().into_iter().flatten().collect()
}

/// PSNR in dB (peak 1) and the mean colour error `mean ‖rgb − truth‖₂` in % of the peak.
fn quality(rgb: &[f32], truth: &[f32]) -> (f64, f64) {
    let se: f64 = rgb
        .iter()
        .zip(truth)
        .map(|(a, b)| (f64::from(*a) - f64::from(*b)).powi(2))
        .sum();
    let mse = se / truth.len() as f64;
    let colour: f64 = rgb
        .chunks_exact(3)
        .zip(truth.chunks_exact(3))
        .map(|(a, b)| {
            (0..3)
                .map(|c| (f64::from(a[c]) - f64::from(b[c])).powi(2))
                .sum::<f64>()
                .sqrt()
        })
        .sum::<f64>()
        / (truth.len() / 3) as f64;
    (-10.0 * mse.log10(), colour * 100.0)
}

/// Per scene and Bayer pattern: PSNR and mean colour error of the three. Ours must beat
/// bilinear by 2 dB or more and stay within 0.1 dB (and 1 % of colour error) of rawler's
/// PPG.
#[test]
fn demosaicking_quality_against_the_truth() {
    println!("| scene | CFA | bilinear | rawler PPG | ours (PPG) |");
    println!("|---|---|---|---|---|");
    for scene in scenes() {
        for name in PATTERNS {
            let cfa = cfa(name);
            let m = mosaic(&scene, &cfa);
            let ours = quality(
                &demosaic::demosaic(&m, &cfa, UNBALANCED, &CAMERA_RGB).0,
                &scene.rgb,
            );
            let base = quality(&bilinear(&m, &cfa), &scene.rgb);
            let ppg = quality(&rawler_ppg(&m, &cfa), &scene.rgb);
            let cell = |(psnr, colour): (f64, f64)| format!("{psnr:.2} dB, {colour:.3} %");
            println!(
                "| {} | {name} | {} | {} | {} |",
                scene.name,
                cell(base),
                cell(ppg),
                cell(ours)
            );
            let case = format!("{} {name}", scene.name);
            assert!(
                ours.0 >= base.0 + 2.0 && ours.1 < base.1,
                "{case}: ours {ours:?} against bilinear {base:?}"
            );
            assert!(
                ours.0 >= ppg.0 - 0.1 && ours.1 <= ppg.1 * 1.01,
                "{case}: ours {ours:?} against rawler's PPG {ppg:?}"
            );
        }
    }
}
