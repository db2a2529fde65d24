//! `splat4d bench`: forward-render speed with the error against the f64 reference.

use std::path::PathBuf;

use splat4d::Result;
use splat4d::render::{DEFAULT_CUTOFF, DEFAULT_DILATION, RenderOptions};
use splat4d::simd::ExpMode;
use splat4d::tasks::bench::{BenchRequest, bench};

use super::args::parse_size;

#[derive(Debug, clap::Args)]
pub struct BenchArgs {
    /// Scene: a built-in seeded bench scene by kernel count (`10k`, `100k`, `1m`, `2500`)
    /// or a scene file; repeat for several (default: `10k` and `100k`).
    #[arg(long)]
    scene: Vec<String>,
    /// Camera file for scene files (default: a look-at camera framing the scene).
    #[arg(long)]
    camera: Option<PathBuf>,
    /// Frame size `WxH` (ignored with --camera).
    #[arg(long, value_parser = parse_size, default_value = "512x512")]
    size: (u32, u32),
    /// Worker threads (default: 1, and one per core).
    #[arg(long, value_parser = clap::value_parser!(u16).range(1..=splat4d::tasks::MAX_THREADS as i64))]
    threads: Option<u16>,
    /// Timed frames per configuration (the median is reported).
    #[arg(long, default_value_t = 10)]
    frames: usize,
    /// Pixels sampled for the error against the f64 reference.
    #[arg(long, default_value_t = 400)]
    samples: usize,
    /// Scene time τ.
    #[arg(long, value_parser = super::args::finite, default_value_t = 0.5, allow_negative_numbers = true)]
    time: f64,
    /// Variance added to each screen covariance, px².
    #[arg(long, value_parser = super::args::finite, default_value_t = DEFAULT_DILATION)]
    dilation: f64,
    /// Cut-off ε.
    #[arg(long, value_parser = super::args::finite, default_value_t = DEFAULT_CUTOFF)]
    cutoff: f64,
    /// How exp(-q/2) is evaluated: `poly` (inlined polynomial, vectorised) or
    /// `std` (libm).
    #[arg(long, default_value = "poly")]
    exp: ExpMode,
    /// Time the seed-style dense baseline (every kernel at every pixel) for every scene. By
    /// default it runs when kernels × pixels ≤ 3·10⁹ (a few seconds a frame).
    #[arg(long, conflicts_with = "no_dense")]
    dense: bool,
    /// Never time the dense baseline.
    #[arg(long)]
    no_dense: bool,
    /// Measure speed against error over the cut-off, dilation and exp evaluation on the
    /// first scene (with --threads, or one thread per core); writes sweep.md and sweep.png
    /// to --out.
    #[arg(long)]
    sweep: bool,
    /// Only run the ceiling probe (the ideal inner loop every figure is compared with) and
    /// print its pairs per second.
    #[arg(long)]
    ceiling: bool,
    /// Output folder of --sweep.
    #[arg(long, default_value = "out/bench")]
    out: PathBuf,
    /// Blend of the built-in scenes: `additive` (SPEC §5) or `alpha` (§8: every kernel at
    /// opacity 0.5, colour its amplitude). Scene files keep their own.
    #[arg(long, default_value = "additive")]
    blend: splat4d::Blend,
}

pub fn run(args: &BenchArgs) -> Result<()> {
    let request = BenchRequest {
        scenes: args.scene.clone(),
        camera: args.camera.clone(),
        size: args.size,
        threads: args.threads.map(usize::from),
        frames: args.frames,
        samples: args.samples,
        time: args.time,
        options: RenderOptions {
            dilation: args.dilation,
            cutoff: args.cutoff,
            exp: args.exp,
        },
        dense: if args.no_dense {
            Some(false)
        } else if args.dense {
            Some(true)
        } else {
            None
        },
        sweep: args.sweep,
        ceiling: args.ceiling,
        out: args.out.clone(),
        blend: args.blend,
    };
    super::with_progress(|bars| bench(&request, bars))
}
