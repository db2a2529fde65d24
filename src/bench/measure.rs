//! Timing one configuration: warm-up renders, then the median of timed renders on a pool of
//! the requested threads, and the error against the dense f64 reference
//! ([`crate::reference::reference_at_pixels`], or its alpha twin) at a seeded sample of
//! pixels: max and mean `|fast - ref|`, and the largest ratio to
//! [`ERROR_BOUND`] (`1e-6 + 2e-6·Σ|a|`; the alpha blend has no `Σ|a|`, its ratio is to the
//! same formula at `Σ = 1`). The seed-style dense evaluation ([`crate::reference::dense`])
//! is timed the same way as a baseline; each row's share of its blend's ceiling probe
//! ([`super::ceiling`]) is filled in from the same run.

use std::time::Instant;

use rand::RngExt;

use crate::model::camera::Camera;
use crate::model::error::{Error, Result};
use crate::model::random::seeded_rng;
use crate::model::scene::Scene;
use crate::model::{Blend, Image};
use crate::reference::composite::reference_alpha_at_pixels;
use crate::reference::dense::dense_render;
use crate::reference::{ERROR_BOUND, reference_at_pixels};
use crate::render::{RenderContext, RenderOptions};

/// Which renderer a row measures.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Renderer {
    /// The tile renderer ([`RenderContext`]).
    Tiles,
    /// The seed-style dense evaluation ([`dense_render`]), every kernel at every pixel.
    Dense,
}

impl std::fmt::Display for Renderer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Renderer::Tiles => "tiles",
            Renderer::Dense => "dense",
        })
    }
}

/// One measured configuration.
#[derive(Clone, Debug, PartialEq)]
pub struct BenchRow {
    /// Scene name.
    pub scene: String,
    /// The scene's blend (which ceiling probe the row is a share of).
    pub blend: Blend,
    /// Renderer measured.
    pub renderer: Renderer,
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
    /// Largest ratio of `|fast - ref|` to [`ERROR_BOUND`].
    pub bound_ratio: f64,
    /// For tile rows: the dense baseline's time over this row's, when it was measured.
    pub speedup: Option<f64>,
    /// `pairs_per_second` over the pairs per second of the blend's ceiling probe
    /// ([`super::ceiling::Probe::of`]) on the same threads in the same run, when it was measured.
    pub efficiency: Option<f64>,
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

/// A pool of `threads` workers.
pub(crate) fn thread_pool(threads: usize) -> Result<rayon::ThreadPool> {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads.max(1))
        .build()
        .map_err(|e| Error::Usage(format!("cannot start {threads} threads: {e}")))
}

/// `samples` pixels of `camera`'s frame, the same for every configuration.
pub(crate) fn sample_pixels(camera: &Camera, samples: usize) -> Vec<(u32, u32)> {
    let mut rng = seeded_rng(7);
    (0..samples)
        .map(|_| {
            (
                rng.random_range(0..camera.width),
                rng.random_range(0..camera.height),
            )
        })
        .collect()
}

/// The f64 reference's colour and `Σ|a|` at `pixels`, for the scene's blend. The alpha blend
/// has no `Σ|a|` bound: its bound column is against the tests' absolute tolerance,
/// [`ERROR_BOUND`] at `Σ = 1`.
pub(crate) fn reference_colours(
    scene: &Scene,
    camera: &Camera,
    tau: f64,
    options: &RenderOptions,
    pixels: &[(u32, u32)],
) -> Vec<([f64; 3], [f64; 3])> {
    match scene.blend {
        Blend::Additive => reference_at_pixels(scene, camera, tau, options, pixels),
        Blend::Alpha => reference_alpha_at_pixels(scene, camera, tau, options, pixels)
            .into_iter()
            .map(|colour| (colour, [1.0; 3]))
            .collect(),
    }
}

/// `|image - reference|` at `pixels`: max, mean, and the largest ratio to the bound.
pub(crate) fn errors(
    image: &Image,
    pixels: &[(u32, u32)],
    reference: &[([f64; 3], [f64; 3])],
) -> [f64; 3] {
    let (mut max_error, mut sum, mut bound_ratio) = (0.0_f64, 0.0, 0.0_f64);
    for (&(i, j), (colour, abs_sum)) in pixels.iter().zip(reference) {
        let fast = image.pixel(i, j);
        for c in 0..3 {
            let error = (f64::from(fast[c]) - colour[c]).abs();
            max_error = max_error.max(error);
            sum += error;
            bound_ratio = bound_ratio.max(error / ERROR_BOUND.at(abs_sum[c]));
        }
    }
    [
        max_error,
        sum / (3 * pixels.len().max(1)) as f64,
        bound_ratio,
    ]
}

/// Renders `frames` times after `warm_up` renders; returns the median seconds and the pairs
/// of the last frame.
pub(crate) fn time_frames(
    pool: &rayon::ThreadPool,
    warm_up: usize,
    frames: usize,
    mut render: impl FnMut() -> Result<u64> + Send,
) -> Result<(f64, u64)> {
    let mut times = Vec::with_capacity(frames);
    let mut pairs = 0;
    pool.install(|| -> Result<()> {
        for _ in 0..warm_up {
            render()?;
        }
        for _ in 0..frames.max(1) {
            let start = Instant::now();
            pairs = render()?;
            times.push(start.elapsed().as_secs_f64());
        }
        Ok(())
    })?;
    times.sort_by(f64::total_cmp);
    Ok((times[times.len() / 2], pairs))
}

/// Times renders of `scene` through `camera` with `renderer` and measures the error at
/// seeded pixels. The dense baseline is timed over `min(frames, 2)` frames without warm-up:
/// it is slow and its time does not depend on caches warming.
pub fn bench_render(
    name: &str,
    scene: &Scene,
    camera: &Camera,
    settings: &BenchSettings,
    renderer: Renderer,
) -> Result<BenchRow> {
    let BenchSettings {
        tau,
        options,
        threads,
        frames,
        samples,
    } = *settings;
    let options = &options;
    let pool = thread_pool(threads)?;
    let mut context = RenderContext::new();
    let mut dense_image = Image::default();
    let (median, pairs) = match renderer {
        Renderer::Tiles => time_frames(&pool, 2, frames, || {
            Ok(context.render(scene, camera, tau, options)?.pairs)
        })?,
        Renderer::Dense => time_frames(&pool, 0, frames.min(2), || {
            let (image, pairs) = dense_render(scene, camera, tau, options)?;
            dense_image = image;
            Ok(pairs)
        })?,
    };
    let pixels = sample_pixels(camera, samples);
    let reference = reference_colours(scene, camera, tau, options, &pixels);
    let image = match renderer {
        Renderer::Tiles => context.image(),
        Renderer::Dense => &dense_image,
    };
    let [max_error, mean_error, bound_ratio] = errors(image, &pixels, &reference);
    Ok(BenchRow {
        scene: name.to_owned(),
        blend: scene.blend,
        renderer,
        kernels: scene.len(),
        size: (camera.width, camera.height),
        threads,
        ms_per_frame: 1e3 * median,
        pairs,
        pairs_per_second: pairs as f64 / median,
        max_error,
        mean_error,
        bound_ratio,
        speedup: None,
        efficiency: None,
    })
}

/// Fills each tile row's `speedup` from the dense row of the same scene, size and threads.
pub fn fill_speedups(rows: &mut [BenchRow]) {
    let dense: Vec<(String, (u32, u32), usize, f64)> = rows
        .iter()
        .filter(|r| r.renderer == Renderer::Dense)
        .map(|r| (r.scene.clone(), r.size, r.threads, r.ms_per_frame))
        .collect();
    for row in rows.iter_mut().filter(|r| r.renderer == Renderer::Tiles) {
        row.speedup = dense
            .iter()
            .find(|d| d.0 == row.scene && d.1 == row.size && d.2 == row.threads)
            .map(|d| d.3 / row.ms_per_frame);
    }
}
