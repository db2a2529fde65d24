//! Seeded synthetic scenes and cameras for tests, benches and demos.
//!
//! Randomness is ChaCha8 seeded from a `u64`, so a seed names the same scene on every
//! machine and with every thread count.

use rand::RngExt;
use rand_chacha::ChaCha8Rng;

use crate::model::random::{log_uniform, random_rotation, seeded_rng};
use crate::model::{Error, Result};
use crate::scenes::paths::{Lens, framing_distance};

use crate::model::camera::Camera;
use crate::model::scene::{Kernel, Scene};

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
                acceleration: [0.0; 3],
                angular_velocity: [0.0; 4],
            }
        })
        .collect();
    Scene::from_kernels(&kernels, [0.0; 3], "<bench scene>").expect("generated kernels are valid")
}

/// [`bench_scene`]'s kernels spread over `duration` time units instead of one, with σt in
/// [0.2, 0.4]: at any time about 1.3/`duration` of them are alive under ε = 1/255 (1% for a
/// duration of 130), for benching the cost of a frame against the kernels alive.
#[must_use]
pub fn bench_scene_in_time(n: usize, seed: u64, duration: f64) -> Scene {
    let mut scene = bench_scene(n, seed);
    let mut rng = seeded_rng(seed ^ 0x5eed);
    for (mean, scale) in scene.means.iter_mut().zip(&mut scene.scales) {
        mean[3] *= duration;
        scale[3] = rng.random_range(0.2..0.4);
    }
    scene
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

/// The sphere that holds every kernel's slice centre at `times`, widened by 3 of its
/// largest spatial σ: `(centre, radius)`.
#[must_use]
pub fn bounding_sphere(scene: &Scene, times: &[f64]) -> ([f64; 3], f64) {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    let centres = |i: usize| {
        times.iter().map(move |&tau| {
            let dt = tau - scene.means[i][3];
            std::array::from_fn::<f64, 3, _>(|c| scene.means[i][c] + scene.velocities[i][c] * dt)
        })
    };
    for i in 0..scene.len() {
        for m in centres(i) {
            for c in 0..3 {
                lo[c] = lo[c].min(m[c]);
                hi[c] = hi[c].max(m[c]);
            }
        }
    }
    if scene.is_empty() {
        return ([0.0; 3], 1.0);
    }
    let centre: [f64; 3] = std::array::from_fn(|c| 0.5 * (lo[c] + hi[c]));
    let mut radius: f64 = 0.0;
    for i in 0..scene.len() {
        let sigma = scene.scales[i][..3].iter().cloned().fold(0.0, f64::max);
        for m in centres(i) {
            let d = (0..3)
                .map(|c| (m[c] - centre[c]).powi(2))
                .sum::<f64>()
                .sqrt();
            radius = radius.max(d + 3.0 * sigma);
        }
    }
    (centre, radius)
}

/// Tries per camera before [`sphere_cameras`] gives up.
pub const MAX_CAMERA_TRIES: usize = 100;

/// `n` seeded cameras on a sphere around `centre`, each looking at it with +y up, far enough
/// for a ball of `radius` to fill its `fov_y_degrees` with a 5% margin. Directions are
/// uniform over the sphere away from the poles (|y| < 0.9 of the distance). An error when
/// no camera can be placed (a degenerate field of view, size or sphere), after
/// [`MAX_CAMERA_TRIES`] tries per camera.
pub fn sphere_cameras(
    centre: [f64; 3],
    radius: f64,
    n: usize,
    fov_y_degrees: f64,
    width: u32,
    height: u32,
    rng: &mut ChaCha8Rng,
) -> Result<Vec<Camera>> {
    let lens = Lens {
        width,
        height,
        fov_y_degrees,
    };
    let distance = framing_distance(radius, &lens);
    let mut cameras = Vec::with_capacity(n.min(1 << 12));
    let mut tries = 0_usize;
    while cameras.len() < n {
        tries += 1;
        if tries > MAX_CAMERA_TRIES.saturating_mul(n) {
            return Err(Error::usage(format!(
                "cannot place cameras around ({:?}, radius {radius}) with a {fov_y_degrees}° field of view at {width}×{height}",
                centre
            )));
        }
        let y: f64 = rng.random_range(-0.9..0.9);
        let phi: f64 = rng.random_range(0.0..std::f64::consts::TAU);
        let r = (1.0 - y * y).sqrt();
        let dir = [r * phi.cos(), y, r * phi.sin()];
        let eye = std::array::from_fn(|c| centre[c] + distance * dir[c]);
        if let Ok(camera) =
            Camera::look_at(eye, centre, [0.0, 1.0, 0.0], fov_y_degrees, width, height)
        {
            cameras.push(camera);
        }
    }
    Ok(cameras)
}

/// [`bench_scene`] as an alpha scene (SPEC §8) whose opacities vary over `[low, 1]` with the
/// kernel index (no SH): the scene the SIMD-path tests of the compositor use.
#[must_use]
pub fn varied_alpha_bench_scene(n: usize, seed: u64, low: f64) -> Scene {
    bench_scene(n, seed)
        .into_alpha(
            (0..n)
                .map(|i| (low + (1.0 - low) * ((i * 53) % 97) as f64 / 96.0).min(1.0))
                .collect(),
            0,
            Vec::new(),
            "<varied alpha bench scene>",
        )
        .expect("bench kernels and opacities in [0, 1] make a valid alpha scene")
}
