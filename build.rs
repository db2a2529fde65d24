//! Sets `SPLAT4D_VERSION` for `splat4d --version`: the package version, followed by the git
//! revision (`0.1.0 (2b87947)`) when built from a checkout with git on PATH; the package
//! version alone otherwise (a tarball, no git). Reruns when HEAD or the branch it names moves.

use std::path::Path;
use std::process::Command;

fn git(args: &[&str]) -> Option<String> {
    let output = Command::new("git").args(args).output().ok()?;
    if !output.status.success() {
        return None;
    }
    let text = String::from_utf8(output.stdout).ok()?;
    let text = text.trim();
    (!text.is_empty()).then(|| text.to_string())
}

/// Asks cargo to rerun this script when `git_path` (a path inside the git directory,
/// resolved by git: worktrees keep HEAD apart from the shared refs) changes; only for files
/// that exist, since a missing one would rerun the script on every build.
fn watch(git_path: &str) {
    if let Some(path) = git(&["rev-parse", "--git-path", git_path])
        && Path::new(&path).exists()
    {
        println!("cargo:rerun-if-changed={path}");
    }
}

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    let package = env!("CARGO_PKG_VERSION");
    let manifest = std::env::var("CARGO_MANIFEST_DIR").unwrap_or_default();
    // Only this repository's own checkout: a tarball unpacked inside another git repository
    // must not report that repository's revision.
    let own_checkout = git(&["rev-parse", "--show-toplevel"])
        .and_then(|top| {
            Some(Path::new(&top).canonicalize().ok()? == Path::new(&manifest).canonicalize().ok()?)
        })
        .unwrap_or(false);
    let revision = if own_checkout {
        git(&["rev-parse", "--short", "HEAD"])
    } else {
        None
    };
    let version = match revision {
        Some(revision) => {
            watch("HEAD");
            if let Some(reference) = git(&["symbolic-ref", "-q", "HEAD"]) {
                watch(&reference);
            }
            watch("packed-refs");
            format!("{package} ({revision})")
        }
        None => package.to_string(),
    };
    println!("cargo:rustc-env=SPLAT4D_VERSION={version}");
}
