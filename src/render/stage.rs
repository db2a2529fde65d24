//! What a blend does to a frame, behind one dispatch: the steps of rendering that differ
//! between the additive blend (SPEC §5, [`super::additive`]) and the alpha blend (SPEC §8,
//! [`super::alpha`]). [`super::RenderContext`] runs the stages every blend shares (the slice,
//! the projection, the bins) and asks the scene's blend for the rest; each blend owns the
//! buffers its steps keep between frames.
//!
//! What the slice's temporal weight multiplies (the amplitude or the opacity) is the slice's
//! own rule, read from the scene ([`crate::slice`], SPEC §2 and §8).

use crate::backward::raster::{PixelGradient, ScreenGradients};
use crate::model::camera::Camera;
use crate::model::error::{Error, Result};
use crate::model::{Image, Scene};
use crate::parallel::{Drain, GroupBuffers};
use crate::project::ProjectedKernels;
use crate::simd::BinnedFrame;
use crate::slice::SlicedKernels;

/// The steps of a frame that depend on the blend, in the order a frame runs them.
pub(crate) trait BlendStages: std::fmt::Debug + Send {
    /// Whether the steps after the projection read the slices, so that the frame keeps
    /// them (the alpha blend's colour and depth order do); otherwise a frame no backward
    /// reads slices and projects each kernel in one pass and keeps no slices.
    fn reads_slices(&self) -> bool;

    /// Per-kernel work between the projection and the bins (the alpha blend: the SH colour
    /// and the depth order, SPEC §8), on `projected`.
    fn after_projection(
        &mut self,
        scene: &Scene,
        sliced: &SlicedKernels,
        camera: &Camera,
        projected: &mut ProjectedKernels,
    );

    /// Stage 4 into `image`, keeping what [`Self::backward`] reads when `for_backward`;
    /// returns the (pixel, kernel) pairs.
    fn render(&mut self, frame: &BinnedFrame, image: &mut Image, for_backward: bool) -> u64;

    /// Stage 4 without an image: the rows go to `drain` in order, a group of tile rows at a
    /// time (see [`super::RenderContext::render_in_bands`]); nothing is kept for a backward.
    fn render_in_bands(
        &mut self,
        frame: &BinnedFrame,
        groups: &mut GroupBuffers,
        drain: &mut Drain<Error>,
    ) -> Result<u64>;

    /// Stage 4's backward of the frame [`Self::render`] rendered `for_backward` (`frame` on
    /// the same row forms): `∂L/∂C` (`v_image`) to the screen-space gradients in `screen`;
    /// returns `∂L/∂b`, the background's gradient.
    fn backward(
        &mut self,
        frame: &BinnedFrame,
        v_image: &[f32],
        screen: &mut ScreenGradients,
    ) -> [f64; 3];

    /// A training step's stage 4 and its backward: [`Self::render`] for a backward, `∂L/∂C`
    /// from the rendered pixels by `gradient`'s function into its buffer (resized to the
    /// image's), then
    /// [`Self::backward`]; the same bits as those three, however the blend runs them (the
    /// additive blend in one pass over the tiles). Returns the pairs and `∂L/∂b`.
    fn render_and_backward(
        &mut self,
        frame: &BinnedFrame,
        image: &mut Image,
        gradient: (&PixelGradient, &mut Vec<f32>),
        screen: &mut ScreenGradients,
    ) -> (u64, [f64; 3]);
}
