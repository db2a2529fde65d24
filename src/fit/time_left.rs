//! The time a running fit has left, from its steps so far and its schedule.
//!
//! A step's cost grows with the kernel count while the density rules add kernels, so a
//! linear extrapolation of the time per step promises a time that keeps growing (it was
//! off by up to half on a D-NeRF-like proxy). The estimate here models a step's duration as
//! `d = c (k + k0)`: `k` kernels, and a fixed cost `k0` (the images' pixels, the loss)
//! expressed in kernels, taken as the recent mean count — half the cost fixed, half per
//! kernel, near what the alpha fits' logs show (`docs/fitting.md`, "Time left"). `c` comes
//! from the recent window (the last tenth of the steps run, at least 50); the kernel count
//! is extrapolated along its recent slope until the last step at which the density rules
//! may add kernels (never beyond their budget), and held after it:
//!
//! ```text
//! left = c Σ_{s > now} (k(s) + k0)
//! ```

use crate::fit::train::{StepRecord, Training};

/// Steps of the window the estimate reads, at least.
const MIN_WINDOW: usize = 50;

/// The estimate of a running fit's time left (see the module docs).
#[derive(Clone, Debug)]
pub struct TimeLeft {
    steps: usize,
    /// The last step at which kernels may be added (0: never).
    growth_ends: usize,
    /// The density rules' budget.
    max_kernels: usize,
    /// `(seconds, kernels)` after each step so far.
    history: Vec<(f64, usize)>,
}

impl TimeLeft {
    /// The estimate for a fit that runs `training`.
    #[must_use]
    pub fn new(training: &Training) -> Self {
        let (growth_ends, max_kernels) =
            training.density.as_ref().map_or((0, usize::MAX), |rules| {
                (rules.growth_ends(training.steps), rules.max_kernels())
            });
        TimeLeft {
            steps: training.steps,
            growth_ends,
            max_kernels,
            history: Vec::with_capacity(training.steps.min(1 << 16)),
        }
    }

    /// Records a step.
    pub fn record(&mut self, record: &StepRecord) {
        self.history.push((record.seconds, record.kernels));
    }

    /// Seconds left after the steps recorded; `None` before two steps.
    #[must_use]
    pub fn seconds_left(&self) -> Option<f64> {
        let now = self.history.len();
        if now < 2 {
            return None;
        }
        let window = MIN_WINDOW.max(now / 10).min(now - 1);
        let (t1, k1) = self.history[now - 1];
        let (t0, k_start) = self.history[now - 1 - window];
        let duration = (t1 - t0) / window as f64;
        let mean_kernels = self.history[now - window..]
            .iter()
            .map(|&(_, k)| k as f64)
            .sum::<f64>()
            / window as f64;
        let fixed = mean_kernels;
        let per_kernel = duration / (mean_kernels + fixed).max(1.0);
        let k = k1 as f64;
        let mut left = 0.0;
        let mut held = k;
        let grow_to = self.growth_ends.min(self.steps);
        if now < grow_to {
            let slope = (k - k_start as f64) / window as f64;
            let steps = (grow_to - now) as f64;
            let end = (k + slope * steps).clamp(0.0, self.max_kernels as f64);
            left += per_kernel * steps * (0.5 * (k + end) + fixed);
            held = end;
        }
        let after = self.steps.saturating_sub(grow_to.max(now)) as f64;
        left += per_kernel * after * (held + fixed);
        Some(left.max(0.0))
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
        }
    }

    /// A run whose kernels grow from 1000 by 10 a step until step 600, each step taking
    /// `1 ms · (k + 1000) / 1000`: the estimate at step `at`, and the truth.
    fn estimate_at(at: usize) -> (f64, f64) {
        let mut estimate = TimeLeft::new(&training());
        let (mut seconds, mut total_at) = (0.0, 0.0);
        for step in 1..=1000 {
            let kernels = 1000 + 10 * step.min(600);
            seconds += 1e-3 * (kernels + 1000) as f64 / 1000.0;
            if step <= at {
                estimate.record(&StepRecord {
                    step,
                    seconds,
                    train_loss: 0.0,
                    heldout_psnr: None,
                    kernels,
                });
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

    #[test]
    fn nothing_is_promised_before_two_steps() {
        let mut estimate = TimeLeft::new(&training());
        assert_eq!(estimate.seconds_left(), None);
        estimate.record(&StepRecord {
            step: 1,
            seconds: 0.1,
            train_loss: 0.0,
            heldout_psnr: None,
            kernels: 10,
        });
        assert_eq!(estimate.seconds_left(), None);
    }
}
