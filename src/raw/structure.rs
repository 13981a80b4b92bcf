//! The TIFF structure of a raw (DNG, CR2, NEF, ARW, ORF, RW2, PEF and the other
//! TIFF-based formats), walked before the decoder sees the file.
//!
//! rawler 0.8 follows a file's chain of IFDs ("next IFD" offsets) until it reads 0, with
//! no memory of where it has been: a chain that points back to itself (a few bytes of
//! damage) makes it allocate without bound. It also allocates each entry's values by the
//! count the entry declares, before reading them. This walk refuses such a file first,
//! with its reason:
//!
//! - the chain may not revisit an IFD, nor hold more than [`MAX_CHAINED_IFDS`];
//! - an IFD of the chain must lie within the file, and declare at most
//!   [`MAX_ENTRIES_PER_IFD`] entries;
//! - the IFDs the decoder opens by pointer (`SubIFDs`, the EXIF, GPS and interoperability
//!   IFDs) are walked too, at most [`MAX_IFD_DEPTH`] levels below the chain and
//!   [`MAX_IFDS`] in all (one the walk has seen already is not walked again);
//! - an entry's values (`count × size of its type`, the type's size as rawler takes it:
//!   one byte for a type it does not know) may not exceed the file, and all entries'
//!   values together may not exceed [`MAX_VALUE_BYTES_PER_FILE_BYTE`] times the file, so
//!   what the decoder allocates for them grows with the file, not with its claims.
//!
//! A CR3 is ISO media whose `CMT1`–`CMT4` boxes each hold a TIFF that rawler reads the
//! same way: those are walked too. A file of another structure (RAF, CRW, MRW, X3F) is
//! left to the decoder.
//! Written here rather than taken from the `tiff` crate: its decoder checks a chain for
//! cycles but refuses a raw's compressions and photometric interpretations before it
//! reaches the chain, and does not bound the entries' declared counts.

use std::collections::HashSet;

/// Most IFDs in the main chain: real raws have one to four (CR2 has four); 64 leaves
/// room for anything a camera writes.
const MAX_CHAINED_IFDS: usize = 64;

/// Most IFDs walked in all (the chain and the IFDs it points to).
const MAX_IFDS: usize = 512;

/// Deepest nesting of IFDs below the chain (`IFD0 → EXIF → interoperability` is two).
const MAX_IFD_DEPTH: usize = 4;

/// Most entries one IFD may declare: rawler reads no more than this many.
const MAX_ENTRIES_PER_IFD: u16 = 4096;

/// All entries' values together, in bytes, may be at most this many times the file's
/// length (values of real files are disjoint parts of it).
const MAX_VALUE_BYTES_PER_FILE_BYTE: u64 = 2;

/// Tags whose values are offsets of further IFDs: `SubIFDs`, `ExifIFD`, `GPSInfo`,
/// `InteroperabilityIFD`.
const POINTER_TAGS: [u16; 4] = [0x014A, 0x8769, 0x8825, 0xA005];

/// TIFF magic numbers rawler reads: TIFF (42), Panasonic RW2 (85), Olympus ORF (`RO`,
/// `RS`).
const MAGICS: [u16; 4] = [42, 85, 0x4F52, 0x5352];

/// Why a raw's TIFF structure is refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum StructureError {
    /// The TIFF inside one of a CR3's boxes is refused (offsets count from the box).
    #[error("its {name} box: {source}")]
    InBox {
        /// The box (`CMT1`…`CMT4`).
        name: String,
        /// Why its TIFF is refused.
        #[source]
        source: Box<StructureError>,
    },
    /// A "next IFD" offset leads back to an IFD of the chain.
    #[error("its chain of IFDs loops back to the IFD at byte {offset}")]
    ChainLoops {
        /// Where the loop closes.
        offset: u64,
    },
    /// The chain holds more IFDs than any camera writes.
    #[error("its chain of IFDs is longer than {MAX_CHAINED_IFDS}")]
    ChainTooLong,
    /// More IFDs than any camera writes.
    #[error("it holds more than {MAX_IFDS} IFDs")]
    TooManyIfds,
    /// IFDs nested deeper than any camera writes.
    #[error("its IFDs are nested deeper than {MAX_IFD_DEPTH} levels")]
    TooDeep,
    /// An IFD of the chain starts beyond the end of the file.
    #[error("the IFD at byte {offset} lies outside the file of {len} bytes")]
    IfdOutside {
        /// Where the IFD should start.
        offset: u64,
        /// The file's length.
        len: u64,
    },
    /// An IFD declares more entries than are read.
    #[error("the IFD at byte {offset} declares {entries} entries (at most {MAX_ENTRIES_PER_IFD})")]
    TooManyEntries {
        /// The IFD.
        offset: u64,
        /// What it declares.
        entries: u16,
    },
    /// An entry declares more bytes of values than the file holds.
    #[error("tag 0x{tag:04X} declares {bytes} bytes of values in a file of {len} bytes")]
    ValueTooLarge {
        /// The entry's tag.
        tag: u16,
        /// Its declared size.
        bytes: u64,
        /// The file's length.
        len: u64,
    },
    /// The entries together declare far more values than the file holds.
    #[error(
        "its entries declare {bytes} bytes of values, more than {MAX_VALUE_BYTES_PER_FILE_BYTE}× the file's {len} bytes"
    )]
    ValuesTooLarge {
        /// The declared total.
        bytes: u64,
        /// The file's length.
        len: u64,
    },
}

/// Walks the TIFF structure of `bytes` (see the module's rules), or of each TIFF a CR3
/// holds (its `CMT1`–`CMT4` boxes, which rawler reads the same way); `Ok` also for a file
/// of another structure, which is left to the decoder.
pub fn check(bytes: &[u8]) -> Result<(), StructureError> {
    if bytes.get(4..8) == Some(b"ftyp") {
        return check_boxes(bytes, 0);
    }
    check_tiff(bytes)
}

/// Deepest nesting of ISO media boxes walked to a CR3's TIFFs (`moov` → `uuid` → `CMT1`).
const MAX_BOX_DEPTH: usize = 3;

/// Walks the ISO media boxes of `bytes` (a CR3, or the inside of one of its container
/// boxes), `depth` levels down, checking the TIFF in each `CMT1`–`CMT4` box.
fn check_boxes(bytes: &[u8], depth: usize) -> Result<(), StructureError> {
    let mut at = 0usize;
    while at + 8 <= bytes.len() {
        let size = u32::from_be_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]]);
        let kind = &bytes[at + 4..at + 8];
        let (mut header, size) = match size {
            0 => (8, bytes.len() - at),
            1 => match bytes.get(at + 8..at + 16) {
                Some(b) => (
                    16,
                    usize::try_from(u64::from_be_bytes(b.try_into().unwrap_or_default()))
                        .unwrap_or(usize::MAX),
                ),
                None => return Ok(()),
            },
            n => (8, n as usize),
        };
        if kind == b"uuid" {
            header += 16;
        }
        if size < header {
            // A damaged box: rawler refuses the file itself; nothing more to walk.
            return Ok(());
        }
        let end = at.saturating_add(size).min(bytes.len());
        let body = bytes.get(at + header..end).unwrap_or_default();
        match kind {
            b"CMT1" | b"CMT2" | b"CMT3" | b"CMT4" => {
                check_tiff(body).map_err(|source| StructureError::InBox {
                    name: String::from_utf8_lossy(kind).into_owned(),
                    source: Box::new(source),
                })?;
            }
            b"moov" | b"uuid" if depth < MAX_BOX_DEPTH => check_boxes(body, depth + 1)?,
            _ => {}
        }
        at = end;
    }
    Ok(())
}

/// Walks the TIFF structure of `bytes`; `Ok` when they are not a TIFF rawler reads.
fn check_tiff(bytes: &[u8]) -> Result<(), StructureError> {
    let Some(mut walk) = Walk::new(bytes) else {
        return Ok(());
    };
    let Some(first) = walk.u32_at(4) else {
        return Ok(());
    };
    let mut offset = u64::from(first);
    let mut chain = HashSet::new();
    while offset != 0 {
        if !chain.insert(offset) {
            return Err(StructureError::ChainLoops { offset });
        }
        if chain.len() > MAX_CHAINED_IFDS {
            return Err(StructureError::ChainTooLong);
        }
        walk.seen.insert(offset);
        let ifd = walk.ifd(offset, 0)?.ok_or(StructureError::IfdOutside {
            offset,
            len: walk.len(),
        })?;
        offset = ifd.next;
    }
    Ok(())
}

/// One IFD as the walk needs it.
struct Ifd {
    /// The "next IFD" offset, 0 at the end of the chain (or when the file ends first, as
    /// rawler takes it).
    next: u64,
}

/// The state of one walk: the file, its byte order, the IFDs seen and the values counted.
struct Walk<'a> {
    bytes: &'a [u8],
    big_endian: bool,
    seen: HashSet<u64>,
    value_bytes: u64,
}

impl<'a> Walk<'a> {
    /// A walk of `bytes` when they start with a TIFF header rawler reads, else `None`.
    fn new(bytes: &'a [u8]) -> Option<Walk<'a>> {
        let big_endian = match bytes.get(..2)? {
            b"II" => false,
            b"MM" => true,
            _ => return None,
        };
        let walk = Walk {
            bytes,
            big_endian,
            seen: HashSet::new(),
            value_bytes: 0,
        };
        MAGICS.contains(&walk.u16_at(2)?).then_some(walk)
    }

    fn len(&self) -> u64 {
        self.bytes.len() as u64
    }

    fn u16_at(&self, at: u64) -> Option<u16> {
        let at = usize::try_from(at).ok()?;
        let b: [u8; 2] = self.bytes.get(at..at.checked_add(2)?)?.try_into().ok()?;
        Some(if self.big_endian {
            u16::from_be_bytes(b)
        } else {
            u16::from_le_bytes(b)
        })
    }

    fn u32_at(&self, at: u64) -> Option<u32> {
        let at = usize::try_from(at).ok()?;
        let b: [u8; 4] = self.bytes.get(at..at.checked_add(4)?)?.try_into().ok()?;
        Some(if self.big_endian {
            u32::from_be_bytes(b)
        } else {
            u32::from_le_bytes(b)
        })
    }

    /// Reads the IFD at `offset`, `depth` levels below the chain, counts its entries'
    /// values and walks the IFDs it points to. `None` when the IFD's entry count lies
    /// outside the file.
    fn ifd(&mut self, offset: u64, depth: usize) -> Result<Option<Ifd>, StructureError> {
        if self.seen.len() > MAX_IFDS {
            return Err(StructureError::TooManyIfds);
        }
        let Some(entries) = self.u16_at(offset) else {
            return Ok(None);
        };
        if depth > MAX_IFD_DEPTH {
            return Err(StructureError::TooDeep);
        }
        if entries > MAX_ENTRIES_PER_IFD {
            return Err(StructureError::TooManyEntries { offset, entries });
        }
        let mut children = Vec::new();
        for i in 0..u64::from(entries) {
            let at = offset + 2 + 12 * i;
            let (Some(tag), Some(kind), Some(count)) =
                (self.u16_at(at), self.u16_at(at + 2), self.u32_at(at + 4))
            else {
                // rawler stops at a truncated IFD.
                break;
            };
            self.count_values(tag, kind, count)?;
            if POINTER_TAGS.contains(&tag) {
                children.extend(self.pointers(at, kind, count));
            }
        }
        let end = offset + 2 + 12 * u64::from(entries);
        let next = self.u32_at(end).map_or(0, u64::from);
        for child in children {
            if child == 0 || !self.seen.insert(child) {
                continue;
            }
            // rawler ignores an IFD it cannot read behind a pointer; so does the walk.
            self.ifd(child, depth + 1)?;
        }
        Ok(Some(Ifd { next }))
    }

    /// Adds an entry's values (`count` of type `kind`) to the walk's total.
    fn count_values(&mut self, tag: u16, kind: u16, count: u32) -> Result<(), StructureError> {
        let bytes = u64::from(count) << type_shift(kind);
        let len = self.len();
        if bytes > 4 && bytes > len {
            return Err(StructureError::ValueTooLarge { tag, bytes, len });
        }
        self.value_bytes += bytes;
        if self.value_bytes > MAX_VALUE_BYTES_PER_FILE_BYTE * len {
            return Err(StructureError::ValuesTooLarge {
                bytes: self.value_bytes,
                len,
            });
        }
        Ok(())
    }

    /// The IFD offsets a pointer entry at `at` holds: its LONG (or IFD-typed) values, or
    /// for another type the place of its values (rawler reads an IFD there).
    fn pointers(&self, at: u64, kind: u16, count: u32) -> Vec<u64> {
        let bytes = u64::from(count) << type_shift(kind);
        let place = if bytes <= 4 {
            Some(at + 8)
        } else {
            self.u32_at(at + 8).map(u64::from)
        };
        let Some(place) = place else {
            return Vec::new();
        };
        match kind {
            4 | 13 => (0..u64::from(count).min(MAX_IFDS as u64))
                .filter_map(|k| self.u32_at(place + 4 * k).map(u64::from))
                .collect(),
            _ => vec![place],
        }
    }
}

/// `log₂` of the size in bytes of one value of TIFF type `kind`, as rawler takes it: an
/// unknown type is one byte.
fn type_shift(kind: u16) -> u32 {
    match kind {
        3 | 8 => 1,
        4 | 9 | 11 => 2,
        5 | 10 | 12 => 3,
        _ => 0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A little-endian TIFF: a header, then one IFD per `(entries, next)` at 8, 8 + 18·…
    /// (each entry a SHORT tag 0x0100 with one value), with `next` the IFD's "next" index
    /// (`None` for 0).
    fn tiff(ifds: &[(u16, Option<usize>)]) -> Vec<u8> {
        let place = |k: usize| -> u32 {
            8 + ifds[..k]
                .iter()
                .map(|(n, _)| 6 + 12 * u32::from(*n))
                .sum::<u32>()
        };
        let mut b = b"II*\0".to_vec();
        b.extend(8u32.to_le_bytes());
        for (entries, next) in ifds {
            b.extend(entries.to_le_bytes());
            for _ in 0..*entries {
                b.extend(0x0100u16.to_le_bytes());
                b.extend(3u16.to_le_bytes());
                b.extend(1u32.to_le_bytes());
                b.extend(64u32.to_le_bytes());
            }
            b.extend(next.map_or(0, place).to_le_bytes());
        }
        b
    }

    #[test]
    fn a_sound_chain_passes() {
        assert_eq!(check(&tiff(&[(2, Some(1)), (1, None)])), Ok(()));
        assert_eq!(check(b"not a tiff at all"), Ok(()));
    }

    #[test]
    fn a_chain_that_loops_is_refused() {
        assert_eq!(
            check(&tiff(&[(2, Some(0))])),
            Err(StructureError::ChainLoops { offset: 8 })
        );
        assert_eq!(
            check(&tiff(&[(1, Some(1)), (1, Some(2)), (1, Some(1))])),
            Err(StructureError::ChainLoops { offset: 8 + 18 })
        );
    }

    #[test]
    fn a_long_chain_is_refused() {
        let chain = |n: usize| -> Vec<(u16, Option<usize>)> {
            (0..n).map(|k| (1, (k + 1 < n).then_some(k + 1))).collect()
        };
        let too_long = tiff(&chain(MAX_CHAINED_IFDS + 1));
        assert_eq!(check(&too_long), Err(StructureError::ChainTooLong));
        assert_eq!(check(&tiff(&chain(MAX_CHAINED_IFDS))), Ok(()));
    }

    #[test]
    fn entries_that_claim_more_than_the_file_are_refused() {
        let mut b = tiff(&[(1, None)]);
        // The one entry: 2^30 RATIONALs.
        b[12..14].copy_from_slice(&5u16.to_le_bytes());
        b[14..18].copy_from_slice(&(1u32 << 30).to_le_bytes());
        assert!(matches!(
            check(&b),
            Err(StructureError::ValueTooLarge { tag: 0x0100, .. })
        ));
        let mut b = tiff(&[(1, None)]);
        b[8..10].copy_from_slice(&u16::MAX.to_le_bytes());
        assert!(matches!(
            check(&b),
            Err(StructureError::TooManyEntries { offset: 8, .. })
        ));
    }

    #[test]
    fn an_ifd_outside_the_file_is_refused() {
        let mut b = tiff(&[(1, None)]);
        b[4..8].copy_from_slice(&1_000_000u32.to_le_bytes());
        assert_eq!(
            check(&b),
            Err(StructureError::IfdOutside {
                offset: 1_000_000,
                len: b.len() as u64
            })
        );
    }

    #[test]
    fn sub_ifds_that_point_at_each_other_end_the_walk() {
        // IFD0 → EXIF IFD (at 26), whose EXIF pointer leads back to IFD0 and to itself.
        let mut b = tiff(&[(1, None), (2, None)]);
        let exif_ifd = 8 + 18;
        b[10..12].copy_from_slice(&0x8769u16.to_le_bytes());
        b[12..14].copy_from_slice(&4u16.to_le_bytes());
        b[18..22].copy_from_slice(&(exif_ifd as u32).to_le_bytes());
        for (k, target) in [(0, 8u32), (1, exif_ifd as u32)] {
            let at = exif_ifd + 2 + 12 * k;
            b[at..at + 2].copy_from_slice(&0x8769u16.to_le_bytes());
            b[at + 2..at + 4].copy_from_slice(&4u16.to_le_bytes());
            b[at + 8..at + 12].copy_from_slice(&target.to_le_bytes());
        }
        assert_eq!(check(&b), Ok(()));
    }

    /// An ISO media box `kind` around `body`.
    fn media_box(kind: &[u8; 4], body: &[u8]) -> Vec<u8> {
        let mut b = ((8 + body.len()) as u32).to_be_bytes().to_vec();
        b.extend(kind);
        b.extend(body);
        b
    }

    #[test]
    fn a_cr3_whose_embedded_tiff_loops_is_refused() {
        let canon = [
            0x85, 0xc0, 0xb6, 0x87, 0x82, 0x0f, 0x11, 0xe0, 0x81, 0x11, 0xf4, 0xce, 0x46, 0x2b,
            0x6a, 0x48,
        ];
        let cr3 = |cmt: Vec<u8>| {
            let mut uuid = canon.to_vec();
            uuid.extend(media_box(b"CMT1", &tiff(&[(1, None)])));
            uuid.extend(media_box(b"CMT2", &cmt));
            let mut b = media_box(b"ftyp", b"crx \0\0\0\x01");
            b.extend(media_box(b"moov", &media_box(b"uuid", &uuid)));
            b
        };
        assert_eq!(check(&cr3(tiff(&[(2, None)]))), Ok(()));
        assert_eq!(
            check(&cr3(tiff(&[(2, Some(0))]))),
            Err(StructureError::InBox {
                name: "CMT2".to_string(),
                source: Box::new(StructureError::ChainLoops { offset: 8 })
            })
        );
    }

    #[test]
    fn ifds_nested_too_deep_are_refused() {
        // A chain of EXIF pointers, each IFD pointing to the next.
        let n = MAX_IFD_DEPTH + 2;
        let mut b = tiff(&vec![(1, None); n]);
        for k in 0..n - 1 {
            let at = 8 + 18 * k + 2;
            b[at..at + 2].copy_from_slice(&0x8769u16.to_le_bytes());
            b[at + 2..at + 4].copy_from_slice(&4u16.to_le_bytes());
            b[at + 8..at + 12].copy_from_slice(&(8 + 18 * (k as u32 + 1)).to_le_bytes());
        }
        assert_eq!(check(&b), Err(StructureError::TooDeep));
        assert_eq!(check(&b[..8 + 18 * (n - 1)]), Ok(()));
    }
}
