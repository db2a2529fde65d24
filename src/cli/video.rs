//! `splat4d video`: videos along camera paths — orbits at fixed times, a spiral, or a path
//! file.

use std::path::PathBuf;

use splat4d::Result;
use splat4d::io::video::VideoOptions;
use splat4d::scenes::paths::{Circle, Up};
use splat4d::tasks::video::{CircleSpec as Spec, VideoRequest, write_videos};

use super::args::{RenderFlags, ShardFlags, TimeList, parse_list, parse_size, parse_times};

/// An orbit or spiral: explicit `cx,cy,cz,radius,elevation,frames`, or `auto` (from the
/// scene's bounds: 20° elevation, 60 frames).
#[derive(Clone, Debug)]
pub struct CircleSpec(Option<[f64; 6]>);

fn parse_circle(text: &str) -> std::result::Result<CircleSpec, String> {
    if text == "auto" {
        return Ok(CircleSpec(None));
    }
    let values = parse_list::<6>(text)?;
    let most = splat4d::scenes::paths::MAX_PATH_FRAMES;
    if !(1.0..=most as f64).contains(&values[5]) || values[5].fract() != 0.0 {
        // As written (cut): `1e300` printed as a number has 301 digits.
        let given = text.rsplit(',').next().unwrap_or_default().trim();
        return Err(format!(
            "frames = {} must be a whole number from 1 to {most}",
            splat4d::model::error::cut(given, splat4d::model::error::MAX_QUOTE)
        ));
    }
    Ok(CircleSpec(Some(values)))
}

#[derive(Debug, clap::Args)]
pub struct VideoArgs {
    /// Scene JSON file.
    #[arg(long)]
    scene: PathBuf,
    /// Orbit at each of --times: `cx,cy,cz,radius,elevation_degrees,frames`, or alone for
    /// one framing the scene (a value starting with `-` needs `--orbit=-1,...`). Without
    /// --orbit, --spiral and --path: one framing orbit.
    #[arg(long, num_args = 0..=1, default_missing_value = "auto", value_parser = parse_circle)]
    orbit: Option<CircleSpec>,
    /// Times of the orbits, comma-separated (default: the start, middle and end of
    /// --time-range, else of the scene's time range, the range of its kernels' time means).
    #[arg(long, value_parser = parse_times, allow_hyphen_values = true)]
    times: Option<TimeList>,
    /// One turn while time runs over --time-range and the elevation rises from -e to +e:
    /// `cx,cy,cz,radius,elevation_degrees,frames`, or alone for one framing the scene.
    #[arg(long, num_args = 0..=1, default_missing_value = "auto", value_parser = parse_circle)]
    spiral: Option<CircleSpec>,
    /// Time range `t0,t1` of the spiral, of the orbits' default --times and of a path file's
    /// cameras without a time (default: the scene's time range).
    #[arg(long, value_parser = parse_list::<2>, allow_hyphen_values = true)]
    time_range: Option<[f64; 2]>,
    /// The axis orbits and spirals turn about, and the cameras' up: `x`, `y`, `z`, `-x`,
    /// `-y` or `-z` (Blender and D-NeRF scenes are `z` up). Default: the scene's own `up`
    /// (a scene fitted from a dataset carries its cameras' mean up), else `y`.
    #[arg(long, allow_hyphen_values = true)]
    up: Option<Up>,
    /// A path file: `[{"camera": {camera JSON}, "time": t}, ...]`, or nerfstudio's
    /// `camera_path.json` (its cameras, or `fps × seconds` frames through its keyframes;
    /// perspective cameras only).
    #[arg(long)]
    path: Option<PathBuf>,
    /// Output folder.
    #[arg(long)]
    out: PathBuf,
    /// Frame size of orbits and spirals, `WxH` [default: 256x256].
    #[arg(long, value_parser = parse_size)]
    size: Option<(u32, u32)>,
    /// Vertical field of view of orbits and spirals, degrees [default: 40].
    #[arg(long, value_parser = super::args::finite)]
    fov: Option<f64>,
    /// Frames per second of the GIF and MP4 (default 25; a nerfstudio path file's own `fps`
    /// for its video).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=100))]
    fps: Option<u32>,
    /// Do not write GIFs.
    #[arg(long)]
    no_gif: bool,
    /// Do not try ffmpeg for MP4s.
    #[arg(long)]
    no_mp4: bool,
    #[command(flatten)]
    render: RenderFlags,
    #[command(flatten)]
    shards: ShardFlags,
}

impl CircleSpec {
    fn spec(&self, up: Up) -> Spec {
        match self.0 {
            Some([cx, cy, cz, radius, elevation, frames]) => Spec::Given(Circle {
                centre: [cx, cy, cz],
                radius,
                elevation_degrees: elevation,
                frames: frames as usize,
                up,
            }),
            None => Spec::Auto,
        }
    }
}

pub fn run(args: &VideoArgs) -> Result<()> {
    let request = VideoRequest {
        scene: args.scene.clone(),
        orbit: args
            .orbit
            .as_ref()
            .map(|c| c.spec(args.up.unwrap_or_default())),
        times: args.times.as_ref().map(|t| t.0.clone()),
        spiral: args
            .spiral
            .as_ref()
            .map(|c| c.spec(args.up.unwrap_or_default())),
        time_range: args.time_range,
        up: args.up,
        path: args.path.clone(),
        out: args.out.clone(),
        size: args.size,
        fov: args.fov,
        video: VideoOptions {
            fps: args.fps.unwrap_or(25),
            gif: !args.no_gif,
            mp4: !args.no_mp4,
        },
        fps_given: args.fps.is_some(),
        options: args.render.options(),
        threads: args.render.threads(),
        sharding: args.shards.sharding(),
    };
    super::with_progress(|bars| write_videos(&request, bars)).map_err(offer_no_gif)
}

/// A GIF that cannot be written is a setting of `gif`: `video` can leave it out.
fn offer_no_gif(error: splat4d::Error) -> splat4d::Error {
    match error {
        splat4d::Error::Setting { fields, message } if fields.contains(&"gif") => {
            splat4d::Error::Setting {
                fields,
                message: format!("{message} (splat4d video takes --no-gif)"),
            }
        }
        other => other,
    }
}
