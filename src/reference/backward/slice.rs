//! f64 twin of [`crate::backward::slice`] (SPEC §2, §6, §8), additive scenes: from one
//! kernel's `∂L/∂m(τ)`, `Σ ∂L/∂C G` and `∂L/∂Σ3` to its parameters, with
//! `w = exp(-½ d²)`, `d = (τ - t)/st`:
//!
//! ```text
//! ∂L/∂(x, y, z) = ∂L/∂m,   ∂L/∂v = (τ - t) ∂L/∂m,   ∂L/∂A_c = w Σ ∂L/∂C_c G
//! ∂L/∂t  = Σ_c A_c w (d/st) Σ ∂L/∂C_c G - vᵀ ∂L/∂m
//! ∂L/∂st = Σ_c A_c w (d²/st) Σ ∂L/∂C_c G
//! ∂L/∂s_k = 2 s_k (Rᵀ ∂L/∂Σ3 R)_kk          (Σ3 = R S² Rᵀ, k = x, y, z)
//! ```
//!
//! and the rotation through `Σ3` (SPEC §8: the quaternion as the scene holds it, of any
//! length, through its normalisation). SPEC §9: with `d_t = τ - t`, `∂L/∂a = ½ d_t² ∂L/∂m`,
//! and with `p = q + ω d_t` (whose normalisation gives the axes) `∂L/∂q = ∂L/∂p`,
//! `∂L/∂ω = d_t ∂L/∂p`; `∂L/∂t` gains `-d_t aᵀ ∂L/∂m - ωᵀ ∂L/∂p`.

use glam::{DMat3, DQuat, DVec3, DVec4};

use crate::backward::Gradients;
use crate::model::Scene;
use crate::reference::ReferenceKernel;

/// Writes kernel `kernel.index`'s gradients into `grads` from `v_m = ∂L/∂m(τ)`,
/// `v_a = Σ ∂L/∂C G` per channel and `v_sigma3 = ∂L/∂Σ3`.
pub fn reference_slice_backward(
    scene: &Scene,
    kernel: &ReferenceKernel,
    tau: f64,
    v_m: DVec3,
    v_a: [f64; 3],
    v_sigma3: DMat3,
    grads: &mut Gradients,
) {
    let i = kernel.index;
    let amplitude = scene.amplitudes[i];
    let velocity = DVec3::from(scene.velocities[i]);
    let st = scene.scales[i][3];
    let dt = tau - scene.means[i][3];
    // SPEC §9: ∂m/∂t = -(v + a d_t), ∂m/∂a = ½ d_t².
    let acceleration = DVec3::from(scene.acceleration(i));
    let mut v_t = (0..3)
        .map(|c| amplitude[c] * kernel.weight * (kernel.d / st) * v_a[c])
        .sum::<f64>()
        - (velocity + acceleration * dt).dot(v_m);
    if let Some(v_acceleration) = grads.v_accelerations.get_mut(i) {
        *v_acceleration = (0.5 * dt * dt * v_m).into();
    }
    grads.v_amplitudes[i] = v_a.map(|v| kernel.weight * v);
    grads.v_velocities[i] = (dt * v_m).into();
    // Scales: Σ3 = R S² Rᵀ; σt through the temporal weight.
    // SPEC §9: the axes of p = q + ω d_t (q itself when ω = 0), through p/|p|.
    let omega = DVec4::from(scene.angular_velocity(i));
    let turned = DVec4::from(scene.rotations[i]) + omega * dt;
    let [qw, qx, qy, qz] = turned.to_array();
    let rotation = DMat3::from_quat(DQuat::from_xyzw(qx, qy, qz, qw).normalize());
    let v_axes = rotation.transpose() * v_sigma3 * rotation;
    let s = scene.scales[i];
    grads.v_scales[i] = [
        2.0 * s[0] * v_axes.x_axis.x,
        2.0 * s[1] * v_axes.y_axis.y,
        2.0 * s[2] * v_axes.z_axis.z,
        (0..3)
            .map(|c| amplitude[c] * kernel.weight * (kernel.d * kernel.d / st) * v_a[c])
            .sum(),
    ];
    let v_turned = quaternion_gradient(turned.to_array(), &rotation, s, v_sigma3);
    grads.v_rotations[i] = v_turned;
    // ∂p/∂q = I, ∂p/∂ω = d_t I, ∂p/∂t = -ω.
    v_t -= omega.dot(DVec4::from(v_turned));
    if let Some(v_omega) = grads.v_angular_velocities.get_mut(i) {
        *v_omega = (dt * DVec4::from(v_turned)).into();
    }
    grads.v_means[i] = [v_m.x, v_m.y, v_m.z, v_t];
}

/// `∂L/∂q` of the quaternion `q` as stored (any length; SPEC §8: through its
/// normalisation) from `V = ∂L/∂Σ3`, with `rotation = R(q̂)` and the scales `s`:
///
/// ```text
/// Σ3 = R S² Rᵀ                              ∂L/∂R = (V + Vᵀ) R S²
/// R(q̂) = (w² - |u|²) I + 2 u uᵀ + 2 w [u]×   q̂ = (w, u) = q/|q|
/// ∂L/∂q̂_k = ⟨∂L/∂R, ∂R/∂q̂_k⟩                ∂L/∂q = (I - q̂ q̂ᵀ) ∂L/∂q̂ / |q|
/// ```
///
/// (the matrix form of R, whose derivatives differ from those of SPEC §1's entries off the
/// unit sphere; the projection removes the difference).
fn quaternion_gradient(q: [f64; 4], rotation: &DMat3, s: [f64; 4], v_sigma3: DMat3) -> [f64; 4] {
    let stored = DVec4::from(q);
    let norm = stored.length();
    let unit = stored / norm;
    let (w, u) = (unit.x, DVec3::new(unit.y, unit.z, unit.w));
    let squares = DMat3::from_diagonal(DVec3::new(s[0] * s[0], s[1] * s[1], s[2] * s[2]));
    let v_rotation = (v_sigma3 + v_sigma3.transpose()) * *rotation * squares;
    // [a]× (its column j is a × e_j) and a bᵀ (its column j is a b_j).
    let cross =
        |a: DVec3| DMat3::from_cols(a.cross(DVec3::X), a.cross(DVec3::Y), a.cross(DVec3::Z));
    let outer = |a: DVec3, b: DVec3| DMat3::from_cols(a * b.x, a * b.y, a * b.z);
    let inner = |a: DMat3, b: DMat3| {
        a.x_axis.dot(b.x_axis) + a.y_axis.dot(b.y_axis) + a.z_axis.dot(b.z_axis)
    };
    let d_w = DMat3::IDENTITY * (2.0 * w) + cross(u) * 2.0;
    let d_u = |e: DVec3, component: f64| {
        DMat3::IDENTITY * (-2.0 * component)
            + (outer(e, u) + outer(u, e)) * 2.0
            + cross(e) * (2.0 * w)
    };
    let v_unit = DVec4::new(
        inner(v_rotation, d_w),
        inner(v_rotation, d_u(DVec3::X, u.x)),
        inner(v_rotation, d_u(DVec3::Y, u.y)),
        inner(v_rotation, d_u(DVec3::Z, u.z)),
    );
    ((v_unit - unit * unit.dot(v_unit)) / norm).into()
}
