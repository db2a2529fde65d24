//! Backward of stage 2, the EWA projection (SPEC §4, §6): from `∂L/∂Σ2` and `∂L/∂m2` to
//! `∂L/∂m(τ)`, the world-space slice centre, and `∂L/∂Σ3`, the world-space covariance (for
//! fits that move the scales). (The conic's gradient `∂L/∂Σ2 = -Q (∂L/∂Q) Q` is already
//! formed by the raster backward.)
//!
//! ```text
//! ∂L/∂J  = 2 (∂L/∂Σ2) J Σc              (2×3, Σ2 = J Σc Jᵀ + s I)
//! J = [[fx/z, 0, -fx tx/z²], [0, fy/z, -fy ty/z²]],   tx = x, or z·lim where x/z is clamped
//! ∂L/∂x  = ∂L/∂J02 (-fx ∂tx/∂x / z²) + ∂L/∂m2x fx/z
//! ∂L/∂y  = ∂L/∂J12 (-fy ∂ty/∂y / z²) + ∂L/∂m2y fy/z
//! ∂L/∂z  = -∂L/∂J00 fx/z² - ∂L/∂J11 fy/z² + ∂L/∂J02 (2 fx tx/z³ - fx ∂tx/∂z / z²)
//!          + ∂L/∂J12 (2 fy ty/z³ - fy ∂ty/∂z / z²) - ∂L/∂m2x fx x/z² - ∂L/∂m2y fy y/z²
//! ∂L/∂m  = Rcᵀ ∂L/∂(x, y, z)
//! ∂L/∂Σ3 = Rcᵀ Jᵀ (∂L/∂Σ2) J Rc        (Σc = Rc Σ3 Rcᵀ)
//! ```
//!
//! with `∂tx/∂x = 1, ∂tx/∂z = 0` unclamped and `∂tx/∂x = 0, ∂tx/∂z = lim = tx/z` clamped
//! (likewise y). All f64; the per-kernel projection is recomputed from the slice.

use rayon::prelude::*;

use crate::backward::raster::ScreenGradients;
use crate::model::camera::Camera;
use crate::project::{ProjectedKernels, Projection, project_one};
use crate::slice::SlicedKernels;

/// Per sliced kernel: gradients at the slice (zero for kernels culled by the projection).
/// For alpha frames `v_amplitudes` is `∂L/∂colour`, carried back by
/// [`crate::backward::slice`].
#[derive(Clone, Debug, Default)]
pub struct SliceGradients {
    /// `∂L/∂m(τ)`, world space.
    pub v_means: Vec<[f64; 3]>,
    /// `∂L/∂a(τ)` per channel.
    pub v_amplitudes: Vec<[f64; 3]>,
    /// `∂L/∂Σ3` (3×3, symmetric), world space.
    pub v_covariances: Vec<[[f64; 3]; 3]>,
    /// Alpha frames: `∂L/∂o(τ)` (empty for additive frames).
    pub v_opacities: Vec<f64>,
}

/// `∂L/∂Σ3 = Rcᵀ Jᵀ V J Rc` for `V = ∂L/∂Σ2` (`[xx, xy, yy]`), `rc` row-major.
#[must_use]
pub fn world_covariance_gradient(
    rc: &[[f64; 3]; 3],
    jacobian: &[[f64; 3]; 2],
    v_covariance2: [f64; 3],
) -> [[f64; 3]; 3] {
    let [vxx, vxy, vyy] = v_covariance2;
    let v = [[vxx, vxy], [vxy, vyy]];
    // J Rc (2×3), then (J Rc)ᵀ V (J Rc).
    let jr: [[f64; 3]; 2] = std::array::from_fn(|i| {
        std::array::from_fn(|j| (0..3).map(|k| jacobian[i][k] * rc[k][j]).sum())
    });
    std::array::from_fn(|a| {
        std::array::from_fn(|b| {
            (0..2)
                .map(|i| (0..2).map(|j| jr[i][a] * v[i][j] * jr[j][b]).sum::<f64>())
                .sum()
        })
    })
}

/// `∂L/∂(x, y, z)` in camera space of one kernel from its screen gradients.
#[must_use]
pub fn camera_mean_gradient(
    camera: &Camera,
    proj: &Projection,
    v_mean2: [f64; 2],
    v_covariance2: [f64; 3],
) -> [f64; 3] {
    let [vxx, vxy, vyy] = v_covariance2;
    let v_sigma2 = [[vxx, vxy], [vxy, vyy]];
    // ∂L/∂J = 2 V_Σ2 J Σc
    let jac = proj.jacobian;
    let sc = proj.camera_covariance;
    let js: [[f64; 3]; 2] = std::array::from_fn(|i| {
        std::array::from_fn(|j| (0..3).map(|k| jac[i][k] * sc[k][j]).sum())
    });
    let v_jac: [[f64; 3]; 2] = std::array::from_fn(|i| {
        std::array::from_fn(|j| 2.0 * (v_sigma2[i][0] * js[0][j] + v_sigma2[i][1] * js[1][j]))
    });
    let [x, y, z] = proj.camera_mean;
    let [tx, ty] = proj.clamped_xy;
    let (fx, fy) = (camera.fx, camera.fy);
    let (dtx_dx, dtx_dz) = if proj.clamped[0] {
        (0.0, tx / z)
    } else {
        (1.0, 0.0)
    };
    let (dty_dy, dty_dz) = if proj.clamped[1] {
        (0.0, ty / z)
    } else {
        (1.0, 0.0)
    };
    let (z2, z3) = (z * z, z * z * z);
    let v_x = v_jac[0][2] * (-fx * dtx_dx / z2) + v_mean2[0] * fx / z;
    let v_y = v_jac[1][2] * (-fy * dty_dy / z2) + v_mean2[1] * fy / z;
    let v_z = -v_jac[0][0] * fx / z2 - v_jac[1][1] * fy / z2
        + v_jac[0][2] * (2.0 * fx * tx / z3 - fx * dtx_dz / z2)
        + v_jac[1][2] * (2.0 * fy * ty / z3 - fy * dty_dz / z2)
        - v_mean2[0] * fx * x / z2
        - v_mean2[1] * fy * y / z2;
    [v_x, v_y, v_z]
}

/// Carries `screen` (per projected kernel) back to the slice, into `out` (one entry per
/// sliced kernel, reset first).
pub fn project_backward(
    sliced: &SlicedKernels,
    proj: &ProjectedKernels,
    camera: &Camera,
    dilation: f64,
    screen: &ScreenGradients,
    out: &mut SliceGradients,
) {
    out.v_means.clear();
    out.v_means.resize(sliced.len(), [0.0; 3]);
    out.v_amplitudes.clear();
    out.v_amplitudes.resize(sliced.len(), [0.0; 3]);
    out.v_covariances.clear();
    out.v_covariances.resize(sliced.len(), [[0.0; 3]; 3]);
    // Alpha frames carry `∂L/∂o(τ)` for every slice, also when no kernel reached the
    // screen (a view that sees nothing: every entry stays zero).
    let alpha = !screen.v_opacities.is_empty() || !sliced.opacities.is_empty();
    out.v_opacities.clear();
    if alpha {
        out.v_opacities.resize(sliced.len(), 0.0);
    }
    let rc = camera.rotation();
    // Each projected kernel's slice, by slice (`slice_from_proj` is one-to-one): the slices
    // are then filled in parallel, each from its own kernel's values alone.
    const CULLED: u32 = u32::MAX;
    let mut proj_from_slice = vec![CULLED; sliced.len()];
    for (p, &s) in proj.slice_from_proj.iter().enumerate() {
        proj_from_slice[s as usize] = p as u32;
    }
    (
        out.v_means.par_iter_mut(),
        out.v_amplitudes.par_iter_mut(),
        out.v_covariances.par_iter_mut(),
        &proj_from_slice,
    )
        .into_par_iter()
        .enumerate()
        .with_min_len(256)
        .filter(|(_, (_, _, _, p))| **p != CULLED)
        .for_each(|(s, (v_mean, v_amplitude, v_covariance, &p))| {
            let p = p as usize;
            let projection = project_one(camera, dilation, sliced.means[s], sliced.covariances[s])
                .expect("a kernel that was projected projects again");
            let v_p = camera_mean_gradient(
                camera,
                &projection,
                screen.v_means[p],
                screen.v_covariances[p],
            );
            // p_cam = Rc m + tc  →  ∂L/∂m = Rcᵀ ∂L/∂p_cam
            *v_mean = std::array::from_fn(|c| (0..3).map(|r| rc[r][c] * v_p[r]).sum());
            *v_amplitude = screen.v_amplitudes[p];
            *v_covariance =
                world_covariance_gradient(&rc, &projection.jacobian, screen.v_covariances[p]);
        });
    if alpha {
        for (&p, v_opacity) in proj_from_slice.iter().zip(&mut out.v_opacities) {
            if p != CULLED {
                *v_opacity = screen.v_opacities[p as usize];
            }
        }
    }
}
