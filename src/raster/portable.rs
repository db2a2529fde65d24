//! The half-row paths (baseline and AVX2) of the additive sum (SPEC §5, Eq. 2, and its
//! precision): a tile is set up by half rows ([`crate::simd::prepare_tile`]) and each half
//! row (8 pixels) summed over its entries: three f64 accumulators of 8 lanes start at the
//! background, `+ 0` (which makes a background of −0 a +0, so that adding a lane's zero or
//! skipping it cannot change a sign), and take `a_c · G` (an exact f64 product of f32
//! values) for every entry in ascending kernel order; the half row is then rounded to f32
//! and written in place. The loop over the entries is written here portably
//! ([`sum_half_row`]) and with AVX2 intrinsics in `super::avx2`, the same operations in the
//! same order.

use crate::simd::{
    BinnedFrame, HalfRow, LANES, RowEntry, TileKernel, TileScratch, half_rows, prepare_tile,
    write_planes,
};
use crate::tiles::TileBins;

/// [`prepare_tile`] then [`sum_tile`], inlined into each path's compiled copy (the
/// baseline's, and AVX2's with `AVX2`).
#[inline(always)]
pub(super) fn tile<const FAST: bool, const AVX2: bool>(
    frame: &BinnedFrame,
    t: usize,
    scratch: &mut TileScratch,
    band: &mut [f32],
) -> u64 {
    prepare_tile(frame.bins, frame.forms, t, scratch);
    sum_tile::<FAST, AVX2>(frame.bins, t, frame.background, scratch, band)
}

/// Sums the entries of one half row into `acc` (set to the background first; `+ 0.0` makes
/// a background of -0 a +0, so that adding a lane's zero or skipping it cannot change a
/// sign). Lane `i` is pixel `first + i` of the tile row; lanes at or beyond `lanes` (past the
/// image's edge) never count. Returns the pairs.
#[inline(always)]
fn sum_half_row<const FAST: bool>(
    entries: &[RowEntry],
    kernels: &[TileKernel],
    first: f32,
    lanes: f32,
    background: [f64; 3],
    acc: &mut [[f64; LANES]; 3],
) -> u64 {
    for (channel, &b) in acc.iter_mut().zip(&background) {
        *channel = [b + 0.0; LANES];
    }
    let mut pairs = 0_u64;
    for entry in entries {
        let kernel = &kernels[entry.kernel as usize];
        let mut g = [0.0_f32; LANES];
        let mut inside = 0_u32;
        for (i, g) in g.iter_mut().enumerate() {
            let (_, value, hit) = entry.lane::<FAST>(kernel, first, lanes, i);
            *g = value;
            inside += u32::from(hit);
        }
        pairs += u64::from(inside);
        for (channel, &a) in acc.iter_mut().zip(&kernel.amplitude) {
            for i in 0..LANES {
                channel[i] += a * f64::from(g[i]);
            }
        }
    }
    pairs
}

/// Sums the prepared tile `t` half row by half row into `band` (the image rows of its tile
/// row): per half row, three f64 accumulators of 8 lanes start at the background and take
/// `a_c · G` (an exact f64 product of f32 values) for every entry, in ascending kernel
/// order; the half row is then rounded to f32 and written in place.
#[inline(always)]
fn sum_tile<const FAST: bool, const AVX2: bool>(
    bins: &TileBins,
    t: usize,
    background: [f64; 3],
    scratch: &TileScratch,
    band: &mut [f32],
) -> u64 {
    let rect = bins.tile_rect(t);
    let width = bins.width as usize;
    let mut pairs = 0_u64;
    for HalfRow {
        row,
        index,
        first,
        lanes,
    } in half_rows(rect)
    {
        let mut acc = [[0.0_f64; LANES]; 3];
        let entries = &scratch.halves[index];
        let (first_lane, lanes_f) = (first as f32, lanes as f32);
        pairs += if AVX2 {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: AVX2 is only asked for on the AVX2 path, which the frame's CPU has
            // (`BinnedFrame`).
            unsafe {
                super::avx2::sum_half_row::<FAST>(
                    entries,
                    &scratch.kernels,
                    first_lane,
                    lanes_f,
                    background,
                    &mut acc,
                )
            }
            #[cfg(not(target_arch = "x86_64"))]
            unreachable!("AVX2 on x86-64 only")
        } else {
            sum_half_row::<FAST>(
                entries,
                &scratch.kernels,
                first_lane,
                lanes_f,
                background,
                &mut acc,
            )
        };
        let out = &mut band[3 * (row * width + rect[0] as usize + first)..][..3 * lanes];
        write_planes(&acc, out);
    }
    pairs
}
