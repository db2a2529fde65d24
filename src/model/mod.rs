//! The model: plain data and math, no files, no threads of its own.
//!
//! - [`Scene`] / [`Kernel`]: 4D Gaussian kernels as struct-of-arrays (SPEC §1);
//! - [`Camera`]: a pinhole camera, OpenCV axes (SPEC §3); [`Up`]: the world's up axis;
//! - [`distortion`]: lens distortion models and the remap that undistorts photos;
//! - [`Image`]: linear RGB, row-major (SPEC §5);
//! - [`View`] / [`Dataset`]: images with their camera and time, in splits, to fit;
//! - [`Error`] / [`ErrorKind`]: what went wrong, by kind, naming file, item and field;
//! - [`random`]: the seeded generator every random choice goes through;
//! - [`progress`]: how long work reports its progress.
//!
//! Every other module builds on these; nothing here imports from the rest of the crate.

pub mod axis;
pub mod camera;
pub mod distortion;
pub mod error;
pub mod image;
pub mod progress;
pub mod random;
pub mod scene;
pub mod view;

pub use axis::Up;
pub use camera::Camera;
pub use error::{Error, ErrorKind, Result, check_finite, check_non_negative_setting};
pub use image::Image;
pub use progress::{Progress, Silent};
pub use scene::{Blend, Kernel, SH_COUNTS, Scene};
pub use view::{Dataset, DatasetPoint, View};
