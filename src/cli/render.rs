//! `splat4d render`: a scene through a camera at one time into a PNG or EXR image.

use std::path::PathBuf;

use splat4d::Result;
use splat4d::io::image_file::BitDepth;
use splat4d::tasks::render::{RenderRequest, render};

use super::args::{RenderFlags, ViewFlags};

#[derive(Debug, clap::Args)]
pub struct RenderArgs {
    #[command(flatten)]
    view: ViewFlags,
    /// Output image: `.png` (8 or 16 bits) or `.exr` (float32 linear RGB).
    #[arg(long)]
    out: PathBuf,
    #[command(flatten)]
    render: RenderFlags,
    /// Bits per channel of a PNG output: 8 or 16 [default: 8].
    #[arg(long, value_parser = parse_bit_depth)]
    bit_depth: Option<BitDepth>,
    /// Draw a debug overlay over the render (PNG only): per-tile load as a red heat map, the
    /// tile grid, and each kernel's ellipse at its cut-off.
    #[arg(long)]
    overlay: bool,
}

fn parse_bit_depth(text: &str) -> std::result::Result<BitDepth, String> {
    match text {
        "8" => Ok(BitDepth::Eight),
        "16" => Ok(BitDepth::Sixteen),
        _ => Err(format!("`{text}` is not a bit depth: use 8 or 16")),
    }
}

pub fn run(args: &RenderArgs) -> Result<()> {
    let summary = render(&RenderRequest {
        view: args.view.request(&args.render)?,
        out: args.out.clone(),
        depth: args.bit_depth,
        overlay: args.overlay,
    })?;
    super::print(summary);
    Ok(())
}
