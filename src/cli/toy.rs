//! `splat4d toy`: the seed paper's toy scene (SPEC §7).

use std::path::PathBuf;

use splat4d::Result;
use splat4d::tasks::scene_files::{ToyKind as Kind, write_toy};

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum ToyKind {
    /// 30 frames × 1000 noisy points along (0,0,0) → (1,1,1), one small kernel each.
    Points,
    /// The single velocity kernel behind the points (SPEC §7).
    Blob,
    /// Three blobs of non-linear motion: one circling, one static and elongated, one
    /// fading in along a line (a test of fitting, not from the paper).
    ThreeBlobs,
}

#[derive(Debug, clap::Args)]
pub struct ToyArgs {
    /// Which scene.
    #[arg(long, value_enum)]
    kind: ToyKind,
    /// Seed of the points (the `points` scene only) [default: 2024].
    #[arg(long)]
    seed: Option<u64>,
    /// Output scene JSON.
    #[arg(long)]
    out: PathBuf,
}

pub fn run(args: &ToyArgs) -> Result<()> {
    let kind = match args.kind {
        ToyKind::Points => Kind::Points,
        ToyKind::Blob => Kind::Blob,
        ToyKind::ThreeBlobs => Kind::ThreeBlobs,
    };
    super::print(write_toy(kind, args.seed, &args.out)?);
    Ok(())
}
