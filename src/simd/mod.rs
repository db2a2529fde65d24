//! What stage 4 of either blend and its backward share, on every instruction-set path:
//! the paths, `exp(-½ q)`, the row forms, the tile set-up and the frame they read
//! (SPEC §5, precision; §8 for the alpha blend, which walks the same rows).
//!
//! **The rule.** A per-pixel loop is written once portably and, where it is hot, again with
//! AVX2 intrinsics (8 lanes) or AVX-512 intrinsics (16), with the same operations in the same
//! order; code that is not written with intrinsics (the tile set-up, the compositor) is one
//! portable body compiled for each path (`#[target_feature]` copies), chosen at run time
//! ([`SimdPath`]). The f32 steps that fuse a product with a sum (`q`'s last step, the exp's
//! range reduction and Horner steps) are `mul_add` in the portable code and FMA instructions
//! in the SIMD code, each rounding once, and the compiler forms no other; the f64
//! accumulation's FMA rounds like `acc + a G` because `a G` is exact; every conversion is
//! exact. So every path gives the same values bit for bit, and only the vector width
//! differs. A [`BinnedFrame`] carries the path its loops run on; its constructors check that
//! the CPU has it, and every `unsafe` call of a path's loops relies on that check; `on_path`
//! (a portable loop compiled for each path, as the training SSIM's line loops are) checks on
//! every call.
//!
//! | file | what |
//! |---|---|
//! | `path` | [`SimdPath`]: the paths this CPU runs, the widest chosen (`SPLAT4D_SIMD` names a narrower one); `on_path`: a portable loop compiled for each |
//! | `exp` | [`ExpMode`] and [`fast_exp_neg_half`]: `exp(-½ q)` in f32, by libm or by an inlined polynomial |
//! | `rows` | [`RowForm`]s (per kernel, once per frame) and a kernel's constants on the 16 rows of a tile; `RowEntry`: one kernel on one row, and its lanes' `t`, `q` and `G` |
//! | `tile` | the half-row set-up of a tile: per half row (8 pixels) the entries of the kernels whose padded ellipse reaches it, in list order |
//! | `frame` | [`BinnedFrame`], what stage 4 reads; the image's rows, written whole or handed out in bands |
//! | `avx2`, `avx512` | the lanes with intrinsics: the exp, `t`, `q` and the pair test on 8 and 16 lanes |
//!
//! The additive sum over these rows is [`crate::raster`], the front-to-back compositing
//! [`crate::composite`], their backwards [`crate::backward::raster`] and
//! [`crate::backward::composite`]; the ideal loops they are measured against,
//! [`crate::bench::ceiling`], take the exp from here too.

mod exp;
mod frame;
mod path;
mod rows;
mod tile;

#[cfg(target_arch = "x86_64")]
pub(crate) mod avx2;
#[cfg(target_arch = "x86_64")]
pub(crate) mod avx512;

pub use exp::{ExpMode, fast_exp_neg_half};
pub(crate) use exp::{exp_constants, gaussian};
pub use frame::BinnedFrame;
pub(crate) use frame::{read_planes, size_image, stream_tile_rows, write_planes};
pub use path::SimdPath;
pub(crate) use path::{LineJob, on_path};
pub(crate) use rows::{RowBlock, RowEntry, TileGeometry, TileKernel, kernel_rows, prefetch_form};
pub use rows::{RowForm, row_forms};
pub(crate) use tile::{HalfRow, TileScratch, half_rows, prepare_tile, prepare_tile_range};

use crate::tiles::TILE_SIZE;

/// Pixels of one tile row: the vector of the AVX-512 loops.
pub(crate) const ROW: usize = TILE_SIZE as usize;

/// Pixels of one half tile row: the vector the half-row loops work on (8 f32 lanes, one
/// AVX2 register; the additive raster's accumulators, 3 × 8 f64, fit in registers beside the
/// exp's constants).
pub(crate) const LANES: usize = ROW / 2;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_simd_path_gives_the_scalar_exp_bit_for_bit() {
        // Dense over [0, 200] (past the clamp), then every 65537th bit pattern of a
        // non-negative f32 (infinity and NaN included).
        let mut qs = Vec::new();
        let mut q = 0.0_f32;
        while q <= 200.0 {
            qs.push(q);
            q = (q + 1e-3).max(q.next_up());
        }
        qs.extend((0..0x7fff_ffff_u32).step_by(65_537).map(f32::from_bits));
        qs.resize(qs.len().next_multiple_of(ROW), 0.0);
        let scalar: Vec<u32> = qs.iter().map(|&q| fast_exp_neg_half(q).to_bits()).collect();
        for &path in SimdPath::available() {
            let mut values = vec![0.0_f32; qs.len()];
            for (q, g) in qs.chunks_exact(ROW).zip(values.chunks_exact_mut(ROW)) {
                match path {
                    #[cfg(target_arch = "x86_64")]
                    // SAFETY: `available` lists only paths this CPU runs; 16 floats each.
                    SimdPath::Avx512 => unsafe {
                        use std::arch::x86_64::{_mm512_loadu_ps, _mm512_storeu_ps};
                        let e = avx512::exp_neg_half(_mm512_loadu_ps(q.as_ptr()));
                        _mm512_storeu_ps(g.as_mut_ptr(), e);
                    },
                    #[cfg(target_arch = "x86_64")]
                    // SAFETY: as above, two halves of 8.
                    SimdPath::Avx2 => unsafe {
                        use std::arch::x86_64::{_mm256_loadu_ps, _mm256_storeu_ps};
                        for h in [0, 8] {
                            let e = avx2::exp_neg_half(_mm256_loadu_ps(q[h..].as_ptr()));
                            _mm256_storeu_ps(g[h..].as_mut_ptr(), e);
                        }
                    },
                    _ => g
                        .iter_mut()
                        .zip(q)
                        .for_each(|(g, &q)| *g = fast_exp_neg_half(q)),
                }
            }
            let differing = values
                .iter()
                .zip(&scalar)
                .zip(&qs)
                .find(|((g, s), _)| g.to_bits() != **s);
            assert!(differing.is_none(), "{path:?}: {differing:?}");
        }
    }
}
