//! `splat4d bench`: forward-render speed with its error against the f64 reference.
//!
//! Each configuration renders a few warm-up frames, then times `frames` renders (median
//! ms per frame) on a pool of the requested threads. The error is measured against the dense
//! f64 reference ([`crate::reference::reference_at_pixels`]) at a seeded sample of pixels:
//! max and mean `|fast - ref|`, and the largest ratio to the documented bound
//! `1e-6 + 2e-6 Σ|a|` (band pairs aside). The seed-style dense evaluation
//! ([`crate::reference::dense`]) is timed the same way as a baseline, and [`sweep`] measures speed
//! against the error to the exact model over the cut-off, dilation and exp evaluation.

use std::time::Instant;

use rand::RngExt;

use crate::model::Blend;
use crate::model::camera::Camera;
use crate::model::error::{Error, Result};
use crate::model::random::seeded_rng;
use crate::model::scene::Scene;
use crate::reference::alpha::reference_alpha_at_pixels;
use crate::reference::dense::dense_render;
use crate::reference::reference_at_pixels;
use crate::render::{DEFAULT_CUTOFF, DEFAULT_DILATION, RenderContext, RenderOptions};
use crate::{model::Image, raster::ExpMode};

/// Which renderer a row measures.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Method {
    /// The tile renderer ([`RenderContext`]).
    Tiles,
    /// The seed-style dense evaluation ([`dense_render`]), every kernel at every pixel.
    Dense,
}

impl std::fmt::Display for Method {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Method::Tiles => "tiles",
            Method::Dense => "dense",
        })
    }
}

/// One measured configuration.
#[derive(Clone, Debug, PartialEq)]
pub struct BenchRow {
    /// Scene name.
    pub scene: String,
    /// Renderer measured.
    pub method: Method,
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
    /// For tile rows: the dense baseline's time over this row's, when it was measured.
    pub speedup: Option<f64>,
    /// `pairs_per_second` over the ceiling probe's pairs per second on the same threads in
    /// the same run ([`measure_ceiling`]), when it was measured.
    pub efficiency: Option<f64>,
}

/// The ceiling probe ([`crate::raster::ceiling_probe`]) on `threads` workers, each running
/// its own probe on the widest SIMD path: total pairs per second, the median of 3 runs of
/// about 0.2 s.
pub fn measure_ceiling(threads: usize) -> Result<f64> {
    use rayon::prelude::*;
    const KERNELS: usize = 256;
    let path = crate::raster::SimdPath::detect();
    let pool = thread_pool(threads)?;
    let run = |passes: usize| -> (f64, u64) {
        pool.install(|| {
            let start = Instant::now();
            let (pairs, checksum) = (0..threads.max(1))
                .into_par_iter()
                .map(|_| crate::raster::ceiling_probe(path, KERNELS, passes))
                .reduce(|| (0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
            std::hint::black_box(checksum);
            (start.elapsed().as_secs_f64(), pairs)
        })
    };
    let (seconds, _) = run(200);
    let passes = ((0.2 / seconds.max(1e-6)) * 200.0).clamp(200.0, 1e8) as usize;
    let mut rates: Vec<f64> = (0..3)
        .map(|_| {
            let (seconds, pairs) = run(passes);
            pairs as f64 / seconds
        })
        .collect();
    rates.sort_by(f64::total_cmp);
    Ok(rates[1])
}

/// Fills each row's `efficiency` from `ceilings` (pairs per second by thread count).
pub fn fill_efficiencies(rows: &mut [BenchRow], ceilings: &[(usize, f64)]) {
    for row in rows {
        row.efficiency = ceilings
            .iter()
            .find(|(threads, _)| *threads == row.threads)
            .map(|(_, ceiling)| row.pairs_per_second / ceiling);
    }
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
fn thread_pool(threads: usize) -> Result<rayon::ThreadPool> {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads.max(1))
        .build()
        .map_err(|e| Error::Usage(format!("cannot start {threads} threads: {e}")))
}

/// `samples` pixels of `camera`'s frame, the same for every configuration.
fn sample_pixels(camera: &Camera, samples: usize) -> Vec<(u32, u32)> {
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
/// `1e-6 + 2e-6` (the same formula with `Σ = 1`).
fn reference_colours(
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
fn errors(image: &Image, pixels: &[(u32, u32)], reference: &[([f64; 3], [f64; 3])]) -> [f64; 3] {
    let (mut max_error, mut sum, mut bound_ratio) = (0.0_f64, 0.0, 0.0_f64);
    for (&(i, j), (colour, abs_sum)) in pixels.iter().zip(reference) {
        let fast = image.pixel(i, j);
        for c in 0..3 {
            let error = (f64::from(fast[c]) - colour[c]).abs();
            max_error = max_error.max(error);
            sum += error;
            bound_ratio = bound_ratio.max(error / (1e-6 + 2e-6 * abs_sum[c]));
        }
    }
    [
        max_error,
        sum / (3 * pixels.len().max(1)) as f64,
        bound_ratio,
    ]
}

/// Renders `frames` times after `warm_up` renders; returns the median seconds, the pairs of
/// the last frame and its image.
fn time_frames(
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

/// Times renders of `scene` through `camera` with `method` and measures the error at seeded
/// pixels. The dense baseline is timed over `min(frames, 2)` frames without warm-up: it is
/// slow and its time does not depend on caches warming.
pub fn bench_render(
    name: &str,
    scene: &Scene,
    camera: &Camera,
    settings: &BenchSettings,
    method: Method,
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
    let (median, pairs) = match method {
        Method::Tiles => time_frames(&pool, 2, frames, || {
            Ok(context.render(scene, camera, tau, options)?.pairs)
        })?,
        Method::Dense => time_frames(&pool, 0, frames.min(2), || {
            let (image, pairs) = dense_render(scene, camera, tau, options)?;
            dense_image = image;
            Ok(pairs)
        })?,
    };
    let pixels = sample_pixels(camera, samples);
    let reference = reference_colours(scene, camera, tau, options, &pixels);
    let image = match method {
        Method::Tiles => context.image(),
        Method::Dense => &dense_image,
    };
    let [max_error, mean_error, bound_ratio] = errors(image, &pixels, &reference);
    Ok(BenchRow {
        scene: name.to_owned(),
        method,
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
        .filter(|r| r.method == Method::Dense)
        .map(|r| (r.scene.clone(), r.size, r.threads, r.ms_per_frame))
        .collect();
    for row in rows.iter_mut().filter(|r| r.method == Method::Tiles) {
        row.speedup = dense
            .iter()
            .find(|d| d.0 == row.scene && d.1 == row.size && d.2 == row.threads)
            .map(|d| d.3 / row.ms_per_frame);
    }
}

/// One point of the speed-against-error sweep.
#[derive(Clone, Debug, PartialEq)]
pub struct SweepPoint {
    /// Options rendered with.
    pub options: RenderOptions,
    /// Median milliseconds per frame.
    pub ms_per_frame: f64,
    /// Pairs per frame.
    pub pairs: u64,
    /// Largest `|fast - exact|` over the sampled pixels, `exact` being the f64 reference of
    /// the model without truncation at the default dilation ([`sweep`]).
    pub model_error: f64,
    /// Mean of the same.
    pub mean_model_error: f64,
    /// Largest ratio of `|fast - ref|` to the bound, `ref` being the f64 reference with the
    /// point's own options (the implementation's error).
    pub bound_ratio: f64,
    /// Not dominated: no other point is at least as fast and as accurate and better in one.
    pub pareto: bool,
}

/// The values the sweep visits.
#[derive(Clone, Debug, PartialEq)]
pub struct SweepGrid {
    /// Cut-offs ε.
    pub cutoffs: Vec<f64>,
    /// Dilations, px².
    pub dilations: Vec<f64>,
    /// Exp evaluations.
    pub exps: Vec<ExpMode>,
}

impl Default for SweepGrid {
    fn default() -> Self {
        SweepGrid {
            cutoffs: vec![1e-5, 1e-4, 1e-3, DEFAULT_CUTOFF, 1e-2, 3e-2],
            dilations: vec![0.0, 0.1, DEFAULT_DILATION],
            exps: ExpMode::ALL.to_vec(),
        }
    }
}

/// Rounds of [`sweep`]: every configuration is timed once per round, the rounds in turn, so
/// that a slow spell of a shared machine spreads over all of them instead of biasing a few.
pub const SWEEP_ROUNDS: usize = 3;

/// Measures every combination of `grid`: speed (the median of `frames` renders in each of
/// [`SWEEP_ROUNDS`] interleaved rounds) and the error against the exact model, the f64
/// reference with no truncation (ε = 0) and the default dilation (SPEC §4–5), at the same
/// seeded pixels. `progress` is called after each configuration of each round. Marks the
/// Pareto front of (ms per frame, max model error).
pub fn sweep(
    scene: &Scene,
    camera: &Camera,
    settings: &BenchSettings,
    grid: &SweepGrid,
    mut progress: impl FnMut(),
) -> Result<Vec<SweepPoint>> {
    let pool = thread_pool(settings.threads)?;
    let pixels = sample_pixels(camera, settings.samples);
    let exact_options = RenderOptions {
        cutoff: 0.0,
        dilation: DEFAULT_DILATION,
        exp: ExpMode::Std,
    };
    let exact = reference_colours(scene, camera, settings.tau, &exact_options, &pixels);
    let mut context = RenderContext::new();
    let mut points = Vec::new();
    for &dilation in &grid.dilations {
        for &cutoff in &grid.cutoffs {
            let own = RenderOptions {
                dilation,
                cutoff,
                exp: ExpMode::Std,
            };
            let reference = reference_colours(scene, camera, settings.tau, &own, &pixels);
            for &exp in &grid.exps {
                let options = RenderOptions { exp, ..own };
                let pairs = context.render(scene, camera, settings.tau, &options)?.pairs;
                let [model_error, mean_model_error, _] = errors(context.image(), &pixels, &exact);
                let [_, _, bound_ratio] = errors(context.image(), &pixels, &reference);
                points.push(SweepPoint {
                    options,
                    ms_per_frame: 0.0,
                    pairs,
                    model_error,
                    mean_model_error,
                    bound_ratio,
                    pareto: false,
                });
            }
        }
    }
    let mut medians = vec![Vec::with_capacity(SWEEP_ROUNDS); points.len()];
    for _ in 0..SWEEP_ROUNDS {
        for (point, times) in points.iter().zip(&mut medians) {
            let (median, _) = time_frames(&pool, 1, settings.frames, || {
                Ok(context
                    .render(scene, camera, settings.tau, &point.options)?
                    .pairs)
            })?;
            times.push(median);
            progress();
        }
    }
    for (point, times) in points.iter_mut().zip(&mut medians) {
        times.sort_by(f64::total_cmp);
        point.ms_per_frame = 1e3 * times[times.len() / 2];
    }
    mark_pareto_front(&mut points);
    Ok(points)
}

/// Marks the points no other point dominates in (ms per frame, max model error). Errors
/// within 1% of each other count as equal, so that two ways of computing the same image
/// (std and poly exp agree to ~1e-7) are told apart by their speed, not by rounding.
pub fn mark_pareto_front(points: &mut [SweepPoint]) {
    const SAME: f64 = 1.01;
    let key: Vec<(f64, f64)> = points
        .iter()
        .map(|p| (p.ms_per_frame, p.model_error))
        .collect();
    for (i, point) in points.iter_mut().enumerate() {
        let (t, e) = key[i];
        point.pareto = !key.iter().enumerate().any(|(k, &(t2, e2))| {
            let no_worse = t2 <= t && e2 <= e * SAME;
            let better = t2 < t || e2 * SAME < e;
            k != i && no_worse && better
        });
    }
}

/// The sweep as a markdown table, fastest first.
#[must_use]
pub fn sweep_table(points: &[SweepPoint]) -> String {
    let mut sorted: Vec<&SweepPoint> = points.iter().collect();
    sorted.sort_by(|a, b| a.ms_per_frame.total_cmp(&b.ms_per_frame));
    let mut out = String::from(
        "| ε | dilation | exp | ms/frame | pairs/frame | max error vs exact | mean error vs exact | /bound (own options) | Pareto |\n\
         |---:|---:|---|---:|---:|---:|---:|---:|:---:|\n",
    );
    for p in sorted {
        out.push_str(&format!(
            "| {:.3e} | {} | {} | {:.2} | {} | {:.3e} | {:.3e} | {:.3} | {} |\n",
            p.options.cutoff,
            p.options.dilation,
            p.options.exp,
            p.ms_per_frame,
            p.pairs,
            p.model_error,
            p.mean_model_error,
            p.bound_ratio,
            if p.pareto { "★" } else { "" }
        ));
    }
    out
}

/// The rows as a table a user can read.
#[must_use]
pub fn format_table(rows: &[BenchRow]) -> String {
    let mut out = format!(
        "{:<18} {:>9} {:>11} {:>7} {:>6} {:>10} {:>12} {:>12} {:>8} {:>10} {:>10} {:>7} {:>9}\n",
        "scene",
        "kernels",
        "size",
        "threads",
        "method",
        "ms/frame",
        "pairs/frame",
        "pairs/s",
        "ceiling",
        "max-err",
        "mean-err",
        "/bound",
        "speed-up"
    );
    for r in rows {
        out.push_str(&format!(
            "{:<18} {:>9} {:>11} {:>7} {:>6} {:>10.2} {:>12} {:>12.3e} {:>8} {:>10.2e} {:>10.2e} {:>7.3} {:>9}\n",
            r.scene,
            r.kernels,
            format!("{}x{}", r.size.0, r.size.1),
            r.threads,
            r.method.to_string(),
            r.ms_per_frame,
            r.pairs,
            r.pairs_per_second,
            r.efficiency
                .map_or("-".to_owned(), |e| format!("{:.1}%", 100.0 * e)),
            r.max_error,
            r.mean_error,
            r.bound_ratio,
            r.speedup.map_or("-".to_owned(), |x| format!("{x:.1}x"))
        ));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(ms: f64, error: f64) -> SweepPoint {
        SweepPoint {
            options: RenderOptions::default(),
            ms_per_frame: ms,
            pairs: 0,
            model_error: error,
            mean_model_error: error,
            bound_ratio: 0.0,
            pareto: false,
        }
    }

    #[test]
    fn pareto_front_keeps_the_undominated_points() {
        let mut points = vec![
            point(10.0, 1.0),
            point(20.0, 0.1),
            point(25.0, 0.2),     // dominated by (20, 0.1)
            point(21.0, 0.09995), // the same error as (20, 0.1) but slower
            point(40.0, 0.01),
            point(10.0, 2.0), // dominated by (10, 1)
        ];
        mark_pareto_front(&mut points);
        let front: Vec<bool> = points.iter().map(|p| p.pareto).collect();
        assert_eq!(front, [true, true, false, false, true, false]);
    }
}
