//! The alpha blend's steps of a frame (SPEC §8): between the projection and the bins each
//! kernel's SH colour for the camera and the depth order ([`crate::colour`]), which read the
//! slices; stage 4 front-to-back compositing ([`crate::composite`]), keeping each pixel's
//! stop for a backward; its backward ([`crate::backward::composite`]), which also gives the
//! background's gradient `Σ_p ∂L/∂C_p T_final`.

use super::stage::BlendStages;
use crate::backward::composite::{AlphaPartial, composite_backward};
use crate::backward::raster::{PixelGradient, ScreenGradients};
use crate::colour::{order_by_depth, shade};
use crate::composite::{PixelStop, composite, composite_in_bands};
use crate::model::camera::Camera;
use crate::model::error::{Error, Result};
use crate::model::{Image, Scene};
use crate::parallel::{Drain, GroupBuffers};
use crate::project::ProjectedKernels;
use crate::simd::BinnedFrame;
use crate::slice::SlicedKernels;

/// The alpha blend's buffers, kept between frames.
#[derive(Debug, Default)]
pub(crate) struct Alpha {
    /// Scratch of the depth order.
    depth_keys: Vec<(f64, u32, u32)>,
    /// Each pixel's final transmittance and stop, for the backward: kept by a frame rendered
    /// for a backward only (after other frames, an older frame's or none).
    pub(crate) stops: Vec<PixelStop>,
    /// The backward's partial sums, one per (tile, kernel) entry.
    partials: Vec<AlphaPartial>,
}

impl BlendStages for Alpha {
    fn reads_slices(&self) -> bool {
        true
    }

    fn after_projection(
        &mut self,
        scene: &Scene,
        sliced: &SlicedKernels,
        camera: &Camera,
        projected: &mut ProjectedKernels,
    ) {
        shade(scene, sliced, camera, projected);
        order_by_depth(sliced, camera, projected, &mut self.depth_keys);
    }

    fn render(&mut self, frame: &BinnedFrame, image: &mut Image, for_backward: bool) -> u64 {
        composite(frame, image, for_backward.then_some(&mut self.stops))
    }

    fn render_in_bands(
        &mut self,
        frame: &BinnedFrame,
        groups: &mut GroupBuffers,
        drain: &mut Drain<Error>,
    ) -> Result<u64> {
        composite_in_bands(frame, groups, drain)
    }

    fn backward(
        &mut self,
        frame: &BinnedFrame,
        v_image: &[f32],
        screen: &mut ScreenGradients,
    ) -> [f64; 3] {
        composite_backward(frame, &self.stops, v_image, &mut self.partials, screen)
    }

    fn render_and_backward(
        &mut self,
        frame: &BinnedFrame,
        image: &mut Image,
        (gradient, v_image): (&PixelGradient, &mut Vec<f32>),
        screen: &mut ScreenGradients,
    ) -> (u64, [f64; 3]) {
        let pairs = self.render(frame, image, true);
        v_image.clear();
        v_image.resize(image.pixels.len(), 0.0);
        gradient(0, &image.pixels, v_image);
        (pairs, self.backward(frame, v_image, screen))
    }
}
