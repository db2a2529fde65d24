//! The COLMAP layout:
//!
//! ```text
//! DIR/sparse/0/{cameras,images,points3D}.{bin,txt}   DIR/images/NAME
//! ```
//!
//! A folder with a sparse model in `DIR/sparse/0` (or `DIR/sparse`) is this format's when no
//! transforms file claims it first. The model is read by [`crate::io::colmap`], the photos
//! from `DIR/images/NAME`. The poses are used as they are (world→camera, OpenCV axes, SPEC
//! §3); a camera's distortion is removed at load as a transforms file's is
//! ([`super::photos`]). The views are sorted by name and split as nerfstudio does
//! ([`super::hold_out`]: every 8th, 0, 8, 16, ..., is held out as `test`; fewer than 8
//! images all train). COLMAP models are static: every time is 0. `points3D` becomes
//! [`Dataset::points`].

use std::path::{Path, PathBuf};

use crate::io::colmap::{self as model, ColmapCamera, ColmapImage, SparseModel};
use crate::model::camera::Camera;
use crate::model::error::{Error, Result};
use crate::model::{Dataset, DatasetPoint};

use super::frames::{Frame, FrameSource, inside_dataset, load_views, regular_file};
use super::photo_memory::FramePhoto;
use super::photos::Source;
use super::{
    DatasetFiles, DatasetOptions, Description, Format, check_downscale, hold_out,
    no_training_frames,
};

/// The COLMAP layout.
pub(super) struct Colmap;

impl Format for Colmap {
    fn sign(&self) -> &'static str {
        "a COLMAP sparse/0"
    }

    fn description_files(&self, dir: &Path) -> Vec<PathBuf> {
        let Some(sparse) = model::find_sparse_model(dir) else {
            return Vec::new();
        };
        model::model_files(&sparse).into_iter().flatten().collect()
    }

    fn claims(&self, dir: &Path) -> Option<PathBuf> {
        let sparse = model::find_sparse_model(dir)?;
        let [_, images, _] = model::model_files(&sparse);
        Some(images.unwrap_or(sparse))
    }

    fn read(&self, dir: &Path) -> Box<dyn Description> {
        let sparse = model::find_sparse_model(dir).unwrap_or_else(|| dir.join("sparse"));
        let model = model::read_sparse_model(&sparse);
        Box::new(Model {
            dir: dir.to_path_buf(),
            sparse,
            model,
        })
    }
}

/// A COLMAP model as read once, and the folder its photos are in.
struct Model {
    dir: PathBuf,
    sparse: PathBuf,
    model: Result<SparseModel>,
}

impl Description for Model {
    fn named_files(&self) -> DatasetFiles {
        let images = self.model.as_ref().map(|m| m.images.as_slice());
        DatasetFiles {
            photos: images
                .unwrap_or_default()
                .iter()
                .map(|image| self.dir.join("images").join(&image.name))
                .collect(),
            ..DatasetFiles::default()
        }
    }

    fn frame_photos(&self) -> Vec<FramePhoto> {
        let Ok(model) = &self.model else {
            return Vec::new();
        };
        let real = |p: &Path| p.canonicalize().unwrap_or_else(|_| p.to_path_buf());
        model
            .images
            .iter()
            .filter_map(|image| {
                let path = self.dir.join("images").join(&image.name);
                let lens = model.cameras.get(&image.camera_id)?.distortion;
                path.is_file().then(|| (real(&path), None, lens))
            })
            .collect()
    }

    fn load(self: Box<Self>, options: &DatasetOptions) -> Result<Dataset> {
        check_downscale(options.downscale)?;
        let Model { dir, sparse, model } = *self;
        let mut model = model?;
        let [cameras_file, images_file, _] = model::model_files(&sparse);
        let name = |file: Option<PathBuf>| file.unwrap_or_else(|| sparse.clone());
        let (origin, cameras_origin) = (name(images_file), name(cameras_file));
        model.images.sort_by(|a, b| a.name.cmp(&b.name));
        let frames = ModelFrames {
            dir: &dir,
            model: &model,
            origin: origin.display().to_string(),
            cameras_origin: cameras_origin.display().to_string(),
        };
        let loaded = load_views(&frames, options)?;
        let (train, test) = hold_out(loaded.views);
        if train.is_empty() {
            return Err(no_training_frames(
                &origin,
                "images",
                "the model registers no image",
            ));
        }
        Ok(Dataset {
            train,
            val: Vec::new(),
            test,
            transparent: loaded.transparent,
            notes: loaded.notes,
            blend: None,
            points: points(&model),
            depth_range: None,
        })
    }
}

/// The model's points as the dataset's (`None` when it has none): colours read as 8-bit
/// images are, `v / 255`.
fn points(model: &SparseModel) -> Option<Vec<DatasetPoint>> {
    (!model.points.is_empty()).then(|| {
        model
            .points
            .iter()
            .map(|p| DatasetPoint {
                position: p.position,
                colour: p.colour.map(|c| (f64::from(c) / 255.0) as f32),
            })
            .collect()
    })
}

/// The registered images of a model (sorted by name), as [`load_views`] asks for them.
struct ModelFrames<'a> {
    dir: &'a Path,
    model: &'a SparseModel,
    /// The images file.
    origin: String,
    /// The cameras file, which errors about a camera's lens name.
    cameras_origin: String,
}

impl ModelFrames<'_> {
    /// The image `index` and its camera, which the cameras file must have; `item` names
    /// the image in the error.
    fn image(&self, index: usize, item: &str) -> Result<(&ColmapImage, &ColmapCamera)> {
        let image = &self.model.images[index];
        let camera = self.model.cameras.get(&image.camera_id).ok_or_else(|| {
            Error::invalid(
                &self.origin,
                item,
                "camera_id",
                format!("camera {} is not in the cameras file", image.camera_id),
            )
        })?;
        Ok((image, camera))
    }
}

impl FrameSource for ModelFrames<'_> {
    fn origin(&self) -> &str {
        &self.origin
    }

    fn count(&self) -> usize {
        self.model.images.len()
    }

    fn frame(&self, index: usize) -> Result<Frame> {
        let origin = self.origin.as_str();
        let entry = &self.model.images[index];
        let item = format!("image {} ({})", entry.id, entry.name);
        let (entry, camera) = self.image(index, &item)?;
        let name = format!("images/{}", entry.name);
        let path = self.dir.join(&name);
        if !path.is_file() {
            regular_file(&path, &name, (origin, &item, "name"), false)?;
            return Ok(Frame {
                item,
                name,
                photo: None,
            });
        }
        let real = inside_dataset(self.dir, &name, origin, &item, "name")?;
        let source = Source {
            image: path,
            real,
            mask: None,
            distortion: camera.distortion,
            lens_origin: Some((
                self.cameras_origin.clone(),
                format!("camera {} (params)", entry.camera_id),
            )),
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
        source: &Source,
        (w, h): (u32, u32),
    ) -> Result<[f64; 4]> {
        let (entry, camera) = self.image(index, &frame.item)?;
        if (w, h) != (camera.width, camera.height) {
            return Err(Error::invalid(
                &self.origin,
                &frame.item,
                "camera_id",
                format!(
                    "{} is {w}×{h} but camera {} is {}×{}",
                    source.real.display(),
                    entry.camera_id,
                    camera.width,
                    camera.height
                ),
            ));
        }
        Ok(camera.intrinsics)
    }

    fn camera(
        &self,
        index: usize,
        frame: &Frame,
        (w, h): (u32, u32),
        k: [f64; 4],
    ) -> Result<(Camera, f64)> {
        let entry = &self.model.images[index];
        let w2c = model::world_to_camera(entry.rotation, entry.translation);
        let camera = Camera::new(w, h, k, w2c).map_err(|e| match e {
            Error::Invalid { field, message, .. } => {
                Error::invalid(&self.origin, &frame.item, &field, message)
            }
            other => other,
        })?;
        Ok((camera, 0.0))
    }
}
