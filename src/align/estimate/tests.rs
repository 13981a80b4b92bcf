//! The cluster-robust spread against the per-block one, the cells' sign test, and
//! where the damped refinement stops.

use super::*;

const W: usize = 256;
const H: usize = 192;

/// A smooth texture in log radiance at block `(x, y)`.
fn texture(x: f64, y: f64) -> f32 {
    (0.3 * (0.7 * x).sin() + 0.3 * (0.5 * y + 0.3 * x).sin() + 0.2 * (0.23 * y).cos()) as f32
}

/// A level of `log(x, y)` at step 1, every block usable with weight 1.
fn level(log: impl Fn(usize, usize) -> f32) -> Level {
    let values = (0..W * H).map(|i| log(i % W, i / W)).collect();
    Level::new(W, H, 1.0, values, vec![1.0; W * H])
}

/// The texture's level, its geometry and a homography at the identity.
fn at_identity() -> (Level, Geometry, State) {
    let state = State {
        motion: Motion::Homography,
        p: [0.0; 8],
        gain: 1.0,
        bias: 0.0,
    };
    let reference = level(|x, y| texture(x as f64, y as f64));
    (reference, Geometry::new(W as u32, H as u32), state)
}

/// The per-block and the cluster-robust spread of a homography at the identity between
/// the texture and `moving`, and the residual's RMS.
fn spreads(moving: &Level) -> (f64, f64, f64) {
    let (reference, geometry, state) = at_identity();
    let n = state.params();
    let normal = accumulate(&reference, moving, &geometry, &state, n);
    let cells = accumulate_cells(&reference, moving, &geometry, &state, n);
    (
        uncertainty_px(&normal, n, &geometry),
        robust_uncertainty_px(&cells, n, &geometry),
        normal.rms(),
    )
}

/// Every cell of the grid shifted by ±0.3 block, alternately: residuals that agree
/// within a cell. Independent noise of the same RMS: residuals that do not.
#[test]
fn residuals_that_agree_within_a_cell_widen_the_robust_spread_only() {
    let (cw, ch) = (W / CELLS, H / CELLS);
    let sign = |x: usize, y: usize| {
        if (x / cw + y / ch).is_multiple_of(2) {
            1.0
        } else {
            -1.0
        }
    };
    let patched = level(|x, y| texture(x as f64 + 0.3 * sign(x, y), y as f64));
    let (per_block, robust, rms) = spreads(&patched);
    // A uniform variate of the same RMS from a fixed linear congruential sequence.
    let mut state = 12_345u64;
    let mut noise = move || {
        state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1);
        ((state >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 12f64.sqrt()
    };
    // The RMS is weighted by 1/2 (two weights of 1), and the binomial smoothing keeps
    // √0.375 of the noise's standard deviation in each direction.
    let amplitude = rms / (0.5f64.sqrt() * 0.375);
    let values: Vec<f32> = (0..W * H)
        .map(|i| texture((i % W) as f64, (i / W) as f64) + (amplitude * noise()) as f32)
        .collect();
    let noisy = Level::new(W, H, 1.0, values, vec![1.0; W * H]);
    let (per_block_noise, robust_noise, rms_noise) = spreads(&noisy);
    assert!(
        (rms_noise / rms - 1.0).abs() < 0.35,
        "RMS {rms_noise:.4} against {rms:.4}"
    );
    assert!(
        per_block < 2.0 * per_block_noise && per_block_noise < 2.0 * per_block,
        "per block: {per_block:.4} patched, {per_block_noise:.4} noisy"
    );
    // The smoothing correlates neighbouring blocks' noise, which the per-block spread
    // ignores: up to √(1/0.375²) ≈ 2.7 times wider.
    assert!(
        (1.0..3.0).contains(&(robust_noise / per_block_noise)),
        "noise: robust {robust_noise:.4}, per block {per_block_noise:.4}"
    );
    assert!(
        robust > 4.0 * robust_noise,
        "robust: {robust:.4} patched, {robust_noise:.4} noisy (per block {per_block:.4})"
    );
}

/// A brightness falling off from the centre (vignetting, flare), in log radiance.
fn falloff(x: usize, y: usize) -> f32 {
    let (u, v) = (
        (x as f32 - W as f32 / 2.0) / W as f32,
        (y as f32 - H as f32 / 2.0) / W as f32,
    );
    -1.5 * (u * u + v * v)
}

/// The homography Gauss–Newton fits from the identity onto the texture.
fn fitted(moving: &Level) -> (State, Geometry) {
    let (reference, geometry, start) = at_identity();
    let (state, _) = refine((&reference, moving), &geometry, start, Convergence::Final)
        .expect("the texture registers");
    (state, geometry)
}

/// A still frame whose brightness falls off differently: the global gain and offset
/// leave the falloff for the homography to fit, the cells' own do not. The same frame
/// moved by 0.4 px keeps its move.
#[test]
fn a_brightness_falloff_does_not_pass_for_a_move() {
    let reference = level(|x, y| texture(x as f64, y as f64));
    let still = level(|x, y| texture(x as f64, y as f64) + falloff(x, y));
    let (state, geometry) = fitted(&still);
    let moved = geometry.displacement(&state.matrix());
    assert!(moved >= IDENTITY_PX, "the falloff fits as {moved:.3} px");
    let why = no_better_locally((&reference, &still), &geometry, &state, moved);
    assert!(why.is_some(), "a move of {moved:.3} px kept");

    let shifted = level(|x, y| texture(x as f64 + 0.4, y as f64) + falloff(x, y));
    let (state, geometry) = fitted(&shifted);
    let moved = geometry.displacement(&state.matrix());
    let why = no_better_locally((&reference, &shifted), &geometry, &state, moved);
    assert_eq!(why, None, "{state:?}");
}

/// Normal equations whose Gauss–Newton step moves the frame's corners by `px` pixels
/// (a translation along x), at a residual that every other state raises; and a count of
/// the passes [`damped`] asks for.
fn refused_step(px: f64) -> (usize, State) {
    let geometry = Geometry::new(W as u32, H as u32);
    let state = State {
        motion: Motion::Translation,
        p: [0.0; 8],
        gain: 1.0,
        bias: 0.0,
    };
    let mut start = Normal::zero();
    for k in 0..4 {
        start.jtj[k][k] = 1.0;
    }
    // δ = −A⁻¹b: a shift of `px` pixels is `px/s` in normalised units.
    start.jtr[0] = -px / geometry.s;
    start.count = MIN_SAMPLES;
    let passes = std::cell::Cell::new(0);
    let normal = |s: &State| {
        passes.set(passes.get() + 1);
        let mut raised = start.clone();
        raised.sse = if s.p == [0.0; 8] { 0.0 } else { 1.0 };
        raised
    };
    let (found, _) = damped(
        &geometry,
        1.0,
        state,
        start.clone(),
        &normal,
        Convergence::Within(0.01),
    )
    .expect("the start stands");
    (passes.get(), found)
}

#[test]
fn a_refused_step_under_twice_the_bound_ends_the_refinement() {
    let (passes, found) = refused_step(0.015);
    assert_eq!(passes, 1, "the step was damped further");
    assert_eq!(found.p, [0.0; 8]);
    // A refused step of 0.05 px says the state may be 0.025 px from the minimum: damped.
    let (passes, found) = refused_step(0.05);
    assert!(passes > 1, "{passes} passes");
    assert_eq!(found.p, [0.0; 8]);
}

/// A still frame whose finest level started far off (a rotation of 20° and a shift of 40
/// blocks, from which a rigid fit does not come back to the identity): its homography at
/// the identity yields to the rigid model refined from it, also at the identity.
#[test]
fn a_still_homography_yields_to_the_rigid_model_refined_from_it() {
    let (reference, geometry, state) = at_identity();
    let still = level(|x, y| texture(x as f64, y as f64));
    let fine = (&reference, &still);
    let normal = accumulate(fine.0, fine.1, &geometry, &state, state.params());
    let mut start = state.as_motion(Motion::Rigid);
    start.p[0] = 20f64.to_radians();
    start.p[1] = 40.0 / geometry.s;
    let kept = Kept {
        state,
        normal,
        start,
    };
    let kept = significant(fine, &geometry, kept, Convergence::Final);
    assert_eq!(kept.state.motion, Motion::Rigid, "{:?}", kept.state);
    let moved = geometry.displacement(&kept.state.matrix());
    assert!(moved < IDENTITY_PX, "moved {moved:.3} px");
}

/// The equations a pass over the samples gives after the gain and offset move, against
/// those [`Normal::with_photometric_step`] gives in closed form, for each model.
#[test]
fn a_gain_and_offset_step_moves_the_equations_as_a_new_pass_would() {
    let (reference, geometry, _) = at_identity();
    let moving = level(|x, y| 1.3 * texture(x as f64 + 0.4, y as f64 - 0.3) + 0.1);
    for motion in [Motion::Translation, Motion::Rigid, Motion::Homography] {
        let mut state = State {
            motion,
            p: [0.0; 8],
            gain: 0.8,
            bias: -0.02,
        };
        state.p[0] = 0.001;
        let n = state.params();
        let before = accumulate(&reference, &moving, &geometry, &state, n);
        let step = [0.15, -0.04];
        let moved = State {
            gain: state.gain + step[0],
            bias: state.bias + step[1],
            ..state
        };
        let pass = accumulate(&reference, &moving, &geometry, &moved, n);
        let closed = before.with_photometric_step(n, state.gain, step);
        let near = |a: f64, b: f64| (a - b).abs() <= 1e-9 * (1.0 + a.abs().max(b.abs()));
        assert_eq!(closed.count, pass.count);
        assert!(
            near(closed.sse, pass.sse),
            "{motion:?}: Σr² {} against {}",
            closed.sse,
            pass.sse
        );
        for i in 0..n + 2 {
            assert!(near(closed.jtr[i], pass.jtr[i]), "{motion:?}: Jᵀr[{i}]");
            for j in i..n + 2 {
                assert!(
                    near(closed.jtj[i][j], pass.jtj[i][j]),
                    "{motion:?}: JᵀJ[{i}][{j}]"
                );
            }
        }
    }
}
