//! The output rule (issue 23): a command only replaces what it created itself, never an
//! input, and one run's outputs never overwrite each other. Each test is a reproducer, from
//! flags and bytes.

use std::path::Path;
use std::process::{Command, Output};

use crate::common::data;
use crate::common::{refused_quickly, run_limited};

fn run(args: &[&str], cwd: &Path, path_env: Option<&str>) -> Output {
    let mut command = Command::new(env!("CARGO_BIN_EXE_splat4d"));
    command.args(args).current_dir(cwd);
    if let Some(p) = path_env {
        command.env("PATH", p);
    }
    command.output().unwrap()
}

fn ok(output: &Output) {
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
}

/// Exit status 2 and `needle` in the message.
fn refused(output: &Output, needle: &str) {
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains(needle), "{stderr}");
}

/// The names in `dir`, sorted.
fn names(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

/// A 4-camera × 2-time 8×8 dataset of the blob (`s.json` in `d`) into `out`.
fn dataset(d: &Path, scene: &str, out: &str) -> Output {
    run(
        &[
            "dataset", "--scene", scene, "--views", "4", "--times", "2", "--size", "8x8", "--out",
            out,
        ],
        d,
        None,
    )
}

fn blob_in(d: &Path, name: &str) {
    std::fs::copy(data("blob.json"), d.join(name)).unwrap();
}

#[test]
fn a_path_file_named_dot_dot_never_names_the_folder_above() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    blob_in(d, "s.json");
    std::fs::write(d.join("notes.txt"), "mine").unwrap();
    let camera: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(data("blob_camera.json")).unwrap()).unwrap();
    let path =
        serde_json::json!([{"camera": camera, "time": 0.5}, {"camera": camera, "time": 0.6}]);
    std::fs::write(d.join("...json"), path.to_string()).unwrap();
    let output = run(
        &[
            "video", "--scene", "s.json", "--path", "...json", "--no-mp4", "--out", "newvids",
        ],
        d,
        None,
    );
    ok(&output);
    assert_eq!(names(d), ["...json", "newvids", "notes.txt", "s.json"]);
    assert_eq!(
        std::fs::read_to_string(d.join("notes.txt")).unwrap(),
        "mine"
    );
    // The frames went to a folder of a safe name inside newvids.
    let frames = names(&d.join("newvids/path"));
    assert_eq!(
        frames,
        [".splat4d-output", "frame_0000.png", "frame_0001.png"]
    );
}

#[test]
fn dataset_replaces_only_its_own_output_and_never_its_input() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    blob_in(d, "s.json");
    // A nerfstudio capture is not a splat4d dataset: refused, untouched.
    std::fs::create_dir_all(d.join("cap/images")).unwrap();
    std::fs::write(d.join("cap/transforms.json"), r#"{"frames": []}"#).unwrap();
    std::fs::write(d.join("cap/images/photo.png"), "photo").unwrap();
    refused(
        &dataset(d, "s.json", "cap"),
        "was not written by `splat4d dataset`",
    );
    assert_eq!(names(&d.join("cap")), ["images", "transforms.json"]);
    assert_eq!(
        std::fs::read_to_string(d.join("cap/images/photo.png")).unwrap(),
        "photo"
    );
    // A dataset's own folder holding the scene it is made from: refused, scene intact.
    ok(&dataset(d, "s.json", "ds"));
    blob_in(d, "ds/scene.json");
    refused(&dataset(d, "ds/scene.json", "ds"), "holds an input");
    assert!(d.join("ds/scene.json").is_file());
    assert!(d.join("ds/transforms_train.json").is_file());
    // `ds/../ds` is `ds`: replaced whole, nothing lost or left beside it.
    std::fs::remove_file(d.join("ds/scene.json")).unwrap();
    ok(&dataset(d, "s.json", "ds/../ds"));
    assert_eq!(names(d), ["cap", "ds", "s.json"]);
    assert_eq!(
        names(&d.join("ds")),
        [
            ".splat4d-output",
            "test",
            "train",
            "transforms_test.json",
            "transforms_train.json",
            "transforms_val.json",
            "val"
        ]
    );
    // Another command's output is not a dataset to replace.
    ok(&run(
        &[
            "export-ply",
            "--scene",
            "s.json",
            "--frames",
            "2",
            "--out",
            "seq",
        ],
        d,
        None,
    ));
    refused(
        &dataset(d, "s.json", "seq"),
        "was not written by `splat4d dataset`",
    );
}

#[test]
fn a_ply_sequence_replaces_only_itself() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    blob_in(d, "s.json");
    let export = |scene: &str, out: &str| {
        run(
            &[
                "export-ply",
                "--scene",
                scene,
                "--frames",
                "3",
                "--out",
                out,
            ],
            d,
            None,
        )
    };
    ok(&export("s.json", "seq"));
    ok(&export("s.json", "seq/../seq"));
    assert_eq!(names(d), ["s.json", "seq"]);
    assert_eq!(
        names(&d.join("seq")),
        [
            ".splat4d-output",
            "frame_0000.ply",
            "frame_0001.ply",
            "frame_0002.ply",
            "frames.json"
        ]
    );
    // Its own frame as the input: refused before anything moves.
    let before = std::fs::read(d.join("seq/frame_0000.ply")).unwrap();
    refused(&export("seq/frame_0000.ply", "seq"), "holds an input");
    assert_eq!(std::fs::read(d.join("seq/frame_0000.ply")).unwrap(), before);
}

#[test]
fn fit_and_grad_never_write_over_what_they_read() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    blob_in(d, "s.json");
    ok(&dataset(d, "s.json", "ds"));
    let photo = d.join("ds/train/r_001.png");
    let before = std::fs::read(&photo).unwrap();
    let fit = run(
        &[
            "fit",
            "--views",
            "ds",
            "--out",
            "f.json",
            "--log",
            "ds/train/r_001.png",
        ],
        d,
        None,
    );
    refused(&fit, "is an input");
    // The same photo through `..`.
    let fit = run(
        &[
            "fit",
            "--views",
            "ds",
            "--out",
            "f.json",
            "--log",
            "ds/../ds/train/r_001.png",
        ],
        d,
        None,
    );
    refused(&fit, "is an input");
    assert_eq!(std::fs::read(&photo).unwrap(), before);
    assert!(!d.join("f.json").exists());
    // grad --camera c.json --out c.json.
    std::fs::copy(data("blob_camera.json"), d.join("c.json")).unwrap();
    let camera = std::fs::read(d.join("c.json")).unwrap();
    let grad = run(
        &[
            "grad",
            "--scene",
            "s.json",
            "--camera",
            "c.json",
            "--time",
            "0.5",
            "--target",
            "ds/train/r_000.png",
            "--out",
            "c.json",
        ],
        d,
        None,
    );
    refused(&grad, "is an input");
    assert_eq!(std::fs::read(d.join("c.json")).unwrap(), camera);
}

#[test]
fn videos_of_one_run_never_overwrite_each_other() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    blob_in(d, "s.json");
    let camera: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(data("blob_camera.json")).unwrap()).unwrap();
    let path = serde_json::json!([{"camera": camera, "time": 0.5}]);
    std::fs::write(d.join("spiral.json"), path.to_string()).unwrap();
    // A spiral and a path file named spiral.json; three orbits whose times round to 0.00.
    let output = run(
        &[
            "video",
            "--scene",
            "s.json",
            "--spiral=0.5,0.5,0.5,3,20,2",
            "--path",
            "spiral.json",
            "--orbit=0.5,0.5,0.5,3,20,2",
            "--times",
            "0.001,0.002,0.003",
            "--size",
            "8x8",
            "--no-mp4",
            "--out",
            "v",
        ],
        d,
        None,
    );
    ok(&output);
    let frames = |name: &str| {
        names(&d.join("v").join(name))
            .iter()
            .filter(|n| n.starts_with("frame_"))
            .count()
    };
    assert_eq!(frames("orbit_t0.00"), 2);
    assert_eq!(frames("orbit_t0.00_2"), 2);
    assert_eq!(frames("orbit_t0.00_3"), 2);
    assert_eq!(frames("spiral"), 2);
    assert_eq!(frames("spiral_2"), 1, "the path's one camera");
    assert!(d.join("v/spiral_2.gif").is_file());
    assert!(d.join("v/orbit_t0.00_3.camera_path.json").is_file());
}

#[cfg(unix)]
#[test]
fn a_failing_ffmpeg_leaves_no_earlier_mp4_and_foreign_files_are_kept() {
    use std::os::unix::fs::PermissionsExt;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    blob_in(d, "s.json");
    let bin = d.join("bin");
    std::fs::create_dir(&bin).unwrap();
    let good = "#!/bin/sh\nfor last; do :; done\necho mp4 > \"$last\"\n";
    let bad = "#!/bin/sh\nif [ \"$1\" = \"-version\" ]; then exit 0; fi\nexit 1\n";
    let path_env = format!("{}:/usr/bin:/bin", bin.display());
    let video = |script: &str| {
        std::fs::write(bin.join("ffmpeg"), script).unwrap();
        std::fs::set_permissions(bin.join("ffmpeg"), std::fs::Permissions::from_mode(0o755))
            .unwrap();
        run(
            &[
                "video",
                "--scene",
                "s.json",
                "--orbit=0.5,0.5,0.5,3,20,2",
                "--times",
                "0.5",
                "--size",
                "8x8",
                "--out",
                "v",
            ],
            d,
            Some(&path_env),
        )
    };
    ok(&video(good));
    assert!(d.join("v/orbit_t0.50.mp4").is_file());
    let output = video(bad);
    ok(&output);
    assert!(String::from_utf8_lossy(&output.stdout).contains("ffmpeg failed"));
    assert!(d.join("v/orbit_t0.50.gif").is_file());
    assert!(
        !d.join("v/orbit_t0.50.mp4").exists(),
        "the previous run's MP4 would pass for this one"
    );
    // A GIF of that name beside no video of ours is not ours to replace.
    std::fs::create_dir(d.join("w")).unwrap();
    std::fs::write(d.join("w/orbit_t0.50.gif"), "mine").unwrap();
    let output = run(
        &[
            "video",
            "--scene",
            "s.json",
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
        None,
    );
    refused(&output, "orbit_t0.50.gif");
    assert_eq!(names(&d.join("w")), ["orbit_t0.50.gif"]);
}

/// Dataset images are read only from inside the dataset's folder, by their real path;
/// `--allow-outside-images` reads them where the user means it.
#[cfg(unix)]
#[test]
fn dataset_images_outside_the_folder_need_a_flag() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    blob_in(d, "s.json");
    ok(&dataset(d, "s.json", "ds"));
    // One training image replaced by a link to a copy outside the dataset.
    std::fs::copy(d.join("ds/train/r_000.png"), d.join("outside.png")).unwrap();
    std::fs::remove_file(d.join("ds/train/r_000.png")).unwrap();
    std::os::unix::fs::symlink(d.join("outside.png"), d.join("ds/train/r_000.png")).unwrap();
    let fit = |extra: &[&str]| {
        let mut args = vec![
            "fit", "--views", "ds", "--steps", "1", "--init", "random:2", "--out", "f.json",
        ];
        args.extend_from_slice(extra);
        run(&args, d, None)
    };
    refused(&fit(&[]), "--allow-outside-images");
    let stderr = String::from_utf8_lossy(&fit(&[]).stderr).into_owned();
    assert!(
        stderr.contains("transforms_train.json")
            && stderr.contains("frame 0")
            && stderr.contains("file_path"),
        "{stderr}"
    );
    assert!(!d.join("f.json").exists());
    ok(&fit(&["--allow-outside-images"]));
    assert!(d.join("f.json").is_file());
}

/// Frames naming one image share one decode (25 frames, one 16×16 file: one image in memory).
#[test]
fn frames_naming_one_file_share_one_decoded_image() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let image = splat4d::Image::filled(16, 16, [0.25, 0.5, 0.75]);
    splat4d::io::image_file::save_image(
        &image,
        &d.join("one.png"),
        splat4d::io::image_file::BitDepth::Sixteen,
    )
    .unwrap();
    let frames: Vec<serde_json::Value> = (0..25)
        .map(|k| {
            serde_json::json!({"file_path": "one.png", "time": f64::from(k) / 24.0,
                "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,4],[0,0,0,1]]})
        })
        .collect();
    let file = serde_json::json!({"camera_angle_x": 0.7, "frames": frames});
    std::fs::write(d.join("transforms_train.json"), file.to_string()).unwrap();
    let dataset =
        splat4d::io::dataset::load_dataset(d, &splat4d::io::dataset::DatasetOptions::default())
            .unwrap();
    assert_eq!(dataset.train.len(), 25);
    let first = &dataset.train[0].image;
    assert!(
        dataset
            .train
            .iter()
            .all(|v| std::sync::Arc::ptr_eq(&v.image, first))
    );
    assert_eq!(std::sync::Arc::strong_count(first), 25);
    assert!((first.pixels[1] - 0.5).abs() < 1e-4);
}

/// import-gltf never writes over a buffer file its model reads.
#[test]
fn import_gltf_never_writes_over_its_buffer() {
    use base64::Engine as _;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let source = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/gltf/Box.gltf");
    let mut gltf: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(source).unwrap()).unwrap();
    let uri = gltf["buffers"][0]["uri"].as_str().unwrap().to_owned();
    let payload = base64::engine::general_purpose::STANDARD
        .decode(uri.split_once(',').unwrap().1)
        .unwrap();
    // A buffer file with a name an output could have.
    std::fs::write(d.join("data.ply"), &payload).unwrap();
    gltf["buffers"][0]["uri"] = serde_json::json!("data.ply");
    std::fs::write(d.join("m.gltf"), gltf.to_string()).unwrap();
    let output = run(
        &[
            "import-gltf",
            "m.gltf",
            "--kernels",
            "20",
            "--out",
            "data.ply",
        ],
        d,
        None,
    );
    refused(&output, "is an input");
    assert_eq!(std::fs::read(d.join("data.ply")).unwrap(), payload);
    ok(&run(
        &[
            "import-gltf",
            "m.gltf",
            "--kernels",
            "20",
            "--out",
            "m.json",
        ],
        d,
        None,
    ));
}

// Limits through the executable (from the former limits.rs): refused quickly, with a
// message and exit status, never a panic, a hang or an unbounded allocation.

#[test]
fn outputs_are_checked_before_the_work_and_never_replace_an_input() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let blob = data("blob.json");
    let camera = data("blob_camera.json");
    std::fs::copy(&blob, d.join("s.json")).unwrap();
    let ok = run_limited(
        &[
            "dataset", "--scene", "s.json", "--views", "4", "--times", "2", "--size", "8x8",
            "--out", "ds",
        ],
        d,
    );
    assert!(ok.status.success());
    let before = std::fs::read(d.join("ds/transforms_train.json")).unwrap();
    // A fit aimed at its dataset, at its start, or at an unwritable place: refused at once.
    refused_quickly(
        &["fit", "--views", "ds", "--out", "ds/transforms_train.json"],
        d,
        2,
        "input",
    );
    refused_quickly(
        &[
            "fit", "--views", "ds", "--init", "s.json", "--out", "s.json",
        ],
        d,
        2,
        "input",
    );
    std::fs::write(d.join("file"), "x").unwrap();
    refused_quickly(
        &["fit", "--views", "ds", "--out", "file/f.json"],
        d,
        3,
        "file/f.json",
    );
    refused_quickly(
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
    refused_quickly(
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
    refused_quickly(&grad, d, 2, ".json");
    let ply = run_limited(&["toy", "--kind", "blob", "--out", "scene.ply"], d);
    assert!(ply.status.success());
    let before = std::fs::read(d.join("scene.ply")).unwrap();
    refused_quickly(
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
    refused_quickly(
        &["import-gltf", "m.gltf", "--out", "m.gltf"],
        d,
        2,
        ".json or .ply",
    );
}

/// Temporaries are told apart by a lock held on them (issue 45), not by a process id: a
/// run in another PID namespace (a container sharing the folder) took a live run's
/// temporary folder for a dead run's and removed it. Here the live ones' locks are held by
/// this test's own open files, as another process anywhere would hold them; the others
/// are left by killed runs, and nobody holds theirs.
#[cfg(target_os = "linux")]
#[test]
fn temporaries_are_removed_only_when_their_lock_is_free() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // Left by killed runs.
    std::fs::write(d.join(".splat4d-tmp-a1b2c3"), vec![0u8; 1000]).unwrap();
    std::fs::create_dir(d.join(".splat4d-tmp-dataset-x4y5z6")).unwrap();
    std::fs::write(d.join(".splat4d-tmp-dataset-x4y5z6/r_000.png"), "half").unwrap();
    // An earlier output moved aside by a run killed before its successor took its place.
    std::fs::create_dir(d.join(".splat4d-old-00aa11bb22cc33dd-ds")).unwrap();
    std::fs::write(d.join(".splat4d-old-00aa11bb22cc33dd-ds/a.txt"), "kept").unwrap();
    // In use: a temporary folder and a temporary file, their locks held.
    let live_dir = d.join(".splat4d-tmp-dataset-live01");
    std::fs::create_dir(&live_dir).unwrap();
    std::fs::write(live_dir.join("r_000.png"), "in progress").unwrap();
    let held_dir = std::fs::File::open(&live_dir).unwrap();
    held_dir.lock().unwrap();
    let live_file = d.join(".splat4d-tmp-live02");
    std::fs::write(&live_file, "in progress").unwrap();
    let held_file = std::fs::File::open(&live_file).unwrap();
    held_file.lock().unwrap();
    // Not a temporary of ours.
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
    ok(&run_limited(&render, d));
    assert_eq!(
        names(d),
        [
            ".splat4d-notes",
            ".splat4d-tmp-dataset-live01",
            ".splat4d-tmp-live02",
            "ds",
            "r.png"
        ]
    );
    assert_eq!(
        std::fs::read_to_string(live_dir.join("r_000.png")).unwrap(),
        "in progress"
    );
    assert_eq!(std::fs::read_to_string(d.join("ds/a.txt")).unwrap(), "kept");
    // Once their runs have ended (their locks released), they are leftovers too.
    drop((held_dir, held_file));
    ok(&run_limited(&render, d));
    assert_eq!(names(d), [".splat4d-notes", "ds", "r.png"]);
}

/// Every path under `dir` with its bytes (`None` for a folder): the folder as it is.
fn snapshot(dir: &Path) -> std::collections::BTreeMap<String, Option<Vec<u8>>> {
    let mut found = std::collections::BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(at) = stack.pop() {
        for entry in std::fs::read_dir(&at).unwrap() {
            let path = entry.unwrap().path();
            let name = path
                .strip_prefix(dir)
                .unwrap()
                .to_string_lossy()
                .into_owned();
            if path.is_dir() {
                stack.push(path);
                found.insert(name, None);
            } else {
                found.insert(name, Some(std::fs::read(&path).unwrap()));
            }
        }
    }
    found
}

/// Issue 45: `video --no-mp4` (or `--no-gif`) run again deleted the MP4 (GIF) of that name
/// that the user had encoded from the frames. A GIF or MP4 is removed or replaced only when
/// the frame folder's marker records it as splat4d's, unchanged.
#[test]
fn a_video_run_again_keeps_the_gif_and_mp4_the_user_made() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    blob_in(d, "s.json");
    let video = |extra: &[&str]| {
        let mut args = vec![
            "video",
            "--scene",
            "s.json",
            "--orbit=0.5,0.5,0.5,3,20,2",
            "--times",
            "0.5",
            "--size",
            "8x8",
            "--out",
            "v",
        ];
        args.extend(extra);
        run(&args, d, None)
    };
    let (gif, mp4) = (d.join("v/orbit_t0.50.gif"), d.join("v/orbit_t0.50.mp4"));
    ok(&video(&["--no-mp4"]));
    assert!(gif.is_file());
    // The user encodes an MP4 of the frames: a run without MP4s keeps it.
    std::fs::write(&mp4, "my own mp4").unwrap();
    ok(&video(&["--no-mp4"]));
    assert_eq!(std::fs::read(&mp4).unwrap(), b"my own mp4");
    // A run that would write an MP4 does not replace it: refused before any work.
    let before = snapshot(&d.join("v"));
    refused(&video(&[]), "orbit_t0.50.mp4");
    assert_eq!(snapshot(&d.join("v")), before);
    // splat4d's own GIF, unchanged, goes with `--no-gif` (it would pass for the new frames).
    ok(&video(&["--no-mp4", "--no-gif"]));
    assert!(!gif.exists());
    assert_eq!(std::fs::read(&mp4).unwrap(), b"my own mp4");
    // The user's GIF stays through `--no-gif` runs, and is not replaced by a GIF.
    std::fs::write(&gif, "my own gif").unwrap();
    ok(&video(&["--no-mp4", "--no-gif"]));
    assert_eq!(std::fs::read(&gif).unwrap(), b"my own gif");
    refused(&video(&["--no-mp4"]), "orbit_t0.50.gif");
    assert_eq!(std::fs::read(&gif).unwrap(), b"my own gif");
    // A GIF splat4d wrote and the user changed since is the user's.
    std::fs::remove_file(&gif).unwrap();
    ok(&video(&["--no-mp4"]));
    let mut changed = std::fs::read(&gif).unwrap();
    changed.extend_from_slice(b"edited");
    std::fs::write(&gif, &changed).unwrap();
    ok(&video(&["--no-mp4", "--no-gif"]));
    assert_eq!(std::fs::read(&gif).unwrap(), changed);
    assert_eq!(std::fs::read(&mp4).unwrap(), b"my own mp4");
}

/// Issue 45: `fit --out` or `--log` naming the dataset's point cloud, a mask or a COLMAP
/// photo replaced it with exit 0. Every file a command reads is an input its outputs are
/// checked against: refused (exit 2) before any work, the file unchanged byte for byte.
#[test]
fn outputs_never_replace_a_mask_point_cloud_colmap_photo_or_start_scene() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    blob_in(d, "s.json");
    ok(&dataset(d, "s.json", "ds"));
    // A point cloud and a mask named by the dataset.
    let transforms = d.join("ds/transforms_train.json");
    let mut value: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&transforms).unwrap()).unwrap();
    value["ply_file_path"] = serde_json::json!("points.ply");
    value["frames"][1]["mask_path"] = serde_json::json!("masks/m1.png");
    std::fs::write(&transforms, value.to_string()).unwrap();
    std::fs::write(
        d.join("ds/points.ply"),
        "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n0.5 0.5 0.5\n",
    )
    .unwrap();
    std::fs::create_dir(d.join("ds/masks")).unwrap();
    std::fs::copy(d.join("ds/train/r_001.png"), d.join("ds/masks/m1.png")).unwrap();
    // A COLMAP model with its photos in images/.
    let sparse = d.join("col/sparse/0");
    std::fs::create_dir_all(&sparse).unwrap();
    std::fs::write(sparse.join("cameras.txt"), "1 PINHOLE 8 8 10 10 4 4\n").unwrap();
    std::fs::write(
        sparse.join("images.txt"),
        "1 1 0 0 0 0 0 4 1 a.png\n\n2 1 0 0 0 0.1 0 4 1 sub/b.json\n\n",
    )
    .unwrap();
    std::fs::create_dir_all(d.join("col/images/sub")).unwrap();
    std::fs::copy(d.join("ds/train/r_000.png"), d.join("col/images/a.png")).unwrap();
    std::fs::copy(
        d.join("ds/train/r_002.png"),
        d.join("col/images/sub/b.json"),
    )
    .unwrap();
    let before = (snapshot(&d.join("ds")), snapshot(&d.join("col")));
    let scene = std::fs::read(d.join("s.json")).unwrap();
    for (views, out, log, init) in [
        ("ds", "ds/points.ply", None, "auto"),
        ("ds", "ds/masks/../points.ply", None, "auto"),
        ("ds", "f.json", Some("ds/points.ply"), "auto"),
        ("ds", "f.json", Some("ds/masks/m1.png"), "auto"),
        ("col", "f.json", Some("col/images/a.png"), "auto"),
        ("col", "col/images/sub/b.json", None, "auto"),
        ("ds", "s.json", None, "s.json"),
        ("ds", "f.json", Some("s.json"), "s.json"),
    ] {
        let mut args = vec!["fit", "--views", views, "--init", init, "--out", out];
        if let Some(log) = log {
            args.extend(["--log", log]);
        }
        let output = run(&args, d, None);
        refused(&output, "is an input");
        assert_eq!(
            (snapshot(&d.join("ds")), snapshot(&d.join("col"))),
            before,
            "{args:?}"
        );
        assert_eq!(std::fs::read(d.join("s.json")).unwrap(), scene);
        assert!(!d.join("f.json").exists());
    }
    // `bench --sweep` writes sweep.md and sweep.png: never over the scene it measures.
    std::fs::create_dir(d.join("b")).unwrap();
    blob_in(d, "b/sweep.md");
    let output = run(
        &["bench", "--scene", "b/sweep.md", "--sweep", "--out", "b"],
        d,
        None,
    );
    refused(&output, "is an input");
    assert_eq!(std::fs::read(d.join("b/sweep.md")).unwrap(), scene);
    assert_eq!(names(&d.join("b")), ["sweep.md"]);
}

/// Issue 45: `video --out NEW` that failed left an empty `NEW`. A failed video leaves nothing
/// it created, and an earlier video as it was: here the second video of the run (a path
/// camera too wide for a GIF) fails after the first is complete.
#[test]
fn a_failed_video_leaves_nothing_it_created() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    blob_in(d, "s.json");
    let mut camera: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(data("blob_camera.json")).unwrap()).unwrap();
    camera["width"] = serde_json::json!(70000);
    camera["height"] = serde_json::json!(1);
    camera["cx"] = serde_json::json!(35000.0);
    camera["cy"] = serde_json::json!(0.5);
    std::fs::write(
        d.join("wide.json"),
        serde_json::json!([{"camera": camera, "time": 0.5}]).to_string(),
    )
    .unwrap();
    let video = |out: &str, path: bool| {
        let mut args = vec![
            "video",
            "--scene",
            "s.json",
            "--orbit=0.5,0.5,0.5,3,20,2",
            "--times",
            "0.5",
            "--size",
            "8x8",
            "--no-mp4",
            "--out",
            out,
        ];
        if path {
            args.extend(["--path", "wide.json"]);
        }
        run(&args, d, None)
    };
    let before = snapshot(d);
    refused(&video("new/videos", true), "GIF");
    assert_eq!(snapshot(d), before);
    // Over an earlier video (and a file of the user's): all as it was.
    ok(&video("v", false));
    std::fs::write(d.join("v/notes.txt"), "mine").unwrap();
    let before = snapshot(d);
    refused(&video("v", true), "GIF");
    assert_eq!(snapshot(d), before);
}

/// Issue 45: `report --out` over a folder it may not write into ran the whole experiment
/// before refusing. It is refused first: the experiment never starts (no progress), and the
/// folder is as it was.
#[test]
fn report_checks_its_folder_before_the_experiment() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::create_dir_all(d.join("a/fit_vs_truth")).unwrap();
    std::fs::write(d.join("a/fit_vs_truth/notes.txt"), "mine").unwrap();
    std::fs::create_dir_all(d.join("b/report.md")).unwrap();
    std::fs::create_dir_all(d.join("c")).unwrap();
    std::fs::write(d.join("c/fit_vs_truth.gif"), "my own gif").unwrap();
    std::fs::write(d.join("e"), "a file").unwrap();
    let before = snapshot(d);
    for (out, needle) in [
        ("a", "fit_vs_truth"),
        ("b", "report.md"),
        ("c", "fit_vs_truth.gif"),
        ("e", "not a folder"),
    ] {
        let output = run(&["report", "--quick", "--out", out], d, None);
        refused(&output, needle);
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(!stderr.contains("dataset: "), "{out}: {stderr}");
        assert_eq!(snapshot(d), before, "{out}");
    }
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
        let output = run_limited(
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

/// Issue 45: `report --quick` on a full disk left 15 files and no `report.md`. The report is
/// written into a temporary folder inside its own and moved into place at the end: a run
/// that fails leaves nothing but what was there. The quick report takes about 1 MB; the
/// 512 KiB tmpfs fills half-way through it (root only, as above).
#[test]
fn a_report_on_a_full_disk_leaves_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let disk = tmp.path().join("disk");
    std::fs::create_dir(&disk).unwrap();
    let mounted = Command::new("mount")
        .args(["-t", "tmpfs", "-o", "size=512k", "tmpfs"])
        .arg(&disk)
        .stderr(std::process::Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    if !mounted {
        eprintln!("cannot mount a tmpfs here (not root?): the full-disk run is skipped");
        return;
    }
    let _unmount = Mounted(disk.clone());
    std::fs::write(disk.join("notes.txt"), "mine").unwrap();
    for out in ["new", "."] {
        let output = run_limited(
            &[
                "report".as_ref(),
                "--quick".as_ref(),
                "--out".as_ref(),
                disk.join(out).as_os_str(),
            ],
            tmp.path(),
        );
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(3), "{out}: {stderr}");
        assert!(stderr.contains("disk full"), "{out}: {stderr}");
        assert_eq!(names(&disk), ["notes.txt"], "{out}");
    }
}
