//! Tasks: what each subcommand does, as one library call that reads its inputs, computes
//! and writes its outputs, and returns a summary to print. The command line turns flags
//! into a task's request and calls it; every default and automatic choice lives below
//! (the fit's in [`crate::fit::plan`], framing in [`crate::scenes::paths`]).
//!
//! | task | subcommand |
//! |---|---|
//! | [`render::render`] | `render` |
//! | [`render::grad`] | `grad` |
//! | [`dataset::write_dataset`] | `dataset` |
//! | [`fit::fit_dataset`] | `fit` |
//! | [`scene_files::write_toy`] | `toy` |
//! | [`scene_files::import_gltf`] | `import-gltf` |
//! | [`scene_files::export_ply`] | `export-ply` |
//! | [`volume::write_volumes`] | `volume` |
//! | [`video::write_videos`] | `video` |
//! | [`view::view_scene`] | `view` |
//! | [`bench::bench`] | `bench` |
//! | [`report::write_report`] | `report`, and `splat4d` alone |
//!
//! Every summary implements `Display`: the lines the command prints.

pub mod bench;
pub mod dataset;
pub mod fit;
pub mod render;
pub mod report;
pub mod scene_files;
pub mod video;
pub mod view;
pub mod volume;

use crate::model::{Error, Result};

/// Most worker threads a task starts.
pub const MAX_THREADS: usize = 1024;

/// Runs `work` on a pool of `threads` threads, or on rayon's global pool (one thread per
/// core) when `None`. Results do not depend on the thread count.
pub fn with_threads<T: Send>(threads: Option<usize>, work: impl FnOnce() -> T + Send) -> Result<T> {
    match threads {
        None => Ok(work()),
        Some(n) if n == 0 || n > MAX_THREADS => Err(Error::setting(
            &["threads"],
            format!("`threads` {n} must be between 1 and {MAX_THREADS}"),
        )),
        Some(n) => {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .map_err(|e| Error::usage(format!("cannot start {n} worker threads: {e}")))?;
            Ok(pool.install(work))
        }
    }
}
