//! The `splat4d` executable on the shipped fixtures in `data/`: outputs, formats, the
//! default job, and bad input (exit status 2, a message naming file and field, no output).

use std::path::Path;

use crate::common::{data, splat4d, stderr};

use splat4d::fit::plan::FitPlan;
use splat4d::io::image_file::load_image;
use splat4d::model::image::quantize;
use splat4d::{RenderOptions, render};

fn render_args<'a>(scene: &'a str, camera: &'a str, out: &'a str) -> Vec<&'a str> {
    vec![
        "render", "--scene", scene, "--camera", camera, "--time", "0.5", "--out", out,
    ]
}

fn blob_image() -> splat4d::Image {
    let scene = splat4d::io::scene_file::load_scene(&data("blob.json")).unwrap();
    let camera = splat4d::io::camera_file::load_camera(&data("blob_camera.json")).unwrap();
    render(&scene, &camera, 0.5, &RenderOptions::default()).unwrap()
}

fn files_in(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

#[test]
fn renders_exr_and_png_8_and_16_bit() {
    let dir = tempfile::tempdir().unwrap();
    let (scene, camera) = (data("blob.json"), data("blob_camera.json"));
    let (scene, camera) = (scene.to_str().unwrap(), camera.to_str().unwrap());
    let expected = blob_image();
    for (out, extra, max) in [
        ("a.exr", None, 0),
        ("a.png", None, 255),
        ("b.png", Some("16"), 65535),
    ] {
        let mut args = render_args(scene, camera, out);
        if let Some(depth) = extra {
            args.extend(["--bit-depth", depth]);
        }
        let output = splat4d(&args, dir.path());
        assert!(output.status.success(), "{out}: {}", stderr(&output));
        let read = load_image(&dir.path().join(out), [0.0; 3]).unwrap();
        assert_eq!((read.width, read.height), (expected.width, expected.height));
        for (r, e) in read.pixels.iter().zip(&expected.pixels) {
            let e = if max == 0 {
                *e
            } else {
                f32::from(quantize(*e, max)) / f32::from(max)
            };
            assert!((r - e).abs() <= 1e-7, "{out}: read {r}, expected {e}");
        }
        assert!(
            read.pixels.iter().cloned().fold(0.0, f32::max) > 0.9,
            "{out}: the blob is visible"
        );
    }
    assert_eq!(files_in(dir.path()), ["a.exr", "a.png", "b.png"]);
}

/// `render`'s summary counts the kernels that reach the image, not every kernel in front of
/// the camera: the blob, and a copy of it three units to the camera's right (in front, at
/// depth 3, its ellipse some 90 pixels past the right edge).
#[test]
fn render_counts_on_screen_only_the_kernels_that_reach_the_image() {
    let dir = tempfile::tempdir().unwrap();
    let scene = r#"{"kernels": [
        {"mean": [0.5, 0.5, 0.5, 0.5], "scale": [0.1, 0.1, 0.1, 100.0], "amplitude": [1.0, 1.0, 1.0]},
        {"mean": [-1.6213203435596424, 0.5, -1.6213203435596424, 0.5], "scale": [0.1, 0.1, 0.1, 100.0], "amplitude": [1.0, 1.0, 1.0]}
    ], "background": [0.0, 0.0, 0.0]}"#;
    std::fs::write(dir.path().join("two.json"), scene).unwrap();
    let camera = data("blob_camera.json");
    let output = splat4d(
        &render_args("two.json", camera.to_str().unwrap(), "two.png"),
        dir.path(),
    );
    assert!(output.status.success(), "{}", stderr(&output));
    let printed = String::from_utf8_lossy(&output.stdout);
    assert!(printed.contains(", 1 of 2 kernels on screen,"), "{printed}");
}

#[test]
fn threads_flag_does_not_change_the_output() {
    let dir = tempfile::tempdir().unwrap();
    let (scene, camera) = (data("blob.json"), data("blob_camera.json"));
    let (scene, camera) = (scene.to_str().unwrap(), camera.to_str().unwrap());
    for (out, threads) in [("1.exr", "1"), ("2.exr", "2")] {
        let mut args = render_args(scene, camera, out);
        args.extend(["--threads", threads, "--dilation", "0.5", "--cutoff", "0"]);
        assert!(splat4d(&args, dir.path()).status.success());
    }
    let one = std::fs::read(dir.path().join("1.exr")).unwrap();
    let two = std::fs::read(dir.path().join("2.exr")).unwrap();
    assert_eq!(one, two);
}

/// Without `--threads`, work this large runs its frame and its writing on a thread of the
/// global pool (`tasks::with_threads_on_pool`), small work on the calling thread: the same file
/// either way, and the same as on one or two threads.
#[test]
fn default_threads_give_the_same_output_for_small_and_large_work() {
    let dir = tempfile::tempdir().unwrap();
    let camera = data("blob_camera.json");
    let camera = camera.to_str().unwrap();
    let large = dir.path().join("large.ply");
    // 200 kernels at 320×240: 1.5·10⁷ pixel-kernel units, above the small-work limit.
    splat4d::io::ply::write_scene_ply(&splat4d::scenes::synthetic::bench_scene(200, 42), &large)
        .unwrap();
    let blob = data("blob.json");
    for (scene, name) in [
        (large.to_str().unwrap(), "large"),
        (blob.to_str().unwrap(), "small"),
    ] {
        let mut outputs = Vec::new();
        for threads in [None, Some("1"), Some("2")] {
            let out = format!("{name}{}.exr", threads.unwrap_or("default"));
            let mut args = render_args(scene, camera, &out);
            if let Some(threads) = threads {
                args.extend(["--threads", threads]);
            }
            let output = splat4d(&args, dir.path());
            assert!(output.status.success(), "{}", stderr(&output));
            let printed = String::from_utf8_lossy(&output.stdout).to_string();
            assert!(
                !printed.contains(" 0 pairs"),
                "{name}: something on screen: {printed}"
            );
            outputs.push(std::fs::read(dir.path().join(&out)).unwrap());
        }
        assert!(outputs.iter().all(|o| *o == outputs[0]), "{name}");
    }
}

#[test]
fn report_quick_writes_the_report_and_its_charts() {
    let dir = tempfile::tempdir().unwrap();
    let output = splat4d(&["report", "--out", "rep", "--quick"], dir.path());
    assert!(output.status.success(), "{}", stderr(&output));
    // Piped, progress comes as log lines: each phase announced and closed.
    let log = stderr(&output);
    for phase in ["dataset", "fit 4D", "evaluate", "volumes"] {
        assert!(
            log.contains(&format!("{phase}: ")) && log.contains(" to do"),
            "{log}"
        );
    }
    assert!(log.contains(" done in "), "{log}");
    let report = std::fs::read_to_string(dir.path().join("rep/report.md")).unwrap();
    for part in [
        "## Headline",
        "MSE per split",
        "4D (paper)",
        "frame 3D",
        "interpolation",
        "ground truth",
        "σt ablation",
        "| 0.5 | 1.8 |",
        "## Model size",
        "| seed blob | 4D adaptive, velocity kernels |",
        "| seed points | 4D adaptive, static kernels |",
        "splat4d report --out rep --quick",
    ] {
        assert!(report.contains(part), "report.md should contain `{part}`");
    }
    // Every image the report links exists and decodes: the charts and volume figures on
    // their own lines, the gallery's cells in a table, the animation.
    let (mut figures, mut cells, mut animations) = (0, 0, 0);
    for (at, _) in report.match_indices("](") {
        let rest = &report[at + 2..];
        let name = &rest[..rest.find(')').unwrap()];
        let path = dir.path().join("rep").join(name);
        if name.ends_with(".gif") {
            let bytes = std::fs::read(&path).unwrap();
            assert!(bytes.starts_with(b"GIF89a") && bytes.len() > 1000, "{name}");
            animations += 1;
            continue;
        }
        let image = load_image(&path, [1.0; 3]).unwrap();
        if name.starts_with("gallery_") {
            // Ground truth | render | error, each the dataset's size zoomed 3×.
            assert!(image.width > 3 * 3 * 16 && image.height >= 3 * 16, "{name}");
            cells += 1;
        } else {
            assert!(image.width >= 200 && image.height >= 100, "{name}");
            figures += 1;
        }
    }
    assert_eq!(figures, 8 + 6, "8 charts and 6 volume figures");
    assert_eq!(cells, 3 * 4, "3 methods at 4 times");
    assert_eq!(animations, 1);
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(stdout.contains("report: rep/report.md"), "{stdout}");
    // Every name written is one the folder was checked for before the experiment, and no
    // temporary is left.
    let checked = splat4d::report::markdown::report_names(
        &splat4d::report::experiment::ExperimentConfig::quick(),
    );
    let mut written: Vec<String> = std::fs::read_dir(dir.path().join("rep"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    written.sort();
    let mut expected = checked.clone();
    expected.sort();
    assert_eq!(written, expected);
}

/// Runs a render that must fail; returns its stderr after checking status 2 and that the
/// output folder holds nothing but what `keep` lists.
fn failing_render(scene: &Path, camera: &Path, out: &str, dir: &Path, keep: &[&str]) -> String {
    let args = render_args(scene.to_str().unwrap(), camera.to_str().unwrap(), out);
    let output = splat4d(&args, dir);
    assert_eq!(output.status.code(), Some(2), "{}", stderr(&output));
    let mut kept: Vec<String> = keep.iter().map(|s| s.to_string()).collect();
    kept.sort();
    assert_eq!(
        files_in(dir),
        kept,
        "no output, no temporary file left behind"
    );
    stderr(&output)
}

#[test]
fn bad_input_exits_2_naming_file_and_field_with_no_output() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let good_scene = data("blob.json");
    let good_camera = data("blob_camera.json");
    std::fs::write(
        d.join("bad_scene.json"),
        r#"{"kernels":[{"mean":[0,0,0,0],"scale":[1,1,-1,1],"amplitude":[1,1,1]}]}"#,
    )
    .unwrap();
    let camera_text = std::fs::read_to_string(&good_camera)
        .unwrap()
        .replace("\"width\": 320", "\"width\": 0");
    std::fs::write(d.join("bad_camera.json"), camera_text).unwrap();
    let keep = ["bad_camera.json", "bad_scene.json"];

    let message = failing_render(&d.join("bad_scene.json"), &good_camera, "x.png", d, &keep);
    assert!(
        message.contains("bad_scene.json")
            && message.contains("kernel 0")
            && message.contains("`scale`"),
        "{message}"
    );
    let message = failing_render(&good_scene, &d.join("bad_camera.json"), "x.png", d, &keep);
    assert!(
        message.contains("bad_camera.json") && message.contains("`width`"),
        "{message}"
    );
    let message = failing_render(&d.join("missing.json"), &good_camera, "x.png", d, &keep);
    assert!(message.contains("missing.json"), "{message}");
    let message = failing_render(&good_scene, &good_camera, "x.jpg", d, &keep);
    assert!(
        message.contains("x.jpg") && message.contains("unsupported image extension"),
        "{message}"
    );
    // The output path is a folder: the write fails after rendering and leaves nothing.
    std::fs::create_dir(d.join("taken.png")).unwrap();
    let message = failing_render(
        &good_scene,
        &good_camera,
        "taken.png",
        d,
        &["bad_camera.json", "bad_scene.json", "taken.png"],
    );
    assert!(message.contains("taken.png"), "{message}");
    assert!(files_in(&d.join("taken.png")).is_empty());
}

#[test]
fn bad_flags_exit_2() {
    let dir = tempfile::tempdir().unwrap();
    let (scene, camera) = (data("blob.json"), data("blob_camera.json"));
    let (scene, camera) = (scene.to_str().unwrap(), camera.to_str().unwrap());
    for extra in [
        ["--dilation", "-1"],
        ["--cutoff", "nan"],
        ["--bit-depth", "12"],
        ["--threads", "0"],
    ] {
        let mut args = render_args(scene, camera, "x.png");
        args.extend(extra);
        let output = splat4d(&args, dir.path());
        assert_eq!(
            output.status.code(),
            Some(2),
            "{extra:?}: {}",
            stderr(&output)
        );
        assert!(
            stderr(&output).contains(&extra[0][2..]),
            "{extra:?}: {}",
            stderr(&output)
        );
        assert!(files_in(dir.path()).is_empty());
    }
    // A value the flag's parser takes and the render's options refuse: the message names the
    // flag given, not the library's field.
    for flag in ["--dilation", "--cutoff"] {
        let mut args = render_args(scene, camera, "x.png");
        args.extend([flag, "-1"]);
        let output = splat4d(&args, dir.path());
        assert_eq!(output.status.code(), Some(2), "{flag}: {}", stderr(&output));
        assert!(
            stderr(&output).contains(&format!("{flag} -1 must be finite and ≥ 0")),
            "{flag}: {}",
            stderr(&output)
        );
    }
}

#[test]
fn grad_matches_the_independent_gradient_vectors() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["toy_blob", "random_200"] {
        let data = crate::common::reference_case_dir(name);
        let tau = std::fs::read_to_string(data.join("tau.txt")).unwrap();
        let out = dir.path().join(format!("{name}.json"));
        let path = |f: &str| data.join(f).to_str().unwrap().to_owned();
        let args = [
            "grad",
            "--scene",
            &path("scene.json"),
            "--camera",
            &path("camera.json"),
            "--time",
            tau.trim(),
            "--target",
            &path("grad_target.exr"),
            "--out",
            out.to_str().unwrap(),
        ];
        let output = splat4d(&args, dir.path());
        assert!(output.status.success(), "{name}: {}", stderr(&output));
        let read = |p: &Path| {
            splat4d::io::gradients_file::gradients_from_json(
                &std::fs::read_to_string(p).unwrap(),
                "x",
            )
            .unwrap()
        };
        let (loss, ours) = read(&out);
        let (expected_loss, expected) = read(&data.join("grad_expected.json"));
        assert!(
            (loss - expected_loss).abs() <= 1e-5 * expected_loss,
            "{name}: loss {loss} vs {expected_loss}"
        );
        assert_eq!(ours.len(), expected.len());
        let flat = |g: &splat4d::Gradients| -> Vec<f64> {
            (0..g.len())
                .flat_map(|i| {
                    g.v_means[i]
                        .into_iter()
                        .chain(g.v_amplitudes[i])
                        .chain(g.v_velocities[i])
                })
                .collect()
        };
        let (ours, expected) = (flat(&ours), flat(&expected));
        let scale = expected.iter().map(|v| v.abs()).fold(0.0, f64::max);
        for (k, (a, e)) in ours.iter().zip(&expected).enumerate() {
            assert!(
                (a - e).abs() <= 1e-5 * scale + 1e-5 * e.abs(),
                "{name}: entry {k}: {a} vs {e}"
            );
        }
    }
}

#[test]
fn grad_refuses_a_target_of_the_wrong_size() {
    let dir = tempfile::tempdir().unwrap();
    let data = crate::common::reference_case_dir("toy_blob");
    let other = crate::common::reference_case_dir("random_200").join("grad_target.exr");
    let (scene, camera) = (data.join("scene.json"), data.join("camera.json"));
    let args = [
        "grad",
        "--scene",
        scene.to_str().unwrap(),
        "--camera",
        camera.to_str().unwrap(),
        "--time",
        "0.5",
        "--target",
        other.to_str().unwrap(),
        "--out",
        "g.json",
    ];
    let output = splat4d(&args, dir.path());
    assert_eq!(output.status.code(), Some(2));
    let message = stderr(&output);
    assert!(
        message.contains("grad_target.exr")
            && message.contains("128×96")
            && message.contains("96×72"),
        "{message}"
    );
    assert!(files_in(dir.path()).is_empty());
}

#[test]
fn dataset_then_fit_as_a_new_user_would() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let blob = data("blob.json");
    let args = [
        "dataset",
        "--scene",
        blob.to_str().unwrap(),
        "--views",
        "6",
        "--times",
        "3",
        "--size",
        "48x40",
        "--out",
        "set",
        "--seed",
        "3",
        "--exr",
    ];
    let output = splat4d(&args, d);
    assert!(output.status.success(), "{}", stderr(&output));
    assert_eq!(
        files_in(&d.join("set")),
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
    assert_eq!(
        files_in(&d.join("set/train")).len(),
        2 * 18,
        "PNG and EXR per frame"
    );

    // Start from the blob displaced by 0.03 and fit its mean and amplitude back.
    let mut start = splat4d::io::scene_file::load_scene(&blob).unwrap();
    start.means[0][0] += 0.03;
    start.amplitudes[0] = [0.8; 3];
    splat4d::io::scene_file::save_scene(&start, &d.join("start.json")).unwrap();
    let args = [
        "fit",
        "--views",
        "set",
        "--init",
        "start.json",
        "--steps",
        "200",
        "--out",
        "fitted.json",
        "--log",
        "log.jsonl",
        "--lr-mean",
        "5e-3",
        "--freeze-time",
        "--lr-final",
        "0.01",
    ];
    let output = splat4d(&args, d);
    assert!(output.status.success(), "{}", stderr(&output));
    let fitted = splat4d::io::scene_file::load_scene(&d.join("fitted.json")).unwrap();
    assert!(
        (fitted.means[0][0] - 0.5).abs() < 1e-3,
        "{:?}",
        fitted.means[0]
    );
    let log = std::fs::read_to_string(d.join("log.jsonl")).unwrap();
    let rows: Vec<serde_json::Value> = log
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(rows.len(), 200);
    assert_eq!(rows[199]["step"], 200);
    let first = rows[0]["train_loss"].as_f64().unwrap();
    let last = rows[199]["train_loss"].as_f64().unwrap();
    assert!(last < 1e-3 * first, "loss {first} → {last}");
    assert!(
        rows[199]["heldout_psnr"].as_f64().unwrap() > 50.0,
        "{}",
        rows[199]
    );
    let report = String::from_utf8_lossy(&output.stdout);
    assert!(report.contains("test: 4 views"), "{report}");

    // random:N with the box inferred from the cameras runs and writes N kernels.
    let args = [
        "fit",
        "--views",
        "set",
        "--init",
        "random:7",
        "--steps",
        "5",
        "--out",
        "random.json",
    ];
    let output = splat4d(&args, d);
    assert!(output.status.success(), "{}", stderr(&output));
    assert_eq!(
        splat4d::io::scene_file::load_scene(&d.join("random.json"))
            .unwrap()
            .len(),
        7
    );

    // No kernel count: a few kernels spread in the box, velocity mode, densify and prune;
    // the log records the count per step.
    let args = [
        "fit",
        "--views",
        "set",
        "--steps",
        "600",
        "--out",
        "auto.json",
        "--log",
        "auto.jsonl",
    ];
    let output = splat4d(&args, d);
    assert!(output.status.success(), "{}", stderr(&output));
    let auto = splat4d::io::scene_file::load_scene(&d.join("auto.json")).unwrap();
    let log = std::fs::read_to_string(d.join("auto.jsonl")).unwrap();
    let rows: Vec<serde_json::Value> = log
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(rows[0]["kernels"], FitPlan::default().start_kernels);
    assert_eq!(rows[599]["kernels"], auto.len());
    assert!(auto.len() <= 20, "{} kernels", auto.len());
    assert!(
        auto.velocities.iter().any(|v| v != &[0.0; 3]),
        "velocities fitted"
    );
    let report = String::from_utf8_lossy(&output.stdout);
    assert!(report.contains("auto.json"), "{report}");
}

#[test]
fn fit_refuses_bad_views_and_flags_with_no_output() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::create_dir(d.join("missing_image")).unwrap();
    std::fs::write(
        d.join("missing_image/transforms_train.json"),
        r#"{"camera_angle_x": 0.7, "frames": [{"file_path": "./train/r_000", "time": 0, "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,3],[0,0,0,1]]}]}"#,
    )
    .unwrap();
    let blob = data("blob.json");
    let args = [
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
        "set",
    ];
    assert!(splat4d(&args, d).status.success());
    let cases: [(&[&str], &[&str]); 6] = [
        (&["--views", "nowhere", "--init", "random:3"], &["nowhere"]),
        (
            &["--views", "missing_image", "--init", "random:3"],
            &["transforms_train.json", "frame 0", "file_path", "r_000"],
        ),
        (
            &["--views", "set", "--init", "random:0"],
            &["random:0", "N must be"],
        ),
        (
            &[
                "--views",
                "set",
                "--init",
                "random:3",
                "--box",
                "1,0,0,0,1,1",
            ],
            &["--box", "x0 < x1"],
        ),
        (
            &[
                "--views",
                "set",
                "--init",
                "random:3",
                "--init-scale",
                "0.1,0,0.1,0.1",
            ],
            &["--init-scale", "> 0"],
        ),
        (
            &["--views", "set", "--init", "nothere.json"],
            &["nothere.json"],
        ),
    ];
    for (extra, parts) in cases {
        let mut args = vec!["fit", "--steps", "3", "--out", "out.json"];
        args.extend(extra);
        let output = splat4d(&args, d);
        assert_eq!(output.status.code(), Some(2), "{extra:?}");
        let message = stderr(&output);
        for part in parts {
            assert!(
                message.contains(part),
                "{extra:?}: `{message}` should mention `{part}`"
            );
        }
        assert_eq!(files_in(d), ["missing_image", "set"]);
    }
}

#[test]
fn overlay_draws_over_the_render_and_needs_a_png() {
    let dir = tempfile::tempdir().unwrap();
    let (scene, camera) = (data("blob.json"), data("blob_camera.json"));
    let (scene, camera) = (scene.to_str().unwrap(), camera.to_str().unwrap());
    let mut args = render_args(scene, camera, "o.png");
    args.push("--overlay");
    let output = splat4d(&args, dir.path());
    assert!(output.status.success(), "{}", stderr(&output));
    let overlay = load_image(&dir.path().join("o.png"), [0.0; 3]).unwrap();
    let plain = blob_image();
    assert_eq!((overlay.width, overlay.height), (plain.width, plain.height));
    // The ellipse outline is drawn in green at the cut-off radius, away from the bright centre:
    // some pixels are much greener than the render there.
    let greener = overlay
        .pixels
        .chunks_exact(3)
        .zip(plain.pixels.chunks_exact(3))
        .filter(|(o, p)| o[1] > p[1] + 0.3 && o[1] > o[0] + 0.2)
        .count();
    assert!(greener > 50, "{greener} outline pixels");
    let mut args = render_args(scene, camera, "o.exr");
    args.push("--overlay");
    let output = splat4d(&args, dir.path());
    assert_eq!(output.status.code(), Some(2));
    assert!(stderr(&output).contains("--overlay"));
}

#[test]
fn import_gltf_and_render_through_its_camera() {
    let dir = tempfile::tempdir().unwrap();
    let gltf = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/gltf/Cameras.gltf");
    let gltf = gltf.to_str().unwrap();
    let output = splat4d(
        &[
            "import-gltf",
            gltf,
            "--kernels",
            "500",
            "--times",
            "4",
            "--out",
            "quad.ply",
        ],
        dir.path(),
    );
    assert!(output.status.success(), "{}", stderr(&output));
    assert!(
        String::from_utf8_lossy(&output.stdout)
            .contains("500 kernels (500 surface points × 1 times")
    );
    let camera_from = format!("{gltf}#0");
    let args = [
        "render",
        "--scene",
        "quad.ply",
        "--camera-from",
        &camera_from,
        "--size",
        "64x48",
        "--time",
        "0",
        "--out",
        "q.png",
    ];
    let output = splat4d(&args, dir.path());
    assert!(output.status.success(), "{}", stderr(&output));
    let image = load_image(&dir.path().join("q.png"), [0.0; 3]).unwrap();
    assert_eq!((image.width, image.height), (64, 48));
    assert!(image.pixels.iter().cloned().fold(0.0, f32::max) > 0.5);
    // Neither --camera nor --camera-from: a usage error.
    let output = splat4d(
        &[
            "render", "--scene", "quad.ply", "--time", "0", "--out", "x.png",
        ],
        dir.path(),
    );
    assert_eq!(output.status.code(), Some(2));
    let output = splat4d(
        &[
            "render",
            "--scene",
            "quad.ply",
            "--camera-from",
            &format!("{gltf}#1"),
            "--time",
            "0",
            "--out",
            "x.png",
        ],
        dir.path(),
    );
    assert_eq!(output.status.code(), Some(2));
    assert!(stderr(&output).contains("orthographic"));
    assert!(!dir.path().join("x.png").exists());
}

#[test]
fn bench_prints_speed_and_error_within_the_bound() {
    let dir = tempfile::tempdir().unwrap();
    let data_dir = crate::common::reference_case_dir("random_200");
    let (scene, camera) = (data_dir.join("scene.json"), data_dir.join("camera.json"));
    let args = [
        "bench",
        "--scene",
        scene.to_str().unwrap(),
        "--camera",
        camera.to_str().unwrap(),
        "--time",
        "0.37",
        "--frames",
        "2",
        "--samples",
        "300",
        "--threads",
        "2",
    ];
    let output = splat4d(&args, dir.path());
    assert!(output.status.success(), "{}", stderr(&output));
    let stdout = String::from_utf8_lossy(&output.stdout);
    let rows = bench_rows(&stdout);
    let tiles = rows
        .iter()
        .find(|r| r["scene"] == "scene.json" && r["method"] == "tiles")
        .unwrap_or_else(|| panic!("{stdout}"));
    assert_eq!(tiles["kernels"], "200");
    assert_eq!(tiles["size"], "128x96");
    let ratio: f64 = tiles["/bound"].parse().unwrap();
    assert!(ratio <= 1.0, "error at {ratio} of the bound");
    let pairs: u64 = tiles["pairs/frame"].parse().unwrap();
    assert!(pairs > 10_000, "{stdout}");
    // The dense baseline ran (a small scene) and evaluated every kernel at every pixel it
    // projected; the tiles row quotes the speed-up over it.
    let dense = rows
        .iter()
        .find(|r| r["method"] == "dense")
        .unwrap_or_else(|| panic!("{stdout}"));
    let dense_pairs: u64 = dense["pairs/frame"].parse().unwrap();
    assert_eq!(dense_pairs % (128 * 96), 0);
    assert!(dense_pairs > pairs);
    let dense_max: f64 = dense["max-err"].parse().unwrap();
    assert!(dense_max < 1e-4, "{stdout}");
    let speedup: f64 = tiles["speed-up"].trim_end_matches('x').parse().unwrap();
    assert!(speedup > 0.0, "{stdout}");
}

/// The rows of `bench`'s table, each as column name → text.
fn bench_rows(stdout: &str) -> Vec<std::collections::HashMap<String, String>> {
    let mut lines = stdout.lines();
    let header: Vec<&str> = lines
        .find(|l| l.starts_with("scene"))
        .unwrap_or_else(|| panic!("{stdout}"))
        .split_whitespace()
        .collect();
    lines
        .take_while(|l| l.split_whitespace().count() == header.len())
        .map(|l| {
            header
                .iter()
                .zip(l.split_whitespace())
                .map(|(h, v)| ((*h).to_owned(), v.to_owned()))
                .collect()
        })
        .collect()
}

#[test]
fn bench_runs_builtin_scenes_by_size() {
    let dir = tempfile::tempdir().unwrap();
    let args = [
        "bench",
        "--scene",
        "300",
        "--scene",
        "1k",
        "--size",
        "96x64",
        "--frames",
        "1",
        "--threads",
        "1",
        "--no-dense",
    ];
    let output = splat4d(&args, dir.path());
    assert!(output.status.success(), "{}", stderr(&output));
    let stdout = String::from_utf8_lossy(&output.stdout);
    let rows = bench_rows(&stdout);
    let kernels: Vec<&str> = rows.iter().map(|r| r["kernels"].as_str()).collect();
    assert_eq!(kernels, ["300", "1000"], "{stdout}");
    assert!(
        rows.iter()
            .all(|r| r["size"] == "96x64" && r["method"] == "tiles")
    );
    // Every row shows its share of the ceiling probe measured in the same run.
    for row in &rows {
        let share: f64 = row["ceiling"].trim_end_matches('%').parse().unwrap();
        assert!(share > 0.0 && share < 100.0, "{stdout}");
    }
    assert!(stdout.contains("ceiling probe ("), "{stdout}");
    let output = splat4d(&["bench", "--ceiling", "--threads", "1"], dir.path());
    assert!(output.status.success(), "{}", stderr(&output));
    let stdout = String::from_utf8_lossy(&output.stdout);
    // Both blends' probes, each on its own line.
    let rate = crate::common::probe_rate(&stdout, "ceiling probe", 1);
    assert!(rate > 1e7, "{stdout}");
    let alpha_rate = crate::common::probe_rate(&stdout, "alpha ceiling probe", 1);
    assert!(alpha_rate > 1e7, "{stdout}");
    assert_eq!(stdout.lines().count(), 2, "{stdout}");
    // SPLAT4D_SIMD names a narrower path for measuring it on a wider CPU; the baseline is
    // on every CPU. A value that names no path leaves the widest.
    for (name, expected) in [("baseline", "baseline"), ("no-such-path", "")] {
        let output = std::process::Command::new(env!("CARGO_BIN_EXE_splat4d"))
            .args(["bench", "--ceiling", "--threads", "1"])
            .env("SPLAT4D_SIMD", name)
            .current_dir(dir.path())
            .output()
            .unwrap();
        assert!(output.status.success(), "{}", stderr(&output));
        let stdout = String::from_utf8_lossy(&output.stdout);
        let path = stdout
            .lines()
            .next()
            .and_then(|l| l.split(" path").next())
            .and_then(|l| l.rsplit('(').next())
            .unwrap_or_default()
            .to_string();
        if expected.is_empty() {
            assert_ne!(path, "", "{stdout}");
        } else {
            assert_eq!(path, expected, "{stdout}");
        }
    }
    let output = splat4d(&["bench", "--scene", "no-such-scene.json"], dir.path());
    assert_eq!(output.status.code(), Some(2));
    assert!(stderr(&output).contains("no-such-scene.json"));
}

#[test]
fn bench_sweep_writes_a_table_and_a_chart_with_a_pareto_front() {
    let dir = tempfile::tempdir().unwrap();
    let args = [
        "bench",
        "--scene",
        "400",
        "--size",
        "64x48",
        "--frames",
        "1",
        "--samples",
        "100",
        "--threads",
        "1",
        "--sweep",
        "--out",
        "sweep",
    ];
    let output = splat4d(&args, dir.path());
    assert!(output.status.success(), "{}", stderr(&output));
    let table = std::fs::read_to_string(dir.path().join("sweep/sweep.md")).unwrap();
    let rows: Vec<&str> = table.lines().filter(|l| l.starts_with("| ")).collect();
    // A header and 6 cut-offs × 3 dilations × 2 exp modes.
    assert_eq!(rows.len(), 1 + 36, "{table}");
    assert!(rows.iter().any(|r| r.ends_with("★ |")), "{table}");
    // Error against the exact model falls as the cut-off falls, at the default dilation.
    let error_at = |cutoff: &str| -> f64 {
        let row = rows
            .iter()
            .find(|r| r.starts_with(&format!("| {cutoff} | 0.3 | std |")))
            .unwrap_or_else(|| panic!("{cutoff}: {table}"));
        row.split('|').nth(6).unwrap().trim().parse().unwrap()
    };
    assert!(error_at("1.000e-5") < error_at("1.000e-3"));
    assert!(error_at("1.000e-3") < error_at("3.000e-2"));
    let chart = image::open(dir.path().join("sweep/sweep.png")).unwrap();
    assert_eq!((chart.width(), chart.height()), (900, 560));
}

#[test]
fn exit_status_follows_the_kind_of_error() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (blob, camera) = (data("blob.json"), data("blob_camera.json"));
    let (blob, camera) = (blob.to_str().unwrap(), camera.to_str().unwrap());
    // Output: the folder of the output cannot be made (a file stands in its place).
    std::fs::write(d.join("file"), "x").unwrap();
    let output = splat4d(&render_args(blob, camera, "file/out.png"), d);
    assert_eq!(output.status.code(), Some(3), "{}", stderr(&output));
    assert!(
        stderr(&output).contains("file/out.png"),
        "{}",
        stderr(&output)
    );
    // Usage: an output that is a folder.
    std::fs::create_dir(d.join("folder.png")).unwrap();
    let output = splat4d(&render_args(blob, camera, "folder.png"), d);
    assert_eq!(output.status.code(), Some(2), "{}", stderr(&output));
    // A learning rate that would send a fit to infinity is refused before any work, the flag
    // named, and no output written (a fit that still leaves the finite numbers ends with
    // exit 4 naming the parameter group: `fit::train::non_finite_parameter`).
    let dataset = [
        "dataset", "--scene", blob, "--views", "4", "--times", "2", "--size", "16x16", "--out",
        "set",
    ];
    assert!(splat4d(&dataset, d).status.success());
    let fit = [
        "fit",
        "--views",
        "set",
        "--init",
        "random:4",
        "--steps",
        "20",
        "--lr-amplitude",
        "1e300",
        "--out",
        "fit.json",
    ];
    let output = splat4d(&fit, d);
    assert_eq!(output.status.code(), Some(2), "{}", stderr(&output));
    assert!(
        stderr(&output).contains("--lr-amplitude 1e300"),
        "{}",
        stderr(&output)
    );
    assert!(!d.join("fit.json").exists());
}

#[test]
fn export_ply_warns_about_what_splat_viewers_cannot_show() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(
        d.join("s.json"),
        r#"{"kernels": [{"mean": [0, 0, 0, 0], "scale": [0.1, 0.1, 0.1, 1], "amplitude": [-0.5, 0.2, 0.2]},
                        {"mean": [1, 0, 0, 0], "scale": [0.1, 0.1, 0.1, 1], "amplitude": [0.5, 0.2, 0.2]}],
            "background": [1, 1, 1]}"#,
    )
    .unwrap();
    let args = [
        "export-ply",
        "--scene",
        "s.json",
        "--time",
        "0",
        "--out",
        "s.ply",
    ];
    let output = splat4d(&args, d);
    assert!(output.status.success(), "{}", stderr(&output));
    let message = stderr(&output);
    assert!(
        message.contains("1 of 2 kernels have negative amplitudes"),
        "{message}"
    );
    assert!(message.contains("background (1, 1, 1)"), "{message}");
    // A scene a viewer shows as it is: no warning.
    std::fs::write(
        d.join("t.json"),
        r#"{"kernels": [{"mean": [0, 0, 0, 0], "scale": [0.1, 0.1, 0.1, 1], "amplitude": [0.5, 0.2, 0.2]}]}"#,
    )
    .unwrap();
    let args = [
        "export-ply",
        "--scene",
        "t.json",
        "--time",
        "0",
        "--out",
        "t.ply",
    ];
    let output = splat4d(&args, d);
    assert!(output.status.success());
    assert!(!stderr(&output).contains("warning"), "{}", stderr(&output));
}
