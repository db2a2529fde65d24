//! Every kind of bad scene, camera and option is refused with a message that names the
//! origin, the item (kernel index or camera) and the field.

use splat4d::{Camera, RenderOptions};

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
