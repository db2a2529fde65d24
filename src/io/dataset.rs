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
//! `cy` in pixels, `w`, `h` (checked against the image; written as `1080` or `1080.0`, a
//! number that is not a whole one is refused); else `camera_angle_x` (horizontal field of
//! view, radians: `fx = ½ W / tan(½ camera_angle_x)`, `fy = fx`) or `camera_angle_y`; the
//! principal point defaults to the image centre.
//!
//! Lens distortion (`k1 k2 k3 p1 p2`, OpenCV's model; `camera_model` PINHOLE,
//! SIMPLE_PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV or none: the coefficients given are used
//! whatever the name, since those models are all the OpenCV formula with some coefficients
//! zero) is removed at load: each photo is resampled into the pinhole camera with the same
//! `fx fy cx cy` ([`crate::model::distortion`]), one remap table per distinct camera, and the
//! pixels whose source lies outside the photo weigh 0 in the loss ([`View::weights`]).
//! Fisheye, equirectangular and other projections (`OPENCV_FISHEYE`, `FISHEYE`,
//! `EQUIRECTANGULAR`, ..., a nonzero `k4`) are refused.
//!
//! A frame's `mask_path` (nerfstudio: a greyscale image the size of the photo, 0 = ignore)
//! multiplies the pixel weights: weight = the mask's grey value (RGB masks: the mean of the
//! channels, alpha composited over black), undistorted with the photo. A top-level
//! `ply_file_path` (nerfstudio: a PLY point cloud in the cameras' world) is read into
//! [`Dataset::points`]. Both must lie inside the dataset folder.
//!
//! Frames whose image file is missing are skipped, with one note naming them; under
//! [`DatasetOptions::strict`] they are refused. Keys not read are reported once per file in
//! [`Dataset::notes`], and ignored.
//!
//! **COLMAP** ([`crate::io::colmap`]): without a transforms file, `DIR/sparse/0` (or
//! `DIR/sparse`) with `cameras`, `images` and `points3D` (`.bin` or `.txt`) is read, the photos
//! from `DIR/images/NAME`. The poses are used as they are (world→camera, OpenCV axes, SPEC
//! §3); the views are sorted by name and every 8th (0, 8, 16, ...) is held out as `test`, as
//! nerfstudio does (fewer than 8 images: all train). COLMAP models are static: every time is
//! 0. `points3D` becomes [`Dataset::points`].
//!
//! Integer images are read as `value / (2^bits - 1)` (SPEC §5: linear, no sRGB curve, JPEG
//! included); RGBA images are composited over [`DatasetOptions::background`] (black by
//! default: the additive model's "nothing"). `downscale` N averages N×N blocks (a box
//! filter, like nerfstudio's `images_N` folders; with pixel weights, the weighted mean of the
//! block and the mean weight) and divides the intrinsics by N, after undistortion.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::io::colmap;
use crate::io::image_file::{BitDepth, load_image_with_alpha, save_image};
use crate::io::json::parse_json;
use crate::io::point_cloud::read_point_cloud;
use crate::io::write_bytes_atomically;
use crate::model::camera::Camera;
use crate::model::distortion::{Distortion, RemapTable};
use crate::model::error::{Error, MAX_QUOTE, Result, check_finite, cut};
use crate::model::{Blend, Dataset, DatasetPoint, Image, View};

/// The transforms files a dataset folder may hold: the three splits', then the single one.
const TRANSFORMS_FILES: [&str; 4] = [
    "transforms_train.json",
    "transforms_val.json",
    "transforms_test.json",
    "transforms.json",
];

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
    /// Refuse frames whose image file is missing (otherwise they are skipped with a note).
    pub strict: bool,
    /// Read images whose real path (symlinks followed) lies outside the dataset's folder.
    pub allow_outside_images: bool,
}

impl Default for DatasetOptions {
    fn default() -> Self {
        DatasetOptions {
            background: [0.0; 3],
            downscale: 1,
            strict: false,
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
    /// The blend the images were rendered with (SPEC §8), so that `fit` fits the same one.
    splat4d_blend: Blend,
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

#[derive(Deserialize)]
struct TransformsFile {
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

/// Frames named in the note (or error) about missing images.
const NAMED_MISSING: usize = 5;

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

/// The lens distortion of a frame: its own coefficients, then the file's.
fn distortion(
    file: &TransformsFile,
    frame: &FrameEntry,
    origin: &str,
    item: &str,
) -> Result<Distortion> {
    let (own, top) = (&frame.intrinsics, &file.intrinsics);
    if let Some(model) = own.camera_model.as_ref().or(top.camera_model.as_ref())
        && !PINHOLE_MODELS.contains(&model.as_str())
    {
        let upper = model.to_ascii_uppercase();
        let kind = if ["FISHEYE", "EQUIRECTANGULAR", "OMNIDIRECTIONAL", "VR180"]
            .iter()
            .any(|k| upper.contains(k))
        {
            "fisheye, equirectangular and omnidirectional projections are not supported"
        } else {
            "not a camera model splat4d reads"
        };
        return Err(Error::invalid(
            origin,
            item,
            "camera_model",
            format!("{model}: {kind} (read: {})", PINHOLE_MODELS.join(", ")),
        ));
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

/// The weighted box filter: per `n × n` block, the mean weight and the weighted mean colour
/// (the plain mean where every weight is 0).
#[must_use]
pub fn downscale_weighted(image: &Image, weights: &[f32], n: u32) -> (Image, Vec<f32>) {
    let (w, h) = (image.width / n, image.height / n);
    let mut pixels = Vec::with_capacity(3 * w as usize * h as usize);
    let mut out_weights = Vec::with_capacity(w as usize * h as usize);
    let inv = 1.0 / f64::from(n * n);
    let width = image.width as usize;
    for j in 0..h {
        for i in 0..w {
            let mut sum = [0.0_f64; 3];
            let mut plain = [0.0_f64; 3];
            let mut total = 0.0_f64;
            for dj in 0..n {
                for di in 0..n {
                    let (x, y) = (n * i + di, n * j + dj);
                    let weight = f64::from(weights[y as usize * width + x as usize]);
                    let p = image.pixel(x, y);
                    total += weight;
                    for c in 0..3 {
                        sum[c] += weight * f64::from(p[c]);
                        plain[c] += f64::from(p[c]);
                    }
                }
            }
            pixels.extend(if total > 0.0 {
                sum.map(|s| (s / total) as f32)
            } else {
                plain.map(|s| (s * inv) as f32)
            });
            out_weights.push((total * inv) as f32);
        }
    }
    (
        Image {
            width: w,
            height: h,
            pixels,
        },
        out_weights,
    )
}

/// Remap tables kept while a dataset loads, by camera (size, intrinsics, distortion): each
/// is computed once. Only the last few are kept (a table takes 16 bytes a pixel).
#[derive(Default)]
struct Undistorter {
    tables: Vec<([u64; 11], RemapTable)>,
    /// Photos undistorted so far.
    undistorted: usize,
}

/// Tables kept at once.
const KEPT_TABLES: usize = 4;

impl Undistorter {
    fn table(&mut self, (w, h): (u32, u32), k: [f64; 4], d: &Distortion) -> &RemapTable {
        let key = [
            u64::from(w),
            u64::from(h),
            k[0].to_bits(),
            k[1].to_bits(),
            k[2].to_bits(),
            k[3].to_bits(),
            d.radial[0].to_bits(),
            d.radial[1].to_bits(),
            d.radial[2].to_bits(),
            d.tangential[0].to_bits(),
            d.tangential[1].to_bits(),
        ];
        let index = match self.tables.iter().position(|(k, _)| *k == key) {
            Some(index) => index,
            None => {
                if self.tables.len() == KEPT_TABLES {
                    self.tables.remove(0);
                }
                self.tables.push((key, RemapTable::new(w, h, k, d)));
                self.tables.len() - 1
            }
        };
        &self.tables[index].1
    }
}

/// One photo as read, before it becomes a [`View`].
/// A photo ready to fit: the image (shared with other frames when nothing changed it), its
/// pixel weights (`None`: every pixel counts fully), and `[fx, fy, cx, cy]`.
type PreparedPhoto = (std::sync::Arc<Image>, Option<Vec<f32>>, [f64; 4]);

struct Photo {
    image: std::sync::Arc<Image>,
    /// The mask's weights, one per photo pixel.
    mask: Option<Vec<f32>>,
    /// `[fx, fy, cx, cy]` of the photo, pixels.
    intrinsics: [f64; 4],
    distortion: Distortion,
    /// Where the lens coefficients come from (file, item), when not the photo's own entry
    /// (a COLMAP camera).
    lens_origin: Option<(String, String)>,
}

/// The photo undistorted, masked and downscaled: the image, its pixel weights (`None` when
/// every pixel counts fully) and the pinhole intrinsics of the result.
fn prepare_photo(
    photo: Photo,
    undistorter: &mut Undistorter,
    n: u32,
    (origin, item): (&str, &str),
) -> Result<PreparedPhoto> {
    use std::sync::Arc;
    let Photo {
        mut image,
        mut mask,
        intrinsics,
        distortion,
        lens_origin,
    } = photo;
    let size = (image.width, image.height);
    if !distortion.is_pinhole() {
        undistorter.undistorted += 1;
        let table = undistorter.table(size, intrinsics, &distortion);
        if !table.any_valid() {
            let (field, values) = lens_coefficients(&distortion);
            let (lens_file, lens_item) =
                lens_origin.as_ref().map_or((origin, item), |(file, item)| {
                    (file.as_str(), item.as_str())
                });
            return Err(Error::invalid(
                lens_file,
                lens_item,
                &field,
                format!(
                    "{values} leaves no pixel of the image inside the lens model's range (every ray folds back or lands outside the photo)"
                ),
            ));
        }
        image = Arc::new(table.undistort_image(&image));
        mask = Some(match mask {
            Some(m) => table.undistort_weights(&m),
            None => table.validity(),
        });
    }
    if size.0 < n || size.1 < n {
        return Err(Error::setting(
            &["downscale"],
            format!(
                "{origin}: {item}: {}×{} is smaller than `downscale` {n}",
                size.0, size.1
            ),
        ));
    }
    // No second whole-image copy when nothing is downscaled: frames naming one file share
    // its decode.
    let (image, weights) = match mask {
        None if n == 1 => (image, None),
        None => (Arc::new(image.downscaled(n)), None),
        Some(m) => {
            let (image, weights) = if n == 1 {
                (image, m)
            } else {
                let (image, weights) = downscale_weighted(&image, &m, n);
                (Arc::new(image), weights)
            };
            if weights.iter().all(|&w| w == 0.0) {
                return Err(Error::invalid(
                    origin,
                    item,
                    "mask_path",
                    "no pixel is left to fit: the mask (and the undistortion) leave every pixel out",
                ));
            }
            let all_ones = weights.iter().all(|&w| w == 1.0);
            (image, (!all_ones).then_some(weights))
        }
    };
    let scale = f64::from(n);
    Ok((image, weights, intrinsics.map(|v| v / scale)))
}

/// A prepared photo's identity: the image file's and the mask's real paths, the photo's
/// intrinsics and its lens (as bits).
type PhotoKey = (PathBuf, Option<PathBuf>, [u64; 4], [u64; 5]);

/// A file decoded: the decode (weak), whether a pixel was transparent, its size.
type DecodedFile = (std::sync::Weak<Image>, bool, (u32, u32));

/// What [`Photos::size`] tells of a file: its size, whether a pixel is transparent, and its
/// decode when at hand.
type FileSize = ((u32, u32), bool, Option<std::sync::Arc<Image>>);

/// The photos of one dataset file as they load. Each distinct image file is decoded once,
/// and frames naming one file with one mask, intrinsics and lens share one prepared photo
/// (one undistorted or downscaled copy, [`View::image`] an `Arc` shared between them): 25
/// frames of one photo hold one image, not 25.
#[derive(Default)]
struct Photos {
    /// Decoded files by real path: the decode (weak: one that nothing keeps, a photo
    /// undistorted or downscaled into a copy, is not held while the rest load), whether a
    /// pixel was transparent, and its size.
    decoded: std::collections::HashMap<PathBuf, DecodedFile>,
    /// Prepared photos: the view holding it (an index into the views loaded so far) and its
    /// intrinsics.
    prepared: std::collections::HashMap<PhotoKey, (usize, [f64; 4])>,
    undistorter: Undistorter,
}

/// A frame's photo as its file names it: the image (its path as found and its real path),
/// the mask's path (real, checked inside the dataset), and the lens.
struct Source<'a> {
    image: &'a Path,
    real: PathBuf,
    mask: Option<PathBuf>,
    distortion: Distortion,
    /// Where the lens comes from when not the frame itself (`(file, item)`: a COLMAP
    /// camera), for errors about its coefficients.
    lens_origin: Option<(String, String)>,
}

impl Photos {
    /// The size of the image `source` names and whether a pixel is transparent; the file is
    /// decoded unless an earlier frame's decode told, and the decode returned when it is at
    /// hand (made now, or still held).
    fn size(&mut self, source: &Source, background: [f32; 3]) -> Result<FileSize> {
        if let Some((weak, alpha, size)) = self.decoded.get(&source.real) {
            return Ok((*size, *alpha, weak.upgrade()));
        }
        let (image, alpha) = self.decode(source, background)?;
        Ok(((image.width, image.height), alpha, Some(image)))
    }

    /// Decodes the image of `source` and records it.
    fn decode(
        &mut self,
        source: &Source,
        background: [f32; 3],
    ) -> Result<(std::sync::Arc<Image>, bool)> {
        let (image, alpha) = load_image_with_alpha(source.image, background)?;
        let image = std::sync::Arc::new(image);
        let size = (image.width, image.height);
        self.decoded.insert(
            source.real.clone(),
            (std::sync::Arc::downgrade(&image), alpha, size),
        );
        Ok((image, alpha))
    }

    /// The photo of the frame that will be `views[views.len()]`: an earlier view's when
    /// one shares its file, mask, intrinsics `k` and lens, else undistorted, masked and
    /// downscaled now from `decoded` (the file decoded again when nothing held it). `ctx`
    /// is `(origin, item)` for errors.
    #[allow(clippy::too_many_arguments)]
    fn prepare(
        &mut self,
        source: Source,
        decoded: Option<std::sync::Arc<Image>>,
        k: [f64; 4],
        n: u32,
        views: &[View],
        background: [f32; 3],
        ctx: (&str, &str),
    ) -> Result<PreparedPhoto> {
        let d = &source.distortion;
        let lens = [
            d.radial[0].to_bits(),
            d.radial[1].to_bits(),
            d.radial[2].to_bits(),
            d.tangential[0].to_bits(),
            d.tangential[1].to_bits(),
        ];
        let key = (
            source.real.clone(),
            source.mask.clone(),
            k.map(f64::to_bits),
            lens,
        );
        if let Some(&(index, k)) = self.prepared.get(&key)
            && let Some(view) = views.get(index)
        {
            if !source.distortion.is_pinhole() {
                self.undistorter.undistorted += 1;
            }
            return Ok((view.image.clone(), view.weights.clone(), k));
        }
        let image = match decoded {
            Some(image) => image,
            None => self.decode(&source, background)?.0,
        };
        let mask = match &source.mask {
            Some(path) => Some(load_mask(path, (image.width, image.height), ctx.0, ctx.1)?),
            None => None,
        };
        let photo = Photo {
            image,
            mask,
            intrinsics: k,
            distortion: source.distortion,
            lens_origin: source.lens_origin.clone(),
        };
        let prepared = prepare_photo(photo, &mut self.undistorter, n, ctx)?;
        self.prepared.insert(key, (views.len(), prepared.2));
        Ok(prepared)
    }
}

/// The names of a lens's non-zero coefficients (`k1, p1`) and their values
/// (`` `k1` = 1e30, `p1` = 2 ``), for a message about the lens.
fn lens_coefficients(distortion: &Distortion) -> (String, String) {
    let [k1, k2, k3] = distortion.radial;
    let [p1, p2] = distortion.tangential;
    let set: Vec<(&str, f64)> = [("k1", k1), ("k2", k2), ("k3", k3), ("p1", p1), ("p2", p2)]
        .into_iter()
        .filter(|&(_, v)| v != 0.0)
        .collect();
    let names: Vec<&str> = set.iter().map(|&(name, _)| name).collect();
    let values: Vec<String> = set
        .iter()
        .map(|&(name, v)| format!("`{name}` = {v:e}"))
        .collect();
    (names.join(", "), values.join(", "))
}

/// `relative` under the dataset folder `dir`, checked to lie inside it (after resolving
/// links and `..`).
fn inside_dataset(
    dir: &Path,
    relative: &str,
    origin: &str,
    item: &str,
    field: &str,
) -> Result<PathBuf> {
    let path = dir.join(relative);
    let canonical = path
        .canonicalize()
        .map_err(|e| Error::read(&path, &format!("{item}: field `{field}`: cannot open"), e))?;
    let root = dir
        .canonicalize()
        .map_err(|e| Error::read(dir, "cannot open the dataset folder", e))?;
    if !canonical.starts_with(&root) {
        return Err(Error::invalid(
            origin,
            item,
            field,
            format!(
                "{relative} lies outside the dataset folder {}",
                dir.display()
            ),
        ));
    }
    regular_file(&canonical, relative, (origin, item, field), true)?;
    Ok(canonical)
}

/// Refuses, naming the file `relative` (as the dataset names it), its item and field, a
/// `path` that exists but is not a regular file: a FIFO, socket or device, and a folder
/// when `folders` ([`crate::io::input`]). A path that does not exist passes (its reader
/// reports it, or it is a missing frame).
fn regular_file(
    path: &Path,
    relative: &str,
    (origin, item, field): (&str, &str, &str),
    folders: bool,
) -> Result<()> {
    match crate::io::input::special_kind(path).filter(|_| folders || !path.is_dir()) {
        Some(kind) => Err(Error::invalid(
            origin,
            item,
            field,
            format!("{relative}: {}", crate::io::input::not_regular(kind)),
        )),
        None => Ok(()),
    }
}

/// A mask image as pixel weights: the mean of its channels (alpha composited over black),
/// clamped to `[0, 1]`; it must have the photo's size.
fn load_mask(path: &Path, (w, h): (u32, u32), origin: &str, item: &str) -> Result<Vec<f32>> {
    let (mask, _) = load_image_with_alpha(path, [0.0; 3])?;
    if (mask.width, mask.height) != (w, h) {
        return Err(Error::invalid(
            origin,
            item,
            "mask_path",
            format!(
                "{}: {}×{} but the photo is {w}×{h}",
                path.display(),
                mask.width,
                mask.height
            ),
        ));
    }
    Ok(mask
        .pixels
        .chunks_exact(3)
        .map(|p| ((p[0] + p[1] + p[2]) / 3.0).clamp(0.0, 1.0))
        .collect())
}

/// The note about frames without an image, `missing` as `(item, name)`; an error naming
/// the first frame when `strict` or when no frame has an image (`loaded` is 0).
fn missing_frames(
    origin: &str,
    missing: &[(String, String)],
    loaded: usize,
    strict: bool,
) -> Result<Option<String>> {
    let Some((first, _)) = missing.first() else {
        return Ok(None);
    };
    let mut names = missing
        .iter()
        .take(NAMED_MISSING)
        .map(|(_, name)| cut(name, MAX_QUOTE))
        .collect::<Vec<_>>()
        .join(", ");
    if missing.len() > NAMED_MISSING {
        names.push_str(", …");
    }
    let count = missing.len();
    let frames = if count == 1 { "frame" } else { "frames" };
    if strict || loaded == 0 {
        let why = if strict {
            "`strict` refuses them"
        } else {
            "no frame has one"
        };
        return Err(Error::invalid(
            origin,
            first,
            "file_path",
            format!(
                "{count} {frames} without an image file (.exr, .png, .jpg or .jpeg): {names} ({why})"
            ),
        ));
    }
    Ok(Some(format!(
        "{origin}: skipped {count} {frames} whose image is missing: {names}"
    )))
}

/// The note on what undistortion and masks did, when they did anything: photos
/// undistorted, and the share of pixel weight left out of the loss.
fn weights_note(origin: &str, views: &[View], undistorted: usize) -> Option<String> {
    let weighted: Vec<&Vec<f32>> = views.iter().filter_map(|v| v.weights.as_ref()).collect();
    if weighted.is_empty() && undistorted == 0 {
        return None;
    }
    let pixels: usize = weighted.iter().map(|w| w.len()).sum();
    let kept: f64 = weighted
        .iter()
        .flat_map(|w| w.iter())
        .map(|&w| f64::from(w))
        .sum();
    let left_out = if pixels > 0 {
        100.0 * (1.0 - kept / pixels as f64)
    } else {
        0.0
    };
    Some(format!(
        "{origin}: {undistorted} of {} photos undistorted into pinhole cameras with the same fx fy cx cy; {} views have pixel weights, {left_out:.1}% of their pixels' weight left out of the loss (outside the photo or masked)",
        views.len(),
        weighted.len()
    ))
}

/// What [`read_transforms`] found in one file.
struct FileViews {
    views: Vec<View>,
    blend: Option<Blend>,
    transparent: bool,
    notes: Vec<String>,
    points: Option<Vec<DatasetPoint>>,
}

/// Checks the `downscale` option.
fn check_downscale(n: u32) -> Result<()> {
    if !(1..=MAX_DOWNSCALE).contains(&n) {
        return Err(Error::setting(
            &["downscale"],
            format!("`downscale` {n} must be between 1 and {MAX_DOWNSCALE}"),
        ));
    }
    Ok(())
}

/// Reads one transforms file and its images.
fn read_transforms(dir: &Path, path: &Path, options: &DatasetOptions) -> Result<FileViews> {
    let origin = path.display().to_string();
    let text = crate::io::input::read_to_string(path, "cannot read")?;
    let file: TransformsFile = parse_json(&text, &origin, "transforms")?;
    let n = options.downscale;
    check_downscale(n)?;
    let mut unread: BTreeSet<&str> = file.other.keys().map(String::as_str).collect();
    let mut views = Vec::with_capacity(file.frames.len().min(1 << 16));
    let mut transparent = false;
    let mut missing = Vec::new();
    let mut photos = Photos::default();
    for (index, frame) in file.frames.iter().enumerate() {
        let item = format!("frame {index}");
        unread.extend(frame.other.keys().map(String::as_str));
        let Some(image_path) = resolve_image(dir, &frame.file_path) else {
            // A FIFO (or other special file) is not a missing image: refused by name.
            regular_file(
                &dir.join(&frame.file_path),
                &frame.file_path,
                (&origin, &item, "file_path"),
                false,
            )?;
            missing.push((item, frame.file_path.clone()));
            continue;
        };
        if !options.allow_outside_images && !crate::io::output::inside(&image_path, dir) {
            return Err(Error::invalid(
                &origin,
                &item,
                "file_path",
                format!(
                    "{} lies outside the dataset's folder (by its real path, links followed); pass `allow_outside_images` to read it",
                    frame.file_path
                ),
            ));
        }
        let mask = match &frame.mask_path {
            Some(mask_path) => Some(inside_dataset(dir, mask_path, &origin, &item, "mask_path")?),
            None => None,
        };
        let source = Source {
            image: &image_path,
            real: image_path
                .canonicalize()
                .unwrap_or_else(|_| image_path.clone()),
            mask,
            distortion: distortion(&file, frame, &origin, &item)?,
            lens_origin: None,
        };
        let ((w, h), alpha, decoded) = photos.size(&source, options.background)?;
        transparent |= alpha;
        let k = intrinsics(&file, frame, (w, h), &origin, &item)?;
        let (image, weights, k) = photos.prepare(
            source,
            decoded,
            k,
            n,
            &views,
            options.background,
            (&origin, &item),
        )?;
        let time = frame.time.unwrap_or(0.0);
        if !time.is_finite() {
            return Err(Error::invalid(&origin, &item, "time", "not finite"));
        }
        let camera = Camera::from_opengl_camera_to_world(
            image.width,
            image.height,
            k,
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
            weights,
        });
    }
    unread.retain(|key| !QUIETLY_IGNORED.contains(key));
    let mut notes = Vec::new();
    if !unread.is_empty() {
        let keys: Vec<&str> = unread.into_iter().collect();
        notes.push(format!("{origin}: ignored keys {}", keys.join(", ")));
    }
    notes.extend(missing_frames(
        &origin,
        &missing,
        views.len(),
        options.strict,
    )?);
    notes.extend(weights_note(
        &origin,
        &views,
        photos.undistorter.undistorted,
    ));
    let points = match &file.ply_file_path {
        Some(ply) => {
            let path = inside_dataset(dir, ply, &origin, "transforms", "ply_file_path")?;
            Some(read_point_cloud(&path)?)
        }
        None => None,
    };
    Ok(FileViews {
        views,
        blend: file.splat4d_blend,
        transparent,
        notes,
        points,
    })
}

/// Reads the COLMAP model in `sparse` with its photos in `dir/images`.
fn read_colmap(dir: &Path, sparse: &Path, options: &DatasetOptions) -> Result<FileViews> {
    let n = options.downscale;
    check_downscale(n)?;
    let model = colmap::read_sparse_model(sparse)?;
    let [cameras_file, images_file, _] = colmap::model_files(sparse);
    let origin =
        images_file.map_or_else(|| sparse.display().to_string(), |p| p.display().to_string());
    let cameras_file =
        cameras_file.map_or_else(|| sparse.display().to_string(), |p| p.display().to_string());
    let mut images = model.images;
    images.sort_by(|a, b| a.name.cmp(&b.name));
    let mut views = Vec::with_capacity(images.len().min(1 << 16));
    let mut transparent = false;
    let mut missing = Vec::new();
    let mut photos = Photos::default();
    for entry in &images {
        let item = format!("image {} ({})", entry.id, entry.name);
        let camera = model.cameras.get(&entry.camera_id).ok_or_else(|| {
            Error::invalid(
                &origin,
                &item,
                "camera_id",
                format!("camera {} is not in the cameras file", entry.camera_id),
            )
        })?;
        let name = format!("images/{}", entry.name);
        let path = dir.join(&name);
        if !path.is_file() {
            regular_file(&path, &name, (&origin, &item, "name"), false)?;
            missing.push((item, name));
            continue;
        }
        let real = inside_dataset(dir, &name, &origin, &item, "name")?;
        let source = Source {
            image: &path,
            real: real.clone(),
            mask: None,
            distortion: camera.distortion,
            lens_origin: Some((
                cameras_file.clone(),
                format!("camera {} (params)", entry.camera_id),
            )),
        };
        let ((w, h), alpha, decoded) = photos.size(&source, options.background)?;
        transparent |= alpha;
        if (w, h) != (camera.width, camera.height) {
            return Err(Error::invalid(
                &origin,
                &item,
                "camera_id",
                format!(
                    "{} is {w}×{h} but camera {} is {}×{}",
                    real.display(),
                    entry.camera_id,
                    camera.width,
                    camera.height
                ),
            ));
        }
        let (image, weights, k) = photos.prepare(
            source,
            decoded,
            camera.intrinsics,
            n,
            &views,
            options.background,
            (&origin, &item),
        )?;
        let w2c = colmap::world_to_camera(entry.rotation, entry.translation);
        let camera = Camera::new(image.width, image.height, k, w2c).map_err(|e| match e {
            Error::Invalid { field, message, .. } => {
                Error::invalid(&origin, &item, &field, message)
            }
            other => other,
        })?;
        views.push(View {
            camera,
            time: 0.0,
            image,
            name,
            weights,
        });
    }
    let notes = missing_frames(&origin, &missing, views.len(), options.strict)?
        .into_iter()
        .chain(weights_note(
            &origin,
            &views,
            photos.undistorter.undistorted,
        ))
        .collect();
    let points = (!model.points.is_empty()).then(|| {
        model
            .points
            .iter()
            .map(|p| DatasetPoint {
                position: p.position,
                colour: p.colour.map(|c| (f64::from(c) / 255.0) as f32),
            })
            .collect()
    });
    Ok(FileViews {
        views,
        blend: None,
        transparent,
        notes,
        points,
    })
}

/// Reads every split of the dataset in `dir`: `transforms_{train,val,test}.json`, or one
/// `transforms.json` split every [`HOLDOUT`]-th frame, or a COLMAP model (`sparse/0`) split
/// the same way.
pub fn load_dataset(dir: &Path, options: &DatasetOptions) -> Result<Dataset> {
    if !dir.is_dir() {
        return Err(Error::malformed(
            &dir.display().to_string(),
            "not a folder with transforms_train.json, transforms.json or a COLMAP sparse/0",
        ));
    }
    // A transforms file that is a FIFO, socket, device or folder is refused, not taken for
    // a missing one.
    for name in TRANSFORMS_FILES {
        let path = dir.join(name);
        if let Some(kind) = crate::io::input::special_kind(&path) {
            return Err(Error::malformed(
                &path.display().to_string(),
                crate::io::input::not_regular(kind),
            ));
        }
    }
    let mut dataset = Dataset::default();
    let train_file = dir.join("transforms_train.json");
    let single = dir.join("transforms.json");
    let sparse = colmap::find_sparse_model(dir);
    if !train_file.is_file() && (single.is_file() || sparse.is_some()) {
        let read = match &sparse {
            Some(sparse) if !single.is_file() => read_colmap(dir, sparse, options)?,
            _ => read_transforms(dir, &single, options)?,
        };
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
        dataset.blend = read.blend;
        dataset.points = read.points;
    } else {
        for split in SPLITS {
            let path = dir.join(format!("transforms_{split}.json"));
            if !path.is_file() {
                continue;
            }
            let read = read_transforms(dir, &path, options)?;
            dataset.transparent |= read.transparent;
            dataset.notes.extend(read.notes);
            dataset.blend = dataset.blend.or(read.blend);
            if read.points.is_some() {
                dataset.points = read.points;
            }
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

/// The file [`load_dataset`] reads the training frames of the dataset in `dir` from
/// (`transforms_train.json`, `transforms.json`, or the COLMAP model's images file), or `dir`
/// itself when there is none: the origin messages about those frames name.
#[must_use]
pub fn training_file(dir: &Path) -> PathBuf {
    let train_file = dir.join("transforms_train.json");
    let single = dir.join("transforms.json");
    if train_file.is_file() {
        return train_file;
    }
    if single.is_file() {
        return single;
    }
    colmap::find_sparse_model(dir)
        .and_then(|sparse| {
            let [_, images, _] = colmap::model_files(&sparse);
            images
        })
        .unwrap_or_else(|| dir.to_path_buf())
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
fn write_transforms(
    dir: &Path,
    split: &str,
    c: &Camera,
    frames: Vec<WrittenFrame>,
    blend: Blend,
) -> Result<()> {
    let file = WrittenTransforms {
        camera_angle_x: 2.0 * (0.5 * f64::from(c.width) / c.fx).atan(),
        fl_x: c.fx,
        fl_y: c.fy,
        cx: c.cx,
        cy: c.cy,
        w: c.width,
        h: c.height,
        frames,
        splat4d_blend: blend,
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
    blend: Blend,
    /// Per split: the first camera (all must share its intrinsics) and the frames.
    splits: [(Option<Camera>, Vec<WrittenFrame>); 3],
}

impl DatasetWriter {
    /// A writer for `out`; checks before any work that `out` may be written.
    pub fn new(out: &Path, exr: bool) -> Result<Self> {
        Ok(DatasetWriter {
            folder: crate::io::output::FolderWriter::new(out, "dataset")?,
            exr,
            blend: Blend::Additive,
            splits: Default::default(),
        })
    }

    /// Records that the images are rendered with `blend` (additive unless said).
    #[must_use]
    pub fn with_blend(mut self, blend: Blend) -> Self {
        self.blend = blend;
        self
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
                write_transforms(self.folder.path(), split, &c, frames, self.blend)?;
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
    write_transforms(dir, split, &first.camera, frames, Blend::Additive)
}

/// The files a dataset is read from, by what they hold ([`dataset_inputs`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DatasetFiles {
    /// The transforms files, or the COLMAP model's files.
    pub descriptions: Vec<PathBuf>,
    /// The photos, one per frame that names one (a file named by two frames is listed
    /// twice).
    pub photos: Vec<PathBuf>,
    /// The masks (`mask_path`), one per frame that names one.
    pub masks: Vec<PathBuf>,
    /// The point clouds (`ply_file_path`).
    pub point_clouds: Vec<PathBuf>,
}

impl DatasetFiles {
    /// Every file, in the order above.
    #[must_use]
    pub fn all(&self) -> Vec<PathBuf> {
        [
            &self.descriptions,
            &self.photos,
            &self.masks,
            &self.point_clouds,
        ]
        .into_iter()
        .flatten()
        .cloned()
        .collect()
    }
}

/// The files a dataset in `dir` is read from (as far as its descriptions can be read; the
/// loader reports what cannot): its transforms files with the photos, masks (`mask_path`)
/// and point cloud (`ply_file_path`) they name, or the COLMAP model's files with the photos
/// its images file names (`images/NAME`). Outputs are checked against all of these before
/// any work ([`crate::io::output`]), and the memory estimate counts the photos and masks.
/// Only regular files are read here (a FIFO named like a transforms file would block).
#[must_use]
pub fn dataset_inputs(dir: &Path) -> DatasetFiles {
    let mut files = DatasetFiles::default();
    for name in TRANSFORMS_FILES {
        let path = dir.join(name);
        files.descriptions.push(path.clone());
        if !path.is_file() {
            continue;
        }
        let Ok(text) = crate::io::input::read_to_string(&path, "cannot read") else {
            continue;
        };
        let Ok(value) = serde_json::from_str::<serde_json::Value>(&text) else {
            continue;
        };
        let named = |v: &serde_json::Value, key: &str| {
            v.get(key).and_then(|p| p.as_str()).map(|p| dir.join(p))
        };
        files.point_clouds.extend(named(&value, "ply_file_path"));
        let frames = value.get("frames").and_then(|f| f.as_array());
        for frame in frames.into_iter().flatten() {
            if let Some(image) = frame
                .get("file_path")
                .and_then(|p| p.as_str())
                .and_then(|p| resolve_image(dir, p))
            {
                files.photos.push(image);
            }
            files.masks.extend(named(frame, "mask_path"));
        }
    }
    if let Some(sparse) = colmap::find_sparse_model(dir) {
        let [cameras, images, points] = colmap::model_files(&sparse);
        files
            .descriptions
            .extend([cameras, images.clone(), points].into_iter().flatten());
        // The photos its images file names, when the model is what the loader reads (no
        // transforms file beside it; a model the loader will refuse names none).
        let read =
            !dir.join("transforms_train.json").is_file() && !dir.join("transforms.json").is_file();
        let model = images.filter(|_| read).and_then(|images| {
            let bytes = std::fs::read(&images).ok()?;
            let origin = images.display().to_string();
            if images.extension().is_some_and(|e| e == "bin") {
                colmap::parse_images_bin(&bytes, &origin).ok()
            } else {
                colmap::parse_images_txt(std::str::from_utf8(&bytes).ok()?, &origin).ok()
            }
        });
        for image in model.map(|m| m.images).unwrap_or_default() {
            files.photos.push(dir.join("images").join(&image.name));
        }
    }
    files
}

/// Every file of [`dataset_inputs`].
#[must_use]
pub fn dataset_files(dir: &Path) -> Vec<PathBuf> {
    dataset_inputs(dir).all()
}

/// What the photos of a dataset hold in memory once loaded, estimated from the files'
/// headers before any is decoded ([`photo_memory`], [`crate::io::memory`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PhotoMemory {
    /// Bytes kept: every distinct photo the views hold (linear RGB f32, 12 bytes a pixel
    /// after downscaling: one decode per file, one undistorted or downscaled copy per file,
    /// mask and lens), and the pixel weights of every frame that has them (4 bytes a pixel,
    /// one array per frame: undistorted or masked).
    pub kept: u64,
    /// Bytes held at once, beyond `kept`, while the largest photo is prepared: its decode
    /// and linear copy, its mask's, its undistorted copy's validity and the remap tables
    /// kept.
    pub working: u64,
    /// Pixels of the largest view (after downscaling).
    pub largest_view: u64,
    /// Frames with an image file.
    pub frames: usize,
    /// Distinct image files.
    pub files: usize,
    /// Distinct arrays of pixels the views hold (decodes shared as they are, undistorted
    /// or downscaled copies).
    pub copies: usize,
}

/// One frame's photo as far as the estimate needs it: the image's real path, its mask's,
/// its lens.
type FramePhoto = (PathBuf, Option<PathBuf>, Distortion);

/// The photos of the frames of the dataset in `dir`, as the loader would read them (the
/// split files, else `transforms.json`, else the COLMAP model), as far as they can be read:
/// the loader reports what cannot.
fn frame_photos(dir: &Path) -> Vec<FramePhoto> {
    let real = |p: &Path| p.canonicalize().unwrap_or_else(|_| p.to_path_buf());
    let split_files: Vec<PathBuf> = SPLITS
        .iter()
        .map(|s| dir.join(format!("transforms_{s}.json")))
        .collect();
    let single = dir.join("transforms.json");
    let files = if split_files[0].is_file() {
        split_files
    } else if single.is_file() {
        vec![single]
    } else {
        let Some(sparse) = colmap::find_sparse_model(dir) else {
            return Vec::new();
        };
        let Ok(model) = colmap::read_sparse_model(&sparse) else {
            return Vec::new();
        };
        return model
            .images
            .iter()
            .filter_map(|image| {
                let path = dir.join("images").join(&image.name);
                let lens = model.cameras.get(&image.camera_id)?.distortion;
                path.is_file().then(|| (real(&path), None, lens))
            })
            .collect();
    };
    let mut photos = Vec::new();
    for path in files {
        let Ok(text) = crate::io::input::read_to_string(&path, "cannot read") else {
            continue;
        };
        let Ok(file) = serde_json::from_str::<TransformsFile>(&text) else {
            continue;
        };
        for frame in &file.frames {
            let Some(image) = resolve_image(dir, &frame.file_path) else {
                continue;
            };
            let mask = frame.mask_path.as_ref().map(|m| real(&dir.join(m)));
            let lens = distortion(&file, frame, "", "").unwrap_or_default();
            photos.push((real(&image), mask, lens));
        }
    }
    photos
}

/// Estimates what loading the dataset in `dir` with `downscale` holds
/// ([`PhotoMemory`]), following the loader's sharing: frames that name one file share its
/// decode, and frames that also share its mask and lens share one undistorted (or
/// downscaled) copy; each frame with weights has its own. Sizes come from the image
/// headers alone (nothing is decoded); unreadable files count nothing (the loader reports
/// them).
#[must_use]
pub fn photo_memory(dir: &Path, downscale: u32) -> PhotoMemory {
    use std::collections::{HashMap, HashSet};
    let n = u64::from(downscale.clamp(1, MAX_DOWNSCALE));
    let mut sizes: HashMap<PathBuf, Option<u64>> = HashMap::new();
    let mut copies: HashSet<(PathBuf, Option<PathBuf>, [u64; 5])> = HashSet::new();
    let mut shared: HashSet<PathBuf> = HashSet::new();
    let mut lenses: HashSet<[u64; 5]> = HashSet::new();
    let mut estimate = PhotoMemory::default();
    let (mut largest, mut masked, mut undistorted) = (0_u64, false, false);
    for (image, mask, lens) in frame_photos(dir) {
        let pixels = *sizes.entry(image.clone()).or_insert_with(|| {
            crate::io::image_file::image_size(&image)
                .ok()
                .map(|(w, h)| u64::from(w) * u64::from(h))
        });
        let Some(pixels) = pixels else {
            continue;
        };
        let view = pixels / (n * n);
        estimate.frames += 1;
        largest = largest.max(pixels);
        estimate.largest_view = estimate.largest_view.max(view);
        let bits = [
            lens.radial[0].to_bits(),
            lens.radial[1].to_bits(),
            lens.radial[2].to_bits(),
            lens.tangential[0].to_bits(),
            lens.tangential[1].to_bits(),
        ];
        let pinhole = lens.is_pinhole();
        if !pinhole {
            lenses.insert(bits);
            undistorted = true;
        }
        masked |= mask.is_some();
        // The decode itself is what the view holds when nothing changes its pixels (a mask
        // only weighs them); else one copy per file, mask and lens.
        let copy = if pinhole && n == 1 {
            shared.insert(image.clone())
        } else {
            copies.insert((image, mask.clone(), bits))
        };
        if copy {
            estimate.kept = estimate.kept.saturating_add(12 * view);
            estimate.copies += 1;
        }
        if mask.is_some() || !pinhole {
            estimate.kept = estimate.kept.saturating_add(4 * view);
        }
    }
    estimate.files = sizes.values().filter(|s| s.is_some()).count();
    // The decode (up to 16 bytes a pixel, RGBA f32) and its linear copy; a mask's the same
    // and its weights; an undistorted copy's validity and the remap tables kept (16 bytes
    // a pixel and a flag each).
    let tables = lenses.len().min(KEPT_TABLES) as u64;
    let per_pixel = crate::io::memory::DATASET_BYTES_PER_PIXEL
        + if masked { 32 } else { 0 }
        + if undistorted { 4 + 17 * tables } else { 0 };
    estimate.working = largest.saturating_mul(per_pixel);
    estimate
}
