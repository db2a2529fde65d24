//! The steps every dataset format shares once it has named a frame's photo: the file decoded
//! once (linear RGB, RGBA composited over the background), lens distortion removed, the
//! mask's weights applied, the photo downscaled; frames that name one file with one mask,
//! intrinsics and lens share one prepared image.
//!
//! Undistortion resamples the photo into the pinhole camera with the same `fx fy cx cy`
//! ([`crate::model::distortion`]), one remap table per distinct camera; pixels whose source
//! lies outside the photo weigh 0 ([`View::weights`]). A mask (a greyscale image the size of
//! the photo, 0 = ignore; RGB masks: the mean of the channels, alpha composited over black)
//! multiplies the weights, undistorted with the photo. `downscale` N then averages N×N blocks
//! ([`downscale_weighted`] with weights) and divides the intrinsics by N.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Weak};

use crate::io::image_file::load_image_with_alpha;
use crate::model::distortion::{Distortion, RemapTable};
use crate::model::error::{Error, Result};
use crate::model::image::downscale_weighted;
use crate::model::{Image, View};

use super::DatasetOptions;

/// A lens's coefficients as bits, `[k1, k2, k3, p1, p2]`: a key for photos and tables.
pub(super) fn lens_bits(d: &Distortion) -> [u64; 5] {
    [
        d.radial[0].to_bits(),
        d.radial[1].to_bits(),
        d.radial[2].to_bits(),
        d.tangential[0].to_bits(),
        d.tangential[1].to_bits(),
    ]
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
pub(super) const KEPT_TABLES: usize = 4;

impl Undistorter {
    fn table(&mut self, (w, h): (u32, u32), k: [f64; 4], d: &Distortion) -> &RemapTable {
        let mut key = [0; 11];
        key[..2].copy_from_slice(&[u64::from(w), u64::from(h)]);
        key[2..6].copy_from_slice(&k.map(f64::to_bits));
        key[6..].copy_from_slice(&lens_bits(d));
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

/// A photo ready to fit: the image (shared with other frames when nothing changed it), its
/// pixel weights (`None`: every pixel counts fully), and `[fx, fy, cx, cy]`.
pub(super) type PreparedPhoto = (Arc<Image>, Option<Vec<f32>>, [f64; 4]);

/// One photo as read, before it becomes a [`View`].
struct Photo {
    image: Arc<Image>,
    /// The mask's weights, one per photo pixel.
    mask: Option<Vec<f32>>,
    /// `[fx, fy, cx, cy]` of the photo, pixels.
    intrinsics: [f64; 4],
    distortion: Distortion,
    /// Where the lens coefficients come from (file, item), when not the photo's own entry
    /// (a COLMAP camera).
    lens_origin: Option<(String, String)>,
}

/// The photo undistorted, masked and downscaled by `n`: the image, its pixel weights
/// (`None` when every pixel counts fully) and the pinhole intrinsics of the result.
fn prepare_photo(
    photo: Photo,
    undistorter: &mut Undistorter,
    n: u32,
    (origin, item): (&str, &str),
) -> Result<PreparedPhoto> {
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
    let (image, weights) = downscale(image, mask, n, (origin, item))?;
    let scale = f64::from(n);
    Ok((image, weights, intrinsics.map(|v| v / scale)))
}

/// `image` and its weights `mask` downscaled by `n`; the weights `None` when all are 1.
/// No second whole-image copy when nothing is downscaled: frames naming one file share its
/// decode.
fn downscale(
    image: Arc<Image>,
    mask: Option<Vec<f32>>,
    n: u32,
    (origin, item): (&str, &str),
) -> Result<(Arc<Image>, Option<Vec<f32>>)> {
    let Some(m) = mask else {
        return Ok(if n == 1 {
            (image, None)
        } else {
            (Arc::new(image.downscaled(n)), None)
        });
    };
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
    Ok((image, (!all_ones).then_some(weights)))
}

/// A prepared photo's identity: the image file's and the mask's real paths, the photo's
/// intrinsics and its lens (as bits).
type PhotoKey = (PathBuf, Option<PathBuf>, [u64; 4], [u64; 5]);

/// A file decoded: the decode (weak), whether a pixel was transparent, its size.
type DecodedFile = (Weak<Image>, bool, (u32, u32));

/// What [`Photos::size`] tells of a file: its size, whether a pixel is transparent, and its
/// decode when at hand.
pub(super) type FileSize = ((u32, u32), bool, Option<Arc<Image>>);

/// A frame's photo as its format names it: the image (its path as found and its real path),
/// the mask's path (real, checked inside the dataset), and the lens.
pub(super) struct Source {
    pub image: PathBuf,
    pub real: PathBuf,
    pub mask: Option<PathBuf>,
    pub distortion: Distortion,
    /// Where the lens comes from when not the frame itself (`(file, item)`: a COLMAP
    /// camera), for errors about its coefficients.
    pub lens_origin: Option<(String, String)>,
}

/// The photos of one dataset file as they load. Each distinct image file is decoded once,
/// and frames naming one file with one mask, intrinsics and lens share one prepared photo
/// (one undistorted or downscaled copy, [`View::image`] an `Arc` shared between them): 25
/// frames of one photo hold one image, not 25.
pub(super) struct Photos {
    /// Decoded files by real path: the decode (weak: one that nothing keeps, a photo
    /// undistorted or downscaled into a copy, is not held while the rest load), whether a
    /// pixel was transparent, and its size.
    decoded: HashMap<PathBuf, DecodedFile>,
    /// Prepared photos: the view holding it (an index into the views loaded so far) and its
    /// intrinsics.
    prepared: HashMap<PhotoKey, (usize, [f64; 4])>,
    undistorter: Undistorter,
    /// RGBA pixels are composited over it.
    background: [f32; 3],
    /// The downscale factor.
    n: u32,
}

impl Photos {
    /// No photo read yet, to be read as `options` say.
    pub fn new(options: &DatasetOptions) -> Self {
        Photos {
            decoded: HashMap::new(),
            prepared: HashMap::new(),
            undistorter: Undistorter::default(),
            background: options.background,
            n: options.downscale,
        }
    }

    /// Photos undistorted so far (each frame counted).
    pub fn undistorted(&self) -> usize {
        self.undistorter.undistorted
    }

    /// The size of the image `source` names and whether a pixel is transparent; the file is
    /// decoded unless an earlier frame's decode told, and the decode returned when it is at
    /// hand (made now, or still held).
    pub fn size(&mut self, source: &Source) -> Result<FileSize> {
        if let Some((weak, alpha, size)) = self.decoded.get(&source.real) {
            return Ok((*size, *alpha, weak.upgrade()));
        }
        let (image, alpha) = self.decode(source)?;
        Ok(((image.width, image.height), alpha, Some(image)))
    }

    /// Decodes the image of `source` and records it.
    fn decode(&mut self, source: &Source) -> Result<(Arc<Image>, bool)> {
        let (image, alpha) = load_image_with_alpha(&source.image, self.background)?;
        let image = Arc::new(image);
        let size = (image.width, image.height);
        self.decoded
            .insert(source.real.clone(), (Arc::downgrade(&image), alpha, size));
        Ok((image, alpha))
    }

    /// The photo of the frame that will be `views[views.len()]`: an earlier view's when
    /// one shares its file, mask, intrinsics `k` and lens, else undistorted, masked and
    /// downscaled now from `decoded` (the file decoded again when nothing held it). `ctx`
    /// is `(origin, item)` for errors.
    pub fn prepare(
        &mut self,
        source: Source,
        decoded: Option<Arc<Image>>,
        k: [f64; 4],
        views: &[View],
        ctx: (&str, &str),
    ) -> Result<PreparedPhoto> {
        let key = (
            source.real.clone(),
            source.mask.clone(),
            k.map(f64::to_bits),
            lens_bits(&source.distortion),
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
            None => self.decode(&source)?.0,
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
            lens_origin: source.lens_origin,
        };
        let prepared = prepare_photo(photo, &mut self.undistorter, self.n, ctx)?;
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
