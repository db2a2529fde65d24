//! Triangles to kernels: `N` points spread (stratified, seeded) over the triangles of a
//! node tree, area-weighted at the first sample time, each becoming one surfel kernel per
//! sample time.
//!
//! Each point becomes one kernel per sample time `t_k` ([`crate::scenes::motion_sampling`]):
//! a surfel with σ = (s, s, 0.3 s), `s = √(area/N)`, its thin axis along the triangle's
//! normal at `t_k`, at the point's (curvature-corrected) position, moving with its analytic
//! velocity, temporal σ `σ_k` and amplitude `colour · g · a_k`, where `g = 1/(2π)` makes
//! surfels at that density sum to the colour face-on and the weights `a_k` make the point's
//! temporal Gaussians sum to one. Without animation (or with one time asked for) each point
//! is one static kernel (σt = 1000, amplitude `colour · g`).

use glam::{DQuat, DVec3};
use rand::RngExt;

use crate::model::error::{Error, Result};
use crate::model::random::seeded_rng;
use crate::model::scene::{Kernel, Scene};
use crate::scenes::animation::{Animation, Pose, Side};
use crate::scenes::motion_sampling::{PosedSample, Spacing, plan_samples};
use crate::scenes::time_samples::{Place, TimeSample};

/// σ of a surfel, as a fraction of the mean spacing √(area/N).
const SURFEL_SPREAD: f64 = 1.0;
/// Thickness of a surfel along its normal, relative to its width.
const SURFEL_THICKNESS: f64 = 0.3;

/// A triangle of a mesh, in its node's local space.
#[derive(Clone, Debug, PartialEq)]
pub struct Triangle {
    /// The node whose world matrix places it.
    pub node: usize,
    /// Its corners.
    pub corners: [DVec3; 3],
    /// Its corners' colours (linear RGB).
    pub colours: [[f64; 3]; 3],
}

/// What [`surfels`] made (and `io::gltf::import_scene` returns).
#[derive(Clone, Debug)]
pub struct Imported {
    /// The 4D scene.
    pub scene: Scene,
    /// The animations' time range (`[0, 0]` when static).
    pub time_range: [f64; 2],
    /// Surface points sampled.
    pub points: usize,
    /// Time samples per point (kernels = points × times).
    pub times: usize,
    /// Largest distance, over the model's size, between where the kernels put any surface
    /// point and where the animation does, at the test times (0 when static).
    pub max_error: f64,
    /// Largest `|Σ temporal weights - 1|` of a point's kernels over the range.
    pub weight_error: f64,
    /// Key times where the pose jumps (STEP keys).
    pub steps: usize,
    /// Per kernel, the temporal weight of its time sample (the partition of unity).
    pub sample_weights: Vec<f64>,
}

/// Peak opacity of an opaque surfel of the alpha blend: with neighbours one σ apart, a
/// point of the surface is covered by several surfels, so the surface closes (T < 1e-3
/// behind it, tested).
pub const SURFEL_OPACITY: f64 = 0.9;

impl Imported {
    /// The import as opaque surfaces (SPEC §8): each kernel's colour is its point's colour
    /// and its opacity [`SURFEL_OPACITY`] times its temporal weight, so that surfaces hide
    /// what is behind them.
    pub fn into_alpha(mut self, origin: &str) -> Result<Imported> {
        let gain = 1.0 / (std::f64::consts::TAU * SURFEL_SPREAD * SURFEL_SPREAD);
        let mut opacities = Vec::with_capacity(self.scene.len());
        for (amplitude, &weight) in self.scene.amplitudes.iter_mut().zip(&self.sample_weights) {
            let scale = gain * weight;
            if scale > 0.0 {
                *amplitude = amplitude.map(|a| a / scale);
            }
            opacities.push((SURFEL_OPACITY * weight).clamp(0.0, 1.0));
        }
        self.scene = self.scene.into_alpha(opacities, 0, Vec::new(), origin)?;
        Ok(self)
    }
}

/// Most kernels an import makes (surface points × time samples): about 1.5 GB of scene.
pub const MAX_IMPORT_KERNELS: usize = 10_000_000;

/// Samples `points` surface points of `triangles`, moved by `animation`, into surfel kernels
/// at the sample times `spacing` asks for (see the module docs). `origin` names the model in
/// errors.
pub fn surfels(
    animation: &Animation,
    triangles: &[Triangle],
    points: usize,
    spacing: Spacing,
    seed: u64,
    origin: &str,
) -> Result<Imported> {
    let range = animation.range().filter(|_| spacing != Spacing::Even(1));
    let first = range.map_or(0.0, |r| r[0]);
    let start = animation.world(first, Side::Right);
    // Area-weighted triangle choice at the first time.
    let areas: Vec<f64> = triangles
        .iter()
        .map(|tri| {
            let m = start[tri.node].0;
            let [a, b, c] = tri.corners.map(|p| m.transform_point3(p));
            0.5 * (b - a).cross(c - a).length()
        })
        .collect();
    let total: f64 = areas.iter().sum();
    if !(total > 0.0 && total.is_finite()) {
        return Err(Error::invalid(
            origin,
            "scene",
            "meshes",
            "no triangle with a finite, positive area in the default scene",
        ));
    }
    let timing = match range {
        Some(range) => {
            animated_samples(animation, triangles, &start, range, points, spacing, origin)?
        }
        None => static_sample(start),
    };
    let (kernels, sample_weights) =
        surfel_kernels(triangles, &areas, total, points, &timing.samples, seed);
    let scene = Scene::from_kernels(&kernels, [0.0; 3], origin)?;
    Ok(Imported {
        scene,
        time_range: timing.range,
        points,
        times: timing.samples.len(),
        max_error: timing.max_error,
        weight_error: timing.weight_error,
        steps: timing.steps,
        sample_weights,
    })
}

/// The samples every point is followed at, with every node's pose at each.
struct Timing {
    samples: Vec<PosedSample>,
    range: [f64; 2],
    max_error: f64,
    weight_error: f64,
    steps: usize,
}

/// Static: one kernel per point, σt = 1000, weight 1.
fn static_sample(start: Vec<Pose>) -> Timing {
    let sample = TimeSample {
        time: 0.0,
        sigma: 1e3,
        weight: 1.0,
        place: Place::Inside { piece: 0 },
    };
    let posed = PosedSample {
        sample,
        poses: start,
    };
    Timing {
        samples: vec![posed],
        range: [0.0, 0.0],
        max_error: 0.0,
        weight_error: 0.0,
        steps: 0,
    }
}

/// The planned samples over `range`, the model's size taken at the first time (`start`).
fn animated_samples(
    animation: &Animation,
    triangles: &[Triangle],
    start: &[Pose],
    range: [f64; 2],
    points: usize,
    spacing: Spacing,
    origin: &str,
) -> Result<Timing> {
    let mut corners = vec![Vec::new(); start.len()];
    for tri in triangles {
        corners[tri.node].extend_from_slice(&tri.corners);
    }
    let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    for tri in triangles {
        for p in tri.corners {
            let w = start[tri.node].0.transform_point3(p);
            (lo, hi) = (lo.min(w), hi.max(w));
        }
    }
    let size = (hi - lo).length().max(f64::MIN_POSITIVE);
    let plan = plan_samples(animation, range, &corners, size, spacing, origin)?;
    if points.saturating_mul(plan.samples.len()) > MAX_IMPORT_KERNELS {
        return Err(Error::setting(
            &["kernels", "tolerance"],
            format!(
                "`kernels` {points} × {} sample times is more than the {MAX_IMPORT_KERNELS} kernels an import may make; lower `kernels` or raise `tolerance`",
                plan.samples.len()
            ),
        ));
    }
    Ok(Timing {
        samples: plan.samples,
        range,
        max_error: plan.max_error,
        weight_error: plan.weight_error,
        steps: plan.steps,
    })
}

/// The kernels of `points` points over `triangles` (of `areas`, summing to `total`), one a
/// sample, and each kernel's temporal weight.
fn surfel_kernels(
    triangles: &[Triangle],
    areas: &[f64],
    total: f64,
    points: usize,
    samples: &[PosedSample],
    seed: u64,
) -> (Vec<Kernel>, Vec<f64>) {
    let cumulative: Vec<f64> = areas
        .iter()
        .scan(0.0, |acc, a| {
            *acc += a;
            Some(*acc)
        })
        .collect();
    let sigma = SURFEL_SPREAD * (total / points as f64).sqrt();
    let gain = 1.0 / (std::f64::consts::TAU * SURFEL_SPREAD * SURFEL_SPREAD);
    let mut rng = seeded_rng(seed);
    let mut kernels = Vec::with_capacity(points.saturating_mul(samples.len()).min(1 << 16));
    let mut sample_weights = Vec::with_capacity(kernels.capacity());
    // Stratified over the cumulative area (point k in the k-th N-th of it, jittered), with
    // barycentric coordinates from the R2 low-discrepancy sequence (seeded offset): far
    // more even coverage than independent draws, whose density fluctuates by ~30% at this
    // surfel size.
    const R2: [f64; 2] = [0.754_877_666_246_692_8, 0.569_840_290_998_053_3];
    let offset: [f64; 2] = [rng.random(), rng.random()];
    for point in 0..points {
        let jitter: f64 = rng.random();
        let r = total * (point as f64 + jitter) / points as f64;
        let index = cumulative
            .partition_point(|&c| c <= r)
            .min(triangles.len() - 1);
        let tri = &triangles[index];
        let (mut u, mut v) = (
            (offset[0] + point as f64 * R2[0]).fract(),
            (offset[1] + point as f64 * R2[1]).fract(),
        );
        if u + v > 1.0 {
            (u, v) = (1.0 - u, 1.0 - v);
        }
        let local = tri.corners[0]
            + u * (tri.corners[1] - tri.corners[0])
            + v * (tri.corners[2] - tri.corners[0]);
        let colour: [f64; 3] = std::array::from_fn(|c| {
            tri.colours[0][c]
                + u * (tri.colours[1][c] - tri.colours[0][c])
                + v * (tri.colours[2][c] - tri.colours[0][c])
        });
        for PosedSample { sample, poses } in samples {
            let (m, rate) = poses[tri.node];
            let [a, b, c] = tri.corners.map(|p| m.transform_point3(p));
            let normal = (b - a).cross(c - a).normalize_or_zero();
            let q = if normal == DVec3::ZERO {
                DQuat::IDENTITY
            } else {
                DQuat::from_rotation_arc(DVec3::Z, normal)
            };
            let p = m.transform_point3(local);
            kernels.push(Kernel {
                mean: [p.x, p.y, p.z, sample.time],
                scale: [sigma, sigma, SURFEL_THICKNESS * sigma, sample.sigma],
                amplitude: colour.map(|c| c * gain * sample.weight),
                rotation: [q.w, q.x, q.y, q.z],
                velocity: rate.transform_point3(local).into(),
                acceleration: [0.0; 3],
                angular_velocity: [0.0; 4],
            });
            sample_weights.push(sample.weight);
        }
    }
    (kernels, sample_weights)
}
