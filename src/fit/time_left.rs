//! The time a running fit has left, from its steps so far and its schedule.
//!
//! A step's cost grows with the kernel count while the density rules add kernels, so a
//! linear extrapolation of the time per step promises a time that keeps growing (it was
//! off by up to half on a D-NeRF-like proxy). The estimate here models a step's duration as
//!
//! ```text
//! d = c (k + k0) m(n),    m(n) = n^(-2β),  β = 0.6
//! ```
//!
//! `k` kernels; a fixed cost `k0` (the images' pixels, the loss) expressed in kernels, taken
//! as the recent mean count — half the cost fixed, half per kernel, near what the alpha fits'
//! logs show (`docs/fitting.md`, "Time left"); and the stage's factor `m`: a step on views
//! downscaled by `n` ([`crate::fit::coarse`]) renders `n²` times fewer pixels and costs about
//! `n^(-1.2)` as much; a step on windows ([`crate::fit::window`]) renders the fraction `f`
//! of its views' pixels that one cell of their grid holds, and costs `f^β` as much, so
//! `m = (f / n²)^β` with `f` that of the first training view at the stage's size (a kernel's cost grows with its footprint less than linearly: the
//! D-NeRF-like proxy at 400×400 took 4.6, 19.8 and 69 ms a step at ¼, ½ and full size with
//! 3 100, 6 500 and 9 000 kernels, exponents 0.5 and 0.66 of the pixel ratio). `c` comes from
//! the recent window (the last tenth of the steps run, at least 50), each of its steps
//! weighted by its own `(k + k0) m(n)`; the kernel count is extrapolated along its recent
//! slope until the last step at which the density rules may add kernels (never beyond their
//! budget), and held after it (times the share the pruning by score keeps,
//! [`crate::fit::density::prune`], while that is still to come):
//!
//! ```text
//! left = c Σ_{s > now} (k(s) + k0) m(n(s))
//! ```

use crate::fit::coarse::{SizeStage, downscale_at};
use crate::fit::density::DensityRules;
use crate::fit::train::{StepRecord, Training};
use crate::fit::window::pixel_fraction;

/// Steps of the window the estimate reads, at least.
const MIN_WINDOW: usize = 50;

/// The exponent of the pixel count in a step's cost (see the module docs).
const PIXEL_EXPONENT: f64 = 0.6;

/// The cost of a step on views downscaled by `n` (and windowed by `window`, of views of
/// `size` at full size), relative to whole views at full size.
fn stage_cost(n: u32, window: Option<u32>, [width, height]: [u32; 2]) -> f64 {
    let n = n.max(1);
    let fraction = pixel_fraction(window, (width / n).max(1), (height / n).max(1));
    (fraction / f64::from(n).powi(2)).powf(PIXEL_EXPONENT)
}

/// The estimate of a running fit's time left (see the module docs).
#[derive(Clone, Debug)]
pub struct TimeLeft {
    steps: usize,
    /// The last step at which kernels may be added (0: never).
    growth_ends: usize,
    /// The density rules' budget.
    max_kernels: usize,
    /// The share of the kernels the pruning by score keeps once growth ends (1: none).
    kept_after_growth: f64,
    /// The coarse stages.
    stages: Vec<SizeStage>,
    /// The steps' window side, and the size of the views it cuts (at full size).
    window: (Option<u32>, [u32; 2]),
    /// `(seconds, kernels, downscale)` after each step so far.
    history: Vec<(f64, usize, u32)>,
}

impl TimeLeft {
    /// The estimate for a fit that runs `training` on views of `view_size` (width, height;
    /// the first training view's).
    #[must_use]
    pub fn new(training: &Training, view_size: [u32; 2]) -> Self {
        TimeLeft {
            steps: training.steps,
            growth_ends: training.growth_ends(),
            max_kernels: training
                .density
                .as_ref()
                .map_or(usize::MAX, DensityRules::max_kernels),
            kept_after_growth: training.prune.map_or(1.0, |rule| 1.0 - rule.fraction),
            stages: training.coarse.clone(),
            window: (training.window, view_size),
            history: Vec::with_capacity(training.steps.min(1 << 16)),
        }
    }

    /// Records a step.
    pub fn record(&mut self, record: &StepRecord) {
        self.history
            .push((record.seconds, record.kernels, record.downscale));
    }

    /// Seconds left after the steps recorded; `None` before two steps.
    #[must_use]
    pub fn seconds_left(&self) -> Option<f64> {
        let now = self.history.len();
        if now < 2 {
            return None;
        }
        let window = MIN_WINDOW.max(now / 10).min(now - 1);
        let (t1, k1, _) = self.history[now - 1];
        let (t0, k_start, _) = self.history[now - 1 - window];
        let recent = &self.history[now - window..];
        let fixed = recent.iter().map(|&(_, k, _)| k as f64).sum::<f64>() / window as f64;
        let units: f64 = recent
            .iter()
            .map(|&(_, k, n)| (k as f64 + fixed) * self.stage_cost(n))
            .sum();
        let per_unit = (t1 - t0) / units.max(1e-12);
        let k = k1 as f64;
        let slope = (k - k_start as f64) / window as f64;
        let grow_to = self.growth_ends.min(self.steps);
        let end = if now < grow_to {
            (k + slope * (grow_to - now) as f64).clamp(0.0, self.max_kernels as f64)
        } else {
            k
        };
        // The kernels after step s: along the slope until `grow_to`, then held (the share
        // the pruning keeps of them, when it is still to come).
        let kernels_at = |s: usize| {
            if s >= grow_to || now >= grow_to {
                end
            } else {
                k + (end - k) * (s - now) as f64 / (grow_to - now) as f64
            }
        };
        let held = if now < grow_to {
            end * self.kept_after_growth
        } else {
            end
        };
        // Piecewise: between the breakpoints (stage ends, the end of growth) the stage is
        // one and the kernel count linear, so each piece's sum is its length times its mean.
        let mut breaks: Vec<usize> = self
            .stages
            .iter()
            .map(|stage| (stage.until * self.steps as f64).round() as usize)
            .chain([grow_to, self.steps])
            .filter(|&b| b > now && b <= self.steps)
            .collect();
        breaks.sort_unstable();
        breaks.dedup();
        let mut left = 0.0;
        let mut from = now;
        for to in breaks {
            let n = downscale_at(&self.stages, to, self.steps);
            let mean = if from >= grow_to {
                held
            } else {
                0.5 * (kernels_at(from) + kernels_at(to))
            };
            left += per_unit * (to - from) as f64 * (mean + fixed) * self.stage_cost(n);
            from = to;
        }
        Some(left.max(0.0))
    }

    /// [`stage_cost`] of this fit's views at downscale `n`.
    fn stage_cost(&self, n: u32) -> f64 {
        stage_cost(n, self.window.0, self.window.1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fit::density::{AlphaRules, DensityRules};

    /// A 1000-step fit whose density rules add kernels until step 600.
    fn training() -> Training {
        let rules = AlphaRules {
            every: 100,
            from: 0.05,
            until: 0.6,
            fraction: 0.05,
            threshold: 0.0,
            max_kernels: 100_000,
            percent_dense: 0.01,
            time_split_fraction: 0.05,
            prune_opacity: 0.005,
            opacity_reset_every: 0,
            reset_opacity: 0.01,
            diagonal: 1.0,
            time_range: 1.0,
        };
        Training {
            steps: 1000,
            batch_size: 1,
            eval_every: 0,
            draw_seed: 0,
            render: crate::render::RenderOptions::default(),
            adam: crate::fit::adam::AdamConfig::default(),
            groups: Vec::new(),
            final_rate_factor: 1.0,
            density: Some(DensityRules::Alpha(rules)),
            coarse: Vec::new(),
            early_stop: None,
            window: None,
            loss: crate::fit::train::TrainingLoss::Mse,
            shape_bound: crate::fit::density::ShapeBound::OFF,
            prune: None,
            regularisers: crate::fit::regularise::Regularisers::OFF,
        }
    }

    /// The record of step `step`, `seconds` into the run, with `kernels` at `downscale`.
    fn record(step: usize, seconds: f64, kernels: usize, downscale: u32) -> StepRecord {
        StepRecord {
            step,
            seconds,
            train_loss: 0.0,
            heldout_psnr: None,
            kernels,
            downscale,
        }
    }

    /// A run whose kernels grow from 1000 by 10 a step until step 600, each step taking
    /// `1 ms · (k + 1000) / 1000`: the estimate at step `at`, and the truth.
    fn estimate_at(at: usize) -> (f64, f64) {
        estimate_pruned_at(at, 0.0)
    }

    /// [`estimate_at`] with the pruning by score removing `prune` of the kernels at step 600.
    fn estimate_pruned_at(at: usize, prune: f64) -> (f64, f64) {
        let training = Training {
            prune: (prune > 0.0).then_some(crate::fit::density::SpacetimePrune {
                fraction: prune,
                rounds: 1,
                every: 100,
            }),
            ..training()
        };
        let mut estimate = TimeLeft::new(&training, [400, 400]);
        let (mut seconds, mut total_at) = (0.0, 0.0);
        for step in 1..=1000 {
            let grown = 1000 + 10 * step.min(600);
            let kernels = if step >= 600 {
                (grown as f64 * (1.0 - prune)) as usize
            } else {
                grown
            };
            seconds += 1e-3 * (kernels + 1000) as f64 / 1000.0;
            if step <= at {
                estimate.record(&record(step, seconds, kernels, 1));
                total_at = seconds;
            }
        }
        (estimate.seconds_left().unwrap(), seconds - total_at)
    }

    #[test]
    fn a_growing_fit_is_estimated_within_a_fifth_where_a_straight_line_is_not() {
        for at in [100, 200, 400, 600, 800] {
            let (estimate, truth) = estimate_at(at);
            assert!(
                (estimate / truth - 1.0).abs() < 0.2,
                "at {at}: {estimate} s estimated, {truth} s left"
            );
        }
        // At step 100 a straight line through the time so far misses by more than a third.
        let (_, truth) = estimate_at(100);
        let seconds_at_100: f64 = (1..=100)
            .map(|s| 1e-3 * (1000 + 10 * s + 1000) as f64 / 1000.0)
            .sum();
        assert!(seconds_at_100 * 9.0 < 0.67 * truth);
    }

    /// Within a fifth before step 400 and after the pruning's window has passed; within a
    /// third around the pruning itself, where the model's fixed cost (the recent mean count,
    /// 6900 kernels) stands for this run's 1000, so that it expects a step after the pruning
    /// to cost 0.75 of one before where it costs 0.56 (1.80 s left at step 599 and 600,
    /// 2.35 s estimated; with the pruning left out of the model, (7000 + 6900)/(3500 + 6900) =
    /// 1.34× that).
    #[test]
    fn a_fit_that_prunes_half_its_kernels_when_growth_ends_is_estimated_within_a_third() {
        for (at, margin) in [
            (100, 0.2),
            (200, 0.2),
            (400, 0.2),
            (599, 0.33),
            (600, 0.33),
            (800, 0.2),
        ] {
            let (estimate, truth) = estimate_pruned_at(at, 0.5);
            assert!(
                (estimate / truth - 1.0).abs() < margin,
                "at {at}: {estimate} s estimated, {truth} s left"
            );
        }
    }

    /// The same run in coarse stages (¼ size until step 300, ½ until 600), whole views and
    /// windows of 200 of 400×400 views, each step's cost scaled by its stage as the model
    /// says: the estimate from step 100 on is within a fifth, where the time so far, spent
    /// at ¼ size, promises far too little.
    #[test]
    fn a_coarse_to_fine_fit_is_estimated_across_its_stages() {
        let stages = vec![
            SizeStage {
                downscale: 4,
                until: 0.3,
            },
            SizeStage {
                downscale: 2,
                until: 0.6,
            },
        ];
        for window in [None, Some(200)] {
            let training = Training {
                coarse: stages.clone(),
                window,
                ..training()
            };
            let cost = |step: usize| {
                let kernels = 1000 + 10 * step.min(600);
                let stage = stage_cost(downscale_at(&stages, step, 1000), window, [400, 400]);
                (kernels, 1e-3 * (kernels + 1000) as f64 / 1000.0 * stage)
            };
            let total: f64 = (1..=1000).map(|s| cost(s).1).sum();
            for at in [100, 250, 300, 450, 700] {
                let mut estimate = TimeLeft::new(&training, [400, 400]);
                let mut seconds = 0.0;
                for step in 1..=at {
                    let (kernels, duration) = cost(step);
                    seconds += duration;
                    let downscale = downscale_at(&stages, step, 1000);
                    estimate.record(&record(step, seconds, kernels, downscale));
                }
                let (guess, truth) = (estimate.seconds_left().unwrap(), total - seconds);
                assert!(
                    (guess / truth - 1.0).abs() < 0.2,
                    "{window:?} at {at}: {guess} s estimated, {truth} s left"
                );
                if at == 100 {
                    assert!(seconds * 9.0 < 0.5 * truth);
                }
            }
        }
        // Windows of 200 make a full-size step of 400×400 views cost what a ½-size one does.
        assert_eq!(
            stage_cost(1, Some(200), [400, 400]),
            stage_cost(2, None, [400, 400])
        );
    }

    #[test]
    fn nothing_is_promised_before_two_steps() {
        let mut estimate = TimeLeft::new(&training(), [400, 400]);
        assert_eq!(estimate.seconds_left(), None);
        estimate.record(&record(1, 0.1, 10, 1));
        assert_eq!(estimate.seconds_left(), None);
    }
}
