//! The seed paper's toy scenes (SPEC §7).
//!
//! - [`blob_scene`]: the continuous object, one velocity kernel: mean (0.5, 0.5, 0.5, 0.5),
//!   scale (0.1, 0.1, 0.1, 100), velocity (1, 1, 1), amplitude (1, 1, 1).
//! - [`points_scene`]: the paper's data. 30 frames at `t_k = k/29`; per frame 1000 points drawn
//!   from `N(c(t_k), 0.1² I)` with `c(t) = (t, t, t)` (seeded); each point becomes a static
//!   kernel with spatial σ [`POINT_SIGMA`] = 0.05 and temporal σ equal to the frame spacing
//!   Δt = 1/29 (consecutive frames blend smoothly: the sum of the temporal weights over frames
//!   ripples by < 1e-7 relative), and amplitude [`point_amplitude`] chosen so that the
//!   expected value of the Eq. 1 volume on the path, away from its ends, is 1. Frame k's
//!   cloud is centred at `c(t_k)`, `√3 |τ - t_k|` from `c(τ)`, so with `τ - t_k = j Δt`:
//!
//! ```text
//! E[frame k at c(τ)] = 1000 A w_j (σp²/(σp² + σ²))^{3/2} exp(-3 j² Δt² / (2 (σp² + σ²)))
//! w_j = exp(-½ j²)                                        (σ = 0.1 the noise)
//! A = 1 / (1000 · 0.2^{3/2} · S),   S = Σ_j exp(-½ j² (1 + 3 Δt²/(σp² + σ²))) ≈ 2.211
//! ```
//!
//!   so `A ≈ 5.06e-3`, and the expected peak is about 0.6 at the path's ends (one side of
//!   frames only).
//!
//! Each point kernel is barely above the default render cut-off of 1/255 ≈ 3.9e-3: with it,
//! a point would be cut at `q = 2 ln(5.06/3.92) ≈ 0.5`, i.e. mostly truncated (SPEC §5). The
//! points scene is rendered with [`POINTS_CUTOFF`] = 1e-5 instead, which cuts each kernel
//! where it falls to 0.2% of its peak.

use rand_distr::{Distribution, Normal};

use crate::model::random::seeded_rng;
use crate::model::scene::{Kernel, Scene};

/// Frames of the paper's point data.
pub const FRAMES: usize = 30;
/// Points per frame.
pub const POINTS_PER_FRAME: usize = 1000;
/// Standard deviation of the points around the path.
pub const NOISE_SIGMA: f64 = 0.1;
/// Spatial σ of each point kernel.
pub const POINT_SIGMA: f64 = 0.05;
/// Amplitude of each point kernel, ≈ 5.06e-3 (see the module docs).
#[must_use]
pub fn point_amplitude() -> f64 {
    let dt = 1.0 / (FRAMES - 1) as f64;
    let spread = POINT_SIGMA.powi(2) + NOISE_SIGMA.powi(2);
    let rate = 0.5 * (1.0 + 3.0 * dt * dt / spread);
    // The series converges fast: j = 12 contributes e^-92.
    let sum: f64 = (-12..=12)
        .map(|j: i32| (-rate * f64::from(j * j)).exp())
        .sum();
    let density = (POINT_SIGMA.powi(2) / spread).powf(1.5);
    1.0 / (POINTS_PER_FRAME as f64 * density * sum)
}
/// Cut-off to render the points scene with.
pub const POINTS_CUTOFF: f64 = 1e-5;
/// The default seed of the points.
pub const DEFAULT_SEED: u64 = 2024;

/// Frame times `t_k = k/29`.
#[must_use]
pub fn frame_times() -> Vec<f64> {
    (0..FRAMES)
        .map(|k| k as f64 / (FRAMES - 1) as f64)
        .collect()
}

/// The blob's centre at time `t`.
#[must_use]
pub fn path(t: f64) -> [f64; 3] {
    [t, t, t]
}

/// The continuous blob of SPEC §7.
#[must_use]
pub fn blob_scene() -> Scene {
    let kernel = Kernel {
        velocity: [1.0, 1.0, 1.0],
        ..Kernel::new(
            [0.5, 0.5, 0.5, 0.5],
            [0.1, 0.1, 0.1, 100.0],
            [1.0, 1.0, 1.0],
        )
    };
    Scene::from_kernels(&[kernel], [0.0; 3], "<blob>").expect("a valid kernel")
}

/// The points of every frame (seeded; the same points for the same seed on every machine).
#[must_use]
pub fn frame_points(seed: u64) -> Vec<Vec<[f64; 3]>> {
    let mut rng = seeded_rng(seed);
    let normal = Normal::new(0.0, NOISE_SIGMA).expect("a valid σ");
    frame_times()
        .iter()
        .map(|&t| {
            let c = path(t);
            (0..POINTS_PER_FRAME)
                .map(|_| std::array::from_fn(|a| c[a] + normal.sample(&mut rng)))
                .collect()
        })
        .collect()
}

/// The paper's point data as 30 000 kernels (see the module docs).
#[must_use]
pub fn points_scene(seed: u64) -> Scene {
    let dt = 1.0 / (FRAMES - 1) as f64;
    let times = frame_times();
    let amplitude = point_amplitude();
    let kernels: Vec<Kernel> = frame_points(seed)
        .iter()
        .zip(&times)
        .flat_map(|(points, &t)| {
            points.iter().map(move |p| {
                Kernel::new(
                    [p[0], p[1], p[2], t],
                    [POINT_SIGMA, POINT_SIGMA, POINT_SIGMA, dt],
                    [amplitude; 3],
                )
            })
        })
        .collect();
    Scene::from_kernels(&kernels, [0.0; 3], "<points>").expect("valid kernels")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn point_amplitude_matches_the_worked_value() {
        // S = 1 + 2 Σ_{j≥1} exp(-0.642687 j²) = 2.21095, 0.2^1.5 = 0.0894427.
        let worked = 1.0 / (1000.0 * 0.0894427191 * 2.21095);
        assert!(
            (point_amplitude() / worked - 1.0).abs() < 1e-5,
            "{}",
            point_amplitude()
        );
    }

    #[test]
    fn the_points_volume_peaks_near_1_on_the_path() {
        use crate::volume::{Grid, evaluate_volume};
        let scene = points_scene(DEFAULT_SEED);
        // A fine grid around c(0.5): the expected value there is 1; one draw of 30 000
        // points deviates by a few percent.
        let grid = Grid {
            min: [0.4; 3],
            max: [0.6; 3],
            res: 9,
        };
        let volume = evaluate_volume(&scene, 0.5, &grid, 0.0);
        let centre = volume.at(4, 4, 4);
        assert!((centre - 1.0).abs() < 0.1, "value at c(0.5): {centre}");
    }

    #[test]
    fn points_follow_the_path_with_the_stated_noise() {
        let frames = frame_points(DEFAULT_SEED);
        assert_eq!(frames.len(), 30);
        for (points, t) in frames.iter().zip(frame_times()) {
            assert_eq!(points.len(), 1000);
            for axis in 0..3 {
                let mean = points.iter().map(|p| p[axis]).sum::<f64>() / 1000.0;
                let var = points.iter().map(|p| (p[axis] - mean).powi(2)).sum::<f64>() / 999.0;
                // 1000 samples: the mean is within 4 standard errors (0.1/√1000), σ within 10%.
                assert!(
                    (mean - t).abs() < 4.0 * 0.1 / 1000f64.sqrt(),
                    "t = {t}: mean {mean}"
                );
                assert!((var.sqrt() - 0.1).abs() < 0.01, "t = {t}: σ {}", var.sqrt());
            }
        }
        assert_eq!(frame_points(DEFAULT_SEED), frames, "seeded");
        assert_ne!(frame_points(DEFAULT_SEED + 1), frames);
    }
}
