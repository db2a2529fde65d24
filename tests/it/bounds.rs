//! Every count bounded and every decode shared (issue 45): frames naming one photo share one
//! decode and one undistorted copy, and the memory estimate counts what is kept; orbit and
//! spiral frame counts are capped like paths; a GIF has one screen size; FIFOs, sockets and
//! devices named as inputs are refused at once.

use std::path::Path;
use std::sync::Arc;

use splat4d::io::dataset::{DatasetOptions, load_dataset, photo_memory};
use splat4d::io::image_file::{BitDepth, save_image};
use splat4d::io::path_file::save_path;
use splat4d::model::View;
use splat4d::model::random::seeded_rng;
use splat4d::scenes::paths::{Circle, Lens, MAX_PATH_FRAMES, PathFrame, orbit};
use splat4d::{Camera, Image};

use crate::common::{blob_dataset, data, run_limited};

/// A `w × h` photo of seeded random levels.
fn random_photo(w: u32, h: u32, seed: u64) -> Image {
    use rand::RngExt;
    let mut rng = seeded_rng(seed);
    let mut image = Image::filled(w, h, [0.0; 3]);
    for v in &mut image.pixels {
        *v = f32::from(rng.random_range(0..=255_u8)) / 255.0;
    }
    image
}

/// How many distinct pixel arrays the views hold.
fn distinct_images(views: &[View]) -> usize {
    let mut seen: Vec<&Arc<Image>> = Vec::new();
    for view in views {
        if !seen.iter().any(|s| Arc::ptr_eq(s, &view.image)) {
            seen.push(&view.image);
        }
    }
    seen.len()
}

fn all_views(dir: &Path) -> Vec<View> {
    let dataset = load_dataset(dir, &DatasetOptions::default()).unwrap();
    dataset
        .train
        .into_iter()
        .chain(dataset.val)
        .chain(dataset.test)
        .collect()
}

/// A COLMAP text model of `count` images that all name `one.png` (64×48): the first half
/// through a PINHOLE camera, the rest through a SIMPLE_RADIAL one (`k` = 0.05).
fn colmap_one_photo(dir: &Path, count: usize) {
    let sparse = dir.join("sparse/0");
    std::fs::create_dir_all(&sparse).unwrap();
    std::fs::create_dir_all(dir.join("images")).unwrap();
    save_image(
        &random_photo(64, 48, 7),
        &dir.join("images/one.png"),
        BitDepth::Eight,
    )
    .unwrap();
    std::fs::write(
        sparse.join("cameras.txt"),
        "1 PINHOLE 64 48 60 60 32 24\n2 SIMPLE_RADIAL 64 48 60 32 24 0.05\n",
    )
    .unwrap();
    let mut images = String::new();
    for k in 0..count {
        let camera = if k < count / 2 { 1 } else { 2 };
        // Each image a little further along x, all looking down +z at the origin's side.
        images.push_str(&format!(
            "{} 1 0 0 0 {} 0 3 {camera} one.png\n\n",
            k + 1,
            0.01 * k as f64
        ));
    }
    std::fs::write(sparse.join("images.txt"), images).unwrap();
}

#[test]
fn colmap_images_naming_one_file_share_one_decode_and_one_undistorted_copy() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    colmap_one_photo(dir, 20);
    let views = all_views(dir);
    assert_eq!(views.len(), 20);
    // One decode for the ten pinhole views, one undistorted copy for the ten radial ones.
    assert_eq!(distinct_images(&views), 2);
    let pinhole: Vec<&View> = views.iter().filter(|v| v.weights.is_none()).collect();
    let radial: Vec<&View> = views.iter().filter(|v| v.weights.is_some()).collect();
    assert_eq!((pinhole.len(), radial.len()), (10, 10));
    assert!(!Arc::ptr_eq(&pinhole[0].image, &radial[0].image));
    // The shared copy is the undistorted photo (the pinhole decode resampled), the same for
    // every radial view.
    assert_ne!(pinhole[0].image.pixels, radial[0].image.pixels);
    // The estimate follows the sharing: two arrays of 12 bytes a pixel, and ten weight
    // arrays of 4.
    let pixels = 64 * 48;
    let estimate = photo_memory(dir, 1);
    assert_eq!(
        (estimate.frames, estimate.files, estimate.copies),
        (20, 1, 2)
    );
    assert_eq!(estimate.kept, 2 * 12 * pixels + 10 * 4 * pixels);
    assert_eq!(estimate.largest_view, pixels);
    assert!(estimate.working >= 28 * pixels, "{estimate:?}");
    // Downscaled by 2: one downscaled copy per lens, a quarter of the pixels.
    let half = photo_memory(dir, 2);
    assert_eq!(half.copies, 2);
    assert_eq!(half.kept, 2 * 12 * pixels / 4 + 10 * 4 * pixels / 4);
    let downscaled = load_dataset(
        dir,
        &DatasetOptions {
            downscale: 2,
            ..Default::default()
        },
    )
    .unwrap();
    let views: Vec<View> = downscaled
        .train
        .into_iter()
        .chain(downscaled.test)
        .collect();
    assert_eq!(distinct_images(&views), 2);
    assert_eq!((views[0].image.width, views[0].image.height), (32, 24));
}

#[test]
fn transforms_frames_of_one_photo_with_k1_share_one_undistorted_copy() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    save_image(
        &random_photo(40, 30, 3),
        &dir.join("p.png"),
        BitDepth::Eight,
    )
    .unwrap();
    let frames: Vec<serde_json::Value> = (0..25)
        .map(|k| {
            let camera = Camera::look_at(
                [0.1 * f64::from(k), 0.0, 4.0],
                [0.0; 3],
                [0.0, 1.0, 0.0],
                50.0,
                40,
                30,
            )
            .unwrap();
            serde_json::json!({"file_path": "p.png", "k1": 0.1,
                "transform_matrix": camera.opengl_camera_to_world()})
        })
        .collect();
    let file = serde_json::json!({"fl_x": 32.0, "fl_y": 32.0, "frames": frames});
    std::fs::write(dir.join("transforms.json"), file.to_string()).unwrap();
    let views = all_views(dir);
    assert_eq!(views.len(), 25);
    assert_eq!(distinct_images(&views), 1, "one undistorted copy, not 25");
    assert!(views.iter().all(|v| v.weights == views[0].weights));
    let pixels = 40 * 30;
    let estimate = photo_memory(dir, 1);
    assert_eq!((estimate.frames, estimate.copies), (25, 1));
    assert_eq!(estimate.kept, 12 * pixels + 25 * 4 * pixels);
}

/// The fit's memory estimate counts what the views keep: 25 frames of one 2048² photo with
/// `k1` hold one undistorted copy (50 MB) and 25 weight arrays (419 MB), beyond 300 MB; the
/// estimate used to count the file once (117 MB). Refused before any decode.
#[test]
fn the_fit_estimate_counts_every_frame_s_weights_of_a_shared_photo() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let ds = dir.join("ds");
    std::fs::create_dir_all(&ds).unwrap();
    // A flat 2048² PNG: a few kilobytes on disk.
    save_image(
        &Image::filled(2048, 2048, [0.25; 3]),
        &ds.join("big.png"),
        BitDepth::Eight,
    )
    .unwrap();
    let frames: Vec<serde_json::Value> = (0..25)
        .map(|k| {
            serde_json::json!({"file_path": "big.png", "k1": 0.01,
                "transform_matrix": [[1, 0, 0, 0.01 * f64::from(k)], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]})
        })
        .collect();
    let file = serde_json::json!({"fl_x": 2000.0, "frames": frames});
    std::fs::write(ds.join("transforms.json"), file.to_string()).unwrap();
    let estimate = photo_memory(&ds, 1);
    let pixels = 2048 * 2048;
    assert_eq!(estimate.kept, 12 * pixels + 25 * 4 * pixels);
    let output = run_limited(
        &[
            "fit",
            "--views",
            "ds",
            "--init",
            "random:10",
            "--steps",
            "1",
            "--out",
            "f.json",
            "--max-memory",
            "300M",
        ],
        dir,
    );
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("--max-memory") && stderr.contains("25 frames"),
        "{stderr}"
    );
    assert!(!dir.join("f.json").exists());
}

#[test]
fn orbit_and_spiral_frame_counts_are_capped_like_paths() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let blob = data("blob.json");
    for (flag, frames) in [
        ("--orbit", "1000000000"),
        ("--spiral", "1000000000"),
        ("--orbit", "100001"),
        ("--spiral", "1e300"),
    ] {
        let circle = format!("{flag}=0.5,0.5,0.5,4,20,{frames}");
        let output = run_limited(
            &[
                "video",
                "--scene",
                blob.to_str().unwrap(),
                &circle,
                "--size",
                "8x8",
                "--no-mp4",
                "--out",
                "v",
            ],
            d,
        );
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(2), "{flag} {frames}: {stderr}");
        assert!(
            stderr.contains(flag) && stderr.contains(frames) && stderr.contains("100000"),
            "{flag} {frames}: {stderr}"
        );
        assert!(!stderr.contains("panicked"), "{stderr}");
        assert!(!d.join("v").exists(), "nothing written");
    }
    // The cap itself passes the flag's check (the library is asked for no more).
    let circle = Circle {
        centre: [0.0; 3],
        radius: 3.0,
        elevation_degrees: 10.0,
        frames: 1_000_000_000,
        up: Default::default(),
    };
    let lens = Lens {
        width: 8,
        height: 8,
        fov_y_degrees: 40.0,
    };
    let message = orbit(&circle, &lens, 0.0).unwrap_err().to_string();
    assert!(
        message.contains("`frames`") && message.contains("1000000000"),
        "{message}"
    );
    let capped = Circle {
        frames: MAX_PATH_FRAMES,
        ..circle
    };
    assert_eq!(orbit(&capped, &lens, 0.0).unwrap().len(), MAX_PATH_FRAMES);
}

#[test]
fn a_path_whose_cameras_differ_in_size_is_refused_for_the_gif() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let blob = data("blob.json");
    let camera = |w: u32, h: u32| {
        Camera::look_at([0.5, 0.5, 4.5], [0.5; 3], [0.0, 1.0, 0.0], 40.0, w, h).unwrap()
    };
    let frames = [
        PathFrame {
            camera: camera(24, 16),
            time: 0.5,
        },
        PathFrame {
            camera: camera(24, 16),
            time: 0.5,
        },
        PathFrame {
            camera: camera(32, 16),
            time: 0.5,
        },
    ];
    save_path(&frames, &d.join("walk.json")).unwrap();
    let video = |extra: &[&str]| {
        let mut args = vec![
            "video",
            "--scene",
            blob.to_str().unwrap(),
            "--path",
            "walk.json",
            "--no-mp4",
            "--out",
            "v",
        ];
        args.extend_from_slice(extra);
        run_limited(&args, d)
    };
    let output = video(&[]);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{stderr}");
    for needle in [
        "walk.json",
        "frame 2",
        "`camera.width`",
        "32×16",
        "24×16",
        "--no-gif",
    ] {
        assert!(stderr.contains(needle), "{needle:?} in {stderr}");
    }
    assert!(!d.join("v").exists(), "refused before any frame");
    // Without the GIF each frame keeps its camera's size.
    let output = video(&["--no-gif"]);
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    let sizes: Vec<(u32, u32)> = (0..3)
        .map(|k| {
            let image = splat4d::io::image_file::load_image(
                &d.join(format!("v/walk/frame_{k:04}.png")),
                [0.0; 3],
            )
            .unwrap();
            (image.width, image.height)
        })
        .collect();
    assert_eq!(sizes, [(24, 16), (24, 16), (32, 16)]);
    assert!(!d.join("v/walk.gif").exists());
}

/// `mkfifo PATH`.
#[cfg(unix)]
fn mkfifo(path: &Path) {
    let status = std::process::Command::new("mkfifo")
        .arg(path)
        .status()
        .unwrap();
    assert!(status.success());
}

/// Runs the executable (at most 20 s: a hang fails) and asserts exit status 2, no panic and
/// every needle in stderr.
fn refused_at_once(args: &[&str], cwd: &Path, needles: &[&str]) {
    let output = run_limited(args, cwd);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{args:?}: {stderr}");
    for needle in needles {
        assert!(stderr.contains(needle), "{args:?}: {needle:?} in {stderr}");
    }
    assert!(!stderr.contains("panicked"), "{args:?}: {stderr}");
}

/// A change to a JSON document.
type Edit = fn(&mut serde_json::Value);

fn edit_json(path: &Path, edit: impl FnOnce(&mut serde_json::Value)) {
    let mut value: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    edit(&mut value);
    std::fs::write(path, value.to_string()).unwrap();
}

/// A dataset naming a FIFO as a mask, a point cloud or a photo: `fit` and `view` refuse it
/// at once naming the field, instead of waiting forever for a writer.
#[cfg(unix)]
#[test]
fn fifos_named_by_a_dataset_are_refused_at_once_by_fit_and_view() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let blob = data("blob.json");
    let blob = blob.to_str().unwrap();
    blob_dataset(d, "3");
    mkfifo(&d.join("ds/pipe.png"));
    mkfifo(&d.join("ds/pipe.ply"));
    let train = d.join("ds/transforms_train.json");
    let original = std::fs::read_to_string(&train).unwrap();
    let fit = [
        "fit", "--views", "ds", "--init", "random:5", "--steps", "1", "--out", "f.json",
    ];
    let view = ["view", "--scene", blob, "--views", "ds", "--port", "0"];
    let cases: [(&str, Edit); 3] = [
        ("mask_path", |v| {
            v["frames"][0]["mask_path"] = "pipe.png".into()
        }),
        ("ply_file_path", |v| v["ply_file_path"] = "pipe.ply".into()),
        ("file_path", |v| {
            v["frames"][1]["file_path"] = "pipe.png".into()
        }),
    ];
    for (field, edit) in cases {
        std::fs::write(&train, &original).unwrap();
        edit_json(&train, edit);
        let named = format!("field `{field}`");
        for args in [&fit[..], &view[..]] {
            refused_at_once(args, d, &["transforms_train.json", &named, "FIFO"]);
        }
    }
    assert!(!d.join("f.json").exists());
    // The transforms file itself.
    std::fs::write(&train, &original).unwrap();
    std::fs::remove_file(d.join("ds/transforms_val.json")).unwrap();
    mkfifo(&d.join("ds/transforms_val.json"));
    for args in [&fit[..], &view[..]] {
        refused_at_once(args, d, &["transforms_val.json", "FIFO"]);
    }
}

/// A COLMAP model whose photo or cameras file is a FIFO.
#[cfg(unix)]
#[test]
fn fifos_in_a_colmap_model_are_refused_at_once() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let ds = d.join("ds");
    colmap_one_photo(&ds, 4);
    std::fs::write(
        ds.join("sparse/0/images.txt"),
        "1 1 0 0 0 0 0 3 1 one.png\n\n2 1 0 0 0 0.1 0 3 1 pipe.png\n\n",
    )
    .unwrap();
    mkfifo(&ds.join("images/pipe.png"));
    let fit = [
        "fit", "--views", "ds", "--init", "random:5", "--steps", "1", "--out", "f.json",
    ];
    refused_at_once(&fit, d, &["images.txt", "field `name`", "FIFO"]);
    std::fs::remove_file(ds.join("sparse/0/cameras.txt")).unwrap();
    mkfifo(&ds.join("sparse/0/cameras.txt"));
    refused_at_once(&fit, d, &["cameras.txt", "FIFO"]);
}

/// Every other input a command reads: scenes, cameras, target images, path files, start
/// scenes, glTF models.
#[cfg(unix)]
#[test]
fn fifos_given_as_input_files_are_refused_at_once() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let blob = data("blob.json");
    let blob = blob.to_str().unwrap();
    let camera = data("blob_camera.json");
    let camera = camera.to_str().unwrap();
    for name in ["s.json", "s.ply", "c.json", "t.png", "p.json", "m.gltf"] {
        mkfifo(&d.join(name));
    }
    blob_dataset(d, "2");
    let render = |scene: &str, camera: &str| {
        vec![
            "render", "--scene", scene, "--camera", camera, "--time", "0", "--out", "o.png",
        ]
        .into_iter()
        .map(str::to_owned)
        .collect::<Vec<_>>()
    };
    let cases: Vec<(Vec<String>, &str)> = vec![
        (render("s.json", camera), "s.json"),
        (render("s.ply", camera), "s.ply"),
        (render(blob, "c.json"), "c.json"),
        (
            [
                "grad", "--scene", blob, "--camera", camera, "--time", "0", "--target", "t.png",
                "--out", "g.json",
            ]
            .map(str::to_owned)
            .to_vec(),
            "t.png",
        ),
        (
            ["video", "--scene", blob, "--path", "p.json", "--out", "v"]
                .map(str::to_owned)
                .to_vec(),
            "p.json",
        ),
        (
            [
                "fit", "--views", "ds", "--init", "s.json", "--steps", "1", "--out", "f.json",
            ]
            .map(str::to_owned)
            .to_vec(),
            "s.json",
        ),
        (
            [
                "export-ply",
                "--scene",
                "s.ply",
                "--time",
                "0",
                "--out",
                "e.ply",
            ]
            .map(str::to_owned)
            .to_vec(),
            "s.ply",
        ),
        (
            ["import-gltf", "m.gltf", "--out", "i.json"]
                .map(str::to_owned)
                .to_vec(),
            "m.gltf",
        ),
    ];
    for (args, file) in cases {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        refused_at_once(&args, d, &[file, "FIFO"]);
    }
    for output in ["o.png", "g.json", "v", "f.json", "e.ply", "i.json"] {
        assert!(!d.join(output).exists(), "{output}");
    }
}

/// `dataset` and `video` at the largest frame, 16384²: what they need is estimated before
/// any work (a render's buffers, the frame at the writer, the PNG encoded in memory, the GIF
/// frame) and refused above the bound; a path file's cameras count at their own size.
#[test]
fn the_largest_frames_are_estimated_before_any_work() {
    use splat4d::io::memory::{
        DATASET_VIEW_BYTES_PER_PIXEL, GIF_BYTES_PER_PIXEL, VIDEO_BYTES_PER_PIXEL,
    };
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let blob = data("blob.json");
    let blob = blob.to_str().unwrap();
    let gb = |per_pixel: u64| format!("{:.1} GB", (per_pixel << 28) as f64 / 1e9);
    let dataset = [
        "dataset",
        "--scene",
        blob,
        "--views",
        "1",
        "--times",
        "1",
        "--size",
        "16384x16384",
        "--out",
        "ds",
        "--max-memory",
        "10G",
    ];
    refused_at_once(
        &dataset,
        d,
        &[
            "16384×16384 views",
            &gb(DATASET_VIEW_BYTES_PER_PIXEL),
            "--max-memory",
        ],
    );
    let video = |extra: &[&str]| {
        let mut args = vec![
            "video",
            "--scene",
            blob,
            "--orbit=0.5,0.5,0.5,4,20,2",
            "--times",
            "0.5",
            "--size",
            "16384x16384",
            "--no-mp4",
            "--out",
            "v",
            "--max-memory",
            "1G",
        ];
        args.extend_from_slice(extra);
        args.into_iter().map(str::to_owned).collect::<Vec<_>>()
    };
    let with_gif = video(&[]);
    let with_gif: Vec<&str> = with_gif.iter().map(String::as_str).collect();
    refused_at_once(
        &with_gif,
        d,
        &[
            "16384×16384 frames",
            &gb(VIDEO_BYTES_PER_PIXEL + GIF_BYTES_PER_PIXEL),
        ],
    );
    let without = video(&["--no-gif"]);
    let without: Vec<&str> = without.iter().map(String::as_str).collect();
    refused_at_once(&without, d, &[&gb(VIDEO_BYTES_PER_PIXEL)]);
    // A path file's camera at 16384², whatever `--size` says.
    let big = Camera::look_at(
        [0.5, 0.5, 4.5],
        [0.5; 3],
        [0.0, 1.0, 0.0],
        40.0,
        16384,
        16384,
    )
    .unwrap();
    save_path(
        &[PathFrame {
            camera: big,
            time: 0.5,
        }],
        &d.join("big.json"),
    )
    .unwrap();
    refused_at_once(
        &[
            "video",
            "--scene",
            blob,
            "--path",
            "big.json",
            "--no-mp4",
            "--out",
            "v",
            "--max-memory",
            "10G",
        ],
        d,
        &["16384×16384 frames", "--max-memory"],
    );
    assert!(!d.join("ds").exists() && !d.join("v").exists());
}

/// One orbit per `--times` entry: the orbits' frames together are bounded too.
#[test]
fn orbits_at_many_times_are_bounded_together() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let blob = data("blob.json");
    // Eleven orbits of the most frames one may have.
    let times: Vec<String> = (0..11).map(|k| format!("{}", f64::from(k) * 0.1)).collect();
    let times = times.join(",");
    let limit = splat4d::tasks::video::MAX_ORBIT_FRAMES.to_string();
    refused_at_once(
        &[
            "video",
            "--scene",
            blob.to_str().unwrap(),
            "--orbit=0.5,0.5,0.5,4,20,100000",
            "--times",
            &times,
            "--size",
            "8x8",
            "--out",
            "v",
        ],
        d,
        &["11 orbits", "--times", "--orbit", "1100000 frames", &limit],
    );
    assert!(!d.join("v").exists());
}
