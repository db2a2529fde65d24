//! Forward render of seeded bench scenes (`splat4d::synthetic::bench_scene`) at 512×512:
//! one group per stage and end to end, throughput in kernel-pixel pairs per second
//! (criterion's "elem/s" is pairs/s here). Machine and flags: `benches/README.md`.

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use splat4d::project::project;
use splat4d::slice::TemporalIndex;
use splat4d::slice::slice;
use splat4d::synthetic::{bench_camera, bench_scene, bench_scene_in_time};
use splat4d::tiles::bin;
use splat4d::{RenderContext, RenderOptions};

const SIZES: [usize; 3] = [1_000, 10_000, 100_000];
const TAU: f64 = 0.5;

fn forward(c: &mut Criterion) {
    let camera = bench_camera(512, 512);
    let options = RenderOptions::default();
    let mut group = c.benchmark_group("forward_512x512");
    group.sample_size(20);
    for n in SIZES {
        let scene = bench_scene(n, 42);
        let mut context = RenderContext::new();
        let stats = context.render(&scene, &camera, TAU, &options).unwrap();
        eprintln!(
            "{n} kernels: {} on screen, {} tile entries, {} pairs",
            stats.projected, stats.tile_entries, stats.pairs
        );
        group.throughput(Throughput::Elements(stats.pairs));
        group.bench_with_input(BenchmarkId::new("render", n), &scene, |b, scene| {
            b.iter(|| context.render(scene, &camera, TAU, &options).unwrap())
        });
    }
    group.finish();
}

fn stages(c: &mut Criterion) {
    let camera = bench_camera(512, 512);
    let options = RenderOptions::default();
    let mut group = c.benchmark_group("stages_512x512");
    group.sample_size(20);
    for n in SIZES {
        let scene = bench_scene(n, 42);
        let mut context = RenderContext::new();
        context.render(&scene, &camera, TAU, &options).unwrap();
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

criterion_group!(benches, forward, stages, temporal_index);
criterion_main!(benches);
