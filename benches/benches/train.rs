//! One training step on the seeded bench scenes (10k, 100k and 1M kernels at 512×512 and
//! 1920×1080, 1 and 2 threads): forward, backward (after a forward), and the whole step
//! (forward + loss + backward + Adam), as `train_WxH/{forward,backward,step}/N/Tt`. Prints
//! backward time over forward time per scene. Machine and flags: `benches/README.md`.
//! Filter to run a part: `cargo bench -p splat4d-benches --bench train -- train_512x512`.

use std::time::Instant;

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use splat4d::fit::adam::{Adam, AdamConfig};
use splat4d::fit::additive::{AdditiveFitOptions, LearningRates};
use splat4d::fit::loss::mse_with_gradient;
use splat4d::scenes::synthetic::{bench_camera, bench_scene};
use splat4d::{Gradients, RenderContext, RenderOptions};

const SIZES: [usize; 3] = [10_000, 100_000, 1_000_000];
const FRAMES: [(u32, u32); 2] = [(512, 512), (1920, 1080)];
const THREADS: [usize; 2] = [1, 2];
const TAU: f64 = 0.5;

fn training_step(c: &mut Criterion) {
    for (w, h) in FRAMES {
        training_step_at(c, w, h);
    }
}

fn training_step_at(c: &mut Criterion, w: u32, h: u32) {
    let camera = bench_camera(w, h);
    let options = RenderOptions::default();
    let groups = AdditiveFitOptions {
        learning_rates: LearningRates {
            mean: 1e-3,
            time: 1e-3,
            amplitude: 1e-3,
            velocity: 1e-3,
            scale: 0.0,
            background: 0.0,
        },
        ..AdditiveFitOptions::default()
    }
    .groups();
    let mut group = c.benchmark_group(format!("train_{w}x{h}"));
    group.sample_size(10);
    for n in SIZES {
        let scene = bench_scene(n, 42);
        let mut context = RenderContext::new();
        // Target: the same scene at another time, so residuals are non-zero everywhere.
        context.render(&scene, &camera, 0.3, &options).unwrap();
        let target = context.image().clone();
        let stats = context
            .render_for_backward(&scene, &camera, TAU, &options)
            .unwrap();
        let mut v_image = Vec::new();
        mse_with_gradient(context.image(), &target, 1.0, &mut v_image);
        let mut grads = Gradients::zeros(n);
        group.throughput(Throughput::Elements(stats.pairs));

        // Backward over forward, measured directly as well (criterion reports each alone).
        let repeats = (2_000_000 / n).clamp(3, 200);
        let start = Instant::now();
        for _ in 0..repeats {
            context
                .render_for_backward(&scene, &camera, TAU, &options)
                .unwrap();
        }
        let forward = start.elapsed().as_secs_f64() / repeats as f64;
        let start = Instant::now();
        for _ in 0..repeats {
            context.backward(&scene, &camera, TAU, &options, &v_image, &mut grads);
        }
        let backward = start.elapsed().as_secs_f64() / repeats as f64;
        eprintln!(
            "{n} kernels at {w}x{h}: {} pairs; forward {:.2} ms, backward {:.2} ms, backward/forward = {:.2}",
            stats.pairs,
            1e3 * forward,
            1e3 * backward,
            backward / forward
        );

        for threads in THREADS {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let id = |what: &str| BenchmarkId::new(format!("{what}/{n}"), format!("{threads}t"));
            group.bench_function(id("forward"), |b| {
                pool.install(|| {
                    b.iter(|| {
                        context
                            .render_for_backward(&scene, &camera, TAU, &options)
                            .unwrap()
                    })
                })
            });
            group.bench_function(id("backward"), |b| {
                pool.install(|| {
                    b.iter(|| {
                        context.backward(&scene, &camera, TAU, &options, &v_image, &mut grads)
                    })
                })
            });
            let mut fitted = scene.clone();
            let mut adam = Adam::new(&scene, &groups, AdamConfig::default());
            group.bench_function(id("step"), |b| {
                pool.install(|| {
                    b.iter(|| {
                        context
                            .render_for_backward(&fitted, &camera, TAU, &options)
                            .unwrap();
                        mse_with_gradient(context.image(), &target, 1.0, &mut v_image);
                        grads.reset(n);
                        context.backward(&fitted, &camera, TAU, &options, &v_image, &mut grads);
                        adam.step(&mut fitted, &grads, 1, 1.0);
                    })
                })
            });
        }
    }
    group.finish();
}

criterion_group!(benches, training_step);
criterion_main!(benches);
