//! OpenEXR's Huffman coder for PIZ: a canonical Huffman code over the 2¹⁶ word values
//! plus one run symbol, written MSB first through a 64-bit bit accumulator.
//!
//! Output, all integers little-endian: five `u32` (first symbol = smallest word present,
//! run symbol = largest word present + 1, bytes of the code table, bits of code, 0); the
//! code table, one 6-bit length per symbol from the first to the run symbol, with 59–62
//! standing for `2..=5` absent symbols (59 + n − 2) and 63 followed by `n − 6` in 8 bits
//! for `6..=261`; then the codes, the last byte padded with zero bits. A run of `n + 1`
//! equal words (`1 ≤ n ≤ 255`) whose code has `l_w` bits is sent as the word's code, the
//! run symbol's code (`l_run` bits) and `n` in 8 bits when `l_w + l_run + 8 < n·l_w`
//! (OpenEXR's rule), otherwise as `n + 1` copies of the word's code.

/// Symbols of the Huffman code: the 65 536 words and the run symbol after the last used word.
const SYMBOLS: usize = (1 << 16) + 1;
/// Longest code a 6-bit length can state (59–63 mark runs of absent symbols).
const MAX_CODE_BITS: u8 = 58;
/// Packed-table code for 2..=5 absent symbols (59 + n − 2).
const SHORT_ZERO_RUN: u64 = 59;
/// Packed-table code for 6..=261 absent symbols, followed by n − 6 in 8 bits.
const LONG_ZERO_RUN: u64 = 63;
const SHORTEST_LONG_RUN: usize = 2 + (LONG_ZERO_RUN - SHORT_ZERO_RUN) as usize;
const LONGEST_LONG_RUN: usize = 255 + SHORTEST_LONG_RUN;

/// MSB-first bit writer over a byte vector.
struct Bits<'a> {
    out: &'a mut Vec<u8>,
    acc: u64,
    pending: u32,
    total: u64,
}

impl<'a> Bits<'a> {
    fn new(out: &'a mut Vec<u8>) -> Self {
        Bits {
            out,
            acc: 0,
            pending: 0,
            total: 0,
        }
    }

    /// Appends the low `len ≤ 58` bits of `value`.
    #[inline(always)]
    fn put(&mut self, value: u64, len: u32) {
        if len > 32 {
            self.put_long(value, len);
        } else {
            self.put_short(value, len);
        }
    }

    #[cold]
    fn put_long(&mut self, value: u64, len: u32) {
        self.put_short(value >> 32, len - 32);
        self.put_short(value & 0xffff_ffff, 32);
    }

    /// Appends the low `len ≤ 32` bits of `value`.
    #[inline(always)]
    fn put_short(&mut self, value: u64, len: u32) {
        self.acc = (self.acc << len) | value;
        self.pending += len;
        self.total += u64::from(len);
        if self.pending >= 32 {
            self.pending -= 32;
            let word = (self.acc >> self.pending) as u32;
            self.out.extend_from_slice(&word.to_be_bytes());
        }
    }

    /// Flushes, padding the last byte with zeros; returns the number of bits written.
    fn finish(mut self) -> u64 {
        while self.pending >= 8 {
            self.pending -= 8;
            self.out.push((self.acc >> self.pending) as u8);
        }
        if self.pending > 0 {
            self.out.push((self.acc << (8 - self.pending)) as u8);
        }
        self.total
    }
}

/// Appends OpenEXR's Huffman encoding of `words` (non-empty) to `out`.
pub(super) fn huffman_encode(words: &[u16], out: &mut Vec<u8>) -> Option<()> {
    // Counted in two interleaved tables so that runs of one word do not wait on
    // their own previous increment.
    let mut frequency = vec![0u64; SYMBOLS];
    let mut odd = vec![0u64; SYMBOLS];
    let pairs = words.chunks_exact(2);
    if let [w] = pairs.remainder() {
        frequency[usize::from(*w)] += 1;
    }
    for pair in pairs {
        frequency[usize::from(pair[0])] += 1;
        odd[usize::from(pair[1])] += 1;
    }
    for (f, o) in frequency.iter_mut().zip(&odd) {
        *f += o;
    }
    let first = frequency.iter().position(|&f| f > 0)?;
    let run_symbol = frequency.iter().rposition(|&f| f > 0)? + 1;
    frequency[run_symbol] = 1;
    let lengths = code_lengths(&frequency[first..=run_symbol])?;
    let codes = canonical_codes(&lengths);

    let header_at = out.len();
    out.extend_from_slice(&[0; 20]);

    // The code table: lengths, runs of absent symbols shortened.
    let table_at = out.len();
    let mut bits = Bits::new(out);
    let mut s = 0;
    while s < lengths.len() {
        if lengths[s] == 0 {
            let mut zeros = 1;
            while s + 1 < lengths.len() && zeros < LONGEST_LONG_RUN && lengths[s + 1] == 0 {
                s += 1;
                zeros += 1;
            }
            if zeros >= SHORTEST_LONG_RUN {
                bits.put(LONG_ZERO_RUN, 6);
                bits.put((zeros - SHORTEST_LONG_RUN) as u64, 8);
                s += 1;
                continue;
            }
            if zeros >= 2 {
                bits.put(SHORT_ZERO_RUN + zeros as u64 - 2, 6);
                s += 1;
                continue;
            }
        }
        bits.put(u64::from(lengths[s]), 6);
        s += 1;
    }
    bits.finish();
    let table_bytes = out.len() - table_at;

    // The data. Codes are packed as `code << 6 | length`, as in OpenEXR.
    let code = |w: u16| codes[usize::from(w) - first];
    let run = codes[run_symbol - first];
    let (run_code, run_len) = (run >> 6, (run & 63) as u32);
    let mut bits = Bits::new(out);
    let mut send = |word: u16, repeats: u32| {
        let c = code(word);
        let (c, len) = (c >> 6, (c & 63) as u32);
        if repeats == 0 {
            bits.put(c, len);
        } else if len + run_len + 8 < len * repeats {
            bits.put(c, len);
            bits.put(run_code, run_len);
            bits.put(u64::from(repeats), 8);
        } else {
            for _ in 0..=repeats {
                bits.put(c, len);
            }
        }
    };
    let mut current = words[0];
    let mut repeats = 0u32;
    for &w in &words[1..] {
        if w == current && repeats < 255 {
            repeats += 1;
        } else {
            send(current, repeats);
            current = w;
            repeats = 0;
        }
    }
    send(current, repeats);
    let data_bits = bits.finish();

    let header = [
        first as u32,
        run_symbol as u32,
        table_bytes as u32,
        u32::try_from(data_bits).ok()?,
        0,
    ];
    for (k, v) in header.iter().enumerate() {
        out[header_at + 4 * k..header_at + 4 * k + 4].copy_from_slice(&v.to_le_bytes());
    }
    Some(())
}

/// Huffman code lengths for `frequency` (zero for absent symbols; at least two present),
/// by the two-queue construction over the symbols sorted by frequency. `None` if a code
/// would exceed [`MAX_CODE_BITS`].
fn code_lengths(frequency: &[u64]) -> Option<Vec<u8>> {
    let mut leaves: Vec<(u64, u32)> = frequency
        .iter()
        .enumerate()
        .filter(|(_, f)| **f > 0)
        .map(|(s, &f)| (f, s as u32))
        .collect();
    leaves.sort_unstable();
    let n = leaves.len();
    let mut lengths = vec![0u8; frequency.len()];
    if n < 2 {
        if let Some(&(_, s)) = leaves.first() {
            lengths[s as usize] = 1;
        }
        return Some(lengths);
    }
    // Nodes 0..n are the leaves, n..2n−1 the merged nodes in order of creation (their
    // weights never decrease, so the next smallest is at the head of one of the queues).
    let mut weight: Vec<u64> = leaves.iter().map(|l| l.0).collect();
    weight.reserve(n - 1);
    let mut parent = vec![0u32; 2 * n - 1];
    let (mut leaf, mut merged) = (0, n);
    for node in n..2 * n - 1 {
        let mut take = || {
            if leaf < n && (merged == node || weight[leaf] <= weight[merged]) {
                leaf += 1;
                leaf - 1
            } else {
                merged += 1;
                merged - 1
            }
        };
        let (a, b) = (take(), take());
        weight.push(weight[a] + weight[b]);
        parent[a] = node as u32;
        parent[b] = node as u32;
    }
    let mut depth = vec![0u8; 2 * n - 1];
    for node in (0..2 * n - 2).rev() {
        depth[node] = depth[parent[node] as usize].checked_add(1)?;
    }
    for (k, &(_, s)) in leaves.iter().enumerate() {
        if depth[k] > MAX_CODE_BITS {
            return None;
        }
        lengths[s as usize] = depth[k];
    }
    Some(lengths)
}

/// OpenEXR's canonical code for the given lengths: codes are handed out from the longest
/// length to the shortest, within a length in symbol order. Returns `code << 6 | length`.
fn canonical_codes(lengths: &[u8]) -> Vec<u64> {
    let mut next = [0u64; MAX_CODE_BITS as usize + 1];
    for &l in lengths {
        next[usize::from(l)] += 1;
    }
    let mut c = 0u64;
    for l in (1..=usize::from(MAX_CODE_BITS)).rev() {
        let following = (c + next[l]) >> 1;
        next[l] = c;
        c = following;
    }
    lengths
        .iter()
        .map(|&l| {
            if l == 0 {
                return 0;
            }
            let code = next[usize::from(l)];
            next[usize::from(l)] += 1;
            code << 6 | u64::from(l)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn huffman_lengths_form_a_complete_prefix_code() {
        // Kraft: Σ 2^-l = 1 for a complete code; frequent symbols get short codes.
        let mut frequency = vec![0u64; 300];
        for (s, f) in frequency.iter_mut().enumerate().step_by(3) {
            *f = 1 + (s as u64 * 7919) % 1000;
        }
        frequency[150] = 1_000_000;
        let lengths = code_lengths(&frequency).unwrap();
        let kraft: f64 = lengths
            .iter()
            .filter(|&&l| l > 0)
            .map(|&l| (-f64::from(l)).exp2())
            .sum();
        assert!((kraft - 1.0).abs() < 1e-12, "{kraft}");
        assert_eq!(lengths[150], 1);
        assert!(
            lengths
                .iter()
                .zip(&frequency)
                .all(|(l, f)| (*l == 0) == (*f == 0))
        );

        // Canonical codes are prefix-free.
        let codes = canonical_codes(&lengths);
        let used: Vec<(u64, u64)> = codes
            .iter()
            .filter(|c| *c & 63 > 0)
            .map(|c| (c >> 6, c & 63))
            .collect();
        for a in &used {
            for b in &used {
                if a != b && a.1 <= b.1 {
                    assert_ne!(b.0 >> (b.1 - a.1), a.0, "{a:?} is a prefix of {b:?}");
                }
            }
        }
    }

    #[test]
    fn bits_are_written_most_significant_first() {
        let mut out = Vec::new();
        let mut bits = Bits::new(&mut out);
        bits.put(0b101, 3);
        bits.put(0x3_ffff_ffff_ffff, 50);
        bits.put(0, 4);
        bits.put(1, 1);
        assert_eq!(bits.finish(), 58);
        // 101 + fifty ones + 0000 + 1, padded: 10111111 ×6 … then 1 0000 1 00 (pad).
        let mut want = String::from("101");
        want.push_str(&"1".repeat(50));
        want.push_str("00001");
        want.push_str("000000");
        let got: String = out.iter().map(|b| format!("{b:08b}")).collect();
        assert_eq!(got, want);
    }
}
