//! The real brackets beside the repository, as folders of frames with their exposures
//! (shared by the integration tests and the benches, which include this file).

use std::path::{Path, PathBuf};

/// Each real bracket under `root` (one folder a bracket, in name order) with its frames
/// and their relative exposures, darkest first: from `exposure_times_seconds.csv`
/// (`file,exposure_seconds`) when the folder has one, else from each image's EXIF
/// (`t·S/N²`, the parts a file lacks taken as equal across the set: learnopencv has no
/// ISO tag). Folders with fewer than two such frames are left out; none when `root` is
/// absent.
pub fn real_brackets(root: &Path) -> Vec<(String, Vec<(PathBuf, f64)>)> {
    let Ok(entries) = std::fs::read_dir(root) else {
        return Vec::new();
    };
    let mut dirs: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_dir())
        .collect();
    dirs.sort();
    let mut sets = Vec::new();
    for dir in dirs {
        let name = dir.file_name().unwrap().to_string_lossy().into_owned();
        let mut files: Vec<(PathBuf, f64)> =
            match std::fs::read_to_string(dir.join("exposure_times_seconds.csv")) {
                Ok(csv) => csv
                    .lines()
                    .skip(1)
                    .filter_map(|l| {
                        let (f, t) = l.split_once(',')?;
                        Some((dir.join(f.trim()), t.trim().parse().ok()?))
                    })
                    .collect(),
                Err(_) => {
                    let Ok(entries) = std::fs::read_dir(&dir) else {
                        continue;
                    };
                    entries
                        .filter_map(|e| e.ok().map(|e| e.path()))
                        .filter(|p| {
                            p.extension().is_some_and(|e| {
                                ["jpg", "jpeg", "png", "tif", "tiff"]
                                    .contains(&e.to_string_lossy().to_lowercase().as_str())
                            })
                        })
                        .filter_map(|p| {
                            let bytes = std::fs::read(&p).ok()?;
                            let e = filmback::metadata::read(&bytes).exposure;
                            let n = e.f_number.unwrap_or(1.0);
                            Some((p, e.time_s? * e.iso.unwrap_or(100.0) / (n * n)))
                        })
                        .collect()
                }
            };
        files.sort_by(|a, b| a.1.total_cmp(&b.1));
        if files.len() >= 2 {
            sets.push((name, files));
        }
    }
    sets
}
