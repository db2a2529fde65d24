//! Stage 4 of alpha scenes: front-to-back compositing per pixel (SPEC §8), tile-parallel.
//!
//! Per pixel, over its pairs (`q ≤ qmax`, the same test as the additive raster) in the
//! tile's list order, which is depth order ([`crate::colour::order_by_depth`]), with `T = 1`,
//! `C = 0`:
//!
//! ```text
//! α̂  = min(0.99, o(τ) exp(-½ q))
//! T' = T (1 - α̂);  if T' < T_stop: stop        T_stop = 1e-4 (1 + 1e-5)
//! C += colour α̂ T;  T = T'
//! pixel = C + T b
//! ```
//!
//! The layout is the additive raster's ([`crate::raster`]): the same per-tile set-up
//! (`raster::prepare_tile`) gives per half row (8 pixels) the entries of the
//! kernels reaching it, in list order, with the same `q` and `G = exp(-½ q)` in f32
//! (`raster::RowEntry::lane`). `α̂`, `T` and `C` are f64 per lane, so the
//! transmittance's product keeps its precision over long lists and the stop decision
//! follows the f64 model; a half row ends when all its lanes have stopped. The loop is one
//! portable function compiled for each [`SimdPath`] (no fused operation can form: Rust never
//! contracts), so the image is the same bit for bit on every path and thread count.

use rayon::prelude::*;

use crate::model::Image;
use crate::project::ProjectedKernels;
use crate::raster::{
    ExpMode, HalfRow, LANES, ROW, RowEntry, RowForm, SimdPath, TileKernel, TileScratch, half_rows,
    prepare_tile, row_forms,
};
use crate::tiles::TileBins;

/// The largest `α̂` (SPEC §8).
pub const MAX_ALPHA: f64 = 0.99;

/// A pixel stops when its transmittance would fall below this (SPEC §8).
pub const T_STOP: f64 = 1e-4 * (1.0 + 1e-5);

/// What the backward needs of a composited pixel: its final transmittance and the number of
/// its half row's entries it consumed (entries from `end` on add nothing to it).
///
/// SPEC §8: a pixel stops when its transmittance would fall below 1e-4; the backward
/// walks back from here.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PixelStop {
    /// `T` after the last kernel it composited.
    pub transmittance: f64,
    /// The position in its half row's list of the kernel that stopped it, or the list's
    /// length.
    pub end: u32,
}

/// Per-worker scratch: the tile's row entries and each tile kernel's opacity.
#[derive(Default)]
pub(crate) struct CompositeScratch {
    pub(crate) tile: TileScratch,
    pub(crate) opacities: Vec<f64>,
}

thread_local! {
    static SCRATCH: std::cell::RefCell<CompositeScratch> =
        std::cell::RefCell::new(CompositeScratch::default());
}

/// Fills `scratch` for tile `t`: [`prepare_tile`], then the opacity of each tile kernel.
#[inline(always)]
pub(crate) fn prepare_alpha_tile(
    proj: &ProjectedKernels,
    bins: &TileBins,
    forms: &[RowForm],
    t: usize,
    scratch: &mut CompositeScratch,
) {
    prepare_tile(bins, forms, t, &mut scratch.tile);
    let entries = bins.tile_entries(t);
    scratch.opacities.clear();
    scratch.opacities.extend(
        scratch
            .tile
            .entry_of
            .iter()
            .map(|&n| proj.opacities[entries[n as usize] as usize]),
    );
}

/// `α̂ = min(0.99, o G)`, `G` the lane's Gaussian (zero when the lane is not a pair).
#[inline(always)]
pub(crate) fn clamped_alpha(opacity: f64, g: f32) -> f64 {
    let alpha = opacity * f64::from(g);
    if alpha < MAX_ALPHA { alpha } else { MAX_ALPHA }
}

/// Composites the binned kernels (binned in depth order) into `image` (resized to the bins'
/// size) over `background`, on the widest [`SimdPath`] the CPU has. `forms` is scratch for
/// [`row_forms`]; `stops` receives each pixel's [`PixelStop`] (row-major, for the backward).
/// Returns the number of (pixel, kernel) pairs composited (before each pixel's stop).
pub fn composite(
    proj: &ProjectedKernels,
    bins: &TileBins,
    background: [f32; 3],
    exp: ExpMode,
    forms: &mut Vec<RowForm>,
    image: &mut Image,
    stops: &mut Vec<PixelStop>,
) -> u64 {
    composite_on(
        SimdPath::detect(),
        proj,
        bins,
        background,
        exp,
        forms,
        image,
        stops,
    )
}

/// [`composite`] on a chosen path (which the CPU must have: see [`SimdPath::available`]).
///
/// # Panics
/// When the CPU lacks `path`'s instructions.
#[allow(clippy::too_many_arguments)]
pub fn composite_on(
    path: SimdPath,
    proj: &ProjectedKernels,
    bins: &TileBins,
    background: [f32; 3],
    exp: ExpMode,
    forms: &mut Vec<RowForm>,
    image: &mut Image,
    stops: &mut Vec<PixelStop>,
) -> u64 {
    assert!(
        SimdPath::available().contains(&path),
        "this CPU cannot run the {path} path"
    );
    assert_eq!(
        proj.opacities.len(),
        proj.len(),
        "opacities of an alpha frame"
    );
    row_forms(proj, bins, forms);
    let (w, h) = (bins.width as usize, bins.height as usize);
    image.width = bins.width;
    image.height = bins.height;
    if image.pixels.capacity() < 3 * w * h {
        image.pixels = vec![0.0; 3 * w * h];
    } else {
        image.pixels.resize(3 * w * h, 0.0);
    }
    stops.clear();
    stops.resize(w * h, PixelStop::default());
    if w == 0 || h == 0 {
        return 0;
    }
    let frame = AlphaFrame {
        proj,
        bins,
        forms,
        background: background.map(f64::from),
    };
    let tiles_x = bins.tiles_x as usize;
    image
        .pixels
        .par_chunks_mut(3 * w * ROW)
        .zip(stops.par_chunks_mut(w * ROW))
        .enumerate()
        .map(|(ty, (band, band_stops))| {
            SCRATCH.with(|cell| {
                let scratch = &mut *cell.borrow_mut();
                let mut pairs = 0;
                for tx in 0..tiles_x {
                    let t = ty * tiles_x + tx;
                    let out = Band {
                        pixels: band,
                        stops: band_stops,
                    };
                    pairs += tile_on(path, exp, &frame, t, scratch, out);
                }
                pairs
            })
        })
        .sum()
}

/// What every tile of an alpha frame shares.
struct AlphaFrame<'a> {
    proj: &'a ProjectedKernels,
    bins: &'a TileBins,
    forms: &'a [RowForm],
    background: [f64; 3],
}

/// The image rows of one tile row, and their pixels' stops.
pub(crate) struct Band<'a> {
    pixels: &'a mut [f32],
    stops: &'a mut [PixelStop],
}

/// [`composite_tile`] compiled for `path`.
fn tile_on(
    path: SimdPath,
    exp: ExpMode,
    frame: &AlphaFrame,
    t: usize,
    scratch: &mut CompositeScratch,
    band: Band,
) -> u64 {
    match (path, exp) {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `composite_on` checked that the CPU has the path's features.
        (SimdPath::Avx512, ExpMode::Poly) => unsafe {
            composite_tile_avx512::<true>(frame, t, scratch, band)
        },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as above.
        (SimdPath::Avx512, ExpMode::Std) => unsafe {
            composite_tile_avx512::<false>(frame, t, scratch, band)
        },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as above.
        (SimdPath::Avx2, ExpMode::Poly) => unsafe {
            composite_tile_avx2::<true>(frame, t, scratch, band)
        },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as above.
        (SimdPath::Avx2, ExpMode::Std) => unsafe {
            composite_tile_avx2::<false>(frame, t, scratch, band)
        },
        (_, ExpMode::Poly) => composite_tile::<true, false>(frame, t, scratch, band),
        (_, ExpMode::Std) => composite_tile::<false, false>(frame, t, scratch, band),
    }
}

/// [`composite_tile`] compiled for AVX-512 (the f64 lanes in one register; the same
/// operations: the same bits).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma")]
fn composite_tile_avx512<const FAST: bool>(
    frame: &AlphaFrame,
    t: usize,
    scratch: &mut CompositeScratch,
    band: Band,
) -> u64 {
    composite_tile::<FAST, true>(frame, t, scratch, band)
}

/// [`composite_tile`] compiled for AVX2 and FMA (the same operations: the same bits).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn composite_tile_avx2<const FAST: bool>(
    frame: &AlphaFrame,
    t: usize,
    scratch: &mut CompositeScratch,
    band: Band,
) -> u64 {
    composite_tile::<FAST, true>(frame, t, scratch, band)
}

/// The state of one half row after compositing: per lane the colour, the transmittance,
/// and the number of the half row's entries consumed (the entries after it add nothing).
pub(crate) struct HalfRowState {
    pub(crate) colour: [[f64; LANES]; 3],
    pub(crate) transmittance: [f64; LANES],
    /// Per lane, the entry that stopped it, or the list's length.
    pub(crate) end: [u32; LANES],
    pub(crate) pairs: u64,
}

/// One entry's 8 lanes: `t`, `G` (zero where the lane is not a pair) and whether each lane
/// is a pair — [`RowEntry::lane`] lane by lane, or its AVX2 twin (the same operations, so
/// the same bits) when `AVX2`.
#[inline(always)]
pub(crate) fn entry_lanes<const FAST: bool, const AVX2: bool>(
    entry: &RowEntry,
    kernel: &TileKernel,
    first: f32,
    lanes: f32,
) -> ([f32; LANES], [f32; LANES], [bool; LANES]) {
    let mut t = [0.0_f32; LANES];
    let mut g = [0.0_f32; LANES];
    let mut hit = [false; LANES];
    if AVX2 {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: AVX2 is only asked for on the paths whose CPU has it (checked by the
        // callers' dispatch).
        unsafe {
            use crate::raster::avx2::{gaussian, lane_numbers, lanes as avx2_lanes};
            use std::arch::x86_64::*;
            let (t8, q, mask) = avx2_lanes(entry, kernel, lane_numbers(lanes), first);
            let g8 = _mm256_and_ps(gaussian::<FAST>(q), mask);
            _mm256_storeu_ps(t.as_mut_ptr(), t8);
            _mm256_storeu_ps(g.as_mut_ptr(), g8);
            let bits = _mm256_movemask_ps(mask);
            for (i, h) in hit.iter_mut().enumerate() {
                *h = bits & (1 << i) != 0;
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        unreachable!("AVX2 on x86-64 only")
    } else {
        for i in 0..LANES {
            (t[i], g[i], hit[i]) = entry.lane::<FAST>(kernel, first, lanes, i);
        }
    }
    (t, g, hit)
}

/// Composites one half row's entries (lane `i` is tile pixel `first + i`; lanes at or past
/// `lanes` are outside the image and take nothing), branch-free over the 8 lanes (adding
/// `colour · 0` to a sum that starts at +0 and only grows changes nothing).
#[inline(always)]
pub(crate) fn composite_half_row<const FAST: bool, const AVX2: bool>(
    entries: &[RowEntry],
    kernels: &[TileKernel],
    opacities: &[f64],
    first: f32,
    lanes: f32,
) -> HalfRowState {
    let mut state = HalfRowState {
        colour: [[0.0; LANES]; 3],
        transmittance: [1.0; LANES],
        end: [entries.len() as u32; LANES],
        pairs: 0,
    };
    let mut alive: [bool; LANES] = std::array::from_fn(|i| (i as f32) < lanes);
    for (n, entry) in entries.iter().enumerate() {
        let kernel = &kernels[entry.kernel as usize];
        let opacity = opacities[entry.kernel as usize];
        let (_, g, hit) = entry_lanes::<FAST, AVX2>(entry, kernel, first, lanes);
        let mut pairs = 0;
        let mut any_alive = false;
        for i in 0..LANES {
            let live = hit[i] & alive[i];
            let alpha = clamped_alpha(opacity, g[i]);
            let t = state.transmittance[i];
            let next = t * (1.0 - alpha);
            let stop = live & (next < T_STOP);
            let add = live & !stop;
            let weight = if add { alpha * t } else { 0.0 };
            for c in 0..3 {
                state.colour[c][i] += kernel.amplitude[c] * weight;
            }
            state.transmittance[i] = if add { next } else { t };
            if stop {
                state.end[i] = n as u32;
            }
            alive[i] &= !stop;
            any_alive |= alive[i];
            pairs += u64::from(live);
        }
        state.pairs += pairs;
        if !any_alive {
            break;
        }
    }
    state
}

/// Prepares tile `t` ([`prepare_alpha_tile`], inlined so that the set-up is compiled for the
/// path too) and composites it half row by half row into `band` (the image rows of its tile
/// row). Returns the pairs.
#[inline(always)]
fn composite_tile<const FAST: bool, const AVX2: bool>(
    frame: &AlphaFrame,
    t: usize,
    scratch: &mut CompositeScratch,
    band: Band,
) -> u64 {
    let AlphaFrame {
        proj,
        bins,
        forms,
        background,
    } = *frame;
    prepare_alpha_tile(proj, bins, forms, t, scratch);
    let rect = bins.tile_rect(t);
    let width = bins.width as usize;
    let mut pairs = 0;
    for HalfRow {
        row,
        index,
        first,
        lanes,
    } in half_rows(rect)
    {
        let state = composite_half_row::<FAST, AVX2>(
            &scratch.tile.halves[index],
            &scratch.tile.kernels,
            &scratch.opacities,
            first as f32,
            lanes as f32,
        );
        pairs += state.pairs;
        let start = row * width + rect[0] as usize + first;
        let out = &mut band.pixels[3 * start..][..3 * lanes];
        for (i, pixel) in out.chunks_exact_mut(3).enumerate() {
            for c in 0..3 {
                pixel[c] = (state.colour[c][i] + state.transmittance[i] * background[c]) as f32;
            }
        }
        for (i, stop) in band.stops[start..start + lanes].iter_mut().enumerate() {
            *stop = PixelStop {
                transmittance: state.transmittance[i],
                end: state.end[i],
            };
        }
    }
    pairs
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::{RenderContext, RenderOptions};

    #[test]
    fn the_avx2_lanes_composite_what_the_portable_ones_do_bit_for_bit() {
        let camera = crate::scenes::synthetic::bench_camera(97, 61);
        let n = 3000;
        let scene = crate::scenes::synthetic::varied_alpha_bench_scene(n, 5, 0.2);
        let mut context = RenderContext::new();
        let options = RenderOptions::default();
        context.render(&scene, &camera, 0.5, &options).unwrap();
        let mut forms = Vec::new();
        row_forms(&context.projected, &context.bins, &mut forms);
        let mut scratch = CompositeScratch::default();
        let avx2 = SimdPath::available().contains(&SimdPath::Avx2);
        let (mut stopped, mut pairs) = (0, 0);
        for t in 0..context.bins.tile_count() {
            prepare_alpha_tile(&context.projected, &context.bins, &forms, t, &mut scratch);
            for half in half_rows(context.bins.tile_rect(t)) {
                let entries = &scratch.tile.halves[half.index];
                let (first, lanes) = (half.first as f32, half.lanes as f32);
                let (kernels, opacities) = (&scratch.tile.kernels, &scratch.opacities);
                let portable =
                    composite_half_row::<true, false>(entries, kernels, opacities, first, lanes);
                pairs += portable.pairs;
                stopped += (0..half.lanes)
                    .filter(|&i| (portable.end[i] as usize) < entries.len())
                    .count();
                if !avx2 {
                    continue;
                }
                let vector =
                    composite_half_row::<true, true>(entries, kernels, opacities, first, lanes);
                assert_eq!((portable.pairs, portable.end), (vector.pairs, vector.end));
                for i in 0..LANES {
                    assert_eq!(
                        portable.transmittance[i].to_bits(),
                        vector.transmittance[i].to_bits()
                    );
                    for c in 0..3 {
                        assert_eq!(
                            portable.colour[c][i].to_bits(),
                            vector.colour[c][i].to_bits()
                        );
                    }
                }
            }
        }
        assert!(
            pairs > 10_000 && stopped > 50,
            "{pairs} pairs, {stopped} lanes stopped"
        );
    }
}
