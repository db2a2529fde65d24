//! f64 twin of stage 2, [`crate::project`] (SPEC §4), written as the SPEC states it: the
//! clamped EWA Jacobian as a matrix, `Σ2 = J Σc Jᵀ + s I`, the conic by the 2×2 inverse.

use glam::{DMat3, DVec3};

use crate::model::Camera;
use crate::reference::slice::ReferenceSlice;

/// One kernel after slicing and projection, in f64.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReferenceKernel {
    /// Scene index.
    pub index: usize,
    /// `m2`, pixels.
    pub mean: [f64; 2],
    /// `Q = Σ2⁻¹` as a full 2×2 matrix (row-major).
    pub conic: [[f64; 2]; 2],
    /// `qmax` (`+∞` without truncation).
    pub qmax: f64,
    /// `a(τ)`; alpha scenes: `A`.
    pub amplitude: [f64; 3],
    /// Alpha scenes: `o(τ)`.
    pub opacity: f64,
    /// Camera-space slice centre `(x, y, z)`.
    pub camera_mean: [f64; 3],
    /// Which of x/z, y/z lie strictly outside the clamp limits (SPEC §4).
    pub clamped: [bool; 2],
    /// Clamped `(tx, ty)`.
    pub clamped_xy: [f64; 2],
    /// `Σc = Rc Σ3 Rcᵀ`.
    pub camera_covariance: DMat3,
    /// Temporal weight `w(τ)`.
    pub weight: f64,
    /// `d = (τ - t)/st`.
    pub d: f64,
}

/// Projects a sliced kernel through `camera` with dilation `dilation` (px²), or `None` when
/// culled (behind `near`, beyond `far`, or a degenerate `Σ2`).
#[must_use]
pub fn reference_project(
    slice: &ReferenceSlice,
    camera: &Camera,
    dilation: f64,
) -> Option<ReferenceKernel> {
    // §4 projection.
    let rc = DMat3::from_cols_array_2d(&camera.rotation()).transpose();
    let p = rc * slice.mean + DVec3::from(camera.translation());
    if p.z < camera.near || p.z > camera.far {
        return None;
    }
    let sigma_c = rc * slice.covariance * rc.transpose();
    let (w_px, h_px) = (f64::from(camera.width), f64::from(camera.height));
    // A window of a view clamps at its view's limits.
    let [lim_x_neg, lim_x_pos, lim_y_neg, lim_y_pos] = camera.clamp.unwrap_or([
        camera.cx / camera.fx + 0.3 * 0.5 * w_px / camera.fx,
        (w_px - camera.cx) / camera.fx + 0.3 * 0.5 * w_px / camera.fx,
        camera.cy / camera.fy + 0.3 * 0.5 * h_px / camera.fy,
        (h_px - camera.cy) / camera.fy + 0.3 * 0.5 * h_px / camera.fy,
    ]);
    let tx = p.z * (p.x / p.z).clamp(-lim_x_neg, lim_x_pos);
    let ty = p.z * (p.y / p.z).clamp(-lim_y_neg, lim_y_pos);
    let (fx, fy, zz) = (camera.fx, camera.fy, p.z);
    // J as a 3×3 with a zero last row, so glam can multiply it.
    let j = DMat3::from_cols_array_2d(&[
        [fx / zz, 0.0, 0.0],
        [0.0, fy / zz, 0.0],
        [-fx * tx / (zz * zz), -fy * ty / (zz * zz), 0.0],
    ]);
    let full = j * sigma_c * j.transpose();
    let s2 = [
        [full.x_axis.x + dilation, full.y_axis.x],
        [full.x_axis.y, full.y_axis.y + dilation],
    ];
    let det = s2[0][0] * s2[1][1] - s2[0][1] * s2[1][0];
    if !(det.is_finite() && det > 0.0) {
        return None;
    }
    let conic = [
        [s2[1][1] / det, -s2[0][1] / det],
        [-s2[1][0] / det, s2[0][0] / det],
    ];
    if !conic.iter().flatten().all(|c| c.is_finite()) {
        return None;
    }
    Some(ReferenceKernel {
        index: slice.index,
        mean: [fx * p.x / p.z + camera.cx, fy * p.y / p.z + camera.cy],
        conic,
        qmax: slice.qmax,
        amplitude: slice.amplitude,
        opacity: slice.opacity,
        camera_mean: p.into(),
        clamped: [
            p.x / p.z < -lim_x_neg || p.x / p.z > lim_x_pos,
            p.y / p.z < -lim_y_neg || p.y / p.z > lim_y_pos,
        ],
        clamped_xy: [tx, ty],
        camera_covariance: sigma_c,
        weight: slice.weight,
        d: slice.d,
    })
}
