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
//! `(Δu, Δv)` would cancel in f32 before being multiplied by `Q`. Each tile walks the
//! forward's per-half-row entries ([`crate::raster`]: the same pairs, the same `t` and `q`)
//! and accumulates, per kernel, `Σ ∂L/∂C G` and `Σ w (t, t², Δv, t Δv, Δv²)` pixel column by
//! pixel column over the tile's rows (f32, at most 16 terms a column), then over the 16
//! columns in f64, into one partial per (tile, kernel) entry. The AVX-512 path takes the
//! forward's whole-row tile set-up (16 lanes a row, `raster::avx512::prepare_tile`) and walks
//! each kernel's own rows with its moments in registers: a column adds the same terms in the
//! same order (one per row, rows ascending), and the lanes of a half the kernel does not
//! reach add exact zeros. The entries are reduced in entry order (tile-major) in
//! f64: no atomics, and the result does not depend on the thread count or the SIMD path (the
//! AVX2 loop performs the portable loop's operations in the same order).

use rayon::prelude::*;

use crate::project::ProjectedKernels;
use crate::raster::{
    ExpMode, HalfRow, LANES, ROW, RowEntry, RowForm, SimdPath, TileKernel, TileScratch, half_rows,
    prepare_tile, read_planes,
};
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
    /// Alpha frames: `∂L/∂o(τ)` (empty for additive frames).
    pub v_opacities: Vec<f64>,
}

/// Accumulates `∂L/∂C` (`v_image`, RGB row-major, `width` pixels per row) into `out`, one
/// entry per projected kernel (reset first). `forms` are the row forms of the forward render
/// of the same frame ([`crate::raster::row_forms`]); `partials` (one per tile entry) and
/// `sums` (one per projected kernel) are scratch, kept between calls.
#[allow(clippy::too_many_arguments)]
pub fn rasterize_backward(
    proj: &ProjectedKernels,
    bins: &TileBins,
    forms: &[RowForm],
    v_image: &[f32],
    exp: ExpMode,
    partials: &mut Vec<[f32; 8]>,
    sums: &mut Vec<[f64; 8]>,
    out: &mut ScreenGradients,
) {
    let path = SimdPath::detect();
    rasterize_backward_on(path, proj, bins, forms, v_image, exp, partials, sums, out);
}

/// [`rasterize_backward`] on `path` (which the CPU must have).
#[allow(clippy::too_many_arguments)]
pub(crate) fn rasterize_backward_on(
    path: SimdPath,
    proj: &ProjectedKernels,
    bins: &TileBins,
    forms: &[RowForm],
    v_image: &[f32],
    exp: ExpMode,
    partials: &mut Vec<[f32; 8]>,
    sums: &mut Vec<[f64; 8]>,
    out: &mut ScreenGradients,
) {
    assert!(
        SimdPath::available().contains(&path),
        "this CPU cannot run {path}"
    );
    let width = bins.width as usize;
    assert_eq!(
        v_image.len(),
        3 * width * bins.height as usize,
        "∂L/∂C has the image's size"
    );
    assert_eq!(forms.len(), proj.len(), "the forward's row forms");
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
    runs.into_par_iter().for_each(|(t, run)| {
        SCRATCH.with(|cell| {
            let scratch = &mut *cell.borrow_mut();
            backward_tile_on(path, exp, bins, forms, v_image, t, run, scratch);
        });
    });
    reduce(proj, bins, partials, sums, out);
}

/// Scratch of one worker: the tile's row entries (as the forward builds them) and, per
/// kernel of the tile, its eight moments column by column.
#[derive(Default)]
struct BackwardScratch {
    tile: TileScratch,
    moments: Vec<Moments>,
}

/// Per pixel column of the tile, the eight sums of one kernel over the tile's rows:
/// `Σ ∂L/∂C_c G` (3), `Σ w t`, `Σ w t²`, `Σ Δv w`, `Σ Δv w t`, `Σ Δv² w`.
type Moments = [[f32; ROW]; 8];

thread_local! {
    static SCRATCH: std::cell::RefCell<BackwardScratch> =
        std::cell::RefCell::new(BackwardScratch::default());
}

/// [`backward_tile`] compiled for `path`.
#[allow(clippy::too_many_arguments)]
fn backward_tile_on(
    path: SimdPath,
    exp: ExpMode,
    bins: &TileBins,
    forms: &[RowForm],
    v_image: &[f32],
    t: usize,
    run: &mut [[f32; 8]],
    scratch: &mut BackwardScratch,
) {
    match (path, exp) {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `SimdPath::detect` found the features.
        (SimdPath::Avx512, ExpMode::Poly) => unsafe {
            avx512::backward_tile::<true>(bins, forms, v_image, t, run, scratch);
        },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as above.
        (SimdPath::Avx512, ExpMode::Std) => unsafe {
            avx512::backward_tile::<false>(bins, forms, v_image, t, run, scratch);
        },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as above.
        (SimdPath::Avx2, ExpMode::Poly) => unsafe {
            backward_tile_avx2::<true>(bins, forms, v_image, t, run, scratch);
        },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as above.
        (SimdPath::Avx2, ExpMode::Std) => unsafe {
            backward_tile_avx2::<false>(bins, forms, v_image, t, run, scratch);
        },
        (_, ExpMode::Poly) => backward_tile::<true, false>(bins, forms, v_image, t, run, scratch),
        (_, ExpMode::Std) => backward_tile::<false, false>(bins, forms, v_image, t, run, scratch),
    }
}

/// [`backward_tile`] compiled for AVX2 and FMA, its half rows with intrinsics.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn backward_tile_avx2<const FAST: bool>(
    bins: &TileBins,
    forms: &[RowForm],
    v_image: &[f32],
    t: usize,
    run: &mut [[f32; 8]],
    scratch: &mut BackwardScratch,
) {
    backward_tile::<FAST, true>(bins, forms, v_image, t, run, scratch);
}

/// Accumulates tile `t`'s entries into `run` (one partial per entry): the forward's row
/// entries, half row by half row; each kernel's moments are summed column by column over
/// the tile's rows (f32, at most 16 terms a column), then over the columns in f64.
#[inline(always)]
fn backward_tile<const FAST: bool, const AVX2: bool>(
    bins: &TileBins,
    forms: &[RowForm],
    v_image: &[f32],
    t: usize,
    run: &mut [[f32; 8]],
    scratch: &mut BackwardScratch,
) {
    prepare_tile(bins, forms, t, &mut scratch.tile);
    let tile = &scratch.tile;
    scratch.moments.clear();
    scratch.moments.resize(tile.kernels.len(), [[0.0; ROW]; 8]);
    let rect = bins.tile_rect(t);
    let [tx0, _, ty0, _] = rect;
    let width = bins.width as usize;
    for HalfRow {
        row,
        index,
        first,
        lanes,
    } in half_rows(rect)
    {
        // ∂L/∂C of the half row, channel by channel; zero past the image's edge.
        let mut v = [[0.0_f32; LANES]; 3];
        let start = 3 * ((ty0 as usize + row) * width + tx0 as usize + first);
        read_planes(&v_image[start..start + 3 * lanes], &mut v);
        let entries = &tile.halves[index];
        let (first_lane, lanes_f) = (first as f32, lanes as f32);
        if AVX2 {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: AVX2 is only asked for on the paths that have it.
            unsafe {
                avx2::half_row::<FAST>(
                    entries,
                    &tile.kernels,
                    first_lane,
                    lanes_f,
                    &v,
                    &mut scratch.moments,
                );
            }
        } else {
            half_row::<FAST>(
                entries,
                &tile.kernels,
                first_lane,
                lanes_f,
                &v,
                &mut scratch.moments,
            );
        }
    }
    store_partials(&scratch.moments, &scratch.tile.entry_of, run);
}

/// Each tile kernel's moments, summed over the columns in f64, into its entry's partial
/// (`entry_of`: each tile kernel's position in the tile's list).
#[inline(always)]
fn store_partials(moments: &[Moments], entry_of: &[u32], run: &mut [[f32; 8]]) {
    for (moments, &n) in moments.iter().zip(entry_of) {
        run[n as usize] = partial_of(moments);
    }
}

/// One tile kernel's partial: each moment summed over the 16 columns in f64, in column
/// order.
#[inline(always)]
fn partial_of(moments: &Moments) -> [f32; 8] {
    std::array::from_fn(|m| moments[m].iter().map(|&x| f64::from(x)).sum::<f64>() as f32)
}

/// One half row's entries into their kernels' moments (lane `i` is tile pixel `first + i`;
/// lanes at or past `lanes` are outside the image and add zero).
// `i` indexes the lane's ∂L/∂C and, offset by the half's column, the moments.
#[allow(clippy::needless_range_loop)]
#[inline(always)]
fn half_row<const FAST: bool>(
    entries: &[RowEntry],
    kernels: &[TileKernel],
    first: f32,
    lanes: f32,
    v: &[[f32; LANES]; 3],
    moments: &mut [Moments],
) {
    for entry in entries {
        let kernel = &kernels[entry.kernel as usize];
        let a = kernel.amplitude.map(|a| a as f32);
        let (dv, dv2) = (entry.dv, entry.dv * entry.dv);
        let m = &mut moments[entry.kernel as usize];
        // Lane i is the tile's pixel column `first + i`.
        let column = first as usize;
        for i in 0..LANES {
            let (t, g, _) = entry.lane::<FAST>(kernel, first, lanes, i);
            let w = (v[0][i] * a[0] + v[1][i] * a[1] + v[2][i] * a[2]) * g;
            let wt = w * t;
            let k = column + i;
            m[0][k] += v[0][i] * g;
            m[1][k] += v[1][i] * g;
            m[2][k] += v[2][i] * g;
            m[3][k] += wt;
            m[4][k] += wt * t;
            m[5][k] += dv * w;
            m[6][k] += dv * wt;
            m[7][k] += dv2 * w;
        }
    }
}

/// [`half_row`] with AVX2 intrinsics: the same operations in the same order (no fused
/// multiply-add), so the same bits.
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use std::arch::x86_64::*;

    use super::Moments;
    use crate::raster::avx2::{gaussian, lane_numbers, lanes};
    use crate::raster::{LANES, RowEntry, TileKernel};

    #[target_feature(enable = "avx2,fma")]
    pub(super) fn half_row<const FAST: bool>(
        entries: &[RowEntry],
        kernels: &[TileKernel],
        first: f32,
        inside: f32,
        v: &[[f32; LANES]; 3],
        moments: &mut [Moments],
    ) {
        let numbers = lane_numbers(inside);
        // SAFETY: each channel holds 8 floats.
        let v = v.map(|c| unsafe { _mm256_loadu_ps(c.as_ptr()) });
        for entry in entries {
            let kernel = &kernels[entry.kernel as usize];
            let a = kernel.amplitude.map(|a| _mm256_set1_ps(a as f32));
            let (t, q, hit) = lanes(entry, kernel, numbers, first);
            if _mm256_movemask_ps(hit) == 0 {
                // Every term is zero: adding them would change nothing (sums start at +0).
                continue;
            }
            let value = gaussian::<FAST>(q);
            let g = _mm256_and_ps(value, hit);
            let w = _mm256_mul_ps(
                _mm256_add_ps(
                    _mm256_add_ps(_mm256_mul_ps(v[0], a[0]), _mm256_mul_ps(v[1], a[1])),
                    _mm256_mul_ps(v[2], a[2]),
                ),
                g,
            );
            let wt = _mm256_mul_ps(w, t);
            let dv = _mm256_set1_ps(entry.dv);
            let dv2 = _mm256_set1_ps(entry.dv * entry.dv);
            let terms = [
                _mm256_mul_ps(v[0], g),
                _mm256_mul_ps(v[1], g),
                _mm256_mul_ps(v[2], g),
                wt,
                _mm256_mul_ps(wt, t),
                _mm256_mul_ps(dv, w),
                _mm256_mul_ps(dv, wt),
                _mm256_mul_ps(dv2, w),
            ];
            let m = &mut moments[entry.kernel as usize];
            for (sum, term) in m.iter_mut().zip(terms) {
                // SAFETY: each moment holds 16 floats, from column `first` (0 or 8) on 8.
                unsafe {
                    let p = sum.as_mut_ptr().add(first as usize);
                    _mm256_storeu_ps(p, _mm256_add_ps(_mm256_loadu_ps(p), term));
                }
            }
        }
    }
}

/// The backward tile with AVX-512, kernel by kernel: each tile kernel walks its own rows
/// (from its row mask, ascending) with its eight moments in registers, 16 columns a
/// register. A column adds the same terms in the same order as the rows-outer loops of the
/// other paths (one term per row, rows ascending), so the sums are the same bits; the lanes
/// of a half the kernel does not reach add exact zeros.
#[cfg(target_arch = "x86_64")]
mod avx512 {
    use std::arch::x86_64::*;

    use super::{BackwardScratch, Moments, ROW, partial_of, read_planes};
    use crate::raster::RowForm;
    use crate::raster::avx512::{gaussian, prepare_tile, row_lanes};
    use crate::tiles::TileBins;

    /// [`super::backward_tile`] with AVX-512: per kernel and row the operations of
    /// [`super::half_row`] on 16 lanes.
    #[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,popcnt")]
    pub(super) fn backward_tile<const FAST: bool>(
        bins: &TileBins,
        forms: &[RowForm],
        v_image: &[f32],
        t: usize,
        run: &mut [[f32; 8]],
        scratch: &mut BackwardScratch,
    ) {
        prepare_tile::<false>(bins, forms, t, &mut scratch.tile.whole_rows);
        let tile = &scratch.tile.whole_rows;
        let [tx0, tx1, ty0, ty1] = bins.tile_rect(t);
        let lanes = (tx1 - tx0) as usize;
        let width = bins.width as usize;
        // ∂L/∂C of the tile's rows, channel by channel; zero past the image's edges.
        let mut v = [[[0.0_f32; ROW]; 3]; ROW];
        for (row, v) in v.iter_mut().enumerate().take((ty1 - ty0) as usize) {
            let start = 3 * ((ty0 as usize + row) * width + tx0 as usize);
            read_planes(&v_image[start..start + 3 * lanes], v);
        }
        // Lanes past the image's right edge never count.
        let valid: __mmask16 = ((1_u32 << lanes) - 1) as __mmask16;
        for (k, kernel) in tile.kernels.iter().enumerate() {
            let block = &tile.blocks[k];
            let a = kernel.amplitude.map(|a| _mm512_set1_ps(a as f32));
            let mut sums = [_mm512_setzero_ps(); 8];
            let mut rows = tile.masks[k];
            while rows != 0 {
                let row = rows.trailing_zeros() as usize;
                rows &= rows - 1;
                let (t, q, hit) = row_lanes(kernel, block, row, valid);
                if hit == 0 {
                    // Every term is zero: adding them would change nothing (sums start at +0).
                    continue;
                }
                // SAFETY: each channel of the row holds 16 floats.
                let v = v[row].map(|c| unsafe { _mm512_loadu_ps(c.as_ptr()) });
                let g = _mm512_maskz_mov_ps(hit, gaussian::<FAST>(q));
                let w = _mm512_mul_ps(
                    _mm512_add_ps(
                        _mm512_add_ps(_mm512_mul_ps(v[0], a[0]), _mm512_mul_ps(v[1], a[1])),
                        _mm512_mul_ps(v[2], a[2]),
                    ),
                    g,
                );
                let wt = _mm512_mul_ps(w, t);
                let dv = _mm512_set1_ps(block.dv[row]);
                let dv2 = _mm512_set1_ps(block.dv[row] * block.dv[row]);
                let terms = [
                    _mm512_mul_ps(v[0], g),
                    _mm512_mul_ps(v[1], g),
                    _mm512_mul_ps(v[2], g),
                    wt,
                    _mm512_mul_ps(wt, t),
                    _mm512_mul_ps(dv, w),
                    _mm512_mul_ps(dv, wt),
                    _mm512_mul_ps(dv2, w),
                ];
                for (sum, term) in sums.iter_mut().zip(terms) {
                    *sum = _mm512_add_ps(*sum, term);
                }
            }
            let mut moments: Moments = [[0.0; ROW]; 8];
            for (column, sum) in moments.iter_mut().zip(sums) {
                // SAFETY: each moment holds 16 floats.
                unsafe { _mm512_storeu_ps(column.as_mut_ptr(), sum) };
            }
            run[tile.entry_of[k] as usize] = partial_of(&moments);
        }
    }
}

/// Reduces the per-entry partials into per-kernel gradients, in entry order (tile-major)
/// in f64, so the result does not depend on the thread count. Partials hold `Σ ∂L/∂a` (3)
/// and the five moments of [`screen_gradients_from_moments`], and with a ninth number (the
/// alpha backward's) `∂L/∂o(τ)`. Shared by the additive and the alpha backward.
pub(crate) fn reduce<T: Copy + Into<f64>, const N: usize>(
    proj: &ProjectedKernels,
    bins: &TileBins,
    partials: &[[T; N]],
    sums: &mut Vec<[f64; N]>,
    out: &mut ScreenGradients,
) {
    sums.clear();
    sums.resize(proj.len(), [0.0; N]);
    for (partial, &p) in partials.iter().zip(&bins.proj_from_entry) {
        for (s, &v) in sums[p as usize].iter_mut().zip(partial) {
            *s += v.into();
        }
    }
    out.v_amplitudes.clear();
    out.v_means.clear();
    out.v_covariances.clear();
    out.v_opacities.clear();
    for (p, s) in sums.iter().enumerate() {
        out.v_amplitudes.push([s[0], s[1], s[2]]);
        let (v_mean, v_covariance) =
            screen_gradients_from_moments(proj, p, [s[3], s[4], s[5], s[6], s[7]]);
        out.v_means.push(v_mean);
        out.v_covariances.push(v_covariance);
        if let Some(&v_opacity) = s.get(8) {
            out.v_opacities.push(v_opacity);
        }
    }
}

/// `∂L/∂m2` and `∂L/∂Σ2` of projected kernel `p` from its moments `Σ w (t, t², Δv, t Δv,
/// Δv²)` (`∂L/∂q = -½ w` per pair): `Σ w Q d` and `½ Σ w (Q d)(Q d)ᵀ` with
/// `Q d = (Qxx t, Qxy t + Δv/Σ2yy)`. Shared by the additive and the alpha backward.
pub(crate) fn screen_gradients_from_moments(
    proj: &ProjectedKernels,
    p: usize,
    [s_t, s_tt, s_v, s_tv, s_vv]: [f64; 5],
) -> ([f64; 2], [f64; 3]) {
    let [a, b, _] = proj.conics[p];
    let e = 1.0 / proj.covariances[p][2];
    (
        [a * s_t, b * s_t + e * s_v],
        [
            0.5 * a * a * s_tt,
            0.5 * a * (b * s_tt + e * s_tv),
            0.5 * (b * b * s_tt + 2.0 * b * e * s_tv + e * e * s_vv),
        ],
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::random::seeded_rng;
    use crate::render::{RenderContext, RenderOptions};
    use rand::RngExt;

    #[test]
    fn every_simd_path_gives_the_same_gradients_bit_for_bit() {
        // Partial tiles on the right (1 and 11 columns) and at the bottom.
        let scene = crate::scenes::synthetic::bench_scene(2000, 9);
        for ((w, h), exp) in [
            ((161, 97), ExpMode::Poly),
            ((171, 83), ExpMode::Poly),
            ((161, 97), ExpMode::Std),
        ] {
            let camera = crate::scenes::synthetic::bench_camera(w, h);
            let options = RenderOptions {
                exp,
                ..RenderOptions::default()
            };
            let mut context = RenderContext::new();
            context.render(&scene, &camera, 0.5, &options).unwrap();
            let mut rng = seeded_rng(3);
            let v_image: Vec<f32> = (0..3 * w * h)
                .map(|_| rng.random_range(-1.0..1.0))
                .collect();
            let mut forms = Vec::new();
            crate::raster::row_forms(&context.projected, &context.bins, &mut forms);
            let mut results = Vec::new();
            for &path in SimdPath::available() {
                let (mut partials, mut sums) = (Vec::new(), Vec::new());
                let mut out = ScreenGradients::default();
                rasterize_backward_on(
                    path,
                    &context.projected,
                    &context.bins,
                    &forms,
                    &v_image,
                    exp,
                    &mut partials,
                    &mut sums,
                    &mut out,
                );
                assert!(partials.iter().flatten().any(|&p| p != 0.0));
                results.push((path, partials));
            }
            for (path, partials) in &results[1..] {
                assert!(
                    partials
                        .iter()
                        .flatten()
                        .zip(results[0].1.iter().flatten())
                        .all(|(a, b)| a.to_bits() == b.to_bits()),
                    "{exp}: {path} differs from {}",
                    results[0].0
                );
            }
        }
    }
}
