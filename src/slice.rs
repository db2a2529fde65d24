//! Stage 1: slice every 4D kernel at time τ into a 3D Gaussian (SPEC §2), with temporal and
//! amplitude culling (SPEC §5).
//!
//! For kernel `i` with mean `(x, y, z, t)`, scales `(sx, sy, sz, st)`, unit quaternion `q`
//! and velocity `v`, at time τ:
//!
//! ```text
//! d    = (τ - t) / st                      (never forms 0·∞ for tiny st)
//! w    = exp(-½ d²)                        temporal weight
//! m    = (x, y, z) + v (τ - t)             3D centre, world space
//! Σ3   = R diag(sx², sy², sz²) Rᵀ          R from q (columns: the kernel's axes)
//! a    = A w                               3D amplitude per channel
//! qmax = 2 (ln max_c |A_c| - ½ d² - ln ε)  cut-off radius², in log space (no underflow)
//! ```
//!
//! A kernel with `qmax ≤ 0` (its largest |amplitude| at τ is ≤ ε) is dropped here, before
//! any projection work. With `ε = 0` nothing is truncated: `qmax = +∞`, and only kernels
//! whose amplitude is exactly zero are dropped. Everything is f64.

use crate::scene::Scene;

/// Kernels alive at τ, sliced to 3D. Struct-of-arrays: index `s` of every array is one
/// sliced kernel; `kernel_from_slice[s]` is its index in the scene (ascending).
#[derive(Clone, Debug, Default)]
pub struct SlicedKernels {
    /// Scene index of each sliced kernel, ascending.
    pub kernel_from_slice: Vec<u32>,
    /// 3D centre `m(τ)`, world space.
    pub means: Vec<[f64; 3]>,
    /// 3D covariance `Σ3` as `[xx, xy, xz, yy, yz, zz]`, world space.
    pub covariances: Vec<[f64; 6]>,
    /// Sliced amplitude `a(τ) = A w(τ)` per channel.
    pub amplitudes: Vec<[f64; 3]>,
    /// Cut-off `qmax` on the squared Mahalanobis radius (`+∞` without truncation).
    pub qmax: Vec<f64>,
}

impl SlicedKernels {
    /// Number of sliced kernels.
    #[must_use]
    pub fn len(&self) -> usize {
        self.kernel_from_slice.len()
    }

    /// True when no kernel is alive at τ.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.kernel_from_slice.is_empty()
    }

    /// Empties every buffer, keeping its capacity.
    pub fn reset(&mut self) {
        self.kernel_from_slice.clear();
        self.means.clear();
        self.covariances.clear();
        self.amplitudes.clear();
        self.qmax.clear();
    }
}

/// Rotation matrix (row-major) of a unit Hamilton quaternion `[w, x, y, z]`.
#[must_use]
pub fn rotation_matrix([w, x, y, z]: [f64; 4]) -> [[f64; 3]; 3] {
    [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
        ],
        [
            2.0 * (x * y + w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - w * x),
        ],
        [
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ]
}

/// `Σ3 = R diag(s²) Rᵀ` as `[xx, xy, xz, yy, yz, zz]`.
#[must_use]
pub fn covariance_3d(rotation: [f64; 4], scale: [f64; 4]) -> [f64; 6] {
    let r = rotation_matrix(rotation);
    let var = [
        scale[0] * scale[0],
        scale[1] * scale[1],
        scale[2] * scale[2],
    ];
    let entry = |i: usize, j: usize| (0..3).map(|k| r[i][k] * var[k] * r[j][k]).sum::<f64>();
    [
        entry(0, 0),
        entry(0, 1),
        entry(0, 2),
        entry(1, 1),
        entry(1, 2),
        entry(2, 2),
    ]
}

/// The cut-off `qmax` of SPEC §5 for peak amplitude `amplitude` at normalised time offset
/// `d`, or `None` when the kernel is culled (`qmax ≤ 0`). `cutoff = 0` means no truncation.
#[must_use]
pub fn cutoff_radius_squared(amplitude: [f64; 3], d: f64, cutoff: f64) -> Option<f64> {
    let peak = amplitude.iter().fold(0.0_f64, |m, a| m.max(a.abs()));
    if peak == 0.0 {
        return None;
    }
    if cutoff == 0.0 {
        return Some(f64::INFINITY);
    }
    let qmax = 2.0 * (peak.ln() - 0.5 * d * d - cutoff.ln());
    (qmax > 0.0).then_some(qmax)
}

/// Slices `scene` at time `tau` into `out` (reset first), dropping kernels culled by the
/// cut-off `cutoff` (ε of SPEC §5, ≥ 0).
pub fn slice(scene: &Scene, tau: f64, cutoff: f64, out: &mut SlicedKernels) {
    out.reset();
    for i in 0..scene.len() {
        let [x, y, z, t] = scene.means[i];
        let scale = scene.scales[i];
        let dt = tau - t;
        let d = dt / scale[3];
        let Some(qmax) = cutoff_radius_squared(scene.amplitudes[i], d, cutoff) else {
            continue;
        };
        let w = (-0.5 * d * d).exp();
        let v = scene.velocities[i];
        out.kernel_from_slice.push(i as u32);
        out.means
            .push([x + v[0] * dt, y + v[1] * dt, z + v[2] * dt]);
        out.covariances
            .push(covariance_3d(scene.rotations[i], scale));
        out.amplitudes.push(scene.amplitudes[i].map(|a| a * w));
        out.qmax.push(qmax);
    }
}
