//! Alpha scenes, per kernel: the view-dependent colour (SPEC §8) and the depth order.
//!
//! **Colour.** With the camera centre `c = -Rc⁻¹ tc` and the unit view direction
//! `ω = (m(τ) - c)/|m(τ) - c| = (x, y, z)` in world space, per channel
//!
//! ```text
//! colour = max(0, A + Σ_j Y_j(ω) sh_j)
//! ```
//!
//! with the real spherical harmonics `Y_j` of degree 1–3 in graphdeco's order and signs
//! ([`sh_basis`]). Evaluated once per kernel and frame in f64, then handed to the raster as
//! three f32 numbers, as the additive raster gets its amplitude.
//!
//! **Order.** Kernels are composited nearest first by the camera-space depth `z` of `m(τ)`
//! (f64, the `z` of SPEC §4), equal depths in kernel order: a sort of `(z, kernel)` pairs,
//! a total order, so the result does not depend on the thread count. The projected kernels
//! are permuted into that order before binning, so every tile's list comes out front to
//! back with no per-tile sort.

use rayon::prelude::*;

use crate::model::camera::Camera;
use crate::model::scene::Scene;
use crate::project::ProjectedKernels;
use crate::slice::SlicedKernels;

/// `C1` of SPEC §8.
pub const SH_C1: f64 = 0.488_602_511_902_919_9;
/// `C2` of SPEC §8.
pub const SH_C2: [f64; 5] = [
    1.092_548_430_592_079_2,
    -1.092_548_430_592_079_2,
    0.315_391_565_252_520_05,
    -1.092_548_430_592_079_2,
    0.546_274_215_296_039_6,
];
/// `C3` of SPEC §8.
pub const SH_C3: [f64; 7] = [
    -0.590_043_589_926_643_5,
    2.890_611_442_640_554,
    -0.457_045_799_464_465_8,
    0.373_176_332_590_115_4,
    -0.457_045_799_464_465_8,
    1.445_305_721_320_277,
    -0.590_043_589_926_643_5,
];

/// The 15 basis values `Y_1 … Y_15` at the unit direction `(x, y, z)` (SPEC §8); the first
/// `sh_count` are used.
#[must_use]
pub fn sh_basis([x, y, z]: [f64; 3]) -> [f64; 15] {
    let (xx, yy, zz) = (x * x, y * y, z * z);
    [
        -SH_C1 * y,
        SH_C1 * z,
        -SH_C1 * x,
        SH_C2[0] * x * y,
        SH_C2[1] * y * z,
        SH_C2[2] * (2.0 * zz - xx - yy),
        SH_C2[3] * x * z,
        SH_C2[4] * (xx - yy),
        SH_C3[0] * y * (3.0 * xx - yy),
        SH_C3[1] * x * y * z,
        SH_C3[2] * y * (4.0 * zz - xx - yy),
        SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
        SH_C3[4] * x * (4.0 * zz - xx - yy),
        SH_C3[5] * z * (xx - yy),
        SH_C3[6] * x * (xx - 3.0 * yy),
    ]
}

/// `∂Y_j/∂(x, y, z)` of the 15 basis polynomials of [`sh_basis`] (as functions of three
/// free coordinates; the direction's normalisation is applied by the caller).
#[must_use]
pub fn sh_basis_gradient([x, y, z]: [f64; 3]) -> [[f64; 3]; 15] {
    let (c1, c2, c3) = (SH_C1, SH_C2, SH_C3);
    let (xx, yy, zz) = (x * x, y * y, z * z);
    [
        [0.0, -c1, 0.0],
        [0.0, 0.0, c1],
        [-c1, 0.0, 0.0],
        [c2[0] * y, c2[0] * x, 0.0],
        [0.0, c2[1] * z, c2[1] * y],
        [-2.0 * c2[2] * x, -2.0 * c2[2] * y, 4.0 * c2[2] * z],
        [c2[3] * z, 0.0, c2[3] * x],
        [2.0 * c2[4] * x, -2.0 * c2[4] * y, 0.0],
        [6.0 * c3[0] * x * y, c3[0] * (3.0 * xx - 3.0 * yy), 0.0],
        [c3[1] * y * z, c3[1] * x * z, c3[1] * x * y],
        [
            -2.0 * c3[2] * x * y,
            c3[2] * (4.0 * zz - xx - 3.0 * yy),
            8.0 * c3[2] * y * z,
        ],
        [
            -6.0 * c3[3] * x * z,
            -6.0 * c3[3] * y * z,
            c3[3] * (6.0 * zz - 3.0 * xx - 3.0 * yy),
        ],
        [
            c3[4] * (4.0 * zz - 3.0 * xx - yy),
            -2.0 * c3[4] * x * y,
            8.0 * c3[4] * x * z,
        ],
        [2.0 * c3[5] * x * z, -2.0 * c3[5] * y * z, c3[5] * (xx - yy)],
        [c3[6] * (3.0 * xx - 3.0 * yy), -6.0 * c3[6] * x * y, 0.0],
    ]
}

/// The camera centre `c = -Rc⁻¹ tc` in world space (`Rc` need not be orthonormal).
#[must_use]
pub fn camera_centre(camera: &Camera) -> [f64; 3] {
    let r = camera.rotation();
    let t = camera.translation();
    // Rc⁻¹ by the adjugate: (Rc⁻¹)_ij = cofactor_ji / det.
    let cof = |i: usize, j: usize| {
        let (a, b) = ((i + 1) % 3, (i + 2) % 3);
        let (c, d) = ((j + 1) % 3, (j + 2) % 3);
        r[a][c] * r[b][d] - r[a][d] * r[b][c]
    };
    let det: f64 = (0..3).map(|j| r[0][j] * cof(0, j)).sum();
    std::array::from_fn(|i| -(0..3).map(|j| cof(j, i) * t[j]).sum::<f64>() / det)
}

/// The unit direction from `centre` to `mean`, and the distance (zero when they coincide:
/// the direction is then `(0, 0, 0)` and only the amplitude counts).
#[must_use]
pub fn view_direction(centre: [f64; 3], mean: [f64; 3]) -> ([f64; 3], f64) {
    let d: [f64; 3] = std::array::from_fn(|k| mean[k] - centre[k]);
    let length = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    if length > 0.0 {
        (d.map(|v| v / length), length)
    } else {
        ([0.0; 3], 0.0)
    }
}

/// The colour of kernel `i` seen along `direction`, before the clamp at zero:
/// `A + Σ_j Y_j sh_j`.
#[must_use]
pub fn raw_colour(scene: &Scene, i: usize, direction: [f64; 3]) -> [f64; 3] {
    let mut colour = scene.amplitudes[i];
    let sh = scene.sh_of(i);
    if !sh.is_empty() {
        let basis = sh_basis(direction);
        for (y, triplet) in basis.iter().zip(sh) {
            for c in 0..3 {
                colour[c] += y * triplet[c];
            }
        }
    }
    colour
}

/// Writes each projected kernel's clamped colour `max(0, A + Σ Y sh)` (f32) into
/// `proj.amplitudes` and its opacity at τ into `proj.opacities` (alpha scenes).
pub fn shade(scene: &Scene, sliced: &SlicedKernels, camera: &Camera, proj: &mut ProjectedKernels) {
    let centre = camera_centre(camera);
    let n = proj.len();
    let slice_from_proj = &proj.slice_from_proj;
    crate::parallel::fill_in_parallel(&mut proj.amplitudes, n, |p| {
        let s = slice_from_proj[p] as usize;
        let i = sliced.kernel_from_slice[s] as usize;
        let (direction, _) = view_direction(centre, sliced.means[s]);
        raw_colour(scene, i, direction).map(|c| c.max(0.0) as f32)
    });
    crate::parallel::fill_in_parallel(&mut proj.opacities, n, |p| {
        sliced.opacities[slice_from_proj[p] as usize]
    });
}

/// The camera-space depth `z` of a world point (the expression of [`crate::project`]).
#[inline]
#[must_use]
pub fn depth(camera: &Camera, mean: [f64; 3]) -> f64 {
    let rc = camera.rotation();
    let tc = camera.translation();
    rc[2][0] * mean[0] + rc[2][1] * mean[1] + rc[2][2] * mean[2] + tc[2]
}

/// Permutes `proj` into depth order, nearest first, equal depths in kernel order; `keys`
/// is scratch.
pub fn order_by_depth(
    sliced: &SlicedKernels,
    camera: &Camera,
    proj: &mut ProjectedKernels,
    keys: &mut Vec<(f64, u32, u32)>,
) {
    keys.clear();
    keys.par_extend((0..proj.len()).into_par_iter().map(|p| {
        let s = proj.slice_from_proj[p] as usize;
        (
            depth(camera, sliced.means[s]),
            proj.kernel_from_proj[p],
            p as u32,
        )
    }));
    keys.par_sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    let order: Vec<u32> = keys.iter().map(|&(_, _, p)| p).collect();
    proj.permute(&order);
}
