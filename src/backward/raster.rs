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
//! forward's whole-row tile set-up (16 lanes a row, `raster::prepare_whole_rows`) and walks
//! each kernel's own rows with its moments in registers: a column adds the same terms in the
//! same order (one per row, rows ascending), and the lanes of a half the kernel does not
//! reach add zeros (which can change only the sign of a zero sum; a partial's zero is stored
//! as +0). The entries are reduced in entry order (tile-major) in
//! f64: no atomics, and the result does not depend on the thread count or the SIMD path (the
//! AVX2 loop performs the portable loop's operations in the same order).
//!
//! A training step runs the forward raster and this backward in one pass over the tiles
//! ([`rasterize_with_backward`]): each tile is set up once, summed, given its `∂L/∂C` by the
//! loss ([`PixelGradient`]) and differentiated at once, with the same bits as the two
//! passes. On the AVX-512 path the forward keeps each (tile kernel, row)'s `G` and pair mask
//! (`raster::KeptGaussians`: 16 values and a mask) and the backward reads them instead of
//! evaluating `q` and the exp again.

use rayon::prelude::*;

use crate::model::Image;
use crate::project::ProjectedKernels;
use crate::raster::{RasterScratch, forward_tile};
use crate::simd::{
    BinnedFrame, ExpMode, HalfRow, LANES, ROW, RowEntry, SimdPath, TileKernel, half_rows,
    prepare_tile, read_planes, size_image,
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

/// The additive backward's partial sums, kept between frames: one per (tile, kernel) entry
/// (`Σ ∂L/∂a` and the five moments, f32 per tile), and their reduction per projected kernel
/// in f64.
#[derive(Clone, Debug, Default)]
pub struct RasterPartials {
    entries: Vec<[f32; 8]>,
    kernels: Vec<[f64; 8]>,
}

impl RasterPartials {
    /// One zeroed partial per tile entry of `bins`.
    fn reset(&mut self, bins: &TileBins) {
        self.entries.clear();
        self.entries.resize(bins.proj_from_entry.len(), [0.0; 8]);
    }
}

/// Accumulates `∂L/∂C` (`v_image`, RGB row-major, `width` pixels per row) of `frame` (whose
/// row forms are its forward render's) into `out`, one entry per projected kernel (reset
/// first), with `partials` as scratch.
pub fn rasterize_backward(
    frame: &BinnedFrame,
    v_image: &[f32],
    partials: &mut RasterPartials,
    out: &mut ScreenGradients,
) {
    let bins = frame.bins;
    assert_eq!(
        v_image.len(),
        3 * bins.width as usize * bins.height as usize,
        "∂L/∂C has the image's size"
    );
    partials.reset(bins);
    // One disjoint run of partials per tile.
    let mut runs = Vec::with_capacity(bins.tile_count());
    let mut rest = partials.entries.as_mut_slice();
    for t in 0..bins.tile_count() {
        let (run, tail) = rest.split_at_mut(bins.tile_entries(t).len());
        runs.push((t, run));
        rest = tail;
    }
    runs.into_par_iter().for_each(|(t, run)| {
        SCRATCH.with(|cell| {
            let scratch = &mut *cell.borrow_mut();
            prepare_backward_tile(frame, t, scratch);
            backward_tile(frame, (v_image, 0), t, run, scratch, false);
        });
    });
    reduce(
        frame.proj,
        bins,
        &partials.entries,
        &mut partials.kernels,
        out,
    );
}

/// A loss's gradient with respect to the rendered pixels, run by run: `gradient(k,
/// rendered, v)` sets `v[i]`, `∂L/∂C` of channel `k + i` of the image (RGB, row-major),
/// from its rendered value `rendered[i]` (the runs are one tile row's pixels, in any
/// order). [`rasterize_with_backward`] calls it on each tile as soon as the tile is summed,
/// on the worker thread that summed it, whose scratch is in use: it must not start parallel
/// work of its own (a rayon call could run another tile on the same thread).
pub type PixelGradient<'a> = dyn Fn(usize, &[f32], &mut [f32]) + Sync + 'a;

/// The forward raster ([`crate::raster::rasterize`]) and [`rasterize_backward`] of `frame`
/// in one pass over its tiles: each tile is set up once, summed into `image`, its `∂L/∂C`
/// computed by `gradient` into `v_image` (resized to the image's), and differentiated while
/// its set-up is in cache. The image, `v_image` and `out` are the same bits as the forward,
/// `gradient` over the whole image and the backward one after the other: every stage is the
/// same code on the same set-up (the forward's). Returns the pairs.
pub fn rasterize_with_backward(
    frame: &BinnedFrame,
    image: &mut Image,
    gradient: &PixelGradient,
    v_image: &mut Vec<f32>,
    partials: &mut RasterPartials,
    out: &mut ScreenGradients,
) -> u64 {
    let bins = frame.bins;
    let pixels = size_image(bins, image);
    v_image.clear();
    v_image.resize(image.pixels.len(), 0.0);
    partials.reset(bins);
    let mut pairs = 0;
    if pixels {
        let (width, tiles_x) = (bins.width as usize, bins.tiles_x as usize);
        // One disjoint run of partials per tile row: its tiles' entries are consecutive.
        let mut band_runs = Vec::with_capacity(bins.tiles_y as usize);
        let mut rest = partials.entries.as_mut_slice();
        for ty in 0..bins.tiles_y as usize {
            let tiles = ty * tiles_x..(ty + 1) * tiles_x;
            let entries = (bins.tile_offsets[tiles.end] - bins.tile_offsets[tiles.start]) as usize;
            let (run, tail) = rest.split_at_mut(entries);
            band_runs.push(run);
            rest = tail;
        }
        pairs = image
            .pixels
            .par_chunks_mut(3 * width * ROW)
            .zip(v_image.par_chunks_mut(3 * width * ROW))
            .zip(band_runs)
            .enumerate()
            .map(|(ty, ((band, v_band), mut runs))| {
                SCRATCH.with(|cell| {
                    let scratch = &mut *cell.borrow_mut();
                    let mut pairs = 0;
                    for t in ty * tiles_x..(ty + 1) * tiles_x {
                        pairs += forward_tile(frame, t, &mut scratch.forward, band);
                        let [tx0, tx1, ty0, ty1] = bins.tile_rect(t);
                        for row in 0..(ty1 - ty0) as usize {
                            let at = 3 * (row * width + tx0 as usize);
                            let run = at..at + 3 * (tx1 - tx0) as usize;
                            let first = 3 * (ty0 as usize * width) + at;
                            gradient(first, &band[run.clone()], &mut v_band[run]);
                        }
                        let (run, tail) =
                            std::mem::take(&mut runs).split_at_mut(bins.tile_entries(t).len());
                        runs = tail;
                        backward_tile(frame, (v_band, ty0 as usize), t, run, scratch, true);
                    }
                    pairs
                })
            })
            .sum();
    }
    reduce(
        frame.proj,
        bins,
        &partials.entries,
        &mut partials.kernels,
        out,
    );
    pairs
}

/// [`backward_prepared_tile`] compiled for the frame's path; `v` holds `∂L/∂C` of the image
/// rows from its second number on. `kept`: the tile's forward ran just before with
/// [`crate::raster::forward_tile`], which keeps its `G` on the AVX-512 path; that path then
/// reads it instead of evaluating `q` and `exp(-½ q)` again.
fn backward_tile(
    frame: &BinnedFrame,
    (v, v_row): (&[f32], usize),
    t: usize,
    run: &mut [[f32; 8]],
    scratch: &mut BackwardScratch,
    kept: bool,
) {
    let bins = frame.bins;
    match (frame.path, frame.exp, kept) {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: a frame's path is one the CPU has (`BinnedFrame`); `kept` says the
        // scratch holds this tile's `G`.
        (SimdPath::Avx512, _, true) => unsafe {
            avx512::backward_prepared_tile::<true, true>(bins, v, v_row, t, run, scratch);
        },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as above.
        (SimdPath::Avx512, ExpMode::Poly, false) => unsafe {
            avx512::backward_prepared_tile::<true, false>(bins, v, v_row, t, run, scratch);
        },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as above.
        (SimdPath::Avx512, ExpMode::Std, false) => unsafe {
            avx512::backward_prepared_tile::<false, false>(bins, v, v_row, t, run, scratch);
        },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as above.
        (SimdPath::Avx2, ExpMode::Poly, _) => unsafe {
            backward_prepared_tile_avx2::<true>(bins, v, v_row, t, run, scratch);
        },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as above.
        (SimdPath::Avx2, ExpMode::Std, _) => unsafe {
            backward_prepared_tile_avx2::<false>(bins, v, v_row, t, run, scratch);
        },
        (_, ExpMode::Poly, _) => {
            backward_prepared_tile::<true, false>(bins, v, v_row, t, run, scratch);
        }
        (_, ExpMode::Std, _) => {
            backward_prepared_tile::<false, false>(bins, v, v_row, t, run, scratch);
        }
    }
}

/// [`backward_prepared_tile`] compiled for AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn backward_prepared_tile_avx2<const FAST: bool>(
    bins: &TileBins,
    v: &[f32],
    v_row: usize,
    t: usize,
    run: &mut [[f32; 8]],
    scratch: &mut BackwardScratch,
) {
    backward_prepared_tile::<FAST, true>(bins, v, v_row, t, run, scratch);
}

/// Scratch of one worker: the tile's set-up (as the forward builds it) and, per kernel of
/// the tile, its eight moments column by column.
#[derive(Default)]
struct BackwardScratch {
    forward: RasterScratch,
    moments: Vec<Moments>,
}

/// Per pixel column of the tile, the eight sums of one kernel over the tile's rows:
/// `Σ ∂L/∂C_c G` (3), `Σ w t`, `Σ w t²`, `Σ Δv w`, `Σ Δv w t`, `Σ Δv² w`.
type Moments = [[f32; ROW]; 8];

thread_local! {
    static SCRATCH: std::cell::RefCell<BackwardScratch> =
        std::cell::RefCell::new(BackwardScratch::default());
}

/// Sets tile `t` of `frame` up in `scratch.forward` for [`backward_tile`] as the forward
/// does on the frame's path: whole rows with AVX-512, half rows otherwise.
fn prepare_backward_tile(frame: &BinnedFrame, t: usize, scratch: &mut BackwardScratch) {
    let (bins, forms) = (frame.bins, frame.forms);
    match frame.path {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: a frame's path is one the CPU has (`BinnedFrame`).
        SimdPath::Avx512 => unsafe {
            crate::raster::prepare_whole_rows::<false>(
                bins,
                forms,
                t,
                &mut scratch.forward.whole_rows,
            );
        },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as above.
        SimdPath::Avx2 => unsafe { prepare_tile_avx2(frame, t, &mut scratch.forward) },
        _ => prepare_tile(bins, forms, t, &mut scratch.forward.tile),
    }
}

/// [`prepare_tile`] compiled for AVX2 and FMA (as the forward's AVX2 tiles are).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn prepare_tile_avx2(frame: &BinnedFrame, t: usize, scratch: &mut RasterScratch) {
    prepare_tile(frame.bins, frame.forms, t, &mut scratch.tile);
}

/// Accumulates tile `t`'s entries into `run` (one partial per entry), the tile set up in
/// `scratch.forward.tile` by [`prepare_tile`] (by the forward of the same frame, say): the
/// forward's row entries, half row by half row; each kernel's moments are summed column by
/// column over the tile's rows (f32, at most 16 terms a column), then over the columns in
/// f64. `v_image` holds `∂L/∂C` of the image rows from `v_row` on.
#[inline(always)]
fn backward_prepared_tile<const FAST: bool, const AVX2: bool>(
    bins: &TileBins,
    v_image: &[f32],
    v_row: usize,
    t: usize,
    run: &mut [[f32; 8]],
    scratch: &mut BackwardScratch,
) {
    let tile = &scratch.forward.tile;
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
        let start = 3 * ((ty0 as usize - v_row + row) * width + tx0 as usize + first);
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
    store_partials(&scratch.moments, &tile.entry_of, run);
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
/// order. A sum that is zero is stored as +0: a fused product that underflows can leave a
/// column at -0 where a path that skips the lane leaves +0 (the only way the paths' column
/// sums can differ), and adding +0 makes the two the same bits.
#[inline(always)]
fn partial_of(moments: &Moments) -> [f32; 8] {
    std::array::from_fn(|m| (moments[m].iter().map(|&x| f64::from(x)).sum::<f64>() + 0.0) as f32)
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
            // Every product that is summed is fused with its sum (`mul_add`: one rounding),
            // as the SIMD paths' FMA instructions do.
            let w = v[2][i].mul_add(a[2], v[1][i].mul_add(a[1], v[0][i] * a[0])) * g;
            let wt = w * t;
            let k = column + i;
            m[0][k] = v[0][i].mul_add(g, m[0][k]);
            m[1][k] = v[1][i].mul_add(g, m[1][k]);
            m[2][k] = v[2][i].mul_add(g, m[2][k]);
            m[3][k] += wt;
            m[4][k] = wt.mul_add(t, m[4][k]);
            m[5][k] = dv.mul_add(w, m[5][k]);
            m[6][k] = dv.mul_add(wt, m[6][k]);
            m[7][k] = dv2.mul_add(w, m[7][k]);
        }
    }
}

/// [`half_row`] with AVX2 intrinsics: the same operations in the same order (its fused
/// multiply-adds by FMA), so the same bits.
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use std::arch::x86_64::*;

    use super::Moments;
    use crate::simd::avx2::{gaussian, lane_numbers, lanes};
    use crate::simd::{LANES, RowEntry, TileKernel};

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
                // Every term is zero: adding them could change only the sign of a zero
                // sum, which `partial_of` stores as +0.
                continue;
            }
            let value = gaussian::<FAST>(q);
            let g = _mm256_and_ps(value, hit);
            let w = _mm256_mul_ps(
                _mm256_fmadd_ps(
                    v[2],
                    a[2],
                    _mm256_fmadd_ps(v[1], a[1], _mm256_mul_ps(v[0], a[0])),
                ),
                g,
            );
            let wt = _mm256_mul_ps(w, t);
            let dv = _mm256_set1_ps(entry.dv);
            let dv2 = _mm256_set1_ps(entry.dv * entry.dv);
            // Each moment's term as (factor, factor); the fourth is `wt` itself, added.
            let products = [
                (v[0], g),
                (v[1], g),
                (v[2], g),
                (wt, t),
                (dv, w),
                (dv, wt),
                (dv2, w),
            ];
            let m = &mut moments[entry.kernel as usize];
            // SAFETY: each moment holds 16 floats, from column `first` (0 or 8) on 8.
            unsafe {
                let p = m[3].as_mut_ptr().add(first as usize);
                _mm256_storeu_ps(p, _mm256_add_ps(_mm256_loadu_ps(p), wt));
                for (moment, (x, y)) in [0, 1, 2, 4, 5, 6, 7].into_iter().zip(products) {
                    let p = m[moment].as_mut_ptr().add(first as usize);
                    _mm256_storeu_ps(p, _mm256_fmadd_ps(x, y, _mm256_loadu_ps(p)));
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

    use super::{BackwardScratch, ROW, read_planes};
    use crate::simd::avx512::{gaussian, row_lanes, row_t};
    use crate::tiles::TileBins;

    /// [`super::backward_prepared_tile`] with AVX-512, per kernel and row the operations of
    /// [`super::half_row`] on 16 lanes, on a tile whose blocks, masks and kernels are set
    /// up in `scratch.forward.whole_rows` (by `prepare_whole_rows::<false>`, or by the
    /// forward's `prepare_whole_rows::<true>`, which sets up the same ones and the row lists
    /// besides).
    /// `v_image` holds `∂L/∂C` of the image rows from `v_row` on.
    #[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,popcnt")]
    pub(super) fn backward_prepared_tile<const FAST: bool, const KEPT: bool>(
        bins: &TileBins,
        v_image: &[f32],
        v_row: usize,
        t: usize,
        run: &mut [[f32; 8]],
        scratch: &mut BackwardScratch,
    ) {
        let (tile, kept) = (&scratch.forward.whole_rows, &scratch.forward.kept);
        let [tx0, tx1, ty0, ty1] = bins.tile_rect(t);
        let lanes = (tx1 - tx0) as usize;
        let width = bins.width as usize;
        // ∂L/∂C of the tile's rows, channel by channel; zero past the image's edges.
        let mut v = [[[0.0_f32; ROW]; 3]; ROW];
        for (row, v) in v.iter_mut().enumerate().take((ty1 - ty0) as usize) {
            let start = 3 * ((ty0 as usize - v_row + row) * width + tx0 as usize);
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
                // `t`, `G` (zero where a lane is not a pair) and the pair mask: as the
                // forward kept them (`KEPT`), or evaluated again (the same operations).
                let (t, g, hit) = if KEPT {
                    let at = ROW * k + row;
                    let t = row_t(block, row);
                    // SAFETY: the forward of this tile made room for 16 rows of each tile
                    // kernel (`make_room`) and wrote the rows it is listed on, which are
                    // the rows read here.
                    unsafe {
                        let g = _mm512_loadu_ps(kept.values.get_unchecked(at).as_ptr());
                        (t, g, *kept.hits.get_unchecked(at))
                    }
                } else {
                    let (t, q, hit) = row_lanes(kernel, block, row, valid);
                    (t, _mm512_maskz_mov_ps(hit, gaussian::<FAST>(q)), hit)
                };
                if hit == 0 {
                    // Every term is zero: adding them could change only the sign of a zero
                    // sum, which `partial_of` stores as +0.
                    continue;
                }
                // SAFETY: each channel of the row holds 16 floats.
                let v = v[row].map(|c| unsafe { _mm512_loadu_ps(c.as_ptr()) });
                let w = _mm512_mul_ps(
                    _mm512_fmadd_ps(
                        v[2],
                        a[2],
                        _mm512_fmadd_ps(v[1], a[1], _mm512_mul_ps(v[0], a[0])),
                    ),
                    g,
                );
                let wt = _mm512_mul_ps(w, t);
                let dv = _mm512_set1_ps(block.dv[row]);
                let dv2 = _mm512_set1_ps(block.dv[row] * block.dv[row]);
                sums[3] = _mm512_add_ps(sums[3], wt);
                let products = [
                    (v[0], g),
                    (v[1], g),
                    (v[2], g),
                    (wt, t),
                    (dv, w),
                    (dv, wt),
                    (dv2, w),
                ];
                for (moment, (x, y)) in [0, 1, 2, 4, 5, 6, 7].into_iter().zip(products) {
                    sums[moment] = _mm512_fmadd_ps(x, y, sums[moment]);
                }
            }
            run[tile.entry_of[k] as usize] = partial_of_registers(&sums);
        }
    }

    /// [`partial_of`] of the moments held in registers (moment `m`'s 16 columns in
    /// `sums[m]`), the same bits: the 8×16 block is transposed so that one register holds
    /// a column of all eight moments, and the columns are added in order in f64, each lane
    /// a moment's sum (`x₀ + x₁ + … + x₁₅`, then `+ 0`). Where the compiler gathered each
    /// moment's columns with inserts and shuffles, this takes 24 shuffles and 16 additions
    /// of eight lanes for the whole partial.
    #[inline]
    #[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,popcnt")]
    pub(super) fn partial_of_registers(sums: &[__m512; 8]) -> [f32; 8] {
        // Within each 128-bit lane (columns 4l .. 4l + 4): rows 0, 1 interleaved, …
        let pairs: [__m512; 8] = std::array::from_fn(|i| {
            let (a, b) = (sums[2 * (i / 2)], sums[2 * (i / 2) + 1]);
            if i % 2 == 0 {
                _mm512_unpacklo_ps(a, b)
            } else {
                _mm512_unpackhi_ps(a, b)
            }
        });
        // … then four moments of one column a lane: `quads[c]` holds, in 128-bit lane l,
        // moments 0..4 of column 4l + c; `quads[4 + c]` moments 4..8 of the same columns.
        let quads: [__m512; 8] = std::array::from_fn(|i| {
            let (half, c) = (i / 4, i % 4);
            let (a, b) = (pairs[4 * half + c / 2], pairs[4 * half + 2 + c / 2]);
            if c % 2 == 0 {
                _mm512_castpd_ps(_mm512_unpacklo_pd(_mm512_castps_pd(a), _mm512_castps_pd(b)))
            } else {
                _mm512_castpd_ps(_mm512_unpackhi_pd(_mm512_castps_pd(a), _mm512_castps_pd(b)))
            }
        });
        // Two columns of all eight moments a register: columns 4l + c and 4(l + 1) + c.
        let mut columns = [_mm256_setzero_ps(); ROW];
        for c in 0..4 {
            for l in [0_i32, 2] {
                let index = _mm512_setr_epi32(
                    4 * l,
                    4 * l + 1,
                    4 * l + 2,
                    4 * l + 3,
                    16 + 4 * l,
                    16 + 4 * l + 1,
                    16 + 4 * l + 2,
                    16 + 4 * l + 3,
                    4 * l + 4,
                    4 * l + 5,
                    4 * l + 6,
                    4 * l + 7,
                    16 + 4 * l + 4,
                    16 + 4 * l + 5,
                    16 + 4 * l + 6,
                    16 + 4 * l + 7,
                );
                let two = _mm512_permutex2var_ps(quads[c], index, quads[4 + c]);
                let l = l as usize;
                columns[4 * l + c] = _mm512_castps512_ps256(two);
                columns[4 * (l + 1) + c] =
                    _mm256_castpd_ps(_mm512_extractf64x4_pd::<1>(_mm512_castps_pd(two)));
            }
        }
        let mut sum = _mm512_cvtps_pd(columns[0]);
        for column in &columns[1..] {
            sum = _mm512_add_pd(sum, _mm512_cvtps_pd(*column));
        }
        let sum = _mm512_add_pd(sum, _mm512_setzero_pd());
        let mut partial = [0.0_f32; 8];
        // SAFETY: `partial` holds 8 floats.
        unsafe { _mm256_storeu_ps(partial.as_mut_ptr(), _mm512_cvtpd_ps(sum)) };
        partial
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
    fn the_render_with_its_backward_is_the_render_then_the_backward_bit_for_bit() {
        use crate::raster::{TileScratchPool, rasterize};
        use crate::simd::RowForm;
        // Partial tiles on the right and at the bottom; an empty frame.
        let scene = crate::scenes::synthetic::bench_scene(2000, 5);
        for ((w, h), exp) in [
            ((171, 83), ExpMode::Poly),
            ((161, 97), ExpMode::Std),
            ((0, 0), ExpMode::Poly),
        ] {
            let camera = crate::scenes::synthetic::bench_camera(w.max(1), h.max(1));
            let camera = crate::model::Camera {
                width: w,
                height: h,
                ..camera
            };
            let options = RenderOptions {
                exp,
                ..RenderOptions::default()
            };
            let mut context = RenderContext::new();
            context.render(&scene, &camera, 0.5, &options).unwrap();
            let (proj, bins) = (&context.projected, &context.bins);
            let mut rng = seeded_rng(7);
            let target: Vec<f32> = (0..3 * w * h).map(|_| rng.random_range(0.0..2.0)).collect();
            // A gradient that depends on the pixel, its channel and its rendered value.
            let gradient = |first: usize, rendered: &[f32], v: &mut [f32]| {
                for (i, (v, &c)) in v.iter_mut().zip(rendered).enumerate() {
                    *v = 0.7 * (c - target[first + i]) + 1e-3 * ((first + i) % 5) as f32;
                }
            };
            let background = [0.25, -0.5, 0.0];
            for &path in SimdPath::available() {
                // One after the other.
                let (mut forms, pool) = (Vec::new(), TileScratchPool::default());
                let frame = BinnedFrame::new(proj, bins, &mut forms, background, exp).on(path);
                let mut image = crate::model::Image::filled(0, 0, [0.0; 3]);
                let pairs = rasterize(&frame, &pool, &mut image);
                let mut v_image = vec![0.0; image.pixels.len()];
                gradient(0, &image.pixels, &mut v_image);
                let mut partials = RasterPartials::default();
                let mut out = ScreenGradients::default();
                rasterize_backward(&frame, &v_image, &mut partials, &mut out);
                // In one pass, with buffers holding another frame's values.
                let mut fused_forms = vec![RowForm::default(); 3];
                let fused_frame =
                    BinnedFrame::new(proj, bins, &mut fused_forms, background, exp).on(path);
                let mut fused_image = crate::model::Image::filled(3, 2, [9.0; 3]);
                let mut fused_v = vec![5.0; 11];
                let mut fused_partials = RasterPartials {
                    entries: vec![[3.0; 8]; 4],
                    kernels: vec![[1.0; 8]; 2],
                };
                let mut fused_out = ScreenGradients::default();
                let fused_pairs = rasterize_with_backward(
                    &fused_frame,
                    &mut fused_image,
                    &gradient,
                    &mut fused_v,
                    &mut fused_partials,
                    &mut fused_out,
                );
                let bits = |values: &[f32]| values.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
                assert_eq!(fused_pairs, pairs, "{path}");
                assert_eq!((fused_image.width, fused_image.height), (w, h));
                assert_eq!(bits(&fused_image.pixels), bits(&image.pixels), "{path}");
                assert_eq!(bits(&fused_v), bits(&v_image), "{path}");
                assert_eq!(
                    bits(fused_partials.entries.as_flattened()),
                    bits(partials.entries.as_flattened()),
                    "{path}"
                );
                assert_eq!(format!("{fused_out:?}"), format!("{out:?}"), "{path}");
                if w > 0 {
                    assert!(pairs > 0 && partials.entries.iter().flatten().any(|&p| p != 0.0));
                }
            }
        }
    }

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
            let (proj, bins) = (&context.projected, &context.bins);
            let frame = BinnedFrame::new(proj, bins, &mut forms, [0.0; 3], exp);
            let mut results = Vec::new();
            for &path in SimdPath::available() {
                let mut partials = RasterPartials::default();
                let mut out = ScreenGradients::default();
                rasterize_backward(&frame.on(path), &v_image, &mut partials, &mut out);
                let partials = partials.entries;
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

    #[test]
    #[cfg(target_arch = "x86_64")]
    fn the_partial_from_registers_is_the_partial_bit_for_bit() {
        use std::arch::x86_64::{__m512, _mm512_loadu_ps};
        if !SimdPath::available().contains(&SimdPath::Avx512) {
            return;
        }
        // Moments of mixed signs and magnitudes, so that the order of the f64 sum shows in
        // the f32 result; zeros of both signs, sums that cancel to zero, subnormals.
        let mut rng = seeded_rng(11);
        let awkward = [0.0, -0.0, 1e-40, -1e-40, 3.0e38, -3.0e38, 1.0, -1.0];
        for round in 0..2000 {
            let moments: Moments = std::array::from_fn(|m| {
                std::array::from_fn(|c| match (round + m + c) % 9 {
                    0 => awkward[(round + 3 * m + c) % awkward.len()],
                    _ => {
                        let scale = 10f32.powi(rng.random_range(-30..30));
                        scale * rng.random_range(-1.0_f32..1.0)
                    }
                })
            });
            // SAFETY: the CPU has the AVX-512 path's features (checked above); each moment
            // holds 16 floats.
            let from_registers = unsafe {
                let sums: [__m512; 8] =
                    std::array::from_fn(|m| _mm512_loadu_ps(moments[m].as_ptr()));
                avx512::partial_of_registers(&sums)
            };
            let expected = partial_of(&moments);
            assert!(
                from_registers
                    .iter()
                    .zip(&expected)
                    .all(|(a, b)| a.to_bits() == b.to_bits()),
                "round {round}: {from_registers:?} against {expected:?}"
            );
        }
    }
}
