//! The additive sum's rows (SPEC §5, Eq. 2) with AVX-512: a whole tile row (16 lanes) is
//! the vector, and each row list ([`super::prepare_whole_rows`]) passes over six f64
//! accumulators of 8 lanes (three channels, two halves). The operations per lane are the
//! half-row loops' in the same order (the same `t`, `q`, test, polynomial and f64
//! products), so the image is the same bit for bit. Four entries are taken at a time, their
//! `G` first and then their terms in list order, so that the exps' dependent chains
//! overlap. With `KEEP` (a training step's forward) each (tile kernel, row)'s `G` and pair
//! mask are kept for the backward.

use std::arch::x86_64::*;

use super::{KeptGaussians, RasterScratch, TileBlocks, prepare_whole_rows};
use crate::simd::avx512::{gaussian, row_lanes};
use crate::simd::{BinnedFrame, ROW, write_planes};
use crate::tiles::TileBins;

/// The tile with AVX-512: [`prepare_whole_rows`], then [`sum_tile`] (16 lanes a row),
/// keeping its `G` in `scratch.kept` when `KEEP`.
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,popcnt")]
pub(super) fn tile<const FAST: bool, const KEEP: bool>(
    frame: &BinnedFrame,
    t: usize,
    scratch: &mut RasterScratch,
    band: &mut [f32],
) -> u64 {
    prepare_whole_rows::<true>(frame.bins, frame.forms, t, &mut scratch.whole_rows);
    let tiles = &scratch.whole_rows;
    if KEEP {
        scratch.kept.make_room(tiles.kernels.len());
    }
    let kept = &mut scratch.kept;
    sum_tile::<FAST, KEEP>(frame.bins, t, frame.background, tiles, band, kept)
}

/// Tile kernel `k`'s `G` on tile row `row` (16 lanes), its pair mask and amplitudes; with
/// `KEEP` also written to `kept` (non-pairs as +0).
///
/// # Safety
/// The CPU has the AVX-512 path's features (a plain function, so that it is inlined into
/// [`sum_tile`], whose target features its intrinsics then take); `k` indexes
/// `tiles.kernels` and `tiles.blocks` (an index of a row list); with `KEEP`,
/// `make_room` gave `kept` 16 rows for each tile kernel.
#[inline(always)]
unsafe fn entry_g<const FAST: bool, const KEEP: bool>(
    tiles: &TileBlocks,
    k: u32,
    row: usize,
    valid: __mmask16,
    kept: &mut KeptGaussians,
) -> ([f64; 3], __m512, __mmask16) {
    debug_assert!((k as usize) < tiles.kernels.len());
    // SAFETY: the caller's promises: the features, `k` in range, and with `KEEP` the
    // room in `kept`.
    unsafe {
        let (kernel, block) = (
            tiles.kernels.get_unchecked(k as usize),
            tiles.blocks.get_unchecked(k as usize),
        );
        let (_, q, hit) = row_lanes(kernel, block, row, valid);
        let g = gaussian::<FAST>(q);
        if KEEP {
            let at = ROW * k as usize + row;
            let values = kept.values.get_unchecked_mut(at);
            _mm512_storeu_ps(values.as_mut_ptr(), _mm512_maskz_mov_ps(hit, g));
            *kept.hits.get_unchecked_mut(at) = hit;
        }
        (kernel.amplitude, g, hit)
    }
}

/// Adds `a_c G` of the pairs in `hit` to the six accumulators (lanes that are not pairs
/// convert as +0, the mask's zeroing); the pairs (counted on the scalar side, off the
/// vector pipes).
///
/// # Safety
/// The CPU has the AVX-512 path's features (as [`entry_g`]).
#[inline(always)]
unsafe fn add_terms(
    amplitude: [f64; 3],
    g: __m512,
    hit: __mmask16,
    lo: &mut [__m512d; 3],
    hi: &mut [__m512d; 3],
) -> u64 {
    // SAFETY: the caller's promise (the features).
    unsafe {
        let g_lo = _mm512_maskz_cvtps_pd(hit as __mmask8, _mm512_castps512_ps256(g));
        let g_hi = _mm512_maskz_cvtps_pd((hit >> 8) as __mmask8, _mm512_extractf32x8_ps::<1>(g));
        // `a G` is exact in f64, so the fused multiply-add rounds as `acc + a G`.
        for c in 0..3 {
            let a = _mm512_set1_pd(amplitude[c]);
            lo[c] = _mm512_fmadd_pd(a, g_lo, lo[c]);
            hi[c] = _mm512_fmadd_pd(a, g_hi, hi[c]);
        }
    }
    u64::from(hit.count_ones())
}

/// Sums the prepared tile `t` row by row into `band`: per row, six accumulators (three
/// channels, two halves of 8 f64 lanes) start at the background and take every entry of
/// the row's list; the row is then rounded to f32 and written in place.
#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,popcnt")]
fn sum_tile<const FAST: bool, const KEEP: bool>(
    bins: &TileBins,
    t: usize,
    background: [f64; 3],
    tiles: &TileBlocks,
    band: &mut [f32],
    kept: &mut KeptGaussians,
) -> u64 {
    let [tx0, tx1, ty0, ty1] = bins.tile_rect(t);
    let width = bins.width as usize;
    let lanes = (tx1 - tx0) as usize;
    // Lanes past the image's right edge never count.
    let valid: __mmask16 = ((1_u32 << lanes) - 1) as __mmask16;
    let mut pairs = 0_u64;
    let mut acc = [[0.0_f64; ROW]; 3];
    for row in 0..(ty1 - ty0) as usize {
        let mut lo = background.map(|b| _mm512_set1_pd(b + 0.0));
        let mut hi = lo;
        // Four entries at a time: their four `G` first, then their terms in list order
        // (the same sums in the same order), so that the exps' dependent chains overlap.
        let list = &tiles.rows[row];
        let mut fours = list.chunks_exact(4);
        // SAFETY: this function has the features (its callers checked the CPU); the
        // lists hold only indices of kept kernels, each with a block; with `KEEP`,
        // `make_room` gave `kept` 16 rows for each tile kernel.
        unsafe {
            for four in &mut fours {
                let entries = [
                    entry_g::<FAST, KEEP>(tiles, four[0], row, valid, kept),
                    entry_g::<FAST, KEEP>(tiles, four[1], row, valid, kept),
                    entry_g::<FAST, KEEP>(tiles, four[2], row, valid, kept),
                    entry_g::<FAST, KEEP>(tiles, four[3], row, valid, kept),
                ];
                for (amplitude, g, hit) in entries {
                    pairs += add_terms(amplitude, g, hit, &mut lo, &mut hi);
                }
            }
            for &k in fours.remainder() {
                let (amplitude, g, hit) = entry_g::<FAST, KEEP>(tiles, k, row, valid, kept);
                pairs += add_terms(amplitude, g, hit, &mut lo, &mut hi);
            }
        }
        for c in 0..3 {
            // SAFETY: each channel holds 16 doubles: 8 in `lo`, 8 in `hi`.
            unsafe {
                _mm512_storeu_pd(acc[c].as_mut_ptr(), lo[c]);
                _mm512_storeu_pd(acc[c].as_mut_ptr().add(8), hi[c]);
            }
        }
        write_planes(
            &acc,
            &mut band[3 * (row * width + tx0 as usize)..][..3 * lanes],
        );
    }
    pairs
}
