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
//! Motion beyond constant velocity (SPEC §9, optional per kernel: acceleration `a` and the
//! quaternion's rate `ω`), with `d_t = τ - t`:
//!
//! ```text
//! m    = (x, y, z) + v d_t + ½ a d_t²
//! R    = R((q + ω d_t) / |q + ω d_t|)      q as stored (not unit when ω ≠ 0)
//! ```
//!
//! A kernel whose `q + ω d_t` is zero or not finite is dropped at τ. Scenes without the
//! fields (empty [`Scene::accelerations`], [`Scene::angular_velocities`]) take the lines
//! above unchanged, to the bit.
//!
//! A kernel with `qmax ≤ 0` (its largest |amplitude| at τ is ≤ ε) is dropped here, before
//! any projection work.
//!
//! Alpha scenes (SPEC §8) put the temporal weight on the opacity instead: `o(τ) = o w` and
//! `qmax = 2 (ln o - ½ d² - ln ε)`; the amplitude stays `A` (the colour's base, made
//! view-dependent by [`crate::colour`]). With `ε = 0` nothing is truncated: `qmax = +∞`, and only kernels
//! whose amplitude is exactly zero are dropped. Everything is f64.

use crate::model::scene::{Blend, Scene};
use rayon::prelude::*;

use crate::parallel::{gather_kept, keep_chunks, keep_in_parallel};

/// Kernels alive at τ, sliced to 3D. Struct-of-arrays: index `s` of every array is one
/// sliced kernel; `kernel_from_slice[s]` is its index in the scene (ascending).
///
/// SPEC §2: the conditional 3D Gaussian at τ, its centre `mean.xyz + velocity (τ − t)` and
/// amplitude scaled by the temporal weight (§9: the centre and axes on their curves).
#[derive(Clone, Debug, Default)]
pub struct SlicedKernels {
    /// Scene index of each sliced kernel, ascending.
    pub kernel_from_slice: Vec<u32>,
    /// 3D centre `m(τ)`, world space.
    pub means: Vec<[f64; 3]>,
    /// 3D covariance `Σ3` as `[xx, xy, xz, yy, yz, zz]`, world space.
    pub covariances: Vec<[f64; 6]>,
    /// Sliced amplitude `a(τ) = A w(τ)` per channel; alpha scenes: `A` itself.
    pub amplitudes: Vec<[f64; 3]>,
    /// Alpha scenes: the opacity at τ, `o(τ) = o w(τ)` (empty for additive scenes).
    pub opacities: Vec<f64>,
    /// Cut-off `qmax` on the squared Mahalanobis radius (`+∞` without truncation).
    pub qmax: Vec<f64>,
}

/// One kernel's slice.
#[derive(Clone, Copy, Debug)]
pub(crate) struct SlicedKernel {
    pub(crate) mean: [f64; 3],
    pub(crate) covariance: [f64; 6],
    pub(crate) amplitude: [f64; 3],
    /// Alpha scenes: `o(τ)` (0 for additive ones).
    pub(crate) opacity: f64,
    pub(crate) qmax: f64,
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
        self.opacities.clear();
        self.qmax.clear();
    }
}

/// The value the cut-off of kernel `i` is decided on: its largest |amplitude| (SPEC §5), or
/// for alpha scenes its opacity (§8).
#[inline]
#[must_use]
pub fn peak(scene: &Scene, i: usize) -> f64 {
    match scene.blend {
        Blend::Additive => scene.amplitudes[i]
            .iter()
            .fold(0.0_f64, |m, a| m.max(a.abs())),
        Blend::Alpha => scene.opacities[i],
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

/// The unit quaternion of `q + ω dt` (SPEC §9), or `None` when it is zero or not finite (the
/// kernel is culled at that time).
#[inline]
#[must_use]
pub fn turned_quaternion(q: [f64; 4], omega: [f64; 4], dt: f64) -> Option<[f64; 4]> {
    let turned: [f64; 4] = std::array::from_fn(|k| q[k] + omega[k] * dt);
    let norm = turned.iter().map(|v| v * v).sum::<f64>().sqrt();
    (norm > 0.0 && norm.is_finite()).then(|| turned.map(|v| v / norm))
}

/// `q / |q|`: the unit quaternion of a nonzero, finite `q`.
#[must_use]
pub fn unit_quaternion(q: [f64; 4]) -> [f64; 4] {
    let norm = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    q.map(|v| v / norm)
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

/// The cut-off `qmax` of SPEC §5 (§8) for a kernel of peak `peak` ([`peak`]) at normalised
/// time offset `d`, or `None` when the kernel is culled (`qmax ≤ 0`). `cutoff = 0` means no
/// truncation.
#[must_use]
pub fn cutoff_radius_squared(peak: f64, d: f64, cutoff: f64) -> Option<f64> {
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
    slice_visiting(scene, scene.len(), |k| k, tau, cutoff, out);
}

/// Slices only `candidates` (ascending scene indices, a superset of the kernels alive at
/// `tau`, as [`TemporalIndex::candidates`] gives): the same output as [`slice()`].
pub fn slice_candidates(
    scene: &Scene,
    candidates: &[u32],
    tau: f64,
    cutoff: f64,
    out: &mut SlicedKernels,
) {
    slice_visiting(
        scene,
        candidates.len(),
        |k| candidates[k] as usize,
        tau,
        cutoff,
        out,
    );
}

/// Slices kernels `kernel(0..count)` (ascending) in parallel, keeping the live ones in that
/// order: the output does not depend on the thread count.
fn slice_visiting(
    scene: &Scene,
    count: usize,
    kernel: impl Fn(usize) -> usize + Sync,
    tau: f64,
    cutoff: f64,
    out: &mut SlicedKernels,
) {
    out.reset();
    // One pass: each chunk of visiting positions writes the slices it keeps at the start of
    // its own stretch of every array; the stretches are gathered after.
    let chunks = keep_chunks(&mut out.kernel_from_slice, count)
        .zip(keep_chunks(&mut out.means, count))
        .zip(keep_chunks(&mut out.covariances, count))
        .zip(keep_chunks(&mut out.amplitudes, count))
        .zip(keep_chunks(&mut out.qmax, count))
        .zip(keep_chunks(&mut out.opacities, count));
    let alpha = scene.blend == Blend::Alpha;
    let kept = keep_in_parallel(
        count,
        chunks,
        |k| {
            let i = kernel(k);
            slice_one(scene, i, tau, cutoff).map(|s| (i, s))
        },
        |columns, at, _, (i, s)| {
            let (((((indices, means), covariances), amplitudes), qmax), opacities) = columns;
            debug_assert!(u32::try_from(i).is_ok(), "scene indices fit in u32");
            indices[at].write(i as u32);
            means[at].write(s.mean);
            covariances[at].write(s.covariance);
            amplitudes[at].write(s.amplitude);
            qmax[at].write(s.qmax);
            if alpha {
                opacities[at].write(s.opacity);
            }
        },
    );
    // SAFETY: each array is a column of the pass, whose chunks wrote their kept slices (the
    // opacities only for alpha scenes; otherwise they stay empty).
    unsafe {
        gather_kept(&mut out.kernel_from_slice, &kept);
        gather_kept(&mut out.means, &kept);
        gather_kept(&mut out.covariances, &kept);
        gather_kept(&mut out.amplitudes, &kept);
        gather_kept(&mut out.qmax, &kept);
        if alpha {
            gather_kept(&mut out.opacities, &kept);
        }
    }
}

/// The temporal weight `w = exp(-½ d²)` of `d = (τ - t) / st` (SPEC §2).
#[inline(always)]
fn weight_of(d: f64) -> f64 {
    (-0.5 * d * d).exp()
}

/// Kernel `i` sliced at `tau`, or `None` when it is culled. Inlined into [`slice_visiting`]'s
/// pass (and [`crate::project::slice_and_project`]'s): its result then stays out of memory
/// until it is kept (as the projection's, whose copy through the stack stalled on store
/// forwarding when it was a call).
#[inline(always)]
pub(crate) fn slice_one(scene: &Scene, i: usize, tau: f64, cutoff: f64) -> Option<SlicedKernel> {
    let [x, y, z, t] = scene.means[i];
    let scale = scene.scales[i];
    let dt = tau - t;
    let d = dt / scale[3];
    let qmax = cutoff_radius_squared(peak(scene, i), d, cutoff)?;
    let w = weight_of(d);
    // SPEC §9: a turning kernel's axes at τ, culled where `q + ω d_t` cannot be normalised.
    let rotation = match scene.angular_velocities.get(i) {
        Some(&omega) if omega != [0.0; 4] => turned_quaternion(scene.rotations[i], omega, dt)?,
        _ => scene.rotations[i],
    };
    let v = scene.velocities[i];
    let mut mean = [x + v[0] * dt, y + v[1] * dt, z + v[2] * dt];
    if let Some(a) = scene.accelerations.get(i) {
        let half_dt2 = 0.5 * dt * dt;
        for (m, a) in mean.iter_mut().zip(a) {
            *m += a * half_dt2;
        }
    }
    let (amplitude, opacity) = match scene.blend {
        Blend::Additive => (scene.amplitudes[i].map(|a| a * w), 0.0),
        Blend::Alpha => {
            let opacity = scene.opacities[i] * w;
            if opacity == 0.0 {
                return None; // o(τ) = 0 adds nothing for any ε (SPEC §8)
            }
            (scene.amplitudes[i], opacity)
        }
    };
    Some(SlicedKernel {
        mean,
        covariance: covariance_3d(rotation, scale),
        amplitude,
        opacity,
        qmax,
    })
}

/// Which kernels can be alive at a time, so that a frame visits those and not the whole
/// scene: cost follows the kernels alive at τ.
///
/// Kernel `i` is alive at τ iff `2 (ln max_c|A_c| - ½ d² - ln ε) > 0` (SPEC §5), i.e. iff
/// `|τ - t| < st √(2 ln(max|A|/ε))`: an open interval around `t`, widened here by a relative
/// 1e-9 so that rounding never drops a kernel (the slice applies the exact test again).
/// Intervals are registered in equal bins over the range of their centres; a kernel whose
/// interval covers more than a quarter of that range (or is infinite, as with ε = 0) goes to
/// a list consulted at every time instead. A query merges that list with one bin's list, in
/// ascending kernel order, so the slice, and the image, are the same as without the index.
/// The index belongs to one scene and one ε; rebuild it when either changes.
#[derive(Clone, Debug, Default)]
pub struct TemporalIndex {
    cutoff: f64,
    kernels: usize,
    start: f64,
    width: f64,
    always: Vec<u32>,
    bins: Vec<Vec<u32>>,
}

impl TemporalIndex {
    /// Builds the index of `scene` for cut-off `cutoff`.
    #[must_use]
    pub fn new(scene: &Scene, cutoff: f64) -> Self {
        let mut intervals = Vec::with_capacity(scene.len());
        let mut always = Vec::new();
        for i in 0..scene.len() {
            let peak = peak(scene, i);
            if peak == 0.0 || (cutoff > 0.0 && peak <= cutoff) {
                continue; // never alive
            }
            let reach = if cutoff == 0.0 {
                f64::INFINITY
            } else {
                scene.scales[i][3] * (2.0 * (peak / cutoff).ln()).sqrt() * (1.0 + 1e-9)
            };
            let t = scene.means[i][3];
            if reach.is_finite() {
                intervals.push((i as u32, t - reach, t + reach));
            } else {
                always.push(i as u32);
            }
        }
        let (lo, hi) = intervals.iter().fold(
            (f64::INFINITY, f64::NEG_INFINITY),
            |(lo, hi), &(_, a, b)| (lo.min(0.5 * (a + b)), hi.max(0.5 * (a + b))),
        );
        let span = if hi > lo { hi - lo } else { 1.0 };
        let count = (intervals.len() / 64).clamp(1, 4096);
        let width = span / count as f64;
        let mut bins = vec![Vec::new(); count];
        let bin_of = |time: f64| (((time - lo) / width).floor().max(0.0) as usize).min(count - 1);
        for &(i, a, b) in &intervals {
            if b - a > 0.25 * span {
                always.push(i);
                continue;
            }
            for bin in &mut bins[bin_of(a)..=bin_of(b)] {
                bin.push(i);
            }
        }
        always.sort_unstable();
        TemporalIndex {
            cutoff,
            kernels: scene.len(),
            start: if lo.is_finite() { lo } else { 0.0 },
            width,
            always,
            bins,
        }
    }

    /// The cut-off the index was built for.
    #[must_use]
    pub fn cutoff(&self) -> f64 {
        self.cutoff
    }

    /// Kernels of the scene the index was built for.
    #[must_use]
    pub fn kernels(&self) -> usize {
        self.kernels
    }

    /// The kernels that may be alive at `tau`, ascending, into `out` (reset first).
    pub fn candidates(&self, tau: f64, out: &mut Vec<u32>) {
        out.clear();
        let position = (tau - self.start) / self.width;
        // A time outside every bin can still be inside an interval that reaches past the
        // range of centres: use the nearest bin, whose intervals cover the edge.
        let bin: &[u32] = if self.bins.is_empty() || position.is_nan() {
            &[]
        } else {
            &self.bins[(position.floor().max(0.0) as usize).min(self.bins.len() - 1)]
        };
        let (mut a, mut b) = (self.always.iter().peekable(), bin.iter().peekable());
        loop {
            let next = match (a.peek(), b.peek()) {
                (Some(&&x), Some(&&y)) if x <= y => a.next(),
                (Some(_), Some(_)) | (None, Some(_)) => b.next(),
                (Some(_), None) => a.next(),
                (None, None) => break,
            };
            out.extend(next.copied());
        }
    }
}
