//! f64 twin of stage 1, [`crate::slice`] (SPEC §2 and the culling of §5), written as the
//! SPEC states it, with glam matrices:
//!
//! ```text
//! d = (τ - t)/st,   w = exp(-½ d²),   m = (x, y, z) + v (τ - t),   Σ3 = R diag(s²) Rᵀ
//! §9:  m = (x, y, z) + v d_t + ½ a d_t²,   R from (q + ω d_t)/|q + ω d_t|   (d_t = τ - t;
//!      culled when q + ω d_t is zero or not finite)
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

/// `m(τ) = (x, y, z) + v (τ - t) + ½ a (τ - t)²` of kernel `index` (SPEC §2, §9).
#[must_use]
pub fn reference_mean(scene: &Scene, index: usize, tau: f64) -> DVec3 {
    let [x, y, z, t] = scene.means[index];
    let dt = tau - t;
    DVec3::new(x, y, z)
        + DVec3::from(scene.velocities[index]) * dt
        + DVec3::from(scene.acceleration(index)) * (0.5 * dt * dt)
}

/// Kernel `index` of `scene` sliced at `tau` with cut-off `cutoff`, or `None` when culled.
#[must_use]
pub fn reference_slice(
    scene: &Scene,
    index: usize,
    tau: f64,
    cutoff: f64,
) -> Option<ReferenceSlice> {
    let t = scene.means[index][3];
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
    let mean = reference_mean(scene, index, tau);
    let [qw, qx, qy, qz] = scene.rotations[index];
    let [ww, wx, wy, wz] = scene.angular_velocity(index);
    // SPEC §9: q(τ) = q + ω (τ - t), normalised; culled when that is impossible.
    let stored = DQuat::from_xyzw(qx, qy, qz, qw);
    let unit = if [ww, wx, wy, wz] == [0.0; 4] {
        stored.normalize()
    } else {
        let turned = stored + DQuat::from_xyzw(wx, wy, wz, ww) * (tau - t);
        let length = turned.length();
        if !(length > 0.0 && length.is_finite()) {
            return None;
        }
        turned / length
    };
    let r = DMat3::from_quat(unit);
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
