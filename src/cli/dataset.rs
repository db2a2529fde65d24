//! `splat4d dataset`: a multi-view dataset (D-NeRF / Blender layout) of a scene.

use std::path::PathBuf;

use splat4d::Result;
use splat4d::scenes::dataset::DatasetSpec;
use splat4d::tasks::dataset::{DatasetRequest, write_dataset};

use super::args::{RenderFlags, parse_list, parse_size};

#[derive(Debug, clap::Args)]
pub struct DatasetArgs {
    /// Scene JSON file.
    #[arg(long)]
    scene: PathBuf,
    /// Training cameras, seeded on a sphere around the scene.
    #[arg(long)]
    views: usize,
    /// Training times, evenly spread over the time range.
    #[arg(long)]
    times: usize,
    /// Image size, `WxH`.
    #[arg(long, value_parser = parse_size)]
    size: (u32, u32),
    /// Output folder.
    #[arg(long)]
    out: PathBuf,
    /// Seed of the cameras.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Also write float32 EXR images beside the 16-bit PNGs.
    #[arg(long)]
    exr: bool,
    /// Time range `t0,t1`.
    #[arg(long, value_parser = parse_list::<2>, default_value = "0,1", allow_hyphen_values = true)]
    time_range: [f64; 2],
    /// Vertical field of view of the cameras, degrees.
    #[arg(long, value_parser = super::args::finite, default_value_t = 40.0)]
    fov: f64,
    /// One camera per time, as D-NeRF's captures are: training camera i sees only time i
    /// (`--views` must equal `--times`), no val split, each test camera at its own time.
    #[arg(long)]
    monocular: bool,
    #[command(flatten)]
    render: RenderFlags,
    #[command(flatten)]
    shards: super::args::ShardFlags,
}

pub fn run(args: &DatasetArgs) -> Result<()> {
    let request = DatasetRequest {
        scene: args.scene.clone(),
        spec: DatasetSpec {
            views: args.views,
            times: args.times,
            width: args.size.0,
            height: args.size.1,
            time_range: args.time_range,
            fov_y_degrees: args.fov,
            seed: args.seed,
            monocular: args.monocular,
        },
        out: args.out.clone(),
        exr: args.exr,
        options: args.render.options(),
        threads: args.render.threads(),
        sharding: args.shards.sharding(),
    };
    super::with_progress(|bars| write_dataset(&request, bars))
}
