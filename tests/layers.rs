//! The library reads as the pipeline bottom to top: a module's code (tests aside) uses
//! only the modules below it in [`LAYERS`], never one above it, so there is no import
//! circle. The order is the one `src/lib.rs` documents; the module tables of README.md and
//! docs/design.md state it too, and are checked against [`LAYERS`] here.

use std::path::{Path, PathBuf};

/// The library's top-level modules, bottom first.
const LAYERS: [&str; 19] = [
    "atomic",
    "metadata",
    "raw",
    "frame",
    "radiance",
    "histogram",
    "response",
    "align",
    "merge",
    "deghost",
    "hdr_output",
    "display",
    "film",
    "tonemap",
    "rendering",
    "darkroom",
    "synthetic",
    "daemon",
    "farm",
];

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).expect("src is readable") {
        let path = entry.expect("directory entry").path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// The code of a file without its tests (a `#[cfg(test)]` module closes every file that
/// has one; a `tests.rs` file is all tests) and without comments.
fn code(path: &Path) -> String {
    if path.file_name().is_some_and(|n| n == "tests.rs") {
        return String::new();
    }
    let text = std::fs::read_to_string(path).expect("source is readable");
    let body = text.split("#[cfg(test)]").next().unwrap_or_default();
    body.lines()
        .map(|l| l.split("//").next().unwrap_or_default())
        .collect::<Vec<_>>()
        .join("\n")
}

/// Every `crate::name` a piece of code refers to.
fn uses(code: &str) -> Vec<String> {
    let mut found = Vec::new();
    let mut rest = code;
    while let Some(i) = rest.find("crate::") {
        rest = &rest[i + "crate::".len()..];
        let name: String = rest
            .chars()
            .take_while(|c| c.is_alphanumeric() || *c == '_')
            .collect();
        if !name.is_empty() {
            found.push(name);
        }
    }
    found
}

#[test]
fn no_module_uses_one_above_it() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    let mut violations = Vec::new();
    let mut checked = 0;
    for file in &files {
        let relative = file.strip_prefix(&src).expect("under src");
        let top = relative
            .components()
            .next()
            .and_then(|c| c.as_os_str().to_str())
            .map(|s| s.trim_end_matches(".rs").to_string())
            .expect("a file name");
        // The binary (main.rs, cli/) sits above the library; lib.rs only declares.
        let Some(level) = LAYERS.iter().position(|l| *l == top) else {
            continue;
        };
        checked += 1;
        for used in uses(&code(file)) {
            match LAYERS.iter().position(|l| *l == used) {
                Some(other) if other > level => violations.push(format!(
                    "{} uses crate::{used}, which is above {top}",
                    relative.display()
                )),
                Some(_) => {}
                None => violations.push(format!(
                    "{} uses crate::{used}, which is not a layer",
                    relative.display()
                )),
            }
        }
    }
    assert!(
        checked > 30,
        "only {checked} library files found under src/"
    );
    assert!(violations.is_empty(), "{}", violations.join("\n"));
}

#[test]
fn every_library_module_has_a_layer() {
    let lib = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("src/lib.rs"))
        .expect("lib.rs is readable");
    let declared: Vec<&str> = lib
        .lines()
        .filter_map(|l| l.strip_prefix("pub mod "))
        .map(|l| l.trim_end_matches(';'))
        .collect();
    assert_eq!(
        declared, LAYERS,
        "lib.rs declares the modules in layer order"
    );
}

/// The modules a document's module table names, in its order: the rows of the table whose
/// header starts `| module |`, each first cell's `name` (or `name/`) spans.
fn stated_order(document: &str) -> Vec<String> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(document);
    let text = std::fs::read_to_string(&path).expect("the document is readable");
    text.lines()
        .skip_while(|l| !l.starts_with("| module |"))
        .skip(2)
        .take_while(|l| l.starts_with('|'))
        .flat_map(|row| {
            let cell = row.split('|').nth(1).unwrap_or_default();
            cell.split('`')
                .skip(1)
                .step_by(2)
                .map(|name| name.trim_end_matches('/').to_string())
                .collect::<Vec<_>>()
        })
        .collect()
}

#[test]
fn the_readme_and_the_design_doc_state_the_layer_order() {
    for document in ["README.md", "docs/design.md"] {
        let levels: Vec<usize> = stated_order(document)
            .iter()
            .filter_map(|name| LAYERS.iter().position(|l| l == name))
            .collect();
        assert!(
            levels.len() >= 12,
            "{document}: only {} layers named in its module table",
            levels.len()
        );
        let out_of_order: Vec<String> = levels
            .windows(2)
            .filter(|w| w[0] >= w[1])
            .map(|w| format!("{} before {}", LAYERS[w[0]], LAYERS[w[1]]))
            .collect();
        assert!(
            out_of_order.is_empty(),
            "{document} names the modules in another order than LAYERS: {}",
            out_of_order.join(", ")
        );
    }
}
