//! The documentation stands alone: every relative link in `README.md` and `docs/**/*.md` leads to
//! a file of the repository (and to a heading of it when the link names one), every
//! `docs/….md` path named in a source comment exists, and nothing cites notes that live outside
//! the repository, which a reader of it cannot see.

use std::fs;
use std::path::{Path, PathBuf};

/// The workspace root (this crate sits one level below it).
fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("workspace root").to_path_buf()
}

/// Files below `dir` whose name ends with one of `extensions`, skipping build output and hidden
/// directories.
fn files(dir: &Path, extensions: &[&str], out: &mut Vec<PathBuf>) {
    let Ok(entries) = fs::read_dir(dir) else { return };
    for entry in entries.flatten() {
        let path = entry.path();
        let name = entry.file_name().to_string_lossy().into_owned();
        if path.is_dir() {
            if name != "target" && !name.starts_with('.') {
                files(&path, extensions, out);
            }
        } else if extensions.iter().any(|e| name.ends_with(e)) {
            out.push(path);
        }
    }
}

/// The markdown documents: `README.md` and everything under `docs/`.
fn documents() -> Vec<PathBuf> {
    let mut out = vec![root().join("README.md")];
    files(&root().join("docs"), &[".md"], &mut out);
    out
}

/// Text outside fenced code blocks.
fn prose(text: &str) -> String {
    let mut fenced = false;
    let mut out = String::new();
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
            continue;
        }
        if !fenced {
            out.push_str(line);
            out.push('\n');
        }
    }
    out
}

/// The targets of the inline links `[text](target)` of a markdown text.
fn link_targets(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut rest = text;
    while let Some(at) = rest.find("](") {
        let after = &rest[at + 2..];
        match after.find(')') {
            Some(end) => {
                out.push(after[..end].trim().to_string());
                rest = &after[end..];
            }
            None => break,
        }
    }
    out
}

/// GitHub's anchor of a heading: lower case, punctuation dropped, spaces as hyphens.
fn anchor(heading: &str) -> String {
    heading
        .trim()
        .to_lowercase()
        .chars()
        .filter(|c| c.is_alphanumeric() || *c == '-' || *c == '_' || *c == ' ')
        .map(|c| if c == ' ' { '-' } else { c })
        .collect()
}

/// The anchors of every heading of a markdown text.
fn anchors(text: &str) -> Vec<String> {
    prose(text)
        .lines()
        .filter_map(|line| {
            let hashes = line.chars().take_while(|c| *c == '#').count();
            (1..=6).contains(&hashes).then(|| line[hashes..].to_string())
        })
        .filter(|heading| heading.starts_with(' '))
        .map(|heading| anchor(&heading))
        .collect()
}

/// The workspace's crates (and `tests`), whose sources may name docs and must not cite notes
/// outside the repository.
const SOURCE_DIRS: [&str; 9] = [
    "protocol",
    "flight",
    "imu-offset",
    "tumble",
    "firmware",
    "sim",
    "configurator-cli",
    "xtask",
    "tests",
];

#[test]
fn every_relative_link_of_the_docs_leads_to_an_existing_file_and_heading() {
    let mut checked = 0;
    let mut broken = Vec::new();
    for document in documents() {
        let text = fs::read_to_string(&document).expect("readable document");
        for target in link_targets(&prose(&text)) {
            if target.contains("://") || target.starts_with("mailto:") {
                continue;
            }
            checked += 1;
            let (path, fragment) = target.split_once('#').unwrap_or((target.as_str(), ""));
            let destination =
                if path.is_empty() { document.clone() } else { document.with_file_name(path) };
            if !destination.exists() {
                broken.push(format!("{}: {target}: no such file", document.display()));
                continue;
            }
            if !fragment.is_empty() && destination.extension().is_some_and(|e| e == "md") {
                let headings = anchors(&fs::read_to_string(&destination).expect("readable"));
                if !headings.iter().any(|a| a == fragment) {
                    broken.push(format!("{}: {target}: no such heading", document.display()));
                }
            }
        }
    }
    assert!(broken.is_empty(), "broken links:\n{}", broken.join("\n"));
    // The docs link to one another (the algorithms pages alone have dozens of links): a parser
    // that found none would pass vacuously.
    assert!(checked >= 30, "only {checked} relative links found");
}

#[test]
fn every_docs_path_named_in_the_sources_exists() {
    let mut sources = Vec::new();
    for dir in SOURCE_DIRS {
        files(&root().join(dir), &[".rs", ".toml"], &mut sources);
    }
    let mut named = 0;
    let mut missing = Vec::new();
    for source in sources {
        let text = fs::read_to_string(&source).expect("readable source");
        let mut rest = text.as_str();
        while let Some(at) = rest.find("docs/") {
            let tail = &rest[at..];
            let end = tail
                .find(|c: char| !(c.is_alphanumeric() || "/._-".contains(c)))
                .unwrap_or(tail.len());
            let path = tail[..end].trim_end_matches('.');
            if path.ends_with(".md") {
                named += 1;
                if !root().join(path).exists() {
                    missing.push(format!("{}: {path}", source.display()));
                }
            }
            rest = &tail[end..];
        }
    }
    assert!(missing.is_empty(), "docs named in the sources but missing:\n{}", missing.join("\n"));
    assert!(named >= 30, "only {named} docs paths found in the sources");
}

#[test]
fn nothing_cites_notes_that_live_outside_the_repository() {
    // Spelled in pieces so that this file does not match itself.
    let outside = [
        ["algorithms", ".md"].concat(),
        ["DESIGN", ".md"].concat(),
        ["../shared", "/"].concat(),
        ["reference", "/paper-"].concat(),
        ["toolchain", "-notes"].concat(),
    ];
    let mut texts = documents();
    for dir in SOURCE_DIRS {
        files(&root().join(dir), &[".rs", ".toml", ".md"], &mut texts);
    }
    let mut citing = Vec::new();
    for path in texts {
        let text = fs::read_to_string(&path).expect("readable");
        for (number, line) in text.lines().enumerate() {
            if let Some(name) = outside.iter().find(|name| line.contains(name.as_str())) {
                citing.push(format!("{}:{}: {name}", path.display(), number + 1));
            }
        }
    }
    assert!(citing.is_empty(), "citations of notes outside the repository:\n{}", citing.join("\n"));
}

/// docs/protocol.md's title names the version the firmware announces in its handshake: a
/// protocol change that forgets `PROTOCOL_VERSION` (1.10 did) or the page fails here.
#[test]
fn the_protocol_page_and_the_code_name_the_same_version() {
    let page = std::fs::read_to_string(root().join("docs/protocol.md")).unwrap();
    let title = page.lines().next().unwrap_or_default();
    let version = protocol::PROTOCOL_VERSION;
    let expected = format!("# The wire protocol (version {}.{})", version.major, version.minor);
    assert_eq!(title, expected);
}
