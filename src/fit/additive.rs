//! The additive blend's fit (SPEC §5, §6): what it moves ([`FitMode`]), its rates and its
//! options, turned into the one training loop's [`Training`].
//!
//! Parameter table: spatial mean (x, y, z), time (t), amplitude (r, g, b), velocity
//! (vx, vy, vz), scale (sx, sy, sz, st, as `ln s`: a rate is a relative change per step) and
//! the scene's background colour, every rate decaying on the schedule; rotations are never
//! changed. Scales are frozen by the seed paper's mode, which fixes σ "for stability" (SPEC
//! §6). Density rules: [`crate::fit::density::additive`].

use crate::fit::adam::{AdamConfig, Field, ParameterGroup};
use crate::fit::density::{AdditiveRules, DensityRules, ShapeBound};
use crate::fit::train::Training;
use crate::render::RenderOptions;

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

/// Learning rate per parameter group of the additive fit; 0 freezes a group.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LearningRates {
    /// Spatial mean `(x, y, z)`, world units per step.
    pub mean: f64,
    /// Time mean `t`.
    pub time: f64,
    /// Amplitude `(r, g, b)`.
    pub amplitude: f64,
    /// Velocity `(vx, vy, vz)`.
    pub velocity: f64,
    /// Scales `(sx, sy, sz, st)`, in `ln s` (a relative change per step).
    pub scale: f64,
    /// The scene's background colour `(r, g, b)` (SPEC §5).
    pub background: f64,
}

/// How to fit an additive scene.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdditiveFitOptions {
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
    /// Densify and prune on a schedule ([`crate::fit::density::additive`]); `None` keeps
    /// the count.
    pub adaptive: Option<AdditiveRules>,
}

impl AdditiveFitOptions {
    /// The parameter table: every group, each rate decaying on the schedule.
    #[must_use]
    pub fn groups(&self) -> Vec<ParameterGroup> {
        let r = &self.learning_rates;
        vec![
            ParameterGroup::new(Field::Mean, "lr_mean", r.mean),
            ParameterGroup::new(Field::Time, "lr_time", r.time),
            ParameterGroup::new(Field::Amplitude, "lr_amplitude", r.amplitude),
            ParameterGroup::new(Field::Velocity, "lr_velocity", r.velocity),
            ParameterGroup::new(Field::Scale, "lr_scale", r.scale),
            ParameterGroup::new(Field::Background, "lr_background", r.background),
        ]
    }

    /// The training loop's input.
    #[must_use]
    pub fn training(&self) -> Training {
        Training {
            steps: self.steps,
            batch_size: self.batch_size,
            eval_every: self.eval_every,
            draw_seed: self.seed,
            render: self.render,
            adam: self.adam,
            groups: self.groups(),
            final_rate_factor: self.final_rate_factor,
            density: self.adaptive.map(DensityRules::Additive),
            coarse: Vec::new(),
            early_stop: None,
            window: None,
            shape_bound: ShapeBound::OFF,
            loss: crate::fit::train::TrainingLoss::Mse,
            prune: None,
            regularisers: crate::fit::regularise::Regularisers::OFF,
        }
    }
}
