//! Stage 2: EWA projection of each sliced 3D Gaussian to a screen-space ellipse (SPEC §4).
//!
//! Camera space has OpenCV axes; screen space is pixels with centres at `i + 0.5`.
//!
//! ```text
//! (x, y, z) = Rc m + tc                      culled unless near ≤ z ≤ far
//! Σc   = Rc Σ3 Rcᵀ
//! lim_x⁺ = (W - cx)/fx + 0.15 W/fx           lim_x⁻ = cx/fx + 0.15 W/fx   (y likewise, H, fy)
//! tx   = z clamp(x/z, -lim_x⁻, lim_x⁺)       ty = z clamp(y/z, -lim_y⁻, lim_y⁺)
//! J    = [[fx/z, 0, -fx tx/z²], [0, fy/z, -fy ty/z²]]
//! Σ2   = J Σc Jᵀ + s I                       s: dilation, px²
//! m2   = (fx x/z + cx, fy y/z + cy)          unclamped
//! Q    = Σ2⁻¹                                culled unless det Σ2 is finite and > 0 and Q finite
//! ```
//!
//! The exact axis-aligned bound of the ellipse `q ≤ qmax` is `|Δu| ≤ √(qmax Σ2xx)`,
//! `|Δv| ≤ √(qmax Σ2yy)` (SPEC §5). For the per-pixel loop the quadratic form is also
//! written as a sum of two squares, `q = Qxx (Δu + k Δv)² + Δv²/Σ2yy` with
//! `k = -Σ2xy/Σ2yy`: no cancellation however thin the ellipse, and each row's span of
//! pixels inside the ellipse follows from one square root. Everything here is f64.

use crate::model::camera::Camera;
use rayon::prelude::*;

use crate::model::scene::{Blend, Scene};
use crate::parallel::{fill_in_parallel, gather_kept, keep_and_tally_in_parallel, keep_chunks};
use crate::slice::{SlicedKernel, SlicedKernels, slice_one};

/// Screen-space ellipses of the kernels that survive projection. Struct-of-arrays, index
/// `p` of every array is one projected kernel, in ascending scene order.
///
/// SPEC §4 (EWA projection) and §5 (the cut-off's `qmax`).
#[derive(Clone, Debug, Default)]
pub struct ProjectedKernels {
    /// Index into the [`SlicedKernels`] it came from; empty after [`slice_and_project`]
    /// (an additive frame no backward reads), which keeps no slices.
    pub slice_from_proj: Vec<u32>,
    /// Scene index, ascending.
    pub kernel_from_proj: Vec<u32>,
    /// 2D centre `m2`, pixels.
    pub means: Vec<[f64; 2]>,
    /// Screen covariance `Σ2` as `[xx, xy, yy]`, px².
    pub covariances: Vec<[f64; 3]>,
    /// Conic `Q = Σ2⁻¹` as `[xx, xy, yy]`, 1/px².
    pub conics: Vec<[f64; 3]>,
    /// Cut-off `qmax` (from the slice stage).
    pub qmax: Vec<f64>,
    /// Half extents `[√(qmax Σ2xx), √(qmax Σ2yy)]` of the ellipse `q ≤ qmax`, pixels.
    pub radii: Vec<[f64; 2]>,
    /// Sliced amplitude `a(τ)`, f32 for the per-pixel loop; alpha scenes: the colour
    /// ([`crate::colour::shade`]).
    pub amplitudes: Vec<[f32; 3]>,
    /// Alpha scenes: the opacity at τ, `o(τ)` ([`crate::colour::shade`]; empty otherwise).
    pub opacities: Vec<f64>,
}

impl ProjectedKernels {
    /// Number of projected kernels.
    #[must_use]
    pub fn len(&self) -> usize {
        self.kernel_from_proj.len()
    }

    /// True when nothing is on screen.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.kernel_from_proj.is_empty()
    }

    /// Empties every buffer, keeping its capacity.
    pub fn reset(&mut self) {
        self.slice_from_proj.clear();
        self.kernel_from_proj.clear();
        self.means.clear();
        self.covariances.clear();
        self.conics.clear();
        self.qmax.clear();
        self.radii.clear();
        self.amplitudes.clear();
        self.opacities.clear();
    }

    /// Reorders every array so that entry `k` becomes the old entry `order[k]` (a
    /// permutation of `0..len`).
    pub fn permute(&mut self, order: &[u32]) {
        fn apply<T: Copy + Send + Sync>(values: &mut Vec<T>, order: &[u32]) {
            if values.is_empty() {
                return;
            }
            let mut permuted = Vec::new();
            fill_in_parallel(&mut permuted, order.len(), |k| values[order[k] as usize]);
            *values = permuted;
        }
        assert_eq!(
            order.len(),
            self.len(),
            "a permutation of the projected kernels"
        );
        apply(&mut self.slice_from_proj, order);
        apply(&mut self.kernel_from_proj, order);
        apply(&mut self.means, order);
        apply(&mut self.covariances, order);
        apply(&mut self.conics, order);
        apply(&mut self.qmax, order);
        apply(&mut self.radii, order);
        apply(&mut self.amplitudes, order);
        apply(&mut self.opacities, order);
    }
}

/// One kernel's projection: everything the later stages (and the backward pass) need.
///
/// SPEC §4: the 2D mean, the screen covariance with the dilation added, its conic.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Projection {
    /// Camera-space centre `(x, y, z)`.
    pub camera_mean: [f64; 3],
    /// `(tx, ty)` of the clamped Jacobian.
    pub clamped_xy: [f64; 2],
    /// Which of `tx`, `ty` hit a clamp limit (x/z strictly outside its limits).
    pub clamped: [bool; 2],
    /// The Jacobian `J` (2×3, row-major).
    pub jacobian: [[f64; 3]; 2],
    /// Camera-space covariance `Σc` (3×3).
    pub camera_covariance: [[f64; 3]; 3],
    /// `Σ2` as `[xx, xy, yy]`.
    pub covariance: [f64; 3],
    /// `Q = Σ2⁻¹` as `[xx, xy, yy]`.
    pub conic: [f64; 3],
    /// `m2`, pixels.
    pub mean: [f64; 2],
}

/// Projects one 3D Gaussian (world-space centre and covariance `[xx, xy, xz, yy, yz, zz]`),
/// or `None` when it is culled (outside `[near, far]`, degenerate or non-finite `Σ2`).
#[must_use]
pub fn project_one(
    camera: &Camera,
    dilation: f64,
    mean: [f64; 3],
    cov: [f64; 6],
) -> Option<Projection> {
    projection(camera, dilation, mean, cov)
}

/// [`project_one`], inlined where it is called, so that a caller which reads a few fields
/// (the forward's [`project`]: `m2`, `Σ2`, `Q`) has the rest, the Jacobian and `Σc`, left
/// out by the compiler, and its result does not go through memory: the 10k-kernel 512×512
/// projection took 0.80 ms on one thread as a call from [`project`]'s pass, 0.39–0.44 ms
/// inlined. The same operations in the same order, so the same bits. The backward's
/// projection pass, which reads the Jacobian, calls [`project_one`] (inlined there, a
/// training step measured slower).
#[inline(always)]
fn projection(camera: &Camera, dilation: f64, mean: [f64; 3], cov: [f64; 6]) -> Option<Projection> {
    let rc = camera.rotation();
    let tc = camera.translation();
    let p: [f64; 3] = std::array::from_fn(|r| {
        rc[r][0] * mean[0] + rc[r][1] * mean[1] + rc[r][2] * mean[2] + tc[r]
    });
    let [x, y, z] = p;
    if !(z >= camera.near && z <= camera.far) {
        return None;
    }
    let sigma = [
        [cov[0], cov[1], cov[2]],
        [cov[1], cov[3], cov[4]],
        [cov[2], cov[4], cov[5]],
    ];
    // Σc = Rc Σ3 Rcᵀ
    let rs: [[f64; 3]; 3] = std::array::from_fn(|i| {
        std::array::from_fn(|j| (0..3).map(|k| rc[i][k] * sigma[k][j]).sum())
    });
    let sc: [[f64; 3]; 3] =
        std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| rs[i][k] * rc[j][k]).sum()));
    let [lxm, lxp, lym, lyp] = camera.clamp_limits();
    let (u, v) = (x / z, y / z);
    let clamped = [u < -lxm || u > lxp, v < -lym || v > lyp];
    let tx = z * u.clamp(-lxm, lxp);
    let ty = z * v.clamp(-lym, lyp);
    let (fx, fy) = (camera.fx, camera.fy);
    let jac = [
        [fx / z, 0.0, -fx * tx / (z * z)],
        [0.0, fy / z, -fy * ty / (z * z)],
    ];
    // Σ2 = J Σc Jᵀ + s I
    let js: [[f64; 3]; 2] = std::array::from_fn(|i| {
        std::array::from_fn(|j| (0..3).map(|k| jac[i][k] * sc[k][j]).sum())
    });
    let s2 = |i: usize, j: usize| (0..3).map(|k| js[i][k] * jac[j][k]).sum::<f64>();
    let covariance = [s2(0, 0) + dilation, s2(0, 1), s2(1, 1) + dilation];
    let det = covariance[0] * covariance[2] - covariance[1] * covariance[1];
    if !(det.is_finite() && det > 0.0) {
        return None;
    }
    let conic = [
        covariance[2] / det,
        -covariance[1] / det,
        covariance[0] / det,
    ];
    if !conic.iter().all(|c| c.is_finite()) {
        return None;
    }
    Some(Projection {
        camera_mean: p,
        clamped_xy: [tx, ty],
        clamped,
        jacobian: jac,
        camera_covariance: sc,
        covariance,
        conic,
        mean: [fx * x / z + camera.cx, fy * y / z + camera.cy],
    })
}

/// Projects every sliced kernel into `out` (reset first). `dilation` is `s` of SPEC §4, px².
/// The kernels are projected in parallel and the ones on screen kept in ascending order
/// (the result does not depend on the thread count).
pub fn project(sliced: &SlicedKernels, camera: &Camera, dilation: f64, out: &mut ProjectedKernels) {
    let slice = |s: usize, _: &mut usize| {
        let kernel = SlicedKernel {
            mean: sliced.means[s],
            covariance: sliced.covariances[s],
            amplitude: sliced.amplitudes[s],
            // Not read by the projection (alpha scenes' opacities are shaded after it).
            opacity: 0.0,
            qmax: sliced.qmax[s],
        };
        Some((sliced.kernel_from_slice[s], kernel))
    };
    projection_pass(sliced.len(), slice, true, (camera, dilation), out);
}

/// The half extents `[√(qmax Σ2xx), √(qmax Σ2yy)]` of the ellipse `q ≤ qmax` of `Σ2`.
#[inline(always)]
fn radii_of(qmax: f64, covariance: [f64; 3]) -> [f64; 2] {
    [(qmax * covariance[0]).sqrt(), (qmax * covariance[2]).sqrt()]
}

/// Stages 1 and 2 in one pass for an additive frame that no backward reads (SPEC §2, §4):
/// each kernel of `scene` is sliced at `tau` ([`crate::slice::slice`]'s per-kernel step)
/// and projected at once, and only the projections are written; the slices' arrays (108
/// bytes a kernel, which [`project`] reads back) are never made. `out` is what
/// [`crate::slice::slice`] then [`project`] give, bit for bit (the same steps on the same
/// f64 values), except `slice_from_proj`, which only a backward reads, left empty. Returns
/// the number of kernels alive at `tau` (the slice's length).
///
/// # Panics
/// When `scene` is an alpha scene (its colours and depth order read the slices).
pub fn slice_and_project(
    scene: &Scene,
    (tau, cutoff): (f64, f64),
    camera: &Camera,
    dilation: f64,
    out: &mut ProjectedKernels,
) -> usize {
    slice_and_project_visiting(
        scene,
        scene.len(),
        |k| k,
        (tau, cutoff),
        camera,
        dilation,
        out,
    )
}

/// [`slice_and_project`] of the kernels `candidates` lists (ascending scene indices, a
/// superset of the kernels alive at `tau`, as [`crate::slice::TemporalIndex::candidates`]
/// gives): the same output.
///
/// # Panics
/// When `scene` is an alpha scene.
pub fn slice_candidates_and_project(
    scene: &Scene,
    candidates: &[u32],
    (tau, cutoff): (f64, f64),
    camera: &Camera,
    dilation: f64,
    out: &mut ProjectedKernels,
) -> usize {
    let kernel = |k: usize| candidates[k] as usize;
    slice_and_project_visiting(
        scene,
        candidates.len(),
        kernel,
        (tau, cutoff),
        camera,
        dilation,
        out,
    )
}

/// [`slice_and_project`] of kernels `kernel(0..count)` (ascending), in parallel, keeping the
/// projections in that order: the output does not depend on the thread count.
fn slice_and_project_visiting(
    scene: &Scene,
    count: usize,
    kernel: impl Fn(usize) -> usize + Sync,
    (tau, cutoff): (f64, f64),
    camera: &Camera,
    dilation: f64,
    out: &mut ProjectedKernels,
) -> usize {
    assert_eq!(
        scene.blend,
        Blend::Additive,
        "slice_and_project: an additive scene"
    );
    let slice = |k: usize, alive: &mut usize| {
        let i = kernel(k);
        let sliced = slice_one(scene, i, tau, cutoff)?;
        *alive += 1;
        debug_assert!(u32::try_from(i).is_ok(), "scene indices fit in u32");
        Some((i as u32, sliced))
    };
    projection_pass(count, slice, false, (camera, dilation), out)
}

/// The projection's one pass over `count` indices, into `out` (reset first):
/// `slice(k, alive)` gives index `k`'s kernel (its scene index and its slice, counting it on
/// `alive` if it likes) or `None`, and each kernel on screen has every array of `out` written
/// but the opacities (alpha scenes: [`crate::colour::shade`]), `slice_from_proj` (as `k`) only
/// with `slice_indices`. The chunks of indices run in parallel, each writing what it keeps at
/// the start of its own stretch of every array, gathered after: the output does not depend
/// on the thread count. Returns the sum of the `alive` counts.
fn projection_pass(
    count: usize,
    slice: impl Fn(usize, &mut usize) -> Option<(u32, SlicedKernel)> + Sync,
    slice_indices: bool,
    (camera, dilation): (&Camera, f64),
    out: &mut ProjectedKernels,
) -> usize {
    out.reset();
    let chunks = keep_chunks(&mut out.slice_from_proj, count)
        .zip(keep_chunks(&mut out.kernel_from_proj, count))
        .zip(keep_chunks(&mut out.means, count))
        .zip(keep_chunks(&mut out.covariances, count))
        .zip(keep_chunks(&mut out.conics, count))
        .zip(keep_chunks(&mut out.qmax, count))
        .zip(keep_chunks(&mut out.radii, count))
        .zip(keep_chunks(&mut out.amplitudes, count));
    let (kept, alive) = keep_and_tally_in_parallel(
        count,
        chunks,
        |k, alive| {
            let (i, sliced) = slice(k, alive)?;
            let on_screen = projection(camera, dilation, sliced.mean, sliced.covariance)?;
            Some((i, sliced, on_screen))
        },
        |columns, at, k, (i, sliced, on_screen)| {
            let (((((((slices, kernels), means), covariances), conics), qmax), radii), amplitudes) =
                columns;
            if slice_indices {
                debug_assert!(u32::try_from(k).is_ok(), "slice indices fit in u32");
                slices[at].write(k as u32);
            }
            kernels[at].write(i);
            means[at].write(on_screen.mean);
            covariances[at].write(on_screen.covariance);
            conics[at].write(on_screen.conic);
            qmax[at].write(sliced.qmax);
            radii[at].write(radii_of(sliced.qmax, on_screen.covariance));
            amplitudes[at].write(sliced.amplitude.map(|a| a as f32));
        },
    );
    // SAFETY: each array is a column of the pass, whose chunks wrote their kept projections
    // (`slice_from_proj` only with `slice_indices`; otherwise it stays empty).
    unsafe {
        if slice_indices {
            gather_kept(&mut out.slice_from_proj, &kept);
        }
        gather_kept(&mut out.kernel_from_proj, &kept);
        gather_kept(&mut out.means, &kept);
        gather_kept(&mut out.covariances, &kept);
        gather_kept(&mut out.conics, &kept);
        gather_kept(&mut out.qmax, &kept);
        gather_kept(&mut out.radii, &kept);
        gather_kept(&mut out.amplitudes, &kept);
    }
    alive
}
