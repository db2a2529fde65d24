//! The temporal index changes which kernels a frame visits, never the image: indexed renders
//! are bit-identical to plain ones, and a frame visits about the kernels alive at τ.

use rand::RngExt;
use splat4d::model::random::{random_rotation, seeded_rng};
use splat4d::slice::{SlicedKernels, TemporalIndex, slice};
use splat4d::{Kernel, RenderContext, RenderOptions, Scene};

/// Kernels spread over t ∈ [0, 10] with σt from 1e-3 to 10 (short- and long-lived), some with
/// zero or sub-cut-off amplitudes.
fn scene(n: usize, seed: u64) -> Scene {
    let mut rng = seeded_rng(seed);
    let kernels: Vec<Kernel> = (0..n)
        .map(|k| {
            let amplitude = match k % 17 {
                0 => [0.0; 3],
                1 => [1e-3, -2e-3, 0.0],
                _ => [
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                ],
            };
            Kernel {
                rotation: random_rotation(&mut rng),
                velocity: [
                    rng.random_range(-0.1..0.1),
                    0.0,
                    rng.random_range(-0.1..0.1),
                ],
                ..Kernel::new(
                    [
                        rng.random_range(-1.0..1.0),
                        rng.random_range(-1.0..1.0),
                        rng.random_range(-1.0..1.0),
                        rng.random_range(0.0..10.0),
                    ],
                    [
                        0.1,
                        0.15,
                        0.1,
                        splat4d::model::random::log_uniform(&mut rng, 1e-3, 10.0),
                    ],
                    amplitude,
                )
            }
        })
        .collect();
    Scene::from_kernels(&kernels, [0.0; 3], "<temporal index test>").unwrap()
}

#[test]
fn indexed_renders_are_bit_identical() {
    let camera = crate::common::test_camera(64, 48);
    let s = scene(3000, 1);
    for cutoff in [1.0 / 255.0, 0.05, 0.0] {
        let options = RenderOptions {
            cutoff,
            ..Default::default()
        };
        let index = TemporalIndex::new(&s, cutoff);
        let (mut plain, mut indexed) = (RenderContext::new(), RenderContext::new());
        for tau in [-5.0, -0.01, 0.0, 0.37, 2.5, 5.0, 9.99, 10.0, 10.4, 30.0] {
            let a = plain.render(&s, &camera, tau, &options).unwrap();
            let b = indexed
                .render_indexed(&s, &index, &camera, tau, &options)
                .unwrap();
            assert_eq!(a, b, "stats at τ = {tau}, cut-off {cutoff}");
            let bits = |c: &RenderContext| {
                c.image()
                    .pixels
                    .iter()
                    .map(|v| v.to_bits())
                    .collect::<Vec<_>>()
            };
            assert_eq!(
                bits(&plain),
                bits(&indexed),
                "image at τ = {tau}, cut-off {cutoff}"
            );
        }
    }
}

#[test]
fn a_frame_visits_about_the_kernels_alive() {
    let s = scene(20_000, 2);
    let cutoff = 1.0 / 255.0;
    let index = TemporalIndex::new(&s, cutoff);
    let mut candidates = Vec::new();
    let mut sliced = SlicedKernels::default();
    for tau in [1.0, 5.0, 9.0] {
        index.candidates(tau, &mut candidates);
        slice(&s, tau, cutoff, &mut sliced);
        let alive = sliced.len();
        assert!(
            candidates.windows(2).all(|w| w[0] < w[1]),
            "ascending, no repeats"
        );
        assert!(
            sliced
                .kernel_from_slice
                .iter()
                .all(|i| candidates.binary_search(i).is_ok()),
            "every alive kernel is a candidate"
        );
        assert!(
            candidates.len() < 3 * alive + 500,
            "τ = {tau}: {} candidates for {alive} alive of {}",
            candidates.len(),
            s.len()
        );
        println!(
            "τ = {tau}: {alive} alive, {} candidates of {}",
            candidates.len(),
            s.len()
        );
    }
    let mismatched = TemporalIndex::new(&s, 0.0);
    let error = RenderContext::new()
        .render_indexed(
            &s,
            &mismatched,
            &crate::common::test_camera(8, 8),
            1.0,
            &RenderOptions::default(),
        )
        .unwrap_err()
        .to_string();
    assert!(error.contains("temporal index"), "{error}");
}
