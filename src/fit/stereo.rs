//! A start made from photos that have neither a flat background nor a point cloud: a
//! **plane sweep** over neighbouring views.
//!
//! Each training view in turn is the *reference*. Its neighbours are the (at most
//! [`NEIGHBOURS`]) other views whose optical axes are within [`MAX_AXIS_ANGLE_DEGREES`] of
//! its own, nearest first, at a different centre. Images wider or taller than
//! [`WORKING_SIDE`] pixels are box-filtered down first (the intrinsics divided alike).
//! Depth hypotheses are [`PLANES`] fronto-parallel planes spread evenly in inverse depth
//! from `d/3` to `6 d`, `d` the depth of the cameras' box centre. For a reference pixel p and
//! a depth z the point `X = c + z R⁻¹ K⁻¹ (p, 1)` is projected into each neighbour and its
//! colour read bilinearly; the pixel's cost at z is the mean over channels of
//! `|I_ref(p) - I_n(X)|`, averaged over the better half of the neighbours that see X (an
//! occluded neighbour should not veto), then averaged over a `(2 WINDOW + 1)²` window. A
//! pixel's depth is the plane of least cost (refined to the vertex of the parabola through
//! it and its two neighbours), kept when
//!
//! - that cost is below [`MAX_COST`],
//! - it is distinct: below [`DISTINCT_RATIO`] times the least cost of the planes more than
//!   two planes away (a textureless wall matches everywhere and says nothing),
//! - and the reference window is textured (its colour's standard deviation above
//!   [`MIN_TEXTURE`]).
//!
//! Every view gets a depth map so. Kept pixels on a grid of stride `s` (chosen so that
//! about `budget` pixels are tested over all views) whose point at least one neighbour's
//! depth map confirms (within [`AGREEMENT`] of the depth it found there: the geometric
//! consistency test of multi-view stereo) become points: position X, the reference's colour, the view's time, and
//! the spacing of the grid at that depth (`z s / fx`). The sweep is a start, not a model:
//! the fit moves, prunes and densifies from there. Deterministic: views are swept
//! independently (in parallel) and collected in order.

use rayon::prelude::*;

use crate::fit::init::SpaceTimeBox;
use crate::model::camera::Camera;
use crate::model::{Image, View};

/// Neighbours per reference view.
pub const NEIGHBOURS: usize = 4;
/// Largest angle between a reference's optical axis and a neighbour's.
pub const MAX_AXIS_ANGLE_DEGREES: f64 = 45.0;
/// Depth planes.
pub const PLANES: usize = 64;
/// The cost window's half side, pixels.
pub const WINDOW: usize = 2;
/// Largest kept cost (mean absolute difference per channel).
pub const MAX_COST: f32 = 0.05;
/// A kept depth's cost is below this fraction of the best cost far from it.
pub const DISTINCT_RATIO: f32 = 0.8;
/// Smallest standard deviation of a kept reference window's colour.
pub const MIN_TEXTURE: f32 = 0.01;
/// Largest side the sweep works at, pixels.
pub const WORKING_SIDE: u32 = 320;

/// A point of the sweep: where, which colour, when, and the spacing of its neighbours.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SweptPoint {
    /// World position.
    pub position: [f64; 3],
    /// The reference pixel's colour.
    pub colour: [f32; 3],
    /// The reference view's time.
    pub time: f64,
    /// The grid's spacing at the point's depth, world units.
    pub spacing: f64,
    /// The reference view's index in the views swept.
    pub view: usize,
    /// The reference pixel `(column, row)` in the view's own image (before the sweep's
    /// downscaling: the centre pixel of the block it averaged).
    pub pixel: [u32; 2],
}

/// The plane-sweep points of `views` (module doc), about `budget` pixels tested; `bounds`
/// gives the depth range.
#[must_use]
pub fn plane_sweep(views: &[View], bounds: &SpaceTimeBox, budget: usize) -> Vec<SweptPoint> {
    let centre: [f64; 3] = std::array::from_fn(|a| 0.5 * (bounds.min[a] + bounds.max[a]));
    plane_sweep_in(views, Depths::Around(centre), budget)
}

/// The depths a sweep tries.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Depths {
    /// From `d/3` to `6 d`, `d` the reference camera's depth of this point.
    Around([f64; 3]),
    /// From `near` to `far` (camera depths, `0 < near < far`) for every reference.
    Between([f64; 2]),
}

/// The plane-sweep points of `views` (module doc) over the planes of `depths`, about
/// `budget` pixels tested.
#[must_use]
pub fn plane_sweep_in(views: &[View], depths: Depths, budget: usize) -> Vec<SweptPoint> {
    let working: Vec<(Camera, Image)> = views.iter().map(working_copy).collect();
    let pixels: usize = working.iter().map(|(c, _)| c.pixel_count()).sum();
    // Stride so that about `budget` of the pixels are tested.
    let stride = ((pixels as f64 / budget.max(1) as f64).sqrt().ceil() as usize).max(1);
    let neighbours: Vec<Vec<usize>> = (0..views.len())
        .map(|r| neighbours_of(r, &working))
        .collect();
    let depth_maps: Vec<Vec<f32>> = (0..views.len())
        .into_par_iter()
        .map(|r| depth_map(&working, r, &neighbours[r], depths))
        .collect();
    (0..views.len())
        .into_par_iter()
        .map(|r| {
            let factor = views[r].camera.width / working[r].0.width.max(1);
            consistent_points(
                &working,
                &depth_maps,
                Reference {
                    view: r,
                    time: views[r].time,
                    factor,
                },
                &neighbours[r],
                stride,
            )
        })
        .collect::<Vec<_>>()
        .concat()
}

/// The view's camera and image at most [`WORKING_SIDE`] on a side.
fn working_copy(view: &View) -> (Camera, Image) {
    let side = view.camera.width.max(view.camera.height);
    let factor = side.div_ceil(WORKING_SIDE).max(1);
    if factor == 1 {
        return (view.camera, (*view.image).clone());
    }
    let mut camera = view.camera;
    camera.width = view.camera.width / factor;
    camera.height = view.camera.height / factor;
    let f = f64::from(factor);
    camera.fx /= f;
    camera.fy /= f;
    camera.cx /= f;
    camera.cy /= f;
    (camera, view.image.downscaled(factor))
}

/// Up to [`NEIGHBOURS`] views near view `r` that look the same way from elsewhere.
fn neighbours_of(r: usize, working: &[(Camera, Image)]) -> Vec<usize> {
    let reference = &working[r].0;
    let (centre, dir) = (reference.centre(), reference.optical_axis());
    let cos_max = MAX_AXIS_ANGLE_DEGREES.to_radians().cos();
    let mut candidates: Vec<(f64, usize)> = working
        .iter()
        .enumerate()
        .filter(|&(n, _)| n != r)
        .filter_map(|(n, (camera, _))| {
            let other = camera.centre();
            let distance = (0..3)
                .map(|a| (other[a] - centre[a]).powi(2))
                .sum::<f64>()
                .sqrt();
            let axis = camera.optical_axis();
            let cos = (0..3).map(|a| axis[a] * dir[a]).sum::<f64>();
            (cos >= cos_max && distance > 1e-9).then_some((distance, n))
        })
        .collect();
    candidates.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    candidates.truncate(NEIGHBOURS);
    candidates.into_iter().map(|(_, n)| n).collect()
}

/// View `r`'s depth per pixel (NaN where the sweep keeps none; module doc).
fn depth_map(
    working: &[(Camera, Image)],
    r: usize,
    neighbours: &[usize],
    depths: Depths,
) -> Vec<f32> {
    let (camera, image) = &working[r];
    let (w, h) = (camera.width as usize, camera.height as usize);
    let mut depth = vec![f32::NAN; w * h];
    let [nearest, farthest] = match depths {
        Depths::Around(centre) => {
            let target = camera.to_camera_space(centre)[2];
            [target / 3.0, 6.0 * target]
        }
        Depths::Between(range) => range,
    };
    let usable = nearest > 0.0 && nearest < farthest && farthest.is_finite();
    if neighbours.is_empty() || !usable {
        return depth;
    }
    let (near, far) = (1.0 / nearest, 1.0 / farthest);
    let inverse_depths: Vec<f64> = (0..PLANES)
        .map(|k| near + (far - near) * k as f64 / (PLANES - 1) as f64)
        .collect();
    let to_world = camera_to_world(camera);
    let mut volume = vec![0.0_f32; PLANES * w * h];
    for (k, &inverse) in inverse_depths.iter().enumerate() {
        let costs = plane_costs(working, camera, image, neighbours, &to_world, 1.0 / inverse);
        box_filter(&costs, w, h, &mut volume[k * w * h..(k + 1) * w * h]);
    }
    for j in 0..h {
        for i in 0..w {
            let p = j * w + i;
            if let Some(k) = chosen_plane(&volume, w * h, p)
                && texture(image, w, h, i, j) >= MIN_TEXTURE
            {
                depth[p] = refined_depth(&volume, w * h, p, k, &inverse_depths) as f32;
            }
        }
    }
    depth
}

/// The points of view `r` on a grid of `stride` whose depth at least one neighbour's depth
/// map confirms: the point, seen from the neighbour, lies within [`AGREEMENT`] (relative)
/// of the depth the neighbour found there.
fn consistent_points(
    working: &[(Camera, Image)],
    depth_maps: &[Vec<f32>],
    reference: Reference,
    neighbours: &[usize],
    stride: usize,
) -> Vec<SweptPoint> {
    let Reference {
        view: r,
        time,
        factor,
    } = reference;
    let (camera, image) = &working[r];
    let (w, h) = (camera.width as usize, camera.height as usize);
    let to_world = camera_to_world(camera);
    let confirmed = |point: [f64; 3]| {
        neighbours.iter().any(|&n| {
            let other = &working[n].0;
            let [u, v, z] = other.project_point(point);
            let (i, j) = (u.floor(), v.floor());
            if !(z > 0.0 && i >= 0.0 && j >= 0.0) {
                return false;
            }
            let (i, j) = (i as usize, j as usize);
            if i >= other.width as usize || j >= other.height as usize {
                return false;
            }
            let found = f64::from(depth_maps[n][j * other.width as usize + i]);
            (found - z).abs() <= AGREEMENT * z
        })
    };
    let mut points = Vec::new();
    for j in (stride / 2..h).step_by(stride) {
        for i in (stride / 2..w).step_by(stride) {
            let depth = f64::from(depth_maps[r][j * w + i]);
            // NaN: no depth kept; a depth beyond f32 (cameras 1e40 apart) is none either.
            if !(depth.is_finite() && depth > 0.0) {
                continue;
            }
            let position = pixel_point(camera, &to_world, i, j, depth);
            let spacing = depth * stride as f64 / camera.fx;
            let finite = position.iter().all(|v| v.is_finite()) && spacing.is_finite();
            if finite && spacing > 0.0 && confirmed(position) {
                points.push(SweptPoint {
                    position,
                    colour: image.pixel(i as u32, j as u32),
                    time,
                    spacing,
                    view: r,
                    pixel: [
                        i as u32 * factor + factor / 2,
                        j as u32 * factor + factor / 2,
                    ],
                });
            }
        }
    }
    points
}

/// A reference view of a sweep: its index, time, and the factor its working copy was
/// downscaled by.
#[derive(Clone, Copy)]
struct Reference {
    view: usize,
    time: f64,
    factor: u32,
}

/// How closely a neighbour's depth must agree with a point's, relative to the depth.
pub const AGREEMENT: f64 = 0.02;

/// Rc⁻¹ and the centre: camera space to world. `Rc` need not be orthonormal (SPEC §3); when
/// it is, to 1e-6 in `Rc Rcᵀ` (rotations from files written to 7 digits or more), `Rc⁻¹` is
/// taken as `Rcᵀ`: a point then lands within about `1e-6 f` pixels of its pixel.
pub(crate) fn camera_to_world(camera: &Camera) -> ([[f64; 3]; 3], [f64; 3]) {
    let r = camera.rotation();
    let transpose: [[f64; 3]; 3] = std::array::from_fn(|a| std::array::from_fn(|b| r[b][a]));
    if camera.has_orthonormal_rotation() {
        return (transpose, camera.centre());
    }
    // glam's matrices are column-major: the transpose's columns are Rc's rows.
    let inverse = glam::DMat3::from_cols_array_2d(&transpose).inverse();
    let rows = inverse.transpose().to_cols_array_2d();
    (rows, camera.centre())
}

/// The world point at camera depth `depth` through pixel `(i, j)`'s centre (`to_world` from
/// [`camera_to_world`]).
pub(crate) fn pixel_point(
    camera: &Camera,
    (rotation, centre): &([[f64; 3]; 3], [f64; 3]),
    i: usize,
    j: usize,
    depth: f64,
) -> [f64; 3] {
    let x = (i as f64 + 0.5 - camera.cx) / camera.fx * depth;
    let y = (j as f64 + 0.5 - camera.cy) / camera.fy * depth;
    let local = [x, y, depth];
    std::array::from_fn(|a| centre[a] + (0..3).map(|b| rotation[a][b] * local[b]).sum::<f64>())
}

/// Per reference pixel, the cost of the plane at `depth`: the mean over the better half of
/// the neighbours that see the point of the mean absolute colour difference; a pixel no
/// neighbour sees costs [`UNSEEN_COST`].
fn plane_costs(
    working: &[(Camera, Image)],
    camera: &Camera,
    image: &Image,
    neighbours: &[usize],
    to_world: &([[f64; 3]; 3], [f64; 3]),
    depth: f64,
) -> Vec<f32> {
    let (w, h) = (camera.width as usize, camera.height as usize);
    let mut costs = vec![UNSEEN_COST; w * h];
    let mut found = Vec::with_capacity(neighbours.len());
    for j in 0..h {
        for i in 0..w {
            let point = pixel_point(camera, to_world, i, j, depth);
            let reference = image.pixel(i as u32, j as u32);
            found.clear();
            for &n in neighbours {
                let (other, other_image) = &working[n];
                let [u, v, z] = other.project_point(point);
                if let Some(colour) = (z > 0.0).then(|| bilinear(other_image, u, v)).flatten() {
                    let difference = (0..3)
                        .map(|c| (colour[c] - reference[c]).abs())
                        .sum::<f32>()
                        / 3.0;
                    found.push(difference);
                }
            }
            if found.is_empty() {
                continue;
            }
            found.sort_by(f32::total_cmp);
            let used = found.len().div_ceil(2);
            costs[j * w + i] = found[..used].iter().sum::<f32>() / used as f32;
        }
    }
    costs
}

/// The cost of a pixel that no neighbour sees at a depth.
const UNSEEN_COST: f32 = 1.0;

/// `image` read bilinearly at pixel coordinates `(u, v)` (pixel centres at `+ ½`), `None`
/// outside the pixel centres' hull.
fn bilinear(image: &Image, u: f64, v: f64) -> Option<[f32; 3]> {
    let (x, y) = (u - 0.5, v - 0.5);
    let (w, h) = (f64::from(image.width), f64::from(image.height));
    if !(x >= 0.0 && y >= 0.0 && x <= w - 1.0 && y <= h - 1.0) {
        return None;
    }
    // `x` and `y` are at least 0 here: truncation is their floor (without a libm call).
    let (i0, j0) = (x as u32, y as u32);
    let (i1, j1) = (
        (i0 + 1).min(image.width - 1),
        (j0 + 1).min(image.height - 1),
    );
    let (fx, fy) = ((x - f64::from(i0)) as f32, (y - f64::from(j0)) as f32);
    let [a, b, c, d] = [
        image.pixel(i0, j0),
        image.pixel(i1, j0),
        image.pixel(i0, j1),
        image.pixel(i1, j1),
    ];
    Some(std::array::from_fn(|k| {
        (a[k] * (1.0 - fx) + b[k] * fx) * (1.0 - fy) + (c[k] * (1.0 - fx) + d[k] * fx) * fy
    }))
}

/// The mean of `costs` over the `(2 WINDOW + 1)²` window around each pixel (clipped at the
/// edges), into `out`: per pixel, the window's row sums (each left to right) added top to
/// bottom, then divided by the window's size. A row's sum over a window is the same for the
/// `2 WINDOW + 1` pixels above and below that use it, so each is computed once
/// (`row_sums`); the additions are those of summing every window afresh, in the same order.
fn box_filter(costs: &[f32], w: usize, h: usize, out: &mut [f32]) {
    let columns = |i: usize| (i.saturating_sub(WINDOW), (i + WINDOW).min(w - 1));
    let row_sums: Vec<f32> = (0..h * w)
        .map(|p| {
            let (jj, i) = (p / w, p % w);
            let (i0, i1) = columns(i);
            costs[jj * w + i0..=jj * w + i1].iter().sum::<f32>()
        })
        .collect();
    for j in 0..h {
        let (j0, j1) = (j.saturating_sub(WINDOW), (j + WINDOW).min(h - 1));
        for i in 0..w {
            let (i0, i1) = columns(i);
            let mut sum = 0.0;
            for jj in j0..=j1 {
                sum += row_sums[jj * w + i];
            }
            out[j * w + i] = sum / ((j1 - j0 + 1) * (i1 - i0 + 1)) as f32;
        }
    }
}

/// The plane of least cost at pixel `p` when it is low and distinct (module doc).
fn chosen_plane(volume: &[f32], plane_size: usize, p: usize) -> Option<usize> {
    let cost = |k: usize| volume[k * plane_size + p];
    let best = (0..PLANES).min_by(|&a, &b| cost(a).total_cmp(&cost(b)))?;
    let rival = (0..PLANES)
        .filter(|&k| k.abs_diff(best) > 2)
        .map(cost)
        .fold(f32::INFINITY, f32::min);
    (cost(best) < MAX_COST && cost(best) < DISTINCT_RATIO * rival).then_some(best)
}

/// The depth of plane `k` at pixel `p`, refined between its neighbours: the vertex of the
/// parabola through the three costs, in inverse depth (the planes' spacing), at most half a
/// plane away.
fn refined_depth(
    volume: &[f32],
    plane_size: usize,
    p: usize,
    k: usize,
    inverse_depths: &[f64],
) -> f64 {
    if k == 0 || k + 1 == PLANES {
        return 1.0 / inverse_depths[k];
    }
    let cost = |k: usize| f64::from(volume[k * plane_size + p]);
    let (before, at, after) = (cost(k - 1), cost(k), cost(k + 1));
    let curvature = before - 2.0 * at + after;
    let offset = if curvature > 0.0 {
        (0.5 * (before - after) / curvature).clamp(-0.5, 0.5)
    } else {
        0.0
    };
    let step = inverse_depths[k + 1] - inverse_depths[k];
    1.0 / (inverse_depths[k] + offset * step)
}

/// The standard deviation of the colour (all channels) in the window around `(i, j)`.
fn texture(image: &Image, w: usize, h: usize, i: usize, j: usize) -> f32 {
    let (j0, j1) = (j.saturating_sub(WINDOW), (j + WINDOW).min(h - 1));
    let (i0, i1) = (i.saturating_sub(WINDOW), (i + WINDOW).min(w - 1));
    let (mut sum, mut square, mut count) = (0.0_f32, 0.0_f32, 0.0_f32);
    for jj in j0..=j1 {
        for ii in i0..=i1 {
            for v in image.pixel(ii as u32, jj as u32) {
                sum += v;
                square += v * v;
                count += 1.0;
            }
        }
    }
    let mean = sum / count;
    (square / count - mean * mean).max(0.0).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_pixels_point_at_a_depth_projects_back_to_it_through_any_invertible_rc() {
        let orthonormal =
            Camera::look_at([1.0, 0.5, 4.0], [0.0; 3], [0.0, 1.0, 0.0], 45.0, 40, 30).unwrap();
        for camera in [orthonormal, orthonormal.sheared()] {
            let to_world = camera_to_world(&camera);
            for (i, j, depth) in [(0, 0, 2.0), (39, 29, 5.0), (17, 11, 0.5)] {
                let [u, v, z] = camera.project_point(pixel_point(&camera, &to_world, i, j, depth));
                assert!((u - (i as f64 + 0.5)).abs() < 1e-9, "{u} for {i}");
                assert!((v - (j as f64 + 0.5)).abs() < 1e-9, "{v} for {j}");
                assert!((z - depth).abs() < 1e-9, "{z} for {depth}");
            }
        }
        // The loaders' orthonormal rotations keep the transpose, bit for bit.
        let r = orthonormal.rotation();
        assert_eq!(
            camera_to_world(&orthonormal).0,
            std::array::from_fn(|a| std::array::from_fn(|b| r[b][a]))
        );
    }

    /// Every window summed afresh: each row of the window left to right, the rows top to
    /// bottom, divided by the window's size.
    fn box_filter_by_definition(costs: &[f32], w: usize, h: usize) -> Vec<f32> {
        let mut out = vec![0.0; w * h];
        for j in 0..h {
            for i in 0..w {
                let (j0, j1) = (j.saturating_sub(WINDOW), (j + WINDOW).min(h - 1));
                let (i0, i1) = (i.saturating_sub(WINDOW), (i + WINDOW).min(w - 1));
                let mut sum = 0.0;
                for jj in j0..=j1 {
                    sum += costs[jj * w + i0..=jj * w + i1].iter().sum::<f32>();
                }
                out[j * w + i] = sum / ((j1 - j0 + 1) * (i1 - i0 + 1)) as f32;
            }
        }
        out
    }

    #[test]
    fn the_box_filter_gives_the_definitions_bits() {
        // Sizes below, at and above the window, with costs of many magnitudes.
        for (w, h) in [(1, 1), (3, 2), (5, 5), (7, 13), (40, 9)] {
            let costs: Vec<f32> = (0..w * h)
                .map(|k| (k as f32 * 0.618_034).fract() * 10f32.powi(k as i32 % 7 - 3))
                .collect();
            let mut out = vec![f32::NAN; w * h];
            box_filter(&costs, w, h, &mut out);
            let expected = box_filter_by_definition(&costs, w, h);
            assert!(
                out.iter()
                    .zip(&expected)
                    .all(|(a, b)| a.to_bits() == b.to_bits()),
                "{w}×{h}"
            );
        }
    }

    #[test]
    fn bilinear_reads_pixel_centres_exactly_and_refuses_outside() {
        let mut image = Image::filled(2, 2, [0.0; 3]);
        image.pixels[3..6].copy_from_slice(&[1.0, 1.0, 1.0]);
        assert_eq!(bilinear(&image, 1.5, 0.5), Some([1.0; 3]));
        assert_eq!(bilinear(&image, 1.0, 0.5), Some([0.5; 3]));
        assert_eq!(bilinear(&image, 0.4, 0.5), None);
        assert_eq!(bilinear(&image, 1.6, 0.5), None);
    }
}
