//! The journal of finished work, in the state folder: `journal.jsonl`.
//!
//! One JSON object per line, appended and `fsync`ed before the daemon moves on, so a
//! bracket counts as finished only once its outputs are all published *and* its line is
//! on disk. After a crash (even `kill -9` mid-write) the start-up scan skips every input
//! the journal names and redoes everything else; outputs are published atomically under
//! deterministic names, so redoing never leaves a partial or a second copy. A torn last
//! line (the crash hit the append itself) is ignored: that bracket is simply redone.
//!
//! Inputs are identified by path, size and modification time: a file rewritten under the
//! same name is new work. Paths are stored losslessly, whatever bytes the file system
//! allows in a name (see [`any_path`]).
//!
//! A failed append (full or failing disk) is fatal: the daemon exits with the error, and
//! under systemd `Restart=on-failure` starts it again. The append is cut back to the last
//! whole line first, so the journal never keeps a torn line; should the cut itself fail
//! (or the process be killed mid-append), the next start drops the torn last line and the
//! bracket it would have recorded is simply developed again.

use std::collections::{HashMap, HashSet};
use std::fs::{self, File, OpenOptions};
use std::io::{self, Write};
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::atomic;
use crate::daemon::bracket::{Alone, CameraId, Input};
use crate::darkroom::Source;

/// File name of the journal inside the state folder.
pub const FILE_NAME: &str = "journal.jsonl";

/// Why the journal cannot be read or appended to (fatal for the daemon: without it, work
/// could be lost or duplicated).
#[derive(Debug, thiserror::Error)]
pub enum JournalError {
    /// Reading, creating or appending failed.
    #[error("{path}: {source}")]
    Io {
        /// The journal (or state folder).
        path: PathBuf,
        /// What the operating system said.
        source: io::Error,
    },
    /// An entry could not be written as JSON.
    #[error("{path}: cannot serialise an entry: {source}")]
    Serialise {
        /// The journal.
        path: PathBuf,
        /// The serialiser's error.
        #[source]
        source: serde_json::Error,
    },
    /// A line other than the last is not a journal entry: the file was edited or damaged.
    #[error("{path}:{line}: not a journal entry: {source}")]
    Corrupt {
        /// The journal.
        path: PathBuf,
        /// 1-based line.
        line: usize,
        /// The parser's error.
        #[source]
        source: serde_json::Error,
    },
}

/// One line of the journal.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Entry {
    /// A bracket merged and all its outputs published.
    Bracket {
        /// [`crate::daemon::bracket::fingerprint`] of the inputs.
        id: String,
        /// The body.
        camera: CameraId,
        /// The frames, in capture order.
        inputs: Vec<Input>,
        /// Published outputs.
        outputs: Vec<PathBuf>,
        /// [`content_digest`] of each input, in the order of `inputs` (absent in entries
        /// of older versions).
        #[serde(default, skip_serializing_if = "Vec::is_empty")]
        digests: Vec<u64>,
        /// Exposure ratio `e_max / e_min`.
        ratio: f64,
        /// Where the response came from.
        response: Source,
        /// Unix time, seconds.
        at: u64,
    },
    /// A frame alone: rendered (outputs) or only reported (no outputs).
    Single {
        /// Fingerprint of the input.
        id: String,
        /// The body.
        camera: CameraId,
        /// The frame.
        input: Input,
        /// Why it was alone.
        alone: Alone,
        /// Published outputs (empty when only reported).
        outputs: Vec<PathBuf>,
        /// [`content_digest`] of the input (absent in entries of older versions).
        #[serde(default, skip_serializing_if = "Vec::is_empty")]
        digests: Vec<u64>,
        /// Unix time, seconds.
        at: u64,
    },
    /// A file that is not a usable frame; set aside, retried only if it changes.
    Rejected {
        /// The file.
        input: Input,
        /// Why.
        reason: String,
        /// Unix time, seconds.
        at: u64,
    },
    /// A developed input whose modification time changed but whose content did not (a
    /// tool touched it): nothing is redone.
    Unchanged {
        /// The file as it is now.
        input: Input,
        /// Id of the bracket or single it was developed in.
        of: String,
        /// Unix time, seconds.
        at: u64,
    },
    /// A bracket whose frames are fine but whose pixels could not be developed (e.g.
    /// frames of different sizes); retried only if an input changes.
    Failed {
        /// Fingerprint of the inputs.
        id: String,
        /// The frames.
        inputs: Vec<Input>,
        /// Why.
        reason: String,
        /// Unix time, seconds.
        at: u64,
    },
}

impl Entry {
    /// The inputs this entry settles.
    pub fn inputs(&self) -> Vec<&Input> {
        match self {
            Entry::Bracket { inputs, .. } | Entry::Failed { inputs, .. } => inputs.iter().collect(),
            Entry::Single { input, .. }
            | Entry::Rejected { input, .. }
            | Entry::Unchanged { input, .. } => vec![input],
        }
    }

    fn inputs_mut(&mut self) -> Vec<&mut Input> {
        match self {
            Entry::Bracket { inputs, .. } | Entry::Failed { inputs, .. } => {
                inputs.iter_mut().collect()
            }
            Entry::Single { input, .. }
            | Entry::Rejected { input, .. }
            | Entry::Unchanged { input, .. } => vec![input],
        }
    }

    /// The content digest recorded for the input at `path`, if this entry developed it.
    pub(crate) fn digest_of(&self, path: &Path) -> Option<u64> {
        let (inputs, digests): (Vec<&Input>, &[u64]) = match self {
            Entry::Bracket {
                inputs, digests, ..
            } => (inputs.iter().collect(), digests),
            Entry::Single { input, digests, .. } => (vec![input], digests),
            _ => return None,
        };
        inputs
            .iter()
            .position(|i| i.path == path)
            .and_then(|k| digests.get(k).copied())
    }

    /// The output stem this bracket or single was published under: the first input's
    /// file stem, or that stem with `-<8 hex digits of the id>` when the outputs say so.
    pub fn output_stem(&self) -> Option<String> {
        let (id, first, outputs) = match self {
            Entry::Bracket {
                id,
                inputs,
                outputs,
                ..
            } => (id, inputs.first()?, outputs),
            Entry::Single {
                id, input, outputs, ..
            } => (id, input, outputs),
            _ => return None,
        };
        let stem = first.path.file_stem().unwrap_or_default().to_string_lossy();
        let stem = crate::atomic::fitting_stem(&stem).into_owned();
        let suffixed = format!("{stem}-{}", id.get(..8).unwrap_or(id));
        let named = |s: &str| {
            outputs.iter().any(|o| {
                o.file_name()
                    .is_some_and(|n| n.to_string_lossy().starts_with(&format!("{s}.")))
            })
        };
        Some(if named(&suffixed) { suffixed } else { stem })
    }
}

/// FNV-1a (64 bit) of a file's bytes: tells a touched file (same
/// content, new modification time) from a changed one.
pub fn content_digest(bytes: &[u8]) -> u64 {
    atomic::fnv1a(atomic::FNV_OFFSET, bytes)
}

/// Seconds since the Unix epoch, now.
pub fn unix_now() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs())
}

/// The open journal: everything recorded so far, and an append handle.
#[derive(Debug)]
pub(crate) struct Journal {
    path: PathBuf,
    file: File,
    entries: Vec<Entry>,
    settled: HashSet<Input>,
    /// Index into `entries` of the latest bracket or single that developed each path.
    developed: HashMap<PathBuf, usize>,
}

impl Journal {
    /// Opens (creating the state folder and file if needed) and reads the journal.
    pub fn open(state: &Path) -> Result<Journal, JournalError> {
        let path = state.join(FILE_NAME);
        fs::create_dir_all(state).map_err(|source| JournalError::Io {
            path: state.to_path_buf(),
            source,
        })?;
        let entries = read(state)?;
        let file = OpenOptions::new()
            .create(true)
            .append(true)
            .open(&path)
            .map_err(|source| JournalError::Io {
                path: path.clone(),
                source,
            })?;
        let mut journal = Journal {
            path,
            file,
            entries: Vec::new(),
            settled: HashSet::new(),
            developed: HashMap::new(),
        };
        // A torn last line (no newline) is cut off so the next entry starts cleanly.
        let bytes = fs::read(&journal.path).map_err(|source| JournalError::Io {
            path: journal.path.clone(),
            source,
        })?;
        if !bytes.is_empty() && !bytes.ends_with(b"\n") {
            let keep = bytes.iter().rposition(|&b| b == b'\n').map_or(0, |i| i + 1);
            journal
                .file
                .set_len(keep as u64)
                .and_then(|()| journal.file.sync_data())
                .map_err(|source| JournalError::Io {
                    path: journal.path.clone(),
                    source,
                })?;
        }
        for e in entries {
            journal.note(e);
        }
        Ok(journal)
    }

    fn note(&mut self, entry: Entry) {
        self.settled.extend(entry.inputs().into_iter().cloned());
        if matches!(entry, Entry::Bracket { .. } | Entry::Single { .. }) {
            for i in entry.inputs() {
                self.developed.insert(i.path.clone(), self.entries.len());
            }
        }
        self.entries.push(entry);
    }

    /// Gives every input path recorded so far the name `resolve` returns for it, in
    /// memory (the file is not rewritten): the daemon resolves a journal written with
    /// relative or differently spelled folders against its canonical ingest folder, so a
    /// file has one identity whatever the configuration said then.
    pub(crate) fn resolve_inputs(&mut self, resolve: impl Fn(&Path) -> PathBuf) {
        let entries = std::mem::take(&mut self.entries);
        self.settled.clear();
        self.developed.clear();
        for mut entry in entries {
            for input in entry.inputs_mut() {
                input.path = resolve(&input.path);
            }
            self.note(entry);
        }
    }

    /// The latest bracket or single that developed the file at `path`.
    pub fn developed(&self, path: &Path) -> Option<&Entry> {
        self.developed.get(path).map(|&k| &self.entries[k])
    }

    /// The latest bracket or single published under output stem `stem`.
    pub(crate) fn by_stem(&self, stem: &str) -> Option<&Entry> {
        self.entries
            .iter()
            .rev()
            .find(|e| e.output_stem().as_deref() == Some(stem))
    }

    fn append_line(&mut self, line: &str) -> Result<(), JournalError> {
        debug_assert!(!line.contains('\n'));
        let io_err = |source| JournalError::Io {
            path: self.path.clone(),
            source,
        };
        let before = self.file.metadata().map_err(io_err)?.len();
        // One write per line: O_APPEND keeps concurrent appends whole.
        let written = self
            .file
            .write_all(format!("{line}\n").as_bytes())
            .and_then(|()| self.file.sync_data());
        if let Err(source) = written {
            // Leave no torn line behind (best effort: the next open drops one anyway).
            let _ = self
                .file
                .set_len(before)
                .and_then(|()| self.file.sync_data());
            return Err(io_err(source));
        }
        Ok(())
    }

    /// Appends an entry and syncs it to disk.
    pub fn record(&mut self, entry: Entry) -> Result<(), JournalError> {
        let line = serde_json::to_string(&entry).map_err(|source| JournalError::Serialise {
            path: self.path.clone(),
            source,
        })?;
        self.append_line(&line)?;
        self.note(entry);
        Ok(())
    }

    /// True when the journal settles this exact input (same path, size and mtime).
    pub(crate) fn is_settled(&self, input: &Input) -> bool {
        self.settled.contains(input)
    }

    /// Everything recorded, oldest first.
    pub fn entries(&self) -> &[Entry] {
        &self.entries
    }
}

/// Serde for paths that may not be UTF-8: a UTF-8 path is a JSON string (as before); any
/// other is `{"bytes": [..]}`, the name's raw bytes (Unix file names are byte strings,
/// anything but `/` and NUL). Both read back to the identical path.
pub mod any_path {
    use std::ffi::OsString;
    use std::os::unix::ffi::{OsStrExt, OsStringExt};
    use std::path::{Path, PathBuf};

    use serde::{Deserialize, Deserializer, Serialize, Serializer};

    #[derive(Serialize, Deserialize)]
    #[serde(untagged)]
    enum Stored {
        Text(String),
        Raw { bytes: Vec<u8> },
    }

    /// Writes `path` as a string, or as its bytes when it is not UTF-8.
    pub(crate) fn serialize<S: Serializer>(path: &Path, s: S) -> Result<S::Ok, S::Error> {
        match path.to_str() {
            Some(text) => s.serialize_str(text),
            None => Stored::Raw {
                bytes: path.as_os_str().as_bytes().to_vec(),
            }
            .serialize(s),
        }
    }

    /// Reads what [`serialize`] wrote.
    pub(crate) fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<PathBuf, D::Error> {
        Ok(match Stored::deserialize(d)? {
            Stored::Text(text) => PathBuf::from(text),
            Stored::Raw { bytes } => PathBuf::from(OsString::from_vec(bytes)),
        })
    }
}

/// Reads the journal of a state folder without opening it for writing (for `status`).
/// A missing file is an empty journal; an unparsable *last* line is a torn append and is
/// skipped; any other unparsable line is an error.
pub fn read(state: &Path) -> Result<Vec<Entry>, JournalError> {
    let path = state.join(FILE_NAME);
    let text = match fs::read_to_string(&path) {
        Ok(t) => t,
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(source) => return Err(JournalError::Io { path, source }),
    };
    let lines: Vec<&str> = text.lines().collect();
    let mut entries = Vec::with_capacity(lines.len());
    for (i, line) in lines.iter().enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        match serde_json::from_str::<Entry>(line) {
            Ok(e) => entries.push(e),
            Err(_) if i + 1 == lines.len() && !text.ends_with('\n') => {}
            Err(source) => {
                return Err(JournalError::Corrupt {
                    path,
                    line: i + 1,
                    source,
                });
            }
        }
    }
    Ok(entries)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn input(name: &str) -> Input {
        Input {
            path: PathBuf::from(format!("/in/{name}")),
            size: 42,
            modified_ns: 1_700_000_000_123_456_789,
        }
    }

    fn bracket(names: &[&str]) -> Entry {
        Entry::Bracket {
            id: "0123456789abcdef".into(),
            camera: CameraId {
                make: Some("Canon".into()),
                model: Some("EOS R5".into()),
                serial: None,
            },
            inputs: names.iter().map(|n| input(n)).collect(),
            outputs: vec![PathBuf::from("/out/a.exr")],
            digests: Vec::new(),
            ratio: 4.0,
            response: Source::Fitted,
            at: 1,
        }
    }

    #[test]
    fn survives_reopen_and_settles_exact_inputs() {
        let dir = tempfile::tempdir().unwrap();
        let state = dir.path().join("state");
        {
            let mut j = Journal::open(&state).unwrap();
            j.record(bracket(&["a.jpg", "b.jpg"])).unwrap();
            j.record(Entry::Rejected {
                input: input("bad.jpg"),
                reason: "not a JPEG".into(),
                at: 2,
            })
            .unwrap();
        }
        let j = Journal::open(&state).unwrap();
        assert_eq!(j.entries().len(), 2);
        assert!(j.is_settled(&input("a.jpg")));
        assert!(j.is_settled(&input("bad.jpg")));
        assert!(!j.is_settled(&input("c.jpg")));
        let mut rewritten = input("a.jpg");
        rewritten.size = 43;
        assert!(!j.is_settled(&rewritten), "a rewritten file is new work");
    }

    #[test]
    fn resolved_inputs_are_found_under_their_new_names() {
        let dir = tempfile::tempdir().unwrap();
        {
            let mut j = Journal::open(dir.path()).unwrap();
            j.record(bracket(&["a.jpg", "b.jpg"])).unwrap();
        }
        let mut j = Journal::open(dir.path()).unwrap();
        j.resolve_inputs(|p| Path::new("/real").join(p.strip_prefix("/").unwrap()));
        let mut moved = input("a.jpg");
        moved.path = PathBuf::from("/real/in/a.jpg");
        assert!(j.is_settled(&moved));
        assert!(!j.is_settled(&input("a.jpg")));
        assert!(j.developed(Path::new("/real/in/b.jpg")).is_some());
        assert!(j.developed(Path::new("/in/b.jpg")).is_none());
    }

    #[test]
    fn torn_last_line_is_skipped_and_next_entry_starts_fresh() {
        let dir = tempfile::tempdir().unwrap();
        {
            let mut j = Journal::open(dir.path()).unwrap();
            j.record(bracket(&["a.jpg", "b.jpg"])).unwrap();
        }
        let path = dir.path().join(FILE_NAME);
        let mut f = OpenOptions::new().append(true).open(&path).unwrap();
        f.write_all(b"{\"kind\":\"bracket\",\"id\":\"ff").unwrap();
        drop(f);
        let mut j = Journal::open(dir.path()).unwrap();
        assert_eq!(j.entries().len(), 1);
        j.record(bracket(&["c.jpg", "d.jpg"])).unwrap();
        drop(j);
        let j = Journal::open(dir.path()).unwrap();
        assert_eq!(j.entries().len(), 2);
        assert!(j.is_settled(&input("d.jpg")));
    }

    #[test]
    fn damage_in_the_middle_is_an_error_naming_the_line() {
        let dir = tempfile::tempdir().unwrap();
        fs::write(dir.path().join(FILE_NAME), "garbage\n{}\n").unwrap();
        let err = Journal::open(dir.path()).unwrap_err();
        let msg = err.to_string();
        assert!(msg.contains("journal.jsonl:1:"), "{msg}");
    }

    #[test]
    fn any_file_name_is_journaled_losslessly() {
        use std::os::unix::ffi::OsStrExt;
        let dir = tempfile::tempdir().unwrap();
        let odd = [
            &b"/in/bad\xff.jpg"[..],
            b"/in/line\nbreak.jpg",
            b"/in/\xc3\x28-half.jpg",
            "/in/caf\u{e9}.jpg".as_bytes(),
        ];
        let inputs: Vec<Input> = odd
            .iter()
            .map(|b| Input {
                path: PathBuf::from(std::ffi::OsStr::from_bytes(b)),
                size: 7,
                modified_ns: 1,
            })
            .collect();
        {
            let mut j = Journal::open(dir.path()).unwrap();
            for i in &inputs {
                j.record(Entry::Rejected {
                    input: i.clone(),
                    reason: "not an image".into(),
                    at: 3,
                })
                .unwrap();
            }
        }
        let j = Journal::open(dir.path()).unwrap();
        for i in &inputs {
            assert!(j.is_settled(i), "{}", i.path.display());
        }
        let text = fs::read_to_string(dir.path().join(FILE_NAME)).unwrap();
        assert!(
            text.contains("\"/in/caf\u{e9}.jpg\""),
            "UTF-8 stays text: {text}"
        );
    }

    /// Pinned: digests in existing journals must stay valid (FNV-1a 64 of "a" is
    /// 0xaf63dc4c8601ec8c in the FNV authors' test vectors).
    #[test]
    fn the_content_digest_is_64_bit_fnv_1a() {
        assert_eq!(content_digest(b""), atomic::FNV_OFFSET);
        assert_eq!(content_digest(b"a"), 0xaf63_dc4c_8601_ec8c);
        assert_eq!(
            atomic::fnv1a(content_digest(b"fo"), b"o"),
            content_digest(b"foo")
        );
    }

    #[test]
    fn missing_journal_reads_empty() {
        let dir = tempfile::tempdir().unwrap();
        assert!(read(&dir.path().join("nothing")).unwrap().is_empty());
    }
}
