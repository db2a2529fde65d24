//! f64 twin of the backward pass, [`crate::backward`] (SPEC §6): the loss and its exact
//! gradient by the chain rule written with whole matrices.

use glam::{DMat2, DMat3, DQuat, DVec2, DVec3, DVec4};

use crate::backward::Gradients;
use crate::model::{Camera, Scene};
use crate::reference::raster::{quadratic_form, render_reference};
use crate::reference::{ReferenceKernel, reference_kernels};
use crate::render::RenderOptions;

/// `MSE = mean over pixels and channels of (C - C_gt)²` (SPEC §6, one view), in f64.
#[must_use]
pub fn mse(image: &[f64], target: &[f32]) -> f64 {
    assert_eq!(image.len(), target.len(), "image and target sizes differ");
    image
        .iter()
        .zip(target)
        .map(|(c, &t)| (c - f64::from(t)).powi(2))
        .sum::<f64>()
        / image.len() as f64
}

/// The MSE of the f64 render against `target` (RGB, row-major) and its exact gradient
/// (SPEC §6), by the chain rule written with whole matrices:
///
/// ```text
/// ∂L/∂Q  = Σ_pairs ∂L/∂q d dᵀ,  ∂L/∂m2 = Σ_pairs ∂L/∂q (-2 Q d),  ∂L/∂q = -½ G Σ_c ∂L/∂C_c a_c
/// ∂L/∂Σ2 = -Q (∂L/∂Q) Q,        ∂L/∂J = 2 (∂L/∂Σ2) J Σc
/// ∂L/∂p  = Σ_(r,c) (∂L/∂J)_rc ∂J_rc/∂p + (∂m2/∂p)ᵀ ∂L/∂m2,   ∂L/∂m = Rcᵀ ∂L/∂p
/// ```
///
/// then through the slice as SPEC §6 lists, and to the rotation through `Σ3` (SPEC §8: the
/// quaternion as `scene` holds it, of any length, through its normalisation). SPEC §9: with
/// `d_t = τ - t`, `∂L/∂a = ½ d_t² ∂L/∂m`, and with `p = q + ω d_t` (whose normalisation gives
/// the axes) `∂L/∂q = ∂L/∂p`, `∂L/∂ω = d_t ∂L/∂p`; `∂L/∂t` gains `-d_t aᵀ ∂L/∂m - ωᵀ ∂L/∂p`.
#[must_use]
pub fn reference_loss_and_gradients(
    scene: &Scene,
    camera: &Camera,
    tau: f64,
    options: &RenderOptions,
    target: &[f32],
) -> (f64, Gradients) {
    let image = render_reference(scene, camera, tau, options);
    let loss = mse(&image.pixels, target);
    let n = scene.len();
    let mut grads = Gradients::zeros(n);
    grads
        .v_accelerations
        .resize(scene.accelerations.len(), [0.0; 3]);
    grads
        .v_angular_velocities
        .resize(scene.angular_velocities.len(), [0.0; 4]);
    let scale = 2.0 / image.pixels.len() as f64;
    let v_image: Vec<f64> = image
        .pixels
        .iter()
        .zip(target)
        .map(|(c, &t)| scale * (c - f64::from(t)))
        .collect();
    for pixel in v_image.chunks_exact(3) {
        for (total, v) in grads.v_background.iter_mut().zip(pixel) {
            *total += v;
        }
    }
    let rc = DMat3::from_cols_array_2d(&camera.rotation()).transpose();
    for kernel in reference_kernels(scene, camera, tau, options) {
        let q_mat = DMat2::from_cols_array_2d(&kernel.conic).transpose();
        let (v_q, v_m2, v_a) = pixel_partials(&kernel, &q_mat, camera, &v_image);
        let (v_m, jac, v_sigma2_3) = projection_partials(&kernel, &q_mat, camera, v_q, v_m2, &rc);
        // Slice (SPEC §6).
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
        // Scales: Σc = Rc Σ3 Rcᵀ with Σ3 = R S² Rᵀ; σt through the temporal weight.
        let v_sigma_c = jac.transpose() * v_sigma2_3 * jac;
        let v_sigma3 = rc.transpose() * v_sigma_c * rc;
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
    (loss, grads)
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

/// One kernel's partials summed over the pixels it reaches: `∂L/∂Q`, `∂L/∂m2` and the
/// amplitude's `Σ ∂L/∂C G` (before the temporal weight).
fn pixel_partials(
    kernel: &ReferenceKernel,
    q_mat: &DMat2,
    camera: &Camera,
    v_image: &[f64],
) -> (DMat2, DVec2, [f64; 3]) {
    let mut v_q = DMat2::ZERO;
    let mut v_m2 = DVec2::ZERO;
    let mut v_a = [0.0; 3];
    for j in 0..camera.height {
        for i in 0..camera.width {
            let q = quadratic_form(kernel, i, j);
            if q > kernel.qmax {
                continue;
            }
            let k = 3 * (j as usize * camera.width as usize + i as usize);
            let g = (-0.5 * q).exp();
            let mut v_q_scalar = 0.0;
            for c in 0..3 {
                v_a[c] += v_image[k + c] * g;
                v_q_scalar += -0.5 * g * v_image[k + c] * kernel.amplitude[c];
            }
            let d = DVec2::new(f64::from(i) + 0.5, f64::from(j) + 0.5) - DVec2::from(kernel.mean);
            v_q += v_q_scalar * DMat2::from_cols(d * d.x, d * d.y);
            v_m2 += v_q_scalar * (-2.0 * (q_mat * d));
        }
    }
    (v_q, v_m2, v_a)
}

/// Through the projection: `∂L/∂m` (camera-to-world applied), and the Jacobian `J` and
/// `∂L/∂Σ2` (as 3×3) the scales' partials need.
fn projection_partials(
    kernel: &ReferenceKernel,
    q_mat: &DMat2,
    camera: &Camera,
    v_q: DMat2,
    v_m2: DVec2,
    rc: &DMat3,
) -> (DVec3, DMat3, DMat3) {
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
    let v_sigma2 = -(*q_mat * v_q * *q_mat);
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
    (rc.transpose() * v_p, jac, v_sigma2_3)
}
