//! Motion beyond constant velocity (SPEC §9): kernels with an acceleration and an angular
//! velocity, in both blends, against the f64 twin (renders), central finite differences of
//! the twin (its analytic backward, every field, pairs frozen) and the fast backward against
//! the twin; files round-trip them.
//!
//! Tolerances are those of `gradients.rs` and `alpha.rs`: twin vs finite differences
//! `|Δ| ≤ 1e-7·scale + 1e-5·|fd|`, fast vs twin `|Δ| ≤ 1e-5·scale + 1e-5·|ref|`, `scale` the
//! field's largest |gradient| over the scene's kernels.

use crate::common::{
    FrozenDifferences, assert_within_bound, hard_random_scene, jittered_target, test_camera,
};
use splat4d::reference::{mse, reference_loss_and_gradients, render_reference};
use splat4d::render::DEFAULT_CUTOFF;
use splat4d::{Camera, Gradients, Image, Kernel, RenderContext, RenderOptions, Scene};

use rand::RngExt;
use splat4d::model::random::seeded_rng;

use splat4d::fit::alpha::{AlphaFitOptions, AlphaRates, MotionFit, alpha_bounds};
use splat4d::fit::defaults::DEFAULT_MOTION_TURNING;
use splat4d::fit::density::TurningRule;
use splat4d::fit::init::SpaceTimeBox;
use splat4d::fit::plan::DEFAULT_ALPHA;
use splat4d::fit::train::{Training, TrainingLoss, fit};
use splat4d::model::Dataset;
use splat4d::scenes::dataset::{DatasetSpec, render_dataset};

/// Fields checked per kernel: mean (4), velocity (3), acceleration (3), quaternion (4),
/// angular velocity (4), amplitude (3), scale (4).
const FIELDS: usize = 25;
const NAMES: [&str; FIELDS] = [
    "x", "y", "z", "t", "vx", "vy", "vz", "ax", "ay", "az", "qw", "qx", "qy", "qz", "ωw", "ωx",
    "ωy", "ωz", "r", "g", "b", "sx", "sy", "sz", "st",
];

fn field_mut(scene: &mut Scene, i: usize, p: usize) -> &mut f64 {
    match p {
        0..4 => &mut scene.means[i][p],
        4..7 => &mut scene.velocities[i][p - 4],
        7..10 => &mut scene.accelerations[i][p - 7],
        10..14 => &mut scene.rotations[i][p - 10],
        14..18 => &mut scene.angular_velocities[i][p - 14],
        18..21 => &mut scene.amplitudes[i][p - 18],
        _ => &mut scene.scales[i][p - 21],
    }
}

fn gradient(grads: &Gradients, i: usize, p: usize) -> f64 {
    match p {
        0..4 => grads.v_means[i][p],
        4..7 => grads.v_velocities[i][p - 4],
        7..10 => grads.v_accelerations[i][p - 7],
        10..14 => grads.v_rotations[i][p - 10],
        14..18 => grads.v_angular_velocities[i][p - 14],
        18..21 => grads.v_amplitudes[i][p - 18],
        _ => grads.v_scales[i][p - 21],
    }
}

/// Gives every kernel of `scene` a random acceleration and angular velocity (every third one
/// none, so that kernels with and without §9 fields mix), keeping each kernel's centre at
/// τ = 0.5 where it was.
fn with_motion(mut scene: Scene, seed: u64) -> Scene {
    let mut rng = seeded_rng(seed);
    let n = scene.len();
    scene.accelerations = vec![[0.0; 3]; n];
    scene.angular_velocities = vec![[0.0; 4]; n];
    for i in (0..n).filter(|i| i % 3 != 0) {
        let a: [f64; 3] = std::array::from_fn(|_| rng.random_range(-2.0..2.0));
        let omega: [f64; 4] = std::array::from_fn(|_| rng.random_range(-1.5..1.5));
        let dt = 0.5 - scene.means[i][3];
        for (mean, a) in scene.means[i].iter_mut().zip(a) {
            *mean -= 0.5 * a * dt * dt;
        }
        scene.accelerations[i] = a;
        scene.angular_velocities[i] = omega;
    }
    scene.validate("<motion>").unwrap();
    scene
}

/// Hard kernels: `q + ω d_t` nearly cancelling at τ (|q(τ)| ~ 1e-2 of |q|), a large
/// acceleration whose parabola passes through the view at τ, a stored quaternion of length
/// 3 that turns.
fn hard_motion_scene(camera: &Camera, tau: f64) -> Scene {
    let centre = crate::common::world_from_camera(camera, [0.0, 0.0, 3.0]);
    let mut kernels = Vec::new();
    let at = |offset: [f64; 3]| -> [f64; 3] { std::array::from_fn(|c| centre[c] + offset[c]) };
    // Nearly cancelling: p = q + ω d_t = 0.01 (0.6, 0.8, 0, 0) + a little across.
    let t = 0.2;
    let dt = tau - t;
    let q = [0.9, -0.3, 0.2, 0.25];
    let p = [0.006, 0.008, 0.001, -0.002];
    let mut cancelling = Kernel::new(
        {
            let m = at([0.1, -0.05, 0.0]);
            [m[0], m[1], m[2], t]
        },
        [0.25, 0.08, 0.12, 0.6],
        [0.8, 0.5, 0.3],
    );
    cancelling.rotation = q;
    cancelling.angular_velocity = std::array::from_fn(|k| (p[k] - q[k]) / dt);
    kernels.push(cancelling);
    // A large acceleration: a ball thrown through the view, at τ near its centre.
    let t = 0.9;
    let dt = tau - t;
    let a = [30.0, -60.0, 12.0];
    let v = [-4.0, 9.0, 1.0];
    let m = at([-0.2, 0.1, 0.3]);
    let mut thrown = Kernel::new(
        [
            m[0] - v[0] * dt - 0.5 * a[0] * dt * dt,
            m[1] - v[1] * dt - 0.5 * a[1] * dt * dt,
            m[2] - v[2] * dt - 0.5 * a[2] * dt * dt,
            t,
        ],
        [0.1, 0.15, 0.1, 0.5],
        [0.4, 0.9, 0.6],
    );
    thrown.velocity = v;
    thrown.acceleration = a;
    thrown.rotation = [0.3, 0.5, -0.6, 0.2];
    kernels.push(thrown);
    // A long stored quaternion, turning.
    let m = at([0.25, 0.2, -0.2]);
    let mut long = Kernel::new([m[0], m[1], m[2], 0.6], [0.2, 0.1, 0.05, 0.7], [0.5; 3]);
    long.rotation = [1.8, -1.2, 2.0, 0.9];
    long.angular_velocity = [0.5, 2.0, -1.0, 0.3];
    kernels.push(long);
    let scene = Scene::from_kernels(&kernels, [0.05, 0.0, 0.1], "<hard motion>").unwrap();
    assert_eq!(
        scene.rotations[0], q,
        "a turning kernel keeps its quaternion as written"
    );
    scene
}

/// Central differences of the twin's loss per kernel and field, each kernel's pairs frozen
/// at the unperturbed scene; `None` where a step changes whether the kernel is culled.
fn finite_differences(
    scene: &Scene,
    camera: &Camera,
    tau: f64,
    options: &RenderOptions,
    target: &[f32],
) -> Vec<[Option<f64>; FIELDS]> {
    let differences = FrozenDifferences::new(scene, (camera, tau, options), target);
    let mut out = Vec::new();
    for i in 0..scene.len() {
        let mut row = [None; FIELDS];
        let [sx, sy, sz, st] = scene.scales[i];
        let spatial = 1e-4 * sx.min(sy).min(sz).min(0.01);
        let dt = (tau - scene.means[i][3]).abs().clamp(1e-2, 1.0);
        let q = scene.rotations[i];
        let omega = scene.angular_velocity(i);
        let turned = (0..4)
            .map(|k| (q[k] + omega[k] * (tau - scene.means[i][3])).powi(2))
            .sum::<f64>()
            .sqrt();
        for (p, value) in row.iter_mut().enumerate() {
            let theta = *field_mut(&mut scene.clone(), i, p);
            let h = match p {
                0..3 => spatial,
                3 => 1e-5 * st.min(1.0).min(spatial / 1e-4),
                4..7 => spatial / dt,
                7..10 => spatial / (0.5 * dt * dt),
                10..14 => 1e-5 * turned,
                14..18 => 1e-5 * turned / dt,
                18..21 => 1e-6 * theta.abs().max(1.0),
                _ => 2e-4 * theta,
            };
            *value = differences.central(i, theta, h, |moved, v| *field_mut(moved, i, p) = v);
        }
        out.push(row);
    }
    out
}

/// Per field, the largest |value| over kernels.
fn field_scales(rows: &[[f64; FIELDS]]) -> [f64; FIELDS] {
    std::array::from_fn(|p| rows.iter().map(|r| r[p].abs()).fold(0.0, f64::max))
}

fn check_twin_against_finite_differences(
    what: &str,
    scene: &Scene,
    camera: &Camera,
    tau: f64,
    options: &RenderOptions,
) {
    let target = jittered_target(scene, camera, tau, options, 99);
    let (_, analytic) = reference_loss_and_gradients(scene, camera, tau, options, &target);
    let fd = finite_differences(scene, camera, tau, options, &target);
    let values: Vec<[f64; FIELDS]> = fd.iter().map(|r| r.map(|v| v.unwrap_or(0.0))).collect();
    let scale = field_scales(&values);
    let (mut checked, mut worst) = (0, 0.0_f64);
    for (i, row) in fd.iter().enumerate() {
        for (p, f) in row.iter().enumerate() {
            let Some(f) = *f else { continue };
            let a = gradient(&analytic, i, p);
            let bound = 1e-7 * scale[p] + 1e-5 * f.abs() + 1e-12;
            let delta = (a - f).abs();
            worst = worst.max(delta / bound);
            assert!(
                delta <= bound,
                "{what}: kernel {i} {}: twin {a} vs finite difference {f} (|Δ| = {delta:e}, bound {bound:e})",
                NAMES[p]
            );
            checked += 1;
        }
    }
    assert!(
        checked * 10 >= 9 * FIELDS * scene.len(),
        "{what}: {checked} checked"
    );
    for p in 7..18 {
        assert!(
            scale[p] > 0.0,
            "{what}: {} has a gradient somewhere",
            NAMES[p]
        );
    }
    println!(
        "{what}: {checked} values, twin vs finite differences worst at {worst:.3} of the bound"
    );
}

fn fast_gradients(
    scene: &Scene,
    camera: &Camera,
    tau: f64,
    options: &RenderOptions,
    target: &[f32],
) -> Gradients {
    let target = Image {
        width: camera.width,
        height: camera.height,
        pixels: target.to_vec(),
    };
    let mut grads = Gradients::for_scene(scene);
    splat4d::fit::loss::view_loss_and_gradients(
        &mut RenderContext::new(),
        scene,
        camera,
        tau,
        options,
        &target,
        &mut grads,
    )
    .unwrap();
    grads
}

fn check_fast_against_twin(
    what: &str,
    scene: &Scene,
    camera: &Camera,
    tau: f64,
    options: &RenderOptions,
) {
    let target = jittered_target(scene, camera, tau, options, 7);
    let (_, reference) = reference_loss_and_gradients(scene, camera, tau, options, &target);
    let fast = fast_gradients(scene, camera, tau, options, &target);
    assert_eq!(fast.v_accelerations.len(), scene.len());
    assert_eq!(fast.v_angular_velocities.len(), scene.len());
    let rows: Vec<[f64; FIELDS]> = (0..scene.len())
        .map(|i| std::array::from_fn(|p| gradient(&reference, i, p)))
        .collect();
    let scale = field_scales(&rows);
    let mut worst = 0.0_f64;
    for (i, r) in rows.iter().enumerate() {
        for p in 0..FIELDS {
            let f = gradient(&fast, i, p);
            let bound = 1e-5 * scale[p] + 1e-5 * r[p].abs() + 1e-15;
            let delta = (f - r[p]).abs();
            worst = worst.max(delta / bound);
            assert!(
                delta <= bound,
                "{what}: kernel {i} {}: fast {f} vs twin {} (|Δ| = {delta:e}, bound {bound:e})",
                NAMES[p],
                r[p]
            );
        }
    }
    println!("{what}: fast vs twin worst at {worst:.3} of the bound");
}

fn options(cutoff: f64) -> RenderOptions {
    RenderOptions {
        dilation: 0.3,
        cutoff,
        ..Default::default()
    }
}

#[test]
fn renders_of_accelerating_and_turning_kernels_match_the_twin() {
    let camera = test_camera(64, 48);
    for seed in 0..2 {
        let scene = with_motion(hard_random_scene(&camera, 300 + seed, 120), seed);
        for tau in [0.2, 0.5, 0.9] {
            for cutoff in [DEFAULT_CUTOFF, 0.0] {
                let fast = {
                    let mut context = RenderContext::new();
                    context
                        .render(&scene, &camera, tau, &options(cutoff))
                        .unwrap();
                    context.image().clone()
                };
                let reference = render_reference(&scene, &camera, tau, &options(cutoff));
                assert_within_bound(
                    &fast,
                    &reference,
                    cutoff,
                    &format!("seed {seed} τ {tau} cut-off {cutoff}"),
                );
            }
        }
    }
    let tau = 0.45;
    let hard = hard_motion_scene(&camera, tau);
    for cutoff in [DEFAULT_CUTOFF, 0.0] {
        let mut context = RenderContext::new();
        context
            .render(&hard, &camera, tau, &options(cutoff))
            .unwrap();
        let reference = render_reference(&hard, &camera, tau, &options(cutoff));
        assert_within_bound(context.image(), &reference, cutoff, "hard motion");
    }
}

#[test]
fn the_twins_gradients_of_every_field_match_finite_differences() {
    let camera = test_camera(48, 36);
    for seed in 0..2 {
        let scene = with_motion(hard_random_scene(&camera, 400 + seed, 30), seed);
        for cutoff in [DEFAULT_CUTOFF, 0.0] {
            check_twin_against_finite_differences(
                &format!("seed {seed} cut-off {cutoff}"),
                &scene,
                &camera,
                0.37,
                &options(cutoff),
            );
        }
    }
    let tau = 0.45;
    for cutoff in [DEFAULT_CUTOFF, 0.0] {
        check_twin_against_finite_differences(
            &format!("hard motion, cut-off {cutoff}"),
            &hard_motion_scene(&camera, tau),
            &camera,
            tau,
            &options(cutoff),
        );
    }
}

#[test]
fn fast_gradients_of_every_field_match_the_twin() {
    let camera = test_camera(96, 72);
    for seed in 0..2 {
        let scene = with_motion(hard_random_scene(&camera, 500 + seed, 150), seed);
        for cutoff in [DEFAULT_CUTOFF, 0.0] {
            check_fast_against_twin(
                &format!("seed {seed} cut-off {cutoff}"),
                &scene,
                &camera,
                0.6,
                &options(cutoff),
            );
        }
    }
    let tau = 0.45;
    check_fast_against_twin(
        "hard motion",
        &hard_motion_scene(&camera, tau),
        &camera,
        tau,
        &options(DEFAULT_CUTOFF),
    );
}

#[test]
fn a_kernel_whose_turned_quaternion_vanishes_is_culled_at_that_time() {
    let camera = test_camera(32, 24);
    let centre = crate::common::world_from_camera(&camera, [0.0, 0.0, 3.0]);
    let mut kernel = Kernel::new(
        [centre[0], centre[1], centre[2], 0.0],
        [0.3, 0.3, 0.3, 1.0],
        [1.0; 3],
    );
    kernel.rotation = [0.6, 0.8, 0.0, 0.0];
    kernel.angular_velocity = [-1.2, -1.6, 0.0, 0.0]; // q(0.5) = 0
    let scene = Scene::from_kernels(&[kernel], [0.0; 3], "<vanishing>").unwrap();
    let mut context = RenderContext::new();
    context.render(&scene, &camera, 0.5, &options(0.0)).unwrap();
    assert!(context.image().pixels.iter().all(|&v| v == 0.0));
    assert!(splat4d::reference::reference_slice(&scene, 0, 0.5, 0.0).is_none());
    context.render(&scene, &camera, 0.4, &options(0.0)).unwrap();
    assert!(context.image().pixels.iter().any(|&v| v > 0.1));
}

#[test]
fn motion_fields_round_trip_through_json_and_are_absent_without_them() {
    let camera = test_camera(32, 24);
    let scene = with_motion(hard_random_scene(&camera, 600, 12), 3);
    let json = splat4d::io::scene_file::scene_to_json(&scene);
    assert!(json.contains("\"acceleration\"") && json.contains("\"angular_velocity\""));
    let back = splat4d::io::scene_file::scene_from_json(&json, "<json>").unwrap();
    assert_eq!(back, scene);
    let plain = hard_random_scene(&camera, 600, 12);
    let json = splat4d::io::scene_file::scene_to_json(&plain);
    assert!(!json.contains("acceleration") && !json.contains("angular_velocity"));
    let back = splat4d::io::scene_file::scene_from_json(&json, "<json>").unwrap();
    assert!(back.accelerations.is_empty() && back.angular_velocities.is_empty());
    let bad = json.replacen(
        "\"velocity\"",
        "\"acceleration\": [1.0, 1e999, 0.0], \"velocity\"",
        1,
    );
    let message = splat4d::io::scene_file::scene_from_json(&bad, "bad.json")
        .unwrap_err()
        .to_string();
    assert!(message.contains("bad.json"), "{message}");
}

#[test]
fn motion_fields_round_trip_through_the_4d_ply() {
    let camera = test_camera(32, 24);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.ply");
    for scene in [
        with_motion(hard_random_scene(&camera, 700, 12), 4),
        hard_motion_scene(&camera, 0.45),
    ] {
        splat4d::io::ply::write_scene_ply(&scene, &path).unwrap();
        let back = splat4d::io::ply::read_scene_ply(&path).unwrap();
        assert_eq!(back, scene);
    }
    let plain = hard_random_scene(&camera, 700, 12);
    splat4d::io::ply::write_scene_ply(&plain, &path).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    assert!(!bytes.windows(5).any(|w| w == b"omega"));
}

/// Alpha scenes with §9 fields: the fast render against the twin (SPEC §8's allowances, the
/// bound of `alpha.rs`), and every field's fast gradient against central differences of the
/// twin with pairs, order and stops frozen (`alpha.rs`'s check for the §8 fields, the same
/// bound here for the acceleration and angular velocity).
#[test]
fn alpha_scenes_with_motion_match_the_twin_in_renders_and_every_gradient() {
    use crate::alpha::{alpha_error, alpha_scene, compare_with_the_twin, jittered_alpha_target};
    use splat4d::reference::composite::{composite_traced, render_reference_alpha};
    let camera = test_camera(67, 45);
    for (seed, sh_count) in [(1, 0), (2, 3)] {
        let scene = alpha_scene(
            with_motion(hard_random_scene(&camera, 800 + seed, 100), seed),
            seed,
            sh_count,
        );
        for tau in [0.2, 0.5] {
            for cutoff in [DEFAULT_CUTOFF, 0.0] {
                let mut context = RenderContext::new();
                context
                    .render(&scene, &camera, tau, &options(cutoff))
                    .unwrap();
                let reference = render_reference_alpha(&scene, &camera, tau, &options(cutoff));
                let (worst, excluded) = alpha_error(context.image(), &reference);
                assert!(worst <= 1e-6, "seed {seed} τ {tau}: max error {worst:e}");
                assert!(excluded * 50 <= reference.borderline.len());
            }
        }
    }
    let camera =
        Camera::look_at([0.2, -0.3, -3.5], [0.0; 3], [0.0, 1.0, 0.0], 45.0, 36, 28).unwrap();
    let tau = 0.45;
    for (seed, sh_count) in [(1, 0), (2, 3)] {
        let scene = alpha_scene(
            with_motion(crate::alpha::random_alpha_scene(seed, 24, 0), seed),
            seed,
            sh_count,
        );
        let target = jittered_alpha_target(&scene, &camera, tau);
        let grads = fast_gradients(&scene, &camera, tau, &RenderOptions::default(), &target);
        let what = format!("alpha seed {seed}");
        // Without ∂L/∂b: unrelated to §9, and held by alpha.rs on its own scenes.
        compare_with_the_twin(&what, &scene, (&camera, tau), &target, &grads, false);
        // The §9 fields, by the same frozen differences.
        let options = RenderOptions::default();
        let traced = render_reference_alpha(&scene, &camera, tau, &options);
        let order: Vec<usize> =
            splat4d::reference::colour::reference_alpha_kernels(&scene, &camera, tau, &options)
                .iter()
                .map(|k| k.kernel.index)
                .collect();
        let loss = |scene: &Scene| {
            let pixels = composite_traced(scene, &camera, tau, &options, &order, &traced.traces);
            mse(&pixels, &target)
        };
        let mut rows = Vec::new();
        for i in 0..scene.len() {
            let row: [f64; 7] = std::array::from_fn(|p| {
                let field = 7 + p + usize::from(p >= 3) * 4; // ax ay az, ωw ωx ωy ωz
                let theta = *field_mut(&mut scene.clone(), i, field);
                let h = 1e-6 * theta.abs().max(0.1);
                let mut plus = scene.clone();
                *field_mut(&mut plus, i, field) = theta + h;
                let mut minus = scene.clone();
                *field_mut(&mut minus, i, field) = theta - h;
                (loss(&plus) - loss(&minus)) / (2.0 * h)
            });
            rows.push(row);
        }
        for p in 0..7 {
            let field = 7 + p + usize::from(p >= 3) * 4;
            let scale = rows.iter().map(|r| r[p].abs()).fold(0.0, f64::max);
            assert!(scale > 0.0, "{what}: {} has a gradient", NAMES[field]);
            for (i, row) in rows.iter().enumerate() {
                let a = gradient(&grads, i, field);
                let bound = 2e-5 * scale + 2e-5 * row[p].abs() + 1e-12;
                assert!(
                    (a - row[p]).abs() <= bound,
                    "{what}: kernel {i} {}: fast {a} vs finite difference {} (bound {bound:e})",
                    NAMES[field],
                    row[p]
                );
            }
        }
    }
}

/// Fits `start` to `truth`'s renders (6 cameras × `times` times at 48×48) with only the
/// rates in `rates` (every other 0), no density rules, 800 steps decaying to 5 %; returns the
/// fitted scene and the first and last training losses.
fn fit_one_motion_group(
    truth: &Scene,
    mut start: Scene,
    times: usize,
    rates: AlphaRates,
) -> (Scene, f64, f64) {
    let spec = DatasetSpec {
        views: 6,
        times,
        width: 48,
        height: 48,
        ..DatasetSpec::default()
    };
    let dataset = render_dataset(truth, &spec, &RenderOptions::default(), || {}).unwrap();
    let bounds = alpha_bounds(&dataset.train, "<motion>").unwrap();
    let options = AlphaFitOptions {
        steps: 800,
        rates,
        sh_count: 0,
        eval_every: 0,
        final_rate_factor: 0.05,
        ..DEFAULT_ALPHA
    };
    let training = Training {
        density: None,
        ..options.training(&bounds)
    };
    let records = fit(&mut start, &dataset.train, &[], &training, |_, _| {}).unwrap();
    let (first, last) = (records[0].train_loss, records.last().unwrap().train_loss);
    (start, first, last)
}

/// Every rate 0.
const NO_RATES: AlphaRates = AlphaRates {
    mean: 0.0,
    time: 0.0,
    velocity: 0.0,
    acceleration: 0.0,
    angular_velocity: 0.0,
    scale: 0.0,
    rotation: 0.0,
    opacity: 0.0,
    colour: 0.0,
    sh: 0.0,
};

/// One opaque alpha kernel.
fn one_alpha_kernel(kernel: Kernel) -> Scene {
    Scene::from_kernels(&[kernel], [0.0; 3], "<motion>")
        .unwrap()
        .into_alpha(vec![0.9], 0, Vec::new(), "<motion>")
        .unwrap()
}

/// A ball thrown under gravity (SPEC §9): launched along x and z, falling along -y.
fn thrown_ball() -> Kernel {
    let mut ball = Kernel::new(
        [0.0, 0.1, 0.0, 0.5],
        [0.12, 0.12, 0.12, 10.0],
        [0.9, 0.5, 0.2],
    );
    ball.velocity = [0.4, 0.0, 0.1];
    ball.acceleration = [0.0, -1.6, 0.0];
    ball
}

/// A ball thrown under gravity (SPEC §9): fitted from a start that knows its launch but not
/// its fall, the acceleration group alone (every other rate 0, no density rules) finds the
/// fall: the fitted acceleration is within 3 % of the truth and the training loss falls
/// below a thousandth of its start.
#[test]
fn the_acceleration_group_finds_a_thrown_balls_fall() {
    let ball = thrown_ball();
    let truth = one_alpha_kernel(ball);
    let mut start = truth.clone();
    start.accelerations.clear();
    let rates = AlphaRates {
        acceleration: 2e-2,
        ..NO_RATES
    };
    let (fitted, first, last) = fit_one_motion_group(&truth, start, 5, rates);
    let found = fitted.acceleration(0);
    let error = (0..3)
        .map(|c| (found[c] - ball.acceleration[c]).powi(2))
        .sum::<f64>()
        .sqrt();
    assert!(
        error < 0.03 * 1.6,
        "found {found:?}, truth {:?}",
        ball.acceleration
    );
    assert!(last < 1e-3 * first, "loss {first:e} → {last:e}");
}

/// A stick spinning about the view axis (SPEC §9): fitted from a start that does not turn,
/// the angular-velocity group alone (every other rate 0, no density rules) finds the spin
/// within 5 %.
#[test]
fn the_angular_velocity_group_finds_a_spinning_sticks_turn() {
    let mut stick = Kernel::new(
        [0.0, 0.0, 0.0, 0.5],
        [0.35, 0.06, 0.06, 10.0],
        [0.9, 0.8, 0.2],
    );
    stick.angular_velocity = [0.0, 0.2, 0.3, 0.8];
    let truth = one_alpha_kernel(stick);
    let mut start = truth.clone();
    start.angular_velocities.clear();
    let rates = AlphaRates {
        angular_velocity: 1e-2,
        ..NO_RATES
    };
    let (fitted, _, _) = fit_one_motion_group(&truth, start, 7, rates);
    let found = fitted.angular_velocity(0);
    // ωw (along q = 1) only scales q(t): no image sees it, so it stays where it started.
    let error = (1..4)
        .map(|c| (found[c] - stick.angular_velocity[c]).powi(2))
        .sum::<f64>()
        .sqrt();
    let size = (1..4)
        .map(|c| stick.angular_velocity[c].powi(2))
        .sum::<f64>()
        .sqrt();
    assert!(
        error < 0.05 * size,
        "found {found:?}, truth {:?}",
        stick.angular_velocity
    );
}

/// The thrown ball and a still plate centred at `plate` (alpha, opacities 0.9), its
/// dataset (6 views, 5 times, 48×48) and the training cameras' box.
fn ball_and_plate(plate: [f64; 3]) -> (Scene, Dataset, SpaceTimeBox) {
    let plate = Kernel::new(
        [plate[0], plate[1], plate[2], 0.5],
        [0.15, 0.03, 0.15, 10.0],
        [0.2, 0.6, 0.3],
    );
    let truth = Scene::from_kernels(&[thrown_ball(), plate], [0.0; 3], "<motion>")
        .unwrap()
        .into_alpha(vec![0.9, 0.9], 0, Vec::new(), "<motion>")
        .unwrap();
    let spec = DatasetSpec {
        views: 6,
        times: 5,
        width: 48,
        height: 48,
        ..DatasetSpec::default()
    };
    let dataset = render_dataset(&truth, &spec, &RenderOptions::default(), || {}).unwrap();
    let bounds = alpha_bounds(&dataset.train, "<motion>").unwrap();
    (truth, dataset, bounds)
}

/// `truth` with its accelerations taken away, fitted by `options` to `dataset`'s training
/// views in `bounds`.
fn fitted_from_no_acceleration(
    truth: &Scene,
    dataset: &Dataset,
    bounds: &SpaceTimeBox,
    options: &AlphaFitOptions,
) -> Scene {
    let mut start = truth.clone();
    start.accelerations.clear();
    fit(
        &mut start,
        &dataset.train,
        &[],
        &options.training(bounds),
        |_, _| {},
    )
    .unwrap();
    start
}

/// A thrown ball beside a still plate, fitted with a density round in which every kernel
/// grows (`motion` where needed, after 0 splits in time; only the acceleration rate above
/// 0): the ball's kernel, which spans motion, gets fitted motion instead of a split in time
/// and finds a fall, while the still plate and its clones keep no acceleration at all. With
/// motion everywhere the plate's acceleration moves too.
#[test]
fn motion_where_needed_goes_only_to_kernels_that_keep_splitting_in_time() {
    let (truth, dataset, bounds) = ball_and_plate([0.3, -0.3, 0.0]);
    let fitted = |motion: MotionFit| {
        let options = AlphaFitOptions {
            steps: 400,
            rates: AlphaRates {
                acceleration: 2e-2,
                ..NO_RATES
            },
            sh_count: 0,
            eval_every: 0,
            final_rate_factor: 0.05,
            densify_every: 100,
            // One round, after step 100.
            densify_from: 0.0,
            densify_until: 0.3,
            densify_fraction: 1.0,
            densify_threshold: 0.0,
            opacity_reset_every: 0,
            prune_fraction: 0.0,
            motion,
            ..DEFAULT_ALPHA
        };
        fitted_from_no_acceleration(&truth, &dataset, &bounds, &options)
    };
    let still = |scene: &Scene, i: usize| scene.velocities[i] == [0.0; 3];
    // The splits in time alone: the turning trigger is the next test's.
    let auto = fitted(MotionFit::WhereNeeded {
        after_time_splits: 0,
        turning: None,
    });
    let balls: Vec<usize> = (0..auto.len()).filter(|&i| !still(&auto, i)).collect();
    assert_eq!(balls.len(), 1, "the ball's kernel was not split in time");
    assert!(
        auto.acceleration(balls[0])[1] < -0.5,
        "{:?}",
        auto.acceleration(balls[0])
    );
    assert!(auto.len() > 2, "the plate was not cloned");
    for i in (0..auto.len()).filter(|&i| still(&auto, i)) {
        assert_eq!(auto.acceleration(i), [0.0; 3], "still kernel {i}");
    }
    let everywhere = fitted(MotionFit::Everywhere);
    assert!(
        (0..everywhere.len())
            .any(|i| still(&everywhere, i) && everywhere.acceleration(i) != [0.0; 3]),
        "with motion everywhere, the plate's acceleration should move too"
    );
}

/// The thrown ball and a still plate apart from it, fitted with density rounds every 50
/// steps in which no kernel grows (only the SPEC §9 rates above 0, so the ball's one
/// straight path cannot settle; the MSE loss): `motion` where needed by the turning
/// trigger alone (never by splits in time) gives the ball's kernel fitted motion, and it
/// finds a fall, while the plate keeps exactly zero acceleration and angular velocity.
/// Without the trigger the ball gets none. (A plate that the ball crosses in the views, as
/// in the test above, feels the ball's misfit as a steady pull too, and moves.)
#[test]
fn motion_where_the_velocity_gradient_keeps_turning_goes_to_the_ball_not_the_plate() {
    let (truth, dataset, bounds) = ball_and_plate([1.2, -0.5, 0.0]);
    let fitted = |turning: Option<TurningRule>| {
        let options = AlphaFitOptions {
            steps: 400,
            rates: AlphaRates {
                acceleration: 2e-2,
                angular_velocity: 1e-3,
                ..NO_RATES
            },
            sh_count: 0,
            eval_every: 0,
            final_rate_factor: 0.05,
            densify_every: 50,
            // Rounds after steps 50, 100, …, 200, in which no kernel grows.
            densify_from: 0.0,
            densify_until: 0.5,
            densify_fraction: 0.0,
            opacity_reset_every: 0,
            prune_fraction: 0.0,
            loss: TrainingLoss::Mse,
            motion: MotionFit::WhereNeeded {
                after_time_splits: u32::MAX,
                turning,
            },
            ..DEFAULT_ALPHA
        };
        fitted_from_no_acceleration(&truth, &dataset, &bounds, &options)
    };
    let turning = fitted(Some(DEFAULT_MOTION_TURNING));
    assert_eq!(turning.len(), 2);
    assert!(
        turning.acceleration(0)[1] < -0.5,
        "the ball: {:?}",
        turning.acceleration(0)
    );
    assert_eq!(turning.acceleration(1), [0.0; 3], "the plate");
    assert_eq!(turning.angular_velocity(1), [0.0; 4], "the plate");
    let without = fitted(None);
    assert_eq!(
        without.acceleration(0),
        [0.0; 3],
        "the ball, without the trigger"
    );
}
