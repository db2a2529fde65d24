//! The training loss of renders of an object, 3D Gaussian splatting's `(1 - λ) L1 + λ
//! (1 - SSIM)` with its gradient (`splat4d::fit::ssim::L1Dssim::loss_and_gradient`), on one
//! thread (a fit renders a step's views side by side, one per thread) at the view sizes a
//! fit meets: `loss/l1_dssim/WxH`. Machine and flags: `benches/README.md`.
//! Run: `cargo bench -p splat4d-benches --bench loss`.

use std::sync::Arc;

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use splat4d::fit::ssim::{L1Dssim, SsimScratch};
use splat4d::model::random::{log_uniform, seeded_rng};
use splat4d::model::{Image, View};
use splat4d::scenes::synthetic::bench_camera;

const SIZES: [(u32, u32); 3] = [(100, 100), (200, 200), (400, 400)];

/// A seeded image of smooth and sharp detail in `[0, 1]`: a ramp across each row plus
/// seeded noise (the project's seeded randomness).
fn seeded_image(width: u32, height: u32, seed: u64) -> Image {
    let mut rng = seeded_rng(seed);
    let pixels = (0..3 * width * height)
        .map(|i| {
            let noise = log_uniform(&mut rng, 1e-3, 1.0) as f32;
            let ramp = (i % (3 * width)) as f32 / (3 * width) as f32;
            0.7 * ramp + 0.3 * noise
        })
        .collect();
    Image {
        width,
        height,
        pixels,
    }
}

fn l1_dssim(c: &mut Criterion) {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("a one-thread pool");
    let loss = L1Dssim { dssim_weight: 0.2 };
    let mut group = c.benchmark_group("loss");
    group.sample_size(20);
    for (w, h) in SIZES {
        let image = seeded_image(w, h, 1);
        let view = View {
            camera: bench_camera(w, h),
            time: 0.0,
            image: Arc::new(seeded_image(w, h, 2)),
            name: "bench".into(),
            weights: None,
        };
        let mut v_image = Vec::new();
        let mut scratch = SsimScratch::default();
        group.throughput(Throughput::Elements(u64::from(w * h)));
        group.bench_function(BenchmarkId::new("l1_dssim", format!("{w}x{h}")), |b| {
            b.iter(|| {
                pool.install(|| {
                    loss.loss_and_gradient(&image, &view, 1.0, &mut v_image, &mut scratch)
                })
            });
        });
    }
    group.finish();
}

criterion_group!(benches, l1_dssim);
criterion_main!(benches);
