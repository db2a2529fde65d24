//! What a dataset's photos will hold in memory once loaded, estimated from the frames its
//! format describes and the image files' headers, before any photo is decoded
//! ([`crate::io::memory`]).

use std::collections::{HashMap, HashSet};
use std::path::PathBuf;

use crate::model::distortion::Distortion;

use super::MAX_DOWNSCALE;
use super::photos::{KEPT_TABLES, lens_bits};

/// What the photos of a dataset hold in memory once loaded, estimated from the files'
/// headers before any is decoded ([`super::photo_memory`], [`crate::io::memory`]).
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
pub(super) type FramePhoto = (PathBuf, Option<PathBuf>, Distortion);

/// Estimates what loading the frames `photos` with `downscale` holds ([`PhotoMemory`]),
/// following the loader's sharing: frames that name one file share its decode, and frames
/// that also share its mask and lens share one undistorted (or downscaled) copy; each frame
/// with weights has its own. Sizes come from the image headers alone (nothing is decoded);
/// unreadable files count nothing (the loader reports them).
pub(super) fn estimate(photos: Vec<FramePhoto>, downscale: u32) -> PhotoMemory {
    let n = u64::from(downscale.clamp(1, MAX_DOWNSCALE));
    let mut sizes: HashMap<PathBuf, Option<u64>> = HashMap::new();
    let mut copies: HashSet<(PathBuf, Option<PathBuf>, [u64; 5])> = HashSet::new();
    let mut shared: HashSet<PathBuf> = HashSet::new();
    let mut lenses: HashSet<[u64; 5]> = HashSet::new();
    let mut estimate = PhotoMemory::default();
    let (mut largest, mut masked, mut undistorted) = (0_u64, false, false);
    for (image, mask, lens) in photos {
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
        let bits = lens_bits(&lens);
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
