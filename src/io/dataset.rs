//! Multi-view datasets in the D-NeRF / Blender layout that dynamic-splatting tools read:
//!
//! ```text
//! DIR/transforms_train.json   {"camera_angle_x": .., "frames": [{"file_path": "./train/r_000",
//! DIR/transforms_val.json        "time": t, "transform_matrix": 4×4 camera-to-world}]}
//! DIR/transforms_test.json
//! DIR/train/r_000.png ...
//! ```
//!
//! `transform_matrix` is row-major camera-to-world with OpenGL axes (x right, y up, z
//! backward); `camera_angle_x` is the horizontal field of view in radians, so
//! `fx = fy = ½ W / tan(½ camera_angle_x)` with the principal point at the image centre and
//! W, H read from the image. Optional top-level `fl_x`, `fl_y`, `cx`, `cy` (nerfstudio's
//! names) override those and are written too, so that cameras round-trip exactly.
//!
//! An image path without extension is looked up as `.exr` first (exact linear values), then
//! `.png`. Integer images are read as `value / (2^bits - 1)`; RGBA images are composited over
//! a background colour (white by default, as D-NeRF does).

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::io::image_file::{BitDepth, load_image_with_alpha, save_image};
use crate::io::json::parse_json;
use crate::io::write_bytes_atomically;
use crate::model::camera::Camera;
use crate::model::error::{Error, Result};
use crate::model::{Dataset, View};

/// The three splits, in file order.
pub const SPLITS: [&str; 3] = ["train", "val", "test"];

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct TransformsFile {
    camera_angle_x: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    fl_x: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    fl_y: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    cx: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    cy: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    w: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    h: Option<u32>,
    frames: Vec<FrameEntry>,
}

#[derive(Serialize, Deserialize)]
struct FrameEntry {
    file_path: String,
    time: f64,
    transform_matrix: [[f64; 4]; 4],
    // Other keys (rotation, ...) that other tools write are ignored.
}

/// The image file a `file_path` entry refers to.
fn resolve_image(dir: &Path, file_path: &str) -> Option<PathBuf> {
    let base = dir.join(file_path);
    if base.extension().is_some() && base.is_file() {
        return Some(base);
    }
    ["exr", "png"]
        .iter()
        .map(|ext| PathBuf::from(format!("{}.{ext}", base.display())))
        .find(|p| p.is_file())
}

/// Reads `DIR/transforms_{split}.json` and its images; a missing file is an empty split.
/// Returns the views and whether any image had alpha.
pub fn read_split(dir: &Path, split: &str, background: [f32; 3]) -> Result<(Vec<View>, bool)> {
    let path = dir.join(format!("transforms_{split}.json"));
    if !path.is_file() {
        return Ok((Vec::new(), false));
    }
    let origin = path.display().to_string();
    let text = std::fs::read_to_string(&path).map_err(|e| Error::read(&path, "cannot read", e))?;
    let file: TransformsFile = parse_json(&text, &origin, "transforms")?;
    let mut views = Vec::with_capacity(file.frames.len());
    let mut had_alpha = false;
    for (index, frame) in file.frames.iter().enumerate() {
        let item = format!("frame {index}");
        let image_path = resolve_image(dir, &frame.file_path).ok_or_else(|| {
            Error::invalid(
                &origin,
                &item,
                "file_path",
                format!("no image at {} (.exr or .png)", frame.file_path),
            )
        })?;
        let (image, alpha) = load_image_with_alpha(&image_path, background)?;
        had_alpha |= alpha;
        let (w, h) = (image.width, image.height);
        if file.w.is_some_and(|fw| fw != w) || file.h.is_some_and(|fh| fh != h) {
            return Err(Error::invalid(
                &origin,
                &item,
                "file_path",
                format!(
                    "{} is {w}×{h}, not the w × h of the file",
                    image_path.display()
                ),
            ));
        }
        if !(file.camera_angle_x > 0.0 && file.camera_angle_x < std::f64::consts::PI) {
            return Err(Error::invalid(
                &origin,
                "transforms",
                "camera_angle_x",
                format!("{} is not in (0, π)", file.camera_angle_x),
            ));
        }
        let focal = 0.5 * f64::from(w) / (0.5 * file.camera_angle_x).tan();
        let intrinsics = [
            file.fl_x.unwrap_or(focal),
            file.fl_y.or(file.fl_x).unwrap_or(focal),
            file.cx.unwrap_or(0.5 * f64::from(w)),
            file.cy.unwrap_or(0.5 * f64::from(h)),
        ];
        if !frame.time.is_finite() {
            return Err(Error::invalid(&origin, &item, "time", "not finite"));
        }
        let camera = Camera::from_opengl_camera_to_world(w, h, intrinsics, frame.transform_matrix)
            .map_err(|e| match e {
                Error::Invalid { field, message, .. } => Error::invalid(
                    &origin,
                    &item,
                    &format!("transform_matrix ({field})"),
                    message,
                ),
                other => other,
            })?;
        views.push(View {
            camera,
            time: frame.time,
            image,
            name: frame.file_path.clone(),
        });
    }
    Ok((views, had_alpha))
}

/// Reads every split of the dataset in `dir`. RGBA images are composited over `background`.
pub fn load_dataset(dir: &Path, background: [f32; 3]) -> Result<Dataset> {
    if !dir.is_dir() {
        return Err(Error::malformed(
            &dir.display().to_string(),
            "not a folder with transforms_*.json",
        ));
    }
    let mut dataset = Dataset::default();
    for split in SPLITS {
        let (views, alpha) = read_split(dir, split, background)?;
        dataset.had_alpha |= alpha;
        match split {
            "train" => dataset.train = views,
            "val" => dataset.val = views,
            _ => dataset.test = views,
        }
    }
    if dataset.train.is_empty() {
        return Err(Error::invalid(
            &dir.join("transforms_train.json").display().to_string(),
            "dataset",
            "frames",
            "transforms_train.json is missing or has no frames",
        ));
    }
    Ok(dataset)
}

/// Writes one split: its images (16-bit PNG, and float EXR when `exr`) and its
/// `transforms_{split}.json`. Every camera must share one set of intrinsics.
pub fn write_split(dir: &Path, split: &str, views: &[View], exr: bool) -> Result<()> {
    let Some(first) = views.first() else {
        return Err(Error::Usage(format!("split {split} has no views")));
    };
    let c = first.camera;
    let mut frames = Vec::with_capacity(views.len());
    for (index, view) in views.iter().enumerate() {
        let v = &view.camera;
        if (v.width, v.height, v.fx, v.fy, v.cx, v.cy)
            != (c.width, c.height, c.fx, c.fy, c.cx, c.cy)
        {
            return Err(Error::Usage(format!(
                "split {split}: view {index} has other intrinsics than view 0"
            )));
        }
        let file_path = format!("./{split}/r_{index:03}");
        let base = dir.join(&file_path);
        save_image(&view.image, &base.with_extension("png"), BitDepth::Sixteen)?;
        if exr {
            save_image(&view.image, &base.with_extension("exr"), BitDepth::Sixteen)?;
        }
        frames.push(FrameEntry {
            file_path,
            time: view.time,
            transform_matrix: v.opengl_camera_to_world(),
        });
    }
    let file = TransformsFile {
        camera_angle_x: 2.0 * (0.5 * f64::from(c.width) / c.fx).atan(),
        fl_x: Some(c.fx),
        fl_y: Some(c.fy),
        cx: Some(c.cx),
        cy: Some(c.cy),
        w: Some(c.width),
        h: Some(c.height),
        frames,
    };
    let text = serde_json::to_string_pretty(&file).expect("finite numbers serialise");
    write_bytes_atomically(
        &dir.join(format!("transforms_{split}.json")),
        text.as_bytes(),
    )
}
