//! glTF node animation: the tracks, the node hierarchy's world matrices and their rates of
//! change at any time, and the sample times an import follows it with.
//!
//! **Evaluation** (glTF 2.0 §3.11): LINEAR translations and scales interpolate linearly,
//! LINEAR rotations by spherical linear interpolation along the shorter arc, STEP holds the
//! key's value until the next key, CUBICSPLINE is the cubic Hermite spline with the keys'
//! tangents scaled by the key interval (rotations normalised after it). Before the first key
//! and after the last every track holds its end value. At a key time either limit can be
//! asked for ([`Side`]): a STEP's value and any track's rate differ on the two sides.
//!
//! **Rates**, analytic: LINEAR `(v1 - v0)/Δt`; slerp's derivative
//! `θ (-cos((1-s)θ) q0 + cos(sθ) q1) / (sin θ Δt)`, so a turning point moves along the tangent
//! of its arc; the Hermite basis' derivatives; a normalised quaternion's `(q' - q (q·q'))/|q|`;
//! `R'` from `(q, q')` entry by entry; a node's local `L = T R S` gives
//! `L' = [R' S + R S' | t']` and a child's world matrix `M = P L` gives `M' = P' L + P L'`.
//! A point `x` of a node moves at `M' x` (tested against finite differences).
//!
//! **Sampling** (`plan_samples`): boundaries at the range's ends and at every key time;
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

use glam::{DMat3, DMat4, DQuat, DVec3};

use crate::model::error::{Error, Result};
use crate::scenes::time_samples::{
    Boundary, Place, TimeSample, for_each_reaching, lay_out, normalise, normalise_within,
};

/// A step is resolved within this fraction of the animation's range: at `b + w` at most
/// 1.5 % of the weight is on the old side (the ladder's first gap is `w/2`).
pub const STEP_WINDOW: f64 = 1e-3;

/// At most this many sample times per surface point.
pub const MAX_SAMPLE_TIMES: usize = 10_000;

/// Which limit to take at a key time.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Side {
    /// The limit from before.
    Left,
    /// The limit from after (the value glTF gives at the key time itself).
    Right,
}

/// One animated property of one node.
pub(crate) struct Track {
    pub(crate) node: usize,
    pub(crate) property: gltf::animation::Property,
    pub(crate) interpolation: gltf::animation::Interpolation,
    pub(crate) times: Vec<f64>,
    /// Per key: 3 or 4 values (×3 for CUBICSPLINE: in-tangent, value, out-tangent).
    pub(crate) values: Vec<Vec<f64>>,
}

impl Track {
    /// The value at `t` (the right limit at a key time).
    #[cfg(test)]
    pub(crate) fn sample(&self, t: f64) -> Vec<f64> {
        self.evaluate(t, Side::Right).0
    }

    /// The value at `t` and its rate of change per time unit, as the limit from `side` at a
    /// key time; held (rate 0) before the first key and after the last.
    pub(crate) fn evaluate(&self, t: f64, side: Side) -> (Vec<f64>, Vec<f64>) {
        use gltf::animation::Interpolation::{CubicSpline, Linear, Step};
        let cubic = self.interpolation == CubicSpline;
        let value = |k: usize| -> &Vec<f64> {
            if cubic {
                &self.values[3 * k + 1]
            } else {
                &self.values[k]
            }
        };
        let n = self.times.len();
        let zero = vec![0.0; value(0).len()];
        let (first, last) = (self.times[0], self.times[n - 1]);
        let (before, after) = match side {
            Side::Right => (t < first, t >= last),
            Side::Left => (t <= first, t > last),
        };
        if n == 1 || before {
            return (value(0).clone(), zero);
        }
        if after {
            return (value(n - 1).clone(), zero);
        }
        // The segment [times[k], times[k + 1]] holding t (on `side` of a key), of length > 0.
        let k = match side {
            Side::Right => self.times.partition_point(|&x| x <= t) - 1,
            Side::Left => self.times.partition_point(|&x| x < t) - 1,
        };
        let dt = self.times[k + 1] - self.times[k];
        let s = (t - self.times[k]) / dt;
        let rotation = self.property == gltf::animation::Property::Rotation;
        let (raw, rate): (Vec<f64>, Vec<f64>) = match self.interpolation {
            Step => (value(k).clone(), zero),
            Linear if rotation => slerp(value(k), value(k + 1), s, dt),
            Linear => {
                let (a, b) = (value(k), value(k + 1));
                (
                    a.iter().zip(b).map(|(a, b)| a + s * (b - a)).collect(),
                    a.iter().zip(b).map(|(a, b)| (b - a) / dt).collect(),
                )
            }
            CubicSpline => {
                let (p0, m0) = (&self.values[3 * k + 1], &self.values[3 * k + 2]);
                let (p1, m1) = (&self.values[3 * (k + 1) + 1], &self.values[3 * (k + 1)]);
                let (s2, s3) = (s * s, s * s * s);
                let h = [
                    2.0 * s3 - 3.0 * s2 + 1.0,
                    s3 - 2.0 * s2 + s,
                    -2.0 * s3 + 3.0 * s2,
                    s3 - s2,
                ];
                let dh = [
                    6.0 * s2 - 6.0 * s,
                    3.0 * s2 - 4.0 * s + 1.0,
                    -6.0 * s2 + 6.0 * s,
                    3.0 * s2 - 2.0 * s,
                ];
                let at = |h: [f64; 4], c: usize| {
                    h[0] * p0[c] + h[1] * dt * m0[c] + h[2] * p1[c] + h[3] * dt * m1[c]
                };
                (
                    (0..p0.len()).map(|c| at(h, c)).collect(),
                    (0..p0.len()).map(|c| at(dh, c) / dt).collect(),
                )
            }
        };
        if rotation {
            // q = raw/|raw|, q' = (raw' - q (q·raw'))/|raw|.
            let norm = raw.iter().map(|v| v * v).sum::<f64>().sqrt();
            let q: Vec<f64> = raw.iter().map(|v| v / norm).collect();
            let along: f64 = q.iter().zip(&rate).map(|(a, b)| a * b).sum();
            let rate = rate
                .iter()
                .zip(&q)
                .map(|(r, q)| (r - q * along) / norm)
                .collect();
            (q, rate)
        } else {
            (raw, rate)
        }
    }
}

/// Slerp from `a` to `b` (x, y, z, w) along the shorter arc at `s`, and its rate over an
/// interval `dt`.
fn slerp(a: &[f64], b: &[f64], s: f64, dt: f64) -> (Vec<f64>, Vec<f64>) {
    let mut dot: f64 = a.iter().zip(b).map(|(a, b)| a * b).sum();
    let b: Vec<f64> = if dot < 0.0 {
        dot = -dot;
        b.iter().map(|v| -v).collect()
    } else {
        b.to_vec()
    };
    let theta = dot.min(1.0).acos();
    if theta < 1e-9 {
        return (
            a.iter().zip(&b).map(|(a, b)| a + s * (b - a)).collect(),
            a.iter().zip(&b).map(|(a, b)| (b - a) / dt).collect(),
        );
    }
    let sin = theta.sin();
    let (wa, wb) = (((1.0 - s) * theta).sin() / sin, (s * theta).sin() / sin);
    let (da, db) = (
        -theta * ((1.0 - s) * theta).cos() / (sin * dt),
        theta * (s * theta).cos() / (sin * dt),
    );
    (
        a.iter().zip(&b).map(|(a, b)| wa * a + wb * b).collect(),
        a.iter().zip(&b).map(|(a, b)| da * a + db * b).collect(),
    )
}

/// `dR/dt` of the rotation of unit quaternion `q` (x, y, z, w) moving at `dq`.
fn rotation_rate(q: [f64; 4], dq: [f64; 4]) -> DMat3 {
    let [x, y, z, w] = q;
    let [dx, dy, dz, dw] = dq;
    // Row-major entries of R(q), differentiated.
    let r = [
        [
            -4.0 * (y * dy + z * dz),
            2.0 * (dx * y + x * dy - dw * z - w * dz),
            2.0 * (dx * z + x * dz + dw * y + w * dy),
        ],
        [
            2.0 * (dx * y + x * dy + dw * z + w * dz),
            -4.0 * (x * dx + z * dz),
            2.0 * (dy * z + y * dz - dw * x - w * dx),
        ],
        [
            2.0 * (dx * z + x * dz - dw * y - w * dy),
            2.0 * (dy * z + y * dz + dw * x + w * dx),
            -4.0 * (x * dx + y * dy),
        ],
    ];
    DMat3::from_cols_array_2d(&[
        [r[0][0], r[1][0], r[2][0]],
        [r[0][1], r[1][1], r[2][1]],
        [r[0][2], r[1][2], r[2][2]],
    ])
}

/// Every channel of every animation of `document`, checked (keys finite, ascending, one value
/// per key or three for CUBICSPLINE; morph target weights refused).
pub(crate) fn read_tracks(
    document: &gltf::Document,
    buffers: &[Vec<u8>],
    origin: &str,
) -> Result<Vec<Track>> {
    let mut tracks = Vec::new();
    for animation in document.animations() {
        for channel in animation.channels() {
            let item = format!(
                "animation {} channel {}",
                animation.index(),
                channel.index()
            );
            let reader = channel.reader(|b| buffers.get(b.index()).map(|d| d.as_slice()));
            let times: Vec<f64> = reader
                .read_inputs()
                .ok_or_else(|| Error::invalid(origin, &item, "sampler.input", "cannot be read"))?
                .map(f64::from)
                .collect();
            let outputs = reader
                .read_outputs()
                .ok_or_else(|| Error::invalid(origin, &item, "sampler.output", "cannot be read"))?;
            use gltf::animation::util::ReadOutputs;
            let values: Vec<Vec<f64>> = match outputs {
                ReadOutputs::Translations(it) => it.map(|v| v.map(f64::from).to_vec()).collect(),
                ReadOutputs::Scales(it) => it.map(|v| v.map(f64::from).to_vec()).collect(),
                ReadOutputs::Rotations(it) => {
                    it.into_f32().map(|v| v.map(f64::from).to_vec()).collect()
                }
                ReadOutputs::MorphTargetWeights(_) => {
                    return Err(Error::invalid(
                        origin,
                        &item,
                        "target.path",
                        "morph target weights are not supported",
                    ));
                }
            };
            let interpolation = channel.sampler().interpolation();
            let per_key = if interpolation == gltf::animation::Interpolation::CubicSpline {
                3
            } else {
                1
            };
            if times.is_empty()
                || values.len() != per_key * times.len()
                || times.iter().any(|t| !t.is_finite())
                || times.windows(2).any(|w| w[1] < w[0])
            {
                return Err(Error::invalid(
                    origin,
                    &item,
                    "sampler",
                    "keyframe times and values do not match (count, order or finiteness)",
                ));
            }
            if let Some(key) = values.iter().position(|v| v.iter().any(|x| !x.is_finite())) {
                return Err(Error::invalid(
                    origin,
                    &item,
                    "sampler.output",
                    format!("keyframe value {key} is not finite (NaN or infinity)"),
                ));
            }
            tracks.push(Track {
                node: channel.target().node().index(),
                property: channel.target().property(),
                interpolation,
                times,
                values,
            });
        }
    }
    Ok(tracks)
}

/// The tracks of a document, by node.
pub(crate) struct Animation {
    pub(crate) tracks: Vec<Track>,
    by_node: Vec<Vec<usize>>,
}

/// A node's world matrix and its rate of change.
pub(crate) type Pose = (DMat4, DMat4);

impl Animation {
    pub(crate) fn new(tracks: Vec<Track>, nodes: usize) -> Self {
        let mut by_node = vec![Vec::new(); nodes];
        for (i, track) in tracks.iter().enumerate() {
            if let Some(list) = by_node.get_mut(track.node) {
                list.push(i);
            }
        }
        Animation { tracks, by_node }
    }

    /// The time range of all tracks, or `None` without animation.
    pub(crate) fn range(&self) -> Option<[f64; 2]> {
        let t0 = self
            .tracks
            .iter()
            .map(|k| k.times[0])
            .fold(f64::INFINITY, f64::min);
        let t1 = self
            .tracks
            .iter()
            .filter_map(|k| k.times.last().copied())
            .fold(f64::NEG_INFINITY, f64::max);
        (t1 > t0).then_some([t0, t1])
    }

    /// Every node's local matrix and its rate at `t` (the limit from `side` at key times).
    fn local(&self, node: &gltf::Node<'_>, t: f64, side: Side) -> Pose {
        let tracks = &self.by_node[node.index()];
        if tracks.is_empty() {
            let m = node.transform().matrix().map(|c| c.map(f64::from));
            return (DMat4::from_cols_array_2d(&m), DMat4::ZERO);
        }
        let (translation, rotation, scale) = node.transform().decomposed();
        let mut t_value = DVec3::from(translation.map(f64::from));
        let mut r_value = rotation.map(f64::from);
        let mut s_value = DVec3::from(scale.map(f64::from));
        let (mut t_rate, mut r_rate, mut s_rate) = (DVec3::ZERO, [0.0; 4], DVec3::ZERO);
        for &i in tracks {
            let track = &self.tracks[i];
            let (v, r) = track.evaluate(t, side);
            match track.property {
                gltf::animation::Property::Translation => {
                    (t_value, t_rate) =
                        (DVec3::new(v[0], v[1], v[2]), DVec3::new(r[0], r[1], r[2]));
                }
                gltf::animation::Property::Rotation => {
                    (r_value, r_rate) = ([v[0], v[1], v[2], v[3]], [r[0], r[1], r[2], r[3]]);
                }
                gltf::animation::Property::Scale => {
                    (s_value, s_rate) =
                        (DVec3::new(v[0], v[1], v[2]), DVec3::new(r[0], r[1], r[2]));
                }
                gltf::animation::Property::MorphTargetWeights => {}
            }
        }
        let norm = r_value.iter().map(|v| v * v).sum::<f64>().sqrt();
        let q = r_value.map(|v| v / norm);
        let [x, y, z, w] = q;
        let rotation = DMat3::from_quat(DQuat::from_xyzw(x, y, z, w));
        let rotation_rate = rotation_rate(q, r_rate);
        let value =
            DMat4::from_scale_rotation_translation(s_value, DQuat::from_xyzw(x, y, z, w), t_value);
        let linear_rate =
            rotation_rate * DMat3::from_diagonal(s_value) + rotation * DMat3::from_diagonal(s_rate);
        let rate = DMat4::from_cols(
            linear_rate.x_axis.extend(0.0),
            linear_rate.y_axis.extend(0.0),
            linear_rate.z_axis.extend(0.0),
            t_rate.extend(0.0),
        );
        (value, rate)
    }

    /// World matrices of every node of the default scene (identity elsewhere) and their rates
    /// at `t`.
    pub(crate) fn world(&self, document: &gltf::Document, t: f64, side: Side) -> Vec<Pose> {
        let mut world = vec![(DMat4::IDENTITY, DMat4::ZERO); document.nodes().count()];
        let mut stack: Vec<(gltf::Node<'_>, Pose)> = document
            .default_scene()
            .or_else(|| document.scenes().next())
            .map(|scene| {
                scene
                    .nodes()
                    .map(|n| (n, (DMat4::IDENTITY, DMat4::ZERO)))
                    .collect()
            })
            .unwrap_or_default();
        while let Some((node, (parent, parent_rate))) = stack.pop() {
            let (local, local_rate) = self.local(&node, t, side);
            let pose = (parent * local, parent_rate * local + parent * local_rate);
            world[node.index()] = pose;
            stack.extend(node.children().map(|c| (c, pose)));
        }
        world
    }
}

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
pub(crate) struct PosedSample {
    pub(crate) sample: TimeSample,
    /// Per node: world matrix corrected by `½ M'' σ²`, and its rate (zero outside the range).
    pub(crate) poses: Vec<Pose>,
}

/// What [`plan_samples`] found.
pub(crate) struct SamplePlan {
    pub(crate) samples: Vec<PosedSample>,
    /// Largest position error of any corner at any test time, over the model's size.
    pub(crate) max_error: f64,
    /// Largest `|Σ weights - 1|` over the range.
    pub(crate) weight_error: f64,
    /// Boundaries with a step in position.
    pub(crate) steps: usize,
}

/// Plans the sample times of `animation` over `range` (see the module docs); `corners[n]` are
/// the triangle corners of node `n` (local space), `size` the model's size.
pub(crate) fn plan_samples(
    document: &gltf::Document,
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
    // Boundaries: the ends and every key time between them; keys closer together than
    // 10⁻⁶ of the range are one boundary (its left limit taken at the first, its right limit
    // at the last), so that no piece is shorter than the samples can resolve.
    let resolution = 1e-6 * length;
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
    // A boundary's time: the range's ends at the ends, else its cluster's last key.
    let times: Vec<f64> = clusters
        .iter()
        .enumerate()
        .map(|(i, c)| if i == 0 { t0 } else { c[1] })
        .collect();
    let mut steps = vec![false; times.len()];
    let mut boundaries: Vec<Boundary> = clusters
        .iter()
        .zip(&times)
        .enumerate()
        .map(|(i, (&[first, last], &b))| {
            let (left, right) = (
                animation.world(document, first, Side::Left),
                animation.world(document, last, Side::Right),
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
    let mut spacings: Vec<f64> = match spacing {
        Spacing::Even(n) => vec![length / (n.max(2) - 1) as f64; times.len() - 1],
        Spacing::Adaptive { .. } => times.windows(2).map(|w| w[1] - w[0]).collect(),
    };
    let before = animation.world(document, t0, Side::Left);
    let after = animation.world(document, t1, Side::Right);
    let pose_of = |sample: &TimeSample| -> Vec<Pose> {
        match sample.place {
            Place::Before => before.iter().map(|p| (p.0, DMat4::ZERO)).collect(),
            Place::After => after.iter().map(|p| (p.0, DMat4::ZERO)).collect(),
            Place::Inside { piece } => {
                let t = sample.time;
                let (a, b) = (times[piece], times[piece + 1]);
                let poses = animation.world(document, t, Side::Right);
                // M'' by a central difference of the analytic rate, within the piece.
                let h = (1e-3 * sample.sigma).min(0.5 * (t - a)).min(0.5 * (b - t));
                let (up, down) = (
                    animation.world(document, t + h, Side::Left),
                    animation.world(document, t - h, Side::Right),
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
    };
    let mut round = 0;
    loop {
        round += 1;
        // Spacings change gradually across boundaries too: a ladder from the finer side's.
        let graded: Vec<Boundary> = boundaries
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
            .collect();
        let mut samples = lay_out(&graded, &spacings);
        if samples.len() > MAX_SAMPLE_TIMES {
            return Err(Error::usage(match spacing {
                Spacing::Adaptive { .. } => format!(
                    "{origin}: following the animation within the tolerance needs more than \
                     {MAX_SAMPLE_TIMES} sample times; raise --tolerance or give --times N"
                ),
                Spacing::Even(n) => format!(
                    "{origin}: the animation's {} key times are each kept as a sample, so even \
                     --times {n} needs more than {MAX_SAMPLE_TIMES} sample times; resample the \
                     animation with fewer keys",
                    boundaries.len()
                ),
            }));
        }
        // Errors are measured as the kernels will be: with fitted weights (roughly fitted
        // while the samples move, fully at the end).
        normalise_within(&mut samples, range, 10);
        let posed: Vec<PosedSample> = samples
            .iter()
            .map(|s| PosedSample {
                sample: *s,
                poses: pose_of(s),
            })
            .collect();
        let errors = test_errors(document, animation, &posed, &times, &steps, corners, length);
        let mut changed = false;
        // Each piece and each ladder narrows at most once a round.
        let mut narrowed = vec![false; times.len()];
        let mut halved = vec![false; spacings.len()];
        if let Spacing::Adaptive { .. } = spacing {
            for &(tau, error) in &errors {
                if error <= tolerance {
                    continue;
                }
                // Near a kink's ladder: narrow the ladder; elsewhere: the piece's spacing.
                let piece = times
                    .partition_point(|&b| b <= tau)
                    .clamp(1, times.len() - 1)
                    - 1;
                let near = [piece, piece + 1].into_iter().find(|&i| {
                    boundaries[i]
                        .ladder
                        .is_some_and(|r| !steps[i] && (tau - times[i]).abs() < 8.0 * r)
                });
                match near {
                    Some(i) => {
                        let r = boundaries[i].ladder.expect("a ladder");
                        if !narrowed[i] && r > 20.0 * resolution {
                            boundaries[i].ladder = Some(0.5 * r);
                            narrowed[i] = true;
                            changed = true;
                        }
                    }
                    None if !halved[piece] && spacings[piece] > length / 65_536.0 => {
                        spacings[piece] *= 0.5;
                        halved[piece] = true;
                        changed = true;
                    }
                    None => {}
                }
            }
        }
        if !changed || round >= 30 {
            let weight_error = normalise(&mut samples, range);
            let posed: Vec<PosedSample> = posed
                .into_iter()
                .zip(&samples)
                .map(|(p, s)| PosedSample { sample: *s, ..p })
                .collect();
            let errors = test_errors(document, animation, &posed, &times, &steps, corners, length);
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

/// Position error of the blend against the animation at the test times: every sample time
/// and midpoint inside the range, and the boundaries — not within two step windows of a
/// step, where the kernels of both sides blend by design.
fn test_errors(
    document: &gltf::Document,
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
        let truth = animation.world(document, tau, Side::Right);
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
    use gltf::animation::{Interpolation, Property};

    fn track(
        property: Property,
        interpolation: Interpolation,
        times: &[f64],
        values: &[&[f64]],
    ) -> Track {
        Track {
            node: 0,
            property,
            interpolation,
            times: times.to_vec(),
            values: values.iter().map(|v| v.to_vec()).collect(),
        }
    }

    #[test]
    fn step_linear_and_clamping() {
        let keys: [&[f64]; 2] = [&[0.0, 0.0, 0.0], &[2.0, 4.0, -2.0]];
        let step = track(
            Property::Translation,
            Interpolation::Step,
            &[1.0, 3.0],
            &keys,
        );
        assert_eq!(step.sample(2.9), vec![0.0, 0.0, 0.0]);
        assert_eq!(step.sample(3.0), vec![2.0, 4.0, -2.0]);
        let linear = track(
            Property::Translation,
            Interpolation::Linear,
            &[1.0, 3.0],
            &keys,
        );
        assert_eq!(linear.sample(2.0), vec![1.0, 2.0, -1.0]);
        assert_eq!(
            linear.sample(0.0),
            vec![0.0, 0.0, 0.0],
            "clamped before the first key"
        );
        assert_eq!(
            linear.sample(9.0),
            vec![2.0, 4.0, -2.0],
            "clamped after the last key"
        );
    }

    #[test]
    fn rotations_slerp_and_stay_unit() {
        // Identity to a half turn about z (x, y, z, w).
        let s = std::f64::consts::FRAC_1_SQRT_2;
        let keys: [&[f64]; 2] = [&[0.0, 0.0, 0.0, 1.0], &[0.0, 0.0, 1.0, 0.0]];
        let r = track(
            Property::Rotation,
            Interpolation::Linear,
            &[0.0, 1.0],
            &keys,
        )
        .sample(0.5);
        assert!(
            (r[2] - s).abs() < 1e-12 && (r[3] - s).abs() < 1e-12,
            "a quarter turn halfway: {r:?}"
        );
    }

    #[test]
    fn cubic_spline_is_hermite_with_tangents_scaled_by_the_interval() {
        // Keys at t = 0 and 2: value 0 → 1, out-tangent 1 at the first, in-tangent 0 at the
        // second. Hermite on s = t/2 with m0 = 2·1, m1 = 2·0.
        let keys: [&[f64]; 6] = [&[9.0], &[0.0], &[1.0], &[0.0], &[1.0], &[9.0]];
        let cubic = track(
            Property::Scale,
            Interpolation::CubicSpline,
            &[0.0, 2.0],
            &keys,
        );
        for t in [0.0, 0.5, 1.0, 1.5, 2.0] {
            let s: f64 = t / 2.0;
            let expected = (s.powi(3) - 2.0 * s * s + s) * 2.0 + (-2.0 * s.powi(3) + 3.0 * s * s);
            assert!((cubic.sample(t)[0] - expected).abs() < 1e-12, "t = {t}");
        }
        assert_eq!(
            cubic.sample(-1.0),
            vec![0.0],
            "the value, not a tangent, before the first key"
        );
        assert_eq!(cubic.sample(5.0), vec![1.0]);
    }

    #[test]
    fn rates_match_finite_differences_for_every_interpolation() {
        let h = 1e-6;
        let s = std::f64::consts::FRAC_1_SQRT_2;
        let cases = [
            track(
                Property::Translation,
                Interpolation::Linear,
                &[0.0, 0.7, 2.0],
                &[&[0.0, 1.0, 2.0], &[3.0, -1.0, 0.5], &[1.0, 1.0, 1.0]],
            ),
            track(
                Property::Rotation,
                Interpolation::Linear,
                &[0.0, 0.25, 1.0],
                &[
                    &[0.0, 0.0, 0.0, 1.0],
                    &[0.3, 0.0, s, s],
                    &[-0.2, 0.9, 0.1, -0.3],
                ],
            ),
            track(
                Property::Rotation,
                Interpolation::CubicSpline,
                &[0.0, 1.5],
                &[
                    &[0.0, 0.0, 0.0, 0.0],
                    &[0.0, 0.0, 0.0, 1.0],
                    &[0.5, 0.2, 0.0, 0.0],
                    &[0.1, -0.3, 0.2, 0.0],
                    &[0.0, s, 0.0, s],
                    &[0.0, 0.0, 0.0, 0.0],
                ],
            ),
            track(
                Property::Scale,
                Interpolation::CubicSpline,
                &[0.0, 2.0],
                &[
                    &[9.0; 3],
                    &[1.0, 2.0, 3.0],
                    &[1.0, -1.0, 0.5],
                    &[0.0, 2.0, 1.0],
                    &[2.0, 1.0, 1.0],
                    &[9.0; 3],
                ],
            ),
        ];
        for (c, track) in cases.iter().enumerate() {
            for t in [0.05, 0.3, 0.69, 0.71, 1.2, 1.45, 1.9] {
                let (_, rate) = track.evaluate(t, Side::Right);
                let (up, down) = (
                    track.evaluate(t + h, Side::Right).0,
                    track.evaluate(t - h, Side::Right).0,
                );
                for (i, r) in rate.iter().enumerate() {
                    let numeric = (up[i] - down[i]) / (2.0 * h);
                    assert!(
                        (r - numeric).abs() < 1e-6 * (1.0 + numeric.abs()),
                        "case {c}, t = {t}, component {i}: analytic {r}, numeric {numeric}"
                    );
                }
            }
        }
        // The two limits at a key differ only where the motion does: a LINEAR key's rate.
        let (left, right) = (
            cases[0].evaluate(0.7, Side::Left),
            cases[0].evaluate(0.7, Side::Right),
        );
        assert_eq!(left.0, right.0);
        assert!((left.1[0] - 3.0 / 0.7).abs() < 1e-12 && (right.1[0] + 2.0 / 1.3).abs() < 1e-12);
        // Held outside the keys.
        assert_eq!(cases[0].evaluate(2.0, Side::Right).1, vec![0.0; 3]);
        assert_eq!(cases[0].evaluate(0.0, Side::Left).1, vec![0.0; 3]);
    }

    #[test]
    fn the_rotation_rate_is_the_derivative_of_the_matrix() {
        let q = |t: f64| {
            let v = [
                0.3 * t.sin(),
                0.5 * t,
                -0.2 + 0.1 * t * t,
                1.0 + 0.2 * t.cos(),
            ];
            let n = v.iter().map(|x| x * x).sum::<f64>().sqrt();
            v.map(|x| x / n)
        };
        let matrix = |q: [f64; 4]| DMat3::from_quat(DQuat::from_xyzw(q[0], q[1], q[2], q[3]));
        let h = 1e-6;
        for t in [-0.4, 0.1, 0.9] {
            let dq: [f64; 4] = std::array::from_fn(|i| (q(t + h)[i] - q(t - h)[i]) / (2.0 * h));
            let numeric = (matrix(q(t + h)) - matrix(q(t - h))) * (1.0 / (2.0 * h));
            let analytic = rotation_rate(q(t), dq);
            let error = (analytic - numeric)
                .to_cols_array()
                .iter()
                .map(|x| x.abs())
                .fold(0.0, f64::max);
            assert!(error < 1e-7, "t = {t}: {error}");
        }
    }

    #[test]
    fn world_rates_follow_the_hierarchy() {
        // A parent translating and turning, a child offset and scaling: M' by the product
        // rule against finite differences of M.
        let json = r#"{"asset":{"version":"2.0"},"scene":0,"scenes":[{"nodes":[0]}],
            "nodes":[{"children":[1]},{"translation":[1,0,0]}]}"#;
        let gltf = gltf::Gltf::from_slice(json.as_bytes()).unwrap();
        let s = std::f64::consts::FRAC_1_SQRT_2;
        let tracks = vec![
            Track {
                node: 0,
                ..track(
                    Property::Translation,
                    Interpolation::Linear,
                    &[0.0, 1.0],
                    &[&[0.0, 0.0, 0.0], &[0.0, 2.0, 1.0]],
                )
            },
            Track {
                node: 0,
                ..track(
                    Property::Rotation,
                    Interpolation::Linear,
                    &[0.0, 1.0],
                    &[&[0.0, 0.0, 0.0, 1.0], &[0.0, 0.0, s, s]],
                )
            },
            Track {
                node: 1,
                ..track(
                    Property::Scale,
                    Interpolation::Linear,
                    &[0.0, 1.0],
                    &[&[1.0, 1.0, 1.0], &[2.0, 0.5, 1.0]],
                )
            },
        ];
        let animation = Animation::new(tracks, 2);
        let h = 1e-6;
        for t in [0.2, 0.5, 0.8] {
            let world = animation.world(&gltf.document, t, Side::Right);
            let (up, down) = (
                animation.world(&gltf.document, t + h, Side::Right),
                animation.world(&gltf.document, t - h, Side::Right),
            );
            for n in 0..2 {
                let numeric = (up[n].0 - down[n].0) * (1.0 / (2.0 * h));
                let error = (world[n].1 - numeric)
                    .to_cols_array()
                    .iter()
                    .map(|x| x.abs())
                    .fold(0.0, f64::max);
                assert!(error < 1e-6, "node {n}, t = {t}: {error}");
            }
        }
    }
}
