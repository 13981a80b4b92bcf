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

/// Longest value [`Bits::put`] takes: with at most 7 bits pending, the accumulator then
/// holds at most 64.
const PUT_BITS: u32 = 57;

/// MSB-first bit writer into a slice grown in advance by the caller. After each value the
/// whole accumulator is stored as 8 big-endian bytes and the position advanced by the
/// whole bytes written, so at most 7 bits stay pending; the next store rewrites the
/// partial byte, and the slice must have 8 bytes to spare past the last one.
struct Bits<'a> {
    buf: &'a mut [u8],
    /// Bytes completed.
    pos: usize,
    /// The pending bits in its low `pending` bits (higher bits are stale).
    acc: u64,
    pending: u32,
}

impl<'a> Bits<'a> {
    fn new(buf: &'a mut [u8]) -> Self {
        Bits {
            buf,
            pos: 0,
            acc: 0,
            pending: 0,
        }
    }

    /// Appends the low `1 ≤ len ≤ 57` bits of `value` (no higher bits set).
    #[inline(always)]
    fn put(&mut self, value: u64, len: u32) {
        debug_assert!((1..=PUT_BITS).contains(&len) && value >> len == 0);
        self.acc = (self.acc << len) | value;
        self.pending += len;
        let aligned = self.acc << (64 - self.pending);
        self.buf[self.pos..self.pos + 8].copy_from_slice(&aligned.to_be_bytes());
        self.pos += (self.pending >> 3) as usize;
        self.pending &= 7;
    }

    /// Appends the low `1 ≤ len ≤ 58` bits of `value`, in two parts when longer than
    /// [`Bits::put`] takes.
    #[inline(always)]
    fn put_any(&mut self, value: u64, len: u32) {
        if len > PUT_BITS {
            self.put(value >> 32, len - 32);
            self.put(value & 0xffff_ffff, 32);
        } else {
            self.put(value, len);
        }
    }

    /// Bits written, and bytes holding them (the last padded with zeros).
    fn finish(self) -> (u64, usize) {
        let bits = 8 * self.pos as u64 + u64::from(self.pending);
        (bits, self.pos + usize::from(self.pending > 0))
    }
}

/// Appends OpenEXR's Huffman encoding of `words` (non-empty) to `out`.
pub(super) fn huffman_encode(words: &[u16], out: &mut Vec<u8>) -> Option<()> {
    let mut frequency = word_frequencies(words);
    let first = frequency.iter().position(|&f| f > 0)?;
    let run_symbol = frequency.iter().rposition(|&f| f > 0)? + 1;
    frequency[run_symbol] = 1;
    let frequency = &frequency[first..=run_symbol];
    let lengths = code_lengths(frequency)?;
    let codes = canonical_codes(&lengths);

    let header_at = out.len();
    out.extend_from_slice(&[0; 20]);

    let table_bytes = write_code_table(&lengths, out);

    // The data: each word costs at most its code (a run is sent as one only when
    // shorter), so Σ frequency·length bounds the bits.
    let data_at = out.len();
    let bound: u64 = frequency
        .iter()
        .zip(&lengths)
        .map(|(&f, &l)| f * u64::from(l))
        .sum();
    out.resize(data_at + usize::try_from(bound / 8).ok()? + 9, 0);
    let longest = u32::from(lengths.iter().copied().max().unwrap_or(0));
    let data = &mut out[data_at..];
    let run = codes[run_symbol - first];
    let (data_bits, data_bytes) = if longest > PUT_BITS {
        pack_words::<true, false>(words, &codes, first, run, data)
    } else if 2 * longest > PUT_BITS {
        pack_words::<false, false>(words, &codes, first, run, data)
    } else {
        pack_words::<false, true>(words, &codes, first, run, data)
    };
    out.truncate(data_at + data_bytes);

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

/// How often each word occurs in `words`, by word. Counted in two interleaved tables so
/// that runs of one word do not wait on their own previous increment.
fn word_frequencies(words: &[u16]) -> Vec<u64> {
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
    frequency
}

/// Appends the code table to `out`: the code `lengths`, runs of absent symbols
/// shortened; at most 6 bits a symbol. Returns its bytes.
fn write_code_table(lengths: &[u8], out: &mut Vec<u8>) -> usize {
    let table_at = out.len();
    out.resize(table_at + lengths.len() * 6 / 8 + 9, 0);
    let mut bits = Bits::new(&mut out[table_at..]);
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
    let (_, table_bytes) = bits.finish();
    out.truncate(table_at + table_bytes);
    table_bytes
}

/// Words checked at once for a stretch without runs.
const STRETCH: usize = 16;

/// Writes the codes of `words` into `buf` (large enough: see [`Bits`]), runs of `n + 1`
/// equal words (`1 ≤ n ≤ 255`) as the word's code, the run symbol's code and `n` when
/// that is shorter. `codes[w − first]` and `run` are `code << 6 | length`; `LONG` when a
/// code may exceed [`PUT_BITS`], `PAIRS` when two codes always fit in one put. Returns the
/// bits and bytes written.
///
/// The words up to the first that equals its successor, looked for [`STRETCH`] at a
/// time, are single codes: they are sent without looking for runs, in pairs when
/// `PAIRS`.
#[inline(always)]
fn pack_words<const LONG: bool, const PAIRS: bool>(
    words: &[u16],
    codes: &[u64],
    first: usize,
    run: u64,
    buf: &mut [u8],
) -> (u64, usize) {
    let put = |bits: &mut Bits, value: u64, len: u32| {
        if LONG {
            bits.put_any(value, len);
        } else {
            bits.put(value, len);
        }
    };
    let code = |w: u16| {
        let c = codes[usize::from(w) - first];
        (c >> 6, (c & 63) as u32)
    };
    let (run_code, run_len) = (run >> 6, (run & 63) as u32);
    let mut bits = Bits::new(buf);
    let mut i = 0;
    while i < words.len() {
        if i + STRETCH < words.len() {
            // Bit k set when word i + k equals its successor; the words before the
            // first such are single codes.
            let this: &[u16; STRETCH] = words[i..i + STRETCH].try_into().expect("a stretch");
            let next: &[u16; STRETCH] = words[i + 1..=i + STRETCH].try_into().expect("a stretch");
            let mut equal = 0u32;
            for (k, (a, b)) in this.iter().zip(next).enumerate() {
                equal |= u32::from(a == b) << k;
            }
            let singles = &this[..(equal.trailing_zeros() as usize).min(STRETCH)];
            if PAIRS {
                let pairs = singles.chunks_exact(2);
                let last = pairs.remainder();
                for pair in pairs {
                    let ((c0, l0), (c1, l1)) = (code(pair[0]), code(pair[1]));
                    bits.put(c0 << l1 | c1, l0 + l1);
                }
                if let [w] = last {
                    let (c, len) = code(*w);
                    bits.put(c, len);
                }
            } else {
                for &w in singles {
                    let (c, len) = code(w);
                    put(&mut bits, c, len);
                }
            }
            i += singles.len();
            if singles.len() == STRETCH {
                continue;
            }
        }
        let word = words[i];
        let end = words.len().min(i + 256);
        let mut j = i + 1;
        while j < end && words[j] == word {
            j += 1;
        }
        let repeats = (j - i - 1) as u32;
        i = j;
        let (c, len) = code(word);
        if repeats == 0 {
            put(&mut bits, c, len);
        } else if len + run_len + 8 < len * repeats {
            put(&mut bits, c, len);
            put(&mut bits, run_code, run_len);
            bits.put(u64::from(repeats), 8);
        } else {
            for _ in 0..=repeats {
                put(&mut bits, c, len);
            }
        }
    }
    bits.finish()
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
    // Counted in four tables: most lengths are 0, and one table would make each
    // increment wait for the previous one.
    let mut count = [[0u64; MAX_CODE_BITS as usize + 1]; 4];
    let quads = lengths.chunks_exact(4);
    for &l in quads.remainder() {
        count[0][usize::from(l)] += 1;
    }
    for quad in quads {
        for (table, &l) in count.iter_mut().zip(quad) {
            table[usize::from(l)] += 1;
        }
    }
    let mut next = [0u64; MAX_CODE_BITS as usize + 1];
    for (l, n) in next.iter_mut().enumerate() {
        *n = count.iter().map(|table| table[l]).sum();
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
        let mut out = vec![0u8; 8 + 9];
        let mut bits = Bits::new(&mut out);
        bits.put(0b101, 3);
        bits.put_any(0x3_ffff_ffff_ffff, 50);
        bits.put(0, 4);
        bits.put(1, 1);
        assert_eq!(bits.finish(), (58, 8));
        // 101 + fifty ones + 0000 + 1, padded: 10111111 ×6 … then 1 0000 1 00 (pad).
        let mut want = String::from("101");
        want.push_str(&"1".repeat(50));
        want.push_str("00001");
        want.push_str("000000");
        let got: String = out[..8].iter().map(|b| format!("{b:08b}")).collect();
        assert_eq!(got, want);
    }

    /// Appends the low `len` bits of `value`, most significant first.
    fn push_bits(bits: &mut Vec<bool>, value: u64, len: u32) {
        bits.extend((0..len).rev().map(|k| value >> k & 1 == 1));
    }

    /// Packs bits into bytes, most significant first, the last byte padded with zeros.
    fn pack(bits: &[bool]) -> Vec<u8> {
        bits.chunks(8)
            .map(|byte| {
                byte.iter()
                    .enumerate()
                    .fold(0u8, |b, (k, &bit)| b | u8::from(bit) << (7 - k))
            })
            .collect()
    }

    /// The data part written one bit at a time, runs found by looking ahead word by word.
    fn reference_data(words: &[u16], codes: &[u64], first: usize, run: u64) -> (u64, Vec<u8>) {
        let split = |c: u64| (c >> 6, (c & 63) as u32);
        let (run_code, run_len) = split(run);
        let mut bits = Vec::new();
        let mut k = 0;
        while k < words.len() {
            let w = words[k];
            let mut n = 0;
            while n < 255 && k + n + 1 < words.len() && words[k + n + 1] == w {
                n += 1;
            }
            let (c, len) = split(codes[usize::from(w) - first]);
            if n > 0 && len + run_len + 8 < len * n as u32 {
                push_bits(&mut bits, c, len);
                push_bits(&mut bits, run_code, run_len);
                push_bits(&mut bits, n as u64, 8);
            } else {
                for _ in 0..=n {
                    push_bits(&mut bits, c, len);
                }
            }
            k += n + 1;
        }
        (bits.len() as u64, pack(&bits))
    }

    /// [`huffman_encode`] written plainly: one frequency table, the code table and the
    /// data one bit at a time.
    fn reference_encode(words: &[u16]) -> Vec<u8> {
        let mut frequency = vec![0u64; SYMBOLS];
        for &w in words {
            frequency[usize::from(w)] += 1;
        }
        let first = frequency.iter().position(|&f| f > 0).unwrap();
        let run_symbol = frequency.iter().rposition(|&f| f > 0).unwrap() + 1;
        frequency[run_symbol] = 1;
        let lengths = code_lengths(&frequency[first..=run_symbol]).unwrap();
        let codes = canonical_codes(&lengths);
        let mut bits = Vec::new();
        let mut s = 0;
        while s < lengths.len() {
            let zeros = lengths[s..]
                .iter()
                .take(LONGEST_LONG_RUN)
                .take_while(|&&l| l == 0)
                .count();
            if zeros >= SHORTEST_LONG_RUN {
                push_bits(&mut bits, LONG_ZERO_RUN, 6);
                push_bits(&mut bits, (zeros - SHORTEST_LONG_RUN) as u64, 8);
                s += zeros;
            } else if zeros >= 2 {
                push_bits(&mut bits, SHORT_ZERO_RUN + zeros as u64 - 2, 6);
                s += zeros;
            } else {
                push_bits(&mut bits, u64::from(lengths[s]), 6);
                s += 1;
            }
        }
        let table = pack(&bits);
        let (data_bits, data) = reference_data(words, &codes, first, codes[run_symbol - first]);
        let mut out = Vec::new();
        for v in [
            first as u32,
            run_symbol as u32,
            table.len() as u32,
            data_bits as u32,
            0,
        ] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out.extend_from_slice(&table);
        out.extend_from_slice(&data);
        out
    }

    /// xorshift64*: a reproducible stream of pseudo-random numbers.
    fn random(seed: u64) -> impl FnMut() -> u64 {
        let mut x = seed | 1;
        move || {
            x ^= x >> 12;
            x ^= x << 25;
            x ^= x >> 27;
            x.wrapping_mul(0x2545_f491_4f6c_dd1d)
        }
    }

    /// Words in runs of random lengths (often past 256), values spread over 2¹⁶.
    fn runs_and_noise(seed: u64, n: usize) -> Vec<u16> {
        let mut next = random(seed);
        let mut words = Vec::with_capacity(n);
        while words.len() < n {
            let r = next();
            let value = match r % 4 {
                0 => 0,
                1 => (r >> 8) as u16,
                _ => (r >> 8) as u16 % 40,
            };
            let length = match (r >> 40) % 5 {
                0 => 1 + (r >> 48) as usize % 600,
                1 => 2 + (r >> 48) as usize % 3,
                _ => 1,
            };
            words.extend(std::iter::repeat_n(value, length.min(n - words.len())));
        }
        words
    }

    #[test]
    fn huffman_encode_matches_a_bit_by_bit_reference() {
        // Fibonacci frequencies give the deepest code the count allows (27 bits here).
        let mut deep = Vec::new();
        let (mut a, mut b) = (1usize, 1usize);
        for w in 0..27u16 {
            deep.extend(std::iter::repeat_n(w * 7 + 3, a));
            (a, b) = (b, a + b);
        }
        let mut shuffle = random(5);
        for k in (1..deep.len()).rev() {
            deep.swap(k, shuffle() as usize % (k + 1));
        }
        let mut noise = random(9);
        let inputs: Vec<(&str, Vec<u16>)> = vec![
            ("one word", vec![42]),
            ("two words", vec![65535, 0]),
            ("all equal", vec![7; 5000]),
            ("all equal, 256", vec![0; 256]),
            ("all equal, 257", vec![u16::MAX; 257]),
            ("runs", runs_and_noise(1, 100_000)),
            ("runs, odd count", runs_and_noise(2, 77_777)),
            ("noise", (0..50_000).map(|_| noise() as u16).collect()),
            ("deep code", deep),
        ];
        for (name, words) in inputs {
            let mut out = vec![0xaa];
            huffman_encode(&words, &mut out).unwrap();
            assert_eq!(out[0], 0xaa, "{name}: wrote before its start");
            assert!(out[1..] == reference_encode(&words), "{name}: bytes differ");
        }
    }

    #[test]
    fn codes_up_to_58_bits_are_packed_like_the_reference() {
        // Any table will do for the writer: random codes of 1..=58 bits.
        let mut next = random(3);
        let first = 100;
        let codes: Vec<u64> = (0..300)
            .map(|_| {
                let r = next();
                let len = 1 + r % 58;
                (next() >> (64 - len)) << 6 | len
            })
            .collect();
        // Runs, then noise (stretches without runs), then runs.
        let mut noise = random(6);
        let words: Vec<u16> = runs_and_noise(4, 30_000)
            .into_iter()
            .chain((0..30_000).map(|_| noise() as u16))
            .chain(runs_and_noise(7, 10_001))
            .map(|w| first as u16 + w % 299)
            .collect();
        // Each path with the longest codes it takes: 58 bits split, 57 in one put, 28 in
        // pairs.
        let shortened = |longest: u64| -> Vec<u64> {
            codes
                .iter()
                .map(|&c| {
                    let len = c & 63;
                    if len > longest {
                        (c >> 6 >> (len - longest)) << 6 | longest
                    } else {
                        c
                    }
                })
                .collect()
        };
        type Pack = fn(&[u16], &[u64], usize, u64, &mut [u8]) -> (u64, usize);
        let paths: [(u64, Pack); 3] = [
            (58, pack_words::<true, false>),
            (57, pack_words::<false, false>),
            (28, pack_words::<false, true>),
        ];
        for (longest, pack_words) in paths {
            let codes = shortened(longest);
            assert!(codes.iter().any(|c| c & 63 == longest));
            let run = codes[299];
            let (want_bits, want) = reference_data(&words, &codes, first, run);
            let mut buf = vec![0u8; want.len() + 8];
            assert_eq!(
                pack_words(&words, &codes, first, run, &mut buf),
                (want_bits, want.len()),
                "codes up to {longest} bits"
            );
            assert!(buf[..want.len()] == want, "codes up to {longest} bits");
        }
    }
}
