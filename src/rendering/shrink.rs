//! Small copies of renderings made while they are developed, for previews: the 8-bit
//! RGB rows handed to the encoder are averaged over square blocks of `f × f` pixels,
//! `f = ⌈max(width, height) / edge⌉`, so the copy's long edge is at most `edge` and no
//! rendering is decoded again to show it. Blocks at the right and bottom edges average
//! the pixels they hold. The averages are of the encoded 8-bit values.

use std::sync::{Mutex, PoisonError};

/// Collects the block sums of one rendering; rows may arrive in any order, from any
/// thread, each row once.
#[derive(Debug)]
pub(crate) struct Shrink {
    width: u32,
    height: u32,
    factor: u32,
    /// Per block and channel, the sum of the 8-bit values added so far.
    sums: Mutex<Vec<u32>>,
}

/// A small 8-bit sRGB copy of a rendering.
#[derive(Debug, Clone, PartialEq)]
pub struct Preview {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Interleaved RGB, `3 · width · height` bytes, rows top down.
    pub rgb: Vec<u8>,
}

impl Shrink {
    /// Collects a copy of a `width × height` rendering with a long edge of at most `edge`
    /// pixels (`edge ≥ 1`).
    pub fn new(width: u32, height: u32, edge: u32) -> Shrink {
        let factor = width.max(height).div_ceil(edge.max(1)).max(1);
        let (w, h) = (width.div_ceil(factor), height.div_ceil(factor));
        Shrink {
            width,
            height,
            factor,
            sums: Mutex::new(vec![0; w as usize * h as usize * 3]),
        }
    }

    /// The copy's size, `(⌈width / f⌉, ⌈height / f⌉)`.
    pub fn size(&self) -> (u32, u32) {
        (
            self.width.div_ceil(self.factor),
            self.height.div_ceil(self.factor),
        )
    }

    /// Adds whole rows of 8-bit RGB starting at row `first` (`rgb.len()` a multiple of
    /// `3 · width`; a partial last row and rows beyond the height are left out).
    pub(crate) fn add_rows(&self, first: usize, rgb: &[u8]) {
        let row = self.width as usize * 3;
        let rows = (rgb.len() / row.max(1)).min((self.height as usize).saturating_sub(first));
        if rows == 0 {
            return;
        }
        let f = self.factor as usize;
        let line = self.size().0 as usize * 3;
        let first_block = first / f;
        let blocks = (first + rows - 1) / f + 1 - first_block;
        let mut local = vec![0u32; blocks * line];
        for (r, pixels) in rgb.chunks_exact(row).take(rows).enumerate() {
            let sums = &mut local[((first + r) / f - first_block) * line..][..line];
            for (sum, block) in sums.chunks_exact_mut(3).zip(pixels.chunks(3 * f)) {
                for px in block.chunks_exact(3) {
                    sum[0] += u32::from(px[0]);
                    sum[1] += u32::from(px[1]);
                    sum[2] += u32::from(px[2]);
                }
            }
        }
        let mut sums = self.sums.lock().unwrap_or_else(PoisonError::into_inner);
        for (s, l) in sums[first_block * line..].iter_mut().zip(&local) {
            *s += l;
        }
    }

    /// The copy: each block's sum over the pixels it holds, rounded to the nearest code.
    pub fn finish(self) -> Preview {
        let (w, h) = self.size();
        let f = self.factor;
        let sums = self
            .sums
            .into_inner()
            .unwrap_or_else(PoisonError::into_inner);
        let mut rgb = Vec::with_capacity(sums.len());
        for y in 0..h {
            let rows = f.min(self.height - y * f);
            for x in 0..w {
                let count = rows * f.min(self.width - x * f);
                let at = (y as usize * w as usize + x as usize) * 3;
                for s in &sums[at..at + 3] {
                    rgb.push(((s + count / 2) / count) as u8);
                }
            }
        }
        Preview {
            width: w,
            height: h,
            rgb,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blocks_average_what_they_hold() {
        // 5 × 3 to an edge of 2: f = 3, a 2 × 1 copy; the right block holds 2 × 3 pixels.
        let mut rgb = Vec::new();
        for y in 0..3u8 {
            for x in 0..5u8 {
                rgb.extend_from_slice(&[10 * x, y, 200]);
            }
        }
        let shrink = Shrink::new(5, 3, 2);
        // Rows out of order, as bands finish.
        shrink.add_rows(2, &rgb[30..]);
        shrink.add_rows(0, &rgb[..30]);
        let p = shrink.finish();
        assert_eq!((p.width, p.height), (2, 1));
        assert_eq!(p.rgb, vec![10, 1, 200, 35, 1, 200]);
    }

    #[test]
    fn a_small_rendering_is_copied_as_it_is() {
        let rgb: Vec<u8> = (0..4 * 2 * 3).map(|v| v as u8).collect();
        let shrink = Shrink::new(4, 2, 16);
        shrink.add_rows(0, &rgb);
        let p = shrink.finish();
        assert_eq!((p.width, p.height, p.rgb), (4, 2, rgb));
    }

    #[test]
    fn the_long_edge_fits() {
        for (w, h, edge) in [
            (6000, 4000, 1600),
            (3000, 2000, 1600),
            (1601, 10, 1600),
            (7, 9000, 256),
        ] {
            let (pw, ph) = Shrink::new(w, h, edge).size();
            assert!(
                pw.max(ph) <= edge && pw.max(ph) > edge / 2,
                "{w}×{h} → {pw}×{ph}"
            );
        }
    }
}
