//! The slow, obviously correct twin of the forward renderer: f64 throughout, every kernel
//! against every pixel, no tiles, no bounds, no rewriting of formulas (SPEC §2–5 as written).
//!
//! It mirrors [`crate::render::RenderContext::render`] and exists for tests, benches and
//! reports. Besides the image it returns, per pixel, the sum of |contributions| (for the
//! error bound `atol + rtol·Σ|a|`), the number of pairs summed, and the number of pairs in
//! the band `|q - qmax| ≤ 1e-4 max(1, qmax)` where SPEC §5 lets implementations differ.

use glam::{DMat3, DQuat, DVec2, DVec3};

use crate::camera::Camera;
use crate::render::RenderOptions;
use crate::scene::Scene;

/// Relative width of the cut-off band of SPEC §5 (precision).
pub const BORDERLINE_BAND: f64 = 1e-4;

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
    /// `a(τ)`.
    pub amplitude: [f64; 3],
}

/// Output of [`render_reference`].
#[derive(Clone, Debug, Default)]
pub struct ReferenceImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// RGB, row-major, like [`crate::raster::Image`].
    pub pixels: Vec<f64>,
    /// Per pixel and channel: `|b_c| + Σ_i [q ≤ qmax] |a_i,c exp(-½ q)|`.
    pub abs_sum: Vec<f64>,
    /// Per pixel: pairs in the cut-off band.
    pub borderline: Vec<u32>,
    /// Pairs summed (indicator 1), all pixels.
    pub pairs: u64,
    /// Pairs in the cut-off band, all pixels.
    pub borderline_pairs: u64,
}

/// Slices and projects kernel `index` of `scene` (SPEC §2 and §4), or `None` when culled.
#[must_use]
pub fn reference_kernel(
    scene: &Scene,
    index: usize,
    camera: &Camera,
    tau: f64,
    options: &RenderOptions,
) -> Option<ReferenceKernel> {
    let [x, y, z, t] = scene.means[index];
    let [sx, sy, sz, st] = scene.scales[index];
    let amp = scene.amplitudes[index];
    // §5 culling in log space.
    let d = (tau - t) / st;
    let peak = amp.iter().map(|a| a.abs()).fold(0.0, f64::max);
    let qmax = if peak == 0.0 {
        return None;
    } else if options.cutoff == 0.0 {
        f64::INFINITY
    } else {
        2.0 * (peak.ln() - 0.5 * d * d - options.cutoff.ln())
    };
    if qmax <= 0.0 {
        return None;
    }
    // §2 slice.
    let w = (-0.5 * d * d).exp();
    let m = DVec3::new(x, y, z) + DVec3::from(scene.velocities[index]) * (tau - t);
    let [qw, qx, qy, qz] = scene.rotations[index];
    let r = DMat3::from_quat(DQuat::from_xyzw(qx, qy, qz, qw).normalize());
    let sigma3 = r * DMat3::from_diagonal(DVec3::new(sx * sx, sy * sy, sz * sz)) * r.transpose();
    // §4 projection.
    let rc = DMat3::from_cols_array_2d(&camera.rotation()).transpose();
    let p = rc * m + DVec3::from(camera.translation());
    if p.z < camera.near || p.z > camera.far {
        return None;
    }
    let sigma_c = rc * sigma3 * rc.transpose();
    let (w_px, h_px) = (f64::from(camera.width), f64::from(camera.height));
    let lim_x_pos = (w_px - camera.cx) / camera.fx + 0.3 * 0.5 * w_px / camera.fx;
    let lim_x_neg = camera.cx / camera.fx + 0.3 * 0.5 * w_px / camera.fx;
    let lim_y_pos = (h_px - camera.cy) / camera.fy + 0.3 * 0.5 * h_px / camera.fy;
    let lim_y_neg = camera.cy / camera.fy + 0.3 * 0.5 * h_px / camera.fy;
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
        [full.x_axis.x + options.dilation, full.y_axis.x],
        [full.x_axis.y, full.y_axis.y + options.dilation],
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
        index,
        mean: [fx * p.x / p.z + camera.cx, fy * p.y / p.z + camera.cy],
        conic,
        qmax,
        amplitude: amp.map(|a| a * w),
    })
}

/// Every kernel that survives culling, in scene order.
#[must_use]
pub fn reference_kernels(
    scene: &Scene,
    camera: &Camera,
    tau: f64,
    options: &RenderOptions,
) -> Vec<ReferenceKernel> {
    (0..scene.len())
        .filter_map(|i| reference_kernel(scene, i, camera, tau, options))
        .collect()
}

/// `q = (p - m2)ᵀ Q (p - m2)` at pixel `(i, j)`.
#[must_use]
pub fn quadratic_form(kernel: &ReferenceKernel, i: u32, j: u32) -> f64 {
    let delta = DVec2::new(f64::from(i) + 0.5, f64::from(j) + 0.5) - DVec2::from(kernel.mean);
    let q = kernel.conic;
    delta.x * (q[0][0] * delta.x + q[0][1] * delta.y)
        + delta.y * (q[1][0] * delta.x + q[1][1] * delta.y)
}

/// True when `q` is in the band `|q - qmax| ≤ 1e-4 max(1, qmax)` of SPEC §5 where
/// implementations may disagree on the indicator. Without truncation there is no band.
#[must_use]
pub fn is_borderline(q: f64, qmax: f64) -> bool {
    qmax.is_finite() && (q - qmax).abs() <= BORDERLINE_BAND * qmax.max(1.0)
}

/// Renders every kernel against every pixel in f64 (SPEC §5, Eq. 2).
#[must_use]
pub fn render_reference(
    scene: &Scene,
    camera: &Camera,
    tau: f64,
    options: &RenderOptions,
) -> ReferenceImage {
    let kernels = reference_kernels(scene, camera, tau, options);
    let n = camera.pixel_count();
    let mut out = ReferenceImage {
        width: camera.width,
        height: camera.height,
        pixels: Vec::with_capacity(3 * n),
        abs_sum: Vec::with_capacity(3 * n),
        borderline: Vec::with_capacity(n),
        ..ReferenceImage::default()
    };
    for j in 0..camera.height {
        for i in 0..camera.width {
            let mut colour = scene.background;
            let mut abs_sum = scene.background.map(f64::abs);
            let mut borderline = 0;
            for kernel in &kernels {
                let q = quadratic_form(kernel, i, j);
                if is_borderline(q, kernel.qmax) {
                    borderline += 1;
                }
                if q <= kernel.qmax {
                    let g = (-0.5 * q).exp();
                    for c in 0..3 {
                        colour[c] += kernel.amplitude[c] * g;
                        abs_sum[c] += (kernel.amplitude[c] * g).abs();
                    }
                    out.pairs += 1;
                }
            }
            out.pixels.extend_from_slice(&colour);
            out.abs_sum.extend_from_slice(&abs_sum);
            out.borderline.push(borderline);
            out.borderline_pairs += u64::from(borderline);
        }
    }
    out
}
