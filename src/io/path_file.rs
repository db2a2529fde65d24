//! Camera path files, in two formats:
//!
//! - splat4d's: `[{"camera": {camera JSON}, "time": t}, ...]`, one entry per frame;
//! - nerfstudio's `camera_path.json` (what `ns-render camera-path` reads and the viewer's
//!   render panel writes): `{"render_width": W, "render_height": H, "camera_path": [{
//!   "camera_to_world": [16 numbers, row-major, OpenGL axes], "fov": vertical degrees,
//!   "aspect": W/H, "render_time": t (optional)}, ...], "fps": f, "seconds": s, ...}`. The
//!   focal length is `(H/2) / tan(fov/2)` for x and y, the principal point the image centre
//!   (nerfstudio's pinhole); other keys (`keyframes`, `camera_type: "perspective"`, `crop`,
//!   `smoothness_value`, …) are ignored. A camera without a time takes one from the caller.

use std::path::Path;

use serde::Deserialize;

use crate::io::camera_file::camera_from_json;
use crate::io::json::parse_json;
use crate::io::write_bytes_atomically;
use crate::model::{Camera, Error, Result};
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

/// Reads a path file in either format (see the module docs): splat4d's list, or nerfstudio's
/// `camera_path.json` (a JSON object).
pub fn load_any_path(path: &Path) -> Result<Vec<PathCamera>> {
    let origin = path.display().to_string();
    let text = std::fs::read_to_string(path)
        .map_err(|e| Error::read(path, "cannot read camera path", e))?;
    if text
        .trim_start_matches('\u{feff}')
        .trim_start()
        .starts_with('{')
    {
        return nerfstudio_path(&text, &origin);
    }
    Ok(load_path_text(&text, &origin)?
        .into_iter()
        .map(|f| PathCamera {
            camera: f.camera,
            time: Some(f.time),
        })
        .collect())
}

/// Largest image side a path may ask for (as cameras elsewhere).
const MAX_SIDE: u64 = 16_384;

/// Parses nerfstudio's `camera_path.json`.
fn nerfstudio_path(text: &str, origin: &str) -> Result<Vec<PathCamera>> {
    let file: serde_json::Value = parse_json(text, origin, "nerfstudio camera path")?;
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
    let cameras = file
        .get("camera_path")
        .and_then(serde_json::Value::as_array)
        .filter(|list| !list.is_empty())
        .ok_or_else(|| {
            Error::invalid(
                origin,
                "camera path",
                "camera_path",
                "a non-empty list of cameras is required (a file with only `keyframes` is the \
                 viewer's state: export the rendered path from nerfstudio's render panel)",
            )
        })?;
    cameras
        .iter()
        .enumerate()
        .map(|(i, entry)| {
            let item = format!("camera_path[{i}]");
            let bad = |field: &str, message: &str| Error::invalid(origin, &item, field, message);
            let numbers: Vec<f64> = entry
                .get("camera_to_world")
                .and_then(serde_json::Value::as_array)
                .map(|v| v.iter().filter_map(serde_json::Value::as_f64).collect())
                .unwrap_or_default();
            if numbers.len() != 16 {
                return Err(bad(
                    "camera_to_world",
                    "16 numbers (a row-major 4×4 matrix) are required",
                ));
            }
            let fov = entry
                .get("fov")
                .and_then(serde_json::Value::as_f64)
                .filter(|f| *f > 0.0 && *f < 180.0)
                .ok_or_else(|| {
                    bad(
                        "fov",
                        "a vertical field of view in (0, 180) degrees is required",
                    )
                })?;
            let time = match entry.get("render_time").or_else(|| entry.get("time")) {
                None | Some(serde_json::Value::Null) => None,
                Some(value) => Some(
                    value
                        .as_f64()
                        .filter(|t| t.is_finite())
                        .ok_or_else(|| bad("render_time", "a finite number is required"))?,
                ),
            };
            let matrix: [[f64; 4]; 4] =
                std::array::from_fn(|r| std::array::from_fn(|c| numbers[4 * r + c]));
            let camera = Camera::from_opengl_camera_to_world(
                width,
                height,
                Camera::centred_intrinsics(width, height, fov.to_radians()),
                matrix,
            )
            .map_err(|e| match e {
                Error::Invalid { field, message, .. } => Error::invalid(
                    origin,
                    &item,
                    &format!("camera_to_world ({field})"),
                    message,
                ),
                other => other,
            })?;
            Ok(PathCamera { camera, time })
        })
        .collect()
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
    let text = std::fs::read_to_string(path)
        .map_err(|e| Error::read(path, "cannot read camera path", e))?;
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
