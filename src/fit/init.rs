//! Initial scenes for fitting: N kernels spread uniformly (seeded) over a space-time box,
//! and the box a user would expect from the cameras when none is given.

use glam::{DMat3, DVec3};
use rand::RngExt;

use crate::model::camera::Camera;
use crate::model::error::{Error, Result};
use crate::model::random::seeded_rng;
use crate::model::scene::{Kernel, Scene};

impl SpaceTimeBox {
    /// An error unless every bound and every side of the box is finite and ordered (a box
    /// from `-1e308` to `1e308` has an infinite side).
    pub fn check(&self) -> Result<()> {
        let sides = (0..3)
            .map(|c| (self.min[c], self.max[c]))
            .chain([(self.time[0], self.time[1])]);
        for (lo, hi) in sides {
            if !(lo.is_finite() && hi.is_finite() && lo <= hi && (hi - lo).is_finite()) {
                return Err(Error::usage(format!(
                    "the space-time box side {lo}..{hi} is not finite and ordered (`box`, `time_range`)"
                )));
            }
        }
        Ok(())
    }
}

/// An axis-aligned space-time box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SpaceTimeBox {
    /// Lower corner `(x, y, z)`.
    pub min: [f64; 3],
    /// Upper corner `(x, y, z)`.
    pub max: [f64; 3],
    /// Time range `[t0, t1]`.
    pub time: [f64; 2],
}

/// The point nearest (least squares) to every camera's optical axis, and a cube around it
/// half as wide as the median camera sees at that distance (its vertical field of view):
/// what the cameras are looking at. Needs two cameras with different viewing directions.
pub fn box_from_cameras(cameras: &[Camera], time: [f64; 2]) -> Result<SpaceTimeBox> {
    let mut normal = DMat3::ZERO;
    let mut rhs = DVec3::ZERO;
    let axes: Vec<(DVec3, DVec3)> = cameras
        .iter()
        .map(|c| (DVec3::from(c.centre()), DVec3::from(c.optical_axis())))
        .collect();
    for (centre, dir) in &axes {
        // Projector onto the plane orthogonal to the axis.
        let p = DMat3::IDENTITY - DMat3::from_cols(*dir * dir.x, *dir * dir.y, *dir * dir.z);
        normal += p;
        rhs += p * *centre;
    }
    let det = normal.determinant();
    if !det.is_finite() || det.abs() <= 1e-9 {
        return Err(Error::Usage(
            "cannot infer a box from the cameras (fewer than two distinct viewing directions): give `box`".into(),
        ));
    }
    let target = normal.inverse() * rhs;
    let mut half_widths: Vec<f64> = cameras
        .iter()
        .zip(&axes)
        .map(|(c, (centre, _))| {
            0.5 * (target - *centre).length() * 0.5 * f64::from(c.height) / c.fy
        })
        .collect();
    half_widths.sort_by(f64::total_cmp);
    let half = half_widths[half_widths.len() / 2];
    Ok(SpaceTimeBox {
        min: (target - DVec3::splat(half)).into(),
        max: (target + DVec3::splat(half)).into(),
        time,
    })
}

/// `n` kernels with means uniform in `bounds` (seeded), axis-aligned, static, grey
/// `amplitude`, and scales `scale = [sx, sy, sz, st]`, or by default a quarter of the box's
/// mean side and time range per `n^(1/4)` (kernels spread over four dimensions).
pub fn random_scene(
    n: usize,
    bounds: &SpaceTimeBox,
    scale: Option<[f64; 4]>,
    amplitude: f64,
    seed: u64,
) -> Result<Scene> {
    bounds.check()?;
    let side = (0..3).map(|c| bounds.max[c] - bounds.min[c]).sum::<f64>() / 3.0;
    let span = bounds.time[1] - bounds.time[0];
    let per_axis = (n.max(1) as f64).powf(0.25);
    let scale = scale.unwrap_or_else(|| {
        let s = 0.5 * side / per_axis;
        [s, s, s, (0.5 * span / per_axis).max(1e-3)]
    });
    let mut rng = seeded_rng(seed);
    let mut uniform = |lo: f64, hi: f64| {
        if hi > lo {
            rng.random_range(lo..hi)
        } else {
            lo
        }
    };
    let kernels: Vec<Kernel> = (0..n)
        .map(|_| {
            let mean = [
                uniform(bounds.min[0], bounds.max[0]),
                uniform(bounds.min[1], bounds.max[1]),
                uniform(bounds.min[2], bounds.max[2]),
                uniform(bounds.time[0], bounds.time[1]),
            ];
            Kernel::new(mean, scale, [amplitude; 3])
        })
        .collect();
    Scene::from_kernels(&kernels, [0.0; 3], "<random initial scene>")
}

/// One kernel at the centre of `bounds` (space and time) with `σ` a quarter of the box's
/// mean side, `σt` half its time range (at least 1e-3) and grey `amplitude`: the start of
/// an adaptive fit, which densifies from there (coarse to fine).
pub fn centre_scene(bounds: &SpaceTimeBox, amplitude: f64) -> Result<Scene> {
    let side = (0..3).map(|c| bounds.max[c] - bounds.min[c]).sum::<f64>() / 3.0;
    let span = bounds.time[1] - bounds.time[0];
    let centre = |c: usize| 0.5 * (bounds.min[c] + bounds.max[c]);
    let kernel = Kernel::new(
        [
            centre(0),
            centre(1),
            centre(2),
            0.5 * (bounds.time[0] + bounds.time[1]),
        ],
        [
            0.25 * side,
            0.25 * side,
            0.25 * side,
            (0.5 * span).max(1e-3),
        ],
        [amplitude; 3],
    );
    Scene::from_kernels(&[kernel], [0.0; 3], "<initial scene>")
}
