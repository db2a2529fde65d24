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
//! f64, branch-free over the tile's 16 rows (`kernel_rows`; no division or square root:
//! the per-kernel constants come from [`row_forms`], once per frame), and joins the list of
//! every row (or half row) whose chord of the padded ellipse ([`crate::tiles::padded_qmax`])
//! reaches one of its pixel centres. The half-row paths copy each row's constants into
//! `RowEntry`s (written at the end of every list and kept by advancing the length, no
//! branch per row); the AVX-512 path keeps each kernel's 16 rows as one `RowBlock` and its
//! rows as a bit mask, and builds each row's list of kernel indices 16 kernels at a time by
//! compressing them. Then rows outer, kernels inner: per row, accumulators (RGB) stay in
//! registers **in f64** while every entry of the row passes over them, and the row is rounded
//! to f32 and written straight into the image. Tile rows (bands of 16 image rows) run in
//! parallel; every pixel adds the same terms in the same order whatever the number of
//! threads. A frame going straight to a file needs no image: [`rasterize_in_bands_on`] sums
//! groups of tile rows into two reused buffers and hands each group to the encoder while the
//! next is summed, the same values. The backward ([`crate::backward::raster`]) evaluates the
//! same pairs.
//!
//! **Per pixel** (SPEC §5, precision): with `Δv` the row's offset from the centre, the
//! quadratic form is `q = Qxx t² + Δv²/Σ2yy` with `t = Δu + k Δv` (see [`crate::project`]);
//! `t` at the tile pixel nearest the ellipse's centre line is rounded once from f64, and the
//! other lanes add exact integer steps. `q`, the test `q ≤ qmax` (which alone decides each
//! pair: lanes outside the ellipse add zero) and `G = exp(-½ q)` are f32; each term
//! `a_c · G` is an exact f64 product added to the f64 sum, so the error does not grow with
//! the number of kernels on a pixel.
//!
//! **Paths.** The row loop is written three times, with AVX-512 intrinsics (16 lanes), AVX2
//! intrinsics (8) and portably (8), with the same operations in the same order; the tile
//! set-up is one portable loop compiled for each path (AVX-512, AVX2+FMA, baseline x86-64),
//! chosen at run time ([`SimdPath`]; `SPLAT4D_SIMD` names a narrower one). The f32 steps
//! that fuse a product with a sum (`q`'s last step, the exp's range reduction and Horner
//! steps) are `mul_add` in the portable loop and FMA instructions in the SIMD loops, each
//! rounding once; the f64 accumulation's FMA rounds like `acc + a G` because `a G` is
//! exact; every conversion is exact. So all paths give the same image bit for bit (tested on
//! every path the CPU has): a whole row's list is the union of its two half lists in the
//! same order, and the lanes of a half a kernel does not reach add exact zeros.
//! [`crate::bench::ceiling_probe`] is the ideal loop the renderer is measured against,
//! compiled for the same path (16 lanes a register on AVX-512, its `q`, exp and f32
//! accumulation fused as well).
//!
//! **Where the rest of the ceiling goes**: the row loop against the ideal loop of
//! [`crate::bench::ceiling_probe`], measured, is in `docs/performance.md` ("The ceiling
//! probe and the raster").

use std::fmt;
use std::str::FromStr;

use rayon::prelude::*;

use crate::model::Image;
use crate::parallel::{Drain, GroupBuffers, fill_and_drain_in_order};
use crate::project::ProjectedKernels;
use crate::tiles::{TILE_SIZE, TileBins, padded_qmax};

/// How the per-pixel loops evaluate `G = exp(-½ q)` in f32.
///
/// The default is [`ExpMode::Poly`]: `splat4d bench --sweep` measured it on the whole
/// speed-against-error front (evaluated 8 lanes at a time with the rest of the loop, while
/// `Std` calls libm once per lane: `Std` takes 1.6–1.8× the time), at the same error
/// against the f64 reference's model.
///
/// SPEC §5 (precision: the per-pixel evaluation of `exp`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ExpMode {
    /// The standard library's `f32::exp` (libm, within 1 ulp), one call per pair.
    Std,
    /// [`fast_exp_neg_half`]: inlined range reduction and a degree-5 polynomial by fused
    /// multiply-adds, relative error ≤ 2.14e-7 (measured; tested at 4e-7).
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
///
/// The range reduction's two products and the Horner steps are fused multiply-adds
/// (`f32::mul_add`, one rounding each), as each SIMD path computes them with its FMA
/// instructions, so every path gives these bits: 8 operations fewer than separate products
/// and sums (at most 7 roundings fewer: `n ln2_hi` is exact), and a dependent chain of 12
/// steps instead of 19. Compiled without FMA (the baseline path) `mul_add` is a call to a
/// software `fmaf`: exact, and slow (the baseline path renders about 3.4× slower than with
/// separate products and sums).
///
/// **Without forming `x`.** The steps work on `y = min(q, 174) = -2 x` and `r' = -2 r`
/// instead, with the constants scaled by powers of two (`exp_constants` in the source):
/// scaling by a power of two commutes with rounding away from underflow and overflow, so
/// each step rounds `(-½)^k` times the value the steps on `x` and `r` round, and the result
/// is the same bits. (A subnormal `q`, whose `-½ q` rounds, gives 1 both ways.) That saves
/// the product `-½ q`: one vector instruction of the 19 that a row entry spends on the FMA
/// pipes. Checked on all 2³² f32 inputs against the steps on
/// `x` (none differs), and against f64 by the tests.
#[inline(always)]
#[must_use]
pub fn fast_exp_neg_half(q: f32) -> f32 {
    use exp_constants::{HORNER, LN2_HI_TWICE, LN2_LO_TWICE, LOG2_E_NEG_HALF, Q_MAX, SHIFT};
    let y = q.min(Q_MAX);
    // `n = round(x log2 e)`: adding 1.5·2²³ rounds to the nearest integer (and vectorises,
    // unlike `f32::round`).
    let shifted = y.mul_add(LOG2_E_NEG_HALF, SHIFT);
    let n = shifted - SHIFT;
    let r = n.mul_add(LN2_LO_TWICE, n.mul_add(LN2_HI_TWICE, y));
    let p = r.mul_add(HORNER[0], HORNER[1]);
    let p = r.mul_add(p, HORNER[2]);
    let p = r.mul_add(p, HORNER[3]);
    let p = r.mul_add(p, HORNER[4]);
    let p = r.mul_add(p, HORNER[5]);
    // `shifted`'s low mantissa bits hold n exactly (|n| < 2²²): integer operations only, which
    // vectorise (`n as i32` is a saturating conversion and does not).
    let n_int = shifted.to_bits().wrapping_sub(SHIFT.to_bits()) as i32;
    let scale = f32::from_bits(((n_int + 127) as u32) << 23);
    p * scale
}

/// The constants of [`fast_exp_neg_half`], shared by every path's loop. The reduction and
/// the polynomial are written for `x = -½ q` and `r`; the steps run on `-2 x` and `-2 r`,
/// so each constant a step meets is the written one times a power of two (exact).
pub(crate) mod exp_constants {
    /// `log2 e`, times the `-½` that turns `y = -2 x` back into `x`.
    pub(crate) const LOG2_E_NEG_HALF: f32 = -0.5 * std::f32::consts::LOG2_E;
    /// ln 2 in two parts (`n ln2_hi` is exact for the `n` that occur), each times 2.
    pub(crate) const LN2_HI_TWICE: f32 = 2.0 * 0.693_145_75;
    /// The low part of ln 2, times 2.
    pub(crate) const LN2_LO_TWICE: f32 = 2.0 * 1.428_606_8e-6;
    /// `1.5·2²³`: added, it rounds to the nearest integer.
    pub(crate) const SHIFT: f32 = 12_582_912.0;
    /// The clamp of `q` (`x ≥ -87`).
    pub(crate) const Q_MAX: f32 = 174.0;
    /// The polynomial `c0 + r (c1 + r (c2 + r (c3 + r (c4 + r c5))))` in `r' = -2 r`:
    /// `c5 (-½)⁵, c4 (-½)⁴, …, c0`, highest first.
    pub(crate) const HORNER: [f32; 6] = [
        -0.008_291_717 / 32.0,
        0.041_915_03 / 16.0,
        -0.166_676_63 / 8.0,
        0.499_989 / 4.0,
        -0.999_999_64 / 2.0,
        1.000_000_1,
    ];
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

/// The instruction set the per-pixel loops are compiled for, chosen once per render from
/// what the CPU has. Every path runs the same operations in the same order (the fused
/// multiply-adds are written out, `mul_add` or FMA instructions, and none is formed by the
/// compiler; conversions are exact), so the image is the same bit for bit on every path;
/// only the vector width differs.
///
/// Not part of SPEC: every path gives the same bits (SPEC §5's sum, evaluated identically).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SimdPath {
    /// Baseline x86-64 (SSE2) or any other architecture.
    Baseline,
    /// AVX2 and FMA (x86-64).
    Avx2,
    /// AVX-512 F/BW/DQ/VL with AVX2 and FMA (x86-64).
    Avx512,
}

impl SimdPath {
    /// The widest path this CPU runs, or a narrower one named by the environment variable
    /// `SPLAT4D_SIMD` (`baseline`, `avx2`, `avx512`: to measure the narrower paths on a
    /// wider CPU; a path the CPU lacks, or another value, is ignored). Read once per
    /// process.
    #[must_use]
    pub fn detect() -> Self {
        static CHOSEN: std::sync::OnceLock<SimdPath> = std::sync::OnceLock::new();
        *CHOSEN.get_or_init(|| {
            let widest = *Self::available()
                .last()
                .expect("the baseline is always available");
            std::env::var("SPLAT4D_SIMD")
                .ok()
                .and_then(|name| {
                    Self::available()
                        .iter()
                        .find(|path| path.to_string() == name)
                        .copied()
                })
                .unwrap_or(widest)
        })
    }

    /// Panics when this CPU cannot run the path: every `unsafe` call of a path's loops
    /// relies on this check.
    pub fn assert_available(self) {
        assert!(
            Self::available().contains(&self),
            "this CPU cannot run the {self} path"
        );
    }

    /// Every path this CPU runs, narrowest first (the tests compare them all). Detected
    /// once per process: renders ask at every frame.
    #[must_use]
    pub fn available() -> &'static [SimdPath] {
        static PATHS: std::sync::OnceLock<Vec<SimdPath>> = std::sync::OnceLock::new();
        PATHS.get_or_init(Self::detect_all)
    }

    fn detect_all() -> Vec<SimdPath> {
        let mut paths = vec![SimdPath::Baseline];
        #[cfg(target_arch = "x86_64")]
        {
            if is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma") {
                paths.push(SimdPath::Avx2);
                // The AVX-512 loops count pairs with POPCNT too (every AVX-512 CPU has it;
                // a virtual machine may hide it).
                if is_x86_feature_detected!("popcnt")
                    && is_x86_feature_detected!("avx512f")
                    && is_x86_feature_detected!("avx512bw")
                    && is_x86_feature_detected!("avx512dq")
                    && is_x86_feature_detected!("avx512vl")
                {
                    paths.push(SimdPath::Avx512);
                }
            }
        }
        paths
    }
}

impl fmt::Display for SimdPath {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            SimdPath::Baseline => "baseline",
            SimdPath::Avx2 => "avx2",
            SimdPath::Avx512 => "avx512",
        })
    }
}

/// Pixels of one tile row.
pub(crate) const ROW: usize = TILE_SIZE as usize;

/// Pixels of one half tile row: the vector the per-pixel loop works on (8 f32 lanes, one
/// AVX2 register; the accumulators, 3 × 8 f64, fit in registers beside the exp's constants).
pub(crate) const LANES: usize = ROW / 2;

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
    bounds: [u32; 4],
    /// What the per-pixel loop needs.
    pixel: TileKernel,
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
    /// evaluate pairs through here (and [`avx2::lanes`], the same operations), so they see
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
    /// The AVX-512 loops' form of the tile.
    pub(crate) whole_rows: TileBlocks,
    /// The AVX-512 forward's `G` of the tile, kept for its backward in a training step.
    pub(crate) kept: KeptGaussians,
}

/// `G` of every (tile kernel, row) the AVX-512 forward evaluated — zero where a lane is not
/// a pair — and the row's pair mask, kernel-major (`16 k + row`): a training step's
/// backward of the same tile reads them instead of evaluating `q` and `exp(-½ q)` again (the
/// same values, so the same bits). Only the rows a kernel is listed on are written, and only
/// those are read.
#[derive(Default)]
pub(crate) struct KeptGaussians {
    pub(crate) values: Vec<[f32; ROW]>,
    pub(crate) hits: Vec<u16>,
}

impl KeptGaussians {
    /// Room for `kernels` tile kernels (grown, never shrunk nor cleared: what a tile writes
    /// is all it reads).
    #[inline(always)]
    fn make_room(&mut self, kernels: usize) {
        if self.values.len() < ROW * kernels {
            self.values.resize(ROW * kernels, [0.0; ROW]);
            self.hits.resize(ROW * kernels, 0);
        }
    }
}

/// The forward's per-tile scratch, owned by the render context and kept between frames: a
/// stack of `TileScratch`es from which each band of tiles takes one while it runs (as many
/// as bands ran at once, so one per worker thread), its buffers keeping their capacity.
#[derive(Default)]
pub struct TileScratchPool {
    free: std::sync::Mutex<Vec<TileScratch>>,
}

impl fmt::Debug for TileScratchPool {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let free = self.free.lock().map_or(0, |free| free.len());
        write!(f, "TileScratchPool {{ {free} scratches }}")
    }
}

impl TileScratchPool {
    /// Runs `work` with a scratch of the pool (a fresh one when all are in use).
    fn with<R>(&self, work: impl FnOnce(&mut TileScratch) -> R) -> R {
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

/// Sums the binned kernels into `image` (resized to the bins' size) over `background`,
/// evaluating the Gaussian as `exp` says, on the widest [`SimdPath`] the CPU has. `forms` and
/// `scratch` are scratch for [`row_forms`] and the tiles. Returns the number of (pixel,
/// kernel) pairs summed.
pub fn rasterize(
    proj: &ProjectedKernels,
    bins: &TileBins,
    background: [f32; 3],
    exp: ExpMode,
    (forms, scratch): (&mut Vec<RowForm>, &TileScratchPool),
    image: &mut Image,
) -> u64 {
    rasterize_on(
        SimdPath::detect(),
        proj,
        bins,
        background,
        exp,
        (forms, scratch),
        image,
    )
}

/// [`rasterize`] on a chosen path (which the CPU must have: see [`SimdPath::available`]).
///
/// # Panics
/// When the CPU lacks `path`'s instructions.
pub fn rasterize_on(
    path: SimdPath,
    proj: &ProjectedKernels,
    bins: &TileBins,
    background: [f32; 3],
    exp: ExpMode,
    (forms, pool): (&mut Vec<RowForm>, &TileScratchPool),
    image: &mut Image,
) -> u64 {
    let frame = Frame::prepare(path, proj, bins, forms, background);
    let w = bins.width as usize;
    if !size_image(bins, image) {
        return 0;
    }
    // Tile rows (bands of 16 image rows) in parallel: each writes only its own rows.
    image
        .pixels
        .par_chunks_mut(3 * w * ROW)
        .enumerate()
        .map(|(ty, band)| tile_row(path, exp, &frame, pool, ty, band))
        .sum()
}

/// [`rasterize_on`] without an image: the frame's rows are handed to `drain` in order, a
/// group of tile rows at a time (its first row and its RGB values), while the next group is
/// summed ([`fill_and_drain_in_order`]). The same values as [`rasterize_on`]'s image, in
/// two groups' memory. Returns the pairs, or `drain`'s first error.
///
/// # Panics
/// When the CPU lacks `path`'s instructions.
#[allow(clippy::too_many_arguments)]
pub fn rasterize_in_bands_on<E: Send>(
    path: SimdPath,
    proj: &ProjectedKernels,
    bins: &TileBins,
    background: [f32; 3],
    exp: ExpMode,
    (forms, pool): (&mut Vec<RowForm>, &TileScratchPool),
    groups: &mut GroupBuffers,
    drain: &mut Drain<E>,
) -> Result<u64, E> {
    let frame = Frame::prepare(path, proj, bins, forms, background);
    stream_tile_rows(
        bins,
        groups,
        |ty, band| tile_row(path, exp, &frame, pool, ty, band),
        drain,
    )
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

/// Sums tile row `ty` of `frame` into `band` (its 16 image rows, or fewer at the bottom)
/// with a scratch of `pool`; returns its pairs. A run of tiles without kernels is the
/// background, written as such ([`fill_background`]) without setting the tiles up.
fn tile_row(
    path: SimdPath,
    exp: ExpMode,
    frame: &Frame,
    pool: &TileScratchPool,
    ty: usize,
    band: &mut [f32],
) -> u64 {
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
                pairs += tile_on(path, exp, frame, first + tx, scratch, band);
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

/// Prepares tile `t` of a frame into `scratch` and sums it into `band` (the image rows of
/// its tile row) with the loops compiled for `path` (which the CPU must have), as
/// [`rasterize_on`] does; the set-up stays in `scratch` for a backward of the same tile
/// ([`crate::backward::raster`]), and on the AVX-512 path its `G` too
/// ([`KeptGaussians`]). Returns the pairs.
#[allow(clippy::too_many_arguments)]
pub(crate) fn forward_tile_on(
    path: SimdPath,
    exp: ExpMode,
    bins: &TileBins,
    forms: &[RowForm],
    background: [f32; 3],
    t: usize,
    scratch: &mut TileScratch,
    band: &mut [f32],
) -> u64 {
    let frame = Frame {
        bins,
        forms,
        background: background.map(f64::from),
    };
    match (path, exp) {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: the caller checked that the CPU has the path's features.
        (SimdPath::Avx512, ExpMode::Poly) => unsafe {
            tile_avx512::<true, true>(&frame, t, scratch, band)
        },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as above.
        (SimdPath::Avx512, ExpMode::Std) => unsafe {
            tile_avx512::<false, true>(&frame, t, scratch, band)
        },
        _ => tile_on(path, exp, &frame, t, scratch, band),
    }
}

/// A tile's pixel geometry, for the per-kernel set-up.
#[derive(Clone, Copy)]
pub(crate) struct TileGeometry {
    /// The tile's pixel rectangle `[x0, x1, y0, y1]`.
    rect: [u32; 4],
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
struct RowReach {
    left: [bool; ROW],
    right: [bool; ROW],
    first_row: u32,
    end_row: u32,
}

/// `form`'s constants on the 16 rows from image row `j0` of the tile `tile` into `block`,
/// all at once and branch-free (vectorised); f64 throughout, no division or square root.
/// Rows outside the kernel's box are computed too (the caller drops them).
// `r` indexes the row offsets, the flags and the block's four arrays alike.
#[allow(clippy::needless_range_loop)]
#[inline(always)]
fn kernel_rows(form: &RowForm, tile: &TileGeometry, j0: u32, block: &mut RowBlock) -> RowReach {
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

/// Kernels are met in scene order, scattered in memory: asks for the record of the one 8
/// places after `n` now (a hint only; no effect on results).
#[inline(always)]
fn prefetch_form(forms: &[RowForm], entries: &[u32], n: usize) {
    #[cfg(target_arch = "x86_64")]
    if let Some(&ahead) = entries.get(n + 8) {
        // SAFETY: prefetching never faults; the pointer is in bounds anyway.
        unsafe {
            use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
            _mm_prefetch::<_MM_HINT_T0>(forms.as_ptr().add(ahead as usize).cast());
        }
    }
}

/// The AVX-512 loops' form of a prepared tile: per tile kernel its [`RowBlock`] (the tile's
/// 16 rows) and, per row, the tile kernels whose padded ellipse reaches a pixel centre of
/// that row, in list order — the union of the row's two half lists of [`prepare_tile`], held
/// as indices so that a kernel's rows are written once, as a block, and the lists are built
/// from the kernels' row masks 16 kernels at a time.
#[derive(Default)]
pub(crate) struct TileBlocks {
    pub(crate) kernels: Vec<TileKernel>,
    /// For each of `kernels`, its position in the tile's list (`TileBins::tile_entries`).
    pub(crate) entry_of: Vec<u32>,
    /// Per tile kernel, its rows (rows of the tile, 0 to 15).
    pub(crate) blocks: Vec<RowBlock>,
    /// Per tile kernel, bit `r` set when it is listed on row `r` (padded with zeros to a
    /// multiple of 16 when the lists are built).
    pub(crate) masks: Vec<u32>,
    /// Per row of the tile, its tile kernels in ascending order.
    pub(crate) rows: [Vec<u32>; ROW],
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

/// What every tile of a frame shares.
struct Frame<'a> {
    bins: &'a TileBins,
    forms: &'a [RowForm],
    background: [f64; 3],
}

impl<'a> Frame<'a> {
    /// The frame of `proj` binned in `bins` over `background`, its row forms computed into
    /// `forms`, after checking that the CPU has `path`'s instructions.
    fn prepare(
        path: SimdPath,
        proj: &ProjectedKernels,
        bins: &'a TileBins,
        forms: &'a mut Vec<RowForm>,
        background: [f32; 3],
    ) -> Self {
        path.assert_available();
        row_forms(proj, bins, forms);
        Frame {
            bins,
            forms,
            background: background.map(f64::from),
        }
    }
}

/// Prepares and sums tile `t` into `band` with the loops compiled for `path`.
fn tile_on(
    path: SimdPath,
    exp: ExpMode,
    frame: &Frame,
    t: usize,
    scratch: &mut TileScratch,
    band: &mut [f32],
) -> u64 {
    match (path, exp) {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: the caller ran `SimdPath::assert_available`: the CPU has the path's features.
        (SimdPath::Avx512, ExpMode::Poly) => unsafe {
            tile_avx512::<true, false>(frame, t, scratch, band)
        },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as above.
        (SimdPath::Avx512, ExpMode::Std) => unsafe {
            tile_avx512::<false, false>(frame, t, scratch, band)
        },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as above.
        (SimdPath::Avx2, ExpMode::Poly) => unsafe { tile_avx2::<true>(frame, t, scratch, band) },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as above.
        (SimdPath::Avx2, ExpMode::Std) => unsafe { tile_avx2::<false>(frame, t, scratch, band) },
        (_, ExpMode::Poly) => tile::<true, false>(frame, t, scratch, band),
        (_, ExpMode::Std) => tile::<false, false>(frame, t, scratch, band),
    }
}

/// The tile with AVX-512: [`avx512::prepare_tile`] (whole rows), then [`avx512::sum_tile`]
/// (16 lanes a row), keeping its `G` in `scratch.kept` when `KEEP`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,popcnt")]
fn tile_avx512<const FAST: bool, const KEEP: bool>(
    frame: &Frame,
    t: usize,
    scratch: &mut TileScratch,
    band: &mut [f32],
) -> u64 {
    avx512::prepare_tile::<true>(frame.bins, frame.forms, t, &mut scratch.whole_rows);
    let tiles = &scratch.whole_rows;
    if KEEP {
        scratch.kept.make_room(tiles.kernels.len());
    }
    let kept = &mut scratch.kept;
    avx512::sum_tile::<FAST, KEEP>(frame.bins, t, frame.background, tiles, band, kept)
}

/// [`tile`] compiled for AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn tile_avx2<const FAST: bool>(
    frame: &Frame,
    t: usize,
    scratch: &mut TileScratch,
    band: &mut [f32],
) -> u64 {
    tile::<FAST, true>(frame, t, scratch, band)
}

/// [`prepare_tile`] then [`sum_tile`], inlined into each path's compiled copy.
#[inline(always)]
fn tile<const FAST: bool, const AVX2: bool>(
    frame: &Frame,
    t: usize,
    scratch: &mut TileScratch,
    band: &mut [f32],
) -> u64 {
    prepare_tile(frame.bins, frame.forms, t, scratch);
    sum_tile::<FAST, AVX2>(frame.bins, t, frame.background, scratch, band)
}

/// Sums the entries of one half row into `acc` (set to the background first; `+ 0.0` makes
/// a background of -0 a +0, so that adding a lane's zero or skipping it cannot change a
/// sign). Lane `i` is pixel `first + i` of the tile row; lanes at or beyond `lanes` (past the
/// image's edge) never count. Returns the pairs.
#[inline(always)]
fn sum_half_row<const FAST: bool>(
    entries: &[RowEntry],
    kernels: &[TileKernel],
    first: f32,
    lanes: f32,
    background: [f64; 3],
    acc: &mut [[f64; LANES]; 3],
) -> u64 {
    for (channel, &b) in acc.iter_mut().zip(&background) {
        *channel = [b + 0.0; LANES];
    }
    let mut pairs = 0_u64;
    for entry in entries {
        let kernel = &kernels[entry.kernel as usize];
        let mut g = [0.0_f32; LANES];
        let mut inside = 0_u32;
        for (i, g) in g.iter_mut().enumerate() {
            let (_, value, hit) = entry.lane::<FAST>(kernel, first, lanes, i);
            *g = value;
            inside += u32::from(hit);
        }
        pairs += u64::from(inside);
        for (channel, &a) in acc.iter_mut().zip(&kernel.amplitude) {
            for i in 0..LANES {
                channel[i] += a * f64::from(g[i]);
            }
        }
    }
    pairs
}

/// Sums the prepared tile `t` half row by half row into `band` (the image rows of its tile
/// row): per half row, three f64 accumulators of 8 lanes start at the background and take
/// `a_c · G` (an exact f64 product of f32 values) for every entry, in ascending kernel
/// order; the half row is then rounded to f32 and written in place.
#[inline(always)]
fn sum_tile<const FAST: bool, const AVX2: bool>(
    bins: &TileBins,
    t: usize,
    background: [f64; 3],
    scratch: &TileScratch,
    band: &mut [f32],
) -> u64 {
    let rect = bins.tile_rect(t);
    let width = bins.width as usize;
    let mut pairs = 0_u64;
    for HalfRow {
        row,
        index,
        first,
        lanes,
    } in half_rows(rect)
    {
        let mut acc = [[0.0_f64; LANES]; 3];
        let entries = &scratch.halves[index];
        let (first_lane, lanes_f) = (first as f32, lanes as f32);
        pairs += if AVX2 {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: AVX2 is only asked for on the AVX2 and AVX-512 paths, which
            // `Frame::prepare` (or the training step's caller) checked the CPU has.
            unsafe {
                avx2::sum_half_row::<FAST>(
                    entries,
                    &scratch.kernels,
                    first_lane,
                    lanes_f,
                    background,
                    &mut acc,
                )
            }
            #[cfg(not(target_arch = "x86_64"))]
            unreachable!("AVX2 on x86-64 only")
        } else {
            sum_half_row::<FAST>(
                entries,
                &scratch.kernels,
                first_lane,
                lanes_f,
                background,
                &mut acc,
            )
        };
        let out = &mut band[3 * (row * width + rect[0] as usize + first)..][..3 * lanes];
        write_planes(&acc, out);
    }
    pairs
}

/// The half-row loop with AVX2 intrinsics: the operations of [`sum_half_row`] in the same
/// order, 8 lanes at a time, so the result is the same bit for bit: the f32 part fuses
/// exactly where the portable code calls `mul_add`, and the f64 accumulation `acc + a G`
/// rounds like the portable sum because `a G` is exact there.
#[cfg(target_arch = "x86_64")]
pub(crate) mod avx2 {
    use std::arch::x86_64::*;

    use super::{LANES, RowEntry, TileKernel};

    /// [`super::fast_exp_neg_half`] on 8 lanes: the same operations, the fused ones by FMA.
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    pub(crate) fn exp_neg_half(q: __m256) -> __m256 {
        use super::exp_constants::{
            HORNER, LN2_HI_TWICE, LN2_LO_TWICE, LOG2_E_NEG_HALF, Q_MAX, SHIFT,
        };
        let y = _mm256_min_ps(q, _mm256_set1_ps(Q_MAX));
        let shift = _mm256_set1_ps(SHIFT);
        let shifted = _mm256_fmadd_ps(y, _mm256_set1_ps(LOG2_E_NEG_HALF), shift);
        let n = _mm256_sub_ps(shifted, shift);
        let r = _mm256_fmadd_ps(n, _mm256_set1_ps(LN2_HI_TWICE), y);
        let r = _mm256_fmadd_ps(n, _mm256_set1_ps(LN2_LO_TWICE), r);
        let step = |p: __m256, c: f32| _mm256_fmadd_ps(r, p, _mm256_set1_ps(c));
        // Horner, as the scalar.
        let p = step(_mm256_set1_ps(HORNER[0]), HORNER[1]);
        let p = step(p, HORNER[2]);
        let p = step(p, HORNER[3]);
        let p = step(p, HORNER[4]);
        let p = step(p, HORNER[5]);
        let n_int = _mm256_sub_epi32(_mm256_castps_si256(shifted), _mm256_castps_si256(shift));
        let scale = _mm256_slli_epi32::<23>(_mm256_add_epi32(n_int, _mm256_set1_epi32(127)));
        _mm256_mul_ps(p, _mm256_castsi256_ps(scale))
    }

    /// The lane numbers 0..8 and the mask of the first `lanes` of them (inside the image).
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    pub(crate) fn lane_numbers(lanes: f32) -> (__m256, __m256) {
        let iota = _mm256_setr_ps(0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0);
        (
            iota,
            _mm256_cmp_ps::<_CMP_LT_OQ>(iota, _mm256_set1_ps(lanes)),
        )
    }

    /// [`RowEntry::lane`] on 8 lanes (`iota` and `valid` from [`lane_numbers`]): `t`, `q`
    /// and the mask of the pairs summed. `G` is [`gaussian`] of `q`, masked.
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    pub(crate) fn lanes(
        entry: &RowEntry,
        kernel: &TileKernel,
        (iota, valid): (__m256, __m256),
        first: f32,
    ) -> (__m256, __m256, __m256) {
        let t = _mm256_add_ps(
            _mm256_add_ps(iota, _mm256_set1_ps(first - entry.offset)),
            _mm256_set1_ps(entry.t_anchor),
        );
        let q = _mm256_fmadd_ps(
            _mm256_mul_ps(_mm256_set1_ps(kernel.qxx), t),
            t,
            _mm256_set1_ps(entry.row_q),
        );
        let hit = _mm256_and_ps(
            _mm256_cmp_ps::<_CMP_LE_OQ>(q, _mm256_set1_ps(kernel.qmax)),
            valid,
        );
        (t, q, hit)
    }

    /// `exp(-½ q)` on 8 lanes as [`super::gaussian`] evaluates it: the polynomial, or libm
    /// lane by lane.
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    pub(crate) fn gaussian<const FAST: bool>(q: __m256) -> __m256 {
        if FAST {
            return exp_neg_half(q);
        }
        let mut values = [0.0_f32; LANES];
        // SAFETY: `values` holds 8 floats.
        unsafe { _mm256_storeu_ps(values.as_mut_ptr(), q) };
        let values = values.map(|q| (-0.5 * q).exp());
        // SAFETY: as above.
        unsafe { _mm256_loadu_ps(values.as_ptr()) }
    }

    /// An entry's `G` on 8 lanes, masked, with its pair mask and its kernel's amplitudes.
    ///
    /// # Safety
    /// The CPU has AVX2 and FMA (a plain function, so that it is inlined into
    /// [`sum_half_row`], whose target features its intrinsics then take).
    #[inline(always)]
    unsafe fn entry_g<const FAST: bool>(
        entry: &RowEntry,
        kernels: &[TileKernel],
        numbers: (__m256, __m256),
        first: f32,
    ) -> ([f64; 3], __m256, __m256) {
        let kernel = &kernels[entry.kernel as usize];
        // SAFETY: the caller's promise (AVX2 and FMA).
        unsafe {
            let (_, q, hit) = lanes(entry, kernel, numbers, first);
            (
                kernel.amplitude,
                _mm256_and_ps(gaussian::<FAST>(q), hit),
                hit,
            )
        }
    }

    /// Adds an entry's `a_c G` to the accumulators; its pairs.
    ///
    /// # Safety
    /// As [`entry_g`]: the CPU has AVX2 and FMA.
    #[inline(always)]
    unsafe fn add_terms(
        (amplitude, g, hit): ([f64; 3], __m256, __m256),
        lo: &mut [__m256d; 3],
        hi: &mut [__m256d; 3],
    ) -> u64 {
        // SAFETY: the caller's promise (AVX2 and FMA).
        unsafe {
            let g_lo = _mm256_cvtps_pd(_mm256_castps256_ps128(g));
            let g_hi = _mm256_cvtps_pd(_mm256_extractf128_ps::<1>(g));
            // `a G` is exact in f64 (two 24-bit significands), so the fused multiply-add
            // rounds exactly as the portable loop's `acc + a G` does.
            for c in 0..3 {
                let a = _mm256_set1_pd(amplitude[c]);
                lo[c] = _mm256_fmadd_pd(a, g_lo, lo[c]);
                hi[c] = _mm256_fmadd_pd(a, g_hi, hi[c]);
            }
            u64::from(_mm256_movemask_ps(hit).count_ones())
        }
    }

    /// [`super::sum_half_row`] with AVX2.
    #[target_feature(enable = "avx2,fma")]
    pub(super) fn sum_half_row<const FAST: bool>(
        entries: &[RowEntry],
        kernels: &[TileKernel],
        first: f32,
        lanes: f32,
        background: [f64; 3],
        acc: &mut [[f64; LANES]; 3],
    ) -> u64 {
        let numbers = lane_numbers(lanes);
        let mut lo = background.map(|b| _mm256_set1_pd(b + 0.0));
        let mut hi = lo;
        let mut pairs = 0_u64;
        // Four entries at a time, their `G` first and then their terms in list order (the
        // same sums in the same order), as on the AVX-512 path.
        let mut fours = entries.chunks_exact(4);
        // SAFETY: this function has AVX2 and FMA (its callers checked the CPU).
        unsafe {
            for four in &mut fours {
                let values = [
                    entry_g::<FAST>(&four[0], kernels, numbers, first),
                    entry_g::<FAST>(&four[1], kernels, numbers, first),
                    entry_g::<FAST>(&four[2], kernels, numbers, first),
                    entry_g::<FAST>(&four[3], kernels, numbers, first),
                ];
                for value in values {
                    pairs += add_terms(value, &mut lo, &mut hi);
                }
            }
            for entry in fours.remainder() {
                let value = entry_g::<FAST>(entry, kernels, numbers, first);
                pairs += add_terms(value, &mut lo, &mut hi);
            }
        }
        for c in 0..3 {
            // SAFETY: each channel holds 8 doubles: 4 in `lo`, 4 in `hi`.
            unsafe {
                _mm256_storeu_pd(acc[c].as_mut_ptr(), lo[c]);
                _mm256_storeu_pd(acc[c].as_mut_ptr().add(4), hi[c]);
            }
        }
        pairs
    }
}

/// The forward's rows with AVX-512: a whole tile row (16 lanes) is the vector, and each row
/// list ([`avx512::prepare_tile`]) passes over six f64 accumulators of 8 lanes.
/// The operations per lane are [`avx2::sum_half_row`]'s in the same order (the same `t`, `q`,
/// test, polynomial and f64 products), so the image is the same bit for bit.
#[cfg(target_arch = "x86_64")]
pub(crate) mod avx512 {
    use std::arch::x86_64::*;

    use super::{
        ROW, RowBlock, RowForm, TileBlocks, TileGeometry, TileKernel, kernel_rows, prefetch_form,
        write_planes,
    };
    use crate::tiles::TileBins;

    /// Prepares tile `t` by whole rows into `tiles`: per kernel its [`RowBlock`] of the
    /// tile's 16 rows and its row mask (the rows whose padded chord reaches a pixel centre
    /// of either half, within its box), then per row the list of kernels whose mask has
    /// the row, 16 kernels at a time (compressed indices, in ascending order). A row's
    /// list is the union of its two half lists of [`super::prepare_tile`] in the same
    /// order, so summing it gives the same bits: a lane that no half list holds is never a
    /// pair, and adds an exact zero. Without `LISTS` the row lists are left as they were
    /// (the backward walks each kernel's mask instead).
    #[inline]
    #[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,popcnt")]
    pub(crate) fn prepare_tile<const LISTS: bool>(
        bins: &TileBins,
        forms: &[RowForm],
        t: usize,
        tiles: &mut TileBlocks,
    ) {
        let tile = TileGeometry::of(bins, t);
        let [_, _, ty0, ty1] = tile.rect;
        tiles.kernels.clear();
        tiles.entry_of.clear();
        tiles.masks.clear();
        // No list outlives its tile (the lists of rows past the image, or all of them
        // without `LISTS`, stay empty).
        for list in &mut tiles.rows {
            list.clear();
        }
        let entries = bins.tile_entries(t);
        if tiles.blocks.len() < entries.len() {
            tiles.blocks.resize(entries.len(), RowBlock::default());
        }
        for (n, &p) in entries.iter().enumerate() {
            prefetch_form(forms, entries, n);
            let form = &forms[p as usize];
            // Written in the next free block, which the next kernel overwrites unless this
            // one is kept.
            let block = &mut tiles.blocks[tiles.kernels.len()];
            let reach = kernel_rows(form, &tile, ty0, block);
            // The rows reached, as a mask read in one load (reading the flags one by one
            // stalled on the vector store that wrote them), within the kernel's rows.
            // SAFETY: each array holds 16 bools, one byte each.
            let (left, right) = unsafe {
                (
                    _mm_loadu_si128(reach.left.as_ptr().cast()),
                    _mm_loadu_si128(reach.right.as_ptr().cast()),
                )
            };
            let either = _mm_or_si128(left, right);
            let reached = u32::from(_mm_test_epi8_mask(either, either));
            let below = |row: u32| (1_u32 << (row - ty0)) - 1;
            let mask = reached & below(reach.end_row) & !below(reach.first_row);
            if mask != 0 {
                tiles.kernels.push(form.pixel);
                tiles.entry_of.push(n as u32);
                tiles.masks.push(mask);
            }
        }
        if !LISTS {
            return;
        }
        let count = tiles.masks.len();
        tiles.masks.resize(count.next_multiple_of(ROW), 0);
        let iota = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
        for (r, list) in tiles.rows[..(ty1 - ty0) as usize].iter_mut().enumerate() {
            // Each chunk stores 16 indices and keeps those of its kernels on the row.
            list.reserve(count + ROW);
            let out = list.as_mut_ptr();
            let bit = _mm512_set1_epi32(1 << r);
            let mut len = 0;
            for (c, chunk) in tiles.masks.chunks_exact(ROW).enumerate() {
                // SAFETY: the chunk holds 16 u32.
                let masks = unsafe { _mm512_loadu_si512(chunk.as_ptr().cast()) };
                let on_row = _mm512_test_epi32_mask(masks, bit);
                let indices = _mm512_add_epi32(iota, _mm512_set1_epi32((ROW * c) as i32));
                // SAFETY: `len` ≤ 16 c, and the list has room for `count + 16` ≥ 16 (c + 1).
                unsafe {
                    _mm512_storeu_si512(
                        out.add(len).cast(),
                        _mm512_maskz_compress_epi32(on_row, indices),
                    );
                }
                len += on_row.count_ones() as usize;
            }
            // SAFETY: the first `len` are written, each below `count`.
            unsafe { list.set_len(len) };
        }
    }

    /// [`super::avx2::exp_neg_half`] on 16 lanes, the same operations but the last.
    #[inline]
    #[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,popcnt")]
    pub(crate) fn exp_neg_half(q: __m512) -> __m512 {
        use super::exp_constants::{
            HORNER, LN2_HI_TWICE, LN2_LO_TWICE, LOG2_E_NEG_HALF, Q_MAX, SHIFT,
        };
        let y = _mm512_min_ps(q, _mm512_set1_ps(Q_MAX));
        let shift = _mm512_set1_ps(SHIFT);
        let shifted = _mm512_fmadd_ps(y, _mm512_set1_ps(LOG2_E_NEG_HALF), shift);
        let n = _mm512_sub_ps(shifted, shift);
        let r = _mm512_fmadd_ps(n, _mm512_set1_ps(LN2_HI_TWICE), y);
        let r = _mm512_fmadd_ps(n, _mm512_set1_ps(LN2_LO_TWICE), r);
        let step = |p: __m512, c: f32| _mm512_fmadd_ps(r, p, _mm512_set1_ps(c));
        let p = step(_mm512_set1_ps(HORNER[0]), HORNER[1]);
        let p = step(p, HORNER[2]);
        let p = step(p, HORNER[3]);
        let p = step(p, HORNER[4]);
        let p = step(p, HORNER[5]);
        // `p · 2ⁿ` in one instruction where the other paths assemble `2ⁿ` in the exponent
        // bits and multiply: `n` is a whole number in [-126, 0] and `2ⁿ` a normal f32, so
        // both round the same exact product once (the same bits, subnormal results too).
        _mm512_scalef_ps(p, n)
    }

    /// The lane numbers 0..16.
    #[inline]
    #[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,popcnt")]
    fn lane_numbers() -> __m512 {
        _mm512_setr_ps(
            0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0, 11.0, 12.0, 13.0, 14.0, 15.0,
        )
    }

    /// [`super::RowEntry::lane`] on the 16 lanes of tile row `row` of a kernel (its
    /// [`RowBlock`]): `t`, `q` and the mask of the pairs (within `valid`, the lanes inside
    /// the image). With `first` 0, `(lane + (0 - offset)) + t_anchor` is `(lane + shift) +
    /// t_anchor` (the same value: `lane + -0` is `lane + 0`).
    #[inline]
    #[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,popcnt")]
    pub(crate) fn row_lanes(
        kernel: &TileKernel,
        block: &RowBlock,
        row: usize,
        valid: __mmask16,
    ) -> (__m512, __m512, __mmask16) {
        let t = row_t(block, row);
        let q = _mm512_fmadd_ps(
            _mm512_mul_ps(_mm512_set1_ps(kernel.qxx), t),
            t,
            _mm512_set1_ps(block.row_q[row]),
        );
        let hit = _mm512_mask_cmp_ps_mask::<_CMP_LE_OQ>(valid, q, _mm512_set1_ps(kernel.qmax));
        (t, q, hit)
    }

    /// The lanes' `t` of [`row_lanes`], alone.
    #[inline]
    #[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,popcnt")]
    pub(crate) fn row_t(block: &RowBlock, row: usize) -> __m512 {
        _mm512_add_ps(
            _mm512_add_ps(lane_numbers(), _mm512_set1_ps(block.shift[row])),
            _mm512_set1_ps(block.t_anchor[row]),
        )
    }

    /// `exp(-½ q)` on 16 lanes as [`super::gaussian`] evaluates it.
    #[inline]
    #[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,popcnt")]
    pub(crate) fn gaussian<const FAST: bool>(q: __m512) -> __m512 {
        if FAST {
            return exp_neg_half(q);
        }
        let mut values = [0.0_f32; ROW];
        // SAFETY: `values` holds 16 floats.
        unsafe { _mm512_storeu_ps(values.as_mut_ptr(), q) };
        let values = values.map(|q| (-0.5 * q).exp());
        // SAFETY: as above.
        unsafe { _mm512_loadu_ps(values.as_ptr()) }
    }

    /// Tile kernel `k`'s `G` on tile row `row` (16 lanes), its pair mask and amplitudes; with
    /// `KEEP` also written to `kept` (non-pairs as +0).
    ///
    /// # Safety
    /// The CPU has the AVX-512 path's features (a plain function, so that it is inlined into
    /// [`sum_tile`], whose target features its intrinsics then take); `k` indexes
    /// `tiles.kernels` and `tiles.blocks` (an index of a row list); with `KEEP`,
    /// `make_room` gave `kept` 16 rows for each tile kernel.
    #[inline(always)]
    unsafe fn entry_g<const FAST: bool, const KEEP: bool>(
        tiles: &TileBlocks,
        k: u32,
        row: usize,
        valid: __mmask16,
        kept: &mut super::KeptGaussians,
    ) -> ([f64; 3], __m512, __mmask16) {
        debug_assert!((k as usize) < tiles.kernels.len());
        // SAFETY: the caller's promises: the features, `k` in range, and with `KEEP` the
        // room in `kept`.
        unsafe {
            let (kernel, block) = (
                tiles.kernels.get_unchecked(k as usize),
                tiles.blocks.get_unchecked(k as usize),
            );
            let (_, q, hit) = row_lanes(kernel, block, row, valid);
            let g = gaussian::<FAST>(q);
            if KEEP {
                let at = ROW * k as usize + row;
                let values = kept.values.get_unchecked_mut(at);
                _mm512_storeu_ps(values.as_mut_ptr(), _mm512_maskz_mov_ps(hit, g));
                *kept.hits.get_unchecked_mut(at) = hit;
            }
            (kernel.amplitude, g, hit)
        }
    }

    /// Adds `a_c G` of the pairs in `hit` to the six accumulators (lanes that are not pairs
    /// convert as +0, the mask's zeroing); the pairs (counted on the scalar side, off the
    /// vector pipes).
    ///
    /// # Safety
    /// The CPU has the AVX-512 path's features (as [`entry_g`]).
    #[inline(always)]
    unsafe fn add_terms(
        amplitude: [f64; 3],
        g: __m512,
        hit: __mmask16,
        lo: &mut [__m512d; 3],
        hi: &mut [__m512d; 3],
    ) -> u64 {
        // SAFETY: the caller's promise (the features).
        unsafe {
            let g_lo = _mm512_maskz_cvtps_pd(hit as __mmask8, _mm512_castps512_ps256(g));
            let g_hi =
                _mm512_maskz_cvtps_pd((hit >> 8) as __mmask8, _mm512_extractf32x8_ps::<1>(g));
            // `a G` is exact in f64, so the fused multiply-add rounds as `acc + a G`.
            for c in 0..3 {
                let a = _mm512_set1_pd(amplitude[c]);
                lo[c] = _mm512_fmadd_pd(a, g_lo, lo[c]);
                hi[c] = _mm512_fmadd_pd(a, g_hi, hi[c]);
            }
        }
        u64::from(hit.count_ones())
    }

    /// Sums the prepared tile `t` row by row into `band`: per row, six accumulators (three
    /// channels, two halves of 8 f64 lanes) start at the background and take every entry of
    /// the row's list; the row is then rounded to f32 and written in place.
    #[inline]
    #[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,popcnt")]
    pub(super) fn sum_tile<const FAST: bool, const KEEP: bool>(
        bins: &TileBins,
        t: usize,
        background: [f64; 3],
        tiles: &TileBlocks,
        band: &mut [f32],
        kept: &mut super::KeptGaussians,
    ) -> u64 {
        let [tx0, tx1, ty0, ty1] = bins.tile_rect(t);
        let width = bins.width as usize;
        let lanes = (tx1 - tx0) as usize;
        // Lanes past the image's right edge never count.
        let valid: __mmask16 = ((1_u32 << lanes) - 1) as __mmask16;
        let mut pairs = 0_u64;
        let mut acc = [[0.0_f64; ROW]; 3];
        for row in 0..(ty1 - ty0) as usize {
            let mut lo = background.map(|b| _mm512_set1_pd(b + 0.0));
            let mut hi = lo;
            // Four entries at a time: their four `G` first, then their terms in list order
            // (the same sums in the same order), so that the exps' dependent chains overlap
            // (100k@1080p, one thread: ~3 % faster than one entry at a time; eight measured
            // the same as four).
            let list = &tiles.rows[row];
            let mut fours = list.chunks_exact(4);
            // SAFETY: this function has the features (its callers checked the CPU); the
            // lists hold only indices of kept kernels, each with a block; with `KEEP`,
            // `make_room` gave `kept` 16 rows for each tile kernel.
            unsafe {
                for four in &mut fours {
                    let entries = [
                        entry_g::<FAST, KEEP>(tiles, four[0], row, valid, kept),
                        entry_g::<FAST, KEEP>(tiles, four[1], row, valid, kept),
                        entry_g::<FAST, KEEP>(tiles, four[2], row, valid, kept),
                        entry_g::<FAST, KEEP>(tiles, four[3], row, valid, kept),
                    ];
                    for (amplitude, g, hit) in entries {
                        pairs += add_terms(amplitude, g, hit, &mut lo, &mut hi);
                    }
                }
                for &k in fours.remainder() {
                    let (amplitude, g, hit) = entry_g::<FAST, KEEP>(tiles, k, row, valid, kept);
                    pairs += add_terms(amplitude, g, hit, &mut lo, &mut hi);
                }
            }
            for c in 0..3 {
                // SAFETY: each channel holds 16 doubles: 8 in `lo`, 8 in `hi`.
                unsafe {
                    _mm512_storeu_pd(acc[c].as_mut_ptr(), lo[c]);
                    _mm512_storeu_pd(acc[c].as_mut_ptr().add(8), hi[c]);
                }
            }
            write_planes(
                &acc,
                &mut band[3 * (row * width + tx0 as usize)..][..3 * lanes],
            );
        }
        pairs
    }
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

    /// The exp's steps on `x = -½ q` and `r`, as written before they ran on `-2 x` and
    /// `-2 r`: the definition [`fast_exp_neg_half`] must keep bit for bit.
    fn exp_neg_half_on_x(q: f32) -> f32 {
        const SHIFT: f32 = 12_582_912.0;
        let x = (-0.5 * q).max(-87.0);
        let shifted = x.mul_add(std::f32::consts::LOG2_E, SHIFT);
        let n = shifted - SHIFT;
        let r = (-n).mul_add(1.428_606_8e-6, (-n).mul_add(0.693_145_75, x));
        let p = r.mul_add(0.008_291_717, 0.041_915_03);
        let p = r.mul_add(p, 0.166_676_63);
        let p = r.mul_add(p, 0.499_989);
        let p = r.mul_add(p, 0.999_999_64);
        let p = r.mul_add(p, 1.000_000_1);
        let n_int = shifted.to_bits().wrapping_sub(SHIFT.to_bits()) as i32;
        p * f32::from_bits(((n_int + 127) as u32) << 23)
    }

    #[test]
    fn the_exp_on_scaled_steps_gives_the_exp_on_x_bit_for_bit() {
        // Dense over [0, 200] (past the clamp), every 4099th bit pattern of every f32
        // (negatives and NaNs included), and the specials. All 2³² agree as well (checked
        // once, 5 s on two cores: too long for the suite).
        let mut q = 0.0_f32;
        let mut checked = 0;
        while q <= 200.0 {
            assert_eq!(
                fast_exp_neg_half(q).to_bits(),
                exp_neg_half_on_x(q).to_bits(),
                "{q:e}"
            );
            q = (q + 1e-4).max(q.next_up());
            checked += 1;
        }
        let specials = [
            0.0,
            -0.0,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
            f32::MIN_POSITIVE,
            f32::from_bits(1),
            f32::from_bits(0x0040_0001),
            174.0,
            174.0_f32.next_up(),
            174.0_f32.next_down(),
            f32::MAX,
        ];
        let sampled = (0..=u32::MAX).step_by(4099).map(f32::from_bits);
        for q in specials.into_iter().chain(sampled) {
            let (new, old) = (fast_exp_neg_half(q), exp_neg_half_on_x(q));
            assert!(
                new.to_bits() == old.to_bits(),
                "{q:e}: {new:e} against {old:e}"
            );
            checked += 1;
        }
        assert!(checked > 2_900_000);
    }

    #[test]
    fn every_simd_path_gives_the_scalar_exp_bit_for_bit() {
        // Dense over [0, 200] (past the clamp), then every 65537th bit pattern of a
        // non-negative f32 (infinity and NaN included).
        let mut qs = Vec::new();
        let mut q = 0.0_f32;
        while q <= 200.0 {
            qs.push(q);
            q = (q + 1e-3).max(q.next_up());
        }
        qs.extend((0..0x7fff_ffff_u32).step_by(65_537).map(f32::from_bits));
        qs.resize(qs.len().next_multiple_of(ROW), 0.0);
        let scalar: Vec<u32> = qs.iter().map(|&q| fast_exp_neg_half(q).to_bits()).collect();
        for &path in SimdPath::available() {
            let mut values = vec![0.0_f32; qs.len()];
            for (q, g) in qs.chunks_exact(ROW).zip(values.chunks_exact_mut(ROW)) {
                match path {
                    #[cfg(target_arch = "x86_64")]
                    // SAFETY: `available` lists only paths this CPU runs; 16 floats each.
                    SimdPath::Avx512 => unsafe {
                        use std::arch::x86_64::{_mm512_loadu_ps, _mm512_storeu_ps};
                        let e = avx512::exp_neg_half(_mm512_loadu_ps(q.as_ptr()));
                        _mm512_storeu_ps(g.as_mut_ptr(), e);
                    },
                    #[cfg(target_arch = "x86_64")]
                    // SAFETY: as above, two halves of 8.
                    SimdPath::Avx2 => unsafe {
                        use std::arch::x86_64::{_mm256_loadu_ps, _mm256_storeu_ps};
                        for h in [0, 8] {
                            let e = avx2::exp_neg_half(_mm256_loadu_ps(q[h..].as_ptr()));
                            _mm256_storeu_ps(g[h..].as_mut_ptr(), e);
                        }
                    },
                    _ => g
                        .iter_mut()
                        .zip(q)
                        .for_each(|(g, &q)| *g = fast_exp_neg_half(q)),
                }
            }
            let differing = values
                .iter()
                .zip(&scalar)
                .zip(&qs)
                .find(|((g, s), _)| g.to_bits() != **s);
            assert!(differing.is_none(), "{path:?}: {differing:?}");
        }
    }

    #[test]
    fn tiles_without_kernels_are_the_background_a_tile_set_up_would_give() {
        use crate::render::{RenderContext, RenderOptions};
        // A few kernels in one corner: most tiles are empty, in runs, with partial tiles at
        // the right and the bottom. Every path, and backgrounds of −0 (written +0) and
        // other values, against each tile set up and summed ([`forward_tile_on`]).
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
                let pool = TileScratchPool::default();
                let mut image = Image::default();
                let pairs = rasterize_on(
                    path,
                    proj,
                    bins,
                    background,
                    ExpMode::Poly,
                    (&mut forms, &pool),
                    &mut image,
                );
                let mut expected = Image::filled(w, h, [f32::NAN; 3]);
                let mut scratch = TileScratch::default();
                let mut expected_pairs = 0;
                for (ty, band) in expected.pixels.chunks_mut(3 * w as usize * ROW).enumerate() {
                    for tx in 0..bins.tiles_x as usize {
                        let t = ty * bins.tiles_x as usize + tx;
                        expected_pairs += forward_tile_on(
                            path,
                            ExpMode::Poly,
                            bins,
                            &forms,
                            background,
                            t,
                            &mut scratch,
                            band,
                        );
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
            let pool = TileScratchPool::default();
            let mut first: Option<(Image, u64)> = None;
            for &path in paths {
                let mut image = Image::default();
                let pairs = rasterize_on(
                    path,
                    proj,
                    bins,
                    [0.1, 0.2, 0.3],
                    exp,
                    (&mut forms, &pool),
                    &mut image,
                );
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

    #[test]
    fn exp_modes_parse_and_print_as_written() {
        for mode in ExpMode::ALL {
            assert_eq!(mode.to_string().parse::<ExpMode>(), Ok(mode));
        }
        assert!("fast".parse::<ExpMode>().is_err());
    }
}
