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
    /// Scratch for the fill pass: the next free slot of each tile.
    fill_cursor: Vec<u32>,
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

/// Bins `proj` for a `width × height` image into `out`, reusing its buffers.
pub fn bin(proj: &ProjectedKernels, width: u32, height: u32, out: &mut TileBins) {
    out.width = width;
    out.height = height;
    out.tiles_x = width.div_ceil(TILE_SIZE);
    out.tiles_y = height.div_ceil(TILE_SIZE);
    let tiles_x = out.tiles_x as usize;
    out.pixel_bounds.clear();
    for p in 0..proj.len() {
        let [mx, my] = proj.means[p];
        let [sxx, _, syy] = proj.covariances[p];
        let q = padded_qmax(proj.qmax[p]);
        let bounds = match (
            pixel_span(mx, (q * sxx).sqrt(), 0, width),
            pixel_span(my, (q * syy).sqrt(), 0, height),
        ) {
            (Some((x0, x1)), Some((y0, y1))) => [x0, x1, y0, y1],
            _ => [0, 0, 0, 0],
        };
        out.pixel_bounds.push(bounds);
    }
    // Count, prefix-sum, fill: kernels enter each tile's list in ascending order.
    out.tile_offsets.clear();
    out.tile_offsets.resize(out.tile_count() + 1, 0);
    for p in 0..proj.len() {
        for_each_tile_row(proj, p, out.pixel_bounds[p], |ty, txs| {
            for tx in txs {
                out.tile_offsets[ty as usize * tiles_x + tx as usize + 1] += 1;
            }
        });
    }
    for t in 0..out.tile_count() {
        out.tile_offsets[t + 1] += out.tile_offsets[t];
    }
    out.proj_from_entry.clear();
    out.proj_from_entry
        .resize(out.tile_offsets[out.tile_count()] as usize, 0);
    out.fill_cursor.clear();
    out.fill_cursor
        .extend_from_slice(&out.tile_offsets[..out.tile_count()]);
    for p in 0..proj.len() {
        for_each_tile_row(proj, p, out.pixel_bounds[p], |ty, txs| {
            for tx in txs {
                let slot = &mut out.fill_cursor[ty as usize * tiles_x + tx as usize];
                out.proj_from_entry[*slot as usize] = p as u32;
                *slot += 1;
            }
        });
    }
}

/// Calls `visit(ty, tx0..tx1)` for each tile row of projected kernel `p` (pixel rectangle
/// `bounds`) with the tile columns its ellipse reaches there (see the module docs).
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
    let dv_star = q.sqrt() * sxy / sxx.sqrt();
    let shear = sxy / syy;
    // The chord's ends on row offset `dv`.
    let chord = |dv: f64| {
        let half = ((q - dv * dv / syy).max(0.0) / qxx).sqrt();
        let centre = mx + shear * dv;
        (centre - half, centre + half)
    };
    for ty in y0 / TILE_SIZE..y1.div_ceil(TILE_SIZE) {
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
