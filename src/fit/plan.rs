//! The fit plan: every default of a fit and the automatic policy of both blends, in one
//! place, used by the command line (`splat4d fit`) and the report alike. The plan decides;
//! the training loop ([`crate::fit::train`]) obeys.
//!
//! **Which blend** ([`fit_blend`]): the one asked for, else the start scene's, else the one a
//! splat4d dataset records, else alpha (what real captures need).
//!
//! **The additive fit**: a [`FitPlan`] is what a user asks for (every field has its default
//! in [`FitPlan::default`]); [`FitPlan::prepare`] turns it and the training views into the
//! initial scene and the [`AdditiveFitOptions`] of the training loop:
//!
//! - **start**: [`Init::Auto`] is [`DEFAULT_START_KERNELS`] kernels spread at random in the
//!   box the cameras look at (`start_kernels = 1`: one at its centre), then densify, prune
//!   and merge so the count follows the data; [`Init::Random`] is N kernels at random in the
//!   box, a fixed count unless `adaptive`; [`Init::Scene`] starts from a given scene.
//! - **mode**: what the fit moves ([`FitMode`]); by default `velocity` for `Auto` (the most
//!   compact models in the report) and `paper` otherwise.
//! - **splitting**: densified kernels are split only when the scales are fixed (the fit
//!   cannot shrink them), above an eighth of the largest initial scale; otherwise cloned.
//! - **background** `b` (SPEC §5): a fitted parameter group (its own learning rate,
//!   `freeze_background` keeps it), starting from the one given, else from the data: the
//!   median of the training images' border pixels ([`border_median`]). A start from a
//!   scene keeps the scene's own background unless one is given.
//! - **amplitudes** of a random or automatic start: the data's mean colour above the
//!   background ([`start_amplitude`]), so the sign follows the data.
//!
//! **The alpha fit** ([`prepare_alpha`]): an automatic start from the dataset's point cloud
//! (completed by a plane sweep over the pixels it leaves unexplained, and both by a far
//! shell over what is still unexplained), else a visual hull, else a rig's sweeps of its still and moving pixels, else a plane
//! sweep (with the far shell), else kernels at random, in the training cameras' box, over the given background or the border median (kept fixed).
//!
//! **Numbers**: every default (steps, rates, batch, the density rules of both blends) is a
//! constant of [`crate::fit::defaults`], re-exported here.

use crate::fit::additive::{AdditiveFitOptions, FitMode, LearningRates};
use crate::fit::alpha::{AlphaFitOptions, KernelBudget, alpha_bounds};
use crate::fit::alpha_start::{
    completed_alpha_scene, hull_alpha_scene, point_cloud_alpha_scene, random_alpha_scene,
    swept_alpha_scene,
};
pub use crate::fit::defaults::*;
use crate::fit::density::{AdditiveRules, DensityRules, GrowthTarget};
use crate::fit::hull::{HULL_GRID, flat_background, is_foreground, visual_hull};
use crate::fit::init::{SpaceTimeBox, box_from_cameras, centre_scene, random_scene};
use crate::fit::rig_start::{find_rig, rig_alpha_scene, rig_bounds};
use crate::fit::stereo::plane_sweep;
use crate::fit::time_left::TimeLeft;
use crate::fit::train::{StepRecord, Training, TrainingLoss, fit};
use crate::model::{
    Blend, Camera, Dataset, Error, Result, Scene, Up, View, check_non_negative_setting,
};
use crate::render::RenderOptions;

/// Where a fit starts.
#[derive(Clone, Debug, PartialEq)]
#[allow(clippy::large_enum_variant)] // one value per fit: boxing would buy nothing
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
                .filter(|&n| (1..=MAX_START_KERNELS).contains(&n))
                .map(|n| Some(Init::Random(n)))
                .ok_or_else(|| {
                    Error::setting(
                        &["init"],
                        format!(
                            "`init` {text}: N must be a whole number from 1 to {MAX_START_KERNELS}"
                        ),
                    )
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
    /// Kernels [`Init::Auto`] starts from ([`DEFAULT_START_KERNELS`], spread at random in
    /// the box; 1: one at the centre of the box).
    pub start_kernels: usize,
    /// Densify and prune with [`Init::Random`] or [`Init::Scene`] too.
    pub adaptive: bool,
    /// The adaptive rounds' settings (`min_scale` is decided by the policy unless
    /// [`FitPlan::min_scale`] is given).
    pub rounds: AdditiveRules,
    /// Densified kernels above this mean spatial scale are split, the others cloned.
    pub min_scale: Option<f64>,
    /// Box of the random start `x0,y0,z0,x1,y1,z1` (default: from the cameras).
    pub bounds: Option<[f64; 6]>,
    /// Time range of the random start (default: the training times' range).
    pub time_range: Option<[f64; 2]>,
    /// Scales of the random start (default: from the box and the count).
    pub init_scale: Option<[f64; 4]>,
    /// Amplitude of every channel of a random or automatic start (default: from the data,
    /// see [`start_amplitude`]).
    pub init_amplitude: Option<f64>,
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
    /// Keep the background fixed at its start.
    pub freeze_background: bool,
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
            steps: DEFAULT_STEPS,
            start_kernels: DEFAULT_START_KERNELS,
            adaptive: false,
            rounds: DEFAULT_ROUNDS,
            min_scale: None,
            bounds: None,
            time_range: None,
            init_scale: None,
            init_amplitude: None,
            rates: DEFAULT_RATES,
            final_rate_factor: DEFAULT_FINAL_RATE_FACTOR,
            mode: None,
            fit_velocity: false,
            fit_scale: false,
            freeze_mean: false,
            freeze_time: false,
            freeze_amplitude: false,
            freeze_background: false,
            batch_size: DEFAULT_BATCH_SIZE,
            eval_every: DEFAULT_EVAL_EVERY,
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
    pub options: AdditiveFitOptions,
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

    /// Checks the values no type rules out: rates ≥ 0, fractions in range, a finite box.
    pub fn validate(&self) -> Result<()> {
        self.render.validate()?;
        self.validate_rates()?;
        self.validate_start()
    }

    /// Rates and the adaptive rounds' thresholds: finite, ≥ 0, rates at most [`MAX_RATE`];
    /// the rounds' window inside the run; a final rate factor > 0.
    fn validate_rates(&self) -> Result<()> {
        let r = &self.rates;
        check_fit_numbers(
            &[
                ("lr_mean", r.mean),
                ("lr_time", r.time),
                ("lr_amplitude", r.amplitude),
                ("lr_velocity", r.velocity),
                ("lr_scale", r.scale),
                ("lr_background", r.background),
                ("densify_threshold", self.rounds.gradient_threshold),
                ("merge_tolerance", self.rounds.merge_tolerance),
                ("max_growth", self.rounds.max_growth),
                ("prune_below", self.rounds.prune_below),
                ("min_scale", self.min_scale.unwrap_or(0.0)),
            ],
            [self.rounds.from, self.rounds.until],
            self.final_rate_factor,
        )?;
        if !self.rounds.min_improvement.is_finite() {
            return Err(Error::setting(
                &["min_improvement"],
                "`min_improvement` must be finite",
            ));
        }
        Ok(())
    }

    /// The start: background, kernel count, amplitude, batch, box and scales in range.
    fn validate_start(&self) -> Result<()> {
        if let Some(background) = self.background
            && background
                .iter()
                .any(|b| !b.is_finite() || b.abs() > MAX_BACKGROUND)
        {
            let [r, g, b] = background;
            return Err(Error::setting(
                &["background"],
                format!(
                    "`background` {r},{g},{b}: each channel must be finite and within ±{MAX_BACKGROUND} (images hold linear values around 0..1)"
                ),
            ));
        }
        if self.start_kernels > MAX_START_KERNELS {
            return Err(Error::setting(
                &["start_kernels"],
                format!(
                    "`start_kernels` {} is more than {MAX_START_KERNELS}",
                    self.start_kernels
                ),
            ));
        }
        if let Some(a) = self.init_amplitude
            && !a.is_finite()
        {
            return Err(Error::setting(
                &["init_amplitude"],
                format!("`init_amplitude` {a} must be finite"),
            ));
        }
        if self.batch_size == 0 {
            return Err(Error::setting(&["batch"], "`batch` must be at least 1"));
        }
        if let Some([x0, y0, z0, x1, y1, z1]) = self.bounds
            && !(x0 < x1 && y0 < y1 && z0 < z1)
        {
            return Err(Error::setting(
                &["box"],
                "`box`: need x0 < x1, y0 < y1, z0 < z1",
            ));
        }
        if let Some(scale) = self.init_scale
            && scale.iter().any(|&s| !(s > 0.0 && s.is_finite()))
        {
            return Err(Error::setting(
                &["init_scale"],
                "`init_scale`: every scale must be finite and > 0",
            ));
        }
        if let Some([x0, y0, z0, x1, y1, z1]) = self.bounds {
            let time = self.time_range.unwrap_or([0.0; 2]);
            SpaceTimeBox {
                min: [x0, y0, z0],
                max: [x1, y1, z1],
                time,
            }
            .check()?;
        }
        Ok(())
    }

    /// The initial scene and the options of a fit from `init` to `train`.
    pub fn prepare(&self, init: Init, train: &[View]) -> Result<PreparedFit> {
        self.validate()?;
        let mode = self.mode_for(&init);
        let random_count = match init {
            Init::Auto => Some(self.start_kernels.max(1)),
            Init::Random(n) => Some(n),
            Init::Scene(_) => None,
        };
        let auto = init == Init::Auto;
        let background = self.background.unwrap_or_else(|| border_median(train));
        let mut scene = match (random_count, init) {
            (Some(n), _) => {
                let bounds = self.start_box(train)?;
                let amplitude = self
                    .init_amplitude
                    .map_or_else(|| start_amplitude(train, background), |a| [a; 3]);
                let mut start = if auto && n == 1 && self.init_scale.is_none() {
                    centre_scene(&bounds, 1.0)?
                } else {
                    random_scene(n, &bounds, self.init_scale, 1.0, self.seed)?
                };
                for a in &mut start.amplitudes {
                    *a = amplitude;
                }
                start
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
            // A velocity kernel spanning several training times is split in time: its two
            // halves follow a curved path with a velocity each.
            let split_time_above = if mode == FitMode::Velocity {
                TIME_SPLIT_SPACINGS * time_spacing(train)
            } else {
                f64::INFINITY
            };
            AdditiveRules {
                max_kernels: self.rounds.max_kernels.max(1),
                min_scale: self.min_scale.unwrap_or(split_above),
                min_time_scale: self.rounds.min_time_scale.min(split_time_above),
                ..self.rounds
            }
        });
        if random_count.is_some() || self.background.is_some() {
            scene.background = background;
        }
        let rate = |frozen: bool, lr: f64| if frozen { 0.0 } else { lr };
        let options = AdditiveFitOptions {
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
                background: rate(self.freeze_background, self.rates.background),
            },
            final_rate_factor: self.final_rate_factor,
            eval_every: self.eval_every,
            seed: self.seed,
            render: self.render,
            adaptive,
            ..AdditiveFitOptions::default()
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
        // Values from the data are named as such: no flag was given for them.
        let [t0, t1] = time;
        if self.time_range.is_none() && !(t1 - t0).is_finite() {
            return Err(Error::usage(format!(
                "the training frames' times span {t0:e}..{t1:e}, wider than the finite numbers: check the `time` field of the frames in the transforms files (or give `time_range`)"
            )));
        }
        match self.bounds {
            Some([x0, y0, z0, x1, y1, z1]) => Ok(SpaceTimeBox {
                min: [x0, y0, z0],
                max: [x1, y1, z1],
                time,
            }),
            None => {
                let cameras: Vec<Camera> = train.iter().map(|v| v.camera).collect();
                let inferred = box_from_cameras(&cameras, time)?;
                let finite = (0..3).all(|c| {
                    let (lo, hi) = (inferred.min[c], inferred.max[c]);
                    lo.is_finite() && hi.is_finite() && lo < hi && (hi - lo).is_finite()
                });
                if !finite {
                    return Err(Error::usage(format!(
                        "the box the cameras look at comes out as {:?}..{:?}, not a finite box with sides > 0: check the training frames' focal lengths (fl_x, fl_y) and positions (transform_matrix), or give `box`",
                        inferred.min, inferred.max
                    )));
                }
                Ok(inferred)
            }
        }
    }
}

/// A fit ready to run, whichever the blend: its start, the training loop's input, and what
/// the plan chose that a user should know (one line each).
#[derive(Clone, Debug, PartialEq)]
pub struct ReadyFit {
    /// The scene the fit starts from.
    pub scene: Scene,
    /// The training loop's input.
    pub training: Training,
    /// What was chosen, for the user.
    pub notes: Vec<String>,
    /// What the fitted scene records of the data ([`ReadyFit::record_data`]).
    recorded: DataFacts,
    /// Whether the training views are still photos from sparse views
    /// ([`ReadyFit::of_sparse_photos`]), whose steps grow dearer with the kernels than the
    /// time-left model has it.
    sparse_photos: bool,
}

/// What a fitted scene records of its data, for the viewer and videos of it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct DataFacts {
    /// The world axis nearest the cameras' mean up, else the start scene's.
    up: Option<Up>,
    /// The range of every view's time.
    time_range: Option<[f64; 2]>,
    /// The sphere the training cameras look at.
    framing: Option<([f64; 3], f64)>,
}

impl ReadyFit {
    /// A fit of `scene` with `training`, and `notes` to show.
    fn new(scene: Scene, training: Training, notes: Vec<String>) -> Self {
        ReadyFit {
            scene,
            training,
            notes,
            recorded: DataFacts::default(),
            sparse_photos: false,
        }
    }

    /// This fit, its training views still photos from sparse views ([`sparse_spacing`])
    /// when `sparse` is true: its time-left estimate then expects a step's time to grow
    /// with the kernels as such fits' did ([`TimeLeft::for_sparse_photos`]) until it has
    /// timed it.
    #[must_use]
    pub fn of_sparse_photos(self, sparse: bool) -> Self {
        ReadyFit {
            sparse_photos: sparse,
            ..self
        }
    }

    /// Records what the fitted scene will carry of `dataset`: its cameras' up axis (noted
    /// when it is not +y), the range of its times and the sphere its cameras look at.
    #[must_use]
    pub fn record_data(mut self, dataset: &Dataset) -> Self {
        let up = cameras_up(&dataset.train);
        if let Some(up) = up
            && up != Up::Y
        {
            self.notes.push(format!(
                "the cameras' mean up is {up}: the fitted scene records it, and videos of it turn about it"
            ));
        }
        self.recorded = DataFacts {
            up: up.or(self.scene.up),
            time_range: data_time_range(dataset),
            framing: data_framing(dataset),
        };
        self
    }

    /// `scene` with what it records of the data.
    fn dress(&self, scene: &mut Scene) {
        scene.up = self.recorded.up;
        scene.time_range = self.recorded.time_range;
        scene.framing = self.recorded.framing;
    }

    /// The start scene as the fitted one will be framed (for a viewer of the running fit).
    #[must_use]
    pub fn framed_start(&self) -> Scene {
        let mut start = self.scene.clone();
        self.dress(&mut start);
        start
    }

    /// The estimate of the time this fit has left on training views `train`, to be given
    /// each step's record.
    #[must_use]
    pub fn time_left(&self, train: &[View]) -> TimeLeft {
        let size = train
            .first()
            .map_or([1, 1], |v| [v.image.width, v.image.height]);
        TimeLeft::new(&self.training, size).for_sparse_photos(self.sparse_photos)
    }

    /// Runs the fit ([`fit`]) on `train`, evaluating on `heldout`; `scene` is then the
    /// fitted scene, with what it records of the data. Returns every step's record.
    pub fn run(
        &mut self,
        train: &[View],
        heldout: &[View],
        on_step: impl FnMut(&StepRecord, &Scene),
    ) -> Result<Vec<StepRecord>> {
        let records = fit(&mut self.scene, train, heldout, &self.training, on_step)?;
        let mut fitted = std::mem::take(&mut self.scene);
        self.dress(&mut fitted);
        self.scene = fitted;
        Ok(records)
    }
}

/// The blend of a fit from `init` (named `init_name`, a start scene's file): the one
/// `asked`, else the start scene's, else the one a dataset `recorded`, else alpha; with why.
/// A start scene of another blend than the one asked is refused.
pub fn fit_blend(
    asked: Option<Blend>,
    init: &Init,
    init_name: &str,
    recorded: Option<Blend>,
) -> Result<(Blend, &'static str)> {
    let (blend, why) = match (asked, init, recorded) {
        (Some(blend), _, _) => (blend, "`blend` chose it"),
        (None, Init::Scene(scene), _) => (scene.blend, "the start scene's"),
        (None, _, Some(blend)) => (blend, "the one the dataset records"),
        (None, _, None) => (Blend::Alpha, "the default for a dataset"),
    };
    if let Init::Scene(scene) = init
        && scene.blend != blend
    {
        return Err(Error::usage(format!(
            "{init_name}: the start scene's blend is {}, the fit's {blend}",
            scene.blend
        )));
    }
    Ok((blend, why))
}

impl FitPlan {
    /// The additive fit from `init` to `train`, ready to run.
    pub fn ready(&self, init: Init, train: &[View]) -> Result<ReadyFit> {
        let prepared = self.prepare(init, train)?;
        let [r, g, b] = prepared.scene.background;
        let fitted = if prepared.options.learning_rates.background > 0.0 {
            "fitted from"
        } else {
            "fixed at"
        };
        let note = format!("background {fitted} ({r:.4}, {g:.4}, {b:.4})");
        Ok(ReadyFit::new(
            prepared.scene,
            prepared.options.training(),
            vec![note],
        ))
    }
}

/// The least a sparse-view cap (set by [`prepare_alpha`] for still photos from sparse
/// views) lets the density rounds grow the start to, as a multiple of it: the king figurine's start of 2978 kernels (from 23
/// photos 10.7° apart) fitted its held-out photos at 18.64 dB left as it was, 19.54 dB grown
/// to 4100 and 19.51 dB to 8250 (`docs/fitting.md`, "A real DSLR capture").
pub const SPARSE_VIEWS_LEAST_GROWTH: f64 = 2.0;

/// Fewer points than this from the plane sweep, and an alpha fit starts at random instead.
pub const MIN_SWEPT_POINTS: usize = 100;

/// The alpha fit of SPEC §8 from `init` to `dataset`, ready to run: over `background` (else
/// the median of the training images' border pixels), in the box of the training cameras
/// ([`alpha_bounds`]; for a rig whose axes are near parallel, [`rig_bounds`]; `origin`
/// names the file the frames come from in its errors).
///
/// An automatic start takes, in this order, the first that gives kernels: the dataset's
/// point cloud, completed (with [`AlphaFitOptions::fill_uncovered`]) by a plane sweep's
/// points on the pixels the cloud leaves unexplained when it keeps at least
/// [`MIN_SWEPT_POINTS`] of them ([`completed_alpha_scene`]), and, with or without the
/// sweep, (with [`AlphaFitOptions::far_shell`]) by a far shell for what is still
/// unexplained ([`crate::fit::shell`]); the visual hull of the training views where their background is flat
/// ([`crate::fit::hull`]); for a rig of synchronised cameras, its plane sweeps over still
/// and moving pixels ([`crate::fit::rig_start`]), when they keep at least
/// [`MIN_SWEPT_POINTS`] still points; a plane sweep over neighbouring views ([`crate::fit::stereo`]),
/// when it keeps at least [`MIN_SWEPT_POINTS`] points, with the far shell; kernels at random
/// in the box.
pub fn prepare_alpha(
    options: &AlphaFitOptions,
    init: Init,
    dataset: &Dataset,
    background: Option<[f64; 3]>,
    origin: &str,
) -> Result<ReadyFit> {
    let train = &dataset.train;
    let bounds = rig_bounds(dataset, alpha_bounds(train, origin))?;
    let background = background.unwrap_or_else(|| border_median(train));
    let colour = start_amplitude(train, background).map(|c| (c + background[0]).clamp(0.05, 1.0));
    let mut notes =
        vec!["fitting the alpha blend (SPEC §8: opacity, SH colour, depth order)".into()];
    let scene = match init {
        Init::Scene(scene) => scene,
        Init::Random(n) => random_alpha_scene(
            &bounds,
            background,
            colour,
            &AlphaFitOptions {
                start_kernels: n,
                ..*options
            },
        )?,
        Init::Auto => {
            let (scene, note) = alpha_auto_start(dataset, &bounds, background, colour, options)?;
            notes.push(note);
            scene
        }
    };
    let mut training = options.training(&bounds);
    let budget = BudgetOnViews::new(options, train);
    if let Some(budget) = &budget
        && let Some(target) = budget.growth_target(options, scene.len())
    {
        notes.push(budget.growth_note(target, options, scene.len()));
        if let Some(DensityRules::Alpha(rules)) = &mut training.density {
            rules.growth_target = Some(target);
        }
    }
    if let Some((cap, note)) = budget.and_then(|b| b.sparse_views_cap(options, scene.len())) {
        notes.push(note);
        if let Some(DensityRules::Alpha(rules)) = &mut training.density {
            rules.max_kernels = rules.max_kernels.min(cap);
        }
    }
    training.coarse = options.coarse.stages(train);
    if !training.coarse.is_empty() {
        notes.push(format!(
            "coarse to fine: {}, then full size",
            training
                .coarse
                .iter()
                .map(|s| format!(
                    "1/{} size until {:.0} % of the steps",
                    s.downscale,
                    100.0 * s.until
                ))
                .collect::<Vec<_>>()
                .join(", ")
        ));
    }
    if let Some(grid) = training.window.and_then(|side| windows_note(side, train)) {
        notes.push(grid);
    }
    Ok(ReadyFit::new(scene, training, notes))
}

/// The growth target of an alpha fit with `options` of `train` that starts from `start`
/// kernels: the count its density rounds steer towards, the options'
/// [`crate::fit::alpha::KernelBudget`] over the share the pruning by score keeps (at most
/// `max_kernels`), each round growing at most the budget's `max_growth`. `None` without a
/// budget, without rounds, or when the start already holds that count.
#[must_use]
pub fn growth_target(
    options: &AlphaFitOptions,
    start: usize,
    train: &[View],
) -> Option<GrowthTarget> {
    BudgetOnViews::new(options, train)?.growth_target(options, start)
}

/// An alpha fit's kernel budget measured once against its training views: what its growth
/// target, its sparse-view cap and their notes read.
struct BudgetOnViews {
    budget: KernelBudget,
    /// The density rounds the fit's schedule runs.
    rounds: usize,
    /// The share of the kernels the pruning by score keeps.
    kept: f64,
    /// The kernels the budget gives dense views ([`dense_budget_kernels`]).
    dense_kernels: f64,
    /// Where the budget finds the views sparse, the share of the dense views' budget they
    /// keep and their spacing ([`sparse_views_factor`]).
    sparse: Option<(f64, f64)>,
}

impl BudgetOnViews {
    /// The budget of `options` against `train`; `None` without one.
    fn new(options: &AlphaFitOptions, train: &[View]) -> Option<Self> {
        let budget = options.kernel_budget?;
        Some(BudgetOnViews {
            budget,
            rounds: options.rules(1.0, 1.0).rounds_from(1, options.steps),
            kept: (1.0 - options.prune_fraction.clamp(0.0, 1.0)).max(f64::MIN_POSITIVE),
            dense_kernels: dense_budget_kernels(&budget, train),
            sparse: sparse_views_factor(&budget, train),
        })
    }

    /// The kernels the budget gives the views before the pruning by score: the dense
    /// views' count times the share sparse views keep, over the share the pruning keeps.
    fn before_pruning(&self) -> f64 {
        self.dense_kernels * self.sparse.map_or(1.0, |(factor, _)| factor) / self.kept
    }

    /// [`growth_target`] from `start` kernels.
    fn growth_target(&self, options: &AlphaFitOptions, start: usize) -> Option<GrowthTarget> {
        let kernels = self.before_pruning().min(options.max_kernels as f64);
        (self.rounds > 0 && kernels > start as f64).then_some(GrowthTarget {
            kernels,
            max_share: self.budget.max_growth,
        })
    }

    /// The cap sparse views put on a fit of `options` from `start` kernels (the budget's
    /// [`sparse_views_factor`]): the budget, at least [`SPARSE_VIEWS_LEAST_GROWTH`] times the
    /// start, and the note that says so; `None` where the budget finds the views dense, or
    /// without rounds.
    fn sparse_views_cap(&self, options: &AlphaFitOptions, start: usize) -> Option<(usize, String)> {
        let dense = self.budget.dense_spacing?;
        let (factor, spacing) = self.sparse?;
        if self.rounds == 0 {
            return None;
        }
        let least = (SPARSE_VIEWS_LEAST_GROWTH * start as f64) as usize;
        let cap = (self.before_pruning() as usize)
            .max(least)
            .min(options.max_kernels);
        let note = format!(
            "sparse views: the training views' axes are {spacing:.1}° from their nearest (the median), above {dense}°, so the kernel budget is {factor:.2} of the dense views' and growth stops at {cap} kernels, the budget or twice the start (give `max_growth` to choose)"
        );
        Some((cap, note))
    }

    /// The note on the growth target `target` the budget gives a fit of `options` from
    /// `start` kernels: its pruning by score, and the least share a round grows, which passes
    /// the target when `start` grown by it every round would (transparent kernels pruned on the
    /// way aside) unless sparse views made the budget a cap ([`Self::sparse_views_cap`]).
    fn growth_note(&self, target: GrowthTarget, options: &AlphaFitOptions, start: usize) -> String {
        let (budget, rounds) = (self.budget, self.rounds);
        let sparse = self.sparse.map(|(factor, _)| factor);
        let prune_fraction = options.prune_fraction;
        let least = options.densify_fraction;
        let at_least = start as f64 * (1.0 + least).powi(rounds.min(i32::MAX as usize) as i32);
        let past = if at_least > target.kernels && sparse.is_none() {
            format!(
                "; {} % a round from the start's {start} kernels passes it",
                percent(least)
            )
        } else {
            String::new()
        };
        let size = if budget.exponent == 1.0 {
            format!("{} a pixel of the largest view", budget.coefficient)
        } else {
            format!(
                "{} times the largest view's pixels to the power {}, at most {} a pixel",
                budget.coefficient, budget.exponent, budget.max_per_pixel
            )
        };
        let size = match sparse {
            Some(factor) => format!("{size}, times {factor:.2} for sparse views"),
            None => size,
        };
        let pruned = if prune_fraction > 0.0 {
            format!(
                ", {:.0} after the pruning by score",
                target.kernels * (1.0 - prune_fraction)
            )
        } else {
            String::new()
        };
        format!(
            "kernel budget: growing towards {:.0} kernels{pruned} ({size}), by {} to {} % of the visible kernels a density round{past} (give `max_growth` to choose)",
            target.kernels,
            percent(least),
            percent(target.max_share.max(least))
        )
    }
}

/// The kernels `budget` gives a fit of `train` whose views are dense: its coefficient times
/// the pixels of the largest view to its exponent, at most its `max_per_pixel` of those
/// pixels.
fn dense_budget_kernels(budget: &KernelBudget, train: &[View]) -> f64 {
    let largest = train
        .iter()
        .map(|v| f64::from(v.image.width) * f64::from(v.image.height))
        .fold(0.0, f64::max);
    (budget.coefficient * largest.powf(budget.exponent)).min(budget.max_per_pixel * largest)
}

/// Where `budget` finds the views `train` sparse (their [`view_spacing_degrees`] above its
/// `dense_spacing`): the share of the budget they keep, `(dense_spacing / spacing)²`, and
/// the spacing; else `None` (only still photos are judged, [`sparse_spacing`]).
fn sparse_views_factor(budget: &KernelBudget, train: &[View]) -> Option<(f64, f64)> {
    let dense = budget.dense_spacing?;
    let spacing = sparse_spacing(train, dense)?;
    Some(((dense / spacing).powi(2), spacing))
}

/// The [`view_spacing_degrees`] of `train` where its views are still photos spaced more
/// than `dense` degrees apart: every view at one time (the captures this was measured on;
/// a video's kernels also span time). `None` where they are dense, span time, or are fewer
/// than two.
#[must_use]
pub fn sparse_spacing(train: &[View], dense: f64) -> Option<f64> {
    let first = train.first()?.time;
    if train.iter().any(|v| v.time != first) {
        return None;
    }
    view_spacing_degrees(train).filter(|&spacing| spacing > dense)
}

/// How far apart the views `train` look, in degrees: the median over the views of the
/// angle between a view's optical axis ([`Camera::optical_axis`]) and the nearest axis of
/// another view. Frames of one camera at several times count as one view. `None` with fewer
/// than two distinct axes.
#[must_use]
pub fn view_spacing_degrees(train: &[View]) -> Option<f64> {
    let mut axes: Vec<[f64; 3]> = Vec::new();
    for view in train {
        let axis = view.camera.optical_axis();
        if axis != [0.0; 3] && !axes.contains(&axis) {
            axes.push(axis);
        }
    }
    if axes.len() < 2 {
        return None;
    }
    let mut nearest: Vec<f64> = axes
        .iter()
        .enumerate()
        .map(|(i, a)| {
            let closest = axes
                .iter()
                .enumerate()
                .filter(|&(j, _)| j != i)
                .map(|(_, b)| (a[0] * b[0] + a[1] * b[1] + a[2] * b[2]).clamp(-1.0, 1.0))
                .fold(-1.0, f64::max);
            closest.acos().to_degrees()
        })
        .collect();
    nearest.sort_by(f64::total_cmp);
    Some(nearest[nearest.len() / 2])
}

/// `share` in percent, to a tenth (`0.15` → `15`, not `15.000000000000002`).
fn percent(share: f64) -> f64 {
    (1000.0 * share).round() / 10.0
}

/// The note on a fit's windows of side `side` over the full-size views `train`: the finest
/// grid, or `None` when every view stays whole.
fn windows_note(side: u32, train: &[View]) -> Option<String> {
    let ([columns, rows], [width, height]) = crate::fit::window::finest_grid(side, train)?;
    (columns * rows > 1).then(|| {
        format!(
            "windows: each full-size step fits one of {columns}×{rows} windows of each drawn {width}×{height} view"
        )
    })
}

/// The alpha defaults that follow the training views' background: whether it is flat
/// ([`flat_background`] around `background` as the fit takes it, else the border median),
/// scanned once for both.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BackgroundDefaults {
    /// Whether the background is flat.
    pub flat: bool,
    /// The pruning by score's share: [`DEFAULT_PRUNE_FRACTION`] over a flat background
    /// (renders of an object, where the kernels of lowest score are nearly invisible: equal
    /// or better held-out PSNR with half the kernels on the D-NeRF-like proxy and the
    /// occluding data), else 0 (photos, where every kernel carries part of the picture: the
    /// phone-like proxy at ⅛ lost 2.34 dB held out, 38.00 → 35.66 dB, for 8 % less CPU
    /// time; `docs/fitting.md`).
    pub prune_fraction: f64,
    /// The training loss: [`DEFAULT_LOSS`] (3DGS's) over a flat background, else
    /// [`DEFAULT_SPARSE_PHOTO_LOSS`] for still photos from sparse views ([`sparse_spacing`]
    /// above [`DEFAULT_DENSE_VIEW_SPACING`]) and [`DEFAULT_PHOTO_LOSS`] for the others.
    pub loss: TrainingLoss,
    /// The kernel budget: [`DEFAULT_OBJECT_KERNEL_BUDGET`] over a flat background, else
    /// [`DEFAULT_PHOTO_KERNEL_BUDGET`].
    pub kernel_budget: Option<crate::fit::alpha::KernelBudget>,
    /// The views' spacing where they are still photos from sparse views ([`sparse_spacing`]
    /// above [`DEFAULT_DENSE_VIEW_SPACING`]; decided once, for the loss, the schedule
    /// [`alpha_schedule`] and the time-left estimate); `None` over a flat background.
    pub sparse_spacing: Option<f64>,
}

/// The [`BackgroundDefaults`] of the training views `train`, `background` as the caller
/// gave it.
#[must_use]
pub fn background_defaults(train: &[View], background: Option<[f64; 3]>) -> BackgroundDefaults {
    let background = background.unwrap_or_else(|| border_median(train));
    if flat_background(train, background) {
        BackgroundDefaults {
            flat: true,
            prune_fraction: DEFAULT_PRUNE_FRACTION,
            loss: DEFAULT_LOSS,
            kernel_budget: Some(DEFAULT_OBJECT_KERNEL_BUDGET),
            sparse_spacing: None,
        }
    } else {
        let spacing = sparse_spacing(train, DEFAULT_DENSE_VIEW_SPACING);
        BackgroundDefaults {
            flat: false,
            prune_fraction: 0.0,
            loss: if spacing.is_some() {
                DEFAULT_SPARSE_PHOTO_LOSS
            } else {
                DEFAULT_PHOTO_LOSS
            },
            kernel_budget: Some(DEFAULT_PHOTO_KERNEL_BUDGET),
            sparse_spacing: spacing,
        }
    }
}

/// The alpha fit's steps, density period and batch when the caller gives no step count,
/// for training views whose background is flat or not and whose [`sparse_spacing`] is
/// `sparse` ([`BackgroundDefaults`]), and a note where the views chose them:
/// [`DEFAULT_OBJECT_SCHEDULE`] where their background is flat (`flat_background`: renders
/// of an object; twice the steps of half as many views took 0.55× the time within ±0.3 dB
/// at 100×100 and gained at 400×400, `docs/fitting.md`, "Steps");
/// [`DEFAULT_SPARSE_PHOTO_SCHEDULE`] for still photos from sparse views ([`sparse_spacing`]
/// above [`DEFAULT_DENSE_VIEW_SPACING`]), whose held-out photos peak early; else
/// [`DEFAULT_PHOTO_SCHEDULE`] (photos lost with the objects' schedule).
#[must_use]
pub fn alpha_schedule(
    flat_background: bool,
    sparse: Option<f64>,
) -> (AlphaSchedule, Option<String>) {
    if flat_background {
        return (DEFAULT_OBJECT_SCHEDULE, None);
    }
    let photos = DEFAULT_PHOTO_SCHEDULE;
    match sparse {
        Some(spacing) => {
            let sparse = DEFAULT_SPARSE_PHOTO_SCHEDULE;
            let note = format!(
                "sparse views: {} steps where dense views take {}, as the training views' axes are {spacing:.1}° from their nearest (the median), above {DEFAULT_DENSE_VIEW_SPACING}°, and such fits match their held-out photos best early (give `steps` to choose)",
                sparse.steps, photos.steps
            );
            (sparse, Some(note))
        }
        None => (photos, None),
    }
}

/// The automatic alpha start (see [`prepare_alpha`]) and a note saying which it is.
fn alpha_auto_start(
    dataset: &Dataset,
    bounds: &SpaceTimeBox,
    background: [f64; 3],
    colour: [f64; 3],
    options: &AlphaFitOptions,
) -> Result<(Scene, String)> {
    let train = &dataset.train;
    if let Some(points) = dataset.points.as_ref().filter(|p| !p.is_empty()) {
        if options.fill_uncovered {
            let swept = plane_sweep(train, bounds, options.start_kernels);
            if let Some((scene, completion)) = completed_alpha_scene(
                points,
                &swept,
                train,
                bounds,
                background,
                (options, MIN_SWEPT_POINTS),
            )? {
                let note = format!(
                    "starting from the dataset's point cloud ({} points) and a plane sweep over the pixels it leaves unexplained ({} points){}",
                    points.len(),
                    completion.swept,
                    shell_note(completion.shell)
                );
                return Ok((scene, note));
            }
        }
        let (scene, shell) = point_cloud_alpha_scene(points, train, bounds, background, options)?;
        let note = format!(
            "starting from the dataset's point cloud ({} points){}",
            points.len(),
            shell_note(shell)
        );
        return Ok((scene, note));
    }
    if flat_background(train, background) {
        let (cells, side) = visual_hull(train, background, bounds);
        if !cells.is_empty() {
            let note = format!(
                "starting from the visual hull of the training views ({} of {} cells kept)",
                cells.len(),
                HULL_GRID.pow(3)
            );
            return Ok((
                hull_alpha_scene(&cells, side, bounds, background, options)?,
                note,
            ));
        }
    }
    if let Some(rig) = find_rig(train)
        && let Some(start) = rig_alpha_scene(
            train,
            &rig,
            dataset.depth_range,
            bounds,
            background,
            options,
            MIN_SWEPT_POINTS,
        )?
    {
        return Ok(start);
    }
    let points = plane_sweep(train, bounds, options.start_kernels);
    if points.len() >= MIN_SWEPT_POINTS {
        let (scene, shell) = swept_alpha_scene(&points, train, bounds, background, options)?;
        let note = format!(
            "starting from a plane sweep over neighbouring training views ({} points){}",
            points.len(),
            shell_note(shell)
        );
        return Ok((scene, note));
    }
    Ok((
        random_alpha_scene(bounds, background, colour, options)?,
        "starting from kernels at random in the cameras' box (no point cloud, no flat background to carve a hull from, no depth the views agree on)".into(),
    ))
}

/// The start note's words on `shell` far-shell kernels (none: nothing).
fn shell_note(shell: usize) -> String {
    if shell == 0 {
        String::new()
    } else {
        format!(", with {shell} kernels on a far shell for the pixels still unexplained")
    }
}

/// The sphere the training cameras look at ([`box_from_cameras`]: the
/// point nearest their optical axes, half as wide as the median camera sees), if they say.
pub fn data_framing(dataset: &Dataset) -> Option<([f64; 3], f64)> {
    let cameras: Vec<Camera> = dataset.train.iter().map(|v| v.camera).collect();
    let bounds = box_from_cameras(&cameras, [0.0, 0.0]).ok()?;
    let centre = std::array::from_fn(|a| 0.5 * (bounds.min[a] + bounds.max[a]));
    let radius = 0.5
        * (0..3)
            .map(|a| (bounds.max[a] - bounds.min[a]).powi(2))
            .sum::<f64>()
            .sqrt();
    (radius > 0.0 && radius.is_finite()).then_some((centre, radius))
}

/// The range of every view's time (train, val and test): what the data shows.
pub fn data_time_range(dataset: &Dataset) -> Option<[f64; 2]> {
    let times = dataset
        .train
        .iter()
        .chain(&dataset.val)
        .chain(&dataset.test)
        .map(|v| v.time);
    times.fold(None, |range, t| {
        Some(range.map_or([t, t], |[lo, hi]: [f64; 2]| [lo.min(t), hi.max(t)]))
    })
}

/// The world axis nearest the training cameras' mean up direction (image up, the camera's
/// -y in OpenCV axes); `None` when the ups cancel out.
pub fn cameras_up(views: &[View]) -> Option<Up> {
    let mut up = [0.0_f64; 3];
    for view in views {
        let down = view.camera.rotation()[1];
        let norm = down.iter().map(|v| v * v).sum::<f64>().sqrt();
        for c in 0..3 {
            up[c] -= down[c] / norm;
        }
    }
    let largest = up.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
    if largest < 1e-9 * views.len() as f64 {
        return None;
    }
    Up::nearest(up)
}

/// The checks every fit's numbers pass, whichever blend: each of `non_negative` finite and
/// ≥ 0, a rate (`lr_*`) at most [`MAX_RATE`]; the density rounds' window `[from, until]`
/// inside the run; the final rate factor finite and > 0. Errors name the setting.
pub fn check_fit_numbers(
    non_negative: &[(&'static str, f64)],
    [from, until]: [f64; 2],
    final_rate_factor: f64,
) -> Result<()> {
    for &(field, value) in non_negative {
        check_non_negative_setting(field, value)?;
        // Adam moves a parameter by about its rate each step: beyond this every parameter
        // leaves the finite numbers within a few steps.
        if field.starts_with("lr_") && value > MAX_RATE {
            return Err(Error::setting(
                &[field],
                format!(
                    "`{field}` {value:e} is more than {MAX_RATE} (Adam moves a parameter by about the rate each step; the defaults are around 1e-2)"
                ),
            ));
        }
    }
    for (field, value) in [("densify_from", from), ("densify_until", until)] {
        if !(0.0..=1.0).contains(&value) {
            return Err(Error::setting(
                &[field],
                format!("`{field}` {value} must be in [0, 1]"),
            ));
        }
    }
    if !(final_rate_factor.is_finite() && final_rate_factor > 0.0) {
        return Err(Error::setting(
            &["lr_final"],
            format!("`lr_final` {final_rate_factor} must be finite and > 0"),
        ));
    }
    Ok(())
}

/// The per-channel median of the border pixels (the outermost row and column on each
/// side) of every training image: the colour the scene shows where nothing is, the start
/// of the fitted background. Black when there are no views.
#[must_use]
pub fn border_median(views: &[View]) -> [f64; 3] {
    let mut channels: [Vec<f32>; 3] = Default::default();
    for p in views.iter().flat_map(|view| view.image.border_pixels()) {
        for c in 0..3 {
            channels[c].push(p[c]);
        }
    }
    channels.map(|mut values| {
        if values.is_empty() {
            return 0.0;
        }
        values.sort_by(f32::total_cmp);
        f64::from(values[values.len() / 2])
    })
}

/// The median gap between consecutive distinct training times; `∞` with fewer than two.
#[must_use]
pub fn time_spacing(views: &[View]) -> f64 {
    let mut times: Vec<f64> = views.iter().map(|v| v.time).collect();
    times.sort_by(f64::total_cmp);
    times.dedup();
    let mut gaps: Vec<f64> = times.windows(2).map(|w| w[1] - w[0]).collect();
    if gaps.is_empty() {
        return f64::INFINITY;
    }
    gaps.sort_by(f64::total_cmp);
    gaps[gaps.len() / 2]
}

/// The amplitude a random or automatic start gives every kernel: the mean colour above
/// `background` of the foreground pixels (those that differ from it by more than
/// [`FOREGROUND_THRESHOLD`] in some channel), so that a dark object on a bright background
/// starts with negative amplitudes and a bright one with positive. When no pixel differs,
/// [`DEFAULT_INIT_AMPLITUDE`].
#[must_use]
pub fn start_amplitude(views: &[View], background: [f64; 3]) -> [f64; 3] {
    let b = background.map(|v| v as f32);
    let mut sum = [0.0_f64; 3];
    let mut count = 0_u64;
    for view in views {
        for p in view.image.pixels.chunks_exact(3) {
            if is_foreground(p, b) {
                for c in 0..3 {
                    sum[c] += f64::from(p[c] - b[c]);
                }
                count += 1;
            }
        }
    }
    if count == 0 {
        return [DEFAULT_INIT_AMPLITUDE; 3];
    }
    sum.map(|s| s / count as f64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Image;

    /// Four 8×8 views of the origin from around it, at times 0 and 1.
    fn views() -> Vec<View> {
        [
            [3.0, 0.5, 0.0],
            [0.0, 0.5, 3.0],
            [-3.0, 0.5, 0.0],
            [0.0, 0.5, -3.0],
        ]
        .iter()
        .enumerate()
        .map(|(k, &eye)| View {
            camera: Camera::look_at(eye, [0.0; 3], [0.0, 1.0, 0.0], 40.0, 8, 8).unwrap(),
            time: (k % 2) as f64,
            image: Image::filled(8, 8, [0.0; 3]).into(),
            name: format!("view {k}"),
            weights: None,
        })
        .collect()
    }

    #[test]
    fn auto_starts_from_a_few_kernels_with_velocity_and_rounds_that_split_only_in_time() {
        let prepared = FitPlan::default().prepare(Init::Auto, &views()).unwrap();
        assert_eq!(prepared.mode, FitMode::Velocity);
        assert_eq!(prepared.scene.len(), DEFAULT_START_KERNELS);
        for mean in &prepared.scene.means {
            assert!(
                (0.0..=1.0).contains(&mean[3]),
                "within the training times: {mean:?}"
            );
        }
        let rounds = prepared.options.adaptive.expect("auto is adaptive");
        assert_eq!(rounds.min_scale, f64::INFINITY, "the fit sizes the kernels");
        // Training times 0 and 1: velocity kernels longer than two spacings split in time.
        assert_eq!(time_spacing(&views()), 1.0);
        assert_eq!(rounds.min_time_scale, TIME_SPLIT_SPACINGS);
        assert_eq!(prepared.options.learning_rates, DEFAULT_RATES);
        assert_eq!(prepared.options.steps, DEFAULT_STEPS);
        let one = FitPlan {
            start_kernels: 1,
            ..FitPlan::default()
        };
        let centre = one.prepare(Init::Auto, &views()).unwrap().scene;
        assert_eq!(centre.len(), 1);
        assert_eq!(centre.means[0][3], 0.5, "the middle of the training times");
    }

    /// The alpha defaults with the photos' kernel budget and no pruning by score, as
    /// photos have them ([`background_defaults`]).
    fn photo_options() -> AlphaFitOptions {
        AlphaFitOptions {
            kernel_budget: Some(DEFAULT_PHOTO_KERNEL_BUDGET),
            prune_fraction: 0.0,
            ..DEFAULT_ALPHA
        }
    }

    /// Four views of `width × height` images from cameras `step` degrees apart on a circle
    /// about the origin, looking at it.
    fn views_apart(step: f64, width: u32, height: u32) -> Vec<View> {
        (0..4)
            .map(|k| {
                let angle = (step * k as f64).to_radians();
                let eye = [3.0 * angle.sin(), 0.0, 3.0 * angle.cos()];
                View {
                    camera: Camera::look_at(eye, [0.0; 3], [0.0, 1.0, 0.0], 40.0, width, height)
                        .unwrap(),
                    time: 0.0,
                    image: Image::filled(width, height, [0.0; 3]).into(),
                    name: format!("view {k}"),
                    weights: None,
                }
            })
            .collect()
    }

    /// Four views of `width × height` images, 1° apart: dense, as a video's frames are.
    fn views_of(width: u32, height: u32) -> Vec<View> {
        views_apart(1.0, width, height)
    }

    /// The note says when the least growth a round passes the budget: from 2978 kernels
    /// at 250×164 (8200 kernels), 5 % a round over 33 rounds reaches about 14 900; from
    /// 1132 at 270×480 (25 920) it reaches about 5650.
    #[test]
    fn the_budget_note_says_when_the_least_growth_passes_it() {
        let options = photo_options();
        for (width, height, start, passes) in [(250, 164, 2978, true), (480, 270, 1132, false)] {
            let views = views_of(width, height);
            let budget = BudgetOnViews::new(&options, &views).unwrap();
            let target = budget.growth_target(&options, start).unwrap();
            let note = budget.growth_note(target, &options, start);
            assert!(
                note.contains("by 5 to 10 % of the visible kernels"),
                "{note}"
            );
            let says = format!("5 % a round from the start's {start} kernels passes it");
            assert_eq!(note.contains(&says), passes, "{note}");
        }
    }

    /// The spacing is the median of each view's nearest axis: three views 2° apart and one
    /// 30° from them give 2°; frames of one camera count once.
    #[test]
    fn the_view_spacing_is_the_median_angle_to_the_nearest_axis() {
        let spacing = |views: &[View]| view_spacing_degrees(views).unwrap();
        assert!((spacing(&views_apart(2.0, 8, 8)) - 2.0).abs() < 1e-9);
        assert!((spacing(&views_apart(20.0, 8, 8)) - 20.0).abs() < 1e-9);
        let mut apart = views_apart(2.0, 8, 8);
        apart[3] = views_apart(34.0, 8, 8).remove(1);
        // Nearest: 2, 2, 2 and 30 degrees.
        assert!((spacing(&apart) - 2.0).abs() < 1e-9, "{}", spacing(&apart));
        // One camera at several times: no spacing; a second camera gives its angle.
        let one = views_apart(5.0, 8, 8).remove(0);
        let frames = vec![
            one.clone(),
            View {
                time: 1.0,
                ..one.clone()
            },
        ];
        assert_eq!(view_spacing_degrees(&frames), None);
        let mut two = frames;
        two.push(views_apart(5.0, 8, 8).remove(1));
        assert!((spacing(&two) - 5.0).abs() < 1e-9);
        assert_eq!(view_spacing_degrees(&[]), None);
    }

    /// Without a step count, still photos from views 9° apart take the sparse photos'
    /// schedule with a note naming their spacing; 1° apart, or a video's frames 9° apart,
    /// the photos' default; renders of an object (a flat background) the objects' whatever
    /// their spacing.
    #[test]
    fn sparse_still_photos_take_the_short_schedule() {
        let spacing = |views: &[View]| sparse_spacing(views, DEFAULT_DENSE_VIEW_SPACING);
        let sparse = views_apart(9.0, 48, 32);
        let (schedule, note) = alpha_schedule(false, spacing(&sparse));
        assert_eq!(schedule, DEFAULT_SPARSE_PHOTO_SCHEDULE);
        assert!(schedule.steps < DEFAULT_ALPHA.steps);
        let note = note.expect("a note on the sparse schedule");
        assert!(
            note.contains("9.0°") && note.contains(&format!("{} steps", schedule.steps)),
            "{note}"
        );
        let photos = DEFAULT_PHOTO_SCHEDULE;
        assert_eq!(photos.steps, DEFAULT_ALPHA.steps);
        assert_eq!(
            alpha_schedule(false, spacing(&views_apart(1.0, 48, 32))),
            (photos, None)
        );
        let mut video = sparse.clone();
        video[1].time = 0.5;
        assert_eq!(spacing(&video), None);
        assert_eq!(alpha_schedule(false, spacing(&video)), (photos, None));
        assert_eq!(
            alpha_schedule(true, spacing(&sparse)),
            (DEFAULT_OBJECT_SCHEDULE, None)
        );
    }

    /// Still photos textured to their borders take the 3DGS loss from views 9° apart and
    /// the MSE from views 1° apart (or a video's frames); renders of an object (a flat
    /// background) the 3DGS loss either way.
    #[test]
    fn sparse_still_photos_take_the_3dgs_loss() {
        let checkered = |mut views: Vec<View>| {
            for view in &mut views {
                let mut image = (*view.image).clone();
                let width = image.width as usize;
                for (i, value) in image.pixels.iter_mut().enumerate() {
                    let (x, y) = ((i / 3) % width, (i / 3) / width);
                    *value = ((x / 4 + y / 4) % 2) as f32;
                }
                view.image = image.into();
            }
            views
        };
        let loss = |views: &[View]| background_defaults(views, None).loss;
        let sparse = checkered(views_apart(9.0, 48, 32));
        assert_eq!(loss(&sparse), DEFAULT_SPARSE_PHOTO_LOSS);
        assert_eq!(DEFAULT_SPARSE_PHOTO_LOSS.name(), DEFAULT_LOSS.name());
        assert_eq!(
            loss(&checkered(views_apart(1.0, 48, 32))),
            DEFAULT_PHOTO_LOSS
        );
        assert_ne!(DEFAULT_PHOTO_LOSS.name(), DEFAULT_LOSS.name());
        let mut video = sparse;
        video[1].time = 0.5;
        assert_eq!(loss(&video), DEFAULT_PHOTO_LOSS);
        assert_eq!(loss(&views_apart(9.0, 48, 32)), DEFAULT_LOSS);
    }

    /// Photos from views 9° apart keep a quarter of the budget, `(4.5 / 9)²`, and growth
    /// stops there or at twice the start; from views 1° apart the budget is whole and no cap is set; without a
    /// budget (`max_growth` given), or for a video's views, neither.
    #[test]
    fn sparse_photos_keep_a_share_of_the_budget_as_a_cap() {
        let options = photo_options();
        let (width, height) = (480, 270);
        let dense = 0.2 * 480.0 * 270.0;
        let sparse = views_apart(9.0, width, height);
        let target = growth_target(&options, 1132, &sparse).unwrap();
        assert!(
            (target.kernels - dense / 4.0).abs() < 1e-6,
            "{}",
            target.kernels
        );
        let budget = BudgetOnViews::new(&options, &sparse).unwrap();
        assert!((budget.sparse.unwrap().0 - 0.25).abs() < 1e-12);
        let (cap, note) = budget.sparse_views_cap(&options, 1132).unwrap();
        assert_eq!(cap, (dense / 4.0) as usize);
        assert!(
            note.contains("9.0°") && note.contains(&format!("stops at {cap} kernels")),
            "{note}"
        );
        // The rounds may at least double the start.
        assert_eq!(cap_of(&options, 4000, &sparse).unwrap().0, 8000);
        // `max_kernels` bounds both.
        let bounded = AlphaFitOptions {
            max_kernels: 3000,
            ..options
        };
        assert_eq!(cap_of(&bounded, 1132, &sparse).unwrap().0, 3000);
        assert_eq!(cap_of(&bounded, 2000, &sparse).unwrap().0, 3000);
        // Dense views: the whole budget, no cap.
        let dense_views = views_apart(1.0, width, height);
        assert_eq!(
            growth_target(&options, 1132, &dense_views).unwrap().kernels,
            dense
        );
        assert_eq!(cap_of(&options, 1132, &dense_views), None);
        let no_budget = AlphaFitOptions {
            kernel_budget: None,
            ..options
        };
        assert_eq!(cap_of(&no_budget, 1132, &sparse), None);
        // A video (views at several times) keeps the whole budget.
        let mut video = sparse.clone();
        video[1].time = 1.0;
        assert_eq!(
            growth_target(&options, 1132, &video).unwrap().kernels,
            dense
        );
        assert_eq!(cap_of(&options, 1132, &video), None);
        // A capped budget's note never says the least growth passes it.
        let target = budget.growth_target(&options, 1132).unwrap();
        let start = 2000;
        let capped = budget.growth_note(target, &options, start);
        assert!(!capped.contains("passes it"), "{capped}");
        assert!(capped.contains("times 0.25 for sparse views"), "{capped}");
        let uncapped = BudgetOnViews {
            sparse: None,
            ..budget
        };
        assert!(
            uncapped
                .growth_note(target, &options, start)
                .contains("passes it")
        );
    }

    /// The sparse-view cap of a fit of `options` of `train` from `start` kernels.
    fn cap_of(options: &AlphaFitOptions, start: usize, train: &[View]) -> Option<(usize, String)> {
        BudgetOnViews::new(options, train)?.sparse_views_cap(options, start)
    }

    #[test]
    fn a_photo_budget_is_a_share_of_the_largest_views_pixels() {
        let options = photo_options();
        assert_eq!(options.rules(1.0, 1.0).rounds_from(1, options.steps), 33);
        let train = views_of(480, 270);
        let target = growth_target(&options, 1132, &train).expect("a budget above the start");
        // No pruning by score on photos: the budget is the target.
        assert_eq!(target.kernels, 0.2 * 480.0 * 270.0);
        assert_eq!(target.max_share, DEFAULT_PHOTO_KERNEL_BUDGET.max_growth);
        // The largest view sets the budget.
        let mut mixed = views_of(100, 100);
        mixed[2] = train[0].clone();
        assert_eq!(growth_target(&options, 1132, &mixed), Some(target));
    }

    /// Renders of an object on their schedule (12 000 steps, a round every 200): the
    /// objects' budget follows the views' side, 40 kernels a pixel of it, and the rounds
    /// grow towards twice that, since the pruning by score removes half.
    #[test]
    fn the_objects_budget_follows_the_views_side_before_the_pruning() {
        let options = AlphaFitOptions {
            kernel_budget: Some(DEFAULT_OBJECT_KERNEL_BUDGET),
            steps: DEFAULT_OBJECT_SCHEDULE.steps,
            densify_every: DEFAULT_OBJECT_SCHEDULE.densify_every,
            prune_fraction: DEFAULT_PRUNE_FRACTION,
            ..DEFAULT_ALPHA
        };
        assert_eq!(options.rules(1.0, 1.0).rounds_from(1, options.steps), 33);
        for (side, budget) in [(100, 4000.0), (400, 16_000.0)] {
            let target = growth_target(&options, 2000, &views_of(side, side)).unwrap();
            assert_eq!(target.kernels, budget / (1.0 - DEFAULT_PRUNE_FRACTION));
            assert_eq!(target.max_share, DEFAULT_OBJECT_KERNEL_BUDGET.max_growth);
        }
        // 100×200 views: 40 √20 000.
        let target = growth_target(&options, 2000, &views_of(100, 200)).unwrap();
        assert!((target.kernels - 2.0 * 40.0 * 20_000_f64.sqrt()).abs() < 1e-9);
        // Small views: at most half a kernel a pixel (40 √P passes P/2 below 160×160).
        let target = growth_target(&options, 200, &views_of(48, 48)).unwrap();
        assert_eq!(target.kernels, 2.0 * 0.5 * 48.0 * 48.0);
    }

    #[test]
    fn a_kernel_budget_gives_no_target_where_it_cannot_act() {
        let options = photo_options();
        // A start at the budget or above it.
        assert_eq!(growth_target(&options, 3000, &views_of(100, 150)), None);
        // No rounds, no budget.
        let no_rounds = AlphaFitOptions {
            densify_every: 0,
            ..options
        };
        assert_eq!(growth_target(&no_rounds, 10, &views_of(480, 270)), None);
        let no_budget = AlphaFitOptions {
            kernel_budget: None,
            ..options
        };
        assert_eq!(growth_target(&no_budget, 10, &views_of(480, 270)), None);
        // `max_kernels` bounds the target.
        let capped = AlphaFitOptions {
            max_kernels: 2000,
            ..options
        };
        let target = growth_target(&capped, 100, &views_of(1920, 1080)).unwrap();
        assert_eq!(target.kernels, 2000.0);
    }

    #[test]
    fn fixed_scales_split_above_an_eighth_of_the_initial_scale() {
        let plan = FitPlan {
            adaptive: true,
            init_scale: Some([0.4, 0.4, 0.4, 0.2]),
            ..FitPlan::default()
        };
        let prepared = plan.prepare(Init::Random(5), &views()).unwrap();
        assert_eq!(prepared.mode, FitMode::Paper);
        assert_eq!(prepared.scene.len(), 5);
        let rounds = prepared.options.adaptive.unwrap();
        assert!(
            (rounds.min_scale - 0.05).abs() < 1e-15,
            "{}",
            rounds.min_scale
        );
        assert_eq!(
            rounds.min_time_scale,
            f64::INFINITY,
            "no time split in paper mode"
        );
        let rates = prepared.options.learning_rates;
        assert_eq!((rates.velocity, rates.scale), (0.0, 0.0), "paper mode");
    }

    #[test]
    fn freezing_a_group_zeroes_its_rate() {
        let plan = FitPlan {
            freeze_time: true,
            freeze_background: true,
            fit_velocity: true,
            ..FitPlan::default()
        };
        let prepared = plan.prepare(Init::Random(2), &views()).unwrap();
        let rates = prepared.options.learning_rates;
        assert_eq!((rates.time, rates.background), (0.0, 0.0));
        assert_eq!(rates.velocity, DEFAULT_RATES.velocity);
        assert!(prepared.options.adaptive.is_none(), "a fixed count");
        let fitted = FitPlan::default().prepare(Init::Auto, &views()).unwrap();
        assert_eq!(
            fitted.options.learning_rates.background,
            DEFAULT_RATES.background
        );
    }

    #[test]
    fn background_and_start_amplitude_come_from_the_data() {
        // A dark square on a bright grey background: the border says 0.9, the square is
        // 0.7 below it.
        let mut views = views();
        for view in &mut views {
            view.image = Image::filled(8, 8, [0.9, 0.8, 0.9]).into();
            for j in 3..5 {
                for i in 3..5 {
                    let k = 3 * (j * 8 + i);
                    std::sync::Arc::make_mut(&mut view.image).pixels[k..k + 3]
                        .copy_from_slice(&[0.2, 0.1, 0.2]);
                }
            }
        }
        let prepared = FitPlan::default().prepare(Init::Auto, &views).unwrap();
        let [r, g, b] = prepared.scene.background;
        assert!((r - 0.9).abs() < 1e-6 && (g - 0.8).abs() < 1e-6 && (b - 0.9).abs() < 1e-6);
        for (a, expected) in prepared.scene.amplitudes[0].iter().zip([-0.7, -0.7, -0.7]) {
            assert!(
                (a - expected).abs() < 1e-6,
                "{:?}",
                prepared.scene.amplitudes[0]
            );
        }
        // Given values win.
        let given = FitPlan {
            background: Some([0.2, 0.3, 0.4]),
            init_amplitude: Some(0.5),
            ..FitPlan::default()
        };
        let scene = given.prepare(Init::Random(3), &views).unwrap().scene;
        assert_eq!(scene.background, [0.2, 0.3, 0.4]);
        assert!(scene.amplitudes.iter().all(|a| *a == [0.5; 3]));
        // Nothing but background: the default amplitude.
        let blank = FitPlan::default()
            .prepare(Init::Auto, &super::tests::views())
            .unwrap();
        assert_eq!(blank.scene.amplitudes[0], [DEFAULT_INIT_AMPLITUDE; 3]);
        assert_eq!(blank.scene.background, [0.0; 3]);
    }

    #[test]
    fn bad_starts_are_refused() {
        assert!(Init::parse_builtin("random:0").is_err());
        assert!(Init::parse_builtin("random:18446744073709551615").is_err());
        assert!(Init::parse_builtin("random:x").is_err());
        assert_eq!(
            Init::parse_builtin("random:3").unwrap(),
            Some(Init::Random(3))
        );
        assert_eq!(Init::parse_builtin("scene.json").unwrap(), None);
        let bad_box = FitPlan {
            bounds: Some([0.0, 0.0, 0.0, -1.0, 1.0, 1.0]),
            ..FitPlan::default()
        };
        assert!(bad_box.prepare(Init::Random(1), &views()).is_err());
    }
}
