//! Publishing output files atomically: nothing half-written is ever visible under its
//! final name.
//!
//! The bytes go to a hidden temporary file in the destination folder, are flushed to disk
//! (`fsync`), and only then appear under the final name: by `rename` when overwriting is
//! allowed, by `link` (which fails if the name exists, so two writers can never clobber
//! each other) when it is not. The folder is synced afterwards so the new name survives a
//! power cut. On any error the temporary file is removed.

use std::fs::{self, File};
use std::io::{self, Write};
use std::path::{Path, PathBuf};

/// Whether an existing file under the final name may be replaced.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Overwrite {
    /// Replace it.
    Replace,
    /// Refuse with [`PublishError::Exists`].
    Refuse,
}

/// Why a file could not be published.
#[derive(Debug, thiserror::Error)]
pub enum PublishError {
    /// The final name is taken and overwriting was refused.
    #[error("{path}: already exists (not overwritten)")]
    Exists {
        /// The final name.
        path: PathBuf,
    },
    /// Writing, syncing or renaming failed (full disk, permissions, …).
    #[error("{path}: cannot write: {source}")]
    Io {
        /// The final name.
        path: PathBuf,
        /// What the operating system said.
        source: io::Error,
    },
    /// The content producer failed; nothing was published.
    #[error("{path}: {reason}")]
    Content {
        /// The final name.
        path: PathBuf,
        /// What went wrong while producing the bytes.
        reason: String,
    },
}

/// The temporary name used for `path` while it is written: `.<name>.filmback-tmp-<pid>`
/// in the same folder. Watchers and cleanup recognise it by [`is_temporary`].
pub fn temporary_name(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    path.with_file_name(format!(".{name}.filmback-tmp-{}", std::process::id()))
}

/// True for names made by [`temporary_name`].
pub fn is_temporary(path: &Path) -> bool {
    path.file_name()
        .and_then(|n| n.to_str())
        .is_some_and(|n| n.starts_with('.') && n.contains(".filmback-tmp-"))
}

/// Writes the bytes that `produce` streams into the file, then publishes it at `path`.
pub fn publish_with<F>(path: &Path, overwrite: Overwrite, produce: F) -> Result<(), PublishError>
where
    F: FnOnce(&mut io::BufWriter<&mut File>) -> Result<(), String>,
{
    if overwrite == Overwrite::Refuse && path.exists() {
        return Err(PublishError::Exists {
            path: path.to_path_buf(),
        });
    }
    let tmp = temporary_name(path);
    let io_err = |source: io::Error| PublishError::Io {
        path: path.to_path_buf(),
        source,
    };
    let result = (|| {
        let mut file = File::create(&tmp).map_err(io_err)?;
        {
            let mut writer = io::BufWriter::with_capacity(1 << 20, &mut file);
            produce(&mut writer).map_err(|reason| PublishError::Content {
                path: path.to_path_buf(),
                reason,
            })?;
            writer.flush().map_err(io_err)?;
        }
        file.sync_all().map_err(io_err)?;
        drop(file);
        match overwrite {
            Overwrite::Replace => fs::rename(&tmp, path).map_err(io_err)?,
            Overwrite::Refuse => {
                fs::hard_link(&tmp, path).map_err(|source| {
                    if source.kind() == io::ErrorKind::AlreadyExists {
                        PublishError::Exists {
                            path: path.to_path_buf(),
                        }
                    } else {
                        io_err(source)
                    }
                })?;
                fs::remove_file(&tmp).map_err(io_err)?;
            }
        }
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            // Persist the directory entry; not every file system supports syncing a folder.
            if let Ok(d) = File::open(dir) {
                let _ = d.sync_all();
            }
        }
        Ok(())
    })();
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    result
}

/// Publishes `bytes` at `path` (see [`publish_with`]).
pub fn publish(path: &Path, bytes: &[u8], overwrite: Overwrite) -> Result<(), PublishError> {
    publish_with(path, overwrite, |w| {
        w.write_all(bytes).map_err(|e| e.to_string())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn publishes_and_refuses_to_clobber() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.bin");
        publish(&path, b"one", Overwrite::Refuse).unwrap();
        assert_eq!(fs::read(&path).unwrap(), b"one");
        let err = publish(&path, b"two", Overwrite::Refuse).unwrap_err();
        assert!(matches!(err, PublishError::Exists { .. }), "{err}");
        assert_eq!(fs::read(&path).unwrap(), b"one");
        publish(&path, b"three", Overwrite::Replace).unwrap();
        assert_eq!(fs::read(&path).unwrap(), b"three");
        let names: Vec<_> = fs::read_dir(dir.path()).unwrap().collect();
        assert_eq!(names.len(), 1, "no temporary file left behind");
    }

    #[test]
    fn failed_producer_leaves_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("b.bin");
        let err = publish_with(&path, Overwrite::Replace, |w| {
            w.write_all(b"partial").map_err(|e| e.to_string())?;
            Err("encoder failed".to_string())
        })
        .unwrap_err();
        assert!(err.to_string().contains("encoder failed"));
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 0);
    }

    #[test]
    fn unwritable_folder_is_an_error_naming_the_file() {
        let path = Path::new("/nonexistent-folder-filmback/c.bin");
        let err = publish(path, b"x", Overwrite::Replace).unwrap_err();
        assert!(err.to_string().contains("c.bin"), "{err}");
    }
}
