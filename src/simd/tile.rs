//! A tile set up by half rows (8 pixels), as the half-row loops of both blends and their
//! backwards walk it (SPEC §5: the pairs `q ≤ qmax` of a tile's pixels, with the ellipse
//! padded so that no pair is missed): per half row, the entries ([`RowEntry`]) of the
//! tile's kernels whose padded ellipse reaches a pixel centre of it inside the tile (and
//! the kernel's box), in the tile's list order (ascending kernel order for the additive
//! blend, depth order for the alpha blend). Each kernel is set up once per tile
//! ([`super::kernel_rows`], f64, no division or square root) and its row constants written
//! at the end of every list and kept by advancing the length: no branch per row. Set up a
//! range of the list at a time, the lists are the same as the whole list's at once, so that
//! a compositor can stop setting up kernels when its pixels stop. The AVX-512 loops take
//! the same kernels by whole rows (`crate::raster::TileBlocks`).

use super::rows::{
    RowBlock, RowEntry, RowForm, TileGeometry, TileKernel, kernel_rows, prefetch_form,
};
use super::{LANES, ROW};
use crate::tiles::TileBins;

/// One half row of a tile, as the forward and the backward walk them.
#[derive(Clone, Copy, Debug)]
pub(crate) struct HalfRow {
    /// Its row in the tile.
    pub(crate) row: usize,
    /// Its index in [`TileScratch::halves`] (`2 row + half`).
    pub(crate) index: usize,
    /// The tile pixel of its lane 0 (0 or [`LANES`]).
    pub(crate) first: usize,
    /// Its lanes inside the image (the rest are past the right edge).
    pub(crate) lanes: usize,
}

/// The half rows of the tile `[tx0, tx1, ty0, ty1]`, row by row, left half first; a half
/// wholly past the image's right edge is left out.
#[inline(always)]
pub(crate) fn half_rows([tx0, tx1, ty0, ty1]: [u32; 4]) -> impl Iterator<Item = HalfRow> {
    let tile_width = (tx1 - tx0) as usize;
    (0..(ty1 - ty0) as usize).flat_map(move |row| {
        (0..2)
            .map(move |half| half * LANES)
            .filter(move |&first| first < tile_width)
            .map(move |first| HalfRow {
                row,
                index: 2 * row + first / LANES,
                first,
                lanes: (tile_width - first).min(LANES),
            })
    })
}

/// Scratch of one worker: the current tile's kernels and, per half row of the tile (row
/// `r`, half `h` at index `2 r + h`), its entries in ascending kernel order.
#[derive(Default)]
pub(crate) struct TileScratch {
    pub(crate) kernels: Vec<TileKernel>,
    /// For each of `kernels`, its position in the tile's list (`TileBins::tile_entries`).
    pub(crate) entry_of: Vec<u32>,
    pub(crate) halves: [Vec<RowEntry>; 2 * ROW],
}

/// Fills `scratch` with tile `t`'s kernels and, per half row of the tile, the entries of the
/// kernels whose padded ellipse reaches a pixel centre of that half row inside the tile (and
/// its box): [`TileScratch::start`], then [`prepare_tile_range`] over the whole list.
#[inline(always)]
pub(crate) fn prepare_tile(
    bins: &TileBins,
    forms: &[RowForm],
    t: usize,
    scratch: &mut TileScratch,
) {
    let kernels = bins.tile_entries(t).len();
    scratch.start(kernels);
    prepare_tile_range(bins, forms, t, 0..kernels, scratch);
}

impl TileScratch {
    /// Empties the scratch for a tile of `kernels` list entries, each half row's list with
    /// room for all of them.
    #[inline(always)]
    pub(crate) fn start(&mut self, kernels: usize) {
        self.kernels.clear();
        self.entry_of.clear();
        // A list takes at most one entry per kernel of the tile: with that room made first,
        // an entry is written at the end of every list its row might join and kept by
        // advancing the length when it does (no branch per row).
        for half in &mut self.halves {
            half.clear();
            half.reserve(kernels);
        }
    }
}

/// Appends the kernels at positions `range` of tile `t`'s list to `scratch` (started by
/// [`TileScratch::start`] with the whole list's length): each joins the list of every half
/// row its padded ellipse reaches at a pixel centre inside the tile (and its box). Ranges
/// taken in order build the same lists as the whole list at once, so that a compositor can
/// set up a tile's kernels a chunk at a time and stop when its pixels do. f64 throughout; no
/// division or square root. Inlined into each path's compiled copy, so that its 16-row loop
/// is vectorised there (the f64 results are the same on every path). The rows come from
/// [`kernel_rows`] (shared with the AVX-512 set-up).
#[inline(always)]
pub(crate) fn prepare_tile_range(
    bins: &TileBins,
    forms: &[RowForm],
    t: usize,
    range: std::ops::Range<usize>,
    scratch: &mut TileScratch,
) {
    let tile = TileGeometry::of(bins, t);
    let ty0 = tile.rect[2];
    let entries = bins.tile_entries(t);
    // Each list takes at most one entry per kernel of the range: checked here once, so that
    // the appends below need no check (`start` makes the room).
    assert!(
        scratch
            .halves
            .iter()
            .all(|half| half.capacity() - half.len() >= range.len()),
        "TileScratch::start reserves room for the tile's list"
    );
    let mut block = RowBlock::default();
    for (n, &p) in entries.iter().enumerate().take(range.end).skip(range.start) {
        prefetch_form(forms, entries, n);
        let form = &forms[p as usize];
        // The rows from the kernel's first row in the tile; rows past `end_row` are
        // computed and ignored.
        let first_row = form.bounds[2].max(ty0);
        let reach = kernel_rows(form, &tile, first_row, &mut block);
        let kernel = scratch.kernels.len() as u32;
        let mut used = false;
        let mut append = |list: &mut Vec<RowEntry>, entry: RowEntry, keep: bool| {
            let len = list.len();
            debug_assert!(len < list.capacity());
            // SAFETY: the list had room for one entry per kernel of the range (asserted
            // above) and takes at most one of this kernel; the new length covers only
            // written entries.
            unsafe {
                list.as_mut_ptr().add(len).write(entry);
                list.set_len(len + usize::from(keep));
            }
            used |= keep;
        };
        for r in 0..(reach.end_row - reach.first_row) as usize {
            let entry = RowEntry {
                t_anchor: block.t_anchor[r],
                offset: -block.shift[r],
                row_q: block.row_q[r],
                dv: block.dv[r],
                kernel,
            };
            let row = (reach.first_row - ty0) as usize + r;
            append(&mut scratch.halves[2 * row], entry, reach.left[r]);
            append(&mut scratch.halves[2 * row + 1], entry, reach.right[r]);
        }
        if used {
            scratch.kernels.push(form.pixel);
            scratch.entry_of.push(n as u32);
        }
    }
}
