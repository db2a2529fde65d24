//! Forward render of seeded bench scenes (`splat4d::scenes::synthetic::bench_scene`): 10k, 100k and
//! 1M kernels at 512×512 and 1920×1080 on 1 and 2 threads (`forward_WxH/render/N/Tt`), the
//! seed-style dense baseline (`dense_512x512`), one group per stage (`stages_512x512`) and the
//! temporal index. Throughput is kernel-pixel pairs per second (criterion's "elem/s" is
//! pairs/s here; for the dense baseline, pairs evaluated). Machine and flags:
//! `benches/README.md`. Filter to run a part: `cargo bench -p splat4d-benches --bench forward -- forward_512`.

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use splat4d::project::project;
use splat4d::reference::dense::dense_render;
use splat4d::scenes::synthetic::{bench_camera, bench_scene, bench_scene_in_time};
use splat4d::slice::TemporalIndex;
use splat4d::slice::slice;
use splat4d::tiles::bin;
use splat4d::{RenderContext, RenderOptions};

const SIZES: [usize; 3] = [10_000, 100_000, 1_000_000];
const FRAMES: [(u32, u32); 2] = [(512, 512), (1920, 1080)];
const THREADS: [usize; 2] = [1, 2];
const TAU: f64 = 0.5;

fn pool(threads: usize) -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap()
}

fn forward(c: &mut Criterion) {
    let options = RenderOptions::default();
    let scenes: Vec<_> = SIZES.iter().map(|&n| (n, bench_scene(n, 42))).collect();
    for (w, h) in FRAMES {
        let camera = bench_camera(w, h);
        let mut group = c.benchmark_group(format!("forward_{w}x{h}"));
        group.sample_size(10);
        for (n, scene) in &scenes {
            let mut context = RenderContext::new();
            let stats = context.render(scene, &camera, TAU, &options).unwrap();
            eprintln!(
                "{n} kernels at {w}x{h}: {} on screen, {} tile entries, {} pairs",
                stats.projected, stats.tile_entries, stats.pairs
            );
            group.throughput(Throughput::Elements(stats.pairs));
            for threads in THREADS {
                let pool = pool(threads);
                group.bench_function(
                    BenchmarkId::new(format!("render/{n}"), format!("{threads}t")),
                    |b| {
                        pool.install(|| {
                            b.iter(|| context.render(scene, &camera, TAU, &options).unwrap())
                        })
                    },
                );
            }
        }
        group.finish();
    }
}

/// The seed-style dense evaluation (every kernel at every pixel) against which the tile
/// renderer's speed-up is quoted; 2 threads.
fn dense_baseline(c: &mut Criterion) {
    let camera = bench_camera(512, 512);
    let options = RenderOptions::default();
    let mut group = c.benchmark_group("dense_512x512");
    group.sample_size(10);
    for n in [1_000, 10_000] {
        let scene = bench_scene(n, 42);
        group.throughput(Throughput::Elements(n as u64 * 512 * 512));
        group.bench_function(BenchmarkId::new("dense", n), |b| {
            b.iter(|| dense_render(&scene, &camera, TAU, &options).unwrap())
        });
    }
    group.finish();
}

fn stages(c: &mut Criterion) {
    let camera = bench_camera(512, 512);
    let options = RenderOptions::default();
    let mut group = c.benchmark_group("stages_512x512");
    group.sample_size(20);
    for n in [1_000, 10_000, 100_000] {
        let scene = bench_scene(n, 42);
        let mut context = RenderContext::new();
        // Rendered for a backward: the context keeps the slices `project` reads.
        context
            .render_for_backward(&scene, &camera, TAU, &options)
            .unwrap();
        group.throughput(Throughput::Elements(n as u64));
        group.bench_function(BenchmarkId::new("slice", n), |b| {
            b.iter(|| slice(&scene, TAU, options.cutoff, &mut context.sliced))
        });
        group.bench_function(BenchmarkId::new("project", n), |b| {
            b.iter(|| {
                project(
                    &context.sliced,
                    &camera,
                    options.dilation,
                    &mut context.projected,
                )
            })
        });
        group.bench_function(BenchmarkId::new("bin", n), |b| {
            b.iter(|| {
                bin(
                    &context.projected,
                    camera.width,
                    camera.height,
                    &mut context.bins,
                )
            })
        });
    }
    group.finish();
}

/// Frame cost against the kernels alive (issue: a temporal index): the 10k scene, all
/// alive, against a 1M-kernel scene with about 1% alive at τ, with and without the index.
fn temporal_index(c: &mut Criterion) {
    let camera = bench_camera(512, 512);
    let options = RenderOptions::default();
    let dense = bench_scene(10_000, 42);
    let sparse = bench_scene_in_time(1_000_000, 42, 130.0);
    let tau = 65.0;
    let index = TemporalIndex::new(&sparse, options.cutoff);
    let mut context = RenderContext::new();
    let alive = context
        .render(&sparse, &camera, tau, &options)
        .unwrap()
        .sliced;
    eprintln!("1M kernels over 130 time units: {alive} alive at τ = {tau}");
    let mut group = c.benchmark_group("temporal_index_512x512");
    group.sample_size(10);
    group.bench_function("10k_all_alive", |b| {
        b.iter(|| context.render(&dense, &camera, TAU, &options).unwrap())
    });
    group.bench_function("1M_1pct_alive_indexed", |b| {
        b.iter(|| {
            context
                .render_indexed(&sparse, &index, &camera, tau, &options)
                .unwrap()
        })
    });
    group.bench_function("1M_1pct_alive_plain", |b| {
        b.iter(|| context.render(&sparse, &camera, tau, &options).unwrap())
    });
    group.finish();
}

criterion_group!(benches, forward, dense_baseline, stages, temporal_index);
criterion_main!(benches);
