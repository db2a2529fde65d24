//! The loss of SPEC §6: per view, the mean over pixels and channels of `(C - C_gt)²` on raw
//! linear values (no clamp); over views, the mean of those. `PSNR = 10 log10(1 / MSE)`.

use crate::model::Image;

/// MSE of `image` against `target` (same size), accumulated in f64.
#[must_use]
pub fn mse(image: &Image, target: &Image) -> f64 {
    assert_eq!(
        (image.width, image.height),
        (target.width, target.height),
        "image and target sizes differ"
    );
    let sum: f64 = image
        .pixels
        .iter()
        .zip(&target.pixels)
        .map(|(&c, &t)| (f64::from(c) - f64::from(t)).powi(2))
        .sum();
    sum / image.pixels.len() as f64
}

/// MSE of `image` against `target`, and `v_image = weight ∂MSE/∂C = weight 2 (C - C_gt)/N`
/// into `v_image` (resized). `weight` is `1/views` when the loss averages several views.
pub fn mse_with_gradient(
    image: &Image,
    target: &Image,
    weight: f64,
    v_image: &mut Vec<f32>,
) -> f64 {
    let scale = (weight * 2.0 / image.pixels.len() as f64) as f32;
    v_image.clear();
    v_image.extend(
        image
            .pixels
            .iter()
            .zip(&target.pixels)
            .map(|(&c, &t)| scale * (c - t)),
    );
    mse(image, target)
}

/// `10 log10(1 / mse)`, dB.
#[must_use]
pub fn psnr(mse: f64) -> f64 {
    -10.0 * mse.log10()
}

/// The MSE of one view against `target` and its gradient, accumulated into `grads` (sized
/// for the scene): what `splat4d grad` computes. The target must have the camera's size.
pub fn view_loss_and_gradients(
    context: &mut crate::RenderContext,
    scene: &crate::Scene,
    camera: &crate::Camera,
    tau: f64,
    options: &crate::RenderOptions,
    target: &Image,
    grads: &mut crate::Gradients,
) -> crate::Result<f64> {
    if (target.width, target.height) != (camera.width, camera.height) {
        return Err(crate::Error::Usage(format!(
            "the target image is {}×{} but the camera is {}×{}",
            target.width, target.height, camera.width, camera.height
        )));
    }
    context.render(scene, camera, tau, options)?;
    let mut v_image = Vec::new();
    let loss = mse_with_gradient(context.image(), target, 1.0, &mut v_image);
    context.backward(scene, camera, tau, options, &v_image, grads);
    Ok(loss)
}
