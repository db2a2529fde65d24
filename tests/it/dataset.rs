//! The D-NeRF / Blender dataset layout: what is written reads back as the same cameras,
//! times and images; other tools' RGBA PNGs are composited over the background.

use crate::common::{data, refused_quickly, run_blob_dataset};
use splat4d::RenderOptions;
use splat4d::io::dataset::{DatasetOptions, SPLITS, load_dataset, write_split};
use splat4d::scenes::dataset::{DatasetSpec, frame_count, render_dataset};

#[test]
fn cameras_times_and_images_round_trip() {
    let scene =
        splat4d::io::scene_file::scene_from_json(include_str!("../../data/blob.json"), "blob")
            .unwrap();
    let spec = DatasetSpec {
        views: 5,
        times: 3,
        width: 40,
        height: 30,
        seed: 9,
        ..DatasetSpec::default()
    };
    let written = render_dataset(&scene, &spec, &RenderOptions::default(), || {}).unwrap();
    assert_eq!(
        written.train.len() + written.val.len() + written.test.len(),
        frame_count(&spec)
    );
    // Test cameras are not training cameras; test and val times lie between training times.
    let train_times: Vec<f64> = written.train.iter().map(|v| v.time).collect();
    for view in written.test.iter().chain(&written.val) {
        assert!(
            !train_times.contains(&view.time),
            "{} at a training time",
            view.name
        );
        if written.test.iter().any(|t| t.name == view.name) {
            assert!(
                written.train.iter().all(|t| t.camera != view.camera),
                "{} reuses a training camera",
                view.name
            );
        }
    }
    for exr in [false, true] {
        let dir = tempfile::tempdir().unwrap();
        for (split, views) in SPLITS
            .iter()
            .zip([&written.train, &written.val, &written.test])
        {
            write_split(dir.path(), split, views, exr).unwrap();
        }
        let read = load_dataset(dir.path(), &DatasetOptions::default()).unwrap();
        assert!(!read.transparent);
        for (a_views, b_views) in [
            (&written.train, &read.train),
            (&written.val, &read.val),
            (&written.test, &read.test),
        ] {
            assert_eq!(a_views.len(), b_views.len());
            for (a, b) in a_views.iter().zip(b_views) {
                assert_eq!(a.time, b.time);
                assert_eq!(a.name, b.name);
                let (ca, cb) = (&a.camera, &b.camera);
                assert_eq!((ca.width, ca.height), (cb.width, cb.height));
                for (x, y) in [ca.fx, ca.fy, ca.cx, ca.cy]
                    .iter()
                    .zip([cb.fx, cb.fy, cb.cx, cb.cy])
                {
                    assert!(
                        (x - y).abs() <= 1e-12 * x.abs().max(1.0),
                        "intrinsics {x} vs {y}"
                    );
                }
                for (x, y) in ca
                    .world_to_camera
                    .iter()
                    .flatten()
                    .zip(cb.world_to_camera.iter().flatten())
                {
                    assert!(
                        (x - y).abs() <= 1e-12,
                        "{}: world_to_camera {x} vs {y}",
                        a.name
                    );
                }
                // EXR is exact; 16-bit PNG within half a step of the clamped value.
                let tolerance = if exr { 0.0 } else { 0.5 / 65535.0 + 1e-7 };
                for (x, y) in a.image.pixels.iter().zip(&b.image.pixels) {
                    assert!(
                        (x.clamp(0.0, 1.0) - y).abs() <= tolerance,
                        "{}: pixel {x} vs {y}",
                        a.name
                    );
                }
            }
        }
    }
}

#[test]
fn rgba_pngs_of_other_datasets_are_composited_over_the_background() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir(dir.path().join("train")).unwrap();
    // 2×1: an opaque red pixel and a half-transparent green one, 8-bit RGBA.
    let rgba = image::RgbaImage::from_raw(2, 1, vec![255, 0, 0, 255, 0, 255, 0, 51]).unwrap();
    rgba.save(dir.path().join("train/r_000.png")).unwrap();
    std::fs::write(
        dir.path().join("transforms_train.json"),
        r#"{"camera_angle_x": 0.6911112070083618, "frames": [{"file_path": "./train/r_000", "rotation": 0.0314, "time": 0.25,
            "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,4],[0,0,0,1]]}]}"#,
    )
    .unwrap();
    let over_white = DatasetOptions {
        background: [1.0; 3],
        ..DatasetOptions::default()
    };
    let white = load_dataset(dir.path(), &over_white).unwrap();
    assert!(white.transparent);
    assert!(
        white.notes.is_empty(),
        "rotation is a known key: {:?}",
        white.notes
    );
    let view = &white.train[0];
    assert_eq!(view.time, 0.25);
    let expected = [1.0, 0.0, 0.0, 0.8, 1.0, 0.8];
    assert!(
        view.image
            .pixels
            .iter()
            .zip(expected)
            .all(|(a, b)| (a - b).abs() < 1e-6),
        "{:?}",
        view.image.pixels
    );
    // OpenGL camera at z = 4 looking down -z: OpenCV world→camera flips y and z.
    let m = view.camera.world_to_camera;
    assert_eq!(m[2], [0.0, 0.0, -1.0, 4.0]);
    assert!((view.camera.fx - 1.0 / (0.5_f64 * 0.6911112070083618).tan()).abs() < 1e-12);
}

// Limits through the executable (from the former limits.rs): refused quickly, with a
// message and exit status, never a panic, a hang or an unbounded allocation.

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
    refused_quickly(
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

/// `--monocular` (D-NeRF's layout): one camera per training time, no val split, each test
/// camera new and at a time of its own; a spec whose views and times differ is refused
/// naming both.
#[test]
fn a_monocular_dataset_has_one_camera_per_time() {
    let scene =
        splat4d::io::scene_file::scene_from_json(include_str!("../../data/blob.json"), "blob")
            .unwrap();
    let spec = DatasetSpec {
        views: 8,
        times: 8,
        width: 24,
        height: 24,
        monocular: true,
        ..DatasetSpec::default()
    };
    let written = render_dataset(&scene, &spec, &RenderOptions::default(), || {}).unwrap();
    assert_eq!(
        (written.train.len(), written.val.len(), written.test.len()),
        (8, 0, 2)
    );
    assert_eq!(written.train.len() + written.test.len(), frame_count(&spec));
    let mut times: Vec<f64> = written.train.iter().map(|v| v.time).collect();
    times.dedup();
    assert_eq!(times.len(), 8, "{times:?}");
    let centres: Vec<[f64; 3]> = written.train.iter().map(|v| v.camera.centre()).collect();
    for (i, a) in centres.iter().enumerate() {
        for b in &centres[i + 1..] {
            assert_ne!(a, b);
        }
    }
    let test_times: Vec<f64> = written.test.iter().map(|v| v.time).collect();
    assert_eq!(test_times, vec![0.25, 0.75]);
    let message = render_dataset(
        &scene,
        &DatasetSpec { times: 5, ..spec },
        &RenderOptions::default(),
        || {},
    )
    .unwrap_err()
    .to_string();
    assert!(
        message.contains("`views` 8 must equal `times` 5"),
        "{message}"
    );
}
