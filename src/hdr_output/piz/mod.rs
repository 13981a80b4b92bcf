//! OpenEXR's PIZ compression, encoder side, for scan-line blocks of half samples.
//!
//! It writes the same format as the exr crate's PIZ encoder, faster (measured in
//! `docs/performance.md`) because its Huffman stage packs codes through a 64-bit bit accumulator instead of writing one byte
//! at a time through `io::Write`. Any conforming reader decodes it (the tests decode with
//! the exr crate, `tests/openexr_check.py` with the OpenEXR library); other compressions
//! and float samples go through exr's encoders.
//!
//! One block, all integers little-endian:
//! 1. The samples as 16-bit words, channel by channel (each channel's lines contiguous).
//! 2. The set of words used, as a 2¹⁶-bit bitmap of 8 192 bytes (word 0 is implied, its
//!    bit not set; word `w` is bit `w mod 8` of byte `⌊w/8⌋`), stored as the `u16`
//!    indices of the first and last non-zero byte and those bytes (first > last when the
//!    bitmap is empty).
//! 3. Each word replaced by its rank in that set (0 for word 0, `1..=max` for the used
//!    words in increasing order), so the values are `0..=max` with no gaps.
//! 4. Per channel, the two-dimensional Haar-like wavelet of [`wavelet`]: pairs `(a, b)`
//!    become `(⌊(a + b)/2⌋, a − b)`, in 16-bit two's complement when `max < 2¹⁴`, else
//!    modulo 2¹⁶ with offsets.
//! 5. An `i32` byte count, then the canonical Huffman code of [`huffman`] over the words
//!    plus one run symbol for runs of up to 256 equal words.

mod huffman;
mod wavelet;

use huffman::huffman_encode;
use wavelet::wavelet_encode;

/// Bytes of the bitmap of used words: 2¹⁶ bits / 8.
const BITMAP_BYTES: usize = (1 << 16) / 8;

/// PIZ-compresses one block. `words` holds the block's half samples as bits, channel by
/// channel, each channel `lines × width` in line order; it is overwritten (ranked and
/// wavelet-transformed). Returns `None` when no Huffman code fits the format's 58-bit
/// limit (it cannot happen below ~10¹² samples per block); the caller then stores the
/// block uncompressed, as it must also do when the result is not smaller than the input.
pub(super) fn compress(words: &mut [u16], width: usize, lines: usize) -> Option<Vec<u8>> {
    let plane = width * lines;
    debug_assert!(plane > 0 && words.len().is_multiple_of(plane));

    // Marking words in a byte per word stores without reading back (no dependency
    // between equal neighbours), then the bitmap is packed from the marks.
    let mut used = vec![false; 1 << 16];
    for &w in words.iter() {
        used[usize::from(w)] = true;
    }
    used[0] = false;
    let mut bitmap = vec![0u8; BITMAP_BYTES];
    for (byte, marks) in bitmap.iter_mut().zip(used.chunks_exact(8)) {
        *byte = marks
            .iter()
            .enumerate()
            .fold(0, |b, (k, &m)| b | (u8::from(m) << k));
    }
    let first = bitmap.iter().position(|&b| b != 0);
    let last = bitmap.iter().rposition(|&b| b != 0);

    // Rank of each used word (0 always has rank 0).
    let mut rank = vec![0u16; 1 << 16];
    let mut max = 0u16;
    for (r, &u) in rank.iter_mut().zip(&used) {
        if u {
            max += 1;
            *r = max;
        }
    }
    for w in words.iter_mut() {
        *w = rank[usize::from(*w)];
    }
    for channel in words.chunks_exact_mut(plane) {
        wavelet_encode(channel, width, lines, max);
    }

    let mut out = Vec::with_capacity(words.len());
    match (first, last) {
        (Some(first), Some(last)) => {
            out.extend_from_slice(&(first as u16).to_le_bytes());
            out.extend_from_slice(&(last as u16).to_le_bytes());
            out.extend_from_slice(&bitmap[first..=last]);
        }
        _ => {
            out.extend_from_slice(&((BITMAP_BYTES - 1) as u16).to_le_bytes());
            out.extend_from_slice(&0u16.to_le_bytes());
        }
    }
    let length_at = out.len();
    out.extend_from_slice(&[0; 4]);
    huffman_encode(words, &mut out)?;
    let length = (out.len() - length_at - 4) as i32;
    out[length_at..length_at + 4].copy_from_slice(&length.to_le_bytes());
    Some(out)
}
