//! `fit`: kernels fitted to a dataset on disk with the plan of [`crate::fit::plan`].

use std::fmt;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use crate::fit::coarse::CoarseToFine;
use crate::fit::plan::Init;
use crate::fit::settings::FitSettings;
use crate::fit::train::{SplitScore, StepRecord, evaluate_splits};
use crate::io::dataset::{DatasetOptions, DatasetSource, FrameRange, PhotoMemory};
use crate::io::scene_file::{load_scene, save_scene};
use crate::io::{check_output, same_file, write_bytes_atomically};
use crate::model::{Blend, Dataset, Result, Scene, Silent};
use crate::tasks::{with_threads_on_pool, with_threads_on_pool_unless_shared};
use crate::view::live::StepPoint;
use crate::view::{Live, Server, Showing};

/// `splat4d fit`.
#[derive(Clone, Debug, PartialEq)]
pub struct FitRequest {
    /// Dataset folder (D-NeRF layout, one `transforms.json`, or a COLMAP model).
    pub views: PathBuf,
    /// Average N×N pixel blocks of every image (1: as they are).
    pub downscale: u32,
    /// Refuse frames whose image is missing (otherwise skipped with a note).
    pub strict: bool,
    /// Read dataset images that lie outside the dataset's folder.
    pub allow_outside_images: bool,
    /// The frames of a dataset filmed over time that are read (`None`: all).
    pub frames: Option<FrameRange>,
    /// Frames per second of a dataset filmed over time (`None`: times from 0 to 1).
    pub fps: Option<f64>,
    /// `auto`, `random:N` or a scene file.
    pub init: String,
    /// Everything else about the fit, as chosen: each setting acts on the fit's blend or
    /// is refused ([`FitSettings`]).
    pub settings: FitSettings,
    /// The blend to fit; `None`: the start scene's, else the dataset's, else alpha.
    pub blend: Option<Blend>,
    /// Output scene.
    pub out: PathBuf,
    /// Log file: one JSON object per step.
    pub log: Option<PathBuf>,
    /// Worker threads (`None`: one per core).
    pub threads: Option<usize>,
    /// Serve the viewer on this loopback port while the fit runs.
    pub view: Option<u16>,
}

/// What [`fit_dataset`] did: the fit and the PSNR per split.
#[derive(Clone, Debug, PartialEq)]
pub struct FitSummary {
    out: PathBuf,
    kernels: usize,
    steps: usize,
    seconds: f64,
    background: [f64; 3],
    /// The score of every non-empty split.
    pub splits: Vec<SplitScore>,
}

impl fmt::Display for FitSummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{}: {} kernels fitted in {} steps, {:.1} s; background ({:.4}, {:.4}, {:.4})",
            self.out.display(),
            self.kernels,
            self.steps,
            self.seconds,
            self.background[0],
            self.background[1],
            self.background[2]
        )?;
        for score in &self.splits {
            write!(
                f,
                "\n  {}: {} views, MSE {:.3e}, PSNR {:.2} dB",
                score.split,
                score.views,
                score.mse,
                score.psnr(),
            )?;
            // On a line of its own, so that scripts reading the line above keep working.
            write!(
                f,
                "\n    per view: mean PSNR {:.2} dB",
                score.mean_view_psnr
            )?;
            if let Some(ssim) = score.ssim {
                write!(f, ", mean SSIM {ssim:.4}")?;
            }
        }
        Ok(())
    }
}

/// Progress of a fit: one tick per step, with the step's record.
pub trait FitProgress: Send {
    /// The fit of `steps` steps begins.
    fn start(&mut self, steps: usize);
    /// Something the user should know before the fit runs.
    fn note(&mut self, text: &str);
    /// A step is done; `heldout_psnr` is the latest held-out PSNR measured, `seconds_left`
    /// the estimate of the time the fit has left ([`crate::fit::time_left`]).
    fn step(&mut self, record: &StepRecord, heldout_psnr: Option<f64>, seconds_left: Option<f64>);
}

impl FitProgress for Silent {
    fn start(&mut self, _: usize) {}
    fn note(&mut self, _: &str) {}
    fn step(&mut self, _: &StepRecord, _: Option<f64>, _: Option<f64>) {}
}

/// Refuses, before the dataset is decoded, a fit whose images (`photos`) and kernels would
/// not fit in memory ([`fit_memory`]).
fn check_fit_memory(request: &FitRequest, photos: PhotoMemory) -> Result<()> {
    let (bytes, what) = fit_memory(request, photos)?;
    crate::io::memory::check(bytes, &what)
}

/// What a fit will hold, in bytes, and what for ([`crate::io::memory`]): the photos as the
/// loader keeps them (`photos`, [`crate::io::dataset::photo_memory`]: one decode per file, one
/// undistorted or downscaled copy per file, mask and lens, weights per frame) and what
/// preparing the largest holds; a coarse stage's copy of them; the kernels (the start, or an alpha fit's budget); each view
/// rendered at once (one per worker thread, up to the batch) with its frame and its kernels'
/// copies and gradients.
fn fit_memory(request: &FitRequest, photos: PhotoMemory) -> Result<(u64, String)> {
    use crate::io::memory::{FIT_BYTES_PER_KERNEL, RENDER_BYTES_PER_PIXEL, VIEW_BYTES_PER_KERNEL};
    let (largest_view, frames) = (photos.largest_view, photos.frames);
    // The additive fit's start, and an alpha fit's budget (unless the additive blend is
    // asked for): what either may hold.
    let additive = request.settings.additive_plan("").ok();
    let alpha = request.settings.alpha_options("").ok();
    let mut kernels = match Init::parse_builtin(&request.init)? {
        Some(Init::Random(n)) => n,
        Some(Init::Auto) => additive.as_ref().map_or(1, |p| p.start_kernels.max(1)),
        _ => 0,
    };
    let mut batch = additive.as_ref().map_or(1, |p| p.batch_size);
    // A coarse stage's copy of the training views: at most the ½-size one, a quarter of
    // the pixels kept ([`crate::fit::coarse`]).
    let mut coarse_copy = 0;
    if let Some(alpha) = alpha.filter(|_| request.blend != Some(Blend::Additive)) {
        kernels = kernels.max(alpha.max_kernels);
        batch = batch.max(alpha.batch_size);
        if alpha.coarse != CoarseToFine::Off {
            coarse_copy = photos.kept / 4;
        }
    }
    // The fit runs on `--threads` workers (or the global pool's), one view on each.
    let threads = request.threads.unwrap_or_else(rayon::current_num_threads);
    let side_by_side = threads.clamp(1, batch.max(1)) as u64;
    let per_kernel = FIT_BYTES_PER_KERNEL + VIEW_BYTES_PER_KERNEL * side_by_side;
    let frames_held =
        side_by_side.saturating_mul(RENDER_BYTES_PER_PIXEL.saturating_mul(largest_view));
    Ok((
        photos
            .kept
            .saturating_add(photos.working)
            .saturating_add(coarse_copy)
            .saturating_add(frames_held)
            .saturating_add((kernels as u64).saturating_mul(per_kernel)),
        format!("fitting up to {kernels} kernels to {frames} frames"),
    ))
}

/// Fits kernels to the dataset in `request.views` and writes the scene (and the log):
/// checks the outputs and the memory, reads the dataset and the start, asks the plan,
/// runs the fit, writes.
pub fn fit_dataset(request: &FitRequest, progress: &mut dyn FitProgress) -> Result<FitSummary> {
    request.settings.validate()?;
    // The dataset's description is read once, for its files, the memory estimate and the
    // views.
    let source = DatasetSource::open(&request.views);
    check_fit_outputs(request, &source)?;
    let options = dataset_options(request);
    check_fit_memory(request, source.photo_memory_as(&options))?;
    // A busy port is refused before the dataset is read.
    // Spread over MPI ranks, rank 0 alone serves the viewer and writes the outputs.
    let leader = crate::fit::spread::is_leader();
    let server = request
        .view
        .filter(|_| leader)
        .map(|port| Server::bind("127.0.0.1", port))
        .transpose()?;
    let dataset = read_dataset(request, source, &options, progress)?;
    let init = match Init::parse_builtin(&request.init)? {
        Some(init) => init,
        None => Init::Scene(load_scene(Path::new(&request.init))?),
    };
    let origin = crate::io::dataset::training_file(&request.views);
    let mut ready = request.settings.prepare(
        request.blend,
        init,
        &request.init,
        &dataset,
        &origin.display().to_string(),
    )?;
    if let Some(note) = idle_ranks_note(ready.training.batch_size) {
        ready.notes.push(note);
    }
    for note in &ready.notes {
        progress.note(note);
    }
    let (steps, render) = (ready.training.steps, ready.training.render);
    let heldout = if dataset.val.is_empty() {
        &dataset.test
    } else {
        &dataset.val
    };
    let viewer = server.map(|server| {
        FitViewer::start(
            server,
            &ready.framed_start(),
            &dataset,
            &render,
            steps,
            progress,
        )
    });
    progress.start(steps);
    let mut last_heldout = None;
    let mut time_left = ready.time_left(&dataset.train);
    // Without a thread count the steps run on a thread of the global pool, so each step's
    // parallel loops start there instead of being handed over one by one; not with a live
    // viewer, whose render thread needs the pool meanwhile. The step's callback only hands
    // the viewer a snapshot: nothing here waits on another thread.
    let records = with_threads_on_pool_unless_shared(request.threads, viewer.is_some(), || {
        ready.run(&dataset.train, heldout, |record, scene| {
            if record.heldout_psnr.is_some() {
                last_heldout = record.heldout_psnr;
            }
            time_left.record(record);
            progress.step(record, last_heldout, time_left.seconds_left());
            if let Some(viewer) = &viewer {
                viewer.step(record, scene);
            }
        })
    })??;
    drop(viewer);
    if records.len() < steps
        && let Some(stop) = ready.training.early_stop
    {
        progress.note(&format!(
            "stopped after step {} of {steps}: the held-out PSNR rose by less than {} dB over the last {:.0} % of the steps",
            records.len(),
            stop.min_gain_db,
            100.0 * stop.flat_fraction
        ));
    }
    let scene = &ready.scene;
    if leader {
        write_fit(request, scene, &records)?;
    }
    let splits = with_threads_on_pool(request.threads, || {
        evaluate_splits(scene, &dataset, &render)
    })??;
    Ok(FitSummary {
        out: request.out.clone(),
        kernels: scene.len(),
        steps: records.len(),
        seconds: records.last().map_or(0.0, |r| r.seconds),
        background: scene.background,
        splits,
    })
}

/// Refuses, before any work, outputs that cannot be written or that would replace an input
/// (the dataset's files, the start): a fit is never lost to an unwritable path.
fn check_fit_outputs(request: &FitRequest, source: &DatasetSource) -> Result<()> {
    let mut inputs = source.files().all();
    inputs.push(PathBuf::from(&request.init));
    let inputs: Vec<&Path> = inputs.iter().map(PathBuf::as_path).collect();
    check_output(&request.out, &["json", "ply"], &inputs)?;
    if let Some(log) = &request.log {
        check_output(log, &[], &inputs)?;
        if same_file(log, &request.out) {
            return Err(crate::model::Error::setting(
                &["log", "out"],
                format!("{}: `log` and `out` name the same file", log.display()),
            ));
        }
    }
    Ok(())
}

/// How the request reads its dataset.
fn dataset_options(request: &FitRequest) -> DatasetOptions {
    DatasetOptions {
        background: request
            .settings
            .background
            .unwrap_or([0.0; 3])
            .map(|b| b as f32),
        downscale: request.downscale,
        strict: request.strict,
        allow_outside_images: request.allow_outside_images,
        frames: request.frames,
        fps: request.fps,
    }
}

/// A note when the fit is spread over more MPI ranks than a step has views: rank `r` renders
/// the batch positions `p ≡ r (mod N)` ([`crate::fit::spread`]), so ranks from `batch` on
/// only wait. The batch is not raised to the rank count, since the fitted scene must not
/// depend on it.
fn idle_ranks_note(batch: usize) -> Option<String> {
    let ranks = crate::fit::spread::ranks()?.size();
    (ranks > batch).then(|| {
        let idle = match ranks - batch {
            1 => "1 rank renders nothing and only waits".to_string(),
            n => format!("{n} ranks render nothing and only wait"),
        };
        format!(
            "{ranks} ranks and {batch} views a step: {idle} (give `batch` {ranks} or more to use every rank)"
        )
    })
}

/// The dataset, read with `options`; its notes, and what the user should know about its
/// images and cameras, shown.
fn read_dataset(
    request: &FitRequest,
    source: DatasetSource,
    options: &DatasetOptions,
    progress: &mut dyn FitProgress,
) -> Result<Dataset> {
    let dataset = source.load(options)?;
    for note in &dataset.notes {
        progress.note(note);
    }
    if dataset.transparent && request.settings.background.is_none() {
        progress.note(
            "images with transparency were composited over black (`background` chooses the colour)",
        );
    }
    Ok(dataset)
}

/// Writes the fitted scene and the log.
fn write_fit(request: &FitRequest, scene: &Scene, records: &[StepRecord]) -> Result<()> {
    save_scene(scene, &request.out)?;
    if let Some(log) = &request.log {
        let mut lines = String::new();
        for record in records {
            lines.push_str(&serde_json::to_string(record).expect("a record serialises"));
            lines.push('\n');
        }
        write_bytes_atomically(log, lines.as_bytes())?;
    }
    Ok(())
}

/// How often a running fit hands its viewer a copy of its scene.
const VIEW_SNAPSHOT_EVERY: Duration = Duration::from_secs(3);
/// The share of the time the viewer of a running fit may render (the fit keeps the rest).
const VIEW_DUTY: f64 = 0.05;

/// The viewer of a running fit ([`crate::view`]): served on its own thread, handed a
/// snapshot of the scene every [`VIEW_SNAPSHOT_EVERY`]; stops when dropped.
struct FitViewer {
    live: Arc<Live>,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl FitViewer {
    /// Serves `scene` (the start, framed as the fitted scene will be) and `dataset`'s views.
    fn start(
        server: Server,
        scene: &Scene,
        dataset: &crate::model::Dataset,
        render: &crate::render::RenderOptions,
        steps: usize,
        progress: &mut dyn FitProgress,
    ) -> FitViewer {
        let live = Arc::new(Live::new(steps, VIEW_SNAPSHOT_EVERY));
        let views: Vec<_> = dataset
            .train
            .iter()
            .chain(&dataset.val)
            .chain(&dataset.test)
            .cloned()
            .collect();
        let showing = Showing {
            title: "fit".into(),
            scene: Arc::new(scene.clone()),
            views: Arc::new(views),
            options: *render,
            live: Some(Arc::clone(&live)),
            duty: VIEW_DUTY,
        };
        progress.note(&format!("viewing the fit at {}", server.url()));
        let stop = Arc::new(AtomicBool::new(false));
        let flag = Arc::clone(&stop);
        let thread = std::thread::spawn(move || {
            // Serving ends only when stopped; its errors have no reader once the fit runs.
            let _ = server.run(&showing, &flag);
        });
        FitViewer {
            live,
            stop,
            thread: Some(thread),
        }
    }

    fn step(&self, record: &StepRecord, scene: &Scene) {
        let point = StepPoint {
            step: record.step,
            seconds: record.seconds,
            loss: record.train_loss,
            heldout_psnr: record.heldout_psnr,
            kernels: record.kernels,
        };
        self.live.step(point, || scene.clone());
    }
}

impl Drop for FitViewer {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::image_file::{BitDepth, save_image};
    use crate::model::Image;

    /// [`fit_memory`] of the dataset in `views` as a fit reads it.
    fn estimate(views: &Path) -> Result<(u64, String)> {
        let request = request(views);
        let photos = crate::io::dataset::photo_memory(views, request.downscale);
        fit_memory(&request, photos)
    }

    fn request(views: &Path) -> FitRequest {
        FitRequest {
            views: views.to_path_buf(),
            downscale: 1,
            strict: false,
            allow_outside_images: false,
            frames: None,
            fps: None,
            init: "random:10".into(),
            settings: FitSettings::default(),
            blend: Some(Blend::Additive),
            out: views.join("fit.json"),
            log: None,
            threads: Some(1),
            view: None,
        }
    }

    fn photo(path: &Path) {
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        save_image(&Image::filled(64, 48, [0.5; 3]), path, BitDepth::Eight).unwrap();
    }

    /// Each 64×48 photo kept as linear RGB (12 bytes a pixel), and one decoded beside it
    /// (16 bytes a pixel).
    const PHOTO_KEPT: u64 = 64 * 48 * 12;
    const DECODE: u64 = 64 * 48 * 16;

    #[test]
    fn the_estimate_counts_a_colmap_models_photos() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let sparse = d.join("sparse/0");
        std::fs::create_dir_all(&sparse).unwrap();
        std::fs::write(sparse.join("cameras.txt"), "1 PINHOLE 64 48 50 50 32 24\n").unwrap();
        std::fs::write(
            sparse.join("images.txt"),
            "1 1 0 0 0 0 0 4 1 a.png\n\n2 1 0 0 0 0 0 4 1 b.png\n\n3 1 0 0 0 0 0 5 1 a.png\n\n",
        )
        .unwrap();
        photo(&d.join("images/a.png"));
        photo(&d.join("images/b.png"));
        let (with, what) = estimate(d).unwrap();
        assert!(what.contains("3 frames"), "{what}");
        std::fs::remove_dir_all(d.join("images")).unwrap();
        let (without, _) = estimate(d).unwrap();
        // Two distinct files (a.png named twice is decoded once).
        assert!(
            with >= without + 2 * PHOTO_KEPT + DECODE,
            "{with} with the photos, {without} without"
        );
        assert!(with < without + 3 * PHOTO_KEPT + DECODE + 2 * 64 * 48 * 40);
    }

    #[test]
    fn the_estimate_counts_every_frames_mask() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        photo(&d.join("a.png"));
        photo(&d.join("m.png"));
        let frame = |k: u32| {
            serde_json::json!({"file_path": "a.png", "mask_path": "m.png", "time": k,
                "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]})
        };
        let transforms = serde_json::json!({"camera_angle_x": 0.8, "frames": [frame(0), frame(1)]});
        std::fs::write(d.join("transforms.json"), transforms.to_string()).unwrap();
        let (with, _) = estimate(d).unwrap();
        let unmasked = |k: u32| {
            serde_json::json!({"file_path": "a.png", "time": k,
                "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]})
        };
        let transforms =
            serde_json::json!({"camera_angle_x": 0.8, "frames": [unmasked(0), unmasked(1)]});
        std::fs::write(d.join("transforms.json"), transforms.to_string()).unwrap();
        let (without, _) = estimate(d).unwrap();
        // One f32 weight a pixel for each of the two frames, and the mask's decode and
        // weights while the largest photo is prepared (32 bytes a pixel).
        assert_eq!(with - without, 2 * 64 * 48 * 4 + 32 * 64 * 48);
    }
}
