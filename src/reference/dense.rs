//! The seed-style dense evaluation, a baseline for the tile renderer's speed: every projected
//! kernel at every pixel, as the paper's PyTorch code evaluates a `[pixels × kernels]`
//! tensor (SPEC §5, Eq. 2, with the same indicator).
//!
//! ```text
//! C(p, τ) = b + Σ_i [q_i(p) ≤ qmax_i] a_i(τ) exp(-½ q_i(p)),   q = Qxx Δu² + 2 Qxy Δu Δv + Qyy Δv²
//! ```
//!
//! Slice and projection are the renderer's own (f64, per kernel; they are not what costs).
//! The per-pair work is f32 throughout, like a GPU tensor program: q in the plain quadratic
//! form, the inlined polynomial exp ([`crate::simd::fast_exp_neg_half`]) so the loop over
//! a row of pixels vectorises, and f32 sums. Rows run in parallel; each row adds the kernels
//! in scene order, so the image does not depend on the thread count. It is a baseline, not a
//! reference: its error against the f64 reference is measured beside its time.

use rayon::prelude::*;

use crate::model::camera::Camera;
use crate::model::error::Result;
use crate::model::scene::Scene;
use crate::project::{ProjectedKernels, project};
use crate::render::RenderOptions;
use crate::slice::{SlicedKernels, slice};
use crate::{model::Image, simd::fast_exp_neg_half};

/// Renders `scene` at `tau` through `camera` by evaluating every projected kernel at every
/// pixel. Returns the image and the number of (pixel, kernel) pairs evaluated.
pub fn dense_render(
    scene: &Scene,
    camera: &Camera,
    tau: f64,
    options: &RenderOptions,
) -> Result<(Image, u64)> {
    options.validate()?;
    let mut sliced = SlicedKernels::default();
    let mut proj = ProjectedKernels::default();
    slice(scene, tau, options.cutoff, &mut sliced);
    project(&sliced, camera, options.dilation, &mut proj);
    let (width, height) = (camera.width as usize, camera.height as usize);
    let mut image = Image::filled(
        camera.width,
        camera.height,
        scene.background.map(|b| b as f32),
    );
    image
        .pixels
        .par_chunks_mut(3 * width)
        .enumerate()
        .for_each(|(j, row)| dense_row(&proj, j, row));
    Ok((image, (proj.len() * width * height) as u64))
}

/// Adds every kernel of `proj` to pixel row `j` (`row`: RGB interleaved, over the
/// background), with AVX2 and FMA when the CPU has them (chosen at run time).
fn dense_row(proj: &ProjectedKernels, j: usize, row: &mut [f32]) {
    #[cfg(target_arch = "x86_64")]
    if is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma") {
        // SAFETY: the CPU supports the features `dense_row_avx2` is compiled for.
        unsafe { dense_row_avx2(proj, j, row) };
        return;
    }
    dense_row_portable(proj, j, row);
}

/// [`dense_row_portable`] compiled for AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn dense_row_avx2(proj: &ProjectedKernels, j: usize, row: &mut [f32]) {
    dense_row_portable(proj, j, row);
}

/// The row loop; the pixel loop is branch-free so that it vectorises.
#[inline(always)]
fn dense_row_portable(proj: &ProjectedKernels, j: usize, row: &mut [f32]) {
    let width = row.len() / 3;
    let mut planes = vec![0.0_f32; 3 * width];
    let (red, rest) = planes.split_at_mut(width);
    let (green, blue) = rest.split_at_mut(width);
    let v = j as f32 + 0.5;
    let centres: Vec<f32> = (0..width).map(|i| i as f32 + 0.5).collect();
    for p in 0..proj.len() {
        let [mx, my] = proj.means[p].map(|m| m as f32);
        let [a, b, c] = proj.conics[p].map(|x| x as f32);
        let qmax = proj.qmax[p] as f32;
        let [ar, ag, ab] = proj.amplitudes[p];
        let dv = v - my;
        let row_q = c * dv * dv;
        let cross = 2.0 * b * dv;
        for (((r, g), bl), &x) in red
            .iter_mut()
            .zip(green.iter_mut())
            .zip(blue.iter_mut())
            .zip(&centres)
        {
            let du = x - mx;
            let q = a * du * du + cross * du + row_q;
            let gauss = fast_exp_neg_half(q);
            let w = if q <= qmax { gauss } else { 0.0 };
            *r += ar * w;
            *g += ag * w;
            *bl += ab * w;
        }
    }
    for (i, px) in row.chunks_exact_mut(3).enumerate() {
        px[0] += red[i];
        px[1] += green[i];
        px[2] += blue[i];
    }
}
