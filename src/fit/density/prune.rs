//! The alpha fit's pruning by a spatio-temporal score (SPEC §8; the criterion of 4DGS-1K,
//! "1000+ FPS 4D Gaussian Splatting", reworded for this renderer): after growth ends, the
//! kernels that contribute least to the training views over their life are removed, a
//! kernel that lives briefly counting for less.
//!
//! **Score.** Kernel `i`'s contribution to a view is `c_i = Σ_pixels α̂_i T_i`, its weight in
//! every pixel it composites (SPEC §8: `α̂ = min(0.99, o(τ) e^{-q/2})`, `T` the light that
//! reaches it; 0 where it is culled or after a pixel's stop). Its temporal weight at the
//! view's time τ is
//!
//! ```text
//! p(τ) = exp(-½ ((τ - t)/st)²)                 the temporal weight of SPEC §2
//! p''(τ) = p(τ) ((τ - t)² / st⁴ - 1 / st²)     its second derivative in τ
//! w(τ) = 2 / (1 + tanh(Δ² |p''(τ)|))           in [1, 2]
//! ```
//!
//! with `Δ` the spacing of the training times (their range over the distinct times less
//! one): `Δ² |p''|` is how much the kernel's opacity bends between neighbouring frames, near
//! 0 for a kernel that lives many frames (weight 2), near or above 1 for one that lives about
//! a frame (weight about 1). The score is `S_i = Σ_views c_i(view) · w_i(τ_view)`: summed
//! over every training view, so over the kernel's whole life.
//!
//! **Rounds.** `rounds` rounds, the first after the step at which growth ends and then every
//! `every` steps, each removing the lowest-scored `1 - (1 - fraction)^(1/rounds)` of the
//! kernels (ties by index), so that together they remove `fraction`. The kernels kept keep
//! their order and their optimiser state.

use crate::model::scene::Scene;

/// The pruning rule (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SpacetimePrune {
    /// The fraction of the kernels the rounds remove together, in `[0, 1)`.
    pub fraction: f64,
    /// Rounds (at least 1).
    pub rounds: usize,
    /// Steps between rounds.
    pub every: usize,
}

impl SpacetimePrune {
    /// The fraction of the kernels removed after step `step` when growth ends after step
    /// `growth_ends`, or `None` when no round is due.
    #[must_use]
    pub fn due(&self, step: usize, growth_ends: usize) -> Option<f64> {
        let rounds = self.rounds.max(1);
        if self.fraction <= 0.0 || step < growth_ends {
            return None;
        }
        let since = step - growth_ends;
        let round = if self.every == 0 {
            (since == 0).then_some(0)?
        } else {
            (since.is_multiple_of(self.every)).then_some(since / self.every)?
        };
        (round < rounds).then(|| 1.0 - (1.0 - self.fraction).powf(1.0 / rounds as f64))
    }
}

/// The temporal weight `w(τ)` of a kernel with time mean `t` and σt `st` at `tau`, the
/// training times `spacing` apart (see the module docs).
#[must_use]
pub fn temporal_weight(t: f64, st: f64, tau: f64, spacing: f64) -> f64 {
    let d = (tau - t) / st;
    let p = (-0.5 * d * d).exp();
    let bend = p * (d * d - 1.0) / (st * st);
    2.0 / (1.0 + (spacing * spacing * bend.abs()).tanh())
}

/// The spacing of `times`: their range over the distinct values less one (1 when there are
/// fewer than two).
#[must_use]
pub fn time_spacing(times: &[f64]) -> f64 {
    let mut sorted = times.to_vec();
    sorted.sort_by(f64::total_cmp);
    sorted.dedup();
    match (sorted.first(), sorted.last()) {
        (Some(lo), Some(hi)) if sorted.len() > 1 => (hi - lo) / (sorted.len() - 1) as f64,
        _ => 1.0,
    }
}

/// The kernels kept when the lowest-scored `fraction` of `scores` (the nearest whole count)
/// is removed (ties by index: of equal scores the later goes first), in index order.
#[must_use]
pub fn kept_after_pruning(scores: &[f64], fraction: f64) -> Vec<usize> {
    let n = scores.len();
    let remove = ((fraction.clamp(0.0, 1.0) * n as f64).round() as usize).min(n);
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| scores[b].total_cmp(&scores[a]).then(a.cmp(&b)));
    let mut keep = order[..n - remove].to_vec();
    keep.sort_unstable();
    keep
}

/// Keeps only the kernels `keep` (indices, ascending) of `scene`. Returns, per kernel of the
/// new scene, the old kernel whose optimiser state it keeps.
pub fn keep_kernels(scene: &mut Scene, keep: &[usize]) -> Vec<Option<usize>> {
    let mut next = Scene {
        background: scene.background,
        up: scene.up,
        blend: scene.blend,
        sh_count: scene.sh_count,
        ..Scene::default()
    };
    for &i in keep {
        next.push_kernel(&scene.kernel(i));
        next.opacities.push(scene.opacities[i]);
        next.sh.extend_from_slice(scene.sh_of(i));
    }
    *scene = next;
    keep.iter().map(|&i| Some(i)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_temporal_weight_is_two_for_a_long_life_and_near_one_for_a_frame() {
        // σt of 100 frames: the opacity barely bends between frames.
        assert!((temporal_weight(0.5, 1.0, 0.5, 0.01) - 2.0).abs() < 1e-3);
        // σt of one frame, at its peak: Δ²|p''| = 1.
        let peak = temporal_weight(0.5, 0.01, 0.5, 0.01);
        assert!((peak - 2.0 / (1.0 + 1f64.tanh())).abs() < 1e-12, "{peak}");
        // At its inflection points p'' = 0: the weight is 2 there.
        assert!((temporal_weight(0.5, 0.01, 0.51, 0.01) - 2.0).abs() < 1e-9);
    }

    #[test]
    fn the_rounds_remove_the_fraction_together_after_growth_ends() {
        let rule = SpacetimePrune {
            fraction: 0.75,
            rounds: 2,
            every: 100,
        };
        let due: Vec<(usize, f64)> = (1..=1000)
            .filter_map(|s| rule.due(s, 600).map(|f| (s, f)))
            .collect();
        assert_eq!(due.iter().map(|d| d.0).collect::<Vec<_>>(), [600, 700]);
        assert!(due.iter().all(|d| (d.1 - 0.5).abs() < 1e-12));
        assert_eq!(rule.due(600, 600).map(|_| ()), Some(()));
        let off = SpacetimePrune {
            fraction: 0.0,
            ..rule
        };
        assert!((1..=1000).all(|s| off.due(s, 600).is_none()));
    }

    #[test]
    fn pruning_keeps_the_highest_scores_in_index_order() {
        let scores = [0.5, 3.0, 0.0, 2.0, 0.5, 1.0];
        assert_eq!(kept_after_pruning(&scores, 0.5), [1, 3, 5]);
        // Ties by index: of the two 0.5 the later goes first.
        assert_eq!(kept_after_pruning(&scores, 2.0 / 6.0), [0, 1, 3, 5]);
        assert_eq!(kept_after_pruning(&scores, 0.0), [0, 1, 2, 3, 4, 5]);
        assert_eq!(time_spacing(&[0.0, 1.0, 0.5, 0.5, 0.25, 0.75]), 0.25);
    }
}
