//! Node animation on plain data: a tree of nodes with tracks, and every node's world matrix
//! and its rate of change at any time.
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
//! The glTF reader (`io::gltf`) fills these types; the sample planner
//! ([`crate::scenes::motion_sampling`]) and the surfels ([`crate::scenes::surfels`]) use them.

use glam::{DMat3, DMat4, DQuat, DVec3};

/// What a track moves.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Property {
    /// The node's translation (3 values a key).
    Translation,
    /// The node's rotation, a quaternion (x, y, z, w).
    Rotation,
    /// The node's scale (3 values a key).
    Scale,
}

/// How a track finds values between its keys.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Interpolation {
    /// Holds each key's value until the next key.
    Step,
    /// Linear (slerp for rotations).
    Linear,
    /// Cubic Hermite with the keys' tangents.
    CubicSpline,
}

/// One node of the tree, at rest.
#[derive(Clone, Debug, PartialEq)]
pub struct Node {
    /// The node's local matrix, used as it is when no track moves the node.
    pub matrix: DMat4,
    /// The same transform as translation, rotation (x, y, z, w) and scale: what tracks
    /// replace part by part.
    pub translation: DVec3,
    /// See [`Node::translation`].
    pub rotation: [f64; 4],
    /// See [`Node::translation`].
    pub scale: DVec3,
    /// Its children (indices into [`NodeTree::nodes`]).
    pub children: Vec<usize>,
}

impl Node {
    /// A node at rest at `matrix` = T·R·S (the parts given), with `children`.
    #[must_use]
    pub fn new(translation: DVec3, rotation: [f64; 4], scale: DVec3, children: Vec<usize>) -> Self {
        let [x, y, z, w] = rotation;
        Node {
            matrix: DMat4::from_scale_rotation_translation(
                scale,
                DQuat::from_xyzw(x, y, z, w),
                translation,
            ),
            translation,
            rotation,
            scale,
            children,
        }
    }
}

/// A forest of nodes: every node, and the roots of the scene shown (nodes outside it keep
/// the identity as their world matrix).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct NodeTree {
    /// Every node.
    pub nodes: Vec<Node>,
    /// The roots of the scene shown.
    pub roots: Vec<usize>,
}

/// Which limit to take at a key time.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Side {
    /// The limit from before.
    Left,
    /// The limit from after (the value glTF gives at the key time itself).
    Right,
}

/// One animated property of one node.
#[derive(Clone, Debug, PartialEq)]
pub struct Track {
    /// The node it moves (an index into [`NodeTree::nodes`]).
    pub node: usize,
    /// What it moves.
    pub property: Property,
    /// How values between keys are found.
    pub interpolation: Interpolation,
    /// Key times, ascending.
    pub times: Vec<f64>,
    /// Per key: 3 or 4 values (×3 for CUBICSPLINE: in-tangent, value, out-tangent).
    pub values: Vec<Vec<f64>>,
}

impl Track {
    /// The value at `t` (the right limit at a key time).
    #[cfg(test)]
    pub fn sample(&self, t: f64) -> Vec<f64> {
        self.evaluate(t, Side::Right).0
    }

    /// The value at `t` and its rate of change per time unit, as the limit from `side` at a
    /// key time; held (rate 0) before the first key and after the last.
    pub fn evaluate(&self, t: f64, side: Side) -> (Vec<f64>, Vec<f64>) {
        use Interpolation::{CubicSpline, Linear, Step};
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
        let rotation = self.property == Property::Rotation;
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

/// A node tree and the tracks that move it.
#[derive(Clone, Debug)]
pub struct Animation {
    /// Every track.
    pub tracks: Vec<Track>,
    /// The nodes.
    pub tree: NodeTree,
    /// Per node: its tracks' indices.
    by_node: Vec<Vec<usize>>,
}

/// A node's world matrix and its rate of change.
pub type Pose = (DMat4, DMat4);

impl Animation {
    /// The tracks, by node, of `tree`.
    #[must_use]
    pub fn new(tracks: Vec<Track>, tree: NodeTree) -> Self {
        let mut by_node = vec![Vec::new(); tree.nodes.len()];
        for (i, track) in tracks.iter().enumerate() {
            if let Some(list) = by_node.get_mut(track.node) {
                list.push(i);
            }
        }
        Animation {
            tracks,
            tree,
            by_node,
        }
    }

    /// The time range of all tracks, or `None` without animation.
    #[must_use]
    pub fn range(&self) -> Option<[f64; 2]> {
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
    fn local(&self, index: usize, t: f64, side: Side) -> Pose {
        let node = &self.tree.nodes[index];
        let tracks = &self.by_node[index];
        if tracks.is_empty() {
            return (node.matrix, DMat4::ZERO);
        }
        let mut t_value = node.translation;
        let mut r_value = node.rotation;
        let mut s_value = node.scale;
        let (mut t_rate, mut r_rate, mut s_rate) = (DVec3::ZERO, [0.0; 4], DVec3::ZERO);
        for &i in tracks {
            let track = &self.tracks[i];
            let (v, r) = track.evaluate(t, side);
            match track.property {
                Property::Translation => {
                    (t_value, t_rate) =
                        (DVec3::new(v[0], v[1], v[2]), DVec3::new(r[0], r[1], r[2]));
                }
                Property::Rotation => {
                    (r_value, r_rate) = ([v[0], v[1], v[2], v[3]], [r[0], r[1], r[2], r[3]]);
                }
                Property::Scale => {
                    (s_value, s_rate) =
                        (DVec3::new(v[0], v[1], v[2]), DVec3::new(r[0], r[1], r[2]));
                }
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

    /// World matrices of every node of the scene shown (identity elsewhere) and their rates
    /// at `t`.
    #[must_use]
    pub fn world(&self, t: f64, side: Side) -> Vec<Pose> {
        let mut world = vec![(DMat4::IDENTITY, DMat4::ZERO); self.tree.nodes.len()];
        let mut stack: Vec<(usize, Pose)> = self
            .tree
            .roots
            .iter()
            .map(|&n| (n, (DMat4::IDENTITY, DMat4::ZERO)))
            .collect();
        while let Some((node, (parent, parent_rate))) = stack.pop() {
            let (local, local_rate) = self.local(node, t, side);
            let pose = (parent * local, parent_rate * local + parent * local_rate);
            world[node] = pose;
            stack.extend(self.tree.nodes[node].children.iter().map(|&c| (c, pose)));
        }
        world
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
        let tree = NodeTree {
            nodes: vec![
                Node::new(DVec3::ZERO, [0.0, 0.0, 0.0, 1.0], DVec3::ONE, vec![1]),
                Node::new(DVec3::X, [0.0, 0.0, 0.0, 1.0], DVec3::ONE, Vec::new()),
            ],
            roots: vec![0],
        };
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
        let animation = Animation::new(tracks, tree);
        let h = 1e-6;
        for t in [0.2, 0.5, 0.8] {
            let world = animation.world(t, Side::Right);
            let (up, down) = (
                animation.world(t + h, Side::Right),
                animation.world(t - h, Side::Right),
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
