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
    &["raster"],
    &["composite"],
    &["backward"],
    &["render"],
    &["overlay", "volume"],
    &["reference"],
    &["fit"],
    &["scenes"],
    &["io"],
    &["report"],
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
