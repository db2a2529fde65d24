//! Fitting works (SPEC §6–7): from a perturbed start, Adam recovers the seed blob from
//! images of 8 views at 5 times, and generalises to unseen cameras at unseen times.

use splat4d::fit::adam::LearningRates;
use splat4d::fit::dataset::{DatasetSpec, render_dataset};
use splat4d::fit::loss::psnr;
use splat4d::fit::train::{FitOptions, evaluate, fit};
use splat4d::{RenderContext, RenderOptions, Scene};

fn seed_blob() -> Scene {
    Scene::from_json_str(include_str!("../data/blob.json"), "data/blob.json").unwrap()
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
    let options = FitOptions {
        steps: 300,
        learning_rates: LearningRates {
            mean: 5e-3,
            time: 0.0,
            amplitude: 1e-2,
            velocity: 0.0,
            scale: 0.0,
        },
        final_rate_factor: 0.01,
        ..FitOptions::default()
    };
    let records = fit(&mut scene, &dataset.train, &dataset.val, &options, |_| {}).unwrap();
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
    let options = FitOptions {
        steps: 50,
        learning_rates: LearningRates {
            mean: 0.0,
            time: 0.0,
            amplitude: 1e300,
            velocity: 0.0,
            scale: 0.0,
        },
        ..FitOptions::default()
    };
    scene.amplitudes[0] = [0.5; 3];
    let error = fit(&mut scene, &dataset.train, &[], &options, |_| {})
        .unwrap_err()
        .to_string();
    assert!(
        error.contains("diverged") && error.contains("learning rates"),
        "{error}"
    );
}
