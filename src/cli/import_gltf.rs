//! `splat4d import-gltf`: a glTF 2.0 model and its node animation sampled into 4D kernels.

use std::path::PathBuf;

use splat4d::Result;
use splat4d::tasks::scene_files::{ImportRequest, import_gltf};

#[derive(Debug, clap::Args)]
pub struct ImportGltfArgs {
    /// The model.
    model: PathBuf,
    /// Surface points to sample (each becomes one kernel per time sample).
    #[arg(long, default_value_t = 2000)]
    kernels: usize,
    /// Time samples: `auto` (key times and adaptive ones until every point follows its path
    /// within --tolerance), or N at most (t1 - t0)/(N - 1) apart (1: static).
    #[arg(long, default_value = "auto")]
    times: TimesArg,
    /// Largest position error of any surface point, relative to the model's size, with
    /// `--times auto` [default: 0.001].
    #[arg(long, value_parser = super::args::finite)]
    tolerance: Option<f64>,
    /// Output scene (.json or .ply).
    #[arg(long)]
    out: PathBuf,
    /// Seed of the surface samples.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// `additive` (glowing surfels whose intensities add) or `alpha` (opaque surfaces that
    /// hide what is behind them, SPEC §8).
    #[arg(long, default_value = "additive")]
    blend: splat4d::Blend,
}

pub fn run(args: &ImportGltfArgs) -> Result<()> {
    super::print(import_gltf(&ImportRequest {
        model: args.model.clone(),
        kernels: args.kernels,
        times: match args.times {
            TimesArg::Auto => None,
            TimesArg::Count(n) => Some(n),
        },
        tolerance: args.tolerance,
        out: args.out.clone(),
        seed: args.seed,
        blend: args.blend,
    })?);
    Ok(())
}

/// `--times auto` or a count.
#[derive(Clone, Copy, Debug)]
pub enum TimesArg {
    Auto,
    Count(usize),
}

impl std::str::FromStr for TimesArg {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        if s == "auto" {
            return Ok(TimesArg::Auto);
        }
        s.parse()
            .map(TimesArg::Count)
            .map_err(|_| format!("`{s}` is neither `auto` nor a whole number"))
    }
}
