//! Each fast stage against its f64 twin in `splat4d::reference`, one stage at a time and on
//! the same input, so a wrong stage is named by the test that fails rather than found only
//! in whole images:
//!
//! | stage | fast | twin | tolerance |
//! |---|---|---|---|
//! | slice (SPEC §2) | `slice::slice` | `reference_slice` | same kernels; `m`, `Σ3`, `a(τ)`, `qmax` within 1e-12 relative |
//! | project (SPEC §4) | `project::project` | `reference_project` on the fast slice | same kernels; `m2` within 1e-9 px + 1e-12 relative, `Q` within 1e-9 of its largest entry |
//! | slice and project in one pass | `project::slice_and_project` | `slice` then `project` | the same bits |
//! | tiles + raster (SPEC §5) | `RenderContext` | the f64 per-pixel sum over the fast projection | the f32 bound `1e-6 + 2e-6 Σ|a|`, band pairs excepted |
//!
//! Scenes are the seeded hard scenes of `common` (rotations, velocities, negative
//! amplitudes, kernels behind, straddling and beside the camera).

use glam::{DMat3, DVec3};
use splat4d::project::{
    ProjectedKernels, project, slice_and_project, slice_candidates_and_project,
};
use splat4d::reference::{ReferenceSlice, is_borderline, reference_project, reference_slice};
use splat4d::render::DEFAULT_CUTOFF;
use splat4d::slice::{SlicedKernels, TemporalIndex, slice};
use splat4d::{RenderContext, RenderOptions};

use crate::common::{ATOL, RTOL, hard_random_scene, test_camera};

const CASES: [(f64, f64); 4] = [
    (DEFAULT_CUTOFF, 0.3),
    (0.0, 0.3),
    (0.05, 0.0),
    (DEFAULT_CUTOFF, 0.0),
];

fn close(a: f64, b: f64, rel: f64, scale: f64) -> bool {
    (a - b).abs() <= rel * scale.max(a.abs()).max(b.abs())
}

/// `Σ3` of the fast slice as a matrix.
fn matrix([xx, xy, xz, yy, yz, zz]: [f64; 6]) -> DMat3 {
    DMat3::from_cols_array_2d(&[[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
}

#[test]
fn slice_matches_its_twin() {
    let camera = test_camera(64, 48);
    let mut sliced = SlicedKernels::default();
    let mut compared = 0;
    for seed in 0..4 {
        let scene = hard_random_scene(&camera, seed, 300);
        for (cutoff, _) in CASES {
            for tau in [-0.5, 0.0, 0.37, 1.0, 3.0] {
                slice(&scene, tau, cutoff, &mut sliced);
                let twins: Vec<ReferenceSlice> = (0..scene.len())
                    .filter_map(|i| reference_slice(&scene, i, tau, cutoff))
                    .collect();
                let what = format!("seed {seed}, ε {cutoff}, τ {tau}");
                let indices: Vec<u32> = twins.iter().map(|t| t.index as u32).collect();
                assert_eq!(
                    sliced.kernel_from_slice, indices,
                    "{what}: the kernels alive"
                );
                for (s, twin) in twins.iter().enumerate() {
                    let k = twin.index;
                    let scale = twin
                        .covariance
                        .to_cols_array()
                        .iter()
                        .fold(0.0, |m: f64, v| m.max(v.abs()));
                    let fast_cov = matrix(sliced.covariances[s]).to_cols_array();
                    for (a, b) in fast_cov.iter().zip(twin.covariance.to_cols_array()) {
                        assert!(
                            close(*a, b, 1e-12, scale),
                            "{what}, kernel {k}: Σ3 {a} vs {b}"
                        );
                    }
                    let mean_scale = twin.mean.abs().max_element();
                    for (a, b) in sliced.means[s].iter().zip(twin.mean.to_array()) {
                        assert!(
                            close(*a, b, 1e-12, mean_scale),
                            "{what}, kernel {k}: m {a} vs {b}"
                        );
                    }
                    for (a, b) in sliced.amplitudes[s].iter().zip(twin.amplitude) {
                        assert!(
                            close(*a, b, 1e-12, 0.0),
                            "{what}, kernel {k}: a(τ) {a} vs {b}"
                        );
                    }
                    let (a, b) = (sliced.qmax[s], twin.qmax);
                    assert!(
                        a == b || close(a, b, 1e-12, 1.0),
                        "{what}, kernel {k}: qmax {a} vs {b}"
                    );
                    compared += 1;
                }
            }
        }
    }
    assert!(compared > 10_000, "only {compared} kernels compared");
}

#[test]
fn project_matches_its_twin_on_the_same_slice() {
    let camera = test_camera(64, 48);
    let mut sliced = SlicedKernels::default();
    let mut projected = ProjectedKernels::default();
    let mut compared = 0;
    for seed in 0..4 {
        let scene = hard_random_scene(&camera, seed, 300);
        for (cutoff, dilation) in CASES {
            let tau = 0.5;
            slice(&scene, tau, cutoff, &mut sliced);
            project(&sliced, &camera, dilation, &mut projected);
            // The twin projects exactly what the fast slice produced.
            let twins: Vec<_> = (0..sliced.len())
                .filter_map(|s| {
                    let input = ReferenceSlice {
                        index: sliced.kernel_from_slice[s] as usize,
                        mean: DVec3::from(sliced.means[s]),
                        covariance: matrix(sliced.covariances[s]),
                        amplitude: sliced.amplitudes[s],
                        opacity: 0.0,
                        qmax: sliced.qmax[s],
                        weight: 1.0,
                        d: 0.0,
                    };
                    reference_project(&input, &camera, dilation)
                })
                .collect();
            let what = format!("seed {seed}, ε {cutoff}, dilation {dilation}");
            let indices: Vec<u32> = twins.iter().map(|t| t.index as u32).collect();
            assert_eq!(
                projected.kernel_from_proj, indices,
                "{what}: the kernels on screen"
            );
            for (p, twin) in twins.iter().enumerate() {
                let k = twin.index;
                for (a, b) in projected.means[p].iter().zip(twin.mean) {
                    assert!(
                        (a - b).abs() <= 1e-9 + 1e-12 * b.abs(),
                        "{what}, kernel {k}: m2 {a} vs {b}"
                    );
                }
                let [xx, xy, yy] = projected.conics[p];
                let reference = [twin.conic[0][0], twin.conic[0][1], twin.conic[1][1]];
                let scale = reference.iter().fold(0.0, |m: f64, v| m.max(v.abs()));
                for (a, b) in [xx, xy, yy].iter().zip(reference) {
                    assert!(
                        close(*a, b, 1e-9, scale),
                        "{what}, kernel {k}: Q {a} vs {b}"
                    );
                }
                assert_eq!(projected.qmax[p], twin.qmax, "{what}, kernel {k}: qmax");
                compared += 1;
            }
        }
    }
    assert!(compared > 1_000, "only {compared} kernels compared");
}

/// Every column `slice_and_project` writes, as bits, for comparing passes.
fn projection_bits(p: &ProjectedKernels) -> Vec<Vec<u64>> {
    let f64s = |values: Vec<f64>| values.into_iter().map(f64::to_bits).collect::<Vec<_>>();
    vec![
        p.kernel_from_proj.iter().map(|&k| u64::from(k)).collect(),
        f64s(p.means.iter().flatten().copied().collect()),
        f64s(p.covariances.iter().flatten().copied().collect()),
        f64s(p.conics.iter().flatten().copied().collect()),
        f64s(p.qmax.clone()),
        f64s(p.radii.iter().flatten().copied().collect()),
        p.amplitudes
            .iter()
            .flatten()
            .map(|&a| u64::from(a.to_bits()))
            .collect(),
    ]
}

#[test]
fn slice_and_project_in_one_pass_give_the_two_stages_bits() {
    let camera = test_camera(64, 48);
    let mut sliced = SlicedKernels::default();
    let (mut apart, mut together) = (ProjectedKernels::default(), ProjectedKernels::default());
    let mut compared = 0;
    for seed in 0..4 {
        // 3000 kernels: several chunks of the parallel pass.
        let scene = hard_random_scene(&camera, seed, 3000);
        for (cutoff, dilation) in CASES {
            for tau in [0.1, 0.5, 0.93] {
                slice(&scene, tau, cutoff, &mut sliced);
                project(&sliced, &camera, dilation, &mut apart);
                let expected = projection_bits(&apart);
                for threads in [1, 2, 3] {
                    let pool = rayon::ThreadPoolBuilder::new()
                        .num_threads(threads)
                        .build()
                        .unwrap();
                    let alive = pool.install(|| {
                        slice_and_project(&scene, (tau, cutoff), &camera, dilation, &mut together)
                    });
                    assert_eq!(alive, sliced.len(), "seed {seed}, τ {tau}");
                    assert_eq!(projection_bits(&together), expected, "seed {seed}, τ {tau}");
                }
                let index = TemporalIndex::new(&scene, cutoff);
                let mut candidates = Vec::new();
                index.candidates(tau, &mut candidates);
                let alive = slice_candidates_and_project(
                    &scene,
                    &candidates,
                    (tau, cutoff),
                    &camera,
                    dilation,
                    &mut together,
                );
                assert_eq!(alive, sliced.len());
                assert_eq!(projection_bits(&together), expected, "indexed, seed {seed}");
                compared += apart.len();
            }
        }
    }
    assert!(compared > 10_000, "{compared} projections compared");
}

#[test]
fn tiles_and_raster_match_the_f64_sum_over_the_same_projection() {
    let camera = test_camera(80, 60);
    let mut context = RenderContext::new();
    let mut sliced = SlicedKernels::default();
    let mut projected = ProjectedKernels::default();
    let mut compared = 0;
    for seed in 0..3 {
        let scene = hard_random_scene(&camera, seed, 250);
        for (cutoff, dilation) in CASES {
            let options = RenderOptions {
                cutoff,
                dilation,
                ..RenderOptions::default()
            };
            let tau = 0.5;
            context.render(&scene, &camera, tau, &options).unwrap();
            slice(&scene, tau, cutoff, &mut sliced);
            project(&sliced, &camera, dilation, &mut projected);
            let image = context.image();
            for j in 0..camera.height {
                for i in 0..camera.width {
                    let (px, py) = (f64::from(i) + 0.5, f64::from(j) + 0.5);
                    let mut sum = scene.background;
                    let mut abs_sum = scene.background.map(f64::abs);
                    let mut band = 0;
                    for p in 0..projected.len() {
                        let [mx, my] = projected.means[p];
                        let [qxx, qxy, qyy] = projected.conics[p];
                        let (dx, dy) = (px - mx, py - my);
                        let q = qxx * dx * dx + 2.0 * qxy * dx * dy + qyy * dy * dy;
                        let qmax = projected.qmax[p];
                        band += u32::from(is_borderline(q, qmax));
                        if q <= qmax {
                            let g = (-0.5 * q).exp();
                            for c in 0..3 {
                                let term = f64::from(projected.amplitudes[p][c]) * g;
                                sum[c] += term;
                                abs_sum[c] += term.abs();
                            }
                        }
                    }
                    let fast = image.pixel(i, j);
                    for c in 0..3 {
                        let bound = ATOL + RTOL * abs_sum[c] + 1.01 * cutoff * f64::from(band);
                        let error = (f64::from(fast[c]) - sum[c]).abs();
                        assert!(
                            error <= bound,
                            "seed {seed}, ε {cutoff}, dilation {dilation}, pixel ({i}, {j}), channel {c}: {} vs {} (bound {bound})",
                            fast[c],
                            sum[c]
                        );
                    }
                    compared += 1;
                }
            }
        }
    }
    assert!(compared > 50_000, "only {compared} pixels compared");
}
