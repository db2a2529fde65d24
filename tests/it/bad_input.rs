//! Every kind of bad scene, camera and option is refused with a message that names the
//! origin, the item (kernel index or camera) and the field.

use crate::common::{blob_dataset, data, refused_quickly, run_limited};
use splat4d::{Camera, RenderOptions};
use std::path::Path;

const GOOD_KERNEL: &str = r#"{"mean":[0,0,0,0],"scale":[1,1,1,1],"amplitude":[1,1,1]}"#;

fn scene_with_second_kernel(kernel: &str) -> String {
    format!(r#"{{"kernels":[{GOOD_KERNEL},{kernel}]}}"#)
}

fn scene_error(text: &str) -> String {
    splat4d::io::scene_file::scene_from_json(text, "s.json")
        .expect_err("must be refused")
        .to_string()
}

fn assert_mentions(message: &str, parts: &[&str]) {
    for part in parts {
        assert!(
            message.contains(part),
            "`{message}` should mention `{part}`"
        );
    }
}

#[test]
fn bad_kernels_name_the_file_the_kernel_and_the_field() {
    let cases: &[(&str, &[&str])] = &[
        (
            r#"{"mean":[0,0,1e999,0],"scale":[1,1,1,1],"amplitude":[1,1,1]}"#,
            &["kernel 1", "mean[2]", "out of range"],
        ),
        (
            r#"{"mean":[0,0,0,0],"scale":[1,0,1,1],"amplitude":[1,1,1]}"#,
            &["kernel 1", "`scale`", "scale[1] = 0 must be > 0"],
        ),
        (
            r#"{"mean":[0,0,0,0],"scale":[1,1,1,-2],"amplitude":[1,1,1]}"#,
            &["kernel 1", "`scale`", "must be > 0"],
        ),
        (
            r#"{"mean":[0,0,0,0],"scale":[1,1,1,1],"amplitude":[1,1,1],"rotation":[0,0,0,0]}"#,
            &["kernel 1", "`rotation`", "zero"],
        ),
        (
            r#"{"mean":[0,0,0,0],"scale":[1,1,1,1],"amplitude":[1,1,1],"colour":[1,1,1]}"#,
            &["kernel 1", "colour", "unknown field"],
        ),
        (
            r#"{"mean":[0,0,0],"scale":[1,1,1,1],"amplitude":[1,1,1]}"#,
            &["kernel 1", "mean", "length 3"],
        ),
        (
            r#"{"mean":[0,0,0,0],"amplitude":[1,1,1]}"#,
            &["kernel 1", "missing field `scale`"],
        ),
        (
            r#"{"mean":[0,0,"x",0],"scale":[1,1,1,1],"amplitude":[1,1,1]}"#,
            &["kernel 1", "mean[2]", "invalid type"],
        ),
        (
            r#"{"mean":[0,0,0,0],"scale":[1,1,1,1],"amplitude":[1,1,1],"velocity":[1,-1e400,0]}"#,
            &["kernel 1", "velocity[1]"],
        ),
    ];
    for (kernel, parts) in cases {
        let message = scene_error(&scene_with_second_kernel(kernel));
        assert_mentions(&message, &[&["s.json"][..], parts].concat());
    }
}

#[test]
fn bad_scene_documents_are_refused() {
    assert_mentions(&scene_error("{\"kernels\": ["), &["s.json", "EOF"]);
    assert_mentions(&scene_error("3"), &["s.json", "invalid type"]);
    assert_mentions(&scene_error("[]"), &["s.json", "expected a scene object"]);
    assert_mentions(
        &scene_error(r#"{"kernels":[],"extra":1}"#),
        &["s.json", "unknown field `extra`"],
    );
    assert_mentions(
        &scene_error(r#"{"kernels":[],"background":[0,1e999,0]}"#),
        &["s.json", "background[1]"],
    );
    assert_mentions(
        &scene_error(r#"{"kernels":[]} trailing"#),
        &["s.json", "trailing"],
    );
    // In-memory scenes go through the same checks.
    let mut scene =
        splat4d::io::scene_file::scene_from_json(&scene_with_second_kernel(GOOD_KERNEL), "s.json")
            .unwrap();
    scene.means[1][3] = f64::NAN;
    assert_mentions(
        &scene.validate("<edited>").unwrap_err().to_string(),
        &["<edited>", "kernel 1", "`mean`", "not finite"],
    );
}

#[test]
fn missing_optional_fields_take_their_defaults_and_rotations_are_normalised() {
    let scene = splat4d::io::scene_file::scene_from_json(
        &scene_with_second_kernel(
            r#"{"mean":[0,0,0,0],"scale":[1,1,1,1],"amplitude":[1,1,1],"rotation":[2,0,0,0]}"#,
        ),
        "s.json",
    )
    .unwrap();
    assert_eq!(scene.rotations, vec![[1.0, 0.0, 0.0, 0.0]; 2]);
    assert_eq!(scene.velocities, vec![[0.0; 3]; 2]);
    assert_eq!(scene.background, [0.0; 3]);
    let round_trip = splat4d::io::scene_file::scene_from_json(
        &splat4d::io::scene_file::scene_to_json(&scene),
        "again",
    )
    .unwrap();
    assert_eq!(round_trip, scene);
}

const GOOD_CAMERA: &str = r#"{"width":4,"height":3,"fx":2,"fy":2,"cx":2,"cy":1.5,
  "world_to_camera":[[1,0,0,0],[0,1,0,0],[0,0,1,3],[0,0,0,1]]"#;

fn camera_error(extra: &str) -> String {
    let text = format!("{GOOD_CAMERA}{extra}}}");
    splat4d::io::camera_file::camera_from_json(&text, "c.json")
        .expect_err("must be refused")
        .to_string()
}

fn camera_with(field: &str, value: &str) -> String {
    let text = format!("{GOOD_CAMERA}}}");
    let mut json: serde_json::Value = serde_json::from_str(&text).unwrap();
    json[field] = serde_json::from_str(value).unwrap();
    splat4d::io::camera_file::camera_from_json(&json.to_string(), "c.json")
        .expect_err("must be refused")
        .to_string()
}

#[test]
fn bad_cameras_name_the_file_and_the_field() {
    let good =
        splat4d::io::camera_file::camera_from_json(&format!("{GOOD_CAMERA}}}"), "c.json").unwrap();
    assert_eq!((good.near, good.far), (0.01, 1e6));
    assert_mentions(&camera_with("width", "0"), &["c.json", "camera", "`width`"]);
    assert_mentions(
        &camera_with("height", "0"),
        &["c.json", "camera", "`height`"],
    );
    assert_mentions(
        &camera_with("width", "-3"),
        &["c.json", "camera", "width", "invalid value"],
    );
    let huge = format!("{GOOD_CAMERA}}}").replace(
        r#""width":4,"height":3"#,
        r#""width":100000,"height":100000"#,
    );
    let message = splat4d::io::camera_file::camera_from_json(&huge, "c.json")
        .unwrap_err()
        .to_string();
    assert_mentions(&message, &["c.json", "`width`", "16384²"]);
    assert_mentions(&camera_with("fx", "0"), &["c.json", "`fx`", "must be > 0"]);
    assert_mentions(&camera_with("fy", "-1"), &["c.json", "`fy`", "must be > 0"]);
    let huge_cx = format!("{}}}", GOOD_CAMERA.replace(r#""cx":2"#, r#""cx":1e999"#));
    let message = splat4d::io::camera_file::camera_from_json(&huge_cx, "c.json")
        .unwrap_err()
        .to_string();
    assert_mentions(&message, &["c.json", "camera", "`cx`", "out of range"]);
    assert_mentions(
        &camera_with(
            "world_to_camera",
            "[[1,0,0,0],[1,0,0,0],[0,0,1,3],[0,0,0,1]]",
        ),
        &["c.json", "`world_to_camera`", "not invertible"],
    );
    assert_mentions(
        &camera_with(
            "world_to_camera",
            "[[1,0,0,0],[0,1,0,0],[0,0,1,3],[0,0,1,1]]",
        ),
        &["c.json", "`world_to_camera`", "last row"],
    );
    assert_mentions(
        &camera_with("world_to_camera", "[[1,0,0,0],[0,1,0,0],[0,0,1,3]]"),
        &["c.json", "world_to_camera", "length 3"],
    );
    assert_mentions(
        &camera_with("near", "0"),
        &["c.json", "`near`", "0 < near < far"],
    );
    assert_mentions(
        &camera_with("far", "0.001"),
        &["c.json", "`near`", "0 < near < far"],
    );
    assert_mentions(
        &camera_error(r#","lens":"wide""#),
        &["c.json", "unknown field `lens`"],
    );
    assert_mentions(
        &camera_error(r#","fx":3"#),
        &["c.json", "duplicate field `fx`"],
    );
    let missing = splat4d::io::camera_file::camera_from_json(r#"{"width":4}"#, "c.json")
        .unwrap_err()
        .to_string();
    assert_mentions(&missing, &["c.json", "missing field"]);
}

#[test]
fn bad_render_options_and_look_at_are_refused() {
    for options in [
        RenderOptions {
            dilation: -0.1,
            cutoff: 0.0,
            ..Default::default()
        },
        RenderOptions {
            dilation: f64::NAN,
            cutoff: 0.0,
            ..Default::default()
        },
        RenderOptions {
            dilation: 0.3,
            cutoff: -1.0,
            ..Default::default()
        },
        RenderOptions {
            dilation: 0.3,
            cutoff: f64::INFINITY,
            ..Default::default()
        },
    ] {
        assert!(options.validate().is_err(), "{options:?} must be refused");
    }
    assert!(Camera::look_at([0.0; 3], [0.0; 3], [0.0, 1.0, 0.0], 40.0, 8, 8).is_err());
    assert!(Camera::look_at([0.0; 3], [0.0, 1.0, 0.0], [0.0, 1.0, 0.0], 40.0, 8, 8).is_err());
    assert!(Camera::look_at([0.0; 3], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0], 180.0, 8, 8).is_err());
}

#[test]
fn scene_files_round_trip_bit_exactly() {
    let camera = crate::common::test_camera(32, 32);
    let scene = crate::common::hard_random_scene(&camera, 8, 300);
    let again = splat4d::io::scene_file::scene_from_json(
        &splat4d::io::scene_file::scene_to_json(&scene),
        "again",
    )
    .unwrap();
    for i in 0..scene.len() {
        assert_eq!(
            again.kernel(i),
            scene.kernel(i),
            "kernel {i}: save → load must give the same bits"
        );
    }
    assert_eq!(again, scene);
    let camera_again = splat4d::io::camera_file::camera_from_json(
        &splat4d::io::camera_file::camera_to_json(&camera),
        "again",
    )
    .unwrap();
    assert_eq!(camera_again, camera);
}

// Limits through the executable (from the former limits.rs): refused quickly, with a
// message and exit status, never a panic, a hang or an unbounded allocation.

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
    refused_quickly(
        &dataset(&["--views", huge, "--times", "2", "--size", "8x8"]),
        d,
        2,
        "--views",
    );
    refused_quickly(
        &dataset(&["--views", "2", "--times", huge, "--size", "8x8"]),
        d,
        2,
        "--times",
    );
    // Found by the second fuzzing round: a random start's count allocated unchecked.
    let views = tempfile::tempdir().unwrap();
    blob_dataset(views.path(), "2");
    let init = format!("random:{huge}");
    refused_quickly(
        &["fit", "--views", "ds", "--init", &init, "--out", "f.json"],
        views.path(),
        2,
        "--init",
    );
    refused_quickly(
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
        refused_quickly(&args, d, 2, "fov");
    }
    refused_quickly(
        &dataset(&["--views", "2", "--times", "2", "--size", "16385x16385"]),
        d,
        2,
        "--size",
    );
    refused_quickly(
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
    refused_quickly(&args, d, 2, "--kernels");
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
    refused_quickly(&render, d, 2, "--threads");
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
    refused_quickly(&args, d, 2, "20000×20000");
    // A float image with a NaN: refused naming the pixel.
    let mut pixels = vec![0.25_f32; 320 * 240 * 3];
    pixels[3 * (7 * 320 + 5)] = f32::NAN;
    let image = image::Rgb32FImage::from_raw(320, 240, pixels).unwrap();
    image::DynamicImage::ImageRgb32F(image)
        .save(d.join("nan.exr"))
        .unwrap();
    let args = grad("nan.exr");
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    refused_quickly(&args, d, 2, "pixel (5, 7)");
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
    let output = run_limited(&render, d);
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
    let output = run_limited(&render, d);
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
    refused_quickly(&render, d, 2, "only `binary_little_endian 1.0`");
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
        let output = run_limited(&args, d);
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
