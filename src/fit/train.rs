//! The training loop: Adam on the mean MSE over mini-batches of views (SPEC §6).
//!
//! Each step draws `batch_size` training views (a seeded shuffle, epoch by epoch), renders
//! each, accumulates `∂(mean over the batch of MSE)/∂θ` through the backward pass, and takes
//! one Adam step with the scheduled learning rates: `lr_k = lr · final_factor^(k/(steps-1))`
//! (exponential decay; `final_factor = 1` keeps them constant). Every `eval_every` steps and
//! at the last, the mean MSE over the held-out views is measured.
//!
//! A batch's views run side by side, one per worker thread (`batch_gradients`), each
//! rendered and differentiated in its own slot; their gradients are added in view order.
//! Every field of a view's gradient takes one term per kernel, so the sum is the one the
//! views give one after the other, bit for bit, whatever the thread count. Fits of small
//! frames (a 64×64 view has 4 tile rows) keep every core busy this way.

use std::time::Instant;

use rand::seq::SliceRandom;
use rayon::prelude::*;

use crate::backward::Gradients;
use crate::fit::adam::{Adam, AdamConfig, LearningRates};
use crate::fit::adaptive::{AdaptiveOptions, DensityStats, densify_and_prune};
use crate::fit::loss::{psnr, view_mse, view_mse_gradient};
use crate::model::View;
use crate::model::error::{Error, Result};
use crate::model::random::seeded_rng;
use crate::model::scene::Scene;
use crate::render::{RenderContext, RenderOptions};

/// Which parameter groups a fit moves.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FitMode {
    /// The seed paper's: means `(x, y, z, t)` and amplitudes; kernels static in space, scales
    /// fixed (SPEC §6).
    Paper,
    /// Also the scales `(sx, sy, sz, st)` (in log space); kernels still static in space.
    Static,
    /// Also the velocities and the scales: kernels that move (SPEC §1).
    Velocity,
}

impl FitMode {
    /// Every mode.
    pub const ALL: [FitMode; 3] = [FitMode::Paper, FitMode::Static, FitMode::Velocity];

    /// `rates` with the groups this mode does not fit set to 0.
    #[must_use]
    pub fn learning_rates(self, rates: LearningRates) -> LearningRates {
        LearningRates {
            velocity: if self == FitMode::Velocity {
                rates.velocity
            } else {
                0.0
            },
            scale: if self == FitMode::Paper {
                0.0
            } else {
                rates.scale
            },
            ..rates
        }
    }

    /// Numbers stored per kernel: mean 4, scale 4, amplitude 3, and velocity 3 when moving.
    #[must_use]
    pub fn parameters_per_kernel(self) -> usize {
        if self == FitMode::Velocity { 14 } else { 11 }
    }
}

impl std::fmt::Display for FitMode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            FitMode::Paper => "paper",
            FitMode::Static => "static",
            FitMode::Velocity => "velocity",
        })
    }
}

impl std::str::FromStr for FitMode {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        FitMode::ALL
            .into_iter()
            .find(|m| m.to_string() == s)
            .ok_or_else(|| format!("unknown fit mode {s:?} (expected paper, static or velocity)"))
    }
}

/// How to fit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FitOptions {
    /// Adam steps.
    pub steps: usize,
    /// Views per step.
    pub batch_size: usize,
    /// Initial learning rate per group (0 freezes a group).
    pub learning_rates: LearningRates,
    /// Learning rates at the last step, as a fraction of the initial ones.
    pub final_rate_factor: f64,
    /// Adam's constants.
    pub adam: AdamConfig,
    /// Held-out evaluation period, in steps (0: only at the end).
    pub eval_every: usize,
    /// Seed of the batch order.
    pub seed: u64,
    /// Rendering options used in fitting and evaluation.
    pub render: RenderOptions,
    /// Densify and prune on a schedule ([`crate::fit::adaptive`]); `None` keeps the count.
    pub adaptive: Option<AdaptiveOptions>,
}

/// One step of the run.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct StepRecord {
    /// Step number, from 1.
    pub step: usize,
    /// Seconds since the start of fitting.
    pub seconds: f64,
    /// Mean MSE over the step's batch (before the update).
    pub train_loss: f64,
    /// PSNR of the mean held-out MSE, on evaluated steps with held-out views.
    pub heldout_psnr: Option<f64>,
    /// Kernels after the step (and after a densify/prune round that followed it).
    pub kernels: usize,
}

/// What every training loop checks first: some training views, every image the size of
/// its camera, and valid render options.
pub(crate) fn check_fit_inputs(
    train: &[View],
    heldout: &[View],
    render: &RenderOptions,
) -> Result<()> {
    if train.is_empty() {
        return Err(Error::Usage("no training views".into()));
    }
    check_views(train)?;
    check_views(heldout)?;
    render.validate()
}

/// Checks that every view's image has its camera's size.
pub fn check_views(views: &[View]) -> Result<()> {
    for view in views {
        let c = &view.camera;
        if (view.image.width, view.image.height) != (c.width, c.height) {
            return Err(Error::invalid(
                &view.name,
                "view",
                "image",
                format!(
                    "{}×{} does not match the camera's {}×{}",
                    view.image.width, view.image.height, c.width, c.height
                ),
            ));
        }
        if let Some(weights) = &view.weights
            && weights.len() != c.pixel_count()
        {
            return Err(Error::invalid(
                &view.name,
                "view",
                "weights",
                format!("{} weights for {} pixels", weights.len(), c.pixel_count()),
            ));
        }
    }
    Ok(())
}

/// Mean MSE of `scene` over `views`.
pub fn evaluate(
    scene: &Scene,
    views: &[View],
    options: &RenderOptions,
    context: &mut RenderContext,
) -> Result<f64> {
    let mut total = 0.0;
    for view in views {
        context.render(scene, &view.camera, view.time, options)?;
        total += view_mse(context.image(), view);
    }
    Ok(total / views.len().max(1) as f64)
}

/// Mean MSE of `scene` over `views`, as [`evaluate`] gives it (the same sum in view order,
/// bit for bit), the views rendered side by side in `slots`.
pub(crate) fn evaluate_in(
    scene: &Scene,
    views: &[View],
    options: &RenderOptions,
    slots: &mut [ViewSlot],
) -> Result<f64> {
    let mut total = 0.0;
    for group in views.chunks(slots.len()) {
        let errors: Vec<Result<f64>> = slots
            .par_iter_mut()
            .zip(group)
            .map(|(slot, view)| {
                slot.context
                    .render(scene, &view.camera, view.time, options)?;
                Ok(view_mse(slot.context.image(), view))
            })
            .collect();
        for error in errors {
            total += error?;
        }
    }
    Ok(total / views.len().max(1) as f64)
}

/// The held-out PSNR after step `step` of `steps` when it is evaluated (every `eval_every`
/// steps, and the last), else `None` (also without held-out views); the views rendered in
/// `slots` ([`evaluate_in`]).
pub(crate) fn heldout_psnr_at(
    step: usize,
    (steps, eval_every): (usize, usize),
    scene: &Scene,
    heldout: &[View],
    render: &RenderOptions,
    slots: &mut [ViewSlot],
) -> Result<Option<f64>> {
    let evaluate_now = step == steps || (eval_every > 0 && step.is_multiple_of(eval_every));
    if !evaluate_now || heldout.is_empty() {
        return Ok(None);
    }
    Ok(Some(psnr(evaluate_in(scene, heldout, render, slots)?)))
}

/// The order a fit draws its training views in: a seeded shuffle per epoch.
pub(crate) struct ViewDraws {
    rng: rand_chacha::ChaCha8Rng,
    order: Vec<usize>,
    cursor: usize,
}

impl ViewDraws {
    /// Draws from `views` views with the shuffles of `seed`.
    pub(crate) fn new(views: usize, seed: u64) -> Self {
        ViewDraws {
            rng: seeded_rng(seed),
            order: (0..views).collect(),
            cursor: views,
        }
    }

    /// The next `batch` views into `drawn` (emptied first); a new shuffle starts whenever
    /// the last one is used up.
    pub(crate) fn next_batch(&mut self, batch: usize, drawn: &mut Vec<usize>) {
        drawn.clear();
        for _ in 0..batch {
            if self.cursor == self.order.len() {
                self.order.shuffle(&mut self.rng);
                self.cursor = 0;
            }
            drawn.push(self.order[self.cursor]);
            self.cursor += 1;
        }
    }
}

/// One view of a step's batch: its frame buffers and its gradients.
pub(crate) struct ViewSlot {
    pub(crate) context: RenderContext,
    pub(crate) grads: Gradients,
    v_image: Vec<f32>,
}

impl ViewSlot {
    pub(crate) fn new(scene: &Scene) -> Self {
        ViewSlot {
            context: RenderContext::new(),
            grads: Gradients::for_scene(scene),
            v_image: Vec::new(),
        }
    }

    /// Renders `view`, and sets `grads` to the gradient of its loss (`weight` times its
    /// MSE); returns the MSE.
    fn run(
        &mut self,
        scene: &Scene,
        view: &View,
        weight: f64,
        options: &RenderOptions,
    ) -> Result<f64> {
        self.grads.reset_for_scene(scene);
        // The render and its backward in one pass over the tiles (the same bits as
        // `render_for_backward`, `view_mse_with_gradient` and `backward`).
        self.context.render_and_backward(
            scene,
            &view.camera,
            view.time,
            options,
            &view_mse_gradient(view, weight),
            &mut self.v_image,
            &mut self.grads,
        )?;
        Ok(view_mse(self.context.image(), view))
    }
}

/// The slots a fit renders a step's views in: one per worker thread, at most `batch`.
pub(crate) fn view_slots(scene: &Scene, batch: usize) -> Vec<ViewSlot> {
    (0..rayon::current_num_threads().clamp(1, batch))
        .map(|_| ViewSlot::new(scene))
        .collect()
}

/// Adds to `grads` the gradient of the batch's loss, the mean MSE of the training views
/// `drawn` (indices into `train`), and returns that loss. The views run side by side in
/// `slots`, each rendered and differentiated on its own; then, in view order, each view's
/// gradient is added to `grads` and `each_view` sees its slot. Every field of a view's
/// gradient takes one term per kernel, so this is the sum the views would give one after
/// the other, bit for bit, whatever the number of slots (threads).
pub(crate) fn batch_gradients(
    slots: &mut [ViewSlot],
    scene: &Scene,
    train: &[View],
    drawn: &[usize],
    options: &RenderOptions,
    grads: &mut Gradients,
    mut each_view: impl FnMut(&ViewSlot),
) -> Result<f64> {
    let weight = 1.0 / drawn.len() as f64;
    let mut loss = 0.0;
    for views in drawn.chunks(slots.len()) {
        let losses: Vec<Result<f64>> = slots
            .par_iter_mut()
            .zip(views)
            .map(|(slot, &view)| slot.run(scene, &train[view], weight, options))
            .collect();
        for (slot, mse) in slots.iter().zip(losses) {
            loss += weight * mse?;
            grads.add(&slot.grads);
            each_view(slot);
        }
    }
    Ok(loss)
}

/// Fits `scene` in place to `train`, evaluating on `heldout`; calls `on_step` after each
/// step with its record and the scene. Returns every step's record. With `options.adaptive` the scene's kernels change
/// between steps (densify and prune); otherwise only their parameters do.
pub fn fit(
    scene: &mut Scene,
    train: &[View],
    heldout: &[View],
    options: &FitOptions,
    mut on_step: impl FnMut(&StepRecord, &Scene),
) -> Result<Vec<StepRecord>> {
    check_fit_inputs(train, heldout, &options.render)?;
    let start = Instant::now();
    let mut adam = Adam::new(scene.len(), options.adam);
    let mut grads = Gradients::zeros(scene.len());
    let mut stats = DensityStats::new(scene.len());
    let mut draws = ViewDraws::new(train.len(), options.seed);
    let batch_size = options.batch_size.clamp(1, train.len());
    // The batch's views run side by side, one per worker thread (`batch_gradients`).
    let mut slots = view_slots(scene, batch_size);
    let mut drawn = Vec::with_capacity(batch_size);
    // Grows with the steps actually run: a flag never decides an allocation up front.
    let mut records = Vec::with_capacity(options.steps.min(1 << 12));
    for step in 1..=options.steps {
        grads.reset(scene.len());
        draws.next_batch(batch_size, &mut drawn);
        let batch_loss = batch_gradients(
            &mut slots,
            scene,
            train,
            &drawn,
            &options.render,
            &mut grads,
            |_| {},
        )?;
        if !batch_loss.is_finite() {
            return Err(Error::Numeric(format!(
                "fitting diverged at step {step}: the loss is {batch_loss}; lower the learning rates"
            )));
        }
        let progress = if options.steps > 1 {
            (step - 1) as f64 / (options.steps - 1) as f64
        } else {
            1.0
        };
        let rates = options
            .learning_rates
            .scaled(options.final_rate_factor.powf(progress));
        adam.step(scene, &grads, &rates);
        if let Some(why) = non_finite_parameter(scene) {
            return Err(Error::Numeric(format!(
                "fitting diverged at step {step}: {why}; lower that learning rate, or check the dataset's focal lengths (fl_x, fl_y) and background"
            )));
        }
        if let Some(adaptive) = &options.adaptive {
            stats.accumulate(scene, &grads);
            if adaptive.round_after(step, options.steps) {
                stats.record_loss(evaluate_in(scene, train, &options.render, &mut slots)?);
                let round = if adaptive.last_round_after(step, options.steps) {
                    adaptive.without_growth()
                } else {
                    *adaptive
                };
                let (next, sources, _) = densify_and_prune(scene, &stats, &round)?;
                *scene = next;
                adam.remap(&sources);
                stats = stats.next_window(scene.len());
            }
        }
        let heldout_psnr = heldout_psnr_at(
            step,
            (options.steps, options.eval_every),
            scene,
            heldout,
            &options.render,
            &mut slots,
        )?;
        let record = StepRecord {
            step,
            seconds: start.elapsed().as_secs_f64(),
            train_loss: batch_loss,
            heldout_psnr,
            kernels: scene.len(),
        };
        on_step(&record, scene);
        records.push(record);
    }
    Ok(records)
}

/// The first parameter of `scene` that left the finite numbers (or a scale that is no
/// longer positive), named by its group and the field of that group's learning rate
/// (`` `lr_mean` ``, which the command line shows as its flag).
#[must_use]
pub fn non_finite_parameter(scene: &Scene) -> Option<String> {
    let bad = |values: &[f64]| values.iter().any(|v| !v.is_finite());
    for i in 0..scene.len() {
        let found = if bad(&scene.means[i][..3]) {
            Some(("mean", "`lr_mean`"))
        } else if bad(&scene.means[i][3..]) {
            Some(("time", "`lr_time`"))
        } else if bad(&scene.scales[i]) || scene.scales[i].iter().any(|&s| s <= 0.0) {
            Some(("scale", "`lr_scale`"))
        } else if bad(&scene.amplitudes[i]) {
            Some(("amplitude", "`lr_amplitude`"))
        } else if bad(&scene.velocities[i]) {
            Some(("velocity", "`lr_velocity`"))
        } else if bad(&scene.rotations[i]) {
            Some(("rotation", "none: rotations come from the start"))
        } else {
            None
        };
        if let Some((group, flag)) = found {
            return Some(format!(
                "kernel {i}'s {group} is no longer finite (its rate: {flag})"
            ));
        }
    }
    bad(&scene.background)
        .then(|| "the background is no longer finite (its rate: `lr_background`)".to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_non_finite_parameter_is_named_with_its_rate() {
        let kernel = crate::model::scene::Kernel::new([0.0; 4], [0.1; 4], [0.5; 3]);
        let mut scene = Scene::from_kernels(&[kernel, kernel], [0.0; 3], "<test>").unwrap();
        assert_eq!(non_finite_parameter(&scene), None);
        scene.amplitudes[1][2] = f64::NAN;
        let why = non_finite_parameter(&scene).unwrap();
        assert!(
            why.contains("kernel 1") && why.contains("`lr_amplitude`"),
            "{why}"
        );
        scene.amplitudes[1][2] = 0.5;
        scene.scales[0][3] = 0.0;
        assert!(non_finite_parameter(&scene).unwrap().contains("`lr_scale`"));
        scene.scales[0][3] = 0.1;
        scene.background[0] = f64::INFINITY;
        assert!(
            non_finite_parameter(&scene)
                .unwrap()
                .contains("`lr_background`")
        );
    }
}
