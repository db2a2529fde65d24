//! The additive sum's half-row loop (SPEC §5, Eq. 2) with AVX2 intrinsics (8 lanes): the
//! operations of the portable loop (`super::portable`) in the same order, so the result is
//! the same bit for bit: the f32 part fuses exactly where the portable code calls
//! `mul_add`, and the f64 accumulation `acc + a G` rounds like the portable sum because `a
//! G` is exact there. Four entries are taken at a time, their `G` first and then their
//! terms in list order (the same sums in the same order), so that the exps' dependent
//! chains overlap.

use std::arch::x86_64::*;

use crate::simd::avx2::{gaussian, lane_numbers, lanes};
use crate::simd::{LANES, RowEntry, TileKernel};

/// An entry's `G` on 8 lanes, masked, with its pair mask and its kernel's amplitudes.
///
/// # Safety
/// The CPU has AVX2 and FMA (a plain function, so that it is inlined into
/// [`sum_half_row`], whose target features its intrinsics then take).
#[inline(always)]
unsafe fn entry_g<const FAST: bool>(
    entry: &RowEntry,
    kernels: &[TileKernel],
    numbers: (__m256, __m256),
    first: f32,
) -> ([f64; 3], __m256, __m256) {
    let kernel = &kernels[entry.kernel as usize];
    // SAFETY: the caller's promise (AVX2 and FMA).
    unsafe {
        let (_, q, hit) = lanes(entry, kernel, numbers, first);
        (
            kernel.amplitude,
            _mm256_and_ps(gaussian::<FAST>(q), hit),
            hit,
        )
    }
}

/// Adds an entry's `a_c G` to the accumulators; its pairs.
///
/// # Safety
/// As [`entry_g`]: the CPU has AVX2 and FMA.
#[inline(always)]
unsafe fn add_terms(
    (amplitude, g, hit): ([f64; 3], __m256, __m256),
    lo: &mut [__m256d; 3],
    hi: &mut [__m256d; 3],
) -> u64 {
    // SAFETY: the caller's promise (AVX2 and FMA).
    unsafe {
        let g_lo = _mm256_cvtps_pd(_mm256_castps256_ps128(g));
        let g_hi = _mm256_cvtps_pd(_mm256_extractf128_ps::<1>(g));
        // `a G` is exact in f64 (two 24-bit significands), so the fused multiply-add
        // rounds exactly as the portable loop's `acc + a G` does.
        for c in 0..3 {
            let a = _mm256_set1_pd(amplitude[c]);
            lo[c] = _mm256_fmadd_pd(a, g_lo, lo[c]);
            hi[c] = _mm256_fmadd_pd(a, g_hi, hi[c]);
        }
        u64::from(_mm256_movemask_ps(hit).count_ones())
    }
}

/// The portable half-row loop (`super::portable`) with AVX2.
#[target_feature(enable = "avx2,fma")]
pub(super) fn sum_half_row<const FAST: bool>(
    entries: &[RowEntry],
    kernels: &[TileKernel],
    first: f32,
    lanes: f32,
    background: [f64; 3],
    acc: &mut [[f64; LANES]; 3],
) -> u64 {
    let numbers = lane_numbers(lanes);
    let mut lo = background.map(|b| _mm256_set1_pd(b + 0.0));
    let mut hi = lo;
    let mut pairs = 0_u64;
    // Four entries at a time, their `G` first and then their terms in list order (the
    // same sums in the same order), as on the AVX-512 path.
    let mut fours = entries.chunks_exact(4);
    // SAFETY: this function has AVX2 and FMA (its callers checked the CPU).
    unsafe {
        for four in &mut fours {
            let values = [
                entry_g::<FAST>(&four[0], kernels, numbers, first),
                entry_g::<FAST>(&four[1], kernels, numbers, first),
                entry_g::<FAST>(&four[2], kernels, numbers, first),
                entry_g::<FAST>(&four[3], kernels, numbers, first),
            ];
            for value in values {
                pairs += add_terms(value, &mut lo, &mut hi);
            }
        }
        for entry in fours.remainder() {
            let value = entry_g::<FAST>(entry, kernels, numbers, first);
            pairs += add_terms(value, &mut lo, &mut hi);
        }
    }
    for c in 0..3 {
        // SAFETY: each channel holds 8 doubles: 4 in `lo`, 4 in `hi`.
        unsafe {
            _mm256_storeu_pd(acc[c].as_mut_ptr(), lo[c]);
            _mm256_storeu_pd(acc[c].as_mut_ptr().add(4), hi[c]);
        }
    }
    pairs
}
