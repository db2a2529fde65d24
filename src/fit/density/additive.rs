//! Densify and prune during fitting: the kernel count follows the data.
//!
//! Between rounds every kernel accumulates its positional gradient measured in its own
//! size, `g̃ = (s̄ ∂L/∂x, s̄ ∂L/∂y, s̄ ∂L/∂z, st ∂L/∂t)` with `s̄` the geometric mean of
//! its spatial scales: how much the loss would change if the kernel moved by one standard
//! deviation. Every `every` steps, from `from` until `until` of the steps have run (the
//! start leaves the initial kernels time to move where they belong before any is judged):
//!
//! 1. **prune** kernels whose peak amplitude `max_c |A_c|` is below `prune_below`: they are
//!    negligible at every time (`a(τ) = A w(τ)` with `w ≤ 1`). One kernel always stays.
//! 2. **merge** kernels that have become the same kernel: same rotation, and position (at
//!    the midpoint of their times), time, velocity over one σt and log-scales all within
//!    `merge_tolerance` standard deviations of each other. The additive sum of two equal
//!    Gaussians is one Gaussian with the summed amplitude, so this is what lets clones that
//!    converged onto one moving object collapse back into one kernel. The merged kernel
//!    takes the summed amplitude and the |amplitude|-weighted mean of the other parameters.
//!    Pairs are compared directly (O(n²)), so merging only runs on up to
//!    [`MERGE_LIMIT`] kernels.
//! 3. **densify**, only when the fit has stalled: the training loss (over every training
//!    view, measured at each round, so batch noise does not count) fell by less than
//!    `min_improvement` (relative) since the round before, and did not rise (a loss that
//!    rose is still settling after the last round).
//!    While the loss is still falling the kernels are still moving to where they belong (one
//!    velocity kernel converging on a moving blob has a large gradient for hundreds of
//!    steps), and adding kernels then only splits one object between several. Densified are
//!    the kernels whose mean `|g̃|` over the steps they were seen is at least
//!    `gradient_threshold`, largest first (ties by index), at most `max_growth · n` of them
//!    and never beyond `max_kernels`. Each becomes two that share its amplitude (half each,
//!    so the additive image barely changes), the new one half a standard deviation down the
//!    accumulated gradient, so the two separate under the same loss. A kernel whose mean
//!    spatial scale `s̄` is above `min_scale` is **split**: both halves take spatial scales
//!    divided by 1.6 (finer detail where the data asks for it, for fits that keep scales
//!    fixed, SPEC §6). At or below `min_scale` it is **cloned** at its own scale. A kernel
//!    whose temporal scale `st` is above `min_time_scale` (velocity fits: two training-time
//!    spacings) is instead **split in time**: two kernels `d = st/√2` before and after its
//!    time on its own path, each with `st/√2` and `A/√2` — the same temporal mean, variance
//!    (`σ² + d² = st²`) and integral — so that a curved motion is followed by straight
//!    pieces, each with its own velocity.
//! 4. **rejoin** (with the merges): two kernels that are pieces of one straight path (same
//!    velocity and position at their midpoint time, overlapping in time; see
//!    `halves_of_one_path`) become one again, keeping their temporal variance and integral —
//!    the inverse of a time split that the data did not need. The schedule's last round
//!    only prunes, merges and rejoins, so no useless split survives into the refining steps.
//!
//! No randomness: the result depends only on the data and the step schedule. Adam's
//! moments follow the kernels (a clone starts from zero moments).

use crate::fit::density::DensityStats;
use crate::model::error::Result;
use crate::model::scene::{Kernel, Scene};

/// The additive rule set: when and how to densify, prune and merge.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdditiveRules {
    /// Steps between rounds.
    pub every: usize,
    /// Fraction of the steps before the first round.
    pub from: f64,
    /// Fraction of the steps after which the count is frozen (the rest refines).
    pub until: f64,
    /// Mean `|g̃|` (loss per standard deviation) at which a kernel is densified.
    pub gradient_threshold: f64,
    /// Relative fall of the training loss between rounds below which the fit counts as
    /// stalled.
    pub min_improvement: f64,
    /// Peak `|amplitude|` below which a kernel is removed.
    pub prune_below: f64,
    /// Largest fraction of the kernels densified in one round.
    pub max_growth: f64,
    /// Budget: never more kernels than this.
    pub max_kernels: usize,
    /// Kernels this close (in standard deviations, see the module docs) are merged; 0
    /// disables merging.
    pub merge_tolerance: f64,
    /// Kernels with a mean spatial scale above this are split (scales / 1.6), the others
    /// cloned; 0 splits every kernel, `∞` only clones.
    pub min_scale: f64,
    /// Kernels with a temporal scale `st` above this are split in time instead (two halves
    /// along their own path, see the module docs); `∞` never splits in time.
    pub min_time_scale: f64,
}

impl AdditiveRules {
    /// Whether a round runs after `step` (1-based) of `steps`.
    #[must_use]
    pub fn round_after(&self, step: usize, steps: usize) -> bool {
        self.every > 0
            && step.is_multiple_of(self.every)
            && step < steps
            && (step as f64) >= self.from * steps as f64
            && (step as f64) <= self.until * steps as f64
    }

    /// Whether the round after `step` is the schedule's last: it only prunes and merges
    /// ([`AdditiveRules::without_growth`]), so that kernels split before it and left on one
    /// path by the fit are rejoined rather than kept for the refining steps.
    #[must_use]
    pub fn last_round_after(&self, step: usize, steps: usize) -> bool {
        self.round_after(step, steps) && !self.round_after(step + self.every, steps)
    }

    /// These options with no room to add kernels (prune and merge only).
    #[must_use]
    pub fn without_growth(&self) -> Self {
        AdditiveRules {
            max_kernels: 0,
            ..*self
        }
    }
}

/// What a round did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RoundReport {
    /// Kernels removed.
    pub pruned: usize,
    /// Kernels merged into another.
    pub merged: usize,
    /// Kernels added (one per kernel densified).
    pub added: usize,
    /// Of those, kernels split (the others were cloned at their scale).
    pub split: usize,
}

/// Spatial scales of a split kernel's halves, as a divisor (3D Gaussian splatting's value).
pub const SPLIT_FACTOR: f64 = 1.6;

/// Runs one round on `scene`: prunes, merges, then densifies. Returns the new scene, for
/// each of its kernels the index of the old kernel whose optimiser state it keeps (`None`
/// for a new one), and what was done.
pub fn densify_and_prune(
    scene: &Scene,
    stats: &DensityStats,
    options: &AdditiveRules,
) -> Result<(Scene, Vec<Option<usize>>, RoundReport)> {
    let keep = prune(scene, options.prune_below);
    let pruned = scene.len() - keep.len();
    let (keep, kernels, merged) = merge_and_rejoin(scene, keep, options.merge_tolerance);
    let (kernels, sources, added, split) = densify(kernels, &keep, stats, options);
    let next = Scene::from_kernels(&kernels, scene.background, "<densified scene>")?;
    Ok((
        next,
        sources,
        RoundReport {
            pruned,
            merged,
            added,
            split,
        },
    ))
}

/// Phase 1, prune: the kernels whose peak amplitude reaches `prune_below` (the brightest
/// alone when none does, rather than an empty model), ascending.
fn prune(scene: &Scene, prune_below: f64) -> Vec<usize> {
    let n = scene.len();
    let peak = |i: usize| {
        scene.amplitudes[i]
            .iter()
            .fold(0.0_f64, |m, a| m.max(a.abs()))
    };
    let mut keep: Vec<usize> = (0..n).filter(|&i| peak(i) >= prune_below).collect();
    if keep.is_empty() && n > 0 {
        let brightest = (0..n).max_by(|&a, &b| peak(a).total_cmp(&peak(b)).then(b.cmp(&a)));
        keep.extend(brightest);
    }
    keep
}

/// Phase 2, merge and rejoin: kept kernels that are the same Gaussian within `tolerance`
/// fold into the first of them; two halves of one path rejoin (one rejoin per kernel and
/// round). Returns the survivors' old indices, their kernels, and how many were folded.
fn merge_and_rejoin(
    scene: &Scene,
    keep: Vec<usize>,
    tolerance: f64,
) -> (Vec<usize>, Vec<Kernel>, usize) {
    // `merged_into[b] = (a, rejoined)`: kept kernel `b` folds into kept kernel `a`, as the
    // same Gaussian or (rejoined) as the other half of its path.
    let mut merged_into: Vec<Option<(usize, bool)>> = vec![None; keep.len()];
    let mut merged = 0;
    if tolerance > 0.0 && keep.len() <= MERGE_LIMIT {
        for a in 0..keep.len() {
            if merged_into[a].is_some() {
                continue;
            }
            let mut rejoined = false;
            for b in a + 1..keep.len() {
                if merged_into[b].is_some() {
                    continue;
                }
                if same_kernel(scene, keep[a], keep[b], tolerance) {
                    merged_into[b] = Some((a, false));
                    merged += 1;
                } else if !rejoined && halves_of_one_path(scene, keep[a], keep[b], tolerance) {
                    merged_into[b] = Some((a, true));
                    rejoined = true;
                    merged += 1;
                }
            }
        }
    }
    let mut kernels: Vec<Kernel> = keep.iter().map(|&i| scene.kernel(i)).collect();
    for b in 0..keep.len() {
        if let Some((a, rejoined)) = merged_into[b] {
            let other = kernels[b];
            if rejoined {
                kernels[a] = rejoin(&kernels[a], &other);
            } else {
                merge_into(&mut kernels[a], &other);
            }
        }
    }
    let survivors: Vec<usize> = (0..keep.len())
        .filter(|&k| merged_into[k].is_none())
        .collect();
    (
        survivors.iter().map(|&k| keep[k]).collect(),
        survivors.iter().map(|&k| kernels[k]).collect(),
        merged,
    )
}

/// Phase 3, densify: the kept kernels (`kernels`, old indices `keep`) with the largest mean
/// positional gradient, once the loss has stalled, each split in time (`st` above
/// `min_time_scale`) or halved in amplitude and cloned half a standard deviation down the
/// gradient (shrunk first when larger than `min_scale`), within `max_growth` and
/// `max_kernels`. Returns the kernels, their sources, the candidates and the splits.
fn densify(
    mut kernels: Vec<Kernel>,
    keep: &[usize],
    stats: &DensityStats,
    options: &AdditiveRules,
) -> (Vec<Kernel>, Vec<Option<usize>>, usize, usize) {
    let mut candidates: Vec<usize> = keep
        .iter()
        .copied()
        .filter(|&i| {
            stats.stalled(options.min_improvement)
                && stats.mean_position_gradient(i) >= options.gradient_threshold
        })
        .collect();
    candidates.sort_by(|&a, &b| {
        stats
            .mean_position_gradient(b)
            .total_cmp(&stats.mean_position_gradient(a))
            .then(a.cmp(&b))
    });
    let growth = ((options.max_growth * keep.len() as f64).ceil() as usize).max(1);
    let room = options.max_kernels.saturating_sub(keep.len());
    candidates.truncate(growth.min(room));
    candidates.sort_unstable();
    let mut sources: Vec<Option<usize>> = keep.iter().map(|&i| Some(i)).collect();
    let mut split = 0;
    for &i in &candidates {
        let slot = keep.binary_search(&i).expect("candidates are kept kernels");
        let parent = &mut kernels[slot];
        if parent.scale[3] > options.min_time_scale {
            let later = split_in_time(parent);
            kernels.push(later);
            sources.push(None);
            split += 1;
            continue;
        }
        for a in &mut parent.amplitude {
            *a *= 0.5;
        }
        if mean_spatial_scale(parent.scale) > options.min_scale {
            for s in &mut parent.scale[..3] {
                *s /= SPLIT_FACTOR;
            }
            split += 1;
        }
        let clone = clone_down_gradient(parent, stats.position_sum(i));
        kernels.push(clone);
        sources.push(None);
    }
    (kernels, sources, candidates.len(), split)
}

/// A copy of `parent` half a standard deviation per axis (x, y, z, t) down `direction` (the summed
/// positional gradient; along x when it has no direction).
fn clone_down_gradient(parent: &Kernel, direction: [f64; 4]) -> Kernel {
    let mut clone = *parent;
    let length = direction.iter().map(|v| v * v).sum::<f64>().sqrt();
    if length > 0.0 && length.is_finite() {
        for (c, m) in clone.mean.iter_mut().enumerate() {
            *m -= 0.5 * clone.scale[c] * direction[c] / length;
        }
    } else {
        clone.mean[0] += 0.5 * clone.scale[0];
    }
    clone
}

/// Splits `parent` in time: it and the returned kernel sit `d = st/√2` before and after its
/// time on its own path (`mean.xyz` moved by `velocity · Δt`, and by SPEC §9's acceleration
/// and turn: [`Kernel::advance_on_path`]), each with `st/√2`, so that each
/// can follow its half of a curved motion with a velocity of its own. The pair keeps the
/// parent's temporal mean and variance (`σ² + d² = st²`) and its integral over time (each
/// half takes `A/√2`); [`rejoin`] is its inverse.
fn split_in_time(parent: &mut Kernel) -> Kernel {
    let half = parent.scale[3] * std::f64::consts::FRAC_1_SQRT_2;
    parent.scale[3] = half;
    for a in &mut parent.amplitude {
        *a *= std::f64::consts::FRAC_1_SQRT_2;
    }
    let mut later = *parent;
    parent.advance_on_path(-half);
    later.advance_on_path(half);
    later
}

/// Whether kernels `i` and `j` are two pieces of one straight path (what [`split_in_time`]
/// makes, when the fit left both halves on the line their parent followed): same rotation,
/// spatial scales within `tolerance` (relative), amplitudes of the same sign, the same
/// velocity over one `st` and the same position at their midpoint time within `tolerance`
/// spatial standard deviations, and times at most `(st_i + st_j)(1 + tolerance)` apart
/// (their temporal Gaussians overlap). Their `st` and amplitudes may differ: [`rejoin`] keeps
/// the pair's integral over time.
fn halves_of_one_path(scene: &Scene, i: usize, j: usize, tolerance: f64) -> bool {
    let (si, sj) = (scene.scales[i], scene.scales[j]);
    let (ai, aj) = (scene.amplitudes[i], scene.amplitudes[j]);
    let (ti, tj) = (scene.means[i][3], scene.means[j][3]);
    !moves_beyond_velocity(scene, i)
        && !moves_beyond_velocity(scene, j)
        && same_rotation(scene, i, j)
        && (0..3).all(|k| (si[k] / sj[k]).ln().abs() <= tolerance)
        && (0..3).all(|c| ai[c] * aj[c] >= 0.0)
        && (ti - tj).abs() <= (si[3] + sj[3]) * (1.0 + tolerance)
        && on_one_line(scene, i, j, tolerance)
}

/// Whether kernel `i` accelerates or turns (SPEC §9): such kernels are never merged nor
/// rejoined (the rules compare straight paths).
fn moves_beyond_velocity(scene: &Scene, i: usize) -> bool {
    scene.acceleration(i) != [0.0; 3] || scene.angular_velocity(i) != [0.0; 4]
}

/// Whether kernels `i` and `j` have the same rotation (up to the quaternion's sign).
fn same_rotation(scene: &Scene, i: usize, j: usize) -> bool {
    let (qi, qj) = (scene.rotations[i], scene.rotations[j]);
    let dot: f64 = (0..4).map(|k| qi[k] * qj[k]).sum();
    dot.abs() >= 1.0 - 1e-6
}

/// Whether kernels `i` and `j` move on one line: at the midpoint of their times their
/// positions agree, and their velocities over one `st` differ, by at most `tolerance`
/// spatial standard deviations (geometric means over the pair).
fn on_one_line(scene: &Scene, i: usize, j: usize, tolerance: f64) -> bool {
    let (si, sj) = (scene.scales[i], scene.scales[j]);
    let spatial = (mean_spatial_scale(si) * mean_spatial_scale(sj)).sqrt();
    let temporal = (si[3] * sj[3]).sqrt();
    let (mi, mj) = (scene.means[i], scene.means[j]);
    let (vi, vj) = (scene.velocities[i], scene.velocities[j]);
    let tau = 0.5 * (mi[3] + mj[3]);
    (0..3).all(|c| {
        let pi = mi[c] + vi[c] * (tau - mi[3]);
        let pj = mj[c] + vj[c] * (tau - mj[3]);
        (pi - pj).abs() <= tolerance * spatial
            && (vi[c] - vj[c]).abs() * temporal <= tolerance * spatial
    })
}

/// `s̄ = (sx sy sz)^(1/3)`, the geometric mean of a kernel's spatial scales.
pub(crate) fn mean_spatial_scale([sx, sy, sz, _]: [f64; 4]) -> f64 {
    (sx * sy * sz).cbrt()
}

/// One kernel from two pieces of a path: the midpoint time, `st² = σ̄² + (Δt/2)²` (the
/// pair's temporal variance when `σ̄ = √(st_a st_b)`), each channel's integral over time
/// `A_a st_a + A_b st_b` kept; position on the mean path at the new time; spatial scales and
/// velocities averaged. The exact inverse of [`split_in_time`].
fn rejoin(a: &Kernel, b: &Kernel) -> Kernel {
    let tau = 0.5 * (a.mean[3] + b.mean[3]);
    let half_gap = 0.5 * (a.mean[3] - b.mean[3]).abs();
    let sigma = (a.scale[3] * b.scale[3]).sqrt();
    let st = (sigma * sigma + half_gap * half_gap).sqrt();
    let mut joined = *a;
    joined.mean[3] = tau;
    for c in 0..3 {
        let pa = a.mean[c] + a.velocity[c] * (tau - a.mean[3]);
        let pb = b.mean[c] + b.velocity[c] * (tau - b.mean[3]);
        joined.mean[c] = 0.5 * (pa + pb);
        joined.velocity[c] = 0.5 * (a.velocity[c] + b.velocity[c]);
        joined.scale[c] = (a.scale[c] * b.scale[c]).sqrt();
        joined.amplitude[c] = (a.amplitude[c] * a.scale[3] + b.amplitude[c] * b.scale[3]) / st;
    }
    joined.scale[3] = st;
    joined
}

/// Merging compares every pair, so it runs on at most this many kernels.
pub const MERGE_LIMIT: usize = 4096;

/// Whether kernels `i` and `j` of `scene` describe the same Gaussian within `tolerance`
/// standard deviations (see the module docs).
fn same_kernel(scene: &Scene, i: usize, j: usize, tolerance: f64) -> bool {
    let (si, sj) = (scene.scales[i], scene.scales[j]);
    let (ti, tj) = (scene.means[i][3], scene.means[j][3]);
    !moves_beyond_velocity(scene, i)
        && !moves_beyond_velocity(scene, j)
        && same_rotation(scene, i, j)
        && (0..4).all(|k| (si[k] / sj[k]).ln().abs() <= tolerance)
        && (ti - tj).abs() <= tolerance * (si[3] * sj[3]).sqrt()
        && on_one_line(scene, i, j, tolerance)
}

/// Folds `other` into `kernel`: amplitudes add, the rest is the |amplitude|-weighted mean.
fn merge_into(kernel: &mut Kernel, other: &Kernel) {
    let weight = |k: &Kernel| k.amplitude.iter().map(|a| a.abs()).sum::<f64>();
    let (wa, wb) = (weight(kernel), weight(other));
    let f = if wa + wb > 0.0 { wb / (wa + wb) } else { 0.5 };
    let blend = |a: f64, b: f64| a + f * (b - a);
    for c in 0..4 {
        kernel.mean[c] = blend(kernel.mean[c], other.mean[c]);
        kernel.scale[c] = blend(kernel.scale[c], other.scale[c]);
    }
    for c in 0..3 {
        kernel.velocity[c] = blend(kernel.velocity[c], other.velocity[c]);
        kernel.amplitude[c] += other.amplitude[c];
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::backward::Gradients;
    use crate::fit::density::Line;

    fn scene(amplitudes: &[f64]) -> Scene {
        let kernels: Vec<Kernel> = amplitudes
            .iter()
            .enumerate()
            .map(|(i, &a)| Kernel::new([i as f64, 0.0, 0.0, 0.5], [0.1, 0.1, 0.1, 0.2], [a; 3]))
            .collect();
        Scene::from_kernels(&kernels, [0.0; 3], "<test>").unwrap()
    }

    /// The temporal weights `A e^{-(τ-t)²/2st²}` of `kernels` summed at `tau`, and their
    /// integral's first and second moments over time, numerically on a fine grid.
    fn temporal_moments(kernels: &[Kernel]) -> (f64, f64, f64) {
        let (mut mass, mut first, mut second) = (0.0, 0.0, 0.0);
        let dt = 1e-4;
        for k in -200_000..200_000 {
            let tau = f64::from(k) * dt;
            let w: f64 = kernels
                .iter()
                .map(|q| {
                    let z = (tau - q.mean[3]) / q.scale[3];
                    q.amplitude[0] * (-0.5 * z * z).exp()
                })
                .sum();
            mass += w * dt;
            first += w * tau * dt;
            second += w * tau * tau * dt;
        }
        let mean = first / mass;
        (mass, mean, second / mass - mean * mean)
    }

    #[test]
    fn a_time_split_keeps_the_path_and_the_temporal_moments_and_rejoin_undoes_it() {
        let parent = Kernel {
            velocity: [0.8, -0.3, 0.1],
            ..Kernel::new(
                [0.2, 0.4, -0.1, 0.6],
                [0.1, 0.12, 0.08, 0.3],
                [0.7, 0.5, -0.2],
            )
        };
        let mut first = parent;
        let second = split_in_time(&mut first);
        assert!(first.mean[3] < parent.mean[3] && second.mean[3] > parent.mean[3]);
        // Both halves sit on the parent's path: m(τ) = mean + v (τ - t).
        for half in [&first, &second] {
            for c in 0..3 {
                let on_path = parent.mean[c] + parent.velocity[c] * (half.mean[3] - parent.mean[3]);
                assert!((half.mean[c] - on_path).abs() < 1e-15);
            }
        }
        // Same integral, temporal mean and variance as the parent.
        let (m0, t0, v0) = temporal_moments(&[parent]);
        let (m1, t1, v1) = temporal_moments(&[first, second]);
        assert!((m1 / m0 - 1.0).abs() < 1e-9, "{m0} {m1}");
        assert!(
            (t1 - t0).abs() < 1e-9 && (v1 / v0 - 1.0).abs() < 1e-9,
            "{t0} {t1} {v0} {v1}"
        );
        // The pieces of one path are recognised and rejoin to the parent exactly.
        let scene = Scene::from_kernels(&[first, second], [0.0; 3], "<test>").unwrap();
        assert!(halves_of_one_path(&scene, 0, 1, 0.1));
        let joined = rejoin(&first, &second);
        for (a, b) in [
            (&joined.mean[..], &parent.mean[..]),
            (&joined.scale[..], &parent.scale[..]),
            (&joined.amplitude[..], &parent.amplitude[..]),
            (&joined.velocity[..], &parent.velocity[..]),
        ] {
            for (x, y) in a.iter().zip(b) {
                assert!((x - y).abs() < 1e-12, "{joined:?} vs {parent:?}");
            }
        }
        // Pieces that turned (velocities differ by a spatial σ over one st) stay apart, as do
        // pieces far apart in time and pieces of opposite sign.
        let mut turned = second;
        turned.velocity[2] += 0.1 / first.scale[3];
        let far = Kernel {
            mean: [
                second.mean[0] + second.velocity[0],
                second.mean[1] + second.velocity[1],
                second.mean[2] + second.velocity[2],
                second.mean[3] + 1.0,
            ],
            ..second
        };
        let negative = Kernel {
            amplitude: second.amplitude.map(|a| -a),
            ..second
        };
        for other in [turned, far, negative] {
            let scene = Scene::from_kernels(&[first, other], [0.0; 3], "<test>").unwrap();
            assert!(!halves_of_one_path(&scene, 0, 1, 0.1), "{other:?}");
        }
    }

    #[test]
    fn prunes_faint_kernels_and_clones_the_steepest_within_the_budget() {
        let scene = scene(&[0.5, 0.001, 0.4, 0.3]);
        let mut stats = DensityStats::new(4);
        stats.record_loss(1.0);
        let mut stats = stats.next_window(vec![Line::default(); 4]);
        stats.record_loss(1.0);
        let mut grads = Gradients::zeros(4);
        grads.v_means[0] = [1e-3, 0.0, 0.0, 0.0]; // |g̃| = 1e-4
        grads.v_means[1] = [1.0, 0.0, 0.0, 0.0]; // faint: pruned first
        grads.v_means[2] = [0.0, -3e-3, 0.0, 0.0]; // |g̃| = 3e-4
        grads.v_means[3] = [1e-5, 0.0, 0.0, 0.0]; // below the threshold
        stats.add_step(&scene, &grads);
        let options = AdditiveRules {
            gradient_threshold: 5e-5,
            max_kernels: 4,
            ..AdditiveRules::default()
        };
        let (next, sources, report) = densify_and_prune(&scene, &stats, &options).unwrap();
        assert_eq!(
            report,
            RoundReport {
                pruned: 1,
                merged: 0,
                added: 1,
                split: 0
            }
        );
        // Budget 4: three kept, one clone, the steepest (kernel 2).
        assert_eq!(sources, [Some(0), Some(2), Some(3), None]);
        assert_eq!(next.amplitudes[1], [0.2; 3]);
        assert_eq!(next.amplitudes[3], [0.2; 3]);
        // The clone moved half a σ down the gradient (+y).
        let moved = next.means[3];
        assert!(
            (moved[1] - 0.05).abs() < 1e-12 && moved[0] == 2.0,
            "{moved:?}"
        );
        // A larger budget clones both steep kernels.
        let (next, _, report) = densify_and_prune(
            &scene,
            &stats,
            &AdditiveRules {
                max_kernels: 10,
                ..options
            },
        )
        .unwrap();
        assert_eq!((report.added, next.len()), (2, 5));
        // Above min_scale the densified kernels are split: both halves shrink.
        let (next, _, report) = densify_and_prune(
            &scene,
            &stats,
            &AdditiveRules {
                max_kernels: 10,
                min_scale: 0.05,
                ..options
            },
        )
        .unwrap();
        assert_eq!(report.split, 2);
        assert_eq!(next.scales[0][..3], [0.1 / SPLIT_FACTOR; 3]);
        assert_eq!(next.scales[4][..3], [0.1 / SPLIT_FACTOR; 3]);
        assert_eq!(next.scales[2], [0.1, 0.1, 0.1, 0.2]);
    }

    #[test]
    fn densifies_only_once_the_loss_has_stalled() {
        let scene = scene(&[0.5]);
        let mut grads = Gradients::zeros(1);
        grads.v_means[0] = [1e-2, 0.0, 0.0, 0.0];
        let options = AdditiveRules::default();
        let run = |losses: [f64; 2]| {
            let mut stats = DensityStats::new(1);
            stats.record_loss(losses[0]);
            let mut stats = stats.next_window(vec![Line::default(); 1]);
            stats.add_step(&scene, &grads);
            stats.record_loss(losses[1]);
            densify_and_prune(&scene, &stats, &options).unwrap().2.added
        };
        // Falling by 20%: still converging, no new kernel; by 1%: stalled, densify.
        assert_eq!(run([1.0, 0.8]), 0);
        assert_eq!(run([1.0, 0.99]), 1);
        // Rising: settling after a round, not stalled.
        assert_eq!(run([1.0, 1.5]), 0);
        // No window before: not judged.
        let mut stats = DensityStats::new(1);
        stats.add_step(&scene, &grads);
        stats.record_loss(1.0);
        assert_eq!(
            densify_and_prune(&scene, &stats, &options).unwrap().2.added,
            0
        );
    }

    #[test]
    fn kernels_that_became_the_same_merge_and_others_do_not() {
        let base = Kernel::new([0.0, 0.0, 0.0, 0.5], [0.1, 0.1, 0.1, 0.4], [0.3; 3]);
        let mut twin = base;
        twin.mean[0] += 0.005; // 0.05 σ
        twin.amplitude = [0.1; 3];
        let mut moving = base;
        moving.velocity = [0.5, 0.0, 0.0]; // 2 σ over one σt
        let mut apart = base;
        apart.mean[1] += 0.05; // 0.5 σ
        let scene = Scene::from_kernels(&[base, twin, moving, apart], [0.0; 3], "<test>").unwrap();
        let (next, sources, report) =
            densify_and_prune(&scene, &DensityStats::new(4), &AdditiveRules::default()).unwrap();
        assert_eq!(report.merged, 1);
        assert_eq!(sources, [Some(0), Some(2), Some(3)]);
        assert_eq!(next.amplitudes[0], [0.4; 3]);
        // Weighted 3:1 towards the brighter kernel.
        assert!(
            (next.means[0][0] - 0.00125).abs() < 1e-12,
            "{:?}",
            next.means[0]
        );
    }

    #[test]
    fn never_prunes_the_last_kernel_and_schedules_rounds() {
        let scene = scene(&[1e-4, 2e-4]);
        let stats = DensityStats::new(2);
        let (next, sources, _) =
            densify_and_prune(&scene, &stats, &AdditiveRules::default()).unwrap();
        assert_eq!((next.len(), sources), (1, vec![Some(1)]));
        let options = AdditiveRules {
            every: 10,
            from: 0.2,
            until: 0.5,
            ..AdditiveRules::default()
        };
        let rounds: Vec<usize> = (1..=100).filter(|&s| options.round_after(s, 100)).collect();
        assert_eq!(rounds, [20, 30, 40, 50]);
    }
}
