//! Every command of `tests/data/recorded/commands.txt` writes the same bytes, file for file,
//! as the code did before the layered move (issue 15): renders, gradients, datasets, fits,
//! imports, exports, volumes and videos. The outputs were recorded by
//! `tests/data/recorded/record.sh` with the release binary before any code moved; outputs
//! re-recorded since for a deliberate change are listed in `tests/data/README.md`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// Every file under `dir`, by its path relative to `dir`.
fn files(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                stack.push(path);
            } else {
                let bytes = std::fs::read(&path).unwrap();
                out.insert(path.strip_prefix(dir).unwrap().to_path_buf(), bytes);
            }
        }
    }
    out
}

#[test]
fn every_recorded_command_writes_the_same_bytes() {
    let out = tempfile::tempdir().unwrap();
    let commands =
        std::fs::read_to_string(root().join("tests/data/recorded/commands.txt")).unwrap();
    let mut ran = 0;
    for line in commands
        .lines()
        .filter(|l| !l.is_empty() && !l.starts_with('#'))
    {
        let args: Vec<String> = line
            .split_whitespace()
            .map(|a| {
                a.replace("$IN", &root().join("tests/data").display().to_string())
                    .replace("$DATA", &root().join("data").display().to_string())
                    .replace("$OUT", &out.path().display().to_string())
            })
            .collect();
        let output = Command::new(env!("CARGO_BIN_EXE_splat4d"))
            .args(&args)
            .output()
            .unwrap();
        assert!(
            output.status.success(),
            "{line}: {}",
            String::from_utf8_lossy(&output.stderr)
        );
        ran += 1;
    }
    assert!(ran >= 15, "only {ran} commands");
    let expected = files(&root().join("tests/data/recorded/outputs"));
    // The output markers (issue 23) name the command and list the files; they are not
    // renders, and the files they list are compared below.
    let mut written = files(out.path());
    let markers = written.len();
    written.retain(|name, _| !name.ends_with(".splat4d-output"));
    assert_eq!(
        markers - written.len(),
        4,
        "the two datasets and the two video folders carry a marker"
    );
    assert_eq!(
        written.keys().collect::<Vec<_>>(),
        expected.keys().collect::<Vec<_>>(),
        "the same files"
    );
    let differing: Vec<_> = expected
        .iter()
        .filter(|(name, bytes)| written[*name] != **bytes)
        .map(|(name, _)| name.display().to_string())
        .collect();
    assert!(differing.is_empty(), "outputs changed: {differing:?}");
}
