//! The Eq. 1 volume on a grid agrees with its dense f64 twin, whatever the threads.

use crate::common::{hard_random_scene, test_camera};
use splat4d::volume::{Grid, evaluate_volume, evaluate_volume_reference, scene_bounds};

#[test]
fn volume_matches_the_dense_reference_with_and_without_truncation() {
    let scene = hard_random_scene(&test_camera(32, 32), 4, 60);
    for cutoff in [1e-3, 0.0] {
        let (min, max) = scene_bounds(&scene, &[0.5], cutoff).unwrap();
        let grid = Grid { min, max, res: 24 };
        let fast = evaluate_volume(&scene, 0.5, &grid, cutoff);
        let reference = evaluate_volume_reference(&scene, 0.5, &grid, cutoff);
        let scale = reference.iter().map(|v| v.abs()).fold(0.0, f64::max);
        assert!(scale > 0.1);
        for (k, (f, r)) in fast.values.iter().zip(&reference).enumerate() {
            // f32 sums of at most a few hundred terms of size ≤ scale.
            assert!(
                (f64::from(*f) - r).abs() <= 1e-5 * scale,
                "cut-off {cutoff}, cell {k}: {f} vs {r}"
            );
        }
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        let single = pool.install(|| evaluate_volume(&scene, 0.5, &grid, cutoff));
        assert_eq!(single, fast, "thread count changed the volume");
    }
}
