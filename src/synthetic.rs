//! Seeded synthetic scenes and cameras for tests, benches and demos.
//!
//! Randomness is ChaCha8 seeded from a `u64`, so a seed names the same scene on every
//! machine and with every thread count.

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::camera::Camera;
use crate::scene::{Kernel, Scene};

/// The project's seeded generator.
#[must_use]
pub fn seeded_rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

/// A uniformly distributed unit quaternion `[w, x, y, z]` (Shoemake's method).
pub fn random_rotation(rng: &mut ChaCha8Rng) -> [f64; 4] {
    let (u1, u2, u3): (f64, f64, f64) = (rng.random(), rng.random(), rng.random());
    let tau = std::f64::consts::TAU;
    let (a, b) = ((1.0 - u1).sqrt(), u1.sqrt());
    [
        b * (tau * u3).cos(),
        a * (tau * u2).sin(),
        a * (tau * u2).cos(),
        b * (tau * u3).sin(),
    ]
}

/// A value whose logarithm is uniform in `[ln lo, ln hi)`.
pub fn log_uniform(rng: &mut ChaCha8Rng, lo: f64, hi: f64) -> f64 {
    (rng.random_range(lo.ln()..hi.ln())).exp()
}

/// A scene of `n` kernels in the cube `[-1, 1]³ × [0, 1]` with a realistic spread of sizes
/// (spatial σ log-uniform in [0.003, 0.1], so from sub-pixel to tens of pixels through
/// [`bench_camera`]), random rotations, small velocities and amplitudes in [0.02, 0.3].
#[must_use]
pub fn bench_scene(n: usize, seed: u64) -> Scene {
    let mut rng = seeded_rng(seed);
    let kernels: Vec<Kernel> = (0..n)
        .map(|_| {
            let mean = [
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(0.0..1.0),
            ];
            let scale = [
                log_uniform(&mut rng, 0.003, 0.1),
                log_uniform(&mut rng, 0.003, 0.1),
                log_uniform(&mut rng, 0.003, 0.1),
                rng.random_range(0.2..1.0),
            ];
            let amplitude = [
                rng.random_range(0.02..0.3),
                rng.random_range(0.02..0.3),
                rng.random_range(0.02..0.3),
            ];
            Kernel {
                mean,
                scale,
                amplitude,
                rotation: random_rotation(&mut rng),
                velocity: [
                    rng.random_range(-0.2..0.2),
                    rng.random_range(-0.2..0.2),
                    rng.random_range(-0.2..0.2),
                ],
            }
        })
        .collect();
    Scene::from_kernels(&kernels, [0.0; 3], "<bench scene>").expect("generated kernels are valid")
}

/// A camera 3.5 units from the origin framing [`bench_scene`]'s cube, 50° vertical field of view.
#[must_use]
pub fn bench_camera(width: u32, height: u32) -> Camera {
    Camera::look_at(
        [2.0, 1.2, 2.6],
        [0.0; 3],
        [0.0, 1.0, 0.0],
        50.0,
        width,
        height,
    )
    .expect("a valid look-at")
}
