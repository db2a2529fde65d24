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
    if from.is_nan() || to.is_nan() {
        return None;
    }
    let first = from.ceil().max(f64::from(lo));
    let last = to.floor().min(f64::from(hi) - 1.0);
    (first <= last).then(|| (first as u32, last as u32 + 1))
}

/// Kernel lists per tile, as offsets into one flat array (CSR layout).
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
    /// Scratch: per tile row (band of 16 pixel rows), its kernels in ascending order (CSR
    /// by `band_offsets`), then its entries and per-tile counts.
    band_offsets: Vec<u32>,
    band_kernels: Vec<u32>,
    bands: Vec<BandScratch>,
}

/// What one tile row's binning builds, kept between frames.
#[derive(Clone, Debug, Default)]
struct BandScratch {
    /// `(kernel, first tile column, end tile column)` per kernel reaching the band.
    reaches: Vec<(u32, u32, u32)>,
    /// Entries per tile of the band, then their start offsets within the band.
    counts: Vec<u32>,
    /// The band's part of `proj_from_entry`, tile by tile.
    entries: Vec<u32>,
}

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

/// Bins `proj` for a `width × height` image into `out`, reusing its buffers. Tile rows are
/// binned in parallel (one ellipse–tile-row test per kernel and tile row); the lists are the
/// same whatever the number of threads.
pub fn bin(proj: &ProjectedKernels, width: u32, height: u32, out: &mut TileBins) {
    use rayon::prelude::*;
    out.width = width;
    out.height = height;
    out.tiles_x = width.div_ceil(TILE_SIZE);
    out.tiles_y = height.div_ceil(TILE_SIZE);
    let (tiles_x, tiles_y) = (out.tiles_x as usize, out.tiles_y as usize);
    out.pixel_bounds.clear();
    out.pixel_bounds.resize(proj.len(), [0; 4]);
    out.pixel_bounds
        .par_iter_mut()
        .enumerate()
        .with_min_len(1024)
        .for_each(|(p, bounds)| {
            let [mx, my] = proj.means[p];
            let [sxx, _, syy] = proj.covariances[p];
            let q = padded_qmax(proj.qmax[p]);
            *bounds = match (
                pixel_span(mx, (q * sxx).sqrt(), 0, width),
                pixel_span(my, (q * syy).sqrt(), 0, height),
            ) {
                (Some((x0, x1)), Some((y0, y1))) => [x0, x1, y0, y1],
                _ => [0, 0, 0, 0],
            };
        });
    // Kernels by tile row (counting sort, ascending within each row).
    let band_range = |[x0, x1, y0, y1]: [u32; 4]| {
        if x0 >= x1 || y0 >= y1 {
            0..0
        } else {
            (y0 / TILE_SIZE) as usize..y1.div_ceil(TILE_SIZE) as usize
        }
    };
    out.band_offsets.clear();
    out.band_offsets.resize(tiles_y + 1, 0);
    for bounds in &out.pixel_bounds {
        for band in band_range(*bounds) {
            out.band_offsets[band + 1] += 1;
        }
    }
    for band in 0..tiles_y {
        out.band_offsets[band + 1] += out.band_offsets[band];
    }
    out.band_kernels.clear();
    out.band_kernels
        .resize(out.band_offsets[tiles_y] as usize, 0);
    {
        let mut cursor = out.band_offsets[..tiles_y].to_vec();
        for (p, bounds) in out.pixel_bounds.iter().enumerate() {
            for band in band_range(*bounds) {
                out.band_kernels[cursor[band] as usize] = p as u32;
                cursor[band] += 1;
            }
        }
    }
    // Each tile row: its kernels' tile columns, then a counting sort by tile.
    out.bands.resize_with(tiles_y, BandScratch::default);
    let (band_offsets, band_kernels, pixel_bounds) =
        (&out.band_offsets, &out.band_kernels, &out.pixel_bounds);
    out.bands.par_iter_mut().enumerate().for_each(|(ty, band)| {
        band.reaches.clear();
        band.counts.clear();
        band.counts.resize(tiles_x + 1, 0);
        let kernels = &band_kernels[band_offsets[ty] as usize..band_offsets[ty + 1] as usize];
        for &p in kernels {
            if let Some(columns) =
                tile_columns(proj, p as usize, pixel_bounds[p as usize], ty as u32)
            {
                for tx in columns.clone() {
                    band.counts[tx as usize + 1] += 1;
                }
                band.reaches.push((p, columns.start, columns.end));
            }
        }
        for tx in 0..tiles_x {
            band.counts[tx + 1] += band.counts[tx];
        }
        band.entries.clear();
        band.entries.resize(band.counts[tiles_x] as usize, 0);
        for &(p, c0, c1) in &band.reaches {
            for tx in c0..c1 {
                let slot = &mut band.counts[tx as usize];
                band.entries[*slot as usize] = p;
                *slot += 1;
            }
        }
        // `counts[tx]` is now the end of tile tx's entries within the band.
    });
    // Concatenate the bands: offsets per tile, then the entries.
    out.tile_offsets.clear();
    out.tile_offsets.resize(out.tile_count() + 1, 0);
    let mut total = 0_u32;
    for (ty, band) in out.bands.iter().enumerate() {
        for tx in 0..tiles_x {
            out.tile_offsets[ty * tiles_x + tx + 1] = total + band.counts[tx];
        }
        total += band.entries.len() as u32;
    }
    out.proj_from_entry.clear();
    out.proj_from_entry.resize(total as usize, 0);
    let mut rest = out.proj_from_entry.as_mut_slice();
    let mut chunks = Vec::with_capacity(tiles_y);
    for band in &out.bands {
        let (head, tail) = rest.split_at_mut(band.entries.len());
        chunks.push((head, &band.entries));
        rest = tail;
    }
    chunks
        .into_par_iter()
        .for_each(|(to, from)| to.copy_from_slice(from));
}

/// The tile columns of tile row `ty` that projected kernel `p` (pixel rectangle `bounds`)
/// reaches (see the module docs), or `None`.
fn tile_columns(
    proj: &ProjectedKernels,
    p: usize,
    bounds: [u32; 4],
    ty: u32,
) -> Option<std::ops::Range<u32>> {
    let mut columns = None;
    for_each_tile_row(proj, p, bounds, ty..ty + 1, |_, range| {
        columns = Some(range)
    });
    columns
}

/// Calls `visit(ty, tx0..tx1)` for each tile row `ty` in `rows` of projected kernel `p`
/// (pixel rectangle `bounds`) with the tile columns its ellipse reaches there (see the module
/// docs).
fn for_each_tile_row(
    proj: &ProjectedKernels,
    p: usize,
    [x0, x1, y0, y1]: [u32; 4],
    rows: std::ops::Range<u32>,
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
    let dv_star = q.sqrt() * sxy / sxx.sqrt();
    let shear = sxy / syy;
    // The chord's ends on row offset `dv`.
    let chord = |dv: f64| {
        let half = ((q - dv * dv / syy).max(0.0) / qxx).sqrt();
        let centre = mx + shear * dv;
        (centre - half, centre + half)
    };
    for ty in (y0 / TILE_SIZE).max(rows.start)..y1.div_ceil(TILE_SIZE).min(rows.end) {
        // Pixel rows of this tile row that the kernel's box covers, as offsets from m2y.
        let first = (ty * TILE_SIZE).max(y0);
        let last = ((ty + 1) * TILE_SIZE).min(y1) - 1;
        let (dv_lo, dv_hi) = (f64::from(first) + 0.5 - my, f64::from(last) + 0.5 - my);
        let right = if (dv_lo..=dv_hi).contains(&dv_star) {
            mx + reach_x
        } else {
            chord(dv_star.clamp(dv_lo, dv_hi)).1
        };
        let left = if (dv_lo..=dv_hi).contains(&-dv_star) {
            mx - reach_x
        } else {
            chord((-dv_star).clamp(dv_lo, dv_hi)).0
        };
        let margin = 1e-9 * (left.abs() + right.abs()) + 1e-9;
        let columns = match pixel_span(0.5 * (left + right), 0.5 * (right - left) + margin, x0, x1)
        {
            Some((i0, i1)) => i0 / TILE_SIZE..i1.div_ceil(TILE_SIZE),
            // Not finite (an infinite cut-off, say): keep the box's columns.
            None if !(left.is_finite() && right.is_finite()) => box_columns.clone(),
            None => continue,
        };
        visit(ty, columns);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
    }
}
