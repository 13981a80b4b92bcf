//! Alignment: every frame of a bracket is registered onto a reference frame's pixel grid
//! before the merge, so that a nudged tripod or a handheld bracket merges without doubled
//! edges.
//!
//! # Conventions
//!
//! A frame's transform is the 3 × 3 matrix `T` that takes a pixel `(x, y)` of the
//! reference frame (pixel centres at integer coordinates, `x` to the right, `y` down, full
//! resolution) to the point `T·(x, y, 1)ᵀ` (divided by its third coordinate) of that
//! frame that saw the same scene point. Warping resamples the frame there, so the warped
//! frame lies on the reference grid. The reference frame's transform is the identity.
//!
//! # Making frames comparable
//!
//! Frames differ in exposure, so they are compared as log radiance: each frame is
//! reduced to one luminance value per block of `step × step` pixels (the block mean of
//! `g(B)` over pixels and channels, `g` the bracket's inverse response, divided by the
//! frame's relative exposure `e`; its natural log). A block counts only when every sample
//! in it is well exposed ([`WELL_EXPOSED_LOW`] ≤ `B` ≤ [`WELL_EXPOSED_HIGH`]): neither in
//! the noise floor nor clipped. The comparison also fits a gain and an offset in log
//! radiance (a response slightly off changes both), so only the geometry must agree.
//!
//! # Estimation
//!
//! On a pyramid of such images (the finest at most [`ESTIMATION_PIXELS`] blocks, halved
//! until its shorter side would fall under [`COARSEST_SIDE`]):
//!
//! 1. coarse: an exhaustive search of integer translations on the coarsest level within
//!    [`SEARCH_RANGE`] of its longer side, scored by the zero-mean normalised
//!    cross-correlation over the blocks well exposed in both frames (masked, which phase
//!    correlation is not; at ≤ 64 × 64 blocks the search costs less than an FFT's set-up,
//!    so no FFT crate is needed);
//! 2. fine: Gauss–Newton on the masked log residual `r = a·L_k(T·x) + b − L_ref(x)` (the
//!    gain `a` and offset `b` estimated with the motion, which makes it invariant to both,
//!    as ECC is) from the coarsest level to the finest, translation on the coarsest, the
//!    mode's model ([`Motion`]) on every finer one. The
//!    motion parameters live in coordinates normalised by the full frame
//!    (`ũ = (u − c)/s`, `c` the centre, `s` half the longer side), the same on every level;
//! 3. full resolution, when the finest level's blocks are larger than a pixel (frames over
//!    [`ESTIMATION_PIXELS`]): the blocks bound the precision (a homography on 3 × 3 blocks
//!    lands 0.8–3 px from the true move), so the same Gauss–Newton, in the model the
//!    pyramid kept, runs once more on sparse pixels of the frame registered onto: one per
//!    cell of a grid of at most 150 000 cells, the pixel of the cell whose log radiance is
//!    steepest among those well exposed with their four neighbours; the moving frame is
//!    read at the warped position through the bilinear interpolation of its four pixels'
//!    linear values (their log, and the gradient of the interpolating patch). Gain and
//!    offset are fitted first; the result is kept only when it lowers the mean squared
//!    residual of those samples and moves no corner by more than two blocks from the
//!    pyramid's estimate (which is good to about a block). The model chosen by the
//!    uncertainty rule below (on the finest level) is not revisited: the samples are
//!    chosen for their gradient, so their `σ/√λ_min` is not comparable with a bound set on
//!    every block, and the refinement only sharpens parameters the blocks determined.
//!    Registrations compared clipped alike are not refined (their samples would be the
//!    tones both frames measure, which is what that way could not register on). Nor is
//!    an estimate that moves no pixel by [`IDENTITY_PX`] after the finest level has
//!    converged fully: a still frame stays still, and its noise is not refined into a
//!    move. A raw frame is refined on its CFA tiles (see "Camera raw").
//!
//! # Frames far apart in exposure
//!
//! Frames are registered outward from the reference in exposure order. One that cannot be
//! registered onto the reference (most often because, several stops apart, they share too
//! few well-exposed blocks) is registered onto the nearest frame between them that was, and
//! the transforms composed (`T_k = T_{k←n}·T_n`). Where a coarse pyramid level of such a
//! pair shares too few blocks to refine on, the pair is tried again on its finer levels
//! alone, the coarse search's shift carried down to them; then onto whichever of the
//! reference and that nearer frame shares more of the finest level's blocks with it first
//! (a registration on a small share fits structure the shared blocks happen to have).
//! Where neither works, each pair is compared again as the log radiance both frames could
//! have measured: every block clamped to the range of log radiance both measure, so a
//! window or a sky clipped in one frame and exposed beyond that range in the other lies at
//! the range's top in both and its edges register (a median threshold bitmap's idea, with
//! the response's ranges for the median).
//! Such a registration is kept only if refining it on the blocks both frames measure well
//! moves it by at most a pixel (or three standard deviations of the refinement): flare and
//! a camera's local tone mapping move clipped edges too. The note says which way a frame
//! was reached.
//!
//! # Knowing when it failed
//!
//! A frame keeps the identity, with a note saying why (for every way tried), when, for
//! each: fewer than [`MIN_OVERLAP`] of the blocks are well exposed in both frames; the best
//! correlation of the coarse search is below [`MIN_CORRELATION`] (too little texture: a
//! flat backdrop, fog); the best shift lies on the edge of the search range (a motion
//! larger than it), or the refined transform moves a corner by more than twice that range
//! (a descent that ran away); the Gauss–Newton system is singular or does not converge; or
//! the aligned residual is not smaller than the residual without alignment (so the merge is
//! never worse than without it). A model whose parameters the texture does not determine
//! (the standard deviation of the displacement they imply, `σ/√λ_min` with `λ_min` the
//! smallest eigenvalue of the motion block of the Gauss–Newton matrix in pixel units,
//! above [`MAX_UNCERTAINTY_BLOCKS`] of the finest level's blocks) falls back to the next
//! simpler one (homography → rigid → translation), refined from the estimate it replaces,
//! with a note. A homography is kept only when it moves some corner of the frame, from
//! the rigid model refined from where the finest level started, by more than three
//! cluster-robust standard deviations (the residuals' scores summed per cell of a 16 ×
//! 16 grid, so a patch whose residuals agree counts once) and by more than a tenth of a
//! block: otherwise its perspective and scale fit structure the residuals share over a
//! patch (a dark frame's noise and quantisation where its shared blocks crowd into part of
//! the frame), extrapolated to corners no shared block reaches. A homography that moves
//! no pixel by [`IDENTITY_PX`] yields to the rigid model refined from it without that test.
//!
//! A transform that moves no pixel of the frame by more than [`IDENTITY_PX`] counts as the
//! identity: the frame is not resampled, so an aligned tripod bracket merges bit for bit
//! as without alignment. So does one that moves no pixel by more than three cluster-robust
//! standard deviations of the displacement it implies on the finest level (the test a
//! homography passes against the rigid model, applied to the move itself), with a note:
//! on a share of blocks crowded into part of a frame several stops from the other, the
//! residuals' shared structure (a JPEG's loss among it) is otherwise fitted as a move.
//! Unless that standard deviation exceeds a pixel: such a registration tells neither a
//! move nor stillness, counts as failed (too little texture), and the next way is tried
//! (see "Frames far apart in exposure").
//! And so does one that fits the finest level better than the identity in too few cells
//! of that grid when each cell has its own gain and offset (a sign test: more than `n/2 +
//! 3·√n/2` of the `n` cells both measure, half of them being what a still frame wins by
//! chance), with a note: a camera's move lowers the residual in nearly every cell with
//! texture, while a brightness that differs across the frame (flare, vignetting, a
//! camera's local tone mapping) is left by one global gain and offset for the motion to
//! fit, and is matched by the cells'.
//!
//! # Coverage
//!
//! The merge takes no mask: where a warped frame has no data (its pixels fell outside it),
//! and where a bilinear sample would mix a clipped neighbour in, the warped frame holds a
//! clipped code, which every merge weight treats as weight 0 (`merge`'s "Weights"; the raw
//! merge's clipped samples). An uncovered sample is set to the top code where the
//! reference's sample is in the upper half of its range and to 0 otherwise, so that where
//! every frame is clipped the merge's "clipped everywhere" rule still reads the side the
//! reference shows.
//!
//! # Camera raw
//!
//! A raw bracket's transform is estimated on a luminance image of whole CFA tiles (the
//! block mean of the normalised signal `(k − b)/(w − b)` of all colours, `step` a multiple
//! of the tile) and each colour plane is warped separately: an output sample takes the
//! bilinear interpolation of the same CFA position's sub-lattice of the frame (every
//! second pixel of a Bayer mosaic), so colours never mix and the merge still runs in CFA
//! space. Frames whose transform is the identity are not touched and keep the CFA merge's
//! full resolution; a warped frame's planes are interpolated at half resolution. X-Trans
//! mosaics (a 6 × 6 tile, too sparse a sub-lattice to interpolate) are not aligned, with a
//! note. A pixel of one colour does not measure luminance, so the full-resolution
//! refinement reads a raw frame's 2 × 2 tiles instead: per tile the mean normalised
//! signal, filtered by the binomial `[1 2 1]/4` in both directions (unfiltered, one
//! tile's shot noise, which the bilinear interpolation averages down most at half-tile
//! offsets, drew a still dark frame about a pixel off). Translations, rotations and
//! homographies are refined there, but a homography is kept only when the rigid model
//! refined on the tiles from the same start leaves at least twice its mean squared
//! residual; otherwise that rigid model replaces it. Where a frame differs in sharpness
//! from the one it is registered onto (a half-pixel shift blurs it evenly; the test
//! brackets resampled from a sharp raster), a homography's perspective and scale fit the
//! difference: the residual falls by 1.6–12 % and the corners land up to 3 px from the
//! true move. A camera's perspective leaves the rigid model 5 to 200 times the
//! homography's residual on the raw test brackets (`docs/accuracy.md`, "Raw brackets").

mod estimate;
mod warp;

use std::fmt::Write as _;

use rayon::prelude::*;

use crate::frame::{Frame, Samples};
use crate::response::InverseResponse;

#[cfg(feature = "raw")]
pub use warp::{MosaicFrame, align_mosaics, warp_mosaics};
pub use warp::{warp_frame, warp_frames};

/// The lower end of the well-exposed code range, as a fraction of full scale: below it a
/// sample is in the noise floor (code 10 of 255).
pub const WELL_EXPOSED_LOW: f64 = 0.04;

/// The upper end of the well-exposed code range, as a fraction of full scale: above it a
/// sample is clipped or rolls off (code 245 of 255).
pub const WELL_EXPOSED_HIGH: f64 = 0.96;

/// A transform that moves no pixel of the frame by more than this many pixels is the
/// identity (the frame is merged as it is).
pub const IDENTITY_PX: f64 = 0.1;

/// The finest estimation level holds at most this many blocks (about 0.3 MP); a frame
/// larger than that is estimated on blocks of `step × step` pixels.
pub const ESTIMATION_PIXELS: usize = 300_000;

/// The pyramid is halved while the coarsest level's shorter side stays at least this
/// many blocks.
pub const COARSEST_SIDE: usize = 32;

/// The coarse search covers translations up to this fraction of the frame's longer side.
pub const SEARCH_RANGE: f64 = 0.05;

/// The least share of the reference's blocks that must be well exposed in both frames.
pub const MIN_OVERLAP: f64 = 0.1;

/// The least normalised cross-correlation of the coarse search's best shift: below it
/// the frames have too little texture in common to be registered.
pub const MIN_CORRELATION: f64 = 0.5;

/// The largest standard deviation of the displacement a model's parameters imply
/// (`σ/√λ_min`, see the module docs) for the model to be kept, in blocks of the finest
/// estimation level (`step` full-resolution pixels: 0.05 px for a frame of at most
/// [`ESTIMATION_PIXELS`], 0.45 px at 24 MP). The estimation sees the frame at that
/// sampling, so the bound scales with it: a fixed bound in pixels would refuse, on a
/// large frame, the perspective the texture does determine. It is evaluated there, before
/// the full-resolution refinement, which keeps the model: that refinement's samples are
/// the steepest pixel of each cell, so their uncertainty would understate what the frame's
/// texture as a whole determines.
pub const MAX_UNCERTAINTY_BLOCKS: f64 = 0.05;

/// The pixels [`choose_reference`] counts: every this-many-th row and column.
const REFERENCE_STRIDE: usize = 4;

/// Frames whose shorter side is under this many pixels are not aligned (too few blocks
/// to estimate anything).
const SMALLEST_SIDE: u32 = 64;

/// How far frames are aligned: `auto` (the default) estimates the most general model the
/// frame's texture determines (homography, else rigid, else translation); the others
/// cap the model; `off` leaves the frames as they are.
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    Default,
    serde::Serialize,
    serde::Deserialize,
    clap::ValueEnum,
)]
#[serde(rename_all = "kebab-case")]
pub enum AlignMode {
    /// The most general model the texture determines.
    #[default]
    Auto,
    /// No alignment.
    Off,
    /// Shifts only.
    Translation,
    /// Rotation and shift.
    Rigid,
    /// A plane's perspective (8 parameters).
    Homography,
}

impl AlignMode {
    /// The most general model the mode allows; `None` for `off`.
    pub fn model(self) -> Option<Motion> {
        match self {
            AlignMode::Off => None,
            AlignMode::Translation => Some(Motion::Translation),
            AlignMode::Rigid => Some(Motion::Rigid),
            AlignMode::Auto | AlignMode::Homography => Some(Motion::Homography),
        }
    }

    /// The name the CLI and the config use.
    pub fn as_str(self) -> &'static str {
        match self {
            AlignMode::Auto => "auto",
            AlignMode::Off => "off",
            AlignMode::Translation => "translation",
            AlignMode::Rigid => "rigid",
            AlignMode::Homography => "homography",
        }
    }
}

/// A motion model, simplest first.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Motion {
    /// `(tx, ty)`.
    Translation,
    /// Rotation `θ` about the frame's centre and `(tx, ty)`.
    Rigid,
    /// Eight parameters of a plane's perspective.
    Homography,
}

impl Motion {
    /// The name records use (`translation`, `rigid`, `homography`), as serialised.
    pub fn as_str(self) -> &'static str {
        match self {
            Motion::Translation => "translation",
            Motion::Rigid => "rigid",
            Motion::Homography => "homography",
        }
    }

    /// The next simpler model.
    fn simpler(self) -> Option<Motion> {
        match self {
            Motion::Homography => Some(Motion::Rigid),
            Motion::Rigid => Some(Motion::Translation),
            Motion::Translation => None,
        }
    }
}

/// The 3 × 3 identity.
pub const IDENTITY: [[f64; 3]; 3] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

/// What alignment did to one frame.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct FrameAlignment {
    /// Reference pixel → this frame's pixel, full resolution (see the module docs); the
    /// identity when the frame was not moved.
    pub transform: [[f64; 3]; 3],
    /// The model applied; `None` when the frame is merged as it is.
    pub motion: Option<Motion>,
    /// The largest displacement of the estimated transform over the frame's corners, in
    /// pixels (0 when nothing was estimated).
    pub displacement_px: f64,
    /// Why the frame was not aligned or its model was simplified, when it was.
    pub note: Option<String>,
}

impl FrameAlignment {
    /// A frame merged as it is, with an optional reason.
    pub fn unmoved(note: Option<String>) -> FrameAlignment {
        FrameAlignment {
            transform: IDENTITY,
            motion: None,
            displacement_px: 0.0,
            note,
        }
    }

    /// The translation `T·c − c` at the frame's centre `c` and the rotation in degrees
    /// (of the transform's linear part).
    pub fn shift_and_rotation(&self, width: u32, height: u32) -> ((f64, f64), f64) {
        let t = &self.transform;
        let (cx, cy) = (
            f64::from(width.max(1) - 1) / 2.0,
            f64::from(height.max(1) - 1) / 2.0,
        );
        let w = t[2][0] * cx + t[2][1] * cy + t[2][2];
        let x = (t[0][0] * cx + t[0][1] * cy + t[0][2]) / w;
        let y = (t[1][0] * cx + t[1][1] * cy + t[1][2]) / w;
        let angle = (t[1][0] - t[0][1]).atan2(t[0][0] + t[1][1]).to_degrees();
        ((x - cx, y - cy), angle)
    }
}

/// What alignment did to a bracket: the reference frame and, per frame (input order), its
/// transform.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Alignment {
    /// The mode asked for.
    pub mode: AlignMode,
    /// The input index of the reference frame.
    pub reference: usize,
    /// Per frame, input order.
    pub frames: Vec<FrameAlignment>,
}

impl Alignment {
    /// No frame moved (mode `off`, or nothing to align).
    pub fn unmoved(mode: AlignMode, reference: usize, frames: usize, note: Option<String>) -> Self {
        Alignment {
            mode,
            reference,
            frames: (0..frames)
                .map(|k| FrameAlignment::unmoved(if k == reference { None } else { note.clone() }))
                .collect(),
        }
    }

    /// True when some frame is resampled.
    #[cfg(test)]
    pub(crate) fn moves_any(&self) -> bool {
        self.frames.iter().any(|f| f.motion.is_some())
    }

    /// One line per frame that was not aligned or was simplified, naming it by `names`
    /// (input order).
    pub fn notes(&self, names: &[String]) -> Vec<String> {
        self.frames
            .iter()
            .zip(names)
            .filter_map(|(f, name)| f.note.as_ref().map(|n| format!("{name}: alignment: {n}")))
            .collect()
    }

    /// The record the EXR header keeps (`filmbackAlignment`): the mode, the reference, and
    /// per frame its model, shift at the centre, rotation and 3 × 3 matrix (row by row).
    pub fn describe(&self, names: &[String], width: u32, height: u32) -> String {
        let mut text = format!(
            "mode {}; reference frame {} ({}); transforms map reference pixels to frame pixels",
            self.mode.as_str(),
            self.reference,
            names.get(self.reference).map_or("?", String::as_str)
        );
        for (k, (f, name)) in self.frames.iter().zip(names).enumerate() {
            let ((dx, dy), angle) = f.shift_and_rotation(width, height);
            let model = match f.motion {
                Some(m) => m.as_str().to_string(),
                None => "identity".to_string(),
            };
            let m = &f.transform;
            let _ = write!(
                text,
                "; frame {k} ({name}): {model}, shift ({dx:.3}, {dy:.3}) px, rotation {angle:.4} deg, \
                 matrix [{:.6} {:.6} {:.4}; {:.6} {:.6} {:.4}; {:.3e} {:.3e} {:.6}]",
                m[0][0], m[0][1], m[0][2], m[1][0], m[1][1], m[1][2], m[2][0], m[2][1], m[2][2]
            );
        }
        text
    }
}

/// One frame as alignment needs it.
#[derive(Debug, Clone, Copy)]
pub struct AlignFrame<'a> {
    /// The pixels.
    pub frame: &'a Frame,
    /// Relative exposure `e = t·S/N²`, > 0.
    pub exposure: f64,
}

/// The frame that exposes most of the scene well: the largest sum, over its pixels
/// (every fourth row and column) whose every channel is within
/// [`WELL_EXPOSED_LOW`]..=[`WELL_EXPOSED_HIGH`] of full scale, of the hat weight
/// `1 − |2B − 1|` of the pixel's worst channel (so a pixel in the mid-tones counts fully
/// and one near either end little); the first such frame on a tie. Alignment registers the
/// other frames onto it, and deghosting trusts it.
pub fn choose_reference(frames: &[&Frame]) -> usize {
    let mut best = (0, f64::NEG_INFINITY);
    for (k, frame) in frames.iter().enumerate() {
        let score = well_exposed_score(frame);
        if score > best.1 {
            best = (k, score);
        }
    }
    best.0
}

/// The code range `[low, high]` that counts as well exposed at `max_code`.
pub fn well_exposed_codes(max_code: u32) -> (u32, u32) {
    let max = f64::from(max_code);
    (
        (WELL_EXPOSED_LOW * max).ceil() as u32,
        (WELL_EXPOSED_HIGH * max).floor() as u32,
    )
}

/// The hat weight `1 − |2B − 1|` of brightness `B` when it is well exposed, else 0.
pub(super) fn exposure_weight(b: f64) -> f64 {
    if (WELL_EXPOSED_LOW..=WELL_EXPOSED_HIGH).contains(&b) {
        1.0 - (2.0 * b - 1.0).abs()
    } else {
        0.0
    }
}

/// The score [`choose_reference`] ranks frames by.
fn well_exposed_score(frame: &Frame) -> f64 {
    let max = frame.bit_depth().max_code();
    let weights: Vec<f64> = (0..=max)
        .map(|code| exposure_weight(f64::from(code) / f64::from(max)))
        .collect();
    match frame.samples() {
        Samples::Eight(v) => weighted_sum(frame, v, &weights),
        Samples::Sixteen(v) => weighted_sum(frame, v, &weights),
    }
}

/// Over every [`REFERENCE_STRIDE`]-th pixel of every such row of `frame` (its `codes`),
/// the least of its channels' `weights`, summed row by row in parallel and then in row
/// order (the same score on every call).
fn weighted_sum<T>(frame: &Frame, codes: &[T], weights: &[f64]) -> f64
where
    T: Copy + Into<usize> + Sync,
{
    let (w, c) = (frame.width() as usize, frame.channels());
    let rows: Vec<f64> = (0..frame.height() as usize)
        .into_par_iter()
        .step_by(REFERENCE_STRIDE)
        .map(|y| {
            let row = &codes[y * w * c..(y + 1) * w * c];
            row.chunks_exact(c)
                .step_by(REFERENCE_STRIDE)
                .map(|px| px.iter().map(|&s| weights[s.into()]).fold(1.0, f64::min))
                .sum::<f64>()
        })
        .collect();
    rows.iter().sum()
}

/// Aligns `frames` (JPEG, PNG or TIFF codes through the inverse response `g`) onto the
/// frame [`choose_reference`] picks, under `mode`: each frame's transform, model and any
/// fallback (see the module docs). The frames are not changed: [`warp_frames`] resamples
/// them.
pub fn align(frames: &[AlignFrame<'_>], response: &InverseResponse, mode: AlignMode) -> Alignment {
    let views: Vec<&Frame> = frames.iter().map(|f| f.frame).collect();
    let reference = choose_reference(&views);
    let Some(model) = mode.model() else {
        return Alignment::unmoved(mode, reference, frames.len(), None);
    };
    let first = frames[reference].frame;
    let shape = |f: &Frame| (f.width(), f.height(), f.channels(), f.bit_depth());
    if frames.iter().any(|f| shape(f.frame) != shape(first)) {
        // The merge refuses such a bracket, naming the files.
        let note = "the frames differ in size or depth: not aligned".to_string();
        return Alignment::unmoved(mode, reference, frames.len(), Some(note));
    }
    if first.width().min(first.height()) < SMALLEST_SIDE {
        let note = format!("the frames are under {SMALLEST_SIDE} pixels on a side: not aligned");
        return Alignment::unmoved(mode, reference, frames.len(), Some(note));
    }
    let step = estimate::step_for(first.width() as usize, first.height() as usize, 1);
    let convert = estimate::Convert::new(response, first.bit_depth(), first.channels());
    let pyramids: Vec<estimate::Pyramid> = frames
        .par_iter()
        .map(|f| estimate::Pyramid::of_frame(f.frame, &convert, f.exposure, step))
        .collect();
    let pictures: Vec<estimate::Codes<'_>> = frames
        .iter()
        .map(|f| estimate::Codes {
            frame: f.frame,
            convert: &convert,
        })
        .collect();
    let full: Vec<estimate::FullFrame<'_>> = frames
        .iter()
        .zip(&pictures)
        .map(|(f, picture)| estimate::FullFrame::new(picture, f.exposure))
        .collect();
    let full = (step > 1).then_some(full.as_slice());
    let geometry = estimate::Geometry::new(first.width(), first.height());
    let results = estimate::register_all(&pyramids, full, reference, &geometry, model);
    Alignment {
        mode,
        reference,
        frames: results,
    }
}

#[cfg(test)]
mod tests;
