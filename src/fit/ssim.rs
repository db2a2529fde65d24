//! The photometric loss of 3D Gaussian splatting, `(1 - λ) L1 + λ (1 - SSIM)`, and its
//! gradient with respect to the rendered pixels (an opt-in training loss; SPEC §6's MSE stays
//! the loss every fit reports and the PSNR's).
//!
//! **SSIM map** (Wang, Bovik, Sheikh, Simoncelli 2004, as 3DGS trains with it): per channel,
//! local means `μx, μy`, second moments `E[x²], E[y²], E[xy]` under an 11×11 Gaussian window
//! (σ = 1.5, the outer product of a 1D window normalised to sum 1) centred on every pixel, the
//! image zero-padded outside (a window is never shrunk; images smaller than it are padded the
//! same way), `σx² = E[x²] - μx²`, `σxy = E[xy] - μx μy`, and
//! `S = (2 μx μy + C1)(2 σxy + C2) / ((μx² + μy² + C1)(σx² + σy² + C2))` with `C1 = 0.01²`,
//! `C2 = 0.03²` (dynamic range 1).
//!
//! **Loss** of a rendered image `C` against its target `T` with per-pixel weights `w_p`
//! ([`View::weights`]; 1 everywhere without them), `W = Σ_p w_p`:
//! `L = Σ_p w_p Σ_c [(1 - λ) |C - T| + λ (1 - S)] / (3 W)`, the SSIM map taken of `w ⊙ C`
//! against `w ⊙ T`: a pixel of weight 0 is zero in both images in every window around it and
//! its own terms do not count, so it takes no part in the loss and gets no gradient. `L = 0`
//! when every weight is 0. `∂|x|/∂x` at 0 is 0.
//!
//! **Gradient**: with `a_p = w_p / (3 W)` and the map's partial derivatives
//! `∂S/∂μx = 2 μy (B - A)/(C D) + 2 μx S (1/D - 1/C)`, `∂S/∂E[x²] = -S/D`,
//! `∂S/∂E[xy] = 2 A/(C D)` (`A, B, C, D` the four factors above), the maps
//! `M1 = -λ a ∂S/∂μx`, `M2 = -λ a ∂S/∂E[x²]`, `M3 = -λ a ∂S/∂E[xy]` are filtered again by the
//! same window (its own transpose: the zero-padded filter of a symmetric window), and
//! `∂L/∂C_q = w_q (G*M1 + 2 x_q G*M2 + y_q G*M3)_q + (1 - λ) a_q sign(C_q - T_q)`, with
//! `x = w ⊙ C`, `y = w ⊙ T`.
//!
//! The fast path ([`L1Dssim::loss_and_gradient`]) filters in f32 (each window separable: a
//! row pass, then a column pass, each output a sum over its taps in order, 32 outputs at a
//! time in registers) and sums the loss in f64 in [`sum_in_blocks`]'s fixed order: the same
//! bits on any thread count. Its line loops are compiled for each [`SimdPath`] and run on the
//! widest the CPU has; each is one IEEE operation per value, none fused, so the same bits on
//! every path. Its twin
//! [`reference_loss`] / [`reference_gradient`] does everything in f64 from the definitions
//! (2D windows summed directly, the gradient by the chain rule window by window).

use rayon::prelude::*;

use crate::fit::loss::{SSIM_C1, SSIM_C2, SSIM_SIGMA, SSIM_WINDOW};
use crate::model::{Image, View};
use crate::parallel::{lane_sum, sum_in_blocks};
use crate::simd::{LineJob, SimdPath, on_path};

/// Side of the training SSIM's window: the reported SSIM's ([`crate::fit::loss::ssim`]).
pub const WINDOW: usize = SSIM_WINDOW;
/// Standard deviation of its Gaussian, pixels.
pub const SIGMA: f64 = SSIM_SIGMA;
/// `C1 = (0.01 L)²`, `L = 1`.
pub const C1: f64 = SSIM_C1;
/// `C2 = (0.03 L)²`, `L = 1`.
pub const C2: f64 = SSIM_C2;
/// Half the window: the taps reach this far on each side.
const HALF: usize = WINDOW / 2;

/// The 1D window: `exp(-k² / 2σ²)` for `k = -5..=5`, normalised to sum 1, in f64.
#[must_use]
pub fn window() -> [f64; WINDOW] {
    let mut g = [0.0; WINDOW];
    for (i, v) in g.iter_mut().enumerate() {
        let k = i as f64 - HALF as f64;
        *v = (-k * k / (2.0 * SIGMA * SIGMA)).exp();
    }
    let total: f64 = g.iter().sum();
    g.map(|v| v / total)
}

/// The buffers of [`L1Dssim::loss_and_gradient`], kept between calls (one per view slot).
#[derive(Default)]
pub struct SsimScratch {
    /// Each channel value's weight.
    weights: ChannelWeights,
    /// `x, y, x², y², xy`.
    maps: [Vec<f32>; 5],
    /// Their filtered values `μx, μy, E[x²], E[y²], E[xy]`.
    filtered: [Vec<f32>; 5],
    /// The row pass's output.
    rows: Vec<f32>,
    /// `M1, M2, M3`.
    back: [Vec<f32>; 3],
    /// Their filtered values.
    back_filtered: [Vec<f32>; 3],
}

/// The loss `(1 - λ) L1 + λ (1 - SSIM)` of the module docs, `λ = dssim_weight`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct L1Dssim {
    /// `λ`, in `[0, 1]`.
    pub dssim_weight: f64,
}

/// `Σ_p w_p` in f64 in a fixed order, and whether the weights are there.
fn total_weight(weights: Option<&[f32]>, pixels: usize) -> f64 {
    match weights {
        None => pixels as f64,
        Some(w) => {
            let [total] = sum_in_blocks(w.len(), |range| {
                [lane_sum(range.len(), |i| f64::from(w[range.start + i]))]
            });
            total
        }
    }
}

/// One line of a filter pass: `out[i] = g[HALF] c[i] + Σ_{k < HALF} g[k] (lo_k[i] +
/// hi_k[i])`, the taps paired by the window's symmetry (`taps[k] = (lo_k, hi_k)`: the inputs
/// `HALF - k` before and after; `c` the centre), summed in that order. Each block of
/// [`BLOCK`] outputs is summed in registers over all its taps and stored once.
struct TapsLine<'a> {
    out: &'a mut [f32],
    centre: &'a [f32],
    taps: [(&'a [f32], &'a [f32]); HALF],
    g: &'a [f32; WINDOW],
}

/// Outputs [`TapsLine`] sums in registers at once: two AVX-512 registers, four AVX2.
const BLOCK: usize = 32;

impl LineJob for TapsLine<'_> {
    #[inline(always)]
    fn run(self) {
        let TapsLine {
            out,
            centre,
            taps,
            g,
        } = self;
        let n = out.len();
        // Whole blocks, the last one ending at the line's end (overlapping the one before:
        // its values are written twice, the same); a line shorter than a block is summed
        // value by value.
        let whole = n / BLOCK * BLOCK;
        let last = (whole < n && n >= BLOCK).then_some(n - BLOCK);
        for at in (0..whole).step_by(BLOCK).chain(last) {
            // Slices of BLOCK values: their indices below need no check.
            let mut sum = [0.0_f32; BLOCK];
            let c = &centre[at..at + BLOCK];
            for j in 0..BLOCK {
                sum[j] = g[HALF] * c[j];
            }
            for (&(lo, hi), &gk) in taps.iter().zip(g) {
                let (lo, hi) = (&lo[at..at + BLOCK], &hi[at..at + BLOCK]);
                for j in 0..BLOCK {
                    sum[j] += gk * (lo[j] + hi[j]);
                }
            }
            out[at..at + BLOCK].copy_from_slice(&sum);
        }
        if n < BLOCK {
            for i in 0..n {
                let mut sum = g[HALF] * centre[i];
                for (&(lo, hi), &gk) in taps.iter().zip(g) {
                    sum += gk * (lo[i] + hi[i]);
                }
                out[i] = sum;
            }
        }
    }
}

/// Filters the interleaved RGB plane `src` (`width × height` pixels) by the separable window
/// `g`, zero-padded ("same" size), into `dst`, through `rows` (both resized): a row pass,
/// then a column pass, each output line a [`TapsLine`], on `path`.
fn blur(
    path: SimdPath,
    src: &[f32],
    (dst, rows): (&mut Vec<f32>, &mut Vec<f32>),
    width: usize,
    g: &[f32; WINDOW],
) {
    let stride = 3 * width;
    // Every value is written below.
    rows.resize(src.len(), 0.0);
    dst.resize(src.len(), 0.0);
    if stride == 0 {
        return;
    }
    let height = src.len() / stride;
    // Row pass, the row padded with HALF zero pixels on each side.
    rows.par_chunks_mut(stride)
        .zip(src.par_chunks(stride))
        .for_each_init(
            || vec![0.0_f32; stride + 6 * HALF],
            |padded, (out, row)| {
                padded[3 * HALF..3 * HALF + stride].copy_from_slice(row);
                let padded = &*padded;
                let at = |k: usize| &padded[3 * k..3 * k + stride];
                let taps = std::array::from_fn(|k| (at(k), at(WINDOW - 1 - k)));
                on_path(
                    path,
                    TapsLine {
                        out,
                        centre: at(HALF),
                        taps,
                        g,
                    },
                );
            },
        );
    // Column pass, rows outside the image zero.
    let rows = &*rows;
    let zeros = vec![0.0_f32; stride];
    let zeros = &zeros[..];
    let row = |r: isize| {
        if r < 0 || r >= height as isize {
            zeros
        } else {
            &rows[r as usize * stride..(r as usize + 1) * stride]
        }
    };
    dst.par_chunks_mut(stride).enumerate().for_each(|(y, out)| {
        let y = y as isize;
        let half = HALF as isize;
        let taps =
            std::array::from_fn(|k| (row(y - half + k as isize), row(y + half - k as isize)));
        on_path(
            path,
            TapsLine {
                out,
                centre: row(y),
                taps,
                g,
            },
        );
    });
}

/// Each channel value's weight `w_p` (pixel `p = k / 3`), 1 everywhere without weights:
/// the ones kept between calls (refilled when the size changes), given weights laid out on
/// every call.
#[derive(Default)]
struct ChannelWeights {
    values: Vec<f32>,
    /// Whether `values` are all 1.
    ones: bool,
}

impl ChannelWeights {
    /// The weights of `n` channel values from the per-pixel `weights`.
    fn of(&mut self, weights: Option<&[f32]>, n: usize) -> &[f32] {
        match weights {
            Some(w) => {
                assert_eq!(w.len(), n / 3, "one weight per pixel");
                self.values.clear();
                self.values.extend(w.iter().flat_map(|&w| [w; 3]));
                self.ones = false;
            }
            None if self.ones && self.values.len() == n => {}
            None => {
                self.values.clear();
                self.values.resize(n, 1.0);
                self.ones = true;
            }
        }
        &self.values
    }
}

/// One line of `x = w c`, `y = w t` and `x², y², xy` (all slices one line long).
struct ProductsLine<'a> {
    /// The render, the target and the weights.
    inputs: (&'a [f32], &'a [f32], &'a [f32]),
    /// `x, y, x², y², xy`.
    out: [&'a mut [f32]; 5],
}

impl LineJob for ProductsLine<'_> {
    #[inline(always)]
    fn run(self) {
        let ((c, t, w), [x, y, xx, yy, xy]) = (self.inputs, self.out);
        let n = x.len();
        let (c, t, w) = (&c[..n], &t[..n], &w[..n]);
        let (y, xx, yy, xy) = (&mut y[..n], &mut xx[..n], &mut yy[..n], &mut xy[..n]);
        for i in 0..n {
            let (a, b) = (w[i] * c[i], w[i] * t[i]);
            (x[i], y[i], xx[i], yy[i], xy[i]) = (a, b, a * a, b * b, a * b);
        }
    }
}

/// One line of the SSIM map `S` and `M1, M2, M3` (the module docs, times `scale w`) from
/// its filtered moments (all slices one line long).
struct MapLine<'a> {
    /// `μx, μy, E[x²], E[y²], E[xy]`.
    moments: [&'a [f32]; 5],
    /// The weights and `scale`.
    weights: (&'a [f32], f32),
    /// `S, M1, M2, M3`.
    out: [&'a mut [f32]; 4],
}

impl LineJob for MapLine<'_> {
    #[inline(always)]
    fn run(self) {
        let [mx, my, exx, eyy, exy] = self.moments;
        let ((w, scale), [map, m1, m2, m3]) = (self.weights, self.out);
        let (c1, c2) = (C1 as f32, C2 as f32);
        let n = map.len();
        let (mx, my, exx, eyy, exy, w) =
            (&mx[..n], &my[..n], &exx[..n], &eyy[..n], &exy[..n], &w[..n]);
        let (m1, m2, m3) = (&mut m1[..n], &mut m2[..n], &mut m3[..n]);
        for i in 0..n {
            let (ux, uy) = (mx[i], my[i]);
            let a = 2.0 * ux * uy + c1;
            let b = 2.0 * (exy[i] - ux * uy) + c2;
            let cc = ux * ux + uy * uy + c1;
            let d = (exx[i] - ux * ux) + (eyy[i] - uy * uy) + c2;
            // 1/(C D); 1/D - 1/C = (C - D)/(C D); 1/D = C/(C D).
            let inv = 1.0 / (cc * d);
            let s = a * b * inv;
            let m = scale * w[i];
            map[i] = s;
            m1[i] = m * (2.0 * uy * (b - a) * inv + 2.0 * ux * s * ((cc - d) * inv));
            m2[i] = m * (-s * cc * inv);
            m3[i] = m * (2.0 * a * inv);
        }
    }
}

/// One line of `∂L/∂C = w (G*M1 + 2 x G*M2 + y G*M3) + l1 w sign(c - t)` (all slices one
/// line long; the sign 0 where `c = t` or either is NaN).
struct GradientLine<'a> {
    /// The render, the target and the weights.
    inputs: (&'a [f32], &'a [f32], &'a [f32]),
    /// `G*M1, G*M2, G*M3`, `x` and `y`.
    filtered: ([&'a [f32]; 3], &'a [f32], &'a [f32]),
    /// `(1 - λ) scale`.
    l1: f32,
    out: &'a mut [f32],
}

impl LineJob for GradientLine<'_> {
    #[inline(always)]
    fn run(self) {
        let ((c, t, w), ([g1, g2, g3], x, y), v) = (self.inputs, self.filtered, self.out);
        let n = v.len();
        let (c, t, w, g1, g2, g3, x, y) = (
            &c[..n],
            &t[..n],
            &w[..n],
            &g1[..n],
            &g2[..n],
            &g3[..n],
            &x[..n],
            &y[..n],
        );
        for i in 0..n {
            let sign = if c[i] > t[i] {
                1.0
            } else if c[i] < t[i] {
                -1.0
            } else {
                0.0
            };
            let w = w[i];
            v[i] = w * (g1[i] + 2.0 * x[i] * g2[i] + y[i] * g3[i]) + self.l1 * w * sign;
        }
    }
}

impl L1Dssim {
    /// The loss of `image` against `view` (its target and weights; the module docs), and
    /// `weight ∂L/∂C` into `v_image` (resized); `scratch` holds the buffers between calls.
    pub fn loss_and_gradient(
        &self,
        image: &Image,
        view: &View,
        weight: f64,
        v_image: &mut Vec<f32>,
        scratch: &mut SsimScratch,
    ) -> f64 {
        self.loss_and_gradient_on(SimdPath::detect(), image, view, weight, v_image, scratch)
    }

    /// [`L1Dssim::loss_and_gradient`] with its loops compiled for `path` (one the CPU has).
    fn loss_and_gradient_on(
        &self,
        path: SimdPath,
        image: &Image,
        view: &View,
        weight: f64,
        v_image: &mut Vec<f32>,
        scratch: &mut SsimScratch,
    ) -> f64 {
        let target = &view.image;
        assert_eq!(
            (image.width, image.height),
            (target.width, target.height),
            "image and target sizes differ"
        );
        let weights = view.weights.as_deref();
        let n = image.pixels.len();
        let width = image.width as usize;
        let total = total_weight(weights, n / 3);
        v_image.resize(n, 0.0);
        if total <= 0.0 || n == 0 {
            v_image.fill(0.0);
            return 0.0;
        }
        let lambda = self.dssim_weight;
        let g = window().map(|v| v as f32);
        let SsimScratch {
            weights: channel_weights,
            maps,
            filtered,
            rows,
            back,
            back_filtered,
        } = scratch;
        for buffer in maps.iter_mut().chain(back.iter_mut()) {
            buffer.resize(n, 0.0);
        }
        let planes = Planes {
            path,
            render: &image.pixels,
            target: &target.pixels,
            weights: channel_weights.of(weights, n),
            line: 3 * width,
        };
        planes.products(maps);
        for (source, out) in maps.iter().zip(filtered.iter_mut()) {
            blur(path, source, (out, rows), width, &g);
        }
        let scale = (weight / (3.0 * total)) as f32;
        // The map goes into the x² buffer, no longer needed.
        let [x, y, map, _, _] = maps;
        planes.map_and_partials(filtered, -(lambda as f32) * scale, map, back);
        let sum = planes.loss_sum(map, lambda);
        for (source, out) in back.iter().zip(back_filtered.iter_mut()) {
            blur(path, source, (out, rows), width, &g);
        }
        let l1 = (1.0 - lambda) as f32 * scale;
        planes.gradient((back_filtered, x, y), l1, v_image);
        sum / (3.0 * total)
    }
}

/// What the phases of one loss read: the path, the render, the target and each value's
/// weight (interleaved RGB), and the values on a line. Element-wise loops go a line at a
/// time, lines in parallel.
struct Planes<'a> {
    path: SimdPath,
    render: &'a [f32],
    target: &'a [f32],
    weights: &'a [f32],
    line: usize,
}

impl Planes<'_> {
    /// The values of line `k`.
    fn range(&self, k: usize) -> std::ops::Range<usize> {
        k * self.line..(k + 1) * self.line
    }

    /// The render, target and weights of line `k`.
    fn inputs(&self, k: usize) -> (&[f32], &[f32], &[f32]) {
        let r = self.range(k);
        (
            &self.render[r.clone()],
            &self.target[r.clone()],
            &self.weights[r],
        )
    }

    /// `x, y, x², y², xy` into `maps` (sized).
    fn products(&self, [x, y, xx, yy, xy]: &mut [Vec<f32>; 5]) {
        let line = self.line;
        x.par_chunks_mut(line)
            .zip(y.par_chunks_mut(line))
            .zip(xx.par_chunks_mut(line))
            .zip(yy.par_chunks_mut(line))
            .zip(xy.par_chunks_mut(line))
            .enumerate()
            .for_each(|(k, ((((x, y), xx), yy), xy))| {
                let inputs = self.inputs(k);
                let out = [x, y, xx, yy, xy];
                on_path(self.path, ProductsLine { inputs, out });
            });
    }

    /// The map `S` into `map` and `M1, M2, M3` into `back` (sized) from the `filtered`
    /// moments, `scale = -λ weight / 3W`.
    fn map_and_partials(
        &self,
        filtered: &[Vec<f32>; 5],
        scale: f32,
        map: &mut [f32],
        [m1, m2, m3]: &mut [Vec<f32>; 3],
    ) {
        let line = self.line;
        map.par_chunks_mut(line)
            .zip(m1.par_chunks_mut(line))
            .zip(m2.par_chunks_mut(line))
            .zip(m3.par_chunks_mut(line))
            .enumerate()
            .for_each(|(k, (((map, m1), m2), m3))| {
                let r = self.range(k);
                let moments = filtered.each_ref().map(|f| &f[r.clone()]);
                let weights = (&self.weights[r], scale);
                let out = [map, m1, m2, m3];
                let job = MapLine {
                    moments,
                    weights,
                    out,
                };
                on_path(self.path, job);
            });
    }

    /// `Σ_p w_p Σ_c [(1 - λ) |C - T| + λ (1 - S)]` in f64 in a fixed order.
    fn loss_sum(&self, map: &[f32], lambda: f64) -> f64 {
        let (c, t, w) = (self.render, self.target, self.weights);
        let [sum] = sum_in_blocks(c.len() / 3, |range| {
            [lane_sum(range.len(), |i| {
                let p = range.start + i;
                let w = f64::from(w[3 * p]);
                if w == 0.0 {
                    return 0.0;
                }
                let terms: f64 = (3 * p..3 * p + 3)
                    .map(|k| {
                        (1.0 - lambda) * (f64::from(c[k]) - f64::from(t[k])).abs()
                            + lambda * (1.0 - f64::from(map[k]))
                    })
                    .sum();
                w * terms
            })]
        });
        sum
    }

    /// `∂L/∂C` into `v_image` (sized) from `G*M1, G*M2, G*M3` and `x, y`; `l1 = (1 - λ)
    /// weight / 3W`.
    fn gradient(
        &self,
        (back_filtered, x, y): (&[Vec<f32>; 3], &[f32], &[f32]),
        l1: f32,
        v_image: &mut [f32],
    ) {
        v_image
            .par_chunks_mut(self.line)
            .enumerate()
            .for_each(|(k, out)| {
                let r = self.range(k);
                let filtered = back_filtered.each_ref().map(|f| &f[r.clone()]);
                let job = GradientLine {
                    inputs: self.inputs(k),
                    filtered: (filtered, &x[r.clone()], &y[r]),
                    l1,
                    out,
                };
                on_path(self.path, job);
            });
    }
}

/// The interleaved `w ⊙ image` in f64 (weight 1 without weights).
fn weighted_f64(image: &Image, weights: Option<&[f32]>) -> Vec<f64> {
    image
        .pixels
        .iter()
        .enumerate()
        .map(|(k, &v)| f64::from(weights.map_or(1.0, |w| w[k / 3])) * f64::from(v))
        .collect()
}

/// The 2D window's weight at offset `(dx, dy)` (each in `-5..=5`), f64.
fn window_2d(g: &[f64; WINDOW], dx: isize, dy: isize) -> f64 {
    g[(dx + HALF as isize) as usize] * g[(dy + HALF as isize) as usize]
}

/// The moments `μx, μy, E[x²], E[y²], E[xy]` of the window centred on pixel `(px, py)`,
/// channel `ch`, summed directly over the 2D window in f64 (zero outside the image).
fn moments(
    (x, y): (&[f64], &[f64]),
    (width, height): (usize, usize),
    (px, py, ch): (usize, usize, usize),
    g: &[f64; WINDOW],
) -> [f64; 5] {
    let mut m = [0.0; 5];
    for dy in -(HALF as isize)..=HALF as isize {
        for dx in -(HALF as isize)..=HALF as isize {
            let (qx, qy) = (px as isize + dx, py as isize + dy);
            if qx < 0 || qy < 0 || qx >= width as isize || qy >= height as isize {
                continue;
            }
            let k = 3 * (qy as usize * width + qx as usize) + ch;
            let g = window_2d(g, dx, dy);
            let (a, b) = (x[k], y[k]);
            for (sum, v) in m.iter_mut().zip([a, b, a * a, b * b, a * b]) {
                *sum += g * v;
            }
        }
    }
    m
}

/// The SSIM map's value from the moments, and its partials `∂S/∂μx, ∂S/∂E[x²], ∂S/∂E[xy]`
/// (by the quotient rule on `A B / (C D)`), f64.
fn ssim_and_partials([ux, uy, exx, eyy, exy]: [f64; 5]) -> [f64; 4] {
    let a = 2.0 * ux * uy + C1;
    let b = 2.0 * (exy - ux * uy) + C2;
    let c = ux * ux + uy * uy + C1;
    let d = (exx - ux * ux) + (eyy - uy * uy) + C2;
    let s = a * b / (c * d);
    // d/dμx of A, B, C, D: 2μy, -2μy, 2μx, -2μx.
    let ds_dux = (2.0 * uy * b + a * (-2.0 * uy)) / (c * d)
        - a * b * (2.0 * ux * d + c * (-2.0 * ux)) / (c * d).powi(2);
    let ds_dexx = -a * b * c / (c * d).powi(2);
    let ds_dexy = 2.0 * a / (c * d);
    [s, ds_dux, ds_dexx, ds_dexy]
}

/// The SSIM map of `x` against `y` (interleaved RGB planes of `width × height` pixels, f64):
/// one value per pixel and channel.
#[must_use]
pub fn reference_map(x: &[f64], y: &[f64], width: usize, height: usize) -> Vec<f64> {
    let g = window();
    let mut map = vec![0.0; x.len()];
    for py in 0..height {
        for px in 0..width {
            for ch in 0..3 {
                let m = moments((x, y), (width, height), (px, py, ch), &g);
                map[3 * (py * width + px) + ch] = ssim_and_partials(m)[0];
            }
        }
    }
    map
}

/// The loss of the module docs, in f64 from the definitions: `image` against `target` with
/// optional per-pixel `weights`, `λ = dssim_weight`.
#[must_use]
pub fn reference_loss(
    image: &Image,
    target: &Image,
    weights: Option<&[f32]>,
    dssim_weight: f64,
) -> f64 {
    let (width, height) = (image.width as usize, image.height as usize);
    let total: f64 = match weights {
        Some(w) => w.iter().map(|&v| f64::from(v)).sum(),
        None => (width * height) as f64,
    };
    if total <= 0.0 {
        return 0.0;
    }
    let (x, y) = (weighted_f64(image, weights), weighted_f64(target, weights));
    let map = reference_map(&x, &y, width, height);
    let mut sum = 0.0;
    for (k, s) in map.iter().enumerate() {
        let w = weights.map_or(1.0, |w| f64::from(w[k / 3]));
        let l1 = (f64::from(image.pixels[k]) - f64::from(target.pixels[k])).abs();
        sum += w * ((1.0 - dssim_weight) * l1 + dssim_weight * (1.0 - s));
    }
    sum / (3.0 * total)
}

/// `∂L/∂C` of [`reference_loss`], in f64: window by window, each window's SSIM's partials
/// carried to every pixel it covers by the chain rule (`∂μx/∂x_q = g`, `∂E[x²]/∂x_q =
/// 2 g x_q`, `∂E[xy]/∂x_q = g y_q`, then `∂x_q/∂C_q = w_q`), and the L1 term's
/// `(1 - λ) w_q sign(C_q - T_q) / (3 W)`.
#[must_use]
pub fn reference_gradient(
    image: &Image,
    target: &Image,
    weights: Option<&[f32]>,
    dssim_weight: f64,
) -> Vec<f64> {
    let (width, height) = (image.width as usize, image.height as usize);
    let mut grad = vec![0.0; image.pixels.len()];
    let total: f64 = match weights {
        Some(w) => w.iter().map(|&v| f64::from(v)).sum(),
        None => (width * height) as f64,
    };
    if total <= 0.0 {
        return grad;
    }
    let weight_at = |p: usize| weights.map_or(1.0, |w| f64::from(w[p]));
    let (x, y) = (weighted_f64(image, weights), weighted_f64(target, weights));
    let g = window();
    for py in 0..height {
        for px in 0..width {
            let a = weight_at(py * width + px) / (3.0 * total);
            for ch in 0..3 {
                let m = moments((&x, &y), (width, height), (px, py, ch), &g);
                let [_, ds_dux, ds_dexx, ds_dexy] = ssim_and_partials(m);
                for dy in -(HALF as isize)..=HALF as isize {
                    for dx in -(HALF as isize)..=HALF as isize {
                        let (qx, qy) = (px as isize + dx, py as isize + dy);
                        if qx < 0 || qy < 0 || qx >= width as isize || qy >= height as isize {
                            continue;
                        }
                        let q = qy as usize * width + qx as usize;
                        let k = 3 * q + ch;
                        let gw = window_2d(&g, dx, dy);
                        let d_x = ds_dux * gw + ds_dexx * 2.0 * gw * x[k] + ds_dexy * gw * y[k];
                        grad[k] += -dssim_weight * a * d_x * weight_at(q);
                    }
                }
            }
        }
    }
    for (k, v) in grad.iter_mut().enumerate() {
        let difference = f64::from(image.pixels[k]) - f64::from(target.pixels[k]);
        let sign = if difference > 0.0 {
            1.0
        } else if difference < 0.0 {
            -1.0
        } else {
            0.0
        };
        *v += (1.0 - dssim_weight) * weight_at(k / 3) * sign / (3.0 * total);
    }
    grad
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::RngExt;

    /// A view of `target` with `weights` (the camera is never used).
    fn view_of(target: &Image, weights: Option<Vec<f32>>) -> View {
        crate::fit::loss::tests::view_of(target.clone(), weights)
    }

    fn random_image(rng: &mut impl rand::Rng, width: u32, height: u32) -> Image {
        Image {
            width,
            height,
            pixels: (0..3 * width * height)
                .map(|_| rng.random_range(0.0..1.0))
                .collect(),
        }
    }

    /// The fast loss and gradient (weight 1).
    fn fast(image: &Image, view: &View, lambda: f64) -> (f64, Vec<f32>) {
        let mut v = Vec::new();
        let loss = L1Dssim {
            dssim_weight: lambda,
        }
        .loss_and_gradient(image, view, 1.0, &mut v, &mut SsimScratch::default());
        (loss, v)
    }

    /// Asserts the fast path against the f64 twin: the loss within `1e-5` of its value (of
    /// 1e-3 when smaller: an image against itself has loss 0, the f32 map 1 - 1e-9) and
    /// every gradient component within `1e-4` of the largest one (or of one L1 term's, if
    /// larger). The f32 filters measured 3e-6 and 3e-5 at worst, on constant images, where
    /// `E[x²] - μx²` cancels and only `C2` is left.
    fn assert_matches_reference(
        image: &Image,
        target: &Image,
        weights: Option<Vec<f32>>,
        lambda: f64,
    ) {
        let view = view_of(target, weights.clone());
        let (loss, grad) = fast(image, &view, lambda);
        let expected = reference_loss(image, target, weights.as_deref(), lambda);
        assert!(
            (loss - expected).abs() <= 1e-5 * expected.abs().max(1e-3),
            "loss {loss} against {expected}"
        );
        let reference = reference_gradient(image, target, weights.as_deref(), lambda);
        // One L1 term's gradient, 1/(3W): the scale of a component when the SSIM's vanish
        // (an image against itself).
        let total: f64 = weights
            .as_ref()
            .map_or((image.width * image.height) as f64, |w| {
                w.iter().map(|&v| f64::from(v)).sum()
            });
        let largest = reference
            .iter()
            .fold(1.0 / (3.0 * total), |m, v| m.max(v.abs()));
        for (k, (&fast, &exact)) in grad.iter().zip(&reference).enumerate() {
            assert!(
                (f64::from(fast) - exact).abs() <= 1e-4 * largest,
                "component {k}: {fast} against {exact} (largest {largest})"
            );
        }
    }

    #[test]
    fn the_fast_loss_and_gradient_match_the_f64_twin_on_random_and_hard_inputs() {
        let mut rng = crate::model::random::seeded_rng(3);
        // Larger than the window, with a border on every side; then the window's size.
        for (w, h) in [(23, 17), (11, 11), (40, 3), (32, 5)] {
            let (image, target) = (random_image(&mut rng, w, h), random_image(&mut rng, w, h));
            for lambda in [0.2, 0.0, 1.0] {
                assert_matches_reference(&image, &target, None, lambda);
            }
            let weights: Vec<f32> = (0..w * h)
                .map(|p| [0.0, 1.0, 0.5, 1.0, 0.25][p as usize % 5])
                .collect();
            assert_matches_reference(&image, &target, Some(weights), 0.2);
        }
        // Smaller than the window.
        for (w, h) in [(3, 2), (1, 1), (5, 9)] {
            let (image, target) = (random_image(&mut rng, w, h), random_image(&mut rng, w, h));
            assert_matches_reference(&image, &target, None, 0.2);
        }
        // Constant images, different and equal (variances 0: the map rests on C2).
        let (a, b) = (
            Image::filled(16, 14, [0.25; 3]),
            Image::filled(16, 14, [0.75, 0.5, 0.0]),
        );
        assert_matches_reference(&a, &b, None, 0.2);
        assert_matches_reference(&a, &a, None, 0.2);
        // A constant image against a random one, and black against white.
        let noise = random_image(&mut rng, 16, 14);
        assert_matches_reference(&a, &noise, None, 0.2);
        assert_matches_reference(
            &Image::filled(13, 12, [0.0; 3]),
            &Image::filled(13, 12, [1.0; 3]),
            None,
            0.2,
        );
    }

    #[test]
    fn zero_weights_take_no_part_and_all_zero_weights_give_zero() {
        let mut rng = crate::model::random::seeded_rng(5);
        let (image, target) = (
            random_image(&mut rng, 20, 15),
            random_image(&mut rng, 20, 15),
        );
        // Every weight 0: loss 0, gradient 0.
        let (loss, grad) = fast(&image, &view_of(&target, Some(vec![0.0; 300])), 0.2);
        assert_eq!(loss, 0.0);
        assert!(grad.iter().all(|&v| v == 0.0));
        // Left half out: its pixels get exactly 0, and what they hold does not matter.
        let weights: Vec<f32> = (0..300)
            .map(|p| if p % 20 < 10 { 0.0 } else { 1.0 })
            .collect();
        let view = view_of(&target, Some(weights.clone()));
        let (loss, grad) = fast(&image, &view, 0.2);
        let mut changed = image.clone();
        for p in (0..300).filter(|p| p % 20 < 10) {
            for c in 0..3 {
                changed.pixels[3 * p + c] = rng.random_range(0.0..1.0);
            }
        }
        let (loss_changed, grad_changed) = fast(&changed, &view, 0.2);
        assert_eq!(loss.to_bits(), loss_changed.to_bits());
        for (p, &w) in weights.iter().enumerate() {
            for c in 0..3 {
                let k = 3 * p + c;
                if w == 0.0 {
                    assert_eq!(grad[k], 0.0);
                } else {
                    assert_eq!(grad[k].to_bits(), grad_changed[k].to_bits());
                }
            }
        }
        // Weights 1 everywhere are the unweighted loss.
        let (plain, _) = fast(&image, &view_of(&target, None), 0.2);
        let (ones, _) = fast(&image, &view_of(&target, Some(vec![1.0; 300])), 0.2);
        assert_eq!(plain.to_bits(), ones.to_bits());
    }

    #[test]
    fn the_f64_gradient_is_the_finite_difference_of_the_f64_loss() {
        let mut rng = crate::model::random::seeded_rng(11);
        let (image, target) = (
            random_image(&mut rng, 14, 13),
            random_image(&mut rng, 14, 13),
        );
        let weights: Vec<f32> = (0..14 * 13).map(|p| [1.0, 0.5, 0.0][p % 3]).collect();
        for weights in [None, Some(weights.as_slice())] {
            let grad = reference_gradient(&image, &target, weights, 0.2);
            // Central differences of step 2^-12 on pixels whose L1 term does not change
            // sign within the step; the second-order error is far below the tolerance.
            let h = 2.0_f32.powi(-12);
            for k in (0..image.pixels.len()).step_by(7) {
                if (image.pixels[k] - target.pixels[k]).abs() < 4.0 * h {
                    continue;
                }
                let at = |delta: f32| {
                    let mut moved = image.clone();
                    moved.pixels[k] += delta;
                    reference_loss(&moved, &target, weights, 0.2)
                };
                let fd = (at(h) - at(-h)) / (2.0 * f64::from(h));
                assert!(
                    (fd - grad[k]).abs() <= 1e-6 + 1e-4 * grad[k].abs(),
                    "component {k}: finite difference {fd} against {}",
                    grad[k]
                );
            }
        }
    }

    #[test]
    fn the_map_inside_the_image_is_the_scikit_checked_ssim() {
        // Where the window fits inside, the zero padding is never read: the mean of the map
        // there is `crate::fit::loss::ssim` (checked against scikit-image).
        let mut rng = crate::model::random::seeded_rng(13);
        let (a, b) = (
            random_image(&mut rng, 24, 19),
            random_image(&mut rng, 24, 19),
        );
        let (x, y) = (weighted_f64(&a, None), weighted_f64(&b, None));
        let map = reference_map(&x, &y, 24, 19);
        let mut sum = 0.0;
        let mut count = 0;
        for py in HALF..19 - HALF {
            for px in HALF..24 - HALF {
                for c in 0..3 {
                    sum += map[3 * (py * 24 + px) + c];
                    count += 1;
                }
            }
        }
        let expected = crate::fit::loss::ssim(&a, &b);
        assert!(
            (sum / f64::from(count) - expected).abs() < 1e-12,
            "{} against {expected}",
            sum / f64::from(count)
        );
    }

    #[test]
    fn every_simd_path_gives_the_same_bits() {
        // 45 × 37: lines of 135 values, whole blocks and an overlapping last one; 32 × 5:
        // lines of 96, whole blocks only; 7 × 5: lines shorter than a block.
        let mut rng = crate::model::random::seeded_rng(19);
        for (width, height) in [(45, 37), (32, 5), (7, 5)] {
            let (image, target) = (
                random_image(&mut rng, width, height),
                random_image(&mut rng, width, height),
            );
            let weights: Vec<f32> = (0..width * height)
                .map(|_| rng.random_range(0.0..1.0))
                .collect();
            for weights in [None, Some(weights)] {
                let view = view_of(&target, weights);
                let on = |path| {
                    let mut v = Vec::new();
                    let loss = L1Dssim { dssim_weight: 0.2 }.loss_and_gradient_on(
                        path,
                        &image,
                        &view,
                        1.0,
                        &mut v,
                        &mut SsimScratch::default(),
                    );
                    (
                        loss.to_bits(),
                        v.iter().map(|g| g.to_bits()).collect::<Vec<_>>(),
                    )
                };
                let baseline = on(SimdPath::Baseline);
                assert!(baseline.1.iter().filter(|&&g| g != 0).count() > 100);
                for &path in SimdPath::available() {
                    assert!(on(path) == baseline, "{path} differs");
                }
            }
        }
    }

    #[test]
    fn a_scratch_kept_between_calls_gives_a_fresh_ones_bits() {
        // Weighted, then unweighted (the ones refilled), then another size, then weighted.
        let mut rng = crate::model::random::seeded_rng(23);
        let mut kept = SsimScratch::default();
        for (width, height, weighted) in [
            (30, 20, true),
            (30, 20, false),
            (41, 9, false),
            (41, 9, true),
        ] {
            let (image, target) = (
                random_image(&mut rng, width, height),
                random_image(&mut rng, width, height),
            );
            let weights = weighted.then(|| {
                (0..width * height)
                    .map(|_| rng.random_range(0.0..1.0))
                    .collect()
            });
            let view = view_of(&target, weights);
            let loss = L1Dssim { dssim_weight: 0.2 };
            let mut with_kept = Vec::new();
            let kept_loss = loss.loss_and_gradient(&image, &view, 1.0, &mut with_kept, &mut kept);
            let (fresh_loss, fresh) = fast(&image, &view, 0.2);
            assert_eq!(kept_loss.to_bits(), fresh_loss.to_bits());
            assert!(
                with_kept
                    .iter()
                    .zip(&fresh)
                    .all(|(a, b)| a.to_bits() == b.to_bits())
            );
        }
    }

    #[test]
    fn the_same_bits_on_any_thread_count() {
        let mut rng = crate::model::random::seeded_rng(17);
        let (image, target) = (
            random_image(&mut rng, 67, 45),
            random_image(&mut rng, 67, 45),
        );
        let weights: Vec<f32> = (0..67 * 45).map(|_| rng.random_range(0.0..1.0)).collect();
        let view = view_of(&target, Some(weights));
        let on = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| fast(&image, &view, 0.2))
        };
        let (loss, grad) = on(1);
        for threads in [2, 3] {
            let (many, many_grad) = on(threads);
            assert_eq!(loss.to_bits(), many.to_bits());
            assert!(
                grad.iter()
                    .zip(&many_grad)
                    .all(|(a, b)| a.to_bits() == b.to_bits())
            );
        }
    }
}
