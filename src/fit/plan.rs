//! The fit plan: every default of a fit and the automatic policy, in one place, used by the
//! command line (`splat4d fit`) and the report alike.
//!
//! A [`FitPlan`] is what a user asks for (every field has its default in
//! [`FitPlan::default`]); [`FitPlan::prepare`] turns it and the training views into the
//! initial scene and the [`FitOptions`] of the training loop:
//!
//! - **start**: [`Init::Auto`] is one kernel at the centre of the box the cameras look at
//!   (or `start_kernels` spread at random in it), then densify, prune and merge so the count
//!   follows the data; [`Init::Random`] is N kernels at random in the box, a fixed count
//!   unless `adaptive`; [`Init::Scene`] starts from a given scene.
//! - **mode**: what the fit moves ([`FitMode`]); by default `velocity` for `Auto` (the most
//!   compact models in the report) and `paper` otherwise.
//! - **splitting**: densified kernels are split only when the scales are fixed (the fit
//!   cannot shrink them), above an eighth of the largest initial scale; otherwise cloned.
//! - **background**: the one given, else white when the images had alpha (D-NeRF's
//!   convention), else the initial scene's.

use crate::fit::adam::LearningRates;
use crate::fit::adaptive::AdaptiveOptions;
use crate::fit::init::{SpaceTimeBox, box_from_cameras, centre_scene, random_scene};
use crate::fit::train::{DEFAULT_RATES, FitMode, FitOptions};
use crate::model::{Camera, Error, Result, Scene, View};
use crate::render::RenderOptions;

/// Where a fit starts.
#[derive(Clone, Debug, PartialEq)]
pub enum Init {
    /// From [`FitPlan::start_kernels`] kernels (one at the box's centre by default), with
    /// densify, prune and merge rounds.
    Auto,
    /// N kernels at random in the box.
    Random(usize),
    /// A given scene.
    Scene(Scene),
}

impl Init {
    /// Parses `auto` or `random:N`; anything else is a scene file name, returned as `None`
    /// for the caller to read.
    pub fn parse_builtin(text: &str) -> Result<Option<Init>> {
        if text == "auto" {
            return Ok(Some(Init::Auto));
        }
        match text.strip_prefix("random:") {
            Some(count) => count
                .parse()
                .ok()
                .filter(|&n| n > 0)
                .map(|n| Some(Init::Random(n)))
                .ok_or_else(|| {
                    Error::usage(format!("--init {text}: N must be a whole number ≥ 1"))
                }),
            None => Ok(None),
        }
    }
}

/// Everything a user can choose about a fit, with its defaults.
#[derive(Clone, Debug, PartialEq)]
pub struct FitPlan {
    /// Adam steps.
    pub steps: usize,
    /// Kernels [`Init::Auto`] starts from (1: one at the centre of the box).
    pub start_kernels: usize,
    /// Densify and prune with [`Init::Random`] or [`Init::Scene`] too.
    pub adaptive: bool,
    /// The adaptive rounds' settings (`min_scale` is decided by the policy unless
    /// [`FitPlan::min_scale`] is given).
    pub rounds: AdaptiveOptions,
    /// Densified kernels above this mean spatial scale are split, the others cloned.
    pub min_scale: Option<f64>,
    /// Box of the random start `x0,y0,z0,x1,y1,z1` (default: from the cameras).
    pub bounds: Option<[f64; 6]>,
    /// Time range of the random start (default: the training times' range).
    pub time_range: Option<[f64; 2]>,
    /// Scales of the random start (default: from the box and the count).
    pub init_scale: Option<[f64; 4]>,
    /// Amplitude of every channel of a random or automatic start.
    pub init_amplitude: f64,
    /// Initial learning rates of every group (the mode zeroes the ones it does not fit).
    pub rates: LearningRates,
    /// Learning rates at the last step as a fraction of the first.
    pub final_rate_factor: f64,
    /// What the fit moves (default: by the start, see the module docs).
    pub mode: Option<FitMode>,
    /// Fit the velocities whatever the mode.
    pub fit_velocity: bool,
    /// Fit the scales whatever the mode.
    pub fit_scale: bool,
    /// Keep the spatial means fixed.
    pub freeze_mean: bool,
    /// Keep the time means fixed.
    pub freeze_time: bool,
    /// Keep the amplitudes fixed.
    pub freeze_amplitude: bool,
    /// Views per step.
    pub batch_size: usize,
    /// Held-out evaluation period in steps (0: only at the end).
    pub eval_every: usize,
    /// Seed of the batch order and of the random start.
    pub seed: u64,
    /// Background colour (default: see the module docs).
    pub background: Option<[f64; 3]>,
    /// Rendering options of fitting and evaluation.
    pub render: RenderOptions,
}

impl Default for FitPlan {
    fn default() -> Self {
        FitPlan {
            steps: 2000,
            start_kernels: 1,
            adaptive: false,
            rounds: AdaptiveOptions::default(),
            min_scale: None,
            bounds: None,
            time_range: None,
            init_scale: None,
            init_amplitude: 0.1,
            rates: DEFAULT_RATES,
            final_rate_factor: 0.05,
            mode: None,
            fit_velocity: false,
            fit_scale: false,
            freeze_mean: false,
            freeze_time: false,
            freeze_amplitude: false,
            batch_size: 8,
            eval_every: 50,
            seed: 0,
            background: None,
            render: RenderOptions::default(),
        }
    }
}

/// A fit ready to run: the initial scene and the training loop's options.
#[derive(Clone, Debug, PartialEq)]
pub struct PreparedFit {
    /// The scene the fit starts from.
    pub scene: Scene,
    /// The training loop's options.
    pub options: FitOptions,
    /// What the fit moves.
    pub mode: FitMode,
}

impl FitPlan {
    /// The mode a fit from `init` uses.
    #[must_use]
    pub fn mode_for(&self, init: &Init) -> FitMode {
        self.mode.unwrap_or(if *init == Init::Auto {
            FitMode::Velocity
        } else {
            FitMode::Paper
        })
    }

    /// Checks the values no type rules out.
    pub fn validate(&self) -> Result<()> {
        self.render.validate()?;
        if let Some([x0, y0, z0, x1, y1, z1]) = self.bounds
            && !(x0 < x1 && y0 < y1 && z0 < z1)
        {
            return Err(Error::usage("--box: need x0 < x1, y0 < y1, z0 < z1"));
        }
        if let Some(scale) = self.init_scale
            && scale.iter().any(|&s| s <= 0.0)
        {
            return Err(Error::usage("--init-scale: every scale must be > 0"));
        }
        Ok(())
    }

    /// The initial scene and the options of a fit from `init` to `train`; `had_alpha` says
    /// whether the training images had an alpha channel (for the default background).
    pub fn prepare(&self, init: Init, train: &[View], had_alpha: bool) -> Result<PreparedFit> {
        self.validate()?;
        let mode = self.mode_for(&init);
        let random_count = match init {
            Init::Auto => Some(self.start_kernels.max(1)),
            Init::Random(n) => Some(n),
            Init::Scene(_) => None,
        };
        let auto = init == Init::Auto;
        let mut scene = match (random_count, init) {
            (Some(n), _) => {
                let bounds = self.start_box(train)?;
                if auto && n == 1 && self.init_scale.is_none() {
                    centre_scene(&bounds, self.init_amplitude)?
                } else {
                    random_scene(n, &bounds, self.init_scale, self.init_amplitude, self.seed)?
                }
            }
            (None, Init::Scene(scene)) => scene,
            (None, _) => unreachable!("only a scene start has no count"),
        };
        let fits_scales = self.fit_scale || mode != FitMode::Paper;
        let adaptive = (auto || self.adaptive).then(|| {
            // With fixed scales, splitting is the only way to finer kernels.
            let initial_scale = scene
                .scales
                .iter()
                .map(|s| (s[0] * s[1] * s[2]).cbrt())
                .fold(0.0_f64, f64::max);
            let split_above = if fits_scales {
                f64::INFINITY
            } else {
                initial_scale / 8.0
            };
            AdaptiveOptions {
                max_kernels: self.rounds.max_kernels.max(1),
                min_scale: self.min_scale.unwrap_or(split_above),
                ..self.rounds
            }
        });
        if let Some(background) = self.background {
            scene.background = background;
        } else if had_alpha {
            scene.background = [1.0; 3];
        }
        let rate = |frozen: bool, lr: f64| if frozen { 0.0 } else { lr };
        let options = FitOptions {
            steps: self.steps,
            batch_size: self.batch_size,
            learning_rates: LearningRates {
                mean: rate(self.freeze_mean, self.rates.mean),
                time: rate(self.freeze_time, self.rates.time),
                amplitude: rate(self.freeze_amplitude, self.rates.amplitude),
                velocity: rate(
                    !(self.fit_velocity || mode == FitMode::Velocity),
                    self.rates.velocity,
                ),
                scale: rate(!fits_scales, self.rates.scale),
            },
            final_rate_factor: self.final_rate_factor,
            eval_every: self.eval_every,
            seed: self.seed,
            render: self.render,
            adaptive,
            ..FitOptions::default()
        };
        Ok(PreparedFit {
            scene,
            options,
            mode,
        })
    }

    /// The space-time box of a random or automatic start.
    fn start_box(&self, train: &[View]) -> Result<SpaceTimeBox> {
        let time = self.time_range.unwrap_or_else(|| {
            train
                .iter()
                .fold([f64::INFINITY, f64::NEG_INFINITY], |[lo, hi], v| {
                    [lo.min(v.time), hi.max(v.time)]
                })
        });
        match self.bounds {
            Some([x0, y0, z0, x1, y1, z1]) => Ok(SpaceTimeBox {
                min: [x0, y0, z0],
                max: [x1, y1, z1],
                time,
            }),
            None => {
                let cameras: Vec<Camera> = train.iter().map(|v| v.camera).collect();
                box_from_cameras(&cameras, time)
            }
        }
    }
}
