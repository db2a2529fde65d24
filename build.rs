//! Sets `SPLAT4D_VERSION` for `splat4d --version`: the package version, followed by the git
//! revision (`0.1.0 (2b87947)`) when built from a checkout with git on PATH; the package
//! version alone otherwise (a tarball, no git). Reruns when HEAD or the branch it names moves.
//!
//! Also links the `splat4d` binary with packed relative relocations where the toolchain
//! and the C library can ([`pack_relative_relocations`]).

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

/// Links the binaries with `-z pack-relative-relocs` (DT_RELR: the ~8 900 relative
/// relocations of a position-independent binary as a bitmap, 213 KB of `.rela.dyn` down to
/// 2.5 KB of `.relr.dyn`), which the dynamic loader applies faster and with fewer pages
/// read: measured on the VM of `docs/performance.md`, `splat4d --version` 1.19 → 1.10 ms
/// and an empty 512×512 render 2.60 → 2.35 ms (medians of 61, alternating). Only where it
/// works: a Linux GNU target built on itself, whose linker (binutils ≥ 2.38) takes the flag
/// and whose C library (glibc ≥ 2.36) runs the result — a probe program is linked with it
/// and run; otherwise the binaries are linked as before. Address randomisation is kept:
/// the relocations are the same, only stored differently. The trade: a binary so linked
/// needs glibc ≥ 2.36 where it runs (`GLIBC_ABI_DT_RELR`), as the machine that built it
/// has; to copy a build to older systems, build with `SPLAT4D_NO_RELR=1`. Not done when
/// `RUSTFLAGS` choose their own linker, which the probe would not be testing.
fn pack_relative_relocations() {
    let var = |name: &str| std::env::var(name).unwrap_or_default();
    let rustflags = var("CARGO_ENCODED_RUSTFLAGS");
    if var("CARGO_CFG_TARGET_OS") != "linux"
        || var("CARGO_CFG_TARGET_ENV") != "gnu"
        || var("TARGET") != var("HOST")
        || std::env::var_os("SPLAT4D_NO_RELR").is_some()
        || rustflags.contains("linker")
        || rustflags.contains("fuse-ld")
    {
        return;
    }
    let Ok(out) = std::env::var("OUT_DIR") else {
        return;
    };
    let linker = std::env::var("RUSTC_LINKER").unwrap_or_else(|_| "cc".to_string());
    let source = Path::new(&out).join("relr_probe.c");
    let probe = Path::new(&out).join("relr_probe");
    let flag = "-Wl,-z,pack-relative-relocs";
    let works = std::fs::write(&source, "int main(void) { return 0; }\n").is_ok()
        && Command::new(&linker)
            .args(["-pie", "-fPIE", flag, "-o"])
            .arg(&probe)
            .arg(&source)
            .output()
            .is_ok_and(|o| o.status.success())
        && Command::new(&probe)
            .output()
            .is_ok_and(|o| o.status.success());
    if works {
        println!("cargo:rustc-link-arg-bins={flag}");
    }
}

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    for name in ["RUSTC_LINKER", "CARGO_ENCODED_RUSTFLAGS", "SPLAT4D_NO_RELR"] {
        println!("cargo:rerun-if-env-changed={name}");
    }
    pack_relative_relocations();
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
