//! Hard cases (numerical stability): each render is compared with the f64 reference at the
//! documented bound `1e-6 + 2e-6·Σ|a| + 1.01 ε·(band pairs)` (see tests/common), and the
//! fast gradients are checked finite and, where the case is smooth, against the f64
//! backward. Each case prints its worst ratio to the bound (`--nocapture`), the numbers in
//! README's table.

use crate::common::{assert_within_bound, worst_ratio};
use splat4d::reference::{reference_at_pixels, reference_loss_and_gradients, render_reference};
use splat4d::{Camera, Gradients, Image, Kernel, RenderContext, RenderOptions, Scene};

fn camera(width: u32, height: u32) -> Camera {
    Camera::look_at(
        [0.0, 0.0, -4.0],
        [0.0; 3],
        [0.0, 1.0, 0.0],
        50.0,
        width,
        height,
    )
    .unwrap()
}

fn scene(kernels: &[Kernel]) -> Scene {
    Scene::from_kernels(kernels, [0.02, 0.0, 0.01], "<hard case>").unwrap()
}

/// Renders fast and reference, asserts the bound, returns the worst ratio.
fn check_render(
    what: &str,
    scene: &Scene,
    camera: &Camera,
    tau: f64,
    options: &RenderOptions,
) -> f64 {
    let mut context = RenderContext::new();
    context.render(scene, camera, tau, options).unwrap();
    let image = context.image();
    assert!(
        image.pixels.iter().all(|v| v.is_finite()),
        "{what}: non-finite pixel"
    );
    let reference = render_reference(scene, camera, tau, options);
    assert_within_bound(image, &reference, options.cutoff, what);
    let (ratio, _) = worst_ratio(image, &reference, options.cutoff);
    println!("{what}: {ratio:.3} of the bound");
    ratio
}

/// Gradients against a constant target: the fast ones finite and within
/// `1e-5·max|g| + 1e-5·|g|` of the f64 backward, and the f64 backward within
/// `1e-7·max|fd| + 1e-5·|fd|` of central finite differences (pair set frozen). Prints both
/// worst ratios.
fn check_gradients(what: &str, scene: &Scene, camera: &Camera, tau: f64, options: &RenderOptions) {
    check_gradients_with(what, scene, camera, tau, options, 1e-5);
}

/// [`check_gradients`] with relative tolerance `fd_rtol` against finite differences, for the
/// cases where the finite differences themselves are the limit (stated at each call).
fn check_gradients_with(
    what: &str,
    scene: &Scene,
    camera: &Camera,
    tau: f64,
    options: &RenderOptions,
    fd_rtol: f64,
) {
    let target = Image::filled(camera.width, camera.height, [0.3, 0.2, 0.1]);
    let (_, grads) = crate::common::fast_gradients(scene, camera, tau, options, &target);
    let (_, reference) = reference_loss_and_gradients(scene, camera, tau, options, &target.pixels);
    let flat = |g: &Gradients| -> Vec<f64> {
        (0..g.len())
            .flat_map(|i| crate::common::grad_of(g, i))
            .collect()
    };
    let (fast, slow) = (flat(&grads), flat(&reference));
    assert!(
        fast.iter().all(|v| v.is_finite()),
        "{what}: non-finite gradient"
    );
    let scale = slow.iter().map(|v| v.abs()).fold(0.0, f64::max);
    let mut fast_worst: f64 = 0.0;
    for (k, (f, s)) in fast.iter().zip(&slow).enumerate() {
        let bound = 1e-5 * scale + 1e-5 * s.abs() + 1e-300;
        fast_worst = fast_worst.max((f - s).abs() / bound);
        assert!(
            (f - s).abs() <= bound,
            "{what}: gradient {k}: fast {f} vs f64 {s}"
        );
    }
    let fd: Vec<Option<f64>> =
        crate::common::finite_difference_gradients(scene, camera, tau, options, &target.pixels)
            .into_iter()
            .flatten()
            .collect();
    let fd_scale = fd.iter().flatten().map(|v| v.abs()).fold(0.0, f64::max);
    let mut fd_worst: f64 = 0.0;
    for (k, (a, f)) in slow.iter().zip(&fd).enumerate() {
        let Some(f) = f else { continue };
        let bound = 1e-7 * fd_scale + fd_rtol * f.abs() + 1e-300;
        fd_worst = fd_worst.max((a - f).abs() / bound);
        assert!(
            (a - f).abs() <= bound,
            "{what}: kernel {} {}: f64 backward {a} vs finite difference {f}",
            k / crate::common::PARAMS,
            crate::common::PARAM_NAMES[k % crate::common::PARAMS]
        );
    }
    println!(
        "{what}: gradients: fast vs f64 {fast_worst:.3}, f64 vs finite differences {fd_worst:.3} of their bounds"
    );
}

#[test]
fn behind_and_straddling_the_near_plane() {
    let cam = camera(64, 48);
    let kernels: Vec<Kernel> = [-3.0, -0.5, 3.99, 3.995, 4.0 - 0.0101, 4.0 - 0.0099, 3.5]
        .iter()
        .map(|&z| Kernel::new([0.05, -0.02, z, 0.5], [0.3, 0.2, 0.5, 1.0], [0.8, 0.5, 0.3]))
        .collect();
    let s = scene(&kernels);
    for options in [
        RenderOptions::default(),
        RenderOptions {
            cutoff: 0.0,
            ..Default::default()
        },
    ] {
        check_render(
            "behind / straddling the near plane",
            &s,
            &cam,
            0.5,
            &options,
        );
        check_gradients(
            "behind / straddling the near plane",
            &s,
            &cam,
            0.5,
            &options,
        );
    }
}

#[test]
fn centres_far_outside_the_frustum_with_ellipses_reaching_in() {
    let cam = camera(64, 48);
    let kernels: Vec<Kernel> = [
        (30.0, 0.0),
        (-30.0, 5.0),
        (0.0, 25.0),
        (8.0, -9.0),
        (200.0, 0.0),
    ]
    .iter()
    .map(|&(x, y)| {
        Kernel::new(
            [x, y, 2.0, 0.5],
            [x.abs().max(y.abs()) * 0.6, 3.0, 1.0, 1.0],
            [0.7, 0.4, 0.9],
        )
    })
    .collect();
    let s = scene(&kernels);
    check_render(
        "far outside the frustum",
        &s,
        &cam,
        0.5,
        &RenderOptions::default(),
    );
    check_gradients(
        "far outside the frustum",
        &s,
        &cam,
        0.5,
        &RenderOptions::default(),
    );
}

#[test]
fn anisotropy_up_to_10_000_to_1() {
    let cam = camera(64, 48);
    let s = std::f64::consts::FRAC_1_SQRT_2;
    for ratio in [1e2, 1e3, 1e4] {
        let kernels = [
            Kernel {
                rotation: [0.92, 0.1, 0.3, 0.2],
                ..Kernel::new(
                    [0.0, 0.0, 0.0, 0.5],
                    [1.0, 1.0 / ratio, 1.0 / ratio, 1.0],
                    [0.9, 0.9, 0.9],
                )
            },
            Kernel {
                rotation: [s, 0.0, 0.0, s],
                ..Kernel::new(
                    [0.2, 0.1, 0.5, 0.5],
                    [1.0 / ratio, 0.8, 0.8 / ratio, 1.0],
                    [0.5, -0.3, 0.2],
                )
            },
        ];
        let sc = scene(&kernels);
        for dilation in [0.3, 0.0] {
            let options = RenderOptions {
                dilation,
                ..Default::default()
            };
            check_render(
                &format!("anisotropy {ratio}:1, dilation {dilation}"),
                &sc,
                &cam,
                0.5,
                &options,
            );
            // The finite differences are the limit here, so they are compared at 1e-3 (fast vs
            // f64 stays at 1e-5): needles ≥ 10³:1 without dilation are 10⁻³ px wide or less and
            // the f64 oracle's plain dᵀQd (Q of 10⁶ px⁻² and more) rounds; at 10⁴:1 the spatial
            // step follows the 3D σ (10⁻⁸) and falls below what the loss's rounding resolves.
            let fd_rtol = if (dilation == 0.0 && ratio >= 1e3) || ratio >= 1e4 {
                1e-3
            } else {
                1e-5
            };
            check_gradients_with(
                &format!("anisotropy {ratio}:1, dilation {dilation}"),
                &sc,
                &cam,
                0.5,
                &options,
                fd_rtol,
            );
        }
    }
}

#[test]
fn sub_pixel_kernels_with_and_without_dilation() {
    let cam = camera(64, 48);
    let kernels: Vec<Kernel> = (0..40)
        .map(|k| {
            Kernel::new(
                [
                    -0.8 + 0.04 * f64::from(k),
                    0.013 * f64::from(k % 7),
                    0.0,
                    0.5,
                ],
                [1e-3, 2e-3, 1e-3, 1.0],
                [1.0, 0.5, 0.2],
            )
        })
        .collect();
    let s = scene(&kernels);
    for dilation in [0.3, 0.0] {
        let options = RenderOptions {
            dilation,
            ..Default::default()
        };
        check_render(
            &format!("sub-pixel, dilation {dilation}"),
            &s,
            &cam,
            0.5,
            &options,
        );
    }
    check_gradients(
        "sub-pixel, dilation 0.3",
        &s,
        &cam,
        0.5,
        &RenderOptions::default(),
    );
}

#[test]
fn one_kernel_covering_the_whole_screen() {
    let cam = camera(64, 48);
    let s = scene(&[Kernel::new(
        [0.1, 0.0, -3.5, 0.5],
        [2.0, 3.0, 0.2, 1.0],
        [0.6, 0.6, 0.6],
    )]);
    let mut context = RenderContext::new();
    let stats = context
        .render(&s, &cam, 0.5, &RenderOptions::default())
        .unwrap();
    assert_eq!(stats.pairs, 64 * 48, "every pixel is a pair");
    check_render("whole screen", &s, &cam, 0.5, &RenderOptions::default());
    check_gradients("whole screen", &s, &cam, 0.5, &RenderOptions::default());
}

#[test]
fn tiny_sigma_t_near_and_far_from_t() {
    let cam = camera(48, 36);
    for st in [1e-3, 1e-6] {
        for offset in [0.0, 0.5, 3.0, 40.0, 1e6] {
            let k = Kernel {
                velocity: [1.0, -2.0, 0.5],
                ..Kernel::new(
                    [0.0, 0.0, 0.0, 0.5 - offset * st],
                    [0.3, 0.3, 0.3, st],
                    [0.9, 0.4, -0.2],
                )
            };
            let s = scene(&[k]);
            for cutoff in [RenderOptions::default().cutoff, 0.0] {
                let options = RenderOptions {
                    cutoff,
                    ..Default::default()
                };
                let what = format!("σt {st}, τ - t = {offset} σt, cut-off {cutoff}");
                check_render(&what, &s, &cam, 0.5, &options);
                // For σt = 1e-6 the step in t is 1e-11: the loss's own rounding (≈ 1e-16 L/h)
                // reaches 1e-3 of the motion part of ∂L/∂t, so finite differences are
                // compared at 5e-2 there (fast vs f64 stays at 1e-5).
                let fd_rtol = if st < 1e-4 { 5e-2 } else { 1e-5 };
                check_gradients_with(&what, &s, &cam, 0.5, &options, fd_rtol);
            }
        }
    }
}

#[test]
fn scene_and_camera_far_from_the_origin() {
    for shift in [1e4, 1e5, 1e6] {
        let offset = [shift, -0.7 * shift, 0.3 * shift];
        let cam = Camera::look_at(
            [offset[0], offset[1], offset[2] - 4.0],
            offset,
            [0.0, 1.0, 0.0],
            50.0,
            64,
            48,
        )
        .unwrap();
        let kernels: Vec<Kernel> = (0..30)
            .map(|k| {
                let f = f64::from(k);
                Kernel::new(
                    [
                        offset[0] + 0.05 * f - 0.7,
                        offset[1] + 0.03 * (f % 5.0),
                        offset[2] + 0.02 * f,
                        0.5,
                    ],
                    [0.1, 0.15, 0.1, 1.0],
                    [0.3, 0.2, 0.1],
                )
            })
            .collect();
        let s = scene(&kernels);
        check_render(
            &format!("translated {shift:e} from the origin"),
            &s,
            &cam,
            0.5,
            &RenderOptions::default(),
        );
        check_gradients(
            &format!("translated {shift:e} from the origin"),
            &s,
            &cam,
            0.5,
            &RenderOptions::default(),
        );
    }
}

#[test]
fn ten_thousand_kernels_stacked_on_one_tile() {
    let cam = camera(64, 64);
    let kernels: Vec<Kernel> = (0..10_000)
        .map(|k| {
            let f = f64::from(k);
            Kernel::new(
                [
                    0.002 * (f % 7.0),
                    0.002 * (f % 11.0),
                    0.001 * (f % 13.0),
                    0.5,
                ],
                [0.01, 0.012, 0.01, 1.0],
                [1e-3, 2e-3, -1e-3],
            )
        })
        .collect();
    let s = scene(&kernels);
    let mut context = RenderContext::new();
    context
        .render(
            &s,
            &cam,
            0.5,
            &RenderOptions {
                cutoff: 0.0,
                ..Default::default()
            },
        )
        .unwrap();
    let busiest = (0..context.bins.tile_count())
        .map(|t| context.bins.tile_entries(t).len())
        .max()
        .unwrap();
    assert_eq!(busiest, 10_000, "all on one tile");
    check_render(
        "10k kernels on one tile, cut-off 0",
        &s,
        &cam,
        0.5,
        &RenderOptions {
            cutoff: 0.0,
            ..Default::default()
        },
    );
}

#[test]
fn tiny_and_huge_amplitudes_and_no_kernels() {
    let cam = camera(48, 36);
    for amplitude in [1e-8, 1e8] {
        let s = scene(&[Kernel::new(
            [0.0, 0.0, 0.0, 0.5],
            [0.3, 0.3, 0.3, 1.0],
            [amplitude, -amplitude, 0.5 * amplitude],
        )]);
        for cutoff in [RenderOptions::default().cutoff, 0.0] {
            let options = RenderOptions {
                cutoff,
                ..Default::default()
            };
            check_render(
                &format!("amplitude {amplitude:e}, cut-off {cutoff}"),
                &s,
                &cam,
                0.5,
                &options,
            );
            check_gradients(
                &format!("amplitude {amplitude:e}, cut-off {cutoff}"),
                &s,
                &cam,
                0.5,
                &options,
            );
        }
    }
    let empty = scene(&[]);
    let mut context = RenderContext::new();
    let stats = context
        .render(&empty, &cam, 0.5, &RenderOptions::default())
        .unwrap();
    assert_eq!(stats.pairs, 0);
    assert!(
        context
            .image()
            .pixels
            .chunks_exact(3)
            .all(|p| p == [0.02, 0.0, 0.01]),
        "background only"
    );
}

#[test]
fn one_pixel_and_8192_squared_images() {
    let kernels: Vec<Kernel> = (0..20)
        .map(|k| {
            Kernel::new(
                [0.1 * f64::from(k) - 1.0, 0.05 * f64::from(k % 4), 0.0, 0.5],
                [0.2, 0.1, 0.2, 1.0],
                [0.5, 0.3, 0.2],
            )
        })
        .collect();
    let s = scene(&kernels);
    check_render(
        "1×1 image",
        &s,
        &camera(1, 1),
        0.5,
        &RenderOptions::default(),
    );
    check_gradients(
        "1×1 image",
        &s,
        &camera(1, 1),
        0.5,
        &RenderOptions::default(),
    );
    let big = camera(8192, 8192);
    let mut context = RenderContext::new();
    let stats = context
        .render(&s, &big, 0.5, &RenderOptions::default())
        .unwrap();
    assert!(stats.pairs > 1_000_000);
    let image = context.image();
    let mut rng = splat4d::model::random::seeded_rng(1);
    use rand::RngExt;
    let pixels: Vec<(u32, u32)> = (0..300)
        .map(|_| (rng.random_range(2500..5700), rng.random_range(3000..5200)))
        .chain([(0, 0), (8191, 8191)])
        .collect();
    let mut worst: f64 = 0.0;
    for (&(i, j), (colour, abs_sum)) in pixels.iter().zip(reference_at_pixels(
        &s,
        &big,
        0.5,
        &RenderOptions::default(),
        &pixels,
    )) {
        let fast = image.pixel(i, j);
        for c in 0..3 {
            let ratio = (f64::from(fast[c]) - colour[c]).abs()
                / (crate::common::ATOL + crate::common::RTOL * abs_sum[c]);
            worst = worst.max(ratio);
        }
    }
    assert!(worst <= 1.0, "8192² image at {worst} of the bound");
    println!("8192² image: {worst:.3} of the bound (300 sampled pixels)");
}

/// Found by the property tests: without truncation a row's span is the kernel's whole box,
/// and `t` anchored at its first pixel (up to 16 px from a thin ellipse's centre line) lost
/// 1e-4 of the term to one f32 rounding (1.7× the bound). `t` is now anchored at the pixel
/// nearest the centre line.
#[test]
fn thin_ellipse_without_truncation_in_a_very_wide_camera() {
    let camera = Camera::new(
        18,
        3,
        [1.769207350257841, 1.769207350257841, 9.0, 1.5],
        [
            [
                -0.10633370246933686,
                0.0,
                0.9943305002458501,
                -0.5319613842965969,
            ],
            [
                0.2630589409422048,
                -0.9643695406918488,
                0.02813152281975774,
                -0.5947985859734102,
            ],
            [
                0.9589020478179867,
                0.2645588573187315,
                0.1025449838104181,
                5.321352630591985,
            ],
            [0.0, 0.0, 0.0, 1.0],
        ],
    )
    .unwrap();
    let s = crate::common::hard_random_scene(&camera, 4196523199664466103, 8);
    let options = RenderOptions {
        dilation: 0.0,
        cutoff: 0.0,
        ..Default::default()
    };
    check_render(
        "thin ellipse, no truncation, 157° camera",
        &s,
        &camera,
        1.1865182092867972,
        &options,
    );
    check_gradients(
        "thin ellipse, no truncation, 157° camera",
        &s,
        &camera,
        1.1865182092867972,
        &options,
    );
}
