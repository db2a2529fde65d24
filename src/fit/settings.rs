//! What a caller chose for a fit, and the plan of each blend made from it: every setting
//! either acts on the chosen blend's fit or is refused naming the setting and the blend it
//! belongs to, never ignored.
//!
//! A [`FitSettings`] holds each setting as the caller gave it (`None`, or `false`, where the
//! caller left the choice to the plan). [`FitSettings::additive_plan`] turns it into the
//! additive fit's [`FitPlan`] (SPEC §5–6), [`FitSettings::alpha_options`] into the alpha
//! fit's [`AlphaFitOptions`] (SPEC §8); the defaults are those of
//! [`crate::fit::defaults`] (through [`FitPlan::default`] and [`DEFAULT_ALPHA`]), and
//! [`FitSettings::prepare`] then sets the alpha defaults the caller left by the data: the
//! pruning share and the loss by its background, the steps, batch and density period by
//! [`alpha_schedule`] where no step count was given.
//!
//! Three kinds of setting ([`BOTH_BLENDS`], [`ADDITIVE_ONLY`], [`ALPHA_ONLY`]):
//! - **both blends**: steps, batch, seed, start and budget counts, the background, the
//!   rendering options, the learning rates of the groups both models have (means, times,
//!   velocities, scales, amplitudes: the alpha colour's base), the final rate factor, the
//!   density rounds' schedule and thresholds, and freezing means, times or amplitudes (a
//!   frozen group's rate is 0);
//! - **additive only**: the mode and what it fits, merging, `min_improvement`, `min_scale`,
//!   the random start's box, time range, scales and amplitude, `adaptive` (the alpha fit
//!   always densifies and prunes), the background's rate and freezing (the alpha fit keeps
//!   its background fixed at its start);
//! - **alpha only**: SH, the opacity, rotation and SH rates, the opacity reset, the split
//!   size (`percent_dense`), the split in time, the coarse stages, the early stop and the
//!   training loss (`loss`, `dssim_weight`; the latter only with `loss` l1-dssim), the
//!   pruning by score (`prune_fraction`, `prune_rounds`; the latter only with a fraction)
//!   and the regularisers (`opacity_regulariser`, `scale_regulariser`).
//!
//! The rates' units follow each model's parameters: the alpha fit's spatial rates are
//! fractions of the cameras' box per step ([`crate::fit::alpha::AlphaRates`]), the
//! additive fit's are absolute ([`crate::fit::additive::LearningRates`]); the density threshold
//! is a mean positional gradient per standard deviation for the additive fit and a mean
//! screen gradient per pixel for the alpha fit; `prune_below` a peak amplitude for the
//! additive fit and an opacity for the alpha fit; `max_growth` the largest fraction of the
//! kernels a round densifies in both.

use crate::fit::additive::FitMode;
use crate::fit::additive::LearningRates;
use crate::fit::alpha::{AlphaFitOptions, AlphaRates, MotionFit};
use crate::fit::coarse::CoarseToFine;
use crate::fit::defaults::{
    DEFAULT_DSSIM_WEIGHT, DEFAULT_MOTION_AFTER_SPLITS, DEFAULT_MOTION_TURNING,
};
use crate::fit::density::AdditiveRules;
use crate::fit::plan::{
    BackgroundDefaults, DEFAULT_ALPHA, FitPlan, Init, ReadyFit, alpha_schedule,
    background_defaults, check_fit_numbers, fit_blend, prepare_alpha,
};
use crate::fit::ssim::L1Dssim;
use crate::fit::train::{EarlyStop, LossName, TrainingLoss};
use crate::model::error::{MAX_QUOTE, cut};
use crate::model::{Blend, Dataset, Error, Result};
use crate::render::RenderOptions;

/// Settings every blend's fit acts on.
pub const BOTH_BLENDS: [&str; 23] = [
    "steps",
    "batch",
    "start_kernels",
    "max_kernels",
    "eval_every",
    "seed",
    "background",
    "lr_mean",
    "lr_time",
    "lr_velocity",
    "lr_scale",
    "lr_amplitude",
    "lr_final",
    "densify_every",
    "densify_from",
    "densify_until",
    "densify_threshold",
    "max_growth",
    "prune_below",
    "freeze_mean",
    "freeze_time",
    "freeze_amplitude",
    "render",
];

/// Settings only the additive fit acts on.
pub const ADDITIVE_ONLY: [&str; 13] = [
    "mode",
    "fit_velocity",
    "fit_scale",
    "adaptive",
    "min_improvement",
    "merge_tolerance",
    "min_scale",
    "box",
    "time_range",
    "init_scale",
    "init_amplitude",
    "lr_background",
    "freeze_background",
];

/// Settings only the alpha fit acts on.
pub const ALPHA_ONLY: [&str; 21] = [
    "sh",
    "sh_raise_every",
    "lr_opacity",
    "lr_rotation",
    "lr_sh",
    "opacity_reset_every",
    "percent_dense",
    "time_split_fraction",
    "coarse_to_fine",
    "lr_acceleration",
    "lr_angular_velocity",
    "early_stop",
    "window",
    "loss",
    "dssim_weight",
    "motion",
    "motion_after_splits",
    "prune_fraction",
    "prune_rounds",
    "opacity_regulariser",
    "scale_regulariser",
];

/// Learning rates a caller chose, per group (`None`: the blend's default).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RateSettings {
    /// Spatial means (both blends).
    pub mean: Option<f64>,
    /// Time means (both blends).
    pub time: Option<f64>,
    /// Velocities (both blends).
    pub velocity: Option<f64>,
    /// Log scales (both blends).
    pub scale: Option<f64>,
    /// Amplitudes: the additive colour, the alpha colour's base (both blends).
    pub amplitude: Option<f64>,
    /// The background (additive: the alpha fit keeps its background fixed).
    pub background: Option<f64>,
    /// Opacity logits (alpha).
    pub opacity: Option<f64>,
    /// SPEC §9 accelerations (alpha).
    pub acceleration: Option<f64>,
    /// SPEC §9 angular velocities (alpha).
    pub angular_velocity: Option<f64>,
    /// Quaternions (alpha).
    pub rotation: Option<f64>,
    /// SH coefficients beyond the base colour (alpha).
    pub sh: Option<f64>,
}

/// Everything a caller can choose about a fit, as chosen: `None` (or `false`) where the
/// plan of the blend decides.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FitSettings {
    /// Adam steps.
    pub steps: Option<usize>,
    /// Views per step.
    pub batch: Option<usize>,
    /// Kernels an automatic start makes.
    pub start_kernels: Option<usize>,
    /// Most kernels the density rounds may reach.
    pub max_kernels: Option<usize>,
    /// Held-out evaluation period in steps (0: only at the end).
    pub eval_every: Option<usize>,
    /// Seed of the start and of the batch order.
    pub seed: Option<u64>,
    /// Background colour (the start's; fitted by the additive fit unless frozen).
    pub background: Option<[f64; 3]>,
    /// Rendering options of fitting and evaluation.
    pub render: RenderOptions,
    /// Learning rates.
    pub rates: RateSettings,
    /// Learning rates at the last step as a fraction of the first.
    pub lr_final: Option<f64>,
    /// Steps between density rounds.
    pub densify_every: Option<usize>,
    /// Density rounds from this fraction of the run …
    pub densify_from: Option<f64>,
    /// … until this one.
    pub densify_until: Option<f64>,
    /// The gradient at which a kernel is densified (units by blend: see the module docs).
    pub densify_threshold: Option<f64>,
    /// Largest fraction of the kernels densified in one round.
    pub max_growth: Option<f64>,
    /// Kernels below this are pruned (additive: peak amplitude; alpha: opacity).
    pub prune_below: Option<f64>,
    /// Keep the spatial means fixed.
    pub freeze_mean: bool,
    /// Keep the time means fixed.
    pub freeze_time: bool,
    /// Keep the amplitudes fixed.
    pub freeze_amplitude: bool,
    /// Additive: keep the background fixed.
    pub freeze_background: bool,
    /// Additive: what the fit moves.
    pub mode: Option<FitMode>,
    /// Additive: fit the velocities whatever the mode.
    pub fit_velocity: bool,
    /// Additive: fit the scales whatever the mode.
    pub fit_scale: bool,
    /// Additive: densify and prune a random or scene start too.
    pub adaptive: bool,
    /// Additive: densify only when the loss fell by less than this fraction.
    pub min_improvement: Option<f64>,
    /// Additive: merge kernels within this many standard deviations.
    pub merge_tolerance: Option<f64>,
    /// Additive: densified kernels above this mean spatial scale are split.
    pub min_scale: Option<f64>,
    /// Additive: the random start's box `x0,y0,z0,x1,y1,z1`.
    pub bounds: Option<[f64; 6]>,
    /// Additive: the random start's time range.
    pub time_range: Option<[f64; 2]>,
    /// Additive: the random start's scales.
    pub init_scale: Option<[f64; 4]>,
    /// Additive: the start's amplitude per channel.
    pub init_amplitude: Option<f64>,
    /// Alpha: SH triplets per kernel (0, 3, 8 or 15).
    pub sh: Option<usize>,
    /// Alpha: steps between SH degree raises.
    pub sh_raise_every: Option<usize>,
    /// Alpha: steps between opacity resets (0: never).
    pub opacity_reset_every: Option<usize>,
    /// Alpha: a densified kernel wider than this fraction of the box's diagonal is split.
    pub percent_dense: Option<f64>,
    /// Alpha: the σt fraction of the time range above which a kernel splits in time.
    pub time_split_fraction: Option<f64>,
    /// Alpha: the coarse stages' choice ([`crate::fit::coarse`]).
    pub coarse_to_fine: Option<CoarseToFine>,
    /// Alpha: the early stop (`Some(None)`: off).
    pub early_stop: Option<Option<EarlyStop>>,
    /// Alpha: the steps' window side ([`crate::fit::window`]; `Some(None)`: whole views).
    pub window: Option<Option<u32>>,
    /// Alpha: the training loss ([`TrainingLoss`]).
    pub loss: Option<LossName>,
    /// Alpha: `λ` of the `l1-dssim` loss ([`crate::fit::ssim`]).
    pub dssim_weight: Option<f64>,
    /// Alpha: which kernels carry fitted SPEC §9 motion ([`MotionName`]).
    pub motion: Option<MotionName>,
    /// Alpha: with `motion` auto, the splits in time of a kernel's line before it gets
    /// motion.
    pub motion_after_splits: Option<u32>,
    /// Alpha: the fraction of the kernels pruned by their spatio-temporal score after
    /// growth ([`crate::fit::density::prune`]).
    pub prune_fraction: Option<f64>,
    /// Alpha: the rounds that prune `prune_fraction` together.
    pub prune_rounds: Option<usize>,
    /// Alpha: `λo` of the L1 on the opacities ([`crate::fit::regularise`]).
    pub opacity_regulariser: Option<f64>,
    /// Alpha: `λs` of the L1 on the spatial scales.
    pub scale_regulariser: Option<f64>,
}

/// The choices of which kernels carry fitted SPEC §9 motion, by the name a caller gives
/// (`auto`, `all`, `off`; [`MotionFit`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MotionName {
    /// [`MotionFit::WhereNeeded`].
    Auto,
    /// [`MotionFit::Everywhere`].
    All,
    /// [`MotionFit::Off`].
    Off,
}

impl std::str::FromStr for MotionName {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "auto" => Ok(MotionName::Auto),
            "all" => Ok(MotionName::All),
            "off" => Ok(MotionName::Off),
            _ => Err(format!("unknown motion {s:?} (expected auto, all or off)")),
        }
    }
}

impl FitSettings {
    /// The settings chosen (by name, as in [`BOTH_BLENDS`], [`ADDITIVE_ONLY`] and
    /// [`ALPHA_ONLY`]) that only the additive fit or only the alpha fit acts on.
    fn chosen(&self) -> (Vec<&'static str>, Vec<&'static str>) {
        let r = &self.rates;
        // In the order of [`ADDITIVE_ONLY`] and [`ALPHA_ONLY`], whose names these are.
        let additive = [
            self.mode.is_some(),
            self.fit_velocity,
            self.fit_scale,
            self.adaptive,
            self.min_improvement.is_some(),
            self.merge_tolerance.is_some(),
            self.min_scale.is_some(),
            self.bounds.is_some(),
            self.time_range.is_some(),
            self.init_scale.is_some(),
            self.init_amplitude.is_some(),
            r.background.is_some(),
            self.freeze_background,
        ];
        let alpha = [
            self.sh.is_some(),
            self.sh_raise_every.is_some(),
            r.opacity.is_some(),
            r.rotation.is_some(),
            r.sh.is_some(),
            self.opacity_reset_every.is_some(),
            self.percent_dense.is_some(),
            self.time_split_fraction.is_some(),
            self.coarse_to_fine.is_some(),
            r.acceleration.is_some(),
            r.angular_velocity.is_some(),
            self.early_stop.is_some(),
            self.window.is_some(),
            self.loss.is_some(),
            self.dssim_weight.is_some(),
            self.motion.is_some(),
            self.motion_after_splits.is_some(),
            self.prune_fraction.is_some(),
            self.prune_rounds.is_some(),
            self.opacity_regulariser.is_some(),
            self.scale_regulariser.is_some(),
        ];
        let given = |names: &[&'static str], on: &[bool]| {
            names
                .iter()
                .zip(on)
                .filter(|(_, on)| **on)
                .map(|(name, _)| *name)
                .collect()
        };
        (given(&ADDITIVE_ONLY, &additive), given(&ALPHA_ONLY, &alpha))
    }

    /// An error naming the first chosen setting that `blend`'s fit cannot act on (`why`
    /// says how the fit's blend was chosen), or `Ok`.
    pub fn check_blend(&self, blend: Blend, why: &str) -> Result<()> {
        let (additive, alpha) = self.chosen();
        let (foreign, theirs) = match blend {
            Blend::Alpha => (additive, Blend::Additive),
            Blend::Additive => (alpha, Blend::Alpha),
        };
        match foreign.first() {
            None => Ok(()),
            Some(&field) => {
                let note = match field {
                    "adaptive" => " (the alpha fit always densifies and prunes)",
                    "lr_background" | "freeze_background" => {
                        " (the alpha fit keeps the background fixed at its start)"
                    }
                    _ => "",
                };
                Err(Error::setting(
                    &[field],
                    format!(
                        "`{field}` acts on the {theirs} blend's fit{note}, and this fit's blend is {blend} ({why}): add `blend` {theirs}, or leave `{field}` out"
                    ),
                ))
            }
        }
    }

    /// An error naming the first chosen setting that the start `init` (`init_text` as the
    /// caller wrote it) leaves without effect in `blend`'s fit, or `Ok`: a start count with
    /// a start that has its own; the additive random start's shape with a scene start; the
    /// additive density rounds' settings where they do not run (a random or scene start
    /// without `adaptive`); a rate of a group the additive mode does not fit; the SH's rate
    /// and schedule of an alpha fit without SH.
    pub fn check_start(&self, blend: Blend, init: &Init, init_text: &str) -> Result<()> {
        let init_text = cut(init_text, MAX_QUOTE);
        let refuse = |field: &'static str, why: String| {
            Err(Error::setting(
                &[field],
                format!("`{field}` {why}, or leave `{field}` out"),
            ))
        };
        if self.start_kernels.is_some() && *init != Init::Auto {
            return refuse(
                "start_kernels",
                format!(
                    "sizes an `auto` start, and `init` is {init_text}: give random:N for N kernels"
                ),
            );
        }
        if blend == Blend::Alpha {
            let sh_count = self.sh.unwrap_or(DEFAULT_ALPHA.sh_count);
            let sh_settings = [
                ("lr_sh", self.rates.sh.is_some()),
                ("sh_raise_every", self.sh_raise_every.is_some()),
            ];
            return match sh_settings.iter().find(|(_, given)| *given) {
                Some(&(field, _)) if sh_count == 0 => refuse(
                    field,
                    "acts on the SH coefficients, and `sh` is 0: give `sh` 3, 8 or 15".into(),
                ),
                _ => Ok(()),
            };
        }
        let start_shape = [
            ("box", self.bounds.is_some()),
            ("time_range", self.time_range.is_some()),
            ("init_scale", self.init_scale.is_some()),
            ("init_amplitude", self.init_amplitude.is_some()),
        ];
        if matches!(init, Init::Scene(_))
            && let Some(&(field, _)) = start_shape.iter().find(|(_, given)| *given)
        {
            return refuse(
                field,
                format!("shapes a random or `auto` start, and `init` is {init_text}"),
            );
        }
        let rounds = [
            ("densify_every", self.densify_every.is_some()),
            ("densify_from", self.densify_from.is_some()),
            ("densify_until", self.densify_until.is_some()),
            ("densify_threshold", self.densify_threshold.is_some()),
            ("max_growth", self.max_growth.is_some()),
            ("prune_below", self.prune_below.is_some()),
            ("max_kernels", self.max_kernels.is_some()),
            ("min_improvement", self.min_improvement.is_some()),
            ("merge_tolerance", self.merge_tolerance.is_some()),
            ("min_scale", self.min_scale.is_some()),
        ];
        if *init != Init::Auto
            && !self.adaptive
            && let Some(&(field, _)) = rounds.iter().find(|(_, given)| *given)
        {
            return refuse(
                field,
                format!(
                    "acts on the density rounds, which an additive fit from `init` {init_text} runs only with `adaptive`: add `adaptive`"
                ),
            );
        }
        let mode = self.additive().mode_for(init);
        if self.rates.velocity.is_some() && !self.fit_velocity && mode != FitMode::Velocity {
            return refuse(
                "lr_velocity",
                format!(
                    "acts when the velocities are fitted, and this additive fit's mode is {mode}: add `fit_velocity` or `mode` velocity"
                ),
            );
        }
        if self.rates.scale.is_some() && !self.fit_scale && mode == FitMode::Paper {
            return refuse(
                "lr_scale",
                format!(
                    "acts when the scales are fitted, and this additive fit's mode is {mode}: add `fit_scale` or `mode` static"
                ),
            );
        }
        Ok(())
    }

    /// Every chosen number in range for the blend it acts on (rates, fractions, counts,
    /// the background): checked before any work, whichever blend the fit turns out to be.
    pub fn validate(&self) -> Result<()> {
        self.additive().validate()?;
        if let Some(weight) = self.dssim_weight
            && !(0.0..=1.0).contains(&weight)
        {
            return Err(Error::setting(
                &["dssim_weight"],
                format!("`dssim_weight` {weight} must lie in [0, 1]"),
            ));
        }
        validate_alpha(&self.alpha())
    }

    /// The training loss chosen: `loss` (else the default's kind) with `dssim_weight` (else
    /// the default's, else [`DEFAULT_DSSIM_WEIGHT`]).
    fn training_loss(&self, default: TrainingLoss) -> TrainingLoss {
        let default_weight = match default {
            TrainingLoss::L1Dssim(loss) => loss.dssim_weight,
            TrainingLoss::Mse => DEFAULT_DSSIM_WEIGHT,
        };
        match self.loss.unwrap_or(default.name()) {
            LossName::Mse => TrainingLoss::Mse,
            LossName::L1Dssim => TrainingLoss::L1Dssim(L1Dssim {
                dssim_weight: self.dssim_weight.unwrap_or(default_weight),
            }),
        }
    }

    /// The additive fit's plan ([`FitSettings::validate`] checks its numbers); an
    /// alpha-only setting is refused.
    pub fn additive_plan(&self, why: &str) -> Result<FitPlan> {
        self.check_blend(Blend::Additive, why)?;
        Ok(self.additive())
    }

    /// The alpha fit's options ([`FitSettings::validate`] checks their numbers); an
    /// additive-only setting is refused, and `dssim_weight` without the `l1-dssim` loss.
    pub fn alpha_options(&self, why: &str) -> Result<AlphaFitOptions> {
        self.check_blend(Blend::Alpha, why)?;
        let options = self.alpha();
        self.check_motion(&options)?;
        self.check_dssim_weight(options.loss)?;
        self.check_prune_rounds(options.prune_fraction)?;
        Ok(options)
    }

    /// An error naming `dssim_weight` when it is chosen and the fit's `loss` is not
    /// `l1-dssim` (no D-SSIM term to weigh), or `Ok`.
    fn check_dssim_weight(&self, loss: TrainingLoss) -> Result<()> {
        if self.dssim_weight.is_some() && loss.name() != LossName::L1Dssim {
            return Err(Error::setting(
                &["dssim_weight"],
                "`dssim_weight` weighs the D-SSIM term of the `l1-dssim` loss, and this fit's `loss` is mse: add `loss` l1-dssim, or leave `dssim_weight` out",
            ));
        }
        Ok(())
    }

    /// An error naming `prune_rounds` when it is chosen and the fit's pruning share
    /// `prune_fraction` is 0 (no pruning to spread), or `Ok`.
    fn check_prune_rounds(&self, prune_fraction: f64) -> Result<()> {
        if self.prune_rounds.is_some() && prune_fraction == 0.0 {
            return Err(Error::setting(
                &["prune_rounds"],
                "`prune_rounds` spreads the pruning of `prune_fraction` over rounds, and this fit's `prune_fraction` is 0 (no pruning): give `prune_fraction`, or leave `prune_rounds` out",
            ));
        }
        Ok(())
    }

    /// The alpha fit's `options` for `dataset` (its training frames from `origin`), with
    /// notes on what the data chose: the pruning share and the loss where the caller gave
    /// none ([`background_defaults`]), the steps, the density period and the batch where it
    /// gave no step count ([`alpha_schedule`]), and every chosen setting that the data
    /// leaves without effect refused by name: `early_stop` without held-out views, a
    /// `window` that cuts no training view, `prune_rounds` where the data's pruning share
    /// is 0. Also whether the training views are still photos from sparse views (for the
    /// time-left estimate, [`ReadyFit::of_sparse_photos`]).
    fn alpha_options_for(
        &self,
        options: AlphaFitOptions,
        dataset: &Dataset,
        origin: &str,
    ) -> Result<(AlphaFitOptions, Vec<String>, bool)> {
        if matches!(self.early_stop, Some(Some(_)))
            && dataset.val.is_empty()
            && dataset.test.is_empty()
        {
            return Err(Error::setting(
                &["early_stop"],
                format!(
                    "{origin}: `early_stop` reads the held-out PSNR, and the dataset has no `val` or `test` views: give a dataset with held-out views, or leave `early_stop` out"
                ),
            ));
        }
        if let Some(Some(side)) = self.window
            && let Some(([1, 1], _)) = crate::fit::window::finest_grid(side, &dataset.train)
        {
            return Err(Error::setting(
                &["window"],
                format!(
                    "{origin}: `window` {side} cuts only views of 1.5×{side} pixels or more on a side, and no training view is that large, so every step would fit whole views: give a smaller side, or `window` off"
                ),
            ));
        }
        let by_background = background_defaults(&dataset.train, self.background);
        let mut notes = self.photo_notes(&by_background);
        let prune_fraction = self.prune_fraction.unwrap_or(by_background.prune_fraction);
        self.check_prune_rounds(prune_fraction)?;
        let loss = self.training_loss(by_background.loss);
        self.check_dssim_weight(loss)?;
        let (steps, densify_every, batch_size) = match self.steps {
            Some(_) => (options.steps, options.densify_every, options.batch_size),
            None => {
                let (schedule, note) =
                    alpha_schedule(by_background.flat, by_background.sparse_spacing);
                notes.extend(note);
                (
                    schedule.steps,
                    self.densify_every.unwrap_or(schedule.densify_every),
                    self.batch.unwrap_or(schedule.batch_size),
                )
            }
        };
        let options = AlphaFitOptions {
            prune_fraction,
            loss,
            kernel_budget: by_background
                .kernel_budget
                .filter(|_| self.max_growth.is_none()),
            steps,
            densify_every,
            batch_size,
            ..options
        };
        Ok((options, notes, by_background.sparse_spacing.is_some()))
    }

    /// The notes on what photos (training views whose background is not flat) change in
    /// the defaults the caller left: no pruning by score, the MSE (the 3DGS loss from sparse
    /// views).
    fn photo_notes(&self, defaults: &BackgroundDefaults) -> Vec<String> {
        let mut notes = Vec::new();
        if defaults.flat {
            return notes;
        }
        if self.prune_fraction.is_none() {
            notes.push("no pruning by score: the photos' background is not flat, so every kernel carries part of the picture (give `prune_fraction` to prune)".into());
        }
        if self.loss.is_none() {
            notes.push(match defaults.loss {
                TrainingLoss::Mse => "training with the MSE: on photos, whose background is not flat, it measured better than the 3DGS loss (give `loss` l1-dssim for it)".into(),
                TrainingLoss::L1Dssim(_) => "training with the 3DGS loss (L1 + D-SSIM): on still photos from sparse views it measured better held out than the MSE (give `loss` mse for it)".into(),
            });
        }
        notes
    }

    /// The fit of `dataset` from `init` (named `init_name`), ready to run: the blend chosen
    /// ([`fit_blend`] from `blend`), every setting checked against it and the start, and the
    /// plan of that blend. `origin` names the file the training frames come from.
    pub fn prepare(
        &self,
        blend: Option<Blend>,
        init: Init,
        init_name: &str,
        dataset: &Dataset,
        origin: &str,
    ) -> Result<ReadyFit> {
        let (blend, why) = fit_blend(blend, &init, init_name, dataset.blend)?;
        match blend {
            Blend::Alpha => {
                let options = self.alpha_options(why)?;
                self.check_start(blend, &init, init_name)?;
                let (options, notes, sparse_photos) =
                    self.alpha_options_for(options, dataset, origin)?;
                let mut ready = prepare_alpha(&options, init, dataset, self.background, origin)?
                    .of_sparse_photos(sparse_photos);
                ready.notes.extend(notes);
                Ok(ready.record_data(dataset))
            }
            Blend::Additive => {
                let plan = self.additive_plan(why)?;
                self.check_start(blend, &init, init_name)?;
                plan.ready(init, &dataset.train)
                    .map(|ready| ready.record_data(dataset))
            }
        }
    }

    /// The chosen settings over [`FitPlan::default`].
    fn additive(&self) -> FitPlan {
        let d = FitPlan::default();
        let r = &self.rates;
        FitPlan {
            steps: self.steps.unwrap_or(d.steps),
            start_kernels: self.start_kernels.unwrap_or(d.start_kernels),
            adaptive: self.adaptive,
            rounds: AdditiveRules {
                every: self.densify_every.unwrap_or(d.rounds.every),
                from: self.densify_from.unwrap_or(d.rounds.from),
                until: self.densify_until.unwrap_or(d.rounds.until),
                gradient_threshold: self
                    .densify_threshold
                    .unwrap_or(d.rounds.gradient_threshold),
                prune_below: self.prune_below.unwrap_or(d.rounds.prune_below),
                max_growth: self.max_growth.unwrap_or(d.rounds.max_growth),
                min_improvement: self.min_improvement.unwrap_or(d.rounds.min_improvement),
                merge_tolerance: self.merge_tolerance.unwrap_or(d.rounds.merge_tolerance),
                max_kernels: self.max_kernels.unwrap_or(d.rounds.max_kernels),
                ..d.rounds
            },
            min_scale: self.min_scale,
            bounds: self.bounds,
            time_range: self.time_range,
            init_scale: self.init_scale,
            init_amplitude: self.init_amplitude,
            rates: LearningRates {
                mean: r.mean.unwrap_or(d.rates.mean),
                time: r.time.unwrap_or(d.rates.time),
                amplitude: r.amplitude.unwrap_or(d.rates.amplitude),
                velocity: r.velocity.unwrap_or(d.rates.velocity),
                scale: r.scale.unwrap_or(d.rates.scale),
                background: r.background.unwrap_or(d.rates.background),
            },
            final_rate_factor: self.lr_final.unwrap_or(d.final_rate_factor),
            mode: self.mode,
            fit_velocity: self.fit_velocity,
            fit_scale: self.fit_scale,
            freeze_mean: self.freeze_mean,
            freeze_time: self.freeze_time,
            freeze_amplitude: self.freeze_amplitude,
            freeze_background: self.freeze_background,
            batch_size: self.batch.unwrap_or(d.batch_size),
            eval_every: self.eval_every.unwrap_or(d.eval_every),
            seed: self.seed.unwrap_or(d.seed),
            background: self.background,
            render: self.render,
        }
    }

    /// The chosen settings over [`DEFAULT_ALPHA`], a frozen group's rate 0.
    fn alpha(&self) -> AlphaFitOptions {
        let d = DEFAULT_ALPHA;
        let r = &self.rates;
        let frozen = |freeze: bool, rate: f64| if freeze { 0.0 } else { rate };
        AlphaFitOptions {
            steps: self.steps.unwrap_or(d.steps),
            batch_size: self.batch.unwrap_or(d.batch_size),
            rates: AlphaRates {
                mean: frozen(self.freeze_mean, r.mean.unwrap_or(d.rates.mean)),
                time: frozen(self.freeze_time, r.time.unwrap_or(d.rates.time)),
                velocity: r.velocity.unwrap_or(d.rates.velocity),
                acceleration: r.acceleration.unwrap_or(d.rates.acceleration),
                angular_velocity: r.angular_velocity.unwrap_or(d.rates.angular_velocity),
                scale: r.scale.unwrap_or(d.rates.scale),
                rotation: r.rotation.unwrap_or(d.rates.rotation),
                opacity: r.opacity.unwrap_or(d.rates.opacity),
                colour: frozen(self.freeze_amplitude, r.amplitude.unwrap_or(d.rates.colour)),
                sh: r.sh.unwrap_or(d.rates.sh),
            },
            final_rate_factor: self.lr_final.unwrap_or(d.final_rate_factor),
            eval_every: self.eval_every.unwrap_or(d.eval_every),
            seed: self.seed.unwrap_or(d.seed),
            render: self.render,
            start_kernels: self.start_kernels.unwrap_or(d.start_kernels),
            sh_count: self.sh.unwrap_or(d.sh_count),
            sh_raise_every: self.sh_raise_every.unwrap_or(d.sh_raise_every),
            max_kernels: self.max_kernels.unwrap_or(d.max_kernels),
            densify_every: self.densify_every.unwrap_or(d.densify_every),
            densify_from: self.densify_from.unwrap_or(d.densify_from),
            densify_until: self.densify_until.unwrap_or(d.densify_until),
            densify_fraction: self.max_growth.unwrap_or(d.densify_fraction),
            densify_threshold: self.densify_threshold.unwrap_or(d.densify_threshold),
            percent_dense: self.percent_dense.unwrap_or(d.percent_dense),
            prune_opacity: self.prune_below.unwrap_or(d.prune_opacity),
            opacity_reset_every: self.opacity_reset_every.unwrap_or(d.opacity_reset_every),
            time_split_fraction: self.time_split_fraction.unwrap_or(d.time_split_fraction),
            coarse: self.coarse_to_fine.unwrap_or(d.coarse),
            early_stop: self.early_stop.unwrap_or(d.early_stop),
            window: self.window.unwrap_or(d.window),
            loss: self.training_loss(d.loss),
            motion: self.motion_fit(d.motion),
            prune_fraction: self.prune_fraction.unwrap_or(d.prune_fraction),
            prune_rounds: self.prune_rounds.unwrap_or(d.prune_rounds),
            opacity_regulariser: self.opacity_regulariser.unwrap_or(d.opacity_regulariser),
            scale_regulariser: self.scale_regulariser.unwrap_or(d.scale_regulariser),
            ..d
        }
    }

    /// The motion chosen: `motion` (else the default's kind) with `motion_after_splits`
    /// (else the default's, else [`DEFAULT_MOTION_AFTER_SPLITS`]) and the default's turning
    /// rule (else [`DEFAULT_MOTION_TURNING`]).
    fn motion_fit(&self, default: MotionFit) -> MotionFit {
        let (default_name, default_after, default_turning) = match default {
            MotionFit::WhereNeeded {
                after_time_splits,
                turning,
            } => (MotionName::Auto, after_time_splits, turning),
            MotionFit::Everywhere => (
                MotionName::All,
                DEFAULT_MOTION_AFTER_SPLITS,
                Some(DEFAULT_MOTION_TURNING),
            ),
            MotionFit::Off => (
                MotionName::Off,
                DEFAULT_MOTION_AFTER_SPLITS,
                Some(DEFAULT_MOTION_TURNING),
            ),
        };
        match self.motion.unwrap_or(default_name) {
            MotionName::Auto => MotionFit::WhereNeeded {
                after_time_splits: self.motion_after_splits.unwrap_or(default_after),
                turning: default_turning,
            },
            MotionName::All => MotionFit::Everywhere,
            MotionName::Off => MotionFit::Off,
        }
    }

    /// An error naming the first chosen motion setting that cannot act with the motion
    /// options `options` the fit ends with, or `Ok`: `motion_after_splits` without `motion`
    /// auto; a SPEC §9 rate with `motion` off; `motion` auto or all with both SPEC §9 rates 0.
    fn check_motion(&self, options: &AlphaFitOptions) -> Result<()> {
        let r = &options.rates;
        let chosen_rate = [
            ("lr_acceleration", self.rates.acceleration),
            ("lr_angular_velocity", self.rates.angular_velocity),
        ]
        .into_iter()
        .find(|(_, rate)| rate.is_some_and(|rate| rate > 0.0));
        let refusal = match options.motion {
            MotionFit::WhereNeeded { .. } => None,
            _ if self.motion_after_splits.is_some() => Some((
                "motion_after_splits",
                "acts when `motion` is auto, and it is not: add `motion` auto, or leave `motion_after_splits` out".to_string(),
            )),
            MotionFit::Off => chosen_rate.map(|(field, _)| {
                (
                    field,
                    format!("fits SPEC §9 motion, and `motion` is off: add `motion` auto or all, or leave `{field}` out"),
                )
            }),
            MotionFit::Everywhere => None,
        };
        let refusal = refusal.or_else(|| {
            (self.motion.is_some_and(|m| m != MotionName::Off)
                && r.acceleration == 0.0
                && r.angular_velocity == 0.0)
                .then(|| {
                    (
                        "motion",
                        "gives kernels SPEC §9 motion, and both its rates (`lr_acceleration`, `lr_angular_velocity`) are 0: give one above 0, or leave `motion` out".to_string(),
                    )
                })
        });
        match refusal {
            Some((field, why)) => Err(Error::setting(&[field], format!("`{field}` {why}"))),
            None => Ok(()),
        }
    }
}

/// Most pruning rounds a fit accepts.
const MAX_PRUNE_ROUNDS: usize = 100;

/// The alpha options' numbers in range ([`check_fit_numbers`]) and SH a count the model
/// has.
fn validate_alpha(options: &AlphaFitOptions) -> Result<()> {
    options.render.validate()?;
    let r = &options.rates;
    check_fit_numbers(
        &[
            ("lr_mean", r.mean),
            ("lr_time", r.time),
            ("lr_velocity", r.velocity),
            ("lr_acceleration", r.acceleration),
            ("lr_angular_velocity", r.angular_velocity),
            ("lr_scale", r.scale),
            ("lr_rotation", r.rotation),
            ("lr_opacity", r.opacity),
            ("lr_amplitude", r.colour),
            ("lr_sh", r.sh),
            ("densify_threshold", options.densify_threshold),
            ("max_growth", options.densify_fraction),
            ("prune_below", options.prune_opacity),
            ("percent_dense", options.percent_dense),
            ("time_split_fraction", options.time_split_fraction),
            ("opacity_regulariser", options.opacity_regulariser),
            ("scale_regulariser", options.scale_regulariser),
        ],
        [options.densify_from, options.densify_until],
        options.final_rate_factor,
    )?;
    if !(0.0..1.0).contains(&options.prune_fraction) {
        return Err(Error::setting(
            &["prune_fraction"],
            format!(
                "`prune_fraction` {} must lie in [0, 1) (the share of the kernels removed; 1 would remove them all)",
                options.prune_fraction
            ),
        ));
    }
    if !(1..=MAX_PRUNE_ROUNDS).contains(&options.prune_rounds) {
        return Err(Error::setting(
            &["prune_rounds"],
            format!(
                "`prune_rounds` {} must be a whole number from 1 to {MAX_PRUNE_ROUNDS}",
                options.prune_rounds
            ),
        ));
    }
    if !crate::model::scene::SH_COUNTS.contains(&options.sh_count) {
        return Err(Error::setting(
            &["sh"],
            format!(
                "`sh` {} must be one of {:?} (SH degree 0 to 3)",
                options.sh_count,
                crate::model::scene::SH_COUNTS
            ),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nothing_chosen_gives_each_blends_defaults() {
        let settings = FitSettings {
            render: DEFAULT_ALPHA.render,
            ..FitSettings::default()
        };
        assert_eq!(
            settings.additive_plan("test").unwrap(),
            FitPlan {
                render: DEFAULT_ALPHA.render,
                ..FitPlan::default()
            }
        );
        assert_eq!(settings.alpha_options("test").unwrap(), DEFAULT_ALPHA);
        settings.validate().unwrap();
    }

    #[test]
    fn every_setting_is_of_one_kind() {
        let mut all: Vec<&str> = BOTH_BLENDS
            .iter()
            .chain(&ADDITIVE_ONLY)
            .chain(&ALPHA_ONLY)
            .copied()
            .collect();
        let count = all.len();
        all.sort_unstable();
        all.dedup();
        assert_eq!(all.len(), count, "a setting listed twice");
    }

    #[test]
    fn a_setting_of_the_other_blend_is_refused_naming_it_and_the_blend() {
        let additive = FitSettings {
            mode: Some(FitMode::Paper),
            ..FitSettings::default()
        };
        let message = additive
            .alpha_options("the default")
            .unwrap_err()
            .to_string();
        assert!(
            message.contains("`mode` acts on the additive blend")
                && message.contains("blend is alpha")
                && message.contains("add `blend` additive"),
            "{message}"
        );
        let alpha = FitSettings {
            sh: Some(8),
            ..FitSettings::default()
        };
        let message = alpha
            .additive_plan("`blend` additive")
            .unwrap_err()
            .to_string();
        assert!(
            message.contains("`sh` acts on the alpha blend"),
            "{message}"
        );
    }

    #[test]
    fn shared_rates_and_freezes_reach_the_alpha_fit() {
        let settings = FitSettings {
            rates: RateSettings {
                mean: Some(1e-3),
                amplitude: Some(2e-3),
                ..RateSettings::default()
            },
            freeze_time: true,
            max_growth: Some(0.2),
            prune_below: Some(0.01),
            ..FitSettings::default()
        };
        let options = settings.alpha_options("test").unwrap();
        assert_eq!(options.rates.mean, 1e-3);
        assert_eq!(options.rates.colour, 2e-3);
        assert_eq!(options.rates.time, 0.0);
        assert_eq!(options.densify_fraction, 0.2);
        assert_eq!(options.prune_opacity, 0.01);
    }
}
