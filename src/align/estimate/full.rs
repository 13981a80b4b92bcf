//! The last step of a registration whose finest pyramid level has blocks of more than one
//! pixel: the same Gauss–Newton ([`damped`]) on sparse samples of the frame registered
//! onto at its finest [`Picture`] (full resolution, or a raw frame's CFA tiles), starting
//! from the pyramid's estimate.

use std::sync::OnceLock;

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

use super::{Convergence, Convert, Geometry, Linearised, Motion, Normal, State, damped, solve};
use crate::frame::{Frame, Samples};

/// What the refinement reads of a frame: an image of linear values (the mean `g(B)` of a
/// pixel's channels, or of a raw CFA tile's normalised signals) and their
/// [`super::log_weight`]s (0: not usable), each image pixel covering `step × step`
/// full-resolution pixels.
pub(in crate::align) trait Picture: Sync {
    /// Width and height in image pixels.
    fn size(&self) -> (usize, usize);
    /// Full-resolution pixels per image pixel, on a side.
    fn step(&self) -> usize;
    /// Image pixel `(x, y)`: value and weight.
    fn pixel(&self, x: usize, y: usize) -> (f32, f32);
    /// Image row `y`'s values and weights, into the two slices (one per image pixel).
    fn row(&self, y: usize, values: &mut [f32], weights: &mut [f32]);
    /// Whether a homography refined on this picture must fit its samples clearly better
    /// than the rigid model refined from the same start to be kept
    /// ([`PERSPECTIVE_GAIN`]).
    fn tests_perspective(&self) -> bool {
        false
    }
}

/// A frame of codes read through the bracket's inverse response: a [`Picture`] at full
/// resolution.
pub(in crate::align) struct Codes<'a> {
    pub(in crate::align) frame: &'a Frame,
    pub(in crate::align) convert: &'a Convert,
}

impl Picture for Codes<'_> {
    fn size(&self) -> (usize, usize) {
        (self.frame.width() as usize, self.frame.height() as usize)
    }

    fn step(&self) -> usize {
        1
    }

    /// The pixel's mean `g(B)` over its channels and its worst channel's weight.
    fn pixel(&self, x: usize, y: usize) -> (f32, f32) {
        let c = self.frame.channels();
        let i = (y * self.frame.width() as usize + x) * c;
        match self.frame.samples() {
            Samples::Eight(v) => self.convert.pixel(&v[i..i + c]),
            Samples::Sixteen(v) => self.convert.pixel(&v[i..i + c]),
        }
    }

    fn row(&self, y: usize, values: &mut [f32], weights: &mut [f32]) {
        let (w, c) = (self.frame.width() as usize, self.frame.channels());
        let span = y * w * c..(y + 1) * w * c;
        match self.frame.samples() {
            Samples::Eight(v) => self.convert.row(&v[span], values, weights),
            Samples::Sixteen(v) => self.convert.row(&v[span], values, weights),
        }
    }
}

/// The reference samples the refinement reads at most: one per cell of a square grid
/// sized to hold this many cells.
const MOST_SAMPLES: usize = 150_000;

/// The farthest, in blocks of the finest pyramid level, the refinement may move a
/// corner from the pyramid's estimate for its result to be kept: that estimate is good
/// to about a block, so a descent that went farther did not refine it.
const MOST_BLOCKS: f64 = 2.0;

/// The refinement ends when a proposed step would move no corner by more than this many
/// pixels: a hundredth of a pixel is far below what the merge can show, and steps that
/// small only chase the residual's noise.
const SETTLED_PX: f64 = 0.01;

/// How many times a homography's mean squared residual the rigid model refined from the
/// same start must leave for the homography to be kept, on a picture that
/// [`Picture::tests_perspective`]: its perspective and scale must explain at least half
/// of what the rigid model leaves. On the raw test brackets a camera's perspective leaves
/// the rigid model 5 to 200 times the homography's residual; a perspective and scale
/// fitted to frames that differ in sharpness, 1.02 to 1.13 times.
const PERSPECTIVE_GAIN: f64 = 2.0;

/// Samples [`accumulate`] sums in one task.
const SAMPLES_PER_GROUP: usize = 4096;

/// One frame's [`Picture`] as log radiance, read on the fly, and the samples the
/// refinement takes of it when other frames are registered onto it (chosen once).
pub(in crate::align) struct FullFrame<'a> {
    picture: &'a dyn Picture,
    /// `ln e`, `e` the frame's relative exposure.
    log_e: f32,
    samples: OnceLock<Vec<Sample>>,
}

/// A row of a [`Picture`]: per pixel its value and weight, and whether it is well exposed
/// (both above 0).
struct Line {
    values: Vec<f32>,
    weights: Vec<f32>,
    usable: Vec<bool>,
}

/// A reference pixel the refinement compares: its position, log radiance and weight.
#[derive(Debug, Clone, Copy)]
struct Sample {
    x: u32,
    y: u32,
    log: f32,
    weight: f32,
}

impl Sample {
    /// Where `m` sends this sample of a picture of `step` pixels per image pixel: its
    /// normalised coordinates `(u, v)`, their image `p = m·(u, v, 1)ᵀ`, and that image in
    /// the picture's pixels.
    fn landing(
        &self,
        geometry: &Geometry,
        step: f64,
        m: &Matrix3<f64>,
    ) -> ((f64, f64, Vector3<f64>), (f64, f64)) {
        let (u, v) = geometry.to_normalised(step, f64::from(self.x), f64::from(self.y));
        let p = m * Vector3::new(u, v, 1.0);
        let at = geometry.to_level(step, p.x / p.z, p.y / p.z);
        ((u, v, p), at)
    }
}

/// A copy of a frame's pixels (value and weight) in the square of [`Patch::SIDE`] pixels
/// whose top-left pixel is `(x, y)`.
#[derive(Clone, Copy)]
struct Patch {
    x: usize,
    y: usize,
    pixels: [(f32, f32); Patch::SIDE * Patch::SIDE],
}

impl Patch {
    /// Pixels on a side: the four of a bilinear sample, and one more on every side.
    const SIDE: usize = 4;

    /// The square around the pixel `(x, y)` of `picture` (one pixel left of it and above
    /// it, moved inside the picture).
    fn around(picture: &dyn Picture, x: usize, y: usize) -> Patch {
        let (w, h) = picture.size();
        let (x, y) = (
            x.saturating_sub(1).min(w - Self::SIDE),
            y.saturating_sub(1).min(h - Self::SIDE),
        );
        let pixels = std::array::from_fn(|i| picture.pixel(x + i % Self::SIDE, y + i / Self::SIDE));
        Patch { x, y, pixels }
    }

    /// The pixels `(x0, y0)`, `(x0 + 1, y0)`, `(x0, y0 + 1)`, `(x0 + 1, y0 + 1)`, when
    /// the copy holds all four.
    fn quad(&self, x0: usize, y0: usize) -> Option<[(f32, f32); 4]> {
        let (dx, dy) = (x0.checked_sub(self.x)?, y0.checked_sub(self.y)?);
        if dx + 1 >= Self::SIDE || dy + 1 >= Self::SIDE {
            return None;
        }
        let i = dy * Self::SIDE + dx;
        let p = &self.pixels;
        Some([p[i], p[i + 1], p[i + Self::SIDE], p[i + Self::SIDE + 1]])
    }
}

/// The frame registered, as the reference's samples see it: per sample, a [`Patch`]
/// around where a state sends it. The refinement moves a sample by a fraction of a pixel,
/// so its passes read these copies in the samples' order rather than the frame's rows
/// at scattered places, which wait on memory.
struct Seen<'f, 'a> {
    frame: &'f FullFrame<'a>,
    copies: Vec<Patch>,
}

impl<'f, 'a> Seen<'f, 'a> {
    /// `frame` where `state` sends each of `reference`'s samples.
    fn at(
        reference: &FullFrame<'_>,
        frame: &'f FullFrame<'a>,
        geometry: &Geometry,
        state: &State,
    ) -> Self {
        let m = state.matrix();
        let step = reference.picture.step() as f64;
        let (w, h) = frame.picture.size();
        let copies = reference
            .samples()
            .par_iter()
            .map(|s| {
                let (_, (x, y)) = s.landing(geometry, step, &m);
                // Off the frame (or not a number): any square; the sample is refused.
                let at = |c: f64, n: usize| if c >= 0.0 { (c as usize).min(n) } else { 0 };
                Patch::around(frame.picture, at(x, w), at(y, h))
            })
            .collect();
        Seen { frame, copies }
    }
}

impl<'a> FullFrame<'a> {
    /// `picture` of a frame at relative `exposure`.
    pub(in crate::align) fn new(picture: &'a dyn Picture, exposure: f64) -> Self {
        FullFrame {
            picture,
            log_e: exposure.ln() as f32,
            samples: OnceLock::new(),
        }
    }

    /// The picture's row `y`.
    fn row(&self, y: usize) -> Line {
        let w = self.picture.size().0;
        let (mut values, mut weights) = (vec![0.0; w], vec![0.0; w]);
        self.picture.row(y, &mut values, &mut weights);
        // `&` rather than `&&` keeps the loop branch-free.
        let usable = values
            .iter()
            .zip(&weights)
            .map(|(&v, &o)| (o > 0.0) & (v > 0.0))
            .collect();
        Line {
            values,
            weights,
            usable,
        }
    }

    /// The samples, chosen on first use.
    fn samples(&self) -> &[Sample] {
        self.samples.get_or_init(|| self.choose())
    }

    /// One sample per cell of `n × n` image pixels, `n` the least (at least 2) that makes
    /// at most [`MOST_SAMPLES`] cells: the pixel of the cell with the steepest log-radiance
    /// gradient (central differences, `|∇m|/m` of the linear mean `m`) among those that
    /// are well exposed with their four neighbours; none where no pixel is. Cell rows are
    /// chosen in parallel and kept in order.
    fn choose(&self) -> Vec<Sample> {
        let (w, h) = self.picture.size();
        let n = ((w * h) as f64 / MOST_SAMPLES as f64)
            .sqrt()
            .ceil()
            .max(2.0) as usize;
        let rows: Vec<Vec<Sample>> = (0..h / n)
            .into_par_iter()
            .map(|j| self.choose_in_row(j * n..(j + 1) * n, n))
            .collect();
        rows.concat()
    }

    /// [`FullFrame::choose`] for the cells of the pixel rows `rows`, `n` pixels wide: the
    /// rows are scanned in order, each cell keeping its first steepest pixel.
    fn choose_in_row(&self, rows: std::ops::Range<usize>, n: usize) -> Vec<Sample> {
        let (w, h) = self.picture.size();
        // Pixel rows rows.start − 1 ..= rows.end (clamped).
        let first = rows.start.saturating_sub(1);
        let last = rows.end.min(h - 1);
        let read: Vec<Line> = (first..=last).map(|y| self.row(y)).collect();
        // Per cell: the steepest pixel so far (steepness ≥ 0 beats the start, -1).
        let mut best = vec![(-1.0f32, 0usize, 0usize); w / n];
        let mut steep = vec![-1.0f32; w];
        for y in rows.start.max(1)..rows.end.min(h - 1) {
            let row = |dy: usize| &read[y + dy - 1 - first];
            steepness(row(0), row(1), row(2), &mut steep);
            for (cell, best) in best.iter_mut().enumerate() {
                let span = (cell * n).max(1)..((cell + 1) * n).min(w - 1);
                for (x, &s) in span.clone().zip(&steep[span]) {
                    if s > best.0 {
                        *best = (s, x, y);
                    }
                }
            }
        }
        best.into_iter()
            .filter(|&(s, _, _)| s >= 0.0)
            .map(|(_, x, y)| {
                let line = &read[y - first];
                Sample {
                    x: x as u32,
                    y: y as u32,
                    log: line.values[x].ln() - self.log_e,
                    weight: line.weights[x],
                }
            })
            .collect()
    }

    /// The log radiance `ln m − ln e` at image position `(x, y)` (`m` the bilinear
    /// interpolation of the four image pixels' linear values), its gradient `∇m/m` per
    /// image pixel (of the interpolating patch) and the interpolated weight, when the four
    /// pixels are well exposed; the four read from `copy` when it holds them.
    fn sample(&self, x: f64, y: f64, copy: &Patch) -> Option<(f64, f64, f64, f64)> {
        let (w, h) = self.picture.size();
        if !(x >= 0.0 && y >= 0.0) {
            return None;
        }
        let (x0, y0) = (x as usize, y as usize);
        if x0 + 1 >= w || y0 + 1 >= h {
            return None;
        }
        let quad = copy.quad(x0, y0).unwrap_or_else(|| {
            [
                self.picture.pixel(x0, y0),
                self.picture.pixel(x0 + 1, y0),
                self.picture.pixel(x0, y0 + 1),
                self.picture.pixel(x0 + 1, y0 + 1),
            ]
        });
        if quad.iter().any(|&(_, weight)| weight <= 0.0) {
            return None;
        }
        let (fx, fy) = (x - x0 as f64, y - y0 as f64);
        let [a, b, c, d] = quad.map(|(m, weight)| (f64::from(m), f64::from(weight)));
        let mix = |a: f64, b: f64, c: f64, d: f64| {
            (1.0 - fy) * ((1.0 - fx) * a + fx * b) + fy * ((1.0 - fx) * c + fx * d)
        };
        let m = mix(a.0, b.0, c.0, d.0);
        if m <= 0.0 {
            return None;
        }
        let dx = (1.0 - fy) * (b.0 - a.0) + fy * (d.0 - c.0);
        let dy = (1.0 - fx) * (c.0 - a.0) + fx * (d.0 - b.0);
        let value = m.ln() - f64::from(self.log_e);
        Some((value, dx / m, dy / m, mix(a.1, b.1, c.1, d.1)))
    }
}

/// The steepness `|∇m|²/m²` (central differences of the linear means `m`) of each pixel
/// of the middle row of `above`, `middle`, `below` (three lines) into `out`, -1
/// where it or one of its four neighbours is not well exposed (weight or value 0) and at
/// the row's ends.
fn steepness(above: &Line, middle: &Line, below: &Line, out: &mut [f32]) {
    let w = out.len();
    let inner = middle
        .values
        .windows(3)
        .zip(middle.usable.windows(3))
        .zip(above.values[1..].iter().zip(&above.usable[1..]))
        .zip(below.values[1..].iter().zip(&below.usable[1..]))
        .map(|(((m, here), (&up, &up_ok)), (&down, &down_ok))| {
            let around = here[0] & here[1] & here[2] & up_ok & down_ok;
            let (gx, gy) = (m[2] - m[0], down - up);
            if around {
                (gx * gx + gy * gy) / (m[1] * m[1])
            } else {
                -1.0
            }
        });
    for (o, s) in out[1..w - 1].iter_mut().zip(inner) {
        *o = s;
    }
    out[0] = -1.0;
    out[w - 1] = -1.0;
}

/// The normal equations of the residual `gain·L_k(T·x) + bias − L_ref(x)` over the
/// samples of `reference` (as [`super::accumulate`] on a level), in the first `motion`
/// motion parameters of `state`, gain and offset. Samples in fixed groups, the groups'
/// sums added in order: the same sums however the threads share the work.
fn accumulate(
    reference: &FullFrame<'_>,
    moving: &Seen<'_, '_>,
    geometry: &Geometry,
    state: &State,
    motion: usize,
) -> Normal {
    let m = state.matrix();
    let at = Linearised::new(state, motion);
    let step = reference.picture.step() as f64;
    let to_image = geometry.s / step;
    let groups: Vec<Normal> = reference
        .samples()
        .par_chunks(SAMPLES_PER_GROUP)
        .zip(moving.copies.par_chunks(SAMPLES_PER_GROUP))
        .map(|(group, copies)| {
            let mut acc = Normal::zero();
            for (s, copy) in group.iter().zip(copies) {
                let ((u, v, p), (x, y)) = s.landing(geometry, step, &m);
                let Some((value, gx, gy, weight)) = moving.frame.sample(x, y, copy) else {
                    continue;
                };
                let seen = (value, gx * to_image, gy * to_image, weight);
                let fixed = (f64::from(s.log), f64::from(s.weight));
                acc.equation(&at, (u, v), &p, fixed, seen);
            }
            acc
        })
        .collect();
    groups.into_iter().fold(Normal::zero(), Normal::add)
}

/// `state` (the pyramid's estimate of `moving` onto `reference`, whose finest level has
/// blocks of `step` pixels) refined at full resolution ([`refined`]). On a picture that
/// [`Picture::tests_perspective`], a homography so refined is kept only when the rigid
/// model refined from the same start (gain and offset fitted) leaves at least
/// [`PERSPECTIVE_GAIN`] times its mean squared residual; otherwise that rigid model.
pub(super) fn refine(
    reference: &FullFrame<'_>,
    moving: &FullFrame<'_>,
    geometry: &Geometry,
    state: State,
    step: f64,
) -> State {
    let moving = &Seen::at(reference, moving, geometry, &state);
    let (kept, fit) = refined(reference, moving, geometry, state, step);
    if state.motion != Motion::Homography || !reference.picture.tests_perspective() {
        return kept;
    }
    let rigid_start = state.as_motion(Motion::Rigid);
    let (rigid, rigid_fit) = refined(reference, moving, geometry, rigid_start, step);
    if rigid_fit >= PERSPECTIVE_GAIN * fit {
        kept
    } else {
        rigid
    }
}

/// `state` with the gain and offset fitted to the samples, and its normal equations in
/// its model: one pass over the samples at `state`, the gain and offset's step solved
/// from their own equations, and the equations moved by it in closed form
/// ([`Normal::with_photometric_step`]).
fn fitted(
    reference: &FullFrame<'_>,
    moving: &Seen<'_, '_>,
    geometry: &Geometry,
    state: State,
) -> (State, Normal) {
    let motion = state.params();
    let normal = accumulate(reference, moving, geometry, &state, motion);
    let Some(delta) = solve(&normal.photometric(motion), 2, 0.0) else {
        return (state, normal);
    };
    let step = [delta[0], delta[1]];
    let mut start = state;
    start.gain += step[0];
    start.bias += step[1];
    (
        start,
        normal.with_photometric_step(motion, state.gain, step),
    )
}

/// `state` refined on the samples: gain and offset fitted, then [`damped`] Gauss–Newton
/// in the same model, and the mean squared residual of the state returned. The refined
/// state is kept only when it lowers the samples' mean squared residual below that of
/// `state` (gain and offset fitted) and moves no corner by more than [`MOST_BLOCKS`]
/// blocks; otherwise, or when the refinement fails (too few samples overlap, a singular
/// system), `state` (with an infinite residual when the refinement failed).
fn refined(
    reference: &FullFrame<'_>,
    moving: &Seen<'_, '_>,
    geometry: &Geometry,
    state: State,
    step: f64,
) -> (State, f64) {
    let n = state.params();
    let normal = |s: &State| accumulate(reference, moving, geometry, s, n);
    let (start, current) = fitted(reference, moving, geometry, state);
    let before = current.mean_square();
    let Ok((refined, after)) = damped(
        geometry,
        1.0,
        start,
        current,
        &normal,
        Convergence::Within(SETTLED_PX),
    ) else {
        return (state, f64::INFINITY);
    };
    let moved = geometry.corner_shift(&state.matrix(), &refined.matrix());
    if after.mean_square() < before && moved <= MOST_BLOCKS * step {
        (refined, after.mean_square())
    } else {
        (state, before)
    }
}

#[cfg(test)]
mod tests;
