//! Helpers shared by the integration tests: seeded hard scenes and the error bound.
#![allow(dead_code)]

use rand::RngExt;
use splat4d::reference::ReferenceImage;
use splat4d::synthetic::{log_uniform, random_rotation, seeded_rng};
use splat4d::{Camera, Image, Kernel, Scene};

/// Absolute part of the f32 bound: `|fast - ref| ≤ ATOL + RTOL Σ|a| + ε·(1 + 1e-2)·borderline`.
pub const ATOL: f64 = 1e-6;
/// Relative part of the bound, against the sum of |contributions| at the pixel.
pub const RTOL: f64 = 2e-6;

/// A camera with an off-centre principal point and unequal focal lengths.
pub fn test_camera(width: u32, height: u32) -> Camera {
    let mut camera = Camera::look_at(
        [0.3, -0.4, -4.0],
        [0.0, 0.1, 0.0],
        [0.0, 1.0, 0.0],
        50.0,
        width,
        height,
    )
    .unwrap();
    camera.fx *= 1.1;
    camera.cx += 3.7;
    camera.cy -= 2.2;
    camera.validate("<test camera>").unwrap();
    camera
}

/// World point of camera-space point `p` (for an orthonormal `Rc`).
pub fn world_from_camera(camera: &Camera, p: [f64; 3]) -> [f64; 3] {
    let r = camera.rotation();
    let t = camera.translation();
    let d = [p[0] - t[0], p[1] - t[1], p[2] - t[2]];
    std::array::from_fn(|c| (0..3).map(|k| r[k][c] * d[k]).sum())
}

/// Hundreds of kernels: random rotations, velocities and signs of amplitude, plus kernels
/// near, behind and straddling the camera and near and beyond the frustum's edges.
pub fn hard_random_scene(camera: &Camera, seed: u64, general: usize) -> Scene {
    let mut rng = seeded_rng(seed);
    let mut kernels = Vec::new();
    let tau_range = 0.0..1.0;
    let kernel_at =
        |rng: &mut rand_chacha::ChaCha8Rng, world: [f64; 3], scale_lo: f64, scale_hi: f64| {
            let t = rng.random_range(tau_range.clone());
            let velocity = [
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            ];
            // Place the slice centre at τ = 0.5 on `world`.
            let dt = 0.5 - t;
            Kernel {
                mean: [
                    world[0] - velocity[0] * dt,
                    world[1] - velocity[1] * dt,
                    world[2] - velocity[2] * dt,
                    t,
                ],
                scale: [
                    log_uniform(rng, scale_lo, scale_hi),
                    log_uniform(rng, scale_lo, scale_hi),
                    log_uniform(rng, scale_lo, scale_hi),
                    log_uniform(rng, 0.05, 2.0),
                ],
                amplitude: [
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                ],
                rotation: random_rotation(rng),
                velocity,
            }
        };
    for _ in 0..general {
        let w = [
            rng.random_range(-1.5..1.5),
            rng.random_range(-1.5..1.5),
            rng.random_range(-1.5..1.5),
        ];
        kernels.push(kernel_at(&mut rng, w, 0.01, 0.5));
    }
    let frustum_point = |rng: &mut rand_chacha::ChaCha8Rng, z: f64, spread: f64| {
        let u = rng.random_range(-spread..spread) * f64::from(camera.width) / camera.fx;
        let v = rng.random_range(-spread..spread) * f64::from(camera.height) / camera.fy;
        [u * z, v * z, z]
    };
    // Near the camera: huge ellipses.
    for _ in 0..20 {
        let z = rng.random_range(0.02..0.6);
        let p = frustum_point(&mut rng, z, 0.6);
        kernels.push(kernel_at(&mut rng, world_from_camera(camera, p), 0.01, 0.2));
    }
    // Behind the camera.
    for _ in 0..20 {
        let z = rng.random_range(-2.0..-0.001);
        let p = frustum_point(&mut rng, z, 0.6);
        kernels.push(kernel_at(&mut rng, world_from_camera(camera, p), 0.05, 0.5));
    }
    // Straddling the near plane.
    for _ in 0..20 {
        let z = camera.near + rng.random_range(-0.01..0.01);
        let p = frustum_point(&mut rng, z.max(1e-4), 0.5);
        kernels.push(kernel_at(&mut rng, world_from_camera(camera, p), 0.05, 0.5));
    }
    // Near and beyond the frustum's edges: x/z or y/z around the clamp limits.
    for _ in 0..60 {
        let z = rng.random_range(1.0..6.0);
        let p = frustum_point(&mut rng, z, 1.2);
        kernels.push(kernel_at(&mut rng, world_from_camera(camera, p), 0.05, 1.0));
    }
    Scene::from_kernels(&kernels, [0.1, -0.05, 0.0], "<hard random scene>").unwrap()
}

/// Worst ratio of `|fast - ref|` to the allowed bound over all pixels and channels (≤ 1
/// passes), and where it is.
pub fn worst_ratio(fast: &Image, reference: &ReferenceImage, cutoff: f64) -> (f64, usize) {
    assert_eq!(
        (fast.width, fast.height),
        (reference.width, reference.height)
    );
    let mut worst = (0.0, 0);
    for k in 0..fast.pixels.len() {
        let bound = ATOL
            + RTOL * reference.abs_sum[k]
            + cutoff * 1.01 * f64::from(reference.borderline[k / 3]);
        let ratio = (f64::from(fast.pixels[k]) - reference.pixels[k]).abs() / bound;
        // A NaN anywhere is the worst possible result.
        let ratio = if ratio.is_nan() { f64::INFINITY } else { ratio };
        if ratio > worst.0 {
            worst = (ratio, k);
        }
    }
    worst
}

/// Panics with the pixel, channel and |Δ| unless `fast` is within the bound of `reference`.
pub fn assert_within_bound(fast: &Image, reference: &ReferenceImage, cutoff: f64, what: &str) {
    let (ratio, k) = worst_ratio(fast, reference, cutoff);
    let (pixel, channel) = (k / 3, k % 3);
    assert!(
        ratio <= 1.0,
        "{what}: pixel ({}, {}) channel {channel}: fast {} vs reference {} (|Δ| = {:e}, Σ|a| = {:e}, {} borderline pairs) is {ratio:.2}× the bound",
        pixel % fast.width as usize,
        pixel / fast.width as usize,
        fast.pixels[k],
        reference.pixels[k],
        (f64::from(fast.pixels[k]) - reference.pixels[k]).abs(),
        reference.abs_sum[k],
        reference.borderline[pixel]
    );
}
