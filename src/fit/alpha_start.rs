//! The alpha fit's starts (SPEC §8): alpha kernels from a dataset's point cloud, from the
//! cells of a visual hull ([`crate::fit::hull`]), from plane-sweep points
//! ([`crate::fit::stereo`]) or at random in the cameras' box. Which one a fit takes is the
//! plan's choice ([`crate::fit::plan`]). Every start is seeded: each kernel's rotation is
//! random, its SH zero, its opacity [`AlphaFitOptions::start_opacity`].

use rand::RngExt;

use crate::fit::alpha::AlphaFitOptions;
use crate::fit::init::SpaceTimeBox;
use crate::fit::shell::{ShellPoint, coverage, far_shell_points};
use crate::fit::stereo::SweptPoint;
use crate::model::error::{Error, Result};
use crate::model::random::{random_rotation, seeded_rng};
use crate::model::scene::{Kernel, Scene};
use crate::model::{DatasetPoint, View};

/// One kernel of a start: at `mean` (x, y, z, t), spatial σ `0.5 spacing`, temporal σ
/// `time_scale`, `colour`, a random rotation from `rng`.
pub(super) fn start_kernel(
    rng: &mut rand_chacha::ChaCha8Rng,
    mean: [f64; 4],
    spacing: f64,
    time_scale: f64,
    colour: [f64; 3],
) -> Kernel {
    let mut kernel = Kernel::new(
        mean,
        [0.5 * spacing, 0.5 * spacing, 0.5 * spacing, time_scale],
        colour,
    );
    kernel.rotation = random_rotation(rng);
    kernel
}

/// The alpha scene of a start's `kernels`: each at `options.start_opacity`, SH zero.
pub(super) fn alpha_start(
    kernels: &[Kernel],
    background: [f64; 3],
    options: &AlphaFitOptions,
    origin: &str,
) -> Result<Scene> {
    let n = kernels.len();
    Scene::from_kernels(kernels, background, origin)?.into_alpha(
        vec![options.start_opacity; n],
        options.sh_count,
        vec![[0.0; 3]; n * options.sh_count],
        origin,
    )
}

/// A random start in the cameras' box: `options.start_kernels` kernels, seeded.
pub fn random_alpha_scene(
    bounds: &SpaceTimeBox,
    background: [f64; 3],
    colour: [f64; 3],
    options: &AlphaFitOptions,
) -> Result<Scene> {
    bounds.check()?;
    let mut rng = seeded_rng(options.seed);
    let n = options.start_kernels.max(1);
    let extent: [f64; 3] = std::array::from_fn(|a| bounds.max[a] - bounds.min[a]);
    // Spread so that neighbours overlap: the side of a cell of the box shared among n.
    let spacing = cell_side(extent, n as f64);
    let time_range = (bounds.time[1] - bounds.time[0]).max(1e-9);
    let kernels: Vec<Kernel> = (0..n)
        .map(|_| {
            let mean = [
                rng.random_range(bounds.min[0]..=bounds.max[0]),
                rng.random_range(bounds.min[1]..=bounds.max[1]),
                rng.random_range(bounds.min[2]..=bounds.max[2]),
                rng.random_range(bounds.time[0]..=bounds.time[1]),
            ];
            let time_scale = options.start_time_scale * time_range;
            start_kernel(&mut rng, mean, spacing, time_scale, colour)
        })
        .collect();
    alpha_start(&kernels, background, options, "<random alpha start>")
}

/// A start from a dataset's point cloud (SPEC §8 kernels at the points, coloured by them):
/// at most `options.max_start_points` (and `max_kernels`) points, taken evenly through the
/// list; each kernel's spatial
/// σ is half the mean distance to its three nearest chosen points (3DGS's start, which
/// follows the cloud's density: sparse background, dense surfaces), σt `start_time_scale`
/// of the time range, centred in time; then, with [`AlphaFitOptions::far_shell`], the far
/// shell for the pixels of `views` they leave unexplained ([`with_far_shell`]). Returns the
/// scene and the shell's kernel count.
pub fn point_cloud_alpha_scene(
    points: &[DatasetPoint],
    views: &[View],
    bounds: &SpaceTimeBox,
    background: [f64; 3],
    options: &AlphaFitOptions,
) -> Result<(Scene, usize)> {
    let kernels = point_cloud_kernels(points, bounds, options);
    let (kernels, shell) = with_far_shell(kernels, views, bounds, background, options);
    let scene = alpha_start(&kernels, background, options, "<point cloud start>")?;
    Ok((scene, shell))
}

/// The kernels of [`point_cloud_alpha_scene`].
fn point_cloud_kernels(
    points: &[DatasetPoint],
    bounds: &SpaceTimeBox,
    options: &AlphaFitOptions,
) -> Vec<Kernel> {
    let most = options.max_start_points.min(options.max_kernels).max(1);
    let stride = points.len().div_ceil(most).max(1);
    let chosen: Vec<&DatasetPoint> = points.iter().step_by(stride).collect();
    let positions: Vec<[f64; 3]> = chosen.iter().map(|p| p.position).collect();
    let spacings = neighbour_spacings(&positions);
    let (centre_time, time_scale) = throughout(bounds, options);
    let mut rng = seeded_rng(options.seed);
    chosen
        .iter()
        .zip(&spacings)
        .map(|(p, &spacing)| {
            let [x, y, z] = p.position;
            let colour = p.colour.map(f64::from);
            start_kernel(
                &mut rng,
                [x, y, z, centre_time],
                spacing,
                time_scale,
                colour,
            )
        })
        .collect()
}

/// The time mean and σt of a start kernel that lives throughout the data (a point cloud's, the
/// far shell's): the middle of the time range, σt `start_time_scale` of it but at least all of
/// it.
fn throughout(bounds: &SpaceTimeBox, options: &AlphaFitOptions) -> (f64, f64) {
    let time_range = (bounds.time[1] - bounds.time[0]).max(1e-9);
    let centre_time = 0.5 * (bounds.time[0] + bounds.time[1]);
    (centre_time, options.start_time_scale.max(1.0) * time_range)
}

/// How a start from a point cloud or a plane sweep was completed: the swept kernels it
/// holds beside the cloud's, and the far shell's ([`crate::fit::shell`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Completion {
    /// Kernels from plane-sweep points on pixels the cloud leaves unexplained.
    pub swept: usize,
    /// Kernels on the far shell for pixels the start leaves unexplained.
    pub shell: usize,
}

/// A start from a point cloud that covers only part of what the views show, completed from
/// a plane sweep: the point cloud's kernels ([`point_cloud_alpha_scene`]), then a kernel
/// (as [`swept_alpha_scene`] makes them) for every swept point whose reference pixel no
/// cloud kernel covers in that view ([`uncovered`]), up to `options.max_kernels` in all,
/// when there are at least `min_swept` of them (else `None`: the cloud explains the views);
/// then, with [`AlphaFitOptions::far_shell`], the far shell ([`with_far_shell`]).
pub fn completed_alpha_scene(
    cloud: &[DatasetPoint],
    swept: &[SweptPoint],
    views: &[View],
    bounds: &SpaceTimeBox,
    background: [f64; 3],
    (options, min_swept): (&AlphaFitOptions, usize),
) -> Result<Option<(Scene, Completion)>> {
    let mut kernels = point_cloud_kernels(cloud, bounds, options);
    let extra = uncovered(swept, &kernels, views);
    let room = options.max_kernels.saturating_sub(kernels.len());
    let filled = swept_kernels(&extra, bounds, options, room);
    let swept = filled.len();
    if swept < min_swept {
        return Ok(None);
    }
    kernels.extend(filled);
    let (kernels, shell) = with_far_shell(kernels, views, bounds, background, options);
    let scene = alpha_start(
        &kernels,
        background,
        options,
        "<point cloud and plane-sweep start>",
    )?;
    Ok(Some((scene, Completion { swept, shell })))
}

/// `kernels` and, with [`AlphaFitOptions::far_shell`], a kernel on the far shell for the
/// pixels of `views` they leave unexplained ([`far_shell_points`]: at most
/// `options.start_kernels` of them, and `options.max_kernels` kernels in all), each with its
/// point's colour and a spatial σ of half its spacing, centred in time with σt at least the
/// time range (a background lives throughout); and how many the shell added.
pub fn with_far_shell(
    mut kernels: Vec<Kernel>,
    views: &[View],
    bounds: &SpaceTimeBox,
    background: [f64; 3],
    options: &AlphaFitOptions,
) -> (Vec<Kernel>, usize) {
    if !options.far_shell {
        return (kernels, 0);
    }
    let room = options.max_kernels.saturating_sub(kernels.len());
    let points: Vec<ShellPoint> = far_shell_points(
        &kernels,
        views,
        bounds,
        background,
        options.start_kernels.min(room),
    );
    let (centre_time, time_scale) = throughout(bounds, options);
    let mut rng = seeded_rng(options.seed ^ SHELL_SEED);
    kernels.extend(points.iter().map(|p| {
        let [x, y, z] = p.position;
        start_kernel(
            &mut rng,
            [x, y, z, centre_time],
            p.spacing,
            time_scale,
            p.colour,
        )
    }));
    (kernels, points.len())
}

/// Mixed into the seed of the shell kernels' rotations, so that they do not repeat the
/// start's.
const SHELL_SEED: u64 = 0x5E11;

/// The swept points whose reference pixel lies outside every disc that `kernels` (static
/// starts, isotropic) project to in that view: a disc of radius
/// `max(1, COVER_SIGMAS · σ f / z)` pixels around the kernel's projection, the cloud's
/// footprint. Each view's coverage is a mask over its pixels; the order is kept.
#[must_use]
pub fn uncovered(swept: &[SweptPoint], kernels: &[Kernel], views: &[View]) -> Vec<SweptPoint> {
    let masks: Vec<Vec<bool>> = views
        .iter()
        .map(|view| coverage(&view.camera, kernels))
        .collect();
    swept
        .iter()
        .filter(|p| {
            let Some(view) = views.get(p.view) else {
                return false;
            };
            let [i, j] = p.pixel;
            let width = view.camera.width as usize;
            let at = j as usize * width + i as usize;
            masks[p.view].get(at).is_some_and(|covered| !covered)
        })
        .copied()
        .collect()
}

/// Per point, the mean distance to its [`SPACING_NEIGHBOURS`] nearest other points (fewer
/// when there are fewer; the cloud's mean spacing for a point with none, or for coincident
/// ones), found on a grid of cells about as wide as the cloud's mean spacing, searched
/// [`MAX_RINGS`] cells out (a point with fewer neighbours there counts the rest that far).
fn neighbour_spacings(points: &[[f64; 3]]) -> Vec<f64> {
    let n = points.len();
    let (lo, hi) = points.iter().fold(
        ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]),
        |(lo, hi), p| {
            (
                std::array::from_fn(|a| lo[a].min(p[a])),
                std::array::from_fn(|a| hi[a].max(p[a])),
            )
        },
    );
    let extent: [f64; 3] = std::array::from_fn(|a| (hi[a] - lo[a]).max(0.0));
    let diagonal = extent.iter().map(|e| e * e).sum::<f64>().sqrt();
    // The spacing n points would have spread through the cloud's box (thin axes ignored).
    let fallback = {
        let volume: f64 = extent.iter().map(|&e| e.max(1e-3 * diagonal)).product();
        let s = (volume / n.max(1) as f64).cbrt();
        if s.is_finite() && s > 0.0 { s } else { 1.0 }
    };
    if n < 2 {
        return vec![fallback; n];
    }
    let cell = fallback;
    // At most 2¹⁰ cells a side (the quotient is capped before the conversion: a cloud
    // spanning 1e38 with a spacing of 1 would overflow the count).
    let cells: [usize; 3] =
        std::array::from_fn(|a| (extent[a] / cell).min(f64::from((1 << 10) - 1)) as usize + 1);
    let index = |p: &[f64; 3]| -> [usize; 3] {
        std::array::from_fn(|a| (((p[a] - lo[a]) / cell) as usize).min(cells[a] - 1))
    };
    let mut grid: std::collections::HashMap<[usize; 3], Vec<usize>> =
        std::collections::HashMap::new();
    for (i, p) in points.iter().enumerate() {
        grid.entry(index(p)).or_default().push(i);
    }
    let rings = cells.iter().copied().max().unwrap_or(1).min(MAX_RINGS);
    points
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let home = index(p);
            let mut nearest: Vec<f64> = Vec::with_capacity(4 * SPACING_NEIGHBOURS);
            for ring in 0..=rings {
                for at in cells_at_ring(home, ring) {
                    let Some(members) = grid.get(&at) else {
                        continue;
                    };
                    nearest.extend(members.iter().filter(|&&j| j != i).map(|&j| {
                        (0..3)
                            .map(|a| (points[j][a] - p[a]).powi(2))
                            .sum::<f64>()
                            .sqrt()
                    }));
                }
                nearest.sort_by(f64::total_cmp);
                nearest.truncate(SPACING_NEIGHBOURS);
                // Every point within `ring · cell` has been seen: done once the k-th is that near.
                if nearest.len() == SPACING_NEIGHBOURS
                    && nearest[SPACING_NEIGHBOURS - 1] <= ring as f64 * cell
                {
                    break;
                }
            }
            // An isolated point (fewer neighbours within the rings searched) is at least
            // that far from the rest.
            nearest.resize(SPACING_NEIGHBOURS, (rings as f64 * cell).max(fallback));
            let mean = nearest.iter().sum::<f64>() / SPACING_NEIGHBOURS as f64;
            if mean.is_finite() && mean > 0.0 {
                mean
            } else {
                fallback
            }
        })
        .collect()
}

/// The grid cells at Chebyshev distance `ring` from `home` (those with a negative index
/// left out; indices past the grid simply hold no points).
fn cells_at_ring(home: [usize; 3], ring: usize) -> impl Iterator<Item = [usize; 3]> {
    let r = ring as i64;
    let offsets = move || -r..=r;
    offsets()
        .flat_map(move |dx| offsets().flat_map(move |dy| offsets().map(move |dz| [dx, dy, dz])))
        .filter(move |d| d.iter().map(|v| v.abs()).max() == Some(r))
        .filter_map(move |d| {
            let cell: Vec<usize> = (0..3)
                .map(|a| usize::try_from(home[a] as i64 + d[a]).ok())
                .collect::<Option<_>>()?;
            Some([cell[0], cell[1], cell[2]])
        })
}

/// Neighbours whose mean distance sets a point-cloud kernel's size.
const SPACING_NEIGHBOURS: usize = 3;
/// Rings of grid cells searched around a point for its neighbours (the search's bound).
const MAX_RINGS: usize = 4;

/// A start from plane-sweep points ([`crate::fit::stereo`]): at most `options.max_kernels`
/// of them, taken evenly through the list, each a kernel at its point and time with a
/// spatial σ of half its spacing, coloured by it, σt `start_time_scale` of the time range;
/// then, with [`AlphaFitOptions::far_shell`], the far shell for the pixels of `views` they
/// leave unexplained ([`with_far_shell`]). Returns the scene and the shell's kernel count.
pub fn swept_alpha_scene(
    points: &[SweptPoint],
    views: &[View],
    bounds: &SpaceTimeBox,
    background: [f64; 3],
    options: &AlphaFitOptions,
) -> Result<(Scene, usize)> {
    if points.is_empty() {
        return Err(Error::usage("the plane sweep kept no point to start from"));
    }
    let kernels = swept_kernels(points, bounds, options, options.max_kernels);
    let (kernels, shell) = with_far_shell(kernels, views, bounds, background, options);
    let scene = alpha_start(&kernels, background, options, "<plane-sweep start>")?;
    Ok((scene, shell))
}

/// The kernels of [`swept_alpha_scene`], at most `most` of them (none when `most` is 0).
fn swept_kernels(
    points: &[SweptPoint],
    bounds: &SpaceTimeBox,
    options: &AlphaFitOptions,
    most: usize,
) -> Vec<Kernel> {
    if most == 0 {
        return Vec::new();
    }
    let stride = points.len().div_ceil(most).max(1);
    let time_range = (bounds.time[1] - bounds.time[0]).max(1e-9);
    let time_scale = options.start_time_scale * time_range;
    let mut rng = seeded_rng(options.seed);
    points
        .iter()
        .step_by(stride)
        .map(|p| {
            let [x, y, z] = p.position;
            let colour = p.colour.map(f64::from);
            start_kernel(&mut rng, [x, y, z, p.time], p.spacing, time_scale, colour)
        })
        .collect()
}

/// A start from the cells a visual hull kept ([`crate::fit::hull`]), coloured by them:
/// `options.start_kernels` kernels, as the random start has, taken evenly through the kept
/// cells (again when fewer were kept), each placed at random in its cell (seeded), with a
/// spatial σ of half the spacing the kernels have through the kept volume, a random time
/// mean and σt `start_time_scale` of the time range: the hull says where, not when.
pub fn hull_alpha_scene(
    cells: &[DatasetPoint],
    side: [f64; 3],
    bounds: &SpaceTimeBox,
    background: [f64; 3],
    options: &AlphaFitOptions,
) -> Result<Scene> {
    if cells.is_empty() {
        return Err(Error::usage("the visual hull kept no cell to start from"));
    }
    bounds.check()?;
    let n = options.start_kernels.max(1);
    let volume = cells.len() as f64 * side[0] * side[1] * side[2];
    let spacing = finite_or((volume / n as f64).cbrt(), || {
        cell_side(side, n as f64 / cells.len() as f64)
    });
    let time_range = (bounds.time[1] - bounds.time[0]).max(1e-9);
    let mut rng = seeded_rng(options.seed);
    let kernels: Vec<Kernel> = (0..n)
        .map(|k| {
            let cell = &cells[k * cells.len() / n];
            let jitter: [f64; 3] = std::array::from_fn(|a| (rng.random::<f64>() - 0.5) * side[a]);
            let [x, y, z] = std::array::from_fn(|a| cell.position[a] + jitter[a]);
            let t = rng.random_range(bounds.time[0]..=bounds.time[1]);
            let time_scale = options.start_time_scale * time_range;
            let colour = cell.colour.map(f64::from);
            start_kernel(&mut rng, [x, y, z, t], spacing, time_scale, colour)
        })
        .collect();
    alpha_start(&kernels, background, options, "<visual hull start>")
}

/// The side of a cube holding `1/share` of a box of sides `sides`: `(Π sides / share)^⅓`,
/// taken side by side when the product overflows or underflows (a box 1e150 or 1e-150
/// wide).
fn cell_side(sides: [f64; 3], share: f64) -> f64 {
    finite_or((sides[0] * sides[1] * sides[2] / share).cbrt(), || {
        sides.iter().map(|s| s.cbrt()).product::<f64>() / share.cbrt()
    })
}

/// `value`, or `otherwise()` when it is not finite and positive.
fn finite_or(value: f64, otherwise: impl FnOnce() -> f64) -> f64 {
    if value.is_finite() && value > 0.0 {
        value
    } else {
        otherwise()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Camera;

    #[test]
    fn a_swept_point_is_kept_only_outside_the_clouds_footprint_in_its_view() {
        // A 40×40 view of the origin from 4 away (f ≈ 48.3 px); one cloud kernel there with
        // σ 0.1: a footprint of 3σ f / z ≈ 3.6 px around the centre pixel (20, 20).
        let camera =
            Camera::look_at([0.0, 0.0, 4.0], [0.0; 3], [0.0, 1.0, 0.0], 45.0, 40, 40).unwrap();
        let view = View {
            camera,
            time: 0.0,
            image: crate::model::Image::filled(40, 40, [0.5; 3]).into(),
            name: "v".into(),
            weights: None,
        };
        let cloud = [Kernel::new([0.0; 4], [0.1, 0.1, 0.1, 1.0], [1.0; 3])];
        let at = |pixel: [u32; 2], view: usize| SweptPoint {
            position: [0.0; 3],
            colour: [0.5; 3],
            time: 0.0,
            spacing: 0.1,
            view,
            pixel,
        };
        let swept = [
            at([20, 20], 0),
            at([22, 21], 0),
            at([25, 20], 0),
            at([0, 39], 0),
        ];
        let kept = uncovered(&swept, &cloud, std::slice::from_ref(&view));
        assert_eq!(kept, vec![swept[2], swept[3]]);
        // A kernel behind the camera covers nothing; a point of a view not given is dropped.
        let behind = [Kernel::new(
            [0.0, 0.0, 9.0, 0.0],
            [0.1, 0.1, 0.1, 1.0],
            [1.0; 3],
        )];
        assert_eq!(
            uncovered(&swept, &behind, std::slice::from_ref(&view)).len(),
            4
        );
        assert!(uncovered(&[at([0, 0], 1)], &cloud, &[view]).is_empty());
    }

    #[test]
    fn point_cloud_spacing_is_the_mean_distance_to_the_three_nearest() {
        // A dense 10×10 grid of spacing 0.01 on a plane and one far point.
        let mut points: Vec<[f64; 3]> = (0..100)
            .map(|k| [0.01 * (k % 10) as f64, 0.01 * (k / 10) as f64, 0.0])
            .collect();
        points.push([5.0, 5.0, 5.0]);
        let spacings = neighbour_spacings(&points);
        // An inner grid point: three neighbours at 0.01.
        assert!((spacings[55] - 0.01).abs() < 1e-12, "{}", spacings[55]);
        // A corner: 0.01, 0.01, 0.01·√2.
        let corner = (0.02 + 0.01 * 2f64.sqrt()) / 3.0;
        assert!((spacings[0] - corner).abs() < 1e-12, "{}", spacings[0]);
        // The far point is far from everything, and counted so.
        assert!(spacings[100] > 0.1, "{}", spacings[100]);
        assert!(spacings.iter().all(|s| s.is_finite() && *s > 0.0));
        // Brute force agrees for every grid point.
        for (i, p) in points.iter().enumerate().take(100) {
            let mut d: Vec<f64> = points
                .iter()
                .enumerate()
                .filter(|&(j, _)| j != i)
                .map(|(_, q)| (0..3).map(|a| (p[a] - q[a]).powi(2)).sum::<f64>().sqrt())
                .collect();
            d.sort_by(f64::total_cmp);
            let mean = d[..3].iter().sum::<f64>() / 3.0;
            assert!(
                (spacings[i] - mean).abs() < 1e-12,
                "{i}: {} {mean}",
                spacings[i]
            );
        }
        assert_eq!(neighbour_spacings(&[[1.0; 3]]).len(), 1);
        assert!(neighbour_spacings(&[]).is_empty());
    }
}
