//! Fitting alpha scenes (SPEC §8): every field, each in the space it is best optimised in,
//! with 3DGS-style density control.
//!
//! **Parameters.** Per kernel, in optimisation space: the spatial mean, the time mean and the
//! velocity as they are; the scales as `ln s` (gradient `s ∂L/∂s`); the quaternion as
//! stored (renormalised after each step); the opacity as `logit o` (gradient
//! `o (1 - o) ∂L/∂o`); the amplitude (the colour's base) and the SH as they are. Adam (SPEC
//! §6) with one learning rate per group; the spatial rates are relative to the cameras' box
//! and decay exponentially to [`AlphaFitOptions::final_rate_factor`] of their start, the
//! others stay constant (as the 3DGS and 4DGS papers schedule them).
//!
//! **A step** draws `batch_size` training views (a seeded shuffle, epoch by epoch) and renders
//! them side by side, one per worker thread, as the additive fit does
//! (`fit::train::batch_gradients`: the same bits whatever the thread count). A view in
//! which no kernel reaches the screen adds a zero gradient; when no view drawn in the steps
//! that draw every view once (or in the whole run) sees a kernel, nothing can ever move into
//! sight, and the fit is refused with a message saying so.
//!
//! **SH degree** rises during the run: degree `d` of the scene's SH is fitted from step
//! `d · sh_raise_every` (its coefficients start at zero and stay there until then).
//!
//! **Density control** (deterministic, bounded by `max_kernels`): every `densify_every`
//! steps between `densify_from` and `densify_until` of the run, the kernels whose mean
//! screen-space positional gradient `|∂L/∂m2|` over the views that saw them is among the
//! largest `densify_fraction` (and above `densify_threshold`) are cloned when small (largest
//! spatial σ below `percent_dense` of the box) or split in two along their largest axis when
//! large (σ / 1.6 each, the children one σ apart); kernels whose opacity fell below
//! `prune_opacity` are removed. A densified kernel that spans motion (σt above
//! `time_split_fraction` of the time range, and |v| σt above its largest spatial σ) is split
//! in time instead: two children at `t ± σt/2`, σt / 1.6 each, their means moved along the
//! velocity so that both follow the parent's path. Every `opacity_reset_every` steps while
//! the rounds run, every opacity is lowered to at most `reset_opacity` (and its Adam moments
//! cleared): what the views need regains its opacity, the rest is pruned.

use std::time::Instant;

use rand::RngExt;

use crate::backward::Gradients;
use crate::fit::init::{SpaceTimeBox, box_from_cameras};
use crate::fit::stereo::SweptPoint;
use crate::fit::train::{
    StepRecord, ViewDraws, batch_gradients, check_fit_inputs, heldout_psnr_at, view_slots,
};
use crate::model::error::{Error, MAX_QUOTE, Result, cut};
use crate::model::random::{random_rotation, seeded_rng};
use crate::model::scene::{Kernel, Scene};
use crate::model::{Camera, DatasetPoint, View};
use crate::render::RenderOptions;

/// Learning rates of the alpha fit, per group.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AlphaRates {
    /// Spatial mean, as a fraction of the box's diagonal per step.
    pub mean: f64,
    /// Time mean, as a fraction of the time range per step.
    pub time: f64,
    /// Velocity, box diagonals per time range per step.
    pub velocity: f64,
    /// `ln s`.
    pub scale: f64,
    /// Quaternion components.
    pub rotation: f64,
    /// `logit o`.
    pub opacity: f64,
    /// Amplitude (the colour's base).
    pub colour: f64,
    /// SH coefficients.
    pub sh: f64,
}

/// How to fit an alpha scene. Defaults in [`crate::fit::plan`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AlphaFitOptions {
    /// Adam steps.
    pub steps: usize,
    /// Views per step.
    pub batch_size: usize,
    /// Initial learning rates.
    pub rates: AlphaRates,
    /// The spatial rates at the last step as a fraction of the first.
    pub final_rate_factor: f64,
    /// Held-out evaluation period, steps (0: only at the end).
    pub eval_every: usize,
    /// Seed of the start and the batch order.
    pub seed: u64,
    /// Rendering options.
    pub render: RenderOptions,
    /// Kernels of a random, hull or plane-sweep start.
    pub start_kernels: usize,
    /// Most points of a dataset's point cloud a start takes (evenly through the list): the
    /// bound on a fit's first steps' cost when a capture ships a dense cloud.
    pub max_start_points: usize,
    /// Opacity of a random start's kernels.
    pub start_opacity: f64,
    /// σt of a random start's kernels, as a fraction of the time range.
    pub start_time_scale: f64,
    /// SH triplets of the fitted scene (0, 3, 8 or 15).
    pub sh_count: usize,
    /// Steps between SH degree raises.
    pub sh_raise_every: usize,
    /// Upper bound on the kernel count.
    pub max_kernels: usize,
    /// Steps between density rounds.
    pub densify_every: usize,
    /// Density rounds from this fraction of the run …
    pub densify_from: f64,
    /// … until this one.
    pub densify_until: f64,
    /// Fraction of the visible kernels densified per round, at most.
    pub densify_fraction: f64,
    /// Smallest mean `|∂L/∂m2|` (per pixel) that densifies.
    pub densify_threshold: f64,
    /// A kernel is split rather than cloned when its largest σ exceeds this fraction of the
    /// box's diagonal.
    pub percent_dense: f64,
    /// Kernels below this opacity are pruned.
    pub prune_opacity: f64,
    /// Steps between opacity resets while density rounds run (0: never): every opacity is
    /// lowered to at most `reset_opacity`, so that kernels the views do not need fade
    /// below `prune_opacity` and are pruned (3DGS's reset).
    pub opacity_reset_every: usize,
    /// The opacity a reset lowers every kernel to, at most.
    pub reset_opacity: f64,
    /// A densified kernel whose σt exceeds this fraction of the time range, and which moves
    /// further than its largest spatial σ within one σt, is split in time rather than in
    /// space (the 4DGS papers' split in the time dimension).
    pub time_split_fraction: f64,
}

/// Per-kernel numbers in Adam's layout: mean 3, t, velocity 3, ln s 4, quaternion 4,
/// logit o, amplitude 3, then the SH.
fn stride(sh_count: usize) -> usize {
    19 + 3 * sh_count
}

/// Adam's moments over every kernel's numbers, in [`stride`] layout.
struct Moments {
    first: Vec<f64>,
    second: Vec<f64>,
    steps: i32,
}

/// One kernel of a start: at `mean` (x, y, z, t), spatial σ `0.5 spacing`, temporal σ
/// `time_scale`, `colour`, a random rotation from `rng`.
fn start_kernel(
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
fn alpha_start(
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
/// of the time range, centred in time.
pub fn point_cloud_alpha_scene(
    points: &[DatasetPoint],
    bounds: &SpaceTimeBox,
    background: [f64; 3],
    options: &AlphaFitOptions,
) -> Result<Scene> {
    let most = options.max_start_points.min(options.max_kernels).max(1);
    let stride = points.len().div_ceil(most).max(1);
    let chosen: Vec<&DatasetPoint> = points.iter().step_by(stride).collect();
    let positions: Vec<[f64; 3]> = chosen.iter().map(|p| p.position).collect();
    let spacings = neighbour_spacings(&positions);
    let time_range = (bounds.time[1] - bounds.time[0]).max(1e-9);
    let centre_time = 0.5 * (bounds.time[0] + bounds.time[1]);
    let mut rng = seeded_rng(options.seed);
    let time_scale = options.start_time_scale.max(1.0) * time_range;
    let kernels: Vec<Kernel> = chosen
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
        .collect();
    alpha_start(&kernels, background, options, "<point cloud start>")
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
/// spatial σ of half its spacing, coloured by it, σt `start_time_scale` of the time range.
pub fn swept_alpha_scene(
    points: &[SweptPoint],
    bounds: &SpaceTimeBox,
    background: [f64; 3],
    options: &AlphaFitOptions,
) -> Result<Scene> {
    if points.is_empty() {
        return Err(Error::usage("the plane sweep kept no point to start from"));
    }
    let stride = points.len().div_ceil(options.max_kernels.max(1)).max(1);
    let time_range = (bounds.time[1] - bounds.time[0]).max(1e-9);
    let time_scale = options.start_time_scale * time_range;
    let mut rng = seeded_rng(options.seed);
    let kernels: Vec<Kernel> = points
        .iter()
        .step_by(stride)
        .map(|p| {
            let [x, y, z] = p.position;
            let colour = p.colour.map(f64::from);
            start_kernel(&mut rng, [x, y, z, p.time], p.spacing, time_scale, colour)
        })
        .collect();
    alpha_start(&kernels, background, options, "<plane-sweep start>")
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

/// The length scales the rates are relative to: the box's diagonal and the time range.
fn extents(bounds: &SpaceTimeBox) -> (f64, f64) {
    let diagonal = (0..3)
        .map(|a| (bounds.max[a] - bounds.min[a]).powi(2))
        .sum::<f64>()
        .sqrt();
    (diagonal, (bounds.time[1] - bounds.time[0]).max(1e-9))
}

/// Fits the alpha scene `scene` in place to `train`, evaluating on `heldout`; `bounds` is
/// the space-time box the rates and density rules are relative to. Calls `on_step` after
/// each step (its record and the scene) and returns every step's record.
pub fn fit_alpha(
    scene: &mut Scene,
    bounds: &SpaceTimeBox,
    train: &[View],
    heldout: &[View],
    options: &AlphaFitOptions,
    mut on_step: impl FnMut(&StepRecord, &Scene),
) -> Result<Vec<StepRecord>> {
    check_fit_inputs(train, heldout, &options.render)?;
    scene.validate("<alpha fit start>")?;
    let start = Instant::now();
    let (diagonal, time_range) = extents(bounds);
    // The batch's views run side by side, one per worker thread (`batch_gradients`).
    let batch = options.batch_size.clamp(1, train.len());
    let mut slots = view_slots(scene, batch);
    let mut grads = Gradients::for_scene(scene);
    let width = stride(scene.sh_count);
    let mut moments = Moments {
        first: vec![0.0; width * scene.len()],
        second: vec![0.0; width * scene.len()],
        steps: 0,
    };

    let mut screen_gradient = vec![0.0_f64; scene.len()];
    let mut seen = vec![0_u32; scene.len()];
    let mut draws = ViewDraws::new(train.len(), options.seed ^ 0x5eed);
    // Grows with the steps actually run: a flag never decides an allocation up front.
    let mut records = Vec::with_capacity(options.steps.min(1 << 12));
    let mut drawn = Vec::with_capacity(batch);
    // Whether some training view has seen a kernel yet (a view that sees none is a step with
    // zero gradient; views that never see one leave nothing to fit).
    let mut seen_any = false;
    // Steps until every training view has been drawn once (the draws go epoch by epoch).
    let first_epoch = train.len().div_ceil(batch);
    for step in 1..=options.steps {
        grads.reset_for_scene(scene);
        let weight = 1.0 / batch as f64;
        draws.next_batch(batch, &mut drawn);
        let train_loss = batch_gradients(
            &mut slots,
            scene,
            train,
            &drawn,
            &options.render,
            &mut grads,
            |slot| {
                let screen = &slot.context.backward.screen;
                for (p, &k) in slot.context.projected.kernel_from_proj.iter().enumerate() {
                    let [gx, gy] = screen.v_means[p];
                    screen_gradient[k as usize] += (gx * gx + gy * gy).sqrt() / weight;
                    seen[k as usize] += 1;
                    seen_any = true;
                }
            },
        )?;
        if !seen_any && (step == first_epoch || step == options.steps) {
            return Err(nothing_in_sight(scene, train, step));
        }
        if !train_loss.is_finite() {
            return Err(Error::Numeric(format!(
                "fitting diverged at step {step} (training loss {train_loss}): lower the learning rates"
            )));
        }
        let progress = (step - 1) as f64 / (options.steps.max(2) - 1) as f64;
        let decay = options.final_rate_factor.powf(progress);
        adam_step(
            scene,
            &grads,
            &mut moments,
            options,
            step,
            [
                diagonal * decay,
                time_range * decay,
                diagonal / time_range * decay,
            ],
        );
        check_parameters(scene, step)?;
        let round = options.densify_every > 0
            && step % options.densify_every == 0
            && progress >= options.densify_from
            && progress <= options.densify_until;
        if reset_due(step, progress, options) {
            reset_opacities(scene, &mut moments, width, options.reset_opacity);
        }
        if round {
            let sources = densify_and_prune(
                scene,
                &screen_gradient,
                &seen,
                [diagonal, time_range],
                options,
            );
            moments.remap(&sources, width);
            screen_gradient = vec![0.0; scene.len()];
            seen = vec![0; scene.len()];
        }
        let heldout_psnr = heldout_psnr_at(
            step,
            (options.steps, options.eval_every),
            scene,
            heldout,
            &options.render,
            &mut slots,
        )?;
        let record = StepRecord {
            step,
            seconds: start.elapsed().as_secs_f64(),
            train_loss,
            heldout_psnr,
            kernels: scene.len(),
        };
        on_step(&record, scene);
        records.push(record);
    }
    Ok(records)
}

/// The error of a fit whose training views saw no kernel in its first `steps` steps (every
/// view once, or the whole run): with zero gradients nothing would ever move into sight.
fn nothing_in_sight(scene: &Scene, train: &[View], steps: usize) -> Error {
    Error::usage(format!(
        "no training view drawn in the first {steps} step(s) ({} training views) sees any of the \
         start's {} kernels, and a fit cannot move what no camera sees: check the cameras' poses \
         and intrinsics (`transform_matrix`, `fl_x`, `fl_y`, `cx`, `cy`; COLMAP cameras and \
         images), the point cloud the fit starts from, or the start scene",
        train.len(),
        scene.len(),
    ))
}

/// One Adam step on every field, in optimisation space. `spatial` are the mean, time and
/// velocity rates' units (box diagonal, time range, diagonal per time range) times the
/// schedule's decay.
fn adam_step(
    scene: &mut Scene,
    grads: &Gradients,
    moments: &mut Moments,
    options: &AlphaFitOptions,
    step: usize,
    spatial: [f64; 3],
) {
    moments.steps += 1;
    let (beta1, beta2, epsilon): (f64, f64, f64) = (0.9, 0.999, 1e-15);
    let correction1 = 1.0 - beta1.powi(moments.steps);
    let correction2 = 1.0 - beta2.powi(moments.steps);
    let rates = &options.rates;
    let count = scene.sh_count;
    let width = stride(count);
    // SH triplets fitted so far: degree d (triplets d² - 1 .. (d + 1)² - 1) from step
    // d · sh_raise_every.
    let degree = step
        .checked_div(options.sh_raise_every)
        .map_or(3, |d| d.min(3));
    let active_sh = ((degree + 1) * (degree + 1) - 1).min(count);
    let lrs: Vec<f64> = (0..width)
        .map(|k| match k {
            0..3 => rates.mean * spatial[0],
            3 => rates.time * spatial[1],
            4..7 => rates.velocity * spatial[2],
            7..11 => rates.scale,
            11..15 => rates.rotation,
            15 => rates.opacity,
            16..19 => rates.colour,
            _ if (k - 19) / 3 < active_sh => rates.sh,
            _ => 0.0,
        })
        .collect();
    // One kernel's gradient in optimisation space and its step, reused kernel after kernel.
    let mut gradient = Vec::with_capacity(width);
    let mut delta = vec![0.0; width];
    for i in 0..scene.len() {
        let scale = scene.scales[i];
        let opacity = scene.opacities[i];
        let o = opacity.clamp(1e-6, 1.0 - 1e-6);
        gradient.clear();
        gradient.extend_from_slice(&grads.v_means[i][..3]);
        gradient.push(grads.v_means[i][3]);
        gradient.extend_from_slice(&grads.v_velocities[i]);
        gradient.extend((0..4).map(|a| scale[a] * grads.v_scales[i][a]));
        gradient.extend_from_slice(&grads.v_rotations[i]);
        gradient.push(o * (1.0 - o) * grads.v_opacities[i]);
        gradient.extend_from_slice(&grads.v_amplitudes[i]);
        gradient.extend(grads.v_sh[i * count..(i + 1) * count].iter().flatten());
        delta.fill(0.0);
        for (k, (&g, &lr)) in gradient.iter().zip(&lrs).enumerate() {
            if lr == 0.0 {
                continue;
            }
            let slot = i * width + k;
            let m = &mut moments.first[slot];
            let v = &mut moments.second[slot];
            *m = beta1 * *m + (1.0 - beta1) * g;
            *v = beta2 * *v + (1.0 - beta2) * g * g;
            delta[k] = lr * (*m / correction1) / ((*v / correction2).sqrt() + epsilon);
        }
        for a in 0..3 {
            scene.means[i][a] -= delta[a];
            scene.velocities[i][a] -= delta[4 + a];
        }
        scene.means[i][3] -= delta[3];
        for a in 0..4 {
            scene.scales[i][a] *= (-delta[7 + a]).exp();
        }
        let mut q = scene.rotations[i];
        for a in 0..4 {
            q[a] -= delta[11 + a];
        }
        let norm = q.iter().map(|v| v * v).sum::<f64>().sqrt();
        if norm > 0.0 && norm.is_finite() {
            scene.rotations[i] = q.map(|v| v / norm);
        }
        let logit = (o / (1.0 - o)).ln() - delta[15];
        scene.opacities[i] = 1.0 / (1.0 + (-logit).exp());
        for c in 0..3 {
            scene.amplitudes[i][c] -= delta[16 + c];
        }
        for (j, triplet) in scene.sh[i * count..(i + 1) * count].iter_mut().enumerate() {
            for c in 0..3 {
                triplet[c] -= delta[19 + 3 * j + c];
            }
        }
    }
}

/// Every parameter finite after a step, else the numeric error naming the group.
fn check_parameters(scene: &Scene, step: usize) -> Result<()> {
    let groups: [(&str, bool); 6] = [
        ("mean", scene.means.iter().flatten().all(|v| v.is_finite())),
        (
            "scale",
            scene
                .scales
                .iter()
                .flatten()
                .all(|v| v.is_finite() && *v > 0.0),
        ),
        (
            "velocity",
            scene.velocities.iter().flatten().all(|v| v.is_finite()),
        ),
        ("opacity", scene.opacities.iter().all(|v| v.is_finite())),
        (
            "amplitude",
            scene.amplitudes.iter().flatten().all(|v| v.is_finite()),
        ),
        ("sh", scene.sh.iter().flatten().all(|v| v.is_finite())),
    ];
    match groups.iter().find(|(_, ok)| !ok) {
        Some((group, _)) => Err(Error::Numeric(format!(
            "fitting diverged at step {step}: the {group} parameters left the finite numbers (lower that group's learning rate)"
        ))),
        None => Ok(()),
    }
}

/// The two children of a split in time: σt / 2 either side of the parent's time mean,
/// σt / 1.6 each, their means moved along the velocity so that both follow its path.
fn split_in_time(kernel: Kernel) -> [Kernel; 2] {
    let time_sigma = kernel.scale[3];
    [-0.5, 0.5].map(|sign| {
        let mut child = kernel;
        child.scale[3] /= 1.6;
        let dt = sign * time_sigma;
        child.mean[3] += dt;
        for a in 0..3 {
            child.mean[a] += kernel.velocity[a] * dt;
        }
        child
    })
}

/// Whether the opacities are reset after `step` (at `progress` of the run): every
/// `opacity_reset_every` steps while the density rounds run, never at the last step.
fn reset_due(step: usize, progress: f64, options: &AlphaFitOptions) -> bool {
    options.opacity_reset_every > 0
        && step.is_multiple_of(options.opacity_reset_every)
        && progress <= options.densify_until
        && step < options.steps
}

/// Lowers every opacity to at most `ceiling` and clears the opacity's Adam moments.
fn reset_opacities(scene: &mut Scene, moments: &mut Moments, width: usize, ceiling: f64) {
    for (i, opacity) in scene.opacities.iter_mut().enumerate() {
        *opacity = opacity.min(ceiling);
        moments.first[i * width + OPACITY_SLOT] = 0.0;
        moments.second[i * width + OPACITY_SLOT] = 0.0;
    }
}

/// Where the logit opacity sits in a kernel's Adam slots.
const OPACITY_SLOT: usize = 15;

/// One density round: prune transparent kernels, then clone or split the ones with the
/// largest mean screen-space gradient. Returns, per kernel of the new scene, the old kernel
/// whose Adam moments it keeps (`None`: fresh).
fn densify_and_prune(
    scene: &mut Scene,
    screen_gradient: &[f64],
    seen: &[u32],
    [diagonal, time_range]: [f64; 2],
    options: &AlphaFitOptions,
) -> Vec<Option<usize>> {
    let n = scene.len();
    let mean_gradient: Vec<f64> = (0..n)
        .map(|i| {
            if seen[i] == 0 {
                0.0
            } else {
                screen_gradient[i] / f64::from(seen[i])
            }
        })
        .collect();
    let keep: Vec<usize> = (0..n)
        .filter(|&i| scene.opacities[i] >= options.prune_opacity)
        .collect();
    // Candidates: the largest mean gradients, ties by index, within the growth budget.
    let mut candidates: Vec<usize> = keep
        .iter()
        .copied()
        .filter(|&i| mean_gradient[i] >= options.densify_threshold)
        .collect();
    candidates.sort_by(|&a, &b| {
        mean_gradient[b]
            .total_cmp(&mean_gradient[a])
            .then(a.cmp(&b))
    });
    let visible = keep.iter().filter(|&&i| seen[i] > 0).count();
    let budget = ((options.densify_fraction * visible as f64) as usize)
        .min(options.max_kernels.saturating_sub(keep.len()));
    candidates.truncate(budget);
    let mut grow = vec![false; n];
    for &i in &candidates {
        grow[i] = true;
    }
    let count = scene.sh_count;
    let mut next = Scene {
        background: scene.background,
        up: scene.up,
        ..Scene::default()
    };
    let (mut opacities, mut sh, mut sources) = (Vec::new(), Vec::new(), Vec::new());
    let mut push = |kernel: Kernel, i: usize, source: Option<usize>, next: &mut Scene| {
        next.means.push(kernel.mean);
        next.scales.push(kernel.scale);
        next.amplitudes.push(kernel.amplitude);
        next.rotations.push(kernel.rotation);
        next.velocities.push(kernel.velocity);
        opacities.push(scene.opacities[i]);
        sh.extend_from_slice(scene.sh_of(i));
        sources.push(source);
    };
    for &i in &keep {
        let kernel = scene.kernel(i);
        if !grow[i] {
            push(kernel, i, Some(i), &mut next);
            continue;
        }
        let largest = (0..3)
            .max_by(|&a, &b| kernel.scale[a].total_cmp(&kernel.scale[b]))
            .expect("three axes");
        let speed = kernel.velocity.iter().map(|v| v * v).sum::<f64>().sqrt();
        let time_sigma = kernel.scale[3];
        if time_sigma > options.time_split_fraction * time_range
            && speed * time_sigma > kernel.scale[largest]
        {
            for child in split_in_time(kernel) {
                push(child, i, None, &mut next);
            }
        } else if kernel.scale[largest] > options.percent_dense * diagonal {
            // Split along the largest axis: the children one σ apart, σ / 1.6 each.
            let r = crate::slice::rotation_matrix(kernel.rotation);
            let sigma = kernel.scale[largest];
            let mut child = kernel;
            for a in 0..3 {
                child.scale[a] /= 1.6;
            }
            for sign in [-0.5, 0.5] {
                let mut placed = child;
                for (mean, row) in placed.mean.iter_mut().zip(&r) {
                    *mean += sign * sigma * row[largest];
                }
                push(placed, i, None, &mut next);
            }
        } else {
            push(kernel, i, Some(i), &mut next);
            push(kernel, i, None, &mut next);
        }
    }
    next.blend = scene.blend;
    next.opacities = opacities;
    next.sh_count = count;
    next.sh = sh;
    *scene = next;
    sources
}

impl Moments {
    /// Kernel `i` of the new scene takes the moments of old kernel `sources[i]`, or zeros.
    fn remap(&mut self, sources: &[Option<usize>], width: usize) {
        let mut first = vec![0.0; width * sources.len()];
        let mut second = vec![0.0; width * sources.len()];
        for (i, source) in sources.iter().enumerate() {
            if let Some(old) = *source {
                first[width * i..width * (i + 1)]
                    .copy_from_slice(&self.first[width * old..width * (old + 1)]);
                second[width * i..width * (i + 1)]
                    .copy_from_slice(&self.second[width * old..width * (old + 1)]);
            }
        }
        self.first = first;
        self.second = second;
    }
}

/// The space-time box of the training cameras and times (the random start's box, and the
/// unit of the spatial rates), or an error naming `origin` (the file the training frames
/// come from), the frame and the field when the frames' numbers give no finite box: times
/// whose span overflows, cameras whose centres or the point they look at leave the finite
/// numbers.
pub fn alpha_bounds(train: &[View], origin: &str) -> Result<SpaceTimeBox> {
    let frame = |i: usize| format!("frame `{}`", cut(&train[i].name, MAX_QUOTE));
    let (Some(first), Some(last)) = (
        (0..train.len()).min_by(|&a, &b| train[a].time.total_cmp(&train[b].time)),
        (0..train.len()).max_by(|&a, &b| train[a].time.total_cmp(&train[b].time)),
    ) else {
        return Err(Error::usage("no training views to fit"));
    };
    let [lo, hi] = [train[first].time, train[last].time];
    if !(lo.is_finite() && hi.is_finite() && (hi - lo).is_finite()) {
        return Err(Error::invalid(
            origin,
            format!("{} and {}", frame(first), frame(last)),
            "time",
            format!(
                "{lo:e} and {hi:e} lie further apart than the finite numbers reach (their difference overflows)"
            ),
        ));
    }
    let cameras: Vec<Camera> = train.iter().map(|v| v.camera).collect();
    let centres: Vec<[f64; 3]> = cameras.iter().map(Camera::centre).collect();
    if let Some(i) = centres
        .iter()
        .position(|c| c.iter().any(|v| !v.is_finite()))
    {
        return Err(Error::invalid(
            origin,
            frame(i),
            "transform_matrix",
            "the camera's position comes out not finite (the matrix is too large, too small or not invertible)",
        ));
    }
    let bounds = box_from_cameras(&cameras, [lo, hi])?;
    let finite = (0..3).all(|c| {
        let (lo, hi) = (bounds.min[c], bounds.max[c]);
        lo.is_finite() && hi.is_finite() && lo < hi && (hi - lo).is_finite()
    });
    if !finite {
        // The camera farthest from the origin is the likeliest culprit.
        let farthest = (0..train.len())
            .max_by(|&a, &b| {
                let norm = |c: &[f64; 3]| c.iter().map(|v| v.abs()).fold(0.0, f64::max);
                norm(&centres[a]).total_cmp(&norm(&centres[b]))
            })
            .unwrap_or(0);
        return Err(Error::invalid(
            origin,
            frame(farthest),
            "transform_matrix",
            format!(
                "the box the training cameras look at comes out as {:.3e}..{:.3e}, {:.3e}..{:.3e}, {:.3e}..{:.3e}, \
                 not a finite box with sides > 0 (this camera sits at {:.3e}, {:.3e}, {:.3e}): check the frames' \
                 positions and focal lengths (`transform_matrix`, `fl_x`, `fl_y`)",
                bounds.min[0],
                bounds.max[0],
                bounds.min[1],
                bounds.max[1],
                bounds.min[2],
                bounds.max[2],
                centres[farthest][0],
                centres[farthest][1],
                centres[farthest][2],
            ),
        ));
    }
    Ok(bounds)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The defaults, with every visible kernel allowed to grow.
    fn grow_all() -> AlphaFitOptions {
        AlphaFitOptions {
            densify_fraction: 1.0,
            ..AlphaFitOptions::default()
        }
    }

    /// One alpha kernel with `velocity` and σt `time_sigma`, opacity 0.8.
    fn one_kernel(velocity: [f64; 3], time_sigma: f64) -> Scene {
        let mut kernel = Kernel::new(
            [0.1, 0.2, 0.3, 0.5],
            [0.01, 0.01, 0.01, time_sigma],
            [0.5; 3],
        );
        kernel.velocity = velocity;
        Scene::from_kernels(&[kernel], [0.0; 3], "<test>")
            .unwrap()
            .into_alpha(vec![0.8], 0, Vec::new(), "<test>")
            .unwrap()
    }

    /// The slice centre of kernel `i` at `tau` (SPEC §2: `m + v (τ - t)`).
    fn centre_at(scene: &Scene, i: usize, tau: f64) -> [f64; 3] {
        std::array::from_fn(|a| {
            scene.means[i][a] + scene.velocities[i][a] * (tau - scene.means[i][3])
        })
    }

    #[test]
    fn a_kernel_that_spans_motion_splits_in_time_along_its_path() {
        let mut scene = one_kernel([1.0, 0.0, -0.5], 0.3);
        let sources = densify_and_prune(&mut scene, &[1.0], &[1], [1.0, 1.0], &grow_all());
        assert_eq!(sources, vec![None, None]);
        assert_eq!(scene.len(), 2);
        let times = [scene.means[0][3], scene.means[1][3]];
        assert!((times[0] - 0.35).abs() < 1e-12 && (times[1] - 0.65).abs() < 1e-12);
        for i in 0..2 {
            assert!((scene.scales[i][3] - 0.3 / 1.6).abs() < 1e-12);
            for tau in [0.0, 0.5, 1.0] {
                let [a, b] = [
                    centre_at(&scene, i, tau),
                    centre_at(&one_kernel([1.0, 0.0, -0.5], 0.3), 0, tau),
                ];
                assert!((0..3).all(|k| (a[k] - b[k]).abs() < 1e-12), "{a:?} {b:?}");
            }
        }
    }

    #[test]
    fn a_still_or_short_lived_kernel_is_cloned_in_space_not_split_in_time() {
        for (velocity, time_sigma) in [([0.0; 3], 0.3), ([1.0, 0.0, 0.0], 0.01)] {
            let mut scene = one_kernel(velocity, time_sigma);
            let sources = densify_and_prune(&mut scene, &[1.0], &[1], [1.0, 1.0], &grow_all());
            assert_eq!(sources, vec![Some(0), None]);
            assert_eq!(scene.means[0], scene.means[1]);
        }
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

    #[test]
    fn a_reset_lowers_opacities_and_clears_their_moments_only() {
        let mut scene = one_kernel([0.0; 3], 0.3);
        let width = stride(0);
        let mut moments = Moments {
            first: vec![1.0; width],
            second: vec![2.0; width],
            steps: 3,
        };
        reset_opacities(&mut scene, &mut moments, width, 0.01);
        assert_eq!(scene.opacities, vec![0.01]);
        for k in 0..width {
            let cleared = k == OPACITY_SLOT;
            assert_eq!(moments.first[k] == 0.0, cleared);
            assert_eq!(moments.second[k] == 0.0, cleared);
        }
    }
}
