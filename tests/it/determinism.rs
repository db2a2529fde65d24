//! The image is the same bit for bit whatever the number of threads, and a reused context
//! gives the same image as a fresh one.

use crate::common::{hard_random_scene, test_camera};
use splat4d::scenes::synthetic::{bench_camera, bench_scene};
use splat4d::{RenderContext, RenderOptions, render};

fn bits(pixels: &[f32]) -> Vec<u32> {
    pixels.iter().map(|v| v.to_bits()).collect()
}

#[test]
fn same_bits_for_1_2_3_and_8_threads() {
    let cases = [
        (
            hard_random_scene(&test_camera(120, 90), 3, 300),
            test_camera(120, 90),
        ),
        (bench_scene(3000, 7), bench_camera(200, 150)),
    ];
    for (scene, camera) in &cases {
        for cutoff in [RenderOptions::default().cutoff, 0.0] {
            let options = RenderOptions {
                cutoff,
                ..RenderOptions::default()
            };
            let images: Vec<_> = [1, 2, 3, 8]
                .iter()
                .map(|&threads| {
                    let pool = rayon::ThreadPoolBuilder::new()
                        .num_threads(threads)
                        .build()
                        .unwrap();
                    let mut context = RenderContext::new();
                    let stats = pool
                        .install(|| context.render(scene, camera, 0.45, &options))
                        .unwrap();
                    (bits(&context.image().pixels), stats)
                })
                .collect();
            assert!(images[0].1.pairs > 0);
            for (threads, image) in [2, 3, 8].iter().zip(&images[1..]) {
                assert!(
                    image == &images[0],
                    "{threads} threads differ from 1 thread (cut-off {cutoff})"
                );
            }
        }
    }
}

#[test]
fn a_reused_context_matches_a_fresh_render() {
    let camera = test_camera(96, 72);
    let big = hard_random_scene(&camera, 1, 300);
    let small = hard_random_scene(&camera, 2, 20);
    let options = RenderOptions::default();
    let mut context = RenderContext::new();
    context.render(&big, &camera, 0.2, &options).unwrap();
    context.render(&small, &camera, 0.7, &options).unwrap();
    let fresh = render(&small, &camera, 0.7, &options).unwrap();
    assert_eq!(bits(&context.image().pixels), bits(&fresh.pixels));
}
