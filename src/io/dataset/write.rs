//! Writing a dataset in the D-NeRF / Blender layout ([`super::blender`]), as
//! `splat4d dataset` does: per split, its images (16-bit PNG, and float EXR when asked) under
//! `DIR/SPLIT/r_000`, and `DIR/transforms_SPLIT.json` with `camera_angle_x` and the exact
//! intrinsics (`fl_x`, `fl_y`, `cx`, `cy`, `w`, `h`, so cameras round-trip), each frame's
//! `time` and OpenGL camera-to-world `transform_matrix`, and `splat4d_blend`.

use std::path::Path;

use serde::Serialize;

use crate::io::image_file::{BitDepth, save_image};
use crate::io::write_bytes_atomically;
use crate::model::camera::Camera;
use crate::model::error::{Error, Result};
use crate::model::{Blend, View};

use super::SPLITS;

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

/// The files (relative to the dataset's folder) of frame `index` of `split`: its PNG, and
/// its EXR when `exr`.
#[must_use]
pub fn frame_files(split: &str, index: usize, exr: bool) -> Vec<String> {
    let base = format!("{split}/r_{index:03}");
    let mut files = vec![format!("{base}.png")];
    if exr {
        files.push(format!("{base}.exr"));
    }
    files
}

/// Writes the images of frame `index` of `split` (the view `view`) under `dir`, as
/// [`DatasetWriter::add`] does; returns their files ([`frame_files`]).
pub fn write_frame_images(
    dir: &Path,
    split: &str,
    index: usize,
    view: &View,
    exr: bool,
) -> Result<Vec<String>> {
    save_frame(dir, split, index, view, &view.camera, exr)?;
    Ok(frame_files(split, index, exr))
}

/// Writes the `transforms_*.json` of the frames `frames` — `(split, index, camera, time)`
/// in file order, their images already in `dir` — as [`DatasetWriter::finish`] does.
pub fn write_all_transforms(
    dir: &Path,
    frames: &[(&str, usize, Camera, f64)],
    blend: Blend,
) -> Result<()> {
    for split in SPLITS {
        let mut first: Option<Camera> = None;
        let mut written = Vec::new();
        for &(s, index, camera, time) in frames.iter().filter(|f| f.0 == split) {
            let c = *first.get_or_insert(camera);
            let (v, c) = (&camera, &c);
            if (v.width, v.height, v.fx, v.fy, v.cx, v.cy)
                != (c.width, c.height, c.fx, c.fy, c.cx, c.cy)
            {
                return Err(Error::Usage(format!(
                    "split {s}: view {index} has other intrinsics than view 0"
                )));
            }
            written.push(WrittenFrame {
                file_path: format!("./{s}/r_{index:03}"),
                time,
                transform_matrix: camera.opengl_camera_to_world(),
            });
        }
        if let Some(c) = first {
            write_transforms(dir, split, &c, written, blend)?;
        }
    }
    Ok(())
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
