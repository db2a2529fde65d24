//! Fitting works (SPEC §6–7): from a perturbed start, Adam recovers the seed blob from
//! images of 8 views at 5 times, and generalises to unseen cameras at unseen times; the
//! adaptive velocity fit ends with the kernels a scene needs.

use splat4d::fit::additive::LearningRates;
use splat4d::fit::additive::{AdditiveFitOptions, FitMode};
use splat4d::fit::loss::psnr;
use splat4d::fit::plan::{FitPlan, Init, PreparedFit};
use splat4d::fit::train::{evaluate, fit};
use splat4d::scenes::dataset::{DatasetSpec, render_dataset};
use splat4d::{RenderContext, RenderOptions, Scene};

fn seed_blob() -> Scene {
    splat4d::io::scene_file::scene_from_json(include_str!("../../data/blob.json"), "data/blob.json")
        .unwrap()
}

#[test]
fn recovers_the_seed_blob_from_a_perturbed_start() {
    let truth = seed_blob();
    let spec = DatasetSpec {
        views: 8,
        times: 5,
        width: 64,
        height: 64,
        ..DatasetSpec::default()
    };
    let dataset = render_dataset(&truth, &spec, &RenderOptions::default(), || {}).unwrap();
    assert_eq!((dataset.train.len(), dataset.test.len()), (40, 8));

    let mut scene = truth.clone();
    scene.means[0] = [0.55, 0.46, 0.53, 0.5];
    scene.amplitudes[0] = [0.7, 1.3, 0.75];
    let options = AdditiveFitOptions {
        steps: 300,
        learning_rates: LearningRates {
            mean: 5e-3,
            time: 0.0,
            amplitude: 1e-2,
            velocity: 0.0,
            scale: 0.0,
            background: 0.0,
        },
        final_rate_factor: 0.01,
        ..AdditiveFitOptions::default()
    };
    let records = fit(
        &mut scene,
        &dataset.train,
        &dataset.val,
        &options.training(),
        |_, _| {},
    )
    .unwrap();
    let error: f64 = (0..3)
        .map(|c| (scene.means[0][c] - 0.5).abs())
        .fold(0.0, f64::max);
    let mut context = RenderContext::new();
    let test_psnr = psnr(evaluate(&scene, &dataset.test, &options.render, &mut context).unwrap());
    println!(
        "mean {:?}, amplitude {:?}, |Δmean|∞ = {error:e}, held-out views at held-out times: {test_psnr:.1} dB, first loss {:e}, last {:e}",
        scene.means[0],
        scene.amplitudes[0],
        records[0].train_loss,
        records.last().unwrap().train_loss
    );
    assert!(
        error <= 1e-3,
        "spatial mean {:?} is {error:e} from (0.5, 0.5, 0.5)",
        scene.means[0]
    );
    assert!(test_psnr >= 50.0, "held-out PSNR {test_psnr:.1} dB");
    assert_eq!(scene.means[0][3], 0.5, "time frozen");
    assert_eq!(scene.velocities[0], [1.0; 3], "velocity frozen");
    assert!(records.last().unwrap().heldout_psnr.is_some());
}

#[test]
fn a_diverging_fit_stops_with_an_error() {
    let truth = seed_blob();
    let spec = DatasetSpec {
        views: 2,
        times: 2,
        width: 16,
        height: 16,
        ..DatasetSpec::default()
    };
    let dataset = render_dataset(&truth, &spec, &RenderOptions::default(), || {}).unwrap();
    let mut scene = truth.clone();
    let options = AdditiveFitOptions {
        steps: 50,
        learning_rates: LearningRates {
            mean: 0.0,
            time: 0.0,
            amplitude: 1e300,
            velocity: 0.0,
            scale: 0.0,
            background: 0.0,
        },
        ..AdditiveFitOptions::default()
    };
    scene.amplitudes[0] = [0.5; 3];
    let error = fit(
        &mut scene,
        &dataset.train,
        &[],
        &options.training(),
        |_, _| {},
    )
    .unwrap_err()
    .to_string();
    assert!(
        error.contains("diverged") && error.contains("learning rates"),
        "{error}"
    );
}

/// An adaptive fit from one kernel at the centre of the cameras' box (what `splat4d fit`
/// does without `--init`): returns the fitted scene and its PSNR on held-out views at
/// held-out times.
fn adaptive_fit(truth: &Scene, mode: FitMode, steps: usize) -> (Scene, f64) {
    let spec = DatasetSpec {
        views: 10,
        times: 8,
        width: 48,
        height: 48,
        ..DatasetSpec::default()
    };
    let dataset = render_dataset(truth, &spec, &RenderOptions::default(), || {}).unwrap();
    let plan = FitPlan {
        steps,
        mode: Some(mode),
        ..FitPlan::default()
    };
    let PreparedFit {
        mut scene, options, ..
    } = plan.prepare(Init::Auto, &dataset.train).unwrap();
    let records = fit(
        &mut scene,
        &dataset.train,
        &dataset.val,
        &options.training(),
        |_, _| {},
    )
    .unwrap();
    assert_eq!(records.last().unwrap().kernels, scene.len());
    let mut context = RenderContext::new();
    let test_psnr = psnr(evaluate(&scene, &dataset.test, &options.render, &mut context).unwrap());
    (scene, test_psnr)
}

#[test]
fn velocity_fit_of_the_seed_blob_ends_with_few_kernels_above_50_db() {
    let (scene, test_psnr) = adaptive_fit(&seed_blob(), FitMode::Velocity, 3000);
    println!(
        "velocity mode: {} kernels, {test_psnr:.1} dB; velocities {:?}",
        scene.len(),
        scene.velocities
    );
    assert!(scene.len() <= 3, "{} kernels", scene.len());
    assert!(test_psnr >= 50.0, "held-out PSNR {test_psnr:.1} dB");
}

#[test]
fn the_kernel_count_follows_the_scene() {
    // Three blobs on three paths: the adaptive fit needs more kernels than for one.
    let mut kernels = seed_blob().kernels();
    for (k, velocity) in [[-1.0, 0.5, 0.0], [0.0, -1.0, 1.0]].into_iter().enumerate() {
        let mut blob = kernels[0];
        blob.mean = [0.2 + 0.3 * k as f64, 0.7, 0.3, 0.5];
        blob.velocity = velocity;
        blob.amplitude = [0.5, 0.8, 1.0];
        kernels.push(blob);
    }
    let three = Scene::from_kernels(&kernels, [0.0; 3], "<three blobs>").unwrap();
    let (scene, test_psnr) = adaptive_fit(&three, FitMode::Velocity, 3000);
    println!("three blobs: {} kernels, {test_psnr:.1} dB", scene.len());
    // Measured: 8 kernels at 33.1 dB (one blob: 2 kernels at 62.7 dB); the fixed-count
    // model of the report uses 300.
    assert!(
        (3..=20).contains(&scene.len()),
        "{} kernels for three blobs",
        scene.len()
    );
    assert!(test_psnr >= 30.0, "held-out PSNR {test_psnr:.1} dB");
}

/// A step's views run side by side, one per worker thread, and their gradients are added in
/// view order: an adaptive fit (densify and prune included) is the same bits on 1, 2 and 3
/// threads (a batch of 4: the last group of 3 short).
#[test]
fn an_adaptive_fit_is_the_same_bits_for_any_thread_count() {
    let truth = seed_blob();
    let spec = DatasetSpec {
        views: 6,
        times: 4,
        width: 32,
        height: 32,
        ..DatasetSpec::default()
    };
    let dataset = render_dataset(&truth, &spec, &RenderOptions::default(), || {}).unwrap();
    let plan = FitPlan {
        steps: 200,
        mode: Some(FitMode::Velocity),
        batch_size: 4,
        ..FitPlan::default()
    };
    let run = |threads: usize| {
        crate::common::on_threads(threads, || {
            let PreparedFit {
                mut scene, options, ..
            } = plan.prepare(Init::Auto, &dataset.train).unwrap();
            let records = fit(
                &mut scene,
                &dataset.train,
                &[],
                &options.training(),
                |_, _| {},
            )
            .unwrap();
            let losses: Vec<u64> = records.iter().map(|r| r.train_loss.to_bits()).collect();
            (splat4d::io::scene_file::scene_to_json(&scene), losses)
        })
    };
    let one = run(1);
    assert!(one.0.len() > 100);
    for threads in [2, 3] {
        assert!(run(threads) == one, "{threads} threads differ from one");
    }
}

/// A step's record counts the (pixel, kernel) pairs its batch's renders composited: with
/// every training view in the batch, the sum of what rendering each of them from the
/// step's start scene reports, under either loss (the MSE's fused render and backward,
/// and L1 + D-SSIM's render then backward).
#[test]
fn a_step_records_the_pairs_its_batch_rendered() {
    use splat4d::fit::ssim::L1Dssim;
    use splat4d::fit::train::TrainingLoss;
    let truth = seed_blob();
    let spec = DatasetSpec {
        views: 3,
        times: 2,
        width: 24,
        height: 20,
        ..DatasetSpec::default()
    };
    let dataset = render_dataset(&truth, &spec, &RenderOptions::default(), || {}).unwrap();
    let mut start = truth.clone();
    start.means[0] = [0.52, 0.47, 0.5, 0.5];
    let options = AdditiveFitOptions {
        steps: 1,
        batch_size: dataset.train.len(),
        ..AdditiveFitOptions::default()
    };
    let mut context = RenderContext::new();
    let expected: u64 = dataset
        .train
        .iter()
        .map(|view| {
            let stats = context
                .render(&start, &view.camera, view.time, &options.render)
                .unwrap();
            stats.pairs
        })
        .sum();
    assert!(expected > 0);
    let losses = [
        TrainingLoss::Mse,
        TrainingLoss::L1Dssim(L1Dssim { dssim_weight: 0.2 }),
    ];
    for loss in losses {
        let training = splat4d::fit::train::Training {
            loss,
            ..options.training()
        };
        let mut scene = start.clone();
        let records = fit(&mut scene, &dataset.train, &[], &training, |_, _| {}).unwrap();
        assert_eq!(records[0].pairs, expected, "{loss:?}");
    }
}
