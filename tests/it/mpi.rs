//! `mpirun -n N splat4d fit …` (cargo feature `mpi`, an MPI launcher on `PATH`): the fitted
//! scene is the one-process scene, byte for byte, for 2 and 3 ranks and any thread count
//! (3 ranks on a batch of 2 too, with a note naming the idle rank); rank 0 alone writes; a
//! failing rank stops them all with its message.

use std::path::Path;
use std::process::{Command, Output};

use crate::common::{splat4d, stderr};

/// `mpirun -n ranks splat4d args…` in `cwd` (as root and on fewer cores than ranks, as CI
/// runs it).
fn mpirun(ranks: usize, args: &[&str], cwd: &Path) -> Output {
    Command::new("mpirun")
        .args([
            "-n",
            &ranks.to_string(),
            "--oversubscribe",
            "--allow-run-as-root",
        ])
        .arg(env!("CARGO_BIN_EXE_splat4d"))
        .args(args)
        .current_dir(cwd)
        .output()
        .expect("mpirun runs (Open MPI on PATH)")
}

fn fit_args<'a>(out: &'a str, threads: &'a str, blend: &'a str) -> Vec<&'a str> {
    vec![
        "fit",
        "--views",
        "ds",
        "--out",
        out,
        "--steps",
        "60",
        "--eval-every",
        "20",
        "--blend",
        blend,
        "--threads",
        threads,
        "--log",
        "log.jsonl",
    ]
}

#[test]
fn every_rank_count_fits_the_one_process_scene() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let ok = |out: Output| assert!(out.status.success(), "{}", stderr(&out));
    ok(splat4d(
        &["toy", "--kind", "three-blobs", "--out", "s.json"],
        d,
    ));
    ok(splat4d(
        &[
            "dataset", "--scene", "s.json", "--views", "8", "--times", "3", "--size", "32x32",
            "--out", "ds",
        ],
        d,
    ));
    for blend in ["alpha", "additive"] {
        ok(splat4d(&fit_args("one.json", "2", blend), d));
        let one = std::fs::read(d.join("one.json")).unwrap();
        for (ranks, threads) in [(2, "1"), (3, "2")] {
            let out = mpirun(ranks, &fit_args("spread.json", threads, blend), d);
            ok(out.clone());
            let spread = std::fs::read(d.join("spread.json")).unwrap();
            assert!(
                one == spread,
                "{blend}: {ranks} ranks × {threads} threads differ"
            );
            // Rank 0 alone prints the summary.
            let summary = String::from_utf8_lossy(&out.stdout);
            assert_eq!(summary.matches("kernels fitted").count(), 1, "{summary}");
            std::fs::remove_file(d.join("spread.json")).unwrap();
        }
    }
    // More ranks than views a step: the idle ranks are named in a note, and the scene is
    // the one-process scene still.
    fn batch_of_two(out: &str) -> Vec<&str> {
        let mut args = fit_args(out, "1", "alpha");
        args.extend(["--batch", "2"]);
        args
    }
    ok(splat4d(&batch_of_two("alone.json"), d));
    let out = mpirun(3, &batch_of_two("spread.json"), d);
    ok(out.clone());
    assert!(
        stderr(&out).contains("3 ranks and 2 views a step: 1 rank renders nothing"),
        "{}",
        stderr(&out)
    );
    assert!(
        std::fs::read(d.join("alone.json")).unwrap()
            == std::fs::read(d.join("spread.json")).unwrap()
    );
    // A rank that fails stops all of them, with its message and the exit status.
    std::fs::write(d.join("start.json"), "{").unwrap();
    let mut args = fit_args("bad.json", "1", "alpha");
    args.extend(["--init", "start.json"]);
    let failed = mpirun(2, &args, d);
    assert!(!failed.status.success());
    assert!(
        stderr(&failed).contains("start.json"),
        "{}",
        stderr(&failed)
    );
    assert!(!d.join("bad.json").exists());
}
