//! splat4d: dynamic scenes as 4D Gaussian kernels over (x, y, z, t), rendered and fitted on
//! the CPU. The math is fixed by `SPEC.md` (shared with independent implementations).
//!
//! The forward renderer is four stages, each a function from plain struct-of-arrays data
//! to plain data, run by a [`RenderContext`] that owns the buffers:
//!
//! 1. [`slice`](mod@slice): each 4D kernel at time τ → a 3D Gaussian and its amplitude (SPEC §2), with
//!    temporal culling;
//! 2. [`project`]: EWA projection through a pinhole [`Camera`] → a screen ellipse (SPEC §4);
//! 3. [`tiles`]: ellipses → kernel lists per 16×16 tile, in kernel order;
//! 4. [`raster`]: the additive sum per pixel, no sorting (SPEC §5).
//!
//! [`reference`](mod@reference) is the slow f64 twin that every fast stage is tested against.
//!
//! Around the renderer:
//!
//! - [`backward`]: the exact gradient of the render (SPEC §6), stage by stage in reverse;
//! - [`fit`]: the loss, Adam, initial scenes, synthetic datasets and the training loop;
//! - [`io`]: scene/camera JSON, PNG/EXR, PLY (3DGS slices and 4D scenes), glTF, D-NeRF
//!   datasets and videos, every output written atomically;
//! - [`toy`], [`volume`], [`report`]: the seed paper's experiment, its Eq. 1 volumes and
//!   report; [`camera_path`] and [`overlay`] for videos and debugging.
//!
//! ```
//! use splat4d::{Camera, Kernel, RenderOptions, Scene, render};
//! let blob = Kernel::new([0.0, 0.0, 0.0, 0.0], [0.1, 0.1, 0.1, 1.0], [1.0, 1.0, 1.0]);
//! let scene = Scene::from_kernels(&[blob], [0.0; 3], "<example>").unwrap();
//! let camera = Camera::look_at([0.0, 0.0, -3.0], [0.0; 3], [0.0, 1.0, 0.0], 40.0, 64, 48).unwrap();
//! let image = render(&scene, &camera, 0.0, &RenderOptions::default()).unwrap();
//! assert!(image.pixel(32, 24)[0] > 0.9);
//! ```

pub mod backward;
pub mod camera;
pub mod camera_path;
pub mod dense;
pub mod error;
pub mod fit;
pub mod io;
pub mod overlay;
pub mod project;
pub mod raster;
pub mod reference;
pub mod render;
pub mod report;
pub mod scene;
pub mod slice;
pub mod synthetic;
pub mod tiles;
pub mod toy;
pub mod volume;

pub use backward::Gradients;
pub use camera::Camera;
pub use error::{Error, Result};
pub use raster::Image;
pub use render::{RenderContext, RenderOptions, RenderStats, render};
pub use scene::{Kernel, Scene};
