//! The lanes of a half row with AVX2 intrinsics (8 f32 lanes; SPEC §5, precision): the exp,
//! `t`, `q` and the pair test of [`RowEntry::lane`], the same operations in the same order
//! (the fused ones by FMA instructions), so the same bits. The loops that use them — the
//! additive sum (`crate::raster`), the compositor's lanes (`crate::composite`) and the
//! additive backward — take them inlined into their own `#[target_feature]` code.

use std::arch::x86_64::*;

use super::{LANES, RowEntry, TileKernel};

/// [`super::fast_exp_neg_half`] on 8 lanes: the same operations, the fused ones by FMA.
#[inline]
#[target_feature(enable = "avx2,fma")]
pub(crate) fn exp_neg_half(q: __m256) -> __m256 {
    use super::exp_constants::{HORNER, LN2_HI_TWICE, LN2_LO_TWICE, LOG2_E_NEG_HALF, Q_MAX, SHIFT};
    let y = _mm256_min_ps(q, _mm256_set1_ps(Q_MAX));
    let shift = _mm256_set1_ps(SHIFT);
    let shifted = _mm256_fmadd_ps(y, _mm256_set1_ps(LOG2_E_NEG_HALF), shift);
    let n = _mm256_sub_ps(shifted, shift);
    let r = _mm256_fmadd_ps(n, _mm256_set1_ps(LN2_HI_TWICE), y);
    let r = _mm256_fmadd_ps(n, _mm256_set1_ps(LN2_LO_TWICE), r);
    let step = |p: __m256, c: f32| _mm256_fmadd_ps(r, p, _mm256_set1_ps(c));
    // Horner, as the scalar.
    let p = step(_mm256_set1_ps(HORNER[0]), HORNER[1]);
    let p = step(p, HORNER[2]);
    let p = step(p, HORNER[3]);
    let p = step(p, HORNER[4]);
    let p = step(p, HORNER[5]);
    let n_int = _mm256_sub_epi32(_mm256_castps_si256(shifted), _mm256_castps_si256(shift));
    let scale = _mm256_slli_epi32::<23>(_mm256_add_epi32(n_int, _mm256_set1_epi32(127)));
    _mm256_mul_ps(p, _mm256_castsi256_ps(scale))
}

/// The lane numbers 0..8 and the mask of the first `lanes` of them (inside the image).
#[inline]
#[target_feature(enable = "avx2,fma")]
pub(crate) fn lane_numbers(lanes: f32) -> (__m256, __m256) {
    let iota = _mm256_setr_ps(0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0);
    (
        iota,
        _mm256_cmp_ps::<_CMP_LT_OQ>(iota, _mm256_set1_ps(lanes)),
    )
}

/// [`RowEntry::lane`] on 8 lanes (`iota` and `valid` from [`lane_numbers`]): `t`, `q`
/// and the mask of the pairs summed. `G` is [`gaussian`] of `q`, masked.
#[inline]
#[target_feature(enable = "avx2,fma")]
pub(crate) fn lanes(
    entry: &RowEntry,
    kernel: &TileKernel,
    (iota, valid): (__m256, __m256),
    first: f32,
) -> (__m256, __m256, __m256) {
    let t = _mm256_add_ps(
        _mm256_add_ps(iota, _mm256_set1_ps(first - entry.offset)),
        _mm256_set1_ps(entry.t_anchor),
    );
    let q = _mm256_fmadd_ps(
        _mm256_mul_ps(_mm256_set1_ps(kernel.qxx), t),
        t,
        _mm256_set1_ps(entry.row_q),
    );
    let hit = _mm256_and_ps(
        _mm256_cmp_ps::<_CMP_LE_OQ>(q, _mm256_set1_ps(kernel.qmax)),
        valid,
    );
    (t, q, hit)
}

/// `exp(-½ q)` on 8 lanes as [`super::gaussian`] evaluates it: the polynomial, or libm
/// lane by lane.
#[inline]
#[target_feature(enable = "avx2,fma")]
pub(crate) fn gaussian<const FAST: bool>(q: __m256) -> __m256 {
    if FAST {
        return exp_neg_half(q);
    }
    let mut values = [0.0_f32; LANES];
    // SAFETY: `values` holds 8 floats.
    unsafe { _mm256_storeu_ps(values.as_mut_ptr(), q) };
    let values = values.map(|q| (-0.5 * q).exp());
    // SAFETY: as above.
    unsafe { _mm256_loadu_ps(values.as_ptr()) }
}
