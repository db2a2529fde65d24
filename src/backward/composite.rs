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
//! the entry of its half row's list that stopped it ([`PixelStop`]); a tile's list is set
//! up in the forward's chunks until every half row's list reaches its lanes' last stop (the
//! kernels after it add nothing), and each half row's entries are walked from there back to
//! the first, with the forward's lanes (the same `t`, `G` and
//! pairs), rebuilding `T_i = T_{i+1} / (1 - α̂_i)` in f64 (at most a few clamped kernels
//! before a stop: the division loses nothing measurable, tested against finite differences)
//! and carrying `R_i = S_i / T_{i+1}` from the back, so that `S_i / (1 - α̂_i) = R_i T_i`
//! needs no second division. Per kernel of a tile the nine sums are f64, kept lane by lane
//! and added over the lanes once per tile; the tiles' partials are reduced in entry order
//! (tile-major): no atomics, the same bits for any thread count or SIMD path.

use rayon::prelude::*;

use crate::backward::raster::{ScreenGradients, reduce};
use crate::composite::{
    CompositeScratch, MAX_ALPHA, PixelStop, chunks, clamped_alpha, entry_lanes,
    prepare_alpha_range, start_alpha_tile,
};
use crate::simd::{BinnedFrame, ExpMode, HalfRow, LANES, ROW, SimdPath, half_rows};

/// Per (tile, kernel) entry: `Σ ∂L/∂colour` (3), `Σ w t`, `Σ w t²`, `Σ w Δv`, `Σ w t Δv`,
/// `Σ w Δv²`, `Σ ∂L/∂α̂ G`.
pub(crate) type AlphaPartial = [f64; 9];

/// Scratch of one worker: a tile's set-up and its kernels' sums.
#[derive(Default)]
struct Scratch {
    composite: CompositeScratch,
    sums: Vec<LaneSums>,
}

/// One tile's backward: its set-up and where its kernels' sums go.
struct TileWork<'a> {
    tile: &'a mut CompositeScratch,
    sums: &'a mut Vec<LaneSums>,
}

thread_local! {
    static SCRATCH: std::cell::RefCell<Scratch> = std::cell::RefCell::new(Scratch::default());
}

/// Accumulates `∂L/∂C` (`v_image`, RGB row-major) of the alpha frame last composited
/// (`frame`, its kernels in depth order, on the forward's row forms, and the forward's
/// `stops`) into `out` (one entry per projected kernel, reset first) and returns `∂L/∂b`.
/// `partials` is scratch.
pub fn composite_backward(
    frame: &BinnedFrame,
    stops: &[PixelStop],
    v_image: &[f32],
    partials: &mut Vec<AlphaPartial>,
    out: &mut ScreenGradients,
) -> [f64; 3] {
    let (proj, bins) = (frame.proj, frame.bins);
    let width = bins.width as usize;
    assert_eq!(
        v_image.len(),
        3 * width * bins.height as usize,
        "∂L/∂C has the image's size"
    );
    assert_eq!(stops.len(), v_image.len() / 3, "the forward's pixel stops");
    let backward = Frame {
        binned: frame,
        stops,
        v_image,
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
                let Scratch { composite, sums } = scratch;
                let scratch = TileWork {
                    tile: composite,
                    sums,
                };
                let frame = &backward;
                match (frame.binned.path, frame.binned.exp) {
                    #[cfg(target_arch = "x86_64")]
                    // SAFETY: a frame's path is one the CPU has (`BinnedFrame`).
                    (SimdPath::Avx512, ExpMode::Poly) => unsafe {
                        backward_tile_avx512::<true>(frame, t, run, scratch)
                    },
                    #[cfg(target_arch = "x86_64")]
                    // SAFETY: as above.
                    (SimdPath::Avx512, ExpMode::Std) => unsafe {
                        backward_tile_avx512::<false>(frame, t, run, scratch)
                    },
                    #[cfg(target_arch = "x86_64")]
                    // SAFETY: as above.
                    (SimdPath::Avx2, ExpMode::Poly) => unsafe {
                        backward_tile_avx2::<true>(frame, t, run, scratch)
                    },
                    #[cfg(target_arch = "x86_64")]
                    // SAFETY: as above.
                    (SimdPath::Avx2, ExpMode::Std) => unsafe {
                        backward_tile_avx2::<false>(frame, t, run, scratch)
                    },
                    (_, ExpMode::Poly) => backward_tile::<true, false>(frame, t, run, scratch),
                    (_, ExpMode::Std) => backward_tile::<false, false>(frame, t, run, scratch),
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

/// What every tile of the frame's backward shares: the frame, the forward's stops and
/// `∂L/∂C`.
struct Frame<'a> {
    binned: &'a BinnedFrame<'a>,
    stops: &'a [PixelStop],
    v_image: &'a [f32],
}

/// [`backward_tile`] compiled for AVX-512 (the f64 lanes in one register; the same
/// operations: the same bits).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma")]
fn backward_tile_avx512<const FAST: bool>(
    frame: &Frame,
    t: usize,
    run: &mut [AlphaPartial],
    scratch: TileWork,
) -> [f64; 3] {
    backward_tile::<FAST, true>(frame, t, run, scratch)
}

/// [`backward_tile`] compiled for AVX2 and FMA (the same operations: the same bits).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn backward_tile_avx2<const FAST: bool>(
    frame: &Frame,
    t: usize,
    run: &mut [AlphaPartial],
    scratch: TileWork,
) -> [f64; 3] {
    backward_tile::<FAST, true>(frame, t, run, scratch)
}

/// Tile `t` (set up here in `scratch.composite`, as far as its pixels' stops reach) into
/// `run`, one partial per tile kernel set up (the entries after them are left as the caller
/// zeroed them: they add nothing);
/// returns the tile's `Σ v T_final`.
///
/// Per lane, walking a half row's entries back to front, with `R = S_i / T_{i+1}` (the
/// light behind kernel `i` per unit of the transmittance just behind it, `R = b` behind
/// the last kernel): `T_i = T_{i+1} / (1 - α̂_i)`, `∂L/∂α̂_i = T_i v · (colour_i - R)`, then
/// `R ← R (1 - α̂_i) + colour_i α̂_i` — one division per pair. The loop over the 8 lanes
/// is branch-free (a lane that is not a pair, or past its stop, takes `α̂ = 0`, which
/// leaves `T` and `R` as they are and adds `0` to sums that start at +0), and each tile
/// kernel keeps its nine sums lane by lane, added over the lanes (in lane order) once per
/// tile: no sum is carried from lane to lane inside the hot loop.
#[inline(always)]
fn backward_tile<const FAST: bool, const AVX2: bool>(
    frame: &Frame,
    t: usize,
    run: &mut [AlphaPartial],
    scratch: TileWork,
) -> [f64; 3] {
    let TileWork {
        tile: composite,
        sums,
    } = scratch;
    let bins = frame.binned.bins;
    let rect = bins.tile_rect(t);
    let [tx0, _, ty0, _] = rect;
    let width = bins.width as usize;
    // Set up here (so that the set-up is compiled for the path too), a chunk at a time as
    // the forward did, until every half row's list reaches its lanes' last stop.
    let mut needed = [0; 2 * ROW];
    for half in half_rows(rect) {
        let pixel = (ty0 as usize + half.row) * width + tx0 as usize + half.first;
        let stops = &frame.stops[pixel..pixel + half.lanes];
        needed[half.index] = stops
            .iter()
            .map(|stop| stop.end as usize)
            .max()
            .unwrap_or(0);
    }
    start_alpha_tile(bins, t, composite);
    for chunk in chunks(bins.tile_entries(t).len()) {
        prepare_alpha_range(frame.binned, t, chunk, composite);
        let halves = &composite.tile.halves;
        if halves.iter().zip(&needed).all(|(list, &n)| list.len() >= n) {
            break;
        }
    }
    let composite = &*composite;
    let tile = &composite.tile;
    sums.clear();
    sums.resize(tile.kernels.len(), [[0.0; LANES]; 9]);
    let mut v_background = [0.0; 3];
    for HalfRow {
        row,
        index,
        first,
        lanes,
    } in half_rows(rect)
    {
        let pixel = (ty0 as usize + row) * width + tx0 as usize + first;
        let mut state = LaneState::at_stops(frame, pixel, lanes);
        for (c, sum) in v_background.iter_mut().enumerate() {
            for i in 0..lanes {
                *sum += state.v[c][i] * state.transmittance[i];
            }
        }
        let entries = &tile.halves[index];
        let last = state.end.iter().copied().max().unwrap_or(0) as usize;
        for n in (0..last.min(entries.len())).rev() {
            let entry = &entries[n];
            let k = entry.kernel as usize;
            let kernel = &tile.kernels[k];
            let lanes_in = entry_lanes::<FAST, AVX2>(entry, kernel, first as f32, lanes as f32);
            state.step_back(
                n as u32,
                lanes_in,
                composite.opacities[k],
                kernel.amplitude,
                f64::from(entry.dv),
                &mut sums[k],
            );
        }
    }
    for (sum, &n) in sums.iter().zip(&tile.entry_of) {
        run[n as usize] = sum.map(|lanes| lanes.iter().sum());
    }
    v_background
}

/// Per tile kernel, its nine sums lane by lane.
type LaneSums = [[f64; LANES]; 9];

/// The backward's state of one half row's lanes.
struct LaneState {
    /// `∂L/∂C` per channel.
    v: [[f64; LANES]; 3],
    /// `T` just behind the next entry to walk (in front of the one walked last).
    transmittance: [f64; LANES],
    /// `R`, the light behind per unit transmittance, per channel.
    behind: [[f64; LANES]; 3],
    /// The forward's stop per lane (0 outside the image: nothing walked).
    end: [u32; LANES],
}

impl LaneState {
    /// The lanes of the half row whose first pixel is `pixel`, at their forward stops.
    #[inline(always)]
    fn at_stops(frame: &Frame, pixel: usize, lanes: usize) -> LaneState {
        let mut state = LaneState {
            v: [[0.0; LANES]; 3],
            transmittance: [1.0; LANES],
            behind: frame.binned.background.map(|b| [b; LANES]),
            end: [0; LANES],
        };
        for i in 0..lanes {
            let stop = frame.stops[pixel + i];
            state.transmittance[i] = stop.transmittance;
            state.end[i] = stop.end;
            for c in 0..3 {
                state.v[c][i] = f64::from(frame.v_image[3 * (pixel + i) + c]);
            }
        }
        state
    }

    /// Walks entry `n` (its lanes' `t`, `G` and pairs), adding its pairs' terms to `sums`.
    #[inline(always)]
    fn step_back(
        &mut self,
        n: u32,
        (t, g, hit): ([f32; LANES], [f32; LANES], [bool; LANES]),
        opacity: f64,
        colour: [f64; 3],
        dv: f64,
        sums: &mut LaneSums,
    ) {
        for i in 0..LANES {
            let live = hit[i] & (n < self.end[i]);
            let alpha = if live {
                clamped_alpha(opacity, g[i])
            } else {
                0.0
            };
            let through = 1.0 - alpha;
            let in_front_t = self.transmittance[i] / through;
            self.transmittance[i] = in_front_t;
            let weight = alpha * in_front_t;
            let mut v_dot = 0.0;
            for c in 0..3 {
                let v = self.v[c][i];
                v_dot += v * (colour[c] - self.behind[c][i]);
                self.behind[c][i] = self.behind[c][i] * through + colour[c] * alpha;
                sums[c][i] += v * weight;
            }
            let v_alpha = in_front_t * v_dot;
            // Clamped at 0.99 (or not a pair): nothing flows through α̂.
            let v_alpha = if live & (alpha < MAX_ALPHA) {
                v_alpha
            } else {
                0.0
            };
            let (t, w) = (f64::from(t[i]), v_alpha * alpha);
            sums[3][i] += w * t;
            sums[4][i] += w * t * t;
            sums[5][i] += w * dv;
            sums[6][i] += w * t * dv;
            sums[7][i] += w * dv * dv;
            sums[8][i] += v_alpha * f64::from(g[i]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::{RenderContext, RenderOptions};

    #[test]
    fn every_simd_path_gives_the_same_alpha_gradients_bit_for_bit() {
        // 161 × 97: partial tiles on the right and at the bottom.
        let camera = crate::scenes::synthetic::bench_camera(161, 97);
        let n = 3000;
        let scene = crate::scenes::synthetic::varied_alpha_bench_scene(n, 11, 0.1);
        let mut context = RenderContext::new();
        let options = RenderOptions::default();
        context
            .render_for_backward(&scene, &camera, 0.4, &options)
            .unwrap();
        let v_image: Vec<f32> = (0..context.image().pixels.len())
            .map(|i| ((i * 7919) % 211) as f32 / 105.0 - 1.0)
            .collect();
        let mut forms = Vec::new();
        let frame = BinnedFrame::new(
            &context.projected,
            &context.bins,
            &mut forms,
            [0.2, 0.3, 0.4],
            ExpMode::Poly,
        );
        let stops = context.pixel_stops().to_vec();
        let gradients = |path| {
            let mut out = ScreenGradients::default();
            let v_background =
                composite_backward(&frame.on(path), &stops, &v_image, &mut Vec::new(), &mut out);
            (out, v_background)
        };
        let (portable, portable_background) = gradients(SimdPath::Baseline);
        assert!(
            portable.v_opacities.iter().filter(|v| **v != 0.0).count() > 1000,
            "most kernels get an opacity gradient"
        );
        let bits = |g: &ScreenGradients| {
            let mut bits: Vec<u64> = Vec::new();
            for p in 0..g.v_opacities.len() {
                bits.extend(g.v_amplitudes[p].map(f64::to_bits));
                bits.extend(g.v_means[p].map(f64::to_bits));
                bits.extend(g.v_covariances[p].map(f64::to_bits));
                bits.push(g.v_opacities[p].to_bits());
            }
            bits
        };
        for &path in SimdPath::available() {
            let (vector, vector_background) = gradients(path);
            assert!(bits(&portable) == bits(&vector), "{path} differs");
            assert_eq!(
                portable_background.map(f64::to_bits),
                vector_background.map(f64::to_bits)
            );
        }
    }
}
