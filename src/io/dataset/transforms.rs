//! The transforms file both the D-NeRF / Blender ([`super::blender`]) and the nerfstudio /
//! instant-ngp ([`super::nerfstudio`]) layouts are made of: a JSON object with `frames`.
//!
//! Each frame has a `file_path` (relative to `DIR`; without an extension it is looked up as
//! `.exr`, `.png`, `.jpg`, `.jpeg`, in that order), a row-major camera-to-world
//! `transform_matrix` with OpenGL axes (x right, y up, z backward; SPEC §3) and, for
//! dynamic scenes, a `time` (missing: 0, a static scene).
//!
//! Intrinsics, per frame or for the whole file (a frame's own win): `fl_x`, `fl_y`, `cx`,
//! `cy` in pixels, `w`, `h` (checked against the image; written as `1080` or `1080.0`, a
//! number that is not a whole one is refused); else `camera_angle_x` (horizontal field of
//! view, radians: `fx = ½ W / tan(½ camera_angle_x)`, `fy = fx`) or `camera_angle_y`; the
//! principal point defaults to the image centre.
//!
//! Lens distortion (`k1 k2 k3 p1 p2`, OpenCV's model; `camera_model` PINHOLE,
//! SIMPLE_PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV or none: the coefficients given are used
//! whatever the name, since those models are all the OpenCV formula with some coefficients
//! zero) is removed at load ([`super::photos`]). Fisheye, equirectangular and other
//! projections (`OPENCV_FISHEYE`, `FISHEYE`, `EQUIRECTANGULAR`, ..., a nonzero `k4`) are
//! refused.
//!
//! A frame's `mask_path` (nerfstudio: a greyscale image the size of the photo, 0 = ignore)
//! weighs its pixels. A top-level `ply_file_path` (nerfstudio: a PLY point cloud in the
//! cameras' world) is read into [`Dataset::points`]. Both must lie inside the dataset
//! folder. Keys not read are reported once per file in [`Dataset::notes`], and ignored.
//!
//! [`Dataset::points`]: crate::model::Dataset::points
//! [`Dataset::notes`]: crate::model::Dataset::notes

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::io::json::parse_json;
use crate::io::point_cloud::read_point_cloud;
use crate::model::camera::Camera;
use crate::model::distortion::Distortion;
use crate::model::error::{Error, Result, check_finite};
use crate::model::{Blend, DatasetPoint, View};

use super::frames::{Frame, FrameSource, inside_dataset, load_views, regular_file};
use super::photo_memory::FramePhoto;
use super::photos::Source;
use super::{DatasetFiles, DatasetOptions};

/// Intrinsics and camera model, at the top of a file or in a frame.
#[derive(Clone, Debug, Default, Deserialize)]
struct Intrinsics {
    fl_x: Option<f64>,
    fl_y: Option<f64>,
    cx: Option<f64>,
    cy: Option<f64>,
    // Floats: nerfstudio writes `"w": 1080.0`; whole numbers are checked in `intrinsics`.
    w: Option<f64>,
    h: Option<f64>,
    camera_model: Option<String>,
    k1: Option<f64>,
    k2: Option<f64>,
    k3: Option<f64>,
    k4: Option<f64>,
    p1: Option<f64>,
    p2: Option<f64>,
}

/// A transforms file's contents.
#[derive(Deserialize)]
pub(super) struct TransformsFile {
    camera_angle_x: Option<f64>,
    camera_angle_y: Option<f64>,
    #[serde(flatten)]
    intrinsics: Intrinsics,
    ply_file_path: Option<String>,
    frames: Vec<FrameEntry>,
    splat4d_blend: Option<Blend>,
    #[serde(flatten)]
    other: BTreeMap<String, serde_json::Value>,
}

#[derive(Deserialize)]
struct FrameEntry {
    file_path: String,
    time: Option<f64>,
    transform_matrix: [[f64; 4]; 4],
    mask_path: Option<String>,
    #[serde(flatten)]
    intrinsics: Intrinsics,
    #[serde(flatten)]
    other: BTreeMap<String, serde_json::Value>,
}

/// Keys other tools write that carry nothing splat4d needs: skipped without a note.
const QUIETLY_IGNORED: [&str; 8] = [
    "aabb_scale",
    "scale",
    "offset",
    "applied_transform",
    "applied_scale",
    "rotation",
    "colmap_im_id",
    "sharpness",
];

/// Camera models read: pinholes, with OpenCV-formula distortion removed at load.
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

/// A whole number of pixels given as a JSON number (`1080` or `1080.0`).
fn whole_pixels(value: f64, origin: &str, item: &str, field: &str, top: bool) -> Result<u32> {
    let place = if top { " (top level)" } else { "" };
    if value.is_finite() && value.fract() == 0.0 && (0.0..=f64::from(u32::MAX)).contains(&value) {
        Ok(value as u32)
    } else {
        Err(Error::invalid(
            origin,
            item,
            field,
            format!("{value}{place} is not a whole number of pixels"),
        ))
    }
}

/// Refuses a `camera_model` that is not a pinhole with OpenCV-formula distortion.
fn check_camera_model(model: &str, origin: &str, item: &str) -> Result<()> {
    if PINHOLE_MODELS.contains(&model) {
        return Ok(());
    }
    let upper = model.to_ascii_uppercase();
    let kind = if ["FISHEYE", "EQUIRECTANGULAR", "OMNIDIRECTIONAL", "VR180"]
        .iter()
        .any(|k| upper.contains(k))
    {
        "fisheye, equirectangular and omnidirectional projections are not supported"
    } else {
        "not a camera model splat4d reads"
    };
    Err(Error::invalid(
        origin,
        item,
        "camera_model",
        format!("{model}: {kind} (read: {})", PINHOLE_MODELS.join(", ")),
    ))
}

/// The lens distortion of a frame: its own coefficients, then the file's.
fn distortion(
    file: &TransformsFile,
    frame: &FrameEntry,
    origin: &str,
    item: &str,
) -> Result<Distortion> {
    let (own, top) = (&frame.intrinsics, &file.intrinsics);
    if let Some(model) = own.camera_model.as_ref().or(top.camera_model.as_ref()) {
        check_camera_model(model, origin, item)?;
    }
    let mut coefficients = [0.0; 6];
    for (k, (field, value)) in [
        ("k1", own.k1.or(top.k1)),
        ("k2", own.k2.or(top.k2)),
        ("k3", own.k3.or(top.k3)),
        ("p1", own.p1.or(top.p1)),
        ("p2", own.p2.or(top.p2)),
        ("k4", own.k4.or(top.k4)),
    ]
    .into_iter()
    .enumerate()
    {
        let v = value.unwrap_or(0.0);
        check_finite(origin, item, field, &[v])?;
        coefficients[k] = v;
    }
    if coefficients[5] != 0.0 {
        return Err(Error::invalid(
            origin,
            item,
            "k4",
            format!(
                "k4 = {}: a fisheye (or rational) lens coefficient; only k1 k2 k3 p1 p2 are read",
                coefficients[5]
            ),
        ));
    }
    let [k1, k2, k3, p1, p2, _] = coefficients;
    Ok(Distortion {
        radial: [k1, k2, k3],
        tangential: [p1, p2],
    })
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
    for (field, value, fallback, actual) in [("w", own.w, top.w, w), ("h", own.h, top.h, h)] {
        let given = match (value, fallback) {
            (Some(v), _) => Some(whole_pixels(v, origin, item, field, false)?),
            (None, Some(v)) => Some(whole_pixels(v, origin, item, field, true)?),
            (None, None) => None,
        };
        if let Some(v) = given
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

/// A transforms file as read once: its path, and its contents or why they cannot be read
/// (reported when its views are loaded).
pub(super) struct Transforms {
    pub path: PathBuf,
    pub file: Result<TransformsFile>,
}

/// What one transforms file gives: its views and what came with them.
pub(super) struct FileViews {
    pub views: Vec<View>,
    pub blend: Option<Blend>,
    pub transparent: bool,
    pub notes: Vec<String>,
    pub points: Option<Vec<DatasetPoint>>,
}

impl Transforms {
    /// Reads and parses the transforms file `path`.
    pub fn read(path: &Path) -> Self {
        let origin = path.display().to_string();
        let file = crate::io::input::read_to_string(path, "cannot read")
            .and_then(|text| parse_json(&text, &origin, "transforms"));
        Transforms {
            path: path.to_path_buf(),
            file,
        }
    }

    /// Adds the photos, masks and point cloud the file names (in `dir`) to `files`.
    pub fn add_named_files(&self, dir: &Path, files: &mut DatasetFiles) {
        let Ok(file) = &self.file else {
            return;
        };
        files
            .point_clouds
            .extend(file.ply_file_path.as_ref().map(|p| dir.join(p)));
        for frame in &file.frames {
            files.photos.extend(resolve_image(dir, &frame.file_path));
            files
                .masks
                .extend(frame.mask_path.as_ref().map(|m| dir.join(m)));
        }
    }

    /// Each frame's photo (real path), mask and lens, as loading would read them.
    pub fn frame_photos(&self, dir: &Path) -> Vec<FramePhoto> {
        let Ok(file) = &self.file else {
            return Vec::new();
        };
        let real = |p: &Path| p.canonicalize().unwrap_or_else(|_| p.to_path_buf());
        file.frames
            .iter()
            .filter_map(|frame| {
                let image = resolve_image(dir, &frame.file_path)?;
                let mask = frame.mask_path.as_ref().map(|m| real(&dir.join(m)));
                let lens = distortion(file, frame, "", "").unwrap_or_default();
                Some((real(&image), mask, lens))
            })
            .collect()
    }

    /// The file's views, its photos in `dir`, with the notes on keys it does not read and
    /// what loading noticed, and its point cloud.
    pub fn load(self, dir: &Path, options: &DatasetOptions) -> Result<FileViews> {
        let origin = self.path.display().to_string();
        let file = self.file?;
        let frames = TransformsFrames {
            dir,
            file: &file,
            origin: &origin,
            options,
        };
        let loaded = load_views(&frames, options)?;
        let mut notes: Vec<String> = unread_keys_note(&file, &origin).into_iter().collect();
        notes.extend(loaded.notes);
        let points = match &file.ply_file_path {
            Some(ply) => {
                let path = inside_dataset(dir, ply, &origin, "transforms", "ply_file_path")?;
                Some(read_point_cloud(&path)?)
            }
            None => None,
        };
        Ok(FileViews {
            views: loaded.views,
            blend: file.splat4d_blend,
            transparent: loaded.transparent,
            notes,
            points,
        })
    }
}

/// The note listing the keys of the file and its frames that are not read (but for those
/// [`QUIETLY_IGNORED`]).
fn unread_keys_note(file: &TransformsFile, origin: &str) -> Option<String> {
    let mut unread: BTreeSet<&str> = file.other.keys().map(String::as_str).collect();
    for frame in &file.frames {
        unread.extend(frame.other.keys().map(String::as_str));
    }
    unread.retain(|key| !QUIETLY_IGNORED.contains(key));
    if unread.is_empty() {
        return None;
    }
    let keys: Vec<&str> = unread.into_iter().collect();
    Some(format!("{origin}: ignored keys {}", keys.join(", ")))
}

/// The frames of a transforms file, as [`load_views`] asks for them.
struct TransformsFrames<'a> {
    dir: &'a Path,
    file: &'a TransformsFile,
    origin: &'a str,
    options: &'a DatasetOptions,
}

impl FrameSource for TransformsFrames<'_> {
    fn origin(&self) -> &str {
        self.origin
    }

    fn count(&self) -> usize {
        self.file.frames.len()
    }

    fn frame(&self, index: usize) -> Result<Frame> {
        let (dir, origin) = (self.dir, self.origin);
        let entry = &self.file.frames[index];
        let item = format!("frame {index}");
        let name = entry.file_path.clone();
        let Some(image) = resolve_image(dir, &entry.file_path) else {
            // A FIFO (or other special file) is not a missing image: refused by name.
            let named = (origin, item.as_str(), "file_path");
            regular_file(&dir.join(&name), &name, named, false)?;
            return Ok(Frame {
                item,
                name,
                photo: None,
            });
        };
        if !self.options.allow_outside_images && !crate::io::output::inside(&image, dir) {
            return Err(Error::invalid(
                origin,
                &item,
                "file_path",
                format!(
                    "{name} lies outside the dataset's folder (by its real path, links followed); pass `allow_outside_images` to read it"
                ),
            ));
        }
        let mask = match &entry.mask_path {
            Some(mask) => Some(inside_dataset(dir, mask, origin, &item, "mask_path")?),
            None => None,
        };
        let source = Source {
            real: image.canonicalize().unwrap_or_else(|_| image.clone()),
            image,
            mask,
            distortion: distortion(self.file, entry, origin, &item)?,
            lens_origin: None,
        };
        Ok(Frame {
            item,
            name,
            photo: Some(source),
        })
    }

    fn intrinsics(
        &self,
        index: usize,
        frame: &Frame,
        _: &Source,
        size: (u32, u32),
    ) -> Result<[f64; 4]> {
        let entry = &self.file.frames[index];
        intrinsics(self.file, entry, size, self.origin, &frame.item)
    }

    fn camera(
        &self,
        index: usize,
        frame: &Frame,
        (w, h): (u32, u32),
        k: [f64; 4],
    ) -> Result<(Camera, f64)> {
        let (origin, item) = (self.origin, frame.item.as_str());
        let entry = &self.file.frames[index];
        let time = entry.time.unwrap_or(0.0);
        if !time.is_finite() {
            return Err(Error::invalid(origin, item, "time", "not finite"));
        }
        let camera =
            Camera::from_opengl_camera_to_world(w, h, k, entry.transform_matrix).map_err(|e| {
                match e {
                    Error::Invalid { field, message, .. } => {
                        // Intrinsics are named by the file's own keys, the rest is the matrix.
                        let named = match field.as_str() {
                            "fx" => "fl_x".to_string(),
                            "fy" => "fl_y".to_string(),
                            "cx" | "cy" => field,
                            _ => format!("transform_matrix ({field})"),
                        };
                        Error::invalid(origin, item, &named, message)
                    }
                    other => other,
                }
            })?;
        Ok((camera, time))
    }
}
