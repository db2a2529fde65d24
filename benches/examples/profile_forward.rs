//! Renders the 100k-kernel bench scene repeatedly, for profilers (perf, callgrind):
//! `cargo run --profile profiling -p splat4d-benches --example profile_forward -- [kernels] [frames] [std|poly] [width] [height]`.

use splat4d::scenes::synthetic::{bench_camera, bench_scene};
use splat4d::{RenderContext, RenderOptions};

fn main() {
    let mut args = std::env::args().skip(1);
    let kernels: usize = args.next().and_then(|a| a.parse().ok()).unwrap_or(100_000);
    let frames: usize = args.next().and_then(|a| a.parse().ok()).unwrap_or(10);
    let options = RenderOptions {
        exp: args.next().and_then(|a| a.parse().ok()).unwrap_or_default(),
        ..RenderOptions::default()
    };
    let width: u32 = args.next().and_then(|a| a.parse().ok()).unwrap_or(512);
    let height: u32 = args.next().and_then(|a| a.parse().ok()).unwrap_or(512);
    let scene = bench_scene(kernels, 42);
    let camera = bench_camera(width, height);
    let mut context = RenderContext::new();
    let start = std::time::Instant::now();
    let mut pairs = 0;
    for _ in 0..frames {
        pairs += context
            .render(&scene, &camera, 0.5, &options)
            .unwrap()
            .pairs;
    }
    let seconds = start.elapsed().as_secs_f64();
    println!(
        "{kernels} kernels, {frames} frames: {:.1} ms/frame, {:.0} M pairs/s",
        1e3 * seconds / frames as f64,
        pairs as f64 / seconds / 1e6
    );
}
