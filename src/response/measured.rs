//! A body's JPEG response measured against its own raw: the two files of one RAW+JPEG
//! capture give, pixel by pixel and channel by channel, the JPEG code `k` beside the
//! linear value `x` the raw says the light was (demosaicked, white-balanced, camera →
//! Rec. 709, so through the same colour processing the camera applied before its curve).
//! No histogram matching and no exposure ratio are needed: the inverse response is read
//! off directly.
//!
//! # The statistic
//!
//! Per channel and code `k ∈ 1..=254` (0 and 255 are clipped), the median of `log₂ x` over
//! the samples with that code, taken from a histogram of `log₂ x` in bins of
//! 1/[`BINS_PER_STOP`] stop and interpolated within its bin; a code needs
//! [`MIN_SAMPLES`] samples to count (the median resists the JPEG's compression noise,
//! sharpening halos and demosaicking differences, which move single samples by many
//! codes). Pixels within [`RING`] pixels of a code 255 in any channel are left out: near
//! clipping the raw's other channels may be clipped too (the colour matrix then spoils
//! all three), and the JPEG's neighbours of a clipped pixel ring with it, reading codes
//! near 255 for light far above, which would inflate the extrapolated white. The
//! medians are made non-decreasing by pooling adjacent violators (weighted by sample
//! counts), interpolated linearly across codes without data, and normalised like the
//! fitted curves: `g(0) = 0` and `g(1) = 1`, with `g(255)` extrapolated along the power
//! law (least-squares line in log-log) through the top measured codes (the last
//! [`TOP_CODES`] of them); below the first
//! measured code `k₀`, `g(k) = g(k₀)·(k/k₀)^p` with `p ∈ [1, 4]` the log-log slope of the
//! first [`TOP_CODES`] measured codes.
//!
//! Several captures (the frames of a RAW+JPEG bracket) add into one histogram when their
//! linear values share one unit: each is given with its factor to that unit.

use crate::frame::{Frame, Samples};
use crate::radiance::RadianceMap;

use super::{InverseResponse, ResponseError};

/// Histogram bins per stop of linear value.
pub const BINS_PER_STOP: f64 = 64.0;

/// Stops of linear value the histogram spans, from `2^LOWEST_STOP` up.
const STOPS: f64 = 40.0;

/// The lowest stop of the histogram: `x` below `2^LOWEST_STOP` counts in the first bin.
const LOWEST_STOP: f64 = -32.0;

const BINS: usize = (STOPS * BINS_PER_STOP) as usize;

/// Pixels left out around a clipped one, each way.
pub const RING: usize = 1;

/// Samples a code needs before its median counts.
pub const MIN_SAMPLES: u32 = 16;

/// Measured codes the extrapolation to code 255 runs through.
pub const TOP_CODES: usize = 6;

/// The brightest measured code must reach at least this, or `g(1)` would be a guess.
const MIN_TOP_CODE: usize = 200;

/// Why a RAW+JPEG pair cannot measure a curve. Names the JPEG where one is concerned.
#[derive(Debug, thiserror::Error)]
pub enum MeasureError {
    /// The JPEG is not 8-bit RGB.
    #[error(
        "{path}: not an 8-bit RGB JPEG ({reason}); the camera's curve is measured on its 8-bit RGB JPEG"
    )]
    NotRgb8 {
        /// The JPEG.
        path: std::path::PathBuf,
        /// What it is.
        reason: String,
    },
    /// The JPEG's geometry does not match the raw's (crop, rotation, larger).
    #[error("{path}: {jpeg_w}×{jpeg_h} JPEG against a {raw_w}×{raw_h} raw: {reason}")]
    Geometry {
        /// The JPEG.
        path: std::path::PathBuf,
        /// JPEG width.
        jpeg_w: u32,
        /// JPEG height.
        jpeg_h: u32,
        /// Raw width.
        raw_w: u32,
        /// Raw height.
        raw_h: u32,
        /// Why the two cannot be compared.
        reason: String,
    },
    /// Too few codes had enough samples.
    #[error("channel {channel}: {reason}")]
    Coverage {
        /// The channel (0 red, 1 green, 2 blue).
        channel: usize,
        /// What is missing.
        reason: String,
    },
    /// The measured curves are not a valid inverse response.
    #[error("the measured curve: {0}")]
    Curve(#[source] ResponseError),
}

/// A measured inverse response and how much of the code range backed it.
#[derive(Debug, Clone, PartialEq)]
pub struct MeasuredResponse {
    /// `g` per channel, one sample per code (`B = k/255`), normalised `g(0)=0`, `g(1)=1`.
    pub response: InverseResponse,
    /// Per channel, the fraction of codes 1..=254 with at least [`MIN_SAMPLES`] samples.
    pub coverage: Vec<f64>,
    /// Per channel, the lowest and highest measured code.
    pub codes: Vec<(u8, u8)>,
    /// Samples that went into the histograms.
    pub samples: u64,
    /// Captures (RAW+JPEG pairs) measured.
    pub captures: u64,
}

/// Accumulates RAW+JPEG captures, then measures (see the module docs).
#[derive(Debug, Clone)]
pub struct JpegMeter {
    /// `[channel][code][bin]` counts.
    histogram: Vec<u32>,
    samples: u64,
    captures: u64,
}

impl Default for JpegMeter {
    fn default() -> Self {
        JpegMeter::new()
    }
}

impl JpegMeter {
    /// An empty meter.
    pub fn new() -> JpegMeter {
        JpegMeter {
            histogram: vec![0; 3 * 256 * BINS],
            samples: 0,
            captures: 0,
        }
    }

    /// Adds one capture: `linear` (interleaved linear RGB of the raw, any unit) times
    /// `unit` is the linear value of the camera's JPEG `jpeg` (read from `path`). A JPEG of
    /// the raw's size is compared pixel by pixel; a smaller one of the same aspect ratio
    /// (within 0.5 %) against the raw averaged over each JPEG pixel's footprint; any
    /// other geometry (a crop, a rotation, a larger JPEG) is refused with the reason.
    pub fn add(
        &mut self,
        linear: &RadianceMap,
        unit: f32,
        jpeg: &Frame,
        path: &std::path::Path,
    ) -> Result<(), MeasureError> {
        let Samples::Eight(codes) = jpeg.samples() else {
            return Err(MeasureError::NotRgb8 {
                path: path.to_path_buf(),
                reason: "16 bits per sample".to_string(),
            });
        };
        if jpeg.channels() != 3 || linear.channels() != 3 {
            return Err(MeasureError::NotRgb8 {
                path: path.to_path_buf(),
                reason: format!("{} channel(s)", jpeg.channels()),
            });
        }
        let resampled = resample(linear, jpeg, path)?;
        let linear = resampled.as_ref().unwrap_or(linear);
        // Pixels within RING pixels of a 255 in any channel: they ring with the clipped
        // ones and read high codes for light far above (separable dilation of the mask).
        let (jw, jh) = (jpeg.width() as usize, jpeg.height() as usize);
        let clipped: Vec<bool> = codes.chunks_exact(3).map(|c| c.contains(&255)).collect();
        let mut rows = vec![false; clipped.len()];
        for y in 0..jh {
            let row = &clipped[y * jw..(y + 1) * jw];
            for x in 0..jw {
                rows[y * jw + x] = row[x.saturating_sub(RING)..(x + RING + 1).min(jw)]
                    .iter()
                    .any(|&c| c);
            }
        }
        let near = |p: usize| {
            let (x, y) = (p % jw, p / jw);
            (y.saturating_sub(RING)..(y + RING + 1).min(jh)).any(|yy| rows[yy * jw + x])
        };
        for (p, (code, x)) in codes
            .chunks_exact(3)
            .zip(linear.pixels().chunks_exact(3))
            .enumerate()
        {
            if near(p) {
                continue;
            }
            for c in 0..3 {
                let k = usize::from(code[c]);
                if k == 0 {
                    continue;
                }
                let v = f64::from(x[c] * unit);
                let bin = if v > 0.0 && v.is_finite() {
                    ((v.log2() - LOWEST_STOP) * BINS_PER_STOP).clamp(0.0, (BINS - 1) as f64)
                        as usize
                } else {
                    0
                };
                self.histogram[(c * 256 + k) * BINS + bin] += 1;
                self.samples += 1;
            }
        }
        self.captures += 1;
        Ok(())
    }

    /// The measured inverse response (see the module docs), or why the captures do not
    /// cover enough of the code range.
    pub fn finish(&self) -> Result<MeasuredResponse, MeasureError> {
        let mut channels = Vec::with_capacity(3);
        let mut coverage = Vec::with_capacity(3);
        let mut ranges = Vec::with_capacity(3);
        for c in 0..3 {
            // (code, log2 median, count) of the codes with enough samples.
            let mut points: Vec<(usize, f64, f64)> = Vec::new();
            for k in 1..255 {
                let h = &self.histogram[(c * 256 + k) * BINS..(c * 256 + k + 1) * BINS];
                let n: u32 = h.iter().sum();
                if n >= MIN_SAMPLES {
                    points.push((k, median_log2(h, n), f64::from(n)));
                }
            }
            let short = |reason: String| MeasureError::Coverage { channel: c, reason };
            if points.len() < 2 * TOP_CODES {
                return Err(short(format!(
                    "only {} codes have {MIN_SAMPLES} samples or more",
                    points.len()
                )));
            }
            let top = points[points.len() - 1].0;
            if top < MIN_TOP_CODE {
                return Err(short(format!(
                    "the brightest code with data is {top} (< {MIN_TOP_CODE}): the highlights are not covered"
                )));
            }
            coverage.push(points.len() as f64 / 254.0);
            ranges.push((points[0].0 as u8, top as u8));
            isotonic(&mut points);
            channels.push(curve(&points));
        }
        let response = InverseResponse::from_samples(channels).map_err(MeasureError::Curve)?;
        Ok(MeasuredResponse {
            response,
            coverage,
            codes: ranges,
            samples: self.samples,
            captures: self.captures,
        })
    }
}

/// The median of `log₂ x` of a histogram of `n` samples, interpolated within its bin.
fn median_log2(h: &[u32], n: u32) -> f64 {
    let half = f64::from(n) / 2.0;
    let mut below = 0.0;
    for (i, &count) in h.iter().enumerate() {
        let count = f64::from(count);
        if below + count >= half && count > 0.0 {
            let within = (half - below) / count;
            return LOWEST_STOP + (i as f64 + within) / BINS_PER_STOP;
        }
        below += count;
    }
    LOWEST_STOP + STOPS
}

/// Pool adjacent violators: the weighted least-squares non-decreasing fit of the medians.
fn isotonic(points: &mut [(usize, f64, f64)]) {
    // Blocks of (value, weight, length).
    let mut blocks: Vec<(f64, f64, usize)> = Vec::with_capacity(points.len());
    for &(_, v, w) in points.iter() {
        blocks.push((v, w, 1));
        while blocks.len() > 1 && blocks[blocks.len() - 2].0 > blocks[blocks.len() - 1].0 {
            let (v2, w2, l2) = blocks.pop().expect("two blocks");
            let (v1, w1, l1) = blocks.pop().expect("two blocks");
            blocks.push(((v1 * w1 + v2 * w2) / (w1 + w2), w1 + w2, l1 + l2));
        }
    }
    let mut i = 0;
    for (v, _, len) in blocks {
        for p in &mut points[i..i + len] {
            p.1 = v;
        }
        i += len;
    }
}

/// `g(k/255)` for every code from non-decreasing `(code, log₂ x)` points: linear in `x`
/// between points, a power law from `g(0) = 0` to the first, extrapolated to 255 along
/// the power law (log-log line) through the last [`TOP_CODES`] points, divided by that
/// value.
fn curve(points: &[(usize, f64, f64)]) -> Vec<f64> {
    let xs: Vec<(f64, f64)> = points
        .iter()
        .map(|&(k, l, _)| (k as f64, l.exp2()))
        .collect();
    // log-log slope of the last TOP_CODES points and of the first TOP_CODES points.
    let log_slope = |pts: &[(f64, f64)]| {
        let n = pts.len() as f64;
        let (lk, lx): (Vec<f64>, Vec<f64>) = pts.iter().map(|p| (p.0.ln(), p.1.ln())).unzip();
        let (mk, mx) = (lk.iter().sum::<f64>() / n, lx.iter().sum::<f64>() / n);
        let slope = lk
            .iter()
            .zip(&lx)
            .map(|(k, x)| (k - mk) * (x - mx))
            .sum::<f64>()
            / lk.iter().map(|k| (k - mk).powi(2)).sum::<f64>();
        if slope.is_finite() { slope } else { 1.0 }
    };
    let last = xs[xs.len() - 1];
    let top = log_slope(&xs[xs.len() - TOP_CODES..]).max(0.0);
    let white = (last.1 * (255.0 / last.0).powf(top)).max(last.1);
    // Below the first measured code, a power law through the origin (1 = linear, as
    // sRGB's toe; at most 4).
    let toe = log_slope(&xs[..TOP_CODES]).clamp(1.0, 4.0);
    let mut g = vec![0.0; 256];
    let mut j = 0;
    for (k, out) in g.iter_mut().enumerate().skip(1) {
        let k = k as f64;
        while j < xs.len() && xs[j].0 < k {
            j += 1;
        }
        let value = if j < xs.len() && xs[j].0 == k {
            xs[j].1
        } else if j == 0 {
            xs[0].1 * (k / xs[0].0).powf(toe)
        } else if j == xs.len() {
            (last.1 * (k / last.0).powf(top)).min(white)
        } else {
            let (a, b) = (xs[j - 1], xs[j]);
            a.1 + (b.1 - a.1) * (k - a.0) / (b.0 - a.0)
        };
        *out = (value / white).clamp(0.0, 1.0);
    }
    g[255] = 1.0;
    // Rounding may leave a last step down next to the clamp.
    for i in 1..256 {
        if g[i] < g[i - 1] {
            g[i] = g[i - 1];
        }
    }
    g
}

/// The raw's linear RGB at the JPEG's size: `None` when the sizes agree; the raw averaged
/// over each JPEG pixel's footprint when the JPEG is smaller with the same aspect ratio;
/// an error otherwise.
fn resample(
    linear: &RadianceMap,
    jpeg: &Frame,
    path: &std::path::Path,
) -> Result<Option<RadianceMap>, MeasureError> {
    let (rw, rh) = (linear.width(), linear.height());
    let (jw, jh) = (jpeg.width(), jpeg.height());
    if (rw, rh) == (jw, jh) {
        return Ok(None);
    }
    let refuse = |reason: &str| MeasureError::Geometry {
        path: path.to_path_buf(),
        jpeg_w: jw,
        jpeg_h: jh,
        raw_w: rw,
        raw_h: rh,
        reason: reason.to_string(),
    };
    let aspect = |w: u32, h: u32| f64::from(w) / f64::from(h);
    if (aspect(rw, rh) / aspect(jw, jh) - 1.0).abs() > 0.005 {
        if (aspect(rw, rh) * aspect(jw, jh) - 1.0).abs() < 0.005 {
            return Err(refuse(
                "the JPEG is rotated against the raw's sensor orientation",
            ));
        }
        return Err(refuse(
            "other aspect ratio: the JPEG is a crop of the raw, which is not located",
        ));
    }
    if jw > rw || jh > rh {
        return Err(refuse("the JPEG is larger than the raw's visible area"));
    }
    let (sx, sy) = (f64::from(rw) / f64::from(jw), f64::from(rh) / f64::from(jh));
    let src = linear.pixels();
    let mut out = Vec::with_capacity(jw as usize * jh as usize * 3);
    for y in 0..jh {
        let (y0, y1) = span(y, sy, rh);
        for x in 0..jw {
            let (x0, x1) = span(x, sx, rw);
            let mut sum = [0f64; 3];
            for yy in y0..y1 {
                let row = yy as usize * rw as usize;
                for xx in x0..x1 {
                    let i = (row + xx as usize) * 3;
                    for c in 0..3 {
                        sum[c] += f64::from(src[i + c]);
                    }
                }
            }
            let n = f64::from((y1 - y0) * (x1 - x0));
            out.extend(sum.iter().map(|s| (s / n) as f32));
        }
    }
    Ok(Some(
        RadianceMap::new(jw, jh, 3, out).expect("three values per JPEG pixel"),
    ))
}

/// The source pixels `[start, end)` of output pixel `i` at scale `s` (at least one).
fn span(i: u32, s: f64, limit: u32) -> (u32, u32) {
    let start = ((f64::from(i) * s).floor() as u32).min(limit - 1);
    let end = ((f64::from(i + 1) * s).floor() as u32).clamp(start + 1, limit);
    (start, end)
}

/// RMS and largest `|log₂(a/b)|` per channel, in stops, over codes 8..=254 where both
/// curves are positive: how far two normalised inverse responses disagree.
pub fn stops_apart(a: &InverseResponse, b: &InverseResponse) -> Vec<(f64, f64)> {
    (0..a.channels().min(b.channels()))
        .map(|c| {
            let (mut sum, mut n, mut max) = (0.0, 0usize, 0.0f64);
            for k in 8..255 {
                let bk = f64::from(k) / 255.0;
                let (x, y) = (a.eval(c, bk), b.eval(c, bk));
                if x > 0.0 && y > 0.0 {
                    let d = (x / y).log2();
                    sum += d * d;
                    max = max.max(d.abs());
                    n += 1;
                }
            }
            (if n == 0 { 0.0 } else { (sum / n as f64).sqrt() }, max)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rgb(width: u32, height: u32, codes: Vec<u8>) -> Frame {
        Frame::new(width, height, 3, Samples::Eight(codes)).unwrap()
    }

    /// A ramp through a gamma-2.2 curve is measured back within a hundredth of a stop,
    /// and its coverage is reported.
    #[test]
    fn a_ramp_through_a_known_curve_is_measured_back() {
        let (w, h) = (256u32, 64u32);
        let mut linear = Vec::new();
        let mut codes = Vec::new();
        for y in 0..h {
            for x in 0..w {
                // Even in code values, so that every code is hit all over its interval.
                let u = (f64::from(x * h + y) + 0.5) / f64::from(w * h);
                let v = u.powf(2.2) * 1.2;
                for c in 0..3 {
                    let v = v * [0.9, 1.0, 0.8][c];
                    linear.push(v as f32);
                    codes.push((v.min(1.0).powf(1.0 / 2.2) * 255.0).round() as u8);
                }
            }
        }
        let map = RadianceMap::new(w, h, 3, linear).unwrap();
        let mut meter = JpegMeter::new();
        meter
            .add(&map, 3.0, &rgb(w, h, codes), std::path::Path::new("a.jpg"))
            .unwrap();
        let m = meter.finish().unwrap();
        let truth = InverseResponse::from_samples(vec![
            (0..256)
                .map(|k| (f64::from(k) / 255.0).powf(2.2))
                .collect();
            3
        ])
        .unwrap();
        for (c, (rms, _)) in stops_apart(&m.response, &truth).into_iter().enumerate() {
            assert!(rms < 0.02, "channel {c}: {rms} stops");
        }
        assert!(m.coverage.iter().all(|&f| f > 0.5), "{:?}", m.coverage);
        assert_eq!(m.captures, 1);
    }

    #[test]
    fn other_geometry_is_refused_with_the_reason() {
        let map = RadianceMap::new(4, 2, 3, vec![0.5; 24]).unwrap();
        let mut meter = JpegMeter::new();
        let path = std::path::Path::new("x.jpg");
        let err = meter
            .add(&map, 1.0, &rgb(2, 4, vec![100; 24]), path)
            .unwrap_err();
        assert!(err.to_string().contains("rotated"), "{err}");
        let err = meter
            .add(&map, 1.0, &rgb(3, 3, vec![100; 27]), path)
            .unwrap_err();
        assert!(err.to_string().contains("crop") && err.to_string().contains("x.jpg"));
        // Half size, same aspect: averaged, accepted.
        meter
            .add(&map, 1.0, &rgb(2, 1, vec![100; 6]), path)
            .unwrap();
        assert!(matches!(meter.finish(), Err(MeasureError::Coverage { .. })));
    }

    #[test]
    fn pooling_makes_medians_non_decreasing() {
        let mut p = vec![(1, 0.0, 1.0), (2, 2.0, 1.0), (3, 1.0, 3.0), (4, 3.0, 1.0)];
        isotonic(&mut p);
        let v: Vec<f64> = p.iter().map(|q| q.1).collect();
        assert_eq!(v, vec![0.0, 1.25, 1.25, 3.0]);
    }
}
