//! The slow, obviously correct twin of the renderer: f64 throughout, every kernel against
//! every pixel, no tiles, no bounds, no rewriting of formulas (SPEC §2–6 as written). One
//! file per fast stage, so tests compare the stages one at a time, not only whole images:
//!
//! | fast stage | twin |
//! |---|---|
//! | [`crate::slice`] (SPEC §2) | [`slice::reference_slice`] |
//! | [`crate::project`] (SPEC §4) | [`project::reference_project`] |
//! | [`crate::tiles`] + [`crate::raster`] (SPEC §5) | [`raster::render_reference`], [`raster::reference_at_pixels`] |
//! | [`crate::colour`] (SPEC §8) | [`colour::reference_alpha_kernels`] |
//! | [`crate::composite`] (SPEC §8) | [`composite::render_reference_alpha`], [`composite::composite_traced`] |
//! | [`crate::backward`] (SPEC §6), stage by stage | [`backward::reference_loss_and_gradients`]: [`backward::raster`], [`backward::project`], [`backward::slice`](mod@backward::slice) |
//!
//! [`dense`] is the seed-style baseline the benches time against the tiles (every kernel at
//! every pixel, but the fast f32 arithmetic): a speed reference, not an accuracy one.

pub mod backward;
pub mod colour;
pub mod composite;
pub mod dense;
pub mod project;
pub mod raster;
pub mod slice;

pub use backward::{mse, reference_loss_and_gradients};
pub use project::{ReferenceKernel, reference_project};
pub use raster::{
    BORDERLINE_BAND, ERROR_BOUND, ErrorBound, PairMask, ReferenceImage, is_borderline,
    kernel_contribution, quadratic_form, reference_at_pixels, render_reference,
};
pub use slice::{ReferenceSlice, reference_slice};

use crate::model::{Camera, Scene};
use crate::render::RenderOptions;

/// Slices and projects kernel `index` of `scene` (SPEC §2 and §4), or `None` when culled.
#[must_use]
pub fn reference_kernel(
    scene: &Scene,
    index: usize,
    camera: &Camera,
    tau: f64,
    options: &RenderOptions,
) -> Option<ReferenceKernel> {
    let slice = reference_slice(scene, index, tau, options.cutoff)?;
    reference_project(&slice, camera, options.dilation)
}

/// Every kernel that survives culling, in scene order.
#[must_use]
pub fn reference_kernels(
    scene: &Scene,
    camera: &Camera,
    tau: f64,
    options: &RenderOptions,
) -> Vec<ReferenceKernel> {
    (0..scene.len())
        .filter_map(|i| reference_kernel(scene, i, camera, tau, options))
        .collect()
}
