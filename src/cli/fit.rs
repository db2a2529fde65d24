//! `splat4d fit`: kernels fitted to a multi-view dataset with Adam. Every default and which
//! blend a setting acts on come from [`splat4d::fit::settings::FitSettings`]; this file only
//! maps flags onto it (a flag left out is `None`: the plan chooses).

use std::path::PathBuf;

use splat4d::Result;
use splat4d::fit::additive::FitMode;
use splat4d::fit::coarse::CoarseToFine;
use splat4d::fit::settings::{FitSettings, MotionName, RateSettings};
use splat4d::fit::train::LossName;
use splat4d::tasks::fit::{FitRequest, fit_dataset};
use splat4d::tasks::fit_options::blend_choice;

use super::args::{EarlyStopChoice, RenderFlags, WindowChoice, parse_list};

/// `help fit` headings: the flags every fit reads, then those of each blend.
const BOTH: &str = "Both blends";
const ADDITIVE: &str = "Additive blend only (refused with the alpha blend)";
const ALPHA: &str = "Alpha blend only (refused with the additive blend)";

#[derive(Debug, clap::Args)]
pub struct FitArgs {
    /// Dataset folder: D-NeRF layout (transforms_train.json, and val/test for held-out
    /// views), one nerfstudio/instant-ngp transforms.json, a COLMAP model (sparse/0 and
    /// images/), or a Neural 3D Video rig (poses_bounds.npy with camNN.mp4 or
    /// camNN/images/).
    #[arg(long)]
    views: PathBuf,
    /// Refuse a dataset with frames whose image file is missing (by default they are
    /// skipped with one warning naming them).
    #[arg(long)]
    strict: bool,
    /// Initial scene: `auto` (additive: one kernel at the centre of the box, then densify,
    /// prune and merge so the count follows the data; alpha: the dataset's point cloud, a
    /// visual hull, a plane sweep or kernels at random), `random:N` for N kernels in the box
    /// (a fixed count for the additive blend unless --adaptive), or a scene file.
    #[arg(long, default_value = "auto")]
    init: String,
    /// The blend to fit (SPEC §5 or §8): `additive`, `alpha`, or `auto`: the start scene's
    /// blend, else the one a splat4d dataset records (`splat4d_blend`), else `alpha`
    /// (occlusion and view-dependent colour, what real captures need).
    #[arg(long, default_value = "auto")]
    blend: String,
    /// Output scene JSON.
    #[arg(long)]
    out: PathBuf,
    /// Log file: one JSON object per step (step, seconds, train_loss, heldout_psnr, kernels,
    /// pairs, downscale).
    #[arg(long)]
    log: Option<PathBuf>,
    /// Watch the fit in a web browser: serve `splat4d view`'s page on this loopback port
    /// (8080 when given alone), with the current model every few seconds and the loss chart.
    #[arg(long, num_args = 0..=1, default_missing_value = "8080", value_name = "PORT")]
    view: Option<u16>,
    /// Average N×N blocks of pixels of every image (a box filter, like nerfstudio's
    /// `images_N`); the intrinsics are divided by N.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=i64::from(splat4d::io::dataset::MAX_DOWNSCALE)))]
    downscale: u32,
    /// Read dataset images whose real path (symlinks followed) lies outside the dataset's
    /// folder (refused by default, naming the frame).
    #[arg(long)]
    allow_outside_images: bool,
    /// Frames read of a multi-camera video dataset (poses_bounds.npy): `A:B[:STEP]`, frames
    /// A to B - 1, every STEP-th (default: all).
    #[arg(long, value_name = "A:B[:STEP]")]
    frames: Option<splat4d::io::dataset::FrameRange>,
    /// Frames per second of a multi-camera video dataset: frame k at time k/FPS seconds
    /// (default: frame k of F at k/(F-1)).
    #[arg(long)]
    fps: Option<f64>,
    #[command(flatten)]
    render: RenderFlags,

    /// Adam steps (default: 4000 additive; alpha 12000 where the training views' background
    /// is flat (renders of an object), else 6000).
    #[arg(long, help_heading = BOTH)]
    steps: Option<usize>,
    /// Views per step (default: 8 additive; alpha 2 with the 12000 steps of renders of an
    /// object when `--steps` is not given, else 4).
    #[arg(long, help_heading = BOTH)]
    batch: Option<usize>,
    /// Kernels `auto` starts from (default: 4 additive, where 1 is one kernel at the centre
    /// of the box; 2000 alpha, the hull's, plane sweep's or random start's count, and the
    /// most a far shell adds).
    #[arg(long, help_heading = BOTH)]
    start_kernels: Option<usize>,
    /// Budget of the density rounds: never more kernels than this (default: 100000
    /// additive, 200000 alpha).
    #[arg(long, help_heading = BOTH)]
    max_kernels: Option<usize>,
    /// Held-out evaluation period, steps (0: only at the end) [default: 50].
    #[arg(long, help_heading = BOTH)]
    eval_every: Option<usize>,
    /// Seed of the start and of the batch order [default: 0].
    #[arg(long, help_heading = BOTH)]
    seed: Option<u64>,
    /// Background `r,g,b`: RGBA images are composited over it and the fit starts from it
    /// (default: RGBA images over black; the fit starts from the median of the images'
    /// border pixels). The additive fit fits it unless --freeze-background; the alpha fit
    /// keeps it.
    #[arg(long, value_parser = parse_list::<3>, help_heading = BOTH)]
    background: Option<[f64; 3]>,
    /// Learning rate of the spatial means (default: 2e-3 additive; 1.6e-4 of the cameras'
    /// box diagonal per step alpha).
    #[arg(long, value_parser = super::args::finite, help_heading = BOTH)]
    lr_mean: Option<f64>,
    /// Learning rate of the time means (default: 2e-3 additive; 1.6e-4 of the time range
    /// per step alpha).
    #[arg(long, value_parser = super::args::finite, help_heading = BOTH)]
    lr_time: Option<f64>,
    /// Learning rate of the amplitudes: the additive colour, the alpha colour's base
    /// (default: 1e-2 additive, 2.5e-3 alpha).
    #[arg(long, value_parser = super::args::finite, help_heading = BOTH)]
    lr_amplitude: Option<f64>,
    /// Learning rate of the velocities (additive: with `--mode velocity` or --fit-velocity;
    /// default: 2e-3 additive, 1.6e-4 alpha).
    #[arg(long, value_parser = super::args::finite, help_heading = BOTH)]
    lr_velocity: Option<f64>,
    /// Learning rate of the log scales, a relative change per step (additive: modes
    /// `static` and `velocity`, or --fit-scale; default: 1e-2 additive, 5e-3 alpha).
    #[arg(long, value_parser = super::args::finite, help_heading = BOTH)]
    lr_scale: Option<f64>,
    /// Learning rates at the last step as a fraction of the first (exponential decay; the
    /// alpha fit decays its spatial rates; default: 0.05 additive, 0.01 alpha).
    #[arg(long, value_parser = super::args::finite, help_heading = BOTH)]
    lr_final: Option<f64>,
    /// Keep the spatial means fixed.
    #[arg(long, help_heading = BOTH)]
    freeze_mean: bool,
    /// Keep the time means fixed.
    #[arg(long, help_heading = BOTH)]
    freeze_time: bool,
    /// Keep the amplitudes fixed (alpha: the colour's base; its SH still move).
    #[arg(long, help_heading = BOTH)]
    freeze_amplitude: bool,
    /// Steps between density rounds (default: 50 additive; alpha 100, or 200 with the
    /// 12000 steps of renders of an object when `--steps` is not given).
    #[arg(long, help_heading = BOTH)]
    densify_every: Option<usize>,
    /// Fraction of the steps before the first density round (default: 0.3 additive, 0.05
    /// alpha).
    #[arg(long, value_parser = super::args::finite, help_heading = BOTH)]
    densify_from: Option<f64>,
    /// Fraction of the steps after which the kernel count is frozen (default: 0.7
    /// additive, 0.6 alpha).
    #[arg(long, value_parser = super::args::finite, help_heading = BOTH)]
    densify_until: Option<f64>,
    /// Gradient at which a kernel is densified: additive, the mean positional gradient
    /// (loss per standard deviation of motion; default 1e-5); alpha, the mean screen
    /// gradient |∂L/∂m2| per pixel (default 0: the largest --max-growth share of the
    /// visible kernels).
    #[arg(long, value_parser = super::args::finite, help_heading = BOTH)]
    densify_threshold: Option<f64>,
    /// Largest fraction of the kernels densified in one round (default: 0.5 additive;
    /// alpha, 0.05 of the visible kernels, raised each round to what reaches a kernel
    /// budget in the rounds left: photos up to 0.1 for 0.2 kernels per pixel of the largest
    /// training view, times (4.5°/spacing)² and never passed where still photos' axes are
    /// more than 4.5° apart, renders of an object up to 0.15 for 40 √pixels of it after the
    /// pruning by score).
    #[arg(long, value_parser = super::args::finite, help_heading = BOTH)]
    max_growth: Option<f64>,
    /// Kernels are pruned below this: additive, their peak |amplitude| (default 2/255);
    /// alpha, their opacity (default 0.005).
    #[arg(long, value_parser = super::args::finite, help_heading = BOTH)]
    prune_below: Option<f64>,

    /// What the fit moves: `paper` (means and amplitudes; kernels static in space, scales
    /// fixed, as in the seed paper), `static` (also the scales), `velocity` (also the
    /// velocities and the scales). Default: `velocity` with `--init auto` (the most compact
    /// models in the report), `paper` otherwise.
    #[arg(long, help_heading = ADDITIVE)]
    mode: Option<FitMode>,
    /// Fit the velocities too, whatever the mode.
    #[arg(long, help_heading = ADDITIVE)]
    fit_velocity: bool,
    /// Fit the scales (sx, sy, sz, st) too, in log space, whatever the mode.
    #[arg(long, help_heading = ADDITIVE)]
    fit_scale: bool,
    /// Densify and prune during the fit (always on with `--init auto`; the alpha fit
    /// always densifies and prunes).
    #[arg(long, help_heading = ADDITIVE)]
    adaptive: bool,
    /// Kernels are densified only when the mean training loss fell by less than this
    /// fraction over the last --densify-every steps (the fit has stalled) [default: 0.05].
    #[arg(long, value_parser = super::args::finite, help_heading = ADDITIVE)]
    min_improvement: Option<f64>,
    /// Kernels within this many standard deviations of each other (position, time,
    /// velocity, log-scale) are merged into one; 0 disables merging [default: 0.1].
    #[arg(long, value_parser = super::args::finite, help_heading = ADDITIVE)]
    merge_tolerance: Option<f64>,
    /// Densified kernels whose mean spatial scale is above this are split (scales / 1.6),
    /// the others cloned (default: when the scales are not fitted, an eighth of the largest
    /// initial scale; otherwise never split: the fit sizes the kernels).
    #[arg(long, value_parser = super::args::finite, help_heading = ADDITIVE)]
    min_scale: Option<f64>,
    /// Box for `random:N`: `x0,y0,z0,x1,y1,z1` (default: from the cameras).
    #[arg(long, value_parser = parse_list::<6>, allow_hyphen_values = true, help_heading = ADDITIVE)]
    r#box: Option<[f64; 6]>,
    /// Time range for `random:N`: `t0,t1` (default: the training times' range).
    #[arg(long, value_parser = parse_list::<2>, allow_hyphen_values = true, help_heading = ADDITIVE)]
    time_range: Option<[f64; 2]>,
    /// Scales for `random:N`: `sx,sy,sz,st` (default: from the box and N).
    #[arg(long, value_parser = parse_list::<4>, help_heading = ADDITIVE)]
    init_scale: Option<[f64; 4]>,
    /// Amplitude of every channel of a `random:N` or `auto` start (default: the data's mean
    /// colour above the background, so the sign follows the data).
    #[arg(long, value_parser = super::args::finite, allow_negative_numbers = true, help_heading = ADDITIVE)]
    init_amplitude: Option<f64>,
    /// Learning rate of the background colour [default: 2e-3].
    #[arg(long, value_parser = super::args::finite, help_heading = ADDITIVE)]
    lr_background: Option<f64>,
    /// Keep the background fixed at its start (the given --background, or the median of the
    /// training images' border pixels).
    #[arg(long, help_heading = ADDITIVE)]
    freeze_background: bool,

    /// SH triplets per kernel: 0, 3, 8 or 15 (degree 0–3) [default: 3].
    #[arg(long, help_heading = ALPHA)]
    sh: Option<usize>,
    /// Steps between raises of the SH degree fitted (degree d from step d × this; 0: all
    /// at once) [default: 1000].
    #[arg(long, help_heading = ALPHA)]
    sh_raise_every: Option<usize>,
    /// Learning rate of the opacity logits [default: 5e-2].
    #[arg(long, value_parser = super::args::finite, help_heading = ALPHA)]
    lr_opacity: Option<f64>,
    /// Learning rate of the rotations' quaternions [default: 1e-3].
    #[arg(long, value_parser = super::args::finite, help_heading = ALPHA)]
    lr_rotation: Option<f64>,
    /// Learning rate of SPEC §9 accelerations, in the cameras' box diagonals per time range
    /// squared (0: none fitted) [default: 5e-3].
    #[arg(long, value_parser = super::args::finite, help_heading = ALPHA)]
    lr_acceleration: Option<f64>,
    /// Learning rate of SPEC §9 angular velocities (the quaternion's rate), per time range
    /// (0: none fitted) [default: 1e-3].
    #[arg(long, value_parser = super::args::finite, help_heading = ALPHA)]
    lr_angular_velocity: Option<f64>,
    /// Learning rate of the SH coefficients beyond the base colour [default: 5e-4].
    #[arg(long, value_parser = super::args::finite, help_heading = ALPHA)]
    lr_sh: Option<f64>,
    /// Steps between opacity resets while density rounds run (0: never) [default: 2000].
    #[arg(long, help_heading = ALPHA)]
    opacity_reset_every: Option<usize>,
    /// A densified kernel is split rather than cloned when its largest σ exceeds this
    /// fraction of the cameras' box diagonal [default: 0.01].
    #[arg(long, value_parser = super::args::finite, help_heading = ALPHA)]
    percent_dense: Option<f64>,
    /// A densified kernel whose σt exceeds this fraction of the time range, and which moves
    /// further than its largest σ within one σt, is split in time [default: 0.05].
    #[arg(long, value_parser = super::args::finite, help_heading = ALPHA)]
    time_split_fraction: Option<f64>,
    /// Fit downscaled views first: at 1/4 size until 30 % of the steps and 1/2 until 60 %,
    /// each only where every training view keeps at least SIDE pixels on its shorter side;
    /// `off`: every step at full size [default: 100].
    #[arg(long, value_name = "SIDE|off", value_parser = splat4d::tasks::fit_options::coarse_to_fine, help_heading = ALPHA)]
    coarse_to_fine: Option<CoarseToFine>,
    /// Stop when the held-out PSNR has not risen by 0.05 dB over this fraction of the steps,
    /// once no more kernels are added (0.15 was measured); `off`: every step runs [default:
    /// off].
    #[arg(long, value_name = "FRACTION|off", value_parser = super::args::early_stop, help_heading = ALPHA)]
    early_stop: Option<EarlyStopChoice>,
    /// Fit one window of each drawn view per step: each view cut into a grid of equal
    /// windows about SIDE pixels on a side (round(width/SIDE) columns, round(height/SIDE)
    /// rows), one drawn at random (seeded) each time the view is; views under 1.5 SIDE stay
    /// whole; `off`: whole views [default: 200].
    #[arg(long, value_name = "SIDE|off", value_parser = super::args::window, help_heading = ALPHA)]
    window: Option<WindowChoice>,
    /// The loss the gradient is taken of: `mse` (SPEC §6), or `l1-dssim`, 3D Gaussian
    /// splatting's (1 - λ)·L1 + λ·(1 - SSIM) with an 11×11 Gaussian window (σ 1.5); the
    /// reported loss and PSNR stay the MSE's [default: l1-dssim where the training views'
    /// background is flat or they are still photos from sparse views, else mse].
    #[arg(long, value_name = "mse|l1-dssim", help_heading = ALPHA)]
    loss: Option<LossName>,
    /// λ, the weight of 1 - SSIM in `--loss l1-dssim` (refused with the mse loss), in
    /// [0, 1] [default: 0.2].
    #[arg(long, value_name = "WEIGHT", value_parser = super::args::finite, help_heading = ALPHA)]
    dssim_weight: Option<f64>,
    /// Which kernels carry fitted SPEC §9 motion (an acceleration and an angular velocity,
    /// at `--lr-acceleration` and `--lr-angular-velocity`): `auto`, those that keep
    /// splitting in time (after `--motion-after-splits` splits of their line, instead of a
    /// further split) or whose velocity gradient keeps turning over their life (a steady
    /// acceleration gradient in 2 density intervals running; it needs `--lr-acceleration`
    /// above 0); `all`, every kernel; `off`, none [default: all].
    #[arg(long, value_name = "auto|all|off", help_heading = ALPHA)]
    motion: Option<MotionName>,
    /// With `--motion auto`: the splits in time of a kernel's line after which a kernel
    /// that still spans motion gets fitted motion instead of a further split [default: 1].
    #[arg(long, value_name = "N", help_heading = ALPHA)]
    motion_after_splits: Option<u32>,
    /// Remove this fraction of the kernels, in [0, 1), once growth ends: those of lowest
    /// spatio-temporal score (each kernel's Σ α·T over the training views' pixels, weighted
    /// up to 2× for a kernel that lives many frames; 4DGS-1K's criterion; 0: none)
    /// [default: 0.5 where the training views' background is flat, else 0].
    #[arg(long, value_name = "FRACTION", value_parser = super::args::finite, help_heading = ALPHA)]
    prune_fraction: Option<f64>,
    /// Spread --prune-fraction over N rounds, --densify-every steps apart, the first when
    /// growth ends [default: 1].
    #[arg(long, value_name = "N", help_heading = ALPHA)]
    prune_rounds: Option<usize>,
    /// λ of an L1 on the opacities (their mean over the kernels) added to the loss
    /// (3DGS-MCMC's) [default: 0].
    #[arg(long, value_name = "WEIGHT", value_parser = super::args::finite, help_heading = ALPHA)]
    opacity_regulariser: Option<f64>,
    /// λ of an L1 on the spatial scales (their mean over the kernels and axes, in box
    /// diagonals) added to the loss (3DGS-MCMC's) [default: 0].
    #[arg(long, value_name = "WEIGHT", value_parser = super::args::finite, help_heading = ALPHA)]
    scale_regulariser: Option<f64>,
}

/// The fit request of `args` (the flags mapped onto the library's fields, the blend read as
/// [`blend_choice`] reads the `blend` option).
fn request(args: &FitArgs) -> Result<FitRequest> {
    let blend = blend_choice(&args.blend)?;
    let settings = FitSettings {
        steps: args.steps,
        batch: args.batch,
        start_kernels: args.start_kernels,
        max_kernels: args.max_kernels,
        eval_every: args.eval_every,
        seed: args.seed,
        background: args.background,
        render: args.render.options(),
        rates: RateSettings {
            mean: args.lr_mean,
            time: args.lr_time,
            velocity: args.lr_velocity,
            scale: args.lr_scale,
            amplitude: args.lr_amplitude,
            background: args.lr_background,
            opacity: args.lr_opacity,
            rotation: args.lr_rotation,
            acceleration: args.lr_acceleration,
            angular_velocity: args.lr_angular_velocity,
            sh: args.lr_sh,
        },
        lr_final: args.lr_final,
        densify_every: args.densify_every,
        densify_from: args.densify_from,
        densify_until: args.densify_until,
        densify_threshold: args.densify_threshold,
        max_growth: args.max_growth,
        prune_below: args.prune_below,
        freeze_mean: args.freeze_mean,
        freeze_time: args.freeze_time,
        freeze_amplitude: args.freeze_amplitude,
        freeze_background: args.freeze_background,
        mode: args.mode,
        fit_velocity: args.fit_velocity,
        fit_scale: args.fit_scale,
        adaptive: args.adaptive,
        min_improvement: args.min_improvement,
        merge_tolerance: args.merge_tolerance,
        min_scale: args.min_scale,
        bounds: args.r#box,
        time_range: args.time_range,
        init_scale: args.init_scale,
        init_amplitude: args.init_amplitude,
        sh: args.sh,
        sh_raise_every: args.sh_raise_every,
        coarse_to_fine: args.coarse_to_fine,
        early_stop: args.early_stop.map(|choice| choice.0),
        window: args.window.map(|choice| choice.0),
        loss: args.loss,
        dssim_weight: args.dssim_weight,
        motion: args.motion,
        motion_after_splits: args.motion_after_splits,
        prune_fraction: args.prune_fraction,
        prune_rounds: args.prune_rounds,
        opacity_regulariser: args.opacity_regulariser,
        scale_regulariser: args.scale_regulariser,
        opacity_reset_every: args.opacity_reset_every,
        percent_dense: args.percent_dense,
        time_split_fraction: args.time_split_fraction,
    };
    let request = FitRequest {
        views: args.views.clone(),
        downscale: args.downscale,
        strict: args.strict,
        allow_outside_images: args.allow_outside_images,
        frames: args.frames,
        fps: args.fps,
        init: args.init.clone(),
        settings,
        blend,
        out: args.out.clone(),
        log: args.log.clone(),
        threads: args.render.threads(),
        view: args.view,
    };
    Ok(request)
}

pub fn run(args: &FitArgs) -> Result<()> {
    let request = request(args)?;
    if !splat4d::fit::spread::is_leader() {
        // Spread over MPI ranks: rank 0 alone shows progress and the summary.
        return fit_dataset(&request, &mut splat4d::model::Silent).map(|_| ());
    }
    super::with_progress(|bars| fit_dataset(&request, bars))
}

#[cfg(test)]
mod tests {
    use super::*;
    use splat4d::tasks::fit_options::{FIT_OPTIONS, OptionValue};

    /// The flags of `fit` that are no option of [`FIT_OPTIONS`] (the Python package's
    /// `fit` options), each with why.
    const CLI_ONLY: &[(&str, &str)] = &[
        // Python's `fit(views, …)`: its first argument.
        ("views", "the dataset, given as the call's first argument"),
        // Python's `fit(…, out=…)`: an argument of its own, optional (the scene is returned).
        ("out", "the output scene, an argument of the call"),
        // Global to every command and to the process (`splat4d::io::memory::set_limit`):
        // an interpreter's fits are bounded by the memory the machine has.
        ("max_memory", "a bound on the whole process"),
        // clap's.
        ("help", "the help text"),
    ];

    /// Values of every option, as its flag's arguments (none: a switch given).
    const SAMPLES: &[(&str, &[&str])] = &[
        ("strict", &[]),
        ("init", &["random:30"]),
        ("blend", &["alpha"]),
        ("blend", &["additive"]),
        ("blend", &["auto"]),
        ("log", &["fit.jsonl"]),
        ("view", &[]),
        ("view", &["9000"]),
        ("downscale", &["2"]),
        ("allow_outside_images", &[]),
        ("frames", &["0:10:2"]),
        ("fps", &["30"]),
        ("dilation", &["0.5"]),
        ("cutoff", &["0.01"]),
        ("exp", &["std"]),
        ("threads", &["2"]),
        ("steps", &["5"]),
        ("batch", &["1"]),
        ("start_kernels", &["50"]),
        ("max_kernels", &["21"]),
        ("eval_every", &["1"]),
        ("seed", &["7"]),
        ("background", &["0.5,0.25,0"]),
        ("lr_mean", &["0.01"]),
        ("lr_time", &["0.02"]),
        ("lr_amplitude", &["0.03"]),
        ("lr_velocity", &["0.04"]),
        ("lr_scale", &["0.05"]),
        ("lr_final", &["0.5"]),
        ("freeze_mean", &[]),
        ("freeze_time", &[]),
        ("freeze_amplitude", &[]),
        ("densify_every", &["2"]),
        ("densify_from", &["0.5"]),
        ("densify_until", &["0.1"]),
        ("densify_threshold", &["1e9"]),
        ("max_growth", &["0.5"]),
        ("prune_below", &["0.2"]),
        ("mode", &["paper"]),
        ("fit_velocity", &[]),
        ("fit_scale", &[]),
        ("adaptive", &[]),
        ("min_improvement", &["0.1"]),
        ("merge_tolerance", &["0.2"]),
        ("min_scale", &["0.1"]),
        ("box", &["-1,-1,-1,1,1,1"]),
        ("time_range", &["0,1"]),
        ("init_scale", &["0.1,0.1,0.1,0.5"]),
        ("init_amplitude", &["-0.5"]),
        ("lr_background", &["0.01"]),
        ("freeze_background", &[]),
        ("sh", &["8"]),
        ("sh_raise_every", &["1"]),
        ("lr_opacity", &["0.2"]),
        ("lr_rotation", &["0.05"]),
        ("lr_acceleration", &["0.01"]),
        ("lr_angular_velocity", &["0.02"]),
        ("lr_sh", &["0.05"]),
        ("opacity_reset_every", &["2"]),
        ("percent_dense", &["0.5"]),
        ("time_split_fraction", &["0.01"]),
        ("coarse_to_fine", &["4"]),
        ("coarse_to_fine", &["off"]),
        ("early_stop", &["0.2"]),
        ("early_stop", &["off"]),
        ("window", &["64"]),
        ("window", &["off"]),
        ("loss", &["mse"]),
        ("loss", &["l1-dssim"]),
        ("dssim_weight", &["0.3"]),
        ("motion", &["auto"]),
        ("motion", &["off"]),
        ("motion_after_splits", &["2"]),
        ("prune_fraction", &["0.3"]),
        ("prune_rounds", &["2"]),
        ("opacity_regulariser", &["0.01"]),
        ("scale_regulariser", &["0.01"]),
    ];

    /// Values each flag and its option refuse.
    const REFUSED: &[(&str, &str)] = &[
        ("window", "8"),
        ("coarse_to_fine", "0"),
        ("early_stop", "2"),
        ("downscale", "0"),
        ("lr_mean", "nan"),
        ("background", "1,2"),
        ("blend", "both"),
        ("loss", "l2"),
        ("motion", "some"),
        ("steps", "-1"),
    ];

    fn flag(name: &str) -> String {
        format!("--{}", name.replace('_', "-"))
    }

    /// The request of `splat4d fit --views v --out o.json EXTRA`, or clap's or the
    /// request's refusal.
    fn parsed(extra: &[&str]) -> std::result::Result<FitRequest, String> {
        let mut argv = vec!["splat4d", "fit", "--views", "v", "--out", "o.json"];
        argv.extend(extra);
        let cli =
            <crate::cli::Cli as clap::Parser>::try_parse_from(argv).map_err(|e| e.to_string())?;
        match cli.command {
            Some(crate::cli::Command::Fit(args)) => request(&args).map_err(|e| e.to_string()),
            _ => unreachable!("a fit"),
        }
    }

    fn by_name() -> FitRequest {
        FitRequest::new("v".into(), "o.json".into())
    }

    #[test]
    fn every_flag_is_an_option_or_the_command_lines_own() {
        let flags = crate::cli::flags::command_flags(&["splat4d".into(), "fit".into()]);
        for flag in &flags {
            let name = flag.trim_start_matches("--").replace('-', "_");
            assert!(
                FIT_OPTIONS.contains(&name.as_str()) || CLI_ONLY.iter().any(|(n, _)| *n == name),
                "{flag} is no option of splat4d::tasks::fit_options::FIT_OPTIONS (the Python package's) and not in CLI_ONLY"
            );
        }
        for name in FIT_OPTIONS {
            assert!(
                flags.contains(&flag(name)),
                "option `{name}` is no flag of fit"
            );
        }
        // The global flags `fit` takes too (`--max-memory`).
        let global = crate::cli::flags::command_flags(&["splat4d".into()]);
        for (name, _) in CLI_ONLY {
            assert!(
                flags.contains(&flag(name)) || global.contains(&flag(name)),
                "CLI_ONLY's `{name}` is no flag of fit"
            );
        }
    }

    #[test]
    fn every_option_sets_what_its_flag_sets_and_refuses_what_it_refuses() {
        assert_eq!(parsed(&[]).unwrap(), by_name());
        for name in FIT_OPTIONS {
            assert!(
                SAMPLES.iter().any(|(n, _)| n == name),
                "`{name}` has no value in SAMPLES"
            );
        }
        for &(name, values) in SAMPLES {
            let flag = flag(name);
            let mut argv = vec![flag.as_str()];
            argv.extend(values);
            let value = match values {
                [] => OptionValue::Switch(true),
                [text] => OptionValue::Text(text),
                _ => unreachable!(),
            };
            let mut request = by_name();
            request.set(name, value).unwrap();
            assert_eq!(parsed(&argv).unwrap(), request, "{argv:?}");
            if !matches!(values, ["auto"]) {
                assert_ne!(request, by_name(), "{argv:?} changed nothing");
            }
        }
        for &(name, text) in REFUSED {
            let flag = flag(name);
            let error = by_name().set(name, OptionValue::Text(text)).unwrap_err();
            assert!(
                matches!(&error, splat4d::Error::Setting { fields, .. } if fields == &[name]),
                "{name} {text}: {error}"
            );
            assert!(parsed(&[&flag, text]).is_err(), "{flag} {text}");
        }
    }
}
