//! f64 twin of stage 1, [`crate::slice`] (SPEC §2 and the culling of §5), written as the
//! SPEC states it, with glam matrices:
//!
//! ```text
//! d = (τ - t)/st,   w = exp(-½ d²),   m = (x, y, z) + v (τ - t),   Σ3 = R diag(s²) Rᵀ
//! qmax = 2 (ln max_c |A_c| - ½ d² - ln ε),  culled iff qmax ≤ 0 (ε = 0: qmax = +∞)
//! ```
//!
//! Alpha scenes (SPEC §8): `o(τ) = o w`, `qmax = 2 (ln o - ½ d² - ln ε)`, culled also when
//! `o(τ) = 0`; the amplitude is `A` (not weighted).

use glam::{DMat3, DQuat, DVec3};

use crate::model::{Blend, Scene};

/// One kernel sliced at τ, in f64.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReferenceSlice {
    /// Scene index.
    pub index: usize,
    /// `m(τ)`, world space.
    pub mean: DVec3,
    /// `Σ3`, world space.
    pub covariance: DMat3,
    /// `a(τ) = A w(τ)`; alpha scenes: `A`.
    pub amplitude: [f64; 3],
    /// Alpha scenes: `o(τ) = o w(τ)` (additive: 0).
    pub opacity: f64,
    /// `qmax` (`+∞` without truncation).
    pub qmax: f64,
    /// Temporal weight `w(τ)`.
    pub weight: f64,
    /// `d = (τ - t)/st`.
    pub d: f64,
}

/// Kernel `index` of `scene` sliced at `tau` with cut-off `cutoff`, or `None` when culled.
#[must_use]
pub fn reference_slice(
    scene: &Scene,
    index: usize,
    tau: f64,
    cutoff: f64,
) -> Option<ReferenceSlice> {
    let [x, y, z, t] = scene.means[index];
    let [sx, sy, sz, st] = scene.scales[index];
    let amp = scene.amplitudes[index];
    // §5 culling in log space.
    let d = (tau - t) / st;
    let alpha = scene.blend == Blend::Alpha;
    let peak = if alpha {
        scene.opacities[index]
    } else {
        amp.iter().map(|a| a.abs()).fold(0.0, f64::max)
    };
    let qmax = if peak == 0.0 {
        return None;
    } else if cutoff == 0.0 {
        f64::INFINITY
    } else {
        2.0 * (peak.ln() - 0.5 * d * d - cutoff.ln())
    };
    if qmax <= 0.0 {
        return None;
    }
    // §2 slice.
    let w = (-0.5 * d * d).exp();
    if alpha && peak * w == 0.0 {
        return None;
    }
    let mean = DVec3::new(x, y, z) + DVec3::from(scene.velocities[index]) * (tau - t);
    let [qw, qx, qy, qz] = scene.rotations[index];
    let r = DMat3::from_quat(DQuat::from_xyzw(qx, qy, qz, qw).normalize());
    let covariance =
        r * DMat3::from_diagonal(DVec3::new(sx * sx, sy * sy, sz * sz)) * r.transpose();
    Some(ReferenceSlice {
        index,
        mean,
        covariance,
        amplitude: if alpha { amp } else { amp.map(|a| a * w) },
        opacity: if alpha { peak * w } else { 0.0 },
        qmax,
        weight: w,
        d,
    })
}
