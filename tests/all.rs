//! Every integration test, one module per file of `tests/`, in one test binary: Cargo
//! links each test binary against the whole library and its dependencies, so one binary
//! instead of eleven saves most of the test build (see `docs/testing.md`). Run a file's
//! tests with `cargo test --test all daemon::` (its file name and `::`).
//!
//! Cargo's automatic test targets are off (`autotests = false` in `Cargo.toml`): a new
//! file in `tests/` runs only once it has its `mod` line here, which
//! [`every_test_file_is_a_module_here`] checks.

mod align;
mod cache_cli;
mod calibrate;
mod cli;
mod colour;
mod common;
mod daemon;
mod deghost;
mod demosaic;
mod docs;
mod dng;
mod farm;
mod film;
mod hdr_still;
mod hostile;
mod layers;
mod lut;
mod merge;
mod raw;
mod real_files;
mod synthetic;
mod viewer;

/// Every `tests/*.rs` file (this one aside) is declared as a module above, so none is
/// left unbuilt and unrun.
#[test]
fn every_test_file_is_a_module_here() {
    let tests = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests");
    let this = include_str!("all.rs");
    let mut missing = Vec::new();
    for entry in std::fs::read_dir(&tests).expect("tests/ is readable") {
        let path = entry.expect("directory entry").path();
        let Some(stem) = path.file_stem().and_then(|s| s.to_str()) else {
            continue;
        };
        if path.extension().is_some_and(|e| e == "rs")
            && stem != "all"
            && !this.lines().any(|l| l == format!("mod {stem};"))
        {
            missing.push(path.display().to_string());
        }
    }
    assert!(
        missing.is_empty(),
        "add `mod NAME;` to tests/all.rs for {missing:?}"
    );
}
