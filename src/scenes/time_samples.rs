//! Sample times for motion given as a path over `[t0, t1]`, with Gaussian temporal weights
//! that form a partition of unity (used by the sample planner, [`crate::scenes::motion_sampling`]).
//!
//! A 4D kernel at time `t_k` with temporal σ `σ_k` and amplitude factor `a_k` weighs
//! `a_k exp(-½ ((τ - t_k)/σ_k)²)` at τ (SPEC §2). A point of a moving surface becomes one
//! kernel per sample; its brightness at τ is the sum of those weights, so the weights must
//! sum to one over the range, and its position at τ is their weighted mean of the kernels'
//! positions `p_k + v_k (τ - t_k)`.
//!
//! **Layout.** The range is cut at *boundaries* (its ends and the animation's key times).
//! Between two boundaries samples are spaced evenly at most `Δ` apart. A boundary where the
//! motion is not smooth (a step in position, or a jump in velocity) gets a *ladder* on each
//! side: samples at `r/2`, `r/2 + r`, `r/2 + r + ρ r`, … from it (gaps growing by ρ = 1.25
//! until they reach Δ), so that kernels near the boundary are narrow and hardly reach across
//! it: just past a step (at `b + 2 r`) at most 1 % of the weight is on the old side. No sample
//! sits on such a boundary. Each sample's σ is `c = 0.9` times the mean of its two gaps. At
//! each end of the range, the first four samples are mirrored outside it, where the motion is
//! clamped (glTF holds the first and last poses), so that the weights also sum to one at the
//! ends.
//!
//! **Normalisation.** Evenly spaced Gaussians with σ = 0.9 Δ sum to a constant within 10⁻⁶;
//! where gaps change (ladders, pieces of different Δ) the sum ripples, so the amplitude
//! factors are fitted — non-negative least squares by multiplicative updates on a dense grid
//! of τ over `[t0, t1]` — until `Σ a_k g_k(τ) = 1`; [`normalise`] returns the largest
//! deviation it leaves on that grid (2·10⁻³ to 7·10⁻³ on the cases tested).

/// Gap growth along a ladder.
pub const LADDER_GROWTH: f64 = 1.25;
/// σ of a sample over the mean of its two gaps.
pub const SIGMA_PER_GAP: f64 = 0.9;
/// Samples mirrored outside each end of the range.
pub const MIRRORED: usize = 4;
/// Gaussians are taken as zero beyond this many σ.
const REACH: f64 = 6.0;

/// Where a sample sits with respect to the range.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Place {
    /// Before `t0`: the motion is clamped to its first pose.
    Before,
    /// Within `[t0, t1]`, in piece `piece` (between boundaries `piece` and `piece + 1`).
    Inside {
        /// The piece.
        piece: usize,
    },
    /// After `t1`: the motion is clamped to its last pose.
    After,
}

/// One sample time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TimeSample {
    /// `t_k`.
    pub time: f64,
    /// `σ_k`.
    pub sigma: f64,
    /// `a_k` (1 until [`normalise`]).
    pub weight: f64,
    /// Where it sits.
    pub place: Place,
}

impl TimeSample {
    /// `a_k exp(-½ ((τ - t_k)/σ_k)²)`, zero beyond 6 σ.
    #[must_use]
    pub fn at(&self, tau: f64) -> f64 {
        self.weight * self.gaussian(tau)
    }

    /// `exp(-½ ((τ - t_k)/σ_k)²)` (without the weight), zero beyond 6 σ.
    #[must_use]
    pub fn gaussian(&self, tau: f64) -> f64 {
        let d = (tau - self.time) / self.sigma;
        if d.abs() > REACH {
            0.0
        } else {
            (-0.5 * d * d).exp()
        }
    }
}

/// A boundary of the pieces: its time and, when the motion is not smooth there, the ladder's
/// first gap `r`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Boundary {
    /// The time.
    pub time: f64,
    /// `r` (`None`: smooth; samples keep their piece's spacing up to it).
    pub ladder: Option<f64>,
}

/// Offsets from a boundary of the samples of its ladder (first gap `r`, at most `spacing`),
/// up to `limit`.
fn ladder_offsets(r: Option<f64>, spacing: f64, limit: f64) -> (Vec<f64>, f64) {
    let mut gap = r.map_or(spacing, |r| r.min(spacing));
    let mut offsets = Vec::new();
    let mut d = 0.5 * gap;
    // Each sample keeps half its next gap clear of the middle, where the other side's
    // ladder or the even samples take over.
    while d + 0.5 * gap <= limit {
        offsets.push(d);
        if gap >= spacing {
            break;
        }
        d += gap;
        gap = (gap * LADDER_GROWTH).min(spacing);
    }
    (offsets, gap)
}

/// The sample times of the pieces between `boundaries` (ascending, at least two: the range's
/// ends first and last), piece `i` spaced at most `spacings[i]`, with ladders where the
/// boundaries ask and [`MIRRORED`] samples mirrored outside each end; weights 1.
///
/// # Panics
/// When `spacings` does not have one entry per piece.
#[must_use]
pub fn lay_out(boundaries: &[Boundary], spacings: &[f64]) -> Vec<TimeSample> {
    assert_eq!(
        spacings.len() + 1,
        boundaries.len(),
        "one spacing per piece"
    );
    let mut times: Vec<(f64, Place)> = Vec::new();
    for (piece, pair) in boundaries.windows(2).enumerate() {
        let (a, b) = (pair[0], pair[1]);
        let length = b.time - a.time;
        let spacing = spacings[piece].min(length);
        let place = Place::Inside { piece };
        let (left, left_gap) = ladder_offsets(a.ladder, spacing, 0.5 * length);
        let (right, right_gap) = ladder_offsets(b.ladder, spacing, 0.5 * length);
        let first = times.len();
        times.extend(left.iter().map(|&d| (a.time + d, place)));
        // Evenly between the ladders' last samples, at most the larger of their gaps apart
        // (which is the piece's spacing once a ladder reached it).
        let (from, to) = (
            a.time + left.last().copied().unwrap_or(0.0),
            b.time - right.last().copied().unwrap_or(0.0),
        );
        if left.is_empty() && right.is_empty() {
            times.push((0.5 * (a.time + b.time), place));
        } else if to > from {
            let gap = left_gap.max(right_gap).min(spacing);
            let n = ((to - from) / gap).round().max(1.0) as usize;
            times.extend((1..n).map(|j| (from + (to - from) * j as f64 / n as f64, place)));
        }
        times.extend(right.iter().rev().map(|&d| (b.time - d, place)));
        // Two ladders meeting in a short piece can leave samples out of order or doubled.
        times[first..].sort_by(|x, y| x.0.total_cmp(&y.0));
        let mut kept = first;
        for k in first..times.len() {
            if kept == first || times[k].0 > times[kept - 1].0 {
                times[kept] = times[k];
                kept += 1;
            }
        }
        times.truncate(kept);
    }
    let (t0, t1) = (boundaries[0].time, boundaries[boundaries.len() - 1].time);
    let inside = times.len();
    let mirrored = MIRRORED.min(inside);
    let mut all: Vec<(f64, Place)> = (0..mirrored)
        .rev()
        .map(|k| (2.0 * t0 - times[k].0, Place::Before))
        .collect();
    all.extend_from_slice(&times);
    all.extend((0..mirrored).map(|k| (2.0 * t1 - times[inside - 1 - k].0, Place::After)));
    let n = all.len();
    (0..n)
        .map(|k| {
            let gap_before = (k > 0).then(|| all[k].0 - all[k - 1].0);
            let gap_after = (k + 1 < n).then(|| all[k + 1].0 - all[k].0);
            let gap = match (gap_before, gap_after) {
                (Some(x), Some(y)) => 0.5 * (x + y),
                (Some(x), None) | (None, Some(x)) => x,
                (None, None) => (t1 - t0).max(1.0),
            };
            TimeSample {
                time: all[k].0,
                sigma: SIGMA_PER_GAP * gap,
                weight: 1.0,
                place: all[k].1,
            }
        })
        .collect()
}

/// For each of the ascending `taus`, calls `visit(i, reaching)` with the samples whose
/// Gaussian reaches `taus[i]` (`|τ - t_k| ≤ 6 σ_k`): a sweep over the samples' reaches, so the
/// cost follows how many reach each τ, not how many there are.
pub fn for_each_reaching(
    samples: &[TimeSample],
    taus: &[f64],
    mut visit: impl FnMut(usize, &[usize]),
) {
    let start = |k: usize| samples[k].time - REACH * samples[k].sigma;
    let end = |k: usize| samples[k].time + REACH * samples[k].sigma;
    let mut order: Vec<usize> = (0..samples.len()).collect();
    order.sort_by(|&a, &b| start(a).total_cmp(&start(b)).then(a.cmp(&b)));
    let (mut next, mut active) = (0, Vec::new());
    for (i, &tau) in taus.iter().enumerate() {
        while next < order.len() && start(order[next]) <= tau {
            active.push(order[next]);
            next += 1;
        }
        active.retain(|&k| end(k) >= tau);
        visit(i, &active);
    }
}

/// `Σ_k a_k g_k(τ)`.
#[must_use]
pub fn weight_sum(samples: &[TimeSample], tau: f64) -> f64 {
    samples.iter().map(|s| s.at(tau)).sum()
}

/// τ over `[t0, t1]` dense enough to see every sample's Gaussian: 13 per sample over ±1.5 σ,
/// and the ends.
#[must_use]
pub fn dense_times(samples: &[TimeSample], range: [f64; 2]) -> Vec<f64> {
    let mut taus: Vec<f64> = samples
        .iter()
        .flat_map(|s| (0..13).map(move |j| s.time + s.sigma * (f64::from(j) - 6.0) / 4.0))
        .filter(|&t| t >= range[0] && t <= range[1])
        .chain(range)
        .collect();
    taus.sort_by(f64::total_cmp);
    taus.dedup();
    taus
}

/// Fits the weights `a_k ≥ 0` so that `Σ a_k g_k(τ) = 1` over `range` (see the module docs)
/// and returns the largest `|Σ - 1|` left on the dense grid.
pub fn normalise(samples: &mut [TimeSample], range: [f64; 2]) -> f64 {
    normalise_within(samples, range, 400)
}

/// [`normalise`] with at most `updates` multiplicative updates (a rough fit is enough while
/// the samples are still being placed).
pub fn normalise_within(samples: &mut [TimeSample], range: [f64; 2], updates: usize) -> f64 {
    let taus = dense_times(samples, range);
    // The Gaussians at every τ, sparse: (sample, value) pairs.
    let mut columns: Vec<Vec<(usize, f64)>> = Vec::with_capacity(taus.len());
    for_each_reaching(samples, &taus, |i, reaching| {
        let tau = taus[i];
        columns.push(
            reaching
                .iter()
                .map(|&k| (k, samples[k].gaussian(tau)))
                .collect(),
        );
    });
    let mut mass = vec![0.0; samples.len()];
    for column in &columns {
        for &(k, g) in column {
            mass[k] += g;
        }
    }
    let sums = |samples: &[TimeSample]| -> Vec<f64> {
        columns
            .iter()
            .map(|column| column.iter().map(|&(k, g)| samples[k].weight * g).sum())
            .collect()
    };
    // Start from the sum at each sample's own time, then multiplicative updates towards the
    // least-squares fit of Σ = 1 (they keep the weights positive).
    let start = sums(samples);
    let mut sample_sums = vec![0.0; samples.len()];
    let mut counts = vec![0.0; samples.len()];
    for (column, sum) in columns.iter().zip(&start) {
        for &(k, g) in column {
            sample_sums[k] += g * sum;
            counts[k] += g;
        }
    }
    for ((s, total), count) in samples.iter_mut().zip(&sample_sums).zip(&counts) {
        if *count > 0.0 {
            s.weight = count / total;
        }
    }
    // Until the fit is within 10⁻⁴, or stops improving by 1 % over 20 updates.
    let mut deviation = f64::INFINITY;
    let mut checkpoint = f64::INFINITY;
    let mut weighted = vec![0.0; samples.len()];
    let mut current = vec![0.0; columns.len()];
    for iteration in 0..=updates {
        for (sum, column) in current.iter_mut().zip(&columns) {
            *sum = column.iter().map(|&(k, g)| samples[k].weight * g).sum();
        }
        deviation = current.iter().map(|s| (s - 1.0).abs()).fold(0.0, f64::max);
        if deviation < 1e-4 {
            break;
        }
        if iteration % 20 == 0 {
            if deviation > 0.99 * checkpoint {
                break;
            }
            checkpoint = deviation;
        }
        weighted.iter_mut().for_each(|w| *w = 0.0);
        for (column, sum) in columns.iter().zip(&current) {
            for &(k, g) in column {
                weighted[k] += g * sum;
            }
        }
        for ((s, w), m) in samples.iter_mut().zip(&weighted).zip(&mass) {
            if *w > 0.0 {
                s.weight *= m / w;
            }
        }
    }
    deviation
}

#[cfg(test)]
mod tests {
    use super::*;

    fn boundaries(times: &[f64], ladder: Option<f64>) -> Vec<Boundary> {
        times
            .iter()
            .map(|&time| Boundary { time, ladder })
            .collect()
    }

    #[test]
    fn even_samples_sum_to_one_and_ladders_keep_steps_apart() {
        // Smooth: even spacing, mirrored ends.
        let mut smooth = lay_out(&boundaries(&[0.0, 1.0], None), &[0.05]);
        assert!(normalise(&mut smooth, [0.0, 1.0]) < 1e-3);
        for k in 0..=1000 {
            let tau = f64::from(k) / 1000.0;
            let sum = weight_sum(&smooth, tau);
            assert!((sum - 1.0).abs() < 2e-3, "τ = {tau}: {sum}");
        }
        // A step at 0.5 with r = 2.5e-4, ladders at the ends too.
        let r = 2.5e-4;
        let mut stepped = lay_out(&boundaries(&[0.0, 0.5, 1.0], Some(r)), &[0.02, 0.02]);
        assert!(stepped.iter().all(|s| s.time != 0.5));
        assert!(normalise(&mut stepped, [0.0, 1.0]) < 3e-3);
        for tau in [0.0, 0.3, 0.5 - r, 0.5, 0.5 + r, 0.7, 1.0 - 1e-4, 1.0] {
            let sum = weight_sum(&stepped, tau);
            assert!((sum - 1.0).abs() < 5e-3, "τ = {tau}: {sum}");
        }
        let old_side = |tau: f64| {
            let old: f64 = stepped
                .iter()
                .filter(|s| s.time < 0.5)
                .map(|s| s.at(tau))
                .sum();
            old / weight_sum(&stepped, tau)
        };
        assert!(
            old_side(0.5 + 2.0 * r) < 0.015,
            "{}",
            old_side(0.5 + 2.0 * r)
        );
        assert!(old_side(0.5 - 2.0 * r) > 0.985);
        // Samples are sorted, inside ones in their pieces.
        assert!(stepped.windows(2).all(|w| w[0].time < w[1].time));
        for s in &stepped {
            match s.place {
                Place::Before => assert!(s.time < 0.0),
                Place::After => assert!(s.time > 1.0),
                Place::Inside { piece } => {
                    assert!(s.time > 0.5 * piece as f64 && s.time < 0.5 * (piece + 1) as f64);
                }
            }
        }
    }

    #[test]
    fn short_pieces_and_uneven_spacings_still_sum_to_one() {
        let times = [0.0, 0.001, 0.3, 0.31, 2.0];
        let mut samples = lay_out(&boundaries(&times, Some(1e-3)), &[0.01, 0.1, 0.005, 0.2]);
        let deviation = normalise(&mut samples, [0.0, 2.0]);
        assert!(deviation < 0.01, "{deviation}");
        assert!(samples.iter().all(|s| s.weight > 0.0 && s.sigma > 0.0));
    }
}
