//! f64 twin of the alpha blend (SPEC §8): [`crate::colour`] (SH colour, depth order) and
//! [`crate::composite`], every kernel against every pixel, written as the SPEC states it.
//!
//! ```text
//! ω = (m(τ) - c)/|m(τ) - c|,  c = -Rc⁻¹ tc          colour = max(0, A + Σ_j Y_j(ω) sh_j)
//! order: camera-space z of m(τ), nearest first, ties by kernel index
//! per pixel, pairs in that order: α̂ = min(0.99, o(τ) e^{-q/2}), T' = T (1 - α̂),
//! stop when T' < T_stop, else C += colour α̂ T, T = T';  pixel = C + T b
//! ```
//!
//! Besides the image, each pixel's trace (the kernels it composited, in order, and whether a
//! kernel stopped it) lets [`composite_traced`] re-evaluate the same pixel with the pairs,
//! the order and the stop held constant: the function whose derivative SPEC §8 defines, so
//! central differences of it check the fast backward field by field.

use glam::{DMat3, DVec3};

use crate::composite::{MAX_ALPHA, T_STOP};
use crate::model::{Camera, Scene};
use crate::reference::pixels::{is_borderline, quadratic_form};
use crate::reference::project::ReferenceKernel;
use crate::reference::reference_kernels;
use crate::render::RenderOptions;

/// A kernel of an alpha scene after slicing, projection and colour.
#[derive(Clone, Copy, Debug)]
pub struct AlphaKernel {
    /// Slice and projection (its `opacity` is `o(τ)`).
    pub kernel: ReferenceKernel,
    /// `A + Σ Y sh` before the clamp.
    pub raw_colour: [f64; 3],
    /// `max(0, raw_colour)`.
    pub colour: [f64; 3],
    /// Camera-space depth of `m(τ)`.
    pub depth: f64,
}

/// Real spherical harmonics of degree 1–3 at unit `d`, in the order and with the signs of
/// SPEC §8, written out degree by degree.
#[must_use]
pub fn reference_sh_basis(d: DVec3) -> Vec<f64> {
    let (x, y, z) = (d.x, d.y, d.z);
    let c1 = 0.488_602_511_902_919_9;
    let c2 = [
        1.092_548_430_592_079_2,
        -1.092_548_430_592_079_2,
        0.315_391_565_252_520_05,
        -1.092_548_430_592_079_2,
        0.546_274_215_296_039_6,
    ];
    let c3 = [
        -0.590_043_589_926_643_5,
        2.890_611_442_640_554,
        -0.457_045_799_464_465_8,
        0.373_176_332_590_115_4,
        -0.457_045_799_464_465_8,
        1.445_305_721_320_277,
        -0.590_043_589_926_643_5,
    ];
    let degree1 = [-c1 * y, c1 * z, -c1 * x];
    let degree2 = [
        c2[0] * x * y,
        c2[1] * y * z,
        c2[2] * (2.0 * z * z - x * x - y * y),
        c2[3] * x * z,
        c2[4] * (x * x - y * y),
    ];
    let degree3 = [
        c3[0] * y * (3.0 * x * x - y * y),
        c3[1] * x * y * z,
        c3[2] * y * (4.0 * z * z - x * x - y * y),
        c3[3] * z * (2.0 * z * z - 3.0 * x * x - 3.0 * y * y),
        c3[4] * x * (4.0 * z * z - x * x - y * y),
        c3[5] * z * (x * x - y * y),
        c3[6] * x * (x * x - 3.0 * y * y),
    ];
    degree1.into_iter().chain(degree2).chain(degree3).collect()
}

/// The camera centre `c = -Rc⁻¹ tc`.
#[must_use]
pub fn reference_camera_centre(camera: &Camera) -> DVec3 {
    let rc = DMat3::from_cols_array_2d(&camera.rotation()).transpose();
    -(rc.inverse() * DVec3::from(camera.translation()))
}

/// Every kernel of the alpha scene alive at τ and on screen, with its colour, in
/// compositing order (depth, then kernel index).
#[must_use]
pub fn reference_alpha_kernels(
    scene: &Scene,
    camera: &Camera,
    tau: f64,
    options: &RenderOptions,
) -> Vec<AlphaKernel> {
    let centre = reference_camera_centre(camera);
    let rc = DMat3::from_cols_array_2d(&camera.rotation()).transpose();
    let mut kernels: Vec<AlphaKernel> = reference_kernels(scene, camera, tau, options)
        .into_iter()
        .map(|kernel| {
            let i = kernel.index;
            let [x, y, z, t] = scene.means[i];
            let mean = DVec3::new(x, y, z) + DVec3::from(scene.velocities[i]) * (tau - t);
            let offset = mean - centre;
            let direction = if offset.length() > 0.0 {
                offset / offset.length()
            } else {
                DVec3::ZERO
            };
            let basis = reference_sh_basis(direction);
            let mut raw_colour = scene.amplitudes[i];
            for (j, triplet) in scene.sh_of(i).iter().enumerate() {
                for c in 0..3 {
                    raw_colour[c] += basis[j] * triplet[c];
                }
            }
            AlphaKernel {
                kernel,
                raw_colour,
                colour: raw_colour.map(|c| c.max(0.0)),
                depth: (rc * mean + DVec3::from(camera.translation())).z,
            }
        })
        .collect();
    kernels.sort_by(|a, b| {
        a.depth
            .total_cmp(&b.depth)
            .then(a.kernel.index.cmp(&b.kernel.index))
    });
    kernels
}

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
