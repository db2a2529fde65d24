//! The alpha fit's start (SPEC §8) for a **rig**: synchronised cameras filmed over time (a
//! Neural 3D Video capture), where every time is seen by several cameras at once.
//!
//! The training views form a rig ([`find_rig`]) when they fall into at least two cameras
//! (views with bit-identical cameras are one camera's frames) of at least two frames each,
//! and every time is seen by at least two cameras. Then:
//!
//! - **What stays still.** Each camera's *still image* is the per-pixel, per-channel median
//!   of its frames (at most [`MEDIAN_FRAMES`] of them, evenly through time): what a pixel
//!   shows most of the time, the backdrop behind whatever passes. A plane sweep
//!   ([`crate::fit::stereo`]) over the still images gives points; each becomes one kernel
//!   alive over the whole time range (σt [`STILL_TIME_SCALES`] times the range, velocity 0):
//!   one kernel, not one per frame.
//! - **What moves.** A pixel of a frame *moves* when some channel differs from its camera's
//!   still image by more than [`MOTION_THRESHOLD`]. At [`MOVING_TIMES`] times (evenly
//!   through the distinct times, all of them when fewer) the cameras' frames of that time
//!   are swept together — they see the same instant, so the sweep holds where the scene
//!   moves — and the points whose reference pixel moves become kernels at that time, with
//!   σt half the time range over the number of times swept (about half their gap).
//!
//! The planes lie between the dataset's depth bounds when it states them (LLFF's near and
//! far, [`crate::model::Dataset::depth_range`]), else around the cameras' box. The still
//! kernels take at most [`STILL_SHARE`] of `options.start_kernels` and the moving ones the
//! rest, each taken evenly through its list. The start is deterministic: the sweeps are, and
//! the kernels' rotations come from the seeded generator in list order.

use std::collections::BTreeMap;
use std::sync::Arc;

use crate::fit::alpha::AlphaFitOptions;
use crate::fit::alpha_start::{alpha_start, start_kernel};
use crate::fit::init::SpaceTimeBox;
use crate::fit::stereo::{Depths, SweptPoint, plane_sweep_in};
use crate::model::camera::Camera;
use crate::model::error::Result;
use crate::model::random::seeded_rng;
use crate::model::scene::{Kernel, Scene};
use crate::model::{Image, View};

/// Most frames of a camera its still image is the median of.
pub const MEDIAN_FRAMES: usize = 15;
/// A pixel moves when some channel differs from the still image by more than this.
pub const MOTION_THRESHOLD: f32 = 0.08;
/// Times whose frames are swept for what moves.
pub const MOVING_TIMES: usize = 12;
/// σt of a still kernel, in time ranges: its opacity at either end of the range is
/// `exp(-½ (½ / 8)²)` ≈ 0.998 of its peak.
pub const STILL_TIME_SCALES: f64 = 8.0;
/// The largest share of the start's kernels that are still.
pub const STILL_SHARE: f64 = 0.6;

/// A rig: per camera, the indices of its views (training order), and the distinct times.
#[derive(Clone, Debug, PartialEq)]
pub struct Rig {
    /// Per camera (in order of first appearance), its views sorted by time.
    pub cameras: Vec<Vec<usize>>,
    /// The distinct times, ascending.
    pub times: Vec<f64>,
}

/// The bits a camera is told apart by.
fn camera_key(camera: &Camera) -> Vec<u64> {
    let mut key: Vec<u64> = camera
        .world_to_camera
        .iter()
        .flatten()
        .map(|v| v.to_bits())
        .collect();
    key.extend([camera.fx, camera.fy, camera.cx, camera.cy].map(f64::to_bits));
    key.extend([u64::from(camera.width), u64::from(camera.height)]);
    key
}

/// The rig `views` form, if they form one (module doc).
#[must_use]
pub fn find_rig(views: &[View]) -> Option<Rig> {
    let mut order: Vec<Vec<u64>> = Vec::new();
    let mut cameras: BTreeMap<Vec<u64>, Vec<usize>> = BTreeMap::new();
    let mut seen_at: BTreeMap<u64, usize> = BTreeMap::new();
    for (i, view) in views.iter().enumerate() {
        let key = camera_key(&view.camera);
        let entry = cameras.entry(key.clone()).or_default();
        if entry.is_empty() {
            order.push(key);
        }
        entry.push(i);
        *seen_at.entry(view.time.to_bits()).or_default() += 1;
    }
    let times = {
        let mut times: Vec<f64> = seen_at.keys().map(|&b| f64::from_bits(b)).collect();
        times.sort_by(f64::total_cmp);
        times
    };
    let rig = order.len() >= 2
        && times.len() >= 2
        && times.iter().all(|t| t.is_finite())
        && cameras.values().all(|v| v.len() >= 2)
        && seen_at.values().all(|&n| n >= 2);
    rig.then(|| Rig {
        cameras: order
            .iter()
            .map(|key| {
                let mut list = cameras[key].clone();
                list.sort_by(|&a, &b| views[a].time.total_cmp(&views[b].time).then(a.cmp(&b)));
                list
            })
            .collect(),
        times,
    })
}

/// `count` items evenly through `0..n` (all of them when `n ≤ count`), ascending.
fn evenly(n: usize, count: usize) -> Vec<usize> {
    if n <= count {
        return (0..n).collect();
    }
    let mut picked: Vec<usize> = (0..count)
        .map(|k| (k * (n - 1) + (count - 1) / 2) / (count - 1).max(1))
        .collect();
    picked.dedup();
    picked
}

/// The per-pixel, per-channel median of `frames` (the upper median of an even count).
fn median_image(frames: &[&Image]) -> Image {
    let first = frames[0];
    let mut values = Vec::with_capacity(frames.len());
    let pixels = (0..first.pixels.len())
        .map(|k| {
            values.clear();
            values.extend(frames.iter().map(|f| f.pixels[k]));
            values.sort_by(f32::total_cmp);
            values[values.len() / 2]
        })
        .collect();
    Image {
        pixels,
        ..first.clone()
    }
}

/// Whether pixel `(i, j)` of `frame` moves against `still` (module doc).
fn moves(frame: &Image, still: &Image, [i, j]: [u32; 2]) -> bool {
    let (a, b) = (frame.pixel(i, j), still.pixel(i, j));
    (0..3).any(|c| (a[c] - b[c]).abs() > MOTION_THRESHOLD)
}

/// `points` thinned to at most `most`, taken evenly through the list.
fn thinned(points: Vec<SweptPoint>, most: usize) -> Vec<SweptPoint> {
    let stride = points.len().div_ceil(most.max(1)).max(1);
    points.into_iter().step_by(stride).collect()
}

/// The still and the moving points of the rig's start (module doc); `depths` the sweeps'
/// planes, `budget` the kernels wanted.
fn rig_points(
    views: &[View],
    rig: &Rig,
    depths: Depths,
    budget: usize,
) -> (Vec<SweptPoint>, Vec<SweptPoint>, f64) {
    let middle = 0.5 * (rig.times[0] + rig.times[rig.times.len() - 1]);
    let stills: Vec<Arc<Image>> = rig
        .cameras
        .iter()
        .map(|frames| {
            let chosen: Vec<&Image> = evenly(frames.len(), MEDIAN_FRAMES)
                .into_iter()
                .map(|k| &*views[frames[k]].image)
                .collect();
            Arc::new(median_image(&chosen))
        })
        .collect();
    let still_views: Vec<View> = rig
        .cameras
        .iter()
        .zip(&stills)
        .map(|(frames, still)| View {
            camera: views[frames[0]].camera,
            time: middle,
            image: Arc::clone(still),
            name: format!("{} (still)", views[frames[0]].name),
            weights: None,
        })
        .collect();
    let still_budget = (STILL_SHARE * budget as f64) as usize;
    // Twice the pixels tested as kernels wanted: the sweep keeps some of them.
    let still = thinned(
        plane_sweep_in(&still_views, depths, 2 * still_budget),
        still_budget,
    );
    let camera_of: BTreeMap<usize, usize> = rig
        .cameras
        .iter()
        .enumerate()
        .flat_map(|(c, frames)| frames.iter().map(move |&v| (v, c)))
        .collect();
    let swept_times = evenly(rig.times.len(), MOVING_TIMES);
    let gap = (rig.times[rig.times.len() - 1] - rig.times[0]) / swept_times.len().max(1) as f64;
    let per_time = (budget - still.len().min(budget)) / swept_times.len().max(1);
    let mut moving = Vec::new();
    for &k in &swept_times {
        let time = rig.times[k];
        let at: Vec<usize> = (0..views.len())
            .filter(|&v| views[v].time.to_bits() == time.to_bits())
            .collect();
        let frames: Vec<View> = at.iter().map(|&v| views[v].clone()).collect();
        let pixels: usize = frames.iter().map(|v| v.camera.pixel_count()).sum();
        let found: Vec<SweptPoint> = plane_sweep_in(&frames, depths, pixels)
            .into_iter()
            .filter(|p| {
                let v = at[p.view];
                moves(&views[v].image, &stills[camera_of[&v]], p.pixel)
            })
            .map(|p| SweptPoint {
                view: at[p.view],
                ..p
            })
            .collect();
        moving.extend(thinned(found, per_time));
    }
    (still, moving, 0.5 * gap)
}

/// The start of a fit of `views` (a `rig`) in `bounds` over `background`: kernels at the
/// still and the moving points (module doc); `None` when the sweep of the still images keeps
/// fewer than `min_points`. Returns the scene and a note saying what it holds.
pub fn rig_alpha_scene(
    views: &[View],
    rig: &Rig,
    depth_range: Option<[f64; 2]>,
    bounds: &SpaceTimeBox,
    background: [f64; 3],
    options: &AlphaFitOptions,
    min_points: usize,
) -> Result<Option<(Scene, String)>> {
    let depths = match depth_range {
        Some([near, far]) if near > 0.0 && near < far && far.is_finite() => {
            Depths::Between([near, far])
        }
        _ => Depths::Around(std::array::from_fn(|a| {
            0.5 * (bounds.min[a] + bounds.max[a])
        })),
    };
    let (still, moving, moving_time_scale) =
        rig_points(views, rig, depths, options.start_kernels.max(1));
    if still.len() < min_points {
        return Ok(None);
    }
    let range = (bounds.time[1] - bounds.time[0]).max(1e-9);
    let middle = 0.5 * (bounds.time[0] + bounds.time[1]);
    let mut rng = seeded_rng(options.seed);
    let mut kernel = |p: &SweptPoint, time: f64, time_scale: f64| -> Kernel {
        let [x, y, z] = p.position;
        let colour = p.colour.map(f64::from);
        start_kernel(&mut rng, [x, y, z, time], p.spacing, time_scale, colour)
    };
    let mut kernels: Vec<Kernel> = still
        .iter()
        .map(|p| kernel(p, middle, STILL_TIME_SCALES * range))
        .collect();
    kernels.extend(
        moving
            .iter()
            .map(|p| kernel(p, p.time, moving_time_scale.max(1e-9))),
    );
    let note = format!(
        "starting from the rig's plane sweeps: {} still kernels from {} cameras' median images, {} moving ones at {} times",
        still.len(),
        rig.cameras.len(),
        moving.len(),
        rig.times.len().min(MOVING_TIMES)
    );
    let scene = alpha_start(&kernels, background, options, "<rig start>")?;
    Ok(Some((scene, note)))
}

/// The box of a fit of `dataset`, given the one its cameras' axes give (`inferred`): for a
/// rig that states its depth range, [`rig_box`] when `inferred` failed or its centre lies
/// outside that range along the rig's mean optical axis (axes near parallel meet far away,
/// or behind the rig); `inferred` otherwise.
pub fn rig_bounds(
    dataset: &crate::model::Dataset,
    inferred: Result<SpaceTimeBox>,
) -> Result<SpaceTimeBox> {
    let (Some(rig), Some([near, far])) = (find_rig(&dataset.train), dataset.depth_range) else {
        return inferred;
    };
    let cameras: Vec<Camera> = rig
        .cameras
        .iter()
        .map(|frames| dataset.train[frames[0]].camera)
        .collect();
    if let Ok(bounds) = &inferred {
        let centre: [f64; 3] = std::array::from_fn(|a| 0.5 * (bounds.min[a] + bounds.max[a]));
        let (origin, axis) = mean_axis(&cameras);
        let depth: f64 = (0..3).map(|a| (centre[a] - origin[a]) * axis[a]).sum();
        if (near..=far).contains(&depth) {
            return inferred;
        }
    }
    let time = [rig.times[0], rig.times[rig.times.len() - 1]];
    match rig_box(&cameras, [near, far], time) {
        Some(bounds) => Ok(bounds),
        None => inferred,
    }
}

/// The cameras' mean centre and their mean optical axis, normalised (zero when the axes
/// cancel out).
fn mean_axis(cameras: &[Camera]) -> ([f64; 3], [f64; 3]) {
    let n = cameras.len().max(1) as f64;
    let centre: [f64; 3] =
        std::array::from_fn(|a| cameras.iter().map(|c| c.centre()[a]).sum::<f64>() / n);
    let axis: [f64; 3] =
        std::array::from_fn(|a| cameras.iter().map(|c| c.optical_axis()[a]).sum::<f64>() / n);
    let norm = axis.iter().map(|v| v * v).sum::<f64>().sqrt();
    let unit = if norm > 1e-9 {
        axis.map(|v| v / norm)
    } else {
        [0.0; 3]
    };
    (centre, unit)
}

/// A box for a rig whose optical axes are too close to parallel for
/// [`crate::fit::init::box_from_cameras`]: centred on the mean optical axis at the middle
/// of `depth_range` (its geometric mean), half as wide as the median camera sees there.
#[must_use]
pub fn rig_box(cameras: &[Camera], [near, far]: [f64; 2], time: [f64; 2]) -> Option<SpaceTimeBox> {
    if cameras.is_empty() || !(near > 0.0 && near < far && far.is_finite()) {
        return None;
    }
    let (centre, axis) = mean_axis(cameras);
    let depth = (near * far).sqrt();
    let target: [f64; 3] = std::array::from_fn(|a| centre[a] + depth * axis[a]);
    let mut halves: Vec<f64> = cameras
        .iter()
        .map(|c| 0.5 * depth * 0.5 * f64::from(c.height) / c.fy)
        .collect();
    halves.sort_by(f64::total_cmp);
    let half = halves[halves.len() / 2];
    let finite = axis != [0.0; 3] && half > 0.0 && target.iter().all(|v| v.is_finite());
    finite.then(|| SpaceTimeBox {
        min: target.map(|v| v - half),
        max: target.map(|v| v + half),
        time,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn view(camera: Camera, time: f64) -> View {
        View {
            camera,
            time,
            image: Image::filled(camera.width, camera.height, [0.5; 3]).into(),
            name: format!("t{time}"),
            weights: None,
        }
    }

    #[test]
    fn a_rig_is_two_cameras_or_more_seeing_every_time_together() {
        let a = Camera::look_at([0.0, 0.0, 3.0], [0.0; 3], [0.0, 1.0, 0.0], 40.0, 8, 6).unwrap();
        let b = Camera::look_at([0.5, 0.0, 3.0], [0.0; 3], [0.0, 1.0, 0.0], 40.0, 8, 6).unwrap();
        let views = vec![view(a, 1.0), view(b, 0.0), view(a, 0.0), view(b, 1.0)];
        let rig = find_rig(&views).unwrap();
        assert_eq!(rig.cameras, [vec![2, 0], vec![1, 3]]);
        assert_eq!(rig.times, [0.0, 1.0]);
        // One camera per time (a monocular capture) is no rig, nor one time.
        assert!(find_rig(&[view(a, 0.0), view(b, 1.0), view(a, 2.0)]).is_none());
        assert!(find_rig(&[view(a, 0.0), view(b, 0.0)]).is_none());
    }

    #[test]
    fn the_still_image_is_the_median_and_motion_is_measured_against_it() {
        let frames: Vec<Image> = [0.1, 0.9, 0.2, 0.15, 0.8]
            .iter()
            .map(|&v| Image::filled(2, 1, [v, 0.5, 0.5]))
            .collect();
        let refs: Vec<&Image> = frames.iter().collect();
        let still = median_image(&refs);
        assert_eq!(still.pixel(1, 0), [0.2, 0.5, 0.5]);
        assert!(moves(&frames[1], &still, [0, 0]));
        assert!(!moves(&frames[3], &still, [0, 0]));
        assert_eq!(evenly(5, 12), [0, 1, 2, 3, 4]);
        assert_eq!(evenly(100, 3), [0, 50, 99]);
    }

    #[test]
    fn parallel_cameras_get_a_box_between_the_bounds() {
        let cameras: Vec<Camera> = [-0.5, 0.5]
            .iter()
            .map(|&x| {
                Camera::look_at([x, 0.0, 0.0], [x, 0.0, -1.0], [0.0, 1.0, 0.0], 60.0, 8, 8).unwrap()
            })
            .collect();
        let bounds = rig_box(&cameras, [1.0, 4.0], [0.0, 1.0]).unwrap();
        let centre: Vec<f64> = (0..3)
            .map(|a| 0.5 * (bounds.min[a] + bounds.max[a]))
            .collect();
        assert!(centre[0].abs() < 1e-12 && centre[1].abs() < 1e-12);
        assert!((centre[2] + 2.0).abs() < 1e-12, "{centre:?}");
        assert!(rig_box(&cameras, [0.0, 4.0], [0.0, 1.0]).is_none());
    }
}
