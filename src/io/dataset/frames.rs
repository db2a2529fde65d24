//! From a format's frames to views: the loop every format that reads photo files shares.
//! A format describes each frame ([`FrameSource`]); [`load_views`] skips frames whose image
//! is missing, runs the shared steps on the others ([`super::photos`]) and collects the notes
//! on what it skipped, undistorted and masked.

use std::path::{Path, PathBuf};

use crate::model::View;
use crate::model::camera::Camera;
use crate::model::error::{Error, MAX_QUOTE, Result, cut};

use super::photos::{Photos, Source};
use super::{DatasetOptions, check_downscale};

/// Frames named in the note (or error) about missing images.
const NAMED_MISSING: usize = 5;

/// One frame as its format describes it, before its photo is read.
pub(super) struct Frame {
    /// The frame in errors: `frame 3`, `image 5 (a.png)`.
    pub item: String,
    /// The view's name (`./train/r_000`), and the missing image's in the note.
    pub name: String,
    /// Its photo; `None` when the image file is missing (the frame is skipped with a note).
    pub photo: Option<Source>,
}

/// What a dataset format says about its frames, asked by [`load_views`] in this order for
/// each: its photo, its intrinsics once the photo's size is known, its camera and time once
/// the photo is prepared.
pub(super) trait FrameSource {
    /// The origin of errors and notes: the file that lists the frames.
    fn origin(&self) -> &str;

    /// How many frames there are.
    fn count(&self) -> usize;

    /// Frame `index`, with its photo's paths checked.
    fn frame(&self, index: usize) -> Result<Frame>;

    /// `[fx, fy, cx, cy]` of frame `index`, whose photo `source` is `size` pixels (before
    /// downscaling).
    fn intrinsics(
        &self,
        index: usize,
        frame: &Frame,
        source: &Source,
        size: (u32, u32),
    ) -> Result<[f64; 4]>;

    /// The camera of frame `index` for its prepared photo of `size` pixels and intrinsics
    /// `k`, and its time.
    fn camera(
        &self,
        index: usize,
        frame: &Frame,
        size: (u32, u32),
        k: [f64; 4],
    ) -> Result<(Camera, f64)>;
}

/// The views of a format's frames and what loading them noticed.
pub(super) struct LoadedViews {
    pub views: Vec<View>,
    /// Some pixel had alpha below 1.
    pub transparent: bool,
    /// The notes on missing frames and on undistortion and masks.
    pub notes: Vec<String>,
}

/// Reads the views of `frames`: each frame's photo decoded, undistorted, masked and
/// downscaled as `options` say ([`Photos`]), in order; frames without an image skipped (or
/// refused, [`DatasetOptions::strict`]).
pub(super) fn load_views(
    frames: &dyn FrameSource,
    options: &DatasetOptions,
) -> Result<LoadedViews> {
    check_downscale(options.downscale)?;
    let origin = frames.origin();
    let mut views = Vec::with_capacity(frames.count().min(1 << 16));
    let mut transparent = false;
    let mut missing = Vec::new();
    let mut photos = Photos::new(options);
    for index in 0..frames.count() {
        let mut frame = frames.frame(index)?;
        let Some(source) = frame.photo.take() else {
            missing.push((frame.item, frame.name));
            continue;
        };
        let (size, alpha, decoded) = photos.size(&source)?;
        transparent |= alpha;
        let k = frames.intrinsics(index, &frame, &source, size)?;
        let ctx = (origin, frame.item.as_str());
        let (image, weights, k) = photos.prepare(source, decoded, k, &views, ctx)?;
        let (camera, time) = frames.camera(index, &frame, (image.width, image.height), k)?;
        views.push(View {
            camera,
            time,
            image,
            name: frame.name,
            weights,
        });
    }
    let notes = missing_frames(origin, &missing, views.len(), options.strict)?
        .into_iter()
        .chain(weights_note(origin, &views, photos.undistorted()))
        .collect();
    Ok(LoadedViews {
        views,
        transparent,
        notes,
    })
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

/// `relative` under the dataset folder `dir`, checked to lie inside it (after resolving
/// links and `..`).
pub(super) fn inside_dataset(
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
pub(super) fn regular_file(
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
