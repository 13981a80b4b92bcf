//! The refinement's copies of a frame's pixels.

use super::*;

/// A picture whose pixel `(x, y)` has value `1 + x + 100·y` and weight `y + 0.5`, every
/// other pixel of row 7 not well exposed.
struct Ramp {
    width: usize,
    height: usize,
}

impl Picture for Ramp {
    fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    fn step(&self) -> usize {
        1
    }

    fn pixel(&self, x: usize, y: usize) -> (f32, f32) {
        let weight = if y == 7 && x % 2 == 1 {
            0.0
        } else {
            y as f32 + 0.5
        };
        ((1 + x + 100 * y) as f32, weight)
    }

    fn row(&self, y: usize, values: &mut [f32], weights: &mut [f32]) {
        for (x, (value, weight)) in values.iter_mut().zip(weights).enumerate() {
            (*value, *weight) = self.pixel(x, y);
        }
    }
}

const RAMP: Ramp = Ramp {
    width: 40,
    height: 30,
};

/// The four pixels of a bilinear sample at `(x0, y0)`, read from the picture.
fn read(x0: usize, y0: usize) -> [(f32, f32); 4] {
    [(0, 0), (1, 0), (0, 1), (1, 1)].map(|(dx, dy)| RAMP.pixel(x0 + dx, y0 + dy))
}

/// Around a pixel the copy serves every quad within a pixel of it, and no other; at the
/// picture's edges it moves inside and serves what it holds.
#[test]
fn a_copy_serves_the_quads_it_holds_and_no_others() {
    for (x, y) in [(10, 12), (0, 0), (39, 29), (38, 1)] {
        let copy = Patch::around(&RAMP, x, y);
        for y0 in y.saturating_sub(3)..(y + 3).min(RAMP.height - 1) {
            for x0 in x.saturating_sub(3)..(x + 3).min(RAMP.width - 1) {
                let held = (copy.x..copy.x + Patch::SIDE - 1).contains(&x0)
                    && (copy.y..copy.y + Patch::SIDE - 1).contains(&y0);
                match copy.quad(x0, y0) {
                    Some(quad) => {
                        assert!(held, "({x0}, {y0}) served from ({}, {})", copy.x, copy.y);
                        assert_eq!(quad, read(x0, y0), "({x0}, {y0})");
                    }
                    None => assert!(!held, "({x0}, {y0}) not served"),
                }
            }
        }
        for (x0, y0) in [(x.saturating_sub(1), y.saturating_sub(1)), (x, y)] {
            if x0 + 1 < RAMP.width && y0 + 1 < RAMP.height {
                assert!(
                    copy.quad(x0, y0).is_some(),
                    "({x0}, {y0}) around ({x}, {y})"
                );
            }
        }
    }
}

/// A sample reads the same through a copy that holds its quad as through one far from
/// it (which falls back on the picture), including where a pixel is not well exposed.
#[test]
fn a_sample_is_the_same_through_any_copy() {
    let frame = FullFrame::new(&RAMP, 2.0);
    let far = Patch::around(&RAMP, 35, 25);
    for (x, y) in [
        (10.25, 12.5),
        (11.9, 6.4),
        (3.0, 7.0),
        (0.5, 0.5),
        (38.2, 28.7),
    ] {
        let copy = Patch::around(&RAMP, x as usize, y as usize);
        let through = frame.sample(x, y, &copy);
        assert_eq!(through, frame.sample(x, y, &far), "({x}, {y})");
        let unusable = y.floor() as usize == 7 || y.floor() as usize == 6;
        assert_eq!(through.is_none(), unusable, "({x}, {y}): {through:?}");
    }
}
