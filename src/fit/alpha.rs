//! The alpha blend's fit (SPEC §8): its rates and options, turned into the one training
//! loop's [`Training`].
//!
//! **Parameter table**, each field in the space it is best optimised in
//! ([`crate::fit::adam`]): the spatial mean, the time mean and the velocity as they are, their
//! rates relative to the cameras' box (its diagonal, the time range, the diagonal per time
//! range) and decaying exponentially to [`AlphaFitOptions::final_rate_factor`] of their
//! start; the scales as `ln s`, the quaternion renormalised after each step, the opacity as
//! `logit o`, the amplitude (the colour's base) and the SH as they are, at constant rates (as
//! the 3DGS and 4DGS papers schedule them). Adam's ε is 3DGS's `1e-15`.
//!
//! **SH degree** rises during the run: degree `d` of the scene's SH is its own group, fitted
//! from step `d · sh_raise_every` (its coefficients start at zero and stay there until then).
//!
//! **Density rules**: [`crate::fit::density::alpha`], relative to the same box; after growth,
//! optionally, pruning by a spatio-temporal score ([`crate::fit::density::prune`]) and,
//! through the run, regularisers of the opacities and scales ([`crate::fit::regularise`]).
//!
//! A step's batch is drawn with the seed `seed ^ 0x5eed`, so that a random start and the
//! draws of the same seed are independent.

use crate::fit::adam::{AdamConfig, Field, ParameterGroup};
use crate::fit::coarse::CoarseToFine;
use crate::fit::density::{AlphaRules, DensityRules, ShapeBound, SpacetimePrune, TurningRule};
use crate::fit::init::{SpaceTimeBox, box_from_cameras};
use crate::fit::regularise::Regularisers;
use crate::fit::train::{EarlyStop, Training, TrainingLoss};
use crate::model::error::{Error, MAX_QUOTE, Result, cut};
use crate::model::{Camera, View};
use crate::render::RenderOptions;

/// Learning rates of the alpha fit, per group.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AlphaRates {
    /// Spatial mean, as a fraction of the box's diagonal per step.
    pub mean: f64,
    /// Time mean, as a fraction of the time range per step.
    pub time: f64,
    /// Velocity, box diagonals per time range per step.
    pub velocity: f64,
    /// SPEC §9 acceleration, box diagonals per time range squared per step (0: not
    /// fitted; with the angular rate 0 too, no kernel gets SPEC §9 fields).
    pub acceleration: f64,
    /// SPEC §9 angular velocity, quaternion units per time range per step (0: not fitted;
    /// with the acceleration rate 0 too, no kernel gets SPEC §9 fields).
    pub angular_velocity: f64,
    /// `ln s`.
    pub scale: f64,
    /// Quaternion components.
    pub rotation: f64,
    /// `logit o`.
    pub opacity: f64,
    /// Amplitude (the colour's base).
    pub colour: f64,
    /// SH coefficients.
    pub sh: f64,
}

/// How to fit an alpha scene. Defaults in [`crate::fit::plan`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AlphaFitOptions {
    /// Adam steps.
    pub steps: usize,
    /// Views per step.
    pub batch_size: usize,
    /// Initial learning rates.
    pub rates: AlphaRates,
    /// The spatial rates at the last step as a fraction of the first.
    pub final_rate_factor: f64,
    /// Held-out evaluation period, steps (0: only at the end).
    pub eval_every: usize,
    /// Seed of the start and the batch order.
    pub seed: u64,
    /// Rendering options.
    pub render: RenderOptions,
    /// Kernels of a random, hull or plane-sweep start, and the most the far shell adds
    /// ([`crate::fit::shell`]).
    pub start_kernels: usize,
    /// Most points of a dataset's point cloud a start takes (evenly through the list): the
    /// bound on a fit's first steps' cost when a capture ships a dense cloud.
    pub max_start_points: usize,
    /// Opacity of a random start's kernels.
    pub start_opacity: f64,
    /// σt of a random start's kernels, as a fraction of the time range.
    pub start_time_scale: f64,
    /// SH triplets of the fitted scene (0, 3, 8 or 15).
    pub sh_count: usize,
    /// Steps between SH degree raises.
    pub sh_raise_every: usize,
    /// Upper bound on the kernel count.
    pub max_kernels: usize,
    /// Steps between density rounds.
    pub densify_every: usize,
    /// Density rounds from this fraction of the run …
    pub densify_from: f64,
    /// … until this one.
    pub densify_until: f64,
    /// Fraction of the visible kernels densified per round, at most.
    pub densify_fraction: f64,
    /// Smallest mean `|∂L/∂m2|` (per pixel) that densifies.
    pub densify_threshold: f64,
    /// A kernel is split rather than cloned when its largest σ exceeds this fraction of the
    /// box's diagonal.
    pub percent_dense: f64,
    /// Kernels below this opacity are pruned.
    pub prune_opacity: f64,
    /// Steps between opacity resets while density rounds run (0: never): every opacity is
    /// lowered to at most `reset_opacity`, so that kernels the views do not need fade
    /// below `prune_opacity` and are pruned (3DGS's reset).
    pub opacity_reset_every: usize,
    /// The opacity a reset lowers every kernel to, at most.
    pub reset_opacity: f64,
    /// A densified kernel whose σt exceeds this fraction of the time range, and which moves
    /// further than its largest spatial σ within one σt, is split in time rather than in
    /// space (the 4DGS papers' split in the time dimension).
    pub time_split_fraction: f64,
    /// The coarse stages' choice ([`crate::fit::coarse`]).
    pub coarse: CoarseToFine,
    /// The stop when the held-out PSNR no longer rises (`None`: every step runs).
    pub early_stop: Option<EarlyStop>,
    /// Each step fits one window of about this side of each drawn view
    /// ([`crate::fit::window`]; `None`: whole views).
    pub window: Option<u32>,
    /// The bound on every kernel's shape after each step ([`ShapeBound`]).
    pub shape_bound: ShapeBound,
    /// A start from a point cloud is completed by plane-sweep kernels on the pixels the
    /// cloud leaves unexplained ([`crate::fit::plan`]).
    pub fill_uncovered: bool,
    /// A start from a point cloud or a plane sweep gets kernels on a far shell for the
    /// training pixels it leaves unexplained, when they are at least 1 % of them
    /// ([`crate::fit::shell`]; not the rig's start).
    pub far_shell: bool,
    /// The per-view loss the gradient is taken of ([`TrainingLoss`]).
    pub loss: TrainingLoss,
    /// Which kernels carry fitted SPEC §9 motion ([`MotionFit`]).
    pub motion: MotionFit,
    /// The fraction of the kernels removed by their spatio-temporal score after growth
    /// ends ([`crate::fit::density::prune`]; 0: none).
    pub prune_fraction: f64,
    /// The rounds that remove `prune_fraction` together, `densify_every` steps apart.
    pub prune_rounds: usize,
    /// `λo` of the L1 on the opacities ([`crate::fit::regularise`]; 0: off).
    pub opacity_regulariser: f64,
    /// `λs` of the L1 on the spatial scales over the box diagonal (0: off).
    pub scale_regulariser: f64,
    /// The kernel count the fit ends with, which the density rounds grow towards where
    /// `densify_fraction` alone would stay short of it ([`crate::fit::plan::growth_target`]);
    /// `None`: the growth is `densify_fraction`.
    pub kernel_budget: Option<KernelBudget>,
}

/// A kernel budget that follows the image size: the kernels a fit ends with,
/// `coefficient · P^exponent` for the `P` pixels of its largest training view (at the fit's
/// size), at most `max_per_pixel · P`. Its density rounds grow towards that count divided
/// by the share the pruning by score keeps, each round by the share of the visible kernels
/// that reaches it in the rounds left ([`crate::fit::density::GrowthTarget`]), at most
/// `max_growth` and never less than the options' `densify_fraction`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KernelBudget {
    /// The kernels per `P^exponent`.
    pub coefficient: f64,
    /// The power of the largest view's pixel count `P` the budget follows: 1 for a share of
    /// the pixels, ½ for a count that grows with the views' side.
    pub exponent: f64,
    /// At most this many kernels per pixel of the largest view (it bounds small views'
    /// budgets).
    pub max_per_pixel: f64,
    /// The largest growth per round it may ask for.
    pub max_growth: f64,
    /// The view spacing, in degrees, above which the training views are sparse: the budget
    /// is then multiplied by `(dense_spacing / spacing)²` and is a cap the density rounds
    /// never pass ([`crate::fit::plan::view_spacing_degrees`]); `None`: never sparse.
    pub dense_spacing: Option<f64>,
}

/// Which kernels of an alpha fit carry fitted SPEC §9 motion: an acceleration and an
/// angular velocity, each fitted at its group's rate when that rate is above 0.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum MotionFit {
    /// No kernel: the fit adds no SPEC §9 field.
    Off,
    /// The kernels that keep splitting in time: a kernel that spans motion after this many
    /// splits in time of its line gets motion instead of a further split
    /// ([`crate::fit::density::alpha`]); and the kernels whose velocity gradient keeps
    /// turning ([`crate::fit::density::turning`]). The others' SPEC §9 fields stay zero.
    WhereNeeded {
        /// Splits in time of a kernel's line before it gets motion.
        after_time_splits: u32,
        /// The turning trigger's thresholds (`None`: only the splits in time give motion).
        turning: Option<TurningRule>,
    },
    /// Every kernel, from the first step.
    Everywhere,
}

/// Adam's ε for the alpha fit (3D Gaussian splatting's): opacity logits and SH have
/// gradients many orders below 1e-8.
pub const ALPHA_ADAM_EPSILON: f64 = 1e-15;

/// The seed of the batch draws is the options' seed with these bits flipped.
const DRAW_SEED_BITS: u64 = 0x5eed;

impl AlphaFitOptions {
    /// The density rules in a box of `diagonal` and a time range `time_range`.
    #[must_use]
    pub fn rules(&self, diagonal: f64, time_range: f64) -> AlphaRules {
        AlphaRules {
            every: self.densify_every,
            from: self.densify_from,
            until: self.densify_until,
            fraction: self.densify_fraction,
            threshold: self.densify_threshold,
            max_kernels: self.max_kernels,
            percent_dense: self.percent_dense,
            time_split_fraction: self.time_split_fraction,
            prune_opacity: self.prune_opacity,
            opacity_reset_every: self.opacity_reset_every,
            reset_opacity: self.reset_opacity,
            diagonal,
            time_range,
            motion_after_time_splits: match self.motion {
                MotionFit::WhereNeeded {
                    after_time_splits, ..
                } if self.fits_motion() => Some(after_time_splits),
                _ => None,
            },
            motion_when_turning: match self.motion {
                MotionFit::WhereNeeded { turning, .. } if self.fits_motion() => turning,
                _ => None,
            },
            // The views' size decides it: the plan sets it from `kernel_budget`.
            growth_target: None,
        }
    }

    /// Whether some kernel's SPEC §9 motion is fitted: [`MotionFit`] not off, and a rate of
    /// its groups above 0.
    #[must_use]
    pub fn fits_motion(&self) -> bool {
        self.motion != MotionFit::Off
            && (self.rates.acceleration > 0.0 || self.rates.angular_velocity > 0.0)
    }

    /// The parameter table in a box of `diagonal` and a time range `time_range` (see the
    /// module docs).
    #[must_use]
    pub fn groups(&self, diagonal: f64, time_range: f64) -> Vec<ParameterGroup> {
        let r = &self.rates;
        let spatial = |field, setting, rate, unit| ParameterGroup {
            unit,
            ..ParameterGroup::new(field, setting, rate)
        };
        let constant = |field, setting, rate| ParameterGroup {
            decays: false,
            ..ParameterGroup::new(field, setting, rate)
        };
        let mut groups = vec![
            spatial(Field::Mean, "lr_mean", r.mean, diagonal),
            spatial(Field::Time, "lr_time", r.time, time_range),
            spatial(
                Field::Velocity,
                "lr_velocity",
                r.velocity,
                diagonal / time_range,
            ),
            constant(Field::Scale, "lr_scale", r.scale),
            constant(Field::Rotation, "lr_rotation", r.rotation),
            constant(Field::Opacity, "lr_opacity", r.opacity),
            constant(Field::Amplitude, "lr_amplitude", r.colour),
        ];
        let motion = self.motion != MotionFit::Off;
        if motion && r.acceleration > 0.0 {
            groups.push(spatial(
                Field::Acceleration,
                "lr_acceleration",
                r.acceleration,
                diagonal / (time_range * time_range),
            ));
        }
        if motion && r.angular_velocity > 0.0 {
            groups.push(spatial(
                Field::AngularVelocity,
                "lr_angular_velocity",
                r.angular_velocity,
                1.0 / time_range,
            ));
        }
        // Degree d holds SH triplets d² - 1 .. (d + 1)² - 1.
        groups.extend((1..=3).map(|d: usize| ParameterGroup {
            from_step: d * self.sh_raise_every,
            ..constant(
                Field::Sh {
                    from: d * d - 1,
                    to: (d + 1) * (d + 1) - 1,
                },
                "lr_sh",
                r.sh,
            )
        }));
        groups
    }

    /// The training loop's input for a fit in `bounds` (the unit of the spatial rates and
    /// of the density rules); its coarse stages are left to the plan, which sees the views.
    #[must_use]
    pub fn training(&self, bounds: &SpaceTimeBox) -> Training {
        let (diagonal, time_range) = extents(bounds);
        Training {
            steps: self.steps,
            batch_size: self.batch_size,
            eval_every: self.eval_every,
            draw_seed: self.seed ^ DRAW_SEED_BITS,
            render: self.render,
            adam: AdamConfig {
                epsilon: ALPHA_ADAM_EPSILON,
                ..AdamConfig::default()
            },
            groups: self.groups(diagonal, time_range),
            final_rate_factor: self.final_rate_factor,
            density: Some(DensityRules::Alpha(self.rules(diagonal, time_range))),
            coarse: Vec::new(),
            early_stop: self.early_stop,
            window: self.window,
            shape_bound: self.shape_bound,
            loss: self.loss,
            prune: (self.prune_fraction > 0.0).then_some(SpacetimePrune {
                fraction: self.prune_fraction,
                rounds: self.prune_rounds,
                every: self.densify_every,
            }),
            regularisers: Regularisers {
                opacity: self.opacity_regulariser,
                scale: self.scale_regulariser,
                diagonal,
            },
        }
    }
}

/// The length scales the rates are relative to: the box's diagonal and the time range.
fn extents(bounds: &SpaceTimeBox) -> (f64, f64) {
    let diagonal = (0..3)
        .map(|a| (bounds.max[a] - bounds.min[a]).powi(2))
        .sum::<f64>()
        .sqrt();
    (diagonal, (bounds.time[1] - bounds.time[0]).max(1e-9))
}

/// The space-time box of the training cameras and times (the random start's box, and the
/// unit of the spatial rates), or an error naming `origin` (the file the training frames
/// come from), the frame and the field when the frames' numbers give no finite box: times
/// whose span overflows, cameras whose centres or the point they look at leave the finite
/// numbers.
pub fn alpha_bounds(train: &[View], origin: &str) -> Result<SpaceTimeBox> {
    let frame = |i: usize| format!("frame `{}`", cut(&train[i].name, MAX_QUOTE));
    let (Some(first), Some(last)) = (
        (0..train.len()).min_by(|&a, &b| train[a].time.total_cmp(&train[b].time)),
        (0..train.len()).max_by(|&a, &b| train[a].time.total_cmp(&train[b].time)),
    ) else {
        return Err(Error::usage("no training views to fit"));
    };
    let [lo, hi] = [train[first].time, train[last].time];
    if !(lo.is_finite() && hi.is_finite() && (hi - lo).is_finite()) {
        return Err(Error::invalid(
            origin,
            format!("{} and {}", frame(first), frame(last)),
            "time",
            format!(
                "{lo:e} and {hi:e} lie further apart than the finite numbers reach (their difference overflows)"
            ),
        ));
    }
    let cameras: Vec<Camera> = train.iter().map(|v| v.camera).collect();
    let centres: Vec<[f64; 3]> = cameras.iter().map(Camera::centre).collect();
    if let Some(i) = centres
        .iter()
        .position(|c| c.iter().any(|v| !v.is_finite()))
    {
        return Err(Error::invalid(
            origin,
            frame(i),
            "transform_matrix",
            "the camera's position comes out not finite (the matrix is too large, too small or not invertible)",
        ));
    }
    // The alpha fit takes no box from its caller: say what would give one instead.
    let bounds = box_from_cameras(&cameras, [lo, hi]).map_err(|_| {
        Error::invalid(
            origin,
            "the training frames",
            "transform_matrix",
            "every camera looks along one direction, so the box the fit works in cannot be found where their axes meet: \
             the alpha fit needs views from at least two directions, or a rig's depth bounds (an N3V folder's poses_bounds.npy)",
        )
    })?;
    let finite = (0..3).all(|c| {
        let (lo, hi) = (bounds.min[c], bounds.max[c]);
        lo.is_finite() && hi.is_finite() && lo < hi && (hi - lo).is_finite()
    });
    if !finite {
        // The camera farthest from the origin is the likeliest culprit.
        let farthest = (0..train.len())
            .max_by(|&a, &b| {
                let norm = |c: &[f64; 3]| c.iter().map(|v| v.abs()).fold(0.0, f64::max);
                norm(&centres[a]).total_cmp(&norm(&centres[b]))
            })
            .unwrap_or(0);
        return Err(Error::invalid(
            origin,
            frame(farthest),
            "transform_matrix",
            format!(
                "the box the training cameras look at comes out as {:.3e}..{:.3e}, {:.3e}..{:.3e}, {:.3e}..{:.3e}, \
                 not a finite box with sides > 0 (this camera sits at {:.3e}, {:.3e}, {:.3e}): check the frames' \
                 positions and focal lengths (`transform_matrix`, `fl_x`, `fl_y`)",
                bounds.min[0],
                bounds.max[0],
                bounds.min[1],
                bounds.max[1],
                bounds.min[2],
                bounds.max[2],
                centres[farthest][0],
                centres[farthest][1],
                centres[farthest][2],
            ),
        ));
    }
    Ok(bounds)
}
