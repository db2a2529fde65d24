//! `video`: videos of a scene along camera paths — orbits at fixed times, a spiral through
//! time, or a path file — rendered here frame by frame and encoded by [`crate::io::video`].

use std::fmt;
use std::path::PathBuf;

use crate::io::image_file::{BitDepth, save_image};
use crate::io::output::{
    Outputs, Staging, Stamp, check_beside, check_replaceable, remove_if_unchanged, time_label,
    unique_names, write_marker,
};
use crate::io::path_file::{PathCamera, load_any_path, save_nerfstudio_path};
use crate::io::scene_file::load_scene;
use crate::io::shards::{Shard, Sharding, check_assembled, check_shared_folder, commit_shard};
use crate::io::video::{VideoFiles, VideoOptions, encode_frames, write_video};
use crate::model::{Error, Progress, Result, Scene};
use crate::render::{RenderContext, RenderOptions};
use crate::scenes::paths::{
    Circle, Lens, PathFrame, Up, even_times, framing_circle, lerp, orbit, spiral, time_range,
};
use crate::slice::TemporalIndex;
use crate::tasks::{with_threads, with_threads_on_pool};

/// An orbit or spiral: explicit, or framing the scene ([`framing_circle`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum CircleSpec {
    /// `centre, radius, elevation, frames` as given.
    Given(Circle),
    /// Framing every kernel alive at the path's times.
    Auto,
}

/// `splat4d video`.
#[derive(Clone, Debug, PartialEq)]
pub struct VideoRequest {
    /// Scene file.
    pub scene: PathBuf,
    /// An orbit at each of `times` (with neither a spiral nor a path: one framing orbit).
    pub orbit: Option<CircleSpec>,
    /// Times of the orbits (default: the start, middle and end of the scene's time range).
    pub times: Option<Vec<f64>>,
    /// One turn while time runs over `time_range`.
    pub spiral: Option<CircleSpec>,
    /// Time range of the spiral (default: the scene's, [`time_range`]).
    pub time_range: Option<[f64; 2]>,
    /// The axis orbits and spirals turn about (given circles' own `up` included); `None`:
    /// the scene's [`Scene::up`], else +y.
    pub up: Option<Up>,
    /// A camera path file.
    pub path: Option<PathBuf>,
    /// Output folder.
    pub out: PathBuf,
    /// Frame size of orbits and spirals (`None`: [`DEFAULT_SIZE`]).
    pub size: Option<(u32, u32)>,
    /// Vertical field of view of orbits and spirals, degrees (`None`: [`DEFAULT_FOV`]).
    pub fov: Option<f64>,
    /// Frame rate and which files to write.
    pub video: VideoOptions,
    /// Whether `video.fps` was asked for; otherwise a path file's own `fps` is used for its
    /// video.
    pub fps_given: bool,
    /// Rendering options.
    pub options: RenderOptions,
    /// Worker threads (`None`: one per core).
    pub threads: Option<usize>,
    /// Every frame, one shard of them, or the GIFs, MP4s and camera paths from the shards'
    /// frames ([`crate::io::shards`]).
    pub sharding: Sharding,
}

/// Frame size of orbits and spirals unless one is given.
pub const DEFAULT_SIZE: (u32, u32) = (256, 256);

/// Vertical field of view of orbits and spirals unless one is given, degrees.
pub const DEFAULT_FOV: f64 = 40.0;

impl VideoRequest {
    /// Frame size and field of view of orbits and spirals.
    #[must_use]
    pub fn lens(&self) -> Lens {
        let (width, height) = self.size.unwrap_or(DEFAULT_SIZE);
        Lens {
            width,
            height,
            fov_y_degrees: self.fov.unwrap_or(DEFAULT_FOV),
        }
    }

    /// An error naming the first setting given that no video of this request uses: the
    /// orbits' `times` without an orbit; the circles' `up`, `size` and `fov` with neither an
    /// orbit nor a spiral (a path's cameras have their own). (`time_range` is checked once
    /// the path file is read: its cameras without a time sweep it.)
    fn check_used(&self, orbit: bool) -> Result<()> {
        if !orbit && self.times.is_some() {
            return Err(Error::setting(
                &["times"],
                "`times` are the orbits' times, and no orbit is asked (only `spiral` or `path`): add `orbit`, or leave `times` out",
            ));
        }
        let circle_settings = [
            ("up", self.up.is_some()),
            ("size", self.size.is_some()),
            ("fov", self.fov.is_some()),
        ];
        if !orbit
            && self.spiral.is_none()
            && let Some(&(field, _)) = circle_settings.iter().find(|(_, given)| *given)
        {
            return Err(Error::setting(
                &[field],
                format!(
                    "`{field}` shapes the orbits and spirals, and only a `path` is asked, whose cameras are its own: add `orbit` or `spiral`, or leave `{field}` out"
                ),
            ));
        }
        Ok(())
    }
}

/// What [`write_videos`] wrote.
#[derive(Clone, Debug, PartialEq)]
pub struct VideoSummary {
    /// One entry per video.
    pub videos: Vec<VideoFiles>,
    /// Per video, its cameras as nerfstudio's `camera_path.json` (`DIR/NAME.camera_path.json`).
    pub camera_paths: Vec<PathBuf>,
}

impl fmt::Display for VideoSummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mut lines = Vec::new();
        for (k, files) in self.videos.iter().enumerate() {
            let mut line = format!("{}: {} frames", files.frames_dir.display(), files.frames);
            if let Some(path) = self.camera_paths.get(k) {
                line.push_str(&format!(", {}", path.display()));
            }
            if let Some(gif) = &files.gif {
                line.push_str(&format!(", {}", gif.display()));
            }
            if let Some(mp4) = &files.mp4 {
                line.push_str(&format!(", {}", mp4.display()));
            }
            lines.push(line);
        }
        if let Some(note) = self.videos.iter().find_map(|f| f.mp4_note.clone()) {
            lines.push(format!("note: {note}"));
        }
        f.write_str(&lines.join("\n"))
    }
}

/// Most frames the orbits of one run may have together (one orbit per time, each at most
/// [`crate::scenes::paths::MAX_PATH_FRAMES`]).
pub const MAX_ORBIT_FRAMES: usize = 10 * crate::scenes::paths::MAX_PATH_FRAMES;

/// A named camera path, with its own frame rate when its file gives one.
type NamedPath = (String, Vec<PathFrame>, Option<u32>);

/// The named camera paths of `request`.
fn paths(request: &VideoRequest, scene: &Scene) -> Result<Vec<NamedPath>> {
    let lens = &request.lens();
    let up = request.up.or(scene.up).unwrap_or_default();
    let circle = |spec: &CircleSpec, times: &[f64]| match spec {
        CircleSpec::Given(circle) => Circle { up, ..*circle },
        CircleSpec::Auto => framing_circle(scene, times, request.options.cutoff, lens, up),
    };
    let [t0, t1] = request.time_range.unwrap_or_else(|| time_range(scene));
    let times = request.times.clone().unwrap_or_else(|| {
        if t0 == t1 {
            vec![t0]
        } else {
            vec![t0, lerp(t0, t1, 0.5), t1]
        }
    });
    let nothing_asked =
        request.orbit.is_none() && request.spiral.is_none() && request.path.is_none();
    let orbit_spec = request.orbit.or(nothing_asked.then_some(CircleSpec::Auto));
    request.check_used(orbit_spec.is_some())?;
    // The time range spans the spiral, the orbits' default times and a path's cameras
    // without a time.
    let mut sweeps_time_range =
        request.spiral.is_some() || (orbit_spec.is_some() && request.times.is_none());
    // One orbit per time: their frames together are bounded too, before any is placed.
    let orbit_frames = match orbit_spec {
        Some(CircleSpec::Given(circle)) => circle.frames,
        Some(CircleSpec::Auto) => 60,
        None => 0,
    };
    let total = orbit_frames.saturating_mul(times.len());
    if total > MAX_ORBIT_FRAMES {
        return Err(Error::setting(
            &["times", "orbit"],
            format!(
                "{} orbits (one per `times`) of {orbit_frames} frames are {total} frames, more than the {MAX_ORBIT_FRAMES} a run may render: give fewer `times` or fewer frames to `orbit`",
                times.len()
            ),
        ));
    }
    let mut videos = Vec::new();
    if let Some(spec) = &orbit_spec {
        for &tau in &times {
            videos.push((
                format!("orbit_t{}", time_label(tau)),
                orbit(&circle(spec, &[tau]), lens, tau)?,
                None,
            ));
        }
    }
    if let Some(spec) = &request.spiral {
        let sweep = even_times([t0, t1], 11);
        videos.push((
            "spiral".into(),
            spiral(&circle(spec, &sweep), lens, [t0, t1])?,
            None,
        ));
    }
    if let Some(path) = &request.path {
        let name = path
            .file_stem()
            .map_or("path".into(), |s| s.to_string_lossy().into_owned());
        let name = crate::io::output::sanitize_label(&name, "path");
        // Cameras without a time (a nerfstudio path of a static scene) sweep the scene's time
        // range in order, as the spiral does.
        let file = load_any_path(path)?;
        sweeps_time_range |= file.cameras.iter().any(|c| c.time.is_none());
        if request.video.gif {
            one_screen_size(&file.cameras, path)?;
        }
        let sweep = even_times([t0, t1], file.cameras.len());
        let frames = file
            .cameras
            .iter()
            .zip(sweep)
            .map(|(c, t)| PathFrame {
                camera: c.camera,
                time: c.time.unwrap_or(t),
            })
            .collect();
        // The file's frame rate (nerfstudio's `fps`) unless one was asked for.
        let fps = file
            .fps
            .filter(|_| !request.fps_given)
            .map(|f| (f.round() as u32).clamp(1, 100));
        videos.push((name, frames, fps));
    }
    if request.time_range.is_some() && !sweeps_time_range {
        return Err(Error::setting(
            &["time_range"],
            "`time_range` spans the spiral, the orbits' default `times` and a path's cameras without a time, and this run has none of them: leave `time_range` out",
        ));
    }
    // Names that can never leave the folder or clash: orbits at times that round to one label,
    // a path file named like the spiral.
    let names: Vec<String> = videos.iter().map(|(name, ..)| name.clone()).collect();
    for ((name, ..), unique) in videos.iter_mut().zip(unique_names(&names)) {
        *name = unique;
    }
    Ok(videos)
}

/// What may be removed after a video is written: an earlier run's GIF or MP4 of its name,
/// recorded unchanged, that this run may not write again.
type Stale = Vec<(PathBuf, Stamp)>;

/// A GIF has one screen size: every camera of the path file `path` must have the first
/// one's (frames of another size would lie outside the GIF's screen). Refused before any
/// work, naming the first camera that differs.
fn one_screen_size(cameras: &[PathCamera], path: &std::path::Path) -> Result<()> {
    let Some(first) = cameras.first().map(|c| (c.camera.width, c.camera.height)) else {
        return Ok(());
    };
    let Some((k, (w, h))) = cameras
        .iter()
        .map(|c| (c.camera.width, c.camera.height))
        .enumerate()
        .find(|&(_, size)| size != first)
    else {
        return Ok(());
    };
    let field = if w == first.0 { "height" } else { "width" };
    Err(Error::setting(
        &["path", "gif"],
        format!(
            "{}: frame {k}: field `camera.{field}`: its camera is {w}×{h} but frame 0's is {}×{}; a GIF has one screen size, so `gif` needs every camera of the `path` at one size (or leave the GIF out)",
            path.display(),
            first.0,
            first.1
        ),
    ))
}

/// Checks, before any work, every output of the videos named `names` in `out` against the
/// inputs and each other: an existing frames folder must be an earlier video's, and an
/// existing GIF, MP4 or camera path this run writes must be one that video recorded,
/// unchanged ([`check_beside`]). Returns, per video, the recorded GIF and MP4 that this run
/// may leave unwritten (`--no-gif`, `--no-mp4`, ffmpeg failing): removed afterwards if still
/// unchanged, so that they never pass for the new frames — and a file the user made is kept.
fn check_outputs(
    request: &VideoRequest,
    names: &[&str],
    check_folder: impl Fn(&str, &std::path::Path) -> Result<()>,
) -> Result<Vec<Stale>> {
    let mut outputs = Outputs::new();
    outputs.input(&request.scene);
    if let Some(path) = &request.path {
        outputs.input(path);
    }
    let mut stale = Vec::new();
    for name in names {
        let frames = request.out.join(name);
        check_folder(name, &frames)?;
        outputs.folder(&frames);
        let mut earlier = Vec::new();
        for (ext, written) in [
            ("gif", request.video.gif),
            ("mp4", request.video.mp4),
            ("camera_path.json", true),
        ] {
            let file = request.out.join(format!("{name}.{ext}"));
            if written {
                check_beside(&frames, &file, "video")?;
                outputs.file(&file);
            }
            // Not written, or perhaps not (ffmpeg may fail): removed afterwards only when it
            // is the earlier run's, unchanged.
            if ext != "camera_path.json"
                && let Ok(Some(stamp)) = check_beside(&frames, &file, "video")
            {
                earlier.push((file, stamp));
            }
        }
        stale.push(earlier);
    }
    outputs.check()?;
    Ok(stale)
}

/// Renders and writes every video of `request`.
pub fn write_videos(request: &VideoRequest, progress: &mut dyn Progress) -> Result<VideoSummary> {
    request.options.validate()?;
    let fov = request.lens().fov_y_degrees;
    if !(fov > 0.0 && fov < 180.0) {
        return Err(Error::setting(
            &["fov"],
            format!("`fov` {fov} must be in (0, 180) degrees"),
        ));
    }
    let scene = load_scene(&request.scene)?;
    let videos = paths(request, &scene)?;
    // The largest frame of any video (a path file's cameras have their own sizes).
    let (w, h) = videos
        .iter()
        .flat_map(|(_, frames, _)| frames)
        .map(|f| (f.camera.width, f.camera.height))
        .max_by_key(|&(w, h)| u64::from(w) * u64::from(h))
        .unwrap_or_else(|| {
            let lens = request.lens();
            (lens.width, lens.height)
        });
    let per_pixel = crate::io::memory::VIDEO_BYTES_PER_PIXEL
        + if request.video.gif {
            crate::io::memory::GIF_BYTES_PER_PIXEL
        } else {
            0
        };
    crate::io::memory::check(
        (u64::from(w) * u64::from(h)).saturating_mul(per_pixel),
        &format!("{w}×{h} frames"),
    )?;
    match request.sharding {
        Sharding::Whole => write_whole(request, &scene, &videos, progress),
        Sharding::Shard(shard) => write_shard(request, &scene, &videos, shard, progress),
        Sharding::Assemble => assemble(request, &videos),
    }
}

/// Every video of `request`, frames and all, in one run.
fn write_whole(
    request: &VideoRequest,
    scene: &Scene,
    videos: &[NamedPath],
    progress: &mut dyn Progress,
) -> Result<VideoSummary> {
    let names: Vec<&str> = videos.iter().map(|(name, ..)| name.as_str()).collect();
    let stale = check_outputs(request, &names, |_, frames| {
        check_replaceable(frames, "video")
    })?;
    // Every video is written into a temporary folder inside `out` and moved into place once
    // all are complete: a run that fails leaves nothing it created.
    let staging = Staging::new(&request.out)?;
    progress.start("frames", videos.iter().map(|(_, f, _)| f.len()).sum());
    let mut context = RenderContext::new();
    // One scene, many frames: each frame visits only the kernels alive at its time.
    let index = TemporalIndex::new(scene, request.options.cutoff);
    let mut written = Vec::new();
    let mut camera_paths = Vec::new();
    for (name, frames, fps) in videos {
        let video = VideoOptions {
            fps: fps.unwrap_or(request.video.fps),
            ..request.video
        };
        // The cameras as nerfstudio's camera path, so other renderers can follow them.
        let camera_path = staging.path().join(format!("{name}.camera_path.json"));
        save_nerfstudio_path(frames, video.fps, &camera_path)?;
        let beside = [camera_path];
        let files = with_threads(request.threads, || {
            write_video(
                frames.len(),
                staging.path(),
                &request.out,
                name,
                &video,
                &beside,
                |k, image| {
                    let frame = &frames[k];
                    // Without a thread count this loop runs outside the pool: the frame goes to
                    // a thread of the global pool whole, not loop by loop. (Not the whole loop:
                    // it waits on the writer thread, whose own parallel work would then find a
                    // one-thread pool busy.) With one, the loop is on that pool already.
                    with_threads_on_pool(request.threads, || {
                        context.render_indexed(
                            scene,
                            &index,
                            &frame.camera,
                            frame.time,
                            &request.options,
                        )
                    })??;
                    // The frame goes to the writer; the context renders the next into `image`'s
                    // old buffer (the writer's spare, once it has handed one back).
                    context.swap_image(image);
                    progress.tick();
                    Ok(())
                },
            )
        })??;
        written.push(files);
        camera_paths.push(request.out.join(format!("{name}.camera_path.json")));
    }
    staging.commit(&[])?;
    remove_stale(&written, stale)?;
    Ok(VideoSummary {
        videos: written,
        camera_paths,
    })
}

/// An earlier run's GIF or MP4 of a name this run did not write would pass for one of
/// these frames: it goes, when it is still what that run recorded.
fn remove_stale(written: &[VideoFiles], stale: Vec<Stale>) -> Result<()> {
    for (files, earlier) in written.iter().zip(stale) {
        for (file, stamp) in earlier {
            if files.gif.as_ref() != Some(&file) && files.mp4.as_ref() != Some(&file) {
                remove_if_unchanged(&file, stamp)?;
            }
        }
    }
    Ok(())
}

/// The file names of a video's `count` frames.
fn frame_names(count: usize) -> Vec<String> {
    (0..count).map(|k| format!("frame_{k:04}.png")).collect()
}

/// What the frames of one video depend on: the scene file's bytes, the cameras and times,
/// the render options ([`crate::io::shards::fingerprint`]).
fn fingerprint(scene: &[u8], frames: &[PathFrame], options: &RenderOptions) -> String {
    let cameras = format!("{frames:?} {options:?}");
    crate::io::shards::fingerprint(&[scene, cameras.as_bytes()])
}

/// The scene file's bytes, for the fingerprint of the frames.
fn scene_bytes(request: &VideoRequest) -> Result<Vec<u8>> {
    std::fs::read(&request.scene).map_err(|e| Error::read(&request.scene, "cannot read", e))
}

/// Shard `shard`'s frames of every video of `request`, moved into each video's frame folder
/// beside the other shards' ([`commit_shard`]); no GIF, MP4 or camera path.
fn write_shard(
    request: &VideoRequest,
    scene: &Scene,
    videos: &[NamedPath],
    shard: Shard,
    progress: &mut dyn Progress,
) -> Result<VideoSummary> {
    let mut outputs = Outputs::new();
    outputs.input(&request.scene);
    if let Some(path) = &request.path {
        outputs.input(path);
    }
    for (name, ..) in videos {
        let frames = request.out.join(name);
        check_shared_folder(&frames, "video")?;
        outputs.folder(&frames);
    }
    outputs.check()?;
    let bytes = scene_bytes(request)?;
    let staging = Staging::new(&request.out)?;
    let mine = |frames: &[PathFrame]| (0..frames.len()).filter(|&k| shard.takes(k)).count();
    progress.start("frames", videos.iter().map(|(_, f, _)| mine(f)).sum());
    let mut context = RenderContext::new();
    let index = TemporalIndex::new(scene, request.options.cutoff);
    let mut written = Vec::new();
    for (name, frames, _) in videos {
        let staged = staging.path().join(name);
        std::fs::create_dir(&staged)
            .map_err(|e| Error::write(&request.out, "cannot write in the output folder", e))?;
        let mut names = Vec::new();
        for (k, frame) in frames.iter().enumerate().filter(|&(k, _)| shard.takes(k)) {
            with_threads(request.threads, || {
                context.render_indexed(scene, &index, &frame.camera, frame.time, &request.options)
            })??;
            let file = format!("frame_{k:04}.png");
            save_image(context.image(), &staged.join(&file), BitDepth::Eight)?;
            names.push(file);
            progress.tick();
        }
        let fingerprint = fingerprint(&bytes, frames, &request.options);
        let dir = request.out.join(name);
        commit_shard(&staged, &dir, "video", shard, &fingerprint, &names)?;
        written.push(VideoFiles {
            frames_dir: dir,
            frames: names.len(),
            gif: None,
            mp4: None,
            mp4_note: None,
        });
    }
    Ok(VideoSummary {
        videos: written,
        camera_paths: Vec::new(),
    })
}

/// The GIF, MP4 and camera path of every video of `request` from the frames its shards
/// wrote ([`check_assembled`]), and each frame folder's marker: the files of one run.
fn assemble(request: &VideoRequest, videos: &[NamedPath]) -> Result<VideoSummary> {
    let bytes = scene_bytes(request)?;
    let names: Vec<&str> = videos.iter().map(|(name, ..)| name.as_str()).collect();
    let stale = check_outputs(request, &names, |name, dir| {
        let (_, frames, _) = videos
            .iter()
            .find(|(n, ..)| n == name)
            .expect("a video of the request");
        let fingerprint = fingerprint(&bytes, frames, &request.options);
        check_assembled(dir, "video", &fingerprint, &frame_names(frames.len()))
    })?;
    let staging = Staging::new(&request.out)?;
    let mut written = Vec::new();
    let mut camera_paths = Vec::new();
    for (name, frames, fps) in videos {
        let video = VideoOptions {
            fps: fps.unwrap_or(request.video.fps),
            ..request.video
        };
        let dir = request.out.join(name);
        crate::io::shards::keep_only(&dir, &frame_names(frames.len()))?;
        save_nerfstudio_path(
            frames,
            video.fps,
            &staging.path().join(format!("{name}.camera_path.json")),
        )?;
        let files = encode_frames(
            frames.len(),
            &dir,
            staging.path(),
            &request.out,
            name,
            &video,
        )?;
        written.push(files);
        camera_paths.push(request.out.join(format!("{name}.camera_path.json")));
    }
    staging.commit(&[])?;
    for (files, camera_path) in written.iter().zip(&camera_paths) {
        let mut recorded: Vec<PathBuf> = files.gif.iter().chain(&files.mp4).cloned().collect();
        recorded.push(camera_path.clone());
        crate::io::shards::drop_shard_markers(&files.frames_dir)?;
        write_marker(&files.frames_dir, "video", &recorded)?;
    }
    remove_stale(&written, stale)?;
    Ok(VideoSummary {
        videos: written,
        camera_paths,
    })
}
