//! The frame stage 4 reads ([`BinnedFrame`]; SPEC §5 and §8: the projected kernels, their
//! bins, the background, the exp) and the image it writes: sized once and filled by tile
//! rows in parallel, or handed out in groups of rows as they are done
//! ([`stream_tile_rows`]); a row's channel planes to and from interleaved RGB.

use super::{ExpMode, ROW, RowForm, SimdPath, row_forms};
use crate::model::Image;
use crate::parallel::{Drain, GroupBuffers, fill_and_drain_in_order};
use crate::project::ProjectedKernels;
use crate::tiles::TileBins;

/// A binned frame as stage 4 of either blend ([`crate::raster`], [`crate::composite`]) and
/// its backward read it: the projected kernels, their tile bins and row forms, the
/// background, how `exp(-½ q)` is evaluated, and the [`SimdPath`] the loops run on — one
/// this CPU has, checked where it is chosen ([`Self::on`]), which every `unsafe` call of a
/// path's loops relies on.
#[derive(Clone, Copy, Debug)]
pub struct BinnedFrame<'a> {
    pub(crate) proj: &'a ProjectedKernels,
    pub(crate) bins: &'a TileBins,
    /// [`row_forms`] of `proj` binned in `bins`.
    pub(crate) forms: &'a [RowForm],
    /// The background, widened (exactly) to f64.
    pub(crate) background: [f64; 3],
    pub(crate) exp: ExpMode,
    pub(crate) path: SimdPath,
}

impl<'a> BinnedFrame<'a> {
    /// The frame of `proj` binned in `bins` over `background`, its row forms computed into
    /// `forms` (kept by the caller: a backward of the frame reads them), evaluating the
    /// Gaussian as `exp` says, on the widest path this CPU has ([`SimdPath::detect`]).
    pub fn new(
        proj: &'a ProjectedKernels,
        bins: &'a TileBins,
        forms: &'a mut Vec<RowForm>,
        background: [f32; 3],
        exp: ExpMode,
    ) -> Self {
        row_forms(proj, bins, forms);
        Self::with_forms(proj, bins, forms, background, exp)
    }

    /// [`Self::new`] with the row forms already computed (by the forward of the same
    /// frame, for its backward).
    ///
    /// # Panics
    /// When there is not one form per projected kernel.
    pub(crate) fn with_forms(
        proj: &'a ProjectedKernels,
        bins: &'a TileBins,
        forms: &'a [RowForm],
        background: [f32; 3],
        exp: ExpMode,
    ) -> Self {
        assert_eq!(forms.len(), proj.len(), "the forward's row forms");
        BinnedFrame {
            proj,
            bins,
            forms,
            background: background.map(f64::from),
            exp,
            path: SimdPath::detect(),
        }
    }

    /// The same frame on `path` (which the CPU must have: see [`SimdPath::available`]):
    /// every path gives the same bits, so this only measures or tests one.
    ///
    /// # Panics
    /// When the CPU lacks `path`'s instructions.
    #[must_use]
    pub fn on(self, path: SimdPath) -> Self {
        path.assert_available();
        BinnedFrame { path, ..self }
    }

    /// The path the frame's loops run on.
    #[must_use]
    pub fn path(&self) -> SimdPath {
        self.path
    }
}

/// Sizes `image` for the frame of `bins`, its pixels to be written tile by tile; whether
/// it has any. A first (or larger) frame takes fresh zeroed pages from the system, so that
/// they are touched first by the parallel tile rows, not by a serial fill here.
pub(crate) fn size_image(bins: &TileBins, image: &mut Image) -> bool {
    let (w, h) = (bins.width as usize, bins.height as usize);
    image.width = bins.width;
    image.height = bins.height;
    if image.pixels.capacity() < 3 * w * h {
        image.pixels = vec![0.0; 3 * w * h];
    } else {
        image.pixels.resize(3 * w * h, 0.0);
    }
    w > 0 && h > 0
}

/// Streams the tile rows of a frame of `bins`' size: tile row `ty` is computed into its 16
/// image rows (fewer at the bottom) by `tile_row(ty, band)`, and the rows are handed to
/// `drain` with the index of the first ([`fill_and_drain_in_order`]), in groups of two tile
/// rows for each thread of the pool, enough that both threads stay busy while a group is
/// drained. Returns the sum of `tile_row`'s results or `drain`'s first error.
pub(crate) fn stream_tile_rows<E: Send>(
    bins: &TileBins,
    groups: &mut GroupBuffers,
    tile_row: impl Fn(usize, &mut [f32]) -> u64 + Sync,
    drain: &mut Drain<E>,
) -> Result<u64, E> {
    let (w, h) = (bins.width as usize, bins.height as usize);
    let row_values = 3 * w;
    let group = 2 * rayon::current_num_threads().max(1);
    fill_and_drain_in_order(
        (row_values * h, row_values * ROW, group),
        groups,
        tile_row,
        &mut |offset, values| drain(offset / row_values.max(1), values),
    )
}

/// Rounds a row's channel planes (f64, pixel `i` at index `i` of each) to f32 into the
/// interleaved RGB pixels of `out`, as many as `out` holds.
#[inline(always)]
pub(crate) fn write_planes<const N: usize>(planes: &[[f64; N]; 3], out: &mut [f32]) {
    for (i, pixel) in out.chunks_exact_mut(3).enumerate() {
        for c in 0..3 {
            pixel[c] = planes[c][i] as f32;
        }
    }
}

/// Reads the interleaved RGB pixels of `pixels` into a row's channel planes (pixel `i` at
/// index `i` of each); the planes' other entries are left as they are.
#[inline(always)]
pub(crate) fn read_planes<const N: usize>(pixels: &[f32], planes: &mut [[f32; N]; 3]) {
    for (i, pixel) in pixels.chunks_exact(3).enumerate() {
        for c in 0..3 {
            planes[c][i] = pixel[c];
        }
    }
}
