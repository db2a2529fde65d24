//! A training step's time against the forward's on the same scene, in one run: the seeded
//! bench scene (as `splat4d bench` and the `train` criterion bench), warm, on the current
//! thread pool. Each round times a forward alone, then a whole step as the fit runs one
//! (zeroing the gradients, the render and its backward in one pass over the tiles with the
//! MSE's gradient, the loss, Adam), its parts timed too, then the same step with the render,
//! the loss's gradient and the backward one after the other; the medians over rounds are
//! printed with the steps over the forward, in wall time and in CPU time of all threads
//! (which waiting for a busy core does not move).
//!
//! `cargo run --release -p splat4d-benches --example train_speed -- [KERNELS] [WxH] [THREADS] [ROUNDS]`
//! (default `10000 512x512 2 15`).

use std::time::Instant;

use splat4d::fit::adam::{Adam, AdamConfig};
use splat4d::fit::additive::{AdditiveFitOptions, LearningRates};
use splat4d::fit::loss::{mse, mse_with_gradient};
use splat4d::scenes::synthetic::{bench_camera, bench_scene};
use splat4d::{Gradients, RenderContext, RenderOptions};

const TAU: f64 = 0.5;

/// CPU seconds of the whole process (every thread) so far: on a shared machine the ratio of
/// CPU times is not moved by time spent waiting for a core.
fn cpu_seconds() -> f64 {
    let mut usage = std::mem::MaybeUninit::<libc::rusage>::uninit();
    // SAFETY: `getrusage` fills the struct it is given.
    let usage = unsafe {
        libc::getrusage(libc::RUSAGE_SELF, usage.as_mut_ptr());
        usage.assume_init()
    };
    let seconds = |t: libc::timeval| t.tv_sec as f64 + 1e-6 * t.tv_usec as f64;
    seconds(usage.ru_utime) + seconds(usage.ru_stime)
}

fn median(mut times: Vec<f64>) -> f64 {
    times.sort_by(f64::total_cmp);
    1e3 * times[times.len() / 2]
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let n: usize = args
        .get(1)
        .map_or(10_000, |a| a.parse().expect("a kernel count"));
    let (w, h) = args.get(2).map_or((512, 512), |a| {
        let (w, h) = a.split_once('x').expect("WxH");
        (w.parse().expect("width"), h.parse().expect("height"))
    });
    let threads: usize = args
        .get(3)
        .map_or(2, |a| a.parse().expect("a thread count"));
    let rounds: usize = args
        .get(4)
        .map_or(15, |a| a.parse().expect("a round count"));
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
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
    let scene = bench_scene(n, 42);
    let mut context = RenderContext::new();
    let mut v_image = Vec::new();
    let mut grads = Gradients::zeros(n);
    let mut fitted = scene.clone();
    let mut adam = Adam::new(&scene, &groups, AdamConfig::default());
    // [forward alone, step, its zeroing, render and backward, loss, Adam, separate step]
    let mut times: [Vec<f64>; 7] = Default::default();
    // CPU seconds of [forward alone, step, its render and backward, separate step].
    let mut cpu: [Vec<f64>; 4] = Default::default();
    let pairs = pool.install(|| {
        // The target: the scene at another time, so residuals are non-zero everywhere.
        context.render(&scene, &camera, 0.3, &options).unwrap();
        let target = context.image().clone();
        // The MSE's gradient as `mse_with_gradient` computes it, run by run.
        let scale = (2.0 / target.pixels.len() as f64) as f32;
        let gradient = |first: usize, rendered: &[f32], v: &mut [f32]| {
            for ((v, &c), &t) in v.iter_mut().zip(rendered).zip(&target.pixels[first..]) {
                *v = scale * (c - t);
            }
        };
        let pairs = context
            .render(&scene, &camera, TAU, &options)
            .unwrap()
            .pairs;
        for round in 0..=rounds {
            let (start, cpu_start) = (Instant::now(), cpu_seconds());
            context.render(&fitted, &camera, TAU, &options).unwrap();
            let forward = start.elapsed().as_secs_f64();
            let cpu_forward = cpu_seconds() - cpu_start;
            // A step as the fit runs it: the render and its backward in one pass over the
            // tiles, the loss, Adam.
            let cpu_step = cpu_seconds();
            let mut marks = [Instant::now(); 5];
            grads.reset(n);
            marks[1] = Instant::now();
            let cpu_fused = cpu_seconds();
            context
                .render_and_backward(
                    &fitted,
                    &camera,
                    TAU,
                    &options,
                    &gradient,
                    &mut v_image,
                    &mut grads,
                )
                .unwrap();
            marks[2] = Instant::now();
            let cpu_fused = cpu_seconds() - cpu_fused;
            std::hint::black_box(mse(context.image(), &target));
            marks[3] = Instant::now();
            adam.step(&mut fitted, &grads, 1, 1.0);
            marks[4] = Instant::now();
            let cpu_step = cpu_seconds() - cpu_step;
            // The same step with the render and the backward one after the other.
            let (separate, cpu_separate) = (Instant::now(), cpu_seconds());
            grads.reset(n);
            context
                .render_for_backward(&fitted, &camera, TAU, &options)
                .unwrap();
            mse_with_gradient(context.image(), &target, 1.0, &mut v_image);
            context.backward(&fitted, &camera, TAU, &options, &v_image, &mut grads);
            adam.step(&mut fitted, &grads, 1, 1.0);
            let separate = separate.elapsed().as_secs_f64();
            let cpu_separate = cpu_seconds() - cpu_separate;
            if round == 0 {
                continue; // the first round warms every buffer
            }
            cpu[0].push(cpu_forward);
            cpu[1].push(cpu_step);
            cpu[2].push(cpu_fused);
            cpu[3].push(cpu_separate);
            times[0].push(forward);
            times[1].push((marks[4] - marks[0]).as_secs_f64());
            for part in 0..4 {
                times[2 + part].push((marks[part + 1] - marks[part]).as_secs_f64());
            }
            times[6].push(separate);
        }
        pairs
    });
    let [forward, step, zeroing, fused, loss, adam, separate] = times.map(median);
    let [cpu_forward, cpu_step, cpu_fused, cpu_separate] = cpu.map(median);
    println!(
        "{n} kernels at {w}x{h}, {threads} threads, {pairs} pairs (median of {rounds} warm rounds)"
    );
    println!(
        "forward {forward:.2} ms; step {step:.2} ms = step / forward {:.2} (render and backward one after the other: {separate:.2} ms = {:.2})",
        step / forward,
        separate / forward
    );
    println!(
        "step's parts: zeroing {zeroing:.2}, render and backward {fused:.2} ({:.2} × forward), loss {loss:.2}, Adam {adam:.2} ms",
        fused / forward
    );
    println!(
        "CPU time of all threads: forward {cpu_forward:.1} ms, step {cpu_step:.1} ms = step / forward {:.2} (one after the other: {:.2}), render and backward / forward {:.2}",
        cpu_step / cpu_forward,
        cpu_separate / cpu_forward,
        cpu_fused / cpu_forward
    );
}
