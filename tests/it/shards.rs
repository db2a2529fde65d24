//! `--shard I/N` and `--assemble`: renders spread over the runs of a batch scheduler's
//! array job give the bytes of one run; bad shards and missing frames are refused.

use std::collections::BTreeMap;
use std::path::Path;

use crate::common::{splat4d, stderr};

/// Every file under `dir` (relative path → bytes); a folder's `.splat4d-output` marker
/// without the stamps of the files beside it (length, time, inode: those of this run).
fn tree(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    let mut files = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(folder) = stack.pop() {
        for entry in std::fs::read_dir(&folder).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                stack.push(path);
                continue;
            }
            let name = path.strip_prefix(dir).unwrap().display().to_string();
            let mut bytes = std::fs::read(&path).unwrap();
            if name.ends_with(".splat4d-output") {
                let text = String::from_utf8(bytes).unwrap();
                let lines: Vec<&str> = text
                    .lines()
                    .map(|l| l.split('\t').next().unwrap())
                    .collect();
                bytes = lines.join("\n").into_bytes();
            }
            files.insert(name, bytes);
        }
    }
    files
}

fn ok(args: &[&str], cwd: &Path) {
    let out = splat4d(args, cwd);
    assert!(out.status.success(), "{args:?}: {}", stderr(&out));
}

/// Runs `command` once into `whole`, and as shards `0/n` … `(n-1)/n` then `--assemble`
/// into `sharded`, and compares every file byte for byte.
fn same_as_one_run(d: &Path, command: &[&str], n: usize) {
    let with = |out: &str, extra: &[&str]| {
        let mut args: Vec<&str> = command.to_vec();
        args.extend(["--out", out]);
        args.extend(extra);
        ok(&args, d);
    };
    with("whole", &[]);
    // In reverse order: no shard counts on another having run first.
    for i in (0..n).rev() {
        with("sharded", &["--shard", &format!("{i}/{n}")]);
    }
    with("sharded", &["--assemble"]);
    let (whole, sharded) = (tree(&d.join("whole")), tree(&d.join("sharded")));
    assert_eq!(
        whole.keys().collect::<Vec<_>>(),
        sharded.keys().collect::<Vec<_>>()
    );
    for (name, bytes) in &whole {
        assert!(bytes == &sharded[name], "{command:?}: {name} differs");
    }
}

#[test]
fn video_export_and_dataset_shards_assemble_to_one_runs_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    ok(&["toy", "--kind", "three-blobs", "--out", "s.json"], d);
    let video = [
        "video", "--scene", "s.json", "--orbit", "--times", "0.2,0.8", "--size", "48x32",
    ];
    same_as_one_run(d, &video, 2);
    std::fs::remove_dir_all(d.join("whole")).unwrap();
    std::fs::remove_dir_all(d.join("sharded")).unwrap();
    same_as_one_run(d, &["export-ply", "--scene", "s.json", "--frames", "7"], 3);
    std::fs::remove_dir_all(d.join("whole")).unwrap();
    std::fs::remove_dir_all(d.join("sharded")).unwrap();
    let dataset = [
        "dataset", "--scene", "s.json", "--views", "5", "--times", "3", "--size", "24x16", "--exr",
    ];
    same_as_one_run(d, &dataset, 4);
}

#[test]
fn assemble_refuses_a_missing_frame_and_shards_keep_each_others_frames() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    ok(&["toy", "--kind", "blob", "--out", "s.json"], d);
    let video = |extra: &[&str]| {
        let mut args = vec![
            "video",
            "--scene",
            "s.json",
            "--orbit=0,0,0,3,20,5",
            "--times",
            "0.5",
            "--size",
            "16x16",
            "--no-mp4",
            "--out",
            "v",
        ];
        args.extend(extra);
        splat4d(&args, d)
    };
    assert!(video(&["--shard", "0/2"]).status.success());
    let missing = video(&["--assemble"]);
    assert_eq!(missing.status.code(), Some(2));
    assert!(
        stderr(&missing).contains("frame_0001.png: missing"),
        "{}",
        stderr(&missing)
    );
    assert!(!d.join("v/orbit_t0.50.gif").exists());
    // Shard 1 leaves shard 0's frames; shard 0 run again leaves shard 1's.
    assert!(video(&["--shard", "1/2"]).status.success());
    assert!(video(&["--shard", "0/2"]).status.success());
    for k in 0..5 {
        assert!(d.join(format!("v/orbit_t0.50/frame_{k:04}.png")).exists());
    }
    // Other settings: the frames are not theirs.
    let other = splat4d(
        &[
            "video",
            "--scene",
            "s.json",
            "--orbit=0,0,0,4,20,5",
            "--times",
            "0.5",
            "--size",
            "16x16",
            "--no-mp4",
            "--out",
            "v",
            "--assemble",
        ],
        d,
    );
    assert_eq!(other.status.code(), Some(2));
    assert!(
        stderr(&other).contains("run of these settings"),
        "{}",
        stderr(&other)
    );
    assert!(video(&["--assemble"]).status.success());
    assert!(d.join("v/orbit_t0.50.gif").exists());
    // A file of the user's in the frame folder: refused before any work.
    std::fs::write(d.join("v/orbit_t0.50/notes.txt"), "mine").unwrap();
    let refused = video(&["--shard", "0/2"]);
    assert_eq!(refused.status.code(), Some(2));
    assert!(
        stderr(&refused).contains("notes.txt"),
        "{}",
        stderr(&refused)
    );
    for bad in ["2/2", "0/0", "1", "x/2"] {
        let out = video(&["--shard", bad]);
        assert_eq!(out.status.code(), Some(2), "{bad}");
        assert!(stderr(&out).contains("--shard"), "{bad}: {}", stderr(&out));
    }
    let one = splat4d(
        &[
            "export-ply",
            "--scene",
            "s.json",
            "--time",
            "0",
            "--out",
            "a.ply",
            "--shard",
            "0/2",
        ],
        d,
    );
    assert_eq!(one.status.code(), Some(2));
    assert!(stderr(&one).contains("--shard"), "{}", stderr(&one));
}
