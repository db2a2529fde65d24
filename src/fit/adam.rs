//! Adam with bias correction (SPEC §6) and one learning rate per parameter group.
//!
//! For each parameter θ with gradient g at step k (1-based):
//!
//! ```text
//! m ← β1 m + (1 - β1) g        v ← β2 v + (1 - β2) g²
//! θ ← θ - lr · (m / (1 - β1^k)) / (√(v / (1 - β2^k)) + ε)
//! ```
//!
//! Groups: spatial mean (x, y, z), time (t), amplitude (r, g, b), velocity (vx, vy, vz),
//! scale (sx, sy, sz, st), and the scene's background colour (r, g, b), one for the scene. A group with learning rate 0 is frozen and its moments are not
//! updated. Scales are optimised as `ln s` (gradient `s ∂L/∂s`, update `s ← s e^(-Δ)`), so
//! they stay positive and a rate is a relative change; they are frozen by default, as the
//! seed paper fixes σ "for stability" (SPEC §6). Rotation is never changed.

use rayon::prelude::*;

use crate::backward::Gradients;
use crate::model::scene::Scene;

/// Learning rate per parameter group; 0 freezes a group.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LearningRates {
    /// Spatial mean `(x, y, z)`, world units per step.
    pub mean: f64,
    /// Time mean `t`.
    pub time: f64,
    /// Amplitude `(r, g, b)`.
    pub amplitude: f64,
    /// Velocity `(vx, vy, vz)`.
    pub velocity: f64,
    /// Scales `(sx, sy, sz, st)`, in `ln s` (a relative change per step).
    pub scale: f64,
    /// The scene's background colour `(r, g, b)` (SPEC §5).
    pub background: f64,
}

impl LearningRates {
    /// Every rate times `factor` (a schedule).
    #[must_use]
    pub fn scaled(&self, factor: f64) -> Self {
        LearningRates {
            mean: self.mean * factor,
            time: self.time * factor,
            amplitude: self.amplitude * factor,
            velocity: self.velocity * factor,
            scale: self.scale * factor,
            background: self.background * factor,
        }
    }
}

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
    fn default() -> Self {
        AdamConfig {
            beta1: 0.9,
            beta2: 0.999,
            epsilon: 1e-8,
        }
    }
}

/// Parameters per kernel, in Adam's layout: x y z t r g b vx vy vz.
const PARAMS: usize = 14;

/// Adam's state for one scene.
#[derive(Clone, Debug)]
pub struct Adam {
    config: AdamConfig,
    steps: i32,
    /// Kernels' moments, [`PARAMS`] per kernel, then the background's three.
    first: Vec<f64>,
    second: Vec<f64>,
}

impl Adam {
    /// Fresh state for `kernels` kernels.
    #[must_use]
    pub fn new(kernels: usize, config: AdamConfig) -> Self {
        Adam {
            config,
            steps: 0,
            first: vec![0.0; PARAMS * kernels + 3],
            second: vec![0.0; PARAMS * kernels + 3],
        }
    }

    /// The state after the scene's kernels changed: kernel `i` of the new scene takes the
    /// moments of old kernel `sources[i]`, or zeros when it is `None` (a new kernel). The
    /// step count, and so the bias correction, carries on.
    pub fn remap(&mut self, sources: &[Option<usize>]) {
        let kernels = PARAMS * sources.len();
        let mut first = vec![0.0; kernels + 3];
        let mut second = vec![0.0; kernels + 3];
        let old = self.first.len() - 3;
        first[kernels..].copy_from_slice(&self.first[old..]);
        second[kernels..].copy_from_slice(&self.second[old..]);
        for (i, source) in sources.iter().enumerate() {
            if let Some(old) = *source {
                first[PARAMS * i..PARAMS * (i + 1)]
                    .copy_from_slice(&self.first[PARAMS * old..PARAMS * (old + 1)]);
                second[PARAMS * i..PARAMS * (i + 1)]
                    .copy_from_slice(&self.second[PARAMS * old..PARAMS * (old + 1)]);
            }
        }
        self.first = first;
        self.second = second;
    }

    /// One update of `scene` with `grads` (sized for the scene).
    pub fn step(&mut self, scene: &mut Scene, grads: &Gradients, rates: &LearningRates) {
        assert_eq!(grads.len(), scene.len(), "gradients sized for the scene");
        assert_eq!(
            self.first.len(),
            PARAMS * scene.len() + 3,
            "Adam state sized for the scene"
        );
        self.steps += 1;
        let config = self.config;
        let corrections = (
            1.0 - config.beta1.powi(self.steps),
            1.0 - config.beta2.powi(self.steps),
        );
        let update = |m: &mut f64, v: &mut f64, grad: f64, rate: f64| {
            advance(config, corrections, (m, v), grad, rate)
        };
        let kernels = scene.len();
        // Kernel by kernel in parallel: each parameter's update reads and writes only its
        // own value and moments, so the result does not depend on the thread count.
        let moments1 = &mut self.first[..PARAMS * kernels];
        let moments2 = &mut self.second[..PARAMS * kernels];
        (
            scene.means.par_iter_mut(),
            scene.amplitudes.par_iter_mut(),
            scene.velocities.par_iter_mut(),
            scene.scales.par_iter_mut(),
            moments1.par_chunks_mut(PARAMS),
            moments2.par_chunks_mut(PARAMS),
        )
            .into_par_iter()
            .enumerate()
            .with_min_len(1024)
            .for_each(
                |(i, ([x, y, z, t], [r, g, b], [vx, vy, vz], scales, first, second))| {
                    let params: [(&mut f64, f64, f64); 10] = [
                        (x, grads.v_means[i][0], rates.mean),
                        (y, grads.v_means[i][1], rates.mean),
                        (z, grads.v_means[i][2], rates.mean),
                        (t, grads.v_means[i][3], rates.time),
                        (r, grads.v_amplitudes[i][0], rates.amplitude),
                        (g, grads.v_amplitudes[i][1], rates.amplitude),
                        (b, grads.v_amplitudes[i][2], rates.amplitude),
                        (vx, grads.v_velocities[i][0], rates.velocity),
                        (vy, grads.v_velocities[i][1], rates.velocity),
                        (vz, grads.v_velocities[i][2], rates.velocity),
                    ];
                    for (k, (value, grad, rate)) in params.into_iter().enumerate() {
                        if rate == 0.0 {
                            continue;
                        }
                        *value -= update(&mut first[k], &mut second[k], grad, rate);
                    }
                    if rates.scale != 0.0 {
                        for (k, s) in scales.iter_mut().enumerate() {
                            // In ln s: the gradient is s ∂L/∂s.
                            let grad = *s * grads.v_scales[i][k];
                            let step =
                                update(&mut first[10 + k], &mut second[10 + k], grad, rates.scale);
                            *s *= (-step).exp();
                        }
                    }
                },
            );
        if rates.background != 0.0 {
            let base = PARAMS * scene.len();
            for c in 0..3 {
                let grad = grads.v_background[c];
                scene.background[c] -= update(
                    &mut self.first[base + c],
                    &mut self.second[base + c],
                    grad,
                    rates.background,
                );
            }
        }
    }
}

/// One parameter's Adam update with bias corrections `(1 - β1^k, 1 - β2^k)`: its moments
/// `(m, v)` are advanced with `grad`, and the step to subtract is returned.
fn advance(
    config: AdamConfig,
    (correction1, correction2): (f64, f64),
    (first, second): (&mut f64, &mut f64),
    grad: f64,
    rate: f64,
) -> f64 {
    let AdamConfig {
        beta1,
        beta2,
        epsilon,
    } = config;
    let m = beta1 * *first + (1.0 - beta1) * grad;
    let v = beta2 * *second + (1.0 - beta2) * grad * grad;
    *first = m;
    *second = v;
    rate * (m / correction1) / ((v / correction2).sqrt() + epsilon)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::scene::Kernel;

    #[test]
    fn first_step_moves_each_live_parameter_by_its_rate_against_the_gradient_sign() {
        let kernel = Kernel::new([0.0; 4], [1.0; 4], [1.0; 3]);
        let mut scene = Scene::from_kernels(&[kernel], [0.0; 3], "<test>").unwrap();
        let mut grads = Gradients::zeros(1);
        grads.v_means[0] = [2.0, -3.0, 0.5, 1.0];
        grads.v_amplitudes[0] = [-1.0, 1e-3, 0.0];
        grads.v_velocities[0] = [1.0, 1.0, 1.0];
        let rates = LearningRates {
            mean: 0.1,
            time: 0.0,
            amplitude: 0.01,
            velocity: 0.0,
            scale: 0.0,
            background: 0.0,
        };
        Adam::new(1, AdamConfig::default()).step(&mut scene, &grads, &rates);
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
        let mut adam = Adam::new(1, AdamConfig::default());
        let rates = LearningRates {
            mean: 0.05,
            time: 0.0,
            amplitude: 0.0,
            velocity: 0.0,
            scale: 0.0,
            background: 0.0,
        };
        for k in 0..2000 {
            let mut grads = Gradients::zeros(1);
            // L = ½ |m - (1, 1, 1)|²
            for c in 0..3 {
                grads.v_means[0][c] = scene.means[0][c] - 1.0;
            }
            adam.step(&mut scene, &grads, &rates.scaled(0.999_f64.powi(k)));
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
        let rates = LearningRates {
            mean: 0.0,
            time: 0.0,
            amplitude: 0.0,
            velocity: 0.0,
            scale: 0.5,
            background: 0.0,
        };
        let mut adam = Adam::new(1, AdamConfig::default());
        adam.step(&mut scene, &grads, &rates);
        let s = scene.scales[0];
        // First step: ln s moves by ∓0.5 whatever the gradient's size (up to Adam's ε/|g|).
        assert!((s[0] - 0.1 * (-0.5_f64).exp()).abs() < 1e-6, "{s:?}");
        assert!((s[1] - 0.2 * 0.5_f64.exp()).abs() < 1e-6, "{s:?}");
        assert_eq!(s[2], 0.3);
        for _ in 0..200 {
            adam.step(&mut scene, &grads, &rates);
        }
        assert!(scene.scales[0].iter().all(|&v| v > 0.0 && v.is_finite()));
        assert_eq!(scene.means[0], [0.0; 4], "other groups frozen");
    }

    #[test]
    fn the_background_is_its_own_group_and_survives_a_remap() {
        let kernel = Kernel::new([0.0; 4], [1.0; 4], [1.0; 3]);
        let mut scene = Scene::from_kernels(&[kernel], [0.5; 3], "<test>").unwrap();
        let mut grads = Gradients::zeros(1);
        grads.v_background = [1.0, -1.0, 0.0];
        let rates = LearningRates {
            mean: 0.0,
            time: 0.0,
            amplitude: 0.0,
            velocity: 0.0,
            scale: 0.0,
            background: 0.01,
        };
        let mut adam = Adam::new(1, AdamConfig::default());
        adam.step(&mut scene, &grads, &rates);
        let b = scene.background;
        assert!((b[0] - 0.49).abs() < 1e-6 && (b[1] - 0.51).abs() < 1e-6 && b[2] == 0.5);
        assert_eq!(scene.amplitudes[0], [1.0; 3], "kernels frozen");
        // Two kernels now (the old one and a new one): the background's moments carry on, so
        // a second step with the same gradient moves it by the same amount again.
        adam.remap(&[Some(0), None]);
        scene = Scene::from_kernels(&[kernel, kernel], scene.background, "<test>").unwrap();
        let mut grads = Gradients::zeros(2);
        grads.v_background = [1.0, -1.0, 0.0];
        adam.step(&mut scene, &grads, &rates);
        assert!(
            (scene.background[0] - 0.48).abs() < 1e-6,
            "{:?}",
            scene.background
        );
    }
}
