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

/// A frame rendered in bands ([`RenderContext::render_in_bands`]) hands over exactly the
/// rows of [`RenderContext::render`]'s image, in order, with the same counts, on any thread
/// count, additive and alpha, with a partial last tile row; a failing drain stops it.
#[test]
fn a_frame_in_bands_is_the_image_row_by_row() {
    let camera = test_camera(100, 75);
    let additive = hard_random_scene(&camera, 4, 300);
    let alpha = crate::alpha::alpha_scene(hard_random_scene(&camera, 5, 300), 6, 3);
    let options = RenderOptions::default();
    for (scene, what) in [(&additive, "additive"), (&alpha, "alpha")] {
        let mut whole = RenderContext::new();
        let stats = whole.render(scene, &camera, 0.45, &options).unwrap();
        assert!(stats.pairs > 0, "{what}");
        let expected = bits(&whole.image().pixels);
        for threads in [1, 2, 3] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let mut context = RenderContext::new();
            for round in 0..2 {
                let mut rows = Vec::new();
                let banded = pool
                    .install(|| {
                        context.render_in_bands(scene, &camera, 0.45, &options, &mut |y, values| {
                            assert_eq!(3 * 100 * y, rows.len(), "{what}: rows in order");
                            assert_eq!(values.len() % 300, 0, "{what}: whole rows");
                            rows.extend(bits(values));
                            Ok(())
                        })
                    })
                    .unwrap();
                assert_eq!(banded, stats, "{what}, {threads} threads, round {round}");
                assert!(
                    rows == expected,
                    "{what}, {threads} threads, round {round}: the rows differ from the image"
                );
            }
            // A drain's error comes back, and no row after it is handed over: the second
            // group fails (the first, when it holds the whole frame).
            let mut seen = Vec::new();
            let failed = pool.install(|| {
                context.render_in_bands(scene, &camera, 0.45, &options, &mut |y, values| {
                    seen.push(y);
                    if y > 0 || values.len() == 3 * 100 * 75 {
                        Err(splat4d::Error::Usage("stop".into()))
                    } else {
                        Ok(())
                    }
                })
            });
            assert!(failed.unwrap_err().to_string().contains("stop"), "{what}");
            let expected_calls = if threads == 3 { 1 } else { 2 };
            assert_eq!(
                seen.len(),
                expected_calls,
                "{what}, {threads} threads: {seen:?}"
            );
        }
    }
}
