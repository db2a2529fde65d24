//! `splat4d bench`: forward-render speed with its error against the f64 reference.
//!
//! Each configuration renders a few warm-up frames, then times `frames` renders (median
//! ms per frame) on a pool of the requested threads. The error is measured against the dense
//! f64 reference ([`crate::reference::reference_at_pixels`]) at a seeded sample of pixels:
//! max and mean `|fast - ref|`, and the largest ratio to the documented bound
//! `1e-6 + 2e-6 Σ|a|` (band pairs aside).

use std::time::Instant;

use rand::RngExt;

use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::reference::reference_at_pixels;
use crate::render::{RenderContext, RenderOptions};
use crate::scene::Scene;
use crate::synthetic::seeded_rng;

/// One measured configuration.
#[derive(Clone, Debug, PartialEq)]
pub struct BenchRow {
    /// Scene name.
    pub scene: String,
    /// Kernels in the scene.
    pub kernels: usize,
    /// Image size.
    pub size: (u32, u32),
    /// Worker threads.
    pub threads: usize,
    /// Median milliseconds per frame.
    pub ms_per_frame: f64,
    /// Kernel-pixel pairs per frame.
    pub pairs: u64,
    /// Pairs per second at the median.
    pub pairs_per_second: f64,
    /// Largest `|fast - ref|` over the sampled pixels and channels.
    pub max_error: f64,
    /// Mean `|fast - ref|`.
    pub mean_error: f64,
    /// Largest ratio of `|fast - ref|` to `1e-6 + 2e-6 Σ|a|`.
    pub bound_ratio: f64,
}

/// How to measure one configuration.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BenchSettings {
    /// Scene time τ.
    pub tau: f64,
    /// Rendering options.
    pub options: RenderOptions,
    /// Worker threads.
    pub threads: usize,
    /// Timed frames (the median is reported).
    pub frames: usize,
    /// Pixels sampled for the error.
    pub samples: usize,
}

/// Times renders of `scene` through `camera` and measures the error at seeded pixels.
pub fn bench_render(
    name: &str,
    scene: &Scene,
    camera: &Camera,
    settings: &BenchSettings,
) -> Result<BenchRow> {
    let BenchSettings {
        tau,
        options,
        threads,
        frames,
        samples,
    } = *settings;
    let options = &options;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads.max(1))
        .build()
        .map_err(|e| Error::Usage(format!("cannot start {threads} threads: {e}")))?;
    let mut context = RenderContext::new();
    let mut times = Vec::with_capacity(frames);
    let mut pairs = 0;
    pool.install(|| -> Result<()> {
        for _ in 0..2 {
            context.render(scene, camera, tau, options)?;
        }
        for _ in 0..frames.max(1) {
            let start = Instant::now();
            pairs = context.render(scene, camera, tau, options)?.pairs;
            times.push(start.elapsed().as_secs_f64());
        }
        Ok(())
    })?;
    times.sort_by(f64::total_cmp);
    let median = times[times.len() / 2];
    let mut rng = seeded_rng(7);
    let pixels: Vec<(u32, u32)> = (0..samples)
        .map(|_| {
            (
                rng.random_range(0..camera.width),
                rng.random_range(0..camera.height),
            )
        })
        .collect();
    let reference = reference_at_pixels(scene, camera, tau, options, &pixels);
    let image = context.image();
    let (mut max_error, mut sum, mut bound_ratio) = (0.0_f64, 0.0, 0.0_f64);
    for (&(i, j), (colour, abs_sum)) in pixels.iter().zip(&reference) {
        let fast = image.pixel(i, j);
        for c in 0..3 {
            let error = (f64::from(fast[c]) - colour[c]).abs();
            max_error = max_error.max(error);
            sum += error;
            bound_ratio = bound_ratio.max(error / (1e-6 + 2e-6 * abs_sum[c]));
        }
    }
    Ok(BenchRow {
        scene: name.to_owned(),
        kernels: scene.len(),
        size: (camera.width, camera.height),
        threads,
        ms_per_frame: 1e3 * median,
        pairs,
        pairs_per_second: pairs as f64 / median,
        max_error,
        mean_error: sum / (3 * pixels.len().max(1)) as f64,
        bound_ratio,
    })
}

/// The rows as a table a user can read.
#[must_use]
pub fn format_table(rows: &[BenchRow]) -> String {
    let mut out = format!(
        "{:<18} {:>9} {:>11} {:>7} {:>10} {:>12} {:>12} {:>10} {:>10} {:>7}\n",
        "scene",
        "kernels",
        "size",
        "threads",
        "ms/frame",
        "pairs/frame",
        "pairs/s",
        "max err",
        "mean err",
        "/bound"
    );
    for r in rows {
        out.push_str(&format!(
            "{:<18} {:>9} {:>11} {:>7} {:>10.2} {:>12} {:>12.3e} {:>10.2e} {:>10.2e} {:>7.3}\n",
            r.scene,
            r.kernels,
            format!("{}x{}", r.size.0, r.size.1),
            r.threads,
            r.ms_per_frame,
            r.pairs,
            r.pairs_per_second,
            r.max_error,
            r.mean_error,
            r.bound_ratio
        ));
    }
    out
}
