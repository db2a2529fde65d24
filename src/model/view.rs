//! Views to fit: images with the camera that took them and their scene time, and the
//! train / val / test splits of a dataset.

use crate::model::camera::Camera;
use crate::model::image::{Image, downscale_weighted};

/// One image with its camera and time.
///
/// SPEC §6: the loss compares a render of `camera` at `time` with `image`.
#[derive(Clone, Debug)]
pub struct View {
    /// The camera that took it.
    pub camera: Camera,
    /// Scene time.
    pub time: f64,
    /// Linear RGB, shared: frames that name one file share one decoded image.
    pub image: std::sync::Arc<Image>,
    /// Where it came from (`./train/r_000`), for messages and reports.
    pub name: String,
    /// Per-pixel loss weights in `[0, 1]`, row-major, one per pixel of `image`: 0 leaves a
    /// pixel out of the loss (outside an undistorted photo, masked out by the dataset), 1
    /// counts it fully. The loss is then the weighted mean (SPEC §6 with weights;
    /// [`crate::fit::loss`]). `None`: every pixel counts fully (the plain mean).
    pub weights: Option<Vec<f32>>,
}

impl View {
    /// The view as a camera of `n`-times fewer pixels on each axis would take it: the image
    /// (and its weights) box-filtered over `n × n` blocks, `⌊w/n⌋ × ⌊h/n⌋`, the intrinsics
    /// divided by `n`. Pixel `(i, j)`'s centre `(i + ½, j + ½)` (SPEC §3) then sits at the
    /// centre of the block it averages, `(n i + n/2, n j + n/2)` of the original, so a render
    /// through the new camera samples the scene where the block's mean does. `n = 1` shares
    /// the image. `None` when the image is smaller than `n` on a side.
    #[must_use]
    pub fn downscaled(&self, n: u32) -> Option<View> {
        let n = n.max(1);
        if n == 1 {
            return Some(self.clone());
        }
        if self.image.width < n || self.image.height < n {
            return None;
        }
        let (image, weights) = match &self.weights {
            Some(w) => {
                let (image, weights) = downscale_weighted(&self.image, w, n);
                (image, Some(weights))
            }
            None => (self.image.downscaled(n), None),
        };
        let scale = f64::from(n);
        let camera = Camera {
            width: image.width,
            height: image.height,
            fx: self.camera.fx / scale,
            fy: self.camera.fy / scale,
            cx: self.camera.cx / scale,
            cy: self.camera.cy / scale,
            ..self.camera
        };
        Some(View {
            camera,
            time: self.time,
            image: std::sync::Arc::new(image),
            name: self.name.clone(),
            weights,
        })
    }
}

impl View {
    /// The `width × height` window of this view whose top-left pixel is `(left, top)`: the
    /// image's (and weights') pixels there, and the camera with its principal point moved by
    /// `(-left, -top)` (SPEC §3: pixel `(i, j)` of the window is pixel `(left + i, top + j)`
    /// of the view, the same ray) that keeps the view's clamp limits (SPEC §4), so that the
    /// window renders the view's pixels. `None` when the window leaves the image or is
    /// empty.
    #[must_use]
    pub fn cropped(&self, left: u32, top: u32, width: u32, height: u32) -> Option<View> {
        let (w, h) = (self.image.width, self.image.height);
        if width == 0 || height == 0 || left.checked_add(width)? > w || top.checked_add(height)? > h
        {
            return None;
        }
        let rows = top as usize..(top + height) as usize;
        let columns = left as usize..(left + width) as usize;
        let mut pixels = Vec::with_capacity(3 * width as usize * height as usize);
        for j in rows.clone() {
            let row = j * w as usize;
            pixels.extend_from_slice(
                &self.image.pixels[3 * (row + columns.start)..3 * (row + columns.end)],
            );
        }
        let weights = self.weights.as_ref().map(|weights| {
            rows.flat_map(|j| {
                let row = j * w as usize;
                weights[row + columns.start..row + columns.end]
                    .iter()
                    .copied()
            })
            .collect()
        });
        let camera = Camera {
            width,
            height,
            cx: self.camera.cx - f64::from(left),
            cy: self.camera.cy - f64::from(top),
            clamp: Some(self.camera.clamp_limits()),
            ..self.camera
        };
        Some(View {
            camera,
            time: self.time,
            image: std::sync::Arc::new(Image {
                width,
                height,
                pixels,
            }),
            name: self.name.clone(),
            weights,
        })
    }
}

/// A point of the cloud a dataset ships (COLMAP `points3D`, nerfstudio `ply_file_path`), in
/// the world of the dataset's cameras.
///
/// Not part of SPEC: a fit's possible start (`docs/formats.md`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DatasetPoint {
    /// World position.
    pub position: [f64; 3],
    /// Colour as the dataset stores it, read like its images: 8-bit `v / 255`, no sRGB curve.
    pub colour: [f32; 3],
}

/// A dataset's splits.
///
/// SPEC §6 fits the `train` split; `docs/formats.md` lists the layouts read.
#[derive(Clone, Debug, Default)]
pub struct Dataset {
    /// Views to fit.
    pub train: Vec<View>,
    /// Held-out views for monitoring.
    pub val: Vec<View>,
    /// Held-out views for final evaluation.
    pub test: Vec<View>,
    /// True when some pixel had alpha below 1 (and was composited over a background).
    pub transparent: bool,
    /// What the reader noticed and skipped (keys it does not read, frames without an
    /// image), for the user to see.
    pub notes: Vec<String>,
    /// The blend a dataset written by splat4d says its images were rendered with.
    pub blend: Option<super::Blend>,
    /// The point cloud the dataset gives (COLMAP `points3D`, nerfstudio `ply_file_path`), to
    /// start kernels from; `None` when it gives none.
    pub points: Option<Vec<DatasetPoint>>,
    /// The camera depths the scene lies between, `[near, far]`, when the dataset states them
    /// (LLFF's bounds in `poses_bounds.npy`: the least near and the greatest far), for a
    /// start's depth search; `None` when it does not.
    pub depth_range: Option<[f64; 2]>,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn view(width: u32, height: u32) -> View {
        let camera = Camera::look_at(
            [0.3, -0.2, 4.0],
            [0.0; 3],
            [0.0, 1.0, 0.0],
            40.0,
            width,
            height,
        )
        .unwrap();
        let pixels = (0..3 * width * height)
            .map(|i| (i % 97) as f32 / 97.0)
            .collect();
        View {
            camera,
            time: 0.25,
            image: std::sync::Arc::new(Image {
                width,
                height,
                pixels,
            }),
            name: "v".into(),
            weights: Some((0..width * height).map(|i| (i % 3) as f32 / 2.0).collect()),
        }
    }

    /// A point lands `n` times closer to the image's corner: pixel `(i, j)` of the small
    /// image, centred at `(i + ½, j + ½)`, sees what the centre of its block sees.
    #[test]
    fn a_downscaled_camera_sees_each_point_at_its_blocks_place() {
        let full = view(43, 30);
        for n in [2, 3, 4] {
            let small = full.downscaled(n).unwrap();
            assert_eq!((small.camera.width, small.camera.height), (43 / n, 30 / n));
            assert_eq!((small.image.width, small.image.height), (43 / n, 30 / n));
            for p in [[0.1, 0.2, -0.3], [-0.5, 0.4, 0.2], [0.0, 0.0, 0.0]] {
                let [u, v, z] = full.camera.project_point(p);
                let [us, vs, zs] = small.camera.project_point(p);
                let scale = f64::from(n);
                assert!((us * scale - u).abs() < 1e-12 * u.abs().max(1.0));
                assert!((vs * scale - v).abs() < 1e-12 * v.abs().max(1.0));
                assert_eq!(zs, z);
            }
        }
    }

    /// Each small pixel is its block's weighted mean colour, and its weight the block's mean
    /// weight; an image smaller than the factor gives none.
    #[test]
    fn a_downscaled_image_is_the_weighted_mean_of_its_blocks() {
        let full = view(7, 5);
        let small = full.downscaled(2).unwrap();
        let weights = full.weights.as_ref().unwrap();
        for (j, i) in [(0, 0), (1, 2), (1, 0)] {
            let block = [(0, 0), (1, 0), (0, 1), (1, 1)].map(|(di, dj)| (2 * i + di, 2 * j + dj));
            let w: Vec<f64> = block
                .iter()
                .map(|&(x, y)| f64::from(weights[(y * 7 + x) as usize]))
                .collect();
            let total: f64 = w.iter().sum();
            let got = small.image.pixel(i, j);
            for (c, got) in got.iter().enumerate() {
                let want: f64 = block
                    .iter()
                    .zip(&w)
                    .map(|(&(x, y), w)| w * f64::from(full.image.pixel(x, y)[c]))
                    .sum::<f64>()
                    / total;
                assert!((f64::from(*got) - want).abs() < 1e-6, "{i},{j},{c}");
            }
            let small_weight = small.weights.as_ref().unwrap()[(j * 3 + i) as usize];
            assert!((f64::from(small_weight) - total / 4.0).abs() < 1e-6);
        }
        assert!(full.downscaled(6).is_none());
        assert!(std::sync::Arc::ptr_eq(
            &full.downscaled(1).unwrap().image,
            &full.image
        ));
    }

    /// A window's pixel `(i, j)` is the view's `(left + i, top + j)`: the same colour and
    /// weight, and a point projects there, shifted by the corner exactly.
    #[test]
    fn a_window_sees_each_point_at_its_place_in_the_view() {
        let full = view(43, 30);
        let window = full.cropped(5, 7, 20, 11).unwrap();
        assert_eq!((window.camera.width, window.camera.height), (20, 11));
        for p in [[0.1, 0.2, -0.3], [-0.5, 0.4, 0.2], [0.0, 0.0, 0.0]] {
            let [u, v, z] = full.camera.project_point(p);
            let [uw, vw, zw] = window.camera.project_point(p);
            assert!((uw + 5.0 - u).abs() < 1e-12 * u.abs().max(1.0));
            assert!((vw + 7.0 - v).abs() < 1e-12 * v.abs().max(1.0));
            assert_eq!(zw, z);
        }
        let (weights, window_weights) = (full.weights.unwrap(), window.weights.unwrap());
        for (i, j) in [(0, 0), (19, 10), (3, 4)] {
            assert_eq!(window.image.pixel(i, j), full.image.pixel(5 + i, 7 + j));
            assert_eq!(
                window_weights[(j * 20 + i) as usize],
                weights[((7 + j) * 43 + 5 + i) as usize]
            );
        }
        let full = view(43, 30);
        assert!(full.cropped(24, 0, 20, 30).is_none());
        assert!(full.cropped(0, 0, 0, 30).is_none());
        assert!(full.cropped(u32::MAX, 0, 2, 2).is_none());
        assert!(full.cropped(23, 0, 20, 30).is_some());
    }
}
