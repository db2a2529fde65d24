//! f64 twin of [`crate::backward::raster`] (SPEC §5–6): one kernel's `∂L/∂C` per pixel
//! summed, over every pixel its cut-off reaches, into `∂L/∂Σ2`, `∂L/∂m2` and the
//! amplitude's `Σ ∂L/∂C G`, written with whole matrices:
//!
//! ```text
//! ∂L/∂q  = -½ G Σ_c ∂L/∂C_c a_c,   ∂L/∂Q = Σ_pairs ∂L/∂q d dᵀ,   ∂L/∂m2 = Σ_pairs ∂L/∂q (-2 Q d)
//! ∂L/∂Σ2 = -Q (∂L/∂Q) Q
//! ```
//!
//! with `d = p - m2` and `Q` the kernel's conic, the plain `dᵀ Q d` of
//! [`crate::reference::raster::quadratic_form`] (not the fast raster's sum of squares).

use glam::{DMat2, DVec2};

use crate::model::Camera;
use crate::reference::ReferenceKernel;
use crate::reference::raster::quadratic_form;

/// One kernel's screen gradients from `v_image = ∂L/∂C` (RGB, row-major): `∂L/∂Σ2` (2×2),
/// `∂L/∂m2` and `Σ ∂L/∂C G` per channel (before the temporal weight and the amplitude, which
/// [`super::slice::reference_slice_backward`] applies).
#[must_use]
pub fn reference_raster_backward(
    kernel: &ReferenceKernel,
    camera: &Camera,
    v_image: &[f64],
) -> (DMat2, DVec2, [f64; 3]) {
    let q_mat = DMat2::from_cols_array_2d(&kernel.conic).transpose();
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
    let v_sigma2 = -(q_mat * v_q * q_mat);
    (v_sigma2, v_m2, v_a)
}
