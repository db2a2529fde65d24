//! Regularisers of the alpha fit (SPEC §8), added to each step's gradient: 3DGS-MCMC's L1
//! on the opacities and L1 on the spatial scales, as means over the kernels.
//!
//! ```text
//! R = λo · mean_i o_i  +  λs · mean_{i, a ∈ x,y,z} s_ia / D
//! ∂R/∂o_i = λo / N,   ∂R/∂s_ia = λs / (3 N D)
//! ```
//!
//! `N` the kernel count and `D` the cameras' box diagonal (so that `λs` is free of the
//! scene's units); opacities and scales are positive, so their L1 is their sum. The image
//! loss is a per-pixel mean, so `λ` weighs a kernel's mean opacity against a mean pixel
//! error. The step's reported loss stays the MSE (SPEC §6).

use crate::backward::Gradients;
use crate::model::scene::Scene;

/// The regularisers' weights (0: off).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Regularisers {
    /// `λo`, the weight of the mean opacity.
    pub opacity: f64,
    /// `λs`, the weight of the mean spatial scale over the box diagonal.
    pub scale: f64,
    /// `D`, the unit of the scales.
    pub diagonal: f64,
}

impl Regularisers {
    /// No regulariser.
    pub const OFF: Regularisers = Regularisers {
        opacity: 0.0,
        scale: 0.0,
        diagonal: 1.0,
    };

    /// Whether every weight is 0.
    #[must_use]
    pub fn is_off(&self) -> bool {
        self.opacity == 0.0 && self.scale == 0.0
    }

    /// `R` of `scene` (see the module docs).
    #[must_use]
    pub fn penalty(&self, scene: &Scene) -> f64 {
        let n = scene.len().max(1) as f64;
        let opacity: f64 = scene.opacities.iter().sum();
        let scale: f64 = scene.scales.iter().map(|s| s[0] + s[1] + s[2]).sum();
        self.opacity * opacity / n + self.scale * scale / (3.0 * n * self.diagonal)
    }

    /// Adds `∂R/∂θ` of `scene` to `grads`.
    pub fn add_gradient(&self, scene: &Scene, grads: &mut Gradients) {
        if self.is_off() {
            return;
        }
        let n = scene.len().max(1) as f64;
        let v_opacity = self.opacity / n;
        let v_scale = self.scale / (3.0 * n * self.diagonal);
        for v in grads.v_opacities.iter_mut().take(scene.opacities.len()) {
            *v += v_opacity;
        }
        for v in grads.v_scales.iter_mut().take(scene.len()) {
            for axis in v.iter_mut().take(3) {
                *axis += v_scale;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::scene::Kernel;

    /// Two alpha kernels, opacities 0.3 and 0.8.
    fn two_kernels() -> Scene {
        let kernels = [
            Kernel::new([0.0; 4], [0.1, 0.2, 0.3, 0.5], [0.5; 3]),
            Kernel::new([1.0; 4], [0.4, 0.05, 0.05, 0.2], [0.2; 3]),
        ];
        Scene::from_kernels(&kernels, [0.0; 3], "<test>")
            .unwrap()
            .into_alpha(vec![0.3, 0.8], 0, Vec::new(), "<test>")
            .unwrap()
    }

    #[test]
    fn the_penalty_and_its_gradient_match_the_hand_computation_and_differences() {
        let rules = Regularisers {
            opacity: 0.01,
            scale: 0.02,
            diagonal: 2.0,
        };
        let scene = two_kernels();
        let expected = 0.01 * (0.3 + 0.8) / 2.0 + 0.02 * (0.6 + 0.5) / (3.0 * 2.0 * 2.0);
        assert!((rules.penalty(&scene) - expected).abs() < 1e-15);
        let mut grads = Gradients::for_scene(&scene);
        rules.add_gradient(&scene, &mut grads);
        let h = 1e-6;
        for i in 0..2 {
            let mut moved = scene.clone();
            moved.opacities[i] += h;
            let mut back = scene.clone();
            back.opacities[i] -= h;
            let difference = (rules.penalty(&moved) - rules.penalty(&back)) / (2.0 * h);
            assert!((grads.v_opacities[i] - difference).abs() < 1e-9);
            for a in 0..4 {
                let mut moved = scene.clone();
                moved.scales[i][a] += h;
                let mut back = scene.clone();
                back.scales[i][a] -= h;
                let difference = (rules.penalty(&moved) - rules.penalty(&back)) / (2.0 * h);
                assert!((grads.v_scales[i][a] - difference).abs() < 1e-9, "{i} {a}");
            }
        }
        let mut untouched = Gradients::for_scene(&scene);
        Regularisers::OFF.add_gradient(&scene, &mut untouched);
        assert_eq!(untouched.v_opacities, [0.0, 0.0]);
    }
}
