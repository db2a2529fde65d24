//! Views to fit: images with the camera that took them and their scene time, and the
//! train / val / test splits of a dataset.

use crate::model::camera::Camera;
use crate::model::image::Image;

/// One image with its camera and time.
///
/// SPEC §6: the loss compares a render of `camera` at `time` with `image`.
#[derive(Clone, Debug)]
pub struct View {
    /// The camera that took it.
    pub camera: Camera,
    /// Scene time.
    pub time: f64,
    /// Linear RGB, shared: frames that name one file share one decoded image.
    pub image: std::sync::Arc<Image>,
    /// Where it came from (`./train/r_000`), for messages and reports.
    pub name: String,
    /// Per-pixel loss weights in `[0, 1]`, row-major, one per pixel of `image`: 0 leaves a
    /// pixel out of the loss (outside an undistorted photo, masked out by the dataset), 1
    /// counts it fully. The loss is then the weighted mean (SPEC §6 with weights;
    /// [`crate::fit::loss`]). `None`: every pixel counts fully (the plain mean).
    pub weights: Option<Vec<f32>>,
}

/// A point of the cloud a dataset ships (COLMAP `points3D`, nerfstudio `ply_file_path`), in
/// the world of the dataset's cameras.
///
/// Not part of SPEC: a fit's possible start (`docs/formats.md`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DatasetPoint {
    /// World position.
    pub position: [f64; 3],
    /// Colour as the dataset stores it, read like its images: 8-bit `v / 255`, no sRGB curve.
    pub colour: [f32; 3],
}

/// A dataset's splits.
///
/// SPEC §6 fits the `train` split; `docs/formats.md` lists the layouts read.
#[derive(Clone, Debug, Default)]
pub struct Dataset {
    /// Views to fit.
    pub train: Vec<View>,
    /// Held-out views for monitoring.
    pub val: Vec<View>,
    /// Held-out views for final evaluation.
    pub test: Vec<View>,
    /// True when some pixel had alpha below 1 (and was composited over a background).
    pub transparent: bool,
    /// What the reader noticed and skipped (keys it does not read, frames without an
    /// image), for the user to see.
    pub notes: Vec<String>,
    /// The blend a dataset written by splat4d says its images were rendered with.
    pub blend: Option<super::Blend>,
    /// The point cloud the dataset gives (COLMAP `points3D`, nerfstudio `ply_file_path`), to
    /// start kernels from; `None` when it gives none.
    pub points: Option<Vec<DatasetPoint>>,
    /// The camera depths the scene lies between, `[near, far]`, when the dataset states them
    /// (LLFF's bounds in `poses_bounds.npy`: the least near and the greatest far), for a
    /// start's depth search; `None` when it does not.
    pub depth_range: Option<[f64; 2]>,
}
