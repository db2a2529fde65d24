//! f64 twin of [`crate::backward::project`] (SPEC §4, §6): from one kernel's `∂L/∂Σ2` and
//! `∂L/∂m2` through the EWA projection to `∂L/∂m(τ)`, the world-space slice centre, and
//! `∂L/∂Σ3`, with whole matrices:
//!
//! ```text
//! ∂L/∂J  = 2 (∂L/∂Σ2) J Σc                 (Σ2 = J Σc Jᵀ + s I, J as 3×3 with a zero third row)
//! ∂L/∂p  = Σ_(r,c) (∂L/∂J)_rc ∂J_rc/∂p + (∂m2/∂p)ᵀ ∂L/∂m2,   ∂L/∂m = Rcᵀ ∂L/∂p
//! ∂L/∂Σ3 = Rcᵀ Jᵀ (∂L/∂Σ2) J Rc            (Σc = Rc Σ3 Rcᵀ)
//! ```
//!
//! with `J`'s derivatives through the frustum clamp as SPEC §6 states them.

use glam::{DMat2, DMat3, DVec2, DVec3};

use crate::model::Camera;
use crate::reference::ReferenceKernel;

/// `∂L/∂m(τ)` (world space) and `∂L/∂Σ3` of one kernel from its screen gradients
/// `v_sigma2 = ∂L/∂Σ2` and `v_m2 = ∂L/∂m2`.
#[must_use]
pub fn reference_project_backward(
    kernel: &ReferenceKernel,
    camera: &Camera,
    v_sigma2: DMat2,
    v_m2: DVec2,
) -> (DVec3, DMat3) {
    let rc = DMat3::from_cols_array_2d(&camera.rotation()).transpose();
    // Σ2 = J Σc Jᵀ + s I; as 3×3 with a zero third row of J.
    let [x, y, z] = kernel.camera_mean;
    let [tx, ty] = kernel.clamped_xy;
    let (fx, fy) = (camera.fx, camera.fy);
    let j_of = |entries: [[f64; 3]; 2]| {
        DMat3::from_cols_array_2d(&[
            [entries[0][0], entries[1][0], 0.0],
            [entries[0][1], entries[1][1], 0.0],
            [entries[0][2], entries[1][2], 0.0],
        ])
    };
    let jac = j_of([
        [fx / z, 0.0, -fx * tx / (z * z)],
        [0.0, fy / z, -fy * ty / (z * z)],
    ]);
    let v_sigma2_3 = DMat3::from_cols_array_2d(&[
        [v_sigma2.x_axis.x, v_sigma2.x_axis.y, 0.0],
        [v_sigma2.y_axis.x, v_sigma2.y_axis.y, 0.0],
        [0.0; 3],
    ]);
    let v_jac = 2.0 * v_sigma2_3 * jac * kernel.camera_covariance;
    // ∂J/∂x, ∂J/∂y, ∂J/∂z with tx = x (unclamped) or z·lim (clamped), SPEC §6.
    let (dtx_dx, dtx_dz) = if kernel.clamped[0] {
        (0.0, tx / z)
    } else {
        (1.0, 0.0)
    };
    let (dty_dy, dty_dz) = if kernel.clamped[1] {
        (0.0, ty / z)
    } else {
        (1.0, 0.0)
    };
    let dj_dx = j_of([[0.0, 0.0, -fx * dtx_dx / (z * z)], [0.0; 3]]);
    let dj_dy = j_of([[0.0; 3], [0.0, 0.0, -fy * dty_dy / (z * z)]]);
    let dj_dz = j_of([
        [
            -fx / (z * z),
            0.0,
            -fx * dtx_dz / (z * z) + 2.0 * fx * tx / (z * z * z),
        ],
        [
            0.0,
            -fy / (z * z),
            -fy * dty_dz / (z * z) + 2.0 * fy * ty / (z * z * z),
        ],
    ]);
    let frobenius = |a: DMat3, b: DMat3| {
        a.x_axis.dot(b.x_axis) + a.y_axis.dot(b.y_axis) + a.z_axis.dot(b.z_axis)
    };
    let dm2_dp = [
        [fx / z, 0.0, -fx * x / (z * z)],
        [0.0, fy / z, -fy * y / (z * z)],
    ];
    let v_p = DVec3::new(
        frobenius(v_jac, dj_dx) + v_m2.x * dm2_dp[0][0] + v_m2.y * dm2_dp[1][0],
        frobenius(v_jac, dj_dy) + v_m2.x * dm2_dp[0][1] + v_m2.y * dm2_dp[1][1],
        frobenius(v_jac, dj_dz) + v_m2.x * dm2_dp[0][2] + v_m2.y * dm2_dp[1][2],
    );
    // Σc = Rc Σ3 Rcᵀ.
    let v_sigma_c = jac.transpose() * v_sigma2_3 * jac;
    let v_sigma3 = rc.transpose() * v_sigma_c * rc;
    (rc.transpose() * v_p, v_sigma3)
}
