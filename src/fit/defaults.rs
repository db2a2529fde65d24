//! Every default and limit of a fit, as constants: the additive fit's (steps, rates,
//! batch, the adaptive rounds) and the alpha fit's ([`DEFAULT_ALPHA`]), and the `Default`
//! of each options type. The policy that chooses among them is [`crate::fit::plan`]; this
//! module only names numbers (each with the measurement behind it), and the training
//! stages below it never read it.

use crate::fit::adam::AdamConfig;
use crate::fit::additive::LearningRates;
use crate::fit::additive::{AdditiveFitOptions, FitMode};
use crate::fit::alpha::{AlphaFitOptions, AlphaRates, KernelBudget, MotionFit};
use crate::fit::coarse::CoarseToFine;
use crate::fit::density::{AdditiveRules, ShapeBound, TurningRule};
use crate::fit::train::{EarlyStop, TrainingLoss};
use crate::render::RenderOptions;

/// Adam steps of a fit (`splat4d fit` without `--steps`).
pub const DEFAULT_STEPS: usize = 4000;

/// Kernels an automatic start spreads at random in the box: several, so that separate
/// objects each draw one (a single start at the centre converges on the brightest object
/// and can leave the others unexplained: measured on the three-blob scene, 4 of 4 camera
/// sets reach 38.4–39.3 dB with 4 starts; with 1, one set stays at 33 dB with 4 kernels).
pub const DEFAULT_START_KERNELS: usize = 4;

/// Views per step.
pub const DEFAULT_BATCH_SIZE: usize = 8;

/// Learning rates at the last step as a fraction of the first (exponential decay).
pub const DEFAULT_FINAL_RATE_FACTOR: f64 = 0.05;

/// Held-out evaluation period, steps.
pub const DEFAULT_EVAL_EVERY: usize = 50;

/// Amplitude of every channel of a random or automatic start when the data cannot say
/// (no pixel differs from the background): the report's fixed-count fits use it too.
pub const DEFAULT_INIT_AMPLITUDE: f64 = 0.1;

/// A pixel whose colour differs from the background by more than this in some channel
/// counts as foreground when the start's amplitude is taken from the data.
pub const FOREGROUND_THRESHOLD: f32 = 1.0 / 255.0;

/// Initial learning rates of every group (a mode then zeroes the groups it does not fit).
pub const DEFAULT_RATES: LearningRates = LearningRates {
    mean: 2e-3,
    time: 2e-3,
    amplitude: 1e-2,
    velocity: 2e-3,
    scale: 1e-2,
    background: 2e-3,
};

/// The adaptive rounds (densify, prune, merge; [`crate::fit::density::additive`]).
pub const DEFAULT_ROUNDS: AdditiveRules = AdditiveRules {
    every: 50,
    from: 0.3,
    until: 0.7,
    gradient_threshold: 1e-5,
    min_improvement: 0.05,
    prune_below: 2.0 / 255.0,
    max_growth: 0.5,
    max_kernels: 100_000,
    merge_tolerance: 0.1,
    min_scale: f64::INFINITY,
    min_time_scale: f64::INFINITY,
};

/// Largest learning rate a fit accepts.
pub const MAX_RATE: f64 = 1e3;

/// Largest background channel (absolute) a fit accepts.
pub const MAX_BACKGROUND: f64 = 1e6;

/// Most kernels a fit may start from (`random:N`, `--start-kernels`): a bound checked before
/// anything is allocated for them.
pub const MAX_START_KERNELS: usize = 1_000_000;

/// A velocity kernel whose `st` exceeds this many training-time spacings is split in time
/// by the adaptive rounds ([`crate::fit::density::additive`]).
pub const TIME_SPLIT_SPACINGS: f64 = 2.0;

/// Where the ¼- and the ½-size stages of a coarse-to-fine fit end, as fractions of the run
/// (`docs/fitting.md`: 0.4 and 0.75 gave 0.2 dB less on the 400² D-NeRF-like proxy).
pub const DEFAULT_COARSE_ENDS: [f64; 2] = [0.3, 0.6];

/// The alpha fit's coarse stages ([`crate::fit::coarse`]): a ½ stage on 100×100 views lost
/// 0.8 dB on the D-NeRF-like proxy, hence the 100-pixel floor.
pub const DEFAULT_COARSE: CoarseToFine = CoarseToFine::Auto {
    min_side: 100,
    ends: DEFAULT_COARSE_ENDS,
};

/// The window side of the alpha fit's steps ([`crate::fit::window`]). On the D-NeRF-like
/// proxy at 400×400 (`docs/fitting.md`, "Windows") 2×2 windows of 200² took 0.58× the
/// whole views' time at the same held-out PSNR (36.34 against 36.33 dB); 4×4 windows of 100²
/// took 0.41× and lost 0.5 dB.
pub const DEFAULT_WINDOW: Option<u32> = Some(200);

/// The alpha fit's steps, steps between density rounds and views per step where the caller
/// gives no step count ([`crate::fit::plan::alpha_schedule`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AlphaSchedule {
    /// Adam steps.
    pub steps: usize,
    /// Steps between density rounds.
    pub densify_every: usize,
    /// Training views per step.
    pub batch_size: usize,
}

/// The schedule of renders of an object (training views over a flat background, at any
/// size): twice [`DEFAULT_ALPHA`]'s steps at the same 33 density rounds, each step on 2
/// views rather than 4, so as many views rendered in all. Photos keep [`DEFAULT_ALPHA`]'s.
///
/// Measured (`docs/fitting.md`, "Steps"; one run each, default fits otherwise, wall time on
/// 2 cores, held-out PSNR of the mean MSE and the mean of the views' PSNR):
/// - D-NeRF-like proxy at 100×100: 38.16 / 39.09 dB in 32.2 s against 4 views a step's
///   37.89 / 39.26 dB in 57.8 s (seed 1: 38.24 / 39.02 dB against 38.38 / 39.21 dB); 6000
///   steps of 4 views gave 37.08 / 38.49 dB;
/// - at 400×400: 38.28 / 39.07 dB in 69.6 s against 6000 steps of 4 views' 36.94 /
///   38.77 dB in 63.0 s (12 000 steps of 4: 37.13 / 39.10 dB, 2.05× the time);
/// - the occluding data at 48×48: 38.43 / 41.10 dB in 20.4 s against 36.75 / 40.06 dB in
///   37.5 s;
/// - but the proxy with 200 views at 100×100 lost: 39.49 / 40.19 dB against 40.13 / 40.98 dB
///   (12 000 steps of 4) and 39.68 / 40.35 dB (6000 of 4).
///
/// On photos 2 views a step lost: the phone-like proxy at ¼ size 38.23 → 36.73 dB (6000
/// steps) and 37.09 dB (12 000), the DSLR-like 40.72 → 40.56 and 39.55 dB.
pub const DEFAULT_OBJECT_SCHEDULE: AlphaSchedule = AlphaSchedule {
    steps: 12_000,
    densify_every: 200,
    batch_size: 2,
};

/// The schedule of still photos from sparse views (their axes more than
/// [`DEFAULT_DENSE_VIEW_SPACING`] from their nearest, [`crate::fit::plan::sparse_spacing`]):
/// a third of [`DEFAULT_PHOTO_SCHEDULE`]'s steps at its density period and batch, so the density
/// rounds (5 % to 60 % of the steps) stop at step 1200, no opacity reset falls among them,
/// SH reaches degree 1, and the last 800 steps polish what the rounds grew. Such photos'
/// held-out PSNR peaks early and falls as the fit goes on: kernels grown and polished
/// past that point fit what only the training photos see.
///
/// Measured (2026-11-29, `docs/fitting.md`, "Sparse views: fewer steps"; one run each,
/// `--downscale 4`, mean of the held-out photos' PSNR, two fits at a time on 2 cores):
/// - a phone capture of a mouse (56 photos, 7 held out, spacing 7.8°): 6000 steps 21.77 dB,
///   3000 steps 22.06 dB, 2000 steps 23.68 dB in 124 s, 1000 steps 23.88 dB; 6000 steps
///   without the opacity reset 22.86 dB;
/// - the king figurine (23 photos, 3 held out, 10.7°): 6000 steps 19.16 dB in 330 s,
///   3000 steps 18.30 dB, 2000 steps 19.28 dB in 140 s, 1000 steps 18.68 dB; 6000 steps
///   without the opacity reset 18.68 dB;
/// - with `--seed 1`: the mouse 22.51 dB at 6000 steps, 23.52 dB at 2000; the king
///   19.16 dB at 6000, 18.69 dB at 2000 (its held-out PSNR moves by ±0.5 dB between runs).
pub const DEFAULT_SPARSE_PHOTO_SCHEDULE: AlphaSchedule = AlphaSchedule {
    steps: 2000,
    ..DEFAULT_PHOTO_SCHEDULE
};

/// The schedule of photos from dense views (training views whose background is not flat):
/// [`DEFAULT_ALPHA`]'s steps, density period and batch.
pub const DEFAULT_PHOTO_SCHEDULE: AlphaSchedule = AlphaSchedule {
    steps: DEFAULT_ALPHA.steps,
    densify_every: DEFAULT_ALPHA.densify_every,
    batch_size: DEFAULT_ALPHA.batch_size,
};

/// The early stop `--early-stop F` asks for, with its gain ([`crate::fit::train::EarlyStop`]).
/// Off by default: on the D-NeRF-like proxy at 100×100 it stopped at step 4750 of 6000 with
/// 35.92 dB held out (35.82 dB after every step), but on the occluding data at step 4500
/// with 37.06 dB against 37.33 dB: the steps at the smallest rates still polish.
pub const DEFAULT_EARLY_STOP: EarlyStop = EarlyStop {
    flat_fraction: 0.15,
    min_gain_db: 0.05,
};

/// A start from a point cloud is completed by plane-sweep kernels on the pixels the cloud
/// leaves unexplained ([`crate::fit::alpha_start::completed_alpha_scene`]). Measured on the
/// DSLR-like proxy (`docs/proxies/dslr_like.py`: 20 training photos on a 27° arc, a cloud on
/// the object only, `--downscale 4`; `docs/fitting.md`): 29.16 → 45.22 dB on the training
/// views and 26.82 → 40.72 dB on the 3 held-out ones. Data without a point cloud never runs it.
pub const DEFAULT_FILL_UNCOVERED: bool = true;

/// A start from a point cloud or a plane sweep gets kernels on a far shell for the training
/// pixels it leaves unexplained, when they are at least 1 % of them
/// ([`crate::fit::shell`]). Measured on the DSLR-like proxy started from its cloud without
/// the sweep (`docs/fitting.md`): 26.82 → 33.69 dB held out (the training views 29.16 →
/// 37.40 dB), 144 → 135 s. With the sweep, and on the other proxies, the start leaves
/// under 1 % unexplained and the shell adds nothing (the same bytes).
pub const DEFAULT_FAR_SHELL: bool = true;

/// The bound on the alpha kernels' shape ([`ShapeBound`]), off by default (one run each,
/// `docs/fitting.md`). Needles at most 8 and σ at most 0.05 of the distance to the nearest
/// camera: on the DSLR-like proxy with the completed start 40.72 dB held out either way (the
/// training views 45.22 → 44.35 dB), from the cloud alone 26.82 → 22.22 dB; D-NeRF-like
/// proxy at 100² 35.82 → 36.09 dB; occluding data 37.17 → 36.40 dB. Needles at most 8
/// alone: DSLR-like 40.72 → 38.71 dB (cloud alone 26.82 → 26.28 dB), D-NeRF-like 36.00 dB,
/// occluding 37.51 dB. It loses on the data it was meant for.
pub const DEFAULT_SHAPE_BOUND: ShapeBound = ShapeBound::OFF;
/// The kernel budget of an alpha fit of photos (training views whose background is not
/// flat) where `--max-growth` is not given ([`KernelBudget`],
/// [`crate::fit::plan::growth_target`]; renders of an object have
/// [`DEFAULT_OBJECT_KERNEL_BUDGET`]): 0.2 kernels per pixel of the largest training view,
/// each density round growing by the share that reaches it in the rounds left, at most
/// 10 % and at least the 5 % of [`DEFAULT_ALPHA`], so fits of photos up to about 200×200
/// pixels (the photo proxies at ⅛, the DSLR-like proxy) stay at 5 %.
///
/// Measured on a real phone capture, instant-ngp's `fox` (50 photos, 7 held out) at
/// `--downscale 4` (270×480), one run each, 2 cores (`docs/fitting.md`, "A real capture"):
/// growing 5 % a round ended with 4878 kernels and 27.81 dB held out (mean of the views'
/// PSNR) in 367 s; 10 % a round with 22 999 kernels and 30.26 dB in 638 s; this budget as
/// one growth for the whole run (9.95 % a round) 22 724 kernels and 30.16 dB in 626 s;
/// 11.3 % a round (a budget of 0.3 a pixel) 33 940 kernels and 30.97 dB in 773 s; this
/// budget steered towards each round asks the cap every round there, 22 999 kernels and
/// 30.26 dB in 595 s (the same bytes as 10 %). A cap of 15 % a round (2026-11-28, on an
/// Intel Xeon where this budget's fit took 642 s, alone): 25 918 kernels, 30.48 dB in
/// 816 s, not taken: 28 % more time for 0.22 dB, and within 10 % of the 15 minutes asked
/// of this fit. The
/// phone-like proxy at ¼ size: 38.23 → 38.65 dB held out (39.20 → 41.04 dB per view),
/// 223 → 605 s. On the DSLR-like proxy 10 % a round took 896 s for 41.31 against
/// 40.72 dB: this budget leaves it at 5 %.
pub const DEFAULT_PHOTO_KERNEL_BUDGET: KernelBudget = KernelBudget {
    coefficient: 0.2,
    exponent: 1.0,
    max_per_pixel: 0.2,
    max_growth: 0.1,
    dense_spacing: Some(DEFAULT_DENSE_VIEW_SPACING),
};

/// The view spacing (the median over the training views of the angle between a view's
/// optical axis and its nearest other view's, [`crate::fit::plan::view_spacing_degrees`])
/// above which photos of a still scene are sparse: [`DEFAULT_PHOTO_KERNEL_BUDGET`] shrinks by
/// `(4.5° / spacing)²` there, as the views' density on the sphere of directions falls, and
/// becomes a cap, at least twice the start ([`crate::fit::plan::SPARSE_VIEWS_LEAST_GROWTH`]).
/// Kernels past it fit what only the training photos see.
///
/// Measured (2026-11-28, `docs/fitting.md`, "A real DSLR capture" and "A second real
/// capture", one run each, 2 cores). Two real COLMAP captures are sparse and lose held-out
/// PSNR to growth: a phone capture of a computer mouse (Myhan1023/mouse-3d-reconstruction,
/// 56 photos, spacing 7.8°) at `--downscale 4`, 34 561 kernels (the budget) 21.01 dB held
/// out per view in 660 s, 8640 kernels 21.85 dB in 350 s; the king figurine (23 photos,
/// 10.7°), 11 796 kernels (the 5 % floor past the budget) 18.96 dB, 8250 kernels 19.51 dB,
/// 4100 kernels 19.54 dB. This rule: the mouse 11 633 kernels, 21.77 dB; the king 5956
/// kernels, 19.16 dB in 330 s. The dense ones gain from growth and keep the budget: instant-ngp's
/// `fox` (3.2°), the phone-like proxy (3.9°), the DSLR-like proxy (1.1°): none of their
/// fits gets the sparse-views note. Above the same spacing, still photos also take
/// [`DEFAULT_SPARSE_PHOTO_SCHEDULE`]'s fewer steps.
pub const DEFAULT_DENSE_VIEW_SPACING: f64 = 4.5;

/// The kernel budget of an alpha fit of renders of an object (training views whose
/// background is flat) where `--max-growth` is not given: 40 √P kernels for the `P` pixels
/// of the largest training view (4000 at 100×100, 16 000 at 400×400; at most P/2, the
/// first budget's, below 160×160) after the pruning by score ([`DEFAULT_PRUNE_FRACTION`]), so the rounds grow towards twice that, each by the
/// share that reaches it in the rounds left, at most 15 % and at least 5 %. An object's
/// detail does not grow with the pixels: a share of them would ask 16 times the kernels
/// at 400×400 for what 100×100 needs 1 of; the views' side asks 4.
///
/// Measured on the NeRF-synthetic `lego` (static; 87 training views, every 8th of its 100
/// held out), one run each, 2 cores (`docs/fitting.md`, "Renders of an object"). At
/// `--downscale 8` (100×100): growing 5 % a round (the default before, whose start of 2000
/// kernels fell to about 1100 transparent-pruned ones before growing) ended with 1993
/// kernels and 31.91 dB held out in 70 s; 7 % a round 3775 kernels and 32.86 dB in 92 s;
/// 10 % 9528 kernels and 33.83 dB in 173 s; the fit before this work (6000 steps of 4
/// views, no pruning) 7511 kernels and 32.46 dB in 119 s. At `--downscale 2` (400×400):
/// 5 % a round 2133 kernels and 26.93 dB in 141 s; 8.76 % 6880 kernels and 29.91 dB in
/// 216 s; 10 % 10 115 kernels and 30.98 dB in 274 s; a budget of 0.5 a pixel as one growth
/// for the whole run (11.83 %) 17 286 kernels and 32.26 dB in 344 s. This budget: 4000
/// kernels and 32.86 dB in 108 s at 100×100, 16 000 kernels and 32.08 dB in 326 s at
/// 400×400. The D-NeRF-like proxy: 38.16 → 38.46 dB held out at 100×100 (71 → 78 s), 38.79 dB
/// either way at 400×400 (305 → 252 s), all on one Intel Xeon.
pub const DEFAULT_OBJECT_KERNEL_BUDGET: KernelBudget = KernelBudget {
    coefficient: 40.0,
    exponent: 0.5,
    max_per_pixel: 0.5,
    max_growth: 0.15,
    dense_spacing: None,
};

/// The weight `λ` of `1 - SSIM` in the 3DGS loss (`--loss l1-dssim`; [`crate::fit::ssim`]):
/// 3D Gaussian splatting's 0.2.
pub const DEFAULT_DSSIM_WEIGHT: f64 = 0.2;

/// The alpha fit's training loss: 3DGS's `0.8 L1 + 0.2 (1 - SSIM)` (`--loss l1-dssim`).
/// Measured against the MSE at equal steps (`docs/fitting.md`, one run per seed, default
/// fits otherwise): held-out PSNR +0.54 dB on the D-NeRF-like proxy at 100² (mean of seeds
/// 0–2: 36.54 against 36.00 dB), +0.55 dB on the occluding data's test views (37.18 against
/// 36.63 dB; 2 of 3 seeds better) and +0.53 dB on its val views, +0.33 dB at 400² (seed 0);
/// SSIM higher in every run; about a third fewer kernels. Its cost: the same CPU time at
/// 100² and 48², 1.47× at 400² (the SSIM pass and the unfused render and backward).
pub const DEFAULT_LOSS: TrainingLoss = TrainingLoss::L1Dssim(crate::fit::ssim::L1Dssim {
    dssim_weight: DEFAULT_DSSIM_WEIGHT,
});

/// The alpha fit's training loss on photos, whose background is textured to their borders
/// ([`crate::fit::plan::background_defaults`]): the MSE. The 3DGS loss measured worse there
/// (`docs/fitting.md`, one run each, the 3DGS loss against the MSE): the phone-like proxy
/// at ¼ size 37.71 against 38.23 dB held out, at ⅛ size 38.00 against 38.56 dB; the
/// DSLR-like proxy 39.48 against 40.72 dB (6000 steps) and 39.45 against 40.07 dB (12 000).
/// Its SSIM was the higher (at ⅛ 0.9822 against 0.9767) and its CPU time the same.
pub const DEFAULT_PHOTO_LOSS: TrainingLoss = TrainingLoss::Mse;

/// The alpha fit's training loss on still photos from sparse views (their axes more than
/// [`DEFAULT_DENSE_VIEW_SPACING`] from their nearest, [`crate::fit::plan::sparse_spacing`]):
/// the 3DGS loss, [`DEFAULT_LOSS`], whose SSIM term weighs local structure (the held-out
/// SSIM rose in every run measured both ways). Measured on two real COLMAP captures at ¼ size with their other defaults
/// (2000 steps; `docs/fitting.md`, "Sparse views: the 3DGS loss"), mean held-out PSNR per
/// photo, the MSE against the 3DGS loss: the king figurine 19.28 → 19.83 dB (seed 1: 18.69
/// → 19.78 dB), SSIM 0.7496 → 0.7940; the mouse 23.68 → 24.00 dB (seed 1: 23.52 dB both),
/// SSIM 0.9319 → 0.9461 (seed 1: 0.9323 → 0.9456); the same time on the king, 13 % more
/// on the mouse.
pub const DEFAULT_SPARSE_PHOTO_LOSS: TrainingLoss = DEFAULT_LOSS;

/// With `--motion auto`, the splits in time of a kernel's line after which a kernel that
/// still spans motion gets fitted SPEC §9 motion instead ([`crate::fit::density::alpha`]).
pub const DEFAULT_MOTION_AFTER_SPLITS: u32 = 1;

/// With `--motion auto`, the turning trigger ([`crate::fit::density::turning`]): a kernel
/// whose velocity gradient's first moment in time (its acceleration gradient, summed over
/// a density interval) is steady, `|Σg|/√Σ|g|²` at least 3, in 2 consecutive intervals
/// each within 60° of the one before, gets fitted SPEC §9 motion. For noise of mean zero
/// `z²` is about χ²₃/3 (mean 1), so an interval of noise passes 3 with probability about
/// 6e-6 and 2 with about 0.007. Measured with `--motion auto` (`docs/fitting.md`, "Motion"; one run
/// each): on the thrown ball 41.31 dB held out against 40.25 dB with the splits-in-time
/// trigger alone (775 of 2678 kernels moving, 5 % more CPU), on the D-NeRF-like proxy at
/// 100² 37.14 against 36.79 dB. Steadiness 4: 41.00 dB (295 moving); 2 in 3 intervals:
/// 41.21 dB (541); steadiness 2: 41.63 dB, with 1422 of 2715 kernels moving (steady
/// pulls, not noise, which passes 2 with probability 0.007). The pull between intervals of the velocity
/// gradient itself (its cosine below 0.5 twice running, steadiness 2) almost never
/// turned: 1 kernel on the ball, 40.24 dB.
pub const DEFAULT_MOTION_TURNING: TurningRule = TurningRule {
    min_steadiness: 3.0,
    min_cosine: 0.5,
    rounds: 2,
};

/// Which kernels of an alpha fit carry fitted SPEC §9 motion: every kernel, at the rates
/// [`DEFAULT_LR_ACCELERATION`] and [`DEFAULT_LR_ANGULAR_VELOCITY`]. Measured against no
/// motion and against motion where needed (`--motion auto`), one run each, default fits
/// otherwise (`docs/fitting.md`, "Motion"): held-out PSNR +1.28 dB on a thrown ball
/// (`docs/proxies/thrown_ball.py`; where needed by splits in time +0.03 dB), +1.18 dB on
/// the occluding data, +0.24 dB on the D-NeRF-like proxy at 100² (its mean per-view PSNR
/// +1.11 dB; where needed +0.07 dB) and +0.42 dB at 400², the same kernel counts within
/// 2 %; 9–19 % more CPU time. With pruning, where needed by both triggers
/// ([`DEFAULT_MOTION_TURNING`]) against every kernel: the ball 41.31 against 42.13 dB, the
/// proxy at 100² 37.14 against 37.08 dB.
pub const DEFAULT_MOTION: MotionFit = MotionFit::Everywhere;

/// The rate of the SPEC §9 accelerations, box diagonals per time range squared per step:
/// 5e-3 against 1e-2 on the thrown ball, 42.54 against 42.77 dB, with the angular rate 1e-3.
pub const DEFAULT_LR_ACCELERATION: f64 = 5e-3;

/// The rate of the SPEC §9 angular velocities, quaternion units per time range per step:
/// 5e-3 gave the thrown ball +0.43 dB but the D-NeRF-like proxy -0.42 dB against 1e-3.
pub const DEFAULT_LR_ANGULAR_VELOCITY: f64 = 1e-3;

/// The fraction of the alpha kernels removed by their spatio-temporal score when growth
/// ends (`--prune-fraction`; [`crate::fit::density::prune`]). Measured against no pruning
/// at equal steps (`docs/fitting.md`, "Pruning and regularisers"; seeds 0 and 1): half the
/// kernels, 8–16 % less CPU time, and the held-out PSNR equal or higher in every run (the
/// D-NeRF-like proxy at 100² 36.64 → 36.64 and 36.12 → 36.28 dB; the occluding data's test
/// views 37.81 → 37.78 and 36.88 → 37.61 dB, its val views +0.63 and +0.71 dB). 0.8, the
/// share 4DGS-1K removes, lost 5 dB on the proxy, 0.65 lost 0.3 dB. It applies where the
/// training views' background is flat ([`crate::fit::plan::background_defaults`]): on
/// the phone-like proxy's photos it lost 2.34 dB.
pub const DEFAULT_PRUNE_FRACTION: f64 = 0.5;

/// The rounds that remove [`DEFAULT_PRUNE_FRACTION`] together (`--prune-rounds`).
pub const DEFAULT_PRUNE_ROUNDS: usize = 1;

/// `λo` of the L1 on the alpha opacities (`--opacity-regulariser`;
/// [`crate::fit::regularise`]). Off: 3DGS-MCMC's 0.01 gave 2505 kernels but 34.17 dB
/// against 36.64 dB on the D-NeRF-like proxy at 100² (`docs/fitting.md`).
pub const DEFAULT_OPACITY_REGULARISER: f64 = 0.0;

/// `λs` of the L1 on the alpha spatial scales (`--scale-regulariser`). Off: 0.01 gave
/// 36.39 dB against 36.64 dB on the D-NeRF-like proxy at 100², with as many kernels.
pub const DEFAULT_SCALE_REGULARISER: f64 = 0.0;

/// Every default of the alpha fit (SPEC §8, [`crate::fit::alpha`]): the 3DGS and 4DGS
/// papers' rates and density rules, scaled to runs of a few thousand steps.
///
/// Measured (one run each, `docs/fitting.md`): on a D-NeRF-like monocular proxy (100 views
/// at 100×100, `docs/proxies/dnerf_like.py`) 3000 → 6000 steps took the test views from
/// 34.4 to 35.5 dB (91 s); σt 0.1 gave 36.2 dB there but 35.3 against 37.3 dB on the
/// occluding data, so σt stays at the 0.25 that a dense prototype used on real D-NeRF
/// scenes; 3DGS's opacity reset (every 2000 steps to 0.01, pruning below 0.005) gave +0.3 dB
/// on the occluding data and -0.3 dB on the proxy, and is kept for the floaters of real
/// photos. On a phone-capture proxy (50 photos, `docs/proxies/phone_like.py`, `--downscale
/// 8`) the defaults end in about 6 minutes on 2 cores.
pub const DEFAULT_ALPHA: AlphaFitOptions = AlphaFitOptions {
    steps: 6000,
    batch_size: 4,
    rates: AlphaRates {
        mean: 1.6e-4,
        time: 1.6e-4,
        velocity: 1.6e-4,
        acceleration: DEFAULT_LR_ACCELERATION,
        angular_velocity: DEFAULT_LR_ANGULAR_VELOCITY,
        scale: 5e-3,
        rotation: 1e-3,
        opacity: 5e-2,
        colour: 2.5e-3,
        sh: 5e-4,
    },
    final_rate_factor: 0.01,
    eval_every: DEFAULT_EVAL_EVERY,
    seed: 0,
    render: RenderOptions {
        dilation: crate::render::DEFAULT_DILATION,
        cutoff: crate::render::DEFAULT_CUTOFF,
        exp: crate::simd::ExpMode::Poly,
    },
    start_kernels: 2000,
    max_start_points: 3000,
    start_opacity: 0.1,
    start_time_scale: 0.25,
    sh_count: 3,
    sh_raise_every: 1000,
    max_kernels: 200_000,
    densify_every: 100,
    densify_from: 0.05,
    densify_until: 0.6,
    densify_fraction: 0.05,
    densify_threshold: 0.0,
    percent_dense: 0.01,
    prune_opacity: 0.005,
    opacity_reset_every: 2000,
    reset_opacity: 0.01,
    time_split_fraction: 0.05,
    coarse: DEFAULT_COARSE,
    early_stop: None,
    window: DEFAULT_WINDOW,
    shape_bound: DEFAULT_SHAPE_BOUND,
    fill_uncovered: DEFAULT_FILL_UNCOVERED,
    far_shell: DEFAULT_FAR_SHELL,
    loss: DEFAULT_LOSS,
    motion: DEFAULT_MOTION,
    prune_fraction: DEFAULT_PRUNE_FRACTION,
    prune_rounds: DEFAULT_PRUNE_ROUNDS,
    opacity_regulariser: DEFAULT_OPACITY_REGULARISER,
    scale_regulariser: DEFAULT_SCALE_REGULARISER,
    kernel_budget: None,
};

/// The defaults of this module with the paper's mode and a fixed count.
impl Default for AdditiveFitOptions {
    fn default() -> Self {
        AdditiveFitOptions {
            steps: DEFAULT_STEPS,
            batch_size: DEFAULT_BATCH_SIZE,
            // The paper fits no background.
            learning_rates: LearningRates {
                background: 0.0,
                ..FitMode::Paper.learning_rates(DEFAULT_RATES)
            },
            final_rate_factor: DEFAULT_FINAL_RATE_FACTOR,
            adam: AdamConfig::default(),
            eval_every: DEFAULT_EVAL_EVERY,
            seed: 0,
            render: RenderOptions::default(),
            adaptive: None,
        }
    }
}

/// [`DEFAULT_ROUNDS`].
impl Default for AdditiveRules {
    fn default() -> Self {
        DEFAULT_ROUNDS
    }
}

impl Default for AlphaFitOptions {
    fn default() -> Self {
        DEFAULT_ALPHA
    }
}
