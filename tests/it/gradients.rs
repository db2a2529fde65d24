//! Gradients (SPEC §6) against three oracles:
//! 1. central finite differences of the f64 reference loss, pair set frozen, for every
//!    parameter group, on seeded random scenes and on hard cases;
//! 2. the f64 analytic backward of the reference, for the f32 fast backward;
//! 3. the independent float64 vectors in `tests/data/reference`.
//!
//! Tolerances, per parameter with `scale` its largest |gradient| over the scene's kernels:
//! analytic vs finite differences `|Δ| ≤ 1e-7·scale + 1e-5·|fd|`; fast (f32 per pixel) vs
//! f64 analytic `|Δ| ≤ 1e-5·scale + 1e-5·|ref|`. A failure names the case, the kernel, the
//! parameter and |Δ|.

use crate::common::{
    PARAM_NAMES, PARAMS, finite_difference_gradients, grad_of, hard_random_scene, jittered_target,
    reference_case, reference_case_dir, test_camera,
};
use splat4d::reference::reference_loss_and_gradients;
use splat4d::render::DEFAULT_CUTOFF;
use splat4d::simd::ExpMode;
use splat4d::{Camera, Gradients, Image, Kernel, RenderOptions, Scene};

/// Finite-difference tolerance: `|analytic - fd| ≤ ATOL_FD·scale + RTOL_FD·|fd|`, `scale` the
/// largest |fd| of the parameter over all kernels.
const RTOL_FD: f64 = 1e-5;
const ATOL_FD: f64 = 1e-7;

/// Fast (f32 per pixel) vs f64 analytic: `|Δ| ≤ ATOL_FAST·scale + RTOL_FAST·|ref|`.
const RTOL_FAST: f64 = 1e-5;
const ATOL_FAST: f64 = 1e-5;

fn fast_gradients(
    scene: &Scene,
    camera: &Camera,
    tau: f64,
    options: &RenderOptions,
    target: &[f32],
) -> (f64, Gradients) {
    let target = Image {
        width: camera.width,
        height: camera.height,
        pixels: target.to_vec(),
    };
    crate::common::fast_gradients(scene, camera, tau, options, &target)
}

/// Per parameter, the largest |value| over kernels.
fn scales<const N: usize>(rows: &[[f64; N]]) -> [f64; N] {
    std::array::from_fn(|p| rows.iter().map(|r| r[p].abs()).fold(0.0, f64::max))
}

fn check_against_finite_differences(
    what: &str,
    scene: &Scene,
    camera: &Camera,
    tau: f64,
    options: &RenderOptions,
) {
    let target = jittered_target(scene, camera, tau, options, 99);
    let (_, analytic) = reference_loss_and_gradients(scene, camera, tau, options, &target);
    let fd = finite_difference_gradients(scene, camera, tau, options, &target);
    let fd_values: Vec<[f64; PARAMS]> = fd.iter().map(|r| r.map(|v| v.unwrap_or(0.0))).collect();
    let scale = scales(&fd_values);
    let (mut checked, mut skipped, mut worst) = (0, 0, 0.0_f64);
    for (i, row) in fd.iter().enumerate() {
        let a = grad_of(&analytic, i);
        for p in 0..PARAMS {
            let Some(f) = row[p] else {
                skipped += 1;
                continue;
            };
            let bound = ATOL_FD * scale[p] + RTOL_FD * f.abs() + 1e-12;
            let delta = (a[p] - f).abs();
            worst = worst.max(delta / bound);
            assert!(
                delta <= bound,
                "{what}: kernel {i} parameter {}: analytic {} vs finite difference {f} (|Δ| = {delta:e}, bound {bound:e})",
                PARAM_NAMES[p],
                a[p]
            );
            checked += 1;
        }
    }
    assert!(
        skipped * 20 <= checked,
        "{what}: {skipped} parameters changed culling under a step, {checked} checked"
    );
    assert!(
        scale.iter().all(|&s| s > 0.0),
        "{what}: every parameter group has a non-zero gradient somewhere: {scale:?}"
    );
    println!("{what}: {checked} parameters, worst at {worst:.3} of the bound");
}

fn check_fast_against_reference(
    what: &str,
    scene: &Scene,
    camera: &Camera,
    tau: f64,
    options: &RenderOptions,
) {
    let target = jittered_target(scene, camera, tau, options, 7);
    let (ref_loss, reference) = reference_loss_and_gradients(scene, camera, tau, options, &target);
    let (fast_loss, fast) = fast_gradients(scene, camera, tau, options, &target);
    assert!(
        (fast_loss - ref_loss).abs() <= 1e-5 * ref_loss + 1e-12,
        "{what}: loss {fast_loss} vs {ref_loss}"
    );
    let rows: Vec<[f64; PARAMS]> = (0..scene.len()).map(|i| grad_of(&reference, i)).collect();
    let scale = scales(&rows);
    let mut worst = 0.0_f64;
    for (i, r) in rows.iter().enumerate() {
        let f = grad_of(&fast, i);
        for p in 0..PARAMS {
            let bound = ATOL_FAST * scale[p] + RTOL_FAST * r[p].abs() + 1e-15;
            let delta = (f[p] - r[p]).abs();
            worst = worst.max(delta / bound);
            assert!(
                delta <= bound,
                "{what}: kernel {i} parameter {}: fast {} vs f64 {} (|Δ| = {delta:e}, bound {bound:e})",
                PARAM_NAMES[p],
                f[p],
                r[p]
            );
        }
    }
    println!("{what}: fast vs f64 worst at {worst:.3} of the bound");
}

#[test]
fn reference_gradients_match_finite_differences_on_random_scenes() {
    let camera = test_camera(48, 36);
    for seed in 0..2 {
        let scene = hard_random_scene(&camera, 100 + seed, 40);
        for cutoff in [DEFAULT_CUTOFF, 0.0] {
            let options = RenderOptions {
                dilation: 0.3,
                cutoff,
                ..Default::default()
            };
            check_against_finite_differences(
                &format!("seed {seed} cut-off {cutoff}"),
                &scene,
                &camera,
                0.37,
                &options,
            );
        }
    }
}

#[test]
fn fast_gradients_match_the_f64_backward_on_random_scenes_with_either_exp() {
    let camera = test_camera(96, 72);
    for seed in 0..3 {
        let scene = hard_random_scene(&camera, 200 + seed, 200);
        for (cutoff, exp) in [
            (DEFAULT_CUTOFF, ExpMode::Std),
            (0.0, ExpMode::Std),
            (DEFAULT_CUTOFF, ExpMode::Poly),
        ] {
            let options = RenderOptions {
                dilation: 0.3,
                cutoff,
                exp,
            };
            check_fast_against_reference(
                &format!("seed {seed} cut-off {cutoff} exp {exp}"),
                &scene,
                &camera,
                0.6,
                &options,
            );
        }
    }
}

/// Small scenes that each stress one part of the chain rule.
fn hard_cases(camera: &Camera) -> Vec<(&'static str, Scene)> {
    // Every kernel moves and sits off τ = 0.5 in time, so that all parameter groups matter.
    let kernel = |mean: [f64; 4], scale: [f64; 4]| Kernel {
        velocity: [0.2, -0.1, 0.15],
        ..Kernel::new(
            [mean[0], mean[1], mean[2], mean[3] - 0.1 * scale[3]],
            scale,
            [0.9, -0.4, 0.6],
        )
    };
    let near_edges = {
        // Centres just inside and just beyond the clamp limits, on every side.
        let limits = camera.clamp_limits();
        let mut ks = Vec::new();
        for (k, factor) in [0.9, 1.05, 1.3].into_iter().enumerate() {
            let z = 3.0 + k as f64;
            for (u, v) in [
                (limits[1] * factor, 0.1),
                (-limits[0] * factor, -0.1),
                (0.05, limits[3] * factor),
                (0.0, -limits[2] * factor),
            ] {
                let world = crate::common::world_from_camera(camera, [u * z, v * z, z]);
                ks.push(kernel(
                    [world[0], world[1], world[2], 0.5],
                    [0.6, 0.3, 0.5, 1.0],
                ));
            }
        }
        ks
    };
    let rotated = |scale: [f64; 4], rotation: [f64; 4]| Kernel {
        rotation,
        ..kernel([0.1, -0.1, 0.2, 0.5], scale)
    };
    let s = std::f64::consts::FRAC_1_SQRT_2;
    vec![
        ("near the frustum clamp", near_edges),
        (
            "strongly anisotropic",
            vec![
                rotated([1.0, 0.001, 0.002, 1.0], [0.9, 0.3, -0.2, 0.24]),
                rotated([0.002, 0.8, 0.001, 1.0], [s, 0.0, s, 0.0]),
            ],
        ),
        (
            "sub-pixel",
            vec![
                kernel([0.0, 0.0, 0.0, 0.5], [0.002, 0.003, 0.002, 1.0]),
                kernel([0.05, 0.02, 0.0, 0.5], [0.004, 0.001, 0.001, 1.0]),
            ],
        ),
        (
            "tiny sigma_t",
            vec![
                kernel([0.0, 0.0, 0.0, 0.5 - 1.5e-3], [0.3, 0.3, 0.3, 1e-3]),
                kernel([0.2, 0.1, 0.0, 0.5 + 2e-6], [0.3, 0.2, 0.3, 1e-6]),
            ],
        ),
        (
            "velocity and rotation",
            vec![
                Kernel {
                    velocity: [0.8, -0.5, 0.3],
                    ..rotated([0.3, 0.1, 0.2, 0.4], [0.5, 0.5, 0.5, 0.5])
                },
                Kernel {
                    velocity: [-1.0, 0.2, 2.0],
                    mean: [0.3, 0.0, -0.2, 0.2],
                    ..rotated([0.2, 0.25, 0.1, 0.3], [0.8, 0.0, 0.6, 0.0])
                },
            ],
        ),
    ]
    .into_iter()
    .map(|(name, ks)| {
        (
            name,
            Scene::from_kernels(&ks, [0.05, 0.0, 0.1], name).unwrap(),
        )
    })
    .collect()
}

#[test]
fn hard_cases_match_finite_differences_and_the_f64_backward() {
    let camera = test_camera(64, 48);
    for (name, scene) in hard_cases(&camera) {
        for (cutoff, dilation) in [(DEFAULT_CUTOFF, 0.3), (0.0, 0.3), (DEFAULT_CUTOFF, 0.0)] {
            if name == "sub-pixel" && dilation == 0.0 {
                continue; // without dilation a sub-pixel kernel falls between pixel centres
            }
            let options = RenderOptions {
                dilation,
                cutoff,
                ..Default::default()
            };
            let what = format!("{name} (cut-off {cutoff}, dilation {dilation})");
            check_against_finite_differences(&what, &scene, &camera, 0.5, &options);
            check_fast_against_reference(&what, &scene, &camera, 0.5, &options);
        }
    }
}

#[test]
fn gradients_are_the_same_bits_for_any_thread_count() {
    let camera = test_camera(96, 72);
    let scene = hard_random_scene(&camera, 5, 300);
    let options = RenderOptions::default();
    let target = jittered_target(&scene, &camera, 0.4, &options, 3);
    let results: Vec<Gradients> = [1, 2, 5]
        .iter()
        .map(|&n| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .unwrap();
            pool.install(|| fast_gradients(&scene, &camera, 0.4, &options, &target).1)
        })
        .collect();
    assert!(
        results.iter().all(|g| g == &results[0]),
        "gradients depend on the thread count"
    );
}

#[derive(serde::Deserialize)]
struct ExpectedKernel {
    mean: [f64; 4],
    amplitude: [f64; 3],
    velocity: [f64; 3],
}

#[derive(serde::Deserialize)]
struct Expected {
    loss: f64,
    kernels: Vec<ExpectedKernel>,
}

#[test]
fn match_the_independent_gradient_vectors() {
    for name in ["toy_blob", "random_200"] {
        let dir = reference_case_dir(name);
        let (scene, camera, tau) = reference_case(name);
        let target =
            splat4d::io::image_file::load_image(&dir.join("grad_target.exr"), [0.0; 3]).unwrap();
        let expected: Expected =
            serde_json::from_str(&std::fs::read_to_string(dir.join("grad_expected.json")).unwrap())
                .unwrap();
        let options = RenderOptions::default();
        let (ref_loss, reference) =
            reference_loss_and_gradients(&scene, &camera, tau, &options, &target.pixels);
        let (fast_loss, fast) = fast_gradients(&scene, &camera, tau, &options, &target.pixels);
        assert!(
            (ref_loss - expected.loss).abs() <= 1e-9 * expected.loss,
            "{name}: f64 loss {ref_loss} vs {}",
            expected.loss
        );
        assert!(
            (fast_loss - expected.loss).abs() <= 1e-5 * expected.loss,
            "{name}: fast loss {fast_loss} vs {}",
            expected.loss
        );
        let rows: Vec<[f64; 10]> = expected
            .kernels
            .iter()
            .map(|k| {
                let (m, a, v) = (k.mean, k.amplitude, k.velocity);
                [m[0], m[1], m[2], m[3], a[0], a[1], a[2], v[0], v[1], v[2]]
            })
            .collect();
        assert_eq!(rows.len(), scene.len());
        let scale = scales(&rows);
        let (mut worst_ref, mut worst_fast) = (0.0_f64, 0.0_f64);
        for (i, e) in rows.iter().enumerate() {
            let (r, f) = (grad_of(&reference, i), grad_of(&fast, i));
            for p in 0..10 {
                let ref_bound = 1e-7 * scale[p] + 1e-6 * e[p].abs();
                let fast_bound = ATOL_FAST * scale[p] + RTOL_FAST * e[p].abs();
                worst_ref = worst_ref.max((r[p] - e[p]).abs() / ref_bound);
                worst_fast = worst_fast.max((f[p] - e[p]).abs() / fast_bound);
                assert!(
                    (r[p] - e[p]).abs() <= ref_bound,
                    "{name}: kernel {i} {}: f64 {} vs expected {}",
                    PARAM_NAMES[p],
                    r[p],
                    e[p]
                );
                assert!(
                    (f[p] - e[p]).abs() <= fast_bound,
                    "{name}: kernel {i} {}: fast {} vs expected {}",
                    PARAM_NAMES[p],
                    f[p],
                    e[p]
                );
            }
        }
        println!("{name}: f64 backward at {worst_ref:.3} of its bound, fast at {worst_fast:.3}");
    }
}

#[test]
fn background_gradient_matches_finite_differences_and_the_f64_backward() {
    use splat4d::reference::{mse, render_reference};
    let camera = test_camera(40, 30);
    for seed in 0..3 {
        let mut scene = hard_random_scene(&camera, seed, 60);
        scene.background = [0.1, -0.2, 0.3];
        let options = RenderOptions::default();
        let tau = 0.5;
        let target = crate::common::jittered_target(&scene, &camera, tau, &options, 5);
        let (_, analytic) = reference_loss_and_gradients(&scene, &camera, tau, &options, &target);
        let (_, fast) = fast_gradients(&scene, &camera, tau, &options, &target);
        for c in 0..3 {
            // The background moves no pair: central differences are exact up to rounding.
            let h = 1e-6;
            let loss_at = |delta: f64| {
                let mut moved = scene.clone();
                moved.background[c] += delta;
                mse(
                    &render_reference(&moved, &camera, tau, &options).pixels,
                    &target,
                )
            };
            let fd = (loss_at(h) - loss_at(-h)) / (2.0 * h);
            let (a, f) = (analytic.v_background[c], fast.v_background[c]);
            assert!(
                (a - fd).abs() <= 1e-7 * fd.abs().max(1e-3) + 1e-9,
                "seed {seed}, channel {c}: analytic {a} vs finite difference {fd}"
            );
            assert!(
                (f - a).abs() <= RTOL_FAST * a.abs() + 1e-7,
                "seed {seed}, channel {c}: fast {f} vs f64 {a}"
            );
        }
    }
}

/// A training step's render and backward in one pass (`RenderContext::render_and_backward`
/// with `view_mse_gradient`, as the fits run it) gives the same image, `∂L/∂C` and
/// gradients, bit for bit, as `render`, `view_mse_with_gradient` and `backward` one after
/// the other: additive and alpha scenes, with and without pixel weights.
#[test]
fn a_training_steps_render_and_backward_in_one_pass_are_the_same_bits() {
    use splat4d::RenderContext;
    use splat4d::fit::loss::{view_mse, view_mse_gradient, view_mse_with_gradient};
    use splat4d::scenes::synthetic::{bench_camera, bench_scene, varied_alpha_bench_scene};
    let camera = bench_camera(133, 71);
    let options = RenderOptions::default();
    for (name, scene) in [
        ("additive", bench_scene(1500, 3)),
        ("alpha", varied_alpha_bench_scene(1500, 3, 0.2)),
    ] {
        let mut context = RenderContext::new();
        context.render(&scene, &camera, 0.3, &options).unwrap();
        let pixels = (camera.width * camera.height) as usize;
        let weights: Vec<f32> = (0..pixels).map(|p| (p % 7) as f32 / 6.0).collect();
        for weights in [None, Some(weights)] {
            let view = splat4d::model::View {
                camera,
                time: 0.5,
                image: std::sync::Arc::new(context.image().clone()),
                name: "target".into(),
                weights,
            };
            let weighted = view.weights.is_some();
            // One after the other.
            let mut apart = RenderContext::new();
            apart
                .render_for_backward(&scene, &camera, 0.6, &options)
                .unwrap();
            let mut v_image = Vec::new();
            let loss = view_mse_with_gradient(apart.image(), &view, 0.5, &mut v_image);
            let mut grads = Gradients::for_scene(&scene);
            apart.backward(&scene, &camera, 0.6, &options, &v_image, &mut grads);
            // In one pass, in a context that rendered another frame before.
            let mut together = RenderContext::new();
            together.render(&scene, &camera, 0.1, &options).unwrap();
            let mut fused_v = vec![1.0; 5];
            let mut fused_grads = Gradients::for_scene(&scene);
            together
                .render_and_backward(
                    &scene,
                    &camera,
                    0.6,
                    &options,
                    &view_mse_gradient(&view, 0.5),
                    &mut fused_v,
                    &mut fused_grads,
                )
                .unwrap();
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            let case = format!("{name}, weighted {weighted}");
            assert_eq!(
                bits(&together.image().pixels),
                bits(&apart.image().pixels),
                "{case}"
            );
            assert_eq!(bits(&fused_v), bits(&v_image), "{case}");
            assert_eq!(
                view_mse(together.image(), &view).to_bits(),
                loss.to_bits(),
                "{case}"
            );
            assert!(loss > 0.0, "{case}");
            assert_eq!(format!("{fused_grads:?}"), format!("{grads:?}"), "{case}");
        }
    }
}

/// Lengths of the stored quaternions the rotation tests use: short, the issue's
/// `[0.9, 0.2, -0.3, 0.1]` (0.975), long, and unit.
const QUATERNION_NORMS: [f64; 4] = [0.5, 0.974_679_434_480_896_4, 3.0, 1.0];

/// Central finite differences of the reference MSE against `target` in each component of
/// kernel `i`'s quaternion as `scene` holds it (of any length: the reference normalises
/// it), with every kernel's pair set frozen at `scene`'s (SPEC §6).
fn quaternion_finite_differences(
    scene: &Scene,
    camera: &Camera,
    tau: f64,
    options: &RenderOptions,
    target: &[f32],
    i: usize,
) -> [f64; 4] {
    use splat4d::reference::{kernel_contribution, mse, reference_kernel};
    let mut base: Vec<f64> = (0..3 * camera.pixel_count())
        .map(|k| scene.background[k % 3])
        .collect();
    let mut own = None;
    for k in 0..scene.len() {
        if let Some(kernel) = reference_kernel(scene, k, camera, tau, options) {
            let (image, mask) = kernel_contribution(&kernel, camera, None);
            base.iter_mut().zip(&image).for_each(|(b, c)| *b += c);
            if k == i {
                own = Some((image, mask));
            }
        }
    }
    let (old, mask) = own.expect("the kernel is on screen");
    std::array::from_fn(|c| {
        let h = 1e-6 * scene.rotations[i][c].abs().max(0.1);
        let loss = |delta: f64| {
            let mut moved = scene.clone();
            moved.rotations[i][c] += delta;
            let kernel = reference_kernel(&moved, i, camera, tau, options).unwrap();
            let (new, _) = kernel_contribution(&kernel, camera, Some(&mask));
            let image: Vec<f64> = base
                .iter()
                .zip(&old)
                .zip(&new)
                .map(|((b, o), n)| b - o + n)
                .collect();
            mse(&image, target)
        };
        (loss(h) - loss(-h)) / (2.0 * h)
    })
}

/// Rotated, anisotropic kernels in front of the test camera, moving, with unit quaternions.
fn rotated_scene() -> Scene {
    let mut rng = splat4d::model::random::seeded_rng(17);
    let kernels: Vec<Kernel> = (0..8)
        .map(|k| {
            let x = -0.6 + 0.17 * k as f64;
            Kernel {
                rotation: splat4d::model::random::random_rotation(&mut rng),
                velocity: [0.3, -0.2, 0.1],
                ..Kernel::new(
                    [x, 0.1 * (k % 3) as f64 - 0.1, 0.2 * (k % 2) as f64, 0.45],
                    [0.35, 0.08, 0.15, 0.8],
                    [0.8, -0.3, 0.5],
                )
            }
        })
        .collect();
    Scene::from_kernels(&kernels, [0.05, 0.0, 0.1], "<rotated>").unwrap()
}

/// SPEC §8 (and §6 for the additive blend): the rotation gradient is that of the stored
/// quaternion through its normalisation, `(I - q̂ q̂ᵀ) ∂L/∂q̂ / |q|`. On quaternions of
/// lengths 0.5, 0.975, 3 and 1: the f64 backward's rotation gradient matches central
/// differences of the f64 forward in the stored components; the fast backward (of the
/// normalised scene, made the stored quaternions' by `rotations_as_stored`) matches them
/// too; and every other field's gradient is the same as for the unit quaternions.
#[test]
fn rotation_gradients_of_non_unit_quaternions_match_finite_differences_of_the_twin() {
    let camera = test_camera(48, 36);
    let options = RenderOptions::default();
    let tau = 0.5;
    let unit = rotated_scene();
    let norms: Vec<f64> = (0..unit.len())
        .map(|i| QUATERNION_NORMS[i % QUATERNION_NORMS.len()])
        .collect();
    let mut stored = unit.clone();
    for (q, &norm) in stored.rotations.iter_mut().zip(&norms) {
        *q = q.map(|v| v * norm);
    }
    let target = jittered_target(&unit, &camera, tau, &options, 3);
    let (_, of_stored) = reference_loss_and_gradients(&stored, &camera, tau, &options, &target);
    let (_, of_unit) = reference_loss_and_gradients(&unit, &camera, tau, &options, &target);
    let (_, mut fast) = fast_gradients(&unit, &camera, tau, &options, &target);
    fast.rotations_as_stored(&norms);
    let fd: Vec<[f64; 4]> = (0..unit.len())
        .map(|i| quaternion_finite_differences(&stored, &camera, tau, &options, &target, i))
        .collect();
    let scale = fd.iter().flatten().fold(0.0_f64, |m, v| m.max(v.abs()));
    assert!(scale > 0.0, "the rotations matter");
    let (mut worst, mut worst_fast) = (0.0_f64, 0.0_f64);
    for (i, f) in fd.iter().enumerate() {
        for (c, &f_c) in f.iter().enumerate() {
            let (analytic, quick) = (of_stored.v_rotations[i][c], fast.v_rotations[i][c]);
            let bound = ATOL_FD * scale + RTOL_FD * f_c.abs() + 1e-12;
            worst = worst.max((analytic - f_c).abs() / bound);
            assert!(
                (analytic - f_c).abs() <= bound,
                "kernel {i} (|q| = {}) q[{c}]: f64 backward {analytic} vs finite difference {} (bound {bound:e})",
                norms[i],
                f_c
            );
            let fast_bound = ATOL_FAST * scale + RTOL_FAST * f_c.abs();
            worst_fast = worst_fast.max((quick - f_c).abs() / fast_bound);
            assert!(
                (quick - f_c).abs() <= fast_bound,
                "kernel {i} (|q| = {}) q[{c}]: fast {quick} vs finite difference {} (bound {fast_bound:e})",
                norms[i],
                f_c
            );
            // The stored quaternion's gradient is the unit one's over |q|.
            let expected = of_unit.v_rotations[i][c] / norms[i];
            assert!(
                (analytic - expected).abs() <= 1e-9 * scale,
                "kernel {i}: {analytic} vs {expected}"
            );
        }
        // Every other field sees the same rotation.
        let (a, b) = (grad_of(&of_stored, i), grad_of(&of_unit, i));
        for p in 0..PARAMS {
            assert!(
                (a[p] - b[p]).abs() <= 1e-9 * b[p].abs() + 1e-12,
                "kernel {i} {}: {} with |q| = {} vs {} with the unit quaternion",
                PARAM_NAMES[p],
                a[p],
                norms[i],
                b[p]
            );
        }
    }
    println!(
        "stored quaternions: f64 backward at {worst:.3} of its bound, fast at {worst_fast:.3}"
    );
}

/// The backward's rotation gradient of a quaternion of any length is that of its unit
/// quaternion over the length (library level: `rotation_gradient` of `k q`).
#[test]
fn the_rotation_gradient_carries_the_normalisations_factor() {
    use splat4d::backward::slice::rotation_gradient;
    use splat4d::slice::rotation_matrix;
    let unit = {
        let q = [0.9, 0.2, -0.3, 0.1];
        let norm = q.iter().map(|v: &f64| v * v).sum::<f64>().sqrt();
        q.map(|v| v / norm)
    };
    let scale = [0.3, 0.1, 0.2, 1.0];
    let r = rotation_matrix(unit);
    let v_sigma = [[0.3, -0.1, 0.2], [-0.1, 0.5, 0.05], [0.2, 0.05, -0.4]];
    let of_unit = rotation_gradient(unit, scale, &r, &v_sigma);
    assert!(of_unit.iter().any(|&v| v.abs() > 1e-3), "{of_unit:?}");
    for k in [0.5, 0.974_679_434_480_896_4, 3.0] {
        let of_stored = rotation_gradient(unit.map(|v| v * k), scale, &r, &v_sigma);
        for c in 0..4 {
            assert!(
                (of_stored[c] - of_unit[c] / k).abs() <= 1e-14,
                "|q| = {k}, q[{c}]: {} vs {}",
                of_stored[c],
                of_unit[c] / k
            );
        }
    }
}

/// `splat4d grad` of an alpha scene whose file stores quaternions of lengths 0.5, 0.975
/// (the issue's `[0.9, 0.2, -0.3, 0.1]`), 3 and 1 writes, for every field, central
/// differences of the f64 twin evaluated at the stored numbers: the rotation is the stored
/// quaternion's (a factor 1/|q| from the unit one's), every other field is unchanged.
#[test]
fn grad_of_an_alpha_scene_with_non_unit_quaternions_matches_the_twin_in_every_field() {
    use crate::alpha::{compare_with_the_twin, jittered_alpha_target, random_alpha_scene};
    use crate::common::{splat4d, stderr};
    let dir = tempfile::tempdir().unwrap();
    let camera =
        Camera::look_at([0.2, -0.3, -3.5], [0.0; 3], [0.0, 1.0, 0.0], 45.0, 36, 28).unwrap();
    let tau = 0.45;
    let mut unit = random_alpha_scene(6, 12, 3);
    unit.rotations[1] = {
        let q = [0.9, 0.2, -0.3, 0.1];
        let norm = q.iter().map(|v: &f64| v * v).sum::<f64>().sqrt();
        q.map(|v| v / norm)
    };
    // The file: the same scene with each quaternion stretched to its length.
    let mut file: serde_json::Value =
        serde_json::from_str(&splat4d::io::scene_file::scene_to_json(&unit)).unwrap();
    let mut stored = unit.clone();
    for (i, kernel) in file["kernels"]
        .as_array_mut()
        .unwrap()
        .iter_mut()
        .enumerate()
    {
        let norm = QUATERNION_NORMS[i % QUATERNION_NORMS.len()];
        stored.rotations[i] = if i == 1 {
            [0.9, 0.2, -0.3, 0.1]
        } else {
            unit.rotations[i].map(|v| v * norm)
        };
        kernel["rotation"] = serde_json::json!(stored.rotations[i]);
    }
    std::fs::write(dir.path().join("s.json"), file.to_string()).unwrap();
    splat4d::io::camera_file::save_camera(&camera, &dir.path().join("c.json")).unwrap();
    let target = jittered_alpha_target(&unit, &camera, tau);
    let image = Image {
        width: camera.width,
        height: camera.height,
        pixels: target.clone(),
    };
    splat4d::io::image_file::save_image(
        &image,
        &dir.path().join("t.exr"),
        splat4d::io::image_file::BitDepth::Sixteen,
    )
    .unwrap();
    let output = splat4d(
        &[
            "grad", "--scene", "s.json", "--camera", "c.json", "--time", "0.45", "--target",
            "t.exr", "--out", "g.json",
        ],
        dir.path(),
    );
    assert!(output.status.success(), "{}", stderr(&output));
    let text = std::fs::read_to_string(dir.path().join("g.json")).unwrap();
    let (_, grads) = splat4d::io::gradients_file::gradients_from_json(&text, "g.json").unwrap();
    let read_back = splat4d::io::image_file::load_image(&dir.path().join("t.exr"), [0.0; 3])
        .unwrap()
        .pixels;
    assert_eq!(read_back, target, "the target reads back exactly");
    let worst = compare_with_the_twin(
        "grad, stored quaternions",
        &stored,
        (&camera, tau),
        &target,
        &grads,
        false,
    );
    assert!(worst <= 1.0);
}
