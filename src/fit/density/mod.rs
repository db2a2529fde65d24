//! Density control: how many kernels a fit has, and where (SPEC §6, §8). The two blends'
//! rule sets sit side by side, each a struct of thresholds chosen by the plan, over one
//! statistics type ([`DensityStats`]) that the training loop fills.
//!
//! | rule | additive ([`additive`]) | alpha ([`alpha`]) |
//! |---|---|---|
//! | judged by | mean positional gradient in the kernel's own σ, `\|s̄ ∂L/∂x…, st ∂L/∂t\|`, per step seen | mean screen gradient `\|∂L/∂m2\|` per pixel, per view seen |
//! | when | every `every` steps in the window, and only once the training loss has stalled | every `every` steps in the window |
//! | clone | half the amplitude each, the copy half a σ down the gradient | a copy in place (its Adam moments fresh) |
//! | split | above `min_scale`: spatial σ / 1.6, then cloned | above `percent_dense` of the box: two children ±σ/2 along the largest axis, σ / 1.6 |
//! | split in time | `st` above `min_time_scale`: two halves `±st/√2` on the path, `st/√2` and `A/√2` each (temporal mean, variance and integral kept) | σt above `time_split_fraction` of the range and moving more than its σ in one σt: two children `±σt/2` on the path, σt / 1.6 each (opacity kept) |
//! | merge | the same Gaussian within `merge_tolerance` σ, and halves of one path rejoined | — (opaque kernels do not add) |
//! | prune | peak \|amplitude\| below `prune_below` | opacity below `prune_opacity`; once growth ends, the lowest spatio-temporal scores ([`prune`], called by the training loop) |
//! | opacity reset | — | every `opacity_reset_every` steps, every opacity to at most `reset_opacity` |
//!
//! The additive split in time keeps the pair's integral because additive kernels add; an
//! opaque kernel's children each cover the parent's colour, so the alpha rule keeps the
//! opacity and only shortens σt. No randomness in either: a round depends only on the data
//! and the step schedule.

pub mod additive;
pub mod alpha;
pub mod prune;
pub mod shape;
pub mod turning;

use crate::backward::Gradients;
use crate::model::error::Result;
use crate::model::scene::Scene;

pub use additive::AdditiveRules;
pub use alpha::{AlphaRules, GrowthTarget};
pub use prune::SpacetimePrune;
pub use shape::ShapeBound;
pub use turning::{Pull, Turning, TurningRule};

/// A kernel's line of descent, carried from round to round: how many splits in time made
/// it, whether it carries fitted SPEC §9 motion (the alpha rules' motion where needed,
/// [`alpha`]) and how its velocity gradient has been turning ([`turning`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Line {
    /// Splits in time among the kernel's ancestors and itself.
    pub time_splits: u32,
    /// Whether its acceleration and angular velocity are fitted.
    pub moving: bool,
    /// Its turning state as of the last round (the default for a new kernel).
    pub turning: Turning,
}

/// Per-kernel statistics between two rounds, filled by the training loop: every step's
/// positional gradients ([`DensityStats::add_step`]), every view's screen gradients
/// ([`DensityStats::add_view`]) and, for the kernels without fitted motion, every step's
/// acceleration gradient ([`DensityStats::keep_motion_to_moving_kernels`]); the training
/// loss at the last two rounds; and each kernel's [`Line`], which the rounds carry on.
#[derive(Clone, Debug, Default)]
pub struct DensityStats {
    /// `Σ g̃` over steps (for the direction of an additive clone).
    position_sum: Vec<[f64; 4]>,
    /// `Σ |g̃|` over steps.
    position_norm_sum: Vec<f64>,
    /// Steps with a non-zero positional gradient.
    steps_seen: Vec<u32>,
    /// `Σ |∂L/∂m2|` over views, each view's loss unweighted by the batch.
    screen_sum: Vec<f64>,
    /// Views in which the kernel reached the screen.
    views_seen: Vec<u32>,
    /// `Σ ∂L/∂a` and `Σ |∂L/∂a|²` over steps, of kernels without fitted motion
    /// ([`turning`]).
    pulls: Vec<Pull>,
    /// Training loss at this round.
    loss: Option<f64>,
    /// Training loss at the round before.
    previous_loss: Option<f64>,
    /// Each kernel's line of descent.
    lines: Vec<Line>,
}

impl DensityStats {
    /// Statistics for `n` kernels, all zero.
    #[must_use]
    pub fn new(n: usize) -> Self {
        DensityStats {
            position_sum: vec![[0.0; 4]; n],
            position_norm_sum: vec![0.0; n],
            steps_seen: vec![0; n],
            screen_sum: vec![0.0; n],
            views_seen: vec![0; n],
            pulls: vec![Pull::default(); n],
            loss: None,
            previous_loss: None,
            lines: vec![Line::default(); n],
        }
    }

    /// Statistics after a round that left one kernel per entry of `lines` (their lines of
    /// descent): per-kernel sums cleared, this round's loss becomes the previous one.
    #[must_use]
    pub fn next_window(&self, lines: Vec<Line>) -> Self {
        let n = lines.len();
        DensityStats {
            previous_loss: self.loss,
            lines,
            ..DensityStats::new(n)
        }
    }

    /// Kernel `i`'s line of descent.
    #[must_use]
    pub fn line(&self, i: usize) -> Line {
        self.lines[i]
    }

    /// Kernel `i`'s acceleration gradients since the last round, while it had no fitted
    /// motion ([`turning`]).
    #[must_use]
    pub fn pull(&self, i: usize) -> &Pull {
        &self.pulls[i]
    }

    /// Zeroes the SPEC §9 gradients (acceleration, angular velocity) of every kernel that
    /// does not carry fitted motion, so that Adam leaves them (and their moments) at zero;
    /// their acceleration gradients are first added to the kernels' pulls ([`turning`]).
    pub fn keep_motion_to_moving_kernels(&mut self, grads: &mut Gradients) {
        for (i, line) in self.lines.iter().enumerate() {
            if !line.moving {
                if let Some(a) = grads.v_accelerations.get_mut(i) {
                    if *a != [0.0; 3] {
                        self.pulls[i].add(*a);
                    }
                    *a = [0.0; 3];
                }
                if let Some(w) = grads.v_angular_velocities.get_mut(i) {
                    *w = [0.0; 4];
                }
            }
        }
    }

    /// Records the training loss at this round.
    pub fn record_loss(&mut self, loss: f64) {
        self.loss = Some(loss);
    }

    /// Whether the loss fell by less than `min_improvement` since the round before.
    #[must_use]
    pub fn stalled(&self, min_improvement: f64) -> bool {
        match (self.previous_loss, self.loss) {
            // A loss that rose is still settling after the last round: not stalled.
            (Some(before), Some(now)) => (0.0..min_improvement * before).contains(&(before - now)),
            _ => false,
        }
    }

    /// Adds one step's positional gradients, each in its kernel's own size:
    /// `g̃ = (s̄ ∂L/∂x, s̄ ∂L/∂y, s̄ ∂L/∂z, st ∂L/∂t)`.
    pub fn add_step(&mut self, scene: &Scene, grads: &Gradients) {
        for i in 0..scene.len() {
            let g = grads.v_means[i];
            if g == [0.0; 4] {
                continue;
            }
            let st = scene.scales[i][3];
            let s = additive::mean_spatial_scale(scene.scales[i]);
            let scaled = [s * g[0], s * g[1], s * g[2], st * g[3]];
            for (acc, v) in self.position_sum[i].iter_mut().zip(scaled) {
                *acc += v;
            }
            self.position_norm_sum[i] += scaled.iter().map(|v| v * v).sum::<f64>().sqrt();
            self.steps_seen[i] += 1;
        }
    }

    /// Adds one view's screen gradients: `(kernel, ∂L/∂m2)` for every kernel it projected,
    /// the view's loss weighted by `weight` in the batch (divided out here).
    pub fn add_view(&mut self, screen: impl Iterator<Item = (usize, [f64; 2])>, weight: f64) {
        for (k, [gx, gy]) in screen {
            self.screen_sum[k] += (gx * gx + gy * gy).sqrt() / weight;
            self.views_seen[k] += 1;
        }
    }

    /// Mean `|g̃|` of kernel `i` over the steps it was seen.
    #[must_use]
    pub fn mean_position_gradient(&self, i: usize) -> f64 {
        if self.steps_seen[i] == 0 {
            0.0
        } else {
            self.position_norm_sum[i] / f64::from(self.steps_seen[i])
        }
    }

    /// `Σ g̃` of kernel `i`.
    #[must_use]
    pub fn position_sum(&self, i: usize) -> [f64; 4] {
        self.position_sum[i]
    }

    /// Mean `|∂L/∂m2|` of kernel `i` over the views that saw it.
    #[must_use]
    pub fn mean_screen_gradient(&self, i: usize) -> f64 {
        if self.views_seen[i] == 0 {
            0.0
        } else {
            self.screen_sum[i] / f64::from(self.views_seen[i])
        }
    }

    /// Whether kernel `i` reached the screen in some view since the last round.
    #[must_use]
    pub fn seen_on_screen(&self, i: usize) -> bool {
        self.views_seen[i] > 0
    }
}

/// The rule set of a fit's blend.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum DensityRules {
    /// Densify, prune, merge and rejoin, by the loss and positional gradients.
    Additive(AdditiveRules),
    /// Clone, split, split in time, prune by opacity and reset opacities (3DGS, 4DGS).
    Alpha(AlphaRules),
}

/// What a step's density control did to the scene.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DensityChange {
    /// Every opacity was lowered: its optimiser state is stale.
    pub opacities_reset: bool,
    /// The kernels changed: per kernel of the new scene, the old kernel whose optimiser
    /// state it keeps (`None`: a new kernel).
    pub sources: Option<Vec<Option<usize>>>,
    /// The new scene's lines of descent (moved into the statistics).
    lines: Vec<Line>,
}

impl DensityRules {
    /// The last step (1-based) of a run of `steps` after which a round may add kernels.
    #[must_use]
    pub fn growth_ends(&self, steps: usize) -> usize {
        let until = match self {
            DensityRules::Additive(rules) => rules.until * steps as f64,
            DensityRules::Alpha(rules) => rules.until * (steps.max(2) - 1) as f64 + 1.0,
        };
        (until.max(0.0) as usize).min(steps)
    }

    /// Whether only the kernels that keep splitting in time or whose velocity gradient
    /// keeps turning over their life carry fitted SPEC §9 motion ([`alpha`], [`turning`]): the others'
    /// SPEC §9 gradients are then kept at zero
    /// ([`DensityStats::keep_motion_to_moving_kernels`]).
    #[must_use]
    pub fn fits_motion_where_needed(&self) -> bool {
        matches!(self, DensityRules::Alpha(rules)
            if rules.motion_after_time_splits.is_some() || rules.motion_when_turning.is_some())
    }

    /// The largest share of the kernels one round may add (0 without rounds).
    #[must_use]
    pub fn max_round_share(&self) -> f64 {
        let (share, every) = match self {
            DensityRules::Additive(rules) => (rules.max_growth, rules.every),
            DensityRules::Alpha(rules) => (rules.max_share(), rules.every),
        };
        if every == 0 { 0.0 } else { share.max(0.0) }
    }

    /// The most kernels the rules may reach.
    #[must_use]
    pub fn max_kernels(&self) -> usize {
        match self {
            DensityRules::Additive(rules) => rules.max_kernels,
            DensityRules::Alpha(rules) => rules.max_kernels,
        }
    }
    /// The rules' work after step `step` (1-based) of `steps`: a round when one is due
    /// (then `stats` start a new window), an opacity reset when one is due.
    /// `training_loss` measures the loss over every training view, for rules that judge by
    /// it.
    pub fn after_step(
        &self,
        (step, steps): (usize, usize),
        scene: &mut Scene,
        stats: &mut DensityStats,
        training_loss: impl FnOnce(&Scene) -> Result<f64>,
    ) -> Result<DensityChange> {
        let mut change = DensityChange::default();
        match self {
            DensityRules::Additive(rules) => {
                if rules.round_after(step, steps) {
                    stats.record_loss(training_loss(scene)?);
                    let round = if rules.last_round_after(step, steps) {
                        rules.without_growth()
                    } else {
                        *rules
                    };
                    let (next, sources, _) = additive::densify_and_prune(scene, stats, &round)?;
                    *scene = next;
                    change.lines = vec![Line::default(); sources.len()];
                    change.sources = Some(sources);
                }
            }
            DensityRules::Alpha(rules) => {
                if rules.reset_due(step, steps) {
                    alpha::reset_opacities(scene, rules.reset_opacity);
                    change.opacities_reset = true;
                }
                if rules.round_due(step, steps) {
                    let rounds_left = rules.rounds_from(step, steps);
                    let (sources, lines) =
                        alpha::densify_and_prune(scene, stats, rules, rounds_left);
                    change.sources = Some(sources);
                    change.lines = lines;
                }
            }
        }
        if change.sources.is_some() {
            *stats = stats.next_window(std::mem::take(&mut change.lines));
        }
        Ok(change)
    }
}
