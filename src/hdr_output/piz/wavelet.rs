//! OpenEXR's PIZ wavelet: a two-dimensional Haar-like transform of one channel of ranked
//! 16-bit words, in place.
//!
//! Each lifting step maps a pair `(a, b)` to `(⌊(a + b)/2⌋, a − b)`: in 16-bit two's
//! complement when every word is below 2¹⁴ ([`lift14`]), otherwise modulo 2¹⁶ with a
//! 2¹⁵ offset ([`lift16`]), so that the step is invertible for any pair of 16-bit words.
//! Levels `p = 1, 2, 4, …` lift the corners of each `2p × 2p` cell along x, then along y.

/// `(a, b) → (⌊(a + b)/2⌋, a − b)` in 16-bit two's complement (words below 2¹⁴).
#[inline(always)]
fn lift14(a: u16, b: u16) -> (u16, u16) {
    let (a, b) = (i32::from(a as i16), i32::from(b as i16));
    (((a + b) >> 1) as u16, (a - b) as u16)
}

/// The same step modulo 2¹⁶, invertible for any pair of 16-bit words: with
/// `a' = (a + 2¹⁵) mod 2¹⁶` and `d = a' − b`, returns `(⌊(a' + b)/2⌋ + 2¹⁵·[d < 0],
/// d)`, both modulo 2¹⁶.
#[inline(always)]
fn lift16(a: u16, b: u16) -> (u16, u16) {
    const OFFSET: i32 = 1 << 15;
    const MASK: i32 = 0xffff;
    let ao = (i32::from(a) + OFFSET) & MASK;
    let mut m = (ao + i32::from(b)) >> 1;
    let d = ao - i32::from(b);
    if d < 0 {
        m = (m + OFFSET) & MASK;
    }
    (m as u16, (d & MASK) as u16)
}

/// OpenEXR's two-dimensional wavelet on one `nx × ny` channel (row-major), in place.
pub(super) fn wavelet_encode(data: &mut [u16], nx: usize, ny: usize, max: u16) {
    if max < 1 << 14 {
        wavelet_levels(data, nx, ny, lift14);
    } else {
        wavelet_levels(data, nx, ny, lift16);
    }
}

/// Level `p = 1, 2, 4, …` while `2p ≤ min(nx, ny)`: each `2p × 2p` cell's corners
/// `(x, y), (x+p, y), (x, y+p), (x+p, y+p)` are lifted along x then y; an odd column or
/// line left over at a level is lifted in one dimension.
#[inline(always)]
fn wavelet_levels(data: &mut [u16], nx: usize, ny: usize, lift: impl Fn(u16, u16) -> (u16, u16)) {
    let n = nx.min(ny);
    let mut p = 1;
    while 2 * p <= n {
        let p2 = 2 * p;
        let mut y = 0;
        while y + p2 <= ny {
            let (top, bottom) = data.split_at_mut((y + p) * nx);
            let top = &mut top[y * nx..y * nx + nx];
            let bottom = &mut bottom[..nx];
            let mut x = 0;
            while x + p2 <= nx {
                let (i00, i01) = lift(top[x], top[x + p]);
                let (i10, i11) = lift(bottom[x], bottom[x + p]);
                (top[x], bottom[x]) = lift(i00, i10);
                (top[x + p], bottom[x + p]) = lift(i01, i11);
                x += p2;
            }
            if nx & p != 0 {
                (top[x], bottom[x]) = lift(top[x], bottom[x]);
            }
            y += p2;
        }
        if ny & p != 0 {
            let row = &mut data[y * nx..y * nx + nx];
            let mut x = 0;
            while x + p2 <= nx {
                (row[x], row[x + p]) = lift(row[x], row[x + p]);
                x += p2;
            }
        }
        p = p2;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lifts_are_undone_by_the_readers_inverse() {
        // OpenEXR's inverse steps (ImfWav.cpp, wdec14/wdec16), written independently.
        let unlift14 = |l: u16, h: u16| {
            let (ls, hs) = (i32::from(l as i16), i32::from(h as i16));
            let hi = hs;
            let ai = ls + (hi & 1) + (hi >> 1);
            (ai as u16, (ai - hi) as u16)
        };
        let unlift16 = |l: u16, h: u16| {
            let (m, d) = (i32::from(l), i32::from(h));
            let b = (m - (d >> 1)) & 0xffff;
            let a = (d + b - (1 << 15)) & 0xffff;
            (a as u16, b as u16)
        };
        for a in (0..=u16::MAX).step_by(13) {
            // Every 211th b, and the b that makes the offset difference zero.
            let partners = (0..=u16::MAX).step_by(211).chain([a.wrapping_add(1 << 15)]);
            for b in partners {
                let (l, h) = lift16(a, b);
                assert_eq!(unlift16(l, h), (a, b), "16-bit ({a}, {b})");
                if a < 1 << 14 && b < 1 << 14 {
                    let (l, h) = lift14(a, b);
                    assert_eq!(unlift14(l, h), (a, b), "14-bit ({a}, {b})");
                }
            }
        }
    }
}
