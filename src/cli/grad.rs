//! `splat4d grad`: the MSE of a render against a target image and its gradient per kernel.

use std::path::PathBuf;

use splat4d::Result;
use splat4d::tasks::render::{GradRequest, grad};

use super::args::{RenderFlags, ViewFlags};

#[derive(Debug, clap::Args)]
pub struct GradArgs {
    #[command(flatten)]
    view: ViewFlags,
    /// Target image (`.exr` or `.png`), the camera's size.
    #[arg(long)]
    target: PathBuf,
    /// Output JSON: `{"loss": L, "kernels": [{"mean": [4], "amplitude": [3], "velocity": [3]}]}`;
    /// alpha scenes add `scale`, `rotation`, `opacity` and `sh`, scenes with SPEC §9 motion
    /// `acceleration` and `angular_velocity` (docs/formats.md).
    #[arg(long)]
    out: PathBuf,
    #[command(flatten)]
    render: RenderFlags,
}

pub fn run(args: &GradArgs) -> Result<()> {
    let summary = grad(&GradRequest {
        view: args.view.request(&args.render)?,
        target: args.target.clone(),
        out: args.out.clone(),
    })?;
    super::print(summary);
    Ok(())
}
