//! Multi-view datasets in the layouts dynamic and static splatting tools write, one file per
//! layout, tried in the order of `FORMATS`:
//!
//! ```text
//! D-NeRF / Blender          (blender)     DIR/transforms_{train,val,test}.json  DIR/train/r_000.png ...
//! nerfstudio / instant-ngp  (nerfstudio)  DIR/transforms.json (every frame)     DIR/images/frame_00001.jpg ...
//! COLMAP                    (colmap)      DIR/sparse/0/{cameras,images,points3D}.{bin,txt}  DIR/images/NAME
//! Neural 3D Video (N3V)     (n3v)         DIR/poses_bounds.npy  DIR/cam00.mp4 ... or DIR/cam00/images/0000.png ...
//! ```
//!
//! Each format answers for a folder "not mine" or "mine" (`Format::claims`), and then reads
//! its description (`Format::read`): what its files name (photos, masks, point clouds), and
//! its views split into train, val and test. The first format that claims the folder reads
//! it; a file any format reads its description from that is a FIFO, socket, device or folder
//! is refused, not taken for a missing one ([`crate::io::input`]). The description is read
//! once ([`DatasetSource`]): the files an output must not replace, the memory the photos
//! will take and the views all come from that one reading.
//!
//! The steps every format shares run on each frame after its format has described it
//! (`frames`, `photos`): the photo is decoded once per file (integer images as
//! `value / (2^bits - 1)`, SPEC §5: linear, no sRGB curve, JPEG included; RGBA composited
//! over [`DatasetOptions::background`], black by default: the additive model's "nothing");
//! lens distortion is removed (the photo resampled into the pinhole camera with the same
//! `fx fy cx cy`, [`crate::model::distortion`], one remap table per distinct camera, the
//! pixels whose source lies outside the photo weighing 0 in the loss, [`View::weights`]); a
//! mask multiplies the pixel weights; `downscale` N averages N×N blocks (a box filter, like
//! nerfstudio's `images_N` folders; with pixel weights, the weighted mean of the block and
//! the mean weight, [`downscale_weighted`]) and divides the intrinsics by N, after
//! undistortion. Frames whose image file is missing are skipped, with one note naming them;
//! under [`DatasetOptions::strict`] they are refused. Frames that name one file with one
//! mask, intrinsics and lens share one image ([`View::image`] is an `Arc`).
//!
//! Writing a dataset (what `splat4d dataset` makes: the D-NeRF layout) is [`DatasetWriter`]
//! and [`write_split`]; the memory estimate made before any photo is decoded is
//! [`photo_memory`].
//!
//! [`View::weights`]: crate::model::View::weights
//! [`View::image`]: crate::model::View::image

mod blender;
mod colmap;
mod frames;
mod n3v;
mod nerfstudio;
mod npy;
mod photo_memory;
mod photos;
mod transforms;
mod video;
mod write;

use std::path::{Path, PathBuf};

use crate::model::error::{Error, Result};
use crate::model::{Dataset, View};

pub use crate::model::image::downscale_weighted;
pub use photo_memory::PhotoMemory;
pub use write::{
    DatasetWriter, frame_files, write_all_transforms, write_frame_images, write_split,
};

/// The dataset formats, in the order they are asked whether a folder is theirs.
const FORMATS: [&dyn Format; 4] = [
    &blender::Blender,
    &nerfstudio::Nerfstudio,
    &colmap::Colmap,
    &n3v::N3v,
];

/// A dataset layout: which folders are its own, and how it reads them.
trait Format {
    /// What marks a folder as this format's, for messages: `transforms_train.json`.
    fn sign(&self) -> &'static str;

    /// The files of `dir` this format reads its description from, whether or not they exist
    /// (each is an input an output must not replace, and refused when it is not a regular
    /// file).
    fn description_files(&self, dir: &Path) -> Vec<PathBuf>;

    /// `None`: not mine. `Some`: mine, and the file its training frames are read from (the
    /// origin messages about them name).
    fn claims(&self, dir: &Path) -> Option<PathBuf>;

    /// The description of `dir`, a folder it claims, read once: what cannot be read is kept
    /// and reported by [`Description::load`].
    fn read(&self, dir: &Path) -> Box<dyn Description>;
}

/// A dataset folder as its format read it, before any photo is decoded.
trait Description {
    /// The photos, masks and point clouds it names, as far as it could be read (the loader
    /// reports what cannot).
    fn named_files(&self) -> DatasetFiles;

    /// Each frame's photo, mask and lens, as [`Description::load`] would read them.
    fn frame_photos(&self) -> Vec<photo_memory::FramePhoto>;

    /// What its photos will hold in memory once loaded as `options` say.
    fn photo_memory(&self, options: &DatasetOptions) -> PhotoMemory {
        photo_memory::estimate(self.frame_photos(), options.downscale)
    }

    /// Whether its frames are filmed over time ([`DatasetOptions::frames`] and
    /// [`DatasetOptions::fps`] act on it).
    fn reads_frames(&self) -> bool {
        false
    }

    /// Its views, split, with the shared steps applied.
    fn load(self: Box<Self>, options: &DatasetOptions) -> Result<Dataset>;
}

/// The three splits, in file order.
pub const SPLITS: [&str; 3] = ["train", "val", "test"];

/// Every `HOLDOUT`-th frame of a dataset without splits of its own is a test frame.
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
    /// The frames of a dataset filmed over time that are read (`None`: all).
    pub frames: Option<FrameRange>,
    /// Frames per second of a dataset filmed over time: frame `k` at `k / fps` seconds
    /// (`None`: frame `k` of `F` at `k / (F - 1)`).
    pub fps: Option<f64>,
}

/// Frames `start`, `start + step`, ... before `end` (`None`: the last), written
/// `A:B[:STEP]` (`A:` to the end).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrameRange {
    pub start: usize,
    pub end: Option<usize>,
    pub step: usize,
}

impl std::str::FromStr for FrameRange {
    type Err = String;

    fn from_str(text: &str) -> std::result::Result<Self, String> {
        let bad = || format!("`{text}` is not A:B or A:B:STEP (frames A to B - 1, every STEP-th)");
        let parts: Vec<&str> = text.split(':').collect();
        let number = |s: &str| s.trim().parse::<usize>().map_err(|_| bad());
        let (start, end, step) = match parts.as_slice() {
            [a, b] => (a, b, "1"),
            [a, b, s] => (a, b, *s),
            _ => return Err(bad()),
        };
        let start = if start.is_empty() { 0 } else { number(start)? };
        let end = if end.is_empty() {
            None
        } else {
            Some(number(end)?)
        };
        let step = number(step)?;
        if step == 0 || end.is_some_and(|e| e <= start) {
            return Err(bad());
        }
        Ok(FrameRange { start, end, step })
    }
}

impl std::fmt::Display for FrameRange {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let end = self.end.map(|e| e.to_string()).unwrap_or_default();
        write!(f, "{}:{end}:{}", self.start, self.step)
    }
}

impl Default for DatasetOptions {
    fn default() -> Self {
        DatasetOptions {
            background: [0.0; 3],
            downscale: 1,
            strict: false,
            allow_outside_images: false,
            frames: None,
            fps: None,
        }
    }
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

/// The views of a dataset without splits of its own, split as mip-NeRF 360 and nerfstudio
/// do: every [`HOLDOUT`]-th (0, 8, 16, ...) is a test view, the others train; fewer views
/// than [`HOLDOUT`] all train.
fn hold_out(views: Vec<View>) -> (Vec<View>, Vec<View>) {
    let hold_out = views.len() >= HOLDOUT;
    let (mut train, mut test) = (Vec::new(), Vec::new());
    for (index, view) in views.into_iter().enumerate() {
        if hold_out && index % HOLDOUT == 0 {
            test.push(view);
        } else {
            train.push(view);
        }
    }
    (train, test)
}

/// The error of a dataset whose training file `file` has no frames.
fn no_training_frames(file: &Path, field: &str, what: &str) -> Error {
    Error::invalid(
        &file.display().to_string(),
        "dataset",
        field,
        format!("no training frames: {what}"),
    )
}

/// The formats' signs as a list: `a, b or c`.
fn signs() -> String {
    let signs: Vec<&str> = FORMATS.iter().map(|f| f.sign()).collect();
    match signs.split_last() {
        Some((last, rest)) if !rest.is_empty() => format!("{} or {last}", rest.join(", ")),
        _ => signs.concat(),
    }
}

/// The format of the dataset in `dir`: the first of `FORMATS` that claims it, with the
/// file its training frames are read from (`None`: no format does). A description file of
/// any format that is not a regular file is refused.
fn find_format(dir: &Path) -> Result<Option<(&'static dyn Format, PathBuf)>> {
    if !dir.is_dir() {
        return Err(Error::malformed(
            &dir.display().to_string(),
            format!("not a folder with {}", signs()),
        ));
    }
    for path in FORMATS.iter().flat_map(|f| f.description_files(dir)) {
        if let Some(kind) = crate::io::input::special_kind(&path) {
            return Err(Error::malformed(
                &path.display().to_string(),
                crate::io::input::not_regular(kind),
            ));
        }
    }
    Ok(FORMATS
        .iter()
        .find_map(|&format| format.claims(dir).map(|file| (format, file))))
}

/// A dataset folder with its format found and its description read once: the files it
/// names ([`DatasetSource::files`]), the memory its photos will take
/// ([`DatasetSource::photo_memory`]) and its views ([`DatasetSource::load`]) all come from
/// that one reading. What cannot be read is reported by `load`.
pub struct DatasetSource {
    dir: PathBuf,
    /// The description read, `None` when no format claims the folder, or why it cannot
    /// be read at all.
    found: Result<Option<Box<dyn Description>>>,
}

impl DatasetSource {
    /// Finds the format of the dataset in `dir` and reads its description.
    #[must_use]
    pub fn open(dir: &Path) -> Self {
        let found = find_format(dir).map(|found| found.map(|(format, _)| format.read(dir)));
        DatasetSource {
            dir: dir.to_path_buf(),
            found,
        }
    }

    /// The files the dataset is read from ([`dataset_inputs`]).
    #[must_use]
    pub fn files(&self) -> DatasetFiles {
        let mut files = match &self.found {
            Ok(Some(description)) => description.named_files(),
            _ => DatasetFiles::default(),
        };
        files.descriptions = FORMATS
            .iter()
            .flat_map(|f| f.description_files(&self.dir))
            .collect();
        files
    }

    /// What its photos will hold in memory ([`photo_memory`]).
    #[must_use]
    pub fn photo_memory(&self, downscale: u32) -> PhotoMemory {
        self.photo_memory_as(&DatasetOptions {
            downscale,
            ..DatasetOptions::default()
        })
    }

    /// What its photos will hold in memory once loaded as `options` say (the frames
    /// chosen, the downscale).
    #[must_use]
    pub fn photo_memory_as(&self, options: &DatasetOptions) -> PhotoMemory {
        match &self.found {
            Ok(Some(description)) => description.photo_memory(options),
            _ => PhotoMemory::default(),
        }
    }

    /// Reads every split ([`load_dataset`]).
    pub fn load(self, options: &DatasetOptions) -> Result<Dataset> {
        match self.found? {
            Some(description) if !description.reads_frames() => {
                let field = match (options.frames, options.fps) {
                    (Some(_), _) => Some("frames"),
                    (_, Some(_)) => Some("fps"),
                    _ => None,
                };
                if let Some(field) = field {
                    return Err(Error::setting(
                        &[field],
                        format!(
                            "`{field}` acts on a dataset filmed over time (poses_bounds.npy with camNN videos or frames); {} is not one",
                            self.dir.display()
                        ),
                    ));
                }
                description.load(options)
            }
            Some(description) => description.load(options),
            None => Err(Error::malformed(
                &self.dir.display().to_string(),
                format!("no {}: not a dataset folder", signs()),
            )),
        }
    }
}

/// Reads every split of the dataset in `dir`, in the first of its `FORMATS` that claims
/// it: `transforms_{train,val,test}.json`, or one `transforms.json` split every
/// [`HOLDOUT`]-th frame, or a COLMAP model (`sparse/0`) split the same way.
pub fn load_dataset(dir: &Path, options: &DatasetOptions) -> Result<Dataset> {
    DatasetSource::open(dir).load(options)
}

/// The file [`load_dataset`] reads the training frames of the dataset in `dir` from
/// (`transforms_train.json`, `transforms.json`, or the COLMAP model's images file), or `dir`
/// itself when there is none: the origin messages about those frames name.
#[must_use]
pub fn training_file(dir: &Path) -> PathBuf {
    FORMATS
        .iter()
        .find_map(|format| format.claims(dir))
        .unwrap_or_else(|| dir.to_path_buf())
}

/// The files a dataset is read from, by what they hold ([`dataset_inputs`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DatasetFiles {
    /// The files every format reads its description from (transforms files, the COLMAP
    /// model's files), whether or not they exist.
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

/// The files a dataset in `dir` is read from (as far as its description can be read; the
/// loader reports what cannot): the description files of every format, and the photos,
/// masks (`mask_path`) and point cloud (`ply_file_path`) that the description of the format
/// that claims it names. Outputs are checked against all of these before any work
/// ([`crate::io::output`]), and the memory estimate counts the photos and masks. Only
/// regular files are read here (a FIFO named like a transforms file would block).
#[must_use]
pub fn dataset_inputs(dir: &Path) -> DatasetFiles {
    DatasetSource::open(dir).files()
}

/// Every file of [`dataset_inputs`].
#[must_use]
pub fn dataset_files(dir: &Path) -> Vec<PathBuf> {
    dataset_inputs(dir).all()
}

/// Estimates what loading the dataset in `dir` with `downscale` holds ([`PhotoMemory`]),
/// from the image headers alone (nothing is decoded).
#[must_use]
pub fn photo_memory(dir: &Path, downscale: u32) -> PhotoMemory {
    DatasetSource::open(dir).photo_memory(downscale)
}
