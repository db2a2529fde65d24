//! `view`: serves the viewer ([`crate::view`]) on a scene, with a dataset's views to compare
//! with, until Ctrl-C.

use std::fmt;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use crate::io::dataset::{DatasetOptions, DatasetSource};
use crate::io::scene_file::load_scene;
use crate::model::{Error, Result};
use crate::render::RenderOptions;
use crate::view::{Server, Showing};

/// `splat4d view`.
#[derive(Clone, Debug, PartialEq)]
pub struct ViewRequest {
    /// Scene file (JSON, 4D PLY or 3DGS PLY).
    pub scene: PathBuf,
    /// A dataset whose cameras the page lists.
    pub views: Option<PathBuf>,
    /// Address to listen on.
    pub host: String,
    /// Port to listen on (0: any free port).
    pub port: u16,
}

/// What [`view_scene`] did.
#[derive(Clone, Debug, PartialEq)]
pub struct ViewSummary {
    /// The page's address.
    pub url: String,
}

impl fmt::Display for ViewSummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "stopped serving {}", self.url)
    }
}

/// Serves the scene of `request`; calls `listening` with the page's address once the port
/// is bound, then serves until Ctrl-C.
pub fn view_scene(request: &ViewRequest, listening: impl FnOnce(&str)) -> Result<ViewSummary> {
    let scene = load_scene(&request.scene)?;
    let views = match &request.views {
        Some(dir) => {
            let options = DatasetOptions {
                background: scene.background.map(|b| b as f32),
                downscale: 1,
                ..DatasetOptions::default()
            };
            // Refused before any photo is decoded when they would not fit in memory.
            let source = DatasetSource::open(dir);
            let photos = source.photo_memory(1);
            crate::io::memory::check(
                photos.kept.saturating_add(photos.working),
                &format!("the {} photos of {}", photos.frames, dir.display()),
            )?;
            let dataset = source.load(&options)?;
            let mut views = dataset.train;
            views.extend(dataset.val);
            views.extend(dataset.test);
            views
        }
        None => Vec::new(),
    };
    let showing = Showing {
        title: request.scene.file_name().map_or_else(
            || request.scene.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        ),
        scene: Arc::new(scene),
        views: Arc::new(views),
        options: RenderOptions::default(),
        live: None,
        duty: 1.0,
    };
    let server = Server::bind(&request.host, request.port)?;
    let url = server.url();
    let stop = Arc::new(AtomicBool::new(false));
    let flag = Arc::clone(&stop);
    ctrlc::set_handler(move || flag.store(true, Ordering::Relaxed))
        .map_err(|e| Error::usage(format!("cannot catch Ctrl-C: {e}")))?;
    listening(&url);
    server.run(&showing, &stop)?;
    Ok(ViewSummary { url })
}
