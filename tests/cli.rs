//! The `splat4d` executable on the shipped fixtures in `data/`: outputs, formats, the
//! default job, and bad input (exit status 2, a message naming file and field, no output).

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use splat4d::io::image_file::{load_image, quantize};
use splat4d::{Camera, RenderOptions, Scene, render};

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("data")
        .join(name)
}

fn splat4d(args: &[&str], cwd: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_splat4d"))
        .args(args)
        .current_dir(cwd)
        .output()
        .expect("the executable runs")
}

fn render_args<'a>(scene: &'a str, camera: &'a str, out: &'a str) -> Vec<&'a str> {
    vec![
        "render", "--scene", scene, "--camera", camera, "--time", "0.5", "--out", out,
    ]
}

fn blob_image() -> splat4d::Image {
    let scene = Scene::load(&data("blob.json")).unwrap();
    let camera = Camera::load(&data("blob_camera.json")).unwrap();
    render(&scene, &camera, 0.5, &RenderOptions::default()).unwrap()
}

fn stderr(output: &Output) -> String {
    String::from_utf8_lossy(&output.stderr).into_owned()
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

#[test]
fn default_job_renders_the_blob_into_out() {
    let dir = tempfile::tempdir().unwrap();
    let output = splat4d(&[], dir.path());
    assert!(output.status.success(), "{}", stderr(&output));
    assert_eq!(
        files_in(&dir.path().join("out")),
        ["blob_t0.00.png", "blob_t0.50.png", "blob_t1.00.png"]
    );
    let image = load_image(&dir.path().join("out/blob_t0.50.png"), [0.0; 3]).unwrap();
    let expected = blob_image();
    let quantized: Vec<f32> = expected
        .pixels
        .iter()
        .map(|&c| f32::from(quantize(c, 255)) / 255.0)
        .collect();
    assert_eq!(image.pixels, quantized);
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
}
