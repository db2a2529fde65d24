//! The alpha blend's density rules (SPEC §8; 3D Gaussian splatting's, with 4DGS's split in
//! time): clone, split, split in time, prune by opacity, opacity reset.
//!
//! Every `every` steps while the run's progress `(step - 1)/(steps - 1)` lies in
//! `[from, until]`, the kernels whose mean screen-space positional gradient `|∂L/∂m2|`
//! over the views that saw them is among the largest `share` of the visible kernels (and
//! at least `threshold`; ties by index; never beyond `max_kernels`) grow. The share is
//! `fraction`, or with a [`GrowthTarget`] of `K` kernels the share that would take the `n`
//! kept kernels there in the `r` rounds left, `(K/n)^(1/r) - 1` (rounded to 1e-4), kept
//! within `[fraction, max_share]`: a kernel budget that the pruning of transparent kernels
//! along the way does not leave short. The kernels grown:
//!
//! - **split in time** when the kernel spans motion: σt above `time_split_fraction` of the
//!   time range and `|v| σt` above its largest spatial σ. Two children at `t ± σt/2`, σt / 1.6
//!   each, their means moved along the velocity so that both follow the parent's path.
//!   (The additive rule, [`super::additive`], splits at `±st/√2` and keeps the temporal
//!   integral, because additive kernels add; opaque children each cover the parent.)
//! - **motion where needed** (when `motion_after_time_splits` is `n`): a kernel that spans
//!   motion, does not yet carry fitted motion and whose line was already split in time `n`
//!   times keeps splitting because one straight piece cannot follow its path: instead of a
//!   further split it is given SPEC §9 motion, its acceleration and angular velocity fitted
//!   from then on (they start at zero, so its path is unchanged). A moving kernel that
//!   still spans motion splits in time, and its children move. The training loop keeps
//!   the other kernels' SPEC §9 gradients at zero
//!   ([`DensityStats::keep_motion_to_moving_kernels`]).
//! - **motion when turning** (when `motion_when_turning` is a rule): before any of the
//!   above, every kept kernel whose velocity gradient keeps turning from interval to
//!   interval ([`super::turning`]) is given SPEC §9 motion the same way, whether it grows
//!   this round or not.
//! - **split** when its largest σ exceeds `percent_dense` of the box's diagonal: two
//!   children one σ apart along that axis, spatial σ / 1.6 each.
//! - **clone** otherwise: a copy in place, with fresh optimiser moments.
//!
//! Kernels whose opacity fell below `prune_opacity` are removed. Every
//! `opacity_reset_every` steps while the rounds run (never at the last step), every opacity
//! is lowered to at most `reset_opacity`: what the views need regains its opacity, the rest
//! fades below `prune_opacity` and is pruned.

use crate::fit::density::{DensityStats, Line, Turning, TurningRule};
use crate::model::scene::{Kernel, Scene};

/// The alpha rule set (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AlphaRules {
    /// Steps between rounds.
    pub every: usize,
    /// Rounds from this fraction of the run …
    pub from: f64,
    /// … until this one.
    pub until: f64,
    /// Fraction of the visible kernels densified per round, at most.
    pub fraction: f64,
    /// Smallest mean `|∂L/∂m2|` (per pixel) that densifies.
    pub threshold: f64,
    /// Upper bound on the kernel count.
    pub max_kernels: usize,
    /// A kernel is split rather than cloned when its largest σ exceeds this fraction of
    /// `diagonal`.
    pub percent_dense: f64,
    /// A densified kernel whose σt exceeds this fraction of `time_range`, and which moves
    /// further than its largest spatial σ within one σt, is split in time.
    pub time_split_fraction: f64,
    /// Kernels below this opacity are pruned.
    pub prune_opacity: f64,
    /// Steps between opacity resets while rounds run (0: never).
    pub opacity_reset_every: usize,
    /// The opacity a reset lowers every kernel to, at most.
    pub reset_opacity: f64,
    /// The cameras' box diagonal: the unit of `percent_dense`.
    pub diagonal: f64,
    /// The training times' range: the unit of `time_split_fraction`.
    pub time_range: f64,
    /// A kernel that spans motion after this many splits in time of its line is given
    /// fitted SPEC §9 motion instead of a further split; `None`: never (no kernel's motion
    /// is fitted, or every kernel's is).
    pub motion_after_time_splits: Option<u32>,
    /// A kernel whose velocity gradient keeps turning by this rule is given fitted SPEC §9
    /// motion ([`super::turning`]); `None`: never.
    pub motion_when_turning: Option<TurningRule>,
    /// The kernel count the rounds grow towards (`None`: each grows by `fraction`).
    pub growth_target: Option<GrowthTarget>,
}

/// The kernel count a fit's density rounds grow towards, each round by the share that
/// would reach it in the rounds left (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GrowthTarget {
    /// The kernels to reach when growth ends.
    pub kernels: f64,
    /// The largest share of the visible kernels a round may grow.
    pub max_share: f64,
}

impl AlphaRules {
    /// The run's progress after step `step` of `steps`: 0 at the first, 1 at the last.
    fn progress(step: usize, steps: usize) -> f64 {
        (step - 1) as f64 / (steps.max(2) - 1) as f64
    }

    /// The steps of a run of `steps` after which a round runs, in order.
    pub fn round_steps(&self, steps: usize) -> impl Iterator<Item = usize> + '_ {
        (1..=steps).filter(move |&s| self.round_due(s, steps))
    }

    /// The rounds that run after steps `step..=steps` of `steps`.
    #[must_use]
    pub fn rounds_from(&self, step: usize, steps: usize) -> usize {
        self.round_steps(steps).filter(|&s| s >= step).count()
    }

    /// The share of the visible kernels a round grows when `kept` kernels are kept and
    /// `rounds_left` rounds remain, this one included (see the module docs).
    #[must_use]
    pub fn round_share(&self, kept: usize, rounds_left: usize) -> f64 {
        let Some(target) = self.growth_target else {
            return self.fraction;
        };
        if kept == 0 || rounds_left == 0 || target.kernels <= kept as f64 {
            return self.fraction;
        }
        let needed = (target.kernels / kept as f64).powf(1.0 / rounds_left as f64) - 1.0;
        // Rounded, so that no last bit of `powf` decides a kernel count.
        let needed = (needed * 1e4).round() / 1e4;
        needed.min(target.max_share).max(self.fraction)
    }

    /// The largest share of the visible kernels a round may grow.
    #[must_use]
    pub fn max_share(&self) -> f64 {
        self.growth_target
            .map_or(self.fraction, |target| target.max_share.max(self.fraction))
    }

    /// Whether a round runs after `step` of `steps`.
    #[must_use]
    pub fn round_due(&self, step: usize, steps: usize) -> bool {
        let progress = Self::progress(step, steps);
        self.every > 0
            && step.is_multiple_of(self.every)
            && progress >= self.from
            && progress <= self.until
    }

    /// Whether the opacities are reset after `step` of `steps`: every
    /// `opacity_reset_every` steps while the rounds run, never at the last step.
    #[must_use]
    pub fn reset_due(&self, step: usize, steps: usize) -> bool {
        self.opacity_reset_every > 0
            && step.is_multiple_of(self.opacity_reset_every)
            && Self::progress(step, steps) <= self.until
            && step < steps
    }
}

/// Lowers every opacity to at most `ceiling`.
pub fn reset_opacities(scene: &mut Scene, ceiling: f64) {
    for opacity in &mut scene.opacities {
        *opacity = opacity.min(ceiling);
    }
}

/// One round, with `rounds_left` rounds left (this one included): prune transparent
/// kernels, give motion to those whose velocity gradient keeps turning, then clone, split,
/// split in time or give motion to the ones with the largest mean screen-space gradient.
/// Returns, per kernel of the new scene, the old kernel whose optimiser state it keeps
/// (`None`: fresh) and its line of descent: a kept kernel (or one given motion) keeps its
/// turning state, a new one starts afresh.
pub fn densify_and_prune(
    scene: &mut Scene,
    stats: &DensityStats,
    rules: &AlphaRules,
    rounds_left: usize,
) -> (Vec<Option<usize>>, Vec<Line>) {
    let n = scene.len();
    let keep: Vec<usize> = (0..n)
        .filter(|&i| scene.opacities[i] >= rules.prune_opacity)
        .collect();
    let share = rules.round_share(keep.len(), rounds_left);
    let grow = chosen_to_grow(&keep, stats, rules, share, n);
    let mut next = Scene {
        background: scene.background,
        up: scene.up,
        ..Scene::default()
    };
    let (mut opacities, mut sh, mut sources) = (Vec::new(), Vec::new(), Vec::new());
    let mut lines = Vec::new();
    let mut push =
        |kernel: Kernel, (i, line): (usize, Line), source: Option<usize>, next: &mut Scene| {
            next.push_kernel(&kernel);
            opacities.push(scene.opacities[i]);
            sh.extend_from_slice(scene.sh_of(i));
            sources.push(source);
            lines.push(match source {
                Some(_) => line,
                None => Line {
                    turning: Turning::default(),
                    ..line
                },
            });
        };
    for &i in &keep {
        let (kernel, line) = (scene.kernel(i), line_after_round(stats, i, rules));
        if !grow[i] {
            push(kernel, (i, line), Some(i), &mut next);
            continue;
        }
        let largest = largest_axis(&kernel);
        if spans_motion(&kernel, largest, rules) {
            if needs_motion(line, rules) {
                // Its moments stay: only the SPEC §9 gradients, zero until now, start.
                let moving = Line {
                    moving: true,
                    ..line
                };
                push(kernel, (i, moving), Some(i), &mut next);
                continue;
            }
            let child_line = Line {
                time_splits: line.time_splits.saturating_add(1),
                ..line
            };
            for child in split_in_time(kernel) {
                push(child, (i, child_line), None, &mut next);
            }
        } else if kernel.scale[largest] > rules.percent_dense * rules.diagonal {
            for child in split(kernel, largest) {
                push(child, (i, line), None, &mut next);
            }
        } else {
            // Clone: the original keeps its moments, the copy starts fresh.
            push(kernel, (i, line), Some(i), &mut next);
            push(kernel, (i, line), None, &mut next);
        }
    }
    next.blend = scene.blend;
    next.opacities = opacities;
    next.sh_count = scene.sh_count;
    next.sh = sh;
    *scene = next;
    (sources, lines)
}

/// Kernel `i`'s line after this round's turning rule ([`super::turning`]): its turning state
/// moved on by the interval's pull (the default without the rule, or once it moves), and
/// moving when that state keeps turning.
fn line_after_round(stats: &DensityStats, i: usize, rules: &AlphaRules) -> Line {
    let line = stats.line(i);
    let turning = match rules.motion_when_turning {
        Some(rule) if !line.moving => rule.after_round(line.turning, stats.pull(i)),
        _ => Turning::default(),
    };
    let turns = rules
        .motion_when_turning
        .is_some_and(|rule| rule.keeps_turning(turning));
    Line {
        moving: line.moving || turns,
        turning,
        ..line
    }
}

/// Whether a kernel of `line` that spans motion is given fitted motion rather than split in
/// time again (see the module docs).
fn needs_motion(line: Line, rules: &AlphaRules) -> bool {
    rules
        .motion_after_time_splits
        .is_some_and(|n| !line.moving && line.time_splits >= n)
}

/// Per kernel, whether it grows this round: of the kept ones, the largest mean screen
/// gradients at or above the threshold, ties by index, at most `share` of the visible
/// kept kernels and never beyond `max_kernels`.
fn chosen_to_grow(
    keep: &[usize],
    stats: &DensityStats,
    rules: &AlphaRules,
    share: f64,
    n: usize,
) -> Vec<bool> {
    let mut candidates: Vec<usize> = keep
        .iter()
        .copied()
        .filter(|&i| stats.mean_screen_gradient(i) >= rules.threshold)
        .collect();
    candidates.sort_by(|&a, &b| {
        stats
            .mean_screen_gradient(b)
            .total_cmp(&stats.mean_screen_gradient(a))
            .then(a.cmp(&b))
    });
    let visible = keep.iter().filter(|&&i| stats.seen_on_screen(i)).count();
    let budget =
        ((share * visible as f64) as usize).min(rules.max_kernels.saturating_sub(keep.len()));
    candidates.truncate(budget);
    let mut grow = vec![false; n];
    for &i in &candidates {
        grow[i] = true;
    }
    grow
}

/// The spatial axis of the kernel's largest σ.
fn largest_axis(kernel: &Kernel) -> usize {
    (0..3)
        .max_by(|&a, &b| kernel.scale[a].total_cmp(&kernel.scale[b]))
        .expect("three axes")
}

/// Whether `kernel` spans motion: σt above the rules' share of the time range, and it moves
/// further than its largest σ (along axis `largest`) within one σt.
fn spans_motion(kernel: &Kernel, largest: usize, rules: &AlphaRules) -> bool {
    let speed = kernel.velocity.iter().map(|v| v * v).sum::<f64>().sqrt();
    let time_sigma = kernel.scale[3];
    time_sigma > rules.time_split_fraction * rules.time_range
        && speed * time_sigma > kernel.scale[largest]
}

/// The two children of a split along axis `largest`: one σ apart, σ / 1.6 each.
fn split(kernel: Kernel, largest: usize) -> [Kernel; 2] {
    // A turning kernel's stored quaternion is not unit (SPEC §9): its axes at t are q/|q|.
    let r = crate::slice::rotation_matrix(if kernel.turns() {
        crate::slice::unit_quaternion(kernel.rotation)
    } else {
        kernel.rotation
    });
    let sigma = kernel.scale[largest];
    let mut child = kernel;
    for a in 0..3 {
        child.scale[a] /= 1.6;
    }
    [-0.5, 0.5].map(|sign| {
        let mut placed = child;
        for (mean, row) in placed.mean.iter_mut().zip(&r) {
            *mean += sign * sigma * row[largest];
        }
        placed
    })
}

/// The two children of a split in time: σt / 2 either side of the parent's time mean,
/// σt / 1.6 each, their means moved along the parent's path (its velocity, and SPEC §9's
/// acceleration and turn) so that both follow it.
fn split_in_time(kernel: Kernel) -> [Kernel; 2] {
    let time_sigma = kernel.scale[3];
    [-0.5, 0.5].map(|sign| {
        let mut child = kernel;
        child.scale[3] /= 1.6;
        child.advance_on_path(sign * time_sigma);
        child
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fit::density::TurningRule;

    /// Rules with every visible kernel allowed to grow, in a unit box and time range.
    fn grow_all() -> AlphaRules {
        AlphaRules {
            every: 100,
            from: 0.0,
            until: 1.0,
            fraction: 1.0,
            threshold: 0.0,
            max_kernels: 100,
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
        }
    }

    /// One alpha kernel with `velocity` and σt `time_sigma`, opacity 0.8.
    fn one_kernel(velocity: [f64; 3], time_sigma: f64) -> Scene {
        let mut kernel = Kernel::new(
            [0.1, 0.2, 0.3, 0.5],
            [0.01, 0.01, 0.01, time_sigma],
            [0.5; 3],
        );
        kernel.velocity = velocity;
        Scene::from_kernels(&[kernel], [0.0; 3], "<test>")
            .unwrap()
            .into_alpha(vec![0.8], 0, Vec::new(), "<test>")
            .unwrap()
    }

    /// Statistics in which kernel 0 was seen once with a screen gradient of 1.
    fn seen_once() -> DensityStats {
        let mut stats = DensityStats::new(1);
        stats.add_view([(0, [1.0, 0.0])].into_iter(), 1.0);
        stats
    }

    /// The slice centre of kernel `i` at `tau` (SPEC §2: `m + v (τ - t)`).
    fn centre_at(scene: &Scene, i: usize, tau: f64) -> [f64; 3] {
        std::array::from_fn(|a| {
            scene.means[i][a] + scene.velocities[i][a] * (tau - scene.means[i][3])
        })
    }

    #[test]
    fn a_kernel_that_spans_motion_splits_in_time_along_its_path() {
        let mut scene = one_kernel([1.0, 0.0, -0.5], 0.3);
        let (sources, lines) = densify_and_prune(&mut scene, &seen_once(), &grow_all(), 1);
        assert_eq!(sources, vec![None, None]);
        let child = Line {
            time_splits: 1,
            moving: false,
            ..Line::default()
        };
        assert_eq!(lines, vec![child; 2]);
        assert_eq!(scene.len(), 2);
        let times = [scene.means[0][3], scene.means[1][3]];
        assert!((times[0] - 0.35).abs() < 1e-12 && (times[1] - 0.65).abs() < 1e-12);
        for i in 0..2 {
            assert!((scene.scales[i][3] - 0.3 / 1.6).abs() < 1e-12);
            for tau in [0.0, 0.5, 1.0] {
                let [a, b] = [
                    centre_at(&scene, i, tau),
                    centre_at(&one_kernel([1.0, 0.0, -0.5], 0.3), 0, tau),
                ];
                assert!((0..3).all(|k| (a[k] - b[k]).abs() < 1e-12), "{a:?} {b:?}");
            }
        }
    }

    /// Statistics in which one kernel of `line` was seen once with a screen gradient of 1.
    fn seen_once_on(line: Line) -> DensityStats {
        let mut stats = DensityStats::new(1).next_window(vec![line]);
        stats.add_view([(0, [1.0, 0.0])].into_iter(), 1.0);
        stats
    }

    #[test]
    fn a_kernel_that_keeps_splitting_in_time_gets_motion_instead_and_then_splits_moving() {
        let motion_after_one = AlphaRules {
            motion_after_time_splits: Some(1),
            ..grow_all()
        };
        let once_split = Line {
            time_splits: 1,
            moving: false,
            ..Line::default()
        };
        // A first split in time, as without the rule.
        let mut scene = one_kernel([1.0, 0.0, -0.5], 0.3);
        let fresh = seen_once_on(Line::default());
        let (_, lines) = densify_and_prune(&mut scene, &fresh, &motion_after_one, 1);
        assert_eq!(lines, vec![once_split; 2]);
        // A kernel split once that still spans motion: kept whole, moments kept, moving.
        let mut scene = one_kernel([1.0, 0.0, -0.5], 0.3);
        let before = scene.clone();
        let (sources, lines) =
            densify_and_prune(&mut scene, &seen_once_on(once_split), &motion_after_one, 1);
        assert_eq!(sources, vec![Some(0)]);
        let moving = Line {
            moving: true,
            ..once_split
        };
        assert_eq!(lines, vec![moving]);
        assert_eq!(scene.kernel(0), before.kernel(0));
        // A moving kernel that still spans motion splits in time, its children moving.
        let (sources, lines) =
            densify_and_prune(&mut scene, &seen_once_on(moving), &motion_after_one, 1);
        assert_eq!(sources, vec![None, None]);
        let children = Line {
            time_splits: 2,
            moving: true,
            ..Line::default()
        };
        assert_eq!(lines, vec![children; 2]);
        // Without the rule, the kernel split once splits again.
        let mut scene = one_kernel([1.0, 0.0, -0.5], 0.3);
        let (_, lines) = densify_and_prune(&mut scene, &seen_once_on(once_split), &grow_all(), 1);
        assert_eq!(lines.len(), 2);
        assert!(lines.iter().all(|l| l.time_splits == 2 && !l.moving));
    }

    /// The statistics of one kernel, `stats`, after `steps` steps in which its
    /// acceleration gradient was `g`, and seen once.
    fn pulled(mut stats: DensityStats, g: [f64; 3], steps: usize) -> DensityStats {
        for _ in 0..steps {
            let mut grads = crate::backward::Gradients {
                v_accelerations: vec![g],
                v_angular_velocities: vec![[0.0; 4]],
                ..Default::default()
            };
            stats.keep_motion_to_moving_kernels(&mut grads);
        }
        stats.add_view([(0, [1.0, 0.0])].into_iter(), 1.0);
        stats
    }

    #[test]
    fn a_kernel_whose_velocity_gradient_keeps_turning_gets_motion_and_its_copy_starts_afresh() {
        let rules = AlphaRules {
            motion_when_turning: Some(TurningRule {
                min_steadiness: 3.0,
                min_cosine: 0.5,
                rounds: 2,
            }),
            fraction: 0.0,
            ..grow_all()
        };
        // A still kernel, steadily pulled towards a fall: one round counts, the second
        // makes it move (no kernel grows; the kernel and its moments are kept).
        let mut scene = one_kernel([0.0; 3], 0.3);
        let before = scene.clone();
        let stats = pulled(DensityStats::new(1), [0.0, -1.0, 0.0], 100);
        let (sources, lines) = densify_and_prune(&mut scene, &stats, &rules, 1);
        assert_eq!(sources, vec![Some(0)]);
        assert!(!lines[0].moving && lines[0].turning.rounds() == 1);
        let stats = pulled(stats.next_window(lines), [0.0, -1.0, 0.0], 100);
        let (_, lines) = densify_and_prune(&mut scene, &stats, &rules, 1);
        assert!(lines[0].moving);
        assert_eq!(scene.kernel(0), before.kernel(0));
        // Without the rule, the same pulls give no motion.
        let mut scene = one_kernel([0.0; 3], 0.3);
        let stats = pulled(DensityStats::new(1), [0.0, -1.0, 0.0], 100);
        let (_, lines) = densify_and_prune(&mut scene, &stats, &grow_all(), 1);
        assert_eq!(lines[0].turning, Turning::default());
        let stats = pulled(stats.next_window(lines), [0.0, -1.0, 0.0], 100);
        let (_, lines) = densify_and_prune(&mut scene, &stats, &grow_all(), 1);
        assert!(!lines[0].moving);
        // A pull that reverses each round never counts twice.
        let mut scene = one_kernel([0.0; 3], 0.3);
        let mut stats = pulled(DensityStats::new(1), [1.0, 0.0, 0.0], 100);
        for sign in [-1.0, 1.0, -1.0] {
            let (_, lines) = densify_and_prune(&mut scene, &stats, &rules, 1);
            assert!(!lines[0].moving && lines[0].turning.rounds() == 1);
            stats = pulled(stats.next_window(lines), [sign, 0.0, 0.0], 100);
        }
        // Once counted, a cloned kernel keeps its count and its copy starts at zero.
        let clone_all = AlphaRules {
            fraction: 1.0,
            ..rules
        };
        let mut scene = one_kernel([0.0; 3], 0.3);
        let stats = pulled(DensityStats::new(1), [0.0, -1.0, 0.0], 100);
        let (sources, lines) = densify_and_prune(&mut scene, &stats, &clone_all, 1);
        assert_eq!(sources, vec![Some(0), None]);
        assert_eq!(
            lines
                .iter()
                .map(|line| line.turning.rounds())
                .collect::<Vec<_>>(),
            [1, 0]
        );
    }

    #[test]
    fn only_moving_kernels_keep_their_motion_gradients() {
        let still = Line::default();
        let moving = Line {
            moving: true,
            ..still
        };
        let mut stats = DensityStats::new(3).next_window(vec![still, moving, still]);
        let mut grads = crate::backward::Gradients {
            v_accelerations: vec![[1.0, 2.0, 3.0]; 3],
            v_angular_velocities: vec![[4.0, 5.0, 6.0, 7.0]; 3],
            ..Default::default()
        };
        stats.keep_motion_to_moving_kernels(&mut grads);
        assert_eq!(
            grads.v_accelerations,
            vec![[0.0; 3], [1.0, 2.0, 3.0], [0.0; 3]]
        );
        assert_eq!(
            grads.v_angular_velocities,
            vec![[0.0; 4], [4.0, 5.0, 6.0, 7.0], [0.0; 4]]
        );
        // The still kernels' acceleration gradients went to their pulls, the moving one's
        // did not.
        let mut pull = crate::fit::density::Pull::default();
        pull.add([1.0, 2.0, 3.0]);
        assert_eq!(stats.pull(0), &pull);
        assert_eq!(stats.pull(1), &crate::fit::density::Pull::default());
        assert_eq!(stats.pull(2), &pull);
    }

    #[test]
    fn a_still_or_short_lived_kernel_is_cloned_in_space_not_split_in_time() {
        for (velocity, time_sigma) in [([0.0; 3], 0.3), ([1.0, 0.0, 0.0], 0.01)] {
            let mut scene = one_kernel(velocity, time_sigma);
            let (sources, _) = densify_and_prune(&mut scene, &seen_once(), &grow_all(), 1);
            assert_eq!(sources, vec![Some(0), None]);
            assert_eq!(scene.means[0], scene.means[1]);
        }
    }

    #[test]
    fn a_reset_lowers_every_opacity_to_the_ceiling_and_is_due_only_while_rounds_run() {
        let mut scene = one_kernel([0.0; 3], 0.3);
        reset_opacities(&mut scene, 0.01);
        assert_eq!(scene.opacities, vec![0.01]);
        let rules = AlphaRules {
            opacity_reset_every: 10,
            until: 0.5,
            ..grow_all()
        };
        let due: Vec<usize> = (1..=101).filter(|&s| rules.reset_due(s, 101)).collect();
        assert_eq!(due, [10, 20, 30, 40, 50]);
    }

    /// Rules that grow at least 5 % and towards `kernels`, at most 15 %, a round every 10
    /// steps over the whole of a 330-step run (33 rounds).
    fn towards(kernels: f64) -> AlphaRules {
        AlphaRules {
            every: 10,
            fraction: 0.05,
            max_kernels: 1_000_000,
            growth_target: Some(GrowthTarget {
                kernels,
                max_share: 0.15,
            }),
            ..grow_all()
        }
    }

    #[test]
    fn a_growth_target_is_reached_in_the_rounds_left_whatever_the_pruning_on_the_way() {
        let rules = towards(8000.0);
        assert_eq!(rules.rounds_from(1, 330), 33);
        assert_eq!(rules.rounds_from(321, 330), 1);
        assert_eq!(rules.max_share(), 0.15);
        // Each round grows its share of the kept kernels (all visible here); after the
        // first, half of them turn transparent and are pruned, as early in a fit.
        let mut kept = 2000_usize;
        for round in 0..33 {
            let share = rules.round_share(kept, 33 - round);
            assert!((0.05..=0.15).contains(&share), "{share}");
            kept += (share * kept as f64) as usize;
            if round == 0 {
                kept /= 2;
            }
        }
        assert!((kept as f64 / 8000.0 - 1.0).abs() < 0.01, "{kept}");
        // The same rules without the target grow 5 % a round, from the same collapse.
        let mut fixed = 2000_usize;
        for round in 0..33 {
            fixed += (0.05 * fixed as f64) as usize;
            if round == 0 {
                fixed /= 2;
            }
        }
        assert!(fixed < 5500, "{fixed}");
    }

    #[test]
    fn a_growth_target_never_lowers_the_share_nor_passes_its_largest() {
        let rules = towards(8000.0);
        // At or past the target, or with nothing kept or no round left: the fraction.
        for (kept, left) in [(8000, 10), (9000, 10), (0, 10), (100, 0)] {
            assert_eq!(rules.round_share(kept, left), 0.05, "{kept} {left}");
        }
        // Far from it: the largest share; one round from it: what reaches it.
        assert_eq!(rules.round_share(10, 2), 0.15);
        assert_eq!(rules.round_share(7000, 1), 0.1429);
        // Without a target: the fraction, whatever the count.
        assert_eq!(grow_all().round_share(10, 2), grow_all().fraction);
        assert_eq!(grow_all().max_share(), grow_all().fraction);
    }

    #[test]
    fn a_round_grows_the_share_its_target_asks_for() {
        // Ten visible kernels, each with a gradient: a target of 12 one round away grows
        // two of them (20 %, above the 5 % floor and within 100 %).
        let kernels: Vec<Kernel> = (0..10)
            .map(|i| {
                let mut kernel = one_kernel([0.0; 3], 0.01).kernel(0);
                kernel.mean[0] = f64::from(i);
                kernel
            })
            .collect();
        let mut scene = Scene::from_kernels(&kernels, [0.0; 3], "<test>")
            .unwrap()
            .into_alpha(vec![0.8; 10], 0, Vec::new(), "<test>")
            .unwrap();
        let mut stats = DensityStats::new(10);
        stats.add_view((0..10).map(|i| (i, [1.0, 0.0])), 1.0);
        let rules = AlphaRules {
            fraction: 0.05,
            growth_target: Some(GrowthTarget {
                kernels: 12.0,
                max_share: 1.0,
            }),
            ..grow_all()
        };
        let (sources, _) = densify_and_prune(&mut scene, &stats, &rules, 1);
        assert_eq!(sources.len(), 12);
    }
}
