//! Stage 3: bin projected ellipses into 16×16 pixel tiles (counting sort, no depth order).
//!
//! A kernel goes to every tile whose pixel centres the ellipse `q ≤ qmax` may reach, not to
//! every tile of its bounding box. The box (SPEC §5: `|Δu| ≤ √(qmax Σ2xx)`,
//! `|Δv| ≤ √(qmax Σ2yy)`, clipped to the image) gives the tile rows; within each tile row
//! the ellipse's horizontal extent over that row band gives the tile columns. With
//! `q = Qxx (Δu + k Δv)² + Δv²/Σ2yy`, row `Δv`'s chord is
//!
//! ```text
//! centre(Δv) ± √((qmax - Δv²/Σ2yy) / Qxx),   centre(Δv) = m2x + (Σ2xy/Σ2yy) Δv
//! ```
//!
//! whose right end is concave in `Δv` with its maximum `m2x + √(qmax Σ2xx)` at
//! `Δv* = √qmax Σ2xy/√Σ2xx` (the left end mirrors it at `-Δv*`). So over a band of rows the
//! extent is the ellipse's own when `±Δv*` falls inside the band and the chord of the band's
//! end row nearest to it otherwise: the very row the raster evaluates, so the test is exact
//! up to rounding (a margin of 1e-9 relative covers that). A tilted ellipse thus skips the
//! corner tiles of its box. Everything is taken for a slightly larger cut-off,
//! [`padded_qmax`], so that no pixel whose f32 test in the raster stage could pass is left
//! out; which pairs are summed is decided by that per-pixel test alone, never by the tiles. Within each tile the kernels are listed in
//! ascending scene order (the fill pass runs in that order), which makes every pixel's sum
//! order, and so the image, independent of threads.

use crate::parallel::fill_in_parallel;
use crate::project::ProjectedKernels;

/// Tile side in pixels.
pub const TILE_SIZE: u32 = 16;

/// The cut-off used for bounds: a little above `qmax` (relative 2e-4, absolute 2e-4), wider
/// than the band `|q - qmax| ≤ 1e-4 max(1, qmax)` in which implementations may differ.
#[must_use]
pub fn padded_qmax(qmax: f64) -> f64 {
    qmax * (1.0 + 2e-4) + 2e-4
}

/// The pixels `i` in `[lo, hi)` whose centres satisfy `|i + 0.5 - centre| ≤ half_width`, as a
/// half-open range, or `None` when there are none (or the inputs are NaN).
#[must_use]
pub fn pixel_span(centre: f64, half_width: f64, lo: u32, hi: u32) -> Option<(u32, u32)> {
    let (from, to) = (centre - half_width - 0.5, centre + half_width - 0.5);
    if from.is_nan() || to.is_nan() || lo >= hi {
        return None;
    }
    // `⌈from⌉` and `⌊to⌋` clipped to the pixels: with both ends clamped to `[lo - 1, hi]`
    // first (whole numbers, so clamping commutes with rounding), the roundings are exact in
    // i64, where the library's `ceil` and `floor` are calls without SSE4.1.
    let (lo_f, hi_f) = (f64::from(lo), f64::from(hi));
    let first = ceil_small(from.clamp(lo_f, hi_f));
    let last = floor_small(to.clamp(lo_f - 1.0, hi_f - 1.0));
    (first <= last).then(|| (first as u32, last as u32 + 1))
}

/// `⌈x⌉` for `|x| < 2^53`.
fn ceil_small(x: f64) -> i64 {
    let t = x as i64;
    t + i64::from((t as f64) < x)
}

/// `⌊x⌋` for `|x| < 2^53`.
fn floor_small(x: f64) -> i64 {
    let t = x as i64;
    t - i64::from((t as f64) > x)
}

/// Kernel lists per tile, as offsets into one flat array (CSR layout).
///
/// SPEC §5: a kernel is listed on every 16×16 tile its cut-off ellipse reaches.
#[derive(Clone, Debug, Default)]
pub struct TileBins {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Tiles per row.
    pub tiles_x: u32,
    /// Tile rows.
    pub tiles_y: u32,
    /// Per projected kernel: its pixel rectangle `[x0, x1, y0, y1]` (half-open, clipped to
    /// the image; empty when it misses the image).
    pub pixel_bounds: Vec<[u32; 4]>,
    /// Tile `t` lists `proj_from_entry[tile_offsets[t]..tile_offsets[t + 1]]`.
    pub tile_offsets: Vec<u32>,
    /// Projected-kernel indices, grouped by tile, ascending within a tile.
    pub proj_from_entry: Vec<u32>,
    /// Scratch: per tile row (band of 16 pixel rows), the kernels reaching it with their
    /// tile columns, ascending by kernel (CSR by `band_offsets`); per tile row its tile
    /// counts; per chunk of kernels its count per tile row.
    band_offsets: Vec<u32>,
    band_reaches: Vec<Reach>,
    band_tile_counts: Vec<Vec<u32>>,
    chunk_band_counts: Vec<u32>,
}

/// A kernel reaching a tile row: its index and the tile columns `first..end` (empty when its
/// box covers the row but its ellipse does not).
#[derive(Clone, Copy, Debug, Default)]
struct Reach {
    kernel: u32,
    first: u32,
    end: u32,
}

/// Kernels per chunk of the per-kernel passes.
const CHUNK: usize = 1024;

impl TileBins {
    /// Number of tiles.
    #[must_use]
    pub fn tile_count(&self) -> usize {
        self.tiles_x as usize * self.tiles_y as usize
    }

    /// The projected kernels listed in tile `t`.
    #[must_use]
    pub fn tile_entries(&self, t: usize) -> &[u32] {
        &self.proj_from_entry[self.tile_offsets[t] as usize..self.tile_offsets[t + 1] as usize]
    }

    /// How many projected kernels some tile lists: the kernels whose cut-off ellipse reaches
    /// a pixel block of the image (SPEC §5), not those merely in front of the camera.
    #[must_use]
    pub fn kernels_listed(&self) -> usize {
        let mut listed = vec![false; self.pixel_bounds.len()];
        for &p in &self.proj_from_entry {
            listed[p as usize] = true;
        }
        listed.iter().filter(|&&l| l).count()
    }

    /// The pixel rectangle `[x0, x1, y0, y1]` (half-open) of tile `t`, clipped to the image.
    #[must_use]
    pub fn tile_rect(&self, t: usize) -> [u32; 4] {
        let (tx, ty) = (
            (t % self.tiles_x as usize) as u32,
            (t / self.tiles_x as usize) as u32,
        );
        [
            tx * TILE_SIZE,
            ((tx + 1) * TILE_SIZE).min(self.width),
            ty * TILE_SIZE,
            ((ty + 1) * TILE_SIZE).min(self.height),
        ]
    }
}

/// Bins `proj` for a `width × height` image into `out`, reusing its buffers. Every pass is
/// parallel and reads the kernels in order: per kernel its box; per chunk of kernels how
/// many reach each tile row; per chunk, each kernel's tile columns on each of its tile rows
/// (one ellipse–tile-row test) written into the rows' lists; per tile row a counting sort of
/// its kernels by tile, straight into the tiles' lists. The lists are the same whatever the
/// number of threads.
pub fn bin(proj: &ProjectedKernels, width: u32, height: u32, out: &mut TileBins) {
    out.width = width;
    out.height = height;
    out.tiles_x = width.div_ceil(TILE_SIZE);
    out.tiles_y = height.div_ceil(TILE_SIZE);
    pixel_boxes(proj, width, height, out);
    count_band_reaches(proj.len(), out);
    fill_band_reaches(proj, out);
    sort_reaches_by_tile(out);
}

/// Pass 1: per kernel, its pixel box (empty off the image).
fn pixel_boxes(proj: &ProjectedKernels, width: u32, height: u32, out: &mut TileBins) {
    let n = proj.len();
    fill_in_parallel(&mut out.pixel_bounds, n, |p| {
        let [mx, my] = proj.means[p];
        let [sxx, _, syy] = proj.covariances[p];
        let q = padded_qmax(proj.qmax[p]);
        match (
            pixel_span(mx, (q * sxx).sqrt(), 0, width),
            pixel_span(my, (q * syy).sqrt(), 0, height),
        ) {
            (Some((x0, x1)), Some((y0, y1))) => [x0, x1, y0, y1],
            _ => [0, 0, 0, 0],
        }
    });
}

/// The tile rows a kernel's pixel box `[x0, x1, y0, y1]` covers.
fn band_range([x0, x1, y0, y1]: [u32; 4]) -> std::ops::Range<usize> {
    if x0 >= x1 || y0 >= y1 {
        0..0
    } else {
        (y0 / TILE_SIZE) as usize..y1.div_ceil(TILE_SIZE) as usize
    }
}

/// Pass 2: per chunk of kernels, how many reach each tile row; the rows' offsets.
fn count_band_reaches(n: usize, out: &mut TileBins) {
    use rayon::prelude::*;
    let tiles_y = out.tiles_y as usize;
    let pixel_bounds = &out.pixel_bounds;
    // Per chunk of kernels, how many reach each tile row.
    let chunks = n.div_ceil(CHUNK);
    let chunk_band_counts = &mut out.chunk_band_counts;
    chunk_band_counts.clear();
    chunk_band_counts.resize(chunks * tiles_y, 0);
    chunk_band_counts
        .par_chunks_mut(tiles_y.max(1))
        .enumerate()
        .for_each(|(c, counts)| {
            for &bounds in &pixel_bounds[c * CHUNK..((c + 1) * CHUNK).min(n)] {
                for band in band_range(bounds) {
                    counts[band] += 1;
                }
            }
        });
    let count = |c: usize, band: usize| chunk_band_counts[c * tiles_y + band] as usize;
    out.band_offsets.clear();
    out.band_offsets.push(0);
    for band in 0..tiles_y {
        let reaching: usize = (0..chunks).map(|c| count(c, band)).sum();
        out.band_offsets
            .push(out.band_offsets[band] + reaching as u32);
    }
}

/// Pass 3: each kernel's tile columns on each of its tile rows, into the rows' lists.
fn fill_band_reaches(proj: &ProjectedKernels, out: &mut TileBins) {
    use rayon::prelude::*;
    let tiles_y = out.tiles_y as usize;
    let n = proj.len();
    let chunks = n.div_ceil(CHUNK);
    let count = |c: usize, band: usize| out.chunk_band_counts[c * tiles_y + band] as usize;
    // Each chunk writes its kernels' reaches into its own part of every tile row's list:
    // the lists are laid out by tile row, then chunk, then kernel.
    out.band_reaches.clear();
    out.band_reaches
        .resize(out.band_offsets[tiles_y] as usize, Reach::default());
    let mut parts: Vec<Vec<&mut [Reach]>> =
        (0..chunks).map(|_| Vec::with_capacity(tiles_y)).collect();
    let mut rest = out.band_reaches.as_mut_slice();
    for band in 0..tiles_y {
        for (c, part) in parts.iter_mut().enumerate() {
            let (head, tail) = rest.split_at_mut(count(c, band));
            part.push(head);
            rest = tail;
        }
    }
    let pixel_bounds = &out.pixel_bounds;
    parts.into_par_iter().enumerate().for_each(|(c, mut rows)| {
        let mut filled = vec![0_usize; tiles_y];
        let first = c * CHUNK;
        for (p, &bounds) in (first..).zip(&pixel_bounds[first..(first + CHUNK).min(n)]) {
            for_each_tile_row(proj, p, bounds, |ty, columns| {
                let ty = ty as usize;
                rows[ty][filled[ty]] = Reach {
                    kernel: p as u32,
                    first: columns.start,
                    end: columns.end,
                };
                filled[ty] += 1;
            });
        }
    });
}

/// Pass 4: per tile row, a counting sort of its kernels by tile, into the tiles' lists.
fn sort_reaches_by_tile(out: &mut TileBins) {
    use rayon::prelude::*;
    let (tiles_x, tiles_y) = (out.tiles_x as usize, out.tiles_y as usize);
    // Per tile row, its entries per tile; the rows' totals give each its part of the tiles'
    // lists.
    out.band_tile_counts.resize_with(tiles_y, Vec::new);
    let (band_offsets, band_reaches) = (&out.band_offsets, &out.band_reaches);
    let reaches_of =
        |ty: usize| &band_reaches[band_offsets[ty] as usize..band_offsets[ty + 1] as usize];
    out.band_tile_counts
        .par_iter_mut()
        .enumerate()
        .for_each(|(ty, counts)| {
            // A reach of tiles `first..end` adds one to each: as a difference, +1 at
            // `first` and -1 at `end` (wrapping: the running sums are the counts, whole),
            // then summed twice, into the counts and into their running totals.
            counts.clear();
            counts.resize(tiles_x + 2, 0);
            for reach in reaches_of(ty) {
                counts[reach.first as usize + 1] = counts[reach.first as usize + 1].wrapping_add(1);
                counts[reach.end as usize + 1] = counts[reach.end as usize + 1].wrapping_sub(1);
            }
            counts.pop();
            for tx in 0..tiles_x {
                counts[tx + 1] = counts[tx + 1].wrapping_add(counts[tx]);
            }
            for tx in 0..tiles_x {
                counts[tx + 1] += counts[tx];
            }
        });
    out.tile_offsets.clear();
    out.tile_offsets.resize(tiles_x * tiles_y + 1, 0);
    let mut total = 0_u32;
    for (ty, counts) in out.band_tile_counts.iter().enumerate() {
        for tx in 0..tiles_x {
            out.tile_offsets[ty * tiles_x + tx + 1] = total + counts[tx + 1];
        }
        total += counts[tiles_x];
    }
    out.proj_from_entry.clear();
    out.proj_from_entry.resize(total as usize, 0);
    let mut rest = out.proj_from_entry.as_mut_slice();
    let mut rows = Vec::with_capacity(tiles_y);
    for (ty, counts) in out.band_tile_counts.iter_mut().enumerate() {
        let (head, tail) = rest.split_at_mut(counts[tiles_x] as usize);
        rows.push((ty, head, counts));
        rest = tail;
    }
    rows.into_par_iter().for_each(|(ty, entries, counts)| {
        // `counts[tx]` is where tile tx's next entry goes within the row.
        for reach in reaches_of(ty) {
            let (first, end) = (reach.first as usize, reach.end as usize);
            for slot in &mut counts[first..end] {
                entries[*slot as usize] = reach.kernel;
                *slot += 1;
            }
        }
    });
}

/// Calls `visit(ty, tx0..tx1)` for each tile row `ty` of projected kernel `p`'s pixel
/// rectangle `bounds`, in order, with the tile columns its ellipse reaches there (see the
/// module docs; an empty range when it reaches none).
fn for_each_tile_row(
    proj: &ProjectedKernels,
    p: usize,
    [x0, x1, y0, y1]: [u32; 4],
    mut visit: impl FnMut(u32, std::ops::Range<u32>),
) {
    if x0 >= x1 || y0 >= y1 {
        return;
    }
    let box_columns = x0 / TILE_SIZE..x1.div_ceil(TILE_SIZE);
    let [mx, my] = proj.means[p];
    let [sxx, sxy, syy] = proj.covariances[p];
    let qxx = proj.conics[p][0];
    let q = padded_qmax(proj.qmax[p]);
    let reach_x = (q * sxx).sqrt();
    // `√q Σ2xy/√Σ2xx`, with the one square root.
    let dv_star = sxy * (reach_x / sxx);
    let shear = sxy / syy;
    // The chord's ends on row offset `dv`: `half² = (q - dv²/Σ2yy) / Qxx`, with the two
    // quotients taken once per kernel.
    let (half_sq_at_centre, half_sq_per_dv_sq) = (q / qxx, 1.0 / (syy * qxx));
    let chord = |dv: f64| {
        let half = (half_sq_at_centre - dv * dv * half_sq_per_dv_sq)
            .max(0.0)
            .sqrt();
        let centre = mx + shear * dv;
        (centre - half, centre + half)
    };
    for ty in y0 / TILE_SIZE..y1.div_ceil(TILE_SIZE) {
        // Pixel rows of this tile row that the kernel's box covers, as offsets from m2y.
        let first = (ty * TILE_SIZE).max(y0);
        let last = ((ty + 1) * TILE_SIZE).min(y1) - 1;
        let (dv_lo, dv_hi) = (f64::from(first) + 0.5 - my, f64::from(last) + 0.5 - my);
        // The band's extremes: the ellipse's own where `±Δv*` falls in the band (the clamp
        // leaves it as it is), else the chord at the clamped row. Both chords are taken and
        // the ends chosen after: a branch on where `Δv*` falls mispredicted (the pass was
        // ~15 % slower with it, the same values).
        let (right_dv, left_dv) = (dv_star.clamp(dv_lo, dv_hi), (-dv_star).clamp(dv_lo, dv_hi));
        let (right_chord, left_chord) = (chord(right_dv).1, chord(left_dv).0);
        let right = if right_dv == dv_star {
            mx + reach_x
        } else {
            right_chord
        };
        let left = if left_dv == -dv_star {
            mx - reach_x
        } else {
            left_chord
        };
        let margin = 1e-9 * (left.abs() + right.abs()) + 1e-9;
        let columns = match pixel_span(0.5 * (left + right), 0.5 * (right - left) + margin, x0, x1)
        {
            Some((i0, i1)) => i0 / TILE_SIZE..i1.div_ceil(TILE_SIZE),
            // Not finite (an infinite cut-off, say): keep the box's columns.
            None if !(left.is_finite() && right.is_finite()) => box_columns.clone(),
            None => 0..0,
        };
        visit(ty, columns);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_tile_lists_the_kernels_reaching_it_in_ascending_order() {
        // The passes (boxes, counts, reaches, the counting sort) against the plain
        // definition: every kernel in order, pushed onto the list of each tile it reaches.
        // Sizes with partial tiles, more kernels than a chunk, on one and three threads.
        use crate::render::{RenderContext, RenderOptions};
        for (n, (w, h)) in [(3000, (161, 97)), (2500, (64, 300)), (10, (17, 16))] {
            let scene = crate::scenes::synthetic::bench_scene(n, 3);
            let camera = crate::scenes::synthetic::bench_camera(w, h);
            let mut context = RenderContext::new();
            context
                .render(&scene, &camera, 0.5, &RenderOptions::default())
                .unwrap();
            let proj = &context.projected;
            let (tiles_x, tiles_y) = (w.div_ceil(TILE_SIZE), h.div_ceil(TILE_SIZE));
            let mut lists = vec![Vec::new(); (tiles_x * tiles_y) as usize];
            for p in 0..proj.len() {
                let bounds = context.bins.pixel_bounds[p];
                for_each_tile_row(proj, p, bounds, |ty, columns| {
                    for tx in columns {
                        lists[(ty * tiles_x + tx) as usize].push(p as u32);
                    }
                });
            }
            let entries: usize = lists.iter().map(Vec::len).sum();
            assert!(entries >= n.min(1000), "{w}×{h}: {entries} entries");
            for threads in [1, 3] {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                let mut bins = TileBins::default();
                pool.install(|| bin(proj, w, h, &mut bins));
                assert_eq!(bins.tile_count(), lists.len());
                for (t, list) in lists.iter().enumerate() {
                    assert_eq!(bins.tile_entries(t), list.as_slice(), "{w}×{h}, tile {t}");
                }
            }
        }
    }

    #[test]
    fn pixel_span_includes_centres_on_the_boundary_and_clips() {
        // Centres 0.5, 1.5, 2.5, 3.5: |c - 2| ≤ 1.5 holds for 0.5 and 3.5 exactly.
        assert_eq!(pixel_span(2.0, 1.5, 0, 10), Some((0, 4)));
        assert_eq!(pixel_span(2.0, 1.49, 0, 10), Some((1, 3)));
        assert_eq!(pixel_span(2.0, 100.0, 1, 3), Some((1, 3)));
        assert_eq!(pixel_span(-5.0, 1.0, 0, 10), None);
        assert_eq!(pixel_span(50.0, 1.0, 0, 10), None);
        assert_eq!(pixel_span(f64::NAN, 1.0, 0, 10), None);
        assert_eq!(pixel_span(0.0, f64::INFINITY, 0, 10), Some((0, 10)));
        assert_eq!(pixel_span(1e300, 1e300, 0, 10), Some((0, 10)));
        assert_eq!(pixel_span(5.0, 1.0, 3, 3), None);
    }

    #[test]
    fn pixel_span_is_the_clipped_ceil_and_floor_of_its_ends() {
        // The definition, with the library's roundings, on ends at and near whole and half
        // numbers, far outside the range, infinite and NaN.
        let definition = |centre: f64, half: f64, lo: u32, hi: u32| {
            let (from, to) = (centre - half - 0.5, centre + half - 0.5);
            if from.is_nan() || to.is_nan() {
                return None;
            }
            let first = from.ceil().max(f64::from(lo));
            let last = to.floor().min(f64::from(hi) - 1.0);
            (first <= last).then(|| (first as u32, last as u32 + 1))
        };
        let mut centres = vec![f64::NAN, f64::INFINITY, -f64::INFINITY, 1e300, -1e300, 4e9];
        for k in -40..80 {
            let x = f64::from(k) * 0.25;
            centres.extend([x, x.next_up(), x.next_down(), -x - 3e9]);
        }
        let halves = [
            0.0,
            0.25,
            0.5,
            0.49999999999,
            1.0,
            2.5,
            7.0,
            1e12,
            f64::INFINITY,
            -1.0,
        ];
        let mut checked = 0;
        for &centre in &centres {
            for &half in &halves {
                for (lo, hi) in [
                    (0, 10),
                    (3, 17),
                    (0, 1),
                    (2, 3),
                    (0, u32::MAX),
                    (5, 3),
                    (0, 0),
                ] {
                    assert_eq!(
                        pixel_span(centre, half, lo, hi),
                        definition(centre, half, lo, hi),
                        "{centre} ± {half} in {lo}..{hi}"
                    );
                    checked += 1;
                }
            }
        }
        assert!(checked > 20_000);
    }
}
