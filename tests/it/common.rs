//! Helpers shared by the integration tests: seeded hard scenes, the error bound, and the
//! executable run with a time limit.

use std::path::Path;
use std::process::{Command, Output};
use std::time::{Duration, Instant};

use rand::RngExt;
use splat4d::model::random::{log_uniform, random_rotation, seeded_rng};
use splat4d::reference::ReferenceImage;
use splat4d::{Camera, Image, Kernel, Scene};

/// Absolute part of the f32 bound: `|fast - ref| ≤ ATOL + RTOL Σ|a| + ε·(1 + 1e-2)·borderline`
/// ([`splat4d::reference::ERROR_BOUND`], `1e-6 + 2e-6·Σ|a|`, plus the cut-off band).
pub const ATOL: f64 = splat4d::reference::ERROR_BOUND.absolute;
/// Relative part of the bound, against the sum of |contributions| at the pixel.
pub const RTOL: f64 = splat4d::reference::ERROR_BOUND.relative;

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
                acceleration: [0.0; 3],
                angular_velocity: [0.0; 4],
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

/// Differentiable parameters per kernel.
pub const PARAMS: usize = 14;

/// Parameter names of one kernel, in the order of [`params`].
pub const PARAM_NAMES: [&str; PARAMS] = [
    "x", "y", "z", "t", "r", "g", "b", "vx", "vy", "vz", "sx", "sy", "sz", "st",
];

/// Mean (4), amplitude (3), velocity (3) and scale (4) as one row, the layout of [`params`].
fn flatten(m: [f64; 4], a: [f64; 3], v: [f64; 3], s: [f64; 4]) -> [f64; PARAMS] {
    [
        m[0], m[1], m[2], m[3], a[0], a[1], a[2], v[0], v[1], v[2], s[0], s[1], s[2], s[3],
    ]
}

/// The differentiable parameters of kernel `i`: mean (4), amplitude (3), velocity (3),
/// scale (4).
pub fn params(scene: &Scene, i: usize) -> [f64; PARAMS] {
    flatten(
        scene.means[i],
        scene.amplitudes[i],
        scene.velocities[i],
        scene.scales[i],
    )
}

fn set_param(scene: &mut Scene, i: usize, p: usize, value: f64) {
    match p {
        0..4 => scene.means[i][p] = value,
        4..7 => scene.amplitudes[i][p - 4] = value,
        7..10 => scene.velocities[i][p - 7] = value,
        _ => scene.scales[i][p - 10] = value,
    }
}

/// The gradient in the same layout as [`params`].
pub fn grad_of(grads: &splat4d::Gradients, i: usize) -> [f64; PARAMS] {
    flatten(
        grads.v_means[i],
        grads.v_amplitudes[i],
        grads.v_velocities[i],
        grads.v_scales[i],
    )
}

/// Central differences of the reference MSE against `target`, every kernel's pair set
/// frozen at the unperturbed scene (SPEC §6: the indicator is a constant): the image of
/// `scene` and what each kernel adds to it (`None` where it is culled).
pub struct FrozenDifferences<'a> {
    scene: &'a Scene,
    camera: &'a Camera,
    tau: f64,
    options: &'a splat4d::RenderOptions,
    target: &'a [f32],
    base: Vec<f64>,
    parts: Vec<Option<(Vec<f64>, splat4d::reference::PairMask)>>,
}

impl<'a> FrozenDifferences<'a> {
    /// The reference image of `scene` at `tau` and each kernel's part of it.
    pub fn new(
        scene: &'a Scene,
        (camera, tau, options): (&'a Camera, f64, &'a splat4d::RenderOptions),
        target: &'a [f32],
    ) -> Self {
        use splat4d::reference::{kernel_contribution, reference_kernel};
        let n_px = 3 * camera.pixel_count();
        let mut base: Vec<f64> = (0..n_px).map(|k| scene.background[k % 3]).collect();
        let parts = (0..scene.len())
            .map(|i| {
                let part = reference_kernel(scene, i, camera, tau, options)
                    .map(|k| kernel_contribution(&k, camera, None));
                if let Some((image, _)) = &part {
                    base.iter_mut().zip(image).for_each(|(b, c)| *b += c);
                }
                part
            })
            .collect();
        FrozenDifferences {
            scene,
            camera,
            tau,
            options,
            target,
            base,
            parts,
        }
    }

    /// `(L(θ + h) - L(θ - h)) / 2h` when `set(scene, θ ± h)` moves one parameter of kernel
    /// `i`; `None` where a step changes whether the kernel is culled.
    pub fn central(
        &self,
        i: usize,
        theta: f64,
        h: f64,
        set: impl Fn(&mut Scene, f64),
    ) -> Option<f64> {
        use splat4d::reference::{kernel_contribution, mse, reference_kernel};
        let mut losses = [0.0; 2];
        for (side, sign) in [1.0, -1.0].into_iter().enumerate() {
            let mut moved = self.scene.clone();
            set(&mut moved, theta + sign * h);
            let kernel = reference_kernel(&moved, i, self.camera, self.tau, self.options);
            let image: Vec<f64> = match (&self.parts[i], kernel) {
                (Some((old, mask)), Some(k)) => {
                    let (new, _) = kernel_contribution(&k, self.camera, Some(mask));
                    self.base
                        .iter()
                        .zip(old)
                        .zip(&new)
                        .map(|((b, o), n)| b - o + n)
                        .collect()
                }
                (None, None) => self.base.clone(),
                _ => return None,
            };
            losses[side] = mse(&image, self.target);
        }
        Some((losses[0] - losses[1]) / (2.0 * h))
    }
}

/// Central finite differences (f64) of the reference MSE against `target`, per kernel and
/// parameter, with every kernel's pair set frozen at the unperturbed scene (SPEC §6: the
/// indicator is a constant). `None` where a step changes whether the kernel is culled.
pub fn finite_difference_gradients(
    scene: &Scene,
    camera: &Camera,
    tau: f64,
    options: &splat4d::RenderOptions,
    target: &[f32],
) -> Vec<[Option<f64>; PARAMS]> {
    let differences = FrozenDifferences::new(scene, (camera, tau, options), target);
    let mut out = Vec::new();
    for i in 0..scene.len() {
        let mut row = [None; PARAMS];
        let theta = params(scene, i);
        for p in 0..PARAMS {
            // Steps follow the scale on which the loss varies: σt for the time mean, the
            // smallest spatial σ for the spatial mean, and that over |τ - t| for the velocity.
            let [sx, sy, sz, st] = scene.scales[i];
            let spatial = 1e-4 * sx.min(sy).min(sz).min(0.01);
            let h = match p {
                0..3 => spatial,
                3 => 1e-5 * st.min(1.0),
                4..7 => 1e-6 * theta[p].abs().max(1.0),
                7..10 => spatial / (tau - theta[3]).abs().clamp(1e-2, 1.0),
                // Scales: relative steps, large enough that the loss's rounding stays far
                // below a needle's small scale gradient (truncation is (h/s)² ~ 4e-8).
                _ => 2e-4 * theta[p],
            };
            row[p] =
                differences.central(i, theta[p], h, |moved, value| set_param(moved, i, p, value));
        }
        out.push(row);
    }
    out
}

/// A target image: the reference render of `scene` with jittered means and amplitudes.
pub fn jittered_target(
    scene: &Scene,
    camera: &Camera,
    tau: f64,
    options: &splat4d::RenderOptions,
    seed: u64,
) -> Vec<f32> {
    let mut rng = seeded_rng(seed);
    let mut moved = scene.clone();
    for i in 0..moved.len() {
        for c in 0..3 {
            moved.means[i][c] += rng.random_range(-0.03..0.03);
            moved.amplitudes[i][c] *= rng.random_range(0.7..1.1);
        }
    }
    let image = splat4d::reference::render_reference(&moved, camera, tau, options);
    image.pixels.iter().map(|&v| v as f32).collect()
}

/// Folder of the shared reference case `name` (`tests/data/reference/NAME`).
pub fn reference_case_dir(name: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/reference")
        .join(name)
}

/// The scene, camera and time of the shared reference case `name`.
pub fn reference_case(name: &str) -> (Scene, Camera, f64) {
    let dir = reference_case_dir(name);
    let scene = splat4d::io::scene_file::load_scene(&dir.join("scene.json")).unwrap();
    let camera = splat4d::io::camera_file::load_camera(&dir.join("camera.json")).unwrap();
    let tau = std::fs::read_to_string(dir.join("tau.txt"))
        .unwrap()
        .trim()
        .parse()
        .unwrap();
    (scene, camera, tau)
}

/// The fast MSE and gradients of `scene` against `target` (the library's own path).
pub fn fast_gradients(
    scene: &Scene,
    camera: &Camera,
    tau: f64,
    options: &splat4d::RenderOptions,
    target: &Image,
) -> (f64, splat4d::Gradients) {
    let mut grads = splat4d::Gradients::zeros(scene.len());
    let loss = splat4d::fit::loss::view_loss_and_gradients(
        &mut splat4d::RenderContext::new(),
        scene,
        camera,
        tau,
        options,
        target,
        &mut grads,
    )
    .unwrap();
    (loss, grads)
}

/// Runs the `splat4d` executable in `cwd`.
pub fn splat4d(args: &[&str], cwd: &std::path::Path) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_splat4d"))
        .args(args)
        .current_dir(cwd)
        .output()
        .expect("the executable runs")
}

/// A command's stderr as text.
pub fn stderr(output: &std::process::Output) -> String {
    String::from_utf8_lossy(&output.stderr).into_owned()
}

/// A shipped fixture in `data/`.
pub fn data(name: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("data")
        .join(name)
}

/// Runs the executable with a time limit (a hang is a failure, not a stuck test).
pub fn run_limited<S: AsRef<std::ffi::OsStr> + std::fmt::Debug>(args: &[S], cwd: &Path) -> Output {
    run_limited_with_env(args, cwd, &[])
}

/// [`run_limited`] with environment variables set for the child.
pub fn run_limited_with_env<S: AsRef<std::ffi::OsStr> + std::fmt::Debug>(
    args: &[S],
    cwd: &Path,
    env: &[(&str, &str)],
) -> Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_splat4d"))
        .args(args)
        .envs(env.iter().copied())
        .current_dir(cwd)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if start.elapsed() > Duration::from_secs(20) {
            child.kill().unwrap();
            panic!("{args:?} ran for more than 20 s");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    child.wait_with_output().unwrap()
}

/// Runs `splat4d dataset` on the blob (`views` cameras × 2 times, 8×8) into `dir/out`.
pub fn run_blob_dataset(dir: &Path, views: &str, out: &str) -> std::process::Output {
    let blob = data("blob.json");
    let args = [
        "dataset",
        "--scene",
        blob.to_str().unwrap(),
        "--views",
        views,
        "--times",
        "2",
        "--size",
        "8x8",
        "--out",
        out,
    ];
    run_limited(&args, dir)
}

/// Renders the blob as a small dataset (`views` cameras × 2 times, 8×8) into `dir/ds`.
pub fn blob_dataset(dir: &Path, views: &str) {
    let output = run_blob_dataset(dir, views, "ds");
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
}

/// Runs the executable (with the time limit of [`run_limited`]) and asserts that it ends
/// with status `code`, a message containing `needle` and no panic.
pub fn refused_quickly<S: AsRef<std::ffi::OsStr> + std::fmt::Debug>(
    args: &[S],
    cwd: &Path,
    code: i32,
    needle: &str,
) {
    let output = run_limited(args, cwd);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(code), "{args:?}: {stderr}");
    assert!(stderr.contains(needle), "{args:?}: {stderr}");
    assert!(!stderr.contains("panicked"), "{args:?}: {stderr}");
}

/// The pairs per second `splat4d bench` printed for `probe` (`ceiling probe`, `alpha ceiling
/// probe`) on `threads` threads: its line `<probe> (<path> path, <threads> thread[s]): <rate>
/// pairs/s`.
pub fn probe_rate(stdout: &str, probe: &str, threads: usize) -> f64 {
    let threads = format!(", {threads} thread");
    stdout
        .lines()
        .find(|l| l.starts_with(&format!("{probe} (")) && l.contains(&threads))
        .and_then(|l| l.split("): ").nth(1))
        .and_then(|r| r.split_whitespace().next())
        .and_then(|r| r.parse().ok())
        .unwrap_or_else(|| panic!("no {probe} line for{threads}: {stdout}"))
}

/// Runs `work` on a fresh pool of `threads` worker threads.
pub fn on_threads<R: Send>(threads: usize, work: impl FnOnce() -> R + Send) -> R {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap()
        .install(work)
}
