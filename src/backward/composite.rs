//! Backward of the alpha compositing stage (SPEC §8): from `∂L/∂C` per pixel to per
//! projected kernel `∂L/∂colour`, `∂L/∂o(τ)`, `∂L/∂m2` and `∂L/∂Σ2`.
//!
//! A pixel is `Σ_i colour_i α̂_i T_i + T_final b` over the kernels it composited (pairs, order
//! and stop held constant), `T_i = Π_{j<i} (1 - α̂_j)`. With `v = ∂L/∂C` and the light
//! behind kernel `i`, `S_i = Σ_{j>i} colour_j α̂_j T_j + T_final b`:
//!
//! ```text
//! ∂L/∂colour_i += v α̂_i T_i
//! ∂L/∂α̂_i      = v · (colour_i T_i - S_i / (1 - α̂_i))
//! α̂ = o(τ) G unclamped:  ∂L/∂o(τ) += ∂L/∂α̂ G,   w = ∂L/∂α̂ α̂,  ∂L/∂q = -½ w
//! α̂ = 0.99 (clamped):    nothing through α̂
//! ∂L/∂b        += v T_final
//! ```
//!
//! and `w` goes to `m2` and `Σ2` through the additive raster's moments of `(t, Δv)` (see
//! [`crate::backward::raster`]). The forward kept, per pixel, its final transmittance and
//! the entry of its half row's list that stopped it ([`PixelStop`]); each half row's entries
//! are walked from there back to the first, with the forward's lanes (the same `t`, `G` and
//! pairs), rebuilding `T_i = T_{i+1} / (1 - α̂_i)` in f64 (at most a few clamped kernels
//! before a stop: the division loses nothing measurable, tested against finite differences)
//! and building `S_i` from the back. Per kernel of a tile the nine sums are f64; the tiles'
//! partials are reduced in entry order (tile-major): no atomics, the same bits for any
//! thread count or SIMD path.

use rayon::prelude::*;

use crate::backward::raster::{ScreenGradients, reduce};
use crate::composite::{
    CompositeScratch, MAX_ALPHA, PixelStop, clamped_alpha, entry_lanes, prepare_alpha_tile,
};
use crate::project::ProjectedKernels;
use crate::raster::{ExpMode, HalfRow, LANES, RowForm, SimdPath, half_rows};
use crate::tiles::TileBins;

/// Per (tile, kernel) entry: `Σ ∂L/∂colour` (3), `Σ w t`, `Σ w t²`, `Σ w Δv`, `Σ w t Δv`,
/// `Σ w Δv²`, `Σ ∂L/∂α̂ G`.
pub(crate) type AlphaPartial = [f64; 9];

/// Scratch of one worker.
#[derive(Default)]
struct Scratch {
    composite: CompositeScratch,
    sums: Vec<AlphaPartial>,
}

thread_local! {
    static SCRATCH: std::cell::RefCell<Scratch> = std::cell::RefCell::new(Scratch::default());
}

/// Accumulates `∂L/∂C` (`v_image`, RGB row-major) of the alpha frame last composited
/// (`proj` in depth order, `bins`, `forms` and `stops` of that frame) into `out` (one entry
/// per projected kernel, reset first) and returns `∂L/∂b`. `partials` is scratch.
#[allow(clippy::too_many_arguments)]
pub fn composite_backward(
    proj: &ProjectedKernels,
    bins: &TileBins,
    forms: &[RowForm],
    stops: &[PixelStop],
    background: [f32; 3],
    v_image: &[f32],
    exp: ExpMode,
    partials: &mut Vec<AlphaPartial>,
    out: &mut ScreenGradients,
) -> [f64; 3] {
    composite_backward_on(
        SimdPath::detect(),
        proj,
        bins,
        forms,
        stops,
        background,
        v_image,
        exp,
        partials,
        out,
    )
}

/// [`composite_backward`] on `path` (which the CPU must have).
#[allow(clippy::too_many_arguments)]
pub(crate) fn composite_backward_on(
    path: SimdPath,
    proj: &ProjectedKernels,
    bins: &TileBins,
    forms: &[RowForm],
    stops: &[PixelStop],
    background: [f32; 3],
    v_image: &[f32],
    exp: ExpMode,
    partials: &mut Vec<AlphaPartial>,
    out: &mut ScreenGradients,
) -> [f64; 3] {
    assert!(
        SimdPath::available().contains(&path),
        "this CPU cannot run {path}"
    );
    let width = bins.width as usize;
    assert_eq!(
        v_image.len(),
        3 * width * bins.height as usize,
        "∂L/∂C has the image's size"
    );
    assert_eq!(forms.len(), proj.len(), "the forward's row forms");
    assert_eq!(stops.len(), v_image.len() / 3, "the forward's pixel stops");
    let background = background.map(f64::from);
    let frame = Frame {
        bins,
        stops,
        v_image,
        background,
    };
    partials.clear();
    partials.resize(bins.proj_from_entry.len(), [0.0; 9]);
    let mut runs = Vec::with_capacity(bins.tile_count());
    let mut rest = partials.as_mut_slice();
    for t in 0..bins.tile_count() {
        let (run, tail) = rest.split_at_mut(bins.tile_entries(t).len());
        runs.push((t, run));
        rest = tail;
    }
    let v_backgrounds: Vec<[f64; 3]> = runs
        .into_par_iter()
        .map(|(t, run)| {
            SCRATCH.with(|cell| {
                let scratch = &mut *cell.borrow_mut();
                prepare_alpha_tile(proj, bins, forms, t, &mut scratch.composite);
                match (path, exp) {
                    #[cfg(target_arch = "x86_64")]
                    // SAFETY: checked above that the CPU has the path's features.
                    (SimdPath::Avx2 | SimdPath::Avx512, ExpMode::Poly) => unsafe {
                        backward_tile_avx2::<true>(&frame, t, run, scratch)
                    },
                    #[cfg(target_arch = "x86_64")]
                    // SAFETY: as above.
                    (SimdPath::Avx2 | SimdPath::Avx512, ExpMode::Std) => unsafe {
                        backward_tile_avx2::<false>(&frame, t, run, scratch)
                    },
                    (_, ExpMode::Poly) => backward_tile::<true, false>(&frame, t, run, scratch),
                    (_, ExpMode::Std) => backward_tile::<false, false>(&frame, t, run, scratch),
                }
            })
        })
        .collect();
    reduce(proj, bins, partials, &mut Vec::new(), out);
    let mut v_background = [0.0; 3];
    for tile in v_backgrounds {
        for (sum, v) in v_background.iter_mut().zip(tile) {
            *sum += v;
        }
    }
    v_background
}

/// What every tile of the frame's backward shares.
struct Frame<'a> {
    bins: &'a TileBins,
    stops: &'a [PixelStop],
    v_image: &'a [f32],
    background: [f64; 3],
}

/// [`backward_tile`] compiled for AVX2 and FMA (the same operations: the same bits).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn backward_tile_avx2<const FAST: bool>(
    frame: &Frame,
    t: usize,
    run: &mut [AlphaPartial],
    scratch: &mut Scratch,
) -> [f64; 3] {
    backward_tile::<FAST, true>(frame, t, run, scratch)
}

/// Tile `t` (prepared in `scratch.composite`) into `run`, one partial per tile entry;
/// returns the tile's `Σ v T_final`.
#[inline(always)]
fn backward_tile<const FAST: bool, const AVX2: bool>(
    frame: &Frame,
    t: usize,
    run: &mut [AlphaPartial],
    scratch: &mut Scratch,
) -> [f64; 3] {
    let Scratch { composite, sums } = scratch;
    let tile = &composite.tile;
    sums.clear();
    sums.resize(tile.kernels.len(), [0.0; 9]);
    let rect = frame.bins.tile_rect(t);
    let [tx0, _, ty0, _] = rect;
    let width = frame.bins.width as usize;
    let background = frame.background;
    let mut v_background = [0.0; 3];
    for HalfRow {
        row,
        index,
        first,
        lanes,
    } in half_rows(rect)
    {
        let entries = &tile.halves[index];
        let (first_lane, lanes_f) = (first as f32, lanes as f32);
        let pixel = (ty0 as usize + row) * width + tx0 as usize + first;
        // ∂L/∂C, the final transmittance and the end of each lane; nothing past the edge.
        let mut v = [[0.0_f64; LANES]; 3];
        let mut transmittance = [1.0_f64; LANES];
        let mut end = [0_u32; LANES];
        let mut behind = [[0.0_f64; LANES]; 3];
        for i in 0..lanes {
            let stop = frame.stops[pixel + i];
            transmittance[i] = stop.transmittance;
            end[i] = stop.end;
            for c in 0..3 {
                v[c][i] = f64::from(frame.v_image[3 * (pixel + i) + c]);
                // The light behind the last kernel: the background's share.
                behind[c][i] = stop.transmittance * background[c];
                v_background[c] += v[c][i] * stop.transmittance;
            }
        }
        let last = end.iter().copied().max().unwrap_or(0) as usize;
        for n in (0..last.min(entries.len())).rev() {
            let entry = &entries[n];
            let k = entry.kernel as usize;
            let kernel = &tile.kernels[k];
            let opacity = composite.opacities[k];
            let (t, g, hit) = entry_lanes::<FAST, AVX2>(entry, kernel, first_lane, lanes_f);
            let dv = f64::from(entry.dv);
            let sum = &mut sums[k];
            for i in 0..LANES {
                if !(hit[i] && (n as u32) < end[i]) {
                    continue;
                }
                let alpha = clamped_alpha(opacity, g[i]);
                // T in front of this kernel, from the one behind it.
                let in_front_t = transmittance[i] / (1.0 - alpha);
                transmittance[i] = in_front_t;
                let weight = alpha * in_front_t;
                // ∂L/∂α̂ = T Σ_c v_c colour_c - (Σ_c v_c S_c) / (1 - α̂)
                let (mut in_front, mut light_behind) = (0.0, 0.0);
                for c in 0..3 {
                    let colour = kernel.amplitude[c];
                    in_front += v[c][i] * colour;
                    light_behind += v[c][i] * behind[c][i];
                    behind[c][i] += colour * weight;
                    sum[c] += v[c][i] * weight;
                }
                let v_alpha = in_front_t * in_front - light_behind / (1.0 - alpha);
                if alpha < MAX_ALPHA {
                    let t = f64::from(t[i]);
                    let w = v_alpha * alpha;
                    sum[3] += w * t;
                    sum[4] += w * t * t;
                    sum[5] += w * dv;
                    sum[6] += w * t * dv;
                    sum[7] += w * dv * dv;
                    sum[8] += v_alpha * f64::from(g[i]);
                }
            }
        }
    }
    for (sum, &n) in sums.iter().zip(&tile.entry_of) {
        run[n as usize] = *sum;
    }
    v_background
}
