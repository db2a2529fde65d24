//! f64 twin of [`crate::colour`] (SPEC §8): each kernel of an alpha scene sliced, projected,
//! coloured by its SH at the view direction and put in depth order, written as the SPEC
//! states it.
//!
//! ```text
//! ω = (m(τ) - c)/|m(τ) - c|,  c = -Rc⁻¹ tc          colour = max(0, A + Σ_j Y_j(ω) sh_j)
//! order: camera-space z of m(τ), nearest first, ties by kernel index
//! ```

use glam::{DMat3, DVec3};

use crate::model::{Camera, Scene};
use crate::reference::project::ReferenceKernel;
use crate::reference::reference_kernels;
use crate::render::RenderOptions;

/// A kernel of an alpha scene after slicing, projection and colour.
#[derive(Clone, Copy, Debug)]
pub struct AlphaKernel {
    /// Slice and projection (its `opacity` is `o(τ)`).
    pub kernel: ReferenceKernel,
    /// `A + Σ Y sh` before the clamp.
    pub raw_colour: [f64; 3],
    /// `max(0, raw_colour)`.
    pub colour: [f64; 3],
    /// Camera-space depth of `m(τ)`.
    pub depth: f64,
}

/// Real spherical harmonics of degree 1–3 at unit `d`, in the order and with the signs of
/// SPEC §8, written out degree by degree.
#[must_use]
pub fn reference_sh_basis(d: DVec3) -> Vec<f64> {
    let (x, y, z) = (d.x, d.y, d.z);
    let c1 = 0.488_602_511_902_919_9;
    let c2 = [
        1.092_548_430_592_079_2,
        -1.092_548_430_592_079_2,
        0.315_391_565_252_520_05,
        -1.092_548_430_592_079_2,
        0.546_274_215_296_039_6,
    ];
    let c3 = [
        -0.590_043_589_926_643_5,
        2.890_611_442_640_554,
        -0.457_045_799_464_465_8,
        0.373_176_332_590_115_4,
        -0.457_045_799_464_465_8,
        1.445_305_721_320_277,
        -0.590_043_589_926_643_5,
    ];
    let degree1 = [-c1 * y, c1 * z, -c1 * x];
    let degree2 = [
        c2[0] * x * y,
        c2[1] * y * z,
        c2[2] * (2.0 * z * z - x * x - y * y),
        c2[3] * x * z,
        c2[4] * (x * x - y * y),
    ];
    let degree3 = [
        c3[0] * y * (3.0 * x * x - y * y),
        c3[1] * x * y * z,
        c3[2] * y * (4.0 * z * z - x * x - y * y),
        c3[3] * z * (2.0 * z * z - 3.0 * x * x - 3.0 * y * y),
        c3[4] * x * (4.0 * z * z - x * x - y * y),
        c3[5] * z * (x * x - y * y),
        c3[6] * x * (x * x - 3.0 * y * y),
    ];
    degree1.into_iter().chain(degree2).chain(degree3).collect()
}

/// The camera centre `c = -Rc⁻¹ tc`.
#[must_use]
pub fn reference_camera_centre(camera: &Camera) -> DVec3 {
    let rc = DMat3::from_cols_array_2d(&camera.rotation()).transpose();
    -(rc.inverse() * DVec3::from(camera.translation()))
}

/// Every kernel of the alpha scene alive at τ and on screen, with its colour, in
/// compositing order (depth, then kernel index).
#[must_use]
pub fn reference_alpha_kernels(
    scene: &Scene,
    camera: &Camera,
    tau: f64,
    options: &RenderOptions,
) -> Vec<AlphaKernel> {
    let centre = reference_camera_centre(camera);
    let rc = DMat3::from_cols_array_2d(&camera.rotation()).transpose();
    let mut kernels: Vec<AlphaKernel> = reference_kernels(scene, camera, tau, options)
        .into_iter()
        .map(|kernel| {
            let i = kernel.index;
            let mean = super::slice::reference_mean(scene, i, tau);
            let offset = mean - centre;
            let direction = if offset.length() > 0.0 {
                offset / offset.length()
            } else {
                DVec3::ZERO
            };
            let basis = reference_sh_basis(direction);
            let mut raw_colour = scene.amplitudes[i];
            for (j, triplet) in scene.sh_of(i).iter().enumerate() {
                for c in 0..3 {
                    raw_colour[c] += basis[j] * triplet[c];
                }
            }
            AlphaKernel {
                kernel,
                raw_colour,
                colour: raw_colour.map(|c| c.max(0.0)),
                depth: (rc * mean + DVec3::from(camera.translation())).z,
            }
        })
        .collect();
    kernels.sort_by(|a, b| {
        a.depth
            .total_cmp(&b.depth)
            .then(a.kernel.index.cmp(&b.kernel.index))
    });
    kernels
}
