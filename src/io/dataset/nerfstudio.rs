//! The nerfstudio / instant-ngp layout:
//!
//! ```text
//! DIR/transforms.json (every frame)   DIR/images/frame_00001.jpg ...
//! ```
//!
//! A folder with a `transforms.json` (and no `transforms_train.json`, which makes it
//! [`super::blender`]'s) is this format's. The one transforms file ([`super::transforms`])
//! holds every frame, split as mip-NeRF 360 does ([`super::hold_out`]): every 8th frame (0,
//! 8, 16, ...) is held out as `test`, the others train (a file of fewer than 8 frames trains
//! on all); there is no `val`.

use std::path::{Path, PathBuf};

use crate::model::Dataset;
use crate::model::error::Result;

use super::photo_memory::FramePhoto;
use super::transforms::Transforms;
use super::{DatasetFiles, DatasetOptions, Description, Format, hold_out, no_training_frames};

/// The nerfstudio / instant-ngp layout.
pub(super) struct Nerfstudio;

/// Its one file.
const FILE: &str = "transforms.json";

impl Format for Nerfstudio {
    fn sign(&self) -> &'static str {
        FILE
    }

    fn description_files(&self, dir: &Path) -> Vec<PathBuf> {
        vec![dir.join(FILE)]
    }

    fn claims(&self, dir: &Path) -> Option<PathBuf> {
        let file = dir.join(FILE);
        file.is_file().then_some(file)
    }

    fn read(&self, dir: &Path) -> Box<dyn Description> {
        Box::new(Single {
            dir: dir.to_path_buf(),
            transforms: Transforms::read(&dir.join(FILE)),
        })
    }
}

/// The one transforms file of a nerfstudio dataset.
struct Single {
    dir: PathBuf,
    transforms: Transforms,
}

impl Description for Single {
    fn named_files(&self) -> DatasetFiles {
        let mut files = DatasetFiles::default();
        self.transforms.add_named_files(&self.dir, &mut files);
        files
    }

    fn frame_photos(&self) -> Vec<FramePhoto> {
        self.transforms.frame_photos(&self.dir)
    }

    fn load(self: Box<Self>, options: &DatasetOptions) -> Result<Dataset> {
        let path = self.transforms.path.clone();
        let read = self.transforms.load(&self.dir, options)?;
        let (train, test) = hold_out(read.views);
        if train.is_empty() {
            return Err(no_training_frames(
                &path,
                "frames",
                "the `frames` list is empty",
            ));
        }
        Ok(Dataset {
            train,
            val: Vec::new(),
            test,
            transparent: read.transparent,
            notes: read.notes,
            blend: read.blend,
            points: read.points,
            depth_range: None,
        })
    }
}
