//! The OpenEXR header's attributes in one order, sorted by name, so that the same image
//! gives the same file byte for byte.
//!
//! The exr crate keeps custom attributes (`cameraMake`, `filmbackFrame0`, …) in
//! `HashMap`s and writes them in their iteration order, which differs from one map to the
//! next (each map draws its own hash key): the same radiance map gave files whose headers
//! differed, and the crate has no setting for the order. [`SortedHeader`] stands between
//! its writer and the destination. It holds back the first bytes until the header is
//! complete — magic number, version field, the attributes (`name\0 type\0 size value`,
//! `size` a little-endian `i32` counting the bytes of `value`) and the empty name that
//! ends them — then writes the same attributes sorted by name (byte order, the order in
//! which the OpenEXR library itself writes a header), and passes everything after it
//! straight through. The sorted header is the held bytes permuted: its length, and so
//! every offset exr writes after it, is unchanged.
//!
//! It refuses (an [`io::ErrorKind::InvalidData`] error, which fails the write, so nothing
//! is published) what it does not expect: no OpenEXR magic number, a multi-part file, a
//! negative size, a name twice, a sorted header that the exr crate reads differently
//! from the original, or a seek, flush or end of file before the header is complete.

use std::io::{self, Seek, SeekFrom, Write};
use std::ops::Range;

use exr::meta::MetaData;

/// The first four bytes of every OpenEXR file.
const MAGIC: [u8; 4] = [0x76, 0x2f, 0x31, 0x01];
/// Bytes before the first attribute: magic number and version field.
const PREAMBLE: usize = 8;
/// Version field bit 12: a multi-part file (more headers follow the first).
const MULTIPART: u32 = 1 << 12;

/// A writer that puts the OpenEXR header written through it in canonical order (see the
/// module docs). Call [`SortedHeader::finish`] after the last byte.
pub(super) struct SortedHeader<W> {
    inner: W,
    /// The bytes held back while the header is incomplete (empty once it is written).
    held: Vec<u8>,
    /// The complete attributes in `held`, in the order written.
    attributes: Vec<Attribute>,
    /// Where the next attribute starts in `held` (0 until the preamble is checked).
    scanned: usize,
    /// The header is written: bytes pass straight through.
    passing: bool,
}

/// Where one attribute is in the held bytes.
struct Attribute {
    /// Its name (without the NUL).
    name: Range<usize>,
    /// The whole attribute: name, type, size and value.
    bytes: Range<usize>,
}

/// Why a header was not sorted, carried as the `InvalidData` [`io::Error`]'s inner error.
#[derive(Debug, thiserror::Error)]
enum Unsorted {
    /// What this module found unexpected.
    #[error("OpenEXR header not sorted: {0}")]
    Refused(String),
    /// The exr crate cannot read the header.
    #[error("OpenEXR header not sorted: the exr crate cannot read it: {0}")]
    Unreadable(#[source] exr::error::Error),
    /// The exr crate cannot encode an attribute it read.
    #[error("OpenEXR header not sorted: cannot encode {value}: {source}")]
    Unencodable {
        /// The attribute's value, debug-printed.
        value: String,
        /// The exr crate's error.
        #[source]
        source: exr::error::Error,
    },
}

impl From<Unsorted> for io::Error {
    fn from(e: Unsorted) -> io::Error {
        io::Error::new(io::ErrorKind::InvalidData, e)
    }
}

fn refuse(reason: impl std::fmt::Display) -> io::Error {
    Unsorted::Refused(reason.to_string()).into()
}

/// The index of the first NUL byte in `bytes` from `from` on.
fn nul(bytes: &[u8], from: usize) -> Option<usize> {
    bytes
        .get(from..)?
        .iter()
        .position(|&b| b == 0)
        .map(|k| from + k)
}

impl<W> SortedHeader<W> {
    pub(super) fn new(inner: W) -> Self {
        SortedHeader {
            inner,
            held: Vec::new(),
            attributes: Vec::new(),
            scanned: 0,
            passing: false,
        }
    }

    /// The destination, once the whole header went through; an error if it did not.
    pub(super) fn finish(self) -> io::Result<W> {
        if self.passing {
            Ok(self.inner)
        } else {
            Err(refuse("the output ended inside the header"))
        }
    }

    /// Records the attributes complete in `held` so far; the header's length (up to and
    /// including the empty name that ends it) once it is all there.
    fn scan(&mut self) -> io::Result<Option<usize>> {
        let held = &self.held;
        if self.scanned == 0 {
            let Some(preamble) = held.get(..PREAMBLE) else {
                return Ok(None);
            };
            if preamble[..4] != MAGIC {
                return Err(refuse("it does not start with the OpenEXR magic number"));
            }
            let version = u32::from_le_bytes([preamble[4], preamble[5], preamble[6], preamble[7]]);
            if version & MULTIPART != 0 {
                return Err(refuse("a multi-part file"));
            }
            self.scanned = PREAMBLE;
        }
        loop {
            let start = self.scanned;
            let Some(name_end) = nul(held, start) else {
                return Ok(None);
            };
            if name_end == start {
                return Ok(Some(start + 1));
            }
            let Some(type_end) = nul(held, name_end + 1) else {
                return Ok(None);
            };
            let Some(&[a, b, c, d]) = held.get(type_end + 1..type_end + 5) else {
                return Ok(None);
            };
            let size = i32::from_le_bytes([a, b, c, d]);
            let size = usize::try_from(size).map_err(|_| {
                refuse(format!(
                    "attribute {} has size {size}",
                    String::from_utf8_lossy(&held[start..name_end])
                ))
            })?;
            let end = type_end + 5 + size;
            if held.len() < end {
                return Ok(None);
            }
            self.attributes.push(Attribute {
                name: start..name_end,
                bytes: start..end,
            });
            self.scanned = end;
        }
    }

    /// The first `len` held bytes (the whole header) with the attributes sorted by name,
    /// checked by reading both with the exr crate.
    fn sorted(&self, len: usize) -> io::Result<Vec<u8>> {
        let held = &self.held[..len];
        let name = |a: &Attribute| &held[a.name.clone()];
        let mut order: Vec<&Attribute> = self.attributes.iter().collect();
        order.sort_by(|a, b| name(a).cmp(name(b)));
        if let Some(twice) = order.windows(2).find(|w| name(w[0]) == name(w[1])) {
            return Err(refuse(format!(
                "attribute {} appears twice",
                String::from_utf8_lossy(name(twice[0]))
            )));
        }
        let mut sorted = Vec::with_capacity(len);
        sorted.extend_from_slice(&held[..PREAMBLE]);
        for a in &order {
            sorted.extend_from_slice(&held[a.bytes.clone()]);
        }
        sorted.push(0);
        if sorted.len() != len {
            return Err(refuse(format!(
                "{} bytes sorted from a header of {len}",
                sorted.len()
            )));
        }
        if canonical(&sorted)? != canonical(held)? {
            return Err(refuse("the sorted header reads differently"));
        }
        Ok(sorted)
    }
}

/// A header as the exr crate reads it: every attribute it would write, encoded, part by
/// part and sorted by name within a part (an encoded attribute starts with its
/// NUL-terminated name; the encoded form compares floats by their bits, so a NaN equals
/// itself).
fn canonical(header: &[u8]) -> io::Result<Vec<Vec<u8>>> {
    let meta = MetaData::read_from_buffered(header, false).map_err(Unsorted::Unreadable)?;
    let mut all = Vec::new();
    for part in &meta.headers {
        let mut attributes = part
            .all_named_attributes()
            .map(|(name, value)| {
                let mut bytes = Vec::new();
                exr::meta::attribute::write(name, &value, &mut bytes).map_err(|source| {
                    Unsorted::Unencodable {
                        value: format!("{value:?}"),
                        source,
                    }
                })?;
                Ok(bytes)
            })
            .collect::<io::Result<Vec<_>>>()?;
        attributes.sort();
        all.append(&mut attributes);
    }
    Ok(all)
}

impl<W: Write> Write for SortedHeader<W> {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        if self.passing {
            return self.inner.write(buf);
        }
        self.held.extend_from_slice(buf);
        if let Some(len) = self.scan()? {
            let sorted = self.sorted(len)?;
            self.inner.write_all(&sorted)?;
            self.inner.write_all(&self.held[len..])?;
            self.held = Vec::new();
            self.attributes = Vec::new();
            self.passing = true;
        }
        Ok(buf.len())
    }

    fn flush(&mut self) -> io::Result<()> {
        if !self.passing {
            return Err(refuse("flushed before the header was complete"));
        }
        self.inner.flush()
    }
}

impl<W: Seek> Seek for SortedHeader<W> {
    fn seek(&mut self, pos: SeekFrom) -> io::Result<u64> {
        if !self.passing {
            return Err(refuse("a seek before the header was complete"));
        }
        self.inner.seek(pos)
    }
}
