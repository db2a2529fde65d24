//! The alpha blend (SPEC §8): the fast forward against its f64 twin on random and hard
//! scenes, the same bits on every path and thread count, files that round-trip.

use rand::RngExt;
use splat4d::model::random::seeded_rng;
use splat4d::reference::composite::{ReferenceAlphaImage, render_reference_alpha};
use splat4d::render::{RenderContext, RenderOptions};
use splat4d::{Blend, Camera, Image, Kernel, Scene};

use crate::common::{hard_random_scene, test_camera};

/// `scene` made an alpha scene: seeded opacities in (0, 1] (some at 1, so that the 0.99
/// clamp binds), amplitudes as colours, `sh_count` SH triplets of either sign.
pub fn alpha_scene(scene: Scene, seed: u64, sh_count: usize) -> Scene {
    let mut rng = seeded_rng(seed);
    let n = scene.len();
    let opacities = (0..n)
        .map(|_| {
            if rng.random_range(0.0..1.0) < 0.2 {
                1.0
            } else {
                rng.random_range(0.02..1.0)
            }
        })
        .collect();
    let sh = (0..n * sh_count)
        .map(|_| std::array::from_fn(|_| rng.random_range(-0.5..0.5)))
        .collect();
    scene
        .into_alpha(opacities, sh_count, sh, "<alpha scene>")
        .unwrap()
}

/// Pixels where the fast image and the twin may differ by SPEC §8's allowances: a pair on
/// the cut-off's edge, or a transmittance within `STOP_BAND` of the stop. The fast loop
/// forms `q` and `G` in f32 (relative error of `α` up to ~1e-6), which moves `T'` by up to
/// `α/(1 - α) · 1e-6 ≤ 1e-4` relative: the band the fast loop is held to.
const STOP_BAND: f64 = 2e-4;

/// Largest `|fast - ref|` over the pixels outside the allowances, and how many were
/// excluded.
pub fn alpha_error(fast: &Image, reference: &ReferenceAlphaImage) -> (f64, usize) {
    let mut worst = 0.0_f64;
    let mut excluded = 0;
    for p in 0..reference.borderline.len() {
        if reference.borderline[p] || reference.stop_margin[p] <= STOP_BAND {
            excluded += 1;
            continue;
        }
        for c in 0..3 {
            let d = (f64::from(fast.pixels[3 * p + c]) - reference.pixels[3 * p + c]).abs();
            worst = worst.max(d);
        }
    }
    (worst, excluded)
}

/// Absolute tolerance on an alpha pixel (colours and backgrounds of order 1): f32 `q`, `G`
/// and colour, f64 compositing (measured: at most 1.9e-7 on these scenes).
const ALPHA_TOLERANCE: f64 = 1e-6;

fn render(scene: &Scene, camera: &Camera, tau: f64, options: &RenderOptions) -> Image {
    let mut context = RenderContext::new();
    context.render(scene, camera, tau, options).unwrap();
    context.image().clone()
}

fn check_against_twin(scene: &Scene, camera: &Camera, tau: f64, what: &str) {
    for cutoff in [1.0 / 255.0, 0.0] {
        let options = RenderOptions {
            cutoff,
            ..RenderOptions::default()
        };
        let fast = render(scene, camera, tau, &options);
        let reference = render_reference_alpha(scene, camera, tau, &options);
        let (worst, excluded) = alpha_error(&fast, &reference);
        let pixels = reference.borderline.len();
        eprintln!(
            "{what}, cut-off {cutoff}: max error {worst:.2e}, {excluded} of {pixels} pixels on an edge"
        );
        assert!(
            worst <= ALPHA_TOLERANCE,
            "{what}, cut-off {cutoff}: max error {worst:.3e}"
        );
        assert!(
            excluded * 50 <= pixels,
            "{what}, cut-off {cutoff}: {excluded} of {pixels} pixels on an edge"
        );
        assert!(reference.pairs > 0, "{what}: the scene reaches the image");
    }
}

#[test]
fn random_hard_alpha_scenes_match_the_f64_twin() {
    let camera = test_camera(67, 45);
    for (seed, sh_count) in [(1, 0), (2, 3), (3, 8), (4, 15)] {
        let scene = alpha_scene(hard_random_scene(&camera, seed, 150), seed, sh_count);
        for tau in [0.2, 0.5] {
            check_against_twin(&scene, &camera, tau, &format!("seed {seed}, τ {tau}"));
        }
    }
}

/// A stack of `layers` opaque kernels facing the camera, one behind the other, plus a
/// kernel crossing them in depth over time.
fn stack_scene(layers: usize, opacity: f64) -> Scene {
    let mut kernels: Vec<Kernel> = (0..layers)
        .map(|k| {
            let z = 0.5 * k as f64;
            let mut kernel = Kernel::new(
                [0.05 * k as f64, 0.0, z, 0.5],
                [0.6, 0.5, 0.05, 1e30],
                [0.2 + 0.1 * (k % 5) as f64, 0.9 - 0.1 * (k % 7) as f64, 0.5],
            );
            kernel.rotation = [0.96, 0.1, 0.2, 0.1];
            kernel
        })
        .collect();
    let mut crossing = Kernel::new([0.2, 0.1, -1.0, 0.0], [0.3, 0.3, 0.3, 2.0], [1.0, 0.2, 0.1]);
    crossing.velocity = [0.0, 0.0, 3.0];
    kernels.push(crossing);
    let n = kernels.len();
    Scene::from_kernels(&kernels, [0.3, 0.2, 0.1], "<stack>")
        .unwrap()
        .into_alpha(vec![opacity; n], 0, Vec::new(), "<stack>")
        .unwrap()
}

#[test]
fn stacks_that_stop_pixels_and_kernels_crossing_in_depth_match_the_twin() {
    let camera =
        Camera::look_at([0.0, 0.0, -4.0], [0.0; 3], [0.0, 1.0, 0.0], 40.0, 48, 40).unwrap();
    // Opacity 1: the 0.99 clamp binds and two layers stop a pixel (T' = 1e-4 < T_stop).
    for (opacity, tau) in [(1.0, 0.0), (1.0, 0.7), (0.6, 0.3), (0.97, 1.0)] {
        let scene = stack_scene(12, opacity);
        let reference = render_reference_alpha(&scene, &camera, tau, &RenderOptions::default());
        let stopped = reference
            .traces
            .iter()
            .filter(|t| t.stopped_by.is_some())
            .count();
        if opacity == 1.0 {
            assert!(stopped > 50, "pixels stop under opaque layers ({stopped})");
        }
        check_against_twin(
            &scene,
            &camera,
            tau,
            &format!("stack o = {opacity}, τ {tau}"),
        );
    }
}

#[test]
fn equal_depths_composite_in_kernel_order() {
    let camera =
        Camera::look_at([0.0, 0.0, -3.0], [0.0; 3], [0.0, 1.0, 0.0], 40.0, 32, 32).unwrap();
    let red = Kernel::new([0.0, 0.0, 0.0, 0.0], [0.4, 0.4, 0.4, 1.0], [1.0, 0.0, 0.0]);
    let green = Kernel::new([0.0, 0.0, 0.0, 0.0], [0.4, 0.4, 0.4, 1.0], [0.0, 1.0, 0.0]);
    let scene = |kernels: &[Kernel]| {
        Scene::from_kernels(kernels, [0.0; 3], "<equal depths>")
            .unwrap()
            .into_alpha(vec![0.9; 2], 0, Vec::new(), "<equal depths>")
            .unwrap()
    };
    let options = RenderOptions::default();
    let red_first = render(&scene(&[red, green]), &camera, 0.0, &options);
    let green_first = render(&scene(&[green, red]), &camera, 0.0, &options);
    let centre = red_first.pixel(16, 16);
    // The first kernel takes 0.9 of the light, the second 0.9 of the rest.
    assert!(
        (f64::from(centre[0]) - 0.9 * 0.99).abs() < 0.02,
        "{centre:?}"
    );
    assert!(centre[0] > 5.0 * centre[1], "{centre:?}");
    let swapped = green_first.pixel(16, 16);
    assert!(swapped[1] > 5.0 * swapped[0], "{swapped:?}");
    check_against_twin(&scene(&[red, green]), &camera, 0.0, "equal depths");
}

#[test]
fn negative_sh_colours_clamp_at_zero_and_static_kernels_hold_over_time() {
    let camera = test_camera(40, 30);
    let mut kernels = Vec::new();
    for k in 0..30 {
        let x = -1.0 + 0.07 * k as f64;
        kernels.push(Kernel::new(
            [x, 0.1 * (k % 3) as f64, 0.2 * (k % 4) as f64, 0.0],
            [0.2, 0.15, 0.1, 1e30],
            [0.1, -0.3, 0.5],
        ));
    }
    let n = kernels.len();
    let sh: Vec<[f64; 3]> = (0..3 * n)
        .map(|k| [0.8 * ((k % 3) as f64 - 1.0), -0.6, 0.4])
        .collect();
    let scene = Scene::from_kernels(&kernels, [0.0, 0.0, 0.2], "<static>")
        .unwrap()
        .into_alpha(vec![0.7; n], 3, sh, "<static>")
        .unwrap();
    let options = RenderOptions::default();
    let early = render(&scene, &camera, -1e6, &options);
    let late = render(&scene, &camera, 1e6, &options);
    assert_eq!(
        early.pixels, late.pixels,
        "static kernels are the same at any time"
    );
    // Green is clamped to zero for every kernel (−0.3 − 0.6 Σ Y): only the background's
    // green (none) remains.
    assert!(early.pixels.chunks(3).all(|p| p[1] == 0.0));
    check_against_twin(&scene, &camera, 0.5, "static kernels with negative SH");
}

#[test]
fn far_from_the_origin_the_blend_keeps_its_precision() {
    let offset = [1e5, -2e5, 5e4];
    let camera = Camera::look_at(
        [offset[0], offset[1], offset[2] - 4.0],
        offset,
        [0.0, 1.0, 0.0],
        40.0,
        40,
        32,
    )
    .unwrap();
    let mut scene = stack_scene(6, 0.8);
    for mean in &mut scene.means {
        for c in 0..3 {
            mean[c] += offset[c];
        }
    }
    check_against_twin(&scene, &camera, 0.4, "far from the origin");
}

#[test]
fn every_thread_count_and_simd_path_composites_the_same_bits() {
    let camera = test_camera(83, 61);
    let scene = alpha_scene(hard_random_scene(&camera, 7, 400), 7, 8);
    let options = RenderOptions::default();
    let mut images = Vec::new();
    for threads in [1, 2, 3] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        images.push(pool.install(|| render(&scene, &camera, 0.5, &options)));
    }
    let mut context = RenderContext::new();
    context.render(&scene, &camera, 0.5, &options).unwrap();
    let mut path_stops = Vec::new();
    let mut forms = Vec::new();
    let frame = splat4d::simd::BinnedFrame::new(
        &context.projected,
        &context.bins,
        &mut forms,
        scene.background.map(|b| b as f32),
        options.exp,
    );
    for &path in splat4d::simd::SimdPath::available() {
        // With the stops a backward reads, and without: the same image.
        for keep_stops in [true, false] {
            let mut image = Image::default();
            // Left as it was when no stops are asked for.
            let mut stops = vec![splat4d::composite::PixelStop::default(); 3];
            splat4d::composite::composite(
                &frame.on(path),
                &mut image,
                keep_stops.then_some(&mut stops),
            );
            images.push(image);
            if keep_stops {
                assert_eq!(stops.len(), (camera.width * camera.height) as usize);
                path_stops.push(stops);
            } else {
                assert_eq!(stops, vec![splat4d::composite::PixelStop::default(); 3]);
            }
        }
    }
    for stops in &path_stops[1..] {
        assert_eq!(stops, &path_stops[0]);
    }
    for image in &images[1..] {
        assert!(
            image
                .pixels
                .iter()
                .zip(&images[0].pixels)
                .all(|(a, b)| a.to_bits() == b.to_bits())
        );
    }
}

#[test]
fn alpha_scenes_round_trip_through_json_and_ply() {
    let camera = test_camera(20, 20);
    let dir = tempfile::tempdir().unwrap();
    for sh_count in [0, 3, 8, 15] {
        let mut scene = alpha_scene(hard_random_scene(&camera, 11, 20), 11, sh_count);
        // A fitted scene records the time range of its data; videos span it by default.
        scene.time_range = Some([0.25, 0.75]);
        assert_eq!(splat4d::scenes::paths::time_range(&scene), [0.25, 0.75]);
        // … and the sphere its cameras looked at, which videos frame.
        scene.framing = Some(([0.1, -0.2, 0.3], 1.5));
        let lens = splat4d::scenes::paths::Lens {
            width: 64,
            height: 48,
            fov_y_degrees: 40.0,
        };
        let circle = splat4d::scenes::paths::framing_circle(
            &scene,
            &[0.5],
            1.0 / 255.0,
            &lens,
            splat4d::model::Up::Y,
        );
        assert_eq!(circle.centre, [0.1, -0.2, 0.3]);
        for name in ["s.json", "s.ply"] {
            let path = dir.path().join(name);
            splat4d::io::scene_file::save_scene(&scene, &path).unwrap();
            let back = splat4d::io::scene_file::load_scene(&path).unwrap();
            assert_eq!(back, scene, "{name}, {sh_count} SH triplets");
            assert_eq!(back.blend, Blend::Alpha);
        }
    }
}

#[test]
fn bad_alpha_fields_are_refused_with_kernel_and_field_named() {
    let base = r#"{"blend": "alpha", "kernels": [
        {"mean": [0,0,0,0], "scale": [1,1,1,1], "amplitude": [1,1,1]},
        {"mean": [0,0,0,0], "scale": [1,1,1,1], "amplitude": [1,1,1], KERNEL1}]}"#;
    let cases = [
        (r#""opacity": 1.5"#, "opacity"),
        (r#""opacity": -0.1"#, "opacity"),
        (r#""sh": [[0,0,0],[0,0,0],[0,0,0]]"#, "sh"),
    ];
    for (field, named) in cases {
        let text = base.replace("KERNEL1", field);
        let error = splat4d::io::scene_file::scene_from_json(&text, "s.json")
            .unwrap_err()
            .to_string();
        assert!(
            error.contains("s.json") && error.contains("kernel 1") && error.contains(named),
            "{field}: {error}"
        );
    }
    let two = r#"{"blend": "alpha", "kernels": [{"mean": [0,0,0,0], "scale": [1,1,1,1],
        "amplitude": [1,1,1], "sh": [[0,0,0],[0,0,0]]}]}"#;
    let error = splat4d::io::scene_file::scene_from_json(two, "s.json")
        .unwrap_err()
        .to_string();
    assert!(error.contains("sh") && error.contains('2'), "{error}");
    let additive = r#"{"kernels": [{"mean": [0,0,0,0], "scale": [1,1,1,1],
        "amplitude": [1,1,1], "opacity": 0.5}]}"#;
    let error = splat4d::io::scene_file::scene_from_json(additive, "s.json")
        .unwrap_err()
        .to_string();
    assert!(
        error.contains("opacity") && error.contains("alpha"),
        "{error}"
    );
}

/// The fields of an alpha kernel, one differentiable number each: mean (4), velocity (3),
/// scale (4), rotation (4), opacity, amplitude (3), then `3 sh_count` SH numbers.
fn field_count(scene: &Scene) -> usize {
    19 + 3 * scene.sh_count
}

fn field_name(p: usize) -> String {
    const NAMES: [&str; 19] = [
        "x", "y", "z", "t", "vx", "vy", "vz", "sx", "sy", "sz", "st", "qw", "qx", "qy", "qz",
        "opacity", "r", "g", "b",
    ];
    NAMES.get(p).map_or_else(
        || format!("sh[{}][{}]", (p - 19) / 3, (p - 19) % 3),
        |n| (*n).to_owned(),
    )
}

fn field(scene: &Scene, i: usize, p: usize) -> f64 {
    match p {
        0..4 => scene.means[i][p],
        4..7 => scene.velocities[i][p - 4],
        7..11 => scene.scales[i][p - 7],
        11..15 => scene.rotations[i][p - 11],
        15 => scene.opacities[i],
        16..19 => scene.amplitudes[i][p - 16],
        _ => scene.sh[i * scene.sh_count + (p - 19) / 3][(p - 19) % 3],
    }
}

fn field_mut(scene: &mut Scene, i: usize, p: usize) -> &mut f64 {
    let count = scene.sh_count;
    match p {
        0..4 => &mut scene.means[i][p],
        4..7 => &mut scene.velocities[i][p - 4],
        7..11 => &mut scene.scales[i][p - 7],
        11..15 => &mut scene.rotations[i][p - 11],
        15 => &mut scene.opacities[i],
        16..19 => &mut scene.amplitudes[i][p - 16],
        _ => &mut scene.sh[i * count + (p - 19) / 3][(p - 19) % 3],
    }
}

fn gradient_field(grads: &splat4d::Gradients, sh_count: usize, i: usize, p: usize) -> f64 {
    match p {
        0..4 => grads.v_means[i][p],
        4..7 => grads.v_velocities[i][p - 4],
        7..11 => grads.v_scales[i][p - 7],
        11..15 => grads.v_rotations[i][p - 11],
        15 => grads.v_opacities[i],
        16..19 => grads.v_amplitudes[i][p - 16],
        _ => grads.v_sh[i * sh_count + (p - 19) / 3][(p - 19) % 3],
    }
}

/// Moderate random alpha kernels in front of the camera: rotations, velocities, SH, some
/// opaque (the clamp binds), some nearly transparent.
pub fn random_alpha_scene(seed: u64, n: usize, sh_count: usize) -> Scene {
    let mut rng = seeded_rng(seed);
    let kernels: Vec<Kernel> = (0..n)
        .map(|_| {
            let velocity = std::array::from_fn(|_| rng.random_range(-0.5..0.5));
            let mut kernel = Kernel::new(
                [
                    rng.random_range(-0.8..0.8),
                    rng.random_range(-0.6..0.6),
                    rng.random_range(-0.8..0.8),
                    rng.random_range(0.2..0.8),
                ],
                [
                    rng.random_range(0.08..0.35),
                    rng.random_range(0.08..0.35),
                    rng.random_range(0.08..0.35),
                    rng.random_range(0.2..1.0),
                ],
                std::array::from_fn(|_| rng.random_range(0.0..1.0)),
            );
            kernel.velocity = velocity;
            kernel.rotation = splat4d::model::random::random_rotation(&mut rng);
            kernel
        })
        .collect();
    let scene = Scene::from_kernels(&kernels, [0.2, 0.1, 0.3], "<random alpha>").unwrap();
    alpha_scene(scene, seed + 100, sh_count)
}

/// Bound on `|fast - finite difference|` per field: relative to the field's largest gradient
/// and to the value (f32 `q`, `G` and colour in the fast loops; measured worst 2e-6
/// relative).
const ALPHA_ATOL_FD: f64 = 2e-5;
const ALPHA_RTOL_FD: f64 = 2e-5;

/// Checks every field's fast gradient against central differences of the f64 twin with
/// pairs, order and stops held constant. Returns the worst ratio to the bound.
fn check_alpha_gradients(what: &str, scene: &Scene, camera: &Camera, tau: f64) -> f64 {
    let options = RenderOptions::default();
    let target = jittered_alpha_target(scene, camera, tau);
    let target_image = Image {
        width: camera.width,
        height: camera.height,
        pixels: target.clone(),
    };
    let mut grads = splat4d::Gradients::for_scene(scene);
    splat4d::fit::loss::view_loss_and_gradients(
        &mut RenderContext::new(),
        scene,
        camera,
        tau,
        &options,
        &target_image,
        &mut grads,
    )
    .unwrap();
    compare_with_the_twin(what, scene, (camera, tau), &target, &grads, true)
}

/// A target for gradient checks: the twin's render of `scene` with jittered means and
/// amplitudes (seeded), in f32.
pub fn jittered_alpha_target(scene: &Scene, camera: &Camera, tau: f64) -> Vec<f32> {
    let options = RenderOptions::default();
    // The target: the twin's render of a jittered scene.
    let mut moved = scene.clone();
    let mut rng = seeded_rng(5);
    for i in 0..moved.len() {
        for c in 0..3 {
            moved.means[i][c] += rng.random_range(-0.05..0.05);
            moved.amplitudes[i][c] *= rng.random_range(0.6..1.2);
        }
    }
    render_reference_alpha(&moved, camera, tau, &options)
        .pixels
        .iter()
        .map(|&v| v as f32)
        .collect()
}

/// Checks every field of `grads` (of the MSE of `scene` against `target`) against central
/// differences of the f64 twin with pairs, order and stops held constant. `scene`'s
/// quaternions may have any length (the twin normalises them): `grads` is then the
/// gradient of the quaternions as `scene` holds them. With `background`, `∂L/∂b` too (the
/// `splat4d grad` file has none). Returns the worst ratio to the bound.
pub fn compare_with_the_twin(
    what: &str,
    scene: &Scene,
    (camera, tau): (&Camera, f64),
    target: &[f32],
    grads: &splat4d::Gradients,
    background: bool,
) -> f64 {
    use splat4d::reference::composite::composite_traced;
    let options = RenderOptions::default();
    let traced = render_reference_alpha(scene, camera, tau, &options);
    let kernels = splat4d::reference::colour::reference_alpha_kernels(scene, camera, tau, &options);
    let order: Vec<usize> = kernels.iter().map(|k| k.kernel.index).collect();
    let loss = |scene: &Scene| {
        let pixels = composite_traced(scene, camera, tau, &options, &order, &traced.traces);
        splat4d::reference::mse(&pixels, target)
    };
    let fields = field_count(scene);
    let mut fd = vec![vec![0.0; fields]; scene.len()];
    for (i, row) in fd.iter_mut().enumerate() {
        for (p, value) in row.iter_mut().enumerate() {
            let theta = field(scene, i, p);
            let h = match p {
                7..11 => 1e-4 * theta,
                _ => 1e-6 * theta.abs().max(0.1),
            };
            let mut plus = scene.clone();
            *field_mut(&mut plus, i, p) = theta + h;
            let mut minus = scene.clone();
            *field_mut(&mut minus, i, p) = theta - h;
            *value = (loss(&plus) - loss(&minus)) / (2.0 * h);
        }
    }
    let scale: Vec<f64> = (0..fields)
        .map(|p| fd.iter().map(|r| r[p].abs()).fold(0.0, f64::max))
        .collect();
    for (p, s) in scale.iter().enumerate() {
        assert!(
            *s > 0.0,
            "{what}: {} has a gradient somewhere",
            field_name(p)
        );
    }
    let mut worst = 0.0_f64;
    for (i, row) in fd.iter().enumerate() {
        for (p, &f) in row.iter().enumerate() {
            let a = gradient_field(grads, scene.sh_count, i, p);
            let bound = ALPHA_ATOL_FD * scale[p] + ALPHA_RTOL_FD * f.abs() + 1e-12;
            let delta = (a - f).abs();
            worst = worst.max(delta / bound);
            assert!(
                delta <= bound,
                "{what}: kernel {i} {}: fast {a} vs finite difference {f} (|Δ| = {delta:e}, bound {bound:e})",
                field_name(p)
            );
        }
    }
    // The background: ∂L/∂b = Σ v T_final.
    for c in (0..3).filter(|_| background) {
        let h = 1e-6;
        let mut plus = scene.clone();
        plus.background[c] += h;
        let mut minus = scene.clone();
        minus.background[c] -= h;
        let f = (loss(&plus) - loss(&minus)) / (2.0 * h);
        let a = grads.v_background[c];
        assert!(
            (a - f).abs() <= 1e-4 * f.abs() + 1e-9,
            "{what}: background {c}: {a} vs {f}"
        );
    }
    eprintln!("{what}: worst gradient at {worst:.3} of the bound");
    worst
}

#[test]
fn gradients_of_every_field_match_finite_differences_of_the_twin() {
    let camera =
        Camera::look_at([0.2, -0.3, -3.5], [0.0; 3], [0.0, 1.0, 0.0], 45.0, 36, 28).unwrap();
    for (seed, sh_count) in [(1, 0), (2, 3), (3, 8), (4, 15)] {
        let scene = random_alpha_scene(seed, 24, sh_count);
        check_alpha_gradients(&format!("seed {seed}"), &scene, &camera, 0.45);
    }
    let stack_camera =
        Camera::look_at([0.3, 0.2, -4.0], [0.0; 3], [0.0, 1.0, 0.0], 40.0, 32, 28).unwrap();
    for (opacity, tau) in [(1.0, 0.3), (0.7, 0.6)] {
        let scene = stack_scene(8, opacity);
        check_alpha_gradients(&format!("stack o = {opacity}"), &scene, &stack_camera, tau);
    }
}

#[test]
fn alpha_gradients_are_the_same_bits_for_any_thread_count() {
    let camera = test_camera(70, 52);
    let scene = alpha_scene(hard_random_scene(&camera, 12, 300), 12, 3);
    let target = Image {
        width: camera.width,
        height: camera.height,
        pixels: vec![0.25; 3 * camera.pixel_count()],
    };
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let mut grads = splat4d::Gradients::for_scene(&scene);
            splat4d::fit::loss::view_loss_and_gradients(
                &mut RenderContext::new(),
                &scene,
                &camera,
                0.5,
                &RenderOptions::default(),
                &target,
                &mut grads,
            )
            .unwrap();
            grads
        })
    };
    let one = run(1);
    assert!(one.v_opacities.iter().any(|&v| v != 0.0));
    assert!(one.v_rotations.iter().flatten().any(|&v| v != 0.0));
    for threads in [2, 3] {
        assert_eq!(run(threads), one, "{threads} threads");
    }
}

/// Every command honours the blend the scene declares: `render`, `grad` (every field),
/// `export-ply` (SPEC §8's mapping), `volume` (the opacity density, said), `bench`.
#[test]
fn commands_honour_an_alpha_scene() {
    use crate::common::{splat4d, stderr};
    let dir = tempfile::tempdir().unwrap();
    let camera = test_camera(40, 30);
    let scene = alpha_scene(hard_random_scene(&camera, 31, 60), 31, 3);
    splat4d::io::scene_file::save_scene(&scene, &dir.path().join("s.json")).unwrap();
    splat4d::io::camera_file::save_camera(&camera, &dir.path().join("c.json")).unwrap();
    let run = |args: &[&str]| {
        let output = splat4d(args, dir.path());
        assert!(output.status.success(), "{args:?}: {}", stderr(&output));
        String::from_utf8_lossy(&output.stdout).into_owned()
    };
    run(&[
        "render", "--scene", "s.json", "--camera", "c.json", "--time", "0.5", "--out", "r.exr",
    ]);
    let image = splat4d::io::image_file::load_image(&dir.path().join("r.exr"), [0.0; 3]).unwrap();
    let expected = render(&scene, &camera, 0.5, &RenderOptions::default());
    assert_eq!(
        image.pixels, expected.pixels,
        "render writes the alpha composite"
    );
    run(&[
        "grad", "--scene", "s.json", "--camera", "c.json", "--time", "0.5", "--target", "r.exr",
        "--out", "g.json",
    ]);
    let text = std::fs::read_to_string(dir.path().join("g.json")).unwrap();
    let (_, grads) = splat4d::io::gradients_file::gradients_from_json(&text, "g.json").unwrap();
    assert_eq!(grads.v_opacities.len(), scene.len());
    assert_eq!(grads.v_sh.len(), scene.sh.len());
    for key in ["\"opacity\"", "\"sh\"", "\"rotation\"", "\"scale\""] {
        assert!(text.contains(key), "{key} in the gradient file");
    }
    run(&[
        "export-ply",
        "--scene",
        "s.json",
        "--time",
        "0.5",
        "--out",
        "e.ply",
    ]);
    let exported = splat4d::io::scene_file::load_scene(&dir.path().join("e.ply")).unwrap();
    assert_eq!((exported.blend, exported.sh_count), (Blend::Alpha, 3));
    let volume = run(&[
        "volume", "--scene", "s.json", "--res", "8", "--times", "0.5", "--out", "v",
    ]);
    assert!(volume.contains("opacity density"), "{volume}");
    let bench = run(&[
        "bench",
        "--scene",
        "2000",
        "--size",
        "64x48",
        "--frames",
        "1",
        "--threads",
        "1",
        "--blend",
        "alpha",
    ]);
    assert!(bench.contains("bench-2000-alpha"), "{bench}");
    // The row's ceiling share is against the alpha probe of the same run, the only probe
    // shown: share = pairs/s over its pairs/s (to the printed digits).
    let row: Vec<&str> = bench
        .lines()
        .find(|l| l.starts_with("bench-2000-alpha"))
        .unwrap()
        .split_whitespace()
        .collect();
    let pairs_per_second: f64 = row[7].parse().unwrap();
    let share: f64 = row[8].trim_end_matches('%').parse().unwrap();
    let probe = crate::common::probe_rate(&bench, "alpha ceiling probe", 1);
    assert!(!bench.contains("\nceiling probe ("), "{bench}");
    let expected = 100.0 * pairs_per_second / probe;
    assert!(
        (share - expected).abs() <= 0.05 + 1e-3 * expected,
        "{share}% shown, {expected}% from the alpha probe: {bench}"
    );
}

/// Mutated alpha and 3DGS PLYs are read or refused as input errors, never a panic.
#[test]
fn mutated_alpha_plys_never_panic() {
    let camera = test_camera(20, 20);
    let scene = alpha_scene(hard_random_scene(&camera, 41, 10), 41, 3);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.ply");
    splat4d::io::scene_file::save_scene(&scene, &path).unwrap();
    let scene_bytes = std::fs::read(&path).unwrap();
    splat4d::io::ply::write_slice_ply(&scene, 0.5, 1.0 / 255.0, true, &path).unwrap();
    let splat_bytes = std::fs::read(&path).unwrap();
    let mut rng = seeded_rng(9);
    let (mut loaded, mut refused) = (0, 0);
    for bytes in [&scene_bytes, &splat_bytes] {
        for _ in 0..400 {
            let mut mutated = bytes.clone();
            for _ in 0..rng.random_range(1..4) {
                let k = rng.random_range(0..mutated.len());
                mutated[k] = rng.random();
            }
            if rng.random_range(0..4) == 0 {
                mutated.truncate(rng.random_range(0..mutated.len()));
            }
            match splat4d::io::ply::parse_scene_ply(&mutated, "m.ply") {
                Ok(_) => loaded += 1,
                Err(e) => {
                    assert_eq!(e.kind(), splat4d::ErrorKind::Input, "{e}");
                    refused += 1;
                }
            }
        }
    }
    assert!(
        loaded > 50 && refused > 50,
        "{loaded} loaded, {refused} refused"
    );
}
