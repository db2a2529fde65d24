//! Stage 4: the additive sum per pixel (SPEC §5, Eq. 2), tile-parallel.
//!
//! ```text
//! C(p, τ) = b + Σ_i [q_i(p) ≤ qmax_i] a_i(τ) exp(-½ q_i(p))
//! ```
//!
//! in ascending kernel order, no sorting and no compositing. Each tile accumulates into its
//! own 16×16 block of a tile-major buffer, so tiles run in parallel without sharing and
//! every pixel adds the same terms in the same order whatever the number of threads. Each
//! term `a exp(-½ q)` is computed in f32 and added to an f64 sum per pixel and channel, so
//! the error does not grow with the number of kernels on a pixel.
//!
//! Per (kernel, row) the row's offsets are formed in f64 and the per-pixel loop runs in f32
//! (SPEC §5, precision). With `Δv` the row's offset from the centre, the quadratic form is
//! `q = Qxx t² + Δv²/Σ2yy` where `t = Δu + k Δv` (see [`crate::project`]); `t` at the pixel
//! of the span nearest the ellipse's centre line is rounded once from f64, and the other
//! pixels add exact integer steps. The row's
//! span comes from the padded cut-off ([`crate::tiles::padded_qmax`]); the f32 test
//! `q ≤ qmax` decides each pair.

use std::fmt;
use std::str::FromStr;

use rayon::prelude::*;

use crate::model::Image;
use crate::project::ProjectedKernels;
use crate::tiles::{TILE_SIZE, TileBins, padded_qmax, pixel_span};

/// Floats per tile in the tile-major buffer (16 × 16 pixels × RGB).
const TILE_FLOATS: usize = (TILE_SIZE * TILE_SIZE * 3) as usize;

/// How the per-pixel loops evaluate `G = exp(-½ q)` in f32.
///
/// The default is [`ExpMode::Poly`]: `splat4d bench --sweep` measured it on the whole
/// speed-against-error front (the forward gathers pairs into batches evaluated with full
/// vectors, 0.67–0.89× the time of `Std`, median 0.75×), at the same error against the f64
/// reference's model.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ExpMode {
    /// The standard library's `f32::exp` (libm, within 1 ulp), one call per pair.
    Std,
    /// [`fast_exp_neg_half`]: inlined range reduction and a degree-5 polynomial, relative
    /// error ≤ 2.4e-7 (measured; tested at 4e-7).
    #[default]
    Poly,
}

impl ExpMode {
    /// Every mode, for sweeps.
    pub const ALL: [ExpMode; 2] = [ExpMode::Std, ExpMode::Poly];
}

impl fmt::Display for ExpMode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            ExpMode::Std => "std",
            ExpMode::Poly => "poly",
        })
    }
}

impl FromStr for ExpMode {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "std" => Ok(ExpMode::Std),
            "poly" => Ok(ExpMode::Poly),
            _ => Err(format!("unknown exp mode {s:?} (expected std or poly)")),
        }
    }
}

/// `exp(-½ q)` for `q ≥ 0` without a library call: `x = -½ q = n ln 2 + r` with
/// `|r| ≤ ½ ln 2` (Cody–Waite, two-part ln 2), `e^r` by a degree-5 polynomial fitted to the
/// relative error on that interval (7.7e-8 in exact arithmetic), and `2^n` assembled in the
/// exponent bits. `x` is clamped at -87 so `2^n` stays a normal f32: for `q > 174` the result
/// is about 1e-38 instead of less (never a subnormal). Relative error ≤ 4e-7 for
/// `0 ≤ q ≤ 174` (tested against f64).
#[inline(always)]
#[must_use]
pub fn fast_exp_neg_half(q: f32) -> f32 {
    const LOG2_E: f32 = std::f32::consts::LOG2_E;
    const LN2_HI: f32 = 0.693_145_75;
    const LN2_LO: f32 = 1.428_606_8e-6;
    // Adding and subtracting 1.5·2²³ rounds to the nearest integer (and vectorises, unlike
    // `f32::round`).
    const SHIFT: f32 = 12_582_912.0;
    let x = (-0.5 * q).max(-87.0);
    let shifted = x * LOG2_E + SHIFT;
    let n = shifted - SHIFT;
    let r = (x - n * LN2_HI) - n * LN2_LO;
    let p = 1.000_000_1
        + r * (0.999_999_64
            + r * (0.499_989 + r * (0.166_676_63 + r * (0.041_915_03 + r * 0.008_291_717))));
    // `shifted`'s low mantissa bits hold n exactly (|n| < 2²²): integer operations only, which
    // vectorise (`n as i32` is a saturating conversion and does not).
    let n_int = shifted.to_bits().wrapping_sub(SHIFT.to_bits()) as i32;
    let scale = f32::from_bits(((n_int + 127) as u32) << 23);
    p * scale
}

/// `exp(-½ q)` as `mode` says; `FAST` is `mode == ExpMode::Poly`, a constant so that each
/// loop is compiled once per mode with no branch inside.
#[inline(always)]
pub(crate) fn gaussian<const FAST: bool>(q: f32) -> f32 {
    if FAST {
        fast_exp_neg_half(q)
    } else {
        (-0.5 * q).exp()
    }
}

/// Sums the binned kernels into `image` (resized to the bins' size) over `background`,
/// evaluating the Gaussian as `exp` says, using `tile_buffer` as scratch. Returns the number of (pixel, kernel) pairs summed.
pub fn rasterize(
    proj: &ProjectedKernels,
    bins: &TileBins,
    background: [f32; 3],
    exp: ExpMode,
    tile_buffer: &mut Vec<f32>,
    image: &mut Image,
) -> u64 {
    tile_buffer.resize(bins.tile_count() * TILE_FLOATS, 0.0);
    let pairs = tile_buffer
        .par_chunks_mut(TILE_FLOATS)
        .enumerate()
        .map(|(t, block)| match exp {
            ExpMode::Std => rasterize_tile::<false>(proj, bins, t, background, block),
            ExpMode::Poly => rasterize_tile_batched(proj, bins, t, background, block),
        })
        .sum();
    untile(bins, tile_buffer, image);
    pairs
}

/// One row of one kernel inside one tile: the pixels `i0..i1` of row `j` that may hold a
/// pair, and what the per-pixel f32 loop needs.
#[derive(Clone, Copy, Debug)]
pub(crate) struct RowSpan {
    /// Pixel row.
    pub j: u32,
    /// First pixel column of the span.
    pub i0: u32,
    /// One past the last pixel column.
    pub i1: u32,
    /// `t = Δu + k Δv` at pixel `anchor`, rounded once from f64. The anchor is the pixel of
    /// the span nearest the ellipse's centre line, where `|t|` and so its rounding are
    /// smallest: a thin ellipse multiplies that rounding by its large `Qxx`.
    pub t_anchor: f32,
    /// The pixel column `t_anchor` belongs to.
    pub anchor: u32,
    /// `Δv = j + 0.5 - m2y`.
    pub dv: f32,
    /// `Δv²/Σ2yy`, the row's part of `q`.
    pub row_q: f32,
}

impl RowSpan {
    /// `t` at the `n`-th pixel of the span: the anchor's `t` plus an exact integer step.
    #[inline(always)]
    pub fn t(&self, n: u32) -> f32 {
        // Pixel columns are below 2²⁸ (camera validation), so the difference is exact in i32.
        self.t_anchor + ((self.i0 + n) as i32 - self.anchor as i32) as f32
    }
}

/// The per-pixel constants of projected kernel `p`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct PixelKernel {
    /// `Qxx`.
    pub qxx: f32,
    /// `qmax` (may be `+∞`).
    pub qmax: f32,
    /// `a(τ)`.
    pub amplitude: [f32; 3],
}

impl PixelKernel {
    /// `q` at the `n`-th pixel of `row`.
    #[inline(always)]
    pub fn q(&self, row: &RowSpan, n: u32) -> f32 {
        let t = row.t(n);
        self.qxx * t * t + row.row_q
    }
}

/// Calls `visit` for each row span of projected kernel `p` inside the pixel rectangle
/// `[x0, x1) × [y0, y1)` (a tile), in ascending rows. Forward and backward both walk pairs
/// through here, so they sum exactly the same pairs.
#[inline(always)]
pub(crate) fn for_each_row_span(
    proj: &ProjectedKernels,
    bins: &TileBins,
    p: usize,
    [tx0, tx1, ty0, ty1]: [u32; 4],
    mut visit: impl FnMut(&PixelKernel, RowSpan),
) {
    let [bx0, bx1, by0, by1] = bins.pixel_bounds[p];
    let (x_lo, x_hi) = (bx0.max(tx0), bx1.min(tx1));
    let [mx, my] = proj.means[p];
    let [_, sxy, syy] = proj.covariances[p];
    let qxx = proj.conics[p][0];
    let shear = -sxy / syy;
    let inv_syy = 1.0 / syy;
    let q_reach = padded_qmax(proj.qmax[p]);
    let kernel = PixelKernel {
        qxx: qxx as f32,
        qmax: proj.qmax[p] as f32,
        amplitude: proj.amplitudes[p],
    };
    for j in by0.max(ty0)..by1.min(ty1) {
        let dv = f64::from(j) + 0.5 - my;
        let row_q = dv * dv * inv_syy;
        let reach = q_reach - row_q;
        if reach.is_nan() || reach < 0.0 {
            continue;
        }
        let centre = mx - shear * dv;
        let Some((i0, i1)) = pixel_span(centre, (reach / qxx).sqrt(), x_lo, x_hi) else {
            continue;
        };
        // Pixel i has its centre at i + ½: floor(centre) is the pixel nearest the centre line.
        let anchor = centre.floor().clamp(f64::from(i0), f64::from(i1 - 1));
        let row = RowSpan {
            j,
            i0,
            i1,
            t_anchor: (anchor + 0.5 - centre) as f32,
            anchor: anchor as u32,
            dv: dv as f32,
            row_q: row_q as f32,
        };
        visit(&kernel, row);
    }
}

/// Sums tile `t` into `block` (its 16×16 RGB pixels, row-major within the tile).
fn rasterize_tile<const FAST: bool>(
    proj: &ProjectedKernels,
    bins: &TileBins,
    t: usize,
    background: [f32; 3],
    block: &mut [f32],
) -> u64 {
    let rect = bins.tile_rect(t);
    let [tx0, _, ty0, _] = rect;
    let mut pairs = 0_u64;
    let mut sums = background_sums(background);
    for &p in bins.tile_entries(t) {
        for_each_row_span(proj, bins, p as usize, rect, |kernel, row| {
            let base = ((row.j - ty0) * TILE_SIZE + (row.i0 - tx0)) as usize;
            for n in 0..row.i1 - row.i0 {
                let q = kernel.q(&row, n);
                if q <= kernel.qmax {
                    let g = gaussian::<FAST>(q);
                    let k = 3 * (base + n as usize);
                    for c in 0..3 {
                        sums[k + c] += f64::from(kernel.amplitude[c] * g);
                    }
                    pairs += 1;
                }
            }
        });
    }
    store_sums(&sums, block);
    pairs
}

/// A tile's per-pixel sums, starting at the background. They are f64 (q and exp stay f32):
/// their error does not grow with the number of terms (10 000 kernels on one pixel gave 7e-6
/// relative error with f32 sums, 3.5× the documented bound).
#[inline(always)]
fn background_sums(background: [f32; 3]) -> [f64; TILE_FLOATS] {
    let mut sums = [0.0_f64; TILE_FLOATS];
    for pixel in sums.chunks_exact_mut(3) {
        for (sum, &b) in pixel.iter_mut().zip(&background) {
            *sum = f64::from(b);
        }
    }
    sums
}

/// Rounds a tile's sums to the f32 image block.
#[inline(always)]
fn store_sums(sums: &[f64; TILE_FLOATS], block: &mut [f32]) {
    for (b, &sum) in block.iter_mut().zip(sums.iter()) {
        *b = sum as f32;
    }
}

/// Pairs evaluated per batch of [`rasterize_tile_batched`].
const BATCH: usize = 512;

/// One batch of candidate pairs of a tile, struct-of-arrays, in the order they were met
/// (kernel by kernel, row by row, pixel by pixel).
struct Batch {
    /// `t` of the pair's pixel.
    t: [f32; BATCH],
    /// The kernel's `Qxx`.
    qxx: [f32; BATCH],
    /// The row's `Δv²/Σ2yy`.
    row_q: [f32; BATCH],
    /// The kernel's `qmax`.
    qmax: [f32; BATCH],
    /// `G`, or 0 where `q > qmax`.
    gaussian: [f32; BATCH],
    /// Pixel index within the tile, `16 (j - ty0) + (i - tx0)`.
    pixel: [u16; BATCH],
    /// Projected kernel.
    kernel: [u32; BATCH],
    /// Candidates held.
    len: usize,
}

impl Batch {
    fn new() -> Box<Self> {
        Box::new(Batch {
            t: [0.0; BATCH],
            qxx: [0.0; BATCH],
            row_q: [0.0; BATCH],
            qmax: [0.0; BATCH],
            gaussian: [0.0; BATCH],
            pixel: [0; BATCH],
            kernel: [0; BATCH],
            len: 0,
        })
    }

    /// Evaluates `q` and `G` for every candidate (a loop without branches over full
    /// arrays, which the compiler vectorises), then adds the pairs to `sums` in candidate
    /// order and empties the batch. Returns the pairs added.
    #[inline(always)]
    fn flush(&mut self, amplitudes: &[[f32; 3]], sums: &mut [f64; TILE_FLOATS]) -> u64 {
        let n = self.len;
        for i in 0..n {
            let t = self.t[i];
            let q = self.qxx[i] * t * t + self.row_q[i];
            let g = fast_exp_neg_half(q);
            self.gaussian[i] = if q <= self.qmax[i] { g } else { 0.0 };
        }
        let mut pairs = 0;
        for i in 0..n {
            let g = self.gaussian[i];
            // `fast_exp_neg_half` is never 0, so 0 marks a pair outside the cut-off.
            if g != 0.0 {
                let a = amplitudes[self.kernel[i] as usize];
                let k = 3 * self.pixel[i] as usize;
                for c in 0..3 {
                    sums[k + c] += f64::from(a[c] * g);
                }
                pairs += 1;
            }
        }
        self.len = 0;
        pairs
    }
}

/// [`rasterize_tile`] with the polynomial exp, pairs gathered into batches so that `q` and
/// `G` are computed with full vectors whatever the length of each row span (spans are a few
/// pixels in typical scenes, too short to vectorise one at a time). The pairs, their values
/// and their order per pixel are those of `rasterize_tile::<true>`, so the image is the same
/// bit for bit. With AVX2 and FMA (detected at run time) the batch loop runs 8 lanes wide;
/// the result does not depend on it (no fused operations are formed).
fn rasterize_tile_batched(
    proj: &ProjectedKernels,
    bins: &TileBins,
    t: usize,
    background: [f32; 3],
    block: &mut [f32],
) -> u64 {
    thread_local! {
        // One batch per worker thread, kept between tiles and frames.
        static SCRATCH: std::cell::RefCell<Box<Batch>> = std::cell::RefCell::new(Batch::new());
    }
    SCRATCH.with(|cell| {
        let batch = &mut **cell.borrow_mut();
        #[cfg(target_arch = "x86_64")]
        if is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma") {
            // SAFETY: the CPU has the features the function is compiled for.
            return unsafe { rasterize_tile_batched_avx2(proj, bins, t, background, block, batch) };
        }
        rasterize_tile_batched_portable(proj, bins, t, background, block, batch)
    })
}

/// [`rasterize_tile_batched_portable`] compiled for AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn rasterize_tile_batched_avx2(
    proj: &ProjectedKernels,
    bins: &TileBins,
    t: usize,
    background: [f32; 3],
    block: &mut [f32],
    batch: &mut Batch,
) -> u64 {
    rasterize_tile_batched_portable(proj, bins, t, background, block, batch)
}

/// The batched tile loop: fills `batch` kernel by kernel, row by row, pixel by pixel, and
/// flushes it into the tile's sums whenever it is full.
#[inline(always)]
fn rasterize_tile_batched_portable(
    proj: &ProjectedKernels,
    bins: &TileBins,
    t: usize,
    background: [f32; 3],
    block: &mut [f32],
    batch: &mut Batch,
) -> u64 {
    let rect = bins.tile_rect(t);
    let [tx0, _, ty0, _] = rect;
    let mut sums = background_sums(background);
    let mut pairs = 0_u64;
    batch.len = 0;
    for &p in bins.tile_entries(t) {
        for_each_row_span(proj, bins, p as usize, rect, |kernel, row| {
            let base = ((row.j - ty0) * TILE_SIZE + (row.i0 - tx0)) as u16;
            for n in 0..row.i1 - row.i0 {
                if batch.len == BATCH {
                    pairs += batch.flush(&proj.amplitudes, &mut sums);
                }
                let i = batch.len;
                batch.t[i] = row.t(n);
                batch.qxx[i] = kernel.qxx;
                batch.row_q[i] = row.row_q;
                batch.qmax[i] = kernel.qmax;
                batch.pixel[i] = base + n as u16;
                batch.kernel[i] = p;
                batch.len += 1;
            }
        });
    }
    pairs += batch.flush(&proj.amplitudes, &mut sums);
    store_sums(&sums, block);
    pairs
}

/// Copies the tile-major buffer into the row-major image.
fn untile(bins: &TileBins, tile_buffer: &[f32], image: &mut Image) {
    let (w, h) = (bins.width as usize, bins.height as usize);
    image.width = bins.width;
    image.height = bins.height;
    image.pixels.resize(3 * w * h, 0.0);
    let tile = TILE_SIZE as usize;
    image
        .pixels
        .par_chunks_mut(3 * w * tile)
        .enumerate()
        .for_each(|(ty, band)| {
            for (r, row) in band.chunks_exact_mut(3 * w).enumerate() {
                for tx in 0..bins.tiles_x as usize {
                    let t = ty * bins.tiles_x as usize + tx;
                    let x0 = tx * tile;
                    let n = tile.min(w - x0);
                    let src = &tile_buffer[t * TILE_FLOATS + 3 * r * tile..][..3 * n];
                    row[3 * x0..3 * (x0 + n)].copy_from_slice(src);
                }
            }
        });
    debug_assert!(image.pixels.len() == 3 * w * h);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fast_exp_is_within_its_documented_relative_error() {
        // Dense over [0, 174] plus the interval ends of the range reduction.
        let mut worst = 0.0_f64;
        let mut q = 0.0_f32;
        while q <= 174.0 {
            let exact = (-0.5 * f64::from(q)).exp();
            let error = (f64::from(fast_exp_neg_half(q)) / exact - 1.0).abs();
            worst = worst.max(error);
            q = (q + 1e-3).max(q.next_up());
        }
        eprintln!("fast exp: worst relative error {worst:e}");
        assert!(worst <= 4e-7, "relative error {worst:e}");
        // Beyond the clamp: tiny, normal, never NaN; exactly 1 at 0.
        for q in [175.0_f32, 1e3, 1e30, f32::INFINITY] {
            let g = fast_exp_neg_half(q);
            assert!(g.is_normal() && g < 1e-37, "{q}: {g:e}");
        }
        assert!((fast_exp_neg_half(0.0) - 1.0).abs() <= 2.0 * f32::EPSILON);
    }

    #[test]
    fn batched_tiles_equal_the_span_loop_bit_for_bit() {
        use crate::render::{RenderContext, RenderOptions};
        let camera = crate::scenes::synthetic::bench_camera(160, 96);
        for (n, cutoff) in [(3000, 1.0 / 255.0), (300, 0.0)] {
            let scene = crate::scenes::synthetic::bench_scene(n, 5);
            let options = RenderOptions {
                cutoff,
                exp: ExpMode::Poly,
                ..RenderOptions::default()
            };
            let mut context = RenderContext::new();
            context.render(&scene, &camera, 0.5, &options).unwrap();
            let (proj, bins) = (&context.projected, &context.bins);
            let background = [0.1, 0.2, 0.3];
            let mut most = 0;
            for t in 0..bins.tile_count() {
                let (mut a, mut b) = ([0.0_f32; TILE_FLOATS], [0.0_f32; TILE_FLOATS]);
                let pairs_a = rasterize_tile::<true>(proj, bins, t, background, &mut a);
                let pairs_b = rasterize_tile_batched(proj, bins, t, background, &mut b);
                assert_eq!(pairs_a, pairs_b, "tile {t}");
                assert!(
                    a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()),
                    "tile {t} differs"
                );
                most = most.max(pairs_a);
            }
            if cutoff == 0.0 {
                // Every kernel reaches every pixel: tiles hold more than one batch, so
                // flushing in the middle of a tile is covered.
                assert!(most > BATCH as u64, "at most {most} pairs in a tile");
            }
        }
    }

    #[test]
    fn exp_modes_parse_and_print_as_written() {
        for mode in ExpMode::ALL {
            assert_eq!(mode.to_string().parse::<ExpMode>(), Ok(mode));
        }
        assert!("fast".parse::<ExpMode>().is_err());
    }
}
