//! Stage 4: the additive sum per pixel (SPEC §5, Eq. 2), tile-parallel.
//!
//! ```text
//! C(p, τ) = b + Σ_i [q_i(p) ≤ qmax_i] a_i(τ) exp(-½ q_i(p))
//! ```
//!
//! in ascending kernel order, no sorting and no compositing.
//!
//! **Layout of the work.** A tile row is the vector: half of it (8 pixels) on the AVX2 and
//! baseline paths, all 16 pixels on AVX-512. Per tile, each listed kernel is set up once in
//! f64 from its row form and joins the list of every row (or half row) its padded ellipse
//! reaches at a pixel centre ([`crate::simd`]: the row forms, the tile set-up and the
//! lanes both blends share). Then rows outer, kernels inner: per row, accumulators (RGB) stay
//! in registers **in f64** while every entry of the row passes over them, and the row is
//! rounded to f32 and written straight into the image. Tile rows (bands of 16 image rows) run
//! in parallel; every pixel adds the same terms in the same order whatever the number of
//! threads. A frame going straight to a file needs no image: [`rasterize_in_bands`] sums
//! groups of tile rows into two reused buffers and hands each group to the encoder while the
//! next is summed, the same values. The backward ([`crate::backward::raster`]) evaluates the
//! same pairs.
//!
//! **Per pixel** (SPEC §5, precision): `q`, the test `q ≤ qmax` and `G = exp(-½ q)` are f32
//! (`crate::simd`'s `RowEntry`); each term `a_c · G` is an exact f64 product added to the f64
//! sum, so the error does not grow with the number of kernels on a pixel. A tile without
//! kernels is the background, `b + 0` rounded to f32, written without a set-up.
//!
//! **Paths**, one file each, with the same operations in the same order (the rule of
//! [`crate::simd`]), so every path gives the same image bit for bit (tested on every path
//! the CPU has):
//!
//! | file | path | what |
//! |---|---|---|
//! | `portable` | baseline (and AVX2's walk) | a tile's half rows, each summed over its entries by the portable loop or its AVX2 twin |
//! | `avx2` | AVX2 + FMA | the half-row loop with intrinsics, four entries' `G` at a time |
//! | `avx512` | AVX-512 | whole rows of 16 lanes, four entries' `G` at a time; `G` kept for a training step's backward |
//! | `whole_rows` | AVX-512 | the tile set up by whole rows (`TileBlocks`) and the kept `G` (`KeptGaussians`) |
//!
//! A whole row's list is the union of its two half lists in the same order, and the lanes of
//! a half a kernel does not reach add exact zeros, so the AVX-512 rows give the half rows'
//! bits. [`crate::bench::ceiling_probe`] is the ideal loop the renderer is measured against,
//! compiled for the same path; where the rest of the ceiling goes, measured, is in
//! `docs/performance.md` ("The ceiling probe and the raster").

#[cfg(target_arch = "x86_64")]
mod avx2;
#[cfg(target_arch = "x86_64")]
mod avx512;
mod portable;
mod whole_rows;

use rayon::prelude::*;

use crate::model::Image;
use crate::parallel::{Drain, GroupBuffers};
use crate::simd::{BinnedFrame, ROW, SimdPath, TileScratch, size_image, stream_tile_rows};

pub(crate) use whole_rows::{KeptGaussians, TileBlocks, prepare_whole_rows};

/// Scratch of one worker of the additive raster: the tile set up by half rows, or by whole
/// rows on the AVX-512 path, and that path's kept `G`.
#[derive(Default)]
pub(crate) struct RasterScratch {
    /// The half-row set-up (baseline and AVX2 paths).
    pub(crate) tile: TileScratch,
    /// The AVX-512 loops' form of the tile.
    pub(crate) whole_rows: TileBlocks,
    /// The AVX-512 forward's `G` of the tile, kept for its backward in a training step.
    pub(crate) kept: KeptGaussians,
}

/// The forward's per-tile scratch, owned by the render context and kept between frames: a
/// stack of scratches from which each band of tiles takes one while it runs (as many as
/// bands ran at once, so one per worker thread), its buffers keeping their capacity.
#[derive(Default)]
pub struct TileScratchPool {
    free: std::sync::Mutex<Vec<RasterScratch>>,
}

impl std::fmt::Debug for TileScratchPool {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let free = self.free.lock().map_or(0, |free| free.len());
        write!(f, "TileScratchPool {{ {free} scratches }}")
    }
}

impl TileScratchPool {
    /// Runs `work` with a scratch of the pool (a fresh one when all are in use).
    fn with<R>(&self, work: impl FnOnce(&mut RasterScratch) -> R) -> R {
        let taken = self
            .free
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .pop();
        let mut scratch = taken.unwrap_or_default();
        let result = work(&mut scratch);
        self.free
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .push(scratch);
        result
    }
}

/// Sums `frame`'s binned kernels into `image` (resized to the bins' size) over its
/// background, on its path, with a scratch of `pool` per worker. Returns the number of
/// (pixel, kernel) pairs summed.
pub fn rasterize(frame: &BinnedFrame, pool: &TileScratchPool, image: &mut Image) -> u64 {
    let w = frame.bins.width as usize;
    if !size_image(frame.bins, image) {
        return 0;
    }
    // Tile rows (bands of 16 image rows) in parallel: each writes only its own rows.
    image
        .pixels
        .par_chunks_mut(3 * w * ROW)
        .enumerate()
        .map(|(ty, band)| tile_row(frame, pool, ty, band))
        .sum()
}

/// [`rasterize`] without an image: the frame's rows are handed to `drain` in order, a
/// group of tile rows at a time (its first row and its RGB values), while the next group is
/// summed ([`crate::parallel::fill_and_drain_in_order`]). The same values as
/// [`rasterize`]'s image, in two groups' memory. Returns the pairs, or `drain`'s first
/// error.
pub fn rasterize_in_bands<E: Send>(
    frame: &BinnedFrame,
    pool: &TileScratchPool,
    groups: &mut GroupBuffers,
    drain: &mut Drain<E>,
) -> Result<u64, E> {
    stream_tile_rows(
        frame.bins,
        groups,
        |ty, band| tile_row(frame, pool, ty, band),
        drain,
    )
}

/// Sums tile row `ty` of `frame` into `band` (its 16 image rows, or fewer at the bottom)
/// with a scratch of `pool`; returns its pairs. A run of tiles without kernels is the
/// background, written as such ([`fill_background`]) without setting the tiles up.
fn tile_row(frame: &BinnedFrame, pool: &TileScratchPool, ty: usize, band: &mut [f32]) -> u64 {
    let tiles_x = frame.bins.tiles_x as usize;
    let first = ty * tiles_x;
    let empty = |tx: usize| frame.bins.tile_entries(first + tx).is_empty();
    pool.with(|scratch| {
        let (mut pairs, mut tx) = (0, 0);
        while tx < tiles_x {
            if empty(tx) {
                let end = (tx..tiles_x).find(|&x| !empty(x)).unwrap_or(tiles_x);
                let width = frame.bins.width as usize;
                let columns = tx * ROW..(end * ROW).min(width);
                fill_background(frame.background, (columns, width), band);
                tx = end;
            } else {
                pairs += tile::<false>(frame, first + tx, scratch, band);
                tx += 1;
            }
        }
        pairs
    })
}

/// Writes `background` into the pixel columns `columns` of every row of `band` (whole rows
/// of `width` RGB pixels), as a tile without kernels would: its f64 sum with no term,
/// `b + 0` (which makes a background of −0 a +0, as the loops do), rounded to f32. The first
/// row's span is written pixel by pixel, the others copied from it.
fn fill_background(
    background: [f64; 3],
    (columns, width): (std::ops::Range<usize>, usize),
    band: &mut [f32],
) {
    let pixel = background.map(|b| (b + 0.0) as f32);
    let span = 3 * columns.start..3 * columns.end;
    let mut lines = band.chunks_exact_mut(3 * width.max(1));
    if let Some(line) = lines.next() {
        for value in line[span.clone()].chunks_exact_mut(3) {
            value.copy_from_slice(&pixel);
        }
        let written: &[f32] = &line[span.clone()];
        for line in lines {
            line[span.clone()].copy_from_slice(written);
        }
    }
}

/// Prepares tile `t` of `frame` into `scratch` and sums it into `band` (the image rows of
/// its tile row), as [`rasterize`] does; the set-up stays in `scratch` for a backward of the
/// same tile ([`crate::backward::raster`]), and on the AVX-512 path its `G` too
/// ([`KeptGaussians`]). Returns the pairs.
pub(crate) fn forward_tile(
    frame: &BinnedFrame,
    t: usize,
    scratch: &mut RasterScratch,
    band: &mut [f32],
) -> u64 {
    tile::<true>(frame, t, scratch, band)
}

/// Prepares and sums tile `t` into `band` with the loops compiled for the frame's path,
/// keeping the AVX-512 path's `G` when `KEEP`.
fn tile<const KEEP: bool>(
    frame: &BinnedFrame,
    t: usize,
    scratch: &mut RasterScratch,
    band: &mut [f32],
) -> u64 {
    use crate::simd::ExpMode::{Poly, Std};
    match (frame.path, frame.exp) {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: a frame's path is one the CPU has (`BinnedFrame`).
        (SimdPath::Avx512, Poly) => unsafe { avx512::tile::<true, KEEP>(frame, t, scratch, band) },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as above.
        (SimdPath::Avx512, Std) => unsafe { avx512::tile::<false, KEEP>(frame, t, scratch, band) },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as above.
        (SimdPath::Avx2, Poly) => unsafe { tile_avx2::<true>(frame, t, &mut scratch.tile, band) },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as above.
        (SimdPath::Avx2, Std) => unsafe { tile_avx2::<false>(frame, t, &mut scratch.tile, band) },
        (_, Poly) => portable::tile::<true, false>(frame, t, &mut scratch.tile, band),
        (_, Std) => portable::tile::<false, false>(frame, t, &mut scratch.tile, band),
    }
}

/// [`portable::tile`] compiled for AVX2 and FMA, its half rows summed by [`avx2`]'s loop.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn tile_avx2<const FAST: bool>(
    frame: &BinnedFrame,
    t: usize,
    scratch: &mut TileScratch,
    band: &mut [f32],
) -> u64 {
    portable::tile::<FAST, true>(frame, t, scratch, band)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::simd::ExpMode;

    #[test]
    fn tiles_without_kernels_are_the_background_a_tile_set_up_would_give() {
        use crate::render::{RenderContext, RenderOptions};
        // A few kernels in one corner: most tiles are empty, in runs, with partial tiles at
        // the right and the bottom. Every path, and backgrounds of −0 (written +0) and
        // other values, against each tile set up and summed ([`forward_tile`]).
        let (w, h) = (165, 83);
        let camera = crate::scenes::synthetic::bench_camera(w, h);
        let kernels: Vec<_> = (0..40)
            .map(|i| {
                let x = -0.9 + 0.01 * f64::from(i);
                crate::model::scene::Kernel::new([x, 0.5, 0.0, 0.5], [0.05; 4], [0.3, 0.2, 0.1])
            })
            .collect();
        let scene = crate::model::Scene::from_kernels(&kernels, [0.0; 3], "test").unwrap();
        let mut context = RenderContext::new();
        let stats = context
            .render(&scene, &camera, 0.5, &RenderOptions::default())
            .unwrap();
        let (proj, bins) = (&context.projected, &context.bins);
        let tiles = bins.tiles_x as usize * bins.tiles_y as usize;
        let empty = (0..tiles)
            .filter(|&t| bins.tile_entries(t).is_empty())
            .count();
        assert!(
            stats.pairs > 0 && empty > tiles / 2 && empty < tiles,
            "{empty} of {tiles}"
        );
        for background in [[-0.0, 0.25, -0.0], [0.1, -0.2, 3e-39]] {
            for &path in SimdPath::available() {
                let mut forms = Vec::new();
                let frame =
                    BinnedFrame::new(proj, bins, &mut forms, background, ExpMode::Poly).on(path);
                let pool = TileScratchPool::default();
                let mut image = Image::default();
                let pairs = rasterize(&frame, &pool, &mut image);
                let mut expected = Image::filled(w, h, [f32::NAN; 3]);
                let mut scratch = RasterScratch::default();
                let mut expected_pairs = 0;
                for (ty, band) in expected.pixels.chunks_mut(3 * w as usize * ROW).enumerate() {
                    for tx in 0..bins.tiles_x as usize {
                        let t = ty * bins.tiles_x as usize + tx;
                        expected_pairs += forward_tile(&frame, t, &mut scratch, band);
                    }
                }
                assert_eq!(pairs, expected_pairs, "{path}");
                let bits = |i: &Image| i.pixels.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
                assert!(bits(&image) == bits(&expected), "{path}, {background:?}");
                assert_eq!(image.pixels[0].to_bits(), (background[0] + 0.0).to_bits());
            }
        }
    }

    #[test]
    fn every_simd_path_gives_the_same_image_bit_for_bit() {
        use crate::render::{RenderContext, RenderOptions};
        let paths = SimdPath::available();
        eprintln!("paths on this CPU: {paths:?}");
        // Partial tiles on the right (1 and 11 columns: a half with no lane, and one with
        // some lanes past the edge) and at the bottom.
        // The last case makes the order of each pixel's sum show in its f32 value: every
        // kernel comes three times in a row, the same ellipse with amplitudes +1e12 and
        // -1e12 around a small one, so a small term added between the two large ones loses
        // its low bits and one added after them does not.
        for ((w, h), n, cutoff, exp, cancelling) in [
            ((161, 97), 3000, 1.0 / 255.0, ExpMode::Poly, false),
            ((171, 83), 3000, 1.0 / 255.0, ExpMode::Poly, false),
            ((161, 97), 300, 0.0, ExpMode::Poly, false),
            ((161, 97), 500, 1.0 / 255.0, ExpMode::Std, false),
            ((161, 97), 600, 1.0 / 255.0, ExpMode::Poly, true),
        ] {
            let camera = crate::scenes::synthetic::bench_camera(w, h);
            let mut scene = crate::scenes::synthetic::bench_scene(n, 5);
            if cancelling {
                let kernels: Vec<_> = (0..n)
                    .flat_map(|i| {
                        let small = scene.kernel(i);
                        let mut large = scene.kernel((i + 1) % n);
                        large.amplitude = large.amplitude.map(|a| a * 1e12);
                        let mut cancel = large;
                        cancel.amplitude = large.amplitude.map(|a| -a);
                        [large, small, cancel]
                    })
                    .collect();
                scene = crate::model::Scene::from_kernels(&kernels, [0.0; 3], "test").unwrap();
            }
            let options = RenderOptions {
                cutoff,
                exp,
                ..RenderOptions::default()
            };
            let mut context = RenderContext::new();
            context.render(&scene, &camera, 0.5, &options).unwrap();
            let (proj, bins) = (&context.projected, &context.bins);
            let mut forms = Vec::new();
            let frame = BinnedFrame::new(proj, bins, &mut forms, [0.1, 0.2, 0.3], exp);
            let pool = TileScratchPool::default();
            let mut first: Option<(Image, u64)> = None;
            for &path in paths {
                let mut image = Image::default();
                let pairs = rasterize(&frame.on(path), &pool, &mut image);
                assert!(pairs > 0);
                match &first {
                    None => first = Some((image, pairs)),
                    Some((reference, reference_pairs)) => {
                        assert_eq!(pairs, *reference_pairs, "{path}: pairs");
                        assert!(
                            image
                                .pixels
                                .iter()
                                .zip(&reference.pixels)
                                .all(|(a, b)| a.to_bits() == b.to_bits()),
                            "{path} differs from {}",
                            paths[0]
                        );
                    }
                }
            }
        }
    }
}
