//! The time a running fit has left, from its steps so far and its schedule.
//!
//! A step's cost grows with the kernel count while the density rules add kernels, so a
//! linear extrapolation of the time per step promises a time that keeps growing. The
//! estimate here models a step's duration as a cost per kernel plus a fixed cost of the
//! pixels it renders (the render's compositing and its backward, and under L1 + D-SSIM the
//! SSIM pass, [`crate::fit::ssim`]), counted in kernels:
//!
//! ```text
//! d = c (k (k / 10⁴)^0.2 + κ P r(n)^0.8),    r(n) = f(n) / n²
//! ```
//!
//! `k` kernels; `P` the pixels of the first training view at full size; `r` the fraction of
//! them a step renders of each view: `1/n²` on views downscaled by `n`
//! ([`crate::fit::coarse`]), times the fraction `f` of the view that one window holds
//! ([`crate::fit::window`]; 1 for whole views), so a full-size step on 2×2 windows costs
//! what a ½-size step on whole views does. `κ`, the fixed cost in kernels per pixel, is 0.3
//! under L1 + D-SSIM and 0.4 under the MSE (its render and backward fused). A kernel's cost
//! grows slowly with their count, as `(k / 10⁴)^0.2` (more pairs per tile to sort, fewer of
//! them in cache: at ½ size on `lego`'s 400×400 renders each kernel added cost a step
//! 1.7 µs between 7 k and 20 k kernels, 2.7 µs between 20 k and 29 k), and hardly with the
//! pixels; the fixed cost grows as their power 0.8, that of a quiet machine (about 0.5 on
//! a loaded one, where small steps wait longer; 0.7, a compromise between the two, was
//! 32 % short at 15 % of a 400×400 fit once the kernel count was foreseen by its growth
//! target; `docs/fitting.md`, "Time left", has the measurements behind these constants).
//!
//! `c` is the median, over the blocks of 50 steps in the recent window (the last fifth of
//! the steps run, at least 50), of each block's seconds over its summed step costs `d / c`: a
//! median, so that a spell of load or a slow density round moves it little. Where the
//! density rules grow towards a kernel count ([`crate::fit::density::GrowthTarget`], a
//! kernel budget), the kernel count is grown as their rounds will grow it, each by the
//! share that reaches the count in the rounds left (extrapolating the recent growth instead
//! was 30–35 % short at 10 % of a 100×100 fit, when the start's transparent kernels had
//! just been pruned). Otherwise each round ahead grows it by a share: the share the recent
//! rounds grew it by (their geometric mean over the rounds run in the window, at least the
//! last round; never down: the pruning early in a fit is followed by growth), under alpha
//! rules averaged with the share they add (additive rules grow only when the loss stalls,
//! so their recent rounds are all there is). Rounds, not steps: the count grows
//! geometrically at the rounds, and the recent growth per step, extrapolated, missed by a
//! round whenever the window held one round fewer than its share of steps (38–44 % short
//! between 10 and 13 % of three recorded fits, between the points every 5 % where they had
//! been checked; a straight line fell 42–46 % short on a real capture whose budget grew it
//! 20-fold). The alpha rules' share weighs in because a round's net growth rises towards it
//! as the start's transparent kernels are pruned away (the D-NeRF-like proxy with the
//! objects' budget grew 6.6 and 8.5 % at its first two rounds, 10–11.6 % at the next six,
//! the rules' 11.83 %; the recent share alone left it 30 % short at a tenth, the last
//! round's alone the `fox` 35 % short at 35 %). Either way it grows until the last step at
//! which the density rules may add kernels (never beyond their budget), and is held after it
//! (times the share the pruning by score keeps, [`crate::fit::density::prune`], while that
//! is still to come):
//!
//! ```text
//! left = c Σ_{s > now} (k(s) (k(s) / 10⁴)^0.2 + κ P r(n(s))^0.8) (k(s) / k)^e(n(s))
//! ```
//!
//! The last factor is what the fit's own steps say of the model's kernel term. Where the
//! kernels widen as they fit (a start from a sparse point cloud, seen from sparse views),
//! their (pixel, kernel) pairs grow faster than their count — as its power 1.8 on a real
//! capture — and a step's time with them, beyond what any fixed split between kernels and
//! pixels foresees. So the estimate times the growth: for each two successive intervals
//! between density rounds on views of one size, with `d` an interval's seconds a step, `k`
//! its kernels, `s` the kernels' share of the model's step cost and `β = 1.2 s` the model's
//! elasticity of a step's time in the kernel count, the excess
//! `ln(d₂/d₁) - β ln(k₂/k₁) = γ s ln(k₂/k₁)`, `γ` fitted by least squares through the origin
//! over all such pairs so far. The kernels' share scales it to each stage ahead,
//! `e(n) = γ s(n)`, clamped to `[0, 0.8]` (never cheaper than the model; 1 left a sparse fit
//! under the 3DGS loss 39 % long at a fifth, read from its first, noisiest intervals, and
//! 0.7 the same capture under the MSE 21 % short); only growth beyond the kernels now is
//! scaled (`k(s) > k`). Before
//! two intervals have been timed, `e = 0`, the model alone, except on still photos from
//! sparse views (the fits whose kernels were seen to widen), where
//! [`SPARSE_PHOTO_GROWTH_EXCESS`] stands in for it: their first round runs at a tenth of
//! their 2000 steps, so at a tenth nothing of growth has been timed, and the model alone
//! was 41–58 % short there on the four recorded sparse fits (a prior for every fit broke
//! those whose steps follow the model).

use crate::fit::coarse::{SizeStage, downscale_at};
use crate::fit::density::{AlphaRules, DensityRules};
use crate::fit::train::{StepRecord, Training, TrainingLoss};
use crate::fit::window::pixel_fraction;

/// Steps of the window the estimate reads, at least.
const MIN_WINDOW: usize = 50;

/// The window the estimate reads, as a fraction of the steps run.
const WINDOW_FRACTION: f64 = 0.2;

/// Steps of each block of the window whose rates the estimate takes the median of.
const BLOCK: usize = 50;

/// The exponent of the pixels rendered in a step's fixed cost (see the module docs).
const PIXEL_EXPONENT: f64 = 0.8;

/// The fixed cost of a step, in kernels per pixel of the full-size view, under the MSE
/// (the render and its backward fused per tile).
const FIXED_PER_PIXEL_MSE: f64 = 0.4;

/// The fixed cost of a step, in kernels per pixel of the full-size view, under
/// L1 + D-SSIM (the SSIM pass, the unfused render and backward).
const FIXED_PER_PIXEL_DSSIM: f64 = 0.3;

/// The exponent of a kernel's cost in the kernel count, relative to
/// [`KERNEL_COUNT_REFERENCE`] (see the module docs).
const KERNEL_EXPONENT: f64 = 0.2;

/// The kernel count at which a kernel costs one unit.
const KERNEL_COUNT_REFERENCE: f64 = 10_000.0;

/// The most a step's time may grow faster with the kernels than the model has it, as an
/// exponent of their growth (see the module docs).
const MAX_EXCESS_ELASTICITY: f64 = 0.8;

/// The exponent `e` at which the growth ahead of a fit on still photos from sparse views is
/// priced until its own steps have timed it ([`TimeLeft::for_sparse_photos`]): the
/// most the estimate allows, as the four recorded sparse fits needed (at 0.6 the mouse's was
/// 35 % short at a tenth, at 0.4 44 %; see the module docs).
pub const SPARSE_PHOTO_GROWTH_EXCESS: f64 = MAX_EXCESS_ELASTICITY;

/// The least growth of the kernels between two intervals, as `|ln(k₂/k₁)|`, whose times
/// are compared.
const MIN_TIMED_GROWTH: f64 = 0.01;

/// The estimate of a running fit's time left (see the module docs).
#[derive(Clone, Debug)]
pub struct TimeLeft {
    steps: usize,
    /// The last step at which kernels may be added (0: never).
    growth_ends: usize,
    /// The density rules' budget.
    max_kernels: usize,
    /// The largest share of the kernels a density round may add.
    max_round_share: f64,
    /// Whether each round adds the rules' share of the visible kernels (alpha rules; the
    /// additive rules' rounds grow only when the loss stalls).
    rounds_add_their_share: bool,
    /// Alpha rules that grow towards a kernel count: the count is then grown as their
    /// rounds ([`TimeLeft::rounds`]) will grow it.
    towards_target: Option<AlphaRules>,
    /// The share of the kernels the pruning by score keeps once growth ends (1: none).
    kept_after_growth: f64,
    /// The coarse stages.
    stages: Vec<SizeStage>,
    /// The steps' window side, and the size of the views it cuts (at full size).
    window: (Option<u32>, [u32; 2]),
    /// The fixed cost of a step, in kernels per pixel of the full-size view.
    fixed_per_pixel: f64,
    /// The steps after which the density rules' rounds run, in order: the intervals
    /// between them are where the cost of growth is timed ([`TimeLeft::excess_elasticity`]),
    /// and those ahead grow the count towards a target.
    rounds: Vec<usize>,
    /// The exponent `e` of the growth ahead before the fit's own steps have timed it
    /// ([`TimeLeft::for_sparse_photos`]; 0: the model's).
    untimed_excess: f64,
    /// Each step so far.
    history: Vec<Past>,
}

/// A step as the estimate keeps it.
#[derive(Clone, Copy, Debug)]
struct Past {
    /// Seconds since the fit began, at the step's end.
    seconds: f64,
    /// Kernels after the step (and its round).
    kernels: usize,
    /// The step's [`TimeLeft::step_cost`], computed once as it is recorded (the estimate
    /// is asked for after every step and reads the costs of a fifth of them).
    cost: f64,
    /// The downscale of the step's views.
    downscale: u32,
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
            max_round_share: training
                .density
                .as_ref()
                .map_or(0.0, DensityRules::max_round_share),
            rounds_add_their_share: matches!(training.density, Some(DensityRules::Alpha(_))),
            towards_target: match training.density {
                Some(DensityRules::Alpha(rules)) if rules.growth_target.is_some() => Some(rules),
                _ => None,
            },
            kept_after_growth: training.prune.map_or(1.0, |rule| 1.0 - rule.fraction),
            stages: training.coarse.clone(),
            window: (training.window, view_size),
            fixed_per_pixel: match training.loss {
                TrainingLoss::Mse => FIXED_PER_PIXEL_MSE,
                TrainingLoss::L1Dssim(_) => FIXED_PER_PIXEL_DSSIM,
            },
            rounds: match &training.density {
                Some(DensityRules::Alpha(rules)) => rules.round_steps(training.steps).collect(),
                Some(DensityRules::Additive(rules)) => (1..=training.steps)
                    .filter(|&step| rules.round_after(step, training.steps))
                    .collect(),
                None => Vec::new(),
            },
            untimed_excess: 0.0,
            history: Vec::with_capacity(training.steps.min(1 << 16)),
        }
    }

    /// This estimate for a fit on still photos from sparse views when `sparse` is true,
    /// whose steps grow dearer with the kernels than the model has it: until two intervals
    /// between rounds are timed, the growth ahead is priced at
    /// [`SPARSE_PHOTO_GROWTH_EXCESS`] (see the module docs).
    #[must_use]
    pub fn for_sparse_photos(self, sparse: bool) -> Self {
        TimeLeft {
            untimed_excess: if sparse {
                SPARSE_PHOTO_GROWTH_EXCESS
            } else {
                0.0
            },
            ..self
        }
    }

    /// Records a step.
    pub fn record(&mut self, record: &StepRecord) {
        self.history.push(Past {
            seconds: record.seconds,
            kernels: record.kernels,
            cost: self.step_cost(record.kernels as f64, record.downscale),
            downscale: record.downscale,
        });
    }

    /// Seconds left after the steps recorded; `None` before two steps.
    #[must_use]
    pub fn seconds_left(&self) -> Option<f64> {
        let now = self.history.len();
        if now < 2 {
            return None;
        }
        let window = MIN_WINDOW
            .max((now as f64 * WINDOW_FRACTION) as usize)
            .min(now - 1);
        let per_unit = self.seconds_per_unit(window);
        let k = self.history[now - 1].kernels as f64;
        let grow_to = self.growth_ends.min(self.steps);
        let cap = (self.max_kernels as f64).max(k);
        // The kernels after step s until `grow_to`, then held (the share the pruning keeps
        // of them, when it is still to come).
        let kernels_after = match &self.towards_target {
            Some(rules) => grown_by_rounds(&self.rounds, (k, cap), now, grow_to, |kept, left| {
                rules.round_share(kept, left)
            }),
            None => {
                let share = self.recent_round_share(now, window);
                grown_by_rounds(&self.rounds, (k, cap), now, grow_to, |_, _| share)
            }
        };
        let end = kernels_after.last().copied().unwrap_or(k);
        let held = if now < grow_to {
            end * self.kept_after_growth
        } else {
            end
        };
        // Piecewise: between the breakpoints (stage ends, the end of growth) the stage is
        // one, so each piece's cost is its summed kernels plus its steps' fixed cost.
        let mut breaks: Vec<usize> = self
            .stages
            .iter()
            .map(|stage| (stage.until * self.steps as f64).round() as usize)
            .chain([grow_to, self.steps])
            .filter(|&b| b > now && b <= self.steps)
            .collect();
        breaks.sort_unstable();
        breaks.dedup();
        let excess = self.excess_elasticity();
        let mut left = 0.0;
        let mut from = now;
        for to in breaks {
            let n = downscale_at(&self.stages, to, self.steps);
            let mean = if from >= grow_to {
                held
            } else {
                kernels_after[from - now..to - now].iter().sum::<f64>() / (to - from) as f64
            };
            let timed = if mean > k {
                let exponent = excess.map_or(self.untimed_excess, |excess| {
                    (excess * self.kernel_share(k, n)).clamp(0.0, MAX_EXCESS_ELASTICITY)
                });
                (mean / k).powf(exponent)
            } else {
                1.0
            };
            left += per_unit * (to - from) as f64 * self.step_cost(mean, n) * timed;
            from = to;
        }
        Some(left.max(0.0))
    }

    /// The share of the kernels each density round ahead is foreseen to add: the geometric
    /// mean of what the rounds run in the last `window` steps added (at least the last
    /// round run; a round after the first step, whose count before it is recorded), in
    /// `[0, max_round_share]`, and under alpha rules the mean of that and the rules' share
    /// (see the module docs); before any such round the rules' share (alpha) or none
    /// (additive). Rounds, not steps: a window of steps holds one round more or less than
    /// its share of them.
    fn recent_round_share(&self, now: usize, window: usize) -> f64 {
        let rules = if self.rounds_add_their_share {
            self.max_round_share
        } else {
            0.0
        };
        let done = &self.rounds[self.rounds.partition_point(|&step| step < 2)
            ..self.rounds.partition_point(|&step| step <= now)];
        let Some(&last) = done.last() else {
            return rules;
        };
        let recent = &done[done.partition_point(|&step| step + window <= now)..];
        let first = recent.first().copied().unwrap_or(last);
        let rounds = recent.len().max(1);
        let before = self.history[first - 2].kernels as f64;
        let after = self.history[last - 1].kernels as f64;
        if before <= 0.0 {
            return rules;
        }
        let measured =
            ((after / before).powf(1.0 / rounds as f64) - 1.0).clamp(0.0, self.max_round_share);
        if self.rounds_add_their_share {
            0.5 * (measured + rules)
        } else {
            measured
        }
    }

    /// Seconds per unit of [`TimeLeft::step_cost`] over the last `window` steps: the median
    /// of the rates of its blocks of [`BLOCK`] steps (the mean rate of the whole window
    /// when it holds no whole block).
    fn seconds_per_unit(&self, window: usize) -> f64 {
        let now = self.history.len();
        let rate = |from: usize, to: usize| {
            let units: f64 = self.history[from..to].iter().map(|past| past.cost).sum();
            (self.history[to - 1].seconds - self.history[from - 1].seconds) / units.max(1e-12)
        };
        let mut rates: Vec<f64> = (1..=window / BLOCK)
            .map(|b| rate(now - b * BLOCK, now - (b - 1) * BLOCK))
            .collect();
        if rates.is_empty() {
            return rate(now - window, now);
        }
        rates.sort_unstable_by(f64::total_cmp);
        rates[rates.len() / 2]
    }

    /// The share of a step's [`TimeLeft::step_cost`] that its `kernels` take on views
    /// downscaled by `n`.
    fn kernel_share(&self, kernels: f64, n: u32) -> f64 {
        let cost = self.step_cost(kernels, n);
        if cost > 0.0 {
            kernel_cost(kernels) / cost
        } else {
            0.0
        }
    }

    /// How much faster than the model a step's time has grown with the kernels, per unit
    /// of the kernels' share of the cost (see the module docs): `γ` fitted by least squares
    /// through the origin over each two successive intervals between density rounds on
    /// views of one size, `ln(d₂/d₁) - β ln(k₂/k₁) = γ s ln(k₂/k₁)`, `d` an interval's
    /// seconds a step, `k` its kernels, `β = (1 + 0.2) s` the model's elasticity and `s`
    /// the kernels' share ([`TimeLeft::kernel_share`]); `None` before two such intervals.
    fn excess_elasticity(&self) -> Option<f64> {
        let intervals = self.intervals_between_rounds();
        let (mut products, mut squares) = (0.0, 0.0);
        for pair in intervals.windows(2) {
            let [Some((n1, d1, k1)), Some((n2, d2, k2))] = [pair[0], pair[1]] else {
                continue;
            };
            let grown = (k2 / k1).ln();
            if n1 != n2 || grown.abs() <= MIN_TIMED_GROWTH || d1 <= 0.0 || d2 <= 0.0 {
                continue;
            }
            let share = self.kernel_share((k1 * k2).sqrt(), n1);
            let excess = (d2 / d1).ln() - (1.0 + KERNEL_EXPONENT) * share * grown;
            products += excess * share * grown;
            squares += (share * grown).powi(2);
        }
        (squares > 0.0).then(|| products / squares)
    }

    /// Each interval `(a, b]` of whole steps run between density rounds (the first from
    /// step 1): its downscale, its seconds a step and its kernels (those after round `a`:
    /// the record of step `b` holds round `b`'s); `None` where it has fewer than two steps,
    /// spans two view sizes or has no kernel.
    fn intervals_between_rounds(&self) -> Vec<Option<(u32, f64, f64)>> {
        let now = self.history.len();
        std::iter::once(1)
            .chain(self.rounds.iter().copied().take_while(|&step| step <= now))
            .collect::<Vec<_>>()
            .windows(2)
            .map(|ends| {
                let (a, b) = (ends[0], ends[1]);
                if b < a + 2 {
                    return None;
                }
                let (first, last) = (self.history[a - 1], self.history[b - 1]);
                let kernels = self.history[b - 2].kernels;
                (first.downscale == last.downscale && kernels > 0).then(|| {
                    let seconds = (last.seconds - first.seconds) / (b - a) as f64;
                    (last.downscale, seconds, kernels as f64)
                })
            })
            .collect()
    }

    /// The cost of a step with `kernels` on views downscaled by `n`, in kernels: the
    /// kernels, each dearer as they grow, plus the fixed cost of the pixels it renders (see
    /// the module docs).
    fn step_cost(&self, kernels: f64, n: u32) -> f64 {
        let [width, height] = self.window.1;
        let pixels = f64::from(width) * f64::from(height);
        kernel_cost(kernels)
            + self.fixed_per_pixel
                * pixels
                * pixel_ratio(n, self.window.0, self.window.1).powf(PIXEL_EXPONENT)
    }
}

/// A step's cost of `kernels`, in kernels: each dearer as they grow.
fn kernel_cost(kernels: f64) -> f64 {
    kernels * (kernels.max(1.0) / KERNEL_COUNT_REFERENCE).powf(KERNEL_EXPONENT)
}

/// The kernels after each step from `now + 1` to `grow_to`, `k` grown after each step of
/// `rounds` (the steps after which the density rounds run) by the share
/// `share(kernels, rounds_left)` gives (rounds left counting this one), at most `cap`.
/// Towards a target that is [`AlphaRules::round_share`]; the pruning of transparent
/// kernels along the way, which its shares make up for, is not foreseen.
fn grown_by_rounds(
    rounds: &[usize],
    (k, cap): (f64, f64),
    now: usize,
    grow_to: usize,
    share: impl Fn(usize, usize) -> f64,
) -> Vec<f64> {
    let first = rounds.partition_point(|&step| step <= now);
    let mut ahead = rounds[first..].iter().peekable();
    let mut grown = k;
    (now + 1..=grow_to)
        .map(|step| {
            if ahead.next_if_eq(&&step).is_some() {
                let share = share(grown as usize, ahead.len() + 1);
                grown = (grown * (1.0 + share)).min(cap);
            }
            grown
        })
        .collect()
}

/// The pixels a step on views downscaled by `n` (and windowed by `window`, of views of
/// `size` at full size) renders, relative to whole views at full size.
fn pixel_ratio(n: u32, window: Option<u32>, [width, height]: [u32; 2]) -> f64 {
    let n = n.max(1);
    let fraction = pixel_fraction(window, (width / n).max(1), (height / n).max(1));
    fraction / f64::from(n).powi(2)
}

/// One point of a replay ([`replay`]): after `steps` of a finished run, the estimate and
/// the seconds the run then had left.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Replayed {
    /// Steps run when the estimate was made.
    pub steps: usize,
    /// The estimate, seconds.
    pub estimate: f64,
    /// The seconds the run had left.
    pub truth: f64,
}

impl Replayed {
    /// The estimate's relative error, `estimate / truth - 1`.
    #[must_use]
    pub fn error(&self) -> f64 {
        self.estimate / self.truth.max(1e-12) - 1.0
    }
}

/// `estimate`, made for a finished fit ([`TimeLeft::new`]), replayed over its step
/// records `records` (a `fit --log`): at each fraction of `fractions` of the run's
/// steps, what [`TimeLeft::seconds_left`] said and what was left.
#[must_use]
pub fn replay(mut estimate: TimeLeft, records: &[StepRecord], fractions: &[f64]) -> Vec<Replayed> {
    let Some(last) = records.last() else {
        return Vec::new();
    };
    let mut points = Vec::new();
    let mut next = fractions.iter().peekable();
    for (i, record) in records.iter().enumerate() {
        estimate.record(record);
        while let Some(&&fraction) = next.peek() {
            if (fraction * records.len() as f64).round() as usize > i + 1 {
                break;
            }
            next.next();
            if let Some(left) = estimate.seconds_left() {
                points.push(Replayed {
                    steps: i + 1,
                    estimate: left,
                    truth: last.seconds - record.seconds,
                });
            }
        }
    }
    points
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fit::density::{AlphaRules, DensityRules, GrowthTarget};

    /// A 1000-step fit whose density rules add up to 35 % of the kernels every 100 steps
    /// until step 600.
    fn training() -> Training {
        let rules = AlphaRules {
            every: 100,
            from: 0.05,
            until: 0.6,
            fraction: 0.35,
            threshold: 0.0,
            max_kernels: 100_000,
            percent_dense: 0.01,
            time_split_fraction: 0.05,
            prune_opacity: 0.005,
            opacity_reset_every: 0,
            reset_opacity: 0.01,
            diagonal: 1.0,
            time_range: 1.0,
            motion_after_time_splits: None,
            motion_when_turning: None,
            growth_target: None,
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
            pairs: 0,
            downscale,
        }
    }

    /// The kernels of the synthetic runs after `step`: 1000 grown by 30 % at each density
    /// round of [`training`] (after steps 100, 200, …, 600: about 4800).
    fn grown(step: usize) -> usize {
        (1000.0 * 1.3_f64.powi((step / 100).min(6) as i32)).round() as usize
    }

    /// A run whose kernels grow as [`grown`], each step taking `1 ms · (k + 1000) / 1000`:
    /// the estimate at step `at`, and the truth.
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
        // 50×50 views: a fixed cost of 0.4 × 2500 = 1000 kernels under the MSE.
        let mut estimate = TimeLeft::new(&training, [50, 50]);
        let (mut seconds, mut total_at) = (0.0, 0.0);
        for step in 1..=1000 {
            let grown = grown(step);
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
            .map(|s| 1e-3 * (grown(s) + 1000) as f64 / 1000.0)
            .sum();
        assert!(seconds_at_100 * 9.0 < 0.67 * truth);
    }

    /// A run whose kernels grow 10 % at each round (every 100 steps from step 100 to 600)
    /// and whose steps take `1 ms · (k / 1000)²`, far faster growth than the model's: once
    /// two intervals between rounds are timed the estimate is within 30 %, where the model
    /// alone, which counts most of a step of 50×50 views as its fixed cost, is short by more
    /// than a third (the excess is clamped at 0.8 of a power, so it stays short while
    /// growth lasts).
    #[test]
    fn growth_dearer_than_the_model_is_timed_between_rounds() {
        // The kernels after step `step` and its round.
        let kernels = |step: usize| (1000.0 * 1.1_f64.powi((step / 100).min(6) as i32)) as usize;
        let duration = |step: usize| 1e-3 * (kernels(step - 1) as f64 / 1000.0).powi(2);
        let total: f64 = (1..=1000).map(duration).sum();
        let training = Training {
            density: Some(DensityRules::Alpha(AlphaRules {
                fraction: 0.1,
                ..match training().density {
                    Some(DensityRules::Alpha(rules)) => rules,
                    _ => unreachable!("the test's rules are alpha rules"),
                }
            })),
            ..training()
        };
        let mut estimate = TimeLeft::new(&training, [50, 50]);
        let mut seconds = 0.0;
        for step in 1..=900 {
            seconds += duration(step);
            estimate.record(&record(step, seconds, kernels(step), 1));
            if step % 100 != 0 {
                continue;
            }
            let (guess, truth) = (estimate.seconds_left().unwrap(), total - seconds);
            if step == 100 {
                assert!(guess < 0.67 * truth, "at {step}: {guess} s, {truth} s left");
            } else {
                assert!(
                    (guess / truth - 1.0).abs() < 0.3,
                    "at {step}: {guess} s estimated, {truth} s left"
                );
            }
        }
    }

    /// The same growth, half the kernels pruned when it ends: within a fifth at every step
    /// measured, the pruning's step included.
    #[test]
    fn a_fit_that_prunes_half_its_kernels_when_growth_ends_is_estimated_within_a_fifth() {
        for at in [100, 200, 400, 599, 600, 800] {
            let (estimate, truth) = estimate_pruned_at(at, 0.5);
            assert!(
                (estimate / truth - 1.0).abs() < 0.2,
                "at {at}: {estimate} s estimated, {truth} s left"
            );
        }
    }

    /// The same growth in coarse stages (¼ size until step 300, ½ until 600), whole views
    /// and windows of 200 of 400×400 views, each step costing what the model says: the
    /// estimate from step 100 on is within a fifth, where the time so far, spent at ¼ size,
    /// promises far too little.
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
            let model = TimeLeft::new(&training, [400, 400]);
            let cost = |step: usize| {
                let kernels = grown(step);
                let n = downscale_at(&stages, step, 1000);
                (kernels, 1e-6 * model.step_cost(kernels as f64, n))
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
            pixel_ratio(1, Some(200), [400, 400]),
            pixel_ratio(2, None, [400, 400])
        );
    }

    /// The step records of a recorded default fit (`tests/data/time_left/README.md`): one
    /// line `milliseconds kernels downscale` a step.
    fn recorded(text: &str) -> Vec<StepRecord> {
        text.lines()
            .enumerate()
            .map(|(i, line)| {
                let fields: Vec<&str> = line.split_whitespace().collect();
                let milliseconds: f64 = fields[0].parse().unwrap();
                record(
                    i + 1,
                    1e-3 * milliseconds,
                    fields[1].parse().unwrap(),
                    fields[2].parse().unwrap(),
                )
            })
            .collect()
    }

    /// How a recorded fit grew: its growth a round (with a target, the largest), its steps
    /// between rounds, the share of the kernels its pruning by score removed when growth
    /// ended (0: none), the kernel count its rounds grew towards (`None`: a fixed
    /// growth) and the count they stopped at (`None`: the defaults' `max_kernels`).
    #[derive(Clone, Copy)]
    struct Growth {
        share: f64,
        every: usize,
        pruned: f64,
        target: Option<f64>,
        cap: Option<usize>,
    }

    /// The alpha fit's defaults for a run of `records`, with coarse stages `stages` (as the
    /// plan chooses them for the recorded views), loss `loss` and growth `growth`.
    fn default_training(
        records: &[StepRecord],
        stages: &[(u32, f64)],
        loss: TrainingLoss,
        growth: &Growth,
    ) -> Training {
        let bounds = crate::fit::init::SpaceTimeBox {
            min: [-1.0; 3],
            max: [1.0; 3],
            time: [0.0, 1.0],
        };
        let floor = crate::fit::defaults::DEFAULT_ALPHA.densify_fraction;
        let mut training = Training {
            steps: records.len(),
            coarse: stages
                .iter()
                .map(|&(downscale, until)| SizeStage { downscale, until })
                .collect(),
            loss,
            ..crate::fit::alpha::AlphaFitOptions {
                densify_fraction: if growth.target.is_some() {
                    floor
                } else {
                    growth.share
                },
                densify_every: growth.every,
                prune_fraction: growth.pruned,
                max_kernels: growth
                    .cap
                    .unwrap_or(crate::fit::defaults::DEFAULT_ALPHA.max_kernels),
                ..crate::fit::defaults::DEFAULT_ALPHA
            }
            .training(&bounds)
        };
        if let Some(DensityRules::Alpha(rules)) = &mut training.density {
            rules.growth_target = growth.target.map(|kernels| GrowthTarget {
                kernels,
                max_share: growth.share,
            });
        }
        training
    }

    /// Seven default fits recorded on a 2-core machine, replayed through the estimate:
    /// within 30 % of the time left at every 0.5 % of the run from 10 % to 90 %.
    #[test]
    fn recorded_default_fits_are_estimated_within_thirty_percent_from_a_tenth() {
        let dn400 = recorded(include_str!("../../tests/data/time_left/fin_dn400.txt"));
        let phone = recorded(include_str!("../../tests/data/time_left/ph4.txt"));
        let fox = recorded(include_str!("../../tests/data/time_left/fox4_budget.txt"));
        let dn400_budget = recorded(include_str!("../../tests/data/time_left/dn400_budget.txt"));
        let lego = recorded(include_str!(
            "../../tests/data/time_left/lego400_budget.txt"
        ));
        let lego_target = recorded(include_str!(
            "../../tests/data/time_left/lego400_target.txt"
        ));
        let lego_thumbnails = recorded(include_str!(
            "../../tests/data/time_left/lego100_target.txt"
        ));
        let coarse_to_fine = [(4, 0.3), (2, 0.6)];
        let photos = [(2, 0.6)];
        let dssim = crate::fit::defaults::DEFAULT_LOSS;
        // The first three ran before the pruning by score, 6000 steps with a round every 100.
        let before_pruning = |share| Growth {
            share,
            every: 100,
            pruned: 0.0,
            target: None,
            cap: None,
        };
        // The objects' kernel budget grew the next two by 11.83 % a round, every 200 of
        // their 12 000 steps, and half their kernels were pruned when growth ended.
        let object_budget = Growth {
            share: 0.1183,
            every: 200,
            pruned: 0.5,
            target: None,
            cap: None,
        };
        // The last two grew towards 32 000 and 8000 kernels at up to 15 % a round, then
        // lost half.
        let object_target = |kernels| Growth {
            share: 0.15,
            target: Some(kernels),
            ..object_budget
        };
        let fits = [
            (
                &dn400,
                &coarse_to_fine[..],
                dssim,
                before_pruning(0.05),
                [400, 400],
            ),
            (
                &phone,
                &photos[..],
                TrainingLoss::Mse,
                before_pruning(0.05),
                [270, 480],
            ),
            // The photos' kernel budget grew it by 9.95 % a round.
            (
                &fox,
                &photos[..],
                TrainingLoss::Mse,
                before_pruning(0.0995),
                [270, 480],
            ),
            (
                &dn400_budget,
                &coarse_to_fine[..],
                dssim,
                object_budget,
                [400, 400],
            ),
            (&lego, &coarse_to_fine[..], dssim, object_budget, [400, 400]),
            (
                &lego_target,
                &coarse_to_fine[..],
                dssim,
                object_target(32_000.0),
                [400, 400],
            ),
            (
                &lego_thumbnails,
                &[][..],
                dssim,
                object_target(8000.0),
                [100, 100],
            ),
        ];
        for (records, stages, loss, growth, size) in fits {
            let training = default_training(records, stages, loss, &growth);
            let estimate = TimeLeft::new(&training, size);
            assert_estimated_within_thirty_percent(estimate, size, records, 0.1);
        }
    }

    /// Two real captures from sparse views, each fitted under the MSE and the 3DGS loss
    /// (2000 steps, a round every 100 from step 200 to 1200), whose steps grow dearer with
    /// the kernels than the model has it (their pairs grow as the kernels to the power 1.8
    /// on the mouse): the same bound from a tenth of the run, with the estimate the fit
    /// makes of still photos from sparse views ([`SPARSE_PHOTO_GROWTH_EXCESS`] until a
    /// round's steps have been timed).
    #[test]
    fn sparse_photo_fits_are_estimated_within_thirty_percent_from_a_tenth() {
        let mouse = recorded(include_str!("../../tests/data/time_left/mouse4_sparse.txt"));
        let king = recorded(include_str!("../../tests/data/time_left/king4_sparse.txt"));
        let mouse_dssim = recorded(include_str!(
            "../../tests/data/time_left/mouse4_sparse_dssim.txt"
        ));
        let king_dssim = recorded(include_str!(
            "../../tests/data/time_left/king4_sparse_dssim.txt"
        ));
        // The mouse grew 10 % a round towards its sparse-view cap of 11 634 kernels, at ½
        // size until 60 %; the king 5 % a round from 2978 kernels (its budget was below its
        // start), under a cap of twice that, at full size throughout.
        let mouse_growth = Growth {
            share: 0.1,
            every: 100,
            pruned: 0.0,
            target: Some(11_634.0),
            cap: Some(11_634),
        };
        let king_growth = Growth {
            share: 0.05,
            target: None,
            cap: Some(5956),
            ..mouse_growth
        };
        // Each under the MSE (`--loss mse`, the default before) and the 3DGS loss (the
        // default now).
        let (mse, dssim) = (TrainingLoss::Mse, crate::fit::defaults::DEFAULT_LOSS);
        let fits = [
            (&mouse, &[(2, 0.6)][..], mouse_growth, [360, 480], mse),
            (&king, &[][..], king_growth, [250, 164], mse),
            (
                &mouse_dssim,
                &[(2, 0.6)][..],
                mouse_growth,
                [360, 480],
                dssim,
            ),
            (&king_dssim, &[][..], king_growth, [250, 164], dssim),
        ];
        for (records, stages, growth, size, loss) in fits {
            let training = default_training(records, stages, loss, &growth);
            let estimate = TimeLeft::new(&training, size);
            assert_estimated_within_thirty_percent(
                estimate.clone().for_sparse_photos(true),
                size,
                records,
                0.1,
            );
            // At a tenth the first round has just run and none of its steps has been
            // timed: the model alone promises too little.
            let at_a_tenth = replay(estimate, records, &[0.1])[0];
            assert!(at_a_tenth.error() < -0.3, "{size:?}: {at_a_tenth:?}");
        }
    }

    /// Replays `records` of a fit of `training` on views of `size` through the estimate
    /// and asserts it within 30 % of the time left at every 0.5 % of the run from `first`
    /// to 90 % (printing it at every 5 %, and its worst).
    fn assert_estimated_within_thirty_percent(
        estimate: TimeLeft,
        size: [u32; 2],
        records: &[StepRecord],
        first: f64,
    ) {
        assert_eq!(estimate.window, (Some(200), size));
        let fractions: Vec<f64> = (0..=180)
            .map(|i| f64::from(i) * 0.005)
            .filter(|&f| f >= first - 1e-9)
            .collect();
        let points = replay(estimate, records, &fractions);
        assert_eq!(points.len(), fractions.len());
        let errors: Vec<String> = points
            .iter()
            .step_by(10)
            .map(|p| format!("{:+.2}", p.error()))
            .collect();
        let worst = points
            .iter()
            .map(Replayed::error)
            .fold(
                0.0,
                |worst: f64, e| if e.abs() > worst.abs() { e } else { worst },
            );
        eprintln!("{size:?}: {} (worst {worst:+.2})", errors.join(" "));
        for point in points {
            assert!(
                point.error().abs() < 0.3,
                "{size:?} after {} steps: {} s estimated, {} s left",
                point.steps,
                point.estimate,
                point.truth
            );
        }
    }

    #[test]
    fn nothing_is_promised_before_two_steps() {
        let mut estimate = TimeLeft::new(&training(), [400, 400]);
        assert_eq!(estimate.seconds_left(), None);
        estimate.record(&record(1, 0.1, 10, 1));
        assert_eq!(estimate.seconds_left(), None);
    }
}
