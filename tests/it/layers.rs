//! The crate's layers (the table in `src/lib.rs`): every `crate::` path in `src/` names a
//! module of the same layer or of one above it, so data flows one way and no change can
//! quietly add a cycle. Unit-test modules (`#[cfg(test)] mod … { … }`) may reach further.

use std::path::Path;

/// Top-level modules, layer by layer; a module may import from its own row and the ones
/// before it.
const LAYERS: &[&[&str]] = &[
    &["model"],
    &["parallel"],
    &["slice"],
    &["project"],
    &["colour"],
    &["tiles"],
    &["simd"],
    &["raster", "composite"],
    &["backward"],
    &["render"],
    &["overlay", "volume"],
    &["reference"],
    &["bench"],
    &["fit"],
    &["scenes"],
    &["io"],
    &["report"],
    &["view"],
    &["tasks"],
];

fn layer_of(module: &str) -> Option<usize> {
    LAYERS.iter().position(|row| row.contains(&module))
}

/// The text without comments and without `#[cfg(test)] mod … { … }` blocks.
fn code_outside_tests(text: &str) -> String {
    let without_comments: String = text
        .lines()
        .map(|l| l.split("//").next().unwrap_or(""))
        .collect::<Vec<_>>()
        .join("\n");
    let mut out = String::new();
    let mut rest = without_comments.as_str();
    while let Some(start) = rest.find("#[cfg(test)]") {
        out.push_str(&rest[..start]);
        let after = &rest[start..];
        let Some(open) = after.find('{') else {
            rest = "";
            break;
        };
        let mut depth = 0;
        let mut end = after.len();
        for (i, c) in after[open..].char_indices() {
            match c {
                '{' => depth += 1,
                '}' => {
                    depth -= 1;
                    if depth == 0 {
                        end = open + i + 1;
                        break;
                    }
                }
                _ => {}
            }
        }
        rest = &after[end..];
    }
    out.push_str(rest);
    out
}

/// The top-level modules a source text names through `crate::X` or `use crate::{X, …}`.
fn imported_modules(code: &str) -> Vec<String> {
    let mut names = Vec::new();
    for (i, _) in code.match_indices("crate::") {
        let after = &code[i + "crate::".len()..];
        if let Some(group) = after.strip_prefix('{') {
            // Top-level parts of the group, split at commas outside nested braces.
            let (mut depth, mut part, mut parts) = (1, String::new(), Vec::new());
            for c in group.chars() {
                match c {
                    '{' => depth += 1,
                    '}' => depth -= 1,
                    ',' if depth == 1 => {
                        parts.push(std::mem::take(&mut part));
                        continue;
                    }
                    _ => {}
                }
                if depth == 0 {
                    break;
                }
                part.push(c);
            }
            parts.push(part);
            for part in parts {
                let word: String = part
                    .trim_start()
                    .chars()
                    .take_while(|c| c.is_alphanumeric() || *c == '_')
                    .collect();
                if !word.is_empty() && word != "self" {
                    names.push(word);
                }
            }
        } else {
            let word: String = after
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_')
                .collect();
            names.push(word);
        }
    }
    names
}

fn sources(dir: &Path, out: &mut Vec<std::path::PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            sources(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

#[test]
fn every_import_goes_to_the_same_layer_or_one_above() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    sources(&src, &mut files);
    let mut violations = Vec::new();
    let mut checked = 0;
    for file in files {
        let relative = file.strip_prefix(&src).unwrap();
        let first = relative
            .components()
            .next()
            .unwrap()
            .as_os_str()
            .to_string_lossy();
        let module = first.trim_end_matches(".rs").to_owned();
        if module == "lib" || module == "main" || module == "cli" {
            continue;
        }
        let own = layer_of(&module)
            .unwrap_or_else(|| panic!("src/{module} is in no layer: add it to LAYERS and lib.rs"));
        let code = code_outside_tests(&std::fs::read_to_string(&file).unwrap());
        for name in imported_modules(&code) {
            if let Some(layer) = layer_of(&name) {
                checked += 1;
                if layer > own {
                    violations.push(format!("{}: {module} imports {name}", relative.display()));
                }
            }
        }
    }
    assert!(
        checked > 100,
        "only {checked} imports found: is the parser broken?"
    );
    assert!(
        violations.is_empty(),
        "imports against the layers:\n{}",
        violations.join("\n")
    );
}

#[test]
fn the_checker_sees_plain_and_grouped_imports() {
    let code = "use crate::model::Scene;\nuse crate::{fit::plan, io::{json, ply}};\n#[cfg(test)]\nmod tests { use crate::tasks::x; }\n";
    let names = imported_modules(&code_outside_tests(code));
    assert_eq!(names, ["model", "fit", "io"]);
}

/// Folders with a known cycle, each being removed elsewhere (none now; the test fails when
/// a listed folder has no cycle left, to say so).
const KNOWN_FOLDER_CYCLES: &[&str] = &[];

/// The modules of folder `dir` (relative to `src/`, `""` for none) that `file` names: through
/// `crate::<dir>::X`, and through `super::X` from a file directly in the folder (not its
/// `mod.rs`, whose `super` is the folder above).
fn sibling_imports(dir: &str, file_in_dir: bool, code: &str) -> Vec<String> {
    let word = |s: &str| -> String {
        s.chars()
            .take_while(|c| c.is_alphanumeric() || *c == '_')
            .collect()
    };
    let mut names = Vec::new();
    let prefix = format!("crate::{}::", dir.replace('/', "::"));
    let mut prefixes = vec![prefix];
    if file_in_dir {
        prefixes.push("super::".to_owned());
    }
    for prefix in &prefixes {
        for (i, _) in code.match_indices(prefix.as_str()) {
            // Not the tail of a longer path (`crate::a::b::` for prefix `b::`).
            if prefix == "super::" && code[..i].ends_with("::") {
                continue;
            }
            let after = &code[i + prefix.len()..];
            if let Some(group) = after.strip_prefix('{') {
                let inner = &group[..group.find('}').unwrap_or(group.len())];
                names.extend(inner.split(',').map(|p| word(p.trim_start())));
            } else {
                names.push(word(after));
            }
        }
    }
    names.retain(|n| !n.is_empty() && n != "self" && n != "super");
    names
}

/// Every cycle (as a path of module names) of the graph `edges`.
fn cycles(
    edges: &std::collections::BTreeMap<String, std::collections::BTreeSet<String>>,
) -> Vec<String> {
    fn visit(
        node: &str,
        edges: &std::collections::BTreeMap<String, std::collections::BTreeSet<String>>,
        path: &mut Vec<String>,
        done: &mut std::collections::BTreeSet<String>,
        found: &mut Vec<String>,
    ) {
        if let Some(at) = path.iter().position(|n| n == node) {
            let mut cycle = path[at..].to_vec();
            cycle.push(node.to_owned());
            found.push(cycle.join(" → "));
            return;
        }
        if done.contains(node) {
            return;
        }
        path.push(node.to_owned());
        for next in edges.get(node).into_iter().flatten() {
            visit(next, edges, path, done, found);
        }
        path.pop();
        done.insert(node.to_owned());
    }
    let (mut done, mut found) = (std::collections::BTreeSet::new(), Vec::new());
    for node in edges.keys() {
        visit(node, edges, &mut Vec::new(), &mut done, &mut found);
    }
    found
}

/// Per folder of `src/` (other than `cli/`, the binary's), the import graph between its
/// files and sub-folders (`mod.rs` counts as the module `mod`).
fn folder_graphs(
    src: &Path,
) -> std::collections::BTreeMap<
    String,
    std::collections::BTreeMap<String, std::collections::BTreeSet<String>>,
> {
    let mut files = Vec::new();
    sources(src, &mut files);
    let mut graphs: std::collections::BTreeMap<
        _,
        std::collections::BTreeMap<_, std::collections::BTreeSet<_>>,
    > = std::collections::BTreeMap::new();
    for file in files {
        let relative = file.strip_prefix(src).unwrap();
        let parts: Vec<String> = relative
            .components()
            .map(|c| {
                c.as_os_str()
                    .to_string_lossy()
                    .trim_end_matches(".rs")
                    .to_owned()
            })
            .collect();
        if parts[0] == "cli" || parts.len() < 2 {
            continue;
        }
        let code = code_outside_tests(&std::fs::read_to_string(&file).unwrap());
        // Every folder the file is inside: the file counts as the folder's module it is in.
        for depth in 1..parts.len() {
            let dir = parts[..depth].join("/");
            let module = parts[depth].clone();
            let file_in_dir = depth == parts.len() - 1 && module != "mod";
            let modules: std::collections::BTreeSet<String> =
                sibling_imports(&dir, file_in_dir, &code)
                    .into_iter()
                    .collect();
            let graph = graphs.entry(dir.clone()).or_default();
            let own = graph.entry(module.clone()).or_default();
            for name in modules {
                if name != module {
                    own.insert(name);
                }
            }
        }
    }
    // Only edges to modules the folder has.
    for graph in graphs.values_mut() {
        let known: std::collections::BTreeSet<String> = graph.keys().cloned().collect();
        for targets in graph.values_mut() {
            targets.retain(|t| known.contains(t));
        }
    }
    graphs
}

#[test]
fn no_folder_has_an_import_cycle_among_its_files() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let graphs = folder_graphs(&src);
    let edges: usize = graphs
        .values()
        .flat_map(|g| g.values())
        .map(|t| t.len())
        .sum();
    assert!(
        edges > 30,
        "only {edges} edges inside folders: is the parser broken?"
    );
    let mut unexpected = Vec::new();
    for (dir, graph) in &graphs {
        let found = cycles(graph);
        let known = KNOWN_FOLDER_CYCLES.contains(&dir.as_str());
        if found.is_empty() && known {
            unexpected.push(format!(
                "{dir}: no cycle left: remove it from KNOWN_FOLDER_CYCLES"
            ));
        } else if !found.is_empty() && !known {
            unexpected.push(format!("{dir}: {}", found.join("; ")));
        }
    }
    assert!(
        unexpected.is_empty(),
        "cycles inside folders:\n{}",
        unexpected.join("\n")
    );
}

#[test]
fn the_folder_checker_sees_siblings_and_finds_cycles() {
    let code = "use super::plan::X;\nuse crate::fit::{train, adam::Y};\nuse crate::io::json;\n";
    assert_eq!(
        sibling_imports("fit", true, code),
        ["train", "adam", "plan"]
    );
    assert_eq!(sibling_imports("fit", false, code), ["train", "adam"]);
    let mut graph = std::collections::BTreeMap::new();
    graph.insert("a".to_owned(), ["b".to_owned()].into());
    graph.insert("b".to_owned(), ["a".to_owned()].into());
    graph.insert("c".to_owned(), ["a".to_owned()].into());
    assert_eq!(cycles(&graph), ["a → b → a"]);
}
