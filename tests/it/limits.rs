//! Hostile flags and files, each reproduced from bytes or flags through the executable (the
//! defects were found by a fuzzing round; see the README's reliability section): every one
//! ends quickly with a message and exit status 2 (4 for a computation that leaves the
//! finite numbers), never a panic (101), a hang or an unbounded allocation.

use std::path::Path;
use std::process::{Command, Output};
use std::time::{Duration, Instant};

use crate::common::data;

/// Runs the executable with a time limit (a hang is a failure, not a stuck test).
fn run<S: AsRef<std::ffi::OsStr> + std::fmt::Debug>(args: &[S], cwd: &Path) -> Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_splat4d"))
        .args(args)
        .current_dir(cwd)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if start.elapsed() > Duration::from_secs(20) {
            child.kill().unwrap();
            panic!("{args:?} ran for more than 20 s");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    child.wait_with_output().unwrap()
}

/// Runs `splat4d dataset` on the blob (`views` cameras × 2 times, 8×8) into `dir/out`.
fn run_blob_dataset(dir: &Path, views: &str, out: &str) -> std::process::Output {
    let blob = data("blob.json");
    let args = [
        "dataset",
        "--scene",
        blob.to_str().unwrap(),
        "--views",
        views,
        "--times",
        "2",
        "--size",
        "8x8",
        "--out",
        out,
    ];
    run(&args, dir)
}

/// Renders the blob as a small dataset (`views` cameras × 2 times, 8×8) into `dir/ds`.
fn blob_dataset(dir: &Path, views: &str) {
    let output = run_blob_dataset(dir, views, "ds");
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
}

fn refused<S: AsRef<std::ffi::OsStr> + std::fmt::Debug>(
    args: &[S],
    cwd: &Path,
    code: i32,
    needle: &str,
) {
    let output = run(args, cwd);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(code), "{args:?}: {stderr}");
    assert!(stderr.contains(needle), "{args:?}: {stderr}");
    assert!(!stderr.contains("panicked"), "{args:?}: {stderr}");
}

#[test]
fn extreme_counts_and_sizes_are_refused_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let blob = data("blob.json");
    let blob = blob.to_str().unwrap();
    let dataset = |extra: &[&'static str]| -> Vec<String> {
        let mut args = vec!["dataset", "--scene", blob, "--out", "ds"];
        args.extend_from_slice(extra);
        args.into_iter().map(String::from).collect()
    };
    let huge = "18446744073709551615";
    refused(
        &dataset(&["--views", huge, "--times", "2", "--size", "8x8"]),
        d,
        2,
        "--views",
    );
    refused(
        &dataset(&["--views", "2", "--times", huge, "--size", "8x8"]),
        d,
        2,
        "--times",
    );
    // Found by the second fuzzing round: a random start's count allocated unchecked.
    let views = tempfile::tempdir().unwrap();
    blob_dataset(views.path(), "2");
    let init = format!("random:{huge}");
    refused(
        &["fit", "--views", "ds", "--init", &init, "--out", "f.json"],
        views.path(),
        2,
        "--init",
    );
    refused(
        &[
            "fit",
            "--views",
            "ds",
            "--start-kernels",
            huge,
            "--out",
            "f.json",
        ],
        views.path(),
        2,
        "--start-kernels",
    );
    for fov in ["0", "180", "nan"] {
        let args = dataset(&[
            "--views", "2", "--times", "2", "--size", "8x8", "--fov", fov,
        ]);
        refused(&args, d, 2, "fov");
    }
    refused(
        &dataset(&["--views", "2", "--times", "2", "--size", "16385x16385"]),
        d,
        2,
        "--size",
    );
    refused(
        &dataset(&[
            "--views",
            "2",
            "--times",
            "2",
            "--size",
            "8x8",
            "--time-range=-1e308,1e308",
        ]),
        d,
        2,
        "time range",
    );
    assert!(!d.join("ds").exists(), "nothing written");
    let gltf = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/gltf/Box.gltf");
    let args = [
        "import-gltf",
        gltf.to_str().unwrap(),
        "--kernels",
        huge,
        "--out",
        "m.json",
    ];
    refused(&args, d, 2, "--kernels");
    let camera = data("blob_camera.json");
    let render = [
        "render",
        "--scene",
        blob,
        "--camera",
        camera.to_str().unwrap(),
        "--time",
        "0.5",
        "--out",
        "r.png",
        "--threads",
        "65535",
    ];
    refused(&render, d, 2, "--threads");
}

#[test]
fn non_finite_flags_are_refused_when_read() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    blob_dataset(d, "4");
    for flag in [
        "--lr-mean=nan",
        "--lr-final=-inf",
        "--merge-tolerance=nan",
        "--prune-below=inf",
        "--init-amplitude=nan",
    ] {
        refused(
            &[
                "fit", "--views", "ds", "--steps", "3", "--out", "f.json", flag,
            ],
            d,
            2,
            "not finite",
        );
    }
    refused(
        &[
            "fit",
            "--views",
            "ds",
            "--steps",
            "3",
            "--out",
            "f.json",
            "--lr-mean=-1",
        ],
        d,
        2,
        "--lr-mean",
    );
    refused(
        &[
            "fit",
            "--views",
            "ds",
            "--init",
            "random:3",
            "--box=-1e308,-1e308,-1e308,1e308,1e308,1e308",
            "--steps",
            "3",
            "--out",
            "f.json",
        ],
        d,
        2,
        "box",
    );
    assert!(!d.join("f.json").exists());
}

#[test]
fn values_too_large_to_evaluate_are_a_numeric_error() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(
        d.join("huge.json"),
        r#"{"kernels": [{"mean": [0, 0, 0, 0.5], "scale": [0.1, 0.1, 0.1, 1], "amplitude": [1e300, 1, 1]}]}"#,
    )
    .unwrap();
    refused(
        &[
            "volume",
            "--scene",
            "huge.json",
            "--res",
            "8",
            "--times",
            "0.5",
            "--out",
            "v",
        ],
        d,
        4,
        "not finite",
    );
    assert!(!d.join("v").exists(), "no figure written");
}

#[test]
fn images_are_checked_by_their_header_and_their_pixels() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let blob = data("blob.json");
    let camera = data("blob_camera.json");
    let grad = |target: &str| {
        vec![
            "grad".to_owned(),
            "--scene".into(),
            blob.display().to_string(),
            "--camera".into(),
            camera.display().to_string(),
            "--time".into(),
            "0.5".into(),
            "--target".into(),
            target.into(),
            "--out".into(),
            "g.json".into(),
        ]
    };
    // A PNG header declaring 20000 × 20000 pixels: refused from the header, nothing decoded.
    let mut png = Vec::new();
    png.extend_from_slice(&[0x89, b'P', b'N', b'G', 0x0d, 0x0a, 0x1a, 0x0a]);
    let mut ihdr = b"IHDR".to_vec();
    ihdr.extend_from_slice(&20000u32.to_be_bytes());
    ihdr.extend_from_slice(&20000u32.to_be_bytes());
    ihdr.extend_from_slice(&[8, 0, 0, 0, 0]);
    png.extend_from_slice(&13u32.to_be_bytes());
    png.extend_from_slice(&ihdr);
    png.extend_from_slice(&crc32(&ihdr).to_be_bytes());
    for (kind, body) in [
        (&b"IDAT"[..], &[0x78, 0x9c, 0x03, 0x00][..]),
        (&b"IEND"[..], &[][..]),
    ] {
        let mut chunk = kind.to_vec();
        chunk.extend_from_slice(body);
        png.extend_from_slice(&(body.len() as u32).to_be_bytes());
        png.extend_from_slice(&chunk);
        png.extend_from_slice(&crc32(&chunk).to_be_bytes());
    }
    std::fs::write(d.join("big.png"), &png).unwrap();
    let args = grad("big.png");
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    refused(&args, d, 2, "20000×20000");
    // A float image with a NaN: refused naming the pixel.
    let mut pixels = vec![0.25_f32; 320 * 240 * 3];
    pixels[3 * (7 * 320 + 5)] = f32::NAN;
    let image = image::Rgb32FImage::from_raw(320, 240, pixels).unwrap();
    image::DynamicImage::ImageRgb32F(image)
        .save(d.join("nan.exr"))
        .unwrap();
    let args = grad("nan.exr");
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    refused(&args, d, 2, "pixel (5, 7)");
    assert!(!d.join("g.json").exists());
}

/// CRC-32 (ISO-HDLC) of PNG chunks.
fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = 0xffff_ffff_u32;
    for &b in bytes {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = if crc & 1 == 1 {
                (crc >> 1) ^ 0xedb8_8320
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

/// A change to a glTF document.
type Mutation = Box<dyn Fn(&mut serde_json::Value)>;

#[test]
fn gltf_files_that_break_the_crates_walkers_are_refused_with_their_json_path() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let source = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/gltf/BoxAnimated.gltf");
    let original: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(source).unwrap()).unwrap();
    let cases: Vec<(&str, Mutation, &str)> = vec![
        (
            "cycle",
            Box::new(|g| g["nodes"][0]["children"] = serde_json::json!([1, 0])),
            "nodes[0]",
        ),
        (
            "two parents",
            Box::new(|g| g["nodes"][3]["children"] = serde_json::json!([2])),
            "two parents",
        ),
        (
            "root and child",
            Box::new(|g| g["nodes"][1]["children"] = serde_json::json!([2, 3])),
            "a root of the scene",
        ),
        (
            "dangling channel",
            Box::new(|g| {
                g["animations"][0]["channels"][0]["target"]["node"] = serde_json::json!(99)
            }),
            "target.node",
        ),
        (
            "camera without object",
            Box::new(|g| g["cameras"] = serde_json::json!([{"type": "perspective"}])),
            "cameras[0]",
        ),
        (
            "no accessors",
            Box::new(|g| g["accessors"] = serde_json::json!([])),
            "out of range",
        ),
        (
            "float indices",
            Box::new(|g| {
                let i = g["meshes"][0]["primitives"][0]["indices"].as_u64().unwrap() as usize;
                g["accessors"][i]["componentType"] = serde_json::json!(5126);
            }),
            "indices",
        ),
        (
            "small stride",
            Box::new(|g| {
                let a = g["meshes"][0]["primitives"][0]["attributes"]["POSITION"]
                    .as_u64()
                    .unwrap() as usize;
                let v = g["accessors"][a]["bufferView"].as_u64().unwrap() as usize;
                g["bufferViews"][v]["byteStride"] = serde_json::json!(4);
            }),
            "byteStride",
        ),
        (
            "huge count",
            Box::new(|g| g["accessors"][0]["count"] = serde_json::json!(1_000_000_000u64)),
            "accessors[0]",
        ),
        (
            "view past its buffer",
            Box::new(|g| g["bufferViews"][0]["byteLength"] = serde_json::json!(100_000_000u64)),
            "bufferViews[0]",
        ),
        (
            "dangling material",
            Box::new(|g| g["meshes"][0]["primitives"][0]["material"] = serde_json::json!(99)),
            "material",
        ),
        (
            "dangling skin",
            Box::new(|g| g["nodes"][2]["skin"] = serde_json::json!(99)),
            "skin",
        ),
    ];
    for (name, mutate, needle) in cases {
        let mut gltf = original.clone();
        mutate(&mut gltf);
        let path = d.join(format!("{}.gltf", name.replace(' ', "_")));
        std::fs::write(&path, gltf.to_string()).unwrap();
        let file = path.to_str().unwrap();
        let output = run(
            &[
                "import-gltf",
                file,
                "--kernels",
                "50",
                "--times",
                "3",
                "--out",
                "m.json",
            ],
            d,
        );
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(2), "{name}: {stderr}");
        assert!(stderr.contains(needle), "{name}: {stderr}");
        let camera = format!("{file}#0");
        let render = [
            "render",
            "--scene",
            "m.json",
            "--camera-from",
            &camera,
            "--time",
            "0",
            "--out",
            "r.png",
        ];
        let output = run(&render, d);
        assert_ne!(
            output.status.code(),
            Some(101),
            "{name}: {}",
            String::from_utf8_lossy(&output.stderr)
        );
    }
    assert!(!d.join("m.json").exists());
}

#[test]
fn outputs_are_checked_before_the_work_and_never_replace_an_input() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let blob = data("blob.json");
    let camera = data("blob_camera.json");
    std::fs::copy(&blob, d.join("s.json")).unwrap();
    let ok = run(
        &[
            "dataset", "--scene", "s.json", "--views", "4", "--times", "2", "--size", "8x8",
            "--out", "ds",
        ],
        d,
    );
    assert!(ok.status.success());
    let before = std::fs::read(d.join("ds/transforms_train.json")).unwrap();
    // A fit aimed at its dataset, at its start, or at an unwritable place: refused at once.
    refused(
        &["fit", "--views", "ds", "--out", "ds/transforms_train.json"],
        d,
        2,
        "input",
    );
    refused(
        &[
            "fit", "--views", "ds", "--init", "s.json", "--out", "s.json",
        ],
        d,
        2,
        "input",
    );
    std::fs::write(d.join("file"), "x").unwrap();
    refused(
        &["fit", "--views", "ds", "--out", "file/f.json"],
        d,
        3,
        "file/f.json",
    );
    refused(
        &[
            "fit",
            "--views",
            "ds",
            "--out",
            "f.json",
            "--log",
            "file/log.jsonl",
        ],
        d,
        3,
        "log.jsonl",
    );
    refused(
        &["fit", "--views", "ds", "--out", "f.txt"],
        d,
        2,
        ".json or .ply",
    );
    assert_eq!(
        std::fs::read(d.join("ds/transforms_train.json")).unwrap(),
        before
    );
    // grad writes JSON, never over its target; export-ply never over its scene.
    let png = d.join("ds/train/r_000.png");
    let grad = [
        "grad",
        "--scene",
        "s.json",
        "--camera",
        camera.to_str().unwrap(),
        "--time",
        "0.5",
        "--target",
        png.to_str().unwrap(),
        "--out",
        png.to_str().unwrap(),
    ];
    refused(&grad, d, 2, ".json");
    let ply = run(&["toy", "--kind", "blob", "--out", "scene.ply"], d);
    assert!(ply.status.success());
    let before = std::fs::read(d.join("scene.ply")).unwrap();
    refused(
        &[
            "export-ply",
            "--scene",
            "scene.ply",
            "--time",
            "0.5",
            "--out",
            "scene.ply",
        ],
        d,
        2,
        "input",
    );
    assert_eq!(
        std::fs::read(d.join("scene.ply")).unwrap(),
        before,
        "the 4D scene is intact"
    );
    let gltf = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/gltf/Box.gltf");
    std::fs::copy(&gltf, d.join("m.gltf")).unwrap();
    refused(
        &["import-gltf", "m.gltf", "--out", "m.gltf"],
        d,
        2,
        ".json or .ply",
    );
}

#[test]
fn gltf_buffers_are_read_only_from_regular_files_beside_the_model() {
    use base64::Engine as _;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let source = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/gltf/Box.gltf");
    let original: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(source).unwrap()).unwrap();
    // The embedded buffer as a file beside the model: read as before.
    let uri = original["buffers"][0]["uri"].as_str().unwrap().to_owned();
    let payload = base64::engine::general_purpose::STANDARD
        .decode(uri.split_once(',').unwrap().1)
        .unwrap();
    std::fs::create_dir(d.join("models")).unwrap();
    std::fs::write(d.join("models/box.bin"), &payload).unwrap();
    let with_uri = |uri: &str| {
        let mut gltf = original.clone();
        gltf["buffers"][0]["uri"] = serde_json::json!(uri);
        std::fs::write(d.join("models/m.gltf"), gltf.to_string()).unwrap();
        run(
            &[
                "import-gltf",
                "models/m.gltf",
                "--kernels",
                "20",
                "--out",
                "m.json",
            ],
            d,
        )
    };
    let output = with_uri("box.bin");
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    std::fs::remove_file(d.join("m.json")).unwrap();
    #[cfg(unix)]
    assert!(
        Command::new("mkfifo")
            .arg(d.join("models/pipe"))
            .status()
            .unwrap()
            .success()
    );
    // A symlink beside the model to a file outside it (a real path check, not a lexical one).
    std::fs::write(d.join("secret.bin"), &payload).unwrap();
    #[cfg(unix)]
    std::os::unix::fs::symlink(d.join("secret.bin"), d.join("models/link.bin")).unwrap();
    for (uri, needle) in [
        ("/etc/passwd", "absolute"),
        ("../../../../etc/passwd", "leaves the model's folder"),
        ("%2e%2e/%2e%2e/etc/passwd", "leaves the model's folder"),
        ("/dev/zero", "absolute"),
        ("sub/../../x.bin", "leaves the model's folder"),
        ("pipe", "not a regular file"),
        (".", "not a regular file"),
        ("link.bin", "outside the model's folder"),
    ] {
        let output = with_uri(uri);
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(2), "{uri}: {stderr}");
        assert!(
            stderr.contains(needle) && stderr.contains("buffer 0"),
            "{uri}: {stderr}"
        );
    }
    assert!(!d.join("m.json").exists());
}

#[test]
fn messages_stay_short_and_a_byte_order_mark_is_accepted() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let camera = data("blob_camera.json");
    let camera = camera.to_str().unwrap();
    let blob = std::fs::read_to_string(data("blob.json")).unwrap();
    std::fs::write(d.join("bom.json"), format!("\u{feff}{blob}")).unwrap();
    let render = [
        "render", "--scene", "bom.json", "--camera", camera, "--time", "0.5", "--out", "r.png",
    ];
    let output = run(&render, d);
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    // A 10 MB string where a number belongs: the message quotes a few hundred characters.
    let long = "x".repeat(10_000_000);
    std::fs::write(
        d.join("long.json"),
        format!(r#"{{"kernels": [{{"mean": "{long}", "scale": [1, 1, 1, 1], "amplitude": [1, 1, 1]}}]}}"#),
    )
    .unwrap();
    let render = [
        "render",
        "--scene",
        "long.json",
        "--camera",
        camera,
        "--time",
        "0.5",
        "--out",
        "l.png",
    ];
    let output = run(&render, d);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(2));
    assert!(
        stderr.len() < 1000 && stderr.contains("kernel 0"),
        "{} bytes: {}",
        stderr.len(),
        &stderr[..200.min(stderr.len())]
    );
    // A PLY of another format version names the one it reads.
    std::fs::write(
        d.join("v2.ply"),
        "ply\nformat binary_little_endian 2.0\nend_header\n",
    )
    .unwrap();
    let render = [
        "render", "--scene", "v2.ply", "--camera", camera, "--time", "0.5", "--out", "p.png",
    ];
    refused(&render, d, 2, "only `binary_little_endian 1.0`");
}

#[test]
fn a_dataset_appears_whole_and_replaces_only_a_dataset() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let blob = data("blob.json");
    let dataset = |views: &str, out: &str| run_blob_dataset(d, views, out);
    assert!(dataset("6", "ds").status.success());
    let count = |split: &str| std::fs::read_dir(d.join("ds").join(split)).unwrap().count();
    assert_eq!(count("train"), 12);
    // Again with fewer views: the new dataset replaces the old one whole (no stale frames).
    assert!(dataset("4", "ds").status.success());
    assert_eq!(count("train"), 8);
    // Nothing else left beside it: no temporary folder, no old copy.
    let names: Vec<String> = std::fs::read_dir(d)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names, ["ds"]);
    // A folder that is not a dataset is never replaced.
    std::fs::create_dir(d.join("photos")).unwrap();
    std::fs::write(d.join("photos/keep.txt"), "mine").unwrap();
    refused(
        &[
            "dataset",
            "--scene",
            blob.to_str().unwrap(),
            "--views",
            "2",
            "--times",
            "2",
            "--size",
            "8x8",
            "--out",
            "photos",
        ],
        d,
        2,
        "was not written by `splat4d dataset`",
    );
    assert_eq!(
        std::fs::read_to_string(d.join("photos/keep.txt")).unwrap(),
        "mine"
    );
}

#[test]
fn video_frames_replace_an_older_video_whole_and_oversized_gifs_are_refused_first() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let blob = data("blob.json");
    let video = |orbit: &str, size: &str| {
        let orbit = format!("--orbit={orbit}");
        run(
            &[
                "video",
                "--scene",
                blob.to_str().unwrap(),
                &orbit,
                "--times",
                "0.5",
                "--size",
                size,
                "--no-mp4",
                "--out",
                "v",
            ],
            d,
        )
    };
    assert!(video("0.5,0.5,0.5,3,20,6", "16x12").status.success());
    assert!(video("0.5,0.5,0.5,3,20,3", "16x12").status.success());
    let frames = std::fs::read_dir(d.join("v/orbit_t0.50")).unwrap().count();
    assert_eq!(
        frames, 4,
        "no stale frames from the longer video (3 and the marker)"
    );
    let names: Vec<String> = std::fs::read_dir(d.join("v"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(
        names.iter().all(|n| !n.starts_with(".splat4d")),
        "{names:?}"
    );
    // A GIF cannot hold a frame wider than 65 535 pixels: refused before any frame is kept.
    let output = video("0.5,0.5,0.5,3,20,2", "70000x1");
    assert_eq!(
        output.status.code(),
        Some(2),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    assert!(String::from_utf8_lossy(&output.stderr).contains("--no-gif"));
    assert_eq!(
        std::fs::read_dir(d.join("v/orbit_t0.50")).unwrap().count(),
        4,
        "the old video is intact"
    );
    // A folder of other files is never replaced.
    std::fs::create_dir_all(d.join("w/orbit_t0.50")).unwrap();
    std::fs::write(d.join("w/orbit_t0.50/notes.txt"), "mine").unwrap();
    let output = run(
        &[
            "video",
            "--scene",
            blob.to_str().unwrap(),
            "--orbit=0.5,0.5,0.5,3,20,2",
            "--times",
            "0.5",
            "--size",
            "8x8",
            "--no-mp4",
            "--out",
            "w",
        ],
        d,
    );
    assert_eq!(output.status.code(), Some(2));
    assert!(d.join("w/orbit_t0.50/notes.txt").exists());
}

#[cfg(target_os = "linux")]
#[test]
fn leftovers_of_killed_runs_are_removed_and_live_ones_kept() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // A run that was killed (no process 999999999 can exist: Linux pids stop at 2^22) and
    // a run still going (this test's own process).
    std::fs::write(d.join(".splat4d-999999999-a1b2c3"), vec![0u8; 1000]).unwrap();
    std::fs::create_dir(d.join(".splat4d-999999999-dataset-x")).unwrap();
    let live = format!(".splat4d-{}-d4e5f6", std::process::id());
    std::fs::write(d.join(&live), "in progress").unwrap();
    std::fs::write(d.join(".splat4d-notes"), "not ours to judge").unwrap();
    let (blob, camera) = (data("blob.json"), data("blob_camera.json"));
    let render = [
        "render",
        "--scene",
        blob.to_str().unwrap(),
        "--camera",
        camera.to_str().unwrap(),
        "--time",
        "0.5",
        "--out",
        "r.png",
    ];
    assert!(run(&render, d).status.success());
    let mut names: Vec<String> = std::fs::read_dir(d)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    let mut expected = vec![".splat4d-notes".to_owned(), live, "r.png".to_owned()];
    expected.sort();
    assert_eq!(names, expected);
}

/// Unmounts a tmpfs when dropped, also when the test fails.
struct Mounted(std::path::PathBuf);

impl Drop for Mounted {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg(&self.0).status();
    }
}

/// A real full disk: a 64 KiB tmpfs, nearly filled, takes a 512×512 EXR. The encoder used
/// to hide the OS error ("Format error decoding OpenExr"); now the message says "disk full",
/// the exit status is 3 (output) and nothing but the filler is left. Mounting needs root:
/// elsewhere the test says so and checks nothing (the unit test
/// `io::tests::a_full_disk_under_an_encoder_is_reported_as_a_full_disk` covers the message
/// on every machine).
#[test]
fn a_full_disk_says_so_and_leaves_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let disk = tmp.path().join("disk");
    std::fs::create_dir(&disk).unwrap();
    let mounted = Command::new("mount")
        .args(["-t", "tmpfs", "-o", "size=64k", "tmpfs"])
        .arg(&disk)
        .stderr(std::process::Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    if !mounted {
        eprintln!("cannot mount a tmpfs here (not root?): the full-disk run is skipped");
        return;
    }
    let _unmount = Mounted(disk.clone());
    std::fs::write(disk.join("filler"), vec![0_u8; 44 * 1024]).unwrap();
    let mut camera: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(data("blob_camera.json")).unwrap()).unwrap();
    camera["width"] = serde_json::json!(512);
    camera["height"] = serde_json::json!(512);
    let camera_path = tmp.path().join("camera.json");
    std::fs::write(&camera_path, camera.to_string()).unwrap();
    let scene = data("blob.json");
    for out in ["a.exr", "a.png"] {
        let output = run(
            &[
                "render".as_ref(),
                "--scene".as_ref(),
                scene.as_os_str(),
                "--camera".as_ref(),
                camera_path.as_os_str(),
                "--time".as_ref(),
                "0.5".as_ref(),
                "--out".as_ref(),
                disk.join(out).as_os_str(),
            ],
            tmp.path(),
        );
        let stderr = String::from_utf8_lossy(&output.stderr);
        if output.status.success() {
            // A PNG of a smooth blob may fit in what is left; then it must be whole.
            assert!(std::fs::metadata(disk.join(out)).unwrap().len() > 0);
            std::fs::remove_file(disk.join(out)).unwrap();
            continue;
        }
        assert_eq!(output.status.code(), Some(3), "{out}: {stderr}");
        assert!(stderr.contains("disk full"), "{out}: {stderr}");
        let left: Vec<_> = std::fs::read_dir(&disk)
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(left, ["filler"], "{out}");
    }
}

/// Seeded fuzzing of flag values through the executable: every subcommand that reads files
/// gets one or two of its flags set to extreme or malformed values (zero, negative, huge,
/// non-finite, subnormal, empty, wrong shape). Each run must end within the time limit with
/// exit status 0, 2, 3 or 4 — never a panic (101) or a signal — and a run that succeeds must
/// leave its output.
#[test]
fn extreme_flag_values_end_in_a_result_or_a_clear_refusal() {
    use rand::RngExt;
    // A longer round (3000 runs, seed 80) found `--init random:18446744073709551615`.
    const RUNS: usize = 300;
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    blob_dataset(d, "2");
    let scene = data("blob.json").display().to_string();
    let camera = data("blob_camera.json").display().to_string();
    let gltf = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/gltf/BoxAnimated.gltf")
        .display()
        .to_string();
    // (arguments of a run that works, the flags to set, the output it writes)
    let commands: Vec<(Vec<String>, &[&str], &str)> = vec![
        (
            vec![
                "render".into(),
                "--scene".into(),
                scene.clone(),
                "--camera".into(),
                camera.clone(),
                "--time".into(),
                "0.5".into(),
            ],
            &[
                "--time",
                "--dilation",
                "--cutoff",
                "--threads",
                "--bit-depth",
                "--exp",
            ],
            "out.png",
        ),
        (
            vec![
                "dataset".into(),
                "--scene".into(),
                scene.clone(),
                "--views".into(),
                "2".into(),
                "--times".into(),
                "2".into(),
                "--size".into(),
                "8x8".into(),
            ],
            &[
                "--views",
                "--times",
                "--size",
                "--seed",
                "--time-range",
                "--fov",
                "--dilation",
                "--cutoff",
            ],
            "out_ds",
        ),
        (
            vec![
                "video".into(),
                "--scene".into(),
                scene.clone(),
                "--size".into(),
                "16x16".into(),
                "--no-mp4".into(),
                "--times".into(),
                "0.5".into(),
            ],
            &[
                "--times",
                "--time-range",
                "--size",
                "--fov",
                "--fps",
                "--up",
                "--orbit",
                "--spiral",
                "--cutoff",
            ],
            "out_video",
        ),
        (
            vec![
                "volume".into(),
                "--scene".into(),
                scene.clone(),
                "--res".into(),
                "8".into(),
                "--times".into(),
                "0.5".into(),
            ],
            &["--res", "--times", "--cutoff"],
            "out_volume",
        ),
        (
            vec![
                "import-gltf".into(),
                gltf.clone(),
                "--kernels".into(),
                "50".into(),
                "--times".into(),
                "3".into(),
            ],
            &["--kernels", "--times", "--seed"],
            "out_import.json",
        ),
        (
            vec![
                "export-ply".into(),
                "--scene".into(),
                scene.clone(),
                "--time".into(),
                "0.5".into(),
            ],
            &["--time", "--cutoff", "--sh-rest"],
            "out.ply",
        ),
        (
            vec![
                "fit".into(),
                "--views".into(),
                "ds".into(),
                "--steps".into(),
                "5".into(),
            ],
            &[
                "--lr-mean",
                "--lr-final",
                "--batch",
                "--downscale",
                "--max-kernels",
                "--start-kernels",
                "--init-amplitude",
                "--prune-below",
                "--merge-tolerance",
                "--background",
                "--box",
                "--time-range",
                "--eval-every",
                "--densify-every",
                "--init",
            ],
            "out_fit.json",
        ),
    ];
    let values = [
        "0",
        "-1",
        "1e308",
        "-1e308",
        "nan",
        "inf",
        "-inf",
        "18446744073709551615",
        "4294967297",
        "1e-310",
        "",
        "65535",
        "abc",
        "0x0",
        "1,2",
        ",,,",
        "16385x16385",
        "-0",
        "random:0",
        "random:18446744073709551615",
        "1,1,1,1,1,1",
        "1e300,1e300",
        "x",
        "-1x5",
    ];
    let mut rng = splat4d::model::random::seeded_rng(8);
    let mut outcomes = [0_usize; 5];
    for run_index in 0..RUNS {
        let (base, flags, out) = &commands[rng.random_range(0..commands.len())];
        let mut args = base.clone();
        for _ in 0..rng.random_range(1..3) {
            args.push(flags[rng.random_range(0..flags.len())].to_string());
            args.push(values[rng.random_range(0..values.len())].to_string());
        }
        let out = d.join(format!("{run_index}_{out}"));
        args.push("--out".into());
        args.push(out.display().to_string());
        let output = run(&args, d);
        let code = output.status.code();
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(
            matches!(code, Some(0 | 2 | 3 | 4)),
            "{args:?}: status {:?}\n{stderr}",
            output.status
        );
        if code == Some(0) {
            assert!(
                out.exists(),
                "{args:?} succeeded without writing {}",
                out.display()
            );
        } else {
            assert!(stderr.contains("error"), "{args:?}: {stderr}");
        }
        outcomes[code.unwrap() as usize] += 1;
    }
    println!("extreme flags: {RUNS} runs, exit 0/2/3/4: {outcomes:?}");
    assert!(
        outcomes[2] > 50,
        "most extreme values are refused: {outcomes:?}"
    );
}
