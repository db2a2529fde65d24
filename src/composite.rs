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
//! The layout is the additive raster's: the same per-tile set-up ([`crate::simd`]'s
//! `prepare_tile_range`) gives per half row (8 pixels) the entries of the kernels reaching
//! it, in list order, with the same `q` and `G = exp(-½ q)` in f32 (`RowEntry::lane`). A
//! tile's list is set up a chunk at a time (32 kernels, then twice as many each time) and
//! composited onto the half rows still alive, so a tile stops setting up kernels when all
//! its pixels have stopped (how many set-ups that saves: `docs/performance.md`, "The alpha
//! blend"). The chunks build the same lists in the same order as the whole list at once
//! (tested), so the image does not depend on them. `α̂`, `T` and `C` are f64 per lane, so the
//! transmittance's product keeps its precision over long lists and the stop decision
//! follows the f64 model; a half row ends when all its lanes have stopped. The loop is one
//! portable function compiled for each [`SimdPath`] (its fused multiply-adds are the
//! written-out `mul_add`s of `RowEntry::lane` and the exp, and Rust forms no other), so the
//! image is the same bit for bit on every path and thread count.

use rayon::prelude::*;

use std::ops::Range;

use crate::model::Image;
use crate::parallel::{Drain, GroupBuffers};
use crate::simd::{
    BinnedFrame, ExpMode, HalfRow, LANES, ROW, RowEntry, SimdPath, TileKernel, TileScratch,
    half_rows, prepare_tile_range, size_image, stream_tile_rows,
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

/// Starts the set-up of tile `t` in `scratch` ([`TileScratch::start`]): no kernel yet.
#[inline(always)]
pub(crate) fn start_alpha_tile(bins: &TileBins, t: usize, scratch: &mut CompositeScratch) {
    scratch.tile.start(bins.tile_entries(t).len());
    scratch.opacities.clear();
}

/// Sets up the kernels at positions `range` of tile `t`'s list of `frame`
/// ([`prepare_tile_range`]), with the opacity of each tile kernel.
#[inline(always)]
pub(crate) fn prepare_alpha_range(
    frame: &BinnedFrame,
    t: usize,
    range: Range<usize>,
    scratch: &mut CompositeScratch,
) {
    let before = scratch.tile.kernels.len();
    prepare_tile_range(frame.bins, frame.forms, t, range, &mut scratch.tile);
    let entries = frame.bins.tile_entries(t);
    scratch.opacities.extend(
        scratch.tile.entry_of[before..]
            .iter()
            .map(|&n| frame.proj.opacities[entries[n as usize] as usize]),
    );
}

/// The chunks in which a tile's list of `len` kernels is set up: [`FIRST_CHUNK`] kernels,
/// then twice as many as before each time. A tile whose pixels all stop early sets up at
/// most about twice the kernels it reaches (the rest of its list is never read); a tile
/// that reads its whole list takes a few chunks.
pub(crate) fn chunks(len: usize) -> impl Iterator<Item = Range<usize>> {
    let mut start = 0;
    let mut size = FIRST_CHUNK;
    std::iter::from_fn(move || {
        (start < len).then(|| {
            let chunk = start..len.min(start + size);
            start = chunk.end;
            size *= 2;
            chunk
        })
    })
}

/// The first chunk of [`chunks`].
const FIRST_CHUNK: usize = 32;

/// `α̂ = min(0.99, o G)`, `G` the lane's Gaussian (zero when the lane is not a pair).
#[inline(always)]
pub(crate) fn clamped_alpha(opacity: f64, g: f32) -> f64 {
    let alpha = opacity * f64::from(g);
    if alpha < MAX_ALPHA { alpha } else { MAX_ALPHA }
}

/// Composites `frame`'s binned kernels (binned in depth order) into `image` (resized to the
/// bins' size) over its background, on its path. `stops`, when given, receives each
/// pixel's [`PixelStop`] (row-major, for the backward; a frame only looked at needs none,
/// and writing them is 16 bytes a pixel). Returns the number of (pixel, kernel) pairs
/// composited (before each pixel's stop).
///
/// # Panics
/// When the frame's kernels have no opacities.
pub fn composite(
    frame: &BinnedFrame,
    image: &mut Image,
    stops: Option<&mut Vec<PixelStop>>,
) -> u64 {
    check_alpha_frame(frame);
    let pixels = size_image(frame.bins, image);
    let (w, h) = (frame.bins.width as usize, frame.bins.height as usize);
    let composite_band = |ty: usize, band: &mut [f32], band_stops: Option<&mut [PixelStop]>| {
        SCRATCH.with(|cell| {
            let scratch = &mut *cell.borrow_mut();
            tile_row(frame, ty, scratch, band, band_stops)
        })
    };
    let bands = image.pixels.par_chunks_mut(3 * w * ROW).enumerate();
    match stops {
        Some(stops) => {
            stops.clear();
            stops.resize(w * h, PixelStop::default());
            if !pixels {
                return 0;
            }
            bands
                .zip(stops.par_chunks_mut(w * ROW))
                .map(|((ty, band), band_stops)| composite_band(ty, band, Some(band_stops)))
                .sum()
        }
        None if !pixels => 0,
        None => bands.map(|(ty, band)| composite_band(ty, band, None)).sum(),
    }
}

/// [`composite`] without an image: the frame's rows are handed to `drain` in order, a group
/// of tile rows at a time (its first row and its RGB values), while the next group is
/// composited ([`crate::parallel::fill_and_drain_in_order`]); the pixels' stops, which only
/// a backward reads, are not kept. The same values as [`composite`]'s image. Returns the
/// pairs composited, or `drain`'s first error.
///
/// # Panics
/// When the frame's kernels have no opacities.
pub fn composite_in_bands<E: Send>(
    frame: &BinnedFrame,
    groups: &mut GroupBuffers,
    drain: &mut Drain<E>,
) -> Result<u64, E> {
    check_alpha_frame(frame);
    stream_tile_rows(
        frame.bins,
        groups,
        |ty, band| {
            SCRATCH.with(|cell| {
                let scratch = &mut *cell.borrow_mut();
                tile_row(frame, ty, scratch, band, None)
            })
        },
        drain,
    )
}

/// Composites tile row `ty` of `frame` into `band` (its 16 image rows, or fewer at the
/// bottom) and, when given, their pixels' `stops`; returns its pairs.
fn tile_row(
    frame: &BinnedFrame,
    ty: usize,
    scratch: &mut CompositeScratch,
    band: &mut [f32],
    mut stops: Option<&mut [PixelStop]>,
) -> u64 {
    let tiles_x = frame.bins.tiles_x as usize;
    (0..tiles_x)
        .map(|tx| {
            let out = Band {
                pixels: band,
                stops: stops.as_deref_mut(),
            };
            tile(frame, ty * tiles_x + tx, scratch, out)
        })
        .sum()
}

/// Panics when `frame`'s kernels have no opacities.
fn check_alpha_frame(frame: &BinnedFrame) {
    assert_eq!(
        frame.proj.opacities.len(),
        frame.proj.len(),
        "opacities of an alpha frame"
    );
}

/// The image rows of one tile row, and their pixels' stops when they are kept.
pub(crate) struct Band<'a> {
    pixels: &'a mut [f32],
    stops: Option<&'a mut [PixelStop]>,
}

/// [`composite_tile`] compiled for the frame's path.
fn tile(frame: &BinnedFrame, t: usize, scratch: &mut CompositeScratch, band: Band) -> u64 {
    match (frame.path, frame.exp) {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: a frame's path is one the CPU has (`BinnedFrame`).
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
    frame: &BinnedFrame,
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
    frame: &BinnedFrame,
    t: usize,
    scratch: &mut CompositeScratch,
    band: Band,
) -> u64 {
    composite_tile::<FAST, true>(frame, t, scratch, band)
}

/// The state of one half row's compositing: per lane the colour, the transmittance, whether
/// it still takes kernels, and the position of the entry that stopped it.
#[derive(Clone, Copy)]
pub(crate) struct HalfRowState {
    pub(crate) colour: [[f64; LANES]; 3],
    pub(crate) transmittance: [f64; LANES],
    /// Per lane, the entry that stopped it ([`NOT_STOPPED`] until one does).
    pub(crate) end: [u32; LANES],
    /// Per lane, inside the image and not stopped.
    pub(crate) alive: [bool; LANES],
    /// The entries of the half row's list composited so far.
    pub(crate) consumed: usize,
    pub(crate) pairs: u64,
}

/// [`HalfRowState::end`] of a lane no entry has stopped.
pub(crate) const NOT_STOPPED: u32 = u32::MAX;

impl HalfRowState {
    /// Nothing composited yet: `T = 1`, `C = 0`; lanes at or past `lanes` are outside the
    /// image and never alive.
    pub(crate) fn new(lanes: usize) -> Self {
        HalfRowState {
            colour: [[0.0; LANES]; 3],
            transmittance: [1.0; LANES],
            end: [NOT_STOPPED; LANES],
            alive: std::array::from_fn(|i| i < lanes),
            consumed: 0,
            pairs: 0,
        }
    }

    /// Whether a lane still takes kernels.
    pub(crate) fn any_alive(&self) -> bool {
        self.alive.contains(&true)
    }

    /// Each lane's stop: the entry that stopped it, or `len`, the length of the whole list
    /// (entries from there on add nothing to it).
    pub(crate) fn ends(&self, len: usize) -> [u32; LANES] {
        self.end
            .map(|end| if end == NOT_STOPPED { len as u32 } else { end })
    }
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
            use crate::simd::avx2::{gaussian, lane_numbers, lanes as avx2_lanes};
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

/// Composites the entries of one half row's list from `state.consumed` on into `state`
/// (lane `i` is tile pixel `first + i`; lanes at or past `lanes` are outside the image and
/// take nothing), branch-free over the 8 lanes (adding `colour · 0` to a sum that starts at
/// +0 and only grows changes nothing), until every lane has stopped or the list ends.
#[inline(always)]
pub(crate) fn composite_half_row<const FAST: bool, const AVX2: bool>(
    state: &mut HalfRowState,
    entries: &[RowEntry],
    kernels: &[TileKernel],
    opacities: &[f64],
    first: f32,
    lanes: f32,
) {
    if !state.any_alive() {
        return;
    }
    // Worked on in a local (kept in registers), written back once.
    let mut local = *state;
    let from = local.consumed;
    local.consumed = entries.len();
    for (n, entry) in entries.iter().enumerate().skip(from) {
        let kernel = &kernels[entry.kernel as usize];
        let opacity = opacities[entry.kernel as usize];
        let (_, g, hit) = entry_lanes::<FAST, AVX2>(entry, kernel, first, lanes);
        let mut pairs = 0;
        let mut any_alive = false;
        for i in 0..LANES {
            let live = hit[i] & local.alive[i];
            let alpha = clamped_alpha(opacity, g[i]);
            let t = local.transmittance[i];
            let next = t * (1.0 - alpha);
            let stop = live & (next < T_STOP);
            let add = live & !stop;
            let weight = if add { alpha * t } else { 0.0 };
            for c in 0..3 {
                local.colour[c][i] += kernel.amplitude[c] * weight;
            }
            local.transmittance[i] = if add { next } else { t };
            if stop {
                local.end[i] = n as u32;
            }
            local.alive[i] &= !stop;
            any_alive |= local.alive[i];
            pairs += u64::from(live);
        }
        local.pairs += pairs;
        if !any_alive {
            local.consumed = n + 1;
            break;
        }
    }
    *state = local;
}

/// Composites tile `t` half row by half row into `band` (the image rows of its tile row),
/// setting its list up a chunk at a time ([`chunks`]; inlined so that the set-up is
/// compiled for the path too): each chunk's entries are composited onto every half row
/// that still has a lane alive, and the tile stops setting up kernels when none has.
/// Returns the pairs.
#[inline(always)]
fn composite_tile<const FAST: bool, const AVX2: bool>(
    frame: &BinnedFrame,
    t: usize,
    scratch: &mut CompositeScratch,
    mut band: Band,
) -> u64 {
    let (bins, background) = (frame.bins, frame.background);
    let rect = bins.tile_rect(t);
    // Halves wholly past the image's edge keep a state with no lane.
    let mut states = [HalfRowState::new(0); 2 * ROW];
    for half in half_rows(rect) {
        states[half.index] = HalfRowState::new(half.lanes);
    }
    start_alpha_tile(bins, t, scratch);
    for chunk in chunks(bins.tile_entries(t).len()) {
        prepare_alpha_range(frame, t, chunk, scratch);
        let mut any_alive = false;
        for half in half_rows(rect) {
            let state = &mut states[half.index];
            composite_half_row::<FAST, AVX2>(
                state,
                &scratch.tile.halves[half.index],
                &scratch.tile.kernels,
                &scratch.opacities,
                half.first as f32,
                half.lanes as f32,
            );
            any_alive |= state.any_alive();
        }
        if !any_alive {
            break;
        }
    }
    let width = bins.width as usize;
    let mut pairs = 0;
    for HalfRow {
        row,
        index,
        first,
        lanes,
    } in half_rows(rect)
    {
        let state = &states[index];
        pairs += state.pairs;
        let start = row * width + rect[0] as usize + first;
        let out = &mut band.pixels[3 * start..][..3 * lanes];
        for (i, pixel) in out.chunks_exact_mut(3).enumerate() {
            for c in 0..3 {
                pixel[c] = (state.colour[c][i] + state.transmittance[i] * background[c]) as f32;
            }
        }
        if let Some(stops) = band.stops.as_deref_mut() {
            let ends = state.ends(scratch.tile.halves[index].len());
            for (i, stop) in stops[start..start + lanes].iter_mut().enumerate() {
                *stop = PixelStop {
                    transmittance: state.transmittance[i],
                    end: ends[i],
                };
            }
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
        let frame = BinnedFrame::new(
            &context.projected,
            &context.bins,
            &mut forms,
            [0.0; 3],
            ExpMode::Poly,
        );
        let mut scratch = CompositeScratch::default();
        let avx2 = SimdPath::available().contains(&SimdPath::Avx2);
        let (mut stopped, mut pairs) = (0, 0);
        for t in 0..context.bins.tile_count() {
            start_alpha_tile(&context.bins, t, &mut scratch);
            let len = context.bins.tile_entries(t).len();
            prepare_alpha_range(&frame, t, 0..len, &mut scratch);
            for half in half_rows(context.bins.tile_rect(t)) {
                let entries = &scratch.tile.halves[half.index];
                let (first, lanes) = (half.first as f32, half.lanes as f32);
                let (kernels, opacities) = (&scratch.tile.kernels, &scratch.opacities);
                let mut portable = HalfRowState::new(half.lanes);
                composite_half_row::<true, false>(
                    &mut portable,
                    entries,
                    kernels,
                    opacities,
                    first,
                    lanes,
                );
                pairs += portable.pairs;
                stopped += (0..half.lanes)
                    .filter(|&i| portable.end[i] != NOT_STOPPED)
                    .count();
                if !avx2 {
                    continue;
                }
                let mut vector = HalfRowState::new(half.lanes);
                composite_half_row::<true, true>(
                    &mut vector,
                    entries,
                    kernels,
                    opacities,
                    first,
                    lanes,
                );
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

    #[test]
    fn chunks_cover_the_list_in_order_doubling() {
        for len in [0, 1, 31, 32, 33, 95, 96, 97, 1000] {
            let chunks: Vec<_> = chunks(len).collect();
            let mut next = 0;
            for (i, chunk) in chunks.iter().enumerate() {
                assert_eq!(chunk.start, next, "len {len}");
                assert!(chunk.end > chunk.start && chunk.len() <= FIRST_CHUNK << i);
                next = chunk.end;
            }
            assert_eq!(next, len);
        }
    }

    #[test]
    fn a_tile_set_up_in_chunks_has_the_lists_of_its_whole_list() {
        let camera = crate::scenes::synthetic::bench_camera(97, 61);
        let scene = crate::scenes::synthetic::varied_alpha_bench_scene(3000, 5, 0.2);
        let mut context = RenderContext::new();
        context
            .render(&scene, &camera, 0.5, &RenderOptions::default())
            .unwrap();
        let (proj, bins) = (&context.projected, &context.bins);
        let mut forms = Vec::new();
        let frame = BinnedFrame::new(proj, bins, &mut forms, [0.0; 3], ExpMode::Poly);
        let (mut whole, mut chunked) = (CompositeScratch::default(), CompositeScratch::default());
        let mut longest = 0;
        for t in 0..bins.tile_count() {
            let len = bins.tile_entries(t).len();
            longest = longest.max(len);
            start_alpha_tile(bins, t, &mut whole);
            prepare_alpha_range(&frame, t, 0..len, &mut whole);
            start_alpha_tile(bins, t, &mut chunked);
            for chunk in chunks(len) {
                prepare_alpha_range(&frame, t, chunk, &mut chunked);
            }
            assert_eq!(whole.tile.entry_of, chunked.tile.entry_of);
            assert_eq!(whole.opacities, chunked.opacities);
            for (a, b) in whole.tile.halves.iter().zip(&chunked.tile.halves) {
                let key = |e: &RowEntry| {
                    (
                        e.t_anchor.to_bits(),
                        e.offset.to_bits(),
                        e.row_q.to_bits(),
                        e.kernel,
                    )
                };
                assert!(a.iter().map(key).eq(b.iter().map(key)));
            }
        }
        assert!(longest > 3 * FIRST_CHUNK, "some tile takes several chunks");
    }
}
