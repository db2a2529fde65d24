//! The loss of SPEC §6: per view, the mean over pixels and channels of `(C - C_gt)²` on raw
//! linear values (no clamp); over views, the mean of those. `PSNR = 10 log10(1 / MSE)`.
//!
//! A view with per-pixel weights `w_p` ([`View::weights`]: undistortion borders, dataset
//! masks) uses the weighted mean `Σ_p w_p Σ_c (C - C_gt)² / (3 Σ_p w_p)` (0 when every weight
//! is 0); without weights the plain mean above. Sums are taken in f64 in a fixed order (blocks
//! of 2¹⁶ values in parallel, added in block order; eight accumulators within a block), so a
//! loss has the same bits on any thread count.

use crate::model::{Image, View};
use crate::parallel::{add_lanes, lane_sum, sum_in_blocks};

/// MSE of `image` against `target` (same size), accumulated in f64 ([`sum_in_blocks`]).
#[must_use]
pub fn mse(image: &Image, target: &Image) -> f64 {
    assert_eq!(
        (image.width, image.height),
        (target.width, target.height),
        "image and target sizes differ"
    );
    let [sum] = sum_in_blocks(image.pixels.len(), |range| {
        [squared_errors(
            &image.pixels[range.clone()],
            &target.pixels[range],
        )]
    });
    sum / image.pixels.len() as f64
}

/// `Σ (c - t)²` in f64 over the values of `c` and `t` (the same length), in
/// [`lane_sum`]'s order (written over groups of eight, which the compiler vectorises).
fn squared_errors(c: &[f32], t: &[f32]) -> f64 {
    let mut s = [0.0_f64; 8];
    let (groups, targets) = (c.chunks_exact(8), t.chunks_exact(8));
    let (tail, target_tail) = (groups.remainder(), targets.remainder());
    for (c, t) in groups.zip(targets) {
        for lane in 0..8 {
            s[lane] += (f64::from(c[lane]) - f64::from(t[lane])).powi(2);
        }
    }
    for (sum, (&c, &t)) in s.iter_mut().zip(tail.iter().zip(target_tail)) {
        *sum += (f64::from(c) - f64::from(t)).powi(2);
    }
    add_lanes(s)
}

/// MSE of `image` against `target`, and `v_image = weight ∂MSE/∂C = weight 2 (C - C_gt)/N`
/// into `v_image` (resized). `weight` is `1/views` when the loss averages several views.
pub fn mse_with_gradient(
    image: &Image,
    target: &Image,
    weight: f64,
    v_image: &mut Vec<f32>,
) -> f64 {
    let scale = (weight * 2.0 / image.pixels.len() as f64) as f32;
    v_image.clear();
    v_image.extend(
        image
            .pixels
            .iter()
            .zip(&target.pixels)
            .map(|(&c, &t)| scale * (c - t)),
    );
    mse(image, target)
}

/// The weighted MSE of `image` against `target` with one weight per pixel (see the module
/// doc), accumulated in f64.
#[must_use]
pub fn weighted_mse(image: &Image, target: &Image, weights: &[f32]) -> f64 {
    assert_eq!(
        (image.width, image.height),
        (target.width, target.height),
        "image and target sizes differ"
    );
    assert_eq!(
        weights.len(),
        image.pixels.len() / 3,
        "one weight per pixel"
    );
    let [sum] = sum_in_blocks(weights.len(), |range| {
        let w = &weights[range.clone()];
        let (c, t) = (
            &image.pixels[3 * range.start..3 * range.end],
            &target.pixels[3 * range.start..3 * range.end],
        );
        [lane_sum(w.len(), |p| {
            let error = (3 * p..3 * p + 3)
                .map(|k| (f64::from(c[k]) - f64::from(t[k])).powi(2))
                .sum::<f64>();
            f64::from(w[p]) * error
        })]
    });
    let total = total_weight(weights);
    if total > 0.0 {
        sum / (3.0 * total)
    } else {
        0.0
    }
}

/// The loss of `image` against `view`: [`weighted_mse`] with the view's weights, else
/// [`mse`].
#[must_use]
pub fn view_mse(image: &Image, view: &View) -> f64 {
    match &view.weights {
        Some(weights) => weighted_mse(image, &view.image, weights),
        None => mse(image, &view.image),
    }
}

/// [`view_mse`] and its gradient `weight ∂loss/∂C` into `v_image` (resized), as
/// [`mse_with_gradient`]; with pixel weights `w_p`, `∂loss/∂C = 2 w_p (C - C_gt) / (3 Σ w)`
/// ([`view_mse_gradient`]).
pub fn view_mse_with_gradient(
    image: &Image,
    view: &View,
    weight: f64,
    v_image: &mut Vec<f32>,
) -> f64 {
    v_image.clear();
    v_image.resize(image.pixels.len(), 0.0);
    view_mse_gradient(view, weight)(0, &image.pixels, v_image);
    view_mse(image, view)
}

/// `Σ w_p` in f64, in the fixed order of [`sum_in_blocks`] and [`lane_sum`]: the loss and its
/// gradient divide by the same bits.
fn total_weight(weights: &[f32]) -> f64 {
    let [total] = sum_in_blocks(weights.len(), |range| {
        let w = &weights[range];
        [lane_sum(w.len(), |p| f64::from(w[p]))]
    });
    total
}

/// The gradient of `weight ×` [`view_mse`] with respect to the rendered pixels, channel
/// run by channel run (a [`crate::backward::raster::PixelGradient`]): `gradient(k, c, v)`
/// sets `v[i]` for channel `k + i` of the view's image from its rendered value `c[i]`, to
/// `s (c - C_gt)` with `s = weight 2 / N` in f32 (as [`mse_with_gradient`]), or with pixel
/// weights `s w_p (c - C_gt)` with `s = weight 2 / (3 Σ w)` (0 when every weight is 0).
pub fn view_mse_gradient(view: &View, weight: f64) -> impl Fn(usize, &[f32], &mut [f32]) + Sync {
    let target = &view.image.pixels;
    let weights = view.weights.as_deref();
    let scale = match weights {
        None => (weight * 2.0 / target.len() as f64) as f32,
        Some(weights) => {
            let total = total_weight(weights);
            if total > 0.0 {
                (weight * 2.0 / (3.0 * total)) as f32
            } else {
                0.0
            }
        }
    };
    move |first: usize, rendered: &[f32], v: &mut [f32]| {
        let targets = &target[first..first + rendered.len()];
        match weights {
            None => {
                for ((v, &c), &t) in v.iter_mut().zip(rendered).zip(targets) {
                    *v = scale * (c - t);
                }
            }
            Some(weights) => {
                for (i, ((v, &c), &t)) in v.iter_mut().zip(rendered).zip(targets).enumerate() {
                    *v = scale * weights[(first + i) / 3] * (c - t);
                }
            }
        }
    }
}

/// `10 log10(1 / mse)`, dB.
#[must_use]
pub fn psnr(mse: f64) -> f64 {
    -10.0 * mse.log10()
}

/// The MSE of one view against `target` and its gradient, accumulated into `grads` (sized
/// for the scene): what `splat4d grad` computes. The target must have the camera's size.
pub fn view_loss_and_gradients(
    context: &mut crate::RenderContext,
    scene: &crate::Scene,
    camera: &crate::Camera,
    tau: f64,
    options: &crate::RenderOptions,
    target: &Image,
    grads: &mut crate::Gradients,
) -> crate::Result<f64> {
    if (target.width, target.height) != (camera.width, camera.height) {
        return Err(crate::Error::Usage(format!(
            "the target image is {}×{} but the camera is {}×{}",
            target.width, target.height, camera.width, camera.height
        )));
    }
    context.render_for_backward(scene, camera, tau, options)?;
    let mut v_image = Vec::new();
    let loss = mse_with_gradient(context.image(), target, 1.0, &mut v_image);
    context.backward(scene, camera, tau, options, &v_image, grads);
    Ok(loss)
}

/// Side of the SSIM window (Wang et al. 2004: 11×11).
pub const SSIM_WINDOW: usize = 11;
/// Standard deviation of the SSIM window's Gaussian, pixels.
pub const SSIM_SIGMA: f64 = 1.5;
/// SSIM's `C1 = (0.01 L)²`, `L = 1`.
pub const SSIM_C1: f64 = 1e-4;
/// SSIM's `C2 = (0.03 L)²`, `L = 1`.
pub const SSIM_C2: f64 = 9e-4;

/// Mean structural similarity (Wang, Bovik, Sheikh, Simoncelli 2004) of `image` against
/// `target`, on linear values with dynamic range `L = 1`: per channel, local means, variances
/// and covariance under an 11×11 Gaussian window (σ = 1.5, weights summing to 1), at every
/// position where the window fits inside the image ("valid", as the paper's reference code),
/// `SSIM = (2 μx μy + C1)(2 σxy + C2) / ((μx² + μy² + C1)(σx² + σy² + C2))` with
/// `C1 = (0.01 L)²`, `C2 = (0.03 L)²`; the mean over positions and channels. Images smaller
/// than the window use one window the size of the image. f64 throughout.
#[must_use]
pub fn ssim(image: &Image, target: &Image) -> f64 {
    assert_eq!(
        (image.width, image.height),
        (target.width, target.height),
        "image and target sizes differ"
    );
    let (w, h) = (image.width as usize, image.height as usize);
    if w == 0 || h == 0 {
        return 1.0;
    }
    let (c1, c2) = (SSIM_C1, SSIM_C2);
    let weights = |n: usize| -> Vec<f64> {
        let centre = (n as f64 - 1.0) / 2.0;
        let raw: Vec<f64> = (0..n)
            .map(|i| (-0.5 * ((i as f64 - centre) / SSIM_SIGMA).powi(2)).exp())
            .collect();
        let total: f64 = raw.iter().sum();
        raw.into_iter().map(|v| v / total).collect()
    };
    let (wx, wy) = (weights(SSIM_WINDOW.min(w)), weights(SSIM_WINDOW.min(h)));
    let (out_w, out_h) = (w - wx.len() + 1, h - wy.len() + 1);
    // Separable filtering of one plane: rows, then columns ("valid" positions only).
    let filter = |plane: &[f64]| -> Vec<f64> {
        let mut rows = vec![0.0; out_w * h];
        for y in 0..h {
            for x in 0..out_w {
                rows[y * out_w + x] = (0..wx.len()).map(|k| wx[k] * plane[y * w + x + k]).sum();
            }
        }
        let mut out = vec![0.0; out_w * out_h];
        for y in 0..out_h {
            for x in 0..out_w {
                out[y * out_w + x] = (0..wy.len())
                    .map(|k| wy[k] * rows[(y + k) * out_w + x])
                    .sum();
            }
        }
        out
    };
    let mut total = 0.0;
    for c in 0..3 {
        let channel = |of: &Image| -> Vec<f64> {
            of.pixels
                .iter()
                .skip(c)
                .step_by(3)
                .map(|&v| f64::from(v))
                .collect()
        };
        let (x, y) = (channel(image), channel(target));
        let product =
            |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(p, q)| p * q).collect::<Vec<_>>();
        let (mx, my) = (filter(&x), filter(&y));
        let (xx, yy, xy) = (
            filter(&product(&x, &x)),
            filter(&product(&y, &y)),
            filter(&product(&x, &y)),
        );
        let mut sum = 0.0;
        for k in 0..mx.len() {
            let (ux, uy) = (mx[k], my[k]);
            let (vx, vy, cxy) = (xx[k] - ux * ux, yy[k] - uy * uy, xy[k] - ux * uy);
            sum += ((2.0 * ux * uy + c1) * (2.0 * cxy + c2))
                / ((ux * ux + uy * uy + c1) * (vx + vy + c2));
        }
        total += sum / mx.len() as f64;
    }
    total / 3.0
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A view of `target` (through some camera of its size) with `weights`.
    pub(crate) fn view_of(target: Image, weights: Option<Vec<f32>>) -> View {
        let camera = crate::model::Camera::look_at(
            [0.0, 0.0, -1.0],
            [0.0; 3],
            [0.0, 1.0, 0.0],
            40.0,
            target.width,
            target.height,
        )
        .unwrap();
        View {
            camera,
            time: 0.0,
            image: target.into(),
            name: "v".into(),
            weights,
        }
    }

    #[test]
    fn losses_sum_in_blocks_and_lanes_as_the_plain_sum_does_and_the_same_on_any_threads() {
        use rand::RngExt;
        let mut rng = crate::model::random::seeded_rng(7);
        // 301×251 pixels: several blocks, the last partial, and a partial group of lanes.
        let (w, h) = (301, 251);
        let mut random = |n: usize, scale: f32| -> Vec<f32> {
            (0..n)
                .map(|_| rng.random_range(-1.0..1.0) * scale)
                .collect()
        };
        let image = Image {
            width: w,
            height: h,
            pixels: random(3 * (w * h) as usize, 2.0),
        };
        let target = Image {
            width: w,
            height: h,
            pixels: random(3 * (w * h) as usize, 1.0),
        };
        let weights: Vec<f32> = random((w * h) as usize, 1.0)
            .iter()
            .map(|x| x.abs())
            .collect();
        // The definitions, one addition after another.
        let squares = |i: usize| (f64::from(image.pixels[i]) - f64::from(target.pixels[i])).powi(2);
        let plain = (0..image.pixels.len()).map(squares).sum::<f64>() / image.pixels.len() as f64;
        let weighted_sum: f64 = (0..weights.len())
            .map(|p| f64::from(weights[p]) * (3 * p..3 * p + 3).map(squares).sum::<f64>())
            .sum();
        let total: f64 = weights.iter().map(|&x| f64::from(x)).sum();
        let weighted = weighted_sum / (3.0 * total);
        let on = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                (
                    mse(&image, &target),
                    weighted_mse(&image, &target, &weights),
                )
            })
        };
        let (one, one_weighted) = on(1);
        assert!((one / plain - 1.0).abs() < 1e-12, "{one} against {plain}");
        assert!(
            (one_weighted / weighted - 1.0).abs() < 1e-12,
            "{one_weighted} against {weighted}"
        );
        for threads in [2, 3] {
            let (many, many_weighted) = on(threads);
            assert_eq!(many.to_bits(), one.to_bits(), "{threads} threads");
            assert_eq!(
                many_weighted.to_bits(),
                one_weighted.to_bits(),
                "{threads} threads"
            );
        }
        // Every term counts once: a lane sum of ones is the count, tails included.
        for len in [0, 1, 7, 8, 9, 17, 64] {
            assert_eq!(lane_sum(len, |_| 1.0), len as f64);
        }
    }

    #[test]
    fn weighted_mse_is_the_weighted_mean_and_its_gradient_matches() {
        let target = Image {
            width: 2,
            height: 1,
            pixels: vec![0.0, 0.0, 0.0, 1.0, 1.0, 1.0],
        };
        let image = Image {
            width: 2,
            height: 1,
            pixels: vec![0.5, 0.5, 0.5, 0.0, 0.0, 0.0],
        };
        let mut view = view_of(target, None);
        let mut v = Vec::new();
        // Unweighted: (3·0.25 + 3·1)/6; weights (1, 1) give the same number.
        assert_eq!(view_mse(&image, &view), 0.625);
        assert_eq!(view_mse_with_gradient(&image, &view, 1.0, &mut v), 0.625);
        view.weights = Some(vec![1.0, 1.0]);
        assert_eq!(view_mse(&image, &view), 0.625);
        // The second pixel left out: the first pixel's 0.25 alone.
        view.weights = Some(vec![1.0, 0.0]);
        assert_eq!(view_mse_with_gradient(&image, &view, 0.5, &mut v), 0.25);
        // ∂/∂C of Σ w (C - T)² / (3 Σ w), times 0.5: 0.5 · 2 · 0.5 / 3 on the first pixel.
        assert!((v[0] - 0.5 * 2.0 * 0.5 / 3.0).abs() < 1e-7, "{v:?}");
        assert_eq!(&v[3..], &[0.0; 3]);
        view.weights = Some(vec![0.0, 0.0]);
        assert_eq!(view_mse(&image, &view), 0.0);
    }

    #[test]
    fn the_per_run_gradient_is_the_whole_image_formula_on_any_runs() {
        // `scale (C - T)`, or `scale w_p (C - T)`, each in f32 as written, with the scale
        // computed in f64 and rounded once; runs of any length and start give the same bits.
        let (w, h) = (7_u32, 3_u32);
        let n = (3 * w * h) as usize;
        let value = |k: usize, phase: f64| (0.37 * k as f64 + phase).sin() as f32;
        let image = Image {
            width: w,
            height: h,
            pixels: (0..n).map(|k| value(k, 0.0)).collect(),
        };
        let target = Image {
            width: w,
            height: h,
            pixels: (0..n).map(|k| value(k, 1.3)).collect(),
        };
        let weights: Vec<f32> = (0..n / 3).map(|p| (p % 4) as f32 / 3.0).collect();
        let total: f64 = weights.iter().map(|&x| f64::from(x)).sum();
        for weighted in [false, true] {
            let view = view_of(target.clone(), weighted.then(|| weights.clone()));
            let expected: Vec<u32> = (0..n)
                .map(|k| {
                    let (c, t) = (image.pixels[k], target.pixels[k]);
                    let v = if weighted {
                        (0.25 * 2.0 / (3.0 * total)) as f32 * weights[k / 3] * (c - t)
                    } else {
                        (0.25 * 2.0 / n as f64) as f32 * (c - t)
                    };
                    v.to_bits()
                })
                .collect();
            let mut whole = Vec::new();
            view_mse_with_gradient(&image, &view, 0.25, &mut whole);
            assert_eq!(
                whole.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                expected
            );
            let gradient = view_mse_gradient(&view, 0.25);
            let mut runs = vec![f32::NAN; n];
            for (start, end) in [(0, 5), (5, 6), (6, 30), (30, n)] {
                gradient(start, &image.pixels[start..end], &mut runs[start..end]);
            }
            assert_eq!(
                runs.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                expected
            );
        }
    }

    /// The pattern of the independent reference value below, as f32 pixels.
    fn pattern(w: u32, h: u32, f: impl Fn(f64, f64, f64) -> f64) -> Image {
        let mut image = Image::filled(w, h, [0.0; 3]);
        for y in 0..h {
            for x in 0..w {
                for c in 0..3 {
                    image.pixels[3 * (y * w + x) as usize + c as usize] =
                        f(f64::from(x), f64::from(y), f64::from(c)) as f32;
                }
            }
        }
        image
    }

    #[test]
    fn ssim_matches_known_values() {
        let a = pattern(24, 20, |x, y, c| 0.5 + 0.4 * (0.3 * x + 0.7 * y + c).sin());
        // Identical images: 1.
        assert!((ssim(&a, &a) - 1.0).abs() < 1e-12);
        // scikit-image 0.26 `structural_similarity(a, b, gaussian_weights=True, sigma=1.5,
        // use_sample_covariance=False, data_range=1.0, channel_axis=-1)` on the same f32
        // values, computed in float64 (an independent implementation of Wang et al.).
        let mut b = a.clone();
        for y in 0..20_u32 {
            for x in 0..24_u32 {
                for c in 0..3_usize {
                    let k = 3 * (y * 24 + x) as usize + c;
                    let shift = 0.1
                        * (0.5 * f64::from(x) - 0.2 * f64::from(y) + 2.0 * c as f64).cos()
                        - 0.05;
                    b.pixels[k] = (f64::from(a.pixels[k]) + shift) as f32;
                }
            }
        }
        let value = ssim(&a, &b);
        assert!((value - 0.961_723_796_647_204_6).abs() < 1e-9, "{value}");
        assert!((ssim(&b, &a) - value).abs() < 1e-12, "symmetric");
        // Constant images x and y: (2xy + C1) / (x² + y² + C1), variances zero.
        let (x, y) = (0.25_f32, 0.75_f32);
        let value = ssim(
            &Image::filled(16, 16, [x; 3]),
            &Image::filled(16, 16, [y; 3]),
        );
        let (x, y) = (f64::from(x), f64::from(y));
        let expected = (2.0 * x * y + 1e-4) / (x * x + y * y + 1e-4);
        assert!((value - expected).abs() < 1e-12, "{value} vs {expected}");
        // Smaller than the window: one window the size of the image, still 1 on itself.
        let small = pattern(5, 4, |x, y, c| 0.1 * x + 0.2 * y + 0.05 * c);
        assert!((ssim(&small, &small) - 1.0).abs() < 1e-12);
    }
}
