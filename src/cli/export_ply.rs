//! `splat4d export-ply`: the 3D Gaussian Splatting PLY of a scene's slice at one time, or a
//! sequence of slices with an index.

use std::path::PathBuf;

use splat4d::Result;
use splat4d::render::DEFAULT_CUTOFF;
use splat4d::tasks::scene_files::{ExportRequest, ExportTimes, export_ply};

use super::args::{TimeList, parse_times};

#[derive(Debug, clap::Args)]
pub struct ExportPlyArgs {
    /// Scene file (JSON or 4D PLY).
    #[arg(long)]
    scene: PathBuf,
    /// Scene time τ of the slice (then --out is a `.ply`).
    #[arg(long, value_parser = super::args::finite, allow_negative_numbers = true,
          required_unless_present_any = ["times", "frames"], conflicts_with_all = ["times", "frames"])]
    time: Option<f64>,
    /// A sequence at these times, `t0,t1,...`: --out is a folder that receives
    /// `frame_0000.ply`, … and `frames.json` (file and time of each).
    #[arg(long, value_parser = parse_times, allow_hyphen_values = true, conflicts_with = "frames")]
    times: Option<TimeList>,
    /// A sequence of N times evenly over the scene's time range (ends included), written like
    /// --times.
    #[arg(long)]
    frames: Option<usize>,
    /// Output `.ply`, or the sequence's folder.
    #[arg(long)]
    out: PathBuf,
    /// Kernels whose value at τ stays below this cut-off are left out (SPEC §5).
    #[arg(long, value_parser = super::args::finite, default_value_t = DEFAULT_CUTOFF)]
    cutoff: f64,
    /// Add 45 zero `f_rest_*` properties (degree-3 spherical harmonics) for loaders that
    /// require them, such as the reference 3DGS training code.
    #[arg(long)]
    sh_rest: bool,
    #[command(flatten)]
    shards: super::args::ShardFlags,
}

pub fn run(args: &ExportPlyArgs) -> Result<()> {
    let summary = export_ply(&ExportRequest {
        scene: args.scene.clone(),
        times: match (args.time, &args.times, args.frames) {
            (Some(tau), _, _) => ExportTimes::One(tau),
            (_, Some(times), _) => ExportTimes::List(times.0.clone()),
            (_, _, Some(n)) => ExportTimes::Frames(n),
            (None, None, None) => unreachable!("clap requires one of them"),
        },
        out: args.out.clone(),
        cutoff: args.cutoff,
        sh_rest: args.sh_rest,
        sharding: args.shards.sharding(),
    })?;
    for warning in &summary.warnings {
        eprintln!("warning: {warning}");
    }
    super::print(summary);
    Ok(())
}
