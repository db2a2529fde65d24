//! `splat4d bench`: forward-render speed with the error against the f64 reference.

use std::path::PathBuf;

use splat4d::Result;
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
    /// Frame size `WxH` of the built-in scenes and of scene files without --camera
    /// [default: 512x512].
    #[arg(long, value_parser = parse_size)]
    size: Option<(u32, u32)>,
    /// Worker threads (default: 1, and one per core).
    #[arg(long, value_parser = clap::value_parser!(u16).range(1..=splat4d::tasks::MAX_THREADS as i64))]
    threads: Option<u16>,
    /// Timed frames per configuration (the median is reported) [default: 10].
    #[arg(long)]
    frames: Option<usize>,
    /// Pixels sampled for the error against the f64 reference [default: 400].
    #[arg(long)]
    samples: Option<usize>,
    /// Scene time τ [default: 0.5].
    #[arg(long, value_parser = super::args::finite, allow_negative_numbers = true)]
    time: Option<f64>,
    /// Variance added to each screen covariance, px² [default: 0.3].
    #[arg(long, value_parser = super::args::finite)]
    dilation: Option<f64>,
    /// Cut-off ε [default: 0.00392156862745098].
    #[arg(long, value_parser = super::args::finite)]
    cutoff: Option<f64>,
    /// How exp(-q/2) is evaluated: `poly` (inlined polynomial, vectorised) or
    /// `std` (libm) [default: poly].
    #[arg(long)]
    exp: Option<ExpMode>,
    /// Time the seed-style dense baseline (every kernel at every pixel) for every scene. By
    /// default it runs when kernels × pixels ≤ 3·10⁹ (a few seconds a frame).
    #[arg(long, conflicts_with = "no_dense")]
    dense: bool,
    /// Never time the dense baseline.
    #[arg(long)]
    no_dense: bool,
    /// Measure speed against error over a grid of cut-offs, dilations and exp evaluations
    /// on one scene (with --threads, or one thread per core); writes sweep.md and sweep.png
    /// to --out.
    #[arg(long)]
    sweep: bool,
    /// Only run the ceiling probes (the ideal inner loop every figure is compared with) and
    /// print their pairs per second; takes only --threads.
    #[arg(long)]
    ceiling: bool,
    /// Output folder of --sweep [default: out/bench].
    #[arg(long)]
    out: Option<PathBuf>,
    /// Blend of the built-in scenes: `additive` (SPEC §5) or `alpha` (§8: every kernel at
    /// opacity 0.5, colour its amplitude). Scene files keep their own [default: additive].
    #[arg(long)]
    blend: Option<splat4d::Blend>,
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
        dilation: args.dilation,
        cutoff: args.cutoff,
        exp: args.exp,
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
