//! The rows of a kernel, as every per-pixel loop reads them (SPEC §5: the quadratic form `q`
//! of each pixel row, from the conic of SPEC §4).
//!
//! With `Δv` a row's offset from the kernel's centre, `q = Qxx t² + Δv²/Σ2yy` with
//! `t = Δu + k Δv` (see [`crate::project`]). Per kernel, once per frame, its [`RowForm`]
//! holds the f64 constants of its rows, so that setting it up on a tile needs no division or
//! square root; per tile, [`kernel_rows`] computes its 16 rows at once, branch-free, in f64:
//! which rows (and halves) its padded ellipse reaches at a pixel centre
//! ([`crate::tiles::padded_qmax`]), and per row the constants of a [`RowEntry`]. `t` at the
//! tile pixel nearest the ellipse's centre line is rounded once from f64, and the other lanes
//! add exact integer steps; `q`, the test `q ≤ qmax` (which alone decides each pair: lanes
//! outside the ellipse add zero) and `G = exp(-½ q)` are f32 ([`RowEntry::lane`]).

use super::{LANES, ROW, gaussian};
use crate::project::ProjectedKernels;
use crate::tiles::{TileBins, padded_qmax};

/// Per projected kernel, the f64 constants of its rows (from [`ProjectedKernels`]; computed
/// once per frame so that the per-(kernel, tile) setup needs no division or square root).
///
/// SPEC §5: the quadratic form `q` of each pixel row, from the conic of SPEC §4.
#[derive(Clone, Copy, Debug, Default)]
pub struct RowForm {
    /// `m2`.
    mean: [f64; 2],
    /// `Qxx`.
    qxx: f64,
    /// `k = -Σ2xy/Σ2yy`: the centre line is `centre(Δv) = m2x - k Δv`.
    shear: f64,
    /// `1/Σ2yy`.
    inv_syy: f64,
    /// [`padded_qmax`]: rows and tiles are kept for this slightly larger cut-off.
    q_reach: f64,
    /// The kernel's pixel box (from the bins), so that a tile reads one record per kernel.
    pub(crate) bounds: [u32; 4],
    /// What the per-pixel loop needs.
    pub(crate) pixel: TileKernel,
}

/// Fills `forms` for `proj` binned in `bins` (in parallel; the values do not depend on the
/// thread count).
pub fn row_forms(proj: &ProjectedKernels, bins: &TileBins, forms: &mut Vec<RowForm>) {
    crate::parallel::fill_in_parallel(forms, proj.len(), |p| {
        let [_, sxy, syy] = proj.covariances[p];
        RowForm {
            mean: proj.means[p],
            qxx: proj.conics[p][0],
            shear: -sxy / syy,
            inv_syy: 1.0 / syy,
            q_reach: padded_qmax(proj.qmax[p]),
            bounds: bins.pixel_bounds[p],
            pixel: TileKernel {
                qxx: proj.conics[p][0] as f32,
                qmax: proj.qmax[p] as f32,
                amplitude: proj.amplitudes[p].map(f64::from),
            },
        }
    });
}

/// A kernel of the tile being summed: what every row of it shares.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct TileKernel {
    /// `Qxx`, f32.
    pub(crate) qxx: f32,
    /// `qmax` (may be `+∞`).
    pub(crate) qmax: f32,
    /// `a(τ)`, widened to f64 (exactly) for the f64 products.
    pub(crate) amplitude: [f64; 3],
}

/// One kernel on one row of the tile: lane `i` (pixel `x0 + i`) has
/// `t = ((i - offset) + t_anchor)`, `q = Qxx t² + row_q`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct RowEntry {
    /// `t` at the anchor pixel (the tile pixel nearest the ellipse's centre line), rounded
    /// once from f64: a thin ellipse multiplies this rounding by its large `Qxx`, so it is
    /// taken where `|t|` is smallest; the other lanes add exact integers.
    pub(crate) t_anchor: f32,
    /// The anchor's lane, as f32 (exact).
    pub(crate) offset: f32,
    /// `Δv²/Σ2yy`, the row's part of `q`.
    pub(crate) row_q: f32,
    /// `Δv`, the row's offset from the centre (for the backward's moments).
    pub(crate) dv: f32,
    /// Index into the tile's [`TileKernel`]s.
    pub(crate) kernel: u32,
}

impl RowEntry {
    /// Lane `i` of a half row whose lane 0 is tile pixel `first` and whose first `lanes`
    /// lanes are inside the image: `t`, and `G = exp(-½ q)` when the pair is summed (`q ≤
    /// qmax` inside the image), else 0 with `false`. The forward and the backward both
    /// evaluate pairs through here (and [`super::avx2::lanes`], the same operations), so they see
    /// the same pairs and the same `t` and `G`.
    #[inline(always)]
    pub(crate) fn lane<const FAST: bool>(
        &self,
        kernel: &TileKernel,
        first: f32,
        lanes: f32,
        i: usize,
    ) -> (f32, f32, bool) {
        let lane = i as f32;
        // Lane i is tile pixel first + i: its offset from the anchor is exact.
        let t = (lane + (first - self.offset)) + self.t_anchor;
        // One rounding for the product and the sum, as the SIMD paths' FMA.
        let q = (kernel.qxx * t).mul_add(t, self.row_q);
        let hit = q <= kernel.qmax && lane < lanes;
        let value = gaussian::<FAST>(q);
        (t, if hit { value } else { 0.0 }, hit)
    }
}

/// A tile's pixel geometry, for the per-kernel set-up.
#[derive(Clone, Copy)]
pub(crate) struct TileGeometry {
    /// The tile's pixel rectangle `[x0, x1, y0, y1]`.
    pub(crate) rect: [u32; 4],
    /// Its left pixel edge, as f64.
    x0: f64,
    /// The last lane inside the image.
    last_lane: f64,
    /// Pixel centres of the first and last lane of each half of a tile row.
    half_ends: [(f64, f64); 2],
}

impl TileGeometry {
    #[inline(always)]
    pub(crate) fn of(bins: &TileBins, t: usize) -> Self {
        let rect @ [tx0, tx1, _, _] = bins.tile_rect(t);
        let last_lane = f64::from(tx1 - tx0 - 1);
        let x0 = f64::from(tx0);
        TileGeometry {
            rect,
            x0,
            last_lane,
            half_ends: [
                (x0 + 0.5, x0 + (LANES as f64 - 0.5).min(last_lane + 0.5)),
                (x0 + LANES as f64 + 0.5, x0 + last_lane + 0.5),
            ],
        }
    }
}

/// One kernel's constants on 16 consecutive rows of a tile, as the per-pixel loops read
/// them ([`RowEntry`]'s fields by row; the AVX-512 loops read them here).
#[derive(Clone, Copy, Debug, Default)]
#[repr(C, align(64))]
pub(crate) struct RowBlock {
    pub(crate) t_anchor: [f32; ROW],
    /// Minus [`RowEntry::offset`] (exact): `t = (lane + shift) + t_anchor` takes it as it is.
    pub(crate) shift: [f32; ROW],
    pub(crate) row_q: [f32; ROW],
    pub(crate) dv: [f32; ROW],
}

/// Which of a kernel's 16 rows (from [`kernel_rows`]) reach a pixel centre of the left and
/// of the right half, and its rows `[first, end)` of the tile (absolute image rows).
pub(crate) struct RowReach {
    pub(crate) left: [bool; ROW],
    pub(crate) right: [bool; ROW],
    pub(crate) first_row: u32,
    pub(crate) end_row: u32,
}

/// `form`'s constants on the 16 rows from image row `j0` of the tile `tile` into `block`,
/// all at once and branch-free (vectorised); f64 throughout, no division or square root.
/// Rows outside the kernel's box are computed too (the caller drops them).
// `r` indexes the row offsets, the flags and the block's four arrays alike.
#[allow(clippy::needless_range_loop)]
#[inline(always)]
pub(crate) fn kernel_rows(
    form: &RowForm,
    tile: &TileGeometry,
    j0: u32,
    block: &mut RowBlock,
) -> RowReach {
    const ROW_OFFSETS: [f64; ROW] = {
        let mut offsets = [0.0; ROW];
        let mut r = 0;
        while r < ROW {
            offsets[r] = r as f64;
            r += 1;
        }
        offsets
    };
    let max = |a: f64, b: f64| if a > b { a } else { b };
    let min = |a: f64, b: f64| if a < b { a } else { b };
    let [tx0, tx1, ty0, ty1] = tile.rect;
    let (x0, last_lane, half_ends) = (tile.x0, tile.last_lane, tile.half_ends);
    let [bx0, bx1, by0, by1] = form.bounds;
    // Pixel centres of the tile within the kernel's box, per half row.
    let (left, right) = (f64::from(bx0.max(tx0)) + 0.5, f64::from(bx1.min(tx1)) - 0.5);
    let (from0, to0) = (max(half_ends[0].0, left), min(half_ends[0].1, right));
    let (from1, to1) = (max(half_ends[1].0, left), min(half_ends[1].1, right));
    let (open0, open1) = (from0 <= to0, from1 <= to1);
    let [mx, my] = form.mean;
    let j0 = f64::from(j0);
    let mut reach = RowReach {
        left: [false; ROW],
        right: [false; ROW],
        first_row: by0.max(ty0),
        end_row: by1.min(ty1),
    };
    for r in 0..ROW {
        let dv = (j0 + ROW_OFFSETS[r]) + 0.5 - my;
        let row_q = dv * dv * form.inv_syy;
        let room = form.q_reach - row_q;
        // The chord of the row is centre ± √(room/Qxx): it reaches a pixel centre of a
        // half row when the nearest one is within it.
        let centre = mx - form.shear * dv;
        let gap0 = max(max(from0 - centre, centre - to0), 0.0);
        let gap1 = max(max(from1 - centre, centre - to1), 0.0);
        reach.left[r] = open0 & (form.qxx * gap0 * gap0 <= room);
        reach.right[r] = open1 & (form.qxx * gap1 * gap1 <= room);
        let anchor = min(max(centre.floor() - x0, 0.0), last_lane);
        block.t_anchor[r] = (x0 + anchor + 0.5 - centre) as f32;
        block.shift[r] = -(anchor as f32);
        block.row_q[r] = row_q as f32;
        block.dv[r] = dv as f32;
    }
    reach
}

/// Kernels are met in scene order, scattered in memory: asks for the record of the one 8
/// places after `n` now (a hint only; no effect on results).
#[inline(always)]
pub(crate) fn prefetch_form(forms: &[RowForm], entries: &[u32], n: usize) {
    #[cfg(target_arch = "x86_64")]
    if let Some(&ahead) = entries.get(n + 8) {
        // SAFETY: prefetching never faults; the pointer is in bounds anyway.
        unsafe {
            use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
            _mm_prefetch::<_MM_HINT_T0>(forms.as_ptr().add(ahead as usize).cast());
        }
    }
}
