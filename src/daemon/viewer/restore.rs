//! The Session view after a restart: the journal's latest developments (at most
//! [`GALLERY`], newest first, one per output stem), each from the record kept beside its
//! previews ([`RECORD_FILE`]) when that names the same outputs, otherwise from the
//! journal's entry alone (names, camera, frames, response's origin; no timings or
//! measurements). Previews already made are linked at once; the rest are made by the
//! previews worker when it has no new development to do.

use std::collections::{HashSet, VecDeque};
use std::path::Path;
use std::sync::Arc;

use tracing::warn;

use super::previews::{self, RECORD_FILE};
use super::{Files, FrameRecord, GALLERY, Gallery, Kind, Published, Record};
use super::{file_name, output_records};
use crate::daemon::journal::Entry;

/// Largest kept record read back, bytes (a record is a few kilobytes).
const MAX_RECORD_BYTES: u64 = 1024 * 1024;

/// Note on a record rebuilt from the journal alone.
const FROM_JOURNAL: &str =
    "shown again after a restart: its timings and measurements were not kept";

/// The gallery of `journal`'s latest developments, with their previews in `dir`
/// (`state/previews`) linked; and those whose previews are incomplete, newest first,
/// for the worker. Records are numbered from the start's Unix time in milliseconds up
/// (the newest highest), so a number from before a restart names nothing after it.
pub(super) async fn gallery(journal: &[Entry], dir: &Path) -> (Gallery, VecDeque<Published>) {
    let recent = recent(journal);
    let dir = dir.to_path_buf();
    let base = crate::daemon::journal::unix_now().saturating_mul(1000);
    let restored = tokio::task::spawn_blocking(move || restore_all(&recent, &dir, base)).await;
    let restored = restored.unwrap_or_else(|e| {
        warn!(error = %e, "the session's recent brackets could not be read back");
        Vec::new()
    });
    let mut gallery = Gallery::default();
    let mut unfinished = VecDeque::new();
    for (published, complete) in restored {
        gallery
            .records
            .push_back(Arc::new(published.record.clone()));
        if !complete {
            unfinished.push_back(published);
        }
    }
    gallery.next_id = base + gallery.records.len() as u64;
    (gallery, unfinished)
}

/// The latest bracket or single of each output stem that published outputs, newest
/// first, at most [`GALLERY`].
fn recent(journal: &[Entry]) -> Vec<Entry> {
    let mut stems = HashSet::new();
    journal
        .iter()
        .rev()
        .filter(|e| match e {
            Entry::Bracket { outputs, .. } | Entry::Single { outputs, .. } => !outputs.is_empty(),
            _ => false,
        })
        .filter(|e| e.output_stem().is_some_and(|s| stems.insert(s)))
        .take(GALLERY)
        .cloned()
        .collect()
}

/// The records of `recent` (newest first), numbered `base + 1` (the oldest) up, their
/// previews in `dir` linked; each with whether its previews are complete.
fn restore_all(recent: &[Entry], dir: &Path, base: u64) -> Vec<(Published, bool)> {
    let n = recent.len() as u64;
    recent
        .iter()
        .zip((base + 1..=base + n).rev())
        .filter_map(|(entry, id)| {
            let mut published = restore(entry, dir)?;
            published.record.id = id;
            let folder = dir.join(&published.record.stem);
            previews::link(&mut published.record, &folder);
            let complete = previews::complete(&published.record, &published.frame_paths);
            Some((published, complete))
        })
        .collect()
}

/// The record of one journal entry, its URLs not yet filled in.
fn restore(entry: &Entry, dir: &Path) -> Option<Published> {
    let stem = entry.output_stem()?;
    let (kind, camera, inputs, outputs, response, at) = match entry {
        Entry::Bracket {
            camera,
            inputs,
            outputs,
            response,
            at,
            ..
        } => (
            Kind::Bracket,
            camera,
            inputs.as_slice(),
            outputs,
            response.to_string(),
            *at,
        ),
        Entry::Single {
            camera,
            input,
            outputs,
            at,
            ..
        } => (
            Kind::Single,
            camera,
            std::slice::from_ref(input),
            outputs,
            "unknown".to_string(),
            *at,
        ),
        _ => return None,
    };
    let names: Vec<String> = outputs.iter().map(|p| file_name(p)).collect();
    let record = kept(&dir.join(&stem), &names).unwrap_or_else(|| {
        let outputs = output_records(&stem, outputs);
        Record {
            id: 0,
            camera: camera.to_string(),
            kind,
            at,
            frames: inputs
                .iter()
                .map(|i| FrameRecord {
                    name: file_name(&i.path),
                    stops: None,
                    thumb: None,
                })
                .collect(),
            looks: outputs.iter().filter_map(|o| o.look.clone()).collect(),
            outputs,
            response,
            confidence: None,
            facts: crate::daemon::Facts::default(),
            clipped: None,
            left_out: None,
            stages: Vec::new(),
            total_ms: 0.0,
            notes: vec![FROM_JOURNAL.to_string()],
            stem,
            files: Files::default(),
        }
    });
    Some(Published {
        record: Record {
            files: Files {
                outputs: outputs.clone(),
                ..Files::default()
            },
            ..record
        },
        frame_paths: inputs.iter().map(|i| i.path.clone()).collect(),
        pictures: None,
    })
}

/// The record kept in `folder`, if it is readable and lists the outputs `names`.
fn kept(folder: &Path, names: &[String]) -> Option<Record> {
    let path = folder.join(RECORD_FILE);
    let meta = std::fs::metadata(&path).ok()?;
    if !meta.is_file() || meta.len() > MAX_RECORD_BYTES {
        return None;
    }
    let record: Record = serde_json::from_slice(&std::fs::read(&path).ok()?).ok()?;
    record
        .outputs
        .iter()
        .map(|o| &o.name)
        .eq(names.iter())
        .then_some(record)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::daemon::bracket::{Alone, CameraId, Input};
    use std::path::PathBuf;

    fn single(name: &str, at: u64, outputs: &[&str]) -> Entry {
        Entry::Single {
            id: format!("{at:016x}"),
            camera: CameraId::default(),
            input: Input {
                path: PathBuf::from(format!("/in/{name}.jpg")),
                size: 1,
                modified_ns: 0,
            },
            alone: Alone::NoPartner,
            outputs: outputs.iter().map(PathBuf::from).collect(),
            digests: Vec::new(),
            at,
        }
    }

    #[test]
    fn recent_keeps_the_latest_of_each_stem_newest_first() {
        let journal = vec![
            single("A", 1, &["/out/A.linear.jpg"]),
            single("B", 2, &["/out/B.linear.jpg"]),
            single("C", 3, &[]),
            single("A", 4, &["/out/A.linear.jpg"]),
        ];
        let at: Vec<u64> = recent(&journal)
            .iter()
            .map(|e| match e {
                Entry::Single { at, .. } => *at,
                _ => 0,
            })
            .collect();
        assert_eq!(at, vec![4, 2]);
    }

    #[test]
    fn recent_is_bounded_like_the_live_list() {
        let journal: Vec<Entry> = (0..GALLERY as u64 + 5)
            .map(|k| single(&format!("S{k}"), k, &[&format!("/out/S{k}.linear.jpg")]))
            .collect();
        assert_eq!(recent(&journal).len(), GALLERY);
    }

    #[test]
    fn a_kept_record_is_used_only_for_the_same_outputs() {
        let dir = tempfile::tempdir().unwrap();
        let entry = single("K", 7, &["/out/K.linear.jpg"]);
        let mut first = restore(&entry, dir.path()).unwrap();
        assert_eq!(first.record.notes, vec![FROM_JOURNAL.to_string()]);
        first.record.notes = vec!["kept".to_string()];
        let folder = dir.path().join("K");
        std::fs::create_dir_all(&folder).unwrap();
        let json = serde_json::to_vec(&first.record).unwrap();
        std::fs::write(folder.join(RECORD_FILE), json).unwrap();
        let again = restore(&entry, dir.path()).unwrap();
        assert_eq!(again.record.notes, vec!["kept".to_string()]);
        assert_eq!(
            again.record.files.outputs,
            vec![PathBuf::from("/out/K.linear.jpg")]
        );
        let other = single("K", 8, &["/out/K.velvia50-t1.jpg"]);
        let rebuilt = restore(&other, dir.path()).unwrap();
        assert_eq!(rebuilt.record.notes, vec![FROM_JOURNAL.to_string()]);
        assert_eq!(rebuilt.record.looks, vec!["velvia50-t1".to_string()]);
    }
}
