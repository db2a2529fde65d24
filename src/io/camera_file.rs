//! Camera files (SPEC §3): `{"width":W,"height":H,"fx":..,"fy":..,"cx":..,"cy":..,
//! "world_to_camera":[[4 numbers],[..],[..],[0,0,0,1]],"near":0.01,"far":1e6}` (row-major,
//! OpenCV axes; `near` and `far` optional). Unknown keys are errors.

use std::path::Path;

use crate::io::json::parse_json;
use crate::io::write_bytes_atomically;
use crate::model::{Camera, Result};

/// Parses and validates a camera JSON document.
pub fn camera_from_json(text: &str, origin: &str) -> Result<Camera> {
    let camera: Camera = parse_json(text, origin, "camera")?;
    camera.validate(origin)?;
    Ok(camera)
}

/// The camera as a JSON document.
#[must_use]
pub fn camera_to_json(camera: &Camera) -> String {
    serde_json::to_string_pretty(camera).expect("a camera of finite numbers serialises")
}

/// Reads a camera JSON file.
pub fn load_camera(path: &Path) -> Result<Camera> {
    let text = crate::io::input::read_to_string(path, "cannot read camera")?;
    camera_from_json(&text, &path.display().to_string())
}

/// Writes a camera as JSON, atomically.
pub fn save_camera(camera: &Camera, path: &Path) -> Result<()> {
    write_bytes_atomically(path, camera_to_json(camera).as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shipped_camera_frames_the_whole_blob_path_with_3_sigma_margin() {
        let camera = camera_from_json(
            include_str!("../../data/blob_camera.json"),
            "data/blob_camera.json",
        )
        .unwrap();
        for t in [0.0, 0.25, 0.5, 0.75, 1.0] {
            let [u, v, z] = camera.project_point([t, t, t]);
            let margin = 3.0 * 0.1 * camera.fx / z;
            assert!(
                u - margin > 0.0 && u + margin < f64::from(camera.width),
                "t = {t}: u = {u}"
            );
            assert!(
                v - margin > 0.0 && v + margin < f64::from(camera.height),
                "t = {t}: v = {v}"
            );
        }
    }
}
