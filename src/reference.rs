//! The slow, obviously correct twin of the forward renderer: f64 throughout, every kernel
//! against every pixel, no tiles, no bounds, no rewriting of formulas (SPEC §2–5 as written).
//!
//! It mirrors [`crate::render::RenderContext::render`] and exists for tests, benches and
//! reports. Besides the image it returns, per pixel, the sum of |contributions| (for the
//! error bound `atol + rtol·Σ|a|`), the number of pairs summed, and the number of pairs in
//! the band `|q - qmax| ≤ 1e-4 max(1, qmax)` where SPEC §5 lets implementations differ.

use glam::{DMat2, DMat3, DQuat, DVec2, DVec3};

use crate::backward::Gradients;
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
        camera_mean: p.into(),
        clamped: [
            p.x / p.z < -lim_x_neg || p.x / p.z > lim_x_pos,
            p.y / p.z < -lim_y_neg || p.y / p.z > lim_y_pos,
        ],
        clamped_xy: [tx, ty],
        camera_covariance: sigma_c,
        weight: w,
        d,
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

/// Which pixels a kernel's indicator `[q ≤ qmax]` includes, row-major; used to freeze the
/// pair set while differencing (SPEC §6: the indicator counts as a constant).
pub type PairMask = Vec<bool>;

/// Kernel `kernel`'s contribution `[q ≤ qmax] a exp(-½ q)` to every pixel (RGB, row-major),
/// with the indicator taken from `mask` when given, and the mask it used.
#[must_use]
pub fn kernel_contribution(
    kernel: &ReferenceKernel,
    camera: &Camera,
    mask: Option<&PairMask>,
) -> (Vec<f64>, PairMask) {
    let n = camera.pixel_count();
    let mut image = vec![0.0; 3 * n];
    let mut used = vec![false; n];
    for j in 0..camera.height {
        for i in 0..camera.width {
            let k = j as usize * camera.width as usize + i as usize;
            let q = quadratic_form(kernel, i, j);
            let inside = mask.map_or(q <= kernel.qmax, |m| m[k]);
            if inside {
                let g = (-0.5 * q).exp();
                for c in 0..3 {
                    image[3 * k + c] = kernel.amplitude[c] * g;
                }
                used[k] = true;
            }
        }
    }
    (image, used)
}

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
/// then through the slice as SPEC §6 lists.
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
    let scale = 2.0 / image.pixels.len() as f64;
    let v_image: Vec<f64> = image
        .pixels
        .iter()
        .zip(target)
        .map(|(c, &t)| scale * (c - f64::from(t)))
        .collect();
    let rc = DMat3::from_cols_array_2d(&camera.rotation()).transpose();
    for kernel in reference_kernels(scene, camera, tau, options) {
        let q_mat = DMat2::from_cols_array_2d(&kernel.conic).transpose();
        let mut v_q = DMat2::ZERO;
        let mut v_m2 = DVec2::ZERO;
        let mut v_a = [0.0; 3];
        for j in 0..camera.height {
            for i in 0..camera.width {
                let q = quadratic_form(&kernel, i, j);
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
                let d =
                    DVec2::new(f64::from(i) + 0.5, f64::from(j) + 0.5) - DVec2::from(kernel.mean);
                v_q += v_q_scalar * DMat2::from_cols(d * d.x, d * d.y);
                v_m2 += v_q_scalar * (-2.0 * (q_mat * d));
            }
        }
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
        let v_sigma2 = -(q_mat * v_q * q_mat);
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
        let v_m = rc.transpose() * v_p;
        // Slice (SPEC §6).
        let i = kernel.index;
        let amplitude = scene.amplitudes[i];
        let velocity = DVec3::from(scene.velocities[i]);
        let st = scene.scales[i][3];
        let dt = tau - scene.means[i][3];
        let v_t = (0..3)
            .map(|c| amplitude[c] * kernel.weight * (kernel.d / st) * v_a[c])
            .sum::<f64>()
            - velocity.dot(v_m);
        grads.v_means[i] = [v_m.x, v_m.y, v_m.z, v_t];
        grads.v_amplitudes[i] = v_a.map(|v| kernel.weight * v);
        grads.v_velocities[i] = (dt * v_m).into();
        // Scales: Σc = Rc Σ3 Rcᵀ with Σ3 = R S² Rᵀ; σt through the temporal weight.
        let v_sigma_c = jac.transpose() * v_sigma2_3 * jac;
        let v_sigma3 = rc.transpose() * v_sigma_c * rc;
        let [qw, qx, qy, qz] = scene.rotations[i];
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
    }
    (loss, grads)
}

/// The reference at chosen pixels only: for each `(i, j)`, the f64 colour and `Σ|a|` per
/// channel (every kernel against those pixels). For error estimates on frames too large for
/// [`render_reference`].
#[must_use]
pub fn reference_at_pixels(
    scene: &Scene,
    camera: &Camera,
    tau: f64,
    options: &RenderOptions,
    pixels: &[(u32, u32)],
) -> Vec<([f64; 3], [f64; 3])> {
    let kernels = reference_kernels(scene, camera, tau, options);
    pixels
        .iter()
        .map(|&(i, j)| {
            let mut colour = scene.background;
            let mut abs_sum = scene.background.map(f64::abs);
            for kernel in &kernels {
                let q = quadratic_form(kernel, i, j);
                if q <= kernel.qmax {
                    let g = (-0.5 * q).exp();
                    for c in 0..3 {
                        colour[c] += kernel.amplitude[c] * g;
                        abs_sum[c] += (kernel.amplitude[c] * g).abs();
                    }
                }
            }
            (colour, abs_sum)
        })
        .collect()
}
