//! The training loop of both blends: Adam on the mean loss over mini-batches of views
//! (SPEC §6, §8): the MSE, or for the alpha fit by default 3DGS's L1 + D-SSIM
//! ([`TrainingLoss`]); the loss a step reports is the MSE either way.
//!
//! Each step draws `batch_size` training views (a seeded shuffle, epoch by epoch), renders
//! each, accumulates `∂(mean over the batch of the loss)/∂θ` through the backward pass, and takes
//! one Adam step over the blend's parameter table ([`crate::fit::adam`]) with the scheduled
//! learning rates: a decaying group's rate at step k of K is
//! `lr · final_factor^((k-1)/(K-1))` (`final_factor = 1` keeps it constant), the
//! regularisers' gradient ([`crate::fit::regularise`]) added first. The blend's density rules
//! ([`crate::fit::density`]) then change the kernels when a round is due, and once growth
//! ends the pruning by score ([`crate::fit::density::prune`]) removes kernels when a round
//! of it is due.
//! Every `eval_every` steps and at the last, the mean MSE over the held-out views is
//! measured.
//!
//! A view in which no kernel reaches the screen adds a zero gradient; when no view drawn in
//! the steps that draw every view once (or in the whole run) sees a kernel, nothing can ever
//! move into sight, and the fit is refused with a message saying so.
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
use crate::fit::adam::{Adam, AdamConfig, Field, ParameterGroup, non_finite_parameter};
use crate::fit::coarse::{SizeStage, StagedViews};
use crate::fit::density::prune::{keep_kernels, kept_after_pruning, temporal_weight, time_spacing};
use crate::fit::density::{DensityRules, DensityStats, Line, ShapeBound, SpacetimePrune};
use crate::fit::loss::{psnr, view_mse, view_mse_gradient};
use crate::fit::regularise::Regularisers;
use crate::fit::spread::{self, BatchTotals};
use crate::fit::ssim::{L1Dssim, SsimScratch};
use crate::fit::window::Windows;
use crate::model::error::{Error, Result};
use crate::model::random::seeded_rng;
use crate::model::scene::Scene;
use crate::model::{Dataset, View};
use crate::render::{RenderContext, RenderOptions};

/// The training loop's input, whichever the blend: its schedule, its parameter table and
/// its density rules (made by `crate::fit::additive` and `crate::fit::alpha` from the
/// blends' options).
#[derive(Clone, Debug, PartialEq)]
pub struct Training {
    /// Adam steps.
    pub steps: usize,
    /// Views per step.
    pub batch_size: usize,
    /// Held-out evaluation period, in steps (0: only at the end).
    pub eval_every: usize,
    /// Seed of the batch order.
    pub draw_seed: u64,
    /// Rendering options used in fitting and evaluation.
    pub render: RenderOptions,
    /// Adam's constants.
    pub adam: AdamConfig,
    /// What the fit moves, and how fast.
    pub groups: Vec<ParameterGroup>,
    /// The decaying groups' rates at the last step, as a fraction of their first.
    pub final_rate_factor: f64,
    /// Density control between steps; `None` keeps the kernel count.
    pub density: Option<DensityRules>,
    /// Coarse to fine: the stages that fit downscaled views before the full-size steps
    /// ([`crate::fit::coarse`]); empty: every step at full size.
    pub coarse: Vec<SizeStage>,
    /// When the held-out PSNR stops rising, stop before the last step; `None`: never.
    pub early_stop: Option<EarlyStop>,
    /// Each step fits one window of about this side of each drawn view
    /// ([`crate::fit::window`]); `None`: whole views.
    pub window: Option<u32>,
    /// The bound on every kernel's shape after each step ([`ShapeBound::OFF`]: none).
    pub shape_bound: ShapeBound,
    /// The per-view loss the gradient is taken of (the reported loss stays the MSE).
    pub loss: TrainingLoss,
    /// Pruning by the spatio-temporal score after growth ends ([`SpacetimePrune`]); `None`:
    /// none.
    pub prune: Option<SpacetimePrune>,
    /// Regularisers added to each step's gradient ([`Regularisers::OFF`]: none).
    pub regularisers: Regularisers,
}

/// The per-view loss a fit's gradient is taken of. Whichever it is, a step's reported
/// `train_loss` and the held-out PSNR are those of the MSE (SPEC §6).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum TrainingLoss {
    /// SPEC §6's MSE, the render and its backward fused per tile.
    Mse,
    /// 3D Gaussian splatting's `(1 - λ) L1 + λ (1 - SSIM)` ([`crate::fit::ssim`]): the
    /// whole image rendered, its gradient taken over it (SSIM's windows reach across tiles),
    /// then the backward.
    L1Dssim(L1Dssim),
}

/// The training losses by the name a caller gives (`mse`, `l1-dssim`); the D-SSIM weight
/// is a setting of its own.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LossName {
    /// [`TrainingLoss::Mse`].
    Mse,
    /// [`TrainingLoss::L1Dssim`].
    L1Dssim,
}

impl std::str::FromStr for LossName {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "mse" => Ok(LossName::Mse),
            "l1-dssim" => Ok(LossName::L1Dssim),
            _ => Err(format!("unknown loss {s:?} (expected mse or l1-dssim)")),
        }
    }
}

impl TrainingLoss {
    /// The loss's name ([`LossName`]).
    #[must_use]
    pub fn name(&self) -> LossName {
        match self {
            TrainingLoss::Mse => LossName::Mse,
            TrainingLoss::L1Dssim(_) => LossName::L1Dssim,
        }
    }
}

/// Mixed into the draw seed for the windows' draws, so that they are not the views' shuffle.
const WINDOW_SEED_BITS: u64 = 0x5749_4e44_4f57_5321;

/// The rule that ends a fit whose held-out PSNR no longer rises: once the density rules
/// can add no more kernels, a fit stops at the first evaluation at which its best held-out
/// PSNR has not risen by `min_gain_db` over the last `flat_fraction` of the steps (counted
/// from the later of that best and the end of growth). Without held-out views it never
/// acts.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EarlyStop {
    /// The fraction of the run's steps without a gain that ends it.
    pub flat_fraction: f64,
    /// The smallest rise of the held-out PSNR, in dB, that counts as a gain.
    pub min_gain_db: f64,
}

/// The early stop's state over a run: the best held-out PSNR that was a gain, and its step.
struct Plateau {
    rule: EarlyStop,
    /// Steps without a gain that end the run.
    flat_steps: usize,
    /// The step after which kernels are no longer added.
    growth_ends: usize,
    best: Option<(f64, usize)>,
}

impl Plateau {
    fn new(rule: EarlyStop, steps: usize, growth_ends: usize) -> Self {
        Plateau {
            rule,
            flat_steps: ((rule.flat_fraction * steps as f64).ceil() as usize).max(1),
            growth_ends,
            best: None,
        }
    }

    /// Whether the run ends after `step`, whose held-out PSNR is `psnr` (when evaluated).
    fn ends_after(&mut self, step: usize, psnr: Option<f64>) -> bool {
        let Some(psnr) = psnr else {
            return false;
        };
        match self.best {
            Some((best, _)) if psnr < best + self.rule.min_gain_db => {}
            _ => self.best = Some((psnr, step)),
        }
        let since = self.best.map_or(step, |(_, at)| at).max(self.growth_ends);
        step > self.growth_ends && step - since >= self.flat_steps
    }
}

impl Training {
    /// The last step (1-based) after which the density rules may add kernels (0: never).
    #[must_use]
    pub fn growth_ends(&self) -> usize {
        self.density
            .as_ref()
            .map_or(0, |rules| rules.growth_ends(self.steps))
    }

    /// The decay factor of the rates at step `step` (1-based): `final_rate_factor^p`, `p`
    /// from 0 at the first step to 1 at the last.
    #[must_use]
    pub fn decay(&self, step: usize) -> f64 {
        let progress = (step - 1) as f64 / (self.steps.max(2) - 1) as f64;
        self.final_rate_factor.powf(progress)
    }
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
    /// The (pixel, kernel) pairs the step's training renders composited (SPEC §5; summed
    /// over its batch): the work of its render and backward, which grows as kernels widen
    /// as well as with their count (the time-left estimate, [`crate::fit::time_left`],
    /// counts kernels only; `docs/fitting.md`, "Time left", says why).
    pub pairs: u64,
    /// The downscale factor of the step's training views (1: full size;
    /// [`crate::fit::coarse`]).
    pub downscale: u32,
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
    if let Some(ranks) = spread::ranks() {
        return spread::evaluate(ranks, scene, views, options, &mut [context]);
    }
    let mut total = 0.0;
    for view in views {
        context.render(scene, &view.camera, view.time, options)?;
        total += view_mse(context.image(), view);
    }
    Ok(total / views.len().max(1) as f64)
}

/// The score of a fitted scene on one split of a dataset.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SplitScore {
    /// `train`, `val` or `test`.
    pub split: &'static str,
    /// Views in the split.
    pub views: usize,
    /// Mean MSE over them.
    pub mse: f64,
    /// The mean over the views of each view's PSNR (as papers report a test split).
    pub mean_view_psnr: f64,
    /// The mean over the views of each view's SSIM ([`crate::fit::loss::ssim`]); held-out
    /// splits only (`None` for `train`).
    pub ssim: Option<f64>,
}

impl SplitScore {
    /// The PSNR of the mean MSE.
    #[must_use]
    pub fn psnr(&self) -> f64 {
        psnr(self.mse)
    }
}

/// The score of `scene` on every non-empty split of `dataset`: each view rendered once, its
/// MSE added in view order (the sum [`evaluate`] takes, bit for bit), its PSNR, and on
/// held-out splits its SSIM.
pub fn evaluate_splits(
    scene: &Scene,
    dataset: &Dataset,
    options: &RenderOptions,
) -> Result<Vec<SplitScore>> {
    let mut context = RenderContext::new();
    let splits = [
        ("train", &dataset.train),
        ("val", &dataset.val),
        ("test", &dataset.test),
    ];
    let mut scores = Vec::new();
    for (split, views) in splits {
        if views.is_empty() {
            continue;
        }
        let heldout = split != "train";
        let (mut mse, mut view_psnr, mut ssim) = (0.0, 0.0, 0.0);
        for view in views {
            context.render(scene, &view.camera, view.time, options)?;
            let error = view_mse(context.image(), view);
            mse += error;
            view_psnr += psnr(error);
            if heldout {
                ssim += crate::fit::loss::ssim(context.image(), &view.image);
            }
        }
        let n = views.len() as f64;
        scores.push(SplitScore {
            split,
            views: views.len(),
            mse: mse / n,
            mean_view_psnr: view_psnr / n,
            ssim: heldout.then_some(ssim / n),
        });
    }
    Ok(scores)
}

/// Mean MSE of `scene` over `views`, as [`evaluate`] gives it (the same sum in view order,
/// bit for bit), the views rendered side by side in `slots`.
pub(crate) fn evaluate_in(
    scene: &Scene,
    views: &[View],
    options: &RenderOptions,
    slots: &mut [ViewSlot],
) -> Result<f64> {
    if let Some(ranks) = spread::ranks() {
        let mut contexts: Vec<_> = slots.iter_mut().map(|s| &mut s.context).collect();
        return spread::evaluate(ranks, scene, views, options, &mut contexts);
    }
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
    /// The (pixel, kernel) pairs of the last view [`ViewSlot::run`] rendered.
    pairs: u64,
    v_image: Vec<f32>,
    ssim: SsimScratch,
}

impl ViewSlot {
    pub(crate) fn new(scene: &Scene) -> Self {
        ViewSlot {
            context: RenderContext::new(),
            grads: Gradients::for_scene(scene),
            pairs: 0,
            v_image: Vec::new(),
            ssim: SsimScratch::default(),
        }
    }

    /// Renders `view`, and sets `grads` to the gradient of its loss (`weight` times its
    /// `loss`) and `pairs` to its render's; returns the MSE.
    fn run(
        &mut self,
        scene: &Scene,
        view: &View,
        (weight, loss): (f64, &TrainingLoss),
        options: &RenderOptions,
    ) -> Result<f64> {
        self.grads.reset_for_scene(scene);
        let (camera, tau) = (&view.camera, view.time);
        let stats = match loss {
            // The render and its backward in one pass over the tiles (the same bits as
            // `render_for_backward`, `view_mse_with_gradient` and `backward`).
            TrainingLoss::Mse => self.context.render_and_backward(
                scene,
                camera,
                tau,
                options,
                &view_mse_gradient(view, weight),
                &mut self.v_image,
                &mut self.grads,
            )?,
            TrainingLoss::L1Dssim(loss) => {
                let stats = self
                    .context
                    .render_for_backward(scene, camera, tau, options)?;
                loss.loss_and_gradient(
                    self.context.image(),
                    view,
                    weight,
                    &mut self.v_image,
                    &mut self.ssim,
                );
                self.context
                    .backward(scene, camera, tau, options, &self.v_image, &mut self.grads);
                stats
            }
        };
        self.pairs = stats.pairs;
        Ok(view_mse(self.context.image(), view))
    }

    /// Renders `view` and runs the backward from `∂L/∂C = 1` on every pixel: each projected
    /// kernel's colour gradient is then its `Σ_pixels α̂ T` (SPEC §8).
    fn contributions(&mut self, scene: &Scene, view: &View, options: &RenderOptions) -> Result<()> {
        self.grads.reset_for_scene(scene);
        let (camera, tau) = (&view.camera, view.time);
        self.context
            .render_for_backward(scene, camera, tau, options)?;
        self.v_image.clear();
        self.v_image.resize(3 * camera.pixel_count(), 1.0);
        self.context
            .backward(scene, camera, tau, options, &self.v_image, &mut self.grads);
        Ok(())
    }

    /// The last view's `Σ_pixels α̂ T` ([`ViewSlot::contributions`]): `(kernel, its
    /// colour gradient's first channel)` for every kernel it projected.
    fn colour_contributions(&self) -> impl Iterator<Item = (usize, f64)> + '_ {
        let colour = &self.context.backward.screen.v_amplitudes;
        self.context
            .projected
            .kernel_from_proj
            .iter()
            .enumerate()
            .map(|(p, &k)| (k as usize, colour[p][0]))
    }

    /// Whether the last view rendered here projected some kernel onto its screen.
    fn sees_a_kernel(&self) -> bool {
        !self.context.projected.kernel_from_proj.is_empty()
    }

    /// The last view's screen-space positional gradients: `(kernel, ∂L/∂m2)` for every
    /// kernel it projected.
    fn screen_gradients(&self) -> impl Iterator<Item = (usize, [f64; 2])> + '_ {
        let screen = &self.context.backward.screen.v_means;
        self.context
            .projected
            .kernel_from_proj
            .iter()
            .enumerate()
            .map(|(p, &k)| (k as usize, screen[p]))
    }
}

/// The slots a fit renders a step's views in: one per worker thread, at most `batch`.
pub(crate) fn view_slots(scene: &Scene, batch: usize) -> Vec<ViewSlot> {
    (0..rayon::current_num_threads().clamp(1, batch))
        .map(|_| ViewSlot::new(scene))
        .collect()
}

/// Adds to `grads` the gradient of the batch's loss (the mean over the training views
/// `drawn`, indices into `train`, of `objective`), and returns their mean MSE and their
/// renders' (pixel, kernel) pairs. The views run side by side in
/// `slots`, each rendered and differentiated on its own; then, in view order, each view's
/// gradient is added to `grads` and `each_view` sees whether it saw a kernel and its screen
/// gradients. Spread over MPI ranks ([`spread`]), each rank runs its share and every rank
/// adds the gathered views in the same order. Every field of a view's
/// gradient takes one term per kernel, so this is the sum the views would give one after
/// the other, bit for bit, whatever the number of slots (threads).
pub(crate) fn batch_gradients(
    slots: &mut [ViewSlot],
    scene: &Scene,
    train: &[View],
    drawn: &[usize],
    (options, objective): (&RenderOptions, &TrainingLoss),
    grads: &mut Gradients,
    mut each_view: impl FnMut(bool, &mut dyn Iterator<Item = (usize, [f64; 2])>),
) -> Result<BatchTotals> {
    let weight = 1.0 / drawn.len() as f64;
    if let Some(ranks) = spread::ranks() {
        // The batch spread over the ranks, summed in view order on each ([`spread::batch`]).
        return spread::batch(
            ranks,
            slots,
            drawn.len(),
            weight,
            grads,
            each_view,
            |slot, p| slot.run(scene, &train[drawn[p]], (weight, objective), options),
            |out, slot, mse| {
                spread::pack_view(
                    out,
                    (mse, slot.pairs),
                    slot.sees_a_kernel(),
                    &slot.grads,
                    slot.screen_gradients(),
                );
            },
        );
    }
    let mut totals = BatchTotals::default();
    for views in drawn.chunks(slots.len()) {
        let losses: Vec<Result<f64>> = slots
            .par_iter_mut()
            .zip(views)
            .map(|(slot, &view)| slot.run(scene, &train[view], (weight, objective), options))
            .collect();
        for (slot, mse) in slots.iter().zip(losses) {
            totals.loss += weight * mse?;
            totals.pairs += slot.pairs;
            grads.add(&slot.grads);
            each_view(slot.sees_a_kernel(), &mut slot.screen_gradients());
        }
    }
    Ok(totals)
}

/// Fits `scene` in place to `train`, evaluating on `heldout`, as `training` says; calls
/// `on_step` after each step with its record and the scene. Returns every step's record
/// (fewer than `training.steps` when its [`EarlyStop`] ended the run).
/// With density rules the scene's kernels change between steps; otherwise only their
/// parameters do.
///
/// A step: draw the batch, render and differentiate its views (the screen gradients go to
/// the density statistics), one Adam step over the parameter table, the finite check, the
/// density rules, the held-out evaluation when due.
pub fn fit(
    scene: &mut Scene,
    all_train: &[View],
    heldout: &[View],
    training: &Training,
    mut on_step: impl FnMut(&StepRecord, &Scene),
) -> Result<Vec<StepRecord>> {
    check_fit_inputs(all_train, heldout, &training.render)?;
    scene.validate("<fit start>")?;
    let start = Instant::now();
    let steps = training.steps;
    let render = &training.render;
    let batch = training.batch_size.clamp(1, all_train.len());
    // The batch's views run side by side, one per worker thread (`batch_gradients`).
    let mut slots = view_slots(scene, batch);
    give_fitted_motion(scene, &training.groups);
    let mut grads = Gradients::for_scene(scene);
    let mut adam = Adam::new(scene, &training.groups, training.adam);
    let mut stats = DensityStats::new(scene.len());
    let mut draws = ViewDraws::new(all_train.len(), training.draw_seed);
    let mut drawn = Vec::with_capacity(batch);
    // Grows with the steps actually run: a flag never decides an allocation up front.
    let mut records = Vec::with_capacity(steps.min(1 << 12));
    // Whether some training view has seen a kernel yet (a view that sees none is a step with
    // zero gradient; views that never see one leave nothing to fit).
    let mut seen_any = false;
    // Steps until every training view has been drawn once (the draws go epoch by epoch).
    let first_epoch = all_train.len().div_ceil(batch);
    let mut staged = StagedViews::new(&training.coarse);
    let mut plateau = training
        .early_stop
        .map(|rule| Plateau::new(rule, steps, training.growth_ends()));
    let mut windows = training
        .window
        .map(|side| Windows::new(side, training.draw_seed ^ WINDOW_SEED_BITS));
    for step in 1..=steps {
        let train = staged.at(all_train, step, steps)?;
        grads.reset_for_scene(scene);
        draws.next_batch(batch, &mut drawn);
        let (batch_views, batch_drawn) = match &mut windows {
            Some(windows) => windows.draw(train, &drawn),
            None => (train, &drawn[..]),
        };
        let weight = 1.0 / batch as f64;
        let totals = batch_gradients(
            &mut slots,
            scene,
            batch_views,
            batch_drawn,
            (render, &training.loss),
            &mut grads,
            |sees, screen| {
                seen_any |= sees;
                stats.add_view(screen, weight);
            },
        )?;
        keep_motion_where_fitted(training, &mut stats, &mut grads);
        if !seen_any && (step == first_epoch || step == steps) {
            let windowed = windows.is_some();
            seen_any = whole_views_in_sight(windowed, scene, train, render, &mut slots, step)?;
        }
        adam_step_checked(&mut adam, scene, &mut grads, (step, totals.loss), training)?;
        bound_shapes(scene, all_train, &training.shape_bound);
        if let Some(rules) = &training.density {
            stats.add_step(scene, &grads);
            run_density_rules(
                (rules, training.prune),
                (step, steps),
                scene,
                &mut stats,
                &mut adam,
                (train, render, &mut slots[..]),
            )?;
        }
        let heldout_psnr = heldout_psnr_at(
            step,
            (steps, training.eval_every),
            scene,
            heldout,
            render,
            &mut slots,
        )?;
        let record = StepRecord {
            step,
            seconds: start.elapsed().as_secs_f64(),
            train_loss: totals.loss,
            heldout_psnr,
            kernels: scene.len(),
            pairs: totals.pairs,
            downscale: staged.downscale(),
        };
        on_step(&record, scene);
        records.push(record);
        if let Some(plateau) = &mut plateau
            && plateau.ends_after(step, heldout_psnr)
        {
            break;
        }
    }
    Ok(records)
}

/// The density rules after step `step` of `steps`: kernels added, split, pruned or their
/// opacities reset, and Adam's moments and the fitted motion fields made to follow; then
/// the pruning by score when a round of it is due. The rules may evaluate the scene on the
/// stage's training views (`evaluation`).
fn run_density_rules(
    (rules, prune): (&DensityRules, Option<SpacetimePrune>),
    (step, steps): (usize, usize),
    scene: &mut Scene,
    stats: &mut DensityStats,
    adam: &mut Adam,
    (train, render, slots): (&[View], &RenderOptions, &mut [ViewSlot]),
) -> Result<()> {
    let change = rules.after_step((step, steps), scene, stats, |scene| {
        evaluate_in(scene, train, render, slots)
    })?;
    if change.opacities_reset {
        adam.clear(Field::Opacity);
    }
    if let Some(sources) = change.sources {
        adam.remap(&sources);
        give_fitted_motion(scene, adam.groups());
    }
    if let Some(fraction) = prune.and_then(|rule| rule.due(step, rules.growth_ends(steps))) {
        let sources = prune_by_score(fraction, scene, (train, render, slots), adam)?;
        // The kept kernels keep their lines of descent (their turning counts too).
        let lines = sources
            .iter()
            .map(|source| source.map_or_else(Line::default, |i| stats.line(i)))
            .collect();
        *stats = stats.next_window(lines);
    }
    Ok(())
}

/// Removes the lowest-scored `fraction` of the kernels of `scene` by their spatio-temporal
/// score over the stage's training views `train` ([`crate::fit::density::prune`]), and
/// makes Adam's moments and the fitted motion fields follow; returns, per kernel kept, the
/// old kernel it was.
fn prune_by_score(
    fraction: f64,
    scene: &mut Scene,
    (train, render, slots): (&[View], &RenderOptions, &mut [ViewSlot]),
    adam: &mut Adam,
) -> Result<Vec<Option<usize>>> {
    let scores = spacetime_scores_in(scene, train, render, slots)?;
    let sources = keep_kernels(scene, &kept_after_pruning(&scores, fraction));
    adam.remap(&sources);
    give_fitted_motion(scene, adam.groups());
    Ok(sources)
}

/// Per kernel of the alpha scene `scene`, its spatio-temporal score over `views`
/// ([`crate::fit::density::prune`]): each view's `Σ_pixels α̂ T` of the kernel (the colour
/// gradient of a backward from `∂L/∂C = 1`), times the kernel's temporal weight at the
/// view's time, added in view order: the same bits for any thread count.
pub fn spacetime_scores(scene: &Scene, views: &[View], render: &RenderOptions) -> Result<Vec<f64>> {
    let mut slots = view_slots(scene, views.len().max(1));
    spacetime_scores_in(scene, views, render, &mut slots)
}

/// [`spacetime_scores`], the views rendered side by side in `slots`; spread over MPI ranks
/// ([`spread::view_terms`]), each rank renders its share and every rank adds the gathered
/// contributions in view order, as one process adds them.
fn spacetime_scores_in(
    scene: &Scene,
    views: &[View],
    render: &RenderOptions,
    slots: &mut [ViewSlot],
) -> Result<Vec<f64>> {
    let times: Vec<f64> = views.iter().map(|v| v.time).collect();
    let spacing = time_spacing(&times);
    let mut scores = vec![0.0; scene.len()];
    let mut add_view = |view: &View, colours: &mut dyn Iterator<Item = (usize, f64)>| {
        for (k, colour) in colours {
            let weight = temporal_weight(scene.means[k][3], scene.scales[k][3], view.time, spacing);
            scores[k] += colour * weight;
        }
    };
    if let Some(ranks) = spread::ranks() {
        spread::view_terms(
            ranks,
            (views.len(), scene.len()),
            slots,
            |slot, p| slot.contributions(scene, &views[p], render),
            |slot, term| slot.colour_contributions().for_each(|(k, c)| term(k, c)),
            |p, colours| add_view(&views[p], colours),
        )?;
    } else {
        for group in views.chunks(slots.len()) {
            let done: Vec<Result<()>> = slots
                .par_iter_mut()
                .zip(group)
                .map(|(slot, view)| slot.contributions(scene, view, render))
                .collect();
            for ((slot, view), result) in slots.iter().zip(group).zip(done) {
                result?;
                add_view(view, &mut slot.colour_contributions());
            }
        }
    }
    Ok(scores)
}

/// With motion only where needed ([`DensityRules::fits_motion_where_needed`]), zeroes the
/// SPEC §9 gradients of the kernels that carry none ([`DensityStats`]' lines); else nothing.
fn keep_motion_where_fitted(training: &Training, stats: &mut DensityStats, grads: &mut Gradients) {
    if let Some(rules) = &training.density
        && rules.fits_motion_where_needed()
    {
        stats.keep_motion_to_moving_kernels(grads);
    }
}

/// One Adam step of `scene` at `step` on `grads` with the training's regularisers added,
/// refused when the step's loss `train_loss` or a parameter after it leaves the finite
/// numbers (naming the parameter and its rate).
fn adam_step_checked(
    adam: &mut Adam,
    scene: &mut Scene,
    grads: &mut Gradients,
    (step, train_loss): (usize, f64),
    training: &Training,
) -> Result<()> {
    if !train_loss.is_finite() {
        return Err(Error::Numeric(format!(
            "fitting diverged at step {step}: the loss is {train_loss}; lower the learning rates"
        )));
    }
    training.regularisers.add_gradient(scene, grads);
    adam.step(scene, grads, step, training.decay(step));
    if let Some(why) = non_finite_parameter(scene, adam.groups()) {
        return Err(Error::Numeric(format!(
            "fitting diverged at step {step}: {why}; lower that learning rate, or check the dataset's focal lengths (fl_x, fl_y) and background"
        )));
    }
    Ok(())
}

/// The shape bound's projection of `scene` after a step, relative to the cameras of `train`
/// ([`ShapeBound::project`]); nothing when the bound is off.
fn bound_shapes(scene: &mut Scene, train: &[View], bound: &ShapeBound) {
    if !bound.is_off() {
        let centres: Vec<[f64; 3]> = train.iter().map(|v| v.camera.centre()).collect();
        bound.project(scene, &centres);
    }
}

/// Gives every kernel of `scene` the SPEC §9 fields that `groups` fit (zero where a kernel
/// has none): their rows must exist for their gradients and moments, and a kernel without
/// them would not move along them.
fn give_fitted_motion(scene: &mut Scene, groups: &[ParameterGroup]) {
    if groups.iter().any(|g| g.field == Field::Acceleration) {
        scene.accelerations.resize(scene.len(), [0.0; 3]);
    }
    if groups.iter().any(|g| g.field == Field::AngularVelocity) {
        scene.angular_velocities.resize(scene.len(), [0.0; 4]);
    }
}

/// After step `step`, at which no training view drawn has seen a kernel: `true` when some
/// whole view of `train` does (the steps' windows all missed it), else the fit's refusal
/// ([`nothing_in_sight`]).
fn whole_views_in_sight(
    windowed: bool,
    scene: &Scene,
    train: &[View],
    render: &RenderOptions,
    slots: &mut [ViewSlot],
    step: usize,
) -> Result<bool> {
    if windowed && some_view_sees_a_kernel(scene, train, render, slots)? {
        return Ok(true);
    }
    Err(nothing_in_sight(scene, train, step))
}

/// Whether some view of `views`, whole, projects a kernel of `scene` onto its screen.
fn some_view_sees_a_kernel(
    scene: &Scene,
    views: &[View],
    render: &RenderOptions,
    slots: &mut [ViewSlot],
) -> Result<bool> {
    for view in views {
        let slot = &mut slots[0];
        slot.context
            .render(scene, &view.camera, view.time, render)?;
        if slot.sees_a_kernel() {
            return Ok(true);
        }
    }
    Ok(false)
}

/// The error of a fit whose training views saw no kernel in its first `steps` steps (every
/// view once, or the whole run): with zero gradients nothing would ever move into sight.
fn nothing_in_sight(scene: &Scene, train: &[View], steps: usize) -> Error {
    Error::usage(format!(
        "no training view drawn in the first {steps} step(s) ({} training views) sees any of the \
         start's {} kernels, and a fit cannot move what no camera sees: check the cameras' poses \
         and intrinsics (`transform_matrix`, `fl_x`, `fl_y`, `cx`, `cy`; COLMAP cameras and \
         images), the point cloud the fit starts from, or the start scene",
        train.len(),
        scene.len(),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    const RULE: EarlyStop = EarlyStop {
        flat_fraction: 0.1,
        min_gain_db: 0.05,
    };

    /// A run of 100 steps, growth until step 60, evaluated every 5 steps: the step after
    /// which `psnr` (by step) stops it, if any.
    fn stop_step(psnr: impl Fn(usize) -> f64) -> Option<usize> {
        let mut plateau = Plateau::new(RULE, 100, 60);
        (1..=100).find(|&step| plateau.ends_after(step, (step % 5 == 0).then(|| psnr(step))))
    }

    #[test]
    fn a_fit_stops_once_its_heldout_psnr_is_flat_for_the_window_after_growth() {
        // Rising by 0.1 dB per evaluation until step 70, then flat: stopped 10 steps on.
        assert_eq!(stop_step(|s| 0.02 * s.min(70) as f64), Some(80));
        // Flat from the start: not before growth ends, then after the window.
        assert_eq!(stop_step(|_| 30.0), Some(70));
        // Rising by 0.06 dB every 5 steps throughout: never.
        assert_eq!(stop_step(|s| 0.012 * s as f64), None);
        // Rising by 0.04 dB over the window (below the gain) counts as flat: the last gain
        // of 0.05 dB since the one before is at step 65.
        assert_eq!(stop_step(|s| 0.004 * s as f64), Some(75));
        // Without evaluations, never.
        let mut plateau = Plateau::new(RULE, 100, 60);
        assert!((1..=100).all(|step| !plateau.ends_after(step, None)));
    }
}
