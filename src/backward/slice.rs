//! Backward of stage 1, the slice at τ (SPEC §2, §6, §8): from `∂L/∂m(τ)`, `∂L/∂a(τ)` and
//! `∂L/∂Σ3` to the kernel's parameters, with `w = exp(-½ d²)`, `d = (τ - t)/st`:
//!
//! ```text
//! ∂L/∂(x, y, z) = ∂L/∂m
//! ∂L/∂A_c       = w ∂L/∂a_c
//! ∂L/∂t         = Σ_c A_c w (d/st) ∂L/∂a_c - vᵀ ∂L/∂m
//! ∂L/∂v         = (τ - t) ∂L/∂m
//! ∂L/∂s_k       = 2 s_k (Rᵀ ∂L/∂Σ3 R)_kk       (Σ3 = R diag(s²) Rᵀ, k = x, y, z)
//! ∂L/∂st        = Σ_c A_c w (d²/st) ∂L/∂a_c
//! ∂L/∂R         = 2 ∂L/∂Σ3 R diag(s²)          then through R(q̂) and q̂ = q/|q|
//! ```
//!
//! SPEC §9 (optional acceleration `a` and quaternion rate `ω`, `d_t = τ - t`):
//! `m = (x, y, z) + v d_t + ½ a d_t²` and `R = R(p̂)` with `p = q + ω d_t`, `p̂ = p/|p|`, so
//!
//! ```text
//! ∂L/∂a  = ½ d_t² ∂L/∂m
//! ∂L/∂t -= d_t aᵀ ∂L/∂m + ωᵀ ∂L/∂p             (∂m/∂t = -(v + a d_t), ∂p/∂t = -ω)
//! ∂L/∂q  = ∂L/∂p = (I - p̂ p̂ᵀ) ∂L/∂p̂ / |p|,   ∂L/∂ω = d_t ∂L/∂p
//! ```
//!
//! (a kernel with ω = 0 is the line above, `q` unit).
//!
//! Alpha scenes (SPEC §8) carry the weight on the opacity, `o(τ) = o w`, and a colour
//! `max(0, A + Σ_j Y_j(ω) sh_j)` with `ω = (m - c)/|m - c|`:
//!
//! ```text
//! ∂L/∂o   = w ∂L/∂o(τ)
//! ∂L/∂t  += o w (d/st) ∂L/∂o(τ),   ∂L/∂st = o w (d²/st) ∂L/∂o(τ)
//! g_c     = ∂L/∂colour_c where A_c + Σ Y sh_c > 0, else 0
//! ∂L/∂A_c = g_c,  ∂L/∂sh_jc = Y_j g_c
//! ∂L/∂m  += (I - ω ωᵀ)/|m - c| Σ_jc g_c sh_jc ∇Y_j
//! ```
//!
//! Results are added to the scene-order [`Gradients`]; culled kernels receive nothing.

use crate::backward::Gradients;
use crate::backward::project::SliceGradients;
use crate::colour::{camera_centre, raw_colour, sh_basis, sh_basis_gradient, view_direction};
use crate::model::camera::Camera;
use crate::model::scene::{Blend, Scene};
use crate::slice::{SlicedKernels, rotation_matrix, turned_quaternion};

/// Adds the kernel gradients of one view to `grads` (sized for the scene:
/// [`Gradients::for_scene`]). The kernels run in blocks, in parallel: each kernel takes the
/// terms of its one slice in the same order as one after the other, so the result does not
/// depend on the thread count.
pub fn slice_backward(
    scene: &Scene,
    camera: &Camera,
    tau: f64,
    sliced: &SlicedKernels,
    from_slice: &SliceGradients,
    grads: &mut Gradients,
) {
    use rayon::prelude::*;
    assert_eq!(grads.len(), scene.len(), "gradients sized for the scene");
    let alpha = scene.blend == Blend::Alpha;
    if alpha {
        assert_eq!(grads.v_opacities.len(), scene.len(), "alpha gradients");
        assert_eq!(
            grads.v_sh.len(),
            scene.sh_count * scene.len(),
            "alpha gradients"
        );
    }
    let centre = camera_centre(camera);
    let view = SliceView {
        scene,
        tau,
        centre,
        sliced,
        from_slice,
    };
    kernel_blocks(scene, sliced, grads)
        .into_par_iter()
        .for_each(|mut block| {
            for s in block.slices.clone() {
                let i = sliced.kernel_from_slice[s] as usize;
                view.kernel_backward(s, i, &mut block.kernel(i));
            }
        });
}

/// What every kernel's backward reads.
struct SliceView<'a> {
    scene: &'a Scene,
    tau: f64,
    centre: [f64; 3],
    sliced: &'a SlicedKernels,
    from_slice: &'a SliceGradients,
}

/// One kernel's entries of [`Gradients`].
struct KernelGradients<'a> {
    mean: &'a mut [f64; 4],
    amplitude: &'a mut [f64; 3],
    velocity: &'a mut [f64; 3],
    scale: &'a mut [f64; 4],
    rotation: &'a mut [f64; 4],
    /// SPEC §9: when the scene has accelerations.
    acceleration: Option<&'a mut [f64; 3]>,
    /// SPEC §9: when the scene has angular velocities.
    angular_velocity: Option<&'a mut [f64; 4]>,
    /// Alpha scenes only.
    opacity: Option<&'a mut f64>,
    /// Alpha scenes: the kernel's `sh_count` coefficients (empty otherwise).
    sh: &'a mut [[f64; 3]],
}

/// A block of consecutive kernels' gradients, and the slices of those kernels.
struct KernelBlock<'a> {
    first: usize,
    slices: std::ops::Range<usize>,
    sh_count: usize,
    means: &'a mut [[f64; 4]],
    amplitudes: &'a mut [[f64; 3]],
    velocities: &'a mut [[f64; 3]],
    scales: &'a mut [[f64; 4]],
    rotations: &'a mut [[f64; 4]],
    accelerations: &'a mut [[f64; 3]],
    angular_velocities: &'a mut [[f64; 4]],
    opacities: &'a mut [f64],
    sh: &'a mut [[f64; 3]],
}

impl KernelBlock<'_> {
    /// Kernel `i`'s gradients (`i` in the block).
    fn kernel(&mut self, i: usize) -> KernelGradients<'_> {
        let k = i - self.first;
        let count = self.sh_count;
        KernelGradients {
            mean: &mut self.means[k],
            amplitude: &mut self.amplitudes[k],
            velocity: &mut self.velocities[k],
            scale: &mut self.scales[k],
            rotation: &mut self.rotations[k],
            acceleration: self.accelerations.get_mut(k),
            angular_velocity: self.angular_velocities.get_mut(k),
            opacity: self.opacities.get_mut(k),
            sh: self
                .sh
                .get_mut(k * count..(k + 1) * count)
                .unwrap_or_default(),
        }
    }
}

/// The first `len` items of `rest`, which keeps the others.
fn take<'a, T>(rest: &mut &'a mut [T], len: usize) -> &'a mut [T] {
    let (head, tail) = std::mem::take(rest).split_at_mut(len);
    *rest = tail;
    head
}

/// `grads` split into blocks of consecutive kernels, each with the range of slices of its
/// kernels (`kernel_from_slice` ascends).
fn kernel_blocks<'a>(
    scene: &Scene,
    sliced: &SlicedKernels,
    grads: &'a mut Gradients,
) -> Vec<KernelBlock<'a>> {
    const KERNELS: usize = 1024;
    let n = scene.len();
    let alpha = scene.blend == Blend::Alpha;
    let count = if alpha { scene.sh_count } else { 0 };
    let mut blocks = Vec::with_capacity(n.div_ceil(KERNELS));
    let (mut means, mut amplitudes, mut velocities) = (
        grads.v_means.as_mut_slice(),
        grads.v_amplitudes.as_mut_slice(),
        grads.v_velocities.as_mut_slice(),
    );
    let (mut scales, mut rotations) = (
        grads.v_scales.as_mut_slice(),
        grads.v_rotations.as_mut_slice(),
    );
    let mut opacities = if alpha {
        grads.v_opacities.as_mut_slice()
    } else {
        &mut []
    };
    let mut sh = if alpha {
        grads.v_sh.as_mut_slice()
    } else {
        &mut []
    };
    let accelerating = !grads.v_accelerations.is_empty();
    let turning = !grads.v_angular_velocities.is_empty();
    let mut accelerations = grads.v_accelerations.as_mut_slice();
    let mut angular_velocities = grads.v_angular_velocities.as_mut_slice();
    let mut slice = 0;
    for first in (0..n).step_by(KERNELS) {
        let len = KERNELS.min(n - first);
        let end = slice
            + sliced.kernel_from_slice[slice..].partition_point(|&i| (i as usize) < first + len);
        blocks.push(KernelBlock {
            first,
            slices: slice..end,
            sh_count: count,
            means: take(&mut means, len),
            amplitudes: take(&mut amplitudes, len),
            velocities: take(&mut velocities, len),
            scales: take(&mut scales, len),
            rotations: take(&mut rotations, len),
            accelerations: take(&mut accelerations, if accelerating { len } else { 0 }),
            angular_velocities: take(&mut angular_velocities, if turning { len } else { 0 }),
            opacities: take(&mut opacities, if alpha { len } else { 0 }),
            sh: take(&mut sh, count * len),
        });
        slice = end;
    }
    blocks
}

impl SliceView<'_> {
    /// Adds slice `s`'s terms to kernel `i`'s gradients.
    fn kernel_backward(&self, s: usize, i: usize, grads: &mut KernelGradients) {
        let (scene, tau, sliced, from_slice) = (self.scene, self.tau, self.sliced, self.from_slice);
        let mut v_m = from_slice.v_means[s];
        let v_a = from_slice.v_amplitudes[s];
        let t = scene.means[i][3];
        let st = scene.scales[i][3];
        let dt = tau - t;
        let d = dt / st;
        let w = (-0.5 * d * d).exp();
        let amplitude = scene.amplitudes[i];
        let velocity = scene.velocities[i];
        // ∂L/∂t and ∂L/∂st through the temporal weight, on a(τ) = A w or on o(τ) = o w
        // (the additive sums keep their order of operations, so their bits).
        let (v_t_weight, v_st_weight) = if let Some(opacity) = grads.opacity.as_deref_mut() {
            let v_opacity = from_slice.v_opacities[s];
            *opacity += w * v_opacity;
            let v_mean_colour = colour_backward(
                scene,
                i,
                self.centre,
                sliced.means[s],
                v_a,
                (grads.amplitude, grads.sh),
            );
            for c in 0..3 {
                v_m[c] += v_mean_colour[c];
            }
            let v_weighted = scene.opacities[i] * w * v_opacity;
            (v_weighted * (d / st), v_weighted * (d * d / st))
        } else {
            for (total, v) in grads.amplitude.iter_mut().zip(v_a) {
                *total += w * v;
            }
            (
                (0..3)
                    .map(|c| amplitude[c] * w * (d / st) * v_a[c])
                    .sum::<f64>(),
                (0..3)
                    .map(|c| amplitude[c] * w * (d * d / st) * v_a[c])
                    .sum::<f64>(),
            )
        };
        let mut v_t = v_t_weight - (0..3).map(|c| velocity[c] * v_m[c]).sum::<f64>();
        if let Some(acceleration) = scene.accelerations.get(i) {
            // m = … + ½ a d_t²: ∂m/∂a = ½ d_t², ∂m/∂t gains -a d_t.
            v_t -= dt * (0..3).map(|c| acceleration[c] * v_m[c]).sum::<f64>();
            if let Some(v_acceleration) = grads.acceleration.as_deref_mut() {
                let half_dt2 = 0.5 * dt * dt;
                for c in 0..3 {
                    v_acceleration[c] += half_dt2 * v_m[c];
                }
            }
        }
        let mean = &mut *grads.mean;
        for c in 0..3 {
            mean[c] += v_m[c];
            grads.velocity[c] += dt * v_m[c];
        }
        // SPEC §9: the axes at τ are those of p = q + ω d_t (normalised); ω = 0 gives q.
        let omega = scene.angular_velocity(i);
        let (turned, r) = if omega == [0.0; 4] {
            (scene.rotations[i], rotation_matrix(scene.rotations[i]))
        } else {
            let q = scene.rotations[i];
            let turned = std::array::from_fn(|k| q[k] + omega[k] * dt);
            let unit = turned_quaternion(q, omega, dt).expect("a sliced kernel's q(τ) is finite");
            (turned, rotation_matrix(unit))
        };
        // Scales: the spatial ones through Σ3, σt through the temporal weight.
        let v_sigma = from_slice.v_covariances[s];
        let scale = scene.scales[i];
        let v_scale = &mut *grads.scale;
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
        v_scale[3] += v_st_weight;
        let v_rotation = rotation_gradient(turned, scale, &r, &v_sigma);
        for (total, v) in grads.rotation.iter_mut().zip(v_rotation) {
            *total += v;
        }
        if omega != [0.0; 4] {
            // ∂p/∂ω = d_t, ∂p/∂t = -ω.
            v_t -= (0..4).map(|k| omega[k] * v_rotation[k]).sum::<f64>();
        }
        if let Some(v_omega) = grads.angular_velocity.as_deref_mut() {
            for k in 0..4 {
                v_omega[k] += dt * v_rotation[k];
            }
        }
        grads.mean[3] += v_t;
    }
}

/// The colour's backward for kernel `i` seen from `centre` at slice centre `mean`: adds
/// `∂L/∂A` and `∂L/∂sh` to the kernel's gradients and returns the part of `∂L/∂m(τ)` that
/// comes through the view direction.
fn colour_backward(
    scene: &Scene,
    i: usize,
    centre: [f64; 3],
    mean: [f64; 3],
    v_colour: [f64; 3],
    (v_amplitude, v_sh): (&mut [f64; 3], &mut [[f64; 3]]),
) -> [f64; 3] {
    let (direction, distance) = view_direction(centre, mean);
    let raw = raw_colour(scene, i, direction);
    let g: [f64; 3] = std::array::from_fn(|c| if raw[c] > 0.0 { v_colour[c] } else { 0.0 });
    for (total, v) in v_amplitude.iter_mut().zip(g) {
        *total += v;
    }
    let count = scene.sh_count;
    if count == 0 || distance == 0.0 {
        return [0.0; 3];
    }
    let basis = sh_basis(direction);
    let basis_gradient = sh_basis_gradient(direction);
    let sh = scene.sh_of(i);
    let mut v_direction = [0.0; 3];
    for j in 0..count {
        let v_sh = &mut v_sh[j];
        let mut along = 0.0;
        for c in 0..3 {
            v_sh[c] += basis[j] * g[c];
            along += sh[j][c] * g[c];
        }
        for k in 0..3 {
            v_direction[k] += along * basis_gradient[j][k];
        }
    }
    // ω = (m - c)/|m - c|:  ∂L/∂m = (I - ω ωᵀ) ∂L/∂ω / |m - c|.
    let radial: f64 = (0..3).map(|k| direction[k] * v_direction[k]).sum();
    std::array::from_fn(|k| (v_direction[k] - direction[k] * radial) / distance)
}

/// `∂L/∂q` of the quaternion `q` (of any length) from `V = ∂L/∂Σ3`, with
/// `Σ3 = R diag(s²) Rᵀ` and `r = R(q̂)`: `∂L/∂R = 2 V R diag(s²)`, then through the entries
/// of `R(q̂)` (SPEC §1) at `q̂ = q/|q|`, and through the normalisation:
/// `∂L/∂q = (I - q̂ q̂ᵀ) ∂L/∂q̂ / |q|` (SPEC §8: the stored quaternion's gradient).
#[must_use]
pub fn rotation_gradient(
    q: [f64; 4],
    scale: [f64; 4],
    r: &[[f64; 3]; 3],
    v_sigma: &[[f64; 3]; 3],
) -> [f64; 4] {
    let var = [
        scale[0] * scale[0],
        scale[1] * scale[1],
        scale[2] * scale[2],
    ];
    let g: [[f64; 3]; 3] = std::array::from_fn(|a| {
        std::array::from_fn(|b| 2.0 * (0..3).map(|k| v_sigma[a][k] * r[k][b]).sum::<f64>() * var[b])
    });
    let norm = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    let unit = q.map(|v| v / norm);
    let [w, x, y, z] = unit;
    let v_unit = [
        2.0 * (-g[0][1] * z + g[0][2] * y + g[1][0] * z - g[1][2] * x - g[2][0] * y + g[2][1] * x),
        2.0 * (g[0][1] * y + g[0][2] * z + g[1][0] * y - 2.0 * g[1][1] * x - g[1][2] * w
            + g[2][0] * z
            + g[2][1] * w
            - 2.0 * g[2][2] * x),
        2.0 * (-2.0 * g[0][0] * y + g[0][1] * x + g[0][2] * w + g[1][0] * x + g[1][2] * z
            - g[2][0] * w
            + g[2][1] * z
            - 2.0 * g[2][2] * y),
        2.0 * (-2.0 * g[0][0] * z - g[0][1] * w + g[0][2] * x + g[1][0] * w - 2.0 * g[1][1] * z
            + g[1][2] * y
            + g[2][0] * x
            + g[2][1] * y),
    ];
    // q̂ = q/|q|: ∂L/∂q = (I - q̂ q̂ᵀ) ∂L/∂q̂ / |q|.
    let radial: f64 = (0..4).map(|k| unit[k] * v_unit[k]).sum();
    std::array::from_fn(|k| (v_unit[k] - unit[k] * radial) / norm)
}
