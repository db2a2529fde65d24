//! Scenes of 4D Gaussian kernels (SPEC §1), stored as struct-of-arrays.
//!
//! A kernel has a space-time mean `[x, y, z, t]`, standard deviations `[sx, sy, sz, st]`
//! (all > 0; `sx, sy, sz` are the conditional spreads of the slice at a fixed time), an
//! unnormalised peak amplitude `[r, g, b]` (any finite real), a Hamilton quaternion
//! `[w, x, y, z]` turning the spatial axes (normalised on load; active rotation, the columns
//! of R are the kernel's axes in world space) and a velocity `[vx, vy, vz]` in world units per
//! time unit (not rotated). Two optional fields (SPEC §9) let a kernel follow a parabola and
//! a turn: an acceleration `[ax, ay, az]` and the quaternion's rate `[ωw, ωx, ωy, ωz]`, with
//! `m(τ) = xyz + v d_t + ½ a d_t²` and axes from `(q + ω d_t)/|q + ω d_t|`, `d_t = τ - t`;
//! a turning kernel keeps its quaternion as written. They live beside the kernels
//! ([`Scene::accelerations`], [`Scene::angular_velocities`]), each empty when no kernel has
//! one. Parameters are stored in f64: the per-kernel stage of the
//! renderer works in f64 (SPEC §5, precision).
//!
//! A scene also declares its [`Blend`] (SPEC §8): `additive` (§5, the default) sums the
//! kernels; `alpha` composites them front to back, and each kernel then also has a peak
//! opacity `o ∈ [0, 1]` and a view-dependent colour: `sh` triplets (3, 8 or 15 per kernel, or
//! none) of real spherical harmonics of degree 1–3 added to the amplitude. These live beside
//! the kernels ([`Scene::opacities`], [`Scene::sh`]), empty for additive scenes.
//!
//! Files (JSON and 4D PLY) are read and written by [`crate::io::scene_file`]; this module
//! knows nothing of them. `Kernel` carries serde derives so that the file layer can read it.

use serde::{Deserialize, Serialize};

use super::Up;

use crate::model::error::{Error, Result, check_finite};

/// One 4D kernel, as read from or written to a file. The renderer works on [`Scene`].
///
/// SPEC §1: mean `(x, y, z, t)`, scales `(sx, sy, sz, st)`, rotation, velocity, amplitude.
///
/// ```
/// use splat4d::Kernel;
/// let mut kernel = Kernel::new([0.0, 0.0, 0.0, 0.5], [0.1, 0.1, 0.1, 1.0], [1.0, 1.0, 1.0]);
/// kernel.velocity = [1.0, 0.0, 0.0]; // the slice centre moves along +x over time
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Kernel {
    /// Centre `[x, y, z, t]`: world space and scene time.
    pub mean: [f64; 4],
    /// Standard deviations `[sx, sy, sz, st]`, all > 0.
    pub scale: [f64; 4],
    /// Peak intensity per channel `[r, g, b]`.
    pub amplitude: [f64; 3],
    /// Hamilton quaternion `[w, x, y, z]`.
    #[serde(default = "identity_rotation")]
    pub rotation: [f64; 4],
    /// World units per time unit.
    #[serde(default)]
    pub velocity: [f64; 3],
    /// World units per time unit² (SPEC §9; zero: §1's motion).
    #[serde(default)]
    pub acceleration: [f64; 3],
    /// The rate of the stored quaternion per time unit, `[ωw, ωx, ωy, ωz]` (SPEC §9; zero:
    /// §1's fixed rotation).
    #[serde(default)]
    pub angular_velocity: [f64; 4],
}

fn identity_rotation() -> [f64; 4] {
    [1.0, 0.0, 0.0, 0.0]
}

impl Kernel {
    /// An axis-aligned, static kernel.
    #[must_use]
    pub fn new(mean: [f64; 4], scale: [f64; 4], amplitude: [f64; 3]) -> Self {
        Kernel {
            mean,
            scale,
            amplitude,
            rotation: identity_rotation(),
            velocity: [0.0; 3],
            acceleration: [0.0; 3],
            angular_velocity: [0.0; 4],
        }
    }

    /// Moves the kernel's time mean by `dt` along its own path (SPEC §9): the centre to
    /// `m(t + dt)`, the velocity to `v + a dt`, a turning kernel's quaternion to `q + ω dt`
    /// (as written); the acceleration and angular velocity stay. Its slice at any τ is then
    /// the same centre and axes as before (the temporal weight is the caller's). Without §9
    /// fields only the centre moves, by `v dt`.
    pub fn advance_on_path(&mut self, dt: f64) {
        self.mean[3] += dt;
        for c in 0..3 {
            self.mean[c] += self.velocity[c] * dt;
        }
        if self.acceleration != [0.0; 3] {
            for c in 0..3 {
                self.mean[c] += 0.5 * self.acceleration[c] * dt * dt;
                self.velocity[c] += self.acceleration[c] * dt;
            }
        }
        if self.turns() {
            for (q, w) in self.rotation.iter_mut().zip(self.angular_velocity) {
                *q += w * dt;
            }
        }
    }

    /// True when the kernel accelerates or turns (SPEC §9).
    #[must_use]
    pub fn has_motion(&self) -> bool {
        self.acceleration != [0.0; 3] || self.turns()
    }

    /// True when the kernel turns (SPEC §9): its angular velocity is not zero, so its
    /// quaternion is kept as written.
    #[must_use]
    pub fn turns(&self) -> bool {
        self.angular_velocity != [0.0; 4]
    }

    /// The kernel as a scene holds it, or an error naming kernel `index` of `origin` and the
    /// field: every value finite, scales > 0, the rotation normalised (a quaternion within a
    /// few ulps of unit norm is kept as it is, so that files round-trip exactly). A kernel that
    /// turns (SPEC §9, [`Kernel::turns`]) keeps its quaternion as written: `q + ω d_t` is
    /// normalised at each τ instead. A zero quaternion is an error either way (§1).
    pub fn checked(&self, index: usize, origin: &str) -> Result<Kernel> {
        let all_finite = [
            &self.mean[..],
            &self.scale,
            &self.amplitude,
            &self.rotation,
            &self.velocity,
            &self.acceleration,
            &self.angular_velocity,
        ]
        .iter()
        .all(|values| values.iter().all(|v| v.is_finite()));
        // The item's name is only formatted for a message (10⁵ kernels load in milliseconds).
        let item = || format!("kernel {index}");
        if !all_finite {
            let item = item();
            check_finite(origin, &item, "mean", &self.mean)?;
            check_finite(origin, &item, "scale", &self.scale)?;
            check_finite(origin, &item, "amplitude", &self.amplitude)?;
            check_finite(origin, &item, "rotation", &self.rotation)?;
            check_finite(origin, &item, "velocity", &self.velocity)?;
            check_finite(origin, &item, "acceleration", &self.acceleration)?;
            check_finite(origin, &item, "angular_velocity", &self.angular_velocity)?;
        }
        if let Some(c) = self.scale.iter().position(|&s| s <= 0.0) {
            return Err(Error::invalid(
                origin,
                item(),
                "scale",
                format!("scale[{c}] = {} must be > 0", self.scale[c]),
            ));
        }
        let norm = self.rotation.iter().map(|q| q * q).sum::<f64>().sqrt();
        if !(norm > 0.0 && norm.is_finite()) {
            return Err(Error::invalid(
                origin,
                item(),
                "rotation",
                "the quaternion is zero (or its norm overflows) and cannot be normalised",
            ));
        }
        // Dividing a unit quaternion again would only perturb its last bits.
        let unit = (norm - 1.0).abs() <= 4.0 * f64::EPSILON || self.turns();
        Ok(Kernel {
            rotation: if unit {
                self.rotation
            } else {
                self.rotation.map(|q| q / norm)
            },
            ..*self
        })
    }
}

/// Pushes `value` as item `n - 1` of `column`, which holds either nothing (every earlier
/// value zero) or `n - 1` values: it stays empty while the values are zero.
fn push_optional<T: Copy + Default + PartialEq>(column: &mut Vec<T>, n: usize, value: T) {
    if column.is_empty() && value == T::default() {
        return;
    }
    if column.len() < n - 1 {
        column.resize(n - 1, T::default());
    }
    column.push(value);
}

/// How a scene's kernels make a pixel (SPEC §5 and §8).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Blend {
    /// The sum of SPEC §5 (the seed paper's Eq. 2): no order, no occlusion.
    #[default]
    Additive,
    /// Front-to-back compositing of SPEC §8: opacity, SH colour, depth order.
    Alpha,
}

impl std::fmt::Display for Blend {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Blend::Additive => "additive",
            Blend::Alpha => "alpha",
        })
    }
}

impl std::str::FromStr for Blend {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "additive" => Ok(Blend::Additive),
            "alpha" => Ok(Blend::Alpha),
            _ => Err(format!("unknown blend {s:?} (expected additive or alpha)")),
        }
    }
}

/// The numbers of SH triplets per kernel a scene may have (none, degree 1, 1–2, 1–3).
pub const SH_COUNTS: [usize; 4] = [0, 3, 8, 15];

/// A scene: kernels as struct-of-arrays (index `i` of every array is kernel `i`) and a
/// background colour added to every pixel.
///
/// SPEC §1 (the kernels), §5 (the background) and §8 (the alpha fields).
///
/// ```
/// use splat4d::{Kernel, Scene};
/// let kernel = Kernel::new([0.0, 0.0, 0.0, 0.5], [0.1, 0.1, 0.1, 1.0], [1.0, 0.5, 0.2]);
/// let scene = Scene::from_kernels(&[kernel], [0.0; 3], "<example>").unwrap();
/// assert_eq!(scene.len(), 1);
/// ```
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Scene {
    /// `[x, y, z, t]` per kernel.
    pub means: Vec<[f64; 4]>,
    /// `[sx, sy, sz, st]` per kernel.
    pub scales: Vec<[f64; 4]>,
    /// `[r, g, b]` per kernel.
    pub amplitudes: Vec<[f64; 3]>,
    /// Quaternions `[w, x, y, z]` per kernel: unit, except for kernels that turn (SPEC §9).
    pub rotations: Vec<[f64; 4]>,
    /// `[vx, vy, vz]` per kernel.
    pub velocities: Vec<[f64; 3]>,
    /// `[ax, ay, az]` per kernel (SPEC §9), or empty when no kernel accelerates.
    pub accelerations: Vec<[f64; 3]>,
    /// `[ωw, ωx, ωy, ωz]` per kernel (SPEC §9), or empty when no kernel turns. A kernel that
    /// turns keeps its quaternion in [`Scene::rotations`] as written (not unit).
    pub angular_velocities: Vec<[f64; 4]>,
    /// `[r, g, b]`, linear.
    pub background: [f64; 3],
    /// The world's up axis when known (a scene fitted from a dataset carries its cameras'
    /// up); videos turn about it unless told otherwise, +y when `None`.
    pub up: Option<Up>,
    /// The time range `[t0, t1]` of the data a fitted scene came from: videos and sequences
    /// span it by default (else the range of the kernels' time means).
    pub time_range: Option<[f64; 2]>,
    /// The sphere (centre, radius) the cameras of the data a fitted scene came from look at:
    /// videos frame it by default (else the kernels alive).
    pub framing: Option<([f64; 3], f64)>,
    /// How kernels make a pixel.
    pub blend: Blend,
    /// Alpha scenes: the peak opacity `o ∈ [0, 1]` per kernel (empty for additive scenes).
    pub opacities: Vec<f64>,
    /// Alpha scenes: SH triplets per kernel, one of [`SH_COUNTS`].
    pub sh_count: usize,
    /// Alpha scenes: `sh_count` `[r, g, b]` triplets per kernel, kernel `i`'s at
    /// `i·sh_count ..`, in the order of SPEC §8.
    pub sh: Vec<[f64; 3]>,
}

impl Scene {
    /// A scene from kernels; rotations are normalised and everything is validated.
    /// `origin` names the data in error messages.
    pub fn from_kernels(kernels: &[Kernel], background: [f64; 3], origin: &str) -> Result<Self> {
        check_finite(origin, "scene", "background", &background)?;
        let mut scene = Scene {
            background,
            ..Scene::default()
        };
        scene.reserve(kernels.len());
        for (index, kernel) in kernels.iter().enumerate() {
            scene.push_kernel(&kernel.checked(index, origin)?);
        }
        Ok(scene)
    }

    /// Appends `kernel`'s fields (not the alpha blend's opacity and SH, which the caller
    /// pushes for an alpha scene).
    pub fn push_kernel(&mut self, kernel: &Kernel) {
        self.means.push(kernel.mean);
        self.scales.push(kernel.scale);
        self.amplitudes.push(kernel.amplitude);
        self.rotations.push(kernel.rotation);
        self.velocities.push(kernel.velocity);
        self.push_motion(kernel.acceleration, kernel.angular_velocity);
    }

    /// Appends the SPEC §9 fields of the kernel just pushed (the last one of
    /// [`Scene::means`]), keeping each array empty while every value is zero and full length
    /// once one is not.
    pub fn push_motion(&mut self, acceleration: [f64; 3], angular_velocity: [f64; 4]) {
        let n = self.means.len();
        push_optional(&mut self.accelerations, n, acceleration);
        push_optional(&mut self.angular_velocities, n, angular_velocity);
    }

    /// Kernel `i`'s acceleration (zero when the scene has none).
    #[must_use]
    pub fn acceleration(&self, i: usize) -> [f64; 3] {
        self.accelerations.get(i).copied().unwrap_or_default()
    }

    /// Kernel `i`'s angular velocity (zero when the scene has none).
    #[must_use]
    pub fn angular_velocity(&self, i: usize) -> [f64; 4] {
        self.angular_velocities.get(i).copied().unwrap_or_default()
    }

    /// True when some kernel has a SPEC §9 field.
    #[must_use]
    pub fn has_motion(&self) -> bool {
        !self.accelerations.is_empty() || !self.angular_velocities.is_empty()
    }

    /// Room for `additional` more kernels in every array.
    pub fn reserve(&mut self, additional: usize) {
        self.means.reserve(additional);
        self.scales.reserve(additional);
        self.amplitudes.reserve(additional);
        self.rotations.reserve(additional);
        self.velocities.reserve(additional);
    }

    /// Number of kernels.
    #[must_use]
    pub fn len(&self) -> usize {
        self.means.len()
    }

    /// True when the scene has no kernel.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.means.is_empty()
    }

    /// Kernel `i` as a [`Kernel`].
    #[must_use]
    pub fn kernel(&self, i: usize) -> Kernel {
        Kernel {
            mean: self.means[i],
            scale: self.scales[i],
            amplitude: self.amplitudes[i],
            rotation: self.rotations[i],
            velocity: self.velocities[i],
            acceleration: self.acceleration(i),
            angular_velocity: self.angular_velocity(i),
        }
    }

    /// All kernels, in order.
    #[must_use]
    pub fn kernels(&self) -> Vec<Kernel> {
        (0..self.len()).map(|i| self.kernel(i)).collect()
    }

    /// Checks every value (finite, scales > 0, unit quaternions; for alpha scenes the
    /// opacities and SH too): for scenes changed in code.
    pub fn validate(&self, origin: &str) -> Result<()> {
        Scene::from_kernels(&self.kernels(), self.background, origin)?;
        for (field, len) in [
            ("acceleration", self.accelerations.len()),
            ("angular_velocity", self.angular_velocities.len()),
        ] {
            if len != 0 && len != self.len() {
                return Err(Error::invalid(
                    origin,
                    "scene",
                    field,
                    format!(
                        "{len} values for {} kernels: one per kernel or none",
                        self.len()
                    ),
                ));
            }
        }
        self.check_time_range(origin)?;
        self.check_appearance(origin)
    }

    /// A recorded time range must be finite and ordered.
    pub fn check_time_range(&self, origin: &str) -> Result<()> {
        match self.time_range {
            Some([t0, t1])
                if !(t0.is_finite() && t1.is_finite() && t0 <= t1 && (t1 - t0).is_finite()) =>
            {
                Err(Error::invalid(
                    origin,
                    "scene",
                    "time_range",
                    format!(
                        "[{t0:?}, {t1:?}] is not a finite, ordered pair whose span t1 - t0 is finite"
                    ),
                ))
            }
            _ => match self.framing {
                Some((centre, radius))
                    if !(centre.iter().all(|c| c.is_finite())
                        && radius.is_finite()
                        && radius > 0.0) =>
                {
                    Err(Error::invalid(
                        origin,
                        "scene",
                        "framing",
                        format!("centre {centre:?}, radius {radius}: finite, radius > 0"),
                    ))
                }
                _ => Ok(()),
            },
        }
    }

    /// Makes this an alpha scene (SPEC §8) with `opacities` (one per kernel) and `sh`
    /// (`sh_count` triplets per kernel), checking them: opacities finite in `[0, 1]`, SH
    /// finite, `sh_count` one of [`SH_COUNTS`], the lengths matching the kernels.
    pub fn into_alpha(
        mut self,
        opacities: Vec<f64>,
        sh_count: usize,
        sh: Vec<[f64; 3]>,
        origin: &str,
    ) -> Result<Scene> {
        self.blend = Blend::Alpha;
        self.opacities = opacities;
        self.sh_count = sh_count;
        self.sh = sh;
        self.check_appearance(origin)?;
        Ok(self)
    }

    /// Kernel `i`'s SH triplets (empty for additive scenes or without SH).
    #[must_use]
    pub fn sh_of(&self, i: usize) -> &[[f64; 3]] {
        &self.sh[i * self.sh_count..(i + 1) * self.sh_count]
    }

    /// The opacity of kernel `i` (1 for additive scenes).
    #[must_use]
    pub fn opacity(&self, i: usize) -> f64 {
        self.opacities.get(i).copied().unwrap_or(1.0)
    }

    /// The checks of SPEC §8 on the alpha fields; additive scenes must have none.
    fn check_appearance(&self, origin: &str) -> Result<()> {
        let n = self.len();
        match self.blend {
            Blend::Additive => {
                if !self.opacities.is_empty() || !self.sh.is_empty() || self.sh_count != 0 {
                    return Err(Error::invalid(
                        origin,
                        "scene",
                        "blend",
                        "opacity and sh are fields of the alpha blend: declare \"blend\": \"alpha\"",
                    ));
                }
                return Ok(());
            }
            Blend::Alpha => {}
        }
        if !SH_COUNTS.contains(&self.sh_count) {
            return Err(Error::invalid(
                origin,
                "scene",
                "sh",
                format!(
                    "{} triplets per kernel: expected 3, 8 or 15 (degree 1, 2 or 3) or none",
                    self.sh_count
                ),
            ));
        }
        if self.opacities.len() != n || self.sh.len() != n * self.sh_count {
            return Err(Error::invalid(
                origin,
                "scene",
                "opacity",
                format!(
                    "{} opacities and {} SH triplets for {n} kernels of {} triplets",
                    self.opacities.len(),
                    self.sh.len(),
                    self.sh_count
                ),
            ));
        }
        for (i, &o) in self.opacities.iter().enumerate() {
            if !(o.is_finite() && (0.0..=1.0).contains(&o)) {
                return Err(Error::invalid(
                    origin,
                    format!("kernel {i}"),
                    "opacity",
                    format!("{o} must be finite and within [0, 1]"),
                ));
            }
        }
        if let Some(k) = self
            .sh
            .iter()
            .position(|t| !t.iter().all(|v| v.is_finite()))
        {
            let (i, j) = (k / self.sh_count, k % self.sh_count);
            return Err(Error::invalid(
                origin,
                format!("kernel {i}"),
                "sh",
                format!("triplet {j} = {:?} is not finite", self.sh[k]),
            ));
        }
        Ok(())
    }
}
