//! The sample times a moving model is followed at, and every node's pose at each: where
//! the motion steps or kinks, ladders of narrow samples; elsewhere even spacing, halved
//! piece by piece until the kernels follow the animation within a tolerance.
//!
//! **Sampling** ([`plan_samples`]): boundaries at the range's ends and at every key time;
//! where a node's pose jumps (a STEP key) by more than the tolerance the boundary is a step,
//! with a ladder starting at `r = 5·10⁻⁴ (t1 - t0)` ([`STEP_WINDOW`]); where the rate jumps
//! by `ΔV` (a kink between segments, or an end where the motion stops: outside the range the
//! pose is held), the ladder starts at `r = tol/ΔV`, so that the few kernels that reach
//! across it carry at most that error. Between boundaries the spacing is halved piece by
//! piece, and `r` at boundaries, until the positions the kernels give — the weighted mean of
//! `p_k + v_k (τ - t_k)` — are within `tol` of the animation evaluated directly at every test
//! time (the samples and the midpoints between them), for every triangle corner of every
//! node (the error is affine in the point, so the corners bound it for all surface points).
//! Each kernel's position carries the second-order correction `½ p''(t_k) σ_k²`, which
//! cancels the outward lead of the tangent lines of a turning point (the blend of lines
//! tangent to an arc lies outside it by `½ |p''| σ²`), leaving an error of order `σ⁴`.

use glam::{DMat4, DVec3};

use crate::model::error::{Error, Result};
use crate::scenes::animation::{Animation, Pose, Side};
use crate::scenes::time_samples::{
    Boundary, Place, TimeSample, for_each_reaching, lay_out, normalise, normalise_within,
};

/// A step is resolved within this fraction of the animation's range: at `b + w` at most
/// 1.5 % of the weight is on the old side (the ladder's first gap is `w/2`).
pub const STEP_WINDOW: f64 = 1e-3;

/// At most this many sample times per surface point.
pub const MAX_SAMPLE_TIMES: usize = 10_000;

/// The largest `|m x|` (the affine part: `x` a point) over `points`.
fn largest_offset(m: &DMat4, points: &[DVec3]) -> f64 {
    points
        .iter()
        .map(|&x| m.transform_point3(x).length())
        .fold(0.0, f64::max)
}

/// How `plan_samples` spaces the samples.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Spacing {
    /// Refined until every point follows its path within `tolerance` × the model's size.
    Adaptive {
        /// Relative to the model's size (its bounding box' diagonal at the first time).
        tolerance: f64,
    },
    /// At most `(t1 - t0)/(n - 1)` apart, not refined (ladders still at steps and kinks).
    Even(usize),
}

/// A sample time with the pose of every node there.
pub struct PosedSample {
    pub sample: TimeSample,
    /// Per node: world matrix corrected by `½ M'' σ²`, and its rate (zero outside the range).
    pub poses: Vec<Pose>,
}

/// What [`plan_samples`] found.
pub struct SamplePlan {
    pub samples: Vec<PosedSample>,
    /// Largest position error of any corner at any test time, over the model's size.
    pub max_error: f64,
    /// Largest `|Σ weights - 1|` over the range.
    pub weight_error: f64,
    /// Boundaries with a step in position.
    pub steps: usize,
}

/// Plans the sample times of `animation` over `range` (see the module docs); `corners[n]` are
/// the triangle corners of node `n` (local space), `size` the model's size.
pub fn plan_samples(
    animation: &Animation,
    range: [f64; 2],
    corners: &[Vec<DVec3>],
    size: f64,
    spacing: Spacing,
    origin: &str,
) -> Result<SamplePlan> {
    let [t0, t1] = range;
    let length = t1 - t0;
    let tolerance = match spacing {
        Spacing::Adaptive { tolerance } => tolerance,
        Spacing::Even(_) => 1e-3,
    } * size;
    let resolution = 1e-6 * length;
    let clusters = key_clusters(animation, range, resolution);
    // A boundary's time: the range's ends at the ends, else its cluster's last key.
    let times: Vec<f64> = clusters
        .iter()
        .enumerate()
        .map(|(i, c)| if i == 0 { t0 } else { c[1] })
        .collect();
    let (mut boundaries, steps) = classify_boundaries(
        animation, &clusters, &times, corners, tolerance, length, resolution,
    );
    let mut spacings: Vec<f64> = match spacing {
        Spacing::Even(n) => vec![length / (n.max(2) - 1) as f64; times.len() - 1],
        Spacing::Adaptive { .. } => times.windows(2).map(|w| w[1] - w[0]).collect(),
    };
    let poser = Poser {
        animation,
        before: animation.world(t0, Side::Left),
        after: animation.world(t1, Side::Right),
        boundaries: &times,
    };
    let mut round = 0;
    loop {
        round += 1;
        let mut samples = lay_out(&graded(&boundaries, &spacings), &spacings);
        if samples.len() > MAX_SAMPLE_TIMES {
            return Err(too_many_samples(spacing, boundaries.len(), origin));
        }
        // Errors are measured as the kernels will be: with fitted weights (roughly fitted
        // while the samples move, fully at the end).
        normalise_within(&mut samples, range, 10);
        let posed: Vec<PosedSample> = samples
            .iter()
            .map(|s| PosedSample {
                sample: *s,
                poses: poser.pose(s),
            })
            .collect();
        let errors = test_errors(animation, &posed, &times, &steps, corners, length);
        let changed = match spacing {
            Spacing::Adaptive { .. } => {
                let mut refinement = Refinement {
                    times: &times,
                    steps: &steps,
                    boundaries: &mut boundaries,
                    spacings: &mut spacings,
                    resolution,
                    length,
                };
                refinement.narrow(&errors, tolerance)
            }
            Spacing::Even(_) => false,
        };
        if !changed || round >= 30 {
            let weight_error = normalise(&mut samples, range);
            let posed: Vec<PosedSample> = posed
                .into_iter()
                .zip(&samples)
                .map(|(p, s)| PosedSample { sample: *s, ..p })
                .collect();
            let errors = test_errors(animation, &posed, &times, &steps, corners, length);
            let max_error = errors.iter().map(|e| e.1).fold(0.0, f64::max) / size;
            return Ok(SamplePlan {
                samples: posed,
                max_error,
                weight_error,
                steps: steps.iter().filter(|&&s| s).count(),
            });
        }
    }
}

/// The range's ends and every key time between them, in clusters: keys closer together
/// than `resolution` (10⁻⁶ of the range) are one boundary (its left limit taken at the
/// first, its right limit at the last), so that no piece is shorter than the samples can
/// resolve. Each cluster is `[first, last]`; the first starts at `t0`, the last ends at `t1`.
fn key_clusters(animation: &Animation, [t0, t1]: [f64; 2], resolution: f64) -> Vec<[f64; 2]> {
    let mut keys: Vec<f64> = animation
        .tracks
        .iter()
        .flat_map(|k| k.times.iter().copied())
        .filter(|&t| t > t0 && t < t1)
        .chain([t0, t1])
        .collect();
    keys.sort_by(f64::total_cmp);
    let mut clusters: Vec<[f64; 2]> = Vec::new();
    for t in keys {
        match clusters.last_mut() {
            Some(cluster) if t - cluster[1] <= resolution => cluster[1] = t,
            _ => clusters.push([t, t]),
        }
    }
    let last = clusters.len() - 1;
    clusters[0][0] = t0;
    clusters[last][1] = t1;
    clusters
}

/// Each boundary's first ladder, and whether it is a step: a pose jump over `tolerance`
/// starts a ladder at `½ STEP_WINDOW` of the range, a rate jump `ΔV` one at `8 tol/ΔV`.
fn classify_boundaries(
    animation: &Animation,
    clusters: &[[f64; 2]],
    times: &[f64],
    corners: &[Vec<DVec3>],
    tolerance: f64,
    length: f64,
    resolution: f64,
) -> (Vec<Boundary>, Vec<bool>) {
    let mut steps = vec![false; times.len()];
    let boundaries = clusters
        .iter()
        .zip(times)
        .enumerate()
        .map(|(i, (&[first, last], &b))| {
            let (left, right) = (
                animation.world(first, Side::Left),
                animation.world(last, Side::Right),
            );
            let (mut jump, mut rate_jump) = (0.0_f64, 0.0_f64);
            for ((l, r), points) in left.iter().zip(&right).zip(corners) {
                jump = jump.max(largest_offset(&(r.0 - l.0), points));
                rate_jump = rate_jump.max(largest_offset(&(r.1 - l.1), points));
            }
            let ladder = if jump > tolerance || !(jump.is_finite() && rate_jump.is_finite()) {
                steps[i] = true;
                Some(0.5 * STEP_WINDOW * length)
            } else if rate_jump > 0.0 {
                Some((8.0 * tolerance / rate_jump).max(10.0 * resolution))
            } else {
                None
            };
            Boundary { time: b, ladder }
        })
        .collect();
    (boundaries, steps)
}

/// Spacings change gradually across boundaries too: every boundary gets a ladder starting
/// no wider than the finer of its two pieces' spacings.
fn graded(boundaries: &[Boundary], spacings: &[f64]) -> Vec<Boundary> {
    boundaries
        .iter()
        .enumerate()
        .map(|(i, b)| {
            let finer = [i.checked_sub(1), (i < spacings.len()).then_some(i)]
                .into_iter()
                .flatten()
                .map(|piece| spacings[piece])
                .fold(f64::INFINITY, f64::min);
            Boundary {
                ladder: Some(b.ladder.map_or(finer, |r| r.min(finer))),
                ..*b
            }
        })
        .collect()
}

/// The refusal when the samples would be more than [`MAX_SAMPLE_TIMES`].
fn too_many_samples(spacing: Spacing, boundaries: usize, origin: &str) -> Error {
    Error::setting(
        &["tolerance", "times"],
        match spacing {
            Spacing::Adaptive { .. } => format!(
                "{origin}: following the animation within the tolerance needs more than \
             {MAX_SAMPLE_TIMES} sample times; raise `tolerance` or give `times` N"
            ),
            Spacing::Even(n) => format!(
                "{origin}: the animation's {boundaries} key times are each kept as a sample, so even \
             `times` {n} needs more than {MAX_SAMPLE_TIMES} sample times; resample the \
             animation with fewer keys"
            ),
        },
    )
}

/// Every node's pose at a sample: held outside the range, else corrected by `½ M'' σ²`.
struct Poser<'a> {
    animation: &'a Animation,
    /// The poses before `t0` and after `t1`.
    before: Vec<Pose>,
    after: Vec<Pose>,
    /// The boundaries' times.
    boundaries: &'a [f64],
}

impl Poser<'_> {
    fn pose(&self, sample: &TimeSample) -> Vec<Pose> {
        match sample.place {
            Place::Before => self.before.iter().map(|p| (p.0, DMat4::ZERO)).collect(),
            Place::After => self.after.iter().map(|p| (p.0, DMat4::ZERO)).collect(),
            Place::Inside { piece } => {
                let t = sample.time;
                let (a, b) = (self.boundaries[piece], self.boundaries[piece + 1]);
                let poses = self.animation.world(t, Side::Right);
                // M'' by a central difference of the analytic rate, within the piece.
                let h = (1e-3 * sample.sigma).min(0.5 * (t - a)).min(0.5 * (b - t));
                let (up, down) = (
                    self.animation.world(t + h, Side::Left),
                    self.animation.world(t - h, Side::Right),
                );
                let half_s2 = 0.5 * sample.sigma * sample.sigma;
                poses
                    .iter()
                    .zip(up.iter().zip(&down))
                    .map(|(p, (u, d))| {
                        let curvature = (u.1 - d.1) * (1.0 / (2.0 * h));
                        (p.0 + curvature * half_s2, p.1)
                    })
                    .collect()
            }
        }
    }
}

/// One round of adaptive refinement: where a test time's error is over the tolerance, the
/// ladder it is near narrows, or else its piece's spacing halves.
struct Refinement<'a> {
    times: &'a [f64],
    steps: &'a [bool],
    boundaries: &'a mut [Boundary],
    spacings: &'a mut [f64],
    resolution: f64,
    length: f64,
}

impl Refinement<'_> {
    /// Narrows what the errors over `tolerance` ask for; whether anything changed.
    fn narrow(&mut self, errors: &[(f64, f64)], tolerance: f64) -> bool {
        let times = self.times;
        let mut changed = false;
        // Each piece and each ladder narrows at most once a round.
        let mut narrowed = vec![false; times.len()];
        let mut halved = vec![false; self.spacings.len()];
        for &(tau, error) in errors {
            if error <= tolerance {
                continue;
            }
            // Near a kink's ladder: narrow the ladder; elsewhere: the piece's spacing.
            let piece = times
                .partition_point(|&b| b <= tau)
                .clamp(1, times.len() - 1)
                - 1;
            let near = [piece, piece + 1].into_iter().find(|&i| {
                self.boundaries[i]
                    .ladder
                    .is_some_and(|r| !self.steps[i] && (tau - times[i]).abs() < 8.0 * r)
            });
            match near {
                Some(i) => {
                    let r = self.boundaries[i].ladder.expect("a ladder");
                    if !narrowed[i] && r > 20.0 * self.resolution {
                        self.boundaries[i].ladder = Some(0.5 * r);
                        narrowed[i] = true;
                        changed = true;
                    }
                }
                None if !halved[piece] && self.spacings[piece] > self.length / 65_536.0 => {
                    self.spacings[piece] *= 0.5;
                    halved[piece] = true;
                    changed = true;
                }
                None => {}
            }
        }
        changed
    }
}

/// Position error of the blend against the animation at the test times: every sample time
/// and midpoint inside the range, and the boundaries — not within two step windows of a
/// step, where the kernels of both sides blend by design.
fn test_errors(
    animation: &Animation,
    posed: &[PosedSample],
    boundaries: &[f64],
    steps: &[bool],
    corners: &[Vec<DVec3>],
    length: f64,
) -> Vec<(f64, f64)> {
    let [t0, t1] = [boundaries[0], boundaries[boundaries.len() - 1]];
    let mut taus: Vec<f64> = posed
        .windows(2)
        .flat_map(|w| {
            [
                w[0].sample.time,
                0.5 * (w[0].sample.time + w[1].sample.time),
            ]
        })
        .chain(boundaries.iter().copied())
        .filter(|&t| t >= t0 && t <= t1)
        .filter(|&t| {
            boundaries
                .iter()
                .zip(steps)
                .all(|(&b, &step)| !step || (t - b).abs() > 2.0 * STEP_WINDOW * length)
        })
        .collect();
    taus.sort_by(f64::total_cmp);
    taus.dedup();
    let samples: Vec<TimeSample> = posed.iter().map(|p| p.sample).collect();
    let mut errors = Vec::with_capacity(taus.len());
    for_each_reaching(&samples, &taus, |i, reaching| {
        let tau = taus[i];
        let truth = animation.world(tau, Side::Right);
        let mut blend = vec![DMat4::ZERO; truth.len()];
        let mut total = 0.0;
        for &k in reaching {
            let p = &posed[k];
            let w = p.sample.at(tau);
            if w == 0.0 {
                continue;
            }
            total += w;
            let dt = tau - p.sample.time;
            for (b, (m, rate)) in blend.iter_mut().zip(&p.poses) {
                *b += (*m + *rate * dt) * w;
            }
        }
        let error = if total > 0.0 {
            blend
                .iter()
                .zip(&truth)
                .zip(corners)
                .map(|((b, t), points)| largest_offset(&(*b * (1.0 / total) - t.0), points))
                .fold(0.0, f64::max)
        } else {
            f64::INFINITY
        };
        errors.push((tau, error));
    });
    errors
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenes::animation::{Interpolation, Node, NodeTree, Property, Track};

    /// One node moved by one translation track; its triangle's corners.
    fn moving_node(interpolation: Interpolation, keys: &[(f64, [f64; 3])]) -> Animation {
        let tree = NodeTree {
            nodes: vec![Node::new(
                DVec3::ZERO,
                [0.0, 0.0, 0.0, 1.0],
                DVec3::ONE,
                Vec::new(),
            )],
            roots: vec![0],
        };
        let track = Track {
            node: 0,
            property: Property::Translation,
            interpolation,
            times: keys.iter().map(|k| k.0).collect(),
            values: keys.iter().map(|k| k.1.to_vec()).collect(),
        };
        Animation::new(vec![track], tree)
    }

    fn corners() -> Vec<Vec<DVec3>> {
        vec![vec![DVec3::ZERO, DVec3::X, DVec3::Y]]
    }

    #[test]
    fn a_kinked_path_is_followed_within_the_tolerance() {
        // Out and back: a kink at t = 1 and the motion stopping at both ends.
        let animation = moving_node(
            Interpolation::Linear,
            &[
                (0.0, [0.0; 3]),
                (1.0, [2.0, 0.0, 0.0]),
                (2.0, [2.0, 1.0, 0.0]),
            ],
        );
        let tolerance = 1e-3;
        let plan = plan_samples(
            &animation,
            [0.0, 2.0],
            &corners(),
            2.0_f64.sqrt(),
            Spacing::Adaptive { tolerance },
            "<test>",
        )
        .unwrap();
        assert!(plan.max_error <= tolerance, "error {}", plan.max_error);
        assert!(plan.weight_error < 1e-2, "weights {}", plan.weight_error);
        assert_eq!(plan.steps, 0);
        // Narrow samples near the kink: the closest sample to t = 1 is within a hundredth.
        let nearest = plan
            .samples
            .iter()
            .map(|s| (s.sample.time - 1.0).abs())
            .fold(f64::INFINITY, f64::min);
        assert!(nearest < 1e-2, "nearest sample to the kink: {nearest}");
    }

    #[test]
    fn a_step_key_is_a_step_and_even_spacing_keeps_its_count() {
        let animation = moving_node(
            Interpolation::Step,
            &[
                (0.0, [0.0; 3]),
                (1.0, [5.0, 0.0, 0.0]),
                (2.0, [5.0, 0.0, 0.0]),
            ],
        );
        let plan = plan_samples(
            &animation,
            [0.0, 2.0],
            &corners(),
            1.0,
            Spacing::Even(5),
            "<test>",
        )
        .unwrap();
        assert_eq!(plan.steps, 1);
        // Held poses outside the range: zero rate there.
        for posed in &plan.samples {
            if posed.sample.time < 0.0 || posed.sample.time > 2.0 {
                assert_eq!(posed.poses[0].1, DMat4::ZERO);
            }
        }
        let inside = plan
            .samples
            .iter()
            .filter(|s| (0.0..=2.0).contains(&s.sample.time))
            .count();
        assert!(inside >= 5, "{inside} samples inside the range");
    }
}
