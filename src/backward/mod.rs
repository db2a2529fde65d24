//! The backward pass (SPEC §6): the exact derivative of the forward render, stage by stage
//! in reverse, with the indicator `[q ≤ qmax]` held constant:
//!
//! 1. [`raster`]: `∂L/∂C` per pixel → per projected kernel `∂L/∂a(τ)`, `∂L/∂m2`, `∂L/∂Q`
//!    (tile-parallel, over exactly the forward's pairs, deterministic reduction); for alpha
//!    frames [`composite`] (SPEC §8), which also gives `∂L/∂o(τ)` and `∂L/∂colour`;
//! 2. [`project`]: → `∂L/∂m(τ)`, the world-space slice centre, through `Q = Σ2⁻¹`, the EWA
//!    Jacobian (including its clamp) and the 2D mean;
//! 3. [`slice`](mod@slice): → `∂L/∂(x, y, z, t)`, `∂L/∂A`, `∂L/∂v`, scales and rotation of
//!    each scene kernel (and SPEC §9's acceleration and angular velocity); alpha scenes also the opacity and, through the colour's view
//!    direction, SH and `m(τ)`.
//!
//! Names follow the `v_x = ∂L/∂x` convention. Gradients are f64 and accumulate (`+=`), so a
//! batch of views sums into one [`Gradients`].

pub mod composite;
pub mod project;
pub mod raster;
pub mod slice;

/// Gradients of a loss with respect to every kernel's parameters, in scene order.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Gradients {
    /// `∂L/∂(x, y, z, t)`.
    pub v_means: Vec<[f64; 4]>,
    /// `∂L/∂(r, g, b)` of the peak amplitude.
    pub v_amplitudes: Vec<[f64; 3]>,
    /// `∂L/∂(vx, vy, vz)`.
    pub v_velocities: Vec<[f64; 3]>,
    /// `∂L/∂(sx, sy, sz, st)`, the standard deviations (in the `splat4d grad` file of alpha
    /// scenes).
    pub v_scales: Vec<[f64; 4]>,
    /// `∂L/∂(w, x, y, z)` of the scene's quaternion `q`, through its normalisation
    /// `q̂ = q/|q|`: `(I - q̂ q̂ᵀ) ∂L/∂q̂ / |q|`. A scene holds unit quaternions, so this is
    /// `(I - q̂ q̂ᵀ) ∂L/∂q̂`; a file's stored quaternion of another length `|q|` has this
    /// divided by `|q|` ([`Self::rotations_as_stored`]).
    pub v_rotations: Vec<[f64; 4]>,
    /// `∂L/∂(ax, ay, az)` (SPEC §9), sized like [`crate::model::Scene::accelerations`]: empty
    /// for scenes without accelerations.
    pub v_accelerations: Vec<[f64; 3]>,
    /// `∂L/∂(ωw, ωx, ωy, ωz)` (SPEC §9), sized like
    /// [`crate::model::Scene::angular_velocities`]: empty for scenes whose kernels do not turn.
    pub v_angular_velocities: Vec<[f64; 4]>,
    /// Alpha scenes: `∂L/∂o`, the peak opacity (empty for additive scenes).
    pub v_opacities: Vec<f64>,
    /// Alpha scenes: `∂L/∂sh`, laid out as [`crate::model::Scene::sh`].
    pub v_sh: Vec<[f64; 3]>,
    /// `∂L/∂b`, the scene's background colour (SPEC §5: `b` is added to every pixel, so
    /// this is `Σ_pixels ∂L/∂C`; not in the `splat4d grad` file).
    pub v_background: [f64; 3],
}

impl Gradients {
    /// Zero gradients for `n` kernels.
    #[must_use]
    pub fn zeros(n: usize) -> Self {
        let mut grads = Gradients::default();
        grads.reset(n);
        grads
    }

    /// Zero gradients for every field of `scene` (alpha scenes: opacity and SH too).
    #[must_use]
    pub fn for_scene(scene: &crate::model::Scene) -> Self {
        let mut grads = Gradients::default();
        grads.reset_for_scene(scene);
        grads
    }

    /// Sets every gradient of `scene`'s fields to zero, keeping the buffers.
    pub fn reset_for_scene(&mut self, scene: &crate::model::Scene) {
        self.reset(scene.len());
        self.v_opacities.resize(scene.opacities.len(), 0.0);
        self.v_sh.resize(scene.sh.len(), [0.0; 3]);
        self.v_accelerations
            .resize(scene.accelerations.len(), [0.0; 3]);
        self.v_angular_velocities
            .resize(scene.angular_velocities.len(), [0.0; 4]);
    }

    /// Sets every gradient to zero, for `n` kernels (alpha and SPEC §9 fields emptied: see
    /// [`Self::for_scene`]).
    pub fn reset(&mut self, n: usize) {
        self.v_rotations.clear();
        self.v_rotations.resize(n, [0.0; 4]);
        self.v_opacities.clear();
        self.v_sh.clear();
        self.v_accelerations.clear();
        self.v_angular_velocities.clear();
        self.v_means.clear();
        self.v_means.resize(n, [0.0; 4]);
        self.v_amplitudes.clear();
        self.v_amplitudes.resize(n, [0.0; 3]);
        self.v_velocities.clear();
        self.v_velocities.resize(n, [0.0; 3]);
        self.v_scales.clear();
        self.v_scales.resize(n, [0.0; 4]);
        self.v_background = [0.0; 3];
    }

    /// Adds `other` (sized alike) field by field.
    ///
    /// # Panics
    /// When the sizes differ.
    pub fn add(&mut self, other: &Gradients) {
        fn add_all<const N: usize>(total: &mut [[f64; N]], part: &[[f64; N]]) {
            assert_eq!(total.len(), part.len(), "gradients sized alike");
            for (total, part) in total.iter_mut().zip(part) {
                for (total, part) in total.iter_mut().zip(part) {
                    *total += part;
                }
            }
        }
        add_all(&mut self.v_means, &other.v_means);
        add_all(&mut self.v_amplitudes, &other.v_amplitudes);
        add_all(&mut self.v_velocities, &other.v_velocities);
        add_all(&mut self.v_scales, &other.v_scales);
        add_all(&mut self.v_rotations, &other.v_rotations);
        add_all(&mut self.v_sh, &other.v_sh);
        add_all(&mut self.v_accelerations, &other.v_accelerations);
        add_all(&mut self.v_angular_velocities, &other.v_angular_velocities);
        assert_eq!(self.v_opacities.len(), other.v_opacities.len());
        for (total, part) in self.v_opacities.iter_mut().zip(&other.v_opacities) {
            *total += part;
        }
        for (total, part) in self.v_background.iter_mut().zip(other.v_background) {
            *total += part;
        }
    }

    /// Makes the rotation gradients those of the quaternions as a file stores them, given
    /// their norms `|q|` (one per kernel; the scene holds `q/|q|`, except a turning kernel's
    /// `q` as stored, SPEC §9, whose norm is given as 1): SPEC §8 differentiates
    /// the stored quaternion through its normalisation, and `∂(q/|q|)/∂q = (I - q̂ q̂ᵀ)/|q|`
    /// carries a factor `1/|q|` beside the unit quaternion's.
    ///
    /// # Panics
    /// When there is not one norm per kernel.
    pub fn rotations_as_stored(&mut self, norms: &[f64]) {
        assert_eq!(norms.len(), self.v_rotations.len(), "one norm per kernel");
        for (v, &norm) in self.v_rotations.iter_mut().zip(norms) {
            *v = v.map(|g| g / norm);
        }
    }

    /// Number of kernels.
    #[must_use]
    pub fn len(&self) -> usize {
        self.v_means.len()
    }

    /// True when there is no kernel.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.v_means.is_empty()
    }
}

/// Reusable buffers of the backward pass.
#[derive(Debug, Default)]
pub struct BackwardBuffers {
    /// Stage 1 output.
    pub screen: raster::ScreenGradients,
    /// Stage 2 output: `∂L/∂m(τ)` and `∂L/∂a(τ)` per sliced kernel.
    pub sliced: project::SliceGradients,
}
