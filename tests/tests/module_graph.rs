//! The modules of a crate form no import circle: a module that needs another's item while that
//! one needs its own is one module split in two, or a constant living on the wrong side (issue
//! 56: background ↔ control ↔ params for two constants, log ↔ system, frame ↔ signing).
//!
//! The graph is read from the sources, not the compiler: each file of a module directory, up to
//! its `#[cfg(test)] mod tests` (tests may use anything), with its comments dropped; an edge for
//! every `super::name::`, `crate::name::` and `super::{…}`/`super::Item` naming an item the
//! directory's `mod.rs` or `lib.rs` re-exports from a module.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// The source of `file` up to its unit tests, without `//` comments.
fn code_of(file: &Path) -> String {
    let text = std::fs::read_to_string(file).expect("a readable source file");
    let code = text.split("#[cfg(test)]\nmod tests").next().unwrap_or_default();
    code.lines()
        .map(|line| line.split("//").next().unwrap_or_default())
        .collect::<Vec<_>>()
        .join("\n")
}

/// Identifiers in `text`.
fn words(text: &str) -> impl Iterator<Item = &str> {
    text.split(|c: char| !(c.is_alphanumeric() || c == '_')).filter(|w| !w.is_empty())
}

/// Which module each item re-exported by `root` (`pub use module::{A, B};`, `pub use module::A;`)
/// comes from.
fn reexports(root: &str) -> BTreeMap<String, String> {
    let mut owner = BTreeMap::new();
    for statement in root.split(';') {
        let Some(rest) = statement.trim().strip_prefix("pub use ") else { continue };
        let Some((module, items)) = rest.split_once("::") else { continue };
        for item in words(items) {
            owner.insert(item.to_string(), module.to_string());
        }
    }
    owner
}

/// Every module of `dir` and the modules it uses (`prefix` is `super` or `crate`).
fn module_graph(dir: &Path, root_file: &str, prefix: &str) -> BTreeMap<String, BTreeSet<String>> {
    let owner = reexports(&code_of(&dir.join(root_file)));
    let mut graph = BTreeMap::new();
    for entry in std::fs::read_dir(dir).expect("a module directory") {
        let path = entry.expect("a directory entry").path();
        let Some(name) = path.file_stem().and_then(|s| s.to_str()) else { continue };
        if path.extension().is_none_or(|e| e != "rs") || name == "mod" || name == "lib" {
            continue;
        }
        let code = code_of(&path);
        let mut uses = BTreeSet::new();
        let marker = format!("{prefix}::");
        for (at, _) in code.match_indices(&marker) {
            let rest = &code[at + marker.len()..];
            if let Some(group) = rest.strip_prefix('{') {
                let group = group.split('}').next().unwrap_or_default();
                for word in words(group) {
                    match owner.get(word) {
                        Some(module) => uses.insert(module.clone()),
                        None => uses.insert(word.to_string()),
                    };
                }
                continue;
            }
            let word = words(rest).next().unwrap_or_default();
            let is_path = rest[word.len()..].starts_with("::");
            match owner.get(word) {
                Some(module) => uses.insert(module.clone()),
                None if is_path => uses.insert(word.to_string()),
                None => false,
            };
        }
        uses.remove(name);
        graph.insert(name.to_string(), uses);
    }
    let modules: BTreeSet<String> = graph.keys().cloned().collect();
    for uses in graph.values_mut() {
        uses.retain(|m| modules.contains(m));
    }
    graph
}

/// The import circles of `graph`, each as its modules in order, starting from the smallest.
fn circles(graph: &BTreeMap<String, BTreeSet<String>>) -> BTreeSet<Vec<String>> {
    fn walk(
        graph: &BTreeMap<String, BTreeSet<String>>,
        path: &mut Vec<String>,
        found: &mut BTreeSet<Vec<String>>,
    ) {
        let last = path.last().cloned().unwrap_or_default();
        for next in &graph[&last] {
            if *next == path[0] {
                let smallest = (0..path.len()).min_by_key(|&i| &path[i]).unwrap_or(0);
                let mut circle = path[smallest..].to_vec();
                circle.extend_from_slice(&path[..smallest]);
                found.insert(circle);
            } else if !path.contains(next) {
                path.push(next.clone());
                walk(graph, path, found);
                path.pop();
            }
        }
    }
    let mut found = BTreeSet::new();
    for start in graph.keys() {
        walk(graph, &mut vec![start.clone()], &mut found);
    }
    found
}

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("the workspace")
}

#[test]
fn the_firmware_application_and_the_protocol_have_no_import_circle() {
    for (dir, root_file, prefix) in [
        ("firmware/src/app", "mod.rs", "super"),
        ("protocol/src", "lib.rs", "crate"),
        ("flight/src", "lib.rs", "crate"),
    ] {
        let graph = module_graph(&root().join(dir), root_file, prefix);
        assert!(graph.len() >= 4, "{dir}: only {} modules read", graph.len());
        let found = circles(&graph);
        assert!(found.is_empty(), "{dir}: import circles {found:?}");
    }
}

#[test]
fn a_circle_through_a_reexported_item_is_found() {
    // Two modules of a scratch directory: `a` names `b`'s item through the root's re-export,
    // `b` names `a` by path.
    let dir = std::env::temp_dir().join(format!("module-graph-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("a scratch directory");
    std::fs::write(dir.join("mod.rs"), "mod a;\nmod b;\npub use b::{Thing, Other};\n").unwrap();
    std::fs::write(dir.join("a.rs"), "use super::{Thing};\n// super::c::X is a comment\n").unwrap();
    std::fs::write(dir.join("b.rs"), "pub struct Thing(super::a::Y);\n").unwrap();
    let graph = module_graph(&dir, "mod.rs", "super");
    let found = circles(&graph);
    let _ = std::fs::remove_dir_all(&dir);
    assert_eq!(found, BTreeSet::from([vec!["a".to_string(), "b".to_string()]]));
}
