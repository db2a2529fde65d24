//! Multi-view datasets in the layouts dynamic and static splatting tools write.
//!
//! ```text
//! D-NeRF / Blender:   DIR/transforms_{train,val,test}.json   DIR/train/r_000.png ...
//! nerfstudio / instant-ngp:   DIR/transforms.json (every frame)   DIR/images/frame_00001.jpg ...
//! ```
//!
//! Each frame has a `file_path` (relative to `DIR`; without an extension it is looked up as
//! `.exr`, `.png`, `.jpg`, `.jpeg`, in that order), a row-major camera-to-world
//! `transform_matrix` with OpenGL axes (x right, y up, z backward; SPEC §3) and, for
//! dynamic scenes, a `time` (missing: 0, a static scene). A single `transforms.json` is
//! split as mip-NeRF 360 does: every 8th frame (0, 8, 16, ...) is held out as `test`, the
//! others train (a file of fewer than 8 frames trains on all); there is no `val`.
//!
//! Intrinsics, per frame or for the whole file (a frame's own win): `fl_x`, `fl_y`, `cx`,
//! `cy` in pixels, `w`, `h` (checked against the image); else `camera_angle_x` (horizontal
//! field of view, radians: `fx = ½ W / tan(½ camera_angle_x)`, `fy = fx`) or
//! `camera_angle_y`; the principal point defaults to the image centre. `camera_model` may be
//! a pinhole or an OpenCV model whose distortion coefficients (`k1`–`k4`, `p1`, `p2`) are all
//! zero; distortion is refused (undistort the images first). Keys not read are reported once
//! per file in [`Dataset::notes`], and ignored.
//!
//! Integer images are read as `value / (2^bits - 1)` (SPEC §5: linear, no sRGB curve, JPEG
//! included); RGBA images are composited over [`DatasetOptions::background`] (black by
//! default: the additive model's "nothing"). `downscale` N averages N×N blocks (a box
//! filter, like nerfstudio's `images_N` folders) and divides the intrinsics by N.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::io::image_file::{BitDepth, load_image_with_alpha, save_image};
use crate::io::json::parse_json;
use crate::io::write_bytes_atomically;
use crate::model::camera::Camera;
use crate::model::error::{Error, Result};
use crate::model::{Dataset, Image, View};

/// The three splits, in file order.
pub const SPLITS: [&str; 3] = ["train", "val", "test"];

/// Every `HOLDOUT`-th frame of a single `transforms.json` is a test frame.
pub const HOLDOUT: usize = 8;

/// Largest `downscale` factor.
pub const MAX_DOWNSCALE: u32 = 64;

/// How a dataset is read.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DatasetOptions {
    /// RGBA pixels are composited over this colour.
    pub background: [f32; 3],
    /// Average N×N blocks of pixels (1: the images as they are).
    pub downscale: u32,
    /// Read images whose real path (symlinks followed) lies outside the dataset's folder.
    pub allow_outside_images: bool,
}

impl Default for DatasetOptions {
    fn default() -> Self {
        DatasetOptions {
            background: [0.0; 3],
            downscale: 1,
            allow_outside_images: false,
        }
    }
}

/// The file as written by [`write_split`] (keys in this order).
#[derive(Serialize)]
struct WrittenTransforms {
    camera_angle_x: f64,
    fl_x: f64,
    fl_y: f64,
    cx: f64,
    cy: f64,
    w: u32,
    h: u32,
    frames: Vec<WrittenFrame>,
}

#[derive(Serialize)]
struct WrittenFrame {
    file_path: String,
    time: f64,
    transform_matrix: [[f64; 4]; 4],
}

/// Intrinsics and camera model, at the top of a file or in a frame.
#[derive(Clone, Debug, Default, Deserialize)]
struct Intrinsics {
    fl_x: Option<f64>,
    fl_y: Option<f64>,
    cx: Option<f64>,
    cy: Option<f64>,
    w: Option<u32>,
    h: Option<u32>,
    camera_model: Option<String>,
    k1: Option<f64>,
    k2: Option<f64>,
    k3: Option<f64>,
    k4: Option<f64>,
    p1: Option<f64>,
    p2: Option<f64>,
}

#[derive(Deserialize)]
struct TransformsFile {
    camera_angle_x: Option<f64>,
    camera_angle_y: Option<f64>,
    #[serde(flatten)]
    intrinsics: Intrinsics,
    frames: Vec<FrameEntry>,
    #[serde(flatten)]
    other: BTreeMap<String, serde_json::Value>,
}

#[derive(Deserialize)]
struct FrameEntry {
    file_path: String,
    time: Option<f64>,
    transform_matrix: [[f64; 4]; 4],
    #[serde(flatten)]
    intrinsics: Intrinsics,
    #[serde(flatten)]
    other: BTreeMap<String, serde_json::Value>,
}

/// Keys other tools write that carry nothing splat4d needs: skipped without a note.
const QUIETLY_IGNORED: [&str; 9] = [
    "aabb_scale",
    "scale",
    "offset",
    "applied_transform",
    "applied_scale",
    "ply_file_path",
    "rotation",
    "colmap_im_id",
    "sharpness",
];

/// Camera models that are pinholes once their distortion coefficients are zero.
const PINHOLE_MODELS: [&str; 5] = [
    "PINHOLE",
    "SIMPLE_PINHOLE",
    "OPENCV",
    "SIMPLE_RADIAL",
    "RADIAL",
];

/// The image file a `file_path` entry refers to: a regular file.
fn resolve_image(dir: &Path, file_path: &str) -> Option<PathBuf> {
    let base = dir.join(file_path);
    if base.extension().is_some() && base.is_file() {
        return Some(base);
    }
    ["exr", "png", "jpg", "jpeg"]
        .iter()
        .map(|ext| PathBuf::from(format!("{}.{ext}", base.display())))
        .find(|p| p.is_file())
}

/// The intrinsics `[fx, fy, cx, cy]` of a `w × h` image (before downscaling) from the
/// frame's own keys, then the file's, then the fields of view.
fn intrinsics(
    file: &TransformsFile,
    frame: &FrameEntry,
    (w, h): (u32, u32),
    origin: &str,
    item: &str,
) -> Result<[f64; 4]> {
    let (own, top) = (&frame.intrinsics, &file.intrinsics);
    for (field, value) in [
        ("k1", own.k1.or(top.k1)),
        ("k2", own.k2.or(top.k2)),
        ("k3", own.k3.or(top.k3)),
        ("k4", own.k4.or(top.k4)),
        ("p1", own.p1.or(top.p1)),
        ("p2", own.p2.or(top.p2)),
    ] {
        if let Some(v) = value
            && v != 0.0
        {
            return Err(Error::invalid(
                origin,
                item,
                field,
                format!(
                    "distortion coefficient {field} = {v}: only undistorted (pinhole) images are supported; undistort them first"
                ),
            ));
        }
    }
    if let Some(model) = own.camera_model.as_ref().or(top.camera_model.as_ref())
        && !PINHOLE_MODELS.contains(&model.as_str())
    {
        return Err(Error::invalid(
            origin,
            item,
            "camera_model",
            format!("{model} is not a pinhole model (expected one of {PINHOLE_MODELS:?})"),
        ));
    }
    for (field, value, actual) in [("w", own.w.or(top.w), w), ("h", own.h.or(top.h), h)] {
        if let Some(v) = value
            && v != actual
        {
            return Err(Error::invalid(
                origin,
                item,
                field,
                format!("{field} = {v} but the image is {w}×{h}"),
            ));
        }
    }
    let angle = |field: &str, value: Option<f64>| -> Result<Option<f64>> {
        match value {
            Some(a) if !(a > 0.0 && a < std::f64::consts::PI) => Err(Error::invalid(
                origin,
                "transforms",
                field,
                format!("{a} is not in (0, π)"),
            )),
            other => Ok(other),
        }
    };
    let from_x =
        angle("camera_angle_x", file.camera_angle_x)?.map(|a| 0.5 * f64::from(w) / (0.5 * a).tan());
    let from_y =
        angle("camera_angle_y", file.camera_angle_y)?.map(|a| 0.5 * f64::from(h) / (0.5 * a).tan());
    let fl_x = own.fl_x.or(top.fl_x);
    let fl_y = own.fl_y.or(top.fl_y);
    let fx = fl_x.or(from_x).or(fl_y).or(from_y).ok_or_else(|| {
        Error::invalid(
            origin,
            item,
            "fl_x",
            "no focal length: give fl_x (pixels) or camera_angle_x (radians)",
        )
    })?;
    let fy = fl_y.or(fl_x).or(from_y).unwrap_or(fx);
    Ok([
        fx,
        fy,
        own.cx.or(top.cx).unwrap_or(0.5 * f64::from(w)),
        own.cy.or(top.cy).unwrap_or(0.5 * f64::from(h)),
    ])
}

/// The mean of each `n × n` block (a box filter); the image shrinks to `⌊w/n⌋ × ⌊h/n⌋`.
#[must_use]
pub fn downscale(image: &Image, n: u32) -> Image {
    if n == 1 {
        return image.clone();
    }
    let (w, h) = (image.width / n, image.height / n);
    let mut pixels = Vec::with_capacity(3 * w as usize * h as usize);
    let inv = 1.0 / f64::from(n * n);
    for j in 0..h {
        for i in 0..w {
            let mut sum = [0.0_f64; 3];
            for dj in 0..n {
                for di in 0..n {
                    let p = image.pixel(n * i + di, n * j + dj);
                    for c in 0..3 {
                        sum[c] += f64::from(p[c]);
                    }
                }
            }
            pixels.extend(sum.map(|s| (s * inv) as f32));
        }
    }
    Image {
        width: w,
        height: h,
        pixels,
    }
}

/// What [`read_transforms`] found in one file.
struct FileViews {
    views: Vec<View>,
    transparent: bool,
    notes: Vec<String>,
}

/// A decoded image file: the (downscaled) image, whether some pixel was transparent, and
/// the size before downscaling.
type Decoded = (std::sync::Arc<Image>, bool, (u32, u32));

/// Reads one transforms file and its images.
fn read_transforms(dir: &Path, path: &Path, options: &DatasetOptions) -> Result<FileViews> {
    let origin = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|e| Error::read(path, "cannot read", e))?;
    let file: TransformsFile = parse_json(&text, &origin, "transforms")?;
    let n = options.downscale;
    if !(1..=MAX_DOWNSCALE).contains(&n) {
        return Err(Error::usage(format!(
            "--downscale {n} must be between 1 and {MAX_DOWNSCALE}"
        )));
    }
    let mut unread: BTreeSet<&str> = file.other.keys().map(String::as_str).collect();
    let mut views = Vec::with_capacity(file.frames.len().min(1 << 16));
    let mut transparent = false;
    let mut decoded: std::collections::HashMap<PathBuf, Decoded> = std::collections::HashMap::new();
    for (index, frame) in file.frames.iter().enumerate() {
        let item = format!("frame {index}");
        unread.extend(frame.other.keys().map(String::as_str));
        let image_path = resolve_image(dir, &frame.file_path).ok_or_else(|| {
            Error::invalid(
                &origin,
                &item,
                "file_path",
                format!(
                    "no image file at {} (.exr, .png, .jpg or .jpeg)",
                    frame.file_path
                ),
            )
        })?;
        if !options.allow_outside_images && !crate::io::output::inside(&image_path, dir) {
            return Err(Error::invalid(
                &origin,
                &item,
                "file_path",
                format!(
                    "{} lies outside the dataset's folder (by its real path, links followed); pass --allow-outside-images to read it",
                    frame.file_path
                ),
            ));
        }
        // Each distinct file is decoded once; frames that name it share the image.
        let key = image_path
            .canonicalize()
            .unwrap_or_else(|_| image_path.clone());
        let (image, alpha, (w, h)) = match decoded.get(&key) {
            Some(hit) => hit.clone(),
            None => {
                let (image, alpha) = load_image_with_alpha(&image_path, options.background)?;
                let (w, h) = (image.width, image.height);
                if w < n || h < n {
                    return Err(Error::usage(format!(
                        "{}: {w}×{h} is smaller than --downscale {n}",
                        image_path.display()
                    )));
                }
                // No second whole-image copy when nothing is downscaled.
                let image = if n == 1 { image } else { downscale(&image, n) };
                let hit = (std::sync::Arc::new(image), alpha, (w, h));
                decoded.insert(key, hit.clone());
                hit
            }
        };
        transparent |= alpha;
        let [fx, fy, cx, cy] = intrinsics(&file, frame, (w, h), &origin, &item)?;
        let scale = f64::from(n);
        let time = frame.time.unwrap_or(0.0);
        if !time.is_finite() {
            return Err(Error::invalid(&origin, &item, "time", "not finite"));
        }
        let camera = Camera::from_opengl_camera_to_world(
            image.width,
            image.height,
            [fx / scale, fy / scale, cx / scale, cy / scale],
            frame.transform_matrix,
        )
        .map_err(|e| match e {
            Error::Invalid { field, message, .. } => {
                // Intrinsics are named by the file's own keys, the rest is the matrix.
                let named = match field.as_str() {
                    "fx" => "fl_x".to_string(),
                    "fy" => "fl_y".to_string(),
                    "cx" | "cy" => field,
                    _ => format!("transform_matrix ({field})"),
                };
                Error::invalid(&origin, &item, &named, message)
            }
            other => other,
        })?;
        views.push(View {
            camera,
            time,
            image,
            name: frame.file_path.clone(),
        });
    }
    unread.retain(|key| !QUIETLY_IGNORED.contains(key));
    let notes = if unread.is_empty() {
        Vec::new()
    } else {
        let keys: Vec<&str> = unread.into_iter().collect();
        vec![format!("{origin}: ignored keys {}", keys.join(", "))]
    };
    Ok(FileViews {
        views,
        transparent,
        notes,
    })
}

/// Reads every split of the dataset in `dir`: `transforms_{train,val,test}.json`, or one
/// `transforms.json` split every [`HOLDOUT`]-th frame.
pub fn load_dataset(dir: &Path, options: &DatasetOptions) -> Result<Dataset> {
    if !dir.is_dir() {
        return Err(Error::malformed(
            &dir.display().to_string(),
            "not a folder with transforms_train.json or transforms.json",
        ));
    }
    let mut dataset = Dataset::default();
    let train_file = dir.join("transforms_train.json");
    let single = dir.join("transforms.json");
    if !train_file.is_file() && single.is_file() {
        let read = read_transforms(dir, &single, options)?;
        // Fewer frames than the hold-out period: every frame trains.
        let hold_out = read.views.len() >= HOLDOUT;
        for (index, view) in read.views.into_iter().enumerate() {
            if hold_out && index % HOLDOUT == 0 {
                dataset.test.push(view);
            } else {
                dataset.train.push(view);
            }
        }
        dataset.transparent = read.transparent;
        dataset.notes = read.notes;
    } else {
        for split in SPLITS {
            let path = dir.join(format!("transforms_{split}.json"));
            if !path.is_file() {
                continue;
            }
            let read = read_transforms(dir, &path, options)?;
            dataset.transparent |= read.transparent;
            dataset.notes.extend(read.notes);
            match split {
                "train" => dataset.train = read.views,
                "val" => dataset.val = read.views,
                _ => dataset.test = read.views,
            }
        }
    }
    if dataset.train.is_empty() {
        // The file that was read (and had no frames), or the folder when there is none.
        let read = [&train_file, &single].into_iter().find(|p| p.is_file());
        return Err(match read {
            Some(file) => Error::invalid(
                &file.display().to_string(),
                "dataset",
                "frames",
                "no training frames: the `frames` list is empty",
            ),
            None => Error::malformed(
                &dir.display().to_string(),
                "no transforms_train.json or transforms.json: not a dataset folder",
            ),
        });
    }
    Ok(dataset)
}

/// Saves the images of frame `index` of `split` under `dir` and returns its entry; `first`
/// is the split's first camera (every view must share its intrinsics).
fn save_frame(
    dir: &Path,
    split: &str,
    index: usize,
    view: &View,
    first: &Camera,
    exr: bool,
) -> Result<WrittenFrame> {
    let (v, c) = (&view.camera, first);
    if (v.width, v.height, v.fx, v.fy, v.cx, v.cy) != (c.width, c.height, c.fx, c.fy, c.cx, c.cy) {
        return Err(Error::Usage(format!(
            "split {split}: view {index} has other intrinsics than view 0"
        )));
    }
    let file_path = format!("./{split}/r_{index:03}");
    let base = dir.join(&file_path);
    save_image(&view.image, &base.with_extension("png"), BitDepth::Sixteen)?;
    if exr {
        save_image(&view.image, &base.with_extension("exr"), BitDepth::Sixteen)?;
    }
    Ok(WrittenFrame {
        file_path,
        time: view.time,
        transform_matrix: v.opengl_camera_to_world(),
    })
}

/// Writes `dir/transforms_{split}.json` for `frames` taken with intrinsics `c`.
fn write_transforms(dir: &Path, split: &str, c: &Camera, frames: Vec<WrittenFrame>) -> Result<()> {
    let file = WrittenTransforms {
        camera_angle_x: 2.0 * (0.5 * f64::from(c.width) / c.fx).atan(),
        fl_x: c.fx,
        fl_y: c.fy,
        cx: c.cx,
        cy: c.cy,
        w: c.width,
        h: c.height,
        frames,
    };
    let text = serde_json::to_string_pretty(&file).expect("finite numbers serialise");
    write_bytes_atomically(
        &dir.join(format!("transforms_{split}.json")),
        text.as_bytes(),
    )
}

/// Writes a dataset frame by frame into a temporary folder beside `out`, renamed into
/// place by [`DatasetWriter::finish`]: memory does not grow with the dataset, and a run that
/// fails (a full disk, a kill) leaves no partial dataset at `out` for `fit` to accept. An
/// existing `out` is replaced only when it is empty or an earlier `splat4d dataset` output
/// ([`crate::io::output`]).
pub struct DatasetWriter {
    folder: crate::io::output::FolderWriter,
    exr: bool,
    /// Per split: the first camera (all must share its intrinsics) and the frames.
    splits: [(Option<Camera>, Vec<WrittenFrame>); 3],
}

impl DatasetWriter {
    /// A writer for `out`; checks before any work that `out` may be written.
    pub fn new(out: &Path, exr: bool) -> Result<Self> {
        Ok(DatasetWriter {
            folder: crate::io::output::FolderWriter::new(out, "dataset")?,
            exr,
            splits: Default::default(),
        })
    }

    /// Writes the images of one view of `split` (`train`, `val` or `test`).
    pub fn add(&mut self, split: &str, view: &View) -> Result<()> {
        let k = SPLITS
            .iter()
            .position(|s| *s == split)
            .ok_or_else(|| Error::usage(format!("unknown split {split}")))?;
        let (first, frames) = &mut self.splits[k];
        let c = *first.get_or_insert(view.camera);
        let frame = save_frame(self.folder.path(), split, frames.len(), view, &c, self.exr)?;
        frames.push(frame);
        Ok(())
    }

    /// Writes the `transforms_*.json` of every split that has frames and moves the dataset
    /// into place.
    pub fn finish(self) -> Result<()> {
        for (split, (first, frames)) in SPLITS.iter().zip(self.splits) {
            if let Some(c) = first {
                write_transforms(self.folder.path(), split, &c, frames)?;
            }
        }
        self.folder.commit()
    }
}

/// Writes one split: its images (16-bit PNG, and float EXR when `exr`) and its
/// `transforms_{split}.json`, into the existing folder `dir`. Every camera must share one
/// set of intrinsics.
pub fn write_split(dir: &Path, split: &str, views: &[View], exr: bool) -> Result<()> {
    let Some(first) = views.first() else {
        return Err(Error::Usage(format!("split {split} has no views")));
    };
    let frames = views
        .iter()
        .enumerate()
        .map(|(index, view)| save_frame(dir, split, index, view, &first.camera, exr))
        .collect::<Result<Vec<_>>>()?;
    write_transforms(dir, split, &first.camera, frames)
}

/// The files a dataset in `dir` is read from: its transforms files and the images their
/// frames name (as far as they can be read; the loader reports what cannot). Outputs are
/// checked against these before any work ([`crate::io::output`]).
#[must_use]
pub fn dataset_files(dir: &Path) -> Vec<PathBuf> {
    let mut files = Vec::new();
    for name in [
        "transforms_train.json",
        "transforms_val.json",
        "transforms_test.json",
        "transforms.json",
    ] {
        let path = dir.join(name);
        files.push(path.clone());
        let Ok(text) = std::fs::read_to_string(&path) else {
            continue;
        };
        let Ok(value) = serde_json::from_str::<serde_json::Value>(&text) else {
            continue;
        };
        let frames = value.get("frames").and_then(|f| f.as_array());
        for frame in frames.into_iter().flatten() {
            if let Some(image) = frame
                .get("file_path")
                .and_then(|p| p.as_str())
                .and_then(|p| resolve_image(dir, p))
            {
                files.push(image);
            }
        }
    }
    files
}
