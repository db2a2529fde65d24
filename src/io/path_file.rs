//! Camera path files: `[{"camera": {camera JSON}, "time": t}, ...]`, one entry per frame.

use std::path::Path;

use serde::Deserialize;

use crate::io::camera_file::camera_from_json;
use crate::io::json::parse_json;
use crate::io::write_bytes_atomically;
use crate::model::{Error, Result};
use crate::scenes::paths::PathFrame;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct PathEntry {
    camera: serde_json::Value,
    time: f64,
}

/// Reads a path file: a JSON list of `{"camera": {camera JSON}, "time": t}`.
pub fn load_path(path: &Path) -> Result<Vec<PathFrame>> {
    let origin = path.display().to_string();
    let text = std::fs::read_to_string(path)
        .map_err(|e| Error::read(path, "cannot read camera path", e))?;
    let entries: Vec<PathEntry> = parse_json(&text, &origin, "camera path")?;
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
