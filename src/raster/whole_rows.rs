//! The AVX-512 form of a tile: whole rows of 16 lanes, the same pairs as the half rows
//! (SPEC §5). Per tile kernel its [`RowBlock`] (its constants on the tile's 16 rows, from
//! [`crate::simd::kernel_rows`] as the half-row set-up computes them) and a mask of the
//! rows it reaches; per row, the list of the tile kernels on it, built from the masks 16
//! kernels at a time. The forward of a training step keeps each (tile kernel, row)'s `G`
//! and pair mask here ([`KeptGaussians`]) for the backward of the same tile, which reads
//! them instead of evaluating `q` and the exp again.

use crate::simd::{ROW, RowBlock, TileKernel};
#[cfg(target_arch = "x86_64")]
use crate::simd::{RowForm, TileGeometry, kernel_rows, prefetch_form};
#[cfg(target_arch = "x86_64")]
use crate::tiles::TileBins;

/// The AVX-512 loops' form of a prepared tile: per tile kernel its [`RowBlock`] (the tile's
/// 16 rows) and, per row, the tile kernels whose padded ellipse reaches a pixel centre of
/// that row, in list order — the union of the row's two half lists of
/// [`crate::simd::prepare_tile`], held as indices so that a kernel's rows are written once,
/// as a block, and the lists are built from the kernels' row masks 16 kernels at a time.
#[derive(Default)]
pub(crate) struct TileBlocks {
    pub(crate) kernels: Vec<TileKernel>,
    /// For each of `kernels`, its position in the tile's list (`TileBins::tile_entries`).
    pub(crate) entry_of: Vec<u32>,
    /// Per tile kernel, its rows (rows of the tile, 0 to 15).
    pub(crate) blocks: Vec<RowBlock>,
    /// Per tile kernel, bit `r` set when it is listed on row `r` (padded with zeros to a
    /// multiple of 16 when the lists are built).
    pub(crate) masks: Vec<u32>,
    /// Per row of the tile, its tile kernels in ascending order.
    pub(crate) rows: [Vec<u32>; ROW],
}

/// `G` of every (tile kernel, row) the AVX-512 forward evaluated — zero where a lane is not
/// a pair — and the row's pair mask, kernel-major (`16 k + row`): a training step's
/// backward of the same tile reads them instead of evaluating `q` and `exp(-½ q)` again (the
/// same values, so the same bits). Only the rows a kernel is listed on are written, and only
/// those are read.
#[derive(Default)]
pub(crate) struct KeptGaussians {
    pub(crate) values: Vec<[f32; ROW]>,
    pub(crate) hits: Vec<u16>,
}

impl KeptGaussians {
    /// Room for `kernels` tile kernels (grown, never shrunk nor cleared: what a tile writes
    /// is all it reads).
    #[inline(always)]
    pub(super) fn make_room(&mut self, kernels: usize) {
        if self.values.len() < ROW * kernels {
            self.values.resize(ROW * kernels, [0.0; ROW]);
            self.hits.resize(ROW * kernels, 0);
        }
    }
}

/// Prepares tile `t` by whole rows into `tiles`: per kernel its [`RowBlock`] of the
/// tile's 16 rows and its row mask (the rows whose padded chord reaches a pixel centre
/// of either half, within its box), then per row the list of kernels whose mask has
/// the row, 16 kernels at a time (compressed indices, in ascending order). A row's
/// list is the union of its two half lists of [`crate::simd::prepare_tile`] in the same
/// order, so summing it gives the same bits: a lane that no half list holds is never a
/// pair, and adds an exact zero. Without `LISTS` the row lists are left as they were
/// (the backward walks each kernel's mask instead).
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,popcnt")]
pub(crate) fn prepare_whole_rows<const LISTS: bool>(
    bins: &TileBins,
    forms: &[RowForm],
    t: usize,
    tiles: &mut TileBlocks,
) {
    use std::arch::x86_64::*;
    let tile = TileGeometry::of(bins, t);
    let [_, _, ty0, ty1] = tile.rect;
    tiles.kernels.clear();
    tiles.entry_of.clear();
    tiles.masks.clear();
    // No list outlives its tile (the lists of rows past the image, or all of them
    // without `LISTS`, stay empty).
    for list in &mut tiles.rows {
        list.clear();
    }
    let entries = bins.tile_entries(t);
    if tiles.blocks.len() < entries.len() {
        tiles.blocks.resize(entries.len(), RowBlock::default());
    }
    for (n, &p) in entries.iter().enumerate() {
        prefetch_form(forms, entries, n);
        let form = &forms[p as usize];
        // Written in the next free block, which the next kernel overwrites unless this
        // one is kept.
        let block = &mut tiles.blocks[tiles.kernels.len()];
        let reach = kernel_rows(form, &tile, ty0, block);
        // The rows reached, as a mask read in one load (reading the flags one by one
        // stalled on the vector store that wrote them), within the kernel's rows.
        // SAFETY: each array holds 16 bools, one byte each.
        let (left, right) = unsafe {
            (
                _mm_loadu_si128(reach.left.as_ptr().cast()),
                _mm_loadu_si128(reach.right.as_ptr().cast()),
            )
        };
        let either = _mm_or_si128(left, right);
        let reached = u32::from(_mm_test_epi8_mask(either, either));
        let below = |row: u32| (1_u32 << (row - ty0)) - 1;
        let mask = reached & below(reach.end_row) & !below(reach.first_row);
        if mask != 0 {
            tiles.kernels.push(form.pixel);
            tiles.entry_of.push(n as u32);
            tiles.masks.push(mask);
        }
    }
    if !LISTS {
        return;
    }
    let count = tiles.masks.len();
    tiles.masks.resize(count.next_multiple_of(ROW), 0);
    let iota = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
    for (r, list) in tiles.rows[..(ty1 - ty0) as usize].iter_mut().enumerate() {
        // Each chunk stores 16 indices and keeps those of its kernels on the row.
        list.reserve(count + ROW);
        let out = list.as_mut_ptr();
        let bit = _mm512_set1_epi32(1 << r);
        let mut len = 0;
        for (c, chunk) in tiles.masks.chunks_exact(ROW).enumerate() {
            // SAFETY: the chunk holds 16 u32.
            let masks = unsafe { _mm512_loadu_si512(chunk.as_ptr().cast()) };
            let on_row = _mm512_test_epi32_mask(masks, bit);
            let indices = _mm512_add_epi32(iota, _mm512_set1_epi32((ROW * c) as i32));
            // SAFETY: `len` ≤ 16 c, and the list has room for `count + 16` ≥ 16 (c + 1).
            unsafe {
                _mm512_storeu_si512(
                    out.add(len).cast(),
                    _mm512_maskz_compress_epi32(on_row, indices),
                );
            }
            len += on_row.count_ones() as usize;
        }
        // SAFETY: the first `len` are written, each below `count`.
        unsafe { list.set_len(len) };
    }
}
