//! Views to fit: images with the camera that took them and their scene time, and the
//! train / val / test splits of a dataset.

use crate::model::camera::Camera;
use crate::model::image::Image;

/// One image with its camera and time.
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
}

/// A dataset's splits.
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
    /// What the reader noticed and skipped (keys it does not read), for the user to see.
    pub notes: Vec<String>,
}
