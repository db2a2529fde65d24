//! The additive blend's steps of a frame (SPEC §5, Eq. 2): nothing between the projection
//! and the bins, stage 4 the sum per pixel ([`crate::raster`]), its backward
//! ([`crate::backward::raster`]), a training step's two in one pass over the tiles, and the
//! background's gradient, `Σ_p ∂L/∂C_p` (the background is added to every pixel).

use super::stage::BlendStages;
use crate::backward::raster::{
    PixelGradient, RasterPartials, ScreenGradients, rasterize_backward, rasterize_with_backward,
};
use crate::model::camera::Camera;
use crate::model::error::{Error, Result};
use crate::model::{Image, Scene};
use crate::parallel::{Drain, GroupBuffers};
use crate::project::ProjectedKernels;
use crate::raster::{TileScratchPool, rasterize, rasterize_in_bands};
use crate::simd::BinnedFrame;
use crate::slice::SlicedKernels;

/// The additive blend's buffers, kept between frames.
#[derive(Debug, Default)]
pub(crate) struct Additive {
    /// The raster's per-tile scratch.
    pool: TileScratchPool,
    /// The backward's partial sums.
    partials: RasterPartials,
}

impl BlendStages for Additive {
    fn reads_slices(&self) -> bool {
        false
    }

    fn after_projection(
        &mut self,
        _: &Scene,
        _: &SlicedKernels,
        _: &Camera,
        _: &mut ProjectedKernels,
    ) {
    }

    fn render(&mut self, frame: &BinnedFrame, image: &mut Image, _for_backward: bool) -> u64 {
        // The backward reads only the row forms, which the frame keeps.
        rasterize(frame, &self.pool, image)
    }

    fn render_in_bands(
        &mut self,
        frame: &BinnedFrame,
        groups: &mut GroupBuffers,
        drain: &mut Drain<Error>,
    ) -> Result<u64> {
        rasterize_in_bands(frame, &self.pool, groups, drain)
    }

    fn backward(
        &mut self,
        frame: &BinnedFrame,
        v_image: &[f32],
        screen: &mut ScreenGradients,
    ) -> [f64; 3] {
        rasterize_backward(frame, v_image, &mut self.partials, screen);
        background_gradient(v_image)
    }

    fn render_and_backward(
        &mut self,
        frame: &BinnedFrame,
        image: &mut Image,
        (gradient, v_image): (&PixelGradient, &mut Vec<f32>),
        screen: &mut ScreenGradients,
    ) -> (u64, [f64; 3]) {
        let partials = &mut self.partials;
        let pairs = rasterize_with_backward(frame, image, gradient, v_image, partials, screen);
        (pairs, background_gradient(v_image))
    }
}

/// The gradient of the background of an additive frame, which is added to every pixel: the
/// sum of `∂L/∂C` over the pixels, per channel, in f64 in a fixed order (blocks of pixels in
/// parallel, eight lanes within a block: [`crate::parallel::sum_in_blocks`]).
fn background_gradient(v_image: &[f32]) -> [f64; 3] {
    use crate::parallel::{add_lanes, sum_in_blocks};
    // Channel c of pixel p goes to lane p mod 8 of its channel (`lane_sum`'s order).
    sum_in_blocks(v_image.len() / 3, |pixels| {
        let values = &v_image[3 * pixels.start..3 * pixels.end];
        let mut s = [0.0_f64; 24];
        let groups = values.chunks_exact(24);
        let tail = groups.remainder();
        for group in groups {
            for (sum, &v) in s.iter_mut().zip(group) {
                *sum += f64::from(v);
            }
        }
        for (sum, &v) in s.iter_mut().zip(tail) {
            *sum += f64::from(v);
        }
        std::array::from_fn(|c| add_lanes(std::array::from_fn(|lane| s[3 * lane + c])))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_background_gradient_is_the_plain_sum_and_the_same_on_any_threads() {
        // 300×300 pixels: two blocks, a partial one, and a partial group of lanes.
        let values: Vec<f32> = (0..3 * 300 * 300)
            .map(|k| ((k as f32 * 0.618_034).fract() - 0.5) * 1e-3)
            .collect();
        let plain: [f64; 3] = std::array::from_fn(|c| {
            values
                .iter()
                .skip(c)
                .step_by(3)
                .map(|&v| f64::from(v))
                .sum()
        });
        let on = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| background_gradient(&values))
        };
        let one = on(1);
        for c in 0..3 {
            assert!(
                (one[c] - plain[c]).abs() <= 1e-12 * plain[c].abs().max(1e-3),
                "{c}"
            );
        }
        for threads in [2, 3] {
            assert_eq!(on(threads).map(f64::to_bits), one.map(f64::to_bits));
        }
        assert_eq!(background_gradient(&[]), [0.0; 3]);
    }
}
