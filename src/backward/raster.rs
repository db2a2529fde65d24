//! Backward of stage 4 (SPEC §5–6): from `∂L/∂C` per pixel to per projected kernel
//! `∂L/∂a(τ)`, `∂L/∂m2` and `∂L/∂Σ2`.
//!
//! Per pair with `G = exp(-½ q)`, `d = p - m2` and `w = Σ_c ∂L/∂C_c a_c G`:
//!
//! ```text
//! ∂L/∂a_c += ∂L/∂C_c G
//! ∂L/∂q    = -½ w
//! ∂q/∂m2   = -2 Q d                  →  ∂L/∂m2 = Σ w Q d
//! ∂q/∂Q    = d dᵀ, ∂Q = -Q ∂Σ2 Q     →  ∂L/∂Σ2 = ½ Σ w (Q d)(Q d)ᵀ
//! ```
//!
//! `Q d` is formed in the basis of the forward's sum of squares (see [`crate::project`]):
//! with `t = Δu + k Δv`, `Q d = (Qxx t, Qxy t + Δv/Σ2yy)`. For a thin, tilted ellipse `Q` is
//! huge while `t` stays short, so moments of `(t, Δv)` keep their precision where moments of
//! `(Δu, Δv)` would cancel in f32 before being multiplied by `Q`. Each tile accumulates, per
//! (tile, kernel) entry, `Σ ∂L/∂C G` and `Σ w (t, t², Δv, t Δv, Δv²)` (f32, per row first);
//! the pairs walked are the forward's, through the same row spans. The entries are reduced
//! in entry order (tile-major) in f64, so the result does not depend on the thread count.

use rayon::prelude::*;

use crate::project::ProjectedKernels;
use crate::raster::{ExpMode, for_each_row_span, gaussian};
use crate::tiles::TileBins;

/// Per projected kernel: the gradients at the screen-space stage.
#[derive(Clone, Debug, Default)]
pub struct ScreenGradients {
    /// `∂L/∂a(τ)` per channel.
    pub v_amplitudes: Vec<[f64; 3]>,
    /// `∂L/∂m2`, per pixel unit.
    pub v_means: Vec<[f64; 2]>,
    /// `∂L/∂Σ2` as `[xx, xy, yy]` of the full symmetric matrix gradient.
    pub v_covariances: Vec<[f64; 3]>,
}

/// Accumulates `∂L/∂C` (`v_image`, RGB row-major, `width` pixels per row) into `out`, one
/// entry per projected kernel (reset first). `partials` (one per tile entry) and `sums`
/// (one per projected kernel) are scratch, kept between calls.
pub fn rasterize_backward(
    proj: &ProjectedKernels,
    bins: &TileBins,
    v_image: &[f32],
    exp: ExpMode,
    partials: &mut Vec<[f32; 8]>,
    sums: &mut Vec<[f64; 8]>,
    out: &mut ScreenGradients,
) {
    let width = bins.width as usize;
    assert_eq!(
        v_image.len(),
        3 * width * bins.height as usize,
        "∂L/∂C has the image's size"
    );
    partials.clear();
    partials.resize(bins.proj_from_entry.len(), [0.0; 8]);
    // One disjoint run of partials per tile.
    let mut runs = Vec::with_capacity(bins.tile_count());
    let mut rest = partials.as_mut_slice();
    for t in 0..bins.tile_count() {
        let (run, tail) = rest.split_at_mut(bins.tile_entries(t).len());
        runs.push((t, run));
        rest = tail;
    }
    #[cfg(target_arch = "x86_64")]
    let avx2 = is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma");
    runs.into_par_iter().for_each(|(t, run)| {
        #[cfg(target_arch = "x86_64")]
        if avx2 {
            // SAFETY: the CPU has the features the function is compiled for.
            unsafe { backward_tile_avx2(proj, bins, v_image, t, run, exp) };
            return;
        }
        backward_tile_with(proj, bins, v_image, t, run, exp);
    });
    reduce(proj, bins, partials, sums, out);
}

/// [`backward_tile`] compiled for AVX2 and FMA (inline rounding for the row spans, wider
/// registers); the same operations, so the same bits (no fused operations are formed).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn backward_tile_avx2(
    proj: &ProjectedKernels,
    bins: &TileBins,
    v_image: &[f32],
    t: usize,
    run: &mut [[f32; 8]],
    exp: ExpMode,
) {
    backward_tile_with(proj, bins, v_image, t, run, exp);
}

/// [`backward_tile`] for `exp`.
#[inline(always)]
fn backward_tile_with(
    proj: &ProjectedKernels,
    bins: &TileBins,
    v_image: &[f32],
    t: usize,
    run: &mut [[f32; 8]],
    exp: ExpMode,
) {
    match exp {
        ExpMode::Std => backward_tile::<false>(proj, bins, v_image, t, run),
        ExpMode::Poly => backward_tile::<true>(proj, bins, v_image, t, run),
    }
}

/// Accumulates tile `t`'s entries into `run` (one partial per entry).
#[inline(always)]
fn backward_tile<const FAST: bool>(
    proj: &ProjectedKernels,
    bins: &TileBins,
    v_image: &[f32],
    t: usize,
    run: &mut [[f32; 8]],
) {
    let width = bins.width as usize;
    {
        let rect = bins.tile_rect(t);
        for (slot, &p) in run.iter_mut().zip(bins.tile_entries(t)) {
            let mut acc = [0.0_f32; 8];
            for_each_row_span(proj, bins, p as usize, rect, |kernel, row| {
                let mut v_a = [0.0_f32; 3];
                let (mut w0, mut w1, mut w2) = (0.0_f32, 0.0_f32, 0.0_f32);
                let base = 3 * (row.j as usize * width + row.i0 as usize);
                for n in 0..row.i1 - row.i0 {
                    let q = kernel.q(&row, n);
                    if q <= kernel.qmax {
                        let g = gaussian::<FAST>(q);
                        let k = base + 3 * n as usize;
                        let v_c = [v_image[k], v_image[k + 1], v_image[k + 2]];
                        v_a[0] += v_c[0] * g;
                        v_a[1] += v_c[1] * g;
                        v_a[2] += v_c[2] * g;
                        let w = (v_c[0] * kernel.amplitude[0]
                            + v_c[1] * kernel.amplitude[1]
                            + v_c[2] * kernel.amplitude[2])
                            * g;
                        let t = row.t(n);
                        w0 += w;
                        w1 += w * t;
                        w2 += w * t * t;
                    }
                }
                acc[0] += v_a[0];
                acc[1] += v_a[1];
                acc[2] += v_a[2];
                acc[3] += w1;
                acc[4] += w2;
                acc[5] += row.dv * w0;
                acc[6] += row.dv * w1;
                acc[7] += row.dv * row.dv * w0;
            });
            *slot = acc;
        }
    }
}

/// Reduces the per-entry partials into per-kernel gradients, in entry order (tile-major)
/// in f64, so the result does not depend on the thread count.
fn reduce(
    proj: &ProjectedKernels,
    bins: &TileBins,
    partials: &[[f32; 8]],
    sums: &mut Vec<[f64; 8]>,
    out: &mut ScreenGradients,
) {
    sums.clear();
    sums.resize(proj.len(), [0.0; 8]);
    for (partial, &p) in partials.iter().zip(&bins.proj_from_entry) {
        for (s, v) in sums[p as usize].iter_mut().zip(partial) {
            *s += f64::from(*v);
        }
    }
    out.v_amplitudes.clear();
    out.v_means.clear();
    out.v_covariances.clear();
    for (p, s) in sums.iter().enumerate() {
        let [a, b, _] = proj.conics[p];
        let e = 1.0 / proj.covariances[p][2];
        let [s_t, s_tt, s_v, s_tv, s_vv] = [s[3], s[4], s[5], s[6], s[7]];
        out.v_amplitudes.push([s[0], s[1], s[2]]);
        // Σ w Q d with Q d = (a t, b t + e Δv).
        out.v_means.push([a * s_t, b * s_t + e * s_v]);
        // ½ Σ w (Q d)(Q d)ᵀ.
        out.v_covariances.push([
            0.5 * a * a * s_tt,
            0.5 * a * (b * s_tt + e * s_tv),
            0.5 * (b * b * s_tt + 2.0 * b * e * s_tv + e * e * s_vv),
        ]);
    }
}
