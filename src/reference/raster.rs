//! f64 twin of stages 3–4, [`crate::tiles`] and [`crate::raster`] (SPEC §5, Eq. 2): every
//! kernel against every pixel, no tiles and no bounds,
//!
//! ```text
//! C(p, τ) = b + Σ_i [q_i(p) ≤ qmax_i] a_i(τ) exp(-½ q_i(p)),   q = (p - m2)ᵀ Q (p - m2)
//! ```
//!
//! Besides the image it returns, per pixel, the sum of |contributions| (for the error bound
//! [`ERROR_BOUND`], `1e-6 + 2e-6·Σ|a|`), the number of pairs summed, and the number of pairs in the band
//! `|q - qmax| ≤ 1e-4 max(1, qmax)` where SPEC §5 lets implementations differ.

use glam::DVec2;

use crate::model::{Camera, Scene};
use crate::reference::project::ReferenceKernel;
use crate::reference::reference_kernels;
use crate::render::RenderOptions;

/// Relative width of the cut-off band of SPEC §5 (precision).
pub const BORDERLINE_BAND: f64 = 1e-4;

/// The f32 renderer's documented error against this twin, per pixel and channel (SPEC §5,
/// precision): `|fast - ref| ≤ absolute + relative·Σ|a|`, `Σ|a|` the sum of |contributions|
/// at the pixel ([`ReferenceImage::abs_sum`]), pairs in the cut-off band aside.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ErrorBound {
    /// The absolute part.
    pub absolute: f64,
    /// The part relative to `Σ|a|`.
    pub relative: f64,
}

impl ErrorBound {
    /// The bound at a pixel whose contributions sum to `abs_sum` in absolute value.
    #[must_use]
    pub fn at(self, abs_sum: f64) -> f64 {
        self.absolute + self.relative * abs_sum
    }
}

impl std::fmt::Display for ErrorBound {
    /// `1e-6 + 2e-6·Σ|a|`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{:e} + {:e}·Σ|a|", self.absolute, self.relative)
    }
}

/// The bound `1e-6 + 2e-6·Σ|a|`: the one the tests hold the renderer to and the benches
/// report the error against.
pub const ERROR_BOUND: ErrorBound = ErrorBound {
    absolute: 1e-6,
    relative: 2e-6,
};

/// Output of [`render_reference`].
#[derive(Clone, Debug, Default)]
pub struct ReferenceImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// RGB, row-major, like [`crate::model::Image`].
    pub pixels: Vec<f64>,
    /// Per pixel and channel: `|b_c| + Σ_i [q ≤ qmax] |a_i,c exp(-½ q)|`.
    pub abs_sum: Vec<f64>,
    /// Per pixel: pairs in the cut-off band.
    pub borderline: Vec<u32>,
    /// Pairs summed (indicator 1), all pixels.
    pub pairs: u64,
    /// Pairs in the cut-off band, all pixels.
    pub borderline_pairs: u64,
}

/// `q = (p - m2)ᵀ Q (p - m2)` at pixel `(i, j)`.
#[must_use]
pub fn quadratic_form(kernel: &ReferenceKernel, i: u32, j: u32) -> f64 {
    let delta = DVec2::new(f64::from(i) + 0.5, f64::from(j) + 0.5) - DVec2::from(kernel.mean);
    let q = kernel.conic;
    delta.x * (q[0][0] * delta.x + q[0][1] * delta.y)
        + delta.y * (q[1][0] * delta.x + q[1][1] * delta.y)
}

/// True when `q` is in the band `|q - qmax| ≤ 1e-4 max(1, qmax)` of SPEC §5 where
/// implementations may disagree on the indicator. Without truncation there is no band.
#[must_use]
pub fn is_borderline(q: f64, qmax: f64) -> bool {
    qmax.is_finite() && (q - qmax).abs() <= BORDERLINE_BAND * qmax.max(1.0)
}

/// Renders every kernel against every pixel in f64 (SPEC §5, Eq. 2).
#[must_use]
pub fn render_reference(
    scene: &Scene,
    camera: &Camera,
    tau: f64,
    options: &RenderOptions,
) -> ReferenceImage {
    let kernels = reference_kernels(scene, camera, tau, options);
    let n = camera.pixel_count();
    let mut out = ReferenceImage {
        width: camera.width,
        height: camera.height,
        pixels: Vec::with_capacity(3 * n),
        abs_sum: Vec::with_capacity(3 * n),
        borderline: Vec::with_capacity(n),
        ..ReferenceImage::default()
    };
    for j in 0..camera.height {
        for i in 0..camera.width {
            let mut colour = scene.background;
            let mut abs_sum = scene.background.map(f64::abs);
            let mut borderline = 0;
            for kernel in &kernels {
                let q = quadratic_form(kernel, i, j);
                if is_borderline(q, kernel.qmax) {
                    borderline += 1;
                }
                if q <= kernel.qmax {
                    let g = (-0.5 * q).exp();
                    for c in 0..3 {
                        colour[c] += kernel.amplitude[c] * g;
                        abs_sum[c] += (kernel.amplitude[c] * g).abs();
                    }
                    out.pairs += 1;
                }
            }
            out.pixels.extend_from_slice(&colour);
            out.abs_sum.extend_from_slice(&abs_sum);
            out.borderline.push(borderline);
            out.borderline_pairs += u64::from(borderline);
        }
    }
    out
}

/// Which pixels a kernel's indicator `[q ≤ qmax]` includes, row-major; used to freeze the
/// pair set while differencing (SPEC §6: the indicator counts as a constant).
pub type PairMask = Vec<bool>;

/// Kernel `kernel`'s contribution `[q ≤ qmax] a exp(-½ q)` to every pixel (RGB, row-major),
/// with the indicator taken from `mask` when given, and the mask it used.
#[must_use]
pub fn kernel_contribution(
    kernel: &ReferenceKernel,
    camera: &Camera,
    mask: Option<&PairMask>,
) -> (Vec<f64>, PairMask) {
    let n = camera.pixel_count();
    let mut image = vec![0.0; 3 * n];
    let mut used = vec![false; n];
    for j in 0..camera.height {
        for i in 0..camera.width {
            let k = j as usize * camera.width as usize + i as usize;
            let q = quadratic_form(kernel, i, j);
            let inside = mask.map_or(q <= kernel.qmax, |m| m[k]);
            if inside {
                let g = (-0.5 * q).exp();
                for c in 0..3 {
                    image[3 * k + c] = kernel.amplitude[c] * g;
                }
                used[k] = true;
            }
        }
    }
    (image, used)
}

/// The reference at chosen pixels only: for each `(i, j)`, the f64 colour and `Σ|a|` per
/// channel (every kernel against those pixels). For error estimates on frames too large for
/// [`render_reference`].
#[must_use]
pub fn reference_at_pixels(
    scene: &Scene,
    camera: &Camera,
    tau: f64,
    options: &RenderOptions,
    pixels: &[(u32, u32)],
) -> Vec<([f64; 3], [f64; 3])> {
    let kernels = reference_kernels(scene, camera, tau, options);
    pixels
        .iter()
        .map(|&(i, j)| {
            let mut colour = scene.background;
            let mut abs_sum = scene.background.map(f64::abs);
            for kernel in &kernels {
                let q = quadratic_form(kernel, i, j);
                if q <= kernel.qmax {
                    let g = (-0.5 * q).exp();
                    for c in 0..3 {
                        colour[c] += kernel.amplitude[c] * g;
                        abs_sum[c] += (kernel.amplitude[c] * g).abs();
                    }
                }
            }
            (colour, abs_sum)
        })
        .collect()
}
