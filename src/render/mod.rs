//! The forward renderer: a reusable context that owns every buffer and runs the four stages
//! slice (SPEC §2) → project (§4) → tiles → raster (§5); for alpha scenes (§8) colour and
//! depth order come between projection and tiles, and compositing replaces the sum:
//!
//! ```text
//! additive: slice → project ──────────────────────────→ tiles → raster::rasterize
//! alpha:    slice → project → colour::shade → order_by_depth → tiles → composite::composite
//! ```
//!
//! The steps that differ between the blends (what comes between the projection and the
//! tiles, stage 4, its backward and a training step's two together) are each blend's, behind
//! one dispatch on the scene's blend (`Blends::of`, the only place a frame branches on it):
//! the steps in `stage.rs`, each blend's in `additive.rs` and `alpha.rs`, with the buffers
//! they keep. A frame whose blend reads no slices and that no backward reads (`render`,
//! `render_in_bands`, `render_indexed` of an additive scene) slices and projects each kernel
//! in one pass ([`crate::project::slice_and_project`]): the same projections without the
//! slices' arrays.
//!
//! Buffers are kept between frames and only cleared, so rendering a sequence of frames
//! allocates nothing once the largest frame has been seen. Tiles run on the current rayon
//! thread pool (install a pool to choose the thread count); the image is identical bit for
//! bit whatever the number of threads.

mod additive;
mod alpha;
mod stage;

use crate::backward::project::project_backward;
use crate::backward::raster::PixelGradient;
use crate::backward::slice::slice_backward;
use crate::backward::{BackwardBuffers, Gradients};
use crate::model::Image;
use crate::model::camera::Camera;
use crate::model::error::{Error, Result, check_non_negative_setting};
use crate::model::scene::{Blend, Scene};
use crate::parallel::{Drain, GroupBuffers};
use crate::project::{ProjectedKernels, project, slice_and_project, slice_candidates_and_project};
use crate::simd::{BinnedFrame, ExpMode, RowForm};
use crate::slice::{SlicedKernels, TemporalIndex, slice, slice_candidates};
use crate::tiles::{TileBins, bin};
use additive::Additive;
use alpha::Alpha;
use stage::BlendStages;

/// Default dilation `s` of SPEC §4, px².
pub const DEFAULT_DILATION: f64 = 0.3;
/// Default cut-off ε of SPEC §5.
pub const DEFAULT_CUTOFF: f64 = 1.0 / 255.0;

/// Rendering options of SPEC §4–5.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderOptions {
    /// Variance added to `Σ2`'s diagonal, px², finite and ≥ 0.
    pub dilation: f64,
    /// Cut-off ε on the Gaussian's value, finite and ≥ 0; 0 disables truncation.
    pub cutoff: f64,
    /// How the per-pixel loops evaluate `exp(-½ q)` (forward and backward alike).
    pub exp: ExpMode,
}

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions {
            dilation: DEFAULT_DILATION,
            cutoff: DEFAULT_CUTOFF,
            exp: ExpMode::Poly,
        }
    }
}

impl RenderOptions {
    /// Checks the ranges of SPEC §4–5.
    pub fn validate(&self) -> Result<()> {
        check_non_negative_setting("dilation", self.dilation)?;
        check_non_negative_setting("cutoff", self.cutoff)
    }
}

/// What a frame cost: kernels alive after each stage and pairs summed.
///
/// Counts of SPEC §2 (alive at τ), §4 (projected) and §5 (pairs within the cut-off).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RenderStats {
    /// Kernels that survived temporal and amplitude culling.
    pub sliced: usize,
    /// Kernels that survived projection.
    pub projected: usize,
    /// (tile, kernel) entries in the bins.
    pub tile_entries: usize,
    /// (pixel, kernel) pairs whose indicator is 1 (SPEC §5).
    pub pairs: u64,
}

/// Which kernels a frame visits: all of the scene's, or the candidates of a temporal index
/// ([`RenderContext::render_indexed`]).
#[derive(Clone, Copy)]
enum Visit {
    All,
    Candidates,
}

/// Owns the buffers of every stage; reuse it across frames.
///
/// SPEC §2–5 forward, §6 and §8 backward.
///
/// ```
/// use splat4d::{Camera, Kernel, RenderContext, RenderOptions, Scene};
/// let kernel = Kernel::new([0.0, 0.0, 0.0, 0.0], [0.2, 0.2, 0.2, 1.0], [1.0, 1.0, 1.0]);
/// let scene = Scene::from_kernels(&[kernel], [0.0; 3], "<example>").unwrap();
/// let camera = Camera::look_at([0.0, 0.0, -3.0], [0.0; 3], [0.0, 1.0, 0.0], 40.0, 32, 32).unwrap();
/// let mut context = RenderContext::new();
/// for time in [0.0, 0.5] {
///     let stats = context.render(&scene, &camera, time, &RenderOptions::default()).unwrap();
///     assert_eq!(stats.pairs > 0, true);
///     assert!(context.image().pixel(16, 16)[0] > 0.5);
/// }
/// ```
#[derive(Debug, Default)]
pub struct RenderContext {
    /// Stage 1 output; empty after an additive frame no backward reads (its kernels are
    /// sliced and projected in one pass, and only the projections kept).
    pub sliced: SlicedKernels,
    /// Kernels a temporal index proposes for the frame.
    candidates: Vec<u32>,
    /// Stage 2 output.
    pub projected: ProjectedKernels,
    /// Stage 3 output.
    pub bins: TileBins,
    /// Buffers of the backward pass.
    pub backward: BackwardBuffers,
    /// The row forms of the frame last rendered (stage 4 of either blend; its backward reads
    /// them).
    row_forms: Vec<RowForm>,
    /// Each blend's steps and the buffers they keep.
    blends: Blends,
    /// Whether the last frame was rendered by [`Self::render_for_backward`]: it kept what
    /// [`Self::backward`] reads.
    ready_for_backward: bool,
    image: Image,
    /// The rows of a frame rendered in bands ([`Self::render_in_bands`]).
    row_groups: GroupBuffers,
}

impl RenderContext {
    /// An empty context.
    #[must_use]
    pub fn new() -> Self {
        RenderContext::default()
    }

    /// Renders `scene` through `camera` at time `tau` into [`Self::image`]. The scene and
    /// camera must be valid (they are when loaded or built by this library). A frame to
    /// differentiate is rendered by [`Self::render_for_backward`] instead.
    pub fn render(
        &mut self,
        scene: &Scene,
        camera: &Camera,
        tau: f64,
        options: &RenderOptions,
    ) -> Result<RenderStats> {
        self.render_frame(scene, camera, tau, options, false)
    }

    /// [`Self::render`], keeping what [`Self::backward`] reads: for alpha scenes each pixel's
    /// stop (its final transmittance and the entry that stopped it, SPEC §8), 16 bytes a
    /// pixel that a frame only looked at does without. The same image.
    pub fn render_for_backward(
        &mut self,
        scene: &Scene,
        camera: &Camera,
        tau: f64,
        options: &RenderOptions,
    ) -> Result<RenderStats> {
        self.render_frame(scene, camera, tau, options, true)
    }

    /// The whole frame's four stages, keeping what the backward reads when `for_backward`.
    fn render_frame(
        &mut self,
        scene: &Scene,
        camera: &Camera,
        tau: f64,
        options: &RenderOptions,
        for_backward: bool,
    ) -> Result<RenderStats> {
        check_frame(tau, options)?;
        let alive = self.prepare_frame(scene, Visit::All, camera, tau, options, for_backward);
        Ok(self.finish_frame(scene, options, for_backward, alive))
    }

    /// [`Self::render`] without an image: the frame's rows go to `drain` in order, a group
    /// of tile rows at a time (the index of its first row and its RGB values, row-major), while
    /// the next group is computed ([`crate::parallel::fill_and_drain_in_order`]). The values
    /// are [`Self::render`]'s image's, bit for bit, in the memory of two groups of rows rather
    /// than an image: for frames that go straight to a file. Nothing is kept for a backward
    /// (call [`Self::render_for_backward`] before [`Self::backward`]), and [`Self::image`] is
    /// left as it was. Returns the frame's counts, or `drain`'s first error, after which no
    /// more rows are handed over (on more than one thread the group after the failed one may
    /// already have been computed).
    pub fn render_in_bands(
        &mut self,
        scene: &Scene,
        camera: &Camera,
        tau: f64,
        options: &RenderOptions,
        drain: &mut Drain<Error>,
    ) -> Result<RenderStats> {
        check_frame(tau, options)?;
        let alive = self.prepare_frame(scene, Visit::All, camera, tau, options, false);
        let frame = binned_frame(
            (&self.projected, &self.bins),
            &mut self.row_forms,
            scene,
            options,
        );
        let stages = self.blends.of(scene.blend);
        let pairs = stages.render_in_bands(&frame, &mut self.row_groups, drain)?;
        Ok(self.stats(alive, pairs))
    }

    /// [`Self::render`] visiting only the kernels `index` says may be alive at `tau`: the
    /// same image, at a cost that follows the kernels alive rather than the scene's size.
    /// `index` must have been built for `scene` and `options.cutoff`.
    pub fn render_indexed(
        &mut self,
        scene: &Scene,
        index: &TemporalIndex,
        camera: &Camera,
        tau: f64,
        options: &RenderOptions,
    ) -> Result<RenderStats> {
        check_frame(tau, options)?;
        if index.kernels() != scene.len() || index.cutoff() != options.cutoff {
            return Err(Error::Usage(format!(
                "the temporal index was built for {} kernels at cut-off {}, not {} at {}",
                index.kernels(),
                index.cutoff(),
                scene.len(),
                options.cutoff
            )));
        }
        index.candidates(tau, &mut self.candidates);
        let alive = self.prepare_frame(scene, Visit::Candidates, camera, tau, options, false);
        Ok(self.finish_frame(scene, options, false, alive))
    }

    /// Stages 1–3 of a frame: the slice, the projection (then the blend's per-kernel work:
    /// the alpha blend's colour and depth order) and the tile bins; returns the number of
    /// kernels alive at `tau`. A frame that keeps what a backward reads, and a frame whose
    /// blend reads the slices, keep the slices in [`Self::sliced`]; another frame slices and
    /// projects each kernel in one pass ([`slice_and_project`]) and keeps none (`sliced` is
    /// left empty): the same projections, bit for bit.
    fn prepare_frame(
        &mut self,
        scene: &Scene,
        visit: Visit,
        camera: &Camera,
        tau: f64,
        options: &RenderOptions,
        keep_slices: bool,
    ) -> usize {
        // Ready again only once a frame for a backward is whole.
        self.ready_for_backward = false;
        let stages = self.blends.of(scene.blend);
        let alive = if keep_slices || stages.reads_slices() {
            match visit {
                Visit::All => slice(scene, tau, options.cutoff, &mut self.sliced),
                Visit::Candidates => {
                    let candidates = &self.candidates;
                    slice_candidates(scene, candidates, tau, options.cutoff, &mut self.sliced);
                }
            }
            project(&self.sliced, camera, options.dilation, &mut self.projected);
            stages.after_projection(scene, &self.sliced, camera, &mut self.projected);
            self.sliced.len()
        } else {
            self.sliced.reset();
            let (times, dilation) = ((tau, options.cutoff), options.dilation);
            let out = &mut self.projected;
            match visit {
                Visit::All => slice_and_project(scene, times, camera, dilation, out),
                Visit::Candidates => {
                    let candidates = &self.candidates;
                    slice_candidates_and_project(scene, candidates, times, camera, dilation, out)
                }
            }
        };
        bin(&self.projected, camera.width, camera.height, &mut self.bins);
        alive
    }

    /// The frame's counts: `alive` kernels after the slice, and the `pairs` its raster took.
    fn stats(&self, alive: usize, pairs: u64) -> RenderStats {
        RenderStats {
            sliced: alive,
            projected: self.projected.len(),
            tile_entries: self.bins.proj_from_entry.len(),
            pairs,
        }
    }

    /// Stage 4 after [`Self::prepare_frame`] (`alive` kernels after the slice), keeping what
    /// the backward reads when `for_backward`.
    fn finish_frame(
        &mut self,
        scene: &Scene,
        options: &RenderOptions,
        for_backward: bool,
        alive: usize,
    ) -> RenderStats {
        self.ready_for_backward = for_backward;
        let frame = binned_frame(
            (&self.projected, &self.bins),
            &mut self.row_forms,
            scene,
            options,
        );
        let stages = self.blends.of(scene.blend);
        let pairs = stages.render(&frame, &mut self.image, for_backward);
        self.stats(alive, pairs)
    }

    /// Adds the gradient of a loss to `grads`, given `v_image = ∂L/∂C` for the frame last
    /// rendered (RGB, row-major, like the image). Call it right after
    /// [`Self::render_for_backward`] with the same scene, camera, time and options: it reuses
    /// that frame's slices, ellipses, bins and (alpha scenes) stops.
    /// `grads` must be sized for the scene ([`Gradients::for_scene`]).
    ///
    /// # Panics
    /// When the last frame was not rendered by [`Self::render_for_backward`] (a
    /// [`Self::render`], [`Self::render_in_bands`], [`Self::render_indexed`] or
    /// [`Self::swap_image`] came between).
    pub fn backward(
        &mut self,
        scene: &Scene,
        camera: &Camera,
        tau: f64,
        options: &RenderOptions,
        v_image: &[f32],
        grads: &mut Gradients,
    ) {
        assert!(
            self.ready_for_backward,
            "RenderContext::backward: the last frame was not rendered by render_for_backward"
        );
        let frame = BinnedFrame::with_forms(
            &self.projected,
            &self.bins,
            &self.row_forms,
            scene.background.map(|b| b as f32),
            options.exp,
        );
        let stages = self.blends.of(scene.blend);
        let v_background = stages.backward(&frame, v_image, &mut self.backward.screen);
        self.backward_from_screen(scene, camera, tau, options, v_background, grads);
    }

    /// [`Self::render_for_backward`], then [`Self::backward`] of the loss whose `∂L/∂C`
    /// `gradient` gives from the rendered pixels ([`PixelGradient`]), written to `v_image`: a
    /// training step's render and backward. Additive scenes take one pass over the tiles,
    /// each set up once for both ([`crate::backward::raster::rasterize_with_backward`]); the
    /// image, `v_image` and the gradients are the same bits as the two calls with `gradient`
    /// applied to the whole image between them.
    #[allow(clippy::too_many_arguments)]
    pub fn render_and_backward(
        &mut self,
        scene: &Scene,
        camera: &Camera,
        tau: f64,
        options: &RenderOptions,
        gradient: &PixelGradient,
        v_image: &mut Vec<f32>,
        grads: &mut Gradients,
    ) -> Result<RenderStats> {
        check_frame(tau, options)?;
        let alive = self.prepare_frame(scene, Visit::All, camera, tau, options, true);
        self.ready_for_backward = true;
        let frame = binned_frame(
            (&self.projected, &self.bins),
            &mut self.row_forms,
            scene,
            options,
        );
        let stages = self.blends.of(scene.blend);
        let (pairs, v_background) = stages.render_and_backward(
            &frame,
            &mut self.image,
            (gradient, v_image),
            &mut self.backward.screen,
        );
        self.backward_from_screen(scene, camera, tau, options, v_background, grads);
        Ok(self.stats(alive, pairs))
    }

    /// The backward's stages 2 and 1 from the screen-space gradients in
    /// `self.backward.screen`, and the background's gradient: into `grads`.
    fn backward_from_screen(
        &mut self,
        scene: &Scene,
        camera: &Camera,
        tau: f64,
        options: &RenderOptions,
        v_background: [f64; 3],
        grads: &mut Gradients,
    ) {
        let buffers = &mut self.backward;
        project_backward(
            &self.sliced,
            &self.projected,
            camera,
            options.dilation,
            &buffers.screen,
            &mut buffers.sliced,
        );
        slice_backward(scene, camera, tau, &self.sliced, &buffers.sliced, grads);
        for (total, sum) in grads.v_background.iter_mut().zip(v_background) {
            *total += sum;
        }
    }

    /// The last rendered image.
    #[must_use]
    pub fn image(&self) -> &Image {
        &self.image
    }

    /// Each pixel's stop, row-major, as [`Self::render_for_backward`] of an alpha scene left
    /// it: the transmittance `T` after the pixel's last kernel (SPEC §8; `1 - T` is the
    /// pixel's opacity) and where it stopped. Read it right after such a frame: other frames
    /// keep no stops (an older frame's, or none, are left here).
    #[must_use]
    pub fn pixel_stops(&self) -> &[crate::composite::PixelStop] {
        &self.blends.alpha.stops
    }

    /// Exchanges the last rendered image with `other`: a sequence of frames handed on (to a
    /// writer, say) without a copy. The context keeps `other`'s buffer, whose pixels the next
    /// render overwrites (every pixel is written each frame); until then [`Self::image`] is
    /// `other`'s old content and [`Self::backward`] refuses to run.
    pub fn swap_image(&mut self, other: &mut Image) {
        self.ready_for_backward = false;
        std::mem::swap(&mut self.image, other);
    }
}

/// The frame stage 4 reads after the bins: `proj` binned in `bins`, its row forms computed
/// into `forms`, over `scene`'s background, with `options`' exp.
fn binned_frame<'a>(
    (proj, bins): (&'a ProjectedKernels, &'a TileBins),
    forms: &'a mut Vec<RowForm>,
    scene: &Scene,
    options: &RenderOptions,
) -> BinnedFrame<'a> {
    let background = scene.background.map(|b| b as f32);
    BinnedFrame::new(proj, bins, forms, background, options.exp)
}

/// Each blend's steps of a frame and the buffers they keep.
#[derive(Debug, Default)]
struct Blends {
    additive: Additive,
    alpha: Alpha,
}

impl Blends {
    /// The steps of `blend`: the one place a frame branches on its blend.
    fn of(&mut self, blend: Blend) -> &mut dyn BlendStages {
        match blend {
            Blend::Additive => &mut self.additive,
            Blend::Alpha => &mut self.alpha,
        }
    }
}

/// The checks of SPEC §4–5 on a frame's options and time.
fn check_frame(tau: f64, options: &RenderOptions) -> Result<()> {
    options.validate()?;
    if !tau.is_finite() {
        return Err(Error::setting(
            &["time"],
            format!("`time` {tau} is not finite"),
        ));
    }
    Ok(())
}

/// Renders one frame with a fresh context: convenient, but allocates; use a
/// [`RenderContext`] for sequences.
pub fn render(scene: &Scene, camera: &Camera, tau: f64, options: &RenderOptions) -> Result<Image> {
    let mut context = RenderContext::new();
    context.render(scene, camera, tau, options)?;
    Ok(context.image)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An alpha frame and a context that rendered it for a backward, then `between` on it.
    fn backward_after(between: impl FnOnce(&mut RenderContext, &Scene, &Camera)) {
        let camera = crate::scenes::synthetic::bench_camera(40, 24);
        let scene = crate::scenes::synthetic::varied_alpha_bench_scene(50, 3, 0.2);
        let options = RenderOptions::default();
        let mut context = RenderContext::new();
        context
            .render_for_backward(&scene, &camera, 0.5, &options)
            .unwrap();
        between(&mut context, &scene, &camera);
        let v_image = vec![1.0_f32; context.image().pixels.len()];
        let mut grads = Gradients::for_scene(&scene);
        context.backward(&scene, &camera, 0.5, &options, &v_image, &mut grads);
    }

    #[test]
    fn a_backward_reads_the_frame_rendered_for_it() {
        backward_after(|_, _, _| {});
        // A frame only looked at keeps no stops, and the image is the same.
        backward_after(|context, scene, camera| {
            let kept = context.image().clone();
            let stops = context.blends.alpha.stops.clone();
            assert_eq!(stops.len(), 40 * 24);
            context
                .render(scene, camera, 0.5, &RenderOptions::default())
                .unwrap();
            assert_eq!(context.image(), &kept);
            context
                .render_for_backward(scene, camera, 0.5, &RenderOptions::default())
                .unwrap();
            assert_eq!(context.blends.alpha.stops, stops);
        });
    }

    #[test]
    #[should_panic(expected = "not rendered by render_for_backward")]
    fn a_backward_after_a_frame_only_looked_at_panics() {
        backward_after(|context, scene, camera| {
            context
                .render(scene, camera, 0.5, &RenderOptions::default())
                .unwrap();
        });
    }

    #[test]
    #[should_panic(expected = "not rendered by render_for_backward")]
    fn a_backward_after_the_image_was_handed_on_panics() {
        backward_after(|context, _, _| context.swap_image(&mut Image::default()));
    }
}
