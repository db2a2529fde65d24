//! The speed-against-error sweep: every combination of cut-off ε, dilation and exp
//! evaluation rendered on one scene, each timed (the median of its renders, over
//! [`SWEEP_ROUNDS`] interleaved rounds) and compared with the exact model, the f64
//! reference without truncation (ε = 0) at the default dilation (SPEC §4–5), and with the
//! reference at its own options (the implementation's error, as a ratio to
//! [`crate::reference::ERROR_BOUND`]). The points no other point beats in both time and
//! error form the Pareto front.

use crate::model::camera::Camera;
use crate::model::error::Result;
use crate::model::scene::Scene;
use crate::render::{DEFAULT_CUTOFF, DEFAULT_DILATION, RenderContext, RenderOptions};
use crate::simd::ExpMode;

use super::measure::{
    BenchSettings, errors, reference_colours, sample_pixels, thread_pool, time_frames,
};

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
