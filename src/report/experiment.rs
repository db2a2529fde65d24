//! The seed paper's experiment (§4–5, SPEC §7), end to end:
//!
//! 1. ground truth: the paper's point data as 30 000 small kernels ([`crate::scenes::toy`]);
//! 2. a multi-view dataset of it ([`crate::scenes::dataset`]): train (seen cameras × training
//!    times), val (seen cameras, times between), test (new cameras, times between);
//! 3. the 4D model: N kernels from a seeded random start, means and amplitudes fitted with
//!    Adam, σ fixed (the paper's setting);
//! 4. the baselines of paper §4.2 ([`super::methods`]): a static fit per training time, used
//!    nearest-in-time or linearly blended;
//! 5. metrics: PSNR per split, PSNR per time over a dense sweep from the test cameras,
//!    temporal roughness over that sweep (beside the ground truth's own), render time, fit
//!    time, parameter count;
//! 6. the σt ablation of paper §5.4;
//! 7. Eq. 1 volumes at t = 0, 0.5, 1 (paper Fig. 1, §5.2).

use std::time::Instant;

use crate::fit::additive::LearningRates;
use crate::fit::additive::{AdditiveFitOptions, FitMode};
use crate::fit::init::{SpaceTimeBox, box_from_cameras, random_scene};
use crate::fit::loss::{mse, psnr, ssim};
use crate::fit::plan::{DEFAULT_INIT_AMPLITUDE, DEFAULT_RATES};
use crate::fit::plan::{FitPlan, Init, PreparedFit};
use crate::fit::train::{StepRecord, fit};
use crate::model::Image;
use crate::model::Progress;
use crate::model::error::Result;
use crate::model::scene::Scene;
use crate::model::{Dataset, View};
use crate::render::{RenderContext, RenderOptions};
use crate::report::methods::{FrameModels, Method, Predictor, temporal_roughness};
use crate::scenes::dataset::{DatasetSpec, render_dataset};
use crate::scenes::toy::{POINTS_CUTOFF, points_scene};
use crate::volume::{Grid, Volume, evaluate_volume, scene_bounds};

/// Everything the experiment does, with the embedded defaults of `cargo run --release`.
#[derive(Clone, Debug, PartialEq)]
pub struct ExperimentConfig {
    /// Seed of the points, the cameras, the initial kernels and the batches.
    pub seed: u64,
    /// The dataset.
    pub dataset: DatasetSpec,
    /// Kernels of the 4D model.
    pub model_kernels: usize,
    /// Their fixed scales `[sx, sy, sz, st]`.
    pub model_scale: [f64; 4],
    /// Adam steps of the 4D fit.
    pub model_steps: usize,
    /// Kernels per frame of the frame-based baseline.
    pub frame_kernels: usize,
    /// Their fixed spatial σ.
    pub frame_sigma: f64,
    /// Adam steps per frame.
    pub frame_steps: usize,
    /// σt values of the ablation (4D model, `model_steps` each).
    pub ablation_sigma_t: Vec<f64>,
    /// Times in the dense evaluation sweep over the time range.
    pub sweep_times: usize,
    /// Volume grid cells per axis.
    pub volume_res: usize,
    /// Times of the volumes.
    pub volume_times: Vec<f64>,
    /// Adam steps of each adaptive fit (model size section).
    pub adaptive_steps: usize,
    /// The seed blob's dataset for the model size section.
    pub blob_dataset: DatasetSpec,
    /// The dataset of the three blobs of non-linear motion ([`crate::scenes::motion`]) for
    /// the model size section.
    pub motion_dataset: DatasetSpec,
}

impl Default for ExperimentConfig {
    fn default() -> Self {
        // The model size section's synthetic scenes (the seed blob, the three blobs).
        let synthetic = DatasetSpec {
            views: 12,
            times: 10,
            width: 64,
            height: 64,
            time_range: [0.0, 1.0],
            fov_y_degrees: 40.0,
            seed: crate::scenes::toy::DEFAULT_SEED,
            monocular: false,
        };
        ExperimentConfig {
            seed: crate::scenes::toy::DEFAULT_SEED,
            dataset: DatasetSpec {
                views: 8,
                times: 10,
                width: 96,
                height: 96,
                time_range: [0.0, 1.0],
                fov_y_degrees: 40.0,
                seed: crate::scenes::toy::DEFAULT_SEED,
                monocular: false,
            },
            model_kernels: 300,
            model_scale: [0.1, 0.1, 0.1, 0.1],
            model_steps: 3000,
            frame_kernels: 30,
            frame_sigma: 0.1,
            frame_steps: 400,
            ablation_sigma_t: vec![0.03, 0.06, 0.1, 0.2, 0.4],
            sweep_times: 41,
            volume_res: 64,
            volume_times: vec![0.0, 0.5, 1.0],
            adaptive_steps: crate::fit::plan::DEFAULT_STEPS,
            blob_dataset: synthetic,
            motion_dataset: synthetic,
        }
    }
}

impl ExperimentConfig {
    /// A small, fast configuration for smoke tests (`splat4d report --quick`): fewer views,
    /// steps and kernels.
    #[must_use]
    pub fn quick() -> Self {
        let mut config = ExperimentConfig::default();
        config.dataset.views = 4;
        config.dataset.times = 4;
        config.dataset.width = 32;
        config.dataset.height = 32;
        config.model_kernels = 20;
        config.model_steps = 60;
        config.frame_kernels = 5;
        config.frame_steps = 20;
        config.ablation_sigma_t = vec![0.05, 0.2];
        config.sweep_times = 9;
        config.volume_res = 16;
        config.adaptive_steps = 60;
        config.blob_dataset.views = 4;
        config.blob_dataset.times = 3;
        config.blob_dataset.width = 24;
        config.blob_dataset.height = 24;
        config.motion_dataset = config.blob_dataset;
        config
    }
}

/// One method's results.
#[derive(Clone, Debug, PartialEq)]
pub struct MethodResult {
    /// Which method.
    pub method: Method,
    /// Stored numbers ([`Predictor::parameter_count`]).
    pub parameters: usize,
    /// Seconds spent fitting.
    pub fit_seconds: f64,
    /// PSNR on train / val / test views, dB.
    pub psnr_splits: [f64; 3],
    /// Mean SSIM ([`crate::fit::loss::ssim`]) on train / val / test views.
    pub ssim_splits: [f64; 3],
    /// Temporal roughness over the sweep from the test cameras.
    pub roughness: f64,
    /// Milliseconds per rendered frame over the sweep.
    pub render_ms: f64,
    /// `(τ, PSNR over the test cameras at τ)` along the sweep.
    pub psnr_per_time: Vec<(f64, f64)>,
    /// Its renders from the first test camera at the sweep's times ([`ExperimentResults::gallery_times`]).
    pub gallery: Vec<Image>,
}

/// One row of the model size comparison: parameters against held-out PSNR.
#[derive(Clone, Debug, PartialEq)]
pub struct ModelSizeRow {
    /// Which dataset (the seed paper's points, or the continuous seed blob).
    pub dataset: String,
    /// Which model.
    pub method: Method,
    /// Kernels at the end of the fit (per frame summed over frames for the baseline).
    pub kernels: usize,
    /// Stored numbers.
    pub parameters: usize,
    /// PSNR on held-out views at held-out times (the test split), dB.
    pub heldout_psnr: f64,
    /// Mean SSIM on the same views.
    pub heldout_ssim: f64,
    /// Milliseconds per rendered test frame.
    pub render_ms: f64,
    /// Seconds spent fitting.
    pub fit_seconds: f64,
}

/// A fit of the model size section: method, mode, fitted scene and seconds.
type Fitted = (Method, FitMode, Scene, f64);

impl ModelSizeRow {
    /// The row of `fitted` on `dataset`, with its measured held-out PSNR and render time.
    fn of_fit(dataset: &str, fitted: &Fitted, heldout: Scores, render_ms: f64) -> Self {
        let (method, mode, scene, fit_seconds) = fitted;
        ModelSizeRow {
            dataset: dataset.into(),
            method: *method,
            kernels: scene.len(),
            parameters: mode.parameters_per_kernel() * scene.len(),
            heldout_psnr: heldout.psnr,
            heldout_ssim: heldout.ssim,
            render_ms,
            fit_seconds: *fit_seconds,
        }
    }
}

/// One row of the σt ablation.
#[derive(Clone, Debug, PartialEq)]
pub struct AblationRow {
    /// Temporal σ of every kernel.
    pub sigma_t: f64,
    /// PSNR on train / val / test views, dB.
    pub psnr_splits: [f64; 3],
    /// Mean SSIM on train / val / test views.
    pub ssim_splits: [f64; 3],
    /// Temporal roughness over the sweep.
    pub roughness: f64,
}

/// Which scene a volume is of.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VolumeOf {
    /// The ground truth, the seed paper's points.
    GroundTruth,
    /// The fitted 4D model.
    Model,
}

impl VolumeOf {
    /// Its name in the report.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            VolumeOf::GroundTruth => "ground truth (points)",
            VolumeOf::Model => "4D model",
        }
    }
}

/// One volume.
#[derive(Clone, Debug)]
pub struct VolumeResult {
    /// Which scene.
    pub of: VolumeOf,
    /// Time.
    pub tau: f64,
    /// The values.
    pub volume: Volume,
    /// Seconds to evaluate it.
    pub seconds: f64,
}

/// Everything measured.
#[derive(Clone, Debug)]
pub struct ExperimentResults {
    /// The configuration that ran.
    pub config: ExperimentConfig,
    /// Frames per split (train, val, test).
    pub split_sizes: [usize; 3],
    /// Ground truth's own temporal roughness over the sweep.
    pub ground_truth_roughness: f64,
    /// 4D, frame 3D, interpolation.
    pub methods: Vec<MethodResult>,
    /// The 4D fit, step by step.
    pub fit_log: Vec<StepRecord>,
    /// The σt ablation.
    pub ablation: Vec<AblationRow>,
    /// Parameters against held-out PSNR: fixed-count, adaptive and velocity 4D, frames.
    pub model_size: Vec<ModelSizeRow>,
    /// Volumes of the ground truth and of the 4D model.
    pub volumes: Vec<VolumeResult>,
    /// The fitted 4D scene.
    pub model: Scene,
    /// The sweep's times, at which [`MethodResult::gallery`] and `gallery_truth` are.
    pub gallery_times: Vec<f64>,
    /// The ground truth from the first test camera (held out) at `gallery_times`.
    pub gallery_truth: Vec<Image>,
    /// Seconds for the whole run.
    pub seconds: f64,
}

/// PSNR of a split (of its mean MSE) and its mean SSIM.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Scores {
    /// dB.
    pub psnr: f64,
    /// Mean over views of [`crate::fit::loss::ssim`].
    pub ssim: f64,
}

fn split_scores(
    method: &Predictor<'_>,
    views: &[View],
    options: &RenderOptions,
    context: &mut RenderContext,
) -> Result<Scores> {
    let mut image = Image::default();
    let (mut total, mut similarity) = (0.0, 0.0);
    for view in views {
        method.render(&view.camera, view.time, options, context, &mut image)?;
        total += mse(&image, &view.image);
        similarity += ssim(&image, &view.image);
    }
    let n = views.len().max(1) as f64;
    Ok(Scores {
        psnr: psnr(total / n),
        ssim: similarity / n,
    })
}

/// Scores of every split (train, val, test).
fn all_splits(
    method: &Predictor<'_>,
    dataset: &crate::model::Dataset,
    options: &RenderOptions,
    context: &mut RenderContext,
) -> Result<([f64; 3], [f64; 3])> {
    let (mut psnrs, mut ssims) = ([0.0; 3], [0.0; 3]);
    for (s, views) in [&dataset.train, &dataset.val, &dataset.test]
        .iter()
        .enumerate()
    {
        let scores = split_scores(method, views, options, context)?;
        psnrs[s] = scores.psnr;
        ssims[s] = scores.ssim;
    }
    Ok((psnrs, ssims))
}

/// The dense sweep: ground-truth renders from each test camera at each sweep time.
struct Sweep {
    times: Vec<f64>,
    /// `[camera][time]`.
    truth: Vec<Vec<Image>>,
}

/// What the sweep measures of one method.
struct SweepMetrics {
    /// `(τ, PSNR over the test cameras)`.
    psnr_per_time: Vec<(f64, f64)>,
    /// Mean temporal roughness over the test cameras.
    roughness: f64,
    /// Milliseconds per frame.
    render_ms: f64,
    /// The frames from the first camera.
    first_camera: Vec<Image>,
}

fn sweep_metrics(
    method: &Predictor<'_>,
    cameras: &[crate::Camera],
    sweep: &Sweep,
    options: &RenderOptions,
    context: &mut RenderContext,
) -> Result<SweepMetrics> {
    let mut per_time = vec![0.0; sweep.times.len()];
    let mut roughness = 0.0;
    let mut seconds = 0.0;
    let mut first_camera = Vec::new();
    for (c, camera) in cameras.iter().enumerate() {
        let mut frames = Vec::with_capacity(sweep.times.len());
        for (k, &tau) in sweep.times.iter().enumerate() {
            let mut image = Image::default();
            let start = Instant::now();
            method.render(camera, tau, options, context, &mut image)?;
            seconds += start.elapsed().as_secs_f64();
            per_time[k] += mse(&image, &sweep.truth[c][k]);
            frames.push(image);
        }
        roughness += temporal_roughness(&frames);
        if c == 0 {
            first_camera = frames;
        }
    }
    let n_cam = cameras.len() as f64;
    let frames = n_cam * sweep.times.len() as f64;
    let per_time = sweep
        .times
        .iter()
        .zip(per_time)
        .map(|(&t, m)| (t, psnr(m / n_cam)))
        .collect();
    Ok(SweepMetrics {
        psnr_per_time: per_time,
        roughness: roughness / n_cam,
        render_ms: 1e3 * seconds / frames,
        first_camera,
    })
}

fn fit_options(steps: usize, seed: u64, rates: LearningRates) -> AdditiveFitOptions {
    AdditiveFitOptions {
        steps,
        learning_rates: rates,
        eval_every: (steps / 30).max(1),
        seed,
        ..AdditiveFitOptions::default()
    }
}

/// The paper's setting: means and amplitudes, scales fixed, no background.
fn model_rates() -> LearningRates {
    LearningRates {
        background: 0.0,
        ..FitMode::Paper.learning_rates(DEFAULT_RATES)
    }
}

/// A static fit per frame: the paper's setting with the time means fixed too.
fn frame_rates() -> LearningRates {
    LearningRates {
        time: 0.0,
        ..model_rates()
    }
}

/// An adaptive fit as `splat4d fit` runs it without `--init`: one kernel at the centre of
/// the cameras' box, densify/prune/merge rounds, `mode`'s parameter groups. Returns the
/// scene and the seconds it took.
fn fit_adaptive(
    dataset: &Dataset,
    mode: FitMode,
    steps: usize,
    seed: u64,
    progress: &mut dyn Progress,
) -> Result<(Scene, f64)> {
    let plan = FitPlan {
        steps,
        seed,
        mode: Some(mode),
        eval_every: (steps / 30).max(1),
        ..FitPlan::default()
    };
    let PreparedFit {
        mut scene, options, ..
    } = plan.prepare(Init::Auto, &dataset.train)?;
    let start = Instant::now();
    fit(
        &mut scene,
        &dataset.train,
        &dataset.val,
        &options.training(),
        |_, _| progress.tick(),
    )?;
    Ok((scene, start.elapsed().as_secs_f64()))
}

/// The adaptive static and velocity fits of the model size section, with their names,
/// modes and seconds.
fn adaptive_fits(
    config: &ExperimentConfig,
    dataset: &Dataset,
    progress: &mut dyn Progress,
) -> Result<Vec<Fitted>> {
    let mut fits = Vec::new();
    for (method, mode) in [
        (Method::AdaptiveStatic, FitMode::Static),
        (Method::AdaptiveVelocity, FitMode::Velocity),
    ] {
        let (scene, seconds) =
            fit_adaptive(dataset, mode, config.adaptive_steps, config.seed, progress)?;
        fits.push((method, mode, scene, seconds));
    }
    Ok(fits)
}

/// Scores of `scene` on `views` and its milliseconds per frame there (renders and scores).
fn heldout_and_speed(
    scene: &Scene,
    views: &[View],
    options: &RenderOptions,
    context: &mut RenderContext,
) -> Result<(Scores, f64)> {
    let start = Instant::now();
    let scores = split_scores(&Predictor::Model4d(scene), views, options, context)?;
    let ms = 1e3 * start.elapsed().as_secs_f64() / views.len().max(1) as f64;
    Ok((scores, ms))
}

/// The model size comparison on the seed blob: the paper's fixed-count model against the
/// adaptive static and velocity fits.
fn synthetic_model_size(
    name: &str,
    truth: &Scene,
    spec: DatasetSpec,
    config: &ExperimentConfig,
    progress: &mut dyn Progress,
) -> Result<Vec<ModelSizeRow>> {
    let options = RenderOptions::default();
    let dataset = render_dataset(truth, &spec, &options, || {})?;
    let cameras: Vec<crate::Camera> = dataset.train.iter().map(|v| v.camera).collect();
    let bounds = box_from_cameras(&cameras, spec.time_range)?;
    let mut context = RenderContext::new();
    let mut rows = Vec::new();
    let mut fixed = random_scene(
        config.model_kernels,
        &bounds,
        Some(config.model_scale),
        DEFAULT_INIT_AMPLITUDE,
        config.seed,
    )?;
    let start = Instant::now();
    fit(
        &mut fixed,
        &dataset.train,
        &dataset.val,
        &fit_options(config.adaptive_steps, config.seed, model_rates()).training(),
        |_, _| progress.tick(),
    )?;
    let fixed_seconds = start.elapsed().as_secs_f64();
    let mut fits = vec![(Method::FixedCount, FitMode::Paper, fixed, fixed_seconds)];
    fits.extend(adaptive_fits(config, &dataset, progress)?);
    for fitted in &fits {
        let (heldout, render_ms) =
            heldout_and_speed(&fitted.2, &dataset.test, &options, &mut context)?;
        rows.push(ModelSizeRow::of_fit(name, fitted, heldout, render_ms));
    }
    Ok(rows)
}

fn fit_4d(
    config: &ExperimentConfig,
    dataset: &Dataset,
    bounds: &SpaceTimeBox,
    scale: [f64; 4],
    progress: &mut dyn Progress,
) -> Result<(Scene, Vec<StepRecord>, f64)> {
    let mut scene = random_scene(
        config.model_kernels,
        bounds,
        Some(scale),
        DEFAULT_INIT_AMPLITUDE,
        config.seed,
    )?;
    let start = Instant::now();
    let options = fit_options(config.model_steps, config.seed, model_rates());
    let log = fit(
        &mut scene,
        &dataset.train,
        &dataset.val,
        &options.training(),
        |_, _| progress.tick(),
    )?;
    Ok((scene, log, start.elapsed().as_secs_f64()))
}

/// Runs the whole experiment, phase by phase: dataset → sweep → fits → baselines →
/// evaluation → ablation → model size → volumes.
pub fn run_experiment(
    config: &ExperimentConfig,
    progress: &mut dyn Progress,
) -> Result<ExperimentResults> {
    let start = Instant::now();
    let truth = points_scene(config.seed);
    let truth_options = RenderOptions {
        cutoff: POINTS_CUTOFF,
        ..RenderOptions::default()
    };
    let spec = DatasetSpec {
        seed: config.seed,
        ..config.dataset
    };
    progress.start("dataset", crate::scenes::dataset::frame_count(&spec));
    let dataset = render_dataset(&truth, &spec, &truth_options, || progress.tick())?;
    let cameras: Vec<crate::Camera> = dataset.train.iter().map(|v| v.camera).collect();
    let bounds = box_from_cameras(&cameras, spec.time_range)?;
    let mut bench = Evaluation {
        dataset: &dataset,
        test_cameras: distinct_cameras(&dataset.test),
        sweep: Sweep {
            times: Vec::new(),
            truth: Vec::new(),
        },
        options: RenderOptions::default(),
        context: RenderContext::new(),
    };
    bench.sweep = bench.sweep_truth(&truth, &truth_options, &spec, config, progress)?;
    let ground_truth_roughness = bench
        .sweep
        .truth
        .iter()
        .map(|frames| temporal_roughness(frames))
        .sum::<f64>()
        / bench.test_cameras.len() as f64;
    progress.start("fit 4D", config.model_steps);
    let (model, fit_log, model_seconds) =
        fit_4d(config, &dataset, &bounds, config.model_scale, progress)?;
    let (frames, frame_seconds) = fit_frame_baselines(config, &dataset, &bounds, progress)?;
    let methods = bench.evaluate_methods(
        [
            (Method::Paper4d, Predictor::Model4d(&model), model_seconds),
            (
                Method::FrameNearest,
                Predictor::FrameNearest(&frames),
                frame_seconds,
            ),
            (
                Method::FrameInterpolation,
                Predictor::FrameInterpolation(&frames),
                frame_seconds,
            ),
        ],
        progress,
    )?;
    let ablation = bench.sigma_t_ablation(config, &bounds, progress)?;
    let model_size = bench.model_size(config, &methods, &model, &frames, progress)?;
    let volumes = volumes(config, &truth, &model, progress);
    Ok(ExperimentResults {
        config: config.clone(),
        split_sizes: [dataset.train.len(), dataset.val.len(), dataset.test.len()],
        ground_truth_roughness,
        methods,
        fit_log,
        ablation,
        model_size,
        volumes,
        model,
        gallery_times: bench.sweep.times.clone(),
        gallery_truth: bench.sweep.truth.first().cloned().unwrap_or_default(),
        seconds: start.elapsed().as_secs_f64(),
    })
}

/// The cameras of `views`, each once, in order.
fn distinct_cameras(views: &[View]) -> Vec<crate::Camera> {
    let mut seen: Vec<crate::Camera> = Vec::new();
    for view in views {
        if !seen.contains(&view.camera) {
            seen.push(view.camera);
        }
    }
    seen
}

/// Frame-based baselines: one static fit per training time, on that time's views; and the
/// seconds they took.
fn fit_frame_baselines(
    config: &ExperimentConfig,
    dataset: &Dataset,
    bounds: &SpaceTimeBox,
    progress: &mut dyn Progress,
) -> Result<(FrameModels, f64)> {
    let train_times = {
        let mut t: Vec<f64> = dataset.train.iter().map(|v| v.time).collect();
        t.sort_by(f64::total_cmp);
        t.dedup();
        t
    };
    progress.start("fit frames", train_times.len() * config.frame_steps);
    let frame_start = Instant::now();
    let mut scenes = Vec::new();
    for (k, &time) in train_times.iter().enumerate() {
        let views: Vec<View> = dataset
            .train
            .iter()
            .filter(|v| v.time == time)
            .cloned()
            .collect();
        let frame_box = SpaceTimeBox {
            time: [time, time],
            ..*bounds
        };
        let sigma = config.frame_sigma;
        // σt far above the time range: constant in time.
        let mut scene = random_scene(
            config.frame_kernels,
            &frame_box,
            Some([sigma, sigma, sigma, 1e3]),
            DEFAULT_INIT_AMPLITUDE,
            config.seed + 1 + k as u64,
        )?;
        fit(
            &mut scene,
            &views,
            &[],
            &fit_options(config.frame_steps, config.seed, frame_rates()).training(),
            |_, _| progress.tick(),
        )?;
        scenes.push(scene);
    }
    let frame_seconds = frame_start.elapsed().as_secs_f64();
    let frames = FrameModels {
        times: train_times,
        scenes,
    };
    Ok((frames, frame_seconds))
}

/// What every method is measured on: the dataset's splits and the dense sweep from the
/// test cameras, rendered with one context.
struct Evaluation<'a> {
    dataset: &'a Dataset,
    test_cameras: Vec<crate::Camera>,
    sweep: Sweep,
    options: RenderOptions,
    context: RenderContext,
}

impl Evaluation<'_> {
    /// The dense sweep of ground-truth renders.
    fn sweep_truth(
        &mut self,
        truth: &Scene,
        truth_options: &RenderOptions,
        spec: &DatasetSpec,
        config: &ExperimentConfig,
        progress: &mut dyn Progress,
    ) -> Result<Sweep> {
        let times = crate::scenes::paths::even_times(spec.time_range, config.sweep_times.max(2));
        progress.start("sweep", self.test_cameras.len() * times.len());
        let mut renders = Vec::new();
        for camera in &self.test_cameras {
            let mut row = Vec::new();
            for &tau in &times {
                self.context.render(truth, camera, tau, truth_options)?;
                row.push(self.context.image().clone());
                progress.tick();
            }
            renders.push(row);
        }
        Ok(Sweep {
            times,
            truth: renders,
        })
    }

    /// Every method's scores on the splits and the sweep.
    fn evaluate_methods(
        &mut self,
        methods_to_run: [(Method, Predictor<'_>, f64); 3],
        progress: &mut dyn Progress,
    ) -> Result<Vec<MethodResult>> {
        progress.start("evaluate", methods_to_run.len());
        let mut methods = Vec::new();
        for (id, method, fit_seconds) in methods_to_run {
            let (splits, ssims) =
                all_splits(&method, self.dataset, &self.options, &mut self.context)?;
            let SweepMetrics {
                psnr_per_time,
                roughness,
                render_ms,
                first_camera,
            } = self.sweep_metrics(&method)?;
            methods.push(MethodResult {
                method: id,
                parameters: method.parameter_count(),
                fit_seconds,
                psnr_splits: splits,
                ssim_splits: ssims,
                roughness,
                render_ms,
                psnr_per_time,
                gallery: first_camera,
            });
            progress.tick();
        }
        Ok(methods)
    }

    fn sweep_metrics(&mut self, method: &Predictor<'_>) -> Result<SweepMetrics> {
        sweep_metrics(
            method,
            &self.test_cameras,
            &self.sweep,
            &self.options,
            &mut self.context,
        )
    }

    /// σt ablation: the 4D fit again at each σt.
    fn sigma_t_ablation(
        &mut self,
        config: &ExperimentConfig,
        bounds: &SpaceTimeBox,
        progress: &mut dyn Progress,
    ) -> Result<Vec<AblationRow>> {
        let dataset = self.dataset;
        progress.start(
            "ablation",
            config.ablation_sigma_t.len() * config.model_steps,
        );
        let mut ablation = Vec::new();
        for &sigma_t in &config.ablation_sigma_t {
            let [sx, sy, sz, _] = config.model_scale;
            let (scene, _, _) = fit_4d(config, dataset, bounds, [sx, sy, sz, sigma_t], progress)?;
            let method = Predictor::Model4d(&scene);
            let (splits, ssims) = all_splits(&method, dataset, &self.options, &mut self.context)?;
            let roughness = self.sweep_metrics(&method)?.roughness;
            ablation.push(AblationRow {
                sigma_t,
                psnr_splits: splits,
                ssim_splits: ssims,
                roughness,
            });
        }

        Ok(ablation)
    }

    /// Model size: adaptive static and velocity fits against the fixed count and the frames,
    /// on the points, then the same on the continuous blob and the three blobs.
    fn model_size(
        &mut self,
        config: &ExperimentConfig,
        methods: &[MethodResult],
        model: &Scene,
        frames: &FrameModels,
        progress: &mut dyn Progress,
    ) -> Result<Vec<ModelSizeRow>> {
        let dataset = self.dataset;
        progress.start("model size", 8 * config.adaptive_steps);
        let mut model_size = Vec::new();
        for method in methods {
            // The paper's model and the per-frame scenes as rows of the section.
            let (row_method, kernels) = match method.method {
                Method::Paper4d => (Method::FixedCount, model.len()),
                Method::FrameNearest => (
                    Method::FrameBaseline,
                    frames.scenes.iter().map(Scene::len).sum(),
                ),
                _ => continue,
            };
            model_size.push(ModelSizeRow {
                dataset: "seed points".into(),
                method: row_method,
                kernels,
                parameters: method.parameters,
                heldout_psnr: method.psnr_splits[2],
                heldout_ssim: method.ssim_splits[2],
                render_ms: method.render_ms,
                fit_seconds: method.fit_seconds,
            });
        }
        for fitted in &adaptive_fits(config, dataset, progress)? {
            let method = Predictor::Model4d(&fitted.2);
            let heldout = split_scores(&method, &dataset.test, &self.options, &mut self.context)?;
            let render_ms = self.sweep_metrics(&method)?.render_ms;
            model_size.push(ModelSizeRow::of_fit(
                "seed points",
                fitted,
                heldout,
                render_ms,
            ));
        }
        model_size.extend(synthetic_model_size(
            "seed blob",
            &crate::scenes::toy::blob_scene(),
            config.blob_dataset,
            config,
            progress,
        )?);
        model_size.extend(synthetic_model_size(
            "three blobs",
            &crate::scenes::motion::three_blobs_scene(),
            config.motion_dataset,
            config,
            progress,
        )?);

        Ok(model_size)
    }
}

/// Volumes on one grid: the ground truth's and the model's.
fn volumes(
    config: &ExperimentConfig,
    truth: &Scene,
    model: &Scene,
    progress: &mut dyn Progress,
) -> Vec<VolumeResult> {
    progress.start("volumes", 2 * config.volume_times.len());
    let (min, max) =
        scene_bounds(truth, &config.volume_times, POINTS_CUTOFF).unwrap_or(([-0.5; 3], [1.5; 3]));
    let grid = Grid {
        min,
        max,
        res: config.volume_res.max(2),
    };
    let mut volumes = Vec::new();
    for (of, scene, cutoff) in [
        (VolumeOf::GroundTruth, truth, 1e-6),
        (VolumeOf::Model, model, 1e-6),
    ] {
        for &tau in &config.volume_times {
            let begin = Instant::now();
            let volume = evaluate_volume(scene, tau, &grid, cutoff);
            volumes.push(VolumeResult {
                of,
                tau,
                volume,
                seconds: begin.elapsed().as_secs_f64(),
            });
            progress.tick();
        }
    }

    volumes
}
