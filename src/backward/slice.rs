//! Backward of stage 1, the slice at τ (SPEC §2, §6): from `∂L/∂m(τ)` and `∂L/∂a(τ)` to the
//! kernel's parameters, with `w = exp(-½ d²)`, `d = (τ - t)/st`:
//!
//! ```text
//! ∂L/∂(x, y, z) = ∂L/∂m
//! ∂L/∂A_c       = w ∂L/∂a_c
//! ∂L/∂t         = Σ_c A_c w (d/st) ∂L/∂a_c - vᵀ ∂L/∂m
//! ∂L/∂v         = (τ - t) ∂L/∂m
//! ∂L/∂s_k       = 2 s_k (Rᵀ ∂L/∂Σ3 R)_kk       (Σ3 = R diag(s²) Rᵀ, k = x, y, z)
//! ∂L/∂st        = Σ_c A_c w (d²/st) ∂L/∂a_c
//! ```
//!
//! Results are added to the scene-order [`Gradients`]; culled kernels receive nothing.

use crate::backward::Gradients;
use crate::backward::project::SliceGradients;
use crate::model::scene::Scene;
use crate::slice::{SlicedKernels, rotation_matrix};

/// Adds the kernel gradients of one view to `grads`.
pub fn slice_backward(
    scene: &Scene,
    tau: f64,
    sliced: &SlicedKernels,
    from_slice: &SliceGradients,
    grads: &mut Gradients,
) {
    assert_eq!(grads.len(), scene.len(), "gradients sized for the scene");
    for s in 0..sliced.len() {
        let i = sliced.kernel_from_slice[s] as usize;
        let v_m = from_slice.v_means[s];
        let v_a = from_slice.v_amplitudes[s];
        let t = scene.means[i][3];
        let st = scene.scales[i][3];
        let dt = tau - t;
        let d = dt / st;
        let w = (-0.5 * d * d).exp();
        let amplitude = scene.amplitudes[i];
        let velocity = scene.velocities[i];
        let v_t = (0..3)
            .map(|c| amplitude[c] * w * (d / st) * v_a[c])
            .sum::<f64>()
            - (0..3).map(|c| velocity[c] * v_m[c]).sum::<f64>();
        let mean = &mut grads.v_means[i];
        for c in 0..3 {
            mean[c] += v_m[c];
            grads.v_amplitudes[i][c] += w * v_a[c];
            grads.v_velocities[i][c] += dt * v_m[c];
        }
        mean[3] += v_t;
        // Scales: the spatial ones through Σ3, σt through the temporal weight.
        let r = rotation_matrix(scene.rotations[i]);
        let v_sigma = from_slice.v_covariances[s];
        let scale = scene.scales[i];
        let v_scale = &mut grads.v_scales[i];
        for k in 0..3 {
            // (Rᵀ V R)_kk = Σ_ab R_ak V_ab R_bk
            let diagonal: f64 = (0..3)
                .map(|a| {
                    (0..3)
                        .map(|b| r[a][k] * v_sigma[a][b] * r[b][k])
                        .sum::<f64>()
                })
                .sum();
            v_scale[k] += 2.0 * scale[k] * diagonal;
        }
        v_scale[3] += (0..3)
            .map(|c| amplitude[c] * w * (d * d / st) * v_a[c])
            .sum::<f64>();
    }
}
