//! Videos: frames on disk match renders, the GIF holds every frame, MP4 goes through
//! `ffmpeg` when it is on PATH (a stand-in here) and is skipped with a note when it is not.

use std::path::Path;
use std::process::Command;

use crate::common::{data, run_limited, run_limited_with_env};
use image::AnimationDecoder;
use splat4d::io::image_file::load_image;
use splat4d::io::path_file::save_path;
use splat4d::model::image::quantize;
use splat4d::scenes::paths::{Circle, Lens, orbit, spiral};
use splat4d::{RenderOptions, Scene, render};

fn blob() -> Scene {
    splat4d::io::scene_file::scene_from_json(include_str!("../../data/blob.json"), "blob").unwrap()
}

/// One video written into `dir` as the `video` command does: staged inside `dir` and moved
/// into place whole.
fn write_video_into(
    frames: usize,
    dir: &Path,
    name: &str,
    options: &splat4d::io::video::VideoOptions,
    next_frame: impl FnMut(usize, &mut splat4d::Image) -> splat4d::Result<()>,
) -> splat4d::Result<splat4d::io::video::VideoFiles> {
    let staging = splat4d::io::output::Staging::new(dir)?;
    let files = splat4d::io::video::write_video(
        frames,
        staging.path(),
        dir,
        name,
        options,
        &[],
        next_frame,
    )?;
    staging.commit(&[])?;
    Ok(files)
}

fn gif_frames(path: &Path) -> usize {
    let file = std::io::BufReader::new(std::fs::File::open(path).unwrap());
    image::codecs::gif::GifDecoder::new(file)
        .unwrap()
        .into_frames()
        .count()
}

fn splat4d(args: &[&str], cwd: &Path, path_env: Option<&str>) -> std::process::Output {
    let mut command = Command::new(env!("CARGO_BIN_EXE_splat4d"));
    command.args(args).current_dir(cwd);
    if let Some(p) = path_env {
        command.env("PATH", p);
    }
    command.output().unwrap()
}

#[test]
fn orbit_frames_are_the_renders_and_the_gif_has_them_all() {
    let scene = blob();
    let circle = Circle {
        centre: [0.5; 3],
        radius: 4.0,
        elevation_degrees: 15.0,
        frames: 6,
        up: Default::default(),
    };
    let lens = Lens {
        width: 40,
        height: 30,
        fov_y_degrees: 45.0,
    };
    let frames = orbit(&circle, &lens, 0.5).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let options = splat4d::io::video::VideoOptions {
        mp4: false,
        ..Default::default()
    };
    let mut ticks = 0;
    let files = write_video_into(frames.len(), dir.path(), "o", &options, |k, image| {
        *image = render(
            &scene,
            &frames[k].camera,
            frames[k].time,
            &RenderOptions::default(),
        )?;
        ticks += 1;
        Ok(())
    })
    .unwrap();
    assert_eq!((files.frames, ticks), (6, 6));
    assert_eq!(gif_frames(files.gif.as_ref().unwrap()), 6);
    for (k, frame) in frames.iter().enumerate() {
        let written =
            load_image(&dir.path().join(format!("o/frame_{k:04}.png")), [0.0; 3]).unwrap();
        let expected =
            render(&scene, &frame.camera, frame.time, &RenderOptions::default()).unwrap();
        let quantized: Vec<f32> = expected
            .pixels
            .iter()
            .map(|&c| f32::from(quantize(c, 255)) / 255.0)
            .collect();
        assert_eq!(written.pixels, quantized, "frame {k}");
        assert!(
            expected.pixels.iter().cloned().fold(0.0, f32::max) > 0.5,
            "the blob is in frame {k}"
        );
    }
}

#[test]
fn video_command_writes_orbits_spiral_and_path_videos() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("blob.json"), include_str!("../../data/blob.json")).unwrap();
    let lens = Lens {
        width: 24,
        height: 24,
        fov_y_degrees: 50.0,
    };
    let path_frames = spiral(
        &Circle {
            centre: [0.5; 3],
            radius: 3.0,
            elevation_degrees: 10.0,
            frames: 4,
            up: Default::default(),
        },
        &lens,
        [0.0, 1.0],
    )
    .unwrap();
    save_path(&path_frames, &d.join("walk.json")).unwrap();
    let args = [
        "video",
        "--scene",
        "blob.json",
        "--orbit",
        "0.5,0.5,0.5,4,20,5",
        "--times",
        "0,1",
        "--spiral",
        "--path",
        "walk.json",
        "--out",
        "v",
        "--size",
        "32x24",
    ];
    // No ffmpeg: an empty PATH.
    let output = splat4d(&args, d, Some(""));
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(stdout.contains("ffmpeg is not on PATH"), "{stdout}");
    for (name, frames) in [
        ("orbit_t0.00", 5),
        ("orbit_t1.00", 5),
        ("spiral", 60),
        ("walk", 4),
    ] {
        assert_eq!(
            std::fs::read_dir(d.join("v").join(name)).unwrap().count(),
            frames + 1,
            "{name}: the frames and the marker"
        );
        assert_eq!(
            gif_frames(&d.join(format!("v/{name}.gif"))),
            frames,
            "{name}"
        );
        assert!(!d.join(format!("v/{name}.mp4")).exists());
    }
}

#[cfg(unix)]
#[test]
fn mp4_goes_through_ffmpeg_when_it_is_on_path() {
    use std::os::unix::fs::PermissionsExt;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("blob.json"), include_str!("../../data/blob.json")).unwrap();
    // A stand-in ffmpeg: answers -version, records its arguments, writes its last argument.
    let bin = d.join("bin");
    std::fs::create_dir(&bin).unwrap();
    let script = "#!/bin/sh\nif [ \"$1\" = \"-version\" ]; then echo fake; exit 0; fi\necho \"$@\" > \"$(dirname \"$0\")/args.txt\"\nfor last; do :; done\necho mp4 > \"$last\"\n";
    std::fs::write(bin.join("ffmpeg"), script).unwrap();
    std::fs::set_permissions(bin.join("ffmpeg"), std::fs::Permissions::from_mode(0o755)).unwrap();
    let path_env = format!("{}:/usr/bin:/bin", bin.display());
    let args = [
        "video",
        "--scene",
        "blob.json",
        "--orbit",
        "0.5,0.5,0.5,4,20,3",
        "--out",
        "v",
        "--size",
        "16x16",
        "--no-gif",
        "--fps",
        "12",
    ];
    let output = splat4d(&args, d, Some(&path_env));
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    assert_eq!(
        std::fs::read_to_string(d.join("v/orbit_t0.50.mp4")).unwrap(),
        "mp4\n"
    );
    let recorded = std::fs::read_to_string(bin.join("args.txt")).unwrap();
    assert!(
        recorded.contains("-framerate 12")
            && recorded.contains("frame_%04d.png")
            && recorded.contains("libx264")
            && recorded.contains("yuv420p")
            && recorded.contains("-movflags +faststart"),
        "{recorded}"
    );
    assert!(!d.join("v/orbit_t0.50.gif").exists());
    let names: Vec<String> = std::fs::read_dir(d.join("v"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(names.iter().all(|n| !n.contains("partial")), "{names:?}");
}

/// The top-level boxes of an MP4 file (ISO BMFF: 32-bit big-endian size and a 4-letter type;
/// size 1 means a 64-bit size follows, 0 means "to the end of the file").
fn mp4_boxes(bytes: &[u8]) -> Vec<String> {
    let mut boxes = Vec::new();
    let mut at = 0_usize;
    while at + 8 <= bytes.len() {
        let size = u32::from_be_bytes(bytes[at..at + 4].try_into().unwrap()) as usize;
        boxes.push(String::from_utf8_lossy(&bytes[at + 4..at + 8]).into_owned());
        let size = match size {
            0 => bytes.len() - at,
            1 => u64::from_be_bytes(bytes[at + 8..at + 16].try_into().unwrap()) as usize,
            n => n,
        };
        assert!(size >= 8, "box {boxes:?} of size {size}");
        at += size;
    }
    boxes
}

/// With a real `ffmpeg`: the MP4 is H.264 that plays as it downloads (`moov` before `mdat`).
/// Without one the test says so and checks nothing.
#[test]
fn mp4_puts_its_index_before_the_media_data() {
    if std::process::Command::new("ffmpeg")
        .arg("-version")
        .output()
        .is_err()
    {
        eprintln!("ffmpeg is not on PATH: the MP4 atom order is not checked here");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("blob.json"), include_str!("../../data/blob.json")).unwrap();
    let args = [
        "video",
        "--scene",
        "blob.json",
        "--orbit",
        "0.5,0.5,0.5,4,20,6",
        "--out",
        "v",
        "--size",
        "33x17",
        "--no-gif",
    ];
    let output = splat4d(&args, d, None);
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    let bytes = std::fs::read(d.join("v/orbit_t0.50.mp4")).unwrap();
    let boxes = mp4_boxes(&bytes);
    let position = |name: &str| boxes.iter().position(|b| b == name);
    let (moov, mdat) = (position("moov"), position("mdat"));
    assert!(
        moov.is_some() && mdat.is_some() && moov < mdat,
        "top-level boxes {boxes:?}"
    );
}

#[test]
fn video_without_a_path_flag_orbits_the_scene_at_its_times() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("blob.json"), include_str!("../../data/blob.json")).unwrap();
    let common = [
        "--scene",
        "blob.json",
        "--size",
        "24x16",
        "--no-mp4",
        "--no-gif",
    ];
    // --times alone: the default orbit at each time.
    let mut args = vec!["video", "--times", "0,0.5,1", "--out", "a"];
    args.extend_from_slice(&common);
    let output = splat4d(&args, d, None);
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    for t in ["0.00", "0.50", "1.00"] {
        let frames = std::fs::read_dir(d.join(format!("a/orbit_t{t}")))
            .unwrap()
            .count();
        assert_eq!(frames, 61, "t = {t}: 60 frames and the marker");
    }
    // Nothing at all: the scene's own time range (the blob's one kernel: t = 0.5), +z up.
    let mut args = vec!["video", "--out", "b", "--up", "z"];
    args.extend_from_slice(&common);
    let output = splat4d(&args, d, None);
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    let mut made: Vec<String> = std::fs::read_dir(d.join("b"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    made.sort();
    assert_eq!(made, ["orbit_t0.50", "orbit_t0.50.camera_path.json"]);
}

/// nerfstudio's `camera_path.json` both ways: `video` writes the cameras it rendered beside
/// each video, `video --path` reads that file (and files like it, with or without a time per
/// camera) and renders the same frames; a file with neither cameras nor keyframes is refused.
#[test]
fn nerfstudio_camera_paths_are_written_and_read() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("blob.json"), include_str!("../../data/blob.json")).unwrap();
    let run = |args: &[&str]| {
        let output = splat4d(args, d, None);
        assert!(
            output.status.success(),
            "{args:?}: {}",
            String::from_utf8_lossy(&output.stderr)
        );
    };
    run(&[
        "video",
        "--scene",
        "blob.json",
        "--orbit",
        "0.5,0.5,0.5,4,20,5",
        "--times",
        "0.5",
        "--out",
        "a",
        "--size",
        "40x30",
        "--no-gif",
        "--no-mp4",
    ]);
    let written = d.join("a/orbit_t0.50.camera_path.json");
    let file: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&written).unwrap()).unwrap();
    assert_eq!(file["render_width"], 40);
    assert_eq!(file["render_height"], 30);
    let cameras = file["camera_path"].as_array().unwrap();
    assert_eq!(cameras.len(), 5);
    for camera in cameras {
        assert_eq!(camera["camera_to_world"].as_array().unwrap().len(), 16);
        assert_eq!(camera["render_time"], 0.5);
        assert!(
            (camera["fov"].as_f64().unwrap() - 40.0).abs() < 1e-9,
            "{camera}"
        );
    }
    // Read back: the same frames (up to the rounding of a matrix inverted twice).
    std::fs::copy(&written, d.join("path.json")).unwrap();
    run(&[
        "video",
        "--scene",
        "blob.json",
        "--path",
        "path.json",
        "--out",
        "b",
        "--no-gif",
        "--no-mp4",
    ]);
    for k in 0..5 {
        let name = format!("frame_{k:04}.png");
        let a = image::open(d.join("a/orbit_t0.50").join(&name))
            .unwrap()
            .to_rgb8();
        let b = image::open(d.join("b/path").join(&name)).unwrap().to_rgb8();
        assert_eq!(a.dimensions(), b.dimensions());
        let worst = a
            .as_raw()
            .iter()
            .zip(b.as_raw())
            .map(|(x, y)| x.abs_diff(*y))
            .max()
            .unwrap();
        assert!(worst <= 1, "frame {k}: {worst}");
    }
    // A file as nerfstudio's viewer writes it, without times: they sweep the scene's range.
    let mut edited = file.clone();
    for camera in edited["camera_path"].as_array_mut().unwrap() {
        camera.as_object_mut().unwrap().remove("render_time");
    }
    edited["keyframes"] = serde_json::json!([{"matrix": "[1,0,0,0]", "fov": 40}]);
    edited["smoothness_value"] = serde_json::json!(0.5);
    std::fs::write(d.join("untimed.json"), edited.to_string()).unwrap();
    run(&[
        "video",
        "--scene",
        "blob.json",
        "--path",
        "untimed.json",
        "--out",
        "c",
        "--no-gif",
        "--no-mp4",
    ]);
    let back: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(d.join("c/untimed.camera_path.json")).unwrap(),
    )
    .unwrap();
    let times: Vec<f64> = back["camera_path"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["render_time"].as_f64().unwrap())
        .collect();
    assert_eq!(times.len(), 5);
    assert!(times.windows(2).all(|w| w[0] <= w[1]), "{times:?}");
    // Neither cameras nor keyframes: refused, naming both.
    std::fs::write(
        d.join("keys.json"),
        serde_json::json!({"render_width": 40, "render_height": 30, "keyframes": []}).to_string(),
    )
    .unwrap();
    let output = splat4d(
        &[
            "video",
            "--scene",
            "blob.json",
            "--path",
            "keys.json",
            "--out",
            "k",
            "--no-gif",
            "--no-mp4",
        ],
        d,
        None,
    );
    assert_eq!(output.status.code(), Some(2));
    assert!(
        String::from_utf8_lossy(&output.stderr).contains("camera_path"),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
}

/// A keyframes-only nerfstudio file (what its viewer saves before rendering, and what
/// `splat4d view` saves): `fps × seconds` frames through the keyframes, the first exactly
/// keyframe 0's view and time, the last the last keyframe's, at the file's frame rate;
/// fisheye and equirectangular paths are refused naming the type.
#[test]
fn keyframes_only_paths_render_fps_times_seconds_frames() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("blob.json"), include_str!("../../data/blob.json")).unwrap();
    let lens = Lens {
        width: 40,
        height: 30,
        fov_y_degrees: 40.0,
    };
    let circle = Circle {
        centre: [0.5, 0.5, 0.5],
        radius: 4.0,
        elevation_degrees: 20.0,
        frames: 4,
        up: Default::default(),
    };
    let keys = orbit(&circle, &lens, 0.5).unwrap();
    let keyframe = |k: usize, time: f64, fov: f64| {
        serde_json::json!({
            "matrix": keys[k].camera.opengl_camera_to_world().iter().flatten().collect::<Vec<_>>(),
            "fov": fov, "aspect": 40.0 / 30.0, "time": time,
        })
    };
    let file = serde_json::json!({
        "camera_type": "perspective", "render_width": 40, "render_height": 30,
        "fps": 10, "seconds": 0.7, "smoothness_value": 0.5, "is_cycle": false,
        "keyframes": [keyframe(0, 0.2, 40.0), keyframe(1, 0.5, 50.0), keyframe(2, 0.8, 40.0)],
    });
    std::fs::write(d.join("keys.json"), file.to_string()).unwrap();
    let args = [
        "video",
        "--scene",
        "blob.json",
        "--path",
        "keys.json",
        "--out",
        "v",
        "--no-mp4",
    ];
    let output = splat4d(&args, d, None);
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    let written: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("v/keys.camera_path.json")).unwrap())
            .unwrap();
    let cameras = written["camera_path"].as_array().unwrap();
    assert_eq!(cameras.len(), 7, "10 fps × 0.7 s");
    assert_eq!(written["fps"], 10, "the file's frame rate");
    let times: Vec<f64> = cameras
        .iter()
        .map(|c| c["render_time"].as_f64().unwrap())
        .collect();
    assert_eq!(times[0], 0.2);
    assert!(
        (times[6] - 0.8).abs() < 1e-12 && (times[3] - 0.5).abs() < 1e-12,
        "{times:?}"
    );
    assert!((cameras[3]["fov"].as_f64().unwrap() - 50.0).abs() < 1e-9);
    // Frame 0 is keyframe 0's view at its time.
    let first = load_image(&d.join("v/keys/frame_0000.png"), [0.0; 3]).unwrap();
    let expected = render(&blob(), &keys[0].camera, 0.2, &RenderOptions::default()).unwrap();
    let worst = first
        .pixels
        .iter()
        .zip(&expected.pixels)
        .map(|(a, b)| quantize(*a, 255).abs_diff(quantize(*b, 255)))
        .max()
        .unwrap();
    assert!(worst <= 1, "frame 0 against keyframe 0: {worst}");
    assert!(d.join("v/keys/frame_0006.png").exists() && !d.join("v/keys/frame_0007.png").exists());
    for kind in ["fisheye", "equirectangular"] {
        let mut other = file.clone();
        other["camera_type"] = kind.into();
        std::fs::write(d.join("other.json"), other.to_string()).unwrap();
        let args = [
            "video",
            "--scene",
            "blob.json",
            "--path",
            "other.json",
            "--out",
            "o",
            "--no-gif",
            "--no-mp4",
        ];
        let output = splat4d(&args, d, None);
        let message = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(2), "{message}");
        assert!(
            message.contains(kind) && message.contains("camera_type"),
            "{message}"
        );
    }
}

// Limits through the executable (from the former limits.rs): refused quickly, with a
// message and exit status, never a panic, a hang or an unbounded allocation.

#[test]
fn video_frames_replace_an_older_video_whole_and_oversized_gifs_are_refused_first() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let blob = data("blob.json");
    let video = |orbit: &str, size: &str| {
        let orbit = format!("--orbit={orbit}");
        run_limited(
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
    let output = run_limited(
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

/// Frames are written on a second thread while the next renders: a failed render or a
/// failed write stops both, returns that error (naming the frame file for a write) and
/// leaves the earlier video as it was, with no partial frames, GIF or temporary files.
#[test]
fn a_failed_frame_or_write_leaves_the_earlier_video_whole() {
    let dir = tempfile::tempdir().unwrap();
    let listing = || {
        let mut names: Vec<String> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        names
    };
    let frame = |k: usize| splat4d::Image::filled(8, 6, [k as f32 / 10.0, 0.25, 0.5]);
    for gif in [true, false] {
        let options = splat4d::io::video::VideoOptions {
            gif,
            mp4: false,
            ..Default::default()
        };
        let write = |fail_render: Option<usize>, nan_at: Option<usize>, ticks: &mut usize| {
            write_video_into(6, dir.path(), "o", &options, |k, image| {
                *ticks += 1;
                if fail_render == Some(k) {
                    return Err(splat4d::Error::usage(format!("frame {k} failed")));
                }
                *image = frame(k);
                if nan_at == Some(k) {
                    image.pixels[4] = f32::NAN;
                }
                Ok(())
            })
        };
        let mut ticks = 0;
        write(None, None, &mut ticks).unwrap();
        assert_eq!(ticks, 6);
        let before = listing();
        let frames_before = std::fs::read_dir(dir.path().join("o")).unwrap().count();
        // A render that fails: its error, and the renders stop there.
        let mut ticks = 0;
        let error = write(Some(3), None, &mut ticks).unwrap_err().to_string();
        assert!(error.contains("frame 3 failed"), "{error}");
        assert_eq!(ticks, 4);
        assert_eq!(listing(), before, "gif {gif}");
        // A write that fails (a NaN pixel in frame 2): the error names its file; frame 3 was
        // rendered while frame 2 was written, and no frame after it.
        let mut ticks = 0;
        let error = write(None, Some(2), &mut ticks).unwrap_err().to_string();
        assert!(
            error.contains("frame_0002.png") && error.contains("not finite"),
            "{error}"
        );
        assert_eq!(ticks, 4);
        assert_eq!(listing(), before, "gif {gif}");
        assert_eq!(
            std::fs::read_dir(dir.path().join("o")).unwrap().count(),
            frames_before
        );
        // The frames of the first run are the ones on disk.
        for k in 0..6 {
            let written =
                load_image(&dir.path().join(format!("o/frame_{k:04}.png")), [0.0; 3]).unwrap();
            let expected: Vec<f32> = frame(k)
                .pixels
                .iter()
                .map(|&c| f32::from(quantize(c, 255)) / 255.0)
                .collect();
            assert_eq!(written.pixels, expected, "frame {k}");
        }
    }
}

/// Without `--threads`, each frame renders on a thread of the global pool while the frame
/// loop waits on the writer thread: the same files as on one thread, and no hang when the
/// global pool has a single thread (`RAYON_NUM_THREADS=1`) and the writer encodes GIFs.
#[test]
fn default_threads_write_the_same_video_and_do_not_wait_on_themselves() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("blob.json"), include_str!("../../data/blob.json")).unwrap();
    let args = |out: &'static str| {
        vec![
            "video",
            "--scene",
            "blob.json",
            "--orbit",
            "0.5,0.5,0.5,4,20,6",
            "--times",
            "0,1",
            "--size",
            "32x24",
            "--no-mp4",
            "--out",
            out,
        ]
    };
    let mut one = args("one");
    one.extend(["--threads", "1"]);
    for (args, env) in [
        (one, vec![]),
        (args("default"), vec![]),
        (args("single_pool"), vec![("RAYON_NUM_THREADS", "1")]),
    ] {
        let output = run_limited_with_env(&args, d, &env);
        assert!(
            output.status.success(),
            "{args:?}: {}",
            String::from_utf8_lossy(&output.stderr)
        );
    }
    let files = |folder: &str| {
        let mut files = Vec::new();
        for video in std::fs::read_dir(d.join(folder)).unwrap() {
            let video = video.unwrap().path();
            let paths: Vec<_> = if video.is_dir() {
                std::fs::read_dir(&video)
                    .unwrap()
                    .map(|f| f.unwrap().path())
                    .collect()
            } else {
                vec![video]
            };
            for path in paths {
                let name = path.strip_prefix(d.join(folder)).unwrap().to_path_buf();
                let mut bytes = std::fs::read(&path).unwrap();
                if name.ends_with(".splat4d-output") {
                    // The files beside the frames are recorded with their times and inodes,
                    // which differ from run to run: the rest of the marker is compared.
                    let text = String::from_utf8(bytes).unwrap();
                    let listed: Vec<&str> =
                        text.lines().filter(|l| !l.starts_with("../")).collect();
                    assert!(text.contains(".gif\t"), "{text}");
                    bytes = listed.join("\n").into_bytes();
                }
                files.push((name, bytes));
            }
        }
        files.sort();
        files
    };
    let one = files("one");
    assert!(
        one.len() >= 2 * 6,
        "two orbits of six frames and their GIFs"
    );
    assert!(files("default") == one, "default threads");
    assert!(files("single_pool") == one, "a one-thread global pool");
}
