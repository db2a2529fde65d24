//! Camera path files, in two formats:
//!
//! - splat4d's: `[{"camera": {camera JSON}, "time": t}, ...]`, one entry per frame;
//! - nerfstudio's `camera_path.json` (what `ns-render camera-path` reads and the viewer's
//!   render panel writes): `{"render_width": W, "render_height": H, "camera_path": [{
//!   "camera_to_world": [16 numbers, row-major, OpenGL axes], "fov": vertical degrees,
//!   "aspect": W/H, "render_time": t (optional)}, ...], "fps": f, "seconds": s, ...}`. The
//!   focal length is `(H/2) / tan(fov/2)` for x and y, the principal point the image centre
//!   (nerfstudio's pinhole). A camera without a time takes one from the caller.
//!
//!   A file without `camera_path` (what nerfstudio's viewer saves before rendering) is read
//!   from its `keyframes`: `[{"matrix": 16 numbers, row-major camera-to-world (or a string
//!   of three.js's column-major `elements`, the older viewer's), "fov": degrees (else the
//!   file's `default_fov`), "time" or "render_time": t (optional)}, ...]`, and rendered as
//!   `round(fps × seconds)` frames through them by [`crate::scenes::keyframes`]. `camera_type`
//!   must be `perspective` (or absent): fisheye and equirectangular paths are refused. Other
//!   keys (`crop`, `smoothness_value`, `is_cycle`, transition overrides, …) are ignored.

use std::path::Path;

use serde::Deserialize;

use crate::io::camera_file::camera_from_json;
use crate::io::json::parse_json;
use crate::io::write_bytes_atomically;
use crate::model::{Camera, Error, Result};
use crate::scenes::keyframes::{Keyframe, check_keyframes, interpolate};
use crate::scenes::paths::PathFrame;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct PathEntry {
    camera: serde_json::Value,
    time: f64,
}

/// One camera of a path file, with its time when the file gives one.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathCamera {
    /// The camera.
    pub camera: Camera,
    /// Scene time, when the file has it (splat4d's always; nerfstudio's `render_time`).
    pub time: Option<f64>,
}

/// The cameras of a path file, and the frame rate it asks for.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraPath {
    /// One camera per frame.
    pub cameras: Vec<PathCamera>,
    /// nerfstudio's `fps`, when the file gives one.
    pub fps: Option<f64>,
}

/// Reads a path file in either format (see the module docs): splat4d's list, or nerfstudio's
/// `camera_path.json` (a JSON object).
pub fn load_any_path(path: &Path) -> Result<CameraPath> {
    let origin = path.display().to_string();
    let text = crate::io::input::read_to_string(path, "cannot read camera path")?;
    if looks_like_json_object(&text) {
        return nerfstudio_path(&text, &origin);
    }
    let cameras = load_path_text(&text, &origin)?
        .into_iter()
        .map(|f| PathCamera {
            camera: f.camera,
            time: Some(f.time),
        })
        .collect();
    Ok(CameraPath { cameras, fps: None })
}

/// What opens a JSON object: nerfstudio's path files are objects, splat4d's are lists.
const OBJECT_OPENER: char = '{';

/// Whether `text` holds a JSON object (its first character past a byte-order mark and white
/// space opens one).
fn looks_like_json_object(text: &str) -> bool {
    let byte_order_mark = '\u{feff}';
    text.trim_start_matches(byte_order_mark)
        .trim_start()
        .starts_with(OBJECT_OPENER)
}

/// Most frames a keyframes-only path may ask for (`fps × seconds`): the cap of every
/// camera path ([`crate::scenes::paths::MAX_PATH_FRAMES`]).
pub const MAX_PATH_FRAMES: f64 = crate::scenes::paths::MAX_PATH_FRAMES as f64;

/// Largest image side a path may ask for (as cameras elsewhere).
const MAX_SIDE: u64 = 16_384;

/// Parses nerfstudio's `camera_path.json`: its rendered cameras, else its keyframes.
fn nerfstudio_path(text: &str, origin: &str) -> Result<CameraPath> {
    let file: serde_json::Value = parse_json(text, origin, "nerfstudio camera path")?;
    check_camera_type(&file, origin)?;
    let side = |key: &str| -> Result<u32> {
        file.get(key)
            .and_then(serde_json::Value::as_u64)
            .filter(|&v| (1..=MAX_SIDE).contains(&v))
            .map(|v| v as u32)
            .ok_or_else(|| {
                Error::invalid(
                    origin,
                    "camera path",
                    key,
                    format!("a whole number of pixels from 1 to {MAX_SIDE} is required"),
                )
            })
    };
    let (width, height) = (side("render_width")?, side("render_height")?);
    let fps = positive(&file, "fps", origin)?;
    let rendered = file
        .get("camera_path")
        .and_then(serde_json::Value::as_array)
        .filter(|list| !list.is_empty());
    let cameras = match rendered {
        Some(list) => rendered_cameras(list, width, height, origin)?,
        None => keyframe_cameras(&file, fps, width, height, origin)?,
    };
    Ok(CameraPath { cameras, fps })
}

/// Refuses a `camera_type` other than `perspective`, naming it.
fn check_camera_type(file: &serde_json::Value, origin: &str) -> Result<()> {
    match file.get("camera_type") {
        None | Some(serde_json::Value::Null) => Ok(()),
        Some(serde_json::Value::String(kind)) if kind == "perspective" => Ok(()),
        Some(other) => {
            let kind = other
                .as_str()
                .map_or_else(|| other.to_string(), str::to_owned);
            Err(Error::invalid(
                origin,
                "camera path",
                "camera_type",
                format!(
                    "`{kind}` cameras are not supported: splat4d renders perspective (pinhole) cameras only"
                ),
            ))
        }
    }
}

/// A finite number > 0 under `key`, if the file has the key.
fn positive(file: &serde_json::Value, key: &str, origin: &str) -> Result<Option<f64>> {
    match file.get(key) {
        None | Some(serde_json::Value::Null) => Ok(None),
        Some(value) => value
            .as_f64()
            .filter(|v| v.is_finite() && *v > 0.0)
            .map(Some)
            .ok_or_else(|| {
                Error::invalid(
                    origin,
                    "camera path",
                    key,
                    "a finite number > 0 is required",
                )
            }),
    }
}

/// The cameras of a `camera_path` list.
fn rendered_cameras(
    cameras: &[serde_json::Value],
    width: u32,
    height: u32,
    origin: &str,
) -> Result<Vec<PathCamera>> {
    cameras
        .iter()
        .enumerate()
        .map(|(i, entry)| {
            let item = format!("camera_path[{i}]");
            let bad = |field: &str, message: &str| Error::invalid(origin, &item, field, message);
            let numbers = sixteen(entry.get("camera_to_world")).ok_or_else(|| {
                bad(
                    "camera_to_world",
                    "16 numbers (a row-major 4×4 matrix) are required",
                )
            })?;
            let fov = fov_of(entry, None).ok_or_else(|| {
                bad(
                    "fov",
                    "a vertical field of view in (0, 180) degrees is required",
                )
            })?;
            let time = time_of(entry).map_err(|field| bad(field, "a finite number is required"))?;
            let matrix: [[f64; 4]; 4] =
                std::array::from_fn(|r| std::array::from_fn(|c| numbers[4 * r + c]));
            let camera = path_camera(width, height, fov, matrix, origin, &item)?;
            Ok(PathCamera { camera, time })
        })
        .collect()
}

/// 16 numbers from a JSON list.
fn sixteen(value: Option<&serde_json::Value>) -> Option<Vec<f64>> {
    let numbers: Vec<f64> = value?
        .as_array()?
        .iter()
        .map(serde_json::Value::as_f64)
        .collect::<Option<_>>()?;
    (numbers.len() == 16).then_some(numbers)
}

/// An entry's `fov`, else `default`, if in (0, 180).
fn fov_of(entry: &serde_json::Value, default: Option<f64>) -> Option<f64> {
    entry
        .get("fov")
        .and_then(serde_json::Value::as_f64)
        .or(default)
        .filter(|f| *f > 0.0 && *f < 180.0)
}

/// An entry's `render_time` (or `time`): `Err(field)` when present and not a finite number.
fn time_of(entry: &serde_json::Value) -> std::result::Result<Option<f64>, &'static str> {
    for key in ["render_time", "time"] {
        match entry.get(key) {
            None | Some(serde_json::Value::Null) => {}
            Some(value) => {
                return value
                    .as_f64()
                    .filter(|t| t.is_finite())
                    .map(Some)
                    .ok_or(key);
            }
        }
    }
    Ok(None)
}

/// The camera of an OpenGL camera-to-world matrix and a vertical field of view; errors name
/// `item`.
fn path_camera(
    width: u32,
    height: u32,
    fov: f64,
    matrix: [[f64; 4]; 4],
    origin: &str,
    item: &str,
) -> Result<Camera> {
    Camera::from_opengl_camera_to_world(
        width,
        height,
        Camera::centred_intrinsics(width, height, fov.to_radians()),
        matrix,
    )
    .map_err(|e| match e {
        Error::Invalid { field, message, .. } => {
            Error::invalid(origin, item, &format!("camera_to_world ({field})"), message)
        }
        other => other,
    })
}

/// The keyframes of a file without rendered cameras.
pub fn parse_keyframes(file: &serde_json::Value, origin: &str) -> Result<Vec<Keyframe>> {
    let list = file
        .get("keyframes")
        .and_then(serde_json::Value::as_array)
        .filter(|list| !list.is_empty())
        .ok_or_else(|| {
            Error::invalid(
                origin,
                "camera path",
                "keyframes",
                "neither a non-empty `camera_path` list of cameras nor a non-empty `keyframes` list",
            )
        })?;
    let default_fov = file.get("default_fov").and_then(serde_json::Value::as_f64);
    let keyframes = list
        .iter()
        .enumerate()
        .map(|(i, entry)| {
            let item = format!("keyframes[{i}]");
            let bad = |field: &str, message: &str| Error::invalid(origin, &item, field, message);
            let camera_to_world = keyframe_matrix(entry.get("matrix")).ok_or_else(|| {
                bad(
                    "matrix",
                    "16 numbers (a row-major 4×4 camera-to-world matrix) are required",
                )
            })?;
            let fov_y_degrees = fov_of(entry, default_fov).ok_or_else(|| {
                bad(
                    "fov",
                    "a vertical field of view in (0, 180) degrees is required",
                )
            })?;
            let time = time_of(entry).map_err(|field| bad(field, "a finite number is required"))?;
            Ok(Keyframe {
                camera_to_world,
                fov_y_degrees,
                time,
            })
        })
        .collect::<Result<Vec<_>>>()?;
    check_keyframes(&keyframes, origin)?;
    Ok(keyframes)
}

/// A keyframe's matrix: a list of 16 (row-major), or a string holding three.js's 16
/// column-major `elements`.
fn keyframe_matrix(value: Option<&serde_json::Value>) -> Option<[[f64; 4]; 4]> {
    if let Some(serde_json::Value::String(text)) = value {
        let list: serde_json::Value = serde_json::from_str(text).ok()?;
        let n = sixteen(Some(&list))?;
        return Some(std::array::from_fn(|r| {
            std::array::from_fn(|c| n[4 * c + r])
        }));
    }
    let n = sixteen(value)?;
    Some(std::array::from_fn(|r| {
        std::array::from_fn(|c| n[4 * r + c])
    }))
}

/// The cameras of a keyframes-only file: `round(fps × seconds)` frames through them.
fn keyframe_cameras(
    file: &serde_json::Value,
    fps: Option<f64>,
    width: u32,
    height: u32,
    origin: &str,
) -> Result<Vec<PathCamera>> {
    let keyframes = parse_keyframes(file, origin)?;
    let seconds = positive(file, "seconds", origin)?;
    let (Some(fps), Some(seconds)) = (fps, seconds) else {
        let missing = if fps.is_none() { "fps" } else { "seconds" };
        return Err(Error::invalid(
            origin,
            "camera path",
            missing,
            "a keyframes-only path needs `fps` and `seconds` (frames = fps × seconds)",
        ));
    };
    let frames = (fps * seconds).round();
    if !(1.0..=MAX_PATH_FRAMES).contains(&frames) {
        return Err(Error::invalid(
            origin,
            "camera path",
            "seconds",
            format!("fps × seconds = {frames} frames; from 1 to {MAX_PATH_FRAMES} are allowed"),
        ));
    }
    interpolate(&keyframes, frames as usize)
        .iter()
        .enumerate()
        .map(|(k, pose)| {
            let camera = path_camera(
                width,
                height,
                pose.fov_y_degrees,
                pose.camera_to_world,
                origin,
                &format!("frame {k}"),
            )?;
            Ok(PathCamera {
                camera,
                time: pose.time,
            })
        })
        .collect()
}

/// nerfstudio's `camera_path.json` of a path through `keyframes` at `width × height`:
/// the keyframes (row-major `matrix`, `fov`, `aspect`, `time`), `fps`, `seconds`, and the
/// `round(fps × seconds)` interpolated cameras as `camera_path` (what `ns-render` and
/// [`load_any_path`] read).
#[must_use]
pub fn keyframes_file_json(
    keyframes: &[Keyframe],
    frames: &[crate::scenes::keyframes::Pose],
    [width, height]: [u32; 2],
    fps: f64,
) -> serde_json::Value {
    let aspect = f64::from(width) / f64::from(height.max(1));
    let keys: Vec<serde_json::Value> = keyframes
        .iter()
        .map(|k| {
            serde_json::json!({
                "matrix": k.camera_to_world.iter().flatten().collect::<Vec<_>>(),
                "fov": k.fov_y_degrees,
                "aspect": aspect,
                "time": k.time,
            })
        })
        .collect();
    let cameras: Vec<serde_json::Value> = frames
        .iter()
        .map(|p| {
            serde_json::json!({
                "camera_to_world": p.camera_to_world.iter().flatten().collect::<Vec<_>>(),
                "fov": p.fov_y_degrees,
                "aspect": aspect,
                "render_time": p.time,
            })
        })
        .collect();
    serde_json::json!({
        "camera_type": "perspective",
        "render_width": width,
        "render_height": height,
        "fps": fps,
        "seconds": frames.len() as f64 / fps,
        "smoothness_value": 0.5,
        "is_cycle": false,
        "keyframes": keys,
        "camera_path": cameras,
    })
}

/// Writes `frames` as nerfstudio's `camera_path.json` (see the module docs) for a video at
/// `fps`: every camera with its `render_time`. nerfstudio's pinhole has its principal point
/// at the image centre and one focal length; cameras that differ are written with their
/// vertical field of view.
pub fn save_nerfstudio_path(frames: &[PathFrame], fps: u32, path: &Path) -> Result<()> {
    let (width, height) = frames
        .first()
        .map_or((0, 0), |f| (f.camera.width, f.camera.height));
    let cameras: Vec<serde_json::Value> = frames
        .iter()
        .map(|f| {
            let m = f.camera.opengl_camera_to_world();
            let fov = 2.0 * (0.5 * f64::from(f.camera.height) / f.camera.fy).atan();
            serde_json::json!({
                "camera_to_world": m.iter().flatten().collect::<Vec<_>>(),
                "fov": fov.to_degrees(),
                "aspect": f64::from(f.camera.width) / f64::from(f.camera.height),
                "render_time": f.time,
            })
        })
        .collect();
    let file = serde_json::json!({
        "camera_type": "perspective",
        "render_width": width,
        "render_height": height,
        "fps": fps,
        "seconds": frames.len() as f64 / f64::from(fps.max(1)),
        "camera_path": cameras,
    });
    let text = serde_json::to_string_pretty(&file).expect("finite numbers serialise");
    write_bytes_atomically(path, text.as_bytes())
}

/// Reads a path file: a JSON list of `{"camera": {camera JSON}, "time": t}`.
pub fn load_path(path: &Path) -> Result<Vec<PathFrame>> {
    let origin = path.display().to_string();
    let text = crate::io::input::read_to_string(path, "cannot read camera path")?;
    load_path_text(&text, &origin)
}

/// Parses splat4d's path list.
fn load_path_text(text: &str, origin: &str) -> Result<Vec<PathFrame>> {
    let origin = origin.to_owned();
    let entries: Vec<PathEntry> = parse_json(text, &origin, "camera path")?;
    if entries.is_empty() {
        return Err(Error::invalid(
            &origin,
            "camera path",
            "frames",
            "the list is empty",
        ));
    }
    entries
        .iter()
        .enumerate()
        .map(|(i, entry)| {
            let item = format!("frame {i}");
            if !entry.time.is_finite() {
                return Err(Error::invalid(&origin, &item, "time", "not finite"));
            }
            let camera = camera_from_json(&entry.camera.to_string(), &format!("{origin}: {item}"))?;
            Ok(PathFrame {
                camera,
                time: entry.time,
            })
        })
        .collect()
}

/// Writes a path file that [`load_path`] reads.
pub fn save_path(frames: &[PathFrame], path: &Path) -> Result<()> {
    let list: Vec<serde_json::Value> = frames
        .iter()
        .map(|f| serde_json::json!({"camera": serde_json::to_value(f.camera).expect("finite"), "time": f.time}))
        .collect();
    let text = serde_json::to_string_pretty(&list).expect("finite numbers serialise");
    write_bytes_atomically(path, text.as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenes::paths::{Circle, Lens, spiral};

    #[test]
    fn path_files_round_trip() {
        let circle = Circle {
            centre: [0.0; 3],
            radius: 2.0,
            elevation_degrees: 10.0,
            frames: 3,
            up: Default::default(),
        };
        let lens = Lens {
            width: 32,
            height: 32,
            fov_y_degrees: 50.0,
        };
        let frames = spiral(&circle, &lens, [0.0, 2.0]).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("path.json");
        save_path(&frames, &file).unwrap();
        assert_eq!(load_path(&file).unwrap(), frames);
        std::fs::write(&file, r#"[{"camera": {"width": 0}, "time": 0}]"#).unwrap();
        let message = load_path(&file).unwrap_err().to_string();
        assert!(
            message.contains("path.json") && message.contains("frame 0"),
            "{message}"
        );
    }
}
