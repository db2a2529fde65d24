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
    /// Time samples over the animation's range (1: static).
    #[arg(long, default_value_t = 16)]
    times: usize,
    /// Output scene (.json or .ply).
    #[arg(long)]
    out: PathBuf,
    /// Seed of the surface samples.
    #[arg(long, default_value_t = 0)]
    seed: u64,
}

pub fn run(args: &ImportGltfArgs) -> Result<()> {
    super::print(import_gltf(&ImportRequest {
        model: args.model.clone(),
        kernels: args.kernels,
        times: args.times,
        out: args.out.clone(),
        seed: args.seed,
    })?);
    Ok(())
}
