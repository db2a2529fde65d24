//! f64 twin of [`crate::composite`] (SPEC §8): the ordered, coloured kernels of
//! [`crate::reference::colour`] composited front to back at every pixel, written as the SPEC
//! states it.
//!
//! ```text
//! per pixel, pairs in that order: α̂ = min(0.99, o(τ) e^{-q/2}), T' = T (1 - α̂),
//! stop when T' < T_stop, else C += colour α̂ T, T = T';  pixel = C + T b
//! ```
//!
//! Besides the image, each pixel's trace (the kernels it composited, in order, and whether a
//! kernel stopped it) lets [`composite_traced`] re-evaluate the same pixel with the pairs,
//! the order and the stop held constant: the function whose derivative SPEC §8 defines, so
//! central differences of it check the fast backward field by field.

use crate::composite::{MAX_ALPHA, T_STOP};
use crate::model::{Camera, Scene};
use crate::reference::colour::{AlphaKernel, reference_alpha_kernels};
use crate::reference::raster::{is_borderline, quadratic_form};
use crate::render::RenderOptions;

/// What decided one pixel: the kernels (indices into the ordered list) that it composited,
/// in order, and the one that stopped it, if any.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct PixelTrace {
    /// Kernels composited, in order.
    pub composited: Vec<u32>,
    /// The kernel whose `T'` fell below `T_stop`.
    pub stopped_by: Option<u32>,
}

/// Output of [`render_reference_alpha`].
#[derive(Clone, Debug, Default)]
pub struct ReferenceAlphaImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// RGB, row-major.
    pub pixels: Vec<f64>,
    /// Per pixel: a pair within the cut-off band of SPEC §5 (`|q - qmax| ≤ 1e-4 max(1,
    /// qmax)`), where implementations may disagree on a pair.
    pub borderline: Vec<bool>,
    /// Per pixel: the smallest `|T' - T_stop| / T'` over the transmittances it tested (∞
    /// when it tested none): a small margin is where implementations may stop one kernel
    /// apart (SPEC §8).
    pub stop_margin: Vec<f64>,
    /// Per pixel: its trace.
    pub traces: Vec<PixelTrace>,
    /// Pairs tested (until each pixel's stop), all pixels.
    pub pairs: u64,
}

/// One pixel composited in f64: its colour, whether a pair sits on the cut-off's edge, its
/// stop margin, its trace and its pairs.
struct PixelResult {
    colour: [f64; 3],
    borderline: bool,
    margin: f64,
    trace: PixelTrace,
    pairs: u64,
}

fn composite_pixel(kernels: &[AlphaKernel], background: [f64; 3], i: u32, j: u32) -> PixelResult {
    let mut colour = [0.0; 3];
    let mut transmittance = 1.0;
    let mut trace = PixelTrace::default();
    let mut borderline = false;
    let mut margin = f64::INFINITY;
    let mut pairs = 0;
    for (k, alpha_kernel) in kernels.iter().enumerate() {
        let kernel = &alpha_kernel.kernel;
        let q = quadratic_form(kernel, i, j);
        borderline |= is_borderline(q, kernel.qmax);
        if q > kernel.qmax {
            continue;
        }
        pairs += 1;
        let alpha = (kernel.opacity * (-0.5 * q).exp()).min(MAX_ALPHA);
        let next = transmittance * (1.0 - alpha);
        margin = margin.min((next - T_STOP).abs() / next);
        if next < T_STOP {
            trace.stopped_by = Some(k as u32);
            break;
        }
        for (sum, c) in colour.iter_mut().zip(alpha_kernel.colour) {
            *sum += c * alpha * transmittance;
        }
        transmittance = next;
        trace.composited.push(k as u32);
    }
    for (sum, b) in colour.iter_mut().zip(background) {
        *sum += transmittance * b;
    }
    PixelResult {
        colour,
        borderline,
        margin,
        trace,
        pairs,
    }
}

/// Composites every kernel against every pixel in f64 (SPEC §8).
#[must_use]
pub fn render_reference_alpha(
    scene: &Scene,
    camera: &Camera,
    tau: f64,
    options: &RenderOptions,
) -> ReferenceAlphaImage {
    let kernels = reference_alpha_kernels(scene, camera, tau, options);
    let n = camera.pixel_count();
    let mut out = ReferenceAlphaImage {
        width: camera.width,
        height: camera.height,
        pixels: Vec::with_capacity(3 * n),
        borderline: Vec::with_capacity(n),
        stop_margin: Vec::with_capacity(n),
        traces: Vec::with_capacity(n),
        pairs: 0,
    };
    for j in 0..camera.height {
        for i in 0..camera.width {
            let pixel = composite_pixel(&kernels, scene.background, i, j);
            out.pixels.extend_from_slice(&pixel.colour);
            out.borderline.push(pixel.borderline);
            out.stop_margin.push(pixel.margin);
            out.traces.push(pixel.trace);
            out.pairs += pixel.pairs;
        }
    }
    out
}

/// Per kernel of `scene` (by scene index), its weight `Σ_pixels α̂ T` in the f64 composite
/// at τ: the `α̂ T` it adds at each pixel before that pixel's stop (0 for kernels culled or
/// off screen).
#[must_use]
pub fn reference_pixel_weights(
    scene: &Scene,
    camera: &Camera,
    tau: f64,
    options: &RenderOptions,
) -> Vec<f64> {
    let kernels = reference_alpha_kernels(scene, camera, tau, options);
    let mut weights = vec![0.0; scene.len()];
    for j in 0..camera.height {
        for i in 0..camera.width {
            let mut transmittance = 1.0;
            for alpha_kernel in &kernels {
                let kernel = &alpha_kernel.kernel;
                let q = quadratic_form(kernel, i, j);
                if q > kernel.qmax {
                    continue;
                }
                let alpha = (kernel.opacity * (-0.5 * q).exp()).min(MAX_ALPHA);
                let next = transmittance * (1.0 - alpha);
                if next < T_STOP {
                    break;
                }
                weights[kernel.index] += alpha * transmittance;
                transmittance = next;
            }
        }
    }
    weights
}

/// The f64 composite at chosen pixels only (for error estimates on frames too large for
/// [`render_reference_alpha`]).
#[must_use]
pub fn reference_alpha_at_pixels(
    scene: &Scene,
    camera: &Camera,
    tau: f64,
    options: &RenderOptions,
    pixels: &[(u32, u32)],
) -> Vec<[f64; 3]> {
    let kernels = reference_alpha_kernels(scene, camera, tau, options);
    pixels
        .iter()
        .map(|&(i, j)| composite_pixel(&kernels, scene.background, i, j).colour)
        .collect()
}

/// The image of `scene` (perturbed from the one traced) composited with each pixel's
/// kernels and order taken from `traces` (by scene index: `order` gives the scene index of
/// each traced position): pairs, order and stops held constant, as SPEC §8's gradient
/// treats them.
#[must_use]
pub fn composite_traced(
    scene: &Scene,
    camera: &Camera,
    tau: f64,
    options: &RenderOptions,
    order: &[usize],
    traces: &[PixelTrace],
) -> Vec<f64> {
    // The perturbed scene's kernels, by scene index (the cut-off off, so that a perturbation
    // never culls a kernel the trace uses).
    let loose = RenderOptions {
        cutoff: 0.0,
        ..*options
    };
    let mut by_index = vec![None; scene.len()];
    for kernel in reference_alpha_kernels(scene, camera, tau, &loose) {
        by_index[kernel.kernel.index] = Some(kernel);
    }
    let mut pixels = Vec::with_capacity(3 * traces.len());
    for (p, trace) in traces.iter().enumerate() {
        let (i, j) = (
            (p % camera.width as usize) as u32,
            (p / camera.width as usize) as u32,
        );
        let mut colour = [0.0; 3];
        let mut transmittance = 1.0;
        for &k in &trace.composited {
            let kernel = by_index[order[k as usize]].expect("a traced kernel stays on screen");
            let q = quadratic_form(&kernel.kernel, i, j);
            let alpha = (kernel.kernel.opacity * (-0.5 * q).exp()).min(MAX_ALPHA);
            for (sum, c) in colour.iter_mut().zip(kernel.colour) {
                *sum += c * alpha * transmittance;
            }
            transmittance *= 1.0 - alpha;
        }
        for (c, b) in colour.iter().zip(scene.background) {
            pixels.push(c + transmittance * b);
        }
    }
    pixels
}
