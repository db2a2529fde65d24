//! Lens distortion (OpenCV / COLMAP models) and its removal: a photo taken through a
//! distorting lens resampled once into the pinhole camera of SPEC §3 with the same
//! intrinsics `K = (fx, fy, cx, cy)`.
//!
//! A camera-space point `(X, Y, Z)` (OpenCV axes) has normalised pinhole coordinates
//! `x = X/Z`, `y = Y/Z`. The lens moves them to (Brown–Conrady, OpenCV's `k1 k2 p1 p2 k3`):
//!
//! ```text
//! r² = x² + y²
//! radial = 1 + k1 r² + k2 r⁴ + k3 r⁶
//! x_d = x radial + 2 p1 x y + p2 (r² + 2 x²)
//! y_d = y radial + p1 (r² + 2 y²) + 2 p2 x y
//! u = fx x_d + cx,   v = fy y_d + cy      (pixels, pixel (i, j) centred at (i + ½, j + ½))
//! ```
//!
//! COLMAP's SIMPLE_RADIAL is `k1` alone, RADIAL `k1 k2`, OPENCV `k1 k2 p1 p2` (k3 = 0):
//! all are this formula with the other coefficients zero.
//!
//! Undistortion ([`RemapTable`]): for each pixel centre `(i + ½, j + ½)` of the pinhole image,
//! `x = (i + ½ - cx)/fx`, `y = (j + ½ - cy)/fy` is distorted with the formula above to the
//! photo position `(u, v)`, and the photo is sampled there bilinearly between its pixel
//! centres (at the photo's outer half pixel, the edge pixel's value is used). A pixel is
//! *valid* when `(u, v)` lies inside the photo, `0 ≤ u ≤ W`, `0 ≤ v ≤ H`, and the lens does
//! not fold there: `r² < s_fold`, the first zero of `d(r · radial)/dr`, i.e. of
//! `1 + 3 k1 s + 5 k2 s² + 7 k3 s³` (`s = r²`), beyond which the polynomial sends rays back
//! towards the centre; and the Jacobian of `(x, y) → (x_d, y_d)` is positive. Invalid pixels
//! weigh 0 in the loss ([`crate::model::View::weights`]); their colour is the photo's at the
//! nearest point of the photo (the source position clamped to it), so that what reads images
//! without weights (a background estimated from border pixels, a mean colour) sees photo
//! colours rather than black.
//!
//! The table is plain data, built once per distinct camera and applied to every photo (and
//! mask) taken with it.

use crate::model::image::Image;

/// Distortion coefficients of the OpenCV model (`k1 k2 p1 p2 k3`); zero is a pinhole.
///
/// Outside SPEC, whose camera is a pinhole (§3): photos are resampled into that pinhole at load.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Distortion {
    /// Radial coefficients `k1, k2, k3` (of r², r⁴, r⁶).
    pub radial: [f64; 3],
    /// Tangential coefficients `p1, p2`.
    pub tangential: [f64; 2],
}

impl Distortion {
    /// True when every coefficient is zero (a pinhole camera: nothing to undistort).
    #[must_use]
    pub fn is_pinhole(&self) -> bool {
        self.radial
            .iter()
            .chain(&self.tangential)
            .all(|&c| c == 0.0)
    }

    /// The distorted normalised coordinates `(x_d, y_d)` of the pinhole ray `(x, y)`.
    #[must_use]
    pub fn distort(&self, [x, y]: [f64; 2]) -> [f64; 2] {
        let [k1, k2, k3] = self.radial;
        let [p1, p2] = self.tangential;
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        [
            x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
        ]
    }

    /// The determinant of the Jacobian of [`Distortion::distort`] at `(x, y)`.
    #[must_use]
    pub fn jacobian_determinant(&self, [x, y]: [f64; 2]) -> f64 {
        let [k1, k2, k3] = self.radial;
        let [p1, p2] = self.tangential;
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        // d radial / d(r²)
        let slope = k1 + r2 * (2.0 * k2 + 3.0 * r2 * k3);
        let dxx = radial + 2.0 * x * x * slope + 2.0 * p1 * y + 6.0 * p2 * x;
        let dxy = 2.0 * x * y * slope + 2.0 * p1 * x + 2.0 * p2 * y;
        let dyx = 2.0 * x * y * slope + 2.0 * p1 * x + 2.0 * p2 * y;
        let dyy = radial + 2.0 * y * y * slope + 6.0 * p1 * y + 2.0 * p2 * x;
        dxx * dyy - dxy * dyx
    }

    /// `s_fold`: the smallest `s = r² > 0` at most `s_max` where `1 + 3 k1 s + 5 k2 s² +
    /// 7 k3 s³` reaches zero (the radial map stops growing with r), or infinity.
    #[must_use]
    pub fn fold_radius_squared(&self, s_max: f64) -> f64 {
        let [k1, k2, k3] = self.radial;
        let g = |s: f64| 1.0 + s * (3.0 * k1 + s * (5.0 * k2 + 7.0 * k3 * s));
        const STEPS: u32 = 4096;
        let mut previous = 0.0;
        for step in 1..=STEPS {
            let s = s_max * f64::from(step) / f64::from(STEPS);
            if g(s) <= 0.0 {
                // Bisect between the last positive sample and this one.
                let (mut lo, mut hi) = (previous, s);
                for _ in 0..60 {
                    let mid = 0.5 * (lo + hi);
                    if g(mid) > 0.0 {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                }
                return lo;
            }
            previous = s;
        }
        f64::INFINITY
    }
}

/// One pinhole pixel's source in the photo: the top-left `(i0, j0)` of the four photo
/// pixels blended and the weights `(tx, ty)` of the next column and row (the next column or
/// row is the same one at the photo's last column or row). 16 bytes a pixel.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Tap {
    i0: u32,
    j0: u32,
    tx: f32,
    ty: f32,
}

/// The resampling of photos of one camera (size, intrinsics, distortion) into its pinhole
/// twin: one entry per output pixel, computed once (see the module doc).
///
/// Outside SPEC, whose camera is a pinhole (§3); the loss then weighs pixels (SPEC §6 with weights).
#[derive(Clone, Debug, PartialEq)]
pub struct RemapTable {
    width: u32,
    height: u32,
    taps: Vec<Tap>,
    /// Whether each pixel's source lies in the photo.
    valid: Vec<bool>,
}

impl RemapTable {
    /// The table for photos of `width × height` pixels with intrinsics `[fx, fy, cx, cy]`
    /// and `distortion`; the output has the same size and intrinsics.
    #[must_use]
    pub fn new(
        width: u32,
        height: u32,
        [fx, fy, cx, cy]: [f64; 4],
        distortion: &Distortion,
    ) -> Self {
        let (w, h) = (f64::from(width), f64::from(height));
        // The largest r² of any output pixel: at a corner.
        let s_max = [0.0, w]
            .iter()
            .flat_map(|&u| [0.0, h].map(|v| ((u - cx) / fx).powi(2) + ((v - cy) / fy).powi(2)))
            .fold(0.0_f64, f64::max);
        let s_fold = distortion.fold_radius_squared(s_max);
        // Between pixel centres k + ½ and k + 1½; clamped at the edges.
        let axis = |p: f64, n: u32| -> (u32, f32) {
            let q = (p - 0.5).clamp(0.0, f64::from(n.saturating_sub(1)));
            let k = q.floor() as u32;
            (k, (q - f64::from(k)) as f32)
        };
        let mut taps = Vec::with_capacity(width as usize * height as usize);
        let mut valids = Vec::with_capacity(width as usize * height as usize);
        for j in 0..height {
            let y = (f64::from(j) + 0.5 - cy) / fy;
            for i in 0..width {
                let x = (f64::from(i) + 0.5 - cx) / fx;
                let [xd, yd] = distortion.distort([x, y]);
                let (u, v) = (fx * xd + cx, fy * yd + cy);
                let valid = (0.0..=w).contains(&u)
                    && (0.0..=h).contains(&v)
                    && x * x + y * y < s_fold
                    && distortion.jacobian_determinant([x, y]) > 0.0;
                // Non-finite positions (a lens far past its fold) clamp to the corner.
                let (u, v) = if u.is_finite() && v.is_finite() {
                    (u, v)
                } else {
                    (0.0, 0.0)
                };
                let (i0, tx) = axis(u, width);
                let (j0, ty) = axis(v, height);
                taps.push(Tap { i0, j0, tx, ty });
                valids.push(valid);
            }
        }
        RemapTable {
            width,
            height,
            taps,
            valid: valids,
        }
    }

    /// `(width, height)` of the photos it takes and the images it makes.
    #[must_use]
    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// Whether some pixel's source lies in the photo (a lens whose coefficients fold or
    /// throw every ray outside it leaves none).
    #[must_use]
    pub fn any_valid(&self) -> bool {
        self.valid.iter().any(|&v| v)
    }

    /// The per-pixel validity: 1 where the pixel's source lies in the photo, 0 elsewhere.
    #[must_use]
    pub fn validity(&self) -> Vec<f32> {
        self.valid.iter().map(|&v| f32::from(u8::from(v))).collect()
    }

    /// Bilinear samples of `n` channels stored interleaved in `values` (one group per photo
    /// pixel).
    fn resample(&self, values: &[f32], n: usize) -> Vec<f32> {
        let w = self.width as usize;
        let mut out = Vec::with_capacity(n * self.taps.len());
        for t in &self.taps {
            let (i0, j0) = (t.i0 as usize, t.j0 as usize);
            let i1 = if t.i0 + 1 < self.width { i0 + 1 } else { i0 };
            let j1 = if t.j0 + 1 < self.height { j0 + 1 } else { j0 };
            let at = |i: usize, j: usize, k: usize| values[n * (j * w + i) + k];
            for k in 0..n {
                let top = at(i0, j0, k) + t.tx * (at(i1, j0, k) - at(i0, j0, k));
                let bottom = at(i0, j1, k) + t.tx * (at(i1, j1, k) - at(i0, j1, k));
                out.push(top + t.ty * (bottom - top));
            }
        }
        out
    }

    /// `photo` (of this table's size) resampled into the pinhole camera; invalid pixels
    /// take the photo's colour at the nearest point of the photo. Panics if the sizes differ
    /// (the caller checks them).
    #[must_use]
    pub fn undistort_image(&self, photo: &Image) -> Image {
        assert_eq!((photo.width, photo.height), self.size(), "photo size");
        Image {
            width: self.width,
            height: self.height,
            pixels: self.resample(&photo.pixels, 3),
        }
    }

    /// Pixel weights (one per photo pixel, row-major, such as a mask) resampled the same
    /// way, times the validity: 0 at invalid pixels.
    #[must_use]
    pub fn undistort_weights(&self, plane: &[f32]) -> Vec<f32> {
        assert_eq!(plane.len(), self.taps.len(), "plane size");
        let mut out = self.resample(plane, 1);
        for (w, &valid) in out.iter_mut().zip(&self.valid) {
            if !valid {
                *w = 0.0;
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_pinhole_table_is_the_identity() {
        let mut photo = Image::filled(7, 5, [0.0; 3]);
        for (k, v) in photo.pixels.iter_mut().enumerate() {
            *v = k as f32 * 0.01;
        }
        let table = RemapTable::new(7, 5, [6.0, 6.5, 3.2, 2.4], &Distortion::default());
        let out = table.undistort_image(&photo);
        // Each pixel samples its own centre, up to the rounding of (i + ½ - cx)/fx · fx + cx.
        for (a, b) in out.pixels.iter().zip(&photo.pixels) {
            assert!((a - b).abs() < 1e-6, "{a} vs {b}");
        }
        assert!(table.validity().iter().all(|&w| w == 1.0));
    }

    #[test]
    fn the_jacobian_matches_finite_differences() {
        let d = Distortion {
            radial: [0.2, -0.05, 0.01],
            tangential: [0.003, -0.002],
        };
        for p in [[0.3, -0.2], [-0.5, 0.4], [0.05, 0.7]] {
            let h = 1e-6;
            let f = |x: f64, y: f64| d.distort([x, y]);
            let (a, b) = (f(p[0] + h, p[1]), f(p[0] - h, p[1]));
            let (c, e) = (f(p[0], p[1] + h), f(p[0], p[1] - h));
            let j = [
                [(a[0] - b[0]) / (2.0 * h), (c[0] - e[0]) / (2.0 * h)],
                [(a[1] - b[1]) / (2.0 * h), (c[1] - e[1]) / (2.0 * h)],
            ];
            let det = j[0][0] * j[1][1] - j[0][1] * j[1][0];
            assert!((det - d.jacobian_determinant(p)).abs() < 1e-7, "{det}");
        }
    }

    #[test]
    fn a_folding_lens_is_cut_at_its_fold() {
        // 1 + 3 k1 s = 0 at s = 1/(3·0.5) for k1 = -0.5.
        let d = Distortion {
            radial: [-0.5, 0.0, 0.0],
            tangential: [0.0; 2],
        };
        let s = d.fold_radius_squared(4.0);
        assert!((s - 1.0 / 1.5).abs() < 1e-9, "{s}");
        assert_eq!(
            Distortion::default().fold_radius_squared(4.0),
            f64::INFINITY
        );
    }
}
