//! f64 twin of the backward pass, [`crate::backward`] (SPEC §6): the loss and its exact
//! gradient by the chain rule written with whole matrices, one file per stage of the fast
//! backward, in the same reverse order:
//!
//! | fast stage | twin |
//! |---|---|
//! | [`crate::backward::raster`] | [`raster::reference_raster_backward`] |
//! | [`crate::backward::project`] | [`project::reference_project_backward`] |
//! | [`crate::backward::slice`](mod@crate::backward::slice) | [`slice::reference_slice_backward`] |
//!
//! These twins are of the additive blend. [`crate::backward::composite`] (SPEC §8) has no
//! analytic twin: the tests check it against central differences of
//! [`crate::reference::composite::composite_traced`], the f64 pixel with its pairs, order
//! and stop held constant.

pub mod project;
pub mod raster;
pub mod slice;

use crate::backward::Gradients;
use crate::model::{Camera, Scene};
use crate::reference::raster::render_reference;
use crate::reference::reference_kernels;
use crate::render::RenderOptions;

/// `MSE = mean over pixels and channels of (C - C_gt)²` (SPEC §6, one view), in f64.
#[must_use]
pub fn mse(image: &[f64], target: &[f32]) -> f64 {
    assert_eq!(image.len(), target.len(), "image and target sizes differ");
    image
        .iter()
        .zip(target)
        .map(|(c, &t)| (c - f64::from(t)).powi(2))
        .sum::<f64>()
        / image.len() as f64
}

/// The MSE of the f64 render against `target` (RGB, row-major) and its exact gradient
/// (SPEC §6), by the chain rule written with whole matrices:
///
/// ```text
/// ∂L/∂Q  = Σ_pairs ∂L/∂q d dᵀ,  ∂L/∂m2 = Σ_pairs ∂L/∂q (-2 Q d),  ∂L/∂q = -½ G Σ_c ∂L/∂C_c a_c
/// ∂L/∂Σ2 = -Q (∂L/∂Q) Q,        ∂L/∂J = 2 (∂L/∂Σ2) J Σc
/// ∂L/∂p  = Σ_(r,c) (∂L/∂J)_rc ∂J_rc/∂p + (∂m2/∂p)ᵀ ∂L/∂m2,   ∂L/∂m = Rcᵀ ∂L/∂p
/// ```
///
/// then through the slice as SPEC §6 lists, and to the rotation through `Σ3` (SPEC §8: the
/// quaternion as `scene` holds it, of any length, through its normalisation): per kernel,
/// [`raster`], [`project`] and [`slice`](mod@slice) in turn.
#[must_use]
pub fn reference_loss_and_gradients(
    scene: &Scene,
    camera: &Camera,
    tau: f64,
    options: &RenderOptions,
    target: &[f32],
) -> (f64, Gradients) {
    let image = render_reference(scene, camera, tau, options);
    let loss = mse(&image.pixels, target);
    let n = scene.len();
    let mut grads = Gradients::zeros(n);
    grads
        .v_accelerations
        .resize(scene.accelerations.len(), [0.0; 3]);
    grads
        .v_angular_velocities
        .resize(scene.angular_velocities.len(), [0.0; 4]);
    let scale = 2.0 / image.pixels.len() as f64;
    let v_image: Vec<f64> = image
        .pixels
        .iter()
        .zip(target)
        .map(|(c, &t)| scale * (c - f64::from(t)))
        .collect();
    for pixel in v_image.chunks_exact(3) {
        for (total, v) in grads.v_background.iter_mut().zip(pixel) {
            *total += v;
        }
    }
    for kernel in reference_kernels(scene, camera, tau, options) {
        let (v_sigma2, v_m2, v_a) = raster::reference_raster_backward(&kernel, camera, &v_image);
        let (v_m, v_sigma3) = project::reference_project_backward(&kernel, camera, v_sigma2, v_m2);
        slice::reference_slice_backward(scene, &kernel, tau, v_m, v_a, v_sigma3, &mut grads);
    }
    (loss, grads)
}
