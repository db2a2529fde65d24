//! `dataset`: a multi-view dataset of a scene in the D-NeRF / Blender layout.

use std::fmt;
use std::path::PathBuf;

use crate::io::dataset::DatasetWriter;
use crate::io::scene_file::load_scene;
use crate::io::shards::{Shard, Sharding};
use crate::model::{Error, Progress, Result, Scene};
use crate::render::{RenderContext, RenderOptions};
use crate::scenes::dataset::{
    DatasetFrame, DatasetSpec, dataset_frames, frame_count, render_frame, render_views,
};
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
    /// Every frame, one shard of them, or the `transforms_*.json` from the shards' frames
    /// ([`crate::io::shards`]).
    pub sharding: Sharding,
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
    if request.sharding != Sharding::Whole {
        crate::io::shards::check_shared_folder(&request.out, "dataset")?;
    }
    let scene = load_scene(&request.scene)?;
    let spec = &request.spec;
    let pixels = u64::from(spec.width) * u64::from(spec.height);
    crate::io::memory::check(
        pixels.saturating_mul(crate::io::memory::DATASET_VIEW_BYTES_PER_PIXEL),
        &format!("{}×{} views", spec.width, spec.height),
    )?;
    match request.sharding {
        Sharding::Whole => {}
        Sharding::Shard(shard) => return write_shard(request, &scene, shard, progress),
        Sharding::Assemble => return assemble(request, &scene),
    }
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

/// What a dataset's frames depend on: the scene file's bytes, the spec, the options and
/// `exr` ([`crate::io::shards::fingerprint`]).
fn fingerprint(request: &DatasetRequest) -> Result<String> {
    let scene =
        std::fs::read(&request.scene).map_err(|e| Error::read(&request.scene, "cannot read", e))?;
    let settings = format!("{:?} {:?} {}", request.spec, request.options, request.exr);
    Ok(crate::io::shards::fingerprint(&[
        &scene,
        settings.as_bytes(),
    ]))
}

/// The summary of the frames `frames` of `request`.
fn summary(request: &DatasetRequest, frames: &[DatasetFrame]) -> DatasetSummary {
    let mut counts = [0_usize; 3];
    for frame in frames {
        counts[frame.split.index()] += 1;
    }
    DatasetSummary {
        out: request.out.clone(),
        frames: counts,
        size: (request.spec.width, request.spec.height),
    }
}

/// Shard `shard`'s frames (in file order, train then val and test) moved into the
/// dataset's folder beside the other shards'; no `transforms_*.json`.
fn write_shard(
    request: &DatasetRequest,
    scene: &Scene,
    shard: Shard,
    progress: &mut dyn Progress,
) -> Result<DatasetSummary> {
    let fingerprint = fingerprint(request)?;
    let frames: Vec<DatasetFrame> = dataset_frames(scene, &request.spec)?
        .into_iter()
        .enumerate()
        .filter(|&(k, _)| shard.takes(k))
        .map(|(_, frame)| frame)
        .collect();
    let staging = crate::io::output::Staging::new(&request.out)?;
    progress.start("render", frames.len());
    let mut names = Vec::new();
    with_threads_on_pool(request.threads, || -> Result<()> {
        let mut context = RenderContext::new();
        for frame in &frames {
            let view = render_frame(scene, frame, &request.options, &mut context)?;
            names.extend(crate::io::dataset::write_frame_images(
                staging.path(),
                frame.split.name(),
                frame.index,
                &view,
                request.exr,
            )?);
            progress.tick();
        }
        Ok(())
    })??;
    crate::io::shards::commit_shard(
        staging.path(),
        &request.out,
        "dataset",
        shard,
        &fingerprint,
        &names,
    )?;
    Ok(summary(request, &frames))
}

/// The `transforms_*.json` from the frames the shards wrote, and the folder's marker: the
/// files of one run.
fn assemble(request: &DatasetRequest, scene: &Scene) -> Result<DatasetSummary> {
    let fingerprint = fingerprint(request)?;
    let frames = dataset_frames(scene, &request.spec)?;
    let names: Vec<String> = frames
        .iter()
        .flat_map(|f| crate::io::dataset::frame_files(f.split.name(), f.index, request.exr))
        .collect();
    let out = &request.out;
    crate::io::shards::check_assembled(out, "dataset", &fingerprint, &names)?;
    crate::io::shards::keep_only(out, &names)?;
    let entries: Vec<_> = frames
        .iter()
        .map(|f| (f.split.name(), f.index, f.camera, f.time))
        .collect();
    crate::io::dataset::write_all_transforms(out, &entries, scene.blend)?;
    crate::io::shards::drop_shard_markers(out)?;
    crate::io::output::write_marker(out, "dataset", &[])?;
    Ok(summary(request, &frames))
}
