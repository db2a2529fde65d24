//! Adam with bias correction (SPEC §6) and one learning rate per parameter group.
//!
//! For each parameter θ with gradient g at step k (1-based):
//!
//! ```text
//! m ← β1 m + (1 - β1) g        v ← β2 v + (1 - β2) g²
//! θ ← θ - lr · (m / (1 - β1^k)) / (√(v / (1 - β2^k)) + ε)
//! ```
//!
//! Groups: spatial mean (x, y, z), time (t), amplitude (r, g, b), velocity (vx, vy, vz). A
//! group with learning rate 0 is frozen and its moments are not updated. Scale and rotation
//! are never changed (the seed paper fixes σ "for stability").

use crate::backward::Gradients;
use crate::scene::Scene;

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
const PARAMS: usize = 10;

/// Adam's state for one scene.
#[derive(Clone, Debug)]
pub struct Adam {
    config: AdamConfig,
    steps: i32,
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
            first: vec![0.0; PARAMS * kernels],
            second: vec![0.0; PARAMS * kernels],
        }
    }

    /// One update of `scene` with `grads` (sized for the scene).
    pub fn step(&mut self, scene: &mut Scene, grads: &Gradients, rates: &LearningRates) {
        assert_eq!(grads.len(), scene.len(), "gradients sized for the scene");
        assert_eq!(
            self.first.len(),
            PARAMS * scene.len(),
            "Adam state sized for the scene"
        );
        self.steps += 1;
        let AdamConfig {
            beta1,
            beta2,
            epsilon,
        } = self.config;
        let correction1 = 1.0 - beta1.powi(self.steps);
        let correction2 = 1.0 - beta2.powi(self.steps);
        for i in 0..scene.len() {
            let [x, y, z, t] = &mut scene.means[i];
            let [r, g, b] = &mut scene.amplitudes[i];
            let [vx, vy, vz] = &mut scene.velocities[i];
            let params: [(&mut f64, f64, f64); PARAMS] = [
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
                let slot = PARAMS * i + k;
                let m = beta1 * self.first[slot] + (1.0 - beta1) * grad;
                let v = beta2 * self.second[slot] + (1.0 - beta2) * grad * grad;
                self.first[slot] = m;
                self.second[slot] = v;
                *value -= rate * (m / correction1) / ((v / correction2).sqrt() + epsilon);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Kernel;

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
}
