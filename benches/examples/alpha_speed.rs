//! The alpha blend's speed against the additive blend's on the same kernels, in one run:
//! the seeded bench scene at opacity 0.5 (as `splat4d bench --blend alpha`), forward and
//! backward (after a forward), median of `FRAMES` warm frames on the current thread pool.
//!
//! `cargo run --release -p splat4d-benches --example alpha_speed -- [KERNELS] [WxH] [THREADS]`
//! (default `100000 1920x1080 2`).

use std::time::Instant;

use splat4d::fit::loss::mse_with_gradient;
use splat4d::scenes::synthetic::{bench_camera, bench_scene};
use splat4d::{Gradients, RenderContext, RenderOptions, Scene};

const FRAMES: usize = 7;
const TAU: f64 = 0.5;

fn median(mut times: Vec<f64>) -> f64 {
    times.sort_by(f64::total_cmp);
    times[times.len() / 2]
}

/// Forward and backward milliseconds of `scene`.
fn measure(scene: &Scene, camera: &splat4d::Camera) -> (f64, f64) {
    let options = RenderOptions::default();
    let mut context = RenderContext::new();
    context.render(scene, camera, 0.3, &options).unwrap();
    let target = context.image().clone();
    context.render(scene, camera, TAU, &options).unwrap();
    let mut v_image = Vec::new();
    mse_with_gradient(context.image(), &target, 1.0, &mut v_image);
    let mut forward = Vec::new();
    let mut backward = Vec::new();
    for _ in 0..FRAMES {
        let start = Instant::now();
        context
            .render_for_backward(scene, camera, TAU, &options)
            .unwrap();
        forward.push(start.elapsed().as_secs_f64());
        let mut grads = Gradients::for_scene(scene);
        let start = Instant::now();
        context.backward(scene, camera, TAU, &options, &v_image, &mut grads);
        backward.push(start.elapsed().as_secs_f64());
    }
    (1e3 * median(forward), 1e3 * median(backward))
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let n: usize = args
        .get(1)
        .map_or(100_000, |a| a.parse().expect("a kernel count"));
    let (w, h) = args.get(2).map_or((1920, 1080), |a| {
        let (w, h) = a.split_once('x').expect("WxH");
        (w.parse().expect("width"), h.parse().expect("height"))
    });
    let threads: usize = args
        .get(3)
        .map_or(2, |a| a.parse().expect("a thread count"));
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    let camera = bench_camera(w, h);
    let additive = bench_scene(n, 42);
    let alpha = bench_scene(n, 42)
        .into_alpha(vec![0.5; n], 0, Vec::new(), "<bench>")
        .unwrap();
    let (add_forward, add_backward) = pool.install(|| measure(&additive, &camera));
    let (alpha_forward, alpha_backward) = pool.install(|| measure(&alpha, &camera));
    println!("{n} kernels at {w}x{h}, {threads} threads (median of {FRAMES} warm frames)");
    println!("additive: forward {add_forward:.1} ms, backward {add_backward:.1} ms");
    println!("alpha:    forward {alpha_forward:.1} ms, backward {alpha_backward:.1} ms");
    println!(
        "alpha forward / additive forward = {:.2}; alpha backward / alpha forward = {:.2}",
        alpha_forward / add_forward,
        alpha_backward / alpha_forward
    );
}
