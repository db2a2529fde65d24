//! COLMAP sparse models (`cameras`, `images`, `points3D`), text (`.txt`) and binary
//! (`.bin`, little endian), as COLMAP writes them.
//!
//! ```text
//! cameras.txt     CAMERA_ID MODEL WIDTH HEIGHT PARAMS...
//! images.txt      IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME
//!                 POINTS2D as (X Y POINT3D_ID)...        (the next line, may be empty)
//! points3D.txt    POINT3D_ID X Y Z R G B ERROR TRACK as (IMAGE_ID POINT2D_IDX)...
//!
//! cameras.bin     u64 count, then per camera: u32 id, i32 model id, u64 width, u64 height,
//!                 f64 params[n(model)]
//! images.bin      u64 count, then per image: u32 id, f64 qw qx qy qz, f64 tx ty tz,
//!                 u32 camera id, NUL-terminated name, u64 n, n × (f64 x, f64 y, i64 point3D id)
//! points3D.bin    u64 count, then per point: u64 id, f64 xyz[3], u8 rgb[3], f64 error,
//!                 u64 track length, length × (u32 image id, u32 point2D index)
//! ```
//!
//! Lines starting with `#` are comments. `(qw, qx, qy, qz)` is a Hamilton quaternion and
//! `(tx, ty, tz)` a translation taking world points to camera space with OpenCV axes:
//! exactly SPEC §3's `Rc = R(q)`, `tc = t`. COLMAP puts pixel centres at `i + ½` as SPEC §3
//! does, so its principal point is used as it is.
//!
//! Cameras read: SIMPLE_PINHOLE (`f cx cy`), PINHOLE (`fx fy cx cy`), SIMPLE_RADIAL
//! (`f cx cy k`), RADIAL (`f cx cy k1 k2`), OPENCV (`fx fy cx cy k1 k2 p1 p2`); other models
//! (fisheye, FULL_OPENCV, FOV, thin prism) are refused by name.
//!
//! Every count in a binary file is checked against the bytes it has left before anything
//! is allocated for it; every error names the file, the item (camera id, image id, point,
//! line) and the field. (The reader is written here: the one COLMAP crate found, `colmap`
//! 0.1, is a young whole-SfM library that needed a newer Rust than this crate did when the
//! reader was written.)

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use crate::model::distortion::Distortion;
use crate::model::error::{Error, Result, check_finite};

/// COLMAP's camera models by id, with their parameter counts.
const MODELS: [(&str, usize); 12] = [
    ("SIMPLE_PINHOLE", 3),
    ("PINHOLE", 4),
    ("SIMPLE_RADIAL", 4),
    ("RADIAL", 5),
    ("OPENCV", 8),
    ("OPENCV_FISHEYE", 8),
    ("FULL_OPENCV", 12),
    ("FOV", 5),
    ("SIMPLE_RADIAL_FISHEYE", 4),
    ("RADIAL_FISHEYE", 5),
    ("THIN_PRISM_FISHEYE", 12),
    ("RAD_TAN_THIN_PRISM_FISHEYE", 16),
];

/// Models read (the first five ids).
const READ_MODELS: usize = 5;

/// A camera: size, intrinsics and distortion.
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapCamera {
    /// Width and height, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// `[fx, fy, cx, cy]`, pixels.
    pub intrinsics: [f64; 4],
    /// The lens distortion (zero for the pinhole models).
    pub distortion: Distortion,
}

/// A registered image: its world→camera pose and camera.
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapImage {
    /// The image's id.
    pub id: u32,
    /// `(qw, qx, qy, qz)`, Hamilton, world→camera.
    pub rotation: [f64; 4],
    /// World→camera translation.
    pub translation: [f64; 3],
    /// The id of its camera in `cameras`.
    pub camera_id: u32,
    /// File name relative to the images folder.
    pub name: String,
}

/// A 3D point of the reconstruction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ColmapPoint {
    /// World position.
    pub position: [f64; 3],
    /// 8-bit colour.
    pub colour: [u8; 3],
}

/// A sparse model: cameras by id, images in file order, points (empty without a
/// `points3D` file).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SparseModel {
    /// Cameras by id.
    pub cameras: BTreeMap<u32, ColmapCamera>,
    /// Registered images.
    pub images: Vec<ColmapImage>,
    /// Points.
    pub points: Vec<ColmapPoint>,
}

/// The folder holding a sparse model under a dataset folder `dir`: `dir/sparse/0`, then
/// `dir/sparse`, whichever has a `cameras.bin` or `cameras.txt` (of any kind: one that is
/// not a regular file is refused when read, [`crate::io::input`]).
#[must_use]
pub fn find_sparse_model(dir: &Path) -> Option<PathBuf> {
    [dir.join("sparse").join("0"), dir.join("sparse")]
        .into_iter()
        .find(|d| d.join("cameras.bin").exists() || d.join("cameras.txt").exists())
}

/// The files of the sparse model in `sparse` (binary first, then text; `points3D` may be
/// missing), as `[cameras, images, points3D]`: the names that exist, whatever their kind
/// (a FIFO or a folder is refused when read, not taken for a missing file).
#[must_use]
pub fn model_files(sparse: &Path) -> [Option<PathBuf>; 3] {
    ["cameras", "images", "points3D"].map(|stem| {
        ["bin", "txt"]
            .iter()
            .map(|ext| sparse.join(format!("{stem}.{ext}")))
            .find(|p| p.exists())
    })
}

/// Reads the sparse model in the folder `sparse`.
pub fn read_sparse_model(sparse: &Path) -> Result<SparseModel> {
    let [cameras, images, points] = model_files(sparse);
    let missing = |stem: &str| {
        Error::malformed(
            &sparse.display().to_string(),
            format!("a COLMAP model needs {stem}.bin or {stem}.txt"),
        )
    };
    let cameras = cameras.ok_or_else(|| missing("cameras"))?;
    let images = images.ok_or_else(|| missing("images"))?;
    let read = |path: &Path| crate::io::input::read(path, "cannot read");
    let binary = |path: &Path| path.extension().is_some_and(|e| e == "bin");
    let parse = |path: &Path,
                 bin: fn(&[u8], &str) -> Result<SparseModel>,
                 text: fn(&str, &str) -> Result<SparseModel>|
     -> Result<SparseModel> {
        let bytes = read(path)?;
        let origin = path.display().to_string();
        if binary(path) {
            bin(&bytes, &origin)
        } else {
            let text_bytes = std::str::from_utf8(&bytes)
                .map_err(|_| Error::malformed(&origin, "not UTF-8 text"))?;
            text(text_bytes, &origin)
        }
    };
    let mut model = parse(&cameras, parse_cameras_bin, parse_cameras_txt)?;
    model.images = parse(&images, parse_images_bin, parse_images_txt)?.images;
    if let Some(points) = points {
        model.points = parse(&points, parse_points_bin, parse_points_txt)?.points;
    }
    Ok(model)
}

/// A camera from a model id (or name) and its parameters.
fn camera(
    origin: &str,
    item: &str,
    model: usize,
    (width, height): (u64, u64),
    params: &[f64],
) -> Result<ColmapCamera> {
    check_finite(origin, item, "params", params)?;
    let size = |field: &str, v: u64| {
        u32::try_from(v).ok().filter(|&v| v > 0).ok_or_else(|| {
            Error::invalid(
                origin,
                item,
                field,
                format!("{v} pixels is not in 1 ..= 2^32 - 1"),
            )
        })
    };
    let (width, height) = (size("width", width)?, size("height", height)?);
    let p = params;
    let (intrinsics, radial, tangential) = match model {
        0 => ([p[0], p[0], p[1], p[2]], [0.0; 3], [0.0; 2]),
        1 => ([p[0], p[1], p[2], p[3]], [0.0; 3], [0.0; 2]),
        2 => ([p[0], p[0], p[1], p[2]], [p[3], 0.0, 0.0], [0.0; 2]),
        3 => ([p[0], p[0], p[1], p[2]], [p[3], p[4], 0.0], [0.0; 2]),
        4 => ([p[0], p[1], p[2], p[3]], [p[4], p[5], 0.0], [p[6], p[7]]),
        _ => unreachable!("models past OPENCV are refused before"),
    };
    Ok(ColmapCamera {
        width,
        height,
        intrinsics,
        distortion: Distortion { radial, tangential },
    })
}

/// The error for a camera model splat4d does not read.
fn unsupported_model(origin: &str, item: &str, name: &str) -> Error {
    let read: Vec<&str> = MODELS[..READ_MODELS].iter().map(|m| m.0).collect();
    Error::invalid(
        origin,
        item,
        "model",
        format!(
            "{name} cameras are not supported (fisheye and other non-pinhole lenses); read: {}",
            read.join(", ")
        ),
    )
}

/// A little-endian reader over a binary file that names what it failed to read.
struct Bytes<'a> {
    bytes: &'a [u8],
    at: usize,
    origin: &'a str,
}

impl<'a> Bytes<'a> {
    fn new(bytes: &'a [u8], origin: &'a str) -> Self {
        Bytes {
            bytes,
            at: 0,
            origin,
        }
    }

    fn remaining(&self) -> usize {
        self.bytes.len() - self.at
    }

    fn take(&mut self, n: usize, item: &str, field: &str) -> Result<&'a [u8]> {
        if n > self.remaining() {
            return Err(Error::invalid(
                self.origin,
                item,
                field,
                format!(
                    "the file ends at byte {} ({n} bytes needed, {} left)",
                    self.bytes.len(),
                    self.remaining()
                ),
            ));
        }
        let slice = &self.bytes[self.at..self.at + n];
        self.at += n;
        Ok(slice)
    }

    fn array<const N: usize>(&mut self, item: &str, field: &str) -> Result<[u8; N]> {
        let slice = self.take(N, item, field)?;
        let mut out = [0; N];
        out.copy_from_slice(slice);
        Ok(out)
    }

    fn u64(&mut self, item: &str, field: &str) -> Result<u64> {
        Ok(u64::from_le_bytes(self.array(item, field)?))
    }

    fn u32(&mut self, item: &str, field: &str) -> Result<u32> {
        Ok(u32::from_le_bytes(self.array(item, field)?))
    }

    fn i32(&mut self, item: &str, field: &str) -> Result<i32> {
        Ok(i32::from_le_bytes(self.array(item, field)?))
    }

    fn f64(&mut self, item: &str, field: &str) -> Result<f64> {
        Ok(f64::from_le_bytes(self.array(item, field)?))
    }

    /// `count` items of at least `min_size` bytes each must fit in what is left; returns
    /// the count as a `usize`.
    fn count(&mut self, item: &str, field: &str, min_size: usize) -> Result<usize> {
        let count = self.u64(item, field)?;
        let remaining = self.remaining();
        usize::try_from(count)
            .ok()
            .filter(|&c| c.checked_mul(min_size).is_some_and(|n| n <= remaining))
            .ok_or_else(|| {
                Error::invalid(
                    self.origin,
                    item,
                    field,
                    format!(
                        "{count} entries of at least {min_size} bytes do not fit in the {remaining} bytes left"
                    ),
                )
            })
    }

    fn finish(&self) -> Result<()> {
        if self.remaining() != 0 {
            return Err(Error::malformed(
                self.origin,
                format!("{} bytes after the last entry", self.remaining()),
            ));
        }
        Ok(())
    }
}

/// Parses `cameras.bin`.
pub fn parse_cameras_bin(bytes: &[u8], origin: &str) -> Result<SparseModel> {
    let mut r = Bytes::new(bytes, origin);
    let count = r.count("cameras", "count", 24)?;
    let mut model = SparseModel::default();
    for k in 0..count {
        let item = format!("camera {k}");
        let id = r.u32(&item, "camera_id")?;
        let item = format!("camera {id}");
        let model_id = r.i32(&item, "model_id")?;
        let width = r.u64(&item, "width")?;
        let height = r.u64(&item, "height")?;
        let Some(&(name, n)) = usize::try_from(model_id).ok().and_then(|m| MODELS.get(m)) else {
            return Err(Error::invalid(
                origin,
                &item,
                "model_id",
                format!("{model_id} is not a COLMAP camera model"),
            ));
        };
        let model_id = model_id as usize;
        if model_id >= READ_MODELS {
            return Err(unsupported_model(origin, &item, name));
        }
        let mut params = Vec::with_capacity(n);
        for p in 0..n {
            params.push(r.f64(&item, &format!("params[{p}]"))?);
        }
        let camera = camera(origin, &item, model_id, (width, height), &params)?;
        if model.cameras.insert(id, camera).is_some() {
            return Err(Error::invalid(origin, &item, "camera_id", "appears twice"));
        }
    }
    r.finish()?;
    Ok(model)
}

/// Parses `images.bin`.
pub fn parse_images_bin(bytes: &[u8], origin: &str) -> Result<SparseModel> {
    let mut r = Bytes::new(bytes, origin);
    // id 4, pose 56, camera 4, name ≥ 1, points count 8.
    let count = r.count("images", "count", 73)?;
    let mut model = SparseModel::default();
    model.images.reserve(count);
    for k in 0..count {
        let item = format!("image {k}");
        let id = r.u32(&item, "image_id")?;
        let item = format!("image {id}");
        let mut q = [0.0; 4];
        for (c, field) in q.iter_mut().zip(["qw", "qx", "qy", "qz"]) {
            *c = r.f64(&item, field)?;
        }
        let mut t = [0.0; 3];
        for (c, field) in t.iter_mut().zip(["tx", "ty", "tz"]) {
            *c = r.f64(&item, field)?;
        }
        let camera_id = r.u32(&item, "camera_id")?;
        let rest = &r.bytes[r.at..];
        let end = rest.iter().position(|&b| b == 0).ok_or_else(|| {
            Error::invalid(
                origin,
                &item,
                "name",
                "no NUL ends the name before the file ends",
            )
        })?;
        let name = std::str::from_utf8(&rest[..end])
            .map_err(|_| Error::invalid(origin, &item, "name", "not UTF-8"))?
            .to_owned();
        r.at += end + 1;
        let points = r.count(&item, "num_points2D", 24)?;
        r.take(points * 24, &item, "points2D")?;
        model
            .images
            .push(image(origin, &item, id, q, t, camera_id, name)?);
    }
    r.finish()?;
    Ok(model)
}

/// Parses `points3D.bin`.
pub fn parse_points_bin(bytes: &[u8], origin: &str) -> Result<SparseModel> {
    let mut r = Bytes::new(bytes, origin);
    // id 8, xyz 24, rgb 3, error 8, track length 8.
    let count = r.count("points3D", "count", 51)?;
    let mut model = SparseModel::default();
    model.points.reserve(count);
    for k in 0..count {
        let item = format!("point {k}");
        let _id = r.u64(&item, "point3D_id")?;
        let mut position = [0.0; 3];
        for (c, field) in position.iter_mut().zip(["x", "y", "z"]) {
            *c = r.f64(&item, field)?;
        }
        check_finite(origin, &item, "xyz", &position)?;
        let colour = r.array::<3>(&item, "rgb")?;
        let _error = r.f64(&item, "error")?;
        let track = r.count(&item, "track_length", 8)?;
        r.take(track * 8, &item, "track")?;
        model.points.push(ColmapPoint { position, colour });
    }
    r.finish()?;
    Ok(model)
}

/// An image entry, checked: a finite pose and a quaternion that is not zero.
fn image(
    origin: &str,
    item: &str,
    id: u32,
    rotation: [f64; 4],
    translation: [f64; 3],
    camera_id: u32,
    name: String,
) -> Result<ColmapImage> {
    check_finite(origin, item, "qvec", &rotation)?;
    check_finite(origin, item, "tvec", &translation)?;
    if rotation.iter().all(|&v| v == 0.0) {
        return Err(Error::invalid(
            origin,
            item,
            "qvec",
            "the quaternion is zero",
        ));
    }
    if name.is_empty() {
        return Err(Error::invalid(origin, item, "name", "empty"));
    }
    Ok(ColmapImage {
        id,
        rotation,
        translation,
        camera_id,
        name,
    })
}

/// The data lines of a text file with their line numbers (from 1): comments and blank
/// lines skipped.
fn data_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines()
        .enumerate()
        .map(|(n, l)| (n + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'))
}

/// The whitespace-separated field `index` of `words`, parsed.
fn field<T: std::str::FromStr>(
    words: &[&str],
    index: usize,
    origin: &str,
    item: &str,
    name: &str,
) -> Result<T> {
    let word = words
        .get(index)
        .ok_or_else(|| Error::invalid(origin, item, name, "missing"))?;
    word.parse().map_err(|_| {
        Error::invalid(
            origin,
            item,
            name,
            format!("{word:?} is not a valid {name}"),
        )
    })
}

/// Parses `cameras.txt`.
pub fn parse_cameras_txt(text: &str, origin: &str) -> Result<SparseModel> {
    let mut model = SparseModel::default();
    for (n, line) in data_lines(text) {
        let item = format!("line {n}");
        let words: Vec<&str> = line.split_whitespace().collect();
        let id: u32 = field(&words, 0, origin, &item, "camera_id")?;
        let item = format!("line {n} (camera {id})");
        let name: String = field(&words, 1, origin, &item, "model")?;
        let width: u64 = field(&words, 2, origin, &item, "width")?;
        let height: u64 = field(&words, 3, origin, &item, "height")?;
        let Some(model_id) = MODELS.iter().position(|m| m.0 == name) else {
            return Err(Error::invalid(
                origin,
                &item,
                "model",
                format!("{name} is not a COLMAP camera model"),
            ));
        };
        if model_id >= READ_MODELS {
            return Err(unsupported_model(origin, &item, &name));
        }
        let count = MODELS[model_id].1;
        if words.len() != 4 + count {
            return Err(Error::invalid(
                origin,
                &item,
                "params",
                format!(
                    "{name} has {count} parameters, the line gives {}",
                    words.len().saturating_sub(4)
                ),
            ));
        }
        let params = (0..count)
            .map(|p| field(&words, 4 + p, origin, &item, &format!("params[{p}]")))
            .collect::<Result<Vec<f64>>>()?;
        let camera = camera(origin, &item, model_id, (width, height), &params)?;
        if model.cameras.insert(id, camera).is_some() {
            return Err(Error::invalid(origin, &item, "camera_id", "appears twice"));
        }
    }
    Ok(model)
}

/// Parses `images.txt`: each image line is followed by its points line (which may be
/// empty), as COLMAP writes it; a missing points line is tolerated.
pub fn parse_images_txt(text: &str, origin: &str) -> Result<SparseModel> {
    let mut model = SparseModel::default();
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(n, l)| (n + 1, l.trim()))
        .peekable();
    while let Some((n, line)) = lines.next() {
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let item = format!("line {n}");
        let words: Vec<&str> = line.split_whitespace().collect();
        let id: u32 = field(&words, 0, origin, &item, "image_id")?;
        let item = format!("line {n} (image {id})");
        let mut q = [0.0; 4];
        for (k, name) in ["qw", "qx", "qy", "qz"].iter().enumerate() {
            q[k] = field(&words, 1 + k, origin, &item, name)?;
        }
        let mut t = [0.0; 3];
        for (k, name) in ["tx", "ty", "tz"].iter().enumerate() {
            t[k] = field(&words, 5 + k, origin, &item, name)?;
        }
        let camera_id: u32 = field(&words, 8, origin, &item, "camera_id")?;
        let name = words.get(9..).map(|w| w.join(" ")).unwrap_or_default();
        model
            .images
            .push(image(origin, &item, id, q, t, camera_id, name)?);
        // The points line (numbers only, or empty): read and ignored. A file written
        // without points lines goes straight on to the next image line (it has a name).
        let is_points = |l: &str| l.split_whitespace().all(|w| w.parse::<f64>().is_ok());
        if lines.peek().is_some_and(|(_, l)| is_points(l)) {
            lines.next();
        }
    }
    Ok(model)
}

/// Parses `points3D.txt`.
pub fn parse_points_txt(text: &str, origin: &str) -> Result<SparseModel> {
    let mut model = SparseModel::default();
    for (n, line) in data_lines(text) {
        let item = format!("line {n}");
        let words: Vec<&str> = line.split_whitespace().collect();
        let _id: u64 = field(&words, 0, origin, &item, "point3D_id")?;
        let mut position = [0.0; 3];
        for (k, name) in ["x", "y", "z"].iter().enumerate() {
            position[k] = field(&words, 1 + k, origin, &item, name)?;
        }
        check_finite(origin, &item, "xyz", &position)?;
        let mut colour = [0u8; 3];
        for (k, name) in ["r", "g", "b"].iter().enumerate() {
            colour[k] = field(&words, 4 + k, origin, &item, name)?;
        }
        model.points.push(ColmapPoint { position, colour });
    }
    Ok(model)
}

/// The world→camera matrix (row-major, OpenCV axes) of a COLMAP pose: `R(q)` of the
/// normalised quaternion `(w, x, y, z)` and the translation.
#[must_use]
pub fn world_to_camera(rotation: [f64; 4], translation: [f64; 3]) -> [[f64; 4]; 4] {
    let [w, x, y, z] = unit_quaternion(rotation);
    let [tx, ty, tz] = translation;
    [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
            tx,
        ],
        [
            2.0 * (x * y + w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - w * x),
            ty,
        ],
        [
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            1.0 - 2.0 * (x * x + y * y),
            tz,
        ],
        [0.0, 0.0, 0.0, 1.0],
    ]
}

/// `q / |q|` for any finite, non-zero `q`: scaled by its largest component first, so that
/// neither `|q|²` overflows (a unit quaternion times 1e200) nor underflows (times 1e-200).
fn unit_quaternion(q: [f64; 4]) -> [f64; 4] {
    let largest = q.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
    let scaled = q.map(|v| v / largest);
    let norm = scaled.iter().map(|v| v * v).sum::<f64>().sqrt();
    scaled.map(|v| v / norm)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_quaternion_scaled_far_up_or_down_is_the_same_rotation() {
        let q = [0.5_f64, 0.5, -0.5, 0.5];
        let t = [1.0, -2.0, 3.0];
        let unit = world_to_camera(q, t);
        for scale in [1e200, 1e-200, 3.0, 1e300, 5e-310] {
            let scaled = world_to_camera(q.map(|v| v * scale), t);
            for (row, expected) in scaled.iter().zip(&unit) {
                for (a, b) in row.iter().zip(expected) {
                    assert!(
                        (a - b).abs() < 1e-12,
                        "scale {scale}: {scaled:?} vs {unit:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn images_txt_with_and_without_points_lines() {
        let with =
            "# comment\n1 1 0 0 0 0.5 0 2 1 a.png\n1.0 2.0 -1 3 4 7\n2 0 1 0 0 0 0 1 1 b c.png\n\n";
        let without = "1 1 0 0 0 0.5 0 2 1 a.png\n2 0 1 0 0 0 0 1 1 b c.png\n";
        let a = parse_images_txt(with, "with").unwrap();
        let b = parse_images_txt(without, "without").unwrap();
        assert_eq!(a, b);
        assert_eq!(a.images.len(), 2);
        assert_eq!(a.images[1].name, "b c.png");
        assert_eq!(a.images[0].translation, [0.5, 0.0, 2.0]);
        // R(q) of a quarter turn about x: y → z.
        let m = world_to_camera([0.5_f64.sqrt(), 0.5_f64.sqrt(), 0.0, 0.0], [0.0; 3]);
        let y = [m[0][1], m[1][1], m[2][1]];
        assert!((y[0]).abs() < 1e-15 && y[1].abs() < 1e-15 && (y[2] - 1.0).abs() < 1e-15);
    }
}
