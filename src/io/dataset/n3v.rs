//! The Neural 3D Video (N3V) layout: a rig of synchronised cameras filmed over time, as
//! the dataset ships it or with its frames extracted:
//!
//! ```text
//! DIR/poses_bounds.npy   DIR/cam00.mp4 cam01.mp4 ...            (as shipped)
//! DIR/poses_bounds.npy   DIR/cam00/images/0000.png 0001.png ...  (frames extracted)
//! ```
//!
//! A folder with a `poses_bounds.npy` is this format's. The file is LLFF's: a float array
//! of shape `(N, 17)`, one row per camera in the order of the cameras' names (`cam00`,
//! `cam01`, ...: the videos, or the folders holding `images/`), each a row-major 3×5 matrix
//! `[R | t | hwf]` and two depth bounds. `R`'s columns are the camera's down, right and
//! back axes in world space and `t` its centre (camera to world); `hwf` is the image height,
//! width and focal length, pixels. The pose is converted once, exactly (a permutation and
//! a sign of columns), to the OpenGL camera-to-world matrix `[right, -down, back | t]` and
//! from there to the world→camera matrix of SPEC §3, in the file's own world: no
//! recentring, rescaling or NDC. The intrinsics are `hwf`'s focal length scaled to the
//! image as read (`fx = f · w / W`, `fy = f · h / H`), the principal point at its centre;
//! `downscale` then divides them as it does for photos. The bounds (LLFF's near and far
//! depths, which set its NDC planes) are checked and kept as the dataset's depth range, the
//! depths a start searches ([`crate::fit::rig_start`]).
//!
//! Every camera has the same frames (the same file names, or the same frame count in each
//! video); frame `k` of `F` is at time `k / (F - 1)` (0 for one frame), or `k / fps`
//! seconds with [`DatasetOptions::fps`]; [`DatasetOptions::frames`] chooses which frames
//! are read. The first camera (`cam00`) is held out as `test`, as the dataset's authors do;
//! a rig of one camera trains on it. Videos are decoded by ffmpeg ([`super::video`]),
//! scaled by `downscale` on the way, one frame held at a time.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::model::camera::Camera;
use crate::model::distortion::Distortion;
use crate::model::error::{Error, Result, check_finite};
use crate::model::{Dataset, View};

use super::frames::{Frame, FrameSource, inside_dataset, load_views};
use super::npy::{Array2, read_npy};
use super::photo_memory::{FramePhoto, PhotoMemory, estimate};
use super::photos::{Photos, Source};
use super::video::{Decoder, VideoInfo, probe};
use super::{DatasetFiles, DatasetOptions, Description, Format, FrameRange, check_downscale};

/// The N3V layout.
pub(super) struct N3v;

/// Its camera file.
const FILE: &str = "poses_bounds.npy";

/// Columns of a row of `poses_bounds.npy`: the 3×5 matrix and the two bounds.
const COLUMNS: usize = 17;

/// The extensions of extracted frames.
const IMAGE_EXTENSIONS: [&str; 3] = ["png", "jpg", "jpeg"];

impl Format for N3v {
    fn sign(&self) -> &'static str {
        FILE
    }

    fn description_files(&self, dir: &Path) -> Vec<PathBuf> {
        vec![dir.join(FILE)]
    }

    fn claims(&self, dir: &Path) -> Option<PathBuf> {
        let file = dir.join(FILE);
        file.is_file().then_some(file)
    }

    fn read(&self, dir: &Path) -> Box<dyn Description> {
        let file = dir.join(FILE);
        Box::new(Rig {
            dir: dir.to_path_buf(),
            poses: read_npy(&file),
            cameras: find_cameras(dir),
            file,
        })
    }
}

/// Where one camera's frames are.
enum CameraFrames {
    /// Extracted, sorted by name.
    Images(Vec<PathBuf>),
    /// A video, and what ffprobe says of it.
    Video(PathBuf, Result<VideoInfo>),
}

/// One camera of the rig: its name (`cam00`) and its frames.
struct RigCamera {
    name: String,
    frames: CameraFrames,
}

/// A rig as read once: its poses and its cameras.
struct Rig {
    dir: PathBuf,
    file: PathBuf,
    poses: Result<Array2>,
    cameras: Result<Vec<RigCamera>>,
}

/// The cameras in `dir`, by number: `camNN/images/` folders, or `camNN.mp4` videos where
/// no such folder is.
fn find_cameras(dir: &Path) -> Result<Vec<RigCamera>> {
    let entries = std::fs::read_dir(dir).map_err(|e| Error::read(dir, "cannot list", e))?;
    let mut found: BTreeMap<(u64, String), CameraFrames> = BTreeMap::new();
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        let (stem, video) = match name.strip_suffix(".mp4") {
            Some(stem) => (stem.to_string(), true),
            None => (name.clone(), false),
        };
        let Some(number) = stem
            .strip_prefix("cam")
            .filter(|d| !d.is_empty() && d.bytes().all(|b| b.is_ascii_digit()))
            .and_then(|d| d.parse::<u64>().ok())
        else {
            continue;
        };
        let path = entry.path();
        let key = (number, stem);
        if video && !path.is_dir() {
            // Read only inside the folder, and only a regular file (a FIFO would hold
            // ffprobe forever): refused, naming the camera, when it loads.
            let origin = dir.join(FILE).display().to_string();
            let info =
                inside_dataset(dir, &name, &origin, &key.1, "video").and_then(|real| probe(&real));
            found
                .entry(key)
                .or_insert_with(|| CameraFrames::Video(path.clone(), info));
        } else if !video && path.join("images").is_dir() {
            found.insert(
                key,
                CameraFrames::Images(list_images(&path.join("images"))?),
            );
        }
    }
    if found.is_empty() {
        return Err(Error::malformed(
            &dir.join(FILE).display().to_string(),
            format!(
                "no camera beside it in {}: neither camNN.mp4 videos nor camNN/images/ folders",
                dir.display()
            ),
        ));
    }
    Ok(found
        .into_iter()
        .map(|((_, name), frames)| RigCamera { name, frames })
        .collect())
}

/// The images in `folder`, sorted by name.
fn list_images(folder: &Path) -> Result<Vec<PathBuf>> {
    let entries = std::fs::read_dir(folder).map_err(|e| Error::read(folder, "cannot list", e))?;
    let mut images: Vec<PathBuf> = entries
        .flatten()
        .map(|e| e.path())
        .filter(|p| {
            p.extension().is_some_and(|x| {
                IMAGE_EXTENSIONS.contains(&x.to_string_lossy().to_ascii_lowercase().as_str())
            })
        })
        .collect();
    images.sort();
    Ok(images)
}

/// A file's name without its extension.
fn stem(path: &Path) -> String {
    path.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// The frames every camera has, `F`, checked: the same file names in every `images/`
/// folder, or the same count in every video.
fn frame_count(dir: &Path, cameras: &[RigCamera]) -> Result<usize> {
    let (first, rest) = cameras.split_first().expect("a rig has a camera");
    match &first.frames {
        CameraFrames::Images(images) => {
            let names: Vec<String> = images.iter().map(|p| stem(p)).collect();
            for camera in rest {
                let folder = dir.join(&camera.name).join("images");
                let CameraFrames::Images(other) = &camera.frames else {
                    return Err(mixed(dir, first, camera));
                };
                let other: Vec<String> = other.iter().map(|p| stem(p)).collect();
                let origin = folder.display().to_string();
                if let Some(name) = names.iter().find(|n| !other.contains(n)) {
                    return Err(Error::invalid(
                        &origin,
                        format!("frame {name}"),
                        "file",
                        format!(
                            "missing ({}/images has it; every camera films the same frames)",
                            first.name
                        ),
                    ));
                }
                if let Some(name) = other.iter().find(|n| !names.contains(n)) {
                    return Err(Error::invalid(
                        &origin,
                        format!("frame {name}"),
                        "file",
                        format!(
                            "{}/images has no such frame (every camera films the same frames)",
                            first.name
                        ),
                    ));
                }
            }
            Ok(names.len())
        }
        CameraFrames::Video(..) => {
            let mut counts = Vec::new();
            for camera in cameras {
                let CameraFrames::Video(path, info) = &camera.frames else {
                    return Err(mixed(dir, first, camera));
                };
                match info {
                    Ok(info) => counts.push((info.frames, path)),
                    Err(_) => {
                        let origin = path.display().to_string();
                        return Err(Error::malformed(&origin, "ffprobe cannot read it"));
                    }
                }
            }
            let most = counts.iter().map(|c| c.0).max().unwrap_or(0);
            let longest = counts
                .iter()
                .find(|c| c.0 == most)
                .map(|c| c.1)
                .expect("a video");
            if let Some((count, path)) = counts.iter().find(|c| c.0 != most) {
                return Err(Error::invalid(
                    &path.display().to_string(),
                    "video",
                    "frames",
                    format!(
                        "{count} frames, but {} has {most} (every camera films the same frames)",
                        longest.display()
                    ),
                ));
            }
            Ok(most)
        }
    }
}

/// The first video ffprobe could not read, as its error.
fn probe_errors(cameras: &mut [RigCamera]) -> Result<()> {
    for camera in cameras {
        if let CameraFrames::Video(_, info) = &mut camera.frames
            && info.is_err()
        {
            let placeholder = Ok(VideoInfo {
                width: 0,
                height: 0,
                frames: 0,
            });
            return std::mem::replace(info, placeholder).map(|_| ());
        }
    }
    Ok(())
}

/// The error of a rig whose cameras are given two ways.
fn mixed(dir: &Path, first: &RigCamera, other: &RigCamera) -> Error {
    Error::malformed(
        &dir.join(FILE).display().to_string(),
        format!(
            "{} is given one way and {} the other (a camNN.mp4 video, or camNN/images/ frames): give every camera the same way",
            first.name, other.name
        ),
    )
}

/// The pose row of every camera checked against the cameras found.
fn check_poses(file: &Path, poses: &Array2, cameras: &[RigCamera]) -> Result<()> {
    let origin = file.display().to_string();
    if poses.cols != COLUMNS {
        return Err(Error::invalid(
            &origin,
            "header",
            "shape",
            format!(
                "({}, {}): LLFF's poses_bounds has {COLUMNS} columns per camera (a 3×5 pose and two bounds)",
                poses.rows, poses.cols
            ),
        ));
    }
    if poses.rows != cameras.len() {
        let names: Vec<&str> = cameras.iter().map(|c| c.name.as_str()).collect();
        return Err(Error::invalid(
            &origin,
            "header",
            "shape",
            format!(
                "{} cameras, but the folder has {}: {}",
                poses.rows,
                cameras.len(),
                crate::model::error::cut(&names.join(", "), 200)
            ),
        ));
    }
    for (r, camera) in cameras.iter().enumerate() {
        let row = poses.row(r);
        let item = format!("camera {r} ({})", camera.name);
        let pose: Vec<f64> = (0..3)
            .flat_map(|i| row[5 * i..5 * i + 4].to_vec())
            .collect();
        check_finite(&origin, &item, "pose", &pose)?;
        let hwf = [row[4], row[9], row[14]];
        if hwf.iter().any(|v| !v.is_finite() || *v <= 0.0) {
            return Err(Error::invalid(
                &origin,
                &item,
                "hwf",
                format!("{hwf:?}: the height, width and focal length must be positive"),
            ));
        }
        check_finite(&origin, &item, "bounds", &row[15..17])?;
    }
    Ok(())
}

/// The least near and the greatest far bound of the rows, when they order as bounds do
/// (`0 < near < far`); `None` otherwise (the bounds are then not used).
fn depth_range(poses: &Array2) -> Option<[f64; 2]> {
    let (near, far) = (0..poses.rows).fold((f64::INFINITY, 0.0_f64), |(near, far), r| {
        let row = poses.row(r);
        (near.min(row[15]), far.max(row[16]))
    });
    (near > 0.0 && near < far && far.is_finite()).then_some([near, far])
}

/// `[fx, fy, cx, cy]` of a camera whose row is `row` for an image of `(w, h)` pixels: the
/// focal length of `hwf` scaled to the image, the principal point at its centre.
fn intrinsics(row: &[f64], (w, h): (u32, u32)) -> [f64; 4] {
    let (height, width, focal) = (row[4], row[9], row[14]);
    let (w, h) = (f64::from(w), f64::from(h));
    [focal * w / width, focal * h / height, 0.5 * w, 0.5 * h]
}

/// The camera of pose row `row` for an image of `size` with intrinsics `k`: LLFF's
/// camera-to-world columns `[down, right, back | t]` as OpenGL's `[right, -down, back | t]`
/// (exact: a permutation and a sign), then SPEC §3's world→camera.
fn llff_camera(row: &[f64], (w, h): (u32, u32), k: [f64; 4]) -> Result<Camera> {
    let m = |i: usize, j: usize| row[5 * i + j];
    let gl = |i: usize| [m(i, 1), -m(i, 0), m(i, 2), m(i, 3)];
    let c2w = [gl(0), gl(1), gl(2), [0.0, 0.0, 0.0, 1.0]];
    Camera::from_opengl_camera_to_world(w, h, k, c2w)
}

/// The frames read of `count`: all, or those `range` chooses.
fn selected(count: usize, range: Option<FrameRange>) -> Result<Vec<usize>> {
    let range = range.unwrap_or(FrameRange {
        start: 0,
        end: None,
        step: 1,
    });
    let end = range.end.unwrap_or(count);
    if end > count || range.start >= end {
        return Err(Error::setting(
            &["frames"],
            format!(
                "`frames` {range} chooses no frame of the {count} every camera has (frames 0 to {})",
                count.saturating_sub(1)
            ),
        ));
    }
    Ok((range.start..end).step_by(range.step).collect())
}

/// The time of frame `k` of `count`.
fn frame_time(k: usize, count: usize, fps: Option<f64>) -> f64 {
    match fps {
        Some(fps) => k as f64 / fps,
        None if count > 1 => k as f64 / (count - 1) as f64,
        None => 0.0,
    }
}

impl Description for Rig {
    fn named_files(&self) -> DatasetFiles {
        let mut files = DatasetFiles::default();
        for camera in self.cameras.iter().flatten() {
            match &camera.frames {
                CameraFrames::Images(images) => files.photos.extend(images.iter().cloned()),
                CameraFrames::Video(path, _) => files.photos.push(path.clone()),
            }
        }
        files
    }

    fn frame_photos(&self) -> Vec<FramePhoto> {
        let real = |p: &PathBuf| p.canonicalize().unwrap_or_else(|_| p.clone());
        let cameras = self.cameras.iter().flatten();
        cameras
            .flat_map(|camera| match &camera.frames {
                CameraFrames::Images(images) => images.iter().map(real).collect(),
                CameraFrames::Video(..) => Vec::new(),
            })
            .map(|path| (path, None, Distortion::default()))
            .collect()
    }

    fn photo_memory(&self, options: &DatasetOptions) -> PhotoMemory {
        let Ok(cameras) = &self.cameras else {
            return PhotoMemory::default();
        };
        let Ok(count) = frame_count(&self.dir, cameras) else {
            return PhotoMemory::default();
        };
        let chosen = selected(count, options.frames).unwrap_or_default();
        let n = u64::from(options.downscale.max(1));
        let mut memory = PhotoMemory::default();
        let mut photos = Vec::new();
        for camera in cameras {
            match &camera.frames {
                CameraFrames::Images(images) => photos.extend(chosen.iter().map(|&k| {
                    let path = &images[k];
                    (
                        path.canonicalize().unwrap_or_else(|_| path.clone()),
                        None,
                        Distortion::default(),
                    )
                })),
                CameraFrames::Video(_, Ok(info)) => {
                    let pixels = u64::from(info.width) / n * (u64::from(info.height) / n);
                    let views = chosen.len() as u64;
                    memory.kept = memory.kept.saturating_add(12 * pixels * views);
                    // The pipe's bytes and the frame's floats.
                    memory.working = memory.working.max(15 * pixels);
                    memory.largest_view = memory.largest_view.max(pixels);
                    memory.frames += chosen.len();
                    memory.copies += chosen.len();
                    memory.files += 1;
                }
                CameraFrames::Video(_, Err(_)) => {}
            }
        }
        if photos.is_empty() {
            memory
        } else {
            estimate(photos, options.downscale)
        }
    }

    fn reads_frames(&self) -> bool {
        true
    }

    fn load(self: Box<Self>, options: &DatasetOptions) -> Result<Dataset> {
        check_downscale(options.downscale)?;
        let Rig {
            dir,
            file,
            poses,
            cameras,
        } = *self;
        let (poses, mut cameras) = (poses?, cameras?);
        probe_errors(&mut cameras)?;
        check_poses(&file, &poses, &cameras)?;
        let count = frame_count(&dir, &cameras)?;
        if let Some(fps) = options.fps
            && !(fps.is_finite() && fps > 0.0)
        {
            return Err(Error::setting(
                &["fps"],
                format!("`fps` {fps} must be a positive number"),
            ));
        }
        let chosen = selected(count, options.frames)?;
        let rig = Chosen {
            dir: &dir,
            origin: file.display().to_string(),
            poses: &poses,
            cameras: &cameras,
            chosen: &chosen,
            count,
            fps: options.fps,
        };
        let (views, transparent, mut notes) = match &cameras[0].frames {
            CameraFrames::Images(_) => {
                let loaded = load_views(&rig, options)?;
                (loaded.views, loaded.transparent, loaded.notes)
            }
            CameraFrames::Video(..) => (load_videos(&rig, options)?, false, Vec::new()),
        };
        let test_camera = format!("{}/", cameras[0].name);
        let hold_out = cameras.len() > 1;
        let (test, train): (Vec<View>, Vec<View>) = views
            .into_iter()
            .partition(|v| hold_out && v.name.starts_with(&test_camera));
        notes.push(format!(
            "{}: {} cameras × {} of {count} frames; {} held out as test",
            file.display(),
            cameras.len(),
            chosen.len(),
            if hold_out {
                cameras[0].name.as_str()
            } else {
                "no camera"
            }
        ));
        Ok(Dataset {
            train,
            val: Vec::new(),
            test,
            transparent,
            notes,
            blend: None,
            points: None,
            depth_range: depth_range(&poses),
        })
    }
}

/// A rig's frames as chosen, camera by camera.
struct Chosen<'a> {
    dir: &'a Path,
    origin: String,
    poses: &'a Array2,
    cameras: &'a [RigCamera],
    chosen: &'a [usize],
    /// Frames every camera has.
    count: usize,
    fps: Option<f64>,
}

impl Chosen<'_> {
    /// The camera and frame number of frame `index` (camera by camera).
    fn at(&self, index: usize) -> (usize, usize) {
        (
            index / self.chosen.len(),
            self.chosen[index % self.chosen.len()],
        )
    }

    /// The camera and time of frame `k` of camera `c` for an image of `size`, `k` its
    /// intrinsics.
    fn camera_at(
        &self,
        c: usize,
        k: usize,
        size: (u32, u32),
        intrinsics: [f64; 4],
        item: &str,
    ) -> Result<(Camera, f64)> {
        let camera = llff_camera(self.poses.row(c), size, intrinsics).map_err(|e| match e {
            Error::Invalid { field, message, .. } => {
                Error::invalid(&self.origin, item, &format!("pose ({field})"), message)
            }
            other => other,
        })?;
        Ok((camera, frame_time(k, self.count, self.fps)))
    }
}

impl FrameSource for Chosen<'_> {
    fn origin(&self) -> &str {
        &self.origin
    }

    fn count(&self) -> usize {
        self.cameras.len() * self.chosen.len()
    }

    fn frame(&self, index: usize) -> Result<Frame> {
        let (c, k) = self.at(index);
        let camera = &self.cameras[c];
        let CameraFrames::Images(images) = &camera.frames else {
            unreachable!("a rig of videos is not read frame by frame");
        };
        let path = &images[k];
        let file_name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let relative = format!("{}/images/{file_name}", camera.name);
        let item = format!("{} frame {}", camera.name, stem(path));
        let real = inside_dataset(self.dir, &relative, &self.origin, &item, "file")?;
        Ok(Frame {
            name: format!("{}/images/{}", camera.name, stem(path)),
            item,
            photo: Some(Source {
                image: path.clone(),
                real,
                mask: None,
                distortion: Distortion::default(),
                lens_origin: None,
            }),
        })
    }

    fn intrinsics(
        &self,
        index: usize,
        _: &Frame,
        _: &Source,
        size: (u32, u32),
    ) -> Result<[f64; 4]> {
        Ok(intrinsics(self.poses.row(self.at(index).0), size))
    }

    fn camera(
        &self,
        index: usize,
        frame: &Frame,
        size: (u32, u32),
        k: [f64; 4],
    ) -> Result<(Camera, f64)> {
        let (c, f) = self.at(index);
        self.camera_at(c, f, size, k, &frame.item)
    }
}

/// The views of a rig of videos: each decoded by ffmpeg up to the last frame chosen,
/// scaled by `downscale` on the way, one frame held at a time.
fn load_videos(rig: &Chosen, options: &DatasetOptions) -> Result<Vec<View>> {
    let n = options.downscale;
    // The frames come scaled: the shared steps do not scale them again.
    let mut photos = Photos::new(&DatasetOptions {
        downscale: 1,
        ..*options
    });
    let end = rig.chosen.last().map_or(0, |&k| k + 1);
    let mut views = Vec::with_capacity(rig.count());
    for (c, camera) in rig.cameras.iter().enumerate() {
        let CameraFrames::Video(path, Ok(info)) = &camera.frames else {
            unreachable!("frame_count checked every camera is a video ffprobe read");
        };
        let origin = path.display().to_string();
        let size = (info.width / n, info.height / n);
        if size.0 == 0 || size.1 == 0 {
            return Err(Error::setting(
                &["downscale"],
                format!(
                    "{origin}: {}×{} is smaller than `downscale` {n}",
                    info.width, info.height
                ),
            ));
        }
        let mut decoder = Decoder::start(path, (info.width, info.height), size, end)?;
        let mut wanted = rig.chosen.iter().copied().peekable();
        for k in 0..end {
            let Some(image) = decoder.next_frame()? else {
                return Err(Error::invalid(
                    &origin,
                    "video",
                    "frames",
                    format!(
                        "ffmpeg decoded {k} frames, but ffprobe counted {}",
                        info.frames
                    ),
                ));
            };
            if wanted.next_if_eq(&k).is_none() {
                continue;
            }
            let item = format!("{} frame {k}", camera.name);
            let source = Source {
                image: path.clone(),
                real: PathBuf::from(format!("{origin}#{k}")),
                mask: None,
                distortion: Distortion::default(),
                lens_origin: None,
            };
            let intrinsics = intrinsics(rig.poses.row(c), size);
            let (image, weights, intrinsics) = photos.prepare(
                source,
                Some(Arc::new(image)),
                intrinsics,
                &views,
                (&origin, &item),
            )?;
            let (camera_k, time) = rig.camera_at(c, k, size, intrinsics, &item)?;
            views.push(View {
                camera: camera_k,
                time,
                image,
                name: format!("{}/{k:04}", camera.name),
                weights,
            });
        }
        decoder.finish()?;
    }
    Ok(views)
}
