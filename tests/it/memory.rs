//! The memory rule (issue 23): work whose estimate exceeds the machine's available memory or
//! `--max-memory` is refused before it starts; counts are bounded before any allocation.

use std::path::Path;
use std::process::{Command, Output};

use crate::common::data;

fn run(args: &[&str], cwd: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_splat4d"))
        .args(args)
        .current_dir(cwd)
        .output()
        .unwrap()
}

fn refused(output: &Output, needles: &[&str]) {
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{stderr}");
    for needle in needles {
        assert!(stderr.contains(needle), "{needle:?} in {stderr}");
    }
    assert!(!stderr.contains("panicked"), "{stderr}");
}

#[test]
fn work_above_max_memory_is_refused_before_it_starts() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let blob = data("blob.json");
    let camera = data("blob_camera.json");
    let render = |limit: &str| {
        run(
            &[
                "render",
                "--scene",
                blob.to_str().unwrap(),
                "--camera",
                camera.to_str().unwrap(),
                "--time",
                "0.5",
                "--out",
                "out.png",
                "--max-memory",
                limit,
            ],
            d,
        )
    };
    refused(&render("1K"), &["--max-memory", "render"]);
    assert!(!d.join("out.png").exists());
    assert!(render("1G").status.success());
    refused(&render("lots"), &["--max-memory"]);
}

#[test]
fn kernel_counts_are_bounded_like_fit() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for count in ["10000000", "18446744073709551615", "0"] {
        refused(
            &run(&["report", "--kernels", count, "--out", "r"], d),
            &["--kernels"],
        );
    }
    assert!(!d.join("r").exists());
    refused(
        &run(
            &[
                "fit",
                "--views",
                "ds",
                "--start-kernels",
                "10000000",
                "--out",
                "f.json",
            ],
            d,
        ),
        &["--start-kernels"],
    );
}

/// A 4D PLY whose header claims 5·10⁸ kernels over a sparse 72 GB hole: refused by the
/// memory its scene would need, before any reservation.
#[cfg(unix)]
#[test]
fn a_sparse_ply_does_not_reserve_what_it_claims() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    assert!(
        run(&["toy", "--kind", "blob", "--out", "one.ply"], d)
            .status
            .success()
    );
    let bytes = std::fs::read(d.join("one.ply")).unwrap();
    let text = String::from_utf8_lossy(&bytes);
    let header_end = text.find("end_header\n").unwrap() + "end_header\n".len();
    let stride = (bytes.len() - header_end) as u64;
    let count: u64 = 500_000_000;
    let header =
        text[..header_end].replace("element vertex 1\n", &format!("element vertex {count}\n"));
    let file = std::fs::File::create(d.join("big.ply")).unwrap();
    std::io::Write::write_all(&mut &file, header.as_bytes()).unwrap();
    file.set_len(header.len() as u64 + count * stride).unwrap();
    let camera = data("blob_camera.json");
    let output = run(
        &[
            "render",
            "--scene",
            "big.ply",
            "--camera",
            camera.to_str().unwrap(),
            "--time",
            "0.5",
            "--out",
            "out.png",
            "--max-memory",
            "4G",
        ],
        d,
    );
    refused(&output, &["big.ply", "500000000 kernels", "--max-memory"]);
}

/// `report --size` is checked before the experiment, with advice `report` can follow.
#[test]
fn report_sizes_are_checked_first_with_advice_it_can_follow() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let output = run(&["report", "--size", "16384x1", "--out", "r"], d);
    refused(&output, &["--size 16384x1", "smaller --size"]);
    assert!(!String::from_utf8_lossy(&output.stderr).contains("--no-gif"));
    refused(
        &run(
            &[
                "report",
                "--size",
                "8192x8192",
                "--max-memory",
                "1G",
                "--out",
                "r",
            ],
            d,
        ),
        &["--max-memory"],
    );
    assert!(!d.join("r").exists());
}

/// A fit renders one view of its batch per worker thread at once, each with its own frame
/// buffers, kernel copies and gradients: its estimate grows with `--threads` (up to the
/// batch), so a bound that one thread's fit fits under refuses the same fit on four.
#[test]
fn a_fits_estimate_counts_the_views_it_renders_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let blob = data("blob.json");
    let made = run(
        &[
            "dataset",
            "--scene",
            blob.to_str().unwrap(),
            "--views",
            "2",
            "--times",
            "2",
            "--size",
            "16x16",
            "--out",
            "ds",
        ],
        d,
    );
    assert!(
        made.status.success(),
        "{}",
        String::from_utf8_lossy(&made.stderr)
    );
    // 100 000 kernels: 410 MB on one thread (2 + 2 KiB each), 1 GB on four (2 + 8 KiB).
    let fit = |threads: &str| {
        run(
            &[
                "fit",
                "--views",
                "ds",
                "--blend",
                "additive",
                "--init",
                "random:100000",
                "--steps",
                "1",
                "--threads",
                threads,
                "--max-memory",
                "450M",
                "--out",
                "f.json",
            ],
            d,
        )
    };
    refused(&fit("4"), &["--max-memory", "fitting up to 100000 kernels"]);
    assert!(!d.join("f.json").exists());
    let one = fit("1");
    assert!(
        one.status.success(),
        "{}",
        String::from_utf8_lossy(&one.stderr)
    );
}
