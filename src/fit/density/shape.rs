//! The alpha fit's bound on a kernel's shape (SPEC §8): a projection applied after every
//! Adam step, so that no kernel grows into a streak that only the training views support.
//!
//! With a kernel's spatial σ sorted `a ≥ b ≥ c` and `d` the distance from its spatial mean
//! to the nearest training camera centre:
//!
//! - **needle**: `a ≤ max_needle · b`. A thin disc (`c` small: a surface) is allowed; a
//!   needle (one axis long, the two others short) is what a fit grows where a narrow arc of
//!   views cannot tell depth apart, and what smears every other view. The bound caps the
//!   ratio of the largest σ to the middle one, as PhysGaussian caps the ratio of the largest
//!   to the smallest.
//! - **size**: `a ≤ max_size · d`, and every σ likewise: the kernel's projected σ in the
//!   nearest view at most `max_size · f` pixels.
//!
//! A σ beyond a bound is lowered to it (never raised); σt is never touched; the kernel's
//! Adam moments are kept (projected gradient descent). Kernel by kernel, no randomness:
//! the same bits on any thread count. `∞` switches a bound off.

use crate::model::scene::Scene;

/// The bounds of the shape projection (module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShapeBound {
    /// Largest ratio of a kernel's largest spatial σ to its middle one (`∞`: no bound).
    pub max_needle: f64,
    /// Largest ratio of a kernel's spatial σ to its distance from the nearest training
    /// camera (`∞`: no bound).
    pub max_size: f64,
}

impl ShapeBound {
    /// No bound at all.
    pub const OFF: ShapeBound = ShapeBound {
        max_needle: f64::INFINITY,
        max_size: f64::INFINITY,
    };

    /// Whether the projection can change a kernel.
    #[must_use]
    pub fn is_off(&self) -> bool {
        self.max_needle == f64::INFINITY && self.max_size == f64::INFINITY
    }

    /// Lowers every kernel's spatial σ of `scene` to the bounds (module docs), `centres`
    /// the training cameras' centres. Returns how many kernels changed.
    pub fn project(&self, scene: &mut Scene, centres: &[[f64; 3]]) -> usize {
        if self.is_off() {
            return 0;
        }
        let mut changed = 0;
        for (scale, mean) in scene.scales.iter_mut().zip(&scene.means) {
            let distance = nearest_distance([mean[0], mean[1], mean[2]], centres);
            let bounded = self.bounded([scale[0], scale[1], scale[2]], distance);
            if bounded != [scale[0], scale[1], scale[2]] {
                scale[..3].copy_from_slice(&bounded);
                changed += 1;
            }
        }
        changed
    }

    /// The spatial σ `s` lowered to the bounds for a kernel `distance` from the nearest
    /// camera (`∞` when there is none: no size bound).
    #[must_use]
    pub fn bounded(&self, s: [f64; 3], distance: f64) -> [f64; 3] {
        let mut order = [0, 1, 2];
        order.sort_by(|&i, &j| s[j].total_cmp(&s[i]).then(i.cmp(&j)));
        let [largest, middle, _] = order;
        let mut out = s;
        let needle_cap = self.max_needle * s[middle];
        if out[largest] > needle_cap {
            out[largest] = needle_cap;
        }
        let size_cap = self.max_size * distance;
        if size_cap > 0.0 {
            for v in &mut out {
                if *v > size_cap {
                    *v = size_cap;
                }
            }
        }
        out
    }
}

/// The distance from `p` to the nearest of `centres` (`∞` when there is none).
#[must_use]
pub fn nearest_distance(p: [f64; 3], centres: &[[f64; 3]]) -> f64 {
    centres
        .iter()
        .map(|c| {
            (0..3)
                .map(|a| (p[a] - c[a]) * (p[a] - c[a]))
                .sum::<f64>()
                .sqrt()
        })
        .fold(f64::INFINITY, f64::min)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::scene::Kernel;

    const BOUND: ShapeBound = ShapeBound {
        max_needle: 4.0,
        max_size: 0.1,
    };

    #[test]
    fn a_needle_is_shortened_to_the_ratio_and_a_disc_is_left_alone() {
        // A needle along y: 2.0 against 0.1 and 0.05 → 4 · 0.1.
        assert_eq!(BOUND.bounded([0.1, 2.0, 0.05], 100.0), [0.1, 0.4, 0.05]);
        // A thin disc: 1.0, 0.9 and 0.001 — the middle σ is near the largest.
        assert_eq!(BOUND.bounded([1.0, 0.001, 0.9], 100.0), [1.0, 0.001, 0.9]);
        // Exactly at the ratio: unchanged; ties between axes taken in order.
        assert_eq!(BOUND.bounded([0.4, 0.1, 0.1], 100.0), [0.4, 0.1, 0.1]);
        assert_eq!(BOUND.bounded([0.5, 0.5, 0.5], 100.0), [0.5, 0.5, 0.5]);
    }

    #[test]
    fn no_sigma_exceeds_the_share_of_the_distance_to_the_nearest_camera() {
        // 2 from the nearest camera: every σ at most 0.2.
        assert_eq!(BOUND.bounded([0.3, 0.25, 0.01], 2.0), [0.2, 0.2, 0.01]);
        // The needle bound first (0.3 → 4 · 0.05 = 0.2), then the size bound.
        assert_eq!(BOUND.bounded([0.3, 0.05, 0.05], 1.0), [0.1, 0.05, 0.05]);
        let centres = [[0.0, 0.0, 5.0], [3.0, 4.0, 0.0]];
        assert_eq!(nearest_distance([0.0; 3], &centres), 5.0);
        assert_eq!(nearest_distance([0.0; 3], &[]), f64::INFINITY);
        // No camera: no size bound.
        assert_eq!(BOUND.bounded([9.0, 9.0, 9.0], f64::INFINITY), [9.0; 3]);
    }

    #[test]
    fn the_projection_lowers_only_what_exceeds_and_keeps_time_and_rotation() {
        let needle = Kernel::new([0.0, 0.0, 0.0, 0.5], [3.0, 0.1, 0.1, 0.7], [1.0; 3]);
        let round = Kernel::new([0.0, 0.0, 1.0, 0.5], [0.05, 0.05, 0.05, 0.2], [1.0; 3]);
        let mut scene = Scene::from_kernels(&[needle, round], [0.0; 3], "<test>").unwrap();
        scene.rotations[0] = [0.5, 0.5, 0.5, 0.5];
        let centres = [[0.0, 0.0, 10.0]];
        assert_eq!(BOUND.project(&mut scene, &centres), 1);
        assert_eq!(scene.scales[0], [0.4, 0.1, 0.1, 0.7]);
        assert_eq!(scene.scales[1], [0.05, 0.05, 0.05, 0.2]);
        assert_eq!(scene.rotations[0], [0.5, 0.5, 0.5, 0.5]);
        // Off: nothing changes.
        let mut again = Scene::from_kernels(&[needle], [0.0; 3], "<test>").unwrap();
        assert_eq!(ShapeBound::OFF.project(&mut again, &centres), 0);
        assert_eq!(again.scales[0], needle.scale);
    }
}
