//! Nothing non-finite leaves with exit 0 (issue 23): writers refuse what they cannot write
//! finitely, inputs finite but absurd are refused up front naming the file, frame and field,
//! and messages name the real culprit. Each test is a reproducer, from flags and bytes.

use std::path::Path;
use std::process::{Command, Output};

use crate::common::data;
use crate::common::{blob_dataset, refused_quickly};

fn run(args: &[&str], cwd: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_splat4d"))
        .args(args)
        .current_dir(cwd)
        .output()
        .unwrap()
}

/// Exit status `code`, every needle in the message, and no panic.
fn refused(output: &Output, code: i32, needles: &[&str]) -> String {
    let stderr = String::from_utf8_lossy(&output.stderr).into_owned();
    assert_eq!(output.status.code(), Some(code), "{stderr}");
    for needle in needles {
        assert!(stderr.contains(needle), "{needle:?} in {stderr}");
    }
    assert!(!stderr.contains("panicked"), "{stderr}");
    stderr
}

fn blob_json() -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(data("blob.json")).unwrap()).unwrap()
}

#[test]
fn writers_refuse_values_they_cannot_hold() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let camera = data("blob_camera.json");
    // A finite scene whose background overflows f32: no EXR of +inf.
    let mut scene = blob_json();
    scene["background"] = serde_json::json!([1e308, 0.0, 0.0]);
    std::fs::write(d.join("bright.json"), scene.to_string()).unwrap();
    for out in ["bright.exr", "bright.png"] {
        let output = run(
            &[
                "render",
                "--scene",
                "bright.json",
                "--camera",
                camera.to_str().unwrap(),
                "--time",
                "0.5",
                "--out",
                out,
            ],
            d,
        );
        refused(&output, 4, &[out, "not written", "not finite"]);
        assert!(!d.join(out).exists());
    }
    // A kernel at x = 1e300: no 3DGS PLY of +inf.
    let mut scene = blob_json();
    scene["kernels"][0]["mean"][0] = serde_json::json!(1e300);
    std::fs::write(d.join("far.json"), scene.to_string()).unwrap();
    let output = run(
        &[
            "export-ply",
            "--scene",
            "far.json",
            "--time",
            "0.5",
            "--cutoff",
            "0",
            "--out",
            "far.ply",
        ],
        d,
    );
    refused(&output, 4, &["far.ply", "kernel 0", "`x`"]);
    assert!(!d.join("far.ply").exists());
}

/// Writes the blob dataset (4 views × 2 times, 8×8) into `d/ds`.
fn dataset(d: &Path) {
    let blob = data("blob.json");
    let output = run(
        &[
            "dataset",
            "--scene",
            blob.to_str().unwrap(),
            "--views",
            "4",
            "--times",
            "2",
            "--size",
            "8x8",
            "--out",
            "ds",
        ],
        d,
    );
    assert!(output.status.success());
}

/// `ds/transforms_train.json` changed by `edit`, into a copy of the dataset at `name`.
fn edited(d: &Path, name: &str, edit: impl Fn(&mut serde_json::Value)) {
    let copy = d.join(name);
    std::fs::create_dir_all(copy.join("train")).unwrap();
    for entry in std::fs::read_dir(d.join("ds/train")).unwrap() {
        let entry = entry.unwrap();
        std::fs::copy(entry.path(), copy.join("train").join(entry.file_name())).unwrap();
    }
    let mut file: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("ds/transforms_train.json")).unwrap())
            .unwrap();
    edit(&mut file);
    std::fs::write(copy.join("transforms_train.json"), file.to_string()).unwrap();
}

#[test]
fn absurd_inputs_to_a_fit_are_refused_naming_their_source() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    dataset(d);
    let fit = |views: &str, extra: &[&str]| {
        let mut args = vec![
            "fit", "--views", views, "--steps", "2", "--init", "random:4", "--out", "f.json",
        ];
        args.extend_from_slice(extra);
        run(&args, d)
    };
    // Rates and backgrounds no fit survives: the flag named, before any work.
    refused(&fit("ds", &["--lr-mean=1e308"]), 2, &["--lr-mean 1e308"]);
    refused(
        &fit("ds", &["--background", "1e30,0,0"]),
        2,
        &["--background"],
    );
    // Focal lengths: the file, frame and field, never a flag that was not given.
    edited(d, "wide", |f| f["fl_x"] = serde_json::json!(1e30));
    let message = refused(
        &fit("wide", &[]),
        2,
        &["transforms_train.json", "frame 0", "fl_x"],
    );
    assert!(!message.contains("--box"), "{message}");
    edited(d, "narrow", |f| f["fl_y"] = serde_json::json!(1e-320));
    let message = refused(&fit("narrow", &[]), 2, &["frame 0", "fl_y"]);
    assert!(!message.contains("--box"), "{message}");
    // Frame times ±1e308 are finite; their span is not.
    edited(d, "times", |f| {
        let frames = f["frames"].as_array_mut().unwrap();
        let n = frames.len();
        frames[0]["time"] = serde_json::json!(-1e308);
        frames[n - 1]["time"] = serde_json::json!(1e308);
    });
    let message = refused(&fit("times", &[]), 2, &["`time`", "frames"]);
    assert!(!message.contains("not finite and ordered"), "{message}");
    // A 100 000-character camera model is quoted cut.
    edited(d, "model", |f| {
        f["camera_model"] = serde_json::json!("X".repeat(100_000));
    });
    let message = refused(
        &fit("model", &[]),
        2,
        &["camera_model", "characters in all"],
    );
    assert!(message.len() < 1000, "{} characters", message.len());
    assert!(!d.join("f.json").exists());
}

#[test]
fn a_truncated_jpeg_is_refused_like_a_truncated_png() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cut.jpg");
    let image = image::RgbImage::from_fn(64, 64, |x, y| {
        image::Rgb([(x * 4) as u8, (y * 4) as u8, 90])
    });
    let mut bytes = Vec::new();
    image
        .write_to(
            &mut std::io::Cursor::new(&mut bytes),
            image::ImageFormat::Jpeg,
        )
        .unwrap();
    std::fs::write(&path, &bytes).unwrap();
    let whole = splat4d::io::image_file::load_image(&path, [0.0; 3]).unwrap();
    assert_eq!((whole.width, whole.height), (64, 64));
    std::fs::write(&path, &bytes[..bytes.len() * 2 / 3]).unwrap();
    let error = splat4d::io::image_file::load_image(&path, [0.0; 3])
        .unwrap_err()
        .to_string();
    assert!(
        error.contains("cut.jpg") && error.contains("truncated"),
        "{error}"
    );
}

#[test]
fn an_empty_frames_list_names_the_file_that_has_it() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::create_dir(d.join("cap")).unwrap();
    std::fs::write(d.join("cap/transforms.json"), r#"{"frames": []}"#).unwrap();
    let output = run(&["fit", "--views", "cap", "--out", "f.json"], d);
    let message = refused(&output, 2, &["transforms.json", "frames", "empty"]);
    assert!(!message.contains("transforms_train.json"), "{message}");
}

// Limits through the executable (from the former limits.rs): refused quickly, with a
// message and exit status, never a panic, a hang or an unbounded allocation.

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
        refused_quickly(
            &[
                "fit", "--views", "ds", "--steps", "3", "--out", "f.json", flag,
            ],
            d,
            2,
            "not finite",
        );
    }
    refused_quickly(
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
    refused_quickly(
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
    refused_quickly(
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
