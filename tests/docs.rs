//! The documents link to each other by relative paths and heading anchors; a renamed
//! heading or a moved page leaves a link that leads nowhere. Every relative link of the
//! README, the CHANGELOG and `docs/` must name a file that exists and, with a `#anchor`
//! into a Markdown file, a heading (or `<a id>`) of that file.

use std::collections::HashSet;
use std::path::{Path, PathBuf};

/// The Markdown files checked: the README, the CHANGELOG and everything under `docs/`.
fn documents(root: &Path) -> Vec<PathBuf> {
    let mut out = vec![root.join("README.md"), root.join("CHANGELOG.md")];
    let mut dirs = vec![root.join("docs")];
    while let Some(dir) = dirs.pop() {
        for entry in std::fs::read_dir(&dir).expect("docs/ is readable") {
            let path = entry.expect("directory entry").path();
            if path.is_dir() {
                dirs.push(path);
            } else if path.extension().is_some_and(|e| e == "md") {
                out.push(path);
            }
        }
    }
    out
}

/// A heading's anchor as GitHub makes it: lower case, letters, digits, `-` and `_` kept,
/// spaces to `-`, everything else dropped.
fn slug(heading: &str) -> String {
    heading
        .trim()
        .chars()
        .filter_map(|c| match c {
            ' ' => Some('-'),
            '-' | '_' => Some(c),
            c if c.is_alphanumeric() => Some(c),
            _ => None,
        })
        .flat_map(char::to_lowercase)
        .collect()
}

/// The anchors a Markdown text defines: its headings' slugs and explicit `<a id="…">` or
/// `<a name="…">` (code blocks aside).
fn anchors(text: &str) -> HashSet<String> {
    let mut found = HashSet::new();
    let mut in_code = false;
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            in_code = !in_code;
        }
        if in_code {
            continue;
        }
        if let Some(heading) = line.strip_prefix('#') {
            found.insert(slug(heading.trim_start_matches('#')));
        }
        for key in ["<a id=\"", "<a name=\""] {
            for (i, _) in line.match_indices(key) {
                let rest = &line[i + key.len()..];
                found.insert(rest.split('"').next().unwrap_or_default().to_string());
            }
        }
    }
    found
}

/// The targets of the inline links `[text](target)` of a Markdown text.
fn links(text: &str) -> Vec<String> {
    let mut found = Vec::new();
    for (i, _) in text.match_indices("](") {
        let rest = &text[i + 2..];
        if let Some(end) = rest.find(')') {
            let target = &rest[..end];
            if !target.contains(char::is_whitespace) {
                found.push(target.to_string());
            }
        }
    }
    found
}

/// Why a link of `document` leads nowhere, if it does.
fn broken(document: &Path, target: &str) -> Option<String> {
    if target.contains("://") || target.starts_with("mailto:") {
        return None;
    }
    let (path, anchor) = target.split_once('#').unwrap_or((target, ""));
    let file = if path.is_empty() {
        document.to_path_buf()
    } else {
        document.parent().expect("a document's folder").join(path)
    };
    if !file.exists() {
        return Some(format!("{target}: no file {}", file.display()));
    }
    if anchor.is_empty() || file.extension().is_none_or(|e| e != "md") {
        return None;
    }
    let text = std::fs::read_to_string(&file).expect("a linked document is readable");
    (!anchors(&text).contains(anchor)).then(|| format!("{target}: no such heading"))
}

#[test]
fn every_relative_link_of_the_docs_leads_somewhere() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut bad = Vec::new();
    for document in documents(root) {
        let text = std::fs::read_to_string(&document).expect("a document is readable");
        for target in links(&text) {
            if let Some(why) = broken(&document, &target) {
                let name = document.strip_prefix(root).unwrap_or(&document);
                bad.push(format!("{}: {why}", name.display()));
            }
        }
    }
    assert!(
        bad.is_empty(),
        "links that lead nowhere:\n{}",
        bad.join("\n")
    );
}

#[test]
fn a_heading_s_anchor_is_the_one_github_makes() {
    assert_eq!(
        slug(" Film options (grain, MTF, halation, printing)"),
        "film-options-grain-mtf-halation-printing"
    );
    assert_eq!(slug(" Each look alone: 0.15 s"), "each-look-alone-015-s");
    let text = "# Top\n```\n# not a heading\n```\n## A–b <a id=\"x\"></a>\n";
    let found = anchors(text);
    assert!(found.contains("top") && found.contains("ab-a-idxa") && found.contains("x"));
    assert!(!found.contains("not-a-heading"));
}
