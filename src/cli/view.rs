//! `splat4d view`: look at a scene in a web browser.

use std::path::PathBuf;

use splat4d::Result;
use splat4d::tasks::view::{ViewRequest, view_scene};

#[derive(Debug, clap::Args)]
pub struct ViewArgs {
    /// Scene file: JSON, 4D PLY or 3DGS PLY.
    #[arg(long)]
    scene: PathBuf,
    /// A dataset folder (D-NeRF, nerfstudio, COLMAP): the page lists its cameras and
    /// compares the render with each view's image.
    #[arg(long)]
    views: Option<PathBuf>,
    /// Port to serve on (0: any free port).
    #[arg(long, default_value_t = 8080)]
    port: u16,
    /// Address to listen on; the default is reachable from this machine only (from another
    /// one, forward the same port over SSH: `ssh -L 8080:localhost:8080 HOST`).
    #[arg(long, default_value = "127.0.0.1")]
    host: String,
}

pub fn run(args: &ViewArgs) -> Result<()> {
    let request = ViewRequest {
        scene: args.scene.clone(),
        views: args.views.clone(),
        host: args.host.clone(),
        port: args.port,
    };
    let summary = view_scene(&request, |url| {
        super::print(format!("serving {url} (Ctrl-C to stop)"));
    })?;
    super::print(summary);
    Ok(())
}
