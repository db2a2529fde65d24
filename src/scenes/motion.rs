//! A scene of non-linear motion for fitting tests and the report: three blobs over
//! τ ∈ [0, 1],
//!
//! 1. one of σ 0.08 circling once around (0, 0, 0) in the x–z plane at radius 0.5;
//! 2. one static and elongated, σ (0.25, 0.05, 0.05) turned 30° about z, at (0, 0.6, 0);
//! 3. one of σ 0.08 fading in (weight `exp(-½ ((τ - 1)/0.5)²)`) while it moves in a line
//!    from (-0.5, -0.5, 0.3) to (0.5, -0.5, 0.3).
//!
//! The circling blob is drawn by [`CIRCLE_SAMPLES`] velocity kernels along its path, each
//! moving with the path's tangent, whose temporal weights overlap so they sum to 1 within
//! 0.1% over the range: a continuous object no small set of linear-motion kernels
//! represents exactly.

use crate::model::{Kernel, Scene};

/// Kernels drawing the circling blob.
pub const CIRCLE_SAMPLES: usize = 96;

/// The three-blob scene.
#[must_use]
pub fn three_blobs_scene() -> Scene {
    let tau = std::f64::consts::TAU;
    let spacing = 1.0 / CIRCLE_SAMPLES as f64;
    // Gaussians of σt = spacing, one every `spacing`: their sum is √(2π) times one.
    let amplitude = 1.0 / (2.0 * std::f64::consts::PI).sqrt();
    let mut kernels: Vec<Kernel> = (-3..CIRCLE_SAMPLES as i64 + 4)
        .map(|k| {
            let t = (k as f64 + 0.5) * spacing;
            let angle = tau * t;
            Kernel {
                mean: [0.5 * angle.cos(), 0.0, 0.5 * angle.sin(), t],
                scale: [0.08, 0.08, 0.08, spacing],
                amplitude: [amplitude, 0.8 * amplitude, 0.6 * amplitude],
                rotation: [1.0, 0.0, 0.0, 0.0],
                velocity: [-0.5 * tau * angle.sin(), 0.0, 0.5 * tau * angle.cos()],
                acceleration: [0.0; 3],
                angular_velocity: [0.0; 4],
            }
        })
        .collect();
    let half = 15f64.to_radians();
    kernels.push(Kernel {
        mean: [0.0, 0.6, 0.0, 0.5],
        scale: [0.25, 0.05, 0.05, 100.0],
        amplitude: [0.4, 0.9, 0.5],
        rotation: [half.cos(), 0.0, 0.0, half.sin()],
        velocity: [0.0; 3],
        acceleration: [0.0; 3],
        angular_velocity: [0.0; 4],
    });
    kernels.push(Kernel {
        mean: [0.5, -0.5, 0.3, 1.0],
        scale: [0.08, 0.08, 0.08, 0.5],
        amplitude: [0.5, 0.6, 1.0],
        rotation: [1.0, 0.0, 0.0, 0.0],
        velocity: [1.0, 0.0, 0.0],
        acceleration: [0.0; 3],
        angular_velocity: [0.0; 4],
    });
    Scene::from_kernels(&kernels, [0.0; 3], "<three blobs>").expect("valid kernels")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::slice::{SlicedKernels, slice};

    #[test]
    fn the_circling_blob_keeps_its_brightness_and_follows_the_circle() {
        let scene = three_blobs_scene();
        let mut sliced = SlicedKernels::default();
        for k in 0..=40 {
            let tau = f64::from(k) / 40.0;
            slice(&scene, tau, 0.0, &mut sliced);
            let circle = 0..scene.len() - 2;
            let (mut weight, mut centre) = (0.0, [0.0; 3]);
            for s in 0..sliced.len() {
                if circle.contains(&(sliced.kernel_from_slice[s] as usize)) {
                    let w = sliced.amplitudes[s][0];
                    weight += w;
                    for (sum, m) in centre.iter_mut().zip(sliced.means[s]) {
                        *sum += w * m;
                    }
                }
            }
            assert!((weight - 1.0).abs() < 1e-3, "τ {tau}: weight {weight}");
            let angle = std::f64::consts::TAU * tau;
            let expected = [0.5 * angle.cos(), 0.0, 0.5 * angle.sin()];
            for c in 0..3 {
                assert!(
                    (centre[c] / weight - expected[c]).abs() < 2e-3,
                    "τ {tau}: {centre:?}"
                );
            }
        }
    }
}
