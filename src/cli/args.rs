//! Flags shared by several subcommands, and the parsers of list-valued flags.

use std::path::PathBuf;

use splat4d::fit::train::EarlyStop;
use splat4d::render::{DEFAULT_CUTOFF, DEFAULT_DILATION, RenderOptions};
use splat4d::simd::ExpMode;
use splat4d::tasks::render::{CameraSource, ViewRequest};

// What to look at: a scene through a camera at a time. (A `//` comment: subcommands are
// defined when first used, `defer`, and a doc comment here would replace the about text of
// every subcommand that flattens these flags.)
#[derive(Debug, clap::Args)]
#[command(group(clap::ArgGroup::new("camera_source").required(true).args(["camera", "camera_from"])))]
pub struct ViewFlags {
    /// Scene file: JSON or 4D PLY.
    #[arg(long)]
    scene: PathBuf,
    /// Camera JSON file.
    #[arg(long)]
    camera: Option<PathBuf>,
    /// A glTF model's camera instead: `MODEL.gltf[#index]` (the index-th camera node).
    #[arg(long)]
    camera_from: Option<String>,
    /// Image size `WxH` for --camera-from (default: 512 high, the camera's aspect ratio).
    #[arg(long, value_parser = parse_size)]
    size: Option<(u32, u32)>,
    /// Scene time τ.
    #[arg(long, value_parser = super::args::finite, allow_negative_numbers = true)]
    time: f64,
}

impl ViewFlags {
    /// The view these flags and `render` describe.
    pub fn request(&self, render: &RenderFlags) -> splat4d::Result<ViewRequest> {
        let camera = CameraSource::new(self.camera.clone(), self.camera_from.clone(), self.size)?;
        Ok(ViewRequest {
            scene: self.scene.clone(),
            camera,
            time: self.time,
            options: render.options(),
            threads: render.threads(),
        })
    }
}

// Flags shared by every command that renders. (`//`: as for `ViewFlags`.)
#[derive(Debug, clap::Args)]
pub struct RenderFlags {
    /// Variance added to each screen-space covariance, px² (SPEC §4).
    #[arg(long, value_parser = super::args::finite, default_value_t = DEFAULT_DILATION, allow_negative_numbers = true)]
    dilation: f64,
    /// Cut-off ε on a kernel's value; 0 disables truncation (SPEC §5).
    #[arg(long, value_parser = super::args::finite, default_value_t = DEFAULT_CUTOFF, allow_negative_numbers = true)]
    cutoff: f64,
    /// How exp(-q/2) is evaluated per pixel: `poly` (inlined polynomial, relative error
    /// ≤ 4e-7, vectorised) or `std` (libm).
    #[arg(long, default_value = "poly")]
    exp: ExpMode,
    /// Worker threads (default: one per core). The output does not depend on it.
    #[arg(long, value_parser = clap::value_parser!(u16).range(1..=splat4d::tasks::MAX_THREADS as i64))]
    threads: Option<u16>,
}

impl RenderFlags {
    /// The rendering options (validated by the task).
    pub fn options(&self) -> RenderOptions {
        RenderOptions {
            dilation: self.dilation,
            cutoff: self.cutoff,
            exp: self.exp,
        }
    }

    /// The worker threads asked for.
    pub fn threads(&self) -> Option<usize> {
        self.threads.map(usize::from)
    }
}

/// A finite number (NaN and ±∞ are refused when the flags are read, before any work): the
/// library's parser of a fit's options ([`splat4d::tasks::fit_options::finite`]).
pub fn finite(text: &str) -> Result<f64, String> {
    splat4d::tasks::fit_options::finite(text)
}

/// What `--window` chose: a side, or none (`off`).
#[derive(Clone, Copy, Debug)]
pub struct WindowChoice(pub Option<u32>);

/// `off`, or a window's largest side ([`splat4d::tasks::fit_options::window`]).
pub fn window(text: &str) -> Result<WindowChoice, String> {
    splat4d::tasks::fit_options::window(text).map(WindowChoice)
}

/// What `--early-stop` chose: a rule, or none (`off`).
#[derive(Clone, Copy, Debug)]
pub struct EarlyStopChoice(pub Option<EarlyStop>);

/// `off`, or the fraction of the steps without a gain that ends a fit
/// ([`splat4d::tasks::fit_options::early_stop`]).
pub fn early_stop(text: &str) -> Result<EarlyStopChoice, String> {
    splat4d::tasks::fit_options::early_stop(text).map(EarlyStopChoice)
}

/// `N` comma-separated finite numbers ([`splat4d::tasks::fit_options::numbers`]).
pub fn parse_list<const N: usize>(text: &str) -> Result<[f64; N], String> {
    splat4d::tasks::fit_options::numbers(text)
}

/// A comma-separated list of times.
#[derive(Clone, Debug)]
pub struct TimeList(pub Vec<f64>);

/// Parses a [`TimeList`].
pub fn parse_times(text: &str) -> Result<TimeList, String> {
    text.split(',')
        .map(|v| match v.trim().parse::<f64>() {
            Ok(t) if t.is_finite() => Ok(t),
            _ => Err(format!("`{v}` is not a finite time")),
        })
        .collect::<Result<_, _>>()
        .map(TimeList)
}

/// `WxH` with both ≥ 1.
pub fn parse_size(text: &str) -> Result<(u32, u32), String> {
    let (w, h) = text
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("`{text}` is not WxH"))?;
    let parse = |v: &str| v.trim().parse::<u32>().ok().filter(|&n| n > 0);
    match (parse(w), parse(h)) {
        (Some(w), Some(h)) => Ok((w, h)),
        _ => Err(format!("`{text}` is not WxH with W, H ≥ 1")),
    }
}

// Frames shared among the runs of an array job (`--shard I/N`), then put together
// (`--assemble`). (`//`: as for `ViewFlags`.)
#[derive(Debug, clap::Args)]
pub struct ShardFlags {
    /// Write only frames I, I+N, I+2N, … (`I/N`, 0 ≤ I < N) into the output's layout, for a
    /// batch scheduler's array job; `--assemble` puts the shards' frames together.
    #[arg(long, value_name = "I/N", conflicts_with = "assemble")]
    shard: Option<splat4d::io::shards::Shard>,
    /// Write what one run writes beyond the frames from the frames the `--shard` runs of the
    /// same command wrote (refused naming a missing frame).
    #[arg(long)]
    assemble: bool,
}

impl ShardFlags {
    /// The sharding these flags ask for.
    pub fn sharding(&self) -> splat4d::io::shards::Sharding {
        use splat4d::io::shards::Sharding;
        match (self.shard, self.assemble) {
            (Some(shard), _) => Sharding::Shard(shard),
            (None, true) => Sharding::Assemble,
            (None, false) => Sharding::Whole,
        }
    }
}
