//! The fourth attack round's messages: values quoted at most 300 characters, errors that name
//! the file's own property (a 3DGS PLY's `scale_0`, a point cloud's `red`), and arithmetic on
//! finite extremes (times of ±1e308) that stays finite or is refused naming the field.

use crate::common::{data, run_limited};
use splat4d::model::error::MAX_QUOTE;
use std::path::Path;

/// A graphdeco 3DGS PLY of one vertex with the given values of its 14 required properties
/// (`x y z f_dc_0..2 opacity scale_0..2 rot_0..3`), float32, little endian.
fn gaussian_ply(values: [f32; 14]) -> Vec<u8> {
    let mut bytes = String::from("ply\nformat binary_little_endian 1.0\nelement vertex 1\n");
    for name in splat4d::io::ply::GAUSSIAN_3D_PROPERTIES {
        bytes.push_str(&format!("property float {name}\n"));
    }
    bytes.push_str("end_header\n");
    let mut bytes = bytes.into_bytes();
    for v in values {
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    bytes
}

const GOOD_SPLAT: [f32; 14] = [
    0.0, 0.0, 0.0, 0.1, 0.2, 0.3, 0.5, -2.0, -2.0, -2.0, 1.0, 0.0, 0.0, 0.0,
];

#[test]
fn a_3dgs_ply_error_names_the_files_property_not_the_converted_field() {
    let good = splat4d::io::ply::parse_scene_ply(&gaussian_ply(GOOD_SPLAT), "g.ply");
    assert!(good.is_ok(), "{:?}", good.err());
    // (index in the row, value, the property the message must name)
    let cases: [(usize, f32, &str); 5] = [
        (7, 1000.0, "scale_0"),
        (9, -1000.0, "scale_2"),
        (3, f32::NAN, "f_dc_0"),
        (6, f32::INFINITY, "opacity"),
        (12, f32::NAN, "rot_2"),
    ];
    for (index, value, property) in cases {
        let mut row = GOOD_SPLAT;
        row[index] = value;
        let message = splat4d::io::ply::parse_scene_ply(&gaussian_ply(row), "g.ply")
            .expect_err("must be refused")
            .to_string();
        assert!(
            message.contains("g.ply")
                && message.contains("vertex 0")
                && message.contains(&format!("`{property}`")),
            "{property} = {value}: {message}"
        );
        assert!(!message.contains("scale["), "{message}");
    }
}

/// A point cloud of one vertex with float colours.
fn float_colour_cloud(colour: [f32; 3]) -> Vec<u8> {
    let mut bytes = b"ply\nformat binary_little_endian 1.0\nelement vertex 1\n\
property float x\nproperty float y\nproperty float z\n\
property float red\nproperty float green\nproperty float blue\nend_header\n"
        .to_vec();
    for v in [0.0, 0.0, 0.0].into_iter().chain(colour) {
        bytes.extend_from_slice(&f32::to_le_bytes(v));
    }
    bytes
}

#[test]
fn a_non_finite_point_colour_is_named_in_the_cloud_not_in_the_start() {
    let read = |colour| {
        splat4d::io::point_cloud::parse_point_cloud(&float_colour_cloud(colour), "points.ply")
    };
    assert!(read([0.2, 0.4, 0.6]).is_ok());
    let message = read([0.2, f32::NAN, 0.6]).expect_err("NaN").to_string();
    assert!(
        message.contains("points.ply")
            && message.contains("vertex 0")
            && message.contains("`green`"),
        "{message}"
    );
    let message = read([0.2, 0.4, f32::INFINITY])
        .expect_err("inf")
        .to_string();
    assert!(message.contains("`blue`"), "{message}");
}

#[test]
fn a_missing_frames_long_name_is_quoted_cut_in_the_note() {
    let dir = tempfile::tempdir().unwrap();
    crate::common::blob_dataset(dir.path(), "2");
    let transforms = dir.path().join("ds/transforms_train.json");
    let mut json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&transforms).unwrap()).unwrap();
    let long_name = format!("./{}", "x".repeat(100_000));
    let frames = json["frames"].as_array_mut().unwrap();
    let mut missing = frames[0].clone();
    missing["file_path"] = serde_json::Value::String(long_name);
    frames.push(missing);
    std::fs::write(&transforms, serde_json::to_string(&json).unwrap()).unwrap();
    let dataset = splat4d::io::dataset::load_dataset(&dir.path().join("ds"), &Default::default())
        .expect("the other frames load");
    let notes = dataset.notes.join("\n");
    assert!(notes.contains("skipped 1 frame"), "{notes}");
    assert!(notes.contains("100002 characters in all"), "{notes}");
    assert!(
        notes.chars().count() < 2 * MAX_QUOTE + 400,
        "{} characters",
        notes.len()
    );
}

/// A scene of two kernels at times -1e308 and 1e308.
fn extreme_times_scene(dir: &Path) -> std::path::PathBuf {
    let path = dir.join("extreme.json");
    std::fs::write(
        &path,
        r#"{"kernels":[
            {"mean":[0,0,0,-1e308],"scale":[0.3,0.3,0.3,1e308],"amplitude":[1,0.5,0.2]},
            {"mean":[0.2,0,0,1e308],"scale":[0.3,0.3,0.3,1e308],"amplitude":[0.2,0.5,1]}]}"#,
    )
    .unwrap();
    path
}

#[test]
fn a_scene_spanning_plus_minus_1e308_exports_finite_times_and_short_file_names() {
    let dir = tempfile::tempdir().unwrap();
    let scene = extreme_times_scene(dir.path());
    let output = run_limited(
        &[
            "export-ply",
            "--scene",
            scene.to_str().unwrap(),
            "--frames",
            "3",
            "--out",
            "seq",
        ],
        dir.path(),
    );
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    let index = std::fs::read_to_string(dir.path().join("seq/frames.json")).unwrap();
    assert!(!index.contains("null"), "{index}");
    let index: serde_json::Value = serde_json::from_str(&index).unwrap();
    let times: Vec<f64> = index["frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f["time"].as_f64().expect("a number"))
        .collect();
    assert_eq!(times, [-1e308, 0.0, 1e308]);

    let output = run_limited(
        &[
            "video",
            "--scene",
            scene.to_str().unwrap(),
            "--orbit",
            "0,0,0,3,10,2",
            "--size",
            "16x16",
            "--no-mp4",
            "--out",
            "video",
        ],
        dir.path(),
    );
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    for entry in std::fs::read_dir(dir.path().join("video")).unwrap() {
        let name = entry.unwrap().file_name().to_string_lossy().into_owned();
        assert!(name.len() < 64, "{name}");
    }
    assert!(dir.path().join("video/orbit_t1.00e308.gif").exists());
}

#[test]
fn a_time_range_whose_span_overflows_is_refused_in_few_words() {
    let message = splat4d::io::scene_file::scene_from_json(
        r#"{"kernels":[],"time_range":[-1e308,1e308]}"#,
        "s.json",
    )
    .expect_err("the span overflows")
    .to_string();
    assert!(
        message.contains("s.json") && message.contains("`time_range`"),
        "{message}"
    );
    assert!(
        message.len() < 200,
        "{} characters: {message}",
        message.len()
    );
    assert!(data("blob.json").exists());
}
