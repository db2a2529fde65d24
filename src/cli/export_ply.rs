//! `splat4d export-ply`: the 3D Gaussian Splatting PLY of a scene's slice at one time.

use std::path::PathBuf;

use splat4d::Result;
use splat4d::render::DEFAULT_CUTOFF;
use splat4d::tasks::scene_files::{ExportRequest, export_ply};

#[derive(Debug, clap::Args)]
pub struct ExportPlyArgs {
    /// Scene file (JSON or 4D PLY).
    #[arg(long)]
    scene: PathBuf,
    /// Scene time τ of the slice.
    #[arg(long, value_parser = super::args::finite, allow_negative_numbers = true)]
    time: f64,
    /// Output `.ply`.
    #[arg(long)]
    out: PathBuf,
    /// Kernels whose value at τ stays below this cut-off are left out (SPEC §5).
    #[arg(long, value_parser = super::args::finite, default_value_t = DEFAULT_CUTOFF)]
    cutoff: f64,
    /// Add 45 zero `f_rest_*` properties (degree-3 spherical harmonics) for loaders that
    /// require them, such as the reference 3DGS training code.
    #[arg(long)]
    sh_rest: bool,
}

pub fn run(args: &ExportPlyArgs) -> Result<()> {
    let summary = export_ply(&ExportRequest {
        scene: args.scene.clone(),
        time: args.time,
        out: args.out.clone(),
        cutoff: args.cutoff,
        sh_rest: args.sh_rest,
    })?;
    for warning in &summary.warnings {
        eprintln!("warning: {warning}");
    }
    super::print(summary);
    Ok(())
}
