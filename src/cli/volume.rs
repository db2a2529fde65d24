//! `splat4d volume`: the Eq. 1 sum on a 3D grid, as slices through its peak.

use std::path::PathBuf;

use splat4d::Result;
use splat4d::tasks::volume::{VolumeRequest, write_volumes};

use super::args::{TimeList, parse_times};

#[derive(Debug, clap::Args)]
pub struct VolumeArgs {
    /// Scene JSON file.
    #[arg(long)]
    scene: PathBuf,
    /// Grid cells per axis.
    #[arg(long, default_value_t = 64, value_parser = clap::value_parser!(u16).range(2..=1024))]
    res: u16,
    /// Times, comma-separated.
    #[arg(long, default_value = "0,0.5,1", value_parser = parse_times, allow_hyphen_values = true)]
    times: TimeList,
    /// Output folder for the slice images.
    #[arg(long)]
    out: PathBuf,
    /// Cut-off ε per kernel (SPEC §5 applied in 3D); 0 sums every kernel everywhere.
    #[arg(long, value_parser = super::args::finite, default_value_t = 1e-6)]
    cutoff: f64,
    /// Worker threads (default: one per core).
    #[arg(long, value_parser = clap::value_parser!(u16).range(1..=splat4d::tasks::MAX_THREADS as i64))]
    threads: Option<u16>,
}

pub fn run(args: &VolumeArgs) -> Result<()> {
    super::print(write_volumes(&VolumeRequest {
        scene: args.scene.clone(),
        res: usize::from(args.res),
        times: args.times.0.clone(),
        out: args.out.clone(),
        cutoff: args.cutoff,
        threads: args.threads.map(usize::from),
    })?);
    Ok(())
}
