//! The layout rules of `src/`, read from the source itself: one dependency direction (no module imports a
//! module that imports it back, at the level of top-level modules and of files), the build's inference
//! modules never reach into training, commands or dataset readers, and files stay small enough to read
//! in one sitting.
//!
//! Imports are read from `use` trees and from `crate::` / `super::` paths in code (comments and string
//! literals are skipped). A `mod.rs` declaring and re-exporting its own children is containment, not a
//! dependency, so a parent's references to its descendants are not counted.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// A module path (`["stages", "pose"]`; the crate root is empty).
type ModPath = Vec<String>;

/// Longest file under `src/` without a header line saying why it is longer.
const MAX_LINES: usize = 400;

/// Top-level modules the build's inference path is made of, and those they may never import.
const INFERENCE: [&str; 14] = [
    "atomic", "geometry", "rng", "runtime", "shards", "sources", "tsdf", "nn", "correction", "diffusion", "inpainting", "scene", "stages",
    "registration",
];
const ABOVE_INFERENCE: [&str; 7] = ["training", "commands", "cli", "export", "preview", "query", "labels"];

fn src_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("src")
}

/// Every `.rs` file under `dir`, with its module path.
fn module_files(dir: &Path, root: &Path, out: &mut BTreeMap<ModPath, PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            module_files(&path, root, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            let rel = path.strip_prefix(root).unwrap().with_extension("");
            let mut parts: ModPath = rel.iter().map(|p| p.to_string_lossy().into_owned()).collect();
            if matches!(parts.last().map(String::as_str), Some("mod")) || parts == ["lib"] || parts == ["main"] {
                parts.pop();
            }
            out.insert(parts, path);
        }
    }
}

/// The source with comments removed and string / char literals emptied (lifetimes kept).
fn code_only(src: &str) -> String {
    let b: Vec<char> = src.chars().collect();
    let (mut out, mut i) = (String::with_capacity(b.len()), 0);
    while i < b.len() {
        let c = b[i];
        let next = b.get(i + 1).copied();
        if c == '/' && next == Some('/') {
            while i < b.len() && b[i] != '\n' {
                i += 1;
            }
        } else if c == '/' && next == Some('*') {
            let mut depth = 0;
            while i < b.len() {
                if b[i] == '/' && b.get(i + 1) == Some(&'*') {
                    depth += 1;
                    i += 2;
                } else if b[i] == '*' && b.get(i + 1) == Some(&'/') {
                    depth -= 1;
                    i += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    i += 1;
                }
            }
        } else if c == 'r' && (next == Some('"') || next == Some('#')) && !b.get(i.wrapping_sub(1)).is_some_and(|p| p.is_alphanumeric() || *p == '_') {
            // Raw string r"..." or r#"..."#.
            let mut j = i + 1;
            let mut hashes = 0;
            while b.get(j) == Some(&'#') {
                hashes += 1;
                j += 1;
            }
            if b.get(j) != Some(&'"') {
                out.push(c);
                i += 1;
                continue;
            }
            j += 1;
            loop {
                if j >= b.len() {
                    break;
                }
                if b[j] == '"' && (0..hashes).all(|h| b.get(j + 1 + h) == Some(&'#')) {
                    j += 1 + hashes;
                    break;
                }
                j += 1;
            }
            out.push_str("\"\"");
            i = j;
        } else if c == '"' {
            i += 1;
            while i < b.len() && b[i] != '"' {
                i += if b[i] == '\\' { 2 } else { 1 };
            }
            i += 1;
            out.push_str("\"\"");
        } else if c == '\'' {
            // A char literal ('x', '\n', '\u{..}') or a lifetime ('a).
            if next == Some('\\') {
                i += 2;
                while i < b.len() && b[i] != '\'' {
                    i += 1;
                }
                i += 1;
                out.push_str("' '");
            } else if b.get(i + 2) == Some(&'\'') {
                i += 3;
                out.push_str("' '");
            } else {
                out.push(c);
                i += 1;
            }
        } else {
            out.push(c);
            i += 1;
        }
    }
    out
}

fn is_ident(c: char) -> bool {
    c.is_alphanumeric() || c == '_'
}

/// Expands a `use` tree (`a::{b, c::{d as e, *}}`) into paths, each a list of segments.
fn expand_use(tree: &str, prefix: &[String], out: &mut Vec<Vec<String>>) {
    let mut depth = 0;
    let mut items = Vec::new();
    let mut cur = String::new();
    for c in tree.chars() {
        match c {
            '{' => depth += 1,
            '}' => depth -= 1,
            _ => {}
        }
        if c == ',' && depth == 0 {
            items.push(std::mem::take(&mut cur));
        } else {
            cur.push(c);
        }
    }
    items.push(cur);
    for item in items {
        let item: String = item.split_whitespace().collect::<Vec<_>>().join(" ");
        let item = item.trim();
        if item.is_empty() {
            continue;
        }
        if let Some(open) = item.find('{') {
            let head = item[..open].trim_end_matches("::");
            let inner = &item[open + 1..item.rfind('}').unwrap_or(item.len())];
            let mut p = prefix.to_vec();
            p.extend(head.split("::").filter(|s| !s.is_empty()).map(|s| s.trim().to_string()));
            expand_use(inner, &p, out);
        } else {
            let item = item.split(" as ").next().unwrap().trim();
            let mut p = prefix.to_vec();
            p.extend(item.split("::").map(|s| s.trim().to_string()).filter(|s| !s.is_empty()));
            out.push(p);
        }
    }
}

/// Every path a file refers to: its `use` trees and the `crate::…` / `super::…` paths in its code.
fn referenced_paths(code: &str) -> Vec<Vec<String>> {
    let mut paths = Vec::new();
    let chars: Vec<char> = code.chars().collect();
    let text: String = chars.iter().collect();
    // `use` statements.
    let mut at = 0;
    while let Some(pos) = text[at..].find("use ") {
        let start = at + pos;
        at = start + 4;
        if start > 0 && text[..start].chars().last().is_some_and(is_ident) {
            continue;
        }
        if let Some(end) = text[start..].find(';') {
            let tree = &text[start + 4..start + end];
            if !tree.contains('(') && !tree.contains('=') {
                expand_use(tree, &[], &mut paths);
            }
        }
    }
    // Inline paths.
    for anchor in ["crate::", "super::"] {
        let mut at = 0;
        while let Some(pos) = text[at..].find(anchor) {
            let start = at + pos;
            at = start + anchor.len();
            if start > 0 && text[..start].chars().last().is_some_and(|c| is_ident(c) || c == ':') {
                continue;
            }
            let rest: String = text[start..].chars().take_while(|c| is_ident(*c) || *c == ':').collect();
            paths.push(rest.split("::").filter(|s| !s.is_empty()).map(str::to_string).collect());
        }
    }
    paths
}

/// The module a path in module `from` (a file; `is_mod` when it is a `mod.rs` or the crate root) names:
/// the longest prefix of its absolute form that is a module file.
fn resolve(path: &[String], from: &ModPath, is_mod: bool, modules: &BTreeMap<ModPath, PathBuf>) -> Option<ModPath> {
    let mut abs: ModPath;
    let mut rest = path;
    match path.first().map(String::as_str) {
        Some("crate") => {
            abs = Vec::new();
            rest = &path[1..];
        }
        Some("super") => {
            // `super` of a file `a/b.rs` (module a::b) is `a`; of `a/b/mod.rs` (module a::b) is also `a`.
            abs = from.clone();
            while rest.first().map(String::as_str) == Some("super") {
                abs.pop();
                rest = &rest[1..];
            }
        }
        Some("self") => {
            abs = from.clone();
            rest = &path[1..];
        }
        Some(first) => {
            // A relative path names a child of a `mod.rs` (`use child::X`); anything else is an extern crate.
            let mut child = from.clone();
            child.push(first.to_string());
            if !is_mod || !modules.contains_key(&child) {
                return None;
            }
            abs = from.clone();
        }
        None => return None,
    }
    abs.extend(rest.iter().cloned());
    (1..=abs.len()).rev().map(|k| abs[..k].to_vec()).find(|m| modules.contains_key(m))
}

/// The import graph of the files under `src/`: module → modules it imports (a parent's references to its
/// own descendants left out).
fn import_graph() -> (BTreeMap<ModPath, PathBuf>, BTreeMap<ModPath, BTreeSet<ModPath>>) {
    let root = src_dir();
    let mut modules = BTreeMap::new();
    module_files(&root, &root, &mut modules);
    let mut graph: BTreeMap<ModPath, BTreeSet<ModPath>> = BTreeMap::new();
    for (m, file) in &modules {
        let is_mod = file.file_name().is_some_and(|n| n == "mod.rs" || n == "lib.rs" || n == "main.rs");
        let code = code_only(&std::fs::read_to_string(file).unwrap());
        let edges = graph.entry(m.clone()).or_default();
        for p in referenced_paths(&code) {
            if let Some(target) = resolve(&p, m, is_mod, &modules) {
                if target != *m && !target.starts_with(m) {
                    edges.insert(target);
                }
            }
        }
    }
    (modules, graph)
}

/// A cycle of `graph`, if any (a path that returns to its first node).
fn find_cycle<N: Ord + Clone>(graph: &BTreeMap<N, BTreeSet<N>>) -> Option<Vec<N>> {
    // Iterative depth-first search with colours: 1 = on the stack, 2 = done.
    let mut colour: BTreeMap<N, u8> = BTreeMap::new();
    for start in graph.keys() {
        if colour.contains_key(start) {
            continue;
        }
        let mut stack: Vec<(N, Vec<N>)> = vec![(start.clone(), graph[start].iter().cloned().collect())];
        colour.insert(start.clone(), 1);
        while let Some((node, todo)) = stack.last_mut() {
            match todo.pop() {
                Some(next) => match colour.get(&next) {
                    Some(1) => {
                        let from = stack.iter().position(|(n, _)| *n == next).unwrap();
                        let mut cycle: Vec<N> = stack[from..].iter().map(|(n, _)| n.clone()).collect();
                        cycle.push(next);
                        return Some(cycle);
                    }
                    Some(_) => {}
                    None => {
                        colour.insert(next.clone(), 1);
                        let children = graph.get(&next).map(|s| s.iter().cloned().collect()).unwrap_or_default();
                        stack.push((next, children));
                    }
                },
                None => {
                    colour.insert(node.clone(), 2);
                    stack.pop();
                }
            }
        }
    }
    None
}

fn show(m: &ModPath) -> String {
    if m.is_empty() {
        "crate".into()
    } else {
        m.join("::")
    }
}

#[test]
fn no_file_imports_a_module_that_imports_it_back() {
    let _timing = crate::support::timed();
    let (modules, graph) = import_graph();
    assert!(modules.len() > 100 && graph.values().map(BTreeSet::len).sum::<usize>() > 300, "the parser sees the imports");
    if let Some(cycle) = find_cycle(&graph) {
        panic!("import cycle between files: {}", cycle.iter().map(show).collect::<Vec<_>>().join(" → "));
    }
}

#[test]
fn top_level_modules_have_one_dependency_direction() {
    let _timing = crate::support::timed();
    let (_, graph) = import_graph();
    let mut top: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for (from, targets) in &graph {
        let Some(a) = from.first() else { continue };
        let edges = top.entry(a.clone()).or_default();
        for t in targets {
            if let Some(b) = t.first().filter(|b| *b != a) {
                edges.insert(b.clone());
            }
        }
    }
    if let Some(cycle) = find_cycle(&top) {
        panic!("import cycle between top-level modules: {}", cycle.join(" → "));
    }
    for low in INFERENCE {
        let reached: Vec<&String> = top.get(low).into_iter().flatten().filter(|b| ABOVE_INFERENCE.contains(&b.as_str())).collect();
        assert!(reached.is_empty(), "`{low}` (on the build's inference path) imports {reached:?}");
    }
    // Spot checks that the graph is read right: edges the code certainly has.
    assert!(top["stages"].contains("inpainting") && top["training"].contains("nn") && top["pipeline"].contains("stages"));
}

#[test]
fn files_under_src_stay_small_or_say_why() {
    let _timing = crate::support::timed();
    let (modules, _) = import_graph();
    let mut long = Vec::new();
    for file in modules.values() {
        let text = std::fs::read_to_string(file).unwrap();
        let lines = text.lines().count();
        let header: String = text.lines().take_while(|l| l.starts_with("//!")).collect::<Vec<_>>().join("\n");
        if lines > MAX_LINES && !header.contains("lines because") {
            long.push(format!("{} ({lines} lines)", file.display()));
        }
    }
    assert!(long.is_empty(), "files over {MAX_LINES} lines without a header line saying why (\"… lines because …\"): {long:?}");
}

#[test]
fn the_checks_themselves_catch_what_they_look_for() {
    let _timing = crate::support::timed();
    // Cycle finding on small graphs.
    let g = |edges: &[(u8, u8)]| {
        let mut m: BTreeMap<u8, BTreeSet<u8>> = BTreeMap::new();
        for (a, b) in edges {
            m.entry(*a).or_default().insert(*b);
            m.entry(*b).or_default();
        }
        m
    };
    assert_eq!(find_cycle(&g(&[(1, 2), (2, 3), (1, 3)])), None);
    let c = find_cycle(&g(&[(1, 2), (2, 3), (3, 4), (4, 2)])).unwrap();
    assert_eq!((c.first(), c.last(), c.len()), (Some(&2), Some(&2), 4), "{c:?}");
    // Comments, strings and char literals hide nothing and invent nothing.
    let code = code_only("use crate::a::{b, c::{d as e}}; // crate::zz\nlet s = \"crate::yy\"; let q = '\"'; x = crate::f::g(1); /* super::w */ fn f<'a>(x: &'a super::h::I) {}");
    let paths: BTreeSet<String> = referenced_paths(&code).iter().map(|p| p.join("::")).collect();
    let want: BTreeSet<String> = ["crate::a", "crate::a::b", "crate::a::c::d", "crate::f::g", "super::h::I"].iter().map(|s| s.to_string()).collect();
    assert_eq!(paths, want);
}
