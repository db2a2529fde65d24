//! The lanes of a whole tile row with AVX-512 intrinsics (16 f32 lanes; SPEC §5,
//! precision): the exp, `t`, `q` and the pair test of [`super::RowEntry::lane`] on a
//! kernel's [`RowBlock`], the same operations in the same order as the other paths (the
//! exp's last step one instruction, the same rounding), so the same bits. Used by the
//! additive raster's whole-row loops and its backward.

use std::arch::x86_64::*;

use super::{ROW, RowBlock, TileKernel};

/// [`super::avx2::exp_neg_half`] on 16 lanes, the same operations but the last.
#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,popcnt")]
pub(crate) fn exp_neg_half(q: __m512) -> __m512 {
    use super::exp_constants::{HORNER, LN2_HI_TWICE, LN2_LO_TWICE, LOG2_E_NEG_HALF, Q_MAX, SHIFT};
    let y = _mm512_min_ps(q, _mm512_set1_ps(Q_MAX));
    let shift = _mm512_set1_ps(SHIFT);
    let shifted = _mm512_fmadd_ps(y, _mm512_set1_ps(LOG2_E_NEG_HALF), shift);
    let n = _mm512_sub_ps(shifted, shift);
    let r = _mm512_fmadd_ps(n, _mm512_set1_ps(LN2_HI_TWICE), y);
    let r = _mm512_fmadd_ps(n, _mm512_set1_ps(LN2_LO_TWICE), r);
    let step = |p: __m512, c: f32| _mm512_fmadd_ps(r, p, _mm512_set1_ps(c));
    let p = step(_mm512_set1_ps(HORNER[0]), HORNER[1]);
    let p = step(p, HORNER[2]);
    let p = step(p, HORNER[3]);
    let p = step(p, HORNER[4]);
    let p = step(p, HORNER[5]);
    // `p · 2ⁿ` in one instruction where the other paths assemble `2ⁿ` in the exponent
    // bits and multiply: `n` is a whole number in [-126, 0] and `2ⁿ` a normal f32, so
    // both round the same exact product once (the same bits, subnormal results too).
    _mm512_scalef_ps(p, n)
}

/// The lane numbers 0..16.
#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,popcnt")]
fn lane_numbers() -> __m512 {
    _mm512_setr_ps(
        0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0, 11.0, 12.0, 13.0, 14.0, 15.0,
    )
}

/// [`super::RowEntry::lane`] on the 16 lanes of tile row `row` of a kernel (its
/// [`RowBlock`]): `t`, `q` and the mask of the pairs (within `valid`, the lanes inside
/// the image). With `first` 0, `(lane + (0 - offset)) + t_anchor` is `(lane + shift) +
/// t_anchor` (the same value: `lane + -0` is `lane + 0`).
#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,popcnt")]
pub(crate) fn row_lanes(
    kernel: &TileKernel,
    block: &RowBlock,
    row: usize,
    valid: __mmask16,
) -> (__m512, __m512, __mmask16) {
    let t = row_t(block, row);
    let q = _mm512_fmadd_ps(
        _mm512_mul_ps(_mm512_set1_ps(kernel.qxx), t),
        t,
        _mm512_set1_ps(block.row_q[row]),
    );
    let hit = _mm512_mask_cmp_ps_mask::<_CMP_LE_OQ>(valid, q, _mm512_set1_ps(kernel.qmax));
    (t, q, hit)
}

/// The lanes' `t` of [`row_lanes`], alone.
#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,popcnt")]
pub(crate) fn row_t(block: &RowBlock, row: usize) -> __m512 {
    _mm512_add_ps(
        _mm512_add_ps(lane_numbers(), _mm512_set1_ps(block.shift[row])),
        _mm512_set1_ps(block.t_anchor[row]),
    )
}

/// `exp(-½ q)` on 16 lanes as [`super::gaussian`] evaluates it.
#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,popcnt")]
pub(crate) fn gaussian<const FAST: bool>(q: __m512) -> __m512 {
    if FAST {
        return exp_neg_half(q);
    }
    let mut values = [0.0_f32; ROW];
    // SAFETY: `values` holds 16 floats.
    unsafe { _mm512_storeu_ps(values.as_mut_ptr(), q) };
    let values = values.map(|q| (-0.5 * q).exp());
    // SAFETY: as above.
    unsafe { _mm512_loadu_ps(values.as_ptr()) }
}
