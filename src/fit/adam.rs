//! Adam with bias correction (SPEC §6) over a table of parameter groups, for both blends.
//!
//! For each parameter θ with gradient g at step k (1-based):
//!
//! ```text
//! m ← β1 m + (1 - β1) g        v ← β2 v + (1 - β2) g²
//! θ ← θ - lr · (m / (1 - β1^k)) / (√(v / (1 - β2^k)) + ε)
//! ```
//!
//! A [`ParameterGroup`] is one row of the table: a [`Field`] of the scene (the same columns of
//! every kernel's array, or the scene's background), the [`Transform`] it is optimised
//! through, and its learning rate and schedule. The blends differ only in their tables
//! (`crate::fit::additive`, `crate::fit::alpha`): the additive fit moves means, times,
//! amplitudes, velocities, log scales and the background; the alpha fit also rotations,
//! opacity logits and SH coefficients, degree by degree. A group whose rate is 0 at a step
//! (frozen, or not yet started) is left as it is, its moments too.
//!
//! **Transforms**: θ is updated in the space where the group is best optimised, and the
//! stored value follows:
//!
//! | transform | optimised | gradient | stored value after the step |
//! |---|---|---|---|
//! | [`Transform::Identity`] | θ | g | θ - Δ |
//! | [`Transform::Log`] | ln s | s g | s e^(-Δ) (stays > 0) |
//! | [`Transform::Logit`] | logit o | o (1 - o) g (o clamped to [1e-6, 1 - 1e-6]) | σ(logit o - Δ) |
//! | [`Transform::UnitQuaternion`] | q as stored | g | (q - Δ)/‖q - Δ‖ (kept when that norm is 0 or not finite) |
//!
//! Each parameter's update reads and writes only its own value and moments (a quaternion,
//! its own four), so the rows run in parallel and the result does not depend on the thread
//! count.

use rayon::prelude::*;

use crate::backward::Gradients;
use crate::model::scene::Scene;

/// Adam's constants.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdamConfig {
    /// First-moment decay.
    pub beta1: f64,
    /// Second-moment decay.
    pub beta2: f64,
    /// Added to the denominator.
    pub epsilon: f64,
}

impl Default for AdamConfig {
    /// Kingma and Ba's constants.
    fn default() -> Self {
        AdamConfig {
            beta1: 0.9,
            beta2: 0.999,
            epsilon: 1e-8,
        }
    }
}

/// A field of the scene that a group moves.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Field {
    /// Spatial means `(x, y, z)`.
    Mean,
    /// Time means `t`.
    Time,
    /// Velocities `(vx, vy, vz)`.
    Velocity,
    /// Scales `(sx, sy, sz, st)`.
    Scale,
    /// Rotation quaternions.
    Rotation,
    /// Accelerations `(ax, ay, az)` (SPEC §9): the fit gives every kernel one (zero at
    /// first) while this group is in its table.
    Acceleration,
    /// Angular velocities `(ωw, ωx, ωy, ωz)` (SPEC §9), the quaternion's rate: the fit gives
    /// every kernel one (zero at first) while this group is in its table.
    AngularVelocity,
    /// Opacities (alpha scenes).
    Opacity,
    /// Amplitudes: the additive colour, the alpha colour's base.
    Amplitude,
    /// SH triplets `from..to` of every kernel (clipped to the scene's count).
    Sh {
        /// First triplet.
        from: usize,
        /// One past the last triplet.
        to: usize,
    },
    /// The scene's background colour: one row for the scene.
    Background,
}

impl Field {
    /// The transform a field is optimised through (see the module docs).
    #[must_use]
    pub fn transform(self) -> Transform {
        match self {
            Field::Scale => Transform::Log,
            Field::Opacity => Transform::Logit,
            Field::Rotation => Transform::UnitQuaternion,
            _ => Transform::Identity,
        }
    }

    /// Whether each kernel has a row (else the scene has one).
    fn per_kernel(self) -> bool {
        self != Field::Background
    }

    /// `(values, gradients, stride, columns)`: the field's array and its gradient's,
    /// flattened, `stride` numbers a row, the group's numbers at `columns` of each row.
    fn arrays<'a>(
        self,
        scene: &'a mut Scene,
        grads: &'a Gradients,
    ) -> (&'a mut [f64], &'a [f64], usize, std::ops::Range<usize>) {
        let sh = scene.sh_count;
        match self {
            Field::Mean => (
                scene.means.as_flattened_mut(),
                grads.v_means.as_flattened(),
                4,
                0..3,
            ),
            Field::Time => (
                scene.means.as_flattened_mut(),
                grads.v_means.as_flattened(),
                4,
                3..4,
            ),
            Field::Velocity => (
                scene.velocities.as_flattened_mut(),
                grads.v_velocities.as_flattened(),
                3,
                0..3,
            ),
            Field::Scale => (
                scene.scales.as_flattened_mut(),
                grads.v_scales.as_flattened(),
                4,
                0..4,
            ),
            Field::Rotation => (
                scene.rotations.as_flattened_mut(),
                grads.v_rotations.as_flattened(),
                4,
                0..4,
            ),
            Field::Acceleration => (
                scene.accelerations.as_flattened_mut(),
                grads.v_accelerations.as_flattened(),
                3,
                0..3,
            ),
            Field::AngularVelocity => (
                scene.angular_velocities.as_flattened_mut(),
                grads.v_angular_velocities.as_flattened(),
                4,
                0..4,
            ),
            Field::Opacity => (&mut scene.opacities, &grads.v_opacities, 1, 0..1),
            Field::Amplitude => (
                scene.amplitudes.as_flattened_mut(),
                grads.v_amplitudes.as_flattened(),
                3,
                0..3,
            ),
            Field::Sh { from, to } => (
                scene.sh.as_flattened_mut(),
                grads.v_sh.as_flattened(),
                3 * sh,
                3 * from.min(sh)..3 * to.min(sh),
            ),
            Field::Background => (&mut scene.background, &grads.v_background, 3, 0..3),
        }
    }
}

/// The space a group is optimised in (see the module docs' table).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Transform {
    /// As stored.
    Identity,
    /// `ln s`.
    Log,
    /// `logit o`.
    Logit,
    /// The quaternion as stored, renormalised after the step.
    UnitQuaternion,
}

/// One row of the parameter table: a field, its rate and its schedule.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ParameterGroup {
    /// What it moves.
    pub field: Field,
    /// The name of its rate's setting (`lr_mean`, …), for messages.
    pub rate_setting: &'static str,
    /// Initial learning rate, in `unit`s per step.
    pub rate: f64,
    /// What the rate is relative to (1, or the cameras' box diagonal, the time range, …).
    pub unit: f64,
    /// Whether the rate follows the schedule's decay (else it stays constant).
    pub decays: bool,
    /// The first step (1-based) at which the group moves.
    pub from_step: usize,
}

impl ParameterGroup {
    /// A group of `field` at `rate` per step, decaying, from the first step.
    #[must_use]
    pub fn new(field: Field, rate_setting: &'static str, rate: f64) -> Self {
        ParameterGroup {
            field,
            rate_setting,
            rate,
            unit: 1.0,
            decays: true,
            from_step: 0,
        }
    }

    /// The learning rate at `step`, with the schedule's decay factor `decay`.
    #[must_use]
    pub fn rate_at(&self, step: usize, decay: f64) -> f64 {
        if step < self.from_step {
            return 0.0;
        }
        let factor = if self.decays { decay } else { 1.0 };
        self.rate * (self.unit * factor)
    }
}

/// A group's moments: `width` numbers a row.
#[derive(Clone, Debug)]
struct Moments {
    width: usize,
    first: Vec<f64>,
    second: Vec<f64>,
}

/// Adam's state for one scene and one table.
#[derive(Clone, Debug)]
pub struct Adam {
    config: AdamConfig,
    steps: i32,
    groups: Vec<ParameterGroup>,
    moments: Vec<Moments>,
}

impl Adam {
    /// Fresh state for `groups` of `scene`.
    #[must_use]
    pub fn new(scene: &Scene, groups: &[ParameterGroup], config: AdamConfig) -> Self {
        let moments = groups
            .iter()
            .map(|group| {
                let width = group_width(group.field, scene.sh_count);
                let rows = if group.field.per_kernel() {
                    scene.len()
                } else {
                    1
                };
                Moments {
                    width,
                    first: vec![0.0; width * rows],
                    second: vec![0.0; width * rows],
                }
            })
            .collect();
        Adam {
            config,
            steps: 0,
            groups: groups.to_vec(),
            moments,
        }
    }

    /// The table.
    #[must_use]
    pub fn groups(&self) -> &[ParameterGroup] {
        &self.groups
    }

    /// The state after the scene's kernels changed: kernel `i` of the new scene takes the
    /// moments of old kernel `sources[i]`, or zeros when it is `None` (a new kernel). The
    /// scene's own rows (the background) and the step count, and so the bias correction,
    /// carry on.
    pub fn remap(&mut self, sources: &[Option<usize>]) {
        for (group, moments) in self.groups.iter().zip(&mut self.moments) {
            if !group.field.per_kernel() {
                continue;
            }
            let w = moments.width;
            let mut first = vec![0.0; w * sources.len()];
            let mut second = vec![0.0; w * sources.len()];
            for (i, source) in sources.iter().enumerate() {
                if let Some(old) = *source {
                    first[w * i..w * (i + 1)]
                        .copy_from_slice(&moments.first[w * old..w * (old + 1)]);
                    second[w * i..w * (i + 1)]
                        .copy_from_slice(&moments.second[w * old..w * (old + 1)]);
                }
            }
            moments.first = first;
            moments.second = second;
        }
    }

    /// Clears the moments of every group of `field` (an opacity reset).
    pub fn clear(&mut self, field: Field) {
        for (group, moments) in self.groups.iter().zip(&mut self.moments) {
            if group.field == field {
                moments.first.fill(0.0);
                moments.second.fill(0.0);
            }
        }
    }

    /// One update of `scene` with `grads` (sized for the scene) at `step` (1-based), the
    /// rates decayed by `decay`.
    pub fn step(&mut self, scene: &mut Scene, grads: &Gradients, step: usize, decay: f64) {
        assert_eq!(grads.len(), scene.len(), "gradients sized for the scene");
        self.steps += 1;
        let config = self.config;
        let corrections = (
            1.0 - config.beta1.powi(self.steps),
            1.0 - config.beta2.powi(self.steps),
        );
        for (group, moments) in self.groups.iter().zip(&mut self.moments) {
            let rate = group.rate_at(step, decay);
            if rate == 0.0 || moments.width == 0 {
                continue;
            }
            let transform = group.field.transform();
            // Only a renormalised quaternion's divisors are kept: the turns follow them.
            let turns_follow =
                transform == Transform::UnitQuaternion && !scene.angular_velocities.is_empty();
            let (values, gradients, stride, columns) = group.field.arrays(scene, grads);
            assert_eq!(
                moments.first.len() / moments.width,
                values.len() / stride,
                "Adam state sized for the scene"
            );
            let update = Update {
                config,
                corrections,
                rate,
                transform,
            };
            let width = moments.width;
            let rows = (
                values.par_chunks_mut(stride),
                gradients.par_chunks(stride),
                moments.first.par_chunks_mut(width),
                moments.second.par_chunks_mut(width),
            )
                .into_par_iter()
                .with_min_len(1024)
                .map(|(row, gradient, first, second)| {
                    update.row(
                        &mut row[columns.clone()],
                        &gradient[columns.clone()],
                        first,
                        second,
                    )
                });
            if turns_follow {
                let divisors: Vec<f64> = rows.collect();
                scale_turns_with_rotations(scene, &divisors);
            } else {
                rows.for_each(drop);
            }
        }
    }
}

/// Divides each turning kernel's angular velocity by the norm its quaternion was divided by
/// (`divisors`, one per kernel): the turned quaternion `q + ω (t - μt)` (SPEC §9) is then
/// divided by the same number at every `t`, so the kernel's axes `q(t)/|q(t)|` stay
/// where they were.
fn scale_turns_with_rotations(scene: &mut Scene, divisors: &[f64]) {
    for (omega, &divisor) in scene.angular_velocities.iter_mut().zip(divisors) {
        if divisor != 1.0 {
            for w in omega {
                *w /= divisor;
            }
        }
    }
}

/// Numbers a row of `field` holds (SH: the triplets that exist in a scene of `sh_count`).
fn group_width(field: Field, sh_count: usize) -> usize {
    match field {
        Field::Time | Field::Opacity => 1,
        Field::Mean
        | Field::Velocity
        | Field::Acceleration
        | Field::Amplitude
        | Field::Background => 3,
        Field::Scale | Field::Rotation | Field::AngularVelocity => 4,
        Field::Sh { from, to } => 3 * (to.min(sh_count).saturating_sub(from.min(sh_count))),
    }
}

/// One step's update of a group's rows.
#[derive(Clone, Copy)]
struct Update {
    config: AdamConfig,
    /// `(1 - β1^k, 1 - β2^k)`.
    corrections: (f64, f64),
    rate: f64,
    transform: Transform,
}

impl Update {
    /// Advances one parameter's moments `(m, v)` with `grad` and returns the step to take.
    fn advance(&self, first: &mut f64, second: &mut f64, grad: f64) -> f64 {
        let AdamConfig {
            beta1,
            beta2,
            epsilon,
        } = self.config;
        let (correction1, correction2) = self.corrections;
        let m = beta1 * *first + (1.0 - beta1) * grad;
        let v = beta2 * *second + (1.0 - beta2) * grad * grad;
        *first = m;
        *second = v;
        self.rate * (m / correction1) / ((v / correction2).sqrt() + epsilon)
    }

    /// Updates one row's `values` (the group's columns) from their `gradients`; returns the
    /// number a quaternion was divided by to renormalise it (1 otherwise).
    fn row(
        &self,
        values: &mut [f64],
        gradients: &[f64],
        first: &mut [f64],
        second: &mut [f64],
    ) -> f64 {
        let moments = first.iter_mut().zip(second.iter_mut());
        match self.transform {
            Transform::Identity => {
                for ((value, &g), (m, v)) in values.iter_mut().zip(gradients).zip(moments) {
                    *value -= self.advance(m, v, g);
                }
            }
            Transform::Log => {
                for ((s, &g), (m, v)) in values.iter_mut().zip(gradients).zip(moments) {
                    // In ln s: the gradient is s ∂L/∂s.
                    let delta = self.advance(m, v, *s * g);
                    *s *= (-delta).exp();
                }
            }
            Transform::Logit => {
                for ((opacity, &g), (m, v)) in values.iter_mut().zip(gradients).zip(moments) {
                    let o = opacity.clamp(1e-6, 1.0 - 1e-6);
                    let delta = self.advance(m, v, o * (1.0 - o) * g);
                    let logit = (o / (1.0 - o)).ln() - delta;
                    *opacity = 1.0 / (1.0 + (-logit).exp());
                }
            }
            Transform::UnitQuaternion => {
                let mut q = [0.0; 4];
                for (((q, &value), &g), (m, v)) in
                    q.iter_mut().zip(&*values).zip(gradients).zip(moments)
                {
                    *q = value - self.advance(m, v, g);
                }
                let norm = q.iter().map(|v| v * v).sum::<f64>().sqrt();
                if norm > 0.0 && norm.is_finite() {
                    for (value, q) in values.iter_mut().zip(q) {
                        *value = q / norm;
                    }
                    return norm;
                }
            }
        }
        1.0
    }
}

/// The first parameter of `scene` that left the finite numbers (or a scale no longer
/// positive), named by kernel, field and the setting of its rate in `groups` (the
/// command line shows it as its flag).
#[must_use]
pub fn non_finite_parameter(scene: &Scene, groups: &[ParameterGroup]) -> Option<String> {
    let rate_of = |field: Field| {
        groups
            .iter()
            .find(|g| std::mem::discriminant(&g.field) == std::mem::discriminant(&field))
            .map_or("none: this fit does not move it".to_string(), |g| {
                format!("`{}`", g.rate_setting)
            })
    };
    let bad = |values: &[f64]| values.iter().any(|v| !v.is_finite());
    let sh = scene.sh_count;
    for i in 0..scene.len() {
        let found = if bad(&scene.means[i][..3]) {
            Some(("mean", Field::Mean))
        } else if bad(&scene.means[i][3..]) {
            Some(("time", Field::Time))
        } else if bad(&scene.scales[i]) || scene.scales[i].iter().any(|&s| s <= 0.0) {
            Some(("scale", Field::Scale))
        } else if bad(&scene.amplitudes[i]) {
            Some(("amplitude", Field::Amplitude))
        } else if bad(&scene.velocities[i]) {
            Some(("velocity", Field::Velocity))
        } else if bad(&scene.rotations[i]) {
            Some(("rotation", Field::Rotation))
        } else if scene.accelerations.get(i).is_some_and(|a| bad(a)) {
            Some(("acceleration", Field::Acceleration))
        } else if scene.angular_velocities.get(i).is_some_and(|w| bad(w)) {
            Some(("angular velocity", Field::AngularVelocity))
        } else if scene.opacities.get(i).is_some_and(|o| !o.is_finite()) {
            Some(("opacity", Field::Opacity))
        } else if scene
            .sh
            .get(i * sh..(i + 1) * sh)
            .is_some_and(|t| bad(t.as_flattened()))
        {
            Some(("SH", Field::Sh { from: 0, to: 0 }))
        } else {
            None
        };
        if let Some((name, field)) = found {
            return Some(format!(
                "kernel {i}'s {name} is no longer finite (its rate: {})",
                rate_of(field)
            ));
        }
    }
    bad(&scene.background).then(|| {
        format!(
            "the background is no longer finite (its rate: {})",
            rate_of(Field::Background)
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::scene::Kernel;

    fn group(field: Field, rate: f64) -> ParameterGroup {
        ParameterGroup::new(field, "lr_test", rate)
    }

    /// A turning kernel's stored quaternion need not be unit (SPEC §9); renormalising it
    /// divides its angular velocity by the same norm, so its axes at every time stay put.
    #[test]
    fn renormalising_a_turning_kernels_quaternion_keeps_its_axes_at_every_time() {
        let mut kernel = Kernel::new([0.0, 0.0, 0.0, 0.5], [1.0; 4], [1.0; 3]);
        kernel.rotation = [1.2, 0.8, -0.6, 1.0];
        kernel.angular_velocity = [0.3, -1.1, 0.7, 0.2];
        let mut scene = Scene::from_kernels(&[kernel], [0.0; 3], "<test>").unwrap();
        let axes = |scene: &Scene, t: f64| {
            let q: [f64; 4] = std::array::from_fn(|c| {
                scene.rotations[0][c] + scene.angular_velocity(0)[c] * (t - 0.5)
            });
            let norm = q.iter().map(|v| v * v).sum::<f64>().sqrt();
            q.map(|v| v / norm)
        };
        let before: Vec<[f64; 4]> = [0.0, 0.3, 0.9].iter().map(|&t| axes(&scene, t)).collect();
        let grads = Gradients::for_scene(&scene);
        Adam::new(
            &scene,
            &[group(Field::Rotation, 0.1)],
            AdamConfig::default(),
        )
        .step(&mut scene, &grads, 1, 1.0);
        let norm: f64 = scene.rotations[0].iter().map(|v| v * v).sum::<f64>().sqrt();
        assert!((norm - 1.0).abs() < 1e-15);
        for (t, before) in [0.0, 0.3, 0.9].into_iter().zip(before) {
            let after = axes(&scene, t);
            for c in 0..4 {
                assert!(
                    (after[c] - before[c]).abs() < 1e-14,
                    "t {t}: {after:?} {before:?}"
                );
            }
        }
    }

    #[test]
    fn first_step_moves_each_live_parameter_by_its_rate_against_the_gradient_sign() {
        let kernel = Kernel::new([0.0; 4], [1.0; 4], [1.0; 3]);
        let mut scene = Scene::from_kernels(&[kernel], [0.0; 3], "<test>").unwrap();
        let mut grads = Gradients::zeros(1);
        grads.v_means[0] = [2.0, -3.0, 0.5, 1.0];
        grads.v_amplitudes[0] = [-1.0, 1e-3, 0.0];
        grads.v_velocities[0] = [1.0, 1.0, 1.0];
        let groups = [
            group(Field::Mean, 0.1),
            group(Field::Time, 0.0),
            group(Field::Amplitude, 0.01),
            group(Field::Velocity, 0.0),
        ];
        Adam::new(&scene, &groups, AdamConfig::default()).step(&mut scene, &grads, 1, 1.0);
        // With bias correction the first step is lr · g/(|g| + ε/…): ±lr.
        let m = scene.means[0];
        assert!(
            (m[0] + 0.1).abs() < 1e-6 && (m[1] - 0.1).abs() < 1e-6 && (m[2] + 0.1).abs() < 1e-6
        );
        assert_eq!(m[3], 0.0, "time frozen");
        let a = scene.amplitudes[0];
        assert!((a[0] - 1.01).abs() < 1e-6 && (a[1] - 0.99).abs() < 1e-5 && a[2] == 1.0);
        assert_eq!(scene.velocities[0], [0.0; 3], "velocity frozen");
    }

    #[test]
    fn minimises_a_quadratic() {
        let kernel = Kernel::new([3.0, -2.0, 1.0, 0.0], [1.0; 4], [0.0; 3]);
        let mut scene = Scene::from_kernels(&[kernel], [0.0; 3], "<test>").unwrap();
        let groups = [group(Field::Mean, 0.05)];
        let mut adam = Adam::new(&scene, &groups, AdamConfig::default());
        for k in 0..2000 {
            let mut grads = Gradients::zeros(1);
            // L = ½ |m - (1, 1, 1)|²
            for c in 0..3 {
                grads.v_means[0][c] = scene.means[0][c] - 1.0;
            }
            adam.step(&mut scene, &grads, k + 1, 0.998_f64.powi(k as i32));
        }
        for c in 0..3 {
            assert!(
                (scene.means[0][c] - 1.0).abs() < 1e-3,
                "{:?}",
                scene.means[0]
            );
        }
    }

    #[test]
    fn scales_move_in_log_space_and_stay_positive() {
        let kernel = Kernel::new([0.0; 4], [0.1, 0.2, 0.3, 1.0], [1.0; 3]);
        let mut scene = Scene::from_kernels(&[kernel], [0.0; 3], "<test>").unwrap();
        let mut grads = Gradients::zeros(1);
        grads.v_scales[0] = [5.0, -1.0, 0.0, 1e6];
        let groups = [group(Field::Mean, 0.0), group(Field::Scale, 0.5)];
        let mut adam = Adam::new(&scene, &groups, AdamConfig::default());
        adam.step(&mut scene, &grads, 1, 1.0);
        let s = scene.scales[0];
        // First step: ln s moves by ∓0.5 whatever the gradient's size (up to Adam's ε/|g|).
        assert!((s[0] - 0.1 * (-0.5_f64).exp()).abs() < 1e-6, "{s:?}");
        assert!((s[1] - 0.2 * 0.5_f64.exp()).abs() < 1e-6, "{s:?}");
        assert_eq!(s[2], 0.3);
        for k in 0..200 {
            adam.step(&mut scene, &grads, k + 2, 1.0);
        }
        assert!(scene.scales[0].iter().all(|&v| v > 0.0 && v.is_finite()));
        assert_eq!(scene.means[0], [0.0; 4], "other groups frozen");
    }

    /// One alpha kernel with opacity `o`, rotation `q` and two SH triplets.
    fn alpha_scene(o: f64, q: [f64; 4]) -> Scene {
        let mut kernel = Kernel::new([0.0; 4], [1.0; 4], [1.0; 3]);
        kernel.rotation = q;
        Scene::from_kernels(&[kernel], [0.0; 3], "<test>")
            .unwrap()
            .into_alpha(vec![o], 3, vec![[0.5; 3]; 3], "<test>")
            .unwrap()
    }

    #[test]
    fn opacities_move_in_logit_space_and_rotations_stay_unit() {
        let mut scene = alpha_scene(0.5, [1.0, 0.0, 0.0, 0.0]);
        let mut grads = Gradients::for_scene(&scene);
        grads.v_opacities[0] = -4.0;
        grads.v_rotations[0] = [0.0, -1.0, 0.0, 0.0];
        let groups = [group(Field::Opacity, 0.5), group(Field::Rotation, 0.1)];
        let mut adam = Adam::new(&scene, &groups, AdamConfig::default());
        adam.step(&mut scene, &grads, 1, 1.0);
        // logit 0.5 = 0 moves by +0.5: σ(0.5).
        let expected = 1.0 / (1.0 + (-0.5_f64).exp());
        assert!((scene.opacities[0] - expected).abs() < 1e-6);
        // q = (1, 0.1, 0, 0) normalised.
        let q = scene.rotations[0];
        let norm = (1.0_f64 + 0.01).sqrt();
        assert!((q[0] - 1.0 / norm).abs() < 1e-6 && (q[1] - 0.1 / norm).abs() < 1e-6);
        for k in 0..500 {
            adam.step(&mut scene, &grads, k + 2, 1.0);
        }
        let o = scene.opacities[0];
        assert!(o > 0.0 && o < 1.0, "{o}");
        let norm = scene.rotations[0].iter().map(|v| v * v).sum::<f64>();
        assert!((norm - 1.0).abs() < 1e-12, "{norm}");
    }

    #[test]
    fn an_sh_degree_moves_only_from_its_step_and_resets_clear_only_their_field() {
        let mut scene = alpha_scene(0.5, [1.0, 0.0, 0.0, 0.0]);
        let mut grads = Gradients::for_scene(&scene);
        grads.v_sh.iter_mut().for_each(|t| *t = [1.0; 3]);
        grads.v_opacities[0] = 1.0;
        let groups = [
            ParameterGroup {
                from_step: 3,
                ..group(Field::Sh { from: 0, to: 3 }, 0.1)
            },
            group(Field::Opacity, 0.1),
        ];
        let mut adam = Adam::new(&scene, &groups, AdamConfig::default());
        for step in 1..=2 {
            adam.step(&mut scene, &grads, step, 1.0);
        }
        assert!(scene.sh.iter().all(|t| *t == [0.5; 3]), "not yet");
        adam.step(&mut scene, &grads, 3, 1.0);
        assert!(scene.sh.iter().all(|t| t.iter().all(|&v| v < 0.5)));
        adam.clear(Field::Opacity);
        assert!(adam.moments[1].first.iter().all(|&m| m == 0.0));
        assert!(adam.moments[0].first.iter().all(|&m| m != 0.0));
    }

    #[test]
    fn the_background_is_its_own_group_and_survives_a_remap() {
        let kernel = Kernel::new([0.0; 4], [1.0; 4], [1.0; 3]);
        let mut scene = Scene::from_kernels(&[kernel], [0.5; 3], "<test>").unwrap();
        let mut grads = Gradients::zeros(1);
        grads.v_background = [1.0, -1.0, 0.0];
        let groups = [group(Field::Amplitude, 0.0), group(Field::Background, 0.01)];
        let mut adam = Adam::new(&scene, &groups, AdamConfig::default());
        adam.step(&mut scene, &grads, 1, 1.0);
        let b = scene.background;
        assert!((b[0] - 0.49).abs() < 1e-6 && (b[1] - 0.51).abs() < 1e-6 && b[2] == 0.5);
        assert_eq!(scene.amplitudes[0], [1.0; 3], "kernels frozen");
        // Two kernels now (the old one and a new one): the background's moments carry on, so
        // a second step with the same gradient moves it by the same amount again.
        adam.remap(&[Some(0), None]);
        scene = Scene::from_kernels(&[kernel, kernel], scene.background, "<test>").unwrap();
        let mut grads = Gradients::zeros(2);
        grads.v_background = [1.0, -1.0, 0.0];
        adam.step(&mut scene, &grads, 2, 1.0);
        assert!(
            (scene.background[0] - 0.48).abs() < 1e-6,
            "{:?}",
            scene.background
        );
    }

    #[test]
    fn a_non_finite_parameter_is_named_with_its_rate() {
        let kernel = Kernel::new([0.0; 4], [0.1; 4], [0.5; 3]);
        let mut scene = Scene::from_kernels(&[kernel, kernel], [0.0; 3], "<test>").unwrap();
        let groups = [
            ParameterGroup::new(Field::Amplitude, "lr_amplitude", 0.1),
            ParameterGroup::new(Field::Scale, "lr_scale", 0.1),
            ParameterGroup::new(Field::Background, "lr_background", 0.1),
        ];
        assert_eq!(non_finite_parameter(&scene, &groups), None);
        scene.amplitudes[1][2] = f64::NAN;
        let why = non_finite_parameter(&scene, &groups).unwrap();
        assert!(
            why.contains("kernel 1") && why.contains("`lr_amplitude`"),
            "{why}"
        );
        scene.amplitudes[1][2] = 0.5;
        scene.scales[0][3] = 0.0;
        assert!(
            non_finite_parameter(&scene, &groups)
                .unwrap()
                .contains("`lr_scale`")
        );
        scene.scales[0][3] = 0.1;
        scene.background[0] = f64::INFINITY;
        assert!(
            non_finite_parameter(&scene, &groups)
                .unwrap()
                .contains("`lr_background`")
        );
    }
}
