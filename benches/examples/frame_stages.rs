//! Times each stage of a warm forward frame of the bench scene on a pool of N threads (the
//! calling thread one of them, as `splat4d render --threads N` runs): medians over the
//! frames, in ms. `cargo run --release -p splat4d-benches --example frame_stages --
//! [kernels] [frames] [threads] [width] [height]`.

use std::time::Instant;

use splat4d::project::{ProjectedKernels, project};
use splat4d::raster::{TileScratchPool, rasterize};
use splat4d::scenes::synthetic::{bench_camera, bench_scene};
use splat4d::simd::{BinnedFrame, ExpMode};
use splat4d::slice::{SlicedKernels, slice};
use splat4d::tiles::{TileBins, bin};
use splat4d::{Image, RenderContext, RenderOptions};

fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(f64::total_cmp);
    values[values.len() / 2]
}

fn main() {
    let mut args = std::env::args().skip(1);
    let mut next = |default: usize| args.next().and_then(|a| a.parse().ok()).unwrap_or(default);
    let (kernels, frames, threads) = (next(10_000), next(200).max(1), next(1).max(1));
    let (width, height) = (next(512) as u32, next(512) as u32);
    let scene = bench_scene(kernels, 42);
    let camera = bench_camera(width, height);
    let options = RenderOptions::default();
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .use_current_thread()
        .build()
        .expect("a thread pool");
    pool.install(|| {
        let (mut sliced, mut projected, mut bins) = (
            SlicedKernels::default(),
            ProjectedKernels::default(),
            TileBins::default(),
        );
        let (mut forms, scratch, mut image) = (Vec::new(), TileScratchPool::default(), Image::default());
        let mut context = RenderContext::new();
        let names = ["slice", "project", "bin", "raster", "stages", "render"];
        let mut times = vec![Vec::new(); names.len()];
        // Ten frames first, so that every buffer has its size.
        for frame in 0..frames + 10 {
            let t0 = Instant::now();
            slice(&scene, 0.5, options.cutoff, &mut sliced);
            let t1 = Instant::now();
            project(&sliced, &camera, options.dilation, &mut projected);
            let t2 = Instant::now();
            bin(&projected, camera.width, camera.height, &mut bins);
            let t3 = Instant::now();
            let background = scene.background.map(|b| b as f32);
            let binned = BinnedFrame::new(&projected, &bins, &mut forms, background, ExpMode::Poly);
            rasterize(&binned, &scratch, &mut image);
            let t4 = Instant::now();
            context
                .render(&scene, &camera, 0.5, &options)
                .expect("a render");
            let t5 = Instant::now();
            if frame >= 10 {
                let spans = [t1 - t0, t2 - t1, t3 - t2, t4 - t3, t4 - t0, t5 - t4];
                for (time, span) in times.iter_mut().zip(spans) {
                    time.push(span.as_secs_f64() * 1e3);
                }
            }
        }
        let line: Vec<String> = names
            .iter()
            .zip(times)
            .map(|(name, time)| format!("{name} {:.3}", median(time)))
            .collect();
        println!(
            "{kernels} kernels, {width}x{height}, {threads} threads, medians of {frames} warm frames (ms): {}",
            line.join(", ")
        );
    });
}
