//! `dataset`: a multi-view dataset of a scene in the D-NeRF / Blender layout.

use std::fmt;
use std::path::PathBuf;

use crate::io::dataset::DatasetWriter;
use crate::io::scene_file::load_scene;
use crate::model::{Progress, Result};
use crate::render::RenderOptions;
use crate::scenes::dataset::{DatasetSpec, frame_count, render_views};
use crate::tasks::with_threads_on_pool;

/// `splat4d dataset`.
#[derive(Clone, Debug, PartialEq)]
pub struct DatasetRequest {
    /// Scene file.
    pub scene: PathBuf,
    /// Cameras, times, size, time range, field of view and seed.
    pub spec: DatasetSpec,
    /// Output folder.
    pub out: PathBuf,
    /// Also write float32 EXR images beside the 16-bit PNGs.
    pub exr: bool,
    /// Rendering options.
    pub options: RenderOptions,
    /// Worker threads (`None`: one per core).
    pub threads: Option<usize>,
}

/// What [`write_dataset`] wrote.
#[derive(Clone, Debug, PartialEq)]
pub struct DatasetSummary {
    out: PathBuf,
    frames: [usize; 3],
    size: (u32, u32),
}

impl fmt::Display for DatasetSummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let [train, val, test] = self.frames;
        write!(
            f,
            "{}: {train} train, {val} val, {test} test frames ({}×{})",
            self.out.display(),
            self.size.0,
            self.size.1
        )
    }
}

/// Renders the dataset of `request` and writes its three splits.
pub fn write_dataset(
    request: &DatasetRequest,
    progress: &mut dyn Progress,
) -> Result<DatasetSummary> {
    request.options.validate()?;
    request.spec.validate()?;
    // Before any work: the output folder holds no input and may be replaced.
    let mut outputs = crate::io::output::Outputs::new();
    outputs.input(&request.scene).folder(&request.out);
    outputs.check()?;
    let scene = load_scene(&request.scene)?;
    let spec = &request.spec;
    let pixels = u64::from(spec.width) * u64::from(spec.height);
    crate::io::memory::check(
        pixels.saturating_mul(crate::io::memory::DATASET_VIEW_BYTES_PER_PIXEL),
        &format!("{}×{} views", spec.width, spec.height),
    )?;
    let mut writer = DatasetWriter::new(&request.out, request.exr)?.with_blend(scene.blend);
    progress.start("render", frame_count(spec));
    let mut frames = [0_usize; 3];
    // Without a thread count the views are rendered and written on a thread of the global
    // pool, so each frame's parallel loops start there instead of being handed over one by
    // one (a 60-frame 48×48 set: 30.8 → 21.8 ms).
    with_threads_on_pool(request.threads, || {
        render_views(&scene, spec, &request.options, |split, view| {
            frames[split.index()] += 1;
            writer.add(split.name(), &view)?;
            progress.tick();
            Ok(())
        })
    })??;
    writer.finish()?;
    Ok(DatasetSummary {
        out: request.out.clone(),
        frames,
        size: (spec.width, spec.height),
    })
}
